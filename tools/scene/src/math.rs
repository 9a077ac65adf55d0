//! Small f64 vector / rotation helpers and a seeded RNG with value noise for the scene generator;
//! everything here is pure and deterministic (same seed, same numbers on every platform).

/// A 3-vector of f64.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct V3(pub f64, pub f64, pub f64);

impl V3 {
    /// Dot product.
    pub fn dot(self, o: V3) -> f64 {
        self.0 * o.0 + self.1 * o.1 + self.2 * o.2
    }
    /// Cross product.
    pub fn cross(self, o: V3) -> V3 {
        V3(
            self.1 * o.2 - self.2 * o.1,
            self.2 * o.0 - self.0 * o.2,
            self.0 * o.1 - self.1 * o.0,
        )
    }
    /// Euclidean length.
    pub fn norm(self) -> f64 {
        self.dot(self).sqrt()
    }
    /// Unit vector in the same direction (the zero vector stays zero).
    pub fn unit(self) -> V3 {
        let n = self.norm();
        if n > 0.0 {
            self * (1.0 / n)
        } else {
            self
        }
    }
}

impl std::ops::Add for V3 {
    type Output = V3;
    fn add(self, o: V3) -> V3 {
        V3(self.0 + o.0, self.1 + o.1, self.2 + o.2)
    }
}
impl std::ops::Sub for V3 {
    type Output = V3;
    fn sub(self, o: V3) -> V3 {
        V3(self.0 - o.0, self.1 - o.1, self.2 - o.2)
    }
}
impl std::ops::Mul<f64> for V3 {
    type Output = V3;
    fn mul(self, k: f64) -> V3 {
        V3(self.0 * k, self.1 * k, self.2 * k)
    }
}

/// A rigid camera pose: `rot` has the camera's x (right), y (down), z (viewing direction) axes
/// expressed in world coordinates as its columns (camera-to-world), `centre` is the camera centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Columns: camera x, y, z axes in world coordinates.
    pub rot: [V3; 3],
    /// Camera centre in world coordinates (metres).
    pub centre: V3,
}

impl Pose {
    /// A camera at `centre` looking along `forward` with its x axis (image right) along the
    /// horizontal `right` (for a camera looking straight down, where `looking` has no up).
    pub fn looking_right(centre: V3, forward: V3, right: V3) -> Pose {
        let z = forward.unit();
        let x = right.unit();
        Pose {
            rot: [x, z.cross(x), z],
            centre,
        }
    }

    /// The pose of a camera at `centre` looking along `forward` with the world's +z up (no roll).
    pub fn looking(centre: V3, forward: V3) -> Pose {
        let z = forward.unit();
        let x = z.cross(V3(0.0, 0.0, 1.0)).unit();
        let y = z.cross(x);
        Pose {
            rot: [x, y, z],
            centre,
        }
    }

    /// World point in camera coordinates (x right, y down, z forward).
    pub fn to_camera(&self, p: V3) -> V3 {
        let d = p - self.centre;
        V3(self.rot[0].dot(d), self.rot[1].dot(d), self.rot[2].dot(d))
    }

    /// Unit quaternion (x, y, z, w) of the camera-to-world rotation, w ≥ 0.
    pub fn quaternion(&self) -> [f64; 4] {
        // m[r][c]: row r of the matrix whose columns are the camera axes.
        let c = &self.rot;
        let m = [
            [c[0].0, c[1].0, c[2].0],
            [c[0].1, c[1].1, c[2].1],
            [c[0].2, c[1].2, c[2].2],
        ];
        let tr = m[0][0] + m[1][1] + m[2][2];
        let q = if tr > 0.0 {
            let s = (tr + 1.0).sqrt() * 2.0;
            [
                (m[2][1] - m[1][2]) / s,
                (m[0][2] - m[2][0]) / s,
                (m[1][0] - m[0][1]) / s,
                0.25 * s,
            ]
        } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
            let s = (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt() * 2.0;
            [
                0.25 * s,
                (m[0][1] + m[1][0]) / s,
                (m[0][2] + m[2][0]) / s,
                (m[2][1] - m[1][2]) / s,
            ]
        } else if m[1][1] > m[2][2] {
            let s = (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt() * 2.0;
            [
                (m[0][1] + m[1][0]) / s,
                0.25 * s,
                (m[1][2] + m[2][1]) / s,
                (m[0][2] - m[2][0]) / s,
            ]
        } else {
            let s = (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt() * 2.0;
            [
                (m[0][2] + m[2][0]) / s,
                (m[1][2] + m[2][1]) / s,
                0.25 * s,
                (m[1][0] - m[0][1]) / s,
            ]
        };
        let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
        let sign = if q[3] < 0.0 { -1.0 } else { 1.0 };
        [
            sign * q[0] / n,
            sign * q[1] / n,
            sign * q[2] / n,
            sign * q[3] / n,
        ]
    }
}

/// SplitMix64: a tiny seeded generator, enough for scene layout.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator for `seed` and a `stream` number (independent sequences per purpose).
    pub fn new(seed: u64, stream: u64) -> Rng {
        let mut r = Rng(seed ^ stream.wrapping_mul(0xD134_2543_DE82_EF95));
        r.next_u64();
        r
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix(self.0)
    }
    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [a, b).
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.unit()
    }
}

fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Smooth 2-D value noise in [-1, 1] from a seed: random values on the integer lattice,
/// interpolated with a quintic fade (continuous first and second derivatives).
#[derive(Debug, Clone, Copy)]
pub struct Noise(pub u64);

impl Noise {
    fn lattice(&self, x: i64, y: i64) -> f64 {
        let h = mix(self.0
            ^ (x as u64).wrapping_mul(0x8CB9_2BA7_2F3D_8DD7)
            ^ (y as u64).wrapping_mul(0xA24B_AED4_963E_E407));
        (h >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }

    /// Value noise at (x, y).
    pub fn at(&self, x: f64, y: f64) -> f64 {
        let (fx, fy) = (x.floor(), y.floor());
        let (ix, iy) = (fx as i64, fy as i64);
        let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
        let (u, v) = (fade(x - fx), fade(y - fy));
        let a = self.lattice(ix, iy);
        let b = self.lattice(ix + 1, iy);
        let c = self.lattice(ix, iy + 1);
        let d = self.lattice(ix + 1, iy + 1);
        let top = a + (b - a) * u;
        let bottom = c + (d - c) * u;
        top + (bottom - top) * v
    }

    /// Fractal sum of `octaves` octaves (lacunarity 2, gain 0.5), roughly in [-1, 1].
    pub fn fbm(&self, x: f64, y: f64, octaves: u32) -> f64 {
        let (mut sum, mut amp, mut freq, mut total) = (0.0, 1.0, 1.0, 0.0);
        for o in 0..octaves {
            let n = Noise(self.0.wrapping_add(o as u64 * 0x5851_F42D_4C95_7F2D));
            // Rotate each octave a little so lattice axes do not line up.
            let (s, c) = (0.5 * o as f64).sin_cos();
            sum += amp * n.at(freq * (c * x - s * y), freq * (s * x + c * y));
            total += amp;
            amp *= 0.5;
            freq *= 2.0;
        }
        sum / total
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternion_of_known_rotation() {
        // Camera looking along world +x with z up: x_cam = -y_world, y_cam = -z_world.
        let p = Pose::looking(V3(0.0, 0.0, 0.0), V3(1.0, 0.0, 0.0));
        assert!((p.rot[0] - V3(0.0, -1.0, 0.0)).norm() < 1e-12);
        assert!((p.rot[1] - V3(0.0, 0.0, -1.0)).norm() < 1e-12);
        let q = p.quaternion();
        // Rebuild the matrix from the quaternion and compare the columns.
        let [x, y, z, w] = q;
        let col0 = V3(
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y + z * w),
            2.0 * (x * z - y * w),
        );
        let col2 = V3(
            2.0 * (x * z + y * w),
            2.0 * (y * z - x * w),
            1.0 - 2.0 * (x * x + y * y),
        );
        assert!((col0 - p.rot[0]).norm() < 1e-12);
        assert!((col2 - p.rot[2]).norm() < 1e-12);
    }

    #[test]
    fn noise_is_deterministic_and_bounded() {
        let n = Noise(42);
        let a: Vec<f64> = (0..100).map(|i| n.fbm(i as f64 * 0.37, 1.3, 5)).collect();
        let b: Vec<f64> = (0..100).map(|i| n.fbm(i as f64 * 0.37, 1.3, 5)).collect();
        assert_eq!(a, b);
        assert!(a.iter().all(|v| v.abs() <= 1.0));
        assert!(a.iter().any(|v| v.abs() > 0.05));
    }
}
