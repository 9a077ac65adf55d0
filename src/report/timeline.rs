//! The report's timeline: per-frame curves, thresholds, boundaries and keyframes laid out in
//! stacked panels over the frame axis, drawn as SVG (HTML page) and as a PNG (OpenCV drawing).

use crate::error::{CvContext, Error, Result};
use crate::project::Project;
use opencv::core::{Mat, Point, Rect, Scalar, Vector, CV_8UC3};
use opencv::imgproc;
use opencv::prelude::*;
use std::fmt::Write;

/// Width of the timeline in pixels (SVG and PNG).
pub const WIDTH: u32 = 1200;
/// Left margin (y-axis labels); frame 0 is drawn at this x.
pub const LEFT: u32 = 80;
/// Right margin; the last frame is drawn at `WIDTH - RIGHT - 1`.
pub const RIGHT: u32 = 20;
/// Top of the first panel.
pub const TOP: u32 = 28;
/// Height of one panel's plot area.
pub const PANEL_H: u32 = 110;
/// Vertical space between panels (title of the next one).
pub const GAP: u32 = 30;
/// Space under the last panel (frame axis labels).
pub const BOTTOM: u32 = 40;
/// Colour of the keyframe bars (used by nothing else on the page or the PNG).
pub const KEYFRAME_RGB: [u8; 3] = [221, 0, 170];

const BOUNDARY_RGB: [u8; 3] = [225, 225, 225];
const AXIS_RGB: [u8; 3] = [90, 90, 90];
const GRID_RGB: [u8; 3] = [238, 238, 238];

/// One curve over the frames; `NaN` where it has no value.
#[derive(Debug, Clone)]
pub struct Curve {
    /// Legend text.
    pub name: String,
    /// Line colour.
    pub rgb: [u8; 3],
    /// Dashed (thresholds) or solid (measurements).
    pub dashed: bool,
    /// One value per frame, in the panel's unit.
    pub values: Vec<f64>,
}

/// One panel: curves sharing a y axis.
#[derive(Debug, Clone)]
pub struct Panel {
    /// Title above the plot.
    pub title: String,
    /// What the y axis measures.
    pub unit: String,
    /// The curves, drawn in order.
    pub curves: Vec<Curve>,
}

impl Panel {
    /// Top of the y axis: the largest finite value of any curve (1 when there is none).
    pub fn max(&self) -> f64 {
        let m = self
            .curves
            .iter()
            .flat_map(|c| c.values.iter())
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0f64, f64::max);
        if m > 0.0 {
            m * 1.05
        } else {
            1.0
        }
    }
}

/// Everything the timeline shows.
#[derive(Debug, Clone)]
pub struct Timeline {
    /// Number of frames of the input.
    pub frames: usize,
    /// Presentation time of every frame, when known.
    pub timestamps_s: Option<Vec<f64>>,
    /// Panels from top to bottom (at least one, possibly without curves).
    pub panels: Vec<Panel>,
    /// Keyframe indices.
    pub keyframes: Vec<usize>,
    /// Sampled range `first..=last` (frames outside it are shaded).
    pub range: Option<(usize, usize)>,
    /// What the project does not contain (shown on the page).
    pub missing: Vec<String>,
}

/// x pixel of frame `f` of `n` frames: frame 0 at `LEFT`, the last frame at `WIDTH - RIGHT - 1`,
/// rounded to whole pixels so that bars are crisp.
pub fn frame_x(f: usize, n: usize) -> i32 {
    let span = f64::from(WIDTH - LEFT - RIGHT - 1);
    if n <= 1 {
        return (f64::from(LEFT) + span / 2.0).round() as i32;
    }
    (f64::from(LEFT) + f as f64 * span / (n - 1) as f64).round() as i32
}

/// Total height for `panels` panels.
pub fn height(panels: usize) -> u32 {
    let k = panels.max(1) as u32;
    TOP + k * PANEL_H + (k - 1) * GAP + BOTTOM
}

/// Top y of panel `i`.
pub fn panel_top(i: usize) -> u32 {
    TOP + i as u32 * (PANEL_H + GAP)
}

