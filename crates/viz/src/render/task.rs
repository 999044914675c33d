//! The pictures of one task's result, written beside its metrics: what `cargo xtask
//! run-scene` draws for each task kind, from [`sinew_scene::results::Pictures`] alone.

use super::{BodyLayout, BodySnapshot, body_gif, body_png, line_chart_svg, samples_png};
use super::{ClothFrame, IkFrame, Series, View, cloth_gif, cloth_png, ik_gif, ik_png};
use sinew_math::DVec3;
use sinew_scene::results::{
    BodyPictures, ClothPictures, CurvePictures, IkPictures, Pictures, Shape,
};
use std::path::{Path, PathBuf};

/// Where a picture of the task goes, from its suffix (`gif`, `error.svg`, ...).
type OutPath<'a> = &'a dyn Fn(&str) -> PathBuf;

/// Draws the pictures of task `name` into `out_dir` as `<name>.<suffix>` (GIF, PNG,
/// SVG charts); a task whose result kept no pictures draws nothing. The error names the
/// file that could not be written.
pub fn draw_task(name: &str, pictures: &Pictures, out_dir: &Path) -> Result<(), String> {
    let out = |suffix: &str| out_dir.join(format!("{name}.{suffix}"));
    match pictures {
        Pictures::None => Ok(()),
        Pictures::Ik(p) => draw_ik(name, p, &out),
        Pictures::Curve(p) => draw_curve(p, &out("png")),
        Pictures::Cloth(p) => draw_cloth(name, p, &out),
        Pictures::Body(p) => draw_body(name, p, &out),
    }
}

/// The animation, the last frame with the whole target path, and plots of error and
/// iterations per frame.
fn draw_ik(name: &str, p: &IkPictures, out: OutPath) -> Result<(), String> {
    let points = p
        .frames
        .iter()
        .flat_map(|f| f.joints.iter().copied())
        .chain(p.targets.iter().copied());
    let view = View::fit(points, 0.6, 0.45, 480, 480);
    let frames: Vec<IkFrame> = p.frames.iter().map(IkFrame::from).collect();
    if frames.len() > 1 {
        ik_gif(&out("gif"), &view, &frames, &p.targets, 20)?;
    }
    if let Some(last) = frames.last() {
        ik_png(&out("png"), &view, last, &p.targets)?;
    }
    frame_charts(
        out,
        &p.solver,
        &p.error,
        &p.iterations,
        &format!("{name}: final error per frame"),
        "effector to target distance",
        &format!("{name}: iterations per frame"),
    )
}

/// The animation (seen from the front and a little to the side, so both the squat's
/// depth and the hands' circles show), the last frame as a still, and charts of the
/// worst effector error and the iterations per frame.
fn draw_body(name: &str, p: &BodyPictures, out: OutPath) -> Result<(), String> {
    let points = p
        .frames
        .iter()
        .flat_map(|f| f.joints.iter().chain(&f.goals).copied());
    let view = View::fit(points, 0.6, 0.25, 480, 480);
    let layout = BodyLayout {
        parents: &p.parents,
        effectors: &p.effectors,
        pinned: &p.pinned,
    };
    let frames: Vec<BodySnapshot> = p.frames.iter().map(BodySnapshot::from).collect();
    if frames.len() > 1 {
        body_gif(&out("gif"), &view, &layout, &frames, 20)?;
    }
    if let Some(last) = frames.last() {
        body_png(&out("png"), &view, &layout, last)?;
    }
    frame_charts(
        out,
        &p.solver,
        &p.error,
        &p.iterations,
        &format!("{name}: worst effector error per frame"),
        "largest effector to goal distance",
        &format!("{name}: iterations per frame"),
    )
}

/// The charts of an IK track (chain or full body): the error (log scale) and the
/// iterations per frame, as `<name>.error.svg` and `<name>.iterations.svg`; nothing for a
/// single frame, which makes no line.
fn frame_charts(
    out: OutPath,
    solver: &str,
    error: &[f64],
    iterations: &[usize],
    error_title: &str,
    error_axis: &str,
    iterations_title: &str,
) -> Result<(), String> {
    if error.len() <= 1 {
        return Ok(());
    }
    let per_frame = |values: &mut dyn Iterator<Item = f64>| -> Vec<(f64, f64)> {
        values.enumerate().map(|(k, v)| (k as f64, v)).collect()
    };
    let error = per_frame(&mut error.iter().copied());
    let iterations = per_frame(&mut iterations.iter().map(|&i| i as f64));
    let chart = |suffix: &str, title: &str, axis: &str, points: &[(f64, f64)], log: bool| {
        line_chart_svg(
            &out(suffix),
            title,
            "frame",
            axis,
            &[Series {
                name: solver,
                points,
            }],
            log,
        )
    };
    chart("error.svg", error_title, error_axis, &error, true)?;
    chart(
        "iterations.svg",
        iterations_title,
        "iterations",
        &iterations,
        false,
    )
}

/// The Sub-Task 4.1 picture: points at uniform parameter steps next to as many evenly
/// spaced by arc length, on the curve's line.
fn draw_curve(p: &CurvePictures, path: &Path) -> Result<(), String> {
    // Looking straight down (elevation pi/2) shows a curve in the plane y = 0, such as
    // the lab flower, flat.
    samples_png(
        path,
        &p.line,
        ("uniform parameter t", &p.uniform),
        ("even arc length", &p.even),
        0.0,
        std::f64::consts::FRAC_PI_2,
    )
}

/// The animation, the last frame as a still, and charts of the total energy and the
/// Newton iterations per step.
fn draw_cloth(name: &str, p: &ClothPictures, out: OutPath) -> Result<(), String> {
    // The view frames the cloth and every ball's extent (a ground is drawn under the
    // cloth only, so it does not widen the view).
    let ball_extents = p
        .frames
        .iter()
        .flat_map(|f| f.colliders.iter())
        .flat_map(|shape| {
            let balls = match *shape {
                Shape::Sphere { center, radius } => vec![(center, radius)],
                Shape::Capsule { a, b, radius } => vec![(a, radius), (b, radius)],
                Shape::HalfSpace { .. } => Vec::new(),
            };
            balls.into_iter().flat_map(|(c, r)| {
                [DVec3::X, DVec3::Y, DVec3::Z]
                    .into_iter()
                    .flat_map(move |axis| [c + r * axis, c - r * axis])
            })
        });
    let view = View::fit(
        p.frames
            .iter()
            .flat_map(|f| f.positions.iter().copied())
            .chain(ball_extents),
        0.7,
        0.35,
        480,
        480,
    );
    let frames: Vec<ClothFrame> = p.frames.iter().map(ClothFrame::from).collect();
    let fps = 15;
    cloth_gif(&out("gif"), &view, &frames, &p.springs, &p.fixed, 0.05, fps)?;
    if let Some(last) = frames.last() {
        cloth_png(&out("png"), &view, last, &p.springs, &p.fixed, 0.05)?;
    }
    line_chart_svg(
        &out("energy.svg"),
        &format!("{name}: total energy"),
        "time (s)",
        "energy",
        &[Series {
            name: "kinetic + spring + gravity",
            points: &p.energy,
        }],
        false,
    )?;
    if !p.iterations.is_empty() {
        line_chart_svg(
            &out("iterations.svg"),
            &format!("{name}: iterations per step"),
            "time (s)",
            "iterations",
            &[Series {
                name: &p.integrator,
                points: &p.iterations,
            }],
            false,
        )?;
    }
    Ok(())
}
