//! Input edge cases: rotation metadata, damaged images in a folder, file names that are not
//! UTF-8, the keyframe-only preview on AVI and on cut-short streams, frames read on demand,
//! variable-frame-rate timestamps and inputs that are not regular files.

use crate::common::*;
use keyframer::source::codec_keyframes::{probe, CodecKeyframeSource};
use keyframer::source::{self, FrameReader, FrameSize, FrameSource, OpenOptions};
use opencv::core::{self, Mat};
use opencv::imgcodecs;
use opencv::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

/// Every file under `dir` (recursively) with its bytes: to prove a command changed nothing.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(p.clone(), std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

fn read(p: &Path) -> Mat {
    let m = imgcodecs::imread(s(p), imgcodecs::IMREAD_COLOR).unwrap();
    assert!(!m.empty(), "cannot read {}", p.display());
    m
}

/// PSNR in dB; 0 when the sizes differ (a transposed frame is as wrong as it gets).
fn psnr(a: &Mat, b: &Mat) -> f64 {
    if a.size().unwrap() != b.size().unwrap() {
        return 0.0;
    }
    core::psnr(a, b, 255.0).unwrap()
}

fn rotate180(m: &Mat) -> Mat {
    let mut r = Mat::default();
    core::rotate(m, &mut r, core::ROTATE_180).unwrap();
    r
}

/// The first exported image, found through the manifest (in `OUT/images/`).
fn first_exported(out: &Path) -> PathBuf {
    let m = json(&out.join("manifest.json"));
    let file = m["frames"][0]["file"].as_str().expect("frames[0].file");
    out.join("images").join(file)
}

/// ffprobe's rotation of the first video stream (its display-matrix side data), 0 without one.
fn ffprobe_rotation(v: &Path) -> i64 {
    let o = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-show_entries",
            "stream_side_data=rotation",
            "-of",
            "csv=p=0",
        ])
        .arg(v)
        .output()
        .unwrap();
    assert!(o.status.success());
    let text = String::from_utf8(o.stdout).unwrap();
    let t = text.trim().trim_end_matches(',');
    if t.is_empty() {
        0
    } else {
        t.parse()
            .unwrap_or_else(|_| panic!("ffprobe rotation `{t}`"))
    }
}

/// 10 frames of testsrc2 (asymmetric: text and a moving pattern), 320x240, with `rotate`
/// metadata set by a stream copy.
fn rotated_clip(dir: &Path, deg: u32) -> PathBuf {
    let plain = dir.join("plain.mp4");
    if !plain.exists() {
        ffmpeg(&[
            "-f",
            "lavfi",
            "-i",
            "testsrc2=size=320x240:rate=10",
            "-frames:v",
            "10",
            "-c:v",
            "libx264",
            "-g",
            "5",
            "-pix_fmt",
            "yuv420p",
            s(&plain),
        ]);
    }
    let v = dir.join(format!("rot{deg}.mp4"));
    ffmpeg(&[
        "-i",
        s(&plain),
        "-c",
        "copy",
        "-metadata:s:v:0",
        &format!("rotate={deg}"),
        s(&v),
    ]);
    v
}

