//! Export: re-decodes the selected frames in one sequential pass, crops then resizes them
//! (INTER_AREA), writes them atomically with sortable names (or the original names for image
//! folders, copied byte for byte when nothing changes them), and writes a manifest last. When the
//! project has telemetry positions, every JPEG it encodes carries its frame's position as EXIF
//! geotags and the manifest lists them (unless `geotag` is off); byte-copied originals keep their
//! own EXIF, PNGs get none.

use crate::encode::encode;
use crate::error::{CvContext, Error, Result};
use crate::fsutil;
use crate::geotag::{tag_jpeg, GeoTag};
use crate::manifest::{
    listed_files, ExportSettings, ExportedFrame, Format, Manifest, MaskSettings, MissingFrame,
    Resize, IMAGE_DIR, LAYOUT, MANIFEST, MASK_DIR, MAX_PIXELS, MAX_SIDE, OVERLAY_DIR, PENDING,
};
use crate::output::Inputs;
use crate::project::Project;
use crate::segment::Segmenter;
use crate::source::telemetry::{self, Camera, Position};
use crate::source::{self, OpenOptions, SourceKind};
use opencv::core::{Mat, Rect};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};

use std::path::{Path, PathBuf};
use time::OffsetDateTime;

/// Checks the crop against the frame and returns the output size.
pub fn output_size(settings: &ExportSettings, width: u32, height: u32) -> Result<(u32, u32)> {
    let (w, h) = match settings.crop {
        Some(c) => {
            if c.width == 0 || c.height == 0 {
                return Err(Error::param("crop", "width and height must be positive"));
            }
            if u64::from(c.x) + u64::from(c.width) > u64::from(width)
                || u64::from(c.y) + u64::from(c.height) > u64::from(height)
            {
                return Err(Error::param(
                    "crop",
                    format!(
                        "{},{},{},{} reaches outside the {width}x{height} frame",
                        c.x, c.y, c.width, c.height
                    ),
                ));
            }
            (c.width, c.height)
        }
        None => (width, height),
    };
    Ok(match settings.resize {
        None => (w, h),
        Some(Resize::Size { width, height }) => (width, height),
        Some(Resize::Scale(s)) => {
            let sw = (f64::from(w) * s).round() as u32;
            let sh = (f64::from(h) * s).round() as u32;
            if sw == 0 || sh == 0 {
                let msg = format!("{s} makes a {w}x{h} frame empty");
                return Err(Error::param("scale", msg));
            }
            (sw, sh)
        }
    })
}

/// Applies crop then resize to one frame.
pub fn transform(image: &Mat, settings: &ExportSettings, out: (u32, u32)) -> Result<Mat> {
    let cropped = match settings.crop {
        Some(c) => Mat::roi(
            image,
            Rect::new(c.x as i32, c.y as i32, c.width as i32, c.height as i32),
        )
        .cv(|| "crop".into())?
        .try_clone()
        .cv(|| "crop copy".into())?,
        None => image.clone(),
    };
    if (cropped.cols() as u32, cropped.rows() as u32) == out {
        return Ok(cropped);
    }
    let size = (out.0 as i32, out.1 as i32);
    crate::encode::resize(&cropped, size, imgproc::INTER_AREA)
        .cv(|| format!("resize to {}x{}", out.0, out.1))
}

/// Refuses an output size the encoders cannot write (before any memory is allocated for it).
fn check_size(settings: &ExportSettings, size: (u32, u32)) -> Result<()> {
    let (w, h) = size;
    if w > MAX_SIDE || h > MAX_SIDE || u64::from(w) * u64::from(h) > MAX_PIXELS {
        let flag = match settings.resize {
            Some(Resize::Scale(_)) => "scale",
            _ => "resize",
        };
        return Err(Error::param(
            flag,
            format!(
                "the exported images would be {w}x{h}; JPEG and PNG allow at most {MAX_SIDE} px a side and OpenCV at most 2^30 pixels: choose a smaller size"
            ),
        ));
    }
    Ok(())
}

/// Exports the keyframes of the project at `project_path` into `out` (`out/images/`,
/// `out/masks/`, `out/overlays/`, `out/manifest.json`). Everything is written into a hidden
/// staging folder first and moved into place only when every image succeeded, so a failed export
/// leaves the folder as it was.
pub fn export(
    project_path: &Path,
    out: &Path,
    settings: &ExportSettings,
    force: bool,
    quiet: bool,
) -> Result<Manifest> {
    let project = Project::load(project_path)?;
    let target = Target {
        out,
        force,
        records: &[],
        project_file: project_path,
    };
    export_project(&project, project_path, &target, settings, quiet)
}

