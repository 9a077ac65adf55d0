//! Workflow files (TOML, `version = 1`): an ordered list of sampler steps and any number of
//! exports, checked completely (file:line and key for every error) before any input is touched,
//! and turned into the same validated settings the `select` / `export` flags produce.

use crate::cli::{ExportArgs, SelectArgs};
use crate::error::{Error, Result};
use crate::export::ExportSettings;
use crate::project::Project;
use crate::select::SelectSettings;
use crate::tomlfile::{self, TomlFile};
use clap::Parser;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The workflow format version this build reads and writes.
pub const VERSION: u32 = 1;

/// A TOML value that is either a number or a string (`120`, `4.5s`, `auto`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum NumOrText {
    /// An integer.
    Int(i64),
    /// A float.
    Float(f64),
    /// A string.
    Text(String),
}

impl NumOrText {
    fn flag_value(&self) -> String {
        match self {
            NumOrText::Int(i) => i.to_string(),
            NumOrText::Float(f) => f.to_string(),
            NumOrText::Text(s) => s.clone(),
        }
    }
}

/// `[analysis]`: how frames are analysed (shared by every sampler).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Analysis {
    /// `gpu` (default) or `opencv`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub backend: Option<String>,
    /// GPU adapter, part of its name.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adapter: Option<String>,
    /// Width frames are scaled to for movement analysis.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub analysis_width: Option<u32>,
    /// Flow measured between frames this many apart (`--flow-stride`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flow_stride: Option<u32>,
    /// `median` or `trimmed-mean`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub movement: Option<String>,
    /// Fraction trimmed from each end for `trimmed-mean`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub trim: Option<f64>,
    /// Frame rate assumed for image folders.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub images_fps: Option<f64>,
    /// Analyse only the codec keyframes (`select --preview`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preview: Option<bool>,
    /// Subtract the camera rotation from the flow (`--derotate`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub derotate: Option<bool>,
    /// Horizontal field of view in degrees for `derotate` (`--hfov`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hfov: Option<f64>,
    /// Farnebäck parameters.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub farneback: Option<Farneback>,
}

/// `[analysis.farneback]`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Farneback {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pyr_scale: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub levels: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub winsize: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub iterations: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub poly_n: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub poly_sigma: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gaussian: Option<bool>,
}

/// One `[[sample]]` step; `plugin` is the stable id. In the file the id is the `plugin` key of
/// the table; in serde it is the variant name (so errors keep the key path).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub enum Sample {
    /// Part of the input to consider: frame index or `"4.5s"`, both ends inclusive.
    Boundaries {
        #[serde(skip_serializing_if = "Option::is_none")]
        start: Option<NumOrText>,
        #[serde(skip_serializing_if = "Option::is_none")]
        end: Option<NumOrText>,
    },
    /// Drop frames where the camera stands still (reference mode).
    Stationary {
        /// Pixels of movement since the last keyframe; `"auto"` proposes one; default 1 % of width.
        #[serde(skip_serializing_if = "Option::is_none")]
        threshold: Option<NumOrText>,
        #[serde(skip_serializing_if = "Option::is_none")]
        reset_delta: Option<usize>,
    },
    /// A keyframe every `threshold` pixels of accumulated movement (or `"auto"`).
    Spacing { threshold: NumOrText },
    /// Every n-th frame.
    #[serde(alias = "every")]
    EveryNth { n: usize },
    /// Resample to `fps` frames per second by timestamps.
    Fps { fps: f64 },
    /// Drop (`filter`) or `replace` blurry keyframes.
    Blur {
        #[serde(skip_serializing_if = "Option::is_none")]
        metric: Option<String>,
        #[serde(skip_serializing_if = "Option::is_none")]
        window: Option<usize>,
        #[serde(skip_serializing_if = "Option::is_none")]
        ratio: Option<f64>,
        #[serde(skip_serializing_if = "Option::is_none")]
        mode: Option<String>,
    },
    /// Add or remove frames by index.
    Manual {
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        add: Vec<usize>,
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        remove: Vec<usize>,
    },
}

