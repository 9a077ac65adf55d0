//! Analysis parameters and results as plain data: what projects, workflows and step lists
//! record (backend, sharpness metric, Farnebäck parameters, movement statistic and request,
//! movement series), with their checks. No GPU, OpenCV or analysis code here: file formats
//! depend on this module, and the engines re-export its types where they use them.

use crate::error::{Error, Result};
use crate::names::{Names, Table};
use crate::numbers::{positive, seconds};
use serde::{Deserialize, Serialize};

crate::names::named_enum! {
    /// Which implementation runs the per-frame kernels.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum Backend: "backend" {
        /// WGSL compute shaders through wgpu.
        Gpu = "gpu": "WGSL compute shaders through wgpu",
        /// OpenCV's CPU functions (the reference).
        Opencv = "opencv": "OpenCV on the CPU",
    }
}

crate::names::named_enum! {
    /// The backend a command or workflow asks for. Projects record the [`Backend`] it resolved
    /// to (`crate::gpu::resolve_backend`), never `auto`.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub enum BackendChoice: "backend" {
        /// The gpu backend where it pays off on this machine's adapter, else opencv
        /// (`crate::gpu::auto_backend`).
        #[default]
        Auto = "auto": "gpu on a hardware adapter, opencv on a software one (lavapipe, llvmpipe, \
            WARP, SwiftShader) or without an adapter; said once on stderr, shown by `keyframer info`",
        /// The gpu backend (opencv when there is no usable adapter).
        Gpu = "gpu": "WGSL compute shaders through wgpu (opencv, with a warning, without an \
            adapter or after a GPU fault)",
        /// The opencv backend.
        Opencv = "opencv": "OpenCV on the CPU",
    }
}

/// A sharpness measure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Metric {
    /// Mean of Gx² + Gy² of the 3x3 Sobel gradients.
    Tenengrad,
    /// Variance of the Laplacian with OpenCV aperture `ksize` (1 or 3).
    Laplacian {
        /// 1 (4-neighbour kernel) or 3.
        ksize: u32,
    },
}

impl Names for Metric {
    const FLAG: &'static str = "metric";
    const NAMES: Table<Self> = &[
        (
            "tenengrad",
            Metric::Tenengrad,
            "Mean squared Sobel gradient",
        ),
        (
            "laplacian-k1",
            Self::Laplacian { ksize: 1 },
            "Laplacian variance, 4 neighbours",
        ),
        (
            "laplacian-k3",
            Self::Laplacian { ksize: 3 },
            "Laplacian variance, aperture 3",
        ),
        ("laplacian", Self::Laplacian { ksize: 1 }, "laplacian-k1"),
    ];
}
crate::names::impl_names!(Metric, serde);

/// Parameters of cv::calcOpticalFlowFarneback.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FarnebackParams {
    /// Scale between pyramid levels (< 1).
    pub pyr_scale: f64,
    /// Number of pyramid levels below the full resolution (fewer when the image gets small).
    pub levels: u32,
    /// Averaging window size.
    pub winsize: u32,
    /// Iterations per level.
    pub iterations: u32,
    /// Neighbourhood of the polynomial expansion (5 or 7).
    pub poly_n: u32,
    /// Gaussian sigma of the polynomial expansion.
    pub poly_sigma: f64,
    /// Gaussian window (OPTFLOW_FARNEBACK_GAUSSIAN) instead of a box.
    pub gaussian: bool,
}

impl Default for FarnebackParams {
    /// The parameters of OpenCV's Farneback tutorial: 0.5, 3, 15, 3, 5, 1.2, box window.
    fn default() -> Self {
        FarnebackParams {
            pyr_scale: 0.5,
            levels: 3,
            winsize: 15,
            iterations: 3,
            poly_n: 5,
            poly_sigma: 1.2,
            gaussian: false,
        }
    }
}

impl FarnebackParams {
    /// Most pyramid levels: 2^-32 of any image is below one pixel at the usual scale of 0.5, and
    /// a scale near 1 with thousands of levels would only allocate buffers.
    pub const MAX_LEVELS: u32 = 32;
    /// Largest averaging window: wider than any analysis image worth a window (its cost grows
    /// with the size, and `winsize²` must stay far from overflowing).
    pub const MAX_WINSIZE: u32 = 1001;
    /// Most iterations per level: 30x the usual 3; the flow stops changing long before.
    pub const MAX_ITERATIONS: u32 = 100;