/// Where [`export_project`] writes.
#[derive(Debug, Clone, Copy)]
pub struct Target<'a> {
    /// The export folder.
    pub out: &'a Path,
    /// Replace what keyframer wrote there.
    pub force: bool,
    /// Records of another keyframer command that also mark the folder as keyframer's (beside
    /// `manifest.json`): `reconstruct` exports into its own workspace.
    pub records: &'a [&'a str],
    /// The project file the manifest names.
    pub project_file: &'a Path,
}

/// Exports the keyframes of `project` (loaded from `read_from`, whose folder its input path is
/// relative to) as [`export`] does, into `target` (`reconstruct` exports its own keyframe set and
/// names the project file it writes).
pub fn export_project(
    project: &Project,
    read_from: &Path,
    target: &Target,
    settings: &ExportSettings,
    quiet: bool,
) -> Result<Manifest> {
    let (project_path, out, force) = (read_from, target.out, target.force);
    let input = project.input_path(project_path);
    check_fingerprint(project, &input)?;
    if !(1..=100).contains(&settings.quality) {
        return Err(Error::param("quality", "must be between 1 and 100"));
    }
    let mut src = source::open(&input, &OpenOptions::default())?;
    let meta = src.metadata().clone();
    let mut size = output_size(settings, meta.width, meta.height)?;
    check_size(settings, size)?;
    // A 360° project's views: checked (and their tables made) before anything is written.
    let rig = match &settings.views {
        Some(vs) => {
            settings.check_whole_frame()?;
            let views = crate::rig::views_of(vs, project.projection, (MAX_SIDE, MAX_PIXELS))?;
            if views.is_empty() {
                None
            } else {
                size = (vs.size, vs.size);
                Some(crate::rig::Rig::new(views, (meta.width, meta.height), vs)?)
            }
        }
        None => None,
    };
    let is_video = meta.kind == SourceKind::Video;
    let names = output_names(project, src.as_ref(), settings, is_video)?;
    let geo = geo_of(project, &input, src.as_ref(), settings, &names);
    // What the export reads: the project, its input and the mask model's files.
    let mut inputs = Inputs::none()
        .with("project", project_path)
        .with("the project's input", &input);
    if let Some(m) = &settings.masks {
        inputs.extend(&crate::model_desc::ModelDesc::load(&m.model)?.inputs);
    }
    // The model is loaded and checked before anything is written.
    let mut masker = settings.masks.as_ref().map(Masker::new).transpose()?;
    let mut records = vec![MANIFEST, PENDING, crate::rig::RIG_CONFIG];
    records.extend_from_slice(target.records);
    let dir = crate::output::prepare_dir(out, force, &records, &inputs)?;
    let job = Job {
        project,
        input: &input,
        settings,
        names: &names,
        size,
        quiet,
        geo: geo.as_ref(),
        rig: rig.as_ref(),
    };
    let result = stage_and_commit(&job, out, dir.is_new(), src.as_mut(), masker.as_mut());
    let (frames, missing) = match result {
        Ok(r) => r,
        Err(e) => {
            dir.abandon();
            return Err(e);
        }
    };
    let manifest = Manifest {
        tool: "keyframer".into(),
        tool_version: env!("CARGO_PKG_VERSION").into(),
        layout: LAYOUT,
        created_unix_s: fsutil::now_unix_s(),
        project: fsutil::absolute(target.project_file),
        source: fsutil::absolute(&input),
        source_kind: meta.kind,
        settings: settings.clone(),
        width: size.0,
        height: size.1,
        frames,
        missing,
        mask_ms_per_image: masker.as_ref().and_then(|m| m.seg.ms_per_image()),
        views: rig.as_ref().map(|r| r.views.clone()).unwrap_or_default(),
    };
    let rig_config = out.join(crate::rig::RIG_CONFIG);
    match &rig {
        Some(r) => fsutil::write_json(&rig_config, &crate::rig::rig_config(&r.views))?,
        None => {
            // A rig export's record of an earlier run here goes with its views.
            if crate::output::check_replaceable(&rig_config).is_ok() {
                let _ = std::fs::remove_file(&rig_config);
            }
        }
    }
    write_manifest(out, &manifest)?;
    let n = manifest
        .frames
        .iter()
        .filter(|f| f.position.is_none())
        .count();
    if geo.is_some() && n > 0 {
        log::warn!(
            "{n} of the {} exported images have no telemetry position (outside the telemetry's time span or without GPS tags): they carry no geotag and manifest.json lists no position for them",
            manifest.frames.len()
        );
    }
    Ok(manifest)
}

