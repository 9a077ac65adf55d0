//! Boundaries: restrict the candidates to a start..=end range given in frames or seconds.
//! Both ends are inclusive.

use super::{BoundArg, Flag, FlagValues, Step};
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// `--start`, `--end`.
pub const FLAGS: &[Flag] = &[
    Flag::value::<Bound>(
        "start",
        "FRAME|SECONDSs",
        "First frame to consider: a frame index (`120`) or a time (`4.5s`)",
    )
    .sets("boundaries", "start"),
    Flag::value::<Bound>(
        "end",
        "FRAME|SECONDSs",
        "Last frame to consider, inclusive: a frame index or a time",
    )
    .sets("boundaries", "end"),
];

/// The step when `--start` or `--end` is given.
pub fn from_flags(v: &FlagValues) -> Result<Option<Step>, crate::error::Error> {
    let (start, end) = (v.get::<Bound>("start")?, v.get::<Bound>("end")?);
    Ok(
        (start.is_some() || end.is_some()).then_some(Step::Boundaries {
            start: start.map(BoundArg),
            end: end.map(BoundArg),
        }),
    )
}

/// One end of a range: a frame index or a time in seconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Bound {
    /// A 0-based frame index.
    Frame(usize),
    /// A time in seconds from the first frame's timestamp.
    Seconds(f64),
}

impl FromStr for Bound {
    type Err = String;

    /// `120` is frame 120; `4.5s` is 4.5 seconds.
    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim();
        if let Some(sec) = s.strip_suffix('s') {
            let v: f64 = sec
                .parse()
                .map_err(|_| format!("`{s}` is not a time like `4.5s`"))?;
            if !v.is_finite() || v < 0.0 {
                return Err(format!("`{s}` must be a non-negative time"));
            }
            return Ok(Bound::Seconds(v));
        }
        s.parse::<usize>().map(Bound::Frame).map_err(|_| {
            format!("`{s}` is neither a frame index (e.g. 120) nor a time (e.g. 4.5s)")
        })
    }
}

impl fmt::Display for Bound {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Bound::Frame(i) => write!(f, "{i}"),
            Bound::Seconds(s) => write!(f, "{s}s"),
        }
    }
}

/// Start and end of the part of the input to sample (both inclusive).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Boundaries {
    /// First frame (or time) to consider.
    pub start: Option<Bound>,
    /// Last frame (or time) to consider, inclusive.
    pub end: Option<Bound>,
}

impl Boundaries {
    /// The candidate frames `start..=end` among `frame_count` frames. Times are resolved through
    /// `timestamps_s` (relative to frame 0's timestamp).
    pub fn candidates(
        &self,
        frame_count: usize,
        timestamps_s: Option<&[f64]>,
    ) -> Result<Vec<usize>> {
        let err = |msg: String| Error::step("boundaries", msg);
        if frame_count == 0 {
            return Err(err("the input has no frames".into()));
        }
        let resolve = |b: Bound, is_end: bool| -> Result<usize> {
            match b {
                Bound::Frame(i) => Ok(i),
                Bound::Seconds(s) => {
                    let ts = timestamps_s.ok_or_else(|| {
                        err(format!(
                            "`{b}` needs timestamps, and this input has no frame rate"
                        ))
                    })?;
                    let t0 = ts.first().copied().unwrap_or(0.0);
                    // Tolerance for timestamps stored in milliseconds.
                    let eps = 1e-6;
                    Ok(if is_end {
                        // Last frame at or before the time (none: before frame 0).
                        let i = ts.iter().rposition(|&t| t - t0 <= s + eps);
                        i.ok_or_else(|| err(format!("end {b} lies before the first frame")))?
                    } else {
                        ts.iter()
                            .position(|&t| t - t0 >= s - eps)
                            .unwrap_or(frame_count)
                    })
                }
            }
        };
        let start = self
            .start
            .map(|b| resolve(b, false))
            .transpose()?
            .unwrap_or(0);
        let end = self
            .end
            .map(|b| resolve(b, true))
            .transpose()?
            .unwrap_or(frame_count - 1)
            .min(frame_count - 1);
        if start > end {
            return Err(err(format!(
                "start ({}) is after end ({}) in a input of {frame_count} frames",
                self.start.map(|b| b.to_string()).unwrap_or("0".into()),
                self.end.map(|b| b.to_string()).unwrap_or("last".into())
            )));
        }
        Ok((start..=end).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_inclusive() {
        let b = Boundaries {
            start: Some(Bound::Frame(20)),
            end: Some(Bound::Frame(60)),
        };
        let c = b.candidates(300, None).unwrap();
        assert_eq!(c.first(), Some(&20));
        assert_eq!(c.last(), Some(&60));
    }

    #[test]
    fn seconds_use_timestamps() {
        let ts: Vec<f64> = (0..100).map(|i| i as f64 / 10.0).collect();
        let b = Boundaries {
            start: Some("1s".parse().unwrap()),
            end: Some("2.05s".parse().unwrap()),
        };
        let c = b.candidates(100, Some(&ts)).unwrap();
        assert_eq!((c[0], *c.last().unwrap()), (10, 20));
    }

    #[test]
    fn start_after_end_is_an_error() {
        let b = Boundaries {
            start: Some(Bound::Frame(50)),
            end: Some(Bound::Frame(10)),
        };
        assert!(b.candidates(100, None).is_err());
    }
}
