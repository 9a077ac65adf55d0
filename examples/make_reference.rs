//! Regenerates `reference/`: synthetic inputs and OpenCV's sharpness scores for every input, one
//! JSON file per (input, metric), named `<input file>__<metric>.json`; the similarity step's
//! descriptor totals (OpenCV twin) of every input at the analysis width 320,
//! `descriptor/<input file>.json`; golden remap views (see `remap_views`).
//!
//! Run from the repository root: `cargo run --release --example make_reference`

use keyframer::kernels::descriptor;
use keyframer::kernels::sharpness::score_opencv;
use keyframer::params::Metric;
use opencv::imgcodecs;
use opencv::prelude::*;
use std::path::Path;

/// Analysis width of the descriptor's golden totals.
const DESCRIPTOR_WIDTH: u32 = 320;

fn main() -> anyhow::Result<()> {
    let root = Path::new("reference");
    let inputs = root.join("inputs");
    // Synthetic inputs: sizes that are not multiples of the 16x16 workgroup.
    for (w, h, seed) in [(37, 83, 1u64), (641, 359, 2)] {
        let img = keyframer::synthetic::pattern(w, h, seed)?;
        let path = inputs.join(format!("synthetic_{w}x{h}_seed{seed}.png"));
        imgcodecs::imwrite(
            path.to_str().unwrap_or_default(),
            &img,
            &opencv::core::Vector::new(),
        )?;
    }
    let mut files: Vec<_> = std::fs::read_dir(&inputs)?
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<_, _>>()?;
    files.sort();
    let metrics = [
        Metric::Tenengrad,
        Metric::Laplacian { ksize: 1 },
        Metric::Laplacian { ksize: 3 },
    ];
    for f in files {
        let img = imgcodecs::imread(f.to_str().unwrap_or_default(), imgcodecs::IMREAD_COLOR)?;
        let name = f
            .file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned();
        for m in metrics {
            let score = score_opencv(&img, m)?;
            let out = root.join("sharpness").join(format!("{name}__{m}.json"));
            let v = serde_json::json!({
                "input": format!("inputs/{name}"),
                "metric": m.to_string(),
                "width": img.cols(),
                "height": img.rows(),
                "opencv_version": opencv::core::get_version_string()?,
                "score": score,
            });
            std::fs::write(&out, serde_json::to_string_pretty(&v)? + "\n")?;
            println!("{}: {score}", out.display());
        }
        let (w, h) = (img.cols() as u32, img.rows() as u32);
        let size = keyframer::analysis::analysis_size(w, h, DESCRIPTOR_WIDTH);
        let small = descriptor::prepare(&img, size)?;
        let totals = descriptor::opencv(&small)?;
        std::fs::create_dir_all(root.join("descriptor"))?;
        let out = root.join("descriptor").join(format!("{name}.json"));
        let v = serde_json::json!({
            "input": format!("inputs/{name}"),
            "descriptor": descriptor::NAME,
            "width": size.0,
            "height": size.1,
            "opencv_version": opencv::core::get_version_string()?,
            "totals": totals,
        });
        std::fs::write(&out, serde_json::to_string_pretty(&v)? + "\n")?;
        println!("{}: {} totals", out.display(), totals.len());
    }
    remap_views(root)
}

/// Golden views in reference/remap: OpenCV's cv::remap of a reference input (as an ERP frame)
/// through `equirect::view_map`, for three views and both interpolations, each with a JSON file
/// naming its input, view and interpolation.
fn remap_views(root: &Path) -> anyhow::Result<()> {
    use keyframer::equirect::{view_map, ViewSet};
    use keyframer::kernels::remap::{opencv as cv_remap, Interp, Table};
    let name = "synthetic_641x359_seed2.png";
    let input = root.join("inputs").join(name);
    let img = imgcodecs::imread(input.to_str().unwrap_or_default(), imgcodecs::IMREAD_COLOR)?;
    let erp = (img.cols() as u32, img.rows() as u32);
    let dir = root.join("remap");
    std::fs::create_dir_all(&dir)?;
    for view in ViewSet::Cube.views(96.0, 64) {
        if !["front", "back", "up"].contains(&view.name.as_str()) {
            continue;
        }
        let (xs, ys) = view_map(&view, erp);
        let table = Table::new((view.size, view.size), xs, ys)?;
        for interp in [Interp::Bilinear, Interp::Bicubic] {
            let tag = serde_json::to_value(interp)?;
            let stem = format!("{name}__{}_{}", view.name, tag.as_str().unwrap_or_default());
            let out = cv_remap(&img, &table, interp)?;
            imgcodecs::imwrite(
                dir.join(format!("{stem}.png")).to_str().unwrap_or_default(),
                &out,
                &opencv::core::Vector::new(),
            )?;
            let v = serde_json::json!({
                "input": format!("inputs/{name}"),
                "output": format!("remap/{stem}.png"),
                "view": view,
                "interp": interp,
                "opencv_version": opencv::core::get_version_string()?,
            });
            std::fs::write(
                dir.join(format!("{stem}.json")),
                serde_json::to_string_pretty(&v)? + "\n",
            )?;
            println!("{}", dir.join(format!("{stem}.png")).display());
        }
    }
    Ok(())
}
