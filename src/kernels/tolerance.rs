//! Tolerances for comparing the gpu backend with its OpenCV twin, in one place with their reasons.

// Gray conversion has no tolerance: the shader uses OpenCV's own 15-bit fixed-point formula, and
// the tests require bit-identical gray images.

/// Sharpness scores (Tenengrad, Laplacian variance), relative error. The gpu path sums exact
/// integers (per-workgroup u32, then 64-bit totals) and divides once in f64; OpenCV accumulates the
/// same integer-valued pixels in double blocks, and the variance subtracts two large terms (an
/// f64 rounding of ~1e-16 relative each, amplified by mean^2 / variance on flat images). 1e-4
/// leaves room for that amplification on low-texture images while catching any real difference
/// (one wrong pixel of a 37x83 image already changes Tenengrad by ~1e-3 or more).
pub const SHARPNESS_REL: f64 = 1e-4;

/// Farneback flow, mean endpoint error in pixels against cv::calcOpticalFlowFarneback with the
/// same parameters. The gpu path runs every stage in f32 where OpenCV accumulates the polynomial
/// expansion's horizontal pass and the box window in double, and sums in another order; the
/// iterations and pyramid levels carry these ~1e-6 relative differences forward.
pub const FLOW_EPE_MEAN: f64 = 0.01;

/// Farneback flow, 99th percentile of the endpoint error in pixels (same reasons; the tail comes
/// from nearly singular windows where the solve amplifies rounding differences).
pub const FLOW_EPE_P99: f64 = 0.1;

/// Movement statistic (median / trimmed mean of flow magnitudes), relative error gpu vs opencv.
/// The selection on the device is exact; the difference comes only from the flow fields, whose
/// endpoint errors (bounded above) are ~1e-5 px on average against movements of tenths of a pixel
/// and more.
pub const MOVEMENT_REL: f64 = 0.01;

/// Derotation: the fitted rotation's matrix entries, device vs host on the same flow (absolute).
/// Both sum the same f32 per-pixel products; the device adds 256 of them per workgroup in f32
/// (tree order) before the host adds the partials in f64, the host adds every one in f64. For
/// fields of ~1e5 pixels and rotations of hundredths of a radian that moves the solved angles by
/// ~1e-8; three Gauss-Newton rounds keep it there. 1e-6 still catches a wrong pixel coordinate or
/// field (a one-pixel shift of the centre changes entries by ~1e-4).
pub const ROTATION_ABS: f32 = 1e-6;

/// Derotated movement, device vs host on the same flow (relative): the residual magnitudes
/// inherit the rotation's ~1e-8 differences times the focal length (hundreds of pixels), ~1e-5 px
/// against statistics of tenths of a pixel and more; the selection itself is exact.
pub const DEROTATED_SAME_FLOW_REL: f64 = 1e-4;

/// The similarity step's built-in descriptor (descriptor.wgsl): none. Both backends compute the
/// same integers (fixed-point gray, 16-bit Sobel, sectors decided by comparisons, integer sums;
/// the frame resized by the same cv::resize call on the host), so the totals must be equal and
/// the embeddings, normalised on the host from them, are bit-identical: the backends select
/// identical keyframes without any quantisation of the descriptor.
pub const DESCRIPTOR_TOTALS_ABS: u32 = 0;

/// Remap (ERP to pinhole views), bilinear: max abs difference in grey levels per channel against
/// cv::remap(INTER_LINEAR, BORDER_WRAP) on the same maps. The shader follows OpenCV's fixed-point
/// path (coordinates rounded to 1/32 px half to even, weights (32 − f)·f exact in 15 bits,
/// (sum + 2^14) >> 15), and is bit-exact on every test table (lavapipe); 1 grey level covers a map coordinate
/// within one f32 ulp of a 1/64 px rounding tie, which a different f32 multiply could round the
/// other way.
pub const REMAP_BILINEAR_MAX: u8 = 1;

/// Remap, bicubic: max abs difference against cv::remap(INTER_CUBIC, BORDER_WRAP). The weights
/// are OpenCV's own 15-bit table (the host rebuilds it with the same f32 arithmetic and sum fix),
/// the sum is exact in i32 (bit-exact on every test table, lavapipe); the same coordinate-rounding tie as bilinear allows 1 grey level, and
/// a tie there moves a 4 x 4 kernel's result by at most the weight change times the local
/// contrast (~1 grey level on 8-bit edges).
pub const REMAP_BICUBIC_MAX: u8 = 1;

/// Relative error `|a - b| / max(|b|, tiny)`.
pub fn rel_err(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1e-12)
}
