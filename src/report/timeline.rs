//! The report's timeline: per-frame curves, thresholds, boundaries and keyframes laid out in
//! stacked panels over the frame axis, drawn by plotters from one description ([`Timeline::draw`]) as SVG (HTML page) and as a PNG.

use crate::error::{Error, Result};
use crate::params::Metric;
use crate::project::{MovementCache, Project};
use crate::steps::{blur, geo_distance, spacing, Applied, BlurMode, Recorded};
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::FontTransform;

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
/// Colour of the bars of keyframes `reconstruct` added (on the page and the PNG).
pub const ADDED_RGB: [u8; 3] = [0, 150, 60];

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
    /// The keyframes `reconstruct` added, with the reason for each.
    pub added: std::collections::BTreeMap<usize, String>,
    /// Sampled range `first..=last` (frames outside it are shaded).
    pub range: Option<(usize, usize)>,
    /// What the project does not contain (shown on the page).
    pub missing: Vec<String>,
    /// The frames shown, `from..=to` (all of them unless [`Timeline::view`] narrowed it).
    pub view: (usize, usize),
}

/// Where the frames lie on the x axis: frame `from` at `left`, frame `to` at `left + span`,
/// linear in between (a client maps a pixel back with [`Layout::frame_at`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Layout {
    /// x pixel of the first frame shown.
    pub left: u32,
    /// Pixels from the first frame shown to the last.
    pub span: u32,
    /// Width of the drawing.
    pub width: u32,
    /// First frame shown.
    pub from: usize,
    /// Last frame shown (inclusive).
    pub to: usize,
}

impl Layout {
    /// The layout showing frames `from..=to`.
    pub fn new(from: usize, to: usize) -> Layout {
        let span = WIDTH - LEFT - RIGHT - 1;
        Layout {
            left: LEFT,
            span,
            width: WIDTH,
            from,
            to,
        }
    }

    /// x pixel of frame `f`, rounded to whole pixels so that bars are crisp (a single frame
    /// shown sits in the middle).
    pub fn x(&self, f: usize) -> i32 {
        let (left, span) = (f64::from(self.left), f64::from(self.span));
        if self.to <= self.from {
            return (left + span / 2.0).round() as i32;
        }
        let at = (f as f64 - self.from as f64) * span / (self.to - self.from) as f64;
        (left + at).round() as i32
    }

    /// The frame shown nearest to pixel `x`.
    pub fn frame_at(&self, x: f64) -> usize {
        let frames = (self.to.saturating_sub(self.from)) as f64;
        let f = ((x - f64::from(self.left)) * frames / f64::from(self.span)).round();
        self.from + (f.max(0.0) as usize).min(self.to.saturating_sub(self.from))
    }
}

