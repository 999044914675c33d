//! The direct solver's reuse of its last factor as a preconditioner
//! (`NewtonSettings::factor_reuse_iterations`): steps taken with it converge to the
//! states of steps that factor every Newton matrix, within the Newton tolerance, with
//! fewer factorizations; and two identical runs make the same decisions and give
//! bitwise the same states.

use sinew_spring_sim::*;

/// A long step, so each takes several Newton iterations.
const H: f64 = 0.1;

/// A 15 x 15 lab-pattern cloth hanging from two corners, falling from rest for 20
/// steps of 1/60 s on the direct solve with the given reuse budget: the positions after
/// every step and the reports.
fn run(reuse: usize) -> (Vec<Vec<DVec3>>, Vec<StepReport>) {
    let system = ClothGrid::lab_sized(15, 0.1)
        .with_damping(0.2)
        .build()
        .unwrap();
    let settings = NewtonSettings {
        linear_solver: LinearSolverChoice::Direct,
        tolerance: 1e-10,
        factor_reuse_iterations: reuse,
        ..NewtonSettings::default()
    };
    let mut sim = Simulation::new(system, Integrator::BackwardEuler(settings)).unwrap();
    let mut states = Vec::new();
    let mut reports = Vec::new();
    for _ in 0..20 {
        let report = sim.step(H).unwrap();
        assert_eq!(report.stop, StepStop::Converged, "{report:?}");
        reports.push(report);
        states.push(sim.system().positions().to_vec());
    }
    (states, reports)
}

#[test]
fn reuse_converges_to_the_states_of_a_factorization_every_iteration() {
    let (exact, exact_reports) = run(0);
    let (reused, reused_reports) = run(8);
    let total = |reports: &[StepReport], f: fn(&StepReport) -> usize| -> usize {
        reports.iter().map(f).sum()
    };
    // Without reuse every Newton iteration factors once (the hanging cloth's matrices
    // are positive definite) and nothing is preconditioned.
    assert_eq!(
        total(&exact_reports, |r| r.factorizations),
        total(&exact_reports, |r| r.iterations)
    );
    assert_eq!(total(&exact_reports, |r| r.kept_factor_solves), 0);
    assert_eq!(total(&exact_reports, |r| r.kept_factor_iterations), 0);
    // With it the factor does most of the work: at most one factorization per step
    // plus the Newton iterations not answered by the kept factor.
    let solves = total(&reused_reports, |r| r.kept_factor_solves);
    assert!(solves > 0);
    assert!(total(&reused_reports, |r| r.kept_factor_iterations) >= solves);
    for r in &reused_reports {
        assert_eq!(
            r.factorizations + r.kept_factor_solves,
            r.iterations,
            "{r:?}"
        );
    }
    assert!(
        total(&reused_reports, |r| r.factorizations) < total(&exact_reports, |r| r.factorizations)
    );
    // The same states within the Newton tolerance: `|grad g|_inf <= tol m/h^2` bounds
    // each step's position error by about `tol` (here 1e-10 m), and 20 steps of a
    // damped sheet do not amplify it beyond a few hundred times.
    let mut largest = 0.0f64;
    for (a, b) in exact.iter().zip(&reused) {
        for (p, q) in a.iter().zip(b) {
            largest = largest.max((*p - *q).abs().max_element());
        }
    }
    eprintln!(
        "TMP exact {} reused {} solves {} kit {} largest {largest:e}",
        total(&exact_reports, |r| r.factorizations),
        total(&reused_reports, |r| r.factorizations),
        solves,
        total(&reused_reports, |r| r.kept_factor_iterations)
    );
    assert!(largest <= 1e-7, "largest difference {largest:e} m");
}

#[test]
fn reuse_decisions_and_states_are_the_same_run_after_run() {
    let (first, first_reports) = run(8);
    let (second, second_reports) = run(8);
    assert_eq!(first_reports, second_reports);
    for (a, b) in first.iter().zip(&second) {
        for (p, q) in a.iter().zip(b) {
            assert_eq!(
                [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()],
                [q.x.to_bits(), q.y.to_bits(), q.z.to_bits()]
            );
        }
    }
}
