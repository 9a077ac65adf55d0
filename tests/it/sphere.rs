//! Analysis on the sphere: on an equirectangular input a yaw turn is an exact column roll, and
//! `select --projection equirect` measures it as no movement (the joint derotation of the horizon
//! views), where the same frames analysed as pinhole ones move by the roll; frames that change
//! otherwise (a zoom) still move. gpu and opencv agree. Sharpness is scored on the band
//! |latitude| < 45°.

use crate::common::{json, keyframes, kf_ok, s, testdata};
use opencv::core::{self, Mat, Rect, Size, Vector};
use opencv::imgcodecs;
use opencv::prelude::*;
use std::path::{Path, PathBuf};

/// Width and height of the ERP frames (twice the default analysis width: a roll by an even
/// number of columns stays an exact roll after the 2:1 INTER_AREA resize).
const W: i32 = 640;
const H: i32 = 320;
/// Columns rolled per frame during the turn (2.25°: 22.5° a second at the 10 fps given).
const ROLL: i32 = 4;
/// Frames of the turn (0..TURN), then frames zoomed on top of the last roll.
const TURN: usize = 20;
const ZOOMED: usize = 8;

/// A 2:1 image of two photographs side by side (texture at every scale, all around).
fn panorama() -> Mat {
    let mut halves = Vector::<Mat>::new();
    for name in ["opencv-doc/baboon.jpg", "opencv-doc/building.jpg"] {
        let img = imgcodecs::imread(s(&testdata(name)), imgcodecs::IMREAD_COLOR).unwrap();
        let mut half = Mat::default();
        let size = Size::new(W / 2, H);
        opencv::imgproc::resize(&img, &mut half, size, 0.0, 0.0, opencv::imgproc::INTER_AREA)
            .unwrap();
        halves.push(half);
    }
    let mut out = Mat::default();
    core::hconcat(&halves, &mut out).unwrap();
    out
}

/// `img` turned right by `k` columns (the ERP of a yaw turn: columns wrap around).
fn roll(img: &Mat, k: i32) -> Mat {
    let k = k.rem_euclid(W);
    let mut parts = Vector::<Mat>::new();
    parts.push(
        img.col_range(&core::Range::new(k, W).unwrap())
            .unwrap()
            .try_clone()
            .unwrap(),
    );
    if k > 0 {
        parts.push(
            img.col_range(&core::Range::new(0, k).unwrap())
                .unwrap()
                .try_clone()
                .unwrap(),
        );
    }
    let mut out = Mat::default();
    core::hconcat(&parts, &mut out).unwrap();
    out
}

/// `img` zoomed by `z` about its centre (real change: no rotation of the sphere makes it).
fn zoom(img: &Mat, z: f64) -> Mat {
    let (cw, ch) = (
        (f64::from(W) / z).round() as i32,
        (f64::from(H) / z).round() as i32,
    );
    let crop = Mat::roi(img, Rect::new((W - cw) / 2, (H - ch) / 2, cw, ch)).unwrap();
    let mut out = Mat::default();
    opencv::imgproc::resize(
        &crop,
        &mut out,
        Size::new(W, H),
        0.0,
        0.0,
        opencv::imgproc::INTER_LINEAR,
    )
    .unwrap();
    out
}

/// The turn then the zoom, as a folder of PNG frames.
fn turn_then_zoom(dir: &Path) -> PathBuf {
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    let base = panorama();
    for i in 0..TURN + ZOOMED {
        let turned = roll(&base, ROLL * i.min(TURN - 1) as i32);
        let img = match i.checked_sub(TURN - 1) {
            Some(z) if z > 0 => zoom(&turned, 1.0 + 0.03 * z as f64),
            _ => turned,
        };
        let p = frames.join(format!("f{i:03}.png"));
        imgcodecs::imwrite(s(&p), &img, &Vector::new()).unwrap();
    }
    frames
}

/// `select` on `frames` into `project` with `extra` flags; returns the keyframes and the
/// movement series.
fn select(frames: &Path, project: &Path, extra: &[&str]) -> (Vec<usize>, Vec<f64>) {
    let mut args = vec!["select", s(frames), "-o", s(project), "--images-fps", "10"];
    args.extend_from_slice(extra);
    kf_ok(&args);
    let p = json(project);
    let values = p["cache"]["movement"][0]["series"]["values"]
        .as_array()
        .unwrap_or_else(|| panic!("no movement series in {p}"))
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    (keyframes(project), values)
}

