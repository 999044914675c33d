//! Animated GIF output: a fixed 256-colour palette made for these pictures, and frames
//! stored as the rectangle that changed since the previous one.
//!
//! The palette is fixed rather than computed per picture so that output is deterministic,
//! fast, and the same ink is the same colour in every frame. It holds every ink exactly,
//! each ink blended with the background (the antialiased edges), the spring-strain
//! colour ramp, a grey ramp and a coarse colour cube for anything else. Each pixel maps
//! to its nearest palette entry through a 32x32x32 lookup table; there is no dithering,
//! which keeps flat areas flat and the files small.

use super::canvas::{Canvas, Rgb, ink};
use gif::{DisposalMethod, Encoder, Frame, Repeat};
use std::borrow::Cow;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

/// Most frames written to one GIF; longer animations are thinned evenly (the first and
/// last frames are always kept), which bounds file size and encoding time.
pub(super) const MAX_GIF_FRAMES: usize = 300;

/// Extra time the last frame stays on screen before the animation loops, in 1/100 s.
const END_PAUSE_CS: u16 = 150;

/// The frames of an animation of `count` frames to draw (see [`frames_to_draw`]), or,
/// when there are none, the error every animation gives: `what` (e.g. "IK animation")
/// and the file that was not written.
pub(super) fn frames_to_draw_or_err(
    count: usize,
    what: &str,
    path: &Path,
) -> Result<Vec<usize>, String> {
    if count == 0 {
        return Err(format!("{what} {}: no frames to draw", path.display()));
    }
    Ok(frames_to_draw(count))
}

/// Indices of the frames to draw out of `count`: all of them up to [`MAX_GIF_FRAMES`],
/// otherwise that many spread evenly from the first to the last.
#[must_use]
pub(super) fn frames_to_draw(count: usize) -> Vec<usize> {
    if count <= MAX_GIF_FRAMES {
        return (0..count).collect();
    }
    let last = count - 1;
    let steps = MAX_GIF_FRAMES - 1;
    (0..=steps)
        .map(|k| (k * last + steps / 2) / steps)
        .collect()
}

/// The colour ramp of spring strain from fully compressed (`t = -1`) through rest
/// (`t = 0`) to fully stretched (`t = 1`); `t` is clamped.
#[must_use]
pub(super) fn strain_colour(t: f64) -> Rgb {
    if !t.is_finite() {
        return ink::STRAIN_ZERO;
    }
    if t < 0.0 {
        ink::STRAIN_ZERO.mix(ink::STRAIN_COMPRESSED, -t)
    } else {
        ink::STRAIN_ZERO.mix(ink::STRAIN_STRETCHED, t)
    }
}

/// The fixed palette and its nearest-colour lookup table.
struct Palette {
    /// Palette entries as RGB triples (256 entries; unused ones are black).
    bytes: Vec<u8>,
    /// Palette index for each colour bin of 5 bits per channel.
    lookup: Vec<u8>,
}

impl Palette {
    fn new() -> Palette {
        let mut entries: Vec<Rgb> = Vec::with_capacity(256);
        let mut push = |c: Rgb| {
            if !entries.contains(&c) && entries.len() < 256 {
                entries.push(c);
            }
        };
        for c in ink::ALL {
            push(c);
        }
        for c in ink::ALL {
            for t in [0.25, 0.5, 0.75] {
                push(c.mix(ink::BACKGROUND, t));
            }
        }
        for k in 0..=24 {
            let t = f64::from(k) / 24.0;
            push(strain_colour(t));
            push(strain_colour(-t));
        }
        for k in 0..16 {
            let v = (k * 17) as u8;
            push(Rgb(v, v, v));
        }
        for r in 0..4 {
            for g in 0..4 {
                for b in 0..4 {
                    push(Rgb(r * 85, g * 85, b * 85));
                }
            }
        }
        let mut lookup = Vec::with_capacity(1 << 15);
        for bin in 0..(1_u32 << 15) {
            // Each 5-bit channel stretched back to 0..=255, so that black and white bins
            // sit on black and white.
            let expand = |c: u32| ((c << 3) | (c >> 2)) as i32;
            let (r, g, b) = (
                expand((bin >> 10) & 31),
                expand((bin >> 5) & 31),
                expand(bin & 31),
            );
            let mut best = (i32::MAX, 0_u8);
            for (index, c) in entries.iter().enumerate() {
                let (dr, dg, db) = (r - i32::from(c.0), g - i32::from(c.1), b - i32::from(c.2));
                // Green weighs most and blue least, roughly as the eye sees differences.
                let d = 3 * dr * dr + 4 * dg * dg + 2 * db * db;
                if d < best.0 {
                    best = (d, index as u8);
                }
            }
            lookup.push(best.1);
        }
        // Every ink is drawn exactly: its bin maps to it even if another entry is nearer
        // to the bin's representative colour. Inks come first in `entries`, so their
        // indices are their positions after deduplication.
        for c in ink::ALL {
            if let Some(index) = entries.iter().position(|&e| e == c) {
                lookup[bin_of(c.0, c.1, c.2)] = index as u8;
            }
        }
        let mut bytes = Vec::with_capacity(256 * 3);
        for c in &entries {
            bytes.extend_from_slice(&[c.0, c.1, c.2]);
        }
        bytes.resize(256 * 3, 0);
        Palette { bytes, lookup }
    }

