//! Embedding networks for the similarity step through model descriptions, on both runtimes
//! (OpenCV DNN and ONNX Runtime): the same embeddings within a stated tolerance and the same
//! keyframes; descriptions with a wrong key refused before any frame, naming file and key; the
//! cache key follows the network's bytes and preprocessing, not its name and size; projects that
//! keep their embeddings as hex text (before the series files) still re-select from the cache.

use crate::common::*;
use crate::onnx_model::embedding_net;
use crate::similarity::{embeddings_of, scenes_clip, select, series_bytes, MIX, SCENE};
use opencv::core::{Mat, Size};
use opencv::imgproc;
use opencv::prelude::*;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Largest difference allowed between a component of the DNN and the ONNX Runtime embedding of
/// a frame (unit vectors stored to 1/32767): both runtimes compute the same float network, whose
/// sums may round differently (~1e-6), which moves a stored component by at most a unit or two.
const RUNTIMES_ABS: f64 = 1e-4;

/// ONNX Runtime's library (ORT_DYLIB_PATH, else where scripts/setup.sh puts it); None, after
/// saying SKIPPED, when it is absent.
fn ort_lib() -> Option<PathBuf> {
    let p = std::env::var_os("ORT_DYLIB_PATH")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("target/onnxruntime/libonnxruntime.so.1.31.1")
        });
    if p.is_file() {
        return Some(p);
    }
    eprintln!(
        "SKIPPED the ONNX Runtime half: {} is absent (scripts/setup.sh fetches it)",
        p.display()
    );
    None
}

/// `select CLIP -o P --force ARGS` with ORT_DYLIB_PATH set to `lib`.
fn select_ort(clip: &Path, p: &Path, args: &[&str], lib: &Path) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args(["select", s(clip), "-o", s(p), "--force"])
        .args(args)
        .arg("--quiet")
        .env("ORT_DYLIB_PATH", lib)
        .output()
        .unwrap();
    code_and_stderr(&out)
}

/// A description of the tiny 4-value network `model` (BGR, mean 0.5, std 0.25), with `extra`
/// lines appended to the `[output]` table and `top` lines before the tables.
fn description(
    dir: &Path,
    name: &str,
    model: &str,
    top: &str,
    input: &str,
    output: &str,
) -> PathBuf {
    let p = dir.join(name);
    let text = format!(
        "model = \"{model}\"\nframework = \"onnx\"\n{top}\n\
         [input]\nwidth = 12\nheight = 8\nchannels = \"bgr\"\nscale = 0.00392156862745098\n\
         mean = [0.5, 0.5, 0.5]\nstd = [0.25, 0.25, 0.25]\n{input}\n\
         [output]\nkind = \"embedding\"\n{output}\n"
    );
    std::fs::write(&p, text).unwrap();
    p
}

/// The first frame's embedding computed here: the frame resized to 12x8 (INTER_AREA), each
/// pixel's B, G, R as (v / 255 - 0.5) / 0.25 in that order, each mix of MIX averaged, as a unit
/// vector.
fn first_frame_embedding(clip: &Path) -> [f64; 4] {
    let mut cap =
        opencv::videoio::VideoCapture::from_file(s(clip), opencv::videoio::CAP_FFMPEG).unwrap();
    let mut img = Mat::default();
    assert!(cap.read(&mut img).unwrap());
    let mut small = Mat::default();
    let to = Size::new(12, 8);
    imgproc::resize(&img, &mut small, to, 0.0, 0.0, imgproc::INTER_AREA).unwrap();
    let mut e = [0.0f64; 4];
    for y in 0..8 {
        for x in 0..12 {
            let px = *small.at_2d::<opencv::core::Vec3b>(y, x).unwrap();
            let bgr: Vec<f64> = (0..3)
                .map(|c| (f64::from(px[c]) / 255.0 - 0.5) / 0.25)
                .collect();
            for (k, w) in MIX.iter().enumerate() {
                e[k] += (0..3).map(|c| f64::from(w[c]) * bgr[c]).sum::<f64>() / 96.0;
            }
        }
    }
    let norm = e.iter().map(|v| v * v).sum::<f64>().sqrt();
    e.map(|v| v / norm)
}

