//! `blur`: drop or replace blurry keyframes using a per-frame sharpness score.
//! Filter mode keeps a keyframe iff score ≥ ratio × mean(scores of the frames within ±window,
//! itself included, clipped to the sampled range). Replace mode moves each keyframe to the
//! sharpest frame within ±window, never onto or across a neighbouring keyframe (ties: the frame
//! nearest the original, then the earlier one).

use super::{Applied, Flag, FlagValues, Inputs, Step};
use crate::error::{Error, Result};
use crate::numbers::positive;
use crate::params::Metric;
use serde::{Deserialize, Serialize};

/// `--blur` and its parameters.
pub const FLAGS: &[Flag] = &[
    Flag::switch("blur", "Drop (filter) or replace blurry keyframes, after --every/--fps"),
    Flag::value::<Metric>("blur-metric", "METRIC", "Sharpness metric: tenengrad, laplacian (= laplacian-k1) or laplacian-k3")
        .default("tenengrad")
        .sets("blur", "metric"),
    Flag::value::<usize>("blur-window", "W", "Half-width of the comparison window, in frames")
        .default("10")
        .sets("blur", "window"),
    Flag::value::<f64>("blur-ratio", "RATIO", "Filter mode keeps a frame iff its score >= RATIO x the mean score within the window")
        .default("0.8")
        .sets("blur", "ratio"),
    Flag::value::<BlurMode>("blur-mode", "BLUR_MODE", "filter: drop blurry keyframes; replace: move each keyframe to the sharpest frame in its window (never onto or across another keyframe)")
        .default("filter")
        .choices::<BlurMode>()
        .sets("blur", "mode"),
];

/// The step when `--blur` is given.
pub fn from_flags(v: &FlagValues) -> Result<Option<Step>> {
    if !v.given("blur") {
        return Ok(None);
    }
    Ok(Some(Step::Blur {
        metric: v.get("blur-metric")?,
        window: v.get("blur-window")?,
        ratio: v.get("blur-ratio")?,
        mode: v.get("blur-mode")?,
    }))
}

/// The step on `keys`, within the candidates' range.
pub fn apply(at: &Inputs, keys: &mut Vec<usize>, b: &BlurParams) -> Result<Applied> {
    let (scores, backend) = at
        .sharpness
        .iter()
        .find(|s| s.0 == b.metric)
        .map(|s| (s.1, s.2))
        .ok_or_else(|| Error::step("blur", format!("no {} scores were computed", b.metric)))?;
    *keys = blur(keys, scores, b, at.range.0, at.range.1)?;
    Ok(Applied::Blur {
        backend: Some(backend),
        metric: Some(b.metric),
        mode: Some(b.mode),
        ratio: Some(b.ratio),
        window: Some(b.window),
    })
}

crate::names::named_enum! {
    /// What to do with blurry keyframes.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum BlurMode: "blur-mode" {
        /// Drop keyframes that are blurrier than their neighbourhood.
        Filter = "filter": "Drop blurry keyframes",
        /// Move keyframes to the sharpest nearby frame.
        Replace = "replace": "Move keyframes to the sharpest nearby frame",
    }
}

/// Parameters of the blur sampler.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BlurParams {
    /// Sharpness metric.
    pub metric: Metric,
    /// Half-width of the window in frames.
    pub window: usize,
    /// Filter threshold relative to the window mean (filter mode).
    pub ratio: f64,
    /// Filter or replace.
    pub mode: BlurMode,
}

impl BlurParams {
    /// Checks ranges.
    pub fn validate(&self) -> Result<()> {
        positive(self.ratio).map_err(|m| Error::step("blur", format!("ratio {m}")))?;
        if self.window == 0 {
            return Err(Error::step("blur", "window must be at least 1 frame"));
        }
        Ok(())
    }
}

