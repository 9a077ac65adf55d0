//! `review`: a local web app over a project's cached scores. A parameter change re-runs the steps
//! through [`select::run_steps`], the code `select` runs, on the cached series (nothing decoded);
//! a step that needs what the cache lacks ([`Step::needs`]) is left out with its refusal, and
//! named with the `select` command that would compute it when `select` can; any other refusal is
//! the answer's error. **Save** writes what `select` with the same steps would write, atomically and only
//! over the project file it loaded (unchanged since; `/api/state`, asked on a page reload, reads a
//! changed file again). Frames are decoded on demand for previews.
//! A `reconstruct` step the project records is no editable step: its frames are kept after the
//! steps' result and its record stays in the history ([`keep_recorded`]).
//! The HTTP side and its request checks are in [`http`].

pub mod bench;
pub mod http;

use crate::error::{Error, Result};
use crate::fsutil::{self, Fingerprint};
use crate::manifest::Manifest;
use crate::params::MovementRequest;
use crate::project::{Project, SCHEMA_VERSION};
use crate::report::timeline::Timeline;
use crate::select::{self, Resolved};
use crate::source::{FrameReader, FrameSize, DEFAULT_BUDGET_BYTES};
use crate::steps::{self, Recorded, Step};
use serde::Serialize;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

/// Validated settings of `keyframer review`.
#[derive(Debug, Clone)]
pub struct ReviewSettings {
    /// The project file to review (and save).
    pub project: PathBuf,
    /// An export of the project whose images, masks and overlays the page shows.
    pub export: Option<PathBuf>,
    /// Port on 127.0.0.1; None: a free one.
    pub port: Option<u16>,
}

/// An answer other than success: the HTTP status and the message (sent as `{"error": ..}` with
/// the optional step index and parameter).
#[derive(Debug, Clone, PartialEq)]
pub struct ApiError {
    /// HTTP status code.
    pub status: u16,
    /// The message.
    pub error: String,
    /// Index of the step the error is about, if any.
    pub step: Option<usize>,
    /// The step's parameter the error is about, if any.
    pub key: Option<String>,
}

/// A review answer: the value, or the HTTP error.
pub type ApiResult<T> = std::result::Result<T, ApiError>;

impl ApiError {
    /// An error with no step or parameter.
    pub fn new(status: u16, error: impl Into<String>) -> ApiError {
        ApiError {
            status,
            error: error.into(),
            step: None,
            key: None,
        }
    }

    /// A 400 about step `step` (and its parameter `key`), when known.
    fn step(step: Option<usize>, key: Option<String>, error: impl Into<String>) -> ApiError {
        ApiError {
            step,
            key,
            ..ApiError::new(400, error)
        }
    }

    /// The JSON body.
    pub fn body(&self) -> Value {
        json!({"error": self.error, "step": self.step, "key": self.key})
    }
}

impl From<Error> for ApiError {
    fn from(e: Error) -> ApiError {
        ApiError::new(500, e.to_string())
    }
}

/// The result of one step list on the cached series.
#[derive(Debug, Clone, Serialize)]
pub struct Selection {
    /// Selected frame indices.
    pub keyframes: Vec<usize>,
    /// What each step that ran did, as a project's history records it.
    pub history: Vec<Recorded>,
    /// One per step given, in order.
    pub steps_state: Vec<StepState>,
    /// The project's recorded steps kept after the given ones ([`keep_recorded`]).
    pub recorded: Vec<RecordedStep>,
}

/// A step the page shows but does not run: a `reconstruct` the project records. Its frames stay
/// in the selection whatever the editable steps do.
#[derive(Debug, Clone, Serialize)]
pub struct RecordedStep {
    /// The step's id (`reconstruct`).
    pub plugin: &'static str,
    /// The frames it added, each with the round it repairs and why.
    pub added: Vec<steps::AddedFrame>,
    /// Keyframes after it.
    pub kept: usize,
    /// What the page says about it.
    pub note: &'static str,
}

/// The page's note on a recorded `reconstruct` step.
pub const RECONSTRUCT_NOTE: &str = "recorded by `keyframer reconstruct`: its frames repair \
    breaks COLMAP found in the project's selection and stay in it whatever the steps above do \
    (a manual removal included); the page cannot run the loop again: run `keyframer reconstruct` \
    on the saved project to check the new selection, or `select` again to drop them";

