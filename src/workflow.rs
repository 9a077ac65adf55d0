//! Workflow files (TOML, `version = 1`): an ordered list of sampler steps, any number of
//! exports and of reconstruction loops (`[[reconstruct]]`), checked completely (file:line and key for every error) before any input is touched,
//! and turned into the same validated settings the `select` / `export` flags produce.

use crate::error::{Error, Result};
use crate::manifest::{ExportSettings, Format, MaskSettings, Resize, SegRuntime, ViewSettings};
use crate::names::Names;
use crate::output::Inputs;
use crate::params::{
    Backend, BackendChoice, Derotate, FarnebackParams, MovementRequest, Statistic,
};
use crate::project::Project;
use crate::sparse::{MapperKind, Mapping, Matcher};
use crate::steps::Step;
use crate::tomlfile::{self, TomlFile};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The workflow format version this build reads and writes.
pub const VERSION: u32 = 1;

/// `[analysis]`: how frames are analysed (shared by every sampler). Here and in the other
/// sections an absent key is `None`, which the TOML serializer leaves out (TOML has no null).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnalysisSection {
    /// `auto` (default), `gpu` or `opencv`.
    pub backend: Option<BackendChoice>,
    /// GPU adapter, part of its name.
    pub adapter: Option<String>,
    /// Width frames are scaled to for movement analysis.
    pub analysis_width: Option<u32>,
    /// Flow measured between frames this many apart (`--flow-stride`).
    pub flow_stride: Option<u32>,
    /// `median` or `trimmed-mean`.
    pub movement: Option<String>,
    /// Fraction trimmed from each end for `trimmed-mean`.
    pub trim: Option<f64>,
    /// Frame rate assumed for image folders.
    pub images_fps: Option<f64>,
    /// Analyse only the codec keyframes (`select --preview`).
    pub preview: Option<bool>,
    /// Subtract the camera rotation from the flow (`--derotate`).
    pub derotate: Option<bool>,
    /// Horizontal field of view in degrees for `derotate` (`--hfov`).
    pub hfov: Option<f64>,
    /// A telemetry file for every input (`--telemetry`), relative to the workflow file: a GPX
    /// track that covers the flights, each video placed in it by its creation time. Without it,
    /// each video's SRT sidecar (or the images' EXIF) is used.
    pub telemetry: Option<PathBuf>,
    /// Seconds added to a frame's timestamp to find it in the telemetry (`--telemetry-offset`).
    pub telemetry_offset: Option<f64>,
    /// Farnebäck parameters.
    pub farneback: Option<FarnebackSection>,
    /// How the inputs' frames map to directions (`--projection`): `pinhole` or `equirect`
    /// (360°: movement measured on horizon views with the sphere's rotation removed). Absent:
    /// from each video's spherical metadata, else pinhole.
    pub projection: Option<crate::equirect::Projection>,
}

/// `[analysis.farneback]`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FarnebackSection {
    /// Scale between pyramid levels, in (0, 1).
    pub pyr_scale: Option<f64>,
    /// Pyramid levels below full resolution.
    pub levels: Option<u32>,
    /// Averaging window size.
    pub winsize: Option<u32>,
    /// Iterations per level.
    pub iterations: Option<u32>,
    /// Polynomial expansion neighbourhood: 5 or 7.
    pub poly_n: Option<u32>,
    /// Polynomial expansion sigma.
    pub poly_sigma: Option<f64>,
    /// Gaussian window instead of a box.
    pub gaussian: Option<bool>,
}

/// `[export.masks]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Masks {
    /// Model description, relative to the workflow file.
    pub model: PathBuf,
    /// Classes to hide (default: the description's `hide` list).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub classes: Vec<String>,
    /// Grow the hidden area by this many pixels.
    pub dilate: Option<u32>,
    /// `opencv` or `ort`.
    pub backend: Option<SegRuntime>,
    /// Also write colour previews of the classes under `overlays/`.
    pub overlay: Option<bool>,
}

/// One `[[export]]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Export {
    /// Output sub-folder name (letters, digits, `-`, `_`, `.`).
    pub name: String,
    /// `jpg` or `png`.
    pub format: Option<Format>,
    /// JPEG quality, 1 to 100.
    pub quality: Option<u8>,
    /// `"1280x720"`.
    pub resize: Option<String>,
    /// Scale factor for the (cropped) frame.
    pub scale: Option<f64>,
    /// `"x,y,w,h"` in source pixels.
    pub crop: Option<String>,
    /// Segmentation masks for every exported image.
    pub masks: Option<Masks>,
    /// `false` is `export --no-geotag` (absent: on).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geotag: Option<bool>,
    /// 360° projects: the views to export, `cube`, `ring:N[,PITCH]` or `equirect` (`--views`).
    pub views: Option<String>,
    /// Field of view of every view in degrees (`--view-fov`); needs `views`.
    pub view_fov: Option<f64>,
    /// Width = height of every view in pixels (`--view-size`); needs `views`.
    pub view_size: Option<u32>,
    /// Radius in degrees of the cap around the nadir the masks hide (`--mask-nadir`); needs
    /// `views`.
    pub mask_nadir: Option<f64>,
    /// `bilinear` or `bicubic` (`--view-interp`); needs `views`.
    pub view_interp: Option<crate::equirect::Interp>,
}

