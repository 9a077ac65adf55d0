//! Small dense 3D geometry on nalgebra: quaternion/rotation helpers, a 3x3 SVD whose factors
//! are normalised to a fixed sign convention, and Umeyama's similarity (Sim(3)) alignment with
//! scale, which never returns a reflection. Points and matrices cross this module's boundary as
//! plain arrays (`[f64; 3]`, row-major `[[f64; 3]; 3]`), the form the COLMAP readers, the
//! report and the tests hold them in.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

/// A 3x3 matrix, row major: `m[row][col]`.
pub type Mat3 = [[f64; 3]; 3];
/// A 3-vector.
pub type Vec3 = [f64; 3];

/// The identity matrix.
pub const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// The nalgebra matrix of a row-major array.
pub fn to_na(a: &Mat3) -> Matrix3<f64> {
    Matrix3::from_fn(|i, j| a[i][j])
}

/// The row-major array of a nalgebra matrix.
pub fn from_na(m: &Matrix3<f64>) -> Mat3 {
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

/// `a * b`.
pub fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    from_na(&(to_na(a) * to_na(b)))
}

/// `aᵀ`.
pub fn transpose(a: &Mat3) -> Mat3 {
    from_na(&to_na(a).transpose())
}

/// `a * v`.
pub fn mul_vec(a: &Mat3, v: &Vec3) -> Vec3 {
    (to_na(a) * Vector3::from(*v)).into()
}

/// Determinant of `a`.
pub fn det(a: &Mat3) -> f64 {
    to_na(a).determinant()
}

/// Euclidean distance.
pub fn dist(a: &Vec3, b: &Vec3) -> f64 {
    (Vector3::from(*a) - Vector3::from(*b)).norm()
}

/// Rotation matrix of a quaternion `(w, x, y, z)` (normalised first; a zero quaternion is the
/// identity).
pub fn quat_to_mat(q: [f64; 4]) -> Mat3 {
    let q = Quaternion::new(q[0], q[1], q[2], q[3]);
    if q.norm() > 0.0 {
        from_na(
            UnitQuaternion::from_quaternion(q)
                .to_rotation_matrix()
                .matrix(),
        )
    } else {
        IDENTITY
    }
}