/// select + export (png) of each rotation matches ffmpeg's own (autorotated) decode, and probe
/// reports ffprobe's angle; the preview's keyframe decode matches too.
#[test]
fn rotated_videos_decode_as_ffmpeg_shows_them() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let mut seen = Vec::new();
    for deg in [0u32, 90, 180, 270] {
        let v = rotated_clip(dp, deg);
        let reference = dp.join(format!("ref{deg}.png"));
        ffmpeg(&["-i", s(&v), "-frames:v", "1", s(&reference)]);
        let want = read(&reference);

        // probe states ffprobe's number (display-matrix convention: counter-clockwise).
        let pj: serde_json::Value =
            serde_json::from_str(&kf_ok(&["probe", s(&v), "--json"])).unwrap();
        let angle = ffprobe_rotation(&v);
        assert_eq!(pj["rotation_deg"].as_i64(), Some(angle), "rotate={deg}");
        let text = kf_ok(&["probe", s(&v)]);
        assert!(
            text.contains(&format!("rotation:    {angle} deg")),
            "rotate={deg}: {text}"
        );
        assert_eq!(
            (pj["width"].as_i64(), pj["height"].as_i64()),
            (Some(want.cols() as i64), Some(want.rows() as i64)),
            "rotate={deg}: probe's size is the displayed size"
        );

        let p = dp.join(format!("p{deg}.json"));
        let out = dp.join(format!("out{deg}"));
        kf_ok(&["select", s(&v), "--every", "5", "-o", s(&p)]);
        assert_eq!(keyframes(&p), vec![0, 5]);
        kf_ok(&["export", s(&p), "--out", s(&out), "--format", "png"]);
        let got = read(&first_exported(&out));
        let right = psnr(&got, &want);
        let wrong = psnr(&got, &rotate180(&want));
        seen.push((deg, angle, right, wrong));
        assert!(
            right >= 30.0,
            "rotate={deg}: export vs ffmpeg {right:.1} dB"
        );
        assert!(
            wrong < right - 15.0,
            "rotate={deg}: export vs the opposite turn {wrong:.1} dB (right {right:.1} dB)"
        );

        // The preview path decodes with ffmpeg: its first keyframe is the same picture.
        let index = Arc::new(probe(&v).unwrap());
        let mut src = CodecKeyframeSource::open(&v, index).unwrap();
        let first = src.next_frame().unwrap().unwrap().image;
        let pv = psnr(&first, &want);
        assert!(pv >= 30.0, "rotate={deg}: preview vs ffmpeg {pv:.1} dB");
    }
    eprintln!("rotation (metadata, ffprobe angle, PSNR vs ffmpeg, vs opposite turn): {seen:?}");
    // The four clips have four different angles.
    let mut angles: Vec<i64> = seen.iter().map(|s| s.1).collect();
    angles.sort_unstable();
    angles.dedup();
    assert_eq!(angles.len(), 4, "{seen:?}");
}

/// `n` JPEG (or PNG) frames of testsrc2 named img1..imgN.
fn image_folder(dir: &Path, ext: &str, n: usize) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "testsrc2=size=320x240:rate=10",
        "-frames:v",
        &n.to_string(),
        s(&dir.join(format!("img%d.{ext}"))),
    ]);
    dir.to_path_buf()
}

/// Replaces `dir/name` with the first half of `good`'s bytes (a file cut short).
fn cut(dir: &Path, name: &str, good: &str) {
    let bytes = std::fs::read(dir.join(good)).unwrap();
    std::fs::write(dir.join(name), &bytes[..bytes.len() / 2]).unwrap();
}

/// A truncated JPEG among good ones: select reports it (frame index and file), exits 2 and
/// never keeps it; with the analysis decoding pixels (blur) too.
#[test]
fn truncated_jpeg_in_a_folder_is_a_decode_problem() {
    let d = tempfile::tempdir().unwrap();
    let imgs = image_folder(&d.path().join("imgs"), "jpg", 10);
    cut(&imgs, "img7.jpg", "img6.jpg");
    // OpenCV alone would accept it: the check is ours.
    {
        let grey = read(&imgs.join("img7.jpg"));
        assert_eq!(grey.cols(), 320, "imread reads a cut JPEG without an error");
    }
    let before = snapshot(&imgs);
    for extra in [&[][..], &["--blur"][..]] {
        let p = d.path().join(format!("p{}.json", extra.len()));
        let mut args = vec!["select", s(&imgs), "--every", "1", "-o", s(&p)];
        args.extend_from_slice(extra);
        let (code, err) = code_and_stderr(&kf(&args));
        assert_eq!(code, 2, "{extra:?}: {err}");
        assert!(
            err.contains("frame 6 (img7.jpg)") && err.contains("cut short"),
            "{extra:?}: {err}"
        );
        let pj = json(&p);
        let problems = pj["decode_problems"].as_array().unwrap();
        assert_eq!(problems.len(), 1, "{problems:?}");
        let msg = problems[0].as_str().unwrap();
        assert!(msg.contains("frame 6 (img7.jpg)"), "{msg}");
        assert_eq!(pj["damaged_frames"], serde_json::json!([6]));
        let keys = keyframes(&p);
        assert_eq!(keys, vec![0, 1, 2, 3, 4, 5, 7, 8, 9], "{extra:?}");
        // A re-select from the cache still leaves it out and still reports it.
        let (code, err) = code_and_stderr(&kf(&[
            "select",
            s(&imgs),
            "--every",
            "2",
            "--add",
            "6",
            "-o",
            s(&p),
            "--force",
        ]));
        assert_eq!(code, 2, "{err}");
        assert!(!keyframes(&p).contains(&6), "{:?}", keyframes(&p));
    }
    assert_eq!(snapshot(&imgs), before, "the input folder is unchanged");
}

