//! The similarity step on a clip assembled from five slow pans over four photos, the first one
//! seen again at the end: `--similarity K` keeps ⌈n/K⌉ frames, the one nearest each scene's mean
//! embedding (computed here from the cached embeddings, not by keyframer's k-means), the same on
//! both backends and across runs; `--similarity-threshold` keeps one frame per scene and leaves
//! the revisit out; re-selection reads the cache (nothing decoded); the GPU descriptor equals its
//! OpenCV twin; the workflow round trip and the review page.

use crate::common::*;
use crate::review::Served;
use opencv::core::{Mat, Rect, Size, Vector};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};
use std::path::{Path, PathBuf};

/// Frames per scene.
pub(crate) const SCENE: usize = 12;
/// The photos panned over, in order; the first comes back as the fifth scene.
const PHOTOS: [&str; 5] = [
    "baboon.jpg",
    "building.jpg",
    "butterfly.jpg",
    "board.jpg",
    "baboon.jpg",
];

/// The clip (320x180, 30 fps): per scene a 2-pixel-per-frame pan over a 400x225 window of its
/// photo (the revisit starts 1 pixel later than the first visit). Returns it with each frame's
/// scene group (the revisit is group 0).
pub(crate) fn scenes_clip(dir: &Path) -> (PathBuf, Vec<usize>) {
    let frames = dir.join("scenes-frames");
    std::fs::create_dir_all(&frames).unwrap();
    let mut groups = Vec::new();
    for (scene, name) in PHOTOS.iter().enumerate() {
        let photo = imgcodecs::imread(
            testdata(&format!("opencv-doc/{name}")).to_str().unwrap(),
            imgcodecs::IMREAD_COLOR,
        )
        .unwrap();
        let start = if scene == 4 { 1 } else { 0 };
        for j in 0..SCENE {
            let x = start + 2 * j as i32;
            let crop = Mat::roi(&photo, Rect::new(x, 10, 400, 225)).unwrap();
            let mut small = Mat::default();
            let to = Size::new(320, 180);
            imgproc::resize(&crop, &mut small, to, 0.0, 0.0, imgproc::INTER_AREA).unwrap();
            let i = scene * SCENE + j;
            let path = frames.join(format!("f{i:04}.png"));
            imgcodecs::imwrite(path.to_str().unwrap(), &small, &Vector::new()).unwrap();
            groups.push(if scene == 4 { 0 } else { scene });
        }
    }
    let clip = dir.join("scenes.mp4");
    encode_frames(&frames, "12", &clip);
    (clip, groups)
}

/// The cached embeddings of a project, decoded independently of keyframer (16-bit two's
/// complement hex per component, renormalised).
fn embeddings(project: &Path) -> Vec<Vec<f64>> {
    assert_eq!(
        json(project)["cache"]["embeddings"][0]["embedder"],
        "builtin-grid-hog-colour-v1"
    );
    embeddings_of(project, 0)
}

fn cos_dist(a: &[f64], b: &[f64]) -> f64 {
    1.0 - a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>()
}

pub(crate) fn select(clip: &Path, p: &Path, args: &[&str]) -> (i32, String) {
    let mut all = vec!["select", s(clip), "-o", s(p), "--force"];
    all.extend(args);
    code_and_stderr(&kf(&all))
}

