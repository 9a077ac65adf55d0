//! Development tools of keyframer, kept out of the product (this crate depends on the `keyframer`
//! library, never the other way round):
//!
//! - `keyframer-scene`: a synthetic drone flight, or a person's walk down a street ([`walk`]),
//!   rendered with wgpu through a pinhole or a 360° equirectangular camera ([`erp`]). Writes into
//!   an output folder, each file atomically and `scene.json` last: `video.mp4` (H.264, yuv420p,
//!   constant frame rate, `creation_time` set), `video.SRT` (DJI-style telemetry: every
//!   frame's true camera position as latitude/longitude/altitude, [`srt`]), `poses.tum` (one
//!   camera-to-world pose per video frame, at the frame's
//!   mid-shutter time i / fps) and `scene.json` (settings, intrinsics, hovers, fast turns,
//!   objects). The same settings and seed give the same poses and pixels.
//! - `keyframer-bench-clip`: the H.264 clips of `keyframer bench pipeline` ([`bench_clip`]).

pub mod bench_clip;
pub mod cli;
pub mod erp;
pub mod math;
pub mod path;
pub mod render;
pub mod srt;
pub mod walk;
pub mod world;

mod encode;

use erp::ErpCamera;
use keyframer::equirect::Projection;
use keyframer::error::{Error, Result};
use math::{Pose, V3};
use path::{Flight, Hover, Preset};
use render::{Instance, Intrinsics, Renderer, SceneData, SubSample};
use std::path::PathBuf;
use world::{Kind, Object, Terrain};

/// Yaw rate above which frames count as a fast turn (degrees per second).
pub const FAST_TURN_DEG_S: f64 = 30.0;
/// Shutter time as a fraction of the frame interval.
pub const SHUTTER: f64 = 0.5;
/// Focal length as a fraction of the image width (horizontal field of view about 71°).
pub const FOCAL_PER_WIDTH: f64 = 0.7;
/// Largest image motion (pixels) between neighbouring shutter sub-samples: a frame whose content
/// moves `m` px during the shutter gets `ceil(m / MAX_SUB_STEP_PX)` sub-samples, at most
/// `--blur-samples` (fewer sub-samples where the motion is small give the same image).
pub const MAX_SUB_STEP_PX: f64 = 1.25;
/// Direction towards the sun (world, unit length after normalisation).
const SUN: V3 = V3(0.45, -0.35, 0.82);

/// What to generate.
#[derive(Debug, Clone)]
pub struct SceneSettings {
    /// Output folder.
    pub out: PathBuf,
    /// Flight preset.
    pub preset: Preset,
    /// Length in seconds (None: the preset's default).
    pub seconds: Option<f64>,
    /// Frame rate.
    pub fps: f64,
    /// Image width (even).
    pub width: u32,
    /// Image height (even).
    pub height: u32,
    /// Seed of every random choice.
    pub seed: u64,
    /// Shutter sub-samples averaged per frame (motion blur); 1 = none.
    pub blur_samples: u32,
    /// Folder with the photos used as textures (Debian opencv-doc examples).
    pub textures: PathBuf,
    /// Add flat magenta marker squares at known positions (test aid).
    pub markers: bool,
    /// Replace the contents of a non-empty output folder.
    pub force: bool,
    /// No progress bar.
    pub quiet: bool,
    /// GPU adapter name part.
    pub adapter: Option<String>,
    /// Where the world origin is on Earth (for video.SRT).
    pub origin: srt::GeoOrigin,
    /// Camera pitch below the horizon of the survey presets, degrees (None: 45; 90: nadir).
    pub pitch_deg: Option<f64>,
    /// Camera model: pinhole, or 360° equirectangular (`width` = 2 `height`).
    pub projection: Projection,
}

/// An inclusive range of frame indices.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FrameRange {
    /// First frame.
    pub start_frame: usize,
    /// Last frame (inclusive).
    pub end_frame: usize,
}

/// A fast-turn segment.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FastTurn {
    /// Frames.
    #[serde(flatten)]
    pub frames: FrameRange,
    /// Largest yaw rate in it (degrees per second).
    pub max_yaw_rate_deg_s: f64,
}

