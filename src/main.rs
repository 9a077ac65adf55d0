//! The `keyframer` binary: parses flags, sets up logging, runs a command, maps the outcome to an
//! exit code (0 ok, 1 usage or input error, 2 partial failure).

use anyhow::Result;
mod cli;

use cli::{Cli, Command};
use keyframer::{analysis, export, gpu, info, select, source};
use std::process::ExitCode;

/// How a command ended when it did not fail outright.
enum Outcome {
    Ok,
    /// Some of the work could not be done; the rest was written.
    Partial,
}

fn main() -> ExitCode {
    keep_frame_buffers();
    keyframer::native::quiet_logs();
    let parsed = {
        use clap::{CommandFactory, FromArgMatches};
        Cli::command()
            .try_get_matches()
            .and_then(|m| Ok((Cli::from_arg_matches(&m)?, m)))
    };
    let (cli, matches) = match parsed {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(1)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    let default_level = if cli.quiet { "warn" } else { "info" };
    env_logger::Builder::from_env(
        env_logger::Env::default().default_filter_or(format!("warn,keyframer={default_level}")),
    )
    .format_timestamp(None)
    .init();
    let outcome = run(cli);
    report_peak_memory();
    match outcome {
        Ok(Outcome::Ok) => ExitCode::SUCCESS,
        Ok(Outcome::Partial) => ExitCode::from(2),
        Err(e) => {
            // Library errors already carry their cause in the message; print it once. A
            // parameter the library names by its key is shown as the flag that set it.
            let e = match e.downcast::<keyframer::Error>() {
                Ok(keyframer::Error::Param { name, msg }) => {
                    let path = cli::command_path(&matches);
                    let name = cli::flag_for(&path, &name).unwrap_or(name);
                    anyhow::Error::new(keyframer::Error::Param { name, msg })
                }
                Ok(other) => anyhow::Error::new(other),
                Err(e) => e,
            };
            eprintln!("error: {e}");
            ExitCode::from(1)
        }
    }
}

/// With `KEYFRAMER_PEAK_RSS` set, prints `peak-rss-kib N` (the process's VmHWM) to stderr at
/// exit: how `bench pipeline` measures each analysis's peak memory.
fn report_peak_memory() {
    if std::env::var_os("KEYFRAMER_PEAK_RSS").is_none() {
        return;
    }
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    if let Some(kib) = status.lines().find_map(|l| {
        l.strip_prefix("VmHWM:")
            .map(|v| v.trim().trim_end_matches("kB").trim().to_string())
    }) {
        eprintln!("peak-rss-kib {kib}");
    }
}

/// Frames are multi-MiB buffers allocated and freed for every frame. glibc serves such sizes with
/// mmap/munmap by default, so every frame paid for fresh zeroed pages: on 300 frames of 1080p,
/// `select --blur` spent 7.8 s in the kernel against 0.2 s with these settings (same user time,
/// same peak memory). Freed blocks up to 256 MiB stay in the heap for the next frame.
fn keep_frame_buffers() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        const M_TRIM_THRESHOLD: std::ffi::c_int = -1;
        const M_MMAP_THRESHOLD: std::ffi::c_int = -3;
        extern "C" {
            fn mallopt(param: std::ffi::c_int, value: std::ffi::c_int) -> std::ffi::c_int;
        }
        // SAFETY: mallopt only tunes glibc's allocator; called before any other thread exists.
        unsafe {
            mallopt(M_MMAP_THRESHOLD, 64 << 20);
            mallopt(M_TRIM_THRESHOLD, 256 << 20);
        }
    }
}