/// The geotags of the keyframes when the project has positions and `settings` wants them;
/// warns once that PNG images are not tagged.
fn geo_of<'a>(
    project: &'a Project,
    input: &Path,
    src: &dyn source::FrameSource,
    settings: &ExportSettings,
    names: &[String],
) -> Option<Geo<'a>> {
    let tel = project
        .cache
        .telemetry
        .as_ref()
        .filter(|_| settings.geotag)?;
    let is_video = src.metadata().kind == SourceKind::Video;
    if !byte_copy(src, settings, is_video) && names.iter().any(|n| format_of(n) == Format::Png) {
        log::warn!(
            "PNG images are not geotagged (EXIF inside PNG is a text chunk photogrammetry tools do not read); manifest.json lists their positions"
        );
    }
    Some(Geo::new(tel, &project.keyframes, input, src, is_video))
}

/// What the JPEGs of one export are geotagged with: the project's positions and what every frame
/// shares (the video's creation time, the camera).
struct Geo<'a> {
    /// One per frame of the input (the project's `cache.telemetry.positions`).
    positions: &'a [Option<Position>],
    /// Frame 0's capture time (the video's `creation_time`, UTC), when the container records one.
    created: Option<OffsetDateTime>,
    camera: Option<&'static Camera>,
    /// What each keyframe's ImageDescription names it (`frame N of NAME`), in keyframe order.
    sources: Vec<String>,
}

impl<'a> Geo<'a> {
    fn new(
        tel: &'a crate::project::TelemetryCache,
        keyframes: &[usize],
        input: &Path,
        src: &dyn source::FrameSource,
        is_video: bool,
    ) -> Geo<'a> {
        let created = match is_video.then(|| telemetry::creation_time(input)) {
            Some(Ok(Some(t))) => Some(t),
            Some(Ok(None)) => {
                log::warn!(
                    "{}: the container records no creation time, so the geotags carry no DateTimeOriginal",
                    input.display()
                );
                None
            }
            Some(Err(e)) => {
                log::warn!("{e}: the geotags carry no DateTimeOriginal");
                None
            }
            None => None,
        };
        let file_name = |p: &Path| {
            p.file_name()
                .unwrap_or(p.as_os_str())
                .to_string_lossy()
                .into_owned()
        };
        let sources = keyframes
            .iter()
            .map(|&i| {
                let name = match src.file_of(i) {
                    Some(f) if !is_video => file_name(f),
                    _ => file_name(input),
                };
                format!("frame {i} of {name}")
            })
            .collect();
        Geo {
            positions: &tel.positions,
            created,
            camera: tel.camera.as_deref().and_then(telemetry::camera_named),
            sources,
        }
    }

    fn position(&self, index: usize) -> Option<&'a Position> {
        self.positions.get(index).and_then(Option::as_ref)
    }

    /// The tag of keyframe number `k` (frame `p`'s position, shown at `timestamp_s`).
    fn tag(&self, k: usize, p: &Position, timestamp_s: Option<f64>) -> GeoTag {
        let taken = match (self.created, timestamp_s) {
            (Some(t0), Some(t)) if t.is_finite() => {
                Some(t0 + time::Duration::milliseconds((t * 1000.0).round() as i64))
            }
            _ => None,
        };
        GeoTag {
            lat_deg: p.lat_deg,
            lon_deg: p.lon_deg,
            alt_m: p.abs_alt_m,
            taken,
            focal_35mm: p.focal_35mm.or(self.camera.map(|c| c.focal_35mm)),
            // The table's cameras are all named `MAKE PRODUCT`; their photos' Model is the code.
            make: self
                .camera
                .and_then(|c| c.name.split_once(' '))
                .map(|(make, _)| make.to_string()),
            model: self
                .camera
                .and_then(|c| c.names.first())
                .map(|m| m.to_string()),
            source: self.sources.get(k).cloned().unwrap_or_default(),
        }
    }
}

