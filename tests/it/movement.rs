//! Camera-movement samplers on synthetic clips with known camera motion: a hover inside a pan
//! (stationary) and a pan whose speed varies 5x (spacing), on both backends.

use crate::common::*;
use opencv::core::{Mat, Rect, Scalar, Size, Vector};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};
use std::path::{Path, PathBuf};

/// Renders frames at crop positions `xs` (640x360 window of aloeL.jpg at y = 300, shown at
/// 320x180), with `objects(i)` small moving squares drawn, and encodes them at 30 fps.
fn render(
    dir: &Path,
    name: &str,
    xs: &[i32],
    objects: impl Fn(usize) -> Vec<(i32, i32)>,
) -> PathBuf {
    let photo = imgcodecs::imread(
        testdata("opencv-doc/aloeL.jpg").to_str().unwrap(),
        imgcodecs::IMREAD_COLOR,
    )
    .unwrap();
    let frames = dir.join(format!("{name}-frames"));
    std::fs::create_dir_all(&frames).unwrap();
    for (i, &x) in xs.iter().enumerate() {
        let crop = Mat::roi(&photo, Rect::new(x, 300, 640, 360))
            .unwrap()
            .try_clone()
            .unwrap();
        let mut small = Mat::default();
        imgproc::resize(
            &crop,
            &mut small,
            Size::new(320, 180),
            0.0,
            0.0,
            imgproc::INTER_AREA,
        )
        .unwrap();
        for (ox, oy) in objects(i) {
            imgproc::rectangle(
                &mut small,
                Rect::new(ox, oy, 10, 10),
                Scalar::new(20.0, 240.0, 250.0, 0.0),
                -1,
                imgproc::LINE_8,
                0,
            )
            .unwrap();
        }
        imgcodecs::imwrite(
            frames.join(format!("f{i:04}.png")).to_str().unwrap(),
            &small,
            &Vector::new(),
        )
        .unwrap();
    }
    let clip = dir.join(format!("{name}.mp4"));
    encode_frames(&frames, "16", &clip);
    clip
}

fn select_args<'a>(
    clip: &'a Path,
    project: &'a Path,
    backend: &'a str,
    extra: &[&'a str],
) -> Vec<&'a str> {
    let mut args = vec![
        "select",
        s(clip),
        "-o",
        s(project),
        "--force",
        "--backend",
        backend,
        "--analysis-width",
        "320",
    ];
    args.extend_from_slice(extra);
    args
}

fn select(clip: &Path, project: &Path, backend: &str, extra: &[&str]) -> Vec<usize> {
    kf_ok(&select_args(clip, project, backend, extra));
    keyframes(project)
}

/// Pan 60 frames (4 crop px = 2 output px per frame), hover 90 frames (3 s) while three small
/// squares move, pan 60 frames.
#[test]
fn stationary_drops_the_hover_not_the_pans() {
    let d = tempfile::tempdir().unwrap();
    let mut xs = Vec::new();
    let mut x = 20;
    for i in 0..210 {
        if !(60..150).contains(&i) {
            x += 4;
        }
        xs.push(x);
    }
    let clip = render(d.path(), "hover", &xs, |i| {
        if (60..150).contains(&i) {
            let t = (i - 60) as i32;
            vec![(20 + 3 * t, 40), (280 - 2 * t, 120), (150, 10 + t)]
        } else {
            Vec::new()
        }
    });
    let mut by_backend = Vec::new();
    for backend in ["gpu", "opencv"] {
        let p = d.path().join(format!("hover-{backend}.json"));
        let keys = select(
            &clip,
            &p,
            backend,
            &["--stationary", "--stationary-threshold", "1.5"],
        );
        let in_hover = keys.iter().filter(|&&k| (61..150).contains(&k)).count();
        assert!(
            in_hover <= 1,
            "{backend}: {in_hover} keyframes inside the hover: {keys:?}"
        );
        for i in (1..60).chain(151..210) {
            assert!(
                keys.contains(&i),
                "{backend}: moving frame {i} dropped: {keys:?}"
            );
        }
        by_backend.push(keys);
    }
    assert_eq!(
        by_backend[0], by_backend[1],
        "gpu and opencv select different keyframes"
    );

    // --auto proposes a threshold from a sample, explains it, and gives the same verdict.
    let p = d.path().join("hover-auto.json");
    let out = kf_loud(&select_args(
        &clip,
        &p,
        "opencv",
        &["--stationary", "--auto"],
    ));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("stationary --auto: sampled") && err.contains("geometric mean"),
        "{err}"
    );
    let keys = keyframes(&p);
    assert!(
        keys.iter().filter(|&&k| (61..150).contains(&k)).count() <= 1,
        "{keys:?}"
    );
    assert!(
        (1..60).chain(151..210).all(|i| keys.contains(&i)),
        "{keys:?}"
    );

    // Re-selecting over that project reuses its proposal (no second sample, the same threshold);
    // another movement measurement samples again.
    let threshold = |p: &Path| -> f64 {
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap();
        v["history"]
            .as_array()
            .unwrap()
            .iter()
            .find(|e| e["plugin"] == "stationary")
            .unwrap()["params"]["threshold_px"]
            .as_f64()
            .unwrap()
    };
    let first = threshold(&p);
    let again = kf_loud(&select_args(
        &clip,
        &p,
        "opencv",
        &["--stationary", "--auto"],
    ));
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(again.status.success(), "{err}");
    assert!(
        err.contains("proposed from a movement sample when") && !err.contains("sampled"),
        "{err}"
    );
    assert_eq!(threshold(&p), first);
    assert_eq!(keyframes(&p), keys);
    let other = kf_loud(&select_args(
        &clip,
        &p,
        "opencv",
        &["--stationary", "--auto", "--winsize", "21"],
    ));
    let err = String::from_utf8_lossy(&other.stderr);
    assert!(err.contains("stationary --auto: sampled"), "{err}");
}

