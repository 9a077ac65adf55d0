//! The export folder's record as plain data: `manifest.json` (what was exported from what, with
//! which settings), the folder's names and layout, and the export settings with their parsing and
//! checks. No decoding, encoding or network code: `workflow`, `colmap`, `eval` and `report` read
//! these without depending on the exporter.

use crate::error::{Error, Result};
use crate::names::Names;
use crate::numbers::positive;
use crate::source::telemetry::Position;
use crate::source::SourceKind;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Name of the manifest written into every export folder.
pub const MANIFEST: &str = "manifest.json";
/// Journal written before files are moved into place and removed after the manifest: the files
/// an interrupted export may have left (earlier and new), so the next export knows them as its own.
pub const PENDING: &str = ".keyframer-pending.json";
/// Sub-folder of an export holding the images.
pub const IMAGE_DIR: &str = "images";
/// Sub-folder of an export holding the COLMAP masks (a sibling of the images: COLMAP, nerfstudio
/// and gsplat read image folders recursively).
pub const MASK_DIR: &str = "masks";
/// Layout of the export folder the manifest describes: 2 = `images/`, `masks/`, `overlays/`
/// beside `manifest.json` (1, images beside the manifest, is no longer written or read).
pub const LAYOUT: u32 = 2;
/// Sub-folder of an export holding the overlay previews.
pub const OVERLAY_DIR: &str = "overlays";

/// Adds what is read of the export folder `dir` to `inputs`: its manifest, images, masks and
/// overlays (not the folder: a report or COLMAP workspace beside them is fine).
pub fn add_export(inputs: &mut crate::output::Inputs, dir: &Path) {
    inputs.add("export manifest", dir.join(MANIFEST));
    for sub in [IMAGE_DIR, MASK_DIR, OVERLAY_DIR] {
        inputs.add("export folder", dir.join(sub));
    }
}

/// How to size the exported images.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Resize {
    /// Exact output size in pixels.
    Size {
        /// Output width in pixels.
        width: u32,
        /// Output height in pixels.
        height: u32,
    },
    /// Scale factor applied to the (cropped) frame.
    Scale(f64),
}

/// A crop rectangle in source-frame pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Crop {
    /// Left edge.
    pub x: u32,
    /// Top edge.
    pub y: u32,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

/// JPEG quality when none is given.
pub const DEFAULT_QUALITY: u8 = 95;

/// Validated export settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExportSettings {
    /// Output size (after the crop).
    pub resize: Option<Resize>,
    /// Part of the source frame to keep; applied before the resize.
    pub crop: Option<Crop>,
    /// Output format; `None` keeps an image folder's files as they are and uses JPEG for video.
    pub format: Option<Format>,
    /// JPEG quality 1..=100.
    pub quality: u8,
    /// Segmentation masks written beside the images (`masks/<image name>.png`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub masks: Option<MaskSettings>,
    /// Write each frame's telemetry position into its JPEG's EXIF and into the manifest (when the
    /// project has positions; `--no-geotag` turns it off). Written only when off: manifests
    /// without it (also those of versions before it) read as on, the default.
    #[serde(default = "on", skip_serializing_if = "is_on")]
    pub geotag: bool,
    /// 360° projects: the views rendered from each frame (`--views`), see docs/360.md.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub views: Option<ViewSettings>,
}

/// How an export renders views from 360° (ERP) frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewSettings {
    /// `cube`, `ring:N,PITCH` or `equirect` ([`crate::equirect::ViewSet`]).
    pub set: String,
    /// Field of view of every pinhole view in degrees.
    pub fov_deg: f64,
    /// Width = height of every pinhole view in pixels.
    pub size: u32,
    /// Radius in degrees of the cap around the nadir hidden by the masks (the operator, the
    /// tripod).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask_nadir_deg: Option<f64>,
    /// Interpolation of the remap.
    pub interp: crate::equirect::Interp,
}

