//! `select`: one analysis pass over the input for the frame count, timestamps and the scores the
//! samplers need (or none, when a project for the same unchanged input already caches them), each
//! frame's position from telemetry when there is any (`select::telemetry`), then the samplers in
//! keyframer's fixed chain (see [`crate::steps::check_order`]). Writes the project file
//! atomically.

pub mod preview;
mod telemetry;

use crate::analysis::{self, Request};
use crate::embedding_file;
use crate::error::{Error, Result};
use crate::fsutil::{self, Fingerprint};
use crate::gpu;
use crate::kernels::descriptor;
use crate::output::lock::Lock;
use crate::output::Inputs;
use crate::params::Metric;
use crate::params::{Backend, BackendChoice, MovementRequest, StationaryRequest};
use crate::project::{
    Cache, EmbeddingCache, InputRef, MovementCache, Project, SharpnessSeries, StationaryCache,
    SCHEMA_VERSION,
};
use crate::source::{self, Metadata, OpenOptions, SourceKind};
use crate::steps::stationary::StationarySettings;
use crate::steps::{self, Boundaries};
use crate::steps::{Applied, Need, Recorded, Step};
use std::path::{Path, PathBuf};

use crate::steps::Threshold;

/// The threshold an earlier `select` proposed from its movement sample for `step`
/// (`stationary` or `spacing` with `auto`), measured the way `movement` says on `backend`, as its
/// project's `history` records it. The sample is a function of the input (unchanged: its
/// fingerprint matched) and of those two, so re-selecting reuses it instead of decoding the
/// sample again; the selection then stays the one the cache was made for.
pub fn recorded_auto(
    history: &[Recorded],
    step: &str,
    movement: &MovementRequest,
    backend: Backend,
) -> Option<f64> {
    history.iter().find_map(|e| match e.applied {
        Applied::Stationary {
            auto: true,
            backend: Some(b),
            movement: Some(m),
            threshold_px: Some(t),
            ..
        } if step == "stationary" && b == backend && m == *movement => Some(t),
        Applied::Spacing {
            auto: true,
            backend: Some(b),
            movement: Some(m),
            threshold_px,
            ..
        } if step == "spacing" && b == backend && m == *movement => Some(threshold_px),
        _ => None,
    })
}

/// The chain's thresholds with `auto` resolved, and the movement measurement they apply to: what
/// the steps need besides the cached series.
#[derive(Debug, Clone, PartialEq)]
pub struct Resolved {
    /// How movement is measured.
    pub movement: MovementRequest,
    /// The stationary step's parameters, when the chain has one.
    pub stationary: Option<StationarySettings>,
    /// The stationary threshold was asked for as `auto`.
    pub stationary_auto: bool,
    /// The spacing threshold in pixels (given, or proposed for `auto`); None for `Nkf` or none.
    pub spacing_px: Option<f64>,
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
    /// Kernel backend asked for the analysis (projects record the one used).
    pub backend: BackendChoice,
    /// GPU adapter choice (part of its name).
    pub adapter: Option<String>,
    /// Frame rate to assume for image folders.
    pub images_fps: Option<f64>,
    /// Telemetry file (DJI SRT or GPX); None: the SRT sidecar beside a video, or the images' EXIF.
    pub telemetry: Option<PathBuf>,
    /// Seconds added to a frame's timestamp to find it in the telemetry.
    pub telemetry_offset_s: f64,
    /// Replace an existing project file.
    pub force: bool,
    /// Seconds between analysis checkpoints (0: none).
    pub checkpoint_every_s: f64,
    /// Analyse only the codec's keyframes (a quick, coarse preview; see [`preview`]).
    pub preview: bool,
    /// The frames' projection; None: from the container's spherical metadata, else pinhole.
    pub projection: Option<crate::equirect::Projection>,
    /// Refuse frames that are not 360° ones, as `export --views` refuses them
    /// ([`crate::manifest::ViewSettings::check_projection`]), once the projection is known and before any frame is
    /// analysed: a workflow whose exports are rigs.
    pub require_equirect: bool,
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
            movement: w.movement,
            backend: w.backend,
            adapter: an.adapter,
            images_fps: an.images_fps,
            telemetry: an.telemetry.as_ref().map(|t| {
                let dir = w.path.parent().unwrap_or(Path::new("."));
                crate::fsutil::absolute(&dir.join(t))
            }),
            telemetry_offset_s: an.telemetry_offset.unwrap_or(0.0),
            force: true,
            checkpoint_every_s: Self::CHECKPOINT_EVERY_S,
            preview: an.preview == Some(true),
            projection: an.projection,
            require_equirect: w.exports.iter().any(|(_, e)| e.views.is_some()),
            quiet,
        }
    }

    /// What this `select` reads: the input, and the telemetry it takes positions from (the
    /// `--telemetry` file, or the DJI SRT found beside a video).
    pub fn inputs(&self) -> Inputs {
        let kind = source::kind_of(&self.input).unwrap_or(SourceKind::Video);
        let mut inputs = Inputs::none().with("input", &self.input);
        if let Some(file) = telemetry::file(self, kind) {
            let what = match self.telemetry {
                Some(_) => "telemetry",
                None => "telemetry found beside the video",
            };
            inputs.add(what, file);
        }
        for (key, file) in self.steps.iter().flat_map(Step::files) {
            inputs.add(Step::file_what(key), file);
        }
        // A network's description names the network (and is itself the `model` above).
        if let Some(m) =
            similarity_model(&self.steps).filter(|m| crate::model_desc::is_description(m))
        {
            if let Ok(d) = crate::model_desc::ModelDesc::load(m) {
                inputs.extend(&d.inputs);
            }
        }
        inputs
    }

    /// `path` relative to the project file's folder when possible, as the project records it.
    fn relative(&self, path: &Path) -> PathBuf {
        let project_dir = fsutil::absolute(&self.output)
            .parent()
            .map(Path::to_path_buf);
        fsutil::relative_to(path, &project_dir.unwrap_or_default())
    }

    /// Whether a step of the chain needs `need`.
    fn needs(&self, need: Need) -> bool {
        self.steps.iter().any(|s| s.needs().contains(&need))
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
    /// A series file this run computed: (where it was written while running, the name the
    /// project gives it), moved into place only when the project is written.
    new_series: Option<(PathBuf, PathBuf)>,
}

