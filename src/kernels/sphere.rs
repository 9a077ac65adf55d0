//! `sphere`: the joint rotation fit over several pinhole views of one 360° frame. A turn of the
//! camera is one rotation of the sphere; fitting it to every view's flow together (and not one
//! rotation per view, which would also take a sideways view's translation for a pan) leaves the
//! translation-induced flow of every view. The views' flows lie stacked in one buffer (view k's
//! rows after view k − 1's, every view `size` x `size`); the device runs the same fit in
//! shaders/movement.wgsl (`consts.views`), this is its host twin.
//!
//! The rotation field of view k for a sphere rotation ω is view k's field of `Vkᵀ ω` (`Vk`: view
//! frame → sphere frame), so the normal equations add up: `A = Σ Vk Ak Vkᵀ`, `b = Σ Vk bk`, with
//! `Ak` the (shared) normal matrix of one view's grid and `bk` view k's sums.

use super::movement::{invert3, matrix, Rotation, RotationField, IDENTITY};
use crate::equirect::View;
use crate::error::{Error, Result};
use crate::params::Derotate;

/// The residual clamps (view pixels) of the refinements after the least-squares start. Flow
/// fails where a view is flat or where content enters it, and such pixels pull a least-squares
/// fit towards no rotation: on a yaw of 2.25° / 4.5° rendered from a photograph (320 x 160 ERP,
/// four 90° views of 102 px, OpenCV's Farneback) the least-squares fit leaves a median residual
/// of 0.38 / 0.81 px, these clamps 0.26 / 0.44 px; the true rotation itself leaves 0.19 / 0.38
/// px (the flow's own error).
pub const CLAMPS_PX: [f32; 6] = [4.0, 2.0, 1.0, 1.0, 1.0, 1.0];

/// Most views the device fit takes (the shader's uniform holds this many rotations).
pub const MAX_VIEWS: usize = 8;

/// The joint fit of one sphere rotation to the stacked flows of `views` square views.
#[derive(Debug, Clone)]
pub struct SphereField {
    /// One view's grid (every view has the same size and field of view).
    field: RotationField,
    size: u32,
    /// Per view: rotation from the view's frame to the sphere's, rows in f32.
    rotations: Vec<Rotation>,
    /// Inverse of `Σ Vk A Vkᵀ`.
    inverse: [[f64; 3]; 3],
}

impl SphereField {
    /// The fit over `views` (all of one size and field of view; 1 to [`MAX_VIEWS`]).
    pub fn new(views: &[View]) -> Result<SphereField> {
        let first = views
            .first()
            .ok_or_else(|| Error::param("views", "the sphere fit needs at least one view"))?;
        if views.len() > MAX_VIEWS {
            let msg = format!("{} views (at most {MAX_VIEWS})", views.len());
            return Err(Error::param("views", msg));
        }
        if let Some(v) = views
            .iter()
            .find(|v| v.size != first.size || v.fov_deg != first.fov_deg)
        {
            let msg = format!("view `{}` differs in size or field of view", v.name);
            return Err(Error::param("views", msg));
        }
        let derotate = Derotate {
            hfov_deg: first.fov_deg,
        };
        let field = RotationField::new(first.size, first.size, derotate)?;
        let a = field.normal();
        let mut sum = [[0.0f64; 3]; 3];
        let mut rotations = Vec::with_capacity(views.len());
        for v in views {
            let r = v.rotation();
            // Vk A Vkᵀ
            for (i, row) in sum.iter_mut().enumerate() {
                for (j, s) in row.iter_mut().enumerate() {
                    for (k, ak) in a.iter().enumerate() {
                        for (l, akl) in ak.iter().enumerate() {
                            *s += r[i][k] * akl * r[j][l];
                        }
                    }
                }
            }
            rotations.push(r.map(|row| row.map(|x| x as f32)));
        }
        let inverse = invert3(&sum)
            .ok_or_else(|| Error::param("views", "the joint rotation fit is singular"))?;
        Ok(SphereField {
            field,
            size: first.size,
            rotations,
            inverse,
        })
    }

    /// Number of views.
    pub fn views(&self) -> usize {
        self.rotations.len()
    }

    /// One view's grid.
    pub fn field(&self) -> &RotationField {
        &self.field
    }

