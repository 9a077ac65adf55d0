//! `keyframer report`: a real project from a small panning clip, the self-contained page, the
//! page in headless Chromium (no script error, keyframe bars where the project puts them), the PNG
//! timeline, the camera path section, missing cache data, refusals and errors; the page driven
//! over the DevTools protocol (the keyframe marks, the hover tip, a screenshot).

use crate::browser::{Browser, CHROMIUM, VIEWPORT};
use crate::common::{code_and_stderr, json, kf, kf_ok, s, unbase64};
use keyframer::report::timeline::{frame_x, GAP, KEYFRAME_RGB, LEFT, PANEL_H, RIGHT, TOP, WIDTH};
use keyframer::report::{write_report, CameraPath, PathPoint, ReportSettings};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// A project made once per test run: a 4 s, 30 fps pan (60 px/s) over a photo of the public test
/// data (320x240), selected with
/// spacing and blur so the cache holds timestamps, sharpness and movement; two adjacent frames
/// added by hand.
fn fixture() -> &'static (PathBuf, PathBuf) {
    static FIXTURE: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("report-fixture");
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let project = crate::common::pan_project(&dir);
        (dir, project)
    })
}

fn project_keyframes(project: &Path) -> (Vec<usize>, usize) {
    let p = json(project);
    let keys = p["keyframes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap() as usize)
        .collect();
    (
        keys,
        p["metadata"]["frame_count"].as_u64().unwrap() as usize,
    )
}

/// Distinct pixel columns of the keyframe bars, computed from the layout constants: frame 0 at
/// LEFT, the last frame at WIDTH - RIGHT - 1, linear in between, rounded.
fn expected_columns(keys: &[usize], n: usize) -> Vec<i64> {
    let span = f64::from(WIDTH - LEFT - RIGHT - 1);
    let mut xs: Vec<i64> = keys
        .iter()
        .map(|&k| (f64::from(LEFT) + k as f64 * span / (n - 1) as f64).round() as i64)
        .collect();
    xs.dedup();
    xs
}

/// Columns (in `x0..x1`) where at least 90 % of the rows `y0..y1` have the keyframe colour
/// (within `tol` per channel).
fn bar_columns(img: &image::RgbImage, x0: u32, x1: u32, y0: u32, y1: u32, tol: i32) -> Vec<i64> {
    (x0..x1.min(img.width()))
        .filter(|&x| {
            let hits = (y0..y1)
                .filter(|&y| {
                    let p = img.get_pixel(x, y).0;
                    (0..3).all(|c| (i32::from(p[c]) - i32::from(KEYFRAME_RGB[c])).abs() <= tol)
                })
                .count();
            hits * 10 >= (y1 - y0) as usize * 9
        })
        .map(i64::from)
        .collect()
}

fn report(project: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec!["report", s(project), "-o", s(out)];
    args.extend_from_slice(extra);
    kf(&args)
}

#[test]
fn report_page_is_self_contained_and_png_timeline_has_the_keyframe_bars() {
    let (dir, project) = fixture();
    let (keys, n) = project_keyframes(project);
    assert!(
        keys.len() >= 5,
        "the pan should give several keyframes: {keys:?}"
    );
    let out = dir.join("self-contained.html");
    let t = Instant::now();
    let r = report(project, &out, &["--thumbs", "4", "--force"]);
    let (code, err) = code_and_stderr(&r);
    assert_eq!(code, 0, "{err}");
    eprintln!("report written in {:?}", t.elapsed());
    let html = std::fs::read_to_string(&out).unwrap();

    // Self-contained: nothing fetched from anywhere.
    for bad in [
        "http://",
        "https://",
        "src=\"/",
        "<link",
        "<script src",
        "url(",
    ] {
        assert!(!html.contains(bad), "page contains {bad:?}");
    }
    assert!(html.starts_with("<!DOCTYPE html>") && html.trim_end().ends_with("</html>"));
    assert_eq!(html.matches("<svg").count(), html.matches("</svg>").count());
    assert_eq!(
        html.matches("<script").count(),
        html.matches("</script>").count()
    );
    // Thumbnails: 4 of the keyframes, as JPEG data URIs that decode.
    let uris: Vec<&str> = html
        .split("src=\"data:image/jpeg;base64,")
        .skip(1)
        .map(|rest| &rest[..rest.find('"').unwrap()])
        .collect();
    assert_eq!(uris.len(), 4);
    for u in &uris {
        let jpeg = image::load_from_memory(&unbase64(u)).expect("thumbnail decodes");
        assert_eq!(jpeg.width(), 160, "thumbnails are 160 px wide");
    }
    assert_eq!(html.matches("class=\"kf\"").count(), keys.len());
    for step in json(project)["history"].as_array().unwrap() {
        let id = step["plugin"].as_str().unwrap();
        assert!(
            html.contains(&format!("<td>{id}</td>")),
            "step {id} missing"
        );
    }
    assert!(html.contains("blur threshold: 0.8 x mean of ±10 frames"));
    assert!(html.contains("spacing threshold 25.0 px"));
    assert!(html.contains("id=\"camera-none\""));
    // No telemetry: no distance panel.
    assert!(!html.contains("Distance moved since the previous keyframe"));
    assert!(
        !html.contains("id=\"missing\""),
        "nothing should be missing"
    );

    // Thumbnails from an export folder: the exported images of the picked keyframes.
    let images = dir.join("exported");
    kf_ok(&["export", s(project), "--out", s(&images), "--force"]);
    let via_export = dir.join("via-export.html");
    let r = report(
        project,
        &via_export,
        &["--export", s(&images), "--thumbs", "3", "--force"],
    );
    assert_eq!(code_and_stderr(&r).0, 0, "{}", code_and_stderr(&r).1);
    let page = std::fs::read_to_string(&via_export).unwrap();
    assert_eq!(page.matches("src=\"data:image/jpeg;base64,").count(), 3);
    let last = keys.last().unwrap();
    assert!(
        page.contains(&format!("alt=\"frame {last}\"")),
        "last keyframe shown"
    );

    // The PNG timeline beside the page: three panels, bars at the keyframe columns.
    let png = dir.join("self-contained.timeline.png");
    let img = image::open(&png).unwrap().to_rgb8();
    let height = TOP + 3 * PANEL_H + 2 * GAP + 40;
    assert_eq!((img.width(), img.height()), (WIDTH, height));
    let want = expected_columns(&keys, n);
    for panel in 0..3 {
        let top = TOP + panel * (PANEL_H + GAP);
        let got = bar_columns(&img, 0, WIDTH, top, top + PANEL_H, 0);
        assert_eq!(got, want, "panel {panel}: bar columns");
    }
    // The library's mapping agrees with the one computed here.
    assert_eq!(
        keys.iter()
            .map(|&k| i64::from(frame_x(k, n)))
            .collect::<Vec<_>>(),
        keys.iter()
            .map(|&k| expected_columns(&[k], n)[0])
            .collect::<Vec<_>>()
    );
}

/// Runs headless Chromium on `page` with `args`; returns stdout.
fn chromium(page: &Path, args: &[&str]) -> String {
    let profile = tempfile::tempdir().unwrap();
    let out = Command::new(CHROMIUM)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            "--force-device-scale-factor=1",
            "--force-color-profile=srgb",
            "--window-size=1300,1000",
        ])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .args(args)
        .arg(format!("file://{}", page.display()))
        .output()
        .expect("run chromium");
    assert!(
        out.status.success(),
        "chromium failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn attr<'a>(dom: &'a str, name: &str) -> Option<&'a str> {
    let start = dom.find(&format!("{name}=\""))? + name.len() + 2;
    Some(&dom[start..start + dom[start..].find('"')?])
}

