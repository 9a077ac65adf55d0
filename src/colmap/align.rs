//! Small dense 3D geometry: a 3x3 SVD (one-sided Jacobi) that always returns proper orthonormal
//! factors, quaternion/rotation helpers, and Umeyama's similarity (Sim(3)) alignment with scale,
//! which never returns a reflection.

/// A 3x3 matrix, row major: `m[row][col]`.
pub type Mat3 = [[f64; 3]; 3];
/// A 3-vector.
pub type Vec3 = [f64; 3];

/// The identity matrix.
pub const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// `a * b`.
pub fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut r = [[0.0; 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    r
}

/// Transpose.
pub fn transpose(a: &Mat3) -> Mat3 {
    let mut r = [[0.0; 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[j][i];
        }
    }
    r
}

/// `a * v`.
pub fn mul_vec(a: &Mat3, v: &Vec3) -> Vec3 {
    [0, 1, 2].map(|i| (0..3).map(|k| a[i][k] * v[k]).sum())
}

/// Determinant.
pub fn det(a: &Mat3) -> f64 {
    a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
}

fn cross(a: &Vec3, b: &Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn norm(a: &Vec3) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

/// Euclidean distance.
pub fn dist(a: &Vec3, b: &Vec3) -> f64 {
    norm(&[a[0] - b[0], a[1] - b[1], a[2] - b[2]])
}

/// Rotation matrix of a quaternion `(w, x, y, z)` (normalised first).
pub fn quat_to_mat(q: [f64; 4]) -> Mat3 {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let [w, x, y, z] = if n > 0.0 {
        q.map(|c| c / n)
    } else {
        [1.0, 0.0, 0.0, 0.0]
    };
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// Angle of a rotation matrix in degrees (0..=180).
pub fn rotation_angle_deg(r: &Mat3) -> f64 {
    let c = ((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0).clamp(-1.0, 1.0);
    c.acos().to_degrees()
}

/// `A = U diag(s) Vᵀ` with `s` sorted descending and non-negative, `U` and `V` orthonormal with
/// determinant +1 each except that `det(U)·det(V)` carries the sign of `det(A)` (a reflection in
/// `A` shows up as exactly one of them being -1 when `A` has full rank).
#[derive(Debug, Clone, Copy)]
pub struct Svd3 {
    /// Left singular vectors as columns.
    pub u: Mat3,
    /// Singular values, descending.
    pub s: Vec3,
    /// Right singular vectors as columns.
    pub v: Mat3,
}

/// Singular value decomposition of a 3x3 matrix by one-sided Jacobi rotations (Hestenes): the
/// columns of `A·V` are orthogonalised by plane rotations until every pair is orthogonal to
/// machine precision; their norms are the singular values. Columns of `U` for (numerically) zero
/// singular values are completed to an orthonormal basis.
pub fn svd3(a: &Mat3) -> Svd3 {
    // Work on columns: w[j] is column j of A·V, vcol[j] column j of V.
    let mut w: [Vec3; 3] = [0, 1, 2].map(|j| [a[0][j], a[1][j], a[2][j]]);
    let mut vcol: [Vec3; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _sweep in 0..60 {
        let mut rotated = false;
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            let alpha: f64 = w[p].iter().map(|x| x * x).sum();
            let beta: f64 = w[q].iter().map(|x| x * x).sum();
            let gamma: f64 = w[p].iter().zip(&w[q]).map(|(x, y)| x * y).sum();
            if gamma == 0.0 || gamma.abs() <= 1e-15 * (alpha * beta).sqrt() {
                continue;
            }
            rotated = true;
            let zeta = (beta - alpha) / (2.0 * gamma);
            let t = zeta.signum() / (zeta.abs() + (1.0 + zeta * zeta).sqrt());
            let c = 1.0 / (1.0 + t * t).sqrt();
            let s = c * t;
            for cols in [&mut w, &mut vcol] {
                let (cp, cq) = (cols[p], cols[q]);
                for i in 0..3 {
                    cols[p][i] = c * cp[i] - s * cq[i];
                    cols[q][i] = s * cp[i] + c * cq[i];
                }
            }
        }
        if !rotated {
            break;
        }
    }
    let mut order = [0usize, 1, 2];
    let sv = w.map(|c| norm(&c));
    order.sort_by(|&i, &j| sv[j].total_cmp(&sv[i]));
    let s = order.map(|i| sv[i]);
    let mut v = order.map(|i| vcol[i]);
    let tol = s[0].max(f64::MIN_POSITIVE) * 1e-13;
    let mut u: [Vec3; 3] = order.map(|i| w[i]);
    let rank = s.iter().filter(|&&x| x > tol).count();
    for (k, col) in u.iter_mut().enumerate().take(rank) {
        let n = s[k];
        *col = col.map(|x| x / n);
    }
    match rank {
        0 => u = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        1 => {
            // Any unit vector orthogonal to u0: cross with the axis least aligned with it.
            let u0 = u[0];
            let k = (0..3)
                .min_by(|&i, &j| u0[i].abs().total_cmp(&u0[j].abs()))
                .unwrap_or(0);
            let mut e = [0.0; 3];
            e[k] = 1.0;
            let c = cross(&u0, &e);
            let n = norm(&c);
            u[1] = c.map(|x| x / n);
            u[2] = cross(&u[0], &u[1]);
        }
        2 => u[2] = cross(&u[0], &u[1]),
        _ => {}
    }
    // Make V a rotation; flipping a column of V with a zero singular value changes nothing, and
    // for a full-rank A flipping both v_k and u_k keeps A = U S Vᵀ.
    let to_mat = |c: &[Vec3; 3]| -> Mat3 { [0, 1, 2].map(|i| [c[0][i], c[1][i], c[2][i]]) };
    if det(&to_mat(&v)) < 0.0 {
        v[2] = v[2].map(|x| -x);
        if rank == 3 {
            u[2] = u[2].map(|x| -x);
        }
    }
    Svd3 {
        u: to_mat(&u),
        s,
        v: to_mat(&v),
    }
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
        let r = mul_vec(&self.rotation, x);
        [0, 1, 2].map(|i| self.scale * r[i] + self.translation[i])
    }
}

/// Least-squares similarity taking `src[i]` onto `dst[i]` (Umeyama 1991, with scale): minimises
/// Σ |dst_i − (s R src_i + t)|². Needs at least 3 pairs and a source that is not a single point;
/// collinear points leave the rotation about their line undetermined (any valid one is
/// returned). Returns `None` when the problem is degenerate.
pub fn umeyama(src: &[Vec3], dst: &[Vec3]) -> Option<Sim3> {
    let n = src.len();
    if n < 3 || dst.len() != n {
        return None;
    }
    let nf = n as f64;
    let mean = |p: &[Vec3]| -> Vec3 { [0, 1, 2].map(|i| p.iter().map(|x| x[i]).sum::<f64>() / nf) };
    let (mx, my) = (mean(src), mean(dst));
    let mut cov = [[0.0; 3]; 3];
    let mut var_x = 0.0;
    for (x, y) in src.iter().zip(dst) {
        let dx = [x[0] - mx[0], x[1] - mx[1], x[2] - mx[2]];
        let dy = [y[0] - my[0], y[1] - my[1], y[2] - my[2]];
        var_x += dx.iter().map(|v| v * v).sum::<f64>();
        for i in 0..3 {
            for j in 0..3 {
                cov[i][j] += dy[i] * dx[j];
            }
        }
    }
    var_x /= nf;
    if var_x <= 0.0 || !var_x.is_finite() {
        return None;
    }
    let cov = cov.map(|r| r.map(|v| v / nf));
    let svd = svd3(&cov);
    if svd.s[0] <= 0.0 {
        return None;
    }
    let mut sign = [1.0, 1.0, 1.0];
    if det(&svd.u) * det(&svd.v) < 0.0 {
        sign[2] = -1.0;
    }
    let us = [0, 1, 2].map(|i| [0, 1, 2].map(|j| svd.u[i][j] * sign[j]));
    let rotation = mul(&us, &transpose(&svd.v));
    let scale = (0..3).map(|i| svd.s[i] * sign[i]).sum::<f64>() / var_x;
    let rm = mul_vec(&rotation, &mx);
    let translation = [0, 1, 2].map(|i| my[i] - scale * rm[i]);
    Some(Sim3 {
        scale,
        rotation,
        translation,
    })
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
        let d = svd3(a);
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
            let mut sorted = svd3(&a).s;
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