/// The `[[export]]` keys that only go with `views`.
const VIEW_KEYS: [&str; 4] = ["view_fov", "view_size", "mask_nadir", "view_interp"];

impl Export {
    /// The view keys given (of [`VIEW_KEYS`]).
    fn view_keys(&self) -> Vec<&'static str> {
        let given = [
            self.view_fov.is_some(),
            self.view_size.is_some(),
            self.mask_nadir.is_some(),
            self.view_interp.is_some(),
        ];
        (VIEW_KEYS.iter().zip(given))
            .filter(|(_, g)| *g)
            .map(|(k, _)| *k)
            .collect()
    }

    /// The view settings of the table, checked as the `export` flags are (their defaults for
    /// what is not given); errors name the flag.
    fn view_settings(&self) -> Result<Option<ViewSettings>> {
        let Some(set) = &self.views else {
            return Ok(None);
        };
        ViewSettings::from_parts(
            set,
            self.view_fov.unwrap_or(crate::manifest::DEFAULT_VIEW_FOV),
            self.view_size.unwrap_or(crate::manifest::DEFAULT_VIEW_SIZE),
            self.mask_nadir,
            self.view_interp
                .unwrap_or(crate::equirect::Interp::Bilinear),
        )
        .map(Some)
    }
}

/// `max_added` of a `[[reconstruct]]`: a frame count (`40`) or a percentage (`"50%"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(
    untagged,
    expecting = "must be a frame count (`40`) or a percentage (`\"50%\"`)"
)]
pub enum MaxAdded {
    /// At most this many frames.
    Frames(usize),
    /// As `--max-added`: `"40"` or `"50%"`.
    Text(String),
}

/// One `[[reconstruct]]`: `keyframer reconstruct` on the selection, its keys the flags of the
/// same name (absent: the flag's default).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Reconstruct {
    /// Output sub-folder name (default `reconstruct`).
    pub name: Option<String>,
    /// Rounds of COLMAP at most.
    pub max_rounds: Option<usize>,
    /// Frames the loop may add in all.
    pub max_added: Option<MaxAdded>,
    /// Fewest 3D points consecutive keyframes must share.
    pub min_shared: Option<usize>,
    /// Fewest inlier matches of consecutive keyframes' two-view geometry.
    pub min_inliers: Option<usize>,
    /// `incremental` or `global`.
    pub mapper: Option<MapperKind>,
    /// `fresh` or `continue`.
    pub mapping: Option<Mapping>,
    /// `auto`, `colmap` or `pycolmap`.
    pub engine: Option<crate::sparse::Engine>,
    /// `sequential` or `exhaustive`.
    pub matcher: Option<Matcher>,
    /// Sequential matching: following images each image is matched with.
    pub overlap: Option<u32>,
    /// COLMAP camera model.
    pub camera_model: Option<String>,
    /// Known intrinsics, comma-separated in COLMAP's order.
    pub camera_params: Option<String>,
    /// Maximum SIFT features per image.
    pub max_features: Option<u32>,
    /// Extra mapper options `KEY=VALUE`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub mapper_option: Vec<String>,
    /// `"1280x720"`: size of the exported images.
    pub resize: Option<String>,
    /// Scale factor of the exported images.
    pub scale: Option<f64>,
    /// JPEG quality, 1 to 100.
    pub quality: Option<u8>,
    /// Segmentation masks for every exported image (passed to COLMAP).
    pub masks: Option<Masks>,
}

/// The folder of a `[[reconstruct]]` without a `name`.
pub const RECONSTRUCT_NAME: &str = "reconstruct";

impl Reconstruct {
    /// Its output sub-folder name.
    pub fn folder(&self) -> &str {
        self.name.as_deref().unwrap_or(RECONSTRUCT_NAME)
    }
}

/// A workflow's content.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkflowFile {
    /// Format version; must be [`VERSION`].
    pub version: u32,
    /// `[analysis]`.
    pub analysis: Option<AnalysisSection>,
    /// `[[sample]]` steps in order.
    pub sample: Vec<Step>,
    /// `[[export]]`s.
    pub export: Vec<Export>,
    /// `[[reconstruct]]`s, run after the exports.
    pub reconstruct: Vec<Reconstruct>,
}

/// The file as written: sample steps are tables with a `plugin` key.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    version: u32,
    analysis: Option<AnalysisSection>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    sample: Vec<toml::Table>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    export: Vec<Export>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    reconstruct: Vec<Reconstruct>,
}

