//! Steps whose Newton solve stops far from converged are redone in pieces: the cases of
//! the stress grid (the lab cloth, 11 x 11, undamped, stiffness up to 1e7, steps up to
//! 1/4, sheets stretched to twice or compressed to half their rest size) that stopped at
//! the iteration cap now converge in pieces; a split step is bitwise the same as its
//! pieces taken by hand; a step that converges at once is not touched; and what cannot
//! converge even at the deepest split says so.

use sinew_math::DVec3;
use sinew_spring_sim::*;

/// The stress grid's starting states (velocities zero).
#[derive(Clone, Copy, Debug)]
enum State {
    Rest,
    Stretched,
    Compressed,
}

/// The stress grid's lab cloth: `grid` particles per side, the sheet 2 wide, mass 1,
/// stiffness `k`, no damping, the lab's gravity, corners (0, 0) and (0, n-1) pinned,
/// every particle scaled about the sheet's centre by 2 (stretched) or 0.5 (compressed).
fn cloth(grid: usize, k: f64, state: State) -> SpringSystem {
    let mut spec = ClothGrid::lab_sized(grid, 2.0 / (grid - 1) as f64).with_damping(0.0);
    spec.material.stiffness = k;
    let mut system = SpringSystem::cloth(&spec).unwrap();
    let scale = match state {
        State::Rest => 1.0,
        State::Stretched => 2.0,
        State::Compressed => 0.5,
    };
    crate::common::scale_about_centre(&mut system, scale);
    system
}

fn settings(depth: usize) -> NewtonSettings {
    NewtonSettings {
        // A fixed solver, so the abandoned attempt's observations cannot change the
        // automatic choice of a later piece.
        linear_solver: LinearSolverChoice::Direct,
        max_split_depth: depth,
        ..NewtonSettings::default()
    }
}

/// `E_spring(x') + E_gravity(x') + 1/2 |v' - v_n|_M^2 - E_total(x_n, v_n)`, relative to the
/// start's energy scale: backward Euler's energy inequality says it is at most 0.
fn inequality_excess(before: &SpringSystem, after: &SpringSystem) -> f64 {
    let e0 = before.energies();
    let e1 = after.energies();
    let dv: f64 = after
        .velocities()
        .iter()
        .zip(before.velocities())
        .zip(before.masses())
        .map(|((v, v0), m)| 0.5 * m * (*v - *v0).length_squared())
        .sum();
    (e1.spring + e1.gravity + dv - e0.total()) / e0.scale()
}

/// First steps of the stress grid that stopped at the cap with residuals 1e7 to 1e11
/// times the tolerance with the automatic solver, above 1e5 times with the direct one
/// (11 x 11, stiffness, 1/dt, state).
const HARD_FIRST_STEPS: [(f64, f64, State); 4] = [
    (1e4, 60.0, State::Compressed),
    (1e6, 240.0, State::Compressed),
    (1e6, 4.0, State::Compressed),
    (1e7, 4.0, State::Compressed),
];

#[test]
fn stress_grid_steps_left_at_the_cap_converge_in_pieces() {
    for (k, inv_dt, state) in HARD_FIRST_STEPS {
        let h = 1.0 / inv_dt;
        // Without splitting: the cap, far above the tolerance (as in the stress grid).
        let mut system = cloth(11, k, state);
        let mut unsplit = BackwardEuler::new(&system, settings(0)).unwrap();
        let report = unsplit.step(&mut system, h).unwrap();
        assert_eq!(
            report.stop,
            StepStop::IterationCap,
            "k {k:e} 1/{inv_dt}: {report:?}"
        );
        assert!(
            report.residual > 1e5 * report.tolerance,
            "k {k:e} 1/{inv_dt}: {report:?}"
        );
        assert_eq!((report.pieces, report.unconverged_pieces), (1, 1));
        // With the default depth: converged, in pieces.
        let mut system = cloth(11, k, state);
        let before = system.clone();
        let mut split = BackwardEuler::new(&system, settings(6)).unwrap();
        let report = split.step(&mut system, h).unwrap();
        assert_eq!(report.stop, StepStop::Converged, "k {k:e} 1/{inv_dt}");
        assert!(report.residual <= report.tolerance, "{report:?}");
        assert!(report.pieces > 1, "k {k:e} 1/{inv_dt}: {report:?}");
        assert!(report.pieces <= 1 << report.split_depth);
        assert_eq!((report.unconverged_pieces, report.rejected_splits), (0, 0));
        // The tolerance is the one of the pieces' own step (tol m_min / h_piece^2), and
        // the report names that piece's length.
        let shortest = h / f64::from(1u32 << report.split_depth);
        assert!(
            report.tolerance >= 1e-9 / (h * h)
                && report.tolerance <= 1e-9 / (shortest * shortest) * (1.0 + 1e-12)
        );
        let piece = report.effective_step;
        assert!(
            (0..=report.split_depth).any(|j| piece == h / f64::from(1u32 << j)),
            "k {k:e} 1/{inv_dt}: {report:?}"
        );
        assert!((report.tolerance - 1e-9 / (piece * piece)).abs() <= 1e-12 * report.tolerance);
        assert!(inequality_excess(&before, &system) <= 1e-12);
        assert!(system.positions().iter().all(|x| x.is_finite()));
    }
}

