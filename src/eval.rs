//! `keyframer eval`: how well a COLMAP reconstruction of exported keyframes turned out:
//! registered/selected images, reprojection error, track length, the spacing of consecutive
//! camera centres (in frame order), and with a TUM ground truth a Sim(3) (Umeyama) alignment with
//! position RMSE (absolute trajectory error) and mean rotation error. Every number is computed
//! from the files given; nothing is estimated when the inputs do not allow it.

use crate::colmap::align::{self, quantile, Vec3};
use crate::colmap::model::{self, Format, Model};
use crate::colmap::{self as cm, read_manifest};
use crate::error::{Error, Result};
use crate::manifest::Manifest;
use crate::output::Inputs;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// What `eval` reads: each field is the flag of the same name (`keyframer eval --help`).
#[derive(Debug, Clone)]
pub struct EvalSettings {
    /// A COLMAP model folder, a `sparse/` folder of models, or a `keyframer colmap` workspace.
    pub model: PathBuf,
    /// The export folder (None: the workspace's export).
    pub export: Option<PathBuf>,
    /// Ground-truth camera-to-world poses in TUM format.
    pub gt: Option<PathBuf>,
}

/// Summary statistics of a list of distances.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct Stats {
    /// Number of distances.
    pub count: usize,
    /// Arithmetic mean.
    pub mean: f64,
    /// Population standard deviation (divides by n).
    pub std: f64,
    /// 10th percentile.
    pub q10: f64,
    /// 90th percentile.
    pub q90: f64,
}

/// Mean, population σ and the 0.1/0.9 quantiles; `None` for an empty list.
pub fn stats(values: &[f64]) -> Option<Stats> {
    if values.is_empty() {
        return None;
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let std = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    Some(Stats {
        count: values.len(),
        mean,
        std,
        q10: quantile(&sorted, 0.1),
        q90: quantile(&sorted, 0.9),
    })
}

/// Distances between consecutive points.
pub fn spacings(points: &[Vec3]) -> Vec<f64> {
    points
        .windows(2)
        .map(|w| align::dist(&w[0], &w[1]))
        .collect()
}

/// One ground-truth pose (camera-to-world).
#[derive(Debug, Clone, Copy)]
pub struct GtPose {
    /// Timestamp in seconds.
    pub t: f64,
    /// Camera position.
    pub position: Vec3,
    /// Orientation quaternion (w, x, y, z).
    pub q: [f64; 4],
}

/// Reads a TUM trajectory (`timestamp tx ty tz qx qy qz qw`, `#` comments), sorted by time.
pub fn read_tum(path: &Path) -> Result<Vec<GtPose>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut poses = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let v: Vec<f64> = l
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|s| !s.is_empty())
            .map(|s| s.parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| tum_err(path, i + 1, "not a number"))?;
        if v.len() != 8 {
            let msg = format!("{} values; TUM lines have 8", v.len());
            return Err(tum_err(path, i + 1, &msg));
        }
        poses.push(GtPose {
            t: v[0],
            position: [v[1], v[2], v[3]],
            q: [v[7], v[4], v[5], v[6]],
        });
    }
    if poses.is_empty() {
        return Err(Error::input(path, "no poses in the ground-truth file"));
    }
    poses.sort_by(|a, b| a.t.total_cmp(&b.t));
    Ok(poses)
}

fn tum_err(path: &Path, line: usize, msg: &str) -> Error {
    let fields = "timestamp tx ty tz qx qy qz qw";
    Error::file(path, Some(line), "TUM trajectory", fields, msg)
}

/// Ground-truth part of the report.
#[derive(Debug, Clone, Serialize)]
pub struct GtReport {
    /// The ground-truth file.
    pub file: PathBuf,
    /// Registered images matched to a ground-truth pose.
    pub matched: usize,
    /// How images were matched: "timestamp" or "index" (frame index × GT interval).
    pub matched_by: String,
    /// Scale of the Sim(3) taking model units to ground-truth units.
    pub scale: f64,
    /// Root mean square of the aligned camera-centre errors (GT units): the absolute trajectory
    /// error of positions.
    pub position_rmse: f64,
    /// Largest aligned camera-centre error (GT units).
    pub position_max: f64,
    /// Mean angle between aligned and ground-truth camera orientations (degrees).
    pub rotation_error_mean_deg: f64,
    /// Spacing of consecutive matched camera centres after alignment (GT units).
    pub spacing: Option<Stats>,
    /// Spacing of the same images' ground-truth positions.
    pub gt_spacing: Option<Stats>,
}

