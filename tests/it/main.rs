//! Integration tests: one binary, one module per capability.

mod blur;
mod common;
mod foundation;
mod sharpness;
