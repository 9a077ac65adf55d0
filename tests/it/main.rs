//! Integration tests: one binary, one module per capability.

mod blur;
mod common;
mod flow;
mod foundation;
mod movement;
mod sharpness;
