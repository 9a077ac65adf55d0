//! Model description files (TOML): which network, how to feed it, how to read its output and what
//! its classes are called (segmentation), or how many values it gives per image (an image
//! embedding, `[output] kind = "embedding"`, for the similarity step). Loading checks everything
//! that can be checked without the model.

use crate::error::{Error, Result};
use crate::output::Inputs;
use crate::tomlfile::{self, TomlFile};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Network file format, as OpenCV DNN names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Framework {
    /// ONNX (the only format ONNX Runtime reads).
    Onnx,
    /// Torch7 `.net` / `.t7`.
    Torch,
    /// Caffe `.caffemodel` with a `.prototxt` config.
    Caffe,
    /// TensorFlow frozen `.pb`, optional `.pbtxt` config.
    Tensorflow,
    /// Darknet `.weights` with a `.cfg` config.
    Darknet,
}

impl Framework {
    /// The name OpenCV's `readNet` expects.
    pub fn opencv_name(self) -> &'static str {
        match self {
            Framework::Onnx => "onnx",
            Framework::Torch => "torch",
            Framework::Caffe => "caffe",
            Framework::Tensorflow => "tensorflow",
            Framework::Darknet => "darknet",
        }
    }
}

/// Memory order of a 4-D image tensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    /// Batch, channels, rows, columns.
    #[default]
    Nchw,
    /// Batch, rows, columns, channels.
    Nhwc,
}

/// Channel order the network expects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ChannelOrder {
    /// Red first.
    #[default]
    Rgb,
    /// Blue first (OpenCV's own order).
    Bgr,
}

/// What the network's output means.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OutputKind {
    /// One score channel per class; the class of a pixel is the argmax.
    Scores,
    /// One channel with the probability of the last class; pixels at or above `threshold` get the
    /// last class, the others the first.
    Probability,
    /// One vector of `dim` values per image (an image embedding); no classes.
    Embedding,
}

/// `[input]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputDesc {
    /// Tensor name; the model's first input when absent.
    pub name: Option<String>,
    /// Width the image is resized to.
    pub width: u32,
    /// Height the image is resized to.
    pub height: u32,
    /// Tensor layout.
    #[serde(default)]
    pub layout: Layout,
    /// Channel order.
    #[serde(default)]
    pub channels: ChannelOrder,
    /// Each 8-bit value is multiplied by this first (e.g. 1/255).
    #[serde(default = "one")]
    pub scale: f32,
    /// Subtracted after scaling, per channel in the model's order.
    #[serde(default = "zeros")]
    pub mean: [f32; 3],
    /// Divides after the mean, per channel in the model's order.
    #[serde(default = "ones")]
    pub std: [f32; 3],
    /// Most images per inference call; 1 for models with a fixed batch dimension.
    #[serde(default = "one_usize")]
    pub batch: usize,
}

/// `[output]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputDesc {
    /// Tensor name; the model's first output when absent.
    pub name: Option<String>,
    /// Meaning of the values.
    pub kind: OutputKind,
    /// Layout of a 4-D output; the input's when absent.
    pub layout: Option<Layout>,
    /// Probability threshold for `kind = "probability"`.
    #[serde(default = "half")]
    pub threshold: f32,
    /// Values per image for `kind = "embedding"`.
    pub dim: Option<usize>,
}

fn one() -> f32 {
    1.0
}
fn one_usize() -> usize {
    1
}
fn half() -> f32 {
    0.5
}
fn zeros() -> [f32; 3] {
    [0.0; 3]
}
fn ones() -> [f32; 3] {
    [1.0; 3]
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDesc {
    model: PathBuf,
    framework: Framework,
    config: Option<PathBuf>,
    classes: Option<Vec<String>>,
    classes_file: Option<PathBuf>,
    colors: Option<Vec<[u8; 3]>>,
    colors_file: Option<PathBuf>,
    hide: Option<Vec<String>>,
    input: InputDesc,
    output: OutputDesc,
}

/// A loaded, checked model description; paths are resolved against the description's folder.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelDesc {
    /// The description file itself.
    pub path: PathBuf,
    /// Network weights.
    pub model: PathBuf,
    /// Network file format.
    pub framework: Framework,
    /// Second file some formats need.
    pub config: Option<PathBuf>,
    /// Class names in output order.
    pub classes: Vec<String>,
    /// Overlay colour (R, G, B) per class.
    pub colors: Vec<[u8; 3]>,
    /// Classes hidden when the user names none.
    pub hide: Vec<String>,
    /// How to feed the network.
    pub input: InputDesc,
    /// How to read its output.
    pub output: OutputDesc,
    /// Every file the description names, itself included (what a command using it reads).
    pub inputs: Inputs,
}

