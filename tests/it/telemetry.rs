//! Telemetry in `select`: the geo-distance and footprint-overlap steps on synthetic flights whose
//! truth (poses.tum, scene.json) the tests measure against, their workflow round trip, the
//! refusal without telemetry and the warnings of bad telemetry, and the per-frame positions a
//! GPX track and an EXIF-tagged image folder give.

use crate::common::{
    code_and_stderr, dated_clip, ffmpeg, json, keyframes, kf, kf_loud, kf_ok, s, scene_ok,
};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// A 20 s survey at 30 fps (small frames, no motion blur) with the camera `pitch` degrees below
/// the horizon, generated once per test run.
fn flight(pitch: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("telemetry")
        .join(format!("pitch-{pitch}"));
    scene_ok(&[
        s(&dir),
        "--force",
        "--size",
        "160x90",
        "--fps",
        "30",
        "--seconds",
        "20",
        "--blur-samples",
        "1",
        "--pitch",
        pitch,
    ]);
    dir
}

fn nadir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| flight("90"))
}

fn oblique() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| flight("45"))
}

/// The true pose of every frame: camera centre and camera-to-world rotation (rows).
struct Truth {
    centre: [f64; 3],
    rot: [[f64; 3]; 3],
}

fn truth(dir: &Path) -> Vec<Truth> {
    (crate::scene::poses(dir).into_iter())
        .map(|(_, v)| Truth {
            centre: [v[0], v[1], v[2]],
            rot: crate::scene::rotation(&v[3..7]),
        })
        .collect()
}

fn dist(a: &Truth, b: &Truth) -> f64 {
    (0..3)
        .map(|i| (a.centre[i] - b.centre[i]).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Where the rays through the image corners of `t` meet the plane z = `ground` (the take-off
/// height), from the scene's pinhole intrinsics.
fn true_footprint(t: &Truth, scene: &serde_json::Value, ground: f64) -> Vec<(f64, f64)> {
    let k = &scene["intrinsics"];
    let f = |key: &str| k[key].as_f64().unwrap();
    let (w, h) = (
        scene["width"].as_f64().unwrap(),
        scene["height"].as_f64().unwrap(),
    );
    [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]
        .iter()
        .map(|&(u, v)| {
            let d = [(u - f("cx")) / f("fx"), (v - f("cy")) / f("fy"), 1.0];
            let r = &t.rot;
            let world: Vec<f64> = (0..3)
                .map(|i| r[i][0] * d[0] + r[i][1] * d[1] + r[i][2] * d[2])
                .collect();
            assert!(world[2] < 0.0, "a corner ray misses the ground");
            let s = (ground - t.centre[2]) / world[2];
            (t.centre[0] + s * world[0], t.centre[1] + s * world[1])
        })
        .collect()
}

/// Whether `p` is inside the convex polygon `poly` (either orientation).
fn inside(poly: &[(f64, f64)], p: (f64, f64)) -> bool {
    let n = poly.len();
    let sides: Vec<f64> = (0..n)
        .map(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % n]);
            (b.0 - a.0) * (p.1 - a.1) - (b.1 - a.1) * (p.0 - a.0)
        })
        .collect();
    sides.iter().all(|&x| x >= 0.0) || sides.iter().all(|&x| x <= 0.0)
}

/// area(a ∩ b) / area(a), counted on a 400 x 400 grid over a's bounding box.
fn sampled_overlap(a: &[(f64, f64)], b: &[(f64, f64)]) -> f64 {
    let (x0, x1) = (
        a.iter().map(|p| p.0).fold(f64::MAX, f64::min),
        a.iter().map(|p| p.0).fold(f64::MIN, f64::max),
    );
    let (y0, y1) = (
        a.iter().map(|p| p.1).fold(f64::MAX, f64::min),
        a.iter().map(|p| p.1).fold(f64::MIN, f64::max),
    );
    let n = 400;
    let (mut in_a, mut in_both) = (0u64, 0u64);
    for i in 0..n {
        for j in 0..n {
            let p = (
                x0 + (x1 - x0) * (i as f64 + 0.5) / n as f64,
                y0 + (y1 - y0) * (j as f64 + 0.5) / n as f64,
            );
            if inside(a, p) {
                in_a += 1;
                if inside(b, p) {
                    in_both += 1;
                }
            }
        }
    }
    in_both as f64 / in_a as f64
}

fn select(dir: &Path, name: &str, flags: &[&str]) -> (PathBuf, Vec<usize>) {
    let project = dir.join(name);
    let video = dir.join("video.mp4");
    let mut args = vec!["select", s(&video), "-o", s(&project), "--force"];
    args.extend_from_slice(flags);
    kf_ok(&args);
    let keys = keyframes(&project);
    (project, keys)
}

