//! `gray`: 8-bit BGR to gray, bit-identical to cv::cvtColor(COLOR_BGR2GRAY) (shaders/gray.wgsl).

use crate::error::{CvContext, Result};
use bytemuck::{Pod, Zeroable};
use opencv::core::Mat;
use opencv::imgproc;

/// WGSL source.
pub const WGSL: &str = include_str!("../../shaders/gray.wgsl");

/// Uniform parameters of gray.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct GrayParams {
    pub width: u32,
    pub height: u32,
    /// u32 words per row of the packed gray output.
    pub stride: u32,
    pub pad: u32,
}

/// OpenCV twin: gray image of a BGR frame (a gray frame is returned as is).
pub fn opencv(bgr: &Mat) -> Result<Mat> {
    use opencv::prelude::*;
    if bgr.channels() == 1 {
        return Ok(bgr.clone());
    }
    let mut gray = Mat::default();
    imgproc::cvt_color(bgr, &mut gray, imgproc::COLOR_BGR2GRAY, 0)
        .cv(|| "cvtColor BGR2GRAY".into())?;
    Ok(gray)
}