    /// Palette indices of an opaque RGBA image.
    fn indices(&self, rgba: &[u8]) -> Vec<u8> {
        rgba.chunks_exact(4)
            .map(|p| self.lookup[bin_of(p[0], p[1], p[2])])
            .collect()
    }
}

/// Lookup-table bin of a colour: the top 5 bits of each channel.
#[must_use]
fn bin_of(r: u8, g: u8, b: u8) -> usize {
    (usize::from(r >> 3) << 10) | (usize::from(g >> 3) << 5) | usize::from(b >> 3)
}

/// Writes canvases as the frames of a looping GIF.
pub(super) struct GifWriter<'p> {
    path: &'p Path,
    encoder: Encoder<BufWriter<File>>,
    palette: Palette,
    width: u16,
    height: u16,
    delay_cs: u16,
    /// The last frame added, not yet written (its delay depends on whether it is last).
    pending: Option<Vec<u8>>,
    /// The image on screen after the frames written so far.
    shown: Option<Vec<u8>>,
}

impl<'p> GifWriter<'p> {
    /// Starts a `width` x `height` GIF at `path` playing `fps` frames per second
    /// (clamped to 1..=50; GIF delays are whole hundredths of a second).
    pub(super) fn create(
        path: &'p Path,
        width: u32,
        height: u32,
        fps: u16,
    ) -> Result<Self, String> {
        let err = |e: &dyn std::fmt::Display| format!("cannot write GIF {}: {e}", path.display());
        let (w, h) = (
            u16::try_from(width).map_err(|e| err(&e))?,
            u16::try_from(height).map_err(|e| err(&e))?,
        );
        super::create_parent(path)?;
        let file = File::create(path).map_err(|e| err(&e))?;
        let palette = Palette::new();
        let mut encoder =
            Encoder::new(BufWriter::new(file), w, h, &palette.bytes).map_err(|e| err(&e))?;
        encoder.set_repeat(Repeat::Infinite).map_err(|e| err(&e))?;
        let fps = fps.clamp(1, 50);
        let delay_cs = ((100.0 / f64::from(fps)).round() as u16).max(2);
        Ok(GifWriter {
            path,
            encoder,
            palette,
            width: w,
            height: h,
            delay_cs,
            pending: None,
            shown: None,
        })
    }

    /// Adds the canvas as the next frame; it must have the size the GIF was created with.
    pub(super) fn add(&mut self, canvas: &Canvas) -> Result<(), String> {
        if canvas.width() != u32::from(self.width) || canvas.height() != u32::from(self.height) {
            return Err(format!(
                "GIF {}: frame is {}x{}, expected {}x{}",
                self.path.display(),
                canvas.width(),
                canvas.height(),
                self.width,
                self.height
            ));
        }
        let frame = self.palette.indices(canvas.rgba());
        if let Some(previous) = self.pending.replace(frame) {
            self.write(previous, self.delay_cs)?;
        }
        Ok(())
    }

    /// Writes the last frame (held on screen a little longer) and closes the file.
    pub(super) fn finish(mut self) -> Result<(), String> {
        let Some(last) = self.pending.take() else {
            return Err(format!("GIF {}: no frames to write", self.path.display()));
        };
        self.write(last, self.delay_cs.saturating_add(END_PAUSE_CS))?;
        let path = self.path;
        let writer = self
            .encoder
            .into_inner()
            .map_err(|e| format!("cannot write GIF {}: {e}", path.display()))?;
        writer
            .into_inner()
            .map_err(|e| format!("cannot write GIF {}: {}", path.display(), e.error()))?;
        Ok(())
    }

