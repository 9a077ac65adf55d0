// movement.wgsl (after f64.wgsl): order statistics of the per-pixel flow magnitude
// |d| = sqrt(dx^2 + dy^2), exact, by radix selection on the f32 bit patterns (non-negative floats
// order like their u32 bits), entirely on the device: `init` resets the selection state, then per
// round (bits 30..19, 18..7, 6..0) `histogram` counts, for two ranks at once, the values whose high
// bits equal the prefix found so far, binned by the round's bits, and `pick` finds the bin holding
// each wanted rank and narrows the prefix. `sums` then counts the values below / at the two
// selected values and sums the values strictly between them (per-workgroup f32 partials), and
// `finish` writes the statistic as an f64 (median: the mean of the two values; trimmed mean: ties
// split exactly, the partials added in order in f64 as the host would) into the results record
// `frame.entry` at `dest.field`, or NaN when the flow was not finite.
// Derotation (consts.derotate = 1): with p = (x, y, 1), x = (i - cx) / f, y = (j - cy) / f, the
// rotation R (sel.rot rows) moves pixel i by r = f ((R p).xy / (R p).z - (x, y)); the other
// passes use |d - r| as the magnitude. `rotation_sums` writes per-workgroup sums of
// e_k . (d - r) / f for the first-order rotation fields e_x = (x y, 1 + y^2),
// e_y = (-(1 + x^2), -x y), e_z = (y, -x); `solve` adds them (compensated), takes a Gauss-Newton
// step omega += N^-1 b (N^-1: consts.inverse) and sets sel.rot to the rotation of omega. Round k
// shortens residuals longer than consts.clamps[k] pixels to it first (Huber's modified residuals;
// 1e30 for least squares).
// Joint derotation over views (consts.derotate = 2): the flow holds the flows of
// n / (width * view_rows) square views stacked (view k's rows after view k - 1's); pixel
// coordinates are local to their view, `rotation_sums` turns each pixel's sums into the sphere's
// frame (consts.view_rot: view k -> sphere rotation rows), so consts.inverse (the joint normal
// matrix's inverse) solves for one rotation of the sphere, and `solve` also writes each view's
// own rotation V_k^T R V_k (sel.view_rot) that the residuals use.
// Bindings: 0 flow (f32 x2), 1 hist (atomic u32: 3 rounds x 2 ranks x 4096, then 2 counts),
//           3 partials (f32, three per workgroup), 4 consts, 5 radix (uniform), 6 sel (state),
//           7 results (u32 records), 8 frame, 9 dest (uniform).
// Workgroup 256; the per-pixel passes run ceil(n / 256) workgroups (folded into 2-D: groups_x
// per row), init / pick / solve / finish one workgroup.
// Twin: src/kernels/movement.rs `cpu` (sort of the same magnitudes) and `RotationField`.

struct Consts {
    n: u32,
    groups_x: u32,
    derotate: u32,
    width: u32,
    // Ranks (0-based, ascending) of the two selected values.
    lo: u32,
    hi: u32,
    // 1: trimmed mean, 0: median.
    trimmed: u32,
    partials: u32,
    f: f32,
    cx: f32,
    cy: f32,
    // Rows per view (the grid's height when there is one view).
    view_rows: u32,
    // Rows of the inverse normal matrix of the rotation fit, padded to vec4.
    inverse: array<vec4<f32>, 3>,
    // Per fit round (sel.round): residuals longer than this many pixels are shortened to it
    // (1e30: least squares).
    clamps: array<vec4<f32>, 2>,
    // Rows of each view's rotation to the sphere's frame (derotate = 2), three per view.
    view_rot: array<vec4<f32>, 24>,
}

struct Radix {
    shift: u32,
    bits: u32,
    prefix_shift: u32,
    index: u32,
}

struct Sel {
    prefix: array<u32, 2>,
    rank: array<u32, 2>,
    failed: u32,
    // Rotation fit rounds solved so far.
    round: u32,
    omega: array<f32, 4>,
    rot: array<vec4<f32>, 3>,
    // Per view (derotate = 2): the sphere's rotation seen from the view, three rows each.
    view_rot: array<vec4<f32>, 24>,
}