/// `--geo-distance D`: the keyframes' true camera centres are D apart, evenly (coefficient of
/// variation of the spacing at most 0.05), each at least D and less than D plus one frame's
/// travel.
#[test]
fn geo_distance_spaces_keyframes_evenly_by_the_truth() {
    let dir = oblique();
    let poses = truth(dir);
    let d = 8.0;
    let (project, keys) = select(dir, "geo.json", &["--geo-distance", "8"]);
    let step = poses
        .windows(2)
        .map(|w| dist(&w[0], &w[1]))
        .fold(0.0, f64::max);
    let spacing: Vec<f64> = keys
        .windows(2)
        .map(|w| dist(&poses[w[0]], &poses[w[1]]))
        .collect();
    assert!(spacing.len() >= 8, "{keys:?}");
    for (w, x) in keys.windows(2).zip(&spacing) {
        // The SRT's 9 decimals and 3 of the heights keep the truth to a millimetre.
        assert!(*x >= d - 0.005 && *x < d + step + 0.005, "{w:?}: {x} m");
    }
    let mean = spacing.iter().sum::<f64>() / spacing.len() as f64;
    let var = spacing.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / spacing.len() as f64;
    let cv = var.sqrt() / mean;
    assert!(cv <= 0.05, "coefficient of variation {cv} ({spacing:?})");
    geo_panel_shows_the_distances_the_step_compared(dir, &project, &keys, d);
}

/// The report's telemetry panel: metres moved since the previous keyframe reach the
/// geo-distance threshold (drawn) at every keyframe after the first and stay below it between.
fn geo_panel_shows_the_distances_the_step_compared(
    dir: &Path,
    project: &Path,
    keys: &[usize],
    d: f64,
) {
    let html = dir.join("geo-report.html");
    let args = [
        "report",
        s(project),
        "-o",
        s(&html),
        "--force",
        "--thumbs",
        "0",
    ];
    kf_ok(&args);
    let page = std::fs::read_to_string(&html).unwrap();
    let svg = page.split("<svg id=\"timeline\"").nth(1).unwrap();
    assert!(svg.contains("Distance moved since the previous keyframe"));
    assert!(svg.contains("geo-distance threshold 8.0 m"));
    let data = page.split("id=\"kf-data\">").nth(1).unwrap();
    let data: serde_json::Value =
        serde_json::from_str(data.split("</script>").next().unwrap()).unwrap();
    let curve = data["curves"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == "metres moved since the previous keyframe")
        .expect("the telemetry curve");
    let values = curve["values"].as_array().unwrap();
    for (f, v) in values.iter().enumerate().skip(keys[0] + 1) {
        let Some(v) = v.as_f64() else { continue };
        match keys.binary_search(&f) {
            Ok(_) => assert!(v >= d - 1e-3, "keyframe {f}: {v} m"),
            Err(_) => assert!(v < d + 1e-3, "frame {f}: {v} m"),
        }
    }
}

/// `--footprint-overlap 80`: consecutive keyframes' true ground footprints (image corners cast
/// onto the take-off height) overlap by 80 % ± 5 %, with the camera straight down and at 45°.
#[test]
fn footprint_overlap_keeps_eighty_percent_by_the_truth() {
    for dir in [nadir(), oblique()] {
        let poses = truth(dir);
        let scene = json(&dir.join("scene.json"));
        let ground = scene["telemetry"]["takeoff_z_m"].as_f64().unwrap();
        let (_, keys) = select(dir, "footprint.json", &["--footprint-overlap", "80"]);
        assert!(keys.len() >= 6, "{}: {keys:?}", dir.display());
        for w in keys.windows(2) {
            let a = true_footprint(&poses[w[0]], &scene, ground);
            let b = true_footprint(&poses[w[1]], &scene, ground);
            let o = sampled_overlap(&a, &b);
            assert!(
                (o - 0.80).abs() <= 0.05,
                "{}: keyframes {w:?} overlap {:.1} %",
                dir.display(),
                100.0 * o
            );
        }
    }
}

