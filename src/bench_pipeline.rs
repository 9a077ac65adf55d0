//! `bench pipeline`: makes its own clips (1080p30 H.264 and 4K clips of two lengths, with the
//! workspace's `keyframer-bench-clip` tool) and, in one run, times decode-only (`ffmpeg -f null`,
//! OpenCV read loop) against full analysis (`select --blur --spacing 200` unless other flags are
//! given: every frame scored and flowed) per backend, with ratios, peak memory and, for the gpu
//! backend, the device work per frame `select` logs (dispatches, bytes uploaded and read back,
//! blocking waits). Analyses run as child processes so each one's peak RSS is its own.

use crate::error::{Error, Result};
use crate::gpu::PerFrame;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// What to run.
#[derive(Debug, Clone)]
pub struct Settings {
    /// Folder for the clips (re-used when present) and scratch projects.
    pub dir: PathBuf,
    /// Length of the 1080p clip in seconds.
    pub seconds: u32,
    /// Frame rate of the 4K clips.
    pub k4_fps: u32,
    /// Lengths of the 4K clips in minutes (empty: no 4K part).
    pub k4_minutes: Vec<u32>,
    /// Backends to time (`gpu`, `opencv`).
    pub backends: Vec<String>,
    /// The `select` flags of the analysis (empty: [`DEFAULT_ANALYSIS`]).
    pub select_args: Vec<String>,
    /// Also measure the analysis-width / flow-stride trade-off on a 20 s 1080p clip.
    pub tradeoffs: bool,
    /// Rounds per clip (decode loops, then every backend, in turn); medians are reported.
    pub rounds: u32,
}

/// The median of `v` (the mean of the middle two for an even count; NaN when empty).
fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    match s.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => s[n / 2],
        n => 0.5 * (s[n / 2 - 1] + s[n / 2]),
    }
}

/// One round's analysis of one backend: seconds, and its ratios to that round's decode loops.
#[derive(Debug, Clone, Copy)]
struct Round {
    secs: f64,
    to_opencv: f64,
    to_ffmpeg: Option<f64>,
}

/// The median of `v` with `decimals`, "-" when empty (no ffmpeg).
fn median_or_dash(v: &[f64], decimals: usize) -> String {
    match v.is_empty() {
        true => "-".into(),
        false => format!("{:.*}", decimals, median(v)),
    }
}

/// "lo-hi" of `v` with two decimals ("-" when empty).
fn range(v: &[f64]) -> String {
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    match v.is_empty() {
        true => "-".into(),
        false => format!("{lo:.2}-{hi:.2}"),
    }
}

fn run_tool(cmd: &mut Command, what: &str) -> Result<std::process::Output> {
    let out = cmd
        .output()
        .map_err(|e| Error::param(what, format!("cannot start: {e}")))?;
    if !out.status.success() {
        return Err(Error::param(
            what,
            format!(
                "failed ({}): {}",
                out.status,
                String::from_utf8_lossy(&out.stderr).trim()
            ),
        ));
    }
    Ok(out)
}

/// The analysis timed when no flags are given.
pub const DEFAULT_ANALYSIS: &[&str] = &["--blur", "--spacing", "200"];

/// The tool that makes the benchmark clips (package `keyframer-scene` of this workspace).
pub const CLIP_TOOL: &str = "keyframer-bench-clip";

/// [`CLIP_TOOL`] beside the running executable, else on PATH.
fn clip_tool() -> Result<PathBuf> {
    let beside = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(|d| d.join(CLIP_TOOL)));
    beside
        .filter(|p| p.is_file())
        .or_else(|| crate::fsutil::find_on_path(CLIP_TOOL))
        .ok_or_else(|| {
            Error::input(
                CLIP_TOOL,
                "not found beside keyframer or on PATH: the benchmark makes its clips with it; \
             build it with `cargo build --release -p keyframer-scene` (it lands beside \
             target/release/keyframer)",
            )
        })
}

