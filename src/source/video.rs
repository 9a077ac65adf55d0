//! Video input through OpenCV's VideoCapture with the FFmpeg backend: metadata, sequential decode,
//! cheap skipping with `grab`, per-frame presentation timestamps, and detection of streams that end
//! before the container says they should.

use super::{Frame, FrameSource, Metadata, SourceKind};
use crate::error::{CvContext, Error, Result};
use opencv::core::Mat;
use opencv::prelude::*;
use opencv::videoio::{self, VideoCapture};
use std::path::{Path, PathBuf};

/// A video file being decoded front to back.
pub struct VideoSource {
    path: PathBuf,
    cap: VideoCapture,
    meta: Metadata,
    /// Frame 0, decoded at open time to prove the stream is readable.
    pending: Option<Frame>,
    /// Index of the next frame to come out of the decoder.
    next_index: usize,
    last_ts: Option<f64>,
    last_step: Option<f64>,
    ended: bool,
    failure: Option<(usize, String)>,
}

impl VideoSource {
    /// Opens `path` and decodes its first frame; fails with a clear message when the file is not a
    /// readable video.
    pub fn open(path: &Path) -> Result<Self> {
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
        let rotation = get(videoio::CAP_PROP_ORIENTATION_META) as i32;
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

    /// Grabs the next frame; returns its index and timestamp, or `None` at the end of the stream.
    fn grab(&mut self) -> Result<Option<(usize, Option<f64>)>> {
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
        let ts = self.timestamp(index);
        Ok(Some((index, ts)))
    }

    /// The current frame's presentation time. When the stream gives none or goes backwards (OpenCV
    /// reports no usable time for frames drained from the decoder at the end), the previous
    /// frame interval is repeated (1 / fps for the second frame).
    fn timestamp(&mut self, index: usize) -> Option<f64> {
        let ms = self.cap.get(videoio::CAP_PROP_POS_MSEC).unwrap_or(f64::NAN);
        let from_stream = ms / 1000.0;
        let fallback_step = self.last_step.or(self.meta.fps.map(|f| 1.0 / f));
        let ts = match self.last_ts {
            Some(prev) if !(from_stream.is_finite() && from_stream > prev) => {
                log::debug!(
                    "{}: frame {index}: no usable timestamp ({ms} ms); extrapolated",
                    self.path.display()
                );
                Some(prev + fallback_step.unwrap_or(0.0))
            }
            None if !from_stream.is_finite() => self.meta.fps.map(|f| index as f64 / f),
            _ => Some(from_stream),
        };
        if let (Some(prev), Some(t)) = (self.last_ts, ts) {
            if t > prev {
                self.last_step = Some(t - prev);
            }
        }
        self.last_ts = ts;
        ts
    }

    fn note_end(&mut self) {
        let declared = self.meta.frame_count;
        let got = self.next_index;
        let slack = 2.max(declared / 100);
        if declared > got + slack {
            self.failure = Some((
                got,
                format!(
                    "decoding stopped after {got} frames but the container declares {declared}; \
                     frames from {got} on could not be decoded (damaged or truncated stream)"
                ),
            ));
        }
    }

    fn decode_next(&mut self) -> Result<Option<Frame>> {
        let Some((index, timestamp_s)) = self.grab()? else {
            return Ok(None);
        };
        let mut image = Mat::default();
        let ok = self
            .cap
            .retrieve(&mut image, 0)
            .cv(|| format!("retrieve {} frame {index}", self.path.display()))?;
        if !ok || image.empty() {
            return Err(Error::Frame {
                path: self.path.clone(),
                index,
                msg: "the decoder returned no image".into(),
            });
        }
        if self.meta.width != 0
            && (image.cols() as u32 != self.meta.width || image.rows() as u32 != self.meta.height)
        {
            return Err(Error::Frame {
                path: self.path.clone(),
                index,
                msg: format!(
                    "frame size changed from {}x{} to {}x{} inside the stream",
                    self.meta.width,
                    self.meta.height,
                    image.cols(),
                    image.rows()
                ),
            });
        }
        Ok(Some(Frame {
            index,
            timestamp_s,
            image,
        }))
    }
}

impl FrameSource for VideoSource {
    fn path(&self) -> &Path {
        &self.path
    }

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
        self.grab()
    }

    fn decode_failure(&self) -> Option<(usize, String)> {
        self.failure.clone()
    }
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
