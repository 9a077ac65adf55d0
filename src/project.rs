//! The project file (JSON): input reference and fingerprint, metadata, boundaries, keyframes, the
//! per-frame cache (timestamps, scores, telemetry positions) and the history of steps. Loading
//! validates every field and names the offending one; saving is atomic.
//!
//! Versions: 2 adds `cache.telemetry` (per-frame positions and where they came from, absent when
//! the input has none); version 1 files load unchanged (they have no positions) and are written
//! back as version 2.

use crate::error::{Error, Result};
use crate::fsutil::{self, Fingerprint};
use crate::manifest::SegRuntime;
use crate::numbers::{non_negative_seconds, positive, positive_px};
use crate::params::{Backend, Metric, MovementRequest, MovementSeries, Rows, StationaryRequest};
use crate::source::telemetry::{Position, TelemetryKind};
use crate::source::{Metadata, SourceKind};
use crate::steps::{Boundaries, Recorded, Stored};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Version of the project file layout this build writes.
pub const SCHEMA_VERSION: u32 = 2;

/// Versions this build reads: 1 is 2 without `cache.telemetry`.
const READS: [u32; 2] = [1, SCHEMA_VERSION];

/// A keyframe selection and everything needed to reproduce and export it. `H` is one step of its
/// history: [`Recorded`], or [`Stored`] (as the file has it) while [`Project::load`] reads it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Project<H = Recorded> {
    /// Layout version; see [`SCHEMA_VERSION`].
    pub schema_version: u32,
    /// keyframer version that wrote the file.
    pub tool_version: String,
    /// Which input the keyframes refer to.
    pub input: InputRef,
    /// Facts about the input (frame count established by decoding).
    pub metadata: Metadata,
    /// The part of the input that was sampled.
    pub boundaries: Boundaries,
    /// Selected frame indices, sorted and distinct.
    pub keyframes: Vec<usize>,
    /// The steps that produced `keyframes`, in order.
    pub history: Vec<H>,
    /// Per-frame data computed from the pixels, reused by later selections.
    pub cache: Cache,
    /// Problems met while decoding the input (damaged streams, damaged images).
    #[serde(default)]
    pub decode_problems: Vec<String>,
    /// Frames that could not be decoded but did not end the input (damaged files of an image
    /// folder), ascending: never selected, never exported.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub damaged_frames: Vec<usize>,
    /// Made by `select --preview` from the codec keyframes only: the cache holds timestamps but
    /// no scores, and the project is never reused as a cache.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub preview: bool,
    /// How the frames map to directions (`select --projection`); pinhole when left out.
    #[serde(
        default,
        skip_serializing_if = "crate::equirect::Projection::is_pinhole"
    )]
    pub projection: crate::equirect::Projection,
}

/// The input a project refers to.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InputRef {
    /// Path, relative to the project file's folder when possible.
    pub path: PathBuf,
    /// Video, image folder or single image.
    pub kind: SourceKind,
    /// Detects a changed or replaced input.
    pub fingerprint: Fingerprint,
}

/// Per-frame numbers computed from the input.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Cache {
    /// Presentation time of every frame in seconds (absent for image folders without a rate).
    pub timestamps_s: Option<Vec<f64>>,
    /// Sharpness scores, one series per (metric, analysis resolution).
    #[serde(default)]
    pub sharpness: Vec<SharpnessSeries>,
    /// Movement between consecutive frames, one series per way of measuring it.
    #[serde(default)]
    pub movement: Vec<MovementCache>,
    /// Stationary-sampler runs (reference mode: their frame pairs depend on the threshold).
    #[serde(default)]
    pub stationary: Vec<StationaryCache>,
    /// Each frame's camera position from telemetry (absent: none known).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub telemetry: Option<TelemetryCache>,
    /// Per-frame embeddings for the similarity step, one series per embedder and analysis size.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub embeddings: Vec<EmbeddingCache>,
}

