//! `resize_area`: 8-bit gray downsizing by integer factors on the device, bit-exact with
//! cv::resize(INTER_AREA) (shaders/resize_area.wgsl), and the same rules on the host ([`host`],
//! the opencv backend's analysis resize); other factors stay on the CPU twin.

use super::gray_stride;
#[cfg(feature = "opencv")]
use crate::error::CvContext;
use crate::error::{Error, Result};
#[cfg(feature = "opencv")]
use crate::gpu::compute_pass;
use crate::gpu::GpuContext;
use bytemuck::{Pod, Zeroable};
#[cfg(feature = "opencv")]
use opencv::{
    core::{Mat, Size},
    prelude::*,
};
use std::sync::Arc;

/// WGSL source.
pub const WGSL: &str = include_str!("../../shaders/resize_area.wgsl");

/// Uniform parameters of resize_area.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct ResizeAreaParams {
    /// Source width in pixels.
    pub src_w: u32,
    /// Source height in pixels.
    pub src_h: u32,
    /// u32 words per source row (gray.wgsl's packed layout).
    pub src_stride: u32,
    /// Output width in pixels.
    pub dst_w: u32,
    /// Output height in pixels.
    pub dst_h: u32,
    /// Horizontal factor.
    pub kx: u32,
    /// Vertical factor.
    pub ky: u32,
    /// 1 / (kx * ky) in f32, as OpenCV computes it.
    pub scale: f32,
}

/// OpenCV twin: `gray` resized to `size` with cv::resize(INTER_AREA).
#[cfg(feature = "opencv")]
pub fn opencv(gray: &Mat, size: Size) -> Result<Mat> {
    crate::encode::resize(gray, (size.width, size.height), opencv::imgproc::INTER_AREA)
        .cv(|| "resize INTER_AREA".into())
}

/// `gray` (8-bit) resized to `size` as cv::resize(INTER_AREA) does, computed here where the
/// factors are integers (the shader's rules: block sums, (sum + 2) >> 2 for 2 x 2, otherwise
/// round-half-even of f32(sum) * (1 / (kx * ky)); rows summed along, so the loops vectorise) and
/// by [`opencv`] otherwise. Bit-exact with OpenCV (`sharpness::resize_area_host_is_bit_exact`).
#[cfg(feature = "opencv")]
pub fn host(gray: &Mat, size: Size) -> Result<Mat> {
    let src_size = (gray.cols() as u32, gray.rows() as u32);
    let dst_size = (size.width.max(0) as u32, size.height.max(0) as u32);
    let plain = gray.typ() == opencv::core::CV_8UC1 && gray.is_continuous();
    let found = plain.then(|| factors(src_size, dst_size)).flatten();
    // Block sums in u16: up to 257 blocks of 255.
    let Some((kx, ky)) = found.filter(|&(kx, ky)| kx * ky <= 257) else {
        return opencv(gray, size);
    };
    let (sw, dw) = (src_size.0 as usize, dst_size.0 as usize);
    let (kx, ky) = (kx as usize, ky as usize);
    let src = gray.data_bytes().cv(|| "resize_area source".into())?;
    let mut out = Mat::new_rows_cols_with_default(
        size.height,
        size.width,
        opencv::core::CV_8UC1,
        opencv::core::Scalar::all(0.0),
    )
    .cv(|| "resize_area output".into())?;
    let dst = out.data_bytes_mut().cv(|| "resize_area output".into())?;
    let blocks = Blocks { sw, dw, kx, ky };
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above), the only requirement of
        // `blocks_avx2`'s `target_feature`.
        unsafe { blocks_avx2(&blocks, src, dst) };
        return Ok(out);
    }
    blocks.run(src, dst);
    Ok(out)
}

/// The integer-factor block averages of [`host`]: source width, destination width, factors.
#[cfg(feature = "opencv")]
struct Blocks {
    sw: usize,
    dw: usize,
    kx: usize,
    ky: usize,
}

#[cfg(feature = "opencv")]
impl Blocks {
    /// Every destination row from its `ky` source rows (the same integer sums and f32 steps
    /// whichever instructions the compiler picks).
    #[inline(always)]
    fn run(&self, src: &[u8], dst: &mut [u8]) {
        let Blocks { sw, dw, kx, ky } = *self;
        let scale = 1.0f32 / (kx * ky) as f32;
        let mut sums = vec![0u16; sw];
        for (y, drow) in dst.chunks_exact_mut(dw).enumerate() {
            sums.fill(0);
            for srow in src[y * ky * sw..(y + 1) * ky * sw].chunks_exact(sw) {
                for (s, &p) in sums.iter_mut().zip(srow) {
                    *s += u16::from(p);
                }
            }
            for (d, block) in drow.iter_mut().zip(sums.chunks_exact(kx)) {
                let sum: u16 = block.iter().sum();
                *d = if kx == 2 && ky == 2 {
                    ((sum + 2) >> 2) as u8
                } else {
                    // Round half to even: adding 2^23 leaves no fraction bits (0 <= v <= 255).
                    let v = f32::from(sum) * scale;
                    ((v + 8_388_608.0) - 8_388_608.0).min(255.0) as u8
                };
            }
        }
    }
}

/// [`Blocks::run`] compiled for AVX2.
#[cfg(all(feature = "opencv", target_arch = "x86_64"))]
#[target_feature(enable = "avx2")]
fn blocks_avx2(blocks: &Blocks, src: &[u8], dst: &mut [u8]) {
    blocks.run(src, dst)
}

