//! Backward Euler with self-contact is bitwise the same on one, two and three threads.
//!
//! Two 33 x 33 sheets (2 178 particles, so the integrator's pool runs the step), the top
//! one 1.6 mm above the bottom one over a corner of it, turned a little: with `dhat` 2 mm
//! and a thickness of 1 mm, hundreds of pairs are within the barrier's reach from the
//! first iteration, more than one chunk of the term's spread loops (gaps, derivatives,
//! energies, CCD, the kept list's box tests). Positions, velocities, Newton iterations and
//! the contact statistics must agree to the bit, with the pairs' projected Hessians and
//! with their exact ones tried first (`SelfContactSettings::exact_hessian`), with
//! friction between the sheets (its pairs' loops split in chunks too), and on the direct
//! solver, whose set-up for a widened pattern runs as a job on the pool while the
//! iteration goes on.

use crate::sheets;
use sinew_math::DVec3;
use sinew_spring_sim::contact::self_contact::SelfContactSettings;
use sinew_spring_sim::{LinearSolverChoice, NewtonSettings, SpringSystem, TriangleMesh};

const H: f64 = 1.0 / 60.0;
const N: usize = 33;

/// What a run ends with: the state, the Newton iterations per step, and per step the
/// active pairs and `kappa` (as bits), then the times the exact pair Hessians were
/// written and the fallbacks to the projected ones so far, then the friction pairs.
type Outcome = (SpringSystem, Vec<usize>, Vec<(usize, u64)>);

/// How a run is set up besides its threads.
#[derive(Clone, Copy)]
struct Setup {
    exact_hessian: bool,
    mu: f64,
    solver: LinearSolverChoice,
}

fn run(threads: usize, steps: usize, setup: Setup) -> Outcome {
    let Setup {
        exact_hessian,
        mu,
        solver,
    } = setup;
    let s = 0.01;
    let (u, w) = (
        DVec3::new(0.995_004, 0.0, 0.099_833_4),
        DVec3::new(-0.099_833_4, 0.0, 0.995_004),
    );
    let (x, t) = sheets::stacked(N, s, DVec3::new(0.06, 0.0016, 0.05), u, w, s);
    let mesh = TriangleMesh::new(x, t).unwrap();
    // The bottom sheet held at two corners; the top one free.
    let cloth = sheets::cloth(vec![0, N * N - 1]);
    let model = cloth.build(&mesh).unwrap();
    let newton = NewtonSettings {
        threads,
        linear_solver: solver,
        ..NewtonSettings::default()
    };
    let mut integrator = model.backward_euler(newton).unwrap();
    assert_eq!(
        integrator.threads(),
        crate::common::expected_threads(threads)
    );
    let settings = SelfContactSettings {
        dhat: 2e-3,
        thickness: 1e-3,
        exact_hessian,
        mu,
        ..SelfContactSettings::default()
    };
    let stats = model
        .enable_self_contact(&mut integrator, settings)
        .unwrap();
    let mut system = model.system.clone();
    if solver == LinearSolverChoice::Direct {
        assert!(integrator.direct_solver().is_some());
    }
    let mut iterations = Vec::new();
    let mut contact = Vec::new();
    let mut widened = 0;
    for _ in 0..steps {
        let report = integrator.step(&mut system, H).unwrap();
        iterations.push(report.iterations);
        contact.push((stats.active_pairs(), stats.kappa().to_bits()));
        contact.push((
            stats.exact_hessians() as usize,
            stats.projected_after_exact(),
        ));
        contact.push((stats.friction_pairs(), 0));
        widened += report.pattern_pairs_added;
        // No direct solver is left being set up once a step returns.
        if solver == LinearSolverChoice::Direct {
            assert!(integrator.direct_solver().is_some());
        }
    }
    // Contact widened the Hessian pattern (which rebuilds the linear solvers), and the
    // integrator still runs on its threads.
    assert!(widened > 0, "the pattern was never widened");
    assert_eq!(
        integrator.threads(),
        crate::common::expected_threads(threads),
        "threads after widening"
    );
    (system, iterations, contact)
}

