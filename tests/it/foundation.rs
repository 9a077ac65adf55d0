//! Foundation: probe, select (fps, every-nth, boundaries, manual), export, project files, and the
//! refusal of bad input without partial output.

use crate::common::*;
use std::path::Path;

fn clip_300(dir: &Path) -> std::path::PathBuf {
    testsrc(dir, "clip.mp4", 640, 360, "30", 10.0)
}

#[test]
fn probe_reports_count_fps_and_size() {
    let d = tempfile::tempdir().unwrap();
    let clip = clip_300(d.path());
    let v: serde_json::Value =
        serde_json::from_str(&kf_ok(&["probe", s(&clip), "--json"])).unwrap();
    assert_eq!(v["frame_count"], 300);
    assert_eq!(v["fps"], 30.0);
    assert_eq!(
        (v["width"].as_u64(), v["height"].as_u64()),
        (Some(640), Some(360))
    );
    assert!((v["duration_s"].as_f64().unwrap() - 10.0).abs() < 1e-6);
    let exact: serde_json::Value =
        serde_json::from_str(&kf_ok(&["probe", s(&clip), "--json", "--exact"])).unwrap();
    assert_eq!(exact["frame_count"], 300);
    assert_eq!(exact["frame_count_exact"], true);
}

#[test]
fn select_fps_every_and_boundaries_then_export() {
    let d = tempfile::tempdir().unwrap();
    let clip = clip_300(d.path());
    let p1 = d.path().join("fps.json");
    kf_ok(&["select", s(&clip), "--fps", "1", "-o", s(&p1)]);
    assert_eq!(keyframes(&p1), (0..10).map(|k| k * 30).collect::<Vec<_>>());

    let p2 = d.path().join("every.json");
    kf_ok(&[
        "select",
        s(&clip),
        "--every",
        "7",
        "--start",
        "20",
        "--end",
        "60",
        "-o",
        s(&p2),
    ]);
    assert_eq!(keyframes(&p2), vec![20, 27, 34, 41, 48, 55]);
    let proj = json(&p2);
    assert_eq!(proj["schema_version"], 2);
    assert_eq!(
        proj["input"]["path"], "clip.mp4",
        "input path relative to the project"
    );
    assert_eq!(proj["metadata"]["frame_count"], 300);
    let plugins: Vec<&str> = proj["history"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["plugin"].as_str().unwrap())
        .collect();
    assert_eq!(plugins, vec!["boundaries", "every-nth"]);

    // Export at 320x180: exactly those frames, that size, listed in the manifest.
    let out = d.path().join("out");
    kf_ok(&["export", s(&p1), "--out", s(&out), "--resize", "320x180"]);
    let expected: Vec<String> = (0..10)
        .map(|k| format!("frame_{:06}.jpg", k * 30))
        .collect();
    assert_eq!(listing(&out), vec!["images", "manifest.json"]);
    assert_eq!(listing(&out.join("images")), expected);
    for f in &expected {
        assert_eq!(
            image::image_dimensions(out.join("images").join(f)).unwrap(),
            (320, 180),
            "{f}"
        );
    }
    let m = json(&out.join("manifest.json"));
    let idx: Vec<u64> = m["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["index"].as_u64().unwrap())
        .collect();
    assert_eq!(idx, (0..10).map(|k| k * 30).collect::<Vec<u64>>());
    assert!((m["frames"][3]["timestamp_s"].as_f64().unwrap() - 3.0).abs() < 1e-3);
    assert_eq!(m["tool_version"], env!("CARGO_PKG_VERSION"));

    // A second export into the same folder is refused without --force, and nothing changes.
    let before = std::fs::read(out.join("manifest.json")).unwrap();
    let (code, err) = code_and_stderr(&kf(&["export", s(&p2), "--out", s(&out)]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("--force"), "{err}");
    assert_eq!(std::fs::read(out.join("manifest.json")).unwrap(), before);
    // With --force the earlier export's images are replaced, not mixed in.
    kf_ok(&["export", s(&p2), "--out", s(&out), "--force"]);
    let names = listing(&out.join("images"));
    assert_eq!(names.len(), 6, "{names:?}");
    assert!(names.contains(&"frame_000055.jpg".to_string()));
}

/// The exported pixels are the frame asked for: compare with ffmpeg's own decode of that frame.
#[test]
fn exported_frames_are_the_selected_ones() {
    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "c.mp4", 320, 180, "30", 3.0);
    let p = d.path().join("p.json");
    kf_ok(&["select", s(&clip), "--every", "40", "-o", s(&p)]);
    let out = d.path().join("out");
    kf_ok(&["export", s(&p), "--out", s(&out), "--format", "png"]);
    for idx in [0usize, 40, 80] {
        let reference = |n: usize| {
            let f = d.path().join(format!("ref{n}.png"));
            ffmpeg(&[
                "-i",
                s(&clip),
                "-vf",
                &format!("select=eq(n\\,{n})"),
                "-frames:v",
                "1",
                s(&f),
            ]);
            image::open(&f).unwrap().to_rgb8()
        };
        let ours = image::open(out.join(format!("images/frame_{idx:06}.png")))
            .unwrap()
            .to_rgb8();
        let mad = |a: &image::RgbImage, b: &image::RgbImage| {
            a.as_raw()
                .iter()
                .zip(b.as_raw())
                .map(|(x, y)| (i32::from(*x) - i32::from(*y)).abs() as f64)
                .sum::<f64>()
                / a.as_raw().len() as f64
        };
        let same = mad(&ours, &reference(idx));
        let next = mad(&ours, &reference(idx + 1));
        assert!(same < 2.0, "frame {idx}: mean abs diff {same}");
        assert!(
            next > 2.0 * same,
            "frame {idx}: neighbour not distinguishable ({same} vs {next})"
        );
    }
}

#[test]
fn ntsc_rate_samples_by_time() {
    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "ntsc.mp4", 160, 90, "30000/1001", 25.0);
    let p = d.path().join("p.json");
    kf_ok(&["select", s(&clip), "--fps", "1", "-o", s(&p)]);
    let k = keyframes(&p);
    let frame_s = 1001.0 / 30000.0;
    assert!(k.len() >= 24, "{k:?}");
    for (sec, &i) in k.iter().enumerate() {
        let t = i as f64 * frame_s;
        assert!(
            (t - sec as f64).abs() <= 0.5 * frame_s + 1e-9,
            "second {sec}: frame {i} at {t}"
        );
    }
    assert!(
        k.iter().enumerate().any(|(sec, &i)| i != sec * 30),
        "29.97 fps must not be sampled as every 30th frame: {k:?}"
    );
}

