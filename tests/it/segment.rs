//! Segmentation masks: exact masks from tiny generated ONNX models on both runtimes, refusal of
//! descriptions that do not fit their model, COLMAP mask files from `export`, and the shared
//! ENet / selfie models on public test images.

use crate::common::*;
use crate::onnx_model::{tiny_model, B1, B3, W1, W3};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BACKENDS: [&str; 2] = ["opencv", "ort"];

/// ONNX Runtime's library: ORT_DYLIB_PATH, else where scripts/setup.sh puts it.
fn ort_lib() -> PathBuf {
    let p = std::env::var_os("ORT_DYLIB_PATH")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("target/onnxruntime/libonnxruntime.so.1.31.1")
        });
    assert!(
        p.is_file(),
        "{} is missing: run scripts/setup.sh (it fetches ONNX Runtime)",
        p.display()
    );
    p
}

/// Runs keyframer quietly with ORT_DYLIB_PATH set.
fn kf_ort(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args(args)
        .arg("--quiet")
        .env("ORT_DYLIB_PATH", ort_lib())
        .output()
        .expect("run keyframer")
}

fn kf_ort_ok(args: &[&str]) -> String {
    let out = kf_ort(args);
    assert!(
        out.status.success(),
        "keyframer {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Whether scripts/setup.sh has fetched the selfie models the repository's descriptions name;
/// says that the test skips, and why, when it has not.
fn fetched_selfie() -> bool {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/models/selfie");
    let files = [
        "selfie_segmentation.onnx",
        "selfie_segmentation_landscape.onnx",
    ];
    let there = files.iter().all(|f| dir.join(f).is_file());
    if !there {
        eprintln!(
            "SKIPPED: {} lacks the selfie models: run scripts/setup.sh",
            dir.display()
        );
    }
    there
}

/// A copy in `dir` of the repository's description `name` with its `model` set to `model`.
fn retarget(dir: &Path, name: &str, model: &Path) -> String {
    let text = std::fs::read_to_string(repo_desc(name)).unwrap();
    let lines: Vec<String> = text
        .lines()
        .map(|l| match l.starts_with("model = ") {
            true => format!("model = {:?}", s(model)),
            false => l.to_string(),
        })
        .collect();
    let copy = dir.join(name);
    std::fs::write(&copy, lines.join("\n")).unwrap();
    s(&copy).to_string()
}

/// The project's models folder beside the repository (test assets only, see its README).
fn shared_model(file: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/models")
        .join(file);
    p.is_file().then_some(p)
}

/// A description of the ENet Cityscapes network (no registry ships it): the repository's own when
/// the network is where it points, else a copy in `dir` that names the shared one; None, saying
/// that the test skips, when neither is there.
fn enet_desc(dir: &Path) -> Option<String> {
    let own = repo_desc("enet-cityscapes.toml");
    let net =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("target/models/enet-cityscapes/enet-model.net");
    if net.is_file() {
        return Some(own);
    }
    match shared_model("enet-cityscapes/enet-model.net") {
        Some(shared) => Some(retarget(dir, "enet-cityscapes.toml", &shared)),
        None => {
            eprintln!(
                "SKIPPED: no ENet Cityscapes network at {} nor beside the repository (see {own})",
                net.display()
            );
            None
        }
    }
}

fn repo_desc(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("models")
        .join(name)
        .to_string_lossy()
        .into_owned()
}

/// Reads an 8-bit gray PNG: (width, height, pixels).
fn read_gray(p: &Path) -> (u32, u32, Vec<u8>) {
    let img = image::open(p)
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
        .into_luma8();
    (img.width(), img.height(), img.into_raw())
}

const PALETTE: [[u8; 3]; 8] = [
    [220, 30, 40],
    [20, 200, 60],
    [30, 40, 230],
    [250, 250, 20],
    [10, 240, 250],
    [240, 20, 240],
    [128, 128, 128],
    [60, 90, 200],
];

/// A w x h RGB image whose pixels come from the palette in a scrambled order.
pub fn palette_image(w: u32, h: u32) -> image::RgbImage {
    image::RgbImage::from_fn(w, h, |x, y| {
        let i = ((x * 7 + y * 13 + x * y) % PALETTE.len() as u32) as usize;
        image::Rgb(PALETTE[i])
    })
}

fn scores(rgb: [u8; 3], w: &[[f32; 3]], b: &[f32]) -> Vec<f32> {
    let x: Vec<f32> = rgb.iter().map(|&v| f32::from(v) * (1.0 / 255.0)).collect();
    w.iter()
        .zip(b)
        .map(|(row, bias)| row.iter().zip(&x).map(|(a, b)| a * b).sum::<f32>() + bias)
        .collect()
}

/// Expected class of a palette colour, asserting the decision is not a near tie.
fn expected_class(rgb: [u8; 3], probability: bool) -> usize {
    if probability {
        let s = scores(rgb, &W1, &B1)[0];
        assert!(s.abs() > 0.05, "palette colour {rgb:?} is a near tie");
        usize::from(s >= 0.0)
    } else {
        let s = scores(rgb, &W3, &B3);
        let best = (0..3).fold(0, |b, k| if s[k] > s[b] { k } else { b });
        for k in 0..3 {
            assert!(
                k == best || s[best] - s[k] > 0.05,
                "palette colour {rgb:?} is a near tie"
            );
        }
        best
    }
}

#[test]
fn tiny_onnx_models_give_the_exact_mask_on_both_backends() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let img = palette_image(12, 8);
    let img_path = d.join("palette.png");
    img.save(&img_path).unwrap();

    for (probability, hide) in [(false, "green"), (true, "hide")] {
        let desc = tiny_model(d, &format!("tiny_p{probability}"), probability, Some(1), "");
        let expected: Vec<u8> = img
            .pixels()
            .map(|p| {
                // Class 1 is hidden in both models ("green", "hide").
                if expected_class(p.0, probability) == 1 {
                    0
                } else {
                    255
                }
            })
            .collect();
        assert!(expected.contains(&0) && expected.contains(&255));
        for backend in BACKENDS {
            let mask = d.join(format!("mask_{probability}_{backend}.png"));
            kf_ort_ok(&[
                "segment",
                s(&img_path),
                "--model",
                s(&desc),
                "-o",
                s(&mask),
                "--classes",
                hide,
                "--backend",
                backend,
            ]);
            let (w, h, px) = read_gray(&mask);
            assert_eq!((w, h), (12, 8));
            assert_eq!(px, expected, "probability={probability} backend={backend}");
        }
    }
}

#[test]
fn descriptions_that_do_not_fit_the_model_are_refused_before_any_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let img_path = d.join("palette.png");
    palette_image(12, 8).save(&img_path).unwrap();
    let good = tiny_model(d, "tiny", false, Some(1), "");
    let text = std::fs::read_to_string(&good).unwrap();

    let wrong_size = d.join("wrong_size.toml");
    std::fs::write(&wrong_size, text.replace("width = 12", "width = 16")).unwrap();
    let wrong_classes = d.join("wrong_classes.toml");
    std::fs::write(
        &wrong_classes,
        text.replace(
            r#"["red", "green", "blue"]"#,
            r#"["red", "green", "blue", "black"]"#,
        ),
    )
    .unwrap();
    let missing_model = d.join("missing_model.toml");
    std::fs::write(&missing_model, text.replace("tiny.onnx", "nowhere.onnx")).unwrap();
    let bad_key = d.join("bad_key.toml");
    std::fs::write(
        &bad_key,
        text.replace("layout = \"nchw\"", "layout = \"chw\""),
    )
    .unwrap();

    let cases: [(&Path, &str, &[&str]); 5] = [
        (
            &wrong_size,
            "green",
            &["does not match", "width 16", "1x3x8x12"],
        ),
        (
            &wrong_classes,
            "green",
            &["does not match", "3 channels", "4 classes"],
        ),
        (
            &missing_model,
            "green",
            &["missing_model.toml:", "nowhere.onnx", "does not exist"],
        ),
        (&bad_key, "green", &["bad_key.toml:", "input.layout", "chw"]),
        (
            &good,
            "pedestrian",
            &["`pedestrian` is not a class", "red, green, blue"],
        ),
    ];
    for backend in BACKENDS {
        for (desc, class, needles) in &cases {
            let mask = d.join("mask.png");
            let out = kf_ort(&[
                "segment",
                s(&img_path),
                "--model",
                s(desc),
                "-o",
                s(&mask),
                "--classes",
                class,
                "--backend",
                backend,
            ]);
            let (code, err) = code_and_stderr(&out);
            assert_eq!(code, 1, "{backend} {}: {err}", desc.display());
            for n in *needles {
                assert!(
                    err.contains(n),
                    "{backend} {}: `{n}` not in: {err}",
                    desc.display()
                );
            }
            assert_eq!(err.lines().count(), 1, "one line: {err}");
            assert!(!mask.exists(), "nothing written");
        }
    }

    // Export refuses before creating its folder.
    let clip = testsrc(d, "clip.mp4", 64, 48, "10", 1.0);
    let project = d.join("p.json");
    kf_ok(&["select", s(&clip), "-o", s(&project), "--every", "3"]);
    for desc in [&wrong_size, &wrong_classes] {
        let out_dir = d.join("export");
        let out = kf_ort(&[
            "export",
            s(&project),
            "--out",
            s(&out_dir),
            "--masks",
            s(desc),
            "--mask-classes",
            "green",
        ]);
        let (code, err) = code_and_stderr(&out);
        assert_eq!(code, 1, "{err}");
        assert!(err.contains("does not match"), "{err}");
        assert!(!out_dir.exists(), "export folder created despite the error");
    }

    // ONNX Runtime absent: a clear error, no panic.
    let out = Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args([
            "segment",
            s(&img_path),
            "--model",
            s(&good),
            "-o",
            s(&d.join("m.png")),
        ])
        .args(["--classes", "red", "--backend", "ort", "--quiet"])
        .env("ORT_DYLIB_PATH", d.join("no-such-libonnxruntime.so"))
        .output()
        .unwrap();
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("ONNX Runtime library") && err.contains("does not exist"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn export_writes_one_colmap_mask_per_image() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Dynamic batch dimension: the export runs batches of 3 (the description's `batch`).
    let desc = tiny_model(d, "tiny_dyn", false, None, "hide = [\"green\"]");
    let clip = testsrc(d, "clip.mp4", 160, 120, "10", 2.0);
    let project = d.join("p.json");
    kf_ok(&["select", s(&clip), "-o", s(&project), "--every", "3"]);
    let n = keyframes(&project).len();
    assert_eq!(n, 7);

    for backend in BACKENDS {
        let out_dir = d.join(format!("export_{backend}"));
        kf_ort_ok(&[
            "export",
            s(&project),
            "--out",
            s(&out_dir),
            "--resize",
            "48x32",
            "--format",
            "png",
            "--masks",
            s(&desc),
            "--mask-backend",
            backend,
            "--mask-overlay",
        ]);
        let manifest = json(&out_dir.join("manifest.json"));
        let frames = manifest["frames"].as_array().unwrap();
        assert_eq!(frames.len(), n);
        let masks = listing(&out_dir.join("masks"));
        assert_eq!(masks.len(), n, "one mask per image: {masks:?}");
        assert_eq!(listing(&out_dir.join("overlays")).len(), n);
        let mut hidden = 0;
        for f in frames {
            let file = f["file"].as_str().unwrap();
            assert_eq!(f["mask"].as_str().unwrap(), format!("{file}.png"));
            let (w, h, px) = read_gray(&out_dir.join("masks").join(format!("{file}.png")));
            assert_eq!((w, h), (48, 32), "mask has the exported image's size");
            assert!(
                px.iter().all(|&v| v == 0 || v == 255),
                "values 0 and 255 only"
            );
            hidden += px.iter().filter(|&&v| v == 0).count();
            // The batched export gives the same mask as segmenting the exported image alone.
            let single = d.join("single.png");
            kf_ort_ok(&[
                "segment",
                s(&out_dir.join("images").join(file)),
                "--model",
                s(&desc),
                "-o",
                s(&single),
                "--backend",
                backend,
                "--force",
            ]);
            assert_eq!(read_gray(&single).2, px, "{file}");
        }
        assert!(hidden > 0, "testsrc2 has green areas; none hidden");

        // A forced re-export without masks removes the masks it no longer writes.
        kf_ok(&[
            "export",
            s(&project),
            "--out",
            s(&out_dir),
            "--force",
            "--format",
            "png",
        ]);
        assert!(listing(&out_dir.join("masks")).is_empty());
        assert!(listing(&out_dir.join("overlays")).is_empty());
    }
}

/// The export layout is COLMAP-ready as it is: `colmap feature_extractor --image_path OUT/images
/// --ImageReader.mask_path OUT/masks` (COLMAP reads image folders recursively) puts exactly the
/// exported images into its database, each with its mask.
#[test]
fn colmap_reads_exactly_the_exported_images_beside_their_masks() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let desc = tiny_model(d, "tiny_dyn", false, None, "hide = [\"green\"]");
    let clip = testsrc(d, "clip.mp4", 320, 240, "10", 2.0);
    let project = d.join("p.json");
    kf_ok(&["select", s(&clip), "-o", s(&project), "--every", "5"]);
    let out = d.join("export");
    kf_ok(&[
        "export",
        s(&project),
        "--out",
        s(&out),
        "--masks",
        s(&desc),
        "--mask-backend",
        "opencv",
        "--mask-overlay",
    ]);
    let exported = listing(&out.join("images"));
    assert_eq!(exported.len(), 4, "{exported:?}");
    assert_eq!(
        listing(&out),
        vec!["images", "manifest.json", "masks", "overlays"]
    );
    let db = d.join("database.db");
    let o = std::process::Command::new("colmap")
        .args([
            "feature_extractor",
            "--database_path",
            s(&db),
            "--image_path",
        ])
        .arg(out.join("images"))
        .arg("--ImageReader.mask_path")
        .arg(out.join("masks"))
        .args(["--SiftExtraction.use_gpu", "0"])
        .output()
        .expect("colmap is installed (scripts/setup.sh)");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The database's image names, read with Python's sqlite3.
    let q = std::process::Command::new("python3")
        .args([
            "-c",
            "import sqlite3,sys; print('\\n'.join(r[0] for r in sqlite3.connect(sys.argv[1]).execute('select name from images order by name')))",
            s(&db),
        ])
        .output()
        .expect("python3");
    assert!(q.status.success(), "{}", String::from_utf8_lossy(&q.stderr));
    let names: Vec<String> = String::from_utf8(q.stdout)
        .unwrap()
        .lines()
        .map(str::to_string)
        .collect();
    assert_eq!(
        names, exported,
        "the database holds exactly the exported images"
    );
    for n in &exported {
        assert!(out.join("masks").join(format!("{n}.png")).is_file(), "{n}");
    }
}

/// Pixels that move between frames of vtest.avi (a static camera): the walking people.
fn moving_pixels(video: &Path, index: usize) -> (usize, usize, Vec<bool>) {
    use opencv::core::{absdiff, Mat};
    use opencv::prelude::*;
    use opencv::{imgproc, videoio};
    let mut cap = videoio::VideoCapture::from_file(s(video), videoio::CAP_FFMPEG).unwrap();
    let mut frames = Vec::new();
    let mut m = Mat::default();
    for i in 0..=index + 4 {
        assert!(cap.read(&mut m).unwrap());
        if i + 4 == index || i == index || i == index + 4 {
            let mut g = Mat::default();
            imgproc::cvt_color_def(&m, &mut g, imgproc::COLOR_BGR2GRAY).unwrap();
            frames.push(g);
        }
    }
    let mut a = Mat::default();
    let mut b = Mat::default();
    absdiff(&frames[1], &frames[0], &mut a).unwrap();
    absdiff(&frames[1], &frames[2], &mut b).unwrap();
    let (w, h) = (a.cols() as usize, a.rows() as usize);
    let pa = a.data_bytes().unwrap();
    let pb = b.data_bytes().unwrap();
    (
        w,
        h,
        pa.iter().zip(pb).map(|(&x, &y)| x > 30 || y > 30).collect(),
    )
}

#[test]
fn enet_hides_the_walking_people_in_vtest() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let Some(enet) = enet_desc(d) else {
        return;
    };
    let video = testdata("opencv-doc/vtest.avi");
    let project = d.join("p.json");
    kf_ok(&[
        "select",
        s(&video),
        "-o",
        s(&project),
        "--start",
        "100",
        "--every",
        "200",
    ]);
    let keys = keyframes(&project);
    assert_eq!(keys, vec![100, 300, 500, 700]);
    let out_dir = d.join("export");
    let err = kf_ort_ok(&[
        "export",
        s(&project),
        "--out",
        s(&out_dir),
        "--format",
        "png",
        "--masks",
        &enet,
        "--mask-classes",
        "person",
    ]);
    eprintln!("{err}");
    for k in keys {
        let (w, h, mask) = read_gray(&out_dir.join(format!("masks/frame_{k:06}.png.png")));
        let (mw, mh, moving) = moving_pixels(&video, k);
        assert_eq!((w as usize, h as usize), (mw, mh));
        let hidden: Vec<bool> = mask.iter().map(|&v| v == 0).collect();
        let n_hidden = hidden.iter().filter(|&&x| x).count();
        let n_moving = moving.iter().filter(|&&x| x).count();
        let both = hidden
            .iter()
            .zip(&moving)
            .filter(|(a, b)| **a && **b)
            .count();
        let kept = 1.0 - n_hidden as f64 / hidden.len() as f64;
        eprintln!(
            "frame {k}: hidden {n_hidden} px, moving {n_moving} px, both {both}, kept {:.1}%",
            kept * 100.0
        );
        assert!(
            kept > 0.9,
            "most of the scene (ground, grass, buildings) is kept"
        );
        // Most hidden pixels are near moving ones (dilate the motion by the walking step).
        let near_moving = dilate(&moving, w as usize, h as usize, 6);
        let hidden_near = hidden
            .iter()
            .zip(&near_moving)
            .filter(|(a, b)| **a && **b)
            .count();
        assert!(
            hidden_near as f64 >= 0.6 * n_hidden as f64,
            "hidden pixels are on the people: {hidden_near} of {n_hidden}"
        );
        // ENet marks only parts of the small, distant people of vtest as Person (frame 300: ~4 %
        // of the moving pixels; reported in issue 6's note), so this asks for pixels on the people
        // being hidden in every frame, as the acceptance does, not for whole silhouettes.
        assert!(
            both >= 100,
            "pixels on the walking people are hidden: {both} of {n_moving}"
        );
    }
}

