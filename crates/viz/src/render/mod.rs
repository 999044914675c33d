//! Pictures of scene results: animated GIFs and PNG stills of IK chains, full bodies and
//! cloth, the
//! curve-sampling comparison, and SVG line charts of per-frame metrics.
//!
//! Rendering only reads the data it is given; nothing here feeds back into a simulation,
//! so the metrics of a run are the same with or without pictures. Output is
//! deterministic: the same input gives byte-identical files.
//!
//! Drawing uses `tiny-skia` (antialiased paths, PNG encoding), animations use `gif` with
//! a fixed palette (see the `animation` module), captions use the `font8x8` bitmap font
//! (no font files needed on the machine) and charts use `plotters`' SVG backend, whose
//! text is drawn by the SVG viewer.
//!
//! Degenerate input never panics: points with a NaN or infinite coordinate are skipped
//! (with every line that touches them), and an `Err` is returned only for I/O failures or
//! when there is nothing at all to draw.
//!
//! World convention: `+y` is up. [`View`] is an orthographic camera placed by azimuth
//! (about `+y`, from `+z` towards `+x`) and elevation (above the `xz` plane).

mod animation;
mod body;
mod canvas;
pub mod chart;
mod cloth;
mod ik;
mod pages;
pub mod plot;
mod samples;
mod task;

pub use body::{BodyLayout, BodySnapshot, body_gif, body_png};
pub use chart::{Series, line_chart_svg};
pub use cloth::{ClothFrame, cloth_gif, cloth_png};
pub use ik::{IkFrame, ik_gif, ik_png};
pub use pages::viewer_page;
pub use samples::samples_png;
pub use task::draw_task;

use animation::strain_colour;
use canvas::{Canvas, GLYPH, Px, Rgb, ink};
use sinew_math::DVec3;
use std::path::Path;

/// Smallest image side in pixels; smaller requests are raised to this.
const MIN_SIDE: u32 = 64;
/// Largest image side in pixels; larger requests are lowered to this (GIF sides are
/// 16-bit, and a frame buffer this size is already 64 MiB).
const MAX_SIDE: u32 = 4096;
/// Height of the band kept free at the top of a picture for its caption, in pixels.
const TOP_BAND: f64 = 30.0;
/// Height of the band kept free at the bottom for a legend, in pixels.
const BOTTOM_BAND: f64 = 26.0;

/// An orthographic camera that maps world points to pixels of a `width` x `height` image.
///
/// Built by [`View::fit`], which frames a set of points; one view is shared by every
/// frame of an animation so that the camera does not jump.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// World direction drawn as image right.
    right: DVec3,
    /// World direction drawn as image up.
    up: DVec3,
    /// World direction from the scene towards the camera (larger depth is nearer).
    toward_camera: DVec3,
    /// Projected (right, up) coordinates drawn at the centre of the framed area.
    centre: (f64, f64),
    /// Pixel position where `centre` is drawn.
    centre_px: (f64, f64),
    /// Pixels per world unit.
    scale: f64,
    width: u32,
    height: u32,
}

impl View {
    /// A camera looking from (`azimuth`, `elevation`) (radians) that frames all `points`
    /// with a margin, for an image of `width` x `height` pixels.
    ///
    /// Azimuth turns about `+y` from `+z` towards `+x`; elevation 0 looks horizontally and
    /// `pi/2` looks straight down (then image up is `-z` turned by the azimuth). A band at
    /// the top and bottom is left free for the caption and the legend. Points with a
    /// non-finite coordinate are ignored; with no finite point the view frames a unit
    /// box at the origin, and a single point is framed as a unit box around it. A non-finite angle counts as 0, and the
    /// sides are clamped to 64..=4096 pixels.
    #[must_use]
    pub fn fit(
        points: impl IntoIterator<Item = DVec3>,
        azimuth: f64,
        elevation: f64,
        width: u32,
        height: u32,
    ) -> View {
        let mut view = View::oriented(azimuth, elevation, width, height);
        let area = (0.0, 0.0, f64::from(view.width), f64::from(view.height));
        view.frame(points, area, 1.0);
        view
    }

