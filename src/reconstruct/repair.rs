//! Choosing the frame that repairs a broken link, from the project's per-frame cache alone (no
//! pixels). Guarantees: the frame lies strictly between the two keyframes; it is never a damaged
//! frame; never a frame the blur step rejects when a frame it keeps lies in the gap; never a
//! textureless frame (black, or nearly: sharpness under [`TEXTURELESS`] of the median) — a gap
//! holding only such frames, or no frame at all, is a true break; among the usable frames it is
//! the sharpest within the middle half of the gap, measured by accumulated movement when the
//! project has a movement series, else by time (or frame index without timestamps).

use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;

/// A frame is textureless when its sharpness is below this fraction of the median sharpness
/// of the sampled range.
pub const TEXTURELESS: f64 = 0.05;

/// What the gap's middle is measured by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Measure {
    /// Movement accumulated from the project's movement series.
    Movement,
    /// Timestamps (or frame indices without them): the project has no movement series.
    Time,
}

/// The per-frame numbers a repair reads (each series one value per frame of the input).
#[derive(Debug, Clone, Default)]
pub struct Frames<'a> {
    /// Movement from frame i-1 to frame i.
    pub movement: Option<&'a [f64]>,
    /// Presentation times in seconds.
    pub times: Option<&'a [f64]>,
    /// Sharpness scores.
    pub sharpness: Option<&'a [f64]>,
    /// Frames the blur step rejects.
    pub rejected: BTreeSet<usize>,
    /// Frames that could not be decoded.
    pub damaged: BTreeSet<usize>,
    /// Sharpness below which a frame is textureless (None: no sharpness known).
    pub textureless_below: Option<f64>,
}

/// The repair of one gap.
#[derive(Debug, Clone, PartialEq)]
pub enum Choice {
    /// Add this frame.
    Frame {
        /// Frame index.
        frame: usize,
        /// How it was chosen, for the history (`sharpest near the middle by movement`).
        how: String,
    },
    /// Nothing in the gap can repair it.
    TrueBreak {
        /// Why (`adjacent frames`, `only textureless frames between`).
        why: String,
    },
}

impl Frames<'_> {
    /// What the middle of a gap is measured by.
    pub fn measure(&self) -> Measure {
        if self.movement.is_some() {
            Measure::Movement
        } else {
            Measure::Time
        }
    }

    /// The position of frame `i` along the measure.
    fn position(&self, acc: &[f64], i: usize) -> f64 {
        match (self.movement, self.times) {
            (Some(_), _) => acc.get(i).copied().unwrap_or(i as f64),
            (None, Some(t)) => t.get(i).copied().unwrap_or(i as f64),
            (None, None) => i as f64,
        }
    }

    fn textureless(&self, i: usize) -> bool {
        match (self.sharpness, self.textureless_below) {
            (Some(s), Some(floor)) => s.get(i).is_some_and(|&v| v < floor),
            _ => false,
        }
    }
}

/// The movement accumulated from frame `a` to each frame of `a..=b`, indexed from `a`.
fn accumulated(movement: &[f64], a: usize, b: usize) -> Vec<f64> {
    let mut acc = Vec::with_capacity(b - a + 1);
    let mut total = 0.0;
    for i in a..=b {
        if i > a {
            let m = movement.get(i).copied().unwrap_or(0.0);
            total += if m.is_finite() { m.max(0.0) } else { 0.0 };
        }
        acc.push(total);
    }
    acc
}

/// The frame that repairs the gap between keyframes `a < b`.
pub fn choose(a: usize, b: usize, f: &Frames) -> Choice {
    if b <= a + 1 {
        return Choice::TrueBreak {
            why: "adjacent frames: nothing lies between them".into(),
        };
    }
    let inside: Vec<usize> = (a + 1..b).filter(|i| !f.damaged.contains(i)).collect();
    if inside.is_empty() {
        return Choice::TrueBreak {
            why: "every frame between them is damaged".into(),
        };
    }
    let textured: Vec<usize> = inside
        .iter()
        .copied()
        .filter(|&i| !f.textureless(i))
        .collect();
    if textured.is_empty() {
        return Choice::TrueBreak {
            why: format!(
                "only textureless frames between them (sharpness under {} % of the median)",
                TEXTURELESS * 100.0
            ),
        };
    }
    let kept: Vec<usize> = textured
        .iter()
        .copied()
        .filter(|i| !f.rejected.contains(i))
        .collect();
    let (pool, blurred) = if kept.is_empty() {
        (textured, true)
    } else {
        (kept, false)
    };
    // Positions relative to `a` (accumulated movement, or time).
    let acc = match f.movement {
        Some(m) => accumulated(m, a, b),
        None => Vec::new(),
    };
    let pos = |i: usize| match f.movement {
        Some(_) => f.position(&acc, i - a),
        None => f.position(&acc, i),
    };
    let (pa, pb) = (pos(a), pos(b));
    let mid = (pa + pb) / 2.0;
    let quarter = (pb - pa).abs() / 4.0;
    let distance = |i: usize| (pos(i) - mid).abs();
    let window: Vec<usize> = pool
        .iter()
        .copied()
        .filter(|&i| distance(i) <= quarter)
        .collect();
    let score = |i: usize| f.sharpness.and_then(|s| s.get(i).copied()).unwrap_or(0.0);
    let by_middle = |x: &usize, y: &usize| distance(*x).total_cmp(&distance(*y)).then(x.cmp(y));
    let frame = if window.is_empty() {
        // Nothing usable in the middle half: the usable frame nearest the middle.
        pool.iter().copied().min_by(by_middle)
    } else if f.sharpness.is_some() {
        window
            .iter()
            .copied()
            .max_by(|x, y| score(*x).total_cmp(&score(*y)).then(by_middle(y, x)))
    } else {
        window.iter().copied().min_by(by_middle)
    };
    let measure = match f.measure() {
        Measure::Movement => "accumulated movement",
        Measure::Time if f.times.is_some() => "time",
        Measure::Time => "frame index",
    };
    let how = match (window.is_empty(), f.sharpness.is_some()) {
        (false, true) => format!("the sharpest frame of the gap's middle half by {measure}"),
        _ => format!("the frame nearest the gap's middle by {measure}"),
    };
    let how = if blurred {
        format!("{how} (every textured frame of the gap is one the blur step rejects)")
    } else {
        how
    };
    match frame {
        Some(frame) => Choice::Frame { frame, how },
        None => Choice::TrueBreak {
            why: "no usable frame between them".into(),
        },
    }
}