/// Angle of a rotation matrix in degrees (0..=180).
pub fn rotation_angle_deg(r: &Mat3) -> f64 {
    let c = ((to_na(r).trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
    c.acos().to_degrees()
}

/// `A = U diag(s) Vᵀ` with `s` sorted descending and non-negative, `U` and `V` orthonormal with
/// `det(V) = +1` (a reflection in `A` shows up in `U`).
#[derive(Debug, Clone, Copy)]
pub struct Svd3 {
    /// Left singular vectors as columns.
    pub u: Mat3,
    /// Singular values, descending.
    pub s: Vec3,
    /// Right singular vectors as columns.
    pub v: Mat3,
}

/// Singular value decomposition of a 3x3 matrix (nalgebra's, sorted descending), with the
/// sign fixed so that `V` is a rotation: when `det(V) < 0` the last columns of `U` and `V` are
/// both negated, which leaves `U diag(s) Vᵀ` unchanged. `None` when `a` holds a non-finite value.
pub fn svd3(a: &Mat3) -> Option<Svd3> {
    let m = to_na(a);
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = m.svd(true, true);
    let (mut u, mut v) = (svd.u?, svd.v_t?.transpose());
    if v.determinant() < 0.0 {
        u.column_mut(2).neg_mut();
        v.column_mut(2).neg_mut();
    }
    Some(Svd3 {
        u: from_na(&u),
        s: svd.singular_values.into(),
        v: from_na(&v),
    })
}

/// A similarity transform `y = scale · R · x + t`.
#[derive(Debug, Clone, Copy)]
pub struct Sim3 {
    /// Scale factor (> 0).
    pub scale: f64,
    /// Rotation (proper: determinant +1).
    pub rotation: Mat3,
    /// Translation.
    pub translation: Vec3,
}

impl Sim3 {
    /// Applies the transform to a point.
    pub fn apply(&self, x: &Vec3) -> Vec3 {
        let y = to_na(&self.rotation) * Vector3::from(*x) * self.scale
            + Vector3::from(self.translation);
        y.into()
    }
}

/// Least-squares similarity taking `src[i]` onto `dst[i]` (Umeyama 1991, with scale): minimises
/// Σ |dst_i − (s R src_i + t)|². Needs at least 3 pairs and a source that is not a single point;
/// collinear points leave the rotation about their line undetermined (any valid one is
/// returned). Returns `None` when the problem is degenerate or a coordinate is not finite.
pub fn umeyama(src: &[Vec3], dst: &[Vec3]) -> Option<Sim3> {
    let n = src.len();
    if n < 3 || dst.len() != n {
        return None;
    }
    let nf = n as f64;
    let mean = |p: &[Vec3]| p.iter().map(|x| Vector3::from(*x)).sum::<Vector3<f64>>() / nf;
    let (mx, my) = (mean(src), mean(dst));
    let mut cov = Matrix3::zeros();
    let mut var_x = 0.0;
    for (x, y) in src.iter().zip(dst) {
        let dx = Vector3::from(*x) - mx;
        let dy = Vector3::from(*y) - my;
        var_x += dx.norm_squared();
        cov += dy * dx.transpose();
    }
    var_x /= nf;
    if var_x <= 0.0 || !var_x.is_finite() {
        return None;
    }
    let svd = svd3(&from_na(&(cov / nf)))?;
    if svd.s[0] <= 0.0 {
        return None;
    }
    let (u, v) = (to_na(&svd.u), to_na(&svd.v));
    // Never a reflection: flip the weakest direction when U Vᵀ would be one.
    let d = if u.determinant() * v.determinant() < 0.0 {
        -1.0
    } else {
        1.0
    };
    let sign = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d));
    let rotation = u * sign * v.transpose();
    let scale = (svd.s[0] + svd.s[1] + d * svd.s[2]) / var_x;
    let translation = my - rotation * mx * scale;
    Some(Sim3 {
        scale,
        rotation: from_na(&rotation),
        translation: translation.into(),
    })
}