/// `{plugin = "fps", fps = 1.0}` -> `Step::Fps`, errors naming `sample[i].<key>`.
fn sample_from_table(file: &TomlFile<RawFile>, i: usize, table: &toml::Table) -> Result<Step> {
    let mut rest = table.clone();
    let plugin = match rest.remove("plugin") {
        Some(toml::Value::String(p)) => p,
        Some(_) => return Err(file.error(&format!("sample[{i}].plugin"), "must be a string")),
        None => return Err(file.error(&format!("sample[{i}]"), "missing field `plugin`")),
    };
    let mut wrapped = toml::Table::new();
    wrapped.insert(plugin, toml::Value::Table(rest));
    serde_path_to_error::deserialize::<_, Step>(toml::Value::Table(wrapped)).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner().to_string();
        let msg = inner.lines().next().unwrap_or("").trim().to_string();
        // The first segment is the plugin id itself.
        let keys: Vec<&str> = path.split('.').filter(|k| !k.is_empty()).skip(1).collect();
        let field = if !keys.is_empty() {
            format!("sample[{i}].{}", keys.join("."))
        } else if msg.contains("unknown variant") {
            format!("sample[{i}].plugin")
        } else {
            format!("sample[{i}]")
        };
        file.error(&field, msg)
    })
}

/// `Step::Fps` -> `{plugin = "fps", fps = 1.0}`.
fn sample_to_table(s: &Step) -> Result<toml::Table> {
    let v = toml::Value::try_from(s).map_err(|e| Error::param("sample", e.to_string()))?;
    let mut out = toml::Table::new();
    out.insert("plugin".into(), toml::Value::String(s.id().into()));
    if let toml::Value::Table(t) = v {
        for (_, inner) in t {
            if let toml::Value::Table(fields) = inner {
                out.extend(fields);
            }
        }
    }
    Ok(out)
}

/// A loaded, fully checked workflow.
#[derive(Debug, Clone)]
pub struct Workflow {
    /// Where it was read from.
    pub path: PathBuf,
    /// The parsed file.
    pub file: WorkflowFile,
    /// FNV-1a hash of the file's text and its steps' files (`geo-area`): a changed workflow
    /// redoes finished inputs.
    pub hash: u64,
    /// How movement is measured (from `[analysis]`, defaults filled in).
    pub movement: MovementRequest,
    /// `[analysis]` backend.
    pub backend: BackendChoice,
    /// Each `[[export]]`: its folder name and checked settings.
    pub exports: Vec<(String, ExportSettings)>,
    /// Each `[[reconstruct]]`: its folder name and checked options.
    pub reconstructs: Vec<(String, crate::sparse::Options)>,
    /// The files it names (telemetry, mask model descriptions and their files), which running it
    /// reads; the workflow file itself is not among them.
    pub inputs: Inputs,
    /// The file's text as read (errors found while running point at its lines).
    text: String,
}

impl Workflow {
    /// Reads and checks a workflow: syntax, types, unknown keys and plugins, parameter values,
    /// step order, export names and mask models. Nothing else is touched.
    pub fn load(path: &Path) -> Result<Workflow> {
        let text = crate::output::read_text(path)?;
        Self::from_text(path, text)
    }

    /// As [`Workflow::load`], for `text` as if read from `path` (which is not touched; mask
    /// models are resolved against its folder): checks a workflow before it is written.
    pub fn from_text(path: &Path, text: String) -> Result<Workflow> {
        let file = tomlfile::parse::<RawFile>(path, "workflow", text)?;
        let raw = &file.value;
        if raw.version != VERSION {
            let v = raw.version;
            let msg = format!("version {v} is not supported (this build reads {VERSION})");
            return Err(file.error("version", msg));
        }
        let mut sample = raw
            .sample
            .iter()
            .enumerate()
            .map(|(i, t)| sample_from_table(&file, i, t))
            .collect::<Result<Vec<_>>>()?;
        let dir = file.path().parent().unwrap_or(Path::new("."));
        sample.iter_mut().for_each(|s| s.resolve_files(dir));
        let content = WorkflowFile {
            version: raw.version,
            analysis: raw.analysis.clone(),
            sample,
            export: raw.export.clone(),
            reconstruct: raw.reconstruct.clone(),
        };
        let w = &content;
        check_relations(&file, w)?;
        check_steps(&file, &w.sample)?;
        let an = w.analysis.clone().unwrap_or_default();
        let movement = movement_request(&an)
            .and_then(|m| {
                let offset = an.telemetry_offset.unwrap_or(0.0);
                crate::params::check_analysis(&m, an.images_fps, offset).map(|()| m)
            })
            .map_err(|e| locate(&file, e))?;
        let mut inputs = Inputs::none();
        // The steps' files count as the workflow's text: a changed area redoes finished inputs.
        let mut hashed = file.text().as_bytes().to_vec();
        for (i, step) in w.sample.iter().enumerate() {
            for (key, f) in step.files() {
                let bad = |e: Error| file.error(&format!("sample[{i}].{key}"), e.to_string());
                step.check_files().map_err(bad)?;
                hashed.extend(std::fs::read(f).map_err(|e| bad(Error::io(f, e)))?);
                inputs.add(Step::file_what(key), f);
            }
        }
        if let Some(t) = &an.telemetry {
            if !dir.join(t).is_file() {
                let msg = format!("{}: no such telemetry file", dir.join(t).display());
                return Err(file.error("analysis.telemetry", msg));
            }
            inputs.add("telemetry", dir.join(t));
        }
        let mut exports = Vec::new();
        for (i, e) in w.export.iter().enumerate() {
            let settings = export_settings(&file, w, i, e)?;
            check_masks(&file, &format!("export[{i}]"), &settings, &mut inputs)?;
            exports.push((e.name.clone(), settings));
        }
        let mut reconstructs = Vec::new();
        for (i, r) in w.reconstruct.iter().enumerate() {
            let options = reconstruct_options(&file, w, i, r)?;
            check_masks(
                &file,
                &format!("reconstruct[{i}]"),
                &options.export,
                &mut inputs,
            )?;
            reconstructs.push((r.folder().to_string(), options));
        }
        Ok(Workflow {
            path: path.to_path_buf(),
            file: content.clone(),
            hash: crate::output::fnv1a64(&hashed),
            movement,
            backend: an.backend.unwrap_or_default(),
            exports,
            reconstructs,
            inputs,
            text: file.text().to_string(),
        })
    }