fn cv(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt() / m
}

/// Speed varies between 1 and 5 crop px per frame; spacing evens out the displacement between
/// keyframes far better than a fixed rate with the same number of keyframes.
#[test]
fn spacing_evens_out_camera_displacement() {
    let d = tempfile::tempdir().unwrap();
    let n = 200;
    let mut pos = 0.0f64;
    let mut xs = Vec::new();
    for i in 0..n {
        xs.push(20 + pos.round() as i32);
        let phase = 2.0 * std::f64::consts::PI * i as f64 / n as f64;
        pos += 1.0 + 4.0 * (0.5 - 0.5 * phase.cos());
    }
    let clip = render(d.path(), "speed", &xs, |_| Vec::new());
    let displacement = |keys: &[usize]| -> Vec<f64> {
        keys.windows(2)
            .map(|w| f64::from(xs[w[1]] - xs[w[0]]))
            .collect()
    };
    let mut by_backend = Vec::new();
    for backend in ["gpu", "opencv"] {
        let p = d.path().join(format!("speed-{backend}.json"));
        let spaced = select(&clip, &p, backend, &["--spacing", "30"]);
        by_backend.push(spaced.clone());
        let count = spaced.len();
        assert!(count >= 8, "{backend}: {spaced:?}");
        let rate = count as f64 / (n as f64 / 30.0);
        let q = d.path().join(format!("fps-{backend}.json"));
        let fixed = select(&clip, &q, backend, &["--fps", &format!("{rate}")]);
        assert!(
            (fixed.len() as i64 - count as i64).abs() <= 1,
            "{} vs {count}",
            fixed.len()
        );
        let (cs, cf) = (cv(&displacement(&spaced)), cv(&displacement(&fixed)));
        eprintln!("{backend}: {count} keyframes, CV spacing {cs:.3}, CV fps {cf:.3}");
        assert!(cf >= 2.0 * cs, "{backend}: CV spacing {cs} vs fps {cf}");
    }
    assert_eq!(
        by_backend[0], by_backend[1],
        "gpu and opencv select different keyframes"
    );
    let p = d.path().join("speed-auto.json");
    let out = kf_loud(&select_args(&clip, &p, "opencv", &["--spacing", "auto"]));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && err.contains("spacing auto: spacing threshold 48.0 px"),
        "{err}"
    );
}

/// The flags `MovementRequest::to_flags` and `Step::to_flags` write give `select` the same
/// movement measure and steps: the project records them as given.
#[test]
fn to_flags_give_select_the_same_request_and_steps() {
    use keyframer::params::{Derotate, FarnebackParams, MovementRequest, Statistic};
    use keyframer::steps::{Applied, Step, Threshold};
    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "clip.mp4", 160, 120, "30", 1.0);
    let project = d.path().join("p.json");
    let request = MovementRequest {
        farneback: FarnebackParams {
            levels: 2,
            poly_n: 7,
            poly_sigma: 1.5,
            gaussian: true,
            ..FarnebackParams::default()
        },
        statistic: Statistic::TrimmedMean { trim: 0.2 },
        analysis_width: 96,
        stride: 3,
        derotate: Some(Derotate { hfov_deg: 80.5 }),
        sphere: None,
    };
    let steps = [
        Step::Spacing {
            threshold: Threshold::Px(3.25),
        },
        Step::Manual {
            add: vec![7, 8],
            remove: Vec::new(),
        },
    ];
    let mut flags = request.to_flags();
    flags.extend(steps.iter().flat_map(Step::to_flags));
    let mut args = vec!["select", s(&clip), "-o", s(&project), "--backend", "opencv"];
    args.extend(flags.iter().map(String::as_str));
    kf_ok(&args);
    let p = keyframer::project::Project::load(&project).unwrap();
    let applied: Vec<Applied> = p.history.iter().map(|e| e.applied.clone()).collect();
    let spacing = applied.iter().find(|a| a.step() == Some(steps[0].clone()));
    assert_eq!(spacing.unwrap().analysis().1, Some(request), "{flags:?}");
    assert!(applied.iter().any(|a| a.step() == Some(steps[1].clone())));
}
