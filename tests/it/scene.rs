//! `keyframer-scene` (the workspace's scene tool): frame count and poses file, poses agree with the pixels (markers at known
//! world positions), hovers are still, fast turns are blurred, same seed gives the same output.

use crate::common::{code_and_stderr, json, kf_ok, s, scene, scene_ok};
use opencv::core::Mat;
use opencv::prelude::*;
use opencv::videoio;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Generates (once per test run) a sequence under the test tmpdir with `args` after the folder.
fn generate(name: &str, args: &[&str]) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("scene")
        .join(name);
    let mut all = vec![s(&dir), "--force", "--size", "320x180", "--fps", "10"];
    all.extend_from_slice(args);
    scene_ok(&all);
    dir
}

/// A 10 s survey with markers: reaches its first fast turn after about 4 s.
fn survey() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        generate(
            "survey",
            &[
                "--seconds",
                "10",
                "--blur-samples",
                "6",
                "--markers",
                "--seed",
                "7",
            ],
        )
    })
}

/// All frames of a video as BGR Mats.
fn decode(video: &Path) -> Vec<Mat> {
    let mut cap = videoio::VideoCapture::from_file(s(video), videoio::CAP_FFMPEG).unwrap();
    assert!(cap.is_opened().unwrap());
    let mut frames = Vec::new();
    loop {
        let mut m = Mat::default();
        if !cap.read(&mut m).unwrap() || m.empty() {
            break;
        }
        frames.push(m);
    }
    frames
}

/// (timestamp, [tx ty tz qx qy qz qw]) per line of poses.tum.
pub fn poses(dir: &Path) -> Vec<(f64, [f64; 7])> {
    std::fs::read_to_string(dir.join("poses.tum"))
        .unwrap()
        .lines()
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            assert_eq!(v.len(), 8, "line `{l}`");
            (v[0], [v[1], v[2], v[3], v[4], v[5], v[6], v[7]])
        })
        .collect()
}

/// Distance between the camera centres of two poses.
pub fn distance(p: &[f64; 7], q: &[f64; 7]) -> f64 {
    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
}

/// Camera-to-world rotation matrix (rows) of a quaternion (x, y, z, w).
pub fn rotation(q: &[f64]) -> [[f64; 3]; 3] {
    let (x, y, z, w) = (q[0], q[1], q[2], q[3]);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - z * w),
            2.0 * (x * z + y * w),
        ],
        [
            2.0 * (x * y + z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - x * w),
        ],
        [
            2.0 * (x * z - y * w),
            2.0 * (y * z + x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

fn pixel(m: &Mat, x: i32, y: i32) -> [f64; 3] {
    let p = m.at_2d::<opencv::core::Vec3b>(y, x).unwrap();
    [p[0] as f64, p[1] as f64, p[2] as f64]
}

/// A video.SRT in a scene folder whose scene.json (made before the sidecar existed) does not
/// record one is not keyframer-scene's: `--force` refuses it and leaves the folder as it was.
#[test]
fn scene_force_leaves_a_sidecar_it_did_not_write() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("old");
    std::fs::create_dir(&dir).unwrap();
    std::fs::write(
        dir.join("scene.json"),
        r#"{"generator": "keyframer-scene"}"#,
    )
    .unwrap();
    std::fs::write(dir.join("video.SRT"), "someone else's").unwrap();
    let out = scene(&[s(&dir), "--force", "--seconds", "1", "--size", "160x90"]);
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("video.SRT") && err.contains("did not write it"),
        "{err}"
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("video.SRT")).unwrap(),
        "someone else's"
    );
    let mut left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    left.sort();
    assert_eq!(left, ["scene.json", "video.SRT"]);
}