    /// A view with its orientation and size set, framing a unit box at the origin.
    fn oriented(azimuth: f64, elevation: f64, width: u32, height: u32) -> View {
        let azimuth = if azimuth.is_finite() { azimuth } else { 0.0 };
        let elevation = if elevation.is_finite() {
            elevation
        } else {
            0.0
        };
        let (sin_az, cos_az) = azimuth.sin_cos();
        let (sin_el, cos_el) = elevation.sin_cos();
        // Right does not depend on elevation, so looking straight down is not singular.
        let right = DVec3::new(cos_az, 0.0, -sin_az);
        let toward_camera = DVec3::new(cos_el * sin_az, sin_el, cos_el * cos_az);
        let up = toward_camera.cross(right);
        View {
            right,
            up,
            toward_camera,
            centre: (0.0, 0.0),
            centre_px: (0.0, 0.0),
            scale: 1.0,
            width: width.clamp(MIN_SIDE, MAX_SIDE),
            height: height.clamp(MIN_SIDE, MAX_SIDE),
        }
    }

    /// Sets centre and scale so that `points` fill the sub-rectangle `area`
    /// (x, y, width, height in pixels) less its margins; `min_extent` is the smallest
    /// world extent framed, so a single point is not magnified without bound.
    fn frame(
        &mut self,
        points: impl IntoIterator<Item = DVec3>,
        area: (f64, f64, f64, f64),
        min_extent: f64,
    ) {
        let mut lo = (f64::INFINITY, f64::INFINITY);
        let mut hi = (f64::NEG_INFINITY, f64::NEG_INFINITY);
        for p in points {
            if !p.is_finite() {
                continue;
            }
            let (x, y) = (p.dot(self.right), p.dot(self.up));
            lo = (lo.0.min(x), lo.1.min(y));
            hi = (hi.0.max(x), hi.1.max(y));
        }
        let (centre, extent) = if lo.0 <= hi.0 {
            (
                (0.5 * (lo.0 + hi.0), 0.5 * (lo.1 + hi.1)),
                (hi.0 - lo.0, hi.1 - lo.1),
            )
        } else {
            ((0.0, 0.0), (min_extent, min_extent))
        };
        // When both extents are tiny, frame `min_extent`; a flat set (one extent zero)
        // is framed by its other extent alone.
        let extent = if extent.0.max(extent.1) < 1e-12 {
            (min_extent, min_extent)
        } else {
            extent
        };
        let (x0, y0, w, h) = area;
        let side_margin = 12.0 + 0.04 * w.min(h);
        let usable_w = (w - 2.0 * side_margin).max(8.0);
        let usable_h = (h - 2.0 * side_margin - TOP_BAND - BOTTOM_BAND).max(8.0);
        let scale_x = if extent.0 > 0.0 {
            usable_w / extent.0
        } else {
            f64::INFINITY
        };
        let scale_y = if extent.1 > 0.0 {
            usable_h / extent.1
        } else {
            f64::INFINITY
        };
        self.scale = scale_x.min(scale_y);
        self.centre = centre;
        // Shift so that the projected centre lands in the middle of the usable area.
        let mid_x = x0 + 0.5 * w;
        let mid_y = y0 + side_margin + TOP_BAND + 0.5 * usable_h;
        self.centre_px = (mid_x, mid_y);
    }

    /// Image width in pixels.
    #[must_use]
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Image height in pixels.
    #[must_use]
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Pixel position of world point `p` (x right, y down), or `None` if `p` is not
    /// finite.
    #[must_use]
    pub fn project(&self, p: DVec3) -> Option<(f32, f32)> {
        if !p.is_finite() {
            return None;
        }
        let x = self.centre_px.0 + (p.dot(self.right) - self.centre.0) * self.scale;
        let y = self.centre_px.1 - (p.dot(self.up) - self.centre.1) * self.scale;
        // Far off-image points are clamped well outside the image; segments to them are
        // clipped before drawing (see `canvas`), so the clamp only bounds the numbers.
        let limit = 1e7;
        Some((x.clamp(-limit, limit) as f32, y.clamp(-limit, limit) as f32))
    }

