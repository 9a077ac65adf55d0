// farneback_flow.wgsl (after border.wgsl): the flow iterations of one pyramid level as
// cv::calcOpticalFlowFarneback runs them: FarnebackUpdateMatrices (sample the second
// expansion R1 where the flow points, bilinear, zero outside; combine with R0; damp the 5-pixel
// border with OpenCV's weights 0.14, 0.14, 0.4472, 0.4472, 0.4472; M = [G11, G12, G22, h1, h2])
// and FarnebackUpdateFlow_Blur / _GaussianBlur (average M over the window, borders replicated:
// box with weights 1 and scale 1/winsize^2, or OpenCV's normalised Gaussian, sigma =
// 0.3 * (winsize / 2), scale 1; then solve G d = h: d = ((G11 h2 - G12 h1), (G22 h1 - G12 h2)) /
// (det + 1e-3)). M at a pixel needs only the flow at that pixel, so the matrices are computed
// where the flow is: right after the solve, and at the start of the level after resizing the
// coarser level's flow (cv::resize INTER_LINEAR, times 1 / pyr_scale).
// Layout: four pixels per texel. M: texel 7 t + c = channel c of pixels 4 t .. 4 t + 3, then
// the level's flow (texel 7 t + 5 = x components, 7 t + 6 = y components). The vertical window
// sums VS: texel 5 (t + halo) + c, with `halo` texels of replicated border left and right. The
// expansions R0, R1: texel 2 x = channels 0..3 of pixel x, 2 x + 1 = channel 4 of pixels x and
// x + 1. The final flow of level 0 goes to a buffer (2 x f32 per pixel, rows unpadded).
// Entry points (workgroup 8 x 1, no shared memory, no barrier):
// - `start`: the level's first M from the coarser flow (or the level's initial flow, or zero).
//   Dispatch ceil(ceil(w / 4) / 8) x h.
// - `vbox` / `vgauss`: vertical window of M into VS, one texel column and strip_rows rows per
//   invocation (vbox: running sums). Dispatch ceil((ceil(w / 4) + 2 halo) / 8) x ceil(h / strip_rows).
// - `hbox0`..`hbox3` (radius & 3) / `hgauss`: horizontal window of VS, solve, then M (or, with
//   `last`, the flow), `run` texels per invocation (hbox: running sums). Dispatch
//   ceil(ceil(ceil(w / 4) / run) / 8) x h.
// Twin: cv::calcOpticalFlowFarneback (src/kernels/farneback.rs `opencv`).

struct FlowParams {
    // This level's size.
    width: u32,
    height: u32,
    // Window radius m (winsize / 2) and the halo of VS in texels.
    radius: u32,
    halo: u32,
    strip_rows: u32,
    run: u32,
    // start: 0 = zero flow, 1 = resize `flow_in`.
    mode: u32,
    // hbox / hgauss: 1 = write the flow instead of M; 2 = write it to `flow_final`.
    last: u32,
    // Size of `flow_in` (start) and where its flow is: x components of texel t at
    // flow_stride * t + flow_offset, y components in the next texel.
    src_w: u32,
    src_h: u32,
    flow_stride: u32,
    flow_offset: u32,
    // Window scale (box: 1 / winsize^2; Gaussian: 1).
    scale: f32,
    // Flow factor of the resize (1 / pyr_scale; 1 for the level's own initial flow).
    factor: f32,
    // cv::resize's source step per destination pixel.
    scale_x: f32,
    scale_y: f32,
}

// Gaussian window taps from the centre out, one per element (x), zero beyond the radius.
struct Taps {
    w: array<vec4<f32>, 1024>,
}

@group(0) @binding(0) var r0: texture_storage_2d<rgba32float, read>;
@group(0) @binding(1) var r1: texture_storage_2d<rgba32float, read>;
@group(0) @binding(4) var m_in: texture_storage_2d<rgba32float, read>;
@group(0) @binding(5) var m_out: texture_storage_2d<rgba32float, write>;
@group(0) @binding(6) var vs_in: texture_storage_2d<rgba32float, read>;
@group(0) @binding(7) var vs_out: texture_storage_2d<rgba32float, write>;
@group(0) @binding(8) var flow_in: texture_storage_2d<rgba32float, read>;
@group(0) @binding(10) var<storage, read_write> flow_final: array<f32>;
@group(0) @binding(11) var<uniform> params: FlowParams;
@group(0) @binding(12) var<uniform> taps: Taps;