    /// A refusal of `[[export]]` `i`'s settings found while running (a rig export of an input
    /// whose frames turn out to be pinhole ones), put on its key (`export[i].views`) in the workflow file;
    /// other errors as they are.
    pub fn export_error(&self, i: usize, e: Error) -> Error {
        match e {
            Error::Param { name, msg } => {
                let field = format!("export[{i}].{}", flag_key(&name));
                crate::tomlfile::error_in(&self.path, "workflow", &self.text, &field, msg)
            }
            other => other,
        }
    }
}

/// `--pyr-scale`, `pyr_scale` -> `pyr_scale`.
fn flag_key(flag: &str) -> String {
    flag.trim_start_matches("--").replace('-', "_")
}

/// Puts a parameter error of `[analysis]` (named by its parameter key) on the
/// key it came from.
fn locate(file: &TomlFile<RawFile>, e: Error) -> Error {
    match e {
        Error::Param { name, msg } => {
            let key = flag_key(&name);
            let table = if FARNEBACK_KEYS.contains(&key.as_str()) {
                "analysis.farneback"
            } else {
                "analysis"
            };
            file.error(&format!("{table}.{key}"), msg)
        }
        other => other,
    }
}

/// The keys of `[analysis.farneback]`.
const FARNEBACK_KEYS: [&str; 7] = [
    "pyr_scale",
    "levels",
    "winsize",
    "iterations",
    "poly_n",
    "poly_sigma",
    "gaussian",
];

/// Every step's parameters and the chain's order, errors on `sample[i].<key>`.
fn check_steps(file: &TomlFile<RawFile>, steps: &[Step]) -> Result<()> {
    crate::steps::check_order(steps)
        .map_err(|(i, msg)| file.error(&format!("sample[{i}].plugin"), msg))?;
    for (i, step) in steps.iter().enumerate() {
        step.validate()
            .map_err(|e| file.error(&format!("sample[{i}].{}", e.key), e.msg))?;
    }
    Ok(())
}

/// `[analysis]` as a movement request: the flags' defaults for what is not given.
fn movement_request(an: &AnalysisSection) -> Result<MovementRequest> {
    let d = FarnebackParams::default();
    let fb = an.farneback.clone().unwrap_or_default();
    let statistic = match an.movement.as_deref() {
        Some(name) => Statistic::from_name(name).map_err(|m| Error::param("movement", m))?,
        None => Statistic::Median,
    };
    let request = MovementRequest {
        farneback: FarnebackParams {
            pyr_scale: fb.pyr_scale.unwrap_or(d.pyr_scale),
            levels: fb.levels.unwrap_or(d.levels),
            winsize: fb.winsize.unwrap_or(d.winsize),
            iterations: fb.iterations.unwrap_or(d.iterations),
            poly_n: fb.poly_n.unwrap_or(d.poly_n),
            poly_sigma: fb.poly_sigma.unwrap_or(d.poly_sigma),
            gaussian: fb.gaussian.unwrap_or(d.gaussian),
        },
        statistic: statistic.with_trim(an.trim.unwrap_or(crate::steps::defaults::TRIM)),
        analysis_width: an
            .analysis_width
            .unwrap_or(crate::steps::defaults::ANALYSIS_WIDTH),
        stride: an
            .flow_stride
            .unwrap_or(crate::steps::defaults::FLOW_STRIDE),
        derotate: (an.derotate == Some(true)).then(|| Derotate {
            hfov_deg: an.hfov.unwrap_or(Derotate::DEFAULT_HFOV_DEG),
        }),
        sphere: None,
    };
    Ok(request)
}

