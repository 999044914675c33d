//! Contact in the integrators: a particle settling on the ground, a sheet on an inclined
//! plane held by friction or sliding with Coulomb's acceleration, an independent check
//! that no accepted state has a particle inside a collider over whole runs (static,
//! spinning and moving colliders), the explicit projection, and the refusals.

use crate::common::{
    G, assert_coulomb_landing, contact_material, contact_sheet, incline_run, outside_colliders,
};
use sinew_math::DVec3;
use sinew_spring_sim::contact::{Collider, ContactSettings};
use sinew_spring_sim::{Integrator, NewtonSettings, Particle, Simulation, SpringSystem, StepError};

const H: f64 = 1.0 / 60.0;

fn backward_euler() -> Integrator {
    Integrator::BackwardEuler(NewtonSettings::default())
}

#[test]
fn a_particle_settles_on_the_ground_within_dhat() {
    let particle = Particle::at_rest(DVec3::new(0.0, 0.02, 0.0), 5e-4);
    let system = SpringSystem::new(&[particle], &[], contact_material()).unwrap();
    let mut sim = Simulation::new(system, backward_euler()).unwrap();
    let settings = ContactSettings::default();
    sim.set_contact(vec![Collider::ground(0.0)], settings)
        .unwrap();
    for step in 0..180 {
        let report = sim.step(H).unwrap();
        assert!(
            report.residual <= report.tolerance,
            "step {step}: {report:?}"
        );
        let y = sim.system().positions()[0].y;
        assert!(y > 0.0, "step {step}: particle at y = {y}");
    }
    let y = sim.system().positions()[0].y;
    let v = sim.system().velocities()[0];
    assert!(y > 0.0 && y < settings.dhat, "rests at {y}");
    assert!(v.length() < 1e-6, "still moving at {v}");
    // At rest the barrier holds the weight: kappa |b'(y)| = m g.
    let kappa = sim.contact_kappa().unwrap();
    let force =
        -kappa * sinew_spring_sim::contact::barrier::barrier_first_derivative(y, settings.dhat);
    assert!(
        (force - 5e-4 * G).abs() <= 1e-6 * 5e-4 * G,
        "barrier force {force}"
    );
    let (min, pairs) = sim.contact_distances().unwrap();
    assert_eq!(min, y);
    assert_eq!(pairs, 1);
}

/// A particle 1 cm above the ground moving at (1, -1, 0) m/s reaches it within one step
/// of 1/60 s, friction `mu` 0.3 and `lags` lags a step: the step's report and the
/// particle's velocity after it (every state above the ground).
fn land(lags: usize) -> (sinew_spring_sim::StepReport, DVec3) {
    land_with(Integrator::BackwardEuler, lags)
}

/// [`land`] with the implicit integrator `scheme`.
fn land_with(
    scheme: fn(NewtonSettings) -> Integrator,
    lags: usize,
) -> (sinew_spring_sim::StepReport, DVec3) {
    land_on(scheme, lags, 0.3)
}

/// [`land_with`] with friction `mu`.
fn land_on(
    scheme: fn(NewtonSettings) -> Integrator,
    lags: usize,
    mu: f64,
) -> (sinew_spring_sim::StepReport, DVec3) {
    let particle = Particle {
        velocity: DVec3::new(1.0, -1.0, 0.0),
        ..Particle::at_rest(DVec3::new(0.0, 0.01, 0.0), 5e-4)
    };
    let system = SpringSystem::new(&[particle], &[], contact_material()).unwrap();
    let settings = NewtonSettings {
        friction_lags: lags,
        ..NewtonSettings::default()
    };
    let mut sim = Simulation::new(system, scheme(settings)).unwrap();
    let contact = ContactSettings {
        mu,
        ..ContactSettings::default()
    };
    sim.set_contact(vec![Collider::ground(0.0)], contact)
        .unwrap();
    let report = sim.step(H).unwrap();
    assert!(report.residual <= report.tolerance, "{report:?}");
    let y = sim.system().positions()[0].y;
    assert!(y > 0.0 && y < contact.dhat, "landed at {y}");
    (report, sim.system().velocities()[0])
}

#[test]
fn friction_lagged_again_acts_in_the_step_a_particle_lands() {
    // The flat ground's normal does not depend on the friction, so the second round's
    // normal force is already the last one's.
    let (once, v_once) = land(1);
    let (again, v) = land(4);
    assert_coulomb_landing(0.3, H, (&once, v_once), (&again, v), 1e-12);
    assert!(v.z.abs() <= 1e-12, "{v}");
}

