//! Kinematic colliders that travel about their own size in a step: a sphere rising
//! through a sheet and a capsule turning through one must push the cloth, not pass
//! through it. Checked here independently of the library: every particle's straight
//! path from one accepted state to the next is sampled against the collider posed at
//! the same times (distances from the shape's fields), and must not go deeper into it
//! than the allowance the integrators grant (`dhat`).

use crate::common::independent_distance;
use sinew_math::DVec3;
use sinew_spring_sim::contact::{Collider, ContactSettings};
use sinew_spring_sim::{
    ClothGrid, Integrator, Material, NewtonSettings, Particle, Simulation, SpringSystem,
};

const H: f64 = 1.0 / 60.0;
/// Samples per path: at 1 m a step the sphere moves 0.25 mm between samples.
const SAMPLES: usize = 4000;

/// The three implicit schemes, named for messages, with `max_split_depth` as given.
fn schemes(max_split_depth: usize) -> [(&'static str, Integrator); 3] {
    let s = NewtonSettings {
        max_split_depth,
        ..NewtonSettings::default()
    };
    [
        ("backward Euler", Integrator::BackwardEuler(s)),
        ("BDF2", Integrator::Bdf2(s)),
        ("implicit midpoint", Integrator::ImplicitMidpoint(s)),
    ]
}

/// A 9 x 9 sheet at rest in the plane y = 0, spacing 5 cm, centred on the origin, 1 kg
/// a particle, soft springs (1 N/m) and no gravity, so only the collider moves it.
fn sheet() -> SpringSystem {
    let n = 9;
    let mut particles = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let p = DVec3::new(0.05 * i as f64 - 0.2, 0.0, 0.05 * j as f64 - 0.2);
            particles.push(Particle::at_rest(p, 1.0));
        }
    }
    let material = Material {
        stiffness: 1.0,
        damping: 0.0,
        gravity: DVec3::ZERO,
    };
    SpringSystem::new(&particles, &ClothGrid::spring_pattern(n), material).unwrap()
}

/// The deepest any particle's straight path from `from` (at `t0`) to `to` (at `t0 + h`)
/// goes into `collider` posed at the same times (negative inside), and the particle.
fn deepest_on_paths(collider: &Collider, t0: f64, from: &[DVec3], to: &[DVec3]) -> (f64, usize) {
    let mut deepest = (f64::INFINITY, 0);
    for (i, (&p, &q)) in from.iter().zip(to).enumerate() {
        for k in 0..=SAMPLES {
            let s = k as f64 / SAMPLES as f64;
            let d = independent_distance(collider, t0 + s * H, p.lerp(q, s));
            if d < deepest.0 {
                deepest = (d, i);
            }
        }
    }
    deepest
}

/// Runs `steps` steps of the sheet against `collider` with `integrator`; returns the
/// deepest any straight path between two states went into the collider, the total
/// [`sinew_spring_sim::StepReport::swept_passes`], the largest number of pieces a step
/// took, and the final positions. Every state is checked strictly outside.
fn run(
    name: &str,
    integrator: Integrator,
    collider: Collider,
    steps: usize,
) -> (f64, usize, usize, Vec<DVec3>) {
    let mut sim = Simulation::new(sheet(), integrator).unwrap();
    sim.set_contact(vec![collider], ContactSettings::default())
        .unwrap();
    let (mut deepest, mut passes, mut pieces) = (f64::INFINITY, 0, 0);
    for step in 0..steps {
        let (t0, before) = (sim.time(), sim.system().positions().to_vec());
        let report = sim.step(H).unwrap();
        let after = sim.system().positions();
        for (i, &x) in after.iter().enumerate() {
            let d = independent_distance(&collider, sim.time(), x);
            assert!(
                d > 0.0,
                "{name}, step {step}: particle {i} inside (d = {d})"
            );
        }
        let (d, i) = deepest_on_paths(&collider, t0, &before, after);
        println!(
            "{name}, step {step}: {} pieces, deepest path {d:.3e} (particle {i}), swept passes {}",
            report.pieces, report.swept_passes
        );
        deepest = deepest.min(d);
        passes += report.swept_passes;
        pieces = pieces.max(report.pieces);
    }
    (deepest, passes, pieces, sim.system().positions().to_vec())
}