    /// Distance of `p` towards the camera (larger is nearer), for drawing far things
    /// first.
    #[must_use]
    fn depth(&self, p: DVec3) -> f64 {
        p.dot(self.toward_camera)
    }

    /// Image direction (x right, y down) of a world direction, unit length in pixels per
    /// world unit; used for the axis gizmo.
    fn screen_direction(&self, d: DVec3) -> (f64, f64) {
        (d.dot(self.right), -d.dot(self.up))
    }
}

/// Creates the folder that will hold `path`, if it has one.
fn create_parent(path: &Path) -> Result<(), String> {
    match path.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => std::fs::create_dir_all(parent)
            .map_err(|e| format!("cannot create folder {}: {e}", parent.display())),
        _ => Ok(()),
    }
}

/// Writes `bytes` to `path`, creating its folder.
fn write_file(path: &Path, bytes: &[u8]) -> Result<(), String> {
    create_parent(path)?;
    std::fs::write(path, bytes).map_err(|e| format!("cannot write {}: {e}", path.display()))
}

/// A sample shown in front of a legend entry.
#[derive(Clone, Copy)]
enum Mark {
    /// A short line of the given colour and width.
    Line(Rgb, f32),
    /// A disc of the given colour and radius.
    Dot(Rgb, f32),
    /// The IK target marker.
    Target,
    /// The fixed-particle marker.
    Pin,
    /// The spring-strain colour bar, labelled with the strain at each end.
    StrainBar(f64),
}

/// Writes the caption lines in the top-left corner, the world axes in the top-right and
/// the legend along the bottom: what every still of a skeleton carries.
fn annotate(
    canvas: &mut Canvas,
    view: &View,
    caption: &[impl AsRef<str>],
    entries: &[(Mark, &str)],
) {
    let max_caption = canvas.width() as f32 - 80.0;
    let lines: Vec<&str> = caption.iter().map(AsRef::as_ref).collect();
    canvas.caption(8.0, 8.0, &lines, max_caption);
    axis_gizmo(canvas, view);
    legend(canvas, entries);
}

/// Draws the legend entries in a row along the bottom of the canvas.
fn legend(canvas: &mut Canvas, entries: &[(Mark, &str)]) {
    let y_mid = canvas.height() as f32 - BOTTOM_BAND as f32 * 0.5 - 2.0;
    let text_top = y_mid - GLYPH * 0.5;
    let mut x = 12.0;
    for &(mark, label) in entries {
        match mark {
            Mark::Line(rgb, width) => {
                canvas.segment(Some((x, y_mid)), Some((x + 16.0, y_mid)), width, rgb);
                x += 22.0;
            }
            Mark::Dot(rgb, radius) => {
                canvas.dot(Some((x + radius, y_mid)), radius, rgb);
                x += 2.0 * radius + 6.0;
            }
            Mark::Target => {
                draw_target(canvas, Some((x + 8.0, y_mid)), 0.7);
                x += 22.0;
            }
            Mark::Pin => {
                draw_pin(canvas, Some((x + 5.0, y_mid)));
                x += 16.0;
            }
            Mark::StrainBar(scale) => {
                let low = format!("{} ", format_strain(-scale));
                canvas.text(x, text_top, &low, 1, ink::TEXT);
                x += Canvas::text_width(&low, 1);
                let (bar_w, steps) = (120.0, 60);
                for k in 0..steps {
                    let t = 2.0 * (f64::from(k) + 0.5) / f64::from(steps) - 1.0;
                    let step_w = bar_w / steps as f32;
                    canvas.rect(
                        x + k as f32 * step_w,
                        y_mid - 5.0,
                        step_w,
                        10.0,
                        strain_colour(t),
                    );
                }
                x += bar_w + 4.0;
                let high = format_strain(scale);
                canvas.text(x, text_top, &high, 1, ink::TEXT);
                x += Canvas::text_width(&high, 1) + 6.0;
            }
        }
        canvas.text(x, text_top, label, 1, ink::TEXT);
        x += Canvas::text_width(label, 1) + 16.0;
    }
}

