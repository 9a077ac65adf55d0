//! `spacing`: even camera movement between keyframes. Movement between consecutive candidates is
//! the sum of the per-frame-pair movements between them; a candidate becomes a keyframe when the
//! movement accumulated since the last keyframe reaches the threshold (the first candidate is
//! always kept).

use super::{Applied, Flag, FlagValues, Inputs, Step, Threshold};
use crate::error::{Error, Result};

/// `--spacing PX|Nkf|auto`.
pub const FLAGS: &[Flag] = &[Flag::value::<Threshold>(
    "spacing",
    "PX|Nkf|auto",
    "Even camera movement: keep a frame each time the movement accumulated since the last keyframe reaches PX full-resolution pixels (`auto`: proposed from a sample, explained; `60kf`: the threshold that keeps 60 keyframes)",
)
.sets("spacing", "threshold")];

/// The step when `--spacing` is given.
pub fn from_flags(v: &FlagValues) -> Result<Option<Step>> {
    Ok(v.get("spacing")?
        .map(|threshold| Step::Spacing { threshold }))
}

/// The step on `keys`, with the threshold as `given` (`auto` resolved in `at`).
pub fn apply(at: &Inputs, keys: &mut Vec<usize>, given: Threshold) -> Result<Applied> {
    let err = |msg: &str| Error::step("spacing", msg);
    let (movement, backend) = at.movement.ok_or_else(|| err("no movement was computed"))?;
    let threshold = match (given, at.spacing_px) {
        (Threshold::Count(n), _) => {
            let t = spacing_for_count(keys, movement, n)?;
            log::info!("spacing {n}kf: threshold {t:.2} px");
            t
        }
        (_, Some(t)) => t,
        _ => return Err(err("no threshold")),
    };
    *keys = spacing(keys, movement, threshold)?;
    Ok(Applied::Spacing {
        auto: given == Threshold::Auto,
        backend: Some(backend),
        count: match given {
            Threshold::Count(n) => Some(n),
            _ => None,
        },
        movement: at.movement_request,
        threshold_px: threshold,
    })
}

/// Candidates spaced by `threshold` of accumulated movement; `movement[i]` is the movement from
/// frame i-1 to frame i.
pub fn spacing(candidates: &[usize], movement: &[f64], threshold: f64) -> Result<Vec<usize>> {
    let err = |msg: String| Err(Error::step("spacing", msg));
    if let Err(m) = crate::numbers::positive_px(threshold) {
        return err(format!("threshold {m}"));
    }
    if let Some(&bad) = candidates.iter().find(|&&c| c >= movement.len()) {
        return err(format!("frame {bad} has no movement value"));
    }
    let Some(&first) = candidates.first() else {
        return Ok(Vec::new());
    };
    let mut out = vec![first];
    let mut acc = 0.0;
    let mut prev = first;
    for &c in &candidates[1..] {
        acc += movement[prev + 1..=c].iter().sum::<f64>();
        prev = c;
        if acc >= threshold {
            out.push(c);
            acc = 0.0;
        }
    }
    Ok(out)
}

