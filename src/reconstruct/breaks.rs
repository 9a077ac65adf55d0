//! Where a reconstruction of a keyframe set is broken: pure functions over what COLMAP made
//! (which model registered each keyframe, the 3D points consecutive keyframes share, the inlier
//! matches of their two-view geometry, how well the model's poses explain those matches) and
//! over the project's telemetry where it has some. Guarantees: every consecutive pair of
//! keyframes is judged once, in frame order, and gets at most one reason; a pair is sound only
//! when both keyframes are registered in the same model, share at least `min_shared` 3D points,
//! rest on at least `min_inliers` inliers, the model's relative pose explains at least
//! [`MIN_EXPLAINED`] of those inliers, the model's turn between them is within
//! [`MAX_TURN_ERROR_DEG`] of the telemetry's, and neither lies further than
//! [`max_off_track_m`] from its telemetry position; the set is connected exactly when no pair
//! is broken and one model registers every keyframe.

use crate::sparse::Limits;
use serde::{Deserialize, Serialize};

/// What COLMAP made of a keyframe set, by keyframe position (0 = the first keyframe).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Observed {
    /// Per keyframe: the model (its index in `models`) that registered it, if any.
    pub model_of: Vec<Option<usize>>,
    /// The models' folders, relative to the COLMAP workspace (`sparse/0`).
    pub models: Vec<String>,
    /// Per consecutive pair `(i, i + 1)`: 3D points whose tracks hold both (0 when they are not
    /// in one model).
    pub shared: Vec<usize>,
    /// Per consecutive pair: inlier matches of their two-view geometry in the database (None:
    /// no database was read).
    pub inliers: Vec<Option<usize>>,
    /// Per consecutive pair in one model: the fraction of its two-view inliers the model's
    /// relative pose explains (`epipolar::agreement`; None: not measured).
    pub explained: Vec<Option<f64>>,
    /// Per consecutive pair in one model: the model's turn and the telemetry's turn between
    /// them, degrees (None: the telemetry has no gimbal angles there).
    pub turns: Vec<Option<(f64, f64)>>,
    /// Per keyframe: metres from its telemetry position after the similarity alignment of its
    /// model to the telemetry (None: no telemetry or no alignment).
    pub off_track_m: Vec<Option<f64>>,
    /// The telemetry path's length over the keyframes, metres (0: no telemetry).
    pub path_m: f64,
}

/// A pair is inconsistent when the model's relative pose explains less than this fraction of its
/// two-view inliers. Correct models explain 95–100 % (docs/reconstruct.md).
pub const MIN_EXPLAINED: f64 = 0.5;

/// A pair disagrees with the telemetry when the model's turn between them differs from the
/// gimbal's by more than this many degrees. Correct models differ by at most 0.4°, the
/// mis-assembled seed-3 model by 7–15° on its straight legs (docs/reconstruct.md).
pub const MAX_TURN_ERROR_DEG: f64 = 5.0;

/// A keyframe is off its track when it lies further than this percentage of the telemetry's
/// path from its telemetry position after the alignment ...
pub const MAX_OFF_TRACK_PCT: f64 = 5.0;

/// ... and further than this many metres (GPS noise).
pub const MIN_OFF_TRACK_M: f64 = 3.0;

/// The distance from its telemetry position beyond which a keyframe is off its track, for a
/// telemetry path of `path_m` metres.
pub fn max_off_track_m(path_m: f64) -> f64 {
    (MAX_OFF_TRACK_PCT / 100.0 * path_m).max(MIN_OFF_TRACK_M)
}

