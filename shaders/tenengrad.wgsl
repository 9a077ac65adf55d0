// tenengrad.wgsl (after strip.wgsl): 3x3 Sobel Gx, Gy of the gray frame and the exact 64-bit
// total of Gx^2 + Gy^2, straight from the BGR texture. Exact integers: |Gx|, |Gy| <= 1020, one
// pixel adds <= 2 080 800, a strip row of 16 pixels < 2^32; rows are added into a 64-bit register
// total, then into the frame's total with atomics. With write_gray, also writes the gray image.
// Bindings: those of strip.wgsl; totals: atomic u32 [low, high], cleared before the dispatch.
// Workgroup: 8 x 1. Dispatch: ceil(ceil(width / 16) / 8) x ceil(height / strip_rows).
// Twin: src/kernels/tenengrad.rs `opencv` (cv::Sobel ksize 3, CV_16S; Mat::dot).

// Gx^2 + Gy^2 of four pixels from the rows above (a), at (b) and below (c): left neighbours,
// pixels, right neighbours.
fn sobel4(al: vec4<i32>, ap: vec4<i32>, ar: vec4<i32>, bl: vec4<i32>, br: vec4<i32>,
          cl: vec4<i32>, cp: vec4<i32>, cr: vec4<i32>) -> vec4<u32> {
    let gx = (ar - al) + 2 * (br - bl) + (cr - cl);
    let gy = (cl + 2 * cp + cr) - (al + 2 * ap + ar);
    return vec4<u32>(gx * gx + gy * gy);
}

fn sobel_row(a: Span, b: Span, c: Span, e: Edge) -> u32 {
    let s0 = sobel4(a.l0, a.p0, a.r0, b.l0, b.r0, c.l0, c.p0, c.r0);
    let s1 = sobel4(a.l1, a.p1, a.r1, b.l1, b.r1, c.l1, c.p1, c.r1);
    let s2 = sobel4(a.l2, a.p2, a.r2, b.l2, b.r2, c.l2, c.p2, c.r2);
    let s3 = sobel4(a.l3, a.p3, a.r3, b.l3, b.r3, c.l3, c.p3, c.r3);
    return dot(s0, e.in0) + dot(s1, e.in1) + dot(s2, e.in2) + dot(s3, e.in3);
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
    var a = gray_row(k, reflect101(y0 - 1, h), e);
    var b = gray_row(k, y0, e);
    var total = vec2<u32>(0u, 0u);
    for (var y = y0; y < y1; y = y + 1) {
        let c = gray_row(k, reflect101(y + 1, h), e);
        if (params.write_gray == 1u) {
            write_gray_row(k, y, b);
        }
        total = acc64(total, sobel_row(span(a), span(b), span(c), e));
        a = b;
        b = c;
    }
    add64x2(0u, total);
}
