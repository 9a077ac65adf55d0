//! Flags of `keyframer-scene` and their conversion into [`SceneSettings`]; the one-line summary.

use super::path::Preset;
use super::srt::GeoOrigin;
use super::{SceneReport, SceneSettings};
use clap::{Parser, ValueEnum};
use keyframer::error::{Error, Result};
use std::path::{Path, PathBuf};

/// Flight presets on the command line.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum PresetArg {
    /// Lawnmower legs, variable speed (3-9 m/s), fast turns (~57°/s); 45 s by default.
    Survey,
    /// Circle of 50 m around a point of interest, looking at it, variable speed; 50 s.
    Orbit,
    /// The survey with three hovers of 10 % of the length each (1-5 s); 55 s.
    HoverSurvey,
    /// A person's walk (camera 1.6 m above the ground, level) down an L-shaped street of
    /// textured blocks, with a stop and a 90° turn on the spot; 21.5 s.
    Walk,
}

/// Renders a synthetic drone sequence (video.mp4, video.SRT, poses.tum, scene.json): a development tool of
/// keyframer, synthetic data with exact ground truth.
#[derive(Debug, Parser)]
#[command(
    name = "keyframer-scene",
    version,
    long_about = "Development tool of keyframer: renders a synthetic drone flight over textured \
                  hilly terrain with driving cars, with motion blur, on the GPU (wgpu). Writes \
                  OUT_DIR/video.mp4 (H.264, yuv420p, constant fps), video.SRT (DJI-style \
                  telemetry: each frame's true position around --origin), poses.tum (camera-to-world \
                  pose per frame at its mid-shutter time, OpenCV camera axes: x right, y down, z \
                  forward; world z up, metres) and scene.json (intrinsics, hovers, fast turns, \
                  objects).\nExit codes: 0 success; 1 usage or error."
)]
pub struct SceneArgs {
    /// Output folder (refused when not empty, unless --force).
    pub out: PathBuf,
    /// Flight.
    #[arg(long, value_enum, default_value = "survey")]
    pub preset: PresetArg,
    /// Length in seconds (default: 45 survey, 50 orbit, 55 hover-survey).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Frame rate of the video.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Image size WxH (even numbers).
    #[arg(long, default_value = "640x360")]
    pub size: String,
    /// Seed of the terrain, textures, path, speeds and objects.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Renders averaged over the shutter (half a frame interval) per frame; 1 = no motion blur.
    #[arg(long, default_value_t = 8)]
    pub blur_samples: u32,
    /// Folder of the texture photos (default: $KEYFRAMER_TESTDATA/opencv-doc, else
    /// target/testdata/opencv-doc).
    #[arg(long)]
    pub textures: Option<PathBuf>,
    /// Add 16 flat magenta 2 m squares at the positions listed in scene.json (test aid).
    #[arg(long)]
    pub markers: bool,
    /// Replace the contents of a non-empty output folder.
    #[arg(long)]
    pub force: bool,
    /// GPU adapter to use (part of its name).
    #[arg(long)]
    pub adapter: Option<String>,
    /// Where the world origin is on Earth, LAT,LON,ALT (degrees, degrees, metres above sea
    /// level), for video.SRT.
    #[arg(long, default_value = "47.3769,8.5417,408")]
    pub origin: String,
    /// Camera model: pinhole (FOCAL_PER_WIDTH) or equirect (360°: --size must be 2:1; six cube
    /// faces rendered and resampled to ERP with keyframer's conventions, docs/360.md).
    #[arg(long, default_value = "pinhole", value_name = "pinhole|equirect")]
    pub projection: String,
    /// Camera pitch below the horizon in degrees for the survey presets (default 45; 90 looks
    /// straight down).
    #[arg(long, value_name = "DEG")]
    pub pitch: Option<f64>,
    /// No progress bar; only errors and warnings on stderr.
    #[arg(short, long)]
    pub quiet: bool,
}

/// `WxH` as (width, height).
pub fn parse_size(size: &str) -> Result<(u32, u32)> {
    let bad = || Error::param("--size", format!("`{size}` is not WxH"));
    let (w, h) = size.split_once(['x', 'X']).ok_or_else(bad)?;
    let width: u32 = w.trim().parse().map_err(|_| bad())?;
    let height: u32 = h.trim().parse().map_err(|_| bad())?;
    Ok((width, height))
}

/// `LAT,LON,ALT` as a [`GeoOrigin`].
pub fn parse_origin(text: &str) -> Result<GeoOrigin> {
    let bad = |why: &str| Error::param("--origin", format!("`{text}`: {why}"));
    let v: Vec<f64> = text
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| bad("not LAT,LON,ALT numbers"))?;
    let [lat_deg, lon_deg, alt_m] = v[..] else {
        return Err(bad("not three numbers LAT,LON,ALT"));
    };
    if !(lat_deg.abs() < 85.0 && lon_deg.abs() <= 180.0 && alt_m.is_finite()) {
        return Err(bad(
            "latitude within ±85°, longitude within ±180° and a finite altitude",
        ));
    }
    Ok(GeoOrigin {
        lat_deg,
        lon_deg,
        alt_m,
    })
}

impl SceneArgs {
    /// Validated settings.
    pub fn settings(&self) -> Result<SceneSettings> {
        let (width, height) = parse_size(&self.size)?;
        let textures = match &self.textures {
            Some(t) => t.clone(),
            None => std::env::var_os("KEYFRAMER_TESTDATA")
                .map(PathBuf::from)
                .unwrap_or_else(|| PathBuf::from("target/testdata"))
                .join("opencv-doc"),
        };
        if !textures.is_dir() {
            return Err(Error::input(
                &textures,
                "texture photo folder not found (scripts/setup.sh fetches Debian's opencv-doc \
                 examples; or pass --textures)",
            ));
        }
        Ok(SceneSettings {
            out: self.out.clone(),
            preset: match self.preset {
                PresetArg::Survey => Preset::Survey,
                PresetArg::Orbit => Preset::Orbit,
                PresetArg::HoverSurvey => Preset::HoverSurvey,
                PresetArg::Walk => Preset::Walk,
            },
            projection: self.projection.parse()?,
            seconds: self.seconds,
            fps: self.fps,
            width,
            height,
            seed: self.seed,
            blur_samples: self.blur_samples,
            textures,
            markers: self.markers,
            force: self.force,
            quiet: self.quiet,
            adapter: self.adapter.clone(),
            origin: parse_origin(&self.origin)?,
            pitch_deg: self.pitch,
        })
    }
}

/// One line for stderr: frames, size, timing, where.
pub fn summary(r: &SceneReport, out: &Path) -> String {
    let d = &r.description;
    format!(
        "{} frames {}x{} @ {} fps ({}, seed {}, {} sub-samples) in {:.1} s = {:.2} frames/s on {} -> {}",
        d.frame_count,
        d.width,
        d.height,
        d.fps,
        d.preset.name(),
        d.seed,
        d.blur_samples,
        r.render_seconds,
        d.frame_count as f64 / r.render_seconds.max(1e-9),
        r.adapter,
        out.display()
    )
}
