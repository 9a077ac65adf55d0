//! Segmentation masks: runs a semantic segmentation network (OpenCV DNN or ONNX Runtime) on
//! images and turns the classes the user hides into COLMAP masks (hidden 0, kept 255), checking
//! the model against its description before any frame is touched.

use crate::model_desc as desc;
pub mod dnn;
pub mod embedding;
pub mod onnx;
#[cfg(feature = "onnx")]
pub mod onnxrt;
#[cfg(not(feature = "onnx"))]
#[path = "onnxrt_off.rs"]
pub mod onnxrt;
pub mod tensor;

use crate::error::{CvContext, Error, Result};
use desc::{Framework, Layout, ModelDesc};
use opencv::core::{Mat, Point, Size, Vec3b, CV_16U, CV_8U, CV_8UC3};
use opencv::imgproc;
use opencv::prelude::*;
use std::path::Path;
use std::time::{Duration, Instant};

use crate::manifest::{MaskSettings, SegRuntime};

enum Runner {
    Dnn(dnn::DnnRunner),
    Ort(onnxrt::OrtRunner),
}

/// A loaded, checked network plus the classes to hide.
pub struct Segmenter {
    desc: ModelDesc,
    runner: Runner,
    hide: Vec<bool>,
    dilate: u32,
    batch: usize,
    inference: Duration,
    images: usize,
}

/// Per-pixel classes of one image at the network's output resolution (CV_16U).
pub struct ClassMap(pub Mat);

impl Segmenter {
    /// Loads the model, checks it against its description (declared shapes for ONNX, then a
    /// trial run on a blank image) and resolves the class names to hide.
    pub fn new(settings: &MaskSettings) -> Result<Segmenter> {
        let desc = ModelDesc::load(&settings.model)?;
        if desc.output.kind == desc::OutputKind::Embedding {
            let msg =
                "an image-embedding network (for --similarity-model), not a segmentation network";
            return Err(Error::file(
                &desc.path,
                None,
                "model description",
                "output.kind",
                msg,
            ));
        }
        let ids = desc.class_ids(&settings.classes)?;
        let mut hide = vec![false; desc.classes.len()];
        for i in ids {
            hide[i] = true;
        }
        let mut batch = desc.input.batch;
        if desc.framework == Framework::Onnx {
            batch = check_onnx_signature(&desc)?;
        } else if settings.backend == SegRuntime::Ort {
            return Err(Error::param(
                "masks.backend",
                format!(
                    "ONNX Runtime reads only ONNX models; {} is a {} model (use the opencv backend)",
                    desc.model.display(),
                    desc.framework.opencv_name()
                ),
            ));
        }
        let runner = match settings.backend {
            SegRuntime::Opencv => Runner::Dnn(dnn::DnnRunner::load(&desc)?),
            SegRuntime::Ort => Runner::Ort(onnxrt::OrtRunner::load(&desc)?),
        };
        let mut s = Segmenter {
            desc,
            runner,
            hide,
            dilate: settings.dilate,
            batch,
            inference: Duration::ZERO,
            images: 0,
        };
        let blank = Mat::new_rows_cols_with_default(
            s.desc.input.height as i32,
            s.desc.input.width as i32,
            CV_8UC3,
            0.into(),
        )
        .cv(|| "blank image".into())?;
        // A full batch, so a model that cannot take it fails here rather than mid-export.
        s.classify(&vec![blank; s.batch])?;
        s.inference = Duration::ZERO;
        s.images = 0;
        Ok(s)
    }

    /// Most images per inference call.
    pub fn batch(&self) -> usize {
        self.batch
    }

    /// Mean inference time per image so far (network only, without pre/post-processing).
    pub fn ms_per_image(&self) -> Option<f64> {
        (self.images > 0).then(|| self.inference.as_secs_f64() * 1e3 / self.images as f64)
    }

    /// Class maps of 8-bit BGR images, run in batches of at most [`Self::batch`].
    pub fn classify(&mut self, images: &[Mat]) -> Result<Vec<ClassMap>> {
        let mut out = Vec::with_capacity(images.len());
        for chunk in images.chunks(self.batch) {
            let shape = tensor::input_shape(&self.desc, chunk.len());
            let mut data = Vec::with_capacity(shape.iter().product());
            for img in chunk {
                tensor::push_image(&self.desc, img, &mut data)?;
            }
            let t = Instant::now();
            let (oshape, values) = match &mut self.runner {
                Runner::Dnn(r) => r.run(&self.desc, &shape, &data)?,
                Runner::Ort(r) => r.run(&self.desc, &shape, &data)?,
            };
            self.inference += t.elapsed();
            self.images += chunk.len();
            let maps = tensor::decode_output(&self.desc, &oshape, &values, chunk.len())?;
            for m in maps.maps {
                let mat = Mat::new_rows_cols_with_data(maps.height as i32, maps.width as i32, &m)
                    .cv(|| "class map".into())?
                    .try_clone()
                    .cv(|| "class map copy".into())?;
                out.push(ClassMap(mat));
            }
        }
        Ok(out)
    }

