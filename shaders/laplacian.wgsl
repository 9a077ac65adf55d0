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

// L of four pixels from the rows above (a), at (b) and below (c).
fn lap4(al: vec4<i32>, ap: vec4<i32>, ar: vec4<i32>, bl: vec4<i32>, bp: vec4<i32>,
        br: vec4<i32>, cl: vec4<i32>, cp: vec4<i32>, cr: vec4<i32>) -> vec4<i32> {
    if (params.ksize == 1u) {
        return ap + cp + bl + br - 4 * bp;
    }
    return 2 * (al + ar + cl + cr) - 8 * bp;
}

// (sum of L + offset, sum of L^2) over the row's pixels inside the frame.
fn lap_row(a: Span, b: Span, c: Span, e: Edge, offset: vec4<i32>) -> vec2<u32> {
    let l0 = lap4(a.l0, a.p0, a.r0, b.l0, b.p0, b.r0, c.l0, c.p0, c.r0);
    let l1 = lap4(a.l1, a.p1, a.r1, b.l1, b.p1, b.r1, c.l1, c.p1, c.r1);
    let l2 = lap4(a.l2, a.p2, a.r2, b.l2, b.p2, b.r2, c.l2, c.p2, c.r2);
    let l3 = lap4(a.l3, a.p3, a.r3, b.l3, b.p3, b.r3, c.l3, c.p3, c.r3);
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
    var a = gray_row(k, reflect101(y0 - 1, h), e);
    var b = gray_row(k, y0, e);
    var total_l = vec2<u32>(0u, 0u);
    var total_sq = vec2<u32>(0u, 0u);
    for (var y = y0; y < y1; y = y + 1) {
        let c = gray_row(k, reflect101(y + 1, h), e);
        if (params.write_gray == 1u) {
            write_gray_row(k, y, b);
        }
        let t = lap_row(span(a), span(b), span(c), e, offset);
        total_l = acc64(total_l, t.x);
        total_sq = acc64(total_sq, t.y);
        a = b;
        b = c;
    }
    add64x2(0u, total_l);
    add64x2(2u, total_sq);
}
