// border.wgsl (prelude of the Farneback and strip shaders): border rules and the helpers of images stored
// four pixels to a texel (texel t of a row holds pixels 4 t .. 4 t + 3, one per component).

// OpenCV's BORDER_REFLECT_101 for one reflection (|i| and i - n below n).
fn reflect101(i: i32, n: i32) -> i32 {
    if (n == 1) {
        return 0;
    }
    var j = i;
    if (j < 0) {
        j = -j;
    }
    if (j >= n) {
        j = 2 * n - 2 - j;
    }
    return j;
}

// The four pixels starting `s` (0..3) pixels into texel `a`, continuing into texel `b`. With a
// constant `s` (after inlining) this is one swizzle.
fn shift4(a: vec4<f32>, b: vec4<f32>, s: u32) -> vec4<f32> {
    let s1 = vec4<f32>(a.yzw, b.x);
    let s2 = vec4<f32>(a.zw, b.xy);
    let s3 = vec4<f32>(a.w, b.xyz);
    return select(select(select(a, s1, s == 1u), s2, s == 2u), s3, s == 3u);
}

// Component `c` (0..3) of `v` by selects (no dynamic indexing).
fn pick(v: vec4<f32>, c: u32) -> f32 {
    return select(select(select(v.x, v.y, c == 1u), v.z, c == 2u), v.w, c == 3u);
}

// Texel `t` of a row of `w` pixels with BORDER_REPLICATE beyond the row: texels left of the row
// repeat pixel 0 (component x of texel 0, `v` when t < 0), pixels at and right of `w` repeat
// pixel w - 1 (`v` is then the row's last texel, fetched with t clamped). Branch free: llvmpipe
// runs both sides of a branch that differs between lanes.
fn replicate4(v: vec4<f32>, t: i32, w: i32) -> vec4<f32> {
    let p = vec4<i32>(4 * t) + vec4<i32>(0, 1, 2, 3);
    let c = select(u32(w - 1) & 3u, 0u, t < 0);
    return select(v, vec4<f32>(pick(v, c)), p >= vec4<i32>(w) | vec4<bool>(t < 0));
}

// cv::resize INTER_LINEAR: source index `s` and weight `f` of the next one for destination index
// `d` (source pixels per destination pixel `scale`, `n` source pixels; clamped at both ends).
struct Coord {
    s: i32,
    f: f32,
}

fn src_coord(d: i32, scale: f32, n: i32) -> Coord {
    let fd = (f32(d) + 0.5) * scale - 0.5;
    var c = Coord(i32(floor(fd)), fd - floor(fd));
    if (c.s < 0) {
        c = Coord(0, 0.0);
    }
    if (c.s >= n - 1) {
        c = Coord(n - 1, 0.0);
    }
    return c;
}
