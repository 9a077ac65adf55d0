//! Export: re-decodes the selected frames in one sequential pass, crops then resizes them
//! (INTER_AREA), writes them atomically with sortable names (or the original names for image
//! folders, copied byte for byte when nothing changes them), and writes a manifest last.

use crate::error::{CvContext, Error, Result};
use crate::fsutil;
use crate::project::Project;
use crate::source::{self, OpenOptions, SourceKind};
use opencv::core::{Mat, Rect, Size, Vector};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Name of the manifest written into every export folder.
pub const MANIFEST: &str = "manifest.json";

/// How to size the exported images.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Resize {
    /// Exact output size in pixels.
    Size { width: u32, height: u32 },
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
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
}

/// Image file format of the export.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// JPEG with a quality setting.
    Jpg,
    /// Lossless PNG.
    Png,
}

impl Format {
    fn ext(self) -> &'static str {
        match self {
            Format::Jpg => "jpg",
            Format::Png => "png",
        }
    }
}

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
}

/// One exported image in the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExportedFrame {
    /// Frame index in the input.
    pub index: usize,
    /// Presentation time in seconds, when known.
    pub timestamp_s: Option<f64>,
    /// File name inside the export folder.
    pub file: String,
}

/// The manifest: what was exported from what, with which settings and which tool.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Always "keyframer".
    pub tool: String,
    /// Version of the tool that wrote it.
    pub tool_version: String,
    /// Seconds since the Unix epoch when the export finished.
    pub created_unix_s: u64,
    /// The project file exported.
    pub project: PathBuf,
    /// The input the frames came from.
    pub source: PathBuf,
    /// Input kind.
    pub source_kind: SourceKind,
    /// Settings used.
    pub settings: ExportSettings,
    /// Size of every exported image.
    pub width: u32,
    /// Size of every exported image.
    pub height: u32,
    /// The exported images, in frame order.
    pub frames: Vec<ExportedFrame>,
    /// Keyframes that could not be exported, with the reason.
    pub missing: Vec<MissingFrame>,
}

/// A keyframe that could not be exported.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MissingFrame {
    /// Frame index.
    pub index: usize,
    /// Why.
    pub reason: String,
}

/// Checks the crop against the frame and returns the output size.
pub fn output_size(settings: &ExportSettings, width: u32, height: u32) -> Result<(u32, u32)> {
    let (w, h) = match settings.crop {
        Some(c) => {
            if c.width == 0 || c.height == 0 {
                return Err(Error::param("--crop", "width and height must be positive"));
            }
            if u64::from(c.x) + u64::from(c.width) > u64::from(width)
                || u64::from(c.y) + u64::from(c.height) > u64::from(height)
            {
                return Err(Error::param(
                    "--crop",
                    format!(
                        "{},{},{},{} reaches outside the {width}x{height} frame",
                        c.x, c.y, c.width, c.height
                    ),
                ));
            }
            (c.width, c.height)
        }
        None => (width, height),
    };
    Ok(match settings.resize {
        None => (w, h),
        Some(Resize::Size { width, height }) => (width, height),
        Some(Resize::Scale(s)) => {
            let sw = (f64::from(w) * s).round() as u32;
            let sh = (f64::from(h) * s).round() as u32;
            if sw == 0 || sh == 0 {
                return Err(Error::param(
                    "--scale",
                    format!("{s} makes a {w}x{h} frame empty"),
                ));
            }
            (sw, sh)
        }
    })
}

/// Applies crop then resize to one frame.
pub fn transform(image: &Mat, settings: &ExportSettings, out: (u32, u32)) -> Result<Mat> {
    let cropped = match settings.crop {
        Some(c) => Mat::roi(
            image,
            Rect::new(c.x as i32, c.y as i32, c.width as i32, c.height as i32),
        )
        .cv(|| "crop".into())?
        .try_clone()
        .cv(|| "crop copy".into())?,
        None => image.clone(),
    };
    if (cropped.cols() as u32, cropped.rows() as u32) == out {
        return Ok(cropped);
    }
    let mut resized = Mat::default();
    imgproc::resize(
        &cropped,
        &mut resized,
        Size::new(out.0 as i32, out.1 as i32),
        0.0,
        0.0,
        imgproc::INTER_AREA,
    )
    .cv(|| format!("resize to {}x{}", out.0, out.1))?;
    Ok(resized)
}

/// Encodes an image as JPEG (with `quality`) or PNG.
pub fn encode(image: &Mat, format: Format, quality: u8) -> Result<Vec<u8>> {
    let mut params = Vector::<i32>::new();
    if format == Format::Jpg {
        params.push(imgcodecs::IMWRITE_JPEG_QUALITY);
        params.push(i32::from(quality));
    }
    let mut buf = Vector::<u8>::new();
    imgcodecs::imencode(&format!(".{}", format.ext()), image, &mut buf, &params)
        .cv(|| format!("encode {}", format.ext()))?;
    Ok(buf.to_vec())
}

/// Outcome of an export.
pub struct ExportReport {
    /// The manifest as written.
    pub manifest: Manifest,
}

