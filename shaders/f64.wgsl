// f64.wgsl: IEEE binary64 arithmetic on u32 pairs, so that the device computes the movement
// statistic and the stationary step's decision bit for bit as the host does in f64 (WGSL has no
// f64). A value is vec2<u32>(high word, low word) of its bits. Only what those need: zero and
// normal non-negative operands (the statistic, its scale, the accumulated movement and the
// threshold are all >= 0 and far from the subnormal range), rounded to nearest, ties to even.
// Integer only, so exact on every device. Prepended to the shaders that use it.

const F64_ZERO: vec2<u32> = vec2<u32>(0u, 0u);
const F64_HALF: vec2<u32> = vec2<u32>(0x3fe00000u, 0u);
// A quiet NaN: marks a statistic that could not be taken (non-finite flow).
const F64_NAN: vec2<u32> = vec2<u32>(0x7ff80000u, 0u);

// 64-bit unsigned helpers on (high, low).
fn u64_add(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.y + b.y;
    return vec2<u32>(a.x + b.x + select(0u, 1u, lo < a.y), lo);
}

fn u64_sub(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    return vec2<u32>(a.x - b.x - select(0u, 1u, a.y < b.y), a.y - b.y);
}

fn u64_lt(a: vec2<u32>, b: vec2<u32>) -> bool {
    return a.x < b.x || (a.x == b.x && a.y < b.y);
}

fn u64_shl(a: vec2<u32>, s: u32) -> vec2<u32> {
    if (s == 0u) {
        return a;
    }
    if (s >= 32u) {
        return vec2<u32>(a.y << (s - 32u), 0u);
    }
    return vec2<u32>((a.x << s) | (a.y >> (32u - s)), a.y << s);
}

// a >> s with every bit shifted out ORed into bit 0 (the sticky bit of rounding).
fn u64_shr_sticky(a: vec2<u32>, s: u32) -> vec2<u32> {
    if (s == 0u) {
        return a;
    }
    if (s >= 64u) {
        return vec2<u32>(0u, select(0u, 1u, a.x != 0u || a.y != 0u));
    }
    var r: vec2<u32>;
    var lost: bool;
    if (s >= 32u) {
        let t = s - 32u;
        r = vec2<u32>(0u, a.x >> t);
        lost = a.y != 0u || (t > 0u && (a.x << (32u - t)) != 0u);
    } else {
        r = vec2<u32>(a.x >> s, (a.y >> s) | (a.x << (32u - s)));
        lost = (a.y << (32u - s)) != 0u;
    }
    return vec2<u32>(r.x, r.y | select(0u, 1u, lost));
}

// The full 64-bit product of two u32.
fn mul_wide(a: u32, b: u32) -> vec2<u32> {
    let a0 = a & 0xffffu;
    let a1 = a >> 16u;
    let b0 = b & 0xffffu;
    let b1 = b >> 16u;
    let lo = a0 * b0;
    let mid1 = a1 * b0;
    let mid2 = a0 * b1;
    let hi = a1 * b1;
    var r = vec2<u32>(hi, lo);
    r = u64_add(r, vec2<u32>(mid1 >> 16u, mid1 << 16u));
    r = u64_add(r, vec2<u32>(mid2 >> 16u, mid2 << 16u));
    return r;
}

fn f64_is_zero(a: vec2<u32>) -> bool {
    return a.x == 0u && a.y == 0u;
}

fn f64_exp(a: vec2<u32>) -> u32 {
    return a.x >> 20u;
}

// The 53-bit significand with its implicit bit.
fn f64_sig(a: vec2<u32>) -> vec2<u32> {
    return vec2<u32>((a.x & 0xfffffu) | 0x100000u, a.y);
}

// Packs exponent `e` and a significand `m` carrying 3 extra low bits (guard, round, sticky) in
// [2^55, 2^56), rounding to nearest even.
fn f64_round(e_in: u32, m_in: vec2<u32>) -> vec2<u32> {
    var e = e_in;
    let low = m_in.y & 7u;
    var m = vec2<u32>(m_in.x >> 3u, (m_in.y >> 3u) | (m_in.x << 29u));
    if (low > 4u || (low == 4u && (m.y & 1u) == 1u)) {
        m = u64_add(m, vec2<u32>(0u, 1u));
        if (m.x >= 0x200000u) {
            m = vec2<u32>(m.x >> 1u, (m.y >> 1u) | (m.x << 31u));
            e = e + 1u;
        }
    }
    return vec2<u32>((e << 20u) | (m.x & 0xfffffu), m.y);
}

