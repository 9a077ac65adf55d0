//! `tenengrad`: sharpness as the mean of Gx² + Gy² of the 3x3 Sobel gradients of the gray image
//! (shaders/tenengrad.wgsl, read from the BGR frame in strips); the OpenCV twin uses cv::Sobel and Mat::dot,
//! and `host` computes the same exact total in one pass over the gray rows (no gradient images).

#[cfg(feature = "opencv")]
use crate::error::{CvContext, Error, Result};
#[cfg(feature = "opencv")]
use opencv::{
    core::{self, Mat},
    imgproc,
    prelude::*,
};

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
#[cfg(feature = "opencv")]
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

/// Pixels per partial sum in [`host`]: each adds at most 2 * 1020^2, so a u32 holds 2048 of them.
#[cfg(feature = "opencv")]
const CHUNK: usize = 2048;

/// The Tenengrad of an 8-bit gray image as [`opencv`] computes it (the same exact integer total
/// of Gx^2 + Gy^2 over 3x3 Sobel gradients with reflect-101 borders, divided by the pixel count),
/// in one pass over the rows without gradient images.
#[cfg(feature = "opencv")]
pub fn host(gray: &Mat) -> Result<f64> {
    if gray.typ() != core::CV_8UC1 {
        return Err(Error::param("tenengrad", "needs an 8-bit gray image"));
    }
    let rows = (0..gray.rows())
        .map(|y| gray.at_row::<u8>(y))
        .collect::<std::result::Result<Vec<&[u8]>, _>>()
        .cv(|| "rows of the gray image".into())?;
    let h = rows.len();
    let mut total = 0u64;
    for y in 0..h {
        let (a, c) = (
            rows[reflect(y as isize - 1, h)],
            rows[reflect(y as isize + 1, h)],
        );
        total += row_total(a, rows[y], c);
    }
    let n = (gray.rows() as f64) * (gray.cols() as f64);
    Ok(total as f64 / n.max(1.0))
}

/// Index `i` in `0..n` with OpenCV's BORDER_REFLECT_101 (n = 1: 0).
#[cfg(feature = "opencv")]
fn reflect(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n <= 1 {
        return 0;
    }
    let i = if i < 0 { -i } else { i };
    (if i >= n { 2 * n - 2 - i } else { i }).clamp(0, n - 1) as usize
}

/// Gx^2 + Gy^2 at column `x` of the row `b` between rows `a` (above) and `c` (below).
#[cfg(feature = "opencv")]
fn at(a: &[u8], b: &[u8], c: &[u8], x: usize) -> u64 {
    let w = b.len();
    let (l, r) = (reflect(x as isize - 1, w), reflect(x as isize + 1, w));
    let p = |row: &[u8], i: usize| i64::from(row[i]);
    let gx = (p(a, r) - p(a, l)) + 2 * (p(b, r) - p(b, l)) + (p(c, r) - p(c, l));
    let gy = (p(c, l) + 2 * p(c, x) + p(c, r)) - (p(a, l) + 2 * p(a, x) + p(a, r));
    (gx * gx + gy * gy) as u64
}

/// The row's total: its two border columns one by one, the inside in u32 chunks.
#[cfg(feature = "opencv")]
fn row_total(a: &[u8], b: &[u8], c: &[u8]) -> u64 {
    let w = b.len();
    if w < 3 {
        return (0..w).map(|x| at(a, b, c, x)).sum();
    }
    let mut total = at(a, b, c, 0) + at(a, b, c, w - 1);
    let inside = w - 2;
    let mut start = 0;
    while start < inside {
        let end = (start + CHUNK).min(inside);
        let (a, b, c) = (&a[start..end + 2], &b[start..end + 2], &c[start..end + 2]);
        let mut sum = 0u32;
        for x in 0..end - start {
            let v = |row: &[u8], k: usize| i32::from(row[x + k]);
            let gx = (v(a, 2) - v(a, 0)) + 2 * (v(b, 2) - v(b, 0)) + (v(c, 2) - v(c, 0));
            let gy = (v(c, 0) + 2 * v(c, 1) + v(c, 2)) - (v(a, 0) + 2 * v(a, 1) + v(a, 2));
            sum += (gx * gx + gy * gy) as u32;
        }
        total += u64::from(sum);
        start = end;
    }
    total
}

#[cfg(all(test, feature = "opencv"))]
mod tests {
    use super::{host, opencv};
    use opencv::core::{Mat, Scalar, CV_8UC1};
    use opencv::prelude::*;

    /// The one-pass total equals cv::Sobel + Mat::dot bit for bit, on noise, on extreme edges
    /// (the largest gradients) and on tiny images (borders on every side).
    #[test]
    fn host_equals_the_opencv_twin() {
        let mut rng = fastrand::Rng::with_seed(35);
        for (w, h) in [
            (1, 1),
            (1, 5),
            (2, 2),
            (3, 3),
            (7, 4),
            (640, 360),
            (4100, 3),
        ] {
            let mut m = Mat::new_rows_cols_with_default(h, w, CV_8UC1, Scalar::all(0.0)).unwrap();
            for (k, b) in m.data_bytes_mut().unwrap().iter_mut().enumerate() {
                *b = match k % 3 {
                    0 => rng.u8(..),
                    _ => (k % 2) as u8 * 255,
                };
            }
            let (a, b) = (host(&m).unwrap(), opencv(&m).unwrap());
            assert_eq!(a.to_bits(), b.to_bits(), "{w}x{h}: {a} vs {b}");
        }
    }
}
