//! The experiment script's smoke version (CI): a short hover-survey scene, 1 fps against the same
//! number of movement-based keyframes (raw flow and derotated), and fps 2 with and without
//! stationary removal, each through COLMAP and `keyframer eval`.

use crate::common::*;
use std::process::Command;

fn rows(path: &std::path::Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn experiment_smoke_reproduces_the_table() {
    let d = tempfile::tempdir().unwrap();
    let work = d.path().join("exp");
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/experiment.sh");
    let out = Command::new(script)
        .args(["--smoke", "--seqs", "hover-survey", s(&work)])
        .env("KEYFRAMER", env!("CARGO_BIN_EXE_keyframer"))
        .env("KEYFRAMER_SCENE", scene_exe())
        .output()
        .unwrap();
    let (code, err) = code_and_stderr(&out);
    assert_eq!(code, 0, "{err}");
    let table = String::from_utf8_lossy(&out.stdout);
    assert_eq!(table.lines().count(), 7, "{table}");
    assert_eq!(
        std::fs::read_to_string(work.join("table.md")).unwrap(),
        table
    );

    let r = rows(&work.join("results.jsonl"));
    let names: Vec<&str> = r.iter().map(|x| x["sampling"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        ["fps1", "spacing-raw", "spacing", "fps2", "fps2-stationary"]
    );
    for x in &r {
        assert!(x["ratio"].as_f64().unwrap() >= 0.95, "registration: {x}");
        assert!(x["rmse"].as_f64().is_some(), "{x}");
    }
    let (fps1, raw, spacing) = (&r[0], &r[1], &r[2]);
    assert_eq!(fps1["keyframes"], spacing["keyframes"]);
    assert_eq!(fps1["keyframes"], raw["keyframes"]);
    let sigma = |x: &serde_json::Value| x["gt_sigma"].as_f64().unwrap();
    assert!(
        sigma(spacing) < sigma(fps1),
        "movement-based spacing is more even: {spacing} vs {fps1}"
    );
    let keys = |x: &serde_json::Value| x["keyframes"].as_u64().unwrap();
    assert!(
        keys(&r[4]) < keys(&r[3]),
        "stationary removal drops hover frames"
    );
}
