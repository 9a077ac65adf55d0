//! Video input through OpenCV's VideoCapture with the FFmpeg backend: metadata, sequential decode,
//! cheap skipping with `grab`, per-frame presentation timestamps, and detection of streams that end
//! before the container says they should.
//!
//! Timestamps are the stream's: FFmpeg's best-effort timestamp of each frame (the pts), in
//! seconds from frame 0, from the packet list ([`super::packets`], read in the background from
//! the moment the video opens, and waited for at the first frame after frame 0). Every frame for which OpenCV reports a position is checked against
//! the list; where they do not pair (no ffprobe, a decoder that drops frames) OpenCV's positions
//! are used, which are missing for the last frames of a stream with B-frames (the previous
//! interval is repeated there).
//!
//! Rotation: frames come out as FFmpeg displays them (`ffmpeg -i v.mp4 f.png` autorotates by the
//! stream's display matrix). OpenCV 4.6 reads the display-matrix angle but turns the frame the
//! wrong way for 90 and 270 (clockwise by ffprobe's counter-clockwise angle), so its automatic
//! rotation is switched off and the frame is turned here. The angle is reported in ffprobe's
//! convention (`ffprobe -show_streams`, side data `rotation`): counter-clockwise degrees in
//! [-180, 180), e.g. `-metadata:s:v:0 rotate=270` gives -90 and 180 gives -180.

use super::packets::{self, StreamTimes, REPEAT_STEP_S};
use super::{Frame, FrameSource, Metadata, SourceKind};
use crate::error::{CvContext, Error, Result};
use opencv::core::{self as cvcore, Mat};
use opencv::prelude::*;
use opencv::videoio::{self, VideoCapture};
use std::path::{Path, PathBuf};

/// Where a video's frame timestamps come from.
enum Times {
    /// Being listed (from the moment the video opened; `None` while taken).
    Pending(Option<packets::Listing>),
    /// The packet list, paired with the decoded frames so far.
    Listed(StreamTimes),
    /// OpenCV's positions: no packet list, or one the decoded frames do not pair with.
    OpenCv,
}

/// A video file being decoded front to back.
pub struct VideoSource {
    path: PathBuf,
    cap: VideoCapture,
    meta: Metadata,
    /// Frame 0, decoded at open time to prove the stream is readable.
    pending: Option<Frame>,
    /// Index of the next frame to come out of the decoder.
    next_index: usize,
    times: Times,
    /// OpenCV's position of frame 0, in seconds: timestamps count from it.
    origin_s: f64,
    last_ts: Option<f64>,
    last_step: Option<f64>,
    ended: bool,
    failure: Option<(usize, String)>,
}

impl VideoSource {
    /// Opens `path` and decodes its first frame; fails with a clear message when the file is not a
    /// readable video.
    pub fn open(path: &Path) -> Result<Self> {
        // ffprobe starts (~0.1 s of loading libraries) while OpenCV opens the file and decodes
        // frame 0 (whose time needs no list); dropped with `cap` on any failure below.
        let listing = packets::Listing::start(path);
        let cap = VideoCapture::from_file(path, videoio::CAP_FFMPEG)
            .cv(|| format!("VideoCapture open {}", path.display()))?;
        let opened = cap.is_opened().cv(|| "VideoCapture::isOpened".into())?;
        if !opened {
            return Err(Error::input(
                path,
                "cannot open as a video (not a video file, an unsupported codec, or a damaged or truncated container)",
            ));
        }
        let get = |prop: i32| cap.get(prop).unwrap_or(0.0);
        let fps = get(videoio::CAP_PROP_FPS);
        let count = get(videoio::CAP_PROP_FRAME_COUNT);
        let fourcc = get(videoio::CAP_PROP_FOURCC) as i64 as u32;
        let rotation = display_rotation(get(videoio::CAP_PROP_ORIENTATION_META));
        let mut cap = cap;
        // Turned here (see the module header), never by OpenCV.
        let auto_off = cap
            .set(videoio::CAP_PROP_ORIENTATION_AUTO, 0.0)
            .cv(|| format!("disable automatic rotation of {}", path.display()))?;
        if rotation != 0 && !auto_off {
            return Err(Error::input(
                path,
                format!(
                    "the video is rotated ({rotation} deg) but OpenCV's automatic rotation cannot \
                     be switched off to apply it correctly"
                ),
            ));
        }
        if rotation % 90 != 0 {
            log::warn!(
                "{}: rotation {rotation} deg is not a multiple of 90; frames are not rotated",
                path.display()
            );
        }
        let codec = fourcc_string(fourcc);
        let fps = (fps.is_finite() && fps > 0.0).then_some(fps);
        let frame_count = if count.is_finite() && count > 0.0 {
            count.round() as usize
        } else {
            0
        };
        let mut src = VideoSource {
            path: path.to_path_buf(),
            cap,
            meta: Metadata {
                kind: SourceKind::Video,
                frame_count,
                frame_count_exact: false,
                fps,
                width: 0,
                height: 0,
                duration_s: fps.map(|f| frame_count as f64 / f),
                codec,
                rotation_deg: rotation,
            },
            pending: None,
            next_index: 0,
            times: Times::Pending(Some(listing)),
            origin_s: 0.0,
            last_ts: None,
            last_step: None,
            ended: false,
            failure: None,
        };
        let first = src.decode_next()?.ok_or_else(|| {
            Error::input(
                path,
                "the video has no decodable frames (empty, truncated or damaged)",
            )
        })?;
        src.meta.width = first.image.cols() as u32;
        src.meta.height = first.image.rows() as u32;
        src.pending = Some(first);
        Ok(src)
    }