/// x pixel of frame `f` of `n` frames with all of them shown: frame 0 at `LEFT`, the last frame
/// at `WIDTH - RIGHT - 1`.
pub fn frame_x(f: usize, n: usize) -> i32 {
    Layout::new(0, n.saturating_sub(1)).x(f)
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
    /// between consecutive frames, movement accumulated since the previous keyframe (with the
    /// spacing and stationary thresholds) and, with telemetry, metres moved since the previous
    /// keyframe (with the geo-distance threshold).
    pub fn from_project(project: &Project) -> Timeline {
        Timeline::from_selection(project, &project.keyframes, &project.history)
    }

    /// The timeline of `project`'s cache for another selection: `keyframes` chosen by steps
    /// recorded as `history`, whose thresholds it draws.
    pub fn from_selection(
        project: &Project,
        keyframes: &[usize],
        history: &[Recorded],
    ) -> Timeline {
        let n = project.metadata.frame_count;
        let cache = &project.cache;
        let range = project
            .boundaries
            .candidates(n, cache.timestamps_s.as_deref())
            .ok()
            .and_then(|c| Some((*c.first()?, *c.last()?)));
        let recorded = Thresholds::of(history);
        let mut panels = Vec::new();
        let mut missing = Vec::new();
        let how = |what: &str| match project.preview {
            true => "a --preview project keeps no scores; a full select computes them".to_string(),
            false => format!("select with {what} computes them"),
        };
        if cache.sharpness.is_empty() {
            missing.push(format!("sharpness scores ({})", how("--blur")));
        } else {
            panels.push(sharpness_panel(project, &recorded, range));
        }
        match cache.movement.first() {
            Some(m) => panels.extend(movement_panels(m, keyframes, &recorded, (n, range))),
            None => missing.push(format!(
                "camera movement ({})",
                how("--spacing or --stationary")
            )),
        }
        if let Some(t) = &cache.telemetry {
            let panel = telemetry_panel(&t.positions, keyframes, &recorded, (n, range));
            panels.push(panel);
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
        let mut added = std::collections::BTreeMap::new();
        for r in history {
            if let crate::steps::Applied::Reconstruct { added: frames, .. } = &r.applied {
                for a in frames.iter().filter(|a| keyframes.contains(&a.frame)) {
                    added.insert(a.frame, a.reason.clone());
                }
            }
        }
        Timeline {
            frames: n,
            timestamps_s: cache.timestamps_s.clone(),
            panels,
            keyframes: keyframes.to_vec(),
            added,
            range,
            missing,
            view: (0, n.saturating_sub(1)),
        }
    }

    /// The same timeline showing only frames `from..=to` (clamped to the input), for zooming.
    pub fn view(self, from: usize, to: usize) -> Timeline {
        let to = to.min(self.frames.saturating_sub(1));
        Timeline {
            view: (from.min(to), to),
            ..self
        }
    }

    /// Where the frames shown lie on the x axis.
    pub fn layout(&self) -> Layout {
        Layout::new(self.view.0, self.view.1)
    }

    /// The keyframes shown.
    fn keyframes_shown(&self) -> impl Iterator<Item = usize> + '_ {
        let (from, to) = self.view;
        self.keyframes
            .iter()
            .copied()
            .filter(move |k| (from..=to).contains(k))
    }

    /// Distinct x pixels of the keyframe bars (keyframes closer than a pixel share one).
    pub fn bar_columns(&self) -> Vec<i32> {
        self.bars().into_iter().map(|(x, _)| x).collect()
    }

    /// The keyframe bars: distinct x pixels and their colour, [`ADDED_RGB`] for a keyframe
    /// `reconstruct` added, else [`KEYFRAME_RGB`] (keyframes closer than a pixel share one
    /// column, coloured by the first of them, as on the page).
    pub fn bars(&self) -> Vec<(i32, [u8; 3])> {
        let layout = self.layout();
        let mut bars: Vec<(i32, [u8; 3])> = self
            .keyframes_shown()
            .map(|k| (layout.x(k), self.colour_of(k)))
            .collect();
        bars.dedup_by_key(|b| b.0);
        bars
    }

    /// The bar colour of keyframe `k`.
    fn colour_of(&self, k: usize) -> [u8; 3] {
        match self.added.contains_key(&k) {
            true => ADDED_RGB,
            false => KEYFRAME_RGB,
        }
    }

    /// y pixel of `v` in panel `i` whose axis tops at `max`.
    fn y(&self, i: usize, v: f64, max: f64) -> f64 {
        let top = f64::from(panel_top(i));
        top + f64::from(PANEL_H) * (1.0 - (v / max).clamp(0.0, 1.0))
    }

    /// Polyline runs (broken at missing values) of curve `c` of panel `i` over the frames shown;
    /// long views are reduced to the minimum and maximum of each pixel column.
    pub fn polylines(&self, i: usize, c: &Curve, max: f64) -> Vec<Vec<(f64, f64)>> {
        let (layout, n) = (self.layout(), (self.view.1 + 1).min(c.values.len()));
        let mut runs: Vec<Vec<(f64, f64)>> = Vec::new();
        let mut cur: Vec<(f64, f64)> = Vec::new();
        let dense = n.saturating_sub(self.view.0) > 2 * (WIDTH - LEFT - RIGHT) as usize;
        let mut f = self.view.0;
        while f < n {
            let x = layout.x(f);
            let mut end = f + 1;
            if dense {
                while end < n && layout.x(end) == x {
                    end += 1;
                }
            }
            // (lo, hi) of the finite values; lo > hi when there is none.
            let (lo, hi) = c.values[f..end]
                .iter()
                .filter(|v| v.is_finite())
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                    (lo.min(v), hi.max(v))
                });
            if lo > hi {
                if cur.len() > 1 {
                    runs.push(std::mem::take(&mut cur));
                }
                cur.clear();
            } else {
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

    /// Frame-axis ticks: about eight round frame numbers among the frames shown.
    pub fn ticks(&self) -> Vec<usize> {
        let (from, to) = self.view;
        let raw = (to - from + 1) as f64 / 8.0;
        let mag = 10f64.powf(raw.max(1.0).log10().floor());
        let step = [1.0, 2.0, 5.0, 10.0]
            .iter()
            .map(|m| m * mag)
            .find(|s| *s >= raw)
            .unwrap_or(10.0 * mag)
            .max(1.0) as usize;
        (from.div_ceil(step) * step..=to).step_by(step).collect()
    }

    fn tick_label(&self, f: usize) -> String {
        match self.timestamps_s.as_ref().and_then(|t| t.get(f)) {
            Some(t) => format!("{f} ({t:.1}s)"),
            None => f.to_string(),
        }
    }

    /// The timeline as an inline SVG element: plotters' drawing of [`Timeline::draw`] inside the
    /// page's own `<svg id="timeline">` (which the page script and the tests find), each
    /// keyframe's bars in a `<g class="kf" data-frame="K">` and a hidden `#cursor` line on top.
    pub fn svg(&self) -> Result<String> {
        let h = height(self.panels.len());
        let n = self.frames;
        let mut s = format!(
            r#"<svg id="timeline" width="{WIDTH}" height="{h}" viewBox="0 0 {WIDTH} {h}" font-family="sans-serif" font-size="11" data-frames="{n}">"#
        );
        s.push('\n');
        s.push_str(&svg_layer(h, |root| self.draw(root))?);
        let (mut last, layout) = (None, self.layout());
        for k in self.keyframes_shown() {
            let x = layout.x(k);
            match self.added.get(&k) {
                // Added by `reconstruct`: its own colour, the reason on hover.
                Some(reason) => s.push_str(&format!(
                    r#"<g class="kf added" data-frame="{k}" fill="{}"><title>frame {k} added by reconstruct: {}</title>"#,
                    hex(ADDED_RGB),
                    xml_escape(reason)
                )),
                None => s.push_str(&format!(
                    r#"<g class="kf" data-frame="{k}" fill="{}">"#,
                    hex(KEYFRAME_RGB)
                )),
            }
            s.push('\n');
            // Keyframes closer than a pixel share one column: drawn once, each still has its group.
            if last != Some(x) {
                let bar = [(x, self.colour_of(k))];
                s.push_str(&svg_layer(h, |root| self.draw_bars(root, &bar))?);
            }
            last = Some(x);
            s.push_str("</g>\n");
        }
        let (by0, by1) = bars_y(self.panels.len());
        s.push_str(&format!(
            r##"<line id="cursor" x1="0" x2="0" y1="{by0}" y2="{by1}" stroke="#000" stroke-width="1" visibility="hidden"/>"##
        ));
        s.push_str("\n</svg>");
        Ok(s)
    }

    /// The timeline as an 8-bit RGB image, `WIDTH` x [`height`] (the same drawing as the SVG).
    pub fn image(&self) -> Result<image::RgbImage> {
        let h = height(self.panels.len());
        let mut buf = vec![0u8; WIDTH as usize * h as usize * 3];
        font::register()?;
        {
            let root = BitMapBackend::with_buffer(&mut buf, (WIDTH, h)).into_drawing_area();
            self.draw(&root).map_err(drawing)?;
            self.draw_bars(&root, &self.bars()).map_err(drawing)?;
            root.present().map_err(drawing)?;
        }
        image::RgbImage::from_raw(WIDTH, h, buf)
            .ok_or_else(|| Error::param("timeline", "the drawing has the wrong size"))
    }

    /// The PNG bytes of [`Timeline::image`].
    pub fn png(&self) -> Result<Vec<u8>> {
        let img = self.image()?;
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Png)
            .map_err(|e| Error::param("timeline", format!("PNG encoding failed: {e}")))?;
        Ok(out.into_inner())
    }

    /// The timeline without the keyframe bars, on any plotters backend, in pixel coordinates:
    /// shading outside the boundaries, per panel its title, grid, axis labels, curves (thresholds
    /// dashed) and frame, then the frame axis.
    pub fn draw<DB: DrawingBackend>(&self, root: &Area<DB>) -> Drawn<DB> {
        root.fill(&WHITE)?;
        self.draw_shading(root)?;
        for (i, p) in self.panels.iter().enumerate() {
            self.draw_panel(root, i, p)?;
        }
        self.draw_frame_axis(root)
    }

    /// x pixel of the last frame shown.
    fn x_end(&self) -> i32 {
        self.layout().x(self.view.1)
    }

    /// Shading of every panel's plot area outside the sampled range.
    fn draw_shading<DB: DrawingBackend>(&self, root: &Area<DB>) -> Drawn<DB> {
        if let Some((lo, hi)) = self.range {
            let (layout, x_end) = (self.layout(), self.x_end());
            let (lo_x, after_hi) = (layout.x(lo).min(x_end + 1), layout.x(hi) + 1);
            for (a, b) in [(LEFT as i32, lo_x), (after_hi.max(LEFT as i32), x_end + 1)] {
                for (y0, y1) in panel_spans(self.panels.len()).filter(|_| b > a) {
                    let shade = [(a, y0 as i32), (b, y1 as i32)];
                    root.draw(&Rectangle::new(shade, rgb(BOUNDARY_RGB).filled()))?;
                }
            }
        }
        Ok(())
    }

    /// Panel `i`: title, grid with value labels, unit, curves and frame.
    fn draw_panel<DB: DrawingBackend>(&self, root: &Area<DB>, i: usize, p: &Panel) -> Drawn<DB> {
        let (top, max, x_end) = (panel_top(i) as i32, p.max(), self.x_end());
        let bold = TextStyle::from((FONT, FONT_PX, FontStyle::Bold).into_font());
        let title = bold.color(&BLACK).pos(Pos::new(HPos::Left, VPos::Bottom));
        root.draw(&Text::new(p.title.clone(), (LEFT as i32, top - 5), title))?;
        for frac in [0.0, 0.5, 1.0] {
            let y = top + (f64::from(PANEL_H) * (1.0 - frac)).round() as i32;
            let grid = vec![(LEFT as i32, y), (x_end, y)];
            root.draw(&PathElement::new(grid, rgb(GRID_RGB)))?;
            if !p.curves.is_empty() {
                let right = axis_text(Pos::new(HPos::Right, VPos::Center));
                root.draw(&Text::new(number(max * frac), (LEFT as i32 - 6, y), right))?;
            }
        }
        let unit = axis_text(Pos::new(HPos::Center, VPos::Center));
        let unit = unit.transform(FontTransform::Rotate270);
        let mid = (6, top + PANEL_H as i32 / 2);
        root.draw(&Text::new(p.unit.clone(), mid, unit))?;
        self.draw_curves(root, i, p)?;
        let frame = [(LEFT as i32, top), (x_end, top + PANEL_H as i32 - 1)];
        root.draw(&Rectangle::new(frame, rgb(AXIS_RGB)))
    }

    /// The curves of panel `i` in order, thresholds dashed.
    fn draw_curves<DB: DrawingBackend>(&self, root: &Area<DB>, i: usize, p: &Panel) -> Drawn<DB> {
        let (max, px) = (p.max(), |v: f64| v.round() as i32);
        for c in &p.curves {
            let style = ShapeStyle::from(rgb(c.rgb)).stroke_width(1);
            for run in self.polylines(i, c, max) {
                let pts: Vec<(i32, i32)> = run.iter().map(|&(x, y)| (px(x), px(y))).collect();
                if c.dashed {
                    root.draw(&DashedPathElement::new(pts, 6, 4, style))?;
                } else {
                    root.draw(&PathElement::new(pts, style))?;
                }
            }
        }
        Ok(())
    }

    /// The frame axis under the panels: ticks, their labels and the axis title.
    fn draw_frame_axis<DB: DrawingBackend>(&self, root: &Area<DB>) -> Drawn<DB> {
        let by1 = bars_y(self.panels.len()).1 as i32;
        let centre = || axis_text(Pos::new(HPos::Center, VPos::Top));
        for t in self.ticks() {
            let x = self.layout().x(t);
            let tick = vec![(x, by1), (x, by1 + 4)];
            root.draw(&PathElement::new(tick, rgb(AXIS_RGB)))?;
            root.draw(&Text::new(self.tick_label(t), (x, by1 + 6), centre()))?;
        }
        let at = ((LEFT + (WIDTH - LEFT - RIGHT) / 2) as i32, by1 + 22);
        root.draw(&Text::new("frame index (time)", at, centre()))
    }

    /// Keyframe bars: one pixel column at each x of `columns`, over every panel's plot area, in
    /// [`KEYFRAME_RGB`] (drawn last so that nothing covers them).
    pub fn draw_bars<DB: DrawingBackend>(
        &self,
        root: &Area<DB>,
        bars: &[(i32, [u8; 3])],
    ) -> Drawn<DB> {
        for &(x, colour) in bars {
            for (y0, y1) in panel_spans(self.panels.len()) {
                root.draw(&Rectangle::new(
                    [(x, y0 as i32), (x + 1, y1 as i32)],
                    rgb(colour).filled(),
                ))?;
            }
        }
        Ok(())
    }
}

