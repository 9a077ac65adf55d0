//! `select`: one pass over the input to establish frame count and timestamps (or none, when a
//! project for the same unchanged input already holds them), then the samplers in a fixed chain:
//! boundaries → every-nth | fps → manual add/remove. Writes the project file atomically.

use crate::error::{Error, Result};
use crate::fsutil::{self, Fingerprint};
use crate::project::{Cache, InputRef, Project, Step, SCHEMA_VERSION};
use crate::samplers::{self, Boundaries};
use crate::source::{self, Metadata, OpenOptions, SourceKind};
use serde_json::json;
use std::path::{Path, PathBuf};

/// The rate sampler to apply after the boundaries.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rate {
    /// Keep every Nth candidate.
    Every(usize),
    /// Resample to this many frames per second by timestamps.
    Fps(f64),
}

/// Validated settings of one `select` run.
#[derive(Debug, Clone)]
pub struct SelectSettings {
    /// Video file, image file or image folder.
    pub input: PathBuf,
    /// Project file to write.
    pub output: PathBuf,
    /// Part of the input to sample.
    pub boundaries: Boundaries,
    /// Rate sampler, if any.
    pub rate: Option<Rate>,
    /// Frames to add after sampling.
    pub add: Vec<usize>,
    /// Frames to remove after sampling.
    pub remove: Vec<usize>,
    /// Frame rate to assume for image folders.
    pub images_fps: Option<f64>,
    /// Replace an existing project file.
    pub force: bool,
    /// No progress bars.
    pub quiet: bool,
}

/// What `select` did.
#[derive(Debug)]
pub struct SelectReport {
    /// The project as written.
    pub project: Project,
    /// Whether the input was decoded (false when the cache of an existing project was reused).
    pub decoded: bool,
}

/// The input's kind and fingerprint, from the file system only.
pub fn identify(input: &Path) -> Result<(SourceKind, Fingerprint)> {
    let meta = std::fs::metadata(input).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => Error::input(input, "no such file or folder"),
        _ => Error::io(input, e),
    })?;
    if meta.is_dir() {
        let files = source::list_images(input)?;
        if files.is_empty() {
            return Err(Error::input(
                input,
                "the folder holds no images (png, jpg, jpeg, tif, tiff, bmp)",
            ));
        }
        return Ok((SourceKind::Images, fsutil::fingerprint_files(&files)?));
    }
    let kind = if crate::source::is_image_name(input) {
        SourceKind::Image
    } else {
        SourceKind::Video
    };
    Ok((kind, fsutil::fingerprint_file(input)?))
}

/// Runs `select`.
pub fn select(s: &SelectSettings) -> Result<SelectReport> {
    let (kind, fingerprint) = identify(&s.input)?;
    fsutil::check_overwrite(&s.output, s.force)?;
    let project_dir = fsutil::absolute(&s.output)
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_default();
    let input_ref = InputRef {
        path: fsutil::relative_to(&s.input, &project_dir),
        kind,
        fingerprint,
    };

    let reusable = s
        .output
        .exists()
        .then(|| Project::load(&s.output).ok())
        .flatten()
        .filter(|p| p.input == input_ref);
    let (metadata, cache, problems, decoded) = match reusable {
        Some(p) => {
            log::info!(
                "reusing the frame data cached in {} (input unchanged; nothing decoded)",
                s.output.display()
            );
            (p.metadata, p.cache, p.decode_problems, false)
        }
        None => {
            let (m, c, pr) = scan_input(&s.input, s.images_fps, s.quiet)?;
            (m, c, pr, true)
        }
    };

    let mut history = Vec::new();
    let ts = cache.timestamps_s.as_deref();
    let mut keys = s.boundaries.candidates(metadata.frame_count, ts)?;
    history.push(Step {
        plugin: "boundaries".into(),
        params: json!({ "start": s.boundaries.start, "end": s.boundaries.end }),
        kept: keys.len(),
    });
    match s.rate {
        Some(Rate::Every(n)) => {
            keys = samplers::every_nth(&keys, n)?;
            history.push(Step {
                plugin: "every-nth".into(),
                params: json!({ "n": n }),
                kept: keys.len(),
            });
        }
        Some(Rate::Fps(f)) => {
            let ts = ts.ok_or_else(|| Error::Plugin {
                plugin: "fps",
                msg:
                    "the input has no timestamps (an image folder: give its rate with --images-fps)"
                        .into(),
            })?;
            keys = samplers::fps(&keys, ts, f)?;
            history.push(Step {
                plugin: "fps".into(),
                params: json!({ "fps": f }),
                kept: keys.len(),
            });
        }
        None => {}
    }
    if !s.add.is_empty() || !s.remove.is_empty() {
        keys = samplers::manual(&keys, &s.add, &s.remove, metadata.frame_count)?;
        history.push(Step {
            plugin: "manual".into(),
            params: json!({ "add": s.add, "remove": s.remove }),
            kept: keys.len(),
        });
    }

    let project = Project {
        schema_version: SCHEMA_VERSION,
        tool_version: env!("CARGO_PKG_VERSION").into(),
        input: input_ref,
        metadata,
        boundaries: s.boundaries,
        keyframes: keys,
        history,
        cache,
        decode_problems: problems,
    };
    project.save(&s.output, true)?;
    Ok(SelectReport { project, decoded })
}

/// Decodes the whole input once: exact frame count, timestamps, and decode problems.
fn scan_input(
    input: &Path,
    images_fps: Option<f64>,
    quiet: bool,
) -> Result<(Metadata, Cache, Vec<String>)> {
    let mut src = source::open(input, &OpenOptions { images_fps })?;
    let declared = src.metadata().frame_count as u64;
    let bar = crate::progress::bar(declared, "scan", quiet);
    let scan = source::scan(src.as_mut(), |n| bar.set_position(n as u64))?;
    bar.finish_and_clear();
    let mut meta = src.metadata().clone();
    if meta.frame_count != scan.frame_count {
        if scan.failure.is_none() {
            log::info!(
                "{}: the container declares {} frames, decoding found {}",
                input.display(),
                meta.frame_count,
                scan.frame_count
            );
        }
        meta.frame_count = scan.frame_count;
    }
    meta.frame_count_exact = true;
    if let (Some(ts), Some(fps)) = (&scan.timestamps_s, meta.fps) {
        if let (Some(first), Some(last)) = (ts.first(), ts.last()) {
            meta.duration_s = Some(last - first + 1.0 / fps);
        }
    }
    let problems: Vec<String> = scan.failure.into_iter().map(|(_, m)| m).collect();
    for p in &problems {
        log::warn!("{}: {p}", input.display());
    }
    Ok((
        meta,
        Cache {
            timestamps_s: scan.timestamps_s,
        },
        problems,
    ))
}
