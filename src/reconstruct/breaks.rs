//! Where a reconstruction of a keyframe set is broken: pure functions over what COLMAP made
//! (which model registered each keyframe, the 3D points consecutive keyframes share, the inlier
//! matches of their two-view geometry). Guarantees: every consecutive pair of keyframes is judged
//! once, in frame order; a pair is sound only when both keyframes are registered in the same
//! model, share at least `min_shared` 3D points and rest on at least `min_inliers` inliers;
//! the set is connected exactly when no pair is broken and one model registers every keyframe.

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
}

impl std::fmt::Display for Why {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Why::Unregistered { frames } => {
                let list: Vec<String> = frames.iter().map(usize::to_string).collect();
                write!(f, "frame {} registered in no model", list.join(" and "))
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
}

/// The thresholds of a weak link.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Limits {
    /// Fewest 3D points consecutive keyframes must share.
    pub min_shared: usize,
    /// Fewest inlier matches of their two-view geometry.
    pub min_inliers: usize,
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
                        _ => None,
                    }
                }
            }
        };
        if let Some(why) = why {
            out.push(Break { from, to, why });
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
        });
    }
    out
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
        let b = find(&k, &o, LIMITS);
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
    fn shared_points_count_consecutive_positions_once_per_track() {
        let tracks: Vec<Vec<usize>> = vec![vec![0, 1, 1, 2], vec![2, 0], vec![3, 2], vec![1]];
        let s = shared_points(4, tracks.iter().map(Vec::as_slice));
        assert_eq!(s, vec![1, 1, 1]);
    }
}