impl Sample {
    /// The stable plugin id.
    pub fn id(&self) -> &'static str {
        match self {
            Sample::Boundaries { .. } => "boundaries",
            Sample::Stationary { .. } => "stationary",
            Sample::Spacing { .. } => "spacing",
            Sample::EveryNth { .. } => "every-nth",
            Sample::Fps { .. } => "fps",
            Sample::Blur { .. } => "blur",
            Sample::Manual { .. } => "manual",
        }
    }

    /// Position in keyframer's fixed chain (every-nth and fps share one slot).
    fn rank(&self) -> usize {
        match self {
            Sample::Boundaries { .. } => 0,
            Sample::Stationary { .. } => 1,
            Sample::Spacing { .. } => 2,
            Sample::EveryNth { .. } | Sample::Fps { .. } => 3,
            Sample::Blur { .. } => 4,
            Sample::Manual { .. } => 5,
        }
    }
}

/// `[export.masks]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Masks {
    /// Model description, relative to the workflow file.
    pub model: PathBuf,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub classes: Vec<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dilate: Option<u32>,
    /// `opencv` or `ort`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub backend: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub overlay: Option<bool>,
}

/// One `[[export]]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Export {
    /// Output sub-folder name (letters, digits, `-`, `_`, `.`).
    pub name: String,
    /// `jpg` or `png`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub format: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub quality: Option<u8>,
    /// `"1280x720"`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub resize: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
    /// `"x,y,w,h"` in source pixels.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub crop: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub masks: Option<Masks>,
}

/// A workflow's content.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkflowFile {
    /// Format version; must be [`VERSION`].
    pub version: u32,
    /// `[analysis]`.
    pub analysis: Option<Analysis>,
    /// `[[sample]]` steps in order.
    pub sample: Vec<Sample>,
    /// `[[export]]`s.
    pub export: Vec<Export>,
}

/// The file as written: sample steps are tables with a `plugin` key.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    version: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    analysis: Option<Analysis>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    sample: Vec<toml::Table>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    export: Vec<Export>,
}

/// `{plugin = "fps", fps = 1.0}` -> `Sample::Fps`, errors naming `sample[i].<key>`.
fn sample_from_table(file: &TomlFile<RawFile>, i: usize, table: &toml::Table) -> Result<Sample> {
    let mut rest = table.clone();
    let plugin = match rest.remove("plugin") {
        Some(toml::Value::String(p)) => p,
        Some(_) => return Err(file.error(&format!("sample[{i}].plugin"), "must be a string")),
        None => return Err(file.error(&format!("sample[{i}]"), "missing field `plugin`")),
    };
    let mut wrapped = toml::Table::new();
    wrapped.insert(plugin, toml::Value::Table(rest));
    serde_path_to_error::deserialize::<_, Sample>(toml::Value::Table(wrapped)).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner().to_string();
        let msg = inner.lines().next().unwrap_or("").trim().to_string();
        // The first segment is the plugin id itself.
        let keys: Vec<&str> = path.split('.').filter(|k| !k.is_empty()).skip(1).collect();
        let field = if !keys.is_empty() {
            format!("sample[{i}].{}", keys.join("."))
        } else if msg.contains("unknown variant") {
            format!("sample[{i}].plugin")
        } else {
            format!("sample[{i}]")
        };
        file.error(&field, msg)
    })
}

/// `Sample::Fps` -> `{plugin = "fps", fps = 1.0}`.
fn sample_to_table(s: &Sample) -> Result<toml::Table> {
    let v = toml::Value::try_from(s).map_err(|e| Error::param("sample", e.to_string()))?;
    let mut out = toml::Table::new();
    out.insert("plugin".into(), toml::Value::String(s.id().into()));
    if let toml::Value::Table(t) = v {
        for (_, inner) in t {
            if let toml::Value::Table(fields) = inner {
                out.extend(fields);
            }
        }
    }
    Ok(out)
}

/// A loaded, fully checked workflow.
#[derive(Debug, Clone)]
pub struct Workflow {
    /// Where it was read from.
    pub path: PathBuf,
    /// Its content.
    pub file: WorkflowFile,
    /// FNV-1a hash of the file's text: a changed workflow redoes finished inputs.
    pub hash: u64,
    select_args: Vec<String>,
    export_args: Vec<Vec<String>>,
}

