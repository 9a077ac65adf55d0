//! Sharpness kernels: gpu (WGSL on lavapipe) against the OpenCV twins, gray bit-exact, scores
//! within `tolerance::SHARPNESS_REL`, on odd sizes, several workgroups, both borders and 4K.

use keyframer::gpu::GpuContext;
use keyframer::kernels::gray;
use keyframer::kernels::sharpness::{score_opencv, SharpnessGpu};
use keyframer::kernels::tolerance::{rel_err, SHARPNESS_REL};
use keyframer::params::Metric;
use opencv::core::Mat;
use opencv::prelude::*;
use std::sync::Arc;

pub const METRICS: [Metric; 3] = [
    Metric::Tenengrad,
    Metric::Laplacian { ksize: 1 },
    Metric::Laplacian { ksize: 3 },
];

pub fn ctx() -> Arc<GpuContext> {
    Arc::new(GpuContext::new(None).expect("a wgpu adapter (lavapipe in CI)"))
}

/// The library's deterministic test pattern.
pub fn synthetic(w: i32, h: i32, seed: u64) -> Mat {
    keyframer::synthetic::pattern(w, h, seed).unwrap()
}

fn check(ctx: &Arc<GpuContext>, img: &Mat, what: &str) {
    for metric in METRICS {
        let mut gpu =
            SharpnessGpu::new(ctx.clone(), metric, img.cols() as u32, img.rows() as u32).unwrap();
        let g = gpu.scores(&[img]).unwrap()[0];
        let c = score_opencv(img, metric).unwrap();
        let e = rel_err(g, c);
        assert!(
            e <= SHARPNESS_REL,
            "{what} {metric}: gpu {g} opencv {c} rel err {e:e}"
        );
        assert!(c > 0.0, "{what} {metric}: degenerate test image");
    }
}

#[test]
fn gray_is_bit_exact() {
    let ctx = ctx();
    for (w, h) in [(37, 83), (641, 359), (1, 1), (256, 1)] {
        let img = synthetic(w, h, 7);
        let mut gpu =
            SharpnessGpu::new(ctx.clone(), Metric::Tenengrad, w as u32, h as u32).unwrap();
        let ours = gpu.gray_of(&img).unwrap();
        let theirs = gray::opencv(&img).unwrap();
        let theirs = theirs.data_bytes().unwrap();
        let diff = ours.iter().zip(theirs).filter(|(a, b)| a != b).count();
        assert_eq!(
            diff, 0,
            "{w}x{h}: {diff} gray pixels differ from cv::cvtColor"
        );
    }
}

#[test]
fn odd_sizes_match_opencv() {
    let ctx = ctx();
    for (w, h) in [(37, 83), (641, 359), (16, 16), (17, 3), (3, 2)] {
        check(
            &ctx,
            &synthetic(w, h, w as u64 * 31 + h as u64),
            &format!("{w}x{h}"),
        );
    }
}

/// Every position of the frame's last column within a 16-pixel strip (widths 1..=34), frames
/// one to a few rows high, and strip heights from 1 row to taller than the frame: the strip
/// kernels' left/right/top/bottom reflections and partial strips equal OpenCV's.
#[test]
fn strip_borders_match_opencv() {
    let ctx = ctx();
    for w in 1..=34 {
        for h in [1, 2, 5] {
            let img = synthetic(w, h, (w * 7 + h) as u64);
            for metric in METRICS {
                let c = score_opencv(&img, metric).unwrap();
                for rows in [1, 3, 36] {
                    let mut gpu = SharpnessGpu::with_strip_rows(
                        ctx.clone(),
                        metric,
                        (w as u32, h as u32),
                        rows,
                    )
                    .unwrap();
                    let g = gpu.scores(&[&img]).unwrap()[0];
                    assert!(
                        rel_err(g, c) <= SHARPNESS_REL || (g == 0.0 && c.abs() < 1e-9),
                        "{w}x{h} {metric} strip {rows} rows: gpu {g} opencv {c}"
                    );
                }
            }
        }
    }
}

#[test]
fn uhd_frame_matches_opencv() {
    let ctx = ctx();
    check(&ctx, &synthetic(3840, 2160, 4), "3840x2160");
}

