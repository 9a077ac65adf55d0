// farneback_pyramid.wgsl (after border.wgsl): one frame's pyramid of polynomial expansions as
// cv::calcOpticalFlowFarneback computes it: level k is the full-resolution image smoothed by
// cv::GaussianBlur (CV_32F, BORDER_REFLECT_101, the level's kernel) and resized by cv::resize
// (INTER_LINEAR); its expansion is FarnebackPolyExp (BORDER_REPLICATE). No shared memory, no
// barrier: textures hold four pixels per texel and each invocation keeps its window in registers.
// Entry points:
// - `level0`: gray (u8, 4 per word, rows unpadded) -> level 0 (3x3 kernel [1 2 1]/4, exact in
//   f32) and the gray as a texture for the smaller levels; strips of 16 pixels x strip_rows rows
//   sliding a three-row window. Dispatch ceil(ceil(w / 16) / 8) x ceil(h / strip_rows).
// - `vsmooth` (level k > 0): the vertical part of the smoothing at the two source rows each
//   destination row interpolates (sy and sy + 1), all columns. Dispatch ceil(ceil(w / 4) / 8) x h_k.
// - `hsmooth` (level k > 0): the horizontal part at the two source columns of each destination
//   pixel, then the bilinear weights; the horizontal tap loop covers both columns at once.
//   Dispatch ceil((ceil(w_k / 4) + 2 HALO) / 8) x h_k.
// - `polyexp5`, `polyexp7` (n): the expansion of one level in strips of 16 pixels x strip_rows
//   rows: per row the vertical sums of 32 pixels, then the horizontal taps (unrolled, constant
//   offsets). Dispatch ceil(ceil(w_k / 16) / 8) x ceil(h_k / strip_rows).
// Level images (`out4` of level0 / hsmooth, `src` of polyexp*) carry HALO texels left and right
// repeating the border pixels, and their pixels right of the width repeat the last one, so the
// expansion reads its 7 neighbours without tests. Expansion R (`out4` of polyexp*): texel 2 x =
// channels 0..3 of pixel x ([r_y, r_x, r_yy, r_xx] in OpenCV's order), texel 2 x + 1 = channel 4
// (r_xy) of pixel x and of its right neighbour (the bilinear sampling of the flow update reads
// both at once).
// Twin: cv::calcOpticalFlowFarneback (src/kernels/farneback.rs `opencv`).

struct PyrParams {
    // Full-resolution size.
    src_w: u32,
    src_h: u32,
    // This level's size.
    dst_w: u32,
    dst_h: u32,
    // Smoothing radius (taps w[0..=radius], w[radius + 1] = 0).
    radius: u32,
    strip_rows: u32,
    // Polynomial expansion half-size n (5 or 7).
    poly_n: u32,
    pad0: u32,
    // cv::resize's source step per destination pixel (src / dst).
    scale_x: f32,
    scale_y: f32,
    pad1: f32,
    pad2: f32,
    // ig11, ig03, ig33, ig55 of FarnebackPrepareGaussian.
    ig: vec4<f32>,
    // Tap k = 0..7: (g, xg, xxg) of the expansion, zero for k > n.
    poly: array<vec4<f32>, 8>,
}

// Smoothing taps from the centre out, one per element (x).
struct Taps {
    w: array<vec4<f32>, 1024>,
}

const HALO: i32 = 2;

@group(0) @binding(0) var<storage, read> gray: array<u32>;
@group(0) @binding(1) var out4: texture_storage_2d<rgba32float, write>;
@group(0) @binding(2) var out_gray: texture_storage_2d<rgba8uint, write>;
@group(0) @binding(3) var gray_tex: texture_storage_2d<rgba8uint, read>;
@group(0) @binding(4) var src: texture_storage_2d<rgba32float, read>;
@group(0) @binding(6) var<uniform> params: PyrParams;
@group(0) @binding(7) var<uniform> taps: Taps;

// ---- level0 ----