/// `workflow save` of a geo-sampled project and `run` of it on the same flight select the same
/// keyframes; chained with blur.
#[test]
fn geo_workflow_save_and_run_reproduce_the_selection() {
    let dir = nadir();
    let (project, keys) = select(
        dir,
        "chain.json",
        &["--footprint-overlap", "75", "--hfov", "71", "--blur"],
    );
    let history = json(&project)["history"].clone();
    let plugins: Vec<&str> = (history.as_array().unwrap().iter())
        .map(|e| e["plugin"].as_str().unwrap())
        .collect();
    assert_eq!(plugins, ["boundaries", "footprint-overlap", "blur"]);
    assert_eq!(history[1]["params"]["hfov"].as_f64(), Some(71.0));
    let tmp = tempfile::tempdir().unwrap();
    let workflow = tmp.path().join("w.toml");
    kf_ok(&["workflow", "save", s(&project), "-o", s(&workflow)]);
    let text = std::fs::read_to_string(&workflow).unwrap();
    assert!(text.contains("plugin = \"footprint-overlap\""), "{text}");
    let runs = tmp.path().join("runs");
    let video = dir.join("video.mp4");
    kf_ok(&["run", s(&workflow), s(&video), "--out", s(&runs)]);
    let folder = runs.join(keyframer::batch::folder_name(&video));
    assert_eq!(keyframes(&folder.join("project.json")), keys);

    let (project, keys) = select(
        dir,
        "geo-every.json",
        &["--geo-distance", "5", "--every", "2"],
    );
    kf_ok(&[
        "workflow",
        "save",
        s(&project),
        "-o",
        s(&workflow),
        "--force",
    ]);
    let runs = tmp.path().join("runs2");
    kf_ok(&["run", s(&workflow), s(&video), "--out", s(&runs)]);
    assert_eq!(
        keyframes(&folder_in(&runs, &video).join("project.json")),
        keys
    );
}

fn folder_in(runs: &Path, input: &Path) -> PathBuf {
    runs.join(keyframer::batch::folder_name(input))
}

/// Without telemetry the geo steps refuse, naming themselves; bad telemetry is warned about
/// with its file and line.
#[test]
fn geo_steps_refuse_without_telemetry_and_bad_telemetry_is_warned() {
    let tmp = tempfile::tempdir().unwrap();
    let clip = dated_clip(tmp.path(), 3);
    let p = tmp.path().join("p.json");
    for flag in ["--geo-distance", "--footprint-overlap"] {
        let out = kf(&["select", s(&clip), flag, "50", "-o", s(&p), "--force"]);
        let (code, err) = code_and_stderr(&out);
        assert_eq!(code, 1, "{err}");
        let step = &flag[2..];
        assert!(
            err.contains(&format!("plugin `{step}`")) && err.contains("no telemetry"),
            "{err}"
        );
        assert!(!p.exists());
    }
    // Zero coordinates, a jump of kilometres, an entry without a position.
    let srt = tmp.path().join("bad.srt");
    let entry = |i: usize, lat: f64, lon: f64| {
        format!(
            "{}\n00:00:0{i},000 --> 00:00:0{},000\n[latitude: {lat}] [longitude: {lon}] [rel_alt: 30.0 abs_alt: 430.0]\n\n",
            i + 1,
            i + 1
        )
    };
    let text = entry(0, 47.0, 8.0)
        + &entry(1, 0.0, 0.0)
        + &entry(2, 47.1, 8.0)
        + "4\n00:00:03,000 --> 00:00:04,000\n[iso: 100]\n";
    std::fs::write(&srt, text).unwrap();
    let out = kf_loud(&[
        "select",
        s(&clip),
        "--telemetry",
        s(&srt),
        "--every",
        "1",
        "-o",
        s(&p),
        "--force",
    ]);
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 0, "{err}");
    let name = srt.display();
    for want in [
        format!("{name}:line 6: position 0, 0"),
        format!("{name}:line 10: the position jumps"),
        format!("{name}:line 14: no position"),
    ] {
        assert!(err.contains(&want), "{want} missing in:\n{err}");
    }
    // Candidates after the telemetry's last fix (at 2 s): the step says none has a position.
    let out = kf(&[
        "select",
        s(&clip),
        "--telemetry",
        s(&srt),
        "--start",
        "2.5s",
        "--geo-distance",
        "5",
        "-o",
        s(&p),
        "--force",
    ]);
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("plugin `geo-distance`: none of the 5 candidates has a position"),
        "{err}"
    );
    // A file with no entry at all: an error naming it.
    let junk = tmp.path().join("junk.srt");
    std::fs::write(&junk, "not a subtitle file\n").unwrap();
    let out = kf(&[
        "select",
        s(&clip),
        "--telemetry",
        s(&junk),
        "-o",
        s(&p),
        "--force",
    ]);
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains(&format!("{}: no telemetry entry", junk.display())),
        "{err}"
    );
    // A clock offset beyond the telemetry: no frame has a position, and the steps refuse.
    let out = kf_loud(&[
        "select",
        s(&clip),
        "--telemetry",
        s(&srt),
        "--telemetry-offset",
        "100",
        "--geo-distance",
        "5",
        "-o",
        s(&p),
        "--force",
    ]);
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("no frame has a position"), "{err}");
    assert!(err.contains("plugin `geo-distance`"), "{err}");
}

