//! Drone flight paths for the scene presets: a pose for any time (camera-to-world, OpenCV camera
//! axes), built from an arc-length parametrised path, a smooth speed profile and hover holds. The
//! same function gives the rendered sub-frame poses and the ground truth, so both agree exactly.

use super::math::{Noise, Pose, Rng, V3};

/// Which flight the camera makes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Preset {
    /// Lawnmower legs joined by tight turns, variable speed.
    Survey,
    /// A circle around a point of interest, looking at it, variable speed.
    Orbit,
    /// The survey with three hovers (holds) of several seconds.
    HoverSurvey,
    /// A person's walk down an L-shaped street with a stop and a turn on the spot
    /// ([`crate::walk`]).
    Walk,
}

impl Preset {
    /// Default sequence length in seconds.
    pub fn default_seconds(self) -> f64 {
        match self {
            Preset::Survey => 45.0,
            Preset::Orbit => 50.0,
            Preset::HoverSurvey => 55.0,
            Preset::Walk => 21.5,
        }
    }
    /// The name used on the command line and in scene.json.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Survey => "survey",
            Preset::Orbit => "orbit",
            Preset::HoverSurvey => "hover-survey",
            Preset::Walk => "walk",
        }
    }
}

/// One piece of a planar path.
#[derive(Debug, Clone, Copy)]
enum Piece {
    /// From `start` along heading `angle` (radians from +x) for `len` metres.
    Line {
        start: (f64, f64),
        angle: f64,
        len: f64,
    },
    /// Circle arc around `centre` with `radius`, starting at polar angle `a0`, turning by `sweep`
    /// radians (positive = counter-clockwise).
    Arc {
        centre: (f64, f64),
        radius: f64,
        a0: f64,
        sweep: f64,
    },
}

impl Piece {
    fn len(&self) -> f64 {
        match *self {
            Piece::Line { len, .. } => len,
            Piece::Arc { radius, sweep, .. } => radius * sweep.abs(),
        }
    }
    /// (x, y, heading) at arc length `s` from the piece's start (extrapolates outside).
    fn at(&self, s: f64) -> (f64, f64, f64) {
        match *self {
            Piece::Line { start, angle, .. } => {
                (start.0 + s * angle.cos(), start.1 + s * angle.sin(), angle)
            }
            Piece::Arc {
                centre,
                radius,
                a0,
                sweep,
            } => {
                let a = a0 + sweep.signum() * s / radius;
                let heading = a + sweep.signum() * std::f64::consts::FRAC_PI_2;
                (
                    centre.0 + radius * a.cos(),
                    centre.1 + radius * a.sin(),
                    heading,
                )
            }
        }
    }
    fn is_arc(&self) -> bool {
        matches!(self, Piece::Arc { .. })
    }
}

/// Lawnmower survey geometry parameters (metres).
const LEG: f64 = 80.0;
const LEG_SPACING: f64 = 30.0;
const TURN_RADIUS: f64 = 7.0;
/// The survey starts this far into its first leg, so short sequences reach a turn early.
const SURVEY_START: f64 = 62.0;
/// Number of survey legs (they stack up 30 m apart from y = -75 m).
const SURVEY_LEGS: usize = 6;
const ORBIT_RADIUS: f64 = 50.0;
/// Speed limits of the smooth speed profile (m/s): a ratio of 4.5.
const V_MIN: f64 = 2.0;
const V_MAX: f64 = 9.0;
/// Speed through survey turns (m/s): with TURN_RADIUS a yaw rate of about 57°/s.
const V_TURN: f64 = 7.0;
/// Deceleration before / acceleration after a hover (m/s²) and the creep speed at the stop.
const HOVER_ACCEL: f64 = 1.5;
const HOVER_CREEP: f64 = 0.15;
/// Hover jitter amplitude (metres).
const HOVER_JITTER: f64 = 0.002;
/// Arc-length step of the time table (metres).
const DS: f64 = 0.02;