/// A `w`x`h` H.264 clip panning over a photo with sensor-like temporal noise (so the bitrate,
/// and with it the decode cost, is that of real footage), made once by [`CLIP_TOOL`].
fn clip(dir: &Path, name: &str, w: u32, h: u32, fps: u32, secs: u32) -> Result<PathBuf> {
    let out = dir.join(name);
    if out.exists() {
        return Ok(out);
    }
    let tool = clip_tool()?;
    eprintln!("bench: making {name} ({w}x{h}, {fps} fps, {secs} s)");
    run_tool(
        Command::new(&tool)
            .arg(&out)
            .args(["--size", &format!("{w}x{h}")])
            .args(["--fps", &fps.to_string()])
            .args(["--seconds", &secs.to_string()]),
        CLIP_TOOL,
    )?;
    if !out.is_file() {
        let msg = format!("succeeded but {} is missing", out.display());
        return Err(Error::param(CLIP_TOOL, msg));
    }
    Ok(out)
}

/// Seconds for `ffmpeg -f null` to decode `clip`, or None without ffmpeg.
fn ffmpeg_decode(clip: &Path) -> Option<f64> {
    let t = Instant::now();
    let ok = Command::new("ffmpeg")
        .args(["-v", "error", "-i"])
        .arg(clip)
        .args(["-f", "null", "-"])
        .output()
        .ok()?
        .status
        .success();
    ok.then(|| t.elapsed().as_secs_f64())
}

/// Seconds for keyframer's OpenCV read loop (decode + BGR, every frame) and the frame count.
fn opencv_decode(clip: &Path) -> Result<(f64, usize)> {
    let t = Instant::now();
    let mut src = crate::source::open(clip, &Default::default())?;
    let mut n = 0;
    while src.next_frame()?.is_some() {
        n += 1;
    }
    Ok((t.elapsed().as_secs_f64(), n))
}

/// One child `select` run with `flags`: wall seconds, peak RSS in MiB and the device work per
/// frame it logged (gpu backend only).
fn analysis(
    clip: &Path,
    project: &Path,
    backend: &str,
    flags: &[String],
) -> Result<(f64, f64, Option<PerFrame>)> {
    let exe = std::env::current_exe().map_err(|e| Error::param("keyframer", e.to_string()))?;
    let _ = std::fs::remove_file(project);
    let t = Instant::now();
    let out = run_tool(
        Command::new(exe)
            .arg("select")
            .arg(clip)
            .args(["--backend", backend])
            .args(flags)
            .args(["--checkpoint-every", "0", "--quiet", "-o"])
            .arg(project)
            .env("KEYFRAMER_PEAK_RSS", "1")
            .env("RUST_LOG", "warn,keyframer::select=info"),
        &format!("keyframer select ({backend})"),
    )?;
    let secs = t.elapsed().as_secs_f64();
    let err = String::from_utf8_lossy(&out.stderr);
    let peak = err
        .lines()
        .find_map(|l| l.strip_prefix("peak-rss-kib "))
        .and_then(|v| v.trim().parse::<f64>().ok())
        .map_or(f64::NAN, |k| k / 1024.0);
    let work = err
        .lines()
        .find_map(|l| l.split_once("gpu backend: "))
        .and_then(|(_, w)| PerFrame::parse(w));
    Ok((secs, peak, work))
}