/// Each frame's embedding (a unit vector quantised to 16 bits, `steps::similarity::quantise`),
/// in a series file beside the project (`embedding_file`) that this record names and owns, or,
/// in projects written before those files, as hex text per frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EmbeddingCache {
    /// What computed them (`builtin-grid-hog-colour-v1`): with the size, the cache key.
    pub embedder: String,
    /// Width in pixels of the frames described.
    pub width: u32,
    /// Height in pixels of the frames described.
    pub height: u32,
    /// Backend that computed them (both give the same bytes: `kernels::tolerance`).
    pub backend: Backend,
    /// The runtime that ran the network, when a network computed them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub runtime: Option<SegRuntime>,
    /// Dimensions of each embedding.
    pub dim: usize,
    /// The series file, a plain file name in the project file's folder: one record per frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
    /// Projects written before the series files: one hex-encoded embedding per frame
    /// (`steps::similarity::encode`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub frames: Vec<String>,
    /// The project file's folder, where `file` is: set when the project is read or the series
    /// made, never written.
    #[serde(skip)]
    pub dir: PathBuf,
}

impl EmbeddingCache {
    /// Where the series file is, when it has one.
    pub fn path(&self) -> Option<PathBuf> {
        self.file.as_ref().map(|f| self.dir.join(f))
    }

    /// Whether its vectors can be read for an input of `n` frames: hex text for each, or a
    /// series file of keyframer's holding exactly `n` records of `dim` values.
    pub fn usable(&self, n: usize) -> bool {
        match self.path() {
            Some(p) => crate::embedding_file::holds(&p, self.dim, n),
            None => self.frames.len() == n,
        }
    }
}

/// Per-frame positions from telemetry and where they came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TelemetryCache {
    /// The file read: the key under which the positions are reused.
    pub source: TelemetrySource,
    /// What was wrong with it (`FILE:line N: ...`), as `select` warned: the first few (older
    /// projects: all of them) ...
    pub warnings: Vec<String>,
    /// ... and how many more there were.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub more_warnings: usize,
    /// One entry per frame: its position interpolated at the frame's timestamp, `null` for a
    /// frame outside the telemetry's time span (or an image without GPS tags).
    pub positions: Vec<Option<Position>>,
    /// The camera of `telemetry::CAMERAS` the video's container tags or the first image's EXIF
    /// model name, when one does.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<String>,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// Where a project's positions came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TelemetrySource {
    /// The telemetry file, relative to the project file's folder when possible (the input itself
    /// for EXIF).
    pub path: PathBuf,
    /// DJI SRT, GPX or EXIF.
    pub kind: TelemetryKind,
    /// Seconds added to the video's clock to find a frame's time in the telemetry
    /// (`--telemetry-offset`).
    pub offset_s: f64,
    /// The telemetry file's fingerprint (None for EXIF, which the input's fingerprint covers).
    pub fingerprint: Option<Fingerprint>,
    /// The rule that placed the frames in the telemetry's time
    /// ([`crate::source::telemetry::PLACEMENT_RULE`]; 0 in older projects): positions placed by
    /// another rule are placed again.
    #[serde(default)]
    pub rule: u32,
}

/// Cached movement between consecutive frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MovementCache {
    /// How it was measured (Farneback parameters, statistic, analysis width): the cache key.
    pub request: MovementRequest,
    /// Backend that computed it.
    pub backend: Backend,
    /// The values.
    pub series: MovementSeries,
}

/// A cached stationary-sampler run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StationaryCache {
    /// How movement was measured.
    pub request: MovementRequest,
    /// Threshold, reset delta and frame range: with `request`, the cache key.
    pub params: StationaryRequest,
    /// Backend that computed it.
    pub backend: Backend,
    /// The frames it kept.
    pub keyframes: Vec<usize>,
}

