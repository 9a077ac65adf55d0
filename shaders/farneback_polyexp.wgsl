// farneback_polyexp.wgsl: Farneback's polynomial expansion (FarnebackPolyExp in OpenCV): separable
// Gaussian-weighted fits of 1, x, y, x^2, y^2, xy over a (2n+1)^2 neighbourhood, borders
// replicated. Output per pixel, 5 f32: [r_y, r_x, r_yy, r_xx, r_xy] in OpenCV's channel order
// (b3*ig11, b2*ig11, b1*ig03 + b5*ig33, b1*ig03 + b4*ig33, b6*ig55).
// Bindings: 0 img (f32 level image), 1 rows3 (f32 x3, vertical pass output), 2 r (f32 x5),
//           3 kern (f32: g[0..n], xg[0..n], xxg[0..n]), 4 params (uniform).
// Entry points: `cols` (vertical part, img -> rows3), `rows` (horizontal part, rows3 -> r).
// Workgroup 16 x 16, one invocation per pixel.
// Twin: cv::calcOpticalFlowFarneback (src/kernels/farneback.rs `opencv`).

struct Params {
    width: u32,
    height: u32,
    n: u32,
    pad: u32,
    ig11: f32,
    ig03: f32,
    ig33: f32,
    ig55: f32,
}

@group(0) @binding(0) var<storage, read> img: array<f32>;
@group(0) @binding(1) var<storage, read_write> rows3: array<f32>;
@group(0) @binding(2) var<storage, read_write> r: array<f32>;
@group(0) @binding(3) var<storage, read> kern: array<f32>;
@group(0) @binding(4) var<uniform> params: Params;

fn g(k: u32) -> f32 {
    return kern[k];
}

fn xg(k: u32) -> f32 {
    return kern[params.n + 1u + k];
}

fn xxg(k: u32) -> f32 {
    return kern[2u * (params.n + 1u) + k];
}

@compute @workgroup_size(16, 16, 1)
fn cols(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= params.width || gid.y >= params.height) {
        return;
    }
    let w = params.width;
    let y = i32(gid.y);
    let h = i32(params.height);
    var t0 = img[gid.y * w + gid.x] * g(0u);
    var t1 = 0.0;
    var t2 = 0.0;
    for (var k = 1u; k <= params.n; k = k + 1u) {
        let above = img[u32(max(y - i32(k), 0)) * w + gid.x];
        let below = img[u32(min(y + i32(k), h - 1)) * w + gid.x];
        let p = above + below;
        t0 = t0 + g(k) * p;
        t1 = t1 + xg(k) * (below - above);
        t2 = t2 + xxg(k) * p;
    }
    let o = (gid.y * w + gid.x) * 3u;
    rows3[o] = t0;
    rows3[o + 1u] = t1;
    rows3[o + 2u] = t2;
}

fn at(x: i32, c: u32, y: u32) -> f32 {
    let xx = u32(clamp(x, 0, i32(params.width) - 1));
    return rows3[(y * params.width + xx) * 3u + c];
}

@compute @workgroup_size(16, 16, 1)
fn rows(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= params.width || gid.y >= params.height) {
        return;
    }
    let x = i32(gid.x);
    let y = gid.y;
    let g0 = g(0u);
    var b1 = at(x, 0u, y) * g0;
    var b2 = 0.0;
    var b3 = at(x, 1u, y) * g0;
    var b4 = 0.0;
    var b5 = at(x, 2u, y) * g0;
    var b6 = 0.0;
    let last = i32(params.width) - 1;
    let row = y * params.width;
    for (var k = 1u; k <= params.n; k = k + 1u) {
        let ki = i32(k);
        let right = (row + u32(min(x + ki, last))) * 3u;
        let left = (row + u32(max(x - ki, 0))) * 3u;
        let r0 = rows3[right];
        let l0 = rows3[left];
        let r1 = rows3[right + 1u];
        let l1 = rows3[left + 1u];
        let r2 = rows3[right + 2u];
        let l2 = rows3[left + 2u];
        let gk = g(k);
        let xgk = xg(k);
        let tg = r0 + l0;
        b1 = b1 + tg * gk;
        b4 = b4 + tg * xxg(k);
        b2 = b2 + (r0 - l0) * xgk;
        b3 = b3 + (r1 + l1) * gk;
        b6 = b6 + (r1 - l1) * xgk;
        b5 = b5 + (r2 + l2) * gk;
    }
    let o = (y * params.width + gid.x) * 5u;
    r[o] = b3 * params.ig11;
    r[o + 1u] = b2 * params.ig11;
    r[o + 2u] = b1 * params.ig03 + b5 * params.ig33;
    r[o + 3u] = b1 * params.ig03 + b4 * params.ig33;
    r[o + 4u] = b6 * params.ig55;
}