/// A cut PNG is found the same way; `probe --exact` lists it too.
#[test]
fn truncated_png_in_a_folder_is_a_decode_problem() {
    let d = tempfile::tempdir().unwrap();
    let imgs = image_folder(&d.path().join("imgs"), "png", 6);
    cut(&imgs, "img3.png", "img2.png");
    let p = d.path().join("p.json");
    let (code, err) = code_and_stderr(&kf(&[
        "select",
        s(&imgs),
        "--every",
        "1",
        "--blur",
        "-o",
        s(&p),
    ]));
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("frame 2 (img3.png)") && err.contains("IEND"),
        "{err}"
    );
    assert_eq!(keyframes(&p), vec![0, 1, 3, 4, 5]);
    let o = kf(&["probe", s(&imgs), "--exact", "--json"]);
    assert_eq!(o.status.code(), Some(2));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let problems = v["decode_problems"].as_array().unwrap();
    assert_eq!(problems.len(), 1, "{problems:?}");
    assert!(problems[0].as_str().unwrap().contains("frame 2 (img3.png)"));
}

/// A file that is no image at all names its own frame index (it used to say frame 0).
#[test]
fn unreadable_image_names_its_frame_index() {
    let d = tempfile::tempdir().unwrap();
    let imgs = image_folder(&d.path().join("imgs"), "jpg", 5);
    std::fs::write(imgs.join("img4.jpg"), b"this is not a jpeg").unwrap();
    let p = d.path().join("p.json");
    let (code, err) = code_and_stderr(&kf(&["select", s(&imgs), "--every", "1", "-o", s(&p)]));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("frame 3 (img4.jpg)"), "{err}");
    assert!(!err.contains("frame 0"), "{err}");
    assert_eq!(keyframes(&p), vec![0, 1, 2, 4]);
    // A single unreadable image is an input error naming it.
    let (code, err) = code_and_stderr(&kf(&["probe", s(&imgs.join("img4.jpg"))]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("img4.jpg"), "{err}");
}