/// The file name of every keyframe's image, checked: plain names, no two alike.
fn output_names(
    project: &Project,
    src: &dyn source::FrameSource,
    settings: &ExportSettings,
    is_video: bool,
) -> Result<Vec<String>> {
    let digits = (project.metadata.frame_count.max(1) - 1)
        .to_string()
        .len()
        .max(6);
    let format = settings.format.unwrap_or(Format::Jpg);
    let byte_copy = byte_copy(src, settings, is_video);
    let mut names = Vec::with_capacity(project.keyframes.len());
    let mut seen = std::collections::HashMap::new();
    for &i in &project.keyframes {
        let name = match src.file_of(i) {
            Some(p) if !is_video => {
                let stem = p.file_stem().unwrap_or_default();
                let ext = p.extension().unwrap_or_default().to_string_lossy();
                let keep = byte_copy
                    || (settings.format.is_none()
                        && matches!(ext.to_ascii_lowercase().as_str(), "jpg" | "jpeg" | "png"));
                let name = if keep {
                    p.file_name().unwrap_or_default().to_os_string()
                } else {
                    let mut n = stem.to_os_string();
                    n.push(format!(".{}", format.ext()));
                    n
                };
                name.into_string().map_err(|n| {
                    Error::frame(
                        p,
                        i,
                        format!(
                            "the file name {} is not valid UTF-8; rename it",
                            n.to_string_lossy()
                        ),
                    )
                })?
            }
            _ => format!("frame_{i:0digits$}.{}", format.ext()),
        };
        crate::output::plain_name(&name, &format!("image of frame {i}"), &project_input(src))?;
        if let Some(other) = seen.insert(name.clone(), i) {
            return Err(Error::output(
                &name,
                format!(
                    "frames {other} and {i} would both be exported under this name; give --format so that every name differs, or rename one of the files"
                ),
            ));
        }
        names.push(name);
    }
    Ok(names)
}

fn project_input(src: &dyn source::FrameSource) -> PathBuf {
    src.file_of(0)
        .and_then(Path::parent)
        .map(Path::to_path_buf)
        .unwrap_or_default()
}

/// Whether the image files can be copied as they are (image folder, no crop, resize or format
/// change).
fn byte_copy(src: &dyn source::FrameSource, settings: &ExportSettings, is_video: bool) -> bool {
    !is_video
        && settings.crop.is_none()
        && settings.resize.is_none()
        && settings.format.is_none_or(|f| {
            src.file_of(0).and_then(|p| p.extension()).is_some_and(|e| {
                let e = e.to_string_lossy().to_ascii_lowercase();
                e == f.ext() || (f == Format::Jpg && e == "jpeg")
            })
        })
}

/// The files keyframer's records say it wrote in an existing export folder: the manifest's, and
/// those of the journal of an interrupted export. A folder whose records cannot be read is refused
/// (keyframer could not tell what it wrote there).
fn own_files(out: &Path) -> Result<Vec<PathBuf>> {
    let refuse = |e: Error| {
        Error::output(
            out,
            format!(
                "{e}; keyframer cannot tell what it wrote in this folder, so it replaces nothing: choose a new --out"
            ),
        )
    };
    let mut files = Vec::new();
    let path = out.join(MANIFEST);
    if path.exists() {
        files = listed_files(&Manifest::load(&path).map_err(refuse)?.frames);
    }
    let journal = out.join(PENDING);
    let bad = |line, field: String, msg: String| {
        refuse(Error::file(&journal, line, "export journal", field, msg))
    };
    if journal.exists() {
        let text = crate::output::read_text(&journal).map_err(refuse)?;
        let listed: Vec<String> = serde_json::from_str(&text)
            .map_err(|e| bad(Some(e.line()), String::new(), e.to_string()))?;
        for (i, f) in listed.iter().enumerate() {
            let rel = crate::output::inside(f, &format!("[{i}]"), &journal).map_err(refuse)?;
            let top = (2..=3).contains(&rel.components().count())
                && [IMAGE_DIR, MASK_DIR, OVERLAY_DIR]
                    .iter()
                    .any(|d| rel.starts_with(d));
            if !top {
                let msg = "not a file of images/, masks/ or overlays/";
                return Err(bad(None, format!("[{i}]"), msg.into()));
            }
            files.push(rel);
        }
    }
    Ok(files)
}

