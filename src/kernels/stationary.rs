//! `stationary` on the device (shaders/stationary.wgsl): the stationary step's decision per frame,
//! in the f64 arithmetic of its twin `steps::StationarySampler` (emulated exactly, shaders/f64.wgsl), and
//! the gates that run the flow from the reference frame only when the step asks for it and keep
//! a frame as the new reference only when it becomes one. So a run of frames is measured and
//! decided without the host reading anything back in between.

use crate::gpu::{compute_pass, GpuContext};
use crate::kernels::movement::RECORD_WORDS;
use crate::params::StationaryRequest;
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;

/// WGSL source (after the f64 arithmetic it uses).
pub const WGSL: &str = concat!(
    include_str!("../../shaders/f64.wgsl"),
    include_str!("../../shaders/stationary.wgsl")
);

/// Frame flag: the frame is a candidate of the step.
pub const CANDIDATE: u32 = 1;
/// Frame flag: the consecutive movement from the previous frame was measured with it.
pub const FROM_PREVIOUS: u32 = 2;

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Consts {
    threshold: [u32; 2],
    scale: [u32; 2],
    reset_delta: u32,
    record: u32,
    plan_end: u32,
    keep_begin: u32,
    keep_end: u32,
    pad: [u32; 3],
}

/// High and low words of an f64's bits, as the shaders hold it.
fn words(v: f64) -> [u32; 2] {
    let b = v.to_bits();
    [(b >> 32) as u32, b as u32]
}

/// The decision and gating passes over one results buffer, and the step's state on the device.
pub struct StationarySamplerGpu {
    ctx: Arc<GpuContext>,
    plan: (Arc<wgpu::ComputePipeline>, wgpu::BindGroup),
    decide: (Arc<wgpu::ComputePipeline>, wgpu::BindGroup),
    state: wgpu::Buffer,
    args: wgpu::Buffer,
}

impl StationarySamplerGpu {
    /// The step of `req` on movements (analysis pixels) times `scale`; frames name their record
    /// in `results` through `frame`. The gated dispatches have the sizes `shapes`: the first
    /// `plan` of them measure from the reference, the rest keep a frame as the reference.
    pub fn new(
        ctx: Arc<GpuContext>,
        req: &StationaryRequest,
        scale: f64,
        (frame, results): (&wgpu::Buffer, &wgpu::Buffer),
        shapes: &[(u32, u32)],
        plan: usize,
    ) -> crate::error::Result<StationarySamplerGpu> {
        let table: Vec<u32> = shapes.iter().flat_map(|&(x, y)| [x, y, 1]).collect();
        let words_of = |n: usize| (3 * n) as u32;
        let consts = Consts {
            threshold: words(req.threshold),
            scale: words(scale),
            reset_delta: u32::try_from(req.reset_delta).unwrap_or(u32::MAX),
            record: RECORD_WORDS,
            plan_end: words_of(plan),
            keep_begin: words_of(plan),
            keep_end: words_of(shapes.len()),
            pad: [0; 3],
        };
        let consts = ctx.uniform("stationary consts", &consts);
        let storage = wgpu::BufferUsages::STORAGE;
        let shapes = ctx.buffer_init("stationary shapes", storage, bytemuck::cast_slice(&table));
        let args = ctx.indirect_buffer("stationary gates", &vec![0u8; table.len() * 4]);
        let state = ctx.storage_buffer("stationary state", 16);
        let binds = [
            (0, &state),
            (1, frame),
            (2, results),
            (3, &shapes),
            (4, &args),
            (5, &consts),
        ];
        let with = |entry: &str, skip: Option<u32>| -> crate::error::Result<_> {
            let p = ctx.pipeline("stationary", WGSL, entry)?;
            let used: Vec<_> = binds
                .iter()
                .filter(|b| Some(b.0) != skip)
                .copied()
                .collect();
            let bg = ctx.bind(entry, &p, &used);
            Ok((p, bg))
        };
        Ok(StationarySamplerGpu {
            // `plan` reads no record.
            plan: with("plan", Some(2))?,
            decide: with("decide", None)?,
            ctx,
            state,
            args,
        })
    }

    /// The buffer the gated dispatches read their sizes from (entries in `shapes` order).
    pub fn args(&self) -> &wgpu::Buffer {
        &self.args
    }

    /// Records the pass opening or closing the measurement from the reference.
    pub fn encode_plan(&self, enc: &mut wgpu::CommandEncoder) {
        let (p, bg) = &self.plan;
        self.ctx
            .dispatch(&mut compute_pass(enc, "stationary"), p, bg, (1, 1));
    }

    /// Records the decision (after the measurements it uses).
    pub fn encode_decide(&self, enc: &mut wgpu::CommandEncoder) {
        let (p, bg) = &self.decide;
        self.ctx
            .dispatch(&mut compute_pass(enc, "stationary"), p, bg, (1, 1));
    }

    /// Sets the step's state: its reference frame (None: none yet) and the movement it
    /// accumulated.
    pub fn restore(&self, reference: Option<usize>, accumulated: f64) {
        let [hi, lo] = words(accumulated);
        let r = reference.map_or(0, |r| r as u32);
        let state = [u32::from(reference.is_some()), r, hi, lo];
        self.ctx.write(&self.state, 0, bytemuck::cast_slice(&state));
    }
}
