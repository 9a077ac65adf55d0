//! COLMAP hand-off and evaluation: a missing COLMAP, workspace refusal and --force, the dense
//! message and a failing stage (through a stand-in COLMAP script), a real sparse reconstruction
//! of a two-layer parallax clip with known camera path evaluated against that ground truth, the
//! binary and text model readers agreeing, eval on a text model made from known poses, and the
//! pycolmap driver serving a run's stages from one process.

use crate::common::*;
use keyframer::colmap::align::{self, Mat3, Vec3};
use keyframer::colmap::model;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs keyframer with extra environment variables (and without --quiet, to read progress).
fn kf_env(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_keyframer"));
    c.args(args);
    for (k, v) in env {
        c.env(k, v);
    }
    c.output().expect("run keyframer")
}

/// A 1 s testsrc2 clip, every 5th frame exported: a small export folder (6 images).
fn small_export(dir: &Path) -> PathBuf {
    let (_, project) = clip_and_project(dir);
    let out = dir.join("export");
    kf_ok(&["export", s(&project), "--out", s(&out)]);
    out
}

#[test]
fn colmap_missing_names_the_package_and_writes_nothing() {
    let d = tempfile::tempdir().unwrap();
    let export = small_export(d.path());
    let before = listing(&export);
    let empty = d.path().join("empty-bin");
    std::fs::create_dir(&empty).unwrap();
    let o = kf_env(&["colmap", s(&export)], &[("PATH", s(&empty))]);
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("colmap not found on PATH") && err.contains("apt-get install colmap"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
    // An override naming a missing binary fails the same way.
    let o = kf_env(
        &["colmap", s(&export), "-o", s(&d.path().join("ws"))],
        &[("KEYFRAMER_COLMAP", "/nonexistent/colmap")],
    );
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("/nonexistent/colmap") && err.contains("apt-get install colmap"));
    assert_eq!(listing(&export), before, "nothing written into the export");
    assert!(!d.path().join("ws").exists());
}

/// `--engine pycolmap` without pycolmap: one line naming what to install, nothing written (the
/// interpreter is named by `KEYFRAMER_PYTHON`, so a pycolmap set up beside keyframer is not found).
#[test]
fn pycolmap_engine_missing_names_the_package_and_writes_nothing() {
    let d = tempfile::tempdir().unwrap();
    let export = small_export(d.path());
    let before = listing(&export);
    let fake = fake_colmap(d.path());
    let ws = d.path().join("ws");
    let missing = d.path().join("no-python");
    let o = kf_env(
        &[
            "colmap",
            s(&export),
            "-o",
            s(&ws),
            "--sparse",
            "--engine",
            "pycolmap",
        ],
        &[
            ("KEYFRAMER_COLMAP", s(&fake)),
            ("KEYFRAMER_PYTHON", s(&missing)),
        ],
    );
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains(&format!(
            "KEYFRAMER_PYTHON={}: no such file",
            missing.display()
        )) && err.contains("pip install pycolmap==4.2.1")
            && err.contains("scripts/setup.sh"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
    assert!(!ws.exists(), "nothing written");
    assert_eq!(listing(&export), before, "nothing written into the export");
    // `auto` on an export that is not a rig keeps the colmap command and needs no pycolmap.
    let o = kf_env(
        &["colmap", s(&export), "-o", s(&ws), "--sparse"],
        &[
            ("KEYFRAMER_COLMAP", s(&fake)),
            ("KEYFRAMER_PYTHON", s(&missing)),
        ],
    );
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 0, "{err}");
    assert!(!err.contains("pycolmap"), "{err}");
    assert!(json(&ws.join("colmap.json")).get("pycolmap").is_none());
}

