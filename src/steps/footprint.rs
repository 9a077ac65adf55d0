//! `footprint-overlap`: a keyframe when the ground footprint of a candidate overlaps the last
//! keyframe's by less than `percent`, the way a photogrammetrist plans a flight's overlap.
//!
//! The footprint of a frame is the quadrilateral where its image corners' rays meet flat ground
//! at the take-off height: the camera stands `rel_alt` metres above it (without `rel_alt`: the
//! altitude above sea level minus the first positioned candidate's, stated), at its position
//! on the WGS84 tangent plane, looking along the gimbal yaw (clockwise from north; without it,
//! along the direction of travel, stated), pitched down by the gimbal pitch (without it: nadir,
//! stated), with no roll. A nadir camera's footprint is a rectangle, a pitched one's a
//! trapezoid; rays that meet the ground further than ten times the height (or not at all) are
//! cut there. The horizontal field of view is `--hfov`, else each frame's 35 mm equivalent focal
//! length f from the telemetry (else from the table of common DJI cameras,
//! `telemetry::CAMERAS`, when the video's container or the images' EXIF name one) taken as the
//! width of a 36 mm frame (hfov = 2 atan(18 / f); a DJI video's crop of its 4:3 sensor is close
//! to this), the vertical one follows from the frame's aspect ratio.
//!
//! Overlap = area(last keyframe's footprint ∩ candidate's footprint) / area(last keyframe's
//! footprint), the intersection of two convex quadrilaterals by Sutherland–Hodgman clipping. The
//! first candidate with a footprint is kept; a candidate whose overlap with the last keyframe
//! falls below `percent` / 100 becomes the next keyframe.
//!
//! A candidate less than [`MIN_HEIGHT_M`] above take-off (on the ground before take-off or after
//! landing, or below the take-off point) has no footprint and is never kept, like one without a
//! position: a warning names those frames, and the step refuses, naming them, when no candidate
//! is left. A camera at or above the horizon (taken as level) and a field of view of
//! [`WIDE_FOV_DEG`] or more (footprints reach the cut) are warned about with their frames.

use super::{Applied, Flag, FlagValues, Inputs, Step};
use crate::error::{Error, Result};
use crate::source::telemetry::{east_north_m, known_camera, Camera, Position};

/// The step's id.
const ID: &str = "footprint-overlap";

/// Rays are cut at this many times the camera's height above the ground.
const MAX_RANGE_PER_HEIGHT: f64 = 10.0;

/// Frames less than this high above take-off (metres) have no footprint.
pub const MIN_HEIGHT_M: f64 = 0.5;

/// A field of view (horizontal or vertical) this wide or wider is warned about, degrees.
pub const WIDE_FOV_DEG: f64 = 170.0;

/// At most this many runs of frames are named in a message.
const RUNS_NAMED: usize = 5;

/// `--footprint-overlap PERCENT` (the field of view is `--hfov`, a movement flag too).
pub const FLAGS: &[Flag] = &[Flag::value::<f64>(
    "footprint-overlap",
    "PERCENT",
    "Keep a frame when its ground footprint overlaps the last keyframe's by less than PERCENT (needs telemetry: height above take-off, field of view from the focal length or --hfov, gimbal pitch)",
)
.sets(ID, "percent")];

/// The step when `--footprint-overlap` is given (`--hfov` is filled in by the command line).
pub fn from_flags(v: &FlagValues) -> Result<Option<Step>> {
    Ok(v.get("footprint-overlap")?
        .map(|percent| Step::FootprintOverlap {
            percent,
            hfov: None,
        }))
}

/// A point on the ground: metres east and north of the reference.
pub(crate) type Pt = (f64, f64);

/// The step on `keys`.
pub fn apply(
    at: &Inputs,
    keys: &mut Vec<usize>,
    percent: f64,
    hfov: Option<f64>,
) -> Result<Applied> {
    let positions = super::positions(at, ID, keys)?;
    let table = at.camera.and_then(known_camera);
    let prints = footprints(keys, positions, hfov, table, at.frame_size)?;
    let mut out = Vec::new();
    let mut last: Option<&Vec<Pt>> = None;
    for (&k, print) in keys.iter().zip(&prints) {
        let Some(print) = print else { continue };
        if last.is_none_or(|l| overlap(l, print) < percent / 100.0) {
            out.push(k);
            last = Some(print);
        }
    }
    *keys = out;
    Ok(Applied::FootprintOverlap { percent, hfov })
}

