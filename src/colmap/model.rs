//! Readers for COLMAP sparse models (`cameras`, `images`, `points3D` in the binary `.bin` or the
//! text `.txt` format of COLMAP's "Output format" documentation). Both readers fill the same
//! [`Model`]; every parse error names the file and the record (or line) at fault.

use super::align::{self, Vec3};
use crate::error::{Error, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One camera (intrinsics).
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    /// Camera id.
    pub id: u32,
    /// COLMAP model name (`SIMPLE_RADIAL`, `PINHOLE`, ...).
    pub model: String,
    /// Image width in pixels.
    pub width: u64,
    /// Image height in pixels.
    pub height: u64,
    /// Model parameters in COLMAP's order.
    pub params: Vec<f64>,
}

/// One registered image: its world-to-camera pose and 2D observations.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Image id.
    pub id: u32,
    /// World-to-camera rotation as a quaternion (w, x, y, z).
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: Vec3,
    /// Camera id.
    pub camera_id: u32,
    /// File name relative to the image folder.
    pub name: String,
    /// 2D points: x, y and the 3D point observed (None when not triangulated).
    pub points2d: Vec<(f64, f64, Option<u64>)>,
}

impl Image {
    /// Camera centre in world coordinates, `C = -Rᵀ t`.
    pub fn centre(&self) -> Vec3 {
        align::mul_vec(&self.cam_to_world(), &self.tvec).map(|v| -v)
    }

    /// Camera-to-world rotation `Rᵀ`.
    pub fn cam_to_world(&self) -> align::Mat3 {
        align::transpose(&align::quat_to_mat(self.qvec))
    }
}

/// One 3D point.
#[derive(Debug, Clone, PartialEq)]
pub struct Point3D {
    /// Point id.
    pub id: u64,
    /// Position.
    pub xyz: Vec3,
    /// Colour.
    pub rgb: [u8; 3],
    /// Mean reprojection error in pixels.
    pub error: f64,
    /// Observations: (image id, index of the 2D point in that image).
    pub track: Vec<(u32, u32)>,
}

/// A sparse model.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Model {
    /// Cameras by id.
    pub cameras: BTreeMap<u32, Camera>,
    /// Registered images by id.
    pub images: BTreeMap<u32, Image>,
    /// 3D points by id.
    pub points: BTreeMap<u64, Point3D>,
}

impl Model {
    /// The mean of `f` over the 3D points; `None` without points.
    pub fn point_mean(&self, f: impl Fn(&Point3D) -> f64) -> Option<f64> {
        let n = self.points.len() as f64;
        (n > 0.0).then(|| self.points.values().map(f).sum::<f64>() / n)
    }
}

/// The on-disk format a model was read from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// `cameras.bin`, `images.bin`, `points3D.bin`.
    Binary,
    /// `cameras.txt`, `images.txt`, `points3D.txt`.
    Text,
}

/// Which format the folder holds (binary preferred when both are complete), if any.
pub fn detect(dir: &Path) -> Option<Format> {
    let has = |ext: &str| {
        ["cameras", "images", "points3D"]
            .iter()
            .all(|n| dir.join(format!("{n}.{ext}")).is_file())
    };
    [("bin", Format::Binary), ("txt", Format::Text)]
        .into_iter()
        .find_map(|(ext, format)| has(ext).then_some(format))
}

/// Reads the model in `dir` (binary if present, else text).
pub fn read(dir: &Path) -> Result<(Model, Format)> {
    match detect(dir) {
        Some(Format::Binary) => Ok((read_binary(dir)?, Format::Binary)),
        Some(Format::Text) => Ok((read_text(dir)?, Format::Text)),
        None => Err(Error::input(
            dir,
            "not a COLMAP sparse model: needs cameras, images and points3D as .bin or .txt",
        )),
    }
}

fn bad(path: &Path, field: impl Into<String>, msg: impl Into<String>) -> Error {
    Error::file(path, None, "COLMAP model", field, msg)
}

/// Little-endian cursor over a whole file, with errors naming the file and the record.
struct Bin<'a> {
    path: &'a Path,
    data: Vec<u8>,
    pos: usize,
}

