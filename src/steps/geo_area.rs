//! `geo-area`: keeps the candidates whose telemetry position lies inside an area on the map
//! (iVS3D's GeoMap), read from a GeoJSON file (Polygon or MultiPolygon, bare or in a Feature,
//! FeatureCollection or GeometryCollection) or a KML file (`<Polygon>` with `outerBoundaryIs` and
//! `innerBoundaryIs`), holes included. `--geo-area-buffer M` grows (M > 0) or shrinks (M < 0)
//! the area: a frame is kept when it is inside and/or within |M| metres of the boundary.
//!
//! Each polygon is taken to a local east/north plane in metres around its centre (a linear map
//! of longitude and latitude with the WGS84 radii at the centre's latitude, see
//! `telemetry::east_north_m`), so the inside test equals the one on longitude and latitude
//! (edges straight in longitude and latitude, as GeoJSON defines them) and the buffer is in
//! metres, accurate for areas up to tens of kilometres. Longitudes are unwrapped around each
//! polygon, so one crossing the antimeridian (written with longitudes jumping from 180 to
//! -180, or going past 180) works; a ring that goes round a pole, or touches one, is refused.
//! Candidates without a position are never kept (a warning counts them).

use super::{Applied, Flag, FlagValues, Inputs, Step};
use crate::error::{Error, Result};
use crate::source::telemetry::{east_north_m, short_deg as short, Position};
use std::path::{Path, PathBuf};

/// The step's id.
const ID: &str = "geo-area";

/// `--geo-area FILE`, `--geo-area-buffer M`.
pub const FLAGS: &[Flag] = &[
    Flag::value::<PathBuf>(
        "geo-area",
        "FILE",
        "Keep the frames whose telemetry position lies inside the area of FILE (GeoJSON Polygon / MultiPolygon, or KML <Polygon>; holes respected)",
    )
    .sets(ID, "file"),
    Flag::value::<f64>(
        "geo-area-buffer",
        "M",
        "Grow (M > 0) or shrink (M < 0) the --geo-area by M metres: keep frames inside and/or within |M| m of its boundary",
    )
    .sets(ID, "buffer_m"),
];

/// The step when `--geo-area` is given; `--geo-area-buffer` alone is refused.
pub fn from_flags(v: &FlagValues) -> Result<Option<Step>> {
    let buffer_m = v.get::<f64>("geo-area-buffer")?;
    match v.get::<PathBuf>("geo-area")? {
        Some(file) => Ok(Some(Step::GeoArea { file, buffer_m })),
        None if buffer_m.is_some() => Err(Error::param(
            "geo-area-buffer",
            "needs --geo-area FILE (the area it grows or shrinks)",
        )),
        None => Ok(None),
    }
}

/// Checks the buffer: a finite number of metres.
pub fn check_buffer(buffer_m: Option<f64>) -> std::result::Result<(), String> {
    match buffer_m {
        Some(b) if !b.is_finite() => Err(format!("must be a number of metres, got {b}")),
        _ => Ok(()),
    }
}

/// The step on `keys`: reads the area (the file as given), keeps the candidates inside.
pub fn apply(
    at: &Inputs,
    keys: &mut Vec<usize>,
    file: &Path,
    buffer_m: Option<f64>,
) -> Result<Applied> {
    let area = Area::load(file)?;
    let positions = super::positions(at, ID, keys)?;
    let buffer = buffer_m.unwrap_or(0.0);
    keys.retain(|&k| {
        (positions.get(k).and_then(Option::as_ref)).is_some_and(|p| area.keeps(p, buffer))
    });
    Ok(Applied::GeoArea {
        file: file.to_path_buf(),
        path: crate::fsutil::absolute(file),
        buffer_m,
        polygons: area.polygons.len(),
        vertices: area.vertices(),
        fnv1a64: area.checksum(),
    })
}

