//! Command-line flags (clap derive) and their conversion into validated settings, in one place.

use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use clap::{Args, Parser, Subcommand, ValueEnum};
use keyframer::colmap::pycolmap::Engine;
use keyframer::error::{Error, Result};
use keyframer::manifest::{ExportSettings, Format, MaskSettings, SegRuntime, DEFAULT_QUALITY};
use keyframer::names::Names;
use keyframer::numbers::non_negative_seconds;
use keyframer::params::{
    BackendChoice, Derotate, FarnebackParams, Metric, MovementRequest, Statistic,
};
use keyframer::select::SelectSettings;
use keyframer::sparse::{MapperKind, Mapping, Matcher};
use keyframer::steps::defaults;
use std::path::PathBuf;

/// Turns videos and image sequences into well-chosen keyframes for 3D reconstruction.
///
/// Exit codes: 0 success; 1 usage or input error (nothing partial is written); 2 partial failure
/// (some frames or inputs could not be processed; the rest was written and the problems reported).
#[derive(Debug, Parser)]
#[command(
    name = "keyframer",
    version,
    about,
    long_about = None,
    after_help = "Exit codes: 0 success; 1 usage or input error (nothing partial is written); \
                  2 partial failure (some frames could not be decoded; the rest was written and \
                  the problems reported).\nLogs: RUST_LOG=debug for more detail on stderr."
)]
pub struct Cli {
    /// No progress bars; only errors and warnings on stderr.
    #[arg(short, long, global = true)]
    pub quiet: bool,
    /// The command.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// GPU adapter, what `--backend auto` picks here and why, OpenCV version and video backends,
    /// COLMAP availability.
    Info(InfoArgs),
    /// Frame count, fps, resolution, duration, codec and rotation of an input.
    Probe(ProbeArgs),
    /// Analyse an input and select keyframes into a project file.
    Select(SelectArgs),
    /// Write a project's keyframes as images with a manifest (and segmentation masks).
    Export(ExportArgs),
    /// Segment one image with a model description: mask (and overlay) for trying a model.
    Segment(SegmentArgs),
    /// Apply a workflow file to many inputs (one folder each; finished inputs are skipped).
    Run(RunArgs),
    /// Workflow files: save the steps that produced a project.
    #[command(subcommand)]
    Workflow(WorkflowCommand),
    /// Per-frame sharpness scores of a video, image folder or image.
    Score(ScoreArgs),
    /// Dense Farneback flow between two images, written as a Middlebury .flo file.
    Flow(FlowArgs),
    /// Side-by-side timings of the gpu and opencv backends (ratios from one run).
    Bench(BenchArgs),
    /// COLMAP workspace from an export (images, masks, database, project.ini); --sparse runs it.
    Colmap(ColmapArgs),
    /// Reconstruction in the loop: export, COLMAP, find the breaks, add frames from the cache
    /// where the model breaks, again, until one connected model registers every keyframe.
    Reconstruct(ReconstructArgs),
    /// Evaluate a COLMAP model: registered images, reprojection error, spacing, GT pose error.
    Eval(EvalArgs),
    /// Self-contained HTML report of a project (timeline, thumbnails, steps) plus a PNG timeline.
    Report(ReportArgs),
    /// Interactive review in the browser: change any step on the cached scores and see the new
    /// selection, preview frames, add/remove keyframes, save the project or a workflow.
    Review(ReviewArgs),
}

/// `review` flags.
#[derive(Debug, Args)]
pub struct ReviewArgs {
    /// Project file written by `select` (saving from the page replaces it).
    pub project: PathBuf,
    /// An export of the project: its images, masks and overlays are shown over the frames.
    #[arg(long, value_name = "DIR")]
    pub export: Option<PathBuf>,
    /// Port on 127.0.0.1 (default: a free one).
    #[arg(long)]
    pub port: Option<u16>,
    /// Open the page in the default browser.
    #[arg(long)]
    pub open: bool,
}

/// `report` flags.
#[derive(Debug, Args)]
pub struct ReportArgs {
    /// Project file written by `select`.
    pub project: PathBuf,
    /// Output HTML page.
    #[arg(short, long)]
    pub output: PathBuf,
    /// PNG timeline (default: `<output stem>.timeline.png` beside the page).
    #[arg(long, value_name = "PNG")]
    pub timeline: Option<PathBuf>,
    /// Take thumbnails from this export folder instead of decoding the input.
    #[arg(long, value_name = "EXPORT_DIR")]
    pub export: Option<PathBuf>,
    /// A COLMAP model of the keyframes (model folder, sparse/ root or `keyframer colmap`
    /// workspace): draws the camera path coloured by spacing.
    #[arg(long, value_name = "MODEL")]
    pub model: Option<PathBuf>,
    /// At most this many keyframe thumbnails, spread evenly (0: none).
    #[arg(long, default_value_t = 60, value_name = "N")]
    pub thumbs: usize,
    /// Replace existing outputs.
    #[arg(long)]
    pub force: bool,
}

impl ReportArgs {
    /// The report settings.
    pub fn settings(&self) -> keyframer::report::ReportSettings {
        keyframer::report::ReportSettings {
            output: self.output.clone(),
            timeline: self.timeline.clone(),
            export: self.export.clone(),
            model: self.model.clone(),
            thumbs: self.thumbs,
            force: self.force,
        }
    }
}

