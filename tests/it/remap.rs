//! Remap kernel (ERP → pinhole views): gpu (WGSL on lavapipe) against cv::remap on the same
//! tables, gray and BGR, bilinear and bicubic, within `tolerance::REMAP_*`; the golden views in
//! reference/remap; the tables agree with the projection conventions.

use keyframer::equirect::{view_map, View, ViewSet};
use keyframer::kernels::remap::{opencv as cv_remap, Interp, RemapGpu, Table};
use keyframer::kernels::tolerance::{REMAP_BICUBIC_MAX, REMAP_BILINEAR_MAX};
use opencv::core::Mat;
use opencv::prelude::*;

use crate::sharpness::{ctx, synthetic};

fn tables(views: &[View], erp: (u32, u32)) -> Vec<Table> {
    views
        .iter()
        .map(|v| {
            let (xs, ys) = view_map(v, erp);
            Table::new((v.size, v.size), xs, ys).unwrap()
        })
        .collect()
}

/// (max abs difference, differing bytes) of two images of one size and type.
fn diff(a: &Mat, b: &Mat) -> (u8, usize) {
    assert_eq!((a.cols(), a.rows(), a.typ()), (b.cols(), b.rows(), b.typ()));
    let (a, b) = (a.data_bytes().unwrap(), b.data_bytes().unwrap());
    let mut max = 0u8;
    let mut n = 0;
    for (x, y) in a.iter().zip(b) {
        let d = x.abs_diff(*y);
        max = max.max(d);
        n += usize::from(d > 0);
    }
    (max, n)
}

fn bound(interp: Interp) -> u8 {
    match interp {
        Interp::Bilinear => REMAP_BILINEAR_MAX,
        Interp::Bicubic => REMAP_BICUBIC_MAX,
    }
}

/// Cube faces, a tilted rolled view and a ring, from ERP frames of odd sizes (rows not whole
/// words, views crossing the ±180° seam and both poles), gray and BGR, both interpolations.
#[test]
fn remap_matches_opencv() {
    let ctx = ctx();
    let mut views = ViewSet::Cube.views(96.0, 37);
    views.extend(ViewSet::Ring { n: 3, pitch: -20.0 }.views(70.0, 50));
    views.push(View {
        name: "odd".into(),
        yaw_deg: 171.0,
        pitch_deg: 33.0,
        roll_deg: 17.0,
        fov_deg: 120.0,
        size: 41,
    });
    for (w, h) in [(402, 201), (127, 63)] {
        let bgr = synthetic(w, h, (w + h) as u64);
        let gray = keyframer::kernels::gray::opencv(&bgr).unwrap();
        let t = tables(&views, (w as u32, h as u32));
        for interp in [Interp::Bilinear, Interp::Bicubic] {
            for (img, ch) in [(&bgr, 3), (&gray, 1)] {
                let gpu = RemapGpu::new(ctx.clone(), (w as u32, h as u32), ch, interp, &t).unwrap();
                let ours = gpu.render(img).unwrap();
                assert_eq!(ours.len(), views.len());
                for ((v, table), o) in views.iter().zip(&t).zip(&ours) {
                    let theirs = cv_remap(img, table, interp).unwrap();
                    let (max, n) = diff(o, &theirs);
                    eprintln!(
                        "{w}x{h} {interp:?} {ch}ch {}: max {max}, {n} bytes differ",
                        v.name
                    );
                    assert!(
                        max <= bound(interp),
                        "{w}x{h} {interp:?} {ch}ch view {}: max diff {max} ({n} bytes differ)",
                        v.name
                    );
                }
            }
        }
    }
}

/// Arbitrary tables (coordinates far outside the image on both axes, negative, exact ties of
/// the 1/32 rounding) exercise the wrap and the rounding rules.
#[test]
fn remap_wraps_and_rounds_like_opencv() {
    let ctx = ctx();
    let (w, h) = (53u32, 29u32);
    let img = synthetic(w as i32, h as i32, 5);
    let size = (61u32, 23u32);
    let n = (size.0 * size.1) as usize;
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut rnd = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut xs = Vec::with_capacity(n);
    let mut ys = Vec::with_capacity(n);
    for i in 0..n {
        if i % 3 == 0 {
            // Exact multiples of 1/64: half way between two 1/32 steps.
            xs.push(((rnd() * 400.0).floor() as f32 - 100.0) / 64.0 * 8.0);
            ys.push(((rnd() * 200.0).floor() as f32 - 50.0) / 64.0 * 4.0);
        } else {
            xs.push((rnd() * 3.0 * f64::from(w) - f64::from(w)) as f32);
            ys.push((rnd() * 3.0 * f64::from(h) - f64::from(h)) as f32);
        }
    }
    let t = Table::new(size, xs, ys).unwrap();
    for interp in [Interp::Bilinear, Interp::Bicubic] {
        let gpu = RemapGpu::new(ctx.clone(), (w, h), 3, interp, std::slice::from_ref(&t)).unwrap();
        let ours = gpu.render(&img).unwrap();
        let theirs = cv_remap(&img, &t, interp).unwrap();
        let (max, n) = diff(&ours[0], &theirs);
        eprintln!("random table {interp:?}: max {max}, {n} bytes differ");
        assert!(
            max <= bound(interp),
            "{interp:?}: max diff {max} ({n} bytes differ)"
        );
    }
}

/// The golden views in reference/remap (OpenCV 4.6's cv::remap of a reference input through
/// `equirect::view_map`): the opencv backend reproduces them exactly, the gpu backend within the
/// tolerance.
#[test]
fn reference_views() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("reference");
    let ctx = ctx();
    let mut checked = 0;
    for entry in std::fs::read_dir(root.join("remap")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) != Some("json") {
            continue;
        }
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        let read = |rel: &str| {
            opencv::imgcodecs::imread(
                root.join(rel).to_str().unwrap(),
                opencv::imgcodecs::IMREAD_COLOR,
            )
            .unwrap()
        };
        let input = read(v["input"].as_str().unwrap());
        let golden = read(v["output"].as_str().unwrap());
        let view: View = serde_json::from_value(v["view"].clone()).unwrap();
        let interp: Interp = serde_json::from_value(v["interp"].clone()).unwrap();
        let erp = (input.cols() as u32, input.rows() as u32);
        let t = tables(std::slice::from_ref(&view), erp);
        let cpu = cv_remap(&input, &t[0], interp).unwrap();
        assert_eq!(diff(&cpu, &golden), (0, 0), "{}: opencv", path.display());
        let gpu = RemapGpu::new(ctx.clone(), erp, 3, interp, &t).unwrap();
        let (max, n) = diff(&gpu.render(&input).unwrap()[0], &golden);
        assert!(
            max <= bound(interp),
            "{}: gpu max {max} ({n})",
            path.display()
        );
        checked += 1;
    }
    assert_eq!(checked, 6, "3 views x 2 interpolations");
}
