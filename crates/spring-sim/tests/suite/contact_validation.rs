//! Contact input validation (errors name the collider, the shape and the field, or the
//! setting) and the explicit integrators' projection, against hand-computed states.

use sinew_math::DVec3;
use sinew_spring_sim::contact::collider::validate_colliders;
use sinew_spring_sim::contact::self_contact::SelfContactSettings;
use sinew_spring_sim::contact::{
    Collider, ContactError, ContactSettings, KappaSettings, MAX_COLLIDER_MAGNITUDE,
    MAX_KAPPA_RATIO, Motion, Shape, project_particle, signed_distance,
};

fn message(e: ContactError) -> String {
    e.to_string()
}

#[test]
fn collider_errors_name_the_collider_and_field() {
    let good = Collider::ground(0.0);
    assert_eq!(good.validate(), Ok(()));
    let cases = [
        (
            Collider::fixed(Shape::HalfSpace {
                point: DVec3::new(f64::NAN, 0.0, 0.0),
                normal: DVec3::Y,
            }),
            "point",
        ),
        (
            Collider::fixed(Shape::HalfSpace {
                point: DVec3::ZERO,
                normal: DVec3::new(0.0, 1.0 + 1e-8, 0.0),
            }),
            "normal",
        ),
        (
            Collider::fixed(Shape::HalfSpace {
                point: DVec3::ZERO,
                normal: DVec3::ZERO,
            }),
            "normal",
        ),
        (Collider::sphere(DVec3::ZERO, 0.0), "radius"),
        (Collider::sphere(DVec3::ZERO, -1.0), "radius"),
        (Collider::sphere(DVec3::INFINITY, 1.0), "center"),
        (Collider::capsule(DVec3::ZERO, DVec3::X, f64::NAN), "radius"),
        (Collider::capsule(DVec3::NAN, DVec3::X, 1.0), "a"),
        (
            Collider::capsule(DVec3::ZERO, DVec3::NEG_INFINITY, 1.0),
            "b",
        ),
        (
            Collider::sphere(DVec3::ZERO, 1.0).moving(DVec3::new(0.0, f64::NAN, 0.0), DVec3::ZERO),
            "linear_velocity",
        ),
        (
            Collider::ground(0.0).moving(DVec3::ZERO, DVec3::INFINITY),
            "angular_velocity",
        ),
        // Finite but beyond the range the contact geometry keeps finite.
        (
            Collider::sphere(DVec3::new(0.0, -1e200, 0.0), 1.0),
            "center",
        ),
        (Collider::sphere(DVec3::ZERO, 2e50), "radius"),
        (
            Collider::capsule(DVec3::ZERO, DVec3::new(1e51, 0.0, 0.0), 1.0),
            "b",
        ),
        (
            Collider::sphere(DVec3::ZERO, 1.0).moving(DVec3::new(0.0, 0.0, 1e160), DVec3::ZERO),
            "linear_velocity",
        ),
        (
            Collider::capsule(DVec3::ZERO, DVec3::X, 1.0)
                .moving(DVec3::ZERO, DVec3::new(0.0, 1e300, 0.0)),
            "angular_velocity",
        ),
        (
            Collider {
                pose_time: 1e308,
                ..Collider::sphere(DVec3::ZERO, 1.0).moving(DVec3::Z, DVec3::ZERO)
            },
            "pose_time",
        ),
    ];
    for (c, field) in cases {
        let err = c.validate().unwrap_err();
        let ContactError::BadCollider {
            field: f, shape, ..
        } = &err
        else {
            panic!("{err:?}");
        };
        assert_eq!(*f, field);
        assert_eq!(*shape, c.shape.kind());
        assert!(message(err.clone()).contains(field), "{err}");
        // In a list, the index is named too.
        let list = [good, good, c];
        let err = validate_colliders(&list).unwrap_err();
        let text = message(err);
        assert!(
            text.starts_with(&format!("collider 2 ({})", c.shape.kind())),
            "{text}"
        );
        assert!(text.contains(field), "{text}");
    }
    // A unit normal to within 1e-9 passes; coincident capsule ends are a sphere, accepted.
    let nearly = Collider::fixed(Shape::HalfSpace {
        point: DVec3::ZERO,
        normal: DVec3::new(0.0, 1.0 + 5e-10, 0.0),
    });
    assert_eq!(nearly.validate(), Ok(()));
    assert_eq!(
        Collider::capsule(DVec3::ONE, DVec3::ONE, 0.2).validate(),
        Ok(())
    );
    assert_eq!(
        validate_colliders(&[good, Collider::sphere(DVec3::ZERO, 1.0)]),
        Ok(())
    );
    assert!(Collider::ground(1.0).is_static());
    assert_eq!(Collider::ground(1.0).motion, Motion::STATIC);
    // At the limit itself: accepted.
    let edge = Collider::sphere(DVec3::new(0.0, -MAX_COLLIDER_MAGNITUDE, 0.0), 1.0);
    assert_eq!(edge.validate(), Ok(()));
}

