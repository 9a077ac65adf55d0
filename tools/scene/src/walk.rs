//! A person's walk down an L-shaped street, for 360° sequences: the camera 1.6 m above the
//! ground, level (no pitch, no roll), heading along the street; it walks east, stops, walks on to
//! the corner, turns on the spot to the north (pure yaw, no translation) and walks north. The
//! street is lined with blocks whose walls show unique parts of the terrain's photo patchwork.
//! Pure functions of the terrain; the same pose function gives the renders and the ground truth.

use crate::math::{Pose, V3};
use crate::path::Hover;
use crate::world::{Kind, Object, Terrain};

/// The middle of the street: the ground is level within 30 m of it (`Terrain::levelled`).
pub const STREET_CENTRE: (f64, f64) = (0.0, 6.0);
/// Camera height above the ground (metres).
pub const EYE_HEIGHT: f64 = 1.6;
/// Walking speed (m/s) between the ramps.
const SPEED: f64 = 1.4;
/// Time to speed up from rest, or to slow down to rest (seconds).
const RAMP: f64 = 0.8;
/// The corner, where the camera turns on the spot.
const CORNER: (f64, f64) = (4.0, 0.0);
/// Start of the walk, west of the corner.
const START_X: f64 = -8.0;
/// Length of the northern leg (metres).
const NORTH_LEG: f64 = 8.0;
/// The mid-leg stop and the pauses around the turn (seconds).
const STOP: f64 = 1.2;
const PAUSE: f64 = 0.4;
/// The turn on the spot: 90° to the left, in this many seconds.
const TURN: f64 = 3.0;

/// One part of the walk.
#[derive(Debug, Clone, Copy)]
enum Part {
    /// Walk from `a` to `b` (planar), starting and ending at rest.
    Walk { a: (f64, f64), b: (f64, f64) },
    /// Stand at `at` facing `heading` (radians from +x).
    Stand { at: (f64, f64), heading: f64 },
    /// Turn on the spot at `at` from heading `h0` to `h1`.
    Turn { at: (f64, f64), h0: f64, h1: f64 },
}

/// The walk: its parts with their start times.
#[derive(Debug, Clone)]
pub struct Walk {
    parts: Vec<(f64, f64, Part)>,
    ground: Terrain,
}

/// Walking time of a leg of `len` metres with ramps of [`RAMP`] seconds at both ends.
fn walk_time(len: f64) -> f64 {
    len / SPEED + RAMP
}

/// Distance walked after `t` seconds of a leg lasting `total` (trapezoid speed profile).
fn walked(t: f64, total: f64) -> f64 {
    let t = t.clamp(0.0, total);
    let accel = SPEED / RAMP;
    let s_ramp = 0.5 * accel * RAMP * RAMP;
    if t < RAMP {
        0.5 * accel * t * t
    } else if t > total - RAMP {
        let r = total - t;
        let len = SPEED * (total - RAMP);
        len - 0.5 * accel * r * r
    } else {
        s_ramp + SPEED * (t - RAMP)
    }
}

impl Walk {
    /// The walk over `terrain`'s ground.
    pub fn new(terrain: &Terrain) -> Walk {
        let mid = (0.5 * (START_X + CORNER.0), CORNER.1);
        let north = std::f64::consts::FRAC_PI_2;
        let end = (CORNER.0, CORNER.1 + NORTH_LEG);
        let plan = [
            Part::Walk {
                a: (START_X, CORNER.1),
                b: mid,
            },
            Part::Stand {
                at: mid,
                heading: 0.0,
            },
            Part::Walk { a: mid, b: CORNER },
            Part::Stand {
                at: CORNER,
                heading: 0.0,
            },
            Part::Turn {
                at: CORNER,
                h0: 0.0,
                h1: north,
            },
            Part::Stand {
                at: CORNER,
                heading: north,
            },
            Part::Walk { a: CORNER, b: end },
        ];
        let mut parts = Vec::new();
        let mut t = 0.0;
        for p in plan {
            let d = match p {
                Part::Walk { a, b } => walk_time((b.0 - a.0).hypot(b.1 - a.1)),
                Part::Stand { at, .. } if at == CORNER => PAUSE,
                Part::Stand { .. } => STOP,
                Part::Turn { .. } => TURN,
            };
            parts.push((t, t + d, p));
            t += d;
        }
        Walk {
            parts,
            ground: terrain.clone(),
        }
    }

    /// Time at which the walk ends (seconds).
    pub fn duration(&self) -> f64 {
        self.parts.last().map_or(0.0, |p| p.1)
    }

    /// The times the camera does not move (stops, and the turn's pauses and the turn itself:
    /// the centre stays put while it turns).
    pub fn holds(&self) -> Vec<Hover> {
        let mut out: Vec<Hover> = Vec::new();
        for &(t0, t1, p) in &self.parts {
            if matches!(p, Part::Walk { .. }) {
                continue;
            }
            match out.last_mut() {
                Some(h) if (h.t1 - t0).abs() < 1e-12 => h.t1 = t1,
                _ => out.push(Hover { t0, t1, s: 0.0 }),
            }
        }
        out
    }

    /// Start and end time of the turn on the spot.
    pub fn turn(&self) -> (f64, f64) {
        self.parts
            .iter()
            .find(|p| matches!(p.2, Part::Turn { .. }))
            .map_or((0.0, 0.0), |p| (p.0, p.1))
    }

