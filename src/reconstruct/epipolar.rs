//! Whether a model's relative pose of two images explains their verified two-view matches: the
//! matches COLMAP's geometric verification kept for the pair (from `database.db`) are tested
//! against the epipolar geometry of the two poses the model gave the images. Guarantees: pure
//! functions; a match is *explained* when its Sampson distance under the model's essential
//! matrix `[t]ₓR` is within [`MAX_PX`] pixels (the distance is invariant to the baseline's
//! length, so a pair the model places with little or no baseline is judged by its rotation
//! alone); pixels are made rays by the camera's model with its distortion undone, and a camera
//! model it cannot undo gives no answer (`None`), never a guess.
//!
//! Why: a model folded by false matches (a scene that repeats its texture) is self-consistent
//! — its reprojection errors are small — yet consecutive video frames that COLMAP matched
//! correctly sit in it at poses their own matches contradict.

use crate::colmap::align::{self, Mat3, Vec3};
use crate::colmap::model::{Camera, Image};

/// A match is explained when its Sampson distance is within this many pixels (COLMAP's own
/// default for two-view verification, `max_error = 4`).
pub const MAX_PX: f64 = 4.0;

/// A pixel position `(x, y)` in COLMAP's convention (the centre of the top-left pixel at 0.5).
pub type Px = [f64; 2];

/// How well a model's relative pose explains a pair's matches.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Agreement {
    /// Matches within [`MAX_PX`].
    pub explained: usize,
    /// Matches tested.
    pub total: usize,
}

impl Agreement {
    /// The explained fraction (1 when there is nothing to test).
    pub fn fraction(&self) -> f64 {
        if self.total == 0 {
            1.0
        } else {
            self.explained as f64 / self.total as f64
        }
    }
}

/// The ray `(x, y, 1)` of pixel `p` in camera `c`, its distortion undone; the focal length in
/// pixels comes with it. `None` for a camera model this module does not know or too few
/// parameters.
pub fn ray(c: &Camera, p: Px) -> Option<([f64; 2], f64)> {
    let k = &c.params;
    let need = |n: usize| (k.len() >= n).then_some(());
    // (fx, fy, cx, cy, k1, k2, p1, p2)
    let (fx, fy, cx, cy, d): (f64, f64, f64, f64, [f64; 4]) = match c.model.as_str() {
        "SIMPLE_PINHOLE" => {
            need(3)?;
            (k[0], k[0], k[1], k[2], [0.0; 4])
        }
        "PINHOLE" => {
            need(4)?;
            (k[0], k[1], k[2], k[3], [0.0; 4])
        }
        "SIMPLE_RADIAL" => {
            need(4)?;
            (k[0], k[0], k[1], k[2], [k[3], 0.0, 0.0, 0.0])
        }
        "RADIAL" => {
            need(5)?;
            (k[0], k[0], k[1], k[2], [k[3], k[4], 0.0, 0.0])
        }
        "OPENCV" => {
            need(8)?;
            (k[0], k[1], k[2], k[3], [k[4], k[5], k[6], k[7]])
        }
        _ => return None,
    };
    if !(fx > 0.0 && fy > 0.0) {
        return None;
    }
    let (xd, yd) = ((p[0] - cx) / fx, (p[1] - cy) / fy);
    // Undo the distortion by fixed-point iteration: x = xd - delta(x).
    let (mut x, mut y) = (xd, yd);
    if d != [0.0; 4] {
        for _ in 0..50 {
            let r2 = x * x + y * y;
            let radial = d[0] * r2 + d[1] * r2 * r2;
            let dx = x * radial + 2.0 * d[2] * x * y + d[3] * (r2 + 2.0 * x * x);
            let dy = y * radial + d[2] * (r2 + 2.0 * y * y) + 2.0 * d[3] * x * y;
            let (nx, ny) = (xd - dx, yd - dy);
            let done = (nx - x).abs() + (ny - y).abs() < 1e-12;
            (x, y) = (nx, ny);
            if done {
                break;
            }
        }
    }
    (x.is_finite() && y.is_finite()).then_some(([x, y], (fx * fy).sqrt()))
}

/// The essential matrix `[t]ₓR` of image `b` relative to image `a` (world-to-camera poses):
/// `x_bᵀ E x_a = 0` for rays `x_a`, `x_b` of one point.
pub fn essential(a: &Image, b: &Image) -> Mat3 {
    let ra = align::quat_to_mat(a.qvec);
    let rb = align::quat_to_mat(b.qvec);
    let r = align::mul(&rb, &align::transpose(&ra));
    let rt = align::mul_vec(&r, &a.tvec);
    let t: Vec3 = [b.tvec[0] - rt[0], b.tvec[1] - rt[1], b.tvec[2] - rt[2]];
    let tx: Mat3 = [[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]];
    align::mul(&tx, &r)
}

/// The Sampson distance of rays `xa`, `xb` (as `(x, y)` with z = 1) under `e`, in the rays'
/// units; infinite when `e` is zero on both (no information: the images' poses coincide).
pub fn sampson(e: &Mat3, xa: [f64; 2], xb: [f64; 2]) -> f64 {
    let a = [xa[0], xa[1], 1.0];
    let b = [xb[0], xb[1], 1.0];
    let ea = align::mul_vec(e, &a);
    let etb = align::mul_vec(&align::transpose(e), &b);
    let num = b[0] * ea[0] + b[1] * ea[1] + b[2] * ea[2];
    let den = ea[0] * ea[0] + ea[1] * ea[1] + etb[0] * etb[0] + etb[1] * etb[1];
    if den <= 0.0 {
        return f64::INFINITY;
    }
    num.abs() / den.sqrt()
}