/// The positions of a project: (lat, lon, altitude above sea level) per frame.
fn positions(project: &Path) -> Vec<Option<(f64, f64, Option<f64>)>> {
    let p = json(project);
    let tel = &p["cache"]["telemetry"]["positions"];
    (tel.as_array().expect("positions").iter())
        .map(|v| {
            (!v.is_null()).then(|| {
                (
                    v["lat_deg"].as_f64().unwrap(),
                    v["lon_deg"].as_f64().unwrap(),
                    v["abs_alt_m"].as_f64(),
                )
            })
        })
        .collect()
}

/// A GPX track timed by the clock (one point every 2 s, moving north-east at a constant rate
/// and climbing), read with an offset of 0.5 s: every frame at t gets the track's position at
/// t + 0.5 s, and the source is recorded.
#[test]
fn gpx_track_gives_every_frame_its_position() {
    let tmp = tempfile::tempdir().unwrap();
    let clip = dated_clip(tmp.path(), 3);
    let (lat0, lon0, alt0) = (47.0, 8.0, 400.0);
    let (dlat, dlon, dalt) = (1e-5, 2e-5, 0.5); // per second
    let point = |k: i64| {
        let t = (2 * k) as f64;
        format!(
            "<trkpt lat=\"{:.9}\" lon=\"{:.9}\"><ele>{}</ele><time>2024-05-01T10:00:{:02}Z</time></trkpt>\n",
            lat0 + dlat * t,
            lon0 + dlon * t,
            alt0 + dalt * t,
            2 * k
        )
    };
    let gpx = tmp.path().join("track.gpx");
    let points: String = (0..4).map(point).collect();
    std::fs::write(
        &gpx,
        format!(
            "<?xml version=\"1.0\"?>\n<gpx version=\"1.1\" creator=\"t\" xmlns=\"http://www.topografix.com/GPX/1/1\"><trk><trkseg>\n{points}</trkseg></trk></gpx>\n"
        ),
    )
    .unwrap();
    let p = tmp.path().join("p.json");
    let out = kf(&[
        "select",
        s(&clip),
        "--telemetry",
        s(&gpx),
        "--telemetry-offset",
        "0.5",
        "--every",
        "1",
        "-o",
        s(&p),
    ]);
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 0, "{err}");
    let project = json(&p);
    let source = &project["cache"]["telemetry"]["source"];
    assert_eq!(source["kind"], "gpx");
    assert_eq!(source["offset_s"].as_f64(), Some(0.5));
    let ts: Vec<f64> = (project["cache"]["timestamps_s"].as_array().unwrap().iter())
        .map(|t| t.as_f64().unwrap())
        .collect();
    let pos = positions(&p);
    assert_eq!(pos.len(), ts.len());
    assert_eq!(ts.len(), 30);
    for (i, (t, got)) in ts.iter().zip(&pos).enumerate() {
        let tt = t + 0.5;
        let (lat, lon, alt) = got.unwrap_or_else(|| panic!("frame {i} has no position"));
        assert!((lat - (lat0 + dlat * tt)).abs() < 1e-9, "frame {i}: {lat}");
        assert!((lon - (lon0 + dlon * tt)).abs() < 1e-9, "frame {i}: {lon}");
        assert!(
            (alt.unwrap() - (alt0 + dalt * tt)).abs() < 1e-9,
            "frame {i}"
        );
    }
    // Re-selecting with another offset reads the track again; with the same one it reuses it.
    let again = kf_loud(&[
        "select",
        s(&clip),
        "--telemetry",
        s(&gpx),
        "--telemetry-offset",
        "0.5",
        "--every",
        "2",
        "-o",
        s(&p),
        "--force",
    ]);
    let (_, err) = code_and_stderr(&again);
    assert!(err.contains("reusing the positions"), "{err}");
    // `workflow save` records the track and the offset, and `run` of the workflow places the
    // video in the track again: the same positions and keyframes.
    let w = tmp.path().join("w.toml");
    kf_ok(&["workflow", "save", s(&p), "-o", s(&w)]);
    let text = std::fs::read_to_string(&w).unwrap();
    assert!(text.contains("telemetry_offset = 0.5"), "{text}");
    let track = keyframer::fsutil::absolute(&gpx);
    assert!(
        text.contains(&format!("telemetry = {:?}", track.display().to_string())),
        "{text}"
    );
    let runs = tmp.path().join("runs");
    kf_ok(&["run", s(&w), s(&clip), "--out", s(&runs)]);
    let ran = folder_in(&runs, &clip).join("project.json");
    assert_eq!(positions(&ran), positions(&p));
    assert_eq!(keyframes(&ran), keyframes(&p));
    // A workflow naming a track that is not there is refused with its key.
    let moved = tmp.path().join("moved.toml");
    std::fs::write(&moved, text.replace("track.gpx", "gone.gpx")).unwrap();
    let (code, err) = code_and_stderr(&kf(&["run", s(&moved), s(&clip), "--out", s(&runs)]));
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("analysis.telemetry") && err.contains("gone.gpx"),
        "{err}"
    );
}

