//! The horizon views an equirectangular frame is measured on (`MovementRequest::sphere`): their
//! remap tables from the analysis-size ERP frame and the joint rotation fit over them. Both
//! backends render the views through these tables (`kernels::remap`, bit-identical) and fit with
//! the same [`SphereField`].

use crate::equirect::{analysis_views, View};
use crate::error::Result;
use crate::kernels::remap::Table;
use crate::kernels::sphere::SphereField;
use crate::params::SphereViews;

/// The views of an ERP frame of the analysis size, their tables and their joint fit.
pub(crate) struct Sphere {
    /// The views, in the order their flows are stacked.
    pub views: Vec<View>,
    /// Each view's remap table from the analysis-size ERP frame.
    pub tables: Vec<Table>,
    /// The joint rotation fit over the stacked flows.
    pub field: SphereField,
}

impl Sphere {
    /// The views `req` asks for, rendered from ERP frames of `erp` (width, height) pixels.
    pub(crate) fn new(req: SphereViews, erp: (u32, u32)) -> Result<Sphere> {
        req.validate()?;
        let views = analysis_views(req.views, req.fov_deg, erp.0);
        let tables = Table::of_views(&views, erp)?;
        let field = SphereField::new(&views)?;
        Ok(Sphere {
            views,
            tables,
            field,
        })
    }

    /// Width (= height) of every view in pixels.
    pub(crate) fn size(&self) -> u32 {
        self.views.first().map_or(0, |v| v.size)
    }
}
