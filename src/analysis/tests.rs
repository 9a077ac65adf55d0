//! The orchestration with fake engines and a fake source: frame order, stride shares, the
//! stationary step, checkpoints and resume, damaged frames, all against what the parts give alone.

use super::checkpoint::Checkpoint;
use super::ingest::Pixels;
use super::movement::{MovementEngine, MovementPass};
use super::sharpness::SharpnessEngine;
use super::*;
use crate::fsutil::Fingerprint;
use crate::kernels::farneback::SLOTS;
use crate::params::Statistic;
use crate::source::{Frame, SourceKind};
use crate::steps::StationarySampler;
use opencv::core::{Scalar, Vec3b, CV_8UC3};
use opencv::prelude::*;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

/// Frames are 8x8 and uniform: frame i has the value i, a damaged frame that of the last
/// readable one before it (as image folders give).
const SIZE: u32 = 8;

/// The fake movement between frames of values `a` and `b` (analysis pixels).
fn fake_flow(a: u8, b: u8) -> f64 {
    (f64::from(a) - f64::from(b)).abs() * 0.37
        + f64::from((a as u32 * 13 + b as u32 * 7) % 5) * 0.11
}

/// The fake sharpness scores of a frame of value `v`, one per metric.
fn fake_scores(v: u8, metrics: usize) -> Vec<f64> {
    (0..metrics)
        .map(|k| f64::from(v) * 1.5 + k as f64)
        .collect()
}

struct FakeSource {
    meta: Metadata,
    next: usize,
    damaged: Vec<usize>,
    fail_at: Option<usize>,
    /// Frames decoded with pixels.
    decoded: Arc<Mutex<Vec<usize>>>,
}

impl FakeSource {
    fn new(n: usize, damaged: &[usize], fail_at: Option<usize>) -> FakeSource {
        FakeSource {
            meta: Metadata {
                kind: SourceKind::Images,
                frame_count: n,
                frame_count_exact: false,
                fps: Some(10.0),
                width: SIZE,
                height: SIZE,
                duration_s: None,
                codec: None,
                rotation_deg: 0,
            },
            next: 0,
            damaged: damaged.to_vec(),
            fail_at,
            decoded: Arc::default(),
        }
    }

    fn advance(&mut self) -> Result<Option<usize>> {
        let i = self.next;
        if Some(i) == self.fail_at {
            return Err(Error::Frame {
                path: PathBuf::new(),
                index: i,
                msg: "killed".into(),
            });
        }
        if i >= self.meta.frame_count {
            return Ok(None);
        }
        self.next += 1;
        Ok(Some(i))
    }
}

/// The value of frame `i`'s pixels.
fn value(i: usize, damaged: &[usize]) -> u8 {
    (0..=i).rev().find(|j| !damaged.contains(j)).unwrap_or(0) as u8
}

impl FrameSource for FakeSource {
    fn metadata(&self) -> &Metadata {
        &self.meta
    }

    fn next_frame(&mut self) -> Result<Option<Frame>> {
        let Some(index) = self.advance()? else {
            return Ok(None);
        };
        self.decoded.lock().unwrap().push(index);
        let v = f64::from(value(index, &self.damaged));
        let image = Mat::new_rows_cols_with_default(8, 8, CV_8UC3, Scalar::all(v)).unwrap();
        Ok(Some(Frame {
            index,
            timestamp_s: Some(index as f64 / 10.0),
            image,
        }))
    }

    fn skip_frame(&mut self) -> Result<Option<(usize, Option<f64>)>> {
        Ok(self.advance()?.map(|i| (i, Some(i as f64 / 10.0))))
    }

    fn damaged_frames(&self) -> Vec<(usize, String)> {
        let met = self.damaged.iter().filter(|&&d| d < self.next);
        met.map(|&d| (d, format!("frame {d}: damaged"))).collect()
    }
}

#[derive(Default)]
struct FakeMovement {
    slots: [Option<u8>; SLOTS],
}

impl MovementEngine for FakeMovement {
    fn load(&mut self, slot: usize, px: Pixels) -> Result<()> {
        let Pixels::Small(gray) = px else {
            return Err(Error::param("fake", "no device"));
        };
        assert_eq!((gray.cols(), gray.rows()), (4, 4), "the analysis size");
        self.slots[slot] = Some(*gray.at_2d::<u8>(0, 0).unwrap());
        Ok(())
    }

    fn movement(&mut self, from: usize, to: usize) -> Result<f64> {
        assert_ne!(from, to);
        Ok(fake_flow(
            self.slots[from].unwrap(),
            self.slots[to].unwrap(),
        ))
    }
}

/// Scores like a device with readback in flight: `take` without `all` keeps the scores of the
/// last batch submitted back.
struct FakeSharpness {
    metrics: usize,
    /// Frames scored, in order.
    scored: Arc<Mutex<Vec<usize>>>,
    /// Scores submitted and not taken, oldest first.
    held: Vec<Vec<f64>>,
    /// Frames in the last batch submitted.
    last: usize,
}