#[test]
fn workspace_refused_without_force_and_replaced_with_it() {
    use std::os::unix::fs::MetadataExt;
    let d = tempfile::tempdir().unwrap();
    let export = small_export(d.path());
    let ws = d.path().join("ws");
    // Not an export.
    let o = kf(&["colmap", s(d.path()), "-o", s(&ws)]);
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 1);
    assert!(err.contains("no manifest.json"), "{err}");
    assert!(!ws.exists());

    let out = kf_ok(&["colmap", s(&export), "-o", s(&ws), "--json"]);
    let rec: serde_json::Value = serde_json::from_str(&out).unwrap();
    let manifest = json(&export.join("manifest.json"));
    let frames = manifest["frames"].as_array().unwrap();
    assert_eq!(rec["images"], frames.len());
    for f in frames {
        let name = f["file"].as_str().unwrap();
        let a = std::fs::metadata(export.join("images").join(name)).unwrap();
        let b = std::fs::metadata(ws.join("images").join(name)).unwrap();
        assert_eq!(
            (a.dev(), a.ino()),
            (b.dev(), b.ino()),
            "{name} is a hard link"
        );
    }
    assert!(ws.join("database.db").is_file());
    let ini = std::fs::read_to_string(ws.join("project.ini")).unwrap();
    let abs = |n: &str| format!("{}", ws.join(n).display());
    assert!(ini.contains(&format!("database_path={}\n", abs("database.db"))));
    assert!(ini.contains(&format!("image_path={}\n", abs("images"))));
    assert!(ini.contains("[ImageReader]\nsingle_camera=true"));
    assert_eq!(json(&ws.join("colmap.json")), rec);

    // A workspace holding the export (its images/ could be the export) is refused.
    let o = kf(&["colmap", s(&export), "-o", s(d.path()), "--force"]);
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 1);
    assert!(err.contains("contains the input"), "{err}");
    assert!(export.join("manifest.json").is_file());

    // Existing workspace: refused, named, untouched.
    std::fs::write(ws.join("notes.txt"), "mine").unwrap();
    let o = kf(&["colmap", s(&export), "-o", s(&ws)]);
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 1);
    assert!(err.contains(s(&ws)) && err.contains("--force"), "{err}");
    // --force replaces keyframer's content and keeps the user's file.
    std::fs::remove_file(ws.join("images").join(frames[0]["file"].as_str().unwrap())).unwrap();
    kf_ok(&["colmap", s(&export), "-o", s(&ws), "--force"]);
    assert_eq!(listing(&ws.join("images")).len(), frames.len());
    assert_eq!(
        std::fs::read_to_string(ws.join("notes.txt")).unwrap(),
        "mine"
    );
}

#[test]
fn dense_without_cuda_explains_and_keeps_sparse_and_failed_stage_named() {
    let d = tempfile::tempdir().unwrap();
    let export = small_export(d.path());
    let fake = fake_colmap(d.path());
    let ws = d.path().join("ws");
    let o = kf_env(
        &["colmap", s(&export), "-o", s(&ws), "--dense"],
        &[("KEYFRAMER_COLMAP", s(&fake))],
    );
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 1, "{err}");
    let sparse0 = ws.join("sparse/0");
    for needle in [
        "needs a CUDA build of COLMAP",
        "patch_match_stereo",
        &format!("sparse model is at {}", sparse0.display()),
        "image_undistorter",
        "OpenMVS",
    ] {
        assert!(err.contains(needle), "missing `{needle}` in: {err}");
    }
    let rec = json(&ws.join("colmap.json"));
    assert_eq!(rec["models"][0]["registered_images"], 3);
    assert_eq!(rec["cuda"], false);
    let stages: Vec<&str> = rec["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["stage"].as_str().unwrap())
        .collect();
    assert_eq!(
        stages,
        [
            "project_generator",
            "feature_extractor",
            "sequential_matcher",
            "mapper"
        ]
    );
    assert!(rec["error"].as_str().unwrap().contains("CUDA"));
    assert!(std::fs::read_to_string(ws.join("logs/mapper.log"))
        .unwrap()
        .contains("fake mapper"));
    assert!(model::detect(&sparse0).is_some(), "sparse result kept");

    // A failing stage: named with its exit status and log.
    let ws2 = d.path().join("ws2");
    let o = kf_env(
        &[
            "colmap",
            s(&export),
            "-o",
            s(&ws2),
            "--sparse",
            "--matcher",
            "exhaustive",
        ],
        &[
            ("KEYFRAMER_COLMAP", s(&fake)),
            ("FAIL_STAGE", "exhaustive_matcher"),
        ],
    );
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 1, "{err}");
    let log = ws2.join("logs/exhaustive_matcher.log");
    assert!(
        err.contains("colmap exhaustive_matcher failed")
            && err.contains("exit status: 3")
            && err.contains(s(&log)),
        "{err}"
    );
    assert!(std::fs::read_to_string(&log).unwrap().contains("boom"));
    assert!(json(&ws2.join("colmap.json"))["error"]
        .as_str()
        .unwrap()
        .contains("exhaustive_matcher"));
}

