//! The measurements: each submits its work, marks the device clock (when the adapter has
//! timestamps), waits, and takes the wall time and the context's counters around it. Frames come
//! from `keyframer::synthetic::Scroll` (slices of one host buffer, no copy per frame).

use crate::clock::Clock;
use keyframer::analysis::{DeviceAnalysis, Request};
use keyframer::gpu::{Counts, GpuContext, PerFrame};
use keyframer::kernels::farneback::FarnebackGpu;
use keyframer::kernels::sharpness::SharpnessGpu;
use keyframer::params::{FarnebackParams, Metric};
use keyframer::synthetic::Scroll;
use keyframer::{Error, Result};
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;

/// Frames per submission of the bench's own upload rows (the sharpness runner's batch at 1080p).
const UPLOAD_SLOTS: usize = 16;
/// Distinct gray frames the Farneback loop cycles through.
const FLOW_FRAMES: usize = 16;

/// One measurement.
#[derive(Debug, Clone, Serialize)]
pub struct Measure {
    /// What ran (`gray+resize+tenengrad`, `farneback`, `analysis`, ...).
    pub name: String,
    /// Frame size, `WxH`.
    pub size: String,
    /// Streams on the device at once (threads, each with its own engine).
    pub streams: usize,
    /// Frames (or pairs, for `farneback`) in all streams together.
    pub count: usize,
    /// Wall time from the first submission until every result was back.
    pub wall_s: f64,
    /// Device time between the marks before the first and after the last submission
    /// (`None` without timestamp queries).
    pub device_s: Option<f64>,
    /// Frames (pairs) per second: from `device_s` where there is one, else from `wall_s`.
    pub per_s: f64,
    /// The context's counters over the run, per frame (pair).
    pub per_frame: PerFrame,
}

/// The results of a run's first frames, kept in the report so that they can be checked against
/// the OpenCV twins where OpenCV is (`tests/it/gpu_bench.rs` reads the recorded reports in
/// `reference/gpu-bench/`): the numbers of a GPU without OpenCV beside it then time kernels
/// whose results were checked.
#[derive(Debug, Clone, Serialize)]
pub struct Recorded {
    /// The run (`gray+resize+tenengrad`, `analysis`, ...).
    pub name: String,
    /// Frame size, `WxH`.
    pub size: String,
    /// Frames of the scene recorded: 0 to `frames - 1`.
    pub frames: usize,
    /// Sharpness of each recorded frame (the run's metric; Tenengrad for `analysis`).
    pub sharpness: Vec<f64>,
    /// Movement into each recorded frame (`analysis`).
    pub movement: Option<Vec<f64>>,
    /// The stationary step's keyframes among the recorded frames (`analysis`).
    pub stationary: Option<Vec<usize>>,
}

/// The device, its clock and the run's sizes.
pub struct Bench {
    /// The context every measurement shares.
    pub ctx: Arc<GpuContext>,
    /// Timestamps, where the adapter has them.
    pub clock: Option<Clock>,
    /// Frames (pairs) per measurement and stream.
    pub frames: usize,
    /// Frames whose results each run records (at most `frames`).
    pub record: usize,
    /// The adapter asked for (for the runs that open a device per stream).
    pub adapter: Option<String>,
}

impl Bench {
    /// Times `submit` (then the end mark), then `wait`; `count` frames.
    fn timed<T>(
        &self,
        label: (&str, (u32, u32), usize, usize),
        submit: impl FnOnce() -> Result<T>,
        wait: impl FnOnce(T) -> Result<()>,
    ) -> Result<Measure> {
        self.timed_on(std::slice::from_ref(&self.ctx), label, submit, wait)
    }

    /// As [`Bench::timed`] for work on the devices `ctxs`: the counters are summed over them;
    /// device time only when `ctxs` is the bench's own device (its clock sees that queue only).
    fn timed_on<T>(
        &self,
        ctxs: &[Arc<GpuContext>],
        (name, size, streams, count): (&str, (u32, u32), usize, usize),
        submit: impl FnOnce() -> Result<T>,
        wait: impl FnOnce(T) -> Result<()>,
    ) -> Result<Measure> {
        let clock = match ctxs {
            [only] if Arc::ptr_eq(only, &self.ctx) => self.clock.as_ref(),
            _ => None,
        };
        let counts = || ctxs.iter().fold(Counts::default(), |a, c| a + c.counts());
        for c in ctxs {
            c.wait()?;
        }
        let before = counts();
        if let Some(c) = clock {
            c.mark(&self.ctx, 0);
        }
        let start = Instant::now();
        let pending = submit()?;
        if let Some(c) = clock {
            c.mark(&self.ctx, 1);
        }
        wait(pending)?;
        let wall_s = start.elapsed().as_secs_f64();
        let used = counts() - before;
        let device_s = clock.map(|c| c.seconds(&self.ctx)).transpose()?;
        let per_s = count as f64 / device_s.unwrap_or(wall_s).max(1e-12);
        Ok(Measure {
            name: name.into(),
            size: format!("{}x{}", size.0, size.1),
            streams,
            count,
            wall_s,
            device_s,
            per_s,
            per_frame: PerFrame::of(used, count),
        })
    }