/// Vertical extent of the panels: top of the first to bottom of the last.
pub fn bars_y(panels: usize) -> (u32, u32) {
    (TOP, panel_top(panels.max(1) - 1) + PANEL_H)
}

/// Rows `top..bottom` of every panel's plot area (where keyframe bars and shading are drawn).
pub fn panel_spans(panels: usize) -> impl Iterator<Item = (u32, u32)> {
    (0..panels.max(1)).map(|i| (panel_top(i), panel_top(i) + PANEL_H))
}

impl Timeline {
    /// Builds the timeline of `project`: sharpness per metric (with the blur threshold), movement
    /// between consecutive frames, and movement accumulated since the previous keyframe (with the
    /// spacing and stationary thresholds).
    pub fn from_project(project: &Project) -> Timeline {
        let n = project.metadata.frame_count;
        let cache = &project.cache;
        let range = project
            .boundaries
            .candidates(n, cache.timestamps_s.as_deref())
            .ok()
            .and_then(|c| Some((*c.first()?, *c.last()?)));
        let step = |id: &str| project.history.iter().rev().find(|s| s.plugin == id);
        let mut panels = Vec::new();
        let mut missing = Vec::new();

        let how = |what: &str| match project.preview {
            true => "a --preview project keeps no scores; a full select computes them".to_string(),
            false => format!("select with {what} computes them"),
        };
        if cache.sharpness.is_empty() {
            missing.push(format!("sharpness scores ({})", how("--blur")));
        } else {
            let several = cache.sharpness.len() > 1;
            let mut curves = Vec::new();
            for (i, s) in cache.sharpness.iter().enumerate() {
                let metric = serde_json::to_value(s.metric).unwrap_or_default();
                let peak = s.scores.iter().copied().fold(0.0f64, f64::max);
                let scale = if several && peak > 0.0 {
                    1.0 / peak
                } else {
                    1.0
                };
                let name = format!(
                    "{} at {}x{}",
                    metric.as_str().unwrap_or("sharpness"),
                    s.width,
                    s.height
                );
                curves.push(Curve {
                    name: format!("sharpness: {name}"),
                    rgb: SHARPNESS_RGB[i % SHARPNESS_RGB.len()],
                    dashed: false,
                    values: s.scores.iter().map(|v| v * scale).collect(),
                });
                let blur = step("blur").filter(|b| {
                    b.params["metric"] == metric
                        && s.width == project.metadata.width
                        && s.height == project.metadata.height
                });
                if let (Some(b), Some((lo, hi))) = (blur, range) {
                    let ratio = b.params["ratio"].as_f64();
                    let window = b.params["window"].as_u64().map(|w| w as usize);
                    let filter = b.params["mode"].as_str() == Some("filter");
                    if let (true, Some(ratio), Some(window)) = (filter, ratio, window) {
                        curves.push(Curve {
                            name: format!("blur threshold: {ratio} x mean of ±{window} frames"),
                            rgb: THRESHOLD_RGB[0],
                            dashed: true,
                            values: blur_threshold(&s.scores, lo, hi, window, ratio * scale),
                        });
                    }
                }
            }
            panels.push(Panel {
                title: if several {
                    "Sharpness (each metric divided by its maximum)".into()
                } else {
                    "Sharpness".into()
                },
                unit: if several { "score / max" } else { "score" }.into(),
                curves,
            });
        }

        if let Some(m) = cache.movement.first() {
            let v = &m.series.values;
            panels.push(Panel {
                title: format!(
                    "Camera movement between consecutive frames ({:?} of the flow magnitudes{} at {} px width)",
                    m.request.statistic,
                    m.request.derotate.map_or(String::new(), |d| format!(
                        " after subtracting the camera rotation, hfov {}°",
                        d.hfov_deg
                    )),
                    m.request.analysis_width
                ),
                unit: "px".into(),
                curves: vec![Curve {
                    name: "movement from the previous frame".into(),
                    rgb: MOVEMENT_RGB,
                    dashed: false,
                    values: v.clone(),
                }],
            });
            let mut curves = vec![Curve {
                name: "movement accumulated since the previous keyframe".into(),
                rgb: ACCUMULATED_RGB,
                dashed: false,
                values: accumulated(v, &project.keyframes, range),
            }];
            for (id, rgb) in [
                ("spacing", THRESHOLD_RGB[1]),
                ("stationary", THRESHOLD_RGB[2]),
            ] {
                if let Some(t) = step(id).and_then(|s| s.params["threshold_px"].as_f64()) {
                    curves.push(Curve {
                        name: format!("{id} threshold {t:.1} px"),
                        rgb,
                        dashed: true,
                        values: in_range(n, range, t),
                    });
                }
            }
            panels.push(Panel {
                title: "Movement accumulated since the previous keyframe (spacing keeps a frame when it reaches its threshold)".into(),
                unit: "px".into(),
                curves,
            });
        } else {
            missing.push(format!(
                "camera movement ({})",
                how("--spacing or --stationary")
            ));
        }
        if cache.timestamps_s.is_none() {
            missing.push("timestamps (an image folder without --images-fps)".to_string());
        }
        if panels.is_empty() {
            panels.push(Panel {
                title: "Keyframes (no per-frame scores cached)".into(),
                unit: String::new(),
                curves: Vec::new(),
            });
        }
        Timeline {
            frames: n,
            timestamps_s: cache.timestamps_s.clone(),
            panels,
            keyframes: project.keyframes.clone(),
            range,
            missing,
        }
    }