/// `score` flags.
#[derive(Debug, Args)]
pub struct ScoreArgs {
    /// Video file, image file or image folder.
    pub input: PathBuf,
    /// Sharpness metric: tenengrad, laplacian (= laplacian-k1) or laplacian-k3.
    #[arg(long, value_parser = named::<Metric>(), hide_possible_values = true, default_value = "tenengrad")]
    pub metric: Metric,
    /// Print one JSON object instead of `index<TAB>timestamp<TAB>score` lines.
    #[arg(long)]
    pub json: bool,
    /// How the frames map to directions, as for `select`: 360° (`equirect`) frames are scored
    /// on their band |latitude| < 45° (see docs/360.md). Default: equirect when the container's
    /// spherical metadata says so, else pinhole.
    #[arg(long, value_name = "pinhole|equirect", value_parser = |v: &str| v.parse::<keyframer::equirect::Projection>())]
    pub projection: Option<keyframer::equirect::Projection>,
    /// Backend flags.
    #[command(flatten)]
    pub analysis: AnalysisArgs,
}

/// Farneback parameters (cv::calcOpticalFlowFarneback's, same meaning and defaults of OpenCV's
/// tutorial).
#[derive(Debug, Clone, Args)]
pub struct FarnebackArgs {
    /// Scale between pyramid levels, in (0, 1).
    #[arg(long, default_value_t = 0.5)]
    pub pyr_scale: f64,
    /// Pyramid levels below full resolution (0 to 32; fewer when the image gets small).
    #[arg(long, default_value_t = 3)]
    pub levels: u32,
    /// Averaging window size (1 to 1001).
    #[arg(long, default_value_t = 15)]
    pub winsize: u32,
    /// Iterations per level (1 to 100).
    #[arg(long, default_value_t = 3)]
    pub iterations: u32,
    /// Polynomial expansion neighbourhood: 5 or 7.
    #[arg(long, default_value_t = 5)]
    pub poly_n: u32,
    /// Polynomial expansion sigma (positive; OpenCV suggests 1.1 for 5, 1.5 for 7).
    #[arg(long, default_value_t = 1.2)]
    pub poly_sigma: f64,
    /// Gaussian window instead of a box (OPTFLOW_FARNEBACK_GAUSSIAN).
    #[arg(long)]
    pub gaussian: bool,
}

impl FarnebackArgs {
    /// The parameters as given (unchecked).
    pub fn params(&self) -> FarnebackParams {
        FarnebackParams {
            pyr_scale: self.pyr_scale,
            levels: self.levels,
            winsize: self.winsize,
            iterations: self.iterations,
            poly_n: self.poly_n,
            poly_sigma: self.poly_sigma,
            gaussian: self.gaussian,
        }
    }
}

/// `flow` flags.
#[derive(Debug, Args)]
pub struct FlowArgs {
    /// First image.
    pub a: PathBuf,
    /// Second image (same size).
    pub b: PathBuf,
    /// Output .flo file.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Start from this flow (.flo of the same size; OPTFLOW_USE_INITIAL_FLOW).
    #[arg(long, value_name = "FLO")]
    pub initial: Option<PathBuf>,
    /// Replace an existing output file.
    #[arg(long)]
    pub force: bool,
    /// Farneback parameters.
    #[command(flatten)]
    pub farneback: FarnebackArgs,
    /// Backend flags.
    #[command(flatten)]
    pub analysis: AnalysisArgs,
}

/// `bench` flags.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// What to time.
    #[arg(value_enum, default_value = "sharpness")]
    pub what: BenchWhat,
    /// Frames per size and backend.
    #[arg(long, default_value_t = 24)]
    pub frames: usize,
    /// sharpness, flow: strip heights (rows per invocation) to compare, e.g. 4,12,36 (default:
    /// the adapter's own choice).
    #[arg(long, value_delimiter = ',', value_parser = clap::value_parser!(u32).range(1..))]
    pub strip_rows: Vec<u32>,
    /// GPU adapter (part of its name).
    #[arg(long)]
    pub adapter: Option<String>,
    /// pipeline: folder for the generated clips (kept and re-used; made by keyframer-bench-clip,
    /// built with `cargo build --release -p keyframer-scene`) and scratch projects; review: its
    /// synthetic project.
    #[arg(long, default_value = "keyframer-bench")]
    pub dir: PathBuf,
    /// review: frames of the synthetic project (written into --dir).
    #[arg(long, default_value_t = 10_000)]
    pub review_frames: usize,
    /// pipeline: length of the 1080p30 clip in seconds.
    #[arg(long, default_value_t = 60)]
    pub seconds: u32,
    /// pipeline: frame rate of the 4K clips.
    #[arg(long, default_value_t = 5)]
    pub k4_fps: u32,
    /// pipeline: lengths of the 4K clips in minutes (peak memory must not grow with length);
    /// `--k4-minutes 0` skips them.
    #[arg(long, value_delimiter = ',', default_value = "1,4")]
    pub k4_minutes: Vec<u32>,
    /// pipeline: backends to time (`NAME-preview`: `select --preview` on backend NAME).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "gpu,opencv,opencv-preview"
    )]
    pub backends: Vec<String>,
    /// pipeline: the `select` flags of the analysis (empty: --blur --spacing 200), e.g. "--stationary --blur".
    #[arg(long, default_value = "", allow_hyphen_values = true)]
    pub select_args: String,
    /// pipeline: also measure the analysis-width / flow-stride trade-off (20 s 1080p clip).
    #[arg(long)]
    pub tradeoffs: bool,
    /// pipeline: rounds per clip, each timing the decode loops and then every backend in turn;
    /// the table shows medians and each ratio's range over the rounds (noisy machines).
    #[arg(long, default_value_t = 1)]
    pub rounds: u32,
}