// Five channels of four pixels.
struct M4 {
    c0: vec4<f32>,
    c1: vec4<f32>,
    c2: vec4<f32>,
    c3: vec4<f32>,
    c4: vec4<f32>,
}

fn m4_add(a: M4, b: M4) -> M4 {
    return M4(a.c0 + b.c0, a.c1 + b.c1, a.c2 + b.c2, a.c3 + b.c3, a.c4 + b.c4);
}

fn m4_sub(a: M4, b: M4) -> M4 {
    return M4(a.c0 - b.c0, a.c1 - b.c1, a.c2 - b.c2, a.c3 - b.c3, a.c4 - b.c4);
}

fn m4_axpy(a: f32, x: M4, y: M4) -> M4 {
    return M4(y.c0 + a * x.c0, y.c1 + a * x.c1, y.c2 + a * x.c2, y.c3 + a * x.c3, y.c4 + a * x.c4);
}

fn m4_zero() -> M4 {
    let z = vec4<f32>(0.0);
    return M4(z, z, z, z, z);
}

fn texels_per_row() -> i32 {
    return (i32(params.width) + 3) / 4;
}

fn tap(i: i32) -> f32 {
    return taps.w[abs(i)].x;
}

// ---- matrices ----

// OpenCV's border damping of pixels i pixels from the edge (1 from 5 on).
fn border_weight(i: vec4<i32>) -> vec4<f32> {
    return select(select(vec4<f32>(0.4472), vec4<f32>(0.14), i < vec4<i32>(2)), vec4<f32>(1.0),
                  i >= vec4<i32>(5));
}

// M of pixel (x, y) with flow d (FarnebackUpdateMatrices for one pixel); a0 = R0 channels 0..3
// of the pixel, e0 = its channel 4, s = its border damping factor.
fn matrices(x: i32, y: i32, d: vec2<f32>, a0: vec4<f32>, e0: f32, s: f32) -> array<f32, 5> {
    let w = i32(params.width);
    let h = i32(params.height);
    var fx = f32(x) + d.x;
    var fy = f32(y) + d.y;
    let x1 = i32(floor(fx));
    let y1 = i32(floor(fy));
    fx = fx - f32(x1);
    fy = fy - f32(y1);
    // R1 around the moved pixel, read at a clamped place and used only inside (branch free).
    let inside = x1 >= 0 && x1 < w - 1 && y1 >= 0 && y1 < h - 1;
    let cx = clamp(x1, 0, w - 2);
    let cy = clamp(y1, 0, h - 2);
    let a00 = (1.0 - fx) * (1.0 - fy);
    let a01 = fx * (1.0 - fy);
    let a10 = (1.0 - fx) * fy;
    let a11 = fx * fy;
    let q = a00 * textureLoad(r1, vec2<i32>(2 * cx, cy))
        + a01 * textureLoad(r1, vec2<i32>(2 * cx + 2, cy))
        + a10 * textureLoad(r1, vec2<i32>(2 * cx, cy + 1))
        + a11 * textureLoad(r1, vec2<i32>(2 * cx + 2, cy + 1));
    let e_0 = textureLoad(r1, vec2<i32>(2 * cx + 1, cy));
    let e_1 = textureLoad(r1, vec2<i32>(2 * cx + 1, cy + 1));
    let e = a00 * e_0.x + a01 * e_0.y + a10 * e_1.x + a11 * e_1.y;
    var r2 = select(0.0, q.x, inside);
    var r3 = select(0.0, q.y, inside);
    var r4 = select(a0.z, (a0.z + q.z) * 0.5, inside);
    var r5 = select(a0.w, (a0.w + q.w) * 0.5, inside);
    var r6 = select(e0 * 0.5, (e0 + e) * 0.25, inside);
    r2 = (a0.x - r2) * 0.5;
    r3 = (a0.y - r3) * 0.5;
    r2 = r2 + r4 * d.y + r6 * d.x;
    r3 = r3 + r6 * d.y + r5 * d.x;
    // OpenCV multiplies only near the border; a factor of 1 changes nothing elsewhere.
    r2 = r2 * s;
    r3 = r3 * s;
    r4 = r4 * s;
    r5 = r5 * s;
    r6 = r6 * s;
    return array<f32, 5>(r4 * r4 + r6 * r6, (r4 + r5) * r6, r5 * r5 + r6 * r6, r4 * r2 + r6 * r3,
                         r6 * r2 + r5 * r3);
}

