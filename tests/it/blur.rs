//! Blur sampler on a synthetic clip with blurred frames injected at known positions.

use crate::common::*;
use opencv::core::{self, Mat, Rect, Scalar, Size, Vector, CV_32F};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};
use std::path::{Path, PathBuf};

/// Injected blurred frames: (index, description). About 10 % of 120 frames; strengths cycle
/// through Gaussian sigma 1, 2, 3 and motion blur of 5, 9, 15 px (horizontal and diagonal).
pub const INJECTED: [usize; 12] = [7, 15, 23, 35, 42, 50, 64, 71, 85, 93, 100, 112];
pub const FRAMES: usize = 120;

fn blur_frame(img: &Mat, k: usize) -> Mat {
    let mut out = Mat::default();
    match k % 6 {
        0..=2 => {
            let sigma = (k % 6 + 1) as f64;
            imgproc::gaussian_blur(
                img,
                &mut out,
                Size::new(0, 0),
                sigma,
                sigma,
                core::BORDER_DEFAULT,
            )
            .unwrap();
        }
        m => {
            let len = [5, 9, 15][m - 3];
            let mut kernel =
                Mat::new_rows_cols_with_default(len, len, CV_32F, Scalar::all(0.0)).unwrap();
            for i in 0..len {
                let (r, c) = if m == 4 { (i, i) } else { (len / 2, i) };
                *kernel.at_2d_mut::<f32>(r, c).unwrap() = 1.0 / len as f32;
            }
            imgproc::filter_2d(
                img,
                &mut out,
                -1,
                &kernel,
                core::Point::new(-1, -1),
                0.0,
                core::BORDER_DEFAULT,
            )
            .unwrap();
        }
    }
    out
}

/// A 120-frame 320x180 pan over a real photo (opencv-doc aloeL.jpg), H.264 at high quality, with
/// the INJECTED frames blurred.
pub fn blur_clip(dir: &Path) -> PathBuf {
    let photo = imgcodecs::imread(
        testdata("opencv-doc/aloeL.jpg").to_str().unwrap(),
        imgcodecs::IMREAD_COLOR,
    )
    .unwrap();
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for i in 0..FRAMES {
        // Pan right 5 px and down 1 px per frame at 640x360, shown at 320x180.
        let roi = Rect::new(20 + 5 * i as i32, 100 + i as i32, 640, 360);
        let crop = Mat::roi(&photo, roi).unwrap().try_clone().unwrap();
        let mut small = Mat::default();
        imgproc::resize(
            &crop,
            &mut small,
            Size::new(320, 180),
            0.0,
            0.0,
            imgproc::INTER_AREA,
        )
        .unwrap();
        let frame = match INJECTED.iter().position(|&j| j == i) {
            Some(k) => blur_frame(&small, k),
            None => small,
        };
        imgcodecs::imwrite(
            frames.join(format!("f{i:04}.png")).to_str().unwrap(),
            &frame,
            &Vector::new(),
        )
        .unwrap();
    }
    let clip = dir.join("blur.mp4");
    encode_frames(&frames, "12", &clip);
    clip
}

fn select(clip: &Path, project: &Path, extra: &[&str]) -> Vec<usize> {
    let mut args = vec!["select", s(clip), "-o", s(project), "--force", "--blur"];
    args.extend_from_slice(extra);
    kf_ok(&args);
    keyframes(project)
}

#[test]
fn filter_and_replace_on_injected_blur() {
    let d = tempfile::tempdir().unwrap();
    let clip = blur_clip(d.path());
    for metric in ["tenengrad", "laplacian", "laplacian-k3"] {
        let mut by_backend = Vec::new();
        for backend in ["gpu", "opencv"] {
            let p = d.path().join(format!("{metric}-{backend}.json"));
            let keys = select(&clip, &p, &["--blur-metric", metric, "--backend", backend]);
            let json = json(&p);
            let used = json["cache"]["sharpness"][0]["backend"]
                .as_str()
                .unwrap()
                .to_string();
            assert_eq!(used, backend, "backend really used");
            for j in INJECTED {
                assert!(
                    !keys.contains(&j),
                    "{metric}/{backend}: blurred frame {j} kept"
                );
            }
            let sharp = FRAMES - INJECTED.len();
            let kept = keys.iter().filter(|k| !INJECTED.contains(k)).count();
            assert!(
                kept * 100 >= sharp * 95,
                "{metric}/{backend}: kept {kept} of {sharp} sharp frames"
            );

            let r = d.path().join(format!("{metric}-{backend}-replace.json"));
            let replaced = select(
                &clip,
                &r,
                &[
                    "--blur-metric",
                    metric,
                    "--backend",
                    backend,
                    "--every",
                    "5",
                    "--blur-mode",
                    "replace",
                    "--blur-window",
                    "2",
                ],
            );
            assert_eq!(replaced.len(), FRAMES / 5);
            for k in &replaced {
                assert!(
                    !INJECTED.contains(k),
                    "{metric}/{backend}: replace landed on blurred frame {k}"
                );
            }
            by_backend.push((keys, replaced));
        }
        assert_eq!(
            by_backend[0], by_backend[1],
            "{metric}: gpu and opencv select different keyframes"
        );
    }
}

