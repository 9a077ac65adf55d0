//! Hand-off to trainers and GIS on a synthetic flight with exact telemetry and ground truth
//! (one real COLMAP run shared by the tests): `colmap --sparse --georegister --undistort` gives a
//! model in ENU metres on the telemetry (aligned to the truth to the model's own accuracy: the
//! best similarity onto the true centres is the identity; north up), an undistorted PINHOLE dataset with every registered image and its
//! mask, whose points reproject where COLMAP observes them and whose undistortion geometry is the
//! one the masks were warped with, and a `transforms.json` that, read the way nerfstudio reads it,
//! gives back the model's cameras; too few or collinear positions are refused before COLMAP runs.

use crate::common::{code_and_stderr, json, kf, kf_ok, s, scene_ok};
use crate::scene::{poses, rotation};
use keyframer::colmap::align::{self, Sim3};
use keyframer::colmap::model::{self, Camera, Model};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

type M3 = [[f64; 3]; 3];

/// Where the flight's world origin is on Earth.
const ORIGIN: &str = "-33.8568,-70.6012,520.5";
/// Size of the flight's images.
const W: u32 = 480;
const H: u32 = 270;
/// Export masks: 0 (ignore) left of this column, 255 from it on.
const MASK_EDGE: u32 = 24;

fn colmap_installed() -> bool {
    Command::new("colmap").arg("-h").output().is_ok()
}

/// A 12 s survey (a straight leg, a U-turn and the leg back) at 10 fps, every 8th frame exported
/// with its telemetry position and a mask: (flight folder, export folder).
fn export() -> &'static (PathBuf, PathBuf) {
    static DIRS: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    DIRS.get_or_init(|| {
        let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("handoff");
        let flight = root.join("flight");
        scene_ok(&[
            s(&flight),
            "--force",
            "--size",
            &format!("{W}x{H}"),
            "--fps",
            "10",
            "--seconds",
            "12",
            "--blur-samples",
            "1",
            &format!("--origin={ORIGIN}"),
        ]);
        let project = root.join("p.json");
        kf_ok(&[
            "select",
            s(&flight.join("video.mp4")),
            "--every",
            "8",
            "-o",
            s(&project),
            "--force",
        ]);
        let out = root.join("export");
        if out.exists() {
            std::fs::remove_dir_all(&out).unwrap();
        }
        kf_ok(&["export", s(&project), "--out", s(&out)]);
        add_masks(&out);
        (flight, out)
    })
}

/// Gives every exported image a mask (the left `MASK_EDGE` columns 0, the rest 255) listed in
/// the manifest, as `export --mask` does.
fn add_masks(export: &Path) {
    let masks = export.join("masks");
    std::fs::create_dir_all(&masks).unwrap();
    let mut manifest = json(&export.join("manifest.json"));
    for f in manifest["frames"].as_array_mut().unwrap() {
        let name = format!("{}.png", f["file"].as_str().unwrap());
        let img = image::GrayImage::from_fn(W, H, |x, _| {
            image::Luma([if x < MASK_EDGE { 0 } else { 255 }])
        });
        img.save(masks.join(&name)).unwrap();
        f["mask"] = serde_json::Value::String(name);
    }
    std::fs::write(export.join("manifest.json"), manifest.to_string()).unwrap();
}

/// The workspace of `colmap --sparse --georegister --undistort` on the export (run once), with
/// exhaustive matching: the leg back overlaps the first leg, and matching the two closes that
/// loop. (At 320x180 COLMAP 3.8 mis-assembled the U-turn in 5 of 20 runs, with sequential or
/// exhaustive matching: a model that nothing can align; at 480x270 in none of 26.)
fn workspace() -> &'static PathBuf {
    static WS: OnceLock<PathBuf> = OnceLock::new();
    WS.get_or_init(|| {
        let (_, export) = export();
        let ws = export.parent().unwrap().join("ws");
        kf_ok(&[
            "colmap",
            s(export),
            "-o",
            s(&ws),
            "--sparse",
            "--georegister",
            "--undistort",
            "--matcher",
            "exhaustive",
            "--force",
        ]);
        ws
    })
}

/// World-to-camera rotation of a COLMAP quaternion (w, x, y, z).
fn w2c(q: [f64; 4]) -> M3 {
    rotation(&[q[1], q[2], q[3], q[0]])
}