impl SharpnessEngine for FakeSharpness {
    fn batch(&self) -> usize {
        3
    }

    fn submit(&mut self, frames: &[Frame]) -> Result<()> {
        let mut scored = self.scored.lock().unwrap();
        scored.extend(frames.iter().map(|f| f.index));
        let v = |f: &Frame| f.image.at_2d::<Vec3b>(0, 0).unwrap()[0];
        let metrics = self.metrics;
        self.held
            .extend(frames.iter().map(|f| fake_scores(v(f), metrics)));
        self.last = frames.len();
        Ok(())
    }

    fn take(&mut self, all: bool) -> Result<Vec<Vec<f64>>> {
        let keep = if all {
            0
        } else {
            self.last.min(self.held.len())
        };
        let rest = self.held.split_off(self.held.len() - keep);
        Ok(std::mem::replace(&mut self.held, rest))
    }
}

fn request(stride: u32, stationary: Option<StationaryRequest>) -> Request {
    Request {
        sharpness: vec![Metric::Tenengrad, Metric::Laplacian { ksize: 3 }],
        sharpness_rows: None,
        movement: Some(MovementRequest {
            farneback: Default::default(),
            statistic: Statistic::Median,
            analysis_width: 4,
            stride,
            derotate: None,
            sphere: None,
        }),
        stationary,
        descriptor: None,
        network: None,
        runtime: None,
        store: None,
    }
}

/// Runs the orchestration over `src` with the fake engines; also returns the frames scored.
fn fake_run(
    src: &mut FakeSource,
    req: &Request,
    resume: Option<&Resume>,
) -> (Result<Analysis>, Vec<usize>) {
    let scored = Arc::new(Mutex::new(Vec::new()));
    let movement = req.movement.map(|m| {
        let engine = Box::new(FakeMovement::default());
        MovementPass::new(&m, req.stationary, engine, &src.meta)
    });
    let engines = Engines {
        movement,
        embedding: None,
        sharpness: Some(Box::new(FakeSharpness {
            metrics: req.sharpness.len(),
            scored: scored.clone(),
            held: Vec::new(),
            last: 0,
        })),
        backend: Backend::Opencv,
    };
    let a = run(src, Path::new("in"), req, engines, true, resume);
    let scored = scored.lock().unwrap().clone();
    (a, scored)
}

/// What the movement of `n` frames measured every `stride` frames must be (scale 2: frames 8
/// wide analysed 4 wide).
fn expected_movement(n: usize, stride: usize, damaged: &[usize]) -> Vec<f64> {
    let mut points: Vec<usize> = (0..n).filter(|i| i % stride == 0).collect();
    if points.last() != Some(&(n - 1)) {
        points.push(n - 1);
    }
    let mut values = vec![0.0];
    for w in points.windows(2) {
        let m = fake_flow(value(w[0], damaged), value(w[1], damaged)) * 2.0;
        values.extend(std::iter::repeat_n(m / (w[1] - w[0]) as f64, w[1] - w[0]));
    }
    values
}