/// A split step equals two steps of h/2 taken by hand with the same settings (each of
/// which may split again the same way), bit for bit, and so does the step after it (the
/// velocity history of the first guess goes on the same way).
#[test]
fn a_split_step_is_its_pieces_taken_by_hand() {
    for (k, inv_dt, state) in HARD_FIRST_STEPS {
        let h = 1.0 / inv_dt;
        let mut split_system = cloth(11, k, state);
        let mut by_hand_system = split_system.clone();
        let mut split = BackwardEuler::new(&split_system, settings(6)).unwrap();
        let mut by_hand = BackwardEuler::new(&by_hand_system, settings(6)).unwrap();
        let report = split.step(&mut split_system, h).unwrap();
        assert!(report.pieces > 1, "k {k:e} 1/{inv_dt}: {report:?}");
        assert_eq!(report.stop, StepStop::Converged);
        let (mut iterations, mut pieces) = (0, 0);
        for _ in 0..2 {
            let half = by_hand.step(&mut by_hand_system, 0.5 * h).unwrap();
            iterations += half.iterations;
            pieces += half.pieces;
        }
        assert_eq!(
            split_system.positions(),
            by_hand_system.positions(),
            "k {k:e} 1/{inv_dt}"
        );
        assert_eq!(split_system.velocities(), by_hand_system.velocities());
        assert_eq!(report.pieces, pieces);
        // The split step's count includes the abandoned attempt (the cap, 50 iterations).
        assert_eq!(report.iterations, iterations + 50);
        // The next step (the same length on both) continues bitwise alike.
        split.step(&mut split_system, 0.5 * h).unwrap();
        by_hand.step(&mut by_hand_system, 0.5 * h).unwrap();
        assert_eq!(split_system.positions(), by_hand_system.positions());
        assert_eq!(split_system.velocities(), by_hand_system.velocities());
    }
}

/// Implicit midpoint is split into midpoint steps, bitwise the same as taken by hand.
#[test]
fn a_split_midpoint_step_is_its_pieces_taken_by_hand() {
    let (k, h) = (1e7, 1.0 / 4.0);
    let mut split_system = cloth(11, k, State::Compressed);
    let mut by_hand_system = split_system.clone();
    let mut split = ImplicitMidpoint::new(&split_system, settings(6)).unwrap();
    let mut by_hand = ImplicitMidpoint::new(&by_hand_system, settings(6)).unwrap();
    let report = split.step(&mut split_system, h).unwrap();
    assert_eq!(report.stop, StepStop::Converged, "{report:?}");
    assert!(report.pieces > 1, "{report:?}");
    let mut pieces = 0;
    for _ in 0..2 {
        pieces += by_hand.step(&mut by_hand_system, 0.5 * h).unwrap().pieces;
    }
    assert_eq!(report.pieces, pieces);
    assert_eq!(split_system.positions(), by_hand_system.positions());
    assert_eq!(split_system.velocities(), by_hand_system.velocities());
}

/// BDF2 splits into backward Euler steps (its starting step) and converges.
#[test]
fn a_bdf2_step_left_at_the_cap_converges_in_pieces() {
    let (k, h) = (1e7, 1.0 / 4.0);
    let mut unsplit_system = cloth(11, k, State::Compressed);
    let mut unsplit = Bdf2::new(&unsplit_system, settings(0)).unwrap();
    let report = unsplit.step(&mut unsplit_system, h).unwrap();
    assert_eq!(report.stop, StepStop::IterationCap, "{report:?}");
    let mut system = cloth(11, k, State::Compressed);
    let mut bdf2 = Bdf2::new(&system, settings(6)).unwrap();
    for n in 0..3 {
        let report = bdf2.step(&mut system, h).unwrap();
        assert_eq!(report.integrator, IntegratorKind::Bdf2);
        assert_eq!(report.stop, StepStop::Converged, "step {n}: {report:?}");
        assert!(report.residual <= report.tolerance);
        if n == 0 {
            assert!(report.pieces > 1, "{report:?}");
        }
    }
}