/// The input's kind and fingerprint, from the file system only.
pub fn identify(input: &Path) -> Result<(SourceKind, Fingerprint)> {
    let kind = source::kind_of(input)?;
    let fingerprint = match kind {
        SourceKind::Images => fsutil::fingerprint_files(&source::folder_images(input)?)?,
        _ => fsutil::fingerprint_file(input)?,
    };
    Ok((kind, fingerprint))
}

/// The output rule for `select`: the project file and its checkpoint are regular files (or
/// missing), none of its inputs nor inside one; an existing project needs `--force`. Returns
/// their locks.
pub(crate) fn check_outputs(s: &SelectSettings) -> Result<[Lock; 2]> {
    let inputs = s.inputs();
    let project = crate::output::check_file(&s.output, s.force, &inputs)?;
    let checkpoint = checkpoint_path(&s.output);
    let partial = crate::output::check_file(&checkpoint, true, &inputs)?;
    // The checkpoint is replaced and removed without --force only when it is keyframer's own.
    if checkpoint.exists() && !s.force && !crate::analysis::is_checkpoint(&checkpoint) {
        return Err(Error::output(
            checkpoint,
            "exists and is not a keyframer checkpoint; pass --force to replace it",
        ));
    }
    if s.needs(Need::Embeddings) {
        let running = series_partial_path(&s.output);
        crate::output::check_name_len(&running)?;
        crate::output::check_name_len(&s.output.with_file_name(series_name(
            &s.output,
            "",
            (0, 0),
        )))?;
        // Never an input, never through a link, a FIFO or a device, even with --force.
        crate::output::check_not_input(&running, &inputs)?;
        crate::output::check_replaceable(&running)?;
        if running.exists() && !s.force && !embedding_file::is_ours(&running) {
            return Err(Error::output(
                running,
                "exists and is not a keyframer embeddings file; pass --force to replace it",
            ));
        }
    }
    Ok([project, partial])
}

/// Where a running analysis appends the embeddings: `output` + `.partial.emb` (with the
/// checkpoint, `output` + `.partial`, which counts its frames).
pub fn series_partial_path(output: &Path) -> PathBuf {
    let mut name = output.file_name().unwrap_or_default().to_os_string();
    name.push(".partial.emb");
    output.with_file_name(name)
}

/// The file name of a finished embedding series of `embedder` at `size` beside the project
/// `output`: its name, 16 hex digits of a hash of the series' key, `.emb`.
fn series_name(output: &Path, embedder: &str, size: (u32, u32)) -> String {
    let key = format!("{embedder} {}x{}", size.0, size.1);
    format!(
        "{}.{:016x}.emb",
        output.file_name().unwrap_or_default().to_string_lossy(),
        crate::output::fnv1a64(key.as_bytes())
    )
}

/// The checkpoint file of a running analysis for the project `output`: `output` + `.partial`.
pub fn checkpoint_path(output: &Path) -> PathBuf {
    let mut name = output.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    output.with_file_name(name)
}

