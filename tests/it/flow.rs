//! Farneback flow: gpu against cv::calcOpticalFlowFarneback with the same parameters.

use crate::common::testdata;
use keyframer::kernels::farneback::{self, FarnebackGpu};
use keyframer::kernels::tolerance::{FLOW_EPE_MEAN, FLOW_EPE_P99};
use keyframer::params::{Derotate, FarnebackParams, Statistic};
use opencv::core::{Mat, Vec2f};
use opencv::prelude::*;

pub fn gray_of(path: &std::path::Path) -> Mat {
    let m = opencv::imgcodecs::imread(path.to_str().unwrap(), opencv::imgcodecs::IMREAD_GRAYSCALE)
        .unwrap();
    assert!(!m.empty(), "{}", path.display());
    m
}

/// (mean, 99th percentile, max) endpoint error between two CV_32FC2 fields.
pub fn epe(a: &Mat, b: &Mat) -> (f64, f64, f64) {
    let a = a.data_typed::<Vec2f>().unwrap();
    let b = b.data_typed::<Vec2f>().unwrap();
    let mut e: Vec<f64> = a
        .iter()
        .zip(b)
        .map(|(p, q)| (f64::from(p[0] - q[0]).powi(2) + f64::from(p[1] - q[1]).powi(2)).sqrt())
        .collect();
    let mean = e.iter().sum::<f64>() / e.len() as f64;
    e.sort_by(f64::total_cmp);
    (
        mean,
        e[(e.len() as f64 * 0.99) as usize],
        *e.last().unwrap(),
    )
}

pub fn compare(prev: &Mat, next: &Mat, p: &FarnebackParams, what: &str) -> (f64, f64, f64) {
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None).unwrap());
    let mut gpu = FarnebackGpu::new(ctx, *p, prev.cols() as u32, prev.rows() as u32).unwrap();
    let g = gpu.flow(prev, next).unwrap();
    let c = farneback::opencv(prev, next, p, None).unwrap();
    let (mean, p99, max) = epe(&g, &c);
    eprintln!("{what} {p:?}: EPE mean {mean:.5} p99 {p99:.5} max {max:.4}");
    assert!(
        mean <= FLOW_EPE_MEAN && p99 <= FLOW_EPE_P99,
        "{what}: EPE mean {mean} p99 {p99} (max {max})"
    );
    (mean, p99, max)
}

fn param_sets() -> Vec<FarnebackParams> {
    let d = FarnebackParams::default();
    vec![
        d,
        FarnebackParams {
            gaussian: true,
            ..d
        },
        FarnebackParams {
            levels: 5,
            winsize: 13,
            iterations: 10,
            poly_n: 5,
            poly_sigma: 1.1,
            ..d
        },
        FarnebackParams {
            poly_n: 7,
            poly_sigma: 1.5,
            winsize: 10,
            gaussian: true,
            ..d
        },
    ]
}

#[test]
fn middlebury_pairs_match_opencv() {
    for (a, b) in [
        ("basketball1.png", "basketball2.png"),
        ("rubberwhale1.png", "rubberwhale2.png"),
    ] {
        let prev = gray_of(&testdata(&format!("opencv-doc/{a}")));
        let next = gray_of(&testdata(&format!("opencv-doc/{b}")));
        for p in param_sets() {
            compare(&prev, &next, &p, a);
        }
    }
}

/// The device statistic equals the host statistic of the same magnitudes (exact selection), and
/// gpu vs opencv movement agrees within MOVEMENT_REL.
#[test]
fn movement_statistic_on_device() {
    use keyframer::kernels::movement::{self, MovementGpu};
    use keyframer::kernels::tolerance::{rel_err, MOVEMENT_REL};
    let prev = gray_of(&testdata("opencv-doc/rubberwhale1.png"));
    let next = gray_of(&testdata("opencv-doc/rubberwhale2.png"));
    let p = FarnebackParams::default();
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None).unwrap());
    let mut gpu =
        FarnebackGpu::new(ctx.clone(), p, prev.cols() as u32, prev.rows() as u32).unwrap();
    let g = gpu.flow(&prev, &next).unwrap();
    let stat = MovementGpu::new(
        ctx,
        gpu.flow_buffer(),
        prev.cols() as u32,
        prev.rows() as u32,
        None,
    )
    .unwrap();
    let cv_flow = farneback::opencv(&prev, &next, &p, None).unwrap();
    let g_mags = movement::magnitudes(&g).unwrap();
    let c_mags = movement::magnitudes(&cv_flow).unwrap();
    for s in [
        Statistic::Median,
        Statistic::TrimmedMean { trim: 0.1 },
        Statistic::TrimmedMean { trim: 0.0 },
        Statistic::TrimmedMean { trim: 0.25 },
    ] {
        let on_device = stat.compute(s).unwrap();
        let host_same = movement::cpu(&g_mags, s).unwrap();
        assert!(
            rel_err(on_device, host_same) < 1e-6,
            "{s:?}: device {on_device} host {host_same}"
        );
        let opencv = movement::cpu(&c_mags, s).unwrap();
        assert!(
            rel_err(on_device, opencv) <= MOVEMENT_REL,
            "{s:?}: gpu {on_device} opencv {opencv}"
        );
        eprintln!("{s:?}: gpu {on_device} opencv {opencv}");
    }
}

