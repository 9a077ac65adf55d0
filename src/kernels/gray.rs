//! `gray`: 8-bit BGR to gray, bit-identical to cv::cvtColor(COLOR_BGR2GRAY). On the device it is
//! part of the sharpness pass (shaders/strip.wgsl `gray_strip_row`); `opencv` is the OpenCV
//! twin, and `host` / `host_row` the same integer formula on the CPU (one thread, AVX2 where the
//! CPU has it: no thread pool between a decoder and the analysis on a small machine).

use crate::error::{CvContext, Result};
use opencv::core::Mat;
use opencv::imgproc;
use opencv::prelude::*;

/// OpenCV twin: gray image of a BGR frame (a gray frame is returned as is).
pub fn opencv(bgr: &Mat) -> Result<Mat> {
    if bgr.channels() == 1 {
        return Ok(bgr.clone());
    }
    let mut gray = Mat::default();
    imgproc::cvt_color(bgr, &mut gray, imgproc::COLOR_BGR2GRAY, 0)
        .cv(|| "cvtColor BGR2GRAY".into())?;
    Ok(gray)
}

/// [`opencv`]'s result computed by [`host_row`] row by row (a gray frame is returned as is; a
/// frame that is not continuous 8-bit BGR goes to [`opencv`]).
pub fn host(bgr: &Mat) -> Result<Mat> {
    if bgr.channels() == 1 {
        return Ok(bgr.clone());
    }
    let Some(rows) = bgr_bytes(bgr)? else {
        return opencv(bgr);
    };
    let (w, h) = (bgr.cols(), bgr.rows());
    // SAFETY: every byte of the new Mat is written below before it is read.
    let mut gray = unsafe { Mat::new_rows_cols(h, w, opencv::core::CV_8UC1) }
        .cv(|| "allocate the gray frame".into())?;
    let out = gray.data_bytes_mut().cv(|| "gray frame bytes".into())?;
    let width = w.max(0) as usize;
    for (src, dst) in rows
        .chunks_exact(3 * width)
        .zip(out.chunks_exact_mut(width))
    {
        host_row(src, dst);
    }
    Ok(gray)
}

/// The bytes of a continuous, non-empty 8-bit BGR frame (rows of 3 x width bytes, no padding);
/// None for any other frame.
pub fn bgr_bytes(bgr: &Mat) -> Result<Option<&[u8]>> {
    if bgr.typ() != opencv::core::CV_8UC3 || !bgr.is_continuous() || bgr.empty() {
        return Ok(None);
    }
    bgr.data_bytes().cv(|| "frame bytes".into()).map(Some)
}

/// OpenCV's 15-bit fixed-point weights of B, G and R; the sum is rounded (+2^14) and shifted.
const WEIGHTS: [u32; 3] = [3735, 19235, 9798];

/// One row: `out[x]` = the gray of the BGR pixel `bgr[3x..3x+3]`, by OpenCV's 15-bit fixed-point
/// weights and rounding (B 3735, G 19235, R 9798; +2^14, >> 15).
pub fn host_row(bgr: &[u8], out: &mut [u8]) {
    let n = out.len().min(bgr.len() / 3);
    let (bgr, out) = (&bgr[..3 * n], &mut out[..n]);
    #[cfg(target_arch = "x86_64")]
    let done = if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above), the only requirement of
        // `avx2::row`'s `target_feature`; it reads and writes inside the two slices only.
        unsafe { avx2::row(bgr, out) }
    } else {
        0
    };
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    host_row_generic(&bgr[3 * done..], &mut out[done..])
}

fn host_row_generic(bgr: &[u8], out: &mut [u8]) {
    let [wb, wg, wr] = WEIGHTS;
    for (g, p) in out.iter_mut().zip(bgr.chunks_exact(3)) {
        let (b, gr, r) = (u32::from(p[0]), u32::from(p[1]), u32::from(p[2]));
        *g = ((wb * b + wg * gr + wr * r + (1 << 14)) >> 15) as u8;
    }
}