/// Runs the benchmark; progress on stderr, the report returned.
pub fn run(s: &Settings) -> Result<String> {
    std::fs::create_dir_all(&s.dir).map_err(|e| Error::io(&s.dir, e))?;
    let name = format!("1080p30-{}s.mp4", s.seconds);
    let mut clips = vec![clip(&s.dir, &name, 1920, 1080, 30, s.seconds)?];
    for &m in &s.k4_minutes {
        let name = format!("2160p{}-{m}min.mp4", s.k4_fps);
        clips.push(clip(&s.dir, &name, 3840, 2160, s.k4_fps, m * 60)?);
    }
    let flags = match s.select_args.is_empty() {
        true => DEFAULT_ANALYSIS.iter().map(|f| f.to_string()).collect(),
        false => s.select_args.clone(),
    };
    let mut report = format!(
        "pipeline: full analysis = `select {}` as a child process; decode-only = ffmpeg -f null \
         and keyframer's OpenCV read loop (decode + BGR); {} round(s) per clip, each timing the \
         decode loops, then every backend: medians, ratios per round (median and range); device \
         work per analysed frame as the gpu backend counts it (budget: at most 1 KiB read back \
         and 1/16 blocking wait)\n",
        flags.join(" "),
        s.rounds
    );
    report += &format!(
        "{:<24} {:>6} {:>9} {:>9} {:>14} {:>9} {:>9} {:>11} {:>9} {:>9}{}\n",
        "clip",
        "frames",
        "ffmpeg s",
        "opencv s",
        "backend",
        "analyse s",
        "/opencv",
        "range",
        "/ffmpeg",
        "peak MiB",
        PerFrame::HEADER
    );
    for path in &clips {
        let name = path.file_name().unwrap_or_default().to_string_lossy();
        // Per backend, one entry per round.
        let mut runs: Vec<Vec<Round>> = vec![Vec::new(); s.backends.len()];
        // Peak memory: the largest over the rounds; the device counters: the last round's.
        let mut peaks = vec![f64::NAN; s.backends.len()];
        let mut works: Vec<Option<PerFrame>> = s.backends.iter().map(|_| None).collect();
        let (mut ffs, mut cvs, mut frames) = (Vec::new(), Vec::new(), 0);
        for round in 1..=s.rounds {
            eprintln!("bench: decoding {name} (round {round} of {})", s.rounds);
            let ff = ffmpeg_decode(path);
            let (cv, n) = opencv_decode(path)?;
            frames = n;
            ffs.extend(ff);
            cvs.push(cv);
            for (k, b) in s.backends.iter().enumerate() {
                eprintln!("bench: analysing {name} with {b}");
                let project = s.dir.join(format!("{name}.{b}.json"));
                // `NAME-preview`: the keyframe-only preview (`select --preview`) on backend NAME.
                let (backend, flags) = match b.strip_suffix("-preview") {
                    Some(base) => (base, [&flags[..], &["--preview".to_string()]].concat()),
                    None => (b.as_str(), flags.clone()),
                };
                let (secs, peak, work) = analysis(path, &project, backend, &flags)?;
                runs[k].push(Round {
                    secs,
                    to_opencv: secs / cv,
                    to_ffmpeg: ff.map(|f| secs / f),
                });
                (peaks[k], works[k]) = (peaks[k].max(peak), work);
            }
        }
        for (k, b) in s.backends.iter().enumerate() {
            let secs: Vec<f64> = runs[k].iter().map(|r| r.secs).collect();
            let ratios: Vec<f64> = runs[k].iter().map(|r| r.to_opencv).collect();
            let to_ff: Vec<f64> = runs[k].iter().filter_map(|r| r.to_ffmpeg).collect();
            report += &format!(
                "{:<24} {:>6} {:>9} {:>9.1} {:>14} {:>9.1} {:>9.2} {:>11} {:>9} {:>9.0}{}\n",
                name,
                frames,
                median_or_dash(&ffs, 1),
                median(&cvs),
                b,
                median(&secs),
                median(&ratios),
                range(&ratios),
                median_or_dash(&to_ff, 2),
                peaks[k],
                works[k].as_ref().map_or(
                    format!(" {:>7} {:>9} {:>9} {:>8}", "-", "-", "-", "-"),
                    |w| w.columns()
                )
            );
        }
    }
    if s.tradeoffs {
        report += &tradeoffs(s)?;
    }
    Ok(report)
}