// Writes M of texel t of row y (pixels right of the width are clamped to the last one) for the
// flow (u, v) of its four pixels.
fn store_matrices(t: i32, y: i32, u: vec4<f32>, v: vec4<f32>) {
    let w = i32(params.width);
    let h = i32(params.height);
    let x = min(vec4<i32>(4 * t) + vec4<i32>(0, 1, 2, 3), vec4<i32>(w - 1));
    // ((left * right) * top) * bottom, OpenCV's order.
    let by = border_weight(vec4<i32>(y, h - y - 1, 5, 5));
    let s = border_weight(x) * border_weight(vec4<i32>(w - 1) - x) * by.x * by.y;
    let e01 = textureLoad(r0, vec2<i32>(2 * x.x + 1, y));
    let e23 = textureLoad(r0, vec2<i32>(2 * x.z + 1, y));
    let a = matrices(x.x, y, vec2<f32>(u.x, v.x), textureLoad(r0, vec2<i32>(2 * x.x, y)), e01.x, s.x);
    let b = matrices(x.y, y, vec2<f32>(u.y, v.y), textureLoad(r0, vec2<i32>(2 * x.y, y)), e01.y, s.y);
    let c = matrices(x.z, y, vec2<f32>(u.z, v.z), textureLoad(r0, vec2<i32>(2 * x.z, y)), e23.x, s.z);
    let d = matrices(x.w, y, vec2<f32>(u.w, v.w), textureLoad(r0, vec2<i32>(2 * x.w, y)), e23.y, s.w);
    textureStore(m_out, vec2<i32>(7 * t, y), vec4<f32>(a[0], b[0], c[0], d[0]));
    textureStore(m_out, vec2<i32>(7 * t + 1, y), vec4<f32>(a[1], b[1], c[1], d[1]));
    textureStore(m_out, vec2<i32>(7 * t + 2, y), vec4<f32>(a[2], b[2], c[2], d[2]));
    textureStore(m_out, vec2<i32>(7 * t + 3, y), vec4<f32>(a[3], b[3], c[3], d[3]));
    textureStore(m_out, vec2<i32>(7 * t + 4, y), vec4<f32>(a[4], b[4], c[4], d[4]));
}

// ---- start ----

// Pixel i (0..7) of the pair of texels (a, b).
fn pick8(a: vec4<f32>, b: vec4<f32>, i: i32) -> f32 {
    return select(pick(a, u32(i) & 3u), pick(b, u32(i) & 3u), i >= 4);
}

// Component `k` (0: x, 1: y) of the resized flow at the four pixels of texel t in row y.
fn resized(t: i32, y: i32, k: i32) -> vec4<f32> {
    let sw = i32(params.src_w);
    let cy = src_coord(y, params.scale_y, i32(params.src_h));
    let y1 = min(cy.s + 1, i32(params.src_h) - 1);
    let last = i32(params.width) - 1;
    let c0 = src_coord(min(4 * t, last), params.scale_x, sw);
    let c1 = src_coord(min(4 * t + 1, last), params.scale_x, sw);
    let c2 = src_coord(min(4 * t + 2, last), params.scale_x, sw);
    let c3 = src_coord(min(4 * t + 3, last), params.scale_x, sw);
    // The source pixels c0.s .. c3.s + 1 lie in the two texels from c0.s's.
    let base = c0.s >> 2u;
    let lastt = (sw - 1) >> 2u;
    let stride = i32(params.flow_stride);
    let t0 = stride * base + i32(params.flow_offset) + k;
    let t1 = stride * min(base + 1, lastt) + i32(params.flow_offset) + k;
    let a0 = textureLoad(flow_in, vec2<i32>(t0, cy.s));
    let b0 = textureLoad(flow_in, vec2<i32>(t1, cy.s));
    let a1 = textureLoad(flow_in, vec2<i32>(t0, y1));
    let b1 = textureLoad(flow_in, vec2<i32>(t1, y1));
    let s = vec4<i32>(c0.s, c1.s, c2.s, c3.s) - vec4<i32>(4 * base);
    let n = min(vec4<i32>(c0.s, c1.s, c2.s, c3.s) + 1, vec4<i32>(sw - 1)) - vec4<i32>(4 * base);
    let fx = vec4<f32>(c0.f, c1.f, c2.f, c3.f);
    let top = vec4<f32>(pick8(a0, b0, s.x), pick8(a0, b0, s.y), pick8(a0, b0, s.z), pick8(a0, b0, s.w)) * (1.0 - fx)
        + vec4<f32>(pick8(a0, b0, n.x), pick8(a0, b0, n.y), pick8(a0, b0, n.z), pick8(a0, b0, n.w)) * fx;
    let bottom = vec4<f32>(pick8(a1, b1, s.x), pick8(a1, b1, s.y), pick8(a1, b1, s.z), pick8(a1, b1, s.w)) * (1.0 - fx)
        + vec4<f32>(pick8(a1, b1, n.x), pick8(a1, b1, n.y), pick8(a1, b1, n.z), pick8(a1, b1, n.w)) * fx;
    return (top * (1.0 - cy.f) + bottom * cy.f) * params.factor;
}

