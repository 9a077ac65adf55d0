//! `keyframer report`: one self-contained HTML page (inline SVG, CSS, JS, data: URI thumbnails)
//! showing a project's timeline, keyframe thumbnails, steps, camera path and flight map, plus a PNG timeline.

mod camera;
mod html;
mod map;
pub mod thumbs;
pub mod timeline;

pub use camera::{scale_colour, CameraPath, PathPoint, PathStats};
pub use timeline::Timeline;

use crate::error::{Error, Result};
use crate::export;
use crate::fsutil;
use crate::output::Inputs;
use crate::project::Project;
use std::path::{Path, PathBuf};

/// What to write and from where.
#[derive(Debug, Clone)]
pub struct ReportSettings {
    /// The HTML page.
    pub output: PathBuf,
    /// The PNG timeline; `None` for [`default_timeline_path`].
    pub timeline: Option<PathBuf>,
    /// Take thumbnails from this export folder (its manifest) instead of decoding the input; an
    /// unreadable folder is an error, a missing input only a note on the page.
    pub export: Option<PathBuf>,
    /// The COLMAP model the camera path was read from (model folder, `sparse/` root or
    /// workspace; see [`crate::eval::camera_centres`]): an input the outputs may not touch.
    pub model: Option<PathBuf>,
    /// At most this many thumbnails, spread evenly over the keyframes (0: none).
    pub thumbs: usize,
    /// Replace existing outputs.
    pub force: bool,
}

/// What was written.
#[derive(Debug, Clone)]
pub struct ReportSummary {
    /// The HTML page.
    pub html: PathBuf,
    /// The PNG timeline.
    pub timeline: PathBuf,
    /// Keyframes of the project.
    pub keyframes: usize,
    /// Thumbnails embedded.
    pub thumbs: usize,
}

/// `<stem>.timeline.png` beside the HTML page (`flight.html` → `flight.timeline.png`).
pub fn default_timeline_path(html: &Path) -> PathBuf {
    let stem = html
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "report".into());
    html.with_file_name(format!("{stem}.timeline.png"))
}

/// Writes the report of the project file at `project_path`: the HTML page and the PNG timeline,
/// atomically, refusing existing outputs unless `settings.force` and outputs that touch an input.
/// `camera` adds the camera-path section (e.g. centres read from `settings.model`); without it
/// the section says how to get one.
pub fn write_report(
    project_path: &Path,
    settings: &ReportSettings,
    camera: Option<&CameraPath>,
) -> Result<ReportSummary> {
    let png_path = settings
        .timeline
        .clone()
        .unwrap_or_else(|| default_timeline_path(&settings.output));
    if crate::output::resolve(&png_path) == crate::output::resolve(&settings.output) {
        return Err(Error::param("timeline", "must differ from the HTML output"));
    }
    let project = Project::load(project_path)?;
    let inputs = inputs(project_path, &project, settings);
    let _held = (
        crate::output::check_file(&settings.output, settings.force, &inputs)?,
        crate::output::check_file(&png_path, settings.force, &inputs)?,
    );
    let timeline = Timeline::from_project(&project);
    let mut missing = timeline.missing.clone();

    let thumbs = keyframe_thumbs(&project, project_path, settings, &mut missing)?;
    for m in &missing {
        log::warn!("not in the report: {m}");
    }

    let page = html::page(&html::PageInput {
        project: &project,
        project_path,
        timeline: &timeline,
        thumbs: &thumbs,
        camera,
        missing: &missing,
        timeline_png: png_path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned()),
    })?;
    let png = timeline.png()?;
    let png_existed = png_path.exists();
    fsutil::write_atomic(&png_path, &png)?;
    if let Err(e) = fsutil::write_atomic(&settings.output, page.as_bytes()) {
        // A failed report leaves no half of itself behind.
        if !png_existed {
            let _ = std::fs::remove_file(&png_path);
        }
        return Err(e);
    }
    Ok(ReportSummary {
        html: settings.output.clone(),
        timeline: png_path,
        keyframes: project.keyframes.len(),
        thumbs: thumbs.len(),
    })
}

/// What a report reads: the project, its input (thumbnails), the export named (its manifest,
/// images and masks: a report beside them is fine) and the COLMAP model of the camera path with
/// the export its workspace records.
fn inputs(project_path: &Path, project: &Project, settings: &ReportSettings) -> Inputs {
    let mut inputs = Inputs::none()
        .with("project", project_path)
        .with("the project's input", project.input_path(project_path));
    if let Some(e) = &settings.export {
        crate::manifest::add_export(&mut inputs, e);
    }
    if let Some(m) = &settings.model {
        inputs.extend(&crate::eval::model_inputs(m, settings.export.as_deref()));
    }
    inputs
}

/// Thumbnails of (a spread of) the keyframes, from the export when one is named, else decoded
/// from the input; what cannot be had is added to `missing`, except that an export the user
/// named must be usable (an error).
fn keyframe_thumbs(
    project: &Project,
    project_path: &Path,
    settings: &ReportSettings,
    missing: &mut Vec<String>,
) -> Result<Vec<thumbs::Thumb>> {
    let wanted = thumbs::pick(&project.keyframes, settings.thumbs);
    let mut thumbs = Vec::new();
    if !wanted.is_empty() {
        let got = match &settings.export {
            // An export folder the user named must be usable.
            Some(dir) => Ok(thumbs::from_export(dir, &wanted)?),
            None => {
                let input = project.input_path(project_path);
                export::check_fingerprint(project, &input)
                    .map_err(|e| e.to_string())
                    .and_then(|()| thumbs::from_input(&input, &wanted).map_err(|e| e.to_string()))
            }
        };
        match got {
            Ok((t, lost)) => {
                if !lost.is_empty() {
                    missing.push(format!(
                        "thumbnails of {} keyframes (frames not available: {:?})",
                        lost.len(),
                        lost
                    ));
                }
                thumbs = t;
            }
            Err(e) => missing.push(format!("keyframe thumbnails: {e}")),
        }
    }
    Ok(thumbs)
}
