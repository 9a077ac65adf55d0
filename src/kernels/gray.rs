//! `gray`: 8-bit BGR to gray, bit-identical to cv::cvtColor(COLOR_BGR2GRAY). On the device it is
//! part of the sharpness pass (shaders/strip.wgsl `gray_strip_row`); this is the OpenCV twin.

use crate::error::{CvContext, Result};
use opencv::core::Mat;
use opencv::imgproc;

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
