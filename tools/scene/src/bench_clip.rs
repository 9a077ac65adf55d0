//! `keyframer-bench-clip`: the H.264 clips `keyframer bench pipeline` times: a pan over a photo
//! (Debian's opencv-doc aerial photo when the test data is present, otherwise ffmpeg's testsrc2
//! pattern) with sensor-like temporal noise, so the bitrate, and with it the decode cost, is that
//! of real footage. Made with ffmpeg; the clip appears at its path only when complete.

use keyframer::error::{Error, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

/// What to make.
#[derive(Debug, Clone)]
pub struct ClipSettings {
    /// Output clip (MP4); the texture is cached beside it.
    pub out: PathBuf,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Frame rate.
    pub fps: u32,
    /// Length in seconds.
    pub seconds: u32,
}

fn ffmpeg_error(what: &str, msg: impl Into<String>) -> Error {
    Error::Param {
        name: what.into(),
        msg: msg.into(),
    }
}

fn run_ffmpeg(cmd: &mut Command, what: &str) -> Result<()> {
    let out = cmd
        .output()
        .map_err(|e| ffmpeg_error(what, format!("cannot start: {e}")))?;
    if !out.status.success() {
        return Err(ffmpeg_error(
            what,
            format!(
                "failed ({}): {}",
                out.status,
                String::from_utf8_lossy(&out.stderr).trim()
            ),
        ));
    }
    Ok(())
}

/// A photo to pan over, `width` pixels wide, made once in `dir`.
fn texture(dir: &Path, width: u32) -> Result<PathBuf> {
    let out = dir.join(format!("texture-{width}.png"));
    if out.exists() {
        return Ok(out);
    }
    let data = std::env::var_os("KEYFRAMER_TESTDATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("target/testdata"));
    let photo = data.join("opencv-doc/aero3.jpg");
    let mut cmd = Command::new("ffmpeg");
    cmd.args(["-v", "error", "-y"]);
    if photo.exists() {
        cmd.arg("-i").arg(&photo);
    } else {
        cmd.args([
            "-f",
            "lavfi",
            "-i",
            "testsrc2=size=640x480:rate=1",
            "-frames:v",
            "1",
        ]);
    }
    cmd.args(["-vf", &format!("scale={width}:-2:flags=bicubic")]);
    let tmp = dir.join(format!(".texture-{width}.tmp.png"));
    cmd.arg(&tmp);
    run_ffmpeg(&mut cmd, "ffmpeg (texture)")?;
    std::fs::rename(&tmp, &out).map_err(|e| Error::io(&out, e))?;
    Ok(out)
}

/// Makes the clip (replacing nothing: an existing clip is left as it is and returned).
pub fn make(s: &ClipSettings) -> Result<PathBuf> {
    let out = s.out.clone();
    if out.exists() {
        return Ok(out);
    }
    if Command::new("ffmpeg").arg("-version").output().is_err() {
        return Err(ffmpeg_error(
            "ffmpeg",
            "the benchmark clips are made with ffmpeg: install it (Debian: apt-get install ffmpeg)",
        ));
    }
    let (w, h, fps, secs) = (s.width, s.height, s.fps, s.seconds);
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| Error::param("OUT", format!("{} is not a file name", out.display())))?;
    let dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let tex = texture(&dir, w * 2)?;
    let tmp = dir.join(format!(".{name}.tmp.mp4"));
    let vf = format!(
        "crop={w}:{h}:x='(iw-{w})/2*(1+sin(t/7))':y='(ih-{h})/2*(1+sin(t/11))',\
         noise=alls=8:allf=t,format=yuv420p"
    );
    run_ffmpeg(
        Command::new("ffmpeg")
            .args(["-v", "error", "-y", "-loop", "1", "-framerate"])
            .arg(fps.to_string())
            .arg("-i")
            .arg(&tex)
            .args(["-vf", &vf, "-t"])
            .arg(secs.to_string())
            .args(["-r"])
            .arg(fps.to_string())
            .args(["-c:v", "libx264", "-preset", "veryfast", "-crf", "23"])
            .arg(&tmp),
        "ffmpeg (clip)",
    )?;
    std::fs::rename(&tmp, &out).map_err(|e| Error::io(&out, e))?;
    Ok(out)
}