/// Why a pair of consecutive keyframes is broken.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Why {
    /// One or both keyframes are registered in no model.
    Unregistered {
        /// The unregistered frames of the pair.
        frames: Vec<usize>,
    },
    /// Both are registered, in different models.
    Split {
        /// The first keyframe's model.
        from_model: String,
        /// The second keyframe's model.
        to_model: String,
    },
    /// One model, but fewer 3D points shared than asked.
    FewShared {
        /// 3D points both keyframes observe.
        shared: usize,
        /// `--min-shared`.
        min: usize,
    },
    /// One model, but the pair's relative pose rests on too few inlier matches.
    FewInliers {
        /// Inlier matches of the pair's two-view geometry.
        inliers: usize,
        /// `--min-inliers`.
        min: usize,
    },
    /// One model, but its relative pose of the pair contradicts the pair's own matches.
    Inconsistent {
        /// Percentage of the two-view inliers the model's relative pose explains.
        explained_pct: f64,
        /// Inlier matches of the pair's two-view geometry.
        inliers: usize,
    },
    /// One model, but it turns the camera between them otherwise than the telemetry's gimbal.
    TurnAgainstTelemetry {
        /// The model's turn, degrees.
        model_deg: f64,
        /// The gimbal's turn, degrees.
        telemetry_deg: f64,
    },
    /// One model, but a keyframe of the pair lies off the telemetry's track.
    OffTrack {
        /// The keyframe furthest off.
        frame: usize,
        /// Its distance from its telemetry position after the alignment, metres.
        off_m: f64,
        /// The distance allowed, metres.
        max_m: f64,
        /// The telemetry path's length, metres.
        path_m: f64,
    },
}

impl Why {
    /// Whether the pair is broken because the model is assembled wrongly there (rather than
    /// not joined at all).
    pub fn mis_assembled(&self) -> bool {
        matches!(
            self,
            Why::Inconsistent { .. } | Why::TurnAgainstTelemetry { .. } | Why::OffTrack { .. }
        )
    }
}

impl std::fmt::Display for Why {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Why::Unregistered { frames } => {
                let list: Vec<String> = frames.iter().map(usize::to_string).collect();
                match list.split_last() {
                    Some((last, rest)) if !rest.is_empty() => write!(
                        f,
                        "frames {} and {last} registered in no model",
                        rest.join(", ")
                    ),
                    _ => write!(f, "frame {} registered in no model", list.join("")),
                }
            }
            Why::Split {
                from_model,
                to_model,
            } => write!(f, "in different models ({from_model}, {to_model})"),
            Why::FewShared { shared, min } => {
                write!(f, "{shared} shared 3D points (fewer than {min})")
            }
            Why::FewInliers { inliers, min } => {
                write!(f, "{inliers} two-view inliers (fewer than {min})")
            }
            Why::Inconsistent {
                explained_pct,
                inliers,
            } => write!(
                f,
                "mis-assembled: the model's relative pose explains {explained_pct:.0} % of their {inliers} two-view inliers (under {:.0} %)",
                MIN_EXPLAINED * 100.0
            ),
            Why::TurnAgainstTelemetry {
                model_deg,
                telemetry_deg,
            } => write!(
                f,
                "mis-assembled: the model turns {model_deg:.1}° between them, the telemetry's gimbal {telemetry_deg:.1}° (more than {MAX_TURN_ERROR_DEG}° apart)"
            ),
            Why::OffTrack {
                frame,
                off_m,
                max_m,
                path_m,
            } => write!(
                f,
                "mis-assembled: frame {frame} lies {off_m:.1} m ({:.1} % of the {path_m:.0} m path) from its telemetry position after a similarity alignment (over {max_m:.1} m)",
                if *path_m > 0.0 { 100.0 * off_m / path_m } else { 0.0 }
            ),
        }
    }
}

/// A broken link between consecutive keyframes `from` and `to` (frame indices).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Break {
    /// The earlier keyframe.
    pub from: usize,
    /// The later keyframe.
    pub to: usize,
    /// What is wrong.
    pub why: Why,
    /// Inlier matches of the pair's two-view geometry in the database, 0 when it has none
    /// (None: no database was read; states of earlier builds).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inliers: Option<usize>,
}

impl Break {
    /// Whether the pair's own matches are thin: fewer verified inliers than `min`, the count
    /// COLMAP's mapper needs to start a model from a pair. Frames are missing there; a pair
    /// that matches well but is split or mis-assembled is a failure of the mapping, which the
    /// next mapping may not repeat.
    pub fn thin(&self, min: usize) -> bool {
        self.inliers.is_some_and(|n| n < min)
    }
}

