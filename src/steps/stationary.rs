//! `stationary` (the paper's reference mode) as a streaming step: fed frame by frame, in order,
//! with the movement from its reference frame, it decides keyframes and re-anchoring. It never
//! touches pixels: whoever feeds it measures the movement it asks for, and only then.

use super::{Applied, Bound, Boundaries, Flag, FlagValues, Inputs, Step, Threshold};
use crate::error::{Error, Result as KfResult};
use crate::params::StationaryRequest;
use crate::source::Metadata;

/// `--stationary`, `--stationary-threshold`, `--reset-delta`, `--auto`.
pub const FLAGS: &[Flag] = &[
    Flag::switch("stationary", "Drop frames where the camera stands still (reference mode: a frame becomes a keyframe when the movement since the last keyframe reaches --stationary-threshold)"),
    Flag::value::<f64>("stationary-threshold", "PX", "Stationary threshold in full-resolution pixels (default: 1 % of the frame width)")
        .sets("stationary", "threshold"),
    Flag::value::<usize>("reset-delta", "N", "Frames after which the stationary reference frame is re-anchored (carrying the movement accumulated so far), so flow is never asked across a larger gap")
        .default("15")
        .sets("stationary", "reset_delta"),
    Flag::switch("auto", "Propose the stationary threshold from a sample of 40 frame pairs (explained on stderr)")
        .sets("stationary", "threshold"),
];

/// The step when `--stationary` is given.
pub fn from_flags(v: &FlagValues) -> KfResult<Option<Step>> {
    if !v.given("stationary") {
        return Ok(None);
    }
    let threshold = match (v.get::<f64>("stationary-threshold")?, v.given("auto")) {
        (Some(t), _) => Some(Threshold::Px(t)),
        (None, true) => Some(Threshold::Auto),
        (None, false) => None,
    };
    Ok(Some(Step::Stationary {
        threshold,
        reset_delta: v.get("reset-delta")?,
    }))
}

/// The stationary step's settings: its threshold (`auto` resolved; None: 1 % of the frame width)
/// and reset delta, before an input gives its [`StationaryRequest`] (threshold and frame range).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StationarySettings {
    /// Pixels of movement at full resolution.
    pub threshold: Option<f64>,
    /// Frames after which the reference is re-anchored.
    pub reset_delta: usize,
}

impl StationarySettings {
    /// The stationary run for this input: the threshold and the candidate range resolved.
    pub fn request(
        self,
        b: &Boundaries,
        meta: &Metadata,
        timestamps_s: Option<&[f64]>,
    ) -> KfResult<StationaryRequest> {
        let err = |msg: String| Error::step("stationary", msg);
        let (first, last) = match meta.frame_count_exact {
            true => {
                let c = b.candidates(meta.frame_count, timestamps_s)?;
                (c[0], *c.last().unwrap_or(&c[0]))
            }
            false => {
                let frame = |b: Option<Bound>, or: usize| match b {
                    Some(Bound::Frame(i)) => i,
                    _ => or,
                };
                (frame(b.start, 0), frame(b.end, usize::MAX))
            }
        };
        let threshold = self.threshold.unwrap_or(f64::from(meta.width) * 0.01);
        crate::numbers::positive_px(threshold).map_err(|m| err(format!("threshold {m}")))?;
        if self.reset_delta == 0 {
            return Err(err("reset delta must be at least 1 frame".into()));
        }
        Ok(StationaryRequest {
            threshold,
            reset_delta: self.reset_delta,
            first,
            last,
        })
    }
}

/// The step on `keys`: the keyframes of the stationary run in `at`.
pub fn apply(at: &Inputs, keys: &mut Vec<usize>) -> KfResult<Applied> {
    let (req, run, backend) = at
        .stationary
        .ok_or_else(|| Error::step("stationary", "no stationary run was computed"))?;
    keys.retain(|k| run.binary_search(k).is_ok());
    Ok(Applied::Stationary {
        auto: at.stationary_auto,
        backend: Some(backend),
        movement: at.movement_request,
        reset_delta: Some(req.reset_delta),
        threshold_px: Some(req.threshold),
    })
}