fn run(cli: Cli) -> Result<Outcome> {
    let quiet = cli.quiet;
    match cli.command {
        Command::Info(a) => {
            let i = info::gather(a.adapter.as_deref());
            if a.json {
                println!("{}", serde_json::to_string_pretty(&i)?);
            } else {
                print!("{}", info::render(&i));
            }
            Ok(Outcome::Ok)
        }
        Command::Probe(a) => probe(&a, quiet),
        Command::Score(a) => score(&a, quiet),
        Command::Flow(a) => flow(&a),
        Command::Bench(a) => {
            if let cli::BenchWhat::Pipeline = a.what {
                print!(
                    "{}",
                    keyframer::bench_pipeline::run(&a.pipeline_settings())?
                );
                return Ok(Outcome::Ok);
            }
            let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(a.adapter.as_deref())?);
            match a.what {
                cli::BenchWhat::Pipeline => {}
                cli::BenchWhat::Flow => {
                    let pairs = a.frames.min(8);
                    let rows = keyframer::bench::flow(&ctx, pairs)?;
                    print!(
                        "{}",
                        keyframer::bench::render_flow(&ctx.info.name, pairs, &rows)
                    );
                }
                cli::BenchWhat::Sharpness => {
                    let rows = keyframer::bench::sharpness(&ctx, a.frames)?;
                    print!(
                        "{}",
                        keyframer::bench::render_sharpness(&ctx.info.name, a.frames, &rows)
                    );
                }
            }
            Ok(Outcome::Ok)
        }
        Command::Select(a) => {
            let settings = a.settings(quiet)?;
            let r = select::select(&settings)?;
            for line in &r.proposals {
                eprintln!("{line}");
            }
            let p = &r.project;
            eprintln!(
                "{} keyframes of {} frames -> {}{}",
                p.keyframes.len(),
                p.metadata.frame_count,
                settings.output.display(),
                if r.decoded {
                    ""
                } else {
                    " (cached frame data, nothing decoded)"
                }
            );
            Ok(if p.decode_problems.is_empty() {
                Outcome::Ok
            } else {
                for e in &p.decode_problems {
                    eprintln!("warning: {}: {e}", settings.input.display());
                }
                Outcome::Partial
            })
        }
        Command::Segment(a) => segment(&a),
        Command::Colmap(a) => colmap(&a, quiet),
        Command::Eval(a) => eval(&a),
        Command::Report(a) => {
            let camera = match &a.model {
                Some(m) => Some(keyframer::report::CameraPath {
                    points: keyframer::eval::camera_centres(m, a.export.as_deref())?
                        .into_iter()
                        .map(|(frame, centre)| keyframer::report::PathPoint { frame, centre })
                        .collect(),
                }),
                None => None,
            };
            let r = keyframer::report::write_report(&a.project, &a.settings(), camera.as_ref())?;
            eprintln!(
                "report: {} keyframes, {} thumbnails -> {} (timeline {})",
                r.keyframes,
                r.thumbs,
                r.html.display(),
                r.timeline.display()
            );
            Ok(Outcome::Ok)
        }
        Command::Run(a) => {
            let wf = keyframer::workflow::Workflow::load(&a.workflow)?;
            let settings = keyframer::batch::RunSettings {
                inputs: a.all_inputs()?,
                out: a.out.clone(),
                force: a.force,
                jobs: a.jobs,
                shard: a.shard,
                quiet,
            };
            let reports = keyframer::batch::run(&wf, &settings)?;
            eprint!("{}", keyframer::batch::table(&reports));
            if a.json {
                println!("{}", serde_json::to_string_pretty(&reports)?);
            }
            use keyframer::batch::Status;
            Ok(
                if reports
                    .iter()
                    .all(|r| matches!(r.status, Status::Done | Status::Skipped))
                {
                    Outcome::Ok
                } else {
                    Outcome::Partial
                },
            )
        }
        Command::Workflow(cli::WorkflowCommand::Save(a)) => {
            // Build the text, check that it loads (in memory), and only then write it.
            let text = keyframer::workflow::from_project(&a.project, &a.export)?;
            keyframer::workflow::Workflow::from_text(&a.output, text.clone()).map_err(|e| {
                anyhow::anyhow!(
                    "{}: cannot be saved as a workflow: {e}",
                    a.project.display()
                )
            })?;
            // Everything the save reads is an input: the project, its video or image folder, and
            // the export folders' manifests.
            let source = keyframer::project::Project::load(&a.project)?.input_path(&a.project);
            let manifests: Vec<std::path::PathBuf> = a
                .export
                .iter()
                .map(|e| e.join(keyframer::export::MANIFEST))
                .collect();
            let mut inputs: Vec<&std::path::Path> = vec![&a.project, &source];
            inputs.extend(manifests.iter().map(|m| m.as_path()));
            keyframer::output::check_file(&a.output, "-o", a.force, &inputs)?;
            keyframer::fsutil::write_atomic(&a.output, text.as_bytes())?;
            eprintln!("workflow -> {}", a.output.display());
            Ok(Outcome::Ok)
        }
        Command::Workflow(cli::WorkflowCommand::Check(a)) => {
            let wf = keyframer::workflow::Workflow::load(&a.workflow)?;
            eprintln!(
                "{}: ok ({} sampler steps, {} exports)",
                a.workflow.display(),
                wf.file.sample.len(),
                wf.exports().len()
            );
            Ok(Outcome::Ok)
        }
        Command::Export(a) => {
            let settings = a.settings()?;
            let r = export::export(&a.project, &a.out, &settings, a.force, quiet)?;
            let m = &r.manifest;
            eprintln!(
                "exported {} images ({}x{}) -> {}",
                m.frames.len(),
                m.width,
                m.height,
                a.out.display()
            );
            if let (Some(ms), Some(s)) = (m.mask_ms_per_image, &m.settings.masks) {
                eprintln!(
                    "masks: {} under {}/ ({:?} backend, {ms:.1} ms per image for the network)",
                    m.frames.iter().filter(|f| f.mask.is_some()).count(),
                    export::MASK_DIR,
                    s.backend
                );
            }
            if m.missing.is_empty() {
                Ok(Outcome::Ok)
            } else {
                for f in &m.missing {
                    eprintln!("warning: frame {} not exported: {}", f.index, f.reason);
                }
                Ok(Outcome::Partial)
            }
        }
    }
}