/// The description written as scene.json.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SceneDescription {
    /// Always "keyframer-scene".
    pub generator: String,
    /// Version of the generator.
    pub version: String,
    /// Preset name.
    pub preset: Preset,
    /// Seed.
    pub seed: u64,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Frame rate (constant).
    pub fps: f64,
    /// Number of video frames (= lines of poses.tum).
    pub frame_count: usize,
    /// Sub-samples per frame.
    pub blur_samples: u32,
    /// Sub-samples actually rendered per frame: min, mean, max (see `MAX_SUB_STEP_PX`).
    pub sub_samples_rendered: [f64; 3],
    /// Exposure time (seconds), centred on each frame's timestamp.
    pub shutter_s: f64,
    /// What a pose's timestamp means.
    pub pose_time: String,
    /// Camera model of the frames: `pinhole` (see `intrinsics`) or `equirect` (360°, the
    /// conventions of keyframer's docs/360.md; the camera frame of poses.tum is the ERP's).
    pub projection: Projection,
    /// Pinhole camera (COLMAP PINHOLE, pixel centres at +0.5); absent for `equirect`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub intrinsics: Option<Intrinsics>,
    /// Conventions of poses.tum and the world.
    pub conventions: Conventions,
    /// Hover holds (frames whose whole shutter lies inside a hold).
    pub hovers: Vec<FrameRange>,
    /// Yaw-rate threshold of `fast_turns`.
    pub fast_turn_threshold_deg_s: f64,
    /// Segments whose yaw rate exceeds the threshold.
    pub fast_turns: Vec<FastTurn>,
    /// Camera speed over moving frames (m/s): min, max.
    pub speed_range_m_s: [f64; 2],
    /// Terrain description.
    pub terrain: TerrainInfo,
    /// Boxes: buildings, cars (with their loops), markers.
    pub objects: Vec<Object>,
    /// video.SRT: the world origin on Earth, the take-off point's world height (`rel_alt` is
    /// measured from it) and the 35 mm equivalent focal length written in every entry.
    pub telemetry: Telemetry,
}

/// What video.SRT was written with.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Telemetry {
    /// The world origin on Earth.
    pub origin: srt::GeoOrigin,
    /// World height of the take-off point, metres (`rel_alt` is measured from it).
    pub takeoff_z_m: f64,
    /// 35 mm equivalent focal length, millimetres.
    pub focal_35mm: f64,
    /// Date and time of frame 0 (also the video's creation_time).
    pub start_utc: String,
}

/// Axis conventions.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Conventions {
    /// poses.tum line format.
    pub poses: String,
    /// Camera axes.
    pub camera_axes: String,
    /// World axes.
    pub world_axes: String,
    /// Pixel coordinates.
    pub pixels: String,
}

/// Terrain facts.
#[derive(Debug, Clone, serde::Serialize)]
pub struct TerrainInfo {
    /// It covers [-half, half]² metres.
    pub half_size_m: f64,
    /// Grid cells per side.
    pub cells: usize,
    /// Lowest and highest terrain height (metres).
    pub height_range_m: [f64; 2],
    /// Photos of the texture patchwork.
    pub photos: Vec<String>,
    /// Direction towards the sun.
    pub sun: [f64; 3],
}

/// What `generate` reports.
#[derive(Debug, Clone)]
pub struct SceneReport {
    /// The description that was written.
    pub description: SceneDescription,
    /// Adapter used.
    pub adapter: String,
    /// Seconds spent rendering and encoding frames.
    pub render_seconds: f64,
}

