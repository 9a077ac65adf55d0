//! `keyframer colmap`: turns an export folder into a COLMAP workspace (linked images and masks,
//! database, a `project.ini` the GUI opens) and optionally runs COLMAP headless, one subprocess
//! per stage with its output in `logs/<stage>.log`. Guarantees: nothing is written when COLMAP is
//! missing, the export is not one, or the workspace exists without `--force` (which replaces only
//! what keyframer makes); `colmap.json` (stages, times, command lines, models) is written
//! atomically, also when a stage fails.

pub mod align;
pub mod extend;
pub mod georegister;
pub mod model;
pub mod pycolmap;
pub mod rig_pairs;
pub mod transforms;
pub mod undistort;

use crate::error::{Error, Result};
use crate::fsutil;
use crate::manifest::{Manifest, MANIFEST, MASK_DIR};
use crate::sparse::{mapper_keys, Matcher, SparseOptions};
use pycolmap::{Engine, Pycolmap};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

/// Name of the record written into every workspace.
pub const RECORD: &str = "colmap.json";
/// Environment variable naming the COLMAP binary to use instead of `colmap` on PATH.
pub const COLMAP_ENV: &str = "KEYFRAMER_COLMAP";
/// What keyframer creates in a workspace; `--force` removes exactly these.
const OURS: [&str; 15] = [
    "images",
    "masks",
    "sparse",
    extend::NEXT,
    "dense",
    undistort::DATASET,
    georegister::GEOREGISTERED,
    "logs",
    "database.db",
    "database.db-shm",
    "database.db-wal",
    "project.ini",
    RIG_PAIRS,
    pycolmap::DRIVER,
    RECORD,
];
/// The match pairs of a rig export (`matches_importer`, [`rig_pairs`]).
const RIG_PAIRS: &str = "rig_pairs.txt";

/// What `colmap` does: the export to reconstruct and COLMAP's options; each field is the flag
/// of the same name, whose help (`keyframer colmap --help`) says what it does.
#[derive(Debug, Clone)]
pub struct ColmapSettings {
    /// Export folder made by `keyframer export`.
    pub export: PathBuf,
    /// Workspace folder (None: EXPORT/colmap).
    pub output: Option<PathBuf>,
    /// Run feature extraction, matching and the mapper.
    pub sparse: bool,
    /// Then densify (needs a CUDA COLMAP).
    pub dense: bool,
    /// Then undistort into `WORKSPACE/dataset/` (PINHOLE images, masks, `transforms.json`).
    pub undistort: bool,
    /// Align the model to the keyframes' positions (ENU metres) first: the inlier threshold of
    /// the robust alignment in metres, or None for no georegistration.
    pub georegister: Option<f64>,
    /// COLMAP's options for the sparse model.
    pub options: SparseOptions,
    /// Replace the keyframer-made content of an existing workspace.
    pub force: bool,
    /// Which COLMAP runs the sparse stages.
    pub engine: Engine,
}

/// The COLMAP installation used.
#[derive(Debug, Clone)]
pub struct Colmap {
    /// The `colmap` executable.
    pub bin: PathBuf,
    /// Header line, e.g. "COLMAP 3.8 (Commit Unknown on Unknown without CUDA)".
    pub version: String,
    /// Whether the build has CUDA (dense stereo).
    pub cuda: bool,
    /// What `colmap help` printed (its header and the commands it offers).
    pub help: String,
}

/// Finds COLMAP (`KEYFRAMER_COLMAP`, else `colmap` on PATH) and reads its version and CUDA
/// support from the header of `colmap help`.
pub fn locate() -> Result<Colmap> {
    let bin = match std::env::var_os(COLMAP_ENV) {
        Some(p) => {
            let p = PathBuf::from(p);
            if !p.is_file() {
                return Err(Error::Colmap(format!(
                    "{COLMAP_ENV}={}: no such file: install COLMAP (Debian/Ubuntu: apt-get install colmap) or fix the variable",
                    p.display()
                )));
            }
            p
        }
        None => crate::fsutil::find_on_path("colmap").ok_or_else(|| {
            Error::Colmap(
                "colmap not found on PATH: install COLMAP (Debian/Ubuntu: apt-get install colmap)"
                    .into(),
            )
        })?,
    };
    let out = Command::new(&bin)
        .arg("help")
        .stdin(Stdio::null())
        .output()
        .map_err(|e| Error::Colmap(format!("{}: cannot run: {e}", bin.display())))?;
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    // Header: "COLMAP 3.8 -- Structure-from-Motion ..." then "(Commit ... without CUDA)".
    let cuda = text.contains("with CUDA") && !text.contains("without CUDA");
    let name = text
        .lines()
        .find(|l| l.trim_start().starts_with("COLMAP"))
        .and_then(|l| l.split("--").next())
        .map(|v| v.trim().to_string())
        .unwrap_or_else(|| "COLMAP (unknown version)".into());
    let version = format!(
        "{name} ({})",
        if cuda { "with CUDA" } else { "without CUDA" }
    );
    Ok(Colmap {
        bin,
        version,
        cuda,
        help: text,
    })
}

/// One COLMAP stage as run.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StageRecord {
    /// COLMAP command name.
    pub stage: String,
    /// Full command line.
    pub command: Vec<String>,
    /// Wall time in seconds.
    pub seconds: f64,
    /// CPU time in seconds (user + system, the stage's process and what it waited for): the
    /// stage's work, which other processes on the machine do not lengthen (0 in records of
    /// earlier builds).
    #[serde(default)]
    pub cpu_s: f64,
    /// Log file, relative to the workspace.
    pub log: String,
    /// Exit code (None when killed by a signal).
    pub exit_code: Option<i32>,
}

/// Summary of one model under `sparse/`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ModelSummary {
    /// Folder relative to the workspace (`sparse/0`).
    pub path: String,
    /// Registered images.
    pub registered_images: usize,
    /// Points in the model.
    pub points3d: usize,
    /// Mean of the points' reprojection errors (px).
    pub mean_reprojection_error: Option<f64>,
}

/// `colmap.json`: what was run, how long it took, and what came out.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Record {
    /// Always "keyframer".
    pub tool: String,
    /// keyframer version.
    pub tool_version: String,
    /// COLMAP binary.
    pub colmap: PathBuf,
    /// COLMAP version line.
    pub colmap_version: String,
    /// Whether COLMAP has CUDA.
    pub cuda: bool,
    /// The export folder (absolute).
    pub export: PathBuf,
    /// The workspace (absolute).
    pub workspace: PathBuf,
    /// Images in the workspace (the export's frames).
    pub images: usize,
    /// Masks in the workspace.
    pub masks: usize,
    /// COLMAP camera model shared by all images.
    pub camera_model: String,
    /// Matcher (when sparse ran).
    pub matcher: Option<Matcher>,
    /// Sequential overlap (when sequential matching ran).
    pub overlap: Option<u32>,
    /// Stages in order.
    pub stages: Vec<StageRecord>,
    /// Models under sparse/, in folder order.
    pub models: Vec<ModelSummary>,
    /// The georegistration (`--georegister`), when it ran.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub georegistration: Option<georegister::Georegistration>,
    /// The undistorted dataset (`--undistort`), when it was made.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dataset: Option<undistort::DatasetSummary>,
    /// Why the run stopped early, when it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// A rig export (360° views, `images/<view>/`): one camera per view folder
    /// (`single_camera_per_folder`), ideal pinholes of known focal length.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub per_folder: bool,
    /// The pycolmap that ran the sparse stages (`--engine pycolmap`), when it did; the `colmap`
    /// command then only wrote `project.ini` and ran the later stages (georegistration,
    /// undistortion).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pycolmap: Option<Pycolmap>,
    /// The views of each keyframe were made one frame of a rig (`rig_config.json` applied by
    /// pycolmap's rig configurator) and mapped as one.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub rig: bool,
    /// Every file keyframer and COLMAP wrote in the workspace, relative to it: what a `--force`
    /// re-run may replace or remove (and nothing else).
    #[serde(default)]
    pub files: Vec<String>,
    /// When the run started (seconds since the Unix epoch).
    #[serde(default)]
    pub started_unix_s: u64,
    /// False while the stages run: a record left unfinished means keyframer was stopped.
    #[serde(default = "finished_default")]
    pub finished: bool,
}

