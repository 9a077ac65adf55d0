//! The report page: summary, timeline (inline SVG with hover details), thumbnails, steps, the
//! camera path and the flight map, in one HTML file with no external reference. The page is the askama template
//! `templates/report.html`, which escapes every value it is given except the two SVG drawings
//! keyframer makes and the JSON data (whose `<` are escaped here).

use super::camera::{CameraPath, PathStats};
use super::thumbs::{base64, Thumb};
use super::timeline::{self, hex, Curve, Timeline};
use crate::error::{Error, Result};
use crate::project::Project;
use askama::Template;
use serde_json::json;
use std::path::Path;

/// Everything the page shows.
pub struct PageInput<'a> {
    pub project: &'a Project,
    pub project_path: &'a Path,
    pub timeline: &'a Timeline,
    pub thumbs: &'a [Thumb],
    pub camera: Option<&'a CameraPath>,
    pub missing: &'a [String],
    pub timeline_png: Option<String>,
}

/// The values the template shows, as text (escaped by the template).
#[derive(Template)]
#[template(path = "report.html")]
struct Page<'a> {
    name: String,
    summary: Vec<(&'static str, String)>,
    decode_problems: &'a [String],
    missing: &'a [String],
    timeline_svg: String,
    keyframe_colour: String,
    keyframes: usize,
    added_colour: String,
    added: usize,
    shaded: bool,
    legend: Vec<Legend>,
    timeline_png: Option<String>,
    thumbs: Vec<ThumbView>,
    steps: Vec<StepRow>,
    camera: Option<CameraView>,
    /// The flight map's SVG, when the project has telemetry positions.
    map: Option<String>,
    data: String,
}

struct Legend {
    dashed: bool,
    colour: String,
    name: String,
}

struct ThumbView {
    frame: usize,
    base64: String,
    time: String,
}

struct StepRow {
    number: usize,
    step: &'static str,
    kept: usize,
    params: String,
}

struct CameraView {
    stats: Option<PathStats>,
    svg: String,
}

/// Values rounded to 4 decimals (null when not finite).
fn round4(values: &[f64]) -> Vec<Option<f64>> {
    values
        .iter()
        .map(|v| v.is_finite().then(|| (v * 1e4).round() / 1e4))
        .collect()
}

/// Renders the page.
pub fn page(p: &PageInput) -> Result<String> {
    let (pr, tl) = (p.project, p.timeline);
    Page {
        name: p
            .project_path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        summary: summary(p),
        decode_problems: &pr.decode_problems,
        missing: p.missing,
        timeline_svg: tl.svg()?,
        keyframe_colour: hex(timeline::KEYFRAME_RGB),
        keyframes: pr.keyframes.len(),
        added_colour: hex(timeline::ADDED_RGB),
        added: tl.added.len(),
        shaded: tl
            .range
            .is_some_and(|(lo, hi)| lo > 0 || hi + 1 < tl.frames),
        legend: curves(tl)
            .map(|c| Legend {
                dashed: c.dashed,
                colour: hex(c.rgb),
                name: c.name.clone(),
            })
            .collect(),
        timeline_png: p.timeline_png.clone(),
        thumbs: thumbs(p),
        steps: steps(pr),
        camera: p
            .camera
            .filter(|c| !c.points.is_empty())
            .map(|c| CameraView {
                stats: c.stats(),
                svg: c.svg(),
            }),
        map: super::map::FlightMap::from_project(pr).map(|m| m.svg()),
        data: hover_data(pr, tl),
    }
    .render()
    .map_err(|e| Error::param("output", format!("rendering the report page failed: {e}")))
}

/// The curves of all panels, top to bottom.
fn curves(tl: &Timeline) -> impl Iterator<Item = &Curve> {
    tl.panels.iter().flat_map(|p| p.curves.iter())
}

/// The summary table: (label, value) rows.
fn summary(p: &PageInput) -> Vec<(&'static str, String)> {
    let (pr, m) = (p.project, &p.project.metadata);
    let input = format!("{} ({:?})", pr.input.path.display(), pr.input.kind);
    let fps = m.fps.map(|f| format!("{f:.3}")).unwrap_or("unknown".into());
    let duration = m
        .duration_s
        .map(|d| format!("{d:.2} s"))
        .unwrap_or("unknown".into());
    vec![
        ("project", p.project_path.display().to_string()),
        ("input", input),
        ("frames", m.frame_count.to_string()),
        ("fps", fps),
        ("size", format!("{}x{}", m.width, m.height)),
        ("duration", duration),
        ("keyframes", pr.keyframes.len().to_string()),
        ("written by", format!("keyframer {}", pr.tool_version)),
    ]
}

/// The thumbnails with their frame time, when known.
fn thumbs(p: &PageInput) -> Vec<ThumbView> {
    let ts = p.project.cache.timestamps_s.as_deref();
    p.thumbs
        .iter()
        .map(|t| ThumbView {
            frame: t.frame,
            base64: base64(&t.jpeg),
            time: ts
                .and_then(|v| v.get(t.frame))
                .map(|v| format!(" · {v:.2} s"))
                .unwrap_or_default(),
        })
        .collect()
}

/// One row per step of the project's history.
fn steps(pr: &Project) -> Vec<StepRow> {
    pr.history
        .iter()
        .enumerate()
        .map(|(i, st)| StepRow {
            number: i + 1,
            step: st.applied.id(),
            kept: st.kept,
            params: serde_json::to_value(st).unwrap_or_default()["params"].to_string(),
        })
        .collect()
}

/// The JSON data for the hover details; `<` never appears raw inside the script element.
fn hover_data(pr: &Project, tl: &Timeline) -> String {
    let n = tl.frames;
    let curves: Vec<_> = curves(tl)
        .map(|c| json!({ "name": c.name, "values": round4(&c.values) }))
        .collect();
    json!({
        "frames": n,
        "left": timeline::LEFT,
        "span": timeline::WIDTH - timeline::LEFT - timeline::RIGHT - 1,
        "x": (0..n).map(|f| timeline::frame_x(f, n)).collect::<Vec<_>>(),
        "keyframes": pr.keyframes,
        "timestamps": pr.cache.timestamps_s,
        "curves": curves,
    })
    .to_string()
    .replace('<', "\\u003c")
}