/// Exports the keyframes of the project at `project_path` into `out`.
pub fn export(
    project_path: &Path,
    out: &Path,
    settings: &ExportSettings,
    force: bool,
    quiet: bool,
) -> Result<ExportReport> {
    let project = Project::load(project_path)?;
    let input = project.input_path(project_path);
    check_fingerprint(&project, &input)?;
    if !(1..=100).contains(&settings.quality) {
        return Err(Error::param("--quality", "must be between 1 and 100"));
    }
    let mut src = source::open(&input, &OpenOptions::default())?;
    let meta = src.metadata().clone();
    let size = output_size(settings, meta.width, meta.height)?;
    let old_manifest = read_manifest(&out.join(MANIFEST));
    fsutil::prepare_output_dir(out, force)?;

    let is_video = meta.kind == SourceKind::Video;
    let transforms = settings.crop.is_some() || settings.resize.is_some();
    let digits = (project.metadata.frame_count.max(1) - 1)
        .to_string()
        .len()
        .max(6);
    let timestamps = project.cache.timestamps_s.as_deref();
    let bar = crate::progress::bar(project.keyframes.len() as u64, "export", quiet);
    let mut frames = Vec::new();
    let mut missing = Vec::new();

    // Image files that can be copied as they are never need decoding.
    let byte_copy = !is_video
        && !transforms
        && settings.format.is_none_or(|f| {
            src.file_of(0)
                .and_then(|p| p.extension())
                .map(|e| {
                    let e = e.to_string_lossy().to_ascii_lowercase();
                    e == f.ext() || (f == Format::Jpg && e == "jpeg")
                })
                .unwrap_or(false)
        });
    if byte_copy {
        for &index in &project.keyframes {
            let from = src
                .file_of(index)
                .ok_or_else(|| Error::Frame {
                    path: input.clone(),
                    index,
                    msg: "no such image in the folder".into(),
                })?
                .to_path_buf();
            let name = file_name(&from);
            fsutil::copy_atomic(&from, &out.join(&name))?;
            frames.push(ExportedFrame {
                index,
                timestamp_s: timestamps.and_then(|t| t.get(index).copied()),
                file: name,
            });
            bar.inc(1);
        }
    } else {
        let format = settings.format.unwrap_or(Format::Jpg);
        let names: Vec<String> = project
            .keyframes
            .iter()
            .map(|&i| match src.file_of(i) {
                Some(p) if !is_video => {
                    let stem = p.file_stem().unwrap_or_default().to_string_lossy();
                    let ext = p.extension().unwrap_or_default().to_string_lossy();
                    let keep = settings.format.is_none()
                        && matches!(ext.to_ascii_lowercase().as_str(), "jpg" | "jpeg" | "png");
                    if keep {
                        file_name(p)
                    } else {
                        format!("{stem}.{}", format.ext())
                    }
                }
                _ => format!("frame_{i:0digits$}.{}", format.ext()),
            })
            .collect();
        let mut k = 0;
        let total = project.keyframes.len();
        let result = source::read_indices(src.as_mut(), &project.keyframes, |frame| {
            let img = transform(&frame.image, settings, size)?;
            let name = &names[k];
            let fmt = if name.ends_with(".png") {
                Format::Png
            } else {
                Format::Jpg
            };
            let bytes = encode(&img, fmt, settings.quality)?;
            fsutil::write_atomic(&out.join(name), &bytes)?;
            frames.push(ExportedFrame {
                index: frame.index,
                timestamp_s: frame
                    .timestamp_s
                    .or_else(|| timestamps.and_then(|t| t.get(frame.index).copied())),
                file: name.clone(),
            });
            k += 1;
            bar.inc(1);
            Ok(())
        });
        let not_read = result.map_err(|e| Error::Output {
            path: out.to_path_buf(),
            msg: format!(
                "{e}; export stopped after {} of {total} images (each written whole), no manifest written",
                frames.len()
            ),
        })?;
        let reason = src
            .decode_failure()
            .map(|(_, m)| m)
            .unwrap_or_else(|| "the stream ended before this frame".into());
        missing.extend(not_read.into_iter().map(|index| MissingFrame {
            index,
            reason: reason.clone(),
        }));
    }
    bar.finish_and_clear();

    remove_stale(out, old_manifest.as_ref(), &frames);
    let manifest = Manifest {
        tool: "keyframer".into(),
        tool_version: env!("CARGO_PKG_VERSION").into(),
        created_unix_s: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0),
        project: fsutil::absolute(project_path),
        source: fsutil::absolute(&input),
        source_kind: meta.kind,
        settings: settings.clone(),
        width: size.0,
        height: size.1,
        frames,
        missing,
    };
    let mut text = serde_json::to_string_pretty(&manifest).map_err(|e| Error::Output {
        path: out.join(MANIFEST),
        msg: e.to_string(),
    })?;
    text.push('\n');
    fsutil::write_atomic(&out.join(MANIFEST), text.as_bytes())?;
    Ok(ExportReport { manifest })
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .unwrap_or_default()
        .to_string_lossy()
        .into_owned()
}

/// Refuses to export when the input is no longer the one the project was made from.
pub fn check_fingerprint(project: &Project, input: &Path) -> Result<()> {
    let (kind, now) = crate::select::identify(input)?;
    if kind != project.input.kind || now != project.input.fingerprint {
        return Err(Error::input(
            input,
            "the input changed since the project was made (size, time or content differ); run select again",
        ));
    }
    Ok(())
}

fn read_manifest(path: &Path) -> Option<Manifest> {
    let text = std::fs::read_to_string(path).ok()?;
    serde_json::from_str(&text).ok()
}

/// After a forced re-export, removes the images an earlier export listed in its manifest that the
/// new export did not write. Files keyframer did not write are left alone.
fn remove_stale(out: &Path, old: Option<&Manifest>, new: &[ExportedFrame]) {
    let Some(old) = old else { return };
    for f in &old.frames {
        let name = Path::new(&f.file);
        let plain = name.components().count() == 1;
        if plain && !new.iter().any(|n| n.file == f.file) {
            let p = out.join(name);
            match std::fs::remove_file(&p) {
                Ok(()) => log::info!("removed {} from the earlier export", p.display()),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => log::warn!("{}: cannot remove stale export: {e}", p.display()),
            }
        }
    }
}