/// Relations between keys that clap would report without naming the key that caused them.
fn check_relations(file: &TomlFile<RawFile>, w: &WorkflowFile) -> Result<()> {
    if let Some(an) = &w.analysis {
        if an.hfov.is_some() && an.derotate != Some(true) {
            return Err(file.error(
                "analysis.hfov",
                "the field of view is only used with `derotate = true`: add it, or remove `hfov`",
            ));
        }
    }
    let sizes = (w.export.iter().map(|e| ("export", &e.resize, e.scale))).chain(
        w.reconstruct
            .iter()
            .map(|r| ("reconstruct", &r.resize, r.scale)),
    );
    let mut counts = std::collections::BTreeMap::new();
    for (table, resize, scale) in sizes {
        let i = counts.entry(table).or_insert(0usize);
        if resize.is_some() && scale.is_some() {
            return Err(file.error(
                &format!("{table}[{i}].scale"),
                "give either `resize` or `scale`, not both",
            ));
        }
        *i += 1;
    }
    Ok(())
}

/// Names `keyframer run` uses in each input's folder, which an export may not take.
pub const RESERVED_NAMES: [&str; 9] = [
    "project.json",
    "project.json.partial",
    crate::output::DONE,
    crate::output::MARKER,
    crate::manifest::MANIFEST,
    crate::manifest::IMAGE_DIR,
    crate::manifest::MASK_DIR,
    crate::manifest::OVERLAY_DIR,
    "colmap",
];

fn valid_name(n: &str) -> bool {
    !n.is_empty()
        && n != "."
        && n != ".."
        && n.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
}

/// Refuses `name`, the output folder of `at` (`export[i]`), when it is no plain folder name,
/// is reserved, or is taken by one of `earlier` (the folders of the tables before it).
fn check_name(file: &TomlFile<RawFile>, at: &str, name: &str, earlier: &[&str]) -> Result<()> {
    let refusal = if !valid_name(name) {
        Some("is not a plain folder name (letters, digits, - _ .)".to_string())
    } else if earlier.contains(&name) {
        Some("is used by an earlier export or reconstruct".to_string())
    } else if RESERVED_NAMES.contains(&name) || name.starts_with('.') {
        Some(format!(
            "is reserved: `keyframer run` keeps its own files under these names in each input's folder ({}, or any name starting with `.`)",
            RESERVED_NAMES.join(", ")
        ))
    } else {
        None
    };
    match refusal {
        Some(why) => Err(file.error(&format!("{at}.name"), format!("`{name}` {why}"))),
        None => Ok(()),
    }
}

/// `[masks]` of a table as settings (the model relative to the workflow file).
fn mask_settings(file: &TomlFile<RawFile>, m: &Option<Masks>) -> Option<MaskSettings> {
    m.as_ref().map(|m| {
        let dir = file.path().parent().unwrap_or(Path::new("."));
        MaskSettings {
            model: crate::fsutil::absolute(&dir.join(&m.model)),
            classes: m.classes.clone(),
            dilate: m.dilate.unwrap_or(0),
            backend: m.backend.unwrap_or_default(),
            overlay: m.overlay == Some(true),
        }
    })
}

/// The mask model of the table `at` (`export[i]`) loads and knows the classes; its files are
/// added to `inputs`.
fn check_masks(
    file: &TomlFile<RawFile>,
    at: &str,
    settings: &ExportSettings,
    inputs: &mut Inputs,
) -> Result<()> {
    if let Some(m) = &settings.masks {
        let desc = crate::model_desc::ModelDesc::load(&m.model)
            .map_err(|e| file.error(&format!("{at}.masks.model"), e.to_string()))?;
        desc.class_ids(&m.classes)
            .map_err(|e| file.error(&format!("{at}.masks.classes"), e.into_msg()))?;
        inputs.extend(&desc.inputs);
    }
    Ok(())
}

