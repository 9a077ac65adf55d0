//! One entry of a project's history, typed: the step as `select` applied it ([`Applied`]) and
//! how many frames it kept. A project file stores it as `{"plugin", "params", "kept"}`
//! ([`Stored`]); [`Recorded::from_stored`] is the one place that reads that form, and writing
//! gives today's bytes back (parameters in key order).

use super::{Applied, STEPS};
use crate::params::Backend;
use serde::{Deserialize, Serialize, Serializer};
use serde_json::Value;

/// One step of a project's history: what `select` applied and how many frames it kept.
#[derive(Debug, Clone, PartialEq)]
pub struct Recorded {
    /// The step with the parameters it ran with.
    pub applied: Applied,
    /// Number of frames the step kept.
    pub kept: usize,
}

/// A history entry as the project file stores it: read as it stands, then by
/// [`Recorded::from_stored`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Stored {
    /// The step id (`boundaries`, `every-nth`, `fps`, `manual`, ...).
    #[serde(rename = "plugin")]
    pub step: String,
    /// The step's parameters.
    pub params: Value,
    /// Number of frames the step kept.
    pub kept: usize,
}

impl Serialize for Recorded {
    /// As [`Stored`], the parameters through a JSON value, which sorts their keys as every
    /// project so far has them.
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut v = serde_json::to_value(&self.applied).map_err(serde::ser::Error::custom)?;
        let stored = Stored {
            step: v["plugin"].as_str().unwrap_or_default().to_string(),
            params: v["params"].take(),
            kept: self.kept,
        };
        stored.serialize(s)
    }
}

impl Recorded {
    /// The record of `applied`, which kept `kept` frames.
    pub fn new(applied: Applied, kept: usize) -> Recorded {
        Recorded { applied, kept }
    }

    /// Reads a stored entry: a known step id and backend, parameters of the step's types; the
    /// error names the key (`plugin`, `params.fps`).
    pub fn from_stored(e: Stored) -> Result<Recorded, (String, String)> {
        let ids = || STEPS.iter().map(|k| k.id);
        let known: Vec<&str> = (ids().take(1).chain(["preview"]))
            .chain(ids().skip(1))
            .chain(["reconstruct"])
            .collect();
        if !known.contains(&e.step.as_str()) {
            let known = known.join(", ");
            let msg = format!("unknown plugin `{}` (known: {known})", e.step);
            return Err(("plugin".into(), msg));
        }
        if let Some(b) = e.params.get("backend").filter(|b| !b.is_null()) {
            if serde_json::from_value::<Backend>(b.clone()).is_err() {
                let msg = format!("unknown backend {b} (known: \"gpu\", \"opencv\")");
                return Err(("params.backend".into(), msg));
            }
        }
        let v = serde_json::json!({ "plugin": e.step, "params": e.params });
        let applied = serde_path_to_error::deserialize(v).map_err(|err| {
            let path = err.path().to_string();
            let key = match path.as_str() {
                "." | "" => "plugin".to_string(),
                p => p.to_string(),
            };
            (key, err.into_inner().to_string())
        })?;
        Ok(Recorded::new(applied, e.kept))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::Metric;
    use crate::steps::BlurMode;

    #[test]
    fn history_entries_round_trip_with_sorted_parameters() {
        let a = Applied::Blur {
            backend: Some(Backend::Opencv),
            metric: Some(Metric::Tenengrad),
            mode: Some(BlurMode::Replace),
            ratio: Some(0.8),
            window: Some(2),
        };
        let e = serde_json::to_value(Recorded::new(a.clone(), 4)).unwrap();
        assert_eq!(e["plugin"], "blur");
        assert_eq!(a.id(), "blur");
        let keys: Vec<_> = e["params"].as_object().unwrap().keys().cloned().collect();
        assert_eq!(keys, ["backend", "metric", "mode", "ratio", "window"]);
        let back = Recorded::from_stored(serde_json::from_value(e).unwrap()).unwrap();
        assert_eq!((back.applied, back.kept), (a, 4));
    }
}
