//! `geo-distance`: a keyframe each time the camera has moved `metres` in 3D from the last
//! keyframe (iVS3D's GeoDistance), by the positions telemetry gives each frame. The distance is
//! the straight line between the two camera positions: east and north on the WGS84 tangent plane
//! (see `telemetry::distance_m`), up from the height above take-off where both frames have it,
//! else from the altitude above sea level, else none. The first candidate with a position is
//! kept; each later candidate at least `metres` from the last keyframe becomes the next one.
//! Candidates without a position are never kept.

use super::{Applied, Flag, FlagValues, Inputs, Step};
use crate::error::Result;
use crate::source::telemetry::{east_north_m, Position};

/// The step's id.
const ID: &str = "geo-distance";

/// `--geo-distance METRES`.
pub const FLAGS: &[Flag] = &[Flag::value::<f64>(
    "geo-distance",
    "METRES",
    "Keep a frame each time the camera has moved METRES (3D, straight line) since the last keyframe, by the telemetry's positions",
)
.sets(ID, "metres")];

/// The step when `--geo-distance` is given.
pub fn from_flags(v: &FlagValues) -> Result<Option<Step>> {
    Ok(v.get("geo-distance")?
        .map(|metres| Step::GeoDistance { metres }))
}

/// The step on `keys`.
pub fn apply(at: &Inputs, keys: &mut Vec<usize>, metres: f64) -> Result<Applied> {
    let positions = super::positions(at, ID, keys)?;
    *keys = geo_distance(keys, positions, metres);
    Ok(Applied::GeoDistance { metres })
}

/// The straight-line distance between two camera positions, metres.
pub fn distance_3d(a: &Position, b: &Position) -> f64 {
    let (east, north) = east_north_m((a.lat_deg, a.lon_deg), (b.lat_deg, b.lon_deg));
    let up = match (a.rel_alt_m, b.rel_alt_m, a.abs_alt_m, b.abs_alt_m) {
        (Some(x), Some(y), _, _) | (_, _, Some(x), Some(y)) => y - x,
        _ => 0.0,
    };
    (east * east + north * north + up * up).sqrt()
}

/// Candidates at least `metres` apart from the previous one kept.
pub fn geo_distance(
    candidates: &[usize],
    positions: &[Option<Position>],
    metres: f64,
) -> Vec<usize> {
    let mut out = Vec::new();
    let mut last: Option<&Position> = None;
    for &k in candidates {
        let Some(p) = positions.get(k).and_then(Option::as_ref) else {
            continue;
        };
        if last.is_none_or(|l| distance_3d(l, p) >= metres) {
            out.push(k);
            last = Some(p);
        }
    }
    out
}

/// The series the report draws under the geo-distance threshold: metres from the position of
/// the previous keyframe (before the first: of the first frame with a position), NaN outside
/// the sampled range `lo..=hi` (none: every frame) and where a frame or its reference has no
/// position. At the keyframes [`geo_distance`] chose it is the distance it compared.
pub fn moved(
    positions: &[Option<Position>],
    keyframes: &[usize],
    range: Option<(usize, usize)>,
) -> Vec<f64> {
    let (lo, hi) = range.unwrap_or((0, positions.len().saturating_sub(1)));
    let mut out = vec![f64::NAN; positions.len()];
    let mut from: Option<&Position> = None;
    for (f, o) in out.iter_mut().enumerate().take(hi + 1).skip(lo) {
        let here = positions[f].as_ref();
        from = from.or(here);
        if let (Some(a), Some(b)) = (from, here) {
            *o = distance_3d(a, b);
        }
        if keyframes.binary_search(&f).is_ok() {
            from = here;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(lat: f64, rel: f64) -> Option<Position> {
        Some(Position {
            lat_deg: lat,
            lon_deg: 8.0,
            rel_alt_m: Some(rel),
            abs_alt_m: None,
            gimbal_pitch_deg: None,
            gimbal_yaw_deg: None,
            focal_35mm: None,
        })
    }

    #[test]
    fn keeps_a_frame_every_distance_in_3d() {
        // 1e-5° of latitude is about 1.11 m; frame 3 climbs 3 m.
        let p = vec![
            at(47.0, 10.0),
            at(47.00001, 10.0),
            None,
            at(47.00001, 13.0),
            at(47.00003, 13.0),
            at(47.00005, 13.0),
        ];
        let c: Vec<usize> = (0..p.len()).collect();
        assert_eq!(geo_distance(&c, &p, 2.5), vec![0, 3, 5]);
        let m = moved(&p, &[0, 3, 5], Some((1, 5)));
        assert!(m[0].is_nan() && m[2].is_nan(), "{m:?}");
        assert_eq!(m[1], 0.0);
        assert!(m[3] >= 2.5 && m[4] < 2.5 && m[5] >= 2.5, "{m:?}");
        let d = distance_3d(p[0].as_ref().unwrap(), p[3].as_ref().unwrap());
        assert!((d - 1.112f64.hypot(3.0)).abs() < 0.01, "{d}");
    }
}
