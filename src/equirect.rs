//! Equirectangular (ERP) projection math: pinhole views of a 360° frame, their rotations, and the
//! remap tables that render them (computed once per view and sizes on the host, used by both
//! backends of `kernels::remap`). Pure functions of their arguments; no I/O.
//!
//! Conventions (also in docs/360.md):
//! - ERP column `x` (0-based, of width `W`) ↔ longitude `(x + 0.5) / W · 360° − 180°`: 0 is
//!   forward, + is to the right. Row `y` (of height `H`) ↔ latitude `90° − (y + 0.5) / H · 180°`:
//!   + is up.
//! - Directions live in the ERP's camera frame: x right, y down, z forward, so latitude `φ` and
//!   longitude `λ` give `(cos φ sin λ, −sin φ, cos φ cos λ)`.
//! - A pinhole view looks along its +z with x right and y down (OpenCV's and COLMAP's camera
//!   frame); pixel `(u, v)` (0-based) sees the ray `((u + 0.5 − w/2) / f, (v + 0.5 − h/2) / f, 1)`
//!   with `f = (w / 2) / tan(fov / 2)` (square pixels, principal point at the centre).
//! - A view's rotation (view frame → ERP frame) is `Ry(yaw) · Rx(pitch) · Rz(roll)`: yaw turns
//!   to the right (its centre's longitude), pitch up (its centre's latitude), roll about its own
//!   axis, clockwise in the image.
//! - Cube faces: `front` (yaw 0), `right` (+90), `back` (180), `left` (−90), `up` (pitch +90,
//!   its lower edge meets `front`), `down` (pitch −90, its upper edge meets `front`).

use crate::error::{Error, Result};
use crate::source::spherical;
use std::path::Path;

/// Interpolation of a view's remap (`kernels::remap`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Interp {
    /// 2 x 2 taps (cv::INTER_LINEAR).
    Bilinear,
    /// 4 x 4 taps, Keys' cubic with A = −0.75 (cv::INTER_CUBIC).
    Bicubic,
}

impl std::str::FromStr for Interp {
    type Err = Error;
    fn from_str(s: &str) -> Result<Interp> {
        match s {
            "bilinear" => Ok(Interp::Bilinear),
            "bicubic" => Ok(Interp::Bicubic),
            _ => Err(Error::param(
                "--view-interp",
                format!("`{s}`: bilinear or bicubic"),
            )),
        }
    }
}

/// How an input's frames map to directions (`select --projection`), recorded in the project.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Projection {
    /// An ordinary camera's frames.
    #[default]
    Pinhole,
    /// 360° equirectangular frames (2:1).
    Equirect,
}

impl std::str::FromStr for Projection {
    type Err = Error;
    fn from_str(s: &str) -> Result<Projection> {
        match s {
            "pinhole" => Ok(Projection::Pinhole),
            "equirect" => Ok(Projection::Equirect),
            _ => Err(Error::param(
                "--projection",
                format!("`{s}`: pinhole or equirect"),
            )),
        }
    }
}

impl Projection {
    /// Whether this is the default (projects leave it out).
    pub fn is_pinhole(&self) -> bool {
        *self == Projection::Pinhole
    }
}

/// Refuses equirect on frames that are not 2:1, with the reason.
pub fn check_equirect(input: &Path, (w, h): (u32, u32)) -> Result<()> {
    if u64::from(w) == 2 * u64::from(h) {
        return Ok(());
    }
    Err(Error::param(
        "--projection",
        format!(
            "{}: equirect needs 2:1 frames (360° of longitude over 180° of latitude), these are {w}x{h}{}",
            input.display(),
            if u64::from(w) * 9 == u64::from(h) * 16 { " (16:9: an ordinary video, or a 360° video already cut to a view)" } else { "" }
        ),
    ))
}

