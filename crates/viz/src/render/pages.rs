//! Interactive viewer pages from scene results: what `cargo xtask run-scene` writes
//! beside the GIFs for each animated task (IK tracks, full-body clips and cloths), converted from
//! [`sinew_scene::results::Pictures`] into the viewer's own [`ViewerPage`].

use crate::viewer::{Collider, Frame, PageKind, Series, ViewerPage};
use sinew_math::DVec3;
use sinew_scene::TaskResult;
use sinew_scene::results::{BodyPictures, ClothPictures, IkPictures, Pictures, Shape};

/// IK tracks have frames, not times: the page's clock runs them at this many frames a
/// second (the viewer's own playback rate at 1x).
const IK_FRAMES_PER_SECOND: f64 = 30.0;

/// The viewer page of an animated task's result, or `None` when the task has no
/// animation: a curve, FK, two-bone IK, a run that kept no frames, or a single frame
/// (an IK task with one target; like its GIF, a page needs two frames to animate).
#[must_use]
pub fn viewer_page(result: &TaskResult) -> Option<ViewerPage> {
    let mut page = match &result.pictures {
        Pictures::Ik(p) if p.track.len() > 1 => ik_page(&result.name, p),
        Pictures::Cloth(p) if p.track.len() > 1 => cloth_page(&result.name, p),
        Pictures::Body(p) if p.track.len() > 1 => body_page(&result.name, p),
        _ => return None,
    };
    page.metrics = metrics_table(result);
    Some(page)
}

fn ik_page(name: &str, p: &IkPictures) -> ViewerPage {
    let mut page = ViewerPage::new(name, PageKind::IkTrack);
    page.subtitle = format!(
        "{}, {} frames (shown at {IK_FRAMES_PER_SECOND} a second)",
        p.solver,
        p.targets.len()
    );
    page.frames = clip_frames(
        p.track.iter().map(|f| (&f.joints, vec![f.target])),
        &p.track_frames,
    );
    let joints = p.track[0].joints.len();
    page.segments = (1..joints).map(|j| (j - 1, j)).collect();
    page.fixed = vec![0];
    page.effectors = vec![joints - 1];
    page.target_path = p.targets.clone();
    page.charts = track_charts("effector error", &p.track_frames, &p.error, &p.iterations);
    page
}

fn body_page(name: &str, p: &BodyPictures) -> ViewerPage {
    let mut page = ViewerPage::new(name, PageKind::Clip);
    page.subtitle = format!(
        "{}, {} effectors, {} frames (shown at {IK_FRAMES_PER_SECOND} a second)",
        p.solver,
        p.effectors.len(),
        p.error.len()
    );
    page.frames = clip_frames(
        p.track.iter().map(|f| (&f.joints, f.goals.clone())),
        &p.track_frames,
    );
    page.segments = p
        .parents
        .iter()
        .enumerate()
        .filter_map(|(j, parent)| parent.map(|q| (q, j)))
        .collect();
    // Pinned effectors are the points that do not move; the others are drawn as
    // effectors with their trails.
    page.fixed = p
        .effectors
        .iter()
        .zip(&p.pinned)
        .filter(|&(_, &pinned)| pinned)
        .map(|(&j, _)| j)
        .collect();
    page.effectors = p
        .effectors
        .iter()
        .zip(&p.pinned)
        .filter(|&(_, &pinned)| !pinned)
        .map(|(&j, _)| j)
        .collect();
    page.charts = track_charts(
        "worst effector error",
        &p.track_frames,
        &p.error,
        &p.iterations,
    );
    page
}

/// The page's frames of an IK track (chain or full body): each shown frame's joints and
/// goals, timed by its frame index at [`IK_FRAMES_PER_SECOND`].
fn clip_frames<'a>(
    shown: impl Iterator<Item = (&'a Vec<DVec3>, Vec<DVec3>)>,
    track_frames: &[usize],
) -> Vec<Frame> {
    shown
        .zip(track_frames)
        .map(|((joints, goals), &k)| Frame {
            time: k as f64 / IK_FRAMES_PER_SECOND,
            points: joints.clone(),
            goals,
            colliders: Vec::new(),
        })
        .collect()
}

/// The charts of an IK track (chain or full body) at the frames the page shows: the
/// error (log scale) and the iterations.
fn track_charts(
    error_name: &str,
    track_frames: &[usize],
    error: &[f64],
    iterations: &[usize],
) -> Vec<Series> {
    vec![
        Series {
            name: error_name.into(),
            unit: "scene units".into(),
            values: track_frames.iter().map(|&k| error[k]).collect(),
            log_scale: true,
        },
        Series {
            name: "iterations".into(),
            unit: String::new(),
            values: track_frames.iter().map(|&k| iterations[k] as f64).collect(),
            log_scale: false,
        },
    ]
}

fn cloth_page(name: &str, p: &ClothPictures) -> ViewerPage {
    let mut page = ViewerPage::new(name, PageKind::Cloth);
    page.subtitle = format!("{}, dt = {:.4} s", p.integrator, p.dt);
    page.frames = p
        .track
        .iter()
        .zip(&p.track_steps)
        .map(|(f, &step)| Frame {
            time: step as f64 * p.dt,
            points: f.positions.clone(),
            goals: Vec::new(),
            colliders: f.colliders.iter().map(collider).collect(),
        })
        .collect();
    page.segments = p.springs.iter().map(|&(a, b, _)| (a, b)).collect();
    page.rest_lengths = p.springs.iter().map(|&(_, _, rest)| rest).collect();
    page.fixed = p.fixed.clone();
    // `energy` holds the start and then one value per step, so a step count indexes it.
    page.charts = vec![Series {
        name: "total energy".into(),
        unit: String::new(),
        values: p.track_steps.iter().map(|&s| p.energy[s].1).collect(),
        log_scale: false,
    }];
    page
}

fn collider(shape: &Shape) -> Collider {
    match *shape {
        Shape::HalfSpace { point, normal } => Collider::HalfSpace { point, normal },
        Shape::Sphere { center, radius } => Collider::Sphere { center, radius },
        Shape::Capsule { a, b, radius } => Collider::Capsule { a, b, radius },
    }
}

/// The task's metrics as (key, value) rows, in the order `metrics.json` has them.
fn metrics_table(result: &TaskResult) -> Vec<(String, String)> {
    let Ok(serde_json::Value::Object(map)) = serde_json::to_value(&result.metrics) else {
        return Vec::new();
    };
    map.into_iter()
        .map(|(key, value)| {
            let text = match value {
                serde_json::Value::Number(n) => match n.as_f64() {
                    Some(x) if n.is_f64() => format!("{x:.6e}"),
                    _ => n.to_string(),
                },
                serde_json::Value::String(s) => s,
                serde_json::Value::Null => "-".into(),
                other => other.to_string(),
            };
            (key, text)
        })
        .collect()
}