fn finished_default() -> bool {
    true
}

impl Record {
    /// The record of a new workspace `ws` of `images` images and `masks` masks from `export`,
    /// before any stage.
    fn new(
        colmap: &Colmap,
        export: &Path,
        ws: &Path,
        images: usize,
        masks: usize,
        a: &ColmapSettings,
    ) -> Record {
        Record {
            tool: "keyframer".into(),
            tool_version: env!("CARGO_PKG_VERSION").into(),
            colmap: colmap.bin.clone(),
            colmap_version: colmap.version.clone(),
            cuda: colmap.cuda,
            export: export.to_path_buf(),
            workspace: ws.to_path_buf(),
            images,
            masks,
            camera_model: a.options.camera_model.clone(),
            ..Record::default()
        }
    }
}

/// Reads a workspace's `colmap.json`.
pub fn read_record(workspace: &Path) -> Result<Record> {
    let p = workspace.join(RECORD);
    let text = crate::output::read_text(&p)?;
    serde_json::from_str(&text)
        .map_err(|e| Error::file(&p, Some(e.line()), "colmap record", "", e.to_string()))
}

/// Reads an export folder's manifest, with a clear error when it is not an export; every name
/// in it is checked to be a plain file name.
pub fn read_manifest(export: &Path) -> Result<Manifest> {
    let p = export.join(MANIFEST);
    if !p.is_file() {
        let msg = "no manifest.json: not an export folder made by `keyframer export`";
        return Err(Error::input(export, msg));
    }
    Manifest::load(&p)
}

/// Runs `keyframer colmap`; returns the record as written.
pub fn run(a: &ColmapSettings, quiet: bool) -> Result<Record> {
    a.options.check()?;
    let colmap = locate()?;
    let (export, manifest, ws) = check_export(a)?;
    if let Some(m) = a.georegister {
        if !(m.is_finite() && m > 0.0) {
            let msg = format!("{m} m: the inlier threshold must be a positive number of metres");
            return Err(Error::param("georegister_max_error", msg));
        }
        georegister::precheck(&manifest)?;
    }
    let spherical = equirect_settings(a, &export, &manifest)?;
    let rigged = rig_settings(a, &manifest);
    let a = spherical.as_ref().or(rigged.as_ref()).unwrap_or(a);
    let stages = a.sparse || a.dense || a.undistort || a.georegister.is_some();
    let py = match spherical.is_some() && stages {
        true => Some(erp_engine(a.engine, &export, &colmap, quiet)?),
        false => engine(a.engine, rigged.is_some() && stages, &colmap, quiet)?,
    };
    if py.is_some() && rigged.is_some() {
        rig_config_of(&export)?;
    }
    // The workspace stays locked until its record is written last.
    let (masks, _held) = fill_workspace(&ws, &export, &manifest, a.force)?;
    let mut rec = Record {
        files: ours_now(&ws),
        started_unix_s: fsutil::now_unix_s(),
        // The record comes first, marked unfinished: a kill during a stage leaves a workspace
        // that a later `--force` knows as keyframer's (files appearing after `started_unix_s`
        // are COLMAP's).
        finished: false,
        per_folder: rigged.is_some(),
        pycolmap: py.clone(),
        rig: py.is_some() && rigged.is_some(),
        ..Record::new(&colmap, &export, &ws, manifest.frames.len(), masks, a)
    };
    write_record(&ws, &rec)?;
    rec.finished = true;
    let runner = Runner::new(&colmap, &ws, quiet);
    let result = run_stages(&runner, &mut rec, a, &manifest, py.as_ref());
    if let Err(e) = &result {
        rec.error = Some(e.to_string());
    }
    rec.files = ours_now(&ws);
    write_record(&ws, &rec)?;
    result.map(|()| rec)
}

/// The pycolmap that runs the sparse stages, or None for the `colmap` command: `--engine
/// pycolmap` needs it (an error naming what to install when it is missing); `auto` takes it for
/// a rig export whose stages run (`rig`) when found and says so, else says how to get rig mapping.
fn engine(engine: Engine, rig: bool, colmap: &Colmap, quiet: bool) -> Result<Option<Pycolmap>> {
    match engine {
        Engine::Colmap => Ok(None),
        Engine::Pycolmap => pycolmap::locate().map(Some),
        Engine::Auto if !rig => Ok(None),
        Engine::Auto => match pycolmap::locate() {
            Ok(py) => {
                if !quiet {
                    eprintln!(
                        "colmap: a rig export: mapped as a rig through pycolmap {} ({})",
                        py.version,
                        py.python.display()
                    );
                }
                Ok(Some(py))
            }
            Err(e) => {
                if !quiet {
                    eprintln!(
                        "colmap: a rig export: {} has no rigs, so its views are registered one by one; \
                         for rig-aware mapping install pycolmap ({e})",
                        colmap.version
                    );
                }
                Ok(None)
            }
        },
    }
}

/// An ERP export's settings (`export --views equirect`): one EQUIRECTANGULAR camera of the
/// frames' size (it has no other parameter), which only pycolmap maps ([`erp_engine`]); the
/// stages that need COLMAP 3.8 to read the model (georegistration, undistortion, dense) are
/// refused. None for any other export.
fn equirect_settings(
    a: &ColmapSettings,
    export: &Path,
    manifest: &Manifest,
) -> Result<Option<ColmapSettings>> {
    if (manifest.settings.views.as_ref()).is_none_or(|v| v.set != "equirect") {
        return Ok(None);
    }
    if a.georegister.is_some() || a.undistort || a.dense {
        let msg = "holds whole ERP frames (`export --views equirect`), mapped with pycolmap's \
                   EQUIRECTANGULAR camera, whose model COLMAP 3.8 cannot read: --georegister, \
                   --undistort and --dense need pinhole views (`--views cube` or `--views ring:N`)";
        return Err(Error::input(export, msg));
    }
    let mut erp = a.clone();
    erp.options.camera_model = "EQUIRECTANGULAR".into();
    erp.options.camera_params = Some(format!("{},{}", manifest.width, manifest.height));
    Ok(Some(erp))
}

