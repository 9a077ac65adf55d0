//! `select`: one analysis pass over the input for the frame count, timestamps and the scores the
//! samplers need (or none, when a project for the same unchanged input already caches them), then
//! the samplers in a fixed chain: boundaries → every-nth | fps → blur → manual add/remove.
//! Writes the project file atomically.

use crate::analysis::{self, Request};
use crate::error::{Error, Result};
use crate::fsutil::{self, Fingerprint};
use crate::gpu::{self, Backend};
use crate::project::{Cache, InputRef, Project, SharpnessSeries, Step, SCHEMA_VERSION};
use crate::samplers::{self, BlurParams, Boundaries};
use crate::source::{self, OpenOptions, SourceKind};
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
    /// Blur sampler, if any (runs after the rate sampler).
    pub blur: Option<BlurParams>,
    /// Kernel backend for the analysis.
    pub backend: Backend,
    /// GPU adapter choice (part of its name).
    pub adapter: Option<String>,
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
    let metrics: Vec<_> = s.blur.iter().map(|b| b.metric).collect();
    let mut decoded = false;
    let (cached_meta, mut cache, mut problems) = match reusable {
        Some(p) => (Some(p.metadata), p.cache, p.decode_problems),
        None => (None, Cache::default(), Vec::new()),
    };
    let missing: Vec<_> = match &cached_meta {
        Some(m) => metrics
            .iter()
            .copied()
            .filter(|&k| cache.sharpness(k, m.width, m.height).is_none())
            .collect(),
        None => metrics.clone(),
    };
    let metadata = match cached_meta {
        Some(m) if missing.is_empty() => {
            log::info!(
                "reusing the frame data cached in {} (input unchanged; nothing decoded)",
                s.output.display()
            );
            m
        }
        cached => {
            let (backend, ctx) = if missing.is_empty() {
                (Backend::Opencv, None)
            } else {
                gpu::resolve_backend(s.backend, s.adapter.as_deref())
            };
            let a = analysis::analyse(
                &s.input,
                &OpenOptions {
                    images_fps: s.images_fps,
                },
                &Request { sharpness: missing },
                backend,
                ctx.as_ref(),
                s.quiet,
            )?;
            if cached.is_some_and(|m| m.frame_count != a.metadata.frame_count) {
                log::warn!(
                    "the input decodes to a different frame count than cached; cache replaced"
                );
                cache = Cache::default();
            }
            for (metric, scores) in a.sharpness {
                cache.sharpness.push(SharpnessSeries {
                    metric,
                    width: a.metadata.width,
                    height: a.metadata.height,
                    backend: a.backend,
                    scores,
                });
            }
            if cache.timestamps_s.is_none() {
                cache.timestamps_s = a.timestamps_s;
            }
            problems = a.problems;
            decoded = true;
            a.metadata
        }
    };

    let mut history = Vec::new();
    let ts = cache.timestamps_s.as_deref();
    let range = s.boundaries.candidates(metadata.frame_count, ts)?;
    let mut keys = range.clone();
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
    if let Some(b) = &s.blur {
        let series = cache
            .sharpness(b.metric, metadata.width, metadata.height)
            .ok_or_else(|| Error::Plugin {
                plugin: "blur",
                msg: format!("no {} scores were computed", b.metric),
            })?;
        let lo = range.first().copied().unwrap_or(0);
        let hi = range.last().copied().unwrap_or(0);
        keys = samplers::blur(&keys, &series.scores, b, lo, hi)?;
        history.push(Step {
            plugin: "blur".into(),
            params: json!({
                "metric": b.metric, "window": b.window, "ratio": b.ratio, "mode": b.mode,
                "backend": series.backend,
            }),
            kept: keys.len(),
        });
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
