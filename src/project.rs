//! The project file (JSON): input reference and fingerprint, metadata, boundaries, keyframes, the
//! per-frame cache (timestamps, scores, telemetry positions) and the history of steps. Loading
//! validates every field and names the offending one; saving is atomic.
//!
//! Versions: 2 adds `cache.telemetry` (per-frame positions and where they came from, absent when
//! the input has none); version 1 files load unchanged (they have no positions) and are written
//! back as version 2.

use crate::error::{Error, Result};
use crate::fsutil::{self, Fingerprint};
use crate::params::{Backend, Metric, MovementRequest, MovementSeries, StationaryRequest};
use crate::source::telemetry::{Position, TelemetryKind};
use crate::source::{Metadata, SourceKind};
use crate::steps::Boundaries;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub use crate::steps::HistoryEntry;

/// Version of the project file layout this build writes.
pub const SCHEMA_VERSION: u32 = 2;

/// Versions this build reads: 1 is 2 without `cache.telemetry`.
const READS: [u32; 2] = [1, SCHEMA_VERSION];

/// A keyframe selection and everything needed to reproduce and export it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Project {
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
    pub history: Vec<HistoryEntry>,
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
}

/// Per-frame positions from telemetry and where they came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TelemetryCache {
    /// The file read: the key under which the positions are reused.
    pub source: TelemetrySource,
    /// What was wrong with it (`FILE:line N: ...`), as `select` warned.
    pub warnings: Vec<String>,
    /// One entry per frame: its position interpolated at the frame's timestamp, `null` for a
    /// frame outside the telemetry's time span (or an image without GPS tags).
    pub positions: Vec<Option<Position>>,
    /// The camera of `telemetry::CAMERAS` the video's container tags or the first image's EXIF
    /// model name, when one does.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<String>,
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

    /// The cached scores for `metric` at `width` x `height`, if present.
    pub fn sharpness(&self, metric: Metric, width: u32, height: u32) -> Option<&SharpnessSeries> {
        self.sharpness
            .iter()
            .find(|s| s.metric == metric && s.width == width && s.height == height)
    }
}

impl Project {
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

    /// Reads and validates a project file.
    pub fn load(path: &Path) -> Result<Project> {
        let text = crate::output::read_text(path)?;
        let bad = |field: String, msg: String| Error::file(path, None, "project file", field, msg);
        let de = &mut serde_json::Deserializer::from_str(&text);
        let project: Project = serde_path_to_error::deserialize(de).map_err(|e| {
            let field = e.path().to_string();
            let inner = e.into_inner();
            bad(
                field,
                format!("{inner} (line {}, column {})", inner.line(), inner.column()),
            )
        })?;
        project.validate().map_err(|(field, msg)| bad(field, msg))?;
        Ok(project)
    }

    /// Checks the invariants serde cannot: version; positive sizes and rates; the frame count
    /// against every per-frame series; finite, strictly increasing timestamps; sorted keyframes
    /// within the input; cache keys (Farneback parameters, statistic, analysis width, stride,
    /// derotation, stationary parameters) in the ranges the flags accept; and the history's
    /// plugins, backends and parameters, so that everything that reads a loaded project (export,
    /// report, `workflow save`) can trust it. The error is (field path, message).
    pub fn validate(&self) -> std::result::Result<(), (String, String)> {
        if !READS.contains(&self.schema_version) {
            return Err((
                "schema_version".into(),
                format!(
                    "version {} is not supported by this build (reads {READS:?})",
                    self.schema_version
                ),
            ));
        }
        let n = self.metadata.frame_count;
        self.validate_metadata()?;
        self.validate_selection(n)?;
        self.validate_timestamps(n)?;
        self.validate_sharpness(n)?;
        self.validate_movement(n)?;
        self.validate_stationary(n)?;
        self.validate_telemetry(n)?;
        self.validate_history(n)
    }

