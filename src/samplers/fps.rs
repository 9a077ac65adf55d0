//! `fps`: resample to a target frame rate by timestamps, so 29.97 fps and variable-frame-rate
//! inputs are sampled by time, not by index arithmetic. For each target time t0 + k/F (t0 = the
//! first candidate's timestamp) the candidate with the nearest timestamp is kept (earlier one on a
//! tie); targets after the last candidate (by more than half a frame interval) are not used.

use crate::error::{Error, Result};

/// Candidates nearest to a regular `target_fps` grid of times.
pub fn fps(candidates: &[usize], timestamps_s: &[f64], target_fps: f64) -> Result<Vec<usize>> {
    let err = |msg: String| Error::Plugin { plugin: "fps", msg };
    if !(target_fps.is_finite() && target_fps > 0.0) {
        return Err(err(format!(
            "target fps must be positive, got {target_fps}"
        )));
    }
    if let Some(&bad) = candidates.iter().find(|&&c| c >= timestamps_s.len()) {
        return Err(err(format!(
            "frame {bad} has no timestamp ({} known)",
            timestamps_s.len()
        )));
    }
    let (Some(&first), Some(&last)) = (candidates.first(), candidates.last()) else {
        return Ok(Vec::new());
    };
    let t0 = timestamps_s[first];
    let t_last = timestamps_s[last];
    let half_frame = 0.5 * median_interval(candidates, timestamps_s);
    let step = 1.0 / target_fps;
    let mut out: Vec<usize> = Vec::new();
    let mut j = 0; // candidate cursor, only moves forward
    for k in 0.. {
        let target = t0 + k as f64 * step;
        if target > t_last + half_frame + 1e-9 {
            break;
        }
        while j + 1 < candidates.len()
            && (timestamps_s[candidates[j + 1]] - target).abs()
                < (timestamps_s[candidates[j]] - target).abs()
        {
            j += 1;
        }
        if out.last() != Some(&candidates[j]) {
            out.push(candidates[j]);
        }
    }
    Ok(out)
}

fn median_interval(candidates: &[usize], ts: &[f64]) -> f64 {
    let mut d: Vec<f64> = candidates
        .windows(2)
        .map(|w| ts[w[1]] - ts[w[0]])
        .filter(|d| *d > 0.0)
        .collect();
    if d.is_empty() {
        return 0.0;
    }
    d.sort_by(f64::total_cmp);
    d[d.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thirty_fps_to_one() {
        let ts: Vec<f64> = (0..300).map(|i| i as f64 / 30.0).collect();
        let c: Vec<usize> = (0..300).collect();
        let k = fps(&c, &ts, 1.0).unwrap();
        assert_eq!(k, (0..10).map(|s| s * 30).collect::<Vec<_>>());
    }

    #[test]
    fn ntsc_rate_follows_time() {
        let rate = 30000.0 / 1001.0;
        let ts: Vec<f64> = (0..3000).map(|i| i as f64 / rate).collect();
        let c: Vec<usize> = (0..3000).collect();
        let k = fps(&c, &ts, 1.0).unwrap();
        for (s, &i) in k.iter().enumerate() {
            assert!(
                (ts[i] - s as f64).abs() <= 0.5 / rate + 1e-9,
                "second {s}: frame {i}"
            );
        }
        // Index arithmetic (every 30th) would drift by one frame every ~33 s.
        assert_ne!(k[40], 40 * 30);
    }
}