/// The thresholds the last recorded steps used.
#[derive(Default)]
struct Thresholds {
    blur: Option<RecordedBlur>,
    spacing: Option<Option<f64>>,
    stationary: Option<Option<f64>>,
    geo_distance: Option<f64>,
}

/// A blur step's metric, mode, ratio and window as recorded.
type RecordedBlur = (Option<Metric>, Option<BlurMode>, Option<f64>, Option<usize>);

impl Thresholds {
    fn of(history: &[Recorded]) -> Thresholds {
        let mut r = Thresholds::default();
        for e in history {
            match e.applied {
                Applied::Blur {
                    metric,
                    mode,
                    ratio,
                    window,
                    ..
                } => r.blur = Some((metric, mode, ratio, window)),
                Applied::Spacing { threshold_px, .. } => r.spacing = Some(Some(threshold_px)),
                Applied::Stationary { threshold_px, .. } => r.stationary = Some(threshold_px),
                Applied::GeoDistance { metres } => r.geo_distance = Some(metres),
                _ => {}
            }
        }
        r
    }
}

/// Every cached sharpness series (each divided by its maximum when there are several), with the
/// blur threshold the last blur step used where it applies.
fn sharpness_panel(project: &Project, r: &Thresholds, range: Option<(usize, usize)>) -> Panel {
    let cache = &project.cache;
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
        let rows = match s.rows {
            Some(r) => format!(", rows {}..{}", r.first, r.first + r.count),
            None => String::new(),
        };
        let name = format!(
            "{} at {}x{}{rows}",
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
        let full_size = s.width == project.metadata.width && s.height == project.metadata.height;
        let blur = r.blur.filter(|b| b.0 == Some(s.metric) && full_size);
        if let (Some((_, mode, ratio, window)), Some((lo, hi))) = (blur, range) {
            if let (Some(BlurMode::Filter), Some(ratio), Some(window)) = (mode, ratio, window) {
                curves.push(Curve {
                    name: format!("blur threshold: {ratio} x mean of ±{window} frames"),
                    rgb: THRESHOLD_RGB[0],
                    dashed: true,
                    values: blur::threshold_series(&s.scores, lo, hi, window, ratio * scale),
                });
            }
        }
    }
    Panel {
        title: if several {
            "Sharpness (each metric divided by its maximum)".into()
        } else {
            "Sharpness".into()
        },
        unit: if several { "score / max" } else { "score" }.into(),
        curves,
    }
}

