//! Deterministic synthetic test images (gradients, a hard-edged rectangle, noise) for kernel
//! checks, reference fixtures and benchmarks. The same seed always gives the same pixels.

use crate::error::{CvContext, Result};
use opencv::core::{Mat, Scalar, CV_8UC3};
use opencv::prelude::*;

/// A `width` x `height` 8-bit BGR image from `seed`.
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
