//! Runs a network through OpenCV DNN (any format `cv::dnn::readNet` reads) on the CPU.

use super::desc::ModelDesc;
use super::tensor::{mismatch, Output};
use crate::error::{CvContext, Error, Result};
use opencv::core::{Mat, Scalar};
use opencv::dnn;
use opencv::prelude::*;

/// An OpenCV DNN network ready to run.
pub struct DnnRunner {
    net: dnn::Net,
    input: String,
    output: String,
}

impl DnnRunner {
    /// Loads the network named by `desc`.
    pub fn load(desc: &ModelDesc) -> Result<DnnRunner> {
        let model = desc.model.to_string_lossy().into_owned();
        let config = desc
            .config
            .as_ref()
            .map(|c| c.to_string_lossy().into_owned())
            .unwrap_or_default();
        let mut net =
            dnn::read_net(&model, &config, desc.framework.opencv_name()).map_err(|e| {
                Error::input(
                    &desc.model,
                    format!(
                        "OpenCV DNN cannot read it as a {} model: {}",
                        desc.framework.opencv_name(),
                        e.message
                    ),
                )
            })?;
        if net.empty().cv(|| "Net::empty".into())? {
            let msg = "OpenCV DNN read an empty network";
            return Err(Error::input(&desc.model, msg));
        }
        net.set_preferable_backend(dnn::DNN_BACKEND_OPENCV)
            .cv(|| "setPreferableBackend".into())?;
        net.set_preferable_target(dnn::DNN_TARGET_CPU)
            .cv(|| "setPreferableTarget".into())?;
        let output = match &desc.output.name {
            Some(n) => n.clone(),
            None => net
                .get_unconnected_out_layers_names()
                .cv(|| "getUnconnectedOutLayersNames".into())?
                .get(0)
                .unwrap_or_default(),
        };
        Ok(DnnRunner {
            net,
            input: desc.input.name.clone().unwrap_or_default(),
            output,
        })
    }

    /// Runs the network on an input tensor of `shape`; returns the output's shape and values.
    pub fn run(&mut self, desc: &ModelDesc, shape: &[usize; 4], data: &[f32]) -> Result<Output> {
        let dims: Vec<i32> = shape.iter().map(|&d| d as i32).collect();
        let blob = Mat::new_nd_with_data(&dims, data).cv(|| "input tensor".into())?;
        self.net
            .set_input(&blob, &self.input, 1.0, Scalar::default())
            .cv(|| format!("setInput `{}`", self.input))?;
        let out: Mat = self.net.forward_single(&self.output).map_err(|e| {
            mismatch(
                desc,
                format!("OpenCV DNN failed on a {shape:?} input: {}", e.message),
            )
        })?;
        let oshape: Vec<usize> = out.mat_size().iter().map(|&d| d as usize).collect();
        let out = if out.is_continuous() {
            out
        } else {
            out.try_clone().cv(|| "output copy".into())?
        };
        let values = out
            .data_typed::<f32>()
            .map_err(|e| mismatch(desc, format!("output is not float: {}", e.message)))?
            .to_vec();
        Ok((oshape, values))
    }
}
