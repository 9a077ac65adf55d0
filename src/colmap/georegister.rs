//! `--georegister`: the sparse model aligned to the keyframes' positions (the export manifest's
//! telemetry or EXIF GPS) by COLMAP's `model_aligner` (robust, with scale) in the local ENU frame
//! of the first position (x east, y north, z up, metres), written to `WORKSPACE/georegistered/`
//! with `georegistration.json` (ENU origin, the similarity taking the model into ENU, the residual
//! of every aligned camera centre) and `cameras.geojson` (every aligned camera centre on Earth, for
//! a GIS). Guarantees: fewer than three positions, or positions on one
//! line (the rotation about it would be a guess), are refused with the reason before COLMAP
//! runs; the residuals are computed by keyframer from the written model, not copied from
//! COLMAP's log.

use super::align::{self, Sim3, Vec3};
use super::model::{self, Model};
use super::{p, Record, Runner};
use crate::error::{Error, Result};
use crate::fsutil;
use crate::manifest::Manifest;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The georegistered model's folder inside the workspace.
pub const GEOREGISTERED: &str = "georegistered";
/// The record inside it.
pub const RECORD: &str = "georegistration.json";
/// The reference positions given to `model_aligner` (image name, latitude, longitude, altitude).
const REFERENCE: &str = "positions.txt";
/// The aligned camera centres as GeoJSON points (WGS84 longitude, latitude, altitude).
pub const CAMERAS: &str = "cameras.geojson";
/// Default inlier threshold of the robust alignment, metres.
pub const DEFAULT_MAX_ERROR_M: f64 = 3.0;
/// Positions whose RMS distance from their best-fitting line is below this many metres, or
/// below [`COLLINEAR_RATIO`] of their RMS spread along it, are collinear.
const COLLINEAR_M: f64 = 0.1;
/// See [`COLLINEAR_M`].
const COLLINEAR_RATIO: f64 = 0.01;

/// One keyframe's position on Earth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GeoPosition {
    /// Image file name.
    pub name: String,
    /// Latitude, degrees north (WGS84).
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Altitude, metres (above sea level, else above the take-off point: see `altitude`).
    pub alt_m: f64,
}

/// The positions of the manifest's frames that have one, in frame order, and which altitude
/// they use: `"above sea level"` when every one has it, else `"above take-off"`; an error when
/// some position has neither.
pub fn positions(manifest: &Manifest) -> Result<(Vec<GeoPosition>, &'static str)> {
    let with: Vec<_> = (manifest.frames.iter())
        .filter_map(|f| f.position.as_ref().map(|p| (f, p)))
        .collect();
    let (kind, alt): (&str, fn(&crate::source::telemetry::Position) -> Option<f64>) =
        if with.iter().all(|(_, p)| p.abs_alt_m.is_some()) {
            ("above sea level", |p| p.abs_alt_m)
        } else {
            ("above take-off", |p| p.rel_alt_m)
        };
    let mut out = Vec::with_capacity(with.len());
    for (f, pos) in with {
        let alt_m = alt(pos).ok_or_else(|| {
            Error::param(
                "georegister",
                format!("{}: its position has no altitude", f.file),
            )
        })?;
        out.push(GeoPosition {
            // COLMAP's image name: `<view>/<file>` in a rig export.
            name: f.rel().to_string_lossy().into_owned(),
            lat_deg: pos.lat_deg,
            lon_deg: pos.lon_deg,
            alt_m,
        });
    }
    Ok((out, kind))
}

/// Earth-centred, Earth-fixed coordinates of a WGS84 position, metres.
pub fn ecef(lat_deg: f64, lon_deg: f64, alt_m: f64) -> Vec3 {
    const A: f64 = 6_378_137.0;
    const E2: f64 = 6.694_379_990_14e-3;
    let (phi, lam) = (lat_deg.to_radians(), lon_deg.to_radians());
    let n = A / (1.0 - E2 * phi.sin().powi(2)).sqrt();
    [
        (n + alt_m) * phi.cos() * lam.cos(),
        (n + alt_m) * phi.cos() * lam.sin(),
        (n * (1.0 - E2) + alt_m) * phi.sin(),
    ]
}