/// Keeps the recorded `reconstruct` steps of `project` after the editable steps' result: their
/// frames (those the input has and that are not damaged) join `keyframes`, their records join
/// `history` as they were, so an edit or a save never loses them.
pub fn keep_recorded(
    project: &Project,
    keyframes: &mut Vec<usize>,
    history: &mut Vec<Recorded>,
) -> Vec<RecordedStep> {
    let n = project.metadata.frame_count;
    let mut out = Vec::new();
    for e in &project.history {
        if let steps::Applied::Reconstruct { added, .. } = &e.applied {
            let usable = |f: &usize| *f < n && project.damaged_frames.binary_search(f).is_err();
            keyframes.extend(added.iter().map(|a| a.frame).filter(usable));
            keyframes.sort_unstable();
            keyframes.dedup();
            history.push(Recorded::new(e.applied.clone(), keyframes.len()));
            out.push(RecordedStep {
                plugin: "reconstruct",
                added: added.clone(),
                kept: keyframes.len(),
                note: RECONSTRUCT_NOTE,
            });
        }
    }
    out
}

/// Whether a step ran, and if not, what would compute what it lacks.
#[derive(Debug, Clone, Serialize)]
pub struct StepState {
    /// The step's id (`plugin` on the page).
    #[serde(rename = "plugin")]
    pub step: &'static str,
    /// Whether it ran.
    pub enabled: bool,
    /// Frames kept after it (when it ran).
    pub kept: Option<usize>,
    /// Why it did not run.
    pub reason: Option<String>,
    /// The `select` command that computes what it lacks (None when `select` cannot: the input
    /// has no telemetry).
    pub command: Option<String>,
}

/// The project as loaded or last saved.
struct Saved {
    project: Arc<Project>,
    /// The file's fingerprint when loaded or saved: a save refuses when it changed since.
    fingerprint: Fingerprint,
    revision: u64,
}

/// Long work in progress, for the page's progress bar.
#[derive(Debug, Clone, Serialize)]
pub struct Busy {
    /// What is being done.
    pub what: String,
    /// Units done.
    pub done: usize,
    /// Units in all.
    pub total: usize,
}

