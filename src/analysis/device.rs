//! The gpu movement engine: each frame's flow, movement statistic and stationary decision are
//! queued on the device with no host round trip in between; their records are read back
//! [`BATCH`] frames at a time through pooled staging buffers, mapped without waiting. The host
//! blocks only when [`DEPTH`] batches are still in flight, or when it asks for every result (a
//! checkpoint, the end of the input).

use super::sphere::Sphere;
use crate::error::{Error, Result};
use crate::gpu::readback::Readback;
use crate::gpu::readback::Until;
use crate::gpu::{Gate, GpuContext};
use crate::kernels::farneback::{FarnebackGpu, SLOTS};
use crate::kernels::movement::{checked, Destination, FrameParams, MovementGpu, RECORD_WORDS};
use crate::kernels::remap::{Interp, RemapGpu};
use crate::kernels::stationary::{StationarySamplerGpu, CANDIDATE, FROM_PREVIOUS};
use crate::params::Statistic;
use crate::params::{MovementRequest, StationaryRequest};
use std::collections::VecDeque;
use std::sync::Arc;

/// Frames whose records are read back together.
const BATCH: usize = 16;
/// Batches in flight before the host waits (for the older half of them).
const DEPTH: usize = 4;
/// The slot holding the stationary step's reference frame (the device copies frames into it).
pub(crate) const REFERENCE: usize = SLOTS - 1;
const RECORD_BYTES: usize = RECORD_WORDS as usize * 4;

/// One frame's pixels at the analysis resolution: an 8-bit gray Mat, or the index of the
/// device buffer the staging engine resized it into (valid until its next batch).
pub(crate) enum Pixels {
    #[cfg(feature = "opencv")]
    Small(opencv::core::Mat),
    Staged(usize),
}

/// Bytes of one `size` x `size` flow (two f32 per pixel).
fn flow_bytes(size: u32) -> u64 {
    u64::from(size) * u64::from(size) * 8
}

/// What to measure at one frame.
pub(crate) struct Work {
    pub index: usize,
    /// The slot the frame is loaded in.
    pub slot: usize,
    /// The slot of the frame to measure the consecutive movement from.
    pub from: Option<usize>,
    /// Whether `from` holds the previous frame.
    pub from_previous: bool,
    /// Whether the stationary step takes the frame.
    pub candidate: bool,
}

/// One frame's results: the movements (analysis pixels, NaN when not finite; each meaningful
/// only when the work asked for it) and the stationary step's decision (0: none).
pub(crate) struct Record {
    pub consecutive: f64,
    pub reference: f64,
    pub decision: u32,
}

impl Record {
    fn parse(b: &[u8]) -> Record {
        let f = |k: usize| f64::from_le_bytes(std::array::from_fn(|i| b[k + i]));
        Record {
            consecutive: f(0),
            reference: f(8),
            decision: u32::from_le_bytes([b[16], b[17], b[18], b[19]]),
        }
    }
}

/// The WGSL Farneback, movement and stationary kernels over one results ring. On a 360° input
/// each frame is rendered into its horizon views on the device (remap), every view has its own
/// Farneback slots, and the views' flows are copied into one stacked buffer for the joint
/// statistic: the host reads back the same 32-byte record per frame as for a pinhole input.
pub(crate) struct DeviceMovement {
    ctx: Arc<GpuContext>,
    /// One Farneback per view (one for a pinhole input).
    flows: Vec<FarnebackGpu>,
    /// The horizon views' renderer (360° inputs).
    remap: Option<RemapGpu>,
    /// The views' flows stacked, view after view (360° inputs).
    stacked: Option<wgpu::Buffer>,
    stat: MovementGpu,
    statistic: Statistic,
    /// The sharpness engine's resized-gray buffers (empty unless frames stay on the device).
    staged: Vec<wgpu::Buffer>,
    stationary: Option<StationarySamplerGpu>,
    /// Records of the batch being filled, one per frame submitted.
    results: wgpu::Buffer,
    frame: wgpu::Buffer,
    /// Where the consecutive movement and the movement from the reference go.
    dest: [Destination; 2],
    readback: Readback,
    /// The first gate entries of the statistic from the reference and of the copy keeping it.
    gates: [usize; 2],
    /// Records in `results` so far.
    filled: usize,
    landed: VecDeque<Record>,
}