/// East, north, up of `p` in metres in the tangent frame at `origin` (through ECEF).
pub fn enu(origin: &GeoPosition, p: &GeoPosition) -> Vec3 {
    let o = ecef(origin.lat_deg, origin.lon_deg, origin.alt_m);
    let x = ecef(p.lat_deg, p.lon_deg, p.alt_m);
    let d = [x[0] - o[0], x[1] - o[1], x[2] - o[2]];
    let (phi, lam) = (origin.lat_deg.to_radians(), origin.lon_deg.to_radians());
    let r = [
        [-lam.sin(), lam.cos(), 0.0],
        [-phi.sin() * lam.cos(), -phi.sin() * lam.sin(), phi.cos()],
        [phi.cos() * lam.cos(), phi.cos() * lam.sin(), phi.sin()],
    ];
    align::mul_vec(&r, &d)
}

/// The WGS84 latitude, longitude (degrees) and altitude (metres) of ECEF coordinates: the
/// inverse of [`ecef`] (Bowring's start, then fixed-point steps; under a micrometre within a
/// few hundred kilometres of the surface).
pub fn geodetic(x: Vec3) -> (f64, f64, f64) {
    const A: f64 = 6_378_137.0;
    const E2: f64 = 6.694_379_990_14e-3;
    let p = x[0].hypot(x[1]);
    let lon = x[1].atan2(x[0]);
    let mut lat = x[2].atan2(p * (1.0 - E2));
    let mut alt = 0.0;
    for _ in 0..6 {
        let n = A / (1.0 - E2 * lat.sin().powi(2)).sqrt();
        alt = if lat.cos().abs() > 1e-9 {
            p / lat.cos() - n
        } else {
            x[2].abs() - n * (1.0 - E2)
        };
        lat = x[2].atan2(p * (1.0 - E2 * n / (n + alt)));
    }
    (lat.to_degrees(), lon.to_degrees(), alt)
}

/// The WGS84 position of `v` (east, north, up metres in the tangent frame at `origin`): the
/// inverse of [`enu`].
pub fn from_enu(origin: &GeoPosition, v: Vec3) -> (f64, f64, f64) {
    let o = ecef(origin.lat_deg, origin.lon_deg, origin.alt_m);
    let (phi, lam) = (origin.lat_deg.to_radians(), origin.lon_deg.to_radians());
    // The columns of `enu`'s rotation: ECEF directions of east, north, up.
    let (e, n, u) = (
        [-lam.sin(), lam.cos(), 0.0],
        [-phi.sin() * lam.cos(), -phi.sin() * lam.sin(), phi.cos()],
        [phi.cos() * lam.cos(), phi.cos() * lam.sin(), phi.sin()],
    );
    geodetic(std::array::from_fn(|k| {
        o[k] + e[k] * v[0] + n[k] * v[1] + u[k] * v[2]
    }))
}