fn validate(s: &SceneSettings) -> Result<f64> {
    if !(s.fps.is_finite() && s.fps > 0.0 && s.fps <= 240.0) {
        return Err(Error::param("--fps", "must be in (0, 240]"));
    }
    if s.width < 32 || s.height < 32 || s.width > 4096 || s.height > 4096 {
        return Err(Error::param(
            "--size",
            "width and height must be in 32..=4096",
        ));
    }
    if s.width % 2 != 0 || s.height % 2 != 0 {
        return Err(Error::param(
            "--size",
            "width and height must be even (yuv420p video)",
        ));
    }
    if s.blur_samples == 0 || s.blur_samples > 64 {
        return Err(Error::param("--blur-samples", "must be in 1..=64"));
    }
    if let Some(p) = s.pitch_deg {
        if s.preset == Preset::Orbit {
            return Err(Error::param(
                "--pitch",
                "the orbit looks at its point of interest; --pitch is for the survey presets",
            ));
        }
        if !(p > 0.0 && p <= 90.0) {
            return Err(Error::param(
                "--pitch",
                format!("must be in (0, 90], got {p}"),
            ));
        }
    }
    if s.projection == Projection::Equirect && s.width != 2 * s.height {
        return Err(Error::param(
            "--size",
            format!(
                "an equirect frame is 2:1 (e.g. 1024x512), got {}x{}",
                s.width, s.height
            ),
        ));
    }
    if s.pitch_deg.is_some() && s.preset == Preset::Walk {
        return Err(Error::param(
            "--pitch",
            "the walk's camera is level; --pitch is for the survey presets",
        ));
    }
    let seconds = s.seconds.unwrap_or(s.preset.default_seconds());
    if !(seconds.is_finite() && seconds > 0.0) {
        return Err(Error::param("--seconds", "must be positive"));
    }
    if (seconds * s.fps).round() < 1.0 {
        return Err(Error::param("--seconds", "gives no frame at this --fps"));
    }
    Ok(seconds)
}

/// Pose of every sub-sample of frame `i`: times spread evenly over the shutter, centred on i / fps.
fn sub_times(i: usize, fps: f64, k: u32) -> Vec<f64> {
    let t = i as f64 / fps;
    let shutter = SHUTTER / fps;
    (0..k)
        .map(|j| t + shutter * ((j as f64 + 0.5) / k as f64 - 0.5))
        .collect()
}

fn yaw(p: &Pose) -> f64 {
    p.rot[2].1.atan2(p.rot[2].0)
}

/// Where the camera goes: a drone's flight or a person's walk.
enum Route {
    Flight(Flight),
    Walk(walk::Walk),
}

impl Route {
    fn pose(&self, t: f64) -> Pose {
        match self {
            Route::Flight(f) => f.pose(t),
            Route::Walk(w) => w.pose(t),
        }
    }
    fn duration(&self) -> f64 {
        match self {
            Route::Flight(f) => f.duration(),
            Route::Walk(w) => w.duration(),
        }
    }
    /// Times the camera centre holds still.
    fn holds(&self) -> Vec<Hover> {
        match self {
            Route::Flight(f) => f.hovers().to_vec(),
            Route::Walk(w) => w.holds(),
        }
    }
    fn ground_track(&self, seconds: f64, step: f64) -> Vec<(f64, f64)> {
        match self {
            Route::Flight(f) => f.ground_track(seconds, step),
            Route::Walk(w) => w.ground_track(step),
        }
    }
}

/// The camera that turns a pose into an image.
enum Camera<'a> {
    Pinhole(Intrinsics),
    Equirect(&'a ErpCamera),
}

impl Camera<'_> {
    /// Directions (camera frame) of a coarse grid of pixels.
    fn sample_directions(&self, w: f64, h: f64) -> Vec<V3> {
        match self {
            Camera::Pinhole(k) => (0..25)
                .map(|g| {
                    let (u, v) = (
                        w * ((g % 5) as f64 + 0.5) / 5.0,
                        h * ((g / 5) as f64 + 0.5) / 5.0,
                    );
                    V3((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0).unit()
                })
                .collect(),
            Camera::Equirect(e) => e.sample_directions(),
        }
    }
    /// Image distance (pixels) between camera-frame points `a` and `b` (`None` where a pinhole
    /// camera has one of them behind it).
    fn shift(&self, a: V3, b: V3) -> Option<f64> {
        match self {
            Camera::Pinhole(k) => {
                if a.2 < 0.5 || b.2 < 0.5 {
                    return None;
                }
                let (ua, va) = k.project(a);
                let (ub, vb) = k.project(b);
                Some((ua - ub).hypot(va - vb))
            }
            Camera::Equirect(e) => {
                let cos = a.unit().dot(b.unit()).clamp(-1.0, 1.0);
                Some(cos.acos() * f64::from(e.width) / std::f64::consts::TAU)
            }
        }
    }
    /// Whether camera-frame point `q` is in (or near: 20 % of the size) a `w` x `h` image.
    fn sees(&self, q: V3, w: f64, h: f64) -> bool {
        match self {
            Camera::Pinhole(k) => {
                if q.2 < 0.5 {
                    return false;
                }
                let (u, v) = k.project(q);
                u >= -0.2 * w && u <= 1.2 * w && v >= -0.2 * h && v <= 1.2 * h
            }
            Camera::Equirect(_) => true,
        }
    }
}

