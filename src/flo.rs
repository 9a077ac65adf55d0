//! Middlebury `.flo` files: "PIEH" magic, width and height (i32 LE), then u, v (f32 LE) per pixel
//! in row order. Written atomically.

use crate::error::{Error, Result};
use crate::fsutil;
use opencv::core::{Mat, Vec2f};
use opencv::prelude::*;
use std::path::Path;

const MAGIC: &[u8; 4] = b"PIEH";

/// Writes a CV_32FC2 flow field to `path`.
pub fn write(path: &Path, flow: &Mat) -> Result<()> {
    let data = flow
        .data_typed::<Vec2f>()
        .map_err(|e| Error::param("flow", e.to_string()))?;
    let mut bytes = Vec::with_capacity(12 + data.len() * 8);
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&flow.cols().to_le_bytes());
    bytes.extend_from_slice(&flow.rows().to_le_bytes());
    for v in data {
        bytes.extend_from_slice(&v[0].to_le_bytes());
        bytes.extend_from_slice(&v[1].to_le_bytes());
    }
    fsutil::write_atomic(path, &bytes)
}

/// Reads a `.flo` file: (width, height, interleaved u, v). Checks the magic (the float
/// 202021.25, "PIEH"), a positive size that matches the data length, and finite values; errors
/// name the file.
pub fn read(path: &Path) -> Result<(u32, u32, Vec<f32>)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let bad = |msg: String| Error::input(path, format!("not a Middlebury .flo file: {msg}"));
    if bytes.len() < 12 || &bytes[..4] != MAGIC {
        return Err(bad(
            "it does not start with the magic number 202021.25 (\"PIEH\")".into(),
        ));
    }
    let w = i32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]);
    let h = i32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
    if w <= 0 || h <= 0 {
        return Err(bad(format!("its header gives the size {w}x{h}")));
    }
    let expected = (w as u64)
        .checked_mul(h as u64)
        .and_then(|n| n.checked_mul(8))
        .and_then(|n| n.checked_add(12));
    if expected != Some(bytes.len() as u64) {
        return Err(bad(format!(
            "its header gives {w}x{h} pixels ({} bytes) but the file has {} bytes",
            expected.map_or_else(|| "too many".to_string(), |n| n.to_string()),
            bytes.len()
        )));
    }
    let v: Vec<f32> = bytes[12..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        let px = i / 2;
        return Err(bad(format!(
            "pixel ({}, {}) has a {} component that is not a finite number ({})",
            px % w as usize,
            px / w as usize,
            if i % 2 == 0 { "u" } else { "v" },
            v[i]
        )));
    }
    Ok((w as u32, h as u32, v))
}

/// Reads a `.flo` file that must be `width` x `height` (an initial flow for two images of that
/// size), as a CV_32FC2 matrix.
pub fn read_sized(path: &Path, width: u32, height: u32) -> Result<Mat> {
    let (w, h, v) = read(path)?;
    if (w, h) != (width, height) {
        return Err(Error::input(
            path,
            format!("the flow is {w}x{h} but the images are {width}x{height}"),
        ));
    }
    let mut m = Mat::new_rows_cols_with_default(
        h as i32,
        w as i32,
        opencv::core::CV_32FC2,
        opencv::core::Scalar::all(0.0),
    )
    .map_err(|e| Error::input(path, e.to_string()))?;
    m.data_typed_mut::<Vec2f>()
        .map_err(|e| Error::input(path, e.to_string()))?
        .iter_mut()
        .zip(v.chunks_exact(2))
        .for_each(|(d, s)| *d = Vec2f::from([s[0], s[1]]));
    Ok(m)
}