    /// Gray + INTER_AREA to `small` + `metric` on `size` BGR frames (upload included), and the
    /// record of the first frames' scores.
    pub fn sharpness(
        &self,
        metric: Metric,
        size: (u32, u32),
        small: (u32, u32),
    ) -> Result<(Measure, Recorded)> {
        let scene = Scroll::bench(size.0, size.1);
        let mut r = SharpnessGpu::new(self.ctx.clone(), metric, size.0, size.1)?;
        r.attach_resize(small)?;
        r.scores(&[scene.frame(0)])?;
        let frames: Vec<&[u8]> = (0..self.frames).map(|i| scene.frame(i)).collect();
        let name = format!("gray+resize+{}", metric_name(metric));
        let n = frames.len();
        let runner = std::cell::RefCell::new(r);
        let mut scores = Vec::new();
        let m = self.timed(
            (&name, size, 1, n),
            || runner.borrow_mut().submit(&frames),
            |()| {
                scores = runner.borrow_mut().take(true)?;
                Ok(())
            },
        )?;
        expect(
            scores.len() == n && scores.iter().all(|s| s.is_finite() && *s > 0.0),
            &name,
        )?;
        let kept = self.record.min(n);
        let recorded = Recorded {
            name,
            size: m.size.clone(),
            frames: kept,
            sharpness: scores[..kept].to_vec(),
            movement: None,
            stationary: None,
        };
        Ok((m, recorded))
    }

    /// The same bytes as [`Bench::upload`] written into storage buffers instead of textures
    /// (`queue.write_buffer`, one buffer per batch slot, one submission per batch): what a frame
    /// kept in a buffer would cost to upload.
    pub fn upload_buffer(&self, size: (u32, u32)) -> Result<Measure> {
        let bytes = u64::from(size.0) * u64::from(size.1) * 3;
        let slots: Vec<wgpu::Buffer> = (0..UPLOAD_SLOTS)
            .map(|_| {
                self.ctx
                    .storage_buffer("bench frame", bytes.next_multiple_of(4))
            })
            .collect();
        // write_buffer wants a multiple of 4 bytes: every frame size here has one.
        let write = |f: &[u8], b: &wgpu::Buffer| self.ctx.write(b, 0, &f[..f.len() & !3]);
        self.queue_upload("upload buffer", size, &slots, write)
    }

    /// The same frames as [`Bench::upload`] into the same kind of textures, but with
    /// `queue.write_texture` (fresh staging memory for every frame, one submission per batch of
    /// 16): how the sharpness runner uploaded until it took a staging belt (2026-11-28).
    pub fn upload_write_texture(&self, size: (u32, u32)) -> Result<Measure> {
        let texels = size.0.saturating_mul(3).div_ceil(16);
        if texels > self.ctx.limits.max_texture_dimension_2d || !size.0.is_multiple_of(16) {
            let msg = "a width of a multiple of 16 within the adapter's texture size";
            return Err(Error::param("upload write_texture", msg));
        }
        let slots: Vec<wgpu::Texture> = (0..UPLOAD_SLOTS)
            .map(|_| {
                self.ctx.texture(
                    "bench frame",
                    (texels, size.1),
                    wgpu::TextureFormat::Rgba32Uint,
                    wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                )
            })
            .collect();
        let write = |f: &[u8], t: &wgpu::Texture| self.ctx.write_texture(t, f, texels * 16);
        self.queue_upload("upload write_texture", size, &slots, write)
    }