/// The pycolmap that maps an ERP export: `--engine pycolmap` or `auto` find it (said on
/// stderr); the `colmap` command (3.8) has no camera model for the sphere.
fn erp_engine(engine: Engine, export: &Path, colmap: &Colmap, quiet: bool) -> Result<Pycolmap> {
    let lacks = format!(
        "holds whole ERP frames (`export --views equirect`), which need a camera model for the \
         sphere that {} lacks",
        colmap.version
    );
    match engine {
        Engine::Colmap => {
            let msg = format!(
                "{lacks}: map it with `--engine pycolmap` (EQUIRECTANGULAR camera), or export \
                 pinhole views (`--views cube` or `--views ring:N`)"
            );
            Err(Error::input(export, msg))
        }
        Engine::Pycolmap | Engine::Auto => {
            let py = pycolmap::locate().map_err(|e| {
                let msg = format!(
                    "{lacks}, and pycolmap, which has one, was not found ({e}); or export \
                     pinhole views (`--views cube` or `--views ring:N`)"
                );
                Error::input(export, msg)
            })?;
            if !quiet && engine == Engine::Auto {
                eprintln!(
                    "colmap: ERP frames: mapped with one EQUIRECTANGULAR camera through pycolmap {} ({})",
                    py.version,
                    py.python.display()
                );
            }
            Ok(py)
        }
    }
}

/// The export's `rig_config.json` (a rig export's, for pycolmap's rig configurator).
fn rig_config_of(export: &Path) -> Result<PathBuf> {
    let p = export.join(crate::rig::RIG_CONFIG);
    if !p.is_file() {
        let msg = "missing: a rig export made by `keyframer export --views` holds it; export again";
        return Err(Error::input(&p, msg));
    }
    Ok(p)
}

/// A rig export's settings: every view folder its own PINHOLE camera with the views' known
/// focal length and centre (the views are ideal pinholes of one fov and size), kept fixed by the
/// mapper. None for other exports.
fn rig_settings(a: &ColmapSettings, manifest: &Manifest) -> Option<ColmapSettings> {
    let v = manifest.views.first()?;
    let (f, c) = (v.focal(), f64::from(v.size) / 2.0);
    let mut rigged = a.clone();
    rigged.options.camera_model = "PINHOLE".into();
    rigged.options.camera_params = Some(format!("{f},{f},{c},{c}"));
    Some(rigged)
}

/// The export (absolute), its manifest (every listed image present) and the workspace folder,
/// which must be neither inside the export's files nor around the export.
fn check_export(a: &ColmapSettings) -> Result<(PathBuf, Manifest, PathBuf)> {
    let export = fsutil::absolute(&a.export);
    let manifest = read_manifest(&export)?;
    if manifest.frames.is_empty() {
        return Err(Error::input(&export, "the export holds no images"));
    }
    let ws = fsutil::absolute(&a.output.clone().unwrap_or_else(|| export.join("colmap")));
    crate::output::check_not_input(&ws, &read_by(&export))?;
    if crate::output::resolve(&export).starts_with(crate::output::resolve(&ws)) {
        return Err(Error::param(
            "output",
            format!(
                "the workspace {} must not be or contain the export folder {}",
                ws.display(),
                export.display()
            ),
        ));
    }
    for f in &manifest.frames {
        let from = crate::manifest::image_path(&export, f);
        if !from.is_file() {
            let msg = "listed in the export's manifest but missing";
            return Err(Error::input(&from, msg));
        }
    }
    Ok((export, manifest, ws))
}

/// Prepares the workspace (replacing only keyframer's own content) and links or copies the
/// export's images and masks into `images/` and `masks/`; on failure removes what it made.
/// Returns the number of masks and the workspace (locked while it lives).
fn fill_workspace(
    ws: &Path,
    export: &Path,
    manifest: &Manifest,
    force: bool,
) -> Result<(usize, crate::output::OutDir)> {
    let dir = prepare_workspace(ws, export, force)?;
    let images = ws.join("images");
    let masks_dir = ws.join("masks");
    let export_masks = export.join(MASK_DIR);
    let mut masks = 0;
    let linked = (|| -> Result<()> {
        std::fs::create_dir_all(&images).map_err(|e| Error::io(&images, e))?;
        std::fs::create_dir_all(ws.join("logs")).map_err(|e| Error::io(ws.join("logs"), e))?;
        for f in &manifest.frames {
            // A rig export's view folders are kept (COLMAP's one camera per folder).
            let to = images.join(f.rel());
            if let (Some(v), Some(parent)) = (&f.view, to.parent()) {
                std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
                if f.mask.is_some() {
                    let d = masks_dir.join(v);
                    std::fs::create_dir_all(&d).map_err(|e| Error::io(&d, e))?;
                }
            }
            link_or_copy(&crate::manifest::image_path(export, f), &to)?;
            if let Some(m) = &f.mask {
                if masks == 0 {
                    std::fs::create_dir_all(&masks_dir).map_err(|e| Error::io(&masks_dir, e))?;
                }
                let from = match &f.view {
                    Some(v) => export_masks.join(v).join(m),
                    None => export_masks.join(m),
                };
                let mut to = f.rel().into_os_string();
                to.push(".png");
                link_or_copy(&from, &masks_dir.join(to))?;
                masks += 1;
            }
        }
        Ok(())
    })();
    if let Err(e) = linked {
        remove_ours(ws, &ours_now(ws));
        // abandon removes only folders this run created.
        dir.abandon();
        return Err(e);
    }
    Ok((masks, dir))
}

/// `project.ini`, then the database alone, or the sparse stages (and the dense ones).
fn run_stages(
    runner: &Runner,
    rec: &mut Record,
    a: &ColmapSettings,
    manifest: &Manifest,
    py: Option<&Pycolmap>,
) -> Result<()> {
    let ws = runner.ws.as_path();
    write_project_ini(runner, rec, &a.options)?;
    let db = ws.join("database.db");
    if !(a.sparse || a.dense || a.undistort || a.georegister.is_some()) {
        rec.stages
            .push(runner.stage("database_creator", &[("--database_path", p(&db))])?);
        return Ok(());
    }
    let best = match py {
        Some(py) => py_sparse(runner, rec, a, py)?,
        None => {
            extract_and_match(runner, rec, &a.options, None)?;
            map(runner, rec, a)?
        }
    };
    let mut model_dir = ws.join(&best);
    let mut world = transforms::World::Colmap;
    if let Some(max_error_m) = a.georegister {
        let (dir, g) = georegister::georegister(runner, rec, manifest, &model_dir, max_error_m)?;
        rec.georegistration = Some(g);
        (model_dir, world) = (dir, transforms::World::Enu);
    }
    if a.undistort {
        rec.dataset = Some(undistort::make_dataset(runner, rec, &model_dir, world)?);
    }
    if a.dense {
        // The georegistered model when there is one, so the dense cloud shares its metres.
        densify(runner, rec, &model_dir)?;
    }
    Ok(())
}

/// COLMAP's option sharing cameras (flag, ini key): one camera for the workspace, or one per
/// view folder for a rig export.
fn camera_key(rec: &Record) -> (&'static str, &'static str) {
    if rec.per_folder {
        (
            "--ImageReader.single_camera_per_folder",
            "single_camera_per_folder",
        )
    } else {
        ("--ImageReader.single_camera", "single_camera")
    }
}

/// A path as a COLMAP argument.
fn p(path: &Path) -> String {
    path.display().to_string()
}

