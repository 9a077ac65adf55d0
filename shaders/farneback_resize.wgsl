// farneback_resize.wgsl: bilinear resize of a 1- or 2-channel f32 image with OpenCV's INTER_LINEAR
// coordinate mapping (fx = (dx + 0.5) * scale_x - 0.5, clamped at the borders with weight 0), then
// a multiplication by `factor` (the 1/pyr_scale applied to flow between pyramid levels).
// Bindings: 0 src (f32, interleaved channels), 1 dst (f32), 2 params (uniform).
// Workgroup 16 x 16, one invocation per destination pixel.
// Twin: cv::resize(INTER_LINEAR) inside cv::calcOpticalFlowFarneback (src/kernels/farneback.rs).

struct Params {
    src_w: u32,
    src_h: u32,
    dst_w: u32,
    dst_h: u32,
    channels: u32,
    pad0: u32,
    scale_x: f32,
    scale_y: f32,
    factor: f32,
    pad1: f32,
    pad2: f32,
    pad3: f32,
}

@group(0) @binding(0) var<storage, read> src: array<f32>;
@group(0) @binding(1) var<storage, read_write> dst: array<f32>;
@group(0) @binding(2) var<uniform> params: Params;

@compute @workgroup_size(16, 16, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= params.dst_w || gid.y >= params.dst_h) {
        return;
    }
    var fx = (f32(gid.x) + 0.5) * params.scale_x - 0.5;
    var fy = (f32(gid.y) + 0.5) * params.scale_y - 0.5;
    var sx = i32(floor(fx));
    var sy = i32(floor(fy));
    fx = fx - floor(fx);
    fy = fy - floor(fy);
    let sw = i32(params.src_w);
    let sh = i32(params.src_h);
    if (sx < 0) {
        sx = 0;
        fx = 0.0;
    }
    if (sx >= sw - 1) {
        sx = sw - 1;
        fx = 0.0;
    }
    if (sy < 0) {
        sy = 0;
        fy = 0.0;
    }
    if (sy >= sh - 1) {
        sy = sh - 1;
        fy = 0.0;
    }
    let sx1 = min(sx + 1, sw - 1);
    let sy1 = min(sy + 1, sh - 1);
    let c = params.channels;
    for (var k = 0u; k < c; k = k + 1u) {
        let a = src[(u32(sy) * params.src_w + u32(sx)) * c + k];
        let b = src[(u32(sy) * params.src_w + u32(sx1)) * c + k];
        let d = src[(u32(sy1) * params.src_w + u32(sx)) * c + k];
        let e = src[(u32(sy1) * params.src_w + u32(sx1)) * c + k];
        let top = a * (1.0 - fx) + b * fx;
        let bottom = d * (1.0 - fx) + e * fx;
        dst[(gid.y * params.dst_w + gid.x) * c + k] = (top * (1.0 - fy) + bottom * fy) * params.factor;
    }
}