impl BenchArgs {
    /// Settings of `bench pipeline`.
    pub fn pipeline_settings(&self) -> keyframer::bench_pipeline::Settings {
        keyframer::bench_pipeline::Settings {
            dir: self.dir.clone(),
            seconds: self.seconds.max(1),
            k4_fps: self.k4_fps.max(1),
            k4_minutes: self.k4_minutes.iter().copied().filter(|&m| m > 0).collect(),
            backends: self.backends.clone(),
            select_args: self
                .select_args
                .split_whitespace()
                .map(String::from)
                .collect(),
            tradeoffs: self.tradeoffs,
            rounds: self.rounds.max(1),
        }
    }
}

/// Benchmarks.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum BenchWhat {
    /// Tenengrad and Laplacian variance at 640x360, 1920x1080, 3840x2160.
    Sharpness,
    /// Farneback flow per frame pair at 320x180, 640x360, 1280x720.
    Flow,
    /// The similarity step's built-in descriptor per frame at 320x180, 640x360, 1280x720.
    Descriptor,
    /// Whole-clip analysis vs decode-only on generated 1080p and 4K clips, with peak memory.
    Pipeline,
    /// `review`'s answer to a parameter change on a synthetic project (--review-frames long):
    /// the step chain, the timeline drawing, the HTTP round trip.
    Review,
    /// ERP → pinhole views (remap, bilinear and bicubic): a 3840x1920 frame to 6 cube faces of
    /// 1024x1024.
    Remap,
}

/// Flags of analysing commands.
#[derive(Debug, Args)]
pub struct AnalysisArgs {
    /// Kernel backend.
    #[arg(long, value_parser = named::<BackendChoice>(), default_value = "auto")]
    pub backend: BackendChoice,
    /// GPU adapter to use: a case-insensitive part of its name (default: hardware first, then
    /// software; also KEYFRAMER_ADAPTER).
    #[arg(long)]
    pub adapter: Option<String>,
}

/// `info` flags.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
    /// GPU adapter to report on (part of its name).
    #[arg(long)]
    pub adapter: Option<String>,
}

/// `probe` flags.
#[derive(Debug, Args)]
pub struct ProbeArgs {
    /// Video file, image file or image folder.
    pub input: PathBuf,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Count frames by decoding the whole input instead of trusting the container.
    #[arg(long)]
    pub exact: bool,
    /// Frame rate to assume for an image folder.
    #[arg(long, value_name = "FPS")]
    pub images_fps: Option<f64>,
}

/// `select` flags.
#[derive(Debug, Args)]
pub struct SelectArgs {
    /// Video file, image file or image folder.
    pub input: PathBuf,
    /// Project file to write (an existing one for the same, unchanged input is re-used as a cache
    /// with --force, so re-selecting decodes nothing).
    #[arg(short, long, value_name = "PROJECT.json")]
    pub output: PathBuf,
    /// Frame rate to assume for an image folder (needed for --fps and times).
    #[arg(long, value_name = "FPS")]
    pub images_fps: Option<f64>,
    /// Telemetry of the flight: a DJI SRT subtitle file or a GPX track (aligned by the video's
    /// creation time). Default: the DJI SRT beside the video (same name, .SRT), or the EXIF GPS
    /// tags of an image folder's images.
    #[arg(long, value_name = "FILE")]
    pub telemetry: Option<PathBuf>,
    /// Seconds added to a frame's timestamp to find it in the telemetry (corrects a clock).
    #[arg(
        long,
        value_name = "SECONDS",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub telemetry_offset: f64,
    /// Replace an existing project file.
    #[arg(long)]
    pub force: bool,
    /// Seconds between checkpoints of a running analysis (`PROJECT.json.partial`; a run killed
    /// midway resumes from it); 0 turns them off.
    #[arg(long, value_name = "SECONDS", default_value_t = SelectSettings::CHECKPOINT_EVERY_S)]
    pub checkpoint_every: f64,
    /// Quick, coarse preview: analyse only the video's codec keyframes (decoded with
    /// `ffmpeg -skip_frame nokey`) and choose among them; frame counts in the other flags count
    /// keyframes. The project is marked as a preview and never reused as a cache.
    #[arg(long)]
    pub preview: bool,
    /// How the frames map to directions: `equirect` for 2:1 360° video (see docs/360.md).
    /// Default: equirect when the container's spherical metadata says so, else pinhole.
    #[arg(long, value_name = "pinhole|equirect", value_parser = |v: &str| v.parse::<keyframer::equirect::Projection>())]
    pub projection: Option<keyframer::equirect::Projection>,
    /// The steps' flags.
    #[command(flatten)]
    pub steps: StepArgs,
    /// Movement sampler flags.
    #[command(flatten)]
    pub movement: MovementArgs,
    /// Backend flags.
    #[command(flatten)]
    pub analysis: AnalysisArgs,
}

