//! Kinematic (prescribed) pinned particles: a spring whose pinned end moves at constant
//! velocity against the exact solution of its ODE (undamped and damped, backward Euler
//! first order and BDF2 and implicit midpoint second order in the step), a pinned sheet
//! translating rigidly and dragging a free sheet along exactly, located errors for bad
//! targets and motions, and a pinned sheet pushed through a free one: every accepted
//! state is checked for triangles passing through each other by an exact test on top of
//! Shewchuk's predicates (sinew-exact, on the `robust` crate), independent of the solver.

use sinew_exact::intersecting_pairs;
use sinew_math::DVec3;
use sinew_spring_sim::contact::self_contact::SelfContactSettings;
use sinew_spring_sim::{
    Bending, ClothGrid, Integrator, Material, MeshCloth, ModelError, NewtonSettings, Particle,
    PinDriver, PinnedMotion, Simulation, SpringSpec, SpringSystem, StepError, TriangleMesh,
    step_to_targets,
};

// A spring with one end prescribed.

/// Pinned particle 0 at the origin moving at `u` along +x, free particle 1 of mass 1 at
/// rest one rest length `L = 1` further, spring stiffness 100 (`omega = 10`), damping
/// `c`, no gravity. The stretch `e = x_1 - x_0 - L` obeys `e'' = -omega^2 e - c e'` with
/// `e(0) = 0`, `e'(0) = -u`, so (underdamped, `zeta = c / (2 omega)`,
/// `omega_d = omega sqrt(1 - zeta^2)`) `e(t) = -(u/omega_d) exp(-zeta omega t)
/// sin(omega_d t)` and `x_1(t) = u t + L + e(t)`.
fn spring_end_error(integrator: Integrator, c: f64, h: f64, t_end: f64) -> f64 {
    let u = 0.5;
    let particles = [
        Particle {
            fixed: true,
            ..Particle::at_rest(DVec3::ZERO, 1.0)
        },
        Particle::at_rest(DVec3::X, 1.0),
    ];
    let material = Material {
        stiffness: 100.0,
        damping: c,
        gravity: DVec3::ZERO,
    };
    let system = SpringSystem::new(&particles, &[SpringSpec::between(0, 1)], material).unwrap();
    let mut sim = Simulation::new(system, integrator).unwrap();
    sim.set_pinned_motion(vec![PinnedMotion::translation(vec![0], DVec3::X * u)])
        .unwrap();
    let steps = (t_end / h).round() as usize;
    for _ in 0..steps {
        let report = sim.step(h).unwrap();
        assert!(
            report.residual <= report.tolerance,
            "{integrator:?}, c = {c}, h = {h}: {report:?}"
        );
    }
    let t = steps as f64 * h;
    let x = sim.system().positions();
    let v = sim.system().velocities();
    // The pinned end is exactly on its path, with the velocity of its move.
    assert!((x[0] - DVec3::X * u * t).length() < 1e-12);
    assert!((v[0] - DVec3::X * u).length() < 1e-12);
    // The motion stays on the x axis.
    assert!(x[1].y.abs() < 1e-12 && x[1].z.abs() < 1e-12);
    let omega: f64 = 10.0;
    let zeta = c / (2.0 * omega);
    let omega_d = omega * (1.0 - zeta * zeta).sqrt();
    let e = -(u / omega_d) * (-zeta * omega * t).exp() * (omega_d * t).sin();
    (x[1].x - (u * t + 1.0 + e)).abs()
}

fn tight() -> NewtonSettings {
    NewtonSettings::default()
}