#[test]
fn the_distance_to_a_far_ball_is_its_distance_not_inside() {
    // |x - c|^2 overflows beyond about 1.3e154: the distance is still |x - c| - r.
    let x = DVec3::new(-0.1, 0.3, -0.1);
    for far in [1e100, 1e160, 1e200, 1e300] {
        let sphere = Shape::Sphere {
            center: DVec3::new(0.0, -far, 0.0),
            radius: 1.0,
        };
        let d = signed_distance(&sphere, x, 0.0);
        assert!((d.distance / far - 1.0).abs() < 1e-15, "{far}: {d:?}");
        assert!((d.normal - DVec3::Y).length() < 1e-15, "{far}: {d:?}");
        let capsule = Shape::Capsule {
            a: DVec3::new(0.0, -far, 0.0),
            b: DVec3::new(0.0, -far, 1.0),
            radius: 1.0,
        };
        let d = signed_distance(&capsule, x, 0.0);
        assert!((d.distance / far - 1.0).abs() < 1e-15, "{far}: {d:?}");
    }
}

#[test]
fn settings_errors_name_the_setting() {
    assert_eq!(ContactSettings::default().validate(), Ok(()));
    let d = ContactSettings::default();
    assert_eq!(ContactSettings { mu: 100.0, ..d }.validate(), Ok(()));
    let cases = [
        (ContactSettings { dhat: 0.0, ..d }, "dhat"),
        (
            ContactSettings {
                dhat: f64::NAN,
                ..d
            },
            "dhat",
        ),
        (
            ContactSettings {
                thickness: -1e-3,
                ..d
            },
            "thickness",
        ),
        (ContactSettings { mu: -0.1, ..d }, "mu"),
        (ContactSettings { mu: 100.5, ..d }, "mu"),
        (ContactSettings { mu: 1e300, ..d }, "mu"),
        (
            ContactSettings {
                mu: f64::INFINITY,
                ..d
            },
            "mu",
        ),
        (ContactSettings { eps_v: 0.0, ..d }, "eps_v"),
        (
            ContactSettings {
                toi_fraction: 1.0,
                ..d
            },
            "toi_fraction",
        ),
        (
            ContactSettings {
                toi_fraction: 0.0,
                ..d
            },
            "toi_fraction",
        ),
        (
            ContactSettings {
                toi_fraction: f64::NAN,
                ..d
            },
            "toi_fraction",
        ),
    ];
    for (s, name) in cases {
        let err = s.validate().unwrap_err();
        assert!(
            matches!(err, ContactError::BadSetting { name: n, .. } if n == name),
            "{err:?}"
        );
        assert!(err.to_string().contains(name));
    }
}