/// An image folder whose JPEGs carry EXIF GPS tags (written by keyframer's geotag): each frame
/// gets its image's position; one image without tags has none.
#[test]
fn exif_tagged_folder_gives_every_image_its_position() {
    use keyframer::geotag::GeoTag;
    let tmp = tempfile::tempdir().unwrap();
    let (folder, tags) = crate::common::tagged_image_folder(tmp.path(), |i| {
        (i != 3).then(|| GeoTag {
            lat_deg: -33.5 + 1e-4 * i as f64,
            lon_deg: 151.25 - 3e-4 * i as f64,
            alt_m: Some(10.0 * i as f64),
            taken: None,
            focal_35mm: Some(24.0),
            make: None,
            model: None,
            source: format!("test image {i}"),
        })
    });
    let truth: Vec<_> = tags
        .iter()
        .map(|t| t.as_ref().map(|t| (t.lat_deg, t.lon_deg, t.alt_m)))
        .collect();
    let p = tmp.path().join("p.json");
    kf_ok(&["select", s(&folder), "--every", "1", "-o", s(&p)]);
    let got = positions(&p);
    assert_eq!(got.len(), truth.len());
    for (i, (g, t)) in got.iter().zip(&truth).enumerate() {
        match (g, t) {
            (Some(g), Some(t)) => {
                assert!(
                    (g.0 - t.0).abs() < 1e-7 && (g.1 - t.1).abs() < 1e-7,
                    "image {i}: {g:?}"
                );
                assert!((g.2.unwrap() - t.2.unwrap()).abs() < 1e-6, "image {i}");
            }
            (None, None) => {}
            _ => panic!("image {i}: {g:?} vs {t:?}"),
        }
    }
    assert_eq!(json(&p)["cache"]["telemetry"]["source"]["kind"], "exif");
}

/// The DJI SRT `srt` without its focal lengths.
pub fn without_focal(srt: &str) -> String {
    srt.lines()
        .map(|l| match (l.find("[focal_len: "), l.find("] [latitude")) {
            (Some(a), Some(b)) => format!("{}{}\n", &l[..a], &l[b + 2..]),
            _ => format!("{l}\n"),
        })
        .collect()
}

/// Without a focal length in the telemetry, footprint-overlap takes the field of view from
/// `--hfov`, else from the camera table when the video's container names a known DJI camera,
/// else refuses, saying so.
#[test]
fn footprint_field_of_view_from_hfov_or_the_camera_table() {
    let dir = nadir();
    let tmp = tempfile::tempdir().unwrap();
    let srt = std::fs::read_to_string(dir.join("video.SRT")).unwrap();
    assert!(srt.contains("[focal_len: "));
    let without_focal = without_focal(&srt);
    assert!(!without_focal.contains("focal_len"));
    let named = tmp.path().join("named.mp4");
    let video = dir.join("video.mp4");
    ffmpeg(&[
        "-i",
        s(&video),
        "-c",
        "copy",
        "-metadata",
        "comment=DJI Mini 3 Pro",
        s(&named),
    ]);
    let bare = tmp.path().join("bare.mp4");
    ffmpeg(&["-i", s(&video), "-c", "copy", s(&bare)]);
    for clip in [&named, &bare] {
        std::fs::write(clip.with_extension("SRT"), &without_focal).unwrap();
    }
    let p = tmp.path().join("p.json");
    let run = |clip: &Path, extra: &[&str]| {
        let mut args = vec![
            "select",
            s(clip),
            "--footprint-overlap",
            "80",
            "-o",
            s(&p),
            "--force",
        ];
        args.extend_from_slice(extra);
        code_and_stderr(&kf(&args))
    };
    let (code, err) = run(&bare, &[]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("plugin `footprint-overlap`") && err.contains("give --hfov"),
        "{err}"
    );
    let (code, err) = run(&bare, &["--hfov", "71.08"]);
    assert_eq!(code, 0, "{err}");
    let with_hfov = keyframes(&p);
    let (code, err) = run(&named, &[]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        json(&p)["cache"]["telemetry"]["camera"].as_str(),
        Some("DJI Mini 3 Pro")
    );
    // The table's 24 mm is a wider view than the scene's 25.2 mm: fewer keyframes.
    let with_table = keyframes(&p);
    assert!(
        with_table.len() <= with_hfov.len() && with_table.len() >= 2,
        "{with_table:?} vs {with_hfov:?}"
    );
}

