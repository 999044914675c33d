//! Task kinds: each module holds one kind's scene fields ([`TaskSpec::validate`] checks
//! them) and how to run it. A task returns its typed metrics (documented per kind in
//! `docs/scenes.md`), a one-line headline for the summary table, the checks it failed
//! (expectations written in the scene), its per-frame table and, when asked, what its
//! pictures need. Tasks write no files and draw nothing: that is the caller's choice.

pub mod cloth;
pub mod curve;
pub mod fk;
pub mod full_body;
pub mod ik;
pub mod limbs;
pub mod mesh_cloth;
pub mod two_bone;

use crate::results::{Csv, Pictures, TaskMetrics};
use std::time::Instant;

/// Told `(task, done, total)` after each unit of work (frame, step) of a task.
pub type ProgressFn<'a> = &'a dyn Fn(&str, usize, usize);

/// What the runner hands a task.
pub struct RunContext<'a> {
    /// Whether to keep what the pictures need (animation frames, curves to draw); it
    /// is gathered outside every timed region, so it never changes a metric.
    pub keep_frames: bool,
    /// Told `(task, done, total)` after each unit of work (frame, step), if set.
    pub progress: Option<ProgressFn<'a>>,
}

impl RunContext<'_> {
    /// A progress counter for `total` units of work (frames, steps) of `task`.
    #[must_use]
    pub fn progress(&self, task: &str, total: usize) -> Progress<'_> {
        Progress {
            sink: self.progress,
            task: task.to_string(),
            total,
            done: 0,
        }
    }
}

/// See [`RunContext::progress`].
pub struct Progress<'a> {
    sink: Option<ProgressFn<'a>>,
    task: String,
    total: usize,
    done: usize,
}

impl Progress<'_> {
    /// One more unit done.
    pub fn inc(&mut self) {
        self.done += 1;
        if let Some(sink) = self.sink {
            sink(&self.task, self.done, self.total);
        }
    }
}

/// What a task produced.
pub struct TaskOutput {
    /// The task's metrics, typed by kind.
    pub metrics: TaskMetrics,
    /// A short human summary for the table.
    pub headline: String,
    /// Expectations written in the scene that did not hold; any makes the run fail.
    pub failures: Vec<String>,
    /// The per-frame (or per-step, per-joint, per-point) table.
    pub table: Csv,
    /// What the pictures need (empty unless the run keeps frames).
    pub pictures: Pictures,
}

impl TaskOutput {
    /// An output whose table has a row per frame (written as `<task>.frames.csv`).
    #[must_use]
    pub fn per_frame(
        metrics: TaskMetrics,
        headline: String,
        failures: Vec<String>,
        csv: String,
        pictures: Pictures,
    ) -> Self {
        TaskOutput {
            metrics,
            headline,
            failures,
            table: Csv {
                suffix: "frames.csv",
                text: csv,
            },
            pictures,
        }
    }
}

/// A task kind's behaviour. Its name and kind are the scene's to tell
/// ([`crate::schema::Task::name`], [`crate::schema::Task::kind`]).
pub trait TaskSpec {
    /// Checks every value; the message names the item and what is allowed.
    fn validate(&self) -> Result<(), String>;
    /// Runs the task.
    fn run(&self, ctx: &RunContext) -> Result<TaskOutput, String>;
}

/// Checks an optional limit or tolerance of a task: absent, or finite and `>= 0`; the
/// error names `field` and its value.
pub fn non_negative(field: &str, value: Option<f64>) -> Result<(), String> {
    match value {
        Some(x) if !(x.is_finite() && x >= 0.0) => {
            Err(format!("{field} = {x}, must be finite and >= 0"))
        }
        _ => Ok(()),
    }
}

/// Median wall time in nanoseconds of `f`, over enough calls to fill about `budget_ms`
/// (at least 5, at most 100 000).
pub fn median_time_ns(budget_ms: f64, mut f: impl FnMut()) -> f64 {
    let start = Instant::now();
    f();
    let first = start.elapsed().as_secs_f64();
    let runs = ((budget_ms * 1e-3 / first.max(1e-9)) as usize).clamp(5, 100_000);
    let mut times = Vec::with_capacity(runs);
    for _ in 0..runs {
        let t = Instant::now();
        f();
        times.push(t.elapsed().as_secs_f64() * 1e9);
    }
    median(&mut times)
}

