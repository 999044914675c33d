//! Backward Euler with the self-contact pairs' exact Hessians tried first, from every
//! step's first iteration (`SelfContactSettings::exact_hessian`): on two sheets dropped
//! one onto the other, the matrix with the exact blocks is refused in some iterations
//! (the barrier's negative curvature), the projected blocks are then used at once, and
//! every step still converges, keeps every gap positive, and ends where the projected
//! run ends (both solve the same minimization, to the tolerance).

use crate::sheets;
use sinew_math::DVec3;
use sinew_spring_sim::contact::self_contact::{SelfContactSettings, SelfContactStats};
use sinew_spring_sim::{BackwardEuler, NewtonSettings, SpringSystem, StepStop, TriangleMesh};
use std::sync::Arc;

const H: f64 = 1.0 / 60.0;

/// What a run ends with: the state, and the exact-Hessian statistics (times written,
/// fallbacks), the Newton iterations and the smallest gap over the steps.
struct Outcome {
    system: SpringSystem,
    exact: u64,
    fallbacks: u64,
    iterations: usize,
    smallest_gap: f64,
    /// The steps' reports' count of refused exact matrices.
    reported_fallbacks: usize,
}

/// Two `n x n` sheets 1 cm apart in their grids, the top one 1.6 mm above the bottom one
/// (its axes `u`, `w`), the bottom one held at its four corners, with self-contact
/// (`dhat` 2 mm, thickness 1 mm, `exact_hessian` as given) and `gravity`.
pub(crate) fn sheets_in_contact(
    n: usize,
    axes: (DVec3, DVec3),
    gravity: DVec3,
    exact_hessian: bool,
) -> (BackwardEuler, Arc<SelfContactStats>, SpringSystem) {
    sheets_in_contact_with(n, axes, gravity, exact_hessian, NewtonSettings::default())
}

/// [`sheets_in_contact`] with the integrator's settings `newton`.
pub(crate) fn sheets_in_contact_with(
    n: usize,
    (u, w): (DVec3, DVec3),
    gravity: DVec3,
    exact_hessian: bool,
    newton: NewtonSettings,
) -> (BackwardEuler, Arc<SelfContactStats>, SpringSystem) {
    let s = 0.01;
    let (x, t) = sheets::stacked(n, s, DVec3::new(0.013, 0.0016, 0.011), u, w, s);
    let mesh = TriangleMesh::new(x, t).unwrap();
    let mut cloth = sheets::cloth(vec![0, n - 1, n * (n - 1), n * n - 1]);
    cloth.material.gravity = gravity;
    let model = cloth.build(&mesh).unwrap();
    let mut integrator = model.backward_euler(newton).unwrap();
    let settings = SelfContactSettings {
        dhat: 2e-3,
        thickness: 1e-3,
        exact_hessian,
        ..SelfContactSettings::default()
    };
    let stats = model
        .enable_self_contact(&mut integrator, settings)
        .unwrap();
    (integrator, stats, model.system)
}

/// [`sheets_in_contact`] with the top sheet turned a little, under gravity: it falls onto
/// the held one.
fn turned_sheets_falling(
    n: usize,
    exact_hessian: bool,
) -> (BackwardEuler, Arc<SelfContactStats>, SpringSystem) {
    let turned = (
        DVec3::new(0.995_004, 0.0, 0.099_833_4),
        DVec3::new(-0.099_833_4, 0.0, 0.995_004),
    );
    let gravity = DVec3::new(0.0, -9.81, 0.0);
    sheets_in_contact(n, turned, gravity, exact_hessian)
}

fn run(exact_hessian: bool, n: usize, steps: usize) -> Outcome {
    let (mut integrator, stats, mut system) = turned_sheets_falling(n, exact_hessian);
    let (mut iterations, mut smallest_gap, mut reported_fallbacks) = (0, f64::INFINITY, 0);
    for step in 0..steps {
        let report = integrator.step(&mut system, H).unwrap();
        assert_eq!(report.stop, StepStop::Converged, "step {step}: {report:?}");
        iterations += report.iterations;
        reported_fallbacks += report.contact_projection_fallbacks;
        smallest_gap = smallest_gap.min(stats.min_gap());
    }
    Outcome {
        system,
        exact: stats.exact_hessians(),
        fallbacks: stats.projected_after_exact(),
        iterations,
        smallest_gap,
        reported_fallbacks,
    }
}

