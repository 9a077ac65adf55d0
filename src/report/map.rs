//! Flight map for the report: the telemetry path on a local east/north plane (metres, north up,
//! one scale on both axes; no tile server, so it works offline), the keyframes marked, and each
//! keyframe's ground footprint drawn while the pointer is on its mark (CSS only), and the
//! outline of a `geo-area` step's area (holes too) when its file still holds what it held.

use super::camera::{bounds, plot_transform};
use crate::project::Project;
use crate::source::telemetry::{east_north_m, known_camera};
use crate::steps::{footprint, geo_area, Applied};
use std::fmt::{self, Write};

const SIZE: f64 = 520.0;

/// One keyframe on the map.
#[derive(Debug, Clone, PartialEq)]
pub struct MapKey {
    pub frame: usize,
    /// East and north of the camera, metres.
    pub at: (f64, f64),
    /// Corners of its ground footprint, east/north metres (empty when not known).
    pub footprint: Vec<(f64, f64)>,
}

/// The flight as the map draws it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FlightMap {
    /// Every frame with a position: frame, east, north (metres from a local origin).
    pub path: Vec<(usize, f64, f64)>,
    /// The keyframes with a position.
    pub keys: Vec<MapKey>,
    /// The geo-area step's polygons, each as its rings (outer first, then holes), east/north.
    pub area: Vec<Vec<Vec<(f64, f64)>>>,
}

impl FlightMap {
    /// The map of a project with telemetry positions (`None` without): east/north from the first
    /// positioned frame; keyframe footprints as the `footprint-overlap` step computes them, with
    /// the field of view that step was given, else from the telemetry (none when it cannot tell).
    pub fn from_project(pr: &Project) -> Option<FlightMap> {
        let positions = &pr.cache.telemetry.as_ref()?.positions;
        let origin = positions.iter().flatten().next()?;
        let origin = (origin.lat_deg, origin.lon_deg);
        let en =
            |p: &crate::source::telemetry::Position| east_north_m(origin, (p.lat_deg, p.lon_deg));
        let path = positions
            .iter()
            .enumerate()
            .filter_map(|(i, p)| p.as_ref().map(|p| (i, en(p))))
            .map(|(i, (e, n))| (i, e, n))
            .collect();
        let hfov = pr.history.iter().find_map(|h| match h.applied {
            Applied::FootprintOverlap { hfov, .. } => hfov,
            _ => None,
        });
        let camera = pr
            .cache
            .telemetry
            .as_ref()
            .and_then(|t| t.camera.as_deref())
            .and_then(known_camera);
        let size = (pr.metadata.width, pr.metadata.height);
        // Footprints come relative to the first positioned keyframe: shift them onto the map.
        let prints = footprint::footprints(&pr.keyframes, positions, hfov, camera, size)
            .unwrap_or_else(|e| {
                log::info!("flight map without footprints: {e}");
                vec![None; pr.keyframes.len()]
            });
        let shift = pr
            .keyframes
            .iter()
            .find_map(|&k| positions.get(k)?.as_ref())
            .map_or((0.0, 0.0), en);
        let keys = pr
            .keyframes
            .iter()
            .zip(prints)
            .filter_map(|(&k, print)| {
                let at = en(positions.get(k)?.as_ref()?);
                let footprint = print
                    .unwrap_or_default()
                    .into_iter()
                    .map(|(e, n)| (e + shift.0, n + shift.1))
                    .collect();
                Some(MapKey {
                    frame: k,
                    at,
                    footprint,
                })
            })
            .collect();
        let area = area_rings(pr, origin);
        Some(FlightMap { path, keys, area })
    }

    /// The inline SVG (`id="flight-map"`).
    pub fn svg(&self) -> String {
        let mut s = String::new();
        // Writing to a String cannot fail.
        let _ = self.write_svg(&mut s);
        s
    }

    fn write_svg(&self, s: &mut String) -> fmt::Result {
        // Everything drawn decides the extent: the path and every footprint.
        let mut extent = self.path.clone();
        for k in &self.keys {
            extent.push((k.frame, k.at.0, k.at.1));
            extent.extend(k.footprint.iter().map(|&(e, n)| (k.frame, e, n)));
        }
        let area = self.area.iter().flatten().flatten();
        extent.extend(area.map(|&(e, n)| (0, e, n)));
        let to = plot_transform(&extent);
        let keys = self.keys.len();
        writeln!(
            s,
            r##"<svg id="flight-map" width="{SIZE}" height="{SIZE}" font-family="sans-serif" font-size="11" data-keyframes="{keys}"><rect width="{SIZE}" height="{SIZE}" fill="#fafafa" stroke="#999"/>"##
        )?;
        let point = |&(e, n): &(f64, f64)| {
            let (x, y) = to(e, n);
            format!("{x:.1},{y:.1}")
        };
        if !self.area.is_empty() {
            // One path, even-odd filled: holes stay open.
            let rings = self.area.iter().flatten();
            let d: Vec<String> = rings
                .map(|r| format!("M{}Z", r.iter().map(point).collect::<Vec<_>>().join(" L")))
                .collect();
            writeln!(
                s,
                r##"<path id="geo-area" d="{}" fill="#1f6fd1" fill-opacity="0.08" fill-rule="evenodd" stroke="#1f6fd1" stroke-width="1.5" stroke-dasharray="5 3"><title>geo-area</title></path>"##,
                d.join(" ")
            )?;
        }
        let line: Vec<String> = self.path.iter().map(|&(_, e, n)| point(&(e, n))).collect();
        writeln!(
            s,
            r##"<polyline points="{}" fill="none" stroke="#888" stroke-width="1.5"/>"##,
            line.join(" ")
        )?;
        for k in &self.keys {
            let corners: Vec<String> = k.footprint.iter().map(point).collect();
            let (x, y) = to(k.at.0, k.at.1);
            writeln!(
                s,
                r##"<g class="kf" data-frame="{f}"><polygon class="fp" points="{c}"/><circle cx="{x:.1}" cy="{y:.1}" r="4" fill="#cc00cc"/><title>frame {f}</title></g>"##,
                f = k.frame,
                c = corners.join(" ")
            )?;
        }
        write_scale(s, &extent, &to)?;
        writeln!(
            s,
            r##"<text x="{x}" y="16" text-anchor="middle">N ↑</text></svg>"##,
            x = SIZE - 20.0
        )
    }
}