@compute @workgroup_size(8, 1, 1)
fn start(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = i32(gid.x);
    let y = i32(gid.y);
    if (t >= texels_per_row() || y >= i32(params.height)) {
        return;
    }
    var u = vec4<f32>(0.0);
    var v = vec4<f32>(0.0);
    if (params.mode == 1u) {
        u = resized(t, y, 0);
        v = resized(t, y, 1);
    }
    store_matrices(t, y, u, v);
}

// ---- vertical window ----

// The raw M of texel t (clamped into the row) of row y (clamped into the level); `replicated`
// turns sums of such texels into those of the replicated border.
fn m_at(t: i32, y: i32) -> M4 {
    let yy = clamp(y, 0, i32(params.height) - 1);
    let x = 7 * clamp(t, 0, texels_per_row() - 1);
    return M4(
        textureLoad(m_in, vec2<i32>(x, yy)),
        textureLoad(m_in, vec2<i32>(x + 1, yy)),
        textureLoad(m_in, vec2<i32>(x + 2, yy)),
        textureLoad(m_in, vec2<i32>(x + 3, yy)),
        textureLoad(m_in, vec2<i32>(x + 4, yy)),
    );
}

// Sums of m_at(t, ..) as the sums of texel t with BORDER_REPLICATE (see `replicate4`): a
// selection of components, so fixing the sum equals summing the fixed texels.
fn replicated(s: M4, t: i32) -> M4 {
    let w = i32(params.width);
    return M4(replicate4(s.c0, t, w), replicate4(s.c1, t, w), replicate4(s.c2, t, w),
              replicate4(s.c3, t, w), replicate4(s.c4, t, w));
}

fn store_vs(t: i32, y: i32, v: M4) {
    let s = replicated(v, t);
    let x = 5 * (t + i32(params.halo));
    textureStore(vs_out, vec2<i32>(x, y), s.c0);
    textureStore(vs_out, vec2<i32>(x + 1, y), s.c1);
    textureStore(vs_out, vec2<i32>(x + 2, y), s.c2);
    textureStore(vs_out, vec2<i32>(x + 3, y), s.c3);
    textureStore(vs_out, vec2<i32>(x + 4, y), s.c4);
}

@compute @workgroup_size(8, 1, 1)
fn vbox(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = i32(gid.x) - i32(params.halo);
    let h = i32(params.height);
    let y0 = i32(gid.y * params.strip_rows);
    if (t >= texels_per_row() + i32(params.halo) || y0 >= h) {
        return;
    }
    let y1 = min(y0 + i32(params.strip_rows), h);
    let m = i32(params.radius);
    // The window of row y0 - 1; each row then adds row y + m and drops row y - m - 1.
    var s = m4_zero();
    for (var j = -m; j <= m; j = j + 1) {
        s = m4_add(s, m_at(t, y0 - 1 + j));
    }
    for (var y = y0; y < y1; y = y + 1) {
        s = m4_add(s, m4_sub(m_at(t, y + m), m_at(t, y - m - 1)));
        store_vs(t, y, s);
    }
}

