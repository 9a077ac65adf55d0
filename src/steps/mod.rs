//! The typed pipeline description and the samplers it runs. A [`Step`] is one sampler with its
//! parameters as a user gives them (flags, built from each step's [`Flag`]s, and a workflow's
//! `[[sample]]` tables both become `Vec<Step>`); an [`Applied`] step is what `select` ran
//! (thresholds resolved, the backend and movement measure that fed it): a project's history
//! holds it, `workflow save` writes it back as steps. Each step's module holds its flags, its
//! pure function over candidate frames and per-frame numbers (samplers never touch pixels) and
//! the series the report draws. Adding a sampler: its module, its variants here, its test.

pub mod auto;
pub mod blur;
mod boundaries;
mod every_nth;
pub mod flags;
pub mod footprint;
mod fps;
pub mod geo_area;
pub mod geo_distance;
mod history;
mod manual;
pub mod similarity;
pub mod spacing;
pub mod stationary;
mod values;

pub use blur::{blur, BlurMode, BlurParams};
pub use boundaries::{Bound, Boundaries};
pub use every_nth::every_nth;
pub use flags::{Flag, FlagValues};
pub use fps::fps;
pub use history::{Recorded, Stored};
pub use manual::manual;
pub use spacing::{spacing, spacing_for_count};
pub use stationary::StationarySampler;
pub use values::{BoundArg, NumOrText, Threshold};

use crate::error::{Error, Result};
use crate::numbers::positive;
use crate::params::{Backend, Metric, MovementRequest, StationaryRequest};
use crate::source::telemetry::Position;
use serde::{Deserialize, Serialize};

/// Defaults of the optional step parameters (the flags' defaults too).
pub mod defaults {
    /// Frames after which the stationary reference is re-anchored.
    pub const RESET_DELTA: usize = 15;
    /// Half-width of the blur sampler's window in frames.
    pub const BLUR_WINDOW: usize = 10;
    /// The blur filter keeps a frame whose score is at least this times the window mean.
    pub const BLUR_RATIO: f64 = 0.8;
    /// Width of the analysis resolution for flow (from `bench pipeline --tradeoffs`).
    pub const ANALYSIS_WIDTH: u32 = 320;
    /// Flow is measured between frames this many apart.
    pub const FLOW_STRIDE: u32 = 2;
    /// Fraction dropped at each end by the trimmed-mean statistic.
    pub const TRIM: f64 = crate::params::Statistic::DEFAULT_TRIM;

    /// The movement `select` measures when no movement flag is given.
    pub fn movement() -> crate::params::MovementRequest {
        crate::params::MovementRequest {
            farneback: crate::params::FarnebackParams::default(),
            statistic: crate::params::Statistic::Median,
            analysis_width: ANALYSIS_WIDTH,
            stride: FLOW_STRIDE,
            derotate: None,
            sphere: None,
        }
    }
}

/// What the steps read besides the candidates: the input's frames and the series `select`
/// measured or took from the project's cache.
#[derive(Debug, Clone, Default)]
pub struct Inputs<'a> {
    /// Frames in the input.
    pub frame_count: usize,
    /// Per-frame timestamps, when known.
    pub timestamps_s: Option<&'a [f64]>,
    /// First and last candidate of the boundaries.
    pub range: (usize, usize),
    /// Sharpness scores per metric, with the backend that measured them.
    pub sharpness: Vec<(Metric, &'a [f64], Backend)>,
    /// How movement is measured.
    pub movement_request: Option<MovementRequest>,
    /// Movement per frame and its backend.
    pub movement: Option<(&'a [f64], Backend)>,
    /// The stationary run (threshold resolved), its keyframes and backend.
    pub stationary: Option<(StationaryRequest, &'a [usize], Backend)>,
    /// Whether the stationary threshold was proposed from a sample (`auto`).
    pub stationary_auto: bool,
    /// The spacing threshold `auto` was resolved to.
    pub spacing_px: Option<f64>,
    /// Each frame's camera position from telemetry, when the input has any.
    pub positions: Option<&'a [Option<Position>]>,
    /// The camera the input names (one of `telemetry::CAMERAS`), when known.
    pub camera: Option<&'a str>,
    /// Width and height of the frames.
    pub frame_size: (u32, u32),
    /// Each frame's embedding, from the embedder the chain's similarity step reads.
    pub embeddings: Option<similarity::Embeddings<'a>>,
}

/// The positions a geo step reads: an error naming the step when the input has none, a warning
/// when some of the candidates `keys` have none (they are never kept).
fn positions<'a>(
    at: &Inputs<'a>,
    step: &'static str,
    keys: &[usize],
) -> Result<&'a [Option<Position>]> {
    let refuse = || {
        Error::step(
            step,
            "needs each frame's position, and the input has no telemetry: give --telemetry \
              FILE (DJI SRT or GPX), put the DJI .SRT beside the video, or use images with EXIF \
              GPS tags",
        )
    };
    let positions = at.positions.ok_or_else(refuse)?;
    let without = (keys.iter())
        .filter(|&&k| positions.get(k).is_none_or(Option::is_none))
        .count();
    if without == keys.len() && !keys.is_empty() {
        let msg = format!(
            "none of the {without} candidates has a position (they lie outside the \
             telemetry's time span; check --telemetry-offset)"
        );
        return Err(Error::step(step, msg));
    }
    if without > 0 {
        log::warn!(
            "{step}: {without} of {} candidates have no position and are not kept",
            keys.len()
        );
    }
    Ok(positions)
}