    /// Distinct x pixels of the keyframe bars (keyframes closer than a pixel share one).
    pub fn bar_columns(&self) -> Vec<i32> {
        let mut xs: Vec<i32> = self
            .keyframes
            .iter()
            .map(|&k| frame_x(k, self.frames))
            .collect();
        xs.dedup();
        xs
    }

    /// y pixel of `v` in panel `i` whose axis tops at `max`.
    fn y(&self, i: usize, v: f64, max: f64) -> f64 {
        let top = f64::from(panel_top(i));
        top + f64::from(PANEL_H) * (1.0 - (v / max).clamp(0.0, 1.0))
    }

    /// Polyline runs (broken at missing values) of curve `c` of panel `i`; long inputs are reduced
    /// to the minimum and maximum of each pixel column.
    pub fn polylines(&self, i: usize, c: &Curve, max: f64) -> Vec<Vec<(f64, f64)>> {
        let n = self.frames.min(c.values.len());
        let mut runs: Vec<Vec<(f64, f64)>> = Vec::new();
        let mut cur: Vec<(f64, f64)> = Vec::new();
        let dense = n > 2 * (WIDTH - LEFT - RIGHT) as usize;
        let mut f = 0;
        while f < n {
            let x = frame_x(f, self.frames);
            let mut end = f + 1;
            if dense {
                while end < n && frame_x(end, self.frames) == x {
                    end += 1;
                }
            }
            let vals: Vec<f64> = c.values[f..end]
                .iter()
                .copied()
                .filter(|v| v.is_finite())
                .collect();
            if vals.is_empty() {
                if cur.len() > 1 {
                    runs.push(std::mem::take(&mut cur));
                }
                cur.clear();
            } else {
                let lo = vals.iter().copied().fold(f64::INFINITY, f64::min);
                let hi = vals.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                cur.push((f64::from(x), self.y(i, lo, max)));
                if hi > lo {
                    cur.push((f64::from(x), self.y(i, hi, max)));
                }
            }
            f = end;
        }
        if !cur.is_empty() {
            runs.push(cur);
        }
        runs
    }

    /// Frame-axis ticks: about eight round frame numbers.
    pub fn ticks(&self) -> Vec<usize> {
        let n = self.frames.max(1);
        let raw = n as f64 / 8.0;
        let mag = 10f64.powf(raw.max(1.0).log10().floor());
        let step = [1.0, 2.0, 5.0, 10.0]
            .iter()
            .map(|m| m * mag)
            .find(|s| *s >= raw)
            .unwrap_or(10.0 * mag)
            .max(1.0) as usize;
        (0..n).step_by(step).collect()
    }

    fn tick_label(&self, f: usize) -> String {
        match self.timestamps_s.as_ref().and_then(|t| t.get(f)) {
            Some(t) => format!("{f} ({t:.1}s)"),
            None => f.to_string(),
        }
    }

