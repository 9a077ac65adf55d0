//! How thresholds and bounds are written in files and flags: a number or a text (`auto`, `60kf`,
//! `4.5s`).

use super::Bound;
use serde::{Deserialize, Serialize};

/// A movement threshold as given: pixels, proposed from a sample (`auto`), or the threshold
/// that keeps a number of keyframes (`60kf`). In files: a number or one of those strings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "NumOrText", into = "NumOrText")]
pub enum Threshold {
    /// Full-resolution pixels.
    Px(f64),
    /// Proposed from a sample of the input.
    Auto,
    /// The threshold that keeps this many keyframes.
    Count(usize),
}

impl std::str::FromStr for Threshold {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        if s == "auto" {
            return Ok(Threshold::Auto);
        }
        if let Some(n) = s.strip_suffix("kf") {
            return match n.parse::<usize>() {
                Ok(n) if n >= 1 => Ok(Threshold::Count(n)),
                _ => Err(format!(
                    "`{s}`: give a keyframe count of 1 or more, e.g. `60kf`"
                )),
            };
        }
        match s.parse::<f64>() {
            Ok(v) if v.is_finite() && v > 0.0 => Ok(Threshold::Px(v)),
            _ => Err(format!(
                "`{s}` is neither a positive number of pixels, a keyframe count (`60kf`) nor `auto`"
            )),
        }
    }
}

/// A number or a string in a file (`120`, `4.5s`, `auto`, `60kf`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum NumOrText {
    /// An integer.
    Int(i64),
    /// A float.
    Float(f64),
    /// A string.
    Text(String),
}

impl NumOrText {
    /// The value parsed as its text; the error quotes it.
    fn parse<T: std::str::FromStr<Err = String>>(&self) -> std::result::Result<T, String> {
        let text = match self {
            NumOrText::Int(i) => i.to_string(),
            NumOrText::Float(f) => f.to_string(),
            NumOrText::Text(s) => s.clone(),
        };
        text.parse()
            .map_err(|e| format!("invalid value '{text}': {e}"))
    }
}

impl TryFrom<NumOrText> for Threshold {
    type Error = String;
    fn try_from(v: NumOrText) -> std::result::Result<Self, String> {
        v.parse()
    }
}

impl From<Threshold> for NumOrText {
    fn from(t: Threshold) -> NumOrText {
        match t {
            Threshold::Px(v) => NumOrText::Float(v),
            Threshold::Auto => NumOrText::Text("auto".into()),
            Threshold::Count(n) => NumOrText::Text(format!("{n}kf")),
        }
    }
}

/// A frame bound as a user writes it: a frame index `120` or a time `"4.5s"`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "NumOrText", into = "NumOrText")]
pub struct BoundArg(pub Bound);

impl TryFrom<NumOrText> for BoundArg {
    type Error = String;
    fn try_from(v: NumOrText) -> std::result::Result<Self, String> {
        v.parse().map(BoundArg)
    }
}

impl From<BoundArg> for NumOrText {
    fn from(b: BoundArg) -> NumOrText {
        match b.0 {
            Bound::Frame(i) => NumOrText::Int(i64::try_from(i).unwrap_or(i64::MAX)),
            Bound::Seconds(_) => NumOrText::Text(b.0.to_string()),
        }
    }
}