    /// Whether class `c` is one to hide (an id beyond the description's classes is kept).
    fn hidden(&self, c: usize) -> bool {
        self.hide.get(c).copied().unwrap_or(false)
    }

    /// The COLMAP mask for a class map at `size` (width, height): hidden classes 0, the rest 255,
    /// resized with nearest neighbour, the hidden area grown by the dilation radius.
    pub fn mask(&self, classes: &ClassMap, size: (u32, u32)) -> Result<Mat> {
        let small = classes.0.data_typed::<u16>().cv(|| "class map".into())?;
        let bytes: Vec<u8> = small
            .iter()
            .map(|&c| if self.hidden(usize::from(c)) { 0 } else { 255 })
            .collect();
        let m = Mat::new_rows_cols_with_data(classes.0.rows(), classes.0.cols(), &bytes)
            .cv(|| "mask".into())?
            .try_clone()
            .cv(|| "mask copy".into())?;
        let mut mask = resize_nearest(&m, size)?;
        if self.dilate > 0 {
            // Growing the hidden (0) area is eroding the kept (255) area.
            let r = self.dilate as i32;
            let kernel = imgproc::get_structuring_element(
                imgproc::MORPH_ELLIPSE,
                Size::new(2 * r + 1, 2 * r + 1),
                Point::new(-1, -1),
            )
            .cv(|| "structuring element".into())?;
            let mut eroded = Mat::default();
            imgproc::erode(
                &mask,
                &mut eroded,
                &kernel,
                Point::new(-1, -1),
                1,
                opencv::core::BORDER_CONSTANT,
                imgproc::morphology_default_border_value().cv(|| "border".into())?,
            )
            .cv(|| "erode".into())?;
            mask = eroded;
        }
        Ok(mask)
    }

    /// A preview: the image blended half and half with the class colours, hidden classes outlined
    /// by keeping them at full colour strength.
    pub fn overlay(&self, image: &Mat, classes: &ClassMap) -> Result<Mat> {
        let size = (image.cols() as u32, image.rows() as u32);
        let map = resize_nearest(&classes.0, size)?;
        let ids = map.data_typed::<u16>().cv(|| "class map".into())?;
        let mut out = image.try_clone().cv(|| "overlay copy".into())?;
        let px = out.data_typed_mut::<Vec3b>().cv(|| "overlay".into())?;
        for (p, &c) in px.iter_mut().zip(ids) {
            let c = usize::from(c);
            let [r, g, b] = self.desc.colors.get(c).copied().unwrap_or([0, 0, 0]);
            let a = if self.hidden(c) { 0.7 } else { 0.4 };
            for (k, col) in [b, g, r].into_iter().enumerate() {
                p[k] = (f32::from(p[k]) * (1.0 - a) + f32::from(col) * a).round() as u8;
            }
        }
        Ok(out)
    }
}

fn resize_nearest(m: &Mat, size: (u32, u32)) -> Result<Mat> {
    if (m.cols() as u32, m.rows() as u32) == size {
        return m.try_clone().cv(|| "copy".into());
    }
    let to = (size.0 as i32, size.1 as i32);
    let out = crate::encode::resize(m, to, imgproc::INTER_NEAREST_EXACT)
        .cv(|| format!("nearest resize to {}x{}", size.0, size.1))?;
    debug_assert!(out.depth() == CV_8U || out.depth() == CV_16U);
    Ok(out)
}

/// Checks the description against the ONNX file's declared input (size, layout, 3 channels) and
/// returns the usable batch size (1 when the model's batch dimension is fixed).
fn check_onnx_signature(desc: &ModelDesc) -> Result<usize> {
    let sig = onnx::signature(&desc.model)?;
    let input = match &desc.input.name {
        Some(n) => sig.inputs.iter().find(|i| &i.name == n).ok_or_else(|| {
            let msg = format!("no input named `{n}` (inputs: {})", names(&sig.inputs));
            tensor::mismatch(desc, msg)
        })?,
        None => &sig.inputs[0],
    };
    if let Some(n) = &desc.output.name {
        if !sig.outputs.iter().any(|o| &o.name == n) {
            let msg = format!("no output named `{n}` (outputs: {})", names(&sig.outputs));
            return Err(tensor::mismatch(desc, msg));
        }
    }
    let Some(shape) = &input.shape else {
        return Ok(desc.input.batch);
    };
    check_input_shape(desc, &input.name, shape)?;
    Ok(match shape[0] {
        onnx::Dim::Fixed(_) => 1,
        onnx::Dim::Dynamic => desc.input.batch,
    })
}

