//! `keyframer run`: applies a workflow to many inputs, one output folder each, a bounded number at
//! a time; a failing input is reported and the rest go on; finished inputs (a `done.json` written
//! last, matching workflow and input) are skipped, so a re-run after a crash finishes the job.

use crate::error::{Error, Result};
use crate::output::Inputs;
use crate::workflow::Workflow;
use crate::{export, fsutil, select};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use crate::output::{DONE, MARKER};

/// Which part of a batch this process handles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// 0-based index.
    pub index: usize,
    /// Number of shards.
    pub count: usize,
}

impl std::str::FromStr for Shard {
    type Err = String;
    /// `I/N` with 0 <= I < N.
    fn from_str(s: &str) -> std::result::Result<Shard, String> {
        let bad = || format!("`{s}` is not I/N with 0 <= I < N (e.g. 0/3)");
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let index: usize = i.trim().parse().map_err(|_| bad())?;
        let count: usize = n.trim().parse().map_err(|_| bad())?;
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

/// Settings of a batch run.
#[derive(Debug, Clone)]
pub struct RunSettings {
    /// Inputs in the order given.
    pub inputs: Vec<PathBuf>,
    /// The file the inputs were listed in (`--inputs-from`), when they were.
    pub inputs_from: Option<PathBuf>,
    /// Folder receiving one sub-folder per input.
    pub out: PathBuf,
    /// Redo finished inputs.
    pub force: bool,
    /// Inputs processed at the same time.
    pub jobs: usize,
    /// This process's share of the inputs.
    pub shard: Option<Shard>,
    /// No per-step progress.
    pub quiet: bool,
}

/// What happened to one input.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// Processed now.
    Done,
    /// Already finished by an earlier run with the same workflow and input.
    Skipped,
    /// Processed, but some frames could not be decoded or exported.
    Partial,
    /// Failed; see `error`.
    Failed,
}

/// One line of the summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InputReport {
    /// The input as given.
    pub input: PathBuf,
    /// Its output folder.
    pub folder: PathBuf,
    /// What happened to it.
    pub status: Status,
    /// Number of keyframes selected.
    pub keyframes: Option<usize>,
    /// Images written per export, in workflow order.
    pub exported: Vec<usize>,
    /// What each `[[reconstruct]]` made, in workflow order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub reconstructed: Vec<Reconstructed>,
    /// Wall time in seconds.
    pub seconds: f64,
    /// Problem, for failed and partial inputs.
    pub error: Option<String>,
}

/// What a `[[reconstruct]]` made of one input.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Reconstructed {
    /// Its folder (in the input's folder).
    pub name: String,
    /// Keyframes at the end of the loop.
    pub keyframes: usize,
    /// Frames the loop added.
    pub added: usize,
    /// How the loop ended.
    pub outcome: crate::reconstruct::Outcome,
}

/// Contents of `done.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Done {
    workflow_hash: String,
    input: PathBuf,
    fingerprint: fsutil::Fingerprint,
    report: InputReport,
}

/// The result folder of one input: its file name (letters, digits, `-`, `_`, `.` kept, anything
/// else `_`; cut to 223 bytes) and the 16 hex digits of a hash of its resolved absolute path, so
/// the same input gets the same folder whatever the other inputs of a run, and two inputs never
/// share one.
pub fn folder_name(input: &Path) -> String {
    use std::os::unix::ffi::OsStrExt;
    let resolved = crate::output::resolve(input);
    // Named by the file it resolves to, so two spellings (or a link) of one input meet.
    let base: String = resolved
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "input".into())
        .replace(
            |c: char| !(c.is_ascii_alphanumeric() || "-_.".contains(c)),
            "_",
        );
    let hash = crate::output::fnv1a64(resolved.as_os_str().as_bytes());
    // Within NAME_MAX with the hash and the `.NAME.keyframer-new` it is made under (the base is
    // ASCII by now, so any cut is a character boundary).
    let room = crate::output::NAME_MAX - ".-0123456789abcdef.keyframer-new".len();
    format!("{}-{hash:016x}", &base[..base.len().min(room)])
}