/// The footprint of every candidate (None: no position, or too low), in metres east and north
/// of the first candidate with a position, saying once what it assumed and which frames have no
/// footprint or a doubtful one; an error when candidates have positions but none a footprint.
pub(crate) fn footprints(
    keys: &[usize],
    positions: &[Option<Position>],
    hfov: Option<f64>,
    camera: Option<&Camera>,
    (width, height): (u32, u32),
) -> Result<Vec<Option<Vec<Pt>>>> {
    let placed: Vec<(usize, &Position)> = keys
        .iter()
        .filter_map(|&k| Some((k, positions.get(k)?.as_ref()?)))
        .collect();
    let Some(&(_, origin)) = placed.first() else {
        return Ok(vec![None; keys.len()]);
    };
    let ground = origin.abs_alt_m;
    if placed.iter().any(|(_, p)| p.rel_alt_m.is_none()) {
        if ground.is_none() {
            return Err(Error::step(
                ID,
                "the telemetry gives no height above take-off (rel_alt) nor altitude",
            ));
        }
        log::warn!("{ID}: no height above take-off in the telemetry: the altitude above the first frame's is used");
    }
    if placed.iter().any(|(_, p)| p.gimbal_pitch_deg.is_none()) {
        log::warn!("{ID}: no gimbal pitch in the telemetry: the camera is taken to look straight down (nadir)");
    }
    if let Some(c) = camera.filter(|_| hfov.is_none()) {
        if placed.iter().any(|(_, p)| p.focal_35mm.is_none()) {
            log::info!(
                "{ID}: frames without a focal length take the {}'s ({} mm equivalent)",
                c.name,
                c.focal_35mm
            );
        }
    }
    if placed.iter().any(|(_, p)| p.gimbal_yaw_deg.is_none()) {
        log::warn!("{ID}: no gimbal yaw in the telemetry: the camera is taken to face the direction of travel");
    }
    let aspect = f64::from(height) / f64::from(width.max(1));
    let local =
        |p: &Position| east_north_m((origin.lat_deg, origin.lon_deg), (p.lat_deg, p.lon_deg));
    let mut by_frame = std::collections::HashMap::new();
    let (mut low, mut skyward, mut wide) = (Vec::new(), Vec::new(), Vec::new());
    for (j, &(k, p)) in placed.iter().enumerate() {
        let tan_h = match (hfov, p.focal_35mm.or(camera.map(|c| c.focal_35mm))) {
            (Some(h), _) => (0.5 * h.to_radians()).tan(),
            (None, Some(f)) => 18.0 / f,
            (None, None) => {
                return Err(Error::step(
                    ID,
                    format!(
                        "frame {k}: no field of view: the telemetry has no focal length and the \
                     camera is not one of the known DJI models; give --hfov"
                    ),
                ))
            }
        };
        let h = match (p.rel_alt_m, p.abs_alt_m, ground) {
            (Some(r), _, _) => Some(r),
            (None, Some(a), Some(g)) => Some(a - g),
            _ => None,
        };
        let Some(h) = h.filter(|h| *h >= MIN_HEIGHT_M) else {
            low.push(k);
            continue;
        };
        let yaw = match p.gimbal_yaw_deg {
            Some(y) => y,
            None => course_deg(&placed, j, &local),
        };
        let depression = -p.gimbal_pitch_deg.unwrap_or(-90.0);
        if depression <= 0.0 {
            skyward.push(k);
        }
        if 2.0 * tan_h.max(tan_h * aspect).atan().to_degrees() >= WIDE_FOV_DEG {
            wide.push(k);
        }
        let print = footprint(local(p), h, yaw, depression, tan_h, tan_h * aspect);
        by_frame.insert(k, print);
    }
    if !low.is_empty() {
        let what = format!(
            "{}: on the ground or below the take-off height (less than {MIN_HEIGHT_M} m above \
             it, or no height): no ground footprint",
            frame_runs(keys, &low)
        );
        if by_frame.is_empty() {
            return Err(Error::step(
                ID,
                format!(
                    "no candidate has a ground footprint: {what} (a flight below its take-off \
                     point can use --geo-distance)"
                ),
            ));
        }
        log::warn!("{ID}: {what}");
    }
    if !skyward.is_empty() {
        log::warn!(
            "{ID}: {}: the camera looks at or above the horizon (gimbal pitch 0° or more): taken \
             as level, footprints cut at {MAX_RANGE_PER_HEIGHT} times the height",
            frame_runs(keys, &skyward)
        );
    }
    if !wide.is_empty() {
        log::warn!(
            "{ID}: {}: a field of view of {WIDE_FOV_DEG}° or more: footprints reach out to the \
             cut at {MAX_RANGE_PER_HEIGHT} times the height (check --hfov or the focal length)",
            frame_runs(keys, &wide)
        );
    }
    Ok(keys.iter().map(|k| by_frame.remove(k)).collect())
}

