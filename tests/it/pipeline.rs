//! The one-pass analysis pipeline: results equal to running the analyses one at a time, flow
//! stride, checkpoints that survive a kill, and re-selection from the cache without decoding.

use crate::common::*;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// A `w`x`h` pan over aloeL.jpg whose speed varies (0 to ~3 px per frame at 320 wide), with a
/// still second in the middle, `secs` seconds at 30 fps.
fn varying_pan(dir: &Path, name: &str, w: u32, h: u32, secs: u32) -> PathBuf {
    let p = dir.join(name);
    let x = "if(between(t\\,4\\,5)\\,160\\,20+40*t+12*sin(t*2.1))";
    ffmpeg(&[
        "-loop",
        "1",
        "-i",
        s(&testdata("opencv-doc/aloeL.jpg")),
        "-vf",
        &format!("crop=320:240:x='{x}':y='20+6*sin(t)',scale={w}:{h},format=yuv420p"),
        "-t",
        &secs.to_string(),
        "-r",
        "30",
        "-c:v",
        "libx264",
        "-crf",
        "18",
        s(&p),
    ]);
    p
}

fn cache(project: &Path) -> serde_json::Value {
    json(project)["cache"].clone()
}

fn movement_values(project: &Path) -> Vec<f64> {
    cache(project)["movement"][0]["series"]["values"]
        .as_array()
        .expect("movement series")
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect()
}

#[test]
fn one_pass_equals_the_analyses_one_by_one() {
    let d = tempfile::tempdir().unwrap();
    let clip = varying_pan(d.path(), "pan.mp4", 160, 120, 3);
    for backend in ["opencv", "gpu"] {
        let both = d.path().join(format!("both-{backend}.json"));
        let steps = d.path().join(format!("steps-{backend}.json"));
        let common = [s(&clip), "--backend", backend, "--spacing", "10"];
        // One pass computes sharpness and movement together.
        let mut a = vec!["select"];
        a.extend(common);
        a.extend(["--blur", "--stationary", "-o", s(&both)]);
        kf_ok(&a);
        // One at a time: movement first, then the stationary run, then sharpness, each run
        // re-using what the project already caches.
        let mut b = vec!["select"];
        b.extend(common);
        b.extend(["-o", s(&steps)]);
        kf_ok(&b);
        let mut c = b.clone();
        c.extend(["--stationary", "--force"]);
        kf_ok(&c);
        let mut e = c.clone();
        e.push("--blur");
        let out = kf_loud(&e);
        assert!(out.status.success());
        let (x, y) = (cache(&both), cache(&steps));
        assert_eq!(x["movement"], y["movement"], "{backend}: movement series");
        assert_eq!(x["sharpness"], y["sharpness"], "{backend}: sharpness");
        assert_eq!(
            x["stationary"], y["stationary"],
            "{backend}: stationary run"
        );
        assert_eq!(x["timestamps_s"], y["timestamps_s"]);
        assert_eq!(keyframes(&both), keyframes(&steps), "{backend}: keyframes");
        assert!(keyframes(&both).len() > 3);
        let n = json(&both)["metadata"]["frame_count"].as_u64().unwrap() as usize;
        assert_eq!(x["sharpness"][0]["scores"].as_array().unwrap().len(), n);
        assert_eq!(movement_values(&both).len(), n);
    }
}