/// The numbers of `name="..."` attributes in `tag`.
fn attr_numbers(tag: &str, name: &str) -> Vec<f64> {
    let Some(v) = tag.split(&format!(" {name}=\"")).nth(1) else {
        return Vec::new();
    };
    v.split('"')
        .next()
        .unwrap()
        .split([' ', ','])
        .map(|x| x.parse().unwrap())
        .collect()
}

/// The report's flight map: every keyframe marked where the truth puts it (one scale, north up)
/// with its footprint where the true footprint lies, and the map seen in headless Chromium.
#[test]
fn report_flight_map_draws_keyframes_and_footprints_where_the_truth_is() {
    let dir = nadir();
    let poses = truth(dir);
    let scene = json(&dir.join("scene.json"));
    let ground = scene["telemetry"]["takeoff_z_m"].as_f64().unwrap();
    // From frame 90: the footprints come relative to the first keyframe, the map from frame 0.
    let (project, keys) = select(
        dir,
        "map.json",
        &["--start", "90", "--footprint-overlap", "80"],
    );
    let html = dir.join("map-report.html");
    kf_ok(&[
        "report",
        s(&project),
        "-o",
        s(&html),
        "--force",
        "--thumbs",
        "0",
    ]);
    let page = std::fs::read_to_string(&html).unwrap();
    let map = page
        .split("<svg id=\"flight-map\"")
        .nth(1)
        .expect("a flight map")
        .split("</svg>")
        .next()
        .unwrap();
    assert!(map.contains(&format!("data-keyframes=\"{}\"", keys.len())));
    // The timeline's telemetry panel, without a geo-distance threshold to draw.
    assert!(page.contains("Distance moved since the previous keyframe"));
    assert!(!page.contains("geo-distance threshold"));
    // (frame, mark, footprint) per keyframe, in px.
    type Mark = (usize, (f64, f64), Vec<(f64, f64)>);
    let marks: Vec<Mark> = map
        .split("<g class=\"kf\"")
        .skip(1)
        .map(|g| {
            let frame = attr_numbers(g, "data-frame")[0] as usize;
            let poly = attr_numbers(g, "points");
            let print = poly.chunks(2).map(|p| (p[0], p[1])).collect();
            let (cx, cy) = (attr_numbers(g, "cx")[0], attr_numbers(g, "cy")[0]);
            (frame, (cx, cy), print)
        })
        .collect();
    assert_eq!(marks.iter().map(|m| m.0).collect::<Vec<_>>(), keys);
    // One scale from the first and last keyframes' true centres (x east, y north).
    let (first, last) = (&marks[0], &marks[marks.len() - 1]);
    let (a, b) = (&poses[first.0].centre, &poses[last.0].centre);
    let px = (last.1 .0 - first.1 .0).hypot(last.1 .1 - first.1 .1);
    let k = px / (b[0] - a[0]).hypot(b[1] - a[1]);
    let to_px = |x: f64, y: f64| (first.1 .0 + k * (x - a[0]), first.1 .1 - k * (y - a[1]));
    for (frame, mark, print) in &marks {
        let c = &poses[*frame].centre;
        let want = to_px(c[0], c[1]);
        assert!(
            (mark.0 - want.0).hypot(mark.1 - want.1) < 1.0,
            "frame {frame}: mark {mark:?}, truth at {want:?}"
        );
        let truth_print: Vec<(f64, f64)> = true_footprint(&poses[*frame], &scene, ground)
            .into_iter()
            .map(|(x, y)| to_px(x, y))
            .collect();
        assert_eq!(print.len(), 4, "frame {frame}");
        let width =
            (truth_print[1].0 - truth_print[0].0).hypot(truth_print[1].1 - truth_print[0].1);
        // Corners in the same order: top-left, top-right, bottom-right, bottom-left.
        for (p, t) in print.iter().zip(&truth_print) {
            assert!(
                (p.0 - t.0).hypot(p.1 - t.1) < 0.03 * width,
                "frame {frame}: footprint corner {p:?}, truth {t:?} (width {width:.1} px)"
            );
        }
    }
    if !Path::new("/usr/bin/chromium").exists() {
        println!("SKIPPED the screenshot: /usr/bin/chromium is absent");
        return;
    }
    let profile = tempfile::tempdir().unwrap();
    let shot = dir.join("map-report.png");
    let out = std::process::Command::new("/usr/bin/chromium")
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--hide-scrollbars",
            "--force-device-scale-factor=1",
            "--window-size=1300,3000",
        ])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg(format!("--screenshot={}", shot.display()))
        .arg(format!("file://{}", html.display()))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = image::open(&shot).unwrap().to_rgb8();
    // The keyframe marks' magenta (#cc00cc), drawn nowhere else on the page.
    let marked = img
        .pixels()
        .filter(|p| {
            (i32::from(p[0]) - 204).abs() < 8
                && i32::from(p[1]) < 8
                && (i32::from(p[2]) - 204).abs() < 8
        })
        .count();
    assert!(
        marked >= 20 * keys.len(),
        "{marked} magenta pixels for {} keyframe marks",
        keys.len()
    );
}