struct Frame {
    index: u32,
    entry: u32,
    flags: u32,
    pad: u32,
}

struct Dest {
    field: u32,
    record: u32,
}

const BINS: u32 = 4096u;
const COUNTS: u32 = 24576u;

@group(0) @binding(0) var<storage, read> flow: array<f32>;
@group(0) @binding(1) var<storage, read_write> hist: array<atomic<u32>>;
@group(0) @binding(3) var<storage, read_write> partials: array<f32>;
@group(0) @binding(4) var<uniform> consts: Consts;
@group(0) @binding(5) var<uniform> radix: Radix;
@group(0) @binding(6) var<storage, read_write> sel: Sel;
@group(0) @binding(7) var<storage, read_write> results: array<u32>;
@group(0) @binding(8) var<storage, read> frame: Frame;
@group(0) @binding(9) var<uniform> dest: Dest;

var<workgroup> acc: array<f32, 256>;
var<workgroup> acc_y: array<f32, 256>;
var<workgroup> acc_z: array<f32, 256>;

fn normalised(i: u32) -> vec2<f32> {
    return vec2<f32>((f32(i % consts.width) - consts.cx) / consts.f,
                     (f32((i / consts.width) % consts.view_rows) - consts.cy) / consts.f);
}

// The view pixel i belongs to.
fn view_of(i: u32) -> u32 {
    return (i / consts.width) / consts.view_rows;
}

