// copy.wgsl: dst = src, word by word (the stationary step keeps a frame's expansion pyramid as
// its reference; dispatched indirectly, so the device decides whether it runs).
// Bindings: 0 src, 1 dst, 2 params. Workgroup 256; ceil(words / 256) workgroups folded into 2-D
// (groups_x per row).

struct Params {
    words: u32,
    groups_x: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<storage, read> src: array<u32>;
@group(0) @binding(1) var<storage, read_write> dst: array<u32>;
@group(0) @binding(2) var<uniform> params: Params;

@compute @workgroup_size(256, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let i = (wid.y * params.groups_x + wid.x) * 256u + li;
    if (i < params.words) {
        dst[i] = src[i];
    }
}
