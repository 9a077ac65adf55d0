//! The rendered 360° walk (`keyframer-scene --preset walk --projection equirect`: a person's walk
//! down an L-shaped street with a stop and a 90° turn on the spot, exact ground truth) end to
//! end: the ERP camera agrees with the pinhole one; `select --projection equirect --spacing Nkf`,
//! `export --views cube --mask-nadir`, then `colmap --sparse --undistort --georegister` with the
//! installed COLMAP registers the views of the textured directions in one model whose `front`
//! centres lie on the truth, in metres on the walk's telemetry, with a PINHOLE dataset and one
//! `transforms.json` entry per registered view; `colmap --engine pycolmap` maps the same export as
//! a rig (one centre per keyframe, the rig's relative rotations) in one model on the truth;
//! spacing spaces the keyframes more evenly than a fixed rate; turning on the spot adds no
//! keyframes.

use crate::common::{json, kf_ok, pycolmap_found, s, scene_ok};
use crate::scene::{distance, poses};
use keyframer::colmap::align::{self, umeyama};
use keyframer::colmap::model::{self, Model};
use opencv::core::Mat;
use opencv::imgcodecs;
use opencv::prelude::*;
use opencv::videoio;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// Frame rate of the rendered walk (21.6 s: 323 frames). Real 360° video runs at 24 to 60 fps; at
/// 5 fps the 45°/s turn moves 18° between the frames of a measured pair (flow stride 2), more
/// than Farnebäck follows on the 102-pixel horizon views (the turn then leaves 7.5 px of residual
/// a pair against 3.8 px of walking); at 15 fps it leaves at most 0.8 px.
const FPS: &str = "15";
/// Keyframes asked of `--spacing` and given by the fixed rate (`--every 21` of 323 frames).
const KEYFRAMES: usize = 16;
const EVERY: &str = "21";
/// Views that see texture (walls, ground); `up` sees the sky.
const TEXTURED: [&str; 5] = ["front", "right", "back", "left", "down"];

fn colmap_installed() -> bool {
    Command::new("colmap").arg("-h").output().is_ok()
}

/// The walk rendered as 1024x512 ERP at `FPS` without motion blur (once per test process).
fn walk() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("walk/erp");
        scene_ok(&[
            s(&dir),
            "--force",
            "--preset",
            "walk",
            "--projection",
            "equirect",
            "--size",
            "1024x512",
            "--fps",
            FPS,
            "--blur-samples",
            "1",
        ]);
        dir
    })
}

/// `select` on the walk with `extra` into DIR/NAME.json; the keyframes.
fn select(name: &str, extra: &[&str]) -> (PathBuf, Vec<usize>) {
    let p = walk().parent().unwrap().join(format!("{name}.json"));
    let video = walk().join("video.mp4");
    let mut args = vec![
        "select",
        s(&video),
        "--projection",
        "equirect",
        "-o",
        s(&p),
        "--force",
    ];
    args.extend_from_slice(extra);
    kf_ok(&args);
    let keys = crate::common::keyframes(&p);
    (p, keys)
}

/// Frames of the walk's turn on the spot (scene.json's only fast turn).
fn turn_frames() -> (usize, usize) {
    let meta = json(&walk().join("scene.json"));
    let turns = meta["fast_turns"].as_array().unwrap();
    assert_eq!(turns.len(), 1, "{turns:?}");
    let f = |k: &str| turns[0][k].as_u64().unwrap() as usize;
    (f("start_frame"), f("end_frame"))
}

fn psnr(a: &[u8], b: &[u8]) -> f64 {
    assert_eq!(a.len(), b.len());
    let mse = a
        .iter()
        .zip(b)
        .map(|(x, y)| (f64::from(*x) - f64::from(*y)).powi(2))
        .sum::<f64>()
        / a.len() as f64;
    10.0 * (255.0f64 * 255.0 / mse.max(1e-12)).log10()
}

