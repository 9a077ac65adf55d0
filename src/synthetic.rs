//! Deterministic synthetic test images (gradients, a hard-edged rectangle, noise) for kernel
//! checks, reference fixtures and benchmarks, and a scrolling scene whose frames are slices of
//! one buffer (`keyframer-gpu-bench`; no OpenCV). The same seed always gives the same pixels.

#[cfg(feature = "opencv")]
use crate::error::{CvContext, Result};
#[cfg(feature = "opencv")]
use opencv::{
    core::{Mat, Scalar, CV_8UC3},
    prelude::*,
};

/// Rows a [`Scroll`] moves through before it starts over.
pub const SCROLL_ROWS: u32 = 240;

/// A scene of 8-bit BGR frames `width` x `height` moving up `speed` rows per frame: a checker of
/// hard edges over diagonal gradients with fixed per-pixel noise (texture for the flow, edges
/// for the sharpness). Frame `i` is the window [`SCROLL_ROWS`]-periodically `speed * i` rows
/// down one buffer, so frames cost no copy (frame rows are packed, `width * 3` bytes).
pub struct Scroll {
    width: u32,
    height: u32,
    speed: u32,
    world: Vec<u8>,
}

/// Rows per frame the scene of `keyframer-gpu-bench` (and its checks) moves.
pub const BENCH_SPEED: u32 = 2;
/// Seed of that scene.
pub const BENCH_SEED: u64 = 35;

impl Scroll {
    /// The scene `keyframer-gpu-bench` times, `width` x `height` ([`BENCH_SPEED`], [`BENCH_SEED`]).
    pub fn bench(width: u32, height: u32) -> Scroll {
        Scroll::new(width, height, BENCH_SPEED, BENCH_SEED)
    }

    /// The scene from `seed` (the same seed, the same pixels).
    pub fn new(width: u32, height: u32, speed: u32, seed: u64) -> Scroll {
        let (w, rows) = (width.max(1) as usize, (height + SCROLL_ROWS) as usize);
        let mut world = vec![0u8; w * rows * 3];
        let mut state = seed | 1;
        for (i, px) in world.chunks_exact_mut(3).enumerate() {
            let (x, y) = (i % w, i / w);
            let checker = ((x / 24 + y / 24) % 2) * 90;
            let gradient = (x * 160 / w + y * 97 / rows) % 160;
            for (c, v) in px.iter_mut().enumerate() {
                // xorshift64: fixed noise in [-20, 20].
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let noise = (state % 41) as i32 - 20;
                let base = (checker + gradient + c * 25) as i32;
                *v = (base + noise).clamp(0, 255) as u8;
            }
        }
        Scroll {
            width,
            height,
            speed,
            world,
        }
    }

    /// Frame `i`'s pixels (rows of `width * 3` bytes).
    pub fn frame(&self, i: usize) -> &[u8] {
        let row = self.width as usize * 3;
        let first = (i as u64 * u64::from(self.speed) % u64::from(SCROLL_ROWS)) as usize;
        &self.world[first * row..(first + self.height as usize) * row]
    }
}

/// A `width` x `height` 8-bit BGR image from `seed`.
#[cfg(feature = "opencv")]
pub fn pattern(width: i32, height: i32, seed: u64) -> Result<Mat> {
    let mut m = Mat::new_rows_cols_with_default(height, width, CV_8UC3, Scalar::all(0.0))
        .cv(|| format!("allocate {width}x{height}"))?;
    let data = m.data_bytes_mut().cv(|| "pattern data".into())?;
    let mut state = seed
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    let (w, h) = (width.max(1), height.max(1));
    for y in 0..height {
        for x in 0..width {
            for c in 0..3 {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                let noise = ((state >> 33) % 41) as i32 - 20;
                let base = (x * 255 / w + c * 40 + y * 97 / h) % 256;
                let inside = x > w / 4 && x < w / 2 && y > h / 3 && y < 2 * h / 3;
                let v = (base + if inside { 120 } else { 0 } + noise).clamp(0, 255);
                data[((y * width + x) * 3 + c) as usize] = v as u8;
            }
        }
    }
    Ok(m)
}