    /// Grabs the next frame; returns its index and OpenCV's position of it in seconds, or `None`
    /// at the end of the stream.
    fn grab(&mut self) -> Result<Option<(usize, f64)>> {
        if self.ended {
            return Ok(None);
        }
        let ok = self
            .cap
            .grab()
            .cv(|| format!("grab {} frame {}", self.path.display(), self.next_index))?;
        if !ok {
            self.ended = true;
            self.note_end();
            return Ok(None);
        }
        let index = self.next_index;
        self.next_index += 1;
        let ms = self.cap.get(videoio::CAP_PROP_POS_MSEC).unwrap_or(f64::NAN);
        Ok(Some((index, ms / 1000.0)))
    }

    /// Grabs the next frame; returns its index and timestamp, or `None` at the end of the stream.
    fn advance(&mut self) -> Result<Option<(usize, Option<f64>)>> {
        let Some((index, pos_s)) = self.grab()? else {
            return Ok(None);
        };
        Ok(Some((index, self.timestamp(index, pos_s))))
    }

    /// Waits for the packet list, once (see the module header).
    fn list_times(&mut self) {
        let Times::Pending(listing) = &mut self.times else {
            return;
        };
        let list = match listing.take() {
            Some(listing) => listing.wait(),
            None => packets::list(&self.path),
        };
        self.times = match list {
            Ok(list) => {
                if let Some(first) = list.repeated.first() {
                    log::warn!(
                        "{}: {} frames (the first is frame {first}) repeat the presentation time \
                         of the frame before; each is placed {REPEAT_STEP_S} s after it",
                        self.path.display(),
                        list.repeated.len()
                    );
                }
                Times::Listed(list)
            }
            Err(e) => {
                log::warn!(
                    "{e}; timestamps come from OpenCV instead (extrapolated for the last frames \
                     of a stream with B-frames)"
                );
                Times::OpenCv
            }
        };
    }

    /// Frame `index`'s presentation time in seconds from frame 0, given OpenCV's position of it
    /// (see the module header).
    fn timestamp(&mut self, index: usize, pos_s: f64) -> Option<f64> {
        if index == 0 {
            self.origin_s = if pos_s.is_finite() { pos_s } else { 0.0 };
        } else {
            self.list_times();
        }
        let listed = match &self.times {
            Times::Listed(l) => match l.pairs(index, pos_s, self.origin_s) {
                Some(false) => {
                    // The positions compared: each from its own frame 0.
                    let first = l.opencv_s.first().copied().unwrap_or(0.0);
                    log::warn!(
                        "{}: frame {index}: the decoder's frames do not pair with the stream's \
                         packet list (OpenCV places it {} s after frame 0, the list {} s); \
                         timestamps come from OpenCV from here on",
                        self.path.display(),
                        pos_s - self.origin_s,
                        l.opencv_s[index] - first
                    );
                    self.times = Times::OpenCv;
                    None
                }
                _ => l.timestamps_s.get(index).copied(),
            },
            _ => None,
        };
        let ts = listed.or_else(|| self.opencv_time(index, pos_s));
        if let (Some(prev), Some(t)) = (self.last_ts, ts) {
            if t > prev {
                self.last_step = Some(t - prev);
            }
        }
        self.last_ts = ts;
        ts
    }

