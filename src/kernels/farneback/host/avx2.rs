//! FarnebackUpdateMatrices eight pixels at a time with AVX2, for `farneback::host`. Each lane
//! does the scalar loop's f32 operations in the scalar loop's order (separate multiplies and
//! adds, never fused), so the bits equal the scalar ones: `host::tests::paths_agree` checks.

use std::arch::x86_64::*;

/// What one row's matrices read.
pub(super) struct MatricesRow<'a> {
    /// The first frame's expansion, this row only (5 values per pixel).
    pub r0: &'a [f32],
    /// The second frame's whole expansion at this level.
    pub r1: &'a [f32],
    /// This row's flow (dx, dy per pixel).
    pub flow: &'a [f32],
    /// Each column's border weight product.
    pub column_weights: &'a [f32],
    /// The row's index and its border weights (low, high).
    pub y: usize,
    pub row_weights: (f32, f32),
    /// The level's width and height.
    pub size: (usize, usize),
}

/// Writes the matrices of the row's first pixels, eight at a time, to `out` (the row's 5 values
/// per pixel) and returns how many pixels it did (a multiple of 8; the rest is the caller's).
///
/// # Safety
/// The CPU must have AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn update_matrices_row(row: &MatricesRow, out: &mut [f32]) -> usize {
    let (width, height) = row.size;
    let step = width * 5;
    // Index arithmetic is in i32 lanes, and lanes outside read the first two rows: other
    // levels are left to the scalar loop.
    if height < 2
        || row.r1.len() != step * height
        || row.r0.len() != step
        || out.len() != step
        || row.flow.len() != width * 2
        || row.column_weights.len() != width
        || row.r1.len() + step >= i32::MAX as usize
    {
        return 0;
    }
    let zero = _mm256_setzero_ps();
    let one = _mm256_set1_ps(1.0);
    let half = _mm256_set1_ps(0.5);
    let quarter = _mm256_set1_ps(0.25);
    let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let last_x = _mm256_set1_epi32(width as i32 - 1);
    let last_y = _mm256_set1_epi32(height as i32 - 1);
    let minus_one = _mm256_set1_epi32(-1);
    let step_v = _mm256_set1_epi32(step as i32);
    let five = _mm256_set1_epi32(5);
    let y = _mm256_set1_ps(row.y as f32);
    let (yl, yh) = (
        _mm256_set1_ps(row.row_weights.0),
        _mm256_set1_ps(row.row_weights.1),
    );
    let first5 = _mm256_setr_epi32(-1, -1, -1, -1, -1, 0, 0, 0);
    let r1 = row.r1.as_ptr();
    let mut weights = [0f32; 32];
    let mut offsets = [0i32; 8];
    let mut soa = [0f32; 8];
    let mut x = 0;
    while x + 8 <= width {
        // SAFETY: x + 8 <= width: 16 flow values from 2x.
        let (lo, hi) = unsafe {
            let f = row.flow.as_ptr().add(x * 2);
            (_mm256_loadu_ps(f), _mm256_loadu_ps(f.add(8)))
        };
        // (dx, dy) pairs to eight dx and eight dy.
        let dx = _mm256_shuffle_ps::<0b10_00_10_00>(lo, hi);
        let dy = _mm256_shuffle_ps::<0b11_01_11_01>(lo, hi);
        let dx = _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(dx)));
        let dy = _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(dy)));
        let xs = _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(x as i32), lanes));
        let fx = _mm256_add_ps(xs, dx);
        let fy = _mm256_add_ps(y, dy);
        let (floor_x, floor_y) = (_mm256_floor_ps(fx), _mm256_floor_ps(fy));
        // Out of i32 (or not a number): i32::MIN, out of the image, as the scalar floor.
        let (x1, y1) = (_mm256_cvttps_epi32(floor_x), _mm256_cvttps_epi32(floor_y));
        let inside = _mm256_and_si256(
            _mm256_and_si256(
                _mm256_cmpgt_epi32(last_x, x1),
                _mm256_cmpgt_epi32(x1, minus_one),
            ),
            _mm256_and_si256(
                _mm256_cmpgt_epi32(last_y, y1),
                _mm256_cmpgt_epi32(y1, minus_one),
            ),
        );
        let inside_ps = _mm256_castsi256_ps(inside);
        let fx = _mm256_sub_ps(fx, floor_x);
        let fy = _mm256_sub_ps(fy, floor_y);
        let (gx, gy) = (_mm256_sub_ps(one, fx), _mm256_sub_ps(one, fy));
        let at = _mm256_add_epi32(_mm256_mullo_epi32(y1, step_v), _mm256_mullo_epi32(x1, five));
        // Lanes outside read pixel (0, 0) (in r1: height >= 2), then are blended away.
        let at = _mm256_and_si256(at, inside);
        // SAFETY: the arrays hold 32 f32 and 8 i32.
        unsafe {
            let w = weights.as_mut_ptr();
            _mm256_storeu_ps(w, _mm256_mul_ps(gx, gy));
            _mm256_storeu_ps(w.add(8), _mm256_mul_ps(fx, gy));
            _mm256_storeu_ps(w.add(16), _mm256_mul_ps(gx, fy));
            _mm256_storeu_ps(w.add(24), _mm256_mul_ps(fx, fy));
            _mm256_storeu_si256(offsets.as_mut_ptr().cast(), at);
        }
        // Per pixel, its 5 values in lanes 0..5: the bilinear mix of r1 and r0's own.
        let mut mixed = [zero; 8];
        let mut own = [zero; 8];
        for i in 0..8 {
            let w = |k: usize| _mm256_set1_ps(weights[k * 8 + i]);
            // SAFETY: an inside lane has x1 <= width - 2 and y1 <= height - 2, so the 8 values
            // from its pixel and from the one below are in r1 (the highest: pixel (x1 + 1,
            // y1 + 1)'s fifth, len - 1), and the two loads of the pixel to the right are masked
            // to its 5 values; any other lane reads from 0 (2 rows >= 20 values). r0 holds the
            // row, pixels x..x + 8 of it, masked to 5 values each.
            let (p, p5, q, q5, r) = unsafe {
                let base = r1.add(offsets[i] as usize);
                (
                    _mm256_loadu_ps(base),
                    _mm256_maskload_ps(base.add(5), first5),
                    _mm256_loadu_ps(base.add(step)),
                    _mm256_maskload_ps(base.add(step + 5), first5),
                    _mm256_maskload_ps(row.r0.as_ptr().add((x + i) * 5), first5),
                )
            };
            let s = _mm256_add_ps(_mm256_mul_ps(w(0), p), _mm256_mul_ps(w(1), p5));
            let s = _mm256_add_ps(s, _mm256_mul_ps(w(2), q));
            mixed[i] = _mm256_add_ps(s, _mm256_mul_ps(w(3), q5));
            own[i] = r;
        }
        let mix = to_channels(&mixed);
        let r0c = to_channels(&own);
        let pick = |inside: __m256, outside: __m256| _mm256_blendv_ps(outside, inside, inside_ps);
        let r4 = pick(_mm256_mul_ps(_mm256_add_ps(r0c[2], mix[2]), half), r0c[2]);
        let r5 = pick(_mm256_mul_ps(_mm256_add_ps(r0c[3], mix[3]), half), r0c[3]);
        let r6 = pick(
            _mm256_mul_ps(_mm256_add_ps(r0c[4], mix[4]), quarter),
            _mm256_mul_ps(r0c[4], half),
        );
        let r2 = _mm256_mul_ps(_mm256_sub_ps(r0c[0], pick(mix[0], zero)), half);
        let r3 = _mm256_mul_ps(_mm256_sub_ps(r0c[1], pick(mix[1], zero)), half);
        let r2 = _mm256_add_ps(
            r2,
            _mm256_add_ps(_mm256_mul_ps(r4, dy), _mm256_mul_ps(r6, dx)),
        );
        let r3 = _mm256_add_ps(
            r3,
            _mm256_add_ps(_mm256_mul_ps(r6, dy), _mm256_mul_ps(r5, dx)),
        );
        // The border scale; exactly 1 inside, where the scalar loop skips it.
        // SAFETY: x + 8 <= width = column_weights.len().
        let columns = unsafe { _mm256_loadu_ps(row.column_weights.as_ptr().add(x)) };
        let scale = _mm256_mul_ps(_mm256_mul_ps(columns, yl), yh);
        let [r2, r3, r4, r5, r6] = [r2, r3, r4, r5, r6].map(|r| _mm256_mul_ps(r, scale));
        let g = [
            _mm256_add_ps(_mm256_mul_ps(r4, r4), _mm256_mul_ps(r6, r6)),
            _mm256_mul_ps(_mm256_add_ps(r4, r5), r6),
            _mm256_add_ps(_mm256_mul_ps(r5, r5), _mm256_mul_ps(r6, r6)),
            _mm256_add_ps(_mm256_mul_ps(r4, r2), _mm256_mul_ps(r6, r3)),
            _mm256_add_ps(_mm256_mul_ps(r6, r2), _mm256_mul_ps(r5, r3)),
        ];
        let pixels = transpose4(&[g[0], g[1], g[2], g[3]]);
        // SAFETY: soa holds 8 values.
        unsafe { _mm256_storeu_ps(soa.as_mut_ptr(), g[4]) };
        for (i, o) in out[x * 5..(x + 8) * 5].chunks_exact_mut(5).enumerate() {
            let half = if i < 4 {
                _mm256_castps256_ps128(pixels[i])
            } else {
                _mm256_extractf128_ps::<1>(pixels[i - 4])
            };
            // SAFETY: o holds 5 values; the store writes the first 4.
            unsafe { _mm_storeu_ps(o.as_mut_ptr(), half) };
            o[4] = soa[i];
        }
        x += 8;
    }
    x
}