/// Refuses positions a similarity cannot be fitted to: fewer than three, or collinear (their
/// RMS distance from the best-fitting line under 0.1 m or under 1 % of their RMS spread along
/// it). `what` names the positions in the message.
pub fn check(points: &[Vec3], what: &str) -> Result<()> {
    let n = points.len();
    if n < 3 {
        return Err(Error::param(
            "georegister",
            format!(
                "{what}: {n} position{}; a similarity (scale, rotation, shift) needs at least 3 not on one line",
                if n == 1 { "" } else { "s" }
            ),
        ));
    }
    let nf = n as f64;
    let mean = (0..3).map(|k| points.iter().map(|p| p[k]).sum::<f64>() / nf);
    let mean: Vec<f64> = mean.collect();
    let mut cov = [[0.0; 3]; 3];
    for p in points {
        for i in 0..3 {
            for j in 0..3 {
                cov[i][j] += (p[i] - mean[i]) * (p[j] - mean[j]) / nf;
            }
        }
    }
    let s = align::svd3(&cov).map(|d| d.s).unwrap_or([0.0; 3]);
    let (along, across) = (s[0].max(0.0).sqrt(), (s[1] + s[2]).max(0.0).sqrt());
    if across < COLLINEAR_M || across < COLLINEAR_RATIO * along {
        return Err(Error::param(
            "georegister",
            format!(
                "{what}: the {n} positions lie on one line (RMS {across:.3} m off it over {along:.1} m along it): \
                 the rotation about that line cannot be determined; fly a turn or a second line"
            ),
        ));
    }
    Ok(())
}

/// How far the aligned camera centres are from the positions, metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Residuals {
    /// Registered images with a position.
    pub images: usize,
    /// Mean distance.
    pub mean_m: f64,
    /// Median distance.
    pub median_m: f64,
    /// Root mean square.
    pub rms_m: f64,
    /// Largest distance.
    pub max_m: f64,
}

/// The residuals of `model`'s camera centres (ENU) against `positions` (ENU of `origin`); `None`
/// when no registered image has a position.
pub fn residuals(
    model: &Model,
    positions: &[GeoPosition],
    origin: &GeoPosition,
) -> Option<Residuals> {
    let mut d: Vec<f64> = (model.images.values())
        .filter_map(|im| {
            let p = positions.iter().find(|p| p.name == im.name)?;
            Some(align::dist(&im.centre(), &enu(origin, p)))
        })
        .collect();
    if d.is_empty() {
        return None;
    }
    d.sort_by(f64::total_cmp);
    let n = d.len() as f64;
    Some(Residuals {
        images: d.len(),
        mean_m: d.iter().sum::<f64>() / n,
        median_m: super::align::quantile(&d, 0.5),
        rms_m: (d.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
        max_m: d[d.len() - 1],
    })
}

/// The registered images of `model` (ENU) whose centre lies farther than `max_m` from their
/// position, in name order.
pub fn outliers(
    model: &Model,
    positions: &[GeoPosition],
    origin: &GeoPosition,
    max_m: f64,
) -> Vec<String> {
    let mut out: Vec<String> = (model.images.values())
        .filter(|im| {
            (positions.iter().find(|p| p.name == im.name))
                .is_some_and(|p| align::dist(&im.centre(), &enu(origin, p)) > max_m)
        })
        .map(|im| im.name.clone())
        .collect();
    out.sort();
    out
}

/// What `georegistration.json` (and `colmap.json`) record.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Georegistration {
    /// The model aligned, relative to the workspace (`sparse/0`).
    pub from_model: String,
    /// The aligned model, relative to the workspace (`georegistered`).
    pub model: String,
    /// What the aligned model's world is.
    pub frame: String,
    /// The ENU origin: the first exported frame's position.
    pub origin: GeoPosition,
    /// Which altitude the positions use ("above sea level" or "above take-off").
    pub altitude: String,
    /// Positions given (exported frames with one).
    pub positions: usize,
    /// Inlier threshold of the robust alignment, metres.
    pub max_error_m: f64,
    /// The similarity taking the source model's coordinates to ENU metres
    /// (`x_enu = scale · R · x + t`), fitted to the aligned camera centres.
    pub scale: f64,
    /// `R`, rows.
    pub rotation: align::Mat3,
    /// `t`, metres.
    pub translation: Vec3,
    /// Aligned camera centres against the positions.
    pub residuals: Residuals,
    /// Images whose aligned centre lies farther than `max_error_m` from their position: where
    /// the model and the positions disagree (a mis-assembled part of the model, or wrong
    /// positions). Empty when they agree.
    #[serde(default)]
    pub outliers: Vec<String>,
}

