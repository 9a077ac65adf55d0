//! EXIF geotags for exported JPEGs: GPS latitude, longitude and altitude with their refs, the
//! capture time, the 35 mm focal length, make and model and the source frame, written into the
//! encoded bytes by a maintained EXIF library (little_exif), never by splicing bytes here.
//! Positions keep 1e-6 arc seconds (3e-10°, 0.03 mm).

use crate::error::{Error, Result};
use little_exif::exif_tag::ExifTag;
use little_exif::filetype::FileExtension;
use little_exif::metadata::Metadata;
use little_exif::rational::uR64;
use std::path::Path;
use time::OffsetDateTime;

/// What an exported image is tagged with.
#[derive(Debug, Clone, PartialEq)]
pub struct GeoTag {
    /// Latitude, degrees north.
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Metres above sea level.
    pub alt_m: Option<f64>,
    /// Capture time: DateTimeOriginal and SubSecTimeOriginal (milliseconds) in its own offset,
    /// which OffsetTimeOriginal states (`+00:00` for UTC).
    pub taken: Option<OffsetDateTime>,
    /// 35 mm equivalent focal length, millimetres.
    pub focal_35mm: Option<f64>,
    /// Camera maker (EXIF Make).
    pub make: Option<String>,
    /// Camera model (EXIF Model).
    pub model: Option<String>,
    /// The frame of the input the image shows (in ImageDescription: `frame N of NAME`).
    pub source: String,
}

/// Degrees as EXIF's three rationals (degrees, minutes, seconds with 6 decimals: below 60 s that
/// is at most 6e7, within a u32).
fn dms(value: f64) -> Vec<uR64> {
    const PER_SECOND: u64 = 1_000_000;
    let total = (value.abs() * 3600.0 * PER_SECOND as f64).round() as u64;
    let (d, rest) = (total / (3600 * PER_SECOND), total % (3600 * PER_SECOND));
    let (m, s) = (rest / (60 * PER_SECOND), rest % (60 * PER_SECOND));
    let r = |nominator: u64, denominator: u64| uR64 {
        nominator: nominator as u32,
        denominator: denominator as u32,
    };
    vec![r(d, 1), r(m, 1), r(s, PER_SECOND)]
}

/// `jpeg` (the encoded bytes of the image to be written at `path`) with `tag` written into its
/// EXIF block.
pub fn tag_jpeg(path: &Path, jpeg: &mut Vec<u8>, tag: &GeoTag) -> Result<()> {
    if !(tag.lat_deg.abs() <= 90.0 && tag.lon_deg.abs() <= 180.0) {
        let msg = format!("geotag {}, {} is not a position", tag.lat_deg, tag.lon_deg);
        return Err(Error::output(path, msg));
    }
    let mut m = Metadata::new();
    let lat_ref = if tag.lat_deg < 0.0 { "S" } else { "N" };
    let lon_ref = if tag.lon_deg < 0.0 { "W" } else { "E" };
    m.set_tag(ExifTag::GPSVersionID(vec![2, 3, 0, 0]));
    m.set_tag(ExifTag::GPSLatitudeRef(lat_ref.into()));
    m.set_tag(ExifTag::GPSLatitude(dms(tag.lat_deg)));
    m.set_tag(ExifTag::GPSLongitudeRef(lon_ref.into()));
    m.set_tag(ExifTag::GPSLongitude(dms(tag.lon_deg)));
    if let Some(alt) = tag.alt_m.filter(|a| a.is_finite()) {
        m.set_tag(ExifTag::GPSAltitudeRef(vec![u8::from(alt < 0.0)]));
        let mm = (alt.abs() * 1000.0).round() as u32;
        m.set_tag(ExifTag::GPSAltitude(vec![uR64 {
            nominator: mm,
            denominator: 1000,
        }]));
    }
    if let Some(t) = tag.taken {
        let (date, offset) = (t.date(), t.offset());
        m.set_tag(ExifTag::DateTimeOriginal(format!(
            "{:04}:{:02}:{:02} {:02}:{:02}:{:02}",
            date.year(),
            u8::from(date.month()),
            date.day(),
            t.hour(),
            t.minute(),
            t.second()
        )));
        let milliseconds = format!("{:03}", t.millisecond());
        m.set_tag(ExifTag::SubSecTimeOriginal(milliseconds));
        let minutes = offset.whole_minutes();
        let sign = if minutes < 0 { '-' } else { '+' };
        m.set_tag(ExifTag::OffsetTimeOriginal(format!(
            "{sign}{:02}:{:02}",
            minutes.unsigned_abs() / 60,
            minutes.unsigned_abs() % 60
        )));
    }
    if let Some(f) = tag.focal_35mm.filter(|f| *f > 0.0 && *f < 65_535.0) {
        m.set_tag(ExifTag::FocalLengthIn35mmFormat(vec![f.round() as u16]));
    }
    if let Some(make) = &tag.make {
        m.set_tag(ExifTag::Make(make.clone()));
    }
    if let Some(model) = &tag.model {
        m.set_tag(ExifTag::Model(model.clone()));
    }
    m.set_tag(ExifTag::ImageDescription(tag.source.clone()));
    m.write_to_vec(jpeg, FileExtension::JPEG)
        .map_err(|e| Error::output(path, format!("cannot write its EXIF geotag: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn jpeg() -> Vec<u8> {
        let img = image::RgbImage::from_pixel(16, 8, image::Rgb([40, 90, 160]));
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Jpeg).unwrap();
        out.into_inner()
    }

    #[test]
    fn keyframers_reader_gets_the_position_back() {
        let d = tempfile::tempdir().unwrap();
        for (lat, lon, alt) in [
            (47.376_912_345, 8.541_698_765, 512.345),
            (-33.86, -70.5, -12.5),
        ] {
            let mut bytes = jpeg();
            let tag = GeoTag {
                lat_deg: lat,
                lon_deg: lon,
                alt_m: Some(alt),
                taken: Some(time::macros::datetime!(2024-05-01 10:00:03.250 UTC)),
                focal_35mm: Some(25.2),
                make: Some("DJI".into()),
                model: None,
                source: "frame 90 of video.mp4".into(),
            };
            let p = d.path().join("a.jpg");
            tag_jpeg(&p, &mut bytes, &tag).unwrap();
            std::fs::write(&p, &bytes).unwrap();
            let f = crate::source::telemetry::exif_fix(&p).unwrap().unwrap();
            assert!(
                (f.lat_deg - lat).abs() < 1e-8 && (f.lon_deg - lon).abs() < 1e-8,
                "{f:?}"
            );
            assert_eq!((f.abs_alt_m, f.focal_35mm), (Some(alt), Some(25.0)));
            // Still a JPEG the decoders read.
            assert_eq!(image::open(&p).unwrap().width(), 16);
        }
    }
}