/// Reads a step from its flags' values (None: its flags were not given).
type FlagReader = fn(&FlagValues) -> Result<Option<Step>>;

/// One kind of step as the chain lists it: its id, its flags and their reader, the parameter a
/// new step of it must be given, and the step whose place it shares (a chain has one of them).
#[derive(Debug, Clone, Copy)]
pub struct Kind {
    /// The stable step id.
    pub id: &'static str,
    /// Its command-line flags.
    pub flags: &'static [Flag],
    read: FlagReader,
    /// The parameter without a default that a new step needs (the review page asks for it).
    pub required: Option<&'static str>,
    /// The step before it whose place in the chain it shares.
    pub instead_of: Option<&'static str>,
}

impl Kind {
    const fn new(id: &'static str, flags: &'static [Flag], read: FlagReader) -> Kind {
        Kind {
            id,
            flags,
            read,
            required: None,
            instead_of: None,
        }
    }

    const fn required(self, key: &'static str) -> Kind {
        Kind {
            required: Some(key),
            ..self
        }
    }

    const fn instead_of(self, id: &'static str) -> Kind {
        Kind {
            instead_of: Some(id),
            ..self
        }
    }
}

/// Every kind of step in keyframer's chain order. The flags, the order [`check_order`] enforces,
/// the history's step ids and the review page's step list come from here; what a step reads
/// from the analysis is its [`Step::needs`], which `select`'s plan and `review` read.
pub static STEPS: [Kind; 11] = [
    Kind::new("boundaries", boundaries::FLAGS, boundaries::from_flags),
    Kind::new("stationary", stationary::FLAGS, stationary::from_flags),
    Kind::new("spacing", spacing::FLAGS, spacing::from_flags),
    Kind::new("geo-area", geo_area::FLAGS, geo_area::from_flags).required("file"),
    Kind::new(
        "geo-distance",
        geo_distance::FLAGS,
        geo_distance::from_flags,
    )
    .required("metres"),
    Kind::new("footprint-overlap", footprint::FLAGS, footprint::from_flags).required("percent"),
    Kind::new("similarity", similarity::FLAGS, similarity::from_flags).required("k"),
    Kind::new("every-nth", every_nth::FLAGS, every_nth::from_flags).required("n"),
    Kind::new("fps", fps::FLAGS, fps::from_flags)
        .required("fps")
        .instead_of("every-nth"),
    Kind::new("blur", blur::FLAGS, blur::from_flags),
    Kind::new("manual", manual::FLAGS, manual::from_flags),
];

/// What a step reads from the analysis: `select` measures what its chain's steps need and the
/// cache lacks; `review` leaves out a step whose need the project's cache lacks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Need {
    /// The sharpness scores of this metric.
    Sharpness(Metric),
    /// The movement series, measured as the movement flags say.
    Movement,
    /// The spacing threshold proposed from a movement sample (`--spacing auto`).
    SpacingProposal,
    /// The stationary run for the step's parameters (measured while decoding).
    StationaryRun,
    /// Each frame's camera position, from the input's telemetry.
    Positions,
    /// Each frame's embedding (the built-in descriptor), for the similarity step.
    Embeddings,
}

impl Need {
    /// Whether `select` on the same input computes it when a step asks: positions come only
    /// from the telemetry the input has, which every `select` reads.
    pub fn measured_by_select(self) -> bool {
        self != Need::Positions
    }

    /// Whether `at` holds it.
    pub fn is_in(self, at: &Inputs) -> bool {
        match self {
            Need::Sharpness(m) => at.sharpness.iter().any(|s| s.0 == m),
            Need::Movement => at.movement.is_some(),
            Need::SpacingProposal => at.spacing_px.is_some(),
            Need::StationaryRun => at.stationary.is_some(),
            Need::Positions => at.positions.is_some(),
            Need::Embeddings => at.embeddings.is_some(),
        }
    }
}

/// The flags of every step, in the chain's order.
pub fn flags() -> impl Iterator<Item = &'static Flag> {
    STEPS.iter().flat_map(|k| k.flags)
}

/// The steps the flags give, in keyframer's order, checked (errors name the flag's parameter).
pub fn from_flags(v: &FlagValues) -> Result<Vec<Step>> {
    let mut steps = Vec::new();
    for kind in &STEPS {
        if let Some(step) = (kind.read)(v)? {
            step.validate().map_err(flag_error)?;
            step.check_files()?;
            steps.push(step);
        }
    }
    Ok(steps)
}

impl Step {
    /// The command-line flags that give this step, the inverse of [`from_flags`]: each
    /// parameter goes through the flag that [`Flag::sets`] it (a switch that sets it stands for
    /// the value that is its name: `--auto`), `--{id}` when that is a switch, and `--{key}`
    /// for a parameter no step flag sets (`--hfov`, which `select` reads as a movement flag).
    /// Unset parameters are left out, so `select` gives them its defaults.
    pub fn to_flags(&self) -> Vec<String> {
        let id = self.id();
        let mut out = Vec::new();
        if flags().any(|f| f.long == id && f.value_name.is_none()) {
            out.push(format!("--{id}"));
        }
        let value = serde_json::to_value(self).unwrap_or_default();
        let params = value
            .get(id)
            .and_then(|p| p.as_object())
            .into_iter()
            .flatten();
        for (key, v) in params.filter(|(_, v)| !v.is_null()) {
            let text = match v {
                serde_json::Value::String(s) => s.clone(),
                serde_json::Value::Array(a) => a
                    .iter()
                    .map(|x| x.to_string())
                    .collect::<Vec<_>>()
                    .join(","),
                other => other.to_string(),
            };
            let setters = || flags().filter(|f| f.sets.is_some_and(|s| s == (id, key.as_str())));
            match setters().find(|f| f.value_name.is_none() && f.long == text) {
                Some(switch) => out.push(format!("--{}", switch.long)),
                None => {
                    let long = setters()
                        .find(|f| f.value_name.is_some())
                        .map(|f| f.long.to_string());
                    out.push(format!(
                        "--{}",
                        long.unwrap_or_else(|| key.replace('_', "-"))
                    ));
                    out.push(text);
                }
            }
        }
        out
    }
}