#[test]
fn self_contact_steps_alike_on_one_two_and_three_threads() {
    let steps = 1;
    for (exact, mu) in [(false, 0.0), (true, 0.0), (true, 0.3)] {
        let setup = Setup {
            exact_hessian: exact,
            mu,
            solver: LinearSolverChoice::Auto,
        };
        let one = run(1, steps, setup);
        assert!(
            one.1.iter().all(|&k| k > 0),
            "a step without Newton iterations: {:?}",
            one.1
        );
        assert!(
            one.2.iter().step_by(3).all(|&(pairs, _)| pairs > 256),
            "too few pairs within dhat to split the term's loops: {:?}",
            one.2
        );
        let written = one.2[one.2.len() - 2].0;
        assert_eq!(written > 0, exact, "exact blocks written {written} times");
        // With friction, more pairs than one chunk of its loops from the first step.
        let friction = one.2.iter().skip(2).step_by(3).map(|p| p.0);
        assert!(
            friction.clone().all(|f| (f > 256) == (mu > 0.0)),
            "friction pairs {:?}",
            friction.collect::<Vec<_>>()
        );
        compare_threads(&one, |threads| run(threads, steps, setup));
    }
}

#[test]
fn self_contact_on_the_direct_solver_steps_alike_on_one_two_and_three_threads() {
    // The pattern widens within the step (asserted in `run`), so on two and three
    // threads the widened pattern's direct solver is set up by a job on the pool.
    let setup = Setup {
        exact_hessian: false,
        mu: 0.0,
        solver: LinearSolverChoice::Direct,
    };
    let one = run(1, 1, setup);
    compare_threads(&one, |threads| run(threads, 1, setup));
}

/// The runs of `run` on two and three threads against `one`, the run on one: the same
/// iterations, contact statistics and state, to the bit.
fn compare_threads(one: &Outcome, run: impl Fn(usize) -> Outcome) {
    for threads in [2, 3] {
        let other = run(threads);
        assert_eq!(other.1, one.1, "{threads} threads: Newton iterations");
        assert_eq!(other.2, one.2, "{threads} threads: contact statistics");
        assert_eq!(
            other.0.positions(),
            one.0.positions(),
            "{threads} threads: positions"
        );
        assert_eq!(
            other.0.velocities(),
            one.0.velocities(),
            "{threads} threads: velocities"
        );
    }
}

/// A small sheet dropped onto a larger one held whole (an obstacle: 900 pinned vertices
/// and 144 free ones), far too few free particles for PCG's chunks: once more than 512
/// pairs are within reach, self-contact asks for the integrator's pool anyway, and the
/// next steps run on it. The run is the same to the bit on one, two and three threads,
/// and the integrator reports the threads the last step ran on: one for the first step
/// (no pair yet), the threads it was given for the others.
fn obstacle_run(threads: usize) -> Outcome {
    let (n, top) = (30, 12);
    let (mut x, mut t) = sheets::grid(n, DVec3::ZERO, DVec3::X, DVec3::Z, 0.01, 0);
    let (u, w) = (
        DVec3::new(0.995_004, 0.0, 0.099_833_4),
        DVec3::new(-0.099_833_4, 0.0, 0.995_004),
    );
    let (xt, tt) = sheets::grid(top, DVec3::new(0.1, 0.0016, 0.09), u, w, 0.008, x.len());
    x.extend(xt);
    t.extend(tt);
    let mesh = TriangleMesh::new(x, t).unwrap();
    let model = sheets::cloth((0..n * n).collect()).build(&mesh).unwrap();
    let newton = NewtonSettings {
        threads,
        ..NewtonSettings::default()
    };
    let mut integrator = model.backward_euler(newton).unwrap();
    // Without a term that asks for them, a system this small runs on the calling thread.
    assert_eq!(integrator.threads(), 1);
    let settings = SelfContactSettings {
        dhat: 2e-3,
        thickness: 1e-3,
        mu: 0.3,
        ..SelfContactSettings::default()
    };
    let stats = model
        .enable_self_contact(&mut integrator, settings)
        .unwrap();
    let mut system = model.system.clone();
    let (mut iterations, mut contact) = (Vec::new(), Vec::new());
    for step in 0..3 {
        let report = integrator.step(&mut system, H).unwrap();
        iterations.push(report.iterations);
        contact.push((stats.active_pairs(), stats.kappa().to_bits()));
        contact.push((stats.friction_pairs(), 0));
        let expected = match step {
            0 => 1,
            _ => crate::common::expected_threads(threads),
        };
        assert_eq!(integrator.threads(), expected, "step {step}");
    }
    (system, iterations, contact)
}

#[test]
fn a_small_sheet_on_a_pinned_one_steps_alike_on_one_two_and_three_threads() {
    let one = obstacle_run(1);
    assert!(
        one.2.iter().step_by(2).all(|&(pairs, _)| pairs > 512),
        "too few pairs within dhat for the pool: {:?}",
        one.2
    );
    compare_threads(&one, obstacle_run);
}