/// One sharpness score per frame, keyed by metric and the resolution it was computed at.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SharpnessSeries {
    /// Metric and its parameters (`tenengrad`, `laplacian-k1`, `laplacian-k3`).
    pub metric: Metric,
    /// Analysis width in pixels.
    pub width: u32,
    /// Analysis height in pixels.
    pub height: u32,
    /// The rows scored, as an image of their own, when not the whole frame (360° frames: the
    /// band |latitude| < 45°, `Rows::erp_band`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rows: Option<Rows>,
    /// Backend that computed the scores (both agree within the kernel tolerance).
    pub backend: Backend,
    /// One score per frame.
    pub scores: Vec<f64>,
}

impl Cache {
    /// Cached consecutive movement measured as `request`.
    pub fn movement(&self, request: &MovementRequest) -> Option<&MovementCache> {
        self.movement.iter().find(|m| &m.request == request)
    }

    /// Cached stationary run for `request` and `params`.
    pub fn stationary(
        &self,
        request: &MovementRequest,
        params: &StationaryRequest,
    ) -> Option<&StationaryCache> {
        self.stationary
            .iter()
            .find(|r| &r.request == request && &r.params == params)
    }

    /// The cached embeddings of `embedder` at `size` (width, height), if present.
    pub fn embeddings(&self, embedder: &str, size: (u32, u32)) -> Option<&EmbeddingCache> {
        (self.embeddings.iter()).find(|e| e.embedder == embedder && (e.width, e.height) == size)
    }

    /// The cached scores for `metric` on `rows` (None: all) of `width` x `height` frames, if
    /// present.
    pub fn sharpness(
        &self,
        metric: Metric,
        (width, height): (u32, u32),
        rows: Option<Rows>,
    ) -> Option<&SharpnessSeries> {
        self.sharpness.iter().find(|s| {
            s.metric == metric && s.width == width && s.height == height && s.rows == rows
        })
    }
}

impl<H> Project<H> {
    /// The input's path resolved against the folder of the project file at `project_path`.
    pub fn input_path(&self, project_path: &Path) -> PathBuf {
        if self.input.path.is_absolute() {
            return self.input.path.clone();
        }
        let base = fsutil::absolute(project_path);
        base.parent()
            .map(|d| d.join(&self.input.path))
            .unwrap_or_else(|| self.input.path.clone())
    }

    /// Checks the invariants serde cannot but the history's: version; positive sizes and rates;
    /// the frame count against every per-frame series; finite, strictly increasing timestamps;
    /// sorted keyframes within the input; cache keys (Farneback parameters, statistic, analysis
    /// width, stride, derotation, stationary parameters) in the ranges the flags accept. The
    /// error is (field path, message).
    fn validate(&self) -> Checked {
        if !READS.contains(&self.schema_version) {
            let v = self.schema_version;
            let msg = format!("version {v} is not supported by this build (reads {READS:?})");
            return fail("schema_version", msg);
        }
        let n = self.metadata.frame_count;
        self.validate_metadata()?;
        self.validate_selection(n)?;
        self.validate_timestamps(n)?;
        self.validate_sharpness(n)?;
        self.validate_movement(n)?;
        self.validate_stationary(n)?;
        self.validate_embeddings(n)?;
        self.validate_telemetry(n)
    }

    /// Embedding series: a positive size, and either hex text for each frame or a series file
    /// named plainly (in the project's folder, ending in `.emb`).
    fn validate_embeddings(&self, n: usize) -> Checked {
        for (i, e) in self.cache.embeddings.iter().enumerate() {
            let at = |k: &str| format!("cache.embeddings[{i}].{k}");
            analysis_size(at("width"), e.width, e.height)?;
            match (&e.file, e.frames.is_empty()) {
                (Some(f), true) => {
                    let plain = !f.contains(['/', '\\', '\0']) && f.ends_with(".emb");
                    if !plain || Path::new(f).file_name() != Some(std::ffi::OsStr::new(f)) {
                        let msg = format!("`{f}` must be a plain file name ending in .emb");
                        return fail(at("file"), msg);
                    }
                }
                (None, false) => per_frame(at("frames"), "embeddings", e.frames.len(), n)?,
                (Some(_), false) => return fail(at("file"), "give `file` or `frames`, not both"),
                (None, true) => return fail(at("file"), "names no series file"),
            }
        }
        Ok(())
    }