/// The stationary step's keyframes when fed directly from the fake engine.
fn expected_keys(st: &StationaryRequest, n: usize, damaged: &[usize]) -> Vec<usize> {
    let mut step = StationarySampler::new(*st);
    for i in 0..n {
        step.step(i, |r| {
            Ok::<_, ()>(fake_flow(value(r, damaged), value(i, damaged)) * 2.0)
        })
        .unwrap();
    }
    step.keys().to_vec()
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Checkpoints to `path` at every stride point.
fn resume_to(path: PathBuf) -> Resume {
    let fingerprint = Fingerprint {
        size: 1,
        mtime_s: 2,
        prefix_hash: "h".into(),
    };
    Resume {
        path,
        fingerprint,
        every_s: 1e-9,
    }
}

const STATIONARY: StationaryRequest = StationaryRequest {
    threshold: 6.0,
    reset_delta: 3,
    first: 2,
    last: 19,
};

#[test]
fn frames_stream_in_order_with_stride_shares() {
    for stride in [1, 2, 4] {
        let n = 23;
        let mut src = FakeSource::new(n, &[], None);
        let (a, scored) = fake_run(&mut src, &request(stride, None), None);
        let a = a.unwrap();
        assert_eq!(scored, (0..n).collect::<Vec<_>>(), "scored once, in order");
        let m = a.movement.unwrap();
        assert_eq!((m.width, m.height, m.scale_to_full), (4, 4, 2.0));
        assert_eq!(
            bits(&m.values),
            bits(&expected_movement(n, stride as usize, &[]))
        );
        for (k, (_, s)) in a.sharpness.iter().enumerate() {
            let want: Vec<f64> = (0..n).map(|i| fake_scores(i as u8, 2)[k]).collect();
            assert_eq!(bits(s), bits(&want));
        }
        let ts: Vec<f64> = (0..n).map(|i| i as f64 / 10.0).collect();
        assert_eq!(a.timestamps_s, Some(ts));
        assert_eq!(
            (a.metadata.frame_count, a.metadata.frame_count_exact),
            (n, true)
        );
        assert_eq!(a.stationary, None);
    }
}

#[test]
fn the_pass_feeds_the_stationary_step_what_it_asks_for() {
    for stride in [1, 2, 3] {
        let mut src = FakeSource::new(24, &[], None);
        let (a, _) = fake_run(&mut src, &request(stride, Some(STATIONARY)), None);
        let keys = a.unwrap().stationary.unwrap();
        assert_eq!(keys, expected_keys(&STATIONARY, 24, &[]), "stride {stride}");
        assert!(keys.len() > 2 && keys[0] == 2 && keys.iter().all(|&k| k <= 19));
    }
}

#[test]
fn damaged_frames_are_named_and_measured_as_their_stand_in() {
    let damaged = [5, 6, 11];
    let mut src = FakeSource::new(20, &damaged, None);
    let (a, _) = fake_run(&mut src, &request(2, Some(STATIONARY)), None);
    let a = a.unwrap();
    assert_eq!(a.damaged, damaged);
    assert_eq!(a.problems.len(), 3);
    let m = a.movement.unwrap();
    assert_eq!(bits(&m.values), bits(&expected_movement(20, 2, &damaged)));
    assert_eq!(
        a.stationary.unwrap(),
        expected_keys(&STATIONARY, 20, &damaged)
    );
    assert_eq!(a.sharpness[0].1[6], fake_scores(4, 2)[0]);
}

#[test]
fn resume_from_a_checkpoint_mid_way_equals_an_uninterrupted_run() {
    let dir = tempfile::tempdir().unwrap();
    for (stride, kill) in [(1, 9), (3, 14), (4, 13)] {
        let n = 26;
        let req = request(stride, Some(STATIONARY));
        let whole = fake_run(&mut FakeSource::new(n, &[7], None), &req, None)
            .0
            .unwrap();
        let resume = resume_to(dir.path().join(format!("c{stride}.json")));
        let mut killed = FakeSource::new(n, &[7], Some(kill));
        let e = fake_run(&mut killed, &req, Some(&resume)).0.unwrap_err();
        assert!(e.to_string().starts_with("in: frame"), "{e}");
        let text = std::fs::read_to_string(&resume.path).unwrap();
        let c: Checkpoint = serde_json::from_str(&text).unwrap();
        let last_point = (0..kill).rev().find(|i| i % stride as usize == 0).unwrap();
        assert_eq!(c.frames, last_point + 1, "saved at the last stride point");
        let st = c.movement.as_ref().unwrap();
        assert_eq!(st.values.len(), c.frames);
        let mut src = FakeSource::new(n, &[7], None);
        let decoded = src.decoded.clone();
        let (resumed, scored) = fake_run(&mut src, &req, Some(&resume));
        let resumed = resumed.unwrap();
        let early: Vec<usize> = decoded
            .lock()
            .unwrap()
            .iter()
            .copied()
            .filter(|&i| i < c.frames)
            .collect();
        let mut primed = st.primed();
        primed.sort_unstable();
        primed.dedup();
        assert_eq!(early, primed, "only the anchor and reference decoded again");
        assert_eq!(scored, (c.frames..n).collect::<Vec<_>>());
        assert_eq!(resumed.timestamps_s, whole.timestamps_s);
        assert_eq!(resumed.stationary, whole.stationary);
        assert_eq!(resumed.movement, whole.movement);
        let values = |a: &Analysis| bits(&a.movement.as_ref().unwrap().values);
        assert_eq!(values(&resumed), values(&whole));
        for (r, w) in resumed.sharpness.iter().zip(&whole.sharpness) {
            assert_eq!(bits(&r.1), bits(&w.1));
        }
        assert_eq!(resumed.metadata, whole.metadata);
    }
}

#[test]
fn a_checkpoint_of_another_request_or_backend_is_not_resumed() {
    let dir = tempfile::tempdir().unwrap();
    let resume = resume_to(dir.path().join("c.json"));
    let req = request(2, None);
    let _ = fake_run(&mut FakeSource::new(12, &[], Some(8)), &req, Some(&resume));
    assert!(checkpoint::restore(Some(&resume), &req, Backend::Opencv, Path::new("in")).is_some());
    assert!(checkpoint::restore(Some(&resume), &req, Backend::Gpu, Path::new("in")).is_none());
    let other = request(3, None);
    assert!(checkpoint::restore(Some(&resume), &other, Backend::Opencv, Path::new("in")).is_none());
    let mut src = FakeSource::new(12, &[], None);
    let (a, scored) = fake_run(&mut src, &other, Some(&resume));
    assert_eq!(scored, (0..12).collect::<Vec<_>>(), "started over");
    assert_eq!(
        bits(&a.unwrap().movement.unwrap().values),
        bits(&expected_movement(12, 3, &[]))
    );
}
