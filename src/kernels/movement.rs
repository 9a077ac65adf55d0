//! `movement`: a robust statistic of the per-pixel flow magnitude (median or trimmed mean),
//! computed on the device by exact radix selection (shaders/movement.wgsl); `cpu` is the twin on
//! the host (sorting the same f32 magnitudes of OpenCV's flow).

use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use bytemuck::{Pod, Zeroable};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// WGSL source.
pub const WGSL: &str = include_str!("../../shaders/movement.wgsl");

/// Which robust statistic of the flow magnitudes measures movement.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Statistic {
    /// The median (mean of the two middle values for an even count), as iVS3D's code uses.
    Median,
    /// The mean after dropping the `trim` fraction of smallest and of largest values, as the
    /// iVS3D paper describes.
    TrimmedMean {
        /// Fraction dropped at each end, in [0, 0.5).
        trim: f64,
    },
}

impl Statistic {
    /// The `--movement` flag value and `--trim` for this statistic.
    pub fn to_flag(self) -> (&'static str, Option<f64>) {
        match self {
            Statistic::Median => ("median", None),
            Statistic::TrimmedMean { trim } => ("trimmed-mean", Some(trim)),
        }
    }
}

impl Statistic {
    /// Checks the trim fraction.
    pub fn validate(&self) -> Result<()> {
        if let Statistic::TrimmedMean { trim } = self {
            if !(0.0..0.5).contains(trim) {
                return Err(Error::param("trim", "must be in [0, 0.5)"));
            }
        }
        Ok(())
    }

    /// The 0-based ranks (lo, hi inclusive) the statistic needs among `n` sorted values.
    fn ranks(&self, n: u32) -> (u32, u32) {
        match self {
            Statistic::Median => ((n - 1) / 2, n / 2),
            Statistic::TrimmedMean { trim } => {
                let cut = (f64::from(n) * trim).floor() as u32;
                (cut, n - cut - 1)
            }
        }
    }
}

/// Per-pixel magnitudes of a CV_32FC2 flow field, in f32 as the shader computes them.
pub fn magnitudes(flow: &opencv::core::Mat) -> Result<Vec<f32>> {
    use opencv::prelude::*;
    let d = flow
        .data_typed::<opencv::core::Vec2f>()
        .map_err(|e| Error::param("flow", e.to_string()))?;
    Ok(d.iter()
        .map(|v| (v[0] * v[0] + v[1] * v[1]).sqrt())
        .collect())
}

/// Host twin: the statistic of `values`.
pub fn cpu(values: &[f32], stat: Statistic) -> Result<f64> {
    stat.validate()?;
    if values.is_empty() {
        return Err(Error::param("flow", "empty flow field"));
    }
    let mut v = values.to_vec();
    v.sort_by(f32::total_cmp);
    let (lo, hi) = stat.ranks(v.len() as u32);
    Ok(match stat {
        Statistic::Median => (f64::from(v[lo as usize]) + f64::from(v[hi as usize])) * 0.5,
        Statistic::TrimmedMean { .. } => {
            let s: f64 = v[lo as usize..=hi as usize]
                .iter()
                .map(|&x| f64::from(x))
                .sum();
            s / f64::from(hi - lo + 1)
        }
    })
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Params {
    n: u32,
    groups_x: u32,
    shift: u32,
    mask: u32,
    prefix_shift: u32,
    prefix0: u32,
    prefix1: u32,
    lo_bits: u32,
    hi_bits: u32,
    pad: [u32; 3],
}

const BINS: usize = 4096;

fn entry(binding: u32, buf: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: buf.as_entire_binding(),
    }
}

/// Device statistic over one flow buffer (2 x f32 per pixel, `n` pixels).
pub struct MovementGpu {
    ctx: Arc<GpuContext>,
    n: u32,
    groups: (u32, u32),
    hist_pipe: Arc<wgpu::ComputePipeline>,
    sums_pipe: Arc<wgpu::ComputePipeline>,
    params: wgpu::Buffer,
    hist: wgpu::Buffer,
    counts: wgpu::Buffer,
    partials: wgpu::Buffer,
    hist_bg: wgpu::BindGroup,
    sums_bg: wgpu::BindGroup,
}

