//! Prints the time-against-error table of `docs/bench/ik-fabrik.md`: W1 (flower tracking,
//! warm-started) and W2 (10 000 cold solves) for plain FABRIK and the hybrid, over
//! iteration caps 1, 2, 4, 8, 16, 32 and 100.
//!
//! Run with `cargo bench -p sinew-ik-fabrik --bench fabrik_table [-- --ratios]`
//! (`--ratios`: the sweep over the hybrid's switch ratio instead). `cargo xtask bench`
//! measures the same caps on W1 and W2, but not the CPU times, the split between passes
//! and least-squares steps, or the ratio sweep, which is why this table stays. Times are the
//! median over repeated runs of (run time / frames or solves), so they are the mean time
//! per frame or solve of a typical run.

#[path = "../tests/common/mod.rs"]
mod common;

use common::{flower_targets, w1_skeleton, w2_skeleton, w2_targets, whole};
use sinew_ik_fabrik::{FabrikMode, FabrikOptions, FabrikSolver};
use sinew_math::DVec3;
use sinew_skeleton::ik::{Chain, IkSolver, SolveSettings};
use sinew_skeleton::{GlobalPose, Skeleton};
use std::time::Instant;

const CAPS: [usize; 7] = [1, 2, 4, 8, 16, 32, 100];
const TOLERANCE: f64 = 1e-6;

/// One workload run: per-target error and iterations, and its wall time.
struct Run {
    errors: Vec<f64>,
    iterations: usize,
    passes: usize,
    steps: usize,
    seconds: f64,
    /// CPU time of this thread during the run (Linux), which leaves out the time other
    /// processes held the core: the machine is shared.
    cpu_seconds: Option<f64>,
}

/// This thread's CPU time in seconds, from `/proc/thread-self/schedstat` (Linux only).
fn thread_cpu_seconds() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: f64 = text.split_whitespace().next()?.parse().ok()?;
    Some(ns * 1e-9)
}

