//! Workflows and batch runs: the example workflow headless on three clips, save and reload,
//! a corrupt input among good ones, resume after a kill, malformed workflows, and a real
//! single-node Slurm job array over shards.

use crate::common::*;
use keyframer::batch::folder_name;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The repository's example workflow with the opencv backend (quicker on lavapipe machines).
fn example_workflow(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("workflows/example.toml"),
    )
    .unwrap();
    assert!(text.contains("backend = \"auto\""));
    let p = dir.join("example.toml");
    std::fs::write(
        &p,
        text.replace("backend = \"auto\"", "backend = \"opencv\""),
    )
    .unwrap();
    p
}

/// A 320x240 pan over aloeL.jpg at `speed` px/s for `secs` seconds, with a still second first.
fn pan_clip(dir: &Path, name: &str, speed: u32, secs: u32) -> PathBuf {
    let p = dir.join(name);
    ffmpeg(&[
        "-loop",
        "1",
        "-i",
        s(&testdata("opencv-doc/aloeL.jpg")),
        "-vf",
        &format!("crop=320:240:x='max(0\\,t-1)*{speed}':y=20,format=yuv420p"),
        "-t",
        &secs.to_string(),
        "-r",
        "30",
        "-c:v",
        "libx264",
        "-crf",
        "18",
        s(&p),
    ]);
    p
}

fn three_clips(d: &Path) -> Vec<PathBuf> {
    vec![
        pan_clip(d, "a.mp4", 40, 4),
        pan_clip(d, "b.mp4", 60, 3),
        pan_clip(d, "c.mp4", 25, 4),
    ]
}

fn run(wf: &Path, inputs: &[PathBuf], out: &Path, extra: &[&str]) -> (i32, String, String) {
    let mut args = vec!["run", s(wf)];
    args.extend(inputs.iter().map(|p| s(p)));
    args.extend(["--out", s(out), "--json"]);
    args.extend(extra);
    let o = kf(&args);
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// Exported files of one input: (export/file name, bytes).
type Files = Vec<(String, Vec<u8>)>;

/// Keyframes of each input's project and the bytes of every exported file.
fn results(out: &Path, inputs: &[PathBuf]) -> Vec<(Vec<usize>, Files)> {
    inputs
        .iter()
        .map(|i| {
            let folder = out.join(folder_name(i));
            let keys = keyframes(&folder.join("project.json"));
            let mut files = Vec::new();
            for export in ["full", "small"] {
                let images = folder.join(export).join("images");
                for f in listing(&images) {
                    let bytes = std::fs::read(images.join(&f)).unwrap();
                    files.push((format!("{export}/{f}"), bytes));
                }
            }
            (keys, files)
        })
        .collect()
}

/// A workflow without `backend` runs on `auto`: `run -j 2` says the decision once for all its
/// jobs, and every project records the backend it resolved to (opencv on a software adapter).
#[test]
fn auto_backend_is_said_once_per_run() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let wf = d.join("wf.toml");
    let text = "version = 1\n[[sample]]\nplugin = \"every-nth\"\nn = 4\n\
                [[sample]]\nplugin = \"blur\"\nwindow = 2\n";
    std::fs::write(&wf, text).unwrap();
    let inputs: Vec<PathBuf> = (0..3)
        .map(|i| testsrc(d, &format!("v{i}.mp4"), 64, 48, "10", 1.0))
        .collect();
    let info: serde_json::Value = serde_json::from_str(&kf_ok(&["info", "--json"])).unwrap();
    let want = info["backend_auto"]["backend"]
        .as_str()
        .unwrap()
        .to_string();
    if info["selected_adapter"]["Ok"]["software"] == true {
        assert_eq!(want, "opencv", "{info}");
    }
    let out = d.join("out");
    let mut args = vec!["run", s(&wf)];
    args.extend(inputs.iter().map(|p| s(p)));
    args.extend(["--out", s(&out), "-j", "2"]);
    let (code, err) = code_and_stderr(&kf_loud(&args));
    assert_eq!(code, 0, "{err}");
    assert_eq!(err.matches("backend auto:").count(), 1, "{err}");
    assert!(err.contains(&format!("backend auto: {want} (")), "{err}");
    for i in &inputs {
        let p = json(&out.join(folder_name(i)).join("project.json"));
        assert_eq!(p["cache"]["sharpness"][0]["backend"], want.as_str(), "{p}");
    }
}