/// The largest distance between corresponding points of two equally long lists.
pub fn max_distance(a: &[sinew_math::DVec3], b: &[sinew_math::DVec3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| x.distance(*y))
        .fold(0.0, f64::max)
}

/// Samples along each particle's straight path in [`deepest_swept_path`].
const PATH_SAMPLES: usize = 64;

/// How deep the deepest free particle's straight path goes into a collider whose surface
/// moves, over a step from `before` at `t0` through the end states of its `pieces` (each
/// its end time and positions; the step's own end alone for a step taken whole), the
/// collider posed at the same times, sampled at `PATH_SAMPLES - 1` inner points of each
/// piece and at its end (positive: inside), and the most that depth exceeds the
/// collider's own allowance `min(dhat, r/2)` (`dhat` for a half-space); `None` when no
/// collider's surface moves. The runner's own check of what the implicit integrators
/// promise for every piece of a step: no deeper than the allowance (docs/contact.md, "A
/// kinematic collider passing the cloth within a step").
pub fn deepest_swept_path<'a>(
    colliders: &[sinew_spring_sim::contact::Collider],
    (thickness, dhat): (f64, f64),
    (t0, before): (f64, &'a [sinew_math::DVec3]),
    pieces: impl Iterator<Item = (f64, &'a [sinew_math::DVec3])> + Clone,
    fixed: &[bool],
) -> Option<SweptDepth> {
    let mut deepest: Option<SweptDepth> = None;
    for c in colliders.iter().filter(|c| c.moves_surface()) {
        let mut depth = f64::NEG_INFINITY;
        let (mut start, mut from) = (t0, before);
        for (end, to) in pieces.clone() {
            for k in 1..=PATH_SAMPLES {
                let s = k as f64 / PATH_SAMPLES as f64;
                let shape = c.at(start + s * (end - start));
                for ((p, q), pinned) in from.iter().zip(to).zip(fixed) {
                    if !*pinned {
                        let d = sinew_spring_sim::contact::signed_distance(
                            &shape,
                            p.lerp(*q, s),
                            thickness,
                        )
                        .distance;
                        depth = depth.max(-d);
                    }
                }
            }
            (start, from) = (end, to);
        }
        let excess = depth - sinew_spring_sim::contact::swept_allowance(&c.shape, dhat);
        deepest = Some(match deepest {
            None => SweptDepth { depth, excess },
            Some(m) => SweptDepth {
                depth: m.depth.max(depth),
                excess: m.excess.max(excess),
            },
        });
    }
    deepest
}

/// Adds the failures of the checks both cloth runners make on moving bodies: a piece's
/// straight path deeper into a moving collider than its allowance (`path_excess` > 0,
/// which the implicit integrators promise never happens) and a held `item` (a particle,
/// a vertex) farther from where its joint's frame puts it than the limbs'
/// `ATTACH_TOLERANCE`, 1e-9 (the pinned motion over a step is the joint's rigid motion,
/// so only round-off accumulates).
pub fn moving_body_failures(
    item: &str,
    path_excess: Option<f64>,
    attach_error_max: Option<f64>,
    failures: &mut Vec<String>,
) {
    if let Some(e) = path_excess
        && e > 0.0
    {
        failures.push(format!(
            "a {item}'s straight path over a piece of a step went {e:.3e} deeper into a moving collider than its allowance min(dhat, r/2)"
        ));
    }
    let tolerance = limbs::ATTACH_TOLERANCE;
    if let Some(e) = attach_error_max
        && e > tolerance
    {
        failures.push(format!(
            "a held {item} ended {e:.3e} from where its joint's frame puts it (more than {tolerance:e})"
        ));
    }
}

/// What [`deepest_swept_path`] measures over a step.
#[derive(Clone, Copy, Debug)]
pub struct SweptDepth {
    /// The deepest any free particle's path went into a moving collider (positive:
    /// inside).
    pub depth: f64,
    /// The most a path's depth into a collider exceeded that collider's allowance
    /// (positive: beyond it, which the implicit integrators promise never happens).
    pub excess: f64,
}

/// The median of `values` (sorted in place); NaN for an empty slice.
pub fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    }
}
