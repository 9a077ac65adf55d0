//! Frames on demand, in any order: [`FrameReader`] gives the JPEG of any frame with the pixels a
//! sequential pass ([`super::read_indices`]) decodes, from one open source used as a cursor
//! (short jumps forward decode forward, others seek; a seek that cannot be verified falls back
//! to reopening and decoding forward), and keeps recent JPEGs under a byte budget.
//! [`shrink`] is the one small-JPEG maker: the report's thumbnails use it too.

use super::{Frame, FrameSource, OpenOptions, SourceKind};
use crate::error::{CvContext, Error, Result};
use opencv::core::{Mat, Size, Vector};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Default byte budget of a reader's JPEG cache.
pub const DEFAULT_BUDGET_BYTES: usize = 64 << 20;

/// JPEG quality of shrunk frames.
const QUALITY: i32 = 80;

/// Seconds of frames a reader decodes forward through rather than seeking.
const SKIP_SECONDS: f64 = 2.0;

/// How large a frame is served.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FrameSize {
    /// 160 px wide (the frame strip and the report's thumbnails).
    Strip,
    /// At most 960 px wide (the large preview).
    Large,
}

impl FrameSize {
    /// Width in pixels (frames narrower than this keep their width).
    pub const fn width(self) -> i32 {
        match self {
            FrameSize::Strip => 160,
            FrameSize::Large => 960,
        }
    }
}

/// `image` resized to `width` (never enlarged; height by aspect, INTER_AREA) as a quality-80
/// JPEG; `what` names the image in errors.
pub fn shrink(image: &Mat, width: i32, what: &dyn Fn() -> String) -> Result<Vec<u8>> {
    let (w, h) = (image.cols(), image.rows());
    if w <= 0 || h <= 0 {
        let msg = format!("{}: empty image", what());
        return Err(Error::param("thumbnail", msg));
    }
    let tw = width.min(w);
    let th = ((f64::from(h) * f64::from(tw) / f64::from(w)).round() as i32).max(1);
    let mut small = Mat::default();
    let size = Size::new(tw, th);
    imgproc::resize(image, &mut small, size, 0.0, 0.0, imgproc::INTER_AREA)
        .cv(|| format!("resizing {} for a thumbnail", what()))?;
    let params = Vector::<i32>::from_slice(&[imgcodecs::IMWRITE_JPEG_QUALITY, QUALITY]);
    let mut buf = Vector::<u8>::new();
    imgcodecs::imencode(".jpg", &small, &mut buf, &params).cv(|| "encode jpg".into())?;
    Ok(buf.to_vec())
}

/// A cached JPEG: frame index and size.
type Key = (usize, FrameSize);

/// JPEGs of one input's frames, decoded on demand (see the module header).
pub struct FrameReader {
    path: PathBuf,
    options: OpenOptions,
    /// Every frame's timestamp from a sequential pass (the cache), to verify seeks.
    timestamps_s: Option<Vec<f64>>,
    source: Box<dyn FrameSource>,
    /// Index of the frame the source's next `next_frame` yields.
    cursor: usize,
    frame_count: usize,
    /// Frames within this distance ahead of the cursor are reached by decoding forward.
    skip_limit: usize,
    warned: bool,
    budget: usize,
    cached: usize,
    /// Cached JPEGs with the tick of their last use; `order` maps ticks back to keys.
    jpegs: HashMap<Key, (Arc<Vec<u8>>, u64)>,
    order: BTreeMap<u64, Key>,
    tick: u64,
}

impl FrameReader {
    /// Opens `path` as [`super::open`] does. `timestamps_s` (the cache's, one per frame) checks
    /// every seek and sets the frame count; `budget_bytes` bounds the JPEG cache
    /// ([`DEFAULT_BUDGET_BYTES`]).
    pub fn open(
        path: &Path,
        options: &OpenOptions,
        timestamps_s: Option<Vec<f64>>,
        budget_bytes: usize,
    ) -> Result<Self> {
        let source = super::open(path, options)?;
        let meta = source.metadata();
        let frame_count = timestamps_s.as_ref().map_or(meta.frame_count, Vec::len);
        let skip_limit = match (meta.kind, meta.fps) {
            (SourceKind::Video, Some(fps)) => (fps * SKIP_SECONDS).round() as usize,
            (SourceKind::Video, None) => 60,
            _ => 0,
        };
        Ok(FrameReader {
            path: path.to_path_buf(),
            options: options.clone(),
            timestamps_s,
            source,
            cursor: 0,
            frame_count,
            skip_limit,
            warned: false,
            budget: budget_bytes,
            cached: 0,
            jpegs: HashMap::new(),
            order: BTreeMap::new(),
            tick: 0,
        })
    }