/// Refuses to write over any file the earlier manifest does not list (a user's file) or that is
/// not a regular file.
fn check_targets(
    out: &Path,
    ours: &[PathBuf],
    names: &[String],
    settings: &ExportSettings,
    views: &[crate::equirect::View],
) -> Result<()> {
    let ours: std::collections::HashSet<&PathBuf> = ours.iter().collect();
    let mut targets = Vec::new();
    let rel: Vec<String> = if views.is_empty() {
        names.to_vec()
    } else {
        let mut rel = Vec::new();
        for v in views {
            rel.extend(names.iter().map(|n| format!("{}/{n}", v.name)));
        }
        rel
    };
    for n in &rel {
        targets.push(Path::new(IMAGE_DIR).join(n));
        if let Some(m) = &settings.masks {
            targets.push(Path::new(MASK_DIR).join(format!("{n}.png")));
            if m.overlay {
                targets.push(Path::new(OVERLAY_DIR).join(n));
            }
        }
    }
    for rel in targets {
        let p = out.join(&rel);
        crate::output::check_replaceable(&p)?;
        crate::output::check_name_len(&p)?;
        if p.exists() && !ours.contains(&rel) {
            return Err(Error::output(
                p,
                "exists but keyframer's manifest does not list it; keyframer never replaces files it did not write: move it away or choose another --out",
            ));
        }
    }
    for d in [IMAGE_DIR, MASK_DIR, OVERLAY_DIR] {
        // A real folder or nothing: a symbolic link would take the writes (and removals)
        // somewhere keyframer was not told to write.
        let p = out.join(d);
        if let Ok(m) = std::fs::symlink_metadata(&p) {
            if !m.file_type().is_dir() {
                return Err(Error::output(
                    p,
                    "exists and is not a folder (keyframer does not write through symbolic links inside its output): move it away",
                ));
            }
        }
    }
    Ok(())
}

/// Decodes, transforms, encodes (or copies) and segments every keyframe into `staging`.
#[allow(clippy::too_many_arguments)]
fn write_staged(
    job: &Job,
    src: &mut dyn source::FrameSource,
    staging: &Path,
    mut masker: Option<&mut Masker>,
) -> Result<(Vec<ExportedFrame>, Vec<MissingFrame>)> {
    let images = staging.join(IMAGE_DIR);
    std::fs::create_dir_all(&images).map_err(|e| Error::io(&images, e))?;
    if let Some(m) = masker.as_deref_mut() {
        m.create_dirs(staging)?;
    }
    let is_video = src.metadata().kind == SourceKind::Video;
    let bar = crate::progress::bar(job.project.keyframes.len() as u64, "export", job.quiet);
    let r = if job.rig.is_none() && byte_copy(src, job.settings, is_video) {
        copy_originals(job, src, &images, masker, &bar)
    } else {
        decode_and_encode(job, src, &images, masker, &bar)
    };
    bar.finish_and_clear();
    r
}

/// The keyframes' image files copied byte for byte (nothing changes them), damaged ones listed
/// as missing.
fn copy_originals(
    job: &Job,
    src: &mut dyn source::FrameSource,
    images: &Path,
    mut masker: Option<&mut Masker>,
    bar: &indicatif::ProgressBar,
) -> Result<(Vec<ExportedFrame>, Vec<MissingFrame>)> {
    let timestamps = job.project.cache.timestamps_s.as_deref();
    let mut frames = Vec::new();
    let mut missing = Vec::new();
    for (k, &index) in job.project.keyframes.iter().enumerate() {
        let from = src
            .file_of(index)
            .ok_or_else(|| Error::frame(job.input, index, "no such image in the folder"))?
            .to_path_buf();
        // A damaged file is never copied (OpenCV would read a cut JPEG as grey-filled).
        let damage = match src.damage_of(index) {
            Some(why) => Some(why.to_string()),
            None => source::check_image(&from).err().map(|why| {
                format!(
                    "frame {index} ({}): damaged image: {why}",
                    from.file_name().unwrap_or_default().to_string_lossy()
                )
            }),
        };
        if let Some(reason) = damage {
            missing.push(MissingFrame { index, reason });
            bar.inc(1);
            continue;
        }
        let name = &job.names[k];
        fsutil::copy_atomic(&from, &images.join(name))?;
        frames.push(ExportedFrame {
            index,
            timestamp_s: timestamps.and_then(|t| t.get(index).copied()),
            file: name.clone(),
            view: None,
            mask: None,
            overlay: None,
            position: job.geo.and_then(|g| g.position(index)).cloned(),
        });
        if let Some(m) = masker.as_deref_mut() {
            let img = imgcodecs::imread(&from, imgcodecs::IMREAD_COLOR)
                .cv(|| format!("read {}", from.display()))?;
            m.push((None, name.clone()), img, None, &mut frames)?;
        }
        bar.inc(1);
    }
    if let Some(m) = masker {
        m.flush(&mut frames)?;
    }
    Ok((frames, missing))
}

