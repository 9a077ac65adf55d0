//! One round of `keyframer reconstruct` in a COLMAP workspace. The first round makes the
//! workspace as `keyframer colmap --sparse` does; a later round adds only the new images: they
//! are linked into `images/`, features are extracted for them alone (`--image_list_path`), the
//! matcher runs again (COLMAP skips the pairs its database already holds) and the mapper maps
//! again, continuing from the largest model (`--input_path`) or afresh. Guarantees: a mapper that
//! makes no model is a result (no image registered), not an error; any other failing stage is an
//! error naming the stage and its log; `colmap.json` lists every file keyframer and COLMAP wrote
//! and is rewritten at the end of every round; the new model replaces `sparse/` only once the
//! mapper has finished (it is written to `sparse.next/` first). The caller's [`Runner`] runs the
//! stages, so that a loop's rounds and mapping trials share one pycolmap process.

use super::pycolmap::{Engine, Pycolmap};
use super::{
    check_export, extract_and_match, fill_workspace, locate, mapper_args, ours_now, p, py_extract,
    py_mapper_args, py_match, read_models, read_record, remove_ours, write_project_ini,
    write_record, Colmap, ColmapSettings, Record, Runner, StageRecord,
};
use crate::error::{Error, Result};
use crate::fsutil;
use crate::sparse::{MapperKind, Mapping, SparseOptions};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Folder the mapper of a later round writes into before it replaces `sparse/`.
pub const NEXT: &str = "sparse.next";
/// The list of new images given to `feature_extractor` (inside `logs/`, which keyframer owns).
const NEW_LIST: &str = "logs/new_images.txt";

/// The COLMAP command of a mapper kind (and the pycolmap driver's stage of that name).
pub fn mapper_command(kind: MapperKind) -> &'static str {
    match kind {
        MapperKind::Incremental => "mapper",
        MapperKind::Global => "global_mapper",
    }
}

/// Whether the installed COLMAP offers `command` (listed by `colmap help`).
pub fn offers(colmap: &Colmap, command: &str) -> bool {
    (colmap.help.lines()).any(|l| l.split_whitespace().any(|w| w == command))
}

/// Finds COLMAP and, unless pycolmap maps (`py`), checks that the command offers the mapper
/// `kind`, saying what is missing.
pub fn locate_with(kind: MapperKind, py: bool) -> Result<Colmap> {
    let colmap = locate()?;
    if py {
        return Ok(colmap);
    }
    let command = mapper_command(kind);
    if !offers(&colmap, command) {
        return Err(Error::param(
            "mapper",
            format!(
                "{} ({}) has no `{command}` command (`colmap help` does not list it): the global mapper came with COLMAP 3.12 (it absorbed GLOMAP); install a recent COLMAP (or point {} at one) or use the incremental mapper",
                colmap.bin.display(),
                colmap.version,
                super::COLMAP_ENV
            ),
        ));
    }
    Ok(colmap)
}

/// The engine of a `reconstruct` loop: the `colmap` command (checked to offer the mapper
/// `kind`), the pycolmap that runs the sparse stages (None: the command), and the line to say
/// about the choice (the caller says it once the output folder is accepted). `pycolmap` needs
/// it (an error naming what to install); `auto` takes it when found, else the command with a
/// one-line hint. A loop being resumed passes the engine its state recorded as `resumed`
/// (Some(None): the command) and keeps it.
pub fn loop_engine(
    engine: Engine,
    kind: MapperKind,
    resumed: Option<Option<&Pycolmap>>,
) -> Result<(Colmap, Option<Pycolmap>, Option<String>)> {
    let (py, line) = match (resumed, engine) {
        (Some(None), _) | (None, Engine::Colmap) => (None, None),
        (Some(Some(was)), _) => {
            let py = super::pycolmap::locate().map_err(|e| {
                Error::Colmap(format!(
                    "this workspace's loop runs through pycolmap {}, which is not found now: {e}",
                    was.version
                ))
            })?;
            let line = (py.version != was.version).then(|| {
                format!(
                    "reconstruct: the loop began with pycolmap {}; it goes on with pycolmap {} ({})",
                    was.version,
                    py.version,
                    py.python.display()
                )
            });
            (Some(py), line)
        }
        (None, Engine::Pycolmap) => (Some(super::pycolmap::locate()?), None),
        (None, Engine::Auto) => match super::pycolmap::locate() {
            Ok(py) => {
                let line = format!(
                    "reconstruct: COLMAP through pycolmap {} ({}); --engine colmap runs the colmap command",
                    py.version,
                    py.python.display()
                );
                (Some(py), Some(line))
            }
            Err(e) => {
                let line = format!(
                    "reconstruct: the colmap command runs the loop; pycolmap's newer mapper folds less often: {e}"
                );
                (None, Some(line))
            }
        },
    };
    Ok((locate_with(kind, py.is_some())?, py, line))
}