/// Draws the IK target marker (a ring with a cross) at `size` times its full size.
fn draw_target(canvas: &mut Canvas, centre: Px, size: f32) {
    canvas.ring(centre, 9.0 * size, 2.5, ink::TARGET);
    canvas.cross(centre, 4.5 * size, 2.0, ink::TARGET);
}

/// Draws the fixed-particle marker: a black disc with a white centre.
fn draw_pin(canvas: &mut Canvas, centre: Px) {
    canvas.dot(centre, 5.0, ink::FIXED);
    canvas.dot(centre, 2.0, ink::BACKGROUND);
}

/// Draws the world axes as seen by `view` in the top-right corner, so that the
/// orientation of an orthographic picture can be read.
fn axis_gizmo(canvas: &mut Canvas, view: &View) {
    let centre = (canvas.width() as f32 - 36.0, 38.0);
    let length = 22.0;
    let axes = [
        (DVec3::X, ink::AXIS_X, "x"),
        (DVec3::Y, ink::AXIS_Y, "y"),
        (DVec3::Z, ink::AXIS_Z, "z"),
    ];
    // Axes pointing away from the camera are drawn first, so nearer ones stay on top.
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| view.depth(axes[a].0).total_cmp(&view.depth(axes[b].0)));
    for index in order {
        let (axis, rgb, name) = axes[index];
        let (dx, dy) = view.screen_direction(axis);
        let tip = (centre.0 + length * dx as f32, centre.1 + length * dy as f32);
        canvas.segment(Some(centre), Some(tip), 2.0, rgb);
        let reach = dx.hypot(dy);
        // An axis seen end-on has no direction to label along.
        if reach > 0.25 {
            let (ux, uy) = ((dx / reach) as f32, (dy / reach) as f32);
            let at = (tip.0 + 7.0 * ux - 4.0, tip.1 + 7.0 * uy - 4.0);
            canvas.text(at.0, at.1, name, 1, rgb);
        }
    }
}

/// Strain as a signed percentage with enough digits to tell small strains apart.
#[must_use]
fn format_strain(strain: f64) -> String {
    let percent = strain * 100.0;
    if !percent.is_finite() {
        "n/a".to_string()
    } else if percent == 0.0 {
        "0%".to_string()
    } else if percent.abs() >= 0.1 {
        format!("{percent:+.1}%")
    } else {
        format!("{percent:+.1e}%")
    }
}

/// A length in scientific notation, or `n/a` when it is not finite.
#[must_use]
fn format_length(x: f64) -> String {
    if x.is_finite() {
        format!("{x:.2e}")
    } else {
        "n/a".to_string()
    }
}

