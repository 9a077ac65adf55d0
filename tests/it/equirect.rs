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
    // Whole ERP frames are not for COLMAP 3.8 (`--engine colmap`): refused before the
    // workspace exists (pycolmap maps them: walk::walk_erp_frames_map_whole_through_pycolmap).
    if keyframer::fsutil::find_on_path("colmap").is_none() {
        eprintln!("SKIPPED: colmap on an equirect export (colmap is not installed)");
        return;
    }
    let out = dir.path().join("o3");
    kf_ok(&["export", s(&p2), "--out", s(&out), "--views", "equirect"]);
    let (code, err) = code_and_stderr(&kf(&["colmap", s(&out), "--sparse", "--engine", "colmap"]));
    assert_ne!(code, 0);
    assert!(err.contains("--views cube"), "{err}");
    assert!(!out.join("colmap").exists(), "no workspace");
}

/// `keyframer colmap --engine colmap` on a rig export (Debian's COLMAP 3.8, no rig support): the
/// view folders are kept in the workspace and every folder is one PINHOLE camera with the views'
/// known focal length and centre. (The mapper's outcome on this synthetic pattern is not what is
/// checked.)
#[test]
fn colmap_takes_one_camera_per_view_folder() {
    let dir = tempfile::tempdir().unwrap();
    let extra = ["--view-size", "64", "--view-fov", "96"];
    let (_, out, _) = cube_export(dir.path(), (240, 120), &extra);
    let args = ["colmap", s(&out), "--sparse", "--matcher", "exhaustive"];
    let _ = kf(&[&args[..], &["--engine", "colmap"]].concat());
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

/// The rig keys of a workflow's `[[export]]` (the `export` flags' values) below `[analysis]
/// projection = "equirect"`.
const RIG_FLAGS: [&str; 12] = [
    "--views",
    "ring:3,-30",
    "--view-fov",
    "100",
    "--view-size",
    "48",
    "--mask-nadir",
    "40",
    "--view-interp",
    "bicubic",
    "--format",
    "png",
];

/// A workflow of one `[[export]]` named `rig` with `keys` (TOML lines) on equirect frames.
fn rig_workflow(path: &Path, projection: Option<&str>, keys: &str) {
    let analysis = projection
        .map(|p| format!("[analysis]\nprojection = \"{p}\"\n"))
        .unwrap_or_default();
    let text = format!("version = 1\n{analysis}[[export]]\nname = \"rig\"\n{keys}");
    std::fs::write(path, text).unwrap();
}

/// `keyframer run` of `wf` on `input` into `out`: exit code, stderr, the input's folder.
fn run_rig(wf: &Path, input: &Path, out: &Path) -> (i32, String, PathBuf) {
    let (code, err) = code_and_stderr(&kf(&["run", s(wf), s(input), "--out", s(out)]));
    let folder = (crate::common::listing(out).into_iter())
        .find(|n| !n.starts_with('.'))
        .map(|n| out.join(n))
        .unwrap_or_default();
    (code, err, folder)
}

/// What two rig exports must share: every file under `images/` and `masks/` (path and bytes),
/// `rig_config.json`, the manifest's view list and its frames' files.
fn rig_content(export: &Path) -> (Vec<(String, Vec<u8>)>, serde_json::Value, serde_json::Value) {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<(String, Vec<u8>)>) {
        for name in crate::common::listing(dir) {
            let p = dir.join(&name);
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    let mut files = Vec::new();
    for sub in ["images", "masks"] {
        walk(export, &export.join(sub), &mut files);
    }
    let m = json(&export.join("manifest.json"));
    let frames: Vec<serde_json::Value> = (m["frames"].as_array().unwrap().iter())
        .map(|f| f["file"].clone())
        .collect();
    (
        files,
        json(&export.join("rig_config.json")),
        serde_json::json!({"views": m["views"], "frames": frames, "settings": m["settings"]}),
    )
}

/// `[[export]]` with `views`, `view_fov`, `view_size`, `mask_nadir`, `view_interp`: `run`
/// writes what `export` with the same flags writes on the run's project; `workflow save` writes
/// the keys and the saved workflow runs to the same export.
#[test]
fn workflow_rig_keys_export_as_the_flags_do_and_round_trip_through_save() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let frames = erp_folder(d, 240, 120, 2);
    let wf = d.join("rig.toml");
    let keys = "views = \"ring:3,-30\"\nview_fov = 100.0\nview_size = 48\nmask_nadir = 40.0\n\
                view_interp = \"bicubic\"\nformat = \"png\"\n";
    rig_workflow(&wf, Some("equirect"), keys);
    let out = d.join("run");
    let (code, err, folder) = run_rig(&wf, &frames, &out);
    assert_eq!(code, 0, "{err}");
    let by_run = rig_content(&folder.join("rig"));
    let names: Vec<&str> = (by_run.2["views"].as_array().unwrap().iter())
        .map(|v| v["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["ring00", "ring01", "ring02"]);
    assert_eq!(
        by_run.2["frames"].as_array().unwrap().len(),
        6,
        "2 x 3 views"
    );
    assert!(
        by_run.0.iter().any(|(f, _)| f.starts_with("masks/ring00/")),
        "the nadir cap is masked: {:?}",
        by_run.0.iter().map(|(f, _)| f).collect::<Vec<_>>()
    );
    // The flags on the run's project.
    let project = folder.join("project.json");
    let flags_out = d.join("flags");
    let mut args = vec!["export", s(&project), "--out", s(&flags_out)];
    args.extend_from_slice(&RIG_FLAGS);
    kf_ok(&args);
    assert_eq!(by_run, rig_content(&flags_out));
    // Saved from the project and the flags' export: the keys are in the file, and it runs alike.
    let saved = d.join("saved.toml");
    kf_ok(&[
        "workflow",
        "save",
        s(&project),
        "-o",
        s(&saved),
        "--export",
        s(&flags_out),
    ]);
    let text = std::fs::read_to_string(&saved).unwrap();
    for key in [
        "views = \"ring:3,-30\"",
        "view_fov = 100.0",
        "view_size = 48",
        "mask_nadir = 40.0",
        "view_interp = \"bicubic\"",
        "projection = \"equirect\"",
    ] {
        assert!(text.contains(key), "no `{key}` in\n{text}");
    }
    let (code, err, again) = run_rig(&saved, &frames, &d.join("run2"));
    assert_eq!(code, 0, "{err}");
    assert_eq!(rig_content(&again.join("flags")), by_run);
}

/// Bad rig keys are refused before any input is read, naming the workflow file and the key; a
/// rig export of frames analysed as pinhole ones is refused as `export --views` refuses it.
#[test]
fn workflow_rig_keys_are_refused_with_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let frames = erp_folder(d, 240, 120, 1);
    let cases = [
        (
            "views = \"ring:0\"\n",
            "export[0].views",
            "N must be 1 to 64",
        ),
        (
            "views = \"cube\"\nview_fov = 200.0\n",
            "export[0].view_fov",
            "(1, 179)",
        ),
        (
            "views = \"cube\"\nview_size = 0\n",
            "export[0].view_size",
            "0 px",
        ),
        (
            "views = \"cube\"\nmask_nadir = 95.0\n",
            "export[0].mask_nadir",
            "(0, 90]",
        ),
        (
            "views = \"cube\"\nview_interp = \"nearest\"\n",
            "export[0].view_interp",
            "bicubic",
        ),
        ("view_size = 64\n", "export[0].view_size", "`views`"),
        (
            "views = \"cube\"\nresize = \"64x32\"\n",
            "export[0].views",
            "whole 360°",
        ),
    ];
    for (k, (keys, key, why)) in cases.iter().enumerate() {
        let wf = d.join(format!("bad{k}.toml"));
        rig_workflow(&wf, Some("equirect"), keys);
        let out = d.join(format!("out{k}"));
        let (code, err, _) = run_rig(&wf, &frames, &out);
        assert_ne!(code, 0, "{keys}");
        assert!(
            err.contains(s(&wf)) && err.contains(key) && err.contains(why),
            "{keys}: {err}"
        );
        assert!(!out.exists(), "{keys}: refused before the run's folder");
    }
    // Pinhole frames: said at load when the workflow says so ...
    let wf = d.join("pinhole.toml");
    rig_workflow(&wf, Some("pinhole"), "views = \"cube\"\n");
    let out = d.join("pinhole");
    let (code, err, _) = run_rig(&wf, &frames, &out);
    assert_ne!(code, 0);
    let named = |err: &str| err.contains(s(&wf)) && err.contains("export[0].views");
    assert!(
        named(&err) && err.contains("--projection equirect"),
        "{err}"
    );
    assert!(!out.exists());
    // ... else when the input turns out to be pinhole (no spherical metadata in a folder),
    // before its frames are analysed.
    rig_workflow(&wf, None, "views = \"cube\"\n");
    let (code, err, folder) = run_rig(&wf, &frames, &out);
    assert_ne!(code, 0);
    assert!(
        named(&err) && err.contains("--projection equirect"),
        "{err}"
    );
    assert!(folder.is_dir(), "the input's folder: {}", out.display());
    assert!(!folder.join("project.json").exists(), "no selection");
    assert!(!folder.join("rig").exists(), "nothing exported");
}

/// Real MP4s with Google's spherical metadata injected (V2 `sv3d` in the sample entry, V1 XML in
/// the track): keyframer reads them from the file as ffprobe does,
/// `select` analyses them as 360° input without being told; a plain MP4 and a Matroska copy
/// (ffprobe's path) stay pinhole.
#[test]
fn spherical_metadata_is_read_from_the_file() {
    use keyframer::source::spherical::{boxes, declared, ffprobe, read_iso};
    let dir = tempfile::tempdir().unwrap();
    let plain = crate::common::testsrc(dir.path(), "plain.mp4", 256, 128, "10", 1.0);
    let bytes = std::fs::read(&plain).unwrap();
    let stsd: &[&[u8; 4]] = &[b"moov", b"trak", b"mdia", b"minf", b"stbl", b"stsd"];
    let v2 = dir.path().join("v2.mp4");
    let injected = boxes::inject(&bytes, stsd, &boxes::sv3d(b"equi", [0; 4]));
    std::fs::write(&v2, injected.expect("the clip has moov/trak/.../stsd")).unwrap();
    let v1 = dir.path().join("v1.mp4");
    let xml = boxes::v1(&boxes::v1_xml("equirectangular"));
    let injected = boxes::inject(&bytes, &[b"moov", b"trak"], &xml);
    std::fs::write(&v1, injected.expect("the clip has moov/trak")).unwrap();
    let cube = dir.path().join("cube.mp4");
    let injected = boxes::inject(&bytes, stsd, &boxes::sv3d(b"cbmp", [0; 4]));
    std::fs::write(&cube, injected.unwrap()).unwrap();
    let mkv = dir.path().join("plain.mkv");
    crate::common::ffmpeg(&["-i", s(&plain), "-c", "copy", s(&mkv)]);

    // The injected boxes are what FFmpeg reads, and this reader agrees with it.
    assert_eq!(ffprobe(&v2).as_deref(), Some("equirectangular"));
    assert_eq!(ffprobe(&v1).as_deref(), Some("equirectangular"));
    assert_eq!(ffprobe(&cube).as_deref(), Some("cubemap"));
    assert_eq!(ffprobe(&plain), None);
    let eq = Some(Some("equirectangular".to_string()));
    assert_eq!(read_iso(&v2), eq);
    assert_eq!(read_iso(&v1), eq);
    assert_eq!(read_iso(&cube), Some(Some("cubemap".to_string())));
    assert_eq!(read_iso(&plain), Some(None));
    assert_eq!(read_iso(&mkv), None, "Matroska goes to ffprobe");
    assert_eq!(declared(&mkv), None);

    for (video, want, says) in [
        (
            &v2,
            "equirect",
            Some("spherical video metadata (equirectangular) found"),
        ),
        (
            &v1,
            "equirect",
            Some("spherical video metadata (equirectangular) found"),
        ),
        (
            &cube,
            "pinhole",
            Some("says `cubemap`, which keyframer does not read"),
        ),
        (&plain, "pinhole", None),
        (&mkv, "pinhole", None),
    ] {
        let project = dir.path().join(format!(
            "{}.json",
            video.file_name().unwrap().to_string_lossy()
        ));
        let out = kf(&["select", s(video), "--every", "5", "-o", s(&project)]);
        let (code, err) = code_and_stderr(&out);
        assert_eq!(code, 0, "{}: {err}", video.display());
        // A pinhole project does not record its projection (the default).
        let p = json(&project)["projection"]
            .as_str()
            .unwrap_or("pinhole")
            .to_string();
        assert_eq!(p, want, "{}: {err}", video.display());
        match says {
            Some(line) => assert!(err.contains(line), "{}: {err}", video.display()),
            None => assert!(!err.contains("spherical video metadata ("), "{err}"),
        }
    }
    // The inputs were only read.
    assert_eq!(std::fs::read(&plain).unwrap(), bytes);
}
