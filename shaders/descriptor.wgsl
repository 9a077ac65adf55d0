// descriptor.wgsl: the integer totals of the built-in image descriptor of one 8-bit BGR frame at
// the analysis size (the similarity step's embedding when no model is given). The frame is cut
// into a 4 x 4 grid of cells (pixel x is in cell column x * 4 / width, y likewise). Per cell:
//   - 8 gradient-orientation bins: the 3x3 Sobel gradient (gx, gy) of the gray image (OpenCV's
//     fixed-point BGR2GRAY, BORDER_REFLECT_101) goes to the 45-degree sector of its direction,
//     decided by integer comparisons only, with the weight |gx| + |gy|; totals 0..127 at
//     cell * 8 + bin;
//   - the sums of B, G and R; totals 128..175 at 128 + cell * 3 + channel.
// Everything is integer, so the totals equal the twin's exactly (no tolerance). The host
// normalises them (src/kernels/descriptor.rs `embedding`).
// Bindings: 0 src (read; the frame's bytes B, G, R, ... 4 to a u32 little-endian, rows `stride`
//             words apart), 1 totals (176 atomic u32, zeroed by the host), 2 params (uniform).
// Workgroup: 16 x 16 x 1, one invocation per pixel; totals gather in workgroup memory first.
// Twin: src/kernels/descriptor.rs `opencv` (cv::cvtColor, cv::Sobel, the same binning).
// Prelude: border.wgsl (`reflect101`).

struct Params {
    width: u32,
    height: u32,
    stride: u32,
    pad: u32,
}

@group(0) @binding(0) var<storage, read> src: array<u32>;
@group(0) @binding(1) var<storage, read_write> totals: array<atomic<u32>>;
@group(0) @binding(2) var<uniform> params: Params;

const GRID: u32 = 4u;
const BINS: u32 = 8u;
const COLOUR_AT: u32 = 128u;
const TOTALS: u32 = 176u;

var<workgroup> local: array<atomic<u32>, 176>;

fn byte_at(i: u32) -> u32 {
    return (src[i >> 2u] >> ((i & 3u) * 8u)) & 0xffu;
}

fn bgr(x: u32, y: u32) -> vec3<u32> {
    let i = y * params.stride * 4u + x * 3u;
    return vec3<u32>(byte_at(i), byte_at(i + 1u), byte_at(i + 2u));
}

// Gray of pixel (x, y), coordinates reflected into the image: cv::cvtColor COLOR_BGR2GRAY.
fn gray(x: i32, y: i32) -> i32 {
    let c = bgr(u32(reflect101(x, i32(params.width))), u32(reflect101(y, i32(params.height))));
    return i32((3735u * c.x + 19235u * c.y + 9798u * c.z + 16384u) >> 15u);
}

// The 45-degree sector (0..7, counter-clockwise from +x with y pointing down as in the image)
// of a non-zero gradient: sector k holds the directions in [45 k, 45 (k + 1)) degrees.
fn sector(gx: i32, gy: i32) -> u32 {
    var x = gx;
    var y = gy;
    var base = 0u;
    if (y < 0 || (y == 0 && x < 0)) {
        x = -x;
        y = -y;
        base = 4u;
    }
    // Now in [0, 180): x > 0 and y >= 0 is [0, 90).
    if (x <= 0) {
        let t = x;
        x = y;
        y = -t;
        base = base + 2u;
    }
    return base + select(0u, 1u, y >= x);
}

@compute @workgroup_size(16, 16, 1)
fn main(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    if (li < TOTALS) {
        atomicStore(&local[li], 0u);
    }
    workgroupBarrier();
    if (gid.x < params.width && gid.y < params.height) {
        let x = i32(gid.x);
        let y = i32(gid.y);
        let a = gray(x - 1, y - 1);
        let b = gray(x, y - 1);
        let c = gray(x + 1, y - 1);
        let d = gray(x - 1, y);
        let f = gray(x + 1, y);
        let g = gray(x - 1, y + 1);
        let h = gray(x, y + 1);
        let k = gray(x + 1, y + 1);
        let gx = (c + 2 * f + k) - (a + 2 * d + g);
        let gy = (g + 2 * h + k) - (a + 2 * b + c);
        let cell = (gid.y * GRID / params.height) * GRID + gid.x * GRID / params.width;
        let weight = u32(abs(gx) + abs(gy));
        if (weight > 0u) {
            atomicAdd(&local[cell * BINS + sector(gx, gy)], weight);
        }
        let colour = bgr(gid.x, gid.y);
        atomicAdd(&local[COLOUR_AT + cell * 3u], colour.x);
        atomicAdd(&local[COLOUR_AT + cell * 3u + 1u], colour.y);
        atomicAdd(&local[COLOUR_AT + cell * 3u + 2u], colour.z);
    }
    workgroupBarrier();
    if (li < TOTALS) {
        let v = atomicLoad(&local[li]);
        if (v != 0u) {
            atomicAdd(&totals[li], v);
        }
    }
}