/// Warns when this selection's area file (same path) no longer holds what the replaced
/// project's selection read: its FNV-1a hash or vertex count differ.
pub fn note_changes(before: &[super::Recorded], now: &[super::Recorded]) {
    let area = |h: &[super::Recorded]| {
        h.iter().find_map(|r| match &r.applied {
            Applied::GeoArea {
                path,
                vertices,
                fnv1a64,
                ..
            } => Some((path.clone(), *vertices, fnv1a64.clone())),
            _ => None,
        })
    };
    if let (Some(old), Some(new)) = (area(before), area(now)) {
        if old.0 == new.0 && (old.1, &old.2) != (new.1, &new.2) {
            log::warn!(
                "{ID}: {} changed since the last selection ({} vertices, FNV-1a {} then; {} \
                 vertices, {} now): the keyframes follow the file as it is now",
                new.0.display(),
                old.1,
                old.2,
                new.1,
                new.2
            );
        }
    }
}

/// One ring as read: where it is in the file (for messages) and its (longitude, latitude)
/// vertices in degrees, with the closing vertex when the file repeats it.
#[derive(Debug, Clone)]
struct RawRing {
    at: String,
    lon_lat: Vec<(f64, f64)>,
}

/// One polygon on its local plane: its outer ring and holes in metres east and north of
/// `origin` (latitude, unwrapped longitude), and the metres per degree there.
#[derive(Debug, Clone)]
pub struct Polygon {
    origin: (f64, f64),
    per_deg: (f64, f64),
    /// The outer ring first, then the holes: east/north metres, not closed.
    rings: Vec<Vec<(f64, f64)>>,
}

impl Polygon {
    /// East/north metres of a position on this polygon's plane (its longitude unwrapped to
    /// within 180° of the polygon's centre).
    fn local(&self, lat: f64, lon: f64) -> (f64, f64) {
        let lon = lon + 360.0 * ((self.origin.1 - lon) / 360.0).round();
        (
            (lon - self.origin.1) * self.per_deg.0,
            (lat - self.origin.0) * self.per_deg.1,
        )
    }

    /// Whether `p` (east/north) is inside: an odd number of ring edges crossed by the ray east
    /// of it (holes are rings, so a point in a hole crosses an even number).
    fn inside(&self, p: (f64, f64)) -> bool {
        let mut odd = false;
        for ring in &self.rings {
            for (i, &a) in ring.iter().enumerate() {
                let b = ring[(i + 1) % ring.len()];
                if (a.1 > p.1) != (b.1 > p.1) {
                    let x = a.0 + (p.1 - a.1) / (b.1 - a.1) * (b.0 - a.0);
                    if p.0 < x {
                        odd = !odd;
                    }
                }
            }
        }
        odd
    }

    /// Metres from `p` to the nearest edge of any ring.
    fn distance_to_boundary(&self, p: (f64, f64)) -> f64 {
        let mut best = f64::INFINITY;
        for ring in &self.rings {
            for (i, &a) in ring.iter().enumerate() {
                best = best.min(segment_distance(p, a, ring[(i + 1) % ring.len()]));
            }
        }
        best
    }

    /// Whether the polygon grown (`buffer` > 0) or shrunk (< 0) by `buffer` metres holds `p`.
    fn holds(&self, p: (f64, f64), buffer: f64) -> bool {
        let inside = self.inside(p);
        if buffer > 0.0 {
            inside || self.distance_to_boundary(p) <= buffer
        } else if buffer < 0.0 {
            inside && self.distance_to_boundary(p) >= -buffer
        } else {
            inside
        }
    }

    /// The rings as (latitude, longitude) in degrees, longitudes unwrapped around the polygon.
    pub fn rings_lat_lon(&self) -> Vec<Vec<(f64, f64)>> {
        (self.rings.iter())
            .map(|r| {
                r.iter()
                    .map(|&(e, n)| {
                        (
                            self.origin.0 + n / self.per_deg.1,
                            self.origin.1 + e / self.per_deg.0,
                        )
                    })
                    .collect()
            })
            .collect()
    }
}