/// Eight pixels' vectors (values in lanes 0..5) to five channels' vectors (pixels in lanes).
#[target_feature(enable = "avx2")]
#[inline]
fn to_channels(m: &[__m256; 8]) -> [__m256; 5] {
    // Lanes 0..4 of pixels k and k + 4 side by side: values 0..4 by the 4x4 transposes; then
    // lanes 4..8 alike, of which only value 4 is wanted.
    let low: [__m256; 4] = std::array::from_fn(|k| _mm256_permute2f128_ps::<0x20>(m[k], m[k + 4]));
    let high: [__m256; 4] = std::array::from_fn(|k| _mm256_permute2f128_ps::<0x31>(m[k], m[k + 4]));
    let [c0, c1, c2, c3] = transpose4(&low);
    [c0, c1, c2, c3, transpose4(&high)[0]]
}

/// The 4x4 transposes of both 128-bit halves of four vectors: vector j holds lane j of each of
/// `v` (in each half). Its own inverse: four channels' vectors (pixels in lanes) become pixel
/// k's four values in vector k's low half and pixel k + 4's in its high half.
#[target_feature(enable = "avx2")]
#[inline]
fn transpose4(v: &[__m256; 4]) -> [__m256; 4] {
    let t0 = _mm256_unpacklo_ps(v[0], v[1]);
    let t1 = _mm256_unpackhi_ps(v[0], v[1]);
    let t2 = _mm256_unpacklo_ps(v[2], v[3]);
    let t3 = _mm256_unpackhi_ps(v[2], v[3]);
    [
        _mm256_shuffle_ps::<0x44>(t0, t2),
        _mm256_shuffle_ps::<0xEE>(t0, t2),
        _mm256_shuffle_ps::<0x44>(t1, t3),
        _mm256_shuffle_ps::<0xEE>(t1, t3),
    ]
}