impl ModelDesc {
    /// Reads and checks a description file.
    pub fn load(path: &Path) -> Result<ModelDesc> {
        let file = tomlfile::read::<RawDesc>(path, "model description")?;
        let raw = &file.value;
        let dir = path.parent().unwrap_or(Path::new("."));
        let model = existing(&file, "model", dir.join(&raw.model))?;
        let config = raw.config.as_deref().map(|c| dir.join(c));
        let config = config.map(|c| existing(&file, "config", c)).transpose()?;
        let embedding = raw.output.kind == OutputKind::Embedding;
        let classes = match embedding {
            true => check_embedding(&file)?,
            false => classes(&file, dir)?,
        };
        let colors = match embedding {
            true => Vec::new(),
            false => colors(&file, dir, classes.len())?,
        };
        let hide = raw.hide.clone().unwrap_or_default();
        for (k, h) in hide.iter().enumerate() {
            if !classes.iter().any(|c| c.eq_ignore_ascii_case(h)) {
                let msg = format!("`{h}` is not one of the classes ({})", classes.join(", "));
                return Err(file.error(&format!("hide[{k}]"), msg));
            }
        }
        check_numbers(&file)?;
        let mut inputs = Inputs::none()
            .with("model description", path)
            .with("network", &model);
        for (what, f) in [
            ("network config", &raw.config),
            ("class names", &raw.classes_file),
            ("class colours", &raw.colors_file),
        ] {
            if let Some(f) = f {
                inputs.add(what, dir.join(f));
            }
        }
        Ok(ModelDesc {
            path: path.to_path_buf(),
            model,
            framework: raw.framework,
            config,
            classes,
            colors,
            hide,
            input: raw.input.clone(),
            output: raw.output.clone(),
            inputs,
        })
    }

    /// Reads a description of an image-embedding network (`[output] kind = "embedding"`); any
    /// other kind is refused, naming the file and the key.
    pub fn load_embedding(path: &Path) -> Result<ModelDesc> {
        let d = ModelDesc::load(path)?;
        if d.output.kind != OutputKind::Embedding {
            let msg = format!(
                "the similarity step needs an image-embedding network (kind = \"embedding\"), \
                 this description is for {:?} (segmentation)",
                d.output.kind
            );
            return Err(Error::file(
                path,
                None,
                "model description",
                "output.kind",
                msg,
            ));
        }
        Ok(d)
    }

    /// The description iVS3D's naming implies for the ONNX embedding network at `model` (no
    /// description file): one RGB `width` x `height` image (NCHW) scaled to [0, 1] and
    /// normalised with ImageNet's mean and standard deviation, `dim` values out.
    pub fn embedding_defaults(model: &Path, dim: usize, width: u32, height: u32) -> ModelDesc {
        ModelDesc {
            path: model.to_path_buf(),
            model: model.to_path_buf(),
            framework: Framework::Onnx,
            config: None,
            classes: Vec::new(),
            colors: Vec::new(),
            hide: Vec::new(),
            input: InputDesc {
                name: None,
                width,
                height,
                layout: Layout::Nchw,
                channels: ChannelOrder::Rgb,
                scale: 1.0 / 255.0,
                mean: IMAGENET_MEAN,
                std: IMAGENET_STD,
                batch: 1,
            },
            output: OutputDesc {
                name: None,
                kind: OutputKind::Embedding,
                layout: None,
                threshold: half(),
                dim: Some(dim),
            },
            inputs: Inputs::none().with("embedding model", model),
        }
    }