/// video.SRT holds every frame's true position: keyframer's parser reads it back, and the
/// distances and heights it gives are those of poses.tum.
#[test]
fn scene_srt_gives_every_frame_its_true_position() {
    use keyframer::source::telemetry::{creation_time, distance_m, read_dji_srt, sidecar_of};
    let dir = survey();
    let video = dir.join("video.mp4");
    let srt = sidecar_of(&video).expect("video.SRT beside video.mp4");
    let track = read_dji_srt(&srt).unwrap();
    assert!(track.warnings.is_empty(), "{:?}", track.warnings);
    let p = poses(dir);
    let desc = json(&dir.join("scene.json"));
    let tel = &desc["telemetry"];
    let takeoff = tel["takeoff_z_m"].as_f64().unwrap();
    let alt0 = tel["origin"]["alt_m"].as_f64().unwrap();
    assert_eq!(track.fixes.len(), p.len());
    let f0 = &track.fixes[0];
    for (i, (f, (t, v))) in track.fixes.iter().zip(&p).enumerate() {
        assert!((f.t_s - t).abs() < 1e-3, "frame {i}: {} vs {t}", f.t_s);
        let truth = (v[0] - p[0].1[0]).hypot(v[1] - p[0].1[1]);
        let d = distance_m(f0, f);
        assert!((d - truth).abs() < 0.01, "frame {i}: {d} m vs {truth} m");
        assert!(
            (f.rel_alt_m.unwrap() - (v[2] - takeoff)).abs() < 1e-3,
            "frame {i}"
        );
        assert!(
            (f.abs_alt_m.unwrap() - (v[2] + alt0)).abs() < 1e-3,
            "frame {i}"
        );
        let forward_z = rotation(&v[3..])[2][2];
        let pitch = forward_z.asin().to_degrees();
        assert!(
            (f.gimbal_pitch_deg.unwrap() - pitch).abs() < 0.006,
            "frame {i}"
        );
        assert_eq!(
            f.focal_35mm,
            tel["focal_35mm"]
                .as_f64()
                .map(|x| (x * 100.0).round() / 100.0)
        );
    }
    let created = creation_time(&video).unwrap().unwrap();
    let want = tel["start_utc"].as_str().unwrap();
    assert_eq!(
        created,
        time::OffsetDateTime::parse(want, &time::format_description::well_known::Rfc3339).unwrap()
    );
}

#[test]
fn scene_video_has_one_pose_per_frame() {
    let dir = survey();
    let frames = decode(&dir.join("video.mp4"));
    let p = poses(dir);
    let desc = json(&dir.join("scene.json"));
    assert_eq!(frames.len(), 100);
    assert_eq!(p.len(), frames.len());
    assert_eq!(desc["frame_count"].as_u64(), Some(100));
    assert_eq!((frames[0].cols(), frames[0].rows()), (320, 180));
    for (i, (t, v)) in p.iter().enumerate() {
        assert!(
            (t - i as f64 / 10.0).abs() < 1e-6,
            "frame {i}: timestamp {t}"
        );
        let n = (v[3] * v[3] + v[4] * v[4] + v[5] * v[5] + v[6] * v[6]).sqrt();
        assert!((n - 1.0).abs() < 1e-6, "frame {i}: |q| = {n}");
    }
    // The camera moves and looks down (its z axis has a negative world z component).
    let first = &p[0].1;
    let last = &p[p.len() - 1].1;
    let moved = ((first[0] - last[0]).powi(2) + (first[1] - last[1]).powi(2)).sqrt();
    assert!(moved > 20.0, "moved {moved} m");
    let r = rotation(&first[3..]);
    assert!(
        r[2][2] < -0.5,
        "camera z axis {:?}",
        [r[0][2], r[1][2], r[2][2]]
    );
    // A non-empty folder is refused without --force, and left alone.
    let out = scene(&[s(dir), "--seconds", "1", "--size", "320x180"]);
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("--force"), "{err}");
    assert_eq!(poses(dir).len(), 100);
}

