//! The one output-safety rule every writing command goes through. Guarantees: an output is never
//! an input (anything the command reads, listed in its [`Inputs`]), nor inside or around one;
//! names are at most [`NAME_MAX`] bytes, keyframer's temporaries included; only regular files (or
//! missing paths) are ever replaced, never a device, FIFO, socket, symbolic link or folder; names
//! read from files are plain file names; a folder output is replaced only where keyframer's own
//! record (manifest.json, colmap.json, scene.json, .keyframer-run) lists what it wrote, a folder
//! without that record is refused; keyframer's own stale temporaries (of processes that are gone)
//! are cleared; a folder created by a command that then fails is removed again; every output is
//! written under its lock (one writer at a time, see [`lock`]).

pub mod lock;

use crate::error::{Error, Result};
use lock::Lock;
use std::ffi::OsStr;
use std::fs;
use std::path::{Component, Path, PathBuf};

/// File written last into an input's folder when every step of the workflow succeeded.
pub const DONE: &str = "done.json";
/// Marks a folder as made by `keyframer run` (so a re-run may replace its partial content).
pub const MARKER: &str = ".keyframer-run";

/// Marker inside the names of keyframer's temporaries: `.<name>.tmp-<pid>`,
/// `.keyframer-staging-<pid>`, `.keyframer-write-test-<pid>`.
const TEMP_PREFIXES: [&str; 2] = [".keyframer-staging-", ".keyframer-write-test-"];

/// Refuses a name read from a file (manifest entry, image file name, workflow export name) that is
/// not a plain file name: empty, `.`/`..`, containing a path separator or NUL, or absolute.
/// `what` says where the name came from (`manifest.json frames[3].file`).
pub fn plain_name(name: &str, what: &str, file: &Path) -> Result<()> {
    let bad = name.is_empty()
        || name == "."
        || name == ".."
        || name.contains('/')
        || name.contains('\\')
        || name.contains('\0');
    if bad {
        return Err(Error::file(file, None, "name", what, format!(
                "`{}` is not a plain file name (no folders, no `..`); keyframer writes only inside its output",
                name.escape_debug()
            )));
    }
    Ok(())
}

/// `path` made absolute the way the kernel walks it: component by component, every symbolic link
/// of the existing part resolved before a following `..` is applied (so `LINK/../x` is where the
/// kernel would write, not where the text suggests); the missing rest is appended as written.
pub fn resolve(path: &Path) -> PathBuf {
    let start = if path.is_absolute() {
        PathBuf::from("/")
    } else {
        std::env::current_dir()
            .and_then(fs::canonicalize)
            .unwrap_or_else(|_| PathBuf::from("/"))
    };
    let mut cur = start;
    let mut exists = true;
    for c in path.components() {
        match c {
            Component::RootDir | Component::Prefix(_) | Component::CurDir => {}
            Component::ParentDir => {
                cur.pop();
            }
            Component::Normal(n) => {
                cur.push(n);
                if exists {
                    match fs::symlink_metadata(&cur) {
                        Ok(m) if m.file_type().is_symlink() => match fs::canonicalize(&cur) {
                            Ok(c) => cur = c,
                            // A dangling link: the kernel would create its target.
                            Err(_) => exists = false,
                        },
                        Ok(_) => {}
                        Err(_) => exists = false,
                    }
                }
            }
        }
    }
    cur
}

/// Everything a command reads (the video, the telemetry beside it, a project, an export's
/// manifest and images, a COLMAP model, a workflow, a model description and the network files it
/// names, ...), each path with what it is. Each command builds its list where it resolves its
/// inputs, and every output check ([`check_file`], [`prepare_dir`], [`check_not_input`]) takes
/// it, so an output is checked against all of them and the refusal names the input.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Inputs(Vec<(&'static str, PathBuf)>);

impl Inputs {
    /// No inputs (a command that reads nothing, or a check made again after the command's own).
    pub fn none() -> Inputs {
        Inputs::default()
    }

