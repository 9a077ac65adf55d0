//! `similarity`: keyframes by what the frames look like (iVS3D's Deep Visual Similarity), over a
//! cached per-frame embedding (the built-in descriptor, `kernels::descriptor`). Two modes:
//! - `--similarity K`: k-means over the candidates' embeddings with k = ⌈n / K⌉ (n candidates),
//!   k-means++ seeding from a fixed seed, and per cluster the candidate nearest its centre; the
//!   arithmetic is f64 in a fixed order with ties to the lower index, so the same embeddings
//!   always give the same keyframes;
//! - `--similarity-threshold D`: walking the candidates in order, a frame is kept unless its
//!   cosine distance to a frame already kept is below D, so a scene seen again later (a revisit,
//!   a loop) is left out, which k-means, blind to order, does not do.
//!
//! With `--similarity-model FILE` the embeddings come from an image-embedding network: a model
//! description (`model_desc`, output kind `embedding`) or an ONNX file named as iVS3D names them,
//! `ImageEmbedding_<NAME>_<DIM>_<W>x<H>.onnx` ([`model_name`]), run by OpenCV DNN or ONNX Runtime
//! (`--similarity-runtime`, `segment::embedding`).
//!
//! Embeddings are kept per frame as unit vectors quantised to 16 bits ([`quantise`]) in a side
//! file beside the project (`embedding_file`; older projects: hex text, [`encode`]), the same
//! bytes for the same descriptor totals whichever backend computed them; the step reads back
//! only its candidates' vectors ([`Stored::vectors`]).

use super::{Applied, Flag, FlagValues, Inputs, Step};
use crate::error::{Error, Result};
use crate::manifest::SegRuntime;
use crate::params::Backend;
use std::path::{Path, PathBuf};

/// The step's id.
pub const ID: &str = "similarity";

/// `--similarity K`, `--similarity-threshold D`, `--similarity-model FILE`.
pub const FLAGS: &[Flag] = &[
    Flag::value::<usize>(
        "similarity",
        "K",
        "Keep one frame per K candidates on average by visual similarity: k-means over the frames' embeddings (k = ceil(n/K)), the frame nearest each cluster centre",
    )
    .sets(ID, "k"),
    Flag::value::<f64>(
        "similarity-threshold",
        "D",
        "Instead of --similarity K: walk the candidates in order and drop a frame whose embedding is within cosine distance D (0..2) of a frame already kept (leaves out revisits)",
    )
    .conflicts("similarity")
    .sets(ID, "threshold"),
    Flag::value::<PathBuf>(
        "similarity-model",
        "FILE",
        "Embeddings for --similarity from an image-embedding network instead of the built-in descriptor: a model description (.toml, output kind \"embedding\") or an ONNX file named ImageEmbedding_<NAME>_<DIM>_<W>x<H>.onnx (iVS3D's naming; RGB, ImageNet mean/std)",
    )
    .sets(ID, "model"),
    Flag::value::<SegRuntime>(
        "similarity-runtime",
        "RUNTIME",
        "Runtime of the --similarity-model network (the runtimes of --mask-backend)",
    )
    .choices::<SegRuntime>()
    .sets(ID, "runtime"),
];

/// The step when `--similarity` or `--similarity-threshold` is given.
pub fn from_flags(v: &FlagValues) -> Result<Option<Step>> {
    let k = v.get::<usize>("similarity")?;
    let threshold = v.get::<f64>("similarity-threshold")?;
    let model = v.get::<PathBuf>("similarity-model")?;
    let runtime = v.get::<SegRuntime>("similarity-runtime")?;
    if runtime.is_some() && model.is_none() {
        return Err(Error::param(
            "similarity-runtime",
            "needs --similarity-model FILE (the built-in descriptor runs on --backend)",
        ));
    }
    match (k.is_some() || threshold.is_some(), model) {
        (true, model) => Ok(Some(Step::Similarity {
            k,
            threshold,
            model,
            runtime,
        })),
        (false, Some(_)) => Err(Error::param(
            "similarity-model",
            "needs --similarity K or --similarity-threshold D (the step it feeds)",
        )),
        (false, None) => Ok(None),
    }
}

/// What an embedding network's file name says (iVS3D's naming,
/// `ImageEmbedding_<NAME>_<DIM>_<W>x<H>.onnx`): its output size and input size.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModelName {
    /// The network's name (`EigenPlaces`).
    pub name: String,
    /// Values in its output (the embedding's dimensions).
    pub dim: usize,
    /// Input width in pixels.
    pub width: u32,
    /// Input height in pixels.
    pub height: u32,
}