    /// View k's rotation (view frame → sphere frame), rows in f32.
    pub fn rotation(&self, k: usize) -> Rotation {
        self.rotations[k]
    }

    /// Inverse of the joint normal matrix.
    pub fn inverse(&self) -> [[f64; 3]; 3] {
        self.inverse
    }

    /// The sphere rotation `r` seen from view k: `Vkᵀ r Vk` (f32, as the shader's `solve`).
    pub fn view_rotation(&self, k: usize, r: &Rotation) -> Rotation {
        let v = &self.rotations[k];
        let rv: Rotation = std::array::from_fn(|i| {
            std::array::from_fn(|j| (0..3).map(|l| r[i][l] * v[l][j]).sum())
        });
        std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|l| v[l][i] * rv[l][j]).sum()))
    }

    /// View k's part of a stacked flow.
    fn part<'a>(&self, flow: &'a [f32], k: usize) -> Result<&'a [f32]> {
        let n = 2 * (self.size as usize) * (self.size as usize);
        if flow.len() != n * self.views() {
            let msg = format!(
                "a stacked flow of {} views of {}x{} needs {} values, got {}",
                self.views(),
                self.size,
                self.size,
                n * self.views(),
                flow.len()
            );
            return Err(Error::param("derotate", msg));
        }
        Ok(&flow[k * n..(k + 1) * n])
    }

    /// Σ Vk bk: every view's sums of e · (flow − rotation flow of `r`) / f, in the sphere frame.
    pub fn sums(&self, flow: &[f32], r: &Rotation) -> Result<[f64; 3]> {
        let mut b = [0.0f64; 3];
        for k in 0..self.views() {
            let bk = self
                .field
                .sums(self.part(flow, k)?, &self.view_rotation(k, r))?;
            let v = &self.rotations[k];
            for (i, bi) in b.iter_mut().enumerate() {
                *bi += (0..3).map(|l| f64::from(v[i][l]) * bk[l]).sum::<f64>();
            }
        }
        Ok(b)
    }

    /// [`SphereField::sums`] with residuals clamped to `clamp` pixels.
    pub fn sums_within(&self, flow: &[f32], r: &Rotation, clamp: f32) -> Result<[f64; 3]> {
        let mut b = [0.0f64; 3];
        for k in 0..self.views() {
            let bk =
                (self.field).sums_within(self.part(flow, k)?, &self.view_rotation(k, r), clamp)?;
            let v = &self.rotations[k];
            for (i, bi) in b.iter_mut().enumerate() {
                *bi += (0..3).map(|l| f64::from(v[i][l]) * bk[l]).sum::<f64>();
            }
        }
        Ok(b)
    }

    fn solve(&self, b: [f64; 3]) -> [f64; 3] {
        let r = &self.inverse;
        std::array::from_fn(|k| r[k][0] * b[0] + r[k][1] * b[1] + r[k][2] * b[2])
    }

    /// The sphere rotation fitted to a stacked flow: a linear least-squares fit, then one
    /// Gauss-Newton step per clamp of [`CLAMPS_PX`] on the modified residuals (Huber's
    /// iteration with the normal matrix kept).
    pub fn fit_cpu(&self, flow: &[f32]) -> Result<Rotation> {
        let mut omega = self.solve(self.sums(flow, &IDENTITY)?);
        for &clamp in &CLAMPS_PX {
            let step = self.solve(self.sums_within(flow, &matrix(omega), clamp)?);
            for (o, d) in omega.iter_mut().zip(step) {
                *o += d;
            }
        }
        Ok(matrix(omega))
    }

    /// |flow − rotation flow| per pixel of every view, view after view, for the sphere
    /// rotation `r`.
    pub fn residual_magnitudes(&self, flow: &[f32], r: &Rotation) -> Result<Vec<f32>> {
        let mut out = Vec::with_capacity(flow.len() / 2);
        for k in 0..self.views() {
            let part = self.part(flow, k)?;
            out.extend(
                self.field
                    .residual_magnitudes(part, &self.view_rotation(k, r))?,
            );
        }
        Ok(out)
    }

    /// The residual magnitudes after the joint fit.
    pub fn derotated(&self, flow: &[f32]) -> Result<Vec<f32>> {
        let r = self.fit_cpu(flow)?;
        self.residual_magnitudes(flow, &r)
    }
}

#[cfg(test)]
mod tests;