/// The ERP camera is the pinhole camera turned into a sphere: the `front` face that keyframer's
/// own `export --views cube` cuts from the ERP walk at the pinhole render's field of view equals a
/// direct pinhole render of the same poses (256², H.264 on both sides) to 30 dB PSNR or better
/// (measured 32.7–33.3 dB on 4 keyframes; the ERP's two resamplings and the two encodes).
#[test]
fn erp_front_face_matches_a_pinhole_render() {
    let n = 256;
    let pin = walk().parent().unwrap().join("pinhole");
    scene_ok(&[
        s(&pin),
        "--force",
        "--preset",
        "walk",
        "--size",
        "256x256",
        "--fps",
        FPS,
        "--seconds",
        "4",
        "--blur-samples",
        "1",
    ]);
    let fx = json(&pin.join("scene.json"))["intrinsics"]["fx"]
        .as_f64()
        .unwrap();
    let fov = format!("{:.6}", 2.0 * (f64::from(n) / 2.0 / fx).atan().to_degrees());
    let (project, keys) = select("faces", &["--every", "18"]);
    let out = walk().parent().unwrap().join("faces");
    let _ = std::fs::remove_dir_all(&out);
    let size = n.to_string();
    kf_ok(&[
        "export",
        s(&project),
        "--out",
        s(&out),
        "--views",
        "cube",
        "--view-fov",
        &fov,
        "--view-size",
        &size,
        "--format",
        "png",
    ]);
    let manifest = json(&out.join("manifest.json"));
    let mut cap =
        videoio::VideoCapture::from_file(s(&pin.join("video.mp4")), videoio::CAP_ANY).unwrap();
    let mut frames = Vec::new();
    let mut m = Mat::default();
    while cap.read(&mut m).unwrap() {
        frames.push(m.data_bytes().unwrap().to_vec());
    }
    // 4 s of the walk.
    assert_eq!(frames.len(), 4 * FPS.parse::<usize>().unwrap());
    let mut checked = 0;
    for f in manifest["frames"].as_array().unwrap() {
        let i = f["index"].as_u64().unwrap() as usize;
        if i >= frames.len() || f["view"] != "front" {
            continue;
        }
        let file = out.join("images/front").join(f["file"].as_str().unwrap());
        let face = imgcodecs::imread(s(&file), imgcodecs::IMREAD_COLOR).unwrap();
        let p = psnr(face.data_bytes().unwrap(), &frames[i]);
        eprintln!("frame {i}: ERP front face vs pinhole render PSNR {p:.1} dB");
        assert!(p >= 30.0, "frame {i}: PSNR {p:.1} dB");
        checked += 1;
    }
    assert!(
        checked >= 3,
        "{checked} frames compared of keyframes {keys:?}"
    );
}

/// Standard deviation of the distances between consecutive keyframes' camera centres.
fn spacing_std(poses: &[(f64, [f64; 7])], keys: &[usize]) -> f64 {
    let d: Vec<f64> = keys
        .windows(2)
        .map(|w| distance(&poses[w[0]].1, &poses[w[1]].1))
        .collect();
    let m = d.iter().sum::<f64>() / d.len() as f64;
    (d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / d.len() as f64).sqrt()
}

/// Turning on the spot adds no keyframes: `--spacing` on the ERP keeps none during the turn
/// (the centre does not move there). Needs the analysis on derotated virtual views.
#[test]
fn turning_on_the_spot_adds_no_keyframes() {
    let (_, keys) = select("turn", &["--spacing", &format!("{KEYFRAMES}kf")]);
    let (a, b) = turn_frames();
    let inside: Vec<usize> = keys.iter().copied().filter(|&k| k >= a && k <= b).collect();
    eprintln!("turn frames {a}..={b}; keyframes {keys:?}");
    assert!(inside.is_empty(), "keyframes during the turn: {inside:?}");
}

