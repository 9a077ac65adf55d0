//! The `keyframer` binary: parses flags, sets up logging, runs a command, maps the outcome to an
//! exit code (0 ok, 1 usage or input error, 2 partial failure).

use anyhow::Result;
mod cli;

use cli::{Cli, Command};
use keyframer::{analysis, equirect, gpu, source};
use std::process::ExitCode;

/// How a command ended when it did not fail outright: 0, or 2 when some of the work could not be
/// done (the rest was written).
fn partial_if(partial: bool) -> ExitCode {
    ExitCode::from(if partial { 2 } else { 0 })
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
        Ok(code) => code,
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

fn run(cli: Cli) -> Result<ExitCode> {
    let quiet = cli.quiet;
    match cli.command {
        Command::Info(a) => info(&a),
        Command::Probe(a) => probe(&a, quiet),
        Command::Score(a) => score(&a, quiet),
        Command::Flow(a) => flow(&a),
        Command::Bench(a) => bench(&a),
        Command::Select(a) => select(&a, quiet),
        Command::Segment(a) => segment(&a),
        Command::Colmap(a) => colmap(&a, quiet),
        Command::Reconstruct(a) => reconstruct(&a, quiet),
        Command::Eval(a) => eval(&a),
        Command::Report(a) => report(&a),
        Command::Review(a) => review(&a),
        Command::Run(a) => run_workflow(&a, quiet),
        Command::Workflow(cli::WorkflowCommand::Save(a)) => workflow_save(&a),
        Command::Workflow(cli::WorkflowCommand::Check(a)) => workflow_check(&a),
        Command::Export(a) => export(&a, quiet),
    }
}

fn info(a: &cli::InfoArgs) -> Result<ExitCode> {
    let i = keyframer::info::gather(a.adapter.as_deref());
    print_json_or(a.json, &i, keyframer::info::render)
}

/// Prints `value` as JSON (`--json`), else as the text `render` gives.
fn print_json_or<T: serde::Serialize>(
    json: bool,
    value: &T,
    render: fn(&T) -> String,
) -> Result<ExitCode> {
    if json {
        println!("{}", serde_json::to_string_pretty(value)?);
    } else {
        print!("{}", render(value));
    }
    Ok(ExitCode::SUCCESS)
}

fn bench(a: &cli::BenchArgs) -> Result<ExitCode> {
    use keyframer::bench;
    let ctx = || keyframer::gpu::GpuContext::new(a.adapter.as_deref()).map(std::sync::Arc::new);
    let text = match a.what {
        cli::BenchWhat::Pipeline => keyframer::bench_pipeline::run(&a.pipeline_settings())?,
        cli::BenchWhat::Review => keyframer::review::bench::review(&a.dir, a.review_frames)?,
        cli::BenchWhat::Flow => {
            let (ctx, pairs) = (ctx()?, a.frames.min(8));
            let rows = bench::flow(&ctx, pairs, &a.strip_rows)?;
            let host_pairs = a.frames.max(8);
            let host = bench::flow_host(host_pairs)?;
            bench::render_flow(&ctx.info.name, pairs, &rows)
                + "\n"
                + &bench::render_flow_host(host_pairs, &host)
        }
        cli::BenchWhat::Descriptor => {
            let ctx = ctx()?;
            let rows = bench::descriptor(&ctx, a.frames)?;
            bench::render_descriptor(&ctx.info.name, a.frames, &rows)
        }
        cli::BenchWhat::Remap => {
            let (ctx, frames) = (ctx()?, a.frames.min(8));
            let rows = bench::remap(&ctx, frames)?;
            bench::render_remap(&ctx.info.name, frames, &rows)
        }
        cli::BenchWhat::Sharpness => {
            let ctx = ctx()?;
            let rows = bench::sharpness(&ctx, a.frames, &a.strip_rows)?;
            bench::render_sharpness(&ctx.info.name, a.frames, &rows)
        }
    };
    print!("{text}");
    Ok(ExitCode::SUCCESS)
}

fn select(a: &cli::SelectArgs, quiet: bool) -> Result<ExitCode> {
    let settings = a.settings(quiet)?;
    let r = keyframer::select::select(&settings)?;
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
    for e in &p.decode_problems {
        eprintln!("warning: {}: {e}", settings.input.display());
    }
    Ok(partial_if(!p.decode_problems.is_empty()))
}

fn review(a: &cli::ReviewArgs) -> Result<ExitCode> {
    use keyframer::review::{http::Served, Review, ReviewSettings};
    let settings = ReviewSettings {
        project: a.project.clone(),
        export: a.export.clone(),
        port: a.port,
    };
    let served = Served::bind(Review::open(&settings)?, a.port.unwrap_or(0))?;
    let url = served.url();
    // The first line on stdout: scripts and tests read the address from it.
    println!("review: {url}");
    use std::io::Write;
    std::io::stdout().flush()?;
    eprintln!("review: serving {} (Ctrl-C stops)", a.project.display());
    let stopper = served.stopper();
    ctrlc::set_handler(move || stopper.stop())?;
    if a.open {
        if let Err(e) = std::process::Command::new("xdg-open").arg(&url).spawn() {
            eprintln!("warning: could not start a browser (xdg-open: {e}); open {url} yourself");
        }
    }
    served.run();
    eprintln!("review stopped");
    Ok(ExitCode::SUCCESS)
}

fn report(a: &cli::ReportArgs) -> Result<ExitCode> {
    let centres = (a.model.as_ref())
        .map(|m| keyframer::eval::camera_centres(m, a.export.as_deref()))
        .transpose()?;
    let north_up = (a.model.as_ref()).is_some_and(|m| keyframer::eval::is_georegistered(m));
    let camera = centres.map(|c| keyframer::report::CameraPath {
        points: (c.into_iter())
            .map(|(frame, centre)| keyframer::report::PathPoint { frame, centre })
            .collect(),
        north_up,
    });
    let r = keyframer::report::write_report(&a.project, &a.settings(), camera.as_ref())?;
    eprintln!(
        "report: {} keyframes, {} thumbnails -> {} (timeline {})",
        r.keyframes,
        r.thumbs,
        r.html.display(),
        r.timeline.display()
    );
    Ok(ExitCode::SUCCESS)
}

fn run_workflow(a: &cli::RunArgs, quiet: bool) -> Result<ExitCode> {
    let wf = keyframer::workflow::Workflow::load(&a.workflow)?;
    let settings = keyframer::batch::RunSettings {
        inputs: a.all_inputs()?,
        inputs_from: a.inputs_from.clone(),
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
    Ok(partial_if(reports.iter().any(|r| {
        !matches!(r.status, Status::Done | Status::Skipped)
    })))
}

fn workflow_save(a: &cli::WorkflowSaveArgs) -> Result<ExitCode> {
    let to = keyframer::workflow::save(&a.project, &a.export, &a.output, a.force)?;
    eprintln!("workflow -> {}", to.display());
    Ok(ExitCode::SUCCESS)
}

fn workflow_check(a: &cli::WorkflowCheckArgs) -> Result<ExitCode> {
    let wf = keyframer::workflow::Workflow::load(&a.workflow)?;
    eprintln!(
        "{}: ok ({} sampler steps, {} exports, {} reconstruct)",
        a.workflow.display(),
        wf.file.sample.len(),
        wf.exports.len(),
        wf.reconstructs.len()
    );
    Ok(ExitCode::SUCCESS)
}

fn export(a: &cli::ExportArgs, quiet: bool) -> Result<ExitCode> {
    let settings = a.settings()?;
    let m = keyframer::export::export(&a.project, &a.out, &settings, a.force, quiet)?;
    eprintln!(
        "exported {} images ({}x{}) -> {}",
        m.frames.len(),
        m.width,
        m.height,
        a.out.display()
    );
    if let (Some(ms), Some(s)) = (m.mask_ms_per_image, &m.settings.masks) {
        eprintln!(
            "masks: {} under {}/ ({} backend, {ms:.1} ms per image for the network)",
            m.frames.iter().filter(|f| f.mask.is_some()).count(),
            keyframer::manifest::MASK_DIR,
            s.backend
        );
    }
    for f in &m.missing {
        eprintln!("warning: frame {} not exported: {}", f.index, f.reason);
    }
    Ok(partial_if(!m.missing.is_empty()))
}

fn colmap(a: &cli::ColmapArgs, quiet: bool) -> Result<ExitCode> {
    let rec = keyframer::colmap::run(&a.settings(), quiet)?;
    print_json_or(a.json, &rec, keyframer::colmap::render)
}

fn reconstruct(a: &cli::ReconstructArgs, quiet: bool) -> Result<ExitCode> {
    let s = keyframer::reconstruct::run(&a.settings()?, quiet)?;
    print_json_or(a.json, &s, keyframer::reconstruct::render)
}

fn eval(a: &cli::EvalArgs) -> Result<ExitCode> {
    let r = keyframer::eval::evaluate(&a.settings())?;
    print_json_or(a.json, &r, keyframer::eval::render)
}

fn segment(a: &cli::SegmentArgs) -> Result<ExitCode> {
    let settings = a.settings();
    let r = keyframer::segment::segment_file(
        &settings,
        &a.image,
        &a.output,
        a.overlay.as_deref(),
        a.force,
    )?;
    eprintln!(
        "{}: {:.1}% hidden, network {:.1} ms ({}) -> {}",
        a.image.display(),
        100.0 * r.hidden_fraction,
        r.network_ms,
        settings.backend,
        a.output.display()
    );
    Ok(ExitCode::SUCCESS)
}

fn probe(a: &cli::ProbeArgs, quiet: bool) -> Result<ExitCode> {
    let options = source::OpenOptions {
        images_fps: a.images_fps,
        ..Default::default()
    };
    let bar = keyframer::progress::bar(0, "count", quiet);
    let source::Probe {
        metadata: meta,
        problems,
    } = source::probe(&a.input, &options, a.exact, |n| bar.set_position(n as u64))?;
    bar.finish_and_clear();
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
    Ok(partial_if(!problems.is_empty()))
}

fn score(a: &cli::ScoreArgs, quiet: bool) -> Result<ExitCode> {
    let open = source::OpenOptions::default();
    let size = {
        let m = source::open(&a.input, &open)?;
        (m.metadata().width, m.metadata().height)
    };
    let is_video = source::kind_of(&a.input)? == source::SourceKind::Video;
    let projection = equirect::resolve_projection(a.projection, &a.input, is_video, size)?;
    let rows = (projection == equirect::Projection::Equirect).then(|| {
        let band = keyframer::params::Rows::erp_band(size.1);
        log::info!(
            "360° input: scoring rows {}..{} (|latitude| < 45°)",
            band.first,
            band.first + band.count
        );
        band
    });
    let (backend, ctx) = gpu::resolve_backend(a.analysis.backend, a.analysis.adapter.as_deref());
    let request = analysis::Request {
        sharpness: vec![a.metric],
        sharpness_rows: rows,
        ..Default::default()
    };
    let r = gpu::or_opencv("the analysis", backend, ctx.as_ref(), |backend, ctx| {
        analysis::analyse(&a.input, &open, &request, backend, ctx, quiet, None)
    })?;
    let scores = &r.sharpness[0].1;
    let ts = r.timestamps_s.as_deref();
    if a.json {
        let v = serde_json::json!({
            "input": a.input,
            "metric": a.metric,
            "projection": projection,
            "rows": rows,
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
    Ok(partial_if(!r.problems.is_empty()))
}

fn flow(a: &cli::FlowArgs) -> Result<ExitCode> {
    let params = a.farneback.params();
    params.validate()?;
    let mut inputs = keyframer::output::Inputs::none()
        .with("first image", &a.a)
        .with("second image", &a.b);
    if let Some(i) = &a.initial {
        inputs.add("initial flow", i);
    }
    let _held = keyframer::output::check_file(&a.output, a.force, &inputs)?;
    let r = keyframer::flow::between_files(
        &a.a,
        &a.b,
        a.initial.as_deref(),
        &params,
        a.analysis.backend,
        a.analysis.adapter.as_deref(),
    )?;
    keyframer::flo::write(&a.output, &r.field)?;
    eprintln!(
        "flow ({}) -> {}: median magnitude {:.4} px",
        r.backend,
        a.output.display(),
        r.median_px
    );
    Ok(ExitCode::SUCCESS)
}
