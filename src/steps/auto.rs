//! `--auto`: threshold proposals from a sample of consecutive-frame movements, each with a
//! one-paragraph explanation for the user.

/// A proposed threshold and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Proposal {
    /// Threshold in full-resolution pixels.
    pub threshold: f64,
    /// Human-readable reasoning, with the sample's numbers.
    pub explanation: String,
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Stationary threshold: the sample's per-frame movements are split into a "still" and a
/// "moving" group (Otsu's split on log movement); when the groups differ at least tenfold the
/// threshold is their geometric mean, so still frames stay below it even after a few re-anchors
/// and every moving frame exceeds it. Without a still group, half the 10th percentile keeps every
/// moving frame.
pub fn stationary_threshold(sample: &[f64]) -> Proposal {
    let mut v: Vec<f64> = sample.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    let floor = 0.01;
    if v.len() < 4 {
        return Proposal {
            threshold: 1.0,
            explanation: format!("only {} frame pairs could be sampled; using 1 px", v.len()),
        };
    }
    let logs: Vec<f64> = v.iter().map(|x| (x + 1e-3).log10()).collect();
    let n = logs.len() as f64;
    let total: f64 = logs.iter().sum();
    let (mut best, mut split) = (f64::MIN, 1);
    let mut left = 0.0;
    for k in 1..logs.len() {
        left += logs[k - 1];
        let (n0, n1) = (k as f64, n - k as f64);
        let (m0, m1) = (left / n0, (total - left) / n1);
        let between = n0 * n1 * (m0 - m1).powi(2);
        if between > best {
            best = between;
            split = k;
        }
    }
    let still = quantile(&v[..split], 0.5);
    let moving = quantile(&v[split..], 0.5);
    let (p10, p50, p90) = (quantile(&v, 0.1), quantile(&v, 0.5), quantile(&v, 0.9));
    let head = format!(
        "sampled {} frame pairs: movement per frame P10 {p10:.3} px, median {p50:.3} px, P90 {p90:.3} px",
        v.len()
    );
    if moving >= 10.0 * still.max(1e-4) {
        let t = (still.max(1e-4) * moving).sqrt().max(floor);
        Proposal {
            threshold: t,
            explanation: format!(
                "{head}; {split} pairs look still (median {still:.3} px) and {} moving (median {moving:.3} px); \
                 stationary threshold {t:.3} px = their geometric mean",
                v.len() - split
            ),
        }
    } else {
        let t = (0.5 * p10).max(floor);
        Proposal {
            threshold: t,
            explanation: format!(
                "{head}; no still segment stands out, so the threshold {t:.3} px (half the 10th percentile) keeps every moving frame"
            ),
        }
    }
}

/// Spacing threshold: 15 % of the frame width of camera movement between keyframes (about 85 %
/// overlap for a sideways pan, a comfortable margin for sequential matching), with the keyframe
/// count the sample predicts for the whole input.
pub fn spacing_threshold(sample: &[f64], width: u32, frame_count: usize) -> Proposal {
    let t = f64::from(width) * 0.15;
    let finite: Vec<f64> = sample.iter().copied().filter(|x| x.is_finite()).collect();
    let mean = if finite.is_empty() {
        0.0
    } else {
        finite.iter().sum::<f64>() / finite.len() as f64
    };
    let expected = mean * frame_count.saturating_sub(1) as f64 / t;
    Proposal {
        threshold: t,
        explanation: format!(
            "spacing threshold {t:.1} px = 15 % of the {width} px frame width; the {} sampled pairs move {mean:.3} px per frame on average, \
             so about {:.0} keyframes are expected over {frame_count} frames",
            finite.len(),
            expected.round() + 1.0
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bimodal_sample_splits_between_still_and_moving() {
        let mut s = vec![0.01; 20];
        s.extend(vec![4.0; 40]);
        let p = stationary_threshold(&s);
        assert!((p.threshold - (0.01f64 * 4.0).sqrt()).abs() < 1e-9, "{p:?}");
    }

    #[test]
    fn always_moving_keeps_every_frame() {
        let s: Vec<f64> = (0..50).map(|i| 2.0 + (i % 5) as f64 * 0.1).collect();
        let p = stationary_threshold(&s);
        assert!(p.threshold <= 1.0 && p.threshold > 0.0, "{p:?}");
    }
}
