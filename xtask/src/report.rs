//! Running a loaded scene and reporting it: the summary table on stdout (or the metrics
//! as JSON with `--json`) and `metrics.json` in the output folder.

use serde_json::json;
use sinew_scene::schema::LoadedScene;
use sinew_scene::tasks::RunContext;
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

struct Row {
    name: String,
    kind: &'static str,
    headline: String,
    seconds: f64,
    failed: bool,
}

/// Runs every task of the scene in order and reports. Exit code 0 when every task ran
/// and met its expectations, 1 otherwise, 2 when the output could not be written.
pub fn run_and_report(loaded: &LoadedScene, out_dir: &Path, options: &Options) -> ExitCode {
    if let Err(e) = std::fs::create_dir_all(out_dir) {
        eprintln!("error: {}: {e}", out_dir.display());
        return ExitCode::from(2);
    }
    let ctx = RunContext {
        out_dir: out_dir.to_path_buf(),
        render: options.render,
        progress: !options.quiet && !options.json && std::io::stdout().is_terminal(),
    };
    let mut rows = Vec::new();
    let mut task_metrics = Vec::new();
    let mut failed = false;
    for task in &loaded.scene.tasks {
        let spec = task.spec();
        let start = Instant::now();
        let result = spec.run(&ctx);
        let seconds = start.elapsed().as_secs_f64();
        match result {
            Ok(output) => {
                for f in &output.failures {
                    eprintln!(
                        "{}: task \"{}\": check failed: {f}",
                        loaded.path.display(),
                        spec.name()
                    );
                }
                let task_failed = !output.failures.is_empty();
                failed |= task_failed;
                task_metrics.push(json!({
                    "name": spec.name(),
                    "kind": spec.kind(),
                    "wall_time_s": seconds,
                    "ok": !task_failed,
                    "metrics": output.metrics,
                }));
                rows.push(Row {
                    name: spec.name().to_string(),
                    kind: spec.kind(),
                    headline: output.headline,
                    seconds,
                    failed: task_failed,
                });
            }
            Err(e) => {
                eprintln!("{}: task \"{}\": {e}", loaded.path.display(), spec.name());
                failed = true;
                task_metrics.push(json!({
                    "name": spec.name(),
                    "kind": spec.kind(),
                    "wall_time_s": seconds,
                    "ok": false,
                    "error": e,
                    "metrics": {},
                }));
                rows.push(Row {
                    name: spec.name().to_string(),
                    kind: spec.kind(),
                    headline: format!("error: {e}"),
                    seconds,
                    failed: true,
                });
            }
        }
    }
    let document = json!({
        "scene": loaded.name,
        "description": loaded.scene.description,
        "tasks": task_metrics,
    });
    let text = serde_json::to_string_pretty(&document).expect("metrics are plain JSON values");
    let metrics_path = out_dir.join("metrics.json");
    if let Err(e) = std::fs::write(&metrics_path, format!("{text}\n")) {
        eprintln!("error: {}: {e}", metrics_path.display());
        return ExitCode::from(2);
    }
    if options.json {
        println!("{text}");
    } else if !options.quiet {
        print_table(loaded, &rows, &metrics_path);
    }
    if failed {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    }
}

fn print_table(loaded: &LoadedScene, rows: &[Row], metrics_path: &Path) {
    println!("scene {}: {}", loaded.name, loaded.scene.description);
    let name_width = rows.iter().map(|r| r.name.len()).max().unwrap_or(4).max(4);
    let kind_width = rows.iter().map(|r| r.kind.len()).max().unwrap_or(4).max(4);
    println!(
        "  {:<name_width$}  {:<kind_width$}  {:>9}  result",
        "task", "kind", "time"
    );
    for r in rows {
        let mark = if r.failed { "FAILED " } else { "" };
        println!(
            "  {:<name_width$}  {:<kind_width$}  {:>9}  {mark}{}",
            r.name,
            r.kind,
            format_seconds(r.seconds),
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
