//! Drone telemetry from a DJI SRT sidecar: one fix (time, position, camera facts) per subtitle
//! entry, read leniently (CRLF, a BOM, missing fields, unknown fields); every entry skipped or
//! suspicious becomes a warning naming the file and line, never a silent guess.
//!
//! The families read (each entry's text, after the SRT index and `start --> end` lines):
//! - bracketed (Mini 2/3/4, Air 2S, Mavic 3 and later): `[latitude: 47.1] [longitude: 8.5]
//!   [rel_alt: 40.0 abs_alt: 512.3] [iso: 100] [shutter: 1/1000.0] [fnum: 2.8]
//!   [focal_len: 24.00] [gb_pitch: -90.0]`, also `longtitude` (a firmware spelling), `altitude`,
//!   `key : value` with a space, several `key: value` pairs in one bracket, an F-number times
//!   100 (`fnum: 170`) and a focal length times 10 (`focal_len: 240`);
//! - older (Phantom 3/4, Mavic Pro): `GPS(8.5,47.1,16)` or `GPS (8.5, 47.1, 16)` with longitude
//!   first, `BAROMETER:40.5` or `H 40.50m` for the height above take-off, `ISO:100`, `Fnum:F2.2`
//!   or `F/2.8`, `Shutter:60` or `SS 320` (1/60 s, 1/320 s).
//!
//! The focal length DJI writes is the 35 mm equivalent. DJI does not publish the format; the
//! families are as described in OpenDroneMap's `opendm/video/srtparser.py` (Mavic Air 2 and
//! Mavic Mini samples in its comments) and the DJI_SRT_Parser project (JuanIrache, Mavic Pro and
//! Phantom files); the tests' entries are written from those descriptions.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};
use time::format_description::well_known::Rfc3339;
use time::OffsetDateTime;

/// What kind of telemetry a project's positions came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TelemetryKind {
    /// A DJI SRT subtitle sidecar.
    DjiSrt,
    /// A GPX track, timed from the video's creation time.
    Gpx,
    /// The EXIF GPS tags of each image of an image folder (or of a single image).
    Exif,
}

/// One frame's camera position and attitude, as a project stores it (a [`Fix`] interpolated at
/// the frame's timestamp, without the exposure facts).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Position {
    /// Latitude, degrees north.
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Height above the take-off point, metres.
    pub rel_alt_m: Option<f64>,
    /// Altitude above sea level, metres.
    pub abs_alt_m: Option<f64>,
    /// Gimbal pitch, degrees (-90: nadir).
    pub gimbal_pitch_deg: Option<f64>,
    /// Gimbal yaw, degrees clockwise from north.
    pub gimbal_yaw_deg: Option<f64>,
    /// 35 mm equivalent focal length, millimetres.
    pub focal_35mm: Option<f64>,
}

impl From<&Fix> for Position {
    fn from(f: &Fix) -> Position {
        Position {
            lat_deg: f.lat_deg,
            lon_deg: f.lon_deg,
            rel_alt_m: f.rel_alt_m,
            abs_alt_m: f.abs_alt_m,
            gimbal_pitch_deg: f.gimbal_pitch_deg,
            gimbal_yaw_deg: f.gimbal_yaw_deg,
            focal_35mm: f.focal_35mm,
        }
    }
}

/// One telemetry entry.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Fix {
    /// Seconds from the start of the video (the entry's start time).
    pub t_s: f64,
    /// Latitude, degrees north.
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Height above the take-off point, metres.
    pub rel_alt_m: Option<f64>,
    /// Altitude above sea level (GPS or barometric, as the drone reports it), metres.
    pub abs_alt_m: Option<f64>,
    /// 35 mm equivalent focal length, millimetres.
    pub focal_35mm: Option<f64>,
    /// Gimbal pitch, degrees (-90: nadir).
    pub gimbal_pitch_deg: Option<f64>,
    /// Gimbal yaw, degrees clockwise from north (DJI's `gb_yaw`).
    pub gimbal_yaw_deg: Option<f64>,
    /// ISO sensitivity.
    pub iso: Option<f64>,
    /// Exposure time, seconds.
    pub shutter_s: Option<f64>,
    /// Aperture f-number.
    pub fnum: Option<f64>,
    /// Where the fix is in its file, for messages: an SRT entry's time line, a GPX track point's
    /// number (from 1, over all tracks and segments), 0 for an image's EXIF.
    pub line: usize,
}

/// The fixes of one telemetry file, in time order, and what was wrong with it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Track {
    /// The telemetry file.
    pub path: PathBuf,
    /// Its fixes, in time order.
    pub fixes: Vec<Fix>,
    /// `FILE:line N: what` (GPX: `FILE:point N: what`) for every entry skipped or suspicious.
    pub warnings: Vec<String>,
}

/// Consecutive fixes further apart than this (metres per second of their time difference, with
/// a floor of one second) are reported as a jump: no drone flies 200 m/s.
const JUMP_M_PER_S: f64 = 200.0;

/// The DJI sidecar of `video`: the same stem with `.SRT` or `.srt`, when it exists.
pub fn sidecar_of(video: &Path) -> Option<PathBuf> {
    ["SRT", "srt"]
        .iter()
        .map(|e| video.with_extension(e))
        .find(|p| p.is_file())
}

/// Reads and parses the DJI SRT file at `path`. Fails when it cannot be read or holds no fix.
pub fn read_dji_srt(path: &Path) -> Result<Track> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let track = parse_dji_srt(path, &String::from_utf8_lossy(&bytes));
    if track.fixes.is_empty() {
        let why = track.warnings.first().map(String::as_str).unwrap_or("");
        let msg = format!("no telemetry entry with a position (first problem: {why})");
        return Err(Error::input(path, msg));
    }
    Ok(track)
}

/// Parses the text of a DJI SRT file (`path` names it in warnings).
pub fn parse_dji_srt(path: &Path, text: &str) -> Track {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let lines: Vec<&str> = text.lines().map(|l| l.trim_end_matches('\r')).collect();
    let mut track = Track {
        path: path.into(),
        ..Track::default()
    };
    let name = path.display().to_string();
    let mut i = 0;
    while i < lines.len() {
        let Some(t_s) = lines[i].split_once("-->").and_then(|(a, _)| srt_time(a)) else {
            i += 1;
            continue;
        };
        let line = i + 1;
        let end = (i + 1..lines.len())
            .find(|&j| lines[j].trim().is_empty() || lines[j].contains("-->"))
            .unwrap_or(lines.len());
        let body = lines[i + 1..end].join(" ");
        match fix_of(&body, t_s, line) {
            Ok(fix) => track.fixes.push(fix),
            Err(why) => track
                .warnings
                .push(format!("{name}:line {line}: {why} (entry skipped)")),
        }
        i = end;
    }
    check_order_and_jumps(&mut track, "line");
    track
}