#[test]
fn example_workflow_runs_headless_and_its_saved_form_selects_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let wf = example_workflow(d);
    let clips = three_clips(d);
    let out = d.join("out");
    let (code, stdout, err) = run(&wf, &clips, &out, &["-j", "2"]);
    assert_eq!(code, 0, "{err}");
    let summary: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(summary.as_array().unwrap().len(), 3);
    for (clip, r) in clips.iter().zip(summary.as_array().unwrap()) {
        assert_eq!(r["status"], "done", "{r}");
        let folder = out.join(folder_name(clip));
        let keys = keyframes(&folder.join("project.json"));
        assert!(keys.len() >= 2, "{}: {keys:?}", clip.display());
        for export in ["full", "small"] {
            let m = json(&folder.join(export).join("manifest.json"));
            assert_eq!(m["frames"].as_array().unwrap().len(), keys.len());
        }
        let small = json(&folder.join("small/manifest.json"));
        assert_eq!(
            (small["width"].as_u64(), small["height"].as_u64()),
            (Some(1280), Some(720))
        );
        let full = json(&folder.join("full/manifest.json"));
        assert_eq!(
            (full["width"].as_u64(), full["height"].as_u64()),
            (Some(320), Some(240))
        );
        // The history names the workflow's plugins in order.
        let plugins: Vec<String> = json(&folder.join("project.json"))["history"]
            .as_array()
            .unwrap()
            .iter()
            .map(|h| h["plugin"].as_str().unwrap().to_string())
            .collect();
        assert_eq!(plugins, ["boundaries", "stationary", "fps", "blur"]);
    }

    // Save the steps of the first project (with its exports), reload, run again: same keyframes.
    let folder = out.join(folder_name(&clips[0]));
    let saved = d.join("saved.toml");
    kf_ok(&[
        "workflow",
        "save",
        s(&folder.join("project.json")),
        "-o",
        s(&saved),
        "--export",
        s(&folder.join("full")),
        "--export",
        s(&folder.join("small")),
    ]);
    let text = std::fs::read_to_string(&saved).unwrap();
    assert!(
        text.contains("version = 1") && text.contains("plugin = \"stationary\""),
        "{text}"
    );
    let out2 = d.join("out2");
    let (code, _, err) = run(&saved, &clips, &out2, &[]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(results(&out, &clips), results(&out2, &clips));

    // Everything done: a re-run skips all inputs.
    let (code, stdout, err) = run(&wf, &clips, &out, &[]);
    assert_eq!(code, 0, "{err}");
    let summary: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(
        summary
            .as_array()
            .unwrap()
            .iter()
            .all(|r| r["status"] == "skipped"),
        "{summary}"
    );
}

