//! The equirectangular (ERP) camera of the scene: six 90° cube faces rendered with the pinhole
//! pipeline (each with a small margin) and resampled bilinearly into a W x W/2 frame on the
//! host, with keyframer's conventions (`keyframer::equirect`, docs/360.md): column ↔ longitude,
//! row ↔ latitude, longitude 0 is the camera's +z (forward), + to the right, latitude + up. The
//! ERP camera's frame is the pose's (x right, y down, z forward), so poses.tum means the same for
//! both projections. The table is computed once; every ERP pixel reads only one face.

use crate::math::{Pose, V3};
use crate::render::Intrinsics;
use keyframer::equirect::{self, Mat3, View, ViewSet};

/// Extra pixels rendered on each side of a face, so that bilinear samples at a face's edge read
/// rendered pixels.
pub const MARGIN: u32 = 2;

/// The cube faces of one ERP size and the ERP pixel → face pixel table.
pub struct ErpCamera {
    /// ERP width (height is half of it).
    pub width: u32,
    /// Side of a rendered face, margins included.
    pub face_size: u32,
    /// The faces' rotations (face frame → ERP camera frame), keyframer's cube order.
    rotations: Vec<Mat3>,
    /// For each ERP pixel, row after row: face, and its top-left tap (x, y) with the weights' fractions.
    table: Vec<(u8, u32, u32, f32, f32)>,
}

impl ErpCamera {
    /// The camera for a `width` x `width / 2` frame: faces of about `width / π` pixels (the ERP's
    /// resolution at the equator), plus the margins.
    pub fn new(width: u32) -> ErpCamera {
        let inner = (f64::from(width) / std::f64::consts::PI).ceil() as u32;
        let face_size = inner + 2 * MARGIN;
        let views = ViewSet::Cube.views(90.0, inner);
        let rotations: Vec<Mat3> = views.iter().map(View::rotation).collect();
        let f = f64::from(inner) / 2.0;
        let c = f64::from(face_size) / 2.0;
        let height = width / 2;
        let mut table = Vec::with_capacity((width * height) as usize);
        for y in 0..height {
            for x in 0..width {
                let (lon, lat) = equirect::lon_lat(f64::from(x), f64::from(y), (width, height));
                let d = equirect::direction(lon, lat);
                // The face whose axis is nearest the direction: largest component along its z.
                let (k, local) = rotations
                    .iter()
                    .enumerate()
                    .map(|(k, r)| (k, equirect::apply(&equirect::transpose(r), d)))
                    .max_by(|a, b| a.1[2].total_cmp(&b.1[2]))
                    .unwrap_or((0, d));
                // Pixel-centre coordinates (0-based) of the continuous projection.
                let u = f * local[0] / local[2] + c - 0.5;
                let v = f * local[1] / local[2] + c - 0.5;
                let max = f64::from(face_size - 2);
                let (u0, v0) = (u.floor().clamp(0.0, max), v.floor().clamp(0.0, max));
                table.push((
                    k as u8,
                    u0 as u32,
                    v0 as u32,
                    (u - u0).clamp(0.0, 1.0) as f32,
                    (v - v0).clamp(0.0, 1.0) as f32,
                ));
            }
        }
        ErpCamera {
            width,
            face_size,
            rotations,
            table,
        }
    }

    /// Number of faces (six).
    pub fn faces(&self) -> usize {
        self.rotations.len()
    }

    /// The faces' pinhole intrinsics (90° across the face without its margins).
    pub fn intrinsics(&self) -> Intrinsics {
        let f = f64::from(self.face_size - 2 * MARGIN) / 2.0;
        let c = f64::from(self.face_size) / 2.0;
        Intrinsics {
            fx: f,
            fy: f,
            cx: c,
            cy: c,
        }
    }

