//! A model checked against the project's telemetry, which COLMAP never saw: the camera centres
//! against the telemetry's positions after a similarity alignment, and each consecutive pair's
//! turn (the angle of its relative rotation) against the turn of the gimbal's yaw and pitch.
//! Guarantees: pure functions; positions are local east/north/up metres; an answer is given only
//! where the telemetry has what it needs (a keyframe without a position has no residual, a pair
//! without both gimbal angles has no turn), and no alignment is made from fewer than
//! [`MIN_ALIGNED`] keyframes or from positions that do not span a plane's worth of directions.
//!
//! Why: a video survey over near-planar ground gives COLMAP two-view geometries with a twofold
//! ambiguity; a sparse keyframe set can settle on the wrong branch and yield one model, every
//! link explained by its matches, that bends the trajectory (docs/reconstruct.md, seed 3).
//! Only a measurement from outside the images tells.

use crate::colmap::align::{self, Mat3, Vec3};

/// Fewest keyframes with a position and a pose for a similarity alignment.
pub const MIN_ALIGNED: usize = 4;

/// One keyframe's telemetry.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Prior {
    /// East, north, up metres from the first position (None: none known).
    pub position: Option<Vec3>,
    /// Gimbal yaw and pitch, degrees (None: either missing).
    pub yaw_pitch: Option<(f64, f64)>,
}

/// The local east/north/up positions and gimbal angles of telemetry positions, relative to the
/// first position that has one.
pub fn of_positions(positions: &[Option<&crate::source::telemetry::Position>]) -> Vec<Prior> {
    let origin = positions.iter().flatten().next().copied();
    positions
        .iter()
        .map(|p| {
            let Some(p) = p else {
                return Prior::default();
            };
            let position = origin.and_then(|o| {
                let (e, n) = crate::source::telemetry::east_north_m(
                    (o.lat_deg, o.lon_deg),
                    (p.lat_deg, p.lon_deg),
                );
                let up = match (p.rel_alt_m, o.rel_alt_m, p.abs_alt_m, o.abs_alt_m) {
                    (Some(a), Some(b), _, _) => a - b,
                    (_, _, Some(a), Some(b)) => a - b,
                    _ => return None,
                };
                Some([e, n, up])
            });
            Prior {
                position,
                yaw_pitch: p.gimbal_yaw_deg.zip(p.gimbal_pitch_deg),
            }
        })
        .collect()
}

/// The camera's orientation in the world of a gimbal yaw (about the vertical) and pitch (about
/// the camera's horizontal axis), in a frame fixed up to a constant rotation: the angle of the
/// relative rotation of two such orientations does not depend on that constant, nor on the
/// signs chosen for yaw and pitch.
fn gimbal(yaw_deg: f64, pitch_deg: f64) -> Mat3 {
    let (sy, cy) = yaw_deg.to_radians().sin_cos();
    let (sp, cp) = pitch_deg.to_radians().sin_cos();
    let yaw = [[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]];
    let pitch = [[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]];
    align::mul(&yaw, &pitch)
}

/// The telemetry's turn between two keyframes: the angle of the gimbal's relative rotation,
/// degrees.
pub fn telemetry_turn_deg(a: (f64, f64), b: (f64, f64)) -> f64 {
    let (ga, gb) = (gimbal(a.0, a.1), gimbal(b.0, b.1));
    align::rotation_angle_deg(&align::mul(&align::transpose(&ga), &gb))
}

/// The model's turn between two world-to-camera rotations, degrees.
pub fn model_turn_deg(a: &Mat3, b: &Mat3) -> f64 {
    align::rotation_angle_deg(&align::mul(b, &align::transpose(a)))
}

/// Per keyframe, how far its camera centre lies from its telemetry position after the
/// similarity alignment of all keyframes that have both (least squares), in metres; `None`
/// where either is missing or no alignment could be made. `centres` and `priors` are by keyframe
/// position.
pub fn off_track_m(centres: &[Option<Vec3>], priors: &[Prior]) -> Vec<Option<f64>> {
    let both: Vec<(usize, Vec3, Vec3)> = centres
        .iter()
        .zip(priors)
        .enumerate()
        .filter_map(|(i, (c, p))| Some((i, (*c)?, p.position?)))
        .collect();
    let mut out = vec![None; centres.len()];
    if both.len() < MIN_ALIGNED {
        return out;
    }
    let src: Vec<Vec3> = both.iter().map(|b| b.1).collect();
    let dst: Vec<Vec3> = both.iter().map(|b| b.2).collect();
    // Positions along one line leave the alignment's rotation about it free: refuse them.
    if !spans_a_plane(&dst) {
        return out;
    }
    let Some(sim) = align::umeyama(&src, &dst) else {
        return out;
    };
    for (i, c, p) in both {
        out[i] = Some(align::dist(&sim.apply(&c), &p));
    }
    out
}