/// A step that converges at once is bitwise the same with splitting on and off: 60 steps
/// of the lab cloth (W4: 11 x 11, stiffness 100, damping 0.2, h = 1/60) and of a stiff
/// one (stiffness 1e4, h = 1/30).
#[test]
fn steps_that_converge_are_unchanged() {
    for (k, h) in [(100.0, 1.0 / 60.0), (1e4, 1.0 / 30.0)] {
        let mut spec = ClothGrid::lab();
        spec.material.stiffness = k;
        let mut a = SpringSystem::cloth(&spec).unwrap();
        let mut b = a.clone();
        let mut on = BackwardEuler::new(&a, NewtonSettings::default()).unwrap();
        let off_settings = NewtonSettings {
            max_split_depth: 0,
            ..NewtonSettings::default()
        };
        let mut off = BackwardEuler::new(&b, off_settings).unwrap();
        for _ in 0..60 {
            let ra = on.step(&mut a, h).unwrap();
            let rb = off.step(&mut b, h).unwrap();
            assert_eq!(ra.stop, StepStop::Converged);
            assert_eq!((ra.pieces, ra.split_depth), (1, 0));
            assert_eq!(ra, rb);
        }
        assert_eq!(a.positions(), b.positions());
        assert_eq!(a.velocities(), b.velocities());
    }
}

/// When even the deepest split allowed does not converge (its pieces' solves continued
/// for their extra caps, here of 2 iterations each), the report says so: the stop of the
/// worst piece, its residual above its tolerance, and the pieces kept unconverged.
#[test]
fn a_split_too_shallow_says_so() {
    let (k, h) = (1e7, 1.0 / 4.0);
    let mut system = cloth(11, k, State::Compressed);
    let before = system.clone();
    let tight = NewtonSettings {
        max_iterations: 2,
        ..settings(1)
    };
    let mut be = BackwardEuler::new(&system, tight).unwrap();
    let report = be.step(&mut system, h).unwrap();
    assert_ne!(report.stop, StepStop::Converged, "{report:?}");
    assert!(report.residual > report.tolerance);
    assert!(report.unconverged_pieces >= 1, "{report:?}");
    // The settings' depth and the two extra levels below it.
    assert!(report.split_depth <= 1 + 2);
    assert!(inequality_excess(&before, &system) <= 1e-12);
}

/// A piece at the settings' deepest split that is still far from converged after its
/// continued solve is halved again (at most twice), and the step converges: the
/// compressed 11 x 11 sheet at k = 1e6, h = 1/240 with a cap of 4 iterations and
/// `max_split_depth` 2 leaves a piece of `h/4` far from converged after its extra caps.
#[test]
fn a_piece_still_far_at_the_deepest_split_is_halved_again() {
    let (k, h) = (1e6, 1.0 / 240.0);
    let tight = NewtonSettings {
        max_iterations: 4,
        ..settings(2)
    };
    let mut system = cloth(11, k, State::Compressed);
    let before = system.clone();
    let mut be = BackwardEuler::new(&system, tight).unwrap();
    let report = be.step(&mut system, h).unwrap();
    assert_eq!(report.stop, StepStop::Converged, "{report:?}");
    assert!(report.residual <= report.tolerance, "{report:?}");
    assert_eq!((report.unconverged_pieces, report.rejected_splits), (0, 0));
    // It needed the extra levels, and no more than the two allowed.
    assert!(
        report.split_depth > 2 && report.split_depth <= 4,
        "{report:?}"
    );
    assert!(report.pieces <= 1 << report.split_depth);
    assert!(inequality_excess(&before, &system) <= 1e-12);
    assert!(system.positions().iter().all(|x| x.is_finite()));
    // Without the halving below the settings' depth, the same piece would be kept far
    // from converged: a step of h/4 alone, with no split allowed, stops at the cap.
    let mut alone_system = cloth(11, k, State::Compressed);
    let no_split = NewtonSettings {
        max_iterations: 4,
        ..settings(0)
    };
    let mut alone = BackwardEuler::new(&alone_system, no_split).unwrap();
    let quarter = alone.step(&mut alone_system, 0.25 * h).unwrap();
    assert_eq!(quarter.stop, StepStop::IterationCap, "{quarter:?}");
    assert!(quarter.residual > 1e3 * quarter.tolerance, "{quarter:?}");
}

