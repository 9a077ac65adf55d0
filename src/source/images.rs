//! Image-folder input: png, jpg, jpeg, tif, tiff and bmp files (any letter case) in natural order,
//! all of one size (checked from the file headers before any frame is used).

use super::{natural_cmp, Frame, FrameSource, Metadata, SourceKind};
use crate::error::{CvContext, Error, Result};
use opencv::imgcodecs;
use opencv::prelude::*;
use std::path::{Path, PathBuf};

const EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "tif", "tiff", "bmp"];

/// True when the file name has one of the supported image extensions.
pub fn is_image_name(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .map(|e| EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
        .unwrap_or(false)
}

/// The supported image files directly inside `dir`, naturally sorted.
pub fn list_images(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        let p = entry.path();
        let hidden = p
            .file_name()
            .map(|n| n.to_string_lossy().starts_with('.'))
            .unwrap_or(true);
        if !hidden && p.is_file() && is_image_name(&p) {
            files.push(p);
        }
    }
    files.sort_by(|a, b| {
        natural_cmp(
            &a.file_name().unwrap_or_default().to_string_lossy(),
            &b.file_name().unwrap_or_default().to_string_lossy(),
        )
    });
    Ok(files)
}

/// A sequence of image files read one at a time.
pub struct ImageSource {
    path: PathBuf,
    files: Vec<PathBuf>,
    meta: Metadata,
    next_index: usize,
}

impl ImageSource {
    /// Opens a folder; refuses an empty folder and images of different sizes.
    pub fn open_folder(dir: &Path, fps: Option<f64>) -> Result<Self> {
        let files = list_images(dir)?;
        if files.is_empty() {
            return Err(Error::input(
                dir,
                "the folder holds no images (png, jpg, jpeg, tif, tiff, bmp)",
            ));
        }
        Self::from_files(dir, files, SourceKind::Images, fps)
    }

    /// Opens one image file as a one-frame sequence.
    pub fn open_single(file: &Path, fps: Option<f64>) -> Result<Self> {
        Self::from_files(file, vec![file.to_path_buf()], SourceKind::Image, fps)
    }

    fn from_files(
        path: &Path,
        files: Vec<PathBuf>,
        kind: SourceKind,
        fps: Option<f64>,
    ) -> Result<Self> {
        let (w, h) = dimensions(&files[0])?;
        for f in &files[1..] {
            let (fw, fh) = dimensions(f)?;
            if (fw, fh) != (w, h) {
                return Err(Error::input(
                    f,
                    format!(
                        "image is {fw}x{fh} but {} is {w}x{h}; all images of a sequence must have one size",
                        files[0].file_name().unwrap_or_default().to_string_lossy()
                    ),
                ));
            }
        }
        let n = files.len();
        Ok(ImageSource {
            path: path.to_path_buf(),
            files,
            meta: Metadata {
                kind,
                frame_count: n,
                frame_count_exact: true,
                fps,
                width: w,
                height: h,
                duration_s: fps.map(|f| n as f64 / f),
                codec: None,
                rotation_deg: 0,
            },
            next_index: 0,
        })
    }

    fn timestamp(&self, index: usize) -> Option<f64> {
        self.meta.fps.map(|f| index as f64 / f)
    }
}

/// Width and height from the file header; falls back to a full decode for formats the header
/// reader does not know.
fn dimensions(file: &Path) -> Result<(u32, u32)> {
    if let Ok(d) = image::image_dimensions(file) {
        return Ok(d);
    }
    let m = read_image(file, 0)?;
    Ok((m.cols() as u32, m.rows() as u32))
}

fn read_image(file: &Path, index: usize) -> Result<opencv::core::Mat> {
    let m = imgcodecs::imread(file, imgcodecs::IMREAD_COLOR)
        .cv(|| format!("imread {}", file.display()))?;
    if m.empty() {
        return Err(Error::Frame {
            path: file.to_path_buf(),
            index,
            msg: "cannot read as an image (damaged or unsupported file)".into(),
        });
    }
    Ok(m)
}

impl FrameSource for ImageSource {
    fn path(&self) -> &Path {
        &self.path
    }

    fn metadata(&self) -> &Metadata {
        &self.meta
    }

    fn next_frame(&mut self) -> Result<Option<Frame>> {
        let index = self.next_index;
        let Some(file) = self.files.get(index) else {
            return Ok(None);
        };
        let image = read_image(file, index)?;
        if image.cols() as u32 != self.meta.width || image.rows() as u32 != self.meta.height {
            return Err(Error::Frame {
                path: file.clone(),
                index,
                msg: format!(
                    "decoded as {}x{}, expected {}x{}",
                    image.cols(),
                    image.rows(),
                    self.meta.width,
                    self.meta.height
                ),
            });
        }
        self.next_index += 1;
        Ok(Some(Frame {
            index,
            timestamp_s: self.timestamp(index),
            image,
        }))
    }

    fn skip_frame(&mut self) -> Result<Option<(usize, Option<f64>)>> {
        let index = self.next_index;
        if index >= self.files.len() {
            return Ok(None);
        }
        self.next_index += 1;
        Ok(Some((index, self.timestamp(index))))
    }

    fn file_of(&self, index: usize) -> Option<&Path> {
        self.files.get(index).map(|p| p.as_path())
    }
}
