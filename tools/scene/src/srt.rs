//! The synthetic flight's telemetry as a DJI SRT sidecar (`video.SRT`): every frame's
//! ground-truth camera centre as latitude, longitude and altitudes around a geographic origin, in
//! the bracketed layout of DJI's recent drones, with the 35 mm equivalent focal length and the
//! gimbal pitch and yaw, so tests of keyframer's telemetry know the truth. Positions carry 9 decimals
//! (real DJI files have 6, about 0.1 m) so the truth survives the text.

use crate::math::Pose;
use keyframer::source::telemetry::wgs84_radii;

/// Where the world's origin (x east, y north, z up; metres) is on the WGS84 ellipsoid.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GeoOrigin {
    /// Latitude, degrees north.
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Altitude above sea level of world z = 0, metres.
    pub alt_m: f64,
}

impl GeoOrigin {
    /// Latitude and longitude (degrees) of the world point (`east`, `north`): the tangent plane
    /// with the ellipsoid's radii of curvature at the origin, the inverse of keyframer's
    /// `telemetry::distance_m` to well under a millimetre over a synthetic flight.
    pub fn lat_lon(&self, east: f64, north: f64) -> (f64, f64) {
        let (meridian, prime) = wgs84_radii(self.lat_deg);
        (
            self.lat_deg + (north / meridian).to_degrees(),
            self.lon_deg + (east / (prime * self.lat_deg.to_radians().cos())).to_degrees(),
        )
    }
}

/// The date and time of the first frame: the video's `creation_time` and the SRT's clock.
pub const START_UTC: &str = "2024-05-01T10:00:00Z";

/// One SRT entry for frame `i` (shown from i / fps to (i + 1) / fps) at `pose`, written as
/// `t` says (origin, take-off height, focal length); the clock line counts from 10:00:00 of
/// [`START_UTC`]'s day.
pub fn entry(i: usize, fps: f64, pose: &Pose, t: &crate::Telemetry) -> String {
    let (t0, t1) = (i as f64 / fps, (i + 1) as f64 / fps);
    let c = pose.centre;
    let (lat, lon) = t.origin.lat_lon(c.0, c.1);
    let pitch = pose.rot[2].2.clamp(-1.0, 1.0).asin().to_degrees();
    let yaw = yaw_deg(pose);
    let ms = (t0 * 1000.0).round() as u64;
    format!(
        "{}\n{} --> {}\n<font size=\"28\">FrameCnt: {}, DiffTime: {}ms\n\
         2024-05-01 {:02}:{:02}:{:02}.{:03}\n\
         [iso: 100] [shutter: 1/1000.0] [fnum: 2.8] [ev: 0] [focal_len: {:.2}] \
         [latitude: {lat:.9}] [longitude: {lon:.9}] [rel_alt: {:.3} abs_alt: {:.3}] \
         [gb_yaw: {yaw:.2} gb_pitch: {pitch:.2} gb_roll: 0.0] </font>\n\n",
        i + 1,
        clock(t0),
        clock(t1),
        i + 1,
        ((t1 - t0) * 1000.0).round(),
        10 + ms / 3_600_000,
        ms / 60_000 % 60,
        ms / 1000 % 60,
        ms % 1000,
        t.focal_35mm,
        c.2 - t.takeoff_z_m,
        t.origin.alt_m + c.2,
    )
}

/// The camera's heading in degrees clockwise from north (DJI's `gb_yaw`): of its viewing
/// direction, or of the image's up direction when it looks (nearly) straight down.
pub fn yaw_deg(pose: &Pose) -> f64 {
    let (z, y) = (pose.rot[2], pose.rot[1]);
    let (east, north) = if z.0.hypot(z.1) > 1e-3 {
        (z.0, z.1)
    } else {
        (-y.0, -y.1)
    };
    east.atan2(north).to_degrees()
}

/// `HH:MM:SS,mmm`.
fn clock(t: f64) -> String {
    let ms = (t * 1000.0).round() as u64;
    format!(
        "{:02}:{:02}:{:02},{:03}",
        ms / 3_600_000,
        ms / 60_000 % 60,
        ms / 1000 % 60,
        ms % 1000
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::V3;

    #[test]
    fn keyframers_parser_reads_back_the_truth() {
        let o = GeoOrigin {
            lat_deg: 47.3769,
            lon_deg: 8.5417,
            alt_m: 408.0,
        };
        let poses = [
            Pose::looking(V3(0.0, 0.0, 60.0), V3(0.0, 1.0, -1.0)),
            Pose::looking(V3(120.0, -80.0, 75.0), V3(0.0, 0.0001, -1.0)),
        ];
        let tel = crate::Telemetry {
            origin: o,
            takeoff_z_m: 10.0,
            focal_35mm: 25.2,
            start_utc: START_UTC.into(),
        };
        let text: String = (0..2)
            .map(|i| entry(i * 61, 30.0, &poses[i], &tel))
            .collect();
        let t = keyframer::source::telemetry::parse_dji_srt(std::path::Path::new("v.SRT"), &text);
        assert!(t.warnings.is_empty(), "{:?}", t.warnings);
        let (a, b) = (&t.fixes[0], &t.fixes[1]);
        assert_eq!((a.lat_deg, a.lon_deg), (47.3769, 8.5417));
        assert_eq!((a.rel_alt_m, a.abs_alt_m), (Some(50.0), Some(468.0)));
        assert_eq!(
            (a.gimbal_pitch_deg, a.focal_35mm),
            (Some(-45.0), Some(25.2))
        );
        assert!((b.t_s - 61.0 / 30.0).abs() < 1e-3 && b.gimbal_pitch_deg == Some(-89.99));
        // Both face north (the second by its image's up direction).
        assert_eq!((a.gimbal_yaw_deg, b.gimbal_yaw_deg), (Some(0.0), Some(0.0)));
        // 120 m east and 80 m south: keyframer measures 144.222 m (sqrt(120² + 80²)) within 1 cm
        // (the 9 decimals of the text are 0.1 mm; east is taken at the origin's latitude here
        // and at the mean latitude there).
        let d = distance_m(a, b);
        assert!((d - 120f64.hypot(80.0)).abs() < 0.01, "{d}");
    }

    use keyframer::source::telemetry::distance_m;
}