    /// Checks the ranges OpenCV accepts and keyframer bounds; errors name the parameter (`levels`; the binary shows its flag).
    pub fn validate(&self) -> Result<()> {
        let bad = |name: &str, msg: String| Err(Error::param(name, msg));
        if !(self.pyr_scale > 0.0 && self.pyr_scale < 1.0) {
            let msg = format!("must be in (0, 1), got {}", self.pyr_scale);
            return bad("pyr_scale", msg);
        }
        if self.levels > Self::MAX_LEVELS {
            let msg = format!("must be at most {}, got {}", Self::MAX_LEVELS, self.levels);
            return bad("levels", msg);
        }
        let up_to = |name: &str, v: u32, max: u32| {
            if (1..=max).contains(&v) {
                Ok(())
            } else {
                bad(name, format!("must be between 1 and {max}, got {v}"))
            }
        };
        up_to("winsize", self.winsize, Self::MAX_WINSIZE)?;
        up_to("iterations", self.iterations, Self::MAX_ITERATIONS)?;
        if self.poly_n != 5 && self.poly_n != 7 {
            return bad("poly_n", format!("must be 5 or 7, got {}", self.poly_n));
        }
        positive(self.poly_sigma)
            .map(drop)
            .or_else(|msg| bad("poly_sigma", msg))
    }
}

/// Which robust statistic of the flow magnitudes measures movement.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Statistic {
    /// The median (mean of the two middle values for an even count), as iVS3D's code uses.
    Median,
    /// The mean after dropping the `trim` fraction of smallest and of largest values, as the
    /// iVS3D paper describes.
    TrimmedMean {
        /// Fraction dropped at each end, in [0, 0.5).
        trim: f64,
    },
}

impl Names for Statistic {
    const FLAG: &'static str = "movement";
    const NAMES: Table<Self> = &[
        ("median", Statistic::Median, "Median of the flow magnitudes"),
        (
            "trimmed-mean",
            Statistic::TrimmedMean {
                trim: Statistic::DEFAULT_TRIM,
            },
            "Trimmed mean of the flow magnitudes (--trim at each end)",
        ),
    ];
}

impl Statistic {
    /// Fraction dropped at each end by `trimmed-mean` when none is given.
    pub const DEFAULT_TRIM: f64 = 0.1;

    /// The `--movement` flag value and `--trim` for this statistic.
    pub fn to_flag(self) -> (&'static str, Option<f64>) {
        match self {
            Statistic::Median => (self.name(), None),
            Statistic::TrimmedMean { trim } => (self.name(), Some(trim)),
        }
    }

    /// The same statistic, trimming `trim` at each end if it trims.
    pub fn with_trim(self, trim: f64) -> Statistic {
        match self {
            Statistic::TrimmedMean { .. } => Statistic::TrimmedMean { trim },
            median => median,
        }
    }

    /// Checks the trim fraction.
    pub fn validate(&self) -> Result<()> {
        if let Statistic::TrimmedMean { trim } = self {
            if !(0.0..0.5).contains(trim) {
                let msg = format!("must be in [0, 0.5), got {trim}");
                return Err(Error::param("trim", msg));
            }
        }
        Ok(())
    }

    /// The 0-based ranks (lo, hi inclusive) the statistic needs among `n` sorted values.
    pub fn ranks(&self, n: u32) -> (u32, u32) {
        match self {
            Statistic::Median => ((n - 1) / 2, n / 2),
            Statistic::TrimmedMean { trim } => {
                let cut = (f64::from(n) * trim).floor() as u32;
                (cut, n - cut - 1)
            }
        }
    }
}

/// Rotation compensation: the flow is measured after subtracting the flow of the camera rotation
/// that best explains it, for a pinhole camera with this horizontal field of view and its
/// principal point at the image centre.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Derotate {
    /// Horizontal field of view in degrees (the focal length is width / (2 tan(hfov / 2))).
    pub hfov_deg: f64,
}

impl Derotate {
    /// The field of view assumed when none is given: 70 degrees, typical of drone and phone main
    /// cameras.
    pub const DEFAULT_HFOV_DEG: f64 = 70.0;

    /// Checks the field of view.
    pub fn validate(&self) -> Result<()> {
        if !(self.hfov_deg > 1.0 && self.hfov_deg < 179.0) {
            let msg = format!("{} must be between 1 and 179 degrees", self.hfov_deg);
            return Err(Error::param("hfov", msg));
        }
        Ok(())
    }