    /// Times `size` frames written into `slots` by `write` (a queue write each), one (empty)
    /// submission per batch of `slots`, after a warm-up of two batches (so that the staging
    /// memory is mapped before the clock starts).
    fn queue_upload<T>(
        &self,
        name: &str,
        size: (u32, u32),
        slots: &[T],
        write: impl Fn(&[u8], &T),
    ) -> Result<Measure> {
        let scene = Scroll::bench(size.0, size.1);
        let frames: Vec<&[u8]> = (0..self.frames).map(|i| scene.frame(i)).collect();
        let put = |frames: &[&[u8]]| {
            for batch in frames.chunks(slots.len()) {
                for (f, slot) in batch.iter().zip(slots) {
                    write(f, slot);
                }
                let enc = self.ctx.encoder(name);
                self.ctx.queue.submit([enc.finish()]);
            }
        };
        put(&frames[..frames.len().min(2 * slots.len())]);
        self.ctx.wait()?;
        self.timed(
            (name, size, 1, frames.len()),
            || {
                put(&frames);
                Ok(())
            },
            |()| self.ctx.wait(),
        )
    }

    /// The upload alone of [`Bench::sharpness`]: `size` BGR frames into the runner's textures,
    /// one submission per batch, nothing computed.
    pub fn upload(&self, size: (u32, u32)) -> Result<Measure> {
        let scene = Scroll::bench(size.0, size.1);
        let mut r = SharpnessGpu::new(self.ctx.clone(), Metric::Tenengrad, size.0, size.1)?;
        let frames: Vec<&[u8]> = (0..self.frames).map(|i| scene.frame(i)).collect();
        // Warm-up: two batches, so that the staging memory is mapped before the clock starts
        // (without it, the first upload row paid for it: 3x slower than the second on lavapipe).
        r.upload_only(&frames[..frames.len().min(2 * r.batch_size())])?;
        self.ctx.wait()?;
        let n = frames.len();
        self.timed(
            ("upload", size, 1, n),
            || r.upload_only(&frames),
            |()| self.ctx.wait(),
        )
    }

    /// The kernels and the read-back alone of [`Bench::sharpness`]: the frames already on the
    /// device (one batch, uploaded before the clock starts) scored again, `frames` scores.
    pub fn resident(&self, metric: Metric, size: (u32, u32), small: (u32, u32)) -> Result<Measure> {
        let scene = Scroll::bench(size.0, size.1);
        let mut r = SharpnessGpu::new(self.ctx.clone(), metric, size.0, size.1)?;
        r.attach_resize(small)?;
        let batch: Vec<&[u8]> = (0..r.batch_size()).map(|i| scene.frame(i)).collect();
        let first = r.scores(&batch)?;
        let name = format!("no-upload {}", metric_name(metric));
        let n = self.frames;
        let runner = std::cell::RefCell::new(r);
        let mut scores = Vec::new();
        let m = self.timed(
            (&name, size, 1, n),
            || runner.borrow_mut().submit_resident(n),
            |()| {
                scores = runner.borrow_mut().take(true)?;
                Ok(())
            },
        )?;
        // The same frames give the same scores, uploaded or not.
        let again = scores.chunks(first.len()).all(|c| c == &first[..c.len()]);
        expect(scores.len() == n && again, &name)?;
        Ok(m)
    }

    /// Farneback pairs at analysis width `width` (16:9): each pair loads the next gray (its
    /// pyramid) and computes the flow from the previous one.
    pub fn farneback(&self, width: u32) -> Result<Measure> {
        let size = (width, (width * 9 / 16).max(1));
        let scene = Scroll::bench(size.0, size.1);
        let grays: Vec<Vec<u8>> = (0..FLOW_FRAMES).map(|i| gray(scene.frame(i))).collect();
        let mut f =
            FarnebackGpu::new(self.ctx.clone(), FarnebackParams::default(), size.0, size.1)?;
        f.load(0, grays[0].as_slice())?;
        f.load(1, grays[1].as_slice())?;
        f.flow_between(0, 1)?;
        self.ctx.wait()?;
        let n = self.frames;
        self.timed(
            ("farneback", size, 1, n),
            || {
                for i in 0..n {
                    let (prev, cur) = (i % 2, (i + 1) % 2);
                    f.load(cur, grays[(i + 1) % FLOW_FRAMES].as_slice())?;
                    f.flow_between(prev, cur)?;
                }
                Ok(())
            },
            |()| self.ctx.wait(),
        )
    }