#[test]
fn masks_reach_colmap_and_eval_reads_the_workspace() {
    let d = tempfile::tempdir().unwrap();
    let export = d.path().join("export");
    std::fs::create_dir_all(export.join("masks")).unwrap();
    std::fs::create_dir_all(export.join("images")).unwrap();
    let mut frames = Vec::new();
    for (k, i) in [0, 5, 10].into_iter().enumerate() {
        let name = format!("frame_{i:06}.jpg");
        std::fs::write(export.join("images").join(&name), format!("image {i}")).unwrap();
        std::fs::write(
            export.join(format!("masks/{name}.png")),
            format!("mask {i}"),
        )
        .unwrap();
        frames.push(
            serde_json::json!({"index": i, "timestamp_s": k as f64 / 6.0, "file": name,
            "mask": format!("{name}.png")}),
        );
    }
    let manifest = serde_json::json!({
        "tool": "keyframer", "tool_version": "0", "layout": 2, "created_unix_s": 0,
        "project": "/p.json", "source": "/v.mp4", "source_kind": "video",
        "settings": {"resize": null, "crop": null, "format": null, "quality": 95},
        "width": 320, "height": 240, "frames": frames, "missing": []
    });
    std::fs::write(export.join("manifest.json"), manifest.to_string()).unwrap();
    let fake = fake_colmap(d.path());
    let o = kf_env(
        &["colmap", s(&export), "--sparse"],
        &[("KEYFRAMER_COLMAP", s(&fake))],
    );
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 0, "{err}");
    let ws = export.join("colmap");
    let masks = ws.join("masks");
    assert_eq!(
        std::fs::read_to_string(masks.join("frame_000005.jpg.png")).unwrap(),
        "mask 5"
    );
    let rec = json(&ws.join("colmap.json"));
    assert_eq!(rec["masks"], 3);
    let fe = &rec["stages"][1];
    assert_eq!(fe["stage"], "feature_extractor");
    let cmd: Vec<&str> = fe["command"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    let at = cmd
        .iter()
        .position(|a| *a == "--ImageReader.mask_path")
        .expect("mask path passed");
    assert_eq!(cmd[at + 1], s(&masks));
    let ini = std::fs::read_to_string(ws.join("project.ini")).unwrap();
    assert!(
        ini.contains(&format!("mask_path={}\n", masks.display())),
        "{ini}"
    );

    // eval on the workspace: the stand-in model has cameras at x = 0, 1, 2.
    let out = kf_ok(&["eval", s(&ws), "--json"]);
    let r: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(
        (r["selected"].as_u64(), r["registered"].as_u64()),
        (Some(3), Some(3))
    );
    assert_eq!(r["models"], 1);
    assert!(r["mean_reprojection_error"].is_null());
    let idx: Vec<u64> = r["order"]
        .as_array()
        .unwrap()
        .iter()
        .map(|o| o[1].as_u64().unwrap())
        .collect();
    assert_eq!(idx, [0, 5, 10]);
    assert!((r["spacing"]["mean"].as_f64().unwrap() - 1.0).abs() < 1e-12);
    assert!(r["spacing"]["std"].as_f64().unwrap().abs() < 1e-12);
}

// ---------------------------------------------------------------------------------------------
// A real reconstruction.

const W: u32 = 480;
const H: u32 = 360;
const FRAMES: i32 = 72;

/// Camera offset of frame `n` in background pixels: a sideways move with a vertical swing.
fn path(n: i32) -> (i32, i32) {
    (2 * n, (30.0 * (f64::from(n) / 15.0).sin()).round() as i32)
}

