//! Pictures of a mass-spring cloth: springs drawn as lines coloured by strain and fixed
//! particles marked, as an animated GIF and a PNG still, over the colliders it touches
//! (the ground as a grid of lines under the sheet, a sphere as its outline, a capsule as
//! its two end outlines joined by its sides).
//!
//! Strain is `l / L - 1` (current over rest length, minus one). Colours run from blue
//! (compressed by `strain_scale` or more) through grey (at rest) to red (stretched by
//! `strain_scale` or more). The scale is fixed for a whole animation so that colours
//! compare across frames.

use super::animation::{GifWriter, frames_to_draw_or_err, strain_colour};
use super::canvas::ink;
use super::canvas::{Canvas, Px};
use super::{Mark, View, annotate, draw_pin, format_strain};
use sinew_math::DVec3;
use sinew_scene::results::Shape;
use std::path::Path;

/// One frame of a cloth run: every particle's world position.
#[derive(Clone, Copy, Debug)]
pub struct ClothFrame<'a> {
    /// Particle positions, indexed as in the springs and the fixed list.
    pub positions: &'a [DVec3],
    /// The colliders, posed at the frame's time (empty without contact).
    pub colliders: &'a [Shape],
}

impl<'a> From<&'a sinew_scene::results::ClothFrame> for ClothFrame<'a> {
    /// The frame of a `Cloth` task's result, as drawn.
    fn from(f: &'a sinew_scene::results::ClothFrame) -> Self {
        ClothFrame {
            positions: &f.positions,
            colliders: &f.colliders,
        }
    }
}

/// Writes an animated GIF of the cloth: each spring `(i, j, rest_length)` as a line
/// coloured by its strain on the symmetric scale `±strain_scale`, fixed particles as
/// pins, captioned with the frame number and the strain range of the frame.
///
/// Springs are drawn far to near so that nearer ones stay on top. A spring with an index
/// out of range, a non-positive or non-finite rest length or a non-finite end is
/// skipped. If `strain_scale` is not a positive finite number, the largest strain
/// magnitude over all frames is used instead. Plays at `fps` (clamped to 1..=50), holds
/// the last frame for 1.5 s and loops; runs longer than 300 frames are thinned evenly.
///
/// # Errors
/// When `frames` is empty, or the file cannot be written.
pub fn cloth_gif(
    path: &Path,
    view: &View,
    frames: &[ClothFrame],
    springs: &[(usize, usize, f64)],
    fixed: &[usize],
    strain_scale: f64,
    fps: u16,
) -> Result<(), String> {
    let picked = frames_to_draw_or_err(frames.len(), "cloth animation", path)?;
    let scale = resolve_scale(strain_scale, picked.iter().map(|&k| &frames[k]), springs);
    let mut gif = GifWriter::create(path, view.width(), view.height(), fps)?;
    for index in picked {
        let label = format!("frame {}/{}", index + 1, frames.len());
        let canvas = draw(view, &frames[index], springs, fixed, scale, &label)?;
        gif.add(&canvas)?;
    }
    gif.finish()
}

/// Writes a PNG still of one cloth frame, drawn as by [`cloth_gif`].
///
/// # Errors
/// When the file cannot be written.
pub fn cloth_png(
    path: &Path,
    view: &View,
    frame: &ClothFrame,
    springs: &[(usize, usize, f64)],
    fixed: &[usize],
    strain_scale: f64,
) -> Result<(), String> {
    let scale = resolve_scale(strain_scale, [frame], springs);
    draw(view, frame, springs, fixed, scale, "")?.save_png(path)
}

/// Strain `l / L - 1` of a spring in a frame, or `None` if it cannot be computed.
#[must_use]
fn strain(positions: &[DVec3], spring: (usize, usize, f64)) -> Option<f64> {
    let (i, j, rest) = spring;
    let (a, b) = (positions.get(i)?, positions.get(j)?);
    if !(rest.is_finite() && rest > 0.0) {
        return None;
    }
    let s = a.distance(*b) / rest - 1.0;
    s.is_finite().then_some(s)
}

