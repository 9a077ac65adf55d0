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

/// Reads a `.flo` file: (width, height, interleaved u, v).
pub fn read(path: &Path) -> Result<(u32, u32, Vec<f32>)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let bad = |msg: &str| Error::input(path, format!("not a Middlebury .flo file: {msg}"));
    if bytes.len() < 12 || &bytes[..4] != MAGIC {
        return Err(bad("missing PIEH magic"));
    }
    let w = i32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]);
    let h = i32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
    if w <= 0 || h <= 0 {
        return Err(bad("bad size"));
    }
    let n = w as usize * h as usize * 2;
    if bytes.len() != 12 + n * 4 {
        return Err(bad("size does not match the data length"));
    }
    let v = bytes[12..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok((w as u32, h as u32, v))
}

/// Reads a `.flo` file as a CV_32FC2 matrix.
pub fn read_mat(path: &Path) -> Result<Mat> {
    let (w, h, v) = read(path)?;
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