/// A video's spherical metadata ([`crate::source::spherical`]): read in place from an MP4/MOV,
/// else by ffprobe on a thread of its own while the caller opens the video;
/// [`resolve_projection_probed`] waits for it.
pub enum SphericalProbe {
    /// Not needed: not a video, or a projection asked for.
    Unneeded,
    /// Being read by ffprobe on its own thread (not an MP4/MOV this module reads).
    Reading(std::thread::JoinHandle<Option<String>>),
    /// Read in place (an MP4/MOV, or no thread to be had).
    Read(Option<String>),
}

impl SphericalProbe {
    /// Starts reading `input`'s metadata where the projection depends on it: a video, with no
    /// projection `asked` for.
    pub fn start(input: &Path, is_video: bool, asked: Option<Projection>) -> SphericalProbe {
        if !is_video || asked.is_some() {
            return SphericalProbe::Unneeded;
        }
        if let Some(found) = spherical::read_iso(input) {
            return SphericalProbe::Read(found);
        }
        let path = input.to_path_buf();
        let thread = std::thread::Builder::new()
            .name("spherical-probe".into())
            .spawn(move || spherical::declared(&path));
        match thread {
            Ok(t) => SphericalProbe::Reading(t),
            Err(_) => SphericalProbe::Read(spherical::declared(input)),
        }
    }

    fn wait(self) -> Option<String> {
        match self {
            SphericalProbe::Unneeded => None,
            SphericalProbe::Reading(t) => t.join().ok().flatten(),
            SphericalProbe::Read(found) => found,
        }
    }
}

/// The projection `select` records: `asked` when given; else equirect when the container's
/// spherical metadata says so (said on stderr), pinhole otherwise (with a one-line hint for 2:1
/// frames). Equirect on frames that are not 2:1 is refused.
pub fn resolve_projection(
    asked: Option<Projection>,
    input: &Path,
    is_video: bool,
    size: (u32, u32),
) -> Result<Projection> {
    let probe = SphericalProbe::start(input, is_video, asked);
    resolve_projection_probed(asked, input, probe, size)
}

/// [`resolve_projection`] with the metadata read by `probe` (started earlier).
pub fn resolve_projection_probed(
    asked: Option<Projection>,
    input: &Path,
    probe: SphericalProbe,
    size: (u32, u32),
) -> Result<Projection> {
    let found = probe.wait();
    let p = match (asked, &found) {
        (Some(p), _) => p,
        (None, Some(kind)) if kind == "equirectangular" => {
            log::warn!(
                "{}: spherical video metadata (equirectangular) found: analysing it as a 360° input (--projection pinhole overrides)",
                input.display()
            );
            Projection::Equirect
        }
        (None, Some(kind)) => {
            log::warn!(
                "{}: spherical video metadata says `{kind}`, which keyframer does not read: analysing the frames as pinhole ones (convert to equirectangular, see docs/360.md)",
                input.display()
            );
            Projection::Pinhole
        }
        (None, None) => {
            if u64::from(size.0) == 2 * u64::from(size.1) {
                log::warn!(
                    "{}: 2:1 frames without spherical metadata: if this is a 360° video, give --projection equirect",
                    input.display()
                );
            }
            Projection::Pinhole
        }
    };
    if p == Projection::Equirect {
        check_equirect(input, size)?;
    }
    Ok(p)
}

/// 3x3 rotation, row-major.
pub type Mat3 = [[f64; 3]; 3];

/// One pinhole view of the sphere.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct View {
    /// Folder name of the view in an export (`front`, `ring03` ...).
    pub name: String,
    /// Longitude of the view's centre in degrees (+ = right).
    pub yaw_deg: f64,
    /// Latitude of the view's centre in degrees (+ = up).
    pub pitch_deg: f64,
    /// Rotation about the view's axis in degrees (clockwise in the image).
    pub roll_deg: f64,
    /// Horizontal (= vertical: views are square) field of view in degrees.
    pub fov_deg: f64,
    /// Width and height in pixels.
    pub size: u32,
}

impl View {
    /// Focal length in pixels.
    pub fn focal(&self) -> f64 {
        f64::from(self.size) / 2.0 / (self.fov_deg.to_radians() / 2.0).tan()
    }