#[test]
fn a_corrupt_input_fails_alone_and_a_killed_batch_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let wf = example_workflow(d);
    let clips = three_clips(d);

    // One corrupt input among three.
    let bad = d.join("broken.mp4");
    let mut bytes = std::fs::read(&clips[0]).unwrap();
    bytes.truncate(bytes.len() / 3);
    std::fs::write(&bad, &bytes[..]).unwrap();
    let inputs = vec![clips[0].clone(), bad.clone(), clips[1].clone()];
    let out = d.join("mixed");
    let (code, stdout, err) = run(&wf, &inputs, &out, &[]);
    assert_eq!(code, 2, "{err}");
    let summary: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let status: Vec<&str> = summary
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["status"].as_str().unwrap())
        .collect();
    assert_eq!(status, ["done", "failed", "done"], "{err}");
    assert!(
        err.contains("FAILED") && err.contains("broken.mp4"),
        "{err}"
    );
    let done = |out: &Path, input: &Path| out.join(folder_name(input)).join("done.json");
    assert!(done(&out, &clips[0]).exists() && done(&out, &clips[1]).exists());
    assert!(!done(&out, &bad).exists());

    // Clean run for reference.
    let clean = d.join("clean");
    let (code, _, err) = run(&wf, &clips, &clean, &[]);
    assert_eq!(code, 0, "{err}");

    // Kill a batch once its first input is done, then run it again.
    let killed = d.join("killed");
    let mut child = Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .arg("run")
        .arg(&wf)
        .args(&clips)
        .args(["--out", s(&killed), "--quiet"])
        .spawn()
        .unwrap();
    let first_done = done(&killed, &clips[0]);
    let t = std::time::Instant::now();
    while !first_done.exists() {
        assert!(t.elapsed().as_secs() < 300, "first input never finished");
        if let Some(status) = child.try_wait().unwrap() {
            panic!("the batch ended before it could be killed: {status}");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let unfinished = clips[1..]
        .iter()
        .filter(|c| !done(&killed, c).exists())
        .count();
    assert!(unfinished >= 1, "the kill came too late to test resuming");
    let (code, stdout, err) = run(&wf, &clips, &killed, &[]);
    assert_eq!(code, 0, "{err}");
    let summary: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(summary[0]["status"], "skipped", "{summary}");
    let redone = summary
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["status"] == "done")
        .count();
    assert_eq!(redone, unfinished, "{summary}");
    assert_eq!(results(&killed, &clips), results(&clean, &clips));
}

#[test]
fn malformed_workflows_are_refused_with_file_line_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let clip = testsrc(d, "clip.mp4", 64, 48, "10", 1.0);
    let cases: [(&str, &str, &[&str]); 7] = [
        (
            "version = 1\n[[sample]]\nplugin = \"fps\"\nfps = 1.0\n[[sample]]\nplugin = \"sharpest\"\n",
            "unknown_plugin",
            &[":6:", "sample[1]", "unknown variant `sharpest`"],
        ),
        (
            "version = 1\n[[sample]]\nplugin = \"fps\"\nfps = \"fast\"\n",
            "wrong_type",
            &[":4:", "sample[0].fps", "expected f64"],
        ),
        (
            "version = 1\n[[sample]]\nplugin = \"every-nth\"\n",
            "missing_field",
            &[":2:", "sample[0]", "missing field `n`"],
        ),
        (
            "version = 1\n\n[[export]]\nname = \"full\"\nsize = \"1280x720\"\n",
            "unknown_key",
            &["export[0]", "unknown field `size`"],
        ),
        (
            "version = 1\n[[sample]]\nplugin = \"blur\"\nratio = -2.0\n",
            "bad_value",
            &[":4:", "sample[0].ratio"],
        ),
        (
            "version = 1\n[[sample]]\nplugin = \"blur\"\n[[sample]]\nplugin = \"fps\"\nfps = 2.0\n",
            "bad_order",
            &[":5:", "sample[1].plugin", "cannot follow `blur`"],
        ),
        ("[[sample]]\nplugin = \"fps\"\nfps = 2.0\n", "no_version", &["missing field `version`"]),
    ];
    for (text, name, needles) in cases {
        let wf = d.join(format!("{name}.toml"));
        std::fs::write(&wf, text).unwrap();
        let out = d.join(format!("out_{name}"));
        let (code, _, err) = run(&wf, std::slice::from_ref(&clip), &out, &[]);
        assert_eq!(code, 1, "{name}: {err}");
        assert!(err.contains(&format!("{name}.toml")), "{name}: {err}");
        for n in needles {
            assert!(err.contains(n), "{name}: `{n}` not in {err}");
        }
        assert!(!out.exists(), "{name}: the output folder was created");
    }
}

/// Root and a Debian apt: what a real single-node Slurm needs here.
fn slurm_possible() -> Result<(), String> {
    let uid = Command::new("id")
        .arg("-u")
        .output()
        .map_err(|e| e.to_string())?;
    if String::from_utf8_lossy(&uid.stdout).trim() != "0" {
        return Err("not root (slurm_up.sh installs packages and starts daemons)".into());
    }
    if !Path::new("/usr/bin/apt-get").exists() {
        return Err("no apt-get (Slurm is installed from Debian's packages)".into());
    }
    Ok(())
}

