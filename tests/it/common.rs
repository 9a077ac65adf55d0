//! Helpers: run the keyframer binary and the workspace's development tools (`keyframer-scene`,
//! `keyframer-bench-clip`), make clips with ffmpeg, find the public test data.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs keyframer with `args`; returns the output (never panics on a non-zero exit).
pub fn kf(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args(args)
        .arg("--quiet")
        .output()
        .expect("run keyframer")
}

/// Runs keyframer with `args` without --quiet (to read its messages); never panics on failure.
pub fn kf_loud(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_keyframer"))
        .args(args)
        .output()
        .expect("run keyframer")
}

/// The development tools of the workspace's `keyframer-scene` package (`keyframer-scene`,
/// `keyframer-bench-clip`) are not targets of this package, so cargo does not build them for
/// these tests: the first call builds them (once per test process) into the target directory the
/// keyframer binary lives in, with its profile, and returns the path of `name` beside it (where
/// `keyframer bench pipeline` also looks for its clip tool).
pub fn tool_exe(name: &str) -> PathBuf {
    static BUILT: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    let kf = Path::new(env!("CARGO_BIN_EXE_keyframer"));
    let bin_dir = kf.parent().expect("keyframer binary folder");
    let built = BUILT.get_or_init(|| {
        let profile = bin_dir.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let target_dir = bin_dir.parent().expect("target folder");
        let mut cmd = Command::new(std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into()));
        cmd.current_dir(env!("CARGO_MANIFEST_DIR"))
            .args(["build", "--quiet", "-p", "keyframer-scene", "--bins"])
            .env("CARGO_TARGET_DIR", target_dir);
        match profile {
            "debug" => {}
            "release" => {
                cmd.arg("--release");
            }
            other => {
                cmd.args(["--profile", other]);
            }
        }
        let out = cmd.output().map_err(|e| format!("cannot run cargo: {e}"))?;
        if out.status.success() {
            Ok(())
        } else {
            Err(String::from_utf8_lossy(&out.stderr).into_owned())
        }
    });
    if let Err(e) = built {
        panic!("cargo build -p keyframer-scene failed:\n{e}");
    }
    let exe = bin_dir.join(name);
    assert!(exe.is_file(), "{} was not built", exe.display());
    exe
}

/// The `keyframer-scene` binary (built on first use, see [`tool_exe`]).
pub fn scene_exe() -> PathBuf {
    tool_exe("keyframer-scene")
}

/// Runs keyframer-scene with `args` (quiet); returns the output (never panics on a non-zero exit).
pub fn scene(args: &[&str]) -> Output {
    Command::new(scene_exe())
        .args(args)
        .arg("--quiet")
        .output()
        .expect("run keyframer-scene")
}