impl DeviceMovement {
    /// The engine at the analysis size `(w, h)`; with `stationary`, its step on movements times
    /// `scale` runs on the device too.
    pub(crate) fn new(
        ctx: &Arc<GpuContext>,
        req: &MovementRequest,
        stationary: Option<&StationaryRequest>,
        scale: f64,
        (w, h): (u32, u32),
        sphere: Option<Sphere>,
    ) -> Result<DeviceMovement> {
        let (flows, remap, stacked, stat) = match sphere {
            None => {
                let flow = FarnebackGpu::new(ctx.clone(), req.farneback, w, h)?;
                let stat = MovementGpu::new(ctx.clone(), flow.flow_buffer(), w, h, req.derotate)?;
                (vec![flow], None, None, stat)
            }
            Some(sp) => {
                let size = sp.size();
                let flows = (0..sp.views.len())
                    .map(|_| FarnebackGpu::new(ctx.clone(), req.farneback, size, size))
                    .collect::<Result<Vec<_>>>()?;
                let remap = RemapGpu::new(ctx.clone(), (w, h), 1, Interp::Bilinear, &sp.tables)?;
                let bytes = flow_bytes(size) * sp.views.len() as u64;
                let stacked = ctx.storage_buffer("sphere flows", bytes);
                let stat = MovementGpu::joint(ctx.clone(), &stacked, &sp.field)?;
                (flows, Some(remap), Some(stacked), stat)
            }
        };
        stat.prepare(req.statistic)?;
        let flow = &flows[0];
        let results = ctx.storage_buffer("movement records", (BATCH * RECORD_BYTES) as u64);
        let frame = ctx.storage_buffer("movement frame", 16);
        let dest = [0, 1].map(|field| stat.destination(&results, &frame, field));
        let mut shapes = flow.flow_shapes();
        let gates = [shapes.len(), shapes.len() + stat.shapes().len()];
        shapes.extend(stat.shapes());
        shapes.extend(flow.copy_shapes());
        let views = (&frame, &results);
        let stationary = stationary
            .map(|st| StationarySamplerGpu::new(ctx.clone(), st, scale, views, &shapes, gates[1]))
            .transpose()?;
        Ok(DeviceMovement {
            ctx: ctx.clone(),
            flows,
            remap,
            stacked,
            stat,
            statistic: req.statistic,
            staged: Vec::new(),
            stationary,
            results,
            frame,
            dest,
            readback: Readback::new((BATCH * RECORD_BYTES) as u64, DEPTH),
            gates,
            filled: 0,
            landed: VecDeque::new(),
        })
    }

    /// Frames will come as [`Pixels::Staged`] indices into `buffers`.
    pub(crate) fn use_staged(&mut self, buffers: Vec<wgpu::Buffer>) {
        self.staged = buffers;
    }

    /// Puts a frame's analysis pixels in `slot`.
    pub(crate) fn load(&mut self, slot: usize, px: Pixels) -> Result<()> {
        match (px, &self.remap) {
            #[cfg(feature = "opencv")]
            (Pixels::Small(gray), Some(remap)) => {
                let mut enc = self.ctx.encoder("sphere views");
                remap.encode(&mut enc, &gray)?;
                self.ctx.queue.submit([enc.finish()]);
                for (k, flow) in self.flows.iter_mut().enumerate() {
                    let view = (remap.output(k))
                        .ok_or_else(|| Error::gpu("a horizon view without its output"))?;
                    flow.load_buffer(slot, view)?;
                }
                Ok(())
            }
            #[cfg(feature = "opencv")]
            (Pixels::Small(gray), None) => self.flows[0].load(slot, &gray),
            (Pixels::Staged(k), None) => {
                let buf = self
                    .staged
                    .get(k)
                    .ok_or_else(|| Error::param("movement", "no device gray staged"))?;
                self.flows[0].load_buffer(slot, buf)
            }
            (Pixels::Staged(_), Some(_)) => Err(Error::param(
                "movement",
                "360° frames come as gray images, not staged buffers",
            )),
        }
    }

    /// The frame in `slot` becomes the stationary step's reference.
    pub(crate) fn keep(&mut self, slot: usize) -> Result<()> {
        let mut enc = self.ctx.encoder("movement reference");
        for flow in &self.flows {
            flow.encode_copy(&mut enc, slot, REFERENCE, None)?;
        }
        self.ctx.queue.submit([enc.finish()]);
        Ok(())
    }