fn helix(keys: &[usize]) -> CameraPath {
    CameraPath {
        points: keys
            .iter()
            .map(|&k| {
                let a = k as f64 * 0.05;
                PathPoint {
                    frame: k,
                    centre: [3.0 * a.cos(), 3.0 * a.sin(), 0.2 * a],
                }
            })
            .collect(),
        north_up: false,
    }
}

#[test]
fn report_renders_in_headless_chromium_with_bars_at_the_keyframes() {
    if !Path::new(CHROMIUM).exists() {
        println!("SKIPPED: {CHROMIUM} is absent (install the Debian package chromium)");
        return;
    }
    let (dir, project) = fixture();
    let (keys, n) = project_keyframes(project);
    let page = dir.join("chromium.html");
    let settings = ReportSettings {
        output: page.clone(),
        timeline: None,
        export: None,
        model: None,
        thumbs: 6,
        force: true,
    };
    // The camera-path section too, from a path made here (the COLMAP reader comes later).
    let path = helix(&keys);
    let summary = write_report(project, &settings, Some(&path)).unwrap();
    assert_eq!(summary.keyframes, keys.len());
    assert_eq!(summary.thumbs, 6);
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(html.contains(&format!("data-cameras=\"{}\"", keys.len())));
    assert_eq!(html.matches("class=\"seg\"").count(), keys.len() - 1);
    let stats = path.stats().unwrap();
    assert!(html.contains(&format!("mean {:.4}", stats.mean_spacing)));

    let t = Instant::now();
    let dom = chromium(&page, &["--dump-dom"]);
    eprintln!("chromium --dump-dom: {:?}", t.elapsed());
    // The handler's own source names the marker; only the attribute and element mean an error.
    assert!(
        !dom.contains("data-script-error=\"") && !dom.contains("<pre id=\"script-error\">"),
        "script error in the page: {}",
        attr(&dom, "data-script-error").unwrap_or("")
    );
    assert_eq!(
        attr(&dom, "data-rendered"),
        Some(format!("{} keyframes", keys.len()).as_str()),
        "the page's script did not finish"
    );
    let left: f64 = attr(&dom, "data-timeline-left").unwrap().parse().unwrap();
    let top: f64 = attr(&dom, "data-timeline-top").unwrap().parse().unwrap();

    let shot = dir.join("chromium.png");
    let t = Instant::now();
    chromium(&page, &[&format!("--screenshot={}", shot.display())]);
    eprintln!("chromium --screenshot: {:?}", t.elapsed());
    let img = image::open(&shot).unwrap().to_rgb8();
    assert_eq!((img.width(), img.height()), (1300, 1000));
    // Not blank.
    let var = luminance_variance(&img);
    assert!(var > 100.0, "screenshot looks blank (variance {var:.1})");
    // Keyframe bars in the first panel at the expected columns, offset by the SVG's position.
    let (x0, y0) = (left.round() as i64, top.round() as i64);
    let panel = (y0 + i64::from(TOP)) as u32;
    assert!(panel + PANEL_H < 1000, "timeline below the fold at y {y0}");
    let got: Vec<i64> = bar_columns(&img, 0, 1300, panel + 2, panel + PANEL_H - 2, 12)
        .into_iter()
        .map(|x| x - x0)
        .collect();
    assert_eq!(
        got,
        expected_columns(&keys, n),
        "bar columns in the screenshot"
    );

    // The error marker works: the same page with a throwing script reports it.
    let broken = dir.join("chromium-broken.html");
    std::fs::write(
        &broken,
        html.replace(
            "</body>",
            "<script>undefinedFunctionOfTheTest();</script></body>",
        ),
    )
    .unwrap();
    let dom = chromium(&broken, &["--dump-dom"]);
    assert!(
        attr(&dom, "data-script-error").is_some_and(|m| m.contains("undefinedFunctionOfTheTest")),
        "onerror marker missing"
    );
    assert!(dom.contains("<pre id=\"script-error\">"));
}

