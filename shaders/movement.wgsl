// movement.wgsl: order statistics of the per-pixel flow magnitude |d| = sqrt(dx^2 + dy^2), exact,
// by radix selection on the f32 bit patterns (non-negative floats order like their u32 bits):
// `histogram` counts, for up to two ranks at once, the values whose high bits equal the prefix
// found so far, binned by the next 12 (then 12, then 7) bits; the host picks the bin holding the
// wanted rank and narrows the prefix. `sums` then counts the values below / at the two selected
// values and sums the values strictly between them (per-workgroup f32 partials), which gives the
// trimmed mean with ties split exactly.
// Derotation (params.derotate = 1): with p = (x, y, 1), x = (i - cx) / f, y = (j - cy) / f, the
// rotation R (params.rot rows) moves pixel i by r = f ((R p).xy / (R p).z - (x, y)); the other
// passes use |d - r| as the magnitude. `rotation_sums` writes per-workgroup sums of
// e_k . (d - r) / f for the first-order rotation fields e_x = (x y, 1 + y^2),
// e_y = (-(1 + x^2), -x y), e_z = (y, -x): the host solves the 3x3 normal equations for a step of
// the least-squares rotation (Gauss-Newton from R = identity).
// Bindings: 0 flow (f32 x2), 1 hist (atomic u32, 2 x 4096), 2 counts (atomic u32 x4),
//           3 partials (f32, three per workgroup), 4 params (uniform).
// Workgroup 256; dispatch ceil(n / 256) workgroups (folded into 2-D: groups_x per row).
// Twin: src/kernels/movement.rs `cpu` (sort of the same magnitudes) and `RotationField`.

struct Params {
    n: u32,
    groups_x: u32,
    shift: u32,
    mask: u32,
    prefix_shift: u32,
    prefix0: u32,
    prefix1: u32,
    lo_bits: u32,
    hi_bits: u32,
    derotate: u32,
    width: u32,
    pad0: u32,
    f: f32,
    cx: f32,
    cy: f32,
    pad1: f32,
    rot0: vec4<f32>,
    rot1: vec4<f32>,
    rot2: vec4<f32>,
}

@group(0) @binding(0) var<storage, read> flow: array<f32>;
@group(0) @binding(1) var<storage, read_write> hist: array<atomic<u32>>;
@group(0) @binding(2) var<storage, read_write> counts: array<atomic<u32>>;
@group(0) @binding(3) var<storage, read_write> partials: array<f32>;
@group(0) @binding(4) var<uniform> params: Params;

var<workgroup> acc: array<f32, 256>;
var<workgroup> acc_y: array<f32, 256>;
var<workgroup> acc_z: array<f32, 256>;

fn normalised(i: u32) -> vec2<f32> {
    return vec2<f32>((f32(i % params.width) - params.cx) / params.f,
                     (f32(i / params.width) - params.cy) / params.f);
}

// The three first-order rotation fields at pixel i: (e_x, e_y, e_z) as (u, v) pairs.
fn basis(i: u32) -> array<vec2<f32>, 3> {
    let n = normalised(i);
    let x = n.x;
    let y = n.y;
    return array<vec2<f32>, 3>(
        vec2<f32>(x * y, 1.0 + y * y),
        vec2<f32>(-(1.0 + x * x), -(x * y)),
        vec2<f32>(y, -x),
    );
}

// The flow of rotation params.rot at pixel i (grid pixels).
fn rotation_flow(i: u32) -> vec2<f32> {
    let n = normalised(i);
    let q = vec3<f32>(params.rot0.x * n.x + params.rot0.y * n.y + params.rot0.z,
                      params.rot1.x * n.x + params.rot1.y * n.y + params.rot1.z,
                      params.rot2.x * n.x + params.rot2.y * n.y + params.rot2.z);
    return vec2<f32>(params.f * (q.x / q.z - n.x), params.f * (q.y / q.z - n.y));
}

fn magnitude_bits(i: u32) -> u32 {
    var dx = flow[2u * i];
    var dy = flow[2u * i + 1u];
    if (params.derotate == 1u) {
        let r = rotation_flow(i);
        dx = dx - r.x;
        dy = dy - r.y;
    }
    return bitcast<u32>(sqrt(dx * dx + dy * dy));
}

@compute @workgroup_size(256, 1, 1)
fn histogram(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let i = (wid.y * params.groups_x + wid.x) * 256u + li;
    if (i >= params.n) {
        return;
    }
    let bits = magnitude_bits(i);
    let bin = (bits >> params.shift) & params.mask;
    let high = bits >> params.prefix_shift;
    if (high == params.prefix0) {
        atomicAdd(&hist[bin], 1u);
    }
    if (high == params.prefix1) {
        atomicAdd(&hist[4096u + bin], 1u);
    }
}

@compute @workgroup_size(256, 1, 1)
fn sums(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let g = wid.y * params.groups_x + wid.x;
    let i = g * 256u + li;
    var v = 0.0;
    if (i < params.n) {
        let bits = magnitude_bits(i);
        if (bits < params.lo_bits) {
            atomicAdd(&counts[0], 1u);
        }
        if (bits <= params.lo_bits) {
            atomicAdd(&counts[1], 1u);
        }
        if (bits < params.hi_bits) {
            atomicAdd(&counts[2], 1u);
        }
        if (bits <= params.hi_bits) {
            atomicAdd(&counts[3], 1u);
        }
        if (bits > params.lo_bits && bits < params.hi_bits) {
            v = bitcast<f32>(bits);
        }
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
        partials[g] = acc[0];
    }
}

@compute @workgroup_size(256, 1, 1)
fn rotation_sums(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let g = wid.y * params.groups_x + wid.x;
    let i = g * 256u + li;
    var s = vec3<f32>(0.0, 0.0, 0.0);
    if (i < params.n) {
        let r = rotation_flow(i);
        let d = vec2<f32>((flow[2u * i] - r.x) / params.f, (flow[2u * i + 1u] - r.y) / params.f);
        let e = basis(i);
        s = vec3<f32>(e[0].x * d.x + e[0].y * d.y, e[1].x * d.x + e[1].y * d.y,
                      e[2].x * d.x + e[2].y * d.y);
    }
    acc[li] = s.x;
    acc_y[li] = s.y;
    acc_z[li] = s.z;
    workgroupBarrier();
    for (var k = 128u; k > 0u; k = k >> 1u) {
        if (li < k) {
            acc[li] = acc[li] + acc[li + k];
            acc_y[li] = acc_y[li] + acc_y[li + k];
            acc_z[li] = acc_z[li] + acc_z[li + k];
        }
        workgroupBarrier();
    }
    if (li == 0u) {
        partials[3u * g] = acc[0];
        partials[3u * g + 1u] = acc_y[0];
        partials[3u * g + 2u] = acc_z[0];
    }
}
