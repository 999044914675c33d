//! Writes one of each picture the scene runner makes, from synthetic data, to
//! `target/render-demo/` (or the folder given as the first argument), so that the
//! rendering can be looked at without running a scene:
//!
//! `cargo run -p sinew-viz --example render_demo [OUT_DIR]`
//!
//! The IK chain and the cloth motion here are faked (interpolated, not solved or
//! simulated): this is a picture test, not a physics one. Each GIF is also decoded back
//! and its first, middle and last frames written as PNG files, to check the animation
//! as it will be seen.

use sinew_math::DVec3;
use sinew_viz::render::{self, ClothFrame, IkFrame, Series, View};
use std::f64::consts::TAU;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The lab's five-petal flower.
fn flower(t: f64) -> DVec3 {
    DVec3::new(
        0.1 * (6.0 * t.cos() - (6.0 * t).cos()),
        0.0,
        0.1 * (6.0 * t.sin() - (6.0 * t).sin()),
    )
}

/// `count` points spread evenly by arc length along the closed flower, measured on a
/// dense polyline.
fn flower_even(count: usize) -> Vec<DVec3> {
    let dense: Vec<DVec3> = (0..=20_000)
        .map(|k| flower(TAU * k as f64 / 20_000.0))
        .collect();
    let mut cumulative = vec![0.0];
    for w in dense.windows(2) {
        cumulative.push(cumulative.last().unwrap() + w[0].distance(w[1]));
    }
    let total = *cumulative.last().unwrap();
    let mut out = Vec::with_capacity(count);
    let mut segment = 0;
    for k in 0..count {
        let s = total * k as f64 / count as f64;
        while cumulative[segment + 1] < s {
            segment += 1;
        }
        let t = (s - cumulative[segment]) / (cumulative[segment + 1] - cumulative[segment]);
        out.push(dense[segment].lerp(dense[segment + 1], t));
    }
    out
}

/// A fake 8-joint chain from the root towards `target`, bowed sideways so that joints
/// are distinct, with the effector short of the target by `miss`.
fn fake_chain(root: DVec3, target: DVec3, miss: f64) -> Vec<DVec3> {
    let reach = target - root;
    let end = root + reach * (1.0 - miss / reach.length().max(1e-9));
    let side = reach.cross(DVec3::Z).normalize_or_zero() * 0.12;
    (0..8)
        .map(|k| {
            let s = k as f64 / 7.0;
            root.lerp(end, s) + side * (std::f64::consts::PI * s).sin()
        })
        .collect()
}

/// The 11x11 lab cloth at time fraction `phase` (0 flat, 1 hanging), faked: it swings
/// down about its pinned edge (x = 0), stretching more towards the free edge, sagging
/// between the pins and drawing in at the bottom, so springs both stretch and compress.
fn fake_cloth(phase: f64) -> Vec<DVec3> {
    let mut out = Vec::with_capacity(121);
    let angle = 1.2 * phase;
    for i in 0..11 {
        for j in 0..11 {
            let u = i as f64 / 10.0;
            let v = j as f64 / 10.0;
            let between_pins = 1.0 - (2.0 * v - 1.0).powi(2);
            let r = 0.2 * i as f64 * (1.0 + 0.04 * phase * (1.0 - u));
            let x = r * angle.cos();
            let y = 1.5 - r * angle.sin() - 0.1 * phase * between_pins;
            let z = (0.2 * j as f64 - 1.0) * (1.0 - 0.06 * phase * u);
            out.push(DVec3::new(x, y, z));
        }
    }
    out
}

/// Spring list of the 11x11 grid: structural, shear and bend springs at rest lengths.
fn cloth_springs(positions: &[DVec3]) -> Vec<(usize, usize, f64)> {
    let at = |i: usize, j: usize| i * 11 + j;
    let mut springs = Vec::new();
    let mut add = |a: usize, b: usize| springs.push((a, b, positions[a].distance(positions[b])));
    for i in 0..11 {
        for j in 0..11 {
            if i >= 1 {
                add(at(i, j), at(i - 1, j));
            }
            if j >= 1 {
                add(at(i, j), at(i, j - 1));
            }
            if i >= 1 && j >= 1 {
                add(at(i, j), at(i - 1, j - 1));
                add(at(i - 1, j), at(i, j - 1));
            }
            if i >= 2 {
                add(at(i, j), at(i - 2, j));
            }
            if j >= 2 {
                add(at(i, j), at(i, j - 2));
            }
        }
    }
    springs
}