    /// Keyframes, damaged frames and boundaries: within the input, sorted and distinct.
    fn validate_selection(&self, n: usize) -> Checked {
        if let Some(i) = self.keyframes.windows(2).position(|w| w[0] >= w[1]) {
            let (a, b) = (self.keyframes[i], self.keyframes[i + 1]);
            let msg = format!("{b} follows {a}: keyframes must be sorted and distinct");
            return fail(format!("keyframes[{}]", i + 1), msg);
        }
        if let Some((i, k)) = self.keyframes.iter().enumerate().find(|(_, &k)| k >= n) {
            let msg = format!("frame {k} is beyond the input's {n} frames");
            return fail(format!("keyframes[{i}]"), msg);
        }
        check_frames(&self.damaged_frames, n).map_err(|msg| ("damaged_frames".into(), msg))?;
        let ends = [
            ("start", self.boundaries.start),
            ("end", self.boundaries.end),
        ];
        for (name, b) in ends {
            if let Some(crate::steps::Bound::Seconds(s)) = b {
                at_field(
                    format!("boundaries.{name}.seconds"),
                    non_negative_seconds(s),
                )?;
            }
        }
        Ok(())
    }

    /// One finite, strictly increasing timestamp per frame.
    fn validate_timestamps(&self, n: usize) -> Checked {
        let Some(ts) = &self.cache.timestamps_s else {
            return Ok(());
        };
        per_frame("cache.timestamps_s".into(), "timestamps", ts.len(), n)?;
        if let Some(i) = ts.iter().position(|t| !t.is_finite()) {
            let msg = format!("must be a finite number of seconds, got {}", ts[i]);
            return fail(format!("cache.timestamps_s[{i}]"), msg);
        }
        if let Some(i) = ts.windows(2).position(|w| w[1] <= w[0]) {
            let msg = format!(
                "{} follows {}: timestamps must increase strictly",
                ts[i + 1],
                ts[i]
            );
            return fail(format!("cache.timestamps_s[{}]", i + 1), msg);
        }
        Ok(())
    }

    /// Sharpness series: a positive analysis size, one finite non-negative score per frame.
    fn validate_sharpness(&self, n: usize) -> Checked {
        for (i, series) in self.cache.sharpness.iter().enumerate() {
            let at = |k: &str| format!("cache.sharpness[{i}].{k}");
            analysis_size(at("width"), series.width, series.height)?;
            if let Some(Err(e)) = series.rows.map(|r| r.check(series.height)) {
                return fail(at("rows"), e.to_string());
            }
            per_frame(at("scores"), "scores", series.scores.len(), n)?;
            if let Some(j) = series
                .scores
                .iter()
                .position(|v| !v.is_finite() || *v < 0.0)
            {
                return fail(
                    at(&format!("scores[{j}]")),
                    "scores must be finite and non-negative",
                );
            }
        }
        Ok(())
    }

    /// Movement series: a valid request, positive sizes and scale, one value per frame.
    fn validate_movement(&self, n: usize) -> Checked {
        for (i, m) in self.cache.movement.iter().enumerate() {
            let at = |k: &str| format!("cache.movement[{i}].{k}");
            validate_request(&m.request).map_err(under(at("request")))?;
            let s = &m.series;
            analysis_size(at("series.width"), s.width, s.height)?;
            at_field(at("series.scale_to_full"), positive(s.scale_to_full))?;
            per_frame(at("series.values"), "values", s.values.len(), n)?;
            if let Some(j) = s.values.iter().position(|v| !v.is_finite() || *v < 0.0) {
                let msg = format!(
                    "movement must be finite and non-negative, got {}",
                    s.values[j]
                );
                return fail(at(&format!("series.values[{j}]")), msg);
            }
        }
        Ok(())
    }