    /// Adds `path`, a `what` ("telemetry", "COLMAP model").
    pub fn add(&mut self, what: &'static str, path: impl Into<PathBuf>) -> &mut Inputs {
        self.0.push((what, path.into()));
        self
    }

    /// `self` with `path` added.
    pub fn with(mut self, what: &'static str, path: impl Into<PathBuf>) -> Inputs {
        self.add(what, path);
        self
    }

    /// Adds every input of `other`.
    pub fn extend(&mut self, other: &Inputs) -> &mut Inputs {
        self.0.extend(other.0.iter().cloned());
        self
    }

    /// The inputs: what each is, and its path.
    pub fn iter(&self) -> impl Iterator<Item = (&'static str, &Path)> {
        self.0.iter().map(|(w, p)| (*w, p.as_path()))
    }
}

/// Refuses an output that is an input, lies inside an input folder or contains an input; the
/// message names the input and what it is.
pub fn check_not_input(out: &Path, inputs: &Inputs) -> Result<()> {
    let o = resolve(out);
    for (what, input) in inputs.iter() {
        let i = resolve(input);
        let how = if o == i {
            "is the input"
        } else if o.starts_with(&i) {
            "lies inside the input"
        } else if i.starts_with(&o) {
            "contains the input"
        } else {
            continue;
        };
        let msg = format!(
            "the output {how} {} ({what}); keyframer never writes into its inputs: choose another output",
            input.display()
        );
        return Err(Error::output(out, msg));
    }
    Ok(())
}

/// What exists at `path`, without following a symbolic link.
fn kind_of(path: &Path) -> Option<&'static str> {
    let m = fs::symlink_metadata(path).ok()?;
    let t = m.file_type();
    Some(if t.is_file() {
        "file"
    } else if t.is_dir() {
        "folder"
    } else if t.is_symlink() {
        "symbolic link"
    } else {
        "device, FIFO or socket"
    })
}

/// Checks a single-file output named by the user (`select -o`, `flow -o`, `report`, ...): not an
/// input, a regular file or a missing path, replaced only with `force`; takes its lock first (hold
/// it until the file is written). Clears this name's stale temporaries of earlier, killed runs.
pub fn check_file(path: &Path, force: bool, inputs: &Inputs) -> Result<Lock> {
    check_not_input(path, inputs)?;
    check_name_len(path)?;
    // Refused before anything is made beside it, and checked again under the lock.
    file_replaceable(path, force)?;
    let held = lock::beside(path)?;
    file_replaceable(path, force)?;
    if let (Some(dir), Some(name)) = (path.parent(), path.file_name()) {
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        clear_stale_temps_of(dir, Some(name));
    }
    Ok(held)
}

/// Refuses a file output that is not a regular file or missing, or that exists without `force`.
fn file_replaceable(path: &Path, force: bool) -> Result<()> {
    match kind_of(path) {
        None => Ok(()),
        Some("file") if !force => Err(Error::output(path, "exists; pass --force to overwrite it")),
        Some("file") => Ok(()),
        Some(kind) => {
            let msg = format!("is a {kind}, not a regular file; keyframer replaces only regular files: choose another output");
            Err(Error::output(path, msg))
        }
    }
}

/// The longest file name the file systems keyframer writes to take (Linux `NAME_MAX`), in bytes.
pub const NAME_MAX: usize = 255;

/// Refuses an output whose file name is longer than [`NAME_MAX`] bytes: said before any work,
/// instead of a failed write at the end.
pub fn check_name_len(path: &Path) -> Result<()> {
    let n = path.file_name().map_or(0, OsStr::len);
    if n > NAME_MAX {
        let msg = format!(
            "its name is {n} bytes; a file name may have at most {NAME_MAX}: choose a shorter name"
        );
        return Err(Error::output(path, msg));
    }
    Ok(())
}

