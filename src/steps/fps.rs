//! `fps`: resample to a target frame rate by timestamps, so 29.97 fps and variable-frame-rate
//! inputs are sampled by time, not by index arithmetic. For each target time t0 + k/F (t0 = the
//! first candidate's timestamp) the candidate with the nearest timestamp is kept (earlier one on a
//! tie); targets after the last candidate (by more than half a frame interval) are not used.
//!
//! The work is bounded by the number of candidates, never by F: targets that would pick the
//! candidate already kept are skipped in one step, and a target rate above the candidates' own
//! rate (a grid finer than their shortest interval) keeps every candidate, as the finer grid would.

use super::{Applied, Flag, FlagValues, Inputs, Step};
use crate::error::{Error, Result};

/// `--fps F`.
pub const FLAGS: &[Flag] = &[Flag::value::<f64>(
    "fps",
    "F",
    "Resample to F frames per second, by timestamps (F at or above the input's frame rate keeps every frame)",
)
.sets("fps", "fps")];

/// The step when `--fps` is given.
pub fn from_flags(v: &FlagValues) -> Result<Option<Step>> {
    Ok(v.get("fps")?.map(|fps| Step::Fps { fps }))
}

/// The step on `keys`.
pub fn apply(at: &Inputs, keys: &mut Vec<usize>, target_fps: f64) -> Result<Applied> {
    let ts = at.timestamps_s.ok_or_else(|| {
        Error::step(
            "fps",
            "the input has no timestamps (an image folder: give its rate with --images-fps)",
        )
    })?;
    *keys = fps(keys, ts, target_fps)?;
    Ok(Applied::Fps { fps: target_fps })
}

/// Candidates nearest to a regular `target_fps` grid of times.
pub fn fps(candidates: &[usize], timestamps_s: &[f64], target_fps: f64) -> Result<Vec<usize>> {
    check(candidates, timestamps_s, target_fps)?;
    let (Some(&first), Some(&last)) = (candidates.first(), candidates.last()) else {
        return Ok(Vec::new());
    };
    let ts = |j: usize| timestamps_s[candidates[j]];
    let t0 = timestamps_s[first];
    let t_last = timestamps_s[last];
    let half_frame = 0.5 * median_interval(candidates, timestamps_s);
    let min_interval = candidates
        .windows(2)
        .map(|w| timestamps_s[w[1]] - timestamps_s[w[0]])
        .filter(|d| *d > 0.0)
        .fold(f64::INFINITY, f64::min);
    // A grid finer than the shortest interval puts a target into every candidate's share of the
    // time line: the same as a grid of half that interval, which keeps the loop short.
    let step = if min_interval.is_finite() {
        (1.0 / target_fps).max(0.5 * min_interval)
    } else {
        1.0 / target_fps
    };
    let later = later_candidates(candidates.len(), ts);
    let end = t_last + half_frame + 1e-9;
    let mut out: Vec<usize> = Vec::new();
    let mut j = 0; // candidate cursor, only moves forward
    let mut k: f64 = 0.0; // target index (f64: exact up to 2^53, far beyond any loop here)
    loop {
        let target = t0 + k * step;
        if target > end {
            break;
        }
        // Candidates at the time of the current one (or earlier) never win: the earlier wins ties.
        while let Some(i) = later[j] {
            if (ts(i) - target).abs() < (ts(j) - target).abs() {
                j = i;
            } else {
                break;
            }
        }
        if out.last() != Some(&candidates[j]) {
            out.push(candidates[j]);
        }
        // The next target that can pick another candidate lies past the midpoint between this
        // candidate and the next later one; skip to just before it (one target early, so that
        // rounding never skips one).
        let jump = match later[j] {
            Some(i) => ((0.5 * (ts(j) + ts(i)) - t0) / step).floor() - 1.0,
            None => ((end - t0) / step).floor(),
        };
        k = (k + 1.0).max(jump);
    }
    Ok(out)
}

/// The rate is positive and every candidate has a finite timestamp.
fn check(candidates: &[usize], timestamps_s: &[f64], target_fps: f64) -> Result<()> {
    let err = |msg: String| Error::step("fps", msg);
    crate::numbers::positive(target_fps).map_err(|m| err(format!("target fps {m}")))?;
    if let Some(&bad) = candidates.iter().find(|&&c| c >= timestamps_s.len()) {
        return Err(err(format!(
            "frame {bad} has no timestamp ({} known)",
            timestamps_s.len()
        )));
    }
    if let Some(i) = candidates
        .iter()
        .position(|&c| !timestamps_s[c].is_finite())
    {
        return Err(err(format!(
            "frame {} has no finite timestamp ({})",
            candidates[i], timestamps_s[candidates[i]]
        )));
    }
    Ok(())
}

/// For each of `n` candidates, the first candidate after it with a later time `ts` (a monotonic
/// stack, O(n)).
fn later_candidates(n: usize, ts: impl Fn(usize) -> f64) -> Vec<Option<usize>> {
    let mut later: Vec<Option<usize>> = vec![None; n];
    let mut stack: Vec<usize> = Vec::new();
    for i in 0..n {
        while let Some(&top) = stack.last() {
            if ts(i) > ts(top) {
                later[top] = Some(i);
                stack.pop();
            } else {
                break;
            }
        }
        stack.push(i);
    }
    later
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
    fn rates_above_the_input_keep_every_frame_at_once() {
        let ts: Vec<f64> = (0..3000).map(|i| i as f64 / 30.0).collect();
        let c: Vec<usize> = (0..3000).collect();
        for f in [30.0, 31.0, 1e3, 6e8, 1e9, 1e300, f64::MAX] {
            let t = std::time::Instant::now();
            assert_eq!(fps(&c, &ts, f).unwrap(), c, "fps {f}");
            assert!(
                t.elapsed().as_secs_f64() < 1.0,
                "fps {f}: {:?}",
                t.elapsed()
            );
        }
        // Variable frame rate with one very short interval: still bounded by the candidates.
        let mut vfr = ts.clone();
        vfr[1] = 1e-9;
        let t = std::time::Instant::now();
        assert_eq!(fps(&c, &vfr, 1e12).unwrap(), c);
        assert!(t.elapsed().as_secs_f64() < 1.0, "{:?}", t.elapsed());
        // Equal timestamps: the earlier frame wins, the later ones are still reachable.
        let dup = [0.0, 0.0, 0.0, 0.1, 0.2];
        assert_eq!(fps(&[0, 1, 2, 3, 4], &dup, 1e9).unwrap(), vec![0, 3, 4]);
        assert!(fps(&[0, 1], &[0.0, f64::NAN], 1.0).is_err());
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
