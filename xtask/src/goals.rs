//! `cargo xtask goals`: the contact workloads' speed goals (C1, C3, C4 and C5 of the
//! shared workload list, docs/workloads.md), each measured through the scene runner on
//! the committed scene that holds it, with the guarantees' counts beside the times.
//!
//! Every goal's scene runs `--runs` times (default 3), in rounds (every goal once, then
//! again), so a burst of load on a shared machine spreads over the goals rather than
//! landing on one goal's runs. A run's figure is its task's `time_per_step_ms_median`
//! (the scene runner's, docs/scenes.md); a goal's figure is the median of its runs'
//! figures, quoted with every run's figure and the load at its start, and the ratio to
//! the goal. The counts (Newton iterations, penetrations, intersections) are the last
//! run's, and the runs must agree on them: a scene is deterministic (docs/scenes.md), so
//! runs that differ fail the command. Written: `goals.md` and `goals.json` (default
//! `docs/bench/`; `--quick` runs the committed short scenes once each in the dev build
//! and writes to `target/goals-quick/`, figures not for quoting).

use crate::machine::Machine;
use serde::Serialize;
use sinew_scene::results::TaskMetrics;
use sinew_scene::{RunOptions, Scene};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

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

/// A goal's runs.
#[derive(Clone, Debug, Serialize)]
struct GoalResult {
    id: &'static str,
    what: &'static str,
    scene: &'static str,
    task: &'static str,
    goal_ms: f64,
    runs: Vec<Measured>,
    /// The 1-minute load average at each run's start (`None` where unknown).
    loads: Vec<Option<f64>>,
    /// The median of the runs' figures, milliseconds per step.
    median_ms: f64,
    /// `median_ms / goal_ms`: at most 1 meets the goal.
    ratio: f64,
}

#[derive(Serialize)]
struct Report<'a> {
    machine: &'a Machine,
    quick: bool,
    goals: &'a [GoalResult],
}

