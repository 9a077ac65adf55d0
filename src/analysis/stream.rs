//! The gpu backend's per-frame analysis fed frames from memory (8-bit BGR, in order) instead of
//! a decoder: the engines `analyse` runs on the gpu backend with frames staged on the device
//! (each frame uploaded once; sharpness, INTER_AREA to the analysis size, Farneback, the movement
//! statistic and the stationary step there), in the same batches, with the device's stationary
//! decisions replayed and checked on the host. Builds without OpenCV (`keyframer-gpu-bench`).

use super::device::Pixels;
use super::movement::MovementPass;
use super::Request;
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::kernels::sharpness::SharpnessGpu;
use crate::params::Backend;
use crate::source::{Metadata, SourceKind};
use std::sync::Arc;

/// One stream of frames through the device analysis. Several may share one [`GpuContext`]
/// (each on its own thread).
pub struct DeviceAnalysis {
    size: (u32, u32),
    /// One runner per metric; the first also stages the resized gray for the movement.
    sharpness: Vec<SharpnessGpu>,
    movement: Option<MovementPass>,
    /// Frames handed to the engines so far.
    frames: usize,
    /// Scores taken so far, per metric.
    scores: Vec<Vec<f64>>,
}

/// What a stream's analysis produced.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceResults {
    /// Frames analysed.
    pub frames: usize,
    /// Scores per requested metric, one per frame.
    pub sharpness: Vec<Vec<f64>>,
    /// Movement from frame i-1 to frame i (full-resolution pixels), when requested.
    pub movement: Option<Vec<f64>>,
    /// The stationary step's keyframes, when requested.
    pub stationary: Option<Vec<usize>>,
}

impl DeviceAnalysis {
    /// The analysis `req` asks for (at least one sharpness metric: its engine stages the frames;
    /// no descriptor) on `width` x `height` frames. The analysis size must be an integer
    /// downscale of the frame (the staged path); anything the gpu backend cannot run is an
    /// error, never a fallback.
    pub fn new(ctx: &Arc<GpuContext>, req: &Request, (width, height): (u32, u32)) -> Result<Self> {
        if req.sharpness.is_empty() {
            let msg =
                "the device analysis stages frames through a sharpness runner: ask for a metric";
            return Err(Error::param("sharpness", msg));
        }
        if req.descriptor.is_some() || req.network.is_some() {
            let msg = "descriptors are not part of the device analysis";
            return Err(Error::param("descriptor", msg));
        }
        if req.stationary.is_some() && req.movement.is_none() {
            return Err(Error::param("stationary", "needs a movement request"));
        }
        if req.sharpness_rows.is_some() {
            let msg = "the device analysis scores whole frames (360° bands are not part of it)";
            return Err(Error::param("sharpness rows", msg));
        }
        let mut sharpness = (req.sharpness.iter())
            .map(|&m| SharpnessGpu::new(ctx.clone(), m, width, height))
            .collect::<Result<Vec<_>>>()?;
        let meta = Metadata {
            kind: SourceKind::Video,
            frame_count: 0,
            frame_count_exact: false,
            fps: None,
            width,
            height,
            duration_s: None,
            codec: None,
            rotation_deg: 0,
        };
        let movement = match req.movement {
            None => None,
            Some(m) => {
                let (mut pass, used) =
                    MovementPass::open(m, req.stationary, Backend::Gpu, Some(ctx), &meta)?;
                let small = (pass.size.0 as u32, pass.size.1 as u32);
                if used != Backend::Gpu || !pass.can_stage((width, height)) {
                    let msg = format!(
                        "{}x{} is no integer downscale of {width}x{height} on the device",
                        small.0, small.1
                    );
                    return Err(Error::param("analysis width", msg));
                }
                pass.use_staged(sharpness[0].attach_resize(small)?);
                Some(pass)
            }
        };
        let scores = vec![Vec::new(); sharpness.len()];
        Ok(DeviceAnalysis {
            size: (width, height),
            sharpness,
            movement,
            frames: 0,
            scores,
        })
    }

    /// Frames scored together (the batch `analyse` stages).
    pub fn batch(&self) -> usize {
        (self.sharpness.iter().map(SharpnessGpu::batch_size))
            .min()
            .unwrap_or(1)
    }

    /// Analyses the next `frames` (8-bit BGR rows, `width * height * 3` bytes each, in order),
    /// in batches of [`DeviceAnalysis::batch`] (a shorter last one): each batch is scored, then
    /// the movement steps through its staged grays (valid until the next batch), as the staged
    /// hand-off of `analyse` does. Results that came back are taken without waiting.
    pub fn push(&mut self, frames: &[&[u8]]) -> Result<()> {
        let want = self.size.0 as usize * self.size.1 as usize * 3;
        if let Some((k, f)) = frames.iter().enumerate().find(|(_, f)| f.len() != want) {
            let msg = format!(
                "has {} bytes, not the {want} of an 8-bit BGR frame",
                f.len()
            );
            return Err(Error::frame(
                std::path::PathBuf::new(),
                self.frames + k,
                msg,
            ));
        }
        for batch in frames.chunks(self.batch()) {
            for r in &mut self.sharpness {
                r.submit(batch)?;
            }
            for k in 0..batch.len() {
                if let Some(m) = self.movement.as_mut() {
                    m.step(self.frames + k, Pixels::Staged(k))?;
                }
            }
            self.frames += batch.len();
            self.take(false)?;
        }
        Ok(())
    }

    /// Takes the scores that came back (with `all`, every one: waits).
    fn take(&mut self, all: bool) -> Result<()> {
        for (r, s) in self.sharpness.iter_mut().zip(&mut self.scores) {
            s.extend(r.take(all)?);
        }
        Ok(())
    }

    /// Waits for every result of the frames pushed.
    pub fn finish(mut self) -> Result<DeviceResults> {
        self.take(true)?;
        if let Some(m) = self.movement.as_mut() {
            m.finish()?;
        }
        let (movement, stationary) = match self.movement {
            Some(m) => (Some(m.values), m.stationary.map(|s| s.keys().to_vec())),
            None => (None, None),
        };
        Ok(DeviceResults {
            frames: self.frames,
            sharpness: self.scores,
            movement,
            stationary,
        })
    }
}
