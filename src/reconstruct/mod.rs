//! `keyframer reconstruct`: reconstruction in the loop. Exports a project's keyframes, runs
//! COLMAP, finds where the result is broken ([`breaks`]), adds frames from the project's cache
//! where it is ([`repair`]) and runs again, extending the same COLMAP workspace, until the
//! keyframes form one connected model, only true breaks remain, or the budget is spent.
//! Guarantees: the workspace holds a normal export of the final keyframes (`images/`,
//! `manifest.json`), its COLMAP workspace (`colmap/`), the project of the final keyframes
//! (`project.json`) and the state file (`reconstruct.json`, rewritten atomically at every
//! round's start and end); a killed run resumes at the round it was in (its own workspace needs
//! no `--force`); a finished one is left as it is; the input is checked against the project's
//! fingerprint before anything is written.

pub mod breaks;
pub mod db;
pub mod epipolar;
pub mod priors;
pub mod repair;

use crate::colmap::extend::{self, Trial};
use crate::colmap::{model, ColmapSettings, Record};
use crate::error::{Error, Result};
use crate::fsutil;
use crate::manifest::Manifest;
use crate::output::Inputs;
use crate::project::Project;
use crate::sparse::{check, Budget, MapperKind, Mapping, Options};
use breaks::{Break, Observed};
use repair::{Choice, Frames, Measure};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The state file in the workspace.
pub const STATE: &str = "reconstruct.json";
/// The project of the final keyframes, in the workspace.
pub const PROJECT: &str = "project.json";
/// The COLMAP workspace inside the workspace.
pub const COLMAP_DIR: &str = "colmap";

/// What `reconstruct` does; each field is the flag of the same name (`keyframer reconstruct
/// --help` says what it does).
#[derive(Debug, Clone)]
pub struct ReconstructSettings {
    /// The project whose keyframes start the loop.
    pub project: PathBuf,
    /// The workspace folder.
    pub out: PathBuf,
    /// The options that decide the result (recorded in the state file).
    pub options: Options,
    /// Replace a workspace keyframer made for another project or other options.
    pub force: bool,
}

/// The loop's own constants.
pub mod defaults {
    /// The mapper options the loop adds unless given: keep models of 3 images and more (COLMAP
    /// discards smaller ones, and a sparse start's models tell where it breaks); start a model
    /// from a pair seen 4° apart rather than 16° (video keyframes have short baselines: with
    /// 16° a survey's straight legs found no initial pair and stayed unregistered); register an
    /// image on 15 inlier 2D-3D matches rather than 30 (sparse keyframes share few points
    /// with the model beyond their neighbour: seed 1's survey split at a link of 175 two-view
    /// inliers, one model at 15; docs/reconstruct.md).
    pub const MAPPER_OPTIONS: [(&str, &str); 3] = [
        ("min_model_size", "3"),
        ("init_min_tri_angle", "4"),
        ("abs_pose_min_num_inliers", "15"),
    ];
    /// Mappings tried with other random seeds when a round's mapping mis-assembles a link whose
    /// pair matches well (a round's database mapped with seeds 0-4 gave its fragments folded or
    /// right, seed by seed: docs/reconstruct.md).
    pub const REMAP_SEEDS: u64 = 3;
    /// Mappings tried from other initial pairs when a round's mapping is whole but mis-assembled
    /// (on the experiment's mis-assembled databases, one of the 3 calibrated pairs with the most
    /// inliers gave a correct model each time: docs/reconstruct.md).
    pub const REMAP_TRIES: usize = 3;
    /// Inlier matches under which a broken link is thin ([`super::Break::thin`]): COLMAP's
    /// `init_min_num_inliers` default, the count its mapper needs to start a model from a pair
    /// (`--mapper-option init_min_num_inliers=N` moves both).
    pub const THIN_INLIERS: usize = 100;
}

/// The state file: the loop's rounds so far.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct State {
    /// Always "keyframer".
    pub tool: String,
    /// keyframer version.
    pub tool_version: String,
    /// The project that started the loop (absolute).
    pub project: PathBuf,
    /// Its keyframes.
    pub start: Vec<usize>,
    /// The options.
    pub options: Options,
    /// COLMAP's version line (`pycolmap X` when pycolmap runs the loop).
    pub colmap_version: String,
    /// The pycolmap that runs the sparse stages (None: the `colmap` command, as in workspaces
    /// made before the engine was chosen).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pycolmap: Option<crate::colmap::pycolmap::Pycolmap>,
    /// What a gap's middle is measured by.
    pub measure: Measure,
    /// The rounds, in order; the last one is still running when its `done` is false.
    pub rounds: Vec<Round>,
    /// How the loop ended (None while it runs).
    pub outcome: Option<Outcome>,
}

/// One round: a COLMAP run on a keyframe set and what it showed.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Round {
    /// 1 for the starting keyframes.
    pub round: usize,
    /// The keyframes reconstructed.
    pub keyframes: Vec<usize>,
    /// The frames new in this round (all of them in round 1).
    pub new: Vec<usize>,
    /// Keyframes registered in the largest model.
    pub registered: usize,
    /// The models, largest first by registered images: folder and keyframe ranges.
    pub models: Vec<ModelRanges>,
    /// The broken links.
    pub breaks: Vec<Break>,
    /// Frames added after this round (reconstructed in the next one).
    pub added: Vec<Added>,
    /// Breaks nothing can repair.
    pub true_breaks: Vec<TrueBreak>,
    /// The thin links among the keyframes, broken or not: consecutive pairs whose two-view
    /// geometry holds fewer inliers than a model starts from (`[from, to, inliers]`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub thin: Vec<[usize; 3]>,
    /// Breaks left for the next round's mapping (their keyframes): their pairs match well, and
    /// thin links were repaired first (see [`thin_first`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub deferred: Vec<[usize; 2]>,
    /// Seconds per COLMAP stage in this round.
    pub colmap_s: BTreeMap<String, f64>,
    /// COLMAP's CPU seconds in this round (all stages; 0 in states of earlier builds).
    #[serde(default)]
    pub colmap_cpu_s: f64,
    /// The mapping made again, when the first mis-assembled a link whose pair matches well.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub remap: Option<Remap>,
    /// Whether the round finished.
    pub done: bool,
}

/// A round mapped again because its first mapping mis-assembled a link whose pair matches well
/// (see [`Job::remap`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Remap {
    /// Broken links of the first mapping (0 in states of earlier builds).
    #[serde(default)]
    pub breaks: usize,
    /// Mis-assembled links of the first mapping.
    pub mis_assembled: usize,
    /// Mappings tried.
    pub tries: usize,
    /// The trials, in order (empty in states of earlier builds).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tried: Vec<Trial>,
    /// The frames of the initial pair of the mapping kept (None: no trial was better, the first
    /// mapping is kept, or another trial's was).
    pub kept: Option<(usize, usize)>,
    /// The mapping kept is the global mapper's (tried through pycolmap after the initial pairs).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub global: bool,
    /// The random seed of the mapping kept, when a trial with another seed was.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// Broken links of the mapping kept (the first one's when no trial was better).
    #[serde(default)]
    pub left: usize,
}