    /// Rotation from the view's frame to the ERP frame.
    pub fn rotation(&self) -> Mat3 {
        let (y, p, r) = (
            self.yaw_deg.to_radians(),
            self.pitch_deg.to_radians(),
            self.roll_deg.to_radians(),
        );
        mul(&mul(&rot_y(y), &rot_x(p)), &rot_z(r))
    }

    /// Unit direction (ERP frame) of the ray through the centre of pixel `(u, v)`.
    pub fn ray(&self, u: f64, v: f64) -> [f64; 3] {
        let (c, f) = (f64::from(self.size) / 2.0, self.focal());
        let d = [(u + 0.5 - c) / f, (v + 0.5 - c) / f, 1.0];
        normalize(apply(&self.rotation(), d))
    }
}

/// The views an export renders from each ERP frame (`--views`).
#[derive(Debug, Clone, PartialEq)]
pub enum ViewSet {
    /// Six cube faces.
    Cube,
    /// `n` views evenly around the horizon (the first at yaw 0) at `pitch` degrees.
    Ring {
        /// Number of views.
        n: u32,
        /// Latitude of their centres in degrees.
        pitch: f64,
    },
    /// The ERP frames unchanged (for trainers and tools that read ERP; not for COLMAP 3.8).
    Equirect,
}

impl std::str::FromStr for ViewSet {
    type Err = Error;
    fn from_str(s: &str) -> Result<ViewSet> {
        let bad = |m: &str| Error::param("--views", format!("`{s}`: {m}"));
        match s {
            "cube" => return Ok(ViewSet::Cube),
            "equirect" => return Ok(ViewSet::Equirect),
            _ => {}
        }
        let rest = s
            .strip_prefix("ring:")
            .ok_or_else(|| bad("expected cube, ring:N[,PITCH] or equirect"))?;
        let (n, pitch) = match rest.split_once(',') {
            Some((n, p)) => (
                n,
                p.parse::<f64>().map_err(|_| bad("PITCH is not a number"))?,
            ),
            None => (rest, 0.0),
        };
        let n: u32 = n.parse().map_err(|_| bad("N is not a whole number"))?;
        if !(1..=64).contains(&n) {
            return Err(bad("N must be 1 to 64"));
        }
        if !pitch.is_finite() || pitch.abs() > 90.0 {
            return Err(bad("PITCH must be within [-90, 90] degrees"));
        }
        Ok(ViewSet::Ring { n, pitch })
    }
}

impl std::fmt::Display for ViewSet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ViewSet::Cube => f.write_str("cube"),
            ViewSet::Equirect => f.write_str("equirect"),
            ViewSet::Ring { n, pitch } => write!(f, "ring:{n},{pitch}"),
        }
    }
}

impl ViewSet {
    /// The pinhole views of the set at `fov_deg` and `size` pixels (none for `Equirect`).
    pub fn views(&self, fov_deg: f64, size: u32) -> Vec<View> {
        let view = |name: String, yaw_deg: f64, pitch_deg: f64| View {
            name,
            yaw_deg,
            pitch_deg,
            roll_deg: 0.0,
            fov_deg,
            size,
        };
        match self {
            ViewSet::Cube => [
                ("front", 0.0, 0.0),
                ("right", 90.0, 0.0),
                ("back", 180.0, 0.0),
                ("left", -90.0, 0.0),
                ("up", 0.0, 90.0),
                ("down", 0.0, -90.0),
            ]
            .into_iter()
            .map(|(n, y, p)| view(n.into(), y, p))
            .collect(),
            ViewSet::Ring { n, pitch } => (0..*n)
                .map(|i| {
                    let yaw = f64::from(i) * 360.0 / f64::from(*n);
                    let yaw = if yaw > 180.0 { yaw - 360.0 } else { yaw };
                    view(format!("ring{i:02}"), yaw, *pitch)
                })
                .collect(),
            ViewSet::Equirect => Vec::new(),
        }
    }
}

