//! `reduce`: exact 64-bit totals of per-workgroup u32 partials (shaders/reduce.wgsl). The OpenCV
//! twin is the double accumulation inside cv::mean / cv::meanStdDev; `cpu` sums the same partials.

use bytemuck::{Pod, Zeroable};

/// WGSL source.
pub const WGSL: &str = include_str!("../../shaders/reduce.wgsl");

/// Uniform parameters of reduce.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct ReduceParams {
    /// Number of records.
    pub count: u32,
    /// u32 words per record (quantities).
    pub stride: u32,
    /// Unused (16-byte uniform alignment).
    pub pad0: u32,
    /// Unused.
    pub pad1: u32,
}

/// CPU twin: totals of each quantity of `stride`-word records.
pub fn cpu(partials: &[u32], stride: usize) -> Vec<u64> {
    let mut t = vec![0u64; stride];
    for rec in partials.chunks_exact(stride) {
        for (acc, &v) in t.iter_mut().zip(rec) {
            *acc += u64::from(v);
        }
    }
    t
}

/// Decodes (lo, hi) word pairs read back from the totals buffer.
pub fn totals_from_words(words: &[u32]) -> Vec<u64> {
    words
        .chunks_exact(2)
        .map(|w| u64::from(w[0]) | (u64::from(w[1]) << 32))
        .collect()
}