@compute @workgroup_size(8, 1, 1)
fn vgauss(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = i32(gid.x) - i32(params.halo);
    let h = i32(params.height);
    let y0 = i32(gid.y * params.strip_rows);
    if (t >= texels_per_row() + i32(params.halo) || y0 >= h) {
        return;
    }
    let y1 = min(y0 + i32(params.strip_rows), h);
    let m = i32(params.radius);
    for (var y = y0; y < y1; y = y + 1) {
        var s = m4_zero();
        for (var j = -m; j <= m; j = j + 1) {
            s = m4_axpy(tap(j), m_at(t, y + j), s);
        }
        store_vs(t, y, s);
    }
}

// ---- horizontal window, solve ----

// VS of texel t (from -halo to texels + halo - 1) of row y.
fn vs_at(t: i32, y: i32) -> M4 {
    let x = 5 * (t + i32(params.halo));
    return M4(
        textureLoad(vs_in, vec2<i32>(x, y)),
        textureLoad(vs_in, vec2<i32>(x + 1, y)),
        textureLoad(vs_in, vec2<i32>(x + 2, y)),
        textureLoad(vs_in, vec2<i32>(x + 3, y)),
        textureLoad(vs_in, vec2<i32>(x + 4, y)),
    );
}

fn m4_shift(a: M4, b: M4, s: u32) -> M4 {
    return M4(shift4(a.c0, b.c0, s), shift4(a.c1, b.c1, s), shift4(a.c2, b.c2, s),
              shift4(a.c3, b.c3, s), shift4(a.c4, b.c4, s));
}

// Running sums along the four pixels: s + d.x, s + d.x + d.y, ...
fn prefix(s: f32, d: vec4<f32>) -> vec4<f32> {
    let a = s + d.x;
    let b = a + d.y;
    let c = b + d.z;
    return vec4<f32>(a, b, c, c + d.w);
}

// Solves the averaged systems of texel t of row y, then writes M or the flow.
fn solve(t: i32, y: i32, b: M4) {
    let sc = params.scale;
    let g11 = b.c0 * sc;
    let g12 = b.c1 * sc;
    let g22 = b.c2 * sc;
    let h1 = b.c3 * sc;
    let h2 = b.c4 * sc;
    let idet = 1.0 / (g11 * g22 - g12 * g12 + 1e-3);
    let u = (g11 * h2 - g12 * h1) * idet;
    let v = (g22 * h1 - g12 * h2) * idet;
    if (params.last == 0u) {
        store_matrices(t, y, u, v);
    } else if (params.last == 1u) {
        textureStore(m_out, vec2<i32>(7 * t + 5, y), u);
        textureStore(m_out, vec2<i32>(7 * t + 6, y), v);
    } else {
        let w = i32(params.width);
        let o = 2 * (y * w + 4 * t);
        flow_final[o] = u.x;
        flow_final[o + 1] = v.x;
        if (4 * t + 1 < w) {
            flow_final[o + 2] = u.y;
            flow_final[o + 3] = v.y;
        }
        if (4 * t + 2 < w) {
            flow_final[o + 4] = u.z;
            flow_final[o + 5] = v.z;
        }
        if (4 * t + 3 < w) {
            flow_final[o + 6] = u.w;
            flow_final[o + 7] = v.w;
        }
    }
}