/// Export never copies nor encodes a damaged file: it is a missing frame with its reason.
#[test]
fn export_refuses_damaged_images() {
    let d = tempfile::tempdir().unwrap();
    let imgs = image_folder(&d.path().join("imgs"), "jpg", 8);
    let p = d.path().join("p.json");
    kf_ok(&["select", s(&imgs), "--every", "2", "-o", s(&p)]);
    assert_eq!(keyframes(&p), vec![0, 2, 4, 6]);
    // Damage a selected image after the selection; the project is re-made on the damaged
    // folder with the frame forced in by hand (as an older keyframer would have kept it).
    cut(&imgs, "img5.jpg", "img4.jpg");
    let before = snapshot(&imgs);
    let (code, _) = code_and_stderr(&kf(&[
        "select",
        s(&imgs),
        "--every",
        "2",
        "-o",
        s(&p),
        "--force",
    ]));
    assert_eq!(code, 2);
    // The damaged frame is no candidate: every 2nd of the other frames.
    assert_eq!(keyframes(&p), vec![0, 2, 5, 7]);
    let mut v = json(&p);
    v["keyframes"] = serde_json::json!([0, 2, 4, 6]);
    v["damaged_frames"] = serde_json::json!([]);
    std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    for format in [None, Some("png")] {
        let out = d.path().join(format!("out-{}", format.unwrap_or("copy")));
        let mut args = vec!["export", s(&p), "--out", s(&out)];
        if let Some(f) = format {
            args.extend(["--format", f]);
        }
        let (code, err) = code_and_stderr(&kf_loud(&args));
        assert_eq!(code, 2, "{format:?}: {err}");
        assert!(
            err.contains("frame 4 not exported")
                && err.contains("img5.jpg")
                && err.contains("damaged"),
            "{format:?}: {err}"
        );
        assert!(err.contains("exported 3 images"), "{format:?}: {err}");
        let m = json(&out.join("manifest.json"));
        let files: Vec<&str> = m["frames"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f["file"].as_str().unwrap())
            .collect();
        let ext = format.unwrap_or("jpg");
        assert_eq!(
            files,
            vec![
                format!("img1.{ext}"),
                format!("img3.{ext}"),
                format!("img7.{ext}")
            ],
            "{format:?}"
        );
        assert_eq!(m["missing"][0]["index"], 4);
        assert!(m["missing"][0]["reason"]
            .as_str()
            .unwrap()
            .contains("img5.jpg"));
        let dir = first_exported(&out).parent().unwrap().to_path_buf();
        assert!(
            !listing(&dir).iter().any(|n| n.starts_with("img5")),
            "{format:?}: {:?}",
            listing(&dir)
        );
    }
    assert_eq!(snapshot(&imgs), before, "the input folder is unchanged");
}

/// Image names that are not UTF-8 are refused when the folder is opened: two of them would be
/// written under one lossy name.
#[test]
fn non_utf8_image_names_are_refused() {
    use std::os::unix::ffi::OsStrExt;
    let d = tempfile::tempdir().unwrap();
    let imgs = image_folder(&d.path().join("imgs"), "jpg", 3);
    let good = std::fs::read(imgs.join("img1.jpg")).unwrap();
    for raw in [&b"a\xff.jpg"[..], &b"a\xfe.jpg"[..]] {
        std::fs::write(imgs.join(std::ffi::OsStr::from_bytes(raw)), &good).unwrap();
    }
    let before = snapshot(&imgs);
    let p = d.path().join("p.json");
    let out = d.path().join("out");
    for args in [
        vec!["select", s(&imgs), "--every", "1", "-o", s(&p)],
        vec!["probe", s(&imgs)],
    ] {
        let (code, err) = code_and_stderr(&kf(&args));
        assert_eq!(code, 1, "{args:?}: {err}");
        assert!(
            (err.contains("a\\xff.jpg") || err.contains("a\\xfe.jpg"))
                && err.contains("not valid UTF-8")
                && err.contains("rename"),
            "{args:?}: {err}"
        );
    }
    assert!(!p.exists(), "no project written");
    assert!(!out.exists());
    assert_eq!(listing(d.path()), vec!["imgs".to_string()]);
    assert_eq!(snapshot(&imgs), before);
}

/// The opencv-doc test data, or a message saying the test is skipped.
fn opencv_doc(name: &str, test: &str) -> Option<PathBuf> {
    let root = std::env::var_os("KEYFRAMER_TESTDATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("target/testdata"));
    let p = root.join("opencv-doc").join(name);
    if p.exists() {
        Some(p)
    } else {
        eprintln!(
            "SKIPPED {test}: {} is missing (scripts/setup.sh fetches it)",
            p.display()
        );
        None
    }
}

/// ffprobe's list of keyframe packets (in packet order) and the container's duration.
fn ffprobe_keyframes(v: &Path) -> (Vec<usize>, f64) {
    let o = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-show_entries",
            "packet=flags",
            "-of",
            "csv=p=0",
        ])
        .arg(v)
        .output()
        .unwrap();
    let keys = String::from_utf8(o.stdout)
        .unwrap()
        .lines()
        .enumerate()
        .filter_map(|(i, l)| l.starts_with('K').then_some(i))
        .collect();
    let o = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-show_entries",
            "format=duration",
            "-of",
            "csv=p=0",
        ])
        .arg(v)
        .output()
        .unwrap();
    let dur = String::from_utf8(o.stdout).unwrap().trim().parse().unwrap();
    (keys, dur)
}