/// How many of `path_len` path points belong to frame `index` of `frame_count`: the
/// path is spread evenly over the frames, so with one path point per frame frame `k`
/// shows points `0..=k`.
#[must_use]
fn path_shown(index: usize, frame_count: usize, path_len: usize) -> usize {
    if frame_count == 0 {
        return path_len;
    }
    ((index + 1) * path_len).div_ceil(frame_count).min(path_len)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn fit_keeps_every_point_inside_the_framed_area() {
        let points = [
            DVec3::new(-1.0, 0.2, 3.0),
            DVec3::new(2.0, -0.5, 0.0),
            DVec3::new(0.3, 4.0, -1.0),
            DVec3::new(f64::NAN, 0.0, 0.0),
        ];
        for (azimuth, elevation) in [(0.0, 0.0), (0.6, 0.45), (-2.0, FRAC_PI_2), (3.0, -0.7)] {
            let view = View::fit(points, azimuth, elevation, 480, 360);
            let mut touches = [false; 2];
            for p in points.iter().filter(|p| p.is_finite()) {
                let (x, y) = view.project(*p).unwrap();
                assert!(x > 12.0 && x < 468.0, "x {x} at {azimuth}, {elevation}");
                assert!(
                    y > 12.0 + TOP_BAND as f32 && y < 348.0 - BOTTOM_BAND as f32,
                    "y {y}"
                );
                touches[0] |= !(40.0..=440.0).contains(&x);
                touches[1] |= !(80.0..=300.0).contains(&y);
            }
            // The fit is tight along at least one image axis.
            assert!(
                touches[0] || touches[1],
                "loose fit at {azimuth}, {elevation}"
            );
        }
    }

    #[test]
    fn orientation_follows_azimuth_and_elevation() {
        let box_points = [DVec3::splat(-1.0), DVec3::splat(1.0)];
        let front = View::fit(box_points, 0.0, 0.0, 400, 400);
        let o = front.project(DVec3::ZERO).unwrap();
        let x = front.project(DVec3::X).unwrap();
        let y = front.project(DVec3::Y).unwrap();
        let z = front.project(DVec3::Z).unwrap();
        assert!(x.0 > o.0 && (x.1 - o.1).abs() < 1e-3, "+x is right");
        assert!(y.1 < o.1 && (y.0 - o.0).abs() < 1e-3, "+y is up");
        assert!(
            (z.0 - o.0).abs() < 1e-3 && (z.1 - o.1).abs() < 1e-3,
            "+z faces us"
        );
        assert!(front.depth(DVec3::Z) > front.depth(DVec3::ZERO));

        let top = View::fit(box_points, 0.0, FRAC_PI_2, 400, 400);
        let o = top.project(DVec3::ZERO).unwrap();
        let x = top.project(DVec3::X).unwrap();
        let z = top.project(DVec3::Z).unwrap();
        assert!(x.0 > o.0, "+x is right from above");
        assert!(
            z.1 > o.1 && (z.0 - o.0).abs() < 1e-3,
            "+z is down from above"
        );
    }

    #[test]
    fn degenerate_input_gives_a_usable_view() {
        let nothing = View::fit([], f64::NAN, f64::INFINITY, 0, 100_000);
        assert_eq!((nothing.width(), nothing.height()), (MIN_SIDE, MAX_SIDE));
        assert!(nothing.scale.is_finite() && nothing.scale > 0.0);
        let single = View::fit([DVec3::ONE], 0.3, 0.2, 200, 200);
        assert!(single.scale.is_finite());
        let (x, y) = single.project(DVec3::ONE).unwrap();
        assert!((0.0..200.0).contains(&x) && (0.0..200.0).contains(&y));
        assert_eq!(single.project(DVec3::new(0.0, f64::NAN, 0.0)), None);
    }

    #[test]
    fn path_is_spread_over_the_frames() {
        assert_eq!(path_shown(0, 10, 10), 1);
        assert_eq!(path_shown(9, 10, 10), 10);
        assert_eq!(path_shown(4, 10, 100), 50);
        assert_eq!(path_shown(0, 3, 0), 0);
        assert_eq!(path_shown(2, 3, 1), 1);
    }

    #[test]
    fn same_input_same_bytes() {
        let dir = std::env::temp_dir().join(format!("sinew-render-{}", std::process::id()));
        let joints = [DVec3::ZERO, DVec3::X, DVec3::new(1.0, 1.0, 0.0)];
        let path = [DVec3::Y, DVec3::new(1.0, 1.2, 0.0)];
        let view = View::fit(joints.iter().chain(&path).copied(), 0.4, 0.3, 160, 120);
        let frame = IkFrame {
            joints: &joints,
            target: path[1],
        };
        let (a, b) = (dir.join("a.png"), dir.join("b.png"));
        ik_png(&a, &view, &frame, &path).unwrap();
        ik_png(&b, &view, &frame, &path).unwrap();
        let (a_bytes, b_bytes) = (std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
        std::fs::remove_dir_all(&dir).ok();
        assert_eq!(a_bytes, b_bytes);
    }
}