#[derive(Parser)]
#[command(no_binary_name = true)]
struct SelectCmd {
    #[command(flatten)]
    args: SelectArgs,
}

#[derive(Parser)]
#[command(no_binary_name = true)]
struct ExportCmd {
    #[command(flatten)]
    args: ExportArgs,
}

/// Which workflow key a command-line flag came from.
struct Origin {
    flag: String,
    field: String,
}

impl Workflow {
    /// Reads and checks a workflow: syntax, types, unknown keys and plugins, parameter values,
    /// step order, export names and mask models. Nothing else is touched.
    pub fn load(path: &Path) -> Result<Workflow> {
        let text = crate::output::read_text(path)?;
        Self::from_text(path, text)
    }

    /// As [`Workflow::load`], for `text` as if read from `path` (which is not touched; mask
    /// models are resolved against its folder): checks a workflow before it is written.
    pub fn from_text(path: &Path, text: String) -> Result<Workflow> {
        let file = tomlfile::parse::<RawFile>(path, "workflow", text)?;
        let raw = &file.value;
        if raw.version != VERSION {
            return Err(file.error(
                "version",
                format!(
                    "version {} is not supported (this build reads {VERSION})",
                    raw.version
                ),
            ));
        }
        let sample = raw
            .sample
            .iter()
            .enumerate()
            .map(|(i, t)| sample_from_table(&file, i, t))
            .collect::<Result<Vec<_>>>()?;
        let content = WorkflowFile {
            version: raw.version,
            analysis: raw.analysis.clone(),
            sample,
            export: raw.export.clone(),
        };
        let w = &content;
        check_relations(&file, w)?;
        let (select_args, origins) = select_flags(&file, w)?;
        let mut export_args = Vec::new();
        for (i, e) in w.export.iter().enumerate() {
            export_args.push(export_flags(&file, w, i, e)?);
        }
        let hash = crate::fsutil::fnv1a64(file.text().as_bytes());
        let wf = Workflow {
            path: path.to_path_buf(),
            file: content.clone(),
            hash,
            select_args,
            export_args,
        };
        // Dry validation with placeholder paths: every parameter error surfaces now.
        wf.select_settings(Path::new("input"), Path::new("project.json"), true)
            .map_err(|e| locate(&file, &origins, "analysis", e))?;
        for i in 0..wf.export_args.len() {
            let s = wf
                .export_settings(i, Path::new("project.json"), Path::new("out"))
                .map_err(|e| {
                    let origins = export_origins(i, &w.export[i]);
                    locate(&file, &origins, &format!("export[{i}]"), e)
                })?;
            if let Some(m) = &s.1.masks {
                let desc = crate::segment::desc::ModelDesc::load(&m.model)
                    .map_err(|e| file.error(&format!("export[{i}].masks.model"), e.to_string()))?;
                desc.class_ids(&m.classes).map_err(|e| {
                    file.error(&format!("export[{i}].masks.classes"), e.to_string())
                })?;
            }
        }
        Ok(wf)
    }

    /// Settings for `select` on `input`, writing `project`.
    pub fn select_settings(
        &self,
        input: &Path,
        project: &Path,
        quiet: bool,
    ) -> Result<SelectSettings> {
        let mut argv: Vec<String> = vec![
            input.to_string_lossy().into_owned(),
            "-o".into(),
            project.to_string_lossy().into_owned(),
            "--force".into(),
        ];
        argv.extend(self.select_args.iter().cloned());
        let cmd = SelectCmd::try_parse_from(&argv).map_err(clap_error)?;
        cmd.args.settings(quiet)
    }

    /// Export `i`: its folder name and settings.
    pub fn export_settings(
        &self,
        i: usize,
        project: &Path,
        out: &Path,
    ) -> Result<(String, ExportSettings)> {
        let mut argv: Vec<String> = vec![
            project.to_string_lossy().into_owned(),
            "--out".into(),
            out.to_string_lossy().into_owned(),
        ];
        argv.extend(self.export_args[i].iter().cloned());
        let cmd = ExportCmd::try_parse_from(&argv).map_err(clap_error)?;
        Ok((self.file.export[i].name.clone(), cmd.args.settings()?))
    }

