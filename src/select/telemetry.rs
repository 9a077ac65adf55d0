//! The per-frame positions of a `select`: from `--telemetry FILE` (a DJI SRT or a GPX track,
//! told apart by extension, else by content), else the DJI SRT sidecar beside a video, else the
//! EXIF GPS tags of an image folder's images. Each frame's position is the telemetry
//! interpolated at the frame's timestamp (plus `--telemetry-offset`). Everything wrong with the
//! telemetry is a warning naming the file and line (the first few printed and kept in the
//! project, the rest counted); positions cached in the project being replaced are reused when
//! they came from the same, unchanged file with the same offset.

use super::SelectSettings;
use crate::error::{Error, Result};
use crate::fsutil;
use crate::project::{TelemetryCache, TelemetrySource};
use crate::source::telemetry::{self, Position, TelemetryKind, Track};
use crate::source::{self, SourceKind};
use std::path::{Path, PathBuf};

/// Consecutive frames further apart than this are reported (metres).
const FRAME_JUMP_M: f64 = 1000.0;

/// Telemetry warnings printed and kept in the project; the rest are counted (and printed at
/// debug level when read).
const WARNINGS_SHOWN: usize = 5;

/// Where this run takes positions from (path as given), or None when the input has no
/// telemetry.
fn wanted(s: &SelectSettings, kind: SourceKind) -> Result<Option<(PathBuf, TelemetryKind)>> {
    if let Some(file) = &s.telemetry {
        if !file.is_file() {
            let why = if file.exists() {
                "telemetry file is not a regular file (a folder, device, FIFO or socket)"
            } else {
                "telemetry file not found"
            };
            return Err(Error::input(file, why));
        }
        return Ok(Some((file.clone(), kind_of_file(file)?)));
    }
    Ok(match kind {
        SourceKind::Video => file(s, kind).map(|p| (p, TelemetryKind::DjiSrt)),
        SourceKind::Images | SourceKind::Image => Some((s.input.clone(), TelemetryKind::Exif)),
    })
}

/// The telemetry file this run reads besides the input (path as given): `--telemetry FILE`,
/// else the DJI SRT sidecar beside a video (images carry theirs in EXIF).
pub(super) fn file(s: &SelectSettings, kind: SourceKind) -> Option<PathBuf> {
    match (&s.telemetry, kind) {
        (Some(f), _) => Some(f.clone()),
        (None, SourceKind::Video) => telemetry::sidecar_of(&s.input),
        (None, _) => None,
    }
}

/// `.gpx` and `.srt` by extension (any case); otherwise a file starting like XML is GPX and
/// anything else is read as a DJI SRT.
fn kind_of_file(file: &Path) -> Result<TelemetryKind> {
    let ext = file
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_lowercase);
    match ext.as_deref() {
        Some("gpx") => return Ok(TelemetryKind::Gpx),
        Some("srt") => return Ok(TelemetryKind::DjiSrt),
        _ => {}
    }
    let io = |e| Error::io(file, e);
    let mut bytes = Vec::with_capacity(512);
    std::io::Read::read_to_end(
        &mut std::io::Read::take(std::fs::File::open(file).map_err(io)?, 512),
        &mut bytes,
    )
    .map_err(io)?;
    let head = String::from_utf8_lossy(&bytes).to_string();
    let head = head.trim_start_matches('\u{feff}').trim_start();
    Ok(if head.starts_with("<?xml") || head.starts_with("<gpx") {
        TelemetryKind::Gpx
    } else {
        TelemetryKind::DjiSrt
    })
}

