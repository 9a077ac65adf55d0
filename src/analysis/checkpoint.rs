//! Checkpoints: a running analysis saves what it computed (atomically, temp + rename) every few
//! seconds at a point where its state is complete, and a later run over the same input, request
//! and backend resumes from it; any other file is ignored (said in the log) and the run starts
//! over. The file format is versioned.

use super::Request;
use crate::error::{Error, Result};
use crate::fsutil::Fingerprint;
use crate::params::Backend;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Where and how often a running analysis saves what it computed, to resume after a kill.
#[derive(Debug, Clone)]
pub struct Resume {
    /// The checkpoint file.
    pub path: PathBuf,
    /// The input's fingerprint (a checkpoint of another input is ignored).
    pub fingerprint: Fingerprint,
    /// Seconds between checkpoints.
    pub every_s: f64,
}

/// A running analysis's saved state: frames 0..`frames` are complete.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    /// Format version; a checkpoint of another version is not resumed.
    pub version: u32,
    /// The input it belongs to.
    pub fingerprint: Fingerprint,
    /// What was being computed.
    pub request: Request,
    /// Backend that computed it.
    pub backend: Backend,
    /// Frames done.
    pub frames: usize,
    /// Their timestamps.
    pub timestamps_s: Vec<f64>,
    /// Whether every frame so far had a timestamp.
    pub have_timestamps: bool,
    /// Sharpness per metric, one score per frame done.
    pub sharpness: Vec<Vec<f64>>,
    /// Movement state after the last frame done. The embeddings of the frames done, when
    /// requested, are the first `frames` records of the request's series file
    /// (`Request::store`), appended as frames go rather than written here each time.
    pub movement: Option<MovementState>,
}

/// The movement state a checkpoint keeps: everything the movement pass needs to go on after the
/// frame `anchor` (whose pixels, and those of `reference`, are decoded again on resume).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MovementState {
    /// Consecutive movement of frames 0..=anchor.
    pub values: Vec<f64>,
    /// The last frame flow was measured to (a stride point).
    pub anchor: usize,
    /// The stationary sampler's reference frame.
    pub reference: Option<usize>,
    /// Movement accumulated by the stationary sampler since its last keyframe.
    pub accumulated: f64,
    /// Keyframes chosen by the stationary sampler so far.
    pub keys: Vec<usize>,
}

impl MovementState {
    /// The frames whose pixels a resumed pass needs again: the anchor and the reference.
    pub(crate) fn primed(&self) -> Vec<usize> {
        [Some(self.anchor), self.reference]
            .into_iter()
            .flatten()
            .collect()
    }
}

const CHECKPOINT_VERSION: u32 = 1;

/// Whether `path` holds a checkpoint of keyframer's (any input, any version it can parse).
pub fn is_checkpoint(path: &Path) -> bool {
    crate::output::read_text(path)
        .ok()
        .and_then(|t| serde_json::from_str::<Checkpoint>(&t).ok())
        .is_some()
}

/// What the frames done so far gave, apart from movement: frames `0..frames`.
#[derive(Debug, Clone)]
pub(crate) struct Collected {
    /// Frames done.
    pub frames: usize,
    /// Their timestamps (while every frame had one).
    pub timestamps: Vec<f64>,
    /// Whether every frame had a timestamp.
    pub have_ts: bool,
    /// Sharpness per metric.
    pub scores: Vec<Vec<f64>>,
}

impl Collected {
    /// Nothing done yet, `metrics` sharpness series.
    pub(crate) fn new(metrics: usize) -> Collected {
        Collected {
            frames: 0,
            timestamps: Vec::new(),
            have_ts: true,
            scores: vec![Vec::new(); metrics],
        }
    }

    /// Records the next frame's timestamp.
    pub(crate) fn push_timestamp(&mut self, t: Option<f64>) {
        self.have_ts &= t.is_some();
        self.timestamps.extend(t);
    }
}

