//! Invalid input is an `Err` naming the offending item, never a panic.

use sinew_math::DVec3;
use sinew_spring_sim::*;

fn two() -> Vec<Particle> {
    vec![
        Particle::at_rest(DVec3::ZERO, 1.0),
        Particle::at_rest(DVec3::X, 1.0),
        Particle::at_rest(DVec3::Y, 1.0),
    ]
}

fn err(particles: &[Particle], springs: &[SpringSpec], material: Material) -> String {
    SpringSystem::new(particles, springs, material)
        .unwrap_err()
        .to_string()
}

#[test]
fn validation_errors_name_the_item() {
    let m = Material::lab();
    let ok = [SpringSpec::between(0, 1)];
    assert!(SpringSystem::new(&two(), &ok, m).is_ok());

    let e = err(
        &two(),
        &[SpringSpec::between(0, 1), SpringSpec::between(1, 7)],
        m,
    );
    assert!(
        e.contains("spring 1") && e.contains("7") && e.contains("out of range"),
        "{e}"
    );

    let e = err(
        &two(),
        &[SpringSpec::between(0, 1), SpringSpec::between(2, 2)],
        m,
    );
    assert!(e.contains("spring 1") && e.contains("itself"), "{e}");

    let e = err(
        &two(),
        &[
            SpringSpec::between(0, 1),
            SpringSpec::between(1, 2),
            SpringSpec::between(1, 0),
        ],
        m,
    );
    assert!(
        e.contains("spring 2") && e.contains("duplicates spring 0"),
        "{e}"
    );

    let mut p = two();
    p[2].mass = 0.0;
    let e = err(&p, &ok, m);
    assert!(e.contains("particle 2") && e.contains("mass"), "{e}");
    p[2].mass = -1.0;
    assert!(err(&p, &ok, m).contains("particle 2"));
    p[2].mass = f64::NAN;
    let e = err(&p, &ok, m);
    assert!(
        e.contains("particle 2") && e.contains("mass") && e.contains("not finite"),
        "{e}"
    );

    let mut p = two();
    p[1].position.y = f64::NAN;
    let e = err(&p, &ok, m);
    assert!(e.contains("particle 1") && e.contains("position"), "{e}");
    let mut p = two();
    p[0].velocity.z = f64::INFINITY;
    let e = err(&p, &ok, m);
    assert!(e.contains("particle 0") && e.contains("velocity"), "{e}");

    let s = [SpringSpec {
        particles: [0, 1],
        rest_length: None,
        stiffness: Some(-1.0),
    }];
    let e = err(&two(), &s, m);
    assert!(e.contains("spring 0") && e.contains("stiffness"), "{e}");
    let s = [SpringSpec {
        particles: [0, 1],
        rest_length: Some(-0.5),
        stiffness: None,
    }];
    let e = err(&two(), &s, m);
    assert!(e.contains("spring 0") && e.contains("rest length"), "{e}");
    let s = [SpringSpec {
        particles: [0, 1],
        rest_length: Some(f64::NAN),
        stiffness: None,
    }];
    assert!(err(&two(), &s, m).contains("spring 0"));

    let e = err(
        &two(),
        &ok,
        Material {
            stiffness: f64::NAN,
            ..m
        },
    );
    assert!(e.contains("default stiffness"), "{e}");
    let e = err(&two(), &ok, Material { damping: -1.0, ..m });
    assert!(e.contains("damping"), "{e}");
    let e = err(
        &two(),
        &ok,
        Material {
            gravity: DVec3::new(0.0, f64::NAN, 0.0),
            ..m
        },
    );
    assert!(e.contains("gravity"), "{e}");
}

#[test]
fn bad_time_steps_are_rejected_for_every_integrator() {
    let system = SpringSystem::cloth(&ClothGrid::lab_sized(3, 0.2)).unwrap();
    for integrator in [
        Integrator::default(),
        Integrator::SymplecticEuler { substeps: 4 },
        Integrator::FlawedReportMethod,
    ] {
        let mut sim = Simulation::new(system.clone(), integrator).unwrap();
        for dt in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let e = sim.step(dt).unwrap_err().to_string();
            assert!(e.contains("time step"), "{e}");
        }
        assert_eq!(sim.system(), &system);
    }
    let e = Simulation::new(system, Integrator::SymplecticEuler { substeps: 0 }).unwrap_err();
    assert!(e.to_string().contains("substeps"));
}

#[test]
fn lab_cloth_matches_the_workload() {
    let s = SpringSystem::cloth(&ClothGrid::lab()).unwrap();
    assert_eq!(s.len(), 121);
    // Per grid: 2 n (n-1) structural, 2 n (n-2) bending, 2 (n-1)^2 shear.
    assert_eq!(s.springs().len(), 2 * 11 * 10 + 2 * 11 * 9 + 2 * 10 * 10);
    // Particle (3, 4) at (0.2 * 3, 1.5, 0.2 * 4 - 1), index 3 * 11 + 4.
    assert!(s.positions()[3 * 11 + 4].distance(DVec3::new(0.6, 1.5, -0.2)) <= 1e-15);
    assert!(s.fixed()[0] && s.fixed()[10]);
    assert_eq!(s.fixed().iter().filter(|f| **f).count(), 2);
    for sp in s.springs() {
        let d = s.positions()[sp.a].distance(s.positions()[sp.b]);
        assert_eq!(sp.rest_length, d);
        assert_eq!(sp.stiffness, 100.0);
    }
    let rope = SpringSystem::rope(&Rope {
        segments: 4,
        segment_length: 0.5,
        start: DVec3::ZERO,
        direction: DVec3::X,
        mass: 1.0,
        material: Material::lab(),
    })
    .unwrap();
    assert_eq!((rope.len(), rope.springs().len()), (5, 4));
    assert!(rope.fixed()[0]);
    let bad = ClothGrid {
        spacing: -1.0,
        ..ClothGrid::lab().with_damping(0.0)
    };
    assert!(bad.build().unwrap_err().to_string().contains("spacing"));
}