    /// Number of exports.
    pub fn exports(&self) -> usize {
        self.export_args.len()
    }
}

/// A clap error as a parameter error named by the flag that caused it (the invalid or
/// conflicting one), with clap's whole message on one line.
fn clap_error(e: clap::Error) -> Error {
    use clap::error::{ContextKind, ContextValue};
    let first = |kind| match e.get(kind) {
        Some(ContextValue::String(s)) => s.split_whitespace().next().map(str::to_string),
        Some(ContextValue::Strings(v)) => v
            .first()
            .and_then(|s| s.split_whitespace().next())
            .map(str::to_string),
        _ => None,
    };
    let flag = first(ContextKind::InvalidArg)
        .or_else(|| first(ContextKind::PriorArg))
        .unwrap_or_default();
    let rendered = e.render().to_string();
    let msg = rendered
        .lines()
        .map(str::trim)
        .take_while(|l| !l.starts_with("Usage:") && !l.starts_with("For more information"))
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join(" ")
        .trim_start_matches("error: ")
        .to_string();
    Error::param(flag, msg)
}

/// `--pyr-scale`, `pyr_scale` -> `pyr_scale`.
fn flag_key(flag: &str) -> String {
    flag.trim_start_matches("--").replace('-', "_")
}

/// Maps a parameter error (named by its flag) back to the workflow key it came from; errors no
/// flag explains are put on `fallback` (the table the flags came from), never on no key.
fn locate(file: &TomlFile<RawFile>, origins: &[Origin], fallback: &str, e: Error) -> Error {
    if let Error::Plugin { plugin, msg } = &e {
        let id = if *plugin == "every" {
            "every-nth"
        } else {
            plugin
        };
        let step = file
            .value
            .sample
            .iter()
            .position(|t| t.get("plugin").and_then(|p| p.as_str()) == Some(id));
        if let Some(i) = step {
            // Messages start with the parameter they are about ("ratio must be ...").
            let word: String = msg
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            let key = if file.value.sample[i].contains_key(&word) {
                word
            } else {
                "plugin".into()
            };
            return file.error(&format!("sample[{i}].{key}"), msg.clone());
        }
        return file.error(fallback, format!("{plugin}: {msg}"));
    }
    if let Error::Param { name, msg } = &e {
        let key = flag_key(name);
        if let Some(o) = origins.iter().find(|o| flag_key(&o.flag) == key) {
            return file.error(&o.field, msg.clone());
        }
        let msg = if name.is_empty() {
            msg.clone()
        } else {
            format!("{name}: {msg}")
        };
        return file.error(fallback, msg);
    }
    e
}

/// Relations between keys that clap would report without naming the key that caused them.
fn check_relations(file: &TomlFile<RawFile>, w: &WorkflowFile) -> Result<()> {
    if let Some(an) = &w.analysis {
        if an.hfov.is_some() && an.derotate != Some(true) {
            return Err(file.error(
                "analysis.hfov",
                "the field of view is only used with `derotate = true`: add it, or remove `hfov`",
            ));
        }
    }
    for (i, e) in w.export.iter().enumerate() {
        if e.resize.is_some() && e.scale.is_some() {
            return Err(file.error(
                &format!("export[{i}].scale"),
                "give either `resize` or `scale`, not both",
            ));
        }
    }
    Ok(())
}

fn push(
    args: &mut Vec<String>,
    origins: &mut Vec<Origin>,
    flag: &str,
    value: Option<String>,
    field: String,
) {
    // `--flag=value`, so values starting with `-` stay values.
    match value {
        Some(v) => args.push(format!("{flag}={v}")),
        None => args.push(flag.to_string()),
    }
    origins.push(Origin {
        flag: flag.to_string(),
        field,
    });
}

