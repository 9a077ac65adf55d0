//! `remap`: renders 8-bit images (gray or BGR) through tables of source coordinates on the device
//! (shaders/remap.wgsl), with cv::remap's fixed-point rules (bilinear, bicubic; BORDER_WRAP), so
//! that one ERP frame uploaded once gives every pinhole view of an export or an analysis.
//! Twin: [`opencv`] (cv::remap on the same maps); bounds in `tolerance::REMAP_*`.

pub use crate::equirect::Interp;
#[cfg(feature = "opencv")]
use crate::error::CvContext;
use crate::error::{Error, Result};
use crate::gpu::{compute_pass, GpuContext, HostImage};
use bytemuck::{Pod, Zeroable};
#[cfg(feature = "opencv")]
use opencv::core::{Mat, Scalar};
#[cfg(feature = "opencv")]
use opencv::prelude::*;
use std::sync::Arc;

/// WGSL source.
pub const WGSL: &str = include_str!("../../shaders/remap.wgsl");

#[cfg(feature = "opencv")]
impl Interp {
    fn cv_flag(self) -> i32 {
        match self {
            Interp::Bilinear => opencv::imgproc::INTER_LINEAR,
            Interp::Bicubic => opencv::imgproc::INTER_CUBIC,
        }
    }
}

/// A remap table: for each output pixel, row after row, the source coordinates it samples.
#[derive(Debug, Clone)]
pub struct Table {
    /// Output width and height in pixels.
    pub size: (u32, u32),
    /// Source x per output pixel.
    pub xs: Vec<f32>,
    /// Source y per output pixel.
    pub ys: Vec<f32>,
}

impl Table {
    /// A table of `size` from the maps `xs`, `ys` (an error unless both hold one entry per pixel).
    pub fn new(size: (u32, u32), xs: Vec<f32>, ys: Vec<f32>) -> Result<Table> {
        let n = size.0 as usize * size.1 as usize;
        if xs.len() != n || ys.len() != n || n == 0 {
            let msg = format!(
                "a {}x{} table needs {n} x and y entries, got {} and {}",
                size.0,
                size.1,
                xs.len(),
                ys.len()
            );
            return Err(Error::param("remap", msg));
        }
        Ok(Table { size, xs, ys })
    }

    /// One table per pinhole view in `views`, sampling an ERP frame of `erp` (width, height)
    /// pixels ([`crate::equirect::view_map`]).
    pub fn of_views(views: &[crate::equirect::View], erp: (u32, u32)) -> Result<Vec<Table>> {
        (views.iter())
            .map(|v| {
                let (xs, ys) = crate::equirect::view_map(v, erp);
                Table::new((v.size, v.size), xs, ys)
            })
            .collect()
    }

    #[cfg(feature = "opencv")]
    fn mat(&self, v: &[f32]) -> Result<Mat> {
        let m = Mat::from_slice(v).cv(|| "remap map".into())?;
        m.reshape(1, self.size.1 as i32)
            .cv(|| "remap map reshape".into())?
            .try_clone()
            .cv(|| "remap map".into())
    }
}

/// OpenCV twin: `src` (8-bit, 1 or 3 channels) through `table` with cv::remap(`interp`,
/// BORDER_WRAP).
#[cfg(feature = "opencv")]
pub fn opencv(src: &Mat, table: &Table, interp: Interp) -> Result<Mat> {
    let (mx, my) = (table.mat(&table.xs)?, table.mat(&table.ys)?);
    let mut out = Mat::default();
    opencv::imgproc::remap(
        src,
        &mut out,
        &mx,
        &my,
        interp.cv_flag(),
        opencv::core::BORDER_WRAP,
        Scalar::default(),
    )
    .cv(|| "cv::remap".into())?;
    Ok(out)
}

