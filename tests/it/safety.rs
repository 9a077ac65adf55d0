//! Output safety (issue 14): every writing command stays inside the output it was given, never
//! writes an input, replaces only regular files and only what keyframer's own records list, and
//! leaves nothing behind when it fails. Each test asserts the exit code, the message and that the
//! files around are byte-identical afterwards.

use crate::common::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Every file under `dir` (relative path → bytes; symlinks and special files by their kind).
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<PathBuf, Vec<u8>>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries {
            let e = e.unwrap();
            let p = e.path();
            let rel = p.strip_prefix(root).unwrap().to_path_buf();
            let t = e.file_type().unwrap();
            if t.is_dir() {
                out.insert(rel, b"<dir>".to_vec());
                walk(root, &p, out);
            } else if t.is_file() {
                out.insert(rel, std::fs::read(&p).unwrap());
            } else {
                out.insert(rel, format!("<{t:?}>").into_bytes());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// A folder of 4 PNG images and a project keeping all of them.
fn image_folder_project(dir: &Path) -> (PathBuf, PathBuf) {
    let imgs = dir.join("imgs");
    std::fs::create_dir_all(&imgs).unwrap();
    for i in 0..4u8 {
        image::RgbImage::from_fn(64, 48, |x, y| {
            image::Rgb([x as u8 * 3, y as u8 * 5, i * 60])
        })
        .save(imgs.join(format!("img{i}.png")))
        .unwrap();
    }
    let project = dir.join("imgs.json");
    kf_ok(&[
        "select",
        s(&imgs),
        "--every",
        "1",
        "--backend",
        "opencv",
        "-o",
        s(&project),
    ]);
    (imgs, project)
}

/// Runs keyframer, killing it after `limit` (a hang is a failure, not a stuck suite).
fn kf_timeout(args: &[&str], limit: Duration) -> (i32, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args(args)
        .arg("--quiet")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut err = String::new();
            use std::io::Read;
            child
                .stderr
                .take()
                .unwrap()
                .read_to_string(&mut err)
                .unwrap();
            return (status.code().unwrap_or(-1), err);
        }
        if start.elapsed() > limit {
            child.kill().unwrap();
            let _ = child.wait();
            panic!("keyframer {args:?} did not finish within {limit:?} (hang)");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn names_read_from_a_manifest_never_leave_the_folder() {
    let d = tempfile::tempdir().unwrap();
    let (_, project) = clip_and_project(d.path());
    let export = d.path().join("deep/a/export");
    kf_ok(&["export", s(&project), "--out", s(&export)]);
    // The target a hostile manifest names: outside the workspace.
    let victim = d.path().join("x.txt");
    std::fs::write(&victim, "precious").unwrap();
    let mpath = export.join("manifest.json");
    let mut m = json(&mpath);
    m["frames"][0]["file"] = serde_json::json!("../../../x.txt");
    std::fs::write(&mpath, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    let before = snapshot(d.path());
    for args in [
        vec!["colmap", s(&export)],
        vec![
            "colmap",
            s(&export),
            "-o",
            s(&d.path().join("ws")),
            "--force",
        ],
    ] {
        let (code, err) = code_and_stderr(&kf(&args));
        assert_eq!(code, 1, "{err}");
        assert!(
            err.contains("frames[0].file") && err.contains("not a plain file name"),
            "{err}"
        );
    }
    // The report reading thumbnails from that export refuses it too.
    let html = d.path().join("r.html");
    let (code, err) = code_and_stderr(&kf(&[
        "report",
        s(&project),
        "-o",
        s(&html),
        "--export",
        s(&export),
    ]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("not a plain file name"), "{err}");
    // A forced re-export does not trust the edited manifest either.
    let (code, err) = code_and_stderr(&kf(&[
        "export",
        s(&project),
        "--out",
        s(&export),
        "--force",
    ]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("cannot tell what it wrote"), "{err}");
    assert_eq!(snapshot(d.path()), before, "nothing changed anywhere");
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
}

#[test]
fn colmap_force_replaces_only_what_its_record_lists() {
    let d = tempfile::tempdir().unwrap();
    let (_, project) = clip_and_project(d.path());
    let export = d.path().join("export");
    kf_ok(&["export", s(&project), "--out", s(&export)]);

    // A user's folder holding COLMAP-looking data: refused even with --force, nothing deleted.
    let user = d.path().join("user-ws");
    for (f, text) in [
        ("images/a.jpg", "a"),
        ("sparse/0/cameras.bin", "c"),
        ("dense/fused.ply", "p"),
    ] {
        let p = user.join(f);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    }
    let before = snapshot(&user);
    let (code, err) = code_and_stderr(&kf(&["colmap", s(&export), "-o", s(&user), "--force"]));
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("holds no colmap.json") && err.contains("keyframer did not make it"),
        "{err}"
    );
    assert_eq!(snapshot(&user), before);

    // Its own workspace: user files inside images/ sparse/ dense/ masks/ logs/ stop a forced
    // re-run before anything is removed; a file beside them is kept across a re-run.
    let ws = d.path().join("ws");
    kf_ok(&["colmap", s(&export), "-o", s(&ws)]);
    let rec = json(&ws.join("colmap.json"));
    let files: Vec<&str> = rec["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert!(files.contains(&"images/frame_000000.jpg"), "{files:?}");
    assert!(files.contains(&"project.ini"), "{files:?}");
    for dir in ["images", "sparse", "dense", "masks", "logs"] {
        let p = ws.join(dir).join("mine.txt");
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(&p, "mine").unwrap();
        let before = snapshot(&ws);
        let (code, err) = code_and_stderr(&kf(&["colmap", s(&export), "-o", s(&ws), "--force"]));
        assert_eq!(code, 1, "{dir}: {err}");
        assert!(
            err.contains(&format!("{dir}/mine.txt"))
                && err.contains("was not written by keyframer"),
            "{err}"
        );
        assert_eq!(snapshot(&ws), before, "{dir}: nothing removed");
        std::fs::remove_file(&p).unwrap();
    }
    std::fs::write(ws.join("notes.txt"), "mine").unwrap();
    kf_ok(&["colmap", s(&export), "-o", s(&ws), "--force"]);
    assert_eq!(
        std::fs::read_to_string(ws.join("notes.txt")).unwrap(),
        "mine"
    );
    assert_eq!(listing(&ws.join("images")).len(), 6);
}

#[test]
fn an_output_is_never_an_input() {
    let d = tempfile::tempdir().unwrap();
    let (clip, project) = clip_and_project(d.path());
    let before = snapshot(d.path());
    // The video as the project output.
    let (code, err) = code_and_stderr(&kf(&[
        "select",
        s(&clip),
        "--every",
        "5",
        "-o",
        s(&clip),
        "--force",
    ]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("is the input"), "{err}");
    // The project as the report, the flow output as one of its images.
    let (code, err) = code_and_stderr(&kf(&["report", s(&project), "-o", s(&project), "--force"]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("is the input"), "{err}");
    assert_eq!(snapshot(d.path()), before);

    // An image folder: export into it, or into a folder inside it, or around it.
    let (imgs, iproject) = image_folder_project(d.path());
    let before = snapshot(d.path());
    for (out, how) in [
        (imgs.clone(), "is the input"),
        (imgs.join("sub"), "lies inside the input"),
        (d.path().to_path_buf(), "contains the input"),
    ] {
        let (code, err) =
            code_and_stderr(&kf(&["export", s(&iproject), "--out", s(&out), "--force"]));
        assert_eq!(code, 1, "{err}");
        assert!(err.contains(how), "{how}: {err}");
    }
    // Flow writing over one of its images.
    let a = imgs.join("img0.png");
    let b = imgs.join("img1.png");
    let (code, err) = code_and_stderr(&kf(&[
        "flow",
        s(&a),
        s(&b),
        "-o",
        s(&b),
        "--force",
        "--backend",
        "opencv",
    ]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("is the input"), "{err}");
    assert_eq!(snapshot(d.path()), before, "inputs untouched");
}

#[test]
fn only_regular_files_are_replaced() {
    let d = tempfile::tempdir().unwrap();
    let (clip, project) = clip_and_project(d.path());
    let special = d.path().join("special");
    std::fs::create_dir(&special).unwrap();
    let fifo = special.join("fifo");
    let made = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    let target = special.join("target.txt");
    std::fs::write(&target, "target").unwrap();
    let link = special.join("link");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    let mut nodes = vec![
        (fifo.clone(), "device, FIFO or socket"),
        (link, "symbolic link"),
    ];
    // A character device needs root (mknod); skipped with a message otherwise.
    let node = special.join("node");
    let mknod = Command::new("mknod")
        .arg(&node)
        .args(["c", "1", "3"])
        .stderr(Stdio::null())
        .status();
    if mknod.is_ok_and(|s| s.success()) {
        nodes.push((node, "device, FIFO or socket"));
    } else {
        eprintln!("skipping the character-device case: mknod needs root");
    }
    let before = snapshot(&special);
    let limit = Duration::from_secs(60);
    for (path, kind) in &nodes {
        let p = s(path);
        for args in [
            vec!["select", s(&clip), "--every", "5", "-o", p, "--force"],
            vec![
                "report",
                s(&project),
                "-o",
                s(&d.path().join("r.html")),
                "--timeline",
                p,
                "--force",
            ],
            vec!["workflow", "save", s(&project), "-o", p, "--force"],
            vec!["flow", s(&project), s(&project), "-o", p, "--force"],
        ] {
            let (code, err) = kf_timeout(&args, limit);
            assert_eq!(code, 1, "{args:?}: {err}");
            assert!(
                err.contains(kind) && err.contains("replaces only regular files"),
                "{args:?}: {err}"
            );
        }
    }
    assert_eq!(snapshot(&special), before, "special files untouched");
    assert!(!d.path().join("r.html").exists());
}

/// A pid that is not running (so its temporaries are stale).
fn dead_pid() -> u32 {
    (3_000_000..4_000_000)
        .find(|p| !Path::new("/proc").join(p.to_string()).exists())
        .unwrap()
}

#[test]
fn nothing_is_left_behind() {
    let d = tempfile::tempdir().unwrap();
    let (clip, project) = clip_and_project(d.path());
    let out = d.path().join("out");
    kf_ok(&["export", s(&project), "--out", s(&out)]);
    // Temporaries of a killed run (export, write test, staging) go with the next run there.
    let pid = dead_pid();
    std::fs::write(out.join(format!(".keyframer-write-test-{pid}")), "ok").unwrap();
    std::fs::write(out.join(format!("images/.frame_000005.jpg.tmp-{pid}")), "x").unwrap();
    let staging = out.join(format!(".keyframer-staging-{pid}/images"));
    std::fs::create_dir_all(&staging).unwrap();
    std::fs::write(staging.join("frame_000010.jpg"), "x").unwrap();
    kf_ok(&["export", s(&project), "--out", s(&out), "--force"]);
    assert_eq!(listing(&out), vec!["images", "manifest.json"]);
    let hidden: Vec<String> = listing(&out.join("images"))
        .into_iter()
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(hidden.is_empty(), "{hidden:?}");

    // A real kill -9 in the middle of an export, then a --force re-run: no hidden files stay.
    let long = testsrc(d.path(), "long.mp4", 640, 480, "30", 8.0);
    let lp = d.path().join("long.json");
    kf_ok(&[
        "select",
        s(&long),
        "--every",
        "1",
        "--backend",
        "opencv",
        "-o",
        s(&lp),
    ]);
    let kout = d.path().join("killed");
    let mut child = Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args([
            "export",
            s(&lp),
            "--out",
            s(&kout),
            "--format",
            "png",
            "--quiet",
        ])
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        let staged = listing(&kout)
            .iter()
            .find(|n| n.starts_with(".keyframer-staging-"))
            .map(|n| listing(&kout.join(n).join("images")).len())
            .unwrap_or(0);
        if staged >= 3 || start.elapsed() > Duration::from_secs(60) {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(
        !kout.join("manifest.json").exists(),
        "killed before the end"
    );
    kf_ok(&[
        "export",
        s(&lp),
        "--out",
        s(&kout),
        "--format",
        "png",
        "--force",
    ]);
    let hidden: Vec<String> = listing(&kout)
        .into_iter()
        .chain(listing(&kout.join("images")))
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(hidden.is_empty(), "{hidden:?}");
    assert_eq!(listing(&kout.join("images")).len(), 240);

    // A size the encoders cannot write: refused before anything exists.
    let big = d.path().join("big");
    let (code, err) = code_and_stderr(&kf(&[
        "export",
        s(&project),
        "--out",
        s(&big),
        "--resize",
        "100000x100000",
    ]));
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("--resize") && err.contains("100000x100000"),
        "{err}"
    );
    assert!(!big.exists(), "no empty output folder");
    // A failure after the folder was made (the disk fills up) removes it again: tested as root in
    // `foundation::full_disk_fails_cleanly`.
    let _ = clip;
}

fn workflow(dir: &Path, export_name: &str) -> PathBuf {
    let w = dir.join(format!("w-{}.toml", export_name.replace('/', "_")));
    std::fs::write(
        &w,
        format!(
            "version = 1\n\n[analysis]\nbackend = \"opencv\"\n\n[[sample]]\nplugin = \"every-nth\"\nn = 10\n\n[[export]]\nname = \"{export_name}\"\nresize = \"160x120\"\n"
        ),
    )
    .unwrap();
    w
}

#[test]
fn run_folders_belong_to_one_input() {
    let d = tempfile::tempdir().unwrap();
    let a = d.path().join("a");
    let b = d.path().join("b");
    std::fs::create_dir_all(&a).unwrap();
    std::fs::create_dir_all(&b).unwrap();
    let va = testsrc(&a, "v.mp4", 160, 120, "30", 1.0);
    let vb = testsrc(&b, "v.mp4", 160, 120, "10", 1.0);
    let w = workflow(d.path(), "small");
    let out = d.path().join("o");
    kf_ok(&["run", s(&w), s(&va), s(&vb), "--out", s(&out)]);
    let folders = listing(&out);
    assert_eq!(folders.len(), 2, "{folders:?}");
    let before = snapshot(&out);
    // b alone: the same folder as before, skipped as done; a's results untouched.
    let (code, err) = code_and_stderr(&kf_loud(&["run", s(&w), s(&vb), "--out", s(&out)]));
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("already done"), "{err}");
    assert_eq!(snapshot(&out), before);
    // The folder name depends only on the input.
    let name_b = keyframer::batch::folder_name(&vb);
    assert!(folders.contains(&name_b), "{folders:?} {name_b}");
    // A folder recorded for another input is not reused without --force.
    let fa = out.join(keyframer::batch::folder_name(&va));
    let fb = out.join(&name_b);
    let marker_a = std::fs::read(fa.join(".keyframer-run")).unwrap();
    std::fs::write(fb.join(".keyframer-run"), &marker_a).unwrap();
    std::fs::remove_file(fb.join("done.json")).unwrap();
    let before = snapshot(&out);
    let (code, err) = code_and_stderr(&kf(&["run", s(&w), s(&vb), "--out", s(&out)]));
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("holds the results of another input"), "{err}");
    assert_eq!(snapshot(&out), before);
    kf_ok(&["run", s(&w), s(&vb), "--out", s(&out), "--force"]);
    assert!(fb.join("done.json").is_file());

    // Reserved names are refused by `workflow check`, with file:line and key.
    for name in [
        "done.json",
        ".keyframer-run",
        "project.json",
        "manifest.json",
        "masks",
        ".x",
    ] {
        let w = workflow(d.path(), name);
        let (code, err) = code_and_stderr(&kf(&["workflow", "check", s(&w)]));
        assert_eq!(code, 1, "{name}: {err}");
        assert!(
            err.contains(&format!("{}:", w.display())) && err.contains("export[0].name"),
            "{name}: {err}"
        );
    }
    // And --out holding the inputs is refused.
    let (code, err) = code_and_stderr(&kf(&["run", s(&w), s(&va), "--out", s(d.path())]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("contains the input"), "{err}");
}

#[test]
fn a_forced_export_never_replaces_a_file_its_manifest_does_not_list() {
    let d = tempfile::tempdir().unwrap();
    let (clip, project) = clip_and_project(d.path());
    let out = d.path().join("out");
    kf_ok(&["export", s(&project), "--out", s(&out)]);
    // Another selection would write frame_000003.jpg, where the user has put a file of theirs.
    let p2 = d.path().join("p2.json");
    kf_ok(&[
        "select",
        s(&clip),
        "--every",
        "3",
        "--backend",
        "opencv",
        "-o",
        s(&p2),
    ]);
    std::fs::write(out.join("images/frame_000003.jpg"), "mine").unwrap();
    let before = snapshot(&out);
    let (code, err) = code_and_stderr(&kf(&["export", s(&p2), "--out", s(&out), "--force"]));
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("frame_000003.jpg") && err.contains("manifest does not list it"),
        "{err}"
    );
    assert_eq!(snapshot(&out), before, "nothing replaced or removed");
    // Moved away, the forced export replaces exactly its own files.
    std::fs::remove_file(out.join("images/frame_000003.jpg")).unwrap();
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    kf_ok(&["export", s(&p2), "--out", s(&out), "--force"]);
    assert_eq!(listing(&out.join("images")).len(), 10);
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).unwrap(),
        "mine"
    );
}

/// The cases a hostile review found after the rule was first built: `LINK/..` spellings, inputs a
/// command reads indirectly, symbolic links inside keyframer's own folders, special files where
/// keyframer reads or removes, user files in temporary-looking names, interrupted exports.
#[test]
fn hostile_spellings_and_planted_files_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path();
    let deep = root.join("deep/a");
    std::fs::create_dir_all(deep.join("sub")).unwrap();
    let (clip, _) = clip_and_project(root);
    let vid = deep.join("vid.mp4");
    std::fs::copy(&clip, &vid).unwrap();
    let pd = root.join("pd.json");
    kf_ok(&[
        "select",
        s(&vid),
        "--every",
        "10",
        "--backend",
        "opencv",
        "-o",
        s(&pd),
    ]);
    let link = root.join("L");
    std::os::unix::fs::symlink(deep.join("sub"), &link).unwrap();
    let before = snapshot(root);
    let limit = Duration::from_secs(60);
    // `L/..` is deep/a (where the kernel goes), so `L/../vid.mp4` is the input.
    let sneaky = format!("{}/../vid.mp4", link.display());
    for args in [
        vec!["select", s(&vid), "--every", "10", "-o", &sneaky, "--force"],
        vec!["report", s(&pd), "-o", &sneaky, "--force"],
        vec!["workflow", "save", s(&pd), "-o", &sneaky, "--force"],
        // The project's own video is an input of the report and of workflow save.
        vec!["report", s(&pd), "-o", s(&vid), "--force"],
        vec![
            "report",
            s(&pd),
            "-o",
            s(&root.join("r.html")),
            "--timeline",
            s(&vid),
            "--force",
        ],
        vec!["workflow", "save", s(&pd), "-o", s(&vid), "--force"],
    ] {
        let (code, err) = kf_timeout(&args, limit);
        assert_eq!(code, 1, "{args:?}: {err}");
        assert!(err.contains("is the input"), "{args:?}: {err}");
    }
    assert_eq!(snapshot(root), before, "nothing written");

    // A symbolic link in place of images/ inside keyframer's own export is not written through.
    let (imgs, ip) = image_folder_project(root);
    let e = root.join("E");
    kf_ok(&["export", s(&ip), "--out", s(&e)]);
    std::fs::remove_dir_all(e.join("images")).unwrap();
    std::os::unix::fs::symlink(&imgs, e.join("images")).unwrap();
    let before = snapshot(&imgs);
    let (code, err) = code_and_stderr(&kf(&["export", s(&ip), "--out", s(&e), "--force"]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("symbolic links"), "{err}");
    assert_eq!(snapshot(&imgs), before, "the input folder untouched");

    // A FIFO where COLMAP's record lists a file: refused before anything is removed, no hang.
    let ev = root.join("EV");
    kf_ok(&["export", s(&pd), "--out", s(&ev)]);
    let ws = root.join("WS");
    kf_ok(&["colmap", s(&ev), "-o", s(&ws)]);
    std::fs::remove_file(ws.join("project.ini")).unwrap();
    assert!(Command::new("mkfifo")
        .arg(ws.join("project.ini"))
        .status()
        .unwrap()
        .success());
    let before = snapshot(&ws);
    let (code, err) = kf_timeout(&["colmap", s(&ev), "-o", s(&ws), "--force"], limit);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("project.ini") && err.contains("replaces only regular files"),
        "{err}"
    );
    assert_eq!(snapshot(&ws), before);
    // FIFOs where keyframer reads its records: an error, never a hang.
    std::fs::remove_file(ev.join("manifest.json")).unwrap();
    assert!(Command::new("mkfifo")
        .arg(ev.join("manifest.json"))
        .status()
        .unwrap()
        .success());
    let (code, err) = kf_timeout(
        &[
            "report",
            s(&pd),
            "-o",
            s(&root.join("r2.html")),
            "--export",
            s(&ev),
        ],
        limit,
    );
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("not a regular file"), "{err}");

    // Temporary-looking user files in a folder keyframer did not make are not swept.
    let u = root.join("U");
    let pid = dead_pid();
    std::fs::create_dir_all(u.join(format!(".keyframer-staging-{pid}/sub"))).unwrap();
    std::fs::write(
        u.join(format!(".keyframer-staging-{pid}/sub/thesis.tex")),
        "x",
    )
    .unwrap();
    std::fs::write(u.join(format!(".notes.txt.tmp-{pid}")), "x").unwrap();
    std::fs::write(u.join("data.csv"), "x").unwrap();
    let before = snapshot(&u);
    let (code, err) = code_and_stderr(&kf(&["export", s(&pd), "--out", s(&u), "--force"]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("keyframer did not make it"), "{err}");
    assert_eq!(snapshot(&u), before, "nothing swept");

    // A user's file where select keeps its checkpoint is not replaced without --force.
    let q = root.join("q.json");
    std::fs::write(root.join("q.json.partial"), "mine").unwrap();
    let (code, err) = code_and_stderr(&kf(&["select", s(&clip), "--every", "10", "-o", s(&q)]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("not a keyframer checkpoint"), "{err}");
    assert_eq!(
        std::fs::read_to_string(root.join("q.json.partial")).unwrap(),
        "mine"
    );

    // An export interrupted while moving files into place (journal written, no manifest yet):
    // the next forced export knows those files as its own and finishes cleanly.
    let j = root.join("J");
    kf_ok(&["export", s(&pd), "--out", s(&j)]);
    std::fs::remove_file(j.join("manifest.json")).unwrap();
    std::fs::write(j.join("images/frame_000099.jpg"), "half-moved").unwrap();
    std::fs::write(
        j.join(".keyframer-pending.json"),
        r#"["images/frame_000000.jpg","images/frame_000010.jpg","images/frame_000020.jpg","images/frame_000099.jpg"]"#,
    )
    .unwrap();
    kf_ok(&["export", s(&pd), "--out", s(&j), "--force"]);
    assert_eq!(listing(&j), vec!["images", "manifest.json"]);
    assert_eq!(
        listing(&j.join("images")),
        vec!["frame_000000.jpg", "frame_000010.jpg", "frame_000020.jpg"]
    );

    // Two spellings of one input (a link) meet in one run folder and are refused together.
    let alias = root.join("alias.mp4");
    std::os::unix::fs::symlink(&vid, &alias).unwrap();
    let w = workflow(root, "small");
    let (code, err) = code_and_stderr(&kf(&[
        "run",
        s(&w),
        s(&vid),
        s(&alias),
        "--out",
        s(&root.join("o")),
    ]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("are the same input"), "{err}");
}