    /// Writes `frame` as the smallest rectangle that differs from what is on screen.
    fn write(&mut self, frame: Vec<u8>, delay: u16) -> Result<(), String> {
        let (w, h) = (usize::from(self.width), usize::from(self.height));
        let (mut x0, mut y0, mut x1, mut y1) = (0, 0, w, h);
        if let Some(shown) = &self.shown {
            let (mut lo_x, mut lo_y, mut hi_x, mut hi_y) = (w, h, 0, 0);
            for y in 0..h {
                let row = y * w..(y + 1) * w;
                let (new_row, old_row) = (&frame[row.clone()], &shown[row]);
                if new_row == old_row {
                    continue;
                }
                let first = new_row
                    .iter()
                    .zip(old_row)
                    .position(|(a, b)| a != b)
                    .unwrap_or(0);
                let last = new_row
                    .iter()
                    .zip(old_row)
                    .rposition(|(a, b)| a != b)
                    .unwrap_or(0);
                lo_x = lo_x.min(first);
                hi_x = hi_x.max(last + 1);
                lo_y = lo_y.min(y);
                hi_y = y + 1;
            }
            // An unchanged frame is still written (one pixel) so that timing is kept.
            (x0, y0, x1, y1) = if hi_x > lo_x {
                (lo_x, lo_y, hi_x, hi_y)
            } else {
                (0, 0, 1, 1)
            };
        }
        let mut buffer = Vec::with_capacity((x1 - x0) * (y1 - y0));
        for y in y0..y1 {
            buffer.extend_from_slice(&frame[y * w + x0..y * w + x1]);
        }
        // Sizes fit u16: they are bounded by the image sides, which are u16.
        let gif_frame = Frame {
            delay,
            dispose: DisposalMethod::Keep,
            left: x0 as u16,
            top: y0 as u16,
            width: (x1 - x0) as u16,
            height: (y1 - y0) as u16,
            buffer: Cow::Owned(buffer),
            ..Frame::default()
        };
        self.encoder
            .write_frame(&gif_frame)
            .map_err(|e| format!("cannot write GIF {}: {e}", self.path.display()))?;
        self.shown = Some(frame);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_ink_is_exact_in_the_palette() {
        let palette = Palette::new();
        for c in ink::ALL {
            let index = palette.indices(&[c.0, c.1, c.2, 255])[0] as usize;
            let entry = &palette.bytes[3 * index..3 * index + 3];
            assert_eq!(entry, &[c.0, c.1, c.2], "ink {c:?}");
        }
    }

    #[test]
    fn gif_round_trip_keeps_frames_and_colours() {
        let dir = std::env::temp_dir().join(format!("sinew-gif-{}", std::process::id()));
        let path = dir.join("t.gif");
        let mut writer = GifWriter::create(&path, 64, 48, 10).unwrap();
        let mut canvas = Canvas::new(64, 48).unwrap();
        writer.add(&canvas).unwrap();
        canvas.rect(10.0, 10.0, 5.0, 4.0, ink::TARGET);
        writer.add(&canvas).unwrap();
        writer.add(&canvas).unwrap();
        writer.finish().unwrap();

        let mut options = gif::DecodeOptions::new();
        options.set_color_output(gif::ColorOutput::RGBA);
        let mut decoder = options
            .read_info(std::fs::File::open(&path).unwrap())
            .unwrap();
        let mut frames = Vec::new();
        while let Some(frame) = decoder.read_next_frame().unwrap() {
            frames.push((
                frame.left,
                frame.top,
                frame.width,
                frame.height,
                frame.delay,
            ));
            if frames.len() == 1 {
                assert_eq!(
                    &frame.buffer[..4],
                    &[255, 255, 255, 255],
                    "white background"
                );
            }
            if frames.len() == 2 {
                assert_eq!(&frame.buffer[..4], &[215, 25, 45, 255], "exact target ink");
            }
        }
        std::fs::remove_dir_all(&dir).ok();
        assert_eq!(frames.len(), 3);
        assert_eq!(frames[0], (0, 0, 64, 48, 10));
        // Only the changed rectangle is stored, and an unchanged frame is one pixel.
        assert_eq!(frames[1], (10, 10, 5, 4, 10));
        assert_eq!(frames[2], (0, 0, 1, 1, 10 + END_PAUSE_CS));
    }

    #[test]
    fn thinning_keeps_first_and_last_and_is_increasing() {
        let picked = frames_to_draw(1000);
        assert_eq!(picked.len(), MAX_GIF_FRAMES);
        assert_eq!(picked[0], 0);
        assert_eq!(*picked.last().unwrap(), 999);
        assert!(picked.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(frames_to_draw(7), (0..7).collect::<Vec<_>>());
    }
}