/// A camera translating in its image plane over two fronto-parallel textured planes: the
/// background (aloeL) shifts by the camera offset, the nearer foreground strip (graf1, 3× closer)
/// by three times it, and hides the background below its top edge. Pure translation over planes
/// at two depths is exact pinhole geometry, so the ground truth is the offset itself: camera
/// centre (cx, cy, 0) in background-pixel units, no rotation.
fn parallax_clip(dir: &Path) -> (PathBuf, PathBuf) {
    use image::imageops::{resize, FilterType};
    let bg = resize(
        &image::open(testdata("opencv-doc/aloeL.jpg"))
            .unwrap()
            .to_rgb8(),
        680,
        480,
        FilterType::Triangle,
    );
    let fg = resize(
        &image::open(testdata("opencv-doc/graf1.png"))
            .unwrap()
            .to_rgb8(),
        1000,
        460,
        FilterType::Triangle,
    );
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    let mut tum = String::from("# timestamp tx ty tz qx qy qz qw (camera to world)\n");
    for n in 0..FRAMES {
        let (cx, cy) = path(n);
        let img = image::RgbImage::from_fn(W, H, |u, v| {
            let (u, v) = (u as i32, v as i32);
            if v + 3 * cy >= 210 {
                *fg.get_pixel((u + 3 * cx) as u32, (v + 3 * cy - 110) as u32)
            } else {
                *bg.get_pixel((u + cx) as u32, (v + cy + 50) as u32)
            }
        });
        img.save(frames.join(format!("f{n:04}.png"))).unwrap();
        tum += &format!("{:.6} {cx} {cy} 0 0 0 0 1\n", f64::from(n) / 30.0);
    }
    let clip = dir.join("parallax.mp4");
    encode_frames(&frames, "16", &clip);
    let gt = dir.join("poses.tum");
    std::fs::write(&gt, tum).unwrap();
    (clip, gt)
}

/// Compares two models read from different formats (text is written with 17 digits).
fn assert_same_model(a: &model::Model, b: &model::Model) {
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * (1.0 + x.abs());
    assert_eq!(a.cameras.len(), b.cameras.len());
    for (id, c) in &a.cameras {
        let d = &b.cameras[id];
        assert_eq!((&c.model, c.width, c.height), (&d.model, d.width, d.height));
        assert!(c.params.iter().zip(&d.params).all(|(x, y)| close(*x, *y)));
    }
    assert_eq!(
        a.images.keys().collect::<Vec<_>>(),
        b.images.keys().collect::<Vec<_>>()
    );
    for (id, i) in &a.images {
        let j = &b.images[id];
        assert_eq!((&i.name, i.camera_id), (&j.name, j.camera_id));
        assert!(i.qvec.iter().zip(&j.qvec).all(|(x, y)| close(*x, *y)));
        assert!(i.tvec.iter().zip(&j.tvec).all(|(x, y)| close(*x, *y)));
        assert_eq!(i.points2d.len(), j.points2d.len());
        for (p, q) in i.points2d.iter().zip(&j.points2d) {
            assert!(close(p.0, q.0) && close(p.1, q.1) && p.2 == q.2);
        }
    }
    assert_eq!(a.points.len(), b.points.len());
    for (id, p) in &a.points {
        let q = &b.points[id];
        assert!(p.xyz.iter().zip(&q.xyz).all(|(x, y)| close(*x, *y)));
        assert!(close(p.error, q.error));
        assert_eq!((p.rgb, &p.track), (q.rgb, &q.track));
    }
}