/// Reads iVS3D's naming from `path`'s file name; the error names the file and the naming.
pub fn model_name(path: &Path) -> Result<ModelName> {
    let file = path.file_name().unwrap_or_default().to_string_lossy();
    let bad = || {
        Error::input(
            path,
            "an embedding model must be named ImageEmbedding_<NAME>_<DIM>_<W>x<H>.onnx (iVS3D's \
             naming, e.g. ImageEmbedding_EigenPlaces_2048_640x480.onnx)",
        )
    };
    let stem = (file.strip_prefix("ImageEmbedding_"))
        .and_then(|s| s.strip_suffix(".onnx"))
        .ok_or_else(bad)?;
    let mut parts = stem.rsplitn(3, '_');
    let (size, dim, name) = (parts.next(), parts.next(), parts.next());
    let (Some(size), Some(dim), Some(name)) = (size, dim, name) else {
        return Err(bad());
    };
    let (w, h) = size.split_once('x').ok_or_else(bad)?;
    let number = |t: &str| t.parse::<u32>().ok().filter(|&v| v > 0).ok_or_else(bad);
    Ok(ModelName {
        name: name.to_string(),
        dim: number(dim)? as usize,
        width: number(w)?,
        height: number(h)?,
    })
}

/// Checks the parameters: one mode, K at least 1, D in (0, 2].
pub fn check(
    k: Option<usize>,
    threshold: Option<f64>,
) -> std::result::Result<(), (&'static str, String)> {
    match (k, threshold) {
        (Some(_), Some(_)) => Err((
            "threshold",
            "give K (k-means) or a threshold, not both".into(),
        )),
        (None, None) => Err((
            "k",
            "give K (one keyframe per K frames) or a threshold".into(),
        )),
        (Some(0), _) => Err(("k", "must be a whole number of at least 1, got 0".into())),
        (_, Some(d)) if !(d > 0.0 && d <= 2.0) => Err((
            "threshold",
            format!("must be a cosine distance above 0 and at most 2, got {d}"),
        )),
        _ => Ok(()),
    }
}

/// The embeddings a similarity step reads: what computed them and each frame's vector.
#[derive(Debug, Clone, Copy)]
pub struct Embeddings<'a> {
    /// The embedder's name (`builtin-grid-hog-colour-v1`).
    pub embedder: &'a str,
    /// Backend that computed them.
    pub backend: Backend,
    /// The runtime that ran the network, when a network computed them.
    pub runtime: Option<SegRuntime>,
    /// Where the vectors are.
    pub frames: Stored<'a>,
}

/// Where a series' vectors are kept.
#[derive(Debug, Clone, Copy)]
pub enum Stored<'a> {
    /// One [`encode`]d vector per frame (projects written before the side files).
    Hex(&'a [String]),
    /// A side file (`embedding_file`) of `count` frames of `dim` values.
    File {
        /// The folder it is in (the project's).
        dir: &'a Path,
        /// Its name.
        name: &'a str,
        /// Values per frame.
        dim: usize,
        /// Frames it holds.
        count: usize,
    },
}

impl Stored<'_> {
    /// The unit vectors of `frames`, in that order: only those are read (memory: 8 bytes per
    /// value of the frames asked for).
    pub fn vectors(&self, frames: &[usize]) -> Result<Vec<Vec<f64>>> {
        match *self {
            Stored::Hex(all) => (frames.iter())
                .map(|&f| {
                    let text = all.get(f).ok_or_else(|| {
                        Error::step(ID, format!("the cache has no embedding of frame {f}"))
                    })?;
                    decode(text).ok_or_else(|| {
                        Error::step(
                            ID,
                            format!("frame {f}: the cached embedding is not readable"),
                        )
                    })
                })
                .collect(),
            Stored::File {
                dir,
                name,
                dim,
                count,
            } => {
                let q = crate::embedding_file::read(&dir.join(name), dim, count, frames)?;
                Ok(q.iter().map(|v| unit(v)).collect())
            }
        }
    }
}

/// Scale of the 16-bit quantisation of a unit vector's components.
const QUANT: f64 = 32767.0;

/// A vector as stored per frame: normalised to unit length (a zero vector stays zero), each
/// component rounded to a multiple of 1/32767.
pub fn quantise(v: &[f64]) -> Vec<i16> {
    let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    v.iter()
        .map(|x| match norm > 0.0 {
            true => (x / norm * QUANT).round().clamp(-QUANT, QUANT) as i16,
            false => 0,
        })
        .collect()
}

/// The [`quantise`]d vector as 4 hex digits a component (two's complement): how projects kept
/// them before the side files.
pub fn encode(v: &[f64]) -> String {
    quantise(v)
        .iter()
        .map(|&q| format!("{:04x}", q as u16))
        .collect()
}

/// The unit vector of a [`quantise`]d one (renormalised after the quantisation).
pub fn unit(q: &[i16]) -> Vec<f64> {
    let v: Vec<f64> = q.iter().map(|&x| f64::from(x)).collect();
    let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    v.iter()
        .map(|x| if norm > 0.0 { x / norm } else { 0.0 })
        .collect()
}

