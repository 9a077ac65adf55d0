//! `keyframer-scene`: renders a synthetic drone sequence (video.mp4, poses.tum, scene.json); see
//! docs/scene.md. Exit codes: 0 success, 1 usage or error.

use clap::Parser;
use keyframer_scene::cli::SceneArgs;
use std::process::ExitCode;

fn main() -> ExitCode {
    keyframer::native::quiet_logs();
    let args = match SceneArgs::try_parse() {
        Ok(a) => a,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(1)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    let level = if args.quiet { "warn" } else { "info" };
    env_logger::Builder::from_env(
        env_logger::Env::default()
            .default_filter_or(format!("warn,keyframer={level},keyframer_scene={level}")),
    )
    .format_timestamp(None)
    .init();
    match args.settings().and_then(|s| keyframer_scene::generate(&s)) {
        Ok(r) => {
            eprintln!("{}", keyframer_scene::cli::summary(&r, &args.out));
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(1)
        }
    }
}
