//! The project file (JSON): input reference and fingerprint, metadata, boundaries, keyframes, the
//! per-frame cache (timestamps, scores) and the history of steps. Loading validates every field and
//! names the offending one; saving is atomic.

use crate::analysis::{MovementRequest, MovementSeries, StationaryRequest};
use crate::error::{Error, Result};
use crate::fsutil::{self, Fingerprint};
use crate::gpu::Backend;
use crate::kernels::sharpness::Metric;
use crate::samplers::Boundaries;
use crate::source::{Metadata, SourceKind};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Version of the project file layout this build reads and writes.
pub const SCHEMA_VERSION: u32 = 1;

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
    pub history: Vec<Step>,
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

/// One step of the selection history.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Step {
    /// Stable plugin id (`boundaries`, `every-nth`, `fps`, `manual`, ...).
    pub plugin: String,
    /// The step's parameters as given.
    pub params: serde_json::Value,
    /// Number of frames the step kept.
    pub kept: usize,
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
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let bad = |field: String, msg: String| Error::File {
            path: path.to_path_buf(),
            line: None,
            what: "project file",
            field,
            msg,
        };
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

    /// Checks the invariants serde cannot: version, ordering and ranges of indices.
    pub fn validate(&self) -> std::result::Result<(), (String, String)> {
        if self.schema_version != SCHEMA_VERSION {
            return Err((
                "schema_version".into(),
                format!(
                    "version {} is not supported by this build (expects {SCHEMA_VERSION})",
                    self.schema_version
                ),
            ));
        }
        let n = self.metadata.frame_count;
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
        if self.damaged_frames.windows(2).any(|w| w[0] >= w[1])
            || self.damaged_frames.iter().any(|&k| k >= n)
        {
            return Err((
                "damaged_frames".into(),
                "must be sorted, distinct frame indices of the input".into(),
            ));
        }
        if let Some(ts) = &self.cache.timestamps_s {
            if ts.len() != n {
                return Err((
                    "cache.timestamps_s".into(),
                    format!("{} timestamps for {n} frames", ts.len()),
                ));
            }
        }
        for (i, series) in self.cache.sharpness.iter().enumerate() {
            if series.scores.len() != n {
                return Err((
                    format!("cache.sharpness[{i}].scores"),
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
        for (i, m) in self.cache.movement.iter().enumerate() {
            if m.series.values.len() != n {
                return Err((
                    format!("cache.movement[{i}].series.values"),
                    format!("{} values for {n} frames", m.series.values.len()),
                ));
            }
        }
        for (i, r) in self.cache.stationary.iter().enumerate() {
            if r.keyframes.windows(2).any(|w| w[0] >= w[1]) || r.keyframes.iter().any(|&k| k >= n) {
                return Err((
                    format!("cache.stationary[{i}].keyframes"),
                    "must be sorted, distinct frame indices of the input".into(),
                ));
            }
        }
        Ok(())
    }

    /// Writes the project file atomically, refusing to replace an existing one unless `force`.
    pub fn save(&self, path: &Path, force: bool) -> Result<()> {
        fsutil::check_overwrite(path, force)?;
        let mut text = serde_json::to_string_pretty(self).map_err(|e| Error::File {
            path: path.to_path_buf(),
            line: None,
            what: "project file",
            field: String::new(),
            msg: e.to_string(),
        })?;
        text.push('\n');
        fsutil::write_atomic(path, text.as_bytes())
    }
}
