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
use keyframer::synthetic::{Scroll, BENCH_SPEED};
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use std::sync::Arc;

/// A BGR Mat holding `bytes` (rows of `w * 3`).
fn bgr(bytes: &[u8], h: i32) -> Mat {
    let flat = Mat::from_slice(bytes).unwrap();
    flat.reshape(3, h).unwrap().try_clone().unwrap()
}

#[test]
fn bench_frames_through_the_kernels_equal_the_opencv_twins() {
    let ((w, h), small) = ((640u32, 360u32), (320u32, 180u32));
    let scene = Scroll::bench(w, h);
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
    let scene = Scroll::bench(w, h);
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
        assert!(c > 0.5, "the scene moves {BENCH_SPEED} rows a frame: {c}");
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

/// The results a real GPU recorded (`reference/gpu-bench/*.json`: keyframer-gpu-bench's JSON
/// from a machine without OpenCV, its first frames' scores, movement and stationary keyframes)
/// equal what the opencv backend computes here on the same frames (written as PNG and read as an
/// image folder): the figures in docs/benchmarks.md time kernels that were correct on that GPU.
#[test]
fn results_recorded_on_a_gpu_equal_the_opencv_backend() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("reference/gpu-bench");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no recorded run in {}", dir.display());
    let tmp = tempfile::tempdir().unwrap();
    for file in &files {
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(file).unwrap()).unwrap();
        let analysis_width = v["analysis_width"].as_u64().unwrap() as u32;
        let results = v["results"].as_array().unwrap();
        assert!(!results.is_empty(), "{}: no results", file.display());
        for r in results {
            let name = r["name"].as_str().unwrap();
            let what = format!("{} {name} {}", file.display(), r["size"]);
            let (w, h) = r["size"].as_str().unwrap().split_once('x').unwrap();
            let (w, h): (u32, u32) = (w.parse().unwrap(), h.parse().unwrap());
            let n = r["frames"].as_u64().unwrap() as usize;
            let f64s = |key: &str| -> Vec<f64> {
                (r[key].as_array().unwrap().iter())
                    .map(|x| x.as_f64().unwrap())
                    .collect()
            };
            let scene = Scroll::bench(w, h);
            let sharpness = f64s("sharpness");
            assert_eq!(sharpness.len(), n, "{what}");
            let metric = match name {
                "gray+resize+laplacian" => Metric::Laplacian { ksize: 3 },
                "gray+resize+tenengrad" | "analysis" => Metric::Tenengrad,
                other => panic!("{what}: unknown run {other}"),
            };
            if name != "analysis" {
                for (i, g) in sharpness.iter().enumerate() {
                    let c = score_opencv(&bgr(scene.frame(i), h as i32), metric).unwrap();
                    let e = rel_err(*g, c);
                    assert!(e <= SHARPNESS_REL, "{what} frame {i}: {g} vs {c} ({e})");
                }
                continue;
            }
            // The whole analysis: the same frames through the opencv backend, a stride more
            // than recorded (the last recorded frames' movement comes from a pair ending after
            // them; the run on the GPU went on).
            let req = Request::stationary_blur_spacing(w, analysis_width);
            let stride = req.movement.as_ref().unwrap().stride as usize;
            let folder = tmp.path().join(format!("{w}x{h}-{analysis_width}"));
            std::fs::create_dir_all(&folder).unwrap();
            for i in 0..n + stride {
                let path = folder.join(format!("{i:04}.png"));
                let m = bgr(scene.frame(i), h as i32);
                let ok = opencv::imgcodecs::imwrite_def(path.to_str().unwrap(), &m).unwrap();
                assert!(ok, "{}", path.display());
            }
            let opts = keyframer::source::OpenOptions::default();
            let cpu = keyframer::analysis::analyse(
                &folder,
                &opts,
                &req,
                keyframer::params::Backend::Opencv,
                None,
                true,
                None,
            )
            .unwrap();
            let (_, scores) = &cpu.sharpness[0];
            for (i, (g, c)) in sharpness.iter().zip(scores).enumerate() {
                let e = rel_err(*g, *c);
                assert!(e <= SHARPNESS_REL, "{what} frame {i}: {g} vs {c} ({e})");
            }
            let movement = f64s("movement");
            let values = &cpu.movement.as_ref().unwrap().values;
            assert_eq!((movement.len(), values.len()), (n, n + stride), "{what}");
            assert!(values[n - 1] > 0.5, "{what}: the scene moves: {values:?}");
            for (i, (g, c)) in movement.iter().zip(values).enumerate() {
                let e = rel_err(*g, *c);
                assert!(
                    e <= MOVEMENT_REL,
                    "{what} frame {i}: movement {g} vs {c} ({e})"
                );
            }
            let keys: Vec<usize> = (r["stationary"].as_array().unwrap().iter())
                .map(|k| k.as_u64().unwrap() as usize)
                .collect();
            let cpu_keys: Vec<usize> = (cpu.stationary.unwrap().into_iter())
                .filter(|&k| k < n)
                .collect();
            assert!(
                keys.len() > 1,
                "{what}: the stationary step keeps frames: {keys:?}"
            );
            assert_eq!(keys, cpu_keys, "{what}: stationary keyframes");
        }
    }
}