/// The result folder names of `inputs`, in order; an input named twice (under two spellings)
/// is refused.
pub fn folder_names(inputs: &[PathBuf]) -> Result<Vec<String>> {
    let names: Vec<String> = inputs.iter().map(|p| folder_name(p)).collect();
    for (i, n) in names.iter().enumerate() {
        if let Some(j) = names[..i].iter().position(|m| m == n) {
            let (a, b) = (inputs[j].display(), inputs[i].display());
            let msg = format!("{a} and {b} are the same input");
            return Err(Error::param("INPUT", msg));
        }
    }
    Ok(names)
}

/// Contents of the `.keyframer-run` marker: the input the folder belongs to.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Marker {
    tool: String,
    input: PathBuf,
}

/// The inputs of `shard`: positions i with i mod N == I in the list sorted by path, so every
/// process given the same list agrees on the split whatever order the list came in.
pub fn shard_of(inputs: &[PathBuf], shard: Option<Shard>) -> Vec<usize> {
    let mut order: Vec<usize> = (0..inputs.len()).collect();
    order.sort_by(|&a, &b| inputs[a].cmp(&inputs[b]));
    let mut mine: Vec<usize> = order
        .into_iter()
        .enumerate()
        .filter(|(pos, _)| shard.is_none_or(|s| pos % s.count == s.index))
        .map(|(_, i)| i)
        .collect();
    mine.sort_unstable();
    mine
}

/// Runs the workflow over the inputs; returns one report per handled input, in input order.
pub fn run(workflow: &Workflow, s: &RunSettings) -> Result<Vec<InputReport>> {
    if s.inputs.is_empty() {
        return Err(Error::param("INPUT", "give at least one input"));
    }
    if s.jobs == 0 {
        return Err(Error::param("jobs", "must be at least 1"));
    }
    let mut sorted = s.inputs.clone();
    sorted.sort();
    sorted.dedup();
    if sorted.len() != s.inputs.len() {
        return Err(Error::param("INPUT", "an input is listed twice"));
    }
    crate::output::check_not_input(&s.out, &read_by(workflow, s))?;
    // A workflow that reconstructs needs COLMAP (and its mapper): said before any input is read.
    for (_, o) in &workflow.reconstructs {
        crate::colmap::extend::loop_engine(o.engine, o.mapper, None)?;
    }
    let names = folder_names(&s.inputs)?;
    std::fs::create_dir_all(&s.out).map_err(|e| Error::io(&s.out, e))?;
    let mine = shard_of(&s.inputs, s.shard);
    let total = mine.len();
    let next = AtomicUsize::new(0);
    let finished = AtomicUsize::new(0);
    let reports: Mutex<Vec<(usize, InputReport)>> = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..s.jobs.min(total.max(1)) {
            scope.spawn(|| loop {
                let k = next.fetch_add(1, Ordering::SeqCst);
                let Some(&i) = mine.get(k) else { break };
                let folder = s.out.join(&names[i]);
                let r = run_one(workflow, &s.inputs[i], &folder, s);
                let n = finished.fetch_add(1, Ordering::SeqCst) + 1;
                log_line(n, total, &r);
                if let Ok(mut v) = reports.lock() {
                    v.push((i, r));
                }
            });
        }
    });
    let mut v = reports.into_inner().unwrap_or_default();
    v.sort_by_key(|(i, _)| *i);
    Ok(v.into_iter().map(|(_, r)| r).collect())
}

/// What a run reads: the workflow and the files it names, the list of inputs, and what the
/// `select` of each input reads (the input and its telemetry).
fn read_by(workflow: &Workflow, s: &RunSettings) -> Inputs {
    let mut inputs = Inputs::none().with("workflow", &workflow.path);
    inputs.extend(&workflow.inputs);
    if let Some(list) = &s.inputs_from {
        inputs.add("list of inputs", list);
    }
    for input in &s.inputs {
        let select = select::SelectSettings::from_workflow(workflow, input, Path::new(""), true);
        inputs.extend(&select.inputs());
    }
    inputs
}

