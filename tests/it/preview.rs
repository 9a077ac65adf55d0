//! `select --preview`: keyframe-only decode, mapped back to the video's frame indices.

use crate::common::*;
use keyframer::source::codec_keyframes::{probe, CodecKeyframeSource};
use keyframer::source::{FrameSource, VideoSource};
use opencv::core::{self, Mat};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// testsrc2 (every frame differs) at 320x240, 30 fps, a codec keyframe every `gop` frames.
fn clip(dir: &Path, gop: u32, secs: u32) -> PathBuf {
    let p = dir.join(format!("g{gop}.mp4"));
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        &format!("testsrc2=size=320x240:rate=30:duration={secs}"),
        "-c:v",
        "libx264",
        "-g",
        &gop.to_string(),
        "-keyint_min",
        &gop.to_string(),
        "-sc_threshold",
        "0",
        "-pix_fmt",
        "yuv420p",
        s(&p),
    ]);
    p
}

/// `select --preview --blur --spacing 6kf` (opencv backend) of `v` into `pv`.
fn preview_args<'a>(v: &'a Path, pv: &'a Path) -> [&'a str; 10] {
    [
        "select",
        s(v),
        "-o",
        s(pv),
        "--preview",
        "--blur",
        "--spacing",
        "6kf",
        "--backend",
        "opencv",
    ]
}

fn mean_abs_diff(a: &Mat, b: &Mat) -> f64 {
    let mut d = Mat::default();
    core::absdiff(a, b, &mut d).unwrap();
    let m = core::mean(&d, &core::no_array()).unwrap();
    (m[0] + m[1] + m[2]) / 3.0
}

#[test]
fn keyframe_source_frames_are_the_video_frames_at_the_mapped_indices() {
    let d = tempfile::tempdir().unwrap();
    let v = clip(d.path(), 10, 3);
    let index = Arc::new(probe(&v).unwrap());
    assert_eq!(index.frame_count(), 90);
    assert_eq!(
        index.keyframes,
        (0..90).step_by(10).collect::<Vec<_>>(),
        "x264 with -g 10 -sc_threshold 0 puts a keyframe every 10 frames"
    );
    // All frames as OpenCV decodes them (the full analysis's view).
    let mut full = VideoSource::open(&v).unwrap();
    let mut frames = Vec::new();
    let mut ts = Vec::new();
    while let Some(f) = full.next_frame().unwrap() {
        ts.push(f.timestamp_s.unwrap());
        frames.push(f.image);
    }
    assert_eq!(frames.len(), 90);
    for (a, b) in ts.iter().zip(&index.timestamps_s) {
        assert!((a - b).abs() < 1e-3, "timestamps {a} vs {b}");
    }
    let mut src = CodecKeyframeSource::open(&v, index.clone()).unwrap();
    assert_eq!(src.metadata().frame_count, 9);
    let mut n = 0;
    while let Some(f) = src.next_frame().unwrap() {
        let k = index.keyframes[f.index];
        let diffs: Vec<f64> = (k.saturating_sub(1)..=(k + 1).min(89))
            .map(|j| mean_abs_diff(&f.image, &frames[j]))
            .collect();
        let own = mean_abs_diff(&f.image, &frames[k]);
        assert!(
            own < 2.0,
            "keyframe {k}: mean abs diff {own} to OpenCV's frame"
        );
        assert!(
            diffs.iter().all(|&x| x >= own),
            "keyframe {k}: a neighbour matches better: {diffs:?}"
        );
        n += 1;
    }
    assert_eq!(n, 9);
}

#[test]
fn preview_selects_among_codec_keyframes_and_is_never_a_cache() {
    let d = tempfile::tempdir().unwrap();
    let v = clip(d.path(), 10, 4);
    let pv = d.path().join("preview.json");
    let out = kf_loud(&preview_args(&v, &pv));
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("12 codec keyframes of 120 frames"), "{err}");
    let p = json(&pv);
    assert_eq!(p["preview"], true);
    assert_eq!(p["metadata"]["frame_count"], 120);
    assert_eq!(p["history"][0]["plugin"], "preview");
    let keys = keyframes(&pv);
    assert_eq!(keys.len(), 6, "{keys:?}");
    assert!(keys.iter().all(|k| k % 10 == 0), "{keys:?}");
    assert!(p["cache"]["sharpness"].as_array().unwrap().is_empty());
    assert_eq!(p["cache"]["timestamps_s"].as_array().unwrap().len(), 120);

    // Frame bounds and manual edits speak the video's frame indices.
    let bounded = d.path().join("bounded.json");
    kf_ok(&[
        "select",
        s(&v),
        "-o",
        s(&bounded),
        "--preview",
        "--start",
        "25",
        "--end",
        "95",
        "--add",
        "3",
        "--backend",
        "opencv",
    ]);
    assert_eq!(keyframes(&bounded), vec![3, 30, 40, 50, 60, 70, 80, 90]);

    // A full select over the preview project decodes (the preview holds no scores to reuse).
    let out = kf_loud(&[
        "select",
        s(&v),
        "-o",
        s(&pv),
        "--blur",
        "--force",
        "--backend",
        "opencv",
    ]);
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 0, "{err}");
    assert!(!err.contains("nothing decoded"), "{err}");
    let p = json(&pv);
    assert!(p.get("preview").is_none());
    assert_eq!(
        p["cache"]["sharpness"][0]["scores"]
            .as_array()
            .unwrap()
            .len(),
        120
    );
}

#[test]
fn preview_errors_are_clear() {
    let d = tempfile::tempdir().unwrap();
    let img = d.path().join("frames");
    std::fs::create_dir(&img).unwrap();
    std::fs::copy(testdata("opencv-doc/aloeL.jpg"), img.join("a.jpg")).unwrap();
    let out = kf(&[
        "select",
        s(&img),
        "-o",
        s(&d.path().join("p.json")),
        "--preview",
    ]);
    let (code, err) = code_and_stderr(&out);
    assert_ne!(code, 0);
    assert!(err.contains("--preview needs a video"), "{err}");

    // Without FFmpeg's tools on PATH the message names the package.
    let v = clip(d.path(), 10, 1);
    let empty = d.path().join("empty-bin");
    std::fs::create_dir(&empty).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args([
            "select",
            s(&v),
            "-o",
            s(&d.path().join("q.json")),
            "--preview",
            "--quiet",
        ])
        .env("PATH", &empty)
        .output()
        .unwrap();
    let (code, err) = code_and_stderr(&out);
    assert_ne!(code, 0);
    assert!(err.contains("apt-get install ffmpeg"), "{err}");
    assert!(!d.path().join("q.json").exists());
}

#[test]
fn a_preview_saves_as_a_workflow_that_runs_the_same_preview() {
    let d = tempfile::tempdir().unwrap();
    let v = clip(d.path(), 10, 4);
    let pv = d.path().join("preview.json");
    kf_ok(&preview_args(&v, &pv));
    let wf = d.path().join("preview.toml");
    kf_ok(&["workflow", "save", s(&pv), "-o", s(&wf)]);
    let text = std::fs::read_to_string(&wf).unwrap();
    assert!(text.contains("preview = true"), "{text}");
    let out = d.path().join("out");
    kf_ok(&["run", s(&wf), s(&v), "--out", s(&out)]);
    let project = out
        .join(keyframer::batch::folder_name(&v))
        .join("project.json");
    assert_eq!(json(&project)["preview"], true);
    assert_eq!(keyframes(&project), keyframes(&pv));
}
