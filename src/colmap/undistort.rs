//! `--undistort`: COLMAP's `image_undistorter` into `WORKSPACE/dataset/` (`images/` and
//! `sparse/0/` in PINHOLE, the layout 3DGS trainers read), the workspace's masks warped into the
//! undistorted cameras with the same geometry (nearest neighbour, so a mask stays binary), and
//! `transforms.json` beside them. Guarantees: every registered image of the dataset's model has its
//! image and, when the workspace has masks, its mask of the undistorted camera's size; a camera
//! model whose distortion keyframer cannot evaluate stops the run with its name instead of
//! writing a wrong mask.

use super::model::{self, Camera, Model};
use super::{p, Record, Runner};
use crate::error::{Error, Result};
use crate::fsutil;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;

/// The dataset folder inside the workspace.
pub const DATASET: &str = "dataset";

/// What `--undistort` made, as `colmap.json` records it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DatasetSummary {
    /// The dataset folder, relative to the workspace (`dataset`).
    pub path: String,
    /// The model it was undistorted from, relative to the workspace.
    pub from_model: String,
    /// Registered images in the dataset.
    pub images: usize,
    /// Masks warped into `masks/`.
    pub masks: usize,
    /// Its cameras (`PINHOLE`): id, width, height, fx, fy, cx, cy.
    pub cameras: Vec<(u32, u64, u64, [f64; 4])>,
}

/// The focal lengths, principal point and distortion parameters of a camera, in COLMAP's
/// parameter order for its model: `(fx, fy, cx, cy, distortion)`.
fn intrinsics(cam: &Camera) -> Result<(f64, f64, f64, f64, &[f64])> {
    let q = &cam.params;
    let need = |n: usize| {
        if q.len() < n {
            Err(Error::Colmap(format!(
                "camera {} ({}) has {} parameters, needs {n}",
                cam.id,
                cam.model,
                q.len()
            )))
        } else {
            Ok(())
        }
    };
    match cam.model.as_str() {
        "SIMPLE_PINHOLE" | "SIMPLE_RADIAL" | "RADIAL" => {
            need(3)?;
            Ok((q[0], q[0], q[1], q[2], &q[3..]))
        }
        "PINHOLE" | "OPENCV" | "FULL_OPENCV" | "OPENCV_FISHEYE" => {
            need(4)?;
            Ok((q[0], q[1], q[2], q[3], &q[4..]))
        }
        other => Err(Error::Colmap(format!(
            "camera {}: keyframer cannot evaluate the {other} camera model's distortion (it can: \
             SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV, OPENCV_FISHEYE)",
            cam.id
        ))),
    }
}

/// The distorted normalised coordinates of the normalised image-plane point `(u, v)` =
/// `(X/Z, Y/Z)` under `model`'s distortion `k` (COLMAP's formulas).
fn distort(model: &str, k: &[f64], u: f64, v: f64) -> (f64, f64) {
    let (u2, v2, uv) = (u * u, v * v, u * v);
    let r2 = u2 + v2;
    let tangential = |p1: f64, p2: f64| {
        (
            2.0 * p1 * uv + p2 * (r2 + 2.0 * u2),
            2.0 * p2 * uv + p1 * (r2 + 2.0 * v2),
        )
    };
    match (model, k) {
        ("SIMPLE_RADIAL", [k1]) => (u * (1.0 + k1 * r2), v * (1.0 + k1 * r2)),
        ("RADIAL", [k1, k2]) => {
            let f = 1.0 + k1 * r2 + k2 * r2 * r2;
            (u * f, v * f)
        }
        ("OPENCV", [k1, k2, p1, p2]) => {
            let f = 1.0 + k1 * r2 + k2 * r2 * r2;
            let (du, dv) = tangential(*p1, *p2);
            (u * f + du, v * f + dv)
        }
        ("FULL_OPENCV", [k1, k2, p1, p2, k3, k4, k5, k6]) => {
            let r4 = r2 * r2;
            let r6 = r4 * r2;
            let f = (1.0 + k1 * r2 + k2 * r4 + k3 * r6) / (1.0 + k4 * r2 + k5 * r4 + k6 * r6);
            let (du, dv) = tangential(*p1, *p2);
            (u * f + du, v * f + dv)
        }
        ("OPENCV_FISHEYE", [k1, k2, k3, k4]) => {
            let r = r2.sqrt();
            if r < f64::EPSILON {
                return (u, v);
            }
            let theta = r.atan();
            let t2 = theta * theta;
            let t4 = t2 * t2;
            let thetad = theta * (1.0 + k1 * t2 + k2 * t4 + k3 * t4 * t2 + k4 * t4 * t4);
            (u * thetad / r, v * thetad / r)
        }
        // Pinhole models (and parameter counts [`intrinsics`] already checked).
        _ => (u, v),
    }
}

