// reduce.wgsl: sums per-workgroup u32 partials into exact 64-bit totals (lo, hi words with carry),
// so a 4K frame keeps every bit: no float summation, no overflow.
// Bindings: 0 partials (read; `count` records of `stride` u32 each), 1 totals (write; for each
//           quantity q < stride: totals[2q] = low word, totals[2q + 1] = high word), 2 params.
// Workgroup: 256 x 1 x 1; dispatch (stride, 1, 1): workgroup q sums quantity q.
// Twin: `cpu` in src/kernels/reduce.rs (OpenCV itself sums in f64 inside cv::mean).

struct Params {
    count: u32,
    stride: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<storage, read> partials: array<u32>;
@group(0) @binding(1) var<storage, read_write> totals: array<u32>;
@group(0) @binding(2) var<uniform> params: Params;

var<workgroup> lo_acc: array<u32, 256>;
var<workgroup> hi_acc: array<u32, 256>;

fn add64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.x + b.x;
    let carry = select(0u, 1u, lo < a.x);
    return vec2<u32>(lo, a.y + b.y + carry);
}

@compute @workgroup_size(256, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let q = wid.x;
    var t = vec2<u32>(0u, 0u);
    for (var i = li; i < params.count; i = i + 256u) {
        t = add64(t, vec2<u32>(partials[i * params.stride + q], 0u));
    }
    lo_acc[li] = t.x;
    hi_acc[li] = t.y;
    workgroupBarrier();
    for (var s = 128u; s > 0u; s = s >> 1u) {
        if (li < s) {
            let r = add64(vec2<u32>(lo_acc[li], hi_acc[li]), vec2<u32>(lo_acc[li + s], hi_acc[li + s]));
            lo_acc[li] = r.x;
            hi_acc[li] = r.y;
        }
        workgroupBarrier();
    }
    if (li == 0u) {
        totals[2u * q] = lo_acc[0];
        totals[2u * q + 1u] = hi_acc[0];
    }
}