#[test]
fn stiffness_rule_errors_name_the_setting_for_colliders_and_self_contact() {
    let d = KappaSettings::default();
    let accepted = [
        d,
        KappaSettings {
            max_ratio: 1.0,
            ..d
        },
        KappaSettings {
            max_ratio: MAX_KAPPA_RATIO,
            ..d
        },
        // With the ratio bounded, a huge growth only sends `kappa` straight to its bound.
        KappaSettings { growth: 1e300, ..d },
        KappaSettings { growth: 1.0, ..d },
        KappaSettings {
            too_close: 0.999,
            ..d
        },
    ];
    let refused = [
        (
            KappaSettings {
                max_ratio: 0.5,
                ..d
            },
            "kappa.max_ratio",
        ),
        (
            KappaSettings {
                max_ratio: 2.0 * MAX_KAPPA_RATIO,
                ..d
            },
            "kappa.max_ratio",
        ),
        (
            KappaSettings {
                max_ratio: 1e300,
                ..d
            },
            "kappa.max_ratio",
        ),
        (
            KappaSettings {
                max_ratio: f64::NAN,
                ..d
            },
            "kappa.max_ratio",
        ),
        (KappaSettings { growth: 0.5, ..d }, "kappa.growth"),
        (
            KappaSettings {
                growth: f64::INFINITY,
                ..d
            },
            "kappa.growth",
        ),
        (
            KappaSettings {
                too_close: 0.0,
                ..d
            },
            "kappa.too_close",
        ),
        (
            KappaSettings {
                too_close: 1.0,
                ..d
            },
            "kappa.too_close",
        ),
        (
            KappaSettings {
                too_close: f64::NAN,
                ..d
            },
            "kappa.too_close",
        ),
    ];
    for kappa in accepted {
        assert_eq!(kappa.validate(), Ok(()), "{kappa:?}");
        let contact = ContactSettings {
            kappa,
            ..ContactSettings::default()
        };
        assert_eq!(contact.validate(), Ok(()), "{kappa:?}");
        let own = SelfContactSettings {
            kappa,
            ..SelfContactSettings::default()
        };
        assert_eq!(own.validate(), Ok(()), "{kappa:?}");
    }
    for (kappa, name) in refused {
        let contact = ContactSettings {
            kappa,
            ..ContactSettings::default()
        };
        let own = SelfContactSettings {
            kappa,
            ..SelfContactSettings::default()
        };
        for err in [
            kappa.validate().unwrap_err(),
            contact.validate().unwrap_err(),
            own.validate().unwrap_err(),
        ] {
            assert!(
                matches!(err, ContactError::BadSetting { name: n, .. } if n == name),
                "{kappa:?}: {err:?}"
            );
            assert!(err.to_string().contains(name), "{err}");
        }
    }
    // A contact potential is refused the rule as well.
    let bad = ContactSettings {
        kappa: KappaSettings { growth: 0.0, ..d },
        ..ContactSettings::default()
    };
    assert!(matches!(
        sinew_spring_sim::contact::ContactPotential::new(vec![Collider::ground(0.0)], bad, 0.0),
        Err(ContactError::BadSetting {
            name: "kappa.growth",
            ..
        })
    ));
}

#[test]
fn projection_pushes_out_and_applies_coulomb_friction() {
    let ground = Collider::ground(0.0);
    // Below the ground by 0.01 with thickness 0.002, falling at 2 and sliding at 3:
    // out to y = 0.002; normal velocity removed; friction 0.5 * 2 = 1 off the sliding 3.
    let p = project_particle(
        &ground,
        0.0,
        DVec3::new(1.0, -0.01, 0.0),
        DVec3::new(3.0, -2.0, 0.0),
        0.002,
        0.5,
    );
    assert!(p.contact);
    assert!(
        (p.position - DVec3::new(1.0, 0.002, 0.0)).length() < 1e-15,
        "{}",
        p.position
    );
    assert!(
        (p.velocity - DVec3::new(2.0, 0.0, 0.0)).length() < 1e-15,
        "{}",
        p.velocity
    );
    // Enough friction to stop it: mu |v_n| >= |v_t|.
    let p = project_particle(
        &ground,
        0.0,
        DVec3::new(1.0, -0.01, 0.0),
        DVec3::new(3.0, -2.0, 0.0),
        0.0,
        2.0,
    );
    assert_eq!(p.velocity, DVec3::ZERO);
    // Inside but already leaving: moved out, velocity kept.
    let p = project_particle(
        &ground,
        0.0,
        DVec3::new(0.0, -0.1, 0.0),
        DVec3::new(1.0, 0.5, 0.0),
        0.0,
        0.5,
    );
    assert!((p.position - DVec3::ZERO).length() < 1e-15);
    assert_eq!(p.velocity, DVec3::new(1.0, 0.5, 0.0));
    // Outside: unchanged.
    let p = project_particle(
        &ground,
        0.0,
        DVec3::new(0.0, 0.1, 0.0),
        DVec3::new(0.0, -9.0, 0.0),
        0.0,
        0.5,
    );
    assert!(!p.contact);
    assert_eq!(p.velocity, DVec3::new(0.0, -9.0, 0.0));
    // A rising ground (1 per second, at y = 0.5 at t = 0.5): a particle at rest at 0.4
    // ends on the surface moving up with it.
    let rising = ground.moving(DVec3::Y, DVec3::ZERO);
    let p = project_particle(
        &rising,
        0.5,
        DVec3::new(0.0, 0.4, 0.0),
        DVec3::ZERO,
        0.0,
        0.3,
    );
    assert!((p.position - DVec3::new(0.0, 0.5, 0.0)).length() < 1e-15);
    assert!((p.velocity - DVec3::Y).length() < 1e-15, "{}", p.velocity);
    // A sphere spinning at 2 rad/s about y: a particle resting on its equator inside the
    // surface is carried by friction toward the surface velocity omega x r = (0, 0, -2)
    // (at (1, 0, 0)); the relative normal speed 1 allows mu * 1 = 0.5 of change.
    let sphere = Collider::sphere(DVec3::ZERO, 1.0).moving(DVec3::ZERO, DVec3::new(0.0, 2.0, 0.0));
    let p = project_particle(
        &sphere,
        0.0,
        DVec3::new(0.99, 0.0, 0.0),
        DVec3::new(-1.0, 0.0, 0.0),
        0.0,
        0.5,
    );
    assert!((p.position - DVec3::new(1.0, 0.0, 0.0)).length() < 1e-15);
    // Relative tangential velocity (0, 0, 2) reduced by 0.5 to (0, 0, 1.5); plus the
    // surface's (0, 0, -2): (0, 0, -0.5).
    assert!(
        (p.velocity - DVec3::new(0.0, 0.0, -0.5)).length() < 1e-15,
        "{}",
        p.velocity
    );
}