#[test]
fn a_spring_pulled_at_constant_velocity_follows_the_exact_ode_as_h_shrinks() {
    // The amplitude is u / omega = 0.05. Backward Euler is first order: halving h halves
    // the error; BDF2 and the implicit midpoint are second order: it falls by about 4.
    // The damped case checks that damping sees the pinned end's velocity (with it taken
    // as zero the damping force would be c x_1' instead of c e', a different ODE whose
    // error would not shrink with h).
    for c in [0.0, 4.0] {
        let cases: [(&str, Integrator, f64, f64); 3] = [
            (
                "backward Euler",
                Integrator::BackwardEuler(tight()),
                1.7,
                2.3,
            ),
            ("BDF2", Integrator::Bdf2(tight()), 3.2, 5.0),
            (
                "implicit midpoint",
                Integrator::ImplicitMidpoint(tight()),
                3.5,
                4.5,
            ),
        ];
        for (name, integrator, low, high) in cases {
            let coarse = spring_end_error(integrator, c, 2e-3, 1.0);
            let fine = spring_end_error(integrator, c, 1e-3, 1.0);
            let ratio = coarse / fine;
            assert!(
                fine < 5e-3 && (low..high).contains(&ratio),
                "{name}, c = {c}: errors {coarse:.3e} at h = 2e-3 and {fine:.3e} at h = 1e-3 (ratio {ratio:.2})"
            );
        }
    }
}

// ---------------------------------------------------------------------------------------
// A rigidly translating pinned sheet.

#[test]
fn a_translating_pinned_border_drags_a_moving_sheet_along_exactly() {
    // An 8 x 8 lab grid, its border pinned and moved at v; the free particles start at v
    // too, no gravity, springs at rest: the exact motion is the rigid translation, which
    // every step reproduces (the springs stay at rest, the inertial prediction is the
    // minimizer) to round-off, damping included.
    let v = DVec3::new(0.3, -0.2, 0.1);
    let mut grid = ClothGrid::lab_sized(8, 0.1);
    grid.fixed = (0..8)
        .flat_map(|i| (0..8).map(move |j| (i, j)))
        .filter(|&(i, j)| i == 0 || j == 0 || i == 7 || j == 7)
        .collect();
    grid.material = Material {
        stiffness: 200.0,
        damping: 0.5,
        gravity: DVec3::ZERO,
    };
    let mut system = grid.build().unwrap();
    let x0 = system.positions().to_vec();
    let velocities = vec![v; system.len()];
    system.set_state(&x0, &velocities).unwrap();
    let pinned: Vec<usize> = (0..system.len()).filter(|&i| system.fixed()[i]).collect();
    for integrator in [
        Integrator::BackwardEuler(NewtonSettings::default()),
        Integrator::Bdf2(NewtonSettings::default()),
        Integrator::ImplicitMidpoint(NewtonSettings::default()),
    ] {
        let mut sim = Simulation::new(system.clone(), integrator).unwrap();
        sim.set_pinned_motion(vec![PinnedMotion::translation(pinned.clone(), v)])
            .unwrap();
        let h = 1.0 / 60.0;
        for step in 1..=30 {
            sim.step(h).unwrap();
            let t = step as f64 * h;
            for (i, (x, w)) in sim
                .system()
                .positions()
                .iter()
                .zip(sim.system().velocities())
                .enumerate()
            {
                assert!(
                    (*x - (x0[i] + v * t)).length() < 1e-12 && (*w - v).length() < 1e-10,
                    "{integrator:?}, step {step}, particle {i}: at {x}, velocity {w}"
                );
            }
        }
        // The kinetic energy reported counts the pinned particles at their velocity.
        let total_mass: f64 = sim.system().masses().iter().sum();
        let kinetic = sim.system().energies().kinetic;
        assert!((kinetic - 0.5 * total_mass * v.length_squared()).abs() < 1e-9 * kinetic);
    }
}

#[test]
fn a_pinned_corner_turned_about_an_axis_lands_on_its_circle() {
    // A rotation: a pinned particle at distance 1 from the axis through the origin
    // along +z, turned at pi/3 rad/s for 3 s (half a turn), is at (-1, 0, 0) up to
    // round-off, whatever the free particle does.
    let particles = [
        Particle {
            fixed: true,
            ..Particle::at_rest(DVec3::X, 1.0)
        },
        Particle::at_rest(DVec3::new(1.0, -1.0, 0.0), 1.0),
    ];
    let material = Material {
        stiffness: 50.0,
        damping: 0.1,
        gravity: DVec3::ZERO,
    };
    let system = SpringSystem::new(&particles, &[SpringSpec::between(0, 1)], material).unwrap();
    let mut sim = Simulation::new(system, Integrator::default()).unwrap();
    let turn = PinnedMotion::rotation(vec![0], DVec3::ZERO, DVec3::Z, std::f64::consts::PI / 3.0);
    sim.set_pinned_motion(vec![turn]).unwrap();
    for _ in 0..180 {
        sim.step(1.0 / 60.0).unwrap();
    }
    let x = sim.system().positions()[0];
    assert!((x - DVec3::new(-1.0, 0.0, 0.0)).length() < 1e-12, "{x}");
    // The speed of a point at radius 1 turning at pi/3 rad/s, up to the chord's
    // shortfall over one step (the velocity is the step's displacement / h).
    let speed = sim.system().velocities()[0].length();
    let chord = 2.0 * (std::f64::consts::PI / 360.0).sin() * 60.0;
    assert!((speed - chord).abs() < 1e-9, "{speed} vs {chord}");
}