impl<'a> Bin<'a> {
    fn open(path: &'a Path) -> Result<Self> {
        let data = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Ok(Bin { path, data, pos: 0 })
    }
    fn take<const N: usize>(&mut self, field: &dyn Fn() -> String) -> Result<[u8; N]> {
        let end = self.pos + N;
        let bytes: [u8; N] = (self.data.get(self.pos..end))
            .and_then(|b| b.try_into().ok())
            .ok_or_else(|| bad(self.path, field(), "file ends early"))?;
        self.pos = end;
        Ok(bytes)
    }
    fn u64(&mut self, f: &dyn Fn() -> String) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(f)?))
    }
    fn u32(&mut self, f: &dyn Fn() -> String) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(f)?))
    }
    fn i32(&mut self, f: &dyn Fn() -> String) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(f)?))
    }
    fn f64(&mut self, f: &dyn Fn() -> String) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(f)?))
    }
    fn u8(&mut self, f: &dyn Fn() -> String) -> Result<u8> {
        Ok(self.take::<1>(f)?[0])
    }
    fn cstr(&mut self, f: &dyn Fn() -> String) -> Result<String> {
        let rest = self.data.get(self.pos..).unwrap_or_default();
        let n = rest
            .iter()
            .position(|&b| b == 0)
            .ok_or_else(|| bad(self.path, f(), "unterminated name"))?;
        let s = String::from_utf8_lossy(&rest[..n]).into_owned();
        self.pos += n + 1;
        Ok(s)
    }
    /// A count that must fit in what is left of the file (`min_bytes` per element).
    fn count(&mut self, min_bytes: usize, f: &dyn Fn() -> String) -> Result<usize> {
        let n = self.u64(f)?;
        let left = (self.data.len() - self.pos) as u64;
        if n.saturating_mul(min_bytes as u64) > left {
            return Err(bad(self.path, f(), format!("count {n} exceeds the file")));
        }
        Ok(n as usize)
    }
    fn end(&self) -> Result<()> {
        let left = self.data.len() - self.pos;
        if left != 0 {
            let msg = format!("{left} unexpected bytes after the last record");
            return Err(bad(self.path, "end", msg));
        }
        Ok(())
    }
}

/// Reads `cameras.bin`, `images.bin` and `points3D.bin` from `dir`.
pub fn read_binary(dir: &Path) -> Result<Model> {
    Ok(Model {
        cameras: read_bin(&dir.join("cameras.bin"), 24, "camera", bin_camera, |c| c.id)?,
        images: read_bin(&dir.join("images.bin"), 64, "image", bin_image, |i| i.id)?,
        points: read_bin(&dir.join("points3D.bin"), 43, "point", bin_point, |p| p.id)?,
    })
}

/// Reads one binary file: a count of `what`s, then their records keyed by id.
fn read_bin<K: Ord, V>(
    path: &Path,
    min_bytes: usize,
    what: &str,
    record: fn(&mut Bin, &dyn Fn() -> String) -> Result<V>,
    key: fn(&V) -> K,
) -> Result<BTreeMap<K, V>> {
    let mut b = Bin::open(path)?;
    let n = b.count(min_bytes, &|| format!("number of {what}s"))?;
    let mut out = BTreeMap::new();
    for k in 0..n {
        let v = record(&mut b, &move || format!("{what} record {k}"))?;
        out.insert(key(&v), v);
    }
    b.end()?;
    Ok(out)
}

/// The bytes of a `cameras.bin` holding `cameras` (COLMAP's binary format: a `u64` count, then
/// per camera `u32` id, `i32` model id, `u64` width, `u64` height and the `f64` parameters).
pub fn cameras_bin(cameras: &BTreeMap<u32, Camera>) -> Result<Vec<u8>> {
    let mut out = (cameras.len() as u64).to_le_bytes().to_vec();
    for cam in cameras.values() {
        let (id, _, np) = crate::sparse::model_file_cameras()
            .find(|m| m.1 == cam.model)
            .ok_or_else(|| Error::Colmap(format!("unknown camera model {}", cam.model)))?;
        if cam.params.len() != *np {
            return Err(Error::Colmap(format!(
                "camera {} ({}) has {} parameters, needs {np}",
                cam.id,
                cam.model,
                cam.params.len()
            )));
        }
        out.extend(cam.id.to_le_bytes());
        out.extend(id.to_le_bytes());
        out.extend(cam.width.to_le_bytes());
        out.extend(cam.height.to_le_bytes());
        for v in &cam.params {
            out.extend(v.to_le_bytes());
        }
    }
    Ok(out)
}