/// A hold of the drone at one place.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Hover {
    /// Start and end time of the hold (seconds).
    pub t0: f64,
    /// End time (seconds).
    pub t1: f64,
    /// Arc length of the hold along the path (metres).
    pub s: f64,
}

/// A complete flight: path geometry, altitude, attitude and timing.
#[derive(Debug, Clone)]
pub struct Flight {
    preset: Preset,
    pieces: Vec<Piece>,
    /// Arc length where each piece starts.
    starts: Vec<f64>,
    /// (time, arc length) samples, increasing in time; holds appear as two samples with one s.
    table: Vec<(f64, f64)>,
    hovers: Vec<Hover>,
    altitude: f64,
    alt_noise: Noise,
    pitch: f64,
    poi: V3,
    jitter_phase: [f64; 3],
}

impl Flight {
    /// The flight of `preset` lasting `seconds`, laid out from `seed` over terrain `height`.
    pub fn new(
        preset: Preset,
        seconds: f64,
        seed: u64,
        height: &dyn Fn(f64, f64) -> f64,
    ) -> Flight {
        let mut rng = Rng::new(seed, 11);
        let speed_noise = Noise(seed ^ 0x5EED_5EED);
        let (pieces, s_start) = match preset {
            Preset::Orbit => (
                vec![Piece::Arc {
                    centre: (0.0, 0.0),
                    radius: ORBIT_RADIUS,
                    a0: rng.range(0.0, std::f64::consts::TAU),
                    sweep: 40.0 * std::f64::consts::TAU,
                }],
                0.0,
            ),
            _ => (lawnmower(SURVEY_LEGS), SURVEY_START),
        };
        let mut starts = Vec::with_capacity(pieces.len());
        let mut acc = 0.0;
        for p in &pieces {
            starts.push(acc);
            acc += p.len();
        }
        let total = acc;
        let mut flight = Flight {
            preset,
            pieces,
            starts,
            table: Vec::new(),
            hovers: Vec::new(),
            altitude: 0.0,
            alt_noise: Noise(seed ^ 0xA17),
            pitch: 0.0,
            poi: V3(0.0, 0.0, height(0.0, 0.0)),
            jitter_phase: [
                rng.unit() * std::f64::consts::TAU,
                rng.unit() * std::f64::consts::TAU,
                rng.unit() * std::f64::consts::TAU,
            ],
        };
        // Base speed: smooth noise along the path, blended to V_TURN around turns.
        // A slow swell between V_MIN and V_MAX (period 90 m of path) made irregular by noise.
        let phase = rng.range(0.0, std::f64::consts::TAU);
        let base = |f: &Flight, s: f64| {
            let swell = (std::f64::consts::TAU * s / 90.0 + phase).sin();
            let n = (1.3 * swell + 0.8 * speed_noise.fbm(s / 40.0, 0.5, 3)).clamp(-1.0, 1.0);
            let free = 0.5 * (V_MIN + V_MAX) + 0.5 * (V_MAX - V_MIN) * n;
            let w = f.turn_weight(s);
            free + (V_TURN - free) * w
        };
        // Speed with decelerations into, and accelerations out of, holds at `stops`.
        let speed = |stops: &[f64], s: f64| {
            let mut v = base(&flight, s);
            for &h in stops {
                let d: f64 = s - h;
                v = v.min((HOVER_CREEP * HOVER_CREEP + 2.0 * HOVER_ACCEL * d.abs()).sqrt());
            }
            v
        };
        // Hovers: centred at 1/4, 1/2 and 3/4 of the sequence; each hold's place along the path
        // is found by bisection on the timeline that includes the earlier holds.
        let mut hover_s: Vec<f64> = Vec::new();
        let hover_len = (0.1 * seconds).clamp(1.0, 5.0);
        if preset == Preset::HoverSurvey {
            for j in 0..3 {
                let target = (j as f64 + 1.0) / 4.0 * seconds - 0.5 * hover_len;
                let (mut lo, mut hi) = (hover_s.last().copied().unwrap_or(s_start), total);
                for _ in 0..24 {
                    let mid = 0.5 * (lo + hi);
                    let mut stops = hover_s.clone();
                    stops.push(mid);
                    let v = |s: f64| speed(&stops, s);
                    let table = time_table(s_start, total, &v, &stops, hover_len, target + 1.0);
                    let t0 = table.iter().find(|p| p.1 == mid).map_or(f64::MAX, |p| p.0);
                    if t0 < target {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                hover_s.push(lo);
            }
        }
        let v = |s: f64| speed(&hover_s, s);
        let table = time_table(s_start, total, &v, &hover_s, hover_len, f64::MAX);
        let hovers = hover_s
            .iter()
            .filter_map(|&h| {
                let i = table.iter().position(|&(_, s)| s == h)?;
                Some(Hover {
                    t0: table[i].0,
                    t1: table[i + 1].0,
                    s: h,
                })
            })
            .collect();
        flight.table = table;
        flight.hovers = hovers;
        // Altitude: clear the highest terrain near the path by 22 m (orbit: 38 m over the
        // point of interest, looking at it).
        match preset {
            Preset::Orbit => {
                flight.altitude = flight.poi.2 + 38.0;
                flight.pitch = (38.0f64).atan2(ORBIT_RADIUS);
            }
            _ => {
                // Over the whole pattern, so the poses do not depend on the length asked for.
                let end = total;
                let mut top = f64::MIN;
                let mut s = s_start;
                while s <= end {
                    let (x, y, _) = flight.planar(s);
                    for (dx, dy) in [
                        (0.0, 0.0),
                        (20.0, 0.0),
                        (-20.0, 0.0),
                        (0.0, 20.0),
                        (0.0, -20.0),
                    ] {
                        top = top.max(height(x + dx, y + dy));
                    }
                    s += 2.0;
                }
                flight.altitude = top + 22.0;
                flight.pitch = 45f64.to_radians();
            }
        }
        flight
    }

    /// The survey presets' camera looking `pitch_deg` below the horizon instead of 45° (90:
    /// straight down); the orbit's camera keeps looking at its point of interest.
    pub fn with_camera_pitch(mut self, pitch_deg: f64) -> Flight {
        if self.preset != Preset::Orbit {
            self.pitch = pitch_deg.to_radians();
        }
        self
    }

    /// The preset.
    pub fn preset(&self) -> Preset {
        self.preset
    }

    /// Time at which the drone reaches the end of its path (seconds).
    pub fn duration(&self) -> f64 {
        self.table.last().map_or(0.0, |p| p.0)
    }

    /// Hover holds.
    pub fn hovers(&self) -> &[Hover] {
        &self.hovers
    }

    /// 1 on turn arcs, falling smoothly to 0 within 12 m before and after them.
    fn turn_weight(&self, s: f64) -> f64 {
        if self.preset == Preset::Orbit {
            return 0.0;
        }
        let mut best: f64 = 0.0;
        for (p, &st) in self.pieces.iter().zip(&self.starts) {
            if !p.is_arc() {
                continue;
            }
            let d = if s < st {
                st - s
            } else if s > st + p.len() {
                s - st - p.len()
            } else {
                0.0
            };
            let t = (1.0 - d / 12.0).clamp(0.0, 1.0);
            best = best.max(t * t * (3.0 - 2.0 * t));
        }
        best
    }

    fn planar(&self, s: f64) -> (f64, f64, f64) {
        let i = match self.starts.binary_search_by(|st| st.total_cmp(&s)) {
            Ok(i) => i,
            Err(0) => 0,
            Err(i) => i - 1,
        };
        self.pieces[i].at(s - self.starts[i])
    }

    /// Arc length flown at time `t`.
    pub fn arc_length(&self, t: f64) -> f64 {
        s_at(&self.table, t)
    }

    /// Camera pose (camera-to-world) at time `t` seconds.
    pub fn pose(&self, t: f64) -> Pose {
        let s = self.arc_length(t);
        let (x, y, heading) = self.planar(s);
        let mut c = match self.preset {
            Preset::Orbit => V3(x, y, self.altitude),
            _ => V3(
                x,
                y,
                self.altitude + 3.0 * self.alt_noise.at(s / 60.0, 0.25),
            ),
        };
        if let Some(h) = self.hovers.iter().find(|h| t > h.t0 && t < h.t1) {
            let env = ((t - h.t0).min(h.t1 - t)).min(0.5) / 0.5;
            let p = &self.jitter_phase;
            c = c + V3(
                (4.1 * t + p[0]).sin(),
                (5.3 * t + p[1]).sin(),
                (3.7 * t + p[2]).sin(),
            ) * (HOVER_JITTER * env);
        }
        let forward = match self.preset {
            Preset::Orbit => self.poi + V3(0.0, 0.0, 2.0) - c,
            _ => {
                let (sp, cp) = self.pitch.sin_cos();
                if cp < 1e-6 {
                    // Straight down: image up along the heading, image right to its right.
                    let right = V3(heading.sin(), -heading.cos(), 0.0);
                    return Pose::looking_right(c, V3(0.0, 0.0, -1.0), right);
                }
                V3(cp * heading.cos(), cp * heading.sin(), -sp)
            }
        };
        Pose::looking(c, forward)
    }

    /// Planar positions sampled along the part of the path flown in `[0, seconds]`, every `step`
    /// metres (for laying out objects near the flight).
    pub fn ground_track(&self, seconds: f64, step: f64) -> Vec<(f64, f64)> {
        let (s0, s1) = (self.arc_length(0.0), self.arc_length(seconds));
        let mut out = Vec::new();
        let mut s = s0;
        while s <= s1 {
            let (x, y, _) = self.planar(s);
            out.push((x, y));
            s += step;
        }
        out
    }
}

/// Lawnmower: `legs` legs along ±x joined by turns of two quarter arcs and a short line.
fn lawnmower(legs: usize) -> Vec<Piece> {
    let mut v = Vec::new();
    let (mut x, mut y, mut angle) = (-LEG / 2.0, -75.0, 0.0f64);
    for i in 0..legs {
        v.push(Piece::Line {
            start: (x, y),
            angle,
            len: LEG,
        });
        x += LEG * angle.cos();
        // Alternate turning left (ccw) and right so the legs stack up in +y.
        let sweep = if i % 2 == 0 { 1.0 } else { -1.0 } * std::f64::consts::FRAC_PI_2;
        for k in 0..2 {
            let left = sweep.signum();
            let centre = (
                x + TURN_RADIUS * (angle + left * std::f64::consts::FRAC_PI_2).cos(),
                y + TURN_RADIUS * (angle + left * std::f64::consts::FRAC_PI_2).sin(),
            );
            let a0 = angle - left * std::f64::consts::FRAC_PI_2;
            let arc = Piece::Arc {
                centre,
                radius: TURN_RADIUS,
                a0,
                sweep,
            };
            v.push(arc);
            let (nx, ny, na) = arc.at(arc.len());
            (x, y, angle) = (nx, ny, na);
            if k == 0 {
                let len = LEG_SPACING - 2.0 * TURN_RADIUS;
                v.push(Piece::Line {
                    start: (x, y),
                    angle,
                    len,
                });
                x += len * angle.cos();
                y += len * angle.sin();
            }
        }
    }
    v
}

/// (time, s) samples from `s0` to `s1` for speed `v(s)`, with a hold of `hold` seconds at each
/// arc length in `stops` (which the table hits exactly). Stops early once the time passes `t_max`.
fn time_table(
    s0: f64,
    s1: f64,
    v: &dyn Fn(f64) -> f64,
    stops: &[f64],
    hold: f64,
    t_max: f64,
) -> Vec<(f64, f64)> {
    let mut out = vec![(0.0, s0)];
    let (mut t, mut s) = (0.0, s0);
    let mut pending: Vec<f64> = stops.iter().copied().filter(|&h| h > s0).collect();
    pending.sort_by(f64::total_cmp);
    let mut next = pending.iter().copied().peekable();
    while s < s1 && t <= t_max {
        let mut step = DS;
        let stop = next.peek().copied();
        if let Some(h) = stop {
            if s + step >= h {
                step = h - s;
            }
        }
        if step > 0.0 {
            t += step / v(s + 0.5 * step).max(1e-3);
            s = match stop {
                Some(h) if s + step >= h => h,
                _ => s + step,
            };
            out.push((t, s));
        }
        if stop.is_some_and(|h| s >= h) {
            next.next();
            t += hold;
            out.push((t, s));
        }
    }
    out
}

/// Arc length at time `t` by linear interpolation (extrapolated before the start with the initial
/// speed, clamped after the end).
fn s_at(table: &[(f64, f64)], t: f64) -> f64 {
    if table.len() < 2 {
        return table.first().map_or(0.0, |p| p.1);
    }
    if t <= table[0].0 {
        let (a, b) = (table[0], table[1]);
        return a.1 + (t - a.0) * (b.1 - a.1) / (b.0 - a.0);
    }
    let i = table.partition_point(|&(tt, _)| tt <= t);
    if i >= table.len() {
        return table[table.len() - 1].1;
    }
    let (a, b) = (table[i - 1], table[i]);
    if b.0 <= a.0 {
        return b.1;
    }
    a.1 + (t - a.0) * (b.1 - a.1) / (b.0 - a.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lawnmower_is_continuous() {
        let p = lawnmower(6);
        for w in p.windows(2) {
            let (x0, y0, a0) = w[0].at(w[0].len());
            let (x1, y1, a1) = w[1].at(0.0);
            assert!((x0 - x1).abs() < 1e-9 && (y0 - y1).abs() < 1e-9, "{w:?}");
            assert!(
                (a0 - a1).sin().abs() < 1e-9 && (a0 - a1).cos() > 0.0,
                "{w:?}"
            );
        }
    }

    #[test]
    fn survey_speed_varies_by_three_or_more() {
        for seed in [1, 2, 3] {
            let f = Flight::new(Preset::Survey, 45.0, seed, &|_, _| 0.0);
            let v: Vec<f64> = (1..450)
                .map(|i| {
                    let t = i as f64 * 0.1;
                    (f.arc_length(t + 0.05) - f.arc_length(t - 0.05)) / 0.1
                })
                .collect();
            let max = v.iter().copied().fold(0.0, f64::max);
            let min = v.iter().copied().fold(f64::MAX, f64::min);
            assert!(max / min > 3.0, "seed {seed}: speed {min}..{max}");
        }
    }

    #[test]
    fn hovers_hold_still_and_speed_varies() {
        let f = Flight::new(Preset::HoverSurvey, 40.0, 3, &|_, _| 0.0);
        assert_eq!(f.hovers().len(), 3);
        for h in f.hovers() {
            assert!(h.t1 - h.t0 > 3.9, "{h:?}");
            let a = f.arc_length(h.t0 + 0.1);
            let b = f.arc_length(h.t1 - 0.1);
            assert_eq!(a, b);
        }
        let speeds: Vec<f64> = (0..400)
            .map(|i| {
                let t = i as f64 * 0.1;
                (f.arc_length(t + 0.05) - f.arc_length(t - 0.05)) / 0.1
            })
            .filter(|v| *v > 0.5)
            .collect();
        let max = speeds.iter().copied().fold(0.0, f64::max);
        let min = speeds.iter().copied().fold(f64::MAX, f64::min);
        assert!(max / min > 3.0, "speed {min}..{max}");
    }
}