/// A contact distance below the positions' rounding, or above the cloth's size, is refused
/// where contact is added: `dhat` must be at least `MIN_RELATIVE_DHAT` (1e-9) of the
/// largest coordinate, for the colliders (`Simulation::set_contact`) and for self-contact
/// (`enable_self_contact`), and at most the diagonal of the positions' box.
#[test]
fn a_contact_distance_below_the_rounding_of_the_positions_or_above_the_cloth_is_refused() {
    use sinew_spring_sim::contact::MIN_RELATIVE_DHAT;
    use sinew_spring_sim::{Integrator, Simulation, TriangleMesh};
    // A sheet 1e4 from the origin: its largest coordinate is 1e4 + 0.3, so the smallest
    // dhat allowed is about 1e-5.
    let origin = DVec3::new(1e4, 0.1, 0.0);
    let scale = 1e4 + 0.1 * 3.0;
    let system = crate::common::contact_sheet(4, 0.1, origin, DVec3::X, DVec3::Z);
    let settings = |dhat| ContactSettings {
        dhat,
        ..ContactSettings::default()
    };
    for dhat in [5e-324, 1e-12, 0.5 * MIN_RELATIVE_DHAT * scale] {
        let mut sim = Simulation::new(system.clone(), Integrator::default()).unwrap();
        let err = sim
            .set_contact(vec![Collider::ground(0.0)], settings(dhat))
            .unwrap_err();
        assert!(
            matches!(err, ContactError::BelowResolution { name: "dhat", value, .. } if value == dhat),
            "{err:?}"
        );
        assert!(err.to_string().contains("dhat"), "{err}");
    }
    let mut sim = Simulation::new(system.clone(), Integrator::default()).unwrap();
    sim.set_contact(vec![Collider::ground(0.0)], settings(2e-5))
        .unwrap();
    // Above the diagonal of the sheet's box (0.3 x 0 x 0.3) a barrier is a force field.
    let diagonal = 0.3 * 2f64.sqrt();
    for dhat in [1.001 * diagonal, 1e3] {
        let mut sim = Simulation::new(system.clone(), Integrator::default()).unwrap();
        let err = sim
            .set_contact(vec![Collider::ground(0.0)], settings(dhat))
            .unwrap_err();
        assert!(
            matches!(err, ContactError::BeyondExtent { name: "dhat", value, extent }
                if value == dhat && (extent - diagonal).abs() < 1e-12),
            "{err:?}"
        );
    }
    let mut sim = Simulation::new(system, Integrator::default()).unwrap();
    sim.set_contact(vec![Collider::ground(0.0)], settings(0.999 * diagonal))
        .unwrap();

    let (positions, triangles) = crate::sheets::grid(4, origin, DVec3::X, DVec3::Z, 0.1, 0);
    let mesh = TriangleMesh::new(positions, triangles).unwrap();
    let model = crate::sheets::cloth(Vec::new()).build(&mesh).unwrap();
    let self_settings = |dhat| SelfContactSettings {
        dhat,
        ..SelfContactSettings::default()
    };
    let mut integrator = model.backward_euler(Default::default()).unwrap();
    let err = model
        .enable_self_contact(&mut integrator, self_settings(1e-6))
        .unwrap_err();
    assert!(
        matches!(err, ContactError::BelowResolution { name: "dhat", .. }),
        "{err:?}"
    );
    model
        .enable_self_contact(&mut integrator, self_settings(2e-5))
        .unwrap();
}

