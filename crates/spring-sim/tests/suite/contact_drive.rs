//! Colliders steered as the run goes ([`Drive`]): the pose is kept where the motion
//! changes, a target pose is reached, bad drives are refused by name, a drive reaches
//! the integrators' barrier and the explicit projection alike, and a capsule driven
//! along an animated limb lifts a sheet without a particle ever inside it (checked
//! against the animation's own capsule, with distances from its fields).

use crate::common::{contact_sheet, independent_distance};
use sinew_math::{DQuat, DVec3};
use sinew_spring_sim::contact::{Collider, ContactError, ContactSettings, Drive, Motion, Shape};
use sinew_spring_sim::{AutoSettings, Integrator, NewtonSettings, Simulation};
use std::f64::consts::PI;

const H: f64 = 1.0 / 60.0;

/// The largest distance between the corresponding points of two shapes of one kind.
fn pose_gap(x: &Shape, y: &Shape) -> f64 {
    match (*x, *y) {
        (
            Shape::HalfSpace { point, normal },
            Shape::HalfSpace {
                point: p,
                normal: n,
            },
        ) => (point - p).length().max((normal - n).length()),
        (
            Shape::Sphere { center, radius },
            Shape::Sphere {
                center: c,
                radius: r,
            },
        ) => (center - c).length().max((radius - r).abs()),
        (
            Shape::Capsule { a, b, radius },
            Shape::Capsule {
                a: p,
                b: q,
                radius: r,
            },
        ) => (a - p)
            .length()
            .max((b - q).length())
            .max((radius - r).abs()),
        _ => f64::INFINITY,
    }
}

#[test]
fn a_rebased_collider_keeps_its_pose_and_takes_the_new_motion() {
    let spinning = Collider::capsule(DVec3::new(-0.2, 0.1, 0.0), DVec3::new(0.3, 0.2, 0.1), 0.05)
        .moving(DVec3::new(0.4, -0.1, 0.2), DVec3::new(0.0, 2.0, 1.0));
    let t = 0.37;
    let motion = Motion {
        linear_velocity: DVec3::new(-1.0, 0.5, 0.0),
        angular_velocity: DVec3::new(3.0, 0.0, 0.0),
    };
    let rebased = spinning.rebased(t, motion);
    // The same pose at the switch, bit for bit, and the new motion after it.
    assert_eq!(rebased.at(t), spinning.at(t));
    assert_eq!(rebased.pose_time, t);
    let dt = 0.25;
    let Shape::Capsule { a, b, .. } = spinning.at(t) else {
        unreachable!()
    };
    let (mid, turn) = (
        0.5 * (a + b),
        DQuat::from_scaled_axis(motion.angular_velocity * dt),
    );
    let expected = Shape::Capsule {
        a: mid + motion.linear_velocity * dt + turn * (a - mid),
        b: mid + motion.linear_velocity * dt + turn * (b - mid),
        radius: 0.05,
    };
    let gap = pose_gap(&rebased.at(t + dt), &expected);
    assert!(gap < 1e-15, "gap {gap:e}");
    // Stopped: it stays where it was at the switch.
    let stopped = spinning.rebased(t, Motion::STATIC);
    assert_eq!(stopped.at(t + 5.0), spinning.at(t));
}

#[test]
fn a_collider_moved_to_a_target_reaches_it() {
    let capsule = Collider::capsule(DVec3::new(-0.2, 0.0, 0.0), DVec3::new(0.2, 0.0, 0.0), 0.03);
    let (start, end) = (0.5, 0.5 + H);
    // Turns about z through small, large, nearly half and exactly half turns, each with
    // a shift; the target's ends are where the turned segment puts them.
    for angle in [1e-9, 1e-4, 0.3, 2.0, PI - 1e-7, PI] {
        let turn = DQuat::from_rotation_z(angle);
        let shift = DVec3::new(0.05, 0.1, -0.02);
        let target = Shape::Capsule {
            a: shift + turn * DVec3::new(-0.2, 0.0, 0.0),
            b: shift + turn * DVec3::new(0.2, 0.0, 0.0),
            radius: 0.03,
        };
        let moved = capsule.moving_to(start, &target, end).unwrap();
        assert_eq!(moved.at(start), capsule.at(start), "angle {angle}");
        let gap = pose_gap(&moved.at(end), &target);
        assert!(gap < 1e-15, "angle {angle}: gap {gap:e}");
        // The turn is the shortest one: its rate is the angle over the step.
        let rate = moved.motion.angular_velocity.length() * (end - start);
        assert!((rate - angle).abs() < 1e-12, "angle {angle}: turned {rate}");
    }
    // A half-space tilted and raised; a sphere shifted (no turn); a capsule with both
    // ends at one point shifted.
    let ground = Collider::ground(0.0);
    let normal = DVec3::new(0.3, 1.0, -0.2).normalize();
    let tilted = Shape::HalfSpace {
        point: DVec3::new(0.0, 0.1, 0.0),
        normal,
    };
    let gap = pose_gap(
        &ground.moving_to(0.0, &tilted, 1.0).unwrap().at(1.0),
        &tilted,
    );
    assert!(gap < 1e-15, "half-space: gap {gap:e}");
    let ball = Collider::sphere(DVec3::ZERO, 0.1).moving(DVec3::ZERO, DVec3::new(0.0, 5.0, 0.0));
    let there = Shape::Sphere {
        center: DVec3::new(1.0, 2.0, 3.0),
        radius: 0.1,
    };
    let moved = ball.moving_to(0.0, &there, 0.5).unwrap();
    assert_eq!(moved.motion.angular_velocity, DVec3::ZERO);
    assert!(pose_gap(&moved.at(0.5), &there) < 1e-15);
    let dot = Collider::capsule(DVec3::ONE, DVec3::ONE, 0.1);
    let elsewhere = Shape::Capsule {
        a: DVec3::ZERO,
        b: DVec3::ZERO,
        radius: 0.1,
    };
    assert!(
        pose_gap(
            &dot.moving_to(0.0, &elsewhere, 1.0).unwrap().at(1.0),
            &elsewhere
        ) < 1e-15
    );
}