    /// Records every view's flow of `pair` (gated by `gate`) and, on a 360° input, their copy
    /// into the stacked buffer (not gated: a stale copy only feeds passes the same gate closes).
    fn encode_flows(
        &self,
        enc: &mut wgpu::CommandEncoder,
        pair: (usize, usize),
        gate: Option<Gate<'_>>,
    ) -> Result<()> {
        for (k, flow) in self.flows.iter().enumerate() {
            flow.encode_flow(enc, pair, gate)?;
            if let Some(stacked) = &self.stacked {
                let bytes = stacked.size() / self.flows.len() as u64;
                enc.copy_buffer_to_buffer(flow.flow_buffer(), 0, stacked, k as u64 * bytes, bytes);
            }
        }
        Ok(())
    }

    /// Sets the stationary step's state on the device.
    pub(crate) fn restore(&self, reference: Option<usize>, accumulated: f64) {
        if let Some(st) = &self.stationary {
            st.restore(reference, accumulated);
        }
    }

    /// Queues the measurements of one frame; its record comes back through
    /// [`DeviceMovement::collect`], after those of the frames submitted before it.
    pub(crate) fn submit(&mut self, w: &Work) -> Result<()> {
        let flag = |on: bool, f: u32| if on { f } else { 0 };
        let params = FrameParams {
            index: w.index as u32,
            entry: self.filled as u32,
            flags: flag(w.candidate, CANDIDATE) | flag(w.from_previous, FROM_PREVIOUS),
            pad: 0,
        };
        self.ctx.write(&self.frame, 0, bytemuck::bytes_of(&params));
        let mut enc = self.ctx.encoder("movement");
        if let Some(from) = w.from {
            self.encode_flows(&mut enc, (from, w.slot), None)?;
            self.stat
                .encode(&mut enc, self.statistic, Some(&self.dest[0]), None);
        }
        if let (true, Some(st)) = (w.candidate, &self.stationary) {
            let gate = |first| {
                Some(Gate {
                    args: st.args(),
                    first,
                })
            };
            let [statistic, keep] = self.gates;
            st.encode_plan(&mut enc);
            let pair = (REFERENCE, w.slot);
            self.encode_flows(&mut enc, pair, gate(0))?;
            let dest = Some(&self.dest[1]);
            self.stat
                .encode(&mut enc, self.statistic, dest, gate(statistic));
            st.encode_decide(&mut enc);
            for flow in &self.flows {
                flow.encode_copy(&mut enc, w.slot, REFERENCE, gate(keep))?;
            }
        }
        self.filled += 1;
        self.close(enc, self.filled == BATCH)
    }

    /// Submits `enc`, with the readback of the records so far when `end`.
    fn close(&mut self, mut enc: wgpu::CommandEncoder, end: bool) -> Result<()> {
        if end {
            if self.readback.is_full() {
                self.land(Until::Half)?;
            }
            let bytes = (self.filled * RECORD_BYTES) as u64;
            self.readback
                .copy(&self.ctx, &mut enc, &self.results, bytes)?;
            self.filled = 0;
        }
        self.readback.submit(&self.ctx, enc);
        Ok(())
    }

    fn land(&mut self, until: Until) -> Result<()> {
        for bytes in self.readback.take(&self.ctx, until)? {
            let records = bytes.chunks_exact(RECORD_BYTES).map(Record::parse);
            self.landed.extend(records);
        }
        Ok(())
    }

    /// The records that have come back, in submission order; with `all`, every one (waits).
    pub(crate) fn collect(&mut self, all: bool) -> Result<Vec<Record>> {
        if all && self.filled > 0 {
            let enc = self.ctx.encoder("movement records");
            self.close(enc, true)?;
        }
        self.land(if all { Until::All } else { Until::Landed })?;
        Ok(self.landed.drain(..).collect())
    }

    /// The movement from slot `from` to slot `to` now (waits; nothing else may be pending).
    pub(crate) fn movement(&mut self, from: usize, to: usize) -> Result<f64> {
        self.submit(&Work {
            index: 0,
            slot: to,
            from: Some(from),
            from_previous: false,
            candidate: false,
        })?;
        let last = self.collect(true)?.pop();
        checked(last.map_or(f64::NAN, |r| r.consecutive))
    }
}