#[test]
fn turning_on_the_spot_adds_no_keyframes_on_an_equirect_input() {
    let d = tempfile::tempdir().unwrap();
    let frames = turn_then_zoom(d.path());
    let spacing = ["--spacing", "20", "--backend", "opencv"];
    let (pinhole_keys, pinhole) = select(
        &frames,
        &d.path().join("pinhole.json"),
        &[&spacing[..], &["--projection", "pinhole"]].concat(),
    );
    let (keys, sphere) = select(
        &frames,
        &d.path().join("sphere.json"),
        &[&spacing[..], &["--projection", "equirect"]].concat(),
    );
    let turn = |v: &[f64]| v[1..TURN].iter().sum::<f64>();
    let zoomed = |v: &[f64]| v[TURN..].iter().sum::<f64>();
    eprintln!(
        "turn of {} frames ({ROLL} columns each): movement pinhole {:.2} px, equirect {:.3} px; \
         zoom of {ZOOMED} frames: pinhole {:.2} px, equirect {:.2} px",
        TURN - 1,
        turn(&pinhole),
        turn(&sphere),
        zoomed(&pinhole),
        zoomed(&sphere)
    );
    eprintln!("keyframes pinhole {pinhole_keys:?}, equirect {keys:?}");
    let in_turn = |k: &[usize]| k.iter().filter(|&&i| i > 0 && i < TURN).count();
    assert!(in_turn(&pinhole_keys) >= 3, "pinhole: the turn is movement");
    assert_eq!(in_turn(&keys), 0, "equirect: the turn is no movement");
    // What is left of the turn is the flow's own error (the true rotation leaves ~8 % of a
    // rendered turn's flow: kernels::sphere::CLAMPS_PX).
    assert!(turn(&sphere) < 0.2 * turn(&pinhole));
    assert!(keys.iter().any(|&i| i >= TURN), "the zoom is movement");
    assert!(zoomed(&sphere) > 0.3 * zoomed(&pinhole));

    // The gpu backend renders the views with the remap shader, measures and fits on the device.
    let (gpu_keys, gpu) = select(
        &frames,
        &d.path().join("gpu.json"),
        &[
            "--spacing",
            "20",
            "--backend",
            "gpu",
            "--projection",
            "equirect",
        ],
    );
    let used = &json(&d.path().join("gpu.json"))["cache"]["movement"][0]["backend"];
    eprintln!(
        "gpu ({used}): keyframes {gpu_keys:?}, turn {:.3} px, zoom {:.2} px",
        turn(&gpu),
        zoomed(&gpu)
    );
    assert_eq!(used, "gpu");
    assert_eq!(gpu_keys, keys, "gpu and opencv select the same keyframes");
    // The project's bound for movement, gpu vs opencv (relative; 0.01 px absolute below 1 px).
    let rel = keyframer::kernels::tolerance::MOVEMENT_REL;
    for (i, (g, c)) in gpu.iter().zip(&sphere).enumerate() {
        assert!(
            (g - c).abs() <= rel * c.abs().max(1.0),
            "frame {i}: gpu {g}, opencv {c}"
        );
    }
}

/// `workflow save` keeps the projection, `run` measures on the sphere again; a bad projection in
/// a workflow is refused naming the file, line and key.
#[test]
fn workflows_carry_the_projection() {
    let d = tempfile::tempdir().unwrap();
    let frames = turn_then_zoom(d.path());
    let p = d.path().join("p.json");
    let flags = [
        "--spacing",
        "20",
        "--backend",
        "opencv",
        "--projection",
        "equirect",
    ];
    let (keys, _) = select(&frames, &p, &flags);
    let w = d.path().join("w.toml");
    kf_ok(&["workflow", "save", s(&p), "-o", s(&w)]);
    let text = std::fs::read_to_string(&w).unwrap();
    assert!(text.contains("projection = \"equirect\""), "{text}");
    let runs = d.path().join("runs");
    kf_ok(&["run", s(&w), s(&frames), "--out", s(&runs)]);
    let ran = runs
        .join(keyframer::batch::folder_name(&frames))
        .join("project.json");
    assert_eq!(keyframes(&ran), keys);
    assert_eq!(json(&ran)["projection"], "equirect");

    let bad = d.path().join("bad.toml");
    std::fs::write(&bad, text.replace("\"equirect\"", "\"fisheye\"")).unwrap();
    let out = crate::common::kf(&["run", s(&bad), s(&frames), "--out", s(&runs)]);
    let (code, err) = crate::common::code_and_stderr(&out);
    assert_ne!(code, 0);
    assert!(
        err.contains("bad.toml:") && err.contains("analysis.projection"),
        "{err}"
    );
}

