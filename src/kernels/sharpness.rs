//! Sharpness scores per frame (Tenengrad or Laplacian variance) with two backends: the gpu runner
//! uploads a batch of frames as BGR textures (through a reused staging belt, in the batch's own
//! submission) and scores each in one strip pass that converts to
//! gray in registers ([`strip`]); it reads back only the exact 64-bit totals, through a pool of
//! asynchronously mapped staging buffers (a batch's scores are taken once they land, with no
//! wait per batch in steady state). The opencv backend
//! runs the OpenCV twins. With a resize attached, the same pass also writes the frame's gray, and
//! the submission downsizes it (resize_area) into a small buffer per batch slot, which the
//! movement pass loads into Farneback without a CPU round trip.

#[cfg(feature = "opencv")]
use super::gray;
use super::resize_area::ResizeAreaGpu;
use super::strip::{self, StripParams};
use super::{gray_stride, laplacian, tenengrad};
use crate::error::{Error, Result};
use crate::gpu::readback::{Readback, Until};
use crate::gpu::{compute_pass, GpuContext, HostImage};
use crate::params::Metric;
#[cfg(feature = "opencv")]
use opencv::core::Mat;
use std::collections::VecDeque;
use std::sync::Arc;

/// Number of 64-bit totals the metric's shader accumulates.
fn totals_of(metric: Metric) -> u64 {
    match metric {
        Metric::Tenengrad => 1,
        Metric::Laplacian { .. } => 2,
    }
}

/// Decodes (low, high) word pairs of 64-bit totals.
fn totals_from_words(words: &[u32]) -> Vec<u64> {
    words
        .chunks_exact(2)
        .map(|w| u64::from(w[0]) | (u64::from(w[1]) << 32))
        .collect()
}

/// OpenCV backend: the score of one 8-bit BGR (or gray) frame.
#[cfg(feature = "opencv")]
pub fn score_opencv(frame: &Mat, metric: Metric) -> Result<f64> {
    score_gray(&gray::opencv(frame)?, metric)
}

/// OpenCV backend: the score of a frame's 8-bit gray image (Tenengrad in one host pass, equal
/// to its OpenCV twin).
#[cfg(feature = "opencv")]
pub fn score_gray(gray: &Mat, metric: Metric) -> Result<f64> {
    match metric {
        Metric::Tenengrad => tenengrad::host(gray),
        Metric::Laplacian { ksize } => laplacian::opencv(gray, ksize),
    }
}

/// Per-frame resources of one batch slot.
struct Slot {
    frame: wgpu::Texture,
    metric_bg: wgpu::BindGroup,
}

/// Memory the runner may use for its batch of uploaded frames.
const BATCH_BUDGET_BYTES: u64 = 192 << 20;
/// Most frames per submission.
const MAX_BATCH: usize = 16;
/// Bytes per slot in the totals buffer (storage offset alignment).
const TOTALS_SLOT: u64 = 256;
/// Batches whose totals may be in flight at once (staging buffers of the readback pool); a
/// full pool waits for two, so a batch of 16 frames costs at most half a wait. Each batch in
/// flight holds its frames' upload (at most `BATCH_BUDGET_BYTES`).
const DEPTH: usize = 3;

/// GPU sharpness for frames of one size: several frames per submission, only scores read back.
/// One pass per frame reads its BGR texture once ([`strip`]); the gray image is written only
/// when a resize is attached (or for [`SharpnessGpu::gray_of`]).
pub struct SharpnessGpu {
    ctx: Arc<GpuContext>,
    metric: Metric,
    width: u32,
    height: u32,
    strip_rows: u32,
    gray: wgpu::Buffer,
    params: wgpu::Buffer,
    totals: wgpu::Buffer,
    readback: Readback,
    /// Frames of each batch in flight, oldest first.
    in_flight: VecDeque<usize>,
    /// Scores that came back and were not taken yet, in frame order.
    landed: VecDeque<f64>,
    slots: Vec<Slot>,
    metric_pipe: Arc<wgpu::ComputePipeline>,
    /// Staging memory of the frames' uploads, reused batch after batch.
    belt: wgpu::util::StagingBelt,
    resize: Option<AttachedResize>,
}