    /// Stationary runs: a valid request and parameters, keyframes of the input.
    fn validate_stationary(&self, n: usize) -> Checked {
        for (i, r) in self.cache.stationary.iter().enumerate() {
            let at = |k: &str| format!("cache.stationary[{i}].{k}");
            validate_request(&r.request).map_err(under(at("request")))?;
            let p = &r.params;
            at_field(at("params.threshold"), positive_px(p.threshold))?;
            if p.reset_delta == 0 {
                return fail(at("params.reset_delta"), "must be at least 1 frame");
            }
            if p.first > p.last || p.last >= n {
                let (a, b) = (p.first, p.last);
                let msg = format!("the range {a}..={b} is not within the input's {n} frames");
                return fail(at("params.last"), msg);
            }
            check_frames(&r.keyframes, n).map_err(|msg| (at("keyframes"), msg))?;
        }
        Ok(())
    }

    /// Telemetry: one entry per frame, latitudes and longitudes in range, finite numbers.
    fn validate_telemetry(&self, n: usize) -> Checked {
        let Some(tel) = &self.cache.telemetry else {
            return Ok(());
        };
        let at = |k: &str| format!("cache.telemetry.{k}");
        if !tel.source.offset_s.is_finite() {
            return fail(at("source.offset_s"), "must be a finite number");
        }
        per_frame(at("positions"), "positions", tel.positions.len(), n)?;
        for (i, p) in tel.positions.iter().enumerate() {
            let Some(p) = p else { continue };
            let optional = [
                p.rel_alt_m,
                p.abs_alt_m,
                p.gimbal_pitch_deg,
                p.gimbal_yaw_deg,
                p.focal_35mm,
            ];
            if !(p.lat_deg.abs() <= 90.0 && p.lon_deg.abs() <= 180.0)
                || optional.iter().flatten().any(|v| !v.is_finite())
            {
                return fail(
                    at(&format!("positions[{i}]")),
                    "latitude within ±90°, longitude within ±180° and finite numbers",
                );
            }
        }
        Ok(())
    }

    fn validate_metadata(&self) -> Checked {
        let m = &self.metadata;
        let at = |k: &str| format!("metadata.{k}");
        if m.frame_count == 0 {
            return fail(at("frame_count"), "an input has at least one frame");
        }
        if m.width == 0 || m.height == 0 {
            let k = if m.width == 0 { "width" } else { "height" };
            let msg = format!("the frame size {}x{} must be positive", m.width, m.height);
            return fail(at(k), msg);
        }
        if let Some(f) = m.fps {
            at_field(at("fps"), positive(f))?;
        }
        match m.duration_s {
            Some(d) => at_field(at("duration_s"), non_negative_seconds(d)),
            None => Ok(()),
        }
    }

    /// Writes the project file atomically, refusing to replace an existing one unless `force`.
    pub fn save(&self, path: &Path, force: bool) -> Result<()>
    where
        H: Serialize,
    {
        let _held = crate::output::check_file(path, force, &crate::output::Inputs::none())?;
        let mut text = serde_json::to_string_pretty(self)
            .map_err(|e| Error::file(path, None, "project file", "", e.to_string()))?;
        text.push('\n');
        fsutil::write_atomic(path, text.as_bytes())
    }
}

