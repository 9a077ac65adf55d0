//! The frames `keyframer-gpu-bench` times (`synthetic::Scroll`, its speed and seed) through the
//! kernels it times equal the OpenCV twins within `tolerance.rs`: the benchmark times correct
//! kernels. (The tool itself builds without OpenCV; its own test runs it on lavapipe.)

use crate::flow::compare;
use keyframer::analysis::{DeviceAnalysis, Request};
use keyframer::gpu::GpuContext;
use keyframer::kernels::sharpness::{score_opencv, SharpnessGpu};
use keyframer::kernels::tolerance::{rel_err, MOVEMENT_REL, SHARPNESS_REL};
use keyframer::kernels::{farneback, gray, movement, resize_area};
use keyframer::params::{FarnebackParams, Metric};
use keyframer::synthetic::Scroll;
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use std::sync::Arc;

/// The tool's scene parameters (tools/gpu-bench/src/bench.rs: SPEED, SEED).
const SPEED: u32 = 2;
const SEED: u64 = 35;

/// A BGR Mat holding `bytes` (rows of `w * 3`).
fn bgr(bytes: &[u8], h: i32) -> Mat {
    let flat = Mat::from_slice(bytes).unwrap();
    flat.reshape(3, h).unwrap().try_clone().unwrap()
}

#[test]
fn bench_frames_through_the_kernels_equal_the_opencv_twins() {
    let ((w, h), small) = ((640u32, 360u32), (320u32, 180u32));
    let scene = Scroll::new(w, h, SPEED, SEED);
    let ctx = Arc::new(GpuContext::new(None).unwrap());
    let indices = [0usize, 1, 7];
    let frames: Vec<&[u8]> = indices.iter().map(|&i| scene.frame(i)).collect();
    let mats: Vec<Mat> = frames.iter().map(|f| bgr(f, h as i32)).collect();
    let size = Size::new(small.0 as i32, small.1 as i32);
    let smalls: Vec<Mat> = (mats.iter())
        .map(|m| resize_area::opencv(&gray::opencv(m).unwrap(), size).unwrap())
        .collect();
    for metric in [Metric::Tenengrad, Metric::Laplacian { ksize: 3 }] {
        let mut gpu = SharpnessGpu::new(ctx.clone(), metric, w, h).unwrap();
        gpu.attach_resize(small).unwrap();
        let scores = gpu.scores(&frames).unwrap();
        assert_eq!(scores.len(), frames.len());
        for ((g, m), i) in scores.iter().zip(&mats).zip(indices) {
            let c = score_opencv(m, metric).unwrap();
            assert!(c > 0.0, "frame {i}: the scene must have edges");
            let e = rel_err(*g, c);
            assert!(
                e <= SHARPNESS_REL,
                "{metric:?} frame {i}: gpu {g} opencv {c} ({e})"
            );
        }
        for ((f, s), i) in frames.iter().zip(&smalls).zip(indices) {
            let resized = gpu.resized_of(*f).unwrap();
            assert_eq!(
                resized,
                s.data_bytes().unwrap(),
                "resized gray of frame {i}"
            );
        }
    }
    // The flow between frames of the scene (it moves: the pairs are not trivial).
    let p = FarnebackParams::default();
    let (_, _, max) = compare(&smalls[0], &smalls[1], &p, "scroll 0-1");
    assert!(max > 0.0);
    compare(&smalls[1], &smalls[2], &p, "scroll 1-7");
}

/// The whole device analysis the benchmark times (`select`'s movement: stride 2, median) gives
/// each frame the movement OpenCV's Farneback and the host statistic give its stride pair, and
/// the scores of the OpenCV twins.
#[test]
fn the_timed_device_analysis_equals_the_opencv_twins() {
    let ((w, h), n) = ((640u32, 360u32), 9usize);
    let scene = Scroll::new(w, h, SPEED, SEED);
    let ctx = Arc::new(GpuContext::new(None).unwrap());
    let mut m = keyframer::steps::defaults::movement();
    m.analysis_width = 320;
    let req = Request {
        sharpness: vec![Metric::Tenengrad],
        movement: Some(m),
        ..Request::default()
    };
    let frames: Vec<&[u8]> = (0..n).map(|i| scene.frame(i)).collect();
    let mut device = DeviceAnalysis::new(&ctx, &req, (w, h)).unwrap();
    device.push(&frames).unwrap();
    let got = device.finish().unwrap();
    assert_eq!(got.frames, n);
    let values = got.movement.unwrap();
    assert_eq!(values.len(), n);
    assert_eq!(values[0], 0.0);
    let small = |i: usize| {
        let g = gray::opencv(&bgr(frames[i], h as i32)).unwrap();
        resize_area::opencv(&g, Size::new(320, 180)).unwrap()
    };
    let (stride, scale) = (m.stride as usize, f64::from(w) / 320.0);
    for b in (stride..n).step_by(stride) {
        let flow = farneback::opencv(&small(b - stride), &small(b), &m.farneback, None).unwrap();
        let c = movement::cpu_flow(&flow, m.statistic, None).unwrap() * scale / stride as f64;
        assert!(c > 0.5, "the scene moves {SPEED} rows a frame: {c}");
        for (i, v) in values.iter().enumerate().take(b + 1).skip(b + 1 - stride) {
            let e = rel_err(*v, c);
            assert!(e <= MOVEMENT_REL, "frame {i}: device {v} opencv {c} ({e})");
        }
    }
    for (i, g) in got.sharpness[0].iter().enumerate() {
        let c = score_opencv(&bgr(frames[i], h as i32), Metric::Tenengrad).unwrap();
        assert!(
            rel_err(*g, c) <= SHARPNESS_REL,
            "frame {i}: device {g} opencv {c}"
        );
    }
}