/// `--spacing Nkf` on the ERP spaces the keyframes' camera centres more evenly (σ of consecutive
/// spacing) than a fixed rate giving as many keyframes. Needs turning on the spot not to count
/// as movement (see `turning_on_the_spot_adds_no_keyframes`): keyframes piled into the turn have
/// no spacing between them.
#[test]
fn spacing_beats_a_fixed_rate_on_the_walk() {
    let (_, fixed) = select("fixed", &["--every", EVERY]);
    let (_, spaced) = select("spaced", &["--spacing", &format!("{}kf", fixed.len())]);
    assert_eq!(spaced.len(), fixed.len());
    let poses = poses(walk());
    let (ss, sf) = (spacing_std(&poses, &spaced), spacing_std(&poses, &fixed));
    eprintln!(
        "{} keyframes, σ of consecutive camera spacing (m): --spacing {ss:.3}, fixed rate {sf:.3}",
        fixed.len()
    );
    assert!(ss < sf, "σ spacing {ss:.3} m vs fixed rate {sf:.3} m");
}

/// The export of the spaced selection (cube faces of 110° so that neighbouring faces overlap,
/// 384², nadir cap 20°), made once.
fn rig_export() -> &'static PathBuf {
    static EXPORT: OnceLock<PathBuf> = OnceLock::new();
    EXPORT.get_or_init(|| {
        let (project, _) = select("rig", &["--spacing", &format!("{KEYFRAMES}kf")]);
        let root = walk().parent().unwrap();
        let export = root.join("rig");
        let _ = std::fs::remove_dir_all(&export);
        kf_ok(&[
            "export",
            s(&project),
            "--out",
            s(&export),
            "--views",
            "cube",
            "--view-size",
            "384",
            "--view-fov",
            "110",
            "--mask-nadir",
            "20",
        ]);
        export
    })
}

/// `colmap --sparse --undistort --georegister` on [`rig_export`] into `root/NAME` with `engine`
/// (each view matched with the views of its keyframe and the next one, 1024 features an image);
/// the workspace and the run's wall time.
fn colmap_on_rig(name: &str, engine: &str) -> (PathBuf, f64, String) {
    let export = rig_export();
    let ws = walk().parent().unwrap().join(name);
    let start = std::time::Instant::now();
    let summary = kf_ok(&[
        "colmap",
        s(export),
        "-o",
        s(&ws),
        "--sparse",
        "--undistort",
        "--georegister",
        "--engine",
        engine,
        "--overlap",
        "1",
        "--max-features",
        "1024",
        "--force",
    ]);
    (ws, start.elapsed().as_secs_f64(), summary)
}

/// The rig export and its workspace made by the `colmap` command (COLMAP 3.8: no rigs, each view
/// folder its own camera), run once; and the run's wall time.
fn workspace() -> &'static (PathBuf, PathBuf, f64) {
    static WS: OnceLock<(PathBuf, PathBuf, f64)> = OnceLock::new();
    WS.get_or_init(|| {
        let (ws, seconds, _) = colmap_on_rig("ws", "colmap");
        (rig_export().clone(), ws, seconds)
    })
}

/// The model of `dir` holding the most images among `dir/*`.
fn largest(dir: &Path) -> (PathBuf, Model) {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| model::detect(p).is_some())
        .map(|p| {
            let m = model::read(&p).unwrap().0;
            (p, m)
        })
        .max_by_key(|(_, m)| m.images.len())
        .unwrap()
}

/// The export's frames (view, file, frame index).
fn exported(export: &Path) -> Vec<(String, String, usize)> {
    let m = json(&export.join("manifest.json"));
    m["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            (
                f["view"].as_str().unwrap().to_string(),
                f["file"].as_str().unwrap().to_string(),
                f["index"].as_u64().unwrap() as usize,
            )
        })
        .collect()
}

/// The image `view/file` in `m`, when registered.
fn registered<'a>(m: &'a Model, view: &str, file: &str) -> Option<&'a model::Image> {
    let name = format!("{view}/{file}");
    m.images.values().find(|im| im.name == name)
}