fn centre(q: [f64; 4], t: [f64; 3]) -> [f64; 3] {
    let r = w2c(q);
    // C = −Rᵀ t: the columns of R dotted with t.
    std::array::from_fn(|j| -(0..3).map(|i| r[i][j] * t[i]).sum::<f64>())
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

fn transpose(r: &M3) -> M3 {
    std::array::from_fn(|i| std::array::from_fn(|j| r[j][i]))
}

/// The angle between two camera-to-world rotations: trace(AᵀB) = 1 + 2 cos θ.
fn angle_deg(a: &M3, b: &M3) -> f64 {
    let trace: f64 = (0..3)
        .map(|k| (0..3).map(|i| a[i][k] * b[i][k]).sum::<f64>())
        .sum();
    ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
}

/// The model's own accuracy against the truth: the least-squares similarity (Umeyama, with
/// scale) taking its camera centres onto the true ones, and per image of `truth` the centre
/// distance (m) and orientation angle (°) left after it. No alignment to positions can do better
/// than this transform, so a georegistration on this flight's exact telemetry must be it.
struct Fit {
    sim: Sim3,
    errors: Vec<(f64, f64)>,
}

fn best_fit(m: &Model, truth: &[(String, [f64; 3], M3)]) -> Fit {
    let image = |name: &str| m.images.values().find(|im| im.name == name).unwrap();
    let src: Vec<[f64; 3]> = (truth.iter())
        .map(|t| centre(image(&t.0).qvec, image(&t.0).tvec))
        .collect();
    let dst: Vec<[f64; 3]> = truth.iter().map(|t| t.1).collect();
    let sim = align::umeyama(&src, &dst).unwrap();
    let errors = (truth.iter().zip(&src))
        .map(|((name, pos, r_true), c)| {
            let c2w = align::mul(&sim.rotation, &transpose(&w2c(image(name).qvec)));
            (dist(&sim.apply(c), pos), angle_deg(r_true, &c2w))
        })
        .collect();
    Fit { sim, errors }
}

/// A correct reconstruction of this flight: after the best similarity every camera within 1 m
/// and 2° of the truth. Measured over 6 COLMAP runs of this export (480x270, free
/// SIMPLE_RADIAL intrinsics, exhaustive matching): at most 0.54 m and 1.18° (8 runs with the
/// scene's intrinsics given: 0.49 m, 1.19°); the mis-assembled models COLMAP 3.8 made of the same
/// flight at 320x180 (5 of 20 runs with the intrinsics given) leave metres and 75–144°.
fn assert_model_right(name: &str, best_m: f64, best_deg: f64) {
    assert!(
        best_m < 1.0 && best_deg < 2.0,
        "{name}: COLMAP's model itself is wrong here ({best_m} m, {best_deg}° after the best \
         similarity onto the truth)"
    );
}

/// The truth of every exported frame registered in `m`: (name, true position relative to the first
/// exported frame's, true camera-to-world rotation).
fn truth(m: &Model) -> Vec<(String, [f64; 3], M3)> {
    let (flight, export) = export();
    let poses = poses(flight);
    let manifest = json(&export.join("manifest.json"));
    let frames = manifest["frames"].as_array().unwrap();
    let first = &poses[frames[0]["index"].as_u64().unwrap() as usize].1;
    frames
        .iter()
        .filter(|f| m.images.values().any(|im| im.name == f["file"]))
        .map(|f| {
            let p = &poses[f["index"].as_u64().unwrap() as usize].1;
            let rel = [p[0] - first[0], p[1] - first[1], p[2] - first[2]];
            (
                f["file"].as_str().unwrap().to_string(),
                rel,
                rotation(&p[3..]),
            )
        })
        .collect()
}

/// The georegistered model lies on the truth to the model's own accuracy (ENU of the first
/// exported frame: the synthetic telemetry is exact, and over this flight's 60 m the scene's
/// tangent plane and the ENU frame agree to the millimetre): the least-squares similarity from its
/// centres onto the true ones is the identity (0.01°, 0.1 %, 1 cm), so every camera is as close to
/// its true position and orientation as the model allows (metres, north up); `colmap.json`,
/// `georegistration.json` and `eval` report the residuals, the model's within 1 cm.
#[test]
fn georegistered_model_lies_on_the_telemetry_in_metres_north_up() {
    if !colmap_installed() {
        eprintln!("skipping: colmap is not installed");
        return;
    }
    let ws = workspace();
    let (m, _) = model::read(&ws.join("georegistered")).unwrap();
    let truth = truth(&m);
    assert!(truth.len() >= 12, "{} of 15 registered", truth.len());
    let fit = best_fit(&m, &truth);
    // The georegistration is the best similarity onto the (exact) telemetry: nothing is left
    // to align.
    let angle = align::rotation_angle_deg(&fit.sim.rotation);
    let shift = dist(&fit.sim.translation, &[0.0; 3]);
    assert!(
        angle < 0.01,
        "a further {angle}° would fit the truth better"
    );
    assert!(
        (fit.sim.scale - 1.0).abs() < 1e-3,
        "scale {}",
        fit.sim.scale
    );
    assert!(
        shift < 0.01,
        "a further {shift} m would fit the truth better"
    );
    let mut got = Vec::new();
    for ((name, pos, r_true), (best_m, best_deg)) in truth.iter().zip(&fit.errors) {
        let im = m.images.values().find(|im| &im.name == name).unwrap();
        let c = centre(im.qvec, im.tvec);
        let angle = angle_deg(r_true, &transpose(&w2c(im.qvec)));
        assert!(dist(&c, pos) < best_m + 0.01, "{name}: {c:?} vs {pos:?}");
        assert!(angle < best_deg + 0.01, "{name}: {angle}° vs {best_deg}°");
        assert_model_right(name, *best_m, *best_deg);
        got.push(c);
    }
    let want: Vec<[f64; 3]> = truth.iter().map(|t| t.1).collect();

    let rec = json(&ws.join("colmap.json"));
    let g = &rec["georegistration"];
    assert_eq!(g["residuals"]["images"].as_u64(), Some(truth.len() as u64));
    let worst = fit.errors.iter().map(|e| e.0).fold(0.0, f64::max);
    let max_m = g["residuals"]["max_m"].as_f64().unwrap();
    assert!((max_m - worst).abs() < 0.01, "{g} vs {worst} m");
    assert_eq!(g["outliers"], serde_json::json!([]), "{g}");
    // The origin is the first exported frame's position.
    let manifest = json(&export().1.join("manifest.json"));
    let p0 = &manifest["frames"][0]["position"];
    assert_eq!(g["origin"]["lat_deg"], p0["lat_deg"]);
    assert_eq!(g["origin"]["alt_m"], p0["abs_alt_m"]);
    assert_eq!(json(&ws.join("georegistered/georegistration.json")), *g);
    let e: serde_json::Value = serde_json::from_str(&kf_ok(&["eval", s(ws), "--json"])).unwrap();
    assert!(
        e["model"].as_str().unwrap().ends_with("georegistered"),
        "{e}"
    );
    let r = &e["georegistration"];
    assert_eq!(r["images"].as_u64(), Some(truth.len() as u64), "{e}");
    assert!((r["max_m"].as_f64().unwrap() - worst).abs() < 0.01, "{e}");
    // Spacing is now in metres: the georegistered centres' mean spacing, and the truth's within
    // what the centres' errors allow (each step by at most two of them).
    let mean_step = |pts: &[[f64; 3]]| {
        pts.windows(2).map(|w| dist(&w[0], &w[1])).sum::<f64>() / (pts.len() - 1) as f64
    };
    let spacing = e["spacing"]["mean"].as_f64().unwrap();
    assert!((spacing - mean_step(&got)).abs() < 1e-6, "{spacing}");
    let true_spacing = mean_step(&want);
    assert!(
        (spacing - true_spacing).abs() <= 2.0 * worst,
        "{spacing} vs {true_spacing}"
    );
    // The report draws the camera path in metres, east right and north up.
    let html = export().1.parent().unwrap().join("report.html");
    let project = export().1.parent().unwrap().join("p.json");
    kf_ok(&[
        "report",
        s(&project),
        "-o",
        s(&html),
        "--model",
        s(ws),
        "--force",
    ]);
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(
        page.contains("east (right), north (up),"),
        "no north-up camera path"
    );
}

/// `georegistered/cameras.geojson`, what a GIS opens: one point per registered camera, at the
/// aligned camera centre (its offset from the telemetry's longitude, latitude and altitude the
/// model's within 1 cm, the distances computed here from degrees with the WGS84 radii of
/// curvature, independent of keyframer's ECEF route), looking where the model camera looks
/// (bearing and elevation within 0.01°; the true camera's within the model's orientation error).
#[test]
fn georegistered_cameras_are_points_on_the_map() {
    if !colmap_installed() {
        eprintln!("skipping: colmap is not installed");
        return;
    }
    let ws = workspace();
    let (m, _) = model::read(&ws.join("georegistered")).unwrap();
    let truth = truth(&m);
    let g = json(&ws.join("georegistered/cameras.geojson"));
    assert_eq!(g["type"], "FeatureCollection");
    let features = g["features"].as_array().unwrap();
    assert_eq!(features.len(), m.images.len());
    let manifest = json(&export().1.join("manifest.json"));
    let fit = best_fit(&m, &truth);
    for ((name, pos, r_true), (best_m, best_deg)) in truth.iter().zip(&fit.errors) {
        assert_model_right(name, *best_m, *best_deg);
        let im = m.images.values().find(|im| &im.name == name).unwrap();
        let centre = centre(im.qvec, im.tvec);
        let f = (features.iter())
            .find(|f| f["properties"]["name"] == name.as_str())
            .unwrap_or_else(|| panic!("{name} is not in cameras.geojson"));
        assert_eq!(f["geometry"]["type"], "Point");
        let c: Vec<f64> = (f["geometry"]["coordinates"].as_array().unwrap().iter())
            .map(|v| v.as_f64().unwrap())
            .collect();
        let frame = (manifest["frames"].as_array().unwrap().iter())
            .find(|fr| fr["file"] == name.as_str())
            .unwrap();
        let p = &frame["position"];
        let (lat, lon, alt) = (
            p["lat_deg"].as_f64().unwrap(),
            p["lon_deg"].as_f64().unwrap(),
            p["abs_alt_m"].as_f64().unwrap(),
        );
        // Metres per degree from the WGS84 meridian and prime-vertical radii at this latitude.
        let (a, e2, phi) = (6_378_137.0_f64, 6.694_379_990_14e-3, lat.to_radians());
        let w = (1.0 - e2 * phi.sin().powi(2)).sqrt();
        let north = (c[1] - lat).to_radians() * a * (1.0 - e2) / w.powi(3);
        let east = (c[0] - lon).to_radians() * a / w * phi.cos();
        // The point is the aligned camera centre: its offset from the telemetry position is the
        // model's (the truth is the telemetry here), within 1 cm.
        let offset = [east, north, c[2] - alt];
        let want: [f64; 3] = std::array::from_fn(|k| centre[k] - pos[k]);
        assert!(
            dist(&offset, &want) < 0.01,
            "{name}: {offset:?} vs {want:?}"
        );
        assert!(
            dist(&offset, &[0.0; 3]) < best_m + 0.01,
            "{name}: {offset:?}"
        );
        let residual = f["properties"]["residual_m"].as_f64().unwrap();
        assert!(
            (residual - dist(&want, &[0.0; 3])).abs() < 0.01,
            "{name}: {residual}"
        );
        // Bearing and elevation of the viewing direction, the camera-to-world rotation's third
        // column (x east, y north, z up): the model camera's within 0.01°, the true camera's
        // within the model's orientation error.
        let r = w2c(im.qvec);
        let look = |v: [f64; 3]| {
            let bearing = v[0].atan2(v[1]).to_degrees().rem_euclid(360.0);
            (bearing, v[2].asin().to_degrees())
        };
        let (model_b, model_e) = look(r[2]);
        let (true_b, true_e) = look([r_true[0][2], r_true[1][2], r_true[2][2]]);
        let got_b = f["properties"]["bearing_deg"].as_f64().unwrap();
        let got_e = f["properties"]["elevation_deg"].as_f64().unwrap();
        let turn = |a: f64, b: f64| ((a - b + 540.0).rem_euclid(360.0) - 180.0).abs();
        assert!(
            turn(got_b, model_b) < 0.01,
            "{name}: bearing {got_b} vs {model_b}"
        );
        assert!(
            (got_e - model_e).abs() < 0.01,
            "{name}: elevation {got_e} vs {model_e}"
        );
        // A look ~45° down: a bearing error is the orientation's over cos(elevation).
        let slack = best_deg / true_e.to_radians().cos() + 0.01;
        assert!(
            turn(got_b, true_b) < slack,
            "{name}: bearing {got_b} vs {true_b}"
        );
        assert!(
            (got_e - true_e).abs() < best_deg + 0.01,
            "{name}: elevation {got_e}"
        );
    }
}

/// `dataset/`: PINHOLE cameras; every registered image present at its camera's size with its
/// mask; the masks keep the export's edge where the undistortion puts it; every 3D point reprojects
/// into the undistorted images where COLMAP observes it (median 0.5 px); and keyframer's
/// undistortion geometry (the masks' maps) takes COLMAP's undistorted observations back onto the
/// distorted ones.
#[test]
fn undistorted_dataset_is_pinhole_with_images_masks_and_consistent_points() {
    if !colmap_installed() {
        eprintln!("skipping: colmap is not installed");
        return;
    }
    let ws = workspace();
    let ds = ws.join("dataset");
    let (m, _) = model::read(&ds.join("sparse/0")).unwrap();
    let (source, _) = model::read(&ws.join("georegistered")).unwrap();
    assert_eq!(m.images.len(), source.images.len());
    let cam: &Camera = m.cameras.values().next().unwrap();
    assert_eq!(m.cameras.len(), 1);
    assert_eq!(cam.model, "PINHOLE");
    let [fx, fy, cx, cy] = [cam.params[0], cam.params[1], cam.params[2], cam.params[3]];
    for im in m.images.values() {
        let img = image::open(ds.join("images").join(&im.name)).unwrap();
        assert_eq!(
            (u64::from(img.width()), u64::from(img.height())),
            (cam.width, cam.height)
        );
        let mask = image::open(ds.join("masks").join(format!("{}.png", im.name)))
            .unwrap()
            .to_luma8();
        assert_eq!(
            (u64::from(mask.width()), u64::from(mask.height())),
            (cam.width, cam.height)
        );
        // The undistortion moves this flight's pixels by under a pixel and a half.
        for (x, y, v) in mask.enumerate_pixels() {
            if x + 2 < MASK_EDGE {
                assert_eq!(v.0[0], 0, "{} ({x}, {y})", im.name);
            } else if x > MASK_EDGE + 1 {
                assert_eq!(v.0[0], 255, "{} ({x}, {y})", im.name);
            }
        }
    }
    // Reprojection into the undistorted images.
    let mut errors = Vec::new();
    for pt in m.points.values() {
        for &(image_id, idx) in &pt.track {
            let im = &m.images[&image_id];
            let r = w2c(im.qvec);
            let xc: [f64; 3] = std::array::from_fn(|i| {
                (0..3).map(|k| r[i][k] * pt.xyz[k]).sum::<f64>() + im.tvec[i]
            });
            let (u, v) = (fx * xc[0] / xc[2] + cx, fy * xc[1] / xc[2] + cy);
            let (ox, oy, _) = im.points2d[idx as usize];
            errors.push(((u - ox).powi(2) + (v - oy).powi(2)).sqrt());
        }
    }
    errors.sort_by(f64::total_cmp);
    assert!(errors.len() > 1000, "{} observations", errors.len());
    let median = errors[errors.len() / 2];
    assert!(median < 0.5, "median reprojection error {median} px");
    // COLMAP's undistorted observations, taken back through keyframer's maps, land on the
    // distorted ones.
    let mut worst: f64 = 0.0;
    for im in m.images.values() {
        let src = source.images.values().find(|s| s.name == im.name).unwrap();
        let src_cam = &source.cameras[&src.camera_id];
        for (k, &(x, y, _)) in im.points2d.iter().enumerate() {
            let (u, v) = keyframer::colmap::undistort::unproject_pinhole(cam, x, y).unwrap();
            let (dx, dy) = keyframer::colmap::undistort::project(src_cam, u, v).unwrap();
            let (sx, sy, _) = src.points2d[k];
            worst = worst.max(((dx - sx).powi(2) + (dy - sy).powi(2)).sqrt());
        }
    }
    assert!(
        worst < 0.01,
        "undistortion maps differ from COLMAP's by {worst} px"
    );
}

/// `transforms.json` read as nerfstudio's parser reads it: `transform_matrix` camera-to-world
/// with OpenGL camera axes (x right, y up, z back) in the world `applied_transform · COLMAP's`;
/// its columns give back each camera's centre and axes computed here from the dataset's model
/// (1e-6), its intrinsics are the PINHOLE camera's, its files exist; on this georegistered
/// dataset the world is ENU (identity) and the centres are the true positions to the model's
/// accuracy.
#[test]
fn transforms_json_gives_back_the_models_cameras() {
    if !colmap_installed() {
        eprintln!("skipping: colmap is not installed");
        return;
    }
    let ds = workspace().join("dataset");
    let (m, _) = model::read(&ds.join("sparse/0")).unwrap();
    let t = json(&ds.join("transforms.json"));
    let cam = m.cameras.values().next().unwrap();
    for (k, key) in ["fl_x", "fl_y", "cx", "cy"].iter().enumerate() {
        assert_eq!(t[key].as_f64(), Some(cam.params[k]), "{key}");
    }
    assert_eq!(
        (t["w"].as_u64(), t["h"].as_u64()),
        (Some(cam.width), Some(cam.height))
    );
    let a: Vec<Vec<f64>> = serde_json::from_value(t["applied_transform"].clone()).unwrap();
    assert_eq!(a.len(), 3);
    let identity = (0..3).all(|i| (0..4).all(|j| a[i][j] == if i == j { 1.0 } else { 0.0 }));
    assert!(identity, "georegistered: ENU kept, {a:?}");
    assert!(t["aabb_scale"]
        .as_u64()
        .is_some_and(|v| v.is_power_of_two()));
    assert!(ds.join(t["ply_file_path"].as_str().unwrap()).is_file());
    let frames = t["frames"].as_array().unwrap();
    assert_eq!(frames.len(), m.images.len());
    let truth = truth(&m);
    let fit = best_fit(&m, &truth);
    // COLMAP world = Aᵀ · transforms world (A is a rotation here).
    let back =
        |v: [f64; 3]| -> [f64; 3] { std::array::from_fn(|j| (0..3).map(|i| a[i][j] * v[i]).sum()) };
    for f in frames {
        let file = f["file_path"].as_str().unwrap();
        assert!(ds.join(file).is_file(), "{file}");
        assert!(ds.join(f["mask_path"].as_str().unwrap()).is_file(), "{f}");
        let name = file.strip_prefix("images/").unwrap();
        let im = m.images.values().find(|im| im.name == name).unwrap();
        let c2w: Vec<Vec<f64>> = serde_json::from_value(f["transform_matrix"].clone()).unwrap();
        assert_eq!(c2w[3], [0.0, 0.0, 0.0, 1.0]);
        let column = |j: usize| back([c2w[0][j], c2w[1][j], c2w[2][j]]);
        let r = w2c(im.qvec);
        // OpenCV camera axes in the world are the rows of R; OpenGL's are x, −y, −z.
        let want = [
            r[0],
            r[1].map(|v| -v),
            r[2].map(|v| -v),
            centre(im.qvec, im.tvec),
        ];
        for (j, w) in want.iter().enumerate() {
            let got = column(j);
            assert!(dist(&got, w) < 1e-6, "{name} column {j}: {got:?} vs {w:?}");
        }
        let k = truth.iter().position(|t| t.0 == name).unwrap();
        let (best_m, best_deg) = fit.errors[k];
        assert_model_right(name, best_m, best_deg);
        let d = dist(&column(3), &truth[k].1);
        assert!(d < best_m + 0.01, "{name}: {d} m from the truth");
    }
}

/// Known intrinsics (`--camera-params`, here the scene's, as a distortion-free SIMPLE_PINHOLE that
/// `image_undistorter` leaves as it is) still give the trainers' dataset: one PINHOLE camera
/// with those intrinsics, every registered image with its mask, `transforms.json`.
#[test]
fn known_intrinsics_give_a_pinhole_dataset() {
    if !colmap_installed() {
        eprintln!("skipping: colmap is not installed");
        return;
    }
    let (flight, export) = export();
    let i = &json(&flight.join("scene.json"))["intrinsics"];
    let f = |k: &str| i[k].as_f64().unwrap();
    assert_eq!(f("fx"), f("fy"));
    let params = format!("{},{},{}", f("fx"), f("cx"), f("cy"));
    let ws = export.parent().unwrap().join("ws-known");
    kf_ok(&[
        "colmap",
        s(export),
        "-o",
        s(&ws),
        "--undistort",
        "--camera-model",
        "SIMPLE_PINHOLE",
        "--camera-params",
        &params,
        "--matcher",
        "exhaustive",
        "--force",
    ]);
    let ds = ws.join("dataset");
    let (m, _) = model::read(&ds.join("sparse/0")).unwrap();
    let (source, _) = model::read(&ws.join("sparse/0")).unwrap();
    assert_eq!(source.cameras[&1].model, "SIMPLE_PINHOLE");
    assert_eq!(m.cameras.len(), 1);
    let cam = &m.cameras[&1];
    assert_eq!(cam.model, "PINHOLE");
    assert_eq!(cam.params, [f("fx"), f("fy"), f("cx"), f("cy")]);
    assert_eq!((cam.width, cam.height), (u64::from(W), u64::from(H)));
    assert_eq!(m.images.len(), source.images.len());
    for im in m.images.values() {
        assert!(ds.join("images").join(&im.name).is_file(), "{}", im.name);
        let mask = ds.join("masks").join(format!("{}.png", im.name));
        assert!(mask.is_file(), "{}", mask.display());
    }
    let t = json(&ds.join("transforms.json"));
    assert_eq!(t["fl_x"].as_f64(), Some(f("fx")));
    assert_eq!(t["frames"].as_array().unwrap().len(), m.images.len());
}

/// `--georegister` refuses an export whose frames carry two positions, and one whose positions
/// lie on a line, with the reason, before COLMAP runs and without making the workspace.
#[test]
fn georegister_refuses_two_positions_and_a_straight_line() {
    if !colmap_installed() {
        eprintln!("skipping: colmap is not installed");
        return;
    }
    let (_, export) = export();
    let tmp = tempfile::tempdir().unwrap();
    for (keep, reason) in [(2usize, "2 positions"), (5, "lie on one line")] {
        let copy = tmp.path().join(format!("export{keep}"));
        std::fs::create_dir_all(copy.join("images")).unwrap();
        let mut manifest = json(&export.join("manifest.json"));
        for (k, f) in manifest["frames"]
            .as_array_mut()
            .unwrap()
            .iter_mut()
            .enumerate()
        {
            let name = f["file"].as_str().unwrap().to_string();
            std::fs::copy(
                export.join("images").join(&name),
                copy.join("images").join(&name),
            )
            .unwrap();
            f.as_object_mut().unwrap().remove("mask");
            if k >= keep {
                f.as_object_mut().unwrap().remove("position");
            }
        }
        std::fs::write(copy.join("manifest.json"), manifest.to_string()).unwrap();
        let (code, err) = code_and_stderr(&kf(&["colmap", s(&copy), "--sparse", "--georegister"]));
        assert_ne!(code, 0, "{err}");
        assert!(err.contains(reason), "{keep}: {err}");
        assert!(!copy.join("colmap").exists(), "{keep}: workspace made");
    }
}

/// `info` says what this machine's COLMAP can do for `keyframer colmap`: with Debian's 3.8
/// (no CUDA) sparse, undistort and georegister but not dense.
#[test]
fn info_says_what_colmap_can_do() {
    if !colmap_installed() {
        eprintln!("skipping: colmap is not installed");
        return;
    }
    let v: serde_json::Value = serde_json::from_str(&kf_ok(&["info", "--json"])).unwrap();
    let a = &v["colmap_abilities"]["Ok"];
    let version = a["version"].as_str().unwrap();
    assert!(version.starts_with("COLMAP"), "{v}");
    for k in ["sparse", "undistort", "georegister"] {
        assert_eq!(a[k], true, "{k}: {a}");
    }
    assert_eq!(a["dense"], !version.contains("without CUDA"), "{a}");
    let text = String::from_utf8(kf(&["info"]).stdout).unwrap();
    assert!(
        text.contains("keyframer colmap can run --sparse --undistort --georegister"),
        "{text}"
    );
}
