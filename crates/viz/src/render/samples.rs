//! The curve-sampling picture: two sets of samples of one curve side by side (for the
//! flower, uniform parameter steps against even arc-length spacing), as dots on the
//! curve's line, so that bunching is visible at a glance and quantified underneath.

use super::View;
use super::canvas::{Canvas, Rgb, ink};
use sinew_math::DVec3;
use std::path::Path;

/// Width and height of each of the two panels, in pixels.
const PANEL: u32 = 480;

/// Writes a PNG with two panels framed by the same orthographic camera (`azimuth`,
/// `elevation` as in [`View::fit`]): each shows `curve_line` as a thin grey line and its
/// samples as dots (blue on the left, orange on the right), titled with the set's name.
/// At the bottom of each panel: the number of samples and the ratio of the largest to
/// the smallest distance between consecutive samples (1 for perfectly even spacing). Non-finite points
/// are skipped.
///
/// # Errors
/// When the curve and both sample sets are all empty, or the file cannot be written.
pub fn samples_png(
    path: &Path,
    curve_line: &[DVec3],
    left: (&str, &[DVec3]),
    right: (&str, &[DVec3]),
    azimuth: f64,
    elevation: f64,
) -> Result<(), String> {
    if curve_line.is_empty() && left.1.is_empty() && right.1.is_empty() {
        return Err(format!(
            "sampling picture {}: no curve and no samples to draw",
            path.display()
        ));
    }
    let all = curve_line.iter().chain(left.1).chain(right.1).copied();
    let left_view = View::fit(all, azimuth, elevation, PANEL, PANEL);
    let mut right_view = left_view;
    right_view.centre_px.0 += f64::from(PANEL);

    let mut canvas = Canvas::new(2 * PANEL, PANEL)?;
    let panels = [
        (&left_view, left, ink::SAMPLE_LEFT, 0.0),
        (&right_view, right, ink::SAMPLE_RIGHT, PANEL as f32),
    ];
    for (view, (name, samples), rgb, x0) in panels {
        draw_panel(&mut canvas, view, curve_line, name, samples, rgb, x0);
    }
    let divider = PANEL as f32;
    canvas.segment(
        Some((divider, 0.0)),
        Some((divider, PANEL as f32)),
        1.0,
        ink::CURVE,
    );
    canvas.save_png(path)
}

/// Draws one panel whose left edge is at `x0`.
fn draw_panel(
    canvas: &mut Canvas,
    view: &View,
    curve_line: &[DVec3],
    name: &str,
    samples: &[DVec3],
    rgb: Rgb,
    x0: f32,
) {
    canvas.polyline(curve_line.iter().map(|&p| view.project(p)), 1.5, ink::CURVE);
    for &p in samples {
        canvas.dot(view.project(p), 3.5, rgb);
    }
    canvas.caption(x0 + 8.0, 8.0, &[name], PANEL as f32 - 16.0);
    let finite: Vec<DVec3> = samples.iter().copied().filter(|p| p.is_finite()).collect();
    let gaps: Vec<f64> = finite.windows(2).map(|w| w[0].distance(w[1])).collect();
    let smallest = gaps.iter().copied().fold(f64::INFINITY, f64::min);
    let largest = gaps.iter().copied().fold(0.0, f64::max);
    let summary = if gaps.is_empty() {
        format!("{} points", samples.len())
    } else if smallest > 0.0 {
        format!(
            "{} points, gap max/min {:.1}",
            samples.len(),
            largest / smallest
        )
    } else {
        format!("{} points, some coincide", samples.len())
    };
    let y = PANEL as f32 - 32.0;
    canvas.caption(x0 + 8.0, y, &[&summary], PANEL as f32 - 16.0);
}