fn instances(objects: &[Object], t: f64, terrain: &Terrain) -> Vec<Instance> {
    let mut v = vec![Instance::terrain()];
    for o in objects {
        let (c, yaw) = o.placement(t, terrain);
        let q = o.quadrant;
        let (rect, kind) = match o.kind {
            // A wall's part of the terrain texture: a 4 x 3 grid of 0.04-wide cells (see
            // scene.wgsl's wall_shift).
            Kind::Wall => (
                [
                    0.40 + 0.045 * (q % 4) as f32,
                    0.42 + 0.045 * (q / 4 % 3) as f32,
                    0.04,
                    0.04,
                ],
                3.0,
            ),
            Kind::Marker => ([0.0, 0.0, 0.5, 0.5], 2.0),
            _ => ([0.5 * (q % 2) as f32, 0.5 * (q / 2) as f32, 0.5, 0.5], 1.0),
        };
        let tint = [o.tint[0] as f32, o.tint[1] as f32, o.tint[2] as f32, kind];
        v.push(Instance::boxed(c, yaw, o.size, rect, tint));
    }
    v
}

/// Where the ray from `pose` along camera-frame direction `d` first meets the terrain (marching
/// 1 m steps).
fn ray_hit(pose: &Pose, d: V3, terrain: &Terrain) -> Option<V3> {
    let r = &pose.rot;
    let dir = r[0] * d.0 + r[1] * d.1 + r[2] * d.2;
    (1..1500)
        .map(|t| pose.centre + dir * t as f64)
        .find(|p| p.2 <= terrain.height(p.0, p.1))
}

/// Largest image displacement (pixels) of the visible content between the start and the end of
/// frame `i`'s shutter: terrain points seen through a coarse grid of pixels, and the visible cars.
fn shutter_motion(
    i: usize,
    s: &SceneSettings,
    route: &Route,
    terrain: &Terrain,
    objects: &[Object],
    cam: &Camera,
) -> f64 {
    let t = i as f64 / s.fps;
    let half = 0.5 * SHUTTER / s.fps;
    let (pa, pm, pb) = (route.pose(t - half), route.pose(t), route.pose(t + half));
    let (w, h) = (s.width as f64, s.height as f64);
    let mut m: f64 = 0.0;
    for d in cam.sample_directions(w, h) {
        if let Some(p) = ray_hit(&pm, d, terrain) {
            m = m.max(cam.shift(pa.to_camera(p), pb.to_camera(p)).unwrap_or(0.0));
        }
    }
    for o in objects.iter().filter(|o| o.path.is_some()) {
        let (c, _) = o.placement(t, terrain);
        if !cam.sees(pm.to_camera(c), w, h) {
            continue;
        }
        let (a, _) = o.placement(t - half, terrain);
        let (b, _) = o.placement(t + half, terrain);
        m = m.max(cam.shift(pa.to_camera(a), pb.to_camera(b)).unwrap_or(0.0));
    }
    m
}

/// One TUM line: `timestamp tx ty tz qx qy qz qw`.
pub fn tum_line(t: f64, p: &Pose) -> String {
    let q = p.quaternion();
    format!(
        "{t:.6} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}\n",
        p.centre.0, p.centre.1, p.centre.2, q[0], q[1], q[2], q[3]
    )
}

/// The files a scene folder holds (scene.json last).
const FILES: [&str; 4] = ["video.mp4", "video.SRT", "poses.tum", "scene.json"];