/// Runs `select` and writes the project file.
pub fn select(s: &SelectSettings) -> Result<SelectReport> {
    // One writer per project file, from the checks until the project is written.
    let _held = check_outputs(s)?;
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
    let mut report = report;
    if let Some((running, to)) = report.new_series.take() {
        publish_series(&mut report.project, &running, &to, s.force)?;
    }
    write(&report.project, &s.output)?;
    Ok(report)
}

/// Refuses to replace `to` with a series file unless it is keyframer's own (or `force`), and
/// never through a link or onto a file that is not regular.
fn check_series_target(to: &Path, force: bool) -> Result<()> {
    if to.exists() && !force && !embedding_file::is_ours(to) {
        let msg = "exists and is not a keyframer embeddings file; pass --force to replace it";
        return Err(Error::output(to, msg));
    }
    crate::output::check_replaceable(to)
}

/// Moves the series file an analysis wrote at `running` to `to`, the name its key gives it,
/// and names it so in `project`'s cache: the last step before the project is written, so that
/// a step failing earlier leaves the file of that name as it was.
fn publish_series(project: &mut Project, running: &Path, to: &Path, force: bool) -> Result<()> {
    check_series_target(to, force)?;
    std::fs::rename(running, to).map_err(|err| Error::io(to, err))?;
    let name = to.file_name().map(|n| n.to_string_lossy().into_owned());
    for e in &mut project.cache.embeddings {
        if e.path().as_deref() == Some(running) {
            e.file = name.clone();
        }
    }
    Ok(())
}

/// Writes `project` to `output` atomically and removes the analysis checkpoint beside it: the
/// end of every `select` (and of `review`'s save).
pub fn write(project: &Project, output: &Path) -> Result<()> {
    let old = replaced_series(output);
    project.save(output, true)?;
    let checkpoint = checkpoint_path(output);
    if checkpoint.is_file() {
        if let Err(e) = std::fs::remove_file(&checkpoint) {
            log::warn!(
                "{}: could not remove the checkpoint: {e}",
                checkpoint.display()
            );
        }
    }
    drop_series(output, &old, &series_files(project));
    Ok(())
}

/// The series files the project at `output`, about to be replaced, names (its own record).
pub(crate) fn replaced_series(output: &Path) -> Vec<PathBuf> {
    match output.is_file() {
        true => Project::load(output).map_or_else(|_| Vec::new(), |p| series_files(&p)),
        false => Vec::new(),
    }
}

/// After the project at `output` was replaced: removes the series files of `old` (the replaced
/// project's) that the new one does not name (`kept`), and the running series file.
pub(crate) fn drop_series(output: &Path, old: &[PathBuf], kept: &[PathBuf]) {
    // Only names this output makes (`<output name>.<key hash>.emb`): a copied project names its
    // original's series, which are not this output's to remove.
    let prefix = format!(
        "{}.",
        output.file_name().unwrap_or_default().to_string_lossy()
    );
    let own = |f: &&PathBuf| {
        f.parent() == output.parent()
            && (f.file_name()).is_some_and(|n| n.to_string_lossy().starts_with(&prefix))
    };
    for f in old.iter().filter(own).filter(|f| !kept.contains(f)) {
        embedding_file::remove_ours(f);
    }
    embedding_file::remove_ours(&series_partial_path(output));
}

/// The series files `project`'s cache names.
pub(crate) fn series_files(project: &Project) -> Vec<PathBuf> {
    (project.cache.embeddings.iter())
        .filter_map(|e| e.path())
        .collect()
}

/// The manual step of `steps` (frames added and removed by index), when there is one.
pub(crate) fn manual_step(
    keys: &mut Vec<usize>,
    history: &mut Vec<Recorded>,
    steps: &[Step],
    frame_count: usize,
) -> Result<()> {
    let at = steps::Inputs {
        frame_count,
        ..Default::default()
    };
    for step in steps.iter().filter(|s| matches!(s, Step::Manual { .. })) {
        if let Some(applied) = step.apply(&at, keys)? {
            history.push(Recorded::new(applied, keys.len()));
        }
    }
    Ok(())
}