/// How many of the matches (pixels in image `a`, in image `b`) the model's poses of `a` and `b`
/// explain; `None` when a camera model is unknown to [`ray`] or the poses coincide.
pub fn agreement(
    a: (&Image, &Camera),
    b: (&Image, &Camera),
    matches: &[(Px, Px)],
) -> Option<Agreement> {
    let e = essential(a.0, b.0);
    let norm: f64 = e.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
    if !(norm > 0.0 && norm.is_finite()) {
        return None;
    }
    let e = e.map(|row| row.map(|v| v / norm));
    let mut explained = 0;
    for (pa, pb) in matches {
        let (xa, fa) = ray(a.1, *pa)?;
        let (xb, fb) = ray(b.1, *pb)?;
        if sampson(&e, xa, xb) * 0.5 * (fa + fb) <= MAX_PX {
            explained += 1;
        }
    }
    Some(Agreement {
        explained,
        total: matches.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(model: &str, params: Vec<f64>) -> Camera {
        Camera {
            id: 1,
            model: model.into(),
            width: 320,
            height: 180,
            params,
        }
    }

    /// A world-to-camera pose from a rotation about y by `deg` and a camera centre `c`.
    fn image(id: u32, deg: f64, c: Vec3) -> Image {
        let h = deg.to_radians() / 2.0;
        let qvec = [h.cos(), 0.0, h.sin(), 0.0];
        let r = align::quat_to_mat(qvec);
        let rc = align::mul_vec(&r, &c);
        Image {
            id,
            qvec,
            tvec: [-rc[0], -rc[1], -rc[2]],
            camera_id: 1,
            name: format!("{id}.jpg"),
            points2d: Vec::new(),
        }
    }

    fn project(img: &Image, cam: &Camera, x: Vec3) -> Px {
        let r = align::quat_to_mat(img.qvec);
        let p = align::mul_vec(&r, &x);
        let p = [p[0] + img.tvec[0], p[1] + img.tvec[1], p[2] + img.tvec[2]];
        let k = &cam.params;
        [k[0] * p[0] / p[2] + k[2], k[1] * p[1] / p[2] + k[3]]
    }

    fn points() -> Vec<Vec3> {
        (0..60)
            .map(|i| {
                let f = i as f64;
                [
                    (f * 0.37).sin() * 3.0,
                    (f * 0.53).cos() * 2.0,
                    8.0 + (f * 0.11).sin() * 2.0,
                ]
            })
            .collect()
    }

    #[test]
    fn true_poses_explain_their_matches_and_a_rotated_pose_does_not() {
        let cam = camera("PINHOLE", vec![224.0, 224.0, 160.0, 90.0]);
        let a = image(1, 0.0, [0.0, 0.0, 0.0]);
        let b = image(2, 10.0, [1.0, 0.2, 0.0]);
        let m: Vec<(Px, Px)> = points()
            .iter()
            .map(|x| (project(&a, &cam, *x), project(&b, &cam, *x)))
            .collect();
        let good = agreement((&a, &cam), (&b, &cam), &m).unwrap();
        assert_eq!(good.explained, 60);
        assert_eq!(good.fraction(), 1.0);
        // The same matches against a model that turned image b by 40° more.
        let folded = image(2, 50.0, [1.0, 0.2, 0.0]);
        let bad = agreement((&a, &cam), (&folded, &cam), &m).unwrap();
        assert!(bad.fraction() < 0.2, "{bad:?}");
    }

    #[test]
    fn a_pure_rotation_is_judged_by_its_rotation() {
        let cam = camera("PINHOLE", vec![224.0, 224.0, 160.0, 90.0]);
        let a = image(1, 0.0, [0.0, 0.0, 0.0]);
        let b = image(2, 12.0, [0.0, 0.0, 0.0]);
        let m: Vec<(Px, Px)> = points()
            .iter()
            .map(|x| (project(&a, &cam, *x), project(&b, &cam, *x)))
            .collect();
        // The model's poses coincide in position: a tiny baseline, in any direction.
        let model_b = image(2, 12.0, [1e-6, -2e-6, 1e-6]);
        let ok = agreement((&a, &cam), (&model_b, &cam), &m).unwrap();
        assert_eq!(ok.explained, 60, "{ok:?}");
        let wrong = image(2, 40.0, [1e-6, -2e-6, 1e-6]);
        let bad = agreement((&a, &cam), (&wrong, &cam), &m).unwrap();
        assert!(bad.fraction() < 0.2, "{bad:?}");
        // Identical poses carry no epipolar geometry: no answer.
        assert_eq!(agreement((&a, &cam), (&a, &cam), &m), None);
    }

    #[test]
    fn rays_undo_radial_distortion_and_refuse_unknown_models() {
        let c = camera("SIMPLE_RADIAL", vec![200.0, 160.0, 90.0, 0.1]);
        // Distort the ray (0.3, -0.2) forward, then undo it.
        let (x, y) = (0.3f64, -0.2f64);
        let r2 = x * x + y * y;
        let p = [
            200.0 * x * (1.0 + 0.1 * r2) + 160.0,
            200.0 * y * (1.0 + 0.1 * r2) + 90.0,
        ];
        let (got, f) = ray(&c, p).unwrap();
        assert!(
            (got[0] - x).abs() < 1e-9 && (got[1] - y).abs() < 1e-9,
            "{got:?}"
        );
        assert_eq!(f, 200.0);
        assert_eq!(ray(&camera("FISHEYE_XYZ", vec![1.0; 8]), p), None);
        assert_eq!(ray(&camera("PINHOLE", vec![1.0, 1.0]), p), None);
    }
}