// A u32 as an f64 (exact).
fn f64_from_u32(n: u32) -> vec2<u32> {
    if (n == 0u) {
        return F64_ZERO;
    }
    let p = 31u - countLeadingZeros(n);
    let m = u64_shl(vec2<u32>(0u, n), 52u - p);
    return vec2<u32>(((1023u + p) << 20u) | (m.x & 0xfffffu), m.y);
}

// The bits of a non-negative f32 as an f64 (exact, subnormal f32 included).
fn f64_from_f32(bits: u32) -> vec2<u32> {
    if (bits == 0u) {
        return F64_ZERO;
    }
    let e = bits >> 23u;
    let f = bits & 0x7fffffu;
    if (e == 0u) {
        let p = 31u - countLeadingZeros(f);
        let m = u64_shl(vec2<u32>(0u, f), 52u - p);
        return vec2<u32>(((p + 874u) << 20u) | (m.x & 0xfffffu), m.y);
    }
    return vec2<u32>(((e + 896u) << 20u) | (f >> 3u), f << 29u);
}

fn f64_add(a_in: vec2<u32>, b_in: vec2<u32>) -> vec2<u32> {
    var a = a_in;
    var b = b_in;
    if (u64_lt(a, b)) {
        a = b_in;
        b = a_in;
    }
    if (f64_is_zero(b)) {
        return a;
    }
    var e = f64_exp(a);
    let ma = u64_shl(f64_sig(a), 3u);
    let mb = u64_shr_sticky(u64_shl(f64_sig(b), 3u), e - f64_exp(b));
    var s = u64_add(ma, mb);
    if (s.x >= 0x1000000u) {
        s = u64_shr_sticky(s, 1u);
        e = e + 1u;
    }
    return f64_round(e, s);
}

fn f64_mul(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    if (f64_is_zero(a) || f64_is_zero(b)) {
        return F64_ZERO;
    }
    var e = f64_exp(a) + f64_exp(b) - 1023u;
    let ma = f64_sig(a);
    let mb = f64_sig(b);
    // 128-bit product in words w3..w0.
    let ll = mul_wide(ma.y, mb.y);
    let lh = mul_wide(ma.y, mb.x);
    let hl = mul_wide(ma.x, mb.y);
    let hh = mul_wide(ma.x, mb.x);
    let w0 = ll.y;
    var mid = u64_add(vec2<u32>(0u, ll.x), vec2<u32>(0u, lh.y));
    mid = u64_add(mid, vec2<u32>(0u, hl.y));
    let w1 = mid.y;
    var top = u64_add(hh, vec2<u32>(0u, mid.x));
    top = u64_add(top, vec2<u32>(0u, lh.x));
    top = u64_add(top, vec2<u32>(0u, hl.x));
    let w2 = top.y;
    let w3 = top.x;
    // The product is in [2^104, 2^106): keep 56 bits from bit `s` up, the rest sticky.
    var s = 49u;
    if ((w3 & 0x200u) != 0u) {
        s = 50u;
        e = e + 1u;
    }
    let t = s - 32u;
    let lo = (w1 >> t) | (w2 << (32u - t));
    let hi = (w2 >> t) | (w3 << (32u - t));
    let lost = w0 != 0u || (w1 << (32u - t)) != 0u;
    return f64_round(e, vec2<u32>(hi, lo | select(0u, 1u, lost)));
}

// a / b for b > 0.
fn f64_div(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    if (f64_is_zero(a)) {
        return F64_ZERO;
    }
    var e = f64_exp(a) + 1023u - f64_exp(b);
    var r = f64_sig(a);
    let d = f64_sig(b);
    if (u64_lt(r, d)) {
        r = u64_shl(r, 1u);
        e = e - 1u;
    }
    // 56 quotient bits by long division: 53 significant ones plus guard, round and sticky.
    var q = vec2<u32>(0u, 0u);
    for (var k = 0u; k < 56u; k = k + 1u) {
        q = u64_shl(q, 1u);
        if (!u64_lt(r, d)) {
            r = u64_sub(r, d);
            q.y = q.y | 1u;
        }
        r = u64_shl(r, 1u);
    }
    q.y = q.y | select(0u, 1u, !f64_is_zero(r));
    return f64_round(e, q);
}

// a >= b (non-negative values order like their bits).
fn f64_ge(a: vec2<u32>, b: vec2<u32>) -> bool {
    return !u64_lt(a, b);
}