/// The broken links of `keyframes` (sorted frame indices), in frame order.
pub fn find(keyframes: &[usize], obs: &Observed, limits: Limits) -> Vec<Break> {
    let model = |i: usize| obs.model_of.get(i).copied().flatten();
    let mut out = Vec::new();
    for (i, pair) in keyframes.windows(2).enumerate() {
        let (from, to) = (pair[0], pair[1]);
        let why = match (model(i), model(i + 1)) {
            (a, b) if a.is_none() || b.is_none() => {
                let frames = [(a, from), (b, to)]
                    .into_iter()
                    .filter(|(m, _)| m.is_none())
                    .map(|(_, f)| f)
                    .collect();
                Some(Why::Unregistered { frames })
            }
            (Some(a), Some(b)) if a != b => Some(Why::Split {
                from_model: obs.models.get(a).cloned().unwrap_or_default(),
                to_model: obs.models.get(b).cloned().unwrap_or_default(),
            }),
            _ => {
                let shared = obs.shared.get(i).copied().unwrap_or(0);
                let inliers = obs.inliers.get(i).copied().flatten();
                if shared < limits.min_shared {
                    Some(Why::FewShared {
                        shared,
                        min: limits.min_shared,
                    })
                } else {
                    match inliers {
                        Some(n) if n < limits.min_inliers => Some(Why::FewInliers {
                            inliers: n,
                            min: limits.min_inliers,
                        }),
                        _ => mis_assembled(obs, i, (from, to), inliers.unwrap_or(0)),
                    }
                }
            }
        };
        if let Some(why) = why {
            let inliers = obs.inliers.get(i).copied().flatten();
            out.push(Break {
                from,
                to,
                why,
                inliers,
            });
        }
    }
    // A single keyframe left unregistered has no pair to break.
    if keyframes.len() == 1 && model(0).is_none() {
        out.push(Break {
            from: keyframes[0],
            to: keyframes[0],
            why: Why::Unregistered {
                frames: vec![keyframes[0]],
            },
            inliers: None,
        });
    }
    out
}

/// Why the sound-looking pair at position `i` (frames `from`, `to`) is mis-assembled, if it is:
/// its matches, then the telemetry's turn, then its track.
fn mis_assembled(
    obs: &Observed,
    i: usize,
    (from, to): (usize, usize),
    inliers: usize,
) -> Option<Why> {
    if let Some(x) = obs.explained.get(i).copied().flatten() {
        if x < MIN_EXPLAINED {
            return Some(Why::Inconsistent {
                explained_pct: 100.0 * x,
                inliers,
            });
        }
    }
    if let Some((model_deg, telemetry_deg)) = obs.turns.get(i).copied().flatten() {
        if (model_deg - telemetry_deg).abs() > MAX_TURN_ERROR_DEG {
            return Some(Why::TurnAgainstTelemetry {
                model_deg,
                telemetry_deg,
            });
        }
    }
    let max_m = max_off_track_m(obs.path_m);
    let off = |k: usize| {
        obs.off_track_m
            .get(k)
            .copied()
            .flatten()
            .filter(|m| *m > max_m)
    };
    let worst = match (off(i), off(i + 1)) {
        (Some(a), Some(b)) if b > a => Some((to, b)),
        (Some(a), _) => Some((from, a)),
        (None, Some(b)) => Some((to, b)),
        (None, None) => None,
    };
    worst.map(|(frame, off_m)| Why::OffTrack {
        frame,
        off_m,
        max_m,
        path_m: obs.path_m,
    })
}

/// Per consecutive pair of keyframe positions, the tracks that hold both: `tracks` gives, per
/// 3D point, the keyframe positions that observe it (any order, repeats allowed).
pub fn shared_points<'a>(n: usize, tracks: impl Iterator<Item = &'a [usize]>) -> Vec<usize> {
    let mut shared = vec![0; n.saturating_sub(1)];
    let mut seen: Vec<usize> = Vec::new();
    for t in tracks {
        seen.clear();
        seen.extend_from_slice(t);
        seen.sort_unstable();
        seen.dedup();
        for w in seen.windows(2) {
            if w[1] == w[0] + 1 {
                if let Some(s) = shared.get_mut(w[0]) {
                    *s += 1;
                }
            }
        }
    }
    shared
}