/// Decodes `gif_path` and writes its first, middle and last frames as PNG files beside
/// it; returns the number of frames.
fn gif_frames_to_png(gif_path: &Path) -> Result<usize, String> {
    let file = std::fs::File::open(gif_path).map_err(|e| e.to_string())?;
    let mut options = gif::DecodeOptions::new();
    options.set_color_output(gif::ColorOutput::RGBA);
    let mut decoder = options.read_info(file).map_err(|e| e.to_string())?;
    let (w, h) = (decoder.width() as usize, decoder.height() as usize);
    let mut screen = vec![255_u8; w * h * 4];
    let mut frames = Vec::new();
    while let Some(frame) = decoder.read_next_frame().map_err(|e| e.to_string())? {
        let (left, top) = (frame.left as usize, frame.top as usize);
        let fw = frame.width as usize;
        for (row, line) in frame.buffer.chunks_exact(fw * 4).enumerate() {
            let at = ((top + row) * w + left) * 4;
            screen[at..at + fw * 4].copy_from_slice(line);
        }
        frames.push(screen.clone());
    }
    let count = frames.len();
    for (name, index) in [("first", 0), ("middle", count / 2), ("last", count - 1)] {
        let size = tiny_skia::IntSize::from_wh(w as u32, h as u32).unwrap();
        let pixmap = tiny_skia::Pixmap::from_vec(frames[index].clone(), size).unwrap();
        let out = gif_path.with_extension(format!("{name}.png"));
        pixmap.save_png(&out).map_err(|e| e.to_string())?;
    }
    Ok(count)
}

fn report(what: &str, path: &Path, started: Instant, result: Result<(), String>) {
    let size = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    match result {
        Ok(()) => println!(
            "{what:<28} {:>8.1} KiB {:>7.0} ms  {}",
            size as f64 / 1024.0,
            started.elapsed().as_secs_f64() * 1e3,
            path.display()
        ),
        Err(e) => println!("{what:<28} FAILED: {e}"),
    }
}