/// Flags of the camera-movement samplers and of how movement is measured.
#[derive(Debug, Args)]
pub struct MovementArgs {
    /// Statistic of the per-pixel flow magnitudes: median (iVS3D's code) or trimmed-mean (the
    /// paper).
    #[arg(long, value_parser = named::<Statistic>(), default_value = "median")]
    pub movement: Statistic,
    /// Fraction dropped at each end by --movement trimmed-mean.
    #[arg(long, default_value_t = defaults::TRIM)]
    pub trim: f64,
    /// Width of the analysis resolution for flow (never above the input's width). Default from
    /// `keyframer bench pipeline --tradeoffs` (see docs/benchmarks.md).
    #[arg(long, value_name = "W", default_value_t = defaults::ANALYSIS_WIDTH)]
    pub analysis_width: u32,
    /// Measure flow between frames K apart (each frame in between gets an equal share of the
    /// movement; consecutive movement only, the stationary sampler compares every frame).
    #[arg(long, value_name = "K", default_value_t = defaults::FLOW_STRIDE)]
    pub flow_stride: u32,
    /// Measure movement after subtracting the flow of the best-fitting camera rotation, so
    /// turning on the spot counts little and travel counts fully (for oblique or forward-looking
    /// cameras; over flat ground with a straight-down camera, sideways travel looks like a
    /// rotation and is discounted too).
    #[arg(long)]
    pub derotate: bool,
    /// Horizontal field of view of the camera in degrees, for --derotate and
    /// --footprint-overlap (which otherwise takes it from the telemetry's focal length).
    #[arg(long, value_name = "DEG")]
    pub hfov: Option<f64>,
    /// Farneback parameters.
    #[command(flatten)]
    pub farneback: FarnebackArgs,
}

impl MovementArgs {
    /// How movement is measured (unchecked).
    pub fn request(&self) -> MovementRequest {
        let derotate = self.derotate.then(|| Derotate {
            hfov_deg: self.hfov.unwrap_or(Derotate::DEFAULT_HFOV_DEG),
        });
        MovementRequest {
            farneback: self.farneback.params(),
            statistic: self.movement.with_trim(self.trim),
            analysis_width: self.analysis_width,
            stride: self.flow_stride,
            derotate,
            sphere: None,
        }
    }
}

/// `export` flags.
#[derive(Debug, Args)]
pub struct ExportArgs {
    /// Project file written by `select`.
    pub project: PathBuf,
    /// Output folder (must be empty or new unless --force).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Output size WxH (after the crop).
    #[arg(long, value_name = "WxH", conflicts_with = "scale")]
    pub resize: Option<String>,
    /// Scale factor for the (cropped) frame, e.g. 0.5.
    #[arg(long, value_name = "S")]
    pub scale: Option<f64>,
    /// Crop X,Y,W,H in source pixels, applied before the resize.
    #[arg(long, value_name = "X,Y,W,H")]
    pub crop: Option<String>,
    /// Image format (default: jpg for video, the original files for image folders).
    #[arg(long, value_parser = named::<Format>())]
    pub format: Option<Format>,
    /// JPEG quality, 1 to 100.
    #[arg(long, default_value_t = DEFAULT_QUALITY)]
    pub quality: u8,
    /// Write into a non-empty folder, replacing an earlier export.
    #[arg(long)]
    pub force: bool,
    /// Leave the telemetry positions out of the export: no EXIF GPS tags in the JPEGs, no
    /// positions in manifest.json (by default both are written when the project has positions).
    #[arg(long)]
    pub no_geotag: bool,
    /// 360° projects: the views to export, `cube` (6 faces), `ring:N[,PITCH]` (N views around
    /// the horizon at PITCH degrees) as a camera rig (`images/<view>/`, `rig_config.json`), or
    /// `equirect` (the frames unchanged). See docs/360.md.
    #[arg(long, value_name = "SET")]
    pub views: Option<String>,
    /// Field of view of every view in degrees.
    #[arg(long, value_name = "DEG", default_value_t = keyframer::manifest::DEFAULT_VIEW_FOV, requires = "views")]
    pub view_fov: f64,
    /// Width = height of every view in pixels.
    #[arg(long, value_name = "PX", default_value_t = keyframer::manifest::DEFAULT_VIEW_SIZE, requires = "views")]
    pub view_size: u32,
    /// Hide a cap of this radius in degrees around the nadir (the operator, the tripod) in the
    /// masks of every view that sees it.
    #[arg(long, value_name = "DEG", requires = "views")]
    pub mask_nadir: Option<f64>,
    /// Interpolation of the views.
    #[arg(long, value_name = "bilinear|bicubic", default_value = "bilinear", requires = "views", value_parser = |v: &str| v.parse::<keyframer::equirect::Interp>())]
    pub view_interp: keyframer::equirect::Interp,
    /// Segmentation masks for every exported image.
    #[command(flatten)]
    pub masks: MaskArgs,
}

/// Segmentation mask flags of `export`.
#[derive(Debug, Clone, Args)]
pub struct MaskArgs {
    /// Write a COLMAP mask (`masks/<image>.png`: hidden 0, kept 255) per exported image, made by
    /// the segmentation model this description (TOML) names.
    #[arg(long, value_name = "MODEL.toml")]
    pub masks: Option<PathBuf>,
    /// Classes to hide, comma-separated (default: the description's `hide` list).
    #[arg(long, value_name = "NAMES", value_delimiter = ',', requires = "masks")]
    pub mask_classes: Vec<String>,
    /// Grow the hidden area by this many pixels.
    #[arg(long, value_name = "PX", default_value_t = 0, requires = "masks")]
    pub mask_dilate: u32,
    /// Runtime for the network.
    #[arg(long, value_parser = named::<SegRuntime>(), default_value = "opencv", requires = "masks")]
    pub mask_backend: SegRuntime,
    /// Also write colour previews of the classes under `overlays/`.
    #[arg(long, requires = "masks")]
    pub mask_overlay: bool,
}