#[test]
fn similarity_keeps_one_frame_per_cluster_and_leaves_revisits_out() {
    let tmp = tempfile::tempdir().unwrap();
    let (clip, groups) = scenes_clip(tmp.path());
    let n = groups.len();
    let k_arg = 15;
    let clusters = n.div_ceil(k_arg);
    assert_eq!(clusters, 4, "the clip has four distinct scenes");

    // Both backends, twice each: the same embeddings byte for byte and the same keyframes.
    let mut runs = Vec::new();
    for backend in ["gpu", "opencv", "gpu", "opencv"] {
        let p = tmp.path().join(format!("p-{backend}.json"));
        let (code, err) = select(&clip, &p, &["--similarity", "15", "--backend", backend]);
        assert_eq!(code, 0, "{err}");
        let project = json(&p);
        let series = project["cache"]["embeddings"][0].clone();
        assert_eq!(series["backend"], backend, "{backend}");
        runs.push((keyframes(&p), series_bytes(&p, 0), p));
    }
    for r in &runs[1..] {
        assert_eq!(r.0, runs[0].0, "keyframes differ between runs/backends");
        assert_eq!(r.1, runs[0].1, "embeddings differ between runs/backends");
    }
    let (keys, _, p) = &runs[1];
    assert_eq!(keys.len(), clusters, "{keys:?}");

    // The scenes are apart in embedding space: every frame is nearer to each frame of its own
    // scene group (the revisit included) than to any frame of another.
    let e = embeddings(p);
    assert_eq!(e.len(), n);
    let mut within: f64 = 0.0;
    let mut across = f64::INFINITY;
    for i in 0..n {
        for j in 0..n {
            let d = cos_dist(&e[i], &e[j]);
            match groups[i] == groups[j] {
                true => within = within.max(d),
                false => across = across.min(d),
            }
        }
    }
    assert!(within < across, "within {within} across {across}");

    // One keyframe per scene group, the frame nearest the group's mean embedding.
    let mut want = Vec::new();
    for g in 0..clusters {
        let members: Vec<usize> = (0..n).filter(|&i| groups[i] == g).collect();
        let dim = e[0].len();
        let mean: Vec<f64> = (0..dim)
            .map(|c| members.iter().map(|&i| e[i][c]).sum::<f64>() / members.len() as f64)
            .collect();
        let d2 = |i: usize| -> f64 { e[i].iter().zip(&mean).map(|(a, b)| (a - b) * (a - b)).sum() };
        let best = members
            .iter()
            .copied()
            .min_by(|&a, &b| d2(a).total_cmp(&d2(b)).then(a.cmp(&b)))
            .unwrap();
        want.push(best);
    }
    want.sort_unstable();
    assert_eq!(keys, &want);
    let history = json(p)["history"].clone();
    let step = (history.as_array().unwrap().iter())
        .find(|h| h["plugin"] == "similarity")
        .unwrap()
        .clone();
    assert_eq!(step["params"]["clusters"], clusters);
    assert_eq!(step["params"]["k"], k_arg);

    // Threshold mode on the cache: one frame per scene, the revisit left out.
    let d = (within + across) / 2.0;
    let d_arg = format!("{d}");
    let (code, err) = select(&clip, p, &["--similarity-threshold", &d_arg]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("nothing decoded"), "{err}");
    assert_eq!(keyframes(p), [0, SCENE, 2 * SCENE, 3 * SCENE]);
    // Another K re-selects from the cache too.
    let (code, err) = select(&clip, p, &["--similarity", "6"]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("nothing decoded"), "{err}");
    assert_eq!(keyframes(p).len(), n.div_ceil(6));
    // Both modes at once are refused, naming the flags.
    let (code, err) = select(
        &clip,
        p,
        &["--similarity", "6", "--similarity-threshold", "0.1"],
    );
    assert_ne!(code, 0, "{err}");
    assert!(
        err.contains("cannot be used with '--similarity-threshold"),
        "{err}"
    );
}