/// A description feeds the step on OpenCV DNN and on ONNX Runtime: each gives the first frame's
/// embedding as computed here (1e-3), the two agree within [`RUNTIMES_ABS`] on every frame and
/// keep the same keyframes; the runtime is recorded; re-selection reads the cache.
#[test]
fn a_description_feeds_the_step_on_both_runtimes() {
    let tmp = tempfile::tempdir().unwrap();
    let (clip, _) = scenes_clip(tmp.path());
    std::fs::write(tmp.path().join("tiny.onnx"), embedding_net(8, 12, &MIX)).unwrap();
    let desc = description(tmp.path(), "tiny.toml", "tiny.onnx", "", "", "dim = 4");
    let dnn = tmp.path().join("p-dnn.json");
    let args = ["--similarity", "15", "--similarity-model", s(&desc)];
    let (code, err) = select(&clip, &dnn, &args);
    assert_eq!(code, 0, "{err}");
    let series = json(&dnn)["cache"]["embeddings"][0].clone();
    assert_eq!(series["dim"], 4);
    assert!(
        series["embedder"]
            .as_str()
            .unwrap()
            .starts_with("onnx:tiny.onnx:"),
        "{series}"
    );
    let e_dnn = embeddings_of(&dnn, 0);
    assert_eq!(e_dnn.len(), 5 * SCENE);
    let want = first_frame_embedding(&clip);
    for (a, b) in e_dnn[0].iter().zip(&want) {
        assert!((a - b).abs() < 1e-3, "{:?} vs {want:?}", e_dnn[0]);
    }
    let keys = keyframes(&dnn);
    assert_eq!(keys.len(), (5 * SCENE).div_ceil(15));

    let Some(lib) = ort_lib() else { return };
    let ort = tmp.path().join("p-ort.json");
    let mut ort_args = args.to_vec();
    ort_args.extend(["--similarity-runtime", "ort"]);
    let (code, err) = select_ort(&clip, &ort, &ort_args, &lib);
    assert_eq!(code, 0, "{err}");
    let project = json(&ort);
    assert_eq!(project["cache"]["embeddings"][0]["runtime"], "ort");
    assert_eq!(
        project["cache"]["embeddings"][0]["embedder"],
        series["embedder"]
    );
    let step = (project["history"].as_array().unwrap().iter())
        .find(|h| h["plugin"] == "similarity")
        .unwrap()
        .clone();
    assert_eq!(step["params"]["runtime"], "ort", "{step}");
    let e_ort = embeddings_of(&ort, 0);
    assert_eq!(e_ort.len(), e_dnn.len());
    let worst = (e_dnn.iter().flatten())
        .zip(e_ort.iter().flatten())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(worst <= RUNTIMES_ABS, "dnn vs ort: {worst}");
    assert_eq!(keyframes(&ort), keys);
    let mut again = args.to_vec();
    again[1] = "6";
    again.extend(["--similarity-runtime", "ort"]);
    let (code, err) = select_ort(&clip, &ort, &again, &lib);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("nothing decoded"), "{err}");
    let w = tmp.path().join("w.toml");
    kf_ok(&["workflow", "save", s(&ort), "-o", s(&w)]);
    let text = std::fs::read_to_string(&w).unwrap();
    assert!(text.contains("runtime = \"ort\""), "{text}");
}

