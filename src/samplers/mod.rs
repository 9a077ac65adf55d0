//! Keyframe samplers: pure, deterministic functions from a candidate list (sorted frame indices)
//! and per-frame numbers to a subset of the candidates. They never touch pixels.

pub mod auto;
pub mod blur;
mod boundaries;
mod every_nth;
mod fps;
mod manual;
pub mod spacing;
mod stationary;

pub use blur::{blur, BlurMode, BlurParams};
pub use boundaries::{Bound, Boundaries};
pub use every_nth::every_nth;
pub use fps::fps;
pub use manual::manual;
pub use spacing::{spacing, spacing_for_count};
pub use stationary::Stationary;