/// `[[reconstruct]]` `i` as the loop's checked options (the flags' defaults for what is not
/// given; checked by [`crate::sparse::check`], as the flags are), errors on
/// `reconstruct[i].<key>`.
fn reconstruct_options(
    file: &TomlFile<RawFile>,
    w: &WorkflowFile,
    i: usize,
    r: &Reconstruct,
) -> Result<crate::sparse::Options> {
    use crate::sparse::{defaults, Budget, Limits, Options};
    let at = |k: &str| format!("reconstruct[{i}].{k}");
    let earlier: Vec<&str> = (w.export.iter().map(|e| e.name.as_str()))
        .chain(w.reconstruct[..i].iter().map(Reconstruct::folder))
        .collect();
    check_name(file, &format!("reconstruct[{i}]"), r.folder(), &earlier)?;
    let located = |err: Error| match err {
        Error::Param { name, msg } => file.error(&at(&flag_key(&name)), msg),
        other => other,
    };
    let max_added = match &r.max_added {
        None => Budget::parse(defaults::MAX_ADDED),
        Some(MaxAdded::Frames(n)) => Ok(Budget::Frames(*n)),
        Some(MaxAdded::Text(t)) => Budget::parse(t),
    }
    .map_err(located)?;
    let export = ExportSettings::from_parts(
        r.resize.as_deref(),
        r.scale,
        None,
        None,
        r.quality.unwrap_or(crate::manifest::DEFAULT_QUALITY),
        mask_settings(file, &r.masks),
        true,
    )
    .map_err(located)?;
    let options = Options {
        max_rounds: r.max_rounds.unwrap_or(defaults::MAX_ROUNDS),
        max_added,
        limits: Limits {
            min_shared: r.min_shared.unwrap_or(defaults::MIN_SHARED),
            min_inliers: r.min_inliers.unwrap_or(defaults::MIN_INLIERS),
        },
        colmap: crate::sparse::SparseOptions {
            matcher: r.matcher.unwrap_or(crate::sparse::defaults::MATCHER),
            overlap: r.overlap.unwrap_or(crate::sparse::defaults::OVERLAP),
            camera_model: (r.camera_model.clone())
                .unwrap_or_else(|| crate::sparse::defaults::CAMERA_MODEL.into()),
            camera_params: r.camera_params.clone(),
            max_features: r.max_features,
            mapper_option: r.mapper_option.clone(),
        },
        mapper: r.mapper.unwrap_or(defaults::MAPPER),
        mapping: r.mapping.unwrap_or(defaults::MAPPING),
        engine: r.engine.unwrap_or_default(),
        export,
    };
    crate::sparse::check(&options).map_err(located)?;
    Ok(options)
}

/// The `[[reconstruct]]` that repeats a loop run with `o`.
fn reconstruct_table(o: &crate::sparse::Options) -> Reconstruct {
    use crate::sparse::Budget;
    let e = &o.export;
    let (resize, scale) = resize_keys(e.resize);
    Reconstruct {
        name: None,
        max_rounds: Some(o.max_rounds),
        max_added: Some(match o.max_added {
            Budget::Frames(n) => MaxAdded::Frames(n),
            Budget::Percent(p) => MaxAdded::Text(format!("{p}%")),
        }),
        min_shared: Some(o.limits.min_shared),
        min_inliers: Some(o.limits.min_inliers),
        mapper: Some(o.mapper),
        mapping: Some(o.mapping),
        engine: Some(o.engine),
        matcher: Some(o.colmap.matcher),
        overlap: Some(o.colmap.overlap),
        camera_model: Some(o.colmap.camera_model.clone()),
        camera_params: o.colmap.camera_params.clone(),
        max_features: o.colmap.max_features,
        mapper_option: o.colmap.mapper_option.clone(),
        resize,
        scale,
        quality: Some(e.quality),
        masks: e.masks.as_ref().map(masks_table),
    }
}

/// `resize` / `scale` keys of a resize.
fn resize_keys(r: Option<Resize>) -> (Option<String>, Option<f64>) {
    match r {
        Some(Resize::Size { width, height }) => (Some(format!("{width}x{height}")), None),
        Some(Resize::Scale(f)) => (None, Some(f)),
        None => (None, None),
    }
}

/// The `[masks]` table of mask settings (the model's path made absolute).
fn masks_table(mk: &MaskSettings) -> Masks {
    Masks {
        model: crate::fsutil::absolute(&mk.model),
        classes: mk.classes.clone(),
        dilate: Some(mk.dilate),
        backend: Some(mk.backend),
        overlay: Some(mk.overlay),
    }
}

/// `[[export]]` `i` as checked settings, errors on `export[i].<key>`.
fn export_settings(
    file: &TomlFile<RawFile>,
    w: &WorkflowFile,
    i: usize,
    e: &Export,
) -> Result<ExportSettings> {
    let at = |k: &str| format!("export[{i}].{k}");
    let earlier: Vec<&str> = w.export[..i].iter().map(|x| x.name.as_str()).collect();
    check_name(file, &format!("export[{i}]"), &e.name, &earlier)?;
    let masks = mask_settings(file, &e.masks);
    // The settings name their parameters by key (`resize`, `crop`) or flag (`--view-fov`).
    let located = |err: Error| match err {
        Error::Param { name, msg } => file.error(&at(&flag_key(&name)), msg),
        other => other,
    };
    let mut settings = ExportSettings::from_parts(
        e.resize.as_deref(),
        e.scale,
        e.crop.as_deref(),
        e.format,
        e.quality.unwrap_or(crate::manifest::DEFAULT_QUALITY),
        masks,
        e.geotag != Some(false),
    )
    .map_err(located)?;
    if e.views.is_none() {
        if let Some(key) = e.view_keys().first() {
            let msg =
                "only goes with `views` (as its flag with --views): add `views`, or remove it";
            return Err(file.error(&at(key), msg));
        }
    }
    settings.views = e.view_settings().map_err(located)?;
    settings.check_whole_frame().map_err(located)?;
    // A project analysed as pinhole is refused as `export --views` refuses it.
    let projection = w.analysis.as_ref().and_then(|a| a.projection);
    if let (Some(p), Some(_)) = (projection, &settings.views) {
        ViewSettings::check_projection(p).map_err(located)?;
    }
    Ok(settings)
}