/// One round: with `new_images` None the workspace is made from the export (its images all
/// new); otherwise only `new_images` (file names in the export) are added to it. The sparse
/// stages run through pycolmap when `py` is given (a workspace keeps the engine of its first
/// round: a later round through the other one is refused). Returns the record as written, with
/// the models of this round's mapping (none when the mapper made none).
///
/// `runner` (made on `a`'s workspace) runs the stages, and may run more rounds and trials after.
pub fn round(
    runner: &Runner,
    a: &ColmapSettings,
    kind: MapperKind,
    mapping: Mapping,
    new_images: Option<&[String]>,
    py: Option<&Pycolmap>,
) -> Result<Record> {
    a.options.check()?;
    let colmap = &runner.colmap;
    let (export, manifest, ws) = check_export(a)?;
    if ws != runner.ws {
        return Err(Error::Colmap(format!(
            "the runner works in {}, not in the workspace {}",
            runner.ws.display(),
            ws.display()
        )));
    }
    // The workspace stays locked until its record is written last.
    let mut _dir = None;
    let mut _lock = None;
    let mut rec = match new_images {
        None => {
            let (masks, held) = fill_workspace(&ws, &export, &manifest, a.force)?;
            _dir = Some(held);
            Record {
                pycolmap: py.cloned(),
                ..Record::new(colmap, &export, &ws, manifest.frames.len(), masks, a)
            }
        }
        Some(new) => {
            _lock = Some(crate::output::lock::folder(&ws)?);
            let rec = read_record(&ws)?;
            same_engine(&ws, &rec, py)?;
            link_new(&ws, &export, &manifest, new)?;
            rec
        }
    };
    rec.images = manifest.frames.len();
    rec.files = ours_now(&ws);
    rec.started_unix_s = fsutil::now_unix_s();
    rec.finished = false;
    rec.error = None;
    write_record(&ws, &rec)?;
    let result = (|| -> Result<()> {
        let list = match new_images {
            None => {
                write_project_ini(runner, &mut rec, &a.options)?;
                None
            }
            Some(new) => {
                let list = ws.join(NEW_LIST);
                let mut text = new.join("\n");
                text.push('\n');
                fsutil::write_atomic(&list, text.as_bytes())?;
                Some(list)
            }
        };
        match py {
            Some(py) => {
                py_extract(runner, &mut rec, &a.options, py, list.as_deref())?;
                py_match(runner, &mut rec, &a.options, py, list.is_some())?;
            }
            None => extract_and_match(runner, &mut rec, &a.options, list.as_deref())?,
        }
        let continue_from = match (new_images, mapping) {
            (Some(_), Mapping::Continue) => super::largest(&rec.models).map(|m| ws.join(&m.path)),
            _ => None,
        };
        map_into_sparse(runner, &mut rec, a, kind, continue_from.as_deref(), py)
    })();
    if let Err(e) = &result {
        rec.error = Some(e.to_string());
    }
    rec.finished = true;
    rec.files = ours_now(&ws);
    write_record(&ws, &rec)?;
    result.map(|()| rec)
}

/// A mapping of the workspace's database made again ([`remap_trial`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Trial {
    /// The incremental mapper (as many models as it finds) with COLMAP's random generator
    /// seeded by this instead of the stages' fixed seed.
    Seed(u64),
    /// The incremental mapper, one model from this initial pair (COLMAP image ids).
    Init(i64, i64),
    /// The global mapper (pycolmap's).
    Global,
}

/// The folder, in the COLMAP workspace, of the mapping trial `n` (1-based) that [`remap_trial`]
/// writes (inside [`NEXT`], so that the workspace's records own it).
pub fn trial_dir(n: usize) -> String {
    format!("{NEXT}/init{n}")
}