// Gray pixels 16 k .. 16 k + 15 of a row (p0..p3) and their left (l) and right (r) neighbours.
struct GrayRow {
    l: f32,
    p0: vec4<f32>,
    p1: vec4<f32>,
    p2: vec4<f32>,
    p3: vec4<f32>,
    r: f32,
}

fn unpack4(w: u32) -> vec4<f32> {
    return vec4<f32>(vec4<u32>(w, w >> 8u, w >> 16u, w >> 24u) & vec4<u32>(0xffu));
}

// Bytes 4 j .. 4 j + 3 after a shift of `s` bits (0, 8, 16, 24) of the word pair (a, b).
fn realign(a: u32, b: u32, s: u32) -> u32 {
    return select((a >> s) | (b << (32u - s)), a, s == 0u);
}

// Row y of strip k, BORDER_REFLECT_101 at both ends (x = -1 mirrors x = 1, x = w mirrors
// x = w - 2); pixels right of x = w are undefined.
fn gray_row(k: i32, y: i32) -> GrayRow {
    let w = i32(params.src_w);
    let base = u32(y) * params.src_w + u32(16 * k);
    let wb = base >> 2u;
    let s = (base & 3u) * 8u;
    let w0 = gray[wb];
    let w1 = gray[wb + 1u];
    let w2 = gray[wb + 2u];
    let w3 = gray[wb + 3u];
    let w4 = gray[wb + 4u];
    var row = GrayRow(
        0.0,
        unpack4(realign(w0, w1, s)),
        unpack4(realign(w1, w2, s)),
        unpack4(realign(w2, w3, s)),
        unpack4(realign(w3, w4, s)),
        f32((w4 >> s) & 0xffu),
    );
    if (k > 0) {
        let lb = base - 1u;
        row.l = f32((gray[lb >> 2u] >> ((lb & 3u) * 8u)) & 0xffu);
    } else {
        row.l = select(row.p0.y, row.p0.x, w == 1);
    }
    let n = w - 16 * k;
    if (n < 16) {
        let v = vec4<i32>(n);
        let q = vec4<i32>(0, 1, 2, 3);
        row.p0 = select(row.p0, vec4<f32>(0.0, row.l, row.p0.xy), q == v);
        row.p1 = select(row.p1, vec4<f32>(row.p0.zw, row.p1.xy), q + 4 == v);
        row.p2 = select(row.p2, vec4<f32>(row.p1.zw, row.p2.xy), q + 8 == v);
        row.p3 = select(row.p3, vec4<f32>(row.p2.zw, row.p3.xy), q + 12 == v);
    } else if (n == 16) {
        row.r = row.p3.z;
    }
    return row;
}

// 1 2 1 sums along the row (exact integers in f32).
fn row121(g: GrayRow) -> array<vec4<f32>, 4> {
    return array<vec4<f32>, 4>(
        vec4<f32>(g.l, g.p0.xyz) + 2.0 * g.p0 + vec4<f32>(g.p0.yzw, g.p1.x),
        vec4<f32>(g.p0.w, g.p1.xyz) + 2.0 * g.p1 + vec4<f32>(g.p1.yzw, g.p2.x),
        vec4<f32>(g.p1.w, g.p2.xyz) + 2.0 * g.p2 + vec4<f32>(g.p2.yzw, g.p3.x),
        vec4<f32>(g.p2.w, g.p3.xyz) + 2.0 * g.p3 + vec4<f32>(g.p3.yzw, g.r),
    );
}

// Stores texel i (0..3) of strip k of row y: the level image and the gray.
fn store_level0(k: i32, y: i32, i: i32, v: vec4<f32>, g: vec4<f32>) {
    let t = 4 * k + i;
    if (t < (i32(params.src_w) + 3) / 4) {
        textureStore(out4, vec2<i32>(t + HALO, y), replicate4(v, t, i32(params.src_w)));
        textureStore(out_gray, vec2<i32>(t, y), vec4<u32>(g));
    }
}

