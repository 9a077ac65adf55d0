//! `keyframer-bench-clip OUT --size WxH --fps N --seconds S`: makes one of the H.264 clips that
//! `keyframer bench pipeline` times (it runs this tool, found beside itself or on PATH).
//! Exit codes: 0 made (or already there), 1 error.

use clap::Parser;
use keyframer_scene::bench_clip::{make, ClipSettings};
use std::path::PathBuf;
use std::process::ExitCode;

/// Makes a benchmark clip: a pan over a photo with temporal noise, H.264 crf 23, yuv420p.
#[derive(Debug, Parser)]
#[command(name = "keyframer-bench-clip", version)]
struct Cli {
    /// Output clip (.mp4); left as it is when it exists. The texture is cached beside it.
    out: PathBuf,
    /// Frame size WxH.
    #[arg(long, default_value = "1920x1080")]
    size: String,
    /// Frame rate.
    #[arg(long, default_value_t = 30)]
    fps: u32,
    /// Length in seconds.
    #[arg(long, default_value_t = 60)]
    seconds: u32,
}

fn settings(cli: &Cli) -> keyframer::Result<ClipSettings> {
    let (width, height) = keyframer_scene::cli::parse_size(&cli.size)?;
    Ok(ClipSettings {
        out: cli.out.clone(),
        width,
        height,
        fps: cli.fps.max(1),
        seconds: cli.seconds.max(1),
    })
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
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
    match settings(&cli).and_then(|s| make(&s)) {
        Ok(_) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(1)
        }
    }
}
