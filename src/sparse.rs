//! The options of COLMAP's sparse reconstruction (`keyframer colmap --sparse`) and of the
//! `reconstruct` loop as plain data, with their one check and their defaults: what projects,
//! workflows and `reconstruct.json` record. No COLMAP runs here, so the file formats can read them.

use crate::error::{Error, Result};
use crate::manifest::ExportSettings;
use serde::{Deserialize, Serialize};

/// Defaults of the options (the `colmap` and `reconstruct` flags' defaults too).
pub mod defaults {
    /// Feature matching strategy.
    pub const MATCHER: super::Matcher = super::Matcher::Sequential;
    /// Sequential matching: how many following images each image is matched with.
    pub const OVERLAP: u32 = 10;
    /// COLMAP camera model shared by all images.
    pub const CAMERA_MODEL: &str = "SIMPLE_RADIAL";
    /// Rounds of COLMAP at most.
    pub const MAX_ROUNDS: usize = 4;
    /// The mapper.
    pub const MAPPER: super::MapperKind = super::MapperKind::Incremental;
    /// How later rounds map.
    pub const MAPPING: super::Mapping = super::Mapping::Fresh;
    /// Frames added at most: twice the starting keyframes.
    pub const MAX_ADDED: &str = "200%";
    /// Fewest 3D points consecutive keyframes must share.
    pub const MIN_SHARED: usize = 15;
    /// Fewest inlier matches of consecutive keyframes' two-view geometry (COLMAP's own minimum
    /// for a verified pair).
    pub const MIN_INLIERS: usize = 15;
}

crate::names::named_enum! {
    /// Feature matching strategy.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum Matcher: "matcher" {
        /// `sequential_matcher`: neighbours in file-name (video) order.
        Sequential = "sequential": "`sequential_matcher`: neighbours in file-name (video) order",
        /// `exhaustive_matcher`: every pair.
        Exhaustive = "exhaustive": "`exhaustive_matcher`: every pair",
    }
}

/// COLMAP's options that decide a sparse model, shared by `colmap` and `reconstruct`; each
/// field is the flag of the same name.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SparseOptions {
    /// Feature matching strategy.
    pub matcher: Matcher,
    /// Sequential matching: how many following images each image is matched with.
    pub overlap: u32,
    /// COLMAP camera model shared by all images.
    pub camera_model: String,
    /// Known intrinsics, comma-separated in COLMAP's order; the mapper keeps them fixed.
    pub camera_params: Option<String>,
    /// Maximum SIFT features per image (None: COLMAP's default).
    pub max_features: Option<u32>,
    /// Extra mapper options `KEY=VALUE`, passed as `--Mapper.KEY VALUE`.
    pub mapper_option: Vec<String>,
}

impl SparseOptions {
    /// Checks the options COLMAP would otherwise refuse only after the workspace is made.
    pub fn check(&self) -> Result<()> {
        if self.overlap == 0 {
            return Err(Error::param("overlap", "must be at least 1"));
        }
        if !CAMERA_MODELS.iter().any(|m| m.1 == self.camera_model) {
            let names: Vec<&str> = CAMERA_MODELS.iter().map(|m| m.1).collect();
            let msg = format!("`{}` is not one of {}", self.camera_model, names.join(", "));
            return Err(Error::param("camera_model", msg));
        }
        mapper_keys(&self.mapper_option)?;
        if let Some(params) = &self.camera_params {
            camera_params(params)?;
        }
        Ok(())
    }
}

/// Checks `--camera-params`: comma-separated finite numbers.
pub fn camera_params(text: &str) -> Result<Vec<f64>> {
    text.split(',')
        .map(|v| match v.trim().parse::<f64>() {
            Ok(x) if x.is_finite() => Ok(x),
            _ => Err(Error::param(
                "camera_params",
                format!("`{v}` is not a number (give e.g. `448,448,320,180` for PINHOLE)"),
            )),
        })
        .collect()
}

/// `KEY=VALUE` mapper options as (`--Mapper.KEY`, `VALUE`).
pub fn mapper_keys(options: &[String]) -> Result<Vec<(String, String)>> {
    options
        .iter()
        .map(|o| match o.split_once('=') {
            Some((k, v)) if !k.trim().is_empty() && !v.trim().is_empty() => {
                let k = k.trim().trim_start_matches("Mapper.");
                Ok((format!("--Mapper.{k}"), v.trim().to_string()))
            }
            _ => Err(Error::param(
                "mapper_option",
                format!("`{o}` is not KEY=VALUE"),
            )),
        })
        .collect()
}

/// COLMAP camera models: (id, name, number of parameters).
pub const CAMERA_MODELS: [(i32, &str, usize); 11] = [
    (0, "SIMPLE_PINHOLE", 3),
    (1, "PINHOLE", 4),
    (2, "SIMPLE_RADIAL", 4),
    (3, "RADIAL", 5),
    (4, "OPENCV", 8),
    (5, "OPENCV_FISHEYE", 8),
    (6, "FULL_OPENCV", 12),
    (7, "FOV", 5),
    (8, "SIMPLE_RADIAL_FISHEYE", 4),
    (9, "RADIAL_FISHEYE", 5),
    (10, "THIN_PRISM_FISHEYE", 12),
];