/// The movement between consecutive frames, and the movement accumulated since the previous
/// keyframe with the spacing and stationary thresholds.
fn movement_panels(
    m: &MovementCache,
    keyframes: &[usize],
    r: &Thresholds,
    (n, range): (usize, Option<(usize, usize)>),
) -> [Panel; 2] {
    let v = &m.series.values;
    let movement = Panel {
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
    };
    let mut curves = vec![Curve {
        name: "movement accumulated since the previous keyframe".into(),
        rgb: ACCUMULATED_RGB,
        dashed: false,
        values: spacing::accumulated(v, keyframes, range),
    }];
    for (id, threshold, rgb) in [
        ("spacing", r.spacing, THRESHOLD_RGB[1]),
        ("stationary", r.stationary, THRESHOLD_RGB[2]),
    ] {
        let curve = threshold_curve(id, threshold.flatten(), "px", rgb, (n, range));
        curves.extend(curve);
    }
    let accumulated = Panel {
        title: "Movement accumulated since the previous keyframe (spacing keeps a frame when it reaches its threshold)".into(),
        unit: "px".into(),
        curves,
    };
    [movement, accumulated]
}

/// A threshold as a dashed curve over `frames` frames, when the steps used one.
fn threshold_curve(
    id: &str,
    threshold: Option<f64>,
    unit: &str,
    rgb: [u8; 3],
    (frames, range): (usize, Option<(usize, usize)>),
) -> Option<Curve> {
    threshold.map(|t| Curve {
        name: format!("{id} threshold {t:.1} {unit}"),
        rgb,
        dashed: true,
        values: spacing::threshold_series(frames, range, t),
    })
}

