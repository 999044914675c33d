//! `cargo xtask goals`: the contact workloads' speed goals (C1, C3, C4 and C5 of the
//! shared workload list, docs/workloads.md), each measured through the scene runner on
//! the committed scene that holds it, with the guarantees' counts beside the times.
//!
//! Every goal's scene runs `--runs` times (default 3), in rounds (every goal once, then
//! again), so a burst of load on a shared machine spreads over the goals rather than
//! landing on one goal's runs. Each run is a process of its own, this same binary's
//! `run-scene <scene> --json --no-render --quiet`, as a user runs a scene. A run's figure
//! is its task's `time_per_step_ms_median` (the scene runner's, docs/scenes.md); a goal's
//! figure is the median of its runs' figures, quoted with every run's figure and the
//! load at its start, and the ratio to the goal. The counts (Newton iterations,
//! penetrations, intersections) are the last run's, and the runs must agree on them: a
//! scene is deterministic (docs/scenes.md), so runs that differ fail the command.
//!
//! `--baseline <xtask binary>` (another build's, e.g. main's) runs that build's
//! `run-scene` on the same scene files beside every run of this one, alternated (the
//! baseline first in the first round, second in the next, and so on), and the page adds
//! its runs, its median and the ratio of this build's median to it: the comparison of a
//! change against main in the same hour. Its counts may differ from this build's (a
//! change may take another path); the page shows both. The page names the baseline by
//! `--baseline-name` (e.g. "main's xtask at 286d580") or else by the binary's file name,
//! never by its path.
//!
//! Written: `goals.md` and `goals.json` (default `docs/bench/`; `--quick` runs the
//! committed short scenes once each in the dev build and writes to
//! `target/goals-quick/`, figures not for quoting).

use crate::machine::{Machine, load_average};
use serde::Serialize;
use serde_json::Value;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

/// `cargo xtask goals` flags.
#[derive(clap::Args)]
pub struct GoalsArgs {
    /// Runs of every goal's scene, in rounds (default 3; 1 with --quick).
    #[arg(long)]
    runs: Option<usize>,
    /// Only these goals, comma-separated (C1, C3, C4, C5, C5-denser).
    #[arg(long, value_delimiter = ',')]
    only: Vec<String>,
    /// Write goals.md and goals.json here (default docs/bench/, or target/goals-quick/
    /// with --quick).
    #[arg(long)]
    out: Option<PathBuf>,
    /// A smoke run: the committed short scenes (scenes/*.ron rather than
    /// scenes/long/*.ron) once each in the dev profile; the figures are not the goals'.
    #[arg(long)]
    quick: bool,
    /// Another build's xtask binary (e.g. main's `target/release/xtask`): its runs of
    /// the same scenes alternate with this build's, and the page compares the two.
    #[arg(long)]
    baseline: Option<PathBuf>,
    /// How the page and its JSON name the baseline build (e.g. "main's xtask at
    /// 286d580"; default: the binary's file name). The page never names its path, which
    /// is usually outside the repository.
    #[arg(long, requires = "baseline")]
    baseline_name: Option<String>,
}

/// The name the page gives the baseline build: `name` when given, else the binary's
/// file name (a path outside the repository would be meaningless to a reader and is
/// refused by the repository's tidy check).
fn baseline_label(binary: &Path, name: Option<&str>) -> String {
    name.map_or_else(
        || {
            binary.file_name().map_or_else(
                || binary.display().to_string(),
                |f| f.to_string_lossy().into_owned(),
            )
        },
        str::to_string,
    )
}

/// A speed goal: the committed scene and task that hold its workload.
#[derive(Clone, Copy, Debug)]
struct Goal {
    id: &'static str,
    /// The workload, in a few words.
    what: &'static str,
    /// The full workload's scene, relative to the project root.
    scene: &'static str,
    /// The shorter committed scene run by `--quick`.
    quick_scene: &'static str,
    /// The task of both scenes that holds the workload.
    task: &'static str,
    /// The goal, milliseconds per step (median).
    goal_ms: f64,
}

