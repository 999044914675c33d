//! Task kinds: each module holds one kind's scene fields ([`TaskSpec::validate`] checks
//! them) and how to run it. A task returns its metrics (documented per kind in
//! `docs/scenes.md`), a one-line headline for the summary table, and the checks it
//! failed (expectations written in the scene).

pub mod cloth;
pub mod curve;
pub mod fk;
pub mod ik;
pub mod two_bone;

use std::path::PathBuf;
use std::time::Instant;

/// Metrics of one task, written under `"metrics"` in `metrics.json`.
pub type Metrics = serde_json::Map<String, serde_json::Value>;

/// What the runner hands a task.
pub struct RunContext {
    /// The scene's output folder (exists when the task runs).
    pub out_dir: PathBuf,
    /// Whether to draw pictures (`--no-render` turns them off; they never change
    /// the metrics).
    pub render: bool,
    /// Whether progress bars may be shown (stdout is a terminal, not `--quiet` or
    /// `--json`).
    pub progress: bool,
}

impl RunContext {
    /// Writes `<task>.<suffix>` in the output folder; the error names the file.
    pub fn write_output(&self, task: &str, suffix: &str, contents: &str) -> Result<(), String> {
        let path = self.out_dir.join(format!("{task}.{suffix}"));
        std::fs::write(&path, contents).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// A progress counter for `total` units of work (frames, steps); it shows a bar
    /// only once the task has run for about a second, and only when allowed.
    pub fn progress(&self, task: &str, total: usize) -> Progress {
        Progress {
            enabled: self.progress,
            label: task.to_string(),
            total: total as u64,
            done: 0,
            start: Instant::now(),
            bar: None,
        }
    }
}

/// See [`RunContext::progress`].
pub struct Progress {
    enabled: bool,
    label: String,
    total: u64,
    done: u64,
    start: Instant,
    bar: Option<indicatif::ProgressBar>,
}

impl Progress {
    /// One more unit done.
    pub fn inc(&mut self) {
        self.done += 1;
        self.update();
    }

    /// A new phase of the task (for example "rendering"), shown next to its name.
    pub fn phase(&mut self, phase: &str) {
        self.label = format!("{} ({phase})", self.label.split(" (").next().unwrap_or(""));
        if let Some(bar) = &self.bar {
            bar.set_message(self.label.clone());
        }
        self.update();
    }

    fn update(&mut self) {
        if !self.enabled {
            return;
        }
        match &self.bar {
            Some(bar) => bar.set_position(self.done),
            None if self.start.elapsed().as_secs_f64() > 1.0 => {
                let bar = indicatif::ProgressBar::new(self.total);
                bar.set_style(
                    indicatif::ProgressStyle::with_template(
                        "  {msg:<28} [{bar:30}] {pos}/{len} {eta}",
                    )
                    .expect("a valid template")
                    .progress_chars("=> "),
                );
                bar.set_message(self.label.clone());
                bar.set_position(self.done);
                self.bar = Some(bar);
            }
            None => {}
        }
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

/// What a task produced.
pub struct TaskOutput {
    /// Metric keys and values.
    pub metrics: Metrics,
    /// A short human summary for the table.
    pub headline: String,
    /// Expectations written in the scene that did not hold; any makes the run fail.
    pub failures: Vec<String>,
}

/// A task kind's behaviour.
pub trait TaskSpec {
    /// The task's name (unique in its scene).
    fn name(&self) -> &str;
    /// The task kind, as in the scene file (`Fk`, ...).
    fn kind(&self) -> &'static str;
    /// Checks every value; the message names the item and what is allowed.
    fn validate(&self) -> Result<(), String>;
    /// Runs the task.
    fn run(&self, ctx: &RunContext) -> Result<TaskOutput, String>;
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
