//! Steps at the edges of the arithmetic: a step so long that backward Euler is a static
//! solve, and damping so strong that the tolerance lies below the round-off of the
//! gradient. Each must end in few iterations, unsplit, at an answer checked here from the
//! forces themselves.

use crate::common::{contact_sheet, static_force};
use sinew_math::DVec3;
use sinew_spring_sim::contact::{Collider, ContactSettings};
use sinew_spring_sim::*;

/// A step of 1e12 s of the lab cloth (flat, at rest, undamped) is a static solve: it
/// lands on the hanging sheet's equilibrium. The Newton step from the flat sheet is a
/// fall of `g h^2 ~ 3e23` (springs at rest resist nothing across the sheet), which
/// halving alone could not shorten to what the springs accept within the line search's
/// trials: the sheet stayed flat and every step was split to its deepest level.
#[test]
fn a_step_of_a_trillion_seconds_lands_on_the_static_equilibrium() {
    let mut system = SpringSystem::cloth(&ClothGrid::lab().with_damping(0.0)).unwrap();
    let start_y = system.positions()[60].y;
    let weight = 0.3;
    let mut stepper = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
    let h = 1e12;
    let report = stepper.step(&mut system, h).unwrap();
    assert_eq!(report.pieces, 1, "{report:?}");
    assert!(report.iterations < 50, "{report:?}");
    // The tolerance (1e-9 m / h^2 = 1e-33) is far below what f64 resolves here.
    assert_eq!(report.stop, StepStop::RoundOff, "{report:?}");
    // The centre of the sheet hangs well below where it started.
    assert!(
        system.positions()[60].y < start_y - 1.0,
        "{:?}",
        system.positions()[60]
    );
    // Equilibrium: the springs carry every particle's weight, to 1e-10 of it.
    let force = static_force(&system);
    assert!(force <= 1e-10 * weight, "static force {force:e}");
    // At equilibrium the next step has nothing left to do.
    let before = system.positions().to_vec();
    let report = stepper.step(&mut system, h).unwrap();
    assert!(report.iterations <= 2, "{report:?}");
    assert_eq!(report.pieces, 1, "{report:?}");
    let moved = before
        .iter()
        .zip(system.positions())
        .map(|(a, b)| a.distance(*b))
        .fold(0.0, f64::max);
    assert!(moved < 1e-12, "moved {moved:e}");
    assert!(static_force(&system) <= 1e-10 * weight);
}

/// A sheet with damping `c = 2^32` (`c/h = 2.6e11` per spring, against `m/h^2 = 0.65`)
/// falling onto a sphere: the damping's rounding in the gradient is far above the
/// tolerance, so no iterate can reach it. Each step must stop at the round-off floor in
/// a handful of iterations, unsplit, with every particle outside the sphere; and each
/// such stop is checked against the part of the floor it claims, computed here from the
/// springs and the damping alone: a sixteenth of `16 eps |x|_max max_p (m_p/h^2 +
/// sum_s (k_s + c/h))`.
#[test]
fn huge_damping_stops_at_round_off_instead_of_splitting() {
    let n = 10;
    let spacing = 0.03;
    let origin = DVec3::new(-0.135, 0.08, -0.135);
    let mut system = contact_sheet(n, spacing, origin, DVec3::X, DVec3::Z);
    let c = 4_294_967_296.0;
    system.set_damping(c).unwrap();
    let (center, radius) = (DVec3::ZERO, 0.06);
    let settings = NewtonSettings {
        max_iterations: 100,
        ..NewtonSettings::default()
    };
    let mut sim = Simulation::new(system, Integrator::BackwardEuler(settings)).unwrap();
    let contact = ContactSettings {
        mu: 0.3,
        ..ContactSettings::default()
    };
    sim.set_contact(vec![Collider::sphere(center, radius)], contact)
        .unwrap();
    let h = 1.0 / 60.0;
    let mut round_off_stops = 0;
    let mut touched = false;
    for step in 0..20 {
        let report = sim.step(h).unwrap();
        let system = sim.system();
        assert_eq!(report.pieces, 1, "step {step}: {report:?}");
        assert!(report.iterations <= 20, "step {step}: {report:?}");
        let closest = system
            .positions()
            .iter()
            .map(|p| p.distance(center) - radius)
            .fold(f64::INFINITY, f64::min);
        assert!(
            closest > 0.0,
            "step {step}: a particle is inside the sphere"
        );
        touched |= closest < contact.dhat;
        match report.stop {
            StepStop::Converged => assert!(report.residual <= report.tolerance),
            StepStop::RoundOff => {
                round_off_stops += 1;
                let mut rows: Vec<f64> = system.masses().iter().map(|m| m / (h * h)).collect();
                for s in system.springs() {
                    rows[s.a] += s.stiffness + c / h;
                    rows[s.b] += s.stiffness + c / h;
                }
                let row = rows.iter().copied().fold(0.0, f64::max);
                let x_max = system
                    .positions()
                    .iter()
                    .map(|x| x.abs().max_element())
                    .fold(0.0, f64::max);
                let floor = f64::EPSILON * x_max * row;
                assert!(
                    report.residual <= floor,
                    "step {step}: residual {:e} above the floor {floor:e}",
                    report.residual
                );
            }
            other => panic!("step {step}: stopped {other:?}: {report:?}"),
        }
    }
    assert!(touched, "the sheet never reached the sphere");
    assert!(round_off_stops > 0, "no step met the round-off floor");
}

/// A gravity of 1e300 makes the first step's fall `g h^2` (3e296 at h = 1/60) overflow
/// the inertia's energy at every step length the line search can try: the step is refused
/// with `StepError::Overflow` and the system is left exactly as it was (it used to be
/// split to the deepest level, each piece stalled, and the sheet stayed frozen in place,
/// step after step, at a hundred times the cost). A gravity of 1e100, far beyond anything
/// physical but within range, still steps: the sheet falls by about `g h^2`.
#[test]
fn a_gravity_beyond_the_range_of_f64_is_refused_and_leaves_the_system_unchanged() {
    let h = 1.0 / 60.0;
    for integrator in [
        Integrator::default(),
        Integrator::BackwardEuler(NewtonSettings::default()),
        Integrator::Bdf2(NewtonSettings::default()),
        Integrator::ImplicitMidpoint(NewtonSettings::default()),
    ] {
        let mut grid = ClothGrid::lab();
        grid.material.gravity = DVec3::new(0.0, -1e300, 0.0);
        let system = SpringSystem::cloth(&grid).unwrap();
        let mut sim = Simulation::new(system.clone(), integrator).unwrap();
        let err = sim.step(h).unwrap_err();
        assert!(
            matches!(err, StepError::Overflow { .. }),
            "{integrator:?}: {err:?}"
        );
        assert!(err.to_string().contains("not finite"), "{err}");
        assert_eq!(sim.system().positions(), system.positions());
        assert_eq!(sim.system().velocities(), system.velocities());
        assert_eq!(sim.time(), 0.0);
    }
    let mut grid = ClothGrid::lab();
    grid.material.gravity = DVec3::new(0.0, -1e100, 0.0);
    let system = SpringSystem::cloth(&grid).unwrap();
    let mut sim = Simulation::new(system.clone(), Integrator::default()).unwrap();
    sim.step(h).unwrap();
    let fall = system.positions()[60].y - sim.system().positions()[60].y;
    assert!(fall > 0.5 * 1e100 * h * h, "fall {fall:e}");
}