const GOALS: [Goal; 5] = [
    Goal {
        id: "C1",
        what: "32 x 32 sheet dropped on the ground, h = 1/60",
        scene: "scenes/cloth-ground.ron",
        quick_scene: "scenes/cloth-ground.ron",
        task: "ground",
        goal_ms: 1.0,
    },
    Goal {
        id: "C3",
        what: "61 x 61 sheet on a sphere turning 180 deg/s, friction 0.4, h = 1/60",
        scene: "scenes/long/cloth-rotating-sphere.ron",
        quick_scene: "scenes/cloth-rotating-sphere.ron",
        task: "rotating-sphere",
        goal_ms: 20.0,
    },
    Goal {
        id: "C4",
        what: "50 x 50 sheet twisted at pi/3 rad/s with self-contact, the whole twist",
        scene: "scenes/long/cloth-twist.ron",
        quick_scene: "scenes/cloth-twist.ron",
        task: "twist",
        goal_ms: 30.0,
    },
    Goal {
        id: "C5",
        what: "three 32 x 32 sheets (5 cm spacing) dropped onto each other, as the workload list writes it",
        scene: "scenes/long/cloth-stack-workload.ron",
        quick_scene: "scenes/cloth-stack.ron",
        task: "stack",
        goal_ms: 30.0,
    },
    Goal {
        id: "C5-denser",
        what: "three 32 x 32 sheets (1 cm spacing, 2 cm apart) dropped onto each other",
        scene: "scenes/long/cloth-stack.ron",
        quick_scene: "scenes/cloth-stack.ron",
        task: "stack",
        goal_ms: 30.0,
    },
];

/// What one run of a goal's task measured.
#[derive(Clone, Debug, PartialEq, Serialize)]
struct Measured {
    /// The task's median wall time per step, milliseconds.
    ms_per_step: f64,
    steps: usize,
    /// The mesh's vertices (`None`: a `Cloth` task, whose metrics do not count them).
    vertices: Option<usize>,
    newton_iterations: usize,
    /// Particle-steps inside a collider.
    penetrations: usize,
    /// Pairs of triangles passing through each other (`None`: a `Cloth` task, no mesh).
    intersections: Option<usize>,
}

impl Measured {
    /// The counts, which every run of a deterministic scene must repeat.
    fn counts(&self) -> (usize, Option<usize>, usize, usize, Option<usize>) {
        (
            self.steps,
            self.vertices,
            self.newton_iterations,
            self.penetrations,
            self.intersections,
        )
    }
}

/// One build's runs of a goal.
#[derive(Clone, Debug, Default, Serialize)]
struct Series {
    runs: Vec<Measured>,
    /// The 1-minute load average at each run's start (`None` where unknown).
    loads: Vec<Option<f64>>,
    /// The median of the runs' figures, milliseconds per step.
    median_ms: f64,
}

impl Series {
    /// Adds a run, unless its counts differ from the first run's (a scene is
    /// deterministic): then the error says how.
    fn push(&mut self, m: Measured, load: Option<f64>) -> Result<(), String> {
        if let Some(first) = self.runs.first()
            && first.counts() != m.counts()
        {
            return Err(format!(
                "the counts {:?} differ from the first run's {:?}, and a scene is deterministic",
                m.counts(),
                first.counts()
            ));
        }
        self.runs.push(m);
        self.loads.push(load);
        self.median_ms = median(&self.runs.iter().map(|m| m.ms_per_step).collect::<Vec<_>>());
        Ok(())
    }

    /// `figure (load)` for every run, comma-separated.
    fn runs_cell(&self) -> String {
        let runs: Vec<String> = self
            .runs
            .iter()
            .zip(&self.loads)
            .map(|(m, l)| {
                format!(
                    "{:.2} ({})",
                    m.ms_per_step,
                    l.map_or("?".into(), |l| format!("{l:.1}"))
                )
            })
            .collect();
        runs.join(", ")
    }
}

