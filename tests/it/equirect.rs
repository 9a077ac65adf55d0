//! 360° input and rig export: `select --projection equirect` (2:1 check, recorded), `export
//! --views cube` against a reference projection of the decoded ERP frame computed here with its
//! own math, the rig layout, rig_config.json, nadir masks, refusals before anything is written.

use crate::common::{code_and_stderr, json, kf, kf_ok, s};
use opencv::core::{Mat, Vector};
use opencv::imgcodecs;
use opencv::prelude::*;
use std::path::{Path, PathBuf};

/// A folder of `n` lossless `w` x `h` frames.
fn erp_folder(dir: &Path, w: i32, h: i32, n: u64) -> std::path::PathBuf {
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for i in 0..n {
        let img = keyframer::synthetic::pattern(w, h, i + 3).unwrap();
        let p = frames.join(format!("f{i:03}.png"));
        imgcodecs::imwrite(s(&p), &img, &Vector::new()).unwrap();
    }
    frames
}

/// The face `name` (90° fov, `n` px) of the ERP image `erp`, rendered in f64 from the issue's
/// conventions alone: direction per pixel, longitude/latitude, bilinear sampling, columns
/// wrapping around.
fn reference_face(erp: &Mat, name: &str, n: usize) -> Vec<f64> {
    let (w, h) = (erp.cols() as usize, erp.rows() as usize);
    let px = |x: i64, y: i64, c: usize| -> f64 {
        let x = x.rem_euclid(w as i64) as i32;
        let y = y.clamp(0, h as i64 - 1) as i32;
        f64::from(erp.at_2d::<opencv::core::Vec3b>(y, x).unwrap()[c])
    };
    let mut out = Vec::with_capacity(n * n * 3);
    let f = n as f64 / 2.0;
    for v in 0..n {
        for u in 0..n {
            let (x, y, z) = (u as f64 + 0.5 - f, v as f64 + 0.5 - f, f);
            // Face frame (x right, y down, z ahead) to the ERP frame.
            let (dx, dy, dz) = match name {
                "front" => (x, y, z),
                "right" => (z, y, -x),
                "back" => (-x, y, -z),
                "left" => (-z, y, x),
                "up" => (x, -z, y),
                "down" => (x, z, -y),
                _ => unreachable!(),
            };
            let lon = dx.atan2(dz).to_degrees();
            let lat = (-dy).atan2(dx.hypot(dz)).to_degrees();
            let ex = (lon + 180.0) / 360.0 * w as f64 - 0.5;
            let ey = ((90.0 - lat) / 180.0 * h as f64 - 0.5).clamp(0.0, h as f64 - 1.0);
            let (x0, y0) = (ex.floor(), ey.floor());
            let (fx, fy) = (ex - x0, ey - y0);
            let (x0, y0) = (x0 as i64, y0 as i64);
            for c in 0..3 {
                let top = px(x0, y0, c) * (1.0 - fx) + px(x0 + 1, y0, c) * fx;
                let bottom = px(x0, y0 + 1, c) * (1.0 - fx) + px(x0 + 1, y0 + 1, c) * fx;
                out.push(top * (1.0 - fy) + bottom * fy);
            }
        }
    }
    out
}

fn psnr(img: &Mat, reference: &[f64]) -> f64 {
    let bytes = img.data_bytes().unwrap();
    assert_eq!(bytes.len(), reference.len());
    let mse = bytes
        .iter()
        .zip(reference)
        .map(|(a, b)| (f64::from(*a) - b).powi(2))
        .sum::<f64>()
        / bytes.len() as f64;
    10.0 * (255.0f64 * 255.0 / mse.max(1e-12)).log10()
}

/// An ERP folder of two `w` x `h` frames selected as equirect, exported with `--views cube`,
/// `--mask-nadir 30` and `extra` into DIR/out; returns the frames' folder, the export and the
/// project.
fn cube_export(dir: &Path, (w, h): (i32, i32), extra: &[&str]) -> (PathBuf, PathBuf, PathBuf) {
    let frames = erp_folder(dir, w, h, 2);
    let project = dir.join("p.json");
    kf_ok(&[
        "select",
        s(&frames),
        "-o",
        s(&project),
        "--projection",
        "equirect",
    ]);
    let out = dir.join("out");
    let mut args = vec!["export", s(&project), "--out", s(&out), "--views", "cube"];
    args.extend_from_slice(&["--mask-nadir", "30"]);
    args.extend_from_slice(extra);
    kf_ok(&args);
    (frames, out, project)
}

