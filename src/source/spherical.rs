//! The projection a video's container declares in Google's spherical video metadata, named as
//! ffprobe names it (`equirectangular`, `tiled equirectangular`, `cubemap`, `mesh`). MP4/MOV
//! files are read here (a few seeks and the `moov` box; no process): the first video track's
//! V2 `sv3d` box (in its sample entry) or V1 `uuid` XML (in its `trak`). Any other container, or
//! an ISO file this reader cannot follow, goes to ffprobe's `-show_streams` (its `Spherical
//! Mapping` side data), as before. Only reads; never fails (no answer is "none declared").

use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

/// The `moov` box is read whole up to this size (a long video's sample tables run to a few MiB);
/// a larger one goes to ffprobe.
const MOOV_MAX: u64 = 256 << 20;

/// The UUID of the V1 metadata box (`uuid` in the video `trak`, RDF/XML inside).
const V1_UUID: [u8; 16] = [
    0xff, 0xcc, 0x82, 0x63, 0xf8, 0x55, 0x4a, 0x93, 0x88, 0x14, 0x58, 0x7a, 0x02, 0x52, 0x1f, 0xdd,
];

/// Top-level box types an ISO-BMFF / QuickTime file starts with.
const FIRST_BOXES: [&[u8; 4]; 8] = [
    b"ftyp", b"moov", b"mdat", b"free", b"skip", b"wide", b"pnot", b"uuid",
];

/// The projection `video` declares, if any: read from the file when it is an MP4/MOV this
/// module can follow, else from ffprobe (None when ffprobe is missing or says nothing).
pub fn declared(video: &Path) -> Option<String> {
    match read_iso(video) {
        Some(found) => found,
        None => ffprobe(video),
    }
}

/// `Some(projection or none)` for an MP4/MOV file whose `moov` was read; None for anything else
/// (another container, unreadable, no `moov`, a box that does not fit its parent).
pub fn read_iso(video: &Path) -> Option<Option<String>> {
    let mut f = std::fs::File::open(video).ok()?;
    let len = f.metadata().ok()?.len();
    let moov = find_moov(&mut f, len)?;
    Some(projection_of_moov(&moov))
}

/// One box header at the reader's position: (type, header length, body length).
fn header(f: &mut impl Read, left: u64) -> Option<([u8; 4], u64, u64)> {
    let mut h = [0u8; 8];
    f.read_exact(&mut h).ok()?;
    let size = u64::from(u32::from_be_bytes([h[0], h[1], h[2], h[3]]));
    let kind = [h[4], h[5], h[6], h[7]];
    let (head, total) = match size {
        0 => (8, left),
        1 => {
            let mut l = [0u8; 8];
            f.read_exact(&mut l).ok()?;
            (16, u64::from_be_bytes(l))
        }
        s => (8, s),
    };
    (total >= head && total <= left).then_some((kind, head, total - head))
}

/// The body of the file's top-level `moov` box (the first box must be one an ISO file starts
/// with, so other containers are not misread).
fn find_moov(f: &mut (impl Read + Seek), len: u64) -> Option<Vec<u8>> {
    let mut pos = 0u64;
    let mut first = true;
    while pos + 8 <= len {
        f.seek(SeekFrom::Start(pos)).ok()?;
        let (kind, head, body) = header(f, len - pos)?;
        if first && !FIRST_BOXES.contains(&&kind) {
            return None;
        }
        first = false;
        if &kind == b"moov" {
            if body > MOOV_MAX {
                return None;
            }
            let mut data = vec![0u8; usize::try_from(body).ok()?];
            f.read_exact(&mut data).ok()?;
            return Some(data);
        }
        pos += head + body;
    }
    None
}

/// The child boxes of a box body: (type, body); stops at the first that does not fit.
fn children(data: &[u8]) -> impl Iterator<Item = ([u8; 4], &[u8])> {
    let mut rest = data;
    std::iter::from_fn(move || {
        let mut r = std::io::Cursor::new(rest);
        let (kind, head, body) = header(&mut r, rest.len() as u64)?;
        let (head, body) = (usize::try_from(head).ok()?, usize::try_from(body).ok()?);
        let inner = rest.get(head..head + body)?;
        rest = &rest[head + body..];
        Some((kind, inner))
    })
}

/// The body of the first child of type `kind`.
fn child<'a>(data: &'a [u8], kind: &[u8; 4]) -> Option<&'a [u8]> {
    children(data).find(|(k, _)| k == kind).map(|(_, b)| b)
}

/// The box at `path` below `data` (each step the first child of that type).
fn at<'a>(data: &'a [u8], path: &[&[u8; 4]]) -> Option<&'a [u8]> {
    path.iter().try_fold(data, |d, k| child(d, k))
}

