// tenengrad.wgsl: 3x3 Sobel Gx, Gy on the gray image and per-workgroup sums of Gx^2 + Gy^2.
// Exact integers: |Gx|, |Gy| <= 1020, so one pixel adds <= 2 080 800 and a 16x16 workgroup
// <= 532 684 800 < 2^32. Borders: BORDER_REFLECT_101 (OpenCV's default).
// Bindings: 0 gray (read, one pixel per u32), 1 partials (write, one u32 per workgroup, row-major
//           over the workgroup grid), 2 params (uniform).
// Workgroup: 16 x 16, one invocation per pixel. Dispatch: ceil(w/16) x ceil(h/16).
// Twin: src/kernels/tenengrad.rs `opencv` (cv::Sobel ksize 3, CV_32F; cv::mean of Gx^2 + Gy^2).

struct Params {
    width: u32,
    height: u32,
    groups_x: u32,
    pad: u32,
}

@group(0) @binding(0) var<storage, read> gray: array<u32>;
@group(0) @binding(1) var<storage, read_write> partials: array<u32>;
@group(0) @binding(2) var<uniform> params: Params;

var<workgroup> acc: array<u32, 256>;

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
    var v = 0u;
    if (gid.x < params.width && gid.y < params.height) {
        let x = i32(gid.x);
        let y = i32(gid.y);
        let tl = px(x - 1, y - 1);
        let tc = px(x, y - 1);
        let tr = px(x + 1, y - 1);
        let ml = px(x - 1, y);
        let mr = px(x + 1, y);
        let bl = px(x - 1, y + 1);
        let bc = px(x, y + 1);
        let br = px(x + 1, y + 1);
        let gx = (tr + 2 * mr + br) - (tl + 2 * ml + bl);
        let gy = (bl + 2 * bc + br) - (tl + 2 * tc + tr);
        v = u32(gx * gx + gy * gy);
    }
    acc[li] = v;
    workgroupBarrier();
    for (var s = 128u; s > 0u; s = s >> 1u) {
        if (li < s) {
            acc[li] = acc[li] + acc[li + s];
        }
        workgroupBarrier();
    }
    if (li == 0u) {
        partials[wid.y * params.groups_x + wid.x] = acc[0];
    }
}