/// Metres the camera moved since the previous keyframe (telemetry positions), with the
/// geo-distance threshold.
fn telemetry_panel(
    positions: &[Option<crate::source::telemetry::Position>],
    keyframes: &[usize],
    r: &Thresholds,
    (n, range): (usize, Option<(usize, usize)>),
) -> Panel {
    let mut curves = vec![Curve {
        name: "metres moved since the previous keyframe".into(),
        rgb: GEO_RGB,
        dashed: false,
        values: geo_distance::moved(positions, keyframes, range),
    }];
    let geo = r.geo_distance;
    let rgb = THRESHOLD_RGB[1];
    curves.extend(threshold_curve("geo-distance", geo, "m", rgb, (n, range)));
    Panel {
        title: "Distance moved since the previous keyframe, by the telemetry's positions (geo-distance keeps a frame when it reaches its threshold)".into(),
        unit: "m".into(),
        curves,
    }
}

/// A plotters drawing area in pixel coordinates.
pub type Area<DB> = DrawingArea<DB, Shift>;
/// What drawing on an [`Area`] returns.
pub type Drawn<DB> =
    std::result::Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// Font family of the timeline's text (the SVG names it; the PNG draws it with DejaVu Sans).
const FONT: &str = "sans-serif";
/// Text size in plotters' units (pixels × 1.24): 11 px, as the page's other text.
const FONT_PX: f64 = 11.0 * 1.24;

