// tenengrad.wgsl: 3x3 Sobel Gx, Gy on the gray image and the exact 64-bit total of Gx^2 + Gy^2.
// Each invocation scores a 4x4 pixel block; a workgroup (8x8) a 32x32 tile. Exact integers:
// |Gx|, |Gy| <= 1020, one pixel adds <= 2 080 800, a tile <= 2 130 739 200 < 2^32; tiles are
// added to a 64-bit total (low word + carry into the high word) with atomics.
// Borders: BORDER_REFLECT_101 (OpenCV's default).
// Bindings: 0 gray (read; 4 pixels per u32, rows padded to `stride` words),
//           1 totals (atomic u32 [low, high], cleared before the dispatch), 2 params (uniform).
// Workgroup: 8 x 8. Dispatch: ceil(width / 32) x ceil(height / 32).
// Twin: src/kernels/tenengrad.rs `opencv` (cv::Sobel ksize 3, CV_32F; cv::mean of Gx^2 + Gy^2).

struct Params {
    width: u32,
    height: u32,
    stride: u32,
    pad: u32,
}

@group(0) @binding(0) var<storage, read> gray: array<u32>;
@group(0) @binding(1) var<storage, read_write> totals: array<atomic<u32>>;
@group(0) @binding(2) var<uniform> params: Params;

var<workgroup> acc: array<u32, 64>;

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
    var sum = 0u;
    if (x0 < w && y0 < h) {
        // 6x6 neighbourhood of the 4x4 block, rows y0-1..y0+4, columns x0-1..x0+4.
        var n: array<array<i32, 6>, 6>;
        for (var r = 0; r < 6; r = r + 1) {
            for (var c = 0; c < 6; c = c + 1) {
                n[r][c] = px(x0 - 1 + c, y0 - 1 + r);
            }
        }
        for (var r = 1; r < 5; r = r + 1) {
            for (var c = 1; c < 5; c = c + 1) {
                if (x0 + c - 1 < w && y0 + r - 1 < h) {
                    let gx = (n[r - 1][c + 1] + 2 * n[r][c + 1] + n[r + 1][c + 1])
                        - (n[r - 1][c - 1] + 2 * n[r][c - 1] + n[r + 1][c - 1]);
                    let gy = (n[r + 1][c - 1] + 2 * n[r + 1][c] + n[r + 1][c + 1])
                        - (n[r - 1][c - 1] + 2 * n[r - 1][c] + n[r - 1][c + 1]);
                    sum = sum + u32(gx * gx + gy * gy);
                }
            }
        }
    }
    acc[li] = sum;
    workgroupBarrier();
    for (var s = 32u; s > 0u; s = s >> 1u) {
        if (li < s) {
            acc[li] = acc[li] + acc[li + s];
        }
        workgroupBarrier();
    }
    if (li == 0u) {
        add64(0u, acc[0]);
    }
}
