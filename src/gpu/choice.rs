//! Which backend runs an analysis: `auto`'s rule per adapter class (one place, said once per
//! process), the resolution of a requested backend to the one used, and the redo on opencv after
//! a GPU fault. Projects record the resolved backend only.

use super::{pick_adapter, shared, GpuContext};
use crate::error::{Error, Result};
use crate::params::{Backend, BackendChoice};
use std::sync::{Arc, Mutex};

/// How `auto` sees an adapter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AdapterClass {
    /// A discrete, integrated or virtual GPU (or a device wgpu cannot classify).
    Hardware,
    /// A rasteriser running on the CPU: wgpu's device type `Cpu`, or a name of Mesa's
    /// llvmpipe/lavapipe, Google's SwiftShader or Microsoft's WARP ("Microsoft Basic Render
    /// Driver"), whatever type the driver reports.
    Software,
}

impl AdapterClass {
    /// The class of the adapter `info` describes.
    pub fn of(info: &wgpu::AdapterInfo) -> AdapterClass {
        const SOFTWARE_NAMES: [&str; 5] = [
            "llvmpipe",
            "lavapipe",
            "swiftshader",
            "microsoft basic render driver",
            "warp",
        ];
        let name = info.name.to_lowercase();
        if info.device_type == wgpu::DeviceType::Cpu
            || SOFTWARE_NAMES.iter().any(|n| name.contains(n))
        {
            AdapterClass::Software
        } else {
            AdapterClass::Hardware
        }
    }

    /// The backend `auto` uses on this class of adapter. Software adapters get opencv: on Mesa
    /// lavapipe (2 cores, 2026-11-25) `keyframer bench sharpness --frames 16` measures opencv/gpu
    /// 0.54 for 1080p Tenengrad and 0.92–1.26 for the Laplacians, `keyframer bench flow --frames
    /// 6` 0.38–0.85, and `keyframer bench pipeline` the gpu analysis at 3.2x the opencv backend's
    /// time: the shaders run on the same CPU cores as OpenCV's SIMD code and the decoder.
    /// Flip a class to gpu here once `bench` measures the kernels at least as fast there.
    pub fn auto_backend(self) -> Backend {
        match self {
            AdapterClass::Hardware => Backend::Gpu,
            AdapterClass::Software => Backend::Opencv,
        }
    }
}

/// What `auto` resolves to on this machine, and why (`keyframer info` shows it).
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct AutoDecision {
    /// `gpu` or `opencv`.
    pub backend: Backend,
    /// One sentence: the adapter and its class, or why there is none.
    pub reason: String,
}

impl std::fmt::Display for AutoDecision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "backend auto: {} ({})", self.backend, self.reason)
    }
}

/// The text of `e` (a GPU error's without its "GPU: ").
fn message(e: Error) -> String {
    let text = e.to_string();
    match e {
        Error::Gpu { .. } => text.strip_prefix("GPU: ").unwrap_or(&text).to_string(),
        _ => text,
    }
}

/// What `auto` resolves to with adapter choice `adapter` (see [`AdapterClass::auto_backend`]).
pub fn auto_backend(adapter: Option<&str>) -> AutoDecision {
    let info = match pick_adapter(adapter) {
        Ok(a) => a.get_info(),
        Err(e) => {
            return AutoDecision {
                backend: Backend::Opencv,
                reason: message(e),
            }
        }
    };
    let class = AdapterClass::of(&info);
    let backend = class.auto_backend();
    let (class_name, other) = (
        match class {
            AdapterClass::Hardware => "hardware",
            AdapterClass::Software => "software",
        },
        match backend {
            Backend::Gpu => "--backend opencv forces OpenCV",
            Backend::Opencv => "--backend gpu forces the WGSL kernels",
        },
    );
    AutoDecision {
        backend,
        reason: format!("{} is a {class_name} adapter; {other}", info.name),
    }
}

/// [`auto_backend`], decided and said on stderr once per process and adapter choice (a `run`
/// over many inputs says it once).
fn auto_backend_once(adapter: Option<&str>) -> Backend {
    static DECIDED: Mutex<Vec<(Option<String>, Backend)>> = Mutex::new(Vec::new());
    let key = adapter.map(str::to_string);
    let Ok(mut decided) = DECIDED.lock() else {
        return auto_backend(adapter).backend;
    };
    if let Some((_, b)) = decided.iter().find(|(k, _)| *k == key) {
        return *b;
    }
    let d = auto_backend(adapter);
    log::info!("{d}");
    decided.push((key, d.backend));
    d.backend
}

/// Resolves the requested backend to the one used: `auto` by [`auto_backend`]; `gpu` without a
/// usable adapter warns and returns `opencv`. Returns the context when the gpu backend is used:
/// one per process and adapter, shared by every stage, worker and `run` job (pipelines compile
/// once; a context that reported a fault is replaced).
pub fn resolve_backend(
    requested: BackendChoice,
    adapter: Option<&str>,
) -> (Backend, Option<Arc<GpuContext>>) {
    let backend = match requested {
        BackendChoice::Auto => auto_backend_once(adapter),
        BackendChoice::Gpu => Backend::Gpu,
        BackendChoice::Opencv => Backend::Opencv,
    };
    match backend {
        Backend::Opencv => (Backend::Opencv, None),
        Backend::Gpu => match shared(adapter) {
            Ok(ctx) => (Backend::Gpu, Some(ctx)),
            Err(e) => {
                log::warn!("{e}; falling back to the opencv backend");
                (Backend::Opencv, None)
            }
        },
    }
}

/// Runs `work` on `backend` (with `ctx` on gpu). A GPU fault while it ran (an error the device
/// reported, or any [`Error::Gpu`]) is warned about, naming the fault, and `work` is redone on
/// opencv, whose result (saying opencv) is returned; other errors are returned as they are.
pub fn or_opencv<T>(
    what: &str,
    backend: Backend,
    ctx: Option<&Arc<GpuContext>>,
    mut work: impl FnMut(Backend, Option<&Arc<GpuContext>>) -> Result<T>,
) -> Result<T> {
    if let (Backend::Gpu, Some(c)) = (backend, ctx) {
        let fault = match work(Backend::Gpu, Some(c)) {
            Ok(v) => match c.check() {
                Ok(()) => return Ok(v),
                Err(fault) => fault,
            },
            Err(e) => match (c.check(), e) {
                (Err(fault), _) | (Ok(()), fault @ Error::Gpu { .. }) => fault,
                (Ok(()), other) => return Err(other),
            },
        };
        let fault = message(fault);
        log::warn!("{what} failed on the gpu backend ({fault}); redoing it on the opencv backend");
    }
    work(Backend::Opencv, None)
}