#[test]
fn bad_drives_are_refused_by_name_and_change_nothing() {
    let capsule = Collider::capsule(DVec3::new(-0.2, 0.0, 0.0), DVec3::new(0.2, 0.0, 0.0), 0.03);
    let field_of = |drive: Drive| match capsule.driven(1.0, &drive) {
        Err(ContactError::BadCollider { field, reason, .. }) => (field, reason),
        other => panic!("{drive:?}: {other:?}"),
    };
    let target = |a: DVec3, b: DVec3, radius: f64| Drive::To {
        target: Shape::Capsule { a, b, radius },
        duration: H,
    };
    let (a, b) = (DVec3::new(0.0, 0.1, -0.2), DVec3::new(0.0, 0.1, 0.2));
    assert_eq!(
        field_of(target(a, b, 0.04)).1,
        "has another radius than the collider"
    );
    assert_eq!(
        field_of(target(a, 2.0 * b, 0.03)).1,
        "has another axis length than the collider"
    );
    assert_eq!(field_of(target(a, DVec3::NAN, 0.03)).0, "target");
    assert_eq!(
        field_of(Drive::To {
            target: Shape::Sphere {
                center: DVec3::ZERO,
                radius: 0.03
            },
            duration: H,
        })
        .1,
        "is another kind of shape than the collider"
    );
    for duration in [0.0, -H, f64::NAN, f64::INFINITY] {
        let drive = Drive::To {
            target: Shape::Capsule { a, b, radius: 0.03 },
            duration,
        };
        assert_eq!(field_of(drive).0, "duration");
    }
    let racing = Drive::Motion(Motion {
        linear_velocity: DVec3::new(f64::INFINITY, 0.0, 0.0),
        angular_velocity: DVec3::ZERO,
    });
    assert_eq!(field_of(racing).0, "linear_velocity");
    // A length within round-off of the collider's (a pose from a chain of transforms)
    // is accepted.
    assert!(
        capsule
            .driven(1.0, &target(a, b * (1.0 + 1e-12), 0.03))
            .is_ok()
    );

    // In a simulation: the index is named, and a refused drive leaves the run as it
    // would have been.
    let sheet = || contact_sheet(5, 0.05, DVec3::new(-0.1, 0.05, -0.1), DVec3::X, DVec3::Z);
    let settings = ContactSettings::default();
    let mut plain = Simulation::new(sheet(), Integrator::Bdf2(NewtonSettings::default())).unwrap();
    assert_eq!(
        plain.drive_collider(0, &Drive::Motion(Motion::STATIC)),
        Err(ContactError::NoSuchCollider { index: 0, count: 0 })
    );
    let mut sim = Simulation::new(sheet(), Integrator::Bdf2(NewtonSettings::default())).unwrap();
    let ground = Collider::ground(0.0);
    plain.set_contact(vec![ground, capsule], settings).unwrap();
    sim.set_contact(vec![ground, capsule], settings).unwrap();
    assert_eq!(
        sim.drive_collider(2, &Drive::Motion(Motion::STATIC)),
        Err(ContactError::NoSuchCollider { index: 2, count: 2 })
    );
    let err = sim.drive_collider(1, &target(a, b, 0.04)).unwrap_err();
    assert!(
        matches!(
            err,
            ContactError::BadCollider {
                collider: Some(1),
                field: "target",
                ..
            }
        ),
        "{err:?}"
    );
    assert!(
        err.to_string()
            .starts_with("collider 1 (capsule): target has another radius")
    );
    for _ in 0..10 {
        plain.step(H).unwrap();
        sim.step(H).unwrap();
    }
    assert_eq!(plain.system().positions(), sim.system().positions());
    assert_eq!(plain.colliders(), sim.colliders());
}