/// The mapping trials of a round: the one kept (its number, the trial and the frames of its
/// initial pair, if it had one), and the trials made.
struct Trials {
    kept: Option<Kept>,
    tried: Vec<Trial>,
}

/// The mapping trial kept: its number (1-based), what it was, and the frames of its initial
/// pair, if it had one.
#[derive(Debug, Clone, Copy)]
struct Kept {
    n: usize,
    trial: Trial,
    pair: Option<(usize, usize)>,
}

/// How many links of `found` are broken because the model is assembled wrongly.
fn mis_assembled(found: &[Break]) -> usize {
    found.iter().filter(|b| b.why.mis_assembled()).count()
}

/// A model and the keyframe ranges it holds.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ModelRanges {
    /// Folder relative to the COLMAP workspace.
    pub path: String,
    /// Keyframes it registered.
    pub registered: usize,
    /// First and last frame of each run of consecutive keyframes it holds.
    pub ranges: Vec<(usize, usize)>,
}

/// A frame the loop added.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Added {
    /// Frame index.
    pub frame: usize,
    /// Its time in seconds, when known.
    pub time_s: Option<f64>,
    /// The round whose result it repairs.
    pub round: usize,
    /// Why and how it was chosen.
    pub reason: String,
}

/// A break nothing in the cache can repair: a span of consecutive broken keyframe pairs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrueBreak {
    /// The keyframe before it.
    pub from: usize,
    /// The keyframe after it.
    pub to: usize,
    /// Their times in seconds, when known.
    pub times_s: Option<(f64, f64)>,
    /// What is broken.
    pub broken: String,
    /// Why nothing repairs it.
    pub why: String,
    /// How many consecutive keyframe pairs the span covers (older states: 1).
    #[serde(default = "one")]
    pub links: usize,
}

fn one() -> usize {
    1
}

/// How the loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Outcome {
    /// One model registers every keyframe with no weak link.
    Connected,
    /// Only true breaks are left.
    TrueBreaks,
    /// `--max-rounds` reached with breaks left.
    RoundBudget,
    /// `--max-added` reached with breaks left.
    FrameBudget,
}

impl Outcome {
    /// One word for tables (`run`'s summary).
    pub fn short(self) -> &'static str {
        match self {
            Outcome::Connected => "connected",
            Outcome::TrueBreaks => "true-breaks",
            Outcome::RoundBudget => "max-rounds",
            Outcome::FrameBudget => "max-added",
        }
    }
}

impl std::fmt::Display for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Outcome::Connected => "connected: one model registers every keyframe",
            Outcome::TrueBreaks => "stopped: only true breaks are left",
            Outcome::RoundBudget => "stopped at --max-rounds with breaks left",
            Outcome::FrameBudget => "stopped at --max-added with breaks left",
        })
    }
}

/// What `reconstruct` prints with `--json` and returns.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Summary {
    /// The workspace (absolute).
    pub workspace: PathBuf,
    /// The project of the final keyframes.
    pub project: PathBuf,
    /// How the loop ended.
    pub outcome: Outcome,
    /// False when this run found the loop finished and changed nothing.
    pub changed: bool,
    /// Rounds run.
    pub rounds: usize,
    /// Keyframes at the start.
    pub start_keyframes: usize,
    /// Keyframes at the end.
    pub final_keyframes: Vec<usize>,
    /// Keyframes of the final set registered in its largest model.
    pub registered: usize,
    /// Models of the last round.
    pub models: Vec<ModelRanges>,
    /// Frames added, with their reasons.
    pub added: Vec<Added>,
    /// Breaks left (the last round's), true breaks among them.
    pub breaks: Vec<Break>,
    /// Breaks nothing can repair.
    pub true_breaks: Vec<TrueBreak>,
    /// What a gap's middle was measured by.
    pub measure: Measure,
    /// COLMAP seconds over all rounds, per stage.
    pub colmap_s: BTreeMap<String, f64>,
    /// COLMAP seconds over all rounds.
    pub colmap_total_s: f64,
    /// COLMAP's CPU seconds over all rounds (user + system): its work, which other load on the
    /// machine does not lengthen.
    pub colmap_cpu_s: f64,
    /// COLMAP's version line.
    pub colmap_version: String,
}

/// Runs the loop (or resumes it); returns its summary. Progress on stderr unless `quiet`.
pub fn run(s: &ReconstructSettings, quiet: bool) -> Result<Summary> {
    check(&s.options)?;
    let project = Project::load(&s.project)?;
    let input = project.input_path(&s.project);
    crate::export::check_fingerprint(&project, &input)?;
    if project.keyframes.is_empty() {
        return Err(Error::input(&s.project, "the project has no keyframes"));
    }
    let ws = fsutil::absolute(&s.out);
    let project_abs = fsutil::absolute(&s.project);
    let inputs = Inputs::none()
        .with("project", &s.project)
        .with("the project's input", &input);
    let earlier = ws
        .join(STATE)
        .is_file()
        .then(|| crate::output::read_json::<State>(&ws.join(STATE), "reconstruct state"))
        .transpose()?;
    let resume = earlier.filter(|st| {
        st.project == project_abs && st.options == s.options && st.start == project.keyframes
    });
    if resume.is_none() && ws.join(STATE).is_file() && !s.force {
        return Err(Error::output(
            &ws,
            "holds a reconstruction of another project or with other options; pass --force to replace what keyframer wrote there, or choose another --out",
        ));
    }
    let recorded = resume.as_ref().map(|st| st.pycolmap.as_ref());
    let (colmap, py, line) = extend::loop_engine(s.options.engine, s.options.mapper, recorded)?;
    let dir = crate::output::prepare_dir(&ws, s.force || resume.is_some(), &[STATE], &inputs)?;
    if let Some(line) = line.filter(|_| !quiet) {
        eprintln!("{line}");
    }
    let frames_data = FrameData::of(&project);
    if !quiet && frames_data.measure == Measure::Time {
        eprintln!(
            "reconstruct: the project has no movement series (e.g. a --preview project): repairs are placed by time"
        );
    }
    let mut state = match resume {
        Some(st) => {
            if let Some(outcome) = st.outcome {
                if !quiet {
                    eprintln!(
                        "reconstruct: {} already holds this loop's result ({outcome}); nothing changed",
                        ws.display()
                    );
                }
                return Ok(summary(&st, &ws, false));
            }
            if !quiet {
                eprintln!(
                    "reconstruct: resuming {} at round {}",
                    ws.display(),
                    st.rounds.len().max(1)
                );
            }
            st
        }
        None => State {
            tool: "keyframer".into(),
            tool_version: env!("CARGO_PKG_VERSION").into(),
            project: project_abs.clone(),
            start: project.keyframes.clone(),
            options: s.options.clone(),
            colmap_version: match &py {
                Some(py) => format!("pycolmap {}", py.version),
                None => colmap.version.clone(),
            },
            pycolmap: py.clone(),
            measure: frames_data.measure,
            rounds: Vec::new(),
            outcome: None,
        },
    };
    let job = Job {
        s,
        project: &project,
        ws: &ws,
        frames: &frames_data,
        py: py.as_ref(),
        runner: crate::colmap::Runner::new(&colmap, &ws.join(COLMAP_DIR), quiet),
        quiet,
    };
    let result = job.rounds(&mut state);
    drop(dir);
    result?;
    Ok(summary(&state, &ws, true))
}