/// One `cameras.bin` record.
fn bin_camera(b: &mut Bin, f: &dyn Fn() -> String) -> Result<Camera> {
    let id = b.u32(f)?;
    let model_id = b.i32(f)?;
    let (_, name, np) = crate::sparse::model_file_cameras()
        .find(|m| m.0 == model_id)
        .ok_or_else(|| bad(b.path, f(), format!("unknown camera model id {model_id}")))?;
    Ok(Camera {
        id,
        model: (*name).to_string(),
        width: b.u64(f)?,
        height: b.u64(f)?,
        params: (0..*np).map(|_| b.f64(f)).collect::<Result<Vec<_>>>()?,
    })
}

/// One `images.bin` record.
fn bin_image(b: &mut Bin, f: &dyn Fn() -> String) -> Result<Image> {
    Ok(Image {
        id: b.u32(f)?,
        qvec: [b.f64(f)?, b.f64(f)?, b.f64(f)?, b.f64(f)?],
        tvec: [b.f64(f)?, b.f64(f)?, b.f64(f)?],
        camera_id: b.u32(f)?,
        name: b.cstr(f)?,
        points2d: (0..b.count(24, f)?)
            .map(|_| {
                let (x, y, p) = (b.f64(f)?, b.f64(f)?, b.u64(f)?);
                // COLMAP writes an invalid id (-1) as u64::MAX.
                Ok((x, y, (p != u64::MAX).then_some(p)))
            })
            .collect::<Result<Vec<_>>>()?,
    })
}

/// One `points3D.bin` record.
fn bin_point(b: &mut Bin, f: &dyn Fn() -> String) -> Result<Point3D> {
    Ok(Point3D {
        id: b.u64(f)?,
        xyz: [b.f64(f)?, b.f64(f)?, b.f64(f)?],
        rgb: [b.u8(f)?, b.u8(f)?, b.u8(f)?],
        error: b.f64(f)?,
        track: (0..b.count(8, f)?)
            .map(|_| Ok((b.u32(f)?, b.u32(f)?)))
            .collect::<Result<Vec<_>>>()?,
    })
}

/// Lines of a text file that are not comments: (1-based line number, trimmed text).
fn text_lines(path: &Path) -> Result<Vec<(usize, String)>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    Ok(text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim().to_string()))
        .filter(|(_, l)| !l.starts_with('#'))
        .collect())
}

/// Text lines still to read (comments left out).
type Lines<'a> = std::slice::Iter<'a, (usize, String)>;

struct Fields<'a> {
    path: &'a PathBuf,
    line: usize,
    it: std::str::SplitWhitespace<'a>,
}

impl<'a> Fields<'a> {
    fn new(path: &'a PathBuf, line: usize, text: &'a str) -> Self {
        let it = text.split_whitespace();
        Fields { path, line, it }
    }
    fn next<T: std::str::FromStr>(&mut self, field: &str) -> Result<T> {
        let tok = self.it.next().ok_or_else(|| self.err(field, "missing"))?;
        tok.parse()
            .map_err(|_| self.err(field, &format!("cannot parse `{tok}`")))
    }
    fn rest(&mut self) -> Vec<&'a str> {
        self.it.by_ref().collect()
    }
    fn err(&self, field: &str, msg: &str) -> Error {
        Error::file(self.path, Some(self.line), "COLMAP model", field, msg)
    }
}

/// Reads `cameras.txt`, `images.txt` and `points3D.txt` from `dir`.
pub fn read_text(dir: &Path) -> Result<Model> {
    Ok(Model {
        cameras: read_txt(&dir.join("cameras.txt"), txt_camera, |c| c.id)?,
        images: read_txt(&dir.join("images.txt"), txt_image, |i| i.id)?,
        points: read_txt(&dir.join("points3D.txt"), txt_point, |p| p.id)?,
    })
}

/// Reads a text file whose records start on non-blank lines, keyed by id.
fn read_txt<K: Ord, V>(
    path: &PathBuf,
    record: fn(Fields, &mut Lines) -> Result<V>,
    key: fn(&V) -> K,
) -> Result<BTreeMap<K, V>> {
    let lines = text_lines(path)?;
    let mut it = lines.iter();
    let mut out = BTreeMap::new();
    while let Some((line, l)) = it.next() {
        if !l.is_empty() {
            let v = record(Fields::new(path, *line, l), &mut it)?;
            out.insert(key(&v), v);
        }
    }
    Ok(out)
}

