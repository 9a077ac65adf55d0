// farneback_flow.wgsl: one Farneback flow update: average M = [G11, G12, G22, h1, h2] over the
// window (box: weights 1 and scale 1/winsize^2 as OpenCV's FarnebackUpdateFlow_Blur; Gaussian:
// OpenCV's normalised kernel with sigma = 0.3 * (winsize / 2) and scale 1), borders replicated,
// then solve G d = h per pixel: d = ((G11 h2 - G12 h1), (G22 h1 - G12 h2)) / (det + 1e-3).
// Bindings: 0 m (f32 x5), 1 vsum (f32 x5, vertical pass output), 2 flow (f32 x2, written),
//           3 weights (f32, m+1 taps from the centre out), 4 params (uniform).
// Entry points: `cols` (vertical pass), `rows` (horizontal pass and solve), one invocation per
// pixel, any weights; `box_cols`, `box_rows`: the box window as running sums, one invocation per
// run of RUN pixels along the pass direction (about 3 additions per pixel instead of 2m+1).
// Workgroup 16 x 16. Dispatch: per pixel ceil(w/16) x ceil(h/16); box_cols
// ceil(w/16) x ceil(ceil(h/RUN)/16); box_rows ceil(ceil(w/RUN)/16) x ceil(h/16).
// Twin: cv::calcOpticalFlowFarneback (src/kernels/farneback.rs `opencv`).

struct Params {
    width: u32,
    height: u32,
    radius: u32,
    pad0: u32,
    scale: f32,
    pad1: f32,
    pad2: f32,
    pad3: f32,
}

@group(0) @binding(0) var<storage, read> m: array<f32>;
@group(0) @binding(1) var<storage, read_write> vsum: array<f32>;
@group(0) @binding(2) var<storage, read_write> flow: array<f32>;
@group(0) @binding(3) var<storage, read> weights: array<f32>;
@group(0) @binding(4) var<uniform> params: Params;

@compute @workgroup_size(16, 16, 1)
fn cols(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= params.width || gid.y >= params.height) {
        return;
    }
    let w = params.width;
    let h = i32(params.height);
    let y = i32(gid.y);
    let o = (gid.y * w + gid.x) * 5u;
    for (var c = 0u; c < 5u; c = c + 1u) {
        var s = m[o + c] * weights[0];
        for (var i = 1u; i <= params.radius; i = i + 1u) {
            let below = u32(min(y + i32(i), h - 1));
            let above = u32(max(y - i32(i), 0));
            s = s + weights[i] * (m[(below * w + gid.x) * 5u + c] + m[(above * w + gid.x) * 5u + c]);
        }
        vsum[o + c] = s;
    }
}

@compute @workgroup_size(16, 16, 1)
fn rows(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= params.width || gid.y >= params.height) {
        return;
    }
    let w = i32(params.width);
    let x = i32(gid.x);
    let row = gid.y * params.width;
    var t: array<f32, 5>;
    for (var c = 0u; c < 5u; c = c + 1u) {
        var s = vsum[(row + gid.x) * 5u + c] * weights[0];
        for (var i = 1u; i <= params.radius; i = i + 1u) {
            let right = u32(min(x + i32(i), w - 1));
            let left = u32(max(x - i32(i), 0));
            s = s + weights[i] * (vsum[(row + right) * 5u + c] + vsum[(row + left) * 5u + c]);
        }
        t[c] = s * params.scale;
    }
    let idet = 1.0 / (t[0] * t[2] - t[1] * t[1] + 1e-3);
    let p = (row + gid.x) * 2u;
    flow[p] = (t[0] * t[4] - t[1] * t[3]) * idet;
    flow[p + 1u] = (t[2] * t[3] - t[1] * t[4]) * idet;
}

const RUN: u32 = 16u;

fn msum(x: u32, y: i32, c: u32) -> f32 {
    let yy = u32(clamp(y, 0, i32(params.height) - 1));
    return m[(yy * params.width + x) * 5u + c];
}

@compute @workgroup_size(16, 16, 1)
fn box_cols(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y0 = gid.y * RUN;
    if (x >= params.width || y0 >= params.height) {
        return;
    }
    let r = i32(params.radius);
    let y_end = min(y0 + RUN, params.height);
    for (var c = 0u; c < 5u; c = c + 1u) {
        var s = 0.0;
        for (var i = -r; i <= r; i = i + 1) {
            s = s + msum(x, i32(y0) + i, c);
        }
        vsum[(y0 * params.width + x) * 5u + c] = s;
        for (var y = y0 + 1u; y < y_end; y = y + 1u) {
            s = s + (msum(x, i32(y) + r, c) - msum(x, i32(y) - r - 1, c));
            vsum[(y * params.width + x) * 5u + c] = s;
        }
    }
}

fn vrow(row: u32, x: i32, c: u32) -> f32 {
    let xx = u32(clamp(x, 0, i32(params.width) - 1));
    return vsum[(row + xx) * 5u + c];
}

@compute @workgroup_size(16, 16, 1)
fn box_rows(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x0 = gid.x * RUN;
    if (x0 >= params.width || gid.y >= params.height) {
        return;
    }
    let r = i32(params.radius);
    let row = gid.y * params.width;
    let x_end = min(x0 + RUN, params.width);
    var t: array<f32, 5>;
    for (var c = 0u; c < 5u; c = c + 1u) {
        var s = 0.0;
        for (var i = -r; i <= r; i = i + 1) {
            s = s + vrow(row, i32(x0) + i, c);
        }
        t[c] = s;
    }
    for (var x = x0; x < x_end; x = x + 1u) {
        if (x > x0) {
            for (var c = 0u; c < 5u; c = c + 1u) {
                t[c] = t[c] + (vrow(row, i32(x) + r, c) - vrow(row, i32(x) - r - 1, c));
            }
        }
        let g11 = t[0] * params.scale;
        let g12 = t[1] * params.scale;
        let g22 = t[2] * params.scale;
        let h1 = t[3] * params.scale;
        let h2 = t[4] * params.scale;
        let idet = 1.0 / (g11 * g22 - g12 * g12 + 1e-3);
        let p = (row + x) * 2u;
        flow[p] = (g11 * h2 - g12 * h1) * idet;
        flow[p + 1u] = (g22 * h1 - g12 * h2) * idet;
    }
}
