//! Frame ingest: a decode thread reads the input in order through a queue of a few frames (memory
//! stays bounded; frames before a resume point are only grabbed), and the hand-off gives each frame
//! its analysis pixels: a gray resized on the CPU in the decode thread, or, with a staging
//! sharpness engine, a device buffer resized from the gray the engine computed on the device.

use super::sharpness::SharpnessEngine;
use crate::error::{CvContext, Result};
use crate::kernels::resize_area;
use crate::source::{Frame, FrameSource};
use opencv::core::Mat;
use opencv::prelude::*;
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::thread::Scope;

/// Frames queued between the decode thread and the analysis (bounds memory with the batch).
const DECODE_QUEUE: usize = 2;

pub(crate) use super::device::Pixels;

/// Items from the decode thread.
pub(crate) enum Decoded {
    /// A frame to analyse (`image` is empty when no sharpness is requested) and its analysis
    /// gray when the CPU prepares it.
    Frame(Frame, Option<Mat>),
    /// An already analysed frame whose pixels a resumed movement state needs again: its
    /// analysis gray, or the frame itself when frames are staged on the device.
    Prime(usize, Mat),
}

/// Gray at the analysis resolution (cv::cvtColor's gray by [`crate::kernels::gray::host`], then
/// INTER_AREA, [`resize_area::host`], unless the size matches).
pub(crate) fn prepare(size: (i32, i32), image: &Mat) -> Result<Mat> {
    shrink(size, crate::kernels::gray::host(image)?)
}

/// `gray` at the analysis resolution (INTER_AREA unless the size matches).
fn shrink(size: (i32, i32), gray: Mat) -> Result<Mat> {
    if (gray.cols(), gray.rows()) == size {
        Ok(gray)
    } else {
        resize_area::host(&gray, opencv::core::Size::new(size.0, size.1))
    }
}

/// What the decode thread hands on with each frame.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Keep {
    /// The analysis size, when the CPU prepares the analysis gray.
    pub small: Option<(i32, i32)>,
    /// Frames keep their image (the sharpness worker scores it).
    pub image: bool,
    /// With `small`, the image a frame keeps is its full-resolution gray instead of the BGR
    /// frame (the worker scores gray): one conversion per frame, and a third of the bytes queued.
    pub gray: bool,
}

impl Keep {
    /// Frame `f`'s analysis gray (when `small`), its image replaced by what it keeps.
    fn apply(&self, f: &mut Frame) -> Result<Option<Mat>> {
        let Some(size) = self.small else {
            if !self.image {
                f.image = Mat::default();
            }
            return Ok(None);
        };
        let gray = crate::kernels::gray::host(&f.image)?;
        let small = match (gray.cols(), gray.rows()) == size {
            true => gray.try_clone().cv(|| "copy the gray frame".into())?,
            false => resize_area::host(&gray, opencv::core::Size::new(size.0, size.1))?,
        };
        match (self.image, self.gray) {
            (false, _) => f.image = Mat::default(),
            (true, true) => f.image = gray,
            (true, false) => {}
        }
        Ok(Some(small))
    }
}

/// Starts the decode thread over `src`: frames before `resume_at` are skipped (grabbed) except
/// those in `prime`; every frame gets its analysis gray and keeps its image as `keep` says.
pub(crate) fn spawn_decoder<'scope>(
    scope: &'scope Scope<'scope, '_>,
    src: &'scope mut dyn FrameSource,
    resume_at: usize,
    prime: &'scope [usize],
    keep: Keep,
) -> Receiver<Result<Decoded>> {
    let (tx, rx) = sync_channel::<Result<Decoded>>(DECODE_QUEUE);
    scope.spawn(move || decode(src, resume_at, prime, keep, tx));
    rx
}

