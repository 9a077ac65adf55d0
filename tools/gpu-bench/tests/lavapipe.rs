//! CI for the GPU benchmark: runs `keyframer-gpu-bench` on a few small frames on whatever
//! adapter the machine has (lavapipe in CI), checks its JSON (every run timed, the whole
//! analysis within the device budget: at most 1 KiB read back and 1/16 blocking waits per
//! frame), and that the package pulls no OpenCV crate.

use std::process::Command;

/// The run CI makes (its figures are in docs/benchmarks.md).
pub const CI_ARGS: &[&str] = &[
    "--frames",
    "64",
    "--sizes",
    "640x360",
    "--widths",
    "160,320",
    "--analysis-width",
    "320",
    "--streams",
    "1,4",
];

#[test]
fn the_benchmark_times_every_run_within_the_budget() {
    let dir = std::env::temp_dir().join(format!("gpu-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("bench.json");
    let out = Command::new(env!("CARGO_BIN_EXE_keyframer-gpu-bench"))
        .args(CI_ARGS)
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    eprintln!("{stderr}{stdout}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let adapter = &v["adapter"];
    for key in ["name", "driver", "backend"] {
        assert!(adapter[key].is_string(), "adapter {key}: {adapter}");
    }
    let timing = v["timing"].as_str().unwrap();
    assert!(timing == "timestamp" || timing == "wall", "{timing}");
    let runs = |key: &str| v[key].as_array().unwrap().clone();
    let (kernels, analysis) = (runs("kernels"), runs("analysis"));
    let names: Vec<&str> = kernels
        .iter()
        .map(|k| k["name"].as_str().unwrap())
        .collect();
    assert_eq!(
        names,
        [
            "upload",
            "upload buffer",
            "upload write_texture",
            "gray+resize+tenengrad",
            "no-upload tenengrad",
            "gray+resize+laplacian",
            "no-upload laplacian",
            "farneback",
            "farneback"
        ]
    );
    let sizes: Vec<&str> = kernels
        .iter()
        .map(|k| k["size"].as_str().unwrap())
        .collect();
    assert_eq!(
        sizes,
        [
            "640x360", "640x360", "640x360", "640x360", "640x360", "640x360", "640x360", "160x90",
            "320x180"
        ]
    );
    let streams: Vec<u64> = analysis
        .iter()
        .map(|a| a["streams"].as_u64().unwrap())
        .collect();
    assert_eq!(streams, [1, 1, 1, 4, 4]);
    let parts: Vec<&str> = (analysis.iter())
        .map(|a| a["name"].as_str().unwrap())
        .collect();
    assert_eq!(
        parts,
        [
            "analysis blur",
            "analysis blur+spacing",
            "analysis",
            "analysis",
            "analysis, own devices"
        ]
    );
    for run in kernels.iter().chain(&analysis) {
        let per_s = run["per_s"].as_f64().unwrap();
        assert!(per_s.is_finite() && per_s > 0.0, "{run}");
        assert!(run["wall_s"].as_f64().unwrap() > 0.0, "{run}");
        // With timestamps every run on the bench's device has its device time, and the rate is
        // taken from it (the runs on devices of their own have wall time only).
        let own = run["name"].as_str().unwrap().ends_with("own devices");
        assert_eq!(run["device_s"].is_null(), own || timing == "wall", "{run}");
        if timing == "timestamp" && !own {
            let device = run["device_s"].as_f64().unwrap();
            let count = run["count"].as_f64().unwrap();
            assert!(
                device > 0.0 && (count / device - per_s).abs() <= 1e-6 * per_s,
                "{run}"
            );
        }
        // The upload row dispatches nothing; the no-upload rows upload nothing; the rest both.
        let name = run["name"].as_str().unwrap();
        let per = &run["per_frame"];
        let (dispatches, bytes) = (
            per["dispatches"].as_f64().unwrap(),
            per["uploaded"].as_f64().unwrap(),
        );
        assert_eq!(dispatches > 0.0, !name.starts_with("upload"), "{run}");
        assert_eq!(bytes > 0.0, !name.starts_with("no-upload"), "{run}");
        if name.starts_with("upload") {
            assert_eq!(bytes, 640.0 * 360.0 * 3.0, "one BGR frame each: {run}");
        }
    }
    // The first frames' results of the sharpness runs and the single-stream analysis.
    let results = runs("results");
    let recorded: Vec<(&str, u64)> = (results.iter())
        .map(|r| (r["name"].as_str().unwrap(), r["frames"].as_u64().unwrap()))
        .collect();
    let want = [
        ("gray+resize+tenengrad", 24),
        ("gray+resize+laplacian", 24),
        ("analysis", 24),
    ];
    assert_eq!(recorded, want);
    for r in &results {
        let scores = r["sharpness"].as_array().unwrap();
        assert_eq!(scores.len(), 24, "{r}");
        assert!(scores.iter().all(|s| s.as_f64().unwrap() > 0.0), "{r}");
    }
    let analysed = &results[2];
    assert_eq!(analysed["movement"].as_array().unwrap().len(), 24);
    let keys = analysed["stationary"].as_array().unwrap();
    assert!(
        keys.first().and_then(|k| k.as_u64()) == Some(0),
        "{analysed}"
    );
    for run in &analysis {
        let per = &run["per_frame"];
        let (back, waits) = (
            per["read_back"].as_f64().unwrap(),
            per["waits"].as_f64().unwrap(),
        );
        assert!(
            back > 0.0 && back <= 1024.0,
            "read back {back} B/frame: {run}"
        );
        assert!(
            waits <= 1.0 / 16.0,
            "{waits} blocking waits per frame: {run}"
        );
    }
}

#[test]
fn the_benchmark_pulls_no_opencv() {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
    let out = Command::new(env!("CARGO"))
        .current_dir(root)
        .args([
            "tree",
            "--offline",
            "-p",
            "keyframer-gpu-bench",
            "-e",
            "normal",
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("keyframer v") && text.contains("wgpu v"),
        "{text}"
    );
    let cv: Vec<&str> = text.lines().filter(|l| l.contains("opencv")).collect();
    assert!(cv.is_empty(), "{cv:?}");
}
