//! `flow`: the dense Farnebäck flow between two image files on the chosen backend, optionally
//! started from a given flow (a `.flo` of the images' size, checked before anything runs). The
//! opencv backend gives cv::calcOpticalFlowFarneback's flow bit for bit (through
//! `farneback::host` unless an initial flow is given).

use crate::error::{Error, Result};
use crate::gpu;
use crate::kernels::{farneback, movement};
use crate::params::FarnebackParams;
use crate::params::{Backend, BackendChoice, Statistic};
use opencv::core::Mat;
use opencv::prelude::*;
use std::path::Path;

/// The flow between two images and how it was computed.
pub struct FlowResult {
    /// The flow field, CV_32FC2, the images' size.
    pub field: Mat,
    /// The backend that computed it (gpu falls back to opencv without an adapter or after a
    /// GPU fault).
    pub backend: Backend,
    /// Median flow magnitude in pixels.
    pub median_px: f64,
}

/// Reads an image file as 8-bit gray.
fn read_gray(path: &Path) -> Result<Mat> {
    if !path.is_file() {
        return Err(Error::input(path, "no such image file"));
    }
    let name = path.to_str().unwrap_or_default();
    let m = opencv::imgcodecs::imread(name, opencv::imgcodecs::IMREAD_GRAYSCALE)
        .map_err(|e| Error::input(path, e.message))?;
    if m.empty() {
        return Err(Error::input(path, "cannot read as an image"));
    }
    Ok(m)
}

/// The flow on the CPU: keyframer's host Farnebäck (bit-identical to OpenCV's call, faster),
/// or OpenCV's call itself from an `initial` flow (which the host one does not take).
fn cpu_flow(a: &Mat, b: &Mat, params: &FarnebackParams, initial: Option<&Mat>) -> Result<Mat> {
    if initial.is_some() {
        return farneback::opencv(a, b, params, initial);
    }
    let expander = farneback::host::Expander::new(params)?;
    farneback::host::flow(&expander.expand(a)?, &expander.expand(b)?)
}

/// The flow from image `a` to image `b` (one size), from `initial` when given.
pub fn between_files(
    a: &Path,
    b: &Path,
    initial: Option<&Path>,
    params: &FarnebackParams,
    backend: BackendChoice,
    adapter: Option<&str>,
) -> Result<FlowResult> {
    params.validate()?;
    let (ga, gb) = (read_gray(a)?, read_gray(b)?);
    if (ga.cols(), ga.rows()) != (gb.cols(), gb.rows()) {
        return Err(Error::input(
            a,
            format!(
                "is {}x{} but {} is {}x{}; flow needs two images of one size",
                ga.cols(),
                ga.rows(),
                b.display(),
                gb.cols(),
                gb.rows()
            ),
        ));
    }
    let (w, h) = (ga.cols() as u32, ga.rows() as u32);
    let initial = initial
        .map(|p| crate::flo::read_sized(p, w, h))
        .transpose()?;
    let (backend, ctx) = gpu::resolve_backend(backend, adapter);
    let (field, backend) = gpu::or_opencv("the flow", backend, ctx.as_ref(), |b, c| {
        Ok(match c {
            Some(c) => (
                farneback::FarnebackGpu::new(c.clone(), *params, w, h)?.flow_from(
                    &ga,
                    &gb,
                    initial.as_ref(),
                )?,
                b,
            ),
            None => (cpu_flow(&ga, &gb, params, initial.as_ref())?, b),
        })
    })?;
    let mags = movement::magnitudes(&field)?;
    let median_px = movement::cpu(&mags, Statistic::Median)?;
    Ok(FlowResult {
        field,
        backend,
        median_px,
    })
}