#[test]
fn variable_frame_rate_samples_by_time() {
    let d = tempfile::tempdir().unwrap();
    let clip = d.path().join("vfr.mp4");
    // 4 s at 30 fps followed by 4 s at 10 fps, timestamps kept as they are.
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "testsrc2=size=160x90:rate=30:duration=4",
        "-f",
        "lavfi",
        "-i",
        "testsrc2=size=160x90:rate=10:duration=4",
        "-filter_complex",
        "[0][1]concat=n=2:v=1[v]",
        "-map",
        "[v]",
        "-fps_mode",
        "passthrough",
        "-c:v",
        "libx264",
        "-pix_fmt",
        "yuv420p",
        s(&clip),
    ]);
    let p = d.path().join("p.json");
    kf_ok(&["select", s(&clip), "--fps", "1", "-o", s(&p)]);
    // ffprobe's own decode gives the reference timestamps.
    let probe = std::process::Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-show_entries",
            "frame=pts_time",
            "-of",
            "csv=p=0",
            s(&clip),
        ])
        .output()
        .unwrap();
    let truth: Vec<f64> = String::from_utf8_lossy(&probe.stdout)
        .lines()
        .map(|l| l.trim().trim_end_matches(','))
        .filter(|l| !l.is_empty())
        .map(|l| l.parse().unwrap())
        .collect();
    let proj = json(&p);
    assert_eq!(
        proj["metadata"]["frame_count"].as_u64().unwrap() as usize,
        truth.len()
    );
    let ts: Vec<f64> = proj["cache"]["timestamps_s"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    for (i, (t, r)) in ts.iter().zip(&truth).enumerate() {
        assert!(
            (t - r).abs() < 2e-3,
            "frame {i}: timestamp {t}, ffprobe {r}"
        );
    }
    // One keyframe per second of content, each within half a frame interval (10 fps part: 50 ms)
    // of its whole second, although the frame rate changes from 30 to 10 fps at 4 s.
    let k = keyframes(&p);
    assert_eq!(k.len(), 8, "{k:?}");
    for (sec, &i) in k.iter().enumerate() {
        let rel = ts[i] - ts[0];
        assert!(
            (rel - sec as f64).abs() <= 0.05 + 1e-6,
            "second {sec}: frame {i} at {rel}"
        );
    }
    assert!(
        k[5] < 5 * 30,
        "after the rate change frames are sparser: {k:?}"
    );
}