/// AVI stores no pts for I and P frames: the preview places packets by their dts.
#[test]
fn preview_reads_avi_keyframes() {
    for name in ["Megamind.avi", "Megamind_bugy.avi"] {
        let Some(v) = opencv_doc(name, "preview_reads_avi_keyframes") else {
            return;
        };
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("p.json");
        let (code, err) = code_and_stderr(&kf(&[
            "select",
            s(&v),
            "--preview",
            "--every",
            "1",
            "-o",
            s(&p),
        ]));
        assert_eq!(code, 0, "{name}: {err}");
        let (want, duration) = ffprobe_keyframes(&v);
        assert!(want.len() >= 5, "{name}: {want:?}");
        assert_eq!(keyframes(&p), want, "{name}");
        let pj = json(&p);
        assert_eq!(pj["metadata"]["frame_count"], 270, "{name}");
        let dur = pj["metadata"]["duration_s"].as_f64().unwrap();
        assert!(
            (dur - duration).abs() < 0.05,
            "{name}: duration {dur} s, ffprobe says {duration} s"
        );
        assert_eq!(listing(d.path()), vec!["p.json".to_string()]);
    }
}

/// A preview project's duration is the video's (it used to be one frame interval when the
/// video had one codec keyframe), as a full select measures it.
#[test]
fn preview_duration_is_the_videos() {
    let d = tempfile::tempdir().unwrap();
    let v = testsrc(d.path(), "c.mp4", 160, 120, "30", 4.0);
    let (pv, full) = (d.path().join("pv.json"), d.path().join("full.json"));
    kf_ok(&["select", s(&v), "--preview", "--every", "1", "-o", s(&pv)]);
    kf_ok(&["select", s(&v), "--every", "1", "-o", s(&full)]);
    let a = json(&pv)["metadata"]["duration_s"].as_f64().unwrap();
    let b = json(&full)["metadata"]["duration_s"].as_f64().unwrap();
    assert!((b - 4.0).abs() < 1e-6, "full select: {b}");
    assert!((a - b).abs() < 1e-6, "preview {a} s vs full {b} s");
}

/// A stream cut short: the preview reports it in `decode_problems` and exits 2, like the full
/// decode does (MP4 with its index first, and AVI).
#[test]
fn preview_reports_cut_short_streams() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let mp4 = dp.join("fs.mp4");
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "testsrc2=size=320x240:rate=30:duration=4",
        "-c:v",
        "libx264",
        "-g",
        "30",
        "-pix_fmt",
        "yuv420p",
        "-movflags",
        "+faststart",
        s(&mp4),
    ]);
    let mut clips = vec![(mp4, 0.9)];
    if let Some(avi) = opencv_doc("Megamind.avi", "preview_reports_cut_short_streams (AVI)") {
        clips.push((avi, 0.5));
    }
    for (k, (v, keep)) in clips.iter().enumerate() {
        let bytes = std::fs::read(v).unwrap();
        let cutv = dp.join(format!(
            "cut{k}.{}",
            v.extension().unwrap().to_str().unwrap()
        ));
        std::fs::write(&cutv, &bytes[..(bytes.len() as f64 * keep) as usize]).unwrap();
        let (full, pv) = (
            dp.join(format!("full{k}.json")),
            dp.join(format!("pv{k}.json")),
        );
        let (code, err) =
            code_and_stderr(&kf(&["select", s(&cutv), "--every", "1", "-o", s(&full)]));
        assert_eq!(code, 2, "full decode of {}: {err}", cutv.display());
        let (code, err) = code_and_stderr(&kf(&[
            "select",
            s(&cutv),
            "--preview",
            "--every",
            "1",
            "-o",
            s(&pv),
        ]));
        assert_eq!(code, 2, "preview of {}: {err}", cutv.display());
        assert!(err.contains("container declares"), "{err}");
        let pj = json(&pv);
        let problems = pj["decode_problems"].as_array().unwrap();
        assert_eq!(problems.len(), 1, "{problems:?}");
        assert!(
            problems[0].as_str().unwrap().contains("truncated stream"),
            "{problems:?}"
        );
        let fj = json(&full);
        let (np, nf) = (
            pj["metadata"]["frame_count"].as_u64().unwrap(),
            fj["metadata"]["frame_count"].as_u64().unwrap(),
        );
        // The packet list and the decoder agree within a few frames on where the data ends.
        assert!(
            np.abs_diff(nf) <= 3,
            "preview {np} frames, full decode {nf}"
        );
        let declared = if k == 0 { 120 } else { 270 };
        assert!(np < declared, "{np} of {declared}");
    }
}

