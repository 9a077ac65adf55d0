// stationary.wgsl (after f64.wgsl): the stationary step's reference mode on the device, frame by
// frame, so that the frames after a new reference are measured from it without the host waiting
// for the decision. Twin: src/steps/stationary.rs `Stationary::step` (same f64 arithmetic).
// `plan` opens or closes the gated dispatches of the flow from the reference frame and of its
// statistic: they run for a candidate frame that has a reference, unless the reference is the
// previous frame and the movement from it was just measured (the consecutive one is used).
// `decide` takes the frame: a keyframe when the accumulated movement plus the movement from the
// reference (times the scale to full-resolution pixels) reaches the threshold, else a
// re-anchoring after reset_delta frames carrying the movement; it writes the decision (0 none,
// 1 keyframe, 2 re-anchored) into the frame's record and opens the dispatches keeping the frame as
// the reference.
// Bindings: 0 state, 1 frame, 2 results (records of consts.record words: consecutive movement at
// 0, movement from the reference at 2, both f64 low word first; decision at 4), 3 shapes (the
// gated dispatch sizes, 3 u32 each), 4 args (what the gated dispatches read), 5 consts.

struct Consts {
    threshold_hi: u32,
    threshold_lo: u32,
    scale_hi: u32,
    scale_lo: u32,
    reset_delta: u32,
    record: u32,
    // Gated words: [0, plan_end) the flow from the reference, [keep_begin, keep_end) the copy.
    plan_end: u32,
    keep_begin: u32,
    keep_end: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

struct State {
    has_reference: u32,
    reference: u32,
    accumulated_hi: u32,
    accumulated_lo: u32,
}

struct Frame {
    index: u32,
    entry: u32,
    flags: u32,
    pad: u32,
}

// Frame flags.
const CANDIDATE: u32 = 1u;
const FROM_PREVIOUS: u32 = 2u;

@group(0) @binding(0) var<storage, read_write> state: State;
@group(0) @binding(1) var<storage, read> frame: Frame;
@group(0) @binding(2) var<storage, read_write> results: array<u32>;
@group(0) @binding(3) var<storage, read> shapes: array<u32>;
@group(0) @binding(4) var<storage, read_write> args: array<u32>;
@group(0) @binding(5) var<uniform> consts: Consts;

fn gate(begin: u32, end: u32, open: bool) {
    for (var w = begin; w < end; w = w + 1u) {
        args[w] = select(0u, shapes[w], open);
    }
}

// Whether the movement from the reference is the consecutive one just measured.
fn from_previous() -> bool {
    return (frame.flags & FROM_PREVIOUS) != 0u && state.reference + 1u == frame.index;
}

@compute @workgroup_size(1, 1, 1)
fn plan() {
    let candidate = (frame.flags & CANDIDATE) != 0u;
    gate(0u, consts.plan_end, candidate && state.has_reference == 1u && !from_previous());
}

@compute @workgroup_size(1, 1, 1)
fn decide() {
    let i = frame.index;
    let at = frame.entry * consts.record;
    var decision = 0u;
    if ((frame.flags & CANDIDATE) != 0u) {
        if (state.has_reference == 0u) {
            decision = 1u;
        } else {
            var m = vec2<u32>(results[at + 3u], results[at + 2u]);
            if (from_previous()) {
                m = vec2<u32>(results[at + 1u], results[at]);
            }
            let acc = vec2<u32>(state.accumulated_hi, state.accumulated_lo);
            let scale = vec2<u32>(consts.scale_hi, consts.scale_lo);
            let total = f64_add(acc, f64_mul(m, scale));
            if (f64_ge(total, vec2<u32>(consts.threshold_hi, consts.threshold_lo))) {
                decision = 1u;
            } else if (i - state.reference >= consts.reset_delta) {
                decision = 2u;
                state.accumulated_hi = total.x;
                state.accumulated_lo = total.y;
            }
        }
        if (decision == 1u) {
            state.accumulated_hi = 0u;
            state.accumulated_lo = 0u;
        }
        if (decision != 0u) {
            state.has_reference = 1u;
            state.reference = i;
        }
    }
    results[at + 4u] = decision;
    gate(consts.keep_begin, consts.keep_end, decision != 0u);
}