/// `frames 0–9, 40 (11 of 120 candidates)`: the runs of consecutive candidates that `of` (some
/// of `keys`) holds, the first [`RUNS_NAMED`] named.
fn frame_runs(keys: &[usize], of: &[usize]) -> String {
    let of: std::collections::HashSet<usize> = of.iter().copied().collect();
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut open = false;
    for &k in keys {
        let inside = of.contains(&k);
        match runs.last_mut() {
            Some(run) if inside && open => run.1 = k,
            _ if inside => runs.push((k, k)),
            _ => {}
        }
        open = inside;
    }
    let named: Vec<String> = (runs.iter().take(RUNS_NAMED))
        .map(|&(a, b)| {
            if a == b {
                a.to_string()
            } else {
                format!("{a}–{b}")
            }
        })
        .collect();
    let more = match runs.len().saturating_sub(RUNS_NAMED) {
        0 => String::new(),
        n => format!(" and {n} more runs"),
    };
    format!(
        "frames {}{more} ({} of {} candidates)",
        named.join(", "),
        of.len(),
        keys.len()
    )
}

/// The direction of travel at `placed[j]` (degrees clockwise from north), from the neighbouring
/// positions.
fn course_deg(placed: &[(usize, &Position)], j: usize, local: &dyn Fn(&Position) -> Pt) -> f64 {
    let a = local(placed[j.saturating_sub(1)].1);
    let b = local(placed[(j + 1).min(placed.len() - 1)].1);
    (b.0 - a.0).atan2(b.1 - a.1).to_degrees()
}

/// The ground footprint of a camera at `centre` (east, north), `h` metres above the ground,
/// facing `yaw_deg` (clockwise from north) and looking `depression_deg` below the horizon,
/// with half-angle tangents `tan_h`, `tan_v`: its image corners in order (top-left, top-right,
/// bottom-right, bottom-left).
pub fn footprint(
    centre: Pt,
    h: f64,
    yaw_deg: f64,
    depression_deg: f64,
    tan_h: f64,
    tan_v: f64,
) -> Vec<Pt> {
    let (sy, cy) = yaw_deg.to_radians().sin_cos();
    let (sp, cp) = depression_deg.clamp(0.0, 90.0).to_radians().sin_cos();
    // East, north, up: forward, right and image-down (forward × right).
    let f = [cp * sy, cp * cy, -sp];
    let r = [cy, -sy, 0.0];
    let d = [-f[2] * r[1], f[2] * r[0], f[0] * r[1] - f[1] * r[0]];
    let max_range = MAX_RANGE_PER_HEIGHT * h;
    [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
        .iter()
        .map(|&(u, v)| {
            let ray: Vec<f64> = (0..3)
                .map(|i| f[i] + u * tan_h * r[i] + v * tan_v * d[i])
                .collect();
            let horizontal = ray[0].hypot(ray[1]);
            let range = if ray[2] < 0.0 {
                (h / -ray[2] * horizontal).min(max_range)
            } else {
                max_range
            };
            let k = if horizontal > 0.0 {
                range / horizontal
            } else {
                0.0
            };
            (centre.0 + k * ray[0], centre.1 + k * ray[1])
        })
        .collect()
}

/// Area of a simple polygon (shoelace), always positive.
pub fn area(poly: &[Pt]) -> f64 {
    signed_area(poly).abs()
}

fn signed_area(poly: &[Pt]) -> f64 {
    let n = poly.len();
    0.5 * (0..n)
        .map(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % n]);
            a.0 * b.1 - b.0 * a.1
        })
        .sum::<f64>()
}

