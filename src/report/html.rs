//! The report page: summary, timeline (inline SVG with hover details), thumbnails, steps and the
//! camera path, in one HTML file with no external reference.

use super::camera::CameraPath;
use super::esc;
use super::thumbs::{base64, Thumb};
use super::timeline::{self, hex, Timeline};
use crate::project::Project;
use serde_json::json;
use std::fmt::Write;
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

const STYLE: &str = r#"
body { font-family: sans-serif; margin: 16px; color: #222; background: #fff; }
h1 { font-size: 20px; margin: 0 0 8px; }
h2 { font-size: 16px; margin: 22px 0 8px; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; font-size: 13px; }
td, th { padding: 2px 10px 2px 0; text-align: left; vertical-align: top; }
code { font-size: 12px; }
.missing { background: #fff4d6; border: 1px solid #e8c46a; padding: 6px 10px; font-size: 13px; }
.scroll { overflow-x: auto; position: relative; }
.legend { font-size: 12px; margin: 6px 0; }
.legend span.sw { display: inline-block; width: 22px; height: 0; border-top: 2px solid; margin: 0 4px 3px 12px; }
.legend span.sw.dash { border-top-style: dashed; }
.legend span.box { display: inline-block; width: 12px; height: 12px; margin: 0 4px -2px 12px; }
#tip { position: fixed; display: none; background: rgba(255,255,255,0.95); border: 1px solid #888; padding: 4px 6px; font-size: 12px; pointer-events: none; white-space: pre; }
.thumbs { display: flex; flex-wrap: wrap; gap: 6px; }
figure { margin: 0; font-size: 11px; text-align: center; }
figure img { display: block; border: 1px solid #ccc; }
"#;

const ON_ERROR: &str = r#"window.onerror = function (msg, src, line) {
  document.documentElement.setAttribute('data-script-error', String(msg) + ' (line ' + line + ')');
  var p = document.createElement('pre');
  p.id = 'script-error';
  p.textContent = 'SCRIPT ERROR: ' + msg + ' (line ' + line + ')';
  (document.body || document.documentElement).appendChild(p);
};"#;

const SCRIPT: &str = r#"(function () {
  var data = JSON.parse(document.getElementById('kf-data').textContent);
  var svg = document.getElementById('timeline');
  var tip = document.getElementById('tip');
  var cursor = document.getElementById('cursor');
  var keys = {};
  data.keyframes.forEach(function (k) { keys[k] = true; });
  function frameAt(x) {
    var n = data.frames;
    if (n <= 1) return 0;
    var f = Math.round((x - data.left) * (n - 1) / data.span);
    return Math.max(0, Math.min(n - 1, f));
  }
  function fmt(v) {
    if (v === null || v === undefined) return '–';
    return Math.abs(v) >= 100 ? v.toFixed(1) : v.toPrecision(4);
  }
  svg.addEventListener('mousemove', function (e) {
    var r = svg.getBoundingClientRect();
    var f = frameAt(e.clientX - r.left);
    var lines = ['frame ' + f + (keys[f] ? '  (keyframe)' : '')];
    if (data.timestamps) lines.push('time ' + data.timestamps[f].toFixed(3) + ' s');
    data.curves.forEach(function (c) { lines.push(c.name + ': ' + fmt(c.values[f])); });
    tip.textContent = lines.join('\n');
    tip.style.display = 'block';
    tip.style.left = (e.clientX + 14) + 'px';
    tip.style.top = (e.clientY + 14) + 'px';
    var x = data.x[f];
    cursor.setAttribute('x1', x);
    cursor.setAttribute('x2', x);
    cursor.setAttribute('visibility', 'visible');
  });
  svg.addEventListener('mouseleave', function () {
    tip.style.display = 'none';
    cursor.setAttribute('visibility', 'hidden');
  });
  var bars = svg.querySelectorAll('.kf').length;
  var r = svg.getBoundingClientRect();
  document.body.setAttribute('data-timeline-left', String(r.left + window.scrollX));
  document.body.setAttribute('data-timeline-top', String(r.top + window.scrollY));
  document.body.setAttribute('data-rendered', bars + ' keyframes');
})();"#;

fn round4(v: f64) -> serde_json::Value {
    if v.is_finite() {
        json!((v * 1e4).round() / 1e4)
    } else {
        serde_json::Value::Null
    }
}

/// Renders the page.
pub fn page(p: &PageInput) -> String {
    let mut s = String::new();
    // Writing to a String cannot fail.
    let _ = write_page(p, &mut s);
    s
}