#[test]
fn image_folder_natural_order_and_byte_copy() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("imgs");
    std::fs::create_dir(&dir).unwrap();
    for (i, name) in ["img1.png", "img2.PNG", "img10.png", "img3.jpg"]
        .iter()
        .enumerate()
    {
        let img = image::RgbImage::from_pixel(40, 30, image::Rgb([i as u8 * 50, 10, 200]));
        img.save_with_format(
            dir.join(name),
            if name.ends_with("jpg") {
                image::ImageFormat::Jpeg
            } else {
                image::ImageFormat::Png
            },
        )
        .unwrap();
    }
    std::fs::write(dir.join("notes.txt"), "not an image").unwrap();
    let v: serde_json::Value = serde_json::from_str(&kf_ok(&["probe", s(&dir), "--json"])).unwrap();
    assert_eq!(v["frame_count"], 4);
    assert_eq!(v["kind"], "images");
    let p = d.path().join("p.json");
    kf_ok(&[
        "select",
        s(&dir),
        "--every",
        "1",
        "--remove",
        "1",
        "-o",
        s(&p),
    ]);
    assert_eq!(keyframes(&p), vec![0, 2, 3]);
    let out = d.path().join("out");
    kf_ok(&["export", s(&p), "--out", s(&out)]);
    let m = json(&out.join("manifest.json"));
    let files: Vec<&str> = m["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["file"].as_str().unwrap())
        .collect();
    assert_eq!(
        files,
        vec!["img1.png", "img3.jpg", "img10.png"],
        "natural order, original names"
    );
    for f in &files {
        assert_eq!(
            std::fs::read(out.join("images").join(f)).unwrap(),
            std::fs::read(dir.join(f)).unwrap(),
            "{f} copied byte for byte"
        );
    }
    // A resize re-encodes but keeps the names.
    let out2 = d.path().join("out2");
    kf_ok(&["export", s(&p), "--out", s(&out2), "--scale", "0.5"]);
    assert_eq!(
        image::image_dimensions(out2.join("images/img10.png")).unwrap(),
        (20, 15)
    );
}

#[test]
fn crop_then_resize() {
    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "c.mp4", 320, 180, "10", 1.0);
    let p = d.path().join("p.json");
    kf_ok(&["select", s(&clip), "--every", "5", "-o", s(&p)]);
    let out = d.path().join("out");
    kf_ok(&[
        "export",
        s(&p),
        "--out",
        s(&out),
        "--crop",
        "10,20,200,100",
        "--scale",
        "0.5",
        "--format",
        "png",
    ]);
    assert_eq!(
        image::image_dimensions(out.join("images/frame_000005.png")).unwrap(),
        (100, 50)
    );
}

