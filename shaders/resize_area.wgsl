// resize_area.wgsl: downsizes an 8-bit gray image by integer factors kx x ky with OpenCV's
// INTER_AREA rules for that case (cv::resize's resizeAreaFast path, OpenCV 4.6): every output
// pixel is the sum of its kx x ky source block; for 2 x 2 the result is (sum + 2) >> 2 (OpenCV's
// fixed-point special case); otherwise it is round_half_even(f32(sum) * scale) with
// scale = 1.0f / (kx * ky) computed in f32 on the host (OpenCV's `sum * scale`, saturate_cast).
// Bindings: 0 src (read; gray.wgsl's layout: 4 pixels per u32 little-endian, rows `src_stride`
//             words apart),
//           1 dst (write; 4 pixels per u32 little-endian, rows not padded: byte p = y*dst_w + x,
//             the layout of a Farneback slot's level-0 input),
//           2 params (uniform).
// Workgroup: 64 x 1 x 1; one invocation per output word (4 consecutive output bytes).
// Dispatch: ceil(words / 64) workgroups, split as x + y * 65535 (see `groups` in resize_area.rs).
// Twin: src/kernels/resize_area.rs `opencv` (cv::resize INTER_AREA).

struct Params {
    src_w: u32,
    src_h: u32,
    src_stride: u32,
    dst_w: u32,
    dst_h: u32,
    kx: u32,
    ky: u32,
    scale: f32,
}

@group(0) @binding(0) var<storage, read> src: array<u32>;
@group(0) @binding(1) var<storage, read_write> dst: array<u32>;
@group(0) @binding(2) var<uniform> params: Params;

fn src_at(x: u32, y: u32) -> u32 {
    let w = src[y * params.src_stride + (x >> 2u)];
    return (w >> ((x & 3u) * 8u)) & 0xffu;
}

fn area(x: u32, y: u32) -> u32 {
    var sum = 0u;
    let x0 = x * params.kx;
    let y0 = y * params.ky;
    for (var j = 0u; j < params.ky; j = j + 1u) {
        for (var i = 0u; i < params.kx; i = i + 1u) {
            sum = sum + src_at(x0 + i, y0 + j);
        }
    }
    if (params.kx == 2u && params.ky == 2u) {
        return (sum + 2u) >> 2u;
    }
    return u32(min(round(f32(sum) * params.scale), 255.0));
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let word = gid.x + gid.y * 65535u * 64u;
    let n = params.dst_w * params.dst_h;
    if (word * 4u >= n) {
        return;
    }
    var packed = 0u;
    for (var k = 0u; k < 4u; k = k + 1u) {
        let p = word * 4u + k;
        if (p < n) {
            packed = packed | (area(p % params.dst_w, p / params.dst_w) << (8u * k));
        }
    }
    dst[word] = packed;
}