fn select_flags(file: &TomlFile<RawFile>, w: &WorkflowFile) -> Result<(Vec<String>, Vec<Origin>)> {
    let mut a = Vec::new();
    let mut o = Vec::new();
    if let Some(an) = &w.analysis {
        let f = |k: &str| format!("analysis.{k}");
        if let Some(v) = &an.backend {
            push(&mut a, &mut o, "--backend", Some(v.clone()), f("backend"));
        }
        if let Some(v) = &an.adapter {
            push(&mut a, &mut o, "--adapter", Some(v.clone()), f("adapter"));
        }
        if let Some(v) = an.analysis_width {
            push(
                &mut a,
                &mut o,
                "--analysis-width",
                Some(v.to_string()),
                f("analysis_width"),
            );
        }
        if let Some(v) = an.flow_stride {
            push(
                &mut a,
                &mut o,
                "--flow-stride",
                Some(v.to_string()),
                f("flow_stride"),
            );
        }
        if let Some(v) = &an.movement {
            push(&mut a, &mut o, "--movement", Some(v.clone()), f("movement"));
        }
        if let Some(v) = an.trim {
            push(&mut a, &mut o, "--trim", Some(v.to_string()), f("trim"));
        }
        if let Some(v) = an.images_fps {
            push(
                &mut a,
                &mut o,
                "--images-fps",
                Some(v.to_string()),
                f("images_fps"),
            );
        }
        if an.preview == Some(true) {
            push(&mut a, &mut o, "--preview", None, f("preview"));
        }
        if an.derotate == Some(true) {
            push(&mut a, &mut o, "--derotate", None, f("derotate"));
        }
        if let Some(v) = an.hfov {
            push(&mut a, &mut o, "--hfov", Some(v.to_string()), f("hfov"));
        }
        if let Some(fb) = &an.farneback {
            let g = |k: &str| format!("analysis.farneback.{k}");
            let nums: [(&str, Option<String>); 6] = [
                ("pyr_scale", fb.pyr_scale.map(|v| v.to_string())),
                ("levels", fb.levels.map(|v| v.to_string())),
                ("winsize", fb.winsize.map(|v| v.to_string())),
                ("iterations", fb.iterations.map(|v| v.to_string())),
                ("poly_n", fb.poly_n.map(|v| v.to_string())),
                ("poly_sigma", fb.poly_sigma.map(|v| v.to_string())),
            ];
            for (k, v) in nums {
                if let Some(v) = v {
                    push(
                        &mut a,
                        &mut o,
                        &format!("--{}", k.replace('_', "-")),
                        Some(v),
                        g(k),
                    );
                }
            }
            if fb.gaussian == Some(true) {
                push(&mut a, &mut o, "--gaussian", None, g("gaussian"));
            }
        }
    }
    let mut last_rank = 0;
    let mut seen: Vec<&'static str> = Vec::new();
    for (i, s) in w.sample.iter().enumerate() {
        let at = |k: &str| format!("sample[{i}].{k}");
        if seen.contains(&s.id())
            || (s.rank() == 3 && seen.iter().any(|x| *x == "every-nth" || *x == "fps"))
        {
            return Err(file.error(
                &format!("sample[{i}].plugin"),
                format!(
                    "`{}`: at most one step per sampler (and one of every-nth / fps)",
                    s.id()
                ),
            ));
        }
        if s.rank() < last_rank {
            return Err(file.error(
                &format!("sample[{i}].plugin"),
                format!(
                    "`{}` cannot follow `{}`: keyframer applies boundaries → stationary → spacing → every-nth/fps → blur → manual",
                    s.id(),
                    seen.last().copied().unwrap_or("")
                ),
            ));
        }
        last_rank = s.rank();
        seen.push(s.id());
        match s {
            Sample::Boundaries { start, end } => {
                if let Some(v) = start {
                    push(&mut a, &mut o, "--start", Some(v.flag_value()), at("start"));
                }
                if let Some(v) = end {
                    push(&mut a, &mut o, "--end", Some(v.flag_value()), at("end"));
                }
            }
            Sample::Stationary {
                threshold,
                reset_delta,
            } => {
                push(&mut a, &mut o, "--stationary", None, at("plugin"));
                match threshold {
                    Some(NumOrText::Text(t)) if t == "auto" => {
                        push(&mut a, &mut o, "--auto", None, at("threshold"))
                    }
                    Some(v) => push(
                        &mut a,
                        &mut o,
                        "--stationary-threshold",
                        Some(v.flag_value()),
                        at("threshold"),
                    ),
                    None => {}
                }
                if let Some(r) = reset_delta {
                    push(
                        &mut a,
                        &mut o,
                        "--reset-delta",
                        Some(r.to_string()),
                        at("reset_delta"),
                    );
                }
            }
            Sample::Spacing { threshold } => push(
                &mut a,
                &mut o,
                "--spacing",
                Some(threshold.flag_value()),
                at("threshold"),
            ),
            Sample::EveryNth { n } => push(&mut a, &mut o, "--every", Some(n.to_string()), at("n")),
            Sample::Fps { fps } => push(&mut a, &mut o, "--fps", Some(fps.to_string()), at("fps")),
            Sample::Blur {
                metric,
                window,
                ratio,
                mode,
            } => {
                push(&mut a, &mut o, "--blur", None, at("plugin"));
                if let Some(v) = metric {
                    push(
                        &mut a,
                        &mut o,
                        "--blur-metric",
                        Some(v.clone()),
                        at("metric"),
                    );
                }
                if let Some(v) = window {
                    push(
                        &mut a,
                        &mut o,
                        "--blur-window",
                        Some(v.to_string()),
                        at("window"),
                    );
                }
                if let Some(v) = ratio {
                    push(
                        &mut a,
                        &mut o,
                        "--blur-ratio",
                        Some(v.to_string()),
                        at("ratio"),
                    );
                }
                if let Some(v) = mode {
                    push(&mut a, &mut o, "--blur-mode", Some(v.clone()), at("mode"));
                }
            }
            Sample::Manual { add, remove } => {
                if !add.is_empty() {
                    let v = add
                        .iter()
                        .map(|x| x.to_string())
                        .collect::<Vec<_>>()
                        .join(",");
                    push(&mut a, &mut o, "--add", Some(v), at("add"));
                }
                if !remove.is_empty() {
                    let v = remove
                        .iter()
                        .map(|x| x.to_string())
                        .collect::<Vec<_>>()
                        .join(",");
                    push(&mut a, &mut o, "--remove", Some(v), at("remove"));
                }
            }
        }
    }
    Ok((a, o))
}