/// The textured directions' views registered in `m` (the model at `path`) and their number;
/// prints every direction's count.
fn textured_registered(
    m: &Model,
    frames: &[(String, String, usize)],
    path: &Path,
) -> (usize, usize) {
    let mut textured = (0, 0);
    for v in ["front", "right", "back", "left", "up", "down"] {
        let views: Vec<_> = frames.iter().filter(|f| f.0 == v).collect();
        let n = (views.iter())
            .filter(|f| registered(m, v, &f.1).is_some())
            .count();
        eprintln!(
            "{v}: {n} of {} registered in {}",
            views.len(),
            path.display()
        );
        if TEXTURED.contains(&v) {
            textured = (textured.0 + n, textured.1 + views.len());
        }
    }
    textured
}

/// COLMAP on the cube export: ≥ 90 % of the textured directions' views registered in one model,
/// and its `front` centres within 2 % of the walk's length of the truth after a similarity.
#[test]
fn walk_rig_registers_in_one_model_on_the_truth() {
    if !colmap_installed() {
        eprintln!("skipping: colmap is not installed");
        return;
    }
    let (export, ws, _) = workspace();
    let (path, m) = largest(&ws.join("sparse"));
    let frames = exported(export);
    let registered = |v: &str, f: &str| registered(&m, v, f);
    let textured = textured_registered(&m, &frames, &path);
    let share = textured.0 as f64 / textured.1 as f64;
    assert!(
        share >= 0.9,
        "{} of {} textured views registered",
        textured.0,
        textured.1
    );
    let poses = poses(walk());
    let length: f64 = poses.windows(2).map(|w| distance(&w[0].1, &w[1].1)).sum();
    let (mut got, mut want) = (Vec::new(), Vec::new());
    for (_, file, i) in frames.iter().filter(|f| f.0 == "front") {
        if let Some(im) = registered("front", file) {
            got.push(im.centre());
            let p = &poses[*i].1;
            want.push([p[0], p[1], p[2]]);
        }
    }
    let (_, worst) = worst_after_similarity(&got, &want);
    eprintln!(
        "front centres after a similarity: worst {worst:.3} m of a {length:.1} m walk ({:.2} %)",
        100.0 * worst / length
    );
    assert!(worst <= 0.02 * length, "worst {worst} m, walk {length} m");
}

/// The same workspace handed off: `dataset/images/<view>/...` with a mask per image, PINHOLE
/// cameras, `transforms.json` with one entry per registered view image (read the nerfstudio
/// way: OpenGL camera-to-world, its centre the georegistered model's), and the georegistered
/// model in metres on the walk's telemetry: centres within 0.5 m of the truth (relative to the
/// first keyframe, the ENU origin), scale within 1 %.
#[test]
fn walk_rig_hands_off_georegistered_in_metres() {
    if !colmap_installed() {
        eprintln!("skipping: colmap is not installed");
        return;
    }
    let (export, ws, _) = workspace();
    let frames = exported(export);
    let poses = poses(walk());
    let first = &poses[frames[0].2].1;
    let (g, _) = model::read(&ws.join("georegistered")).unwrap();
    let (mut got, mut want) = (Vec::new(), Vec::new());
    for im in g.images.values() {
        let (v, f) = im.name.split_once('/').unwrap();
        let (_, _, i) = frames.iter().find(|x| x.0 == v && x.1 == f).unwrap();
        let p = &poses[*i].1;
        let truth = [p[0] - first[0], p[1] - first[1], p[2] - first[2]];
        let c = im.centre();
        assert!(
            align::dist(&c, &truth) < 0.5,
            "{}: {c:?} vs {truth:?}",
            im.name
        );
        got.push(c);
        want.push(truth);
    }
    let sim = umeyama(&got, &want).unwrap();
    assert!((sim.scale - 1.0).abs() < 0.01, "scale {}", sim.scale);

    let ds = ws.join("dataset");
    let (d, _) = model::read(&ds.join("sparse/0")).unwrap();
    assert!(d.cameras.values().all(|c| c.model == "PINHOLE"));
    let t = json(&ds.join("transforms.json"));
    let entries = t["frames"].as_array().unwrap();
    assert_eq!(
        entries.len(),
        d.images.len(),
        "one entry per registered view"
    );
    let a: Vec<Vec<f64>> = serde_json::from_value(t["applied_transform"].clone()).unwrap();
    let back =
        |v: [f64; 3]| -> [f64; 3] { std::array::from_fn(|j| (0..3).map(|i| a[i][j] * v[i]).sum()) };
    for f in entries {
        let file = f["file_path"].as_str().unwrap();
        let name = file.strip_prefix("images/").unwrap();
        assert!(name.contains('/'), "{file}: not in a view folder");
        assert!(ds.join(file).is_file(), "{file}");
        assert!(ds.join(f["mask_path"].as_str().unwrap()).is_file(), "{f}");
        let im = d.images.values().find(|im| im.name == name).unwrap();
        let c2w: Vec<Vec<f64>> = serde_json::from_value(f["transform_matrix"].clone()).unwrap();
        let centre = back([c2w[0][3], c2w[1][3], c2w[2][3]]);
        assert!(align::dist(&centre, &im.centre()) < 1e-6, "{name}");
        // OpenGL: the camera looks along −z; COLMAP's viewing axis is the third row of R.
        let look = back([-c2w[0][2], -c2w[1][2], -c2w[2][2]]);
        let r = im.cam_to_world();
        let z = [r[0][2], r[1][2], r[2][2]];
        assert!(align::dist(&look, &z) < 1e-6, "{name}: {look:?} vs {z:?}");
    }
}

