//! `--geo-area`: on a clip placed on a GPX track, the kept frames are exactly those whose
//! interpolated positions (the project's cache) lie inside the area, by a point-in-polygon test
//! written here (ray casting on longitude and latitude); holes, MultiPolygon, KML, the
//! antimeridian, the buffer; a polar area and malformed files refused naming file and place;
//! the workflow round trip, re-selection from the cache, the report's map and the review page.

use crate::common::{
    code_and_stderr, dated_clip, json, keyframes, kf, kf_loud, kf_ok, project_positions, s,
};
use crate::review::Served;
use std::path::{Path, PathBuf};

/// Metres per degree of latitude and of longitude at `lat` (WGS84 radii), as a surveyor's
/// local plane: the test's own, to measure the buffer.
fn per_deg(lat: f64) -> (f64, f64) {
    let (a, e2) = (6_378_137.0, 6.694_379_990_14e-3);
    let w = 1.0 - e2 * lat.to_radians().sin().powi(2);
    let (meridian, prime) = (a * (1.0 - e2) / w.powf(1.5), a / w.sqrt());
    let k = std::f64::consts::PI / 180.0;
    (meridian * k, prime * lat.to_radians().cos() * k)
}

/// A polygon as (lon, lat) rings, the outer first; `centre` is (lat, lon).
type Rings = Vec<Vec<(f64, f64)>>;

/// A square ring `half` metres either side of `centre` (lat, lon), closed, as (lon, lat).
fn square(centre: (f64, f64), half: f64) -> Vec<(f64, f64)> {
    let (n, e) = per_deg(centre.0);
    let (dlat, dlon) = (half / n, half / e);
    let (lat, lon) = centre;
    vec![
        (lon - dlon, lat - dlat),
        (lon + dlon, lat - dlat),
        (lon + dlon, lat + dlat),
        (lon - dlon, lat + dlat),
        (lon - dlon, lat - dlat),
    ]
}

/// Wraps a longitude into -180..180 (as a file would write it).
fn wrap(lon: f64) -> f64 {
    if lon > 180.0 {
        lon - 360.0
    } else {
        lon
    }
}

/// Ray casting on (lon, lat), even-odd over all rings (holes included); `lon` unwrapped by the
/// caller the same way as the rings.
fn inside(rings: &Rings, lon: f64, lat: f64) -> bool {
    let mut odd = false;
    for r in rings {
        for w in r.windows(2) {
            let ((x1, y1), (x2, y2)) = (w[0], w[1]);
            if (y1 > lat) != (y2 > lat) && lon < x1 + (lat - y1) / (y2 - y1) * (x2 - x1) {
                odd = !odd;
            }
        }
    }
    odd
}

