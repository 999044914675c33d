//! Pictures of a full-body clip: an animated GIF of the skeleton tree with its effectors
//! and their goals, and a PNG still of one frame.

use super::animation::{GifWriter, frames_to_draw_or_err};
use super::canvas::{Canvas, ink};
use super::{Mark, View, annotate, draw_pin, draw_target, format_length};
use sinew_math::DVec3;
use std::path::Path;

/// One frame of a body clip, borrowed from the caller's data.
#[derive(Clone, Copy, Debug)]
pub struct BodySnapshot<'a> {
    /// Every joint's world position, in the skeleton's order.
    pub joints: &'a [DVec3],
    /// Every effector's goal position, in the order of the effectors.
    pub goals: &'a [DVec3],
    /// The frame's worst effector error (shown in the caption).
    pub error: f64,
}

impl<'a> From<&'a sinew_scene::results::BodyFrame> for BodySnapshot<'a> {
    /// The frame of a `FullBody` task's result, as drawn.
    fn from(f: &'a sinew_scene::results::BodyFrame) -> Self {
        BodySnapshot {
            joints: &f.joints,
            goals: &f.goals,
            error: f.error,
        }
    }
}

/// The skeleton's shape and which joints are effectors, shared by every frame.
#[derive(Clone, Copy, Debug)]
pub struct BodyLayout<'a> {
    /// Each joint's parent (`None` for a root): a bone is drawn from each joint to it.
    pub parents: &'a [Option<usize>],
    /// The effectors' joints, in the order of [`BodySnapshot::goals`].
    pub effectors: &'a [usize],
    /// Whether each effector is pinned (drawn with the pin marker).
    pub pinned: &'a [bool],
}

/// Writes an animated GIF of the body: bones as thick lines, joints as dots, free
/// effectors in orange and pinned ones with the pin marker, each goal as a red ring with a
/// cross, captioned with the frame number and the worst effector error. Plays at `fps`
/// frames per second (clamped to 1..=50), holds the last frame and loops; runs longer
/// than 300 frames are thinned evenly. Non-finite points and out-of-range indices are
/// skipped.
///
/// # Errors
/// When `frames` is empty, or the file cannot be written.
pub fn body_gif(
    path: &Path,
    view: &View,
    layout: &BodyLayout,
    frames: &[BodySnapshot],
    fps: u16,
) -> Result<(), String> {
    let picked = frames_to_draw_or_err(frames.len(), "body animation", path)?;
    let mut gif = GifWriter::create(path, view.width(), view.height(), fps)?;
    for index in picked {
        let frame = &frames[index];
        let caption = [
            format!("frame {}/{}", index + 1, frames.len()),
            format!("worst error {}", format_length(frame.error)),
        ];
        gif.add(&draw(view, layout, frame, &caption)?)?;
    }
    gif.finish()
}

/// Writes a PNG still of one body frame, captioned with its worst effector error.
///
/// # Errors
/// When the file cannot be written.
pub fn body_png(
    path: &Path,
    view: &View,
    layout: &BodyLayout,
    frame: &BodySnapshot,
) -> Result<(), String> {
    let caption = [format!("worst error {}", format_length(frame.error))];
    draw(view, layout, frame, &caption)?.save_png(path)
}

fn draw(
    view: &View,
    layout: &BodyLayout,
    frame: &BodySnapshot,
    caption: &[String],
) -> Result<Canvas, String> {
    let mut canvas = Canvas::new(view.width(), view.height())?;
    let at = |j: usize| frame.joints.get(j).and_then(|&p| view.project(p));
    // Goals go under the body, so that a reached goal shows its effector inside the ring.
    for &goal in frame.goals {
        draw_target(&mut canvas, view.project(goal), 0.8);
    }
    for (j, parent) in layout.parents.iter().enumerate() {
        if let Some(p) = *parent {
            canvas.segment(at(p), at(j), 4.0, ink::BONE);
        }
    }
    for (j, parent) in layout.parents.iter().enumerate() {
        let colour = if parent.is_none() {
            ink::ROOT
        } else {
            ink::JOINT
        };
        canvas.dot(at(j), 3.0, colour);
    }
    for (k, &j) in layout.effectors.iter().enumerate() {
        if layout.pinned.get(k).copied().unwrap_or(false) {
            draw_pin(&mut canvas, at(j));
        } else {
            canvas.dot(at(j), 6.0, ink::JOINT);
            canvas.dot(at(j), 4.5, ink::EFFECTOR);
        }
    }
    annotate(
        &mut canvas,
        view,
        caption,
        &[
            (Mark::Line(ink::BONE, 4.0), "bones"),
            (Mark::Dot(ink::EFFECTOR, 4.5), "effector"),
            (Mark::Pin, "pinned"),
            (Mark::Target, "goal"),
        ],
    );
    Ok(canvas)
}