    /// Number of frames (the cache's count when timestamps were given, else the source's).
    pub fn frame_count(&self) -> usize {
        self.frame_count
    }

    /// Bytes of JPEG held in the cache (never above the budget).
    pub fn cached_bytes(&self) -> usize {
        self.cached
    }

    /// The JPEG of frame `index` at `size`; an error names the frame when it is beyond the end
    /// or damaged.
    pub fn read(&mut self, index: usize, size: FrameSize) -> Result<Arc<Vec<u8>>> {
        self.tick += 1;
        if let Some((jpeg, used)) = self.jpegs.get_mut(&(index, size)) {
            self.order.remove(used);
            *used = self.tick;
            self.order.insert(self.tick, (index, size));
            return Ok(jpeg.clone());
        }
        if index >= self.frame_count {
            return Err(self.beyond_end(index));
        }
        // After an error the source's position is unknown: the next read seeks.
        let frame = self
            .decode(index)
            .inspect_err(|_| self.cursor = usize::MAX)?;
        if let Some(why) = self.source.damage_of(index) {
            return Err(Error::frame(&self.path, index, why));
        }
        let what = || format!("{} frame {index}", self.path.display());
        let jpeg = Arc::new(shrink(&frame.image, size.width(), &what)?);
        self.keep((index, size), jpeg.clone());
        Ok(jpeg)
    }

    fn decode(&mut self, index: usize) -> Result<Frame> {
        self.move_to(index)?;
        let Some(frame) = self.source.next_frame()? else {
            return Err(self.beyond_end(index));
        };
        self.cursor = frame.index + 1;
        if frame.index != index {
            let msg = format!("the decoder yielded frame {} instead", frame.index);
            return Err(Error::frame(&self.path, index, msg));
        }
        Ok(frame)
    }

    fn beyond_end(&self, index: usize) -> Error {
        let msg = format!("beyond the end of the input ({} frames)", self.frame_count);
        Error::frame(&self.path, index, msg)
    }

    /// Positions the source so that its next frame is `index`.
    fn move_to(&mut self, index: usize) -> Result<()> {
        let ahead = index >= self.cursor && index - self.cursor <= self.skip_limit;
        // A seek that cannot be verified (the last frames of a video come out of the decoder's
        // drain without timestamps) is retried from `skip_limit` frames earlier.
        let earlier = index.saturating_sub(self.skip_limit.max(1));
        let placed = ahead || self.seek(index)? || (index > 0 && self.seek(earlier)?);
        if !placed {
            if !self.warned {
                log::warn!(
                    "{}: cannot seek exactly (first at frame {index}); frames are reached by \
                     decoding from the start (slower)",
                    self.path.display()
                );
                self.warned = true;
            }
            self.source = super::open(&self.path, &self.options)?;
            self.cursor = 0;
        }
        while self.cursor < index {
            if self.source.skip_frame()?.is_none() {
                return Err(self.beyond_end(index));
            }
            self.cursor += 1;
        }
        Ok(())
    }

    /// Seeks the source to `index`, checked against the cached timestamp; true when exact.
    fn seek(&mut self, index: usize) -> Result<bool> {
        let expect = self
            .timestamps_s
            .as_ref()
            .and_then(|t| t.get(index).copied());
        let landed = self.source.seek(index, expect)?;
        if landed {
            self.cursor = index;
        }
        Ok(landed)
    }

    /// Caches `jpeg`, dropping the least recently used ones to stay within the budget.
    fn keep(&mut self, key: Key, jpeg: Arc<Vec<u8>>) {
        if jpeg.len() > self.budget {
            return;
        }
        while self.cached + jpeg.len() > self.budget {
            let Some((_, old)) = self.order.pop_first() else {
                break;
            };
            if let Some((gone, _)) = self.jpegs.remove(&old) {
                self.cached -= gone.len();
            }
        }
        self.cached += jpeg.len();
        self.order.insert(self.tick, key);
        self.jpegs.insert(key, (jpeg, self.tick));
    }
}