/// The threshold for which [`spacing`] keeps `count` keyframes of `candidates` (or the count
/// nearest to it: the count falls in steps as the threshold grows), by bisection.
pub fn spacing_for_count(candidates: &[usize], movement: &[f64], count: usize) -> Result<f64> {
    let total: f64 = match (candidates.first(), candidates.last()) {
        (Some(&a), Some(&b)) if b < movement.len() => movement[a + 1..=b].iter().sum(),
        _ => 0.0,
    };
    if total.is_nan() || total <= 0.0 {
        return Err(Error::step(
            "spacing",
            "the camera does not move over the candidate frames",
        ));
    }
    let kept = |t: f64| spacing(candidates, movement, t).map(|k| k.len());
    // kept(t) falls from candidates.len() (t tiny) to 1 (t > total); find the smallest t that
    // keeps at most `count`, then take whichever side of the step is nearer to `count`.
    let (mut lo, mut hi) = (total * 1e-9, total * 2.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if kept(mid)? > count {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let (above, below) = (kept(lo)?, kept(hi)?);
    let t = if above.abs_diff(count) < below.abs_diff(count) {
        lo
    } else {
        hi
    };
    middle_of_same_selection(candidates, movement, t, (total * 1e-9, total * 2.0))
}

/// The middle of the interval of thresholds that keep the same frames as `t` (within `bounds`).
/// The keyframes change where a threshold equals an accumulated sum, and bisection for a count
/// ends on such an edge; recorded there, the threshold would select other frames after any change
/// of the movement in its last digits (another backend, a saved workflow run elsewhere). The set
/// is fixed on an interval: each kept frame bounds the threshold from above by the sum that
/// reached it, each skipped one from below by the sum that did not.
fn middle_of_same_selection(
    candidates: &[usize],
    movement: &[f64],
    t: f64,
    bounds: (f64, f64),
) -> Result<f64> {
    let want = spacing(candidates, movement, t)?;
    let same = |x: f64| spacing(candidates, movement, x).map(|k| k == want);
    // Bisects between `inside` (same frames) and `outside`; returns the last inside point.
    let edge = |mut inside: f64, mut outside: f64| -> Result<f64> {
        if same(outside)? {
            return Ok(outside);
        }
        for _ in 0..100 {
            let mid = 0.5 * (inside + outside);
            if same(mid)? {
                inside = mid;
            } else {
                outside = mid;
            }
        }
        Ok(inside)
    };
    let (low, high) = (edge(t, bounds.0)?, edge(t, bounds.1)?);
    let mid = 0.5 * (low + high);
    Ok(if same(mid)? { mid } else { t })
}

/// The series the report draws under a movement threshold: movement accumulated over
/// consecutive frames since the previous keyframe (0 at a keyframe, `movement[i]` being the
/// movement from frame i-1 to frame i), NaN outside the sampled range `lo..=hi` (none: every
/// frame). On the frames [`spacing`] had as candidates it is the sum that sampler compared with
/// its threshold, as long as no later step moved the keyframes.
pub fn accumulated(
    movement: &[f64],
    keyframes: &[usize],
    range: Option<(usize, usize)>,
) -> Vec<f64> {
    let (lo, hi) = range.unwrap_or((0, movement.len().saturating_sub(1)));
    let mut out = vec![f64::NAN; movement.len()];
    let mut sum = 0.0;
    for (f, o) in out.iter_mut().enumerate().take(hi + 1).skip(lo) {
        if f > lo {
            sum += movement[f];
        }
        *o = sum;
        if keyframes.binary_search(&f).is_ok() {
            sum = 0.0;
        }
    }
    out
}

/// A movement threshold (spacing's or the stationary sampler's) as a per-frame series over
/// `frames` frames: `threshold` within the sampled range `lo..=hi` (none: every frame), NaN
/// outside.
pub fn threshold_series(frames: usize, range: Option<(usize, usize)>, threshold: f64) -> Vec<f64> {
    let (lo, hi) = range.unwrap_or((0, frames.saturating_sub(1)));
    (0..frames)
        .map(|f| {
            if (lo..=hi).contains(&f) {
                threshold
            } else {
                f64::NAN
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn count_threshold_keeps_that_many() {
        let mv: Vec<f64> = (0..300)
            .map(|i| if i == 0 { 0.0 } else { 1.0 + (i % 7) as f64 })
            .collect();
        let c: Vec<usize> = (0..300).collect();
        let total: f64 = mv.iter().sum();
        for n in [1, 2, 10, 37, 100, 250] {
            let t = super::spacing_for_count(&c, &mv, n).unwrap();
            let got = super::spacing(&c, &mv, t).unwrap().len();
            // No threshold on a fine grid keeps a count nearer to n.
            let best = (1..=4000)
                .map(|k| {
                    super::spacing(&c, &mv, total * k as f64 / 4000.0)
                        .unwrap()
                        .len()
                })
                .map(|m| m.abs_diff(n))
                .min()
                .unwrap();
            assert!(
                got.abs_diff(n) <= best,
                "count {n}: kept {got}, a grid threshold gets within {best}"
            );
            if n <= 37 {
                assert_eq!(got, n);
            }
            // Centred: the same frames at 0.1 % either side of the threshold.
            let keys = super::spacing(&c, &mv, t).unwrap();
            for x in [t * 0.999, t * 1.001] {
                assert_eq!(
                    super::spacing(&c, &mv, x).unwrap(),
                    keys,
                    "count {n}: {x} vs {t}"
                );
            }
        }
        assert!(super::spacing_for_count(&c, &vec![0.0; 300], 5).is_err());
    }

    #[test]
    fn accumulated_series_reaches_the_threshold_at_each_keyframe() {
        let mv: Vec<f64> = (0..20).map(|i| if i == 0 { 0.0 } else { 1.0 }).collect();
        let c: Vec<usize> = (2..18).collect();
        let k = super::spacing(&c, &mv, 4.0).unwrap();
        let acc = super::accumulated(&mv, &k, Some((2, 17)));
        assert!(acc[1].is_nan() && acc[18].is_nan());
        assert_eq!(acc[2], 0.0);
        for &f in &k[1..] {
            assert_eq!(acc[f], 4.0, "frame {f}");
        }
        let t = super::threshold_series(20, Some((2, 17)), 4.0);
        assert!(t[1].is_nan() && t[2] == 4.0 && t[17] == 4.0 && t[18].is_nan());
    }

    #[test]
    fn keeps_a_frame_per_threshold_of_movement() {
        // Speed 1 px/frame for 10 frames, then 5 px/frame.
        let mv: Vec<f64> = (0..20)
            .map(|i| {
                if i == 0 {
                    0.0
                } else if i <= 10 {
                    1.0
                } else {
                    5.0
                }
            })
            .collect();
        let c: Vec<usize> = (0..20).collect();
        let k = super::spacing(&c, &mv, 5.0).unwrap();
        assert_eq!(k, vec![0, 5, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19]);
        // Sparse candidates sum the movement in between.
        let k = super::spacing(&[0, 3, 6, 9], &mv, 5.0).unwrap();
        assert_eq!(k, vec![0, 6]);
    }
}