/// Refuses to replace `path` unless it is a regular file or missing (for files inside an output
/// folder that keyframer is about to write).
pub fn check_replaceable(path: &Path) -> Result<()> {
    match kind_of(path) {
        None | Some("file") => Ok(()),
        Some(kind) => Err(Error::output(
            path,
            format!("is a {kind}; keyframer replaces only regular files it wrote"),
        )),
    }
}

/// Whether process `pid` is alive (Linux: `/proc/PID` exists).
fn pid_alive(pid: u32) -> bool {
    pid == std::process::id() || Path::new("/proc").join(pid.to_string()).exists()
}

/// Bytes a temporary's name adds to its base: `.`, `.tmp-` and [`unique_suffix`] (a pid of at
/// most 10 digits, `-`, a counter of at most 20 and 9 digits of nanoseconds).
const TEMP_EXTRA: usize = 1 + 5 + 40;

/// The part of a temporary's name that says whose it is: the file's `name` when the rest fits
/// within [`NAME_MAX`], else its first bytes, `~` and 16 hex digits of a hash of the whole name:
/// one base per name either way, so the temporaries of a long name are still found as its own.
fn temp_base(name: &OsStr) -> String {
    use std::os::unix::ffi::OsStrExt;
    let full = name.to_string_lossy();
    let room = NAME_MAX - TEMP_EXTRA;
    if full.len() <= room {
        return full.into_owned();
    }
    let tag = format!("~{:016x}", fnv1a64(name.as_bytes()));
    let mut cut = room - tag.len();
    while !full.is_char_boundary(cut) {
        cut -= 1;
    }
    format!("{}{tag}", &full[..cut])
}

/// A new temporary's name for the file `name` (written beside it, then renamed over it):
/// `.NAME.tmp-PID-N`, the name shortened so that it never has more than [`NAME_MAX`] bytes.
pub fn temp_name(name: &OsStr) -> String {
    format!(".{}.tmp-{}", temp_base(name), unique_suffix())
}

/// The pid a keyframer temporary's name ends with, if `name` is one (of `of`, when given).
fn temp_pid(name: &str, of: Option<&OsStr>) -> Option<u32> {
    // `PID` or `PID-UNIQUE`.
    let digits = |s: &str| s.split('-').next().and_then(|p| p.parse::<u32>().ok());
    if let Some(rest) = name.strip_prefix('.') {
        if let Some((base, pid)) = rest.rsplit_once(".tmp-") {
            if of.is_none_or(|o| temp_base(o) == base) {
                return digits(pid);
            }
        }
    }
    if of.is_none() {
        for p in TEMP_PREFIXES {
            if let Some(pid) = name.strip_prefix(p) {
                return digits(pid);
            }
        }
    }
    None
}

/// Removes keyframer's temporaries in `dir` left by processes that are gone (all of them, or
/// those of the file `of`). Returns how many were removed.
pub fn clear_stale_temps_of(dir: &Path, of: Option<&OsStr>) -> usize {
    let Ok(entries) = fs::read_dir(dir) else {
        return 0;
    };
    let mut n = 0;
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(pid) = name.to_str().and_then(|s| temp_pid(s, of)) else {
            continue;
        };
        if pid_alive(pid) {
            continue;
        }
        let p = e.path();
        let r = match e.file_type() {
            Ok(t) if t.is_dir() => fs::remove_dir_all(&p),
            Ok(t) if t.is_file() => fs::remove_file(&p),
            _ => continue,
        };
        match r {
            Ok(()) => {
                log::info!(
                    "removed a stale temporary of an earlier run: {}",
                    p.display()
                );
                n += 1;
            }
            Err(e) => log::warn!("{}: cannot remove a stale temporary: {e}", p.display()),
        }
    }
    n
}

/// Reads a file keyframer reads as a record or input document (project, manifest, colmap.json,
/// done.json, .keyframer-run, workflow): only a regular file (following links) is opened, so a FIFO
/// or device in its place is an error, never a hang.
pub fn read_text(path: &Path) -> Result<String> {
    let m = fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !m.file_type().is_file() {
        return Err(Error::input(
            path,
            "is not a regular file (a folder, device, FIFO or socket)",
        ));
    }
    fs::read_to_string(path).map_err(|e| Error::io(path, e))
}