/// Generates the sequence described by `s`.
pub fn generate(s: &SceneSettings) -> Result<SceneReport> {
    let seconds = validate(s)?;
    let textures = keyframer::output::Inputs::none().with("textures", &s.textures);
    let dir = keyframer::output::prepare_dir(&s.out, s.force, &["scene.json"], &textures)?;
    let r = (|| {
        for name in FILES {
            keyframer::output::check_replaceable(&s.out.join(name))?;
        }
        check_sidecar_is_ours(&s.out)?;
        render_scene(s, seconds)
    })();
    if r.is_err() && dir.is_new() {
        // A folder this run made is removed again with what it holds (only our files).
        for name in FILES {
            let _ = std::fs::remove_file(s.out.join(name));
        }
        dir.abandon();
    }
    r
}

/// A scene folder made before video.SRT existed records no `telemetry` in its scene.json: a
/// video.SRT there is someone else's, and is refused rather than replaced.
fn check_sidecar_is_ours(out: &std::path::Path) -> Result<()> {
    let srt = out.join("video.SRT");
    let Ok(text) = std::fs::read_to_string(out.join("scene.json")) else {
        return Ok(());
    };
    let recorded = serde_json::from_str::<serde_json::Value>(&text)
        .map(|v| v.get("telemetry").is_some())
        .unwrap_or(false);
    if srt.exists() && !recorded {
        return Err(Error::output(
            &srt,
            "its scene.json records no telemetry, so keyframer-scene did not write it; move it \
             away to replace this scene",
        ));
    }
    Ok(())
}

