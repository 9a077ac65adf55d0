//! keyframer: selects keyframes (and masks) from videos and image sequences for 3D reconstruction.
//! Per-frame analysis runs as WGSL compute shaders through wgpu, checked against OpenCV's CPU
//! implementation; OpenCV decodes, and exports. Without the default feature `opencv` only the
//! GPU layer, the kernels' GPU halves and the gpu backend's per-frame analysis are built.

pub mod analysis;
#[cfg(feature = "opencv")]
pub mod batch;
#[cfg(feature = "opencv")]
pub mod bench;
#[cfg(feature = "opencv")]
pub mod bench_pipeline;
#[cfg(feature = "opencv")]
pub mod colmap;
pub mod embedding_file;
#[cfg(feature = "opencv")]
pub mod encode;
pub mod equirect;
pub mod error;
#[cfg(feature = "opencv")]
pub mod eval;
#[cfg(feature = "opencv")]
pub mod export;
#[cfg(feature = "opencv")]
pub mod flo;
#[cfg(feature = "opencv")]
pub mod flow;
pub mod fsutil;
#[cfg(feature = "opencv")]
pub mod geotag;
pub mod gpu;
#[cfg(feature = "opencv")]
pub mod info;
pub mod kernels;
pub mod manifest;
pub mod model_desc;
pub mod names;
#[cfg(feature = "opencv")]
pub mod native;
pub mod numbers;
pub mod output;
pub mod params;
pub mod progress;
#[cfg(feature = "opencv")]
pub mod project;
#[cfg(feature = "opencv")]
pub mod reconstruct;
#[cfg(feature = "opencv")]
pub mod report;
#[cfg(feature = "opencv")]
pub mod review;
#[cfg(feature = "opencv")]
pub mod rig;
#[cfg(feature = "opencv")]
pub mod segment;
#[cfg(feature = "opencv")]
pub mod select;
pub mod source;
pub mod sparse;
pub mod steps;
pub mod synthetic;
pub mod tomlfile;
#[cfg(feature = "opencv")]
pub mod workflow;

pub use error::{Error, Result};
