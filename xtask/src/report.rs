//! Running a loaded scene and reporting it: progress bars while it runs, each task's
//! table (CSV), pictures and interactive viewer page in the output folder with an
//! `index.html` linking the pages, the summary table on stdout (or the
//! metrics as JSON with `--json`) and `metrics.json`.

use indicatif::{ProgressBar, ProgressStyle};
use sinew_scene::{RunOptions, Scene, TaskResult};
use sinew_viz::{render, viewer};
use std::cell::RefCell;
use std::io::IsTerminal;
use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

/// How to report.
pub struct Options {
    /// Print the metrics JSON on stdout instead of the table.
    pub json: bool,
    /// Print nothing but errors.
    pub quiet: bool,
    /// Draw the pictures tasks offer.
    pub render: bool,
}

/// Runs every task of the scene in order and reports. Exit code 0 when every task ran
/// and met its expectations, 1 otherwise, 2 when the output could not be written.
pub fn run_and_report(scene: &Scene, out_dir: &Path, options: &Options) -> ExitCode {
    if let Err(e) = std::fs::create_dir_all(out_dir) {
        eprintln!("error: {}: {e}", out_dir.display());
        return ExitCode::from(2);
    }
    let show_progress = !options.quiet && !options.json && std::io::stdout().is_terminal();
    let bar = RefCell::new(Bar::default());
    let progress =
        |task: &str, done: usize, total: usize| bar.borrow_mut().update(task, done, total);
    let run_options = RunOptions {
        keep_frames: options.render,
        progress: show_progress.then_some(&progress as &dyn Fn(&str, usize, usize)),
    };
    let mut results = scene.run(&run_options);
    bar.borrow_mut().clear();
    let mut pages = Vec::new();
    for task in &mut results.tasks {
        // Writing a task's table, pictures or viewer page can fail; that task then
        // failed, as when it could not run.
        if let Err(e) = write_outputs(task, out_dir, &mut pages) {
            *task = TaskResult::failed(&task.name, task.kind, task.wall_time_s, e);
        }
        for f in &task.failures {
            eprintln!(
                "{}: task \"{}\": check failed: {f}",
                scene.path.display(),
                task.name
            );
        }
        if let Some(e) = &task.error {
            eprintln!("{}: task \"{}\": {e}", scene.path.display(), task.name);
        }
    }
    if options.render
        && let Err(e) = viewer::write_scene_index(out_dir, &scene.name, &pages)
    {
        eprintln!("error: {e}");
        return ExitCode::from(2);
    }
    // Through a JSON value, so keys come out sorted as they always have.
    let text = serde_json::to_value(&results)
        .and_then(|v| serde_json::to_string_pretty(&v))
        .expect("metrics are plain JSON values");
    let metrics_path = out_dir.join("metrics.json");
    if let Err(e) = std::fs::write(&metrics_path, format!("{text}\n")) {
        eprintln!("error: {}: {e}", metrics_path.display());
        return ExitCode::from(2);
    }
    if options.json {
        println!("{text}");
    } else if !options.quiet {
        print_table(scene, &results.tasks, &metrics_path);
    }
    if results.ok() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    }
}

/// Writes the task's CSV table, draws its pictures and writes its viewer page (if the
/// run kept frames and the task is animated), adding the page to `pages`.
fn write_outputs(
    task: &TaskResult,
    out_dir: &Path,
    pages: &mut Vec<viewer::PageSummary>,
) -> Result<(), String> {
    if !task.table.suffix.is_empty() {
        let path = out_dir.join(format!("{}.{}", task.name, task.table.suffix));
        std::fs::write(&path, &task.table.text).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    render::draw_task(&task.name, &task.pictures, out_dir)?;
    if let Some(page) = render::viewer_page(task) {
        let file = format!("{}.html", task.name);
        let summary = viewer::write_page(out_dir, &file, &page, &viewer::Budget::default())
            .map_err(|e| e.to_string())?;
        pages.push(summary);
    }
    Ok(())
}

/// A progress bar that appears only once a task has run for about a second.
#[derive(Default)]
struct Bar {
    task: String,
    start: Option<Instant>,
    bar: Option<ProgressBar>,
}

impl Bar {
    fn update(&mut self, task: &str, done: usize, total: usize) {
        if self.task != task || self.start.is_none() {
            self.clear();
            self.task = task.to_string();
            self.start = Some(Instant::now());
        }
        match &self.bar {
            Some(bar) => bar.set_position(done as u64),
            None if self.start.is_some_and(|s| s.elapsed().as_secs_f64() > 1.0) => {
                let bar = ProgressBar::new(total as u64);
                bar.set_style(
                    ProgressStyle::with_template("  {msg:<28} [{bar:30}] {pos}/{len} {eta}")
                        .expect("a valid template")
                        .progress_chars("=> "),
                );
                bar.set_message(self.task.clone());
                bar.set_position(done as u64);
                self.bar = Some(bar);
            }
            None => {}
        }
    }

    fn clear(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
        self.start = None;
    }
}

fn print_table(scene: &Scene, rows: &[TaskResult], metrics_path: &Path) {
    println!("scene {}: {}", scene.name, scene.description);
    let name_width = rows.iter().map(|r| r.name.len()).max().unwrap_or(4).max(4);
    let kind_width = rows.iter().map(|r| r.kind.len()).max().unwrap_or(4).max(4);
    println!(
        "  {:<name_width$}  {:<kind_width$}  {:>9}  result",
        "task", "kind", "time"
    );
    for r in rows {
        let mark = if r.ok { "" } else { "FAILED " };
        println!(
            "  {:<name_width$}  {:<kind_width$}  {:>9}  {mark}{}",
            r.name,
            r.kind,
            format_seconds(r.wall_time_s),
            r.headline
        );
    }
    println!("metrics: {}", metrics_path.display());
}

fn format_seconds(s: f64) -> String {
    if s >= 1.0 {
        format!("{s:.2} s")
    } else if s >= 1e-3 {
        format!("{:.1} ms", s * 1e3)
    } else {
        format!("{:.0} us", s * 1e6)
    }
}
