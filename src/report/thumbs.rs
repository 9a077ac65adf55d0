//! Keyframe thumbnails for the report: small JPEGs decoded from the input in one sequential pass
//! (bounded memory) or read from an export folder, plus the base64 needed for data: URIs.

use crate::error::{CvContext, Error, Result};
use crate::manifest::{image_path, Manifest, MANIFEST};
use crate::source;
use opencv::prelude::*;
use std::path::Path;

/// Width of a thumbnail: the review page's frame strip.
const STRIP: i32 = source::FrameSize::Strip.width();

/// One thumbnail.
#[derive(Debug, Clone)]
pub struct Thumb {
    /// Frame index.
    pub frame: usize,
    /// JPEG bytes.
    pub jpeg: Vec<u8>,
}

/// At most `max` of the sorted `keyframes`, spread evenly (first and last included).
pub fn pick(keyframes: &[usize], max: usize) -> Vec<usize> {
    let k = keyframes.len();
    if k <= max {
        return keyframes.to_vec();
    }
    match max {
        0 => Vec::new(),
        1 => vec![keyframes[0]],
        _ => {
            let mut v: Vec<usize> = (0..max)
                .map(|i| keyframes[(i * (k - 1) + (max - 1) / 2) / (max - 1)])
                .collect();
            v.dedup();
            v
        }
    }
}

/// Thumbnails of `frames` (sorted, distinct) decoded from `input`; frames the stream does not
/// reach are left out and returned as the second value.
pub fn from_input(input: &Path, frames: &[usize]) -> Result<(Vec<Thumb>, Vec<usize>)> {
    let mut src = source::open(input, &source::OpenOptions::default())?;
    let mut thumbs = Vec::with_capacity(frames.len());
    let missing = source::read_indices(src.as_mut(), frames, |f| {
        let jpeg = source::shrink(&f.image, STRIP, &|| {
            format!("{} frame {}", input.display(), f.index)
        })?;
        thumbs.push(Thumb {
            frame: f.index,
            jpeg,
        });
        Ok(())
    })?;
    Ok((thumbs, missing))
}

/// Thumbnails of `frames` from the images of the export folder `dir` (its manifest names them);
/// frames the export does not hold are returned as the second value.
pub fn from_export(dir: &Path, frames: &[usize]) -> Result<(Vec<Thumb>, Vec<usize>)> {
    let mpath = dir.join(MANIFEST);
    let manifest = Manifest::load(&mpath)?;
    let mut thumbs = Vec::new();
    let mut missing = Vec::new();
    for &f in frames {
        let Some(e) = manifest.frames.iter().find(|e| e.index == f) else {
            missing.push(f);
            continue;
        };
        let path = image_path(dir, e);
        let name = path.to_string_lossy().into_owned();
        let image = opencv::imgcodecs::imread(&name, opencv::imgcodecs::IMREAD_COLOR)
            .cv(|| format!("reading {name}"))?;
        if image.empty() {
            return Err(Error::input(&path, "not a readable image"));
        }
        thumbs.push(Thumb {
            frame: f,
            jpeg: source::shrink(&image, STRIP, &|| name.clone())?,
        });
    }
    Ok((thumbs, missing))
}

/// Standard base64 (RFC 4648, with padding).
pub fn base64(bytes: &[u8]) -> String {
    const ABC: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for i in 0..=chunk.len() {
            out.push(char::from(ABC[((n >> (18 - 6 * i)) & 63) as usize]));
        }
        out.push_str(&"=="[chunk.len() - 1..]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648_vectors() {
        let cases = [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ];
        for (plain, enc) in cases {
            assert_eq!(base64(plain.as_bytes()), enc, "{plain:?}");
        }
    }

    #[test]
    fn pick_spreads_evenly_and_keeps_the_ends() {
        let keys: Vec<usize> = (0..100).map(|i| i * 3).collect();
        let p = pick(&keys, 5);
        assert_eq!(p.len(), 5);
        assert_eq!(p[0], 0);
        assert_eq!(*p.last().unwrap(), 297);
        assert!(p.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(pick(&keys[..3], 5), keys[..3].to_vec());
        assert!(pick(&keys, 0).is_empty());
    }
}