/// A collider given its motion by a drive before the first step runs as the same
/// collider built with that motion, bit for bit, in every integrator that takes contact:
/// the drive reaches the barrier term (wherever `auto` keeps it) and the explicit
/// projection alike. Stopped after four steps, the collider stays where it was, and no particle
/// ends a step inside it there.
#[test]
fn a_drive_reaches_every_integrators_contact() {
    let newton = NewtonSettings::default();
    let integrators = [
        ("backward Euler", Integrator::BackwardEuler(newton)),
        ("BDF2", Integrator::Bdf2(newton)),
        ("implicit midpoint", Integrator::ImplicitMidpoint(newton)),
        ("auto", Integrator::Auto(AutoSettings::default())),
        (
            "velocity Verlet",
            Integrator::VelocityVerlet { substeps: None },
        ),
    ];
    let rise = Motion {
        linear_velocity: DVec3::new(0.0, 0.6, 0.0),
        angular_velocity: DVec3::new(0.0, 0.0, 1.0),
    };
    let rest = Collider::capsule(
        DVec3::new(-0.15, -0.04, 0.0),
        DVec3::new(0.15, -0.04, 0.0),
        0.03,
    );
    let moving = rest.moving(rise.linear_velocity, rise.angular_velocity);
    for (name, integrator) in integrators {
        // Runs 30 steps against `collider`, driven by `drive` before step `at`; the
        // smallest distance of a step's end state to the capsule where it should be:
        // `moving` until `stop` (a step index), held from there.
        let run = |collider: Collider, (at, drive): (usize, Drive), stop: Option<usize>| {
            let system = contact_sheet(7, 0.05, DVec3::new(-0.15, 0.0, -0.15), DVec3::X, DVec3::Z);
            let mut sim = Simulation::new(system, integrator).unwrap();
            sim.set_contact(vec![collider], ContactSettings::default())
                .unwrap();
            let (mut lowest, mut held) = (f64::INFINITY, f64::INFINITY);
            for step in 0..30 {
                if step == at {
                    sim.drive_collider(0, &drive).unwrap();
                }
                if Some(step) == stop {
                    held = sim.time();
                }
                sim.step(H).unwrap();
                let there = Collider::fixed(moving.at(sim.time().min(held)));
                for x in sim.system().positions() {
                    lowest = lowest.min(independent_distance(&there, 0.0, *x));
                }
            }
            (
                sim.system().positions().to_vec(),
                sim.colliders()[0],
                lowest,
            )
        };
        let (built, _, _) = run(moving, (0, Drive::Motion(rise)), None);
        let (driven, collider, lowest) = run(rest, (0, Drive::Motion(rise)), None);
        assert_eq!(built, driven, "{name}");
        assert_eq!(collider.motion, rise, "{name}");
        let outside = |lowest: f64| {
            if name == "velocity Verlet" {
                // The projection puts particles on the surface, not strictly outside.
                lowest >= -1e-12
            } else {
                lowest > 0.0
            }
        };
        assert!(outside(lowest), "{name}: a particle at {lowest:e}");
        // The comparison can fail: against the capsule at rest the run differs.
        let (still, _, _) = run(rest, (0, Drive::Motion(Motion::STATIC)), None);
        assert_ne!(still, built, "{name}");
        if name != "velocity Verlet" {
            // The capsule rose 0.3 m under the sheet: the sheet rose with it. (The
            // projection lets the sheet slide off the rod and fall, moving or not.)
            let top = driven.iter().map(|x| x.y).fold(f64::NEG_INFINITY, f64::max);
            assert!(top > 0.2, "{name}: highest particle at {top}");
        }
        let (stopped, collider, lowest) = run(moving, (4, Drive::Motion(Motion::STATIC)), Some(4));
        assert!(collider.is_static(), "{name}");
        assert!(outside(lowest), "{name}, stopped: a particle at {lowest:e}");
        assert_ne!(stopped, built, "{name}");
    }
}

/// A forearm lifted by the shoulder while it tilts up and back about the elbow: the
/// capsule from the elbow to the wrist at time `t`. The elbow rises 0.5 m in a second;
/// the tilt (up to 0.3 rad) turns the capsule about the elbow, not about its own
/// midpoint as one constant motion would.
fn forearm(t: f64) -> (DVec3, DVec3) {
    let elbow = DVec3::new(-0.25, -0.035 + 0.25 * (1.0 - (PI * t).cos()), 0.0);
    let tilt = 0.3 * (PI * t).sin();
    (
        elbow,
        elbow + 0.45 * DVec3::new(tilt.cos(), tilt.sin(), 0.0),
    )
}