impl MaskArgs {
    /// The masks' settings, when `--masks` is given.
    pub fn settings(&self) -> Option<MaskSettings> {
        self.masks.as_ref().map(|model| MaskSettings {
            model: model.clone(),
            classes: self.mask_classes.clone(),
            dilate: self.mask_dilate,
            backend: self.mask_backend,
            overlay: self.mask_overlay,
        })
    }
}

/// `segment` flags.
#[derive(Debug, Args)]
pub struct SegmentArgs {
    /// Image to segment.
    pub image: PathBuf,
    /// Model description (TOML).
    #[arg(long, value_name = "MODEL.toml")]
    pub model: PathBuf,
    /// Mask output (PNG: hidden 0, kept 255, the image's size).
    #[arg(short, long, value_name = "MASK.png")]
    pub output: PathBuf,
    /// Colour preview of the classes.
    #[arg(long, value_name = "IMAGE")]
    pub overlay: Option<PathBuf>,
    /// Classes to hide, comma-separated (default: the description's `hide` list).
    #[arg(long, value_name = "NAMES", value_delimiter = ',')]
    pub classes: Vec<String>,
    /// Grow the hidden area by this many pixels.
    #[arg(long, value_name = "PX", default_value_t = 0)]
    pub dilate: u32,
    /// Runtime for the network.
    #[arg(long, value_parser = named::<SegRuntime>(), default_value = "opencv")]
    pub backend: SegRuntime,
    /// Replace existing output files.
    #[arg(long)]
    pub force: bool,
}

impl SegmentArgs {
    /// Validated settings.
    pub fn settings(&self) -> MaskSettings {
        MaskSettings {
            model: self.model.clone(),
            classes: self.classes.clone(),
            dilate: self.dilate,
            backend: self.backend,
            overlay: self.overlay.is_some(),
        }
    }
}

/// `run` flags.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Workflow file (TOML).
    pub workflow: PathBuf,
    /// Videos, image folders or images.
    #[arg(required_unless_present = "inputs_from")]
    pub inputs: Vec<PathBuf>,
    /// Also read inputs from this file, one path per line (blank lines and # comments ignored).
    #[arg(long, value_name = "FILE")]
    pub inputs_from: Option<PathBuf>,
    /// Output folder: one sub-folder per input (project.json, one folder per export, done.json).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Redo inputs that are already done.
    #[arg(long)]
    pub force: bool,
    /// Inputs processed at the same time.
    #[arg(long, short = 'j', default_value_t = 1)]
    pub jobs: usize,
    /// Handle only shard I of N (0-based): inputs at positions i mod N == I of the list sorted by
    /// path. For Slurm job arrays: --shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT.
    #[arg(long, value_name = "I/N")]
    pub shard: Option<keyframer::batch::Shard>,
    /// Print the summary as JSON on stdout (the table goes to stderr either way).
    #[arg(long)]
    pub json: bool,
}

impl RunArgs {
    /// The inputs from the command line and --inputs-from, in order.
    pub fn all_inputs(&self) -> Result<Vec<PathBuf>> {
        let mut v = self.inputs.clone();
        if let Some(f) = &self.inputs_from {
            let text = std::fs::read_to_string(f).map_err(|e| Error::io(f, e))?;
            v.extend(
                text.lines()
                    .map(str::trim)
                    .filter(|l| !l.is_empty() && !l.starts_with('#'))
                    .map(PathBuf::from),
            );
        }
        Ok(v)
    }
}

/// `workflow` subcommands.
#[derive(Debug, Subcommand)]
pub enum WorkflowCommand {
    /// Write the workflow that reproduces a project's selection (and the given exports, and its
    /// `reconstruct` loop as a `[[reconstruct]]` table).
    Save(WorkflowSaveArgs),
    /// Check a workflow file without running it.
    Check(WorkflowCheckArgs),
}

/// `workflow save` flags.
#[derive(Debug, Args)]
pub struct WorkflowSaveArgs {
    /// Project file.
    pub project: PathBuf,
    /// Workflow file to write.
    #[arg(short, long, value_name = "WORKFLOW.toml")]
    pub output: PathBuf,
    /// Export folders of this project whose settings become `[[export]]` steps.
    #[arg(long, value_name = "DIR")]
    pub export: Vec<PathBuf>,
    /// Replace an existing file.
    #[arg(long)]
    pub force: bool,
}

/// `workflow check` flags.
#[derive(Debug, Args)]
pub struct WorkflowCheckArgs {
    /// Workflow file.
    pub workflow: PathBuf,
}

/// The steps' flags, built from each step's [`keyframer::steps::Flag`]s.
#[derive(Debug, Clone)]
pub struct StepArgs(pub keyframer::steps::FlagValues);

