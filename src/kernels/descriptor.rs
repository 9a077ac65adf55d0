//! `descriptor`: the built-in image descriptor the similarity step compares frames with when no
//! embedding model is given (shaders/descriptor.wgsl; the OpenCV twin is [`opencv`]). On the
//! frame at the analysis size (cv::resize INTER_AREA, the same call for both backends), a 4 x 4
//! grid of cells holds per cell an 8-bin histogram of 3x3 Sobel gradient directions (45-degree
//! sectors, weighted by |gx| + |gy|) and the cell's sums of B, G and R: 176 integer totals,
//! identical on both backends (integer arithmetic only, decided by comparisons). [`embedding`]
//! turns them into a unit vector.
//!
//! Why this descriptor: the grid of orientation histograms (a coarse HOG / GIST) describes the
//! layout of edges of a view, which changes as the camera moves to another place and stays when
//! it comes back, and it ignores brightness (normalised, square-rooted as in RootSIFT so that a
//! few strong edges do not dominate); the colour layout separates views with similar structure
//! (sky over grass against a wall). Both come from the pixels the analysis already decodes, cost
//! one pass over a small frame, and need no model file.

use super::gray;
use crate::error::{CvContext, Error, Result};
use crate::gpu::{compute_pass, mat_bytes, GpuContext};
use bytemuck::{Pod, Zeroable};
use opencv::core::{self, Mat, Size};
use opencv::imgproc;
use opencv::prelude::*;
use std::sync::Arc;

/// WGSL source, after its prelude (shaders/border.wgsl: `reflect101`).
pub const WGSL: &str = concat!(
    include_str!("../../shaders/border.wgsl"),
    include_str!("../../shaders/descriptor.wgsl")
);

/// Cells per side of the grid.
pub const GRID: usize = 4;
/// Orientation bins per cell.
pub const BINS: usize = 8;
/// Where the colour sums start among the totals.
pub const COLOUR_AT: usize = GRID * GRID * BINS;
/// Integer totals per frame (and dimensions of the embedding).
pub const TOTALS: usize = COLOUR_AT + GRID * GRID * 3;
/// The descriptor's name and version in projects (a changed descriptor is a new name).
pub const NAME: &str = "builtin-grid-hog-colour-v1";

/// Uniform parameters of descriptor.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct DescriptorParams {
    /// Frame width in pixels.
    pub width: u32,
    /// Frame height in pixels.
    pub height: u32,
    /// u32 words per row of the uploaded BGR bytes.
    pub stride: u32,
    /// Unused: pads the struct to 16 bytes.
    pub pad: u32,
}

/// The frame at the analysis `size` (width, height) in 8-bit BGR, as both backends describe it:
/// cv::resize INTER_AREA (a gray frame is made BGR first).
pub fn prepare(frame: &Mat, size: (u32, u32)) -> Result<Mat> {
    let bgr = if frame.channels() == 1 {
        let mut out = Mat::default();
        imgproc::cvt_color(frame, &mut out, imgproc::COLOR_GRAY2BGR, 0)
            .cv(|| "cvtColor GRAY2BGR".into())?;
        out
    } else {
        frame.clone()
    };
    if (bgr.cols() as u32, bgr.rows() as u32) == size {
        return Ok(bgr);
    }
    let mut out = Mat::default();
    let to = Size::new(size.0 as i32, size.1 as i32);
    imgproc::resize(&bgr, &mut out, to, 0.0, 0.0, imgproc::INTER_AREA)
        .cv(|| "resize INTER_AREA".into())?;
    Ok(out)
}

/// The 45-degree sector (0..7, counter-clockwise from +x, y down as in the image) of a non-zero
/// gradient, by comparisons only: sector k holds the directions in [45 k, 45 (k + 1)) degrees.
pub fn sector(gx: i32, gy: i32) -> usize {
    let (mut x, mut y, mut base) = (gx, gy, 0);
    if y < 0 || (y == 0 && x < 0) {
        (x, y, base) = (-x, -y, 4);
    }
    if x <= 0 {
        (x, y, base) = (y, -x, base + 2);
    }
    base + usize::from(y >= x)
}