/// Sorts the fixes by time (warning when they were not) and warns of every jump between
/// consecutive fixes (`unit` names what `Fix::line` counts).
fn check_order_and_jumps(track: &mut Track, unit: &str) {
    let name = track.path.display().to_string();
    if !track.fixes.windows(2).all(|w| w[0].t_s <= w[1].t_s) {
        track
            .warnings
            .push(format!("{name}: entries out of time order (sorted)"));
        track.fixes.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    }
    for w in track.fixes.windows(2) {
        let d = distance_m(&w[0], &w[1]);
        if d > JUMP_M_PER_S * (w[1].t_s - w[0].t_s).max(1.0) {
            track.warnings.push(format!(
                "{name}:{unit} {}: the position jumps {:.0} m from {unit} {} in {:.3} s",
                w[1].line,
                d,
                w[0].line,
                w[1].t_s - w[0].t_s
            ));
        }
    }
}

/// Reads the track points of a GPX file (every track and segment) as fixes timed in seconds
/// from `start` (the video's creation time) plus `offset_s` (`--telemetry-offset`, to correct
/// the camera's clock): a point at `start + offset_s` is at the video's first frame. A point
/// without a time, with a latitude, longitude, elevation or time that does not parse or is out
/// of range, is skipped with a warning naming it; XML broken after the first point (a file cut
/// short) ends the track there, warned. Fails when the file cannot be read, is not GPX, or holds
/// no usable point.
pub fn read_gpx(path: &Path, start: OffsetDateTime, offset_s: f64) -> Result<Track> {
    use xml::reader::{EventReader, XmlEvent};
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let not_gpx = |why: String| Error::input(path, format!("not a readable GPX file: {why}"));
    let name = path.display().to_string();
    let mut track = Track {
        path: path.into(),
        ..Track::default()
    };
    let mut reader = EventReader::new(std::io::BufReader::new(file));
    let (mut depth, mut count) = (0, 0);
    let mut point: Option<GpxPoint> = None;
    // The `ele` or `time` child of the point being read, and its text so far.
    let mut child: Option<(String, String)> = None;
    loop {
        match reader.next() {
            Ok(XmlEvent::StartElement {
                name: tag,
                attributes,
                ..
            }) => {
                depth += 1;
                let tag = tag.local_name;
                if depth == 1 && tag != "gpx" {
                    return Err(not_gpx(format!("the root element is <{tag}>")));
                }
                let attr = |n: &str| {
                    let a = attributes.iter().find(|a| a.name.local_name == n);
                    a.map(|a| a.value.clone())
                };
                match &point {
                    None if tag == "trkpt" => {
                        count += 1;
                        point = Some(GpxPoint {
                            depth,
                            number: count,
                            lat: attr("lat"),
                            lon: attr("lon"),
                            ..GpxPoint::default()
                        });
                    }
                    Some(p) if depth == p.depth + 1 && (tag == "ele" || tag == "time") => {
                        child = Some((tag, String::new()));
                    }
                    _ => {}
                }
            }
            Ok(XmlEvent::Characters(t) | XmlEvent::CData(t)) => {
                if let Some((_, text)) = &mut child {
                    text.push_str(&t);
                }
            }
            Ok(XmlEvent::EndElement { .. }) => {
                if let (Some((tag, text)), Some(p)) = (child.take(), &mut point) {
                    *(if tag == "ele" {
                        &mut p.ele
                    } else {
                        &mut p.time
                    }) = Some(text);
                } else if let Some(p) = point.take_if(|p| p.depth == depth) {
                    match p.fix(start, offset_s) {
                        Ok(fix) => track.fixes.push(fix),
                        Err(why) => (track.warnings)
                            .push(format!("{name}:point {}: {why} (skipped)", p.number)),
                    }
                }
                depth -= 1;
            }
            Ok(XmlEvent::EndDocument) => break,
            Ok(_) => {}
            Err(e) if count == 0 => return Err(not_gpx(e.to_string())),
            Err(e) => {
                let msg = format!("{name}: broken XML after point {count}: {e} (the rest skipped)");
                track.warnings.push(msg);
                break;
            }
        }
    }
    if track.fixes.is_empty() {
        let why = track
            .warnings
            .first()
            .map_or("none in the file", String::as_str);
        let msg = format!("no track point with a position and a time (first problem: {why})");
        return Err(Error::input(path, msg));
    }
    check_order_and_jumps(&mut track, "point");
    Ok(track)
}

/// A GPX track point as written: its depth in the document, its number (from 1, over all tracks
/// and segments) and the text of its coordinates, elevation and time.
#[derive(Default)]
struct GpxPoint {
    depth: usize,
    number: usize,
    lat: Option<String>,
    lon: Option<String>,
    ele: Option<String>,
    time: Option<String>,
}

impl GpxPoint {
    /// Its fix, or why it has none.
    fn fix(&self, start: OffsetDateTime, offset_s: f64) -> std::result::Result<Fix, String> {
        use time::format_description::well_known::Iso8601;
        let num = |v: &Option<String>, what: &str| {
            let v = v.as_deref().ok_or_else(|| format!("no {what}"))?;
            let x = v.trim().parse::<f64>().ok().filter(|x| x.is_finite());
            x.ok_or_else(|| format!("{what} `{v}` is not a finite number"))
        };
        let (lat, lon) = (num(&self.lat, "lat")?, num(&self.lon, "lon")?);
        position_ok(lat, lon)?;
        let ele = self
            .ele
            .as_ref()
            .map(|_| num(&self.ele, "ele"))
            .transpose()?;
        let text = self.time.as_deref().ok_or("no time")?.trim();
        // xsd:dateTime: with an offset, or without one (UTC).
        let time = OffsetDateTime::parse(text, &Iso8601::PARSING)
            .or_else(|_| {
                time::PrimitiveDateTime::parse(text, &Iso8601::PARSING)
                    .map(time::PrimitiveDateTime::assume_utc)
            })
            .map_err(|_| format!("time `{text}` is not an ISO 8601 date and time"))?;
        Ok(Fix {
            t_s: (time - start).as_seconds_f64() - offset_s,
            lat_deg: lat,
            lon_deg: lon,
            abs_alt_m: ele,
            line: self.number,
            ..Fix::default()
        })
    }
}