    /// The whole per-frame analysis of `select --stationary --blur --spacing` on the gpu backend
    /// (`keyframer::analysis::DeviceAnalysis`), `streams` threads at once, each with its engine,
    /// all on the bench's device and queue, or with `own_devices` each on a device (and queue)
    /// of its own opened on the same adapter (wall time then: the clock sees one queue).
    pub fn analysis(
        &self,
        (name, size): (&str, (u32, u32)),
        req: &Request,
        streams: usize,
        own_devices: bool,
    ) -> Result<(Measure, Recorded)> {
        let scene = Scroll::bench(size.0, size.1);
        let frames: Vec<&[u8]> = (0..self.frames).map(|i| scene.frame(i)).collect();
        let ctxs: Vec<Arc<GpuContext>> = match own_devices {
            false => vec![self.ctx.clone()],
            true => (0..streams)
                .map(|_| GpuContext::new(self.adapter.as_deref()).map(Arc::new))
                .collect::<Result<_>>()?,
        };
        // Warm-up: the pipelines are compiled once per context.
        for ctx in &ctxs {
            let mut warm = DeviceAnalysis::new(ctx, req, size)?;
            warm.push(&frames[..frames.len().min(warm.batch())])?;
            warm.finish()?;
        }
        let engines = (0..streams)
            .map(|i| DeviceAnalysis::new(&ctxs[i % ctxs.len()], req, size))
            .collect::<Result<Vec<_>>>()?;
        let n = frames.len();
        let frames = &frames;
        let mut results = Vec::new();
        let m = self.timed_on(
            &ctxs,
            (name, size, streams, n * streams),
            || {
                let done = std::thread::scope(|s| {
                    let handles: Vec<_> = (engines.into_iter())
                        .map(|mut e| {
                            s.spawn(move || {
                                e.push(frames)?;
                                e.finish()
                            })
                        })
                        .collect();
                    handles
                        .into_iter()
                        .map(|h| {
                            h.join()
                                .unwrap_or_else(|_| Err(Error::gpu("a stream panicked")))
                        })
                        .collect::<Result<Vec<_>>>()
                });
                results = done?;
                Ok(())
            },
            |()| Ok(()),
        )?;
        let ok = results.iter().all(|r| {
            r.frames == n
                && r.sharpness.iter().all(|s| s.len() == n)
                && r.movement.as_ref().map(|v| v.len()) == req.movement.as_ref().map(|_| n)
                && r.stationary.as_ref().map(|k| k.is_empty())
                    == req.stationary.as_ref().map(|_| false)
        });
        expect(ok && results.windows(2).all(|w| w[0] == w[1]), name)?;
        let kept = self.record.min(n);
        let first = &results[0];
        let recorded = Recorded {
            name: name.into(),
            size: m.size.clone(),
            frames: kept,
            sharpness: first.sharpness[0][..kept].to_vec(),
            movement: first.movement.as_ref().map(|v| v[..kept].to_vec()),
            stationary: (first.stationary.as_ref())
                .map(|k| k.iter().copied().filter(|&i| i < kept).collect()),
        };
        Ok((m, recorded))
    }
}

/// The parts of [`Request::stationary_blur_spacing`] timed alone (a stage's cost is the difference between two
/// rows): the blur step's sharpness, then the spacing's movement too, then all of it.
pub fn select_parts(width: u32, analysis_width: u32) -> [(&'static str, Request); 3] {
    let full = Request::stationary_blur_spacing(width, analysis_width);
    let blur = Request {
        sharpness: full.sharpness.clone(),
        ..Request::default()
    };
    let spacing = Request {
        sharpness: full.sharpness.clone(),
        movement: full.movement,
        ..Request::default()
    };
    [
        ("analysis blur", blur),
        ("analysis blur+spacing", spacing),
        ("analysis", full),
    ]
}

/// The metric's name in the report.
fn metric_name(m: Metric) -> &'static str {
    match m {
        Metric::Tenengrad => "tenengrad",
        Metric::Laplacian { .. } => "laplacian",
    }
}

/// An 8-bit gray of a BGR frame (BT.601 weights in 8.8 fixed point; input for the flow timing).
fn gray(bgr: &[u8]) -> Vec<u8> {
    (bgr.chunks_exact(3))
        .map(|p| {
            ((u32::from(p[0]) * 29 + u32::from(p[1]) * 150 + u32::from(p[2]) * 77 + 128) >> 8) as u8
        })
        .collect()
}

/// An error unless the results of `what` are complete and plausible.
fn expect(ok: bool, what: &str) -> Result<()> {
    match ok {
        true => Ok(()),
        false => Err(Error::gpu(format!(
            "{what}: incomplete or implausible results"
        ))),
    }
}