/// The unit vector of an [`encode`]d one; None when the text is not whole 4-digit hex numbers.
pub fn decode(text: &str) -> Option<Vec<f64>> {
    if !text.len().is_multiple_of(4) || !text.is_ascii() {
        return None;
    }
    let q = (0..text.len() / 4)
        .map(|i| u16::from_str_radix(&text[4 * i..4 * i + 4], 16).map(|q| q as i16))
        .collect::<std::result::Result<Vec<i16>, _>>()
        .ok()?;
    Some(unit(&q))
}

/// Cosine distance of two unit vectors (1 - their dot product; 1 when one is zero).
pub fn cosine_distance(a: &[f64], b: &[f64]) -> f64 {
    1.0 - a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>()
}

/// The step on `keys` with `K` or the threshold `D` (checked by [`check`]).
pub fn apply(
    at: &Inputs,
    keys: &mut Vec<usize>,
    (k, threshold): (Option<usize>, Option<f64>),
    model: Option<&Path>,
) -> Result<Applied> {
    let e = at.embeddings.ok_or_else(|| {
        Error::step(
            ID,
            "needs each frame's embedding, which the project's cache lacks: run `keyframer select` with the step",
        )
    })?;
    let points = e.frames.vectors(keys)?;
    let dim = points.first().map_or(0, Vec::len);
    let (chosen, clusters) = match (k, threshold) {
        (Some(k), _) => {
            let clusters = keys.len().div_ceil(k.max(1));
            let chosen = kmeans_keep(&points, clusters);
            if chosen.len() < clusters {
                log::warn!(
                    "{ID}: {} keyframes for {clusters} clusters: the candidates have only that \
                     many distinct embeddings",
                    chosen.len()
                );
            }
            (chosen, Some(clusters))
        }
        (None, Some(d)) => (threshold_keep(&points, d), None),
        (None, None) => (Vec::new(), None),
    };
    *keys = chosen.into_iter().map(|i| keys[i]).collect();
    Ok(Applied::Similarity {
        backend: Some(e.backend),
        clusters,
        dim,
        embedder: e.embedder.to_string(),
        k,
        model: model.map(crate::fsutil::absolute),
        runtime: e.runtime,
        threshold,
    })
}

/// Indices of the points kept walking in order: a point within cosine distance `d` of one
/// already kept is dropped.
pub fn threshold_keep(points: &[Vec<f64>], d: f64) -> Vec<usize> {
    let mut kept: Vec<usize> = Vec::new();
    for (i, p) in points.iter().enumerate() {
        if kept.iter().all(|&j| cosine_distance(p, &points[j]) >= d) {
            kept.push(i);
        }
    }
    kept
}

/// The fixed seed of the k-means++ seeding.
const SEED: u64 = 0x6b65_7966_7261_6d65;

