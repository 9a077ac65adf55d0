// remap.wgsl: renders an image through a table of source coordinates, cv::remap's rules for 8-bit
// images with float maps and BORDER_WRAP (OpenCV 4.6): each map coordinate is rounded to 1/32 of
// a pixel (round half to even, INTER_BITS = 5); the integer part picks the top-left tap (floor),
// the fraction the fixed-point weights (INTER_REMAP_COEF_BITS = 15); taps outside the image wrap
// around on both axes. Bilinear weights are exact products of (32 - f) and f; bicubic weights come
// from the host's table (`remap::bicubic_table`, OpenCV's interpolateCubic with A = -0.75 rounded
// to 15 bits with its sum fix). The output is (sum + 2^14) >> 15, saturated to 0..255.
// Bindings: 0 src (read; the image's bytes, rows of src_w * channels bytes, 4 bytes per u32
//             little-endian, as a continuous cv::Mat holds them),
//           1 dst (write; dst_w * dst_h * channels bytes, the same layout),
//           2 coords (read; per output pixel, row after row, its source (x, y) as two f32),
//           3 params (uniform),
//           4 cubic (read; 32 * 32 * 16 i32 weights: entry (fy * 32 + fx) * 16 + ky * 4 + kx).
// Workgroup: 64 x 1 x 1; one invocation per output word (4 consecutive output bytes, which may
// belong to two pixels).
// Dispatch: ceil(words / 64) workgroups, split as x + y * 65535 (see `groups` in remap.rs).
// Twin: src/kernels/remap.rs `opencv` (cv::remap, BORDER_WRAP).

struct Params {
    src_w: u32,
    src_h: u32,
    dst_w: u32,
    dst_h: u32,
    channels: u32,
    bicubic: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<storage, read> src: array<u32>;
@group(0) @binding(1) var<storage, read_write> dst: array<u32>;
@group(0) @binding(2) var<storage, read> coords: array<vec2<f32>>;
@group(0) @binding(3) var<uniform> params: Params;
@group(0) @binding(4) var<storage, read> cubic: array<i32>;

fn wrap(p: i32, n: u32) -> u32 {
    let m = i32(n);
    return u32(((p % m) + m) % m);
}

fn tap(x: i32, y: i32, c: u32) -> i32 {
    let b = (wrap(y, params.src_h) * params.src_w + wrap(x, params.src_w)) * params.channels + c;
    return i32((src[b >> 2u] >> ((b & 3u) * 8u)) & 0xffu);
}

fn sample(p: u32, c: u32) -> u32 {
    let m = coords[p];
    let ix = i32(round(m.x * 32.0));
    let iy = i32(round(m.y * 32.0));
    let x0 = ix >> 5u;
    let y0 = iy >> 5u;
    let fx = ix & 31;
    let fy = iy & 31;
    var sum = 0;
    if (params.bicubic == 0u) {
        let top = tap(x0, y0, c) * (32 - fx) + tap(x0 + 1, y0, c) * fx;
        let bottom = tap(x0, y0 + 1, c) * (32 - fx) + tap(x0 + 1, y0 + 1, c) * fx;
        sum = (top * (32 - fy) + bottom * fy) * 32;
    } else {
        let base = u32(fy * 32 + fx) * 16u;
        for (var ky = 0; ky < 4; ky = ky + 1) {
            for (var kx = 0; kx < 4; kx = kx + 1) {
                let w = cubic[base + u32(ky * 4 + kx)];
                sum = sum + w * tap(x0 - 1 + kx, y0 - 1 + ky, c);
            }
        }
    }
    return u32(clamp((sum + 16384) >> 15u, 0, 255));
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let word = gid.x + gid.y * 65535u * 64u;
    let n = params.dst_w * params.dst_h * params.channels;
    if (word * 4u >= n) {
        return;
    }
    var packed = 0u;
    for (var k = 0u; k < 4u; k = k + 1u) {
        let b = word * 4u + k;
        if (b < n) {
            packed = packed | (sample(b / params.channels, b % params.channels) << (8u * k));
        }
    }
    dst[word] = packed;
}