/// Names `keyframer run` uses in each input's folder, which an export may not take.
pub const RESERVED_NAMES: [&str; 9] = [
    "project.json",
    "project.json.partial",
    crate::batch::DONE,
    crate::batch::MARKER,
    crate::export::MANIFEST,
    crate::export::IMAGE_DIR,
    crate::export::MASK_DIR,
    crate::export::OVERLAY_DIR,
    "colmap",
];

fn valid_name(n: &str) -> bool {
    !n.is_empty()
        && n != "."
        && n != ".."
        && n.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
}

fn export_origins(i: usize, e: &Export) -> Vec<Origin> {
    let at = |k: &str| format!("export[{i}].{k}");
    let mut o = vec![
        Origin {
            flag: "--format".into(),
            field: at("format"),
        },
        Origin {
            flag: "--quality".into(),
            field: at("quality"),
        },
        Origin {
            flag: "--resize".into(),
            field: at("resize"),
        },
        Origin {
            flag: "--scale".into(),
            field: at("scale"),
        },
        Origin {
            flag: "--crop".into(),
            field: at("crop"),
        },
    ];
    if e.masks.is_some() {
        o.push(Origin {
            flag: "--mask-backend".into(),
            field: at("masks.backend"),
        });
        o.push(Origin {
            flag: "--mask-classes".into(),
            field: at("masks.classes"),
        });
        o.push(Origin {
            flag: "--mask-dilate".into(),
            field: at("masks.dilate"),
        });
    }
    o
}

