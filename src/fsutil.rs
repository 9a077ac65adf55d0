//! File-system helpers that never leave a partial file behind: atomic writes, output-folder checks,
//! relative paths and input fingerprints.

use crate::error::{Error, Result};
use crate::output::fnv1a64;
use serde::{Deserialize, Serialize};
use std::fs;
use std::io::{Read, Write};
use std::path::{Component, Path, PathBuf};

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename, so readers
/// see either the old file or the whole new one. The temporary is a new file with a unique name
/// (created exclusively, so a link or FIFO planted under a guessed name is never followed) and is
/// removed on failure.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_via_temp(path, |f| f.write_all(bytes))
}

/// Copies `from` to `to` atomically (temporary file + rename), byte for byte.
pub fn copy_atomic(from: &Path, to: &Path) -> Result<()> {
    let mut src = fs::File::open(from).map_err(|e| Error::io(to, e))?;
    write_via_temp(to, |f| std::io::copy(&mut src, f).map(drop))
}

/// Writes `value` as pretty JSON with a final newline, atomically.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let mut text =
        serde_json::to_string_pretty(value).map_err(|e| Error::output(path, e.to_string()))?;
    text.push('\n');
    write_atomic(path, text.as_bytes())
}

/// The [`write_atomic`] protocol with `fill` writing the temporary's content.
fn write_via_temp(
    path: &Path,
    fill: impl FnOnce(&mut fs::File) -> std::io::Result<()>,
) -> Result<()> {
    let tmp = temp_sibling(path);
    let result = (|| -> std::io::Result<()> {
        let mut f = fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)?;
        fill(&mut f)?;
        f.sync_data()?;
        fs::rename(&tmp, path)
    })();
    result.map_err(|e| {
        let _ = fs::remove_file(&tmp);
        Error::io(path, e)
    })
}

/// Seconds since the Unix epoch (0 for a clock set before it).
pub fn now_unix_s() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

fn temp_sibling(path: &Path) -> PathBuf {
    path.with_file_name(crate::output::temp_name(
        path.file_name().unwrap_or_default(),
    ))
}

/// `target` expressed relative to the folder `base`, when both are absolute paths on the same root;
/// otherwise `target` made absolute.
pub fn relative_to(target: &Path, base: &Path) -> PathBuf {
    let target = absolute(target);
    let base = absolute(base);
    let t: Vec<Component> = target.components().collect();
    let b: Vec<Component> = base.components().collect();
    if t.first() != b.first() {
        return target;
    }
    let common = t.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let mut out = PathBuf::new();
    for _ in common..b.len() {
        out.push("..");
    }
    for c in &t[common..] {
        out.push(c.as_os_str());
    }
    if out.as_os_str().is_empty() {
        out.push(".");
    }
    out
}

/// `path` made absolute against the current directory, with `.` and `..` resolved lexically.
pub fn absolute(path: &Path) -> PathBuf {
    let joined = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir()
            .unwrap_or_else(|_| PathBuf::from("/"))
            .join(path)
    };
    let mut out = PathBuf::new();
    for c in joined.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            other => out.push(other.as_os_str()),
        }
    }
    out
}

/// Identifies an input file or folder cheaply: size, modification time and a hash of its start.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fingerprint {
    /// Total size in bytes (sum over files for a folder).
    pub size: u64,
    /// Modification time, seconds since the Unix epoch (latest file for a folder).
    pub mtime_s: u64,
    /// FNV-1a 64 of the first 1 MiB (of the file, or of the sorted file names and sizes).
    pub prefix_hash: String,
}

const PREFIX_BYTES: u64 = 1 << 20;

/// Fingerprint of one file.
pub fn fingerprint_file(path: &Path) -> Result<Fingerprint> {
    let meta = fs::metadata(path).map_err(|e| Error::io(path, e))?;
    let mut buf = Vec::new();
    fs::File::open(path)
        .and_then(|f| f.take(PREFIX_BYTES).read_to_end(&mut buf))
        .map_err(|e| Error::io(path, e))?;
    Ok(Fingerprint {
        size: meta.len(),
        mtime_s: mtime_s(&meta),
        prefix_hash: format!("{:016x}", fnv1a64(&buf)),
    })
}

/// Fingerprint of a list of files (an image folder): names, sizes and newest mtime.
pub fn fingerprint_files(files: &[PathBuf]) -> Result<Fingerprint> {
    let mut size = 0;
    let mut newest = 0;
    let mut listing = Vec::new();
    for f in files {
        let meta = fs::metadata(f).map_err(|e| Error::io(f, e))?;
        size += meta.len();
        newest = newest.max(mtime_s(&meta));
        let name = f
            .file_name()
            .map(|n| n.to_string_lossy())
            .unwrap_or_default();
        listing.extend_from_slice(format!("{name}\t{}\n", meta.len()).as_bytes());
    }
    Ok(Fingerprint {
        size,
        mtime_s: newest,
        prefix_hash: format!("{:016x}", fnv1a64(&listing)),
    })
}

fn mtime_s(meta: &fs::Metadata) -> u64 {
    meta.modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

/// The first executable called `name` on PATH.
pub fn find_on_path(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_paths() {
        assert_eq!(
            relative_to(Path::new("/a/b/c.mp4"), Path::new("/a/d")),
            PathBuf::from("../b/c.mp4")
        );
        assert_eq!(
            relative_to(Path::new("/a/b/c.mp4"), Path::new("/a/b")),
            PathBuf::from("c.mp4")
        );
    }

    #[test]
    fn fnv_known_value() {
        // FNV-1a 64 of "a" is 0xaf63dc4c8601ec8c (published test vector).
        assert_eq!(fnv1a64(b"a"), 0xaf63_dc4c_8601_ec8c);
    }
}