#[test]
fn flow_stride_spreads_the_movement_of_each_step() {
    let d = tempfile::tempdir().unwrap();
    let clip = varying_pan(d.path(), "pan.mp4", 320, 240, 3);
    let one = d.path().join("one.json");
    let three = d.path().join("three.json");
    let base = ["select", s(&clip), "--backend", "opencv", "--spacing", "30"];
    let mut a = base.to_vec();
    a.extend(["--flow-stride", "1", "-o", s(&one)]);
    kf_ok(&a);
    let mut b = base.to_vec();
    b.extend(["--flow-stride", "3", "-o", s(&three)]);
    kf_ok(&b);
    let (v1, v3) = (movement_values(&one), movement_values(&three));
    assert_eq!(v1.len(), v3.len());
    let n = v3.len();
    assert_eq!(v3[0], 0.0);
    // Frames 3k-2, 3k-1, 3k share the movement measured from frame 3k-3 to 3k.
    for k in (3..n).step_by(3) {
        assert_eq!(v3[k - 2], v3[k], "frame {k}");
        assert_eq!(v3[k - 1], v3[k], "frame {k}");
    }
    // The last frames after the final multiple of 3 are measured too.
    assert!(v3[n - 1] > 0.0);
    // Over each step the spread movement matches the sum of consecutive movements of this
    // steady pan (flow over 3 frames vs 3 flows of 1 frame: within 15 %, summed per second).
    for sec in 0..(n / 30) {
        if sec == 4 {
            continue;
        }
        let r = sec * 30 + 1..((sec + 1) * 30 + 1).min(n);
        let (s1, s3): (f64, f64) = (v1[r.clone()].iter().sum(), v3[r].iter().sum());
        assert!(
            (s3 - s1).abs() <= 0.15 * s1.max(1.0),
            "second {sec}: stride 1 sums to {s1:.1} px, stride 3 to {s3:.1} px"
        );
    }
}

#[test]
fn a_killed_analysis_resumes_to_the_same_result() {
    kill_and_resume("opencv", 320, 240);
}

/// The gpu backend at 640x480 takes the device path (one upload, gray and an integer INTER_AREA
/// downscale on the device) through checkpoint and resume.
#[test]
fn a_killed_gpu_analysis_with_device_downscale_resumes_to_the_same_result() {
    kill_and_resume("gpu", 640, 480);
}

fn kill_and_resume(backend: &str, w: u32, h: u32) {
    let d = tempfile::tempdir().unwrap();
    let clip = varying_pan(d.path(), "pan.mp4", w, h, 10);
    let clean = d.path().join("clean.json");
    let resumed = d.path().join("resumed.json");
    let args = |p: &Path| -> Vec<String> {
        [
            "select",
            s(&clip),
            "--backend",
            backend,
            "--blur",
            "--stationary",
            "--spacing",
            "40",
            "--checkpoint-every",
            "0.3",
            "-o",
            s(p),
        ]
        .iter()
        .map(|x| x.to_string())
        .collect()
    };
    let a = args(&clean);
    kf_ok(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(
        !d.path().join("clean.json.partial").exists(),
        "checkpoint removed at the end"
    );

    let partial = d.path().join("resumed.json.partial");
    let mut child = Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args(args(&resumed))
        .arg("--quiet")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Kill it after its second checkpoint.
    let start = Instant::now();
    let mut seen = Vec::new();
    while start.elapsed() < Duration::from_secs(120) {
        if let Ok(bytes) = std::fs::read(&partial) {
            let v: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
            let frames = v["frames"].as_u64().unwrap();
            if seen.last() != Some(&frames) {
                seen.push(frames);
            }
            if seen.len() >= 2 {
                break;
            }
        }
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(
        seen.len() >= 2 && !resumed.exists(),
        "the run should be killed midway after two checkpoints (saw {seen:?})"
    );
    let done_at_kill = seen[seen.len() - 1];
    assert!(done_at_kill > 0 && done_at_kill < 300);

    let b = args(&resumed);
    let out = kf_loud(&b.iter().map(String::as_str).collect::<Vec<_>>());
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("resuming the analysis"),
        "resumed from the checkpoint:\n{err}"
    );
    assert!(!partial.exists());
    assert_eq!(keyframes(&resumed), keyframes(&clean));
    let (x, y) = (cache(&resumed), cache(&clean));
    for key in ["timestamps_s", "sharpness", "movement", "stationary"] {
        assert_eq!(
            x[key], y[key],
            "{key} after resuming at frame {done_at_kill}"
        );
    }
}

#[test]
fn reselecting_a_10000_frame_project_decodes_nothing() {
    let d = tempfile::tempdir().unwrap();
    let clip = d.path().join("long.mp4");
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "testsrc2=size=256x192:rate=100",
        "-vf",
        "crop=64:48:x='96+90*sin(t/3)':y='72+60*cos(t/4)'",
        "-frames:v",
        "10000",
        "-c:v",
        "libx264",
        "-preset",
        "ultrafast",
        "-pix_fmt",
        "yuv420p",
        s(&clip),
    ]);
    let p = d.path().join("p.json");
    let first = [
        "select",
        s(&clip),
        "--backend",
        "opencv",
        "--blur",
        "--spacing",
        "20",
        "-o",
        s(&p),
    ];
    kf_ok(&first);
    assert_eq!(json(&p)["metadata"]["frame_count"], 10000);
    let before = keyframes(&p);
    // New thresholds for every cached sampler: spacing, blur ratio and window, fps.
    let again = [
        "select",
        s(&clip),
        "--backend",
        "opencv",
        "--blur",
        "--blur-ratio",
        "0.9",
        "--blur-window",
        "5",
        "--spacing",
        "35",
        "--fps",
        "20",
        "-o",
        s(&p),
        "--force",
    ];
    let out = kf_loud(&again);
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("nothing decoded"), "{err}");
    assert!(!err.contains("analys"), "no analysis ran:\n{err}");
    let after = keyframes(&p);
    assert_ne!(before, after);
    assert!(!after.is_empty());
}

