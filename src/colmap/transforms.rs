//! `dataset/transforms.json` in nerfstudio's format (also read by instant-ngp) and its
//! `sparse_pc.ply`, from an undistorted (PINHOLE) COLMAP model. Guarantees: one frame per
//! registered image, sorted by name; `transform_matrix` is the camera-to-world matrix with
//! OpenGL camera axes (x right, y up, z back) in the world `applied_transform` makes of COLMAP's
//! (`w_json = A · w_colmap`); the point cloud is in the file's world too, as nerfstudio expects.
//! docs/colmap.md works one camera through by hand.

use super::align::{self, Mat3};
use super::model::Model;
use crate::error::{Error, Result};
use crate::fsutil;
use serde_json::{json, Value};
use std::path::Path;

/// The file name.
pub const TRANSFORMS: &str = "transforms.json";
/// The point cloud beside it (`ply_file_path`).
pub const POINT_CLOUD: &str = "sparse_pc.ply";
/// instant-ngp's bounding box scale (a power of two; it is ignored by nerfstudio).
pub const AABB_SCALE: u32 = 16;

/// What the model's world frame is, which decides `applied_transform`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum World {
    /// COLMAP's arbitrary frame: nerfstudio's `ns-process-data` rotation `(x, y, z) → (x, z, −y)`
    /// is applied (COLMAP's first camera looks along +z with y down, so −y is roughly up).
    Colmap,
    /// Geo-registered east/north/up metres: kept as is (z is already up).
    Enu,
}

impl World {
    /// The rotation `A` taking COLMAP's world into the transforms' world.
    pub fn applied(self) -> Mat3 {
        match self {
            World::Colmap => [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]],
            World::Enu => align::IDENTITY,
        }
    }
}

/// The camera-to-world 4x4 matrix (rows) of a world-to-camera pose `(q, t)` with OpenGL camera
/// axes, in the world `a · w`: columns `a·Rᵀ·diag(1, −1, −1)` and `a·C`, `C = −Rᵀt`.
pub fn transform_matrix(qvec: [f64; 4], tvec: [f64; 3], a: &Mat3) -> [[f64; 4]; 4] {
    let rt = align::transpose(&align::quat_to_mat(qvec));
    let c = align::mul_vec(&rt, &tvec).map(|v| -v);
    let flip = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]];
    let r = align::mul(a, &align::mul(&rt, &flip));
    let c = align::mul_vec(a, &c);
    let mut m = [[0.0; 4]; 4];
    for i in 0..3 {
        m[i] = [r[i][0], r[i][1], r[i][2], c[i]];
    }
    m[3] = [0.0, 0.0, 0.0, 1.0];
    m
}

/// A PINHOLE camera's intrinsics as nerfstudio's keys (no distortion).
fn intrinsics(cam: &super::model::Camera) -> Result<serde_json::Map<String, Value>> {
    let (fx, fy, cx, cy, _) = match cam.params.as_slice() {
        [fx, fy, cx, cy] if cam.model == "PINHOLE" => (fx, fy, cx, cy, ()),
        _ => {
            return Err(Error::Colmap(format!(
                "transforms.json needs undistorted PINHOLE cameras; camera {} is {}",
                cam.id, cam.model
            )))
        }
    };
    let v = json!({
        "camera_model": "OPENCV",
        "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": cam.width, "h": cam.height,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
    });
    Ok(v.as_object().cloned().unwrap_or_default())
}

/// The transforms of `model` (PINHOLE cameras): shared intrinsics at the top when there is one
/// camera, else in every frame; `mask_path` when `masks`.
pub fn transforms(model: &Model, masks: bool, world: World) -> Result<Value> {
    let a = world.applied();
    let one_camera = model.cameras.len() == 1;
    let mut images: Vec<_> = model.images.values().collect();
    images.sort_by(|x, y| x.name.cmp(&y.name));
    let mut frames = Vec::with_capacity(images.len());
    for im in images {
        let cam = model.cameras.get(&im.camera_id).ok_or_else(|| {
            Error::Colmap(format!(
                "image {}: camera {} missing",
                im.name, im.camera_id
            ))
        })?;
        let mut f = serde_json::Map::new();
        f.insert("file_path".into(), json!(format!("images/{}", im.name)));
        f.insert(
            "transform_matrix".into(),
            json!(transform_matrix(im.qvec, im.tvec, &a)),
        );
        f.insert("colmap_im_id".into(), json!(im.id));
        if masks {
            f.insert("mask_path".into(), json!(format!("masks/{}.png", im.name)));
        }
        if !one_camera {
            f.extend(intrinsics(cam)?);
        }
        frames.push(Value::Object(f));
    }
    let mut top = serde_json::Map::new();
    if let Some(cam) = model.cameras.values().next().filter(|_| one_camera) {
        top.extend(intrinsics(cam)?);
    }
    let applied: Vec<[f64; 4]> = a.iter().map(|r| [r[0], r[1], r[2], 0.0]).collect();
    top.insert("applied_transform".into(), json!(applied));
    top.insert("aabb_scale".into(), json!(AABB_SCALE));
    top.insert("ply_file_path".into(), json!(POINT_CLOUD));
    top.insert("frames".into(), Value::Array(frames));
    Ok(Value::Object(top))
}