/// Re-selecting with another ratio reads the cached scores: nothing is decoded. Shown two ways:
/// the run says so, and it still succeeds with the same frame data after everything past the
/// fingerprinted first MiB of the video was zeroed (size and mtime kept), which no decoder could
/// read past.
#[test]
fn reselect_uses_the_score_cache() {
    let d = tempfile::tempdir().unwrap();
    let clip = d.path().join("big.mp4");
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "testsrc2=size=640x360:rate=30:duration=6",
        "-vf",
        "noise=alls=30:allf=t",
        "-c:v",
        "libx264",
        "-crf",
        "8",
        "-pix_fmt",
        "yuv420p",
        s(&clip),
    ]);
    let len = std::fs::metadata(&clip).unwrap().len();
    assert!(len > 3 << 20, "clip must be well over 1 MiB, is {len}");
    let p = d.path().join("p.json");
    kf_ok(&["select", s(&clip), "-o", s(&p), "--blur"]);
    let before = json(&p);

    let mtime = std::fs::metadata(&clip).unwrap().modified().unwrap();
    let mut bytes = std::fs::read(&clip).unwrap();
    bytes[1 << 20..].fill(0);
    std::fs::write(&clip, &bytes).unwrap();
    std::fs::File::options()
        .write(true)
        .open(&clip)
        .unwrap()
        .set_modified(mtime)
        .unwrap();

    let run = |extra: &[&str]| {
        let mut args = vec!["select", s(&clip), "-o", s(&p), "--force", "--blur"];
        args.extend_from_slice(extra);
        kf_loud(&args)
    };
    let out = run(&["--blur-ratio", "1.05"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && err.contains("nothing decoded"),
        "{err}"
    );
    let strict = keyframes(&p);
    let out = run(&["--blur-ratio", "0.5"]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("nothing decoded"));
    let loose = keyframes(&p);
    assert!(
        strict.len() < loose.len(),
        "ratio changes the selection: {} vs {}",
        strict.len(),
        loose.len()
    );
    let after = json(&p);
    assert_eq!(
        after["cache"]["sharpness"], before["cache"]["sharpness"],
        "scores come from the cache"
    );
    assert_eq!(after["metadata"]["frame_count"], 180);

    // Control: a metric that is not cached needs the pixels, and the zeroed stream shows.
    let out = run(&["--blur-metric", "laplacian"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("nothing decoded"), "{err}");
    let decoded = json(&p)["metadata"]["frame_count"].as_u64().unwrap();
    assert!(
        !out.status.success() || decoded < 180,
        "the damaged file decoded fully? {err}"
    );
}

#[test]
fn score_command_prints_per_frame_scores() {
    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "c.mp4", 160, 90, "30", 1.0);
    let v: serde_json::Value = serde_json::from_str(&kf_ok(&[
        "score",
        s(&clip),
        "--metric",
        "laplacian-k3",
        "--json",
    ]))
    .unwrap();
    assert_eq!(v["scores"].as_array().unwrap().len(), 30);
    assert_eq!(v["metric"], "laplacian-k3");
    let text = kf_ok(&["score", s(&clip), "--backend", "opencv"]);
    assert_eq!(text.lines().count(), 30);
    // Single images work too.
    let img = Path::new(env!("CARGO_MANIFEST_DIR")).join("reference/inputs/text_motion.jpg");
    let v: serde_json::Value = serde_json::from_str(&kf_ok(&["score", s(&img), "--json"])).unwrap();
    let stored: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("reference/sharpness/text_motion.jpg__tenengrad.json"),
        )
        .unwrap(),
    )
    .unwrap();
    let (a, b) = (
        v["scores"][0].as_f64().unwrap(),
        stored["score"].as_f64().unwrap(),
    );
    assert!(
        keyframer::kernels::tolerance::rel_err(a, b)
            <= keyframer::kernels::tolerance::SHARPNESS_REL
    );
}