/// A step's parameter error, naming the flag that sets the parameter when there is one.
fn flag_error(e: StepError) -> Error {
    match flags().find(|f| f.sets == Some((e.step, e.key))) {
        Some(f) => Error::param(f.long, e.msg),
        None => Error::step(e.step, e.msg),
    }
}

/// One sampler and its parameters as given. In a workflow's `[[sample]]` table the `plugin` key
/// names the variant; in serde the variant is the outer key, so errors keep the parameter's path.
/// Steps are only written as TOML, whose serializer leaves `None` parameters out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub enum Step {
    /// Part of the input to consider, both ends inclusive.
    Boundaries {
        /// First candidate; absent: the input's first frame.
        start: Option<BoundArg>,
        /// Last candidate; absent: the input's last frame.
        end: Option<BoundArg>,
    },
    /// Drop frames where the camera stands still (reference mode).
    Stationary {
        /// Pixels of movement since the last keyframe, or `auto`; default 1 % of the width.
        threshold: Option<Threshold>,
        /// Frames after which the reference is re-anchored, carrying the accumulated movement.
        reset_delta: Option<usize>,
    },
    /// A keyframe every `threshold` pixels of accumulated movement.
    Spacing {
        /// Pixels of accumulated movement per keyframe, `auto`, or a keyframe count (`60kf`).
        threshold: Threshold,
    },
    /// Keep the candidates whose telemetry position lies inside the area of `file` (GeoJSON
    /// or KML polygons), grown or shrunk by `buffer_m` metres.
    GeoArea {
        /// The area's file; in a workflow relative to the workflow's folder.
        file: std::path::PathBuf,
        /// Metres the area grows (> 0) or shrinks (< 0) by.
        buffer_m: Option<f64>,
    },
    /// A keyframe each time the camera has moved `metres` (telemetry positions).
    GeoDistance {
        /// Metres of travel between keyframes.
        metres: f64,
    },
    /// A keyframe when the ground footprint overlaps the last keyframe's by less than
    /// `percent`; `hfov` in degrees (default: from the telemetry's focal length).
    FootprintOverlap {
        /// Overlap in percent below which a frame is kept.
        percent: f64,
        /// Horizontal field of view in degrees.
        hfov: Option<f64>,
    },
    /// Keep frames by what they look like: k-means over their embeddings (one keyframe per `k`
    /// candidates on average), or, with `threshold`, drop a frame within that cosine distance
    /// of one kept before.
    Similarity {
        /// One keyframe per `k` candidates on average (k-means with ⌈n / k⌉ clusters).
        k: Option<usize>,
        /// Cosine distance below which a frame counts as seen (instead of `k`).
        threshold: Option<f64>,
        /// The embedding network: a model description (`.toml`) or an ONNX file named
        /// `ImageEmbedding_<NAME>_<DIM>_<W>x<H>.onnx`; absent: the built-in descriptor. In a
        /// workflow relative to the workflow's folder.
        model: Option<std::path::PathBuf>,
        /// The runtime that runs `model` (OpenCV DNN when absent).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        runtime: Option<crate::manifest::SegRuntime>,
    },
    /// Every n-th candidate.
    #[serde(alias = "every")]
    EveryNth {
        /// Keep one candidate in `n`.
        n: usize,
    },
    /// Resample to `fps` frames per second by timestamps.
    Fps {
        /// Target frames per second.
        fps: f64,
    },
    /// Drop (`filter`) or `replace` blurry keyframes.
    Blur {
        /// Sharpness measure (Tenengrad or variance of the Laplacian).
        metric: Option<Metric>,
        /// Half-width in frames of the window a frame is compared with.
        window: Option<usize>,
        /// Filter mode keeps a frame iff its score over the window's mean is at least this.
        ratio: Option<f64>,
        /// `filter` or `replace`.
        mode: Option<BlurMode>,
    },
    /// Add or remove frames by index.
    Manual {
        /// Frame indices to add.
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        add: Vec<usize>,
        /// Frame indices to remove.
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        remove: Vec<usize>,
    },
}

/// A step's parameter that is out of range: `key` is the parameter's name in the step.
#[derive(Debug, Clone, PartialEq)]
pub struct StepError {
    /// Stable step id.
    pub step: &'static str,
    /// The parameter (`window`), or `plugin` (a workflow's key for it) for the step as a whole.
    pub key: &'static str,
    /// What is wrong, starting with the parameter's name as a user reads it.
    pub msg: String,
}