    /// Whether this description is a file of its own (false: implied by a model's name).
    pub fn has_file(&self) -> bool {
        self.path != self.model
    }

    /// The fields that decide what a network computes from an image besides its weights (input
    /// size, layout, channels, scale, mean, std, tensor names, output size), as text: part of
    /// an embedding series' cache key.
    pub fn preprocessing(&self) -> String {
        let i = &self.input;
        format!(
            "{:?} {}x{} {:?} {:?} {:?} {:?} {:?} -> {:?} {:?}",
            i.name,
            i.width,
            i.height,
            i.layout,
            i.channels,
            i.scale,
            i.mean,
            i.std,
            self.output.name,
            self.output.dim
        )
    }

    /// Layout of the output tensor.
    pub fn output_layout(&self) -> Layout {
        self.output.layout.unwrap_or(self.input.layout)
    }

    /// Number of channels the output must have.
    pub fn output_channels(&self) -> usize {
        match self.output.kind {
            OutputKind::Scores => self.classes.len(),
            OutputKind::Probability => 1,
            OutputKind::Embedding => self.output.dim.unwrap_or(0),
        }
    }

    /// Class indices for the given names (case-insensitive); an unknown name is an error that
    /// lists the known ones.
    pub fn class_ids(&self, names: &[String]) -> Result<Vec<usize>> {
        let names = if names.is_empty() {
            &self.hide[..]
        } else {
            names
        };
        let (path, classes) = (self.path.display(), self.classes.join(", "));
        let bad = |msg: String| Error::param("masks.classes", msg);
        if names.is_empty() {
            let msg =
                format!("name the classes to hide ({path} has no `hide` list); classes: {classes}");
            return Err(bad(msg));
        }
        names
            .iter()
            .map(|n| {
                let i = self
                    .classes
                    .iter()
                    .position(|c| c.eq_ignore_ascii_case(n.trim()));
                i.ok_or_else(|| {
                    bad(format!(
                        "`{n}` is not a class of {path} (classes: {classes})"
                    ))
                })
            })
            .collect()
    }
}

/// ImageNet's per-channel mean (R, G, B) of values in [0, 1].
pub const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
/// ImageNet's per-channel standard deviation (R, G, B) of values in [0, 1].
pub const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];

/// Whether `path` names a description file (`.toml`) rather than a network.
pub fn is_description(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
}

/// An embedding network's description: an ONNX model, no classes, colours or hidden classes
/// (the error names the key), `output.dim` given. Returns the (empty) class list.
fn check_embedding(file: &TomlFile<RawDesc>) -> Result<Vec<String>> {
    let raw = &file.value;
    if raw.framework != Framework::Onnx {
        let msg = "an embedding network must be an ONNX model (framework = \"onnx\")";
        return Err(file.error("framework", msg));
    }
    let given = [
        ("classes", raw.classes.is_some()),
        ("classes_file", raw.classes_file.is_some()),
        ("colors", raw.colors.is_some()),
        ("colors_file", raw.colors_file.is_some()),
        ("hide", raw.hide.is_some()),
    ];
    if let Some((key, _)) = given.iter().find(|(_, g)| *g) {
        let msg = "an embedding network (kind = \"embedding\") has no classes: leave it out";
        return Err(file.error(key, msg));
    }
    match raw.output.dim {
        Some(d) if (1..=65536).contains(&d) => Ok(Vec::new()),
        Some(d) => Err(file.error("output.dim", format!("must be 1..=65536, got {d}"))),
        None => Err(file.error(
            "output.dim",
            "give the values per image of an embedding network (e.g. dim = 2048)",
        )),
    }
}

/// `path` (the value of `field`) if it is a file.
fn existing(file: &TomlFile<RawDesc>, field: &str, path: PathBuf) -> Result<PathBuf> {
    if !path.is_file() {
        let msg = format!("{} does not exist or is not a file", path.display());
        return Err(file.error(field, msg));
    }
    Ok(path)
}