/// Metres from (lon, lat) to the nearest edge of `rings`, on the plane at `lat0`.
fn to_boundary(rings: &Rings, lon: f64, lat: f64, lat0: f64) -> f64 {
    let (n, e) = per_deg(lat0);
    let p = (lon * e, lat * n);
    let mut best = f64::INFINITY;
    for r in rings {
        for w in r.windows(2) {
            let (a, b) = ((w[0].0 * e, w[0].1 * n), (w[1].0 * e, w[1].1 * n));
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            let t = (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
            best = best.min((p.0 - a.0 - t * dx).hypot(p.1 - a.1 - t * dy));
        }
    }
    best
}

fn ring_json(r: &[(f64, f64)]) -> String {
    let pts: Vec<String> = r.iter().map(|(x, y)| format!("[{x:.9},{y:.9}]")).collect();
    format!("[{}]", pts.join(","))
}

fn polygon_json(p: &Rings) -> String {
    format!(
        "[{}]",
        p.iter().map(|r| ring_json(r)).collect::<Vec<_>>().join(",")
    )
}

/// A 10 s clip at 10 fps (100 frames) with `creation_time` set, and a GPX track of its first
/// 9 s (frames 91–99 have no position): one point a second on a zig-zag `east, north` metres
/// around `centre` (lat, lon).
fn flight(dir: &Path, centre: (f64, f64)) -> (PathBuf, PathBuf) {
    std::fs::create_dir_all(dir).unwrap();
    let clip = dated_clip(dir, 10);
    let (n, e) = per_deg(centre.0);
    let point = |k: i32| {
        let t = f64::from(k);
        let (east, north) = (-110.0 + 26.0 * t, 75.0 * (1.3 * t).sin());
        let (lat, lon) = (centre.0 + north / n, wrap(centre.1 + east / e));
        format!(
            "<trkpt lat=\"{lat:.9}\" lon=\"{lon:.9}\"><ele>400</ele><time>2024-05-01T10:00:{k:02}Z</time></trkpt>\n"
        )
    };
    let gpx = dir.join("track.gpx");
    let points: String = (0..=9).map(point).collect();
    std::fs::write(
        &gpx,
        format!("<?xml version=\"1.0\"?>\n<gpx version=\"1.1\" creator=\"t\" xmlns=\"http://www.topografix.com/GPX/1/1\"><trk><trkseg>\n{points}</trkseg></trk></gpx>\n"),
    )
    .unwrap();
    (clip, gpx)
}

/// The cached positions of a project: (lat, lon) per frame.
fn positions(project: &Path) -> Vec<Option<(f64, f64)>> {
    let all = project_positions(project).into_iter();
    all.map(|p| p.map(|(lat, lon, _)| (lat, lon))).collect()
}

/// `select CLIP --telemetry GPX ARGS -o P --force`, loud: exit code and stderr.
fn select(clip: &Path, gpx: &Path, p: &Path, args: &[&str]) -> (i32, String) {
    let mut all = vec![
        "select",
        s(clip),
        "--telemetry",
        s(gpx),
        "-o",
        s(p),
        "--force",
    ];
    all.extend_from_slice(args);
    code_and_stderr(&kf_loud(&all))
}

/// The frames the test's own geometry keeps: inside any polygon (grown or shrunk by `buffer`
/// metres), longitudes unwrapped by `unwrap`; frames within `margin` metres of the buffer's
/// edge are returned apart (the test's plane and keyframer's differ by millimetres there).
fn expected(
    pos: &[Option<(f64, f64)>],
    polygons: &[Rings],
    buffer: f64,
    unwrap: fn(f64) -> f64,
) -> (Vec<usize>, Vec<usize>) {
    let (mut keep, mut close) = (Vec::new(), Vec::new());
    for (f, p) in pos.iter().enumerate() {
        let Some((lat, lon)) = *p else { continue };
        let lon = unwrap(lon);
        let mut kept = false;
        for poly in polygons {
            let ins = inside(poly, lon, lat);
            if buffer == 0.0 {
                kept |= ins;
                continue;
            }
            let d = to_boundary(poly, lon, lat, poly[0][0].1);
            if (d - buffer.abs()).abs() < 0.01 {
                close.push(f);
            }
            kept |= if buffer > 0.0 {
                ins || d <= buffer
            } else {
                ins && d >= -buffer
            };
        }
        if kept {
            keep.push(f);
        }
    }
    (keep, close)
}

/// Asserts that the keyframes are `want` except at the frames `close` to a buffer's edge.
fn assert_kept(what: &str, got: &[usize], (want, close): &(Vec<usize>, Vec<usize>)) {
    let strip =
        |v: &[usize]| -> Vec<usize> { v.iter().copied().filter(|f| !close.contains(f)).collect() };
    assert!(
        close.len() <= 1,
        "{what}: frames {close:?} too close to the edge"
    );
    assert_eq!(strip(got), strip(want), "{what}");
    assert!(want.len() >= 5 && want.len() <= 80, "{what}: {want:?}");
}

/// A 120 m square with a 40 m hole, 10 m north of `centre`.
fn holed_square(centre: (f64, f64)) -> Rings {
    let north = (centre.0 + 10.0 / per_deg(centre.0).0, centre.1);
    vec![square(north, 60.0), square(north, 20.0)]
}

/// The kept frames are those inside the polygon, hole and MultiPolygon included, GeoJSON and
/// KML alike; frames without a position are counted and dropped; the history records the file
/// and its content; buffers grow and shrink the area; re-selection reads the cache.
#[test]
fn geo_area_keeps_exactly_the_frames_inside() {
    let tmp = tempfile::tempdir().unwrap();
    let centre = (47.0, 8.0);
    let (clip, gpx) = flight(tmp.path(), centre);
    let p = tmp.path().join("p.json");
    let n = per_deg(centre.0).0;
    let holed = holed_square(centre);
    let area = tmp.path().join("area.geojson");
    std::fs::write(
        &area,
        format!(
            "{{\"type\": \"FeatureCollection\", \"features\": [{{\"type\": \"Feature\", \"properties\": {{}}, \"geometry\": {{\"type\": \"Polygon\", \"coordinates\": {}}}}}]}}\n",
            polygon_json(&holed)
        ),
    )
    .unwrap();
    let (code, err) = select(&clip, &gpx, &p, &["--geo-area", s(&area)]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("geo-area: 9 of 100 candidates have no position and are not kept"),
        "{err}"
    );
    let pos = positions(&p);
    assert_eq!(pos.iter().filter(|p| p.is_none()).count(), 9);
    let id = |x: f64| x;
    let want = expected(&pos, std::slice::from_ref(&holed), 0.0, id);
    assert_kept("polygon with a hole", &keyframes(&p), &want);
    // Some frames lie in the hole, so the hole matters.
    let in_outer = expected(&pos, &[vec![holed[0].clone()]], 0.0, id).0;
    assert!(in_outer.len() > want.0.len(), "{in_outer:?}");
    let history = &json(&p)["history"][1];
    assert_eq!(history["plugin"], "geo-area");
    let params = &history["params"];
    assert_eq!(params["file"].as_str(), Some(s(&area)));
    assert_eq!(params["vertices"].as_u64(), Some(8));
    assert_eq!(params["polygons"].as_u64(), Some(1));
    let bytes = std::fs::read(&area).unwrap();
    let fnv = format!("{:016x}", keyframer::output::fnv1a64(&bytes));
    assert_eq!(params["fnv1a64"].as_str(), Some(fnv.as_str()));

    // The same area in KML: the same keyframes.
    let kml = tmp.path().join("area.kml");
    let coords = |r: &[(f64, f64)]| -> String {
        r.iter()
            .map(|(x, y)| format!("{x:.9},{y:.9},0"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    std::fs::write(
        &kml,
        format!(
            "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<kml xmlns=\"http://www.opengis.net/kml/2.2\"><Document><Placemark><name>survey</name>\n<Polygon><outerBoundaryIs><LinearRing><coordinates>\n{}\n</coordinates></LinearRing></outerBoundaryIs>\n<innerBoundaryIs><LinearRing><coordinates>{}</coordinates></LinearRing></innerBoundaryIs></Polygon></Placemark></Document></kml>\n",
            coords(&holed[0]),
            coords(&holed[1])
        ),
    )
    .unwrap();
    let pk = tmp.path().join("kml.json");
    let (code, err) = select(&clip, &gpx, &pk, &["--geo-area", s(&kml)]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(keyframes(&pk), keyframes(&p));

    // A MultiPolygon of two squares west and east of the centre.
    let e = per_deg(centre.0).1;
    let two: Vec<Rings> = vec![
        vec![square((centre.0, centre.1 - 70.0 / e), 35.0)],
        vec![square((centre.0 + 20.0 / n, centre.1 + 60.0 / e), 30.0)],
    ];
    let multi = tmp.path().join("multi.geojson");
    let polys: Vec<String> = two.iter().map(polygon_json).collect();
    std::fs::write(
        &multi,
        format!(
            "{{\"type\": \"MultiPolygon\", \"coordinates\": [{}]}}",
            polys.join(",")
        ),
    )
    .unwrap();
    let (code, err) = select(&clip, &gpx, &p, &["--geo-area", s(&multi)]);
    assert_eq!(code, 0, "{err}");
    let want = expected(&pos, &two, 0.0, id);
    assert_kept("MultiPolygon", &keyframes(&p), &want);
    let each: Vec<usize> = two
        .iter()
        .map(|t| expected(&pos, std::slice::from_ref(t), 0.0, id).0.len())
        .collect();
    assert!(
        each.iter().all(|&c| c > 0),
        "both parts keep frames: {each:?}"
    );

    // Buffers: grown by 15 m, shrunk by 10 m (a negative value on the command line); the
    // cache is reused (nothing decoded).
    for (buffer, text) in [(15.0, "15"), (-10.0, "-10")] {
        let (code, err) = select(
            &clip,
            &gpx,
            &p,
            &["--geo-area", s(&area), "--geo-area-buffer", text],
        );
        assert_eq!(code, 0, "{err}");
        assert!(err.contains("nothing decoded"), "{err}");
        let want = expected(&pos, std::slice::from_ref(&holed), buffer, id);
        assert_kept(&format!("buffer {text} m"), &keyframes(&p), &want);
        let plain = expected(&pos, std::slice::from_ref(&holed), 0.0, id).0;
        if buffer > 0.0 {
            assert!(want.0.len() > plain.len(), "{want:?} vs {plain:?}");
        } else {
            assert!(want.0.len() < plain.len(), "{want:?} vs {plain:?}");
        }
    }
    // A changed file is noticed when the selection is made again.
    std::fs::write(&area, format!("{}\n", String::from_utf8(bytes).unwrap())).unwrap();
    let (code, err) = select(
        &clip,
        &gpx,
        &p,
        &["--geo-area", s(&area), "--geo-area-buffer", "-10"],
    );
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("changed since the last selection"), "{err}");
}

/// A polygon across the antimeridian (longitudes from 179.999 to -179.999) on a flight that
/// crosses it: handled; a ring round the north pole: refused, naming the file and the ring.
#[test]
fn geo_area_across_the_antimeridian_and_round_a_pole() {
    let tmp = tempfile::tempdir().unwrap();
    let centre = (-16.5, 180.0);
    let (clip, gpx) = flight(tmp.path(), centre);
    let p = tmp.path().join("p.json");
    let n = per_deg(centre.0).0;
    let east = |lon: f64| if lon < 0.0 { lon + 360.0 } else { lon };
    let poly: Rings = vec![square((centre.0 + 10.0 / n, 180.0), 60.0)];
    let written: Vec<(f64, f64)> = poly[0].iter().map(|&(x, y)| (wrap(x), y)).collect();
    assert!(written.iter().any(|p| p.0 < 0.0) && written.iter().any(|p| p.0 > 0.0));
    let area = tmp.path().join("dateline.geojson");
    std::fs::write(
        &area,
        format!(
            "{{\"type\": \"Polygon\", \"coordinates\": [{}]}}",
            ring_json(&written)
        ),
    )
    .unwrap();
    let (code, err) = select(&clip, &gpx, &p, &["--geo-area", s(&area)]);
    assert_eq!(code, 0, "{err}");
    let pos = positions(&p);
    // The flight's positions lie on both sides of the antimeridian, none near longitude 0.
    let lons: Vec<f64> = pos.iter().flatten().map(|p| p.1).collect();
    assert!(lons.iter().any(|&l| l < 0.0) && lons.iter().any(|&l| l > 0.0));
    assert!(lons.iter().all(|l| l.abs() > 179.9), "{lons:?}");
    let want = expected(&pos, &[poly], 0.0, east);
    assert_kept("across the antimeridian", &keyframes(&p), &want);
    let kept_lons: Vec<f64> = keyframes(&p).iter().map(|&k| pos[k].unwrap().1).collect();
    assert!(kept_lons.iter().any(|&l| l < 0.0) && kept_lons.iter().any(|&l| l > 0.0));

    let polar = tmp.path().join("polar.geojson");
    std::fs::write(
        &polar,
        "{\"type\": \"Polygon\", \"coordinates\": [[[0, 85], [90, 85], [180, 85], [-90, 85], [0, 85]]]}",
    )
    .unwrap();
    let q = tmp.path().join("q.json");
    let (code, err) = select(&clip, &gpx, &q, &["--geo-area", s(&polar)]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains(&format!("{}: not a usable area file: coordinates[0] (outer ring): the ring goes round the north pole", polar.display())),
        "{err}"
    );
    assert!(!q.exists());
}

/// Malformed files name the file and the place: line and column of broken JSON, the ring and
/// coordinate of bad geometry; before any frame is decoded.
#[test]
fn malformed_areas_name_the_file_and_the_place() {
    let tmp = tempfile::tempdir().unwrap();
    let (clip, gpx) = flight(tmp.path(), (47.0, 8.0));
    let p = tmp.path().join("p.json");
    let cases = [
        (
            "{\"type\": \"Polygon\",\n  \"coordinates\": [[[8, 47], [8.1, 47],\n  [8.1, 47.1] [8, 47]]]}",
            "line 3, column 15: not JSON",
        ),
        (
            "{\"type\": \"Polygon\", \"coordinates\": [[[8, 47], [8.1, 47], [8, 47]]]}",
            "coordinates[0] (outer ring): too few points",
        ),
        (
            "{\"type\": \"MultiPolygon\", \"coordinates\": [[[[8, 47], [8.1, 47], [8.1, 47.1], [8, 47]]], [[[8, 47], [8.1, 47], [8.1, 47.1], [8, 47]], [[8, 47], [8.01, \"x\"], [8.01, 47.01], [8, 47]]]]}",
            "coordinates[1][1] (hole), coordinate 1: [8.01,\"x\"] is not a position",
        ),
        (
            "{\"type\": \"Polygon\", \"coordinates\": [[[8, 47], [8.1, 47], [8.1, 97.5], [8, 47]]]}",
            "coordinates[0] (outer ring), coordinate 2: latitude 97.5 is outside -90..90",
        ),
        ("{\"type\": \"Point\", \"coordinates\": [8, 47]}", "no polygon in it"),
    ];
    for (i, (text, want)) in cases.iter().enumerate() {
        let area = tmp.path().join(format!("bad{i}.geojson"));
        std::fs::write(&area, text).unwrap();
        let (code, err) = select(&clip, &gpx, &p, &["--geo-area", s(&area)]);
        assert_eq!(code, 1, "{err}");
        let want = format!("{}: not a usable area file: {want}", area.display());
        assert!(err.contains(&want), "want {want} in:\n{err}");
        assert!(!p.exists());
        // Read with the flags, before the input is opened: a missing video is not reached.
        let gone = tmp.path().join("gone.mp4");
        let (code, err) = select(&gone, &gpx, &p, &["--geo-area", s(&area)]);
        assert_eq!(code, 1, "{err}");
        assert!(err.contains(&want) && !err.contains("gone.mp4"), "{err}");
    }
    let (code, err) = select(&clip, &gpx, &p, &["--geo-area-buffer", "5"]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("needs --geo-area"), "{err}");
}

/// `workflow save` writes the step with its file (absolute) and buffer, `run` repeats the
/// selection; a workflow naming the file relative to its folder works from anywhere; the
/// report's map draws the area's outline and hole; the review page offers the step and applies
/// it on the cache as `select` does.
#[test]
fn geo_area_workflow_report_and_review() {
    let tmp = tempfile::tempdir().unwrap();
    let centre = (47.0, 8.0);
    let (clip, gpx) = flight(tmp.path(), centre);
    let holed = holed_square(centre);
    let area = tmp.path().join("area.geojson");
    std::fs::write(
        &area,
        format!(
            "{{\"type\": \"Polygon\", \"coordinates\": {}}}",
            polygon_json(&holed)
        ),
    )
    .unwrap();
    let p = tmp.path().join("p.json");
    let (code, err) = select(
        &clip,
        &gpx,
        &p,
        &[
            "--geo-area",
            s(&area),
            "--geo-area-buffer",
            "-5",
            "--every",
            "2",
        ],
    );
    assert_eq!(code, 0, "{err}");
    let keys = keyframes(&p);
    assert!(keys.len() >= 3, "{keys:?}");
    let w = tmp.path().join("w.toml");
    kf_ok(&["workflow", "save", s(&p), "-o", s(&w)]);
    let text = std::fs::read_to_string(&w).unwrap();
    assert!(text.contains("plugin = \"geo-area\""), "{text}");
    assert!(text.contains("buffer_m = -5.0"), "{text}");
    let runs = tmp.path().join("runs");
    kf_ok(&["run", s(&w), s(&clip), "--out", s(&runs)]);
    let ran = runs
        .join(keyframer::batch::folder_name(&clip))
        .join("project.json");
    assert_eq!(keyframes(&ran), keys);
    // The file relative to the workflow's folder (the tests run elsewhere).
    let rel = tmp.path().join("rel.toml");
    let abs = format!(
        "file = {:?}",
        keyframer::fsutil::absolute(&area).display().to_string()
    );
    assert!(text.contains(&abs), "{text}");
    std::fs::write(&rel, text.replace(&abs, "file = \"area.geojson\"")).unwrap();
    let runs = tmp.path().join("runs-rel");
    kf_ok(&["run", s(&rel), s(&clip), "--out", s(&runs)]);
    let ran = runs
        .join(keyframer::batch::folder_name(&clip))
        .join("project.json");
    assert_eq!(keyframes(&ran), keys);
    // A changed area file redoes the finished input: the hole filled, more frames kept.
    let filled = format!(
        "{{\"type\": \"Polygon\", \"coordinates\": {}}}",
        polygon_json(&vec![holed[0].clone()])
    );
    std::fs::write(&area, filled).unwrap();
    kf_ok(&["run", s(&rel), s(&clip), "--out", s(&runs)]);
    let more = keyframes(&ran);
    assert!(more.len() > keys.len(), "{more:?} vs {keys:?}");
    std::fs::write(
        &area,
        format!(
            "{{\"type\": \"Polygon\", \"coordinates\": {}}}",
            polygon_json(&holed)
        ),
    )
    .unwrap();
    // A workflow naming a broken area is refused at its key.
    let bad = tmp.path().join("bad.geojson");
    std::fs::write(&bad, "{\"type\": \"Polygon\"}").unwrap();
    std::fs::write(&rel, text.replace(&abs, "file = \"bad.geojson\"")).unwrap();
    let (code, err) = code_and_stderr(&kf(&["run", s(&rel), s(&clip), "--out", s(&runs)]));
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("sample[0].file") && err.contains("bad.geojson"),
        "{err}"
    );

    // The report's flight map: one path, the outline and the hole, even-odd filled.
    let html = tmp.path().join("report.html");
    kf_ok(&["report", s(&p), "-o", s(&html), "--force", "--thumbs", "0"]);
    let page = std::fs::read_to_string(&html).unwrap();
    let map = page
        .split("<svg id=\"flight-map\"")
        .nth(1)
        .expect("a flight map");
    let outline = map
        .split("<path id=\"geo-area\" d=\"")
        .nth(1)
        .expect("the area");
    let d = outline.split('"').next().unwrap();
    assert_eq!(d.matches('M').count(), 2, "{d}");
    assert_eq!(d.matches('Z').count(), 2, "{d}");
    assert_eq!(d.matches(" L").count(), 6, "{d}");
    assert!(outline.contains("fill-rule=\"evenodd\""));

    // The review page lists the step with its required file and applies it on the cache.
    let mut srv = Served::start(&p, &[]);
    let (code, state) = srv.call("GET", "/api/state", None);
    assert_eq!(code, 200, "{state}");
    let chain = state["chain"].as_array().unwrap();
    let step = chain
        .iter()
        .find(|k| k["id"] == "geo-area")
        .expect("geo-area in the chain");
    assert_eq!(step["required"], "file");
    assert!(state["schema"]
        .as_array()
        .unwrap()
        .iter()
        .any(|f| f["plugin"] == "geo-area" && f["key"] == "buffer_m"));
    let abs_area = keyframer::fsutil::absolute(&area);
    let body = serde_json::json!({"steps": [{"geo-area": {"file": abs_area, "buffer_m": 15}}]});
    let (code, v) = srv.call("POST", "/api/apply", Some(&body));
    assert_eq!(code, 200, "{v}");
    assert_eq!(v["steps_state"][0]["enabled"], true, "{}", v["steps_state"]);
    let got: Vec<usize> = (v["keyframes"].as_array().unwrap().iter())
        .map(|k| k.as_u64().unwrap() as usize)
        .collect();
    let (code, err) = select(
        &clip,
        &gpx,
        &p,
        &["--geo-area", s(&area), "--geo-area-buffer", "15"],
    );
    assert_eq!(code, 0, "{err}");
    assert_eq!(got, keyframes(&p));
    srv.stop();
    // Without positions in the cache the step is offered disabled, saying why, with no
    // `select` command (select reads the same telemetry).
    let pan = crate::review::pan_copy(&tmp.path().join("pan"));
    let srv = Served::start(&pan, &[]);
    let (code, v) = srv.call("POST", "/api/apply", Some(&body));
    assert_eq!(code, 200, "{v}");
    let state = &v["steps_state"][0];
    assert_eq!(state["enabled"], false, "{state}");
    assert!(
        state["reason"].as_str().unwrap().contains("--telemetry"),
        "{state}"
    );
    assert!(state["command"].is_null(), "{state}");
}
