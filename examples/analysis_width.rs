//! Experiment behind the default `--analysis-width`: movement between consecutive frames of a real
//! clip at several analysis widths, compared with the full-resolution movement (opencv backend),
//! with the time per frame pair. Run: `cargo run --release --example analysis_width -- CLIP`
//! (default: Debian's opencv-doc Megamind.avi fetched by scripts/setup.sh).

use keyframer::kernels::farneback;
use keyframer::kernels::movement;
use keyframer::params::{FarnebackParams, Statistic};
use opencv::core::Size;
use opencv::prelude::*;
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "target/testdata/opencv-doc/Megamind.avi".into());
    let mut src = keyframer::source::open(std::path::Path::new(&path), &Default::default())?;
    let (w, h) = (src.metadata().width, src.metadata().height);
    let mut frames = Vec::new();
    while let Some(f) = src.next_frame()? {
        if f.index % 3 == 0 && frames.len() < 120 {
            frames.push(keyframer::kernels::gray::opencv(&f.image)?);
        }
    }
    let p = FarnebackParams::default();
    let widths: Vec<u32> = [160u32, 240, 320, 480, 640, w]
        .into_iter()
        .filter(|&x| x <= w)
        .collect();
    let mut series = Vec::new();
    println!(
        "{path}: {w}x{h}, {} frame pairs (every 3rd frame)",
        frames.len() - 1
    );
    println!(
        "{:>6} {:>10} {:>22} {:>22}",
        "width", "ms/pair", "median rel. err vs full", "P90 rel. err vs full"
    );
    for &aw in widths.iter().rev() {
        let (sw, sh) = keyframer::analysis::analysis_size(w, h, aw);
        let small: Vec<Mat> = frames
            .iter()
            .map(|g| {
                if sw == w {
                    Ok(g.clone())
                } else {
                    keyframer::kernels::resize_area::opencv(g, Size::new(sw as i32, sh as i32))
                }
            })
            .collect::<keyframer::Result<_>>()?;
        let t = Instant::now();
        let mut v = Vec::new();
        for pair in small.windows(2) {
            let f = farneback::opencv(&pair[0], &pair[1], &p, None)?;
            v.push(
                movement::cpu(&movement::magnitudes(&f)?, Statistic::Median)? * f64::from(w)
                    / f64::from(sw),
            );
        }
        let ms = t.elapsed().as_secs_f64() * 1e3 / v.len() as f64;
        series.push((aw, ms, v));
    }
    let full = series[0].2.clone();
    for (aw, ms, v) in &series {
        let mut e: Vec<f64> = v
            .iter()
            .zip(&full)
            .filter(|(_, f)| **f > 0.05)
            .map(|(a, f)| (a - f).abs() / f)
            .collect();
        e.sort_by(f64::total_cmp);
        let q = |p: f64| {
            e.get(((e.len().max(1) - 1) as f64 * p) as usize)
                .copied()
                .unwrap_or(0.0)
        };
        println!("{aw:>6} {ms:>10.1} {:>22.3} {:>22.3}", q(0.5), q(0.9));
    }
    Ok(())
}
