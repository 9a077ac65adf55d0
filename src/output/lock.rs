//! One writer per output. A writing command holds an exclusive advisory lock (`flock`) on a lock
//! file inside its output folder ([`IN_FOLDER`]) or beside its single-file output
//! (`.NAME.keyframer-lock`) from before it checks the output until it has committed; a second
//! writer is refused at once, with the holder's pid and command line. The kernel drops a lock
//! with its process, so the lock of a killed holder is free and simply taken over. Locks are
//! re-entrant within one process (`run` calls `select` and `export`). The lock file is opened
//! without following a link, only when it is a regular file holding keyframer's record (or
//! nothing), is never an output's content, and is removed when released.

use crate::error::{Error, Result};
use std::ffi::{OsStr, OsString};
use std::fs::{self, File};
use std::io::{Read, Seek, Write};
use std::os::unix::ffi::{OsStrExt, OsStringExt};
use std::os::unix::fs::{MetadataExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError, Weak};

/// The lock file inside an output folder; beside a file output it is `.NAME` + this.
pub const IN_FOLDER: &str = ".keyframer-lock";
/// The first line of a lock file's record (then `pid N` and `command ...`).
const HEADER: &str = "keyframer lock";

/// Whether `name` is one of keyframer's lock files (never an output's content).
pub fn is_lock_file(name: &str) -> bool {
    name.starts_with('.') && name.ends_with(IN_FOLDER)
}