/// The GPU descriptor (lavapipe in the tests) gives exactly the OpenCV twin's totals on real
/// photos and on odd sizes that are not multiples of the 16x16 workgroup.
#[test]
fn descriptor_kernel_equals_its_opencv_twin() {
    use keyframer::kernels::{descriptor, tolerance};
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None).unwrap());
    let mut inputs: Vec<Mat> = ["baboon.jpg", "building.jpg", "HappyFish.jpg"]
        .iter()
        .map(|n| {
            let path = testdata(&format!("opencv-doc/{n}"));
            imgcodecs::imread(path.to_str().unwrap(), imgcodecs::IMREAD_COLOR).unwrap()
        })
        .collect();
    inputs.push(keyframer::synthetic::pattern(37, 83, 1).unwrap());
    inputs.push(keyframer::synthetic::pattern(641, 359, 2).unwrap());
    for (i, image) in inputs.iter().enumerate() {
        for width in [320u32, 97] {
            let size =
                keyframer::analysis::analysis_size(image.cols() as u32, image.rows() as u32, width);
            let small = descriptor::prepare(image, size).unwrap();
            let mut gpu = descriptor::DescriptorGpu::new(ctx.clone(), size).unwrap();
            let got = gpu.totals(&small).unwrap();
            let want = descriptor::opencv(&small).unwrap();
            assert_eq!(got.len(), descriptor::TOTALS);
            let worst = got.iter().zip(&want).map(|(a, b)| a.abs_diff(*b)).max();
            assert!(
                worst <= Some(tolerance::DESCRIPTOR_TOTALS_ABS),
                "input {i} at {size:?}: {got:?} vs {want:?}"
            );
            assert!(want[..descriptor::COLOUR_AT].iter().any(|&t| t > 0));
        }
    }
}

/// `workflow save` writes the step, `run` repeats the selection; the review page offers the
/// step when the cache has embeddings and applies it as `select` does.
#[test]
fn similarity_workflow_and_review() {
    let tmp = tempfile::tempdir().unwrap();
    let (clip, _) = scenes_clip(tmp.path());
    let p = tmp.path().join("p.json");
    let (code, err) = select(&clip, &p, &["--similarity", "10", "--backend", "opencv"]);
    assert_eq!(code, 0, "{err}");
    let keys = keyframes(&p);
    let w = tmp.path().join("w.toml");
    kf_ok(&["workflow", "save", s(&p), "-o", s(&w)]);
    let text = std::fs::read_to_string(&w).unwrap();
    assert!(text.contains("plugin = \"similarity\""), "{text}");
    assert!(text.contains("k = 10"), "{text}");
    let runs = tmp.path().join("runs");
    kf_ok(&["run", s(&w), s(&clip), "--out", s(&runs)]);
    let ran = runs
        .join(keyframer::batch::folder_name(&clip))
        .join("project.json");
    assert_eq!(keyframes(&ran), keys);

    let mut srv = Served::start(&p, &[]);
    let (code, state) = srv.call("GET", "/api/state", None);
    assert_eq!(code, 200, "{state}");
    let chain = state["chain"].as_array().unwrap();
    let step = (chain.iter())
        .find(|k| k["id"] == "similarity")
        .expect("similarity in the chain");
    assert_eq!(step["required"], "k");
    let body = serde_json::json!({"steps": [{"similarity": {"k": 20}}]});
    let (code, v) = srv.call("POST", "/api/apply", Some(&body));
    assert_eq!(code, 200, "{v}");
    assert_eq!(v["steps_state"][0]["enabled"], true, "{}", v["steps_state"]);
    let got: Vec<usize> = (v["keyframes"].as_array().unwrap().iter())
        .map(|k| k.as_u64().unwrap() as usize)
        .collect();
    srv.stop();
    let (code, err) = select(&clip, &p, &["--similarity", "20"]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("nothing decoded"), "{err}");
    assert_eq!(got, keyframes(&p));

    // A project without embeddings offers the step disabled, with the `select` that computes
    // them.
    let pan = crate::review::pan_copy(&tmp.path().join("pan"));
    let srv = Served::start(&pan, &[]);
    let (code, v) = srv.call("POST", "/api/apply", Some(&body));
    assert_eq!(code, 200, "{v}");
    let state = &v["steps_state"][0];
    assert_eq!(state["enabled"], false, "{state}");
    assert!(
        state["command"]
            .as_str()
            .unwrap()
            .contains("--similarity 20"),
        "{state}"
    );
}