#[test]
fn colmap_sparse_reconstructs_parallax_clip_and_eval_matches_ground_truth() {
    let d = tempfile::tempdir().unwrap();
    let (clip, gt) = parallax_clip(d.path());
    let project = d.path().join("p.json");
    let export = d.path().join("export");
    kf_ok(&[
        "select",
        s(&clip),
        "--every",
        "6",
        "--backend",
        "opencv",
        "-o",
        s(&project),
    ]);
    kf_ok(&["export", s(&project), "--out", s(&export)]);
    let selected = json(&export.join("manifest.json"))["frames"]
        .as_array()
        .unwrap()
        .len();
    assert_eq!(selected, 12);

    // Short baselines: COLMAP's first initial-pair search (16°) fails on this clip and its own
    // relaxation costs a minute; starting at 4° gives the same kind of model quickly.
    let o = kf_env(
        &[
            "colmap",
            s(&export),
            "--sparse",
            "--overlap",
            "6",
            "--max-features",
            "1024",
            "--mapper-option",
            "init_min_tri_angle=4",
        ],
        &[],
    );
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 0, "{err}");
    let ws = export.join("colmap");
    let rec = json(&ws.join("colmap.json"));
    let mut times = Vec::new();
    for st in rec["stages"].as_array().unwrap() {
        let name = st["stage"].as_str().unwrap();
        let secs = st["seconds"].as_f64().unwrap();
        if ["feature_extractor", "sequential_matcher", "mapper"].contains(&name) {
            assert!(secs > 0.0, "{name}");
            assert!(
                err.contains(&format!("{name}: ")),
                "progress line for {name}"
            );
            assert!(ws.join(st["log"].as_str().unwrap()).is_file());
        }
        times.push(format!("{name} {secs:.1} s"));
    }
    assert!(rec["stages"][3]["command"]
        .as_array()
        .unwrap()
        .iter()
        .any(|a| a == "--Mapper.init_min_tri_angle"));
    let best = rec["models"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["registered_images"].as_u64().unwrap())
        .max()
        .expect("a model");
    eprintln!(
        "stages: {}; largest model {best} of {selected}",
        times.join(", ")
    );
    assert!(best >= 10, "{best} of {selected} registered");

    // Eval against the known camera path.
    let out = kf_ok(&["eval", s(&ws), "--gt", s(&gt), "--json"]);
    let r: serde_json::Value = serde_json::from_str(&out).unwrap();
    eprintln!("{}", kf_ok(&["eval", s(&ws), "--gt", s(&gt)]));
    assert_eq!(r["selected"], selected);
    assert_eq!(r["registered"], best);
    assert!(r["mean_reprojection_error"].as_f64().unwrap() < 1.0);
    let g = &r["gt"];
    assert_eq!(g["matched"], best);
    assert_eq!(g["matched_by"], "timestamp");

    // The report draws the reconstructed camera path (one camera per registered image).
    let html = d.path().join("report.html");
    kf_ok(&[
        "report",
        s(&project),
        "-o",
        s(&html),
        "--model",
        s(&ws),
        "--thumbs",
        "0",
    ]);
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(
        page.contains(&format!("<p id=\"camera-stats\">{best} cameras;")),
        "camera path of {best} cameras in the report"
    );
    // The ground-truth spacing of the registered frames, from the path itself.
    let order: Vec<i32> = r["order"]
        .as_array()
        .unwrap()
        .iter()
        .map(|o| o[1].as_i64().unwrap() as i32)
        .collect();
    assert!(
        order.windows(2).all(|w| w[0] < w[1]),
        "frame order {order:?}"
    );
    let gaps: Vec<f64> = order
        .windows(2)
        .map(|w| {
            let (a, b) = (path(w[0]), path(w[1]));
            f64::from((b.0 - a.0).pow(2) + (b.1 - a.1).pow(2)).sqrt()
        })
        .collect();
    let gt_mean = gaps.iter().sum::<f64>() / gaps.len() as f64;
    assert!((g["gt_spacing"]["mean"].as_f64().unwrap() - gt_mean).abs() < 1e-9);
    let rmse = g["position_rmse"].as_f64().unwrap();
    let spacing = g["spacing"]["mean"].as_f64().unwrap();
    // Camera centres within 5 % of the keyframe spacing; spacing within 5 % of the truth.
    assert!(rmse < 0.05 * gt_mean, "rmse {rmse} vs spacing {gt_mean}");
    assert!(
        (spacing - gt_mean).abs() < 0.05 * gt_mean,
        "{spacing} vs {gt_mean}"
    );
    assert!(g["rotation_error_mean_deg"].as_f64().unwrap() < 1.0);

    // Binary and text readers agree (COLMAP converts the model).
    let sparse0 = ws.join("sparse/0");
    let txt = d.path().join("txt");
    std::fs::create_dir(&txt).unwrap();
    let conv = Command::new("colmap")
        .args([
            "model_converter",
            "--input_path",
            s(&sparse0),
            "--output_path",
            s(&txt),
        ])
        .args(["--output_type", "TXT"])
        .output()
        .unwrap();
    assert!(conv.status.success());
    let bin = model::read_binary(&sparse0).unwrap();
    let text = model::read_text(&txt).unwrap();
    assert!(!bin.points.is_empty());
    assert_same_model(&bin, &text);
}

// ---------------------------------------------------------------------------------------------
// Eval on a model made from known poses.

fn lcg(state: &mut u64) -> f64 {
    *state = state
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
}

/// Rotation matrix → quaternion (w, x, y, z) for a proper rotation.
fn mat_to_quat(r: &Mat3) -> [f64; 4] {
    let w = (1.0 + r[0][0] + r[1][1] + r[2][2]).max(0.0).sqrt() / 2.0;
    let x = (1.0 + r[0][0] - r[1][1] - r[2][2]).max(0.0).sqrt() / 2.0;
    let y = (1.0 - r[0][0] + r[1][1] - r[2][2]).max(0.0).sqrt() / 2.0;
    let z = (1.0 - r[0][0] - r[1][1] + r[2][2]).max(0.0).sqrt() / 2.0;
    [
        w,
        x.copysign(r[2][1] - r[1][2]),
        y.copysign(r[0][2] - r[2][0]),
        z.copysign(r[1][0] - r[0][1]),
    ]
}