/// The keyframes decoded in one pass, cropped, resized and encoded; frames the input could not
/// give are listed as missing with the reason.
fn decode_and_encode(
    job: &Job,
    src: &mut dyn source::FrameSource,
    images: &Path,
    mut masker: Option<&mut Masker>,
    bar: &indicatif::ProgressBar,
) -> Result<(Vec<ExportedFrame>, Vec<MissingFrame>)> {
    let timestamps = job.project.cache.timestamps_s.as_deref();
    let total = job.project.keyframes.len();
    let mut frames = Vec::new();
    let mut missing = Vec::new();
    let result = source::read_indices(src, &job.project.keyframes, |frame| {
        let outputs: Vec<(Option<usize>, Mat)> = match job.rig {
            Some(r) => r
                .render(&frame.image)?
                .into_iter()
                .enumerate()
                .map(|(v, m)| (Some(v), m))
                .collect(),
            None => vec![(None, transform(&frame.image, job.settings, job.size)?)],
        };
        // Damaged frames are never passed here: find this frame's name by its index.
        let k = job
            .project
            .keyframes
            .binary_search(&frame.index)
            .map_err(|_| {
                Error::frame(
                    job.input,
                    frame.index,
                    "the source delivered a frame that was not asked for",
                )
            })?;
        let name = &job.names[k];
        let format = format_of(name);
        let timestamp_s = frame
            .timestamp_s
            .or_else(|| timestamps.and_then(|t| t.get(frame.index).copied()));
        let position = job.geo.and_then(|g| g.position(frame.index));
        for (v, img) in outputs {
            let view = v.and_then(|v| job.rig.map(|r| (v, r)));
            let folder = view.map(|(v, r)| r.views[v].name.clone());
            let dir = match &folder {
                Some(f) => images.join(f),
                None => images.to_path_buf(),
            };
            if folder.is_some() {
                std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
            }
            let path = dir.join(name);
            let mut bytes = encode(&img, format, job.settings.quality)?;
            if let (Some(g), Some(p), Format::Jpg) = (job.geo, position, format) {
                tag_jpeg(&path, &mut bytes, &g.tag(k, p, timestamp_s))?;
            }
            fsutil::write_atomic(&path, &bytes)?;
            let nadir = view.and_then(|(v, r)| r.nadir[v].clone());
            frames.push(ExportedFrame {
                index: frame.index,
                timestamp_s,
                file: name.clone(),
                view: folder.clone(),
                mask: None,
                overlay: None,
                position: position.cloned(),
            });
            match masker.as_deref_mut() {
                Some(m) => m.push((folder, name.clone()), img, nadir, &mut frames)?,
                None => {
                    if let (Some(mask), Some(f)) = (nadir, &folder) {
                        let masks = images.with_file_name(MASK_DIR).join(f);
                        std::fs::create_dir_all(&masks).map_err(|e| Error::io(&masks, e))?;
                        let mask_name = crate::segment::write_mask(&masks, name, &mask)?;
                        if let Some(last) = frames.last_mut() {
                            last.mask = Some(mask_name);
                        }
                    }
                }
            }
        }
        bar.inc(1);
        Ok(())
    })
    .and_then(|missing| {
        if let Some(m) = masker {
            m.flush(&mut frames)?;
        }
        Ok(missing)
    });
    let not_read = result.map_err(|e| {
        Error::output(
            job.input,
            format!(
                "{e}; export stopped after {} of {total} images; nothing was written",
                frames.len()
            ),
        )
    })?;
    let reason = src
        .decode_failure()
        .map(|(_, m)| m)
        .unwrap_or_else(|| "the stream ended before this frame".into());
    missing.extend(not_read.into_iter().map(|index| {
        MissingFrame {
            index,
            reason: src
                .damage_of(index)
                .map_or_else(|| reason.clone(), str::to_string),
        }
    }));
    Ok((frames, missing))
}

