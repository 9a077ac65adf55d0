//! Images to file bytes in the formats keyframer writes (JPEG with a quality, lossless PNG):
//! the one encoder export, segment and the report share, and the one cv::resize call they share.

use crate::error::{CvContext, Result};
use crate::manifest::Format;
use opencv::core::{Mat, Size, Vector};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};

/// Encodes an image as JPEG (with `quality`) or PNG.
pub fn encode(image: &Mat, format: Format, quality: u8) -> Result<Vec<u8>> {
    let mut params = Vector::<i32>::new();
    if format == Format::Jpg {
        params.push(imgcodecs::IMWRITE_JPEG_QUALITY);
        params.push(i32::from(quality));
    }
    let mut buf = Vector::<u8>::new();
    imgcodecs::imencode(&format!(".{}", format.ext()), image, &mut buf, &params)
        .cv(|| format!("encode {}", format.ext()))?;
    Ok(buf.to_vec())
}

/// `image` resized to `size` (width, height) with cv::resize and `interpolation`.
pub fn resize(image: &Mat, size: (i32, i32), interpolation: i32) -> opencv::Result<Mat> {
    let mut out = Mat::default();
    let size = Size::new(size.0, size.1);
    imgproc::resize(image, &mut out, size, 0.0, 0.0, interpolation)?;
    Ok(out)
}