/// cv::remap's bicubic weights for 8-bit images: for each fraction (fy, fx) in 1/32 pixel,
/// entry `(fy * 32 + fx) * 16 + ky * 4 + kx` is the weight of tap (kx, ky) in 1/2^15, OpenCV's
/// f32 interpolateCubic (A = −0.75) products rounded, then one central weight adjusted so the 16
/// sum to exactly 2^15 (OpenCV's rule: the smallest of the lower-right central taps takes a
/// surplus, the largest a deficit).
pub fn bicubic_table() -> Vec<i32> {
    const SCALE: f32 = 32768.0;
    let coeffs = |x: f32| -> [f32; 4] {
        const A: f32 = -0.75;
        let c0 = ((A * (x + 1.0) - 5.0 * A) * (x + 1.0) + 8.0 * A) * (x + 1.0) - 4.0 * A;
        let c1 = ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0;
        let c2 = ((A + 2.0) * (1.0 - x) - (A + 3.0)) * (1.0 - x) * (1.0 - x) + 1.0;
        [c0, c1, c2, 1.0 - c0 - c1 - c2]
    };
    let step = 1.0f32 / 32.0;
    let mut tab = Vec::with_capacity(32 * 32 * 16);
    for fy in 0..32 {
        let vy = coeffs(fy as f32 * step);
        for fx in 0..32 {
            let vx = coeffs(fx as f32 * step);
            let mut w = [0i32; 16];
            for (k1, y) in vy.iter().enumerate() {
                for (k2, x) in vx.iter().enumerate() {
                    w[k1 * 4 + k2] = (y * x * SCALE).round_ties_even() as i32;
                }
            }
            let diff = w.iter().sum::<i32>() - 32768;
            if diff != 0 {
                let (mut lo, mut hi) = ((2, 2), (2, 2));
                for k1 in 2..4 {
                    for k2 in 2..4 {
                        if w[k1 * 4 + k2] < w[lo.0 * 4 + lo.1] {
                            lo = (k1, k2);
                        } else if w[k1 * 4 + k2] > w[hi.0 * 4 + hi.1] {
                            hi = (k1, k2);
                        }
                    }
                }
                let at = if diff < 0 { hi } else { lo };
                w[at.0 * 4 + at.1] -= diff;
            }
            tab.extend_from_slice(&w);
        }
    }
    tab
}

/// Uniform parameters of remap.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct RemapParams {
    /// Source width in pixels.
    pub src_w: u32,
    /// Source height in pixels.
    pub src_h: u32,
    /// Output width in pixels.
    pub dst_w: u32,
    /// Output height in pixels.
    pub dst_h: u32,
    /// Channels (bytes) per pixel, 1 or 3.
    pub channels: u32,
    /// 1 for bicubic, 0 for bilinear.
    pub bicubic: u32,
    /// Padding to 16 bytes.
    pub pad: [u32; 2],
}

/// Workgroups (x, y) covering `invocations` invocations in groups of 64 (x at most 65535).
pub fn groups(invocations: u32) -> (u32, u32) {
    super::resize_area::groups(invocations)
}

struct Output {
    // Read by `render` (OpenCV Mats) only.
    #[cfg_attr(not(feature = "opencv"), allow(dead_code))]
    params: RemapParams,
    bind: wgpu::BindGroup,
    dst: wgpu::Buffer,
    bytes: u64,
}

/// The device remap of frames of one size and type through a fixed list of tables (the views):
/// each frame is uploaded once and rendered through every table in one submission.
pub struct RemapGpu {
    ctx: Arc<GpuContext>,
    pipe: Arc<wgpu::ComputePipeline>,
    src_size: (u32, u32),
    channels: u32,
    src: wgpu::Buffer,
    outputs: Vec<Output>,
    #[cfg_attr(not(feature = "opencv"), allow(dead_code))]
    staging: wgpu::Buffer,
}

impl RemapGpu {
    /// Prepares the remap of `src_size` frames of `channels` (1 or 3) 8-bit channels through
    /// every table of `tables` with `interp` (the tables are uploaded here, once).
    pub fn new(
        ctx: Arc<GpuContext>,
        src_size: (u32, u32),
        channels: u32,
        interp: Interp,
        tables: &[Table],
    ) -> Result<Self> {
        if channels != 1 && channels != 3 {
            let msg = format!("{channels} channels (1 or 3 are supported)");
            return Err(Error::param("remap", msg));
        }
        let pipe = ctx.pipeline("remap", WGSL, "main")?;
        let src_bytes = u64::from(src_size.0) * u64::from(src_size.1) * u64::from(channels);
        let src = ctx.storage_buffer("remap src", src_bytes);
        let cubic = bicubic_table();
        let cubic = ctx.buffer_init(
            "remap cubic",
            wgpu::BufferUsages::STORAGE,
            bytemuck::cast_slice(&cubic),
        );
        let mut outputs = Vec::with_capacity(tables.len());
        let mut staged = 0u64;
        for t in tables {
            let params = RemapParams {
                src_w: src_size.0,
                src_h: src_size.1,
                dst_w: t.size.0,
                dst_h: t.size.1,
                channels,
                bicubic: u32::from(interp == Interp::Bicubic),
                pad: [0; 2],
            };
            let coords: Vec<f32> = t.xs.iter().zip(&t.ys).flat_map(|(x, y)| [*x, *y]).collect();
            let coords = ctx.buffer_init(
                "remap coords",
                wgpu::BufferUsages::STORAGE,
                bytemuck::cast_slice(&coords),
            );
            let bytes = u64::from(t.size.0) * u64::from(t.size.1) * u64::from(channels);
            let dst = ctx.storage_buffer("remap dst", bytes);
            let uniform = ctx.uniform("remap params", &params);
            let entries = [
                (0, &src),
                (1, &dst),
                (2, &coords),
                (3, &uniform),
                (4, &cubic),
            ];
            let bind = ctx.bind("remap", &pipe, &entries);
            staged += bytes.next_multiple_of(4);
            outputs.push(Output {
                params,
                bind,
                dst,
                bytes,
            });
        }
        let staging = ctx.staging_buffer("remap readback", staged.max(4));
        Ok(RemapGpu {
            ctx,
            pipe,
            src_size,
            channels,
            src,
            outputs,
            staging,
        })
    }