/// The format an exported image's name says (`.png`, else JPEG).
fn format_of(name: &str) -> Format {
    if name.ends_with(".png") {
        Format::Png
    } else {
        Format::Jpg
    }
}

/// Writes `manifest.json` atomically, then drops the journal: the manifest now lists exactly
/// what is in `out`.
fn write_manifest(out: &Path, manifest: &Manifest) -> Result<()> {
    fsutil::write_json(&out.join(MANIFEST), manifest)?;
    let _ = std::fs::remove_file(out.join(PENDING));
    Ok(())
}

/// Writes every image (and mask) into a staging folder inside `out`, then moves them into place
/// replacing only what keyframer wrote there before (`is_new`: `out` was just made).
fn stage_and_commit(
    job: &Job,
    out: &Path,
    is_new: bool,
    src: &mut dyn source::FrameSource,
    masker: Option<&mut Masker>,
) -> Result<(Vec<ExportedFrame>, Vec<MissingFrame>)> {
    let ours = if is_new { Vec::new() } else { own_files(out)? };
    let views = job.rig.map(|r| r.views.as_slice()).unwrap_or_default();
    check_targets(out, &ours, job.names, job.settings, views)?;
    for sub in [IMAGE_DIR, MASK_DIR, OVERLAY_DIR] {
        crate::output::clear_stale_temps_of(&out.join(sub), None);
    }
    let staging = out.join(format!(
        ".keyframer-staging-{}",
        crate::output::unique_suffix()
    ));
    std::fs::create_dir(&staging).map_err(|e| Error::io(&staging, e))?;
    let r = write_staged(job, src, &staging, masker).and_then(|(frames, missing)| {
        commit(out, &staging, &ours, &frames)?;
        Ok((frames, missing))
    });
    let _ = std::fs::remove_dir_all(&staging);
    r
}

/// One export's fixed inputs, shared by its stages.
struct Job<'a> {
    project: &'a Project,
    input: &'a Path,
    settings: &'a ExportSettings,
    /// The file name of each keyframe's image, in keyframe order.
    names: &'a [String],
    size: (u32, u32),
    quiet: bool,
    /// What the JPEGs are geotagged with (None: no positions or `geotag` off).
    geo: Option<&'a Geo<'a>>,
    /// A 360° project's views (images/<view>/, masks/<view>/), None for flat exports.
    rig: Option<&'a crate::rig::Rig>,
}

/// Moves the staged files into place and removes what the earlier manifest listed that this
/// export did not write.
fn commit(out: &Path, staging: &Path, ours: &[PathBuf], frames: &[ExportedFrame]) -> Result<()> {
    let new = listed_files(frames);
    let new_set: std::collections::HashSet<&PathBuf> = new.iter().collect();
    // The journal first: a kill while files move leaves records of everything that may be here.
    let mut journal: Vec<String> = ours
        .iter()
        .chain(new.iter())
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    journal.sort();
    journal.dedup();
    let text = serde_json::to_string(&journal)
        .map_err(|e| Error::output(out.join(PENDING), e.to_string()))?;
    fsutil::write_atomic(&out.join(PENDING), text.as_bytes())?;
    for rel in &new {
        let to = out.join(rel);
        if let Some(parent) = to.parent() {
            std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
        }
        let from = staging.join(rel);
        std::fs::rename(&from, &to).map_err(|e| Error::io(&to, e))?;
    }
    for rel in ours {
        if new_set.contains(rel) {
            continue;
        }
        let p = out.join(rel);
        if crate::output::check_replaceable(&p).is_err() {
            continue;
        }
        match std::fs::remove_file(&p) {
            Ok(()) => log::info!("removed {} from the earlier export", p.display()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => log::warn!("{}: cannot remove stale export: {e}", p.display()),
        }
        if rel.components().count() == 3 {
            // An earlier rig export's view folder goes once empty.
            if let Some(parent) = p.parent() {
                let _ = std::fs::remove_dir(parent);
            }
        }
    }
    for d in [MASK_DIR, OVERLAY_DIR] {
        // Empty masks/ or overlays/ folders left from an earlier export go.
        let _ = std::fs::remove_dir(out.join(d));
    }
    warn_unlisted(out, &new_set);
    Ok(())
}

/// Warns about the files beside the export's own that no record of keyframer lists (a user's,
/// or left by two older keyframers exporting here at once): kept, as keyframer removes only what
/// it wrote, but whatever reads the folder reads them too.
fn warn_unlisted(out: &Path, listed: &std::collections::HashSet<&PathBuf>) {
    for d in [IMAGE_DIR, MASK_DIR, OVERLAY_DIR] {
        let Ok(entries) = std::fs::read_dir(out.join(d)) else {
            continue;
        };
        let names: Vec<String> = entries
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| {
                let p = Path::new(d).join(n);
                !n.starts_with('.')
                    && !listed.contains(&p)
                    && !listed.iter().any(|l| l.starts_with(&p))
            })
            .collect();
        if let Some(first) = names.first() {
            log::warn!(
                "{}: {} file(s) that keyframer did not write by its records were kept ({first}{}); tools reading this folder will read them too: move them away",
                out.join(d).display(),
                names.len(),
                if names.len() > 1 { ", ..." } else { "" }
            );
        }
    }
}

