//! Image-folder input: png, jpg, jpeg, tif, tiff and bmp files (any letter case) in natural order,
//! all of one size (checked from the file headers before any frame is used). File names must be
//! UTF-8 (they are written into manifests and output folders as text). A damaged image (cut
//! short, or one OpenCV cannot decode) does not stop the sequence: it is recorded as a damaged
//! frame ([`FrameSource::damage_of`]), the analysis sees the previous readable image in its
//! place, and it is never exported. OpenCV's `imread` accepts a truncated JPEG (grey-filled)
//! without an error, so every file is first checked for its format's end: the JPEG EOI marker
//! after the last scan, the PNG IEND chunk, the BMP size its header declares ([`check_image`]).

use super::{natural_cmp, Frame, FrameSource, Metadata, SourceKind};
use crate::error::{CvContext, Error, Result};
use opencv::imgcodecs;
use opencv::prelude::*;
use std::ffi::OsStr;
use std::path::{Path, PathBuf};

const EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "tif", "tiff", "bmp"];

/// True when the file name has one of the supported image extensions.
pub fn is_image_name(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// A file name for messages: valid UTF-8 as it is, other bytes as `\xNN` escapes.
pub fn escaped_name(name: &OsStr) -> String {
    use std::os::unix::ffi::OsStrExt;
    let mut out = String::new();
    for chunk in name.as_bytes().utf8_chunks() {
        out.push_str(chunk.valid());
        out.extend(chunk.invalid().iter().map(|b| format!("\\x{b:02x}")));
    }
    out
}

/// The supported image files directly inside `dir`, naturally sorted. Refuses a folder without
/// any, and an image whose name is not UTF-8: names are written into manifests and output
/// folders as text, and two such names could become one.
pub fn folder_images(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        let p = entry.path();
        let hidden = p
            .file_name()
            .is_none_or(|n| n.to_string_lossy().starts_with('.'));
        if !hidden && p.is_file() && is_image_name(&p) {
            let name = entry.file_name();
            if name.to_str().is_none() {
                return Err(Error::input(
                    dir,
                    format!(
                        "the image file name `{}` is not valid UTF-8; keyframer writes image \
                         names into manifests and output folders as text, so rename the file \
                         (e.g. with `convmv` or `mv`) and run again",
                        escaped_name(&name)
                    ),
                ));
            }
            files.push(p);
        }
    }
    files.sort_by(|a, b| {
        natural_cmp(
            &a.file_name().unwrap_or_default().to_string_lossy(),
            &b.file_name().unwrap_or_default().to_string_lossy(),
        )
    });
    if files.is_empty() {
        let msg = "the folder holds no images (png, jpg, jpeg, tif, tiff, bmp)";
        return Err(Error::input(dir, msg));
    }
    Ok(files)
}

/// A sequence of image files read one at a time.
pub struct ImageSource {
    path: PathBuf,
    files: Vec<PathBuf>,
    meta: Metadata,
    next_index: usize,
    /// Damaged frames met so far (index, why), ascending.
    damaged: Vec<(usize, String)>,
    /// The last frame that decoded, shown to the analysis in place of a damaged one.
    last_good: Option<usize>,
}

impl ImageSource {
    /// Opens a folder; refuses an empty folder and images of different sizes.
    pub fn open_folder(dir: &Path, fps: Option<f64>) -> Result<Self> {
        Self::from_files(dir, folder_images(dir)?, SourceKind::Images, fps)
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
        // Sizes from the headers; a file whose size cannot be read at all is a damaged frame
        // (a single image that cannot be read is an error: there is nothing else to use).
        let mut size: Option<(usize, (u32, u32))> = None;
        let mut damaged = Vec::new();
        for (index, f) in files.iter().enumerate() {
            let d = match dimensions(f, index) {
                Ok(d) => d,
                Err(e @ Error::Frame { .. }) if kind == SourceKind::Images => {
                    damaged.push((index, damage_message(f, index, &e.to_string())));
                    continue;
                }
                Err(e) => return Err(e),
            };
            match size {
                None => size = Some((index, d)),
                Some((first, (w, h))) if d != (w, h) => {
                    return Err(Error::input(
                        f,
                        format!(
                            "image is {}x{} but {} is {w}x{h}; all images of a sequence must have one size",
                            d.0,
                            d.1,
                            files[first].file_name().unwrap_or_default().to_string_lossy()
                        ),
                    ));
                }
                Some(_) => {}
            }
        }
        let Some((_, (w, h))) = size else {
            let msg = "none of the images can be read (all damaged or unsupported)";
            return Err(Error::input(path, msg));
        };
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
            damaged,
            last_good: None,
        })
    }

    fn timestamp(&self, index: usize) -> Option<f64> {
        self.meta.fps.map(|f| index as f64 / f)
    }

    fn note_damage(&mut self, index: usize, why: &str) {
        if self.damage_of(index).is_none() {
            let msg = damage_message(&self.files[index], index, why);
            log::warn!("{}: {msg}", self.path.display());
            let at = self.damaged.partition_point(|(i, _)| *i < index);
            self.damaged.insert(at, (index, msg));
        }
    }

    /// Reads frame `index` completely: the file's structure, then the pixels at the sequence's size.
    fn load(&self, index: usize) -> std::result::Result<opencv::core::Mat, String> {
        let file = &self.files[index];
        let bytes = std::fs::read(file).map_err(|e| format!("cannot read the file: {e}"))?;
        check_bytes(&bytes)?;
        let buf = opencv::core::Vector::<u8>::from_slice(&bytes);
        let m = imgcodecs::imdecode(&buf, imgcodecs::IMREAD_COLOR)
            .map_err(|e| crate::error::explain_opencv(&e))?;
        if m.empty() {
            return Err("cannot be decoded as an image (damaged or unsupported file)".into());
        }
        if m.cols() as u32 != self.meta.width || m.rows() as u32 != self.meta.height {
            return Err(format!(
                "decoded as {}x{}, expected {}x{}",
                m.cols(),
                m.rows(),
                self.meta.width,
                self.meta.height
            ));
        }
        Ok(m)
    }

    /// The image the analysis sees in place of damaged frame `index`: the last readable frame
    /// before it, else the first readable one after it.
    fn stand_in(&mut self, index: usize) -> Result<opencv::core::Mat> {
        if let Some(g) = self.last_good {
            if let Ok(m) = self.load(g) {
                return Ok(m);
            }
        }
        for j in index + 1..self.files.len() {
            if self.damage_of(j).is_some() {
                continue;
            }
            match self.load(j) {
                Ok(m) => return Ok(m),
                Err(why) => self.note_damage(j, &why),
            }
        }
        Err(Error::input(
            &self.path,
            "none of the images can be read (all damaged or unsupported)",
        ))
    }
}