/// The declared projection of the `moov`'s first video track (V2 before V1).
fn projection_of_moov(moov: &[u8]) -> Option<String> {
    let video = children(moov)
        .filter(|(k, _)| k == b"trak")
        .map(|(_, t)| t)
        .find(|t| {
            // hdlr: version/flags (4), pre_defined (4), handler_type (4).
            at(t, &[b"mdia", b"hdlr"]).and_then(|h| h.get(8..12)) == Some(b"vide")
        })?;
    v2(video).or_else(|| v1(video))
}

/// V2: `sv3d` among the children of the first sample entry of the track's `stsd`.
fn v2(trak: &[u8]) -> Option<String> {
    let stsd = at(trak, &[b"mdia", b"minf", b"stbl", b"stsd"])?;
    // stsd: version/flags (4), entry count (4), then the sample entries.
    let (_, entry) = children(stsd.get(8..)?).next()?;
    // A visual sample entry's fixed fields take 78 bytes before its child boxes.
    let sv3d = child(entry.get(78..)?, b"sv3d")?;
    let proj = child(sv3d, b"proj")?;
    children(proj).find_map(|(kind, body)| match &kind {
        b"equi" => {
            // version/flags (4), then the top, bottom, left, right bounds (u32 each).
            let bounds = body.get(4..20)?;
            let cropped = bounds.iter().any(|&b| b != 0);
            Some(
                if cropped {
                    "tiled equirectangular"
                } else {
                    "equirectangular"
                }
                .to_string(),
            )
        }
        b"cbmp" => Some("cubemap".to_string()),
        b"mshp" => Some("mesh".to_string()),
        _ => None,
    })
}

/// V1: the track's `uuid` box with the spherical UUID, `<GSpherical:Spherical>true` in its XML;
/// its `ProjectionType` (V1 allows only equirectangular, the default when absent).
fn v1(trak: &[u8]) -> Option<String> {
    let xml = children(trak).find_map(|(kind, body)| {
        (&kind == b"uuid" && body.get(..16) == Some(&V1_UUID[..])).then(|| &body[16..])
    })?;
    let xml = String::from_utf8_lossy(xml);
    let value = |tag: &str| {
        let open = format!("<GSpherical:{tag}>");
        let start = xml.find(&open)? + open.len();
        let end = xml[start..].find('<')? + start;
        Some(xml[start..end].trim().to_string())
    };
    if !value("Spherical")?.eq_ignore_ascii_case("true") {
        return None;
    }
    Some(value("ProjectionType").unwrap_or_else(|| "equirectangular".to_string()))
}

/// ffprobe's answer for any container: the first `Spherical Mapping` of the first video stream
/// (None also when ffprobe is missing or fails).
pub fn ffprobe(video: &Path) -> Option<String> {
    let out = std::process::Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-show_streams",
            "-of",
            "json",
        ])
        .arg(video)
        .stdin(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .output()
        .ok()?;
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).ok()?;
    spherical_of(&v)
}

/// The `projection` of the first `Spherical Mapping` side data of ffprobe's `-show_streams`
/// JSON.
pub fn spherical_of(probe: &serde_json::Value) -> Option<String> {
    let streams = probe.get("streams")?.as_array()?;
    streams.iter().find_map(|s| {
        s.get("side_data_list")?.as_array()?.iter().find_map(|d| {
            let t = d.get("side_data_type")?.as_str()?;
            (t == "Spherical Mapping")
                .then(|| {
                    d.get("projection")
                        .and_then(|p| p.as_str())
                        .unwrap_or("unknown")
                })
                .map(str::to_string)
        })
    })
}

/// Box-writing helpers for tests (here and in the integration tests that inject metadata into
/// real files): a box, the V2 `sv3d` box and the V1 `uuid` box.
pub mod boxes {
    /// A box of type `kind` around `body` (32-bit size).
    pub fn plain(kind: &[u8; 4], body: &[u8]) -> Vec<u8> {
        let mut out = ((body.len() + 8) as u32).to_be_bytes().to_vec();
        out.extend_from_slice(kind);
        out.extend_from_slice(body);
        out
    }

    /// A V2 `sv3d` box declaring `projection` (`equi` with `bounds` top, bottom, left, right;
    /// `cbmp`; `mshp`), as the Spherical Video V2 RFC lays it out.
    pub fn sv3d(projection: &[u8; 4], bounds: [u32; 4]) -> Vec<u8> {
        let svhd = plain(b"svhd", &[0, 0, 0, 0, b'k', b'f', 0]);
        let prhd = plain(b"prhd", &[0u8; 16]);
        let mut kind_body = vec![0u8; 4];
        match projection {
            b"equi" => bounds
                .iter()
                .for_each(|b| kind_body.extend_from_slice(&b.to_be_bytes())),
            b"cbmp" => kind_body.extend_from_slice(&[0u8; 8]),
            _ => {}
        }
        let proj = plain(b"proj", &[prhd, plain(projection, &kind_body)].concat());
        plain(b"sv3d", &[svhd, proj].concat())
    }

