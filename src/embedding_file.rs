//! The side file of one cached embedding series, beside its project: a 16-byte header (the magic
//! [`MAGIC`], the dimension as a little-endian u32, four zero bytes), then one record per frame
//! in frame order, `dim` little-endian i16 (a unit vector quantised to multiples of 1/32767, as
//! `steps::similarity::quantise` makes them). The analysis appends frame by frame ([`Writer`]),
//! a resumed analysis truncates it back to its checkpoint's frame count, and selection reads back
//! only the frames it needs ([`read`]). A file without the magic is never written over or removed
//! by keyframer ([`is_ours`]).

use crate::error::{Error, Result};
use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

/// The first 8 bytes of every series file (format version 1).
pub const MAGIC: [u8; 8] = *b"KFEMB\0\0\x01";
/// Bytes before the first record.
pub const HEADER: u64 = 16;

/// Bytes of one record of `dim` values.
fn record(dim: usize) -> u64 {
    2 * dim as u64
}

/// The header of a series of `dim` values per frame.
fn header(dim: usize) -> [u8; 16] {
    let mut h = [0u8; 16];
    h[..8].copy_from_slice(&MAGIC);
    h[8..12].copy_from_slice(&(dim as u32).to_le_bytes());
    h
}

/// The dimension a series file's header gives, and its length in bytes; None when `path` is not
/// a readable series file (no magic).
fn read_header(path: &Path) -> Option<(usize, u64)> {
    let mut f = File::open(path).ok()?;
    let mut h = [0u8; 16];
    f.read_exact(&mut h).ok()?;
    if h[..8] != MAGIC {
        return None;
    }
    let dim = u32::from_le_bytes([h[8], h[9], h[10], h[11]]) as usize;
    Some((dim, f.metadata().ok()?.len()))
}

/// Whether `path` is a regular file that starts as keyframer's series files do.
pub fn is_ours(path: &Path) -> bool {
    std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_file())
        && read_header(path).is_some()
}

/// Whole frames `path` holds (None: not a series file).
pub fn frames_in(path: &Path) -> Option<usize> {
    let (dim, len) = read_header(path)?;
    match dim {
        0 => Some(0),
        _ => Some((len.saturating_sub(HEADER) / record(dim)) as usize),
    }
}

/// Whether `path` is a series file of exactly `n` records of `dim` values: what [`read`] accepts
/// (a file with a torn last record or another dimension is recomputed, not read).
pub fn holds(path: &Path, dim: usize, n: usize) -> bool {
    read_header(path).is_some_and(|(got, len)| got == dim && len == HEADER + n as u64 * record(dim))
}

/// Removes `path` when it is keyframer's series file; anything else is left alone.
pub fn remove_ours(path: &Path) {
    if is_ours(path) {
        if let Err(e) = std::fs::remove_file(path) {
            log::warn!("{}: could not remove the embeddings: {e}", path.display());
        }
    }
}

/// Appends one series' records to its file, frame by frame.
pub struct Writer {
    path: PathBuf,
    file: Option<BufWriter<File>>,
    dim: usize,
    frames: usize,
}

impl Writer {
    /// Writes at `path`, keeping its first `frames` records (a resumed analysis; the file must
    /// hold them) or, with 0, starting a new file (an existing one is replaced).
    pub fn open(path: &Path, frames: usize) -> Result<Writer> {
        let mut w = Writer {
            path: path.to_path_buf(),
            file: None,
            dim: 0,
            frames: 0,
        };
        if frames == 0 {
            return Ok(w);
        }
        let (dim, _) = read_header(path)
            .ok_or_else(|| Error::input(path, "not a keyframer embeddings file"))?;
        if frames_in(path).unwrap_or(0) < frames {
            let msg = format!("holds fewer than the checkpoint's {frames} frames");
            return Err(Error::input(path, msg));
        }
        let f = File::options()
            .write(true)
            .custom_flags(libc::O_NOFOLLOW)
            .open(path)
            .map_err(|e| Error::io(path, e))?;
        let end = HEADER + frames as u64 * record(dim);
        f.set_len(end).map_err(|e| Error::io(path, e))?;
        let mut f = BufWriter::new(f);
        f.seek(SeekFrom::Start(end))
            .map_err(|e| Error::io(path, e))?;
        (w.file, w.dim, w.frames) = (Some(f), dim, frames);
        Ok(w)
    }

    /// Appends the next frame's record; every record of a series has the first one's length.
    pub fn push(&mut self, values: &[i16]) -> Result<()> {
        if self.file.is_none() {
            self.create(values.len())?;
        }
        let path = &self.path;
        if values.len() != self.dim {
            let msg = format!(
                "frame {}: {} values after {} per frame",
                self.frames,
                values.len(),
                self.dim
            );
            return Err(Error::input(path, msg));
        }
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        if let Some(f) = self.file.as_mut() {
            f.write_all(&bytes).map_err(|e| Error::io(path, e))?;
        }
        self.frames += 1;
        Ok(())
    }