/// The size of a square view of `fov_deg` whose centre samples the sphere as densely as the
/// equator of a `erp_width`-wide ERP frame (focal length = ERP pixels per radian, W / 2π):
/// `W · tan(fov / 2) / π`, rounded (at least 16).
pub fn native_view_size(erp_width: u32, fov_deg: f64) -> u32 {
    let s = f64::from(erp_width) * (fov_deg.to_radians() / 2.0).tan() / std::f64::consts::PI;
    (s.round() as u32).max(16)
}

/// The views the analysis measures an ERP frame on: `count` views evenly around the horizon
/// (the first forward), `fov_deg` wide, at the native size of an `erp_width`-wide frame.
pub fn analysis_views(count: u32, fov_deg: f64, erp_width: u32) -> Vec<View> {
    let ring = ViewSet::Ring {
        n: count,
        pitch: 0.0,
    };
    ring.views(fov_deg, native_view_size(erp_width, fov_deg))
}

/// Longitude and latitude in degrees of the centre of ERP pixel `(x, y)` of a `w` x `h` frame.
pub fn lon_lat(x: f64, y: f64, (w, h): (u32, u32)) -> (f64, f64) {
    (
        (x + 0.5) / f64::from(w) * 360.0 - 180.0,
        90.0 - (y + 0.5) / f64::from(h) * 180.0,
    )
}

/// Unit direction (ERP frame) of longitude `lon` and latitude `lat` in degrees.
pub fn direction(lon_deg: f64, lat_deg: f64) -> [f64; 3] {
    let (l, p) = (lon_deg.to_radians(), lat_deg.to_radians());
    [p.cos() * l.sin(), -p.sin(), p.cos() * l.cos()]
}

/// The ERP pixel coordinates (x, y), 0-based, where direction `d` lands in a `w` x `h` frame:
/// x in [−0.5, w − 0.5), y in [−0.5, h − 0.5].
pub fn erp_pixel(d: [f64; 3], (w, h): (u32, u32)) -> (f64, f64) {
    let lon = d[0].atan2(d[2]).to_degrees();
    let lat = (-d[1]).atan2(d[0].hypot(d[2])).to_degrees();
    (
        (lon + 180.0) / 360.0 * f64::from(w) - 0.5,
        (90.0 - lat) / 180.0 * f64::from(h) - 0.5,
    )
}

/// The remap table of `view` from a `w` x `h` ERP frame: for each view pixel, row after row, the
/// ERP coordinates (x, y) it samples (cv::remap's map1 / map2). Columns wrap around (the
/// kernel's border is BORDER_WRAP); rows are clamped to [0, h − 1] so no sample crosses a pole
/// into the opposite edge's row.
pub fn view_map(view: &View, erp: (u32, u32)) -> (Vec<f32>, Vec<f32>) {
    let n = view.size as usize;
    let (mut xs, mut ys) = (Vec::with_capacity(n * n), Vec::with_capacity(n * n));
    let rot = view.rotation();
    let (c, f) = (f64::from(view.size) / 2.0, view.focal());
    for v in 0..n {
        for u in 0..n {
            let d = [(u as f64 + 0.5 - c) / f, (v as f64 + 0.5 - c) / f, 1.0];
            let (x, y) = erp_pixel(apply(&rot, d), erp);
            xs.push(x as f32);
            ys.push(y.clamp(0.0, f64::from(erp.1) - 1.0) as f32);
        }
    }
    (xs, ys)
}

/// The mask of `view` hiding everything below latitude `-nadir_deg` (the operator and tripod
/// under the camera): 0 where hidden, 255 elsewhere, row after row; None when the view sees
/// nothing that low.
pub fn nadir_mask(view: &View, nadir_deg: f64) -> Option<Vec<u8>> {
    let n = view.size as usize;
    let limit = -(90.0 - nadir_deg);
    let mut any = false;
    let mut mask = vec![255u8; n * n];
    for v in 0..n {
        for u in 0..n {
            let d = view.ray(u as f64, v as f64);
            let lat = (-d[1]).asin().to_degrees();
            if lat < limit {
                mask[v * n + u] = 0;
                any = true;
            }
        }
    }
    any.then_some(mask)
}