impl Project {
    /// Reads and validates a project file, its history read once into [`Recorded`] steps: known
    /// step ids and backends, the parameters `workflow save` reads in their ranges. Everything
    /// that reads a loaded project (export, report, `workflow save`) can trust it.
    pub fn load(path: &Path) -> Result<Project> {
        let stored: Project<Stored> = crate::output::read_json(path, "project file")?;
        let bad = |(field, msg)| Error::file(path, None, "project file", field, msg);
        stored.validate().map_err(bad)?;
        let n = stored.metadata.frame_count;
        let read = |(i, e)| read_step(e, n).map_err(under(format!("history[{i}]")));
        let history = (stored.history.into_iter().enumerate())
            .map(read)
            .collect::<std::result::Result<_, _>>()
            .map_err(bad)?;
        let mut cache = stored.cache;
        let dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
        for e in &mut cache.embeddings {
            e.dir = dir.clone();
        }
        Ok(Project {
            schema_version: stored.schema_version,
            tool_version: stored.tool_version,
            input: stored.input,
            metadata: stored.metadata,
            boundaries: stored.boundaries,
            keyframes: stored.keyframes,
            history,
            cache,
            decode_problems: stored.decode_problems,
            damaged_frames: stored.damaged_frames,
            preview: stored.preview,
            projection: stored.projection,
        })
    }
}

/// A check's outcome: on failure, the path of the offending field and what is wrong with it.
type Checked = std::result::Result<(), (String, String)>;

/// The failure `msg` at `field`.
fn fail(field: impl Into<String>, msg: impl Into<String>) -> Checked {
    Err((field.into(), msg.into()))
}

/// Puts a failure whose field is relative to `prefix` under it (an empty field is `prefix`).
fn under(prefix: String) -> impl FnOnce((String, String)) -> (String, String) {
    move |(k, msg)| match k.is_empty() {
        true => (prefix, msg),
        false => (format!("{prefix}.{k}"), msg),
    }
}

/// `len` values of a per-frame series called `what`, for an input of `n` frames.
fn per_frame(field: String, what: &str, len: usize, n: usize) -> Checked {
    if len != n {
        return fail(field, format!("{len} {what} for {n} frames"));
    }
    Ok(())
}

/// An analysis size with both sides positive.
fn analysis_size(field: String, width: u32, height: u32) -> Checked {
    if width == 0 || height == 0 {
        let msg = format!("the analysis size {width}x{height} must be positive");
        return fail(field, msg);
    }
    Ok(())
}

/// A number check's outcome for `field`.
fn at_field(field: String, checked: std::result::Result<f64, String>) -> Checked {
    checked.map(drop).map_err(|msg| (field, msg))
}

/// A movement request's fields in the ranges the flags accept; the error's key is relative to
/// the request (`farneback.pyr_scale`).
fn validate_request(r: &MovementRequest) -> Checked {
    r.validate().map_err(|e| match e {
        Error::Param { name, msg } => {
            let k = match name.as_str() {
                "trim" => "statistic.trimmed_mean.trim".to_string(),
                "hfov" => "derotate.hfov_deg".to_string(),
                "flow_stride" => "stride".to_string(),
                "analysis_width" => name,
                other => format!("farneback.{other}"),
            };
            (k, msg)
        }
        other => (String::new(), other.to_string()),
    })
}

/// Frame indices that are sorted, distinct and within an input of `n` frames.
fn check_frames(frames: &[usize], n: usize) -> std::result::Result<(), String> {
    if frames.windows(2).any(|w| w[0] >= w[1]) || frames.iter().any(|&k| k >= n) {
        return Err("must be sorted, distinct frame indices of the input".into());
    }
    Ok(())
}

/// One history step: a known step id, a known backend, and the parameters `workflow save` reads
/// in their ranges. The error's key is relative to the step (`params.fps`).
fn read_step(step: Stored, n: usize) -> std::result::Result<Recorded, (String, String)> {
    if step.kept > n {
        let msg = format!("{} kept frames of an input of {n} frames", step.kept);
        return Err(("kept".into(), msg));
    }
    let step = Recorded::from_stored(step)?;
    if let (_, Some(r)) = step.applied.analysis() {
        validate_request(&r).map_err(under("params.movement".into()))?;
    }
    step.applied.check(n)?;
    Ok(step)
}
