//! The report page: summary, timeline (inline SVG with hover details), thumbnails, steps and the
//! camera path, in one HTML file with no external reference. The page is the askama template
//! `templates/report.html`, which escapes every value it is given except the two SVG drawings
//! keyframer makes and the JSON data (whose `<` are escaped here).

use super::camera::{CameraPath, PathStats};
use super::thumbs::{base64, Thumb};
use super::timeline::{self, hex, Timeline};
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
    shaded: bool,
    legend: Vec<Legend>,
    timeline_png: Option<String>,
    thumbs: Vec<ThumbView>,
    steps: Vec<StepRow>,
    camera: Option<CameraView>,
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
    plugin: String,
    kept: usize,
    params: String,
}

struct CameraView {
    stats: Option<PathStats>,
    svg: String,
}

fn round4(v: f64) -> serde_json::Value {
    if v.is_finite() {
        json!((v * 1e4).round() / 1e4)
    } else {
        serde_json::Value::Null
    }
}

/// Renders the page.
pub fn page(p: &PageInput) -> Result<String> {
    let pr = p.project;
    let m = &pr.metadata;
    let tl = p.timeline;
    let name = p
        .project_path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let fps = m.fps.map(|f| format!("{f:.3}")).unwrap_or("unknown".into());
    let duration = m
        .duration_s
        .map(|d| format!("{d:.2} s"))
        .unwrap_or("unknown".into());
    let summary = vec![
        ("project", p.project_path.display().to_string()),
        (
            "input",
            format!("{} ({:?})", pr.input.path.display(), pr.input.kind),
        ),
        ("frames", m.frame_count.to_string()),
        ("fps", fps),
        ("size", format!("{}x{}", m.width, m.height)),
        ("duration", duration),
        ("keyframes", pr.keyframes.len().to_string()),
        ("written by", format!("keyframer {}", pr.tool_version)),
    ];
    let legend = tl
        .panels
        .iter()
        .flat_map(|p| p.curves.iter())
        .map(|c| Legend {
            dashed: c.dashed,
            colour: hex(c.rgb),
            name: c.name.clone(),
        })
        .collect();
    let ts = pr.cache.timestamps_s.as_deref();
    let thumbs = p
        .thumbs
        .iter()
        .map(|t| ThumbView {
            frame: t.frame,
            base64: base64(&t.jpeg),
            time: ts
                .and_then(|v| v.get(t.frame))
                .map(|v| format!(" · {v:.2} s"))
                .unwrap_or_default(),
        })
        .collect();
    let steps = pr
        .history
        .iter()
        .enumerate()
        .map(|(i, st)| StepRow {
            number: i + 1,
            plugin: st.plugin.clone(),
            kept: st.kept,
            params: st.params.to_string(),
        })
        .collect();
    let camera = p
        .camera
        .filter(|c| !c.points.is_empty())
        .map(|c| CameraView {
            stats: c.stats(),
            svg: c.svg(),
        });

    // Data for the hover details.
    let n = tl.frames;
    let curves: Vec<serde_json::Value> = tl
        .panels
        .iter()
        .flat_map(|p| p.curves.iter())
        .map(|c| {
            json!({
                "name": c.name,
                "values": c.values.iter().map(|v| round4(*v)).collect::<Vec<_>>(),
            })
        })
        .collect();
    let data = json!({
        "frames": n,
        "left": timeline::LEFT,
        "span": timeline::WIDTH - timeline::LEFT - timeline::RIGHT - 1,
        "x": (0..n).map(|f| timeline::frame_x(f, n)).collect::<Vec<_>>(),
        "keyframes": pr.keyframes,
        "timestamps": pr.cache.timestamps_s,
        "curves": curves,
    });
    // `<` never appears raw inside the script element.
    let data = data.to_string().replace('<', "\\u003c");

    Page {
        name,
        summary,
        decode_problems: &pr.decode_problems,
        missing: p.missing,
        timeline_svg: tl.svg()?,
        keyframe_colour: hex(timeline::KEYFRAME_RGB),
        keyframes: pr.keyframes.len(),
        shaded: tl
            .range
            .is_some_and(|(lo, hi)| lo > 0 || hi + 1 < tl.frames),
        legend,
        timeline_png: p.timeline_png.clone(),
        thumbs,
        steps,
        camera,
        data,
    }
    .render()
    .map_err(|e| Error::param("-o", format!("rendering the report page failed: {e}")))
}