/// The resize of each batch slot's gray into its own small buffer.
struct AttachedResize {
    gpu: ResizeAreaGpu,
    small: Vec<wgpu::Buffer>,
    groups: Vec<wgpu::BindGroup>,
}

impl SharpnessGpu {
    /// Prepares textures, buffers and pipelines for `width` x `height` frames, in strips of the
    /// adapter's height ([`strip::strip_rows_for`]).
    pub fn new(ctx: Arc<GpuContext>, metric: Metric, width: u32, height: u32) -> Result<Self> {
        let rows = strip::strip_rows_for(&ctx);
        SharpnessGpu::with_strip_rows(ctx, metric, (width, height), rows)
    }

    /// As [`SharpnessGpu::new`] with `strip_rows` rows per invocation (for `bench`).
    pub fn with_strip_rows(
        ctx: Arc<GpuContext>,
        metric: Metric,
        (width, height): (u32, u32),
        strip_rows: u32,
    ) -> Result<Self> {
        if width == 0 || height == 0 || strip_rows == 0 {
            return Err(Error::param("frame size", "must not be empty"));
        }
        let frame_bytes = u64::from(strip::texels_per_row(width)) * 16 * u64::from(height);
        let batch = ((BATCH_BUDGET_BYTES / frame_bytes) as usize).clamp(1, MAX_BATCH);
        let (name, wgsl, ksize) = match metric {
            Metric::Tenengrad => ("tenengrad", tenengrad::WGSL, 0),
            Metric::Laplacian { ksize: k @ (1 | 3) } => ("laplacian", laplacian::WGSL, k),
            Metric::Laplacian { .. } => {
                return Err(Error::param("laplacian ksize", "must be 1 or 3"));
            }
        };
        let metric_pipe = ctx.pipeline(name, wgsl, "main")?;
        let stride = gray_stride(width);
        let params = ctx.uniform(
            "strip params",
            &StripParams {
                width,
                height,
                strip_rows,
                stride,
                ksize,
                write_gray: 0,
                pad: [0; 2],
            },
        );
        let gray = ctx.storage_buffer("gray", u64::from(stride) * u64::from(height) * 4);
        let totals = ctx.storage_buffer("totals", TOTALS_SLOT * batch as u64);
        let readback = Readback::new(TOTALS_SLOT * batch as u64, DEPTH);
        let slots = (0..batch)
            .map(|i| {
                let frame = strip::frame_texture(&ctx, width, height)?;
                let view = frame.create_view(&Default::default());
                let totals_slot = wgpu::BufferBinding {
                    buffer: &totals,
                    offset: TOTALS_SLOT * i as u64,
                    size: wgpu::BufferSize::new(totals_of(metric) * 8),
                };
                let metric_bg = ctx.bind_resources(
                    name,
                    &metric_pipe,
                    &[
                        (0, wgpu::BindingResource::TextureView(&view)),
                        (1, wgpu::BindingResource::Buffer(totals_slot)),
                        (2, params.as_entire_binding()),
                        (3, gray.as_entire_binding()),
                    ],
                );
                Ok(Slot { frame, metric_bg })
            })
            .collect::<Result<_>>()?;
        let belt = strip::belt(&ctx, (width, height), batch);
        Ok(SharpnessGpu {
            ctx,
            metric,
            width,
            height,
            strip_rows,
            gray,
            params,
            totals,
            readback,
            in_flight: VecDeque::new(),
            landed: VecDeque::new(),
            slots,
            metric_pipe,
            belt,
            resize: None,
        })
    }

    /// Whether the pass also writes the gray image.
    fn set_write_gray(&self, on: bool) {
        let at = std::mem::offset_of!(StripParams, write_gray) as u64;
        self.ctx
            .write(&self.params, at, bytemuck::bytes_of(&u32::from(on)));
    }