/// Derotation on the device: the fitted rotation and the residual statistic equal the host twin
/// on the same (device) flow and agree with OpenCV's flow within MOVEMENT_REL; the flow of a known
/// rotation (plus a local bump) is fitted back and leaves (almost) no residual.
#[test]
fn derotated_movement_on_device() {
    use keyframer::kernels::movement::{self, MovementGpu, RotationField};
    use keyframer::kernels::tolerance::{
        rel_err, DEROTATED_SAME_FLOW_REL, MOVEMENT_REL, ROTATION_ABS,
    };
    let prev = gray_of(&testdata("opencv-doc/rubberwhale1.png"));
    let next = gray_of(&testdata("opencv-doc/rubberwhale2.png"));
    let (w, h) = (prev.cols() as u32, prev.rows() as u32);
    let p = FarnebackParams::default();
    let d = Derotate { hfov_deg: 65.0 };
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None).unwrap());
    let mut gpu = FarnebackGpu::new(ctx.clone(), p, w, h).unwrap();
    let g = gpu.flow(&prev, &next).unwrap();
    let stat = MovementGpu::new(ctx.clone(), gpu.flow_buffer(), w, h, Some(d)).unwrap();
    let field = RotationField::new(w, h, d).unwrap();
    let cv_flow = farneback::opencv(&prev, &next, &p, None).unwrap();
    let g_vals = movement::flow_values(&g).unwrap();
    let close = |a: &movement::Rotation, b: &movement::Rotation, tol: f32| {
        (0..3).all(|i| (0..3).all(|j| (a[i][j] - b[i][j]).abs() <= tol))
    };
    let r_dev = stat.rotation().unwrap().unwrap();
    let r_host = field.fit_cpu(&g_vals).unwrap();
    let max_diff = (0..9)
        .map(|k| (r_dev[k / 3][k % 3] - r_host[k / 3][k % 3]).abs())
        .fold(0.0f32, f32::max);
    eprintln!("rotation device vs host: max entry difference {max_diff:e}");
    assert!(
        close(&r_dev, &r_host, ROTATION_ABS),
        "device {r_dev:?} host {r_host:?}"
    );
    for s in [Statistic::Median, Statistic::TrimmedMean { trim: 0.1 }] {
        let on_device = stat.compute(s).unwrap();
        let host_same = movement::cpu_flow(&g, s, Some(&field)).unwrap();
        assert!(
            rel_err(on_device, host_same) <= DEROTATED_SAME_FLOW_REL,
            "{s:?}: device {on_device} host {host_same}"
        );
        let opencv = movement::cpu_flow(&cv_flow, s, Some(&field)).unwrap();
        assert!(
            rel_err(on_device, opencv) <= MOVEMENT_REL,
            "{s:?}: gpu {on_device} opencv {opencv}"
        );
        let raw = movement::cpu(&movement::magnitudes(&g).unwrap(), s).unwrap();
        eprintln!("{s:?} derotated: gpu {on_device} opencv {opencv} (raw {raw})");
    }

    // Flow of a rotation of 0.04 rad, plus a 0.5 px bump on 1/8 of the pixels.
    let truth = movement::matrix([0.01, -0.03, 0.025]);
    let mut synth = Vec::with_capacity(2 * (w * h) as usize);
    for j in 0..h {
        for i in 0..w {
            let r = field.rotation_flow(i, j, &truth);
            let bump = if i < w / 4 && j < h / 2 { 0.5 } else { 0.0 };
            synth.extend_from_slice(&[r[0] + bump, r[1]]);
        }
    }
    let pure: Vec<f32> = (0..h)
        .flat_map(|j| (0..w).map(move |i| (i, j)))
        .flat_map(|(i, j)| field.rotation_flow(i, j, &truth))
        .collect();
    let exact = field.fit_cpu(&pure).unwrap();
    assert!(close(&exact, &truth, 1e-5), "{exact:?} vs {truth:?}");
    ctx.queue
        .write_buffer(gpu.flow_buffer(), 0, bytemuck::cast_slice(&synth));
    let fitted = stat.rotation().unwrap().unwrap();
    let host = field.fit_cpu(&synth).unwrap();
    assert!(
        close(&fitted, &host, ROTATION_ABS),
        "{fitted:?} vs {host:?}"
    );
    let median = stat.compute(Statistic::Median).unwrap();
    let raw_median = movement::cpu(
        &synth
            .chunks(2)
            .map(|v| (v[0] * v[0] + v[1] * v[1]).sqrt())
            .collect::<Vec<f32>>(),
        Statistic::Median,
    )
    .unwrap();
    eprintln!("synthetic rotation: residual median {median}, raw {raw_median}");
    assert!(
        median < 0.02 * raw_median,
        "residual {median} raw {raw_median}"
    );
}

