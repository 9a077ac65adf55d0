//! Integration tests: one binary, one module per capability.

mod common;
mod foundation;
mod sharpness;