/// A GPU fault is an error, never a panic. `KEYFRAMER_TEST_GPU_FAULT=1` (a test-only hook) makes
/// the process's first dispatch invalid: `select` and `flow` warn naming the fault and redo the
/// work on opencv (exit 0, the keyframes of `--backend opencv`, the project says opencv); `bench`,
/// which has no opencv to fall back to, exits 1 with the fault in its message.
#[test]
fn a_gpu_fault_is_warned_and_the_analysis_redone_on_opencv() {
    let d = tempfile::tempdir().unwrap();
    let clip = varying_pan(d.path(), "pan.mp4", 160, 120, 3);
    let faulty = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_keyframer"))
            .args(args)
            .env("KEYFRAMER_TEST_GPU_FAULT", "1")
            .output()
            .unwrap();
        let (code, err) = code_and_stderr(&out);
        assert!(!err.contains("panicked"), "{err}");
        (code, err)
    };
    let fault = "dispatch group size dimension";
    fn select<'a>(clip: &'a Path, backend: &'a str, project: &'a Path) -> [&'a str; 9] {
        let (c, p) = (s(clip), s(project));
        [
            "select",
            c,
            "--blur",
            "--spacing",
            "10",
            "--backend",
            backend,
            "-o",
            p,
        ]
    }
    let g = d.path().join("gpu.json");
    let (code, err) = faulty(&select(&clip, "gpu", &g));
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        err.matches("the analysis failed on the gpu backend (")
            .count(),
        1,
        "{err}"
    );
    assert!(err.contains(fault), "the warning names the fault: {err}");
    assert!(err.contains("redoing it on the opencv backend"), "{err}");
    let o = d.path().join("opencv.json");
    kf_ok(&select(&clip, "opencv", &o));
    assert!(keyframes(&o).len() >= 3, "{:?}", keyframes(&o));
    assert_eq!(keyframes(&g), keyframes(&o));
    let c = cache(&g);
    assert_eq!(c["sharpness"][0]["backend"], "opencv");
    assert_eq!(c["movement"][0]["backend"], "opencv");

    let (a, b) = (
        testdata("opencv-doc/basketball1.png"),
        testdata("opencv-doc/basketball2.png"),
    );
    let flo = d.path().join("f.flo");
    let (code, err) = faulty(&["flow", s(&a), s(&b), "-o", s(&flo), "--backend", "gpu"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("the flow failed on the gpu backend ("),
        "{err}"
    );
    assert!(err.contains("flow (opencv) ->"), "{err}");

    let (code, err) = faulty(&["bench", "sharpness", "--frames", "1"]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("error: GPU: ") && err.contains(fault), "{err}");
}