#[test]
fn reselect_reuses_cached_frame_data() {
    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "c.mp4", 160, 90, "30", 4.0);
    let p = d.path().join("p.json");
    kf_ok(&["select", s(&clip), "--fps", "1", "-o", s(&p)]);
    // Without --force an existing project is not replaced.
    let (code, err) = code_and_stderr(&kf(&["select", s(&clip), "--fps", "2", "-o", s(&p)]));
    assert_eq!(code, 1, "{err}");
    assert_eq!(keyframes(&p).len(), 4);
    let out = kf_loud(&["select", s(&clip), "--fps", "2", "-o", s(&p), "--force"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("nothing decoded"), "{err}");
    assert_eq!(keyframes(&p), vec![0, 15, 30, 45, 60, 75, 90, 105]);
}

#[test]
fn project_file_errors_name_the_field() {
    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "c.mp4", 160, 90, "30", 1.0);
    let p = d.path().join("p.json");
    kf_ok(&["select", s(&clip), "--every", "10", "-o", s(&p)]);
    let mut v = json(&p);
    v["keyframes"][1] = serde_json::json!("ten");
    std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    let out = d.path().join("out");
    let (code, err) = code_and_stderr(&kf(&["export", s(&p), "--out", s(&out)]));
    assert_eq!(code, 1);
    assert!(
        err.contains("keyframes[1]") && err.contains("p.json"),
        "{err}"
    );
    v["keyframes"] = serde_json::json!([0, 10, 5]);
    std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    let (code, err) = code_and_stderr(&kf(&["export", s(&p), "--out", s(&out)]));
    assert_eq!(code, 1);
    assert!(
        err.contains("keyframes[2]") && err.contains("sorted"),
        "{err}"
    );
    assert!(!out.exists(), "nothing written for a bad project");
}