    #[cfg(feature = "opencv")]
    fn typ(&self) -> i32 {
        if self.channels == 3 {
            opencv::core::CV_8UC3
        } else {
            opencv::core::CV_8UC1
        }
    }

    /// The device buffer output `k` is rendered into (its table's size times the channels in
    /// bytes, 4 per u32, rows not padded), until the next frame.
    pub fn output(&self, k: usize) -> Option<&wgpu::Buffer> {
        self.outputs.get(k).map(|o| &o.dst)
    }

    /// Uploads `frame` (8-bit, of the source size and channels) and records its rendering
    /// through every table into the outputs.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        frame: &(impl HostImage + ?Sized),
    ) -> Result<()> {
        let bytes = frame.pixel_bytes(self.channels, self.src_size, "remap")?;
        let mut padded;
        let upload: &[u8] = if bytes.len() % 4 == 0 {
            &bytes
        } else {
            padded = bytes.to_vec();
            padded.resize(bytes.len().next_multiple_of(4), 0);
            &padded
        };
        self.ctx.write(&self.src, 0, upload);
        let mut pass = compute_pass(enc, "remap");
        for o in &self.outputs {
            // One invocation per four output pixels.
            let quads = (o.bytes / u64::from(self.channels)).div_ceil(4) as u32;
            self.ctx
                .dispatch(&mut pass, &self.pipe, &o.bind, groups(quads));
        }
        Ok(())
    }

    /// Renders `frame` (8-bit, of the source size and channels) through every table and reads the
    /// outputs back, in the order of the tables.
    #[cfg(feature = "opencv")]
    pub fn render(&self, frame: &Mat) -> Result<Vec<Mat>> {
        let typ = self.typ();
        let mut enc = self.ctx.encoder("remap");
        self.encode(&mut enc, frame)?;
        let mut at = 0;
        for o in &self.outputs {
            let n = o.bytes.next_multiple_of(4);
            enc.copy_buffer_to_buffer(&o.dst, 0, &self.staging, at, n);
            at += n;
        }
        self.ctx.queue.submit([enc.finish()]);
        let all = self.ctx.map_and_copy(&self.staging)?;
        let mut out = Vec::with_capacity(self.outputs.len());
        let mut at = 0usize;
        for o in &self.outputs {
            let p = &o.params;
            let mut m = Mat::new_rows_cols_with_default(
                p.dst_h as i32,
                p.dst_w as i32,
                typ,
                Scalar::default(),
            )
            .cv(|| "remap output".into())?;
            m.data_bytes_mut()
                .cv(|| "remap output".into())?
                .copy_from_slice(&all[at..at + o.bytes as usize]);
            at += o.bytes.next_multiple_of(4) as usize;
            out.push(m);
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bicubic_weights_sum_to_one_and_interpolate() {
        let tab = bicubic_table();
        assert_eq!(tab.len(), 32 * 32 * 16);
        for w in tab.chunks(16) {
            assert_eq!(w.iter().sum::<i32>(), 32768);
        }
        // Fraction 0: the sample is the tap (1, 1) itself.
        let mut first = [0; 16];
        first[5] = 32768;
        assert_eq!(tab[..16], first);
        // Half way on x only: taps (1, 1) and (2, 1) weigh the same, the outer two negative.
        let half = &tab[16 * 16..16 * 17];
        assert_eq!(half[5], half[6]);
        assert!(half[4] < 0 && half[4] == half[7]);
    }

    #[test]
    fn tables_check_their_size() {
        assert!(Table::new((2, 2), vec![0.0; 4], vec![0.0; 4]).is_ok());
        assert!(Table::new((2, 2), vec![0.0; 3], vec![0.0; 4]).is_err());
        assert!(Table::new((0, 2), vec![], vec![]).is_err());
    }
}