/// Metres from `p` to the segment `a`–`b`.
fn segment_distance(p: (f64, f64), a: (f64, f64), b: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p.0 - a.0 - t * dx).hypot(p.1 - a.1 - t * dy)
}

/// An area read from a file: its polygons and the FNV-1a hash of the file's bytes.
#[derive(Debug, Clone)]
pub struct Area {
    /// The polygons; a position inside any of them is inside the area.
    pub polygons: Vec<Polygon>,
    hash: u64,
}

impl Area {
    /// Reads a GeoJSON or KML file (by its content: KML starts with `<`); errors name the file
    /// and the place in it: line and column for broken JSON or XML, the ring and coordinate for
    /// bad geometry.
    pub fn load(path: &Path) -> Result<Area> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let bad = |msg: String| Error::input(path, format!("not a usable area file: {msg}"));
        let text = String::from_utf8_lossy(&bytes);
        let text = text.trim_start_matches('\u{feff}');
        let rings = if text.trim_start().starts_with('<') {
            kml_rings(text).map_err(bad)?
        } else {
            geojson_rings(text).map_err(bad)?
        };
        if rings.is_empty() {
            return Err(bad(
                "no polygon in it (a GeoJSON Polygon or MultiPolygon, or a KML <Polygon>)".into(),
            ));
        }
        let polygons = (rings.iter())
            .map(|p| polygon(p))
            .collect::<std::result::Result<Vec<_>, String>>()
            .map_err(bad)?;
        Ok(Area {
            polygons,
            hash: crate::output::fnv1a64(&bytes),
        })
    }

    /// Whether the area, grown or shrunk by `buffer` metres, holds the position.
    pub fn keeps(&self, p: &Position, buffer: f64) -> bool {
        (self.polygons.iter()).any(|poly| poly.holds(poly.local(p.lat_deg, p.lon_deg), buffer))
    }

    /// Vertices over all rings (each counted once, the closing one not).
    pub fn vertices(&self) -> usize {
        (self.polygons.iter())
            .flat_map(|p| &p.rings)
            .map(Vec::len)
            .sum()
    }

    /// The file's FNV-1a hash as 16 hex digits (the history records it).
    pub fn checksum(&self) -> String {
        format!("{:016x}", self.hash)
    }
}