/// What `eval` reports.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// The model folder evaluated.
    pub model: PathBuf,
    /// How the model was stored (.bin or .txt).
    pub format: Format,
    /// Models found (1 for a single model folder).
    pub models: usize,
    /// Images selected (exported), when known.
    pub selected: Option<usize>,
    /// Registered images in the evaluated model.
    pub registered: usize,
    /// registered / selected.
    pub registered_ratio: Option<f64>,
    /// Points in the evaluated model.
    pub points3d: usize,
    /// Mean of the points' reprojection errors (px).
    pub mean_reprojection_error: Option<f64>,
    /// Mean number of observations per point.
    pub mean_track_length: Option<f64>,
    /// Spacing of consecutive registered camera centres in frame order (model units).
    pub spacing: Option<Stats>,
    /// Registered images in frame order: (file name, frame index when known).
    pub order: Vec<(String, Option<usize>)>,
    /// Ground-truth comparison.
    pub gt: Option<GtReport>,
    /// A georegistered workspace's aligned camera centres against the export's positions
    /// (metres); its georegistered model is the one evaluated.
    pub georegistration: Option<cm::georegister::Residuals>,
}

/// Where the model, the manifest and the selected count come from.
struct Resolved {
    model_dir: PathBuf,
    models: usize,
    export: Option<PathBuf>,
    selected_from_workspace: Option<usize>,
    /// The workspace, when the model is its georegistered one.
    georegistered: Option<PathBuf>,
}

fn resolve(path: &Path) -> Result<Resolved> {
    if model::detect(path).is_some() {
        return Ok(Resolved {
            model_dir: path.to_path_buf(),
            models: 1,
            export: None,
            selected_from_workspace: None,
            georegistered: None,
        });
    }
    let (root, export, selected) = if path.join(cm::RECORD).is_file() {
        let rec = cm::read_record(path)?;
        (path.join("sparse"), Some(rec.export), Some(rec.images))
    } else {
        (path.to_path_buf(), None, None)
    };
    if !root.is_dir() {
        let msg = "no sparse model here (run `keyframer colmap --sparse`)";
        return Err(Error::input(root, msg));
    }
    let dirs = model::model_dirs(&root)?;
    // The largest model by registered images; reading images.* is enough to count them.
    let mut best: Option<(usize, PathBuf)> = None;
    for d in &dirs {
        let (m, _) = model::read(d)?;
        if best.as_ref().is_none_or(|(n, _)| m.images.len() > *n) {
            best = Some((m.images.len(), d.clone()));
        }
    }
    let (_, model_dir) = best.ok_or_else(|| {
        Error::input(
            path,
            "not a COLMAP model, a sparse/ folder of models or a keyframer colmap workspace",
        )
    })?;
    // A georegistered workspace: the same model in ENU metres.
    let geo = path.join(cm::georegister::GEOREGISTERED);
    let georegistered =
        (export.is_some() && model::detect(&geo).is_some()).then(|| path.to_path_buf());
    Ok(Resolved {
        model_dir: if georegistered.is_some() {
            geo
        } else {
            model_dir
        },
        models: dirs.len(),
        export,
        selected_from_workspace: selected,
        georegistered,
    })
}

/// Whether `model` (anything [`evaluate`] accepts) resolves to a workspace's georegistered model
/// (ENU metres: x east, y north, z up).
pub fn is_georegistered(model: &Path) -> bool {
    resolve(model).is_ok_and(|r| r.georegistered.is_some())
}

/// Evaluates the model at `a.model`.
pub fn evaluate(a: &EvalSettings) -> Result<Report> {
    let r = resolve(&a.model)?;
    let (m, format) = model::read(&r.model_dir)?;
    let export = a.export.clone().or(r.export);
    let manifest = export.as_deref().map(read_manifest).transpose()?;
    let selected = manifest
        .as_ref()
        .map(|m| m.frames.len())
        .or(r.selected_from_workspace);
    let ordered = order_images(&m, manifest.as_ref(), export.as_deref())?;
    let centres: Vec<Vec3> = ordered.iter().map(|o| o.centre).collect();
    let registered = m.images.len();
    let gt = a.gt.as_deref().map(|p| compare_gt(p, &ordered));
    let georegistration = match (&r.georegistered, &manifest) {
        (Some(ws), Some(man)) => cm::georegister::evaluate(ws, man)?,
        _ => None,
    };
    Ok(Report {
        model: r.model_dir,
        format,
        models: r.models,
        selected,
        registered,
        registered_ratio: selected
            .filter(|&s| s > 0)
            .map(|s| registered as f64 / s as f64),
        points3d: m.points.len(),
        mean_reprojection_error: m.point_mean(|p| p.error),
        mean_track_length: m.point_mean(|p| p.track.len() as f64),
        spacing: stats(&spacings(&centres)),
        order: ordered.iter().map(|o| (o.name.clone(), o.index)).collect(),
        gt: gt.transpose()?,
        georegistration,
    })
}

