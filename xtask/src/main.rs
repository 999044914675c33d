//! `cargo xtask`: sinew's scene runner, its time-against-error benchmarks and its
//! numerical stress grid.
//!
//! `cargo xtask run-scene [FILE]` reads a RON scene (default `scenes/lab4.ron`), checks
//! every task before running any, runs the tasks it names and nothing else, prints a
//! summary table and writes `metrics.json` to `target/scenes/<scene>/` (or `--out DIR`).
//! See `docs/scenes.md` for the schema and every metric key.
//!
//! `cargo xtask bench` runs every method across its knobs on the shared workloads and
//! writes `docs/bench/README.md`, `docs/bench/results.json` and SVG plots of time against
//! error. `cargo xtask stress` runs the cloth stability grid and the IK degenerate set,
//! writes `docs/bench/stress.md` and exits non-zero on NaN, divergence or a broken
//! invariant. `cargo xtask scale` runs backward Euler on cloths from 11 x 11 to
//! 1000 x 1000 particles on one thread and on every core and writes
//! `docs/bench/scale.md` (time, memory and the speed-up per size) and a plot of the cost
//! per particle. `cargo xtask goals` runs the contact workloads' speed goals (C1, C3,
//! C4, C5) through the scene runner in rounds and writes `docs/bench/goals.md` (each
//! run's median time per step, the load at its start, the ratio to the goal, the
//! guarantees' counts). All four re-run themselves in release, except with `--quick` (a
//! smoke run).

mod bench;
mod goals;
mod machine;
mod report;
mod scale;
mod stress;

use clap::{Parser, Subcommand};
use sinew_scene::Scene;
use sinew_scene::schema as scene;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// sinew's developer tasks.
#[derive(Parser)]
#[command(name = "cargo xtask", bin_name = "cargo xtask", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a RON scene file (default: scenes/lab4.ron, the whole course lab).
    RunScene(RunSceneArgs),
    /// Time against error for every method and knob on the shared workloads
    /// (writes docs/bench/README.md, results.json and plots).
    Bench(bench::BenchArgs),
    /// The numerical stress grid (cloth) and the degenerate IK set (writes
    /// docs/bench/stress.md; exits 1 on NaN, divergence or a broken invariant).
    Stress(stress::StressArgs),
    /// Cost against cloth size on one thread and on every core, with peak memory
    /// (writes docs/bench/scale.md, scale.json and plots/scale.svg; exits 1 when two
    /// thread counts end in different states).
    Scale(scale::ScaleArgs),
    /// The contact workloads' speed goals (C1, C3, C4, C5), each scene run in rounds
    /// (writes docs/bench/goals.md and goals.json).
    Goals(goals::GoalsArgs),
}

#[derive(clap::Args)]
struct RunSceneArgs {
    /// The scene file to run (default: scenes/lab4.ron).
    file: Option<PathBuf>,
    /// Run every scene in scenes/ (not its subfolders).
    #[arg(long, conflicts_with = "file")]
    all: bool,
    /// List the scenes in scenes/ with their descriptions and exit.
    #[arg(long, conflicts_with_all = ["file", "all"])]
    list: bool,
    /// Write outputs here instead of `target/scenes/<scene>/` (with --all: one subfolder per scene).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print the metrics as JSON on stdout instead of the summary table.
    #[arg(long)]
    json: bool,
    /// Print nothing but errors.
    #[arg(long)]
    quiet: bool,
    /// Write no pictures (GIF, PNG, SVG); metrics and CSV files are unchanged.
    #[arg(long)]
    no_render: bool,
}

/// The workspace root, from this crate's manifest directory.
pub fn project_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives one level below the workspace root")
        .to_path_buf()
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::RunScene(args) => run_scene_command(&args),
        Command::Bench(args) => bench::run(&args),
        Command::Stress(args) => stress::run(&args),
        Command::Scale(args) => scale::run(&args),
        Command::Goals(args) => goals::run(&args),
    }
}

fn run_scene_command(args: &RunSceneArgs) -> ExitCode {
    let scenes_dir = project_root().join("scenes");
    if args.list {
        return match scene::list_scenes(&scenes_dir) {
            Ok(list) => {
                for (path, description) in list {
                    let name = path.file_stem().unwrap_or_default().to_string_lossy();
                    println!("{name:<28} {description}");
                }
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("error: {e}");
                ExitCode::from(2)
            }
        };
    }
    let files = if args.all {
        match scene::list_scenes(&scenes_dir) {
            Ok(list) => list.into_iter().map(|(p, _)| p).collect(),
            Err(e) => {
                eprintln!("error: {e}");
                return ExitCode::from(2);
            }
        }
    } else {
        vec![
            args.file
                .clone()
                .unwrap_or_else(|| scenes_dir.join("lab4.ron")),
        ]
    };
    let mut worst = ExitCode::SUCCESS;
    for file in &files {
        let out_dir = match (&args.out, args.all) {
            (Some(out), true) => out.join(scene::scene_name(file)),
            (Some(out), false) => out.clone(),
            (None, _) => project_root()
                .join("target/scenes")
                .join(scene::scene_name(file)),
        };
        let options = report::Options {
            json: args.json,
            quiet: args.quiet,
            render: !args.no_render,
        };
        let code = match Scene::from_file(file) {
            Err(e) => {
                eprintln!("error: {e}");
                ExitCode::from(2)
            }
            Ok(scene) => report::run_and_report(&scene, &out_dir, &options),
        };
        if code != ExitCode::SUCCESS {
            worst = code;
        }
    }
    worst
}