/// One polygon's rings as read, checked and put on its local plane: each ring has at least
/// three distinct vertices, latitudes within ±90° (not at a pole), longitudes within ±540°;
/// edges take the short way across the antimeridian, and a ring whose longitudes wind round
/// the globe (it encloses a pole) is refused.
fn polygon(rings: &[RawRing]) -> std::result::Result<Polygon, String> {
    let mut unwrapped: Vec<Vec<(f64, f64)>> = Vec::new();
    for ring in rings {
        let at = &ring.at;
        let mut pts = ring.lon_lat.clone();
        for (i, &(lon, lat)) in pts.iter().enumerate() {
            if !(-90.0..=90.0).contains(&lat) {
                return Err(format!(
                    "{at}, coordinate {i}: latitude {lat} is outside -90..90"
                ));
            }
            if !(-540.0..=540.0).contains(&lon) {
                return Err(format!(
                    "{at}, coordinate {i}: longitude {lon} is outside -540..540"
                ));
            }
            if lat.abs() == 90.0 {
                return Err(format!(
                    "{at}, coordinate {i}: a vertex at the pole (latitude {lat}): areas at or \
                     around a pole are not supported (split it into parts that stay off the pole)"
                ));
            }
        }
        if pts.len() > 1 && pts.first() == pts.last() {
            pts.pop();
        }
        pts.dedup();
        if pts.len() < 3 {
            return Err(format!(
                "{at}: too few points ({} distinct; a ring needs at least 3, and GeoJSON repeats \
                 the first at the end)",
                pts.len()
            ));
        }
        // The short way along each edge; the reference for the holes is the outer ring's start.
        let start = match unwrapped.first() {
            Some(outer) => outer[0].0,
            None => pts[0].0,
        };
        let mut lon = pts[0].0 + 360.0 * ((start - pts[0].0) / 360.0).round();
        let mut out = vec![(lon, pts[0].1)];
        for w in pts.windows(2) {
            lon += short(w[1].0 - w[0].0);
            out.push((lon, w[1].1));
        }
        let closing = short(pts[0].0 - pts[pts.len() - 1].0);
        let wound = lon + closing - out[0].0;
        if wound.abs() > 180.0 {
            let pole = if pts.iter().map(|p| p.1).sum::<f64>() > 0.0 {
                "north"
            } else {
                "south"
            };
            return Err(format!(
                "{at}: the ring goes round the {pole} pole (its longitudes wind through 360°): \
                 areas around a pole are not supported (split it into parts that do not \
                 enclose the pole)"
            ));
        }
        unwrapped.push(out);
    }
    let outer = &unwrapped[0];
    let (lat_lo, lat_hi) = min_max(outer.iter().map(|p| p.1));
    let (lon_lo, lon_hi) = min_max(outer.iter().map(|p| p.0));
    let origin = (0.5 * (lat_lo + lat_hi), 0.5 * (lon_lo + lon_hi));
    // Metres per degree at the centre's latitude: east along the parallel, north along the
    // meridian (both ends equally far from it, so the mean latitude is the centre's).
    let per_deg = (
        east_north_m((origin.0, 0.0), (origin.0, 1.0)).0,
        east_north_m((origin.0 - 0.5, 0.0), (origin.0 + 0.5, 0.0)).1,
    );
    let rings = (unwrapped.iter())
        .map(|r| {
            r.iter()
                .map(|&(lon, lat)| ((lon - origin.1) * per_deg.0, (lat - origin.0) * per_deg.1))
                .collect()
        })
        .collect();
    Ok(Polygon {
        origin,
        per_deg,
        rings,
    })
}

fn min_max(v: impl Iterator<Item = f64>) -> (f64, f64) {
    v.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
        (lo.min(x), hi.max(x))
    })
}

/// The polygons of a GeoJSON text, each as its rings.
fn geojson_rings(text: &str) -> std::result::Result<Vec<Vec<RawRing>>, String> {
    let v: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| format!("line {}, column {}: not JSON: {e}", e.line(), e.column()))?;
    let mut out = Vec::new();
    geojson_object(&v, "", &mut out)?;
    Ok(out)
}

/// Walks a GeoJSON object at `path` (`features[2].geometry`), collecting its polygons; other
/// geometries (points, lines) are skipped.
fn geojson_object(
    v: &serde_json::Value,
    path: &str,
    out: &mut Vec<Vec<RawRing>>,
) -> std::result::Result<(), String> {
    let here = |key: &str| match path {
        "" => key.to_string(),
        p => format!("{p}.{key}"),
    };
    let name = if path.is_empty() {
        "the top level"
    } else {
        path
    };
    let Some(kind) = v.get("type").and_then(|t| t.as_str()) else {
        return Err(format!("{name}: not a GeoJSON object (no \"type\")"));
    };
    let list = |key: &str| {
        v.get(key)
            .and_then(|x| x.as_array())
            .ok_or_else(|| format!("{}: missing or not a list", here(key)))
    };
    match kind {
        "FeatureCollection" => {
            for (i, f) in list("features")?.iter().enumerate() {
                geojson_object(f, &format!("{}[{i}]", here("features")), out)?;
            }
        }
        "GeometryCollection" => {
            for (i, g) in list("geometries")?.iter().enumerate() {
                geojson_object(g, &format!("{}[{i}]", here("geometries")), out)?;
            }
        }
        "Feature" => match v.get("geometry") {
            Some(g) if !g.is_null() => geojson_object(g, &here("geometry"), out)?,
            _ => {}
        },
        "Polygon" => out.push(geojson_polygon(list("coordinates")?, &here("coordinates"))?),
        "MultiPolygon" => {
            for (i, p) in list("coordinates")?.iter().enumerate() {
                let at = format!("{}[{i}]", here("coordinates"));
                let rings = p
                    .as_array()
                    .ok_or_else(|| format!("{at}: not a list of rings"))?;
                out.push(geojson_polygon(rings, &at)?);
            }
        }
        _ => {}
    }
    Ok(())
}

