//! Times the stages of the GPU Farneback (development aid): per dispatch kind, ms per frame pair
//! (one pyramid + one flow, each dispatch waited for alone; CPU time of the process, which runs
//! lavapipe's threads), at the sizes and parameter sets of
//! `keyframer bench flow`, plus the whole pair streamed as `bench` runs it and OpenCV's time.
//! Usage: `cargo run --release --example profile_flow [WIDTHxHEIGHT ...]` (default 640x360).
use keyframer::kernels::farneback::{self, FarnebackGpu};
use std::time::Instant;

/// CPU time of all the process's threads (ms): lavapipe runs the dispatches on its own threads,
/// and CPU time is far less disturbed by other processes than wall time.
fn cpu_ms() -> f64 {
    let mut ns = 0u64;
    if let Ok(tasks) = std::fs::read_dir("/proc/self/task") {
        for t in tasks.flatten() {
            let stat = std::fs::read_to_string(t.path().join("schedstat")).unwrap_or_default();
            ns += stat
                .split_whitespace()
                .next()
                .and_then(|v| v.parse().ok())
                .unwrap_or(0);
        }
    }
    ns as f64 / 1e6
}

fn main() -> anyhow::Result<()> {
    env_logger::init();
    let sizes: Vec<(u32, u32)> = std::env::args()
        .skip(1)
        .filter_map(|a| {
            let (w, h) = a.split_once('x')?;
            Some((w.parse().ok()?, h.parse().ok()?))
        })
        .collect();
    let sizes = if sizes.is_empty() {
        vec![(640, 360)]
    } else {
        sizes
    };
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None)?);
    for (w, h) in sizes {
        let frames = keyframer::bench::flow_frames(w, h)?;
        let only = std::env::var("PROFILE_ONLY").unwrap_or_default();
        for (label, p) in keyframer::bench::flow_params() {
            if !label.starts_with(only.as_str()) {
                continue;
            }
            let mut f = FarnebackGpu::new(ctx.clone(), p, w, h)?;
            f.load(0, &frames[0])?;
            f.load(1, &frames[1])?;
            f.flow_between(0, 1)?;
            ctx.wait()?;
            let rounds = std::env::var("PROFILE_ROUNDS")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(5);
            let stages = f.profile(rounds, &cpu_ms)?;
            let (t, c0) = (Instant::now(), cpu_ms());
            for i in 0..rounds {
                let (from, to) = (i % 2, (i + 1) % 2);
                f.load(to, &frames[to])?;
                f.flow_between(from, to)?;
            }
            ctx.wait()?;
            let streamed = t.elapsed().as_secs_f64() * 1e3 / rounds as f64;
            let streamed_cpu = (cpu_ms() - c0) / rounds as f64;
            let (t, c) = (Instant::now(), cpu_ms());
            for _ in 0..rounds {
                farneback::opencv(&frames[0], &frames[1], &p, None)?;
            }
            let cv = t.elapsed().as_secs_f64() * 1e3 / rounds as f64;
            let cv_cpu = (cpu_ms() - c) / rounds as f64;
            println!(
                "{w}x{h} {label}: streamed {streamed:.1} ms/pair ({streamed_cpu:.1} ms CPU), opencv {cv:.1} ms ({cv_cpu:.1} ms CPU)"
            );
            let total: f64 = stages.iter().map(|s| s.2).sum();
            for (kind, n, ms) in &stages {
                println!("  {kind:>12}: {n:>3} dispatches {ms:>8.2} ms");
            }
            println!("  {:>12}: {total:>21.2} ms", "sum");
        }
    }
    Ok(())
}