    /// Keyframes, damaged frames and boundaries: within the input, sorted and distinct.
    fn validate_selection(&self, n: usize) -> std::result::Result<(), (String, String)> {
        for (i, w) in self.keyframes.windows(2).enumerate() {
            if w[0] >= w[1] {
                return Err((
                    format!("keyframes[{}]", i + 1),
                    format!(
                        "{} follows {}: keyframes must be sorted and distinct",
                        w[1], w[0]
                    ),
                ));
            }
        }
        if let Some((i, k)) = self.keyframes.iter().enumerate().find(|(_, &k)| k >= n) {
            return Err((
                format!("keyframes[{i}]"),
                format!("frame {k} is beyond the input's {n} frames"),
            ));
        }
        check_frames(&self.damaged_frames, n).map_err(|msg| ("damaged_frames".into(), msg))?;
        for (name, b) in [
            ("start", self.boundaries.start),
            ("end", self.boundaries.end),
        ] {
            if let Some(crate::steps::Bound::Seconds(s)) = b {
                if !(s.is_finite() && s >= 0.0) {
                    return Err((
                        format!("boundaries.{name}.seconds"),
                        format!("must be a non-negative number of seconds, got {s}"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// One finite, strictly increasing timestamp per frame.
    fn validate_timestamps(&self, n: usize) -> std::result::Result<(), (String, String)> {
        if let Some(ts) = &self.cache.timestamps_s {
            if ts.len() != n {
                return Err((
                    "cache.timestamps_s".into(),
                    format!("{} timestamps for {n} frames", ts.len()),
                ));
            }
            if let Some(i) = ts.iter().position(|t| !t.is_finite()) {
                return Err((
                    format!("cache.timestamps_s[{i}]"),
                    format!("must be a finite number of seconds, got {}", ts[i]),
                ));
            }
            if let Some(i) = ts.windows(2).position(|w| w[1] <= w[0]) {
                return Err((
                    format!("cache.timestamps_s[{}]", i + 1),
                    format!(
                        "{} follows {}: timestamps must increase strictly",
                        ts[i + 1],
                        ts[i]
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Sharpness series: a positive analysis size, one finite non-negative score per frame.
    fn validate_sharpness(&self, n: usize) -> std::result::Result<(), (String, String)> {
        for (i, series) in self.cache.sharpness.iter().enumerate() {
            let at = |k: &str| format!("cache.sharpness[{i}].{k}");
            if series.width == 0 || series.height == 0 {
                return Err((
                    at("width"),
                    format!(
                        "the analysis size {}x{} must be positive",
                        series.width, series.height
                    ),
                ));
            }
            if series.scores.len() != n {
                return Err((
                    at("scores"),
                    format!("{} scores for {n} frames", series.scores.len()),
                ));
            }
            if let Some(j) = series
                .scores
                .iter()
                .position(|v| !v.is_finite() || *v < 0.0)
            {
                return Err((
                    format!("cache.sharpness[{i}].scores[{j}]"),
                    "scores must be finite and non-negative".into(),
                ));
            }
        }
        Ok(())
    }

    /// Movement series: a valid request, positive sizes and scale, one value per frame.
    fn validate_movement(&self, n: usize) -> std::result::Result<(), (String, String)> {
        for (i, m) in self.cache.movement.iter().enumerate() {
            let at = |k: &str| format!("cache.movement[{i}].{k}");
            validate_request(&m.request).map_err(|(k, msg)| (at(&format!("request.{k}")), msg))?;
            let s = &m.series;
            if s.width == 0 || s.height == 0 {
                return Err((
                    at("series.width"),
                    format!(
                        "the analysis size {}x{} must be positive",
                        s.width, s.height
                    ),
                ));
            }
            if !(s.scale_to_full.is_finite() && s.scale_to_full > 0.0) {
                return Err((
                    at("series.scale_to_full"),
                    format!("must be a positive number, got {}", s.scale_to_full),
                ));
            }
            if s.values.len() != n {
                return Err((
                    at("series.values"),
                    format!("{} values for {n} frames", s.values.len()),
                ));
            }
            if let Some(j) = s.values.iter().position(|v| !v.is_finite() || *v < 0.0) {
                return Err((
                    at(&format!("series.values[{j}]")),
                    format!(
                        "movement must be finite and non-negative, got {}",
                        s.values[j]
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Stationary runs: a valid request and parameters, keyframes of the input.
    fn validate_stationary(&self, n: usize) -> std::result::Result<(), (String, String)> {
        for (i, r) in self.cache.stationary.iter().enumerate() {
            let at = |k: &str| format!("cache.stationary[{i}].{k}");
            validate_request(&r.request).map_err(|(k, msg)| (at(&format!("request.{k}")), msg))?;
            let p = &r.params;
            if !(p.threshold.is_finite() && p.threshold > 0.0) {
                return Err((
                    at("params.threshold"),
                    format!("must be a positive number of pixels, got {}", p.threshold),
                ));
            }
            if p.reset_delta == 0 {
                return Err((at("params.reset_delta"), "must be at least 1 frame".into()));
            }
            if p.first > p.last || p.last >= n {
                return Err((
                    at("params.last"),
                    format!(
                        "the range {}..={} is not within the input's {n} frames",
                        p.first, p.last
                    ),
                ));
            }
            check_frames(&r.keyframes, n).map_err(|msg| (at("keyframes"), msg))?;
        }
        Ok(())
    }

    /// Telemetry: one entry per frame, latitudes and longitudes in range, finite numbers.
    fn validate_telemetry(&self, n: usize) -> std::result::Result<(), (String, String)> {
        let Some(tel) = &self.cache.telemetry else {
            return Ok(());
        };
        let at = |k: &str| format!("cache.telemetry.{k}");
        if !tel.source.offset_s.is_finite() {
            return Err((at("source.offset_s"), "must be a finite number".into()));
        }
        if tel.positions.len() != n {
            return Err((
                at("positions"),
                format!("{} positions for {n} frames", tel.positions.len()),
            ));
        }
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
                return Err((
                    at(&format!("positions[{i}]")),
                    "latitude within ±90°, longitude within ±180° and finite numbers".into(),
                ));
            }
        }
        Ok(())
    }

    /// History entries: known plugins with parameters in range (see `validate_step`).
    fn validate_history(&self, n: usize) -> std::result::Result<(), (String, String)> {
        for (i, step) in self.history.iter().enumerate() {
            validate_step(step, n).map_err(|(k, msg)| {
                let field = if k.is_empty() {
                    format!("history[{i}]")
                } else {
                    format!("history[{i}].{k}")
                };
                (field, msg)
            })?;
        }
        Ok(())
    }

    fn validate_metadata(&self) -> std::result::Result<(), (String, String)> {
        let m = &self.metadata;
        let bad = |k: &str, msg: String| Err((format!("metadata.{k}"), msg));
        if m.frame_count == 0 {
            return bad("frame_count", "an input has at least one frame".into());
        }
        if m.width == 0 || m.height == 0 {
            return bad(
                if m.width == 0 { "width" } else { "height" },
                format!("the frame size {}x{} must be positive", m.width, m.height),
            );
        }
        if let Some(f) = m.fps {
            if !(f.is_finite() && f > 0.0) {
                return bad("fps", format!("must be a positive number, got {f}"));
            }
        }
        if let Some(d) = m.duration_s {
            if !(d.is_finite() && d >= 0.0) {
                return bad(
                    "duration_s",
                    format!("must be a non-negative number of seconds, got {d}"),
                );
            }
        }
        Ok(())
    }

    /// Writes the project file atomically, refusing to replace an existing one unless `force`.
    pub fn save(&self, path: &Path, force: bool) -> Result<()> {
        fsutil::check_overwrite(path, force)?;
        let mut text = serde_json::to_string_pretty(self)
            .map_err(|e| Error::file(path, None, "project file", "", e.to_string()))?;
        text.push('\n');
        fsutil::write_atomic(path, text.as_bytes())
    }
}

/// A movement request's fields in the ranges the flags accept; the error's key is relative to
/// the request (`farneback.pyr_scale`).
fn validate_request(r: &MovementRequest) -> std::result::Result<(), (String, String)> {
    crate::steps::check_movement(r).map_err(|e| match e {
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

/// One history step: a known plugin, a known backend, and the parameters `workflow save` reads
/// in their ranges. The error's key is relative to the step (`params.fps`).
fn validate_step(step: &HistoryEntry, n: usize) -> std::result::Result<(), (String, String)> {
    use crate::steps::Applied;
    let bad = |k: &str, msg: String| Err((k.to_string(), msg));
    if step.kept > n {
        return bad(
            "kept",
            format!("{} kept frames of an input of {n} frames", step.kept),
        );
    }
    let applied = Applied::from_entry(step)?;
    if let (_, Some(r)) = applied.analysis() {
        validate_request(&r).map_err(|(k, msg)| (format!("params.movement.{k}"), msg))?;
    }
    applied.check(n)
}