#[test]
fn a_free_particle_starting_inside_or_on_a_collider_is_refused() {
    use sinew_spring_sim::{Integrator, Particle, Simulation, SpringSystem, StepError};
    // Two particles joined by a spring, 0.1 apart along x at height `y`; the sphere of
    // radius 0.2 about (0, 0.1, 0) holds the first when y = 0.1.
    let system = |y: f64, first_fixed: bool| {
        let mut a = Particle::at_rest(DVec3::new(0.0, y, 0.0), 0.01);
        a.fixed = first_fixed;
        let b = Particle::at_rest(DVec3::new(1.0, y, 0.0), 0.01);
        SpringSystem::new(
            &[a, b],
            &[sinew_spring_sim::SpringSpec::between(0, 1)],
            crate::common::contact_material(),
        )
        .unwrap()
    };
    let sphere = Collider::sphere(DVec3::new(0.0, 0.1, 0.0), 0.2);
    let settings = ContactSettings::default();
    let contact = |sys: SpringSystem, colliders: Vec<Collider>, s: ContactSettings| {
        Simulation::new(sys, Integrator::default())
            .unwrap()
            .set_contact(colliders, s)
    };
    // Inside the sphere, collider 1 of the list: named with its distance (-0.2).
    let err = contact(
        system(0.1, false),
        vec![Collider::ground(-1.0), sphere],
        settings,
    )
    .unwrap_err();
    match err {
        ContactError::StartsInside {
            particle: 0,
            collider: 1,
            distance,
        } => assert!((distance + 0.2).abs() < 1e-15, "{distance}"),
        other => panic!("{other:?}"),
    }
    assert!(
        message(err).contains("particle 0 starts inside collider 1"),
        "the message names both"
    );
    // On the ground exactly (distance 0), and within the thickness of it: refused.
    let err = contact(system(0.0, false), vec![Collider::ground(0.0)], settings).unwrap_err();
    assert!(
        matches!(err, ContactError::StartsInside { particle: 0, distance, .. } if distance == 0.0),
        "{err:?}"
    );
    let thick = ContactSettings {
        thickness: 0.01,
        ..settings
    };
    let err = contact(system(0.005, false), vec![Collider::ground(0.0)], thick).unwrap_err();
    assert!(matches!(err, ContactError::StartsInside { .. }), "{err:?}");
    // Just outside: accepted; a pinned particle inside is not checked (it never moves).
    contact(system(0.02, false), vec![Collider::ground(0.0)], thick).unwrap();
    contact(system(0.1, true), vec![sphere], settings).unwrap();

    // A state moved inside through `system_mut` after contact was set: the next step is
    // refused, naming the particle, and the system is left as it was.
    let mut sim = Simulation::new(system(0.5, false), Integrator::default()).unwrap();
    sim.set_contact(vec![Collider::ground(0.0)], settings)
        .unwrap();
    sim.step(0.01).unwrap();
    let mut positions = sim.system().positions().to_vec();
    positions[1].y = -0.25;
    let velocities = sim.system().velocities().to_vec();
    sim.system_mut().set_state(&positions, &velocities).unwrap();
    let err = sim.step(0.01).unwrap_err();
    assert!(
        matches!(err, StepError::StartsInside { particle: 1, collider: 0, distance } if distance == -0.25),
        "{err:?}"
    );
    assert!(
        err.to_string().contains("particle 1 is inside collider 0"),
        "{err}"
    );
    assert_eq!(sim.system().positions(), &positions[..]);
}