/// The per-frame numbers of the project that repairs read.
struct FrameData {
    movement: Option<Vec<f64>>,
    times: Option<Vec<f64>>,
    sharpness: Option<Vec<f64>>,
    rejected: BTreeSet<usize>,
    damaged: BTreeSet<usize>,
    textureless_below: Option<f64>,
    measure: Measure,
}

impl FrameData {
    /// The project's first movement series and the sharpness the blur step used (else the
    /// first); the frames the blur step (its parameters from the history, else the defaults)
    /// rejects among all frames of the sampled range.
    fn of(p: &Project) -> FrameData {
        let n = p.metadata.frame_count;
        let movement = p
            .cache
            .movement
            .first()
            .map(|m| m.series.values.clone())
            .filter(|v| v.len() == n);
        let blur = blur_params(p);
        let series = p
            .cache
            .sharpness
            .iter()
            .find(|s| s.metric == blur.metric)
            .or(p.cache.sharpness.first())
            .map(|s| s.scores.clone())
            .filter(|v| v.len() == n);
        let (lo, hi) = range_of(p);
        let mut rejected = BTreeSet::new();
        let mut textureless_below = None;
        if let Some(scores) = &series {
            let all: Vec<usize> = (lo..=hi).collect();
            if let Ok(kept) = crate::steps::blur(&all, scores, &blur, lo, hi) {
                let kept: BTreeSet<usize> = kept.into_iter().collect();
                rejected = all.into_iter().filter(|i| !kept.contains(i)).collect();
            }
            textureless_below = repair::median(scores, lo, hi).map(|m| m * repair::TEXTURELESS);
        }
        let measure = if movement.is_some() {
            Measure::Movement
        } else {
            Measure::Time
        };
        FrameData {
            movement,
            times: p.cache.timestamps_s.clone().filter(|t| t.len() == n),
            sharpness: series,
            rejected,
            damaged: p.damaged_frames.iter().copied().collect(),
            textureless_below,
            measure,
        }
    }

    fn frames(&self) -> Frames<'_> {
        Frames {
            movement: self.movement.as_deref(),
            times: self.times.as_deref(),
            sharpness: self.sharpness.as_deref(),
            rejected: self.rejected.clone(),
            damaged: self.damaged.clone(),
            textureless_below: self.textureless_below,
        }
    }

    fn time(&self, frame: usize) -> Option<f64> {
        self.times.as_ref().and_then(|t| t.get(frame).copied())
    }
}

/// The blur step's parameters from the project's history (filter mode), else the defaults.
fn blur_params(p: &Project) -> crate::steps::BlurParams {
    use crate::steps::{defaults, BlurMode, BlurParams};
    let mut b = BlurParams {
        metric: crate::params::Metric::Tenengrad,
        window: defaults::BLUR_WINDOW,
        ratio: defaults::BLUR_RATIO,
        mode: BlurMode::Filter,
    };
    for e in &p.history {
        if let crate::steps::Applied::Blur {
            metric,
            ratio,
            window,
            ..
        } = &e.applied
        {
            b.metric = metric.unwrap_or(b.metric);
            b.ratio = ratio.unwrap_or(b.ratio);
            b.window = window.unwrap_or(b.window);
        }
    }
    b
}

/// The sampled frame range of a project (its keyframes' span when the boundaries are open).
fn range_of(p: &Project) -> (usize, usize) {
    let n = p.metadata.frame_count.max(1);
    (0, n - 1)
}

/// One run of the loop.
struct Job<'a> {
    s: &'a ReconstructSettings,
    project: &'a Project,
    ws: &'a Path,
    frames: &'a FrameData,
    /// The pycolmap that runs the sparse stages (None: the `colmap` command).
    py: Option<&'a crate::colmap::pycolmap::Pycolmap>,
    /// Runs every round's stages and mapping trials (one pycolmap process for the loop).
    runner: crate::colmap::Runner,
    quiet: bool,
}