// The level image's halo of row y: `first` (pixel 0) left, `last` (pixel w - 1) right; stored
// by the strips holding those pixels.
fn store_halo(k: i32, y: i32, first: f32, last: f32) {
    let w = i32(params.src_w);
    let w4 = (w + 3) / 4;
    if (k == 0) {
        textureStore(out4, vec2<i32>(0, y), vec4<f32>(first));
        textureStore(out4, vec2<i32>(1, y), vec4<f32>(first));
    }
    if ((w - 1) / 16 == k) {
        textureStore(out4, vec2<i32>(w4 + HALO, y), vec4<f32>(last));
        textureStore(out4, vec2<i32>(w4 + HALO + 1, y), vec4<f32>(last));
    }
}

// Pixel i (0..15) of four texels.
fn pick16(a: vec4<f32>, b: vec4<f32>, c: vec4<f32>, d: vec4<f32>, i: u32) -> f32 {
    let q = i & 3u;
    return select(select(pick(a, q), pick(b, q), i >= 4u), select(pick(c, q), pick(d, q), i >= 12u),
                  i >= 8u);
}

@compute @workgroup_size(8, 1, 1)
fn level0(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = i32(gid.x);
    let h = i32(params.src_h);
    let y0 = i32(gid.y * params.strip_rows);
    if (16 * k >= i32(params.src_w) || y0 >= h) {
        return;
    }
    let y1 = min(y0 + i32(params.strip_rows), h);
    var a = row121(gray_row(k, reflect101(y0 - 1, h)));
    var mid = gray_row(k, y0);
    var b = row121(mid);
    for (var y = y0; y < y1; y = y + 1) {
        let below = gray_row(k, reflect101(y + 1, h));
        let c = row121(below);
        let s = 1.0 / 16.0;
        let v0 = (a[0] + 2.0 * b[0] + c[0]) * s;
        let v1 = (a[1] + 2.0 * b[1] + c[1]) * s;
        let v2 = (a[2] + 2.0 * b[2] + c[2]) * s;
        let v3 = (a[3] + 2.0 * b[3] + c[3]) * s;
        store_level0(k, y, 0, v0, mid.p0);
        store_level0(k, y, 1, v1, mid.p1);
        store_level0(k, y, 2, v2, mid.p2);
        store_level0(k, y, 3, v3, mid.p3);
        store_halo(k, y, v0.x, pick16(v0, v1, v2, v3, u32(i32(params.src_w) - 1 - 16 * k) & 15u));
        a = b;
        b = c;
        mid = below;
    }
}

// ---- vsmooth, hsmooth ----

fn tap(i: i32) -> f32 {
    return taps.w[abs(i)].x;
}

@compute @workgroup_size(8, 1, 1)
fn vsmooth(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = i32(gid.x);
    let dy = i32(gid.y);
    if (t >= (i32(params.src_w) + 3) / 4 || dy >= i32(params.dst_h)) {
        return;
    }
    let h = i32(params.src_h);
    let c = src_coord(dy, params.scale_y, h);
    let r = i32(params.radius);
    var s0 = vec4<f32>(0.0);
    var s1 = vec4<f32>(0.0);
    for (var u = -r; u <= r + 1; u = u + 1) {
        let g = vec4<f32>(textureLoad(gray_tex, vec2<i32>(t, reflect101(c.s + u, h))));
        s0 = s0 + tap(u) * g;
        s1 = s1 + tap(u - 1) * g;
    }
    textureStore(out4, vec2<i32>(t, 2 * dy), s0);
    textureStore(out4, vec2<i32>(t, 2 * dy + 1), s1);
}

// Pixel p of row `row` of the vertical smoothing.
fn vert_at(p: i32, row: i32) -> f32 {
    return pick(textureLoad(src, vec2<i32>(p >> 2u, row)), u32(p) & 3u);
}

