//! Images to file bytes in the formats keyframer writes (JPEG with a quality, lossless PNG):
//! the one encoder export, segment and the report share.

use crate::error::{CvContext, Result};
use opencv::core::{Mat, Vector};
use opencv::imgcodecs;
use opencv::prelude::*;
use serde::{Deserialize, Serialize};

/// Image file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// JPEG with a quality setting.
    Jpg,
    /// Lossless PNG.
    Png,
}

impl Format {
    /// File extension.
    pub fn ext(self) -> &'static str {
        match self {
            Format::Jpg => "jpg",
            Format::Png => "png",
        }
    }
}

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