/// Where `cam` images the normalised image-plane point `(u, v)` = `(X/Z, Y/Z)`, in COLMAP's
/// pixel coordinates (the image's top-left corner at (0, 0), pixel (i, j) covering
/// `[i, i+1) × [j, j+1)`).
pub fn project(cam: &Camera, u: f64, v: f64) -> Result<(f64, f64)> {
    let (fx, fy, cx, cy, k) = intrinsics(cam)?;
    let (ud, vd) = distort(&cam.model, k, u, v);
    Ok((fx * ud + cx, fy * vd + cy))
}

/// The normalised image-plane point `(X/Z, Y/Z)` a pinhole camera (`SIMPLE_PINHOLE`, `PINHOLE`)
/// sees at pixel coordinates `(x, y)`.
pub fn unproject_pinhole(cam: &Camera, x: f64, y: f64) -> Result<(f64, f64)> {
    let (fx, fy, cx, cy, k) = intrinsics(cam)?;
    if !k.is_empty() || !matches!(cam.model.as_str(), "PINHOLE" | "SIMPLE_PINHOLE") {
        return Err(Error::Colmap(format!(
            "camera {} is {}, not an undistorted pinhole camera",
            cam.id, cam.model
        )));
    }
    Ok(((x - cx) / fx, (y - cy) / fy))
}

/// For every pixel of the undistorted pinhole camera `dst` (row major), the index of the pixel of
/// the distorted camera `src` its centre comes from (`None` outside `src`'s image): the inverse
/// map of an undistortion, as OpenCV's `initUndistortRectifyMap` builds it, for nearest-neighbour
/// sampling.
pub fn remap_indices(src: &Camera, dst: &Camera) -> Result<Vec<Option<u32>>> {
    let (w, h) = (dst.width, dst.height);
    let mut out = Vec::with_capacity((w * h) as usize);
    for j in 0..h {
        for i in 0..w {
            let (u, v) = unproject_pinhole(dst, i as f64 + 0.5, j as f64 + 0.5)?;
            let (x, y) = project(src, u, v)?;
            let inside = x >= 0.0 && y >= 0.0 && x < src.width as f64 && y < src.height as f64;
            out.push(inside.then(|| (y.floor() as u64 * src.width + x.floor() as u64) as u32));
        }
    }
    Ok(out)
}

/// Warps the mask `from` (of `src`'s size) into `dst`'s camera through `map` and writes it as an
/// 8-bit grey PNG to `to`; pixels that fall outside the source are 0 (ignored, COLMAP's and
/// nerfstudio's meaning).
fn warp_mask(
    from: Option<&Path>,
    to: &Path,
    src: &Camera,
    dst: &Camera,
    map: &[Option<u32>],
) -> Result<()> {
    let img = match from {
        Some(from) => image::open(from)
            .map_err(|e| Error::input(from, format!("cannot read the mask: {e}")))?
            .to_luma8(),
        // A view without a mask keeps every pixel: only what undistortion adds is masked.
        None => {
            image::GrayImage::from_pixel(src.width as u32, src.height as u32, image::Luma([255]))
        }
    };
    let from = from.unwrap_or(to);
    if (u64::from(img.width()), u64::from(img.height())) != (src.width, src.height) {
        let msg = format!(
            "mask is {}x{}, its image's camera {}x{}",
            img.width(),
            img.height(),
            src.width,
            src.height
        );
        return Err(Error::input(from, msg));
    }
    let pixels = img.as_raw();
    let data: Vec<u8> = map
        .iter()
        .map(|k| k.map_or(0, |k| pixels[k as usize]))
        .collect();
    let (w, h) = (dst.width as u32, dst.height as u32);
    let out = image::GrayImage::from_raw(w, h, data)
        .ok_or_else(|| Error::output(to, "mask size does not match its camera"))?;
    let mut png = std::io::Cursor::new(Vec::new());
    out.write_to(&mut png, image::ImageFormat::Png)
        .map_err(|e| Error::output(to, format!("cannot encode the mask: {e}")))?;
    fsutil::write_atomic(to, png.get_ref())
}