/// Every golden file in reference/descriptor (made by `examples/make_reference.rs`): the OpenCV
/// twin reproduces its totals and the GPU kernel equals them within its tolerance.
#[test]
fn descriptor_reproduces_the_reference_totals() {
    use keyframer::kernels::{descriptor, tolerance};
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("reference");
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None).unwrap());
    let mut seen = 0;
    for entry in std::fs::read_dir(root.join("descriptor")).unwrap() {
        let golden = json(&entry.unwrap().path());
        let input = root.join(golden["input"].as_str().unwrap());
        let image = imgcodecs::imread(input.to_str().unwrap(), imgcodecs::IMREAD_COLOR).unwrap();
        let size = (
            golden["width"].as_u64().unwrap() as u32,
            golden["height"].as_u64().unwrap() as u32,
        );
        let want: Vec<u32> = (golden["totals"].as_array().unwrap().iter())
            .map(|t| t.as_u64().unwrap() as u32)
            .collect();
        let small = descriptor::prepare(&image, size).unwrap();
        assert_eq!(
            descriptor::opencv(&small).unwrap(),
            want,
            "{}",
            input.display()
        );
        let got = descriptor::DescriptorGpu::new(ctx.clone(), size)
            .unwrap()
            .totals(&small)
            .unwrap();
        let worst = got.iter().zip(&want).map(|(a, b)| a.abs_diff(*b)).max();
        assert!(
            worst <= Some(tolerance::DESCRIPTOR_TOTALS_ABS),
            "{}",
            input.display()
        );
        seen += 1;
    }
    assert!(seen >= 5, "{seen} golden files");
}

/// Weights of the tiny embedding network: four mixes of R, G and B.
pub(crate) const MIX: [[f32; 3]; 4] = [
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [0.5, -0.5, 0.25],
];

/// An ONNX embedding network named as iVS3D names them feeds the step (its embeddings cached
/// under its name, re-selection decodes nothing); a model whose input is not what its name
/// says, or whose output size is not its name's DIM, or whose name is not iVS3D's, is refused
/// before any frame is decoded (the input here is not even a video), naming the file.
#[test]
fn similarity_with_an_onnx_embedding_network() {
    use crate::onnx_model::embedding_net;
    let tmp = tempfile::tempdir().unwrap();
    let (clip, _) = scenes_clip(tmp.path());
    let model = tmp.path().join("ImageEmbedding_Tiny_4_12x8.onnx");
    std::fs::write(&model, embedding_net(8, 12, &MIX)).unwrap();
    let p = tmp.path().join("p.json");
    let (code, err) = select(
        &clip,
        &p,
        &["--similarity", "15", "--similarity-model", s(&model)],
    );
    assert_eq!(code, 0, "{err}");
    let project = json(&p);
    let series = &project["cache"]["embeddings"][0];
    let embedder = series["embedder"].as_str().unwrap();
    let hash = embedder.strip_prefix("onnx:ImageEmbedding_Tiny_4_12x8.onnx:");
    assert!(
        hash.is_some_and(|h| h.len() == 16 && h.chars().all(|c| c.is_ascii_hexdigit())),
        "{embedder}"
    );
    assert_eq!(series["dim"], 4);
    assert_eq!(
        (series["width"].clone(), series["height"].clone()),
        (12.into(), 8.into())
    );
    let n = embeddings_of(&p, 0).len();
    assert_eq!(n, SCENE * PHOTOS.len());
    assert_eq!(keyframes(&p).len(), n.div_ceil(15));
    // The first frame's embedding as an independent computation gives it: the mean of each mix
    // of the ImageNet-normalised RGB of the frame resized to 12x8, as a unit vector.
    let first = {
        // The first frame as OpenCV decodes it (keyframer's decoder).
        let mut cap =
            opencv::videoio::VideoCapture::from_file(s(&clip), opencv::videoio::CAP_FFMPEG)
                .unwrap();
        let mut img = Mat::default();
        assert!(cap.read(&mut img).unwrap());
        let mut small = Mat::default();
        imgproc::resize(
            &img,
            &mut small,
            Size::new(12, 8),
            0.0,
            0.0,
            imgproc::INTER_AREA,
        )
        .unwrap();
        let (mean, std) = ([0.485, 0.456, 0.406], [0.229, 0.224, 0.225]);
        let mut e = [0.0f64; 4];
        for y in 0..8 {
            for x in 0..12 {
                let px = *small.at_2d::<opencv::core::Vec3b>(y, x).unwrap();
                let rgb: Vec<f64> = (0..3)
                    .map(|c| (f64::from(px[2 - c]) / 255.0 - mean[c]) / std[c])
                    .collect();
                for (k, w) in MIX.iter().enumerate() {
                    e[k] += (0..3).map(|c| f64::from(w[c]) * rgb[c]).sum::<f64>() / 96.0;
                }
            }
        }
        let norm = e.iter().map(|v| v * v).sum::<f64>().sqrt();
        e.map(|v| v / norm)
    };
    let got = &embeddings_of(&p, 0)[0];
    for (a, b) in got.iter().zip(&first) {
        assert!((a - b).abs() < 1e-3, "{got:?} vs {first:?}");
    }
    let (code, err) = select(
        &clip,
        &p,
        &["--similarity", "6", "--similarity-model", s(&model)],
    );
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("nothing decoded"), "{err}");

    // Refusals, on an input that is no video: the model is checked first.
    let junk = tmp.path().join("junk.mp4");
    std::fs::write(&junk, b"not a video at all").unwrap();
    let q = tmp.path().join("q.json");
    let cases = [
        (
            "ImageEmbedding_Tiny_4_16x8.onnx",
            embedding_net(8, 12, &MIX),
            "its name says [1, 3, 8, 16]",
        ),
        (
            "ImageEmbedding_Tiny_5_12x8.onnx",
            embedding_net(8, 12, &MIX),
            "its name says 5 values per image",
        ),
        (
            "tiny-embedding.onnx",
            embedding_net(8, 12, &MIX),
            "ImageEmbedding_<NAME>_<DIM>_<W>x<H>.onnx",
        ),
    ];
    for (name, bytes, says) in cases {
        let bad = tmp.path().join(name);
        std::fs::write(&bad, bytes).unwrap();
        let (code, err) = select(
            &junk,
            &q,
            &["--similarity", "15", "--similarity-model", s(&bad)],
        );
        assert_ne!(code, 0, "{err}");
        assert!(err.contains(name) && err.contains(says), "{name}: {err}");
        assert!(!q.exists());
    }
}