/// The tensors' names, comma-separated.
fn names(tensors: &[onnx::TensorDecl]) -> String {
    let list: Vec<&str> = tensors.iter().map(|t| t.name.as_str()).collect();
    list.join(", ")
}

/// Checks the declared shape of input `name`: 4 dimensions, the fixed ones past the batch as
/// the description gives them.
fn check_input_shape(desc: &ModelDesc, name: &str, shape: &[onnx::Dim]) -> Result<()> {
    let want = tensor::input_shape(desc, 1);
    if shape.len() != 4 {
        let msg = format!("input `{name}` has {} dimensions, not 4", shape.len());
        return Err(tensor::mismatch(desc, msg));
    }
    let dims = match desc.input.layout {
        Layout::Nchw => ["batch", "channels", "height", "width"],
        Layout::Nhwc => ["batch", "height", "width", "channels"],
    };
    for k in 1..4 {
        if let onnx::Dim::Fixed(d) = shape[k] {
            if d != want[k] as i64 {
                let shown: Vec<String> = shape
                    .iter()
                    .map(|d| match d {
                        onnx::Dim::Fixed(v) => v.to_string(),
                        onnx::Dim::Dynamic => "?".into(),
                    })
                    .collect();
                return Err(tensor::mismatch(
                    desc,
                    format!(
                        "input `{}` is {} but the description gives {} {} for {:?} (want {:?})",
                        name,
                        shown.join("x"),
                        dims[k],
                        want[k],
                        desc.input.layout,
                        want
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Writes `mask` as `<dir>/<image_name>.png` (COLMAP's naming) atomically.
pub fn write_mask(dir: &Path, image_name: &str, mask: &Mat) -> Result<String> {
    let name = format!("{image_name}.png");
    let bytes = crate::encode::encode(mask, crate::manifest::Format::Png, 100)?;
    crate::fsutil::write_atomic(&dir.join(&name), &bytes)?;
    Ok(name)
}

/// What [`segment_file`] wrote.
pub struct SegmentReport {
    /// Fraction of the image's pixels the mask hides.
    pub hidden_fraction: f64,
    /// Network time for the image in milliseconds.
    pub network_ms: f64,
}

/// Segments one image file: writes its mask (PNG: hidden 0, kept 255, the image's size) to
/// `output` and, when asked, a colour preview of the classes to `overlay` (PNG or JPEG by its
/// extension). Outputs are checked first: never an input (the image, the description, the
/// network files it names), replaced only with `force`.
pub fn segment_file(
    settings: &MaskSettings,
    image_path: &Path,
    output: &Path,
    overlay: Option<&Path>,
    force: bool,
) -> Result<SegmentReport> {
    use crate::manifest::Format;
    let desc = ModelDesc::load(&settings.model)?;
    let mut inputs = crate::output::Inputs::none().with("image", image_path);
    inputs.extend(&desc.inputs);
    let _held = (
        crate::output::check_file(output, force, &inputs)?,
        (overlay.map(|o| crate::output::check_file(o, force, &inputs))).transpose()?,
    );
    if overlay.is_some_and(|o| crate::output::resolve(o) == crate::output::resolve(output)) {
        return Err(Error::param("overlay", "must differ from the mask output"));
    }
    let mut seg = Segmenter::new(settings)?;
    let image = opencv::imgcodecs::imread(
        image_path.to_str().unwrap_or_default(),
        opencv::imgcodecs::IMREAD_COLOR,
    )
    .map_err(|e| Error::input(image_path, e.message))?;
    if image.empty() {
        return Err(Error::input(image_path, "not a readable image"));
    }
    let maps = seg.classify(std::slice::from_ref(&image))?;
    let size = (image.cols() as u32, image.rows() as u32);
    let mask = seg.mask(&maps[0], size)?;
    crate::fsutil::write_atomic(output, &crate::encode::encode(&mask, Format::Png, 100)?)?;
    if let Some(o) = overlay {
        let ov = seg.overlay(&image, &maps[0])?;
        let png = o.extension().is_some_and(|e| e.eq_ignore_ascii_case("png"));
        let format = if png { Format::Png } else { Format::Jpg };
        crate::fsutil::write_atomic(o, &crate::encode::encode(&ov, format, 90)?)?;
    }
    let kept = opencv::core::count_non_zero(&mask).map_err(|e| Error::input(output, e.message))?;
    Ok(SegmentReport {
        hidden_fraction: 1.0 - kept as f64 / (f64::from(size.0) * f64::from(size.1)),
        network_ms: seg.ms_per_image().unwrap_or(0.0),
    })
}