    /// OpenCV's position relative to frame 0's. Where it gives none past frame 0 (the frames
    /// drained from the decoder at the end), the previous frame interval is repeated (1 / fps for
    /// the second frame); where it repeats or goes back, the frame is placed
    /// [`REPEAT_STEP_S`] after the previous one.
    fn opencv_time(&self, index: usize, pos_s: f64) -> Option<f64> {
        let t = pos_s - self.origin_s;
        let ts = match self.last_ts {
            Some(prev) if !pos_s.is_finite() || pos_s == 0.0 => {
                let step = self.last_step.or(self.meta.fps.map(|f| 1.0 / f));
                Some(prev + step.unwrap_or(0.0))
            }
            Some(prev) if t <= prev => Some(prev + REPEAT_STEP_S),
            None if !pos_s.is_finite() => self.meta.fps.map(|f| index as f64 / f),
            _ => Some(t),
        };
        if ts != Some(t) {
            log::debug!(
                "{}: frame {index}: no usable position from OpenCV ({pos_s} s); {ts:?} s",
                self.path.display()
            );
        }
        ts
    }

    fn note_end(&mut self) {
        let got = self.next_index;
        self.failure =
            short_stream(self.meta.frame_count, got, "decoding stopped after").map(|m| (got, m));
    }

    fn decode_next(&mut self) -> Result<Option<Frame>> {
        let Some((index, timestamp_s)) = self.advance()? else {
            return Ok(None);
        };
        self.retrieve(index, timestamp_s).map(Some)
    }

    /// The pixels of the frame just grabbed (frame `index`), turned upright.
    fn retrieve(&mut self, index: usize, timestamp_s: Option<f64>) -> Result<Frame> {
        let mut image = Mat::default();
        let ok = self
            .cap
            .retrieve(&mut image, 0)
            .cv(|| format!("retrieve {} frame {index}", self.path.display()))?;
        if !ok || image.empty() {
            let msg = "the decoder returned no image";
            return Err(Error::frame(&self.path, index, msg));
        }
        let turn = match self.meta.rotation_deg {
            90 => Some(cvcore::ROTATE_90_COUNTERCLOCKWISE),
            -90 => Some(cvcore::ROTATE_90_CLOCKWISE),
            -180 => Some(cvcore::ROTATE_180),
            _ => None,
        };
        if let Some(code) = turn {
            let mut turned = Mat::default();
            cvcore::rotate(&image, &mut turned, code)
                .cv(|| format!("rotate {} frame {index}", self.path.display()))?;
            image = turned;
        }
        if self.meta.width != 0
            && (image.cols() as u32 != self.meta.width || image.rows() as u32 != self.meta.height)
        {
            return Err(Error::frame(
                &self.path,
                index,
                format!(
                    "frame size changed from {}x{} to {}x{} inside the stream",
                    self.meta.width,
                    self.meta.height,
                    image.cols(),
                    image.rows()
                ),
            ));
        }
        Ok(Frame {
            index,
            timestamp_s,
            image,
        })
    }
}

impl FrameSource for VideoSource {
    fn metadata(&self) -> &Metadata {
        &self.meta
    }

    fn next_frame(&mut self) -> Result<Option<Frame>> {
        if let Some(f) = self.pending.take() {
            return Ok(Some(f));
        }
        self.decode_next()
    }

    fn skip_frame(&mut self) -> Result<Option<(usize, Option<f64>)>> {
        if let Some(f) = self.pending.take() {
            return Ok(Some((f.index, f.timestamp_s)));
        }
        self.advance()
    }

    /// Sets `CAP_PROP_POS_FRAMES`, decodes the frame there and keeps it for `next_frame`. The
    /// landing is checked: OpenCV's position of the frame must be the one the packet list gives
    /// frame `index` (when there is a list), and its timestamp must lie within half a frame of
    /// `expect_ts` (else of `index / fps`). Timestamps of later frames follow as in a sequential
    /// pass.
    fn seek(&mut self, index: usize, expect_ts: Option<f64>) -> Result<bool> {
        let Some(fps) = self.meta.fps else {
            return Ok(false);
        };
        self.list_times();
        let moved = self
            .cap
            .set(videoio::CAP_PROP_POS_FRAMES, index as f64)
            .cv(|| format!("seek {} to frame {index}", self.path.display()))?;
        (self.pending, self.next_index, self.ended) = (None, index, false);
        (self.last_ts, self.last_step) = (None, None);
        let Some((_, pos_s)) = moved.then(|| self.grab()).transpose()?.flatten() else {
            return Ok(false);
        };
        let on_list = match &self.times {
            Times::Listed(l) => l.pairs(index, pos_s, self.origin_s) == Some(true),
            _ => true,
        };
        let ts = on_list.then(|| self.timestamp(index, pos_s)).flatten();
        let want = expect_ts.unwrap_or(index as f64 / fps);
        if !ts.is_some_and(|t| (t - want).abs() < 0.5 / fps) {
            log::debug!(
                "{}: seek to frame {index} landed at {pos_s} s (OpenCV), expected {want} s",
                self.path.display()
            );
            return Ok(false);
        }
        self.pending = Some(self.retrieve(index, ts)?);
        Ok(true)
    }