/// `requested` if it is a usable colour scale, otherwise the largest strain magnitude in
/// `frames` (or 1% if every spring is at rest).
#[must_use]
fn resolve_scale<'f, 'a: 'f>(
    requested: f64,
    frames: impl IntoIterator<Item = &'f ClothFrame<'a>>,
    springs: &[(usize, usize, f64)],
) -> f64 {
    if requested.is_finite() && requested > 0.0 {
        return requested;
    }
    let largest = frames
        .into_iter()
        .flat_map(|f| springs.iter().filter_map(|&s| strain(f.positions, s)))
        .fold(0.0_f64, |m, s| m.max(s.abs()));
    if largest > 0.0 { largest } else { 0.01 }
}

/// Draws one frame; `label` (may be empty) is the caption's first line.
fn draw(
    view: &View,
    frame: &ClothFrame,
    springs: &[(usize, usize, f64)],
    fixed: &[usize],
    scale: f64,
    label: &str,
) -> Result<Canvas, String> {
    let mut canvas = Canvas::new(view.width(), view.height())?;
    let positions = frame.positions;
    // Colliders first, so the cloth lying on them is drawn on top.
    for shape in frame.colliders {
        draw_collider(&mut canvas, view, shape, positions);
    }
    // (depth, strain, ends) of every drawable spring.
    let mut lines: Vec<(f64, f64, Px, Px)> = springs
        .iter()
        .filter_map(|&spring| {
            let s = strain(positions, spring)?;
            let (a, b) = (positions[spring.0], positions[spring.1]);
            let depth = view.depth(0.5 * (a + b));
            depth
                .is_finite()
                .then(|| (depth, s, view.project(a), view.project(b)))
        })
        .collect();
    // Far to near; the sort is stable, so equal depths keep the springs' order.
    lines.sort_by(|x, y| x.0.total_cmp(&y.0));
    let width = if lines.len() <= 2000 { 2.0 } else { 1.0 };
    for &(_, s, a, b) in &lines {
        canvas.segment(a, b, width, strain_colour(s / scale));
    }
    for &index in fixed {
        if let Some(&p) = positions.get(index) {
            draw_pin(&mut canvas, view.project(p));
        }
    }

    let range = lines
        .iter()
        .map(|l| l.1)
        .fold(None, |acc: Option<(f64, f64)>, s| {
            Some(acc.map_or((s, s), |(lo, hi)| (lo.min(s), hi.max(s))))
        });
    let strain_text = match range {
        Some((lo, hi)) => format!("strain {} .. {}", format_strain(lo), format_strain(hi)),
        None => "no springs".to_string(),
    };
    let lines: Vec<&str> = [label, strain_text.as_str()]
        .into_iter()
        .filter(|l| !l.is_empty())
        .collect();
    annotate(
        &mut canvas,
        view,
        &lines,
        &[(Mark::StrainBar(scale), "strain"), (Mark::Pin, "fixed")],
    );
    Ok(canvas)
}