/// The stationary step (reference mode, run on the device on gpu) on the sphere: both backends
/// agree, and the turn adds far fewer keyframes than on pinhole frames. Not none: each frame is
/// compared with the last keyframe, so the rotation between them grows through a turn, and the
/// flow's error grows with it (a residual of 0.4 px at 4.5° a pair, 2.3 px at 9°: docs/360.md).
#[test]
fn stationary_on_the_sphere_agrees_across_backends() {
    let d = tempfile::tempdir().unwrap();
    let frames = turn_then_zoom(d.path());
    let stationary = ["--stationary", "--stationary-threshold", "6"];
    let mut got = Vec::new();
    for (backend, projection) in [
        ("opencv", "pinhole"),
        ("opencv", "equirect"),
        ("gpu", "equirect"),
    ] {
        let p = d.path().join(format!("{backend}-{projection}.json"));
        let flags = [
            &stationary[..],
            &["--backend", backend, "--projection", projection],
        ]
        .concat();
        let (keys, _) = select(&frames, &p, &flags);
        eprintln!("{backend} {projection}: stationary keyframes {keys:?}");
        assert_eq!(json(&p)["cache"]["movement"][0]["backend"], backend);
        got.push(keys);
    }
    assert_eq!(got[1], got[2], "gpu and opencv keep the same frames");
    let in_turn = |k: &[usize]| k.iter().filter(|&&i| i > 0 && i < TURN).count();
    assert!(
        2 * in_turn(&got[1]) <= in_turn(&got[0]),
        "the turn adds at most half the pinhole analysis' keyframes"
    );
    assert!(got[1].iter().any(|&i| i >= TURN), "the zoom is movement");
}

/// The device's joint fit (shaders/movement.wgsl, `derotate = 2`) equals its host twin on one
/// stacked flow: a turn of the sphere with a fifth of every view's pixels failed (zero flow).
#[test]
fn joint_fit_on_device_equals_the_hosts() {
    use keyframer::equirect::analysis_views;
    use keyframer::kernels::movement::{self, MovementGpu};
    use keyframer::kernels::sphere::SphereField;
    use keyframer::kernels::tolerance::{rel_err, DEROTATED_SAME_FLOW_REL, ROTATION_ABS};
    use keyframer::params::Statistic;
    let views = analysis_views(4, 90.0, 400);
    let field = SphereField::new(&views).unwrap();
    let n = views[0].size;
    let truth = movement::matrix([0.01, -0.05, 0.02]);
    let mut flow = Vec::new();
    for k in 0..views.len() {
        let r = field.view_rotation(k, &truth);
        for j in 0..n {
            for i in 0..n {
                let failed = (i * 7 + j * 3 + k as u32).is_multiple_of(5);
                let f = field.field().rotation_flow(i, j, &r);
                flow.extend_from_slice(if failed { &[0.0, 0.0] } else { &f });
            }
        }
    }
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None).unwrap());
    let buf = ctx.storage_buffer("flow", (flow.len() * 4) as u64);
    ctx.write(&buf, 0, bytemuck::cast_slice(&flow));
    let stat = MovementGpu::joint(ctx.clone(), &buf, &field).unwrap();
    let on_device = stat.rotation().unwrap().unwrap();
    let host = field.fit_cpu(&flow).unwrap();
    let diff = (0..9)
        .map(|k| (on_device[k / 3][k % 3] - host[k / 3][k % 3]).abs())
        .fold(0.0f32, f32::max);
    let error = (0..9)
        .map(|k| (host[k / 3][k % 3] - truth[k / 3][k % 3]).abs())
        .fold(0.0f32, f32::max);
    eprintln!("joint rotation: device vs host {diff:e}, host vs truth {error:e}");
    assert!(diff <= ROTATION_ABS, "device {on_device:?} host {host:?}");
    // The failed fifth still pulls, each pixel by at most the last clamp (1 px): 2.6e-3 of a
    // 0.055 rad turn here.
    assert!(
        error < 5e-3,
        "the clamped fit finds the turn despite the failed pixels"
    );
    for s in [Statistic::Median, Statistic::TrimmedMean { trim: 0.1 }] {
        let device = stat.compute(s).unwrap();
        let residual = field.residual_magnitudes(&flow, &host).unwrap();
        let host = movement::cpu(&residual, s).unwrap();
        eprintln!("{s:?}: device {device}, host {host}");
        assert!(
            rel_err(device, host) <= DEROTATED_SAME_FLOW_REL || (device - host).abs() < 1e-5,
            "{s:?}: device {device} host {host}"
        );
    }
}

/// `select` on `frames` into `project` with `extra` flags (no movement asked).
fn score_only(frames: &Path, project: &Path, extra: &[&str]) {
    let mut args = vec!["select", s(frames), "-o", s(project), "--images-fps", "10"];
    args.extend_from_slice(extra);
    kf_ok(&args);
}

