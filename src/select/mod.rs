//! `select`: one analysis pass over the input for the frame count, timestamps and the scores the
//! samplers need (or none, when a project for the same unchanged input already caches them), then
//! the samplers in a fixed chain: boundaries → every-nth | fps → blur → manual add/remove.
//! Writes the project file atomically.

pub mod preview;

use crate::analysis::{self, MovementRequest, Request, StationaryRequest};
use crate::error::{Error, Result};
use crate::fsutil::{self, Fingerprint};
use crate::gpu::{self, Backend};
use crate::project::{
    Cache, HistoryEntry, InputRef, MovementCache, Project, SharpnessSeries, StationaryCache,
    SCHEMA_VERSION,
};
use crate::samplers::{self, Boundaries};
use crate::source::{self, OpenOptions, SourceKind};
use crate::steps::{Applied, Step};
use std::path::{Path, PathBuf};

pub use crate::steps::Threshold;

/// Stationary sampler settings with `auto` resolved (the threshold defaults to 1 % of the frame
/// width).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Stationary {
    /// Movement in full-resolution pixels since the last keyframe that makes a new one.
    pub threshold: Option<f64>,
    /// Frames after which the reference frame is re-anchored.
    pub reset_delta: usize,
}

/// The stationary request for this input: threshold and candidate range resolved.
fn stationary_request(
    st: Stationary,
    b: &Boundaries,
    meta: &crate::source::Metadata,
    cache: &Cache,
) -> Result<StationaryRequest> {
    let width = Some(meta.width);
    let (first, last) = match meta.frame_count_exact {
        true => {
            let c = b.candidates(meta.frame_count, cache.timestamps_s.as_deref())?;
            (c[0], *c.last().unwrap_or(&c[0]))
        }
        false => {
            let first = match b.start {
                Some(samplers::Bound::Frame(i)) => i,
                _ => 0,
            };
            let last = match b.end {
                Some(samplers::Bound::Frame(i)) => i,
                _ => usize::MAX,
            };
            (first, last)
        }
    };
    let threshold = match (st.threshold, width) {
        (Some(t), _) => t,
        (None, Some(w)) => f64::from(w) * 0.01,
        (None, None) => {
            return Err(Error::Plugin {
                plugin: "stationary",
                msg: "give --stationary-threshold for an input whose size is not known yet".into(),
            })
        }
    };
    if !(threshold.is_finite() && threshold > 0.0) {
        return Err(Error::Plugin {
            plugin: "stationary",
            msg: format!("threshold must be a positive number of pixels, got {threshold}"),
        });
    }
    if st.reset_delta == 0 {
        return Err(Error::Plugin {
            plugin: "stationary",
            msg: "reset delta must be at least 1 frame".into(),
        });
    }
    Ok(StationaryRequest {
        threshold,
        reset_delta: st.reset_delta,
        first,
        last,
    })
}

/// Validated settings of one `select` run.
#[derive(Debug, Clone)]
pub struct SelectSettings {
    /// Video file, image file or image folder.
    pub input: PathBuf,
    /// Project file to write.
    pub output: PathBuf,
    /// The sampler chain, in keyframer's order (see [`crate::steps::check_order`]).
    pub steps: Vec<Step>,
    /// How movement is measured for the stationary and spacing samplers.
    pub movement: MovementRequest,
    /// Kernel backend for the analysis.
    pub backend: Backend,
    /// GPU adapter choice (part of its name).
    pub adapter: Option<String>,
    /// Frame rate to assume for image folders.
    pub images_fps: Option<f64>,
    /// Replace an existing project file.
    pub force: bool,
    /// Seconds between analysis checkpoints (0: none).
    pub checkpoint_every_s: f64,
    /// Analyse only the codec's keyframes (a quick, coarse preview; see [`preview`]).
    pub preview: bool,
    /// No progress bars.
    pub quiet: bool,
}

impl SelectSettings {
    /// Seconds between checkpoints of a running analysis unless told otherwise.
    pub const CHECKPOINT_EVERY_S: f64 = 15.0;