impl Job<'_> {
    /// The telemetry of `keys` (empty when the project has none).
    fn priors(&self, keys: &[usize]) -> Vec<priors::Prior> {
        let Some(t) = &self.project.cache.telemetry else {
            return Vec::new();
        };
        let positions: Vec<_> = keys
            .iter()
            .map(|&f| t.positions.get(f).and_then(Option::as_ref))
            .collect();
        priors::of_positions(&positions)
    }

    fn save(&self, state: &State) -> Result<()> {
        fsutil::write_json(&self.ws.join(STATE), state)
    }

    /// Runs rounds until the loop ends; the state is saved at every round's start and end.
    fn rounds(&self, state: &mut State) -> Result<()> {
        loop {
            let (keys, new) = match state.rounds.last() {
                None => (state.start.clone(), state.start.clone()),
                Some(r) if !r.done => (r.keyframes.clone(), r.new.clone()),
                Some(r) => {
                    let new: Vec<usize> = r.added.iter().map(|a| a.frame).collect();
                    let keys: BTreeSet<usize> = r.keyframes.iter().chain(&new).copied().collect();
                    (keys.into_iter().collect(), new)
                }
            };
            if state.rounds.last().is_none_or(|r| r.done) {
                state.rounds.push(Round {
                    round: state.rounds.len() + 1,
                    keyframes: keys.clone(),
                    new: new.clone(),
                    registered: 0,
                    models: Vec::new(),
                    breaks: Vec::new(),
                    added: Vec::new(),
                    true_breaks: Vec::new(),
                    thin: Vec::new(),
                    deferred: Vec::new(),
                    colmap_s: BTreeMap::new(),
                    colmap_cpu_s: 0.0,
                    remap: None,
                    done: false,
                });
                self.save(state)?;
            }
            let index = state.rounds.len() - 1;
            let first = index == 0;
            let round = self.round(state, &keys, &new, first)?;
            let outcome = self.decide(state, round)?;
            self.save(state)?;
            if let Some(o) = outcome {
                state.outcome = Some(o);
                self.write_project(state)?;
                self.save(state)?;
                return Ok(());
            }
        }
    }

    /// Exports `keys`, runs COLMAP (the first round makes the workspace, later ones add `new`)
    /// and reads what it made.
    fn round(&self, state: &State, keys: &[usize], new: &[usize], first: bool) -> Result<Round> {
        let o = &self.s.options;
        let n = state.rounds.len();
        let manifest = self.export(keys)?;
        let by_frame: BTreeMap<usize, &str> = manifest
            .frames
            .iter()
            .map(|f| (f.index, f.file.as_str()))
            .collect();
        let keys: Vec<usize> = by_frame.keys().copied().collect();
        let cws = self.ws.join(COLMAP_DIR);
        let mut options = o.colmap.clone();
        for (key, value) in defaults::MAPPER_OPTIONS {
            let given =
                |m: &String| m.trim().trim_start_matches("Mapper.").split('=').next() == Some(key);
            if !o.colmap.mapper_option.iter().any(given) {
                options.mapper_option.push(format!("{key}={value}"));
            }
        }
        let cs = ColmapSettings {
            export: self.ws.to_path_buf(),
            output: Some(cws.clone()),
            sparse: true,
            dense: false,
            undistort: false,
            georegister: None,
            options,
            force: true,
            // Unused: the rounds run through `self.py` (the engine resolved once for the loop).
            engine: crate::colmap::pycolmap::Engine::Colmap,
        };
        let earlier = crate::colmap::read_record(&cws).ok();
        let extend_it = !first && earlier.is_some();
        let before = match (&earlier, extend_it) {
            (Some(r), true) => r.stages.len(),
            _ => 0,
        };
        let names: Vec<String> = new
            .iter()
            .filter_map(|f| by_frame.get(f).map(|s| s.to_string()))
            .collect();
        let runner = &self.runner;
        let mut rec = extend::round(
            runner,
            &cs,
            o.mapper,
            o.mapping,
            extend_it.then_some(names.as_slice()),
            self.py,
        )?;
        let priors = self.priors(&keys);
        let mut obs = observe(&cws, &rec, &keys, &by_frame, &priors)?;
        let mut found = breaks::find(&keys, &obs, o.limits);
        let fresh = first || o.mapping == Mapping::Fresh;
        let mut remap = None;
        // A link mis-assembled although its pair matches well is the mapping's failure, which
        // another mapping of the same database may not repeat: the round is mapped again before
        // frames are added. Thin links (too few inliers) need frames whatever the mapping, and
        // so, measured, did the splits and unregistered keyframes beside them. A first round
        // with thin links leaves its well-matched breaks to the next mapping anyway
        // ([`thin_first`]): no trial then.
        let min = self.thin_inliers();
        let folded = found.iter().any(|b| b.why.mis_assembled() && !b.thin(min));
        // The thin links come from the database's two-view geometries, which no mapping changes.
        let thin: Vec<[usize; 3]> = keys
            .windows(2)
            .zip(&obs.inliers)
            .filter_map(|(w, n)| n.filter(|&n| n < min).map(|n| [w[0], w[1], n]))
            .collect();
        let waits = thin_first_round(n, o.max_rounds) && !thin.is_empty();
        if fresh && o.mapper == MapperKind::Incremental && folded && !waits {
            let Trials { kept, tried } =
                self.remap(runner, &cs, &keys, &by_frame, &priors, &found)?;
            rec = extend::end_trials(&cws, tried.len(), kept.map(|k| k.n))?;
            let (first_breaks, first_mis_assembled) = (found.len(), mis_assembled(&found));
            if kept.is_some() {
                obs = observe(&cws, &rec, &keys, &by_frame, &priors)?;
                found = breaks::find(&keys, &obs, o.limits);
            }
            remap = Some(Remap {
                breaks: first_breaks,
                mis_assembled: first_mis_assembled,
                tries: tried.len(),
                tried,
                kept: kept.and_then(|k| k.pair),
                global: kept.is_some_and(|k| k.trial == Trial::Global),
                seed: kept.and_then(|k| match k.trial {
                    Trial::Seed(s) => Some(s),
                    _ => None,
                }),
                left: found.len(),
            });
        }
        let mut colmap_s = BTreeMap::new();
        for st in rec.stages.iter().skip(before) {
            *colmap_s.entry(st.stage.clone()).or_insert(0.0) += st.seconds;
        }
        let colmap_cpu_s = rec.stages.iter().skip(before).map(|st| st.cpu_s).sum();
        let ranges = breaks::ranges(&keys, &obs);
        let mut models: Vec<ModelRanges> = obs
            .models
            .iter()
            .zip(ranges)
            .map(|(path, ranges)| ModelRanges {
                path: path.clone(),
                registered: obs
                    .model_of
                    .iter()
                    .filter(|m| m.and_then(|m| obs.models.get(m)) == Some(path))
                    .count(),
                ranges,
            })
            .collect();
        // A model holding only keyframes a larger one holds too (COLMAP may register an image
        // in two models) tells nothing: it is left out.
        models.retain(|m| m.registered > 0);
        models.sort_by_key(|m| std::cmp::Reverse(m.registered));
        Ok(Round {
            round: n,
            keyframes: keys.clone(),
            new: new.to_vec(),
            registered: models.first().map_or(0, |m| m.registered),
            models,
            breaks: found,
            added: Vec::new(),
            true_breaks: Vec::new(),
            thin,
            deferred: Vec::new(),
            colmap_s,
            colmap_cpu_s,
            remap,
            done: false,
        })
    }

    /// Maps the round's database again, because its mapping broke links (`found`), one of them
    /// mis-assembled between well-matched keyframes: by `runner` (the loop's), with the
    /// incremental mapper seeded otherwise ([`defaults::REMAP_SEEDS`] seeds); when every break
    /// is a mis-assembly (the model whole, its shape wrong), then from other initial pairs (the
    /// calibrated two-view geometries with the most inliers, [`defaults::REMAP_TRIES`] at most)
    /// and, through pycolmap, with the global mapper. Stops at the first trial without any
    /// break. Returns the trial that judged best, if one beats the first mapping (fewer breaks,
    /// then fewer mis-assembled links), with the frames of its initial pair if it had one; and
    /// the trials made.
    fn remap(
        &self,
        runner: &crate::colmap::Runner,
        cs: &ColmapSettings,
        keys: &[usize],
        by_frame: &BTreeMap<usize, &str>,
        priors: &[priors::Prior],
        found: &[Break],
    ) -> Result<Trials> {
        let cws = self.ws.join(COLMAP_DIR);
        let frame_of: BTreeMap<&str, usize> = by_frame.iter().map(|(f, n)| (*n, *f)).collect();
        let names: Vec<String> = by_frame.values().map(|n| n.to_string()).collect();
        let only_shape = mis_assembled(found) == found.len();
        let frames = |p: &db::Pair| {
            let (na, nb) = &p.names;
            (
                frame_of.get(na.as_str()).copied().unwrap_or(0),
                frame_of.get(nb.as_str()).copied().unwrap_or(0),
            )
        };
        let mut trials: Vec<(Trial, Option<(usize, usize)>)> = (1..=defaults::REMAP_SEEDS)
            .map(|s| (Trial::Seed(s), None))
            .collect();
        if only_shape {
            let candidates = db::calibrated_pairs(&cws.join("database.db"), &names)?;
            let pairs = candidates.iter().take(defaults::REMAP_TRIES);
            trials.extend(pairs.map(|p| (Trial::Init(p.ids.0, p.ids.1), Some(frames(p)))));
            if self.py.is_some() {
                trials.push((Trial::Global, None));
            }
        }
        // Fewer breaks to repair first (each costs frames), then fewer mis-assembled links.
        let score = |b: &[Break]| (b.len(), mis_assembled(b));
        let mut best_score = score(found);
        let mut out = Trials {
            kept: None,
            tried: Vec::new(),
        };
        for (trial, pair) in trials {
            out.tried.push(trial);
            let n = out.tried.len();
            let made = extend::remap_trial(runner, cs, n, trial, self.py)?;
            let obs = observe(&cws, &made, keys, by_frame, priors)?;
            let got = score(&breaks::find(keys, &obs, self.s.options.limits));
            if got < best_score {
                best_score = got;
                out.kept = Some(Kept { n, trial, pair });
            }
            if got.0 == 0 {
                break;
            }
        }
        Ok(out)
    }

    /// Records `round` as the state's last and chooses the repairs; returns the outcome when the
    /// loop ends here.
    fn decide(&self, state: &mut State, mut round: Round) -> Result<Option<Outcome>> {
        let o = &self.s.options;
        let connected = round.breaks.is_empty()
            && round.models.len() == 1
            && round.registered == round.keyframes.len();
        let frames = self.frames.frames();
        let thin = self.thin_inliers();
        let added = |frame: usize, reason: String| Added {
            frame,
            time_s: self.frames.time(frame),
            round: round.round,
            reason,
        };
        let mut repairs: Vec<Repair> = Vec::new();
        let mut unrepairable: Vec<(Break, String)> = Vec::new();
        if !connected {
            for b in &round.breaks {
                match repair::choose(b.from, b.to, &frames) {
                    Choice::Frame { frame, how } => {
                        let reason =
                            format!("repairs keyframes {}–{} ({}): {how}", b.from, b.to, b.why);
                        if !repairs.iter().any(|r| r.added.frame == frame) {
                            repairs.push(Repair {
                                pair: [b.from, b.to],
                                thin: b.thin(thin),
                                added: added(frame, reason),
                            });
                        }
                    }
                    Choice::TrueBreak { why } => unrepairable.push((b.clone(), why)),
                }
            }
        }
        if !connected {
            // The thin links the mapping held this time.
            let held: Vec<Repair> = round
                .thin
                .iter()
                .filter(|[a, b, _]| !round.breaks.iter().any(|k| k.from == *a && k.to == *b))
                .filter_map(|&[a, b, n]| match repair::choose(a, b, &frames) {
                    Choice::Frame { frame, how } => Some(Repair {
                        pair: [a, b],
                        thin: true,
                        added: added(
                            frame,
                            format!(
                                "repairs keyframes {a}–{b} (a thin link: {n} two-view inliers, fewer than the {thin} a model starts from): {how}"
                            ),
                        ),
                    }),
                    Choice::TrueBreak { .. } => None,
                })
                .collect();
            round.deferred = thin_first(round.round, o.max_rounds, &mut repairs, held);
        }
        round.true_breaks = spans(unrepairable, |f| self.frames.time(f));
        let added_so_far: usize = state.rounds.iter().map(|r| r.added.len()).sum();
        let allowed = o.max_added.frames(state.start.len());
        let outcome = if connected {
            Some(Outcome::Connected)
        } else if repairs.is_empty() {
            Some(Outcome::TrueBreaks)
        } else if round.round >= o.max_rounds {
            Some(Outcome::RoundBudget)
        } else if added_so_far >= allowed {
            Some(Outcome::FrameBudget)
        } else {
            // The widest gaps first when the budget cannot repair them all.
            let width = |r: &Repair| r.pair[1] - r.pair[0];
            repairs.sort_by(|a, b| {
                width(b)
                    .cmp(&width(a))
                    .then(a.added.frame.cmp(&b.added.frame))
            });
            repairs.truncate(allowed - added_so_far);
            let mut added: Vec<Added> = repairs.into_iter().map(|r| r.added).collect();
            added.sort_by_key(|a| a.frame);
            round.added = added;
            None
        };
        round.done = true;
        self.progress(&round);
        if let Some(last) = state.rounds.last_mut() {
            *last = round;
        }
        Ok(outcome)
    }

    /// Inlier matches under which a broken link is thin: the mapper's `init_min_num_inliers`
    /// when `--mapper-option` gives it, else [`defaults::THIN_INLIERS`].
    fn thin_inliers(&self) -> usize {
        self.s
            .options
            .colmap
            .mapper_option
            .iter()
            .filter_map(|m| m.trim().trim_start_matches("Mapper.").split_once('='))
            .filter(|(k, _)| k.trim() == "init_min_num_inliers")
            .find_map(|(_, v)| v.trim().parse().ok())
            .unwrap_or(defaults::THIN_INLIERS)
    }

    /// The round's line on stderr.
    fn progress(&self, r: &Round) {
        if self.quiet {
            return;
        }
        let stages: Vec<String> = r
            .colmap_s
            .iter()
            .map(|(k, v)| format!("{k} {v:.1} s"))
            .collect();
        let remap = match &r.remap {
            Some(m) => {
                let how = match (m.kept, m.global, m.seed) {
                    (Some((a, b)), _, _) => format!("from frames {a} and {b}"),
                    (_, true, _) => "by the global mapper".to_string(),
                    (_, _, Some(s)) => format!("with random seed {s}"),
                    _ => String::new(),
                };
                let first = format!(
                    "; {} break(s) ({} mis-assembled)",
                    m.breaks, m.mis_assembled
                );
                match how.is_empty() {
                    true => format!("{first}: {} other mapping(s) did no better", m.tries),
                    false => format!("{first}: mapped again {how}, {} left", m.left),
                }
            }
            None => String::new(),
        };
        let deferred = match r.deferred.len() {
            0 => String::new(),
            n => format!(" at thin links, {n} well-matched break(s) left to the next mapping"),
        };
        eprintln!(
            "round {}: {}/{} registered, {} model(s), {} break(s), +{} frame(s){deferred}{remap}; COLMAP {}",
            r.round,
            r.registered,
            r.keyframes.len(),
            r.models.len(),
            r.breaks.len(),
            r.added.len(),
            stages.join(", ")
        );
    }

    /// Exports `keys` into the workspace (replacing only what the earlier rounds wrote).
    fn export(&self, keys: &[usize]) -> Result<Manifest> {
        let mut p = self.project.clone();
        p.keyframes = keys.to_vec();
        let target = crate::export::Target {
            out: self.ws,
            force: true,
            records: &[STATE],
            project_file: &self.ws.join(PROJECT),
        };
        crate::export::export_project(
            &p,
            &self.s.project,
            &target,
            &self.s.options.export,
            self.quiet,
        )
    }

    /// Writes the project of the final keyframes (`project.json`): the starting project with
    /// a `reconstruct` step in its history (the added frames with their reasons, the rounds,
    /// COLMAP's version and the options) when frames were added; its input path made absolute.
    fn write_project(&self, state: &State) -> Result<()> {
        let mut p = self.project.clone();
        let Some(last) = state.rounds.last() else {
            return Ok(());
        };
        p.keyframes = last.keyframes.clone();
        let added: Vec<crate::steps::AddedFrame> = state
            .rounds
            .iter()
            .flat_map(|r| r.added.iter())
            .map(|a| crate::steps::AddedFrame {
                frame: a.frame,
                round: a.round,
                reason: a.reason.clone(),
            })
            .collect();
        if !added.is_empty() {
            let step = crate::steps::Applied::Reconstruct {
                rounds: state.rounds.len(),
                added,
                colmap_version: state.colmap_version.clone(),
                options: options_as_flags(&state.options),
                settings: Some(Box::new(state.options.clone())),
            };
            p.history
                .push(crate::steps::Recorded::new(step, p.keyframes.len()));
        }
        p.input.path = self.project.input_path(&self.s.project);
        if let Some(t) = &mut p.cache.telemetry {
            if t.source.path.is_relative() {
                let base = fsutil::absolute(&self.s.project);
                if let Some(dir) = base.parent() {
                    t.source.path = dir.join(&t.source.path);
                }
            }
        }
        p.save(&self.ws.join(PROJECT), true)
    }
}