/// The creation time a video's container records (`ffprobe` format tag `creation_time`), which
/// GPX tracks are aligned by; `None` when the container has none.
pub fn creation_time(video: &Path) -> Result<Option<OffsetDateTime>> {
    let out = std::process::Command::new("ffprobe")
        .args(["-v", "error", "-show_entries", "format_tags=creation_time"])
        .args(["-of", "default=noprint_wrappers=1:nokey=1"])
        .arg(video)
        .output()
        .map_err(|e| Error::input(video, format!("cannot run ffprobe: {e}")))?;
    if !out.status.success() {
        return Err(Error::input(video, "ffprobe cannot read the container"));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    Ok(text
        .lines()
        .find_map(|l| OffsetDateTime::parse(l.trim(), &Rfc3339).ok()))
}

/// The EXIF GPS position of one image (and its 35 mm focal length), `None` when it has none;
/// an unreadable EXIF block is an error naming the image.
pub fn exif_fix(image: &Path) -> Result<Option<Fix>> {
    use exif::{In, Tag, Value};
    let file = std::fs::File::open(image).map_err(|e| Error::io(image, e))?;
    let exif = match exif::Reader::new().read_from_container(&mut std::io::BufReader::new(file)) {
        Ok(e) => e,
        Err(exif::Error::NotFound(_)) => return Ok(None),
        Err(e) => return Err(Error::input(image, format!("unreadable EXIF: {e}"))),
    };
    let field = |t: Tag| exif.get_field(t, In::PRIMARY).map(|f| &f.value);
    let degrees = |t: Tag, reference: Tag, negative: u8| -> Option<f64> {
        let Some(Value::Rational(v)) = field(t) else {
            return None;
        };
        let d = v
            .iter()
            .zip([1.0, 60.0, 3600.0])
            .map(|(r, s)| r.to_f64() / s)
            .sum::<f64>();
        let flip = matches!(field(reference), Some(Value::Ascii(a))
            if a.first().and_then(|s| s.first()).is_some_and(|c| c.eq_ignore_ascii_case(&negative)));
        Some(if flip { -d } else { d })
    };
    let (Some(lat), Some(lon)) = (
        degrees(Tag::GPSLatitude, Tag::GPSLatitudeRef, b'S'),
        degrees(Tag::GPSLongitude, Tag::GPSLongitudeRef, b'W'),
    ) else {
        return Ok(None);
    };
    let altitude = match field(Tag::GPSAltitude) {
        Some(Value::Rational(v)) => v.first().map(|r| r.to_f64()),
        _ => None,
    };
    let below = matches!(field(Tag::GPSAltitudeRef), Some(Value::Byte(b)) if b.first() == Some(&1));
    let focal = field(Tag::FocalLengthIn35mmFilm)
        .and_then(|v| v.get_uint(0))
        .map(f64::from)
        .filter(|f| *f > 0.0);
    Ok(Some(Fix {
        lat_deg: lat,
        lon_deg: lon,
        abs_alt_m: altitude.map(|a| if below { -a } else { a }),
        focal_35mm: focal,
        ..Fix::default()
    }))
}

/// A camera of the table [`CAMERAS`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Its name.
    pub name: &'static str,
    /// How its files name it: the EXIF `Model` code of its photos (first; geotagged exports carry
    /// it) and the product name (matched without case, spaces or dashes).
    pub names: &'static [&'static str],
    /// 35 mm equivalent focal length of its main camera, millimetres.
    pub focal_35mm: f64,
}

/// Common DJI cameras and their 35 mm equivalent focal lengths, as DJI's specification pages
/// state them (with the diagonal fields of view they give: Mini 2 83°, Mini 3 Pro and Mini 4 Pro
/// 82.1°, Air 2 84°, Air 2S 88°, Mavic 3 84°, Mavic Pro 78.8°, Phantom 4 Pro 84°, Phantom 4 94°).
pub const CAMERAS: &[Camera] = &[
    camera("DJI Mini 2", &["FC7303", "Mini 2"], 24.0),
    camera("DJI Mini 3 Pro", &["FC3582", "Mini 3 Pro"], 24.0),
    camera("DJI Mini 4 Pro", &["FC8482", "Mini 4 Pro"], 24.0),
    camera("DJI Mavic Air 2", &["FC3170", "Mavic Air 2", "Air 2"], 24.0),
    camera("DJI Air 2S", &["FC3411", "Air 2S"], 22.0),
    camera("DJI Mavic 3", &["L2D-20c", "Mavic 3"], 24.0),
    camera("DJI Mavic Pro", &["FC220", "Mavic Pro"], 26.0),
    camera("DJI Phantom 4 Pro", &["FC6310", "Phantom 4 Pro"], 24.0),
    camera("DJI Phantom 4", &["FC330", "Phantom 4"], 20.0),
];

const fn camera(name: &'static str, names: &'static [&'static str], focal_35mm: f64) -> Camera {
    Camera {
        name,
        names,
        focal_35mm,
    }
}

/// The camera of [`CAMERAS`] that `text` (an EXIF model, a container tag) names: the one whose
/// longest name it contains, compared without case, spaces or dashes.
pub fn known_camera(text: &str) -> Option<&'static Camera> {
    let squash = |s: &str| -> String {
        s.chars()
            .filter(|c| c.is_ascii_alphanumeric())
            .map(|c| c.to_ascii_lowercase())
            .collect()
    };
    let text = squash(text);
    CAMERAS
        .iter()
        .flat_map(|c| c.names.iter().map(move |n| (c, squash(n))))
        .filter(|(_, n)| text.contains(n.as_str()))
        .max_by_key(|(_, n)| n.len())
        .map(|(c, _)| c)
}

/// The camera of [`CAMERAS`] called `name` (as a project records it).
pub fn camera_named(name: &str) -> Option<&'static Camera> {
    CAMERAS.iter().find(|c| c.name == name)
}

/// The camera a video's container tags or an image's EXIF `Model` name, when it is one of
/// [`CAMERAS`].
pub fn camera_of(input: &Path, image: bool) -> Option<&'static Camera> {
    if image {
        let file = std::fs::File::open(input).ok()?;
        let exif = exif::Reader::new()
            .read_from_container(&mut std::io::BufReader::new(file))
            .ok()?;
        let model = exif.get_field(exif::Tag::Model, exif::In::PRIMARY)?;
        return known_camera(&model.display_value().to_string());
    }
    let out = std::process::Command::new("ffprobe")
        .args(["-v", "error", "-show_entries", "format_tags"])
        .args(["-of", "default=noprint_wrappers=1"])
        .arg(input)
        .output()
        .ok()?;
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_once('=').map(|(_, v)| v))
        .find_map(known_camera)
}

