//! `tenengrad`: sharpness as the mean of Gx² + Gy² of the 3x3 Sobel gradients of the gray image
//! (shaders/tenengrad.wgsl, read from the BGR frame in strips); the OpenCV twin uses cv::Sobel and Mat::dot.

use crate::error::{CvContext, Result};
use opencv::core::{self, Mat};
use opencv::imgproc;
use opencv::prelude::MatTraitConst;

/// WGSL source, after its preludes (shaders/border.wgsl, shaders/strip.wgsl, whose `StripParams` it takes).
pub const WGSL: &str = concat!(
    include_str!("../../shaders/border.wgsl"),
    include_str!("../../shaders/strip.wgsl"),
    include_str!("../../shaders/tenengrad.wgsl")
);

/// Score from the exact total of Gx² + Gy² over `n` pixels.
pub fn from_totals(sum_sq: u64, n: u64) -> f64 {
    sum_sq as f64 / n as f64
}

/// OpenCV twin: Tenengrad of an 8-bit gray image. Sobel into 16-bit integers (|G| ≤ 1020, so
/// exact) and the squares summed by `Mat::dot` in double precision (sums below 2^53, so exact):
/// the same exact total the gpu computes, in two passes fewer than multiply + add + mean.
pub fn opencv(gray: &Mat) -> Result<f64> {
    let mut gx = Mat::default();
    let mut gy = Mat::default();
    let border = core::BORDER_DEFAULT;
    imgproc::sobel(gray, &mut gx, core::CV_16S, 1, 0, 3, 1.0, 0.0, border)
        .cv(|| "Sobel dx".into())?;
    imgproc::sobel(gray, &mut gy, core::CV_16S, 0, 1, 3, 1.0, 0.0, border)
        .cv(|| "Sobel dy".into())?;
    let sx = gx.dot(&gx).cv(|| "dot dx".into())?;
    let sy = gy.dot(&gy).cv(|| "dot dy".into())?;
    let n = (gray.rows() as f64) * (gray.cols() as f64);
    Ok((sx + sy) / n.max(1.0))
}