/// Reads the JSON record `path` (a `what`: "project file"), errors naming the offending field
/// with its line and column.
pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path, what: &'static str) -> Result<T> {
    let text = read_text(path)?;
    let de = &mut serde_json::Deserializer::from_str(&text);
    serde_path_to_error::deserialize(de).map_err(|e| {
        let field = e.path().to_string();
        let inner = e.into_inner();
        let msg = format!("{inner} (line {}, column {})", inner.line(), inner.column());
        Error::file(path, None, what, field, msg)
    })
}

/// FNV-1a, 64 bit: a small, stable, non-cryptographic hash (fingerprints, folder and temporary
/// names).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    fnv1a64_update(FNV_OFFSET, bytes)
}

/// [`fnv1a64`]'s starting state.
pub const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

/// [`fnv1a64`] continued from the state `h` over `bytes` (a long input hashed in pieces).
pub fn fnv1a64_update(mut h: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// A name suffix unique to this process and call: `PID-N`, so a temporary is always a new file
/// (never one planted or left under a predictable name).
pub fn unique_suffix() -> String {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    format!(
        "{}-{}{nanos:09}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    )
}

/// A folder output being written, locked for this process while the value lives; created by this
/// command when `created` is not empty (the folders made, outermost first), which
/// [`OutDir::abandon`] removes again when still empty.
#[derive(Debug)]
pub struct OutDir {
    /// The folder.
    pub path: PathBuf,
    created: Vec<PathBuf>,
    lock: Lock,
}

impl OutDir {
    /// Whether this command created the folder.
    pub fn is_new(&self) -> bool {
        !self.created.is_empty()
    }

    /// After a failure: releases the lock and removes the folders this command created, when
    /// nothing else is in them.
    pub fn abandon(self) {
        drop(self.lock);
        remove_created(&self.created);
    }
}

/// Removes the folders of `created` (outermost first) that hold nothing but stale temporaries.
fn remove_created(created: &[PathBuf]) {
    for d in created.iter().rev() {
        clear_stale_temps_of(d, None);
        let _ = fs::remove_dir(d);
    }
}

/// Prepares a folder output named by the user (`export --out`, `colmap -o`, `keyframer-scene`):
/// refuses an input, a non-folder and a folder keyframer did not make (non-empty without `record`
/// inside); a non-empty folder of keyframer's needs `force`. Clears stale temporaries, creates the folder
/// when missing, locks it and checks that it is writable, leaving nothing behind.
pub fn prepare_dir(dir: &Path, force: bool, records: &[&str], inputs: &Inputs) -> Result<OutDir> {
    check_not_input(dir, inputs)?;
    check_name_len(dir)?;
    let created = create_dir(dir)?;
    // Ownership first (a folder keyframer may not write is not touched, not even locked), and
    // again under the lock; temporaries are cleared only in a folder that is keyframer's (or empty).
    check_ours(dir, force, records)?;
    let held = lock::folder(dir).inspect_err(|_| remove_created(&created))?;
    let out = OutDir {
        path: dir.to_path_buf(),
        created,
        lock: held,
    };
    check_ours(dir, force, records)?;
    clear_stale_temps_of(dir, None);
    if let Err(e) = probe_write(dir) {
        out.abandon();
        let msg = format!("output folder is not writable: {e}");
        return Err(Error::output(dir, msg));
    }
    Ok(out)
}

/// Creates `dir` when missing; returns the folders made (outermost first) for [`OutDir::abandon`].
fn create_dir(dir: &Path) -> Result<Vec<PathBuf>> {
    match kind_of(dir) {
        Some("folder") => Ok(Vec::new()),
        Some("symbolic link") if dir.is_dir() => Ok(Vec::new()),
        Some(kind) => {
            let msg = format!("exists and is a {kind}, not a folder; choose another output folder");
            Err(Error::output(dir, msg))
        }
        None => {
            let mut missing: Vec<PathBuf> = dir
                .ancestors()
                .take_while(|d| !d.as_os_str().is_empty() && fs::symlink_metadata(d).is_err())
                .map(Path::to_path_buf)
                .collect();
            fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
            missing.reverse();
            Ok(missing)
        }
    }
}

/// Refuses a non-empty `dir` (keyframer's temporaries and lock files aside) without a record, or
/// without `force`.
fn check_ours(dir: &Path, force: bool, records: &[&str]) -> Result<()> {
    let record = records.first().copied().unwrap_or("record");
    let non_empty = fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .flatten()
        .any(|e| {
            !e.file_name()
                .to_str()
                .is_some_and(|n| temp_pid(n, None).is_some() || lock::is_lock_file(n))
        });
    if non_empty && !records.iter().any(|r| dir.join(r).is_file()) {
        let msg = format!("is not empty and holds no {record}, so keyframer did not make it; keyframer replaces only its own results: choose a new or empty folder");
        return Err(Error::output(dir, msg));
    }
    if non_empty && !force {
        let msg = format!(
            "holds earlier results ({record}); pass --force to replace what keyframer wrote there"
        );
        return Err(Error::output(dir, msg));
    }
    Ok(())
}

/// Writes and removes a probe file in `dir`.
fn probe_write(dir: &Path) -> std::io::Result<()> {
    let probe = dir.join(format!(".keyframer-write-test-{}", unique_suffix()));
    let written = fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .and_then(|mut f| std::io::Write::write_all(&mut f, b"ok"));
    let _ = fs::remove_file(&probe);
    written
}

/// A path relative to an output folder, as read from keyframer's own record: relative, made of
/// plain names only (so it stays inside the folder).
pub fn inside(rel: &str, what: &str, file: &Path) -> Result<PathBuf> {
    let p = Path::new(rel);
    let plain = !rel.is_empty()
        && p.components().all(|c| matches!(c, Component::Normal(_)))
        && !rel.contains('\\')
        && !rel.contains('\0');
    if !plain {
        return Err(Error::file(file, None, "record", what, format!(
                "`{}` is not a path inside the folder; keyframer reads and removes only inside its output",
                rel.escape_debug()
            )));
    }
    Ok(p.to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_names() {
        let f = Path::new("m.json");
        for ok in ["a.jpg", "frame_000001.png", "a b.JPG", ".hidden"] {
            assert!(plain_name(ok, "x", f).is_ok(), "{ok}");
        }
        for bad in ["", ".", "..", "../x", "a/b", "/etc/x", "a\\b", "a\0b"] {
            assert!(plain_name(bad, "x", f).is_err(), "{bad:?}");
        }
        assert!(inside("images/a.jpg", "x", f).is_ok());
        for bad in ["../a", "/a", "a/../../b", "", "./a"] {
            assert!(inside(bad, "x", f).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn temp_names() {
        assert_eq!(temp_pid(".a.jpg.tmp-123", None), Some(123));
        assert_eq!(
            temp_pid(".a.jpg.tmp-123", Some(OsStr::new("a.jpg"))),
            Some(123)
        );
        assert_eq!(temp_pid(".a.jpg.tmp-123", Some(OsStr::new("b.jpg"))), None);
        assert_eq!(temp_pid(".keyframer-write-test-9", None), Some(9));
        assert_eq!(temp_pid(".keyframer-staging-9", None), Some(9));
        assert_eq!(temp_pid("a.jpg", None), None);
        assert_eq!(temp_pid(".a.tmp-x", None), None);
        assert_eq!(temp_pid(".a.jpg.tmp-123-7", None), Some(123));
        assert_eq!(temp_pid(".keyframer-staging-9-3", None), Some(9));
    }

    #[test]
    fn temp_names_of_long_names_fit_and_stay_recognised() {
        let d = tempfile::tempdir().unwrap();
        // 255 bytes, the longest name a file may have; one ASCII, one of 2-byte characters.
        let ascii = "a".repeat(251) + ".jpg";
        let wide = "é".repeat(125) + "x.jpg";
        let sibling = "a".repeat(250) + "b.jpg";
        for name in [&ascii, &wide, &sibling] {
            assert_eq!(name.len(), NAME_MAX);
            let n = OsStr::new(name.as_str());
            let (t1, t2) = (temp_name(n), temp_name(n));
            assert!(t1.len() <= NAME_MAX, "{} bytes", t1.len());
            assert_ne!(t1, t2, "unique");
            // The file system takes it, and it is known as this name's temporary only.
            std::fs::write(d.path().join(&t1), "x").unwrap();
            assert_eq!(temp_pid(&t1, Some(n)), Some(std::process::id()));
            assert_eq!(temp_pid(&t1, None), Some(std::process::id()));
            let other = if name == &ascii { &sibling } else { &ascii };
            assert_eq!(temp_pid(&t1, Some(OsStr::new(other.as_str()))), None);
        }
        // A short name keeps its plain form.
        let t = temp_name(OsStr::new("p.json"));
        assert!(t.starts_with(".p.json.tmp-"), "{t}");
        // A stale temporary of a long name (its process gone) is cleared as that name's.
        let dead = (3_000_000..4_000_000)
            .find(|p| !Path::new("/proc").join(p.to_string()).exists())
            .unwrap();
        let stale = format!(".{}.tmp-{dead}-0", temp_base(OsStr::new(ascii.as_str())));
        std::fs::write(d.path().join(&stale), "x").unwrap();
        assert_eq!(
            clear_stale_temps_of(d.path(), Some(OsStr::new(&sibling))),
            0
        );
        assert_eq!(clear_stale_temps_of(d.path(), Some(OsStr::new(&ascii))), 1);
        assert!(!d.path().join(&stale).exists());
    }

    #[test]
    fn outputs_never_touch_inputs() {
        let d = tempfile::tempdir().unwrap();
        let input = d.path().join("in");
        fs::create_dir_all(&input).unwrap();
        let i = Inputs::none().with("image folder", &input);
        assert!(check_not_input(&input, &i).is_err());
        assert!(check_not_input(&input.join("x"), &i).is_err());
        assert!(check_not_input(d.path(), &i).is_err());
        assert!(check_not_input(&d.path().join("out"), &i).is_ok());
        // The refusal names the input and what it is.
        let e = check_not_input(&input, &i).unwrap_err().to_string();
        assert!(
            e.contains("is the input") && e.contains("(image folder)"),
            "{e}"
        );
        // Through a symbolic link too, and through `LINK/..` (the link's parent, not `.`).
        let link = d.path().join("link");
        std::os::unix::fs::symlink(&input, &link).unwrap();
        assert!(check_not_input(&link.join("y"), &i).is_err());
        let sub = input.join("sub");
        fs::create_dir_all(&sub).unwrap();
        let elsewhere = d.path().join("elsewhere");
        fs::create_dir_all(&elsewhere).unwrap();
        let l2 = elsewhere.join("l2");
        std::os::unix::fs::symlink(&sub, &l2).unwrap();
        assert_eq!(resolve(&l2.join("../v.mp4")), resolve(&input.join("v.mp4")));
        assert!(check_not_input(&l2.join("../v.mp4"), &i).is_err());
    }

    #[test]
    fn names_past_name_max_are_refused_before_any_work() {
        let d = tempfile::tempdir().unwrap();
        let ok = d.path().join("a".repeat(NAME_MAX));
        assert!(check_file(&ok, false, &Inputs::none()).is_ok());
        let long = d.path().join("a".repeat(NAME_MAX + 1));
        let e = check_file(&long, false, &Inputs::none())
            .unwrap_err()
            .to_string();
        assert!(e.contains("256 bytes"), "{e}");
        assert!(prepare_dir(&long, false, &["r"], &Inputs::none()).is_err());
        assert!(!long.exists());
    }
}