/// Writes an export manifest, a TUM ground truth for every frame, and a text model whose
/// cameras are the ground truth mapped by the inverse of (scale, rotation, translation) plus
/// `noise` (model units). Returns (export, model, gt, GT positions of the keyframes in order).
fn synthetic_case(dir: &Path, noise: f64) -> (PathBuf, PathBuf, PathBuf, Vec<Vec3>) {
    let mut st = 11u64;
    let fps = 25.0;
    let every = 4;
    let frames = 60;
    // GT: a helix with the camera looking at its axis.
    let gt_pose = |n: usize| -> (Vec3, Mat3) {
        let a = n as f64 * 0.05;
        let c = [3.0 * a.cos(), 3.0 * a.sin(), 0.2 * n as f64];
        let ry = align::quat_to_mat([(a / 2.0).cos(), 0.0, 0.0, (a / 2.0).sin()]);
        (c, ry)
    };
    let mut tum = String::from("# t tx ty tz qx qy qz qw\n");
    for n in 0..frames {
        let (c, r) = gt_pose(n);
        let q = mat_to_quat(&r);
        tum += &format!(
            "{:.9} {} {} {} {} {} {} {}\n",
            n as f64 / fps,
            c[0],
            c[1],
            c[2],
            q[1],
            q[2],
            q[3],
            q[0]
        );
    }
    let gt = dir.join("poses.tum");
    std::fs::write(&gt, tum).unwrap();
    // Model = inverse similarity of the GT: x_m = Sᵀ (x_gt − t) / s.
    let s_rot = align::quat_to_mat([0.3, -0.5, 0.7, 0.2]);
    let (scale, t) = (2.5, [10.0, -4.0, 1.5]);
    let keys: Vec<usize> = (0..frames).step_by(every).collect();
    let export = dir.join("export");
    std::fs::create_dir_all(&export).unwrap();
    let mframes: Vec<serde_json::Value> = keys
        .iter()
        .map(|&i| {
            serde_json::json!({"index": i, "timestamp_s": i as f64 / fps,
                "file": format!("frame_{i:06}.jpg")})
        })
        .collect();
    let manifest = serde_json::json!({
        "tool": "keyframer", "tool_version": "0", "layout": 2, "created_unix_s": 0,
        "project": "/p.json", "source": "/v.mp4", "source_kind": "video",
        "settings": {"resize": null, "crop": null, "format": null, "quality": 95},
        "width": 640, "height": 480, "frames": mframes, "missing": []
    });
    std::fs::write(export.join("manifest.json"), manifest.to_string()).unwrap();
    let m = dir.join("model");
    std::fs::create_dir_all(&m).unwrap();
    std::fs::write(m.join("cameras.txt"), "1 PINHOLE 640 480 500 500 320 240\n").unwrap();
    let mut images = String::from("# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME\n");
    let mut gt_positions = Vec::new();
    // Image ids in reverse frame order: eval must order by the manifest's frame index.
    for (k, &i) in keys.iter().enumerate().rev() {
        let (c, r) = gt_pose(i);
        gt_positions.push(c);
        let st_t = align::transpose(&s_rot);
        let d = [c[0] - t[0], c[1] - t[1], c[2] - t[2]];
        let mut cm = align::mul_vec(&st_t, &d).map(|v| v / scale);
        for v in &mut cm {
            *v += noise * lcg(&mut st);
        }
        // Model camera-to-world rotation: Sᵀ R_gt; world-to-camera is its transpose.
        let r_wc = align::transpose(&align::mul(&st_t, &r));
        let tv = align::mul_vec(&r_wc, &cm).map(|v| -v);
        let q = mat_to_quat(&r_wc);
        images += &format!(
            "{} {} {} {} {} {} {} {} 1 frame_{i:06}.jpg\n100 200 {}\n",
            k + 1,
            q[0],
            q[1],
            q[2],
            q[3],
            tv[0],
            tv[1],
            tv[2],
            k
        );
    }
    gt_positions.reverse();
    std::fs::write(m.join("images.txt"), images).unwrap();
    // Points: errors 0.5, 1.0, 1.5 (mean 1.0) and tracks of 2, 3, 4 (mean 3).
    let mut pts = String::new();
    for (id, (err, len)) in [(0.5, 2), (1.0, 3), (1.5, 4)].iter().enumerate() {
        let track: Vec<String> = (0..*len).map(|j| format!("{} 0", j + 1)).collect();
        pts += &format!("{id} 1 2 3 10 20 30 {err} {}\n", track.join(" "));
    }
    std::fs::write(m.join("points3D.txt"), pts).unwrap();
    (export, m, gt, gt_positions)
}