    /// Settings for a workflow's `select` on `input`, writing `project` (replaced: `run` owns
    /// its folders).
    pub fn from_workflow(
        w: &crate::workflow::Workflow,
        input: &Path,
        project: &Path,
        quiet: bool,
    ) -> SelectSettings {
        let an = w.file.analysis.clone().unwrap_or_default();
        SelectSettings {
            input: input.to_path_buf(),
            output: project.to_path_buf(),
            steps: w.file.sample.clone(),
            movement: w.movement(),
            backend: w.backend(),
            adapter: an.adapter,
            images_fps: an.images_fps,
            force: true,
            checkpoint_every_s: Self::CHECKPOINT_EVERY_S,
            preview: an.preview == Some(true),
            quiet,
        }
    }

    /// The part of the input to sample.
    pub fn boundaries(&self) -> Boundaries {
        crate::steps::boundaries(&self.steps)
    }

    /// The stationary step: threshold as given and reset delta.
    fn stationary(&self) -> Option<(Option<Threshold>, usize)> {
        self.steps.iter().find_map(|s| match s {
            Step::Stationary {
                threshold,
                reset_delta,
            } => Some((
                *threshold,
                reset_delta.unwrap_or(crate::steps::defaults::RESET_DELTA),
            )),
            _ => None,
        })
    }

    /// The spacing step's threshold as given.
    fn spacing(&self) -> Option<Threshold> {
        self.steps.iter().find_map(|s| match s {
            Step::Spacing { threshold } => Some(*threshold),
            _ => None,
        })
    }
}