/// The positions of every frame (`frames` of them, at `timestamps_s`), reusing `cached` when it
/// came from the same source; None when the input has no telemetry or none of it covers a
/// frame (warned).
pub(crate) fn positions(
    s: &SelectSettings,
    kind: SourceKind,
    frames: usize,
    timestamps_s: Option<&[f64]>,
    cached: Option<TelemetryCache>,
) -> Result<Option<TelemetryCache>> {
    let Some((file, tkind)) = wanted(s, kind)? else {
        if s.telemetry_offset_s != 0.0 {
            log::warn!("--telemetry-offset is ignored: the input has no telemetry");
        }
        return Ok(None);
    };
    let source = source_of(s, &file, tkind)?;
    if let Some(c) = cached.filter(|c| c.source == source && c.positions.len() == frames) {
        log::info!(
            "reusing the positions from {} cached in {} (unchanged)",
            file.display(),
            s.output.display()
        );
        let (warnings, more_warnings) = summarised(&file, c.warnings, c.more_warnings);
        return Ok(Some(TelemetryCache {
            warnings,
            more_warnings,
            ..c
        }));
    }
    if s.telemetry.is_none() && tkind == TelemetryKind::DjiSrt {
        log::info!(
            "telemetry: {} found beside the video (give --telemetry FILE for another)",
            file.display()
        );
    }
    let (positions, warnings) = match tkind {
        TelemetryKind::Exif => exif_positions(&s.input, kind)?,
        _ => {
            let track = match read_track(s, &file, tkind) {
                Ok(t) => t,
                // An explicit file that cannot be used is an error; a sidecar found is a warning.
                Err(e) if s.telemetry.is_none() => {
                    log::warn!("{e} (no positions)");
                    return Ok(None);
                }
                Err(e) => return Err(e),
            };
            timed_positions(&track, &file, timestamps_s, frames)
        }
    };
    let (warnings, more_warnings) = summarised(&file, warnings, 0);
    if positions.len() != frames {
        log::warn!(
            "{}: {} positions for the input's {frames} frames (no positions)",
            file.display(),
            positions.len()
        );
        return Ok(None);
    }
    if positions.iter().all(Option::is_none) {
        if tkind != TelemetryKind::Exif {
            log::warn!("{}: no frame has a position", file.display());
        }
        return Ok(None);
    }
    Ok(Some(TelemetryCache {
        source,
        warnings,
        more_warnings,
        positions,
        camera: camera_of(&s.input, kind)?,
    }))
}

/// Prints the first [`WARNINGS_SHOWN`] of `warnings` (the rest at debug level) and a count of
/// the rest and of `more` (not kept), and returns what a project keeps: those printed and the
/// count.
fn summarised(file: &Path, mut warnings: Vec<String>, more: usize) -> (Vec<String>, usize) {
    let rest = warnings.split_off(warnings.len().min(WARNINGS_SHOWN));
    for w in &warnings {
        log::warn!("{w}");
    }
    for w in &rest {
        log::debug!("{w}");
    }
    let more = more + rest.len();
    if more > 0 {
        let how = match rest.is_empty() {
            true => "",
            false => " (RUST_LOG=keyframer=debug prints them)",
        };
        log::warn!("{}: {more} more telemetry warnings{how}", file.display());
    }
    (warnings, more)
}

/// Where the positions come from, as the project records it: `file` relative to the project's
/// folder, its kind, the offset and (except for EXIF) the file's fingerprint.
fn source_of(s: &SelectSettings, file: &Path, kind: TelemetryKind) -> Result<TelemetrySource> {
    Ok(TelemetrySource {
        path: s.relative(file),
        kind,
        offset_s: s.telemetry_offset_s,
        fingerprint: match kind {
            TelemetryKind::Exif => None,
            _ => Some(fsutil::fingerprint_file(file)?),
        },
        rule: telemetry::PLACEMENT_RULE,
    })
}

/// The known camera ([`telemetry::CAMERAS`]) the video's container tags or the (first) image's
/// EXIF name.
fn camera_of(input: &Path, kind: SourceKind) -> Result<Option<String>> {
    let camera = match kind {
        SourceKind::Video => telemetry::camera_of(input, false),
        SourceKind::Image => telemetry::camera_of(input, true),
        SourceKind::Images => (source::folder_images(input)?.first())
            .and_then(|first| telemetry::camera_of(first, true)),
    };
    Ok(camera.map(|c| c.name.to_string()))
}

/// Reads a DJI SRT (its times shifted by the offset) or a GPX track (timed from the video's
/// creation time plus the offset).
fn read_track(s: &SelectSettings, file: &Path, kind: TelemetryKind) -> Result<Track> {
    match kind {
        TelemetryKind::Gpx => {
            let start = telemetry::creation_time(&s.input)?.ok_or_else(|| {
                Error::input(
                    &s.input,
                    format!(
                        "the video records no creation time, which the GPX track {} is aligned by",
                        file.display()
                    ),
                )
            })?;
            telemetry::read_gpx(file, start, s.telemetry_offset_s)
        }
        _ => {
            let mut track = telemetry::read_dji_srt(file)?;
            for f in &mut track.fixes {
                f.t_s -= s.telemetry_offset_s;
            }
            Ok(track)
        }
    }
}

