//! Time against error for CCD over iteration caps, on W1 (flower tracking) and W2
//! (random cold solves): mean and max error, share within 1e-6, iterations and median
//! time, for plain CCD and the over-relaxed variant.
//!
//! Run with `cargo bench -p sinew-ik-ccd --bench ccd_table [-- variant...]` (variants:
//! `plain`, `extrapolated`, or an over-relaxation factor such as `1.5`). Results are
//! copied into `docs/bench/ik-ccd.md`. `cargo xtask bench` measures the same caps for
//! plain and extrapolated CCD on W1 and W2, but not over-relaxation, caps above 100 or
//! the 10 000-bone chain, which is why this table stays.

mod common;

use sinew_ik_ccd::CcdSolver;
use sinew_math::DVec3;
use sinew_skeleton::ik::{Chain, IkSolver, SolveSettings};
use sinew_skeleton::{GlobalPose, Skeleton};
use std::time::Instant;

const TOLERANCE: f64 = 1e-6;

struct Row {
    errors: Vec<f64>,
    iterations: usize,
    /// Per frame or per solve, nanoseconds, over every repetition.
    times: Vec<f64>,
    /// Indices of frames (or reachable solves) that missed the tolerance.
    missed: Vec<usize>,
    considered: usize,
}

fn run(
    solver: &mut CcdSolver,
    skeleton: &Skeleton,
    targets: &[DVec3],
    cap: usize,
    warm: bool,
    reps: usize,
) -> Row {
    let chain = Chain::whole(skeleton).expect("chain");
    let settings = SolveSettings {
        max_iterations: cap,
        tolerance: TOLERANCE,
        ..Default::default()
    };
    let base = skeleton.offset(0);
    let mut row = Row {
        errors: Vec::new(),
        iterations: 0,
        times: Vec::with_capacity(reps * targets.len()),
        missed: Vec::new(),
        considered: 0,
    };
    let mut global = GlobalPose::new();
    for rep in 0..reps {
        let mut pose = skeleton.rest_pose();
        for (i, &target) in targets.iter().enumerate() {
            if !warm {
                pose.rotations.fill(sinew_math::DQuat::IDENTITY);
            }
            let start = Instant::now();
            let report = solver
                .solve_position(skeleton, &chain, &mut pose, &mut global, target, &settings)
                .expect("solve");
            row.times.push(start.elapsed().as_nanos() as f64);
            if rep == 0 {
                // W2 reports the reachable targets on their own; W1 is all reachable.
                let reachable = target.distance(base) < chain.reach();
                if reachable {
                    row.considered += 1;
                    row.errors.push(report.error);
                    row.iterations += report.iterations;
                    if report.error > TOLERANCE {
                        row.missed.push(i);
                    }
                }
            }
        }
    }
    row
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn table(name: &str, skeleton: &Skeleton, targets: &[DVec3], warm: bool, variants: &[String]) {
    println!("\n## {name}\n");
    println!(
        "| variant | cap | mean error | max error | within 1e-6 | iterations (total) | median time (us) | mean time (us) |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for variant in variants {
        // "plain", "extrapolated", or "relaxed:<omega>".
        let mut solver = match variant.as_str() {
            "plain" => CcdSolver::plain(),
            "extrapolated" => CcdSolver::plain().with_extrapolation(true),
            other => {
                let omega = other.trim_start_matches("relaxed:").parse().expect("omega");
                CcdSolver::with_relaxation(omega).expect("omega")
            }
        };
        let omega = variant;
        for cap in [1usize, 2, 4, 8, 16, 32, 100, 200, 400, 1000, 10_000] {
            let reps = if targets.len() > 1000 { 1 } else { 5 };
            let mut row = run(&mut solver, skeleton, targets, cap, warm, reps);
            let mean = row.errors.iter().sum::<f64>() / row.errors.len() as f64;
            let max = row.errors.iter().copied().fold(0.0, f64::max);
            let mean_time = row.times.iter().sum::<f64>() / row.times.len() as f64;
            let med = median(&mut row.times);
            println!(
                "| {omega} | {cap} | {mean:.3e} | {max:.3e} | {}/{} ({:.1}%) | {} | {:.2} | {:.2} |",
                row.considered - row.missed.len(),
                row.considered,
                100.0 * (row.considered - row.missed.len()) as f64 / row.considered as f64,
                row.iterations,
                med / 1e3,
                mean_time / 1e3,
            );
            if cap == 100 && !row.missed.is_empty() && row.missed.len() <= 100 {
                println!("<!-- omega {omega} cap 100 misses: {:?} -->", row.missed);
            }
        }
    }
}

/// The 10 000-bone chain tracking the flower scaled to its reach, 12 frames: per-frame
/// time, error and sweeps.
fn long_chain() {
    println!("\n## 10 000-bone chain, flower scaled to the reach, 12 frames (default solver)\n");
    println!("| frame | error | sweeps | stop | time (ms) |");
    println!("|---|---|---|---|---|");
    let skeleton = common::long_skeleton(10_000, 1.05);
    let chain = Chain::whole(&skeleton).expect("chain");
    let mut solver = CcdSolver::new();
    let mut pose = skeleton.rest_pose();
    let mut global = GlobalPose::new();
    for (i, &target) in common::scaled_flower(1.05, 12).iter().enumerate() {
        let start = Instant::now();
        let report = solver
            .solve_position(
                &skeleton,
                &chain,
                &mut pose,
                &mut global,
                target,
                &SolveSettings::default(),
            )
            .expect("solve");
        let ms = start.elapsed().as_secs_f64() * 1e3;
        println!(
            "| {i} | {:.3e} | {} | {} | {ms:.1} |",
            report.error, report.iterations, report.stop
        );
    }
}

const NAME: &str = "ccd_table";
const RUN: &str = "-p sinew-ik-ccd --bench ccd_table";

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --benches` does not, and this table
    // takes minutes, so a test run only says how to run it.
    let args: Vec<String> = std::env::args().skip(1).collect();
    if !args.iter().any(|a| a == "--bench") {
        eprintln!("{NAME}: a measurement, not a test; run it with `cargo bench {RUN}`");
        return;
    }
    let mut variants: Vec<String> = args.into_iter().filter(|a| !a.starts_with("--")).collect();
    if variants.is_empty() {
        variants = vec!["plain".into(), "extrapolated".into()];
    }
    table(
        "W1 flower tracking (per frame, 500 frames, warm start)",
        &common::w1_skeleton(),
        &common::w1_targets(),
        true,
        &variants,
    );
    table(
        "W2 random cold solves (reachable targets; time over all 10 000)",
        &common::w2_skeleton(),
        &common::w2_targets(10_000),
        false,
        &variants,
    );
    long_chain();
}