fn rgb(c: [u8; 3]) -> RGBColor {
    RGBColor(c[0], c[1], c[2])
}

/// Axis-coloured timeline text anchored at `anchor`.
fn axis_text(anchor: Pos) -> TextStyle<'static> {
    let mut style = TextStyle::from((FONT, FONT_PX).into_font()).pos(anchor);
    style.color = rgb(AXIS_RGB).to_backend_color();
    style
}

fn drawing<E: std::error::Error + Send + Sync>(e: DrawingAreaErrorKind<E>) -> Error {
    Error::param("timeline", format!("drawing the timeline failed: {e}"))
}

/// The SVG elements plotters writes for `draw` on a `WIDTH` x `h` area, without plotters' own
/// `<svg>` element (the page wraps them in its own, without an `xmlns` address: inline SVG in
/// HTML needs none, and the page refers to nothing outside itself).
fn svg_layer(
    h: u32,
    draw: impl for<'a> FnOnce(&Area<SVGBackend<'a>>) -> Drawn<SVGBackend<'a>>,
) -> Result<String> {
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (WIDTH, h)).into_drawing_area();
        draw(&root).map_err(drawing)?;
        root.present().map_err(drawing)?;
    }
    let body = out
        .find('>')
        .map(|i| &out[i + 1..])
        .and_then(|rest| rest.trim_end().strip_suffix("</svg>"))
        .ok_or_else(|| Error::param("timeline", "unexpected SVG from the plotting library"))?;
    Ok(body.trim_start_matches('\n').to_string())
}