/// Each frame's fix interpolated at its timestamp; warnings for the track's own problems, for
/// frames outside its time span and for jumps between consecutive frames.
fn timed_positions(
    track: &Track,
    file: &Path,
    timestamps_s: Option<&[f64]>,
    frames: usize,
) -> (Vec<Option<Position>>, Vec<String>) {
    let mut warnings = track.warnings.clone();
    let name = file.display();
    let Some(ts) = timestamps_s.filter(|ts| ts.len() == frames) else {
        warnings.push(format!(
            "{name}: the input has no frame timestamps to place the telemetry at"
        ));
        return (vec![None; frames], warnings);
    };
    let fixes: Vec<_> = ts.iter().map(|&t| telemetry::at(&track.fixes, t)).collect();
    let missing = fixes.iter().filter(|f| f.is_none()).count();
    if missing > 0 {
        let span = |f: Option<&telemetry::Fix>| f.map_or(f64::NAN, |f| f.t_s);
        let (a, b) = (span(track.fixes.first()), span(track.fixes.last()));
        let (v0, v1) = (ts.first().copied(), ts.last().copied());
        let msg = if missing == frames {
            "no frame has a position (no overlap in time; check --telemetry-offset)".to_string()
        } else {
            format!("{missing} of {frames} frames have no position")
        };
        // First: it is printed however many warnings follow.
        let msg = format!(
            "{name}: the telemetry spans {a:.3}..{b:.3} s of the video's clock, the frames \
             {:.3}..{:.3} s: {msg}",
            v0.unwrap_or(0.0),
            v1.unwrap_or(0.0)
        );
        warnings.insert(0, msg);
    }
    for (i, w) in fixes.windows(2).enumerate() {
        if let (Some(a), Some(b)) = (&w[0], &w[1]) {
            let d = telemetry::distance_m(a, b);
            if d > FRAME_JUMP_M {
                warnings.push(format!(
                    "{name}:line {}: frames {i} and {} are {:.1} km apart",
                    b.line,
                    i + 1,
                    d / 1000.0
                ));
            }
        }
    }
    let positions = fixes
        .iter()
        .map(|f| f.as_ref().map(Position::from))
        .collect();
    (positions, warnings)
}

/// The EXIF GPS position of every image of an image folder (or of a single image), with a
/// warning for each unreadable EXIF block and a count of the images without one.
fn exif_positions(input: &Path, kind: SourceKind) -> Result<(Vec<Option<Position>>, Vec<String>)> {
    let images = match kind {
        SourceKind::Images => source::folder_images(input)?,
        _ => vec![input.to_path_buf()],
    };
    let mut warnings = Vec::new();
    let mut positions = Vec::with_capacity(images.len());
    for image in &images {
        match telemetry::exif_fix(image) {
            Ok(Some(f)) if f.lat_deg == 0.0 && f.lon_deg == 0.0 => {
                let name = image.display();
                warnings.push(format!("{name}: EXIF GPS position 0, 0 (no fix; ignored)"));
                positions.push(None);
            }
            Ok(f) => positions.push(f.as_ref().map(Position::from)),
            Err(e) => {
                warnings.push(format!("{e} (no position)"));
                positions.push(None);
            }
        }
    }
    let without = positions.iter().filter(|p| p.is_none()).count();
    if without > 0 && without < positions.len() {
        // First, as in `timed_positions`.
        warnings.insert(
            0,
            format!(
                "{}: {without} of {} images have no EXIF GPS position",
                input.display(),
                positions.len()
            ),
        );
    }
    Ok((positions, warnings))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn telemetry_files_are_told_apart_by_extension_then_content() {
        let d = tempfile::tempdir().unwrap();
        let write = |name: &str, text: &str| {
            let p = d.path().join(name);
            std::fs::write(&p, text).unwrap();
            p
        };
        let gpx = write("a.GPX", "1\n");
        let srt = write("b.Srt", "<?xml");
        let xml = write("c.txt", "\u{feff}  <?xml version=\"1.0\"?><gpx>");
        let other = write("d.log", "1\n00:00:00,000 --> 00:00:01,000\n");
        assert_eq!(kind_of_file(&gpx).unwrap(), TelemetryKind::Gpx);
        assert_eq!(kind_of_file(&srt).unwrap(), TelemetryKind::DjiSrt);
        assert_eq!(kind_of_file(&xml).unwrap(), TelemetryKind::Gpx);
        assert_eq!(kind_of_file(&other).unwrap(), TelemetryKind::DjiSrt);
    }
}