    /// A V1 `uuid` box with `xml`.
    pub fn v1(xml: &str) -> Vec<u8> {
        plain(b"uuid", &[&super::V1_UUID[..], xml.as_bytes()].concat())
    }

    /// V1 XML as Google's spatial-media injector writes it, declaring `projection`.
    pub fn v1_xml(projection: &str) -> String {
        format!(
            "<?xml version=\"1.0\"?><rdf:SphericalVideo xmlns:rdf=\"http://www.w3.org/1999/02/22-rdf-syntax-ns#\" \
             xmlns:GSpherical=\"http://ns.google.com/videos/1.0/spherical/\">\
             <GSpherical:Spherical>true</GSpherical:Spherical><GSpherical:Stitched>true</GSpherical:Stitched>\
             <GSpherical:StitchingSoftware>keyframer tests</GSpherical:StitchingSoftware>\
             <GSpherical:ProjectionType>{projection}</GSpherical:ProjectionType></rdf:SphericalVideo>"
        )
    }

    /// `file` (a whole MP4/MOV) with `extra` appended to the box at `path` below the top level
    /// (e.g. `moov/trak`), every enclosing box's size grown to match; `entry` also descends
    /// into `stsd`'s first sample entry (past its 8 + 78 fixed bytes) when the path ends in
    /// `stsd`. Only for files whose `moov` follows `mdat` (so no chunk offset moves).
    pub fn inject(file: &[u8], path: &[&[u8; 4]], extra: &[u8]) -> Option<Vec<u8>> {
        fn walk(data: &[u8], skip: usize, path: &[&[u8; 4]], extra: &[u8]) -> Option<Vec<u8>> {
            let Some((first, rest)) = path.split_first() else {
                return Some([data, extra].concat());
            };
            let mut out = data.get(..skip)?.to_vec();
            let mut pos = skip;
            let mut done = false;
            while pos + 8 <= data.len() {
                let size = u32::from_be_bytes(data[pos..pos + 4].try_into().ok()?) as usize;
                let kind: [u8; 4] = data[pos + 4..pos + 8].try_into().ok()?;
                let body = data.get(pos + 8..pos + size)?;
                if !done && &kind == *first {
                    done = true;
                    let inner_skip = match &kind {
                        b"stsd" => 8,
                        b"hdlr" | b"meta" => 4,
                        _ => 0,
                    };
                    // stsd's children are sample entries: descend into the first one.
                    let new_body = if &kind == b"stsd" && rest.is_empty() {
                        let entry_size = u32::from_be_bytes(body.get(8..12)?.try_into().ok()?);
                        let entry = body.get(8..8 + entry_size as usize)?;
                        let entry_kind: [u8; 4] = entry[4..8].try_into().ok()?;
                        let grown = walk(&entry[8..], 78, &[], extra)?;
                        [
                            &body[..8],
                            &plain(&entry_kind, &grown),
                            &body[8 + entry.len()..],
                        ]
                        .concat()
                    } else {
                        walk(body, inner_skip, rest, extra)?
                    };
                    out.extend(plain(&kind, &new_body));
                } else {
                    out.extend_from_slice(&data[pos..pos + size]);
                }
                pos += size;
            }
            out.extend_from_slice(&data[pos..]);
            done.then_some(out)
        }
        walk(file, 0, path, extra)
    }
}

#[cfg(test)]
mod tests {
    use super::boxes::{plain, sv3d, v1, v1_xml};
    use super::*;

    /// A minimal MP4: ftyp, mdat, then a moov with the given tracks.
    fn mp4(tracks: &[Vec<u8>]) -> Vec<u8> {
        let ftyp = plain(b"ftyp", b"isom\0\0\x02\0isomiso2avc1mp41");
        let mdat = plain(b"mdat", &[0u8; 64]);
        let moov = plain(
            b"moov",
            &[plain(b"mvhd", &[0u8; 100]), tracks.concat()].concat(),
        );
        [ftyp, mdat, moov].concat()
    }

    /// A track of handler `handler` whose first sample entry holds `entry_children` and whose
    /// `trak` ends with `trak_extra`.
    fn track(handler: &[u8; 4], entry_children: &[u8], trak_extra: &[u8]) -> Vec<u8> {
        let hdlr = plain(b"hdlr", &[&[0u8; 8][..], handler, &[0u8; 13]].concat());
        let entry = plain(b"avc1", &[&[0u8; 78][..], entry_children].concat());
        let stsd = plain(b"stsd", &[&[0, 0, 0, 0, 0, 0, 0, 1][..], &entry].concat());
        let stbl = plain(b"stbl", &stsd);
        let minf = plain(b"minf", &stbl);
        let mdia = plain(b"mdia", &[plain(b"mdhd", &[0u8; 24]), hdlr, minf].concat());
        plain(
            b"trak",
            &[plain(b"tkhd", &[0u8; 84]), mdia, trak_extra.to_vec()].concat(),
        )
    }