    /// From now on every scored frame is also resized on the device to `dst` (width, height)
    /// with INTER_AREA (integer factors only, else an error); returns the small buffers, one per
    /// batch slot (8-bit, 4 pixels per u32, rows not padded), valid until the next batch.
    pub fn attach_resize(&mut self, dst: (u32, u32)) -> Result<Vec<wgpu::Buffer>> {
        let gpu = ResizeAreaGpu::new(self.ctx.clone(), (self.width, self.height), dst)?;
        let small: Vec<wgpu::Buffer> = (0..self.slots.len())
            .map(|_| self.ctx.storage_buffer("resized gray", gpu.dst_bytes()))
            .collect();
        let groups = small.iter().map(|b| gpu.bind(&self.gray, b)).collect();
        self.set_write_gray(true);
        self.resize = Some(AttachedResize {
            gpu,
            small: small.clone(),
            groups,
        });
        Ok(small)
    }

    /// The device-resized gray of `frame` (needs [`SharpnessGpu::attach_resize`]), row after
    /// row, for checking against cv::resize.
    pub fn resized_of<F: HostImage + ?Sized>(&mut self, frame: &F) -> Result<Vec<u8>> {
        self.scores(&[frame])?;
        let Some(r) = &self.resize else {
            return Err(Error::param("resize", "no resize attached"));
        };
        self.ctx.read_back(&r.small[0], r.gpu.dst_bytes())
    }

    /// Frames per submission.
    pub fn batch_size(&self) -> usize {
        self.slots.len()
    }

    /// Records the upload of `frames` into the first slots on a new encoder.
    fn upload<F: HostImage + ?Sized>(&mut self, frames: &[&F]) -> Result<wgpu::CommandEncoder> {
        let what = "sharpness (8-bit BGR)";
        let mut enc = self.ctx.encoder("sharpness batch");
        for (slot, f) in self.slots.iter().zip(frames) {
            let staging = (&mut self.belt, &mut enc);
            strip::upload(&self.ctx, staging, &slot.frame, *f, self.width, what)?;
        }
        Ok(enc)
    }

    /// Submits `enc` (through the read-back pool when it copies totals back) with the staging
    /// memory it copies from, then hands that memory back to the belt for when the device is
    /// done with it.
    fn submit_staged(&mut self, enc: wgpu::CommandEncoder, totals: bool) -> Result<()> {
        self.belt.finish();
        match totals {
            true => self.readback.submit(&self.ctx, enc),
            false => drop(self.ctx.queue.submit([enc.finish()])),
        }
        self.belt.recall();
        self.ctx.poll()
    }

    fn encode(&self, enc: &mut wgpu::CommandEncoder, slot: usize) {
        let s = &self.slots[slot];
        let groups = strip::groups(self.width, self.height, self.strip_rows);
        let totals = Some(totals_of(self.metric) * 8);
        enc.clear_buffer(&self.totals, TOTALS_SLOT * slot as u64, totals);
        let mut pass = compute_pass(enc, "sharpness");
        self.ctx
            .dispatch(&mut pass, &self.metric_pipe, &s.metric_bg, groups);
        if let Some(r) = &self.resize {
            r.gpu.encode(&mut pass, &r.groups[slot]);
        }
    }

    /// Scores of `frames` (8-bit BGR, this runner's size), in order (waits for them; not
    /// while submitted scores are still to be taken).
    pub fn scores<F: HostImage + ?Sized>(&mut self, frames: &[&F]) -> Result<Vec<f64>> {
        if !(self.in_flight.is_empty() && self.landed.is_empty()) {
            return Err(Error::gpu(
                "sharpness scores asked while submitted scores are not taken",
            ));
        }
        self.submit(frames)?;
        self.take(true)
    }

    /// Starts scoring `frames` (8-bit BGR, this runner's size) after the frames submitted
    /// before; their scores come back through [`SharpnessGpu::take`]. Blocks only when every
    /// staging buffer is in flight, and then until half of them have landed.
    pub fn submit<F: HostImage + ?Sized>(&mut self, frames: &[&F]) -> Result<()> {
        for chunk in frames.chunks(self.slots.len()) {
            self.make_room()?;
            let enc = self.upload(chunk)?;
            self.submit_batch(enc, chunk.len())?;
        }
        Ok(())
    }