fn log_line(n: usize, total: usize, r: &InputReport) {
    let what = match r.status {
        Status::Done | Status::Partial => format!(
            "{} keyframes, exports {:?}{} ({:.1} s)",
            r.keyframes.unwrap_or(0),
            r.exported,
            (r.reconstructed.iter())
                .map(|c| format!(
                    ", {}: {} keyframes (+{}), {}",
                    c.name, c.keyframes, c.added, c.outcome
                ))
                .collect::<String>(),
            r.seconds
        ),
        Status::Skipped => "already done".into(),
        Status::Failed => format!("FAILED: {}", r.error.as_deref().unwrap_or("")),
    };
    eprintln!("[{n}/{total}] {}: {what}", r.input.display());
}

fn run_one(w: &Workflow, input: &Path, folder: &Path, s: &RunSettings) -> InputReport {
    let t = Instant::now();
    let mut report = InputReport {
        input: input.to_path_buf(),
        folder: folder.to_path_buf(),
        status: Status::Failed,
        keyframes: None,
        exported: Vec::new(),
        reconstructed: Vec::new(),
        seconds: 0.0,
        error: None,
    };
    // One run per folder: locked beside it (it may not exist yet) until done.json is written.
    let result = crate::output::lock::beside(folder).and_then(|_held| {
        let status = process(w, input, folder, s, &mut report);
        report.seconds = t.elapsed().as_secs_f64();
        report.status = status?;
        record_done(w, input, folder, &report)
    });
    if let Err(e) = result {
        report.status = Status::Failed;
        report.error = Some(e.to_string());
    }
    report
}

/// Records a done or partial input as finished (`done.json`).
fn record_done(w: &Workflow, input: &Path, folder: &Path, report: &InputReport) -> Result<()> {
    if !matches!(report.status, Status::Done | Status::Partial) {
        return Ok(());
    }
    let (_, fingerprint) = select::identify(input)?;
    let done = Done {
        workflow_hash: format!("{:016x}", w.hash),
        input: fsutil::absolute(input),
        fingerprint,
        report: report.clone(),
    };
    let text = serde_json::to_string_pretty(&done)
        .map_err(|e| Error::output(folder.join(DONE), e.to_string()))?;
    fsutil::write_atomic(&folder.join(DONE), text.as_bytes())
}

fn process(
    w: &Workflow,
    input: &Path,
    folder: &Path,
    s: &RunSettings,
    report: &mut InputReport,
) -> Result<Status> {
    let done_path = folder.join(DONE);
    if !s.force && finished_before(w, input, &done_path, report) {
        return Ok(Status::Skipped);
    }
    claim_folder(input, folder, s.force)?;
    let _ = std::fs::remove_file(&done_path);
    select_and_export(w, input, folder, s.quiet, report)
}

/// Whether `done_path` records this workflow finished on this unchanged input (its counts are
/// then copied into `report`).
fn finished_before(w: &Workflow, input: &Path, done_path: &Path, report: &mut InputReport) -> bool {
    let Some(done) = read_done(done_path) else {
        return false;
    };
    let same_input = select::identify(input).is_ok_and(|(_, f)| f == done.fingerprint);
    if done.workflow_hash == format!("{:016x}", w.hash) && same_input {
        report.keyframes = done.report.keyframes;
        report.exported = done.report.exported.clone();
        report.reconstructed = done.report.reconstructed.clone();
        return true;
    }
    false
}