fn main() {
    let out: PathBuf = std::env::args_os().nth(1).map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/render-demo"),
        PathBuf::from,
    );
    std::fs::create_dir_all(&out).expect("output folder");
    let out = out.canonicalize().unwrap_or(out);

    // IK: the chain follows 120 evenly spaced targets on the flower.
    let root = DVec3::new(0.0, 0.5, 0.0);
    let targets = flower_even(120);
    let chains: Vec<Vec<DVec3>> = targets
        .iter()
        .enumerate()
        .map(|(k, &t)| fake_chain(root, t, 0.02 * (-(k as f64) / 15.0).exp()))
        .collect();
    let frames: Vec<IkFrame> = chains
        .iter()
        .zip(&targets)
        .map(|(joints, &target)| IkFrame { joints, target })
        .collect();
    let framed = chains.iter().flatten().chain(&targets).copied();
    let view = View::fit(framed, 0.6, 0.45, 480, 480);

    let path = out.join("ik.gif");
    let t = Instant::now();
    report(
        "ik_gif",
        &path,
        t,
        render::ik_gif(&path, &view, &frames, &targets, 20),
    );
    let path = out.join("ik.png");
    let t = Instant::now();
    let last = frames.last().unwrap();
    report(
        "ik_png",
        &path,
        t,
        render::ik_png(&path, &view, last, &targets),
    );

    // Same run seen from straight above (elevation pi/2), the flower's own plane.
    let framed = chains.iter().flatten().chain(&targets).copied();
    let top = View::fit(framed, 0.0, std::f64::consts::FRAC_PI_2, 480, 480);
    let path = out.join("ik-top.png");
    let t = Instant::now();
    report(
        "ik_png (top view)",
        &path,
        t,
        render::ik_png(&path, &top, &frames[30], &targets),
    );

    // Curves: 100 uniform-parameter samples against 100 evenly spaced ones.
    let line: Vec<DVec3> = (0..=600).map(|k| flower(TAU * k as f64 / 600.0)).collect();
    let uniform: Vec<DVec3> = (0..100).map(|k| flower(TAU * k as f64 / 100.0)).collect();
    let even = flower_even(100);
    let path = out.join("samples.png");
    let t = Instant::now();
    let result = render::samples_png(
        &path,
        &line,
        ("uniform parameter t", &uniform),
        ("even arc length", &even),
        0.0,
        std::f64::consts::FRAC_PI_2,
    );
    report("samples_png", &path, t, result);

    // Cloth: 40 frames sagging from two pinned corners.
    let flat = fake_cloth(0.0);
    let springs = cloth_springs(&flat);
    let cloth: Vec<Vec<DVec3>> = (0..40)
        .map(|k| fake_cloth((k as f64 / 39.0).powf(0.7)))
        .collect();
    let cloth_frames: Vec<ClothFrame> = cloth
        .iter()
        .map(|p| ClothFrame {
            positions: p,
            colliders: &[],
        })
        .collect();
    let fixed = [0, 10];
    let cloth_view = View::fit(cloth.iter().flatten().copied(), 0.7, 0.35, 480, 480);
    let path = out.join("cloth.gif");
    let t = Instant::now();
    let result = render::cloth_gif(
        &path,
        &cloth_view,
        &cloth_frames,
        &springs,
        &fixed,
        0.05,
        15,
    );
    report("cloth_gif", &path, t, result);
    let path = out.join("cloth.png");
    let t = Instant::now();
    let result = render::cloth_png(
        &path,
        &cloth_view,
        cloth_frames.last().unwrap(),
        &springs,
        &fixed,
        0.05,
    );
    report("cloth_png", &path, t, result);

    // Charts: iterations per frame (linear) and error per frame (log, with zeros).
    let ccd: Vec<(f64, f64)> = (0..120)
        .map(|k| (k as f64, (12.0 + 8.0 * (k as f64 * 0.3).sin()).round()))
        .collect();
    let fabrik: Vec<(f64, f64)> = (0..120)
        .map(|k| (k as f64, (5.0 + 3.0 * (k as f64 * 0.2).cos()).round()))
        .collect();
    let path = out.join("iterations.svg");
    let t = Instant::now();
    let result = render::line_chart_svg(
        &path,
        "Iterations per frame",
        "frame",
        "iterations",
        &[
            Series {
                name: "CCD",
                points: &ccd,
            },
            Series {
                name: "FABRIK",
                points: &fabrik,
            },
        ],
        false,
    );
    report("line_chart_svg (linear)", &path, t, result);
    let ccd_error: Vec<(f64, f64)> = (0..120)
        .map(|k| {
            let e = 1e-3 * (-(k as f64) / 12.0).exp() + 1e-7;
            (k as f64, if k % 25 == 7 { 0.0 } else { e })
        })
        .collect();
    let mut fabrik_error: Vec<(f64, f64)> = (0..120)
        .map(|k| {
            (
                k as f64,
                2e-4 * (1.0 + (k as f64 * 0.25).sin().abs()) * 10f64.powi(-(k / 30)),
            )
        })
        .collect();
    fabrik_error[60].1 = f64::NAN;
    let path = out.join("error.svg");
    let t = Instant::now();
    let result = render::line_chart_svg(
        &path,
        "Effector error per frame",
        "frame",
        "distance to target (m)",
        &[
            Series {
                name: "CCD",
                points: &ccd_error,
            },
            Series {
                name: "FABRIK",
                points: &fabrik_error,
            },
        ],
        true,
    );
    report("line_chart_svg (log)", &path, t, result);

    for name in ["ik.gif", "cloth.gif"] {
        match gif_frames_to_png(&out.join(name)) {
            Ok(count) => println!("{name}: {count} frames decoded, first/middle/last written"),
            Err(e) => println!("{name}: cannot decode: {e}"),
        }
    }

    // Degenerate input: must not panic; errors only for truly empty input.
    let nan = DVec3::splat(f64::NAN);
    let broken = [
        root,
        nan,
        DVec3::new(0.3, 0.2, 0.1),
        DVec3::new(f64::INFINITY, 0.0, 0.0),
    ];
    let odd_view = View::fit([nan], f64::NAN, 0.3, 0, 100_000);
    println!(
        "degenerate view: {}x{}",
        odd_view.width(),
        odd_view.height()
    );
    let checks: Vec<(&str, Result<(), String>)> = vec![
        (
            "ik_gif, no frames",
            render::ik_gif(&out.join("bad/empty.gif"), &view, &[], &targets, 20),
        ),
        (
            "ik_png, NaN joints",
            render::ik_png(
                &out.join("bad/nan.png"),
                &view,
                &IkFrame {
                    joints: &broken,
                    target: nan,
                },
                &broken,
            ),
        ),
        (
            "ik_png, no joints",
            render::ik_png(
                &out.join("bad/nojoints.png"),
                &odd_view,
                &IkFrame {
                    joints: &[],
                    target: root,
                },
                &[],
            ),
        ),
        (
            "cloth_png, bad springs",
            render::cloth_png(
                &out.join("bad/cloth.png"),
                &cloth_view,
                &ClothFrame {
                    positions: &broken,
                    colliders: &[],
                },
                &[
                    (0, 1, 0.1),
                    (0, 2, 0.0),
                    (2, 99, 1.0),
                    (0, 2, f64::NAN),
                    (0, 2, 0.5),
                ],
                &[1, 500],
                f64::NAN,
            ),
        ),
        (
            "samples_png, empty",
            render::samples_png(
                &out.join("bad/samples.png"),
                &[],
                ("a", &[]),
                ("b", &[]),
                0.0,
                0.0,
            ),
        ),
        (
            "chart, all zeros on log",
            render::line_chart_svg(
                &out.join("bad/zeros.svg"),
                "zeros",
                "x",
                "y",
                &[Series {
                    name: "z",
                    points: &[(0.0, 0.0), (1.0, 0.0)],
                }],
                true,
            ),
        ),
        (
            "chart, one point",
            render::line_chart_svg(
                &out.join("bad/one.svg"),
                "one point",
                "x",
                "y",
                &[Series {
                    name: "p",
                    points: &[(3.0, 3.0)],
                }],
                false,
            ),
        ),
        (
            "chart, no series",
            render::line_chart_svg(&out.join("bad/none.svg"), "none", "x", "y", &[], false),
        ),
    ];
    for (what, result) in checks {
        println!("{what:<28} {result:?}");
    }
}