impl MovementGpu {
    /// Binds the statistic to `flow` holding `n` flow vectors.
    pub fn new(ctx: Arc<GpuContext>, flow: &wgpu::Buffer, n: u32) -> Result<Self> {
        if n == 0 {
            return Err(Error::param("flow", "empty flow field"));
        }
        let hist_pipe = ctx.pipeline("movement", WGSL, "histogram")?;
        let sums_pipe = ctx.pipeline("movement", WGSL, "sums")?;
        let total = n.div_ceil(256);
        let gx = total.min(65_535);
        let groups = (gx, total.div_ceil(gx));
        let params = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("movement params"),
            size: std::mem::size_of::<Params>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let hist = ctx.storage_buffer("movement histogram", (2 * BINS * 4) as u64);
        let counts = ctx.storage_buffer("movement counts", 16);
        let partials = ctx.storage_buffer("movement partials", u64::from(groups.0 * groups.1) * 4);
        let hist_bg = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("movement histogram"),
            layout: &hist_pipe.get_bind_group_layout(0),
            entries: &[entry(0, flow), entry(1, &hist), entry(4, &params)],
        });
        let sums_bg = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("movement sums"),
            layout: &sums_pipe.get_bind_group_layout(0),
            entries: &[
                entry(0, flow),
                entry(2, &counts),
                entry(3, &partials),
                entry(4, &params),
            ],
        });
        Ok(MovementGpu {
            ctx,
            n,
            groups,
            hist_pipe,
            sums_pipe,
            params,
            hist,
            counts,
            partials,
            hist_bg,
            sums_bg,
        })
    }

    fn run(&self, p: &Params, histogram: bool) {
        self.ctx
            .queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(p));
        let mut enc = self
            .ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("movement"),
            });
        if histogram {
            enc.clear_buffer(&self.hist, 0, None);
        } else {
            enc.clear_buffer(&self.counts, 0, None);
        }
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("movement"),
                timestamp_writes: None,
            });
            if histogram {
                pass.set_pipeline(&self.hist_pipe);
                pass.set_bind_group(0, &self.hist_bg, &[]);
            } else {
                pass.set_pipeline(&self.sums_pipe);
                pass.set_bind_group(0, &self.sums_bg, &[]);
            }
            pass.dispatch_workgroups(self.groups.0, self.groups.1, 1);
        }
        self.ctx.queue.submit([enc.finish()]);
    }

    /// Bit patterns of the values at ranks `lo` and `hi` (0-based, ascending).
    fn select(&self, lo: u32, hi: u32) -> Result<[u32; 2]> {
        // (shift, mask bits, prefix_shift) of the three radix passes over bits 30..0.
        let passes = [(19u32, 12u32, 31u32), (7, 12, 19), (0, 7, 7)];
        let mut prefix = [0u32; 2];
        let mut rank = [lo, hi];
        for (shift, bits, prefix_shift) in passes {
            let p = Params {
                n: self.n,
                groups_x: self.groups.0,
                shift,
                mask: (1 << bits) - 1,
                prefix_shift,
                prefix0: prefix[0],
                prefix1: prefix[1],
                lo_bits: 0,
                hi_bits: 0,
                pad: [0; 3],
            };
            self.run(&p, true);
            let bytes = self.ctx.read_back(&self.hist, (2 * BINS * 4) as u64)?;
            let h: &[u32] = bytemuck::cast_slice(&bytes);
            for r in 0..2 {
                let mut before = 0u32;
                let mut found = None;
                for (b, &c) in h[r * BINS..r * BINS + (1 << bits)].iter().enumerate() {
                    if rank[r] < before + c {
                        found = Some(b as u32);
                        break;
                    }
                    before += c;
                }
                let b = found.ok_or_else(|| {
                    Error::Gpu("movement histogram lost values (non-finite flow?)".into())
                })?;
                rank[r] -= before;
                prefix[r] = (prefix[r] << bits) | b;
            }
        }
        Ok(prefix)
    }

    /// The statistic of the magnitudes in the bound flow buffer (submitted work must be queued).
    pub fn compute(&self, stat: Statistic) -> Result<f64> {
        stat.validate()?;
        let (lo, hi) = stat.ranks(self.n);
        let [lo_bits, hi_bits] = self.select(lo, hi)?;
        let (vlo, vhi) = (
            f64::from(f32::from_bits(lo_bits)),
            f64::from(f32::from_bits(hi_bits)),
        );
        if let Statistic::Median = stat {
            return Ok((vlo + vhi) * 0.5);
        }
        if lo_bits == hi_bits {
            return Ok(vlo);
        }
        let p = Params {
            n: self.n,
            groups_x: self.groups.0,
            shift: 0,
            mask: 0,
            prefix_shift: 31,
            prefix0: u32::MAX,
            prefix1: u32::MAX,
            lo_bits,
            hi_bits,
            pad: [0; 3],
        };
        self.run(&p, false);
        let c = self.ctx.read_back(&self.counts, 16)?;
        let c: &[u32] = bytemuck::cast_slice(&c);
        let parts = self
            .ctx
            .read_back(&self.partials, u64::from(self.groups.0 * self.groups.1) * 4)?;
        let between: f64 = bytemuck::cast_slice::<u8, f32>(&parts)
            .iter()
            .map(|&v| f64::from(v))
            .sum();
        let take_lo = f64::from(c[1] - lo);
        let take_hi = f64::from(hi + 1 - c[2]);
        Ok((take_lo * vlo + between + take_hi * vhi) / f64::from(hi - lo + 1))
    }
}
