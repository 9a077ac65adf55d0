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
            "gray+resize+tenengrad",
            "gray+resize+laplacian",
            "farneback",
            "farneback"
        ]
    );
    let sizes: Vec<&str> = kernels
        .iter()
        .map(|k| k["size"].as_str().unwrap())
        .collect();
    assert_eq!(sizes, ["640x360", "640x360", "160x90", "320x180"]);
    let streams: Vec<u64> = analysis
        .iter()
        .map(|a| a["streams"].as_u64().unwrap())
        .collect();
    assert_eq!(streams, [1, 4]);
    for run in kernels.iter().chain(&analysis) {
        let per_s = run["per_s"].as_f64().unwrap();
        assert!(per_s.is_finite() && per_s > 0.0, "{run}");
        assert!(run["wall_s"].as_f64().unwrap() > 0.0, "{run}");
        // With timestamps every run has its device time, and the rate is taken from it.
        if timing == "timestamp" {
            let device = run["device_s"].as_f64().unwrap();
            let count = run["count"].as_f64().unwrap();
            assert!(
                device > 0.0 && (count / device - per_s).abs() <= 1e-6 * per_s,
                "{run}"
            );
        }
        assert!(
            run["per_frame"]["dispatches"].as_f64().unwrap() > 0.0,
            "{run}"
        );
        assert!(
            run["per_frame"]["uploaded"].as_f64().unwrap() > 0.0,
            "{run}"
        );
    }
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