/// Reads a workspace's `georegistered/georegistration.json`, if there is one.
pub fn read(ws: &Path) -> Result<Option<Georegistration>> {
    let p = ws.join(GEOREGISTERED).join(RECORD);
    if !p.is_file() {
        return Ok(None);
    }
    let text = crate::output::read_text(&p)?;
    serde_json::from_str(&text)
        .map(Some)
        .map_err(|e| Error::file(&p, Some(e.line()), "georegistration", "", e.to_string()))
}

/// The manifest's positions (in ENU of the first) checked before any COLMAP stage runs.
pub(super) fn precheck(manifest: &Manifest) -> Result<()> {
    let (pos, _) = positions(manifest)?;
    let Some(origin) = pos.first() else {
        return check(
            &[],
            "the export's frames carry no position (telemetry or EXIF GPS)",
        );
    };
    let enus: Vec<Vec3> = pos.iter().map(|p| enu(origin, p)).collect();
    check(&enus, "the export's frames")
}

/// Aligns the model in `model_dir` to the manifest's positions into `WORKSPACE/georegistered`.
pub(super) fn georegister(
    runner: &Runner,
    rec: &mut Record,
    manifest: &Manifest,
    model_dir: &Path,
    max_error_m: f64,
) -> Result<(PathBuf, Georegistration)> {
    let ws = runner.ws.as_path();
    let (pos, altitude) = positions(manifest)?;
    let (source, _) = model::read(model_dir)?;
    let origin = pos
        .first()
        .cloned()
        .ok_or_else(|| Error::param("georegister", "the export's frames carry no position"))?;
    let registered: Vec<Vec3> = (pos.iter())
        .filter(|p| source.images.values().any(|im| im.name == p.name))
        .map(|p| enu(&origin, p))
        .collect();
    check(&registered, "the registered images with a position")?;
    let out = ws.join(GEOREGISTERED);
    std::fs::create_dir_all(&out).map_err(|e| Error::io(&out, e))?;
    // The first line is the ENU origin COLMAP uses.
    let reference: String = (pos.iter())
        .map(|q| {
            format!(
                "{} {:.12} {:.12} {:.6}\n",
                q.name, q.lat_deg, q.lon_deg, q.alt_m
            )
        })
        .collect();
    fsutil::write_atomic(&out.join(REFERENCE), reference.as_bytes())?;
    rec.stages.push(runner.stage(
        "model_aligner",
        &[
            ("--input_path", p(model_dir)),
            ("--output_path", p(&out)),
            ("--ref_images_path", p(&out.join(REFERENCE))),
            ("--ref_is_gps", "1".into()),
            ("--alignment_type", "enu".into()),
            ("--robust_alignment", "1".into()),
            ("--robust_alignment_max_error", max_error_m.to_string()),
            ("--min_common_images", "3".into()),
            ("--transform_path", p(&out.join("transform.txt"))),
        ],
    )?);
    if model::detect(&out).is_none() {
        return Err(Error::Colmap(format!(
            "model_aligner wrote no model (alignment failed: too few positions within {max_error_m} m \
             of a consistent similarity?); log: {}",
            ws.join("logs/model_aligner.log").display()
        )));
    }
    let (aligned, _) = model::read(&out)?;
    let (src, dst): (Vec<Vec3>, Vec<Vec3>) = (aligned.images.values())
        .filter_map(|a| {
            let s = source.images.get(&a.id)?;
            Some((s.centre(), a.centre()))
        })
        .unzip();
    let sim: Sim3 = align::umeyama(&src, &dst).ok_or_else(|| {
        Error::Colmap(format!(
            "{}: the aligned camera centres do not determine a similarity",
            out.display()
        ))
    })?;
    let residuals = residuals(&aligned, &pos, &origin)
        .ok_or_else(|| Error::Colmap("no aligned image has a position".into()))?;
    let outliers = outliers(&aligned, &pos, &origin, max_error_m);
    if !outliers.is_empty() {
        let shown: Vec<&str> = outliers.iter().take(5).map(String::as_str).collect();
        log::warn!(
            "{} of {} aligned cameras lie more than {max_error_m} m from their positions ({}{}): \
             the model and the positions disagree there (a mis-assembled model, or wrong \
             positions); `keyframer reconstruct` rebuilds such models",
            outliers.len(),
            residuals.images,
            shown.join(", "),
            if outliers.len() > shown.len() {
                ", ..."
            } else {
                ""
            }
        );
    }
    let g = Georegistration {
        from_model: fsutil::relative_to(model_dir, ws).display().to_string(),
        model: GEOREGISTERED.into(),
        frame: "local ENU: x east, y north, z up, metres, origin at `origin`".into(),
        origin,
        altitude: altitude.into(),
        positions: pos.len(),
        max_error_m,
        scale: sim.scale,
        rotation: sim.rotation,
        translation: sim.translation,
        residuals,
        outliers,
    };
    fsutil::write_json(&out.join(RECORD), &g)?;
    fsutil::write_json(&out.join(CAMERAS), &cameras_geojson(&aligned, &pos, &g))?;
    if !runner.quiet {
        eprintln!(
            "georegistered: {} images, residual mean {:.3} m, median {:.3} m, max {:.3} m, scale {:.6}",
            residuals.images, residuals.mean_m, residuals.median_m, residuals.max_m, sim.scale
        );
    }
    Ok((out, g))
}