/// What `select` did.
#[derive(Debug)]
pub struct SelectReport {
    /// The project as written.
    pub project: Project,
    /// Whether the input was decoded (false when the cache of an existing project was reused).
    pub decoded: bool,
    /// Explanations of thresholds proposed by `--auto`.
    pub proposals: Vec<String>,
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

/// The output rule for `select`: the project file and its checkpoint are regular files (or
/// missing), not the input nor inside it; an existing project needs `--force`.
pub(crate) fn check_outputs(s: &SelectSettings) -> Result<()> {
    crate::output::check_file(&s.output, "-o", s.force, &[&s.input])?;
    let checkpoint = checkpoint_path(&s.output);
    crate::output::check_file(&checkpoint, "-o", true, &[&s.input])?;
    // The checkpoint is replaced and removed without --force only when it is keyframer's own.
    if checkpoint.exists() && !s.force && !crate::analysis::is_checkpoint(&checkpoint) {
        return Err(Error::Output {
            path: checkpoint,
            msg: "exists and is not a keyframer checkpoint; pass --force to replace it".into(),
        });
    }
    Ok(())
}

/// The checkpoint file of a running analysis for the project `output`: `output` + `.partial`.
pub fn checkpoint_path(output: &Path) -> PathBuf {
    let mut name = output.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    output.with_file_name(name)
}

/// Runs `select` and writes the project file.
pub fn select(s: &SelectSettings) -> Result<SelectReport> {
    if s.preview {
        return preview::select_preview(s);
    }
    let report = build(
        s,
        &OpenOptions {
            images_fps: s.images_fps,
            codec_keyframes: None,
        },
    )?;
    report.project.save(&s.output, true)?;
    let checkpoint = checkpoint_path(&s.output);
    if checkpoint.is_file() {
        if let Err(e) = std::fs::remove_file(&checkpoint) {
            log::warn!(
                "{}: could not remove the checkpoint: {e}",
                checkpoint.display()
            );
        }
    }
    Ok(report)
}

/// The manual step of `steps` (frames added and removed by index), when there is one.
pub(crate) fn manual_step(
    keys: &mut Vec<usize>,
    history: &mut Vec<HistoryEntry>,
    steps: &[Step],
    frame_count: usize,
) -> Result<()> {
    for step in steps {
        if let Step::Manual { add, remove } = step {
            *keys = samplers::manual(keys, add, remove, frame_count)?;
            let applied = Applied::Manual {
                add: add.clone(),
                remove: remove.clone(),
            };
            history.push(applied.entry(keys.len()));
        }
    }
    Ok(())
}

/// Analyses (or reuses the cache) and runs the sampler chain; returns the project unsaved. A
/// keyframe-only source (`open.keyframes`) never reuses or checkpoints a cache.
pub(crate) fn build(s: &SelectSettings, open: &OpenOptions) -> Result<SelectReport> {
    let full = open.codec_keyframes.is_none();
    let (kind, fingerprint) = identify(&s.input)?;
    check_outputs(s)?;
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
        .filter(|p| full && !p.preview && p.input == input_ref);
    let metrics: Vec<_> = s
        .steps
        .iter()
        .filter_map(|b| b.blur_params())
        .map(|b| b.metric)
        .collect();
    let boundaries = s.boundaries();
    let mut decoded = false;
    let (mut cached_meta, mut cache, mut problems, mut damaged) = match reusable {
        Some(p) => (
            Some(p.metadata),
            p.cache,
            p.decode_problems,
            p.damaged_frames,
        ),
        None => (None, Cache::default(), Vec::new(), Vec::new()),
    };
    let uses_seconds = [boundaries.start, boundaries.end]
        .iter()
        .any(|b| matches!(b, Some(samplers::Bound::Seconds(_))));
    if s.stationary().is_some() && cached_meta.is_none() && uses_seconds {
        // The stationary sampler runs during decoding and needs its frame range first.
        let a = analysis::analyse(
            &s.input,
            open,
            &Request::default(),
            Backend::Opencv,
            None,
            s.quiet,
        )?;
        cache.timestamps_s = a.timestamps_s;
        problems = a.problems;
        damaged = a.damaged;
        cached_meta = Some(a.metadata);
        decoded = true;
    }
    let mut proposals = Vec::new();
    let wants_auto_stationary = matches!(s.stationary(), Some((Some(Threshold::Auto), _)));
    let mut stationary_setting = s.stationary().map(|(t, reset_delta)| Stationary {
        threshold: match t {
            Some(Threshold::Px(v)) => Some(v),
            _ => None,
        },
        reset_delta,
    });
    let mut spacing = match s.spacing() {
        Some(Threshold::Px(v)) => Some(v),
        _ => None,
    };
    if wants_auto_stationary || s.spacing() == Some(Threshold::Auto) {
        let (backend, ctx) = gpu::resolve_backend(s.backend, s.adapter.as_deref());
        let sample =
            analysis::sample_movement(&s.input, open, s.movement, 40, backend, ctx.as_ref())?;
        let meta = match &cached_meta {
            Some(m) => m.clone(),
            None => source::open(&s.input, open)?.metadata().clone(),
        };
        if wants_auto_stationary {
            let p = samplers::auto::stationary_threshold(&sample);
            if let Some(st) = stationary_setting.as_mut() {
                st.threshold = Some(p.threshold);
            }
            proposals.push(format!("stationary --auto: {}", p.explanation));
        }
        if s.spacing() == Some(Threshold::Auto) {
            let p = samplers::auto::spacing_threshold(&sample, meta.width, meta.frame_count);
            spacing = Some(p.threshold);
            proposals.push(format!("spacing auto: {}", p.explanation));
        }
    }
    let stationary_req = match stationary_setting {
        Some(st) => {
            let meta = match &cached_meta {
                Some(m) => m.clone(),
                None => source::open(&s.input, open)?.metadata().clone(),
            };
            Some(stationary_request(st, &boundaries, &meta, &cache)?)
        }
        None => None,
    };
    let missing: Vec<_> = match &cached_meta {
        Some(m) => metrics
            .iter()
            .copied()
            .filter(|&k| cache.sharpness(k, m.width, m.height).is_none())
            .collect(),
        None => metrics.clone(),
    };
    let need_series = s.spacing().is_some() && cache.movement(&s.movement).is_none();
    let need_stationary =
        stationary_req.is_some_and(|st| cache.stationary(&s.movement, &st).is_none());
    let complete = missing.is_empty() && !need_series && !need_stationary;
    let metadata = match cached_meta {
        Some(m) if complete => {
            if !decoded {
                log::info!(
                    "reusing the frame data cached in {} (input unchanged; nothing decoded)",
                    s.output.display()
                );
            }
            m
        }
        cached => {
            let wants_pixels = !missing.is_empty() || need_series || need_stationary;
            let (backend, ctx) = if wants_pixels {
                gpu::resolve_backend(s.backend, s.adapter.as_deref())
            } else {
                (Backend::Opencv, None)
            };
            let resume = analysis::Resume {
                path: checkpoint_path(&s.output),
                fingerprint: input_ref.fingerprint.clone(),
                every_s: s.checkpoint_every_s,
            };
            let a = analysis::analyse_with(
                &s.input,
                open,
                &Request {
                    sharpness: missing,
                    movement: (need_series || need_stationary).then_some(s.movement),
                    stationary: if need_stationary {
                        stationary_req
                    } else {
                        None
                    },
                },
                backend,
                ctx.as_ref(),
                s.quiet,
                full.then_some(&resume),
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
            if let Some(series) = a.movement {
                cache.movement.retain(|m| m.request != s.movement);
                cache.movement.push(MovementCache {
                    request: s.movement,
                    backend: a.backend,
                    series,
                });
            }
            if let (Some(keys), Some(mut st)) = (a.stationary, stationary_req) {
                st.last = st.last.min(a.metadata.frame_count.saturating_sub(1));
                cache.stationary.push(StationaryCache {
                    request: s.movement,
                    params: st,
                    backend: a.backend,
                    keyframes: keys,
                });
            }
            if cache.timestamps_s.is_none() {
                cache.timestamps_s = a.timestamps_s;
            }
            problems = a.problems;
            damaged = a.damaged;
            decoded = true;
            a.metadata
        }
    };

    let chain = Chain {
        s,
        cache: &cache,
        metadata: &metadata,
        stationary: stationary_setting,
        spacing,
        auto_stationary: wants_auto_stationary,
    };
    let (mut keys, history) = chain.apply(&damaged)?;
    let before = keys.len();
    keys.retain(|k| damaged.binary_search(k).is_err());
    if keys.len() < before {
        log::warn!(
            "{}: {} damaged frame(s) dropped from the keyframes (moved there by blur replace or --add)",
            s.input.display(),
            before - keys.len()
        );
    }

    let project = Project {
        schema_version: SCHEMA_VERSION,
        tool_version: env!("CARGO_PKG_VERSION").into(),
        input: input_ref,
        metadata,
        boundaries,
        keyframes: keys,
        history,
        cache,
        decode_problems: problems,
        damaged_frames: damaged,
        preview: false,
    };
    Ok(SelectReport {
        project,
        decoded,
        proposals,
    })
}

/// The sampler chain over the analysed (or cached) input: `select`'s interpreter of its steps.
struct Chain<'a> {
    s: &'a SelectSettings,
    cache: &'a Cache,
    metadata: &'a crate::source::Metadata,
    /// The stationary step with `auto` resolved.
    stationary: Option<Stationary>,
    /// The spacing threshold in pixels when known before the chain runs (given, or `auto`).
    spacing: Option<f64>,
    auto_stationary: bool,
}

impl Chain<'_> {
    /// Runs every step in order on the candidates (damaged frames never are); returns the
    /// keyframes and the history.
    fn apply(&self, damaged: &[usize]) -> Result<(Vec<usize>, Vec<HistoryEntry>)> {
        let boundaries = self.s.boundaries();
        let ts = self.cache.timestamps_s.as_deref();
        let range = boundaries.candidates(self.metadata.frame_count, ts)?;
        let mut keys = range.clone();
        keys.retain(|k| damaged.binary_search(k).is_err());
        let mut history = vec![Applied::Boundaries {
            end: boundaries.end,
            start: boundaries.start,
        }
        .entry(keys.len())];
        let lo = range.first().copied().unwrap_or(0);
        let hi = range.last().copied().unwrap_or(0);
        for step in &self.s.steps {
            let applied = match step {
                Step::Boundaries { .. } | Step::Manual { .. } => continue,
                Step::Stationary { .. } => self.stationary(&mut keys, &boundaries)?,
                Step::Spacing { threshold } => self.spacing(&mut keys, *threshold)?,
                Step::EveryNth { n } => {
                    keys = samplers::every_nth(&keys, *n)?;
                    Applied::EveryNth { n: *n }
                }
                Step::Fps { fps } => {
                    let ts = ts.ok_or_else(|| Error::Plugin {
                        plugin: "fps",
                        msg: "the input has no timestamps (an image folder: give its rate with --images-fps)"
                            .into(),
                    })?;
                    keys = samplers::fps(&keys, ts, *fps)?;
                    Applied::Fps { fps: *fps }
                }
                Step::Blur { .. } => self.blur(&mut keys, step, lo, hi)?,
            };
            history.push(applied.entry(keys.len()));
        }
        manual_step(
            &mut keys,
            &mut history,
            &self.s.steps,
            self.metadata.frame_count,
        )?;
        Ok((keys, history))
    }