/// A goal's runs, this build's and the baseline's.
#[derive(Clone, Debug, Serialize)]
struct GoalResult {
    id: &'static str,
    what: &'static str,
    scene: &'static str,
    task: &'static str,
    goal_ms: f64,
    /// This build's runs.
    this: Series,
    /// The baseline build's runs (with `--baseline`).
    baseline: Option<Series>,
    /// This build's median over the goal: at most 1 meets it.
    ratio: f64,
    /// This build's median over the baseline's.
    against_baseline: Option<f64>,
}

#[derive(Serialize)]
struct Report<'a> {
    machine: &'a Machine,
    quick: bool,
    baseline: Option<String>,
    goals: &'a [GoalResult],
}

/// The task `task` of a scene run's results as `run-scene --json` prints them: its
/// figure and counts, or why there are none.
fn measured_from(results: &Value, task: &str) -> Result<Measured, String> {
    let t = results["tasks"]
        .as_array()
        .and_then(|tasks| tasks.iter().find(|t| t["name"] == task))
        .ok_or_else(|| format!("the scene has no task `{task}`"))?;
    if t["ok"] != true {
        let why = t["error"]
            .as_str()
            .unwrap_or("an expectation of the scene failed");
        return Err(format!("task `{task}` failed: {why}"));
    }
    let m = &t["metrics"];
    let count = |key: &str| m[key].as_u64().map(|v| v as usize);
    let need = |key: &str| count(key).ok_or_else(|| format!("task `{task}` has no `{key}`"));
    let kind = t["kind"].as_str().unwrap_or("");
    if kind != "Cloth" && kind != "MeshCloth" {
        return Err(format!("task `{task}` is neither Cloth nor MeshCloth"));
    }
    Ok(Measured {
        ms_per_step: m["time_per_step_ms_median"]
            .as_f64()
            .ok_or_else(|| format!("task `{task}` has no `time_per_step_ms_median`"))?,
        steps: need("steps")?,
        vertices: count("vertices"),
        newton_iterations: need("newton_iterations_total")?,
        penetrations: need("penetrations")?,
        intersections: count("intersections"),
    })
}

/// Runs `exe run-scene <scene> --json` (outputs written below `out`) and returns what it
/// printed.
fn run_scene(exe: &Path, scene: &Path, out: &Path) -> Result<Value, String> {
    let output = Command::new(exe)
        .arg("run-scene")
        .arg(scene)
        .args(["--json", "--no-render", "--quiet", "--out"])
        .arg(out)
        .output()
        .map_err(|e| format!("{}: {e}", exe.display()))?;
    serde_json::from_slice(&output.stdout).map_err(|e| {
        format!(
            "{} run-scene {}: no metrics on its output ({e}; {}): {}",
            exe.display(),
            scene.display(),
            output.status,
            String::from_utf8_lossy(&output.stderr).trim()
        )
    })
}

/// The median of `values` (the mean of the two middle ones for an even count).
fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The goals named in `only` (all when empty), or the unknown name.
fn chosen(only: &[String]) -> Result<Vec<Goal>, String> {
    if only.is_empty() {
        return Ok(GOALS.to_vec());
    }
    only.iter()
        .map(|name| {
            GOALS
                .iter()
                .find(|g| g.id.eq_ignore_ascii_case(name))
                .copied()
                .ok_or_else(|| {
                    let ids: Vec<_> = GOALS.iter().map(|g| g.id).collect();
                    format!("unknown goal `{name}` (expected one of {})", ids.join(", "))
                })
        })
        .collect()
}