/// The integer factors (kx, ky) when cv::resize(INTER_AREA) from `src` to `dst` takes its
/// integer-factor path (the shader's case): OpenCV's test that 1 / (dst / src) is within
/// f64::EPSILON of an integer on both axes, which for real sizes means `src = k * dst` exactly.
/// None otherwise (upscaling, fractional factors): the CPU twin handles those.
pub fn factors(src: (u32, u32), dst: (u32, u32)) -> Option<(u32, u32)> {
    let axis = |s: u32, d: u32| -> Option<u32> {
        if s == 0 || d == 0 || d > s {
            return None;
        }
        let scale = 1.0 / (f64::from(d) / f64::from(s));
        let k = scale.round();
        ((scale - k).abs() < f64::EPSILON && u64::from(d) * k as u64 == u64::from(s))
            .then_some(k as u32)
    };
    Some((axis(src.0, dst.0)?, axis(src.1, dst.1)?))
}

/// Workgroups (x, y) covering `words` invocations of 64 (x at most 65535).
pub fn groups(words: u32) -> (u32, u32) {
    let g = words.div_ceil(64).max(1);
    (g.min(65535), g.div_ceil(65535))
}

/// The device resize from a packed gray image of one size to a packed output of another.
pub struct ResizeAreaGpu {
    ctx: Arc<GpuContext>,
    pipe: Arc<wgpu::ComputePipeline>,
    params: wgpu::Buffer,
    p: ResizeAreaParams,
}

impl ResizeAreaGpu {
    /// Prepares the resize from `src` to `dst` (width, height); an error unless [`factors`]
    /// gives integer factors.
    pub fn new(ctx: Arc<GpuContext>, src: (u32, u32), dst: (u32, u32)) -> Result<Self> {
        let (kx, ky) = factors(src, dst).ok_or_else(|| {
            Error::param(
                "resize_area",
                format!(
                    "{}x{} -> {}x{} is not an integer downscale",
                    src.0, src.1, dst.0, dst.1
                ),
            )
        })?;
        let p = ResizeAreaParams {
            src_w: src.0,
            src_h: src.1,
            src_stride: gray_stride(src.0),
            dst_w: dst.0,
            dst_h: dst.1,
            kx,
            ky,
            scale: 1.0f32 / (kx * ky) as f32,
        };
        let pipe = ctx.pipeline("resize_area", WGSL, "main")?;
        let params = ctx.uniform("resize_area params", &p);
        Ok(ResizeAreaGpu {
            ctx,
            pipe,
            params,
            p,
        })
    }

    /// Bytes of the output (before rounding the buffer up to 4).
    pub fn dst_bytes(&self) -> u64 {
        u64::from(self.p.dst_w) * u64::from(self.p.dst_h)
    }

    /// A bind group reading the gray buffer `src` and writing `dst`.
    pub fn bind(&self, src: &wgpu::Buffer, dst: &wgpu::Buffer) -> wgpu::BindGroup {
        let entries = [(0, src), (1, dst), (2, &self.params)];
        self.ctx.bind("resize_area", &self.pipe, &entries)
    }

    /// Records the resize of one bound (src, dst) pair.
    pub fn encode(&self, pass: &mut wgpu::ComputePass<'_>, bg: &wgpu::BindGroup) {
        let words = self.dst_bytes().div_ceil(4) as u32;
        self.ctx.dispatch(pass, &self.pipe, bg, groups(words));
    }

    /// Resizes an 8-bit gray `Mat` of the source size (uploaded in gray.wgsl's layout) and reads
    /// the output back, row after row (for checking against [`opencv`]).
    #[cfg(feature = "opencv")]
    pub fn resize_mat(&self, gray: &Mat) -> Result<Vec<u8>> {
        let (w, h) = (self.p.src_w as usize, self.p.src_h as usize);
        if gray.typ() != opencv::core::CV_8UC1
            || (gray.cols() as usize, gray.rows() as usize) != (w, h)
        {
            let msg = format!("input must be {w}x{h} 8-bit gray");
            return Err(Error::param("resize_area", msg));
        }
        let row = self.p.src_stride as usize * 4;
        let mut packed = vec![0u8; row * h];
        for y in 0..h {
            let line = gray.at_row::<u8>(y as i32).cv(|| "gray row".into())?;
            packed[y * row..y * row + w].copy_from_slice(line);
        }
        let src = self
            .ctx
            .storage_buffer("resize_area src", packed.len() as u64);
        self.ctx.write(&src, 0, &packed);
        let dst = self.ctx.storage_buffer("resize_area dst", self.dst_bytes());
        let bg = self.bind(&src, &dst);
        let mut enc = self.ctx.encoder("resize_area");
        self.encode(&mut compute_pass(&mut enc, "resize_area"), &bg);
        self.ctx.queue.submit([enc.finish()]);
        self.ctx.read_back(&dst, self.dst_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integer_factors_follow_opencv_rule() {
        assert_eq!(factors((1920, 1080), (640, 360)), Some((3, 3)));
        assert_eq!(factors((3840, 2160), (640, 360)), Some((6, 6)));
        assert_eq!(factors((1280, 720), (640, 360)), Some((2, 2)));
        assert_eq!(factors((640, 720), (640, 360)), Some((1, 2)));
        assert_eq!(factors((1440, 1080), (640, 480)), None);
        assert_eq!(factors((1921, 1080), (640, 360)), None);
        assert_eq!(factors((320, 180), (640, 360)), None);
        assert_eq!(groups(900), (15, 1));
        assert_eq!(groups(65535 * 64 + 1), (65535, 2));
    }
}