// Row `row` of the rotation whose flow pixel i loses: the fitted one, or its view's own.
fn rot_row(i: u32, row: u32) -> vec4<f32> {
    if (consts.derotate == 2u) {
        return sel.view_rot[3u * view_of(i) + row];
    }
    return sel.rot[row];
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

// The flow of rotation sel.rot at pixel i (grid pixels).
fn rotation_flow(i: u32) -> vec2<f32> {
    let n = normalised(i);
    let r = array<vec4<f32>, 3>(rot_row(i, 0u), rot_row(i, 1u), rot_row(i, 2u));
    let q = vec3<f32>(r[0].x * n.x + r[0].y * n.y + r[0].z,
                      r[1].x * n.x + r[1].y * n.y + r[1].z,
                      r[2].x * n.x + r[2].y * n.y + r[2].z);
    return vec2<f32>(consts.f * (q.x / q.z - n.x), consts.f * (q.y / q.z - n.y));
}

fn magnitude_bits(i: u32) -> u32 {
    var dx = flow[2u * i];
    var dy = flow[2u * i + 1u];
    if (consts.derotate != 0u) {
        let r = rotation_flow(i);
        dx = dx - r.x;
        dy = dy - r.y;
    }
    return bitcast<u32>(sqrt(dx * dx + dy * dy));
}

fn pixel(wid: vec3<u32>, li: u32) -> u32 {
    return (wid.y * consts.groups_x + wid.x) * 256u + li;
}

@compute @workgroup_size(1, 1, 1)
fn init() {
    sel.prefix = array<u32, 2>(0u, 0u);
    sel.rank = array<u32, 2>(consts.lo, consts.hi);
    sel.failed = 0u;
    sel.round = 0u;
    sel.omega = array<f32, 4>(0.0, 0.0, 0.0, 0.0);
    sel.rot = array<vec4<f32>, 3>(vec4<f32>(1.0, 0.0, 0.0, 0.0), vec4<f32>(0.0, 1.0, 0.0, 0.0),
                                  vec4<f32>(0.0, 0.0, 1.0, 0.0));
    for (var k = 0u; k < 8u; k = k + 1u) {
        sel.view_rot[3u * k] = sel.rot[0];
        sel.view_rot[3u * k + 1u] = sel.rot[1];
        sel.view_rot[3u * k + 2u] = sel.rot[2];
    }
}

@compute @workgroup_size(256, 1, 1)
fn histogram(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let i = pixel(wid, li);
    if (i >= consts.n) {
        return;
    }
    let bits = magnitude_bits(i);
    let bin = (bits >> radix.shift) & ((1u << radix.bits) - 1u);
    let high = bits >> radix.prefix_shift;
    let base = radix.index * 2u * BINS;
    if (high == sel.prefix[0]) {
        atomicAdd(&hist[base + bin], 1u);
    }
    if (high == sel.prefix[1]) {
        atomicAdd(&hist[base + BINS + bin], 1u);
    }
}

// Invocation r narrows the prefix of rank r to the bin holding it.
@compute @workgroup_size(2, 1, 1)
fn pick(@builtin(local_invocation_index) r: u32) {
    let base = (radix.index * 2u + r) * BINS;
    let rank = sel.rank[r];
    var before = 0u;
    for (var b = 0u; b < (1u << radix.bits); b = b + 1u) {
        let c = atomicLoad(&hist[base + b]);
        if (rank < before + c) {
            sel.rank[r] = rank - before;
            sel.prefix[r] = (sel.prefix[r] << radix.bits) | b;
            return;
        }
        before = before + c;
    }
    // Fewer values than ranks: some magnitudes were not finite.
    sel.failed = 1u;
}

@compute @workgroup_size(256, 1, 1)
fn sums(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let g = wid.y * consts.groups_x + wid.x;
    let i = g * 256u + li;
    let lo_bits = sel.prefix[0];
    let hi_bits = sel.prefix[1];
    var v = 0.0;
    if (i < consts.n) {
        let bits = magnitude_bits(i);
        if (bits <= lo_bits) {
            atomicAdd(&hist[COUNTS], 1u);
        }
        if (bits < hi_bits) {
            atomicAdd(&hist[COUNTS + 1u], 1u);
        }
        if (bits > lo_bits && bits < hi_bits) {
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

// The statistic as an f64, in the host's order of operations.
fn statistic() -> vec2<u32> {
    let lo_bits = sel.prefix[0];
    let hi_bits = sel.prefix[1];
    let vlo = f64_from_f32(lo_bits);
    let vhi = f64_from_f32(hi_bits);
    if (consts.trimmed == 0u) {
        return f64_mul(f64_add(vlo, vhi), F64_HALF);
    }
    if (lo_bits == hi_bits) {
        return vlo;
    }
    var between = F64_ZERO;
    for (var g = 0u; g < consts.partials; g = g + 1u) {
        between = f64_add(between, f64_from_f32(bitcast<u32>(partials[g])));
    }
    let take_lo = f64_from_u32(atomicLoad(&hist[COUNTS]) - consts.lo);
    let take_hi = f64_from_u32(consts.hi + 1u - atomicLoad(&hist[COUNTS + 1u]));
    let sum = f64_add(f64_add(f64_mul(take_lo, vlo), between), f64_mul(take_hi, vhi));
    return f64_div(sum, f64_from_u32(consts.hi - consts.lo + 1u));
}

@compute @workgroup_size(1, 1, 1)
fn finish() {
    var v = F64_NAN;
    if (sel.failed == 0u) {
        v = statistic();
    }
    let at = frame.entry * dest.record + 2u * dest.field;
    results[at] = v.y;
    results[at + 1u] = v.x;
}

@compute @workgroup_size(256, 1, 1)
fn rotation_sums(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let g = wid.y * consts.groups_x + wid.x;
    let i = g * 256u + li;
    var s = vec3<f32>(0.0, 0.0, 0.0);
    if (i < consts.n) {
        let r = rotation_flow(i);
        var dx = flow[2u * i] - r.x;
        var dy = flow[2u * i + 1u] - r.y;
        let clamp = consts.clamps[sel.round / 4u][sel.round % 4u];
        let m = sqrt(dx * dx + dy * dy);
        if (m > clamp) {
            dx = dx * (clamp / m);
            dy = dy * (clamp / m);
        }
        let d = vec2<f32>(dx / consts.f, dy / consts.f);
        let e = basis(i);
        s = vec3<f32>(e[0].x * d.x + e[0].y * d.y, e[1].x * d.x + e[1].y * d.y,
                      e[2].x * d.x + e[2].y * d.y);
        if (consts.derotate == 2u) {
            let k = 3u * view_of(i);
            s = vec3<f32>(dot(consts.view_rot[k].xyz, s), dot(consts.view_rot[k + 1u].xyz, s),
                          dot(consts.view_rot[k + 2u].xyz, s));
        }
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

// The rotation whose first-order flow is sum_k omega_k e_k: by the angle t = |omega| about
// -omega (Rodrigues, I + s W + k W^2 with s = sin t / t, k = (1 - cos t) / t^2 from their series,
// accurate in f32 for any angle a frame pair can have).
fn rotation_of(omega: vec3<f32>) -> array<vec4<f32>, 3> {
    let a = -omega;
    let t2 = dot(a, a);
    var s = 0.0;
    var k = 0.0;
    var ts = 1.0;
    var tk = 0.5;
    for (var n = 0u; n < 10u; n = n + 1u) {
        s = s + ts;
        k = k + tk;
        let m = f32(2u * n + 2u);
        ts = -ts * t2 / (m * (m + 1.0));
        tk = -tk * t2 / ((m + 1.0) * (m + 2.0));
    }
    let w = mat3x3<f32>(vec3<f32>(0.0, a.z, -a.y), vec3<f32>(-a.z, 0.0, a.x),
                        vec3<f32>(a.y, -a.x, 0.0));
    let r = mat3x3<f32>(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0),
                        vec3<f32>(0.0, 0.0, 1.0)) + w * s + (w * w) * k;
    // WGSL matrices are column-major: row j of r is (r[0][j], r[1][j], r[2][j]).
    return array<vec4<f32>, 3>(vec4<f32>(r[0].x, r[1].x, r[2].x, 0.0),
                               vec4<f32>(r[0].y, r[1].y, r[2].y, 0.0),
                               vec4<f32>(r[0].z, r[1].z, r[2].z, 0.0));
}

@compute @workgroup_size(1, 1, 1)
fn solve() {
    var b = vec3<f32>(0.0, 0.0, 0.0);
    var c = vec3<f32>(0.0, 0.0, 0.0);
    for (var g = 0u; g < consts.partials; g = g + 1u) {
        let y = vec3<f32>(partials[3u * g], partials[3u * g + 1u], partials[3u * g + 2u]) - c;
        let t = b + y;
        c = (t - b) - y;
        b = t;
    }
    let inv = consts.inverse;
    let omega = vec3<f32>(sel.omega[0], sel.omega[1], sel.omega[2])
        + vec3<f32>(dot(inv[0].xyz, b), dot(inv[1].xyz, b), dot(inv[2].xyz, b));
    sel.omega = array<f32, 4>(omega.x, omega.y, omega.z, 0.0);
    let r = rotation_of(omega);
    sel.rot = r;
    sel.round = sel.round + 1u;
    if (consts.derotate == 2u) {
        let views = consts.n / (consts.width * consts.view_rows);
        for (var k = 0u; k < views; k = k + 1u) {
            let v = array<vec3<f32>, 3>(consts.view_rot[3u * k].xyz,
                                        consts.view_rot[3u * k + 1u].xyz,
                                        consts.view_rot[3u * k + 2u].xyz);
            // rv = r v, then v^T rv, summed in the host twin's order (SphereField::view_rotation).
            var rv: array<vec3<f32>, 3>;
            for (var a = 0u; a < 3u; a = a + 1u) {
                rv[a] = r[a].x * v[0] + r[a].y * v[1] + r[a].z * v[2];
            }
            for (var a = 0u; a < 3u; a = a + 1u) {
                let row = v[0][a] * rv[0] + v[1][a] * rv[1] + v[2][a] * rv[2];
                sel.view_rot[3u * k + a] = vec4<f32>(row, 0.0);
            }
        }
    }
}