/// The rings of one GeoJSON polygon (`coordinates` of a Polygon) at `at`.
fn geojson_polygon(
    rings: &[serde_json::Value],
    at: &str,
) -> std::result::Result<Vec<RawRing>, String> {
    if rings.is_empty() {
        return Err(format!("{at}: a polygon without rings"));
    }
    let mut out = Vec::new();
    for (j, ring) in rings.iter().enumerate() {
        let kind = if j == 0 { "outer ring" } else { "hole" };
        let ring_at = format!("{at}[{j}] ({kind})");
        let pts = ring
            .as_array()
            .ok_or_else(|| format!("{ring_at}: not a list of positions"))?;
        let mut lon_lat = Vec::with_capacity(pts.len());
        for (i, p) in pts.iter().enumerate() {
            let nums = p
                .as_array()
                .map(|a| a.iter().map(|x| x.as_f64()).collect::<Vec<_>>());
            match nums.as_deref() {
                Some([Some(lon), Some(lat), rest @ ..]) if rest.iter().all(Option::is_some) => {
                    lon_lat.push((*lon, *lat));
                }
                _ => {
                    return Err(format!(
                        "{ring_at}, coordinate {i}: {p} is not a position [longitude, \
                         latitude(, altitude)] of numbers"
                    ))
                }
            }
        }
        out.push(RawRing {
            at: ring_at,
            lon_lat,
        });
    }
    Ok(out)
}

/// The polygons of a KML text: every `<Polygon>` with its `outerBoundaryIs` and
/// `innerBoundaryIs` `<LinearRing><coordinates>` (`lon,lat[,alt]` tuples separated by white
/// space); other elements are skipped.
fn kml_rings(text: &str) -> std::result::Result<Vec<Vec<RawRing>>, String> {
    use xml::common::Position as _;
    use xml::reader::{EventReader, XmlEvent};
    let mut reader = EventReader::new(text.as_bytes());
    let mut out: Vec<Vec<RawRing>> = Vec::new();
    // The polygon being read, the boundary we are in (true: outer) and the coordinates' text
    // with the line where it started.
    let mut polygon: Option<(usize, Vec<RawRing>)> = None;
    let mut boundary: Option<bool> = None;
    let mut coords: Option<(u64, String)> = None;
    let mut count = 0;
    loop {
        let line = reader.position().row + 1;
        match reader.next() {
            Ok(XmlEvent::StartElement { name, .. }) => match name.local_name.as_str() {
                "Polygon" => {
                    count += 1;
                    polygon = Some((count, Vec::new()));
                }
                "outerBoundaryIs" => boundary = Some(true),
                "innerBoundaryIs" => boundary = Some(false),
                "coordinates" if polygon.is_some() && boundary.is_some() => {
                    coords = Some((reader.position().row + 1, String::new()));
                }
                _ => {}
            },
            Ok(XmlEvent::Characters(t) | XmlEvent::CData(t)) => {
                if let Some((_, text)) = &mut coords {
                    text.push_str(&t);
                }
            }
            Ok(XmlEvent::EndElement { name }) => match name.local_name.as_str() {
                "coordinates" => {
                    if let (Some((row, text)), Some((n, rings)), Some(outer)) =
                        (coords.take(), &mut polygon, boundary)
                    {
                        let kind = if outer {
                            "outerBoundaryIs"
                        } else {
                            "innerBoundaryIs"
                        };
                        let at = format!("<Polygon> {n}, {kind} (line {row})");
                        if outer && !rings.is_empty() {
                            return Err(format!("{at}: a second outer boundary"));
                        }
                        if !outer && rings.is_empty() {
                            return Err(format!("{at}: a hole before the outer boundary"));
                        }
                        let lon_lat = kml_coordinates(&text).map_err(|e| format!("{at}, {e}"))?;
                        rings.push(RawRing { at, lon_lat });
                    }
                }
                "outerBoundaryIs" | "innerBoundaryIs" => boundary = None,
                "Polygon" => {
                    if let Some((n, rings)) = polygon.take() {
                        if rings.is_empty() {
                            return Err(format!(
                                "<Polygon> {n} (ending line {line}): no outerBoundaryIs coordinates"
                            ));
                        }
                        out.push(rings);
                    }
                }
                _ => {}
            },
            Ok(XmlEvent::EndDocument) => break,
            Ok(_) => {}
            Err(e) => {
                let p = e.position();
                return Err(format!(
                    "line {}, column {}: not readable XML: {}",
                    p.row + 1,
                    p.column + 1,
                    e.msg()
                ));
            }
        }
    }
    Ok(out)
}

