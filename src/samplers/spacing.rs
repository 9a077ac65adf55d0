//! `spacing`: even camera movement between keyframes. Movement between consecutive candidates is
//! the sum of the per-frame-pair movements between them; a candidate becomes a keyframe when the
//! movement accumulated since the last keyframe reaches the threshold (the first candidate is
//! always kept).

use crate::error::{Error, Result};

/// Candidates spaced by `threshold` of accumulated movement; `movement[i]` is the movement from
/// frame i-1 to frame i.
pub fn spacing(candidates: &[usize], movement: &[f64], threshold: f64) -> Result<Vec<usize>> {
    if !(threshold.is_finite() && threshold > 0.0) {
        return Err(Error::Plugin {
            plugin: "spacing",
            msg: format!("threshold must be a positive number of pixels, got {threshold}"),
        });
    }
    if let Some(&bad) = candidates.iter().find(|&&c| c >= movement.len()) {
        return Err(Error::Plugin {
            plugin: "spacing",
            msg: format!("frame {bad} has no movement value"),
        });
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

#[cfg(test)]
mod tests {
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