#[test]
fn cube_export_matches_a_reference_projection() {
    let dir = tempfile::tempdir().unwrap();
    let n = 96usize;
    let size = n.to_string();
    let extra = ["--view-size", size.as_str(), "--format", "png"];
    let (frames, out, project) = cube_export(dir.path(), (480, 240), &extra);
    assert_eq!(json(&project)["projection"], "equirect");
    let m = json(&out.join("manifest.json"));
    let views = m["views"].as_array().unwrap();
    let names: Vec<&str> = views.iter().map(|v| v["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["front", "right", "back", "left", "up", "down"]);
    for v in views {
        for k in ["yaw_deg", "pitch_deg", "roll_deg", "fov_deg", "size"] {
            assert!(v[k].is_number(), "manifest view without {k}: {v}");
        }
    }
    assert_eq!(
        m["frames"].as_array().unwrap().len(),
        12,
        "2 keyframes x 6 views"
    );
    let rig = json(&out.join("rig_config.json"));
    let cams = rig[0]["cameras"].as_array().unwrap();
    assert_eq!(cams.len(), 6);
    assert_eq!(cams[0]["image_prefix"], "front/");
    for name in names {
        for (k, src) in ["f000.png", "f001.png"].iter().enumerate() {
            let erp = imgcodecs::imread(s(&frames.join(src)), imgcodecs::IMREAD_COLOR).unwrap();
            let file = out.join("images").join(name).join(format!("f00{k}.png"));
            let face = imgcodecs::imread(s(&file), imgcodecs::IMREAD_COLOR).unwrap();
            assert_eq!((face.cols(), face.rows()), (n as i32, n as i32));
            let p = psnr(&face, &reference_face(&erp, name, n));
            eprintln!("{name} {src}: PSNR {p:.1} dB");
            assert!(p >= 40.0, "{name} of {src}: PSNR {p:.1} dB < 40");
        }
        // The nadir cap (30°) is seen by `down` only (a 90° face reaches 45° below the horizon).
        let mask = out.join("masks").join(name).join("f000.png.png");
        assert_eq!(mask.exists(), name == "down", "{}", mask.display());
    }
    let mask = imgcodecs::imread(
        s(&out.join("masks/down/f000.png.png")),
        imgcodecs::IMREAD_GRAYSCALE,
    )
    .unwrap();
    let c = (n / 2) as i32;
    assert_eq!(*mask.at_2d::<u8>(c, c).unwrap(), 0, "the nadir is hidden");
    assert_eq!(
        *mask.at_2d::<u8>(0, 0).unwrap(),
        255,
        "a corner is 35° below"
    );
}

#[test]
fn bad_360_inputs_are_refused_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let wide = erp_folder(&dir.path().join("wide"), 320, 180, 1);
    let project = dir.path().join("w.json");
    let (code, err) = code_and_stderr(&kf(&[
        "select",
        s(&wide),
        "-o",
        s(&project),
        "--projection",
        "equirect",
    ]));
    assert_eq!(code, 1);
    assert!(err.contains("2:1") && err.contains("16:9"), "{err}");
    assert!(!project.exists());
    // --views on a pinhole project.
    kf_ok(&["select", s(&wide), "-o", s(&project)]);
    let out = dir.path().join("o1");
    let (code, err) = code_and_stderr(&kf(&[
        "export",
        s(&project),
        "--out",
        s(&out),
        "--views",
        "cube",
    ]));
    assert_eq!(code, 1);
    assert!(err.contains("--projection equirect"), "{err}");
    assert!(!out.exists(), "nothing written");
    // A view size over the limits.
    let erp = erp_folder(&dir.path().join("erp"), 200, 100, 1);
    let p2 = dir.path().join("e.json");
    kf_ok(&["select", s(&erp), "-o", s(&p2), "--projection", "equirect"]);
    let out = dir.path().join("o2");
    let (code, err) = code_and_stderr(&kf(&[
        "export",
        s(&p2),
        "--out",
        s(&out),
        "--views",
        "ring:4",
        "--view-size",
        "70000",
    ]));
    assert_eq!(code, 1);
    assert!(err.contains("--view-size"), "{err}");
    assert!(!out.exists(), "nothing written");
    // Whole ERP frames are not for COLMAP 3.8: refused before the workspace exists.
    if keyframer::fsutil::find_on_path("colmap").is_none() {
        eprintln!("SKIPPED: colmap on an equirect export (colmap is not installed)");
        return;
    }
    let out = dir.path().join("o3");
    kf_ok(&["export", s(&p2), "--out", s(&out), "--views", "equirect"]);
    let (code, err) = code_and_stderr(&kf(&["colmap", s(&out), "--sparse"]));
    assert_ne!(code, 0);
    assert!(err.contains("--views cube"), "{err}");
    assert!(!out.join("colmap").exists(), "no workspace");
}

/// `keyframer colmap` on a rig export (Debian's COLMAP 3.8, no rig support): the view folders are
/// kept in the workspace and every folder is one PINHOLE camera with the views' known focal length
/// and centre. (The mapper's outcome on this synthetic pattern is not what is checked.)
#[test]
fn colmap_takes_one_camera_per_view_folder() {
    let dir = tempfile::tempdir().unwrap();
    let extra = ["--view-size", "64", "--view-fov", "96"];
    let (_, out, _) = cube_export(dir.path(), (240, 120), &extra);
    let _ = kf(&["colmap", s(&out), "--sparse", "--matcher", "exhaustive"]);
    let ws = out.join("colmap");
    let record = json(&ws.join("colmap.json"));
    assert_eq!(record["per_folder"], true);
    assert!(ws.join("images/front/f000.png").is_file());
    assert!(ws.join("masks/down/f000.png.png").is_file());
    let fe = std::fs::read_to_string(ws.join("project.ini")).unwrap();
    assert!(fe.contains("single_camera_per_folder=true"), "{fe}");
    let db = rusqlite::Connection::open(ws.join("database.db")).unwrap();
    let cams: Vec<(i64, Vec<u8>)> = db
        .prepare("SELECT model, params FROM cameras")
        .unwrap()
        .query_map([], |r| Ok((r.get(0)?, r.get(1)?)))
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(cams.len(), 6, "one camera per view folder");
    let f = 32.0 / (48f64.to_radians()).tan();
    for (model, params) in cams {
        assert_eq!(model, 1, "PINHOLE");
        let p: Vec<f64> = params
            .chunks(8)
            .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
            .collect();
        assert!(
            (p[0] - f).abs() < 1e-9 && (p[1] - f).abs() < 1e-9,
            "{p:?} vs {f}"
        );
        assert_eq!((p[2], p[3]), (32.0, 32.0));
    }
    let images: i64 = db
        .query_row("SELECT count(*) FROM images", [], |r| r.get(0))
        .unwrap();
    assert_eq!(images, 12, "2 keyframes x 6 views");
}