/// The embeddings of series `i` of a project, decoded independently of keyframer: from its
/// series file (16-byte header with the dimension at bytes 8..12, then little-endian i16 per
/// value), or from the hex text of older projects (16-bit two's complement per component);
/// renormalised.
pub(crate) fn embeddings_of(project: &Path, i: usize) -> Vec<Vec<f64>> {
    let p = json(project);
    let series = &p["cache"]["embeddings"][i];
    let unit = |v: Vec<f64>| {
        let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        v.iter().map(|x| x / n).collect::<Vec<f64>>()
    };
    if let Some(frames) = series["frames"].as_array() {
        return (frames.iter())
            .map(|f| {
                let t = f.as_str().unwrap();
                unit(
                    (0..t.len() / 4)
                        .map(|i| {
                            f64::from(u16::from_str_radix(&t[4 * i..4 * i + 4], 16).unwrap() as i16)
                        })
                        .collect(),
                )
            })
            .collect();
    }
    let bytes = series_bytes(project, i);
    assert_eq!(&bytes[..8], b"KFEMB\0\0\x01");
    let dim = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
    assert_eq!(dim as u64, series["dim"].as_u64().unwrap());
    assert_eq!((bytes.len() - 16) % (2 * dim), 0);
    (bytes[16..].chunks(2 * dim))
        .map(|rec| {
            unit(
                rec.chunks(2)
                    .map(|b| f64::from(i16::from_le_bytes([b[0], b[1]])))
                    .collect(),
            )
        })
        .collect()
}