/// The energy inequality of backward Euler holds for every step, split or not: where the
/// pieces of a split break it (the stretched stiff sheet's second step), the split is
/// discarded and the report says so, and the whole step's solve, continued from where
/// it stopped, converges.
#[test]
fn splits_that_break_the_energy_inequality_are_discarded() {
    let (k, h) = (1e7, 1.0 / 4.0);
    let mut system = cloth(11, k, State::Stretched);
    let mut be = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
    // The pieces' record keeps what the step kept: the pieces of a kept split, or the
    // whole step alone where the split was discarded.
    be.record_piece_ends(true);
    let mut rejected = 0;
    let mut split = 0;
    for n in 0..4 {
        let before = system.clone();
        let report = be.step(&mut system, h).unwrap();
        let record = be.piece_ends().unwrap();
        assert_eq!(record.len(), report.pieces, "step {n}: {report:?}");
        let (end, last) = record.get(record.len() - 1).unwrap();
        assert_eq!(last, system.positions(), "step {n}");
        assert!((end - be.time()).abs() <= 1e-12, "step {n}: {end}");
        rejected += report.rejected_splits;
        split += usize::from(report.pieces > 1);
        if report.rejected_splits > 0 {
            assert_eq!(report.pieces, 1, "step {n}: {report:?}");
            assert_eq!(report.unconverged_pieces, 0, "step {n}: {report:?}");
            assert_eq!(report.stop, StepStop::Converged, "step {n}: {report:?}");
            assert!(report.residual <= report.tolerance);
        }
        let excess = inequality_excess(&before, &system);
        assert!(excess <= 1e-12, "step {n}: excess {excess:e}, {report:?}");
    }
    assert!(
        split >= 1 && rejected >= 1,
        "split {split}, rejected {rejected}"
    );
}

/// A rejected split whose whole-step solve is still far from converged after its
/// continued caps is taken up once more from the pieces' end positions (where `g` is
/// below the start state's): a stretched stiff sheet (k = 1e7, h = 1/60) whose second
/// step, with a cap of 4, stays far from converged after the continuation alone (the test
/// fails with the new start removed) converges from there, and keeps the energy
/// inequality. The fixture depends on the solver's round-off: found again by a search
/// over stiffness, step, state and cap when that changed.
#[test]
fn a_rejected_split_is_taken_up_from_the_pieces_end() {
    let (k, h) = (1e7, 1.0 / 60.0);
    let mut system = cloth(11, k, State::Stretched);
    let settings = NewtonSettings {
        max_iterations: 4,
        ..settings(NewtonSettings::default().max_split_depth)
    };
    let mut be = BackwardEuler::new(&system, settings).unwrap();
    let first = be.step(&mut system, h).unwrap();
    assert_eq!(first.rejected_splits, 0, "{first:?}");
    let before = system.clone();
    let report = be.step(&mut system, h).unwrap();
    assert!(report.rejected_splits >= 1, "{report:?}");
    assert_eq!(report.pieces, 1, "{report:?}");
    assert_eq!(report.unconverged_pieces, 0, "{report:?}");
    assert_eq!(report.stop, StepStop::Converged, "{report:?}");
    let excess = inequality_excess(&before, &system);
    assert!(excess <= 1e-12, "excess {excess:e}, {report:?}");
}

#[test]
fn a_split_depth_beyond_the_limit_is_refused_by_name() {
    let system = cloth(3, 10.0, State::Rest);
    let settings = NewtonSettings {
        max_split_depth: 21,
        ..NewtonSettings::default()
    };
    let err = BackwardEuler::new(&system, settings).unwrap_err();
    assert!(err.to_string().contains("max_split_depth"), "{err}");
}