    /// The pose of face `k` of an ERP camera at `pose` (camera-to-world, OpenCV axes).
    pub fn face_pose(&self, pose: &Pose, k: usize) -> Pose {
        let m = &self.rotations[k];
        let col = |j: usize| pose.rot[0] * m[0][j] + pose.rot[1] * m[1][j] + pose.rot[2] * m[2][j];
        Pose {
            rot: [col(0), col(1), col(2)],
            centre: pose.centre,
        }
    }

    /// The ERP frame (RGBA8, rows top first) from the six rendered faces (RGBA8, `face_size`²
    /// each, in face order).
    pub fn resample(&self, faces: &[Vec<u8>]) -> Vec<u8> {
        let fs = self.face_size as usize;
        let mut out = Vec::with_capacity(self.table.len() * 4);
        for &(k, x, y, fx, fy) in &self.table {
            let img = &faces[k as usize];
            let at = |xx: usize, yy: usize, c: usize| f32::from(img[(yy * fs + xx) * 4 + c]);
            let (x, y) = (x as usize, y as usize);
            for c in 0..4 {
                let top = at(x, y, c) * (1.0 - fx) + at(x + 1, y, c) * fx;
                let bottom = at(x, y + 1, c) * (1.0 - fx) + at(x + 1, y + 1, c) * fx;
                out.push((top * (1.0 - fy) + bottom * fy).round().clamp(0.0, 255.0) as u8);
            }
        }
        out
    }

    /// Directions (camera frame) of a coarse grid of ERP pixels, for the shutter-motion estimate.
    pub fn sample_directions(&self) -> Vec<V3> {
        let (w, h) = (self.width, self.width / 2);
        let mut out = Vec::new();
        for gy in 0..5 {
            for gx in 0..8 {
                let x = (f64::from(gx) + 0.5) / 8.0 * f64::from(w);
                let y = (f64::from(gy) + 0.5) / 5.0 * f64::from(h);
                let (lon, lat) = equirect::lon_lat(x, y, (w, h));
                let d = equirect::direction(lon, lat);
                out.push(V3(d[0], d[1], d[2]));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every ERP pixel's ray, sent through its face's pose and projected with the face's
    /// intrinsics, lands on the face pixel the table samples (within the bilinear cell).
    #[test]
    fn the_table_samples_where_each_ray_meets_its_face() {
        let cam = ErpCamera::new(256);
        let k = cam.intrinsics();
        let pose = Pose::looking(V3(1.0, 2.0, 3.0), V3(0.3, 1.0, -0.2));
        let (w, h) = (256, 128);
        for y in (0..h).step_by(7) {
            for x in (0..w).step_by(5) {
                let (lon, lat) = equirect::lon_lat(f64::from(x), f64::from(y), (w, h));
                let d = equirect::direction(lon, lat);
                let world = pose.centre
                    + (pose.rot[0] * d[0] + pose.rot[1] * d[1] + pose.rot[2] * d[2]) * 10.0;
                let (face, u0, v0, fu, fv) = cam.table[(y * w + x) as usize];
                let fp = cam.face_pose(&pose, face as usize);
                let q = fp.to_camera(world);
                assert!(q.2 > 0.0, "pixel ({x}, {y}) behind face {face}");
                let (u, v) = k.project(q);
                let (tu, tv) = (
                    f64::from(u0) + f64::from(fu) + 0.5,
                    f64::from(v0) + f64::from(fv) + 0.5,
                );
                assert!(
                    (u - tu).abs() < 1e-4 && (v - tv).abs() < 1e-4,
                    "pixel ({x}, {y}): face {face} ({u}, {v}) vs table ({tu}, {tv})"
                );
            }
        }
    }

    /// The faces cover the sphere with their margins to spare: no tap is clamped.
    #[test]
    fn no_tap_leaves_its_face() {
        let cam = ErpCamera::new(512);
        for &(_, u, v, _, _) in &cam.table {
            assert!(u >= 1 && v >= 1 && u + 2 < cam.face_size && v + 2 < cam.face_size);
        }
    }
}