/// The pixels of a JPEG.
fn decoded(jpeg: &[u8]) -> Mat {
    let m = imgcodecs::imdecode(
        &core::Vector::<u8>::from_slice(jpeg),
        imgcodecs::IMREAD_COLOR,
    );
    m.unwrap()
}

/// Frames read on demand in any order (seeks, forward skips, the decoder's drain at the end,
/// and reopening when a seek cannot be verified) are the frames a sequential pass decodes,
/// shrunk the same way; the JPEG cache stays within its budget; a frame beyond the end is an
/// error naming the frame and the input.
#[test]
fn frames_on_demand_equal_sequential_decode() {
    let d = tempfile::tempdir().unwrap();
    // The report fixture's 4 s, 30 fps pan, with a codec keyframe every second to seek to.
    let clip = d.path().join("pan.mp4");
    crate::common::pan_clip(&clip, Some("30"));
    let folder = image_folder(&d.path().join("images"), "jpg", 120);
    let opts = OpenOptions::default();
    let order = [119, 0, 61, 60, 3, 90];
    let sizes = [FrameSize::Strip, FrameSize::Large];
    for input in [&clip, &folder] {
        let mut src = source::open(input, &opts).unwrap();
        let ts = source::scan(src.as_mut(), |_| {}).unwrap().timestamps_s;
        let mut want = BTreeMap::new();
        let mut sorted = order.to_vec();
        sorted.sort();
        let mut src = source::open(input, &opts).unwrap();
        let missing = source::read_indices(src.as_mut(), &sorted, |f| {
            for size in sizes {
                let jpeg = source::shrink(&f.image, size.width(), &String::new)?;
                want.insert((f.index, size.width()), decoded(&jpeg));
            }
            Ok(())
        });
        assert_eq!(missing.unwrap(), Vec::<usize>::new());
        // Timestamps a second off make every seek fail its check: reopen and decode forward.
        let shifted = ts.as_ref().map(|t| t.iter().map(|x| x + 1.0).collect());
        for (what, ts) in [
            ("cached timestamps", ts.clone()),
            ("no timestamps", None),
            ("wrong timestamps", shifted),
        ] {
            let mut reader = FrameReader::open(input, &opts, ts, source::DEFAULT_BUDGET_BYTES);
            let reader = reader.as_mut().unwrap();
            assert_eq!(reader.frame_count(), 120);
            for i in order {
                for size in sizes {
                    let got = decoded(&reader.read(i, size).unwrap());
                    let want = &want[&(i, size.width())];
                    assert_eq!(got.size().unwrap(), want.size().unwrap());
                    let diff = core::norm2(&got, want, core::NORM_INF, &Mat::default()).unwrap();
                    assert_eq!(diff, 0.0, "{} frame {i} {size:?}, {what}", input.display());
                }
            }
            let e = reader.read(120, FrameSize::Strip).unwrap_err().to_string();
            let named = e.contains("frame 120") && e.contains(&input.display().to_string());
            assert!(named, "{e}");
        }
        // Every frame twice, both sizes, in a budget of a few JPEGs: the cache stays within it
        // and serves a frame just read without decoding it again.
        let budget = 60_000;
        let mut reader = FrameReader::open(input, &opts, ts, budget).unwrap();
        for _ in 0..2 {
            for i in 0..120 {
                for size in sizes {
                    reader.read(i, size).unwrap();
                    assert!(reader.cached_bytes() <= budget, "{}", reader.cached_bytes());
                }
            }
        }
        assert!(
            reader.cached_bytes() > budget / 4,
            "{}",
            reader.cached_bytes()
        );
        let again = (
            reader.read(119, FrameSize::Large),
            reader.read(119, FrameSize::Large),
        );
        assert!(Arc::ptr_eq(&again.0.unwrap(), &again.1.unwrap()));
    }
}