/// A sphere of radius 0.1 starting 1 cm below the sheet's middle and rising at `speed`.
fn rising_sphere(speed: f64) -> Collider {
    Collider::sphere(DVec3::new(0.0, -0.11, 0.0), 0.1)
        .moving(DVec3::new(0.0, speed, 0.0), DVec3::ZERO)
}

/// The middle particle of the 9 x 9 sheet.
const MIDDLE: usize = 40;

#[test]
fn a_sphere_rising_through_a_sheet_within_a_step_lifts_it() {
    // At 24 and 60 m/s the sphere travels 2 and 5 of its diameters a step: the end-pose
    // minimization alone left the sheet flat behind it. Split until no path passes, the
    // sheet rides on it in every scheme.
    let dhat = ContactSettings::default().dhat;
    for speed in [1.5, 3.0, 6.0, 12.0, 24.0, 60.0] {
        for (name, integrator) in schemes(NewtonSettings::default().max_split_depth) {
            let name = format!("{name} at {speed} m/s");
            let steps = 3;
            let (deepest, passes, pieces, end) =
                run(&name, integrator, rising_sphere(speed), steps);
            assert_eq!(passes, 0, "{name}: a step kept a pass");
            assert!(
                deepest > -dhat,
                "{name}: a straight path went {deepest} into the sphere"
            );
            if speed > 10.0 {
                assert!(pieces > 1, "{name}: the pass was found without splitting");
            }
            // The middle particle is above the sphere: carried on it (backward Euler),
            // or thrown ahead of it by the barrier's rebound (the less dissipative BDF2
            // and midpoint), never left behind.
            let top = -0.11 + speed * steps as f64 * H + 0.1;
            let y = end[MIDDLE].y;
            println!(
                "{name}: the middle particle {:.4} above the sphere's top",
                y - top
            );
            assert!(
                y > top,
                "{name}: the middle particle at y = {y}, the sphere's top at {top}"
            );
        }
    }
}

#[test]
fn without_splitting_a_pass_is_reported_not_hidden() {
    // With splitting off the step cannot be resolved: the sphere passes through the
    // sheet, and the report says so.
    for (name, integrator) in schemes(0) {
        let (deepest, passes, _, end) = run(name, integrator, rising_sphere(60.0), 1);
        assert!(deepest < -0.05, "{name}: deepest path {deepest}");
        assert_eq!(passes, 1, "{name}");
        assert!(end[MIDDLE].y.abs() < 1e-9, "{name}: the sheet stayed flat");
    }
}

/// A paddle (a capsule 0.3 long, radius 0.03) 1 cm below the sheet, turning at 30 rad/s
/// about the z axis through its middle: its tips move 7.5 cm a step, more than its
/// diameter, and one rises through the sheet's plane within three steps.
fn paddle() -> Collider {
    Collider::capsule(
        DVec3::new(-0.15, -0.04, 0.0),
        DVec3::new(0.15, -0.04, 0.0),
        0.03,
    )
    .moving(DVec3::ZERO, DVec3::new(0.0, 0.0, 30.0))
}

#[test]
fn without_splitting_a_turning_paddle_passes_and_it_is_reported() {
    for (name, integrator) in schemes(0) {
        let (deepest, passes, _, _) = run(name, integrator, paddle(), 4);
        assert!(deepest < -0.01, "{name}: deepest path {deepest}");
        assert!(passes >= 1, "{name}");
    }
}

#[test]
fn a_capsule_turning_through_a_sheet_pushes_it() {
    // The turning shape's time of impact is the conservative advancement, not a closed
    // form.
    let dhat = ContactSettings::default().dhat;
    let paddle = paddle();
    for (name, integrator) in schemes(NewtonSettings::default().max_split_depth) {
        let (deepest, passes, pieces, end) = run(name, integrator, paddle, 4);
        assert_eq!(passes, 0, "{name}: a step kept a pass");
        assert!(
            deepest > -dhat,
            "{name}: a path went {deepest} into the paddle"
        );
        assert!(pieces > 1, "{name}: no step was split");
        // The rising arm (x > 0) has lifted the sheet above its plane.
        let lifted = end.iter().map(|p| p.y).fold(f64::NEG_INFINITY, f64::max);
        assert!(lifted > 0.05, "{name}: highest particle at {lifted}");
    }
}