/// The class names, from `classes` or `classes_file`: some, each once, two for a probability.
fn classes(file: &TomlFile<RawDesc>, dir: &Path) -> Result<Vec<String>> {
    let raw = &file.value;
    let classes = match (&raw.classes, &raw.classes_file) {
        (Some(c), None) => c.clone(),
        (None, Some(f)) => read_lines(&dir.join(f))?,
        _ => {
            let msg =
                "give exactly one of `classes` (a list) or `classes_file` (one name per line)";
            return Err(file.error("classes", msg));
        }
    };
    if classes.is_empty() {
        return Err(file.error("classes", "no class names"));
    }
    if raw.output.kind == OutputKind::Probability && classes.len() != 2 {
        let n = classes.len();
        let msg = format!("a probability output needs exactly two classes (below, at or above the threshold), got {n}");
        return Err(file.error("classes", msg));
    }
    for (i, c) in classes.iter().enumerate() {
        if classes[..i].iter().any(|d| d.eq_ignore_ascii_case(c)) {
            return Err(file.error("classes", format!("`{c}` is listed twice")));
        }
    }
    Ok(classes)
}

/// The colours, from `colors`, `colors_file` or defaults: one per class.
fn colors(file: &TomlFile<RawDesc>, dir: &Path, classes: usize) -> Result<Vec<[u8; 3]>> {
    let colors = match (&file.value.colors, &file.value.colors_file) {
        (Some(c), None) => c.clone(),
        (None, Some(f)) => read_colors(&dir.join(f))?,
        (None, None) => default_colors(classes),
        _ => return Err(file.error("colors", "give at most one of `colors` and `colors_file`")),
    };
    if colors.len() != classes {
        let msg = format!("{} colours for {classes} classes", colors.len());
        return Err(file.error("colors", msg));
    }
    Ok(colors)
}

/// Checks the input size, scale, std and batch, and the output threshold.
fn check_numbers(file: &TomlFile<RawDesc>) -> Result<()> {
    let i = &file.value.input;
    let o = &file.value.output;
    if o.dim.is_some() && o.kind != OutputKind::Embedding {
        let msg = "`dim` is for an embedding network (kind = \"embedding\")";
        return Err(file.error("output.dim", msg));
    }
    if i.width == 0 || i.height == 0 || i.width > 16384 || i.height > 16384 {
        return Err(file.error("input.width", "width and height must be 1..=16384"));
    }
    if !(i.scale.is_finite() && i.scale != 0.0) {
        return Err(file.error("input.scale", "must be a finite, non-zero number"));
    }
    if i.std.iter().any(|s| !(s.is_finite() && *s != 0.0)) {
        return Err(file.error("input.std", "every value must be finite and non-zero"));
    }
    if i.batch == 0 || i.batch > 256 {
        return Err(file.error("input.batch", "must be 1..=256"));
    }
    if !(0.0..=1.0).contains(&file.value.output.threshold) {
        return Err(file.error("output.threshold", "must be between 0 and 1"));
    }
    Ok(())
}

fn read_lines(path: &Path) -> Result<Vec<String>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    Ok(text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .map(String::from)
        .collect())
}

fn read_colors(path: &Path) -> Result<Vec<[u8; 3]>> {
    read_lines(path)?
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let v: Vec<u8> = l
                .split([',', ' ', '\t'])
                .filter(|s| !s.is_empty())
                .map(|s| s.parse::<u8>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|e| Error::input(path, format!("line {}: {e}", i + 1)))?;
            match v[..] {
                [r, g, b] => Ok([r, g, b]),
                _ => Err(Error::input(
                    path,
                    format!("line {}: expected R,G,B, got `{l}`", i + 1),
                )),
            }
        })
        .collect()
}

/// Distinct, stable colours for classes without a colour table.
fn default_colors(n: usize) -> Vec<[u8; 3]> {
    (0..n)
        .map(|i| {
            let h = (i as u32).wrapping_mul(2_654_435_761);
            [(h >> 8) as u8, (h >> 16) as u8, (h >> 24) as u8]
        })
        .collect()
}