// The box window of one run; se = radius & 3 (a constant in each entry point, so the texel
// shifts are swizzles).
fn hbox_run(gid: vec3<u32>, se: u32) {
    let n = texels_per_row();
    let t0 = i32(gid.x * params.run);
    let y = i32(gid.y);
    if (t0 >= n || y >= i32(params.height)) {
        return;
    }
    let t1 = min(t0 + i32(params.run), n);
    let m = i32(params.radius);
    // The window of pixel 4 t0 - 1 (the halo holds the replicated border).
    var s = vec4<f32>(0.0);
    var s4 = 0.0;
    let c = 4 * t0 - 1;
    for (var u = (c - m) >> 2u; u <= (c + m) >> 2u; u = u + 1) {
        let v = vs_at(u, y);
        let p = vec4<i32>(4 * u) + vec4<i32>(0, 1, 2, 3);
        let inside = select(vec4<f32>(0.0), vec4<f32>(1.0), abs(p - vec4<i32>(c)) <= vec4<i32>(m));
        s = s + vec4<f32>(dot(v.c0, inside), dot(v.c1, inside), dot(v.c2, inside), dot(v.c3, inside));
        s4 = s4 + dot(v.c4, inside);
    }
    // Pixel x adds VS at x + m and drops VS at x - m - 1: texel pairs slid one texel per step.
    let sl = 3u - se;
    var e_prev = vs_at((4 * t0 + m) >> 2u, y);
    var l_prev = vs_at((4 * t0 - m - 1) >> 2u, y);
    for (var t = t0; t < t1; t = t + 1) {
        let e_next = vs_at(((4 * t + m) >> 2u) + 1, y);
        let l_next = vs_at(((4 * t - m - 1) >> 2u) + 1, y);
        let d = m4_sub(m4_shift(e_prev, e_next, se), m4_shift(l_prev, l_next, sl));
        let b = M4(prefix(s.x, d.c0), prefix(s.y, d.c1), prefix(s.z, d.c2), prefix(s.w, d.c3),
                   prefix(s4, d.c4));
        s = vec4<f32>(b.c0.w, b.c1.w, b.c2.w, b.c3.w);
        s4 = b.c4.w;
        solve(t, y, b);
        e_prev = e_next;
        l_prev = l_next;
    }
}

@compute @workgroup_size(8, 1, 1)
fn hbox0(@builtin(global_invocation_id) gid: vec3<u32>) {
    hbox_run(gid, 0u);
}

@compute @workgroup_size(8, 1, 1)
fn hbox1(@builtin(global_invocation_id) gid: vec3<u32>) {
    hbox_run(gid, 1u);
}

@compute @workgroup_size(8, 1, 1)
fn hbox2(@builtin(global_invocation_id) gid: vec3<u32>) {
    hbox_run(gid, 2u);
}

@compute @workgroup_size(8, 1, 1)
fn hbox3(@builtin(global_invocation_id) gid: vec3<u32>) {
    hbox_run(gid, 3u);
}

@compute @workgroup_size(8, 1, 1)
fn hgauss(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = texels_per_row();
    let t0 = i32(gid.x * params.run);
    let y = i32(gid.y);
    if (t0 >= n || y >= i32(params.height)) {
        return;
    }
    let t1 = min(t0 + i32(params.run), n);
    let m = i32(params.radius);
    for (var t = t0; t < t1; t = t + 1) {
        var b = m4_zero();
        for (var u = (4 * t - m) >> 2u; u <= (4 * t + 3 + m) >> 2u; u = u + 1) {
            let v = vs_at(u, y);
            // Pixel 4 u + q weighs tap(4 u + q - x) into pixel x = 4 t + i.
            let o = 4 * (u - t);
            let w0 = vec4<f32>(tap(o), tap(o + 1), tap(o + 2), tap(o + 3));
            let w1 = vec4<f32>(tap(o - 1), tap(o), tap(o + 1), tap(o + 2));
            let w2 = vec4<f32>(tap(o - 2), tap(o - 1), tap(o), tap(o + 1));
            let w3 = vec4<f32>(tap(o - 3), tap(o - 2), tap(o - 1), tap(o));
            b.c0 = b.c0 + vec4<f32>(dot(v.c0, w0), dot(v.c0, w1), dot(v.c0, w2), dot(v.c0, w3));
            b.c1 = b.c1 + vec4<f32>(dot(v.c1, w0), dot(v.c1, w1), dot(v.c1, w2), dot(v.c1, w3));
            b.c2 = b.c2 + vec4<f32>(dot(v.c2, w0), dot(v.c2, w1), dot(v.c2, w2), dot(v.c2, w3));
            b.c3 = b.c3 + vec4<f32>(dot(v.c3, w0), dot(v.c3, w1), dot(v.c3, w2), dot(v.c3, w3));
            b.c4 = b.c4 + vec4<f32>(dot(v.c4, w0), dot(v.c4, w1), dot(v.c4, w2), dot(v.c4, w3));
        }
        solve(t, y, b);
    }
}