/// Every bad input: one clear line naming the file, exit 1, no output written.
#[test]
fn bad_inputs_fail_cleanly() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let text = dp.join("notes.mp4");
    std::fs::write(&text, "this is not a video\n").unwrap();
    let empty = dp.join("empty");
    std::fs::create_dir(&empty).unwrap();
    let mixed = dp.join("mixed");
    std::fs::create_dir(&mixed).unwrap();
    image::RgbImage::new(40, 30)
        .save(mixed.join("a1.png"))
        .unwrap();
    image::RgbImage::new(40, 31)
        .save(mixed.join("a2.png"))
        .unwrap();
    // An MP4 whose index is at the end, cut in half: the container cannot be read.
    let whole = testsrc(dp, "whole.mp4", 160, 90, "30", 2.0);
    let bytes = std::fs::read(&whole).unwrap();
    let truncated = dp.join("truncated.mp4");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();

    let cases: [(&Path, &str); 5] = [
        (&dp.join("missing.mp4"), "no such file"),
        (&text, "cannot open as a video"),
        (&truncated, "cannot open as a video"),
        (&empty, "no images"),
        (&mixed, "a2.png"),
    ];
    for (input, msg) in cases {
        let p = dp.join("p.json");
        for args in [
            vec!["probe", s(input)],
            vec!["select", s(input), "--every", "2", "-o", s(&p)],
        ] {
            let (code, err) = code_and_stderr(&kf(&args));
            assert_eq!(code, 1, "{args:?}: {err}");
            assert!(err.contains(msg), "{args:?}: expected `{msg}` in: {err}");
            let name = input.file_name().unwrap().to_string_lossy();
            assert!(
                err.contains(&*name),
                "{args:?}: message must name the input: {err}"
            );
            assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
            assert!(!p.exists(), "{args:?}: no project written");
        }
    }

    // Crop outside the frame and an unwritable output: refused before anything is written.
    let p = dp.join("ok.json");
    kf_ok(&["select", s(&whole), "--every", "10", "-o", s(&p)]);
    let out = dp.join("out");
    let (code, err) = code_and_stderr(&kf(&[
        "export",
        s(&p),
        "--out",
        s(&out),
        "--crop",
        "100,0,100,90",
    ]));
    assert_eq!(code, 1);
    assert!(err.contains("--crop") && err.contains("160x90"), "{err}");
    assert!(!out.exists());
    let blocker = dp.join("file");
    std::fs::write(&blocker, "x").unwrap();
    let bad_out = blocker.join("out");
    let (code, err) = code_and_stderr(&kf(&["export", s(&p), "--out", s(&bad_out)]));
    assert_eq!(code, 1);
    assert!(err.contains("file/out"), "{err}");
    let (code, err) = code_and_stderr(&kf(&[
        "select",
        s(&whole),
        "--every",
        "3",
        "-o",
        s(&blocker.join("p.json")),
    ]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("p.json"), "{err}");

    // A field of view out of range, or one given without --derotate: refused, nothing written.
    let p = dp.join("hfov.json");
    for (extra, code_want, msg) in [
        (
            &["--derotate", "--hfov", "200"][..],
            1,
            "--hfov: 200 must be between 1 and 179",
        ),
        (&["--hfov", "60"][..], 1, "--derotate"),
    ] {
        let mut args = vec!["select", s(&whole), "--spacing", "20", "-o", s(&p)];
        args.extend_from_slice(extra);
        let (code, err) = code_and_stderr(&kf(&args));
        assert_eq!(code, code_want, "{args:?}: {err}");
        assert!(err.contains(msg), "{args:?}: {err}");
        assert!(!p.exists());
    }
    // Bad parameters.
    for args in [
        vec!["select", s(&whole), "--every", "0", "-o", s(&p), "--force"],
        vec!["select", s(&whole), "--fps", "-1", "-o", s(&p), "--force"],
        vec![
            "select",
            s(&whole),
            "--start",
            "1.5x",
            "-o",
            s(&p),
            "--force",
        ],
        vec!["export", s(&p), "--out", s(&out), "--resize", "20y10"],
        vec!["export", s(&p), "--out", s(&out), "--quality", "0"],
    ] {
        let (code, err) = code_and_stderr(&kf(&args));
        assert_eq!(code, 1, "{args:?}: {err}");
        assert!(!out.exists());
    }
}

/// A stream cut mid-way (index at the front): decodable frames are used, the rest reported, exit 2.
#[test]
fn truncated_stream_decodes_what_it_can() {
    let d = tempfile::tempdir().unwrap();
    let whole = d.path().join("fast.mp4");
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "testsrc2=size=320x180:rate=30:duration=10",
        "-c:v",
        "libx264",
        "-pix_fmt",
        "yuv420p",
        "-movflags",
        "+faststart",
        s(&whole),
    ]);
    let bytes = std::fs::read(&whole).unwrap();
    let cut = d.path().join("cut.mp4");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let p = d.path().join("p.json");
    let (code, err) = code_and_stderr(&kf(&["select", s(&cut), "--every", "30", "-o", s(&p)]));
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("cut.mp4") && err.contains("could not be decoded"),
        "{err}"
    );
    let proj = json(&p);
    let n = proj["metadata"]["frame_count"].as_u64().unwrap();
    assert!(n > 30 && n < 300, "decodable frames: {n}");
    assert!(keyframes(&p).iter().all(|&k| (k as u64) < n));
}