/// `--view-fov` when not given.
pub const DEFAULT_VIEW_FOV: f64 = 90.0;
/// `--view-size` when not given.
pub const DEFAULT_VIEW_SIZE: u32 = 1024;
/// Smallest view side accepted.
pub const MIN_VIEW_SIZE: u32 = 16;
/// Largest exported image side: JPEG stores at most 65535 and libjpeg accepts 65500.
pub const MAX_SIDE: u32 = 65_500;
/// Largest exported image in pixels: OpenCV's own image I/O limit (`CV_IO_MAX_IMAGE_PIXELS`).
pub const MAX_PIXELS: u64 = 1 << 30;

impl ViewSettings {
    /// Refuses views on a project whose frames are not 360° (equirectangular) ones.
    pub fn check_projection(projection: crate::equirect::Projection) -> Result<()> {
        if projection != crate::equirect::Projection::Equirect {
            return Err(Error::param(
                "--views",
                "the project's frames are pinhole ones; views are cut from 360° (equirectangular) projects: select with --projection equirect",
            ));
        }
        Ok(())
    }

    /// Checked view settings from their parts as a user writes them (`--views ring:8,10
    /// --view-fov 96 ...`, or the same keys of a workflow's `[[export]]`): the set parsed and
    /// written in its normal form, the numbers checked by [`ViewSettings::check`] against the
    /// encoders' limits; errors name the flag (`--views`, `--view-fov`, ...).
    pub fn from_parts(
        set: &str,
        fov_deg: f64,
        size: u32,
        mask_nadir_deg: Option<f64>,
        interp: crate::equirect::Interp,
    ) -> Result<ViewSettings> {
        let set: crate::equirect::ViewSet = set.parse()?;
        let s = ViewSettings {
            set: set.to_string(),
            fov_deg,
            size,
            mask_nadir_deg,
            interp,
        };
        s.check((MAX_SIDE, MAX_PIXELS))?;
        Ok(s)
    }

    /// The view set, after checking the view side against [`MIN_VIEW_SIZE`] and the encoders'
    /// limits (`max_side`, `max_pixels`), the field of view and the nadir cap; errors name the
    /// flag.
    pub fn check(&self, (max_side, max_pixels): (u32, u64)) -> Result<crate::equirect::ViewSet> {
        let set: crate::equirect::ViewSet = self.set.parse()?;
        let s = self.size;
        if s < MIN_VIEW_SIZE || s > max_side || u64::from(s) * u64::from(s) > max_pixels {
            return Err(Error::param(
                "--view-size",
                format!("{s} px: views are {MIN_VIEW_SIZE} to {max_side} px a side and at most {max_pixels} pixels (JPEG, PNG and OpenCV's limits)"),
            ));
        }
        if !(self.fov_deg > 1.0 && self.fov_deg < 179.0) {
            let msg = format!("{}°: must be within (1, 179) degrees", self.fov_deg);
            return Err(Error::param("--view-fov", msg));
        }
        if let Some(n) = self.mask_nadir_deg {
            if !(n > 0.0 && n <= 90.0) {
                let msg = format!("{n}°: the cap's radius must be within (0, 90] degrees");
                return Err(Error::param("--mask-nadir", msg));
            }
        }
        Ok(set)
    }
}

fn on() -> bool {
    true
}

fn is_on(b: &bool) -> bool {
    *b
}

impl ExportSettings {
    /// Checked settings from their parts as a user writes them (`--resize 1280x720`, `--crop
    /// x,y,w,h`, or the same keys of a workflow's `[[export]]`); errors name the parameter (`resize`, `crop`, ...).
    pub fn from_parts(
        resize: Option<&str>,
        scale: Option<f64>,
        crop: Option<&str>,
        format: Option<Format>,
        quality: u8,
        masks: Option<MaskSettings>,
        geotag: bool,
    ) -> Result<ExportSettings> {
        let resize = match (resize, scale) {
            (Some(s), _) => {
                let (width, height) = parse_size(s)?;
                Some(Resize::Size { width, height })
            }
            (None, Some(f)) => Some(Resize::Scale(
                positive(f).map_err(|m| Error::param("scale", m))?,
            )),
            (None, None) => None,
        };
        let crop = crop.map(parse_crop).transpose()?;
        if !(1..=100).contains(&quality) {
            return Err(Error::param("quality", "must be between 1 and 100"));
        }
        Ok(ExportSettings {
            resize,
            crop,
            format,
            quality,
            masks,
            geotag,
            views: None,
        })
    }
}

