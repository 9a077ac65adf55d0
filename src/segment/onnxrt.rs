//! Runs an ONNX network through ONNX Runtime (the `ort` crate), loading `libonnxruntime` at run
//! time from `ORT_DYLIB_PATH`; a missing or unloadable library is an error, never a panic.

use super::desc::ModelDesc;
use super::tensor::{mismatch, Output};
use crate::error::{Error, Result};
use ort::session::Session;
use ort::value::Tensor;
use std::path::PathBuf;
use std::sync::OnceLock;

/// Environment variable naming the ONNX Runtime shared library.
pub const LIB_VAR: &str = "ORT_DYLIB_PATH";

/// Where the runtime library is looked for: `ORT_DYLIB_PATH`, else `libonnxruntime.so` next to
/// the executable.
pub fn library_path() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os(LIB_VAR) {
        return Some(PathBuf::from(p));
    }
    let exe = std::env::current_exe().ok()?;
    let p = exe.parent()?.join("libonnxruntime.so");
    p.is_file().then_some(p)
}

fn environment() -> Result<&'static ort::environment::Environment> {
    static ENV: OnceLock<std::result::Result<ort::environment::Environment, String>> =
        OnceLock::new();
    ENV.get_or_init(|| {
        let Some(lib) = library_path() else {
            return Err(format!(
                "ONNX Runtime is not available: set {LIB_VAR} to libonnxruntime.so \
                 (scripts/setup.sh downloads version 1.31.1 into target/onnxruntime/), \
                 or use the opencv backend"
            ));
        };
        if !lib.is_file() {
            return Err(format!(
                "ONNX Runtime library {} ({LIB_VAR}) does not exist",
                lib.display()
            ));
        }
        let builder = ort::init_from(&lib)
            .map_err(|e| format!("cannot load ONNX Runtime from {}: {e}", lib.display()))?;
        builder
            .with_name("keyframer")
            .with_telemetry(false)
            .build()
            .map_err(|e| format!("ONNX Runtime from {}: {e}", lib.display()))
    })
    .as_ref()
    .map_err(|msg| Error::step("segment", msg.clone()))
}

/// An ONNX Runtime session ready to run.
pub struct OrtRunner {
    session: Session,
    input: String,
    output: String,
}

impl OrtRunner {
    /// Loads the ONNX model named by `desc` (CPU, two intra-op threads).
    pub fn load(desc: &ModelDesc) -> Result<OrtRunner> {
        let env = environment()?;
        let fail = |e: String| Error::input(&desc.model, format!("ONNX Runtime: {e}"));
        let threads = std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1);
        let session = Session::builder(env)
            .map_err(|e| fail(e.to_string()))?
            .with_intra_threads(threads)
            .map_err(|e| fail(e.to_string()))?
            .commit_from_file(&desc.model)
            .map_err(|e| fail(e.to_string()))?;
        // The name the description gives, else the model's first of `outlets`.
        let name = |given: &Option<String>, outlets: &[ort::value::Outlet], what: &str| match given
        {
            Some(n) => Ok(n.clone()),
            None => (outlets.first().map(|o| o.name().to_string()))
                .ok_or_else(|| fail(format!("the model has no {what}"))),
        };
        Ok(OrtRunner {
            input: name(&desc.input.name, session.inputs(), "inputs")?,
            output: name(&desc.output.name, session.outputs(), "outputs")?,
            session,
        })
    }

    /// Runs the network on an input tensor of `shape`; returns the output's shape and values.
    pub fn run(&mut self, desc: &ModelDesc, shape: &[usize; 4], data: &[f32]) -> Result<Output> {
        let dims: Vec<i64> = shape.iter().map(|&d| d as i64).collect();
        let tensor = Tensor::from_array((dims, data.to_vec()))
            .map_err(|e| mismatch(desc, format!("input tensor: {e}")))?;
        let outputs = self
            .session
            .run(ort::inputs![self.input.as_str() => tensor])
            .map_err(|e| {
                mismatch(
                    desc,
                    format!("ONNX Runtime failed on a {shape:?} input: {e}"),
                )
            })?;
        let value = outputs
            .get(self.output.as_str())
            .ok_or_else(|| mismatch(desc, format!("no output named `{}`", self.output)))?;
        let (oshape, values) = value
            .try_extract_tensor::<f32>()
            .map_err(|e| mismatch(desc, format!("output `{}`: {e}", self.output)))?;
        let oshape = oshape.iter().map(|&d| d.max(0) as usize).collect();
        Ok((oshape, values.to_vec()))
    }
}