/// Analyses (or reuses the cache) and runs the sampler chain; returns the project unsaved. A
/// keyframe-only source (`open.keyframes`) never reuses or checkpoints a cache.
pub(crate) fn build(s: &SelectSettings, open: &OpenOptions) -> Result<SelectReport> {
    let full = open.codec_keyframes.is_none();
    let input_ref = input_ref(s)?;
    // ffprobe reads the spherical metadata while the checks below run and the video opens.
    let is_video = input_ref.kind == SourceKind::Video;
    let spherical = crate::equirect::SphericalProbe::start(&s.input, is_video, s.projection);
    let _held = check_outputs(s)?;
    // A model that does not fit its name is refused before any frame is decoded.
    if let Some(model) = similarity_model(&s.steps) {
        drop(crate::segment::embedding::check(model)?);
    }
    let boundaries = steps::boundaries(&s.steps);
    let mut known = Known::from_project(s, full, &input_ref);
    known.scan_for_times(s, open, &boundaries)?;
    let (projection, height) = {
        let m = known.metadata(s, open)?;
        let p = crate::equirect::resolve_projection_probed(
            s.projection,
            &s.input,
            spherical,
            (m.width, m.height),
        )?;
        (p, m.height)
    };
    // 360° frames are scored for sharpness on their band |latitude| < 45°.
    let sharpness_rows = (projection == crate::equirect::Projection::Equirect)
        .then(|| crate::params::Rows::erp_band(height));
    if s.require_equirect {
        crate::manifest::ViewSettings::check_projection(projection)?;
    }
    let on_sphere;
    let s = match projection {
        crate::equirect::Projection::Equirect => {
            on_sphere = on_the_sphere(s);
            &on_sphere
        }
        crate::equirect::Projection::Pinhole => s,
    };
    let auto = AutoThresholds::find(s, open, &mut known)?;
    let stationary_req = match auto.resolved.stationary {
        Some(st) => {
            let meta = known.metadata(s, open)?;
            Some(st.request(&boundaries, &meta, known.cache.timestamps_s.as_deref())?)
        }
        None => None,
    };
    let plan = Plan::of(s, &known, stationary_req, sharpness_rows);
    let metadata = match known.metadata.take() {
        Some(m) if plan.is_empty() => {
            if !known.decoded {
                log::info!(
                    "reusing the frame data cached in {} (input unchanged; nothing decoded)",
                    s.output.display()
                );
            }
            m
        }
        cached => known.analyse(s, open, &plan, cached, full.then(|| resume(s, &input_ref)))?,
    };
    known.cache.telemetry = telemetry::positions(
        s,
        input_ref.kind,
        metadata.frame_count,
        known.cache.timestamps_s.as_deref(),
        known.cache.telemetry.take(),
    )?;
    let (keys, history) = run_steps(
        &s.input,
        &s.steps,
        &auto.resolved,
        &known.cache,
        &metadata,
        &known.damaged,
    )?;
    steps::geo_area::note_changes(&known.history, &history);
    let project = Project {
        schema_version: SCHEMA_VERSION,
        tool_version: env!("CARGO_PKG_VERSION").into(),
        input: input_ref,
        metadata,
        boundaries,
        keyframes: keys,
        history,
        cache: known.cache,
        decode_problems: known.problems,
        damaged_frames: known.damaged,
        preview: false,
        projection,
    };
    Ok(SelectReport {
        project,
        decoded: known.decoded,
        proposals: auto.proposals,
        new_series: known.new_series,
    })
}

/// `s` for 360° frames: movement measured on the horizon views with the sphere's rotation
/// removed (always: a turn on the spot is no movement on a 360° input), said on stderr.
fn on_the_sphere(s: &SelectSettings) -> SelectSettings {
    let mut s = s.clone();
    let views = s
        .movement
        .sphere
        .unwrap_or(crate::params::SphereViews::DEFAULT);
    if s.needs(Need::Movement) {
        log::info!(
            "360° input: movement is measured on {} views of {}° around the horizon, with the \
             rotation of the sphere removed from all of them together (turning on the spot is not \
             movement{})",
            views.views,
            views.fov_deg,
            if s.movement.derotate.is_some() {
                "; --derotate and --hfov are implied and not used"
            } else {
                ""
            }
        );
    }
    s.movement.sphere = Some(views);
    s.movement.derotate = None;
    s
}

/// The project's reference to its input: kind, fingerprint and a path relative to the project.
fn input_ref(s: &SelectSettings) -> Result<InputRef> {
    let (kind, fingerprint) = identify(&s.input)?;
    Ok(InputRef {
        path: s.relative(&s.input),
        kind,
        fingerprint,
    })
}

/// Where a running analysis keeps its checkpoint.
fn resume(s: &SelectSettings, input: &InputRef) -> analysis::Resume {
    analysis::Resume {
        path: checkpoint_path(&s.output),
        fingerprint: input.fingerprint.clone(),
        every_s: s.checkpoint_every_s,
    }
}

/// Keyframes without the damaged frames blur replace or `--add` may have moved there.
fn drop_damaged(input: &Path, mut keys: Vec<usize>, damaged: &[usize]) -> Vec<usize> {
    let before = keys.len();
    keys.retain(|k| damaged.binary_search(k).is_err());
    if keys.len() < before {
        log::warn!(
            "{}: {} damaged frame(s) dropped from the keyframes (moved there by blur replace or --add)",
            input.display(),
            before - keys.len()
        );
    }
    keys
}

