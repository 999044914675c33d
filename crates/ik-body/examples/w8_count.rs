//! A fixed amount of W8 work for an instruction counter: run with
//! `valgrind --tool=callgrind target/release/examples/w8_count PART [COUNT] [SOLVER] [THREADS]`.
//!
//! PART is `cold` (COUNT goal sets, default 100, solved from the rest pose, as the `body`
//! criterion bench's cold solves), `warm` (COUNT frames of the squat clip, default 600,
//! warm-started) or `batch` (1 000 characters each solving one warm frame, COUNT times,
//! default 1, on THREADS threads, default 1), or `trace` (the 600 clip frames warm, one
//! line per frame: iterations, linearizations, restart, stop, the cost before and after)
//! and `trace-batch` (the batch of 1 000 characters for COUNT frames, default 12, one line
//! per character for the last one: its clip frame, iterations, linearizations), for
//! matching with a per-solve callgrind dump (`--dump-after='*BodySolver>::solve'`).
//! SOLVER is a body solver name (default
//! `fabrik`; the batch always runs the default options, `dls`). With
//! a fixed amount of work, the instructions counted divided by COUNT are the cost of one
//! solve, a figure that does not depend on the load of the machine the way a clock does.
//! With the environment variable `W8_DIGEST` set it also prints a digest of the bits of
//! every answer, to check that a change returns the same bits.

use sinew_ik_body::workload::{self, CLIP_FRAMES};
use sinew_ik_body::{
    BodyBatch, BodyEffector, BodyProblem, BodyReport, BodySolver, BodySolverOptions, BodyState,
    TreeFabrikOptions, TreeFabrikSolver,
};
use sinew_skeleton::ik::SolveSettings;
use std::hint::black_box;