/// `feature_extractor` (with the masks and known intrinsics) and the chosen matcher.
fn extract_and_match(
    runner: &Runner,
    rec: &mut Record,
    o: &SparseOptions,
    image_list: Option<&Path>,
) -> Result<()> {
    let ws = runner.ws.as_path();
    let db = ws.join("database.db");
    let gpu = if runner.colmap.cuda { "1" } else { "0" };
    let mut fe = vec![
        ("--database_path", p(&db)),
        ("--image_path", p(&ws.join("images"))),
        (camera_key(rec).0, "1".into()),
        ("--ImageReader.camera_model", o.camera_model.clone()),
        ("--SiftExtraction.use_gpu", gpu.into()),
    ];
    if rec.masks > 0 {
        fe.push(("--ImageReader.mask_path", p(&ws.join("masks"))));
    }
    if let Some(n) = o.max_features {
        fe.push(("--SiftExtraction.max_num_features", n.to_string()));
    }
    if let Some(params) = &o.camera_params {
        fe.push(("--ImageReader.camera_params", params.clone()));
    }
    if let Some(list) = image_list {
        // Only the listed images, sharing the camera the first extraction made.
        fe.push(("--image_list_path", p(list)));
        fe.push(("--ImageReader.existing_camera_id", "1".into()));
    }
    rec.stages.push(runner.stage("feature_extractor", &fe)?);
    let (name, args) = matching(ws, rec, o, image_list.is_some())?;
    let mut args: Vec<(&str, String)> = args;
    args.push(("--SiftMatching.use_gpu", gpu.into()));
    rec.stages.push(runner.stage(name, &args)?);
    Ok(())
}

/// The matching stage (`colmap`'s command name) and its arguments for the chosen matcher: on a
/// rig export (not `extending` a model), sequential matching matches the views of a keyframe
/// with those of the next `overlap` keyframes through the pair list it writes.
fn matching(
    ws: &Path,
    rec: &mut Record,
    o: &SparseOptions,
    extending: bool,
) -> Result<(&'static str, Vec<(&'static str, String)>)> {
    let db = ws.join("database.db");
    rec.matcher = Some(o.matcher);
    let (name, mut args) = match o.matcher {
        Matcher::Sequential if rec.per_folder && !extending => {
            // A rig: the views of a keyframe and of the next `overlap` keyframes.
            rec.overlap = Some(o.overlap);
            let list = ws.join(RIG_PAIRS);
            let names = rig_image_names(&ws.join("images"))?;
            let text: String = rig_pairs::pairs(&names, o.overlap as usize)
                .iter()
                .map(|(a, b)| format!("{a} {b}\n"))
                .collect();
            crate::fsutil::write_atomic(&list, text.as_bytes())?;
            (
                "matches_importer",
                vec![
                    ("--match_list_path", p(&list)),
                    ("--match_type", "pairs".into()),
                ],
            )
        }
        Matcher::Sequential => {
            rec.overlap = Some(o.overlap);
            (
                "sequential_matcher",
                vec![("--SequentialMatching.overlap", o.overlap.to_string())],
            )
        }
        Matcher::Exhaustive => ("exhaustive_matcher", Vec::new()),
    };
    args.push(("--database_path", p(&db)));
    Ok((name, args))
}

/// The image names (`view/file`) of a rig workspace's `images` folder.
fn rig_image_names(images: &Path) -> Result<Vec<String>> {
    let mut out = Vec::new();
    let read = |dir: &Path| std::fs::read_dir(dir).map_err(|e| Error::io(dir, e));
    for view in read(images)? {
        let view = view.map_err(|e| Error::io(images, e))?.path();
        if !view.is_dir() {
            continue;
        }
        let vname = view.file_name().map(|n| n.to_string_lossy().to_string());
        for f in read(&view)? {
            let f = f.map_err(|e| Error::io(&view, e))?;
            let name = f.file_name().to_string_lossy().to_string();
            // Images only: no hidden or stray files (matches_importer would name images that
            // are not in the database).
            let image = (Path::new(&name).extension())
                .and_then(|e| e.to_str())
                .is_some_and(|e| {
                    ["jpg", "jpeg", "png", "tif", "tiff"].contains(&e.to_ascii_lowercase().as_str())
                });
            if let (Some(v), true) = (&vname, image && !name.starts_with('.')) {
                out.push(format!("{v}/{name}"));
            }
        }
    }
    out.sort();
    Ok(out)
}

/// The `mapper` (known intrinsics kept fixed unless a mapper option says otherwise); records
/// every model and returns the largest one's path, relative to the workspace.
fn map(runner: &Runner, rec: &mut Record, a: &ColmapSettings) -> Result<String> {
    let ws = runner.ws.as_path();
    let sparse = ws.join("sparse");
    std::fs::create_dir_all(&sparse).map_err(|e| Error::io(&sparse, e))?;
    let margs = mapper_args(ws, &sparse, &a.options)?;
    let margs: Vec<(&str, String)> = margs.iter().map(|(k, v)| (k.as_str(), v.clone())).collect();
    rec.stages.push(runner.stage("mapper", &margs)?);
    best_model(runner, rec)
}

/// Records every model under `sparse/` and returns the largest one's path, relative to the
/// workspace (an error when the mapper made none).
fn best_model(runner: &Runner, rec: &mut Record) -> Result<String> {
    let ws = runner.ws.as_path();
    rec.models = read_models(ws, &ws.join("sparse"))?;
    let Some(best) = largest(&rec.models) else {
        return Err(Error::Colmap(format!(
            "mapper made no model from {} images (see {})",
            rec.images,
            ws.join("logs/mapper.log").display()
        )));
    };
    if !runner.quiet {
        for m in &rec.models {
            eprintln!(
                "{}: {} of {} images registered, {} points",
                m.path, m.registered_images, rec.images, m.points3d
            );
        }
    }
    Ok(best.path.clone())
}

/// pycolmap's sparse stages through keyframer's driver (written into the workspace): features
/// (one camera per view folder for a rig export, known intrinsics), the rig configuration of a
/// rig export (`rig_config.json`: the views of a keyframe one frame), the matcher as the
/// `colmap` command's path chooses it, and the incremental mapper (known intrinsics and the rig's
/// relative poses kept fixed unless a mapper option says otherwise). Records every model and
/// returns the largest one's path, relative to the workspace.
fn py_sparse(
    runner: &Runner,
    rec: &mut Record,
    a: &ColmapSettings,
    py: &Pycolmap,
) -> Result<String> {
    let ws = runner.ws.as_path();
    let o = &a.options;
    py_extract(runner, rec, o, py, None)?;
    if rec.rig {
        let config = rig_config_of(&rec.export)?;
        let args = [
            ("--database_path", p(&ws.join("database.db"))),
            ("--rig_config_path", p(&config)),
        ];
        rec.stages
            .push(runner.py_stage(py, "rig_configurator", &args)?);
    }
    py_match(runner, rec, o, py, false)?;
    let sparse = ws.join("sparse");
    std::fs::create_dir_all(&sparse).map_err(|e| Error::io(&sparse, e))?;
    let margs = py_mapper_args(
        ws,
        &sparse,
        o,
        rec.rig,
        crate::sparse::MapperKind::Incremental,
    )?;
    let margs: Vec<(&str, String)> = margs.iter().map(|(k, v)| (k.as_str(), v.clone())).collect();
    rec.stages.push(runner.py_stage(py, "mapper", &margs)?);
    best_model(runner, rec)
}

