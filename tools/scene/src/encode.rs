//! H.264 encoding of raw RGBA frames by piping them into ffmpeg; the video appears at its final
//! path only when ffmpeg succeeded (temporary file in the same folder, then a rename).

use keyframer::error::{Error, Result};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

/// A running ffmpeg encoder; dropping it unfinished stops ffmpeg and removes the partial file.
pub struct Encoder {
    child: Option<Child>,
    tmp: PathBuf,
    path: PathBuf,
}

impl Encoder {
    /// Starts ffmpeg writing `path` (H.264, yuv420p, crf 18, constant `fps`, the container's
    /// `creation_time` tag set to `created_utc`, RFC 3339).
    pub fn start(
        path: &Path,
        width: u32,
        height: u32,
        fps: f64,
        created_utc: &str,
    ) -> Result<Encoder> {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let tmp = path.with_file_name(format!(".{name}.tmp-{}", std::process::id()));
        let rate = format!("{fps}");
        let child = Command::new("ffmpeg")
            .args([
                "-y",
                "-loglevel",
                "error",
                "-f",
                "rawvideo",
                "-pix_fmt",
                "rgba",
            ])
            .args([
                "-video_size",
                &format!("{width}x{height}"),
                "-framerate",
                &rate,
            ])
            .args([
                "-i", "pipe:0", "-c:v", "libx264", "-preset", "medium", "-crf", "18",
            ])
            .args(["-pix_fmt", "yuv420p", "-r", &rate, "-f", "mp4"])
            .args(["-metadata", &format!("creation_time={created_utc}")])
            .arg(&tmp)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| Error::Output {
                path: path.to_path_buf(),
                msg: format!("cannot start ffmpeg (is it installed?): {e}"),
            })?;
        Ok(Encoder {
            child: Some(child),
            tmp,
            path: path.to_path_buf(),
        })
    }

    /// Sends one frame.
    pub fn write(&mut self, rgba: &[u8]) -> Result<()> {
        let stdin = self
            .child
            .as_mut()
            .and_then(|c| c.stdin.as_mut())
            .ok_or_else(|| Error::Output {
                path: self.path.clone(),
                msg: "ffmpeg input closed".into(),
            })?;
        stdin.write_all(rgba).map_err(|e| Error::Output {
            path: self.path.clone(),
            msg: format!("writing a frame to ffmpeg failed: {e}"),
        })
    }

    /// Closes the input, waits for ffmpeg and moves the video into place.
    pub fn finish(mut self) -> Result<()> {
        let Some(mut child) = self.child.take() else {
            return Err(Error::Output {
                path: self.path.clone(),
                msg: "ffmpeg already stopped".into(),
            });
        };
        drop(child.stdin.take());
        let out = child
            .wait_with_output()
            .map_err(|e| Error::io(&self.path, e))?;
        if !out.status.success() {
            let _ = std::fs::remove_file(&self.tmp);
            return Err(Error::Output {
                path: self.path.clone(),
                msg: format!(
                    "ffmpeg failed ({}): {}",
                    out.status,
                    String::from_utf8_lossy(&out.stderr).trim()
                ),
            });
        }
        std::fs::rename(&self.tmp, &self.path).map_err(|e| Error::io(&self.path, e))
    }
}

impl Drop for Encoder {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            drop(child.stdin.take());
            let _ = child.kill();
            let _ = child.wait();
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}
