//! `info`: what this machine offers keyframer: wgpu adapters and limits, what `--backend auto`
//! resolves to and why, OpenCV version and video I/O backends, whether `colmap` is on PATH and
//! what the COLMAP `keyframer colmap` would run can do (sparse, undistort, georegister, dense),
//! and the pycolmap `--engine pycolmap` would run.

use crate::gpu::{self, AdapterSummary, AutoDecision};
use serde::Serialize;
use std::path::PathBuf;

/// Everything `keyframer info` reports.
#[derive(Debug, Serialize)]
pub struct Info {
    /// keyframer version.
    pub version: String,
    /// Adapter the gpu backend would use (with the device limits requested), or why none.
    pub selected_adapter: Result<AdapterSummary, String>,
    /// All adapters found, best first.
    pub adapters: Vec<AdapterSummary>,
    /// The backend `--backend auto` (the default) resolves to here, and why.
    pub backend_auto: AutoDecision,
    /// OpenCV's version string.
    pub opencv_version: String,
    /// OpenCV video I/O backends available for reading files.
    pub opencv_video_backends: Vec<String>,
    /// Path of `colmap`, if found on PATH.
    pub colmap: Option<PathBuf>,
    /// What the COLMAP `keyframer colmap` would run (`KEYFRAMER_COLMAP`, else PATH) can do, or
    /// why it cannot be run.
    pub colmap_abilities: Result<ColmapAbilities, String>,
    /// The pycolmap `keyframer colmap --engine pycolmap` would run, or why there is none.
    pub pycolmap: Result<crate::colmap::pycolmap::Pycolmap, String>,
}

/// What a COLMAP installation offers `keyframer colmap`, read from its `colmap help`.
#[derive(Debug, Serialize)]
pub struct ColmapAbilities {
    /// The binary.
    pub bin: PathBuf,
    /// Its version line (with or without CUDA).
    pub version: String,
    /// `--sparse`: feature_extractor, the matchers and mapper are there.
    pub sparse: bool,
    /// `--undistort`: image_undistorter is there.
    pub undistort: bool,
    /// `--georegister`: model_aligner is there.
    pub georegister: bool,
    /// `--dense`: patch_match_stereo is there and the build has CUDA (it needs it).
    pub dense: bool,
}

/// Reads what the COLMAP found by [`crate::colmap::locate`] offers.
pub fn colmap_abilities() -> Result<ColmapAbilities, String> {
    let c = crate::colmap::locate().map_err(|e| e.to_string())?;
    let has = |cmd: &str| {
        c.help
            .lines()
            .any(|l| l.split_whitespace().any(|w| w == cmd))
    };
    Ok(ColmapAbilities {
        sparse: ["feature_extractor", "sequential_matcher", "mapper"]
            .iter()
            .all(|cmd| has(cmd)),
        undistort: has("image_undistorter"),
        georegister: has("model_aligner"),
        dense: c.cuda && has("patch_match_stereo"),
        bin: c.bin,
        version: c.version,
    })
}

/// Gathers the facts; `adapter` is the `--adapter` choice.
pub fn gather(adapter: Option<&str>) -> Info {
    let adapters = gpu::adapters()
        .iter()
        .map(|a| gpu::summarize(&a.get_info(), &a.limits()))
        .collect();
    let selected_adapter = gpu::GpuContext::new(adapter)
        .map(|c| c.summary())
        .map_err(|e| e.to_string());
    Info {
        version: env!("CARGO_PKG_VERSION").into(),
        selected_adapter,
        adapters,
        backend_auto: gpu::auto_backend(adapter),
        opencv_version: opencv::core::get_version_string().unwrap_or_default(),
        opencv_video_backends: video_backends(),
        colmap: crate::fsutil::find_on_path("colmap"),
        colmap_abilities: colmap_abilities(),
        pycolmap: crate::colmap::pycolmap::locate().map_err(|e| e.to_string()),
    }
}

fn video_backends() -> Vec<String> {
    use opencv::videoio;
    let Ok(list) = videoio::get_stream_backends() else {
        return Vec::new();
    };
    list.iter()
        .map(|b| videoio::get_backend_name(b).unwrap_or_else(|_| format!("{b:?}")))
        .collect()
}

/// Human-readable form of [`Info`].
pub fn render(info: &Info) -> String {
    let mut s = format!("keyframer {}\n", info.version);
    match &info.selected_adapter {
        Ok(a) => {
            s += &format!(
                "gpu adapter: {} ({}, {}{})\n  driver: {}\n  limits: storage binding {} MiB, buffer {} MiB, {} invocations/workgroup, {} workgroups/dim, {} KiB workgroup storage\n",
                a.name,
                a.graphics_api,
                a.device_type,
                if a.software { ", software" } else { "" },
                a.driver,
                a.max_storage_buffer_binding_size >> 20,
                a.max_buffer_size >> 20,
                a.max_compute_invocations_per_workgroup,
                a.max_compute_workgroups_per_dimension,
                a.max_compute_workgroup_storage_size >> 10
            );
        }
        Err(e) => s += &format!("gpu adapter: none ({e}); analysis uses the opencv backend\n"),
    }
    for a in &info.adapters {
        s += &format!(
            "  found: {} ({}, {})\n",
            a.name, a.graphics_api, a.device_type
        );
    }
    s += &format!("{}\n", info.backend_auto);
    s += &format!("opencv: {}\n", info.opencv_version);
    s += &format!(
        "  video backends: {}\n",
        info.opencv_video_backends.join(", ")
    );
    s += &match &info.colmap {
        Some(p) => format!("colmap: {}\n", p.display()),
        None => "colmap: not found on PATH (Debian package `colmap`)\n".into(),
    };
    match &info.colmap_abilities {
        Ok(a) => {
            let (mut can, mut cannot) = (Vec::new(), Vec::new());
            for (ok, what) in [
                (a.sparse, "--sparse"),
                (a.undistort, "--undistort"),
                (a.georegister, "--georegister"),
                (a.dense, "--dense"),
            ] {
                if ok { &mut can } else { &mut cannot }.push(what);
            }
            s += &format!(
                "  {} ({}): keyframer colmap can run {}",
                a.version,
                a.bin.display(),
                can.join(" ")
            );
            if !cannot.is_empty() {
                s += &format!("; not {}", cannot.join(" "));
            }
            if !a.dense {
                s += " (dense stereo needs a CUDA build of COLMAP)";
            }
            s += "\n";
        }
        Err(e) => s += &format!("  {e}\n"),
    }
    s += &match &info.pycolmap {
        Ok(p) => format!(
            "pycolmap: {} ({}): maps rig and ERP exports (keyframer colmap) and runs keyframer reconstruct's loop\n",
            p.version,
            p.python.display()
        ),
        Err(e) => format!("pycolmap: {e}\n"),
    };
    s
}