/// Maps the workspace's database afresh into [`trial_dir`]`(n)` by `runner` (the loop's) and
/// leaves `sparse/` as it is, as `trial` says: the incremental mapper with another random seed,
/// or making one model from an initial pair, or the global mapper (pycolmap's, `py` needed).
/// Returns the record with the trial's models (their paths in the trial folder); the mapper's
/// stage is added to `colmap.json`. A mapper that makes no model is a trial without models.
pub fn remap_trial(
    runner: &Runner,
    a: &ColmapSettings,
    n: usize,
    trial: Trial,
    py: Option<&Pycolmap>,
) -> Result<Record> {
    let kind = match trial {
        Trial::Global => MapperKind::Global,
        Trial::Seed(_) | Trial::Init(..) => MapperKind::Incremental,
    };
    if kind == MapperKind::Global && py.is_none() {
        return Err(Error::Colmap(
            "a global mapping trial runs through pycolmap".into(),
        ));
    }
    let ws = runner.ws.as_path();
    let _lock = crate::output::lock::folder(ws)?;
    let mut rec = read_record(ws)?;
    same_engine(ws, &rec, py)?;
    let name = trial_dir(n);
    clear(ws, &name)?;
    let output = ws.join(&name);
    std::fs::create_dir_all(&output).map_err(|e| Error::io(&output, e))?;
    let mut with_init = a.options.clone();
    let options = &mut with_init.mapper_option;
    let mut seed = None;
    match trial {
        Trial::Init(a, b) => {
            options.retain(|m| !m.contains("init_image_id") && !m.contains("multiple_models"));
            options.push(format!("init_image_id1={a}"));
            options.push(format!("init_image_id2={b}"));
            // One model, from that pair: with more, COLMAP 3.8 starts every further model from
            // the same pair again (52 times, 31 s against 0.7 s on an 18-image database).
            options.push("multiple_models=0".into());
        }
        Trial::Seed(s) => seed = Some(s),
        Trial::Global => {}
    }
    let (stage, failure) = try_mapper(runner, rec.rig, kind, &output, &with_init, None, seed, py)?;
    rec.stages.push(stage);
    rec.files = ours_now(ws);
    write_record(ws, &rec)?;
    if let Some(e) = failure {
        return Err(e);
    }
    rec.models = read_models(ws, &output)?;
    Ok(rec)
}

/// Ends the mapping trials `1..=trials` of the workspace `ws`: trial `keep` (if any) replaces
/// `sparse/`, the others are removed. Returns the record as written.
pub fn end_trials(ws: &Path, trials: usize, keep: Option<usize>) -> Result<Record> {
    let _lock = crate::output::lock::folder(ws)?;
    let mut rec = read_record(ws)?;
    if let Some(n) = keep {
        clear(ws, "sparse")?;
        let sparse = ws.join("sparse");
        let from = ws.join(trial_dir(n));
        std::fs::rename(&from, &sparse).map_err(|e| Error::io(&sparse, e))?;
        rec.models = read_models(ws, &sparse)?;
    }
    for n in 1..=trials {
        clear(ws, &trial_dir(n))?;
    }
    clear(ws, NEXT)?;
    rec.files = ours_now(ws);
    write_record(ws, &rec)?;
    Ok(rec)
}

/// Refuses to extend the workspace `ws` (record `rec`) through an engine other than the one its
/// first round ran: a database written by pycolmap is not COLMAP 3.8's, and the other way round
/// the rounds would mix two COLMAPs.
fn same_engine(ws: &Path, rec: &Record, py: Option<&Pycolmap>) -> Result<()> {
    let name = |p: Option<&Pycolmap>| match p {
        Some(p) => format!("pycolmap {}", p.version),
        None => "the colmap command".to_string(),
    };
    if rec.pycolmap.is_some() != py.is_some() {
        let msg = format!(
            "was made through {}; this round would run {}: continue it with the same --engine, or start afresh in another folder",
            name(rec.pycolmap.as_ref()),
            name(py)
        );
        return Err(Error::output(ws, msg));
    }
    Ok(())
}

/// Links the new images (and their masks) of the export into the workspace.
fn link_new(
    ws: &Path,
    export: &Path,
    manifest: &crate::manifest::Manifest,
    new: &[String],
) -> Result<()> {
    let export_masks = export.join(crate::manifest::MASK_DIR);
    for name in new {
        let f = manifest
            .frames
            .iter()
            .find(|f| &f.file == name)
            .ok_or_else(|| Error::input(export, format!("{name}: not in the export's manifest")))?;
        let to = ws.join("images").join(&f.file);
        if !to.is_file() {
            super::link_or_copy(&crate::manifest::image_path(export, f), &to)?;
        }
        if let Some(m) = &f.mask {
            let dir = ws.join("masks");
            std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
            let to = dir.join(format!("{}.png", f.file));
            if !to.is_file() {
                super::link_or_copy(&export_masks.join(m), &to)?;
            }
        }
    }
    Ok(())
}

