//! Times the stages of the GPU Farneback + movement path at 640x480 (development aid).
use keyframer::kernels::farneback::{FarnebackGpu, FarnebackParams};
use keyframer::kernels::movement::{MovementGpu, Statistic};
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let a = opencv::imgcodecs::imread("target/testdata/opencv-doc/basketball1.png", 0)?;
    let b = opencv::imgcodecs::imread("target/testdata/opencv-doc/basketball2.png", 0)?;
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None)?);
    let mut f = FarnebackGpu::new(ctx.clone(), FarnebackParams::default(), 640, 480)?;
    let m = MovementGpu::new(ctx.clone(), f.flow_buffer(), 640, 480, None)?;
    let wait = || {
        ctx.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
    };
    for _ in 0..3 {
        let t = Instant::now();
        f.load(0, &a)?;
        wait()?;
        let t1 = t.elapsed();
        f.load(1, &b)?;
        wait()?;
        let t2 = t.elapsed();
        f.flow_between(0, 1)?;
        wait()?;
        let t3 = t.elapsed();
        let v = m.compute(Statistic::Median)?;
        let t4 = t.elapsed();
        println!(
            "load {:?} load {:?} flow {:?} median {:?} ({v})",
            t1,
            t2 - t1,
            t3 - t2,
            t4 - t3
        );
    }
    for levels in 0..4 {
        let p = FarnebackParams {
            levels,
            ..FarnebackParams::default()
        };
        let mut f = FarnebackGpu::new(ctx.clone(), p, 640, 480)?;
        f.load(0, &a)?;
        wait()?;
        let t = Instant::now();
        f.load(0, &a)?;
        wait()?;
        println!("levels {levels}: pyramid {:?}", t.elapsed());
    }
    let t = Instant::now();
    let _ = keyframer::kernels::farneback::opencv(&a, &b, &FarnebackParams::default(), None)?;
    println!("opencv {:?}", t.elapsed());
    Ok(())
}