/// A description that does not fit its network, or has a wrong key, is refused before any
/// frame (the input is no video), on both runtimes (even without the ONNX Runtime library),
/// naming the description and the key; nothing is written.
#[test]
fn descriptions_with_a_wrong_key_are_refused_naming_file_and_key() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::write(dir.join("tiny.onnx"), embedding_net(8, 12, &MIX)).unwrap();
    let junk = dir.join("junk.mp4");
    std::fs::write(&junk, b"not a video at all").unwrap();
    let q = dir.join("q.json");
    let cases = [
        ("no-dim.toml", "", "", "", "output.dim"),
        ("dim-5.toml", "", "", "dim = 5", "output.dim"),
        (
            "wide.toml",
            "",
            "name = \"input\"\nlayout = \"nhwc\"",
            "dim = 4",
            "input.width",
        ),
        (
            "classes.toml",
            "classes = [\"a\", \"b\"]",
            "",
            "dim = 4",
            "classes",
        ),
        (
            "no-input.toml",
            "",
            "name = \"pixels\"",
            "dim = 4",
            "input.name",
        ),
    ];
    for (name, top, input, output, key) in cases {
        let desc = description(dir, name, "tiny.onnx", top, input, output);
        for runtime in ["opencv", "ort"] {
            let out = Command::new(env!("CARGO_BIN_EXE_keyframer"))
                .args(["select", s(&junk), "-o", s(&q), "--similarity", "15"])
                .args([
                    "--similarity-model",
                    s(&desc),
                    "--similarity-runtime",
                    runtime,
                ])
                .env("ORT_DYLIB_PATH", dir.join("no-such-libonnxruntime.so"))
                .output()
                .unwrap();
            let (code, err) = code_and_stderr(&out);
            assert_ne!(code, 0, "{name} {runtime}: {err}");
            assert!(
                err.contains(name) && err.contains(key),
                "{name} {runtime}: {err}"
            );
            assert!(!q.exists());
        }
    }
    // A segmentation description is no embedding network.
    let seg = crate::onnx_model::tiny_model(dir, "seg", false, Some(1), "");
    let (code, err) = select(
        &junk,
        &q,
        &["--similarity", "15", "--similarity-model", s(&seg)],
    );
    assert_ne!(code, 0, "{err}");
    assert!(
        err.contains("seg.toml") && err.contains("output.kind"),
        "{err}"
    );
}

/// The cache key is the network's content: another file of the same name and size (one weight
/// changed), or the same network with another mean, computes the embeddings again.
#[test]
fn a_changed_network_of_the_same_name_and_size_is_computed_again() {
    let tmp = tempfile::tempdir().unwrap();
    let (clip, _) = scenes_clip(tmp.path());
    let model = tmp.path().join("ImageEmbedding_Tiny_4_12x8.onnx");
    let first = embedding_net(8, 12, &MIX);
    let mut mix = MIX;
    mix[3][1] = 0.75;
    let second = embedding_net(8, 12, &mix);
    assert_eq!(first.len(), second.len());
    assert_ne!(first, second);
    std::fs::write(&model, &first).unwrap();
    let p = tmp.path().join("p.json");
    let args = ["--similarity", "15", "--similarity-model", s(&model)];
    let (code, err) = select(&clip, &p, &args);
    assert_eq!(code, 0, "{err}");
    let key_first = json(&p)["cache"]["embeddings"][0]["embedder"].clone();
    let e_first = embeddings_of(&p, 0);
    let (code, err) = select(&clip, &p, &args);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("nothing decoded"), "{err}");

    std::fs::write(&model, &second).unwrap();
    let (code, err) = select(&clip, &p, &args);
    assert_eq!(code, 0, "{err}");
    assert!(!err.contains("nothing decoded"), "{err}");
    let project = json(&p);
    let series = project["cache"]["embeddings"].as_array().unwrap();
    let i = (series.iter())
        .position(|e| e["embedder"] != key_first)
        .expect("a series of the changed network");
    let e_second = embeddings_of(&p, i);
    assert_ne!(e_first, e_second);

    // The same network through a description: another mean is another series.
    std::fs::write(tmp.path().join("tiny.onnx"), &first).unwrap();
    let d1 = description(tmp.path(), "d1.toml", "tiny.onnx", "", "", "dim = 4");
    let d2 = tmp.path().join("d2.toml");
    let text = std::fs::read_to_string(&d1).unwrap();
    std::fs::write(
        &d2,
        text.replace("mean = [0.5, 0.5, 0.5]", "mean = [0.4, 0.5, 0.5]"),
    )
    .unwrap();
    let r = tmp.path().join("r.json");
    let (code, err) = select(
        &clip,
        &r,
        &["--similarity", "15", "--similarity-model", s(&d1)],
    );
    assert_eq!(code, 0, "{err}");
    let (code, err) = select(
        &clip,
        &r,
        &["--similarity", "15", "--similarity-model", s(&d2)],
    );
    assert_eq!(code, 0, "{err}");
    assert!(!err.contains("nothing decoded"), "{err}");
    assert_eq!(json(&r)["cache"]["embeddings"].as_array().unwrap().len(), 2);
}