fn movement(project: &Path) -> Result<(Vec<f64>, Vec<usize>)> {
    let p = crate::project::Project::load(project)?;
    let values = p
        .cache
        .movement
        .first()
        .map(|m| m.series.values.clone())
        .unwrap_or_default();
    Ok((values, p.keyframes))
}

/// Analysis width and flow stride against the reference (640, 1): time, movement per second
/// (relative difference, median and P90 over the clip's seconds) and the spacing selection.
fn tradeoffs(s: &Settings) -> Result<String> {
    let clip = clip(&s.dir, "1080p30-20s.mp4", 1920, 1080, 30, 20)?;
    let settings = [
        (640, 1),
        (640, 2),
        (640, 3),
        (320, 1),
        (320, 2),
        (320, 3),
        (320, 5),
    ];
    let mut out = String::from(
        "\ntrade-offs on 1080p30-20s.mp4 (opencv backend, `select --spacing 200` movement only; \
         reference width 640 stride 1)\n",
    );
    out += &format!(
        "{:>6} {:>6} {:>9} {:>12} {:>10} {:>10} {:>14}\n",
        "width", "stride", "analyse s", "movement/s", "P90", "keyframes", "mean |shift|"
    );
    let exe = std::env::current_exe().map_err(|e| Error::param("keyframer", e.to_string()))?;
    let mut reference: Option<(Vec<f64>, Vec<usize>)> = None;
    for (w, k) in settings {
        let project = s.dir.join(format!("tradeoff-{w}-{k}.json"));
        let _ = std::fs::remove_file(&project);
        eprintln!("bench: trade-off width {w} stride {k}");
        let t = Instant::now();
        run_tool(
            Command::new(&exe)
                .arg("select")
                .arg(&clip)
                .args(["--spacing", "200", "--backend", "opencv", "--quiet"])
                .args(["--analysis-width", &w.to_string()])
                .args(["--flow-stride", &k.to_string()])
                .args(["--checkpoint-every", "0", "-o"])
                .arg(&project),
            "keyframer select (trade-off)",
        )?;
        let secs = t.elapsed().as_secs_f64();
        let (values, keys) = movement(&project)?;
        let (rel, p90, shift) = match &reference {
            None => (0.0, 0.0, 0.0),
            Some((rv, rk)) => {
                let per_sec =
                    |v: &[f64]| -> Vec<f64> { v.chunks(30).map(|c| c.iter().sum()).collect() };
                let (a, b) = (per_sec(rv), per_sec(&values));
                let mut d: Vec<f64> = a
                    .iter()
                    .zip(&b)
                    .filter(|(x, _)| **x > 1.0)
                    .map(|(x, y)| (y - x).abs() / x)
                    .collect();
                d.sort_by(f64::total_cmp);
                let q = |p: f64| {
                    d.get(((d.len() as f64 - 1.0) * p).round() as usize)
                        .copied()
                };
                let shift = keys
                    .iter()
                    .map(|&k| rk.iter().map(|&r| r.abs_diff(k)).min().unwrap_or(0) as f64)
                    .sum::<f64>()
                    / keys.len().max(1) as f64;
                (q(0.5).unwrap_or(0.0), q(0.9).unwrap_or(0.0), shift)
            }
        };
        out += &format!(
            "{w:>6} {k:>6} {secs:>9.1} {rel:>12.3} {p90:>10.3} {:>10} {shift:>14.2}\n",
            keys.len()
        );
        if reference.is_none() {
            reference = Some((values, keys));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::{median, median_or_dash, range};

    #[test]
    fn medians_and_ranges_of_rounds() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert!(median(&[]).is_nan());
        assert_eq!(median_or_dash(&[1.234, 1.0, 9.0], 2), "1.23");
        assert_eq!(median_or_dash(&[], 2), "-");
        assert_eq!(range(&[1.5, 1.25, 1.75]), "1.25-1.75");
        assert_eq!(range(&[]), "-");
    }
}