/// Runs keyframer-scene and asserts success.
pub fn scene_ok(args: &[&str]) {
    let out = scene(args);
    assert!(
        out.status.success(),
        "keyframer-scene {args:?} failed ({:?}):\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Encodes `dir/f%04d.png` at 30 fps as H.264 (`crf`) into `out`.
pub fn encode_frames(dir: &Path, crf: &str, out: &Path) {
    ffmpeg(&[
        "-framerate",
        "30",
        "-i",
        dir.join("f%04d.png").to_str().unwrap(),
        "-c:v",
        "libx264",
        "-crf",
        crf,
        "-pix_fmt",
        "yuv420p",
        s(out),
    ]);
}

/// Runs keyframer and asserts success; returns stdout.
pub fn kf_ok(args: &[&str]) -> String {
    let out = kf(args);
    assert!(
        out.status.success(),
        "keyframer {args:?} failed ({:?}):\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("utf-8 stdout")
}

/// Exit code and stderr of a run.
pub fn code_and_stderr(out: &Output) -> (i32, String) {
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs ffmpeg with `args` (quiet, overwrite), asserting success.
pub fn ffmpeg(args: &[&str]) {
    let out = Command::new("ffmpeg")
        .args(["-y", "-loglevel", "error"])
        .args(args)
        .output()
        .expect("ffmpeg is installed (scripts/setup.sh)");
    assert!(
        out.status.success(),
        "ffmpeg {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A testsrc2 clip: `secs` seconds at `rate` fps, `w`x`h`, H.264 in MP4.
pub fn testsrc(dir: &Path, name: &str, w: u32, h: u32, rate: &str, secs: f64) -> PathBuf {
    let p = dir.join(name);
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        &format!("testsrc2=size={w}x{h}:rate={rate}:duration={secs}"),
        "-c:v",
        "libx264",
        "-pix_fmt",
        "yuv420p",
        p.to_str().unwrap(),
    ]);
    p
}

/// A file of the public test data (Debian's opencv-doc examples, fetched by scripts/setup.sh).
pub fn testdata(rel: &str) -> PathBuf {
    let root = std::env::var_os("KEYFRAMER_TESTDATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("target/testdata"));
    let p = root.join(rel);
    assert!(
        p.exists(),
        "{} is missing: run scripts/setup.sh (it fetches Debian's opencv-doc test data)",
        p.display()
    );
    p
}

/// Reads a JSON file.
pub fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("read json")).expect("parse json")
}

/// The `keyframes` array of a project file.
pub fn keyframes(project: &Path) -> Vec<usize> {
    json(project)["keyframes"]
        .as_array()
        .expect("keyframes array")
        .iter()
        .map(|v| v.as_u64().unwrap() as usize)
        .collect()
}

/// Path as &str.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Names of the entries of a folder, sorted.
pub fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|r| {
            r.map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// A 1 s 320x240 testsrc2 clip (`dir/clip.mp4`) and a project keeping every 5th frame
/// (`dir/p.json`, 6 keyframes, opencv backend).
pub fn clip_and_project(dir: &Path) -> (PathBuf, PathBuf) {
    let clip = testsrc(dir, "clip.mp4", 320, 240, "30", 1.0);
    let project = dir.join("p.json");
    kf_ok(&[
        "select",
        s(&clip),
        "--every",
        "5",
        "--backend",
        "opencv",
        "-o",
        s(&project),
    ]);
    (clip, project)
}

/// A folder `dir/images` of five 64x48 JPEGs (`img01.jpg`..`img05.jpg`), each tagged by
/// keyframer's geotag with `tag(i)` (i from 1; `None`: left untagged); returns the folder and the
/// tags in file order.
pub fn tagged_image_folder(
    dir: &Path,
    tag: impl Fn(usize) -> Option<keyframer::geotag::GeoTag>,
) -> (PathBuf, Vec<Option<keyframer::geotag::GeoTag>>) {
    let folder = dir.join("images");
    std::fs::create_dir(&folder).unwrap();
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "testsrc2=size=64x48:rate=5:duration=1",
        s(&folder.join("img%02d.jpg")),
    ]);
    let tags = (1..=5)
        .map(|i| {
            let t = tag(i)?;
            let path = folder.join(format!("img{i:02}.jpg"));
            let mut bytes = std::fs::read(&path).unwrap();
            keyframer::geotag::tag_jpeg(&path, &mut bytes, &t).unwrap();
            std::fs::write(&path, bytes).unwrap();
            Some(t)
        })
        .collect();
    (folder, tags)
}

/// Decodes standard base64 (the test's own decoder, independent of the page's encoder).
pub fn unbase64(text: &str) -> Vec<u8> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => u32::from(c - b'A'),
        b'a'..=b'z' => u32::from(c - b'a') + 26,
        b'0'..=b'9' => u32::from(c - b'0') + 52,
        b'+' => 62,
        b'/' => 63,
        _ => panic!("not base64: {c}"),
    };
    let mut out = Vec::new();
    for chunk in text.as_bytes().chunks(4) {
        let data: Vec<u8> = chunk.iter().copied().filter(|&c| c != b'=').collect();
        let n = data
            .iter()
            .enumerate()
            .fold(0u32, |acc, (i, &c)| acc | (value(c) << (18 - 6 * i)));
        out.extend((0..data.len().saturating_sub(1)).map(|i| (n >> (16 - 8 * i)) as u8));
    }
    out
}

/// A 4 s, 30 fps pan (60 px/s) over a photo of the public test data, 320x240, H.264 at `path`;
/// `gop`: a codec keyframe every that many frames (None: x264's default).
pub fn pan_clip(path: &Path, gop: Option<&str>) {
    let photo = testdata("opencv-doc/aloeL.jpg");
    let mut args = vec!["-loop", "1", "-framerate", "30", "-t", "4", "-i", s(&photo)];
    args.extend(["-vf", "crop=320:240:'t*60':100", "-c:v", "libx264"]);
    if let Some(g) = gop {
        args.extend(["-g", g]);
    }
    args.extend(["-pix_fmt", "yuv420p", s(path)]);
    ffmpeg(&args);
}

/// The `select` flags of the pan project's analysis (a re-select with them reuses its cache).
pub const PAN_ANALYSIS: [&str; 4] = ["--backend", "opencv", "--analysis-width", "160"];