/// `HH:MM:SS,mmm` (or with a dot) in seconds.
fn srt_time(s: &str) -> Option<f64> {
    let s = s.trim().replace(',', ".");
    let mut parts = s.split(':');
    let (h, m, sec) = (parts.next()?, parts.next()?, parts.next()?);
    if parts.next().is_some() {
        return None;
    }
    let v = h.parse::<f64>().ok()? * 3600.0
        + m.parse::<f64>().ok()? * 60.0
        + sec.parse::<f64>().ok()?;
    v.is_finite().then_some(v)
}

/// The fix in one entry's text, or why there is none: no position, a position that is not a
/// latitude and longitude, or a field read whose value is not a whole, finite number.
fn fix_of(body: &str, t_s: f64, line: usize) -> std::result::Result<Fix, String> {
    let fields = fields(body);
    let field = |keys: &[&str], parse: fn(&str) -> Option<f64>| {
        let found = keys
            .iter()
            .find_map(|k| fields.iter().find(|(name, _)| name == k));
        match found {
            None => Ok(None),
            Some((key, v)) => parse(v)
                .map(Some)
                .ok_or_else(|| format!("{key}: `{v}` is not a finite number")),
        }
    };
    let num = |keys: &[&str]| field(keys, number);
    let (lat, lon, gps_alt) = match (num(&["latitude"])?, num(&["longitude", "longtitude"])?) {
        (Some(lat), Some(lon)) => (lat, lon, None),
        _ => match gps_triple(body) {
            Some(found) => found.map(|(lon, lat, alt)| (lat, lon, alt))?,
            None => return Err("no position".into()),
        },
    };
    position_ok(lat, lon)?;
    let fnum = num(&["fnum"])?.map(|f| if f > 30.0 { f / 100.0 } else { f });
    let focal = num(&["focal_len"])?.map(|f| if f > 200.0 { f / 10.0 } else { f });
    let shutter = field(&["shutter", "ss"], |v| {
        let s = match v.trim().split_once('/') {
            Some((a, b)) => number(a)? / number(b)?,
            // The older family writes the denominator alone (`SS 320`, `Shutter:60`).
            None => 1.0 / number(v)?,
        };
        s.is_finite().then_some(s)
    })?;
    Ok(Fix {
        t_s,
        lat_deg: lat,
        lon_deg: lon,
        rel_alt_m: num(&["rel_alt", "barometer", "h"])?,
        abs_alt_m: num(&["abs_alt", "altitude"])?.or(gps_alt),
        focal_35mm: focal.filter(|f| *f > 0.0),
        gimbal_pitch_deg: num(&["gb_pitch", "gimbal_pitch", "pitch"])?,
        gimbal_yaw_deg: num(&["gb_yaw", "gimbal_yaw", "yaw"])?,
        iso: num(&["iso"])?,
        shutter_s: shutter.filter(|s| *s > 0.0),
        fnum: fnum.filter(|f| *f > 0.0),
        line,
    })
}

/// `key: value` and `key value` pairs of an entry, keys lower-cased: the bracketed family's
/// `[a: 1 b: 2]` and the older family's comma-separated `ISO:100` / `SS 320` / `H 40.5m`.
fn fields(body: &str) -> Vec<(String, String)> {
    let cleaned = body.replace(['[', ']', ',', '<', '>'], " ");
    let words: Vec<&str> = cleaned.split_whitespace().collect();
    let mut out = Vec::new();
    let mut k = 0;
    while k < words.len() {
        let (w, after) = (words[k], |j: usize| words.get(k + j).copied());
        // The key and value at word `k`, and how many words they take.
        let pair = if let Some(f) = w.strip_prefix("F/").filter(|f| starts_numeric(f)) {
            // The older family's `F/2.8`.
            Some(("fnum", f, 1))
        } else if let Some((key, value)) = w.split_once(':') {
            // `key: value`, or `key:value` in one word.
            match value {
                "" => after(1).map(|v| (key, v, 2)),
                _ => Some((key, value, 1)),
            }
        } else if after(1) == Some(":") {
            // `key : value`.
            after(2).map(|v| (w, v, 3))
        } else {
            // The older family's `SS 320`, `H 40.50m`, `ISO 100`.
            (after(1).filter(|v| starts_numeric(v))).map(|v| (w, v, 2))
        };
        match pair {
            Some((key, value, used)) => {
                out.push((key.to_lowercase(), value.to_string()));
                k += used;
            }
            None => k += 1,
        }
    }
    out
}

/// Whether `v` starts like a number (`40.5m`, `-3`, `F2.8`, `1/60`): what makes the older
/// family's `KEY v` a pair.
fn starts_numeric(v: &str) -> bool {
    let v = v.trim_start_matches(['F', 'f', '/']);
    v.trim_start_matches(['-', '+', '.'])
        .starts_with(|c: char| c.is_ascii_digit())
}

/// A number written whole (exponent notation included), with an optional unit after it or `F`
/// before it: `40.50m`, `F2.8`, `2.80m/s`, `4.7e1`; None when the rest is not a number (`1e`,
/// `4O.5`, `nan`) or it is not finite (`1e999`).
fn number(v: &str) -> Option<f64> {
    let v = v.trim().trim_start_matches(['F', 'f', '/']);
    let unitless = v.trim_end_matches(|c: char| c.is_alphabetic() || matches!(c, '/' | '°' | '%'));
    // `1e` is no number with the unit `e`.
    if v[unitless.len()..].starts_with(['e', 'E']) {
        return None;
    }
    unitless.parse::<f64>().ok().filter(|x| x.is_finite())
}

/// Refuses what is not a latitude and longitude, and 0, 0 (a receiver without a fix yet).
fn position_ok(lat: f64, lon: f64) -> std::result::Result<(), String> {
    if !(lat.abs() <= 90.0 && lon.abs() <= 180.0) {
        return Err(format!(
            "position {lat:?}, {lon:?} is not a latitude and longitude"
        ));
    }
    if lat == 0.0 && lon == 0.0 {
        return Err("position 0, 0 (no GPS fix yet)".into());
    }
    Ok(())
}

/// Longitude and latitude (degrees), and an altitude when given (metres).
type LonLatAlt = (f64, f64, Option<f64>);