/// Debian's `Megamind_bugy.avi` (a damaged sample): keyframer decodes exactly the frames ffmpeg's
/// own decoder can count, and exports them.
#[test]
fn damaged_megamind_stream() {
    let bugy = testdata("opencv-doc/Megamind_bugy.avi");
    let counted = std::process::Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-count_frames",
            "-select_streams",
            "v:0",
            "-show_entries",
            "stream=nb_read_frames",
            "-of",
            "csv=p=0",
            s(&bugy),
        ])
        .output()
        .unwrap();
    let counted: u64 = String::from_utf8_lossy(&counted.stdout)
        .trim()
        .parse()
        .unwrap();
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("p.json");
    let (code, err) = code_and_stderr(&kf(&["select", s(&bugy), "--every", "10", "-o", s(&p)]));
    assert_eq!(code, 0, "{err}");
    let proj = json(&p);
    assert_eq!(proj["metadata"]["frame_count"].as_u64().unwrap(), counted);
    let out = d.path().join("out");
    kf_ok(&["export", s(&p), "--out", s(&out), "--scale", "0.5"]);
    assert_eq!(listing(&out.join("images")).len(), keyframes(&p).len());
}

#[test]
fn info_names_an_adapter() {
    let v: serde_json::Value = serde_json::from_str(&kf_ok(&["info", "--json"])).unwrap();
    assert!(v["opencv_version"].as_str().unwrap().starts_with('4'));
    assert!(v["opencv_video_backends"]
        .as_array()
        .unwrap()
        .iter()
        .any(|b| b == "FFMPEG"));
    let name = v["selected_adapter"]["Ok"]["name"].as_str();
    assert!(name.is_some(), "no GPU adapter (lavapipe expected): {v}");
}

/// Rotation metadata is reported and applied: a 320x180 stream tagged 90° decodes as 180x320.
#[test]
fn rotation_metadata_is_applied() {
    let d = tempfile::tempdir().unwrap();
    let plain = testsrc(d.path(), "plain.mp4", 320, 180, "30", 1.0);
    let rotated = d.path().join("rotated.mp4");
    ffmpeg(&[
        "-i",
        s(&plain),
        "-c",
        "copy",
        "-metadata:s:v:0",
        "rotate=90",
        s(&rotated),
    ]);
    let v: serde_json::Value =
        serde_json::from_str(&kf_ok(&["probe", s(&rotated), "--json"])).unwrap();
    assert_eq!(v["rotation_deg"], 90);
    assert_eq!(
        (v["width"].as_u64(), v["height"].as_u64()),
        (Some(180), Some(320))
    );
    let p = d.path().join("p.json");
    kf_ok(&["select", s(&rotated), "--every", "10", "-o", s(&p)]);
    let out = d.path().join("out");
    kf_ok(&["export", s(&p), "--out", s(&out)]);
    assert_eq!(
        image::image_dimensions(out.join("images/frame_000010.jpg")).unwrap(),
        (180, 320)
    );
}

/// Without a usable adapter the gpu backend warns once and the opencv backend does the work;
/// `auto` takes opencv and says why.
#[test]
fn missing_adapter_falls_back_to_opencv() {
    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "c.mp4", 160, 90, "30", 1.0);
    let score = |backend: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_keyframer"))
            .args(["score", s(&clip), "--json", "--backend", backend])
            .env("KEYFRAMER_ADAPTER", "no-such-adapter")
            .output()
            .unwrap()
    };
    for backend in ["gpu", "auto"] {
        let out = score(backend);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{err}");
        let (fell_back, said) = match backend {
            "gpu" => (1, 0),
            _ => (0, 1),
        };
        assert_eq!(
            err.matches("falling back to the opencv backend").count(),
            fell_back,
            "{err}"
        );
        let auto = "backend auto: opencv (no adapter matches `no-such-adapter`";
        assert_eq!(err.matches(auto).count(), said, "{err}");
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(v["backend"], "opencv");
        assert_eq!(v["scores"].as_array().unwrap().len(), 30);
    }
}