/// The sparse stages' time (features, rig, matching, mapper) in a workspace's `colmap.json`.
fn sparse_seconds(rec: &serde_json::Value) -> f64 {
    let stages = rec["stages"].as_array().unwrap();
    (stages.iter())
        .filter(|st| {
            let name = st["stage"].as_str().unwrap();
            name.contains("feature")
                || name.contains("match")
                || name.starts_with("rig")
                || name == "mapper"
        })
        .map(|st| st["seconds"].as_f64().unwrap())
        .sum()
}

/// pycolmap on the cube export (`--engine pycolmap`: `rig_config.json` applied, the views of a
/// keyframe one rig frame): ≥ 90 % of the textured directions' views in one model, the views of
/// each keyframe sharing one centre (< 1 cm on the truth's scale) and keeping the rig's relative
/// rotations (< 0.1°), the `front` centres within 2 % of the walk's length of the truth after a
/// similarity; georegistration and undistortion still run on its model. Compared with the
/// `colmap` command's run on the same export.
#[test]
fn walk_rig_maps_as_one_rig_through_pycolmap() {
    if !colmap_installed() {
        eprintln!("skipping: colmap is not installed");
        return;
    }
    if !pycolmap_found() {
        eprintln!(
            "skipping: pycolmap is not installed (scripts/setup.sh puts it in target/pycolmap)"
        );
        return;
    }
    let (ws, seconds, summary) = colmap_on_rig("ws-pycolmap", "pycolmap");
    let export = rig_export();
    let rec = json(&ws.join("colmap.json"));
    assert_eq!(rec["rig"], true, "{rec}");
    let version = rec["pycolmap"]["version"].as_str().unwrap();
    assert!(
        summary.contains(&format!("pycolmap:  {version} (")) && summary.contains("one rig frame"),
        "{summary}"
    );
    let stages: Vec<&str> = (rec["stages"].as_array().unwrap().iter())
        .map(|st| st["stage"].as_str().unwrap())
        .collect();
    assert!(stages.contains(&"rig_configurator"), "{stages:?}");
    let (path, m) = largest(&ws.join("sparse"));
    let frames = exported(export);
    let textured = textured_registered(&m, &frames, &path);
    let share = textured.0 as f64 / textured.1 as f64;
    assert!(
        share >= 0.9,
        "{} of {} textured views registered",
        textured.0,
        textured.1
    );

    // The front centres on the truth after a similarity (its scale puts the model in metres).
    let poses = poses(walk());
    let length: f64 = poses.windows(2).map(|w| distance(&w[0].1, &w[1].1)).sum();
    let (mut got, mut want) = (Vec::new(), Vec::new());
    for (_, file, i) in frames.iter().filter(|f| f.0 == "front") {
        if let Some(im) = registered(&m, "front", file) {
            got.push(im.centre());
            let p = &poses[*i].1;
            want.push([p[0], p[1], p[2]]);
        }
    }
    let (sim, worst) = worst_after_similarity(&got, &want);
    eprintln!(
        "pycolmap: front centres after a similarity: worst {worst:.3} m of a {length:.1} m walk ({:.2} %)",
        100.0 * worst / length
    );
    assert!(worst <= 0.02 * length, "worst {worst} m, walk {length} m");

    // One centre and the rig's relative rotations per keyframe.
    let config = json(&export.join("rig_config.json"));
    let cam_from_rig = |view: &str| -> align::Mat3 {
        let cams = config[0]["cameras"].as_array().unwrap();
        let c = (cams.iter())
            .find(|c| c["image_prefix"] == format!("{view}/"))
            .unwrap();
        match c.get("cam_from_rig_rotation") {
            Some(q) => align::quat_to_mat(serde_json::from_value(q.clone()).unwrap()),
            None => align::quat_to_mat([1.0, 0.0, 0.0, 0.0]),
        }
    };
    let mut keys: Vec<usize> = frames.iter().map(|f| f.2).collect();
    keys.dedup();
    let (mut spread, mut turn, mut pairs) = (0.0f64, 0.0f64, 0);
    for k in keys {
        let views: Vec<(&str, &model::Image)> = (frames.iter())
            .filter(|f| f.2 == k)
            .filter_map(|f| registered(&m, &f.0, &f.1).map(|im| (f.0.as_str(), im)))
            .collect();
        for (i, (va, a)) in views.iter().enumerate() {
            for (vb, b) in &views[i + 1..] {
                spread = spread.max(sim.scale * align::dist(&a.centre(), &b.centre()));
                // World-to-camera rotations: R_a R_bᵀ is cam_a_from_cam_b, the rig's Q_a Q_bᵀ.
                let (ra, rb) = (align::quat_to_mat(a.qvec), align::quat_to_mat(b.qvec));
                let model = align::mul(&ra, &align::transpose(&rb));
                let rig = align::mul(&cam_from_rig(va), &align::transpose(&cam_from_rig(vb)));
                turn = turn.max(align::rotation_angle_deg(&align::mul(
                    &align::transpose(&rig),
                    &model,
                )));
                pairs += 1;
            }
        }
    }
    eprintln!(
        "pycolmap: {pairs} view pairs of one keyframe: centres at most {:.3} mm apart, \
         relative rotations at most {turn:.4}° off the rig's",
        spread * 1000.0
    );
    assert!(pairs > 0);
    assert!(
        spread < 0.01,
        "{spread} m between the centres of one keyframe's views"
    );
    assert!(turn < 0.1, "{turn}° off the rig's relative rotations");

    // The hand-off stages run on its model.
    let (g, _) = model::read(&ws.join("georegistered")).unwrap();
    assert_eq!(g.images.len(), m.images.len());
    let ds = ws.join("dataset");
    let (d, _) = model::read(&ds.join("sparse/0")).unwrap();
    let t = json(&ds.join("transforms.json"));
    assert_eq!(t["frames"].as_array().unwrap().len(), d.images.len());

    // Against the colmap command on the same export.
    let (_, cli_ws, cli_seconds) = workspace();
    let cli = json(&cli_ws.join("colmap.json"));
    let (cli_path, cli_model) = largest(&cli_ws.join("sparse"));
    let cli_textured = textured_registered(&cli_model, &frames, &cli_path);
    let models = |r: &serde_json::Value| r["models"].as_array().unwrap().len();
    eprintln!(
        "colmap command: {} of {} textured views in the largest of {} models, sparse stages {:.1} s, run {cli_seconds:.1} s",
        cli_textured.0, cli_textured.1, models(&cli), sparse_seconds(&cli)
    );
    eprintln!(
        "pycolmap {}: {} of {} textured views in the largest of {} models, sparse stages {:.1} s, run {seconds:.1} s",
        version, textured.0, textured.1, models(&rec), sparse_seconds(&rec)
    );
}