/// `[analysis]` keys that reproduce the movement measure `req`.
fn record_movement(analysis: &mut AnalysisSection, req: &MovementRequest) {
    analysis.analysis_width = Some(req.analysis_width);
    analysis.flow_stride = Some(req.stride);
    let (name, trim) = req.statistic.to_flag();
    analysis.movement = Some(name.into());
    analysis.trim = trim;
    if let Some(d) = req.derotate {
        analysis.derotate = Some(true);
        analysis.hfov = Some(d.hfov_deg);
    }
    let f = req.farneback;
    analysis.farneback = Some(FarnebackSection {
        pyr_scale: Some(f.pyr_scale),
        levels: Some(f.levels),
        winsize: Some(f.winsize),
        iterations: Some(f.iterations),
        poly_n: Some(f.poly_n),
        poly_sigma: Some(f.poly_sigma),
        gaussian: Some(f.gaussian),
    });
}

/// The workflow that reproduces a project's selection (its history), plus exports like the ones
/// whose folders are given (read from their manifests).
pub fn from_project(project: &Path, exports: &[PathBuf]) -> Result<String> {
    from_loaded(&Project::load(project)?, project, exports)
}

/// [`from_project`] for a project already in memory (`review` saves the workflow of an edit not
/// yet written); `project` is where it lives (relative paths in it are relative to its folder).
pub fn from_loaded(p: &Project, project: &Path, exports: &[PathBuf]) -> Result<String> {
    let bad = |msg: String| Error::file(project, None, "project file", "history", msg);
    let mut analysis = AnalysisSection {
        projection: (!p.projection.is_pinhole()).then_some(p.projection),
        ..AnalysisSection::default()
    };
    let mut sample = Vec::new();
    let mut reconstruct = None;
    for (k, entry) in p.history.iter().enumerate() {
        let applied = &entry.applied;
        let (backend, movement) = applied.analysis();
        if let Some(req) = movement {
            record_movement(&mut analysis, &req);
        }
        if let Some(b) = backend {
            analysis.backend = Some(match b {
                Backend::Gpu => BackendChoice::Gpu,
                Backend::Opencv => BackendChoice::Opencv,
            });
        }
        match applied.step() {
            Some(Step::Boundaries {
                start: None,
                end: None,
            }) => {}
            Some(step) => sample.push((k, step)),
            None => match applied {
                crate::steps::Applied::Reconstruct { settings, .. } => {
                    if reconstruct.is_some() {
                        log::warn!(
                            "history[{k}] is a second reconstruct step: the workflow's [[reconstruct]] repeats the last one, on the selection"
                        );
                    }
                    reconstruct = Some(match settings {
                        Some(o) => reconstruct_table(o),
                        None => {
                            log::warn!(
                                "history[{k}] (reconstruct) records no options (an earlier keyframer): the workflow's [[reconstruct]] takes the defaults"
                            );
                            Reconstruct::default()
                        }
                    });
                }
                _ => analysis.preview = Some(true),
            },
        }
    }
    if p.input.kind == crate::source::SourceKind::Images {
        // The rate given with --images-fps is the folder's rate in the metadata.
        analysis.images_fps = p.metadata.fps;
    }
    if let Some(tel) = &p.cache.telemetry {
        analysis.telemetry_offset = (tel.source.offset_s != 0.0).then_some(tel.source.offset_s);
        // A GPX track can serve other flights; an SRT belongs to its video (found beside each).
        if tel.source.kind == crate::source::telemetry::TelemetryKind::Gpx {
            let dir = project.parent().unwrap_or(Path::new("."));
            analysis.telemetry = Some(crate::fsutil::absolute(&dir.join(&tel.source.path)));
        }
    }
    let export = exports
        .iter()
        .map(|dir| export_from_folder(dir))
        .collect::<Result<Vec<_>>>()?;
    let wf = RawFile {
        version: VERSION,
        analysis: (analysis != AnalysisSection::default()).then_some(analysis),
        sample: sample
            .iter()
            .map(|(k, s)| {
                sample_to_table(s).map_err(|e| Error::file(project, None, "project file", format!("history[{k}].params"), format!(
                        "cannot be written as a workflow step ({}; TOML integers go up to 2^63 - 1)",
                        e.into_msg()
                    )))
            })
            .collect::<Result<Vec<_>>>()?,
        export,
        reconstruct: reconstruct.into_iter().collect(),
    };
    let body = toml::to_string(&wf).map_err(|e| bad(e.to_string()))?;
    Ok(format!(
        "# keyframer workflow saved from {} (thresholds are the values the project used).\n\
         # Run it with: keyframer run THIS.toml INPUT... --out DIR\n{body}",
        project.display()
    ))
}