/// A step with a moving collider is split too, and equals its pieces taken by hand: each
/// piece poses the collider from its own start time, and the abandoned attempt's barrier
/// stiffness is rewound.
#[test]
fn a_split_step_with_a_moving_collider_is_its_pieces_taken_by_hand() {
    use sinew_spring_sim::contact::{Collider, ContactSettings, Shape};
    let h = 1.0 / 30.0;
    // A 6 x 6 sheet falling at 0.6 m/s, 2 mm above a ground sinking at 0.3 m/s: it
    // reaches the ground within the step, and 4 Newton iterations leave the step far
    // from converged. (The ground takes energy from the sheet, so backward Euler's
    // energy inequality, which a split step must keep, holds; a collider pushing the
    // sheet does work, and a split that breaks the inequality falls back to the attempt.)
    let n = 6;
    let mut particles = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let p = DVec3::new(0.05 * i as f64, 0.002, 0.05 * j as f64);
            particles.push(Particle {
                velocity: DVec3::new(0.0, -0.6, 0.0),
                ..Particle::at_rest(p, 5e-4)
            });
        }
    }
    let material = Material {
        stiffness: 1000.0,
        damping: 0.1,
        gravity: DVec3::new(0.0, -9.81, 0.0),
    };
    let system = SpringSystem::new(&particles, &ClothGrid::spring_pattern(n), material).unwrap();
    let ground = Collider::fixed(Shape::HalfSpace {
        point: DVec3::ZERO,
        normal: DVec3::Y,
    })
    .moving(DVec3::new(0.0, -0.3, 0.0), DVec3::ZERO);
    let run = |depth: usize| {
        let settings = NewtonSettings {
            max_iterations: 4,
            ..settings(depth)
        };
        let mut sim = Simulation::new(system.clone(), Integrator::BackwardEuler(settings)).unwrap();
        sim.set_contact(vec![ground], ContactSettings::default())
            .unwrap();
        sim
    };
    // The halves by hand may split once more, as the split step's halves may: the
    // deepest pieces of both (whose solves are continued past the cap, which a step with
    // splitting off is not) are then alike.
    let mut split = run(2);
    let mut by_hand = run(1);
    let report = split.step(h).unwrap();
    assert!(report.pieces >= 2, "{report:?}");
    // Within the settings' depth, so the halves by hand take the same decisions. (Below
    // it, a piece halved twice more in the first half makes the split step skip the
    // solves of the second half's coarser pieces, which a second half asked for by hand,
    // a whole step, always tries: then the leaves are still ordinary steps, but not the
    // same ones.)
    assert!(report.split_depth <= 2, "{report:?}");
    let mut pieces = 0;
    for _ in 0..2 {
        pieces += by_hand.step(0.5 * h).unwrap().pieces;
    }
    assert_eq!(pieces, report.pieces);
    assert_eq!(split.system().positions(), by_hand.system().positions());
    assert_eq!(split.system().velocities(), by_hand.system().velocities());
    assert_eq!(split.contact_kappa(), by_hand.contact_kappa());
    // The ground reached the sheet: the collider's pose shaped the result.
    let (min, pairs) = split.contact_distances().unwrap();
    assert!(min > 0.0 && pairs > 0, "min {min}, pairs {pairs}");
}

/// `Auto` runs PCG on a run's first step to observe its count, but a step whose PCG count
/// per Newton iteration is above the cost model's crossover finishes on the direct solve
/// after the probe iterations: the stretched stiff sheet's first step (hundreds of Newton
/// iterations) runs PCG for its first three only, and the next step starts on the direct
/// solve.
#[test]
fn a_step_far_above_the_pcg_crossover_finishes_on_the_direct_solve() {
    let (k, h) = (1e7, 1.0 / 4.0);
    let mut system = cloth(11, k, State::Stretched);
    let settings = NewtonSettings {
        max_split_depth: 0,
        max_iterations: 200,
        ..NewtonSettings::default()
    };
    assert_eq!(settings.linear_solver, LinearSolverChoice::Auto);
    let mut be = BackwardEuler::new(&system, settings).unwrap();
    let first = be.step(&mut system, h).unwrap();
    assert_eq!(
        first.linear_solver,
        Some(LinearSolverKind::Direct),
        "{first:?}"
    );
    assert!(first.iterations > 3, "{first:?}");
    // Three Newton iterations on PCG, each above the crossover (about 23 here) and at
    // most PCG's cap.
    assert!(first.linear_iterations > 3 * 23, "{first:?}");
    assert!(
        first.linear_iterations <= 3 * settings.pcg_max_iterations,
        "{first:?}"
    );
    let second = be.step(&mut system, h).unwrap();
    assert_eq!(
        second.linear_solver,
        Some(LinearSolverKind::Direct),
        "{second:?}"
    );
    assert_eq!(second.linear_iterations, 0, "{second:?}");
}