/// One `cameras.txt` line.
fn txt_camera(mut f: Fields, _: &mut Lines) -> Result<Camera> {
    let id: u32 = f.next("CAMERA_ID")?;
    let model: String = f.next("MODEL")?;
    let width = f.next("WIDTH")?;
    let height = f.next("HEIGHT")?;
    let params = f
        .rest()
        .iter()
        .map(|t| t.parse::<f64>())
        .collect::<std::result::Result<Vec<_>, _>>()
        .map_err(|_| f.err("PARAMS", "not a number"))?;
    match crate::sparse::model_file_cameras().find(|m| m.1 == model) {
        Some(m) if m.2 == params.len() => {}
        Some(m) => {
            return Err(f.err("PARAMS", &format!("{model} needs {} parameters", m.2)));
        }
        None => return Err(f.err("MODEL", &format!("unknown camera model {model}"))),
    }
    Ok(Camera {
        id,
        model,
        width,
        height,
        params,
    })
}

/// One `images.txt` record: its line, then the 2D points line (which may be blank).
fn txt_image(mut f: Fields, lines: &mut Lines) -> Result<Image> {
    let id: u32 = f.next("IMAGE_ID")?;
    let qvec = [f.next("QW")?, f.next("QX")?, f.next("QY")?, f.next("QZ")?];
    let tvec = [f.next("TX")?, f.next("TY")?, f.next("TZ")?];
    let camera_id = f.next("CAMERA_ID")?;
    // Names may contain spaces: the rest of the line.
    let name = f.rest().join(" ");
    if name.is_empty() {
        return Err(f.err("NAME", "missing"));
    }
    let (pline, pl) = lines
        .next()
        .map(|(n, s)| (*n, s.as_str()))
        .unwrap_or((f.line + 1, ""));
    let points2d = txt_points2d(Fields::new(f.path, pline, pl))?;
    Ok(Image {
        id,
        qvec,
        tvec,
        camera_id,
        name,
        points2d,
    })
}

/// The `X Y POINT3D_ID` triples of an image's second line.
fn txt_points2d(mut g: Fields) -> Result<Vec<(f64, f64, Option<u64>)>> {
    let toks = g.rest();
    if !toks.len().is_multiple_of(3) {
        return Err(g.err("POINTS2D", "not a list of X Y POINT3D_ID triples"));
    }
    let num = |t: &str| {
        t.parse::<f64>()
            .map_err(|_| g.err("POINTS2D", "bad coordinate"))
    };
    toks.chunks(3)
        .map(|c| {
            let p: i64 = c[2]
                .parse()
                .map_err(|_| g.err("POINTS2D", "bad POINT3D_ID"))?;
            Ok((num(c[0])?, num(c[1])?, u64::try_from(p).ok()))
        })
        .collect()
}

/// One `points3D.txt` line.
fn txt_point(mut f: Fields, _: &mut Lines) -> Result<Point3D> {
    let id: u64 = f.next("POINT3D_ID")?;
    let xyz = [f.next("X")?, f.next("Y")?, f.next("Z")?];
    let rgb = [f.next("R")?, f.next("G")?, f.next("B")?];
    let error = f.next("ERROR")?;
    let toks = f.rest();
    if !toks.len().is_multiple_of(2) {
        return Err(f.err("TRACK", "not a list of IMAGE_ID POINT2D_IDX pairs"));
    }
    let track = toks
        .chunks(2)
        .map(|c| Some((c[0].parse().ok()?, c[1].parse().ok()?)))
        .collect::<Option<Vec<_>>>()
        .ok_or_else(|| f.err("TRACK", "not integers"))?;
    Ok(Point3D {
        id,
        xyz,
        rgb,
        error,
        track,
    })
}

/// The numbered model folders (`0/`, `1/`, …) under a `sparse/` root that hold a model, in
/// numeric order.
pub fn model_dirs(root: &Path) -> Result<Vec<PathBuf>> {
    let mut dirs: Vec<(u64, PathBuf)> = std::fs::read_dir(root)
        .map_err(|e| Error::io(root, e))?
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let n: u64 = e.file_name().to_str()?.parse().ok()?;
            let p = e.path();
            detect(&p).map(|_| (n, p))
        })
        .collect();
    dirs.sort();
    Ok(dirs.into_iter().map(|(_, p)| p).collect())
}
