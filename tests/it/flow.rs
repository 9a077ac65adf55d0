//! Farneback flow: gpu against cv::calcOpticalFlowFarneback with the same parameters.

use crate::common::testdata;
use keyframer::kernels::farneback::{self, FarnebackGpu, FarnebackParams};
use keyframer::kernels::tolerance::{FLOW_EPE_MEAN, FLOW_EPE_P99};
use opencv::core::{Mat, Vec2f};
use opencv::prelude::*;

pub fn gray_of(path: &std::path::Path) -> Mat {
    let m = opencv::imgcodecs::imread(path.to_str().unwrap(), opencv::imgcodecs::IMREAD_GRAYSCALE)
        .unwrap();
    assert!(!m.empty(), "{}", path.display());
    m
}

/// (mean, 99th percentile, max) endpoint error between two CV_32FC2 fields.
pub fn epe(a: &Mat, b: &Mat) -> (f64, f64, f64) {
    let a = a.data_typed::<Vec2f>().unwrap();
    let b = b.data_typed::<Vec2f>().unwrap();
    let mut e: Vec<f64> = a
        .iter()
        .zip(b)
        .map(|(p, q)| (f64::from(p[0] - q[0]).powi(2) + f64::from(p[1] - q[1]).powi(2)).sqrt())
        .collect();
    let mean = e.iter().sum::<f64>() / e.len() as f64;
    e.sort_by(f64::total_cmp);
    (
        mean,
        e[(e.len() as f64 * 0.99) as usize],
        *e.last().unwrap(),
    )
}

pub fn compare(prev: &Mat, next: &Mat, p: &FarnebackParams, what: &str) -> (f64, f64, f64) {
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None).unwrap());
    let mut gpu = FarnebackGpu::new(ctx, *p, prev.cols() as u32, prev.rows() as u32).unwrap();
    let g = gpu.flow(prev, next).unwrap();
    let c = farneback::opencv(prev, next, p, None).unwrap();
    let (mean, p99, max) = epe(&g, &c);
    eprintln!("{what} {p:?}: EPE mean {mean:.5} p99 {p99:.5} max {max:.4}");
    assert!(
        mean <= FLOW_EPE_MEAN && p99 <= FLOW_EPE_P99,
        "{what}: EPE mean {mean} p99 {p99} (max {max})"
    );
    (mean, p99, max)
}

fn param_sets() -> Vec<FarnebackParams> {
    let d = FarnebackParams::default();
    vec![
        d,
        FarnebackParams {
            gaussian: true,
            ..d
        },
        FarnebackParams {
            levels: 5,
            winsize: 13,
            iterations: 10,
            poly_n: 5,
            poly_sigma: 1.1,
            ..d
        },
        FarnebackParams {
            poly_n: 7,
            poly_sigma: 1.5,
            winsize: 10,
            gaussian: true,
            ..d
        },
    ]
}

#[test]
fn middlebury_pairs_match_opencv() {
    for (a, b) in [
        ("basketball1.png", "basketball2.png"),
        ("rubberwhale1.png", "rubberwhale2.png"),
    ] {
        let prev = gray_of(&testdata(&format!("opencv-doc/{a}")));
        let next = gray_of(&testdata(&format!("opencv-doc/{b}")));
        for p in param_sets() {
            compare(&prev, &next, &p, a);
        }
    }
}

/// The device statistic equals the host statistic of the same magnitudes (exact selection), and
/// gpu vs opencv movement agrees within MOVEMENT_REL.
#[test]
fn movement_statistic_on_device() {
    use keyframer::kernels::movement::{self, MovementGpu, Statistic};
    use keyframer::kernels::tolerance::{rel_err, MOVEMENT_REL};
    let prev = gray_of(&testdata("opencv-doc/rubberwhale1.png"));
    let next = gray_of(&testdata("opencv-doc/rubberwhale2.png"));
    let p = FarnebackParams::default();
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None).unwrap());
    let mut gpu =
        FarnebackGpu::new(ctx.clone(), p, prev.cols() as u32, prev.rows() as u32).unwrap();
    let g = gpu.flow(&prev, &next).unwrap();
    let n = (prev.cols() * prev.rows()) as u32;
    let stat = MovementGpu::new(ctx, gpu.flow_buffer(), n).unwrap();
    let cv_flow = farneback::opencv(&prev, &next, &p, None).unwrap();
    let g_mags = movement::magnitudes(&g).unwrap();
    let c_mags = movement::magnitudes(&cv_flow).unwrap();
    for s in [
        Statistic::Median,
        Statistic::TrimmedMean { trim: 0.1 },
        Statistic::TrimmedMean { trim: 0.0 },
        Statistic::TrimmedMean { trim: 0.25 },
    ] {
        let on_device = stat.compute(s).unwrap();
        let host_same = movement::cpu(&g_mags, s).unwrap();
        assert!(
            rel_err(on_device, host_same) < 1e-6,
            "{s:?}: device {on_device} host {host_same}"
        );
        let opencv = movement::cpu(&c_mags, s).unwrap();
        assert!(
            rel_err(on_device, opencv) <= MOVEMENT_REL,
            "{s:?}: gpu {on_device} opencv {opencv}"
        );
        eprintln!("{s:?}: gpu {on_device} opencv {opencv}");
    }
}
