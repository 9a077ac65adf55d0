//! Geotagged export on a small synthetic flight south of the equator and west of Greenwich (so
//! the hemisphere refs matter): every exported JPEG, read back by exiftool, carries its frame's
//! true position, altitude above sea level, capture time and 35 mm focal length, and the manifest
//! lists the positions; COLMAP reads the tags (its position priors and EXIF focal length);
//! `--no-geotag` leaves them out; PNGs and frames without a position stay untagged with one
//! warning each; a known camera gives Make and Model.

use crate::common::{code_and_stderr, ffmpeg, json, kf, kf_ok, project_positions, s, scene_ok};
use keyframer::source::telemetry::wgs84_radii;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// Where the flight's world origin is on Earth (latitude, longitude, metres above sea level).
const ORIGIN: &str = "-33.8568,-70.6012,520.5";

/// An 8 s survey at 10 fps, 320x180 (80 frames), generated once per test run.
fn flight() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join("geotag")
            .join("flight");
        scene_ok(&[
            s(&dir),
            "--force",
            "--size",
            "320x180",
            "--fps",
            "10",
            "--seconds",
            "8",
            "--blur-samples",
            "1",
            &format!("--origin={ORIGIN}"),
        ]);
        dir
    })
}

/// One frame's truth: its time and where the camera was.
struct Truth {
    t_s: f64,
    lat_deg: f64,
    lon_deg: f64,
    /// Metres above sea level.
    alt_m: f64,
}

/// Every frame's truth from poses.tum (world metres: x east, y north, z up) placed on Earth by
/// scene.json's origin, on the tangent plane with the WGS84 radii of curvature at the origin
/// (how the scene defines its geography).
fn truth(dir: &Path) -> Vec<Truth> {
    let origin = &json(&dir.join("scene.json"))["telemetry"]["origin"];
    let (lat0, lon0, alt0) = (
        origin["lat_deg"].as_f64().unwrap(),
        origin["lon_deg"].as_f64().unwrap(),
        origin["alt_m"].as_f64().unwrap(),
    );
    let given: Vec<f64> = ORIGIN.split(',').map(|x| x.parse().unwrap()).collect();
    assert_eq!(given, [lat0, lon0, alt0]);
    let (meridian, prime) = wgs84_radii(lat0);
    (crate::scene::poses(dir).into_iter())
        .map(|(t_s, v)| Truth {
            t_s,
            lat_deg: lat0 + (v[1] / meridian).to_degrees(),
            lon_deg: lon0 + (v[0] / (prime * lat0.to_radians().cos())).to_degrees(),
            alt_m: alt0 + v[2],
        })
        .collect()
}

/// The flight's clock at frame 0 (the video's creation time).
fn start(dir: &Path) -> time::OffsetDateTime {
    let text = json(&dir.join("scene.json"))["telemetry"]["start_utc"]
        .as_str()
        .unwrap()
        .to_string();
    time::OffsetDateTime::parse(&text, &time::format_description::well_known::Rfc3339).unwrap()
}

/// The focal length the SRT gives (25.20 mm: two decimals) as EXIF stores it (whole mm).
fn focal_35mm(dir: &Path) -> u64 {
    let f = json(&dir.join("scene.json"))["telemetry"]["focal_35mm"]
        .as_f64()
        .unwrap();
    ((f * 100.0).round() / 100.0).round() as u64
}

/// What exiftool reads from every image of `images` (numbers as numbers, tags by group), by file
/// name.
fn exif(images: &Path) -> std::collections::BTreeMap<String, Value> {
    let out = Command::new("exiftool")
        .args(["-n", "-json", "-G"])
        .arg(images)
        .output()
        .expect("run exiftool (Debian: libimage-exiftool-perl)");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let all: Vec<Value> = serde_json::from_slice(&out.stdout).unwrap();
    all.into_iter()
        .map(|v| (v["File:FileName"].as_str().unwrap().to_string(), v))
        .collect()
}

/// `YYYY:MM:DD HH:MM:SS.mmm+00:00`: exiftool's SubSecDateTimeOriginal of a UTC time.
fn exif_time(t: time::OffsetDateTime) -> String {
    format!(
        "{:04}:{:02}:{:02} {:02}:{:02}:{:02}.{:03}+00:00",
        t.year(),
        u8::from(t.month()),
        t.day(),
        t.hour(),
        t.minute(),
        t.second(),
        t.millisecond()
    )
}