/// Writes keyframer's pycolmap driver into the workspace (one of keyframer's own files there)
/// and runs its feature extraction: every image, or only those listed in `image_list` (a later
/// round's new images, sharing the first camera).
fn py_extract(
    runner: &Runner,
    rec: &mut Record,
    o: &SparseOptions,
    py: &Pycolmap,
    image_list: Option<&Path>,
) -> Result<()> {
    let ws = runner.ws.as_path();
    fsutil::write_atomic(
        &ws.join(pycolmap::DRIVER),
        pycolmap::DRIVER_SOURCE.as_bytes(),
    )?;
    let mode = if rec.per_folder {
        "per_folder"
    } else {
        "single"
    };
    let mut fe = vec![
        ("--database_path", p(&ws.join("database.db"))),
        ("--image_path", p(&ws.join("images"))),
        ("--camera_mode", mode.into()),
        ("--camera_model", o.camera_model.clone()),
    ];
    if rec.masks > 0 {
        fe.push(("--mask_path", p(&ws.join("masks"))));
    }
    if let Some(n) = o.max_features {
        fe.push(("--max_num_features", n.to_string()));
    }
    if let Some(params) = &o.camera_params {
        fe.push(("--camera_params", params.clone()));
    }
    if let Some(list) = image_list {
        fe.push(("--image_list", p(list)));
        fe.push(("--existing_camera_id", "1".into()));
    }
    rec.stages
        .push(runner.py_stage(py, "feature_extractor", &fe)?);
    Ok(())
}

/// The chosen matcher through the pycolmap driver (pairs already in the database are skipped,
/// so a later round matches only the pairs with a new image).
fn py_match(
    runner: &Runner,
    rec: &mut Record,
    o: &SparseOptions,
    py: &Pycolmap,
    extending: bool,
) -> Result<()> {
    let (name, args) = matching(runner.ws.as_path(), rec, o, extending)?;
    rec.stages.push(runner.py_stage(py, name, &args)?);
    Ok(())
}

/// The arguments of the pycolmap driver's mapper `kind` writing its models into `output/N`:
/// known intrinsics and a rig's relative poses kept fixed; the incremental mapper takes the
/// mapper options (`--option KEY=VALUE`), the global one has options of its own and takes none.
fn py_mapper_args(
    ws: &Path,
    output: &Path,
    o: &SparseOptions,
    rig: bool,
    kind: crate::sparse::MapperKind,
) -> Result<Vec<(String, String)>> {
    let s = |k: &str, v: String| (k.to_string(), v);
    let mut margs = vec![
        s("--database_path", p(&ws.join("database.db"))),
        s("--image_path", p(&ws.join("images"))),
        s("--output_path", p(output)),
        s(
            "--fixed_intrinsics",
            u8::from(o.camera_params.is_some()).to_string(),
        ),
    ];
    if kind == crate::sparse::MapperKind::Incremental {
        margs.push(s("--fixed_rig", u8::from(rig).to_string()));
        for (k, v) in mapper_keys(&o.mapper_option)? {
            let k = k.trim_start_matches("--Mapper.");
            margs.push(s("--option", format!("{k}={v}")));
        }
    }
    Ok(margs)
}

/// The mapper's arguments writing into `output` (known intrinsics kept fixed unless a mapper
/// option says otherwise).
fn mapper_args(ws: &Path, output: &Path, o: &SparseOptions) -> Result<Vec<(String, String)>> {
    let mut margs = vec![
        ("--database_path".to_string(), p(&ws.join("database.db"))),
        ("--image_path".to_string(), p(&ws.join("images"))),
        ("--output_path".to_string(), p(output)),
    ];
    let keys = mapper_keys(&o.mapper_option)?;
    if o.camera_params.is_some() {
        for k in [
            "--Mapper.ba_refine_focal_length",
            "--Mapper.ba_refine_extra_params",
        ] {
            if !keys.iter().any(|(key, _)| key == k) {
                margs.push((k.to_string(), "0".into()));
            }
        }
    }
    margs.extend(keys);
    Ok(margs)
}

/// The summaries of the models under `sparse` (relative to `ws`), in folder order.
fn read_models(ws: &Path, sparse: &Path) -> Result<Vec<ModelSummary>> {
    let mut models = Vec::new();
    for dir in model::model_dirs(sparse)? {
        let (m, _) = model::read(&dir)?;
        models.push(summarise(&m, &fsutil::relative_to(&dir, ws)));
    }
    Ok(models)
}

/// `image_undistorter`, `patch_match_stereo` and `stereo_fusion` on the model in `model_dir`
/// (a CUDA build of COLMAP only; otherwise an error saying how to densify elsewhere).
fn densify(runner: &Runner, rec: &mut Record, model_dir: &Path) -> Result<()> {
    let (colmap, ws) = (&runner.colmap, runner.ws.as_path());
    let images = ws.join("images");
    if !colmap.cuda {
        return Err(Error::Colmap(format!(
            "dense reconstruction (patch_match_stereo) needs a CUDA build of COLMAP and {} is built without CUDA; \
             the sparse model is at {}; `colmap image_undistorter --image_path {} --input_path {} --output_path DIR` \
             prepares it for densifying elsewhere (e.g. OpenMVS)",
            colmap.bin.display(),
            model_dir.display(),
            images.display(),
            model_dir.display()
        )));
    }
    let dense = ws.join("dense");
    rec.stages.push(runner.stage(
        "image_undistorter",
        &[
            ("--image_path", p(&images)),
            ("--input_path", p(model_dir)),
            ("--output_path", p(&dense)),
            ("--output_type", "COLMAP".into()),
        ],
    )?);
    rec.stages.push(runner.stage(
        "patch_match_stereo",
        &[
            ("--workspace_path", p(&dense)),
            ("--workspace_format", "COLMAP".into()),
            ("--PatchMatchStereo.geom_consistency", "true".into()),
        ],
    )?);
    rec.stages.push(runner.stage(
        "stereo_fusion",
        &[
            ("--workspace_path", p(&dense)),
            ("--workspace_format", "COLMAP".into()),
            ("--input_type", "geometric".into()),
            ("--output_path", p(&dense.join("fused.ply"))),
        ],
    )?);
    Ok(())
}

/// The model with the most registered images (the first of equals).
pub fn largest(models: &[ModelSummary]) -> Option<&ModelSummary> {
    models
        .iter()
        .rev()
        .max_by_key(|m| m.registered_images)
        .filter(|m| m.registered_images > 0)
}

fn summarise(m: &model::Model, rel: &Path) -> ModelSummary {
    ModelSummary {
        path: rel.display().to_string(),
        registered_images: m.images.len(),
        points3d: m.points.len(),
        mean_reprojection_error: m.point_mean(|p| p.error),
    }
}

fn write_record(ws: &Path, rec: &Record) -> Result<()> {
    fsutil::write_json(&ws.join(RECORD), rec)
}

/// What `colmap` reads: the export's manifest, images and masks, and a rig export's
/// `rig_config.json` (the workspace may lie beside them, in the export folder).
fn read_by(export: &Path) -> crate::output::Inputs {
    let mut inputs = crate::output::Inputs::none();
    crate::manifest::add_export(&mut inputs, export);
    inputs.add(
        "export rig configuration",
        export.join(crate::rig::RIG_CONFIG),
    );
    inputs
}