    /// Focal length in pixels for an image `width` pixels wide.
    pub fn focal(&self, width: u32) -> f64 {
        f64::from(width) / (2.0 * (self.hfov_deg.to_radians() / 2.0).tan())
    }
}

/// Movement on 360° (equirectangular) frames: measured on square pinhole views around the
/// horizon, with one rotation of the sphere fitted to all views' flows together and removed
/// (`kernels::sphere`), so that turning on the spot is no movement.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SphereViews {
    /// Views evenly around the horizon (the first forward).
    pub views: u32,
    /// Field of view of each view in degrees (its size follows from the analysis width:
    /// `equirect::native_view_size`).
    pub fov_deg: f64,
}

impl SphereViews {
    /// Four views of 90°: two thirds of the sphere (latitudes within ±45° at the views' centres,
    /// ±54.7° at their corners), no direction seen twice, 0.81 times the ERP frame's pixels.
    pub const DEFAULT: SphereViews = SphereViews {
        views: 4,
        fov_deg: 90.0,
    };

    /// Checks the view count (1 to `kernels::sphere::MAX_VIEWS`, 8) and field of view.
    pub fn validate(&self) -> Result<()> {
        if !(1..=8).contains(&self.views) {
            let msg = format!("{} views: 1 to 8", self.views);
            return Err(Error::param("sphere views", msg));
        }
        if !(self.fov_deg >= 10.0 && self.fov_deg <= 170.0) {
            let msg = format!("{} degrees: 10 to 170", self.fov_deg);
            return Err(Error::param("sphere view fov", msg));
        }
        Ok(())
    }
}

/// The rows of a frame a sharpness score is computed on, as an image of its own (its first
/// and last rows mirror inside it): on 360° frames the band |latitude| < 45°
/// (`Rows::erp_band`), where a turn's blur is not diluted by the stretched poles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Rows {
    /// First row.
    pub first: u32,
    /// Number of rows.
    pub count: u32,
}

impl Rows {
    /// The rows sharpness is scored on in an ERP frame `height` rows high: the band |latitude|
    /// < 45° (the rows whose centre lies within 45° of the equator: H/4 to H − H/4 when 4
    /// divides H), half the frame's pixels and 71 % of the sphere. The whole frame's score is
    /// diluted by the rows near the poles, which are stretched and barely move in a turn
    /// (docs/360.md "Analysis on the sphere": measured against the horizon views). A frame under
    /// 4 rows is scored whole.
    pub fn erp_band(height: u32) -> Rows {
        let first = if height < 4 { 0 } else { (height + 1) / 4 };
        Rows {
            first,
            count: height - 2 * first,
        }
    }

    /// Checks the rows lie inside a frame `height` rows high and are not empty.
    pub fn check(&self, height: u32) -> Result<()> {
        let end = u64::from(self.first) + u64::from(self.count);
        if self.count == 0 || end > u64::from(height) {
            let msg = format!("rows {}..{} of a frame {height} rows high", self.first, end);
            return Err(Error::param("sharpness rows", msg));
        }
        Ok(())
    }
}

/// How movement is measured.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MovementRequest {
    /// Optical flow parameters.
    pub farneback: FarnebackParams,
    /// Statistic of the flow magnitudes.
    pub statistic: Statistic,
    /// Width of the analysis resolution (frames are converted to gray and resized with
    /// INTER_AREA; never upscaled).
    pub analysis_width: u32,
    /// Flow is measured between frames `stride` apart (every frame index divisible by it, and
    /// the last); each frame in between gets an equal share. 1 measures every pair.
    #[serde(default = "one")]
    pub stride: u32,
    /// Subtract the flow of the best-fitting camera rotation before taking the statistic (the
    /// movement then follows translation, which gives reconstructions their baseline).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub derotate: Option<Derotate>,
    /// On 360° frames: the horizon views measured and derotated together (`derotate` is then
    /// unused: the sphere's rotation is always removed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sphere: Option<SphereViews>,
}

impl MovementRequest {
    /// Checks how movement is to be measured (every sampler that reads movement shares it);
    /// errors name the parameter (`flow_stride`).
    pub fn validate(&self) -> Result<()> {
        self.statistic.validate()?;
        if self.stride == 0 {
            return Err(Error::param("flow_stride", "must be at least 1"));
        }
        if self.analysis_width < 16 {
            let msg = format!("must be at least 16 pixels, got {}", self.analysis_width);
            return Err(Error::param("analysis_width", msg));
        }
        if let Some(d) = &self.derotate {
            d.validate()?;
        }
        if let Some(v) = &self.sphere {
            v.validate()?;
        }
        self.farneback.validate()
    }