/// The walk's keyframes exported as whole ERP frames (`export --views equirect`) and mapped by
/// `colmap --sparse` with its default engine: pycolmap's EQUIRECTANGULAR camera (COLMAP 3.8 has
/// none), every keyframe registered in one model whose centres lie on the truth (≤ 2 % of the
/// walk's length after a similarity); `--engine colmap` and the stages that need COLMAP 3.8 to
/// read the model are refused with the reason, before anything is written.
#[test]
fn walk_erp_frames_map_whole_through_pycolmap() {
    if !colmap_installed() || !pycolmap_found() {
        eprintln!("skipping: needs colmap and pycolmap (scripts/setup.sh installs both)");
        return;
    }
    // Its own project: `rig_export` selects into `rig.json` from other tests at the same time.
    let (project, keys) = select("erp-keys", &["--spacing", &format!("{KEYFRAMES}kf")]);
    let root = walk().parent().unwrap();
    let export = root.join("erp-export");
    let _ = std::fs::remove_dir_all(&export);
    kf_ok(&[
        "export",
        s(&project),
        "--out",
        s(&export),
        "--views",
        "equirect",
    ]);
    let ws = root.join("ws-erp");
    let _ = std::fs::remove_dir_all(&ws);
    for refused in [&["--engine", "colmap"][..], &["--georegister"][..]] {
        let mut args = vec!["colmap", s(&export), "-o", s(&ws), "--sparse", "--force"];
        args.extend_from_slice(refused);
        let out = crate::common::kf(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{refused:?}: {err}");
        assert!(err.contains("whole ERP frames"), "{refused:?}: {err}");
        assert!(!ws.exists(), "{refused:?}: nothing is written");
    }
    let start = std::time::Instant::now();
    kf_ok(&["colmap", s(&export), "-o", s(&ws), "--sparse", "--force"]);
    let seconds = start.elapsed().as_secs_f64();
    let rec = json(&ws.join("colmap.json"));
    assert!(rec["pycolmap"]["version"].is_string(), "{rec}");
    let (path, m) = largest(&ws.join("sparse"));
    assert_eq!(
        m.images.len(),
        keys.len(),
        "every keyframe in {}",
        path.display()
    );
    assert!(m.cameras.values().all(|c| c.model == "EQUIRECTANGULAR"));
    let manifest = json(&export.join("manifest.json"));
    let index_of = |name: &str| -> usize {
        let f = (manifest["frames"].as_array().unwrap().iter())
            .find(|f| f["file"] == name)
            .unwrap_or_else(|| panic!("{name} not in the manifest"));
        f["index"].as_u64().unwrap() as usize
    };
    let poses = poses(walk());
    let length: f64 = poses.windows(2).map(|w| distance(&w[0].1, &w[1].1)).sum();
    let (mut got, mut want) = (Vec::new(), Vec::new());
    for im in m.images.values() {
        got.push(im.centre());
        let p = &poses[index_of(&im.name)].1;
        want.push([p[0], p[1], p[2]]);
    }
    let (_, worst) = worst_after_similarity(&got, &want);
    eprintln!(
        "ERP through pycolmap: {} of {} keyframes in one model in {seconds:.1} s; centres after a \
         similarity: worst {worst:.3} m of a {length:.1} m walk ({:.2} %)",
        m.images.len(),
        keys.len(),
        100.0 * worst / length
    );
    assert!(worst <= 0.02 * length, "worst {worst} m, walk {length} m");
}

/// The least-squares similarity from a model's camera centres (`got`) onto the true ones
/// (`want`, the same order), and the largest distance left between them after it.
fn worst_after_similarity(got: &[[f64; 3]], want: &[[f64; 3]]) -> (align::Sim3, f64) {
    let sim = umeyama(got, want).expect("a similarity");
    let worst = (got.iter().zip(want))
        .map(|(g, w)| align::dist(&sim.apply(g), w))
        .fold(0.0, f64::max);
    (sim, worst)
}