fn damage_message(file: &Path, index: usize, why: &str) -> String {
    format!(
        "frame {index} ({}): damaged image, left out of the selection and the export: {why}",
        file.file_name().unwrap_or_default().to_string_lossy()
    )
}

/// Width and height from the file header; falls back to a full decode for formats the header
/// reader does not know. Errors name frame `index`.
fn dimensions(file: &Path, index: usize) -> Result<(u32, u32)> {
    if let Ok(d) = image::image_dimensions(file) {
        return Ok(d);
    }
    let m = imgcodecs::imread(file, imgcodecs::IMREAD_COLOR)
        .cv(|| format!("imread {}", file.display()))?;
    if m.empty() {
        let msg = "cannot read as an image (damaged or unsupported file)";
        return Err(Error::frame(file, index, msg));
    }
    Ok((m.cols() as u32, m.rows() as u32))
}

/// Checks that an image file is complete (see the module header); `Err` says what is wrong.
pub fn check_image(file: &Path) -> std::result::Result<(), String> {
    let bytes = std::fs::read(file).map_err(|e| format!("cannot read the file: {e}"))?;
    check_bytes(&bytes)
}

/// [`check_image`] on the file's bytes: JPEG, PNG and BMP are checked; other formats (TIFF) are
/// left to the decoder.
pub fn check_bytes(b: &[u8]) -> std::result::Result<(), String> {
    if b.is_empty() {
        return Err("the file is empty".into());
    }
    if b.starts_with(&[0xFF, 0xD8]) {
        check_jpeg(b)
    } else if b.starts_with(b"\x89PNG\r\n\x1a\n") {
        check_png(b)
    } else if b.starts_with(b"BM") && b.len() >= 14 {
        let declared = u32::from_le_bytes([b[2], b[3], b[4], b[5]]) as usize;
        if declared > b.len() {
            return Err(format!(
                "cut short: the BMP header declares {declared} bytes, the file has {}",
                b.len()
            ));
        }
        Ok(())
    } else {
        Ok(())
    }
}

/// Walks the JPEG's segments (lengths) and entropy-coded scans (byte stuffing, restart markers)
/// up to the EOI marker. Bytes after EOI (camera trailers) are allowed.
fn check_jpeg(b: &[u8]) -> std::result::Result<(), String> {
    let short = |what: &str| {
        Err(format!(
            "cut short: the JPEG ends ({} bytes) {what}, before its end marker (EOI)",
            b.len()
        ))
    };
    let mut pos = 2;
    loop {
        // Next marker: 0xFF (fill bytes allowed) then a code.
        while pos < b.len() && b[pos] != 0xFF {
            pos += 1;
        }
        while pos < b.len() && b[pos] == 0xFF {
            pos += 1;
        }
        let Some(&code) = b.get(pos) else {
            return short("between segments");
        };
        pos += 1;
        match code {
            0xD9 => return Ok(()),
            0x01 | 0xD0..=0xD7 => continue,
            _ => {}
        }
        let (Some(&hi), Some(&lo)) = (b.get(pos), b.get(pos + 1)) else {
            return short("inside a segment header");
        };
        let len = u16::from_be_bytes([hi, lo]) as usize;
        if len < 2 {
            return Err(format!("marker 0xFF{code:02X} has an invalid length {len}"));
        }
        if pos + len > b.len() {
            return short("inside a segment");
        }
        pos += len;
        if code == 0xDA {
            // Entropy-coded data: 0xFF 0x00 is a stuffed byte, 0xFF 0xD0-D7 a restart marker;
            // any other marker ends the scan.
            loop {
                while pos < b.len() && b[pos] != 0xFF {
                    pos += 1;
                }
                match b.get(pos + 1) {
                    None => return short("inside compressed image data"),
                    Some(0x00) | Some(0xD0..=0xD7) => pos += 2,
                    Some(0xFF) => pos += 1,
                    Some(_) => break,
                }
            }
        }
    }
}