/// Writes `transforms.json` and `sparse_pc.ply` into `dir`; the points are in the file's world
/// (`A · xyz`, as the frames), which is what nerfstudio's parser expects: it loads the cloud with
/// its own orientation transform only, not with `applied_transform` (`ns-process-data` writes it
/// the same way).
pub fn write(dir: &Path, model: &Model, masks: bool, world: World) -> Result<()> {
    let a = world.applied();
    fsutil::write_json(&dir.join(TRANSFORMS), &transforms(model, masks, world)?)?;
    let mut ply = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty double x\nproperty double y\n\
         property double z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        model.points.len()
    );
    for pt in model.points.values() {
        let [x, y, z] = align::mul_vec(&a, &pt.xyz);
        let [r, g, b] = pt.rgb;
        ply += &format!("{x} {y} {z} {r} {g} {b}\n");
    }
    fsutil::write_atomic(&dir.join(POINT_CLOUD), ply.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::colmap::model::{Camera, Image, Point3D};

    /// A camera at (1, 2, 3) looking down −z of the world with x right: in OpenGL axes its
    /// camera-to-world rotation is the identity.
    #[test]
    fn camera_looking_down_is_identity_in_opengl_axes() {
        // World-to-camera: camera x = world x, camera y = −world y, camera z = −world z.
        let r = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]];
        let c = [1.0, 2.0, 3.0];
        let t = align::mul_vec(&r, &c).map(|v| -v);
        // q of a 180° turn about x: (0, 1, 0, 0).
        let m = transform_matrix([0.0, 1.0, 0.0, 0.0], t, &align::IDENTITY);
        let want = [
            [1.0, 0.0, 0.0, 1.0],
            [0.0, 1.0, 0.0, 2.0],
            [0.0, 0.0, 1.0, 3.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        for i in 0..4 {
            for j in 0..4 {
                assert!((m[i][j] - want[i][j]).abs() < 1e-12, "{m:?}");
            }
        }
        // nerfstudio's default world: (x, y, z) → (x, z, −y).
        let m = transform_matrix([0.0, 1.0, 0.0, 0.0], t, &World::Colmap.applied());
        assert_eq!([m[0][3], m[1][3], m[2][3]], [1.0, 3.0, -2.0]);
    }

    /// The cloud and the frames share a world: a point 5 units in front of a camera in COLMAP's
    /// world is 5 units along the frame's −z (OpenGL forward) in the written files, in both worlds.
    #[test]
    fn the_point_cloud_is_in_the_frames_world() {
        let r = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]];
        let c = [1.0, 2.0, 3.0];
        let t = align::mul_vec(&r, &c).map(|v| -v);
        let seen = [1.0, 2.0, -2.0]; // camera z (forward) = −world z: 5 in front of c
        let model = Model {
            cameras: [(
                1,
                Camera {
                    id: 1,
                    model: "PINHOLE".into(),
                    width: 64,
                    height: 48,
                    params: vec![50.0, 50.0, 32.0, 24.0],
                },
            )]
            .into(),
            images: [(
                1,
                Image {
                    id: 1,
                    qvec: [0.0, 1.0, 0.0, 0.0],
                    tvec: t,
                    camera_id: 1,
                    name: "a.jpg".into(),
                    points2d: Vec::new(),
                },
            )]
            .into(),
            points: [(
                7,
                Point3D {
                    id: 7,
                    xyz: seen,
                    rgb: [1, 2, 3],
                    error: 0.5,
                    track: vec![(1, 0)],
                },
            )]
            .into(),
        };
        for world in [World::Colmap, World::Enu] {
            let dir = tempfile::tempdir().unwrap();
            write(dir.path(), &model, false, world).unwrap();
            let ply = std::fs::read_to_string(dir.path().join(POINT_CLOUD)).unwrap();
            let row = ply.lines().last().unwrap();
            let v: Vec<f64> = row.split(' ').take(3).map(|x| x.parse().unwrap()).collect();
            let m = transform_matrix([0.0, 1.0, 0.0, 0.0], t, &world.applied());
            // Camera-frame coordinates of the point: Rᵀ of the 3×3 block times (p − centre).
            let d: Vec<f64> = (0..3).map(|i| v[i] - m[i][3]).collect();
            let cam: Vec<f64> = (0..3)
                .map(|j| (0..3).map(|i| m[i][j] * d[i]).sum())
                .collect();
            for (got, want) in cam.iter().zip([0.0, 0.0, -5.0]) {
                assert!((got - want).abs() < 1e-9, "{world:?}: {cam:?}");
            }
        }
    }
}
