// strip.wgsl (prelude of tenengrad.wgsl and laplacian.wgsl, after border.wgsl): an 8-bit BGR frame read as a texture
// in strips of 16 pixels, converted to gray in registers; no shared memory, no barrier.
// Frame layout: texture_2d<u32> Rgba32Uint, one texture row per frame row; row y's 3 * width bytes
// (B, G, R per pixel, little-endian words x, y, z, w) fill its texels from texel 0, the rest of
// the last texel is padding. Pixels [16 k, 16 k + 16) start on texel 3 k (48 bytes = 3 texels).
// Gray: OpenCV's fixed-point formula, gray = (3735 B + 19235 G + 9798 R + 16384) >> 15
// (cv::cvtColor COLOR_BGR2GRAY for 8-bit: BY15, GY15, RY15, gray_shift 15), bit-exact.
// Borders: BORDER_REFLECT_101 (OpenCV's default) on both axes.
// Strip: an invocation owns the 16 columns [16 k, 16 k + 16) of `strip_rows` rows and slides a
// window of three gray rows down them (each row read once, plus one row above and below).
// Twin: src/kernels/gray.rs `opencv` (cv::cvtColor), src/kernels/strip.rs (layout and upload).

struct StripParams {
    width: u32,
    height: u32,
    // Rows per invocation (the strip shape; chosen per adapter, see src/kernels/strip.rs).
    strip_rows: u32,
    // u32 words per row of the packed gray output (4 pixels per word).
    stride: u32,
    // laplacian.wgsl only: aperture 1 or 3.
    ksize: u32,
    // 1: also write the gray image to `gray` (for resize_area and checks).
    write_gray: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var frame: texture_2d<u32>;
@group(0) @binding(1) var<storage, read_write> totals: array<atomic<u32>>;
@group(0) @binding(2) var<uniform> params: StripParams;
@group(0) @binding(3) var<storage, read_write> gray: array<u32>;

// One row of a strip in gray: `l` and `r` the left and right neighbours (pixels 16 k - 1 and
// 16 k + 16), p0..p3 pixels 16 k .. 16 k + 15, four per vector.
struct Row {
    l: u32,
    p0: vec4<u32>,
    p1: vec4<u32>,
    p2: vec4<u32>,
    p3: vec4<u32>,
    r: u32,
}

// The row as signed vectors of left neighbours (l*), pixels (p*) and right neighbours (r*).
struct Span {
    l0: vec4<i32>, l1: vec4<i32>, l2: vec4<i32>, l3: vec4<i32>,
    p0: vec4<i32>, p1: vec4<i32>, p2: vec4<i32>, p3: vec4<i32>,
    r0: vec4<i32>, r1: vec4<i32>, r2: vec4<i32>, r3: vec4<i32>,
}

// The right border of the strip holding the frame's last column: `n` = width - 16 k (the
// position of x = width, whose value mirrors x = width - 2), and which pixels lie inside.
struct Edge {
    n: i32,
    in0: vec4<u32>, in1: vec4<u32>, in2: vec4<u32>, in3: vec4<u32>,
    at0: vec4<bool>, at1: vec4<bool>, at2: vec4<bool>, at3: vec4<bool>,
}

fn edge_of(k: i32) -> Edge {
    let n = i32(params.width) - 16 * k;
    let v = vec4<i32>(n);
    let q = vec4<i32>(0, 1, 2, 3);
    let one = vec4<u32>(1u);
    let zero = vec4<u32>(0u);
    return Edge(
        n,
        select(zero, one, q < v), select(zero, one, q + 4 < v),
        select(zero, one, q + 8 < v), select(zero, one, q + 12 < v),
        q == v, q + 4 == v, q + 8 == v, q + 12 == v,
    );
}

// Gray of four pixels packed in three words (12 bytes B G R B G R ...).
fn gray4(a: u32, b: u32, c: u32) -> vec4<u32> {
    let m = vec4<u32>(0xffu);
    let bl = vec4<u32>(a, a >> 24u, b >> 16u, c >> 8u) & m;
    let gr = vec4<u32>(a >> 8u, b, b >> 24u, c >> 16u) & m;
    let rd = vec4<u32>(a >> 16u, b >> 8u, c, c >> 24u) & m;
    return (bl * 3735u + gr * 19235u + rd * 9798u + vec4<u32>(16384u)) >> vec4<u32>(15u);
}

fn gray1(a: u32) -> u32 {
    return ((a & 0xffu) * 3735u + ((a >> 8u) & 0xffu) * 19235u + ((a >> 16u) & 0xffu) * 9798u
        + 16384u) >> 15u;
}

// Row y of strip k in gray (texels 3 k - 1 .. 3 k + 3), BORDER_REFLECT_101 at both ends of the
// frame row; values right of the mirrored x = width are undefined.
fn gray_row(k: i32, y: i32, e: Edge) -> Row {
    let last = i32(textureDimensions(frame).x) - 1;
    let t0 = textureLoad(frame, vec2<i32>(max(3 * k - 1, 0), y), 0);
    let t1 = textureLoad(frame, vec2<i32>(min(3 * k, last), y), 0);
    let t2 = textureLoad(frame, vec2<i32>(min(3 * k + 1, last), y), 0);
    let t3 = textureLoad(frame, vec2<i32>(min(3 * k + 2, last), y), 0);
    let t4 = textureLoad(frame, vec2<i32>(min(3 * k + 3, last), y), 0);
    var row = Row(
        gray1(t0.w >> 8u),
        gray4(t1.x, t1.y, t1.z),
        gray4(t1.w, t2.x, t2.y),
        gray4(t2.z, t2.w, t3.x),
        gray4(t3.y, t3.z, t3.w),
        gray1(t4.x),
    );
    if (k == 0) {
        // x = -1 mirrors x = 1 (x = 0 when the frame is one pixel wide).
        row.l = select(row.p0.y, row.p0.x, params.width == 1u);
    }
    if (e.n < 16) {
        // x = width takes the value of x = width - 2 (two places to the left).
        row.p0 = select(row.p0, vec4<u32>(0u, row.l, row.p0.xy), e.at0);
        row.p1 = select(row.p1, vec4<u32>(row.p0.zw, row.p1.xy), e.at1);
        row.p2 = select(row.p2, vec4<u32>(row.p1.zw, row.p2.xy), e.at2);
        row.p3 = select(row.p3, vec4<u32>(row.p2.zw, row.p3.xy), e.at3);
    } else if (e.n == 16) {
        row.r = row.p3.z;
    }
    return row;
}

fn span(r: Row) -> Span {
    let p0 = vec4<i32>(r.p0);
    let p1 = vec4<i32>(r.p1);
    let p2 = vec4<i32>(r.p2);
    let p3 = vec4<i32>(r.p3);
    let l = i32(r.l);
    let rr = i32(r.r);
    return Span(
        vec4<i32>(l, p0.xyz), vec4<i32>(p0.w, p1.xyz),
        vec4<i32>(p1.w, p2.xyz), vec4<i32>(p2.w, p3.xyz),
        p0, p1, p2, p3,
        vec4<i32>(p0.yzw, p1.x), vec4<i32>(p1.yzw, p2.x),
        vec4<i32>(p2.yzw, p3.x), vec4<i32>(p3.yzw, rr),
    );
}

fn pack(p: vec4<u32>) -> u32 {
    return p.x | (p.y << 8u) | (p.z << 16u) | (p.w << 24u);
}

// Writes pixels 16 k .. 16 k + 15 of row y to the packed gray image.
fn write_gray_row(k: i32, y: i32, r: Row) {
    let base = u32(y) * params.stride;
    let word = u32(k) * 4u;
    gray[base + word] = pack(r.p0);
    if (word + 1u < params.stride) {
        gray[base + word + 1u] = pack(r.p1);
    }
    if (word + 2u < params.stride) {
        gray[base + word + 2u] = pack(r.p2);
    }
    if (word + 3u < params.stride) {
        gray[base + word + 3u] = pack(r.p3);
    }
}

// Adds `v` to the 64-bit total at totals[index] (low word, carry into index + 1).
fn add64(index: u32, v: u32) {
    let old = atomicAdd(&totals[index], v);
    if (old + v < old) {
        atomicAdd(&totals[index + 1u], 1u);
    }
}

// Adds `v` to the 64-bit register total (lo, hi).
fn acc64(t: vec2<u32>, v: u32) -> vec2<u32> {
    let lo = t.x + v;
    return vec2<u32>(lo, t.y + select(0u, 1u, lo < v));
}

// Adds a 64-bit register total to the 64-bit total at totals[index].
fn add64x2(index: u32, t: vec2<u32>) {
    add64(index, t.x);
    if (t.y > 0u) {
        atomicAdd(&totals[index + 1u], t.y);
    }
}
