// gray.wgsl: 8-bit BGR to 8-bit gray with OpenCV's fixed-point coefficients and rounding,
// gray = (3735*B + 19235*G + 9798*R + 16384) >> 15 (cv::cvtColor COLOR_BGR2GRAY for 8-bit:
// OpenCV's BY15, GY15, RY15 with gray_shift 15).
// Bindings: 0 bgr (read; bytes packed little-endian 4 per u32, pixel-interleaved, rows not padded),
//           1 gray (write; 4 pixels per u32, little-endian, each row padded to `stride` words),
//           2 params (uniform).
// Workgroup: 64 x 1 x 1; one invocation per output word (4 pixels of a row).
// Dispatch: ceil(stride / 64) x height.
// Twin: src/kernels/gray.rs `opencv` (cv::cvtColor).

struct Params {
    width: u32,
    height: u32,
    stride: u32,
    pad: u32,
}

@group(0) @binding(0) var<storage, read> bgr: array<u32>;
@group(0) @binding(1) var<storage, read_write> gray: array<u32>;
@group(0) @binding(2) var<uniform> params: Params;

fn byte_at(i: u32) -> u32 {
    return (bgr[i >> 2u] >> ((i & 3u) * 8u)) & 0xffu;
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let word = gid.x;
    let y = gid.y;
    if (word >= params.stride || y >= params.height) {
        return;
    }
    var packed = 0u;
    for (var k = 0u; k < 4u; k = k + 1u) {
        let x = word * 4u + k;
        if (x < params.width) {
            let o = (y * params.width + x) * 3u;
            let v = (byte_at(o) * 3735u + byte_at(o + 1u) * 19235u + byte_at(o + 2u) * 9798u + 16384u) >> 15u;
            packed = packed | (v << (8u * k));
        }
    }
    gray[y * params.stride + word] = packed;
}