fn export_flags(
    file: &TomlFile<RawFile>,
    w: &WorkflowFile,
    i: usize,
    e: &Export,
) -> Result<Vec<String>> {
    let at = |k: &str| format!("export[{i}].{k}");
    if !valid_name(&e.name) {
        return Err(file.error(
            &at("name"),
            format!(
                "`{}` is not a plain folder name (letters, digits, - _ .)",
                e.name
            ),
        ));
    }
    if w.export[..i].iter().any(|x| x.name == e.name) {
        return Err(file.error(
            &at("name"),
            format!("`{}` is used by an earlier export", e.name),
        ));
    }
    if RESERVED_NAMES.contains(&e.name.as_str()) || e.name.starts_with('.') {
        return Err(file.error(
            &at("name"),
            format!(
                "`{}` is reserved: `keyframer run` keeps its own files under these names in each input's folder ({}, or any name starting with `.`)",
                e.name,
                RESERVED_NAMES.join(", ")
            ),
        ));
    }
    let mut a = Vec::new();
    let mut opt = |flag: &str, v: Option<String>| {
        if let Some(v) = v {
            a.push(format!("{flag}={v}"));
        }
    };
    opt("--format", e.format.clone());
    opt("--quality", e.quality.map(|q| q.to_string()));
    opt("--resize", e.resize.clone());
    opt("--scale", e.scale.map(|s| s.to_string()));
    opt("--crop", e.crop.clone());
    if let Some(m) = &e.masks {
        let dir = file.path().parent().unwrap_or(Path::new("."));
        let model = crate::fsutil::absolute(&dir.join(&m.model));
        opt("--masks", Some(model.to_string_lossy().into_owned()));
        if !m.classes.is_empty() {
            opt("--mask-classes", Some(m.classes.join(",")));
        }
        opt("--mask-dilate", m.dilate.map(|d| d.to_string()));
        opt("--mask-backend", m.backend.clone());
        if m.overlay == Some(true) {
            a.push("--mask-overlay".into());
        }
    }
    Ok(a)
}