/// The cell (row-major) of pixel (x, y) in a `w` x `h` frame.
fn cell(x: usize, y: usize, w: usize, h: usize) -> usize {
    (y * GRID / h) * GRID + x * GRID / w
}

/// OpenCV twin: the totals of an 8-bit BGR frame (cv::cvtColor to gray, cv::Sobel into 16-bit
/// integers with BORDER_DEFAULT = REFLECT_101, exact; the binning and sums as the shader does).
pub fn opencv(bgr: &Mat) -> Result<Vec<u32>> {
    if bgr.typ() != core::CV_8UC3 || bgr.empty() {
        return Err(Error::param(
            "descriptor",
            "takes a non-empty 8-bit BGR frame",
        ));
    }
    let g = gray::opencv(bgr)?;
    let (mut gx, mut gy) = (Mat::default(), Mat::default());
    let border = core::BORDER_DEFAULT;
    imgproc::sobel(&g, &mut gx, core::CV_16S, 1, 0, 3, 1.0, 0.0, border)
        .cv(|| "Sobel dx".into())?;
    imgproc::sobel(&g, &mut gy, core::CV_16S, 0, 1, 3, 1.0, 0.0, border)
        .cv(|| "Sobel dy".into())?;
    let (w, h) = (bgr.cols() as usize, bgr.rows() as usize);
    let mut totals = vec![0u32; TOTALS];
    for y in 0..h {
        let rx = gx.at_row::<i16>(y as i32).cv(|| "Sobel dx row".into())?;
        let ry = gy.at_row::<i16>(y as i32).cv(|| "Sobel dy row".into())?;
        let pixels = (bgr.at_row::<core::Vec3b>(y as i32)).cv(|| "frame row".into())?;
        for x in 0..w {
            let c = cell(x, y, w, h);
            let (dx, dy) = (i32::from(rx[x]), i32::from(ry[x]));
            let weight = dx.unsigned_abs() + dy.unsigned_abs();
            if weight > 0 {
                totals[c * BINS + sector(dx, dy)] += weight;
            }
            for ch in 0..3 {
                totals[COLOUR_AT + c * 3 + ch] += u32::from(pixels[x][ch]);
            }
        }
    }
    Ok(totals)
}

/// The unit embedding of a `w` x `h` frame's totals: the orientation histograms L1-normalised
/// and square-rooted (a unit vector, the Hellinger map of RootSIFT), the colour layout as each
/// cell's mean B, G, R in [-0.5, 0.5] (around mid-gray) L2-normalised, each half weighted
/// sqrt(1/2) so that both count alike. A flat frame (no gradient, mid-gray) gives zeros there.
pub fn embedding(totals: &[u32], (w, h): (u32, u32)) -> Vec<f64> {
    let (w, h) = (w.max(1) as usize, h.max(1) as usize);
    let orient = &totals[..COLOUR_AT];
    let sum: f64 = orient.iter().map(|&t| f64::from(t)).sum();
    let half = std::f64::consts::FRAC_1_SQRT_2;
    let mut out: Vec<f64> = orient
        .iter()
        .map(|&t| match sum > 0.0 {
            true => (f64::from(t) / sum).sqrt() * half,
            false => 0.0,
        })
        .collect();
    let span = |n: usize, i: usize| (0..n).filter(|&p| p * GRID / n == i).count();
    let colour: Vec<f64> = (0..GRID * GRID * 3)
        .map(|i| {
            let c = i / 3;
            let pixels = (span(w, c % GRID) * span(h, c / GRID)).max(1);
            f64::from(totals[COLOUR_AT + i]) / pixels as f64 / 255.0 - 0.5
        })
        .collect();
    let norm = colour.iter().map(|v| v * v).sum::<f64>().sqrt();
    out.extend(colour.iter().map(|v| match norm > 0.0 {
        true => v / norm * half,
        false => 0.0,
    }));
    out
}

/// The descriptor on the device for frames of one analysis size: one dispatch and one read-back
/// of the 176 totals per frame.
pub struct DescriptorGpu {
    ctx: Arc<GpuContext>,
    pipe: Arc<wgpu::ComputePipeline>,
    src: wgpu::Buffer,
    totals: wgpu::Buffer,
    bind: wgpu::BindGroup,
    p: DescriptorParams,
    scratch: Vec<u8>,
}