impl ExportSettings {
    /// Refuses views together with a crop or a resize: views are rendered from the whole 360°
    /// frame at their own size.
    pub fn check_whole_frame(&self) -> Result<()> {
        if self.views.is_some() && (self.crop.is_some() || self.resize.is_some()) {
            let msg = "views are rendered from the whole 360° frame: drop --crop, --resize and --scale (--view-size sets their size)";
            return Err(Error::param("--views", msg));
        }
        Ok(())
    }
}

/// Parses `WxH` with both positive.
pub fn parse_size(s: &str) -> Result<(u32, u32)> {
    let bad = || Error::param("resize", format!("`{s}` is not WIDTHxHEIGHT like 1280x720"));
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let w: u32 = w.trim().parse().map_err(|_| bad())?;
    let h: u32 = h.trim().parse().map_err(|_| bad())?;
    if w == 0 || h == 0 {
        return Err(bad());
    }
    // OpenCV reads no image above 2^30 pixels or 2^20 a side (CV_IO_MAX_IMAGE_PIXELS): an
    // export nothing can read back would only exhaust memory.
    if w > 1 << 20 || h > 1 << 20 || u64::from(w) * u64::from(h) > 1 << 30 {
        let msg = format!("`{s}` is larger than images can be (at most 2^30 pixels, 2^20 a side)");
        return Err(Error::param("resize", msg));
    }
    Ok((w, h))
}

/// Parses `X,Y,W,H`.
pub fn parse_crop(s: &str) -> Result<Crop> {
    let bad = || Error::param("crop", format!("`{s}` is not X,Y,W,H like 0,40,1920,1000"));
    let v: Vec<u32> = s
        .split(',')
        .map(|p| p.trim().parse::<u32>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| bad())?;
    let [x, y, width, height] = v[..] else {
        return Err(bad());
    };
    if width == 0 || height == 0 {
        return Err(Error::param("crop", "width and height must be positive"));
    }
    Ok(Crop {
        x,
        y,
        width,
        height,
    })
}

/// One exported image in the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExportedFrame {
    /// Frame index in the input.
    pub index: usize,
    /// Presentation time in seconds, when known.
    pub timestamp_s: Option<f64>,
    /// File name inside the export's `images/` folder (inside `images/<view>/` for a view).
    pub file: String,
    /// The view's folder (a rig export of a 360° project: `images/<view>/`, `masks/<view>/`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view: Option<String>,
    /// Mask file name inside `masks/` (`<file>.png`), when masks were requested.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask: Option<String>,
    /// Overlay preview file name inside `overlays/`, when requested.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub overlay: Option<String>,
    /// The frame's telemetry position (latitude, longitude, altitudes, gimbal, 35 mm focal
    /// length), when the project has one for it and the export geotags.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<Position>,
}

/// The manifest: what was exported from what, with which settings and which tool.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Always "keyframer".
    pub tool: String,
    /// Version of the tool that wrote it.
    pub tool_version: String,
    /// Folder layout ([`LAYOUT`]); manifests without it are of layout 1.
    #[serde(default = "layout_one")]
    pub layout: u32,
    /// Seconds since the Unix epoch when the export finished.
    pub created_unix_s: u64,
    /// The project file exported.
    pub project: PathBuf,
    /// The input the frames came from.
    pub source: PathBuf,
    /// Video or image folder.
    pub source_kind: SourceKind,
    /// How the images were made.
    pub settings: ExportSettings,
    /// Size of every exported image.
    pub width: u32,
    /// Size of every exported image.
    pub height: u32,
    /// The exported images, in frame order.
    pub frames: Vec<ExportedFrame>,
    /// Keyframes that could not be exported, with the reason.
    pub missing: Vec<MissingFrame>,
    /// Mean network time per image when masks were made (ms).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask_ms_per_image: Option<f64>,
    /// A rig export's views (name, yaw, pitch, roll, fov, size), in folder order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub views: Vec<crate::equirect::View>,
}

fn layout_one() -> u32 {
    1
}

/// A keyframe that could not be exported.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MissingFrame {
    /// The keyframe's frame index.
    pub index: usize,
    /// Why it was not exported.
    pub reason: String,
}