fn colmap(a: &cli::ColmapArgs, quiet: bool) -> Result<Outcome> {
    let rec = keyframer::colmap::run(&a.settings(), quiet)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rec)?);
    } else {
        print!("{}", keyframer::colmap::render(&rec));
    }
    Ok(Outcome::Ok)
}

fn eval(a: &cli::EvalArgs) -> Result<Outcome> {
    let r = keyframer::eval::evaluate(&a.settings())?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        print!("{}", keyframer::eval::render(&r));
    }
    Ok(Outcome::Ok)
}

fn segment(a: &cli::SegmentArgs) -> Result<Outcome> {
    use keyframer::segment::Segmenter;
    use keyframer::{fsutil, Error};
    use opencv::imgcodecs;
    use opencv::prelude::*;
    let settings = a.settings();
    // The description names the network (and config) files: inputs too.
    let desc = keyframer::segment::desc::ModelDesc::load(&a.model)?;
    let mut inputs: Vec<&std::path::Path> = vec![&a.image, &a.model, &desc.model];
    if let Some(c) = &desc.config {
        inputs.push(c);
    }
    keyframer::output::check_file(&a.output, "-o", a.force, &inputs)?;
    if let Some(o) = &a.overlay {
        keyframer::output::check_file(o, "--overlay", a.force, &inputs)?;
        if keyframer::output::resolve(o) == keyframer::output::resolve(&a.output) {
            return Err(Error::param("--overlay", "must differ from -o").into());
        }
    }
    let mut seg = Segmenter::new(&settings)?;
    let image = imgcodecs::imread(&a.image, imgcodecs::IMREAD_COLOR)
        .map_err(|e| Error::input(&a.image, e.message))?;
    if image.empty() {
        return Err(Error::input(&a.image, "not a readable image").into());
    }
    let maps = seg.classify(std::slice::from_ref(&image))?;
    let size = (image.cols() as u32, image.rows() as u32);
    let mask = seg.mask(&maps[0], size)?;
    let bytes = export::encode(&mask, export::Format::Png, 100)?;
    fsutil::write_atomic(&a.output, &bytes)?;
    if let Some(o) = &a.overlay {
        let ov = seg.overlay(&image, &maps[0])?;
        let png = o.extension().is_some_and(|e| e.eq_ignore_ascii_case("png"));
        let fmt = if png {
            export::Format::Png
        } else {
            export::Format::Jpg
        };
        fsutil::write_atomic(o, &export::encode(&ov, fmt, 90)?)?;
    }
    let hidden =
        opencv::core::count_non_zero(&mask).map_err(|e| Error::input(&a.output, e.message))?;
    let total = size.0 as f64 * size.1 as f64;
    eprintln!(
        "{}: {:.1}% hidden, network {:.1} ms ({:?}) -> {}",
        a.image.display(),
        100.0 * (1.0 - hidden as f64 / total),
        seg.ms_per_image().unwrap_or(0.0),
        settings.backend,
        a.output.display()
    );
    Ok(Outcome::Ok)
}