#[test]
fn refused_exact_blocks_fall_back_to_the_projection_and_the_steps_converge() {
    let (n, steps) = (9, 12);
    let exact = run(true, n, steps);
    let projected = run(false, n, steps);
    assert!(exact.exact > 0, "the exact blocks were never written");
    assert!(exact.fallbacks > 0, "the fallback never engaged");
    assert_eq!(projected.exact, 0);
    assert_eq!(projected.fallbacks, 0);
    // The step reports show the fallbacks too, and only where the exact blocks were on.
    assert!(exact.reported_fallbacks > 0, "no step reported a fallback");
    assert!(exact.reported_fallbacks as u64 <= exact.fallbacks);
    assert_eq!(projected.reported_fallbacks, 0);
    // Contact happened, and every gap stayed positive.
    assert!(exact.smallest_gap < 2e-3, "{}", exact.smallest_gap);
    assert!(exact.smallest_gap > 0.0, "{}", exact.smallest_gap);
    assert!(projected.smallest_gap > 0.0);
    // The same minimization: the two runs end at the same state to the tolerance.
    let deviation = exact
        .system
        .positions()
        .iter()
        .zip(projected.system.positions())
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0, f64::max);
    assert!(deviation < 1e-6, "{deviation} m");
    eprintln!(
        "iterations: exact {} ({} exact matrices, {} fallbacks), projected {}; deviation {deviation:.2e} m",
        exact.iterations, exact.exact, exact.fallbacks, projected.iterations
    );
}

#[test]
fn a_step_in_contact_tries_the_exact_blocks_from_its_first_iteration() {
    // Without gravity, a free sheet 0.6 mm (within `dhat`) above a held one: the barrier
    // pushes it off. Every iterate has pairs within `dhat`, and every Newton iteration,
    // the first included, writes a matrix with the exact blocks except one that follows
    // a refused one (the first iteration would not if they were tried only once Newton
    // is slow).
    let (mut integrator, stats, mut system) =
        sheets_in_contact(6, (DVec3::X, DVec3::Z), DVec3::ZERO, true);
    let report = integrator.step(&mut system, H).unwrap();
    assert_eq!(report.stop, StepStop::Converged, "{report:?}");
    assert!(
        stats.active_pairs() > 0,
        "the sheets left contact: the case tests nothing"
    );
    assert!(
        stats.exact_hessians() + report.contact_projection_fallbacks as u64
            >= report.iterations as u64,
        "{} exact matrices and {} refusals in {} iterations",
        stats.exact_hessians(),
        report.contact_projection_fallbacks,
        report.iterations
    );
    assert!(stats.min_gap() > 0.0);
}

#[test]
fn the_iteration_after_a_refused_exact_matrix_asks_for_the_projection_at_once() {
    // The turned sheet of the first test falling onto the held one: several steps refuse
    // the exact blocks more than once. Each Newton iteration writes at most one matrix
    // with the exact blocks, and one that follows a refusal writes none, so a step with
    // `r` refusals in `n` iterations writes at most `n - (r - 1)` of them (its last
    // refusal may be in its last iteration). Trying them in every iteration would write
    // `n` with `r` up to `n`.
    let (mut integrator, stats, mut system) = turned_sheets_falling(9, true);
    let mut repeated = 0;
    for step in 0..12 {
        let before = stats.exact_hessians();
        let report = integrator.step(&mut system, H).unwrap();
        assert_eq!(report.stop, StepStop::Converged, "step {step}: {report:?}");
        let (exact, refused) = (
            stats.exact_hessians() - before,
            report.contact_projection_fallbacks,
        );
        assert!(
            exact as usize + refused <= report.iterations + 1,
            "step {step}: {exact} exact matrices and {refused} refusals in {} iterations",
            report.iterations
        );
        repeated += usize::from(refused >= 2);
    }
    assert!(
        repeated > 0,
        "no step refused the exact blocks twice: the case tests nothing"
    );
    assert!(stats.min_gap() > 0.0);
}