    fn decode_failure(&self) -> Option<(usize, String)> {
        self.failure.clone()
    }
}

/// OpenCV's `CAP_PROP_ORIENTATION_META` (the display matrix's angle, counter-clockwise, as
/// 0..360 or signed) in ffprobe's convention: [-180, 180), which is how ffprobe prints an exact
/// half turn (-180).
fn display_rotation(meta: f64) -> i32 {
    if !meta.is_finite() {
        return 0;
    }
    (meta.round() as i32 + 180).rem_euclid(360) - 180
}

/// The problem when a stream holds `got` frames of the `declared` ones (a 1 % or 2-frame slack:
/// containers round their counts); `what` says how `got` was established.
pub(crate) fn short_stream(declared: usize, got: usize, what: &str) -> Option<String> {
    let slack = 2.max(declared / 100);
    (declared > got + slack).then(|| {
        format!(
            "{what} {got} frames but the container declares {declared}; \
             frames from {got} on could not be decoded (damaged or truncated stream)"
        )
    })
}

fn fourcc_string(code: u32) -> Option<String> {
    if code == 0 {
        return None;
    }
    let s: String = code
        .to_le_bytes()
        .iter()
        .map(|&b| if b.is_ascii_graphic() { b as char } else { '?' })
        .collect();
    Some(s.trim_end_matches('?').to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A seek lands on the frame a sequential pass decodes there, with its index and timestamp,
    /// and the frame after it follows; a landing that misses `expect_ts` reports false.
    #[test]
    fn seek_yields_the_sequential_frame_index_and_timestamp() {
        let d = tempfile::tempdir().unwrap();
        let clip = d.path().join("c.mp4");
        let ok = std::process::Command::new("ffmpeg")
            .args(["-v", "error", "-f", "lavfi", "-i"])
            .arg("testsrc2=size=160x120:rate=30:duration=4")
            .args(["-c:v", "libx264", "-g", "30", "-pix_fmt", "yuv420p"])
            .arg(&clip)
            .status()
            .unwrap();
        assert!(ok.success());
        let mut seq = VideoSource::open(&clip).unwrap();
        let mut frames = Vec::new();
        while let Some(f) = seq.next_frame().unwrap() {
            frames.push(f);
        }
        assert_eq!(frames.len(), 120);
        let mut src = VideoSource::open(&clip).unwrap();
        // The last frames come out of the decoder's drain without a timestamp, so a seek there
        // cannot be verified (false); wherever a seek reports true, it must be exact.
        for i in [119, 0, 61, 60, 3, 90, 118, 110] {
            let want = &frames[i];
            for expect in [want.timestamp_s, None] {
                let landed = src.seek(i, expect).unwrap();
                assert!(landed || i > 110, "seek to {i} ({expect:?})");
                if !landed {
                    continue;
                }
                let got = src.next_frame().unwrap().unwrap();
                assert_eq!((got.index, got.timestamp_s), (i, want.timestamp_s));
                let diff =
                    cvcore::norm2(&got.image, &want.image, cvcore::NORM_INF, &Mat::default());
                assert_eq!(diff.unwrap(), 0.0, "frame {i} pixels");
                let next = src.next_frame().unwrap().map(|f| (f.index, f.timestamp_s));
                assert_eq!(next, frames.get(i + 1).map(|f| (f.index, f.timestamp_s)));
            }
        }
        assert!(!src.seek(61, Some(frames[60].timestamp_s.unwrap())).unwrap());
    }

    #[test]
    fn rotation_follows_ffprobe() {
        for (meta, want) in [
            (0.0, 0),
            (90.0, 90),
            (-90.0, -90),
            (270.0, -90),
            (180.0, -180),
            (-180.0, -180),
            (f64::NAN, 0),
        ] {
            assert_eq!(super::display_rotation(meta), want, "{meta}");
        }
    }
}
