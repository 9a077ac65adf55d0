//! The joint fit on analytic flow fields of four horizon views: a pure rotation leaves nothing, a
//! forward walk keeps its flow (a per-view fit would take much of it for turns).

use super::SphereField;
use crate::equirect::{analysis_views, View};
use crate::kernels::movement::{cpu, RotationField};
use crate::params::{Derotate, Statistic};

type V3 = [f64; 3];

fn apply(m: &[[f64; 3]; 3], v: V3) -> V3 {
    [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

fn transpose(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| m[j][i]))
}

/// The stacked flow of `views` when every scene direction `d` (sphere frame, first frame) is
/// seen along `motion(d)` in the second frame.
fn stacked_flow(views: &[View], motion: impl Fn(V3) -> V3) -> Vec<f32> {
    let mut flow = Vec::new();
    for v in views {
        let (r, f, c) = (v.rotation(), v.focal(), f64::from(v.size) / 2.0);
        for y in 0..v.size {
            for x in 0..v.size {
                let p = [
                    (f64::from(x) + 0.5 - c) / f,
                    (f64::from(y) + 0.5 - c) / f,
                    1.0,
                ];
                let q = apply(&transpose(&r), motion(apply(&r, p)));
                flow.push((f * (q[0] / q[2] - p[0])) as f32);
                flow.push((f * (q[1] / q[2] - p[1])) as f32);
            }
        }
    }
    flow
}

/// A turn of `yaw` and `pitch` degrees.
fn turn(yaw: f64, pitch: f64) -> impl Fn(V3) -> V3 {
    let (a, b) = (yaw.to_radians(), pitch.to_radians());
    let ry = [
        [a.cos(), 0.0, a.sin()],
        [0.0, 1.0, 0.0],
        [-a.sin(), 0.0, a.cos()],
    ];
    let rx = [
        [1.0, 0.0, 0.0],
        [0.0, b.cos(), -b.sin()],
        [0.0, b.sin(), b.cos()],
    ];
    move |d| apply(&ry, apply(&rx, d))
}

/// A step of `step` forward (+z) in a box room (walls at x −1.5 / 2.5, ceiling y −1.2, floor
/// y 1.5, z −3 / 4; the camera at the origin): the direction of each wall point afterwards.
fn walk(step: f64) -> impl Fn(V3) -> V3 {
    move |d: V3| {
        let (lo, hi) = ([-1.5, -1.2, -3.0], [2.5, 1.5, 4.0]);
        let t = (0..3)
            .filter(|&i| d[i].abs() > 1e-12)
            .map(|i| {
                if d[i] > 0.0 {
                    hi[i] / d[i]
                } else {
                    lo[i] / d[i]
                }
            })
            .fold(f64::INFINITY, f64::min);
        [t * d[0], t * d[1], t * d[2] - step]
    }
}

fn median(v: &[f32]) -> f64 {
    cpu(v, Statistic::Median).unwrap()
}

fn magnitudes(flow: &[f32]) -> Vec<f32> {
    flow.chunks_exact(2)
        .map(|d| (d[0] * d[0] + d[1] * d[1]).sqrt())
        .collect()
}

/// Residual magnitudes when each view fits its own rotation (`--derotate` per view).
fn per_view(views: &[View], flow: &[f32]) -> Vec<f32> {
    let s = views[0].size;
    let derotate = Derotate {
        hfov_deg: views[0].fov_deg,
    };
    let field = RotationField::new(s, s, derotate).unwrap();
    flow.chunks_exact(2 * (s * s) as usize)
        .flat_map(|part| {
            let r = field.fit_cpu(part).unwrap();
            field.residual_magnitudes(part, &r).unwrap()
        })
        .collect()
}

/// (raw, joint residual, per-view residual) medians of `flow`.
fn medians(views: &[View], flow: &[f32]) -> (f64, f64, f64) {
    let sphere = SphereField::new(views).unwrap();
    let joint = sphere.derotated(flow).unwrap();
    (
        median(&magnitudes(flow)),
        median(&joint),
        median(&per_view(views, flow)),
    )
}

#[test]
fn a_pure_turn_leaves_no_movement() {
    let views = analysis_views(4, 90.0, 400);
    for (yaw, pitch) in [(3.0, 0.0), (0.0, 2.0), (-4.0, 1.5)] {
        let flow = stacked_flow(&views, turn(yaw, pitch));
        let (raw, joint, single) = medians(&views, &flow);
        eprintln!(
            "turn yaw {yaw}° pitch {pitch}°: raw median {raw:.4} px, joint residual {joint:.6} px, \
             per-view residual {single:.6} px"
        );
        assert!(raw > 1.0, "the turn moves the views ({raw} px)");
        assert!(
            joint < 0.01 && joint < 0.005 * raw,
            "joint residual {joint} px"
        );
    }
}

#[test]
fn a_forward_step_keeps_its_movement_under_the_joint_fit() {
    let views = analysis_views(4, 90.0, 400);
    let flow = stacked_flow(&views, walk(0.05));
    let (raw, joint, single) = medians(&views, &flow);
    eprintln!(
        "forward step: raw median {raw:.4} px, joint residual {joint:.4} px ({:.0} %), per-view \
         residual {single:.4} px ({:.0} %)",
        100.0 * joint / raw,
        100.0 * single / raw
    );
    assert!(raw > 0.3, "the step moves the views ({raw} px)");
    assert!(joint >= 0.8 * raw, "the joint fit keeps the translation");
    assert!(single < 0.7 * joint, "a per-view fit takes much of it");
}

#[test]
fn a_step_with_a_turn_keeps_the_steps_movement() {
    let views = analysis_views(4, 90.0, 400);
    let step = stacked_flow(&views, walk(0.05));
    let (alone, _, _) = medians(&views, &step);
    let (turning, step) = (turn(5.0, 1.0), walk(0.05));
    let flow = stacked_flow(&views, |d| turning(step(d)));
    let (raw, joint, _) = medians(&views, &flow);
    eprintln!(
        "step + turn: raw median {raw:.4} px, joint residual {joint:.4} px; the step alone \
         {alone:.4} px"
    );
    assert!(raw > 3.0 * alone, "the turn dominates the raw flow");
    assert!(
        (joint - alone).abs() < 0.25 * alone,
        "the residual is the step's"
    );
}

#[test]
fn views_must_share_size_and_field_of_view() {
    let mut views = analysis_views(4, 90.0, 400);
    assert!(SphereField::new(&views).is_ok());
    views[2].size += 1;
    assert!(SphereField::new(&views).is_err());
    assert!(SphereField::new(&[]).is_err());
    assert!(SphereField::new(&analysis_views(9, 60.0, 400)).is_err());
}