impl clap::FromArgMatches for StepArgs {
    fn from_arg_matches(m: &clap::ArgMatches) -> std::result::Result<Self, clap::Error> {
        let mut v = keyframer::steps::FlagValues::default();
        for f in keyframer::steps::flags() {
            let id = f.long;
            if f.value_name.is_none() {
                if m.get_flag(id) {
                    v.set(f.long, Vec::new());
                }
            } else if let Some(values) = m.get_many::<String>(id) {
                v.set(f.long, values.cloned().collect());
            }
        }
        Ok(StepArgs(v))
    }

    fn update_from_arg_matches(
        &mut self,
        m: &clap::ArgMatches,
    ) -> std::result::Result<(), clap::Error> {
        *self = Self::from_arg_matches(m)?;
        Ok(())
    }
}

impl clap::Args for StepArgs {
    fn augment_args(cmd: clap::Command) -> clap::Command {
        keyframer::steps::flags().fold(cmd, |cmd, f| cmd.arg(step_arg(f)))
    }

    fn augment_args_for_update(cmd: clap::Command) -> clap::Command {
        Self::augment_args(cmd)
    }
}

/// One step flag as a clap argument.
fn step_arg(f: &keyframer::steps::Flag) -> clap::Arg {
    let arg = clap::Arg::new(f.long).long(f.long).help(f.help);
    let Some(name) = f.value_name else {
        return arg.action(clap::ArgAction::SetTrue);
    };
    // Negative numbers are values (`--geo-area-buffer -5`), not flags.
    let mut arg = arg.value_name(name).allow_negative_numbers(true);
    if let Some(d) = f.default {
        arg = arg.default_value(d);
    }
    if let Some(other) = f.conflicts {
        arg = arg.conflicts_with(other);
    }
    if f.list {
        arg = arg.value_delimiter(',').action(clap::ArgAction::Append);
    }
    let choices = (f.choices)();
    if !choices.is_empty() {
        let values = choices.iter().map(|(v, h)| PossibleValue::new(*v).help(*h));
        return arg.value_parser(PossibleValuesParser::new(values));
    }
    match f.check {
        Some(check) => arg.value_parser(move |s: &str| check(s).map(|()| s.to_string())),
        None => arg,
    }
}

/// The value parser of a flag taking the names of `T`: its possible values (with their help and
/// aliases) come from `T`'s table.
fn named<T: Names + Send + Sync>() -> impl TypedValueParser<Value = T> {
    let values = T::choices().into_iter().map(|(name, help)| {
        PossibleValue::new(name)
            .help(help)
            .aliases(T::aliases(name))
    });
    PossibleValuesParser::new(values).try_map(|name| T::from_name(&name))
}

impl SelectArgs {
    /// Validated settings.
    pub fn settings(&self, quiet: bool) -> Result<SelectSettings> {
        let mut steps = keyframer::steps::from_flags(&self.steps.0)?;
        let footprint = steps.iter_mut().find_map(|s| match s {
            keyframer::steps::Step::FootprintOverlap { hfov, .. } => Some(hfov),
            _ => None,
        });
        match (self.movement.hfov, footprint) {
            (Some(h), Some(hfov)) => *hfov = Some(h),
            (Some(_), None) if !self.movement.derotate => {
                return Err(Error::param(
                    "--hfov",
                    "the field of view is for --derotate or --footprint-overlap; give one",
                ))
            }
            _ => {}
        }
        for s in steps.iter().filter(|s| s.id() == "footprint-overlap") {
            s.validate().map_err(|e| Error::param("--hfov", e.msg))?;
        }
        let movement = self.movement.request();
        keyframer::params::check_analysis(&movement, self.images_fps, self.telemetry_offset)?;
        Ok(SelectSettings {
            input: self.input.clone(),
            output: self.output.clone(),
            steps,
            telemetry: self.telemetry.clone(),
            telemetry_offset_s: self.telemetry_offset,
            movement,
            backend: self.analysis.backend,
            adapter: self.analysis.adapter.clone(),
            images_fps: self.images_fps,
            force: self.force,
            checkpoint_every_s: non_negative_seconds(self.checkpoint_every)
                .map_err(|m| Error::param("--checkpoint-every", m))?,
            preview: self.preview,
            projection: self.projection,
            require_equirect: false,
            quiet,
        })
    }
}

/// The flag of `command` (a subcommand path like `["workflow", "save"]`) that sets the library's
/// parameter `key` (`levels`, `farneback.levels`, `masks.classes`, `quality`), as the user typed
/// it (`--levels`, `--mask-classes` for `export` and `--classes` for `segment`); None when no flag
/// sets it (the library's name is then shown as it is).
pub fn flag_for(command: &[&str], key: &str) -> Option<String> {
    use clap::CommandFactory;
    let mut cmd = Cli::command();
    for name in command {
        cmd = cmd.find_subcommand(name)?.clone();
    }
    let leaf = key.rsplit('.').next().unwrap_or(key);
    let mut ids = vec![key.replace('.', "_"), leaf.to_string()];
    if let Some(rest) = key.strip_prefix("masks.") {
        ids.insert(0, format!("mask_{rest}"));
    }
    ids.iter().find_map(|id| {
        let arg = cmd.get_arguments().find(|a| a.get_id().as_str() == id)?;
        match (arg.get_long(), arg.get_short()) {
            (Some(l), _) => Some(format!("--{l}")),
            (None, Some(c)) => Some(format!("-{c}")),
            _ => None,
        }
    })
}

