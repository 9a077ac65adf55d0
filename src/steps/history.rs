//! One entry of a project's history, typed: the step as `select` applied it ([`Applied`]) and
//! how many frames it kept. It is read once, when the file is, and written back as the file's
//! `{"plugin", "params", "kept"}` object byte for byte as before (parameters in key order); a bad
//! entry's error names its key (`history[2].params.fps`, `history[1].plugin`).

use super::{Applied, STEPS};
use crate::params::Backend;
use serde::de::{self, DeserializeSeed, IntoDeserializer, MapAccess};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use serde_json::Value;

/// One step of a project's history: what `select` applied and how many frames it kept.
#[derive(Debug, Clone, PartialEq)]
pub struct Recorded {
    /// The step with the parameters it ran with.
    pub applied: Applied,
    /// Number of frames the step kept.
    pub kept: usize,
}

/// A history entry as the project file stores it.
#[derive(Serialize)]
struct Stored<'a> {
    #[serde(rename = "plugin")]
    step: &'a Value,
    params: &'a Value,
    kept: usize,
}

impl Serialize for Recorded {
    /// Parameters pass through a JSON value, which sorts their keys, as every project so far has them.
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let v = serde_json::to_value(&self.applied).map_err(serde::ser::Error::custom)?;
        let (step, params) = (&v["plugin"], &v["params"]);
        let kept = self.kept;
        Stored { step, params, kept }.serialize(s)
    }
}

impl<'de> Deserialize<'de> for Recorded {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Recorded, D::Error> {
        d.deserialize_map(EntryVisitor)
    }
}

struct EntryVisitor;

impl<'de> de::Visitor<'de> for EntryVisitor {
    type Value = Recorded;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a history entry (plugin, params, kept)")
    }

    /// [`Applied`] reads the entry's own map, so that an error inside it keeps its key's path.
    fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<Recorded, A::Error> {
        let mut entry = Entry {
            map,
            kept: None,
            step_next: false,
        };
        let applied = Applied::deserialize(de::value::MapAccessDeserializer::new(&mut entry))?;
        let kept = entry.kept.ok_or_else(|| de::Error::missing_field("kept"))?;
        Ok(Recorded { applied, kept })
    }
}

/// An entry's map as [`Applied`] reads it: `kept` taken aside, the step id checked.
struct Entry<A> {
    map: A,
    kept: Option<usize>,
    /// The value next is the step id (`plugin`).
    step_next: bool,
}

impl<'de, A: MapAccess<'de>> MapAccess<'de> for Entry<A> {
    type Error = A::Error;

    fn next_key_seed<K: DeserializeSeed<'de>>(
        &mut self,
        seed: K,
    ) -> Result<Option<K::Value>, A::Error> {
        while let Some(key) = self.map.next_key::<String>()? {
            if key == "kept" {
                self.kept = Some(self.map.next_value()?);
                continue;
            }
            self.step_next = key == "plugin";
            return seed.deserialize(key.into_deserializer()).map(Some);
        }
        Ok(None)
    }

    fn next_value_seed<V: DeserializeSeed<'de>>(&mut self, seed: V) -> Result<V::Value, A::Error> {
        match std::mem::take(&mut self.step_next) {
            true => self.map.next_value_seed(KnownStep(seed)),
            false => self.map.next_value_seed(seed),
        }
    }
}

/// A step id that keyframer knows (the history's ids: [`STEPS`]' and `preview`).
struct KnownStep<S>(S);

impl<'de, S: DeserializeSeed<'de>> DeserializeSeed<'de> for KnownStep<S> {
    type Value = S::Value;

    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<S::Value, D::Error> {
        let id = String::deserialize(d)?;
        let ids = || STEPS.iter().map(|k| k.id);
        let known: Vec<&str> = (ids().take(1).chain(["preview"]))
            .chain(ids().skip(1))
            .collect();
        if !known.contains(&id.as_str()) {
            let known = known.join(", ");
            let msg = format!("unknown plugin `{id}` (known: {known})");
            return Err(de::Error::custom(msg));
        }
        self.0.deserialize(id.into_deserializer())
    }
}

/// An applied step's `backend`: absent, `null` or a known backend.
pub(super) fn known_backend<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Backend>, D::Error> {
    match Option::<Value>::deserialize(d)? {
        None => Ok(None),
        Some(b) => serde_json::from_value(b.clone()).map(Some).map_err(|_| {
            de::Error::custom(format!("unknown backend {b} (known: \"gpu\", \"opencv\")"))
        }),
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
        let e = serde_json::to_value(Recorded {
            applied: a.clone(),
            kept: 4,
        })
        .unwrap();
        assert_eq!(e["plugin"], "blur");
        let keys: Vec<_> = e["params"].as_object().unwrap().keys().cloned().collect();
        assert_eq!(keys, ["backend", "metric", "mode", "ratio", "window"]);
        let back: Recorded = serde_json::from_value(e).unwrap();
        assert_eq!((back.applied, back.kept), (a, 4));
    }

    /// The error's path and message for the history entry `entry`, read as a project reads it.
    fn refusal(entry: &str) -> (String, String) {
        let text = format!("{{\"history\": [{{\"plugin\": \"fps\", \"params\": {{\"fps\": 2.0}}, \"kept\": 3}}, {entry}]}}");
        #[derive(Debug, Deserialize)]
        struct File {
            #[allow(dead_code)]
            history: Vec<Recorded>,
        }
        let de = &mut serde_json::Deserializer::from_str(&text);
        let e = serde_path_to_error::deserialize::<_, File>(de).unwrap_err();
        (e.path().to_string(), e.into_inner().to_string())
    }

    #[test]
    fn a_bad_entry_is_refused_at_its_key() {
        let (path, msg) = refusal(r#"{"plugin": "stationry", "params": {}, "kept": 1}"#);
        assert_eq!(path, "history[1].plugin");
        assert!(
            msg.starts_with("unknown plugin `stationry` (known: boundaries, preview, stationary,"),
            "{msg}"
        );
        let (path, msg) =
            refusal(r#"{"plugin": "blur", "params": {"backend": "opencV"}, "kept": 1}"#);
        assert_eq!(path, "history[1].params.backend");
        assert!(
            msg.starts_with(r#"unknown backend "opencV" (known: "gpu", "opencv")"#),
            "{msg}"
        );
        let (path, msg) = refusal(r#"{"plugin": "fps", "params": {"fps": "x"}, "kept": 1}"#);
        assert_eq!(path, "history[1].params.fps");
        assert!(msg.starts_with("invalid type: string \"x\""), "{msg}");
        let (path, msg) = refusal(r#"{"kept": 1, "plugin": "every-nth", "params": {}}"#);
        assert_eq!(path, "history[1].params");
        assert!(msg.starts_with("missing field `n`"), "{msg}");
        let (path, msg) = refusal(r#"{"plugin": "fps", "params": {"fps": 1.0}}"#);
        assert_eq!(path, "history[1]");
        assert!(msg.starts_with("missing field `kept`"), "{msg}");
    }

    #[test]
    fn entries_read_in_any_key_order_and_absent_options_are_none() {
        let e: Recorded = serde_json::from_str(
            r#"{"kept": 2, "params": {"backend": null, "threshold_px": 4}, "plugin": "spacing"}"#,
        )
        .unwrap();
        let want = Applied::Spacing {
            auto: false,
            backend: None,
            count: None,
            movement: None,
            threshold_px: 4.0,
        };
        assert_eq!((e.applied, e.kept), (want, 2));
    }
}
