// tenengrad.wgsl (after strip.wgsl): 3x3 Sobel Gx, Gy of the gray frame and the exact 64-bit
// total of Gx^2 + Gy^2, straight from the BGR texture. Exact integers: |Gx|, |Gy| <= 1020, one
// pixel adds <= 2 080 800, a strip row of 16 pixels < 2^32; rows are added into a 64-bit register
// total, then into the frame's total with atomics. With write_gray, also writes the gray image.
// Bindings: those of strip.wgsl; totals: atomic u32 [low, high], cleared before the dispatch.
// Workgroup: 8 x 1. Dispatch: ceil(ceil(width / 16) / 8) x ceil(height / strip_rows).
// Twin: src/kernels/tenengrad.rs `opencv` (cv::Sobel ksize 3, CV_16S; Mat::dot).

// A row's horizontal Sobel parts: d = right - left, s = left + 2 pixel + right (four pixels per
// vector); Gx = d(above) + 2 d(at) + d(below), Gy = s(below) - s(above).
struct Parts {
    d0: vec4<i32>, d1: vec4<i32>, d2: vec4<i32>, d3: vec4<i32>,
    s0: vec4<i32>, s1: vec4<i32>, s2: vec4<i32>, s3: vec4<i32>,
}

fn parts(r: Row) -> Parts {
    let x = span(r);
    return Parts(
        x.r0 - x.l0, x.r1 - x.l1, x.r2 - x.l2, x.r3 - x.l3,
        x.l0 + 2 * x.p0 + x.r0, x.l1 + 2 * x.p1 + x.r1,
        x.l2 + 2 * x.p2 + x.r2, x.l3 + 2 * x.p3 + x.r3,
    );
}

fn sq4(da: vec4<i32>, db: vec4<i32>, dc: vec4<i32>, sa: vec4<i32>, sc: vec4<i32>) -> vec4<u32> {
    let gx = da + 2 * db + dc;
    let gy = sc - sa;
    return vec4<u32>(gx * gx + gy * gy);
}

// Sum of Gx^2 + Gy^2 over the pixels of the middle row (b) inside the frame.
fn sobel_row(a: Parts, b: Parts, c: Parts, e: Edge) -> u32 {
    return dot(sq4(a.d0, b.d0, c.d0, a.s0, c.s0), e.in0)
        + dot(sq4(a.d1, b.d1, c.d1, a.s1, c.s1), e.in1)
        + dot(sq4(a.d2, b.d2, c.d2, a.s2, c.s2), e.in2)
        + dot(sq4(a.d3, b.d3, c.d3, a.s3, c.s3), e.in3);
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
    let first = gray_row(k, y0, e);
    if (params.write_gray == 1u) {
        write_gray_row(k, y0, first);
    }
    var a = parts(gray_row(k, reflect101(y0 - 1, h), e));
    var b = parts(first);
    var total = vec2<u32>(0u, 0u);
    for (var y = y0; y < y1; y = y + 1) {
        let below = gray_row(k, reflect101(y + 1, h), e);
        if (params.write_gray == 1u && y + 1 < y1) {
            write_gray_row(k, y + 1, below);
        }
        let c = parts(below);
        total = acc64(total, sobel_row(a, b, c, e));
        a = b;
        b = c;
    }
    add64x2(0u, total);
}