/// The font the PNG's text is drawn with, read once from the Debian package `fonts-dejavu-core`.
mod font {
    use crate::error::{Error, Result};
    use plotters::style::{register_font, FontStyle};
    use std::sync::OnceLock;

    /// Where Debian's `fonts-dejavu-core` puts DejaVu Sans and its bold face.
    pub const REGULAR: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";
    /// The bold face (panel titles).
    pub const BOLD: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans-Bold.ttf";

    /// Registers DejaVu Sans as plotters' `sans-serif` (once per process).
    pub fn register() -> Result<()> {
        static DONE: OnceLock<std::result::Result<(), String>> = OnceLock::new();
        DONE.get_or_init(|| {
            for (path, style) in [(REGULAR, FontStyle::Normal), (BOLD, FontStyle::Bold)] {
                let bytes = std::fs::read(path).map_err(|e| {
                    format!(
                        "the PNG timeline's text needs the font {path} ({e}); install the Debian \
                         package fonts-dejavu-core (scripts/setup.sh does)"
                    )
                })?;
                // Registered fonts live as long as the process.
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                register_font(super::FONT, style, bytes)
                    .map_err(|_| format!("{path} is not a font plotters can read"))?;
            }
            Ok(())
        })
        .clone()
        .map_err(|msg| Error::param("timeline", msg))
    }
}

/// Colours of sharpness curves, one per metric.
pub const SHARPNESS_RGB: [[u8; 3]; 3] = [[31, 119, 180], [23, 190, 207], [140, 86, 75]];
/// Colour of the consecutive movement curve.
pub const MOVEMENT_RGB: [u8; 3] = [44, 160, 44];
/// Colour of the accumulated movement curve.
pub const ACCUMULATED_RGB: [u8; 3] = [80, 80, 80];
/// Colour of the distance moved by the telemetry's positions.
pub const GEO_RGB: [u8; 3] = [31, 119, 180];
/// Colours of the blur, spacing and stationary thresholds.
pub const THRESHOLD_RGB: [[u8; 3]; 3] = [[255, 127, 14], [214, 39, 40], [148, 103, 189]];