/// The aligned model's camera centres as a GeoJSON FeatureCollection of 3D points (longitude,
/// latitude, altitude of `g.altitude`'s kind: RFC 7946's WGS84), in image-name order, each with its
/// image name, its position's distance (`residual_m`, when it has one) and the camera's viewing
/// direction as a compass bearing and an elevation angle, in degrees.
fn cameras_geojson(
    model: &Model,
    positions: &[GeoPosition],
    g: &Georegistration,
) -> serde_json::Value {
    let mut images: Vec<_> = model.images.values().collect();
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let features: Vec<serde_json::Value> = (images.iter())
        .map(|im| {
            let c = im.centre();
            let (lat, lon, alt) = from_enu(&g.origin, c);
            let residual = (positions.iter().find(|p| p.name == im.name))
                .map(|p| align::dist(&c, &enu(&g.origin, p)));
            // The viewing direction (the camera's +z) in ENU: the third row of world-to-camera.
            let z = align::quat_to_mat(im.qvec)[2];
            serde_json::json!({
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": [lon, lat, alt]},
                "properties": {
                    "name": im.name,
                    "residual_m": residual,
                    "bearing_deg": z[0].atan2(z[1]).to_degrees().rem_euclid(360.0),
                    "elevation_deg": z[2].clamp(-1.0, 1.0).asin().to_degrees(),
                },
            })
        })
        .collect();
    serde_json::json!({
        "type": "FeatureCollection",
        "name": "cameras",
        "altitude": g.altitude,
        "features": features,
    })
}

