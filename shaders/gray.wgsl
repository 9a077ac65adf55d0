// gray.wgsl: 8-bit BGR to 8-bit gray with OpenCV's fixed-point coefficients and rounding,
// gray = (3735*B + 19235*G + 9798*R + 16384) >> 15 (cv::cvtColor COLOR_BGR2GRAY for 8-bit:
// OpenCV's BY15, GY15, RY15 with gray_shift 15).
// Bindings: 0 bgr (read, bytes packed little-endian 4 per u32, pixel-interleaved, no row padding),
//           1 gray (write, one pixel per u32), 2 params (uniform).
// Workgroup: 256 x 1 x 1, one invocation per pixel; 2D dispatch, row of groups = params.groups_x.
// Twin: src/kernels/gray.rs `opencv` (cv::cvtColor).

struct Params {
    width: u32,
    height: u32,
    groups_x: u32,
    pad: u32,
}

@group(0) @binding(0) var<storage, read> bgr: array<u32>;
@group(0) @binding(1) var<storage, read_write> gray: array<u32>;
@group(0) @binding(2) var<uniform> params: Params;

fn byte_at(i: u32) -> u32 {
    return (bgr[i >> 2u] >> ((i & 3u) * 8u)) & 0xffu;
}

@compute @workgroup_size(256, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let idx = (wid.y * params.groups_x + wid.x) * 256u + li;
    if (idx >= params.width * params.height) {
        return;
    }
    let o = idx * 3u;
    let b = byte_at(o);
    let g = byte_at(o + 1u);
    let r = byte_at(o + 2u);
    gray[idx] = (b * 3735u + g * 19235u + r * 9798u + 16384u) >> 15u;
}