/// Which builds run in round `round`, in order: this build alone, or with a baseline
/// the baseline first in even rounds and second in odd ones, so neither build always
/// runs just after the other's.
fn order(round: usize, with_baseline: bool) -> Vec<bool> {
    match (with_baseline, round % 2) {
        (false, _) => vec![false],
        (true, 0) => vec![true, false],
        (true, _) => vec![false, true],
    }
}

/// Runs every goal `runs` times in rounds (and the baseline beside it); an error names
/// the goal, the build and the run.
fn measure_all(
    goals: &[Goal],
    runs: usize,
    quick: bool,
    baseline: Option<&Path>,
    root: &Path,
) -> Result<Vec<GoalResult>, String> {
    let this_exe = std::env::current_exe().map_err(|e| format!("this binary's path: {e}"))?;
    let outputs = root.join("target/goals-runs");
    let mut results: Vec<GoalResult> = goals
        .iter()
        .map(|g| GoalResult {
            id: g.id,
            what: g.what,
            scene: if quick { g.quick_scene } else { g.scene },
            task: g.task,
            goal_ms: g.goal_ms,
            this: Series::default(),
            baseline: baseline.map(|_| Series::default()),
            ratio: f64::NAN,
            against_baseline: None,
        })
        .collect();
    for round in 0..runs {
        for (g, out) in goals.iter().zip(&mut results) {
            let scene = root.join(out.scene);
            for is_baseline in order(round, baseline.is_some()) {
                let (exe, build) = match baseline {
                    Some(b) if is_baseline => (b, "baseline"),
                    _ => (this_exe.as_path(), "this build"),
                };
                let load = load_average();
                eprintln!(
                    "goals: {} run {} of {runs}, {build} (load {})",
                    g.id,
                    round + 1,
                    load.map_or("unknown".into(), |l| format!("{l:.2}"))
                );
                let name = format!("{}-{}", g.id, if is_baseline { "baseline" } else { "this" });
                let printed = run_scene(exe, &scene, &outputs.join(name))?;
                let series = match (is_baseline, out.baseline.as_mut()) {
                    (true, Some(s)) => s,
                    _ => &mut out.this,
                };
                measured_from(&printed, g.task)
                    .and_then(|m| series.push(m, load))
                    .map_err(|e| format!("{} run {}, {build}: {e}", g.id, round + 1))?;
            }
        }
    }
    for r in &mut results {
        r.ratio = r.this.median_ms / r.goal_ms;
        r.against_baseline = r.baseline.as_ref().map(|b| r.this.median_ms / b.median_ms);
    }
    Ok(results)
}

/// A count, or `-` where the task has none.
fn cell(count: Option<usize>) -> String {
    count.map_or("-".into(), |c| c.to_string())
}

/// How a table's column is aligned.
#[derive(Clone, Copy)]
enum Align {
    Left,
    Right,
}
use Align::{Left, Right};

/// A markdown table's header and the separator line it implies.
fn head(s: &mut String, columns: &[(&str, Align)]) {
    let names: Vec<&str> = columns.iter().map(|(name, _)| *name).collect();
    let rules: Vec<&str> = columns
        .iter()
        .map(|(_, align)| match align {
            Left => "---",
            Right => "---:",
        })
        .collect();
    let _ = writeln!(s, "| {} |", names.join(" | "));
    let _ = writeln!(s, "|{}|", rules.join("|"));
}

/// OGC's published CPU cost per vertex and step, microseconds: 0.21 s a step on average for
/// 246 000 vertices (Chen et al. 2025, "Offset Geometric Contact", its 50 layers of cloth
/// dropped onto a cylinder).
const OGC_US_PER_VERTEX_STEP: f64 = 0.21e6 / 246_000.0;

