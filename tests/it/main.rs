//! Integration tests: one binary, one module per capability.

mod batch;
mod blur;
mod browser;
mod cdp;
mod checks;
mod colmap;
mod common;
mod experiment;
mod fixtures;
mod flow;
mod foundation;
mod geotag;
mod inputs;
mod layers;
mod movement;
mod onnx_model;
mod pipeline;
mod preview;
mod read_inputs;
mod report;
mod review;
mod safety;
mod scene;
mod segment;
mod sharpness;
mod telemetry;