#[test]
fn eval_recovers_known_similarity_from_a_text_model() {
    let d = tempfile::tempdir().unwrap();
    let (export, m, gt, truth) = synthetic_case(d.path(), 0.0);
    let out = kf_ok(&[
        "eval",
        s(&m),
        "--export",
        s(&export),
        "--gt",
        s(&gt),
        "--json",
    ]);
    let r: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(r["registered"], 15);
    assert_eq!(r["selected"], 15);
    assert_eq!(r["registered_ratio"], 1.0);
    assert!((r["mean_reprojection_error"].as_f64().unwrap() - 1.0).abs() < 1e-12);
    assert!((r["mean_track_length"].as_f64().unwrap() - 3.0).abs() < 1e-12);
    let g = &r["gt"];
    assert_eq!(g["matched"], 15);
    assert!((g["scale"].as_f64().unwrap() - 2.5).abs() < 1e-9, "{g}");
    assert!(g["position_rmse"].as_f64().unwrap() < 1e-9);
    assert!(g["rotation_error_mean_deg"].as_f64().unwrap() < 1e-5);
    // Spacing statistics computed here from the ground truth (type-7 quantiles).
    let gaps: Vec<f64> = truth
        .windows(2)
        .map(|w| align::dist(&w[0], &w[1]))
        .collect();
    let mean = gaps.iter().sum::<f64>() / gaps.len() as f64;
    let std = (gaps.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / gaps.len() as f64).sqrt();
    let mut sorted = gaps.clone();
    sorted.sort_by(f64::total_cmp);
    let q = |p: f64| {
        let h = (sorted.len() - 1) as f64 * p;
        let lo = h.floor() as usize;
        sorted[lo] + (h - lo as f64) * (sorted[(lo + 1).min(sorted.len() - 1)] - sorted[lo])
    };
    for (key, want) in [
        ("mean", mean),
        ("std", std),
        ("q10", q(0.1)),
        ("q90", q(0.9)),
    ] {
        let got = g["spacing"][key].as_f64().unwrap();
        assert!((got - want).abs() < 1e-9, "{key}: {got} vs {want}");
        let model_units = r["spacing"][key].as_f64().unwrap();
        assert!(
            (model_units * 2.5 - want).abs() < 1e-9,
            "{key} in model units"
        );
    }
    // Frame order from the manifest although image ids run backwards.
    let first = &r["order"][0];
    assert_eq!(first[0], "frame_000000.jpg");

    // With noise of known size, the aligned error can only be at most the noise (the true
    // similarity already achieves it), and not zero.
    let d2 = tempfile::tempdir().unwrap();
    let noise = 0.01;
    let (export, m, gt, _) = synthetic_case(d2.path(), noise);
    let out = kf_ok(&[
        "eval",
        s(&m),
        "--export",
        s(&export),
        "--gt",
        s(&gt),
        "--json",
    ]);
    let r: serde_json::Value = serde_json::from_str(&out).unwrap();
    let rmse = r["gt"]["position_rmse"].as_f64().unwrap();
    // Per-axis noise is uniform in ±noise: |e| ≤ √3·noise, scaled by 2.5 into GT units.
    assert!(rmse > 0.0 && rmse <= 2.5 * noise * 3f64.sqrt(), "{rmse}");
}