/// A frame chosen to repair a broken link.
#[derive(Debug, Clone)]
struct Repair {
    /// The broken link's keyframes.
    pair: [usize; 2],
    /// Whether the link's own matches are thin ([`Break::thin`]).
    thin: bool,
    /// The frame and why.
    added: Added,
}

/// Thin links first: when the first round is broken and has thin links (fewer inliers than a
/// model starts from), every thin link gets a frame in `repairs`, those the mapping `held` this
/// time too, and the well-matched breaks (pairs split or mis-assembled by the mapping) wait for
/// the next round's mapping, which often joins them once the thin links hold. Seed 3 of the
/// survey from every 45: 2 thin links (62 and 26 inliers) of 9, 8 breaks in round 1; the
/// 10 + 2 keyframes map whole and right, while a frame in every broken link made 18-22.
/// Later rounds repair every break: what is still broken then is the mapping's own, and
/// waiting again costs rounds (measured: docs/reconstruct.md). Nothing changes unless a round
/// after the next is left to repair what waits, and a broken link has a frame to add. Returns
/// the keyframes of the links left waiting.
fn thin_first(
    round: usize,
    max_rounds: usize,
    repairs: &mut Vec<Repair>,
    held: Vec<Repair>,
) -> Vec<[usize; 2]> {
    let any_thin = repairs.iter().any(|r| r.thin) || !held.is_empty();
    if !thin_first_round(round, max_rounds) || repairs.is_empty() || !any_thin {
        return Vec::new();
    }
    let waiting = repairs.iter().filter(|r| !r.thin).map(|r| r.pair).collect();
    repairs.retain(|r| r.thin);
    for h in held {
        if !repairs.iter().any(|r| r.added.frame == h.added.frame) {
            repairs.push(h);
        }
    }
    waiting
}