/// SplitMix64: a small deterministic generator (the same sequence on every platform).
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1), 53 bits.
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Squared Euclidean distance.
fn dist2(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// The index of the nearest of `centres` (ties: the lower index).
fn nearest(p: &[f64], centres: &[Vec<f64>]) -> usize {
    let mut best = (0, f64::INFINITY);
    for (c, centre) in centres.iter().enumerate() {
        let d = dist2(p, centre);
        if d < best.1 {
            best = (c, d);
        }
    }
    best.0
}

/// k-means++ seeding: the first centre uniformly, each next one with probability proportional
/// to the squared distance to the nearest chosen centre; when every point lies on a chosen
/// centre, the first point not chosen yet.
fn seed(points: &[Vec<f64>], k: usize, rng: &mut SplitMix) -> Vec<usize> {
    let n = points.len();
    let first = ((rng.unit() * n as f64) as usize).min(n - 1);
    let mut chosen = vec![first];
    let mut d2: Vec<f64> = points.iter().map(|p| dist2(p, &points[first])).collect();
    while chosen.len() < k {
        let total: f64 = d2.iter().sum();
        let next = if total > 0.0 {
            let r = rng.unit() * total;
            let mut acc = 0.0;
            let last = d2.iter().rposition(|&d| d > 0.0).unwrap_or(0);
            (0..n)
                .find(|&i| {
                    acc += d2[i];
                    d2[i] > 0.0 && acc > r
                })
                .unwrap_or(last)
        } else {
            match (0..n).find(|i| !chosen.contains(i)) {
                Some(i) => i,
                None => break,
            }
        };
        chosen.push(next);
        for (d, p) in d2.iter_mut().zip(points) {
            *d = d.min(dist2(p, &points[next]));
        }
    }
    chosen
}

/// Most Lloyd iterations (they stop earlier once no assignment changes).
const MAX_ITERATIONS: usize = 100;

/// k-means of `points` into `k` clusters: the cluster of each point and the centres.
pub fn kmeans(points: &[Vec<f64>], k: usize) -> (Vec<usize>, Vec<Vec<f64>>) {
    let k = k.min(points.len());
    if k == 0 {
        return (Vec::new(), Vec::new());
    }
    let mut rng = SplitMix(SEED);
    let mut centres: Vec<Vec<f64>> = (seed(points, k, &mut rng).into_iter())
        .map(|i| points[i].clone())
        .collect();
    let mut assigned: Vec<usize> = points.iter().map(|p| nearest(p, &centres)).collect();
    for _ in 0..MAX_ITERATIONS {
        let dim = points[0].len();
        let mut sums = vec![vec![0.0; dim]; centres.len()];
        let mut counts = vec![0usize; centres.len()];
        for (p, &c) in points.iter().zip(&assigned) {
            counts[c] += 1;
            sums[c].iter_mut().zip(p).for_each(|(s, x)| *s += x);
        }
        for ((centre, sum), &count) in centres.iter_mut().zip(sums).zip(&counts) {
            if count > 0 {
                *centre = sum.into_iter().map(|s| s / count as f64).collect();
            }
        }
        let next: Vec<usize> = points.iter().map(|p| nearest(p, &centres)).collect();
        if next == assigned {
            break;
        }
        assigned = next;
    }
    (assigned, centres)
}

/// Indices (ascending) of the point nearest each non-empty cluster's centre of [`kmeans`] with
/// `k` clusters (ties: the lower index).
pub fn kmeans_keep(points: &[Vec<f64>], k: usize) -> Vec<usize> {
    let (assigned, centres) = kmeans(points, k);
    let mut best: Vec<Option<(usize, f64)>> = vec![None; centres.len()];
    for (i, (p, &c)) in points.iter().zip(&assigned).enumerate() {
        let d = dist2(p, &centres[c]);
        if best[c].is_none_or(|(_, b)| d < b) {
            best[c] = Some((i, d));
        }
    }
    let mut keep: Vec<usize> = best.into_iter().flatten().map(|(i, _)| i).collect();
    keep.sort_unstable();
    keep
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(v: &[f64]) -> Vec<f64> {
        let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        v.iter().map(|x| x / n).collect()
    }

    #[test]
    fn encoding_keeps_unit_vectors_to_16_bits() {
        let v = unit(&[0.3, -0.2, 0.9, 0.0]);
        let text = encode(&v);
        assert_eq!(text.len(), 16);
        let back = decode(&text).unwrap();
        for (a, b) in v.iter().zip(&back) {
            assert!((a - b).abs() < 1e-4, "{a} {b}");
        }
        assert_eq!(encode(&back), text);
        assert_eq!(decode(&encode(&[0.0, 0.0])).unwrap(), [0.0, 0.0]);
        assert!(decode("12g4").is_none());
        assert!(decode("123").is_none());
    }

    /// Three tight groups: k-means with k = 3 keeps one point of each, the one nearest the
    /// group's mean; the same call gives the same answer.
    #[test]
    fn kmeans_keeps_the_point_nearest_each_centre() {
        let mut points = Vec::new();
        for (g, base) in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
            .iter()
            .enumerate()
        {
            for j in 0..5 {
                let o = 0.01 * (j as f64 - 2.0) * (g as f64 + 1.0);
                points.push(unit(&[base[0] + o, base[1] + o * o, base[2] - o]));
            }
        }
        let keep = kmeans_keep(&points, 3);
        assert_eq!(keep, [2, 7, 12]);
        assert_eq!(kmeans_keep(&points, 3), keep);
        // More clusters than distinct points: one per distinct point.
        let same = vec![vec![1.0, 0.0]; 4];
        assert_eq!(kmeans_keep(&same, 3), [0]);
    }

    #[test]
    fn threshold_leaves_out_what_was_seen() {
        let a = unit(&[1.0, 0.0]);
        let b = unit(&[0.0, 1.0]);
        let a2 = unit(&[1.0, 0.05]);
        let points = vec![a.clone(), a2.clone(), b, a2, a];
        assert_eq!(threshold_keep(&points, 0.1), [0, 2]);
    }

    #[test]
    fn parameters_are_checked() {
        assert!(check(Some(3), None).is_ok());
        assert!(check(None, Some(0.2)).is_ok());
        assert_eq!(check(Some(0), None).unwrap_err().0, "k");
        assert_eq!(check(Some(2), Some(0.2)).unwrap_err().0, "threshold");
        assert_eq!(check(None, Some(0.0)).unwrap_err().0, "threshold");
        assert_eq!(check(None, Some(2.5)).unwrap_err().0, "threshold");
        assert_eq!(check(None, None).unwrap_err().0, "k");
    }
}