struct SlurmDown(PathBuf);
impl Drop for SlurmDown {
    fn drop(&mut self) {
        let _ = Command::new("bash")
            .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/slurm/slurm_down.sh"))
            .env("SLURM_LAB_DIR", &self.0)
            .output();
    }
}

#[test]
fn slurm_job_array_processes_every_input_exactly_once() {
    if let Err(why) = slurm_possible() {
        eprintln!("skipped: Slurm cannot be installed here: {why}");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // World-readable so job steps can read the inputs whatever user Slurm runs them as.
    let lab = PathBuf::from(format!("/tmp/keyframer-slurm-{}", std::process::id()));
    let _down = SlurmDown(lab.clone());
    let up = Command::new("bash")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/slurm/slurm_up.sh"))
        .env("SLURM_LAB_DIR", &lab)
        .env("SLURM_LAB_LINK_ETC", "0")
        .env("SLURM_UP_TIMEOUT", "120")
        .output()
        .unwrap();
    assert!(
        up.status.success(),
        "slurm_up.sh failed:\n{}",
        String::from_utf8_lossy(&up.stderr)
    );
    let conf = lab.join("etc/slurm.conf");

    let wf = d.join("wf.toml");
    std::fs::write(
        &wf,
        "version = 1\n[analysis]\nbackend = \"opencv\"\n[[sample]]\nplugin = \"every-nth\"\nn = 4\n\
         [[export]]\nname = \"img\"\nscale = 0.5\n",
    )
    .unwrap();
    let mut inputs = Vec::new();
    for i in 0..7 {
        inputs.push(testsrc(d, &format!("v{i}.mp4"), 64, 48, "10", 1.0));
    }
    let list = d.join("inputs.txt");
    std::fs::write(
        &list,
        inputs
            .iter()
            .map(|p| format!("{}\n", p.display()))
            .collect::<String>(),
    )
    .unwrap();
    let out = d.join("out");
    let job = d.join("job.sh");
    std::fs::write(
        &job,
        format!(
            "#!/bin/bash\nset -euo pipefail\n\"{}\" run \"{}\" --inputs-from \"{}\" --out \"{}\" \
             --shard \"$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT\" --quiet --json \
             > \"{}/summary_$SLURM_ARRAY_TASK_ID.json\"\n",
            env!("CARGO_BIN_EXE_keyframer"),
            wf.display(),
            list.display(),
            out.display(),
            d.display()
        ),
    )
    .unwrap();
    let sb = Command::new("timeout")
        .args(["600", "sbatch", "--wait", "--array=0-2", "--mem=500M"])
        .arg(format!("--chdir={}", d.display()))
        .arg(format!("--output={}/slurm-%A_%a.out", d.display()))
        .arg(&job)
        .env("SLURM_CONF", &conf)
        .output()
        .unwrap();
    let logs: String = listing(d)
        .iter()
        .filter(|f| f.starts_with("slurm-"))
        .map(|f| std::fs::read_to_string(d.join(f)).unwrap_or_default())
        .collect();
    assert!(
        sb.status.success(),
        "sbatch: {}\n{}\njob logs:\n{logs}",
        String::from_utf8_lossy(&sb.stdout),
        String::from_utf8_lossy(&sb.stderr)
    );
    let mut processed: Vec<String> = Vec::new();
    for task in 0..3 {
        let summary = json(&d.join(format!("summary_{task}.json")));
        let handled = summary.as_array().unwrap();
        assert!(!handled.is_empty(), "task {task} handled nothing");
        for r in handled {
            assert_eq!(r["status"], "done", "task {task}: {r}");
            processed.push(r["input"].as_str().unwrap().to_string());
        }
    }
    processed.sort();
    let mut expected: Vec<String> = inputs.iter().map(|p| p.display().to_string()).collect();
    expected.sort();
    assert_eq!(processed, expected, "every input exactly once");
    for i in &inputs {
        let folder = out.join(folder_name(i));
        assert!(folder.join("done.json").exists(), "{}", folder.display());
        assert_eq!(listing(&folder.join("img/images")).len(), 3, "3 images");
    }
}