#[test]
fn friction_lagged_again_can_stop_a_landing_particle() {
    // With `mu` 5 Coulomb's share of the normal impulse is more than the tangential
    // velocity: friction lagged again holds the particle where it lands (static friction,
    // smoothed below `eps_v`). With the new lag `g` is higher at the first round's
    // minimizer than at x_n (that round slid 1.7 cm along the ground), so the second
    // round starts again from x_n.
    let (_, once) = land_on(Integrator::BackwardEuler, 1, 5.0);
    assert!((once.x - 1.0).abs() <= 1e-12, "{once}");
    let (again, v) = land_on(Integrator::BackwardEuler, 4, 5.0);
    assert!(again.friction_relags >= 1, "{again:?}");
    assert!(again.friction_restarts >= 1, "{again:?}");
    println!("mu 5 landing: v {v}");
    let eps_v = ContactSettings::default().eps_v;
    assert!(v.x.abs() < eps_v, "{v}");
}

#[test]
fn friction_lagged_again_acts_in_the_landing_step_of_the_midpoint() {
    // The midpoint lags friction over its end state (docs/contact.md), and its forces act
    // at the midpoint for the whole step: `m (v' - v)/h` is the barrier's normal force
    // there less gravity, and Coulomb's `-mu lambda` along the slide, so the same law
    // holds with the midpoint's own velocities. (BDF2's first step is this step.)
    let (_, once) = land_with(Integrator::ImplicitMidpoint, 1);
    assert!((once.x - 1.0).abs() <= 1e-12, "{once}");
    let (again, v) = land_with(Integrator::ImplicitMidpoint, 4);
    assert!(again.friction_relags >= 1, "{again:?}");
    assert_eq!(
        again.friction_restarts, 0,
        "the midpoint's rounds start at the minimizer"
    );
    let expected = 1.0 - 0.3 * (v.y - (-1.0) + G * H);
    println!("midpoint landing: v {v}, v_x expected {expected}");
    assert!((v.x - expected).abs() <= 1e-6, "{} vs {expected}", v.x);
}

#[test]
fn friction_holds_a_sheet_on_an_incline_when_mu_exceeds_tan_theta() {
    let theta = 30f64.to_radians();
    let speeds = incline_run(backward_euler(), theta, 0.8, 60, H);
    // Static friction is smoothed below eps_v = 1e-3: the sheet may creep, no faster.
    let eps_v = ContactSettings::default().eps_v;
    for (step, s) in speeds.iter().enumerate().skip(5) {
        assert!(s.abs() < eps_v, "step {step}: creeping at {s}");
    }
}

#[test]
fn a_sheet_slides_with_coulomb_acceleration_when_mu_is_below_tan_theta() {
    let theta = 30f64.to_radians();
    let mu = 0.2;
    let speeds = incline_run(backward_euler(), theta, mu, 60, H);
    let expected = G * (theta.sin() - mu * theta.cos());
    // Backward Euler gives a constant acceleration exactly; skip the first steps while the
    // lagged normal force settles.
    let (a, b) = (20, 59);
    let measured = (speeds[b] - speeds[a]) / ((b - a) as f64 * H);
    println!("incline: measured {measured}, expected {expected}");
    assert!(
        (measured - expected).abs() <= 1e-3 * expected,
        "measured {measured} vs g (sin - mu cos) = {expected}"
    );
}

#[test]
fn no_accepted_state_has_a_particle_inside_a_collider() {
    // A 10 x 10 sheet dropped onto a spinning sphere, a capsule sliding under it and the
    // ground, with friction.
    let system = contact_sheet(10, 0.05, DVec3::new(0.0, 0.4, 0.0), DVec3::X, DVec3::Z);
    let mut sim = Simulation::new(system, backward_euler()).unwrap();
    let colliders = vec![
        Collider::ground(0.0),
        Collider::sphere(DVec3::new(0.2, 0.15, 0.2), 0.12)
            .moving(DVec3::ZERO, DVec3::new(0.0, std::f64::consts::PI, 0.0)),
        Collider::capsule(
            DVec3::new(-0.2, 0.05, 0.35),
            DVec3::new(0.6, 0.05, 0.35),
            0.04,
        )
        .moving(DVec3::new(0.0, 0.0, -0.05), DVec3::ZERO),
    ];
    let settings = ContactSettings {
        mu: 0.3,
        ..ContactSettings::default()
    };
    sim.set_contact(colliders.clone(), settings).unwrap();
    let mut min_seen = f64::INFINITY;
    let mut touched = [false; 3];
    for step in 0..90 {
        sim.step(H).unwrap();
        let t = sim.time();
        let nearest = outside_colliders(
            &colliders,
            t,
            sim.system().positions(),
            &format!("step {step}"),
        );
        for (c, d) in nearest.into_iter().enumerate() {
            min_seen = min_seen.min(d);
            touched[c] |= d < settings.dhat;
        }
    }
    println!("smallest distance over the run: {min_seen}");
    assert!(
        touched[0] && touched[1],
        "the run never reached the ground and the sphere: {touched:?}"
    );
}

