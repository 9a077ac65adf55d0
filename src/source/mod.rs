//! Frame sources: videos (OpenCV VideoCapture) and image folders behind one streaming interface.
//! Frames are produced one at a time in index order, so memory stays bounded on any input length.

#[cfg(feature = "opencv")]
pub mod codec_keyframes;
#[cfg(feature = "opencv")]
mod images;
mod natural;
#[cfg(feature = "opencv")]
mod packets;
#[cfg(feature = "opencv")]
mod reader;
pub mod spherical;
pub mod telemetry;
#[cfg(feature = "opencv")]
mod video;

#[cfg(feature = "opencv")]
pub use images::{check_image, escaped_name, folder_images, is_image_name, ImageSource};
pub use natural::natural_cmp;
#[cfg(feature = "opencv")]
pub use reader::{shrink, FrameReader, FrameSize, DEFAULT_BUDGET_BYTES};
#[cfg(feature = "opencv")]
pub use video::VideoSource;

#[cfg(feature = "opencv")]
use crate::error::{Error, Result};
#[cfg(feature = "opencv")]
use opencv::core::Mat;
use serde::{Deserialize, Serialize};
#[cfg(feature = "opencv")]
use std::path::Path;

/// What kind of input a source reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SourceKind {
    /// A video file decoded with OpenCV's FFmpeg backend.
    Video,
    /// A folder of image files in natural order.
    Images,
    /// A single image file.
    Image,
}

/// Facts about an input, as `keyframer probe` reports them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Metadata {
    /// Video or image folder.
    pub kind: SourceKind,
    /// Number of frames (decoded count when `frame_count_exact`, else the container's claim).
    pub frame_count: usize,
    /// Whether `frame_count` was established by decoding every frame.
    pub frame_count_exact: bool,
    /// Frames per second claimed by the container (average for variable frame rate); `None` for
    /// image folders unless given by the user.
    pub fps: Option<f64>,
    /// Frame width in pixels, as decoded (after rotation metadata is applied).
    pub width: u32,
    /// Frame height in pixels, as decoded.
    pub height: u32,
    /// Duration in seconds (`None` without a frame rate).
    pub duration_s: Option<f64>,
    /// Codec four-character code for videos.
    pub codec: Option<String>,
    /// Rotation metadata in degrees (applied by the decoder).
    pub rotation_deg: i32,
}

#[cfg(feature = "opencv")]
/// One decoded frame.
pub struct Frame {
    /// 0-based frame index in decode order.
    pub index: usize,
    /// Presentation time in seconds (from the stream; index / fps when the stream has none).
    pub timestamp_s: Option<f64>,
    /// The pixels, 8-bit BGR.
    pub image: Mat,
}

#[cfg(feature = "opencv")]
/// A stream of frames in index order.
pub trait FrameSource: Send {
    /// Metadata known so far.
    fn metadata(&self) -> &Metadata;
    /// Decodes the next frame; `Ok(None)` at the end of the stream.
    fn next_frame(&mut self) -> Result<Option<Frame>>;
    /// Advances past the next frame without producing pixels (cheaper than `next_frame` when the
    /// decoder allows); returns its index and timestamp, or `None` at the end.
    fn skip_frame(&mut self) -> Result<Option<(usize, Option<f64>)>>;
    /// Positions the source so that the next `next_frame` yields frame `index` with its index
    /// and timestamp; `expect_ts` is that frame's timestamp from a sequential pass (the cache),
    /// to check the landing against. `Ok(false)`: not supported, beyond the end or not exact;
    /// the position is then unspecified and the caller reopens the source.
    fn seek(&mut self, _index: usize, _expect_ts: Option<f64>) -> Result<bool> {
        Ok(false)
    }
    /// For image folders, the file behind frame `index`.
    fn file_of(&self, _index: usize) -> Option<&Path> {
        None
    }
    /// Frames the decoder gave up on (damaged stream): the index where decoding stopped and why.
    fn decode_failure(&self) -> Option<(usize, String)> {
        None
    }
    /// Damaged frames met so far that did not stop the input (a damaged file in an image
    /// folder), ascending: index and a message naming the frame and file. `next_frame` yields
    /// a stand-in image for them (the previous readable frame), so they must never be exported
    /// or selected.
    fn damaged_frames(&self) -> Vec<(usize, String)> {
        Vec::new()
    }
    /// Why frame `index` is damaged, if it is (see [`FrameSource::damaged_frames`]).
    fn damage_of(&self, _index: usize) -> Option<&str> {
        None
    }
}

#[cfg(feature = "opencv")]
/// Options for opening a source.
#[derive(Debug, Clone, Default)]
pub struct OpenOptions {
    /// Frame rate to assume for image folders (they have none of their own).
    pub images_fps: Option<f64>,
    /// Decode only these codec keyframes of a video (`select --preview`); the source's frame `j`
    /// is the `j`-th keyframe.
    pub codec_keyframes: Option<std::sync::Arc<codec_keyframes::CodecKeyframeIndex>>,
}

/// What `path` is, from the file system only: a folder of images, an image file (by its
/// extension) or a video; anything but a folder or a regular file (a FIFO would block the
/// reader) is refused.
#[cfg(feature = "opencv")]
pub fn kind_of(path: &Path) -> Result<SourceKind> {
    let meta = std::fs::metadata(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => Error::input(path, "no such file or folder"),
        _ => Error::io(path, e),
    })?;
    if !meta.is_dir() && !meta.is_file() {
        let msg = "is not a regular file (a device, FIFO or socket): give a video file, an image \
                   file or a folder of images";
        return Err(Error::input(path, msg));
    }
    Ok(if meta.is_dir() {
        SourceKind::Images
    } else if is_image_name(path) {
        SourceKind::Image
    } else {
        SourceKind::Video
    })
}