@compute @workgroup_size(8, 1, 1)
fn hsmooth(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = i32(gid.x) - HALO;
    let dy = i32(gid.y);
    let dw = i32(params.dst_w);
    if (t >= (dw + 3) / 4 + HALO || dy >= i32(params.dst_h)) {
        return;
    }
    let w = i32(params.src_w);
    let cy = src_coord(dy, params.scale_y, i32(params.src_h));
    let d = clamp(vec4<i32>(4 * t) + vec4<i32>(0, 1, 2, 3), vec4<i32>(0), vec4<i32>(dw - 1));
    let c0 = src_coord(d.x, params.scale_x, w);
    let c1 = src_coord(d.y, params.scale_x, w);
    let c2 = src_coord(d.z, params.scale_x, w);
    let c3 = src_coord(d.w, params.scale_x, w);
    let sx = vec4<i32>(c0.s, c1.s, c2.s, c3.s);
    let fx = vec4<f32>(c0.f, c1.f, c2.f, c3.f);
    let r = i32(params.radius);
    // Row sy at columns sx (a0) and sx + 1 (a1); row sy + 1 likewise (b0, b1).
    var a0 = vec4<f32>(0.0);
    var a1 = vec4<f32>(0.0);
    var b0 = vec4<f32>(0.0);
    var b1 = vec4<f32>(0.0);
    let ra = 2 * dy;
    for (var u = -r; u <= r + 1; u = u + 1) {
        let p = vec4<i32>(
            reflect101(sx.x + u, w),
            reflect101(sx.y + u, w),
            reflect101(sx.z + u, w),
            reflect101(sx.w + u, w),
        );
        let va = vec4<f32>(vert_at(p.x, ra), vert_at(p.y, ra), vert_at(p.z, ra), vert_at(p.w, ra));
        let vb = vec4<f32>(
            vert_at(p.x, ra + 1),
            vert_at(p.y, ra + 1),
            vert_at(p.z, ra + 1),
            vert_at(p.w, ra + 1),
        );
        let wa = tap(u);
        let wb = tap(u - 1);
        a0 = a0 + wa * va;
        a1 = a1 + wb * va;
        b0 = b0 + wa * vb;
        b1 = b1 + wb * vb;
    }
    let top = a0 * (1.0 - fx) + a1 * fx;
    let bottom = b0 * (1.0 - fx) + b1 * fx;
    textureStore(out4, vec2<i32>(t + HALO, dy), top * (1.0 - cy.f) + bottom * cy.f);
}

// ---- polyexp ----

// 32 pixels of one row: span texels 0..7 = level texels 4 j - 2 .. 4 j + 5 of strip j.
struct Span {
    t0: vec4<f32>,
    t1: vec4<f32>,
    t2: vec4<f32>,
    t3: vec4<f32>,
    t4: vec4<f32>,
    t5: vec4<f32>,
    t6: vec4<f32>,
    t7: vec4<f32>,
}

// Vertical sums of a span: g-, xg- and xxg-weighted (OpenCV's row[3 x], row[3 x + 1], row[3 x + 2]).
struct Vert {
    g: Span,
    xg: Span,
    xxg: Span,
}

fn span_texel(s: Span, i: u32) -> vec4<f32> {
    switch i {
        case 0u: { return s.t0; }
        case 1u: { return s.t1; }
        case 2u: { return s.t2; }
        case 3u: { return s.t3; }
        case 4u: { return s.t4; }
        case 5u: { return s.t5; }
        case 6u: { return s.t6; }
        default: { return s.t7; }
    }
}

// Span pixels off .. off + 3 (off constant after inlining; texel 8 reads as texel 7).
fn px4(s: Span, off: u32) -> vec4<f32> {
    return shift4(span_texel(s, off >> 2u), span_texel(s, (off >> 2u) + 1u), off & 3u);
}