/// The median of the finite values of `scores[lo..=hi]` (None when there are none).
pub fn median(scores: &[f64], lo: usize, hi: usize) -> Option<f64> {
    let mut v: Vec<f64> = scores
        .get(lo..=hi.min(scores.len().saturating_sub(1)))?
        .iter()
        .copied()
        .filter(|x| x.is_finite())
        .collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(c: Choice) -> usize {
        match c {
            Choice::Frame { frame, .. } => frame,
            other => panic!("expected a frame, got {other:?}"),
        }
    }

    #[test]
    fn adjacent_and_damaged_gaps_are_true_breaks() {
        let f = Frames::default();
        assert!(matches!(choose(4, 5, &f), Choice::TrueBreak { .. }));
        let f = Frames {
            damaged: [5, 6].into(),
            ..Frames::default()
        };
        assert!(matches!(choose(4, 7, &f), Choice::TrueBreak { .. }));
        assert_eq!(frame(choose(4, 8, &f)), 7);
    }

    #[test]
    fn middle_by_time_without_movement() {
        let f = Frames::default();
        assert_eq!(frame(choose(0, 10, &f)), 5);
        let times: Vec<f64> = (0..11)
            .map(|i| if i < 8 { i as f64 * 0.1 } else { 10.0 })
            .collect();
        let f = Frames {
            times: Some(&times),
            ..Frames::default()
        };
        // Frames 0..=7 span 0.7 s, then a jump to 10 s: no frame lies in the middle half
        // (2.5 s to 7.5 s); frame 7 (0.7 s) is the nearest to 5 s.
        assert_eq!(frame(choose(0, 10, &f)), 7);
    }

    #[test]
    fn middle_by_accumulated_movement() {
        // All the movement happens between frames 8 and 10.
        let mut movement = vec![0.0; 11];
        movement[9] = 10.0;
        movement[10] = 10.0;
        let f = Frames {
            movement: Some(&movement),
            ..Frames::default()
        };
        assert_eq!(f.measure(), Measure::Movement);
        assert_eq!(frame(choose(0, 10, &f)), 9);
    }

    #[test]
    fn sharpest_of_the_middle_half_and_never_a_rejected_one() {
        let mut sharp = vec![10.0; 21];
        sharp[13] = 30.0; // within the middle half (5..=15)
        sharp[17] = 99.0; // outside it
        let f = Frames {
            sharpness: Some(&sharp),
            textureless_below: Some(0.5),
            ..Frames::default()
        };
        assert_eq!(frame(choose(0, 20, &f)), 13);
        let f = Frames {
            rejected: [13].into(),
            ..f
        };
        // Ties among the rest: the one nearest the middle.
        assert_eq!(frame(choose(0, 20, &f)), 10);
        // Every frame rejected but one outside the middle half: that one.
        let f = Frames {
            rejected: (1..20).filter(|&i| i != 2).collect(),
            ..f
        };
        assert_eq!(frame(choose(0, 20, &f)), 2);
        // Every frame rejected: the sharpest of the middle, said so.
        let f = Frames {
            rejected: (1..20).collect(),
            ..f
        };
        match choose(0, 20, &f) {
            Choice::Frame { frame, how } => {
                assert_eq!(frame, 13);
                assert!(how.contains("blur step rejects"), "{how}");
            }
            c => panic!("{c:?}"),
        }
    }

    #[test]
    fn textureless_frames_are_skipped_and_a_black_gap_is_a_true_break() {
        let mut sharp = vec![10.0; 21];
        for s in &mut sharp[3..=18] {
            *s = 0.01;
        }
        let f = Frames {
            sharpness: Some(&sharp),
            textureless_below: Some(0.5),
            ..Frames::default()
        };
        // Nearest the middle among the textured frames 1, 2, 19.
        assert_eq!(frame(choose(0, 20, &f)), 2);
        assert!(matches!(choose(2, 19, &f), Choice::TrueBreak { .. }));
    }

    #[test]
    fn median_of_a_range() {
        assert_eq!(median(&[5.0, 1.0, 3.0, 9.0], 0, 2), Some(3.0));
        assert_eq!(median(&[], 0, 2), None);
    }
}
