//! Analysis: one decode pass over an input that yields the exact frame count, every frame's
//! timestamp and the requested per-frame scores: sharpness, camera movement between consecutive
//! frames, and the stationary sampler's keyframes (its reference mode needs movement between
//! frame pairs that depend on the threshold, so the movement pass feeds it while decoding).
//! Frames stream through in small batches (bounded memory); when nothing needs pixels, frames are
//! only grabbed, never converted. The parts: `ingest` (decode thread, frame hand-off),
//! `sharpness` and `movement` (engines behind traits), `checkpoint`; this module wires them.
//! `stream` feeds the gpu backend's engines frames from memory instead (no decoder, no OpenCV).

// Without OpenCV only `stream` drives these (no resume, no opencv engine): parts stay unused.
#[cfg_attr(not(feature = "opencv"), allow(dead_code))]
mod checkpoint;
#[cfg_attr(not(feature = "opencv"), allow(dead_code))]
mod device;
#[cfg(feature = "opencv")]
mod embedding;
#[cfg(feature = "opencv")]
mod ingest;
#[cfg_attr(not(feature = "opencv"), allow(dead_code))]
mod movement;
#[cfg(feature = "opencv")]
mod priority;
#[cfg(feature = "opencv")]
mod run;
#[cfg(feature = "opencv")]
mod sharpness;
mod sphere;
mod stream;

pub use checkpoint::{is_checkpoint, Checkpoint, MovementState, Resume};
#[cfg(feature = "opencv")]
pub use movement::sample_movement;
#[cfg(feature = "opencv")]
pub use run::{analyse, analyse_source};
pub use stream::{DeviceAnalysis, DeviceResults};

use crate::params::{MovementRequest, MovementSeries, StationaryRequest};

use crate::manifest::SegRuntime;
use crate::params::{Backend, Metric, Rows};
use crate::source::Metadata;
use serde::{Deserialize, Serialize};

/// What to compute.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Request {
    /// Sharpness metrics to score every frame with.
    pub sharpness: Vec<Metric>,
    /// The rows sharpness is scored on (360° frames: `Rows::erp_band`); None: all.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sharpness_rows: Option<Rows>,
    /// Camera movement between consecutive frames.
    pub movement: Option<MovementRequest>,
    /// The stationary sampler's reference-mode run (requires `movement`).
    pub stationary: Option<StationaryRequest>,
    /// Each frame's built-in descriptor, on the frame resized to this width ([`analysis_size`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub descriptor: Option<u32>,
    /// With `descriptor`: the embeddings come from this network instead
    /// (`segment::embedding`), at its own input size.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub network: Option<std::path::PathBuf>,
    /// The runtime of `network` (OpenCV DNN when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub runtime: Option<SegRuntime>,
    /// With `descriptor`: the series file the embeddings are appended to (`embedding_file`;
    /// keyframer's own, replaced). Where the results go, not what is computed: no part of a
    /// checkpoint's request.
    #[serde(skip)]
    pub store: Option<std::path::PathBuf>,
}

impl Request {
    /// The request `select --stationary --blur --spacing` makes with its defaults for frames
    /// `width` wide, its movement at `analysis_width`: Tenengrad, the movement, the stationary
    /// run with its default threshold (1 % of the width). What `keyframer-gpu-bench` times and
    /// `tests/it/gpu_bench.rs` checks against the opencv backend.
    pub fn stationary_blur_spacing(width: u32, analysis_width: u32) -> Request {
        let mut movement = crate::steps::defaults::movement();
        movement.analysis_width = analysis_width;
        Request {
            sharpness: vec![Metric::Tenengrad],
            movement: Some(movement),
            stationary: Some(StationaryRequest {
                threshold: f64::from(width) * 0.01,
                reset_delta: crate::steps::defaults::RESET_DELTA,
                first: 0,
                last: usize::MAX,
            }),
            ..Request::default()
        }
    }
}

/// The analysis size for a `width` x `height` input: `analysis_width` wide (never wider than the
/// input), height scaled and rounded.
pub fn analysis_size(width: u32, height: u32, analysis_width: u32) -> (u32, u32) {
    let w = analysis_width.clamp(1, width.max(1));
    let h = ((f64::from(height) * f64::from(w) / f64::from(width.max(1))).round() as u32).max(1);
    (w, h)
}

/// The embeddings of every frame, as one pass computed them.
#[derive(Debug, Clone)]
pub struct Embedded {
    /// The series file holding them (`Request::store`).
    pub file: std::path::PathBuf,
    /// Values per frame.
    pub dim: usize,
    /// Frames in the file.
    pub count: usize,
    /// The network's runtime, when a network computed them.
    pub runtime: Option<SegRuntime>,
    /// The analysis size (width, height) the frames were described at.
    pub size: (u32, u32),
    /// Backend that computed them.
    pub backend: Backend,
}

/// What one pass produced.
#[derive(Debug, Clone)]
pub struct Analysis {
    /// Metadata with the decoded frame count.
    pub metadata: Metadata,
    /// Timestamp of every frame (None for image folders without a rate).
    pub timestamps_s: Option<Vec<f64>>,
    /// Scores per requested metric, one per frame.
    pub sharpness: Vec<(Metric, Vec<f64>)>,
    /// Movement between consecutive frames, when requested.
    pub movement: Option<MovementSeries>,
    /// Keyframes chosen by the stationary sampler, when requested.
    pub stationary: Option<Vec<usize>>,
    /// The series file of every frame's embedding, the size they were computed at and the
    /// backend that computed them, when requested.
    pub embeddings: Option<Embedded>,
    /// Decode problems (damaged stream, damaged images), one line each.
    pub problems: Vec<String>,
    /// Damaged frames that did not stop the input (image folders): their scores are those of a
    /// stand-in image, and they must never be selected.
    pub damaged: Vec<usize>,
    /// Backend that computed the scores.
    pub backend: Backend,
}