/// The subcommand path of a parsed command line (`["select"]`, `["workflow", "save"]`).
pub fn command_path(m: &clap::ArgMatches) -> Vec<&str> {
    let mut path = Vec::new();
    let mut at = m;
    while let Some((name, sub)) = at.subcommand() {
        path.push(name);
        at = sub;
    }
    path
}

impl ExportArgs {
    /// Validated settings (the crop is checked against the frame later, when its size is known).
    pub fn settings(&self) -> Result<ExportSettings> {
        let mut s = ExportSettings::from_parts(
            self.resize.as_deref(),
            self.scale,
            self.crop.as_deref(),
            self.format,
            self.quality,
            self.masks.settings(),
            !self.no_geotag,
        )?;
        if let Some(set) = &self.views {
            s.views = Some(keyframer::manifest::ViewSettings::from_parts(
                set,
                self.view_fov,
                self.view_size,
                self.mask_nadir,
                self.view_interp,
            )?);
        }
        Ok(s)
    }
}

/// COLMAP's flags shared by `colmap` and `reconstruct`.
#[derive(Debug, Args)]
pub struct ColmapFlags {
    /// Feature matching strategy: sequential (video order) or exhaustive (all pairs).
    #[arg(long, value_parser = named::<Matcher>(), default_value_t = keyframer::sparse::defaults::MATCHER)]
    pub matcher: Matcher,
    /// Sequential matching: match each image with this many following images (a rig export:
    /// every view of a keyframe with every view of this many following keyframes).
    #[arg(long, default_value_t = keyframer::sparse::defaults::OVERLAP)]
    pub overlap: u32,
    /// COLMAP camera model shared by all images (SIMPLE_RADIAL, PINHOLE, OPENCV, ...).
    #[arg(long, default_value = keyframer::sparse::defaults::CAMERA_MODEL)]
    pub camera_model: String,
    /// Known intrinsics for the camera model, comma-separated in COLMAP's order (PINHOLE:
    /// `fx,fy,cx,cy`), e.g. from a synthetic scene's scene.json; the mapper then keeps them fixed.
    #[arg(long, value_name = "P1,P2,..")]
    pub camera_params: Option<String>,
    /// Maximum SIFT features per image (COLMAP's default 8192 when not given).
    #[arg(long, value_name = "N")]
    pub max_features: Option<u32>,
    /// Extra mapper option `KEY=VALUE`, passed as `--Mapper.KEY VALUE` (repeatable), e.g.
    /// `init_min_tri_angle=4` for short baselines.
    #[arg(long, value_name = "KEY=VALUE")]
    pub mapper_option: Vec<String>,
}

impl ColmapFlags {
    /// The library's options.
    pub fn options(&self) -> keyframer::sparse::SparseOptions {
        keyframer::sparse::SparseOptions {
            matcher: self.matcher,
            overlap: self.overlap,
            camera_model: self.camera_model.clone(),
            camera_params: self.camera_params.clone(),
            max_features: self.max_features,
            mapper_option: self.mapper_option.clone(),
        }
    }
}

/// `colmap` flags.
#[derive(Debug, Args)]
pub struct ColmapArgs {
    /// Export folder made by `keyframer export` (holds manifest.json).
    pub export: PathBuf,
    /// Workspace folder (default: EXPORT/colmap).
    #[arg(short, long, value_name = "WORKSPACE")]
    pub output: Option<PathBuf>,
    /// Run feature extraction, matching and the mapper (sparse model under sparse/N).
    #[arg(long)]
    pub sparse: bool,
    /// Then densify (image_undistorter, patch_match_stereo, stereo_fusion); needs a CUDA COLMAP.
    #[arg(long)]
    pub dense: bool,
    /// Then undistort the model into WORKSPACE/dataset (images/, masks/, sparse/0 in PINHOLE,
    /// transforms.json) for 3DGS and NeRF trainers; implies --sparse.
    #[arg(long)]
    pub undistort: bool,
    /// Align the model to the keyframes' positions (telemetry or EXIF GPS) with COLMAP's
    /// model_aligner: ENU metres from the first position, in WORKSPACE/georegistered (and the
    /// dataset made from it); implies --sparse.
    #[arg(long)]
    pub georegister: bool,
    /// Inlier threshold of the robust georegistration, metres.
    #[arg(long, value_name = "METRES", default_value_t = keyframer::colmap::georegister::DEFAULT_MAX_ERROR_M)]
    pub georegister_max_error: f64,
    /// COLMAP's options.
    #[command(flatten)]
    pub colmap: ColmapFlags,
    /// Which COLMAP runs the sparse stages: the colmap command, or pycolmap (found through
    /// KEYFRAMER_PYTHON, target/pycolmap beside keyframer's folder, or python3 on PATH), which
    /// maps a rig export as a rig; auto: pycolmap for a rig export when found.
    #[arg(long, value_parser = named::<Engine>(), default_value = "auto")]
    pub engine: Engine,
    /// Replace the keyframer-made content of an existing workspace.
    #[arg(long)]
    pub force: bool,
    /// Print colmap.json to stdout instead of a summary.
    #[arg(long)]
    pub json: bool,
}