fn video_gray(path: &std::path::Path, frames: &[usize]) -> Vec<Mat> {
    let mut src = keyframer::source::open(path, &Default::default()).unwrap();
    let mut out = Vec::new();
    keyframer::source::read_indices(src.as_mut(), frames, |f| {
        out.push(keyframer::kernels::gray::opencv(&f.image).unwrap());
        Ok(())
    })
    .unwrap();
    out
}

/// Megamind frames (camera motion) at full size and cropped to 641x359 (not a multiple of 16).
#[test]
fn megamind_frames_and_odd_size_match_opencv() {
    let g = video_gray(&testdata("opencv-doc/Megamind.avi"), &[40, 41, 120, 122]);
    for (a, b) in [(&g[0], &g[1]), (&g[2], &g[3])] {
        compare(a, b, &FarnebackParams::default(), "Megamind");
        let roi = opencv::core::Rect::new(37, 80, 641, 359);
        let ca = Mat::roi(a, roi).unwrap().try_clone().unwrap();
        let cb = Mat::roi(b, roi).unwrap().try_clone().unwrap();
        for p in param_sets() {
            compare(&ca, &cb, &p, "Megamind 641x359");
        }
    }
}

/// A sub-pixel translation of a real photo is recovered within 0.05 px (median over the interior).
#[test]
fn synthetic_translation_is_recovered() {
    let photo = gray_of(&testdata("opencv-doc/aloeL.jpg"));
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None).unwrap());
    for (dx, dy) in [(1.3f64, -0.7f64), (-4.25, 2.5), (0.2, 0.0)] {
        let m = Mat::from_slice_2d(&[[1.0f64, 0.0, dx], [0.0, 1.0, dy]]).unwrap();
        let mut shifted = Mat::default();
        opencv::imgproc::warp_affine(
            &photo,
            &mut shifted,
            &m,
            photo.size().unwrap(),
            opencv::imgproc::INTER_CUBIC,
            opencv::core::BORDER_REFLECT_101,
            opencv::core::Scalar::all(0.0),
        )
        .unwrap();
        let roi = opencv::core::Rect::new(200, 200, 480, 320);
        let a = Mat::roi(&photo, roi).unwrap().try_clone().unwrap();
        let b = Mat::roi(&shifted, roi).unwrap().try_clone().unwrap();
        let p = FarnebackParams::default();
        let mut gpu = FarnebackGpu::new(ctx.clone(), p, 480, 320).unwrap();
        let f = gpu.flow(&a, &b).unwrap();
        let d = f.data_typed::<Vec2f>().unwrap();
        let (mut us, mut vs) = (Vec::new(), Vec::new());
        for y in 40..280 {
            for x in 40..440 {
                us.push(d[y * 480 + x][0]);
                vs.push(d[y * 480 + x][1]);
            }
        }
        us.sort_by(f32::total_cmp);
        vs.sort_by(f32::total_cmp);
        let (mu, mv) = (f64::from(us[us.len() / 2]), f64::from(vs[vs.len() / 2]));
        assert!(
            (mu - dx).abs() <= 0.05 && (mv - dy).abs() <= 0.05,
            "shift ({dx}, {dy}) recovered as ({mu}, {mv})"
        );
        compare(&a, &b, &p, "translation");
    }
}

