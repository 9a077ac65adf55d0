// farneback_smooth.wgsl: the Gaussian smoothing OpenCV's Farneback applies to the full-resolution
// image before resizing it to each pyramid level (cv::GaussianBlur on CV_32F, separable, rows then
// columns, BORDER_REFLECT_101). Input is 8-bit gray, 4 pixels per u32, rows `stride` bytes apart.
// Bindings: 0 gray (read), 1 tmp (f32, row pass output), 2 out (f32, smoothed image),
//           3 weights (f32, 2*radius+1 taps, centre at index radius), 4 params (uniform).
// Entry points: `rows` (gray -> tmp), `cols` (tmp -> out). Workgroup 16 x 16, one invocation per
// pixel; dispatch ceil(width/16) x ceil(height/16).
// Twin: src/kernels/farneback.rs `opencv` (cv::calcOpticalFlowFarneback does this internally).

struct Params {
    width: u32,
    height: u32,
    stride: u32,
    radius: u32,
}

@group(0) @binding(0) var<storage, read> gray: array<u32>;
@group(0) @binding(1) var<storage, read_write> tmp: array<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;
@group(0) @binding(3) var<storage, read> weights: array<f32>;
@group(0) @binding(4) var<uniform> params: Params;

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

fn gray_at(x: u32, y: u32) -> f32 {
    let b = y * params.stride + x;
    return f32((gray[b >> 2u] >> ((b & 3u) * 8u)) & 0xffu);
}

@compute @workgroup_size(16, 16, 1)
fn rows(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= params.width || gid.y >= params.height) {
        return;
    }
    let r = i32(params.radius);
    let w = i32(params.width);
    var s = 0.0;
    for (var k = -r; k <= r; k = k + 1) {
        s = s + weights[k + r] * gray_at(u32(reflect101(i32(gid.x) + k, w)), gid.y);
    }
    tmp[gid.y * params.width + gid.x] = s;
}

@compute @workgroup_size(16, 16, 1)
fn cols(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= params.width || gid.y >= params.height) {
        return;
    }
    let r = i32(params.radius);
    let h = i32(params.height);
    var s = 0.0;
    for (var k = -r; k <= r; k = k + 1) {
        let y = u32(reflect101(i32(gid.y) + k, h));
        s = s + weights[k + r] * tmp[y * params.width + gid.x];
    }
    out[gid.y * params.width + gid.x] = s;
}
