//! `strip`: the frame layout and invocation shape shared by the sharpness kernels
//! (shaders/strip.wgsl, the prelude their `WGSL` starts with): an 8-bit BGR frame uploaded as an `Rgba32Uint` texture
//! (one texture row per frame row, 16 bytes per texel, rows padded to whole texels), read by
//! invocations that each own 16 columns of `strip_rows` rows, with no shared memory and no
//! barrier. The strip height is the one shape parameter, chosen per adapter class
//! ([`strip_rows_for`]) and overridable for `bench`.

use crate::error::{Error, Result};
use crate::gpu::{GpuContext, HostImage};
use bytemuck::{Pod, Zeroable};

/// Columns per invocation (48 bytes of BGR = 3 texels).
pub const STRIP_WIDTH: u32 = 16;

/// Invocations per workgroup along x (the kernels' `@workgroup_size(8, 1, 1)`).
const GROUP_WIDTH: u32 = 8;

/// Uniform parameters of strip.wgsl (shared by tenengrad.wgsl and laplacian.wgsl).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct StripParams {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Rows per invocation.
    pub strip_rows: u32,
    /// u32 words per row of the packed gray output.
    pub stride: u32,
    /// laplacian.wgsl: aperture 1 or 3.
    pub ksize: u32,
    /// 1: also write the packed gray image.
    pub write_gray: u32,
    /// Unused: pads the struct to a multiple of 16 bytes.
    pub pad: [u32; 2],
}

/// Rows per invocation on `ctx`'s adapter. Software adapters (lavapipe/llvmpipe run each
/// invocation on a CPU SIMD lane) gain from long strips: each row is read once and the window
/// slides in registers; 36 rows measured fastest there (`keyframer bench sharpness --strip-rows`).
/// Hardware GPUs need many short strips for occupancy.
pub fn strip_rows_for(ctx: &GpuContext) -> u32 {
    if ctx.summary().software {
        36
    } else {
        4
    }
}

/// Texels per texture row of a `width`-pixel frame.
pub fn texels_per_row(width: u32) -> u32 {
    (width * 3).div_ceil(16)
}

/// Workgroups for a `width` x `height` frame in strips of `strip_rows` rows.
pub fn groups(width: u32, height: u32, strip_rows: u32) -> (u32, u32) {
    (
        width.div_ceil(STRIP_WIDTH).div_ceil(GROUP_WIDTH),
        height.div_ceil(strip_rows),
    )
}

/// A texture holding one `width` x `height` BGR frame.
pub fn frame_texture(ctx: &GpuContext, width: u32, height: u32) -> Result<wgpu::Texture> {
    let (tw, max) = (texels_per_row(width), ctx.limits.max_texture_dimension_2d);
    if tw > max || height > max {
        return Err(Error::gpu(format!(
            "a {width}x{height} frame needs a {tw}x{height} texture; this adapter allows {max}x{max}"
        )));
    }
    Ok(ctx.texture(
        "bgr frame",
        (tw, height),
        wgpu::TextureFormat::Rgba32Uint,
        wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
    ))
}

/// Uploads the pixels of `frame` (8-bit BGR, `width` x the texture's height; `what` names the runner in
/// errors) into `texture`; rows whose bytes do not fill whole texels are padded in `scratch`.
pub fn upload(
    ctx: &GpuContext,
    texture: &wgpu::Texture,
    frame: &(impl HostImage + ?Sized),
    width: u32,
    what: &str,
    scratch: &mut Vec<u8>,
) -> Result<()> {
    let size = texture.size();
    let bytes = frame.pixel_bytes(3, (width, size.height), what)?;
    let row = width as usize * 3;
    let padded = size.width as usize * 16;
    let data: &[u8] = if row == padded {
        &bytes
    } else {
        scratch.clear();
        for r in bytes.chunks_exact(row) {
            scratch.extend_from_slice(r);
            scratch.resize(scratch.len() + padded - row, 0);
        }
        scratch
    };
    ctx.write_texture(texture, data, padded as u32);
    Ok(())
}