    fn stationary(&self, keys: &mut Vec<usize>, boundaries: &Boundaries) -> Result<Applied> {
        let st = self.stationary.ok_or_else(|| Error::Plugin {
            plugin: "stationary",
            msg: "no threshold".into(),
        })?;
        let req = stationary_request(st, boundaries, self.metadata, self.cache)?;
        let run = self
            .cache
            .stationary(&self.s.movement, &req)
            .ok_or_else(|| Error::Plugin {
                plugin: "stationary",
                msg: "no stationary run was computed".into(),
            })?;
        keys.retain(|k| run.keyframes.binary_search(k).is_ok());
        Ok(Applied::Stationary {
            auto: self.auto_stationary,
            backend: Some(run.backend),
            movement: Some(self.s.movement),
            reset_delta: Some(req.reset_delta),
            threshold_px: Some(req.threshold),
        })
    }

    fn spacing(&self, keys: &mut Vec<usize>, given: Threshold) -> Result<Applied> {
        let series = self
            .cache
            .movement(&self.s.movement)
            .ok_or_else(|| Error::Plugin {
                plugin: "spacing",
                msg: "no movement was computed".into(),
            })?;
        let threshold = match (given, self.spacing) {
            (Threshold::Count(n), _) => {
                let t = samplers::spacing_for_count(keys, &series.series.values, n)?;
                log::info!("spacing {n}kf: threshold {t:.2} px");
                t
            }
            (_, Some(t)) => t,
            _ => {
                return Err(Error::Plugin {
                    plugin: "spacing",
                    msg: "no threshold".into(),
                })
            }
        };
        *keys = samplers::spacing(keys, &series.series.values, threshold)?;
        Ok(Applied::Spacing {
            auto: given == Threshold::Auto,
            backend: Some(series.backend),
            count: match given {
                Threshold::Count(n) => Some(n),
                _ => None,
            },
            movement: Some(self.s.movement),
            threshold_px: threshold,
        })
    }

    fn blur(&self, keys: &mut Vec<usize>, step: &Step, lo: usize, hi: usize) -> Result<Applied> {
        let b = step.blur_params().ok_or_else(|| Error::Plugin {
            plugin: "blur",
            msg: "not a blur step".into(),
        })?;
        let series = self
            .cache
            .sharpness(b.metric, self.metadata.width, self.metadata.height)
            .ok_or_else(|| Error::Plugin {
                plugin: "blur",
                msg: format!("no {} scores were computed", b.metric),
            })?;
        *keys = samplers::blur(keys, &series.scores, &b, lo, hi)?;
        Ok(Applied::Blur {
            backend: Some(series.backend),
            metric: Some(b.metric),
            mode: Some(b.mode),
            ratio: Some(b.ratio),
            window: Some(b.window),
        })
    }
}