fn main() {
    let mut args = std::env::args().skip(1);
    let part = args.next().unwrap_or_else(|| "cold".into());
    let count: Option<usize> = args.next().map(|s| s.parse().expect("a count"));
    let name = args.next().unwrap_or_else(|| "fabrik".into());
    let threads: usize = args
        .next()
        .map_or(1, |s| s.parse().expect("a thread count"));
    let skel = workload::humanoid().expect("valid");
    let settings = SolveSettings::default();
    let rest = BodyState::rest(&skel);
    let mut solver = BodySolverOptions::by_name(&name)
        .and_then(|o| o.build())
        .expect("a body solver name");
    let frames: Vec<[BodyEffector; 5]> = (0..CLIP_FRAMES)
        .map(|f| workload::clip_frame(&rest.global, f))
        .collect();
    let mut within = 0;
    let mut restarts = 0;
    // With `W8_DIGEST` set, a digest of every answer's bits (pose and translation), so
    // that two builds can be told to return the same bits or not (off by default, so that
    // it does not count in the instructions).
    let digesting = std::env::var_os("W8_DIGEST").is_some();
    let mut digest = 0xcbf2_9ce4_8422_2325_u64;
    let mut absorb = |state: &BodyState| {
        if !digesting {
            return;
        }
        let words = state
            .pose
            .rotations
            .iter()
            .flat_map(|q| q.to_array())
            .chain(state.root_translation.to_array());
        for w in words {
            digest = (digest ^ w.to_bits()).wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    let mut histogram = vec![0usize; settings.max_iterations + 1];
    let mut count_report = |report: &BodyReport| {
        restarts += usize::from(report.restarted);
        histogram[report.iterations.min(settings.max_iterations)] += 1;
    };
    let total;
    match part.as_str() {
        "cold" => {
            total = count.unwrap_or(100);
            let sets = workload::goal_sets(&skel, total, 8, false);
            let mut state = rest.clone();
            for set in &sets {
                state.copy_pose_from(&rest.pose, rest.root_translation);
                let problem =
                    BodyProblem::new(&skel, &set.effectors, settings).with_root_translation(true);
                let report = solver.solve(&problem, &mut state).expect("valid");
                within += usize::from(report.within(&settings));
                count_report(&report);
                absorb(&state);
                black_box(report);
            }
        }
        "warm" => {
            total = count.unwrap_or(CLIP_FRAMES);
            let mut state = rest.clone();
            for f in 0..total {
                let problem = BodyProblem::new(&skel, &frames[f % CLIP_FRAMES], settings)
                    .with_root_translation(true);
                let report = solver.solve(&problem, &mut state).expect("valid");
                within += usize::from(report.within(&settings));
                count_report(&report);
                absorb(&state);
                black_box(report);
            }
        }
        "batch" => {
            total = count.unwrap_or(1);
            let characters = 1000;
            let mut states = vec![rest.clone(); characters];
            let empty = BodyReport::UNSOLVED;
            let mut reports = vec![empty; characters];
            let mut batch = BodyBatch::new(TreeFabrikOptions::default()).expect("valid");
            for step in 0..total {
                let problems = workload::batch_problems(&skel, &frames, settings, characters, step);
                batch
                    .solve(&problems, &mut states, &mut reports, threads)
                    .expect("valid");
                within += reports.iter().filter(|r| r.within(&settings)).count();
            }
            states.iter().for_each(&mut absorb);
        }
        "trace" => {
            total = CLIP_FRAMES;
            let mut state = rest.clone();
            let mut solver = TreeFabrikSolver::new();
            println!("frame iterations linearizations restarted stop initial_cost cost");
            for (f, effectors) in frames.iter().enumerate() {
                let problem =
                    BodyProblem::new(&skel, effectors, settings).with_root_translation(true);
                let before = solver.linearizations();
                let report = solver.solve(&problem, &mut state).expect("valid");
                within += usize::from(report.within(&settings));
                count_report(&report);
                println!(
                    "{f} {} {} {} {} {:.3e} {:.3e}",
                    report.iterations,
                    solver.linearizations() - before,
                    u8::from(report.restarted),
                    report.stop.name(),
                    report.initial_cost,
                    report.cost
                );
            }
        }
        "trace-batch" => {
            let steps = count.unwrap_or(12);
            total = 1000;
            let mut states = vec![rest.clone(); total];
            let mut solvers = vec![TreeFabrikSolver::new(); total];
            let mut reports = vec![BodyReport::UNSOLVED; total];
            let mut lins = vec![0; total];
            for step in 0..steps {
                let problems = workload::batch_problems(&skel, &frames, settings, total, step);
                for c in 0..total {
                    let before = solvers[c].linearizations();
                    reports[c] = solvers[c]
                        .solve(&problems[c], &mut states[c])
                        .expect("valid");
                    lins[c] = solvers[c].linearizations() - before;
                }
            }
            println!("character frame iterations linearizations restarted");
            for c in 0..total {
                within += usize::from(reports[c].within(&settings));
                count_report(&reports[c]);
                println!(
                    "{c} {} {} {} {}",
                    (c * 7 + steps - 1) % CLIP_FRAMES,
                    reports[c].iterations,
                    lins[c],
                    u8::from(reports[c].restarted)
                );
            }
        }
        other => panic!("unknown part {other}: cold, warm, batch, trace or trace-batch"),
    }
    if digesting {
        println!("{part} {name}: {within} within of {total}; digest of the answers {digest:016x}");
    } else {
        println!("{part} {name}: {within} within of {total}");
    }
    let solves: usize = histogram.iter().sum();
    if solves > 0 {
        let iterations: usize = histogram.iter().enumerate().map(|(i, n)| i * n).sum();
        println!(
            "iterations per solve: mean {:.2}, restarts {restarts}",
            iterations as f64 / solves as f64
        );
        for (i, n) in histogram.iter().enumerate().filter(|(_, n)| **n > 0) {
            println!("  {i:3} iterations: {n}");
        }
    }
}