fn decode(
    src: &mut dyn FrameSource,
    resume_at: usize,
    prime: &[usize],
    keep: Keep,
    tx: SyncSender<Result<Decoded>>,
) {
    let mut next = 0usize;
    loop {
        let item = if next < resume_at && !prime.contains(&next) {
            match src.skip_frame() {
                Ok(Some(_)) => {
                    next += 1;
                    continue;
                }
                Ok(None) => return,
                Err(e) => Err(e),
            }
        } else {
            match src.next_frame() {
                Ok(None) => return,
                Ok(Some(f)) if f.index < resume_at => {
                    next = f.index + 1;
                    // Without `small` the frame itself goes (staged on the device).
                    let gray = keep.small.map(|s| prepare(s, &f.image)).transpose();
                    gray.map(|g| Decoded::Prime(f.index, g.unwrap_or(f.image)))
                }
                Ok(Some(mut f)) => {
                    next = f.index + 1;
                    keep.apply(&mut f).map(|g| Decoded::Frame(f, g))
                }
                Err(e) => Err(e),
            }
        };
        let stop = item.is_err();
        if tx.send(item).is_err() || stop {
            return;
        }
    }
}

/// A frame ready for the analysis, in frame order, with its analysis pixels (when movement is
/// measured); the staging engine's scores of it come through [`HandOff::scores`].
pub(crate) struct Ready {
    pub frame: Frame,
    pub pixels: Option<Pixels>,
}

/// How decoded frames reach the analysis.
pub(crate) enum HandOff {
    /// The decode thread prepared the gray; frames go one by one.
    Cpu,
    /// The staging engine scores frames in batches and leaves frame k's resized gray in its
    /// small buffer k (gpu backend, integer downscale: each frame is uploaded once).
    Staged {
        engine: Box<dyn SharpnessEngine>,
        pending: Vec<Frame>,
    },
}

impl HandOff {
    /// The frames ready after `frame` arrives (none while a staged batch fills).
    pub(crate) fn frame(&mut self, frame: Frame, gray: Option<Mat>) -> Result<Vec<Ready>> {
        match self {
            HandOff::Cpu => Ok(vec![Ready {
                frame,
                pixels: gray.map(Pixels::Small),
            }]),
            HandOff::Staged { engine, pending } => {
                pending.push(frame);
                if pending.len() < engine.batch() {
                    return Ok(Vec::new());
                }
                staged_batch(engine.as_mut(), pending)
            }
        }
    }

    /// The pixels of a primed frame (`image` is its gray, or the frame when staged).
    pub(crate) fn prime(&mut self, image: Mat) -> Result<Pixels> {
        match self {
            HandOff::Cpu => Ok(Pixels::Small(image)),
            HandOff::Staged { engine, .. } => {
                engine.stage(&image)?;
                Ok(Pixels::Staged(0))
            }
        }
    }

    /// The staging engine's scores that came back (with `all`, of every frame handed on), in
    /// frame order, one vector per frame with one score per metric.
    pub(crate) fn scores(&mut self, all: bool) -> Result<Vec<Vec<f64>>> {
        match self {
            HandOff::Cpu => Ok(Vec::new()),
            HandOff::Staged { engine, .. } => engine.take(all),
        }
    }

    /// The frames still pending at the end of the input.
    pub(crate) fn end(&mut self) -> Result<Vec<Ready>> {
        match self {
            HandOff::Staged { engine, pending } if !pending.is_empty() => {
                staged_batch(engine.as_mut(), pending)
            }
            _ => Ok(Vec::new()),
        }
    }
}

/// Starts scoring the `pending` frames with the staging engine and hands them on with their
/// pixels, in order.
fn staged_batch(engine: &mut dyn SharpnessEngine, pending: &mut Vec<Frame>) -> Result<Vec<Ready>> {
    engine.submit(pending)?;
    Ok(pending
        .drain(..)
        .enumerate()
        .map(|(k, frame)| Ready {
            frame,
            pixels: Some(Pixels::Staged(k)),
        })
        .collect())
}