/// The scores of `project`'s one sharpness series and its `rows` record.
fn sharpness_series(project: &Path) -> (Vec<f64>, serde_json::Value) {
    let p = json(project);
    let series = p["cache"]["sharpness"].as_array().unwrap();
    assert_eq!(series.len(), 1, "one series per metric: {series:?}");
    let scores = (series[0]["scores"].as_array().unwrap().iter())
        .map(|v| v.as_f64().unwrap())
        .collect();
    (scores, series[0]["rows"].clone())
}

/// Tenengrad and Laplacian variance (ksize 3) of the rows `first..first + count` of `img`'s gray,
/// cut out as an image of their own, computed here with OpenCV directly.
fn band_scores(img: &Mat, first: i32, count: i32) -> (f64, f64) {
    let band = Mat::roi(img, Rect::new(0, first, W, count))
        .unwrap()
        .try_clone()
        .unwrap();
    let mut gray = Mat::default();
    opencv::imgproc::cvt_color(&band, &mut gray, opencv::imgproc::COLOR_BGR2GRAY, 0).unwrap();
    let sobel = |dx, dy| {
        let mut g = Mat::default();
        opencv::imgproc::sobel(&gray, &mut g, core::CV_16S, dx, dy, 3, 1.0, 0.0, 4).unwrap();
        g.dot(&g).unwrap()
    };
    let tenengrad = (sobel(1, 0) + sobel(0, 1)) / f64::from(W * count);
    let mut lap = Mat::default();
    opencv::imgproc::laplacian(&gray, &mut lap, core::CV_64F, 3, 1.0, 0.0, 4).unwrap();
    let (mut mean, mut std) = (Vector::<f64>::new(), Vector::<f64>::new());
    core::mean_std_dev(&lap, &mut mean, &mut std, &core::no_array()).unwrap();
    (tenengrad, std.get(0).unwrap().powi(2))
}

/// On an equirect input both backends score the band |latitude| < 45° (rows H/4 to 3H/4) as an
/// image of its own, equal to the same scores computed here on the cropped frames; a project
/// cached with whole-frame scores is re-scored on the band; `score --projection equirect` gives
/// the same scores.
#[test]
fn sharpness_on_the_sphere_scores_the_band() {
    let d = tempfile::tempdir().unwrap();
    let frames = turn_then_zoom(d.path());
    let (first, count) = (H / 4, H / 2);
    let truth: Vec<(f64, f64)> = (0..TURN + ZOOMED)
        .map(|i| {
            let p = frames.join(format!("f{i:03}.png"));
            let img = imgcodecs::imread(s(&p), imgcodecs::IMREAD_COLOR).unwrap();
            band_scores(&img, first, count)
        })
        .collect();
    let rel = keyframer::kernels::tolerance::SHARPNESS_REL;
    let close = |a: f64, b: f64| (a - b).abs() <= rel * b.abs().max(1e-12);
    for (metric, pick) in [("tenengrad", 0), ("laplacian-k3", 1)] {
        for backend in ["opencv", "gpu"] {
            let p = d.path().join(format!("{metric}-{backend}.json"));
            let flags = ["--blur", "--blur-metric", metric, "--backend", backend];
            let flags = [&flags[..], &["--projection", "equirect"]].concat();
            score_only(&frames, &p, &flags);
            let (scores, rows) = sharpness_series(&p);
            assert_eq!(rows, serde_json::json!({"first": first, "count": count}));
            assert_eq!(json(&p)["cache"]["sharpness"][0]["backend"], backend);
            assert_eq!(scores.len(), truth.len());
            for (i, (got, t)) in scores.iter().zip(&truth).enumerate() {
                let want = if pick == 0 { t.0 } else { t.1 };
                assert!(
                    close(*got, want),
                    "{metric} {backend} frame {i}: {got} vs {want}"
                );
            }
        }
    }
    // A project whose cache holds whole-frame scores (as before the band) is re-scored.
    let p = d.path().join("tenengrad-opencv.json");
    let mut old = json(&p);
    let series = &mut old["cache"]["sharpness"][0];
    series.as_object_mut().unwrap().remove("rows");
    series["scores"] = serde_json::json!(vec![1.0; TURN + ZOOMED]);
    std::fs::write(&p, serde_json::to_string(&old).unwrap()).unwrap();
    let flags = ["--blur", "--projection", "equirect", "--force"];
    score_only(&frames, &p, &flags);
    let (scores, rows) = sharpness_series(&p);
    assert_eq!(rows["first"], first);
    assert!(
        close(scores[3], truth[3].0),
        "re-scored: {} vs {}",
        scores[3],
        truth[3].0
    );
    // `score` on the same frames.
    let out = kf_ok(&["score", s(&frames), "--projection", "equirect", "--json"]);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["rows"]["count"], count);
    let scored: Vec<f64> = (v["scores"].as_array().unwrap().iter())
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert_eq!(scored, scores, "score and select agree");
}