/// A project whose cache keeps the embeddings as hex text per frame (as projects did before the
/// series files; converted here from a new project's series file) loads and re-selects from its
/// cache: nothing decoded, the keyframes of the series file's project.
#[test]
fn projects_with_hex_embeddings_still_reselect() {
    let tmp = tempfile::tempdir().unwrap();
    let (clip, _) = scenes_clip(tmp.path());
    let p = tmp.path().join("p.json");
    let (code, err) = select(&clip, &p, &["--similarity", "15", "--backend", "opencv"]);
    assert_eq!(code, 0, "{err}");
    let (code, err) = select(&clip, &p, &["--similarity", "6"]);
    assert_eq!(code, 0, "{err}");
    let want = keyframes(&p);

    let old = tmp.path().join("old.json");
    let bytes = series_bytes(&p, 0);
    let dim = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
    let frames: Vec<serde_json::Value> = (bytes[16..].chunks(2 * dim))
        .map(|rec| {
            let hex: String = (rec.chunks(2))
                .map(|b| format!("{:04x}", u16::from_le_bytes([b[0], b[1]])))
                .collect();
            hex.into()
        })
        .collect();
    let mut project = json(&p);
    let series = project["cache"]["embeddings"][0].as_object_mut().unwrap();
    let file = series.remove("file").unwrap();
    series.insert("frames".into(), frames.into());
    std::fs::write(&old, serde_json::to_string_pretty(&project).unwrap()).unwrap();
    assert!(file.as_str().unwrap().ends_with(".emb"), "{file}");
    let (code, err) = select(&clip, &old, &["--similarity", "15"]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("nothing decoded"), "{err}");
    let (code, err) = select(&clip, &old, &["--similarity", "6"]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("nothing decoded"), "{err}");
    assert_eq!(keyframes(&old), want);
}

/// An analysis computing embeddings, killed after its second checkpoint, resumes from it: the
/// series file is truncated back to the checkpoint's frames and appended to, and ends byte for
/// byte as an uninterrupted run's; no running file is left.
#[test]
fn a_killed_analysis_resumes_its_embeddings() {
    use std::process::Stdio;
    use std::time::{Duration, Instant};
    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "long.mp4", 320, 180, "60", 20.0);
    let args = |p: &Path| -> Vec<String> {
        let p = s(p).to_string();
        let c = s(&clip).to_string();
        [
            "select",
            &c,
            "--similarity",
            "40",
            "--backend",
            "opencv",
            "--checkpoint-every",
            "0.3",
            "-o",
            &p,
        ]
        .iter()
        .map(|x| x.to_string())
        .collect()
    };
    let clean = d.path().join("clean.json");
    kf_ok(&args(&clean).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(!d.path().join("clean.json.partial.emb").exists());

    let resumed = d.path().join("resumed.json");
    let partial = d.path().join("resumed.json.partial");
    let mut child = Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args(args(&resumed))
        .arg("--quiet")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let mut seen = Vec::new();
    while start.elapsed() < Duration::from_secs(120) && seen.len() < 2 {
        if let Ok(bytes) = std::fs::read(&partial) {
            let v: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
            let frames = v["frames"].as_u64().unwrap();
            if seen.last() != Some(&frames) {
                seen.push(frames);
            }
        }
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    if seen.len() < 2 || resumed.exists() {
        eprintln!("SKIPPED the resume check: the run ended before two checkpoints ({seen:?})");
        return;
    }
    let running = d.path().join("resumed.json.partial.emb");
    assert!(running.exists(), "the series file while the analysis runs");
    let out = kf_loud(
        &args(&resumed)
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>(),
    );
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("resuming the analysis"), "{err}");
    assert!(!partial.exists() && !running.exists());
    assert_eq!(series_bytes(&resumed, 0), series_bytes(&clean, 0));
    assert_eq!(keyframes(&resumed), keyframes(&clean));
}