/// `#rrggbb`.
pub fn hex(c: [u8; 3]) -> String {
    format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
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

/// `text` escaped for XML character data.
fn xml_escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A timeline of `frames` frames with one curve (the frame index) and `keyframes`.
    fn timeline(frames: usize, keyframes: Vec<usize>) -> Timeline {
        let curve = Curve {
            name: "index".into(),
            rgb: MOVEMENT_RGB,
            dashed: false,
            values: (0..frames).map(|f| f as f64).collect(),
        };
        Timeline {
            frames,
            timestamps_s: None,
            panels: vec![Panel {
                title: "panel".into(),
                unit: "px".into(),
                curves: vec![curve],
            }],
            keyframes,
            added: Default::default(),
            range: Some((2, frames - 3)),
            missing: Vec::new(),
            view: (0, frames - 1),
        }
    }

    #[test]
    fn added_keyframes_have_their_colour_and_reason() {
        let mut t = timeline(40, vec![5, 10, 20]);
        t.added.insert(10, "repairs keyframes 5–20 <split>".into());
        let svg = t.svg().unwrap();
        assert_eq!(svg.matches(r#"class="kf""#).count(), 2);
        let added = format!(
            r#"<g class="kf added" data-frame="10" fill="{}"><title>frame 10 added by reconstruct: repairs keyframes 5–20 &lt;split&gt;</title>"#,
            hex(ADDED_RGB)
        );
        assert!(svg.contains(&added), "{svg}");
    }

    #[test]
    fn the_png_draws_added_keyframes_in_their_colour() {
        let mut t = timeline(40, vec![5, 10, 20]);
        t.added.insert(10, "repairs keyframes 5–20".into());
        let img = t.image().unwrap();
        let layout = t.layout();
        let colour_at = |k: usize| {
            let (y0, y1) = panel_spans(1).next().unwrap();
            let x = layout.x(k) as u32;
            // Every row of the panel's bar has one colour.
            let colours: std::collections::BTreeSet<[u8; 3]> =
                (y0..y1).map(|y| img.get_pixel(x, y).0).collect();
            assert_eq!(colours.len(), 1, "frame {k}: {colours:?}");
            colours.into_iter().next().unwrap()
        };
        assert_eq!(colour_at(10), ADDED_RGB);
        assert_eq!(colour_at(5), KEYFRAME_RGB);
        assert_eq!(colour_at(20), KEYFRAME_RGB);
        assert_eq!(
            t.bars(),
            [
                (layout.x(5), KEYFRAME_RGB),
                (layout.x(10), ADDED_RGB),
                (layout.x(20), KEYFRAME_RGB)
            ]
        );
    }

    #[test]
    fn a_view_of_twenty_frames_spreads_them_over_the_plot() {
        let full = timeline(1000, vec![5, 500, 510, 990]);
        let layout = full.layout();
        assert!((0..1000).all(|f| layout.x(f) == frame_x(f, 1000)));
        assert_eq!(layout.frame_at(f64::from(frame_x(990, 1000))), 990);
        let t = full.view(500, 519);
        let l = t.layout();
        let right = (LEFT + l.span) as i32;
        assert_eq!(
            (l.x(500), l.x(519), l.x(499) < LEFT as i32),
            (LEFT as i32, right, true)
        );
        assert!(l.x(501) - l.x(500) >= 55, "{l:?}");
        assert!((500..=519).all(|f| l.frame_at(f64::from(l.x(f))) == f));
        assert_eq!((l.frame_at(0.0), l.frame_at(f64::from(WIDTH))), (500, 519));
        assert_eq!(t.bar_columns(), [l.x(500), l.x(510)]);
        assert_eq!(t.ticks(), [500, 505, 510, 515]);
        let runs = t.polylines(0, &t.panels[0].curves[0], 1000.0);
        let xs: Vec<i32> = runs.concat().iter().map(|p| p.0 as i32).collect();
        assert_eq!(xs, (500..=519).map(|f| l.x(f)).collect::<Vec<_>>());
        let svg = t.svg().unwrap();
        assert_eq!(svg.matches("class=\"kf\"").count(), 2);
        assert_eq!(timeline(100, Vec::new()).view(90, 500).view, (90, 99));
    }
}
