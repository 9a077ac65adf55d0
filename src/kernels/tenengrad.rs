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

/// Pixels per partial sum in [`inside_total_generic`]: each adds at most 2 * 1020^2, so an i32
/// holds 1024 of them (1024 * 2 * 1020^2 = 2 130 739 200 < 2^31).
const CHUNK: usize = 1024;

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
    Ok(host_rows(&rows))
}

/// [`host`] of the gray of an 8-bit BGR frame (gray by [`crate::kernels::gray::host_row`],
/// bit-identical to cv::cvtColor), converting rows into a ring of three as the pass reaches
/// them: one read of the BGR bytes and no gray image. A frame that is not continuous 8-bit BGR
/// is converted whole first.
#[cfg(feature = "opencv")]
pub fn host_bgr(bgr: &Mat) -> Result<f64> {
    use crate::kernels::gray;
    let Some(bytes) = gray::bgr_bytes(bgr)? else {
        return host(&gray::host(bgr)?);
    };
    let (w, h) = (bgr.cols().max(0) as usize, bgr.rows().max(0) as usize);
    // Gray row r lives at r % 3; rows are converted in order, up to the one below row y.
    let mut ring = vec![0u8; 3 * w];
    let mut converted = 0;
    let mut total = 0u64;
    for y in 0..h {
        let (above, below) = (reflect(y as isize - 1, h), reflect(y as isize + 1, h));
        while converted <= below.max(y) {
            let src = &bytes[3 * w * converted..3 * w * (converted + 1)];
            gray::host_row(src, &mut ring[w * (converted % 3)..w * (converted % 3 + 1)]);
            converted += 1;
        }
        let row = |r: usize| &ring[w * (r % 3)..w * (r % 3 + 1)];
        total += row_total(row(above), row(y), row(below));
    }
    Ok(total as f64 / ((h * w) as f64).max(1.0))
}

/// [`host`] on the rows of a gray image (all of one width; none: 0): needs no OpenCV.
pub fn host_rows(rows: &[&[u8]]) -> f64 {
    let h = rows.len();
    let mut total = 0u64;
    for y in 0..h {
        let (a, c) = (
            rows[reflect(y as isize - 1, h)],
            rows[reflect(y as isize + 1, h)],
        );
        total += row_total(a, rows[y], c);
    }
    let n = (h as f64) * (rows.first().map_or(0, |r| r.len()) as f64);
    total as f64 / n.max(1.0)
}

/// Index `i` in `0..n` with OpenCV's BORDER_REFLECT_101 (n = 1: 0).
fn reflect(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n <= 1 {
        return 0;
    }
    let i = if i < 0 { -i } else { i };
    (if i >= n { 2 * n - 2 - i } else { i }).clamp(0, n - 1) as usize
}

/// Gx^2 + Gy^2 at column `x` of the row `b` between rows `a` (above) and `c` (below).
fn at(a: &[u8], b: &[u8], c: &[u8], x: usize) -> u64 {
    let w = b.len();
    let (l, r) = (reflect(x as isize - 1, w), reflect(x as isize + 1, w));
    let p = |row: &[u8], i: usize| i64::from(row[i]);
    let gx = (p(a, r) - p(a, l)) + 2 * (p(b, r) - p(b, l)) + (p(c, r) - p(c, l));
    let gy = (p(c, l) + 2 * p(c, x) + p(c, r)) - (p(a, l) + 2 * p(a, x) + p(a, r));
    (gx * gx + gy * gy) as u64
}

/// The row's total: its two border columns one by one, the inside by [`inside_total`].
fn row_total(a: &[u8], b: &[u8], c: &[u8]) -> u64 {
    let w = b.len();
    if w < 3 {
        return (0..w).map(|x| at(a, b, c, x)).sum();
    }
    at(a, b, c, 0) + at(a, b, c, w - 1) + inside_total(a, b, c)
}

/// [`inside_total_generic`]'s total, sixteen pixels at a time with AVX2 when the CPU has it
/// (exact integers either way, so the same total: `row_total_paths_agree` checks it).
fn inside_total(a: &[u8], b: &[u8], c: &[u8]) -> u64 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above), the only requirement of
        // `avx2::inside`'s `target_feature`; it reads inside the three slices only.
        let (total, done) = unsafe { avx2::inside(a, b, c) };
        // Pixels 1 + done ..= w-2 remain: the generic loop over columns done .. w.
        return total + inside_total_generic(&a[done..], &b[done..], &c[done..]);
    }
    inside_total_generic(a, b, c)
}