/// The ranges of consecutive keyframes (first and last frame index) each model holds.
pub fn ranges(keyframes: &[usize], obs: &Observed) -> Vec<Vec<(usize, usize)>> {
    let mut out = vec![Vec::new(); obs.models.len()];
    let mut i = 0;
    while i < keyframes.len() {
        let Some(m) = obs.model_of.get(i).copied().flatten() else {
            i += 1;
            continue;
        };
        let start = i;
        while i + 1 < keyframes.len() && obs.model_of.get(i + 1).copied().flatten() == Some(m) {
            i += 1;
        }
        if let Some(r) = out.get_mut(m) {
            r.push((keyframes[start], keyframes[i]));
        }
        i += 1;
    }
    out
}

/// Whether the set is one connected piece: one model registers every keyframe and no link is
/// broken.
pub fn connected(obs: &Observed, breaks: &[Break]) -> bool {
    breaks.is_empty()
        && !obs.model_of.is_empty()
        && obs
            .model_of
            .iter()
            .all(|m| *m == obs.model_of[0] && m.is_some())
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: Limits = Limits {
        min_shared: 10,
        min_inliers: 20,
    };

    fn obs(model_of: Vec<Option<usize>>, shared: Vec<usize>) -> Observed {
        let n = model_of.len();
        Observed {
            model_of,
            models: vec!["sparse/0".into(), "sparse/1".into()],
            shared,
            inliers: vec![Some(100); n.saturating_sub(1)],
            ..Observed::default()
        }
    }

    #[test]
    fn one_model_with_strong_links_is_connected() {
        let o = obs(vec![Some(0); 4], vec![50, 40, 30]);
        let b = find(&[0, 10, 20, 30], &o, LIMITS);
        assert!(b.is_empty());
        assert!(connected(&o, &b));
        assert_eq!(ranges(&[0, 10, 20, 30], &o), vec![vec![(0, 30)], vec![]]);
    }

    #[test]
    fn unregistered_split_and_weak_links_are_named() {
        let mut o = obs(
            vec![Some(0), Some(0), None, Some(1), Some(1), Some(1)],
            vec![50, 0, 0, 5, 40],
        );
        o.inliers[4] = Some(12);
        let k = [0, 10, 20, 30, 40, 50];
        o.inliers[1] = Some(0);
        let b = find(&k, &o, LIMITS);
        // Each break carries its pair's inliers from the database.
        let inliers: Vec<Option<usize>> = b.iter().map(|b| b.inliers).collect();
        assert_eq!(inliers, vec![Some(0), Some(100), Some(100), Some(12)]);
        let got: Vec<(usize, usize, Why)> = b.into_iter().map(|b| (b.from, b.to, b.why)).collect();
        assert_eq!(
            got,
            vec![
                (10, 20, Why::Unregistered { frames: vec![20] }),
                (20, 30, Why::Unregistered { frames: vec![20] }),
                (30, 40, Why::FewShared { shared: 5, min: 10 }),
                (
                    40,
                    50,
                    Why::FewInliers {
                        inliers: 12,
                        min: 20
                    }
                ),
            ]
        );
        assert_eq!(ranges(&k, &o), vec![vec![(0, 10)], vec![(30, 50)]]);
        assert!(!connected(&o, &[]));
    }

    #[test]
    fn split_models_break_where_they_meet() {
        let o = obs(vec![Some(0), Some(0), Some(1), Some(1)], vec![50, 0, 50]);
        let b = find(&[0, 5, 9, 14], &o, LIMITS);
        assert_eq!(b.len(), 1);
        assert_eq!((b[0].from, b[0].to), (5, 9));
        assert!(matches!(b[0].why, Why::Split { .. }));
        assert_eq!(
            b[0].why.to_string(),
            "in different models (sparse/0, sparse/1)"
        );
    }

    #[test]
    fn a_mis_assembled_link_breaks_by_its_matches_its_turn_or_its_track() {
        let k = [0, 30, 60, 90, 120];
        let mut o = obs(vec![Some(0); 5], vec![50; 4]);
        o.explained = vec![Some(0.99), Some(0.97), Some(0.98), Some(1.0)];
        o.turns = vec![Some((0.1, 0.0)); 4];
        o.off_track_m = vec![Some(0.2); 5];
        o.path_m = 100.0;
        assert!(find(&k, &o, LIMITS).is_empty());
        // One link the model rotated: its own inliers contradict it.
        o.explained[1] = Some(0.12);
        // Another where the model turns 8° while the gimbal holds still.
        o.turns[2] = Some((8.0, 0.0));
        // A keyframe 7 m off a 100 m track (the limit: 5 m).
        o.off_track_m[4] = Some(7.0);
        let b = find(&k, &o, LIMITS);
        let got: Vec<(usize, usize, Why)> = b.into_iter().map(|b| (b.from, b.to, b.why)).collect();
        assert_eq!(
            got,
            vec![
                (
                    30,
                    60,
                    Why::Inconsistent {
                        explained_pct: 12.0,
                        inliers: 100
                    }
                ),
                (
                    60,
                    90,
                    Why::TurnAgainstTelemetry {
                        model_deg: 8.0,
                        telemetry_deg: 0.0
                    }
                ),
                (
                    90,
                    120,
                    Why::OffTrack {
                        frame: 120,
                        off_m: 7.0,
                        max_m: 5.0,
                        path_m: 100.0
                    }
                ),
            ]
        );
        assert!(got.iter().all(|(_, _, w)| w.mis_assembled()));
        // One model registers every keyframe, but it is not connected while mis-assembled.
        assert!(!connected(&o, &find(&k, &o, LIMITS)));
        assert_eq!(
            got[1].2.to_string(),
            "mis-assembled: the model turns 8.0° between them, the telemetry's gimbal 0.0° (more than 5° apart)"
        );
        assert!(got[2]
            .2
            .to_string()
            .contains("frame 120 lies 7.0 m (7.0 % of the 100 m path)"));
    }

    #[test]
    fn small_turn_errors_and_gps_noise_pass() {
        let k = [0, 30, 60];
        let mut o = obs(vec![Some(0); 3], vec![50; 2]);
        o.explained = vec![Some(0.6), None];
        o.turns = vec![Some((30.0, 26.0)), None];
        // 2.5 m off a 20 m track: over 5 % of it, within the 3 m of GPS noise.
        o.off_track_m = vec![Some(2.5), None, Some(0.1)];
        o.path_m = 20.0;
        assert!(find(&k, &o, LIMITS).is_empty());
        assert_eq!(max_off_track_m(20.0), MIN_OFF_TRACK_M);
        assert_eq!(max_off_track_m(200.0), 10.0);
        // Weak links are named before mis-assembly.
        o.shared[0] = 3;
        o.explained[0] = Some(0.1);
        assert!(matches!(find(&k, &o, LIMITS)[0].why, Why::FewShared { .. }));
    }

    #[test]
    fn unregistered_frames_are_listed() {
        let one = Why::Unregistered { frames: vec![20] };
        let three = Why::Unregistered {
            frames: vec![20, 30, 40],
        };
        assert_eq!(one.to_string(), "frame 20 registered in no model");
        assert_eq!(
            three.to_string(),
            "frames 20, 30 and 40 registered in no model"
        );
    }

    #[test]
    fn shared_points_count_consecutive_positions_once_per_track() {
        let tracks: Vec<Vec<usize>> = vec![vec![0, 1, 1, 2], vec![2, 0], vec![3, 2], vec![1]];
        let s = shared_points(4, tracks.iter().map(Vec::as_slice));
        assert_eq!(s, vec![1, 1, 1]);
    }
}
