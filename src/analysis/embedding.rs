//! The built-in descriptor of every frame (the similarity step's embedding), on the analysis
//! thread as frames arrive: the frame resized to the analysis size on the CPU (the same call for
//! both backends), its totals on the device or by the OpenCV twin (equal integers), normalised
//! and quantised on the host. One small read-back per frame; nothing is kept: the caller appends
//! each frame's vector to the series file. With a network (`segment::embedding`), the frame goes
//! through it on the CPU instead (OpenCV DNN or ONNX Runtime).

use crate::error::Result;
use crate::gpu::GpuContext;
use crate::kernels::descriptor::{self, DescriptorGpu};
use crate::manifest::SegRuntime;
use crate::params::Backend;
use crate::segment::embedding::Network;
use crate::steps::similarity;
use opencv::core::Mat;
use std::sync::Arc;

/// The descriptor of frames described at one size, on one backend.
pub(crate) struct EmbeddingPass {
    /// The analysis size (width, height).
    pub size: (u32, u32),
    gpu: Option<DescriptorGpu>,
    network: Option<Network>,
}

impl EmbeddingPass {
    /// The pass at `size` (width, height) on `backend` (the device when it is gpu and `ctx` is
    /// given).
    pub(crate) fn open(
        size: (u32, u32),
        backend: Backend,
        ctx: Option<&Arc<GpuContext>>,
    ) -> Result<EmbeddingPass> {
        let gpu = match (backend, ctx) {
            (Backend::Gpu, Some(c)) => Some(DescriptorGpu::new(c.clone(), size)?),
            _ => None,
        };
        Ok(EmbeddingPass {
            size,
            gpu,
            network: None,
        })
    }

    /// The pass through the embedding network at `model` (a description or an ONNX file) on
    /// `runtime`.
    pub(crate) fn network(model: &std::path::Path, runtime: SegRuntime) -> Result<EmbeddingPass> {
        let net = Network::load(model, runtime)?;
        Ok(EmbeddingPass {
            size: net.size(),
            gpu: None,
            network: Some(net),
        })
    }

    /// The backend its totals come from.
    pub(crate) fn backend(&self) -> Backend {
        match self.gpu {
            Some(_) => Backend::Gpu,
            None => Backend::Opencv,
        }
    }

    /// The runtime of its network, when it has one.
    pub(crate) fn runtime(&self) -> Option<SegRuntime> {
        self.network.as_ref().map(Network::runtime)
    }

    /// The quantised embedding of one decoded frame (8-bit BGR at the input's size).
    pub(crate) fn frame(&mut self, image: &Mat) -> Result<Vec<i16>> {
        if let Some(net) = self.network.as_mut() {
            return Ok(similarity::quantise(&net.embed(image)?));
        }
        let small = descriptor::prepare(image, self.size)?;
        let totals = match self.gpu.as_mut() {
            Some(g) => g.totals(&small)?,
            None => descriptor::opencv(&small)?,
        };
        Ok(similarity::quantise(&descriptor::embedding(
            &totals, self.size,
        )))
    }
}
