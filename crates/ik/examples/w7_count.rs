//! A fixed amount of W7 work for an instruction counter: run with
//! `valgrind --tool=callgrind target/release/examples/w7_count SOLVER [SOLVES]`.
//!
//! Solves SOLVES (default 200) cold W7 problems (the human arm with joint limits: forward
//! kinematics of the hand tip for poses uniform in the limits, from the rest pose, cap
//! 100, tolerance 1e-6) with the named registry solver, the same cycle of targets as the
//! `w7` criterion bench, and prints how many ended within the tolerance. With a fixed
//! count of solves, the instructions counted divided by SOLVES is the cost of one solve,
//! a figure that does not depend on the load of the machine the way a clock does.
//!
//! It also prints how the solves spent their iterations: the histogram of
//! `SolveReport::iterations` (for FABRIK one pass plus the finish's trials, both seeds'
//! when it restarted), the number of restarts and the largest limit violation.

use sinew_ik::SolverOptions;
use sinew_ik::workloads::{allowed_pose, human_arm};
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::GlobalPose;
use sinew_skeleton::ik::{Chain, SolveSettings};
use std::hint::black_box;

/// splitmix64 with the workloads' W7 seed (as in the bench).
struct SplitMix64(u64);

impl SplitMix64 {
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let name = args.next().unwrap_or_else(|| "fabrik".into());
    let solves: usize = args.next().map_or(200, |s| s.parse().expect("a count"));
    let options = SolverOptions::by_name(&name).expect("a registry solver name");
    let skeleton = human_arm().expect("the W7 arm");
    let chain = Chain::whole(&skeleton).expect("a chain");
    let mut rng = SplitMix64(0x5EED_0000_0000_0007);
    let mut global = GlobalPose::new();
    let targets: Vec<DVec3> = (0..solves)
        .map(|_| {
            let pose = allowed_pose(&skeleton, || rng.unit());
            skeleton
                .forward_kinematics(&pose, &mut global)
                .expect("valid");
            global.positions[4]
        })
        .collect();
    let settings = SolveSettings::default();
    let mut solver = options.build().expect("valid");
    let mut pose = skeleton.rest_pose();
    let mut within = 0;
    let mut restarts = 0;
    let mut violation: f64 = 0.0;
    let mut histogram = vec![0usize; settings.max_iterations + 1];
    for &target in &targets {
        pose.rotations.fill(DQuat::IDENTITY);
        let report = solver
            .solve_position(&skeleton, &chain, &mut pose, &mut global, target, &settings)
            .expect("valid workload");
        within += usize::from(report.error <= settings.tolerance);
        restarts += usize::from(report.restarted);
        violation = violation.max(report.limit_violation);
        histogram[report.iterations.min(settings.max_iterations)] += 1;
        black_box(report);
    }
    println!("{name}: {within} of {solves} within {}", settings.tolerance);
    let total: usize = histogram.iter().enumerate().map(|(i, n)| i * n).sum();
    println!(
        "iterations per solve: mean {:.2}, restarts {restarts}, largest limit violation {violation:.3e} rad",
        total as f64 / solves as f64
    );
    for (iterations, n) in histogram.iter().enumerate().filter(|(_, n)| **n > 0) {
        println!("  {iterations:3} iterations: {n}");
    }
}
