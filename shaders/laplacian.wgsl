// laplacian.wgsl: Laplacian of the gray image (OpenCV ksize 1: [0 1 0; 1 -4 1; 0 1 0], ksize 3:
// [2 0 2; 0 -8 0; 2 0 2]) and per-workgroup sums of (L + offset) and L^2, for the variance.
// Exact integers: |L| <= offset (1020 for ksize 1, 2040 for ksize 3); a 16x16 workgroup adds at
// most 256 * 2040^2 = 1 065 369 600 < 2^32 for L^2 and 256 * 4080 for L + offset.
// Borders: BORDER_REFLECT_101 (OpenCV's default).
// Bindings: 0 gray (read, one pixel per u32), 1 partials (write, two u32 per workgroup:
//           [sum(L + offset), sum(L^2)]), 2 params (uniform; ksize 1 or 3).
// Workgroup: 16 x 16, one invocation per pixel. Dispatch: ceil(w/16) x ceil(h/16).
// Twin: src/kernels/laplacian.rs `opencv` (cv::Laplacian CV_64F; cv::meanStdDev).

struct Params {
    width: u32,
    height: u32,
    groups_x: u32,
    ksize: u32,
}

@group(0) @binding(0) var<storage, read> gray: array<u32>;
@group(0) @binding(1) var<storage, read_write> partials: array<u32>;
@group(0) @binding(2) var<uniform> params: Params;

var<workgroup> acc_l: array<u32, 256>;
var<workgroup> acc_sq: array<u32, 256>;

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
    let xx = reflect101(x, i32(params.width));
    let yy = reflect101(y, i32(params.height));
    return i32(gray[u32(yy) * params.width + u32(xx)]);
}

@compute @workgroup_size(16, 16, 1)
fn main(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    var l_off = 0u;
    var sq = 0u;
    if (gid.x < params.width && gid.y < params.height) {
        let x = i32(gid.x);
        let y = i32(gid.y);
        var l = 0;
        var offset = 0;
        if (params.ksize == 1u) {
            l = px(x, y - 1) + px(x - 1, y) + px(x + 1, y) + px(x, y + 1) - 4 * px(x, y);
            offset = 1020;
        } else {
            l = 2 * (px(x - 1, y - 1) + px(x + 1, y - 1) + px(x - 1, y + 1) + px(x + 1, y + 1))
                - 8 * px(x, y);
            offset = 2040;
        }
        l_off = u32(l + offset);
        sq = u32(l * l);
    }
    acc_l[li] = l_off;
    acc_sq[li] = sq;
    workgroupBarrier();
    for (var s = 128u; s > 0u; s = s >> 1u) {
        if (li < s) {
            acc_l[li] = acc_l[li] + acc_l[li + s];
            acc_sq[li] = acc_sq[li] + acc_sq[li + s];
        }
        workgroupBarrier();
    }
    if (li == 0u) {
        let g = wid.y * params.groups_x + wid.x;
        partials[2u * g] = acc_l[0];
        partials[2u * g + 1u] = acc_sq[0];
    }
}