/// The mesh goals' cost per vertex and step next to OGC's published CPU figure, the
/// reference the self-contact goals are compared with; nothing for a smoke run, whose
/// scenes are not the workloads, or when no goal ran on a mesh.
fn per_vertex(s: &mut String, quick: bool, goals: &[GoalResult]) {
    let rows: Vec<(&GoalResult, usize)> = goals
        .iter()
        .filter_map(|g| Some((g, g.this.runs.last()?.vertices?)))
        .filter(|&(_, v)| v > 0)
        .collect();
    if quick || rows.is_empty() {
        return;
    }
    let _ = writeln!(
        s,
        "\nThe goals on triangle meshes per vertex and step, next to OGC's published CPU figure (Chen et al. 2025, \"Offset Geometric Contact\": 50 layers of cloth, 246 000 vertices, 0.21 s a step on average, {OGC_US_PER_VERTEX_STEP:.3} us per vertex-step). Another method, scene and machine: the ratio says how far apart the two costs are, not which is better at equal work.\n"
    );
    head(
        s,
        &[
            ("goal", Left),
            ("vertices", Right),
            ("median, ms per step", Right),
            ("us per vertex-step", Right),
            ("/ OGC's", Right),
        ],
    );
    for (g, vertices) in rows {
        let us = 1e3 * g.this.median_ms / vertices as f64;
        let _ = writeln!(
            s,
            "| {} | {vertices} | {:.2} | {us:.1} | {:.0} |",
            g.id,
            g.this.median_ms,
            us / OGC_US_PER_VERTEX_STEP
        );
    }
}

/// The goals as a markdown page.
fn markdown(
    machine: &Machine,
    quick: bool,
    baseline: Option<&str>,
    goals: &[GoalResult],
) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Speed goals of the contact workloads\n");
    let _ = writeln!(
        s,
        "Written by `cargo xtask goals{}` (docs/bench.md, \"Speed goals of the contact workloads\"). Machine: {}.\n",
        if quick { " --quick" } else { "" },
        machine.describe()
    );
    if quick {
        let _ = writeln!(
            s,
            "A smoke run of the short scenes in the dev profile (each shorter or smaller than its goal's workload, which the second column describes): these are not the goals' figures, and no ratio is given.\n"
        );
    }
    let _ = writeln!(
        s,
        "Each figure is the scene runner's median time per step of the task (ms); a goal's figure is the median of its runs, quoted with each run's figure and the 1-minute load at its start.\n"
    );
    head(
        &mut s,
        &[
            ("goal", Left),
            ("workload", Left),
            ("scene (task)", Left),
            ("runs, ms per step (load)", Left),
            ("median", Right),
            ("goal", Right),
            ("ratio", Right),
            ("steps", Right),
            ("Newton iterations", Right),
            ("penetrations", Right),
            ("intersections", Right),
        ],
    );
    for g in goals {
        let last = g.this.runs.last();
        let _ = writeln!(
            s,
            "| {} | {} | `{}` ({}) | {} | {:.2} | {} | {} | {} | {} | {} | {} |",
            g.id,
            g.what,
            g.scene,
            g.task,
            g.this.runs_cell(),
            g.this.median_ms,
            g.goal_ms,
            // A short scene's figure is not the workload's: no ratio to its goal.
            if quick {
                "-".to_string()
            } else {
                format!("{:.2}", g.ratio)
            },
            last.map_or(0, |m| m.steps),
            last.map_or(0, |m| m.newton_iterations),
            last.map_or(0, |m| m.penetrations),
            cell(last.and_then(|m| m.intersections)),
        );
    }
    per_vertex(&mut s, quick, goals);
    if let Some(path) = baseline {
        let _ = writeln!(
            s,
            "\nAgainst the baseline build `{path}`, its runs alternated with this build's in every round (the baseline first in the first round):\n"
        );
        head(
            &mut s,
            &[
                ("goal", Left),
                ("this build: runs (load)", Left),
                ("median", Right),
                ("baseline: runs (load)", Left),
                ("median", Right),
                ("this / baseline", Right),
                ("Newton iterations (this, baseline)", Right),
                ("penetrations", Right),
                ("intersections", Right),
            ],
        );
        for g in goals {
            let Some(b) = &g.baseline else { continue };
            let (this, base) = (g.this.runs.last(), b.runs.last());
            let pair = |f: fn(&Measured) -> Option<usize>| {
                format!("{}, {}", cell(this.and_then(f)), cell(base.and_then(f)))
            };
            let _ = writeln!(
                s,
                "| {} | {} | {:.2} | {} | {:.2} | {:.3} | {} | {} | {} |",
                g.id,
                g.this.runs_cell(),
                g.this.median_ms,
                b.runs_cell(),
                b.median_ms,
                g.against_baseline.unwrap_or(f64::NAN),
                pair(|m| Some(m.newton_iterations)),
                pair(|m| Some(m.penetrations)),
                pair(|m| m.intersections),
            );
        }
    }
    s
}