impl Step {
    /// The stable step id (`plugin` in project and workflow files).
    pub fn id(&self) -> &'static str {
        match self {
            Step::Boundaries { .. } => "boundaries",
            Step::Stationary { .. } => "stationary",
            Step::Spacing { .. } => "spacing",
            Step::GeoArea { .. } => "geo-area",
            Step::GeoDistance { .. } => "geo-distance",
            Step::FootprintOverlap { .. } => "footprint-overlap",
            Step::Similarity { .. } => similarity::ID,
            Step::EveryNth { .. } => "every-nth",
            Step::Fps { .. } => "fps",
            Step::Blur { .. } => "blur",
            Step::Manual { .. } => "manual",
        }
    }

    /// Runs the step on `keys`; returns what it did (None: boundaries, which `select` applies
    /// when it lists the candidates).
    pub fn apply(&self, at: &Inputs, keys: &mut Vec<usize>) -> Result<Option<Applied>> {
        Ok(Some(match self {
            Step::Boundaries { .. } => return Ok(None),
            Step::Stationary { .. } => stationary::apply(at, keys)?,
            Step::Spacing { threshold } => spacing::apply(at, keys, *threshold)?,
            Step::GeoArea { file, buffer_m } => geo_area::apply(at, keys, file, *buffer_m)?,
            Step::GeoDistance { metres } => geo_distance::apply(at, keys, *metres)?,
            Step::FootprintOverlap { percent, hfov } => {
                footprint::apply(at, keys, *percent, *hfov)?
            }
            Step::Similarity {
                k,
                threshold,
                model,
                ..
            } => similarity::apply(at, keys, (*k, *threshold), model.as_deref())?,
            Step::EveryNth { n } => every_nth::apply(keys, *n)?,
            Step::Fps { fps } => fps::apply(at, keys, *fps)?,
            Step::Blur { .. } => match self.blur_params() {
                Some(b) => blur::apply(at, keys, &b)?,
                None => return Ok(None),
            },
            Step::Manual { add, remove } => manual::apply(at, keys, add, remove)?,
        }))
    }

    /// What the step reads from the analysis.
    pub fn needs(&self) -> Vec<Need> {
        match self {
            Step::Stationary { .. } => vec![Need::StationaryRun],
            Step::Spacing {
                threshold: Threshold::Auto,
            } => vec![Need::Movement, Need::SpacingProposal],
            Step::Spacing { .. } => vec![Need::Movement],
            Step::GeoArea { .. } | Step::GeoDistance { .. } | Step::FootprintOverlap { .. } => {
                vec![Need::Positions]
            }
            Step::Similarity { .. } => vec![Need::Embeddings],
            Step::Blur { .. } => (self.blur_params().into_iter())
                .map(|b| Need::Sharpness(b.metric))
                .collect(),
            Step::Boundaries { .. }
            | Step::EveryNth { .. }
            | Step::Fps { .. }
            | Step::Manual { .. } => Vec::new(),
        }
    }

    /// The files the step reads, each with its parameter (`file`): `select` and workflows
    /// count them among their inputs.
    pub fn files(&self) -> Vec<(&'static str, &std::path::Path)> {
        match self {
            Step::GeoArea { file, .. } => vec![("file", file.as_path())],
            Step::Similarity { model: Some(m), .. } => vec![("model", m.as_path())],
            _ => Vec::new(),
        }
    }

    /// What a file of [`Step::files`] is, by its parameter (for the output rules' messages).
    pub fn file_what(key: &str) -> &'static str {
        match key {
            "model" => "embedding model",
            _ => "area file",
        }
    }

    /// The step with its relative files taken relative to `base` (a workflow's folder).
    pub fn resolve_files(&mut self, base: &std::path::Path) {
        let file = match self {
            Step::GeoArea { file, .. } => file,
            Step::Similarity { model: Some(m), .. } => m,
            _ => return,
        };
        if file.is_relative() {
            *file = base.join(&*file);
        }
    }

    /// Reads the files the step names, so that a bad one is refused before any frame is
    /// decoded (the error names the file and the place in it).
    pub fn check_files(&self) -> Result<()> {
        match self {
            Step::GeoArea { file, .. } => drop(geo_area::Area::load(file)?),
            Step::Similarity { model: Some(m), .. } => {
                if !m.is_file() {
                    return Err(Error::input(m, "no such embedding model"));
                }
                match crate::model_desc::is_description(m) {
                    true => drop(crate::model_desc::ModelDesc::load_embedding(m)?),
                    false => drop(similarity::model_name(m)?),
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// What the step needs that `at` lacks.
    pub fn lacks(&self, at: &Inputs) -> Vec<Need> {
        (self.needs().into_iter())
            .filter(|n| !n.is_in(at))
            .collect()
    }

    /// Position in keyframer's chain ([`STEPS`]; a step shares the place it stands in for).
    fn rank(&self) -> usize {
        let at = |id: &str| STEPS.iter().position(|k| k.id == id);
        let kind = at(self.id()).map(|i| &STEPS[i]);
        (kind.and_then(|k| at(k.instead_of.unwrap_or(k.id)))).unwrap_or(usize::MAX)
    }

    /// The blur step's parameters with the defaults filled in.
    pub fn blur_params(&self) -> Option<BlurParams> {
        match *self {
            Step::Blur {
                metric,
                window,
                ratio,
                mode,
            } => Some(BlurParams {
                metric: metric.unwrap_or(Metric::Tenengrad),
                window: window.unwrap_or(defaults::BLUR_WINDOW),
                ratio: ratio.unwrap_or(defaults::BLUR_RATIO),
                mode: mode.unwrap_or(BlurMode::Filter),
            }),
            _ => None,
        }
    }

    /// Checks the parameters' ranges (the input is not needed).
    pub fn validate(&self) -> std::result::Result<(), StepError> {
        let step = self.id();
        let bad = |key: &'static str, msg: String| Err(StepError { step, key, msg });
        match self {
            Step::Stationary {
                threshold,
                reset_delta,
            } => {
                match threshold {
                    Some(Threshold::Count(_)) => {
                        return bad(
                            "threshold",
                            "give pixels or `auto` (a keyframe count is for spacing)".into(),
                        )
                    }
                    Some(Threshold::Px(t)) => {
                        positive(*t).map(drop).or_else(|m| bad("threshold", m))?
                    }
                    _ => {}
                }
                if *reset_delta == Some(0) {
                    return bad("reset_delta", "must be at least 1 frame".into());
                }
            }
            Step::Boundaries { start, end } => {
                for (key, b) in [("start", start), ("end", end)] {
                    if let Some(BoundArg(Bound::Seconds(s))) = b {
                        if !(s.is_finite() && *s >= 0.0) {
                            return bad(key, format!("must be a non-negative time, got {s}"));
                        }
                    }
                }
            }
            Step::Spacing {
                threshold: Threshold::Px(t),
            } => return positive(*t).map(drop).or_else(|m| bad("threshold", m)),
            Step::EveryNth { n: 0 } => return bad("n", "must be at least 1".into()),
            Step::GeoDistance { metres } => {
                return positive(*metres).map(drop).or_else(|m| bad("metres", m))
            }
            Step::GeoArea { file, buffer_m } => {
                if file.as_os_str().is_empty() {
                    return bad("file", "must name a GeoJSON or KML file".into());
                }
                return geo_area::check_buffer(*buffer_m).or_else(|m| bad("buffer_m", m));
            }
            Step::FootprintOverlap { percent, hfov } => {
                if !(*percent > 0.0 && *percent < 100.0) {
                    let msg = format!("must be between 0 and 100 (exclusive), got {percent}");
                    return bad("percent", msg);
                }
                if let Some(h) = hfov.filter(|h| !(*h > 1.0 && *h < 179.0)) {
                    return bad("hfov", format!("{h} must be between 1 and 179 degrees"));
                }
            }
            Step::Fps { fps } => return positive(*fps).map(drop).or_else(|m| bad("fps", m)),
            Step::Similarity { k, threshold, .. } => {
                return similarity::check(*k, *threshold).or_else(|(key, m)| bad(key, m))
            }
            Step::Blur { .. } => {
                if let Some(p) = self.blur_params() {
                    if let Err(e) = p.validate() {
                        let key = if p.window == 0 { "window" } else { "ratio" };
                        return bad(key, e.into_msg());
                    }
                }
            }
            _ => {}
        }
        Ok(())
    }
}

/// Checks that `steps` follow keyframer's chain ([`STEPS`]: boundaries → stationary → spacing →
/// ... → manual), at most one of each: the error names the step's index.
pub fn check_order(steps: &[Step]) -> std::result::Result<(), (usize, String)> {
    let mut last: Option<&Step> = None;
    for (i, s) in steps.iter().enumerate() {
        let id = s.id();
        if steps[..i].iter().any(|p| p.rank() == s.rank()) {
            let shared = (places().into_iter())
                .filter(|p| p.contains('/'))
                .map(|p| format!(" (and one of {})", p.replace('/', " / ")));
            let msg = format!(
                "`{id}`: at most one step per sampler{}",
                shared.collect::<String>()
            );
            return Err((i, msg));
        }
        if let Some(p) = last.filter(|p| p.rank() > s.rank()) {
            let msg = format!(
                "`{id}` cannot follow `{}`: keyframer applies {}",
                p.id(),
                places().join(" → ")
            );
            return Err((i, msg));
        }
        last = Some(s);
    }
    Ok(())
}

/// The places of the chain: each step's id, ids that share a place joined by `/`.
fn places() -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for k in &STEPS {
        match (k.instead_of, out.last_mut()) {
            (Some(_), Some(last)) => *last = format!("{last}/{}", k.id),
            _ => out.push(k.id.to_string()),
        }
    }
    out
}

/// The boundaries of a step list (none: the whole input).
pub fn boundaries(steps: &[Step]) -> Boundaries {
    steps
        .iter()
        .find_map(|s| match s {
            Step::Boundaries { start, end } => Some(Boundaries {
                start: start.map(|b| b.0),
                end: end.map(|b| b.0),
            }),
            _ => None,
        })
        .unwrap_or_default()
}

/// A step as `select` applied it: one entry of a project's history (`plugin`, `params`).
/// A frame `reconstruct` added.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AddedFrame {
    /// Frame index.
    pub frame: usize,
    /// The round whose model it repairs.
    pub round: usize,
    /// Why and how it was chosen.
    pub reason: String,
}

/// Parameters absent from projects of older versions are optional.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "plugin", content = "params", rename_all = "kebab-case")]
pub enum Applied {
    /// The candidate range.
    Boundaries {
        /// Last candidate, when given.
        end: Option<Bound>,
        /// First candidate, when given.
        start: Option<Bound>,
    },
    /// `select --preview`: the chain ran on the codec keyframes.
    Preview {
        /// Codec keyframes the chain ran on.
        codec_keyframes: usize,
        /// Frames in the input.
        frames: usize,
    },
    /// `keyframer reconstruct`: frames added where COLMAP's model broke (not a sampler: a
    /// workflow replays it as its `[[reconstruct]]` table, after the selection).
    Reconstruct {
        /// COLMAP runs, the first on the starting keyframes.
        rounds: usize,
        /// The frames added, each with the round it repairs and why.
        added: Vec<AddedFrame>,
        /// COLMAP's version line.
        colmap_version: String,
        /// The loop's options as flags (`--max-rounds 4`, ...).
        options: Vec<String>,
        /// The same options as the loop read them, which `workflow save` writes as a
        /// `[[reconstruct]]` table (absent in projects of earlier builds).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        settings: Option<Box<crate::sparse::Options>>,
    },
    /// The stationary sampler with its resolved threshold.
    Stationary {
        /// Whether the threshold was proposed (`auto`).
        #[serde(default)]
        auto: bool,
        /// Backend that measured the movement.
        backend: Option<Backend>,
        /// How the movement was measured.
        movement: Option<MovementRequest>,
        /// Frames after which the reference was re-anchored.
        reset_delta: Option<usize>,
        /// Threshold in pixels as applied.
        threshold_px: Option<f64>,
    },
    /// The spacing sampler with its resolved threshold.
    Spacing {
        /// Whether the threshold was proposed (`auto`).
        #[serde(default)]
        auto: bool,
        /// Backend that measured the movement.
        backend: Option<Backend>,
        /// Keyframe count asked for (`--spacing Nkf`), if any.
        count: Option<usize>,
        /// How the movement was measured.
        movement: Option<MovementRequest>,
        /// Threshold in pixels as applied.
        threshold_px: f64,
    },
    /// The geo-area step: the file as given and as an absolute path (which `workflow save` and
    /// the review replay), with what identifies its content: the polygons, their vertices and
    /// the FNV-1a hash of the file's bytes (a changed file is noticed on re-selection).
    GeoArea {
        /// The area's file as given.
        file: std::path::PathBuf,
        /// The same file as an absolute path.
        path: std::path::PathBuf,
        /// Metres the area grew (> 0) or shrank (< 0) by.
        buffer_m: Option<f64>,
        /// Polygons in the file.
        polygons: usize,
        /// Vertices over all their rings.
        vertices: usize,
        /// FNV-1a (64 bit) of the file's bytes, 16 hex digits.
        fnv1a64: String,
    },
    /// The geo-distance sampler.
    GeoDistance {
        /// Metres of travel between keyframes.
        metres: f64,
    },
    /// The footprint-overlap sampler (`hfov` as given).
    FootprintOverlap {
        /// Horizontal field of view in degrees, when given.
        hfov: Option<f64>,
        /// Overlap in percent below which a frame was kept.
        percent: f64,
    },
    /// The similarity step: its parameters as given and the embeddings it read.
    Similarity {
        /// Backend that computed the embeddings.
        backend: Option<Backend>,
        /// Clusters of the k-means (k mode).
        clusters: Option<usize>,
        /// Dimensions of the embeddings.
        dim: usize,
        /// What computed the embeddings.
        embedder: String,
        /// One keyframe per `k` candidates on average, when given.
        k: Option<usize>,
        /// The embedding network as given, when one was.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        model: Option<std::path::PathBuf>,
        /// The runtime that ran the network, when one did.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        runtime: Option<crate::manifest::SegRuntime>,
        /// The cosine-distance threshold, when given.
        threshold: Option<f64>,
    },
    /// Every n-th candidate.
    EveryNth {
        /// One candidate in `n` was kept.
        n: usize,
    },
    /// Resampled by timestamps.
    Fps {
        /// Target frames per second.
        fps: f64,
    },
    /// The blur sampler.
    Blur {
        /// Backend that measured the sharpness.
        backend: Option<Backend>,
        /// Sharpness measure.
        metric: Option<Metric>,
        /// `filter` or `replace`.
        mode: Option<BlurMode>,
        /// Filter-mode ratio.
        ratio: Option<f64>,
        /// Half-width of the window in frames.
        window: Option<usize>,
    },
    /// Frames added and removed by index.
    Manual {
        /// Frame indices added.
        #[serde(default)]
        add: Vec<usize>,
        /// Frame indices removed.
        #[serde(default)]
        remove: Vec<usize>,
    },
}

impl Applied {
    /// The step's id (`plugin` in a project file; `preview` for `select --preview`'s record).
    pub fn id(&self) -> &'static str {
        match self {
            Applied::Reconstruct { .. } => "reconstruct",
            _ => self.step().map_or("preview", |s| s.id()),
        }
    }

    /// The step that repeats this one on another input (resolved thresholds, not `auto`).
    pub fn step(&self) -> Option<Step> {
        Some(match self {
            Applied::Boundaries { start, end } => Step::Boundaries {
                start: start.map(BoundArg),
                end: end.map(BoundArg),
            },
            Applied::Preview { .. } | Applied::Reconstruct { .. } => return None,
            Applied::Stationary {
                threshold_px,
                reset_delta,
                ..
            } => Step::Stationary {
                threshold: threshold_px.map(Threshold::Px),
                reset_delta: *reset_delta,
            },
            Applied::Spacing { threshold_px, .. } => Step::Spacing {
                threshold: Threshold::Px(*threshold_px),
            },
            Applied::GeoArea { path, buffer_m, .. } => Step::GeoArea {
                file: path.clone(),
                buffer_m: *buffer_m,
            },
            Applied::GeoDistance { metres } => Step::GeoDistance { metres: *metres },
            Applied::FootprintOverlap { percent, hfov } => Step::FootprintOverlap {
                percent: *percent,
                hfov: *hfov,
            },
            Applied::Similarity {
                k,
                threshold,
                model,
                runtime,
                ..
            } => Step::Similarity {
                k: *k,
                threshold: *threshold,
                model: model.clone(),
                runtime: *runtime,
            },
            Applied::EveryNth { n } => Step::EveryNth { n: *n },
            Applied::Fps { fps } => Step::Fps { fps: *fps },
            Applied::Blur {
                metric,
                mode,
                ratio,
                window,
                ..
            } => Step::Blur {
                metric: *metric,
                window: *window,
                ratio: *ratio,
                mode: *mode,
            },
            Applied::Manual { add, remove } => Step::Manual {
                add: add.clone(),
                remove: remove.clone(),
            },
        })
    }

    /// The backend and movement measure the step read (for a workflow's `[analysis]`).
    pub fn analysis(&self) -> (Option<Backend>, Option<MovementRequest>) {
        match self {
            Applied::Stationary {
                backend, movement, ..
            }
            | Applied::Spacing {
                backend, movement, ..
            } => (*backend, *movement),
            Applied::Blur { backend, .. } => (*backend, None),
            _ => (None, None),
        }
    }

    /// Checks the parameters `workflow save` reads, for an input of `frames` frames, with the
    /// step's own [`Step::validate`]; the error names the parameter (`params.fps`).
    pub fn check(&self, frames: usize) -> std::result::Result<(), (String, String)> {
        let bad = |k: &str, msg: String| Err((format!("params.{k}"), msg));
        let lists: Vec<(&str, Vec<usize>)> = match self {
            Applied::Manual { add, remove } => {
                vec![("add", add.clone()), ("remove", remove.clone())]
            }
            Applied::Reconstruct { added, .. } => {
                vec![("added", added.iter().map(|a| a.frame).collect())]
            }
            _ => Vec::new(),
        };
        if let Some((k, _)) = lists.iter().find(|(_, l)| l.iter().any(|&i| i >= frames)) {
            return bad(k, format!("must be a list of frame indices below {frames}"));
        }
        match self.step().map(|s| s.validate()) {
            // The flag's `threshold` is recorded as `threshold_px` by these two.
            Some(Err(e))
                if e.key == "threshold"
                    && matches!(self, Applied::Stationary { .. } | Applied::Spacing { .. }) =>
            {
                bad("threshold_px", e.msg)
            }
            Some(Err(e)) => bad(e.key, e.msg),
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_read_from_tables_as_a_workflow_writes_them() {
        let t: toml::Table = toml::from_str("[spacing]\nthreshold = \"60kf\"").unwrap();
        let s: Step = toml::Value::Table(t).try_into().unwrap();
        assert_eq!(
            s,
            Step::Spacing {
                threshold: Threshold::Count(60)
            }
        );
        let t: toml::Table = toml::from_str("[boundaries]\nstart = 3\nend = \"4.5s\"").unwrap();
        let s: Step = toml::Value::Table(t).try_into().unwrap();
        assert_eq!(
            boundaries(std::slice::from_ref(&s)).end,
            Some(Bound::Seconds(4.5))
        );
        let back = toml::Value::try_from(&s).unwrap();
        assert_eq!(back["boundaries"]["start"].as_integer(), Some(3));
        assert_eq!(back["boundaries"]["end"].as_str(), Some("4.5s"));
    }

    #[test]
    fn order_and_ranges_are_checked() {
        let every = Step::EveryNth { n: 2 };
        let fps = Step::Fps { fps: 1.0 };
        assert!(check_order(&[every.clone(), fps.clone()]).is_err());
        let blur = Step::Blur {
            metric: None,
            window: Some(0),
            ratio: None,
            mode: None,
        };
        assert_eq!(
            check_order(&[blur.clone(), every.clone()]).unwrap_err().0,
            1
        );
        assert_eq!(blur.validate().unwrap_err().key, "window");
        assert_eq!(Step::EveryNth { n: 0 }.validate().unwrap_err().key, "n");
    }

    /// The chain's order and shared place come from [`STEPS`]; the messages are the ones
    /// keyframer gave when the chain was written out by hand.
    #[test]
    fn the_chain_is_the_step_tables() {
        let stationary = Step::Stationary {
            threshold: None,
            reset_delta: None,
        };
        let (i, msg) = check_order(&[Step::Fps { fps: 1.0 }, stationary]).unwrap_err();
        assert_eq!(i, 1);
        assert_eq!(
            msg,
            "`stationary` cannot follow `fps`: keyframer applies boundaries → stationary → \
             spacing → geo-area → geo-distance → footprint-overlap → similarity → every-nth/fps → blur → \
             manual"
        );
        let (_, msg) = check_order(&[Step::EveryNth { n: 2 }, Step::Fps { fps: 1.0 }]).unwrap_err();
        assert_eq!(
            msg,
            "`fps`: at most one step per sampler (and one of every-nth / fps)"
        );
    }

    #[test]
    fn flag_defaults_are_the_steps_defaults() {
        let mut v = FlagValues::default();
        for f in flags() {
            if let (Some(d), Some(check)) = (f.default, f.check) {
                assert_eq!(check(d), Ok(()), "{}", f.long);
                v.set(f.long, vec![d.to_string()]);
            }
        }
        v.set("stationary", Vec::new());
        v.set("blur", Vec::new());
        let steps = from_flags(&v).unwrap();
        let given = |s: &Step| Step::validate(s).is_ok();
        assert!(steps.iter().all(given));
        assert_eq!(
            steps[0],
            Step::Stationary {
                threshold: None,
                reset_delta: Some(defaults::RESET_DELTA)
            }
        );
        let blur = Step::Blur {
            metric: None,
            window: None,
            ratio: None,
            mode: None,
        };
        assert_eq!(steps[1].blur_params(), blur.blur_params());
    }

    /// `args` as the command line hands them to [`from_flags`] (as `cli::StepArgs`: defaults,
    /// switches without a value, lists split at commas); `--hfov` is a movement flag that
    /// `select` puts into the footprint step.
    fn parse_flags(args: &[String]) -> Vec<Step> {
        let mut v = FlagValues::default();
        for f in flags().filter(|f| f.default.is_some()) {
            v.set(f.long, vec![f.default.unwrap().to_string()]);
        }
        let (mut hfov, mut i) = (None, 0);
        while i < args.len() {
            let long = args[i].strip_prefix("--").unwrap();
            if long == "hfov" {
                hfov = Some(args[i + 1].parse::<f64>().unwrap());
                i += 2;
                continue;
            }
            let f = flags().find(|f| f.long == long).unwrap();
            let values = match f.value_name {
                None => Vec::new(),
                Some(_) if f.list => args[i + 1].split(',').map(String::from).collect(),
                Some(_) => vec![args[i + 1].clone()],
            };
            if let Some(check) = f.check {
                values.iter().for_each(|x| check(x).unwrap());
            }
            i += 1 + usize::from(f.value_name.is_some());
            v.set(f.long, values);
        }
        let mut steps = from_flags(&v).unwrap();
        for s in &mut steps {
            if let Step::FootprintOverlap { hfov: h, .. } = s {
                *h = hfov;
            }
        }
        steps
    }

    #[test]
    fn geo_area_goes_through_its_flags_and_reads_its_file_with_them() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("area.geojson");
        let square = r#"{"type":"Polygon","coordinates":[[[8,47],[8.1,47],[8.1,47.1],[8,47]]]}"#;
        std::fs::write(&file, square).unwrap();
        let step = Step::GeoArea {
            file: file.clone(),
            buffer_m: Some(-12.5),
        };
        let flags = step.to_flags();
        let pair = |a: &str, b: &str| flags.windows(2).any(|w| w[0] == a && w[1] == b);
        assert!(pair("--geo-area", &file.display().to_string()), "{flags:?}");
        assert!(pair("--geo-area-buffer", "-12.5"), "{flags:?}");
        assert_eq!(parse_flags(&flags), [step]);
        std::fs::write(&file, "{").unwrap();
        let mut v = FlagValues::default();
        v.set("geo-area", vec![file.display().to_string()]);
        let e = from_flags(&v).unwrap_err().to_string();
        assert!(
            e.contains("area.geojson: not a usable area file: line 1"),
            "{e}"
        );
    }

    #[test]
    fn to_flags_gives_the_step_back_through_the_flags() {
        use crate::params::Metric;
        let bound = |t: &str| Some(BoundArg(t.parse().unwrap()));
        let steps = [
            Step::Boundaries {
                start: bound("12"),
                end: bound("4.25s"),
            },
            Step::Stationary {
                threshold: Some(Threshold::Px(7.5)),
                reset_delta: Some(9),
            },
            Step::Stationary {
                threshold: Some(Threshold::Auto),
                reset_delta: Some(3),
            },
            Step::Spacing {
                threshold: Threshold::Px(0.1 + 0.2),
            },
            Step::Spacing {
                threshold: Threshold::Auto,
            },
            Step::Spacing {
                threshold: Threshold::Count(60),
            },
            Step::GeoDistance { metres: 12.5 },
            Step::FootprintOverlap {
                percent: 70.0,
                hfov: Some(84.5),
            },
            Step::FootprintOverlap {
                percent: 35.5,
                hfov: None,
            },
            Step::EveryNth { n: 7 },
            Step::Fps { fps: 29.97 },
            Step::Blur {
                metric: Some(Metric::Laplacian { ksize: 3 }),
                window: Some(4),
                ratio: Some(0.65),
                mode: Some(BlurMode::Replace),
            },
            Step::Manual {
                add: vec![3, 60, 61],
                remove: vec![5],
            },
        ];
        for step in steps {
            let flags = step.to_flags();
            assert_eq!(
                parse_flags(&flags),
                std::slice::from_ref(&step),
                "{flags:?}"
            );
        }
        let auto = Step::Stationary {
            threshold: Some(Threshold::Auto),
            reset_delta: None,
        };
        assert_eq!(auto.to_flags(), ["--stationary", "--auto"]);
        let count = Step::Spacing {
            threshold: Threshold::Count(60),
        };
        assert_eq!(count.to_flags(), ["--spacing", "60kf"]);
    }

    #[test]
    fn a_recorded_threshold_error_names_the_recorded_key() {
        let spacing = Applied::Spacing {
            auto: false,
            backend: None,
            count: None,
            movement: None,
            threshold_px: -1.0,
        };
        assert_eq!(spacing.check(10).unwrap_err().0, "params.threshold_px");
        let similarity = Applied::Similarity {
            backend: None,
            clusters: None,
            dim: 176,
            embedder: "descriptor".into(),
            k: Some(4),
            model: None,
            runtime: None,
            threshold: Some(0.2),
        };
        let (key, msg) = similarity.check(10).unwrap_err();
        assert_eq!(key, "params.threshold", "{msg}");
    }
}