fn probe(a: &cli::ProbeArgs, quiet: bool) -> Result<Outcome> {
    let mut src = source::open(
        &a.input,
        &source::OpenOptions {
            images_fps: a.images_fps,
            ..Default::default()
        },
    )?;
    let mut meta = src.metadata().clone();
    let mut problems = Vec::new();
    if a.exact || (meta.frame_count == 0 && !meta.frame_count_exact) {
        let bar = keyframer::progress::bar(meta.frame_count as u64, "count", quiet);
        let scan = source::scan(src.as_mut(), |n| bar.set_position(n as u64))?;
        bar.finish_and_clear();
        meta.frame_count = scan.frame_count;
        meta.frame_count_exact = true;
        if let (Some(ts), Some(fps)) = (&scan.timestamps_s, meta.fps) {
            if let (Some(f), Some(l)) = (ts.first(), ts.last()) {
                meta.duration_s = Some(l - f + 1.0 / fps);
            }
        }
        problems.extend(scan.damaged.into_iter().map(|(_, m)| m));
        problems.extend(scan.failure.map(|(_, m)| m));
    }
    if a.json {
        let mut v = serde_json::to_value(&meta)?;
        v["path"] = serde_json::json!(a.input);
        v["decode_problems"] = serde_json::json!(problems);
        println!("{}", serde_json::to_string(&v)?);
    } else {
        println!("path:        {}", a.input.display());
        println!("kind:        {:?}", meta.kind);
        println!(
            "frames:      {}{}",
            meta.frame_count,
            if meta.frame_count_exact {
                ""
            } else {
                " (declared by the container; --exact counts)"
            }
        );
        match meta.fps {
            Some(f) => println!("fps:         {f:.3}"),
            None => println!("fps:         unknown"),
        }
        println!("resolution:  {}x{}", meta.width, meta.height);
        if let Some(d) = meta.duration_s {
            println!("duration:    {d:.3} s");
        }
        if let Some(c) = &meta.codec {
            println!("codec:       {c}");
        }
        println!("rotation:    {} deg", meta.rotation_deg);
        for p in &problems {
            println!("problem:     {p}");
        }
    }
    Ok(if problems.is_empty() {
        Outcome::Ok
    } else {
        Outcome::Partial
    })
}

