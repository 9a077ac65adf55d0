//! The frames `keyframer-gpu-bench` times (`synthetic::Scroll`, its speed and seed) through the
//! kernels it times equal the OpenCV twins within `tolerance.rs`: the benchmark times correct
//! kernels. (The tool itself builds without OpenCV; its own test runs it on lavapipe.)

use crate::flow::compare;
use keyframer::gpu::GpuContext;
use keyframer::kernels::sharpness::{score_opencv, SharpnessGpu};
use keyframer::kernels::tolerance::{rel_err, SHARPNESS_REL};
use keyframer::kernels::{gray, resize_area};
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