/// Runs the mapper into `sparse.next/` (continuing from `continue_from` when given), then
/// replaces `sparse/` with it and records the models. A mapper that found no model leaves an
/// empty `sparse/` and no models.
fn map_into_sparse(
    runner: &Runner,
    rec: &mut Record,
    a: &ColmapSettings,
    kind: MapperKind,
    continue_from: Option<&Path>,
    py: Option<&Pycolmap>,
) -> Result<()> {
    let ws = runner.ws.as_path();
    let next = ws.join(NEXT);
    clear(ws, NEXT)?;
    // The command's mapper writes a continued model into the output folder itself; pycolmap
    // writes every model into a numbered folder.
    let output = match (continue_from, py) {
        (Some(_), None) => next.join("0"),
        _ => next.clone(),
    };
    std::fs::create_dir_all(&output).map_err(|e| Error::io(&output, e))?;
    let (stage, failure) = try_mapper(
        runner,
        rec.rig,
        kind,
        &output,
        &a.options,
        continue_from,
        None,
        py,
    )?;
    rec.stages.push(stage);
    if let Some(e) = failure {
        return Err(e);
    }
    clear(ws, "sparse")?;
    let sparse = ws.join("sparse");
    std::fs::rename(&next, &sparse).map_err(|e| Error::io(&sparse, e))?;
    rec.models = read_models(ws, &sparse)?;
    Ok(())
}

/// Runs the mapper `kind` (through pycolmap when `py` is given) with `options`, writing into
/// `output`, continuing the model in `continue_from` when given and seeding COLMAP's random
/// generator with `seed` when given (else the stages' fixed seed). Returns its stage record and
/// its failure, if any: a mapper that keeps no model (COLMAP 3.8 then exits 1) has not failed.
#[allow(clippy::too_many_arguments)]
fn try_mapper(
    runner: &Runner,
    rig: bool,
    kind: MapperKind,
    output: &Path,
    options: &SparseOptions,
    continue_from: Option<&Path>,
    seed: Option<u64>,
    py: Option<&Pycolmap>,
) -> Result<(StageRecord, Option<Error>)> {
    let ws = runner.ws.as_path();
    let mut args = match py {
        Some(_) => py_mapper_args(ws, output, options, rig, kind)?,
        None => mapper_args(ws, output, options)?,
    };
    if let Some(from) = continue_from {
        args.push(("--input_path".into(), p(from)));
    }
    if let Some(seed) = seed {
        // COLMAP's own option of its commands; the driver's mappers take it alike.
        args.push(("--random_seed".into(), seed.to_string()));
    }
    if kind == MapperKind::Global {
        // The global mapper has its own options: only the paths carry over.
        args.retain(|(k, _)| !k.starts_with("--Mapper."));
    }
    let args: Vec<(&str, String)> = args.iter().map(|(k, v)| (k.as_str(), v.clone())).collect();
    let command = mapper_command(kind);
    let (stage, failure) = match py {
        Some(py) => runner.try_py_stage(py, command, &args)?,
        None => runner.try_stage(command, &args)?,
    };
    let no_model = || {
        (std::fs::read_to_string(ws.join(&stage.log)).unwrap_or_default())
            .contains("failed to create sparse model")
    };
    let failure = failure.filter(|_| !no_model());
    Ok((stage, failure))
}

/// Removes the folder `name` of the workspace, which holds only what keyframer and COLMAP wrote
/// (its files are among keyframer's places; anything else in it stops the run).
fn clear(ws: &Path, name: &str) -> Result<()> {
    let dir = ws.join(name);
    if !dir.exists() {
        return Ok(());
    }
    let files: Vec<String> = ours_now(ws)
        .into_iter()
        .filter(|f| Path::new(f).starts_with(name))
        .collect();
    for f in &files {
        crate::output::check_replaceable(&ws.join(f))?;
    }
    remove_ours(ws, &files);
    if dir.exists() {
        let msg = "holds something keyframer did not write (only regular files are removed): move it away";
        return Err(Error::output(dir, msg));
    }
    Ok(())
}