/// `lon,lat[,alt]` tuples separated by white space.
fn kml_coordinates(text: &str) -> std::result::Result<Vec<(f64, f64)>, String> {
    let mut out = Vec::new();
    for (i, tuple) in text.split_whitespace().enumerate() {
        let nums: Vec<Option<f64>> = tuple.split(',').map(|x| x.parse().ok()).collect();
        match nums.as_slice() {
            [Some(lon), Some(lat)] | [Some(lon), Some(lat), Some(_)] => out.push((*lon, *lat)),
            _ => {
                return Err(format!(
                    "coordinate {i}: `{tuple}` is not longitude,latitude[,altitude] in numbers"
                ))
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(lat: f64, lon: f64) -> Position {
        Position {
            lat_deg: lat,
            lon_deg: lon,
            rel_alt_m: None,
            abs_alt_m: None,
            gimbal_pitch_deg: None,
            gimbal_yaw_deg: None,
            focal_35mm: None,
        }
    }

    fn area(text: &str) -> std::result::Result<Area, String> {
        let rings = if text.starts_with('<') {
            kml_rings(text)?
        } else {
            geojson_rings(text)?
        };
        Ok(Area {
            polygons: rings
                .iter()
                .map(|r| polygon(r))
                .collect::<std::result::Result<_, _>>()?,
            hash: 0,
        })
    }

    #[test]
    fn square_with_a_hole_and_a_buffer() {
        // 0.002° square around (47.001, 8.001) with a 0.0005° hole in the middle.
        let a = area(
            r#"{"type":"Polygon","coordinates":[
              [[8,47],[8.002,47],[8.002,47.002],[8,47.002],[8,47]],
              [[8.00075,47.00075],[8.00125,47.00075],[8.00125,47.00125],[8.00075,47.00125],[8.00075,47.00075]]]}"#,
        )
        .unwrap();
        assert_eq!(a.vertices(), 8);
        assert!(a.keeps(&at(47.0005, 8.0005), 0.0));
        assert!(!a.keeps(&at(47.001, 8.001), 0.0), "in the hole");
        assert!(!a.keeps(&at(47.003, 8.001), 0.0));
        // 0.0001° of latitude is about 11.1 m: 20 m grows the area past a point 11 m out.
        assert!(a.keeps(&at(47.0021, 8.001), 20.0));
        assert!(!a.keeps(&at(47.0021, 8.001), 5.0));
        // Shrinking: a point 11 m inside the edge is dropped with -20 m, kept with -5 m.
        assert!(!a.keeps(&at(47.0019, 8.0005), -20.0));
        assert!(a.keeps(&at(47.0019, 8.0005), -5.0));
        // The hole grows when the area shrinks: 11 m from the hole's edge.
        assert!(!a.keeps(&at(47.00135, 8.001), -20.0));
        assert!(a.keeps(&at(47.00135, 8.001), 0.0));
    }

    #[test]
    fn antimeridian_is_unwrapped_and_poles_are_refused() {
        let a = area(
            r#"{"type":"Polygon","coordinates":[[[179.999,-16],[-179.999,-16],[-179.999,-15.998],[179.999,-15.998],[179.999,-16]]]}"#,
        )
        .unwrap();
        assert!(a.keeps(&at(-15.999, 180.0), 0.0));
        assert!(a.keeps(&at(-15.999, -180.0), 0.0));
        assert!(a.keeps(&at(-15.999, 179.9995), 0.0));
        assert!(a.keeps(&at(-15.999, -179.9995), 0.0));
        assert!(!a.keeps(&at(-15.999, 179.99), 0.0));
        assert!(!a.keeps(&at(-15.999, 0.0), 0.0));
        let polar =
            r#"{"type":"Polygon","coordinates":[[[0,80],[90,80],[180,80],[-90,80],[0,80]]]}"#;
        let e = area(polar).unwrap_err();
        assert!(
            e.contains("north pole") && e.contains("coordinates[0]"),
            "{e}"
        );
        let cap = r#"{"type":"Polygon","coordinates":[[[-180,80],[180,80],[180,90],[-180,90],[-180,80]]]}"#;
        let e = area(cap).unwrap_err();
        assert!(e.contains("coordinate 2") && e.contains("pole"), "{e}");
    }

    #[test]
    fn errors_name_the_place() {
        let e =
            area("{\"type\": \"Polygon\",\n \"coordinates\": [[[8, 47], [8.1, 47]").unwrap_err();
        assert!(e.starts_with("line 2, column "), "{e}");
        let e = area(r#"{"type":"Feature","geometry":{"type":"Polygon","coordinates":[[[8,47],[8.1,47],[8,47]]]}}"#)
            .unwrap_err();
        assert!(
            e.contains("geometry.coordinates[0] (outer ring): too few points"),
            "{e}"
        );
        let e = area(r#"{"type":"MultiPolygon","coordinates":[[[[8,47],[8.1,47],[8.1,47.1],[8,47]]],[[[8,47],[8.1,"x"],[8.1,47.1],[8,47]]]]}"#)
            .unwrap_err();
        assert!(
            e.contains("coordinates[1][0] (outer ring), coordinate 1"),
            "{e}"
        );
        let e = area(r#"{"type":"Polygon","coordinates":[[[8,47],[8.1,47],[8.1,97],[8,47]]]}"#)
            .unwrap_err();
        assert!(e.contains("coordinate 2: latitude 97"), "{e}");
    }

    #[test]
    fn kml_polygon_with_a_hole() {
        let kml = "<?xml version=\"1.0\"?>\n<kml xmlns=\"http://www.opengis.net/kml/2.2\"><Placemark>\n\
            <Polygon><outerBoundaryIs><LinearRing><coordinates>\n 8,47,0 8.002,47,0 8.002,47.002,0 8,47.002,0 8,47,0\n\
            </coordinates></LinearRing></outerBoundaryIs><innerBoundaryIs><LinearRing><coordinates>8.00075,47.00075 \
            8.00125,47.00075 8.00125,47.00125 8.00075,47.00125 8.00075,47.00075</coordinates></LinearRing>\
            </innerBoundaryIs></Polygon></Placemark></kml>\n";
        let a = area(kml).unwrap();
        assert_eq!(a.polygons.len(), 1);
        assert!(a.keeps(&at(47.0005, 8.0005), 0.0));
        assert!(!a.keeps(&at(47.001, 8.001), 0.0));
        let e = area(&kml.replace("8.002,47,0", "8.002;47")).unwrap_err();
        assert!(
            e.contains("<Polygon> 1, outerBoundaryIs (line 3), coordinate 1"),
            "{e}"
        );
        let e = area("<kml><Polygon>\n<outerBoundaryIs></Polygon></kml>").unwrap_err();
        assert!(e.starts_with("line 2"), "{e}");
    }
}
