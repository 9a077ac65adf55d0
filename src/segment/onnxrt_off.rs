//! Stand-in for the ONNX Runtime backend in a build without the `onnx` cargo feature: choosing
//! the `ort` mask backend is an error that says so; nothing else changes.

use super::desc::ModelDesc;
use super::tensor::Output;
use crate::error::{Error, Result};

/// Never constructed: [`OrtRunner::load`] always fails in this build.
pub enum OrtRunner {}

impl OrtRunner {
    /// Fails: keyframer was built without ONNX Runtime.
    pub fn load(desc: &ModelDesc) -> Result<OrtRunner> {
        Err(Error::step(
            "segment",
            format!(
                "cannot run {} with ONNX Runtime: keyframer was built without the `onnx` cargo \
                 feature (rebuild with default features, or use the opencv backend)",
                desc.model.display()
            ),
        ))
    }

    /// Unreachable: no runner exists.
    pub fn run(&mut self, _: &ModelDesc, _: &[usize; 4], _: &[f32]) -> Result<Output> {
        match *self {}
    }
}
