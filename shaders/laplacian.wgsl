// laplacian.wgsl (after strip.wgsl): Laplacian of the gray frame (OpenCV ksize 1:
// [0 1 0; 1 -4 1; 0 1 0], ksize 3: [2 0 2; 0 -8 0; 2 0 2]) and exact 64-bit totals of
// (L + offset) and L^2 for the variance, straight from the BGR texture. Exact integers:
// |L| <= offset (1020 for ksize 1, 2040 for ksize 3); a strip row of 16 pixels adds at most
// 16 * 2040^2 < 2^32 to the L^2 total; rows are added into 64-bit register totals, then into
// the frame's totals with atomics. With write_gray, also writes the gray image.
// Bindings: those of strip.wgsl; totals: atomic u32 [sum(L + offset) low, high, sum(L^2) low,
// high], cleared before the dispatch.
// Workgroup: 8 x 1. Dispatch: ceil(ceil(width / 16) / 8) x ceil(height / strip_rows).
// Twin: src/kernels/laplacian.rs `opencv` (cv::Laplacian CV_64F; cv::meanStdDev).

// A row's parts: p the pixels, n = left + right neighbours (four pixels per vector).
// ksize 1: L = p(above) + p(below) + n(at) - 4 p(at); ksize 3: L = 2 (n(above) + n(below)) - 8 p(at).
struct Parts {
    p0: vec4<i32>, p1: vec4<i32>, p2: vec4<i32>, p3: vec4<i32>,
    n0: vec4<i32>, n1: vec4<i32>, n2: vec4<i32>, n3: vec4<i32>,
}

fn parts(r: Row) -> Parts {
    let x = span(r);
    return Parts(x.p0, x.p1, x.p2, x.p3, x.l0 + x.r0, x.l1 + x.r1, x.l2 + x.r2, x.l3 + x.r3);
}

fn lap4(pa: vec4<i32>, na: vec4<i32>, pb: vec4<i32>, nb: vec4<i32>, pc: vec4<i32>,
        nc: vec4<i32>) -> vec4<i32> {
    if (params.ksize == 1u) {
        return pa + pc + nb - 4 * pb;
    }
    return 2 * (na + nc) - 8 * pb;
}

// (sum of L + offset, sum of L^2) over the pixels of the middle row (b) inside the frame.
fn lap_row(a: Parts, b: Parts, c: Parts, e: Edge, offset: vec4<i32>) -> vec2<u32> {
    let l0 = lap4(a.p0, a.n0, b.p0, b.n0, c.p0, c.n0);
    let l1 = lap4(a.p1, a.n1, b.p1, b.n1, c.p1, c.n1);
    let l2 = lap4(a.p2, a.n2, b.p2, b.n2, c.p2, c.n2);
    let l3 = lap4(a.p3, a.n3, b.p3, b.n3, c.p3, c.n3);
    let sum = dot(vec4<u32>(l0 + offset), e.in0) + dot(vec4<u32>(l1 + offset), e.in1)
        + dot(vec4<u32>(l2 + offset), e.in2) + dot(vec4<u32>(l3 + offset), e.in3);
    let sq = dot(vec4<u32>(l0 * l0), e.in0) + dot(vec4<u32>(l1 * l1), e.in1)
        + dot(vec4<u32>(l2 * l2), e.in2) + dot(vec4<u32>(l3 * l3), e.in3);
    return vec2<u32>(sum, sq);
}

@compute @workgroup_size(8, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = i32(gid.x);
    let h = i32(params.height);
    let y0 = i32(gid.y * params.strip_rows);
    if (16 * k >= i32(params.width) || y0 >= h) {
        return;
    }
    let y1 = min(y0 + i32(params.strip_rows), h);
    let e = edge_of(k);
    let offset = vec4<i32>(select(2040, 1020, params.ksize == 1u));
    let first = gray_row(k, y0, e);
    if (params.write_gray == 1u) {
        write_gray_row(k, y0, first);
    }
    var a = parts(gray_row(k, reflect101(y0 - 1, h), e));
    var b = parts(first);
    var total_l = vec2<u32>(0u, 0u);
    var total_sq = vec2<u32>(0u, 0u);
    for (var y = y0; y < y1; y = y + 1) {
        let below = gray_row(k, reflect101(y + 1, h), e);
        if (params.write_gray == 1u && y + 1 < y1) {
            write_gray_row(k, y + 1, below);
        }
        let c = parts(below);
        let t = lap_row(a, b, c, e, offset);
        total_l = acc64(total_l, t.x);
        total_sq = acc64(total_sq, t.y);
        a = b;
        b = c;
    }
    add64x2(0u, total_l);
    add64x2(2u, total_sq);
}
