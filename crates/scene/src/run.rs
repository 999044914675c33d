//! Running a checked scene: every task in order, each timed, its result typed.

use crate::results::{Csv, NoMetrics, Pictures, SceneResults, TaskMetrics, TaskResult};
use crate::schema::Scene;
use crate::tasks::{ProgressFn, RunContext};
use std::time::Instant;

/// How to run a scene.
#[derive(Clone, Copy, Default)]
pub struct RunOptions<'a> {
    /// Keep what the pictures need (animation frames, curves to draw) in each
    /// [`TaskResult::pictures`]. It is gathered outside every timed region, so it
    /// changes no metric; off by default.
    pub keep_frames: bool,
    /// Told `(task, done, total)` after each unit of work (frame, step) of a task, to
    /// show progress.
    pub progress: Option<ProgressFn<'a>>,
}

impl Scene {
    /// Runs every task in order. A task that cannot run (an error the checks could not
    /// foresee, such as a solver failing mid-run) is a result with `ok == false` and its
    /// error; the other tasks still run.
    #[must_use]
    pub fn run(&self, options: &RunOptions) -> SceneResults {
        let ctx = RunContext {
            keep_frames: options.keep_frames,
            progress: options.progress,
        };
        let tasks = self
            .tasks
            .iter()
            .map(|task| {
                let start = Instant::now();
                let result = task.spec().run(&ctx);
                let wall_time_s = start.elapsed().as_secs_f64();
                match result {
                    Ok(output) => TaskResult {
                        name: task.name().to_string(),
                        kind: task.kind(),
                        wall_time_s,
                        ok: output.failures.is_empty(),
                        error: None,
                        metrics: output.metrics,
                        headline: output.headline,
                        failures: output.failures,
                        table: output.table,
                        pictures: output.pictures,
                    },
                    Err(e) => TaskResult::failed(task.name(), task.kind(), wall_time_s, e),
                }
            })
            .collect();
        SceneResults {
            scene: self.name.clone(),
            description: self.description.clone(),
            tasks,
        }
    }
}

impl TaskResult {
    /// The result of a task that could not run (or whose outputs could not be written):
    /// no metrics, `ok == false`, the error kept.
    #[must_use]
    pub fn failed(name: &str, kind: &'static str, wall_time_s: f64, error: String) -> TaskResult {
        TaskResult {
            name: name.to_string(),
            kind,
            wall_time_s,
            ok: false,
            headline: format!("error: {error}"),
            error: Some(error),
            metrics: TaskMetrics::None(NoMetrics {}),
            failures: Vec::new(),
            table: Csv::default(),
            pictures: Pictures::None,
        }
    }
}