/// The rings of the geo-area step in the history (east/north metres from `origin`), read again
/// from its file; none (logged) when the file is gone or no longer holds what it held.
fn area_rings(pr: &Project, origin: (f64, f64)) -> Vec<Vec<Vec<(f64, f64)>>> {
    let Some((path, fnv)) = pr.history.iter().find_map(|h| match &h.applied {
        Applied::GeoArea { path, fnv1a64, .. } => Some((path, fnv1a64)),
        _ => None,
    }) else {
        return Vec::new();
    };
    let area = match geo_area::Area::load(path) {
        Ok(a) if a.checksum() == *fnv => a,
        Ok(_) => {
            log::warn!(
                "flight map without the geo-area: {} changed since the selection",
                path.display()
            );
            return Vec::new();
        }
        Err(e) => {
            log::warn!("flight map without the geo-area: {e}");
            return Vec::new();
        }
    };
    (area.polygons.iter())
        .map(|p| {
            (p.rings_lat_lon().into_iter())
                .map(|r| r.into_iter().map(|v| east_north_m(origin, v)).collect())
                .collect()
        })
        .collect()
}

/// A scale bar of a round length (1, 2 or 5 × 10^k metres) about a fifth of the plot wide.
fn write_scale(
    s: &mut String,
    extent: &[(usize, f64, f64)],
    to: &impl Fn(f64, f64) -> (f64, f64),
) -> fmt::Result {
    let (lo, hi) = bounds(extent.iter().map(|p| p.1));
    let (x0, _) = to(lo, 0.0);
    let (x1, _) = to(hi, 0.0);
    let px_per_m = if hi > lo { (x1 - x0) / (hi - lo) } else { 0.0 };
    if !(px_per_m.is_finite() && px_per_m > 0.0) {
        return Ok(());
    }
    let metres = round_length(SIZE / 5.0 / px_per_m);
    let w = metres * px_per_m;
    let y = SIZE - 14.0;
    writeln!(
        s,
        r##"<line x1="14" y1="{y}" x2="{x2:.1}" y2="{y}" stroke="#333" stroke-width="3"/><text x="14" y="{t}">{metres} m</text>"##,
        x2 = 14.0 + w,
        t = y - 6.0
    )
}

/// The largest 1, 2 or 5 × 10^k not above `m` (m > 0).
fn round_length(m: f64) -> f64 {
    let p = 10f64.powf(m.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|f| f * p)
        .find(|&v| v <= m)
        .unwrap_or(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_lengths() {
        assert_eq!(round_length(7.3), 5.0);
        assert_eq!(round_length(230.0), 200.0);
        assert_eq!(round_length(1.0), 1.0);
        assert_eq!(round_length(0.031), 0.02);
    }

    #[test]
    fn north_is_up_and_every_keyframe_has_its_footprint() {
        let map = FlightMap {
            path: vec![(0, 0.0, 0.0), (1, 0.0, 50.0), (2, 0.0, 100.0)],
            keys: vec![MapKey {
                frame: 2,
                at: (0.0, 100.0),
                footprint: vec![(-10.0, 90.0), (10.0, 90.0), (10.0, 110.0), (-10.0, 110.0)],
            }],
            area: Vec::new(),
        };
        let svg = map.svg();
        assert!(svg.contains(r#"data-keyframes="1""#) && svg.contains(r#"data-frame="2""#));
        // The path goes north: its last point is drawn above its first.
        let pts = svg.split("polyline points=\"").nth(1).unwrap();
        let ys: Vec<f64> = pts
            .split('"')
            .next()
            .unwrap()
            .split(' ')
            .map(|p| p.split(',').nth(1).unwrap().parse().unwrap())
            .collect();
        assert!(ys[2] < ys[0], "{ys:?}");
        let fp = svg.split("class=\"fp\" points=\"").nth(1).unwrap();
        assert_eq!(fp.split('"').next().unwrap().split(' ').count(), 4);
    }
}