/// The task `task` of a run's results: its figure and counts, or why there are none.
fn measured(results: &sinew_scene::results::SceneResults, task: &str) -> Result<Measured, String> {
    let t = results
        .tasks
        .iter()
        .find(|t| t.name == task)
        .ok_or_else(|| format!("the scene has no task `{task}`"))?;
    if !t.ok {
        let why = t.error.clone().unwrap_or_else(|| t.failures.join("; "));
        return Err(format!("task `{task}` failed: {why}"));
    }
    match &t.metrics {
        TaskMetrics::Cloth(m) => {
            let contact = m
                .contact
                .as_ref()
                .ok_or_else(|| format!("task `{task}` has no contact metrics"))?;
            Ok(Measured {
                ms_per_step: m.run.time_per_step_ms_median,
                steps: m.run.steps,
                vertices: None,
                newton_iterations: m.run.newton_iterations_total,
                penetrations: contact.penetrations,
                intersections: None,
            })
        }
        TaskMetrics::MeshCloth(m) => Ok(Measured {
            ms_per_step: m.time_per_step_ms_median,
            steps: m.steps,
            vertices: Some(m.vertices),
            newton_iterations: m.newton_iterations_total,
            penetrations: m.penetrations,
            intersections: Some(m.intersections),
        }),
        _ => Err(format!("task `{task}` is neither Cloth nor MeshCloth")),
    }
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

fn load_average() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    text.split_whitespace().next()?.parse().ok()
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

/// Runs every goal `runs` times in rounds; an error names the goal and run.
fn measure_all(
    goals: &[Goal],
    runs: usize,
    quick: bool,
    root: &Path,
) -> Result<Vec<GoalResult>, String> {
    let scenes = goals
        .iter()
        .map(|g| {
            let file = root.join(if quick { g.quick_scene } else { g.scene });
            Scene::from_file(&file).map_err(|e| format!("{}: {e}", g.id))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut results: Vec<GoalResult> = goals
        .iter()
        .map(|g| GoalResult {
            id: g.id,
            what: g.what,
            scene: if quick { g.quick_scene } else { g.scene },
            task: g.task,
            goal_ms: g.goal_ms,
            runs: Vec::new(),
            loads: Vec::new(),
            median_ms: f64::NAN,
            ratio: f64::NAN,
        })
        .collect();
    for round in 0..runs {
        for ((g, scene), out) in goals.iter().zip(&scenes).zip(&mut results) {
            let load = load_average();
            eprintln!(
                "goals: {} run {} of {runs} (load {})",
                g.id,
                round + 1,
                load.map_or("unknown".into(), |l| format!("{l:.2}"))
            );
            let run = scene.run(&RunOptions::default());
            let m =
                measured(&run, g.task).map_err(|e| format!("{} run {}: {e}", g.id, round + 1))?;
            if let Some(first) = out.runs.first()
                && first.counts() != m.counts()
            {
                return Err(format!(
                    "{} run {}: the counts {:?} differ from the first run's {:?}, and a scene is deterministic",
                    g.id,
                    round + 1,
                    m.counts(),
                    first.counts()
                ));
            }
            out.runs.push(m);
            out.loads.push(load);
        }
    }
    for r in &mut results {
        let figures: Vec<f64> = r.runs.iter().map(|m| m.ms_per_step).collect();
        r.median_ms = median(&figures);
        r.ratio = r.median_ms / r.goal_ms;
    }
    Ok(results)
}

/// The goals as a markdown page.
fn markdown(machine: &Machine, quick: bool, goals: &[GoalResult]) -> String {
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
    let _ = writeln!(
        s,
        "| goal | workload | scene (task) | runs, ms per step (load) | median | goal | ratio | steps | Newton iterations | penetrations | intersections |"
    );
    let _ = writeln!(s, "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for g in goals {
        let runs: Vec<String> = g
            .runs
            .iter()
            .zip(&g.loads)
            .map(|(m, l)| {
                format!(
                    "{:.2} ({})",
                    m.ms_per_step,
                    l.map_or("?".into(), |l| format!("{l:.1}"))
                )
            })
            .collect();
        let last = g.runs.last();
        let _ = writeln!(
            s,
            "| {} | {} | `{}` ({}) | {} | {:.2} | {} | {} | {} | {} | {} | {} |",
            g.id,
            g.what,
            g.scene,
            g.task,
            runs.join(", "),
            g.median_ms,
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
            last.and_then(|m| m.intersections)
                .map_or("-".into(), |i| i.to_string()),
        );
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
    let root = crate::project_root();
    let out = args.out.clone().unwrap_or_else(|| {
        root.join(if args.quick {
            "target/goals-quick"
        } else {
            "docs/bench"
        })
    });
    let machine = Machine::read();
    let results = match measure_all(&goals, runs, args.quick, &root) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
    };
    let page = markdown(&machine, args.quick, &results);
    print!("{page}");
    let json = serde_json::to_string_pretty(&Report {
        machine: &machine,
        quick: args.quick,
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

    /// A Cloth contact task and a MeshCloth task give their figures and counts; a task
    /// that is missing, or of another kind, is an error naming it.
    #[test]
    fn a_runs_figures_and_counts_are_the_tasks() {
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
        let run = scene.run(&RunOptions::default());
        let ground = measured(&run, "ground").unwrap();
        assert_eq!(
            (ground.steps, ground.penetrations, ground.intersections),
            (6, 0, None)
        );
        assert!(ground.newton_iterations >= 6 && ground.ms_per_step > 0.0);
        let stack = measured(&run, "stack").unwrap();
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
            measured(&run, "absent")
                .unwrap_err()
                .contains("no task `absent`")
        );
        assert!(
            measured(&run, "curve")
                .unwrap_err()
                .contains("neither Cloth nor MeshCloth")
        );
    }

    #[test]
    fn the_page_lists_every_run_and_the_ratio() {
        let machine = Machine::read();
        let m = |ms: f64| Measured {
            ms_per_step: ms,
            steps: 120,
            vertices: Some(3072),
            newton_iterations: 165,
            penetrations: 0,
            intersections: Some(0),
        };
        let goal = GoalResult {
            id: "C5",
            what: "w",
            scene: "scenes/long/cloth-stack-workload.ron",
            task: "stack",
            goal_ms: 30.0,
            runs: vec![m(33.0), m(27.0), m(36.0)],
            loads: vec![Some(0.4), None, Some(1.25)],
            median_ms: 33.0,
            ratio: 1.1,
        };
        let page = markdown(&machine, false, std::slice::from_ref(&goal));
        assert!(
            page.contains("| C5 | w | `scenes/long/cloth-stack-workload.ron` (stack) | 33.00 (0.4), 27.00 (?), 36.00 (1.2) | 33.00 | 30 | 1.10 | 120 | 165 | 0 | 0 |"),
            "{page}"
        );
        // A smoke run's short scenes give no ratio.
        let quick = markdown(&machine, true, &[goal]);
        assert!(
            quick.contains("| 33.00 | 30 | - | 120 |") && quick.contains("no ratio"),
            "{quick}"
        );
    }
}