/// `select --preview` keeps every frame's position (for the geotagged export and the map), the
/// positions a full selection stores.
#[test]
fn preview_keeps_every_frames_position() {
    let dir = oblique();
    let (full, _) = select(dir, "full-positions.json", &["--every", "30"]);
    let (preview, keys) = select(
        dir,
        "preview-positions.json",
        &["--preview", "--geo-distance", "20"],
    );
    assert!(!keys.is_empty());
    assert_eq!(json(&preview)["preview"], true);
    let (a, b) = (positions(&full), positions(&preview));
    assert_eq!(a.len(), b.len());
    for (i, (a, b)) in a.iter().zip(&b).enumerate() {
        let (a, b) = (a.unwrap(), b.expect("a position for every frame"));
        assert!(
            (a.0 - b.0).abs() < 1e-9 && (a.1 - b.1).abs() < 1e-9,
            "frame {i}: {a:?} vs {b:?}"
        );
    }
}

/// A DJI SRT for `dated_clip`'s 3 s: an entry every 0.1 s (entries 0 to 30), flying north at
/// 10 m/s with a 24 mm lens facing north; `entry(i)` gives entry i's height above take-off and
/// gimbal pitch; `bad` entries without a position follow.
fn flight_srt(path: &Path, entry: impl Fn(usize) -> (f64, f64), bad: usize) {
    let time = |i: usize| format!("00:00:{:02},{:03}", i / 10, (i % 10) * 100);
    let mut text: String = (0..=30)
        .map(|i| {
            let (h, pitch) = entry(i);
            format!(
                "{}\n{} --> {}\n[focal_len: 24.00] [latitude: {:.8}] [longitude: 8.0] [rel_alt: {h:.3} abs_alt: {:.3}] [gb_yaw: 0.0 gb_pitch: {pitch:.1} gb_roll: 0.0]\n\n",
                i + 1,
                time(i),
                time(i + 1),
                47.0 + 9e-6 * i as f64,
                500.0 + h
            )
        })
        .collect();
    for i in 31..31 + bad {
        text += &format!("{}\n{} --> {}\n[iso: 100]\n\n", i + 1, time(i), time(i + 1));
    }
    std::fs::write(path, text).unwrap();
}

/// `keyframer select CLIP --telemetry SRT ARGS -o P --force --quiet`.
fn select_cmd(clip: &Path, srt: &Path, p: &Path, args: &[&str]) -> std::process::Command {
    let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_keyframer"));
    c.args([
        "select",
        s(clip),
        "--telemetry",
        s(srt),
        "-o",
        s(p),
        "--force",
    ]);
    c.args(args).arg("--quiet");
    c
}

/// Runs [`select_cmd`]: exit code and stderr.
fn select_with(clip: &Path, srt: &Path, p: &Path, args: &[&str]) -> (i32, String) {
    code_and_stderr(&select_cmd(clip, srt, p, args).output().unwrap())
}

