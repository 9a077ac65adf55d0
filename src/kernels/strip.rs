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

/// Bytes per row of a `width`-pixel frame in staging memory: its texels, rounded up to the
/// 256 bytes `copy_buffer_to_texture` wants between rows.
pub fn staging_pitch(width: u32) -> u32 {
    (texels_per_row(width) * 16).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
}

/// The staging memory of a runner that uploads `frames` frames of `width` x `height` per
/// submission: a `wgpu::util::StagingBelt` of one batch per chunk, mapped once and reused once
/// the device is done with a batch. (`queue.write_texture` took fresh staging memory for every
/// frame: twice the upload time on lavapipe at 1080p; docs/benchmarks.md, "upload belt".)
pub fn belt(
    ctx: &GpuContext,
    (width, height): (u32, u32),
    frames: usize,
) -> wgpu::util::StagingBelt {
    let frame = u64::from(staging_pitch(width)) * u64::from(height);
    wgpu::util::StagingBelt::new(ctx.device.clone(), frame * frames.max(1) as u64)
}

/// Stages the pixels of `frame` (8-bit BGR, `width` x the texture's height; `what` names the
/// runner in errors) in `belt`, one row at a time at [`staging_pitch`] (the padding of the last
/// texel zeroed), and records their copy into `texture` on `enc` (counted as uploaded). The
/// belt must be finished before `enc` is submitted and recalled after.
pub fn upload(
    ctx: &GpuContext,
    (belt, enc): (&mut wgpu::util::StagingBelt, &mut wgpu::CommandEncoder),
    texture: &wgpu::Texture,
    frame: &(impl HostImage + ?Sized),
    width: u32,
    what: &str,
) -> Result<()> {
    let size = texture.size();
    let bytes = frame.pixel_bytes(3, (width, size.height), what)?;
    let row = width as usize * 3;
    let padded = size.width as usize * 16;
    let pitch = staging_pitch(width);
    let total = u64::from(pitch) * u64::from(size.height);
    let align = u64::from(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let (Some(total), Some(align)) = (wgpu::BufferSize::new(total), wgpu::BufferSize::new(align))
    else {
        return Err(Error::gpu(format!("{what}: an empty frame")));
    };
    let slice = belt.allocate(total, align);
    {
        let mut view = (slice.get_mapped_range_mut())
            .map_err(|e| Error::gpu(format!("{what}: staging memory: {e:?}")))?;
        let zeros = [0u8; 16];
        for (y, r) in bytes.chunks_exact(row).enumerate() {
            let at = y * pitch as usize;
            view.slice(at..at + row).copy_from_slice(r);
            view.slice(at + row..at + padded)
                .copy_from_slice(&zeros[..padded - row]);
        }
    }
    enc.copy_buffer_to_texture(
        wgpu::TexelCopyBufferInfo {
            buffer: slice.buffer(),
            layout: wgpu::TexelCopyBufferLayout {
                offset: slice.offset(),
                bytes_per_row: Some(pitch),
                rows_per_image: None,
            },
        },
        texture.as_image_copy(),
        size,
    );
    ctx.count_upload((padded * size.height as usize) as u64);
    Ok(())
}
