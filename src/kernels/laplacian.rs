//! `laplacian`: sharpness as the variance of the Laplacian of the gray image, OpenCV ksize 1 or 3
//! (shaders/laplacian.wgsl); the OpenCV twin uses cv::Laplacian and cv::meanStdDev.

#[cfg(feature = "opencv")]
use crate::error::{CvContext, Result};
#[cfg(feature = "opencv")]
use opencv::{
    core::{self, Mat, Vector},
    imgproc,
};

/// WGSL source, after its preludes (shaders/border.wgsl, shaders/strip.wgsl, whose `StripParams` it takes).
pub const WGSL: &str = concat!(
    include_str!("../../shaders/border.wgsl"),
    include_str!("../../shaders/strip.wgsl"),
    include_str!("../../shaders/laplacian.wgsl")
);

/// The offset the shader adds to each Laplacian value to keep sums unsigned.
pub fn offset(ksize: u32) -> i64 {
    if ksize == 1 {
        1020
    } else {
        2040
    }
}

/// Variance from the exact totals of (L + offset) and L² over `n` pixels.
pub fn from_totals(sum_off: u64, sum_sq: u64, n: u64, ksize: u32) -> f64 {
    let sum = sum_off as i128 - i128::from(offset(ksize)) * i128::from(n);
    let n = n as f64;
    let mean = sum as f64 / n;
    (sum_sq as f64 / n - mean * mean).max(0.0)
}

/// OpenCV twin: variance of the Laplacian (CV_64F) of an 8-bit gray image.
#[cfg(feature = "opencv")]
pub fn opencv(gray: &Mat, ksize: u32) -> Result<f64> {
    let mut lap = Mat::default();
    let (depth, border) = (core::CV_64F, core::BORDER_DEFAULT);
    imgproc::laplacian(gray, &mut lap, depth, ksize as i32, 1.0, 0.0, border)
        .cv(|| format!("Laplacian ksize {ksize}"))?;
    let mut mean = Vector::<f64>::new();
    let mut std = Vector::<f64>::new();
    core::mean_std_dev(&lap, &mut mean, &mut std, &core::no_array()).cv(|| "meanStdDev".into())?;
    let s = std.get(0).cv(|| "meanStdDev result".into())?;
    Ok(s * s)
}