/// Renders the sequence into the prepared folder `s.out`.
fn render_scene(s: &SceneSettings, seconds: f64) -> Result<SceneReport> {
    let frames = (seconds * s.fps).round() as usize;
    let terrain = match s.preset {
        Preset::Walk => Terrain::new(s.seed).levelled(walk::STREET_CENTRE, 30.0, 40.0),
        _ => Terrain::new(s.seed),
    };
    let route = if s.preset == Preset::Walk {
        Route::Walk(walk::Walk::new(&terrain))
    } else {
        let mut flight = Flight::new(s.preset, seconds, s.seed, &|x, y| terrain.height(x, y));
        if let Some(p) = s.pitch_deg {
            flight = flight.with_camera_pitch(p);
        }
        Route::Flight(flight)
    };
    let last_t = (frames - 1) as f64 / s.fps + 0.5 * SHUTTER / s.fps;
    if last_t > route.duration() {
        return Err(Error::param(
            "--seconds",
            format!(
                "the {} path lasts {:.1} s; ask for at most that",
                s.preset.name(),
                route.duration()
            ),
        ));
    }
    let track = route.ground_track(seconds, 5.0);
    let objects = match s.preset {
        Preset::Walk => {
            let mut v = walk::street(s.seed, &terrain);
            v.extend(
                world::objects(s.seed, &terrain, &track, s.markers)
                    .into_iter()
                    .filter(|o| o.kind == Kind::Marker),
            );
            v
        }
        _ => world::objects(s.seed, &terrain, &track, s.markers),
    };
    let t0 = std::time::Instant::now();
    log::info!("building textures from {}", s.textures.display());
    let terrain_tex = world::terrain_texture(&s.textures, s.seed, world::TERRAIN_TEX)?;
    let atlas = world::atlas(&s.textures)?;
    log::info!("textures built in {:.1} s", t0.elapsed().as_secs_f64());
    let (tv, ti) = terrain.mesh();
    let (bv, bi) = world::box_mesh();
    // The product asks for downlevel limits (2048-texel textures); the terrain texture and large
    // frames need more. Asking for no more than the adapter has leaves the error to the renderer,
    // which names the size it needs.
    let erp = (s.projection == Projection::Equirect).then(|| ErpCamera::new(s.width));
    let (rw, rh) = match &erp {
        Some(e) => (e.face_size, e.face_size),
        None => (s.width, s.height),
    };
    let texels = world::TERRAIN_TEX.max(rw).max(rh);
    let ctx = keyframer::gpu::GpuContext::with_limits(s.adapter.as_deref(), |limits, have| {
        limits.max_texture_dimension_2d = limits
            .max_texture_dimension_2d
            .max(texels.min(have.max_texture_dimension_2d));
    })?;
    let data = SceneData {
        terrain: (&tv, &ti),
        boxes: (&bv, &bi),
        terrain_tex: &terrain_tex,
        atlas: &atlas,
        instances: 1 + objects.len() as u32,
    };
    let renderer = Renderer::new(&ctx, &data, rw, rh, s.blur_samples)?;
    log::info!("renderer ready after {:.1} s", t0.elapsed().as_secs_f64());
    drop(terrain_tex);
    drop(atlas);
    let k = match &erp {
        Some(e) => e.intrinsics(),
        None => Intrinsics {
            fx: FOCAL_PER_WIDTH * s.width as f64,
            fy: FOCAL_PER_WIDTH * s.width as f64,
            cx: 0.5 * s.width as f64,
            cy: 0.5 * s.height as f64,
        },
    };
    let cam = match &erp {
        Some(e) => Camera::Equirect(e),
        None => Camera::Pinhole(k),
    };
    let sun = SUN.unit();
    let sun4 = [sun.0 as f32, sun.1 as f32, sun.2 as f32, 0.0];
    let video = s.out.join("video.mp4");
    let mut enc = encode::Encoder::start(&video, s.width, s.height, s.fps, srt::START_UTC)?;
    let first = route.pose(0.0).centre;
    let telemetry = Telemetry {
        origin: s.origin,
        takeoff_z_m: terrain.height(first.0, first.1),
        // fx / width = f35 / 36 mm.
        focal_35mm: FOCAL_PER_WIDTH * 36.0,
        start_utc: srt::START_UTC.into(),
    };
    let mut sidecar = String::new();
    let bar = keyframer::progress::bar(frames as u64, "render", s.quiet);
    let started = std::time::Instant::now();
    let mut tum = String::new();
    let mut yaw_rates = Vec::with_capacity(frames);
    let mut speeds = Vec::with_capacity(frames);
    let mut sub_counts = Vec::with_capacity(frames);
    let chunks = terrain.chunk_bounds();
    for i in 0..frames {
        let motion = shutter_motion(i, s, &route, &terrain, &objects, &cam);
        let count = ((motion / MAX_SUB_STEP_PX).ceil() as u32).clamp(1, s.blur_samples);
        sub_counts.push(count);
        let times = sub_times(i, s.fps, count);
        let subs = |face: Option<usize>| -> Vec<SubSample> {
            times
                .iter()
                .map(|&t| {
                    let pose = route.pose(t);
                    let pose = match (&erp, face) {
                        (Some(e), Some(f)) => e.face_pose(&pose, f),
                        _ => pose,
                    };
                    SubSample {
                        clip: render::clip_matrix(&pose, &k, rw, rh),
                        instances: instances(&objects, t, &terrain),
                        terrain: render::visible_chunks(&pose, &k, rw, rh, &chunks),
                    }
                })
                .collect()
        };
        let rgba = match &erp {
            Some(e) => {
                let faces = (0..e.faces())
                    .map(|f| renderer.frame(&subs(Some(f)), sun4))
                    .collect::<Result<Vec<_>>>()?;
                e.resample(&faces)
            }
            None => renderer.frame(&subs(None), sun4)?,
        };
        enc.write(&rgba)?;
        let t = i as f64 / s.fps;
        let pose = route.pose(t);
        tum.push_str(&tum_line(t, &pose));
        sidecar.push_str(&srt::entry(i, s.fps, &pose, &telemetry));
        let h = 0.01;
        let (a, b) = (route.pose(t - h), route.pose(t + h));
        let mut d = yaw(&b) - yaw(&a);
        d = (d + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
        yaw_rates.push((d / (2.0 * h)).to_degrees().abs());
        speeds.push((b.centre - a.centre).norm() / (2.0 * h));
        bar.inc(1);
    }
    bar.finish_and_clear();
    enc.finish()?;
    let render_seconds = started.elapsed().as_secs_f64();
    let sub_total: u64 = sub_counts.iter().map(|&c| c as u64).sum();
    keyframer::fsutil::write_atomic(&s.out.join("poses.tum"), tum.as_bytes())?;
    keyframer::fsutil::write_atomic(&s.out.join("video.SRT"), sidecar.as_bytes())?;

    let half_shutter = 0.5 * SHUTTER / s.fps;
    let hovers = route
        .holds()
        .iter()
        .filter_map(|h| {
            let inside: Vec<usize> = (0..frames)
                .filter(|&i| {
                    let t = i as f64 / s.fps;
                    t - half_shutter >= h.t0 && t + half_shutter <= h.t1
                })
                .collect();
            Some(FrameRange {
                start_frame: *inside.first()?,
                end_frame: *inside.last()?,
            })
        })
        .collect();
    let mut fast_turns: Vec<FastTurn> = Vec::new();
    for (i, &r) in yaw_rates.iter().enumerate() {
        if r < FAST_TURN_DEG_S {
            continue;
        }
        match fast_turns.last_mut() {
            Some(f) if f.frames.end_frame + 1 == i => {
                f.frames.end_frame = i;
                f.max_yaw_rate_deg_s = f.max_yaw_rate_deg_s.max(r);
            }
            _ => fast_turns.push(FastTurn {
                frames: FrameRange {
                    start_frame: i,
                    end_frame: i,
                },
                max_yaw_rate_deg_s: r,
            }),
        }
    }
    for f in &mut fast_turns {
        f.max_yaw_rate_deg_s = (f.max_yaw_rate_deg_s * 100.0).round() / 100.0;
    }
    let moving: Vec<f64> = speeds.iter().copied().filter(|&v| v > 0.05).collect();
    let lo = terrain.heights.iter().copied().fold(f32::MAX, f32::min) as f64;
    let hi = terrain.heights.iter().copied().fold(f32::MIN, f32::max) as f64;
    let round2 = |v: f64| (v * 100.0).round() / 100.0;
    let description = SceneDescription {
        generator: "keyframer-scene".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        preset: s.preset,
        seed: s.seed,
        width: s.width,
        height: s.height,
        fps: s.fps,
        frame_count: frames,
        blur_samples: s.blur_samples,
        sub_samples_rendered: [
            sub_counts.iter().copied().min().unwrap_or(0) as f64,
            round2(sub_total as f64 / frames as f64),
            sub_counts.iter().copied().max().unwrap_or(0) as f64,
        ],
        shutter_s: SHUTTER / s.fps,
        pose_time:
            "mid-shutter: frame i is exposed over [i/fps - shutter_s/2, i/fps + shutter_s/2] \
                    (1 to blur_samples renders spread evenly over it and averaged: as many as keep the image motion between neighbouring renders under 1.25 px); its pose is at i/fps"
                .into(),
        projection: s.projection,
        intrinsics: erp.is_none().then_some(k),
        conventions: Conventions {
            poses: "poses.tum: `timestamp tx ty tz qx qy qz qw` per video frame, timestamp = \
                    frame index / fps; camera-to-world: t is the camera centre in the world, q \
                    rotates camera axes into world axes (Hamilton, w last)"
                .into(),
            camera_axes: "OpenCV / COLMAP: x right, y down, z viewing direction".into(),
            world_axes: "x east, y north, z up; metres".into(),
            pixels: "COLMAP: image top-left corner at (0, 0), pixel (i, j) centred at \
                     (i + 0.5, j + 0.5); u = fx x/z + cx, v = fy y/z + cy"
                .into(),
        },
        hovers,
        fast_turn_threshold_deg_s: FAST_TURN_DEG_S,
        fast_turns,
        speed_range_m_s: [
            round2(moving.iter().copied().fold(f64::MAX, f64::min).min(1e9)),
            round2(moving.iter().copied().fold(0.0, f64::max)),
        ],
        terrain: TerrainInfo {
            half_size_m: world::HALF,
            cells: world::CELLS,
            height_range_m: [round2(lo), round2(hi)],
            photos: world::TERRAIN_PHOTOS
                .iter()
                .map(|p| p.to_string())
                .collect(),
            sun: [sun.0, sun.1, sun.2],
        },
        objects,
        telemetry,
    };
    let json = serde_json::to_string_pretty(&description)
        .map_err(|e| Error::gpu(format!("scene.json: {e}")))?;
    keyframer::fsutil::write_atomic(&s.out.join("scene.json"), json.as_bytes())?;
    Ok(SceneReport {
        description,
        adapter: ctx.info.name.clone(),
        render_seconds,
    })
}