/// COLMAP's `cam_from_rig` rotation of `view` in a rig whose reference sensor is `reference`,
/// as a unit quaternion [w, x, y, z] (rig_configurator's `cam_from_rig_rotation`).
pub fn cam_from_rig(view: &View, reference: &View) -> [f64; 4] {
    quaternion(&mul(&transpose(&view.rotation()), &reference.rotation()))
}

/// The unit quaternion [w, x, y, z] (w ≥ 0) of a rotation matrix.
pub fn quaternion(m: &Mat3) -> [f64; 4] {
    let tr = m[0][0] + m[1][1] + m[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [
            0.25 * s,
            (m[2][1] - m[1][2]) / s,
            (m[0][2] - m[2][0]) / s,
            (m[1][0] - m[0][1]) / s,
        ]
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt() * 2.0;
        [
            (m[2][1] - m[1][2]) / s,
            0.25 * s,
            (m[0][1] + m[1][0]) / s,
            (m[0][2] + m[2][0]) / s,
        ]
    } else if m[1][1] > m[2][2] {
        let s = (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt() * 2.0;
        [
            (m[0][2] - m[2][0]) / s,
            (m[0][1] + m[1][0]) / s,
            0.25 * s,
            (m[1][2] + m[2][1]) / s,
        ]
    } else {
        let s = (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt() * 2.0;
        [
            (m[1][0] - m[0][1]) / s,
            (m[0][2] + m[2][0]) / s,
            (m[1][2] + m[2][1]) / s,
            0.25 * s,
        ]
    };
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let sign = if q[0] < 0.0 { -1.0 } else { 1.0 };
    q.map(|v| v * sign / n)
}

fn rot_x(a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]
}

fn rot_y(a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
}

fn rot_z(a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

/// `a · b`.
pub fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}

/// `aᵀ`.
pub fn transpose(a: &Mat3) -> Mat3 {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[j][i];
        }
    }
    m
}