/// The clip: 120 frames, 30 fps up to frame 50, frame 51 repeating frame 50's pts, then
/// 30 fps again to frame 60 and 15 fps after it (H.264 with B-frames in MP4).
fn vfr_clip(dir: &Path) -> PathBuf {
    let clip = dir.join("vfr.mp4");
    let pts = "if(lte(N,50),N,if(lte(N,60),N-1,59+2*(N-60)))/30/TB";
    let args = format!(
        "-f lavfi -i testsrc2=size=160x120:rate=30 -vf setpts='{pts}' -frames:v 120 \
         -fps_mode passthrough -c:v libx264 -pix_fmt yuv420p {}",
        s(&clip)
    );
    ffmpeg(&args.split_whitespace().collect::<Vec<_>>());
    clip
}

/// `ffprobe -show_frames`' best-effort timestamp of every frame, in seconds from the first.
fn ffprobe_best_effort(v: &Path) -> Vec<f64> {
    let o = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0", "-show_entries"])
        .args([
            "stream=time_base:frame=best_effort_timestamp",
            "-of",
            "compact=nk=1",
        ])
        .arg(v)
        .output()
        .unwrap();
    let text = String::from_utf8(o.stdout).unwrap();
    let field = |l: &str| l.split('|').nth(1).unwrap().to_string();
    let tb = text.lines().find(|l| l.starts_with("stream|")).map(field);
    let (num, den) = tb.as_deref().and_then(|t| t.split_once('/')).unwrap();
    let tb = num.parse::<f64>().unwrap() / den.parse::<f64>().unwrap();
    let ticks: Vec<i64> = text
        .lines()
        .filter(|l| l.starts_with("frame|"))
        .map(|l| field(l).parse().unwrap())
        .collect();
    ticks.iter().map(|t| (t - ticks[0]) as f64 * tb).collect()
}

/// Asserts that `project` caches `truth`'s timestamps within `tolerance` seconds, strictly
/// increasing.
fn assert_cached_timestamps(project: &Path, truth: &[f64], tolerance: f64) {
    let ts = json(project)["cache"]["timestamps_s"].clone();
    let ts: Vec<f64> = ts
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_f64().unwrap())
        .collect();
    assert_eq!(ts.len(), truth.len());
    assert!(ts.windows(2).all(|w| w[1] > w[0]), "{ts:?}");
    for (i, (t, want)) in ts.iter().zip(truth).enumerate() {
        assert!(
            (t - want).abs() < tolerance,
            "frame {i}: {t} s, ffprobe {want} s"
        );
    }
}