/// A held lock; released (and its file removed) when the last clone in this process is dropped.
#[must_use = "the lock is released when dropped: keep it until the output is committed"]
#[derive(Debug, Clone)]
pub struct Lock(#[allow(dead_code)] Arc<Held>);

#[derive(Debug)]
struct Held {
    /// Open (and locked) for as long as the lock is held.
    _file: File,
    path: PathBuf,
    id: FileId,
}

impl Drop for Held {
    fn drop(&mut self) {
        // Removed while still locked, and only while it is this file: a writer that opened it
        // meanwhile finds it gone once it has the lock, and starts again with a new one.
        if file_id(&self.path) == Some(self.id) {
            let _ = fs::remove_file(&self.path);
        }
    }
}

/// A file's device and inode.
type FileId = (u64, u64);

/// The locks this process holds, by lock file (for re-entry).
static HELD: Mutex<Vec<(FileId, Weak<Held>)>> = Mutex::new(Vec::new());

/// Locks the output folder `dir` (which exists) for this process.
pub fn folder(dir: &Path) -> Result<Lock> {
    acquire(&dir.join(IN_FOLDER), dir)
}

/// Locks the single-file output `path` (or a folder made beside it) for this process: the lock
/// file is `.NAME.keyframer-lock` in the same folder, whose name stays within 255 bytes.
pub fn beside(path: &Path) -> Result<Lock> {
    let Some(name) = path.file_name() else {
        return Err(Error::output(path, "names no file"));
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    acquire(&dir.join(lock_name(name)), path)
}

/// `.NAME.keyframer-lock`, with NAME cut and followed by a hash of the whole name when the result
/// would pass the 255 bytes a file name may have.
fn lock_name(name: &OsStr) -> OsString {
    const MAX: usize = 255;
    let bytes = name.as_bytes();
    let mut out = b".".to_vec();
    if 1 + bytes.len() + IN_FOLDER.len() <= MAX {
        out.extend_from_slice(bytes);
    } else {
        // FNV-1a 64 (stable across versions, unlike std's hasher).
        let fnv = (bytes.iter()).fold(0xcbf2_9ce4_8422_2325_u64, |h, &b| {
            (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
        });
        let hash = format!("~{fnv:016x}");
        out.extend_from_slice(&bytes[..MAX - 1 - hash.len() - IN_FOLDER.len()]);
        out.extend_from_slice(hash.as_bytes());
    }
    out.extend_from_slice(IN_FOLDER.as_bytes());
    OsString::from_vec(out)
}

/// Takes the lock file `lock` for the output `out` (named in every message).
fn acquire(lock: &Path, out: &Path) -> Result<Lock> {
    let mut held = HELD.lock().unwrap_or_else(PoisonError::into_inner);
    held.retain(|(_, w)| w.strong_count() > 0);
    // A few tries: a holder that releases removes the file between our open and our lock.
    for _ in 0..10 {
        let file = open(lock, out)?;
        let id = file
            .metadata()
            .map(|m| (m.dev(), m.ino()))
            .map_err(|e| Error::io(lock, e))?;
        if let Some(mine) = held.iter().find(|(i, _)| *i == id) {
            if let Some(h) = mine.1.upgrade() {
                return Ok(Lock(h));
            }
        }
        match file.try_lock() {
            Ok(()) => {}
            Err(fs::TryLockError::WouldBlock) => return Err(refusal(lock, out, file)),
            Err(fs::TryLockError::Error(e)) => return Err(Error::io(lock, e)),
        }
        if file_id(lock) != Some(id) {
            continue;
        }
        let h = Arc::new(take_over(file, lock, out, id)?);
        held.push((id, Arc::downgrade(&h)));
        return Ok(Lock(h));
    }
    let msg = format!("its lock file {} keeps being replaced", lock.display());
    Err(Error::output(out, msg))
}

/// Opens (or creates) the lock file without following a link or blocking on a FIFO; refuses
/// anything but a regular file there.
fn open(lock: &Path, out: &Path) -> Result<File> {
    let not_regular = || {
        Error::output(
            lock,
            "is keyframer's lock file name but not a regular file; move it away",
        )
    };
    if fs::symlink_metadata(lock).is_ok_and(|m| !m.file_type().is_file()) {
        return Err(not_regular());
    }
    let file = fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .mode(0o644)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
        .open(lock)
        .map_err(|e| match fs::symlink_metadata(lock) {
            Ok(m) if !m.file_type().is_file() => not_regular(),
            _ => Error::output(
                out,
                format!("cannot make its lock file {}: {e}", lock.display()),
            ),
        })?;
    match file.metadata() {
        Ok(m) if m.file_type().is_file() => Ok(file),
        Ok(_) => Err(not_regular()),
        Err(e) => Err(Error::io(lock, e)),
    }
}

/// The lock file's device and inode, when it exists (not following a link).
fn file_id(path: &Path) -> Option<FileId> {
    fs::symlink_metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

/// The whole text of an open lock file.
fn read_record(file: &mut File) -> String {
    let mut bytes = Vec::new();
    let _ = file.rewind().and_then(|()| file.read_to_end(&mut bytes));
    String::from_utf8_lossy(&bytes).into_owned()
}

/// `pid N: `COMMAND`` from a lock file's record, when it is a whole one.
fn holder(record: &str) -> Option<String> {
    let mut lines = record.strip_prefix(HEADER)?.lines().skip(1);
    let pid = lines.next()?.strip_prefix("pid ")?;
    let command = lines.next()?.strip_prefix("command ")?;
    record
        .ends_with('\n')
        .then(|| format!("pid {pid}: `{command}`"))
}

/// The refusal of a second writer, naming the holder.
fn refusal(lock: &Path, out: &Path, mut file: File) -> Error {
    // The holder writes its record right after taking the lock: give it a moment.
    let mut who = None;
    for _ in 0..20 {
        who = holder(&read_record(&mut file));
        if who.is_some() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let who = who.unwrap_or_else(|| "a process that has not yet said which".into());
    Error::output(
        out,
        format!(
            "another keyframer is writing it ({who}); refused rather than mixing two results: wait until it ends, or choose another output (lock file {})",
            lock.display()
        ),
    )
}

/// The lock just taken: a file holding nothing or keyframer's record (of a holder that died) gets
/// this process's record; anything else is someone's file and is left alone.
fn take_over(mut file: File, lock: &Path, out: &Path, id: FileId) -> Result<Held> {
    let old = read_record(&mut file);
    if !old.is_empty() && !old.starts_with(HEADER) {
        let msg = "is not keyframer's lock file, though it has its name; move it away";
        return Err(Error::output(lock, msg));
    }
    if let Some(who) = holder(&old) {
        log::info!(
            "{}: taking over the lock of {who}, which ended without releasing it",
            out.display()
        );
    }
    let record = format!(
        "{HEADER}\npid {}\ncommand {}\n",
        std::process::id(),
        command_line()
    );
    let written = file
        .set_len(0)
        .and_then(|()| file.rewind())
        .and_then(|()| file.write_all(record.as_bytes()));
    // From here on the file is ours: dropping `held` removes it, on failure too.
    let held = Held {
        _file: file,
        path: lock.to_path_buf(),
        id,
    };
    written.map_err(|e| Error::io(lock, e))?;
    Ok(held)
}

/// This process's command line on one line (program by its file name), at most 500 characters.
fn command_line() -> String {
    let mut args = std::env::args_os();
    let program = args
        .next()
        .map(|p| Path::new(&p).file_name().unwrap_or(&p).to_os_string())
        .unwrap_or_default();
    let mut line = std::iter::once(program)
        .chain(args)
        .map(|a| a.to_string_lossy().replace(['\n', '\r'], " "))
        .collect::<Vec<_>>()
        .join(" ");
    if let Some((cut, _)) = line.char_indices().nth(500) {
        line.truncate(cut);
    }
    line
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lock_names_fit_a_file_name() {
        assert_eq!(lock_name(OsStr::new("p.json")), ".p.json.keyframer-lock");
        let long = "a".repeat(250);
        let n = lock_name(OsStr::new(&long));
        assert_eq!(n.len(), 255, "{n:?}");
        assert!(is_lock_file(n.to_str().unwrap()));
        let other = lock_name(OsStr::new(&format!("{}b", "a".repeat(249))));
        assert_ne!(n, other, "two long names keep two locks");
        assert!(is_lock_file(IN_FOLDER) && !is_lock_file("keyframer-lock"));
    }

    #[test]
    fn reentrant_in_one_process_and_removed_when_released() {
        let d = tempfile::tempdir().unwrap();
        let file = d.path().join(IN_FOLDER);
        let a = folder(d.path()).unwrap();
        let b = folder(d.path()).unwrap();
        let text = fs::read_to_string(&file).unwrap();
        assert!(
            text.starts_with(&format!("{HEADER}\npid {}\n", std::process::id())),
            "{text}"
        );
        drop(a);
        assert!(file.exists(), "still held by the second");
        drop(b);
        assert!(!file.exists());
    }

    #[test]
    fn a_holder_elsewhere_refuses_and_a_dead_one_is_taken_over() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("p.json");
        let file = d.path().join(".p.json.keyframer-lock");
        // Another open file description holding the lock: another writer, as far as flock goes.
        let record = format!("{HEADER}\npid 4242\ncommand keyframer select v.mp4 -o p.json\n");
        fs::write(&file, &record).unwrap();
        let other = File::open(&file).unwrap();
        other.try_lock().unwrap();
        let err = beside(&out).unwrap_err().to_string();
        assert!(
            err.contains("pid 4242: `keyframer select v.mp4 -o p.json`"),
            "{err}"
        );
        assert_eq!(fs::read_to_string(&file).unwrap(), record, "untouched");
        // Its holder gone (the kernel drops the lock), the record left behind is taken over.
        drop(other);
        let lock = beside(&out).unwrap();
        let now = fs::read_to_string(&file).unwrap();
        assert!(
            now.contains(&format!("pid {}\n", std::process::id())),
            "{now}"
        );
        drop(lock);
        assert!(!file.exists());
    }

    #[test]
    fn only_a_regular_file_of_keyframer_is_used() {
        let d = tempfile::tempdir().unwrap();
        let file = d.path().join(IN_FOLDER);
        let target = d.path().join("target");
        std::os::unix::fs::symlink(&target, &file).unwrap();
        let err = folder(d.path()).unwrap_err().to_string();
        assert!(err.contains("not a regular file"), "{err}");
        assert!(!target.exists(), "the link was not followed");
        fs::remove_file(&file).unwrap();
        let made = std::process::Command::new("mkfifo")
            .arg(&file)
            .status()
            .unwrap();
        assert!(made.success());
        let err = folder(d.path()).unwrap_err().to_string();
        assert!(err.contains("not a regular file"), "{err}");
        fs::remove_file(&file).unwrap();
        fs::write(&file, "mine").unwrap();
        let err = folder(d.path()).unwrap_err().to_string();
        assert!(err.contains("not keyframer's lock file"), "{err}");
        assert_eq!(fs::read_to_string(&file).unwrap(), "mine");
    }
}