#[test]
fn a_contact_term_added_by_hand_refuses_a_start_inside_a_collider() {
    use sinew_spring_sim::contact::{ContactPotential, ContactTerm};
    use sinew_spring_sim::{BackwardEuler, NewtonSettings, Particle, SpringSystem, StepError};
    // Two free particles 1 apart at height 0.5, a spring between them, and a sphere of
    // radius 0.2 that moves along x at 1 per second from (-2, 0.5, 0): at t = 0 it is far
    // from both, at t = 2 it holds the first particle (distance -0.2).
    let mut system = SpringSystem::new(
        &[
            Particle::at_rest(DVec3::new(0.0, 0.5, 0.0), 0.01),
            Particle::at_rest(DVec3::new(1.0, 0.5, 0.0), 0.01),
        ],
        &[sinew_spring_sim::SpringSpec::between(0, 1)],
        crate::common::contact_material(),
    )
    .unwrap();
    let sphere = Collider {
        motion: Motion {
            linear_velocity: DVec3::X,
            angular_velocity: DVec3::ZERO,
        },
        ..Collider::sphere(DVec3::new(-2.0, 0.5, 0.0), 0.2)
    };
    let ground = Collider::ground(0.0);
    let mut integrator = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
    let contact =
        ContactPotential::new(vec![ground, sphere], ContactSettings::default(), 0.0).unwrap();
    integrator.add_term(Box::new(ContactTerm::new(contact)));

    // A free particle moved below the ground: refused, naming it, the system untouched.
    let mut positions = system.positions().to_vec();
    positions[1].y = -0.25;
    let velocities = system.velocities().to_vec();
    system.set_state(&positions, &velocities).unwrap();
    let err = integrator.step(&mut system, 0.01).unwrap_err();
    assert!(
        matches!(err, StepError::StartsInside { particle: 1, collider: 0, distance } if distance == -0.25),
        "{err:?}"
    );
    assert_eq!(system.positions(), &positions[..]);
    assert_eq!(system.velocities(), &velocities[..]);
    assert_eq!(
        integrator.time(),
        0.0,
        "a refused step does not advance time"
    );

    // Back above the ground: the step runs. Posed at the stepper's time: at t = 2 the
    // moving sphere holds particle 0 (its centre at (0, 0.5, 0)), which is refused,
    // though the same positions at t = 0 were accepted.
    positions[1].y = 0.5;
    system.set_state(&positions, &velocities).unwrap();
    let start = system.clone();
    integrator.step(&mut system, 0.01).unwrap();
    system = start;
    integrator.set_time(2.0);
    let err = integrator.step(&mut system, 0.01).unwrap_err();
    match err {
        StepError::StartsInside {
            particle: 0,
            collider: 1,
            distance,
        } => assert!((distance + 0.2).abs() < 1e-15, "{distance}"),
        other => panic!("{other:?}"),
    }
    assert_eq!(system.positions(), &positions[..]);
    // The stepper's time set where the moving sphere's pose is not finite, or beyond
    // the range: refused, naming the collider and the time, the system untouched.
    for time in [f64::NAN, 1e300, -1e300] {
        integrator.set_time(time);
        let err = integrator.step(&mut system, 0.01).unwrap_err();
        assert!(
            matches!(err, StepError::ColliderOutOfRange { collider: 1, time: t } if t.to_bits() == time.to_bits()),
            "{err:?}"
        );
        assert!(err.to_string().contains("collider 1"), "{err}");
        assert_eq!(system.positions(), &positions[..]);
    }
    // A static collider's pose does not depend on the time: with the ground alone, a
    // time of 1e300 is no error.
    let mut integrator = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
    let contact = ContactPotential::new(vec![ground], ContactSettings::default(), 0.0).unwrap();
    integrator.add_term(Box::new(ContactTerm::new(contact)));
    integrator.set_time(1e300);
    integrator.step(&mut system, 0.01).unwrap();
}

/// A 4 x 4 mesh sheet, 0.3 wide, flat at height 0.05 from the origin along x and z.
fn low_sheet() -> sinew_spring_sim::TriangleMesh {
    let (positions, triangles) =
        crate::sheets::grid(4, DVec3::new(0.0, 0.05, 0.0), DVec3::X, DVec3::Z, 0.1, 0);
    sinew_spring_sim::TriangleMesh::new(positions, triangles).unwrap()
}