#[test]
fn explicit_projection_keeps_particles_out() {
    let particle = Particle {
        position: DVec3::new(0.0, 0.1, 0.0),
        velocity: DVec3::new(1.0, -2.0, 0.0),
        mass: 1.0,
        fixed: false,
    };
    let system = SpringSystem::new(&[particle], &[], contact_material()).unwrap();
    let mut sim = Simulation::new(system, Integrator::SymplecticEuler { substeps: 4 }).unwrap();
    sim.set_contact(
        vec![Collider::ground(0.0)],
        ContactSettings {
            mu: 0.5,
            ..ContactSettings::default()
        },
    )
    .unwrap();
    assert_eq!(sim.contact_kappa(), None);
    for _ in 0..60 {
        sim.step(H).unwrap();
        assert!(sim.system().positions()[0].y >= 0.0);
    }
    assert!(sim.contact_projections() > 0);
    let v = sim.system().velocities()[0];
    // On the ground: no normal velocity after the last projection, and friction has
    // stopped the sliding (mu g h per step against 1 m/s: about 12 steps).
    assert_eq!(v.y, 0.0);
    assert_eq!(v.x, 0.0);
}

#[test]
fn refusals_name_what_is_wrong() {
    let particle = Particle::at_rest(DVec3::new(0.0, 0.01, 0.0), 1.0);
    let system = SpringSystem::new(&[particle], &[], contact_material()).unwrap();
    {
        let mut sim = Simulation::new(system.clone(), Integrator::FlawedReportMethod).unwrap();
        let err = sim
            .set_contact(vec![Collider::ground(0.0)], ContactSettings::default())
            .unwrap_err();
        assert!(err.to_string().contains("not supported"), "{err}");
    }
    let mut sim = Simulation::new(system.clone(), backward_euler()).unwrap();
    let err = sim
        .set_contact(
            vec![Collider::ground(0.0), Collider::sphere(DVec3::ZERO, 0.0)],
            ContactSettings::default(),
        )
        .unwrap_err();
    assert!(
        err.to_string().starts_with("collider 1 (sphere): radius"),
        "{err}"
    );
    // A sphere coming down at 6 m/s onto a particle 0.01 above the ground: carried
    // with the sphere it would end inside the ground, so the step is refused.
    let falling = Collider::sphere(DVec3::new(0.0, 0.5, 0.0), 0.45)
        .moving(DVec3::new(0.0, -6.0, 0.0), DVec3::ZERO);
    sim.set_contact(
        vec![Collider::ground(0.0), falling],
        ContactSettings::default(),
    )
    .unwrap();
    let before = sim.system().clone();
    let err = sim.step(H).unwrap_err();
    assert!(
        matches!(
            err,
            StepError::Contact {
                particle: 0,
                collider: 0
            }
        ),
        "{err}"
    );
    assert_eq!(sim.system(), &before, "a refused step changes nothing");
}

#[test]
fn a_rising_platform_carries_a_resting_particle() {
    // Ground rising at 0.5 m/s under a particle resting on it: the particle rides along,
    // never inside, at the platform's speed once settled.
    let particle = Particle::at_rest(DVec3::new(0.0, 5e-4, 0.0), 5e-4);
    let system = SpringSystem::new(&[particle], &[], contact_material()).unwrap();
    let mut sim = Simulation::new(system, backward_euler()).unwrap();
    let platform = Collider::ground(0.0).moving(DVec3::new(0.0, 0.5, 0.0), DVec3::ZERO);
    sim.set_contact(vec![platform], ContactSettings::default())
        .unwrap();
    for step in 0..120 {
        sim.step(H).unwrap();
        let gap = sim.system().positions()[0].y - 0.5 * sim.time();
        assert!(gap > 0.0, "step {step}: particle {gap} below the platform");
    }
    let v = sim.system().velocities()[0];
    assert!((v.y - 0.5).abs() < 1e-4, "rides at {v}");
    let gap = sim.system().positions()[0].y - 0.5 * sim.time();
    assert!(gap < ContactSettings::default().dhat, "gap {gap}");
}