fn write_page(p: &PageInput, s: &mut String) -> std::fmt::Result {
    let pr = p.project;
    let m = &pr.metadata;
    let tl = p.timeline;
    let name = p
        .project_path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    writeln!(
        s,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>keyframer report: {}</title>\n<script>{ON_ERROR}</script>\n<style>{STYLE}</style>\n</head>\n<body>",
        esc(&name)
    )?;
    writeln!(s, "<h1>keyframer report: {}</h1>", esc(&name))?;

    // Summary.
    let fps = m.fps.map(|f| format!("{f:.3}")).unwrap_or("unknown".into());
    let duration = m
        .duration_s
        .map(|d| format!("{d:.2} s"))
        .unwrap_or("unknown".into());
    writeln!(s, "<table id=\"summary\">")?;
    let rows = [
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
    for (k, v) in rows {
        writeln!(s, "<tr><th>{k}</th><td>{}</td></tr>", esc(&v))?;
    }
    for d in &pr.decode_problems {
        writeln!(s, "<tr><th>decode problem</th><td>{}</td></tr>", esc(d))?;
    }
    writeln!(s, "</table>")?;
    if !p.missing.is_empty() {
        writeln!(
            s,
            "<div class=\"missing\" id=\"missing\"><b>Not in this report:</b><ul>"
        )?;
        for item in p.missing {
            writeln!(s, "<li>{}</li>", esc(item))?;
        }
        writeln!(s, "</ul></div>")?;
    }

    // Timeline.
    writeln!(
        s,
        "<h2>Timeline</h2>\n<div class=\"scroll\">\n{}</div>",
        tl.svg()
    )?;
    writeln!(
        s,
        "<div class=\"legend\"><span class=\"box\" style=\"background:{}\"></span>keyframe ({})",
        hex(timeline::KEYFRAME_RGB),
        pr.keyframes.len()
    )?;
    if tl
        .range
        .is_some_and(|(lo, hi)| lo > 0 || hi + 1 < tl.frames)
    {
        writeln!(
            s,
            "<span class=\"box\" style=\"background:#e1e1e1\"></span>outside the boundaries (not sampled)"
        )?;
    }
    for c in tl.panels.iter().flat_map(|p| p.curves.iter()) {
        writeln!(
            s,
            "<span class=\"sw{}\" style=\"border-color:{}\"></span>{}",
            if c.dashed { " dash" } else { "" },
            hex(c.rgb),
            esc(&c.name)
        )?;
    }
    writeln!(
        s,
        "<br>Hover the timeline for per-frame values. Thresholds: the blur filter keeps a frame whose \
         sharpness is at or above its dashed line (ratio × mean of the window); spacing keeps a frame \
         when the accumulated movement reaches its line; the stationary sampler compares each frame \
         with the keyframe directly, so the accumulated curve only approximates what it measured.{}</div>",
        p.timeline_png
            .as_ref()
            .map(|f| format!(" The same timeline is written as the PNG <code>{}</code>.", esc(f)))
            .unwrap_or_default()
    )?;
    writeln!(s, "<div id=\"tip\"></div>")?;

    // Thumbnails.
    writeln!(
        s,
        "<h2>Keyframes</h2>\n<p>{} of {} keyframes shown{}.</p>\n<div class=\"thumbs\" id=\"thumbs\">",
        p.thumbs.len(),
        pr.keyframes.len(),
        if p.thumbs.len() < pr.keyframes.len() {
            ", spread evenly"
        } else {
            ""
        }
    )?;
    let ts = pr.cache.timestamps_s.as_deref();
    for t in p.thumbs {
        let time = ts
            .and_then(|v| v.get(t.frame))
            .map(|v| format!(" · {v:.2} s"))
            .unwrap_or_default();
        writeln!(
            s,
            "<figure><img alt=\"frame {f}\" src=\"data:image/jpeg;base64,{}\"><figcaption>frame {f}{time}</figcaption></figure>",
            base64(&t.jpeg),
            f = t.frame
        )?;
    }
    writeln!(s, "</div>")?;

    // History.
    writeln!(
        s,
        "<h2>Steps</h2>\n<table id=\"history\"><tr><th>#</th><th>plugin</th><th>kept</th><th>parameters</th></tr>"
    )?;
    for (i, st) in pr.history.iter().enumerate() {
        writeln!(
            s,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td><code>{}</code></td></tr>",
            i + 1,
            esc(&st.plugin),
            st.kept,
            esc(&st.params.to_string())
        )?;
    }
    writeln!(s, "</table>")?;

    // Camera path.
    writeln!(s, "<h2>Camera path</h2>")?;
    match p.camera.filter(|c| !c.points.is_empty()) {
        Some(c) => {
            if let Some(st) = c.stats() {
                writeln!(
                    s,
                    "<p id=\"camera-stats\">{} cameras; spacing between consecutive cameras: mean {:.4}, \
                     coefficient of variation {:.3} (lower is more even). Top view on the two principal \
                     axes of the centres; segments coloured by the spacing to the previous camera.</p>",
                    st.cameras, st.mean_spacing, st.cv_spacing
                )?;
            }
            writeln!(s, "{}", c.svg())?;
        }
        None => writeln!(
            s,
            "<p id=\"camera-none\">No camera path: the report was made without a reconstruction \
             (camera centres come from a COLMAP model).</p>"
        )?,
    }

    // Data for the hover details, then the script.
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
    writeln!(
        s,
        "<script type=\"application/json\" id=\"kf-data\">{data}</script>\n<script>{SCRIPT}</script>\n</body>\n</html>"
    )
}