/// What [`camera_centres`] reads: the model at `model` (folder, `sparse/` root or workspace)
/// and the export that numbers its images (`export`, else the one a workspace records).
pub fn model_inputs(model: &Path, export: Option<&Path>) -> Inputs {
    let mut inputs = Inputs::none().with("COLMAP model", model);
    let recorded = || {
        let workspace = model.join(cm::RECORD).is_file();
        workspace.then(|| cm::read_record(model).ok()).flatten()
    };
    let export = export
        .map(Path::to_path_buf)
        .or_else(|| recorded().map(|r| r.export));
    if let Some(e) = export {
        crate::manifest::add_export(&mut inputs, &e);
    }
    inputs
}

/// Registered camera centres with their frame index (from the export's manifest), in frame
/// order, for the largest model at `model` (anything [`evaluate`] accepts).
pub fn camera_centres(model: &Path, export: Option<&Path>) -> Result<Vec<(usize, Vec3)>> {
    let r = resolve(model)?;
    let (m, _) = model::read(&r.model_dir)?;
    let export = export.map(Path::to_path_buf).or(r.export);
    let manifest = export.as_deref().map(read_manifest).transpose()?;
    let ordered = order_images(&m, manifest.as_ref(), export.as_deref())?;
    ordered
        .iter()
        .map(|o| {
            o.index.map(|i| (i, o.centre)).ok_or_else(|| {
                Error::input(
                    model,
                    "the model's images need the export's manifest for their frame numbers (--export)",
                )
            })
        })
        .collect()
}

/// A registered image with what the manifest knows about it.
struct Ordered {
    name: String,
    index: Option<usize>,
    timestamp: Option<f64>,
    centre: Vec3,
    cam_to_world: align::Mat3,
}

/// Registered images in frame order (manifest frame index; file name without a manifest).
fn order_images(
    m: &Model,
    manifest: Option<&Manifest>,
    export: Option<&Path>,
) -> Result<Vec<Ordered>> {
    let mut out = Vec::with_capacity(m.images.len());
    for im in m.images.values() {
        let frame = manifest
            .map(|man| {
                man.frames
                    .iter()
                    .find(|f| f.rel() == Path::new(&im.name))
                    .ok_or_else(|| {
                        let msg = format!(
                            "image {} of the model is not in the export's manifest",
                            im.name
                        );
                        Error::input(export.unwrap_or(Path::new(".")), msg)
                    })
            })
            .transpose()?;
        out.push(Ordered {
            name: im.name.clone(),
            index: frame.map(|f| f.index),
            timestamp: frame.and_then(|f| f.timestamp_s),
            centre: im.centre(),
            cam_to_world: im.cam_to_world(),
        });
    }
    out.sort_by(|a, b| a.index.cmp(&b.index).then_with(|| a.name.cmp(&b.name)));
    Ok(out)
}

