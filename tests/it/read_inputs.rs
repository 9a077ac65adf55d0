//! Every file or folder a command reads is an input the output may not be, lie in or contain
//! (issue 29): the telemetry beside the video or given with `--telemetry`, a COLMAP model, a
//! workflow, a model description and the files it names, an initial flow. Each refusal names the
//! input and what it is, and what was read is byte-for-byte unchanged.

use crate::common::*;
use std::path::Path;

/// Runs `args`; asserts exit 1, a message holding `named` (`is the input PATH (WHAT)`) and `kept`
/// byte-for-byte unchanged.
fn refused(args: &[&str], named: &str, kept: &Path) {
    let before = std::fs::read(kept).unwrap();
    let (code, err) = code_and_stderr(&kf(args));
    assert_eq!(code, 1, "{args:?}: {err}");
    assert!(err.contains(named), "{args:?}: wanted `{named}` in: {err}");
    assert_eq!(std::fs::read(kept).unwrap(), before, "{}", kept.display());
}

/// `HOW PATH (WHAT)`, as a refusal names an input.
fn named(how: &str, input: &Path, what: &str) -> String {
    format!("{how} {} ({what})", input.display())
}

/// A DJI SRT of `seconds` one-second entries.
fn srt(path: &Path, seconds: usize) {
    let text: String = (0..seconds)
        .map(|i| {
            format!(
                "{}\n00:00:{i:02},000 --> 00:00:{:02},000\n[latitude: 47.{i:04}] [longitude: 8.0] [rel_alt: 30.0 abs_alt: 430.0]\n\n",
                i + 1,
                i + 1
            )
        })
        .collect();
    std::fs::write(path, text).unwrap();
}

/// A GPX track of four points a second apart from 2024-05-01T10:00:00Z.
fn gpx(path: &Path) {
    let points: String = (0..4)
        .map(|k| format!("<trkpt lat=\"47.{k}\" lon=\"8.0\"><ele>400</ele><time>2024-05-01T10:00:0{k}Z</time></trkpt>\n"))
        .collect();
    let text = format!("<?xml version=\"1.0\"?>\n<gpx version=\"1.1\" creator=\"t\" xmlns=\"http://www.topografix.com/GPX/1/1\"><trk><trkseg>\n{points}</trkseg></trk></gpx>\n");
    std::fs::write(path, text).unwrap();
}

#[test]
fn telemetry_is_an_input() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // The sidecar select finds beside the video.
    let clip = testsrc(dir, "v.mp4", 64, 48, "10", 2.0);
    let sidecar = dir.join("v.SRT");
    srt(&sidecar, 3);
    let sel = ["select", s(&clip), "--every", "5", "--backend", "opencv"];
    let what = "telemetry found beside the video";
    let to_sidecar = [&sel[..], &["-o", s(&sidecar), "--force"]].concat();
    refused(
        &to_sidecar,
        &named("is the input", &sidecar, what),
        &sidecar,
    );
    // A GPX track given with --telemetry (the clip has the creation time a track needs).
    let timed = dir.join("timed.mp4");
    let time = "creation_time=2024-05-01T10:00:00Z";
    ffmpeg(&["-i", s(&clip), "-metadata", time, "-c", "copy", s(&timed)]);
    let track = dir.join("track.gpx");
    gpx(&track);
    let tel = [
        "select",
        s(&timed),
        "--telemetry",
        s(&track),
        "--every",
        "5",
    ];
    let to_track = [
        &tel[..],
        &["--backend", "opencv", "-o", s(&track), "--force"],
    ]
    .concat();
    refused(
        &to_track,
        &named("is the input", &track, "telemetry"),
        &track,
    );
    // Both are read when the output goes elsewhere (the refusals are not of unusable files).
    let p = dir.join("p.json");
    kf_ok(&[&sel[..], &["-o", s(&p)]].concat());
    assert_eq!(json(&p)["cache"]["telemetry"]["source"]["kind"], "dji-srt");
    kf_ok(&[&tel[..], &["--backend", "opencv", "-o", s(&p), "--force"]].concat());
    assert_eq!(json(&p)["cache"]["telemetry"]["source"]["kind"], "gpx");
    // The workflow `workflow save` writes names the project's track: an input of the save.
    let save = ["workflow", "save", s(&p), "-o", s(&track), "--force"];
    refused(&save, &named("is the input", &track, "telemetry"), &track);
}

/// A text COLMAP model of three of the exported frames, in `dir`.
fn text_model(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(
        dir.join("cameras.txt"),
        "1 SIMPLE_RADIAL 320 240 380 160 120 0\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("images.txt"),
        "1 1 0 0 0 0 0 0 1 frame_000000.jpg\n\n2 1 0 0 0 -1 0 0 1 frame_000005.jpg\n\n3 1 0 0 0 -2 0 0 1 frame_000010.jpg\n\n",
    )
    .unwrap();
    std::fs::write(dir.join("points3D.txt"), "# no points\n").unwrap();
}

