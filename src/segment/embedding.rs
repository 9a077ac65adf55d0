//! An image-embedding network for the similarity step, named as iVS3D names them
//! (`ImageEmbedding_<NAME>_<DIM>_<W>x<H>.onnx`), run through OpenCV DNN on the CPU. [`check`]
//! refuses, before any frame is decoded, a model whose declared input is not one 3-channel
//! W x H image (NCHW) or whose output does not hold DIM values, naming the file. Each frame is
//! resized to W x H (INTER_AREA), taken to RGB in [0, 1] and normalised with ImageNet's mean and
//! standard deviation, as iVS3D feeds these networks.

use super::onnx::{self, Dim};
use crate::error::{CvContext, Error, Result};
use crate::steps::similarity::{model_name, ModelName};
use opencv::core::{Mat, Scalar, Size, Vec3b};
use opencv::dnn;
use opencv::imgproc;
use opencv::prelude::*;
use std::path::{Path, PathBuf};

/// ImageNet's per-channel mean (R, G, B).
pub const MEAN: [f32; 3] = [0.485, 0.456, 0.406];
/// ImageNet's per-channel standard deviation (R, G, B).
pub const STD: [f32; 3] = [0.229, 0.224, 0.225];

/// Checks the model at `path` against its name without running it: the name follows iVS3D's
/// naming, the graph's one input is [1 or dynamic, 3, H, W] and its first output holds DIM
/// values after the batch. Returns what the name says.
pub fn check(path: &Path) -> Result<ModelName> {
    let name = model_name(path)?;
    let sig = onnx::signature(path)?;
    let bad = |msg: String| Error::input(path, msg);
    let fixed = |d: &Dim| match d {
        Dim::Fixed(v) => Some(*v),
        Dim::Dynamic => None,
    };
    let input = &sig.inputs[0];
    let want = [3, i64::from(name.height), i64::from(name.width)];
    let dims = input.shape.clone().unwrap_or_default();
    let fits = dims.len() == 4
        && fixed(&dims[0]).is_none_or(|b| b == 1)
        && dims[1..]
            .iter()
            .zip(want)
            .all(|(d, w)| fixed(d).is_none_or(|v| v == w));
    if !fits {
        return Err(bad(format!(
            "its input `{}` is {}, and its name says [1, 3, {}, {}] (one RGB {}x{} image, NCHW)",
            input.name,
            shape_text(&dims),
            name.height,
            name.width,
            name.width,
            name.height
        )));
    }
    let output = &sig.outputs[0];
    let odims = output.shape.clone().unwrap_or_default();
    let values: Option<i64> = odims.iter().skip(1).map(fixed).product();
    if values.is_some_and(|v| v != name.dim as i64) || odims.is_empty() {
        return Err(bad(format!(
            "its output `{}` is {}, and its name says {} values per image",
            output.name,
            shape_text(&odims),
            name.dim
        )));
    }
    Ok(name)
}

fn shape_text(dims: &[Dim]) -> String {
    let d: Vec<String> = (dims.iter())
        .map(|d| match d {
            Dim::Fixed(v) => v.to_string(),
            Dim::Dynamic => "?".into(),
        })
        .collect();
    format!("[{}]", d.join(", "))
}

/// A checked embedding network ready to run.
pub struct Network {
    path: PathBuf,
    name: ModelName,
    net: dnn::Net,
    input: Vec<f32>,
}

impl Network {
    /// Checks ([`check`]) and loads the model at `path`.
    pub fn load(path: &Path) -> Result<Network> {
        let name = check(path)?;
        let file = path.to_string_lossy().into_owned();
        let mut net = dnn::read_net_from_onnx(&file)
            .map_err(|e| Error::input(path, format!("OpenCV DNN cannot read it: {}", e.message)))?;
        net.set_preferable_backend(dnn::DNN_BACKEND_OPENCV)
            .cv(|| "setPreferableBackend".into())?;
        net.set_preferable_target(dnn::DNN_TARGET_CPU)
            .cv(|| "setPreferableTarget".into())?;
        Ok(Network {
            path: path.to_path_buf(),
            name,
            net,
            input: Vec::new(),
        })
    }

    /// The input size (width, height) its name gives.
    pub fn size(&self) -> (u32, u32) {
        (self.name.width, self.name.height)
    }

    /// Values per embedding.
    pub fn dim(&self) -> usize {
        self.name.dim
    }

    /// The embedding of one 8-bit BGR frame.
    pub fn embed(&mut self, bgr: &Mat) -> Result<Vec<f64>> {
        let (w, h) = (self.name.width as i32, self.name.height as i32);
        let mut small = Mat::default();
        imgproc::resize(
            bgr,
            &mut small,
            Size::new(w, h),
            0.0,
            0.0,
            imgproc::INTER_AREA,
        )
        .cv(|| "resize to the network's input".into())?;
        let plane = (w * h) as usize;
        self.input.clear();
        self.input.resize(3 * plane, 0.0);
        for y in 0..h {
            let row = small.at_row::<Vec3b>(y).cv(|| "frame row".into())?;
            for (x, px) in row.iter().enumerate() {
                for c in 0..3 {
                    // BGR in the frame, RGB in the tensor.
                    let v = f32::from(px[2 - c]) / 255.0;
                    self.input[c * plane + y as usize * w as usize + x] = (v - MEAN[c]) / STD[c];
                }
            }
        }
        let blob =
            Mat::new_nd_with_data(&[1, 3, h, w], &self.input).cv(|| "input tensor".into())?;
        self.net
            .set_input(&blob, "", 1.0, Scalar::default())
            .cv(|| "setInput".into())?;
        let out: Mat = self.net.forward_single("").map_err(|e| {
            Error::input(
                &self.path,
                format!("OpenCV DNN failed on it: {}", e.message),
            )
        })?;
        let out = match out.is_continuous() {
            true => out,
            false => out.try_clone().cv(|| "output copy".into())?,
        };
        let values = out
            .data_typed::<f32>()
            .map_err(|e| Error::input(&self.path, format!("output is not float: {}", e.message)))?;
        if values.len() != self.name.dim {
            let msg = format!(
                "gave {} values for an image, and its name says {}",
                values.len(),
                self.name.dim
            );
            return Err(Error::input(&self.path, msg));
        }
        Ok(values.iter().map(|&v| f64::from(v)).collect())
    }
}