/// Whether round `round` of at most `max_rounds` repairs its thin links first ([`thin_first`]):
/// the first, when a round after the next is left to repair what waits.
fn thin_first_round(round: usize, max_rounds: usize) -> bool {
    round == 1 && round + 1 < max_rounds
}

/// The true breaks of `unrepairable` (each broken link with why nothing repairs it, in frame
/// order), consecutive links (one's later keyframe the next one's earlier) merged into one span:
/// its first and last keyframe, the keyframes left unregistered inside it named once, every
/// other reason and every distinct why once, in order.
fn spans(
    unrepairable: Vec<(Break, String)>,
    time: impl Fn(usize) -> Option<f64>,
) -> Vec<TrueBreak> {
    let mut groups: Vec<Vec<(Break, String)>> = Vec::new();
    for (b, why) in unrepairable {
        match groups.last_mut() {
            Some(g) if g.last().is_some_and(|(last, _)| last.to == b.from) => g.push((b, why)),
            _ => groups.push(vec![(b, why)]),
        }
    }
    groups
        .into_iter()
        .filter_map(|g| {
            let (from, to) = (g.first()?.0.from, g.last()?.0.to);
            let mut unregistered: BTreeSet<usize> = BTreeSet::new();
            let mut broken: Vec<String> = Vec::new();
            let mut whys: Vec<String> = Vec::new();
            for (b, why) in &g {
                match &b.why {
                    breaks::Why::Unregistered { frames } => unregistered.extend(frames),
                    other => {
                        let text = other.to_string();
                        if !broken.contains(&text) {
                            broken.push(text);
                        }
                    }
                }
                if !whys.contains(why) {
                    whys.push(why.clone());
                }
            }
            if !unregistered.is_empty() {
                let frames = unregistered.into_iter().collect();
                broken.insert(0, breaks::Why::Unregistered { frames }.to_string());
            }
            Some(TrueBreak {
                from,
                to,
                times_s: time(from).zip(time(to)),
                broken: broken.join("; "),
                why: whys.join("; "),
                links: g.len(),
            })
        })
        .collect()
}

/// The options as the flags that give them (for the project's history).
fn options_as_flags(o: &Options) -> Vec<String> {
    let mut f = vec![
        format!("--max-rounds {}", o.max_rounds),
        match o.max_added {
            Budget::Frames(n) => format!("--max-added {n}"),
            Budget::Percent(p) => format!("--max-added {p}%"),
        },
        format!("--min-shared {}", o.limits.min_shared),
        format!("--min-inliers {}", o.limits.min_inliers),
        format!("--mapper {}", o.mapper),
        format!("--mapping {}", o.mapping),
        format!("--engine {}", o.engine),
        format!("--matcher {}", o.colmap.matcher),
        format!("--overlap {}", o.colmap.overlap),
        format!("--camera-model {}", o.colmap.camera_model),
    ];
    f.extend(
        o.colmap
            .camera_params
            .iter()
            .map(|p| format!("--camera-params {p}")),
    );
    f.extend(
        o.colmap
            .max_features
            .iter()
            .map(|n| format!("--max-features {n}")),
    );
    f.extend(
        o.colmap
            .mapper_option
            .iter()
            .map(|m| format!("--mapper-option {m}")),
    );
    f
}