/// One review session over a project file.
pub struct Review {
    path: PathBuf,
    input: PathBuf,
    export: Option<(PathBuf, Manifest)>,
    /// Movement measured when the project records none (the `select` default).
    movement: MovementRequest,
    saved: Mutex<Saved>,
    busy: Mutex<Option<Busy>>,
    /// Decodes frames on demand (opened at the first request), with its bounded JPEG cache.
    frames: Mutex<Option<FrameReader>>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Review {
    /// Loads the project (and the export's manifest); refuses a preview project's save later.
    pub fn open(s: &ReviewSettings) -> Result<Review> {
        let project = Project::load(&s.project)?;
        let fingerprint = fsutil::fingerprint_file(&s.project)?;
        let manifest = |dir: &PathBuf| Manifest::load(&dir.join(crate::manifest::MANIFEST));
        let export = (s.export.as_ref())
            .map(|dir| Ok((dir.clone(), manifest(dir)?)))
            .transpose()?;
        Ok(Review {
            input: project.input_path(&s.project),
            path: s.project.clone(),
            export,
            movement: steps::defaults::movement(),
            saved: Mutex::new(Saved {
                project: Arc::new(project),
                fingerprint,
                revision: 0,
            }),
            busy: Mutex::new(None),
            frames: Mutex::new(None),
        })
    }

    /// The project file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The project as last loaded or saved.
    pub fn project(&self) -> Arc<Project> {
        lock(&self.saved).project.clone()
    }

    /// The save count of this session.
    pub fn revision(&self) -> u64 {
        lock(&self.saved).revision
    }

    /// Sets (or clears) the work in progress shown by `/api/status`.
    pub fn set_busy(&self, busy: Option<Busy>) {
        *lock(&self.busy) = busy;
    }

    /// `/api/status`: the revision (a second tab reloads on a higher one) and the work in
    /// progress.
    pub fn status(&self) -> Value {
        json!({"revision": self.revision(), "busy": *lock(&self.busy)})
    }

    /// The project's own steps, as its history records them.
    pub fn steps_of(project: &Project) -> Vec<Step> {
        (project.history.iter())
            .filter_map(|e| e.applied.step())
            .filter(|s| {
                *s != Step::Boundaries {
                    start: None,
                    end: None,
                }
            })
            .collect()
    }

    /// The movement measurement of `project`: the one its history records, else its first cached
    /// series, else `select`'s default.
    fn movement_of(&self, project: &Project) -> MovementRequest {
        (project.history.iter())
            .find_map(|e| e.applied.analysis().1)
            .or_else(|| project.cache.movement.first().map(|m| m.request))
            .unwrap_or(self.movement)
    }

    /// The thresholds of `steps` on `project`, `auto` taken from what its history recorded.
    fn resolve(&self, project: &Project, steps: &[Step]) -> Resolved {
        let movement = self.movement_of(project);
        let mut r = Resolved::given(steps, movement);
        let backend = project.cache.movement(&movement).map(|m| m.backend);
        let recorded = |step| {
            backend.and_then(|b| select::recorded_auto(&project.history, step, &movement, b))
        };
        if r.stationary_auto {
            if let Some(st) = r.stationary.as_mut() {
                st.threshold = recorded("stationary");
            }
        }
        if steps.contains(&Step::Spacing {
            threshold: steps::Threshold::Auto,
        }) {
            r.spacing_px = recorded("spacing");
        }
        r
    }

    /// Runs `steps` on the cached series of the loaded project. A step that needs what the
    /// cache lacks is left out with its refusal (and the command that computes what it lacks,
    /// when `select` can); any other refusal is the error.
    pub fn select(&self, steps: &[Step]) -> ApiResult<Selection> {
        check(steps)?;
        let project = self.project();
        let (meta, cache) = (&project.metadata, &project.cache);
        let refused = |e: Error| {
            let at = match &e {
                Error::Step { step, .. } => steps.iter().position(|s| s.id() == *step),
                _ => None,
            };
            ApiError::step(at, None, e.to_string())
        };
        let lacking =
            select::lacking(steps, &self.resolve(&project, steps), cache, meta).map_err(refused)?;
        let lacks = |step: &str| {
            let mut all = steps.iter().zip(&lacking);
            all.find(|(s, _)| s.id() == step).map(|(_, l)| l)
        };
        let mut active: Vec<Step> = steps.to_vec();
        // Each step left out: its id, its refusal, whether `select` computes what it lacks.
        let mut disabled: Vec<(&'static str, String, bool)> = Vec::new();
        let (mut keyframes, mut history) = loop {
            let resolved = self.resolve(&project, &active);
            let damaged = &project.damaged_frames;
            match select::run_steps(&self.input, &active, &resolved, cache, meta, damaged) {
                Ok(done) => break done,
                Err(Error::Step { step, msg }) if lacks(step).is_some_and(|l| !l.is_empty()) => {
                    let measured =
                        lacks(step).is_some_and(|l| l.iter().all(|n| n.measured_by_select()));
                    active.retain(|s| s.id() != step);
                    disabled.push((step, msg, measured));
                }
                Err(e) => return Err(refused(e)),
            }
        };
        let command = self.command(&project, steps);
        let kept = |s: &Step| match s {
            Step::Boundaries { .. } => history.first().map(|e| e.kept),
            s => (history.iter().skip(1))
                .find(|e| e.applied.id() == s.id())
                .map(|e| e.kept),
        };
        let steps_state = (steps.iter())
            .map(|s| {
                let off = disabled.iter().find(|d| d.0 == s.id());
                StepState {
                    step: s.id(),
                    enabled: off.is_none(),
                    kept: kept(s),
                    reason: off.map(|d| d.1.clone()),
                    command: off.filter(|d| d.2).map(|_| command.clone()),
                }
            })
            .collect();
        let recorded = keep_recorded(&project, &mut keyframes, &mut history);
        Ok(Selection {
            keyframes,
            history,
            steps_state,
            recorded,
        })
    }

    /// The `select` command that computes the analysis `steps` need and selects with them.
    fn command(&self, project: &Project, steps: &[Step]) -> String {
        let mut words = vec![
            "keyframer".to_string(),
            "select".into(),
            quote(&self.input.display().to_string()),
            "-o".into(),
            quote(&self.path.display().to_string()),
            "--force".into(),
        ];
        words.extend(steps.iter().flat_map(|s| s.to_flags()));
        let mut movement = self.movement_of(project).to_flags();
        // `--hfov` is one flag for derotation and the footprint: given once.
        if let Some(i) = (words.iter().any(|w| w == "--hfov"))
            .then(|| movement.iter().position(|w| w == "--hfov"))
            .flatten()
        {
            movement.drain(i..i + 2);
        }
        words.extend(movement);
        words.join(" ")
    }

    /// `/api/apply`: the selection of `steps` and its timeline showing frames `view` (all when
    /// None), with the time the server took.
    pub fn apply(&self, steps: &[Step], view: Option<(usize, usize)>) -> ApiResult<Value> {
        let started = Instant::now();
        let selection = self.select(steps)?;
        let project = self.project();
        let last = project.metadata.frame_count.saturating_sub(1);
        let (from, to) = view.unwrap_or((0, last));
        let timeline = Timeline::from_selection(&project, &selection.keyframes, &selection.history)
            .view(from, to);
        let svg = timeline.svg()?;
        let mut v =
            serde_json::to_value(&selection).map_err(|e| ApiError::new(500, e.to_string()))?;
        v["timeline_svg"] = json!(svg);
        v["layout"] = json!(timeline.layout());
        v["server_ms"] = json!(started.elapsed().as_secs_f64() * 1e3);
        Ok(v)
    }

    /// The project `select` with `steps` would write over the loaded one's cache.
    pub fn reselect(&self, steps: &[Step]) -> ApiResult<Project> {
        let selection = self.select(steps)?;
        if let Some(s) = selection.steps_state.iter().find(|s| !s.enabled) {
            let (step, reason) = (s.step, s.reason.as_deref().unwrap_or_default());
            let msg = match &s.command {
                Some(c) => format!("`{step}` needs analysis the project lacks; run: {c}"),
                None => format!("`{step}` cannot run on this project: {reason}"),
            };
            return Err(ApiError::new(409, msg));
        }
        let mut p = (*self.project()).clone();
        p.schema_version = SCHEMA_VERSION;
        p.tool_version = env!("CARGO_PKG_VERSION").into();
        p.boundaries = steps::boundaries(steps);
        p.keyframes = selection.keyframes;
        p.history = selection.history;
        Ok(p)
    }

    /// Saves the project `select` with `steps` would write, if the file is still the one loaded
    /// (or last saved) and `revision` is the session's; returns the new revision.
    pub fn save(&self, steps: &[Step], revision: u64) -> ApiResult<u64> {
        let project = self.reselect(steps)?;
        if self.project().preview {
            let msg = "a preview project is never saved from review; run select without --preview";
            return Err(ApiError::new(409, msg));
        }
        if self.input.exists() {
            let same =
                select::identify(&self.input).is_ok_and(|(_, f)| f == project.input.fingerprint);
            if !same {
                return Err(ApiError::new(
                    409,
                    format!(
                        "{} changed since the project was made: its cached scores are not the \
                         input's; run select again",
                        self.input.display()
                    ),
                ));
            }
        }
        let mut saved = lock(&self.saved);
        // Under the project file's lock: a `select` writing it now makes this save a conflict.
        let _held = crate::output::check_file(&self.path, true, &self.inputs())
            .map_err(|e| ApiError::new(409, e.to_string()))?;
        let now = fsutil::fingerprint_file(&self.path).ok();
        if saved.revision != revision || now.as_ref() != Some(&saved.fingerprint) {
            return Err(ApiError::new(
                409,
                format!(
                    "{} changed since this page loaded it (saved elsewhere or by another tab); \
                     reload the page: it reads the file again (edits not saved are lost)",
                    self.path.display()
                ),
            ));
        }
        select::write(&project, &self.path)?;
        saved.fingerprint = fsutil::fingerprint_file(&self.path)?;
        saved.project = Arc::new(project);
        saved.revision += 1;
        Ok(saved.revision)
    }

    /// What a save reads besides the project it replaces: the project's input and the export.
    fn inputs(&self) -> crate::output::Inputs {
        let mut inputs = crate::output::Inputs::none().with("the project's input", &self.input);
        if let Some((dir, _)) = &self.export {
            crate::manifest::add_export(&mut inputs, dir);
        }
        inputs
    }

    /// Writes the workflow of `steps` beside the project (`<stem>.workflow.toml`), refusing to
    /// replace one unless `force`.
    pub fn save_workflow(&self, steps: &[Step], force: bool) -> ApiResult<PathBuf> {
        let project = self.reselect(steps)?;
        let stem = self.path.file_stem().unwrap_or_default().to_string_lossy();
        let out = self.path.with_file_name(format!("{stem}.workflow.toml"));
        let exports: Vec<PathBuf> = self.export.iter().map(|e| e.0.clone()).collect();
        crate::workflow::save_loaded(&project, &self.path, &exports, &out, force).map_err(|e| {
            match e {
                Error::Output { .. } => ApiError::new(409, e.to_string()),
                e => e.into(),
            }
        })
    }

    /// Frame `index` as a JPEG of `size`, decoded on demand (a bounded cache keeps recent ones).
    pub fn frame(&self, index: usize, size: FrameSize) -> ApiResult<Arc<Vec<u8>>> {
        let project = self.project();
        if index >= project.metadata.frame_count {
            return Err(ApiError::new(404, format!("no frame {index}")));
        }
        if project.damaged_frames.binary_search(&index).is_ok() {
            return Err(ApiError::new(404, format!("frame {index} is damaged")));
        }
        let unavailable = |e: Error| ApiError::new(503, e.to_string());
        let mut frames = lock(&self.frames);
        if frames.is_none() {
            let same =
                select::identify(&self.input).map_err(unavailable)?.1 == project.input.fingerprint;
            if !same {
                return Err(ApiError::new(
                    503,
                    format!(
                        "{} changed since the project was made",
                        self.input.display()
                    ),
                ));
            }
            let open = crate::source::OpenOptions {
                images_fps: project.metadata.fps,
                codec_keyframes: None,
            };
            let ts = project.cache.timestamps_s.clone();
            *frames = Some(
                FrameReader::open(&self.input, &open, ts, DEFAULT_BUDGET_BYTES)
                    .map_err(unavailable)?,
            );
        }
        let reader = frames
            .as_mut()
            .ok_or_else(|| ApiError::new(503, "no frame reader"))?;
        self.set_busy(Some(Busy {
            what: format!("decoding frame {index}"),
            done: 0,
            total: 1,
        }));
        let jpeg = reader.read(index, size);
        self.set_busy(None);
        jpeg.map_err(|e| ApiError::new(404, e.to_string()))
    }

    /// The export's file of `kind` (`image`, `mask`, `overlay`) for frame `index`: a regular file
    /// inside the export folder, as its manifest lists it.
    pub fn export_file(&self, kind: &str, index: usize) -> ApiResult<PathBuf> {
        let (dir, manifest) = (self.export.as_ref())
            .ok_or_else(|| ApiError::new(404, "review was started without --export"))?;
        let f = (manifest.frames.iter().find(|f| f.index == index))
            .ok_or_else(|| ApiError::new(404, format!("frame {index} was not exported")))?;
        let (sub, name) = match kind {
            "image" => (crate::manifest::IMAGE_DIR, Some(&f.file)),
            "mask" => (crate::manifest::MASK_DIR, f.mask.as_ref()),
            "overlay" => (crate::manifest::OVERLAY_DIR, f.overlay.as_ref()),
            _ => return Err(ApiError::new(404, format!("no export file kind `{kind}`"))),
        };
        let name =
            name.ok_or_else(|| ApiError::new(404, format!("frame {index} has no {kind}")))?;
        let rel = format!("{sub}/{name}");
        let path = crate::output::inside(&rel, "export file", &dir.join(crate::manifest::MANIFEST))
            .map_err(|e| ApiError::new(404, e.to_string()))?;
        let path = dir.join(path);
        let regular = std::fs::symlink_metadata(&path).is_ok_and(|m| m.file_type().is_file());
        let canon = (path.canonicalize().ok())
            .zip(dir.canonicalize().ok())
            .is_some_and(|(p, d)| p.starts_with(d));
        match regular && canon {
            true => Ok(path),
            false => Err(ApiError::new(
                404,
                format!("{rel} is not a file of the export"),
            )),
        }
    }

    /// Re-reads the project file when it changed on disk since it was loaded or saved (a page
    /// reload asks for the state, so "reload the page" makes the next save start from the file on
    /// disk); a new revision makes other tabs reload too. Refuses a file that no longer loads or
    /// that names another input.
    fn reread(&self) -> ApiResult<()> {
        let mut saved = lock(&self.saved);
        let path = self.path.display();
        let now = fsutil::fingerprint_file(&self.path)
            .map_err(|e| ApiError::new(409, format!("{e}; restore {path} or restart review")))?;
        if now == saved.fingerprint {
            return Ok(());
        }
        let project = Project::load(&self.path).map_err(|e| {
            let msg =
                format!("{path} changed on disk and does not load ({e}); fix it, then reload");
            ApiError::new(409, msg)
        })?;
        if project.input_path(&self.path) != self.input {
            let msg = format!(
                "{path} now names another input ({}); restart review on it",
                project.input_path(&self.path).display()
            );
            return Err(ApiError::new(409, msg));
        }
        if project.input.fingerprint != saved.project.input.fingerprint {
            *lock(&self.frames) = None;
        }
        log::info!("review: {path} changed on disk; read it again");
        *saved = Saved {
            project: Arc::new(project),
            fingerprint: now,
            revision: saved.revision + 1,
        };
        Ok(())
    }

    /// `/api/state`: the project, its steps, the parameters each step takes, the series that do
    /// not depend on the keyframes, the export and the current selection.
    pub fn state(&self) -> ApiResult<Value> {
        self.reread()?;
        let project = self.project();
        let steps = Review::steps_of(&project);
        let started = Instant::now();
        let selection = self.select(&steps)?;
        let exported: Vec<Value> = (self.export.iter())
            .flat_map(|(_, m)| &m.frames)
            .map(|f| json!({"index": f.index, "mask": f.mask.is_some(), "overlay": f.overlay.is_some()}))
            .collect();
        Ok(json!({
            "revision": self.revision(),
            "project": {"path": self.path, "name": self.path.file_name().map(|n| n.to_string_lossy())},
            "input": {"path": self.input, "kind": project.input.kind, "frames": project.metadata.frame_count,
                      "fps": project.metadata.fps, "width": project.metadata.width, "height": project.metadata.height,
                      "available": self.input.exists()},
            "steps": steps,
            "chain": chain(),
            "schema": schema(),
            "series": series(&project),
            "export": exported,
            "selection": selection,
            "server_ms": started.elapsed().as_secs_f64() * 1e3,
        }))
    }
}

/// The chain for the page's editor, in order: each step's id, the step whose place it shares,
/// and the parameter a new one must be given.
fn chain() -> Value {
    (steps::STEPS.iter())
        .map(|k| json!({"id": k.id, "instead_of": k.instead_of, "required": k.required}))
        .collect()
}

/// The step list's order and each step's parameters, as `select` checks them.
pub fn check(steps: &[Step]) -> ApiResult<()> {
    steps::check_order(steps).map_err(|(i, msg)| ApiError::step(Some(i), None, msg))?;
    for (i, s) in steps.iter().enumerate() {
        s.validate()
            .map_err(|e| ApiError::step(Some(i), Some(e.key.into()), e.msg))?;
    }
    Ok(())
}

/// Parses a JSON step list, errors naming the step and parameter.
pub fn parse_steps(v: &Value) -> ApiResult<Vec<Step>> {
    serde_path_to_error::deserialize::<_, Vec<Step>>(v.clone()).map_err(|e| {
        let path = e.path().to_string();
        let step = path
            .strip_prefix('[')
            .and_then(|p| p.split(']').next())
            .and_then(|i| i.parse().ok());
        let key = path.rsplit('.').next().map(str::to_string);
        let msg = format!("steps{}: {}", path.trim_start_matches('.'), e.inner());
        ApiError::step(step, key, msg)
    })
}

/// Every step's parameters for the page's editor: step id (`plugin`), key, flag, help, default,
/// choices.
fn schema() -> Value {
    let mut out: Vec<Value> = Vec::new();
    for f in steps::flags() {
        // Switches (`--blur`, `--auto`) turn a step or a value on; the editor has its own.
        let Some((step, key)) = f.sets.filter(|_| f.value_name.is_some()) else {
            continue;
        };
        out.push(json!({
            "plugin": step, "key": key, "flag": f.long, "help": f.help, "default": f.default,
            "choices": (f.choices)().iter().map(|c| c.0).collect::<Vec<_>>(), "switch": f.value_name.is_none(),
        }));
    }
    Value::Array(out)
}

/// A shell word, quoted when it needs to be.
fn quote(s: &str) -> String {
    let plain = (s.chars()).all(|c| c.is_ascii_alphanumeric() || "-_./=:,".contains(c));
    match plain && !s.is_empty() {
        true => s.to_string(),
        false => format!("'{}'", s.replace('\'', r"'\''")),
    }
}

/// The per-frame series that do not depend on the keyframes: timestamps, each sharpness metric,
/// each movement measurement, the telemetry's distance from the first position.
fn series(p: &Project) -> Value {
    let c = &p.cache;
    let mut curves: Vec<Value> = (c.sharpness.iter())
        .map(|s| json!({"name": s.metric.to_string(), "values": s.scores}))
        .collect();
    curves.extend((c.movement.iter()).map(|m| {
        json!({"name": format!("movement ({} px wide)", m.request.analysis_width), "values": m.series.values})
    }));
    json!({"timestamps": c.timestamps_s, "curves": curves})
}
