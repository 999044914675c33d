//! A raster canvas over `tiny-skia`: antialiased lines, dots and markers that skip
//! missing points, captions in the `font8x8` bitmap font, and PNG output.
//!
//! Points arrive as `Option<(f32, f32)>` pixel positions (`None` for a world point that
//! was not finite), so every drawing call can skip what cannot be drawn instead of
//! failing. Segments are clipped to a slightly enlarged image rectangle before they reach
//! `tiny-skia`, which keeps coordinates small whatever the camera.

use std::path::Path;
use tiny_skia::{
    Color, FillRule, LineCap, LineJoin, Paint, PathBuilder, Pixmap, Rect, Stroke, Transform,
};

/// An opaque colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Rgb(pub u8, pub u8, pub u8);

impl Rgb {
    /// The colour a fraction `t` (clamped to 0..=1) of the way from `self` to `other`.
    #[must_use]
    pub(super) fn mix(self, other: Rgb, t: f64) -> Rgb {
        let t = if t.is_finite() {
            t.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let lerp = |a: u8, b: u8| (f64::from(a) + (f64::from(b) - f64::from(a)) * t).round() as u8;
        Rgb(
            lerp(self.0, other.0),
            lerp(self.1, other.1),
            lerp(self.2, other.2),
        )
    }
}

/// The colours the pictures are drawn with. The GIF palette is built from these (see
/// `animation`), so each is reproduced exactly in animations.
pub(super) mod ink {
    use super::Rgb;
    /// Picture background.
    pub const BACKGROUND: Rgb = Rgb(255, 255, 255);
    /// Caption and legend text.
    pub const TEXT: Rgb = Rgb(25, 25, 25);
    /// Box behind captions.
    pub const CAPTION_BOX: Rgb = Rgb(238, 240, 244);
    /// Target path (IK).
    pub const PATH: Rgb = Rgb(120, 160, 220);
    /// Bones (IK).
    pub const BONE: Rgb = Rgb(60, 70, 95);
    /// Joints (IK) and free particles (cloth).
    pub const JOINT: Rgb = Rgb(20, 20, 20);
    /// End effector (IK).
    pub const EFFECTOR: Rgb = Rgb(245, 150, 20);
    /// Target marker (IK).
    pub const TARGET: Rgb = Rgb(215, 25, 45);
    /// Chain root (IK).
    pub const ROOT: Rgb = Rgb(130, 130, 130);
    /// World x axis in the gizmo.
    pub const AXIS_X: Rgb = Rgb(205, 50, 50);
    /// World y axis in the gizmo.
    pub const AXIS_Y: Rgb = Rgb(40, 150, 60);
    /// World z axis in the gizmo.
    pub const AXIS_Z: Rgb = Rgb(50, 90, 210);
    /// Curve line under sample dots.
    pub const CURVE: Rgb = Rgb(185, 185, 185);
    /// Samples in the left panel.
    pub const SAMPLE_LEFT: Rgb = Rgb(30, 110, 190);
    /// Samples in the right panel.
    pub const SAMPLE_RIGHT: Rgb = Rgb(225, 95, 15);
    /// Springs at their rest length.
    pub const STRAIN_ZERO: Rgb = Rgb(160, 160, 160);
    /// Springs compressed to the end of the colour scale.
    pub const STRAIN_COMPRESSED: Rgb = Rgb(30, 80, 225);
    /// Springs stretched to the end of the colour scale.
    pub const STRAIN_STRETCHED: Rgb = Rgb(220, 30, 25);
    /// Fixed (pinned) particles.
    pub const FIXED: Rgb = Rgb(0, 0, 0);

    /// Every ink above, for building palettes.
    pub const ALL: [Rgb; 19] = [
        BACKGROUND,
        TEXT,
        CAPTION_BOX,
        PATH,
        BONE,
        JOINT,
        EFFECTOR,
        TARGET,
        ROOT,
        AXIS_X,
        AXIS_Y,
        AXIS_Z,
        CURVE,
        SAMPLE_LEFT,
        SAMPLE_RIGHT,
        STRAIN_ZERO,
        STRAIN_COMPRESSED,
        STRAIN_STRETCHED,
        FIXED,
    ];
}

/// A pixel position, or `None` when the world point behind it was not finite.
pub(super) type Px = Option<(f32, f32)>;

/// Pixels of slack around the image inside which segments are kept after clipping, so
/// that thick lines and round caps leaving the image are still drawn correctly.
const CLIP_SLACK: f32 = 32.0;

/// Horizontal advance and height of one `font8x8` glyph at scale 1, in pixels.
pub(super) const GLYPH: f32 = 8.0;

/// An opaque raster image being drawn.
pub(super) struct Canvas {
    pixmap: Pixmap,
}

impl Canvas {
    /// A `width` x `height` canvas filled with the background colour.
    pub(super) fn new(width: u32, height: u32) -> Result<Canvas, String> {
        let mut pixmap = Pixmap::new(width, height)
            .ok_or_else(|| format!("cannot allocate a {width}x{height} picture"))?;
        pixmap.fill(color(ink::BACKGROUND));
        Ok(Canvas { pixmap })
    }