/// Makes `folder` this input's run folder, or refuses: a folder keyframer did not make is never
/// written into; one made for this input is redone; one recorded for another input needs
/// `force`.
fn claim_folder(input: &Path, folder: &Path, force: bool) -> Result<()> {
    let marker = Marker {
        tool: "keyframer run".into(),
        input: crate::output::resolve(input),
    };
    let marker_text = serde_json::to_string_pretty(&marker)
        .map_err(|e| Error::output(folder.join(MARKER), e.to_string()))?
        + "\n";
    if folder.exists() {
        let empty = std::fs::read_dir(folder)
            .map(|mut d| d.next().is_none())
            .unwrap_or(false);
        let recorded = crate::output::read_text(&folder.join(MARKER))
            .ok()
            .map(|t| serde_json::from_str::<Marker>(&t).ok().map(|m| m.input));
        let refusal = match recorded {
            None if !empty => {
                Some("exists and was not made by `keyframer run`; move it away".to_string())
            }
            Some(Some(other)) if other != marker.input && !force => Some(format!(
                "holds the results of another input ({}); pass --force to replace them",
                other.display()
            )),
            Some(None) if !force => Some(format!(
                "its {MARKER} does not say which input it belongs to (an older keyframer); pass --force to replace it"
            )),
            _ => None,
        };
        if let Some(msg) = refusal {
            return Err(Error::output(folder, msg));
        }
        crate::output::clear_stale_temps_of(folder, None);
        fsutil::write_atomic(&folder.join(MARKER), marker_text.as_bytes())?;
    } else {
        // The folder appears with its marker inside (made under a hidden name, then renamed),
        // so a kill at any moment never leaves an unmarked folder behind.
        let name = folder.file_name().unwrap_or_default().to_string_lossy();
        let tmp = folder.with_file_name(format!(".{name}.keyframer-new"));
        if tmp.exists() {
            std::fs::remove_dir_all(&tmp).map_err(|e| Error::io(&tmp, e))?;
        }
        std::fs::create_dir_all(&tmp).map_err(|e| Error::io(&tmp, e))?;
        std::fs::write(tmp.join(MARKER), marker_text.as_bytes())
            .map_err(|e| Error::io(tmp.join(MARKER), e))?;
        std::fs::rename(&tmp, folder).map_err(|e| Error::io(folder, e))?;
    }
    Ok(())
}

/// The workflow's select, then each export, then each reconstruction loop, into `folder`.
fn select_and_export(
    w: &Workflow,
    input: &Path,
    folder: &Path,
    quiet: bool,
    report: &mut InputReport,
) -> Result<Status> {
    let project = folder.join("project.json");
    let settings = select::SelectSettings::from_workflow(w, input, &project, true);
    // A rig export of pinhole frames is refused by the select, before any frame is analysed.
    let rig = w.exports.iter().position(|(_, e)| e.views.is_some());
    let sel = select::select(&settings).map_err(|e| match (&e, rig) {
        (Error::Param { name, .. }, Some(i)) if name == "--views" => w.export_error(i, e),
        _ => e,
    })?;
    report.keyframes = Some(sel.project.keyframes.len());
    let mut partial: Vec<String> = sel
        .project
        .decode_problems
        .iter()
        .map(|p| p.to_string())
        .collect();
    for (i, (name, es)) in w.exports.iter().enumerate() {
        let out = folder.join(name);
        let m = export::export(&project, &out, es, true, true).map_err(|e| w.export_error(i, e))?;
        report.exported.push(m.frames.len());
        partial.extend(
            m.missing
                .iter()
                .map(|m| format!("{name}: frame {} not exported: {}", m.index, m.reason)),
        );
    }
    // Each loop's workspace is keyframer's own (the folder is this input's): a loop killed
    // earlier resumes from its state file, another one's content is replaced.
    for (name, options) in &w.reconstructs {
        let rs = crate::reconstruct::ReconstructSettings {
            project: project.clone(),
            out: folder.join(name),
            options: options.clone(),
            force: true,
        };
        let sum = crate::reconstruct::run(&rs, quiet)?;
        report.reconstructed.push(Reconstructed {
            name: name.clone(),
            keyframes: sum.final_keyframes.len(),
            added: sum.added.len(),
            outcome: sum.outcome,
        });
    }
    if partial.is_empty() {
        Ok(Status::Done)
    } else {
        report.error = Some(partial.join("; "));
        Ok(Status::Partial)
    }
}

fn read_done(path: &Path) -> Option<Done> {
    serde_json::from_str(&crate::output::read_text(path).ok()?).ok()
}