/// A step so long that even its deepest piece is static (the lab cloth, k = 100, mass 1,
/// h = 1e9: `k h^2 / m` is 1.5e15 in a piece of `h / 256`) is not split: each piece would
/// be the same static solve from the start. The whole step's solve, stopped at a cap of
/// 5 iterations, is continued instead and converges, and its end state is the hanging
/// sheet's equilibrium: at every free particle the spring forces, computed here from
/// the springs, cancel gravity to 1e-9 of the particle's weight.
#[test]
fn a_step_whose_pieces_would_all_be_static_is_continued_not_split() {
    let h = 1e9;
    let mut system = cloth(11, 100.0, State::Rest);
    let capped = NewtonSettings {
        max_iterations: 5,
        ..settings(6)
    };
    let mut be = BackwardEuler::new(&system, capped).unwrap();
    let report = be.step(&mut system, h).unwrap();
    assert_eq!(report.pieces, 1, "{report:?}");
    assert_eq!(report.split_depth, 0, "{report:?}");
    assert_eq!(report.unconverged_pieces, 0, "{report:?}");
    // The first attempt reached its cap; the continued solve ended at the round-off
    // floor (possibly at a cap, so the stop is not asserted: the equilibrium is).
    assert!(report.iterations > 5, "the cap was reached: {report:?}");

    let x = system.positions();
    let gravity = system.material().gravity;
    let mut force: Vec<DVec3> = system.masses().iter().map(|m| *m * gravity).collect();
    for s in system.springs() {
        let d = x[s.b] - x[s.a];
        let pull = s.stiffness * (d.length() - s.rest_length) * d.normalize();
        force[s.a] += pull;
        force[s.b] -= pull;
    }
    for (p, f) in force.iter().enumerate() {
        if !system.fixed()[p] {
            let weight = system.masses()[p] * gravity.length();
            assert!(f.length() <= 1e-9 * weight, "particle {p}: net force {f}");
        }
    }
    // The sheet did swing down to hang: its lowest particle is far below the pins.
    let lowest = x.iter().map(|p| p.y).fold(f64::INFINITY, f64::min);
    assert!(lowest < x[0].y - 1.0, "lowest {lowest}, pin at {}", x[0].y);
}

/// With `record_objective`, a split step's traces hold every minimization it ran: the
/// abandoned whole-step attempt (at the cap) and each piece's solve, each descending,
/// the last one the `objective_trace` of the last piece.
#[test]
fn a_split_steps_traces_hold_every_minimization_each_descending() {
    let (k, inv_dt, state) = HARD_FIRST_STEPS[0];
    let h = 1.0 / inv_dt;
    let mut system = cloth(11, k, state);
    let newton = NewtonSettings {
        record_objective: true,
        ..settings(6)
    };
    let mut be = BackwardEuler::new(&system, newton).unwrap();
    let report = be.step(&mut system, h).unwrap();
    assert!(report.pieces > 1, "{report:?}");
    let traces: Vec<&[f64]> = be.step_objective_traces().collect();
    // At least the abandoned attempt and one solve per piece (no contact here, so no
    // minimization is cut by a change of its function).
    assert!(traces.len() > report.pieces, "{} traces", traces.len());
    // One value per iteration, and one more where a minimization stopped converged
    // (its last iterate is recorded before the test that stops it).
    let iterates: usize = traces.iter().map(|t| t.len()).sum();
    assert!(
        iterates >= report.iterations && iterates <= report.iterations + traces.len(),
        "{iterates} values, {report:?}"
    );
    assert!(traces.first().unwrap().len() >= newton.max_iterations);
    assert_eq!(*traces.last().unwrap(), be.objective_trace());
    for (m, t) in traces.iter().enumerate() {
        for w in t.windows(2) {
            assert!(w[1] <= w[0] + 1e-12 * w[0].abs(), "minimization {m}: {w:?}");
        }
    }
    // The next step starts its own.
    let report = be.step(&mut system, h).unwrap();
    let count: usize = be.step_objective_traces().map(<[f64]>::len).sum();
    let slices = be.step_objective_traces().count();
    assert!(count >= report.iterations && count <= report.iterations + slices);
    assert_eq!(
        be.step_objective_traces().last(),
        Some(be.objective_trace())
    );
}