/// A mesh cloth's colliders added in one call are checked as `Simulation::set_contact`
/// checks them: the colliders (named), the settings (named), `dhat` against the
/// positions' rounding and their extent, and a free particle starting inside a collider
/// (named, at the integrator's time, so a kinematic collider is posed there); a pinned
/// vertex inside is not refused. What is accepted keeps the guarantee over a drop onto
/// the ground.
#[test]
fn a_mesh_cloths_colliders_are_checked_where_they_are_added() {
    let mesh = low_sheet();
    let model = crate::sheets::cloth(Vec::new()).build(&mesh).unwrap();
    let add = |colliders: Vec<Collider>, settings: ContactSettings, time: f64| {
        let mut integrator = model.backward_euler(Default::default()).unwrap();
        integrator.set_time(time);
        model
            .enable_contact(&mut integrator, colliders, settings)
            .map(|_| integrator)
    };
    let settings = ContactSettings::default();
    let ground = Collider::ground(0.0);

    let bad_sphere = Collider::sphere(DVec3::new(5.0, 0.0, 0.0), -1.0);
    let err = add(vec![ground, bad_sphere], settings, 0.0).unwrap_err();
    assert!(
        matches!(
            err,
            ContactError::BadCollider {
                collider: Some(1),
                field: "radius",
                ..
            }
        ),
        "{err:?}"
    );
    // A moving sphere posed at an integrator time where it lies beyond the range.
    let moving = Collider::sphere(DVec3::new(5.0, 0.0, 0.0), 1.0).moving(DVec3::Z, DVec3::ZERO);
    for time in [f64::NAN, 1e60] {
        let err = add(vec![ground, moving], settings, time).unwrap_err();
        assert!(
            matches!(
                err,
                ContactError::BadCollider {
                    collider: Some(1),
                    field: "pose",
                    ..
                }
            ),
            "{err:?}"
        );
    }
    add(vec![ground, moving], settings, 1e3).unwrap();
    for (name, bad) in [
        (
            "dhat",
            ContactSettings {
                dhat: -1e-3,
                ..settings
            },
        ),
        (
            "mu",
            ContactSettings {
                mu: f64::NAN,
                ..settings
            },
        ),
        (
            "thickness",
            ContactSettings {
                thickness: f64::INFINITY,
                ..settings
            },
        ),
    ] {
        let err = add(vec![ground], bad, 0.0).unwrap_err();
        assert!(
            matches!(err, ContactError::BadSetting { name: n, .. } if n == name),
            "{name}: {err:?}"
        );
    }
    // Largest coordinate 0.3: dhat 1e-12 is below its rounding (3e-10 allowed at least).
    let err = add(
        vec![ground],
        ContactSettings {
            dhat: 1e-12,
            ..settings
        },
        0.0,
    )
    .unwrap_err();
    assert!(
        matches!(err, ContactError::BelowResolution { name: "dhat", .. }),
        "{err:?}"
    );
    // Above the diagonal of the sheet's box (0.3 x 0 x 0.3): a force field, refused.
    let err = add(
        vec![ground],
        ContactSettings {
            dhat: 1.0,
            ..settings
        },
        0.0,
    )
    .unwrap_err();
    assert!(
        matches!(err, ContactError::BeyondExtent { name: "dhat", .. }),
        "{err:?}"
    );
    // The ground at 0.06 holds every vertex: refused, naming vertex 0 (0.01 inside).
    let err = add(vec![Collider::ground(0.06)], settings, 0.0).unwrap_err();
    match err {
        ContactError::StartsInside {
            particle: 0,
            collider: 0,
            distance,
        } => {
            assert!((distance + 0.01).abs() < 1e-15, "{distance}");
        }
        other => panic!("{other:?}"),
    }
    // Within the thickness of the ground (0.05 < 0.08): refused.
    let thick = ContactSettings {
        thickness: 0.08,
        ..settings
    };
    let err = add(vec![ground], thick, 0.0).unwrap_err();
    assert!(matches!(err, ContactError::StartsInside { .. }), "{err:?}");
    // A sphere of radius 0.05 moving along x at 1 per second from (-1, 0.05, 0): far at
    // time 0, over vertex 0 (the origin's corner) at time 1.
    let moving = Collider {
        motion: Motion {
            linear_velocity: DVec3::X,
            angular_velocity: DVec3::ZERO,
        },
        ..Collider::sphere(DVec3::new(-1.0, 0.05, 0.0), 0.05)
    };
    add(vec![moving], settings, 0.0).unwrap();
    let err = add(vec![moving], settings, 1.0).unwrap_err();
    assert!(
        matches!(
            err,
            ContactError::StartsInside {
                particle: 0,
                collider: 0,
                ..
            }
        ),
        "{err:?}"
    );
    // A pinned vertex inside is not checked: it never moves.
    let pinned = crate::sheets::cloth(vec![0]).build(&mesh).unwrap();
    let mut integrator = pinned.backward_euler(Default::default()).unwrap();
    pinned
        .enable_contact(
            &mut integrator,
            vec![Collider::sphere(DVec3::new(0.0, 0.05, 0.0), 0.02)],
            settings,
        )
        .unwrap();

    // Accepted, with friction: the sheet falls onto the ground and no vertex is ever
    // below it; the statistics returned are the term's (kappa chosen, and a lagged
    // friction contact per vertex once the sheet lies within dhat of the ground).
    let mut integrator = model.backward_euler(Default::default()).unwrap();
    let rough = ContactSettings {
        mu: 0.3,
        ..settings
    };
    let stats = model
        .enable_contact(&mut integrator, vec![ground], rough)
        .unwrap();
    assert_eq!(stats.kappa(), 0.0, "no step yet");
    assert_eq!(
        (stats.active_pairs(), stats.min_distance()),
        (0, f64::INFINITY)
    );
    let mut system = model.system.clone();
    for step in 0..30 {
        integrator.step(&mut system, 1.0 / 60.0).unwrap();
        assert!(system.positions().iter().all(|x| x.y > 0.0));
        if step == 0 {
            // Still 5 cm up after the first step (a fall of g h^2 = 2.7 mm).
            assert_eq!(
                (stats.active_pairs(), stats.min_distance()),
                (0, f64::INFINITY)
            );
        }
    }
    assert!(stats.kappa() > 0.0);
    assert_eq!(stats.friction_contacts(), system.len());
    // Resting within dhat: every vertex is a pair at the last iteration's start.
    assert_eq!(stats.active_pairs(), system.len());
    let d = stats.min_distance();
    assert!(d > 0.0 && d < settings.dhat, "{d}");
}