/// The summary as a table for stderr; a `reconstructed` column (final keyframes, frames
/// added, how each loop ended) when the workflow has `[[reconstruct]]` tables.
pub fn table(reports: &[InputReport]) -> String {
    let loops = reports.iter().any(|r| !r.reconstructed.is_empty());
    let dash = |s: String| if s.is_empty() { "-".to_string() } else { s };
    let mut out = format!(
        "{:<8} {:>9} {:>16} {:>8}  {}input\n",
        "status",
        "keyframes",
        "exported",
        "seconds",
        if loops {
            format!("{:<24}  ", "reconstructed")
        } else {
            String::new()
        }
    );
    for r in reports {
        let status = match r.status {
            Status::Done => "done",
            Status::Skipped => "skipped",
            Status::Partial => "partial",
            Status::Failed => "FAILED",
        };
        let exported: Vec<String> = r.exported.iter().map(|n| n.to_string()).collect();
        let rec: Vec<String> = (r.reconstructed.iter())
            .map(|l| format!("{} (+{}) {}", l.keyframes, l.added, l.outcome.short()))
            .collect();
        out.push_str(&format!(
            "{status:<8} {:>9} {:>16} {:>8.1}  {}{}\n",
            r.keyframes.map_or("-".into(), |k| k.to_string()),
            dash(exported.join(",")),
            r.seconds,
            if loops {
                format!("{:<24}  ", dash(rec.join(", ")))
            } else {
                String::new()
            },
            r.input.display()
        ));
        if let Some(e) = &r.error {
            out.push_str(&format!("         {e}\n"));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_has_a_reconstructed_column_only_for_loops() {
        let mut r = InputReport {
            input: PathBuf::from("a.mp4"),
            folder: PathBuf::from("out/a"),
            status: Status::Done,
            keyframes: Some(18),
            exported: vec![18],
            reconstructed: Vec::new(),
            seconds: 1.5,
            error: None,
        };
        let plain = table(std::slice::from_ref(&r));
        assert!(!plain.contains("reconstructed"), "{plain}");
        r.reconstructed.push(Reconstructed {
            name: "reconstruct".into(),
            keyframes: 21,
            added: 3,
            outcome: crate::reconstruct::Outcome::Connected,
        });
        let t = table(&[r]);
        let lines: Vec<&str> = t.lines().collect();
        assert!(lines[0].contains("reconstructed"), "{t}");
        assert!(lines[1].contains("21 (+3) connected"), "{t}");
        assert!(lines[1].ends_with("a.mp4"), "{t}");
    }

    #[test]
    fn shards_cover_every_input_once_whatever_the_order() {
        let inputs: Vec<PathBuf> = (0..10)
            .map(|i| PathBuf::from(format!("v{i}.mp4")))
            .collect();
        let mut rev = inputs.clone();
        rev.reverse();
        let mut seen = Vec::new();
        for k in 0..3 {
            let s = Some(Shard { index: k, count: 3 });
            let a: Vec<&PathBuf> = shard_of(&inputs, s).iter().map(|&i| &inputs[i]).collect();
            let mut b: Vec<&PathBuf> = shard_of(&rev, s).iter().map(|&i| &rev[i]).collect();
            b.sort();
            assert_eq!(a, b, "same split for a reordered list");
            seen.extend(a);
        }
        seen.sort();
        assert_eq!(seen, inputs.iter().collect::<Vec<_>>());
        assert!("3/3".parse::<Shard>().is_err());
        assert_eq!("1/3".parse::<Shard>(), Ok(Shard { index: 1, count: 3 }));
    }

    #[test]
    fn folder_names_are_unique_and_stable() {
        let a = PathBuf::from("/data/a/clip.mp4");
        let b = PathBuf::from("/data/b/clip.mp4");
        let n = folder_names(&[a.clone(), b.clone(), PathBuf::from("/data/c d.mp4")]).unwrap();
        assert!(n[0].starts_with("clip.mp4-") && n[1].starts_with("clip.mp4-"));
        assert_ne!(n[0], n[1]);
        assert!(n[2].starts_with("c_d.mp4-"));
        // The same input, the same folder, whatever else is in the run.
        assert_eq!(folder_names(std::slice::from_ref(&b)).unwrap()[0], n[1]);
        assert_eq!(folder_name(Path::new("/data/x/../b/clip.mp4")), n[1]);
        assert!(folder_names(&[a.clone(), PathBuf::from("/data/a/./clip.mp4")]).is_err());
    }
}