/// `keyframer flow` writes a Middlebury .flo that both backends agree on.
/// The gated copy of a slot's expansion pyramid: with its gate closed the target slot keeps its
/// frame, open it receives the source's, so the flow from it is bit-identical to the flow from
/// the source.
#[test]
fn gated_copy_moves_a_pyramid_only_when_open() {
    use keyframer::gpu::Gate;
    let prev = gray_of(&testdata("opencv-doc/rubberwhale1.png"));
    let next = gray_of(&testdata("opencv-doc/rubberwhale2.png"));
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None).unwrap());
    let (w, h) = (prev.cols() as u32, prev.rows() as u32);
    let mut gpu = FarnebackGpu::new(ctx.clone(), FarnebackParams::default(), w, h).unwrap();
    gpu.load(0, &prev).unwrap();
    gpu.load(1, &next).unwrap();
    gpu.load(2, &next).unwrap();
    let flow_to_1 = |gpu: &mut FarnebackGpu, from: usize| {
        gpu.flow_between(from, 1).unwrap();
        gpu.read_flow().unwrap().data_bytes().unwrap().to_vec()
    };
    let from_prev = flow_to_1(&mut gpu, 0);
    let from_next = flow_to_1(&mut gpu, 2);
    assert_ne!(from_prev, from_next);
    for (open, want) in [(false, &from_next), (true, &from_prev)] {
        let table: Vec<u32> = (gpu.copy_shapes().iter())
            .flat_map(|&(x, y)| if open { [x, y, 1] } else { [0; 3] })
            .collect();
        let args = ctx.indirect_buffer("gates", bytemuck::cast_slice(&table));
        let mut enc = ctx.encoder("gated copy");
        let gate = Some(Gate {
            args: &args,
            first: 0,
        });
        gpu.encode_copy(&mut enc, 0, 2, gate).unwrap();
        ctx.queue.submit([enc.finish()]);
        assert!(flow_to_1(&mut gpu, 2) == *want, "gate open: {open}");
    }
}