impl DescriptorGpu {
    /// Prepares the buffers for `size` (width, height) frames.
    pub fn new(ctx: Arc<GpuContext>, (width, height): (u32, u32)) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(Error::param(
                "descriptor",
                "the frame size must not be empty",
            ));
        }
        let p = DescriptorParams {
            width,
            height,
            stride: (width * 3).div_ceil(4),
            pad: 0,
        };
        let pipe = ctx.pipeline("descriptor", WGSL, "main")?;
        let params = ctx.uniform("descriptor params", &p);
        let src = ctx.storage_buffer(
            "descriptor frame",
            u64::from(p.stride) * 4 * u64::from(height),
        );
        let totals = ctx.storage_buffer("descriptor totals", TOTALS as u64 * 4);
        let bind = ctx.bind(
            "descriptor",
            &pipe,
            &[(0, &src), (1, &totals), (2, &params)],
        );
        Ok(DescriptorGpu {
            ctx,
            pipe,
            src,
            totals,
            bind,
            p,
            scratch: Vec::new(),
        })
    }

    /// The totals of one 8-bit BGR frame of the prepared size.
    pub fn totals(&mut self, bgr: &Mat) -> Result<Vec<u32>> {
        let (w, h) = (self.p.width, self.p.height);
        let bytes = mat_bytes(bgr, core::CV_8UC3, (w, h), "descriptor")?;
        let (row, padded) = (w as usize * 3, self.p.stride as usize * 4);
        let data: &[u8] = if row == padded {
            &bytes
        } else {
            self.scratch.clear();
            for r in bytes.chunks_exact(row) {
                self.scratch.extend_from_slice(r);
                self.scratch.resize(self.scratch.len() + padded - row, 0);
            }
            &self.scratch
        };
        self.ctx.write(&self.src, 0, data);
        self.ctx.write(&self.totals, 0, &[0u8; TOTALS * 4]);
        let mut enc = self.ctx.encoder("descriptor");
        let groups = (w.div_ceil(16), h.div_ceil(16));
        self.ctx.dispatch(
            &mut compute_pass(&mut enc, "descriptor"),
            &self.pipe,
            &self.bind,
            groups,
        );
        self.ctx.queue.submit([enc.finish()]);
        let back = self.ctx.read_back(&self.totals, TOTALS as u64 * 4)?;
        Ok(bytemuck::pod_collect_to_vec(&back))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sectors_follow_the_direction() {
        let deg = |d: f64| {
            let r = d.to_radians();
            sector(
                (1000.0 * r.cos()).round() as i32,
                (1000.0 * r.sin()).round() as i32,
            )
        };
        for k in 0..8 {
            assert_eq!(deg(45.0 * k as f64 + 10.0), k, "{k}");
            assert_eq!(deg(45.0 * k as f64 + 35.0), k, "{k}");
        }
        // Boundaries belong to the sector they open.
        assert_eq!(sector(1, 0), 0);
        assert_eq!(sector(1, 1), 1);
        assert_eq!(sector(0, 1), 2);
        assert_eq!(sector(-1, 1), 3);
        assert_eq!(sector(-1, 0), 4);
        assert_eq!(sector(-1, -1), 5);
        assert_eq!(sector(0, -1), 6);
        assert_eq!(sector(1, -1), 7);
    }

    #[test]
    fn embedding_is_a_unit_vector() {
        let img = crate::synthetic::pattern(37, 23, 4).unwrap();
        let t = opencv(&img).unwrap();
        let e = embedding(&t, (37, 23));
        assert_eq!(e.len(), TOTALS);
        let n: f64 = e.iter().map(|v| v * v).sum();
        assert!((n - 1.0).abs() < 1e-12, "{n}");
        // Every pixel counted once per channel.
        let pixels: u64 = (COLOUR_AT..TOTALS)
            .step_by(3)
            .map(|i| u64::from(t[i]))
            .sum();
        assert!(pixels > 0);
        let cells: usize = (0..GRID * GRID)
            .map(|c| {
                let span = |n: usize, i: usize| (0..n).filter(|&p| p * GRID / n == i).count();
                span(37, c % GRID) * span(23, c / GRID)
            })
            .sum();
        assert_eq!(cells, 37 * 23);
    }
}
