// farneback_matrices.wgsl: FarnebackUpdateMatrices: for each pixel, sample the second image's
// expansion R1 at the position displaced by the current flow (bilinear, zero outside), combine it
// with R0, damp the 5-pixel border (OpenCV's weights 0.14, 0.14, 0.4472, 0.4472, 0.4472) and
// write M = [G11, G12, G22, h1, h2].
// Bindings: 0 ra0, 1 ra1 (expansion channels 0..3 per pixel), 5 rb0, 6 rb1 (channel 4 of the
// pixel and its right neighbour), 2 flow (f32 x2), 3 m (f32 x5, written), 4 params (uniform).
// Workgroup 16 x 16, one invocation per pixel.
// Twin: cv::calcOpticalFlowFarneback (src/kernels/farneback.rs `opencv`).

struct Params {
    width: u32,
    height: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var ra0: texture_2d<f32>;
@group(0) @binding(1) var ra1: texture_2d<f32>;
@group(0) @binding(5) var rb0: texture_2d<f32>;
@group(0) @binding(6) var rb1: texture_2d<f32>;
@group(0) @binding(2) var<storage, read> flow: array<f32>;
@group(0) @binding(3) var<storage, read_write> m: array<f32>;
@group(0) @binding(4) var<uniform> params: Params;

fn border_weight(i: i32) -> f32 {
    switch i {
        case 0: { return 0.14; }
        case 1: { return 0.14; }
        default: { return 0.4472; }
    }
}

@compute @workgroup_size(16, 16, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= params.width || gid.y >= params.height) {
        return;
    }
    let w = i32(params.width);
    let h = i32(params.height);
    let x = i32(gid.x);
    let y = i32(gid.y);
    let p = gid.y * params.width + gid.x;
    let dx = flow[p * 2u];
    let dy = flow[p * 2u + 1u];
    var fx = f32(x) + dx;
    var fy = f32(y) + dy;
    let x1 = i32(floor(fx));
    let y1 = i32(floor(fy));
    fx = fx - f32(x1);
    fy = fy - f32(y1);
    var r2 = 0.0;
    var r3 = 0.0;
    var r4 = 0.0;
    var r5 = 0.0;
    var r6 = 0.0;
    let o0 = p * 5u;
    let a0 = textureLoad(ra0, vec2<i32>(x, y), 0);
    let e0 = textureLoad(rb0, vec2<i32>(x, y), 0).x;
    if (x1 >= 0 && x1 < w - 1 && y1 >= 0 && y1 < h - 1) {
        let a00 = (1.0 - fx) * (1.0 - fy);
        let a01 = fx * (1.0 - fy);
        let a10 = (1.0 - fx) * fy;
        let a11 = fx * fy;
        let q00 = textureLoad(ra1, vec2<i32>(x1, y1), 0);
        let q01 = textureLoad(ra1, vec2<i32>(x1 + 1, y1), 0);
        let q10 = textureLoad(ra1, vec2<i32>(x1, y1 + 1), 0);
        let q11 = textureLoad(ra1, vec2<i32>(x1 + 1, y1 + 1), 0);
        let e_0 = textureLoad(rb1, vec2<i32>(x1, y1), 0);
        let e_1 = textureLoad(rb1, vec2<i32>(x1, y1 + 1), 0);
        let q = a00 * q00 + a01 * q01 + a10 * q10 + a11 * q11;
        r2 = q.x;
        r3 = q.y;
        r4 = q.z;
        r5 = q.w;
        r6 = a00 * e_0.x + a01 * e_0.y + a10 * e_1.x + a11 * e_1.y;
        r4 = (a0.z + r4) * 0.5;
        r5 = (a0.w + r5) * 0.5;
        r6 = (e0 + r6) * 0.25;
    } else {
        r4 = a0.z;
        r5 = a0.w;
        r6 = e0 * 0.5;
    }
    r2 = (a0.x - r2) * 0.5;
    r3 = (a0.y - r3) * 0.5;
    r2 = r2 + r4 * dy + r6 * dx;
    r3 = r3 + r6 * dy + r5 * dx;
    if (x < 5 || x >= w - 5 || y < 5 || y >= h - 5) {
        var s = 1.0;
        if (x < 5) {
            s = s * border_weight(x);
        }
        if (x >= w - 5) {
            s = s * border_weight(w - x - 1);
        }
        if (y < 5) {
            s = s * border_weight(y);
        }
        if (y >= h - 5) {
            s = s * border_weight(h - y - 1);
        }
        r2 = r2 * s;
        r3 = r3 * s;
        r4 = r4 * s;
        r5 = r5 * s;
        r6 = r6 * s;
    }
    m[o0] = r4 * r4 + r6 * r6;
    m[o0 + 1u] = (r4 + r5) * r6;
    m[o0 + 2u] = r5 * r5 + r6 * r6;
    m[o0 + 3u] = r4 * r2 + r6 * r3;
    m[o0 + 4u] = r6 * r2 + r5 * r3;
}
