// laplacian.wgsl: Laplacian of the gray image (OpenCV ksize 1: [0 1 0; 1 -4 1; 0 1 0], ksize 3:
// [2 0 2; 0 -8 0; 2 0 2]) and exact 64-bit totals of (L + offset) and L^2, for the variance.
// Each invocation handles a 4x4 pixel block; a workgroup (8x8) a 32x32 tile. Exact integers:
// |L| <= offset (1020 for ksize 1, 2040 for ksize 3); a tile adds at most
// 1024 * 2040^2 = 4 261 478 400 < 2^32 to the L^2 total and 1024 * 4080 to the (L + offset) one;
// tiles are added to 64-bit totals (low word + carry into the high word) with atomics.
// Borders: BORDER_REFLECT_101 (OpenCV's default).
// Bindings: 0 gray (read; 4 pixels per u32, rows padded to `stride` words),
//           1 totals (atomic u32 [sum(L + offset) low, high, sum(L^2) low, high], cleared
//           before the dispatch), 2 params (uniform; ksize 1 or 3).
// Workgroup: 8 x 8. Dispatch: ceil(width / 32) x ceil(height / 32).
// Twin: src/kernels/laplacian.rs `opencv` (cv::Laplacian CV_64F; cv::meanStdDev).

struct Params {
    width: u32,
    height: u32,
    stride: u32,
    ksize: u32,
}

@group(0) @binding(0) var<storage, read> gray: array<u32>;
@group(0) @binding(1) var<storage, read_write> totals: array<atomic<u32>>;
@group(0) @binding(2) var<uniform> params: Params;

var<workgroup> acc_l: array<u32, 64>;
var<workgroup> acc_sq: array<u32, 64>;

fn reflect101(i: i32, n: i32) -> i32 {
    if (n == 1) {
        return 0;
    }
    var j = i;
    if (j < 0) {
        j = -j;
    }
    if (j >= n) {
        j = 2 * n - 2 - j;
    }
    return j;
}

fn px(x: i32, y: i32) -> i32 {
    let xx = u32(reflect101(x, i32(params.width)));
    let yy = u32(reflect101(y, i32(params.height)));
    return i32((gray[yy * params.stride + (xx >> 2u)] >> ((xx & 3u) * 8u)) & 0xffu);
}

fn add64(index: u32, v: u32) {
    let old = atomicAdd(&totals[index], v);
    if (old + v < old) {
        atomicAdd(&totals[index + 1u], 1u);
    }
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let x0 = i32(gid.x * 4u);
    let y0 = i32(gid.y * 4u);
    let w = i32(params.width);
    let h = i32(params.height);
    var sum_l = 0u;
    var sum_sq = 0u;
    if (x0 < w && y0 < h) {
        var n: array<array<i32, 6>, 6>;
        for (var r = 0; r < 6; r = r + 1) {
            for (var c = 0; c < 6; c = c + 1) {
                n[r][c] = px(x0 - 1 + c, y0 - 1 + r);
            }
        }
        var offset = 2040;
        if (params.ksize == 1u) {
            offset = 1020;
        }
        for (var r = 1; r < 5; r = r + 1) {
            for (var c = 1; c < 5; c = c + 1) {
                if (x0 + c - 1 < w && y0 + r - 1 < h) {
                    var l = 0;
                    if (params.ksize == 1u) {
                        l = n[r - 1][c] + n[r][c - 1] + n[r][c + 1] + n[r + 1][c] - 4 * n[r][c];
                    } else {
                        l = 2 * (n[r - 1][c - 1] + n[r - 1][c + 1] + n[r + 1][c - 1] + n[r + 1][c + 1])
                            - 8 * n[r][c];
                    }
                    sum_l = sum_l + u32(l + offset);
                    sum_sq = sum_sq + u32(l * l);
                }
            }
        }
    }
    acc_l[li] = sum_l;
    acc_sq[li] = sum_sq;
    workgroupBarrier();
    for (var s = 32u; s > 0u; s = s >> 1u) {
        if (li < s) {
            acc_l[li] = acc_l[li] + acc_l[li + s];
            acc_sq[li] = acc_sq[li] + acc_sq[li + s];
        }
        workgroupBarrier();
    }
    if (li == 0u) {
        add64(0u, acc_l[0]);
        add64(2u, acc_sq[0]);
    }
}
