//! The full-body workload (W8) measured: run with
//! `cargo run --release -p sinew-ik-body --example w8 [-- GOAL_SETS [SOLVER]]`.
//!
//! Prints, for the 22-joint humanoid with five effectors and the hips free to translate:
//! the fraction of goal sets (made by forward kinematics of random limit-respecting poses,
//! so feasible) solved cold from the rest pose with every effector within 1e-6 and no limit
//! violated by more than 1e-12 rad, and the median time per cold solve; the same with
//! rotation goals on the wrists; the 600-frame squat clip warm-started (median time per
//! frame, frames within tolerance, worst pinned-foot drift, the largest joint rotation
//! change between frames, frames that restarted); and 1 000 characters each
//! solving one warm frame through the batch API on one and on two threads (median time per
//! batch, and whether the answers agree to the bit).

use sinew_ik_body::workload::{self, CLIP_FRAMES, EFFECTORS};
use sinew_ik_body::{
    BodyBatch, BodyProblem, BodyReport, BodySolverOptions, BodyState, TreeFabrikOptions,
};
use sinew_skeleton::Skeleton;
use sinew_skeleton::ik::{SolveSettings, largest_rotation_change};
use std::collections::BTreeMap;
use std::time::Instant;

fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    if xs.is_empty() {
        return f64::NAN;
    }
    xs[xs.len() / 2]
}

fn percentile(mut xs: Vec<f64>, p: f64) -> f64 {
    xs.sort_by(f64::total_cmp);
    if xs.is_empty() {
        return f64::NAN;
    }
    xs[((xs.len() - 1) as f64 * p).round() as usize]
}

fn cold(skeleton: &Skeleton, solver_name: &str, count: usize, rotations: bool) {
    let settings = SolveSettings::default();
    let sets = workload::goal_sets(skeleton, count, 8, rotations);
    let mut solver = BodySolverOptions::by_name(solver_name)
        .and_then(|o| o.build())
        .expect("named solver");
    let rest = BodyState::rest(skeleton);
    let mut state = rest.clone();
    let mut times = Vec::with_capacity(count);
    let mut iterations = Vec::with_capacity(count);
    let mut ok = 0;
    let mut restarted = 0;
    let mut worst_violation: f64 = 0.0;
    let mut stops: BTreeMap<&str, usize> = BTreeMap::new();
    let mut errors = Vec::with_capacity(count);
    for set in &sets {
        state.copy_pose_from(&rest.pose, rest.root_translation);
        let problem =
            BodyProblem::new(skeleton, &set.effectors, settings).with_root_translation(true);
        let start = Instant::now();
        let report = solver.solve(&problem, &mut state).expect("valid workload");
        times.push(start.elapsed().as_secs_f64() * 1e6);
        iterations.push(report.iterations as f64);
        errors.push(report.max_error);
        worst_violation = worst_violation.max(report.limit_violation);
        restarted += usize::from(report.restarted);
        *stops.entry(report.stop.name()).or_default() += 1;
        if report.within(&settings) && report.limit_violation <= 1e-12 {
            ok += 1;
        }
    }
    println!(
        "cold {solver_name}{}: {ok}/{count} = {:.2}% within 1e-6 and limits; median {:.2} us, p90 {:.2} us per solve; median {} iterations; {restarted} restarts; worst limit violation {:.1e}; stops {stops:?}; p99 error {:.2e}",
        if rotations {
            " (wrist rotation goals)"
        } else {
            ""
        },
        100.0 * ok as f64 / count as f64,
        median(times.clone()),
        percentile(times, 0.9),
        median(iterations),
        worst_violation,
        percentile(errors, 0.99),
    );
}

fn clip(skeleton: &Skeleton, solver_name: &str) {
    let settings = SolveSettings::default();
    let mut solver = BodySolverOptions::by_name(solver_name)
        .and_then(|o| o.build())
        .expect("named solver");
    let mut state = BodyState::rest(skeleton);
    let rest = state.global.clone();
    let mut times = Vec::with_capacity(CLIP_FRAMES);
    let mut within = 0;
    let mut worst: f64 = 0.0;
    let mut drift: f64 = 0.0;
    let mut violation: f64 = 0.0;
    let mut jump: f64 = 0.0;
    let mut restarts = 0;
    let joints: Vec<usize> = (0..skeleton.len()).collect();
    let mut previous = state.pose.clone();
    for frame in 0..CLIP_FRAMES {
        let effectors = workload::clip_frame(&rest, frame);
        let problem = BodyProblem::new(skeleton, &effectors, settings).with_root_translation(true);
        let start = Instant::now();
        let report: BodyReport = solver.solve(&problem, &mut state).expect("valid workload");
        times.push(start.elapsed().as_secs_f64() * 1e6);
        within += usize::from(report.within(&settings));
        worst = worst.max(report.max_error);
        violation = violation.max(report.limit_violation);
        restarts += usize::from(report.restarted);
        if frame > 0 {
            jump = jump.max(largest_rotation_change(&previous, &state.pose, &joints));
        }
        previous.rotations.copy_from_slice(&state.pose.rotations);
        for k in [2, 3] {
            drift = drift
                .max(state.global.positions[EFFECTORS[k]].distance(rest.positions[EFFECTORS[k]]));
        }
    }
    println!(
        "clip {solver_name}: {within}/{CLIP_FRAMES} frames within 1e-6; median {:.2} us, p90 {:.2} us per warm frame; worst effector error {worst:.2e}; worst ankle drift {drift:.2e}; worst limit violation {violation:.1e}; largest joint rotation change between frames {jump:.3} rad; {restarts} frames restarted",
        median(times.clone()),
        percentile(times, 0.9),
    );
}

