//! Pictures of an IK chain following its target: an animated GIF of the run and a PNG
//! still with the whole target path.

use super::animation::{GifWriter, frames_to_draw_or_err};
use super::canvas::{Canvas, ink};
use super::{Mark, View, annotate, draw_target, format_length, path_shown};
use sinew_math::DVec3;
use std::path::Path;

/// One frame of an IK run: the chain's joint positions (root first, end effector last)
/// and the target the chain was solving for.
#[derive(Clone, Copy, Debug)]
pub struct IkFrame<'a> {
    /// World positions of the joints, root first; the last one is the end effector.
    pub joints: &'a [DVec3],
    /// The target of this frame.
    pub target: DVec3,
}

impl<'a> From<&'a sinew_scene::results::IkFrame> for IkFrame<'a> {
    /// The frame of an `Ik` task's result, as drawn.
    fn from(f: &'a sinew_scene::results::IkFrame) -> Self {
        IkFrame {
            joints: &f.joints,
            target: f.target,
        }
    }
}

impl IkFrame<'_> {
    /// Distance from the end effector to the target (NaN with no joints).
    #[must_use]
    fn error(&self) -> f64 {
        self.joints
            .last()
            .map_or(f64::NAN, |effector| effector.distance(self.target))
    }
}

/// Writes an animated GIF of the chain following its target: bones as thick lines,
/// joints as dots, the end effector in orange, the target as a red ring with a cross and
/// the target path so far as a thin blue line, with the frame number and the
/// effector-target distance as caption.
///
/// Frame `k` of `frames.len()` shows the first `ceil((k + 1) * n / frames.len())` of
/// the `n` points of `targets_path` (all points up to frame `k` when there is one per
/// frame). Plays at `fps` frames per second (clamped to 1..=50), holds the last frame
/// for 1.5 s and loops; runs longer than 300 frames are thinned evenly. Size is the
/// view's. Non-finite points are skipped.
///
/// # Errors
/// When `frames` is empty, or the file cannot be written.
pub fn ik_gif(
    path: &Path,
    view: &View,
    frames: &[IkFrame],
    targets_path: &[DVec3],
    fps: u16,
) -> Result<(), String> {
    let picked = frames_to_draw_or_err(frames.len(), "IK animation", path)?;
    let mut gif = GifWriter::create(path, view.width(), view.height(), fps)?;
    for index in picked {
        let shown = path_shown(index, frames.len(), targets_path.len());
        let frame = &frames[index];
        let caption = [
            format!("frame {}/{}", index + 1, frames.len()),
            format!("error {}", format_length(frame.error())),
        ];
        let canvas = draw(view, frame, &targets_path[..shown], &caption)?;
        gif.add(&canvas)?;
    }
    gif.finish()
}

/// Writes a PNG still of one IK frame over the whole target path, captioned with the
/// effector-target distance. Size is the view's; non-finite points are skipped.
///
/// # Errors
/// When the file cannot be written.
pub fn ik_png(
    path: &Path,
    view: &View,
    frame: &IkFrame,
    targets_path: &[DVec3],
) -> Result<(), String> {
    let caption = [format!("error {}", format_length(frame.error()))];
    draw(view, frame, targets_path, &caption)?.save_png(path)
}

/// Draws one frame with the given part of the target path and caption lines.
fn draw(
    view: &View,
    frame: &IkFrame,
    path: &[DVec3],
    caption: &[String],
) -> Result<Canvas, String> {
    let mut canvas = Canvas::new(view.width(), view.height())?;
    canvas.polyline(path.iter().map(|&p| view.project(p)), 1.5, ink::PATH);

    // The target goes under the chain, so that a reached target shows the effector
    // inside its ring.
    draw_target(&mut canvas, view.project(frame.target), 1.0);
    let joints: Vec<_> = frame.joints.iter().map(|&p| view.project(p)).collect();
    if let Some(&root) = joints.first() {
        canvas.dot(root, 7.0, ink::ROOT);
    }
    canvas.polyline(joints.iter().copied(), 5.0, ink::BONE);
    if let Some((&effector, inner)) = joints.split_last() {
        for &joint in inner {
            canvas.dot(joint, 4.0, ink::JOINT);
        }
        canvas.dot(effector, 6.5, ink::JOINT);
        canvas.dot(effector, 5.0, ink::EFFECTOR);
    }

    annotate(
        &mut canvas,
        view,
        caption,
        &[
            (Mark::Line(ink::BONE, 5.0), "chain"),
            (Mark::Dot(ink::EFFECTOR, 5.0), "effector"),
            (Mark::Target, "target"),
            (Mark::Line(ink::PATH, 1.5), "target path"),
        ],
    );
    Ok(canvas)
}