// ---------------------------------------------------------------------------------------
// Bad input.

fn two_particles() -> SpringSystem {
    let particles = [
        Particle {
            fixed: true,
            ..Particle::at_rest(DVec3::ZERO, 1.0)
        },
        Particle::at_rest(DVec3::X, 1.0),
    ];
    SpringSystem::new(&particles, &[SpringSpec::between(0, 1)], Material::earth()).unwrap()
}

/// Pinned particles and their end-of-step positions.
type Targets<'a> = &'a [(usize, DVec3)];

#[test]
fn bad_targets_and_motions_are_errors_naming_the_particle() {
    let system = two_particles();
    let mut be = sinew_spring_sim::BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
    let pin_error = |e: StepError| match e {
        StepError::Invalid(ModelError::BadPin { particle, .. }) => particle,
        other => panic!("not a pin error: {other}"),
    };
    let cases: [(Targets, usize, &str); 4] = [
        (&[(1, DVec3::Y)], 1, "not pinned"),
        (&[(5, DVec3::Y)], 5, "no such particle"),
        (&[(0, DVec3::Y), (0, DVec3::X)], 0, "given twice"),
        (&[(0, DVec3::new(f64::NAN, 0.0, 0.0))], 0, "not finite"),
    ];
    for (targets, particle, words) in cases {
        let mut s = system.clone();
        let e = step_to_targets(&mut be, &mut s, 0.01, targets, 4).unwrap_err();
        assert!(e.to_string().contains(words), "{e}");
        assert!(
            e.to_string().contains(&format!("particle {particle}")),
            "{e}"
        );
        assert_eq!(pin_error(e), particle);
        // Nothing changed.
        assert_eq!(s.positions(), system.positions());
        assert_eq!(s.velocities(), system.velocities());
    }
    // Motions: not pinned, a zero axis, a NaN rate, an empty group, two groups sharing
    // a particle.
    let bad = [
        (PinnedMotion::translation(vec![1], DVec3::X), "not pinned"),
        (
            PinnedMotion::rotation(vec![0], DVec3::ZERO, DVec3::ZERO, 1.0),
            "axis",
        ),
        (
            PinnedMotion::rotation(vec![0], DVec3::ZERO, DVec3::Y, f64::NAN),
            "angular_speed",
        ),
        (
            PinnedMotion::translation(vec![], DVec3::X),
            "at least one particle",
        ),
    ];
    for (motion, words) in bad {
        let e = PinDriver::new(&system, vec![motion]).unwrap_err();
        assert!(
            matches!(e, ModelError::BadPin { .. }) && e.to_string().contains(words),
            "{e}"
        );
    }
    let twice = vec![
        PinnedMotion::translation(vec![0], DVec3::X),
        PinnedMotion::translation(vec![0], DVec3::Y),
    ];
    let e = PinDriver::new(&system, twice).unwrap_err();
    assert!(
        e.to_string().contains("pinned particle 0") && e.to_string().contains("twice"),
        "{e}"
    );
    // The explicit integrators refuse moving pins.
    let mut sim = Simulation::new(
        system.clone(),
        Integrator::VelocityVerlet { substeps: None },
    )
    .unwrap();
    let e = sim
        .set_pinned_motion(vec![PinnedMotion::translation(vec![0], DVec3::X)])
        .unwrap_err();
    assert!(e.to_string().contains("implicit integrator"), "{e}");
    let e = sim.step_to(0.01, &[(0, DVec3::X)]).unwrap_err();
    assert!(e.to_string().contains("implicit integrator"), "{e}");
}

// ---------------------------------------------------------------------------------------
// A pinned sheet pushed through a free one.