    /// The `select` flags that measure movement this way (Farnebäck parameters only where they
    /// differ from the defaults). `--hfov` is shared with the footprint step's field of view.
    pub fn to_flags(&self) -> Vec<String> {
        let (statistic, trim) = self.statistic.to_flag();
        let (f, d) = (self.farneback, FarnebackParams::default());
        let mut pairs = vec![
            ("movement", Some(statistic.to_string())),
            ("trim", trim.map(|t| t.to_string())),
            ("analysis-width", Some(self.analysis_width.to_string())),
            ("flow-stride", Some(self.stride.to_string())),
            ("hfov", self.derotate.map(|r| r.hfov_deg.to_string())),
            ("projection", self.sphere.map(|_| "equirect".to_string())),
        ];
        let unless_default = |k, v: fn(&FarnebackParams) -> String| {
            let value = v(&f);
            (k, (value != v(&d)).then_some(value))
        };
        pairs.extend([
            unless_default("pyr-scale", |p| p.pyr_scale.to_string()),
            unless_default("levels", |p| p.levels.to_string()),
            unless_default("winsize", |p| p.winsize.to_string()),
            unless_default("iterations", |p| p.iterations.to_string()),
            unless_default("poly-n", |p| p.poly_n.to_string()),
            unless_default("poly-sigma", |p| p.poly_sigma.to_string()),
        ]);
        let mut out: Vec<String> = (pairs.into_iter())
            .filter_map(|(k, v)| Some([format!("--{k}"), v?]))
            .flatten()
            .collect();
        let switches = [
            ("derotate", self.derotate.is_some()),
            ("gaussian", f.gaussian),
        ];
        out.extend(
            switches
                .iter()
                .filter(|s| s.1)
                .map(|s| format!("--{}", s.0)),
        );
        out
    }
}

/// The one check of what `select`'s flags and a workflow's `[analysis]` both give: how movement
/// is measured, the frame rate assumed for an image folder and the telemetry clock offset.
/// Errors name the parameter by its key (`images_fps`; the binary shows its flag).
pub fn check_analysis(
    movement: &MovementRequest,
    images_fps: Option<f64>,
    telemetry_offset_s: f64,
) -> Result<()> {
    movement.validate()?;
    images_fps
        .map(positive)
        .transpose()
        .map_err(|m| Error::param("images_fps", m))?;
    seconds(telemetry_offset_s).map_err(|m| Error::param("telemetry_offset", m))?;
    Ok(())
}

fn one() -> u32 {
    1
}

/// The stationary sampler's parameters (reference mode).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StationaryRequest {
    /// Movement (full-resolution pixels) since the last keyframe that makes a new keyframe.
    pub threshold: f64,
    /// Frames after which the reference is re-anchored, carrying the accumulated movement.
    pub reset_delta: usize,
    /// First candidate frame.
    pub first: usize,
    /// Last candidate frame (inclusive).
    pub last: usize,
}

/// Movement between consecutive frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MovementSeries {
    /// Analysis width in pixels.
    pub width: u32,
    /// Analysis height in pixels.
    pub height: u32,
    /// Factor from analysis pixels to full-resolution pixels.
    pub scale_to_full: f64,
    /// values[i] = movement from frame i-1 to frame i in full-resolution pixels; values[0] = 0.
    pub values: Vec<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ERP band's rows are |latitude| < 45° (at row centres), symmetric about the equator.
    #[test]
    fn erp_band_is_the_middle_half() {
        for h in [4u32, 5, 6, 7, 512, 1920, 1921, 1922] {
            let r = Rows::erp_band(h);
            assert_eq!(r.first, h - (r.first + r.count), "symmetric at {h}");
            r.check(h).unwrap();
            let lat = |y: u32| crate::equirect::lon_lat(0.0, f64::from(y), (2 * h, h)).1;
            assert!(lat(r.first) <= 45.0 + 1e-9, "{h}: first row inside");
            assert!(lat(r.first - 1) > 45.0 + 1e-9, "{h}: the row above outside");
        }
        assert_eq!(
            Rows::erp_band(512),
            Rows {
                first: 128,
                count: 256
            }
        );
        assert_eq!(Rows::erp_band(3).count, 3, "a tiny frame is scored whole");
    }
}
