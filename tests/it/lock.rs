//! One writer per output (issue 29): a second writer of an output in use is refused at once,
//! naming the holder's pid and command, and the output stays whole; the lock of a holder killed
//! with SIGKILL is taken over; a forced re-export removes only what keyframer's records list.
//! Holders are frozen with SIGSTOP while the second writer runs, so no timing decides a test.

use crate::common::*;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Starts keyframer in the background.
fn spawn(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args(args)
        .arg("--quiet")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Sends `sig` (`STOP`, `CONT`) to `child`.
fn signal(child: &Child, sig: &str) {
    let ok = Command::new("kill")
        .args([format!("-{sig}"), child.id().to_string()])
        .status()
        .unwrap();
    assert!(ok.success(), "kill -{sig}");
}

/// Waits until `ready` holds, at most `limit`; returns whether it held.
fn wait_for(limit: Duration, mut ready: impl FnMut() -> bool) -> bool {
    let start = Instant::now();
    while !ready() {
        if start.elapsed() > limit {
            return false;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    true
}

/// Runs keyframer to its end within `limit` (a writer waiting for the lock is a failure, not a
/// hang); returns the exit code, stderr and how long it took.
fn run_within(args: &[&str], limit: Duration) -> (i32, String, Duration) {
    let start = Instant::now();
    let mut child = spawn(args);
    if !wait_for(limit, || matches!(child.try_wait(), Ok(Some(_)))) {
        child.kill().unwrap();
        let _ = child.wait();
        panic!("keyframer {args:?} did not finish within {limit:?}");
    }
    let Output { status, stderr, .. } = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&stderr).into_owned();
    (status.code().unwrap_or(-1), err, start.elapsed())
}

/// Whether `out` holds an export's staging folder (the export is writing its images).
fn staging(out: &Path) -> bool {
    listing(out)
        .iter()
        .any(|n| n.starts_with(".keyframer-staging-"))
}

/// The image names the export's manifest lists, sorted.
fn manifest_files(out: &Path) -> Vec<String> {
    let m = json(&out.join("manifest.json"));
    let mut v: Vec<String> = m["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["file"].as_str().unwrap().to_string())
        .collect();
    v.sort();
    v
}

/// An 8 s 640x480 clip (240 frames: exporting them as PNG takes a few seconds) and two projects
/// of it: every frame (`all.json`) and every 2nd frame (`half.json`).
fn long_clip_projects(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let clip = testsrc(dir, "long.mp4", 640, 480, "30", 8.0);
    let all = dir.join("all.json");
    let half = dir.join("half.json");
    for (p, every) in [(&all, "1"), (&half, "2")] {
        kf_ok(&[
            "select",
            s(&clip),
            "--every",
            every,
            "--backend",
            "opencv",
            "-o",
            s(p),
        ]);
    }
    (clip, all, half)
}

const LIMIT: Duration = Duration::from_secs(120);

#[test]
fn a_second_export_into_a_busy_folder_is_refused_and_the_folder_stays_whole() {
    let d = tempfile::tempdir().unwrap();
    let (_, all, half) = long_clip_projects(d.path());
    let out = d.path().join("out");
    let png = ["--format", "png"];
    let a = spawn(&[&["export", s(&all), "--out", s(&out)][..], &png].concat());
    assert!(
        wait_for(LIMIT, || staging(&out)),
        "the first export started"
    );
    // The first export frozen mid-way: the second must not wait for it, nor write beside it.
    signal(&a, "STOP");
    let b = run_within(
        &[&["export", s(&half), "--out", s(&out)][..], &png].concat(),
        LIMIT,
    );
    signal(&a, "CONT");
    let a_pid = a.id();
    let a_out = a.wait_with_output().unwrap();
    let (code, err, took) = b;
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains(&format!("pid {a_pid}: `keyframer export {}", s(&all))),
        "names the holder: {err}"
    );
    assert!(took < Duration::from_secs(20), "refused at once: {took:?}");
    assert!(a_out.status.success(), "{a_out:?}");
    let images = listing(&out.join("images"));
    assert_eq!(images.len(), 240);
    assert_eq!(
        images,
        manifest_files(&out),
        "images/ is what manifest.json lists"
    );
    assert!(!out.join(".keyframer-lock").exists(), "released");

    // A forced re-export of another selection removes what keyframer wrote and keeps a user's
    // file (saying so: whatever reads the folder reads it too).
    std::fs::write(out.join("images/mine.png"), "mine").unwrap();
    let (code, err, _) = run_within(
        &[&["export", s(&half), "--out", s(&out), "--force"][..], &png].concat(),
        LIMIT,
    );
    assert_eq!(code, 0, "{err}");
    let mut expected = manifest_files(&out);
    assert_eq!(expected.len(), 120);
    expected.push("mine.png".into());
    expected.sort();
    assert_eq!(listing(&out.join("images")), expected);
    assert_eq!(
        std::fs::read_to_string(out.join("images/mine.png")).unwrap(),
        "mine"
    );
    let (code, err) = code_and_stderr(&kf_loud(&[
        "export",
        s(&half),
        "--out",
        s(&out),
        "--force",
        "--format",
        "png",
    ]));
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("mine.png") && err.contains("did not write"),
        "{err}"
    );
}

#[test]
fn a_lock_left_by_a_killed_export_is_taken_over() {
    let d = tempfile::tempdir().unwrap();
    let (_, all, half) = long_clip_projects(d.path());
    let out = d.path().join("out");
    // An earlier export, then a forced one killed while it writes.
    kf_ok(&["export", s(&half), "--out", s(&out), "--format", "png"]);
    let mut a = spawn(&[
        "export",
        s(&all),
        "--out",
        s(&out),
        "--format",
        "png",
        "--force",
    ]);
    assert!(wait_for(LIMIT, || staging(&out)), "the export started");
    a.kill().unwrap();
    a.wait().unwrap();
    let lock = out.join(".keyframer-lock");
    let left = std::fs::read_to_string(&lock).unwrap_or_default();
    assert!(
        left.contains(&format!("pid {}\n", a.id())),
        "the killed holder's lock file is left: {left:?}"
    );
    // The next export takes the lock over, replaces only keyframer's files, keeps the user's.
    std::fs::write(out.join("images/mine.png"), "mine").unwrap();
    let (code, err, _) = run_within(
        &[
            "export",
            s(&half),
            "--out",
            s(&out),
            "--format",
            "png",
            "--force",
        ],
        LIMIT,
    );
    assert_eq!(code, 0, "{err}");
    assert!(!lock.exists(), "released");
    let mut expected = manifest_files(&out);
    assert_eq!(expected.len(), 120);
    expected.push("mine.png".into());
    expected.sort();
    assert_eq!(listing(&out.join("images")), expected);
    assert_eq!(listing(&out), vec!["images", "manifest.json"]);
}

#[test]
fn a_project_file_has_one_writer_and_a_killed_ones_lock_is_taken_over() {
    let d = tempfile::tempdir().unwrap();
    let clip = testsrc(d.path(), "long.mp4", 640, 480, "30", 8.0);
    let p = d.path().join("p.json");
    let lock = d.path().join(".p.json.keyframer-lock");
    let select = |every: &'static str| {
        let (clip, p) = (s(&clip), s(&p));
        vec![
            "select",
            clip,
            "--every",
            every,
            "--backend",
            "opencv",
            "-o",
            p,
            "--force",
        ]
    };
    let (first, second) = (select("1"), select("3"));

    // Whether `child` has taken the lock (its record is in the lock file).
    let holds = |child: &Child| {
        std::fs::read_to_string(&lock).is_ok_and(|t| t.contains(&format!("pid {}\n", child.id())))
    };
    let a = spawn(&first);
    // Frozen once it holds the lock (a keyframer without locks is frozen after 20 s, or has
    // finished: the second writer then succeeds, which fails this test as it should).
    wait_for(Duration::from_secs(20), || holds(&a));
    signal(&a, "STOP");
    let (code, err, took) = run_within(&second, LIMIT);
    signal(&a, "CONT");
    let a_pid = a.id();
    let a_out = a.wait_with_output().unwrap();
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains(&format!("pid {a_pid}: `keyframer select")) && err.contains("p.json"),
        "{err}"
    );
    assert!(took < Duration::from_secs(20), "refused at once: {took:?}");
    assert!(a_out.status.success(), "{a_out:?}");
    assert_eq!(keyframes(&p).len(), 240, "the first writer's project");
    assert!(!lock.exists(), "released");

    // Killed while it holds the lock: the next select takes it over. Without its project the
    // select decodes the clip (about a second under the lock); with it, the cached run can
    // finish between two looks at the lock file.
    std::fs::remove_file(&p).unwrap();
    let mut a = spawn(&first);
    assert!(wait_for(LIMIT, || holds(&a)), "the select took its lock");
    a.kill().unwrap();
    a.wait().unwrap();
    assert!(holds(&a), "the killed holder's lock file is left");
    let (code, err, _) = run_within(&second, LIMIT);
    assert_eq!(code, 0, "{err}");
    assert_eq!(keyframes(&p).len(), 80);
    assert!(!lock.exists(), "released");
    let hidden: Vec<String> = listing(d.path())
        .into_iter()
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(hidden.is_empty(), "{hidden:?}");
}