/// Sixteen pixels at a time: the 48 bytes split into B, G and R by byte shuffles, widened to
/// 16 bits, (B, G) and (R, 1) pairs multiplied and added in 32 bits against (3735, 19235) and
/// (9798, 2^14) (the same exact integers as the scalar formula), shifted and packed back.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    /// Byte shuffles picking one channel out of the three 16-byte thirds of 16 pixels
    /// (-1: zero), one row per channel (B, G, R) and third.
    const PICK: [[[i8; 16]; 3]; 3] = {
        let mut m = [[[-1i8; 16]; 3]; 3];
        let mut c = 0;
        while c < 3 {
            let mut p = 0;
            while p < 16 {
                let byte = 3 * p + c;
                m[c][byte / 16][p] = (byte % 16) as i8;
                p += 1;
            }
            c += 1;
        }
        m
    };

    /// Converts the row's first pixels, sixteen at a time, and returns how many it did (a
    /// multiple of 16; the rest is the caller's). `bgr` holds 3 bytes per pixel of `out`.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn row(bgr: &[u8], out: &mut [u8]) -> usize {
        let [wb, wg, wr] = super::WEIGHTS.map(|w| w as i32);
        let bg_weights = _mm256_set1_epi32(wb | (wg << 16));
        let r_weights = _mm256_set1_epi32(wr | (1 << 14 << 16));
        let ones = _mm256_set1_epi16(1);
        let pick = PICK.map(|c| c.map(|t| _mm_loadu_si128(t.as_ptr().cast())));
        let n = out.len() / 16 * 16;
        for (src, dst) in bgr.chunks_exact(48).zip(out.chunks_exact_mut(16)) {
            let thirds = [0, 16, 32].map(|o| _mm_loadu_si128(src[o..o + 16].as_ptr().cast()));
            let [b, g, r] = pick.map(|p| {
                let picked = _mm_or_si128(
                    _mm_shuffle_epi8(thirds[0], p[0]),
                    _mm_or_si128(
                        _mm_shuffle_epi8(thirds[1], p[1]),
                        _mm_shuffle_epi8(thirds[2], p[2]),
                    ),
                );
                _mm256_cvtepu8_epi16(picked)
            });
            // unpack lo/hi work within each 128-bit lane: pixels 0-3 and 8-11, then 4-7 and
            // 12-15; the 32-to-16 pack below undoes it (pixels 0-7 | 8-15).
            let sum = |bg: __m256i, r1: __m256i| {
                let s = _mm256_add_epi32(
                    _mm256_madd_epi16(bg, bg_weights),
                    _mm256_madd_epi16(r1, r_weights),
                );
                _mm256_srli_epi32::<15>(s)
            };
            let lo = sum(_mm256_unpacklo_epi16(b, g), _mm256_unpacklo_epi16(r, ones));
            let hi = sum(_mm256_unpackhi_epi16(b, g), _mm256_unpackhi_epi16(r, ones));
            let words = _mm256_packus_epi32(lo, hi);
            let bytes = _mm_packus_epi16(
                _mm256_castsi256_si128(words),
                _mm256_extracti128_si256::<1>(words),
            );
            _mm_storeu_si128(dst.as_mut_ptr().cast(), bytes);
        }
        n
    }
}

#[cfg(test)]
mod tests {
    use super::{host, host_row_generic, opencv};
    use opencv::core::{Mat, Scalar, CV_8UC3};
    use opencv::prelude::*;

    /// The host gray equals cv::cvtColor on every (B, G, R) value pattern: noise, and all 2^24
    /// colours laid out as one 4096x4096 image, plus odd widths (the vector loop's tail).
    #[test]
    fn host_equals_the_opencv_twin() {
        let mut rng = fastrand::Rng::with_seed(37);
        let all = 4096;
        for (w, h) in [(1, 1), (7, 3), (33, 5), (1919, 4), (all, all)] {
            let mut m = Mat::new_rows_cols_with_default(h, w, CV_8UC3, Scalar::all(0.0)).unwrap();
            let bytes = m.data_bytes_mut().unwrap();
            for (k, px) in bytes.chunks_exact_mut(3).enumerate() {
                if w == all {
                    px.copy_from_slice(&(k as u32).to_le_bytes()[..3]);
                } else {
                    px.iter_mut().for_each(|b| *b = rng.u8(..));
                }
            }
            let (a, b) = (host(&m).unwrap(), opencv(&m).unwrap());
            assert_eq!(a.data_bytes().unwrap(), b.data_bytes().unwrap(), "{w}x{h}");
            // And the generic path alone.
            let mut row = vec![0u8; w as usize];
            host_row_generic(&m.data_bytes().unwrap()[..3 * w as usize], &mut row);
            assert_eq!(row, b.at_row::<u8>(0).unwrap(), "{w}x{h} generic");
        }
    }
}