#[test]
fn friction_carries_a_particle_on_a_turntable() {
    // A half-space spinning about its normal at 1 rad/s under a particle 0.1 from the
    // axis, mu = 0.5 (mu g = 4.9 far above the centripetal 0.1 m/s^2 needed): friction
    // brings the particle to the surface's speed omega r = 0.1 m/s. Measured slip after
    // 3 s: 1.7e-3 m/s, of the order of the smoothing eps_v = 1e-3 m/s plus the lag's error
    // (the surface's displacement over a step is taken along its velocity at the step's
    // start, a chord error of h^2 omega^2 r / 2 = 1.4e-5 m per step, 8e-4 m/s).
    let particle = Particle::at_rest(DVec3::new(0.1, 5e-4, 0.0), 5e-4);
    let system = SpringSystem::new(&[particle], &[], contact_material()).unwrap();
    let mut sim = Simulation::new(system, backward_euler()).unwrap();
    let turntable = Collider::ground(0.0).moving(DVec3::ZERO, DVec3::new(0.0, 1.0, 0.0));
    let settings = ContactSettings {
        mu: 0.5,
        ..ContactSettings::default()
    };
    sim.set_contact(vec![turntable], settings).unwrap();
    for _ in 0..180 {
        sim.step(H).unwrap();
    }
    let x = sim.system().positions()[0];
    let v = sim.system().velocities()[0];
    let surface = DVec3::new(0.0, 1.0, 0.0).cross(x);
    let slip = (v - surface).length();
    println!(
        "turntable: speed {}, surface {}, slip {slip}",
        v.length(),
        surface.length()
    );
    assert!(slip < 2.0 * settings.eps_v, "slip {slip} at {x}, v {v}");
    assert!(
        (x.length() - 0.1).abs() < 5e-3,
        "drifted to radius {}",
        x.length()
    );
}

#[test]
fn kappa_starts_at_the_balance_of_a_spring_pressing_a_particle_onto_the_ground() {
    // A particle at rest 0.5 mm above the ground (within dhat = 1 mm), pressed down by a
    // spring of stiffness 1 N/m compressed from 0.2 m to 0.0995 m against a fixed
    // particle above it. The forces the barrier must hold: the spring's k (L0 - l) and
    // the weight m g, so the balancing start is kappa = (k (L0 - l) + m g) / |b'(d)|,
    // well above kappa_min (the minimum holds m (g + dhat/h^2) at dhat/2).
    let (m, d, top, rest, k) = (5e-4, 5e-4, 0.1, 0.2, 1.0);
    let mut anchor = Particle::at_rest(DVec3::new(0.0, top, 0.0), m);
    anchor.fixed = true;
    let pressed = Particle::at_rest(DVec3::new(0.0, d, 0.0), m);
    let spring = sinew_spring_sim::SpringSpec {
        rest_length: Some(rest),
        stiffness: Some(k),
        ..sinew_spring_sim::SpringSpec::between(0, 1)
    };
    let system = SpringSystem::new(&[anchor, pressed], &[spring], contact_material()).unwrap();
    let mut sim = Simulation::new(system, backward_euler()).unwrap();
    let settings = ContactSettings::default();
    sim.set_contact(vec![Collider::ground(0.0)], settings)
        .unwrap();
    sim.step(H).unwrap();
    let b1 = sinew_spring_sim::contact::barrier::barrier_first_derivative(d, settings.dhat);
    let expected = (k * (rest - (top - d)) + m * G) / -b1;
    let kmin = sinew_spring_sim::contact::barrier::minimum_kappa(settings.dhat, m, G, H);
    assert!(
        expected > 2.0 * kmin && expected < 100.0 * kmin,
        "{expected} vs {kmin}"
    );
    let kappa = sim.contact_kappa().unwrap();
    assert!(
        (kappa - expected).abs() <= 1e-9 * expected,
        "kappa {kappa} vs the balance {expected}"
    );
    // Balanced at the start, the particle barely moves: it stays near 0.5 mm.
    let y = sim.system().positions()[1].y;
    assert!((y - d).abs() < 0.1 * d, "moved to {y}");
}