fn select(video: &Path, project: &Path) {
    kf_ok(&[
        "select",
        s(video),
        "--every",
        "8",
        "-o",
        s(project),
        "--force",
    ]);
}

/// Export of `project` into `out` with `extra` flags; stderr.
fn export(project: &Path, out: &Path, extra: &[&str]) -> String {
    let mut args = vec!["export", s(project), "--out", s(out)];
    args.extend_from_slice(extra);
    let (code, err) = code_and_stderr(&kf(&args));
    assert_eq!(code, 0, "{err}");
    err
}

fn has_gps(tags: &Value) -> bool {
    tags.as_object().unwrap().keys().any(|k| k.contains(":GPS"))
}

/// Every exported JPEG carries its frame's true position (within 1e-7° of the truth and of the
/// project), its altitude above sea level, the video's creation time plus the frame's timestamp,
/// the SRT's 35 mm focal length and the source frame; the manifest lists the same positions;
/// COLMAP's hand-off reconstructs the export and its database holds the EXIF position priors and
/// the focal length COLMAP derives from FocalLengthIn35mmFilm.
#[test]
fn geotagged_export_carries_the_true_positions_and_colmap_reads_them() {
    let dir = flight();
    let truth = truth(dir);
    let t0 = start(dir);
    let tmp = tempfile::tempdir().unwrap();
    let project = tmp.path().join("p.json");
    select(&dir.join("video.mp4"), &project);
    let positions = project_positions(&project);
    assert_eq!(positions.len(), truth.len());
    let out = tmp.path().join("export");
    let err = export(&project, &out, &[]);
    assert!(!err.contains("WARN"), "{err}");
    let manifest = json(&out.join("manifest.json"));
    // On, the default, is not written (manifests of earlier versions read the same).
    assert!(manifest["settings"].get("geotag").is_none());
    let frames = manifest["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 10);
    let tags = exif(&out.join("images"));
    assert_eq!(tags.len(), frames.len());
    for f in frames {
        let i = f["index"].as_u64().unwrap() as usize;
        let name = f["file"].as_str().unwrap();
        let (t, p) = (&truth[i], positions[i].expect("a position"));
        let e = &tags[name];
        let (lat, lon) = (
            e["Composite:GPSLatitude"].as_f64().unwrap(),
            e["Composite:GPSLongitude"].as_f64().unwrap(),
        );
        for (got, want, of) in [(lat, t.lat_deg, p.0), (lon, t.lon_deg, p.1)] {
            assert!((got - want).abs() < 1e-7, "{name}: {got} vs truth {want}");
            assert!((got - of).abs() < 1e-7, "{name}: {got} vs project {of}");
        }
        let hemisphere = |x: f64, pos: &str, neg: &str| if x < 0.0 { neg } else { pos }.to_string();
        assert_eq!(e["EXIF:GPSLatitudeRef"], hemisphere(t.lat_deg, "N", "S"));
        assert_eq!(e["EXIF:GPSLongitudeRef"], hemisphere(t.lon_deg, "E", "W"));
        // Above sea level; the SRT keeps millimetres and so does EXIF (each rounds by 0.5 mm).
        assert_eq!(e["EXIF:GPSAltitudeRef"], 0);
        let alt = e["EXIF:GPSAltitude"].as_f64().unwrap();
        assert!(
            (alt - t.alt_m).abs() <= 1e-3 + 1e-9,
            "{name}: {alt} vs {}",
            t.alt_m
        );
        assert!(
            (alt - p.2).abs() <= 0.5e-3 + 1e-9,
            "{name}: {alt} vs {}",
            p.2
        );
        let taken = t0 + time::Duration::milliseconds((t.t_s * 1000.0).round() as i64);
        assert_eq!(
            e["Composite:SubSecDateTimeOriginal"].as_str(),
            Some(exif_time(taken).as_str()),
            "{name}"
        );
        assert_eq!(
            e["EXIF:FocalLengthIn35mmFormat"].as_u64(),
            Some(focal_35mm(dir))
        );
        assert_eq!(
            e["EXIF:ImageDescription"].as_str(),
            Some(format!("frame {i} of video.mp4").as_str())
        );
        // The scene's container names no camera.
        assert!(e.get("EXIF:Make").is_none() && e.get("EXIF:Model").is_none());
        // The manifest: the project's position, exactly.
        let m = &f["position"];
        assert_eq!(
            (
                m["lat_deg"].as_f64(),
                m["lon_deg"].as_f64(),
                m["abs_alt_m"].as_f64()
            ),
            (Some(p.0), Some(p.1), Some(p.2)),
            "{name}"
        );
    }

    if Command::new("colmap").arg("-h").output().is_err() {
        eprintln!("skipping COLMAP's reading of the geotags: colmap is not installed");
        return;
    }
    let (code, err) = code_and_stderr(&kf(&["colmap", s(&out), "--sparse"]));
    assert_eq!(code, 0, "{err}");
    let rec = json(&out.join("colmap").join("colmap.json"));
    let registered = rec["models"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["registered_images"].as_u64().unwrap())
        .max();
    assert_eq!(registered, Some(frames.len() as u64), "{rec}");
    colmap_read_the_tags(&out, frames, &truth);
}

/// Runs `sqlite3 -separator | DB SQL`; None when sqlite3 is not installed.
fn sqlite(db: &Path, sql: &str) -> Option<std::process::Output> {
    Command::new("sqlite3")
        .args(["-separator", "|"])
        .arg(db)
        .arg(sql)
        .output()
        .ok()
}

/// COLMAP's database of the export's workspace: one camera whose focal length COLMAP took from
/// FocalLengthIn35mmFilm (f35 / 35 × the longer side, flagged as a prior), and each image's
/// position prior from its GPS tags. COLMAP 3.8 reads the positions through FreeImage's text of
/// the tags, which keeps 0.01 arc seconds: within 0.005" (1.4e-6°) of the truth.
fn colmap_read_the_tags(out: &Path, frames: &[Value], truth: &[Truth]) {
    let db = out.join("colmap").join("database.db");
    let Some(cam) = sqlite(
        &db,
        "SELECT width, height, prior_focal_length, hex(params) FROM cameras",
    ) else {
        eprintln!("skipping the check of COLMAP's database: sqlite3 is not installed");
        return;
    };
    let text = String::from_utf8(cam.stdout).unwrap();
    let row: Vec<&str> = text.trim().split('|').collect();
    assert_eq!(row.len(), 4, "one camera: {text}");
    let (w, h): (f64, f64) = (row[0].parse().unwrap(), row[1].parse().unwrap());
    assert_eq!(row[2], "1", "focal length from EXIF: {text}");
    let hex = row[3];
    let first: Vec<u8> = (0..8)
        .map(|k| u8::from_str_radix(&hex[2 * k..2 * k + 2], 16).unwrap())
        .collect();
    let focal = f64::from_le_bytes(first.try_into().unwrap());
    let want = focal_35mm(flight()) as f64 / 35.0 * w.max(h);
    assert!((focal - want).abs() < 1e-9, "{focal} vs {want}");

    // COLMAP up to 3.8 keeps the priors in `images`, later versions in `pose_priors`.
    let old = sqlite(
        &db,
        "SELECT name, prior_tx, prior_ty, prior_tz FROM images ORDER BY name",
    )
    .unwrap();
    let rows: Vec<(String, [f64; 3])> = if old.status.success() {
        String::from_utf8(old.stdout)
            .unwrap()
            .lines()
            .map(|l| {
                let v: Vec<&str> = l.split('|').collect();
                let n = |k: usize| v[k].parse::<f64>().unwrap();
                (v[0].to_string(), [n(1), n(2), n(3)])
            })
            .collect()
    } else {
        let new = sqlite(
            &db,
            "SELECT images.name, hex(pose_priors.position) FROM images JOIN pose_priors USING (image_id) ORDER BY images.name",
        )
        .unwrap();
        assert!(
            new.status.success(),
            "{}",
            String::from_utf8_lossy(&new.stderr)
        );
        String::from_utf8(new.stdout)
            .unwrap()
            .lines()
            .map(|l| {
                let (name, hex) = l.split_once('|').unwrap();
                let n = |k: usize| {
                    let b: Vec<u8> = (0..8)
                        .map(|j| u8::from_str_radix(&hex[16 * k + 2 * j..][..2], 16).unwrap())
                        .collect();
                    f64::from_le_bytes(b.try_into().unwrap())
                };
                (name.to_string(), [n(0), n(1), n(2)])
            })
            .collect()
    };
    assert_eq!(rows.len(), frames.len());
    for f in frames {
        let name = f["file"].as_str().unwrap();
        let t = &truth[f["index"].as_u64().unwrap() as usize];
        let (_, p) = rows.iter().find(|r| r.0 == name).expect(name);
        let arcsec = 0.005 / 3600.0 + 1e-12;
        assert!((p[0] - t.lat_deg).abs() <= arcsec, "{name}: {p:?}");
        assert!((p[1] - t.lon_deg).abs() <= arcsec, "{name}: {p:?}");
        assert!((p[2] - t.alt_m).abs() <= 1e-3 + 1e-9, "{name}: {p:?}");
    }
}

/// `--no-geotag` writes no GPS tags and no positions (and `workflow save` keeps it); a PNG export
/// is not tagged, says so once, and its manifest lists the positions.
#[test]
fn no_geotag_and_png_exports_carry_no_tags() {
    let dir = flight();
    let tmp = tempfile::tempdir().unwrap();
    let project = tmp.path().join("p.json");
    select(&dir.join("video.mp4"), &project);
    let positions = project_positions(&project);

    let plain = tmp.path().join("plain");
    let err = export(&project, &plain, &["--no-geotag"]);
    assert!(!err.contains("WARN"), "{err}");
    let manifest = json(&plain.join("manifest.json"));
    assert_eq!(manifest["settings"]["geotag"], false);
    let frames = manifest["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 10);
    let tags = exif(&plain.join("images"));
    assert_eq!(tags.len(), frames.len());
    for (name, e) in &tags {
        assert!(!has_gps(e), "{name}: {e}");
        assert!(e.get("EXIF:ImageDescription").is_none(), "{name}");
    }
    assert!(frames.iter().all(|f| f.get("position").is_none()));
    let w = tmp.path().join("w.toml");
    kf_ok(&[
        "workflow",
        "save",
        s(&project),
        "--export",
        s(&plain),
        "-o",
        s(&w),
    ]);
    let text = std::fs::read_to_string(&w).unwrap();
    assert!(text.contains("geotag = false"), "{text}");
    let runs = tmp.path().join("runs");
    let video = dir.join("video.mp4");
    kf_ok(&["run", s(&w), s(&video), "--out", s(&runs)]);
    let again = runs
        .join(keyframer::batch::folder_name(&video))
        .join("plain");
    assert_eq!(
        json(&again.join("manifest.json"))["settings"]["geotag"],
        false
    );
    assert!(exif(&again.join("images")).values().all(|e| !has_gps(e)));

    let png = tmp.path().join("png");
    let err = export(&project, &png, &["--format", "png"]);
    assert_eq!(
        err.matches("PNG images are not geotagged").count(),
        1,
        "{err}"
    );
    let manifest = json(&png.join("manifest.json"));
    let frames = manifest["frames"].as_array().unwrap();
    let tags = exif(&png.join("images"));
    assert_eq!(tags.len(), frames.len());
    assert!(tags.values().all(|e| !has_gps(e)));
    for f in frames {
        let p = positions[f["index"].as_u64().unwrap() as usize].unwrap();
        assert_eq!(f["position"]["lat_deg"].as_f64(), Some(p.0));
        assert_eq!(f["position"]["lon_deg"].as_f64(), Some(p.1));
    }
}

/// A video whose container names a known DJI camera and whose SRT stops halfway: the frames after
/// its last entry have no position and are exported untagged, counted in one warning; the others
/// carry Make and Model (the camera's EXIF model code) besides their position.
#[test]
fn frames_without_position_are_untagged_and_a_known_camera_is_named() {
    let dir = flight();
    let truth = truth(dir);
    let tmp = tempfile::tempdir().unwrap();
    let clip = tmp.path().join("clip.mp4");
    ffmpeg(&[
        "-i",
        s(&dir.join("video.mp4")),
        "-c",
        "copy",
        "-metadata",
        "comment=DJI Mini 3 Pro",
        s(&clip),
    ]);
    // The first 40 entries (0 to 4 s).
    let srt = std::fs::read_to_string(dir.join("video.SRT")).unwrap();
    let entries: Vec<&str> = srt.split("\n\n").filter(|e| !e.trim().is_empty()).collect();
    assert_eq!(entries.len(), truth.len());
    let kept = 40;
    std::fs::write(
        clip.with_extension("SRT"),
        entries[..kept].join("\n\n") + "\n\n",
    )
    .unwrap();
    let project = tmp.path().join("p.json");
    select(&clip, &project);
    let positions = project_positions(&project);
    let out = tmp.path().join("export");
    let err = export(&project, &out, &[]);
    let manifest = json(&out.join("manifest.json"));
    let frames = manifest["frames"].as_array().unwrap();
    let last = truth[kept - 1].t_s;
    let unplaced = frames
        .iter()
        .filter(|f| truth[f["index"].as_u64().unwrap() as usize].t_s > last)
        .count();
    assert!(unplaced > 0 && unplaced < frames.len(), "{frames:?}");
    assert_eq!(
        err.matches(&format!(
            "{unplaced} of the {} exported images have no telemetry position",
            frames.len()
        ))
        .count(),
        1,
        "{err}"
    );
    let camera = keyframer::source::telemetry::known_camera("DJI Mini 3 Pro").unwrap();
    let tags = exif(&out.join("images"));
    for f in frames {
        let i = f["index"].as_u64().unwrap() as usize;
        let e = &tags[f["file"].as_str().unwrap()];
        if truth[i].t_s > last {
            assert!(positions[i].is_none(), "frame {i}");
            assert!(!has_gps(e) && f.get("position").is_none(), "frame {i}: {e}");
            continue;
        }
        let lat = e["Composite:GPSLatitude"].as_f64().unwrap();
        assert!((lat - truth[i].lat_deg).abs() < 1e-7, "frame {i}");
        assert_eq!(
            e["EXIF:Make"].as_str(),
            camera.name.split_once(' ').map(|n| n.0)
        );
        assert_eq!(e["EXIF:Model"].as_str(), camera.names.first().copied());
        assert!(f["position"].is_object(), "frame {i}");
    }
}

/// An image folder whose JPEGs carry their own GPS tags (one has none): copied byte for byte they
/// keep their own EXIF; re-encoded (`--scale`) they are tagged from the project's positions (no
/// capture time: an image folder has no creation time), the untagged one counted in one warning.
#[test]
fn image_folder_copies_keep_their_exif_and_re_encoded_images_are_tagged() {
    use keyframer::geotag::GeoTag;
    let tmp = tempfile::tempdir().unwrap();
    let (folder, tags) = crate::common::tagged_image_folder(tmp.path(), |i| {
        (i != 3).then(|| GeoTag {
            lat_deg: 51.5 - 1e-4 * i as f64,
            lon_deg: -0.12 - 3e-4 * i as f64,
            alt_m: Some(30.0 + 2.5 * i as f64),
            taken: None,
            focal_35mm: Some(28.0),
            make: None,
            model: None,
            source: format!("original {i}"),
        })
    });
    let truth: Vec<_> = tags;
    let project = tmp.path().join("p.json");
    kf_ok(&["select", s(&folder), "--every", "1", "-o", s(&project)]);

    let copies = tmp.path().join("copies");
    export(&project, &copies, &[]);
    let scaled = tmp.path().join("scaled");
    let err = export(&project, &scaled, &["--scale", "0.5"]);
    assert_eq!(
        err.matches("1 of the 5 exported images have no telemetry position")
            .count(),
        1,
        "{err}"
    );
    for (out, copied) in [(&copies, true), (&scaled, false)] {
        let manifest = json(&out.join("manifest.json"));
        let frames = manifest["frames"].as_array().unwrap();
        let tags = exif(&out.join("images"));
        assert_eq!(frames.len(), 5);
        for (f, want) in frames.iter().zip(&truth) {
            let name = f["file"].as_str().unwrap();
            let (i, e) = (f["index"].as_u64().unwrap(), &tags[name]);
            let Some(want) = want else {
                assert!(!has_gps(e) && f.get("position").is_none(), "{name}: {e}");
                continue;
            };
            let got = (
                e["Composite:GPSLatitude"].as_f64().unwrap(),
                e["Composite:GPSLongitude"].as_f64().unwrap(),
            );
            for (g, w) in [(got.0, want.lat_deg), (got.1, want.lon_deg)] {
                assert!((g - w).abs() < 1e-7, "{name}: {g} vs {w}");
            }
            let alt = e["EXIF:GPSAltitude"].as_f64().unwrap();
            assert!((alt - want.alt_m.unwrap()).abs() <= 0.5e-3, "{name}");
            assert!((f["position"]["lat_deg"].as_f64().unwrap() - want.lat_deg).abs() < 1e-7);
            let description = if copied {
                want.source.clone()
            } else {
                format!("frame {i} of {name}")
            };
            assert_eq!(
                e["EXIF:ImageDescription"].as_str(),
                Some(description.as_str())
            );
            assert!(e.get("EXIF:DateTimeOriginal").is_none(), "{name}");
        }
        if copied {
            for f in frames {
                let name = f["file"].as_str().unwrap();
                assert_eq!(
                    std::fs::read(out.join("images").join(name)).unwrap(),
                    std::fs::read(folder.join(name)).unwrap(),
                    "{name}: copied byte for byte"
                );
            }
        }
    }
}