    /// Image width in pixels.
    pub(super) fn width(&self) -> u32 {
        self.pixmap.width()
    }

    /// Image height in pixels.
    pub(super) fn height(&self) -> u32 {
        self.pixmap.height()
    }

    /// The RGBA bytes of the image (opaque, so premultiplied equals straight alpha).
    pub(super) fn rgba(&self) -> &[u8] {
        self.pixmap.data()
    }

    /// Draws a line through `points`, `width` pixels thick with round caps and joins,
    /// broken wherever a point is `None`.
    pub(super) fn polyline(&mut self, points: impl IntoIterator<Item = Px>, width: f32, rgb: Rgb) {
        let mut builder = PathBuilder::new();
        let mut pen: Option<(f32, f32)> = None;
        let mut previous: Px = None;
        for point in points {
            if let (Some(a), Some(b)) = (previous, point)
                && let Some((ca, cb)) = self.clip(a, b)
            {
                if pen != Some(ca) {
                    builder.move_to(ca.0, ca.1);
                }
                builder.line_to(cb.0, cb.1);
                pen = Some(cb);
            }
            previous = point;
        }
        if let Some(path) = builder.finish() {
            let stroke = Stroke {
                width,
                line_cap: LineCap::Round,
                line_join: LineJoin::Round,
                ..Stroke::default()
            };
            self.pixmap
                .stroke_path(&path, &paint(rgb), &stroke, Transform::identity(), None);
        }
    }

    /// Draws one segment (nothing if either end is `None`).
    pub(super) fn segment(&mut self, a: Px, b: Px, width: f32, rgb: Rgb) {
        self.polyline([a, b], width, rgb);
    }

    /// Fills a disc of `radius` pixels around `centre`.
    pub(super) fn dot(&mut self, centre: Px, radius: f32, rgb: Rgb) {
        let Some((x, y)) = centre.filter(|&c| self.near_image(c, radius)) else {
            return;
        };
        if let Some(path) = PathBuilder::from_circle(x, y, radius) {
            self.pixmap.fill_path(
                &path,
                &paint(rgb),
                FillRule::Winding,
                Transform::identity(),
                None,
            );
        }
    }

    /// Strokes a circle of `radius` pixels around `centre`.
    pub(super) fn ring(&mut self, centre: Px, radius: f32, width: f32, rgb: Rgb) {
        let Some((x, y)) = centre.filter(|&c| self.near_image(c, radius)) else {
            return;
        };
        if let Some(path) = PathBuilder::from_circle(x, y, radius) {
            let stroke = Stroke {
                width,
                ..Stroke::default()
            };
            self.pixmap
                .stroke_path(&path, &paint(rgb), &stroke, Transform::identity(), None);
        }
    }

    /// Draws an `x`-shaped cross reaching `half` pixels from `centre` along each axis.
    pub(super) fn cross(&mut self, centre: Px, half: f32, width: f32, rgb: Rgb) {
        let Some((x, y)) = centre else {
            return;
        };
        self.segment(
            Some((x - half, y - half)),
            Some((x + half, y + half)),
            width,
            rgb,
        );
        self.segment(
            Some((x - half, y + half)),
            Some((x + half, y - half)),
            width,
            rgb,
        );
    }

    /// Fills an axis-aligned rectangle (nothing if it is empty or not finite).
    pub(super) fn rect(&mut self, x: f32, y: f32, w: f32, h: f32, rgb: Rgb) {
        if let Some(rect) = Rect::from_xywh(x, y, w, h) {
            self.pixmap
                .fill_rect(rect, &paint(rgb), Transform::identity(), None);
        }
    }

    /// Width in pixels of `text` drawn at integer `scale`.
    #[must_use]
    pub(super) fn text_width(text: &str, scale: u32) -> f32 {
        text.chars().count() as f32 * GLYPH * scale as f32
    }

