//! One benchmark row's IK solves alone, for instruction counts that do not depend on the
//! load of a shared machine:
//!
//! ```sh
//! cargo build --release -p sinew-bench --example ik_count
//! valgrind --tool=callgrind --toggle-collect='*ik_count*solve_all*' \
//!     target/release/examples/ik_count w1 ccd 100 1e-6
//! ```
//!
//! Arguments: the workload (`w1`: the 500 flower frames warm-started, as the benchmark
//! tracks them; `w2`: the 10 000 seeded targets, each from the rest pose), a solver of
//! `SolverOptions::NAMED`, the iteration cap and the tolerance. Prints the iterations and
//! the sum of the final errors, so two builds can be checked to solve the same problems.
use sinew_bench::seeded::w2_targets;
use sinew_ik::SolverOptions;
use sinew_math::{DQuat, DVec3};
use sinew_scene::workloads::{w1_skeleton, w1_targets, w2_skeleton};
use sinew_skeleton::ik::{Chain, SolveSettings};
use sinew_skeleton::{GlobalPose, Skeleton};

/// Solves every target in order; returns the iterations and the sum of the errors.
#[inline(never)]
fn solve_all(
    name: &str,
    skeleton: &Skeleton,
    targets: &[DVec3],
    warm: bool,
    settings: &SolveSettings,
) -> Result<(usize, f64), String> {
    let chain = Chain::whole(skeleton).map_err(|e| e.to_string())?;
    let options = SolverOptions::NAMED
        .iter()
        .find(|(n, _)| *n == name)
        .ok_or_else(|| format!("no solver named {name:?}"))?
        .1;
    let mut solver = options.build().map_err(|e| e.to_string())?;
    let mut pose = skeleton.rest_pose();
    let mut global = GlobalPose::new();
    let (mut iterations, mut error_sum) = (0, 0.0);
    for &target in targets {
        if !warm {
            pose.rotations.fill(DQuat::IDENTITY);
        }
        let report = solver
            .solve_position(skeleton, &chain, &mut pose, &mut global, target, settings)
            .map_err(|e| e.to_string())?;
        iterations += report.iterations;
        error_sum += report.error;
    }
    Ok((iterations, error_sum))
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [workload, name, cap, tolerance] = args.as_slice() else {
        return Err("usage: ik_count <w1|w2> <solver> <cap> <tolerance>".into());
    };
    let settings = SolveSettings {
        max_iterations: cap.parse().map_err(|e| format!("cap: {e}"))?,
        tolerance: tolerance.parse().map_err(|e| format!("tolerance: {e}"))?,
        ..Default::default()
    };
    let (iterations, error_sum) = match workload.as_str() {
        "w1" => solve_all(name, &w1_skeleton()?, &w1_targets(500), true, &settings)?,
        "w2" => solve_all(name, &w2_skeleton()?, &w2_targets(10_000), false, &settings)?,
        other => return Err(format!("unknown workload {other:?}: expected w1 or w2")),
    };
    println!(
        "{workload} {name} cap {cap} tol {tolerance}: iterations {iterations}, error sum {error_sum:.6e}"
    );
    Ok(())
}