/// Matches registered images to ground-truth poses (nearest timestamp within half the median GT
/// interval; without a timestamp, frame index × interval after the first GT time), aligns the
/// camera centres with Umeyama's Sim(3) and measures the residuals.
fn compare_gt(path: &Path, ordered: &[Ordered]) -> Result<GtReport> {
    let gt = read_tum(path)?;
    let mut diffs: Vec<f64> = gt.windows(2).map(|w| w[1].t - w[0].t).collect();
    diffs.sort_by(f64::total_cmp);
    let dt = if diffs.is_empty() {
        0.0
    } else {
        quantile(&diffs, 0.5)
    };
    let mut by_index = false;
    let mut pairs: Vec<(&Ordered, &GtPose)> = Vec::new();
    for o in ordered {
        let t = match (o.timestamp, o.index) {
            (Some(t), _) => t,
            (None, Some(i)) if dt > 0.0 => {
                by_index = true;
                gt[0].t + i as f64 * dt
            }
            _ => continue,
        };
        let k = gt.partition_point(|g| g.t < t);
        let best = [k.checked_sub(1), Some(k)]
            .into_iter()
            .flatten()
            .filter_map(|i| gt.get(i))
            .min_by(|a, b| (a.t - t).abs().total_cmp(&(b.t - t).abs()));
        if let Some(g) = best {
            if (g.t - t).abs() <= 0.5 * dt + 1e-9 || (gt.len() == 1 && g.t == t) {
                pairs.push((o, g));
            }
        }
    }
    let src: Vec<Vec3> = pairs.iter().map(|(o, _)| o.centre).collect();
    let dst: Vec<Vec3> = pairs.iter().map(|(_, g)| g.position).collect();
    let sim = align::umeyama(&src, &dst).ok_or_else(|| {
        Error::input(
            path,
            format!(
                "{} registered images matched a ground-truth pose (by frame timestamp within half a frame interval); \
                 a similarity alignment needs at least 3 that are not all at one place",
                pairs.len()
            ),
        )
    })?;
    let aligned: Vec<Vec3> = src.iter().map(|c| sim.apply(c)).collect();
    let errors: Vec<f64> = aligned
        .iter()
        .zip(&dst)
        .map(|(a, g)| align::dist(a, g))
        .collect();
    let n = errors.len() as f64;
    let rot_errors: Vec<f64> = pairs
        .iter()
        .map(|(o, g)| {
            let est = align::mul(&sim.rotation, &o.cam_to_world);
            let gt_r = align::quat_to_mat(g.q);
            align::rotation_angle_deg(&align::mul(&align::transpose(&gt_r), &est))
        })
        .collect();
    Ok(GtReport {
        file: path.to_path_buf(),
        matched: pairs.len(),
        matched_by: if by_index { "index" } else { "timestamp" }.into(),
        scale: sim.scale,
        position_rmse: (errors.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
        position_max: errors.iter().copied().fold(0.0, f64::max),
        rotation_error_mean_deg: rot_errors.iter().sum::<f64>() / n,
        spacing: stats(&spacings(&aligned)),
        gt_spacing: stats(&spacings(&dst)),
    })
}

fn fmt_stats(s: &Option<Stats>) -> String {
    match s {
        Some(s) => format!(
            "mean {:.6}  σ {:.6}  Q0.1 {:.6}  Q0.9 {:.6}  (n={})",
            s.mean, s.std, s.q10, s.q90, s.count
        ),
        None => "- (fewer than 2 registered images)".into(),
    }
}

/// The report as a table.
pub fn render(r: &Report) -> String {
    let opt = |v: Option<f64>, unit: &str| {
        v.map(|x| format!("{x:.4}{unit}"))
            .unwrap_or_else(|| "-".into())
    };
    let mut s = format!(
        "model:                 {} ({:?})\nmodels:                {}\nselected images:       {}\nregistered images:     {}{}\n3D points:             {}\nmean reprojection err: {}\nmean track length:     {}\nspacing (model units): {}\n",
        r.model.display(),
        r.format,
        r.models,
        r.selected.map(|v| v.to_string()).unwrap_or_else(|| "unknown (give --export)".into()),
        r.registered,
        r.registered_ratio
            .map(|x| format!(" ({:.1} % of selected)", 100.0 * x))
            .unwrap_or_default(),
        r.points3d,
        opt(r.mean_reprojection_error, " px"),
        opt(r.mean_track_length, ""),
        fmt_stats(&r.spacing),
    );
    if let Some(g) = &r.gt {
        s += &format!(
            "ground truth:          {} ({} images matched by {})\nsim(3) scale:          {:.6}\nposition RMSE (ATE):   {:.6} (max {:.6})\nrotation error mean:   {:.4} deg\nspacing (GT units):    {}\nGT spacing:            {}\n",
            g.file.display(),
            g.matched,
            g.matched_by,
            g.scale,
            g.position_rmse,
            g.position_max,
            g.rotation_error_mean_deg,
            fmt_stats(&g.spacing),
            fmt_stats(&g.gt_spacing),
        );
    }
    if let Some(g) = &r.georegistration {
        s += &format!(
            "georegistered:         model in ENU metres (x east, y north, z up): spacing above is in metres
             residual to positions: {} images, mean {:.3} m, median {:.3} m, RMS {:.3} m, max {:.3} m
",
            g.images, g.mean_m, g.median_m, g.rms_m, g.max_m
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_interpolate_linearly() {
        let v = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0];
        assert_eq!(quantile(&v, 0.1), 2.0);
        assert_eq!(quantile(&v, 0.9), 10.0);
        let v = [0.0, 10.0];
        assert!((quantile(&v, 0.1) - 1.0).abs() < 1e-12);
        let s = stats(&[2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0]).expect("non-empty");
        assert_eq!((s.mean, s.std), (5.0, 2.0));
    }
}