const RADIUS: f64 = 0.03;

/// Friction enough to hold the sheet on the forearm at its steepest tilt.
fn gripping() -> ContactSettings {
    ContactSettings {
        mu: 0.5,
        ..ContactSettings::default()
    }
}

/// A sheet lying across a forearm that is lifted and tilted, the capsule driven to the
/// animation's pose at each step's end: no particle is ever inside the animation's own
/// capsule at a step's end, in the three implicit schemes, and the sheet is carried up.
#[test]
fn a_capsule_driven_along_an_animated_limb_never_lets_a_particle_in() {
    let newton = NewtonSettings::default();
    for (name, integrator) in [
        ("backward Euler", Integrator::BackwardEuler(newton)),
        ("BDF2", Integrator::Bdf2(newton)),
        ("implicit midpoint", Integrator::ImplicitMidpoint(newton)),
    ] {
        let system = contact_sheet(9, 0.05, DVec3::new(-0.2, 0.0, -0.2), DVec3::X, DVec3::Z);
        let mut sim = Simulation::new(system, integrator).unwrap();
        let (a, b) = forearm(0.0);
        sim.set_contact(vec![Collider::capsule(a, b, RADIUS)], gripping())
            .unwrap();
        let mut nearest = f64::INFINITY;
        for step in 0..60 {
            let end = (step + 1) as f64 * H;
            let (a, b) = forearm(end);
            let target = Shape::Capsule {
                a,
                b,
                radius: RADIUS,
            };
            sim.drive_collider(
                0,
                &Drive::To {
                    target,
                    duration: H,
                },
            )
            .unwrap();
            let report = sim.step(H).unwrap();
            assert!(
                report.residual <= report.tolerance,
                "{name}, step {step}: {report:?}"
            );
            // The animation's capsule, not the library's: a static collider of those
            // fields, whose pose is the fields themselves.
            let animated = Collider::capsule(a, b, RADIUS);
            for (i, x) in sim.system().positions().iter().enumerate() {
                let d = independent_distance(&animated, 0.0, *x);
                assert!(
                    d > 0.0,
                    "{name}, step {step}: particle {i} inside (d = {d:e})"
                );
                nearest = nearest.min(d);
            }
        }
        // Carried: the elbow rose 0.5 m, and the sheet lies across the forearm.
        let top = sim
            .system()
            .positions()
            .iter()
            .map(|x| x.y)
            .fold(f64::NEG_INFINITY, f64::max);
        println!("{name}: nearest {nearest:.3e}, highest particle {top:.3}");
        assert!(top > 0.4, "{name}: highest particle at {top}");
    }
}

/// A mesh cloth's integrator drives its contact term at its own time; without a contact
/// term there is nothing to drive.
#[test]
fn a_mesh_cloths_integrator_drives_its_colliders() {
    let (positions, triangles) =
        crate::sheets::grid(9, DVec3::new(-0.2, 0.0, -0.2), DVec3::X, DVec3::Z, 0.05, 0);
    let mesh = sinew_spring_sim::TriangleMesh::new(positions, triangles).unwrap();
    let model = crate::sheets::cloth(Vec::new()).build(&mesh).unwrap();
    let mut integrator = model.backward_euler(NewtonSettings::default()).unwrap();
    assert_eq!(
        integrator.drive_collider(0, &Drive::Motion(Motion::STATIC)),
        Err(ContactError::NoSuchCollider { index: 0, count: 0 })
    );
    let (a, b) = forearm(0.0);
    model
        .enable_contact(
            &mut integrator,
            vec![Collider::capsule(a, b, RADIUS)],
            gripping(),
        )
        .unwrap();
    let mut system = model.system.clone();
    for step in 0..60 {
        let (a, b) = forearm((step + 1) as f64 * H);
        let target = Shape::Capsule {
            a,
            b,
            radius: RADIUS,
        };
        let driven = integrator
            .drive_collider(
                0,
                &Drive::To {
                    target,
                    duration: H,
                },
            )
            .unwrap();
        assert_eq!(driven.pose_time, integrator.time());
        integrator.step(&mut system, H).unwrap();
        let animated = Collider::capsule(a, b, RADIUS);
        for (i, x) in system.positions().iter().enumerate() {
            let d = independent_distance(&animated, 0.0, *x);
            assert!(d > 0.0, "step {step}: vertex {i} inside (d = {d:e})");
        }
    }
    let top = system
        .positions()
        .iter()
        .map(|x| x.y)
        .fold(f64::NEG_INFINITY, f64::max);
    assert!(top > 0.4, "highest vertex at {top}");
}