/// Gx^2 + Gy^2 sixteen pixels at a time: each row's three shifted 16-byte loads widened to i16,
/// the gradients in i16 (|G| <= 1020), their squares summed in pairs by `madd` into i32 lanes
/// (at most 4 * 1020^2 per lane and step), emptied into a u64 before they could overflow.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    /// Steps between emptying the i32 lanes: 512 * 4 * 1020^2 < 2^31.
    const FLUSH: usize = 512;

    /// The total over pixels 1 ..= n of row `b` (between `a` above and `c` below) and n, a
    /// multiple of 16 with n + 2 <= the rows' width: the caller adds pixels n + 1 ..= w-2.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn inside(a: &[u8], b: &[u8], c: &[u8]) -> (u64, usize) {
        let w = a.len().min(b.len()).min(c.len());
        let steps = w.saturating_sub(2) / 16;
        let load = |row: &[u8], x: usize| {
            _mm256_cvtepu8_epi16(_mm_loadu_si128(row[x..x + 16].as_ptr().cast()))
        };
        let mut total = 0u64;
        let mut acc = _mm256_setzero_si256();
        for k in 0..steps {
            // Outputs x0 ..= x0 + 15 read columns x0 - 1 ..= x0 + 16.
            let x = 16 * k;
            let (al, am, ar) = (load(a, x), load(a, x + 1), load(a, x + 2));
            let (bl, br) = (load(b, x), load(b, x + 2));
            let (cl, cm, cr) = (load(c, x), load(c, x + 1), load(c, x + 2));
            let gx = _mm256_add_epi16(
                _mm256_add_epi16(_mm256_sub_epi16(ar, al), _mm256_sub_epi16(cr, cl)),
                _mm256_slli_epi16::<1>(_mm256_sub_epi16(br, bl)),
            );
            let (dl, dm, dr) = (
                _mm256_sub_epi16(cl, al),
                _mm256_sub_epi16(cm, am),
                _mm256_sub_epi16(cr, ar),
            );
            let gy = _mm256_add_epi16(_mm256_add_epi16(dl, dr), _mm256_slli_epi16::<1>(dm));
            let sq = _mm256_add_epi32(_mm256_madd_epi16(gx, gx), _mm256_madd_epi16(gy, gy));
            acc = _mm256_add_epi32(acc, sq);
            if (k + 1) % FLUSH == 0 || k + 1 == steps {
                let mut lanes = [0u32; 8];
                _mm256_storeu_si256(lanes.as_mut_ptr().cast(), acc);
                total += lanes.iter().map(|&l| u64::from(l)).sum::<u64>();
                acc = _mm256_setzero_si256();
            }
        }
        (total, 16 * steps)
    }
}

/// The total over the pixels 1 ..= w−2 of row `b` (the three rows equally long, ≥ 3). Per chunk,
/// the vertical parts first: `s = a + 2b + c` (Gx = s[x+1] − s[x−1]) and `d = c − a`
/// (Gy = d[x−1] + 2d[x] + d[x+1]), in i16 (|s|, |Gx|, |Gy| ≤ 1020), then the squares in i32:
/// straight loops the compiler vectorises.
#[inline(always)]
fn inside_total_generic(a: &[u8], b: &[u8], c: &[u8]) -> u64 {
    let inside = b.len() - 2;
    let mut s = [0i16; CHUNK + 2];
    let mut d = [0i16; CHUNK + 2];
    let mut total = 0u64;
    let mut start = 0;
    while start < inside {
        let end = (start + CHUNK).min(inside);
        let n = end - start;
        let (a, b, c) = (&a[start..end + 2], &b[start..end + 2], &c[start..end + 2]);
        for k in 0..n + 2 {
            let (p, q, r) = (i16::from(a[k]), i16::from(b[k]), i16::from(c[k]));
            s[k] = p + 2 * q + r;
            d[k] = r - p;
        }
        let mut sum = 0i32;
        for x in 0..n {
            let gx = i32::from(s[x + 2] - s[x]);
            let gy = i32::from(d[x] + 2 * d[x + 1] + d[x + 2]);
            sum += gx * gx + gy * gy;
        }
        total += u64::from(sum.unsigned_abs());
        start = end;
    }
    total
}

#[cfg(all(test, feature = "opencv"))]
mod tests {
    use super::{host, inside_total, inside_total_generic, opencv};
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
            (1026, 3),
            (1027, 4),
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

    /// The fused pass over a BGR frame equals the Tenengrad of cv::cvtColor's gray (and OpenCV's
    /// twin), on noise and hard edges, at sizes that exercise the row ring and the borders.
    #[test]
    fn host_bgr_equals_the_gray_path() {
        use opencv::core::CV_8UC3;
        let mut rng = fastrand::Rng::with_seed(38);
        for (w, h) in [
            (1, 1),
            (1, 4),
            (2, 1),
            (3, 2),
            (5, 3),
            (17, 9),
            (40, 41),
            (1920, 12),
        ] {
            let mut m = Mat::new_rows_cols_with_default(h, w, CV_8UC3, Scalar::all(0.0)).unwrap();
            for (k, b) in m.data_bytes_mut().unwrap().iter_mut().enumerate() {
                *b = match k % 5 {
                    0 | 1 => rng.u8(..),
                    _ => ((k / 7) % 2) as u8 * 255,
                };
            }
            let gray = crate::kernels::gray::opencv(&m).unwrap();
            let (fused, twin) = (super::host_bgr(&m).unwrap(), opencv(&gray).unwrap());
            assert_eq!(fused.to_bits(), host(&gray).unwrap().to_bits(), "{w}x{h}");
            assert_eq!(
                fused.to_bits(),
                twin.to_bits(),
                "{w}x{h}: {fused} vs {twin}"
            );
        }
    }

    /// The row totals of the dispatching path (AVX2 where the CPU has it) equal the generic
    /// code's, on rows of every value and at the chunk boundaries.
    #[test]
    fn row_total_paths_agree() {
        let mut rng = fastrand::Rng::with_seed(36);
        for w in [3, 4, 1025, 1026, 1027, 2050, 4099] {
            for fill in 0..3 {
                // Noise; then the largest gradients: a dark row above a bright one below, with
                // a step every few columns in the middle row.
                let mut row = |k: usize| -> Vec<u8> {
                    (0..w)
                        .map(|x| match (fill, k) {
                            (0, _) => rng.u8(..),
                            (_, 0) => 0,
                            (_, 2) => 255,
                            _ => ((x / (fill + 1)) % 2) as u8 * 255,
                        })
                        .collect()
                };
                let (a, b, c) = (row(0), row(1), row(2));
                assert_eq!(
                    inside_total(&a, &b, &c),
                    inside_total_generic(&a, &b, &c),
                    "width {w}, fill {fill}"
                );
            }
        }
    }
}