#[cfg(feature = "opencv")]
/// Opens a video file, an image file or a folder of images.
pub fn open(path: &Path, opts: &OpenOptions) -> Result<Box<dyn FrameSource>> {
    let kind = kind_of(path)?;
    if opts.codec_keyframes.is_some() && kind != SourceKind::Video {
        let msg = "the keyframe-only preview needs a video (images have no codec keyframes)";
        return Err(Error::input(path, msg));
    }
    Ok(match (kind, &opts.codec_keyframes) {
        (SourceKind::Images, _) => Box::new(ImageSource::open_folder(path, opts.images_fps)?),
        (SourceKind::Image, _) => Box::new(ImageSource::open_single(path, opts.images_fps)?),
        (SourceKind::Video, Some(index)) => Box::new(codec_keyframes::CodecKeyframeSource::open(
            path,
            index.clone(),
        )?),
        (SourceKind::Video, None) => Box::new(VideoSource::open(path)?),
    })
}

/// Reads the frames at the sorted, distinct `indices`, calling `f` for each, in one sequential
/// pass: skipped frames are only grabbed, never seeked to. Returns the indices that could not be
/// decoded, ascending: damaged frames (never passed to `f`; see [`FrameSource::damage_of`]) and
/// those after the stream ended early.
#[cfg(feature = "opencv")]
pub fn read_indices(
    source: &mut dyn FrameSource,
    indices: &[usize],
    mut f: impl FnMut(Frame) -> Result<()>,
) -> Result<Vec<usize>> {
    if indices.windows(2).any(|w| w[0] >= w[1]) {
        return Err(Error::param("frame indices", "must be sorted and distinct"));
    }
    let mut pos = 0usize;
    let mut damaged = Vec::new();
    for (k, &want) in indices.iter().enumerate() {
        while pos < want && source.skip_frame()?.is_some() {
            pos += 1;
        }
        // Short of `want`, the stream ended while skipping.
        let next = (pos == want).then(|| source.next_frame());
        let Some(frame) = next.transpose()?.flatten() else {
            damaged.extend_from_slice(&indices[k..]);
            return Ok(damaged);
        };
        pos += 1;
        if source.damage_of(frame.index).is_some() {
            damaged.push(frame.index);
        } else {
            f(frame)?;
        }
    }
    Ok(damaged)
}

#[cfg(feature = "opencv")]
/// Result of one pass over every frame without decoding pixels beyond what the codec needs.
#[derive(Debug, Clone)]
pub struct Scan {
    /// Timestamp of every frame, in seconds (`None` for image folders without a frame rate).
    pub timestamps_s: Option<Vec<f64>>,
    /// Number of frames that could be read.
    pub frame_count: usize,
    /// Where and why decoding stopped early, if it did.
    pub failure: Option<(usize, String)>,
    /// Damaged frames that did not stop the input (see [`FrameSource::damaged_frames`]).
    pub damaged: Vec<(usize, String)>,
}

#[cfg(feature = "opencv")]
/// Walks the whole input once with `skip_frame`, collecting timestamps and the true frame count.
pub fn scan(source: &mut dyn FrameSource, mut progress: impl FnMut(usize)) -> Result<Scan> {
    let mut ts = Vec::new();
    let mut have_ts = true;
    let mut count = 0;
    while let Some((_, t)) = source.skip_frame()? {
        match t {
            Some(t) => ts.push(t),
            None => have_ts = false,
        }
        count += 1;
        progress(count);
    }
    Ok(Scan {
        timestamps_s: have_ts.then_some(ts),
        frame_count: count,
        failure: source.decode_failure(),
        damaged: source.damaged_frames(),
    })
}

/// What `probe` found: the input's metadata (frame count counted by decoding when asked or when
#[cfg(feature = "opencv")]
/// the container gives none) and the decode problems met while counting.
#[derive(Debug, Clone)]
pub struct Probe {
    /// Metadata; `frame_count_exact` says whether the count was decoded.
    pub metadata: Metadata,
    /// Damaged frames and where decoding stopped early, as messages.
    pub problems: Vec<String>,
}

/// Opens `input` and reads its metadata; with `exact` (or a container without a frame count)
/// counts the frames by decoding them all, reporting the count to `progress`.
#[cfg(feature = "opencv")]
pub fn probe(
    input: &Path,
    options: &OpenOptions,
    exact: bool,
    progress: impl FnMut(usize),
) -> Result<Probe> {
    let mut src = open(input, options)?;
    let mut metadata = src.metadata().clone();
    let mut problems = Vec::new();
    if exact || (metadata.frame_count == 0 && !metadata.frame_count_exact) {
        let scan = scan(src.as_mut(), progress)?;
        metadata.frame_count = scan.frame_count;
        metadata.frame_count_exact = true;
        if let (Some(ts), Some(fps)) = (&scan.timestamps_s, metadata.fps) {
            if let (Some(f), Some(l)) = (ts.first(), ts.last()) {
                metadata.duration_s = Some(l - f + 1.0 / fps);
            }
        }
        problems.extend(scan.damaged.into_iter().map(|(_, m)| m));
        problems.extend(scan.failure.map(|(_, m)| m));
    }
    Ok(Probe { metadata, problems })
}