fn score(a: &cli::ScoreArgs, quiet: bool) -> Result<Outcome> {
    let (backend, ctx) =
        gpu::resolve_backend(a.analysis.backend.into(), a.analysis.adapter.as_deref());
    let r = analysis::analyse(
        &a.input,
        &source::OpenOptions::default(),
        &analysis::Request {
            sharpness: vec![a.metric],
            ..Default::default()
        },
        backend,
        ctx.as_ref(),
        quiet,
    )?;
    let scores = &r.sharpness[0].1;
    let ts = r.timestamps_s.as_deref();
    if a.json {
        let v = serde_json::json!({
            "input": a.input,
            "metric": a.metric,
            "backend": r.backend,
            "width": r.metadata.width,
            "height": r.metadata.height,
            "frame_count": r.metadata.frame_count,
            "timestamps_s": ts,
            "scores": scores,
            "decode_problems": r.problems,
        });
        println!("{}", serde_json::to_string(&v)?);
    } else {
        use std::io::Write;
        let mut out = std::io::BufWriter::new(std::io::stdout().lock());
        for (i, s) in scores.iter().enumerate() {
            match ts.and_then(|t| t.get(i)) {
                Some(t) => writeln!(out, "{i}\t{t:.6}\t{s}")?,
                None => writeln!(out, "{i}\t\t{s}")?,
            }
        }
    }
    Ok(if r.problems.is_empty() {
        Outcome::Ok
    } else {
        Outcome::Partial
    })
}

fn flow(a: &cli::FlowArgs) -> Result<Outcome> {
    use keyframer::kernels::{farneback, movement};
    let params = a.farneback.params()?;
    {
        let mut inputs: Vec<&std::path::Path> = vec![&a.a, &a.b];
        if let Some(i) = &a.initial {
            inputs.push(i);
        }
        keyframer::output::check_file(&a.output, "-o", a.force, &inputs)?;
    }
    let read = |p: &std::path::Path| -> Result<opencv::core::Mat> {
        use opencv::prelude::*;
        if !p.is_file() {
            anyhow::bail!("{}: no such image file", p.display());
        }
        let m = opencv::imgcodecs::imread(
            p.to_str().unwrap_or_default(),
            opencv::imgcodecs::IMREAD_GRAYSCALE,
        )?;
        if m.empty() {
            anyhow::bail!("{}: cannot read as an image", p.display());
        }
        Ok(m)
    };
    let (ga, gb) = (read(&a.a)?, read(&a.b)?);
    {
        use opencv::prelude::*;
        if ga.size()? != gb.size()? {
            anyhow::bail!(
                "{} is {}x{} but {} is {}x{}; flow needs two images of one size",
                a.a.display(),
                ga.cols(),
                ga.rows(),
                a.b.display(),
                gb.cols(),
                gb.rows()
            );
        }
    }
    // The initial flow (OPTFLOW_USE_INITIAL_FLOW): a .flo of the images' size, checked before
    // any flow is computed.
    let initial = match &a.initial {
        Some(p) => {
            use opencv::prelude::*;
            Some(keyframer::flo::read_sized(
                p,
                ga.cols() as u32,
                ga.rows() as u32,
            )?)
        }
        None => None,
    };
    let (backend, ctx) =
        gpu::resolve_backend(a.analysis.backend.into(), a.analysis.adapter.as_deref());
    let field = match (backend, ctx) {
        (gpu::Backend::Gpu, Some(ctx)) => {
            use opencv::prelude::*;
            let mut f =
                farneback::FarnebackGpu::new(ctx, params, ga.cols() as u32, ga.rows() as u32)?;
            f.flow_from(&ga, &gb, initial.as_ref())?
        }
        _ => farneback::opencv(&ga, &gb, &params, initial.as_ref())?,
    };
    keyframer::flo::write(&a.output, &field)?;
    let mags = movement::magnitudes(&field)?;
    let median = movement::cpu(&mags, movement::Statistic::Median)?;
    eprintln!(
        "flow ({backend}) -> {}: median magnitude {median:.4} px",
        a.output.display()
    );
    Ok(Outcome::Ok)
}
