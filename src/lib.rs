//! keyframer: selects keyframes (and masks) from videos and image sequences for 3D reconstruction.
//! Per-frame analysis runs as WGSL compute shaders through wgpu, checked against OpenCV's CPU
//! implementation; OpenCV decodes, and exports.

pub mod analysis;
pub mod batch;
pub mod bench;
pub mod bench_pipeline;
pub mod colmap;
pub mod embedding_file;
pub mod encode;
pub mod equirect;
pub mod error;
pub mod eval;
pub mod export;
pub mod flo;
pub mod flow;
pub mod fsutil;
pub mod geotag;
pub mod gpu;
pub mod info;
pub mod kernels;
pub mod manifest;
pub mod model_desc;
pub mod names;
pub mod native;
pub mod numbers;
pub mod output;
pub mod params;
pub mod progress;
pub mod project;
pub mod reconstruct;
pub mod report;
pub mod review;
pub mod rig;
pub mod segment;
pub mod select;
pub mod source;
pub mod sparse;
pub mod steps;
pub mod synthetic;
pub mod tomlfile;
pub mod workflow;

pub use error::{Error, Result};
