//! Same inputs, same outputs: every scene in `scenes/` run twice, once on a quiet process
//! and once while other threads keep every core busy, gives bitwise the same metrics,
//! tables and picture frames (positions, errors, energies). Only wall-clock figures may
//! differ; they are removed before the comparison, by name, and nothing else is.
//!
//! Load changes timing, and timing is what could leak into a result (a solver chosen by
//! a stopwatch, a thread pool splitting work differently, a time budget cutting an
//! iteration short); a difference in any other figure fails the test with the scene, the
//! task and the first differing item.

use serde_json::Value;
use sinew_scene::{RunOptions, Scene, SceneResults};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// Keys of `metrics.json` that hold wall-clock measurements.
fn is_timing_key(key: &str) -> bool {
    key == "wall_time_s" || key.starts_with("time_")
}

/// Columns of the task tables that hold wall-clock measurements.
fn is_timing_column(name: &str) -> bool {
    name.ends_with("_us") || name.ends_with("_ns") || name.ends_with("_ms")
}

fn strip_timings(value: &mut Value) {
    match value {
        Value::Object(map) => {
            map.retain(|k, _| !is_timing_key(k));
            map.values_mut().for_each(strip_timings);
        }
        Value::Array(items) => items.iter_mut().for_each(strip_timings),
        _ => {}
    }
}

/// A table with its timing columns removed.
fn strip_columns(csv: &str) -> String {
    let mut lines = csv.lines();
    let Some(header) = lines.next() else {
        return String::new();
    };
    let keep: Vec<bool> = header.split(',').map(|c| !is_timing_column(c)).collect();
    let filter = |line: &str| {
        line.split(',')
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(cell, _)| cell)
            .collect::<Vec<_>>()
            .join(",")
    };
    std::iter::once(filter(header))
        .chain(lines.map(filter))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Everything a run produced but its timings, task by task, as text (f64 values are
/// printed in their shortest round-trip form, so equal text is equal bits).
fn fingerprint(results: &SceneResults) -> Vec<(String, String, String, String)> {
    results
        .tasks
        .iter()
        .map(|task| {
            let mut metrics = serde_json::to_value(task).expect("results serialize");
            strip_timings(&mut metrics);
            (
                task.name.clone(),
                metrics.to_string(),
                strip_columns(&task.table.text),
                format!("{:?}", task.pictures),
            )
        })
        .collect()
}

fn scene_files() -> Vec<PathBuf> {
    let dir = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes"));
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("the scenes directory exists")
        .map(|e| e.expect("readable entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "ron"))
        .collect();
    files.sort();
    files
}

/// Runs `f` while `threads` threads spin, so the run shares the cores with busy work.
fn under_load<T>(threads: usize, f: impl FnOnce() -> T) -> T {
    let stop = Arc::new(AtomicBool::new(false));
    let spinners: Vec<_> = (0..threads)
        .map(|_| {
            let stop = Arc::clone(&stop);
            std::thread::spawn(move || {
                let mut x = 1.0f64;
                while !stop.load(Ordering::Relaxed) {
                    x = std::hint::black_box(x * 1.000_000_1 + 1e-9);
                }
                x
            })
        })
        .collect();
    let out = f();
    stop.store(true, Ordering::Relaxed);
    for s in spinners {
        s.join().expect("a spinner never panics");
    }
    out
}

fn first_difference(a: &str, b: &str) -> String {
    let at = a
        .bytes()
        .zip(b.bytes())
        .position(|(x, y)| x != y)
        .unwrap_or(a.len().min(b.len()));
    let from = at.saturating_sub(60);
    let show = |s: &str| {
        s.get(from..(at + 60).min(s.len()))
            .unwrap_or("")
            .to_string()
    };
    format!("quiet: ...{}...\nloaded: ...{}...", show(a), show(b))
}

#[test]
fn every_scene_gives_the_same_bits_whatever_the_load() {
    let files = scene_files();
    assert!(
        files.len() >= 10,
        "expected the repository's scenes, found {files:?}"
    );
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let options = RunOptions {
        keep_frames: true,
        ..RunOptions::default()
    };
    for file in files {
        let scene = Scene::from_file(&file).unwrap_or_else(|e| panic!("{e}"));
        let quiet = fingerprint(&scene.run(&options));
        let loaded = fingerprint(&under_load(cores, || scene.run(&options)));
        assert_eq!(quiet.len(), loaded.len());
        for (q, l) in quiet.iter().zip(&loaded) {
            let what = [
                ("metrics", &q.1, &l.1),
                ("table", &q.2, &l.2),
                ("frames", &q.3, &l.3),
            ];
            for (item, a, b) in what {
                assert!(
                    a == b,
                    "{}: task {}: {item} differ between a quiet and a loaded run\n{}",
                    file.display(),
                    q.0,
                    first_difference(a, b)
                );
            }
        }
    }
}

#[test]
fn the_timing_filters_remove_only_timings() {
    let mut v: Value = serde_json::json!({
        "wall_time_s": 1.0, "time_per_step_ms_median": 2.0,
        "metrics": {"time_ns": 3.0, "steps": 4, "time": 5.0, "energy_rise_max": 6.0}
    });
    strip_timings(&mut v);
    assert_eq!(
        v,
        serde_json::json!({"metrics": {"steps": 4, "time": 5.0, "energy_rise_max": 6.0}})
    );
    assert_eq!(
        strip_columns("frame,error,solve_us\n0,1e-7,12.5\n1,2e-7,11.0"),
        "frame,error\n0,1e-7\n1,2e-7"
    );
}