#[test]
fn scene_markers_appear_where_the_poses_project_them() {
    let dir = survey();
    let frames = decode(&dir.join("video.mp4"));
    let p = poses(dir);
    let desc = json(&dir.join("scene.json"));
    let k = &desc["intrinsics"];
    let (fx, fy, cx, cy) = (
        k["fx"].as_f64().unwrap(),
        k["fy"].as_f64().unwrap(),
        k["cx"].as_f64().unwrap(),
        k["cy"].as_f64().unwrap(),
    );
    let markers: Vec<[f64; 3]> = desc["objects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|o| o["kind"] == "marker")
        .map(|o| {
            let c = o["centre"].as_array().unwrap();
            [
                c[0].as_f64().unwrap(),
                c[1].as_f64().unwrap(),
                c[2].as_f64().unwrap(),
            ]
        })
        .collect();
    assert_eq!(markers.len(), 16);
    let (mut checked, mut found, mut worst) = (0, 0, 0.0f64);
    for i in (0..frames.len()).step_by(4) {
        let (_, v) = &p[i];
        let r = rotation(&v[3..]);
        for m in &markers {
            let d = [m[0] - v[0], m[1] - v[1], m[2] - v[2]];
            // Camera coordinates: R^T d.
            let c: Vec<f64> = (0..3)
                .map(|a| r[0][a] * d[0] + r[1][a] * d[1] + r[2][a] * d[2])
                .collect();
            if c[2] < 1.0 {
                continue;
            }
            // COLMAP pixel convention: continuous coordinates, pixel (i, j) centred at +0.5.
            let (u, w) = (fx * c[0] / c[2] + cx, fy * c[1] / c[2] + cy);
            if u < 14.0 || w < 14.0 || u > 320.0 - 14.0 || w > 180.0 - 14.0 {
                continue;
            }
            checked += 1;
            // Expected pixel area of the 2 m square (corners projected, shoelace formula).
            let corners: Vec<(f64, f64)> = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
                .iter()
                .map(|(dx, dy)| {
                    let d = [m[0] + dx - v[0], m[1] + dy - v[1], m[2] - v[2]];
                    let c: Vec<f64> = (0..3)
                        .map(|a| r[0][a] * d[0] + r[1][a] * d[1] + r[2][a] * d[2])
                        .collect();
                    (fx * c[0] / c[2] + cx, fy * c[1] / c[2] + cy)
                })
                .collect();
            let area = 0.5
                * (0..4)
                    .map(|j| {
                        let (a, b) = (corners[j], corners[(j + 1) % 4]);
                        a.0 * b.1 - b.0 * a.1
                    })
                    .sum::<f64>()
                    .abs();
            // Centroid of the clearly magenta pixels in a window around the projection.
            let (mut n, mut sx, mut sy) = (0.0, 0.0, 0.0);
            for y in (w as i32 - 10)..=(w as i32 + 10) {
                for x in (u as i32 - 10)..=(u as i32 + 10) {
                    let [b, g, rr] = pixel(&frames[i], x, y);
                    if b > 170.0 && rr > 170.0 && g < 90.0 {
                        n += 1.0;
                        sx += x as f64 + 0.5;
                        sy += y as f64 + 0.5;
                    }
                }
            }
            let sw = n;
            // A marker partly hidden (by a car, a building or a hill) has a shifted centroid.
            if n < 0.5 * area {
                continue;
            }
            found += 1;
            let err = (sx / sw - u).hypot(sy / sw - w);
            worst = worst.max(err);
            assert!(
                err < 1.5,
                "frame {i}: marker {m:?} at {:.2},{:.2}, projected {u:.2},{w:.2}",
                sx / sw,
                sy / sw
            );
        }
    }
    assert!(checked >= 20, "only {checked} marker projections in view");
    assert!(
        found * 10 >= checked * 8,
        "found {found} of {checked} markers"
    );
    eprintln!("markers: {found} of {checked} found, worst error {worst:.2} px");
}

#[test]
fn scene_fast_turns_are_blurred() {
    let dir = survey();
    let desc = json(&dir.join("scene.json"));
    let turns = desc["fast_turns"].as_array().unwrap();
    assert!(!turns.is_empty(), "no fast turn in {desc}");
    let mut in_turn = [false; 100];
    let mut near_turn = [false; 100];
    for t in turns {
        let (a, b) = (
            t["start_frame"].as_u64().unwrap() as usize,
            t["end_frame"].as_u64().unwrap() as usize,
        );
        assert!(t["max_yaw_rate_deg_s"].as_f64().unwrap() > 45.0, "{t}");
        in_turn[a..=b].iter_mut().for_each(|f| *f = true);
        near_turn[a.saturating_sub(6)..(b + 6).min(100)]
            .iter_mut()
            .for_each(|f| *f = true);
    }
    let out: serde_json::Value = serde_json::from_str(&kf_ok(&[
        "score",
        s(&dir.join("video.mp4")),
        "--json",
        "--backend",
        "opencv",
    ]))
    .unwrap();
    let scores: Vec<f64> = out["scores"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(scores.len(), 100);
    let mean = |f: &dyn Fn(usize) -> bool| {
        let v: Vec<f64> = (0..100).filter(|&i| f(i)).map(|i| scores[i]).collect();
        assert!(v.len() >= 5, "{} frames", v.len());
        v.iter().sum::<f64>() / v.len() as f64
    };
    let turn = mean(&|i| in_turn[i]);
    let straight = mean(&|i| !near_turn[i]);
    eprintln!("tenengrad: turn {turn:.1}, straight {straight:.1}");
    assert!(turn < 0.6 * straight, "turn {turn} vs straight {straight}");
}

#[test]
fn scene_hovers_are_still() {
    let dir = generate(
        "hover",
        &[
            "--preset",
            "hover-survey",
            "--seconds",
            "12",
            "--blur-samples",
            "2",
            "--seed",
            "3",
        ],
    );
    let desc = json(&dir.join("scene.json"));
    let hovers = desc["hovers"].as_array().unwrap();
    assert_eq!(hovers.len(), 3, "{desc}");
    let frames = decode(&dir.join("video.mp4"));
    let p = poses(&dir);
    assert_eq!(frames.len(), p.len());
    let mut still = vec![false; frames.len()];
    for h in hovers {
        let (a, b) = (
            h["start_frame"].as_u64().unwrap() as usize,
            h["end_frame"].as_u64().unwrap() as usize,
        );
        assert!(b >= a + 5, "{h}");
        for i in a..=b {
            still[i] = true;
            let d = ((p[i].1[0] - p[a].1[0]).powi(2)
                + (p[i].1[1] - p[a].1[1]).powi(2)
                + (p[i].1[2] - p[a].1[2]).powi(2))
            .sqrt();
            assert!(d < 0.005, "frame {i} is {d} m from the hover start");
        }
    }
    let diff = |i: usize| {
        let mut d = Mat::default();
        opencv::core::absdiff(&frames[i - 1], &frames[i], &mut d).unwrap();
        let m = opencv::core::mean(&d, &opencv::core::no_array()).unwrap();
        (m[0] + m[1] + m[2]) / 3.0
    };
    let hover: Vec<f64> = (1..frames.len())
        .filter(|&i| still[i] && still[i - 1])
        .map(diff)
        .collect();
    let moving: Vec<f64> = (1..frames.len())
        .filter(|&i| !still[i] && !still[i - 1])
        .map(diff)
        .collect();
    let avg = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    eprintln!(
        "mean abs difference: hover {:.3}, moving {:.3}",
        avg(&hover),
        avg(&moving)
    );
    assert!(avg(&hover) < 1.5, "hover {}", avg(&hover));
    assert!(
        avg(&hover) < 0.15 * avg(&moving),
        "hover {} moving {}",
        avg(&hover),
        avg(&moving)
    );
}

#[test]
fn scene_same_seed_same_output() {
    let a = generate(
        "same-a",
        &[
            "--seconds",
            "0.5",
            "--blur-samples",
            "6",
            "--markers",
            "--seed",
            "7",
        ],
    );
    let b = generate(
        "same-b",
        &[
            "--seconds",
            "0.5",
            "--blur-samples",
            "6",
            "--markers",
            "--seed",
            "7",
        ],
    );
    let c = generate(
        "other",
        &[
            "--seconds",
            "0.5",
            "--blur-samples",
            "6",
            "--markers",
            "--seed",
            "8",
        ],
    );
    let read = |d: &Path| std::fs::read_to_string(d.join("poses.tum")).unwrap();
    assert_eq!(read(&a), read(&b));
    assert_ne!(read(&a), read(&c));
    // The poses do not depend on the length asked for: they start like the 10 s survey's.
    let long = read(survey());
    assert!(
        long.starts_with(&read(&a)),
        "poses differ from the longer run"
    );
    let (fa, fb, fc) = (
        decode(&a.join("video.mp4")),
        decode(&b.join("video.mp4")),
        decode(&c.join("video.mp4")),
    );
    assert_eq!(fa.len(), 5);
    for (x, y) in fa.iter().zip(&fb) {
        assert_eq!(x.data_bytes().unwrap(), y.data_bytes().unwrap());
    }
    assert_ne!(fa[0].data_bytes().unwrap(), fc[0].data_bytes().unwrap());
}

/// Std of the distances between consecutive keyframes' camera centres (poses.tum).
fn spacing_std(poses: &[(f64, [f64; 7])], keys: &[usize]) -> f64 {
    let d: Vec<f64> = keys
        .windows(2)
        .map(|w| distance(&poses[w[0]].1, &poses[w[1]].1))
        .collect();
    let m = d.iter().sum::<f64>() / d.len() as f64;
    (d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / d.len() as f64).sqrt()
}

/// On a survey with two fast turns (57°/s yaw), --derotate --spacing puts fewer keyframes into
/// the turns than spacing on the raw flow, spaces the keyframes' camera centres more evenly than
/// both raw spacing and a fixed rate with as many keyframes, selects the same keyframes on both
/// backends, and saves as a workflow that runs the same.
#[test]
fn derotated_spacing_discounts_fast_turns() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("scene/survey-turns");
    // Fresh every run: projects left by an earlier build would be reused as caches.
    let _ = std::fs::remove_dir_all(&dir);
    scene_ok(&[
        s(&dir),
        "--force",
        "--size",
        "320x180",
        "--seconds",
        "12",
        "--blur-samples",
        "2",
    ]);
    let meta = json(&dir.join("scene.json"));
    let turns: Vec<(usize, usize)> = meta["fast_turns"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| {
            (
                t["start_frame"].as_u64().unwrap() as usize,
                t["end_frame"].as_u64().unwrap() as usize,
            )
        })
        .collect();
    assert_eq!(turns.len(), 2, "{turns:?}");
    let in_turns = |keys: &[usize]| {
        keys.iter()
            .filter(|&&k| turns.iter().any(|&(a, b)| k >= a && k <= b))
            .count()
    };
    let fx = meta["intrinsics"]["fx"].as_f64().unwrap();
    let hfov = format!("{:.3}", 2.0 * (160.0 / fx).atan().to_degrees());
    let video = dir.join("video.mp4");
    let select = |name: &str, extra: &[&str]| {
        let p = dir.join(format!("{name}.json"));
        let mut args = vec!["select", s(&video), "-o", s(&p), "--force"];
        args.extend_from_slice(extra);
        kf_ok(&args);
        crate::common::keyframes(&p)
    };
    let spacing = ["--spacing", "24kf"];
    let derotate = ["--derotate", "--hfov", &hfov];
    let raw = select("raw", &[&spacing[..], &["--backend", "opencv"]].concat());
    let derot_cv = select(
        "derot-opencv",
        &[&spacing[..], &derotate, &["--backend", "opencv"]].concat(),
    );
    let derot_gpu = select(
        "derot-gpu",
        &[&spacing[..], &derotate, &["--backend", "gpu"]].concat(),
    );
    let fixed = select("fps", &["--fps", "2"]);
    assert_eq!(
        derot_gpu, derot_cv,
        "gpu and opencv select different keyframes"
    );
    assert_eq!(
        [raw.len(), derot_cv.len(), fixed.len()],
        [24, 24, 24],
        "same number of keyframes"
    );
    let poses = poses(&dir);
    let sd = spacing_std(&poses, &derot_cv);
    let (sr, sf) = (spacing_std(&poses, &raw), spacing_std(&poses, &fixed));
    let (tr, td, tf) = (in_turns(&raw), in_turns(&derot_cv), in_turns(&fixed));
    eprintln!(
        "keyframes in turns / spacing std (m): raw {tr} / {sr:.3}, derotated {td} / {sd:.3}, \
         fps 2 {tf} / {sf:.3}"
    );
    assert!(td < tr, "keyframes in turns: derotated {td}, raw {tr}");
    assert!(
        2.0 * sd < sr && sd < sf,
        "spacing std: derotated {sd}, raw {sr}, fps {sf}"
    );

    // Saved as a workflow, the derotated selection records its setting and runs the same.
    let wf = dir.join("derotate.toml");
    kf_ok(&[
        "workflow",
        "save",
        s(&dir.join("derot-opencv.json")),
        "-o",
        s(&wf),
    ]);
    let text = std::fs::read_to_string(&wf).unwrap();
    assert!(
        text.contains("derotate = true") && text.contains(&format!("hfov = {hfov}")),
        "{text}"
    );
    let out = dir.join("run");
    kf_ok(&["run", s(&wf), s(&video), "--out", s(&out)]);
    assert_eq!(
        crate::common::keyframes(
            &out.join(keyframer::batch::folder_name(&video))
                .join("project.json")
        ),
        derot_cv
    );
}
