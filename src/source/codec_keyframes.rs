//! Keyframe-only decode for `select --preview`: `ffprobe` lists the video's packets (which ones
//! the codec marks as keyframes, every frame's presentation time), `ffmpeg -skip_frame nokey`
//! decodes only those keyframes. The source yields them in order as a short sequence whose frame
//! `j` is the `j`-th codec keyframe; [`CodecKeyframeIndex`] maps it back to the video's frame indices.
//! Frames are streamed from the decoder's pipe one at a time, so memory stays bounded.

use super::{Frame, FrameSource, Metadata, VideoSource};
use crate::error::{CvContext, Error, Result};
use opencv::core::{Mat, Scalar, CV_8UC3};
use opencv::prelude::*;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};

/// Which frames of a video the codec can decode on their own, from its packet list.
#[derive(Debug, Clone, PartialEq)]
pub struct CodecKeyframeIndex {
    /// Presentation time of every frame in display order, seconds from the first frame.
    pub timestamps_s: Vec<f64>,
    /// Display-order indices of the codec keyframes, ascending.
    pub keyframes: Vec<usize>,
}

impl CodecKeyframeIndex {
    /// Number of frames in the video.
    pub fn frame_count(&self) -> usize {
        self.timestamps_s.len()
    }
}

fn missing_tool(tool: &str, e: std::io::Error) -> Error {
    Error::step(
        "preview",
        format!(
            "cannot run `{tool}` ({e}); the keyframe-only preview needs FFmpeg's command-line \
             tools (Debian/Ubuntu: apt-get install ffmpeg)"
        ),
    )
}

/// Parses `ffprobe -show_entries packet=pts_time,dts_time,flags -of csv=p=0` output into an
/// index. A packet's time is its presentation time, or its decode time when the container
/// stores none (AVI: only B-frames carry a pts; there display order is decode order). Packets
/// with neither are skipped; order is by that time (stable: ties keep the packet order).
pub fn parse_packets(path: &Path, text: &str) -> Result<CodecKeyframeIndex> {
    let mut packets: Vec<(f64, bool)> = Vec::new();
    let mut untimed = 0usize;
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let bad =
            |what: String| Error::input(path, format!("ffprobe packet line {}: {what}", n + 1));
        let mut parts = line.split(',');
        let (Some(pts), Some(dts), Some(flags)) = (parts.next(), parts.next(), parts.next()) else {
            return Err(bad(format!("`{line}` is not `pts,dts,flags`")));
        };
        let t = if pts != "N/A" { pts } else { dts };
        if t == "N/A" {
            untimed += 1;
            continue;
        }
        let t: f64 = t.parse().map_err(|_| bad(format!("bad time `{t}`")))?;
        packets.push((t, flags.starts_with('K')));
    }
    if untimed > 0 {
        log::debug!(
            "{}: {untimed} packets carry neither a presentation nor a decode time; left out",
            path.display()
        );
    }
    if packets.is_empty() {
        return Err(Error::input(path, "ffprobe lists no video packets"));
    }
    packets.sort_by(|a, b| a.0.total_cmp(&b.0));
    let t0 = packets[0].0;
    Ok(CodecKeyframeIndex {
        timestamps_s: packets.iter().map(|p| p.0 - t0).collect(),
        keyframes: packets
            .iter()
            .enumerate()
            .filter_map(|(i, p)| p.1.then_some(i))
            .collect(),
    })
}

/// Lists the packets of `path`'s first video stream with `ffprobe` (demuxing only, no decode).
pub fn probe(path: &Path) -> Result<CodecKeyframeIndex> {
    let args = [
        "-show_entries",
        "packet=pts_time,dts_time,flags",
        "-of",
        "csv=p=0",
    ];
    let text = super::packets::ffprobe(path, &args, |out| {
        let mut text = Vec::new();
        out.read_to_end(&mut text).map_err(|e| Error::io(path, e))?;
        Ok(String::from_utf8_lossy(&text).into_owned())
    })?;
    let index = parse_packets(path, &text)?;
    if index.keyframes.is_empty() {
        let msg = "the video marks no packet as a keyframe";
        return Err(Error::input(path, msg));
    }
    Ok(index)
}

/// The codec keyframes of a video, decoded by `ffmpeg` and read from its pipe.
pub struct CodecKeyframeSource {
    path: PathBuf,
    meta: Metadata,
    index: std::sync::Arc<CodecKeyframeIndex>,
    child: Child,
    pipe: ChildStdout,
    next: usize,
    /// The stream holds fewer frames than its container declares.
    failure: Option<(usize, String)>,
}