pub fn run(args: &GoalsArgs) -> ExitCode {
    if !args.quick
        && let Some(code) = crate::machine::rerun_in_release()
    {
        return code;
    }
    let goals = match chosen(&args.only) {
        Ok(g) => g,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let runs = args.runs.unwrap_or(if args.quick { 1 } else { 3 });
    if runs == 0 {
        eprintln!("error: --runs must be at least 1");
        return ExitCode::from(2);
    }
    if let Some(b) = &args.baseline
        && !b.is_file()
    {
        eprintln!("error: --baseline {}: no such file", b.display());
        return ExitCode::from(2);
    }
    let root = crate::project_root();
    let out = args.out.clone().unwrap_or_else(|| {
        root.join(if args.quick {
            "target/goals-quick"
        } else {
            "docs/bench"
        })
    });
    let machine = Machine::read();
    let results = match measure_all(&goals, runs, args.quick, args.baseline.as_deref(), &root) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
    };
    let baseline = args
        .baseline
        .as_ref()
        .map(|b| baseline_label(b, args.baseline_name.as_deref()));
    let page = markdown(&machine, args.quick, baseline.as_deref(), &results);
    print!("{page}");
    let json = serde_json::to_string_pretty(&Report {
        machine: &machine,
        quick: args.quick,
        baseline,
        goals: &results,
    })
    .expect("the report serializes");
    let written = std::fs::create_dir_all(&out)
        .and_then(|()| std::fs::write(out.join("goals.md"), &page))
        .and_then(|()| std::fs::write(out.join("goals.json"), json + "\n"));
    if let Err(e) = written {
        eprintln!("error: writing {}: {e}", out.display());
        return ExitCode::FAILURE;
    }
    eprintln!("written: {}", out.join("goals.md").display());
    ExitCode::SUCCESS
}

#[cfg(test)]
mod tests {
    use super::*;
    use sinew_scene::{RunOptions, Scene};