    /// Planar position and heading at time `t` (clamped to the walk).
    fn planar(&self, t: f64) -> (f64, f64, f64) {
        let i = self
            .parts
            .iter()
            .position(|p| t < p.1)
            .unwrap_or(self.parts.len() - 1);
        let (t0, t1, p) = self.parts[i];
        match p {
            Part::Walk { a, b } => {
                let len = (b.0 - a.0).hypot(b.1 - a.1);
                let f = walked(t - t0, t1 - t0) / len;
                (
                    a.0 + f * (b.0 - a.0),
                    a.1 + f * (b.1 - a.1),
                    (b.1 - a.1).atan2(b.0 - a.0),
                )
            }
            Part::Stand { at, heading } => (at.0, at.1, heading),
            Part::Turn { at, h0, h1 } => {
                // Smooth in and out: the yaw rate peaks at 1.5 times its mean.
                let u = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
                let e = u * u * (3.0 - 2.0 * u);
                (at.0, at.1, h0 + e * (h1 - h0))
            }
        }
    }

    /// Camera pose (camera-to-world, OpenCV axes) at time `t`: level, looking along the heading.
    pub fn pose(&self, t: f64) -> Pose {
        let (x, y, h) = self.planar(t);
        let c = V3(x, y, self.ground.height(x, y) + EYE_HEIGHT);
        Pose::looking(c, V3(h.cos(), h.sin(), 0.0))
    }

    /// Planar positions along the walk every `step` metres or so (for the markers).
    pub fn ground_track(&self, step: f64) -> Vec<(f64, f64)> {
        let dt = step / SPEED;
        let n = (self.duration() / dt).ceil() as usize;
        (0..=n)
            .map(|i| {
                let (x, y, _) = self.planar(i as f64 * dt);
                (x, y)
            })
            .collect()
    }
}

/// The street's blocks: rows along both legs of the L (walls 5 m from the path), one across the
/// far end of each leg, sunk to the lowest ground under them; heights from `seed`. Each block
/// gets its own part of the terrain texture (`quadrant` numbers them).
pub fn street(seed: u64, terrain: &Terrain) -> Vec<Object> {
    let mut rng = crate::math::Rng::new(seed, 29);
    // (centre x, centre y, size x, size y)
    let blocks = [
        // South of the eastern leg, three blocks with 1 m gaps.
        (-11.0, -9.0, 9.0, 8.0),
        (-1.0, -9.0, 9.0, 8.0),
        (9.0, -9.0, 9.0, 8.0),
        // North of the eastern leg, west of the northern one.
        (-12.0, 9.0, 8.0, 8.0),
        (-4.0, 9.0, 6.0, 8.0),
        (-4.0, 17.0, 6.0, 6.0),
        // East of the northern leg.
        (13.0, 1.0, 8.0, 9.0),
        (13.0, 11.0, 8.0, 9.0),
        // Across the ends: north of the northern leg, west of the start.
        (4.0, 24.0, 12.0, 6.0),
        (-24.0, 0.0, 6.0, 12.0),
    ];
    blocks
        .iter()
        .enumerate()
        .map(|(k, &(x, y, sx, sy))| {
            let height = rng.range(7.0, 13.0);
            let mut low = f64::MAX;
            for (dx, dy) in [
                (-0.5, -0.5),
                (0.5, -0.5),
                (0.5, 0.5),
                (-0.5, 0.5),
                (0.0, 0.0),
            ] {
                low = low.min(terrain.height(x + dx * sx, y + dy * sy));
            }
            let shade = rng.range(0.85, 1.1);
            Object {
                kind: Kind::Wall,
                size: [sx, sy, height],
                quadrant: k as u32,
                tint: [shade, shade, shade * rng.range(0.92, 1.05)],
                centre: [x, y, low - 0.3 + 0.5 * height],
                yaw: 0.0,
                path: None,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_turn_is_pure_yaw_and_the_walk_is_continuous() {
        let w = Walk::new(&Terrain::new(1));
        let (t0, t1) = w.turn();
        assert!((t1 - t0 - TURN).abs() < 1e-9);
        let a = w.pose(t0 - PAUSE);
        for i in 0..=30 {
            let p = w.pose(t0 + (t1 - t0) * i as f64 / 30.0);
            assert_eq!(p.centre, a.centre);
            assert!(p.rot[2].2.abs() < 1e-12, "level");
        }
        let end = w.pose(t1);
        assert!(
            (end.rot[2].1 - 1.0).abs() < 1e-12,
            "faces north after the turn"
        );
        // Continuous: no jump larger than a walking step between poses 10 ms apart.
        let mut t = 0.0;
        while t < w.duration() {
            let (p, q) = (w.pose(t), w.pose(t + 0.01));
            assert!((q.centre - p.centre).norm() < 0.02, "t {t}");
            assert!((q.rot[2] - p.rot[2]).norm() < 0.01, "t {t}");
            t += 0.01;
        }
    }

    #[test]
    fn holds_cover_the_stop_and_the_turn() {
        let w = Walk::new(&Terrain::new(1));
        let holds = w.holds();
        assert_eq!(holds.len(), 2, "{holds:?}");
        let (t0, t1) = w.turn();
        assert!(holds[1].t0 < t0 && holds[1].t1 > t1);
        for h in &holds {
            assert_eq!(w.pose(h.t0 + 0.01).centre, w.pose(h.t1 - 0.01).centre);
        }
    }
}