/// The residuals of a workspace's georegistered model against the export's positions, as
/// `eval` reports them (`None` without a georegistered model).
pub fn evaluate(ws: &Path, manifest: &Manifest) -> Result<Option<Residuals>> {
    let Some(g) = read(ws)? else {
        return Ok(None);
    };
    let (model, _) = model::read(&ws.join(&g.model))?;
    let (pos, _) = positions(manifest)?;
    Ok(residuals(&model, &pos, &g.origin))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cameras_beyond_the_max_error_are_outliers() {
        let origin = at(-33.85, -70.6, 500.0);
        let mut model = Model::default();
        let mut positions = Vec::new();
        for (k, off) in [0.5, 4.0, 2.9].into_iter().enumerate() {
            let name = format!("f{k}.jpg");
            let p = GeoPosition {
                name: name.clone(),
                ..at(-33.85 + 1e-4 * k as f64, -70.6, 500.0)
            };
            let mut c = enu(&origin, &p);
            c[2] += off;
            model.images.insert(
                k as u32,
                model::Image {
                    id: k as u32,
                    qvec: [1.0, 0.0, 0.0, 0.0],
                    tvec: c.map(|v| -v),
                    camera_id: 1,
                    name,
                    points2d: Vec::new(),
                },
            );
            positions.push(p);
        }
        assert_eq!(outliers(&model, &positions, &origin, 3.0), ["f1.jpg"]);
        assert!(outliers(&model, &positions, &origin, 5.0).is_empty());
        let r = residuals(&model, &positions, &origin).unwrap();
        assert!((r.max_m - 4.0).abs() < 1e-6, "{r:?}");
    }

    fn at(lat: f64, lon: f64, alt: f64) -> GeoPosition {
        GeoPosition {
            name: String::new(),
            lat_deg: lat,
            lon_deg: lon,
            alt_m: alt,
        }
    }

    #[test]
    fn geodetic_and_from_enu_invert_ecef_and_enu() {
        for (lat, lon, alt) in [
            (-33.8568, -70.6012, 520.5),
            (0.0, 0.0, 0.0),
            (89.9, 179.9, -100.0),
            (47.3, 8.5, 3000.0),
        ] {
            let (la, lo, al) = geodetic(ecef(lat, lon, alt));
            assert!(
                (la - lat).abs() < 1e-9 && (lo - lon).abs() < 1e-9,
                "{la} {lo}"
            );
            assert!((al - alt).abs() < 1e-6, "{al} vs {alt}");
            let origin = at(lat, lon, alt);
            for v in [[0.0, 0.0, 0.0], [1500.0, -800.0, 35.0], [-20.0, 40.0, -3.0]] {
                let (la, lo, al) = from_enu(&origin, v);
                let back = enu(&origin, &at(la, lo, al));
                assert!(align::dist(&back, &v) < 1e-6, "{v:?} -> {back:?}");
            }
        }
    }

    #[test]
    fn enu_axes_point_east_north_up() {
        let o = at(-33.8568, -70.6012, 520.5);
        let (meridian, prime) = crate::source::telemetry::wgs84_radii(o.lat_deg);
        let north = enu(
            &o,
            &at(
                o.lat_deg + (100.0 / meridian).to_degrees(),
                o.lon_deg,
                520.5,
            ),
        );
        assert!(
            (north[1] - 100.0).abs() < 1e-2 && north[0].abs() < 1e-6,
            "{north:?}"
        );
        let east_deg = (100.0 / (prime * o.lat_deg.to_radians().cos())).to_degrees();
        let east = enu(&o, &at(o.lat_deg, o.lon_deg + east_deg, 520.5));
        assert!(
            (east[0] - 100.0).abs() < 1e-2 && east[1].abs() < 1e-2,
            "{east:?}"
        );
        let up = enu(&o, &at(o.lat_deg, o.lon_deg, 530.5));
        assert!((up[2] - 10.0).abs() < 1e-9 && up[0].abs() < 1e-9, "{up:?}");
    }

    #[test]
    fn too_few_and_collinear_positions_are_refused() {
        let e = check(&[[0.0; 3], [1.0, 0.0, 0.0]], "test").unwrap_err();
        assert!(e.to_string().contains("2 positions"), "{e}");
        let line: Vec<Vec3> = (0..10)
            .map(|i| [f64::from(i), 2.0 * f64::from(i), 0.0])
            .collect();
        let e = check(&line, "test").unwrap_err();
        assert!(e.to_string().contains("one line"), "{e}");
        let mut turn = line.clone();
        turn.push([5.0, 0.0, 0.0]);
        check(&turn, "test").unwrap();
    }
}