/// The checkpoint at `resume` when it fits `input`, `req` and `backend`: what it collected and
/// its movement state.
pub(crate) fn restore(
    resume: Option<&Resume>,
    req: &Request,
    backend: Backend,
    input: &Path,
) -> Option<(Collected, Option<MovementState>)> {
    let r = resume?;
    let c = load(r, req)?;
    if c.backend != backend {
        log::info!(
            "the checkpoint was computed by the {} backend; starting over",
            c.backend
        );
        return None;
    }
    log::info!(
        "resuming the analysis of {} at frame {} (checkpoint {})",
        input.display(),
        c.frames,
        r.path.display()
    );
    let done = Collected {
        frames: c.frames,
        timestamps: c.timestamps_s,
        have_ts: c.have_timestamps,
        scores: c.sharpness,
    };
    Some((done, c.movement))
}

fn load(resume: &Resume, req: &Request) -> Option<Checkpoint> {
    let bytes = crate::output::read_text(&resume.path).ok()?.into_bytes();
    let c: Checkpoint = match serde_json::from_slice(&bytes) {
        Ok(c) => c,
        Err(e) => {
            log::warn!(
                "{}: unreadable checkpoint ({e}); starting over",
                resume.path.display()
            );
            return None;
        }
    };
    let work = Request {
        store: None,
        ..req.clone()
    };
    // The series file holds at least the frames done (it may hold more: written after the
    // checkpoint, they are written again).
    let embedded = match (&req.descriptor, &req.store) {
        (Some(_), Some(p)) => {
            c.frames == 0 || crate::embedding_file::frames_in(p).is_some_and(|n| n >= c.frames)
        }
        _ => true,
    };
    let fits = c.version == CHECKPOINT_VERSION
        && c.fingerprint == resume.fingerprint
        && c.request == work
        && embedded
        && c.sharpness.len() == req.sharpness.len()
        && c.sharpness.iter().all(|s| s.len() == c.frames)
        && c.timestamps_s.len() == if c.have_timestamps { c.frames } else { 0 }
        && c.movement.is_some() == req.movement.is_some()
        && c.movement
            .as_ref()
            .is_none_or(|m| m.values.len() == c.frames && m.anchor + 1 == c.frames);
    if !fits {
        log::info!(
            "{}: checkpoint is for another input or request; starting over",
            resume.path.display()
        );
        return None;
    }
    Some(c)
}

/// Saves checkpoints to a [`Resume`] when they are due.
pub(crate) struct Saver<'a> {
    resume: Option<&'a Resume>,
    last: Instant,
}

impl<'a> Saver<'a> {
    /// The first checkpoint is due `resume.every_s` from now; none without `resume`.
    pub(crate) fn new(resume: Option<&'a Resume>) -> Saver<'a> {
        Saver {
            resume,
            last: Instant::now(),
        }
    }

    /// Whether a checkpoint is due.
    pub(crate) fn due(&self) -> bool {
        self.resume
            .is_some_and(|r| r.every_s > 0.0 && self.last.elapsed().as_secs_f64() >= r.every_s)
    }

    /// Writes the checkpoint of `done` and `movement` (atomically).
    pub(crate) fn save(
        &mut self,
        req: &Request,
        backend: Backend,
        done: &Collected,
        movement: Option<MovementState>,
    ) -> Result<()> {
        let Some(r) = self.resume else {
            return Ok(());
        };
        let frames = done.frames;
        let c = Checkpoint {
            version: CHECKPOINT_VERSION,
            fingerprint: r.fingerprint.clone(),
            request: req.clone(),
            backend,
            frames,
            timestamps_s: if done.have_ts {
                done.timestamps.clone()
            } else {
                Vec::new()
            },
            have_timestamps: done.have_ts,
            sharpness: done
                .scores
                .iter()
                .map(|s| s[..frames.min(s.len())].to_vec())
                .collect(),
            movement,
        };
        let bytes = serde_json::to_vec(&c).map_err(|e| Error::output(&r.path, e.to_string()))?;
        crate::fsutil::write_atomic(&r.path, &bytes)?;
        log::debug!("checkpoint: {frames} frames -> {}", r.path.display());
        self.last = Instant::now();
        Ok(())
    }
}