/// Camera models only recent COLMAP writes (pycolmap, `keyframer colmap --engine pycolmap` on an
/// `export --views equirect`): read in model files, never asked of COLMAP 3.8's command line.
pub const RECENT_CAMERA_MODELS: [(i32, &str, usize); 1] = [(17, "EQUIRECTANGULAR", 2)];

/// Every camera model keyframer reads in a model file: (id, name, number of parameters).
pub fn model_file_cameras() -> impl Iterator<Item = &'static (i32, &'static str, usize)> {
    CAMERA_MODELS.iter().chain(RECENT_CAMERA_MODELS.iter())
}

crate::names::named_enum! {
    /// Which COLMAP runs the sparse stages (`keyframer colmap --engine`, `reconstruct --engine`).
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum Engine: "engine" {
        /// pycolmap where keyframer prefers it and finds it (rig and ERP exports, the
        /// `reconstruct` loop), else the `colmap` command.
        Auto = "auto": "pycolmap where it maps better and is found (rig and ERP exports; the reconstruct loop), else the colmap command",
        /// The `colmap` command line (the installed COLMAP).
        Colmap = "colmap": "the colmap command (a rig export: one camera per view folder, views registered one by one)",
        /// pycolmap (PyPI): a recent COLMAP; rig-aware mapping for a rig export.
        Pycolmap = "pycolmap": "pycolmap, a recent COLMAP from PyPI (a rig export: its views mapped as one rig)",
    }
}

impl Default for Engine {
    /// `auto`, also for the options of workspaces made before the flag existed (they resume with
    /// the engine their state file records).
    fn default() -> Engine {
        Engine::Auto
    }
}

crate::names::named_enum! {
    /// Which mapper builds the model.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum MapperKind: "mapper" {
        /// `colmap mapper`: incremental structure from motion (every COLMAP).
        Incremental = "incremental": "COLMAP's incremental `mapper` (every COLMAP)",
        /// `colmap global_mapper`: global structure from motion (recent COLMAP only).
        Global = "global": "COLMAP's `global_mapper` (COLMAP 3.12 and later)",
    }
}

crate::names::named_enum! {
    /// How a later round maps.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum Mapping: "mapping" {
        /// A fresh mapping of every image of the database (features and matches are reused).
        Fresh = "fresh": "map every image afresh (features and matches are reused)",
        /// `mapper --input_path` the largest model: registers the new images into it (other
        /// models are not carried over: their images are mapped again into it or left out).
        Continue = "continue": "`mapper --input_path` the largest model with the new images",
    }
}

/// How many frames the loop may add in all.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Budget {
    /// At most this many frames.
    Frames(usize),
    /// At most this percentage of the starting keyframe count (rounded up).
    Percent(f64),
}

impl Budget {
    /// `N` or `P%`; errors name the parameter `max_added`.
    pub fn parse(text: &str) -> Result<Budget> {
        let t = text.trim();
        let bad = || {
            Error::param(
                "max_added",
                format!("`{text}` is neither a frame count (`40`) nor a percentage (`50%`)"),
            )
        };
        if let Some(p) = t.strip_suffix('%') {
            let v: f64 = p.trim().parse().map_err(|_| bad())?;
            if !(v.is_finite() && v >= 0.0) {
                return Err(bad());
            }
            return Ok(Budget::Percent(v));
        }
        t.parse().map(Budget::Frames).map_err(|_| bad())
    }

    /// The number of frames it allows for a start of `start` keyframes.
    pub fn frames(&self, start: usize) -> usize {
        match *self {
            Budget::Frames(n) => n,
            Budget::Percent(p) => (p / 100.0 * start as f64).ceil() as usize,
        }
    }
}

/// The options of a loop that decide its result; a workspace made with other options is not
/// resumed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Options {
    /// Rounds of COLMAP at most (the first reconstructs the starting keyframes).
    pub max_rounds: usize,
    /// Frames added at most, over all rounds.
    pub max_added: Budget,
    /// What makes a link weak.
    pub limits: Limits,
    /// COLMAP's options (recorded inline, as the flags of the same names).
    #[serde(flatten)]
    pub colmap: SparseOptions,
    /// Incremental or global mapper.
    pub mapper: MapperKind,
    /// How later rounds map: continuing the largest model, or afresh.
    pub mapping: Mapping,
    /// Which COLMAP runs the loop (`auto`: pycolmap when found).
    #[serde(default)]
    pub engine: Engine,
    /// How the images are exported.
    pub export: ExportSettings,
}

/// Checks the options before anything runs: the one check of `reconstruct`'s flags and of a
/// workflow's `[[reconstruct]]` table. Errors name the option's key (`max_rounds`,
/// `camera_model`, ...); COLMAP's options are checked as `keyframer colmap` checks them.
pub fn check(o: &Options) -> Result<()> {
    if o.max_rounds == 0 {
        return Err(Error::param("max_rounds", "must be at least 1"));
    }
    if o.mapper == MapperKind::Global && o.mapping == Mapping::Continue {
        let msg = "`continue` extends a model with the incremental mapper; the global mapper maps every image at once (use `fresh`)";
        return Err(Error::param("mapping", msg));
    }
    o.colmap.check()
}

/// The thresholds of a weak link.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Limits {
    /// Fewest 3D points consecutive keyframes must share.
    pub min_shared: usize,
    /// Fewest inlier matches of their two-view geometry.
    pub min_inliers: usize,
}