/// Whether points spread in two directions: the second singular value of their centred
/// coordinates is at least 5 % of the first.
fn spans_a_plane(points: &[Vec3]) -> bool {
    let n = points.len() as f64;
    let mean: Vec3 = std::array::from_fn(|k| points.iter().map(|p| p[k]).sum::<f64>() / n);
    let mut cov = [[0.0; 3]; 3];
    for p in points {
        for r in 0..3 {
            for c in 0..3 {
                cov[r][c] += (p[r] - mean[r]) * (p[c] - mean[c]);
            }
        }
    }
    align::svd3(&cov).is_some_and(|s| s.s[0] > 0.0 && (s.s[1] / s.s[0]).sqrt() >= 0.05)
}

/// The telemetry path's length through `priors`' positions in order, metres.
pub fn path_m(priors: &[Prior]) -> f64 {
    let ps: Vec<Vec3> = priors.iter().filter_map(|p| p.position).collect();
    ps.windows(2).map(|w| align::dist(&w[0], &w[1])).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn prior(p: Vec3) -> Prior {
        Prior {
            position: Some(p),
            yaw_pitch: None,
        }
    }

    /// An L-shaped survey: 6 positions east, then 5 north.
    fn track() -> Vec<Vec3> {
        (0..6)
            .map(|i| [10.0 * i as f64, 0.0, 30.0])
            .chain((1..6).map(|i| [50.0, 10.0 * i as f64, 30.0]))
            .collect()
    }

    #[test]
    fn a_similar_model_lies_on_its_track_and_a_moved_keyframe_does_not() {
        let t = track();
        let priors: Vec<Prior> = t.iter().map(|p| prior(*p)).collect();
        // The model: the track scaled by 0.1, turned 90° about z and shifted.
        let model: Vec<Option<Vec3>> = t
            .iter()
            .map(|p| Some([-0.1 * p[1] + 3.0, 0.1 * p[0] - 1.0, 0.1 * p[2] + 7.0]))
            .collect();
        let off = off_track_m(&model, &priors);
        assert!(off.iter().all(|o| o.unwrap() < 1e-6), "{off:?}");
        let mut moved = model.clone();
        moved[8] = moved[8].map(|c| [c[0] + 2.0, c[1], c[2]]);
        let off = off_track_m(&moved, &priors);
        let worst = (0..off.len())
            .max_by(|a, b| off[*a].unwrap().total_cmp(&off[*b].unwrap()))
            .unwrap();
        assert_eq!(worst, 8);
        assert!(off[8].unwrap() > 10.0, "{off:?}");
        assert!((path_m(&priors) - 100.0).abs() < 1e-9);
    }

    #[test]
    fn no_alignment_from_too_few_or_collinear_positions() {
        let line: Vec<Prior> = (0..6).map(|i| prior([i as f64, 0.0, 0.0])).collect();
        let model: Vec<Option<Vec3>> = (0..6).map(|i| Some([0.0, i as f64, 0.0])).collect();
        assert!(off_track_m(&model, &line).iter().all(Option::is_none));
        let t = track();
        let few: Vec<Prior> = t.iter().take(3).map(|p| prior(*p)).collect();
        let m: Vec<Option<Vec3>> = t.iter().take(3).map(|p| Some(*p)).collect();
        assert!(off_track_m(&m, &few).iter().all(Option::is_none));
        // A keyframe the model did not register has no residual; the others still do.
        let priors: Vec<Prior> = t.iter().map(|p| prior(*p)).collect();
        let mut m: Vec<Option<Vec3>> = t.iter().map(|p| Some(*p)).collect();
        m[2] = None;
        let off = off_track_m(&m, &priors);
        assert_eq!(off[2], None);
        assert!(off.iter().enumerate().all(|(i, o)| i == 2 || o.is_some()));
    }

    #[test]
    fn turns_compare_whatever_the_axes_convention() {
        // Yaw alone, pitch alone, and both: the relative angle.
        assert!((telemetry_turn_deg((90.0, -45.0), (90.0, -45.0))).abs() < 1e-9);
        assert!((telemetry_turn_deg((90.0, -45.0), (120.0, -45.0)) - 30.0).abs() < 1e-6);
        assert!((telemetry_turn_deg((0.0, -90.0), (30.0, -90.0)) - 30.0).abs() < 1e-6);
        assert!((telemetry_turn_deg((10.0, -30.0), (10.0, -50.0)) - 20.0).abs() < 1e-6);
        // A model whose world-to-camera rotations differ by a 30° turn.
        let a = gimbal(0.0, -60.0);
        let b = gimbal(30.0, -60.0);
        let (wa, wb) = (align::transpose(&a), align::transpose(&b));
        let turn = model_turn_deg(&wa, &wb);
        assert!((turn - telemetry_turn_deg((0.0, -60.0), (30.0, -60.0))).abs() < 1e-9);
    }
}
