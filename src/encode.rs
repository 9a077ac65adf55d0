//! Images to file bytes in the formats keyframer writes (JPEG with a quality, lossless PNG):
//! the one encoder export and segment share, and the one cv::resize call they share (small
//! JPEGs of frames for the report and the review page: `source::shrink`, below this layer).

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

#[cfg(test)]
mod tests {
    use super::*;

    /// `source::shrink` (the report's thumbnails, the review's frames) makes the bytes this
    /// module's resize and JPEG encoder made for the report before it moved below this layer.
    #[test]
    fn shrink_equals_resize_then_encode() {
        let mut bgr =
            Mat::new_rows_cols_with_default(217, 331, opencv::core::CV_8UC3, 0.into()).unwrap();
        let (lo, hi) = (
            opencv::core::Scalar::all(0.0),
            opencv::core::Scalar::all(255.0),
        );
        opencv::core::randu(&mut bgr, &lo, &hi).unwrap();
        assert!(opencv::core::mean(&bgr, &Mat::default()).unwrap().0[..3]
            .iter()
            .all(|m| *m > 100.0));
        for width in [160, 960] {
            let tw = width.min(331);
            let th = (217.0 * f64::from(tw) / 331.0).round() as i32;
            let small = resize(&bgr, (tw, th), imgproc::INTER_AREA).unwrap();
            let want = encode(&small, Format::Jpg, 80).unwrap();
            let got = crate::source::shrink(&bgr, width, &String::new).unwrap();
            assert_eq!(got, want, "width {width}");
        }
    }
}