fn dilate(m: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let mut out = vec![false; m.len()];
    for y in 0..h {
        for x in 0..w {
            if m[y * w + x] {
                for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                        out[yy * w + xx] = true;
                    }
                }
            }
        }
    }
    out
}

#[test]
fn selfie_model_masks_agree_between_backends() {
    if !fetched_selfie() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let vt = d.join("vtest300.png");
    ffmpeg(&[
        "-i",
        s(&testdata("opencv-doc/vtest.avi")),
        "-vf",
        "select=eq(n\\,300)",
        "-frames:v",
        "1",
        s(&vt),
    ]);
    let images = [
        testdata("opencv-doc/messi5.jpg"),
        testdata("opencv-doc/basketball1.png"),
        vt,
    ];
    for desc in ["selfie.toml", "selfie-landscape.toml"] {
        for img in &images {
            let mut masks = Vec::new();
            for backend in BACKENDS {
                let m = d.join(format!("{backend}.png"));
                kf_ort_ok(&[
                    "segment",
                    s(img),
                    "--model",
                    &repo_desc(desc),
                    "-o",
                    s(&m),
                    "--backend",
                    backend,
                    "--force",
                ]);
                masks.push(read_gray(&m).2);
            }
            let a: Vec<bool> = masks[0].iter().map(|&v| v == 0).collect();
            let b: Vec<bool> = masks[1].iter().map(|&v| v == 0).collect();
            let inter = a.iter().zip(&b).filter(|(x, y)| **x && **y).count();
            let union = a.iter().zip(&b).filter(|(x, y)| **x || **y).count();
            let iou = if union == 0 {
                1.0
            } else {
                inter as f64 / union as f64
            };
            eprintln!("{desc} {}: hidden {union} px, IoU {iou:.5}", img.display());
            assert!(iou >= 0.99, "{desc} {}: IoU {iou}", img.display());
        }
    }
}