/// The workflow that reproduces a project's selection (its history), plus exports like the ones
/// whose folders are given (read from their manifests).
pub fn from_project(project: &Path, exports: &[PathBuf]) -> Result<String> {
    let p = Project::load(project)?;
    let bad = |msg: String| Error::File {
        path: project.to_path_buf(),
        line: None,
        what: "project file",
        field: "history".into(),
        msg,
    };
    let mut analysis = Analysis::default();
    let mut sample = Vec::new();
    for (k, step) in p.history.iter().enumerate() {
        let v = &step.params;
        let num = |key: &str| v.get(key).and_then(|x| x.as_f64());
        let movement = |analysis: &mut Analysis| {
            if let Some(m) = v.get("movement") {
                if let Ok(req) =
                    serde_json::from_value::<crate::analysis::MovementRequest>(m.clone())
                {
                    analysis.analysis_width = Some(req.analysis_width);
                    analysis.flow_stride = Some(req.stride);
                    let (name, trim) = req.statistic.to_flag();
                    analysis.movement = Some(name.into());
                    analysis.trim = trim;
                    if let Some(d) = req.derotate {
                        analysis.derotate = Some(true);
                        analysis.hfov = Some(d.hfov_deg);
                    }
                    let f = req.farneback;
                    analysis.farneback = Some(Farneback {
                        pyr_scale: Some(f.pyr_scale),
                        levels: Some(f.levels),
                        winsize: Some(f.winsize),
                        iterations: Some(f.iterations),
                        poly_n: Some(f.poly_n),
                        poly_sigma: Some(f.poly_sigma),
                        gaussian: Some(f.gaussian),
                    });
                }
            }
            if let Some(b) = v.get("backend").and_then(|b| b.as_str()) {
                analysis.backend = Some(b.to_string());
            }
        };
        let s = match step.plugin.as_str() {
            "boundaries" => {
                let bound = |key: &str| -> Option<NumOrText> {
                    serde_json::from_value::<Option<crate::samplers::Bound>>(v.get(key)?.clone())
                        .ok()
                        .flatten()
                        .map(|b| match b {
                            crate::samplers::Bound::Frame(f) => NumOrText::Int(f as i64),
                            crate::samplers::Bound::Seconds(s) => NumOrText::Text(format!("{s}s")),
                        })
                };
                let (start, end) = (bound("start"), bound("end"));
                if start.is_none() && end.is_none() {
                    continue;
                }
                Sample::Boundaries { start, end }
            }
            "stationary" => {
                movement(&mut analysis);
                Sample::Stationary {
                    threshold: num("threshold_px").map(NumOrText::Float),
                    reset_delta: v
                        .get("reset_delta")
                        .and_then(|x| x.as_u64())
                        .map(|x| x as usize),
                }
            }
            "spacing" => {
                movement(&mut analysis);
                Sample::Spacing {
                    threshold: NumOrText::Float(
                        num("threshold_px")
                            .ok_or_else(|| bad(format!("step {k}: no threshold_px")))?,
                    ),
                }
            }
            "every-nth" => Sample::EveryNth {
                n: v.get("n")
                    .and_then(|x| x.as_u64())
                    .ok_or_else(|| bad(format!("step {k}: no n")))? as usize,
            },
            "fps" => Sample::Fps {
                fps: num("fps").ok_or_else(|| bad(format!("step {k}: no fps")))?,
            },
            "blur" => {
                if let Some(b) = v.get("backend").and_then(|b| b.as_str()) {
                    analysis.backend = Some(b.to_string());
                }
                Sample::Blur {
                    metric: v.get("metric").and_then(|x| x.as_str()).map(String::from),
                    window: v.get("window").and_then(|x| x.as_u64()).map(|x| x as usize),
                    ratio: num("ratio"),
                    mode: v.get("mode").and_then(|x| x.as_str()).map(String::from),
                }
            }
            "manual" => {
                let list = |key: &str| -> Vec<usize> {
                    v.get(key)
                        .and_then(|x| x.as_array())
                        .map(|a| {
                            a.iter()
                                .filter_map(|x| x.as_u64())
                                .map(|x| x as usize)
                                .collect()
                        })
                        .unwrap_or_default()
                };
                Sample::Manual {
                    add: list("add"),
                    remove: list("remove"),
                }
            }
            "preview" => {
                analysis.preview = Some(true);
                continue;
            }
            other => return Err(bad(format!("step {k}: unknown plugin `{other}`"))),
        };
        sample.push((k, s));
    }
    if p.input.kind == crate::source::SourceKind::Images {
        // The rate given with --images-fps is the folder's rate in the metadata.
        analysis.images_fps = p.metadata.fps;
    }
    let mut export = Vec::new();
    for dir in exports {
        let m =
            crate::export::read_manifest(&dir.join(crate::export::MANIFEST)).ok_or_else(|| {
                Error::input(
                    dir,
                    "no readable manifest.json: not a keyframer export folder",
                )
            })?;
        let s = &m.settings;
        export.push(Export {
            name: dir
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| "export".into()),
            format: s.format.map(|f| f.ext().to_string()),
            quality: Some(s.quality),
            resize: match s.resize {
                Some(crate::export::Resize::Size { width, height }) => {
                    Some(format!("{width}x{height}"))
                }
                _ => None,
            },
            scale: match s.resize {
                Some(crate::export::Resize::Scale(f)) => Some(f),
                _ => None,
            },
            crop: s
                .crop
                .map(|c| format!("{},{},{},{}", c.x, c.y, c.width, c.height)),
            masks: s.masks.as_ref().map(|mk| Masks {
                model: crate::fsutil::absolute(&mk.model),
                classes: mk.classes.clone(),
                dilate: Some(mk.dilate),
                backend: Some(match mk.backend {
                    crate::segment::SegBackend::Opencv => "opencv".into(),
                    crate::segment::SegBackend::Ort => "ort".into(),
                }),
                overlay: Some(mk.overlay),
            }),
        });
    }
    let wf = RawFile {
        version: VERSION,
        analysis: (analysis != Analysis::default()).then_some(analysis),
        sample: sample
            .iter()
            .map(|(k, s)| {
                sample_to_table(s).map_err(|e| Error::File {
                    path: project.to_path_buf(),
                    line: None,
                    what: "project file",
                    field: format!("history[{k}].params"),
                    msg: format!(
                        "cannot be written as a workflow step ({}; TOML integers go up to 2^63 - 1)",
                        match e {
                            Error::Param { msg, .. } => msg,
                            other => other.to_string(),
                        }
                    ),
                })
            })
            .collect::<Result<Vec<_>>>()?,
        export,
    };
    let body = toml::to_string(&wf).map_err(|e| bad(e.to_string()))?;
    Ok(format!(
        "# keyframer workflow saved from {} (thresholds are the values the project used).\n\
         # Run it with: keyframer run THIS.toml INPUT... --out DIR\n{body}",
        project.display()
    ))
}