#[test]
fn a_colmap_model_is_an_input_of_report() {
    let d = tempfile::tempdir().unwrap();
    let (_, project) = clip_and_project(d.path());
    let export = d.path().join("E");
    kf_ok(&["export", s(&project), "--out", s(&export)]);
    let model = d.path().join("ws/sparse/0");
    text_model(&model);
    let with = ["--model", s(&model), "--export", s(&export), "--force"];
    // The model is read (the camera path drawn) when the page goes elsewhere.
    let html = d.path().join("r.html");
    kf_ok(&[&["report", s(&project), "-o", s(&html)], &with[..]].concat());
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(page.contains("data-cameras=\"3\""));
    let images = model.join("images.txt");
    let args = [&["report", s(&project), "-o", s(&images)], &with[..]].concat();
    let how = named("lies inside the input", &model, "COLMAP model");
    refused(&args, &how, &images);
    let manifest = export.join("manifest.json");
    let args = [&["report", s(&project), "-o", s(&manifest)], &with[..]].concat();
    let how = named("is the input", &manifest, "export manifest");
    refused(&args, &how, &manifest);
}

#[test]
fn a_workflow_is_an_input_of_run() {
    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "v.mp4", 64, 48, "10", 1.0);
    let job = d.path().join("job");
    std::fs::create_dir(&job).unwrap();
    let w = job.join("w.toml");
    let text = "version = 1\n\n[analysis]\nbackend = \"opencv\"\n\n[[sample]]\nplugin = \"every-nth\"\nn = 5\n";
    std::fs::write(&w, text).unwrap();
    let run = ["run", s(&w), s(&clip), "--out", s(&job)];
    refused(&run, &named("contains the input", &w, "workflow"), &w);
    assert_eq!(listing(&job), ["w.toml"], "nothing written");
    // The list of inputs too.
    let list = job.join("inputs.txt");
    std::fs::write(&list, format!("{}\n", clip.display())).unwrap();
    let w2 = d.path().join("w2.toml");
    std::fs::copy(&w, &w2).unwrap();
    let run = ["run", s(&w2), "--inputs-from", s(&list), "--out", s(&job)];
    refused(
        &run,
        &named("contains the input", &list, "list of inputs"),
        &list,
    );
    kf_ok(&["run", s(&w2), s(&clip), "--out", s(&d.path().join("runs"))]);
}

#[test]
fn a_model_description_and_the_files_it_names_are_inputs() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // The tiny ONNX model of the segment tests, its classes read from a file.
    let desc = crate::onnx_model::tiny_model(dir, "tiny", false, Some(1), "");
    let classes = dir.join("classes.txt");
    std::fs::write(&classes, "red\ngreen\nblue\n").unwrap();
    let text = std::fs::read_to_string(&desc).unwrap();
    let text = text.replace(
        r#"classes = ["red", "green", "blue"]"#,
        "classes_file = \"classes.txt\"",
    );
    std::fs::write(&desc, text).unwrap();
    let img = dir.join("palette.png");
    crate::segment::palette_image(12, 8).save(&img).unwrap();
    let seg = [
        "segment",
        s(&img),
        "--model",
        s(&desc),
        "--classes",
        "green",
    ];
    let mask = dir.join("mask.png");
    kf_ok(&[&seg[..], &["-o", s(&mask)]].concat());
    let args = [&seg[..], &["-o", s(&classes), "--force"]].concat();
    refused(
        &args,
        &named("is the input", &classes, "class names"),
        &classes,
    );
    // An export's mask model is read by `workflow save` (which checks the workflow it writes):
    // its description and network are inputs of the save.
    let (_, project) = clip_and_project(dir);
    let export = dir.join("E");
    kf_ok(&["export", s(&project), "--out", s(&export)]);
    let manifest = export.join("manifest.json");
    let mut m = json(&manifest);
    m["settings"]["masks"] = serde_json::json!({
        "model": desc, "classes": ["green"], "dilate": 0, "backend": "opencv", "overlay": false
    });
    std::fs::write(&manifest, m.to_string()).unwrap();
    let network = dir.join("tiny.onnx");
    for (out, what) in [(&desc, "model description"), (&network, "network")] {
        let save = ["workflow", "save", s(&project), "--export", s(&export)];
        let args = [&save[..], &["-o", s(out), "--force"]].concat();
        refused(&args, &named("is the input", out, what), out);
    }
}

#[test]
fn an_initial_flow_is_an_input() {
    let d = tempfile::tempdir().unwrap();
    let (a, b) = (d.path().join("a.png"), d.path().join("b.png"));
    for (p, shift) in [(&a, 0u32), (&b, 2)] {
        image::GrayImage::from_fn(64, 48, |x, y| {
            image::Luma([((x + shift) * 7 + y * 3) as u8])
        })
        .save(p)
        .unwrap();
    }
    let init = d.path().join("init.flo");
    let flow = ["flow", s(&a), s(&b), "--backend", "opencv"];
    kf_ok(&[&flow[..], &["-o", s(&init)]].concat());
    let args = [
        &flow[..],
        &["--initial", s(&init), "-o", s(&init), "--force"],
    ]
    .concat();
    refused(&args, &named("is the input", &init, "initial flow"), &init);
}