/// Prepares the workspace through the one output rule (a folder without `colmap.json` is not
/// keyframer's and is refused; `--force` is needed to replace a keyframer workspace). With
/// `force`, removes exactly the files `colmap.json` lists; any other file inside the places
/// keyframer and COLMAP write (`images/ masks/ sparse/ dense/ logs/ database.db project.ini`) is a
/// user's and stops the run before anything is removed.
fn prepare_workspace(ws: &Path, export: &Path, force: bool) -> Result<crate::output::OutDir> {
    let dir = crate::output::prepare_dir(ws, force, &[RECORD], &read_by(export))?;
    if dir.is_new() || !ws.join(RECORD).is_file() {
        return Ok(dir);
    }
    let record = read_record(ws).map_err(|e| {
        Error::output(
            ws,
            format!(
                "{e}; keyframer cannot tell what it wrote in this workspace, so it replaces nothing: choose a new -o"
            ),
        )
    })?;
    let rec_path = ws.join(RECORD);
    let listed = (record.files.iter().enumerate())
        .map(|(i, f)| crate::output::inside(f, &format!("files[{i}]"), &rec_path))
        .collect::<Result<std::collections::HashSet<PathBuf>>>()?;
    let present = ours_now(ws);
    // After an interrupted run, what appeared in keyframer's places since it started is COLMAP's.
    let since_start = |f: &str| {
        !record.finished
            && std::fs::symlink_metadata(ws.join(f))
                .ok()
                .and_then(|m| m.modified().ok())
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                .is_some_and(|t| t.as_secs() >= record.started_unix_s)
    };
    let foreign: Vec<&String> = present
        .iter()
        .filter(|f| !listed.contains(Path::new(f.as_str())) && !since_start(f))
        .collect();
    if let Some(first) = foreign.first() {
        return Err(Error::output(
            ws.join(first),
            format!(
                "was not written by keyframer ({RECORD} does not list it{}); keyframer never replaces files it did not write: move it away",
                if foreign.len() > 1 {
                    format!(", nor {} other files", foreign.len() - 1)
                } else {
                    String::new()
                }
            ),
        ));
    }
    for f in &present {
        crate::output::check_replaceable(&ws.join(f))?;
    }
    remove_ours(ws, &present);
    Ok(dir)
}

/// Every regular file (and link) now inside the places keyframer and COLMAP write in `ws`,
/// relative to `ws`, sorted.
fn ours_now(ws: &Path) -> Vec<String> {
    fn walk(p: &Path, rel: &Path, out: &mut Vec<String>) {
        match std::fs::symlink_metadata(p) {
            Ok(m) if m.is_dir() => {
                for e in std::fs::read_dir(p).into_iter().flatten().flatten() {
                    walk(&e.path(), &rel.join(e.file_name()), out);
                }
            }
            Ok(_) => out.push(rel.to_string_lossy().into_owned()),
            Err(_) => {}
        }
    }
    let mut out = Vec::new();
    for name in OURS.into_iter().filter(|&n| n != RECORD) {
        walk(&ws.join(name), Path::new(name), &mut out);
    }
    out.sort();
    out
}

/// Removes the listed files (regular files and links only) and then the folders of `OURS` that
/// are left empty.
fn remove_ours(ws: &Path, files: &[String]) {
    for f in files {
        let p = ws.join(f);
        if std::fs::symlink_metadata(&p).is_ok_and(|m| m.file_type().is_file()) {
            if let Err(e) = std::fs::remove_file(&p) {
                log::warn!("{}: cannot remove: {e}", p.display());
            }
        }
    }
    fn prune(dir: &Path) {
        if let Ok(entries) = std::fs::read_dir(dir) {
            for e in entries.flatten() {
                if e.file_type().is_ok_and(|t| t.is_dir()) {
                    prune(&e.path());
                }
            }
        }
        let _ = std::fs::remove_dir(dir);
    }
    for name in OURS {
        let p = ws.join(name);
        if p.is_dir() && !p.is_symlink() {
            prune(&p);
        }
    }
}

/// Hard-links `from` to `to`, copying (atomically) when a link is impossible (other file system).
fn link_or_copy(from: &Path, to: &Path) -> Result<()> {
    if !from.is_file() {
        let msg = "listed in the export's manifest but missing";
        return Err(Error::input(from, msg));
    }
    crate::output::check_replaceable(to)?;
    if std::fs::hard_link(from, to).is_ok() {
        return Ok(());
    }
    fsutil::copy_atomic(from, to)
}