/// Luminance variance of an RGB image (0 for a blank one).
pub(crate) fn luminance_variance(img: &image::RgbImage) -> f64 {
    let lum: Vec<f64> = img
        .pixels()
        .map(|p| (u32::from(p[0]) + u32::from(p[1]) + u32::from(p[2])) as f64 / 3.0)
        .collect();
    let mean = lum.iter().sum::<f64>() / lum.len() as f64;
    lum.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / lum.len() as f64
}

#[test]
fn report_driven_over_devtools_marks_keyframes_and_shows_the_hovered_frame() {
    let Some(browser) = Browser::launch() else {
        return;
    };
    let (dir, project) = fixture();
    let (keys, n) = project_keyframes(project);
    let page = dir.join("devtools.html");
    let settings = ReportSettings {
        output: page.clone(),
        timeline: None,
        export: None,
        model: None,
        thumbs: 0,
        force: true,
    };
    write_report(project, &settings, None).unwrap();
    let t = Instant::now();
    let tab = browser.open(&format!("file://{}", page.display()));
    tab.wait_for("document.body.dataset.rendered", Duration::from_secs(10))
        .unwrap();
    eprintln!("page open and rendered in {:?}", t.elapsed());

    // The keyframe marks of the timeline are the project's keyframes, in order.
    let marks = tab
        .eval("[...document.querySelectorAll('#timeline g.kf')].map(g => Number(g.dataset.frame))");
    let marks: Vec<usize> = serde_json::from_value(marks).unwrap();
    assert_eq!(marks, keys);
    assert_eq!(
        tab.eval("document.body.dataset.rendered"),
        serde_json::json!(format!("{} keyframes", keys.len()))
    );

    // Hovering frame k of the timeline shows its tip and moves the cursor line there.
    tab.eval("document.getElementById('timeline').scrollIntoView()");
    let rect = tab.eval(
        "(r => [r.left, r.top])(document.getElementById('timeline').getBoundingClientRect())",
    );
    let (left, top) = (rect[0].as_f64().unwrap(), rect[1].as_f64().unwrap());
    let row = top + f64::from(TOP + PANEL_H / 2);
    assert!(
        row < f64::from(VIEWPORT.1),
        "timeline below the fold at {top}"
    );
    let key = keys[keys.len() / 2];
    let plain = (key + 1..n).find(|f| !keys.contains(f)).unwrap();
    for (frame, label) in [
        (key, format!("frame {key}  (keyframe)")),
        (plain, format!("frame {plain}")),
    ] {
        tab.hover(left + f64::from(frame_x(frame, n)), row);
        tab.wait_for(
            "getComputedStyle(document.getElementById('tip')).display === 'block'",
            Duration::from_secs(5),
        )
        .unwrap();
        let tip = tab.eval("document.getElementById('tip').textContent");
        assert_eq!(tip.as_str().unwrap().lines().next(), Some(label.as_str()));
        let cursor = tab.eval("[document.getElementById('cursor').getAttribute('x1'), document.getElementById('cursor').getAttribute('visibility')]");
        let x: f64 = cursor[0].as_str().unwrap().parse().unwrap();
        assert_eq!(
            x.round() as i32,
            frame_x(frame, n),
            "cursor of frame {frame}"
        );
        assert_eq!(cursor[1], "visible");
    }
    // Leaving the timeline hides the tip and the cursor.
    tab.hover(2.0, 2.0);
    tab.wait_for(
        "getComputedStyle(document.getElementById('tip')).display === 'none'",
        Duration::from_secs(5),
    )
    .unwrap();
    assert_eq!(
        tab.eval("document.getElementById('cursor').getAttribute('visibility')"),
        "hidden"
    );
    assert_eq!(tab.errors(), Vec::<String>::new());

    // The screenshot is not blank and shows the bars at the keyframe columns.
    let t = Instant::now();
    let png = tab.screenshot_png();
    eprintln!("screenshot over DevTools in {:?}", t.elapsed());
    let img = image::load_from_memory(&png).unwrap().to_rgb8();
    assert_eq!((img.width(), img.height()), VIEWPORT);
    let var = luminance_variance(&img);
    assert!(var > 100.0, "screenshot looks blank (variance {var:.1})");
    let panel = (top.round() as i64 + i64::from(TOP)) as u32;
    let got: Vec<i64> = bar_columns(&img, 0, VIEWPORT.0, panel + 2, panel + PANEL_H - 2, 12)
        .into_iter()
        .map(|x| x - left.round() as i64)
        .collect();
    assert_eq!(
        got,
        expected_columns(&keys, n),
        "bar columns in the screenshot"
    );
}