/// `m · v`.
pub fn apply(m: &Mat3, v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|x| x / n)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: [f64; 3], b: [f64; 3]) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-9)
    }

    #[test]
    fn cube_faces_look_where_the_issue_says() {
        let views = ViewSet::Cube.views(90.0, 64);
        let names: Vec<&str> = views.iter().map(|v| v.name.as_str()).collect();
        assert_eq!(names, ["front", "right", "back", "left", "up", "down"]);
        let centre = |v: &View| apply(&v.rotation(), [0.0, 0.0, 1.0]);
        assert!(close(centre(&views[0]), direction(0.0, 0.0)));
        assert!(close(centre(&views[1]), direction(90.0, 0.0)));
        assert!(close(centre(&views[1]), [1.0, 0.0, 0.0]));
        assert!(close(centre(&views[2]), direction(180.0, 0.0)));
        assert!(close(centre(&views[3]), [-1.0, 0.0, 0.0]));
        assert!(close(centre(&views[4]), [0.0, -1.0, 0.0]));
        assert!(close(centre(&views[5]), [0.0, 1.0, 0.0]));
        // The lower edge of `up` and the upper edge of `down` point forward.
        assert!(apply(&views[4].rotation(), [0.0, 1.0, 0.0])[2] > 0.99);
        assert!(apply(&views[5].rotation(), [0.0, -1.0, 0.0])[2] > 0.99);
        // A 90° face's corner ray is 45° off axis horizontally at its middle row.
        let edge = views[0].ray(-0.5, 31.5);
        let (lon, _) = (edge[0].atan2(edge[2]).to_degrees(), 0.0);
        assert!((lon + 45.0).abs() < 1e-9, "{lon}");
    }

    #[test]
    fn erp_pixels_round_trip_with_the_conventions() {
        let size = (400, 200);
        assert_eq!(lon_lat(199.5, 99.5, size), (0.0, 0.0));
        let (x, y) = erp_pixel(direction(90.0, 45.0), size);
        assert!(
            (x - 299.5).abs() < 1e-9 && (y - 49.5).abs() < 1e-9,
            "{x} {y}"
        );
        for (px, py) in [(0.0, 0.0), (17.0, 150.0), (399.0, 199.0), (250.3, 33.7)] {
            let (lon, lat) = lon_lat(px, py, size);
            let (x, y) = erp_pixel(direction(lon, lat), size);
            assert!((x - px).abs() < 1e-9 && (y - py).abs() < 1e-9);
        }
    }

    #[test]
    fn view_sets_parse_and_refuse() {
        assert_eq!("cube".parse::<ViewSet>().unwrap(), ViewSet::Cube);
        assert_eq!(
            "ring:8,-10".parse::<ViewSet>().unwrap(),
            ViewSet::Ring { n: 8, pitch: -10.0 }
        );
        assert_eq!(
            "ring:3".parse::<ViewSet>().unwrap(),
            ViewSet::Ring { n: 3, pitch: 0.0 }
        );
        for bad in ["ring:0", "ring:x", "ring:4,91", "sphere", "ring:4,nan"] {
            assert!(bad.parse::<ViewSet>().is_err(), "{bad}");
        }
        let ring = ViewSet::Ring { n: 4, pitch: 10.0 }.views(90.0, 8);
        let yaws: Vec<f64> = ring.iter().map(|v| v.yaw_deg).collect();
        assert_eq!(yaws, [0.0, 90.0, 180.0, -90.0]);
        assert_eq!(ring[3].name, "ring03");
    }

    #[test]
    fn rig_rotations_are_relative_to_the_reference() {
        let views = ViewSet::Cube.views(90.0, 8);
        assert_eq!(cam_from_rig(&views[0], &views[0]), [1.0, 0.0, 0.0, 0.0]);
        // `right`: a point straight ahead of the rig is at the camera's left (−x).
        let q = cam_from_rig(&views[1], &views[0]);
        let r = transpose(&views[1].rotation());
        let p = apply(&r, [0.0, 0.0, 1.0]);
        assert!(close(p, [-1.0, 0.0, 0.0]), "{p:?}");
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert!(
            close([q[0], q[1], q[2]], [h, 0.0, -h]) && q[3].abs() < 1e-9,
            "{q:?}"
        );
        for v in &views {
            let q = quaternion(&v.rotation());
            assert!((q.iter().map(|x| x * x).sum::<f64>() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn projection_checks_and_metadata() {
        let p = Path::new("v.mp4");
        assert!(check_equirect(p, (3840, 1920)).is_ok());
        let e = check_equirect(p, (1920, 1080)).unwrap_err().to_string();
        assert!(
            e.contains("2:1") && e.contains("16:9") && e.contains("1920x1080"),
            "{e}"
        );
        let asked = resolve_projection(Some(Projection::Equirect), p, false, (1920, 1080));
        assert!(asked.is_err());
        let plain = resolve_projection(None, p, false, (400, 200)).unwrap();
        assert_eq!(plain, Projection::Pinhole);
    }

    #[test]
    fn nadir_mask_covers_the_floor_only() {
        let views = ViewSet::Cube.views(90.0, 32);
        assert!(nadir_mask(&views[0], 30.0).is_none(), "front stops at -45°");
        assert!(nadir_mask(&views[4], 30.0).is_none(), "up sees no floor");
        let down = nadir_mask(&views[5], 30.0).unwrap();
        assert_eq!(down[16 * 32 + 16], 0, "the nadir is hidden");
        assert_eq!(down[0], 255, "the corners are 35° from the horizon");
        let front = nadir_mask(&views[0], 50.0).unwrap();
        assert_eq!(front[31 * 32 + 16], 0);
        assert_eq!(front[16 * 32 + 16], 255);
    }
}