/// Walks the PNG's chunks (length, type, data, CRC) up to IEND.
fn check_png(b: &[u8]) -> std::result::Result<(), String> {
    let mut pos = 8;
    loop {
        if pos + 8 > b.len() {
            return Err(format!(
                "cut short: the PNG ends ({} bytes) before its IEND chunk",
                b.len()
            ));
        }
        let len = u32::from_be_bytes([b[pos], b[pos + 1], b[pos + 2], b[pos + 3]]) as usize;
        let kind = &b[pos + 4..pos + 8];
        let end = pos + 12 + len;
        if end > b.len() {
            return Err(format!(
                "cut short: the PNG ends ({} bytes) inside its `{}` chunk, before IEND",
                b.len(),
                String::from_utf8_lossy(kind)
            ));
        }
        if kind == b"IEND" {
            return Ok(());
        }
        pos = end;
    }
}

impl FrameSource for ImageSource {
    fn metadata(&self) -> &Metadata {
        &self.meta
    }

    fn next_frame(&mut self) -> Result<Option<Frame>> {
        let index = self.next_index;
        if index >= self.files.len() {
            return Ok(None);
        }
        let image = match self.damage_of(index) {
            Some(_) => self.stand_in(index)?,
            None => match self.load(index) {
                Ok(m) => {
                    self.last_good = Some(index);
                    m
                }
                Err(why) => {
                    self.note_damage(index, &why);
                    self.stand_in(index)?
                }
            },
        };
        self.next_index += 1;
        Ok(Some(Frame {
            index,
            timestamp_s: self.timestamp(index),
            image,
        }))
    }

    /// Checks the file's structure (no decode), so that a pass over the frames finds the
    /// damaged ones too.
    fn skip_frame(&mut self) -> Result<Option<(usize, Option<f64>)>> {
        let index = self.next_index;
        if index >= self.files.len() {
            return Ok(None);
        }
        if self.damage_of(index).is_none() {
            if let Err(why) = check_image(&self.files[index]) {
                self.note_damage(index, &why);
            }
        }
        self.next_index += 1;
        Ok(Some((index, self.timestamp(index))))
    }

    /// Exact: the next frame is read from `file_of(index)`.
    fn seek(&mut self, index: usize, _expect_ts: Option<f64>) -> Result<bool> {
        if index >= self.files.len() {
            return Ok(false);
        }
        self.next_index = index;
        self.last_good = (0..index).rev().find(|&j| self.damage_of(j).is_none());
        Ok(true)
    }

    fn file_of(&self, index: usize) -> Option<&Path> {
        self.files.get(index).map(|p| p.as_path())
    }

    fn damaged_frames(&self) -> Vec<(usize, String)> {
        self.damaged.clone()
    }

    fn damage_of(&self, index: usize) -> Option<&str> {
        self.damaged
            .binary_search_by_key(&index, |(i, _)| *i)
            .ok()
            .map(|k| self.damaged[k].1.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn jpeg() -> Vec<u8> {
        let img =
            image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([x as u8 * 4, y as u8 * 5, 7]));
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Jpeg).unwrap();
        out.into_inner()
    }

    fn png() -> Vec<u8> {
        let img = image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([x as u8, y as u8, 9]));
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Png).unwrap();
        out.into_inner()
    }

    #[test]
    fn complete_files_pass_and_any_cut_fails() {
        for (name, b) in [("jpeg", jpeg()), ("png", png())] {
            assert_eq!(check_bytes(&b), Ok(()), "{name}");
            let mut trailer = b.clone();
            trailer.extend_from_slice(b"camera trailer after the end");
            assert_eq!(check_bytes(&trailer), Ok(()), "{name} with a trailer");
            for cut in [10, 20, b.len() / 3, b.len() / 2, b.len() - 2, b.len() - 1] {
                let e = check_bytes(&b[..cut]).unwrap_err();
                assert!(e.contains("cut short"), "{name} cut at {cut}: {e}");
            }
        }
        assert!(check_bytes(&[]).unwrap_err().contains("empty"));
    }

    #[test]
    fn invalid_names_are_escaped() {
        use std::os::unix::ffi::OsStrExt;
        assert_eq!(
            escaped_name(OsStr::from_bytes(b"a\xff\xfe.jpg")),
            "a\\xff\\xfe.jpg"
        );
        assert_eq!(escaped_name(OsStr::new("bild_ü.jpg")), "bild_ü.jpg");
    }
}