/// What is known of the input before this run decodes anything: the earlier project's metadata,
/// cache and problems when it is for the same unchanged input (a full analysis only), and
/// whether this run has decoded the input yet.
#[derive(Default)]
struct Known {
    metadata: Option<Metadata>,
    cache: Cache,
    /// The history of the project being replaced (its `--auto` thresholds are reused).
    history: Vec<Recorded>,
    problems: Vec<String>,
    damaged: Vec<usize>,
    decoded: bool,
    /// The series file the analysis wrote and the name the cache gives it (not moved yet).
    new_series: Option<(PathBuf, PathBuf)>,
    /// The source opened for its metadata, still at its first frame: the analysis reads it
    /// (one open, and one packet listing started that much earlier, instead of two).
    opened: Option<Box<dyn source::FrameSource>>,
}

impl Known {
    fn from_project(s: &SelectSettings, full: bool, input: &InputRef) -> Known {
        let reusable = s
            .output
            .exists()
            .then(|| Project::load(&s.output).ok())
            .flatten()
            .filter(|p| full && !p.preview && p.input == *input);
        match reusable {
            Some(p) => Known {
                metadata: Some(p.metadata),
                cache: p.cache,
                history: p.history,
                problems: p.decode_problems,
                damaged: p.damaged_frames,
                decoded: false,
                new_series: None,
                opened: None,
            },
            None => Known::default(),
        }
    }

    /// The stationary sampler runs during decoding and needs its frame range first: with
    /// boundaries in seconds and nothing cached, a scan gives the timestamps.
    fn scan_for_times(
        &mut self,
        s: &SelectSettings,
        open: &OpenOptions,
        boundaries: &Boundaries,
    ) -> Result<()> {
        let uses_seconds = [boundaries.start, boundaries.end]
            .iter()
            .any(|b| matches!(b, Some(steps::Bound::Seconds(_))));
        if !s.needs(Need::StationaryRun) || self.metadata.is_some() || !uses_seconds {
            return Ok(());
        }
        let a = analysis::analyse(
            &s.input,
            open,
            &Request::default(),
            Backend::Opencv,
            None,
            s.quiet,
            None,
        )?;
        self.cache.timestamps_s = a.timestamps_s;
        self.problems = a.problems;
        self.damaged = a.damaged;
        self.metadata = Some(a.metadata);
        self.decoded = true;
        Ok(())
    }

    /// The input's metadata: cached, or read from its header.
    fn metadata(&mut self, s: &SelectSettings, open: &OpenOptions) -> Result<Metadata> {
        if let Some(m) = &self.metadata {
            return Ok(m.clone());
        }
        let src = match self.opened.take() {
            Some(src) => src,
            None => source::open(&s.input, open)?,
        };
        let m = src.metadata().clone();
        self.opened = Some(src);
        Ok(m)
    }

    /// Runs the analysis `plan` asks for and merges it into the cache (replaced when the input
    /// decodes to another frame count than `cached` says). Returns the decoded metadata.
    fn analyse(
        &mut self,
        s: &SelectSettings,
        open: &OpenOptions,
        plan: &Plan,
        cached: Option<Metadata>,
        resume: Option<analysis::Resume>,
    ) -> Result<Metadata> {
        let (backend, ctx) = if plan.is_empty() {
            (Backend::Opencv, None)
        } else {
            gpu::resolve_backend(s.backend, s.adapter.as_deref())
        };
        let request = plan.request(s);
        // A second try (the gpu backend failed over to opencv) opens the input again.
        let mut opened = self.opened.take();
        let a = gpu::or_opencv("the analysis", backend, ctx.as_ref(), |backend, ctx| {
            let before = ctx.map(|c| c.counts());
            let src = match opened.take() {
                Some(src) => src,
                None => source::open(&s.input, open)?,
            };
            let a = analysis::analyse_source(
                src,
                &s.input,
                &request,
                backend,
                ctx,
                s.quiet,
                resume.as_ref(),
            )?;
            if let (Some(c), Some(before)) = (ctx, before) {
                let work = gpu::PerFrame::of(c.counts() - before, a.metadata.frame_count);
                log::info!("gpu backend: {work}");
            }
            Ok(a)
        })?;
        if cached.is_some_and(|m| m.frame_count != a.metadata.frame_count) {
            log::warn!("the input decodes to a different frame count than cached; cache replaced");
            self.cache = Cache::default();
        }
        self.merge(s, a, plan)
    }