    #[test]
    fn median_of_odd_and_even_counts() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median(&[]).is_nan());
    }

    #[test]
    fn goals_are_chosen_by_name_and_an_unknown_one_is_named() {
        let all = chosen(&[]).unwrap();
        assert_eq!(all.len(), GOALS.len());
        let some = chosen(&["c3".into(), "C5-denser".into()]).unwrap();
        assert_eq!(
            some.iter().map(|g| g.id).collect::<Vec<_>>(),
            ["C3", "C5-denser"]
        );
        let err = chosen(&["C2".into()]).unwrap_err();
        assert!(err.contains("`C2`") && err.contains("C1, C3"), "{err}");
    }

    /// The baseline runs first in even rounds and second in odd ones.
    #[test]
    fn the_builds_alternate_from_round_to_round() {
        assert_eq!(order(0, false), [false]);
        assert_eq!(order(1, false), [false]);
        assert_eq!(order(0, true), [true, false]);
        assert_eq!(order(1, true), [false, true]);
        assert_eq!(order(2, true), [true, false]);
    }

    /// Every goal's scenes exist, parse, and hold the goal's task.
    #[test]
    fn every_goal_names_a_task_of_its_scenes() {
        let root = crate::project_root();
        for g in GOALS {
            for file in [g.scene, g.quick_scene] {
                let scene = Scene::from_file(root.join(file))
                    .unwrap_or_else(|e| panic!("{}: {file}: {e}", g.id));
                assert!(
                    scene.tasks.iter().any(|t| t.name() == g.task),
                    "{}: {file} has no task `{}`",
                    g.id,
                    g.task
                );
            }
        }
    }

    /// A Cloth contact task and a MeshCloth task give their figures and counts from the
    /// JSON `run-scene --json` prints (the results serialized as the runner serializes
    /// them); a task that is missing, of another kind or failed is an error naming it.
    #[test]
    fn a_runs_figures_and_counts_are_read_from_the_runners_json() {
        let scene = Scene::from_text(
            "goals-test.ron",
            r#"Scene(
                description: "two small contact tasks",
                tasks: [
                    Cloth(name: "ground", system: Grid(size: 6, spacing: 0.1, origin: (0.0, 0.05, 0.0), mass: 5e-4, fixed: [],
                            material: (stiffness: 100.0, damping: 0.1, gravity: (0.0, -9.81, 0.0))),
                          integrator: backward_euler(), dt: 0.016666666666666666, steps: 6,
                          contact: (colliders: [(shape: HalfSpace(point: (0.0, 0.0, 0.0), normal: (0.0, 1.0, 0.0)))],
                                    settings: (dhat: 1e-3, mu: 0.3))),
                    MeshCloth(name: "stack", sheets: [Grid(size: 4, spacing: 0.05, origin: (0.0, 0.02, 0.0))],
                          material: (stiffness: 100.0, damping: 0.1, gravity: (0.0, -9.81, 0.0)),
                          dt: 0.016666666666666666, steps: 4, self_contact: (dhat: 2e-3, thickness: 1e-3),
                          colliders: [(shape: HalfSpace(point: (0.0, 0.0, 0.0), normal: (0.0, 1.0, 0.0)))],
                          contact: (dhat: 1e-3, mu: 0.3)),
                    Curve(name: "curve", curve: Epicycloid(petals: 5, r: 0.1), sampling: Uniform(n: 50)),
                ],
            )"#,
        )
        .unwrap();
        let results = scene.run(&RunOptions::default());
        let printed = serde_json::to_value(&results).unwrap();
        let ground = measured_from(&printed, "ground").unwrap();
        assert_eq!(
            (
                ground.steps,
                ground.vertices,
                ground.penetrations,
                ground.intersections
            ),
            (6, None, 0, None)
        );
        assert!(ground.newton_iterations >= 6 && ground.ms_per_step > 0.0);
        let stack = measured_from(&printed, "stack").unwrap();
        assert_eq!(
            (
                stack.steps,
                stack.vertices,
                stack.penetrations,
                stack.intersections
            ),
            (4, Some(16), 0, Some(0))
        );
        assert!(stack.newton_iterations >= 4 && stack.ms_per_step > 0.0);
        assert!(
            measured_from(&printed, "absent")
                .unwrap_err()
                .contains("no task `absent`")
        );
        assert!(
            measured_from(&printed, "curve")
                .unwrap_err()
                .contains("neither Cloth nor MeshCloth")
        );
        let mut failed = printed.clone();
        failed["tasks"][0]["ok"] = Value::Bool(false);
        failed["tasks"][0]["error"] = Value::String("the solver stopped".into());
        assert!(
            measured_from(&failed, "ground")
                .unwrap_err()
                .contains("task `ground` failed: the solver stopped")
        );
    }

    /// A run of C5 as written with its counts, taking `ms` a step and `newton` Newton
    /// iterations.
    fn stack_run(ms: f64, newton: usize) -> Measured {
        Measured {
            ms_per_step: ms,
            steps: 120,
            vertices: Some(3072),
            newton_iterations: newton,
            penetrations: 0,
            intersections: Some(0),
        }
    }

    /// A run whose counts differ from the first run's is refused.
    #[test]
    fn a_series_refuses_runs_that_count_differently() {
        let mut s = Series::default();
        s.push(stack_run(33.0, 165), Some(0.4)).unwrap();
        s.push(stack_run(27.0, 165), None).unwrap();
        let err = s.push(stack_run(30.0, 166), None).unwrap_err();
        assert!(err.contains("differ"), "{err}");
        assert_eq!((s.runs.len(), s.median_ms), (2, 30.0));
    }

    #[test]
    fn the_baseline_is_named_by_its_given_name_or_file_name_never_its_directory() {
        let binary = Path::new("/opt/builds/xtask-main");
        assert_eq!(baseline_label(binary, None), "xtask-main");
        assert_eq!(
            baseline_label(binary, Some("main's xtask at 286d580")),
            "main's xtask at 286d580"
        );
    }

    #[test]
    fn the_page_lists_every_run_the_ratio_and_the_baseline() {
        let machine = Machine::read();
        let series = |figures: &[f64], newton: usize, loads: &[Option<f64>]| {
            let mut s = Series::default();
            for (&f, &l) in figures.iter().zip(loads) {
                s.push(stack_run(f, newton), l).unwrap();
            }
            s
        };
        let goal = GoalResult {
            id: "C5",
            what: "w",
            scene: "scenes/long/cloth-stack-workload.ron",
            task: "stack",
            goal_ms: 30.0,
            this: series(&[33.0, 27.0, 36.0], 165, &[Some(0.4), None, Some(1.25)]),
            baseline: Some(series(
                &[40.0, 44.0, 42.0],
                170,
                &[Some(1.0), Some(1.0), Some(1.0)],
            )),
            ratio: 1.1,
            against_baseline: Some(33.0 / 42.0),
        };
        let page = markdown(
            &machine,
            false,
            Some("/main/xtask"),
            std::slice::from_ref(&goal),
        );
        assert!(
            page.contains("| C5 | w | `scenes/long/cloth-stack-workload.ron` (stack) | 33.00 (0.4), 27.00 (?), 36.00 (1.2) | 33.00 | 30 | 1.10 | 120 | 165 | 0 | 0 |"),
            "{page}"
        );
        assert!(
            page.contains("`/main/xtask`")
                && page.contains("| C5 | 33.00 (0.4), 27.00 (?), 36.00 (1.2) | 33.00 | 40.00 (1.0), 44.00 (1.0), 42.00 (1.0) | 42.00 | 0.786 | 165, 170 | 0, 0 | 0, 0 |"),
            "{page}"
        );
        // C5's 33 ms a step over its 3 072 vertices: 10.7 us a vertex-step, 12.6 times
        // OGC's 0.854.
        assert!(
            page.contains("| C5 | 3072 | 33.00 | 10.7 | 13 |") && page.contains("0.854 us"),
            "{page}"
        );
        let quick = markdown(&machine, true, None, std::slice::from_ref(&goal));
        assert!(!quick.contains("per vertex-step"), "{quick}");
        // The headers and the separators they imply, as the committed page has them.
        assert!(
            page.contains("| goal | workload | scene (task) | runs, ms per step (load) | median | goal | ratio | steps | Newton iterations | penetrations | intersections |\n|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|\n"),
            "{page}"
        );
        assert!(
            page.contains("| goal | this build: runs (load) | median | baseline: runs (load) | median | this / baseline | Newton iterations (this, baseline) | penetrations | intersections |\n|---|---|---:|---|---:|---:|---:|---:|---:|\n"),
            "{page}"
        );
        // A smoke run's short scenes give no ratio, and without a baseline no second table.
        let quick = markdown(&machine, true, None, &[goal]);
        assert!(
            quick.contains("| 33.00 | 30 | - | 120 |")
                && quick.contains("no ratio")
                && !quick.contains("baseline"),
            "{quick}"
        );
    }
}