/// A batch of different frames in one submission gives each frame its own score.
#[test]
fn batches_keep_frames_apart() {
    let ctx = ctx();
    let frames: Vec<Mat> = (0..5).map(|s| synthetic(97, 61, s)).collect();
    let refs: Vec<&Mat> = frames.iter().collect();
    for metric in METRICS {
        let mut gpu = SharpnessGpu::new(ctx.clone(), metric, 97, 61).unwrap();
        assert!(gpu.batch_size() >= 5);
        let g = gpu.scores(&refs).unwrap();
        for (i, f) in frames.iter().enumerate() {
            let c = score_opencv(f, metric).unwrap();
            assert!(
                rel_err(g[i], c) <= SHARPNESS_REL,
                "{metric} frame {i}: {} vs {c}",
                g[i]
            );
        }
    }
}

/// Every golden file in reference/sharpness: the opencv backend reproduces it and the gpu backend
/// matches it within the tolerance.
#[test]
fn reference_scores() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("reference");
    let ctx = ctx();
    let mut checked = 0;
    for entry in std::fs::read_dir(root.join("sharpness")).unwrap() {
        let path = entry.unwrap().path();
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        let input = root.join(v["input"].as_str().unwrap());
        let metric: Metric = v["metric"].as_str().unwrap().parse().unwrap();
        let expected = v["score"].as_f64().unwrap();
        let img =
            opencv::imgcodecs::imread(input.to_str().unwrap(), opencv::imgcodecs::IMREAD_COLOR)
                .unwrap();
        assert_eq!(
            (img.cols() as u64, img.rows() as u64),
            (v["width"].as_u64().unwrap(), v["height"].as_u64().unwrap())
        );
        let cpu = score_opencv(&img, metric).unwrap();
        assert!(
            rel_err(cpu, expected) <= SHARPNESS_REL,
            "{}: opencv {cpu} vs stored {expected}",
            path.display()
        );
        let mut gpu =
            SharpnessGpu::new(ctx.clone(), metric, img.cols() as u32, img.rows() as u32).unwrap();
        let g = gpu.scores(&[&img]).unwrap()[0];
        assert!(
            rel_err(g, expected) <= SHARPNESS_REL,
            "{}: gpu {g} vs OpenCV {expected} (rel {:e})",
            path.display(),
            rel_err(g, expected)
        );
        checked += 1;
    }
    assert_eq!(checked, 15, "5 inputs x 3 metrics");
    let size: u64 = walk_size(&root);
    assert!(
        size < 2 << 20,
        "reference/ is {size} bytes, over its 2 MiB cap"
    );
}

fn walk_size(p: &std::path::Path) -> u64 {
    if p.is_dir() {
        std::fs::read_dir(p)
            .unwrap()
            .map(|e| walk_size(&e.unwrap().path()))
            .sum()
    } else {
        std::fs::metadata(p).unwrap().len()
    }
}

/// Pixels of `ours` that differ from the 8-bit Mat `theirs` (same size, row after row).
fn differing(ours: &[u8], theirs: &Mat) -> usize {
    let theirs = theirs.data_bytes().unwrap();
    assert_eq!(ours.len(), theirs.len(), "sizes differ");
    ours.iter().zip(theirs).filter(|(a, b)| a != b).count()
}

/// Source and output sizes of the resize_area checks.
const RESIZE_AREA_CASES: [((i32, i32), (i32, i32)); 14] = [
    ((1920, 1080), (640, 360)),
    ((1920, 1080), (320, 180)),
    ((3840, 2160), (640, 360)),
    ((1280, 720), (640, 360)),
    ((64, 48), (32, 24)),
    ((45, 35), (9, 7)),
    ((21, 40), (7, 8)),
    ((123, 66), (41, 22)),
    ((30, 8), (10, 8)),
    ((640, 720), (640, 360)),
    ((8, 3), (4, 3)),
    ((7, 7), (7, 7)),
    ((1440, 1080), (640, 480)),
    ((3840, 2160), (160, 90)),
];

