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
// Workgroup: 64 x 1 x 1; one invocation per 4 consecutive output pixels (`channels` whole words
// of the output; the coordinate, weights and wrapped taps of a pixel serve all its channels).
// Dispatch: ceil(pixels / 4 / 64) workgroups, split as x + y * 65535 (see `groups` in remap.rs).
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

// p wrapped into 0..n (BORDER_WRAP); the common case inside the image without a division.
fn wrap(p: i32, n: u32) -> u32 {
    let m = i32(n);
    if (p >= 0 && p < m) {
        return u32(p);
    }
    return u32(((p % m) + m) % m);
}

fn byte_at(b: u32) -> i32 {
    return i32((src[b >> 2u] >> ((b & 3u) * 8u)) & 0xffu);
}

// The channels of output pixel p (in x, y, z, w): its coordinate, weights and wrapped taps are
// computed once for all channels.
fn pixel(p: u32) -> vec4<u32> {
    let m = coords[p];
    let ix = i32(round(m.x * 32.0));
    let iy = i32(round(m.y * 32.0));
    let x0 = ix >> 5u;
    let y0 = iy >> 5u;
    let fx = ix & 31;
    let fy = iy & 31;
    let ch = params.channels;
    let row = params.src_w * ch;
    var sum = vec4<i32>(0);
    if (params.bicubic == 0u) {
        let xa = wrap(x0, params.src_w) * ch;
        let xb = wrap(x0 + 1, params.src_w) * ch;
        let ra = wrap(y0, params.src_h) * row;
        let rb = wrap(y0 + 1, params.src_h) * row;
        // (top * (32 - fy) + bottom * fy) * 32 with top = t00 (32 - fx) + t10 fx: exact
        // integers, so the products may be distributed.
        let w00 = (32 - fx) * (32 - fy) * 32;
        let w10 = fx * (32 - fy) * 32;
        let w01 = (32 - fx) * fy * 32;
        let w11 = fx * fy * 32;
        for (var c = 0u; c < ch; c = c + 1u) {
            sum[c] = byte_at(ra + xa + c) * w00 + byte_at(ra + xb + c) * w10
                + byte_at(rb + xa + c) * w01 + byte_at(rb + xb + c) * w11;
        }
    } else {
        let base = u32(fy * 32 + fx) * 16u;
        var xs: array<u32, 4>;
        var rows: array<u32, 4>;
        for (var k = 0; k < 4; k = k + 1) {
            xs[k] = wrap(x0 - 1 + k, params.src_w) * ch;
            rows[k] = wrap(y0 - 1 + k, params.src_h) * row;
        }
        for (var ky = 0; ky < 4; ky = ky + 1) {
            for (var kx = 0; kx < 4; kx = kx + 1) {
                let w = cubic[base + u32(ky * 4 + kx)];
                let at = rows[ky] + xs[kx];
                for (var c = 0u; c < ch; c = c + 1u) {
                    sum[c] = sum[c] + w * byte_at(at + c);
                }
            }
        }
    }
    return vec4<u32>(clamp((sum + vec4<i32>(16384)) >> vec4<u32>(15u), vec4<i32>(0), vec4<i32>(255)));
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let group = gid.x + gid.y * 65535u * 64u;
    let ch = params.channels;
    let pixels = params.dst_w * params.dst_h;
    let first = group * 4u;
    if (first >= pixels) {
        return;
    }
    // Four pixels are `ch` whole words of the output.
    var words = array<u32, 4>(0u, 0u, 0u, 0u);
    for (var k = 0u; k < 4u; k = k + 1u) {
        if (first + k < pixels) {
            let v = pixel(first + k);
            for (var c = 0u; c < ch; c = c + 1u) {
                let b = k * ch + c;
                words[b >> 2u] = words[b >> 2u] | (v[c] << ((b & 3u) * 8u));
            }
        }
    }
    let n = pixels * ch;
    for (var w = 0u; w < ch; w = w + 1u) {
        let word = group * ch + w;
        if (word * 4u < n) {
            dst[word] = words[w];
        }
    }
}