fn batch(skeleton: &Skeleton) {
    let settings = SolveSettings::default();
    let characters = 1000;
    let rest = BodyState::rest(skeleton);
    let rest_global = rest.global.clone();
    let empty = BodyReport::UNSOLVED;
    // The same batches on one and on two threads, taken in turn (so a change in the
    // machine's load touches both alike), each with its own solvers and states; their
    // answers must agree to the bit.
    let thread_counts = [1, 2];
    let mut states = vec![vec![rest.clone(); characters]; thread_counts.len()];
    let mut reports = vec![vec![empty; characters]; thread_counts.len()];
    let mut batches: Vec<BodyBatch> = thread_counts
        .iter()
        .map(|_| BodyBatch::new(TreeFabrikOptions::default()).expect("default options"))
        .collect();
    // Each character is at its own frame of the clip, so the batch is not 1 000 copies of
    // one solve; every character warm-starts from its previous frame.
    let frames: Vec<[sinew_ik_body::BodyEffector; 5]> = (0..CLIP_FRAMES)
        .map(|f| workload::clip_frame(&rest_global, f))
        .collect();
    let mut times = vec![Vec::new(); thread_counts.len()];
    let mut within = 0;
    let mut solved = 0;
    let mut identical = true;
    for step in 0..20 {
        let problems = workload::batch_problems(skeleton, &frames, settings, characters, step);
        for (k, &threads) in thread_counts.iter().enumerate() {
            let start = Instant::now();
            batches[k]
                .solve(&problems, &mut states[k], &mut reports[k], threads)
                .expect("valid workload");
            let elapsed = start.elapsed().as_secs_f64() * 1e3;
            // The first two steps warm the buffers and bring every character onto its
            // clip.
            if step >= 2 {
                times[k].push(elapsed);
            }
        }
        identical &= states[0] == states[1] && reports[0] == reports[1];
        if step >= 2 {
            within += reports[0].iter().filter(|r| r.within(&settings)).count();
            solved += characters;
        }
    }
    let [one, two] = [0, 1].map(|k| median(times[k].clone()));
    println!(
        "batch: 1000 characters, one warm frame each: median {one:.2} ms per batch on one thread, {two:.2} ms on two (ratio {:.2}); {within} of {solved} solves within 1e-6; answers on one and two threads {}",
        one / two,
        if identical { "identical" } else { "DIFFERENT" }
    );
}

/// What a batch's threads cost: two characters already at their goals (each solve is the
/// validation and the early exit), solved as one batch on one thread and on two, many
/// times; the difference of the medians is the spawn and join of one scoped thread.
fn spawn_cost(skeleton: &Skeleton) {
    let settings = SolveSettings::default();
    let rest = BodyState::rest(skeleton);
    let effectors = workload::clip_frame(&rest.global, 0);
    let problems =
        vec![BodyProblem::new(skeleton, &effectors, settings).with_root_translation(true); 2];
    let empty = BodyReport::UNSOLVED;
    let mut medians = [0.0; 2];
    for (k, threads) in [1, 2].into_iter().enumerate() {
        let mut batch = BodyBatch::new(TreeFabrikOptions::default()).expect("default options");
        let mut states = vec![rest.clone(); 2];
        let mut reports = vec![empty; 2];
        let mut times = Vec::with_capacity(2000);
        for _ in 0..2000 {
            let start = Instant::now();
            batch
                .solve(&problems, &mut states, &mut reports, threads)
                .expect("valid workload");
            times.push(start.elapsed().as_secs_f64() * 1e6);
        }
        medians[k] = median(times);
    }
    println!(
        "threads: a batch of two characters already at their goals: median {:.2} us on one thread, {:.2} us on two (one scoped thread spawned and joined: {:.2} us)",
        medians[0],
        medians[1],
        medians[1] - medians[0]
    );
}

fn main() {
    let mut args = std::env::args().skip(1);
    let count: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(10_000);
    let solver = args.next().unwrap_or_else(|| "dls".into());
    let skeleton = workload::humanoid().expect("the humanoid is valid");
    cold(&skeleton, &solver, count, false);
    cold(&skeleton, &solver, count, true);
    clip(&skeleton, &solver);
    if solver == "dls" {
        batch(&skeleton);
        spawn_cost(&skeleton);
    }
}