/// Runs `image_undistorter` on `model_dir` into `WORKSPACE/dataset`, moves its model into
/// `sparse/0/`, removes its dense-stereo scripts and configuration, warps the masks and writes
/// `transforms.json` (`world` says what the model's world frame is).
/// Turns every camera of the undistorted model `m` (read from `dir`) into a `PINHOLE` one:
/// `image_undistorter` leaves a camera without distortion (a known-intrinsics `PINHOLE`,
/// `SIMPLE_PINHOLE`, or a radial model whose coefficients are all zero) as it was, and trainers
/// read only pinhole cameras. Returns whether any camera changed; a camera that still has
/// distortion is an error naming it.
fn as_pinhole(m: &mut Model, dir: &Path) -> Result<bool> {
    let mut changed = false;
    for cam in m.cameras.values_mut() {
        if cam.model == "PINHOLE" {
            continue;
        }
        let (fx, fy, cx, cy, k) = intrinsics(cam)?;
        if k.iter().any(|&v| v != 0.0) {
            return Err(Error::Colmap(format!(
                "{}: camera {} is {} with distortion {k:?} after undistortion, not PINHOLE",
                dir.display(),
                cam.id,
                cam.model
            )));
        }
        cam.model = "PINHOLE".into();
        cam.params = vec![fx, fy, cx, cy];
        changed = true;
    }
    Ok(changed)
}

/// What `image_undistorter` writes beside the dataset for COLMAP's dense stereo.
const DENSE_EXTRAS: [&str; 3] = [
    "run-colmap-geometric.sh",
    "run-colmap-photometric.sh",
    "stereo",
];

pub(super) fn make_dataset(
    runner: &Runner,
    rec: &mut Record,
    model_dir: &Path,
    world: super::transforms::World,
) -> Result<DatasetSummary> {
    let ws = runner.ws.as_path();
    let out = ws.join(DATASET);
    // What the undistorter writes for COLMAP's dense stereo is removed after it; anything there
    // now is not keyframer's (its own was removed with the workspace's records), so refuse.
    for name in DENSE_EXTRAS {
        let f = out.join(name);
        if std::fs::symlink_metadata(&f).is_ok() {
            let msg = "keyframer did not write this (the undistorter's dense-stereo files are \
                       removed after it): move it out of the workspace";
            return Err(Error::output(&f, msg));
        }
    }
    rec.stages.push(runner.stage(
        "image_undistorter",
        &[
            ("--image_path", p(&ws.join("images"))),
            ("--input_path", p(model_dir)),
            ("--output_path", p(&out)),
            ("--output_type", "COLMAP".into()),
        ],
    )?);
    // COLMAP 3.8 writes the model straight into sparse/; trainers read sparse/0.
    let sparse = out.join("sparse");
    let zero = sparse.join("0");
    std::fs::create_dir_all(&zero).map_err(|e| Error::io(&zero, e))?;
    for name in ["cameras.bin", "images.bin", "points3D.bin"] {
        let from = sparse.join(name);
        std::fs::rename(&from, zero.join(name)).map_err(|e| Error::io(&from, e))?;
    }
    // What image_undistorter adds for COLMAP's own dense stereo: not part of the dataset.
    for name in DENSE_EXTRAS {
        let f = out.join(name);
        match std::fs::symlink_metadata(&f) {
            Ok(m) if m.is_dir() => std::fs::remove_dir_all(&f).map_err(|e| Error::io(&f, e))?,
            Ok(_) => std::fs::remove_file(&f).map_err(|e| Error::io(&f, e))?,
            Err(_) => {}
        }
    }
    let (mut dataset, _) = model::read(&zero)?;
    if as_pinhole(&mut dataset, &zero)? {
        let bin = zero.join("cameras.bin");
        fsutil::write_atomic(&bin, &model::cameras_bin(&dataset.cameras)?)?;
    }
    let masks = if ws.join("masks").is_dir() {
        let (source, _) = model::read(model_dir)?;
        warp_masks(ws, &out, &source, &dataset)?
    } else {
        0
    };
    super::transforms::write(&out, &dataset, masks > 0, world)?;
    Ok(DatasetSummary {
        path: DATASET.into(),
        from_model: fsutil::relative_to(model_dir, ws).display().to_string(),
        images: dataset.images.len(),
        masks,
        cameras: (dataset.cameras.values())
            .map(|c| {
                let q = &c.params;
                (c.id, c.width, c.height, [q[0], q[1], q[2], q[3]])
            })
            .collect(),
    })
}