crate::names::named_enum! {
    /// Image file format.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum Format: "format" {
        /// JPEG with a quality setting.
        Jpg = "jpg": "JPEG",
        /// Lossless PNG.
        Png = "png": "PNG",
    }
}

impl Format {
    /// File extension (the format's name).
    pub fn ext(self) -> &'static str {
        self.name()
    }
}

/// Where the images of an export go, relative to its folder.
pub fn image_path(out: &Path, f: &ExportedFrame) -> PathBuf {
    out.join(IMAGE_DIR).join(f.rel())
}

impl ExportedFrame {
    /// The image's path inside `images/` (and its mask's inside `masks/`, less `.png`):
    /// `<view>/<file>` for a view, else `<file>`.
    pub fn rel(&self) -> PathBuf {
        match &self.view {
            Some(v) => Path::new(v).join(&self.file),
            None => PathBuf::from(&self.file),
        }
    }
}

/// Every file an export lists, relative to its folder (images, masks, overlays).
pub fn listed_files(frames: &[ExportedFrame]) -> Vec<PathBuf> {
    let mut v = Vec::new();
    for f in frames {
        let dir = |d: &str| match &f.view {
            Some(view) => Path::new(d).join(view),
            None => PathBuf::from(d),
        };
        v.push(dir(IMAGE_DIR).join(&f.file));
        v.extend(f.mask.iter().map(|m| dir(MASK_DIR).join(m)));
        v.extend(f.overlay.iter().map(|o| dir(OVERLAY_DIR).join(o)));
    }
    v
}

/// Reads an export's manifest, if present and valid.
pub fn read_manifest(path: &Path) -> Option<Manifest> {
    Manifest::load(path).ok()
}

impl Manifest {
    /// Reads and checks a manifest: the current layout, every name a plain file name.
    pub fn load(path: &Path) -> Result<Manifest> {
        let m: Manifest = crate::output::read_json(path, "export manifest")?;
        let bad = |field: &str, msg: &str| Error::file(path, None, "export manifest", field, msg);
        if m.layout != LAYOUT {
            return Err(bad(
                "layout",
                "made by an older keyframer (images beside manifest.json, no images/ folder); export again into a new folder",
            ));
        }
        for (k, f) in m.frames.iter().enumerate() {
            crate::output::plain_name(&f.file, &format!("frames[{k}].file"), path)?;
            if let Some(x) = &f.mask {
                crate::output::plain_name(x, &format!("frames[{k}].mask"), path)?;
            }
            if let Some(x) = &f.overlay {
                crate::output::plain_name(x, &format!("frames[{k}].overlay"), path)?;
            }
            if let Some(x) = &f.view {
                crate::output::plain_name(x, &format!("frames[{k}].view"), path)?;
                if !m.views.iter().any(|v| &v.name == x) {
                    return Err(bad(&format!("frames[{k}].view"), "not one of `views`"));
                }
            }
        }
        let mut names: Vec<PathBuf> = m.frames.iter().map(ExportedFrame::rel).collect();
        names.sort_unstable();
        if names.windows(2).any(|w| w[0] == w[1]) {
            return Err(bad("frames", "lists one file twice"));
        }
        Ok(m)
    }
}

crate::names::named_enum! {
    /// Which runtime executes the network.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub enum SegRuntime: "mask-backend" {
        /// OpenCV DNN on the CPU (every format OpenCV reads).
        #[default]
        Opencv = "opencv": "OpenCV DNN (every format OpenCV reads)",
        /// ONNX Runtime through the `ort` crate (ONNX models only; library loaded at run time).
        Ort = "ort": "ONNX Runtime (ONNX models; library from ORT_DYLIB_PATH)",
    }
}

/// Segmentation masks of an export: the model, the hidden classes and the runtime.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MaskSettings {
    /// Model description file.
    pub model: std::path::PathBuf,
    /// Class names whose pixels are hidden.
    pub classes: Vec<String>,
    /// Grow the hidden area by this many pixels (of the exported image).
    pub dilate: u32,
    /// Runtime that ran the network.
    pub backend: SegRuntime,
    /// Also write colour overlays of the class map.
    pub overlay: bool,
}