#[test]
fn report_without_cached_scores_still_renders_and_says_what_is_missing() {
    let (dir, project) = fixture();
    let mut p = json(project);
    p["cache"]["sharpness"] = serde_json::json!([]);
    p["cache"]["movement"] = serde_json::json!([]);
    let bare = dir.join("bare.json");
    std::fs::write(&bare, serde_json::to_string(&p).unwrap()).unwrap();
    let out = dir.join("bare.html");
    let r = report(&bare, &out, &["--thumbs", "0", "--force"]);
    let (code, err) = code_and_stderr(&r);
    assert_eq!(code, 0, "{err}");
    let html = std::fs::read_to_string(&out).unwrap();
    assert!(html.contains("id=\"missing\""));
    assert!(html.contains("sharpness scores"));
    assert!(html.contains("camera movement"));
    let keys = p["keyframes"].as_array().unwrap().len();
    assert_eq!(html.matches("class=\"kf\"").count(), keys);
    // One panel left: the PNG is one panel high and still shows the bars.
    let img = image::open(dir.join("bare.timeline.png"))
        .unwrap()
        .to_rgb8();
    assert_eq!(img.height(), TOP + PANEL_H + 40);
    let (k, n) = project_keyframes(&bare);
    assert_eq!(
        bar_columns(&img, 0, WIDTH, TOP, TOP + PANEL_H, 0),
        expected_columns(&k, n)
    );
}

