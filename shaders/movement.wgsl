// movement.wgsl: order statistics of the per-pixel flow magnitude |d| = sqrt(dx^2 + dy^2), exact,
// by radix selection on the f32 bit patterns (non-negative floats order like their u32 bits):
// `histogram` counts, for up to two ranks at once, the values whose high bits equal the prefix
// found so far, binned by the next 12 (then 12, then 7) bits; the host picks the bin holding the
// wanted rank and narrows the prefix. `sums` then counts the values below / at the two selected
// values and sums the values strictly between them (per-workgroup f32 partials), which gives the
// trimmed mean with ties split exactly.
// Bindings: 0 flow (f32 x2), 1 hist (atomic u32, 2 x 4096), 2 counts (atomic u32 x4),
//           3 partials (f32, one per workgroup), 4 params (uniform).
// Workgroup 256; dispatch ceil(n / 256) workgroups (folded into 2-D: groups_x per row).
// Twin: src/kernels/movement.rs `cpu` (sort of the same magnitudes).

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
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<storage, read> flow: array<f32>;
@group(0) @binding(1) var<storage, read_write> hist: array<atomic<u32>>;
@group(0) @binding(2) var<storage, read_write> counts: array<atomic<u32>>;
@group(0) @binding(3) var<storage, read_write> partials: array<f32>;
@group(0) @binding(4) var<uniform> params: Params;

var<workgroup> acc: array<f32, 256>;

fn magnitude_bits(i: u32) -> u32 {
    let dx = flow[2u * i];
    let dy = flow[2u * i + 1u];
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