/// The bytes of the series file of series `i` of a project (beside it, named by `file`).
pub(crate) fn series_bytes(project: &Path, i: usize) -> Vec<u8> {
    let p = json(project);
    let name = p["cache"]["embeddings"][i]["file"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(!name.contains('/'), "{name}");
    std::fs::read(project.with_file_name(name)).unwrap()
}

/// The running embeddings file (`P.partial.emb`) follows the output rules: a symbolic link there
/// (dangling or not) is refused even with `--force`, before any frame, and its target is intact.
#[test]
fn the_embeddings_file_is_never_written_through_a_link() {
    let tmp = tempfile::tempdir().unwrap();
    let (clip, _) = scenes_clip(tmp.path());
    let p = tmp.path().join("p.json");
    let running = tmp.path().join("p.json.partial.emb");
    let theirs = tmp.path().join("theirs.txt");
    std::fs::write(&theirs, "their data").unwrap();
    std::os::unix::fs::symlink(&theirs, &running).unwrap();
    let (code, err) = select(&clip, &p, &["--similarity", "15"]);
    assert_ne!(code, 0, "{err}");
    assert!(err.contains("symbolic link"), "{err}");
    assert_eq!(std::fs::read_to_string(&theirs).unwrap(), "their data");
    assert!(!p.exists());
    // Dangling: nothing is created where it points.
    std::fs::remove_file(&running).unwrap();
    let elsewhere = tmp.path().join("elsewhere.emb");
    std::os::unix::fs::symlink(&elsewhere, &running).unwrap();
    let (code, err) = select(&clip, &p, &["--similarity", "15"]);
    assert_ne!(code, 0, "{err}");
    assert!(!elsewhere.exists(), "written through a dangling link");
}

/// A step failing after the analysis (here the manual step's frame beyond the input) leaves the
/// project and its series files as they were: the new series stays the running file a re-run
/// resumes, and no file of another name appears that no project names.
#[test]
fn a_failing_step_leaves_the_series_files_as_they_were() {
    let tmp = tempfile::tempdir().unwrap();
    let (clip, _) = scenes_clip(tmp.path());
    let p = tmp.path().join("p.json");
    let (code, err) = select(&clip, &p, &["--similarity", "15"]);
    assert_eq!(code, 0, "{err}");
    let series = |dir: &Path| -> Vec<String> {
        let mut names: Vec<String> = (std::fs::read_dir(dir).unwrap())
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".emb"))
            .collect();
        names.sort();
        names
    };
    let before = series(tmp.path());
    assert_eq!(before.len(), 1, "{before:?}");
    let bytes = std::fs::read(tmp.path().join(&before[0])).unwrap();
    let project = std::fs::read(&p).unwrap();
    // Another analysis width: another series key, so another file name.
    let args = [
        "--similarity",
        "15",
        "--analysis-width",
        "160",
        "--add",
        "99999",
    ];
    let (code, err) = select(&clip, &p, &args);
    assert_ne!(code, 0, "{err}");
    assert!(err.contains("99999"), "{err}");
    // The analysis ran (its series is there, under its running name) and named nothing else.
    let mut expected = [before.clone(), vec!["p.json.partial.emb".to_string()]].concat();
    expected.sort();
    assert_eq!(series(tmp.path()), expected);
    assert_eq!(std::fs::read(tmp.path().join(&before[0])).unwrap(), bytes);
    assert_eq!(
        std::fs::read(&p).unwrap(),
        project,
        "the project is untouched"
    );
    // The same run without the bad frame names its new series.
    let (code, err) = select(
        &clip,
        &p,
        &["--similarity", "15", "--analysis-width", "160"],
    );
    assert_eq!(code, 0, "{err}");
    let named: Vec<String> = (json(&p)["cache"]["embeddings"].as_array().unwrap().iter())
        .filter_map(|e| e["file"].as_str().map(String::from))
        .collect();
    let last = series(tmp.path());
    assert!(
        !last.contains(&"p.json.partial.emb".to_string()),
        "{last:?}"
    );
    for n in &named {
        assert!(last.contains(n), "{n} named, files {last:?}");
    }
}