/// The host resize (the opencv backend's analysis resize) against cv::resize(INTER_AREA):
/// pixel-exact for every case (fractional factors and blocks over 257 pixels go to OpenCV).
#[test]
fn resize_area_host_is_bit_exact() {
    use keyframer::kernels::resize_area::{host, opencv as cv_area};
    for ((sw, sh), (dw, dh)) in RESIZE_AREA_CASES {
        let gray = gray::opencv(&synthetic(sw, sh, (sw * 7 + sh) as u64)).unwrap();
        let size = opencv::core::Size::new(dw, dh);
        let theirs = cv_area(&gray, size).unwrap();
        let ours = host(&gray, size).unwrap();
        assert_eq!((ours.cols(), ours.rows()), (dw, dh));
        let diff = differing(ours.data_bytes().unwrap(), &theirs);
        assert_eq!(
            diff, 0,
            "{sw}x{sh} -> {dw}x{dh}: {diff} pixels differ from cv::resize INTER_AREA"
        );
    }
}

/// resize_area on the device against cv::resize(INTER_AREA), pixel-exact, for integer factors:
/// 3x, 6x, 2x (OpenCV's (sum + 2) >> 2 case), odd and unequal factors, 1 x 2 and 2 x 1 (where
/// round-half-even decides ties), outputs whose rows do not fill whole u32 words.
#[test]
fn resize_area_is_bit_exact() {
    use keyframer::kernels::resize_area::{factors, opencv as cv_area, ResizeAreaGpu};
    let ctx = ctx();
    let integer = |&((sw, sh), (dw, dh)): &((i32, i32), (i32, i32))| {
        factors((sw as u32, sh as u32), (dw as u32, dh as u32)).is_some()
    };
    for ((sw, sh), (dw, dh)) in RESIZE_AREA_CASES.into_iter().filter(integer) {
        let gray = gray::opencv(&synthetic(sw, sh, (sw * 7 + sh) as u64)).unwrap();
        let size = opencv::core::Size::new(dw, dh);
        let theirs = cv_area(&gray, size).unwrap();
        let gpu = ResizeAreaGpu::new(ctx.clone(), (sw as u32, sh as u32), (dw as u32, dh as u32))
            .unwrap();
        let ours = gpu.resize_mat(&gray).unwrap();
        let diff = differing(&ours, &theirs);
        assert_eq!(
            diff, 0,
            "{sw}x{sh} -> {dw}x{dh}: {diff} pixels differ from cv::resize INTER_AREA"
        );
        // The rounding rules are exercised: some blocks sum to an exact tie.
        let (kx, ky) = (sw / dw, sh / dh);
        if kx * ky == 2 || kx * ky == 4 {
            let area = (kx * ky) as u32;
            let ties = (0..dh)
                .flat_map(|y| (0..dw).map(move |x| (x, y)))
                .filter(|&(x, y)| {
                    let mut sum = 0u32;
                    for j in 0..ky {
                        for i in 0..kx {
                            sum += u32::from(*gray.at_2d::<u8>(y * ky + j, x * kx + i).unwrap());
                        }
                    }
                    sum % area == area / 2
                })
                .count();
            assert!(
                ties > 0,
                "{sw}x{sh} -> {dw}x{dh}: no tie to check rounding on"
            );
        }
    }
}

/// The resize attached to the sharpness runner reads the gray the device computed from the BGR
/// frame: BGR -> gray.wgsl -> resize_area equals cv::cvtColor -> cv::resize(INTER_AREA).
#[test]
fn device_gray_resized_matches_opencv() {
    let ctx = ctx();
    for ((sw, sh), (dw, dh)) in [
        ((1920, 1080), (640, 360)),
        ((99, 63), (33, 21)),
        ((6, 6), (3, 3)),
    ] {
        let mut gpu = SharpnessGpu::new(ctx.clone(), Metric::Tenengrad, sw, sh).unwrap();
        let small = gpu.attach_resize((dw, dh)).unwrap();
        assert_eq!(small.len(), gpu.batch_size());
        for seed in 0..2 {
            let img = synthetic(sw as i32, sh as i32, seed);
            let ours = gpu.resized_of(&img).unwrap();
            let theirs = keyframer::kernels::resize_area::opencv(
                &gray::opencv(&img).unwrap(),
                opencv::core::Size::new(dw as i32, dh as i32),
            )
            .unwrap();
            let diff = differing(&ours, &theirs);
            assert_eq!(
                diff, 0,
                "{sw}x{sh} -> {dw}x{dh} seed {seed}: {diff} pixels differ"
            );
        }
    }
}

