//! Frame ingest: a decode thread reads the input in order and does nothing else (frames before a
//! resume point are only grabbed), a preparing thread gives each frame its analysis gray (resized
//! on the CPU), both through queues of at most 48 MiB of frames (memory stays bounded), and the
//! hand-off gives each frame its analysis pixels: that gray, or, with a staging sharpness engine,
//! a device buffer resized from the gray the engine computed on the device.

use super::sharpness::SharpnessEngine;
use crate::error::{CvContext, Result};
use crate::kernels::resize_area;
use crate::source::{Frame, FrameSource};
use opencv::core::Mat;
use opencv::prelude::*;
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::thread::Scope;

/// Bytes of decoded frames each of the two queues (decoder to preparer, preparer to analysis)
/// may hold: enough frames that the decoder runs on while the analysis measures a flow, few
/// enough that memory stays bounded (8 frames at 1080p, 2 at 4K).
const QUEUE_BYTES: usize = 48 << 20;

/// Frames queued in each queue for frames of `width` x `height` (BGR): between 2 and 8.
fn queue_frames(width: u32, height: u32) -> usize {
    let frame = (width as usize * height as usize * 3).max(1);
    (QUEUE_BYTES / frame).clamp(2, 8)
}

pub(crate) use super::device::Pixels;

/// Items from the preparing thread.
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

/// What the preparing thread hands on with each frame.
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
/// those in `prime`; a second thread gives every frame its analysis gray and keeps its image as
/// `keep` says. The decode thread does nothing but decode, so the decoder's own worker threads
/// (frame threading) are fed their next packets at once instead of waiting for the conversions.
pub(crate) fn spawn_decoder<'scope>(
    scope: &'scope Scope<'scope, '_>,
    src: &'scope mut dyn FrameSource,
    resume_at: usize,
    prime: &'scope [usize],
    keep: Keep,
) -> Receiver<Result<Decoded>> {
    let depth = queue_frames(src.metadata().width, src.metadata().height);
    let (raw_tx, raw_rx) = sync_channel::<Result<Raw>>(depth);
    let (tx, rx) = sync_channel::<Result<Decoded>>(depth);
    scope.spawn(move || decode(src, resume_at, prime, raw_tx));
    scope.spawn(move || prepare_all(raw_rx, keep, tx));
    rx
}

/// A decoded frame before its preparation: one to analyse, or one a resumed state primes.
enum Raw {
    Frame(Frame),
    Prime(Frame),
}

fn decode(
    src: &mut dyn FrameSource,
    resume_at: usize,
    prime: &[usize],
    tx: SyncSender<Result<Raw>>,
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
                Ok(Some(f)) => {
                    next = f.index + 1;
                    Ok(match f.index < resume_at {
                        true => Raw::Prime(f),
                        false => Raw::Frame(f),
                    })
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

/// The preparing thread: each decoded frame's analysis gray, in order.
fn prepare_all(rx: Receiver<Result<Raw>>, keep: Keep, tx: SyncSender<Result<Decoded>>) {
    let mut input = super::priority::Consumer::new("preparer");
    while let Ok(item) = input.recv(&rx) {
        let item = item.and_then(|raw| match raw {
            Raw::Prime(f) => {
                // Without `small` the frame itself goes (staged on the device).
                let gray = keep.small.map(|s| prepare(s, &f.image)).transpose();
                gray.map(|g| Decoded::Prime(f.index, g.unwrap_or(f.image)))
            }
            Raw::Frame(mut f) => keep.apply(&mut f).map(|g| Decoded::Frame(f, g)),
        });
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
    /// The preparing thread made the gray; frames go one by one.
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn queues_hold_a_bounded_number_of_bytes() {
        // 1080p: 8 frames of 6.2 MB; 4K: 2 (also the floor: each queue needs two to overlap).
        assert_eq!(queue_frames(1920, 1080), 8);
        assert_eq!(queue_frames(3840, 2160), 2);
        assert_eq!(queue_frames(7680, 4320), 2);
        // Small frames: the ceiling of 8, and a zero size does not divide by zero.
        assert_eq!(queue_frames(320, 180), 8);
        assert_eq!(queue_frames(0, 0), 8);
        for (w, h) in [(1280, 720), (1920, 1080), (2704, 1520), (3840, 2160)] {
            let frames = queue_frames(w, h);
            assert!(frames == 2 || frames * (w * h * 3) as usize <= QUEUE_BYTES);
        }
    }
}