/// keyframer killed during a COLMAP stage: the stage's process dies with it, and the workspace,
/// whose record says the run did not finish, is taken over by the next `--force` run.
#[test]
fn a_killed_colmap_run_stops_its_stage_and_recovers_with_force() {
    let d = tempfile::tempdir().unwrap();
    let export = small_export(d.path());
    let fake = fake_colmap(d.path());
    let ws = d.path().join("ws");
    let mut child = Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args(["colmap", s(&export), "-o", s(&ws), "--sparse", "--quiet"])
        .env("KEYFRAMER_COLMAP", &fake)
        .env("SLEEP_STAGE", "feature_extractor")
        .spawn()
        .unwrap();
    let log = ws.join("logs/feature_extractor.log");
    let t = std::time::Instant::now();
    let pid = loop {
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        if let Some(p) = text.lines().find_map(|l| l.strip_prefix("pid ")) {
            break p.trim().to_string();
        }
        assert!(t.elapsed().as_secs() < 60, "the stage never started");
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    assert_eq!(json(&ws.join("colmap.json"))["finished"], false);
    child.kill().unwrap();
    child.wait().unwrap();
    // The stage's process is gone (or a zombie waiting for its reaper) within a few seconds.
    let alive = || {
        std::fs::read_to_string(format!("/proc/{pid}/status"))
            .map(|s| {
                !s.lines()
                    .any(|l| l.starts_with("State:") && l.contains('Z'))
            })
            .unwrap_or(false)
    };
    let t = std::time::Instant::now();
    while alive() && t.elapsed().as_secs() < 10 {
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    assert!(!alive(), "COLMAP stage {pid} outlived keyframer");
    // Without --force refused; with it, the unfinished workspace is replaced and the run ends.
    let (code, err) = code_and_stderr(&kf(&["colmap", s(&export), "-o", s(&ws)]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("--force"), "{err}");
    let o = kf_env(
        &["colmap", s(&export), "-o", s(&ws), "--sparse", "--force"],
        &[("KEYFRAMER_COLMAP", s(&fake))],
    );
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 0, "{err}");
    let rec = json(&ws.join("colmap.json"));
    assert_eq!(rec["finished"], true);
    assert_eq!(rec["models"][0]["registered_images"], 3);
}

/// Through pycolmap, one driver process serves a run's stages (pycolmap imported once, not once
/// per stage): each stage still has its own log, wall and CPU time and exit code in the record,
/// the record's command runs the stage alone, and a stage the driver refuses (a mapper option
/// pycolmap lacks) fails by name with its exit status and log, after the stages before it
/// succeeded in the same process.
#[test]
fn pycolmap_stages_share_one_process_and_a_failing_one_is_named() {
    if !pycolmap_found() {
        eprintln!("skipped: pycolmap is not installed (scripts/setup.sh installs it)");
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let export = small_export(d.path());
    let ws = d.path().join("ws");
    let o = kf_env(
        &[
            "colmap",
            s(&export),
            "-o",
            s(&ws),
            "--engine",
            "pycolmap",
            "--sparse",
            "--mapper-option",
            "no_such_option=1",
        ],
        &[],
    );
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, 1, "{err}");
    let log = ws.join("logs/mapper.log");
    assert!(
        err.contains("pycolmap mapper failed (exit status: 1)") && err.contains(s(&log)),
        "{err}"
    );
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(
        text.contains("pycolmap 4.2.1: mapper") && text.contains("no_such_option: pycolmap"),
        "{text}"
    );
    let rec = json(&ws.join("colmap.json"));
    let stages = rec["stages"].as_array().unwrap();
    let by_name = |name: &str| {
        stages
            .iter()
            .find(|st| st["stage"] == name)
            .unwrap_or_else(|| panic!("no {name} in {rec}"))
    };
    for name in ["feature_extractor", "sequential_matcher"] {
        let st = by_name(name);
        assert_eq!(st["exit_code"], 0, "{st}");
        assert!(st["cpu_s"].as_f64().unwrap() > 0.0, "{st}");
        let own = std::fs::read_to_string(ws.join(format!("logs/{name}.log"))).unwrap();
        assert!(own.contains(&format!("pycolmap 4.2.1: {name}")), "{own}");
        assert!(
            !own.contains("mapper"),
            "{name}'s log holds only its own stage: {own}"
        );
    }
    assert!(rec["error"]
        .as_str()
        .unwrap()
        .contains("pycolmap mapper failed"));
    // The record's command runs the stage alone, as before the driver served stages.
    let command: Vec<String> = by_name("sequential_matcher")["command"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a.as_str().unwrap().to_string())
        .collect();
    let alone = Command::new(&command[0])
        .args(&command[1..])
        .output()
        .unwrap();
    assert!(alone.status.success(), "{alone:?}");
    assert!(String::from_utf8_lossy(&alone.stdout).contains("verified image pairs"));
    // No driver process is left behind.
    let driver = ws.join("pycolmap_stages.py");
    let ps = Command::new("ps").args(["-eo", "args"]).output().unwrap();
    assert!(
        !String::from_utf8_lossy(&ps.stdout).contains(s(&driver)),
        "a driver of {} still runs",
        ws.display()
    );
}