    /// The timeline as an inline SVG element.
    pub fn svg(&self) -> String {
        let mut s = String::new();
        // Writing to a String cannot fail.
        let _ = self.write_svg(&mut s);
        s
    }

    fn write_svg(&self, s: &mut String) -> std::fmt::Result {
        let h = height(self.panels.len());
        let n = self.frames;
        writeln!(
            s,
            r#"<svg id="timeline" width="{WIDTH}" height="{h}" viewBox="0 0 {WIDTH} {h}" font-family="sans-serif" font-size="11" data-frames="{n}">"#
        )?;
        writeln!(s, r##"<rect width="{WIDTH}" height="{h}" fill="#fff"/>"##)?;
        let (by0, by1) = bars_y(self.panels.len());
        let x_end = frame_x(n.saturating_sub(1), n);
        if let Some((lo, hi)) = self.range {
            let shade = |a: i32, b: i32, s: &mut String| -> std::fmt::Result {
                for (y0, y1) in panel_spans(self.panels.len()) {
                    if b > a {
                        writeln!(
                            s,
                            r#"<rect class="outside" x="{a}" y="{y0}" width="{}" height="{}" fill="{}"/>"#,
                            b - a,
                            y1 - y0,
                            hex(BOUNDARY_RGB)
                        )?;
                    }
                }
                Ok(())
            };
            shade(LEFT as i32, frame_x(lo, n), s)?;
            shade(frame_x(hi, n) + 1, x_end + 1, s)?;
        }
        for (i, p) in self.panels.iter().enumerate() {
            let top = panel_top(i);
            let max = p.max();
            writeln!(
                s,
                r#"<text x="{LEFT}" y="{}" font-weight="bold">{}</text>"#,
                top - 8,
                super::esc(&p.title)
            )?;
            for frac in [0.0, 0.5, 1.0] {
                let y = top as f64 + PANEL_H as f64 * (1.0 - frac);
                writeln!(
                    s,
                    r#"<line x1="{LEFT}" x2="{x_end}" y1="{y}" y2="{y}" stroke="{}"/>"#,
                    hex(GRID_RGB)
                )?;
                if !p.curves.is_empty() {
                    writeln!(
                        s,
                        r#"<text x="{}" y="{}" text-anchor="end">{}</text>"#,
                        LEFT - 6,
                        y + 4.0,
                        number(max * frac)
                    )?;
                }
            }
            writeln!(
                s,
                r#"<text transform="translate(12 {}) rotate(-90)" text-anchor="middle">{}</text>"#,
                top + PANEL_H / 2,
                super::esc(&p.unit)
            )?;
            for c in &p.curves {
                for run in self.polylines(i, c, max) {
                    let pts: Vec<String> =
                        run.iter().map(|(x, y)| format!("{x:.1},{y:.1}")).collect();
                    writeln!(
                        s,
                        r#"<polyline fill="none" stroke="{}" stroke-width="1.3"{} points="{}"><title>{}</title></polyline>"#,
                        hex(c.rgb),
                        if c.dashed {
                            r#" stroke-dasharray="6 4""#
                        } else {
                            ""
                        },
                        pts.join(" "),
                        super::esc(&c.name)
                    )?;
                }
            }
            writeln!(
                s,
                r#"<rect x="{LEFT}" y="{top}" width="{}" height="{PANEL_H}" fill="none" stroke="{}"/>"#,
                x_end - LEFT as i32 + 1,
                hex(AXIS_RGB)
            )?;
        }
        for &k in &self.keyframes {
            write!(
                s,
                r#"<g class="kf" data-frame="{k}" fill="{}">"#,
                hex(KEYFRAME_RGB)
            )?;
            for (y0, y1) in panel_spans(self.panels.len()) {
                write!(
                    s,
                    r#"<rect x="{}" y="{y0}" width="1" height="{}" shape-rendering="crispEdges"/>"#,
                    frame_x(k, n),
                    y1 - y0
                )?;
            }
            writeln!(s, "</g>")?;
        }
        for t in self.ticks() {
            let x = frame_x(t, n);
            writeln!(
                s,
                r#"<line x1="{x}" x2="{x}" y1="{by1}" y2="{}" stroke="{}"/><text x="{x}" y="{}" text-anchor="middle">{}</text>"#,
                by1 + 4,
                hex(AXIS_RGB),
                by1 + 16,
                self.tick_label(t)
            )?;
        }
        writeln!(
            s,
            r#"<text x="{}" y="{}" text-anchor="middle">frame index (time)</text>"#,
            LEFT + (WIDTH - LEFT - RIGHT) / 2,
            by1 + 32
        )?;
        writeln!(
            s,
            r##"<line id="cursor" x1="0" x2="0" y1="{by0}" y2="{by1}" stroke="#000" stroke-width="1" visibility="hidden"/>"##
        )?;
        writeln!(s, "</svg>")
    }

    /// The timeline as an 8-bit BGR image (same layout as the SVG, OpenCV drawing).
    pub fn image(&self) -> Result<Mat> {
        let h = height(self.panels.len()) as i32;
        let n = self.frames;
        let cv = |what: &str| {
            let what = what.to_string();
            move || format!("drawing the timeline ({what})")
        };
        let mut img = Mat::new_rows_cols_with_default(h, WIDTH as i32, CV_8UC3, bgr([255; 3]))
            .cv(cv("canvas"))?;
        let by1 = bars_y(self.panels.len()).1 as i32;
        let x_end = frame_x(n.saturating_sub(1), n);
        if let Some((lo, hi)) = self.range {
            for (a, b) in [
                (LEFT as i32, frame_x(lo, n)),
                (frame_x(hi, n) + 1, x_end + 1),
            ] {
                for (y0, y1) in panel_spans(self.panels.len()).filter(|_| b > a) {
                    let (y0, y1) = (y0 as i32, y1 as i32);
                    imgproc::rectangle(
                        &mut img,
                        Rect::new(a, y0, b - a, y1 - y0),
                        bgr(BOUNDARY_RGB),
                        imgproc::FILLED,
                        imgproc::LINE_8,
                        0,
                    )
                    .cv(cv("boundaries"))?;
                }
            }
        }
        let text = |img: &mut Mat, t: &str, x: i32, y: i32| -> Result<()> {
            imgproc::put_text(
                img,
                t,
                Point::new(x, y),
                imgproc::FONT_HERSHEY_SIMPLEX,
                0.38,
                bgr(AXIS_RGB),
                1,
                imgproc::LINE_AA,
                false,
            )
            .cv(cv("text"))
        };
        for (i, p) in self.panels.iter().enumerate() {
            let top = panel_top(i) as i32;
            let max = p.max();
            text(&mut img, &p.title, LEFT as i32, top - 8)?;
            for frac in [0.0, 0.5, 1.0] {
                let y = top + (f64::from(PANEL_H) * (1.0 - frac)).round() as i32;
                imgproc::line(
                    &mut img,
                    Point::new(LEFT as i32, y),
                    Point::new(x_end, y),
                    bgr(GRID_RGB),
                    1,
                    imgproc::LINE_8,
                    0,
                )
                .cv(cv("grid"))?;
                if !p.curves.is_empty() {
                    text(&mut img, &number(max * frac), 4, y + 4)?;
                }
            }
            for c in &p.curves {
                for run in self.polylines(i, c, max) {
                    let pts: Vec<Point> = run
                        .iter()
                        .map(|(x, y)| Point::new(x.round() as i32, y.round() as i32))
                        .collect();
                    for (j, w) in pts.windows(2).enumerate() {
                        if c.dashed && j % 2 == 1 && pts.len() > 2 {
                            continue;
                        }
                        imgproc::line(&mut img, w[0], w[1], bgr(c.rgb), 1, imgproc::LINE_AA, 0)
                            .cv(cv("curve"))?;
                    }
                }
            }
            imgproc::rectangle(
                &mut img,
                Rect::new(LEFT as i32, top, x_end - LEFT as i32 + 1, PANEL_H as i32),
                bgr(AXIS_RGB),
                1,
                imgproc::LINE_8,
                0,
            )
            .cv(cv("frame"))?;
        }
        for x in self.bar_columns() {
            for (y0, y1) in panel_spans(self.panels.len()) {
                imgproc::line(
                    &mut img,
                    Point::new(x, y0 as i32),
                    Point::new(x, y1 as i32 - 1),
                    bgr(KEYFRAME_RGB),
                    1,
                    imgproc::LINE_8,
                    0,
                )
                .cv(cv("keyframes"))?;
            }
        }
        for t in self.ticks() {
            let x = frame_x(t, n);
            imgproc::line(
                &mut img,
                Point::new(x, by1),
                Point::new(x, by1 + 4),
                bgr(AXIS_RGB),
                1,
                imgproc::LINE_8,
                0,
            )
            .cv(cv("ticks"))?;
            let label = self.tick_label(t);
            text(&mut img, &label, x - 3 * label.len() as i32, by1 + 16)?;
        }
        Ok(img)
    }

    /// The PNG bytes of [`Timeline::image`].
    pub fn png(&self) -> Result<Vec<u8>> {
        let img = self.image()?;
        let mut buf = Vector::<u8>::new();
        let ok = opencv::imgcodecs::imencode(".png", &img, &mut buf, &Vector::new())
            .cv(|| "encoding the timeline PNG".into())?;
        if !ok {
            return Err(Error::param("timeline", "PNG encoding failed"));
        }
        Ok(buf.to_vec())
    }
}

/// Colours of sharpness curves, one per metric.
pub const SHARPNESS_RGB: [[u8; 3]; 3] = [[31, 119, 180], [23, 190, 207], [140, 86, 75]];
/// Colour of the consecutive movement curve.
pub const MOVEMENT_RGB: [u8; 3] = [44, 160, 44];
/// Colour of the accumulated movement curve.
pub const ACCUMULATED_RGB: [u8; 3] = [80, 80, 80];
/// Colours of the blur, spacing and stationary thresholds.
pub const THRESHOLD_RGB: [[u8; 3]; 3] = [[255, 127, 14], [214, 39, 40], [148, 103, 189]];

/// ratio x mean of `scores` over ±`window` frames clipped to `lo..=hi` (the blur filter's
/// threshold), NaN outside the range.
pub fn blur_threshold(scores: &[f64], lo: usize, hi: usize, window: usize, ratio: f64) -> Vec<f64> {
    let mut out = vec![f64::NAN; scores.len()];
    if hi >= scores.len() || lo > hi {
        return out;
    }
    // Prefix sums keep this linear in the frame count.
    let mut prefix = vec![0.0; scores.len() + 1];
    for (i, v) in scores.iter().enumerate() {
        prefix[i + 1] = prefix[i] + v;
    }
    for (k, o) in out.iter_mut().enumerate().take(hi + 1).skip(lo) {
        let a = k.saturating_sub(window).max(lo);
        let b = (k + window).min(hi);
        *o = ratio * (prefix[b + 1] - prefix[a]) / (b + 1 - a) as f64;
    }
    out
}

/// Movement accumulated over consecutive frames since the previous keyframe (0 at a keyframe),
/// NaN outside the sampled range.
pub fn accumulated(values: &[f64], keyframes: &[usize], range: Option<(usize, usize)>) -> Vec<f64> {
    let (lo, hi) = range.unwrap_or((0, values.len().saturating_sub(1)));
    let mut out = vec![f64::NAN; values.len()];
    let mut sum = 0.0;
    for (f, o) in out.iter_mut().enumerate().take(hi + 1).skip(lo) {
        if f > lo {
            sum += values[f];
        }
        *o = sum;
        if keyframes.binary_search(&f).is_ok() {
            sum = 0.0;
        }
    }
    out
}

fn in_range(n: usize, range: Option<(usize, usize)>, v: f64) -> Vec<f64> {
    let (lo, hi) = range.unwrap_or((0, n.saturating_sub(1)));
    (0..n)
        .map(|f| if (lo..=hi).contains(&f) { v } else { f64::NAN })
        .collect()
}

/// `#rrggbb`.
pub fn hex(c: [u8; 3]) -> String {
    format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
}

fn bgr(c: [u8; 3]) -> Scalar {
    Scalar::new(f64::from(c[2]), f64::from(c[1]), f64::from(c[0]), 0.0)
}

/// A short axis label: 3 significant digits.
pub fn number(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() >= 1000.0 {
        format!("{v:.0}")
    } else if v.abs() >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.3}")
    }
}
