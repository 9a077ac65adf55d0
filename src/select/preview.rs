//! `select --preview`: the whole sampler chain run on a video's codec keyframes only (decoded
//! with `ffmpeg -skip_frame nokey`), mapped back to the video's frame indices. Much faster than a
//! full analysis when keyframes are sparse; coarse by construction: only codec keyframes can be
//! chosen, and counts in frames (every N, blur window, reset delta) count keyframes. The project
//! is marked `preview`, holds no scores (only timestamps and, with telemetry, every frame's
//! position), and is never reused as a cache.

use super::{self as select, SelectReport, SelectSettings};
use crate::error::{Error, Result};
use crate::project::Cache;
use crate::source::codec_keyframes::{self, CodecKeyframeIndex};
use crate::source::{OpenOptions, SourceKind};
use crate::steps::{Applied, BoundArg, Recorded, Step};
use crate::steps::{Bound, Boundaries};
use std::sync::Arc;

/// Translates frame-index bounds into positions in the keyframe sequence (times stay times:
/// keyframes carry the video's timestamps).
pub fn keyframe_bounds(b: &Boundaries, index: &CodecKeyframeIndex) -> Result<Boundaries> {
    let k = &index.keyframes;
    let none = |msg: String| Err(Error::step("preview", msg));
    let start = match b.start {
        Some(Bound::Frame(i)) => match k.partition_point(|&f| f < i) {
            pos if pos == k.len() => {
                return none(format!("no codec keyframe at or after --start frame {i}"))
            }
            pos => Some(Bound::Frame(pos)),
        },
        other => other,
    };
    let end = match b.end {
        Some(Bound::Frame(i)) => match k.partition_point(|&f| f <= i) {
            0 => return none(format!("no codec keyframe at or before --end frame {i}")),
            n => Some(Bound::Frame(n - 1)),
        },
        other => other,
    };
    Ok(Boundaries { start, end })
}

/// Runs the preview selection and writes the project.
pub fn select_preview(s: &SelectSettings) -> Result<SelectReport> {
    check_input(s)?;
    let index = Arc::new(codec_keyframes::probe(&s.input)?);
    let (n_key, n_all) = (index.keyframes.len(), index.frame_count());
    announce(s, n_key, n_all);
    // Keyframes are already far apart: measure flow between every consecutive pair.
    let mut movement = s.movement;
    movement.stride = 1;
    let bounds = keyframe_bounds(&crate::steps::boundaries(&s.steps), &index)?;
    let mut steps: Vec<Step> = s
        .steps
        .iter()
        .filter(|st| !matches!(st, Step::Boundaries { .. } | Step::Manual { .. }))
        .cloned()
        .collect();
    steps.insert(
        0,
        Step::Boundaries {
            start: bounds.start.map(BoundArg),
            end: bounds.end.map(BoundArg),
        },
    );
    let inner = SelectSettings {
        movement,
        steps,
        preview: false,
        ..s.clone()
    };
    let open = OpenOptions {
        images_fps: None,
        codec_keyframes: Some(index.clone()),
    };
    let mut report = select::build(&inner, &open)?;
    let p = &mut report.project;
    let mut keys: Vec<usize> = p.keyframes.iter().map(|&j| index.keyframes[j]).collect();
    let preview = Applied::Preview {
        codec_keyframes: n_key,
        frames: n_all,
    };
    let mut history = vec![Recorded::new(preview, n_key)];
    history.append(&mut p.history);
    // Added and removed frames are the video's own indices: applied after the mapping.
    select::manual_step(&mut keys, &mut history, &s.steps, n_all)?;
    p.keyframes = keys;
    p.history = history;
    p.boundaries = crate::steps::boundaries(&s.steps);
    p.metadata.frame_count = n_all;
    p.metadata.frame_count_exact = true;
    // As a full decode measures it: first to last frame plus one frame interval (the analysis
    // saw only the keyframes' times).
    p.metadata.duration_s = match (index.timestamps_s.last(), p.metadata.fps) {
        (Some(last), Some(fps)) => Some(last + 1.0 / fps),
        _ => None,
    };
    // Positions for every frame, as a full selection keeps them (export geotags, the map), when
    // the keyframes had any.
    let telemetry = match p.cache.telemetry.is_some() {
        true => {
            let ts = Some(index.timestamps_s.as_slice());
            super::telemetry::positions(s, SourceKind::Video, n_all, ts, None)?
        }
        false => None,
    };
    // A preview is never reused as a cache: the embeddings its keyframes gave are dropped, and
    // so are the series of the project it replaces.
    let mut old = select::replaced_series(&s.output);
    old.extend(select::series_files(p));
    p.cache = Cache {
        timestamps_s: Some(index.timestamps_s.clone()),
        telemetry,
        ..Cache::default()
    };
    p.preview = true;
    p.save(&s.output, true)?;
    select::drop_series(&s.output, &old, &[]);
    Ok(report)
}

/// A video, outputs that may be written, and a warning when a full analysis is replaced.
fn check_input(s: &SelectSettings) -> Result<()> {
    let (kind, _) = select::identify(&s.input)?;
    if kind != SourceKind::Video {
        return Err(Error::input(
            &s.input,
            "--preview needs a video (images have no codec keyframes)",
        ));
    }
    let _held = select::check_outputs(s)?;
    if let Ok(old) = crate::project::Project::load(&s.output) {
        if !old.preview && !old.cache.sharpness.is_empty() {
            log::warn!(
                "{}: replacing a project whose cache holds full-analysis scores with a preview",
                s.output.display()
            );
        }
    }
    Ok(())
}

/// Says how many frames the preview analyses.
fn announce(s: &SelectSettings, n_key: usize, n_all: usize) {
    if n_key == n_all {
        log::warn!(
            "{}: every frame is a codec keyframe; the preview decodes every frame (no speed-up)",
            s.input.display()
        );
    } else {
        log::info!(
            "preview: analysing the {n_key} codec keyframes of {n_all} frames (one every {:.1})",
            n_all as f64 / n_key as f64
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn index() -> CodecKeyframeIndex {
        CodecKeyframeIndex {
            timestamps_s: (0..30).map(|i| i as f64 / 10.0).collect(),
            keyframes: vec![0, 10, 20],
        }
    }

    #[test]
    fn frame_bounds_map_to_keyframe_positions() {
        let b = Boundaries {
            start: Some(Bound::Frame(5)),
            end: Some(Bound::Frame(20)),
        };
        let k = keyframe_bounds(&b, &index()).unwrap();
        assert_eq!(k.start, Some(Bound::Frame(1)));
        assert_eq!(k.end, Some(Bound::Frame(2)));
        let t = Boundaries {
            start: Some(Bound::Seconds(1.5)),
            end: None,
        };
        assert_eq!(keyframe_bounds(&t, &index()).unwrap(), t);
    }

    #[test]
    fn bounds_without_keyframes_are_errors() {
        let late = Boundaries {
            start: Some(Bound::Frame(21)),
            end: None,
        };
        let e = keyframe_bounds(&late, &index()).unwrap_err();
        assert!(e.to_string().contains("after --start frame 21"), "{e}");
    }
}