#[test]
fn flow_command_writes_flo() {
    use crate::common::{kf, kf_ok, s};
    let d = tempfile::tempdir().unwrap();
    let a = testdata("opencv-doc/basketball1.png");
    let b = testdata("opencv-doc/basketball2.png");
    let g = d.path().join("g.flo");
    let c = d.path().join("c.flo");
    kf_ok(&["flow", s(&a), s(&b), "-o", s(&g), "--backend", "gpu"]);
    kf_ok(&["flow", s(&a), s(&b), "-o", s(&c), "--backend", "opencv"]);
    let (w, h, fg) = keyframer::flo::read(&g).unwrap();
    let (_, _, fc) = keyframer::flo::read(&c).unwrap();
    assert_eq!((w, h), (640, 480));
    let mean: f64 = fg
        .chunks(2)
        .zip(fc.chunks(2))
        .map(|(p, q)| f64::from(((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt()))
        .sum::<f64>()
        / f64::from(w * h);
    assert!(mean <= FLOW_EPE_MEAN, "{mean}");
    // The opencv backend's file holds OpenCV's flow bit for bit (the default parameters).
    let direct = farneback::opencv(
        &gray_of(&a),
        &gray_of(&b),
        &FarnebackParams::default(),
        None,
    )
    .unwrap();
    let direct: Vec<u32> = direct
        .data_typed::<opencv::core::Vec2f>()
        .unwrap()
        .iter()
        .flat_map(|v| [v[0].to_bits(), v[1].to_bits()])
        .collect();
    let written: Vec<u32> = fc.iter().map(|v| v.to_bits()).collect();
    assert!(
        direct == written,
        "the opencv backend's .flo differs from OpenCV's flow"
    );
    // Refuses to overwrite, and rejects images of different sizes.
    assert_eq!(
        kf(&["flow", s(&a), s(&b), "-o", s(&g)]).status.code(),
        Some(1)
    );
    let other = testdata("opencv-doc/rubberwhale1.png");
    let out = kf(&["flow", s(&a), s(&other), "-o", s(&d.path().join("x.flo"))]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("one size"));
}

/// OPTFLOW_USE_INITIAL_FLOW: both start from the same initial field.
#[test]
fn initial_flow_option_matches_opencv() {
    let prev = gray_of(&testdata("opencv-doc/basketball1.png"));
    let next = gray_of(&testdata("opencv-doc/basketball2.png"));
    let ctx = std::sync::Arc::new(keyframer::gpu::GpuContext::new(None).unwrap());
    for p in [
        FarnebackParams::default(),
        FarnebackParams {
            levels: 0,
            iterations: 2,
            ..FarnebackParams::default()
        },
    ] {
        let start =
            farneback::opencv(&prev, &next, &FarnebackParams { iterations: 1, ..p }, None).unwrap();
        let mut gpu = FarnebackGpu::new(ctx.clone(), p, 640, 480).unwrap();
        let g = gpu.flow_from(&prev, &next, Some(&start)).unwrap();
        let c = farneback::opencv(&prev, &next, &p, Some(&start)).unwrap();
        let without = farneback::opencv(&prev, &next, &p, None).unwrap();
        let (mean, p99, max) = epe(&g, &c);
        assert!(
            mean <= FLOW_EPE_MEAN && p99 <= FLOW_EPE_P99,
            "initial flow {p:?}: mean {mean} p99 {p99} max {max}"
        );
        assert!(
            epe(&c, &without).0 > 10.0 * mean.max(1e-6),
            "the initial flow must change the result"
        );
    }
}

/// The device's f64 arithmetic (shaders/f64.wgsl, which the movement statistic and the stationary
/// decision use to equal the host bit for bit) gives exactly the host's f64 results: sums,
/// products, quotients and comparisons of non-negative values over many magnitudes, rounding
/// ties included, and the exact conversions from f32 (subnormal too) and u32.
#[test]
fn f64_arithmetic_on_device_equals_the_hosts() {
    use keyframer::gpu::{compute_pass, GpuContext};
    const DRIVER: &str = "
@group(0) @binding(0) var<storage, read> input: array<u32>;
@group(0) @binding(1) var<storage, read_write> output: array<u32>;
fn put(at: u32, v: vec2<u32>) { output[at] = v.x; output[at + 1u] = v.y; }
@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let k = id.x;
    if (6u * k >= arrayLength(&input)) { return; }
    let a = vec2<u32>(input[6u * k], input[6u * k + 1u]);
    let b = vec2<u32>(input[6u * k + 2u], input[6u * k + 3u]);
    put(11u * k, f64_add(a, b));
    put(11u * k + 2u, f64_mul(a, b));
    put(11u * k + 4u, f64_div(a, b));
    put(11u * k + 6u, f64_from_f32(input[6u * k + 4u]));
    put(11u * k + 8u, f64_from_u32(input[6u * k + 5u]));
    output[11u * k + 10u] = select(0u, 1u, f64_ge(a, b));
}
";
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    // Positive normal values from 2^-200 to 2^200, half of them f32 values (the statistic's)
    // from 2^-100 to 2^100.
    let value = |r: u64, bits: u64| match r % 2 {
        0 => f64::from(f64::from_bits(((923 + r % 200) << 52) | (bits >> 12)) as f32),
        _ => f64::from_bits(((823 + r % 400) << 52) | (bits >> 12)),
    };
    let mut cases: Vec<(f64, f64, u32, u32)> = vec![
        (1.0, 2f64.powi(-53), 1, 0),
        (1.0 + 2f64.powi(-52), 2f64.powi(-53), 0x0000_0001, u32::MAX),
        (3.0, 0.5, 0x007f_ffff, 7),
        (0.0, 2.5, 0x3f80_0000, 1 << 31),
        (1.5, 1.5, 0x7f7f_ffff, 12345),
        (2f64.powi(60), 1.0, 0x0040_0000, 3),
    ];
    for _ in 0..20_000 {
        let r = next();
        let a = value(r, next());
        // Often close to `a`, so sums round, carry and tie.
        let b = match r % 4 {
            0 => a * (1.0 + (next() % 1000) as f64 * f64::EPSILON),
            1 => a * 2f64.powi(-((next() % 70) as i32)),
            _ => value(next(), next()),
        };
        let f = (next() as u32) & 0x7fff_ffff;
        let f = if f >> 23 == 0xff { f & 0x3fff_ffff } else { f };
        cases.push((a, b, f, next() as u32));
    }
    let words = |v: f64| [(v.to_bits() >> 32) as u32, v.to_bits() as u32];
    let input: Vec<u32> = cases
        .iter()
        .flat_map(|&(a, b, f, n)| {
            let (a, b) = (words(a), words(b));
            [a[0], a[1], b[0], b[1], f, n]
        })
        .collect();
    let ctx = GpuContext::new(None).unwrap();
    let src = format!("{}{DRIVER}", keyframer::kernels::F64_WGSL);
    let pipe = ctx.pipeline("f64 check", &src, "main").unwrap();
    let storage = wgpu::BufferUsages::STORAGE;
    let inb = ctx.buffer_init("f64 input", storage, bytemuck::cast_slice(&input));
    let out = ctx.storage_buffer("f64 output", cases.len() as u64 * 44);
    let bg = ctx.bind("f64 check", &pipe, &[(0, &inb), (1, &out)]);
    let mut enc = ctx.encoder("f64 check");
    ctx.dispatch(
        &mut compute_pass(&mut enc, "f64 check"),
        &pipe,
        &bg,
        ((cases.len() as u32).div_ceil(64), 1),
    );
    ctx.queue.submit([enc.finish()]);
    let bytes = ctx.read_back(&out, cases.len() as u64 * 44).unwrap();
    let got: &[u32] = bytemuck::cast_slice(&bytes);
    let f64_at =
        |w: &[u32], i: usize| f64::from_bits((u64::from(w[i]) << 32) | u64::from(w[i + 1]));
    for (k, &(a, b, f, n)) in cases.iter().enumerate() {
        let g = &got[11 * k..11 * k + 11];
        let want = [
            a + b,
            a * b,
            a / b,
            f64::from(f32::from_bits(f)),
            f64::from(n),
        ];
        for (j, w) in want.iter().enumerate() {
            let d = f64_at(g, 2 * j);
            assert_eq!(
                d.to_bits(),
                w.to_bits(),
                "case {k} op {j}: a {a:e} b {b:e} f {f:#x} n {n}: device {d:e} host {w:e}"
            );
        }
        assert_eq!(g[10] == 1, a >= b, "case {k}: {a:e} >= {b:e}");
    }
}

/// The host Farneback (expansions computed once per frame, then the pairs) equals
/// cv::calcOpticalFlowFarneback bit for bit: Middlebury pairs, Megamind frames at full size, an
/// odd crop and a small image, every parameter set (box and Gaussian windows, poly_n 5 and 7);
/// one expansion reused for two pairs gives each pair's own result.
#[test]
fn host_flow_equals_opencv_bit_for_bit() {
    use farneback::host;
    let mut pairs: Vec<(String, Mat, Mat)> = Vec::new();
    for (a, b) in [
        ("basketball1.png", "basketball2.png"),
        ("rubberwhale1.png", "rubberwhale2.png"),
    ] {
        let prev = gray_of(&testdata(&format!("opencv-doc/{a}")));
        let next = gray_of(&testdata(&format!("opencv-doc/{b}")));
        pairs.push((a.to_string(), prev, next));
    }
    let g = video_gray(&testdata("opencv-doc/Megamind.avi"), &[40, 41, 120, 122]);
    pairs.push(("Megamind 40-41".into(), g[0].clone(), g[1].clone()));
    for (name, rect) in [
        (
            "Megamind 641x359",
            opencv::core::Rect::new(37, 80, 641, 359),
        ),
        ("Megamind 45x37", opencv::core::Rect::new(300, 200, 45, 37)),
    ] {
        let ca = Mat::roi(&g[2], rect).unwrap().try_clone().unwrap();
        let cb = Mat::roi(&g[3], rect).unwrap().try_clone().unwrap();
        pairs.push((name.into(), ca, cb));
    }
    let same = |a: &Mat, b: &Mat| -> usize {
        let (a, b) = (
            a.data_typed::<Vec2f>().unwrap(),
            b.data_typed::<Vec2f>().unwrap(),
        );
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .filter(|(p, q)| p[0].to_bits() != q[0].to_bits() || p[1].to_bits() != q[1].to_bits())
            .count()
    };
    for (name, prev, next) in &pairs {
        for p in param_sets() {
            let expander = host::Expander::new(&p).unwrap();
            let (ea, eb) = (
                expander.expand(prev).unwrap(),
                expander.expand(next).unwrap(),
            );
            let ours = host::flow(&ea, &eb).unwrap();
            let cv = farneback::opencv(prev, next, &p, None).unwrap();
            let differing = same(&ours, &cv);
            let (mean, _, max) = epe(&ours, &cv);
            eprintln!("{name} {p:?}: {differing} values differ, EPE mean {mean:e} max {max:e}");
            assert_eq!(differing, 0, "{name} {p:?}: EPE mean {mean:e} max {max:e}");
            // The same expansion of `prev` serves a second pair (backwards).
            let back = host::flow(&eb, &ea).unwrap();
            let cv_back = farneback::opencv(next, prev, &p, None).unwrap();
            assert_eq!(same(&back, &cv_back), 0, "{name} {p:?} backwards");
        }
    }
}