/// `--backend auto`, the default, takes opencv on a software adapter (lavapipe here) and gpu on a
/// hardware one, says so once per process (even when the analysis and the `--spacing auto`
/// sample both resolve it), `info` shows the same decision, and the project records the backend
/// used. `--backend gpu` still forces the WGSL kernels.
#[test]
fn auto_backend_is_the_default_said_once_and_recorded_resolved() {
    let info: serde_json::Value = serde_json::from_str(&kf_ok(&["info", "--json"])).unwrap();
    let adapter = &info["selected_adapter"]["Ok"];
    let software = adapter["software"]
        .as_bool()
        .expect("an adapter (lavapipe in CI)");
    let (class, want) = match software {
        true => ("software", "opencv"),
        false => ("hardware", "gpu"),
    };
    assert_eq!(info["backend_auto"]["backend"], want, "{info}");
    let reason = info["backend_auto"]["reason"].as_str().unwrap();
    let name = adapter["name"].as_str().unwrap();
    assert!(
        reason.starts_with(&format!("{name} is a {class} adapter; --backend ")),
        "{reason}"
    );
    let line = format!("backend auto: {want} ({reason})");
    assert!(kf_ok(&["info"]).contains(&line), "info names the decision");

    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "c.mp4", 160, 90, "30", 2.0);
    let select = |project: &Path, extra: &[&str]| {
        let mut args = vec!["select", s(&clip), "--blur", "--spacing", "auto"];
        args.extend(extra);
        args.extend(["-o", s(project)]);
        let (code, err) = code_and_stderr(&kf_loud(&args));
        assert_eq!(code, 0, "{err}");
        let cache = json(project)["cache"].clone();
        let used = [&cache["sharpness"][0], &cache["movement"][0]].map(|c| c["backend"].clone());
        (err, used)
    };
    let (err, used) = select(&d.path().join("auto.json"), &[]);
    assert_eq!(err.matches("backend auto:").count(), 1, "{err}");
    assert!(err.contains(&line), "{err}");
    assert_eq!(
        used,
        [want, want],
        "the project records the resolved backend"
    );
    let (err, used) = select(&d.path().join("gpu.json"), &["--backend", "gpu"]);
    assert!(!err.contains("backend auto"), "{err}");
    assert_eq!(used, ["gpu", "gpu"]);
}

/// A full disk: a clear error naming the file, and the disk as it was: the output folder the
/// export made is gone again, no temporary or write-test file stays. Needs a 256 KiB tmpfs (root); skipped with a message where mounting is not allowed.
#[test]
fn full_disk_fails_cleanly() {
    struct Mount(std::path::PathBuf);
    impl Drop for Mount {
        fn drop(&mut self) {
            let _ = std::process::Command::new("umount").arg(&self.0).status();
        }
    }
    let d = tempfile::tempdir().unwrap();
    let small = d.path().join("small");
    std::fs::create_dir(&small).unwrap();
    let ok = std::process::Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=256k", "tmpfs", s(&small)])
        .stderr(std::process::Stdio::null())
        .status()
        .map(|st| st.success())
        .unwrap_or(false);
    if !ok {
        eprintln!("SKIPPED full_disk_fails_cleanly: cannot mount a tmpfs here (needs root)");
        return;
    }
    let _guard = Mount(small.clone());
    let clip = testsrc(d.path(), "c.mp4", 640, 360, "30", 2.0);
    let p = d.path().join("p.json");
    kf_ok(&["select", s(&clip), "--every", "5", "-o", s(&p)]);
    let out = small.join("out");
    let (code, err) = code_and_stderr(&kf(&["export", s(&p), "--out", s(&out), "--format", "png"]));
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("No space left")
            && err.contains(".png")
            && err.contains("nothing was written"),
        "{err}"
    );
    assert_eq!(
        err.matches("No space left").count(),
        1,
        "one clear line: {err}"
    );
    assert!(!out.exists(), "{:?}", listing(&out));
    assert!(listing(&small).is_empty(), "{:?}", listing(&small));
    // A smaller export then fits, and leaves no temporary behind either.
    kf_ok(&["export", s(&p), "--out", s(&out), "--resize", "64x36"]);
    assert_eq!(listing(&out), vec!["images", "manifest.json"]);
    assert!(listing(&out.join("images"))
        .iter()
        .all(|n| !n.starts_with('.')));
}