/// Applies the blur sampler to `keyframes` within the sampled range `lo..=hi`.
pub fn blur(
    keyframes: &[usize],
    scores: &[f64],
    p: &BlurParams,
    lo: usize,
    hi: usize,
) -> Result<Vec<usize>> {
    p.validate()?;
    if hi >= scores.len() || lo > hi {
        let n = scores.len();
        let msg = format!("range {lo}..={hi} does not fit {n} scored frames");
        return Err(Error::step("blur", msg));
    }
    let window = |k: usize| k.saturating_sub(p.window).max(lo)..=k.saturating_add(p.window).min(hi);
    Ok(match p.mode {
        BlurMode::Filter => keyframes
            .iter()
            .copied()
            .filter(|&k| {
                let w = window(k);
                let n = w.clone().count() as f64;
                let mean = scores[w].iter().sum::<f64>() / n;
                scores[k] >= p.ratio * mean
            })
            .collect(),
        BlurMode::Replace => {
            let mut out: Vec<usize> = Vec::with_capacity(keyframes.len());
            for (i, &k) in keyframes.iter().enumerate() {
                let w = window(k);
                let mut lower = *w.start();
                if let Some(&prev) = out.last() {
                    lower = lower.max(prev + 1);
                }
                let mut upper = *w.end();
                if let Some(&next) = keyframes.get(i + 1) {
                    upper = upper.min(next.saturating_sub(1));
                }
                let best = (lower..=upper)
                    .max_by(|&a, &b| {
                        scores[a]
                            .total_cmp(&scores[b])
                            .then_with(|| k.abs_diff(b).cmp(&k.abs_diff(a)))
                            .then_with(|| b.cmp(&a))
                    })
                    .unwrap_or(k);
                out.push(best);
            }
            out
        }
    })
}

/// The filter mode's threshold for every frame: `ratio` × the mean score of the frames within
/// ±`window`, clipped to the sampled range `lo..=hi`; NaN outside the range (and everywhere when
/// the range does not fit the scores). This is the series the report draws; [`blur`] compares each
/// keyframe with the same window mean, summed over the window itself (a series over every frame
/// uses prefix sums to stay linear in the frame count, so the two can differ in the last bits).
pub fn threshold_series(
    scores: &[f64],
    lo: usize,
    hi: usize,
    window: usize,
    ratio: f64,
) -> Vec<f64> {
    let mut out = vec![f64::NAN; scores.len()];
    if hi >= scores.len() || lo > hi {
        return out;
    }
    // Prefix sums keep this linear in the frame count.
    let mut prefix = vec![0.0; scores.len() + 1];
    for (i, v) in scores.iter().enumerate() {
        prefix[i + 1] = prefix[i] + v;
    }
    for (k, o) in out.iter_mut().enumerate().take(hi + 1).skip(lo) {
        let a = k.saturating_sub(window).max(lo);
        let b = (k + window).min(hi);
        *o = ratio * (prefix[b + 1] - prefix[a]) / (b + 1 - a) as f64;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(mode: BlurMode) -> BlurParams {
        BlurParams {
            metric: Metric::Tenengrad,
            window: 2,
            ratio: 0.8,
            mode,
        }
    }

    #[test]
    fn filter_drops_dips() {
        let scores = [10.0, 10.0, 2.0, 10.0, 10.0, 9.0, 10.0];
        let k = blur(
            &[0, 1, 2, 3, 4, 5, 6],
            &scores,
            &params(BlurMode::Filter),
            0,
            6,
        )
        .unwrap();
        assert_eq!(k, vec![0, 1, 3, 4, 5, 6]);
    }

    #[test]
    fn threshold_series_is_what_the_filter_compares_with() {
        let scores = [10.0, 10.0, 2.0, 10.0, 10.0, 9.0, 10.0];
        let p = params(BlurMode::Filter);
        let t = threshold_series(&scores, 1, 5, p.window, p.ratio);
        assert!(t[0].is_nan() && t[6].is_nan());
        let kept = blur(&[1, 2, 3, 4, 5], &scores, &p, 1, 5).unwrap();
        for k in 1usize..=5 {
            let w = k.saturating_sub(2).max(1)..=(k + 2).min(5);
            let mean = scores[w.clone()].iter().sum::<f64>() / w.count() as f64;
            assert!((t[k] - 0.8 * mean).abs() < 1e-12);
            assert_eq!(kept.contains(&k), scores[k] >= t[k], "frame {k}");
        }
        assert!(threshold_series(&scores, 3, 9, 2, 0.8)
            .iter()
            .all(|v| v.is_nan()));
    }

    #[test]
    fn replace_moves_without_crossing() {
        let scores = [1.0, 5.0, 1.0, 1.0, 9.0, 1.0, 1.0, 1.0];
        // Keyframe 2 would like frame 4, but keyframe 3 is in the way: it takes frame 1 instead.
        let k = blur(&[2, 3, 7], &scores, &params(BlurMode::Replace), 0, 7).unwrap();
        assert_eq!(k, vec![1, 4, 7]);
        assert!(k.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn replace_ties_prefer_the_original() {
        let scores = [3.0; 9];
        let k = blur(&[4], &scores, &params(BlurMode::Replace), 0, 8).unwrap();
        assert_eq!(k, vec![4]);
    }
}