/// The `[[export]]` that repeats the export in `dir` (read from its manifest).
fn export_from_folder(dir: &Path) -> Result<Export> {
    let m =
        crate::manifest::read_manifest(&dir.join(crate::manifest::MANIFEST)).ok_or_else(|| {
            Error::input(
                dir,
                "no readable manifest.json: not a keyframer export folder",
            )
        })?;
    let s = &m.settings;
    let (resize, scale) = resize_keys(s.resize);
    Ok(Export {
        name: dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "export".into()),
        format: s.format,
        quality: Some(s.quality),
        resize,
        scale,
        crop: s
            .crop
            .map(|c| format!("{},{},{},{}", c.x, c.y, c.width, c.height)),
        masks: s.masks.as_ref().map(masks_table),
        geotag: (!s.geotag).then_some(false),
        views: s.views.as_ref().map(|v| v.set.clone()),
        view_fov: s.views.as_ref().map(|v| v.fov_deg),
        view_size: s.views.as_ref().map(|v| v.size),
        mask_nadir: s.views.as_ref().and_then(|v| v.mask_nadir_deg),
        view_interp: s.views.as_ref().map(|v| v.interp),
    })
}

/// `workflow save`: the workflow of [`from_project`], checked to load (in memory) before it is
/// written atomically to `output`, which may be none of what the save reads (the project, its
/// input, the exports' manifests) and is replaced only with `force`. Returns `output`.
pub fn save(project: &Path, exports: &[PathBuf], output: &Path, force: bool) -> Result<PathBuf> {
    save_loaded(&Project::load(project)?, project, exports, output, force)
}

/// [`save`] for a project already in memory, living at `project`.
pub fn save_loaded(
    p: &Project,
    project: &Path,
    exports: &[PathBuf],
    output: &Path,
    force: bool,
) -> Result<PathBuf> {
    let text = from_loaded(p, project, exports)?;
    let wf = Workflow::from_text(output, text.clone())
        .map_err(|e| Error::input(project, format!("cannot be saved as a workflow: {e}")))?;
    // What the save reads: the project, its input, the exports, and the files the workflow names
    // (the project's telemetry, the exports' mask models).
    let mut inputs = Inputs::none()
        .with("project", project)
        .with("the project's input", p.input_path(project));
    for e in exports {
        crate::manifest::add_export(&mut inputs, e);
    }
    inputs.extend(&wf.inputs);
    let _held = crate::output::check_file(output, force, &inputs)?;
    crate::fsutil::write_atomic(output, text.as_bytes())?;
    Ok(output.to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `[[reconstruct]]` written from a loop's options reads back as the same options.
    #[test]
    fn a_reconstruct_table_round_trips_the_loops_options() {
        let text = "version = 1\n[[reconstruct]]\nname = \"rec\"\nmax_added = \"50%\"\n\
                    mapping = \"continue\"\ncamera_model = \"PINHOLE\"\n\
                    camera_params = \"224,224,160,90\"\nmax_features = 1024\n\
                    mapper_option = [\"init_min_tri_angle=8\"]\nscale = 0.5\nquality = 80\n";
        let w = Workflow::from_text(Path::new("/tmp/w.toml"), text.into()).unwrap();
        let (name, o) = &w.reconstructs[0];
        assert_eq!(name, "rec");
        assert_eq!(o.max_added, crate::sparse::Budget::Percent(50.0));
        assert_eq!(o.mapping, Mapping::Continue);
        assert_eq!(o.max_rounds, crate::sparse::defaults::MAX_ROUNDS);
        assert_eq!(o.colmap.matcher, crate::sparse::defaults::MATCHER);
        assert_eq!(o.export.quality, 80);
        let raw = RawFile {
            version: VERSION,
            analysis: None,
            sample: Vec::new(),
            export: Vec::new(),
            reconstruct: vec![reconstruct_table(o)],
        };
        let saved = toml::to_string(&raw).unwrap();
        let again = Workflow::from_text(Path::new("/tmp/w.toml"), saved.clone()).unwrap();
        assert_eq!(&again.reconstructs[0].1, o, "{saved}");
        assert_eq!(again.reconstructs[0].0, RECONSTRUCT_NAME);
        // A frame count is written as an integer and read back.
        let mut counted = o.clone();
        counted.max_added = crate::sparse::Budget::Frames(7);
        let raw = RawFile {
            reconstruct: vec![reconstruct_table(&counted)],
            ..raw
        };
        let saved = toml::to_string(&raw).unwrap();
        assert!(saved.contains("max_added = 7"), "{saved}");
        let again = Workflow::from_text(Path::new("/tmp/w.toml"), saved).unwrap();
        assert_eq!(again.reconstructs[0].1, counted);
    }
}