/// An `n x n` grid of points `origin + i s u + j s w` and its triangles, indices offset.
fn grid(n: usize, origin: DVec3, s: f64, offset: usize) -> (Vec<DVec3>, Vec<[usize; 3]>) {
    let x = (0..n)
        .flat_map(|i| (0..n).map(move |j| origin + s * DVec3::new(i as f64, 0.0, j as f64)))
        .collect();
    let grid = ClothGrid {
        size: n,
        ..ClothGrid::lab()
    };
    let t = grid
        .triangles()
        .into_iter()
        .map(|t| t.map(|v| v + offset))
        .collect();
    (x, t)
}

#[test]
fn a_pinned_sheet_pushed_through_a_free_sheet_never_crosses_it() {
    // A free 6 x 6 sheet (its corners pinned, still) at y = 0 and a fully pinned 4 x 4
    // sheet 1 cm above its middle, moved down at 0.9 m/s: one step of 1/60 s would carry
    // it 1.5 cm, through the free sheet. The move is cut into pieces while it is not
    // safe; the free sheet is pushed down and, held at its corners, stretched until the
    // moving sheet cannot go on without crossing, and the step is refused. At every
    // accepted state no two triangles meet (the exact check) and no gap closed.
    let (mut x, mut triangles) = grid(6, DVec3::ZERO, 0.02, 0);
    let (xb, tb) = grid(4, DVec3::new(0.021, 0.01, 0.021), 0.02, 36);
    x.extend(xb);
    triangles.extend(tb);
    let mut fixed: Vec<usize> = vec![0, 5, 30, 35];
    fixed.extend(36..52);
    let mesh = TriangleMesh::new(x, triangles.clone()).unwrap();
    let model = MeshCloth {
        areal_density: 0.2,
        material: Material {
            stiffness: 50.0,
            damping: 0.1,
            gravity: DVec3::ZERO,
        },
        bending: Bending::None,
        fixed,
    }
    .build(&mesh)
    .unwrap();
    let mut be = model.backward_euler(NewtonSettings::default()).unwrap();
    let settings = SelfContactSettings {
        dhat: 2e-3,
        thickness: 1e-3,
        ..SelfContactSettings::default()
    };
    model.enable_self_contact(&mut be, settings).unwrap();
    let mut system = model.system.clone();
    let mut driver = PinDriver::new(
        &system,
        vec![PinnedMotion::translation(
            (36..52).collect(),
            DVec3::new(0.0, -0.9, 0.0),
        )],
    )
    .unwrap();
    // The pieces of the pinned motion are one step: the record holds all of them, and
    // each piece's end state is checked too.
    be.record_piece_ends(true);
    let mut split = false;
    let mut refused = false;
    for step in 0..60 {
        let before = (system.positions().to_vec(), system.velocities().to_vec());
        match driver.step(&mut be, &mut system, 1.0 / 60.0) {
            Ok(report) => {
                split |= report.pieces > 1;
                let x = system.positions();
                let bad = intersecting_pairs(x, &triangles);
                assert!(bad.is_empty(), "step {step}: triangles {bad:?} meet");
                let record = be.piece_ends().unwrap();
                assert_eq!(record.len(), report.pieces, "step {step}");
                assert_eq!(record.get(record.len() - 1).unwrap().1, x, "step {step}");
                for (k, (_, y)) in record.iter().enumerate() {
                    let bad = intersecting_pairs(y, &triangles);
                    assert!(bad.is_empty(), "step {step}, piece {k}: {bad:?} meet");
                }
            }
            Err(e) => {
                assert!(
                    matches!(e, StepError::PinnedMove { .. }),
                    "step {step}: {e}"
                );
                assert_eq!(
                    system.positions(),
                    &before.0[..],
                    "step {step}: state changed"
                );
                assert_eq!(system.velocities(), &before.1[..]);
                assert!(
                    be.piece_ends().unwrap().is_empty(),
                    "step {step}: refused, recorded"
                );
                refused = true;
                break;
            }
        }
    }
    assert!(
        split,
        "the move was never cut into pieces: the test does not test"
    );
    assert!(
        refused,
        "the pinned sheet went on for 60 steps (0.9 m) through a sheet held at its corners"
    );
}