/// The older family's `GPS(lon,lat,alt)` / `GPS (lon, lat, alt)`: longitude, latitude and the
/// third value when present (None: no `GPS(...)`; an error when its values are not numbers).
fn gps_triple(body: &str) -> Option<std::result::Result<LonLatAlt, String>> {
    let at = body.find("GPS")?;
    let rest = body[at + 3..].trim_start().strip_prefix('(')?;
    let inner = &rest[..rest.find(')')?];
    let v: Option<Vec<f64>> = inner.split(',').map(number).collect();
    Some(match v.as_deref() {
        Some([lon, lat]) => Ok((*lon, *lat, None)),
        Some([lon, lat, alt, ..]) => Ok((*lon, *lat, Some(*alt))),
        _ => Err(format!(
            "GPS({inner}) is not longitude, latitude[, altitude]"
        )),
    })
}

/// Radii of curvature of the WGS84 ellipsoid at latitude `lat_deg`: (meridian, prime vertical),
/// metres.
pub fn wgs84_radii(lat_deg: f64) -> (f64, f64) {
    const A: f64 = 6_378_137.0;
    const E2: f64 = 6.694_379_990_14e-3;
    let w = 1.0 - E2 * lat_deg.to_radians().sin().powi(2);
    (A * (1.0 - E2) / w.powf(1.5), A / w.sqrt())
}

/// Horizontal distance between two fixes, metres: on the tangent plane with the ellipsoid's
/// radii at their mean latitude, within millimetres over the hundreds of metres between
/// consecutive fixes or keyframes (beyond a few kilometres it only serves to see a jump).
pub fn distance_m(a: &Fix, b: &Fix) -> f64 {
    let (east, north) = east_north_m((a.lat_deg, a.lon_deg), (b.lat_deg, b.lon_deg));
    north.hypot(east)
}

/// East and north metres from `a` to `b` (latitude, longitude in degrees), on the tangent plane
/// with the ellipsoid's radii at their mean latitude (see [`distance_m`]); east the short way
/// round (across the antimeridian when that is shorter).
pub fn east_north_m(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    let lat = 0.5 * (a.0 + b.0);
    let (meridian, prime) = wgs84_radii(lat);
    let north = (b.0 - a.0).to_radians() * meridian;
    let east = short_deg(b.1 - a.1).to_radians() * prime * lat.to_radians().cos();
    (east, north)
}

/// An angle difference in degrees the short way round, in -180..180.
pub(crate) fn short_deg(d: f64) -> f64 {
    if d.abs() <= 180.0 {
        d
    } else {
        (d + 540.0).rem_euclid(360.0) - 180.0
    }
}

/// The version of [`at`]'s placement of frames in the track, recorded with cached positions:
/// 1 takes the end's fix within [`SPAN_SLACK_S`] of the span (0: none outside it).
pub const PLACEMENT_RULE: u32 = 1;

/// How far outside the track's time span a frame may lie and still take the end's fix: SRT
/// times are whole milliseconds, and a frame's timestamp (stream time base, or index / rate in
/// floating point) can miss the entry it sits on by a rounding (107 / 5 fps is 21.400000000000002,
/// after the 21.400 s of the last entry).
const SPAN_SLACK_S: f64 = 5e-4;