/// Every frame's timestamp is the stream's best-effort timestamp, as `ffprobe -show_frames`
/// prints it (from the first frame's), to the nanosecond: across frame-rate changes, where the
/// stream repeats a pts (frames 51-60 used to come 1/30 s late, frame 60 at 2.000 s), and for the
/// last frames, which the decoder drains without a position.
#[test]
fn vfr_timestamps_are_the_streams() {
    let d = tempfile::tempdir().unwrap();
    let clip = vfr_clip(d.path());
    let truth = ffprobe_best_effort(&clip);
    assert_eq!(truth.len(), 120);
    assert!(truth.windows(2).all(|w| w[1] > w[0]), "{truth:?}");
    assert!((truth[60] - 59.0 / 30.0).abs() < 1e-3, "{}", truth[60]);
    let p = d.path().join("p.json");
    kf_ok(&["select", s(&clip), "--every", "1", "-o", s(&p)]);
    assert_cached_timestamps(&p, &truth, 1e-9);
}

/// Without ffprobe the timestamps come from OpenCV, and a warning says so; a repeated pts no
/// longer pushes the frames after it late.
#[test]
fn without_ffprobe_timestamps_come_from_opencv() {
    let d = tempfile::tempdir().unwrap();
    let clip = vfr_clip(d.path());
    let truth = ffprobe_best_effort(&clip);
    let p = d.path().join("p.json");
    let out = Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args(["select", s(&clip), "--every", "1", "-o", s(&p), "--quiet"])
        .env("PATH", d.path())
        .output()
        .unwrap();
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("cannot run `ffprobe`") && err.contains("timestamps come from OpenCV"),
        "{err}"
    );
    assert_cached_timestamps(&p, &truth, 1e-3);
}

/// A FIFO given as the input is refused at once (it used to hang with no message).
#[test]
fn fifo_input_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let fifo = d.path().join("v.mp4");
    let made = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    let p = d.path().join("p.json");
    // A FIFO as the telemetry file of a real video (an extension that is neither .gpx nor .srt,
    // so the reader would sniff its first bytes).
    let video = testsrc(d.path(), "real.mp4", 64, 48, "10", 1.0);
    let track = d.path().join("track.dat");
    let made = Command::new("mkfifo").arg(&track).status().unwrap();
    assert!(made.success());
    for args in [
        vec!["select", s(&fifo), "-o", s(&p)],
        vec!["select", s(&fifo), "--preview", "-o", s(&p)],
        vec!["probe", s(&fifo)],
        vec!["select", s(&video), "--telemetry", s(&track), "-o", s(&p)],
    ] {
        let started = std::time::Instant::now();
        let out = Command::new("timeout")
            .arg("10")
            .arg(env!("CARGO_BIN_EXE_keyframer"))
            .args(&args)
            .output()
            .unwrap();
        let (code, err) = code_and_stderr(&out);
        assert_eq!(code, 1, "{args:?}: {err}");
        assert!(err.contains("not a regular file"), "{args:?}: {err}");
        assert!(started.elapsed().as_secs() < 5, "{args:?}");
    }
    assert!(!p.exists());
}

/// An H.264 clip too short to reorder as deep as its stream declares (x264's defaults declare 2;
/// 10 and 25 frames reorder 1 deep) still pairs with its packet list: the stream's own times, no
/// fallback warning.
#[test]
fn short_h264_clips_pair_with_their_packet_list() {
    let dir = tempfile::tempdir().unwrap();
    for (rate, n) in [(10, 10usize), (25, 25)] {
        let clip = testsrc(
            dir.path(),
            &format!("r{rate}.mp4"),
            128,
            96,
            &rate.to_string(),
            1.0,
        );
        let project = dir.path().join(format!("r{rate}.json"));
        let out = kf(&["select", s(&clip), "--every", "5", "-o", s(&project)]);
        let (code, err) = code_and_stderr(&out);
        assert_eq!(code, 0, "{err}");
        assert!(!err.contains("do not pair"), "{rate} fps: {err}");
        let ts: Vec<f64> = json(&project)["cache"]["timestamps_s"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| t.as_f64().unwrap())
            .collect();
        assert_eq!(ts.len(), n);
        for (i, t) in ts.iter().enumerate() {
            assert!(
                (t - i as f64 / rate as f64).abs() < 1e-9,
                "{rate} fps frame {i}: {t}"
            );
        }
    }
}