/// Warps `WORKSPACE/masks/<image>.png` of every image of the dataset into `dataset/masks/`, one
/// map per (distorted, undistorted) camera pair; returns how many it wrote (every image has one).
fn warp_masks(ws: &Path, out: &Path, source: &Model, dataset: &Model) -> Result<usize> {
    let dir = out.join("masks");
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let mut maps: HashMap<(u32, u32), Vec<Option<u32>>> = HashMap::new();
    let mut n = 0;
    // The source model's images by name (a rig export has thousands: no scan per image).
    let by_name: HashMap<&str, &model::Image> = source
        .images
        .values()
        .map(|s| (s.name.as_str(), s))
        .collect();
    for im in dataset.images.values() {
        let from = ws.join("masks").join(format!("{}.png", im.name));
        // A rig export (`<view>/<frame>`) masks only the views that see the nadir cap or a
        // person; any other image without a mask is a broken workspace.
        let rig_view = im.name.contains('/');
        if !from.is_file() && !rig_view {
            return Err(Error::input(
                &from,
                "the workspace has masks but none for this registered image",
            ));
        }
        let src_im = (by_name.get(im.name.as_str()).copied())
            .ok_or_else(|| Error::Colmap(format!("{}: not in the undistorted model", im.name)))?;
        let camera = |m: &Model, id: u32| {
            m.cameras
                .get(&id)
                .cloned()
                .ok_or_else(|| Error::Colmap(format!("{}: camera {id} missing", im.name)))
        };
        let (src, dst) = (
            camera(source, src_im.camera_id)?,
            camera(dataset, im.camera_id)?,
        );
        let map = match maps.entry((src.id, dst.id)) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(e) => e.insert(remap_indices(&src, &dst)?),
        };
        let to = dir.join(format!("{}.png", im.name));
        if let Some(parent) = to.parent() {
            std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
        }
        let from = from.is_file().then_some(from.as_path());
        warp_mask(from, &to, &src, &dst, map)?;
        n += 1;
    }
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(model: &str, params: &[f64]) -> Camera {
        Camera {
            id: 1,
            model: model.into(),
            width: 64,
            height: 48,
            params: params.to_vec(),
        }
    }

    #[test]
    fn pinhole_round_trip_and_distortion_formulas() {
        let pin = cam("PINHOLE", &[50.0, 60.0, 32.0, 24.0]);
        let (x, y) = project(&pin, 0.1, -0.2).unwrap();
        assert_eq!((x, y), (37.0, 12.0));
        assert_eq!(unproject_pinhole(&pin, x, y).unwrap(), (0.1, -0.2));
        // SIMPLE_RADIAL: u (1 + k r²).
        let sr = cam("SIMPLE_RADIAL", &[50.0, 32.0, 24.0, 0.1]);
        let r2: f64 = 0.1 * 0.1 + 0.2 * 0.2;
        let (x, _) = project(&sr, 0.1, -0.2).unwrap();
        assert!((x - (32.0 + 50.0 * 0.1 * (1.0 + 0.1 * r2))).abs() < 1e-12);
        // OPENCV with only p1: du = 2 p1 u v.
        let cv = cam("OPENCV", &[50.0, 50.0, 32.0, 24.0, 0.0, 0.0, 0.01, 0.0]);
        let (x, _) = project(&cv, 0.1, -0.2).unwrap();
        assert!((x - (32.0 + 50.0 * (0.1 + 2.0 * 0.01 * 0.1 * -0.2))).abs() < 1e-12);
        assert!(project(&cam("THIN_PRISM_FISHEYE", &[0.0; 12]), 0.0, 0.0).is_err());
    }

    #[test]
    fn distortion_free_cameras_become_pinhole_and_are_written_back() {
        let dir = std::env::temp_dir().join(format!("kf-as-pinhole-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut m = Model::default();
        let mut second = cam("SIMPLE_PINHOLE", &[40.0, 32.0, 24.0]);
        second.id = 2;
        m.cameras
            .insert(1, cam("SIMPLE_RADIAL", &[50.0, 32.0, 24.0, 0.0]));
        m.cameras.insert(2, second);
        assert!(as_pinhole(&mut m, &dir).unwrap());
        assert_eq!(m.cameras[&1], cam("PINHOLE", &[50.0, 50.0, 32.0, 24.0]));
        assert_eq!(m.cameras[&2].params, [40.0, 40.0, 32.0, 24.0]);
        // Written as COLMAP's cameras.bin and read back by the model reader.
        std::fs::write(
            dir.join("cameras.bin"),
            model::cameras_bin(&m.cameras).unwrap(),
        )
        .unwrap();
        for (name, empty) in [("images.bin", 0u64), ("points3D.bin", 0)] {
            std::fs::write(dir.join(name), empty.to_le_bytes()).unwrap();
        }
        assert_eq!(model::read_binary(&dir).unwrap().cameras, m.cameras);
        // Already pinhole: nothing to rewrite; real distortion left: an error naming the camera.
        assert!(!as_pinhole(&mut m, &dir).unwrap());
        let mut d = Model::default();
        d.cameras
            .insert(1, cam("SIMPLE_RADIAL", &[50.0, 32.0, 24.0, 0.01]));
        let e = as_pinhole(&mut d, &dir).unwrap_err().to_string();
        assert!(e.contains("camera 1 is SIMPLE_RADIAL"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn remap_of_identical_pinholes_is_the_identity() {
        let pin = cam("PINHOLE", &[50.0, 60.0, 32.0, 24.0]);
        let map = remap_indices(&pin, &pin).unwrap();
        assert!(map.iter().enumerate().all(|(i, k)| *k == Some(i as u32)));
    }
}