/// The stationary sampler's reference-mode state machine: its run's parameters, the reference
/// frame, the movement accumulated since the last keyframe and the keyframes so far.
#[derive(Debug, Clone, PartialEq)]
pub struct StationarySampler {
    params: StationaryRequest,
    reference: Option<usize>,
    accumulated: f64,
    keys: Vec<usize>,
}

impl StationarySampler {
    /// A frame becomes a keyframe when the movement since the last keyframe reaches the
    /// threshold; after `reset_delta` frames without one the reference moves to the current frame,
    /// carrying the movement accumulated so far. Candidates are frames `first..=last`.
    pub fn new(params: StationaryRequest) -> StationarySampler {
        StationarySampler {
            params,
            reference: None,
            accumulated: 0.0,
            keys: Vec::new(),
        }
    }

    /// Continues from a saved state (see [`StationarySampler::reference`], [`StationarySampler::accumulated`],
    /// [`StationarySampler::keys`]).
    pub fn restore(&mut self, reference: Option<usize>, accumulated: f64, keys: Vec<usize>) {
        self.reference = reference;
        self.accumulated = accumulated;
        self.keys = keys;
    }

    /// Whether frame `i` is a candidate (the step must then be fed it).
    pub fn wants(&self, i: usize) -> bool {
        (self.params.first..=self.params.last).contains(&i)
    }

    /// The frame movement is measured from.
    pub fn reference(&self) -> Option<usize> {
        self.reference
    }

    /// Movement accumulated since the last keyframe by re-anchorings.
    pub fn accumulated(&self) -> f64 {
        self.accumulated
    }

    /// Keyframes so far, ascending.
    pub fn keys(&self) -> &[usize] {
        &self.keys
    }

    /// Takes frame `i` (after every earlier candidate). `measure(reference)` gives the movement
    /// from the reference frame to `i` in full-resolution pixels; it is called only when there
    /// is a reference. Returns whether `i` is now the reference (a keyframe or a re-anchoring).
    pub fn step<E>(
        &mut self,
        i: usize,
        measure: impl FnOnce(usize) -> Result<f64, E>,
    ) -> Result<bool, E> {
        if !self.wants(i) {
            return Ok(false);
        }
        let Some(reference) = self.reference else {
            self.keyframe(i);
            return Ok(true);
        };
        let total = self.accumulated + measure(reference)?;
        if total >= self.params.threshold {
            self.keyframe(i);
            Ok(true)
        } else if i - reference >= self.params.reset_delta {
            self.reference = Some(i);
            self.accumulated = total;
            Ok(true)
        } else {
            Ok(false)
        }
    }