/// Draws one collider. The view is orthographic, so a ball's outline is the circle of its
/// radius (times the view's scale) around its projected centre, and a capsule's is its
/// end circles joined by the two lines its sides project to.
fn draw_collider(canvas: &mut Canvas, view: &View, shape: &Shape, positions: &[DVec3]) {
    match *shape {
        Shape::HalfSpace { point, normal } => {
            // A square patch of the plane under the cloth: centred below the particles'
            // centroid, as wide as the cloth's spread plus a margin, ruled every fifth.
            let finite: Vec<DVec3> = positions
                .iter()
                .copied()
                .filter(|p| p.is_finite())
                .collect();
            if finite.is_empty() {
                return;
            }
            let centroid = finite.iter().copied().sum::<DVec3>() / finite.len() as f64;
            let centre = centroid - normal.dot(centroid - point) * normal;
            let t1 = normal.any_orthonormal_vector();
            let t2 = normal.cross(t1);
            let spread = finite
                .iter()
                .map(|p| (*p - centre).reject_from_normalized(normal).length())
                .fold(0.0f64, f64::max);
            let half = 1.2 * spread.max(1e-3);
            for k in 0..=10 {
                let s = half * (k as f64 / 5.0 - 1.0);
                for (u, v) in [(t1, t2), (t2, t1)] {
                    let a = centre + s * u - half * v;
                    let b = centre + s * u + half * v;
                    canvas.segment(view.project(a), view.project(b), 1.0, ink::CURVE);
                }
            }
        }
        Shape::Sphere { center, radius } => {
            canvas.ring(
                view.project(center),
                (radius * view.scale) as f32,
                1.5,
                ink::ROOT,
            );
        }
        Shape::Capsule { a, b, radius } => {
            let r = (radius * view.scale) as f32;
            let (pa, pb) = (view.project(a), view.project(b));
            canvas.ring(pa, r, 1.5, ink::ROOT);
            canvas.ring(pb, r, 1.5, ink::ROOT);
            if let (Some(pa), Some(pb)) = (pa, pb) {
                let (dx, dy) = (pb.0 - pa.0, pb.1 - pa.1);
                let len = (dx * dx + dy * dy).sqrt();
                if len > 0.0 {
                    // The sides are the axis shifted by the radius across it on screen.
                    let (nx, ny) = (-dy / len * r, dx / len * r);
                    for sign in [-1.0f32, 1.0] {
                        canvas.segment(
                            Some((pa.0 + sign * nx, pa.1 + sign * ny)),
                            Some((pb.0 + sign * nx, pb.1 + sign * ny)),
                            1.5,
                            ink::ROOT,
                        );
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strain_is_length_over_rest_minus_one() {
        let p = [
            DVec3::ZERO,
            DVec3::new(0.0, 0.3, 0.4),
            DVec3::splat(f64::NAN),
        ];
        assert_eq!(strain(&p, (0, 1, 0.5)), Some(0.0));
        assert!((strain(&p, (0, 1, 0.4)).unwrap() - 0.25).abs() < 1e-15);
        assert!((strain(&p, (1, 0, 1.0)).unwrap() + 0.5).abs() < 1e-15);
        assert_eq!(strain(&p, (0, 2, 1.0)), None, "NaN end");
        assert_eq!(strain(&p, (0, 3, 1.0)), None, "index out of range");
        assert_eq!(strain(&p, (0, 1, 0.0)), None, "zero rest length");
        assert_eq!(strain(&p, (0, 1, -1.0)), None, "negative rest length");
    }

    #[test]
    fn unusable_scale_falls_back_to_the_largest_strain() {
        let p = [DVec3::ZERO, DVec3::X, DVec3::new(3.0, 0.0, 0.0)];
        let frame = ClothFrame {
            positions: &p,
            colliders: &[],
        };
        let springs = [(0, 1, 0.8), (1, 2, 2.5)];
        assert_eq!(resolve_scale(0.1, [&frame], &springs), 0.1);
        // Strains are 0.25 and -0.2.
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!((resolve_scale(bad, [&frame], &springs) - 0.25).abs() < 1e-15);
        }
        assert_eq!(resolve_scale(f64::NAN, [&frame], &[]), 0.01);
    }

    #[test]
    fn a_sphere_is_drawn_as_its_outline() {
        // Two particles frame the view; a sphere of radius 0.5 at the origin.
        let p = [DVec3::new(-1.0, -1.0, 0.0), DVec3::new(1.0, 1.0, 0.0)];
        let view = View::fit(p.iter().copied(), 0.0, 0.0, 200, 200);
        let spheres = [Shape::Sphere {
            center: DVec3::ZERO,
            radius: 0.5,
        }];
        let pixel = |canvas: &Canvas, (x, y): (f32, f32)| {
            let i = 4 * (y.round() as usize * canvas.width() as usize + x.round() as usize);
            canvas.rgba()[i..i + 3].to_vec()
        };
        let with = draw(
            &view,
            &ClothFrame {
                positions: &p,
                colliders: &spheres,
            },
            &[],
            &[],
            0.05,
            "",
        )
        .unwrap();
        let without = draw(
            &view,
            &ClothFrame {
                positions: &p,
                colliders: &[],
            },
            &[],
            &[],
            0.05,
            "",
        )
        .unwrap();
        let centre = view.project(DVec3::ZERO).unwrap();
        let on_ring = view.project(DVec3::new(0.5, 0.0, 0.0)).unwrap();
        let white = vec![255u8, 255, 255];
        assert_eq!(pixel(&with, centre), white, "the ball is not filled");
        assert_ne!(pixel(&with, on_ring), white, "the outline is drawn");
        assert_eq!(
            pixel(&without, on_ring),
            white,
            "nothing there without the sphere"
        );
    }
}