/// Refuses to export when the input is no longer the one the project was made from.
pub fn check_fingerprint(project: &Project, input: &Path) -> Result<()> {
    let (kind, now) = crate::select::identify(input)?;
    if kind != project.input.kind || now != project.input.fingerprint {
        return Err(Error::input(
            input,
            "the input changed since the project was made (size, time or content differ); run select again",
        ));
    }
    Ok(())
}

/// Collects exported images into batches for the segmentation network and writes their masks
/// (and overlays) as each batch completes.
struct Masker {
    seg: Segmenter,
    overlay: bool,
    /// The staging folder receiving `masks/` and `overlays/`.
    out: PathBuf,
    /// (view folder, file name) of each queued image, with its view's nadir mask.
    names: Vec<(Option<String>, String, Option<Mat>)>,
    images: Vec<Mat>,
}

impl Masker {
    fn new(settings: &MaskSettings) -> Result<Masker> {
        let seg = Segmenter::new(settings)?;
        Ok(Masker {
            seg,
            overlay: settings.overlay,
            out: PathBuf::new(),
            names: Vec::new(),
            images: Vec::new(),
        })
    }

    fn create_dirs(&mut self, staging: &Path) -> Result<()> {
        self.out = staging.to_path_buf();
        for d in [Some(MASK_DIR), self.overlay.then_some(OVERLAY_DIR)]
            .iter()
            .flatten()
        {
            let d = self.out.join(d);
            std::fs::create_dir_all(&d).map_err(|e| Error::io(&d, e))?;
        }
        Ok(())
    }

    /// Queues one exported image (`name` in the export folder); runs a batch when full.
    fn push(
        &mut self,
        (view, name): (Option<String>, String),
        image: Mat,
        nadir: Option<Mat>,
        frames: &mut [ExportedFrame],
    ) -> Result<()> {
        self.names.push((view, name, nadir));
        self.images.push(image);
        if self.images.len() >= self.seg.batch() {
            self.flush(frames)?;
        }
        Ok(())
    }

    /// Segments the queued images and writes their masks, recording them in `frames`.
    fn flush(&mut self, frames: &mut [ExportedFrame]) -> Result<()> {
        if self.images.is_empty() {
            return Ok(());
        }
        let names = std::mem::take(&mut self.names);
        let images = std::mem::take(&mut self.images);
        let maps = self.seg.classify(&images)?;
        for (((view, name, nadir), image), map) in names.iter().zip(&images).zip(&maps) {
            let size = (image.cols() as u32, image.rows() as u32);
            let mut mask = self.seg.mask(map, size)?;
            if let Some(n) = nadir {
                mask = crate::rig::combine(&mask, n)?;
            }
            let dir = |d: &str| {
                let p = self.out.join(d);
                let p = view.as_ref().map_or(p.clone(), |v| p.join(v));
                std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
                Ok::<_, Error>(p)
            };
            let mask_name = crate::segment::write_mask(&dir(MASK_DIR)?, name, &mask)?;
            let overlay = if self.overlay {
                let o = self.seg.overlay(image, map)?;
                let bytes = encode(&o, format_of(name), 90)?;
                fsutil::write_atomic(&dir(OVERLAY_DIR)?.join(name), &bytes)?;
                Some(name.clone())
            } else {
                None
            };
            let is = |f: &&mut ExportedFrame| &f.file == name && &f.view == view;
            if let Some(f) = frames.iter_mut().rev().find(is) {
                f.mask = Some(mask_name);
                f.overlay = overlay;
            }
        }
        Ok(())
    }
}