    /// Waits for half of the staging buffers when every one is in flight.
    fn make_room(&mut self) -> Result<()> {
        match self.readback.is_full() {
            true => self.land(Until::Half),
            false => Ok(()),
        }
    }

    /// Scores the frames in the first `n` slots after what `enc` holds (their uploads): one
    /// submission, its totals copied back.
    fn submit_batch(&mut self, mut enc: wgpu::CommandEncoder, n: usize) -> Result<()> {
        for i in 0..n {
            self.encode(&mut enc, i);
        }
        let used = TOTALS_SLOT * n as u64;
        self.readback
            .copy(&self.ctx, &mut enc, &self.totals, used)?;
        self.in_flight.push_back(n);
        self.submit_staged(enc, true)
    }

    /// Uploads `frames` into the batch slots, one submission per batch, and scores nothing:
    /// the upload alone, as [`SharpnessGpu::submit`] makes it (`keyframer-gpu-bench` times it).
    pub fn upload_only<F: HostImage + ?Sized>(&mut self, frames: &[&F]) -> Result<()> {
        for chunk in frames.chunks(self.slots.len()) {
            let enc = self.upload(chunk)?;
            self.submit_staged(enc, false)?;
        }
        Ok(())
    }

    /// Scores the frames already in the batch slots again, `count` scores in full batches (the
    /// last one partial), uploading nothing: the kernels and the read-back alone
    /// (`keyframer-gpu-bench` times it). Their scores come back through [`SharpnessGpu::take`].
    pub fn submit_resident(&mut self, count: usize) -> Result<()> {
        let batch = self.slots.len();
        let mut left = count;
        while left > 0 {
            self.make_room()?;
            let n = left.min(batch);
            let enc = self.ctx.encoder("sharpness batch");
            self.submit_batch(enc, n)?;
            left -= n;
        }
        Ok(())
    }

    /// The scores of submitted frames that have come back, in frame order; with `all`, of
    /// every submitted frame (waits).
    pub fn take(&mut self, all: bool) -> Result<Vec<f64>> {
        self.land(if all { Until::All } else { Until::Landed })?;
        Ok(self.landed.drain(..).collect())
    }

    /// Turns the totals of the batches that landed (as far as `until` waits) into scores.
    fn land(&mut self, until: Until) -> Result<()> {
        let n = u64::from(self.width) * u64::from(self.height);
        for bytes in self.readback.take(&self.ctx, until)? {
            let frames = self.in_flight.pop_front().unwrap_or(0);
            for i in 0..frames {
                let off = i * TOTALS_SLOT as usize;
                let words: &[u32] = bytemuck::cast_slice(&bytes[off..off + 16]);
                let t = totals_from_words(words);
                self.landed.push_back(match self.metric {
                    Metric::Tenengrad => tenengrad::from_totals(t[0], n),
                    Metric::Laplacian { ksize } => laplacian::from_totals(t[0], t[1], n, ksize),
                });
            }
        }
        Ok(())
    }

    /// The gray image the gpu computes for `frame` (for checking against cv::cvtColor).
    pub fn gray_of<F: HostImage + ?Sized>(&mut self, frame: &F) -> Result<Vec<u8>> {
        self.set_write_gray(true);
        let mut enc = self.upload(&[frame])?;
        self.encode(&mut enc, 0);
        self.submit_staged(enc, false)?;
        let (w, h) = (self.width as usize, self.height as usize);
        let row = gray_stride(self.width) as usize * 4;
        let bytes = self.ctx.read_back(&self.gray, (row * h) as u64)?;
        self.set_write_gray(self.resize.is_some());
        let rows = bytes.chunks_exact(row);
        Ok(rows.flat_map(|r| &r[..w]).copied().collect())
    }
}