/// Reads the models of a round: which keyframe (position in `keys`) each registered, the 3D
/// points consecutive keyframes share, their two-view inliers from the database, how well the
/// model's poses explain those inliers, and the model against the telemetry (`priors`, by
/// keyframe position; empty without telemetry).
fn observe(
    cws: &Path,
    rec: &Record,
    keys: &[usize],
    by_frame: &BTreeMap<usize, &str>,
    priors: &[priors::Prior],
) -> Result<Observed> {
    let position: BTreeMap<&str, usize> = keys
        .iter()
        .enumerate()
        .filter_map(|(i, f)| by_frame.get(f).map(|n| (*n, i)))
        .collect();
    let pairs = keys.len().saturating_sub(1);
    let mut obs = Observed {
        model_of: vec![None; keys.len()],
        shared: vec![0; pairs],
        explained: vec![None; pairs],
        turns: vec![None; pairs],
        off_track_m: vec![None; keys.len()],
        ..Observed::default()
    };
    // Larger models first, so a keyframe registered twice counts in the larger.
    let mut order: Vec<&crate::colmap::ModelSummary> = rec.models.iter().collect();
    order.sort_by_key(|m| std::cmp::Reverse(m.registered_images));
    // Per model read: the model and the image id of each keyframe position it registered.
    let mut read: Vec<(model::Model, BTreeMap<usize, u32>)> = Vec::new();
    for summary in order {
        let (m, _) = model::read(&cws.join(&summary.path))?;
        let index = obs.models.len();
        obs.models.push(summary.path.clone());
        let mut pos_of_image: BTreeMap<u32, usize> = BTreeMap::new();
        for (id, img) in &m.images {
            if let Some(&i) = position.get(img.name.as_str()) {
                pos_of_image.insert(*id, i);
                if obs.model_of[i].is_none() {
                    obs.model_of[i] = Some(index);
                }
            }
        }
        let tracks: Vec<Vec<usize>> = m
            .points
            .values()
            .map(|p| {
                p.track
                    .iter()
                    .filter_map(|(id, _)| pos_of_image.get(id).copied())
                    .filter(|&i| obs.model_of[i] == Some(index))
                    .collect()
            })
            .collect();
        let shared = breaks::shared_points(keys.len(), tracks.iter().map(Vec::as_slice));
        for (total, s) in obs.shared.iter_mut().zip(shared) {
            *total += s;
        }
        let image_at = pos_of_image
            .into_iter()
            .filter(|(_, i)| obs.model_of[*i] == Some(index))
            .map(|(id, i)| (i, id))
            .collect();
        read.push((m, image_at));
    }
    let db = cws.join("database.db");
    let table = db::inliers(&db)?;
    obs.inliers = keys
        .windows(2)
        .map(|w| match (by_frame.get(&w[0]), by_frame.get(&w[1])) {
            (Some(a), Some(b)) => Some(db::of(&table, a, b)),
            _ => None,
        })
        .collect();
    // The pairs in one model: their images, and the matches the model must explain.
    let image = |i: usize| {
        let (m, at) = &read[obs.model_of[i]?];
        let img = m.images.get(at.get(&i)?)?;
        Some((img, m.cameras.get(&img.camera_id)?))
    };
    let linked: Vec<usize> = (0..pairs)
        .filter(|&i| obs.model_of[i].is_some() && obs.model_of[i] == obs.model_of[i + 1])
        .collect();
    let names: Vec<(String, String)> = linked
        .iter()
        .filter_map(|&i| {
            Some((
                by_frame.get(&keys[i])?.to_string(),
                by_frame.get(&keys[i + 1])?.to_string(),
            ))
        })
        .collect();
    let matches = if names.len() == linked.len() {
        db::inlier_points(&db, &names)?
    } else {
        Vec::new()
    };
    for (k, &i) in linked.iter().enumerate() {
        let (Some(a), Some(b)) = (image(i), image(i + 1)) else {
            continue;
        };
        if let Some(m) = matches.get(k).filter(|m| !m.is_empty()) {
            obs.explained[i] = epipolar::agreement(a, b, m).map(|g| g.fraction());
        }
        let (pa, pb) = (priors.get(i).copied(), priors.get(i + 1).copied());
        if let (Some(ya), Some(yb)) = (pa.and_then(|p| p.yaw_pitch), pb.and_then(|p| p.yaw_pitch)) {
            let ra = crate::colmap::align::quat_to_mat(a.0.qvec);
            let rb = crate::colmap::align::quat_to_mat(b.0.qvec);
            obs.turns[i] = Some((
                priors::model_turn_deg(&ra, &rb),
                priors::telemetry_turn_deg(ya, yb),
            ));
        }
    }
    if priors.len() == keys.len() {
        obs.path_m = priors::path_m(priors);
        for index in 0..read.len() {
            let centres: Vec<_> = (0..keys.len())
                .map(|i| {
                    (obs.model_of[i] == Some(index))
                        .then(|| image(i).map(|(img, _)| img.centre()))
                        .flatten()
                })
                .collect();
            for (i, off) in priors::off_track_m(&centres, priors)
                .into_iter()
                .enumerate()
            {
                if off.is_some() {
                    obs.off_track_m[i] = off;
                }
            }
        }
    }
    Ok(obs)
}

/// The summary of a state.
fn summary(st: &State, ws: &Path, changed: bool) -> Summary {
    let last = st.rounds.last();
    let mut colmap_s: BTreeMap<String, f64> = BTreeMap::new();
    for r in &st.rounds {
        for (k, v) in &r.colmap_s {
            *colmap_s.entry(k.clone()).or_insert(0.0) += v;
        }
    }
    Summary {
        workspace: ws.to_path_buf(),
        project: ws.join(PROJECT),
        outcome: st.outcome.unwrap_or(Outcome::RoundBudget),
        changed,
        rounds: st.rounds.len(),
        start_keyframes: st.start.len(),
        final_keyframes: last.map(|r| r.keyframes.clone()).unwrap_or_default(),
        registered: last.map_or(0, |r| r.registered),
        models: last.map(|r| r.models.clone()).unwrap_or_default(),
        added: st.rounds.iter().flat_map(|r| r.added.clone()).collect(),
        breaks: last.map(|r| r.breaks.clone()).unwrap_or_default(),
        true_breaks: last.map(|r| r.true_breaks.clone()).unwrap_or_default(),
        measure: st.measure,
        colmap_total_s: colmap_s.values().sum(),
        colmap_s,
        colmap_cpu_s: st.rounds.iter().map(|r| r.colmap_cpu_s).sum(),
        colmap_version: st.colmap_version.clone(),
    }
}