/// The fix at time `t_s`, linear between the two entries around it (positions, altitudes and
/// pitch; the camera facts of the earlier one); `None` outside the track's time span (widened by
/// [`SPAN_SLACK_S`] at both ends, where the end's fix is taken).
pub fn at(fixes: &[Fix], t_s: f64) -> Option<Fix> {
    let (first, last) = (fixes.first()?, fixes.last()?);
    if t_s < first.t_s - SPAN_SLACK_S || t_s > last.t_s + SPAN_SLACK_S {
        return None;
    }
    if t_s < first.t_s {
        return Some(Fix {
            t_s,
            ..first.clone()
        });
    }
    let k = fixes.partition_point(|f| f.t_s <= t_s);
    let a = &fixes[k.saturating_sub(1)];
    let Some(b) = fixes.get(k) else {
        return Some(Fix { t_s, ..a.clone() });
    };
    let u = if b.t_s > a.t_s {
        (t_s - a.t_s) / (b.t_s - a.t_s)
    } else {
        0.0
    };
    let mix = |x: f64, y: f64| x + (y - x) * u;
    let mix_opt = |x: Option<f64>, y: Option<f64>| match (x, y) {
        (Some(x), Some(y)) => Some(mix(x, y)),
        (x, y) => x.or(y),
    };
    Some(Fix {
        t_s,
        lat_deg: mix(a.lat_deg, b.lat_deg),
        // The short way round, back into -180..180: across the antimeridian, not the globe.
        lon_deg: {
            let lon = mix(a.lon_deg, a.lon_deg + short_deg(b.lon_deg - a.lon_deg));
            lon - 360.0 * (lon / 360.0).round()
        },
        rel_alt_m: mix_opt(a.rel_alt_m, b.rel_alt_m),
        abs_alt_m: mix_opt(a.abs_alt_m, b.abs_alt_m),
        gimbal_pitch_deg: mix_opt(a.gimbal_pitch_deg, b.gimbal_pitch_deg),
        gimbal_yaw_deg: match (a.gimbal_yaw_deg, b.gimbal_yaw_deg) {
            // The short way round: 350° to 10° passes north.
            (Some(x), Some(y)) => Some(mix(x, x + short_deg(y - x))),
            (x, y) => x.or(y),
        },
        ..a.clone()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Track {
        parse_dji_srt(Path::new("DJI_0001.SRT"), text)
    }

    /// Asserts that the track's warnings are `want`, each between `prefix` and `suffix`.
    fn assert_warnings(t: &Track, prefix: &str, want: &[&str], suffix: &str) {
        let want: Vec<String> = want
            .iter()
            .map(|w| format!("{prefix}{w}{suffix}"))
            .collect();
        assert_eq!(t.warnings, want);
    }

    #[test]
    fn bracketed_family_with_crlf_bom_and_odd_spacing() {
        let text = "\u{feff}1\r\n00:00:00,000 --> 00:00:00,033\r\n<font size=\"28\">FrameCnt: 1, DiffTime: 33ms\r\n2024-05-01 10:00:00.000\r\n[iso : 110] [shutter : 1/200.0] [fnum : 170] [ev : 0] [focal_len : 24.00] [latitude: 47.376887] [longitude: 8.541694] [rel_alt: 40.500 abs_alt: 512.250] [gb_yaw: 10.0 gb_pitch: -90.0 gb_roll: 0.0] </font>\r\n\r\n2\r\n00:00:00,033 --> 00:00:00,066\r\n<font size=\"28\">FrameCnt: 2, DiffTime: 33ms\r\n[fnum: 2.8] [focal_len: 240] [latitude : 47.376897] [longtitude : 8.541704] [altitude: 515.0]</font>\r\n";
        let t = parse(text);
        assert!(t.warnings.is_empty(), "{:?}", t.warnings);
        assert_eq!(t.fixes.len(), 2);
        let f = &t.fixes[0];
        assert_eq!((f.t_s, f.lat_deg, f.lon_deg), (0.0, 47.376887, 8.541694));
        assert_eq!((f.rel_alt_m, f.abs_alt_m), (Some(40.5), Some(512.25)));
        assert_eq!(
            (f.iso, f.fnum, f.focal_35mm),
            (Some(110.0), Some(1.7), Some(24.0))
        );
        assert_eq!(
            (f.shutter_s, f.gimbal_pitch_deg, f.line),
            (Some(0.005), Some(-90.0), 2)
        );
        let g = &t.fixes[1];
        assert_eq!(
            (g.t_s, g.lon_deg, g.abs_alt_m),
            (0.033, 8.541704, Some(515.0))
        );
        assert_eq!(
            (g.fnum, g.focal_35mm, g.rel_alt_m),
            (Some(2.8), Some(24.0), None)
        );
    }

    #[test]
    fn older_families() {
        let text = "1\n00:00:01,000 --> 00:00:02,000\nHOME(8.5400,47.3700) 2017.08.05 14:12:54\nGPS(8.5417,47.3769,16) BAROMETER:40.5\nISO:100 Shutter:60 EV:0 Fnum:F2.2\n\n2\n00:00:02,000 --> 00:00:03,000\nF/2.8, SS 320, ISO 200, EV 0, GPS (8.5418, 47.3770, 19), D 24.41m, H 41.30m, H.S 2.80m/s, V.S 0.00m/s\n";
        let t = parse(text);
        assert!(t.warnings.is_empty(), "{:?}", t.warnings);
        let (a, b) = (&t.fixes[0], &t.fixes[1]);
        assert_eq!((a.t_s, a.lat_deg, a.lon_deg), (1.0, 47.3769, 8.5417));
        assert_eq!(
            (a.rel_alt_m, a.abs_alt_m, a.iso),
            (Some(40.5), Some(16.0), Some(100.0))
        );
        assert_eq!((a.fnum, a.shutter_s), (Some(2.2), Some(1.0 / 60.0)));
        assert_eq!(
            (b.lat_deg, b.lon_deg, b.rel_alt_m),
            (47.3770, 8.5418, Some(41.3))
        );
        assert_eq!(
            (b.fnum, b.shutter_s, b.iso),
            (Some(2.8), Some(1.0 / 320.0), Some(200.0))
        );
    }

    #[test]
    fn bad_entries_are_warned_with_file_and_line() {
        let text = "1\n00:00:00,000 --> 00:00:01,000\n[iso: 100] [rel_alt: 3.0 abs_alt: 9.0]\n\n2\n00:00:01,000 --> 00:00:02,000\n[latitude: 0.0] [longitude: 0.0]\n\n3\n00:00:02,000 --> 00:00:03,000\n[latitude: 47.0] [longitude: 8.0]\n\n4\n00:00:03,000 --> 00:00:04,000\n[latitude: 47.1] [longitude: 8.0]\n";
        let t = parse(text);
        assert_eq!(t.fixes.len(), 2);
        assert!(
            t.warnings[0].starts_with("DJI_0001.SRT:line 2: no position"),
            "{:?}",
            t.warnings
        );
        assert!(
            t.warnings[1].starts_with("DJI_0001.SRT:line 6: position 0, 0"),
            "{:?}",
            t.warnings
        );
        // 0.1 degree of latitude in one second.
        assert!(
            t.warnings[2].starts_with("DJI_0001.SRT:line 14: the position jumps 11"),
            "{:?}",
            t.warnings
        );
        assert_eq!(t.warnings.len(), 3);
    }

    /// Numbers are read whole: exponent notation is a number (and 1e308 then no latitude), a
    /// token that is not wholly a number (`1e`, `4O.5`), NaN and infinities refuse the entry.
    #[test]
    fn numbers_are_read_whole_and_bad_ones_refuse_the_entry() {
        let bodies = [
            "[latitude: 1e308] [longitude: 8.0]",
            "[latitude: 4.7e1] [longitude: 8.0e0] [rel_alt: 3E1 abs_alt: 5.3e2]",
            "[latitude: 47.0] [longitude: 1e]",
            "[latitude: nan] [longitude: 8.0]",
            "[latitude: 47.0] [longitude: -inf]",
            "[latitude: 91.0] [longitude: 8.0]",
            "[latitude: 47.0] [longitude: -180.5]",
            "[latitude: 47.0] [longitude: 8.0] [rel_alt: 1e999 abs_alt: 500.0]",
            "[latitude: 47.0] [longitude: 8.0] [focal_len: 4O.5]",
            "GPS(8.0,1e308,16) BAROMETER:30.0",
            "GPS(8.0,4O.5,16) BAROMETER:30.0",
            "GPS(8.0,47.0,16) BAROMETER:3e1",
        ];
        let text: String = (bodies.iter().enumerate())
            .map(|(i, b)| {
                format!(
                    "{}\n00:00:{i:02},000 --> 00:00:{:02},000\n{b}\n\n",
                    i + 1,
                    i + 1
                )
            })
            .collect();
        let t = parse(&text);
        // Each entry takes four lines: its time line is line 4 i + 2.
        let lines: Vec<usize> = t.fixes.iter().map(|f| f.line).collect();
        assert_eq!(lines, [6, 46], "{:?}", t.warnings);
        let (a, b) = (&t.fixes[0], &t.fixes[1]);
        assert_eq!((a.lat_deg, a.lon_deg, a.rel_alt_m), (47.0, 8.0, Some(30.0)));
        assert_eq!(a.abs_alt_m, Some(530.0));
        assert_eq!((b.lat_deg, b.lon_deg, b.rel_alt_m), (47.0, 8.0, Some(30.0)));
        let want = [
            "line 2: position 1e308, 8.0 is not a latitude and longitude",
            "line 10: longitude: `1e` is not a finite number",
            "line 14: latitude: `nan` is not a finite number",
            "line 18: longitude: `-inf` is not a finite number",
            "line 22: position 91.0, 8.0 is not a latitude and longitude",
            "line 26: position 47.0, -180.5 is not a latitude and longitude",
            "line 30: rel_alt: `1e999` is not a finite number",
            "line 34: focal_len: `4O.5` is not a finite number",
            "line 38: position 1e308, 8.0 is not a latitude and longitude",
            "line 42: GPS(8.0,4O.5,16) is not longitude, latitude[, altitude]",
        ];
        assert_warnings(&t, "DJI_0001.SRT:", &want, " (entry skipped)");
    }

    #[test]
    fn a_file_without_positions_is_an_error_naming_it() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.SRT");
        std::fs::write(&p, "1\n00:00:00,000 --> 00:00:01,000\nhello\n").unwrap();
        let e = read_dji_srt(&p).unwrap_err().to_string();
        assert!(
            e.contains("x.SRT") && e.contains("no telemetry entry"),
            "{e}"
        );
        let video = d.path().join("x.MP4");
        assert_eq!(sidecar_of(&video), Some(p));
        assert_eq!(sidecar_of(&d.path().join("y.MP4")), None);
    }

    #[test]
    fn gpx_points_are_timed_from_the_video_start_plus_the_offset() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("track.gpx");
        std::fs::write(
            &p,
            r#"<?xml version="1.0" encoding="UTF-8"?>
<gpx version="1.1" creator="test" xmlns="http://www.topografix.com/GPX/1/1">
<trk><trkseg>
<trkpt lat="47.0" lon="8.0"><ele>500.5</ele><time>2024-05-01T10:00:00Z</time></trkpt>
<trkpt lat="47.0001" lon="8.0"><time>2024-05-01T10:00:02Z</time></trkpt>
<trkpt lat="47.0002" lon="8.0"></trkpt>
</trkseg></trk></gpx>"#,
        )
        .unwrap();
        let start = OffsetDateTime::parse("2024-05-01T09:59:59Z", &Rfc3339).unwrap();
        let t = read_gpx(&p, start, 0.5).unwrap();
        assert_eq!(t.fixes.len(), 2);
        assert_eq!((t.fixes[0].t_s, t.fixes[0].abs_alt_m), (0.5, Some(500.5)));
        assert_eq!(
            (t.fixes[1].t_s, t.fixes[1].lat_deg, t.fixes[1].line),
            (2.5, 47.0001, 2)
        );
        assert!(
            t.warnings[0].ends_with("track.gpx:point 3: no time (skipped)"),
            "{:?}",
            t.warnings
        );
        std::fs::write(&p, "<gpx").unwrap();
        let e = read_gpx(&p, start, 0.0).unwrap_err().to_string();
        assert!(
            e.contains("track.gpx") && e.contains("not a readable GPX"),
            "{e}"
        );
    }

    /// A bad GPX point is skipped with a warning naming it, the others are kept; a file cut
    /// short keeps the points before the cut; a file with no usable point is an error.
    #[test]
    fn bad_gpx_points_are_skipped_with_a_warning() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("track.gpx");
        let pt =
            |lat: &str, inner: &str| format!("<trkpt lat=\"{lat}\" lon=\"8.0\">{inner}</trkpt>\n");
        let time = |s: u32| format!("<time>2024-05-01T10:00:{s:02}Z</time>");
        let points = [
            pt("47.0", &format!("<ele>500</ele>{}", time(0))),
            pt("abc", &time(1)),
            pt("95", &time(2)),
            pt("47.0", "<time>yesterday</time>"),
            pt("47.0", &format!("<ele>high</ele>{}", time(4))),
            pt("NaN", &time(5)),
            pt(
                "47.00001",
                &format!("<extensions><time>x</time></extensions>{}", time(6)),
            ),
        ]
        .concat();
        let head = "<?xml version=\"1.0\"?>\n<gpx version=\"1.1\" creator=\"t\" xmlns=\"http://www.topografix.com/GPX/1/1\"><trk><trkseg>\n";
        std::fs::write(&p, format!("{head}{points}</trkseg></trk></gpx>\n")).unwrap();
        let start = OffsetDateTime::parse("2024-05-01T10:00:00Z", &Rfc3339).unwrap();
        let t = read_gpx(&p, start, 0.0).unwrap();
        let kept: Vec<(usize, f64, f64)> = (t.fixes.iter())
            .map(|f| (f.line, f.t_s, f.lat_deg))
            .collect();
        assert_eq!(
            kept,
            [(1, 0.0, 47.0), (7, 6.0, 47.00001)],
            "{:?}",
            t.warnings
        );
        let name = p.display();
        let want = [
            "point 2: lat `abc` is not a finite number",
            "point 3: position 95.0, 8.0 is not a latitude and longitude",
            "point 4: time `yesterday` is not an ISO 8601 date and time",
            "point 5: ele `high` is not a finite number",
            "point 6: lat `NaN` is not a finite number",
        ];
        assert_warnings(&t, &format!("{name}:"), &want, " (skipped)");
        // Cut inside the third point's tag: the two before it are read (one kept), the cut warned.
        let whole = format!("{head}{points}");
        let cut = whole.find("<trkpt lat=\"95\"").unwrap() + 20;
        std::fs::write(&p, &whole[..cut]).unwrap();
        let t = read_gpx(&p, start, 0.0).unwrap();
        assert_eq!(t.fixes.len(), 1, "{:?}", t.warnings);
        let last = t.warnings.last().unwrap();
        assert!(
            last.starts_with(&format!("{name}: broken XML after point 2: "))
                && last.ends_with("(the rest skipped)"),
            "{:?}",
            t.warnings
        );
        // Only bad points: an error naming the file and the first problem.
        std::fs::write(
            &p,
            format!("{head}{}</trkseg></trk></gpx>", pt("abc", &time(1))),
        )
        .unwrap();
        let e = read_gpx(&p, start, 0.0).unwrap_err().to_string();
        assert!(
            e.contains("track.gpx")
                && e.contains("no track point with a position and a time")
                && e.contains("point 1: lat `abc`"),
            "{e}"
        );
        std::fs::write(&p, "<?xml version=\"1.0\"?><kml></kml>").unwrap();
        let e = read_gpx(&p, start, 0.0).unwrap_err().to_string();
        assert!(
            e.contains("not a readable GPX file: the root element is <kml>"),
            "{e}"
        );
    }

    #[test]
    fn exif_gps_with_south_west_and_below_sea_level() {
        use exif::{Field, In, Rational, Tag, Value};
        let field = |tag, value| Field {
            tag,
            ifd_num: In::PRIMARY,
            value,
        };
        let dms = |d, m, s| {
            Value::Rational(vec![
                Rational::from((d, 1)),
                Rational::from((m, 1)),
                Rational::from((s, 100)),
            ])
        };
        let fields = [
            field(Tag::GPSLatitudeRef, Value::Ascii(vec![b"S".to_vec()])),
            field(Tag::GPSLatitude, dms(33, 51, 3600)),
            field(Tag::GPSLongitudeRef, Value::Ascii(vec![b"W".to_vec()])),
            field(Tag::GPSLongitude, dms(70, 30, 0)),
            field(Tag::GPSAltitudeRef, Value::Byte(vec![1])),
            field(
                Tag::GPSAltitude,
                Value::Rational(vec![Rational::from((25, 2))]),
            ),
            field(Tag::FocalLengthIn35mmFilm, Value::Short(vec![24])),
        ];
        let mut w = exif::experimental::Writer::new();
        for f in &fields {
            w.push_field(f);
        }
        let mut buf = std::io::Cursor::new(Vec::new());
        w.write(&mut buf, false).unwrap();
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a.tif");
        std::fs::write(&p, buf.into_inner()).unwrap();
        let f = exif_fix(&p).unwrap().unwrap();
        assert!(
            (f.lat_deg + (33.0 + 51.0 / 60.0 + 36.0 / 3600.0)).abs() < 1e-12,
            "{}",
            f.lat_deg
        );
        assert!((f.lon_deg + 70.5).abs() < 1e-12, "{}", f.lon_deg);
        assert_eq!((f.abs_alt_m, f.focal_35mm), (Some(-12.5), Some(24.0)));
    }

    #[test]
    fn creation_time_from_the_container() {
        let d = tempfile::tempdir().unwrap();
        let make = |name: &str, extra: [&str; 4]| {
            let path = d.path().join(name);
            let ok = std::process::Command::new("ffmpeg")
                .args([
                    "-v",
                    "error",
                    "-f",
                    "lavfi",
                    "-i",
                    "testsrc=size=32x32:rate=5",
                ])
                .args(["-t", "1"])
                .args(extra)
                .arg(&path)
                .status()
                .unwrap();
            assert!(ok.success());
            path
        };
        // MP4 stores the creation time in whole seconds.
        let v = make(
            "v.mp4",
            [
                "-metadata",
                "creation_time=2024-05-01T10:00:07Z",
                "-f",
                "mp4",
            ],
        );
        let want = OffsetDateTime::parse("2024-05-01T10:00:07Z", &Rfc3339).unwrap();
        assert_eq!(creation_time(&v).unwrap(), Some(want));
        let bare = make("bare.mkv", ["-map_metadata", "-1", "-fflags", "+bitexact"]);
        assert_eq!(creation_time(&bare).unwrap(), None);
    }

    #[test]
    fn cameras_are_found_by_model_code_or_name() {
        assert_eq!(known_camera("FC3582").unwrap().name, "DJI Mini 3 Pro");
        assert_eq!(
            known_camera("dji mini-4 pro").unwrap().name,
            "DJI Mini 4 Pro"
        );
        // The longest name wins: "Phantom 4 Pro" over "Phantom 4", "Air 2S" over "Air 2".
        assert_eq!(
            known_camera("DJI Phantom 4 Pro V2").unwrap().focal_35mm,
            24.0
        );
        assert_eq!(known_camera("Phantom 4").unwrap().focal_35mm, 20.0);
        assert_eq!(known_camera("DJIAir2S").unwrap().focal_35mm, 22.0);
        assert!(known_camera("Lavf60.16.100").is_none());
    }

    #[test]
    fn interpolation_between_entries() {
        let t = parse("1\n00:00:00,000 --> 00:00:01,000\n[latitude: 47.0] [longitude: 8.0] [rel_alt: 10.0 abs_alt: 500.0]\n\n2\n00:00:01,000 --> 00:00:02,000\n[latitude: 47.001] [longitude: 8.002] [rel_alt: 20.0 abs_alt: 510.0]\n");
        let f = at(&t.fixes, 0.25).unwrap();
        assert!((f.lat_deg - 47.00025).abs() < 1e-12 && (f.lon_deg - 8.0005).abs() < 1e-12);
        assert_eq!((f.rel_alt_m, f.abs_alt_m), (Some(12.5), Some(502.5)));
        assert_eq!(at(&t.fixes, 1.0).unwrap().lat_deg, 47.001);
        assert!(at(&t.fixes, 1.5).is_none() && at(&t.fixes, -0.1).is_none());
        // A frame a rounding past either end takes that end's fix (frame 107 at 5 fps is at
        // 107 * 0.2 = 21.400000000000002 s, past an entry at 21.400); a millisecond past has none.
        let end = at(&t.fixes, 1.0 + 1e-12).unwrap();
        assert_eq!((end.lat_deg, end.t_s), (47.001, 1.0 + 1e-12));
        assert_eq!(at(&t.fixes, -1e-9).unwrap().lat_deg, 47.0);
        assert!(at(&t.fixes, 1.001).is_none() && at(&t.fixes, -0.001).is_none());
        // 0.001 degree of latitude at 47.0005° N: the WGS84 meridian radius there is
        // 6 369 620.58 m (a (1 - e²) / (1 - e² sin² φ)^1.5), so the arc is 111.1709 m.
        let d = distance_m(
            &t.fixes[0],
            &Fix {
                lon_deg: 8.0,
                ..t.fixes[1].clone()
            },
        );
        assert!((d - 111.1709).abs() < 1e-4, "{d}");
    }

    #[test]
    fn across_the_antimeridian_positions_and_distances_take_the_short_way() {
        let fix = |t_s: f64, lon_deg: f64| Fix {
            t_s,
            lat_deg: 0.0,
            lon_deg,
            ..Fix::default()
        };
        let fixes = [fix(0.0, 179.9999), fix(1.0, -179.9997)];
        let lon = |t: f64| at(&fixes, t).unwrap().lon_deg;
        assert!((lon(0.125) - 179.99995).abs() < 1e-9, "{}", lon(0.125));
        assert!((lon(0.25).abs() - 180.0).abs() < 1e-9, "{}", lon(0.25));
        assert!((lon(0.75) + 179.9998).abs() < 1e-9, "{}", lon(0.75));
        // 0.0004° of longitude on the equator: 44.53 m, not the globe's circumference.
        let d = distance_m(&fixes[0], &fixes[1]);
        assert!((d - 44.528).abs() < 0.01, "{d}");
    }
}