/// Contact of each kind is added once: a second call (which would add a second barrier)
/// is refused naming the kind, for a mesh cloth's colliders and self-contact and for a
/// simulation's colliders; one of each kind goes together.
#[test]
fn contact_of_one_kind_is_added_once() {
    use sinew_spring_sim::contact::self_contact::{SelfContactSettings, enable_self_contact};
    use sinew_spring_sim::{Integrator, Simulation};
    let model = crate::sheets::cloth(Vec::new())
        .build(&low_sheet())
        .unwrap();
    let mut integrator = model.backward_euler(Default::default()).unwrap();
    let ground = vec![Collider::ground(0.0)];
    let settings = ContactSettings::default();
    let own = SelfContactSettings::default();
    model
        .enable_contact(&mut integrator, ground.clone(), settings)
        .unwrap();
    model.enable_self_contact(&mut integrator, own).unwrap();
    let err = model
        .enable_contact(&mut integrator, ground.clone(), settings)
        .unwrap_err();
    assert_eq!(err, ContactError::AddedTwice { what: "contact" });
    assert!(message(err).starts_with("contact was added to this integrator already"));
    let err = model.enable_self_contact(&mut integrator, own).unwrap_err();
    assert_eq!(
        err,
        ContactError::AddedTwice {
            what: "self-contact"
        }
    );
    let err =
        enable_self_contact(&mut integrator, &model.system, &model.triangles, own).unwrap_err();
    assert_eq!(
        err,
        ContactError::AddedTwice {
            what: "self-contact"
        }
    );
    // The integrator still steps with one term of each.
    let mut system = model.system.clone();
    integrator.step(&mut system, 1.0 / 60.0).unwrap();

    let mut sim = Simulation::new(model.system.clone(), Integrator::default()).unwrap();
    sim.set_contact(ground.clone(), settings).unwrap();
    let err = sim.set_contact(ground, settings).unwrap_err();
    assert_eq!(err, ContactError::AddedTwice { what: "contact" });
}