    /// Writes `text` with its top-left corner at (`x`, `y`), each font pixel drawn as a
    /// `scale` x `scale` square. Characters outside ASCII are drawn as `?`.
    pub(super) fn text(&mut self, x: f32, y: f32, text: &str, scale: u32, rgb: Rgb) {
        let s = scale.max(1) as f32;
        let mut pen_x = x.round();
        let top = y.round();
        for ch in text.chars() {
            let code = if ch.is_ascii() {
                ch as usize
            } else {
                '?' as usize
            };
            let glyph = font8x8::legacy::BASIC_LEGACY[code];
            for (row, bits) in glyph.iter().enumerate() {
                // Runs of set bits become one rectangle each; bit 0 is the leftmost pixel.
                let mut column = 0;
                while column < 8 {
                    if bits & (1 << column) == 0 {
                        column += 1;
                        continue;
                    }
                    let start = column;
                    while column < 8 && bits & (1 << column) != 0 {
                        column += 1;
                    }
                    self.rect(
                        pen_x + start as f32 * s,
                        top + row as f32 * s,
                        (column - start) as f32 * s,
                        s,
                        rgb,
                    );
                }
            }
            pen_x += GLYPH * s;
        }
    }

    /// Writes `lines` of text on one light box with its top-left corner at (`x`, `y`),
    /// at scale 2 if every line fits in `max_width` pixels and at scale 1 otherwise.
    /// Returns the box's width and height.
    pub(super) fn caption(&mut self, x: f32, y: f32, lines: &[&str], max_width: f32) -> (f32, f32) {
        let pad = 4.0;
        let widest = lines.iter().map(|l| l.chars().count()).max().unwrap_or(0) as f32;
        let scale: u32 = if widest * GLYPH * 2.0 + 2.0 * pad <= max_width {
            2
        } else {
            1
        };
        let line_height = GLYPH * scale as f32 + 2.0;
        let w = widest * GLYPH * scale as f32 + 2.0 * pad;
        let h = line_height * lines.len() as f32 - 2.0 + 2.0 * pad;
        if lines.is_empty() {
            return (0.0, 0.0);
        }
        self.rect(x, y, w, h, ink::CAPTION_BOX);
        for (k, line) in lines.iter().enumerate() {
            self.text(
                x + pad,
                y + pad + k as f32 * line_height,
                line,
                scale,
                ink::TEXT,
            );
        }
        (w, h)
    }

    /// Writes the image as a PNG file.
    pub(super) fn save_png(&self, path: &Path) -> Result<(), String> {
        let bytes = self
            .pixmap
            .encode_png()
            .map_err(|e| format!("cannot encode PNG for {}: {e}", path.display()))?;
        super::write_file(path, &bytes)
    }

    /// Whether a shape of `radius` around `c` can touch the image.
    fn near_image(&self, c: (f32, f32), radius: f32) -> bool {
        let r = radius.abs() + 2.0;
        c.0 > -r && c.1 > -r && c.0 < self.width() as f32 + r && c.1 < self.height() as f32 + r
    }

    /// The part of segment `a`-`b` inside the image grown by `CLIP_SLACK`
    /// (Liang-Barsky), or `None` if it misses it.
    fn clip(&self, a: (f32, f32), b: (f32, f32)) -> Option<((f32, f32), (f32, f32))> {
        let (x_min, y_min) = (-CLIP_SLACK, -CLIP_SLACK);
        let x_max = self.width() as f32 + CLIP_SLACK;
        let y_max = self.height() as f32 + CLIP_SLACK;
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let (mut t0, mut t1) = (0.0_f32, 1.0_f32);
        // Each pair is (p, q) for one boundary: the segment is inside where t * p <= q.
        for (p, q) in [
            (-dx, a.0 - x_min),
            (dx, x_max - a.0),
            (-dy, a.1 - y_min),
            (dy, y_max - a.1),
        ] {
            if p == 0.0 {
                if q < 0.0 {
                    return None;
                }
            } else {
                let t = q / p;
                if p < 0.0 {
                    t0 = t0.max(t);
                } else {
                    t1 = t1.min(t);
                }
            }
        }
        if t0 > t1 || !t0.is_finite() || !t1.is_finite() {
            return None;
        }
        let at = |t: f32| (a.0 + t * dx, a.1 + t * dy);
        Some((at(t0), at(t1)))
    }
}

/// `tiny-skia` colour of an ink.
fn color(rgb: Rgb) -> Color {
    Color::from_rgba8(rgb.0, rgb.1, rgb.2, 255)
}

/// An antialiased solid paint.
fn paint(rgb: Rgb) -> Paint<'static> {
    let mut paint = Paint::default();
    paint.set_color(color(rgb));
    paint.anti_alias = true;
    paint
}