impl CodecKeyframeSource {
    /// Starts decoding the keyframes of `path` listed in `index`. Size and rotation come from
    /// OpenCV (as in a full decode); `ffmpeg` applies the same rotation.
    pub fn open(path: &Path, index: std::sync::Arc<CodecKeyframeIndex>) -> Result<Self> {
        let full = VideoSource::open(path)?.metadata().clone();
        let mut child = Command::new("ffmpeg")
            .args(["-nostdin", "-v", "error", "-skip_frame", "nokey", "-i"])
            .arg(path)
            .args(["-map", "0:v:0", "-fps_mode", "passthrough"])
            .args(["-f", "rawvideo", "-pix_fmt", "bgr24", "-"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| missing_tool("ffmpeg", e))?;
        let pipe = child
            .stdout
            .take()
            .ok_or_else(|| Error::step("preview", "ffmpeg started without an output pipe"))?;
        // The packet list ends where the data does: a stream cut short lists fewer packets than
        // the container declares frames (the full decode reports the same).
        let failure = super::video::short_stream(
            full.frame_count,
            index.frame_count(),
            "the stream's packet list holds",
        )
        .map(|m| (index.keyframes.len(), m));
        let meta = Metadata {
            frame_count: index.keyframes.len(),
            frame_count_exact: true,
            ..full
        };
        Ok(CodecKeyframeSource {
            path: path.to_path_buf(),
            meta,
            index,
            child,
            pipe,
            next: 0,
            failure,
        })
    }

    fn fail(&mut self, what: String) -> Error {
        let _ = self.child.kill();
        let mut err = String::new();
        if let Some(mut e) = self.child.stderr.take() {
            let _ = e.read_to_string(&mut err);
        }
        let _ = self.child.wait();
        Error::frame(
            &self.path,
            self.index.keyframes.get(self.next).copied().unwrap_or(0),
            format!("{what} {}", err.trim()),
        )
    }
}

impl Drop for CodecKeyframeSource {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl FrameSource for CodecKeyframeSource {
    fn metadata(&self) -> &Metadata {
        &self.meta
    }

    fn next_frame(&mut self) -> Result<Option<Frame>> {
        let total = self.index.keyframes.len();
        if self.next >= total {
            // The pairing of decoded frames with listed keyframes holds only if the decoder
            // delivered exactly as many: anything more would shift every index.
            if self.next == total {
                self.next += 1;
                if matches!(self.pipe.read(&mut [0u8; 1]), Ok(n) if n > 0) {
                    self.next = total;
                    return Err(self.fail(format!(
                        "ffmpeg delivered more frames than the {total} keyframes its packet list marks:"
                    )));
                }
            }
            return Ok(None);
        }
        let (w, h) = (self.meta.width as i32, self.meta.height as i32);
        let mut image = Mat::new_rows_cols_with_default(h, w, CV_8UC3, Scalar::all(0.0))
            .cv(|| "Mat::new keyframe".into())?;
        let bytes = image.data_bytes_mut().cv(|| "Mat::data_bytes_mut".into())?;
        if let Err(e) = self.pipe.read_exact(bytes) {
            let decoded = self.next;
            return Err(self.fail(format!(
                "ffmpeg delivered {decoded} of {total} keyframes ({e}):"
            )));
        }
        let index = self.next;
        self.next += 1;
        let frame = self.index.keyframes[index];
        Ok(Some(Frame {
            index,
            timestamp_s: self.index.timestamps_s.get(frame).copied(),
            image,
        }))
    }

    fn skip_frame(&mut self) -> Result<Option<(usize, Option<f64>)>> {
        Ok(self.next_frame()?.map(|f| (f.index, f.timestamp_s)))
    }

    fn decode_failure(&self) -> Option<(usize, String)> {
        self.failure.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packets_sort_by_time_and_keep_key_flags() {
        // Decode order with B-frames: I P B B, presentation 0 3 1 2.
        let text = "0.0,-0.04,K__\n0.12,0.0,___\n0.04,0.04,___\n0.08,0.08,___\n0.16,0.12,K__\nN/A,N/A,___\n";
        let ix = parse_packets(Path::new("v.mp4"), text).unwrap();
        assert_eq!(ix.timestamps_s, vec![0.0, 0.04, 0.08, 0.12, 0.16]);
        assert_eq!(ix.keyframes, vec![0, 4]);
        assert_eq!(ix.frame_count(), 5);
    }

    #[test]
    fn malformed_packet_lines_name_the_line() {
        let e = parse_packets(Path::new("v.mp4"), "0.0,0.0,K__\nxyz\n").unwrap_err();
        assert!(e.to_string().contains("line 2"), "{e}");
        let e = parse_packets(Path::new("v.mp4"), "").unwrap_err();
        assert!(e.to_string().contains("no video packets"), "{e}");
    }

    #[test]
    fn packets_without_pts_use_their_dts() {
        // AVI (Megamind.avi): I and P packets have no pts, B packets have pts = dts.
        let text = "N/A,0.000000,K_\nN/A,0.041708,K_\nN/A,0.083417,__\n0.125125,0.125125,__\nN/A,0.166834,K_\n";
        let ix = parse_packets(Path::new("v.avi"), text).unwrap();
        assert_eq!(ix.frame_count(), 5);
        assert_eq!(ix.keyframes, vec![0, 1, 4]);
        assert!((ix.timestamps_s[3] - 0.125125).abs() < 1e-9);
    }
}