/// A validation error on the device (here a buffer usage wgpu forbids) is caught by the context,
/// not wgpu's default handler (which panics): the next wait for the device returns an error that
/// says so, and a fresh context is unaffected.
#[test]
fn gpu_faults_are_errors_not_panics() {
    let ctx = ctx();
    let good = ctx.storage_buffer("good", 16);
    assert!(ctx.read_back(&good, 16).is_ok());
    let _bad = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("map-read storage, forbidden"),
        size: 16,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
    let err = ctx.read_back(&good, 16).unwrap_err().to_string();
    assert!(err.contains("reported an error"), "{err}");
    assert!(err.contains(&ctx.info.name), "{err}");
    assert!(ctx.check().is_err());
    let fresh = super::sharpness::ctx();
    assert!(fresh.read_back(&fresh.storage_buffer("b", 4), 4).is_ok());
}

#[test]
fn the_gpu_context_counts_what_the_host_asks_of_the_device() {
    let ctx = ctx();
    let frames: Vec<Mat> = (0..3)
        .map(|s| keyframer::synthetic::pattern(64, 48, s).unwrap())
        .collect();
    let list: Vec<&Mat> = frames.iter().collect();
    let mut gpu = SharpnessGpu::new(ctx.clone(), Metric::Tenengrad, 64, 48).unwrap();
    let before = ctx.counts();
    let scores = gpu.scores(&list).unwrap();
    let c = ctx.counts() - before;
    assert_eq!(scores.len(), 3);
    // Each frame's BGR bytes go up (64 x 48 x 3), at least one dispatch each, and the totals
    // come back; reading them back needs at least one blocking wait.
    assert!(c.uploaded >= 3 * 64 * 48 * 3, "{c:?}");
    assert!(c.dispatches >= 3, "{c:?}");
    assert!(c.read_back > 0 && c.waits >= 1, "{c:?}");
    let per = keyframer::gpu::PerFrame::of(c, 3);
    assert_eq!(per.waits, c.waits as f64 / 3.0);
}

/// Pipelined scoring: batches submitted ahead of their readback come back in frame order with
/// the scores of one-by-one scoring, and a full staging pool costs one wait per two batches.
#[test]
fn pipelined_batches_come_back_in_order_with_few_waits() {
    let ctx = ctx();
    let frames: Vec<Mat> = (0..7).map(|s| synthetic(97, 61, s)).collect();
    for metric in METRICS {
        let mut one = SharpnessGpu::new(ctx.clone(), metric, 97, 61).unwrap();
        let alone: Vec<f64> = frames
            .iter()
            .map(|f| one.scores(&[f]).unwrap()[0])
            .collect();
        let mut gpu = SharpnessGpu::new(ctx.clone(), metric, 97, 61).unwrap();
        let batch = gpu.batch_size();
        let batches = 12;
        let order: Vec<usize> = (0..batch * batches)
            .map(|i| (i * 3) % frames.len())
            .collect();
        let before = ctx.counts();
        let mut got = Vec::new();
        for chunk in order.chunks(batch) {
            let list: Vec<&Mat> = chunk.iter().map(|&i| &frames[i]).collect();
            gpu.submit(&list).unwrap();
            got.extend(gpu.take(false).unwrap());
        }
        got.extend(gpu.take(true).unwrap());
        let waits = (ctx.counts() - before).waits;
        let want: Vec<f64> = order.iter().map(|&i| alone[i]).collect();
        assert_eq!(got, want, "{metric}");
        assert!(
            waits as usize <= batches / 2 + 1,
            "{metric}: {waits} waits for {batches} batches"
        );
        assert!(gpu.scores(&[&frames[0]]).is_ok());
    }
}
