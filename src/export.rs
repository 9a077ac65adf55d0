//! Export: re-decodes the selected frames in one sequential pass, crops then resizes them
//! (INTER_AREA), writes them atomically with sortable names (or the original names for image
//! folders, copied byte for byte when nothing changes them), and writes a manifest last.

use crate::error::{CvContext, Error, Result};
use crate::fsutil;
use crate::project::Project;
use crate::segment::{MaskSettings, Segmenter};
use crate::source::{self, OpenOptions, SourceKind};
use opencv::core::{Mat, Rect, Size, Vector};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Name of the manifest written into every export folder.
pub const MANIFEST: &str = "manifest.json";
/// Sub-folder of an export holding the COLMAP masks.
pub const MASK_DIR: &str = "masks";
/// Sub-folder of an export holding the overlay previews.
pub const OVERLAY_DIR: &str = "overlays";

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
    /// File extension.
    pub fn ext(self) -> &'static str {
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
    /// Segmentation masks written beside the images (`masks/<image name>.png`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub masks: Option<MaskSettings>,
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
    /// Mask file (`masks/<file>.png`), when masks were requested.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask: Option<String>,
    /// Overlay preview (`overlays/<file>`), when requested.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub overlay: Option<String>,
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
    /// Mean network time per image when masks were made (ms).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask_ms_per_image: Option<f64>,
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
    // The model is loaded and checked before anything is written.
    let mut masker = match &settings.masks {
        Some(m) => Some(Masker::new(m, out)?),
        None => None,
    };
    let old_manifest = read_manifest(&out.join(MANIFEST));
    fsutil::prepare_output_dir(out, force)?;
    if let Some(m) = &masker {
        m.create_dirs()?;
    }

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
            // A damaged file is never copied (OpenCV would read a cut JPEG as grey-filled).
            let damage = match src.damage_of(index) {
                Some(why) => Some(why.to_string()),
                None => source::check_image(&from).err().map(|why| {
                    format!("frame {index} ({}): damaged image: {why}", file_name(&from))
                }),
            };
            if let Some(reason) = damage {
                missing.push(MissingFrame { index, reason });
                bar.inc(1);
                continue;
            }
            let name = file_name(&from);
            fsutil::copy_atomic(&from, &out.join(&name))?;
            frames.push(ExportedFrame {
                index,
                timestamp_s: timestamps.and_then(|t| t.get(index).copied()),
                file: name.clone(),
                mask: None,
                overlay: None,
            });
            if let Some(m) = masker.as_mut() {
                let img = imgcodecs::imread(&from, imgcodecs::IMREAD_COLOR)
                    .cv(|| format!("read {}", from.display()))?;
                m.push(name, img, &mut frames)?;
            }
            bar.inc(1);
        }
        if let Some(m) = masker.as_mut() {
            m.flush(&mut frames)?;
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
        let total = project.keyframes.len();
        let result = source::read_indices(src.as_mut(), &project.keyframes, |frame| {
            let img = transform(&frame.image, settings, size)?;
            // Damaged frames are never passed here: find this frame's name by its index.
            let k = project
                .keyframes
                .binary_search(&frame.index)
                .map_err(|_| Error::Frame {
                    path: input.clone(),
                    index: frame.index,
                    msg: "the source delivered a frame that was not asked for".into(),
                })?;
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
                mask: None,
                overlay: None,
            });
            if let Some(m) = masker.as_mut() {
                m.push(name.clone(), img, &mut frames)?;
            }
            bar.inc(1);
            Ok(())
        })
        .and_then(|missing| {
            if let Some(m) = masker.as_mut() {
                m.flush(&mut frames)?;
            }
            Ok(missing)
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
        missing.extend(not_read.into_iter().map(|index| {
            MissingFrame {
                index,
                reason: src
                    .damage_of(index)
                    .map_or_else(|| reason.clone(), str::to_string),
            }
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
        mask_ms_per_image: masker.as_ref().and_then(|m| m.seg.ms_per_image()),
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

/// Reads an export's manifest, if present and readable.
pub fn read_manifest(path: &Path) -> Option<Manifest> {
    let text = std::fs::read_to_string(path).ok()?;
    serde_json::from_str(&text).ok()
}

/// After a forced re-export, removes the images an earlier export listed in its manifest that the
/// new export did not write. Files keyframer did not write are left alone.
fn remove_stale(out: &Path, old: Option<&Manifest>, new: &[ExportedFrame]) {
    let Some(old) = old else { return };
    let written: Vec<&str> = new
        .iter()
        .flat_map(|n| [Some(&n.file), n.mask.as_ref(), n.overlay.as_ref()])
        .flatten()
        .map(String::as_str)
        .collect();
    let listed = old
        .frames
        .iter()
        .flat_map(|f| [Some(&f.file), f.mask.as_ref(), f.overlay.as_ref()])
        .flatten();
    for file in listed {
        let name = Path::new(file);
        // Only plain names or names inside our own masks/ and overlays/ folders.
        let ours = match name.components().count() {
            1 => true,
            2 => name.starts_with(MASK_DIR) || name.starts_with(OVERLAY_DIR),
            _ => false,
        };
        if ours && !written.contains(&file.as_str()) {
            let p = out.join(name);
            match std::fs::remove_file(&p) {
                Ok(()) => log::info!("removed {} from the earlier export", p.display()),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => log::warn!("{}: cannot remove stale export: {e}", p.display()),
            }
        }
    }
}

/// Collects exported images into batches for the segmentation network and writes their masks
/// (and overlays) as each batch completes.
struct Masker {
    seg: Segmenter,
    overlay: bool,
    out: PathBuf,
    names: Vec<String>,
    images: Vec<Mat>,
}

impl Masker {
    fn new(settings: &MaskSettings, out: &Path) -> Result<Masker> {
        let seg = Segmenter::new(settings)?;
        Ok(Masker {
            seg,
            overlay: settings.overlay,
            out: out.to_path_buf(),
            names: Vec::new(),
            images: Vec::new(),
        })
    }

    fn create_dirs(&self) -> Result<()> {
        let mut dirs = vec![self.out.join(MASK_DIR)];
        if self.overlay {
            dirs.push(self.out.join(OVERLAY_DIR));
        }
        for d in dirs {
            std::fs::create_dir_all(&d).map_err(|e| Error::io(&d, e))?;
        }
        Ok(())
    }

    /// Queues one exported image (`name` in the export folder); runs a batch when full.
    fn push(&mut self, name: String, image: Mat, frames: &mut [ExportedFrame]) -> Result<()> {
        self.names.push(name);
        self.images.push(image);
        if self.images.len() >= self.seg.batch() {
            self.flush(frames)?;
        }
        Ok(())
    }

    /// Segments the queued images and writes their masks, recording them in `frames`.
    fn flush(&mut self, frames: &mut [ExportedFrame]) -> Result<()> {
        if self.images.is_empty() {
            return Ok(());
        }
        let names = std::mem::take(&mut self.names);
        let images = std::mem::take(&mut self.images);
        let maps = self.seg.classify(&images)?;
        for ((name, image), map) in names.iter().zip(&images).zip(&maps) {
            let size = (image.cols() as u32, image.rows() as u32);
            let mask = self.seg.mask(map, size)?;
            let mask_name = crate::segment::write_mask(&self.out.join(MASK_DIR), name, &mask)?;
            let overlay = if self.overlay {
                let o = self.seg.overlay(image, map)?;
                let fmt = if name.ends_with(".png") {
                    Format::Png
                } else {
                    Format::Jpg
                };
                let bytes = encode(&o, fmt, 90)?;
                fsutil::write_atomic(&self.out.join(OVERLAY_DIR).join(name), &bytes)?;
                Some(format!("{OVERLAY_DIR}/{name}"))
            } else {
                None
            };
            if let Some(f) = frames.iter_mut().rev().find(|f| &f.file == name) {
                f.mask = Some(format!("{MASK_DIR}/{mask_name}"));
                f.overlay = overlay;
            }
        }
        Ok(())
    }
}