/// `dir/pan.mp4` ([`pan_clip`]) and `dir/pan.json`, selected with spacing 25 and blur (so the
/// cache holds timestamps, sharpness and movement), frames 60 and 61 added by hand.
pub fn pan_project(dir: &Path) -> PathBuf {
    let clip = dir.join("pan.mp4");
    pan_clip(&clip, None);
    let project = dir.join("pan.json");
    let mut args = vec![
        "select",
        s(&clip),
        "-o",
        s(&project),
        "--spacing",
        "25",
        "--blur",
    ];
    args.extend(PAN_ANALYSIS);
    args.extend(["--add", "60,61"]);
    kf_ok(&args);
    project
}

/// A stand-in for COLMAP: says it has no CUDA and offers the incremental mapper, writes a project
/// file, and for `mapper` a text model of three images under OUTPUT/0; fails the stage named in
/// $FAIL_STAGE with status 3 (saying "STAGE broke: boom") and sleeps (printing its pid) in the
/// stage named in $SLEEP_STAGE.
pub fn fake_colmap(dir: &Path) -> PathBuf {
    let p = dir.join("fake-colmap");
    std::fs::write(
        &p,
        r##"#!/bin/sh
stage="$1"; shift
out=""
while [ $# -gt 0 ]; do
  case "$1" in --output_path) out="$2";; esac
  shift
done
echo "fake $stage"
if [ "$stage" = "$FAIL_STAGE" ]; then echo "$stage broke: boom" >&2; exit 3; fi
if [ "$stage" = "$SLEEP_STAGE" ]; then echo "pid $$"; exec sleep 120; fi
case "$stage" in
  help|-h) printf 'COLMAP 3.8 -- fake\n  (Commit Unknown on Unknown without CUDA)\nAvailable commands:\n  feature_extractor\n  mapper\n';;
  project_generator) printf 'database_path=\nimage_path=\n[ImageReader]\nmask_path=\n' > "$out";;
  mapper)
    mkdir -p "$out/0"
    echo "1 SIMPLE_RADIAL 320 240 380 160 120 0" > "$out/0/cameras.txt"
    printf '1 1 0 0 0 0 0 0 1 frame_000000.jpg\n\n2 1 0 0 0 -1 0 0 1 frame_000005.jpg\n\n3 1 0 0 0 -2 0 0 1 frame_000010.jpg\n\n' > "$out/0/images.txt"
    echo "# no points" > "$out/0/points3D.txt";;
esac
"##,
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    p
}

/// A 64×48 testsrc2 clip of `seconds` at 10 fps with `creation_time` 2024-05-01T10:00:00Z and
/// no sidecar, at `dir/clip.mp4`.
pub fn dated_clip(dir: &Path, seconds: u32) -> PathBuf {
    let p = dir.join("clip.mp4");
    let src = format!("testsrc2=size=64x48:rate=10:duration={seconds}");
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        &src,
        "-metadata",
        "creation_time=2024-05-01T10:00:00Z",
        "-c:v",
        "libx264",
        "-pix_fmt",
        "yuv420p",
        p.to_str().unwrap(),
    ]);
    p
}

/// A project's cached per-frame positions: (lat, lon, abs_alt).
pub fn project_positions(project: &Path) -> Vec<Option<(f64, f64, f64)>> {
    let p = json(project);
    (p["cache"]["telemetry"]["positions"]
        .as_array()
        .unwrap()
        .iter())
    .map(|v| {
        (!v.is_null()).then(|| {
            (
                v["lat_deg"].as_f64().unwrap(),
                v["lon_deg"].as_f64().unwrap(),
                v["abs_alt_m"].as_f64().unwrap(),
            )
        })
    })
    .collect()
}

/// A Python that imports pycolmap where keyframer looks (`KEYFRAMER_PYTHON`, else
/// `target/pycolmap` beside the binary's folder, else `python3`).
pub fn pycolmap_found() -> bool {
    let beside = Path::new(env!("CARGO_BIN_EXE_keyframer"))
        .parent()
        .and_then(Path::parent)
        .map(|t| t.join("pycolmap/bin/python"));
    let candidates: Vec<PathBuf> = match std::env::var_os("KEYFRAMER_PYTHON") {
        Some(p) => vec![p.into()],
        None => beside
            .into_iter()
            .chain([PathBuf::from("python3")])
            .collect(),
    };
    candidates.iter().any(|p| {
        (Command::new(p).args(["-c", "import pycolmap"]).output()).is_ok_and(|o| o.status.success())
    })
}