#[test]
fn report_refuses_to_overwrite_and_names_bad_project_files() {
    let (dir, project) = fixture();
    let out = dir.join("refuse.html");
    let png = dir.join("refuse-timeline.png");
    let first = ["--thumbs", "0", "--timeline", s(&png), "--force"];
    assert_eq!(report(project, &out, &first).status.code(), Some(0));
    let before = std::fs::read(&out).unwrap();
    // Existing page, or existing PNG, without --force: refused, nothing changed.
    std::fs::write(&out, b"earlier results").unwrap();
    let (code, err) = code_and_stderr(&report(project, &out, &["--timeline", s(&png)]));
    assert_eq!(code, 1);
    assert!(
        err.contains("refuse.html") && err.contains("--force"),
        "{err}"
    );
    assert_eq!(std::fs::read(&out).unwrap(), b"earlier results");
    std::fs::remove_file(&out).unwrap();
    let (code, err) = code_and_stderr(&report(project, &out, &["--timeline", s(&png)]));
    assert_eq!(code, 1);
    assert!(err.contains("refuse-timeline.png"), "{err}");
    assert!(!out.exists(), "nothing may be written when refused");
    let r = report(project, &out, &first);
    assert_eq!(r.status.code(), Some(0));
    assert_eq!(std::fs::read(&out).unwrap().len(), before.len());

    // A broken and a missing project file are named.
    let broken = dir.join("broken.json");
    std::fs::write(&broken, "{ \"schema_version\": 1, \"keyframes\": [").unwrap();
    let (code, err) = code_and_stderr(&report(&broken, &dir.join("b.html"), &[]));
    assert_eq!(code, 1);
    assert!(err.contains("broken.json"), "{err}");
    assert!(!dir.join("b.html").exists());
    let (code, err) = code_and_stderr(&report(&dir.join("absent.json"), &dir.join("b.html"), &[]));
    assert_eq!(code, 1);
    assert!(err.contains("absent.json"), "{err}");

    // An export folder without a manifest is an error naming it.
    let (code, err) = code_and_stderr(&report(
        project,
        &dir.join("e.html"),
        &["--export", s(&dir.join("no-export"))],
    ));
    assert_eq!(code, 1);
    assert!(err.contains("no-export"), "{err}");
    assert!(!dir.join("e.html").exists());

    // An unwritable output is named.
    let nowhere = dir.join("no-such-folder").join("r.html");
    let (code, err) = code_and_stderr(&report(project, &nowhere, &["--thumbs", "0"]));
    assert_eq!(code, 1);
    assert!(err.contains("no-such-folder"), "{err}");
}