fn track(
    skel: &Skeleton,
    chain: &Chain,
    targets: &[DVec3],
    solver: &mut FabrikSolver,
    settings: &SolveSettings,
    cold: bool,
    laps: usize,
) -> Run {
    let rest = skel.rest_pose();
    let mut pose = rest.clone();
    let mut global = GlobalPose::new();
    let mut errors = Vec::with_capacity(targets.len());
    let (mut iterations, mut passes, mut steps) = (0, 0, 0);
    let cpu_start = thread_cpu_seconds();
    let start = Instant::now();
    for lap in 0..laps {
        for &t in targets {
            if cold {
                pose.rotations.copy_from_slice(&rest.rotations);
            }
            let report = solver
                .solve_position(skel, chain, &mut pose, &mut global, t, settings)
                .expect("valid workload");
            if lap == 0 {
                errors.push(report.error);
                iterations += report.iterations;
                passes += solver.last_stats().passes;
                steps += solver.last_stats().refinement_steps;
            }
        }
    }
    Run {
        errors,
        iterations,
        passes,
        steps,
        seconds: start.elapsed().as_secs_f64() / laps as f64,
        cpu_seconds: thread_cpu_seconds()
            .zip(cpu_start)
            .map(|(b, a)| (b - a) / laps as f64),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

const NAME: &str = "fabrik_table";
const RUN: &str = "-p sinew-ik-fabrik --bench fabrik_table";

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --benches` does not, and this table
    // takes minutes, so a test run only says how to run it.
    let args: Vec<String> = std::env::args().skip(1).collect();
    if !args.iter().any(|a| a == "--bench") {
        eprintln!("{NAME}: a measurement, not a test; run it with `cargo bench {RUN}`");
        return;
    }
    if args.iter().any(|a| a == "--ratios") {
        ratio_sweep();
        return;
    }
    let w1 = w1_skeleton();
    let w1_chain = whole(&w1);
    let flower = flower_targets(500);
    let w2 = w2_skeleton();
    let w2_chain = whole(&w2);
    let random = w2_targets(10_000);
    let reachable: Vec<bool> = random
        .iter()
        .map(|t| t.length() < w2_chain.reach())
        .collect();
    let n_reachable = reachable.iter().filter(|&&r| r).count();
    println!(
        "W2: {} targets, {} reachable ({:.1}%)",
        random.len(),
        n_reachable,
        100.0 * n_reachable as f64 / random.len() as f64
    );
    println!(
        "| workload | mode | cap | mean error | max error | within 1e-6 | mean iterations (passes + LM steps) | median wall time | median CPU time |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for (name, skel, chain, targets, cold, repeats, laps) in [
        ("W1", &w1, &w1_chain, &flower, false, 9, 40),
        ("W2", &w2, &w2_chain, &random, true, 5, 1),
    ] {
        for mode in [FabrikMode::Plain, FabrikMode::Hybrid] {
            for cap in CAPS {
                let settings = SolveSettings {
                    max_iterations: cap,
                    tolerance: TOLERANCE,
                    ..Default::default()
                };
                let options = FabrikOptions {
                    mode,
                    ..FabrikOptions::default()
                };
                let mut solver = FabrikSolver::with_options(options).expect("valid options");
                let first = track(skel, chain, targets, &mut solver, &settings, cold, laps);
                let mut times = vec![first.seconds];
                let mut cpu = vec![first.cpu_seconds.unwrap_or(f64::NAN)];
                for _ in 1..repeats {
                    let run = track(skel, chain, targets, &mut solver, &settings, cold, laps);
                    times.push(run.seconds);
                    cpu.push(run.cpu_seconds.unwrap_or(f64::NAN));
                }
                let per = median(times) / targets.len() as f64;
                let cpu_per = median(cpu) / targets.len() as f64;
                // W2 errors are reported over the reachable targets; the unreachable ones
                // are solved in closed form (checked by the tests).
                let considered: Vec<f64> = first
                    .errors
                    .iter()
                    .zip(0..)
                    .filter(|&(_, i)| !cold || reachable[i])
                    .map(|(e, _)| *e)
                    .collect();
                let within = considered.iter().filter(|&&e| e <= TOLERANCE).count();
                let mean = considered.iter().sum::<f64>() / considered.len() as f64;
                let max = considered.iter().copied().fold(0.0, f64::max);
                let count = targets.len() as f64;
                println!(
                    "| {name} | {} | {cap} | {mean:.2e} | {max:.2e} | {within}/{} ({:.1}%) | {:.2} ({:.2} + {:.2}) | {:.2} us | {:.2} us |",
                    mode.name(),
                    considered.len(),
                    100.0 * within as f64 / considered.len() as f64,
                    first.iterations as f64 / count,
                    first.passes as f64 / count,
                    first.steps as f64 / count,
                    per * 1e6,
                    cpu_per * 1e6,
                );
            }
        }
    }
}

/// The hybrid at cap 100 over switch ratios: why the default is what it is.
fn ratio_sweep() {
    let w1 = w1_skeleton();
    let w1_chain = whole(&w1);
    let flower = flower_targets(500);
    let w2 = w2_skeleton();
    let w2_chain = whole(&w2);
    let random = w2_targets(10_000);
    let settings = SolveSettings::default();
    println!(
        "| switch ratio | W1 mean iterations | W1 within | W1 median CPU time | W2 mean iterations | W2 reachable within | W2 median CPU time |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|");
    for ratio in [0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0] {
        let options = FabrikOptions {
            mode: FabrikMode::Hybrid,
            switch_ratio: ratio,
        };
        let mut cells = Vec::new();
        for (skel, chain, targets, cold, repeats, laps) in [
            (&w1, &w1_chain, &flower, false, 9, 40),
            (&w2, &w2_chain, &random, true, 5, 1),
        ] {
            let mut solver = FabrikSolver::with_options(options).expect("valid");
            let first = track(skel, chain, targets, &mut solver, &settings, cold, laps);
            let mut times = vec![first.cpu_seconds.unwrap_or(first.seconds)];
            for _ in 1..repeats {
                let run = track(skel, chain, targets, &mut solver, &settings, cold, laps);
                times.push(run.cpu_seconds.unwrap_or(run.seconds));
            }
            let within = first
                .errors
                .iter()
                .zip(targets.iter())
                .filter(|(e, t)| **e <= TOLERANCE && (!cold || t.length() < chain.reach()))
                .count();
            let considered = targets
                .iter()
                .filter(|t| !cold || t.length() < chain.reach())
                .count();
            cells.push(format!(
                "{:.2} | {within}/{considered} | {:.2} us",
                first.iterations as f64 / targets.len() as f64,
                median(times) / targets.len() as f64 * 1e6
            ));
        }
        println!("| {ratio} | {} | {} |", cells[0], cells[1]);
    }
}
