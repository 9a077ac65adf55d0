//! `tenengrad`: sharpness as the mean of Gx² + Gy² of the 3x3 Sobel gradients of the gray image
//! (shaders/tenengrad.wgsl); the OpenCV twin uses cv::Sobel and cv::mean.

use crate::error::{CvContext, Result};
use bytemuck::{Pod, Zeroable};
use opencv::core::{self, Mat};
use opencv::imgproc;

/// WGSL source.
pub const WGSL: &str = include_str!("../../shaders/tenengrad.wgsl");

/// Uniform parameters of tenengrad.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct TenengradParams {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// u32 words per row of the packed gray input.
    pub stride: u32,
    /// Unused.
    pub pad: u32,
}

/// Score from the exact total of Gx² + Gy² over `n` pixels.
pub fn from_totals(sum_sq: u64, n: u64) -> f64 {
    sum_sq as f64 / n as f64
}

/// OpenCV twin: Tenengrad of an 8-bit gray image.
pub fn opencv(gray: &Mat) -> Result<f64> {
    let mut gx = Mat::default();
    let mut gy = Mat::default();
    let border = core::BORDER_DEFAULT;
    imgproc::sobel(gray, &mut gx, core::CV_32F, 1, 0, 3, 1.0, 0.0, border)
        .cv(|| "Sobel dx".into())?;
    imgproc::sobel(gray, &mut gy, core::CV_32F, 0, 1, 3, 1.0, 0.0, border)
        .cv(|| "Sobel dy".into())?;
    let mut gx2 = Mat::default();
    let mut gy2 = Mat::default();
    core::multiply(&gx, &gx, &mut gx2, 1.0, -1).cv(|| "multiply".into())?;
    core::multiply(&gy, &gy, &mut gy2, 1.0, -1).cv(|| "multiply".into())?;
    let mut sum = Mat::default();
    core::add(&gx2, &gy2, &mut sum, &core::no_array(), -1).cv(|| "add".into())?;
    let m = core::mean(&sum, &core::no_array()).cv(|| "mean".into())?;
    Ok(m[0])
}