/// Frames on the ground (DJI's 0 m, and -0.2 m below the take-off point) before a climb have no
/// footprint: footprint-overlap says which, keeps none of them and selects from the airborne
/// frames as if the ground frames were no candidates (the same keyframes as `--start 11`).
#[test]
fn footprint_overlap_leaves_out_frames_on_the_ground_and_says_so() {
    let tmp = tempfile::tempdir().unwrap();
    let clip = dated_clip(tmp.path(), 3);
    let srt = tmp.path().join("ground.srt");
    let height = |i: usize| match i {
        0..=5 => 0.0,
        6..=10 => -0.2,
        _ => 30.0,
    };
    flight_srt(&srt, |i| (height(i), -90.0), 0);
    let p = tmp.path().join("p.json");
    let (code, err) = select_with(&clip, &srt, &p, &["--footprint-overlap", "80"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains(
            "footprint-overlap: frames 0–10 (11 of 30 candidates): on the ground or below the \
             take-off height"
        ),
        "{err}"
    );
    let keys = keyframes(&p);
    assert!(keys.len() >= 2 && keys[0] == 11, "{keys:?}");
    let (code, err) = select_with(
        &clip,
        &srt,
        &p,
        &["--start", "11", "--footprint-overlap", "80"],
    );
    assert_eq!(code, 0, "{err}");
    assert!(!err.contains("on the ground"), "{err}");
    assert_eq!(keyframes(&p), keys);
}

/// A flight that never leaves the ground, or stays below its take-off point (a survey down a
/// slope), has no footprint at all: footprint-overlap refuses, naming the frames, and writes
/// nothing.
#[test]
fn footprint_overlap_refuses_a_flight_without_a_frame_above_take_off() {
    let tmp = tempfile::tempdir().unwrap();
    let clip = dated_clip(tmp.path(), 3);
    let srt = tmp.path().join("below.srt");
    flight_srt(&srt, |i| (if i < 16 { 0.0 } else { -12.0 }, -90.0), 0);
    let p = tmp.path().join("p.json");
    let (code, err) = select_with(&clip, &srt, &p, &["--footprint-overlap", "80"]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains(
            "plugin `footprint-overlap`: no candidate has a ground footprint: frames 0–29 (30 of \
             30 candidates): on the ground or below the take-off height"
        ),
        "{err}"
    );
    assert!(!p.exists());
}

/// A camera at or above the horizon and a field of view of 170° or more are warned about with
/// their frames (the selection still runs); a 24 mm lens looking down is not.
#[test]
fn footprint_overlap_warns_of_a_camera_at_the_horizon_and_a_very_wide_view() {
    let tmp = tempfile::tempdir().unwrap();
    let clip = dated_clip(tmp.path(), 3);
    let srt = tmp.path().join("level.srt");
    flight_srt(&srt, |i| (30.0, if i < 20 { -90.0 } else { 5.0 }), 0);
    let p = tmp.path().join("p.json");
    let horizon = "frames 20–29 (10 of 30 candidates): the camera looks at or above the horizon";
    let wide = "frames 0–29 (30 of 30 candidates): a field of view of 170° or more";
    let (code, err) = select_with(&clip, &srt, &p, &["--footprint-overlap", "80"]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains(horizon) && !err.contains(wide), "{err}");
    let args = ["--footprint-overlap", "80", "--hfov", "172"];
    let (code, err) = select_with(&clip, &srt, &p, &args);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains(horizon) && err.contains(wide), "{err}");
    assert!(!keyframes(&p).is_empty());
}

/// Many bad telemetry entries: the first five are printed (also with `-q`) and a count of the
/// rest, and the project keeps those five and the count; RUST_LOG=keyframer=debug prints all.
/// An older project keeping the full list still loads, and its reuse prints and keeps the
/// summary.
#[test]
fn many_telemetry_warnings_are_summarised() {
    let tmp = tempfile::tempdir().unwrap();
    let clip = dated_clip(tmp.path(), 3);
    let srt = tmp.path().join("noisy.srt");
    flight_srt(&srt, |_| (30.0, -90.0), 40);
    let p = tmp.path().join("p.json");
    let (code, err) = select_with(&clip, &srt, &p, &["--every", "1"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(err.matches("(entry skipped)").count(), 5, "{err}");
    let count = format!("{}: 35 more telemetry warnings", srt.display());
    assert!(err.contains(&count), "{err}");
    let tel = &json(&p)["cache"]["telemetry"];
    assert_eq!(tel["warnings"].as_array().unwrap().len(), 5);
    assert_eq!(tel["more_warnings"], 35);
    let debug = tmp.path().join("debug.json");
    let out = select_cmd(&clip, &srt, &debug, &["--every", "1"])
        .env("RUST_LOG", "keyframer=debug")
        .output()
        .unwrap();
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 0, "{err}");
    assert_eq!(err.matches("(entry skipped)").count(), 40, "{err}");
    // The project as an older version wrote it: every warning, no count.
    let mut old = json(&p);
    let all: Vec<String> = (1..=40).map(|i| format!("old warning {i}.")).collect();
    let tel = old["cache"]["telemetry"].as_object_mut().unwrap();
    tel.insert("warnings".into(), serde_json::json!(all));
    tel.remove("more_warnings");
    std::fs::write(&p, serde_json::to_string_pretty(&old).unwrap()).unwrap();
    let (code, err) = select_with(&clip, &srt, &p, &["--every", "1"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("old warning 5.") && !err.contains("old warning 6."),
        "{err}"
    );
    assert!(err.contains(&count), "{err}");
    let tel = &json(&p)["cache"]["telemetry"];
    assert_eq!(tel["warnings"], serde_json::json!(all[..5]));
    assert_eq!(tel["more_warnings"], 35);
}