/// Quantile `p` of ascending `sorted` values by linear interpolation between order statistics:
/// position h = (n − 1)·p, value x[⌊h⌋] + (h − ⌊h⌋)(x[⌊h⌋+1] − x[⌊h⌋]) (Hyndman & Fan type 7,
/// numpy's default).
pub fn quantile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let h = (sorted.len() - 1) as f64 * p.clamp(0.0, 1.0);
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator (64-bit LCG, top bits) for test values in [-1, 1).
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        }
        fn rotation(&mut self) -> Mat3 {
            quat_to_mat([self.next(), self.next(), self.next(), self.next()])
        }
    }

    fn max_diff(a: &Mat3, b: &Mat3) -> f64 {
        (0..9)
            .map(|k| (a[k / 3][k % 3] - b[k / 3][k % 3]).abs())
            .fold(0.0, f64::max)
    }

    fn check_svd(a: &Mat3) {
        let d = svd3(a).unwrap();
        let s = [[d.s[0], 0.0, 0.0], [0.0, d.s[1], 0.0], [0.0, 0.0, d.s[2]]];
        let back = mul(&mul(&d.u, &s), &transpose(&d.v));
        let scale = a.iter().flatten().fold(1.0f64, |m, v| m.max(v.abs()));
        assert!(max_diff(&back, a) < 1e-12 * scale, "{a:?} -> {d:?}");
        assert!(max_diff(&mul(&transpose(&d.u), &d.u), &IDENTITY) < 1e-12);
        assert!(max_diff(&mul(&transpose(&d.v), &d.v), &IDENTITY) < 1e-12);
        assert!(d.s[0] >= d.s[1] && d.s[1] >= d.s[2] && d.s[2] >= 0.0);
        assert!((det(&d.v) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn svd_random_and_rank_deficient() {
        let mut g = Lcg(7);
        for _ in 0..500 {
            let a = [0, 1, 2].map(|_| [g.next(), g.next(), g.next()].map(|v| v * 10.0));
            check_svd(&a);
        }
        // Rank 2, rank 1, zero, repeated singular values, a reflection.
        let r = g.rotation();
        let r2 = g.rotation();
        for s in [
            [3.0, 2.0, 0.0],
            [5.0, 0.0, 0.0],
            [0.0; 3],
            [2.0, 2.0, 2.0],
            [4.0, 1.0, 1.0],
        ] {
            let d = [[s[0], 0.0, 0.0], [0.0, s[1], 0.0], [0.0, 0.0, s[2]]];
            let a = mul(&mul(&r, &d), &r2);
            check_svd(&a);
            let mut sorted = svd3(&a).unwrap().s;
            sorted.iter_mut().zip(s).for_each(|(x, e)| *x -= e);
            assert!(sorted.iter().all(|x| x.abs() < 1e-12), "{s:?}");
        }
        let reflect = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]];
        check_svd(&mul(&r, &reflect));
    }

    #[test]
    fn umeyama_recovers_random_similarities() {
        let mut g = Lcg(42);
        for trial in 0..200 {
            let r = g.rotation();
            let scale = 0.01 + 100.0 * (g.next() + 1.0);
            let t = [g.next(), g.next(), g.next()].map(|v| v * 50.0);
            let n = 3 + trial % 20;
            let src: Vec<Vec3> = (0..n).map(|_| [g.next(), g.next(), g.next()]).collect();
            let truth = Sim3 {
                scale,
                rotation: r,
                translation: t,
            };
            let dst: Vec<Vec3> = src.iter().map(|p| truth.apply(p)).collect();
            let est = umeyama(&src, &dst).expect("well-posed");
            assert!((est.scale - scale).abs() < 1e-9 * scale, "{trial}");
            assert!(max_diff(&est.rotation, &r) < 1e-9, "{trial}");
            assert!((0..3).all(|i| (est.translation[i] - t[i]).abs() < 1e-9 * (1.0 + scale)));
        }
    }

    #[test]
    fn umeyama_never_reflects_and_handles_planar_sets() {
        let mut g = Lcg(3);
        // Target is a mirror image: the best proper rotation, never det -1.
        let src: Vec<Vec3> = (0..10).map(|_| [g.next(), g.next(), g.next()]).collect();
        let dst: Vec<Vec3> = src.iter().map(|p| [p[0], p[1], -p[2]]).collect();
        let est = umeyama(&src, &dst).expect("solvable");
        assert!((det(&est.rotation) - 1.0).abs() < 1e-12);
        // Planar source (z = 0) under a known similarity: recovered exactly.
        let r = g.rotation();
        let truth = Sim3 {
            scale: 2.5,
            rotation: r,
            translation: [1.0, -2.0, 3.0],
        };
        let src: Vec<Vec3> = (0..8).map(|_| [g.next(), g.next(), 0.0]).collect();
        let dst: Vec<Vec3> = src.iter().map(|p| truth.apply(p)).collect();
        let est = umeyama(&src, &dst).expect("planar is well-posed");
        assert!(max_diff(&est.rotation, &r) < 1e-9);
        assert!((est.scale - 2.5).abs() < 1e-9);
        // Collinear: positions still map exactly.
        let src: Vec<Vec3> = (0..5).map(|i| [f64::from(i), 0.0, 0.0]).collect();
        let dst: Vec<Vec3> = src.iter().map(|p| truth.apply(p)).collect();
        let est = umeyama(&src, &dst).expect("collinear positions align");
        for (s, d) in src.iter().zip(&dst) {
            assert!(dist(&est.apply(s), d) < 1e-9);
        }
        assert!(umeyama(&src[..2], &dst[..2]).is_none());
    }
}