/// Human-readable summary.
pub fn render(s: &Summary) -> String {
    let mut out = format!(
        "workspace: {}\nproject:   {}\noutcome:   {}{}\nrounds:    {}\nkeyframes: {} -> {} ({} added), {} registered in the largest of {} model(s)\n",
        s.workspace.display(),
        s.project.display(),
        s.outcome,
        if s.changed { "" } else { " (nothing changed)" },
        s.rounds,
        s.start_keyframes,
        s.final_keyframes.len(),
        s.added.len(),
        s.registered,
        s.models.len()
    );
    for m in &s.models {
        let ranges: Vec<String> = m.ranges.iter().map(|(a, b)| format!("{a}–{b}")).collect();
        out += &format!(
            "model:     {} ({} keyframes): frames {}\n",
            m.path,
            m.registered,
            ranges.join(", ")
        );
    }
    for a in &s.added {
        out += &format!(
            "added:     frame {} (after round {}): {}\n",
            a.frame, a.round, a.reason
        );
    }
    for b in &s.true_breaks {
        let times = b
            .times_s
            .map(|(x, y)| format!(" ({x:.2} s – {y:.2} s)"))
            .unwrap_or_default();
        out += &format!(
            "break:     frames {}–{}{times}: {}; {}\n",
            b.from, b.to, b.broken, b.why
        );
    }
    let stages: Vec<String> = s
        .colmap_s
        .iter()
        .map(|(k, v)| format!("{k} {v:.1} s"))
        .collect();
    out += &format!(
        "colmap:    {:.1} s in all ({}), {:.1} CPU-s; {}\n",
        s.colmap_total_s,
        stages.join(", "),
        s.colmap_cpu_s,
        s.colmap_version
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn consecutive_true_breaks_merge_into_one_span() {
        use breaks::Why;
        let b = |from, to, why| Break {
            from,
            to,
            why,
            inliers: None,
        };
        let unrepairable = vec![
            (
                b(119, 135, Why::Unregistered { frames: vec![135] }),
                "only textureless frames between them".to_string(),
            ),
            (
                b(
                    135,
                    150,
                    Why::Unregistered {
                        frames: vec![135, 150],
                    },
                ),
                "only textureless frames between them".to_string(),
            ),
            (
                b(
                    150,
                    165,
                    Why::Split {
                        from_model: "sparse/0".into(),
                        to_model: "sparse/1".into(),
                    },
                ),
                "adjacent frames".to_string(),
            ),
            (
                b(165, 180, Why::Unregistered { frames: vec![165] }),
                "only textureless frames between them".to_string(),
            ),
            (
                b(300, 301, Why::FewShared { shared: 2, min: 15 }),
                "adjacent frames".to_string(),
            ),
        ];
        let spans = spans(unrepairable, |f| Some(f as f64 / 30.0));
        assert_eq!(spans.len(), 2);
        assert_eq!((spans[0].from, spans[0].to, spans[0].links), (119, 180, 4));
        assert_eq!(spans[0].times_s, Some((119.0 / 30.0, 6.0)));
        assert_eq!(
            spans[0].broken,
            "frames 135, 150 and 165 registered in no model; in different models (sparse/0, sparse/1)"
        );
        assert_eq!(
            spans[0].why,
            "only textureless frames between them; adjacent frames"
        );
        assert_eq!((spans[1].from, spans[1].to, spans[1].links), (300, 301, 1));
        assert_eq!(spans[1].broken, "2 shared 3D points (fewer than 15)");
    }

    #[test]
    fn budgets_parse_and_scale() {
        assert_eq!(Budget::parse("40").unwrap(), Budget::Frames(40));
        assert_eq!(Budget::parse("50%").unwrap(), Budget::Percent(50.0));
        assert_eq!(Budget::Percent(50.0).frames(7), 4);
        assert_eq!(Budget::Frames(3).frames(100), 3);
        for bad in ["", "x", "-5%", "1.5"] {
            let e = Budget::parse(bad).unwrap_err();
            assert!(e.to_string().contains("max_added"), "{e}");
        }
    }

    #[test]
    fn the_first_round_repairs_thin_links_first_and_later_rounds_everything() {
        let repair = |from: usize, to: usize, thin: bool| Repair {
            pair: [from, to],
            thin,
            added: Added {
                frame: (from + to) / 2,
                time_s: None,
                round: 1,
                reason: String::new(),
            },
        };
        let mixed = || {
            vec![
                repair(0, 45, false),
                repair(90, 135, true),
                repair(180, 225, false),
                repair(225, 270, true),
            ]
        };
        let frames = |r: &[Repair]| r.iter().map(|r| r.added.frame).collect::<Vec<_>>();
        let held = || vec![repair(360, 405, true)];
        // Round 1 of 4 with both kinds: the thin links get frames, held ones too; the others
        // wait.
        let mut r = mixed();
        assert_eq!(thin_first(1, 4, &mut r, held()), vec![[0, 45], [180, 225]]);
        assert_eq!(frames(&r), vec![112, 247, 382]);
        // Later rounds, or no round left after the next: every break gets its frame, and the
        // held thin links none.
        for (round, max) in [(2, 4), (3, 4), (1, 2), (1, 1)] {
            let mut r = mixed();
            assert!(thin_first(round, max, &mut r, held()).is_empty());
            assert_eq!(frames(&r), vec![22, 112, 202, 247], "{round} of {max}");
        }
        // Only thin breaks: nothing waits, held thin links get frames too.
        let mut r = vec![repair(0, 45, true)];
        assert!(thin_first(1, 4, &mut r, held()).is_empty());
        assert_eq!(frames(&r), vec![22, 382]);
        // Only well-matched breaks, and a thin link held: the held link gets a frame, the
        // breaks wait.
        let mut r = vec![repair(0, 45, false), repair(90, 135, false)];
        assert_eq!(thin_first(1, 4, &mut r, held()), vec![[0, 45], [90, 135]]);
        assert_eq!(frames(&r), vec![382]);
        // No thin link at all: every break gets its frame.
        let mut r = vec![repair(0, 45, false), repair(90, 135, false)];
        assert!(thin_first(1, 4, &mut r, Vec::new()).is_empty());
        assert_eq!(frames(&r), vec![22, 112]);
        // Nothing broken that a frame repairs (true breaks only): nothing added for the held
        // thin links, so the loop ends there.
        let mut r = Vec::new();
        assert!(thin_first(1, 4, &mut r, held()).is_empty());
        assert!(r.is_empty());
    }

    #[test]
    fn remap_records_of_earlier_builds_still_read_and_trials_round_trip() {
        let old: Remap =
            serde_json::from_str(r#"{"mis_assembled":2,"tries":4,"kept":[270,330]}"#).unwrap();
        assert_eq!((old.breaks, old.left, old.seed), (0, 0, None));
        assert!(old.tried.is_empty() && !old.global);
        assert_eq!(old.kept, Some((270, 330)));
        let tried = vec![Trial::Seed(2), Trial::Init(3, 7), Trial::Global];
        let text = serde_json::to_string(&tried).unwrap();
        assert_eq!(text, r#"[{"seed":2},{"init":[3,7]},"global"]"#);
        assert_eq!(serde_json::from_str::<Vec<Trial>>(&text).unwrap(), tried);
    }

    #[test]
    fn a_link_is_thin_under_the_inliers_a_model_starts_from() {
        let b = |inliers| Break {
            from: 0,
            to: 45,
            why: breaks::Why::Split {
                from_model: "sparse/0".into(),
                to_model: "sparse/1".into(),
            },
            inliers,
        };
        assert!(b(Some(0)).thin(defaults::THIN_INLIERS));
        assert!(b(Some(99)).thin(100));
        assert!(!b(Some(100)).thin(100));
        // No database read: nothing is known to be thin.
        assert!(!b(None).thin(100));
        // Breaks of states written before the field read as unknown.
        let old = r#"{"from":0,"to":45,"why":{"kind":"split","from_model":"a","to_model":"b"}}"#;
        let read: Break = serde_json::from_str(old).unwrap();
        assert_eq!(read.inliers, None);
    }
}