    /// Adds what an analysis measured to the cache; returns its metadata.
    fn merge(
        &mut self,
        s: &SelectSettings,
        a: analysis::Analysis,
        plan: &Plan,
    ) -> Result<Metadata> {
        let cache = &mut self.cache;
        for (metric, scores) in a.sharpness {
            // One series per metric: one measured on other rows (a 360° project cached
            // before its band was scored) is replaced.
            cache.sharpness.retain(|x| x.metric != metric);
            cache.sharpness.push(SharpnessSeries {
                metric,
                width: a.metadata.width,
                height: a.metadata.height,
                rows: plan.rows,
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
        if let (Some(keys), Some(mut st)) = (a.stationary, plan.stationary) {
            st.last = st.last.min(a.metadata.frame_count.saturating_sub(1));
            cache.stationary.push(StationaryCache {
                request: s.movement,
                params: st,
                backend: a.backend,
                keyframes: keys,
            });
        }
        if let (Some(e), Some((embedder, _))) = (a.embeddings, plan.embedder.clone()) {
            // The running series file becomes the project's, under a name of its key, when
            // the project is written ([`select`]): a later failing step leaves it where a
            // re-run resumes it, and the file of that name as it was.
            let to = s
                .output
                .with_file_name(series_name(&s.output, &embedder, e.size));
            check_series_target(&to, s.force)?;
            let dir = to.parent().unwrap_or(Path::new("")).to_path_buf();
            let running = e.file.file_name().map(|n| n.to_string_lossy().into_owned());
            self.new_series = Some((dir.join(running.as_deref().unwrap_or_default()), to));
            cache
                .embeddings
                .retain(|c| !(c.embedder == embedder && (c.width, c.height) == e.size));
            // Named by its running file until [`publish_series`] moves it.
            cache.embeddings.push(EmbeddingCache {
                embedder,
                width: e.size.0,
                height: e.size.1,
                backend: e.backend,
                runtime: e.runtime,
                dim: e.dim,
                file: running,
                frames: Vec::new(),
                dir,
            });
        }
        if cache.timestamps_s.is_none() {
            cache.timestamps_s = a.timestamps_s;
        }
        self.problems = a.problems;
        self.damaged = a.damaged;
        self.decoded = true;
        Ok(a.metadata)
    }
}

/// The thresholds the steps use: given ones, or proposed from a sample of the movement for
/// `--auto` / `--spacing auto` (with the explanations `select` prints).
struct AutoThresholds {
    resolved: Resolved,
    proposals: Vec<String>,
}

impl AutoThresholds {
    fn find(s: &SelectSettings, open: &OpenOptions, known: &mut Known) -> Result<AutoThresholds> {
        let mut t = AutoThresholds {
            resolved: Resolved::given(&s.steps, s.movement),
            proposals: Vec::new(),
        };
        let wants_auto_stationary = t.resolved.stationary_auto;
        let auto_spacing = s.needs(Need::SpacingProposal);
        if !(wants_auto_stationary || auto_spacing) {
            return Ok(t);
        }
        let (backend, ctx) = gpu::resolve_backend(s.backend, s.adapter.as_deref());
        let recorded = |step: &str, wanted: bool| {
            wanted
                .then(|| recorded_auto(&known.history, step, &s.movement, backend))
                .flatten()
        };
        let reused = |what: &str, t: f64| {
            format!(
                "{what}: {t:.3} px, proposed from a movement sample when {} was written (same input, \
                 same movement measurement); give a number to change it",
                s.output.display()
            )
        };
        let (old_stationary, old_spacing) = (
            recorded("stationary", wants_auto_stationary),
            recorded("spacing", auto_spacing),
        );
        let needs_sample = (wants_auto_stationary && old_stationary.is_none())
            || (auto_spacing && old_spacing.is_none());
        let sample = match needs_sample {
            true => gpu::or_opencv("the movement sample", backend, ctx.as_ref(), |b, c| {
                analysis::sample_movement(&s.input, open, s.movement, 40, b, c)
            })?,
            false => Vec::new(),
        };
        if wants_auto_stationary {
            let (threshold, said) = match old_stationary {
                Some(v) => (v, reused("stationary --auto", v)),
                None => {
                    let p = steps::auto::stationary_threshold(&sample);
                    (p.threshold, format!("stationary --auto: {}", p.explanation))
                }
            };
            if let Some(st) = t.resolved.stationary.as_mut() {
                st.threshold = Some(threshold);
            }
            t.proposals.push(said);
        }
        if auto_spacing {
            let (threshold, said) = match old_spacing {
                Some(v) => (v, reused("spacing auto", v)),
                None => {
                    let meta = known.metadata(s, open)?;
                    let p = steps::auto::spacing_threshold(&sample, meta.width, meta.frame_count);
                    (p.threshold, format!("spacing auto: {}", p.explanation))
                }
            };
            t.resolved.spacing_px = Some(threshold);
            t.proposals.push(said);
        }
        Ok(t)
    }
}

/// What the analysis must still measure: what the steps need ([`Step::needs`]) and the cache
/// lacks (sharpness metrics, the movement series, the stationary run).
struct Plan {
    missing: Vec<Metric>,
    /// The rows sharpness is scored on (360° frames); None: whole frames.
    rows: Option<crate::params::Rows>,
    movement: bool,
    stationary: Option<StationaryRequest>,
    /// The analysis width to describe the frames at (the similarity step's embeddings).
    descriptor: Option<u32>,
    /// The embedder the chain reads (its cache name) and its network, if any.
    embedder: Option<(String, Option<PathBuf>)>,
}

impl Plan {
    fn of(
        s: &SelectSettings,
        known: &Known,
        stationary: Option<StationaryRequest>,
        rows: Option<crate::params::Rows>,
    ) -> Plan {
        let needs: Vec<Need> = s.steps.iter().flat_map(Step::needs).collect();
        let metrics = needs.iter().filter_map(|n| match n {
            Need::Sharpness(m) => Some(*m),
            _ => None,
        });
        let missing = match &known.metadata {
            Some(m) => metrics
                .filter(|&k| (known.cache.sharpness(k, (m.width, m.height), rows)).is_none())
                .collect(),
            None => metrics.collect(),
        };
        let cache = &known.cache;
        let need_series = needs.contains(&Need::Movement) && cache.movement(&s.movement).is_none();
        let need_run = needs.contains(&Need::StationaryRun);
        let width = s.movement.analysis_width;
        let model = similarity_model(&s.steps);
        let embedder = (needs.contains(&Need::Embeddings)).then(|| match model {
            Some(m) => (
                crate::segment::embedding::embedder_of(m).unwrap_or_default(),
                Some(m.to_path_buf()),
            ),
            None => (descriptor::NAME.to_string(), None),
        });
        // The built-in descriptor at this analysis size, or the step's network, readable.
        let described = |m: &Metadata| match model {
            Some(_) => embeddings(cache, m, width, model).is_some(),
            None => {
                let size = analysis::analysis_size(m.width, m.height, width);
                (cache.embeddings(descriptor::NAME, size)).is_some_and(|e| e.usable(m.frame_count))
            }
        };
        let need_embeddings = embedder.is_some() && !known.metadata.as_ref().is_some_and(described);
        Plan {
            descriptor: need_embeddings.then_some(width),
            embedder,
            missing,
            rows,
            movement: need_series,
            stationary: stationary
                .filter(|st| need_run && cache.stationary(&s.movement, st).is_none()),
        }
    }

    /// Nothing to measure: every series is cached (the metadata still needs a scan when none is
    /// cached).
    fn is_empty(&self) -> bool {
        self.missing.is_empty()
            && !self.movement
            && self.stationary.is_none()
            && self.descriptor.is_none()
    }

    fn request(&self, s: &SelectSettings) -> Request {
        Request {
            sharpness: self.missing.clone(),
            // Only with scores to compute: a movement-only checkpoint keeps its key.
            sharpness_rows: self.rows.filter(|_| !self.missing.is_empty()),
            movement: (self.movement || self.stationary.is_some()).then_some(s.movement),
            stationary: self.stationary,
            descriptor: self.descriptor,
            network: self.embedder.clone().and_then(|e| e.1),
            runtime: similarity_runtime(&s.steps),
            store: self.descriptor.map(|_| series_partial_path(&s.output)),
        }
    }
}

impl Resolved {
    /// The thresholds `steps` give as numbers (`auto` still unresolved), for `movement`.
    pub fn given(steps: &[Step], movement: MovementRequest) -> Resolved {
        let px = |t: Option<Threshold>| match t {
            Some(Threshold::Px(v)) => Some(v),
            _ => None,
        };
        let (mut stationary, mut stationary_auto, mut spacing_px) = (None, false, None);
        for step in steps {
            match step {
                Step::Stationary {
                    threshold,
                    reset_delta,
                } => {
                    stationary_auto = *threshold == Some(Threshold::Auto);
                    stationary = Some(StationarySettings {
                        threshold: px(*threshold),
                        reset_delta: reset_delta.unwrap_or(steps::defaults::RESET_DELTA),
                    });
                }
                Step::Spacing { threshold } => spacing_px = px(Some(*threshold)),
                _ => {}
            }
        }
        Resolved {
            movement,
            stationary,
            stationary_auto,
            spacing_px,
        }
    }
}

/// Runs every step in order on the candidates (damaged frames never are) over the cached series
/// of `cache`, with `resolved` thresholds; returns the keyframes (no damaged frame) and the
/// history. `select` and `review` both run their chains through here.
pub fn run_steps(
    input: &Path,
    steps: &[Step],
    resolved: &Resolved,
    cache: &Cache,
    metadata: &Metadata,
    damaged: &[usize],
) -> Result<(Vec<usize>, Vec<Recorded>)> {
    let (range, at) = inputs(steps, resolved, cache, metadata)?;
    let mut keys = range;
    keys.retain(|k| damaged.binary_search(k).is_err());
    let boundaries = steps::boundaries(steps);
    let (end, start) = (boundaries.end, boundaries.start);
    let mut history = vec![Recorded::new(
        Applied::Boundaries { end, start },
        keys.len(),
    )];
    for step in steps {
        if let Some(applied) = step.apply(&at, &mut keys)? {
            history.push(Recorded::new(applied, keys.len()));
        }
    }
    Ok((drop_damaged(input, keys, damaged), history))
}

/// What each of `steps` needs that `cache` lacks ([`Step::lacks`]), with `resolved` thresholds.
pub fn lacking(
    steps: &[Step],
    resolved: &Resolved,
    cache: &Cache,
    metadata: &Metadata,
) -> Result<Vec<Vec<Need>>> {
    let (_, at) = inputs(steps, resolved, cache, metadata)?;
    Ok(steps.iter().map(|s| s.lacks(&at)).collect())
}

/// The boundaries' candidates and what the steps read: the input's frames and the series of
/// `cache` that `resolved` selects.
fn inputs<'a>(
    steps: &[Step],
    resolved: &Resolved,
    cache: &'a Cache,
    metadata: &Metadata,
) -> Result<(Vec<usize>, steps::Inputs<'a>)> {
    let boundaries = steps::boundaries(steps);
    let ts = cache.timestamps_s.as_deref();
    let range = boundaries.candidates(metadata.frame_count, ts)?;
    let movement = &resolved.movement;
    let stationary = match resolved.stationary {
        Some(st) => {
            let req = st.request(&boundaries, metadata, ts)?;
            let run = cache.stationary(movement, &req);
            run.map(|r| (req, r.keyframes.as_slice(), r.backend))
        }
        None => None,
    };
    let (w, h) = (metadata.width, metadata.height);
    let at = steps::Inputs {
        frame_count: metadata.frame_count,
        timestamps_s: ts,
        range: (
            range.first().copied().unwrap_or(0),
            range.last().copied().unwrap_or(0),
        ),
        sharpness: (cache.sharpness.iter())
            .filter(|x| x.width == w && x.height == h)
            .map(|x| (x.metric, x.scores.as_slice(), x.backend))
            .collect(),
        movement_request: Some(*movement),
        movement: (cache.movement(movement)).map(|m| (m.series.values.as_slice(), m.backend)),
        stationary,
        stationary_auto: resolved.stationary_auto,
        spacing_px: resolved.spacing_px,
        positions: cache.telemetry.as_ref().map(|t| t.positions.as_slice()),
        camera: cache.telemetry.as_ref().and_then(|t| t.camera.as_deref()),
        frame_size: (w, h),
        embeddings: embeddings(
            cache,
            metadata,
            movement.analysis_width,
            similarity_model(steps),
        ),
    };
    Ok((range, at))
}

/// The embedding network of the chain's similarity step, if it names one.
fn similarity_model(steps: &[Step]) -> Option<&Path> {
    steps.iter().find_map(|s| match s {
        Step::Similarity { model, .. } => model.as_deref(),
        _ => None,
    })
}

/// The runtime the chain's similarity step asks for its network, if it names one.
fn similarity_runtime(steps: &[Step]) -> Option<crate::manifest::SegRuntime> {
    steps.iter().find_map(|s| match s {
        Step::Similarity { runtime, .. } => *runtime,
        _ => None,
    })
}

/// The embeddings in `cache` the similarity step reads (readable ones: [`EmbeddingCache::usable`]):
/// those of its `model`'s network, else the built-in descriptor's at the analysis size of
/// `analysis_width`, else at any size.
fn embeddings<'a>(
    cache: &'a Cache,
    metadata: &Metadata,
    analysis_width: u32,
    model: Option<&Path>,
) -> Option<steps::similarity::Embeddings<'a>> {
    let n = metadata.frame_count;
    let e = match model {
        Some(m) => {
            let name = crate::segment::embedding::embedder_of(m)?;
            (cache.embeddings.iter()).find(|e| e.embedder == name && e.usable(n))?
        }
        None => {
            let size = analysis::analysis_size(metadata.width, metadata.height, analysis_width);
            let ours = || {
                (cache.embeddings.iter()).find(|e| e.embedder == descriptor::NAME && e.usable(n))
            };
            (cache.embeddings(descriptor::NAME, size))
                .filter(|e| e.usable(n))
                .or_else(ours)?
        }
    };
    let frames = match &e.file {
        Some(name) => steps::similarity::Stored::File {
            dir: &e.dir,
            name,
            dim: e.dim,
            count: n,
        },
        None => steps::similarity::Stored::Hex(&e.frames),
    };
    Some(steps::similarity::Embeddings {
        embedder: &e.embedder,
        backend: e.backend,
        runtime: e.runtime,
        frames,
    })
}