    fn keyframe(&mut self, i: usize) {
        self.keys.push(i);
        self.reference = Some(i);
        self.accumulated = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::StationarySampler;
    use crate::params::StationaryRequest;
    use std::convert::Infallible;

    fn sampler(threshold: f64, reset_delta: usize, first: usize, last: usize) -> StationarySampler {
        StationarySampler::new(StationaryRequest {
            threshold,
            reset_delta,
            first,
            last,
        })
    }

    /// Feeds frames `0..n` with movement `per_frame[r..=i]` summed from the reference `r`;
    /// returns the keys and the references asked for.
    fn run(st: &mut StationarySampler, per_frame: &[f64]) -> (Vec<usize>, Vec<(usize, usize)>) {
        let mut asked = Vec::new();
        for i in 0..per_frame.len() {
            st.step(i, |r| {
                asked.push((r, i));
                Ok::<_, Infallible>(per_frame[r + 1..=i].iter().sum())
            })
            .unwrap();
        }
        (st.keys().to_vec(), asked)
    }

    #[test]
    fn keyframe_when_threshold_reached() {
        let mut st = sampler(3.0, 100, 0, 9);
        let (keys, asked) = run(&mut st, &[0.0, 1.0, 1.0, 1.0, 0.5, 2.9, 0.1, 0.0, 5.0, 0.0]);
        // 1+1+1 = 3 reaches 3 at frame 3; 0.5+2.9 = 3.4 at 5; 0.1+0+5 at 8.
        assert_eq!(keys, vec![0, 3, 5, 8]);
        assert_eq!(asked.first(), Some(&(0, 1)));
        assert!(asked.iter().all(|&(r, i)| keys.contains(&r) && r < i));
        assert_eq!(st.reference(), Some(8));
        assert_eq!(st.accumulated(), 0.0);
    }

    #[test]
    fn reset_delta_reanchors_carrying_the_movement() {
        let mut st = sampler(10.0, 3, 0, 9);
        let (keys, asked) = run(&mut st, &[0.0; 10].map(|_| 1.0));
        // Frame 3 is 3 frames from 0: re-anchored there with 3 px carried; frame 6 carries 6;
        // frame 9 has 6 + 3 = 9 < 10 and is re-anchored again.
        assert_eq!(keys, vec![0]);
        assert_eq!(
            asked.iter().map(|a| a.0).collect::<Vec<_>>(),
            vec![0, 0, 0, 3, 3, 3, 6, 6, 6]
        );
        assert_eq!(st.reference(), Some(9));
        assert_eq!(st.accumulated(), 9.0);
        let mut more = sampler(10.0, 3, 0, 10);
        let (keys, _) = run(&mut more, &[1.0; 11]);
        assert_eq!(
            keys,
            vec![0, 10],
            "the carried 9 px plus 1 reach the threshold"
        );
    }

    #[test]
    fn only_frames_in_range_are_candidates() {
        let mut st = sampler(2.0, 100, 3, 7);
        let (keys, asked) = run(&mut st, &[5.0; 12]);
        assert_eq!(keys, vec![3, 4, 5, 6, 7]);
        assert!(asked
            .iter()
            .all(|&(r, i)| (3..=7).contains(&r) && (4..=7).contains(&i)));
        assert!(!st.wants(2) && st.wants(3) && st.wants(7) && !st.wants(8));
    }

    #[test]
    fn below_threshold_and_reset_keeps_the_reference() {
        let mut st = sampler(1.0, 2, 0, 5);
        let ok = |m: f64| move |_: usize| Ok::<_, Infallible>(m);
        assert_eq!(st.step(0, ok(9.0)), Ok(true), "first frame: no measurement");
        assert_eq!(st.step(1, ok(0.25)), Ok(false));
        assert_eq!(st.step(2, ok(0.5)), Ok(true), "2 frames on: re-anchored");
        assert_eq!((st.reference(), st.accumulated()), (Some(2), 0.5));
        assert_eq!(st.step(3, ok(0.5)), Ok(true), "0.5 carried + 0.5 reach 1");
        assert_eq!((st.keys(), st.accumulated()), (&[0, 3][..], 0.0));
    }

    #[test]
    fn restored_state_goes_on_as_an_uninterrupted_one() {
        let per_frame = [0.0, 0.4, 0.7, 0.2, 0.9, 0.1, 0.3, 1.2, 0.05, 0.6, 0.6, 0.0];
        let mut whole = sampler(1.0, 3, 1, 11);
        run(&mut whole, &per_frame);
        let mut first = sampler(1.0, 3, 1, 11);
        run(&mut first, &per_frame[..6]);
        let mut resumed = sampler(1.0, 3, 1, 11);
        resumed.restore(
            first.reference(),
            first.accumulated(),
            first.keys().to_vec(),
        );
        for i in 6..per_frame.len() {
            resumed
                .step(i, |r| {
                    Ok::<_, Infallible>(per_frame[r + 1..=i].iter().sum())
                })
                .unwrap();
        }
        assert_eq!(resumed, whole);
    }

    #[test]
    fn a_failed_measurement_changes_nothing() {
        let mut st = sampler(1.0, 2, 0, 5);
        st.step(0, |_| Ok::<_, ()>(0.0)).unwrap();
        let before = st.clone();
        assert_eq!(st.step(1, |_| Err("flow failed")), Err("flow failed"));
        assert_eq!(st, before);
    }
}