fn load_span(j: i32, y: i32) -> Span {
    let last = i32(textureDimensions(src).x) - 1;
    let x = 4 * j;
    return Span(
        textureLoad(src, vec2<i32>(min(x, last), y)),
        textureLoad(src, vec2<i32>(min(x + 1, last), y)),
        textureLoad(src, vec2<i32>(min(x + 2, last), y)),
        textureLoad(src, vec2<i32>(min(x + 3, last), y)),
        textureLoad(src, vec2<i32>(min(x + 4, last), y)),
        textureLoad(src, vec2<i32>(min(x + 5, last), y)),
        textureLoad(src, vec2<i32>(min(x + 6, last), y)),
        textureLoad(src, vec2<i32>(min(x + 7, last), y)),
    );
}

fn span_axpy(a: f32, x: Span, y: Span) -> Span {
    return Span(
        y.t0 + a * x.t0, y.t1 + a * x.t1, y.t2 + a * x.t2, y.t3 + a * x.t3,
        y.t4 + a * x.t4, y.t5 + a * x.t5, y.t6 + a * x.t6, y.t7 + a * x.t7,
    );
}

fn span_add(a: Span, b: Span) -> Span {
    return Span(a.t0 + b.t0, a.t1 + b.t1, a.t2 + b.t2, a.t3 + b.t3,
                a.t4 + b.t4, a.t5 + b.t5, a.t6 + b.t6, a.t7 + b.t7);
}

fn span_sub(a: Span, b: Span) -> Span {
    return Span(a.t0 - b.t0, a.t1 - b.t1, a.t2 - b.t2, a.t3 - b.t3,
                a.t4 - b.t4, a.t5 - b.t5, a.t6 - b.t6, a.t7 - b.t7);
}

fn span_scale(a: f32, x: Span) -> Span {
    return Span(a * x.t0, a * x.t1, a * x.t2, a * x.t3, a * x.t4, a * x.t5, a * x.t6, a * x.t7);
}

// The vertical part for row y of strip j (OpenCV's order: centre, then pairs k = 1..n).
fn vertical(j: i32, y: i32) -> Vert {
    let h = i32(params.dst_h);
    let c = load_span(j, y);
    var v = Vert(span_scale(params.poly[0].x, c), span_scale(0.0, c), span_scale(0.0, c));
    for (var k = 1; k <= i32(params.poly_n); k = k + 1) {
        let wk = params.poly[k];
        let top = load_span(j, max(y - k, 0));
        let bottom = load_span(j, min(y + k, h - 1));
        let p = span_add(top, bottom);
        v = Vert(span_axpy(wk.x, p, v.g), span_axpy(wk.y, span_sub(bottom, top), v.xg),
                 span_axpy(wk.z, p, v.xxg));
    }
    return v;
}

// Horizontal sums b1..b6 of four pixels (OpenCV's names; b1 ~ 1, b2 ~ x, b3 ~ y, b4 ~ x^2,
// b5 ~ y^2, b6 ~ xy).
struct Sums {
    b1: vec4<f32>,
    b2: vec4<f32>,
    b3: vec4<f32>,
    b4: vec4<f32>,
    b5: vec4<f32>,
    b6: vec4<f32>,
}

// Adds horizontal tap k (constant) of the pixels at span offset c.
fn htap(b: Sums, v: Vert, c: u32, k: u32) -> Sums {
    let w = params.poly[k];
    let r0 = px4(v.g, c + k);
    let l0 = px4(v.g, c - k);
    let r1 = px4(v.xg, c + k);
    let l1 = px4(v.xg, c - k);
    let r2 = px4(v.xxg, c + k);
    let l2 = px4(v.xxg, c - k);
    let tg = r0 + l0;
    return Sums(
        b.b1 + tg * w.x,
        b.b2 + (r0 - l0) * w.y,
        b.b3 + (r1 + l1) * w.x,
        b.b4 + tg * w.z,
        b.b5 + (r2 + l2) * w.x,
        b.b6 + (r1 - l1) * w.y,
    );
}