    /// Starts the file with the header of `dim` values a record, not through a symbolic link
    /// (`select`'s output checks refused one; this closes the race).
    fn create(&mut self, dim: usize) -> Result<()> {
        let path = &self.path;
        let f = File::options()
            .write(true)
            .create(true)
            .truncate(true)
            .custom_flags(libc::O_NOFOLLOW)
            .open(path)
            .map_err(|e| Error::io(path, e))?;
        let mut f = BufWriter::new(f);
        f.write_all(&header(dim)).map_err(|e| Error::io(path, e))?;
        (self.file, self.dim) = (Some(f), dim);
        Ok(())
    }

    /// Puts every record pushed so far on disk (before a checkpoint names them).
    pub fn flush(&mut self) -> Result<()> {
        if let Some(f) = self.file.as_mut() {
            let path = &self.path;
            f.flush().map_err(|e| Error::io(path, e))?;
            f.get_ref().sync_data().map_err(|e| Error::io(path, e))?;
        }
        Ok(())
    }

    /// Flushes and closes the file; returns the dimension and the frames written. With no frame
    /// pushed the file is still made (a header of 0 values: an empty series).
    pub fn finish(mut self) -> Result<(usize, usize)> {
        if self.file.is_none() {
            self.create(0)?;
        }
        self.flush()?;
        Ok((self.dim, self.frames))
    }
}

/// The records of `frames` (in the order given) of the series at `path`, which must hold exactly
/// `count` records of `dim` values.
pub fn read(path: &Path, dim: usize, count: usize, frames: &[usize]) -> Result<Vec<Vec<i16>>> {
    let damaged = |msg: String| Error::input(path, format!("{msg}: run `keyframer select` again"));
    let Some((got, len)) = read_header(path) else {
        return Err(damaged(
            "missing, or not a keyframer embeddings file".into(),
        ));
    };
    if got != dim || len != HEADER + count as u64 * record(dim) {
        return Err(damaged(format!(
            "holds {len} bytes of {got} values per frame, the project says {count} frames of {dim}"
        )));
    }
    let mut f = std::io::BufReader::new(File::open(path).map_err(|e| Error::io(path, e))?);
    let mut buf = vec![0u8; record(dim) as usize];
    frames
        .iter()
        .map(|&i| {
            if i >= count {
                return Err(damaged(format!("has no frame {i}")));
            }
            f.seek(SeekFrom::Start(HEADER + i as u64 * record(dim)))
                .and_then(|_| f.read_exact(&mut buf))
                .map_err(|e| Error::io(path, e))?;
            Ok(buf
                .chunks_exact(2)
                .map(|b| i16::from_le_bytes([b[0], b[1]]))
                .collect())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_resumes_and_reads_back() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.emb");
        let mut w = Writer::open(&p, 0).unwrap();
        for i in 0..5i16 {
            w.push(&[i, -i, 7]).unwrap();
        }
        assert!(w.push(&[1, 2]).is_err());
        assert_eq!(w.finish().unwrap(), (3, 5));
        assert_eq!(frames_in(&p), Some(5));
        // Resumed at frame 3: frames 3 and 4 are written again.
        let mut w = Writer::open(&p, 3).unwrap();
        w.push(&[30, 31, 32]).unwrap();
        assert_eq!(w.finish().unwrap(), (3, 4));
        let got = read(&p, 3, 4, &[3, 0, 2]).unwrap();
        assert_eq!(got, [vec![30, 31, 32], vec![0, 0, 7], vec![2, -2, 7]]);
        assert!(read(&p, 3, 5, &[0]).is_err());
        assert!(read(&p, 3, 4, &[4]).is_err());
        assert!(Writer::open(&p, 9).is_err());
        let other = dir.path().join("other.txt");
        std::fs::write(&other, b"not ours at all, not ours").unwrap();
        assert!(!is_ours(&other));
        remove_ours(&other);
        assert!(other.exists());
        remove_ours(&p);
        assert!(!p.exists());
    }

    /// `holds` accepts exactly what `read` accepts: a torn last record or another dimension
    /// is not a usable series; a series of no frames is made and reads back empty.
    #[test]
    fn holds_agrees_with_read_and_empty_series_exist() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.json.partial.emb");
        let mut w = Writer::open(&path, 0).unwrap();
        w.push(&[1, 2, 3]).unwrap();
        w.push(&[4, 5, 6]).unwrap();
        assert_eq!(w.finish().unwrap(), (3, 2));
        assert!(holds(&path, 3, 2));
        assert!(read(&path, 3, 2, &[1]).is_ok());
        assert!(!holds(&path, 2, 3) && !holds(&path, 3, 1));
        let f = File::options().append(true).open(&path).unwrap();
        f.set_len(f.metadata().unwrap().len() - 1).unwrap();
        assert!(!holds(&path, 3, 2) && read(&path, 3, 2, &[0]).is_err());
        assert_eq!(frames_in(&path), Some(1), "whole records only");

        let empty = dir.path().join("e.emb");
        assert_eq!(Writer::open(&empty, 0).unwrap().finish().unwrap(), (0, 0));
        assert!(holds(&empty, 0, 0));
        assert_eq!(read(&empty, 0, 0, &[]).unwrap().len(), 0);
    }
}