/// The part of convex polygon `subject` inside convex polygon `clipper` (Sutherland–Hodgman).
pub fn clip(subject: &[Pt], clipper: &[Pt]) -> Vec<Pt> {
    let mut edges = clipper.to_vec();
    if signed_area(&edges) < 0.0 {
        edges.reverse();
    }
    let inside = |a: Pt, b: Pt, p: Pt| (b.0 - a.0) * (p.1 - a.1) - (b.1 - a.1) * (p.0 - a.0) >= 0.0;
    let cross_at = |a: Pt, b: Pt, p: Pt, q: Pt| {
        let (r, s) = ((b.0 - a.0, b.1 - a.1), (q.0 - p.0, q.1 - p.1));
        let denom = r.0 * s.1 - r.1 * s.0;
        let t = ((a.1 - p.1) * r.0 - (a.0 - p.0) * r.1) / denom;
        (p.0 + t * s.0, p.1 + t * s.1)
    };
    let mut out = subject.to_vec();
    for i in 0..edges.len() {
        let (a, b) = (edges[i], edges[(i + 1) % edges.len()]);
        let input = std::mem::take(&mut out);
        for j in 0..input.len() {
            let (p, q) = (input[j], input[(j + 1) % input.len()]);
            match (inside(a, b, p), inside(a, b, q)) {
                (true, true) => out.push(q),
                (true, false) => out.push(cross_at(a, b, p, q)),
                (false, true) => {
                    out.push(cross_at(a, b, p, q));
                    out.push(q);
                }
                (false, false) => {}
            }
        }
        if out.is_empty() {
            break;
        }
    }
    out
}

/// area(a ∩ b) / area(a), 0 for an empty `a`.
pub fn overlap(a: &[Pt], b: &[Pt]) -> f64 {
    let whole = area(a);
    if whole <= 0.0 {
        return 0.0;
    }
    area(&clip(a, b)) / whole
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nadir_footprint_is_the_rectangle_under_the_camera() {
        // 100 m up, facing east, 90° by 2·atan(0.5) fields of view: 200 m across the track
        // (north-south), 100 m along it.
        let p = footprint((10.0, 20.0), 100.0, 90.0, 90.0, 1.0, 0.5);
        let want = [(60.0, 120.0), (60.0, -80.0), (-40.0, -80.0), (-40.0, 120.0)];
        for (got, want) in p.iter().zip(want) {
            assert!(
                (got.0 - want.0).abs() < 1e-9 && (got.1 - want.1).abs() < 1e-9,
                "{p:?}"
            );
        }
        assert!((area(&p) - 20_000.0).abs() < 1e-6);
        // Moved 25 m along the track: 75 % of it still covered.
        let q = footprint((35.0, 20.0), 100.0, 90.0, 90.0, 1.0, 0.5);
        assert!((overlap(&p, &q) - 0.75).abs() < 1e-12);
        // Turned by 90° on the spot: the square 100 x 100 in the middle is shared.
        let t = footprint((10.0, 20.0), 100.0, 0.0, 90.0, 1.0, 0.5);
        assert!((overlap(&p, &t) - 0.5).abs() < 1e-12);
        assert_eq!(
            overlap(&p, &footprint((1e4, 0.0), 100.0, 0.0, 90.0, 1.0, 0.5)),
            0.0
        );
    }

    #[test]
    fn frame_runs_name_runs_of_consecutive_candidates() {
        let keys = [0, 2, 4, 6, 8, 10, 12, 14];
        assert_eq!(
            frame_runs(&keys, &[0, 2, 4, 8, 12, 14]),
            "frames 0–4, 8, 12–14 (6 of 8 candidates)"
        );
        let all: Vec<usize> = (0..20).collect();
        let odd: Vec<usize> = (1..20).step_by(2).collect();
        assert_eq!(
            frame_runs(&all, &odd),
            "frames 1, 3, 5, 7, 9 and 5 more runs (10 of 20 candidates)"
        );
    }

    #[test]
    fn pitched_footprint_is_a_trapezoid_ahead() {
        // 45° down, facing north, 2·atan(0.5) fields of view, 10 m up: the lower corners lie
        // as far ahead as the lower edge's centre ray meets the ground.
        let p = footprint((0.0, 0.0), 10.0, 0.0, 45.0, 0.5, 0.5);
        let (near, far) = (p[3].1, p[0].1);
        // Centre ray of the lower edge: 45° + atan(0.5) down.
        let want_near = 10.0 / (45f64.to_radians() + 0.5f64.atan()).tan();
        assert!((near - want_near).abs() < 1e-9, "{p:?}");
        assert!(far > near && (p[0].0 + p[1].0).abs() < 1e-9);
        // Wider at the far edge than at the near one.
        assert!(p[1].0 - p[0].0 > p[2].0 - p[3].0);
    }
}