// b1..b6 of the four pixels at span offset c (constant) for n = 5 or 7 (constant).
fn horizontal(v: Vert, c: u32, n: u32) -> Sums {
    let g0 = params.poly[0].x;
    var b = Sums(px4(v.g, c) * g0, vec4<f32>(0.0), px4(v.xg, c) * g0, vec4<f32>(0.0),
                 px4(v.xxg, c) * g0, vec4<f32>(0.0));
    b = htap(b, v, c, 1u);
    b = htap(b, v, c, 2u);
    b = htap(b, v, c, 3u);
    b = htap(b, v, c, 4u);
    b = htap(b, v, c, 5u);
    if (n == 7u) {
        b = htap(b, v, c, 6u);
        b = htap(b, v, c, 7u);
    }
    return b;
}

// Writes the expansion of the four pixels x0 .. x0 + 3 of row y; `next4` is channel 4 of the
// pixel right of them.
fn store_r(x0: i32, y: i32, b: Sums, next4: f32) {
    let ig = params.ig;
    let c0 = b.b3 * ig.x;
    let c1 = b.b2 * ig.x;
    let c2 = b.b1 * ig.y + b.b5 * ig.z;
    let c3 = b.b1 * ig.y + b.b4 * ig.z;
    let c4 = b.b6 * ig.w;
    let w = i32(params.dst_w);
    store_px(x0, y, vec4<f32>(c0.x, c1.x, c2.x, c3.x), vec4<f32>(c4.x, c4.y, 0.0, 0.0));
    if (x0 + 1 < w) {
        store_px(x0 + 1, y, vec4<f32>(c0.y, c1.y, c2.y, c3.y), vec4<f32>(c4.y, c4.z, 0.0, 0.0));
    }
    if (x0 + 2 < w) {
        store_px(x0 + 2, y, vec4<f32>(c0.z, c1.z, c2.z, c3.z), vec4<f32>(c4.z, c4.w, 0.0, 0.0));
    }
    if (x0 + 3 < w) {
        store_px(x0 + 3, y, vec4<f32>(c0.w, c1.w, c2.w, c3.w), vec4<f32>(c4.w, next4, 0.0, 0.0));
    }
}

fn store_px(x: i32, y: i32, a: vec4<f32>, b: vec4<f32>) {
    textureStore(out4, vec2<i32>(2 * x, y), a);
    textureStore(out4, vec2<i32>(2 * x + 1, y), b);
}

@compute @workgroup_size(8, 1, 1)
fn polyexp5(@builtin(global_invocation_id) gid: vec3<u32>) {
    polyexp_strip(gid, 5u);
}

@compute @workgroup_size(8, 1, 1)
fn polyexp7(@builtin(global_invocation_id) gid: vec3<u32>) {
    polyexp_strip(gid, 7u);
}

// The expansion of one strip for n = 5 or 7 (constant in each entry point).
fn polyexp_strip(gid: vec3<u32>, n: u32) {
    let j = i32(gid.x);
    let w = i32(params.dst_w);
    let h = i32(params.dst_h);
    let y0 = i32(gid.y * params.strip_rows);
    if (16 * j >= w || y0 >= h) {
        return;
    }
    let y1 = min(y0 + i32(params.strip_rows), h);
    let x0 = 16 * j;
    for (var y = y0; y < y1; y = y + 1) {
        let v = vertical(j, y);
        let b0 = horizontal(v, 8u, n);
        let b1 = horizontal(v, 12u, n);
        let b2 = horizontal(v, 16u, n);
        let b3 = horizontal(v, 20u, n);
        let next = horizontal(v, 24u, n).b6.x * params.ig.w;
        store_r(x0, y, b0, b1.b6.x * params.ig.w);
        if (x0 + 4 < w) {
            store_r(x0 + 4, y, b1, b2.b6.x * params.ig.w);
        }
        if (x0 + 8 < w) {
            store_r(x0 + 8, y, b2, b3.b6.x * params.ig.w);
        }
        if (x0 + 12 < w) {
            store_r(x0 + 12, y, b3, next);
        }
    }
}
