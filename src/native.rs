//! Settings of the native libraries keyframer's binaries load (FFmpeg through OpenCV, Mesa's
//! Vulkan drivers), made once at start-up by the `keyframer` binary and the development tools.

/// FFmpeg and OpenCV print their own diagnostics to stderr; keyframer reports problems itself in
/// one line each, so theirs are silenced unless the user configured them. Mesa's Vulkan drivers
/// print an error line when XDG_RUNTIME_DIR is unset (headless machines): give them a private one.
///
/// Call it first thing in `main`, before any other thread exists (it sets environment variables).
pub fn quiet_logs() {
    for (var, value) in [
        ("OPENCV_FFMPEG_LOGLEVEL", "-8"),
        ("OPENCV_LOG_LEVEL", "FATAL"),
    ] {
        if std::env::var_os(var).is_none() {
            std::env::set_var(var, value);
        }
    }
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        use std::os::unix::fs::{DirBuilderExt, MetadataExt};
        let uid = std::fs::metadata("/proc/self")
            .map(|m| m.uid())
            .unwrap_or(0);
        let dir = std::env::temp_dir().join(format!("keyframer-runtime-{uid}"));
        let _ = std::fs::DirBuilder::new().mode(0o700).create(&dir);
        let private = std::fs::metadata(&dir)
            .map(|m| m.is_dir() && m.uid() == uid && m.mode() & 0o077 == 0)
            .unwrap_or(false);
        if private {
            std::env::set_var("XDG_RUNTIME_DIR", &dir);
        }
    }
}
