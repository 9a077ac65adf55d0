//! Export of a 360° project as a camera rig: the pinhole views of each ERP frame rendered through
//! tables computed once (`kernels::remap`, on the device when `auto` picks the gpu, else its
//! OpenCV twin), their nadir masks, and COLMAP rig_configurator's `rig_config.json`.

use crate::equirect::{cam_from_rig, nadir_mask, Projection, View};
use crate::error::{CvContext, Result};
use crate::kernels::remap::{opencv as cv_remap, Interp, RemapGpu, Table};
use crate::manifest::ViewSettings;
use opencv::core::Mat;
use opencv::prelude::*;

/// The record of a rig export beside `manifest.json` (COLMAP rig_configurator's input).
pub const RIG_CONFIG: &str = "rig_config.json";

/// The checked views of `settings` for a project of `projection`: refuses views on a pinhole
/// project ([`ViewSettings::check_projection`]) and settings [`ViewSettings::check`] refuses (sizes the
/// encoders cannot write: `max_side`, `max_pixels`), before anything is written. Empty for
/// `equirect` (the frames are exported unchanged).
pub fn views_of(
    settings: &ViewSettings,
    projection: Projection,
    limits: (u32, u64),
) -> Result<Vec<View>> {
    ViewSettings::check_projection(projection)?;
    let set = settings.check(limits)?;
    Ok(set.views(settings.fov_deg, settings.size))
}

enum Backend {
    Gpu(RemapGpu),
    Opencv(Vec<Table>),
}

/// Renders the views of one ERP size.
pub struct Rig {
    /// The views, in folder order.
    pub views: Vec<View>,
    /// Per view, its nadir mask (0 hidden, 255 kept) when it sees the cap.
    pub nadir: Vec<Option<Mat>>,
    interp: Interp,
    backend: Backend,
}

impl Rig {
    /// The rig of `views` from `erp`-sized BGR frames: tables computed once, the device used
    /// when `auto` would pick it (a hardware adapter).
    pub fn new(views: Vec<View>, erp: (u32, u32), settings: &ViewSettings) -> Result<Rig> {
        let tables = Table::of_views(&views, erp)?;
        let nadir = views
            .iter()
            .map(|v| {
                let Some(cap) = settings.mask_nadir_deg else {
                    return Ok(None);
                };
                nadir_mask(v, cap)
                    .map(|m| {
                        Mat::from_slice(&m)
                            .and_then(|m| m.reshape(1, v.size as i32)?.try_clone())
                            .cv(|| "nadir mask".into())
                    })
                    .transpose()
            })
            .collect::<Result<Vec<_>>>()?;
        let auto = crate::gpu::auto_backend(None);
        let backend = match auto.backend {
            crate::params::Backend::Gpu => {
                let gpu = crate::gpu::GpuContext::new(None)
                    .map(std::sync::Arc::new)
                    .and_then(|ctx| RemapGpu::new(ctx, erp, 3, settings.interp, &tables));
                match gpu {
                    Ok(g) => Backend::Gpu(g),
                    Err(e) => {
                        log::warn!("views: the device remap failed ({e}); using OpenCV's");
                        Backend::Opencv(tables)
                    }
                }
            }
            crate::params::Backend::Opencv => Backend::Opencv(tables),
        };
        Ok(Rig {
            views,
            nadir,
            interp: settings.interp,
            backend,
        })
    }

    /// The views of one BGR frame, in folder order.
    pub fn render(&self, frame: &Mat) -> Result<Vec<Mat>> {
        match &self.backend {
            Backend::Gpu(g) => g.render(frame),
            Backend::Opencv(t) => t.iter().map(|t| cv_remap(frame, t, self.interp)).collect(),
        }
    }
}

/// rig_configurator's configuration of `views` as one rig: the first view is the reference
/// sensor, every other has its rotation relative to it (`cam_from_rig_rotation`, w x y z) and no
/// translation (the views share the ERP's centre).
pub fn rig_config(views: &[View]) -> serde_json::Value {
    let Some(reference) = views.first() else {
        return serde_json::json!([]);
    };
    let cameras: Vec<serde_json::Value> = views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let prefix = format!("{}/", v.name);
            if i == 0 {
                serde_json::json!({"image_prefix": prefix, "ref_sensor": true})
            } else {
                serde_json::json!({
                    "image_prefix": prefix,
                    "cam_from_rig_rotation": cam_from_rig(v, reference),
                    "cam_from_rig_translation": [0.0, 0.0, 0.0],
                })
            }
        })
        .collect();
    serde_json::json!([{ "cameras": cameras }])
}

/// Applies the nadir mask `nadir` to a person mask `mask` of the same size (hidden where either
/// hides).
pub fn combine(mask: &Mat, nadir: &Mat) -> Result<Mat> {
    let mut out = Mat::default();
    opencv::core::bitwise_and(mask, nadir, &mut out, &opencv::core::no_array())
        .cv(|| "nadir mask".into())?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::equirect::ViewSet;

    fn settings(set: &str, size: u32) -> ViewSettings {
        ViewSettings {
            set: set.into(),
            fov_deg: 90.0,
            size,
            mask_nadir_deg: Some(30.0),
            interp: Interp::Bilinear,
        }
    }

    #[test]
    fn refusals_come_first() {
        let limits = (65_500, 1 << 30);
        let e = views_of(&settings("cube", 512), Projection::Pinhole, limits).unwrap_err();
        assert!(e.to_string().contains("--projection equirect"), "{e}");
        let e = views_of(&settings("cube", 70_000), Projection::Equirect, limits).unwrap_err();
        assert!(e.to_string().contains("--view-size"), "{e}");
        let e = views_of(&settings("cube", 40_000), Projection::Equirect, limits).unwrap_err();
        assert!(e.to_string().contains("pixels"), "{e}");
        assert_eq!(
            views_of(&settings("cube", 512), Projection::Equirect, limits)
                .unwrap()
                .len(),
            6
        );
        assert!(
            views_of(&settings("equirect", 512), Projection::Equirect, limits)
                .unwrap()
                .is_empty()
        );
    }

    #[test]
    fn rig_config_names_every_view_relative_to_the_first() {
        let views = ViewSet::Cube.views(90.0, 64);
        let c = rig_config(&views);
        let cams = c[0]["cameras"].as_array().unwrap();
        assert_eq!(cams.len(), 6);
        assert_eq!(cams[0]["image_prefix"], "front/");
        assert_eq!(cams[0]["ref_sensor"], true);
        assert_eq!(cams[2]["image_prefix"], "back/");
        let q: Vec<f64> = serde_json::from_value(cams[2]["cam_from_rig_rotation"].clone()).unwrap();
        // `back`: a half turn about y.
        assert!(
            q[0].abs() < 1e-9 && (q[2].abs() - 1.0).abs() < 1e-9,
            "{q:?}"
        );
    }
}