/// Makes the stage's process end when keyframer does (Linux: the parent-death signal), so a killed
/// keyframer never leaves COLMAP writing into a workspace.
fn die_with_parent(cmd: &mut Command) {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        const PR_SET_PDEATHSIG: std::ffi::c_int = 1;
        const SIGKILL: std::ffi::c_ulong = 9;
        extern "C" {
            fn prctl(option: std::ffi::c_int, arg2: std::ffi::c_ulong, ...) -> std::ffi::c_int;
        }
        // SAFETY: prctl(PR_SET_PDEATHSIG) is async-signal-safe and only sets a flag of the child
        // between fork and exec; nothing is allocated.
        unsafe {
            cmd.pre_exec(|| {
                if prctl(PR_SET_PDEATHSIG, SIGKILL) == -1 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    }
}

/// Waits for `child`; returns its exit status and the CPU seconds (user + system) it and the
/// descendants it waited for used.
fn wait_with_cpu(child: &std::process::Child) -> std::io::Result<(std::process::ExitStatus, f64)> {
    use std::os::unix::process::ExitStatusExt;
    let pid = child.id() as libc::pid_t;
    let mut status: libc::c_int = 0;
    // SAFETY: rusage is plain old data, for which all-zero bytes are a valid value.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    loop {
        // SAFETY: `pid` is our own child, not yet waited for (std waits only when asked);
        // `status` and `usage` are valid for writes for the call.
        let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
        if r == pid {
            break;
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
    let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    let cpu = secs(usage.ru_utime) + secs(usage.ru_stime);
    Ok((std::process::ExitStatus::from_raw(status), cpu))
}

/// Runs COLMAP stages in a workspace; its pycolmap stages share one driver process, started at
/// the first and ended with the runner (a `reconstruct` loop's rounds and trials share one).
pub struct Runner {
    colmap: Colmap,
    /// The workspace (absolute).
    ws: PathBuf,
    quiet: bool,
    /// keyframer's pycolmap driver serving this runner's pycolmap stages, started at the first
    /// (ends with the runner).
    server: std::cell::RefCell<Option<Server>>,
}

/// The answer of [`Server`] to a stage.
#[derive(Debug, Deserialize)]
struct Answer {
    /// The stage's exit code, as if it had run alone.
    code: i32,
    /// The server's CPU seconds since its previous answer.
    cpu_s: f64,
}

/// keyframer's pycolmap driver running stages in one process (`pycolmap_stages.py serve`), so
/// that a round imports pycolmap once (~0.2 CPU-s) instead of once per stage.
struct Server {
    child: std::process::Child,
    requests: Option<std::process::ChildStdin>,
    answers: std::io::BufReader<std::process::ChildStdout>,
    /// CPU seconds the answers have accounted for.
    accounted_s: f64,
    /// Whether the process has been waited for.
    reaped: bool,
}

impl Server {
    /// Starts the driver in `ws` with its own stderr (an import failure) appended to `log`.
    fn start(py: &Pycolmap, ws: &Path, log: &Path) -> Result<Server> {
        let err = std::fs::OpenOptions::new()
            .append(true)
            .create(true)
            .open(log)
            .map_err(|e| Error::io(log, e))?;
        let mut cmd = Command::new(&py.python);
        cmd.arg(ws.join(pycolmap::DRIVER))
            .arg("serve")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(err);
        die_with_parent(&mut cmd);
        let mut child = cmd
            .spawn()
            .map_err(|e| Error::Colmap(format!("{}: cannot run: {e}", py.python.display())))?;
        let (Some(requests), Some(answers)) = (child.stdin.take(), child.stdout.take()) else {
            let _ = child.kill();
            let _ = child.wait();
            return Err(Error::Colmap(
                "pycolmap: the driver's pipes are missing".into(),
            ));
        };
        Ok(Server {
            child,
            requests: Some(requests),
            answers: std::io::BufReader::new(answers),
            accounted_s: 0.0,
            reaped: false,
        })
    }

    /// Runs stage `argv` with its output appended to `log`; None when the server ended (or
    /// answered nonsense) instead of answering.
    fn ask(&mut self, log: &Path, argv: &[String]) -> Option<Answer> {
        use std::io::{BufRead, Write};
        let line = serde_json::json!({ "log": p(log), "argv": argv }).to_string();
        let requests = self.requests.as_mut()?;
        writeln!(requests, "{line}").ok()?;
        requests.flush().ok()?;
        let mut answer = String::new();
        match self.answers.read_line(&mut answer) {
            Ok(n) if n > 0 => {}
            _ => return None,
        }
        let a: Answer = serde_json::from_str(&answer).ok()?;
        self.accounted_s += a.cpu_s;
        Some(a)
    }

    /// Ends the server (its stdin closed, or killed when `kill`) and waits for it: its exit
    /// status and the CPU seconds no answer accounted for.
    fn end(&mut self, kill: bool) -> std::io::Result<(std::process::ExitStatus, f64)> {
        drop(self.requests.take());
        if kill {
            let _ = self.child.kill();
        }
        let (status, cpu) = wait_with_cpu(&self.child)?;
        self.reaped = true;
        Ok((status, (cpu - self.accounted_s).max(0.0)))
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        if !self.reaped {
            let _ = self.end(false);
        }
    }
}

impl Runner {
    /// A runner of `colmap` (or of pycolmap's stages) in the workspace `ws`; `quiet`: no
    /// spinner and no stage times on stderr.
    pub fn new(colmap: &Colmap, ws: &Path, quiet: bool) -> Runner {
        Runner {
            colmap: colmap.clone(),
            ws: fsutil::absolute(ws),
            quiet,
            server: std::cell::RefCell::new(None),
        }
    }

    /// Runs `colmap <name> <args>` with stdout and stderr in `logs/<name>.log`; a failure is an
    /// error naming the stage and its log.
    fn stage(&self, name: &str, args: &[(&str, String)]) -> Result<StageRecord> {
        let (record, failure) = self.try_stage(name, args)?;
        match failure {
            Some(e) => Err(e),
            None => Ok(record),
        }
    }

    /// Runs a stage as [`Runner::stage`] does and returns its record also when it failed, with
    /// the error naming the stage and its log; Err only when COLMAP could not be started.
    fn try_stage(
        &self,
        name: &str,
        args: &[(&str, String)],
    ) -> Result<(StageRecord, Option<Error>)> {
        let mut command = vec![self.colmap.bin.display().to_string(), name.to_string()];
        command.extend(args.iter().flat_map(|(k, v)| [(*k).to_string(), v.clone()]));
        self.try_command("colmap", name, command)
    }

    /// Runs stage `name` of keyframer's pycolmap driver (in the workspace) as
    /// [`Runner::stage`] runs a `colmap` stage.
    fn py_stage(&self, py: &Pycolmap, name: &str, args: &[(&str, String)]) -> Result<StageRecord> {
        let (record, failure) = self.try_py_stage(py, name, args)?;
        match failure {
            Some(e) => Err(e),
            None => Ok(record),
        }
    }

    /// Runs a pycolmap driver stage as [`Runner::try_stage`] runs a `colmap` stage, through the
    /// runner's [`Server`]; the record's command is the stage run alone.
    fn try_py_stage(
        &self,
        py: &Pycolmap,
        name: &str,
        args: &[(&str, String)],
    ) -> Result<(StageRecord, Option<Error>)> {
        let mut command = vec![
            py.python.display().to_string(),
            p(&self.ws.join(pycolmap::DRIVER)),
            name.to_string(),
        ];
        command.extend(args.iter().flat_map(|(k, v)| [(*k).to_string(), v.clone()]));
        self.timed("pycolmap", name, command, |argv, _, log| {
            let (code, how, cpu_s) = self.serve(py, log, &argv[2..])?;
            Ok((code, (code != Some(0)).then_some(how), cpu_s))
        })
    }

    /// Runs stage `name` of `engine` by `run` (given `command`, the stage's log file, created
    /// empty, and its path), which returns its exit code (None: killed), how it failed (None:
    /// it succeeded) and its CPU seconds, under a spinner: its record, with its wall time and
    /// `logs/<name>.log`, and when it failed the error naming the engine, the stage, how it
    /// ended and the log; its time on stderr when it succeeded. Err only when it could not run.
    fn timed(
        &self,
        engine: &str,
        name: &str,
        command: Vec<String>,
        run: impl FnOnce(&[String], std::fs::File, &Path) -> Result<(Option<i32>, Option<String>, f64)>,
    ) -> Result<(StageRecord, Option<Error>)> {
        let rel = format!("logs/{name}.log");
        let log = self.ws.join(&rel);
        let file = std::fs::File::create(&log).map_err(|e| Error::io(&log, e))?;
        let start = Instant::now();
        let spinner = crate::progress::spinner(name, self.quiet);
        let done = run(&command, file, &log);
        spinner.finish_and_clear();
        let (exit_code, failed, cpu_s) = done?;
        let seconds = start.elapsed().as_secs_f64();
        let record = StageRecord {
            stage: name.into(),
            command,
            seconds,
            cpu_s,
            log: rel,
            exit_code,
        };
        if let Some(how) = failed {
            let e = Error::Colmap(format!(
                "{engine} {name} failed ({how}) after {seconds:.1} s; log: {}",
                log.display()
            ));
            return Ok((record, Some(e)));
        }
        if !self.quiet {
            eprintln!("{name}: {seconds:.1} s");
        }
        Ok((record, None))
    }

    /// Runs `argv` (a stage and its arguments) in the runner's server, starting one when there
    /// is none: its exit code (None: killed by a signal, or the server ended without
    /// answering), how it ended, and its CPU seconds. A server that ended instead of answering
    /// is waited for and gone.
    fn serve(
        &self,
        py: &Pycolmap,
        log: &Path,
        argv: &[String],
    ) -> Result<(Option<i32>, String, f64)> {
        let mut slot = self.server.borrow_mut();
        let server = match slot.as_mut() {
            Some(s) => s,
            None => slot.insert(Server::start(py, &self.ws, log)?),
        };
        if let Some(a) = server.ask(log, argv) {
            return Ok((Some(a.code), format!("exit status: {}", a.code), a.cpu_s));
        }
        let ended = server.end(true);
        *slot = None;
        let (status, cpu) = ended.map_err(|e| Error::Colmap(format!("pycolmap: {e}")))?;
        // No answer is a failure whatever the status: the stage did not report.
        let code = status.code().filter(|&c| c != 0);
        let how = format!("the driver ended without answering, {status}");
        Ok((code, how, cpu))
    }

    /// Runs `command` (the program first) as stage `name` of `engine` with stdout and stderr in
    /// `logs/<name>.log`; its record also when it failed, with the error naming the stage and
    /// its log; Err only when the program could not be started.
    fn try_command(
        &self,
        engine: &str,
        name: &str,
        command: Vec<String>,
    ) -> Result<(StageRecord, Option<Error>)> {
        self.timed(engine, name, command, |command, file, log| {
            let err = file.try_clone().map_err(|e| Error::io(log, e))?;
            let mut cmd = Command::new(&command[0]);
            cmd.args(&command[1..])
                .stdin(Stdio::null())
                .stdout(file)
                .stderr(err);
            die_with_parent(&mut cmd);
            let (status, cpu_s) = cmd
                .spawn()
                .and_then(|child| wait_with_cpu(&child))
                .map_err(|e| Error::Colmap(format!("{}: cannot run: {e}", command[0])))?;
            let failed = (!status.success()).then(|| status.to_string());
            Ok((status.code(), failed, cpu_s))
        })
    }
}

/// Writes `project.ini` from `colmap project_generator`'s defaults with this workspace's paths
/// (absolute) and settings filled in.
fn write_project_ini(runner: &Runner, rec: &mut Record, o: &SparseOptions) -> Result<()> {
    let ws = runner.ws.as_path();
    let tmp = ws.join(crate::output::temp_name("project.ini".as_ref()));
    let stage = runner.stage(
        "project_generator",
        &[
            ("--output_path", tmp.display().to_string()),
            ("--quality", "high".into()),
        ],
    );
    let text = std::fs::read_to_string(&tmp).map_err(|e| Error::io(&tmp, e));
    let _ = std::fs::remove_file(&tmp);
    rec.stages.push(stage?);
    let mut text = text?;
    let p = |n: &str| ws.join(n).display().to_string();
    let mut set = vec![
        ("", "database_path", p("database.db")),
        ("", "image_path", p("images")),
        ("ImageReader", camera_key(rec).1, "true".into()),
        ("ImageReader", "camera_model", o.camera_model.clone()),
        ("SequentialMatching", "overlap", o.overlap.to_string()),
    ];
    if rec.masks > 0 {
        set.push(("ImageReader", "mask_path", p("masks")));
    }
    if let Some(params) = &o.camera_params {
        set.push(("ImageReader", "camera_params", params.clone()));
    }
    if let Some(n) = o.max_features {
        set.push(("SiftExtraction", "max_num_features", n.to_string()));
    }
    for (section, key, value) in set {
        text = ini_set(&text, section, key, &value);
    }
    fsutil::write_atomic(&ws.join("project.ini"), text.as_bytes())
}

/// `text` (an ini file) with `key` in `[section]` (`""`: before the first section) set to
/// `value`; the key is appended to the section (created at the end if absent) when missing.
pub fn ini_set(text: &str, section: &str, key: &str, value: &str) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut current = String::new();
    let mut done = false;
    let mut section_end: Option<usize> = None;
    for line in text.lines() {
        let t = line.trim();
        if t.starts_with('[') && t.ends_with(']') {
            if current == section && !done {
                section_end = Some(out.len());
            }
            current = t[1..t.len() - 1].to_string();
        } else if current == section && !done {
            if let Some((k, _)) = t.split_once('=') {
                if k.trim() == key {
                    out.push(format!("{key}={value}"));
                    done = true;
                    continue;
                }
            }
        }
        out.push(line.to_string());
    }
    if !done {
        let entry = format!("{key}={value}");
        if current == section {
            out.push(entry);
        } else if let Some(i) = section_end {
            out.insert(i, entry);
        } else {
            out.push(format!("[{section}]"));
            out.push(entry);
        }
    }
    let mut s = out.join("\n");
    s.push('\n');
    s
}

/// Human-readable summary of a record.
pub fn render(rec: &Record) -> String {
    let mut s = format!(
        "workspace: {}\ncolmap:    {} ({})\nimages:    {} ({} masks)\n",
        rec.workspace.display(),
        rec.colmap_version,
        rec.colmap.display(),
        rec.images,
        rec.masks
    );
    if let Some(py) = &rec.pycolmap {
        s += &format!(
            "pycolmap:  {} ({}): the sparse stages{}\n",
            py.version,
            py.python.display(),
            if rec.rig {
                ", the views of a keyframe one rig frame"
            } else {
                ""
            }
        );
    }
    for st in &rec.stages {
        s += &format!("stage:     {:<20} {:>8.1} s\n", st.stage, st.seconds);
    }
    for m in &rec.models {
        s += &format!(
            "model:     {:<20} {} of {} images registered, {} points, mean reprojection error {}\n",
            m.path,
            m.registered_images,
            rec.images,
            m.points3d,
            m.mean_reprojection_error
                .map(|e| format!("{e:.3} px"))
                .unwrap_or_else(|| "-".into())
        );
    }
    if let Some(g) = &rec.georegistration {
        let r = &g.residuals;
        s += &format!(
            "georeg:    {} (ENU metres from {:.7}, {:.7}, {:.2} m): {} images, residual mean {:.3} m, \
             median {:.3} m, max {:.3} m, scale {:.6}\n",
            g.model, g.origin.lat_deg, g.origin.lon_deg, g.origin.alt_m, r.images, r.mean_m,
            r.median_m, r.max_m, g.scale
        );
    }
    if let Some(d) = &rec.dataset {
        s += &format!(
            "dataset:   {} ({} PINHOLE images, {} masks, transforms.json)\n",
            rec.workspace.join(&d.path).display(),
            d.images,
            d.masks
        );
    }
    s += &format!(
        "gui:       colmap gui --project_path {}\n",
        rec.workspace.join("project.ini").display()
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_params_are_numbers() {
        assert_eq!(
            crate::sparse::camera_params("448, 448,320,180.5").unwrap(),
            vec![448.0, 448.0, 320.0, 180.5]
        );
        let e = crate::sparse::camera_params("448,,320").unwrap_err();
        assert!(e.to_string().contains("`` is not a number"), "{e}");
    }

    #[test]
    fn ini_set_replaces_appends_and_creates() {
        let t = "a=1\ndatabase_path=\n[ImageReader]\nmask_path=\ncamera_model=X\n[Other]\nk=v\n";
        let t = ini_set(t, "", "database_path", "/w/db");
        let t = ini_set(&t, "ImageReader", "camera_model", "PINHOLE");
        let t = ini_set(&t, "ImageReader", "single_camera", "true");
        let t = ini_set(&t, "New", "x", "1");
        assert_eq!(
            t,
            "a=1\ndatabase_path=/w/db\n[ImageReader]\nmask_path=\ncamera_model=PINHOLE\nsingle_camera=true\n[Other]\nk=v\n[New]\nx=1\n"
        );
    }
}