    fn read(bytes: &[u8]) -> Option<Option<String>> {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("v.mp4");
        std::fs::write(&p, bytes).unwrap();
        read_iso(&p)
    }

    #[test]
    fn reads_v2_and_v1_metadata_of_the_first_video_track() {
        let avcc = plain(b"avcC", &[1, 2, 3]);
        let equi = [avcc.clone(), sv3d(b"equi", [0; 4])].concat();
        let cases: Vec<(Vec<u8>, Option<&str>)> = vec![
            (mp4(&[track(b"vide", &equi, &[])]), Some("equirectangular")),
            (
                mp4(&[track(b"vide", &sv3d(b"equi", [0, 0, 5, 5]), &[])]),
                Some("tiled equirectangular"),
            ),
            (
                mp4(&[track(b"vide", &sv3d(b"cbmp", [0; 4]), &[])]),
                Some("cubemap"),
            ),
            (
                mp4(&[track(b"vide", &sv3d(b"mshp", [0; 4]), &[])]),
                Some("mesh"),
            ),
            (
                mp4(&[track(b"vide", &avcc, &v1(&v1_xml("equirectangular")))]),
                Some("equirectangular"),
            ),
            // An audio track first: the video track's box counts; a second video track not.
            (
                mp4(&[
                    track(b"soun", &[], &[]),
                    track(b"vide", &equi, &[]),
                    track(b"vide", &sv3d(b"cbmp", [0; 4]), &[]),
                ]),
                Some("equirectangular"),
            ),
            (mp4(&[track(b"vide", &avcc, &[])]), None),
            (mp4(&[track(b"soun", &equi, &[])]), None),
            (
                mp4(&[track(
                    b"vide",
                    &avcc,
                    &v1(&v1_xml("x").replace(">true<", ">false<")),
                )]),
                None,
            ),
        ];
        for (i, (bytes, want)) in cases.iter().enumerate() {
            assert_eq!(read(bytes), Some(want.map(str::to_string)), "case {i}");
        }
    }

    #[test]
    fn a_64_bit_box_size_and_a_last_box_to_the_end_are_followed() {
        let track = track(b"vide", &sv3d(b"equi", [0; 4]), &[]);
        let ftyp = plain(b"ftyp", b"isom\0\0\x02\0");
        // mdat with a 64-bit size (size field 1, then the total in 8 bytes).
        let mut mdat = 1u32.to_be_bytes().to_vec();
        mdat.extend_from_slice(b"mdat");
        mdat.extend_from_slice(&(16u64 + 32).to_be_bytes());
        mdat.extend_from_slice(&[0u8; 32]);
        // moov last with size 0 ("to the end of the file").
        let mut moov = 0u32.to_be_bytes().to_vec();
        moov.extend_from_slice(b"moov");
        moov.extend_from_slice(&track);
        let bytes = [ftyp, mdat, moov].concat();
        assert_eq!(read(&bytes), Some(Some("equirectangular".into())));
    }

    #[test]
    fn other_containers_and_broken_files_go_to_ffprobe() {
        // Matroska's EBML header, AVI's RIFF, an empty file, a moov that runs past the end.
        let mkv = [
            0x1a, 0x45, 0xdf, 0xa3, 0x9f, 0x42, 0x86, 0x81, 0x01, 0, 0, 0, 0,
        ];
        let avi = b"RIFF\x10\0\0\0AVI LIST\0\0\0\0".to_vec();
        let whole = mp4(&[track(b"vide", &sv3d(b"equi", [0; 4]), &[])]);
        let truncated = whole[..whole.len() - 10].to_vec();
        for (name, bytes) in [
            ("mkv", mkv.to_vec()),
            ("avi", avi),
            ("empty", vec![]),
            ("truncated", truncated),
        ] {
            assert_eq!(read(&bytes), None, "{name}");
        }
    }

    #[test]
    fn spherical_of_reads_ffprobe_side_data() {
        let probe = serde_json::json!({"streams": [{"side_data_list": [
            {"side_data_type": "Display Matrix"},
            {"side_data_type": "Spherical Mapping", "projection": "equirectangular"}
        ]}]});
        assert_eq!(spherical_of(&probe).as_deref(), Some("equirectangular"));
        assert_eq!(spherical_of(&serde_json::json!({"streams": [{}]})), None);
    }
}