impl ColmapArgs {
    /// The library's settings.
    pub fn settings(&self) -> keyframer::colmap::ColmapSettings {
        keyframer::colmap::ColmapSettings {
            export: self.export.clone(),
            output: self.output.clone(),
            sparse: self.sparse,
            dense: self.dense,
            undistort: self.undistort,
            georegister: self.georegister.then_some(self.georegister_max_error),
            options: self.colmap.options(),
            force: self.force,
            engine: self.engine,
        }
    }
}

/// `reconstruct` flags.
#[derive(Debug, Args)]
pub struct ReconstructArgs {
    /// Project file written by `select` (its keyframes start the loop; it is not changed).
    pub project: PathBuf,
    /// Workspace folder: the export of the final keyframes (images/, manifest.json), their COLMAP
    /// workspace (colmap/), their project (project.json) and the loop's state (reconstruct.json).
    #[arg(long, value_name = "WS")]
    pub out: PathBuf,
    /// Rounds of COLMAP at most (the first reconstructs the project's keyframes).
    #[arg(long, default_value_t = keyframer::sparse::defaults::MAX_ROUNDS, value_name = "N")]
    pub max_rounds: usize,
    /// Frames the loop may add in all: a count (`40`) or a percentage of the starting keyframes
    /// (`50%`).
    #[arg(long, default_value = keyframer::sparse::defaults::MAX_ADDED, value_name = "N|PCT%")]
    pub max_added: String,
    /// A link between consecutive keyframes of one model is weak when they share fewer 3D
    /// points than this.
    #[arg(long, default_value_t = keyframer::sparse::defaults::MIN_SHARED, value_name = "P")]
    pub min_shared: usize,
    /// ... or when their two-view geometry has fewer inlier matches than this.
    #[arg(long, default_value_t = keyframer::sparse::defaults::MIN_INLIERS, value_name = "N")]
    pub min_inliers: usize,
    /// Mapper: incremental (COLMAP's `mapper`) or global (`global_mapper`, recent COLMAP only).
    #[arg(long, value_parser = named::<MapperKind>(), default_value_t = keyframer::sparse::defaults::MAPPER)]
    pub mapper: MapperKind,
    /// How later rounds map: afresh, or continuing the largest model with the new images
    /// (features and matches are reused either way).
    #[arg(long, value_parser = named::<Mapping>(), default_value_t = keyframer::sparse::defaults::MAPPING)]
    pub mapping: Mapping,
    /// Which COLMAP runs the loop: pycolmap (a recent COLMAP from PyPI, which `scripts/setup.sh`
    /// installs; its incremental mapper folds far less often than COLMAP 3.8's) or the colmap
    /// command; auto takes pycolmap when it is found.
    #[arg(long, value_parser = named::<Engine>(), default_value = "auto")]
    pub engine: Engine,
    /// COLMAP's options (the loop adds `min_model_size=3`, `init_min_tri_angle=4` and
    /// `abs_pose_min_num_inliers=15` to the mapper options unless given).
    #[command(flatten)]
    pub colmap: ColmapFlags,
    /// Output size WxH of the exported images.
    #[arg(long, value_name = "WxH", conflicts_with = "scale")]
    pub resize: Option<String>,
    /// Scale factor of the exported images, e.g. 0.5.
    #[arg(long, value_name = "S")]
    pub scale: Option<f64>,
    /// JPEG quality, 1 to 100.
    #[arg(long, default_value_t = DEFAULT_QUALITY)]
    pub quality: u8,
    /// Segmentation masks for every exported image (passed to COLMAP).
    #[command(flatten)]
    pub masks: MaskArgs,
    /// Replace a workspace keyframer made for another project or with other options (a
    /// workspace of this loop is resumed without it).
    #[arg(long)]
    pub force: bool,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

impl ReconstructArgs {
    /// The library's settings.
    pub fn settings(&self) -> Result<keyframer::reconstruct::ReconstructSettings> {
        use keyframer::reconstruct::ReconstructSettings;
        use keyframer::sparse::{Budget, Limits, Options};
        let export = ExportSettings::from_parts(
            self.resize.as_deref(),
            self.scale,
            None,
            None,
            self.quality,
            self.masks.settings(),
            true,
        )?;
        Ok(ReconstructSettings {
            project: self.project.clone(),
            out: self.out.clone(),
            force: self.force,
            options: Options {
                max_rounds: self.max_rounds,
                max_added: Budget::parse(&self.max_added)?,
                limits: Limits {
                    min_shared: self.min_shared,
                    min_inliers: self.min_inliers,
                },
                colmap: self.colmap.options(),
                mapper: self.mapper,
                mapping: self.mapping,
                engine: self.engine,
                export,
            },
        })
    }
}

/// `eval` flags.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// A COLMAP model folder (.bin or .txt), a `sparse/` folder of models 0/ 1/ …, or a workspace
    /// made by `keyframer colmap`.
    pub model: PathBuf,
    /// The export folder (its manifest orders images by frame and gives their timestamps);
    /// default: the workspace's export.
    #[arg(long, value_name = "EXPORT_DIR")]
    pub export: Option<PathBuf>,
    /// Ground-truth camera-to-world poses in TUM format (`t tx ty tz qx qy qz qw`).
    #[arg(long, value_name = "POSES")]
    pub gt: Option<PathBuf>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

impl EvalArgs {
    /// The library's settings.
    pub fn settings(&self) -> keyframer::eval::EvalSettings {
        keyframer::eval::EvalSettings {
            model: self.model.clone(),
            export: self.export.clone(),
            gt: self.gt.clone(),
        }
    }
}
