//! Fixtures of an earlier version (`tests/fixtures/v2`, made by its `make.sh`, which says which): every case is replayed with this build and must give the same project file
//! (byte for byte but its schema version, 1 → 2, re-selected from the fixture's cache), the same `workflow save`, byte-identical
//! exported images with the same manifest, and the same keyframes when its workflow is run.

use crate::common::s;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Modification time the fixture inputs had when the projects were made (see make.sh).
const MTIME: u64 = 1_700_000_000;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/v2")
}

/// One line of cases.tsv.
struct Case {
    name: String,
    input: String,
    select: Vec<String>,
    export: Option<Vec<String>>,
}

fn cases() -> Vec<Case> {
    let text = std::fs::read_to_string(fixtures().join("cases.tsv")).unwrap();
    let words = |t: &str| t.split_whitespace().map(String::from).collect::<Vec<_>>();
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split('\t').collect();
            assert_eq!(f.len(), 4, "cases.tsv line {l:?}");
            Case {
                name: f[0].into(),
                input: f[1].into(),
                select: words(f[2]),
                export: (f[3] != "-").then(|| words(f[3])),
            }
        })
        .collect()
}

/// Copies `from` into `to` (files and folders), giving every file the fixture's mtime.
fn copy_tree(from: &Path, to: &Path) {
    if from.is_dir() {
        std::fs::create_dir_all(to).unwrap();
        for e in std::fs::read_dir(from).unwrap() {
            let e = e.unwrap();
            copy_tree(&e.path(), &to.join(e.file_name()));
        }
    } else {
        std::fs::copy(from, to).unwrap();
        let t = std::time::UNIX_EPOCH + std::time::Duration::from_secs(MTIME);
        let f = std::fs::File::options().write(true).open(to).unwrap();
        f.set_modified(t).unwrap();
    }
}

/// Runs keyframer in `dir` (the fixtures' relative paths are relative to it).
fn kf_in(dir: &Path, args: &[&str]) -> Output {
    let out = Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .current_dir(dir)
        .args(args)
        .output()
        .expect("run keyframer");
    assert!(
        out.status.success(),
        "keyframer {args:?} failed ({:?}):\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// `sha256sum` of every file of an export but its manifest, as make.sh lists them.
fn export_listing(dir: &Path) -> String {
    let out = Command::new("sh")
        .current_dir(dir)
        .args([
            "-c",
            "find . -type f ! -name manifest.json | sort | xargs sha256sum",
        ])
        .output()
        .unwrap();
    assert!(out.status.success());
    String::from_utf8(out.stdout).unwrap()
}

/// A manifest without what differs between runs (time, absolute paths), as make.sh keeps it
/// with jq, and with every number as an f64 (jq writes `0.0` as `0`).
fn manifest(path: &Path) -> serde_json::Value {
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let m = v.as_object_mut().unwrap();
    m.remove("created_unix_s");
    m.insert("project".into(), "PROJECT".into());
    m.insert("source".into(), "SOURCE".into());
    as_f64(v)
}

fn as_f64(v: serde_json::Value) -> serde_json::Value {
    use serde_json::Value;
    match v {
        Value::Number(n) => Value::from(n.as_f64().unwrap()),
        Value::Array(a) => Value::Array(a.into_iter().map(as_f64).collect()),
        Value::Object(o) => Value::Object(o.into_iter().map(|(k, v)| (k, as_f64(v))).collect()),
        other => other,
    }
}

fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// A fixture project (schema version 1) as this build writes it back: version 2, which only adds
/// `cache.telemetry`, left out when the input has none (these inputs have none); every other
/// byte the same.
fn upgraded(v1: &str) -> String {
    let (old, new) = ("\"schema_version\": 1,", "\"schema_version\": 2,");
    assert!(
        v1.starts_with(&format!("{{\n  {old}")),
        "not a version 1 project"
    );
    v1.replacen(old, new, 1)
}

fn keyframes_of(p: &Path) -> serde_json::Value {
    serde_json::from_str::<serde_json::Value>(&read(p)).unwrap()["keyframes"].clone()
}

#[test]
fn fixtures_of_the_previous_version_give_the_same_results() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    copy_tree(&fixtures().join("input"), &dir.join("input"));
    let cases = cases();
    assert_eq!(cases.len(), 6);
    for c in &cases {
        let want = fixtures().join(&c.name);
        let project = format!("{}/project.json", c.name);
        std::fs::create_dir_all(dir.join(&c.name)).unwrap();
        std::fs::copy(want.join("project.json"), dir.join(&project)).unwrap();

        // 1. Re-selecting with the same flags over the fixture (its cache) writes it unchanged.
        let mut args = vec!["select", &c.input];
        args.extend(c.select.iter().map(String::as_str));
        args.extend(["-o", &project, "--force"]);
        let out = kf_in(dir, &args);
        let log = String::from_utf8_lossy(&out.stderr);
        let is_preview = c.select.iter().any(|a| a == "--preview");
        if !is_preview {
            assert!(
                log.contains("reusing the frame data cached"),
                "{}: the cache was not reused:\n{log}",
                c.name
            );
        }
        assert_eq!(
            read(&dir.join(&project)),
            upgraded(&read(&want.join("project.json"))),
            "{}: project file",
            c.name
        );

        // 2. The export: byte-identical images, the same manifest.
        let export_dir = dir.join("exports").join(&c.name);
        if let Some(flags) = &c.export {
            let mut args = vec!["export", &project, "--out", s(&export_dir), "--quiet"];
            args.extend(flags.iter().map(String::as_str));
            kf_in(dir, &args);
            assert_eq!(
                export_listing(&export_dir),
                read(&want.join("export.sha256")),
                "{}: exported files",
                c.name
            );
            let want_manifest =
                as_f64(serde_json::from_str(&read(&want.join("manifest.json"))).unwrap());
            assert_eq!(
                manifest(&export_dir.join("manifest.json")),
                want_manifest,
                "{}: manifest",
                c.name
            );
        }

        // 3. `workflow save` writes the same TOML.
        let workflow = format!("{}/workflow.toml", c.name);
        let mut args = vec!["workflow", "save", &project, "-o", &workflow, "--quiet"];
        if c.export.is_some() {
            args.extend(["--export", s(&export_dir)]);
        }
        kf_in(dir, &args);
        assert_eq!(
            read(&dir.join(&workflow)),
            read(&want.join("workflow.toml")),
            "{}: workflow save",
            c.name
        );

        // 4. Running that workflow on the input selects the same keyframes and exports the same
        // images.
        let runs = dir.join("runs").join(&c.name);
        kf_in(
            dir,
            &["run", &workflow, &c.input, "--out", s(&runs), "--quiet"],
        );
        let folder = runs.join(keyframer::batch::folder_name(&dir.join(&c.input)));
        assert_eq!(
            keyframes_of(&folder.join("project.json")),
            keyframes_of(&want.join("project.json")),
            "{}: keyframes of the workflow run",
            c.name
        );
        if c.export.is_some() {
            assert_eq!(
                export_listing(&folder.join(&c.name)),
                read(&want.join("export.sha256")),
                "{}: files exported by the workflow run",
                c.name
            );
        }
    }
}