/// The selfie models that set-up converts (scripts/tflite-onnx.py) give exactly the masks of the
/// shared ONNX conversions of the same MediaPipe models, on both backends (when those are there).
#[test]
fn fetched_selfie_models_give_the_masks_of_the_shared_conversion() {
    if !fetched_selfie() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let images = [
        testdata("opencv-doc/messi5.jpg"),
        testdata("opencv-doc/basketball1.png"),
    ];
    for (desc, file) in [
        ("selfie.toml", "selfie_segmentation.onnx"),
        (
            "selfie-landscape.toml",
            "selfie_segmentation_landscape.onnx",
        ),
    ] {
        let Some(shared) = shared_model(&format!("selfie/{file}")) else {
            eprintln!("SKIPPED: no shared {file} beside the repository to compare with");
            return;
        };
        let shared_desc = retarget(d, desc, &shared);
        let mut hidden = 0;
        for img in &images {
            for backend in BACKENDS {
                let masks: Vec<Vec<u8>> = [repo_desc(desc), shared_desc.clone()]
                    .iter()
                    .enumerate()
                    .map(|(i, model)| {
                        let m = d.join(format!("{i}.png"));
                        kf_ort_ok(&[
                            "segment",
                            s(img),
                            "--model",
                            model,
                            "-o",
                            s(&m),
                            "--backend",
                            backend,
                            "--force",
                        ]);
                        read_gray(&m).2
                    })
                    .collect();
                let n = masks[0].iter().filter(|&&v| v == 0).count();
                eprintln!("{desc} {} {backend}: {n} px hidden", img.display());
                assert!(masks[0] == masks[1], "{desc} {} {backend}", img.display());
                hidden += n;
            }
        }
        assert!(hidden > 0, "{desc} hides the people of the images");
    }
}
