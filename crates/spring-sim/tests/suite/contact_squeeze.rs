//! Two colliders closing in on the same particles within one step: the step's start is
//! moved out of both (while there is room between them at the step's end), every
//! accepted state has every particle outside every collider (distances recomputed here
//! from the colliders' fields), and once the colliders overlap where a particle is, the
//! step is refused with an error naming the particle and a collider, leaving the system
//! unchanged.

use sinew_math::DVec3;
use sinew_spring_sim::contact::{Collider, ContactSettings, Shape};
use sinew_spring_sim::{
    ClothGrid, Integrator, Material, NewtonSettings, Particle, Simulation, SpringSystem, StepError,
};

const H: f64 = 1.0 / 60.0;

fn material() -> Material {
    Material {
        stiffness: 1000.0,
        damping: 0.1,
        gravity: DVec3::new(0.0, -9.81, 0.0),
    }
}

/// The signed distance from `x` to a half-space or sphere posed at `t`, from the fields.
fn distance(collider: &Collider, t: f64, x: DVec3) -> f64 {
    match collider.at(t) {
        Shape::HalfSpace { point, normal } => (x - point).dot(normal),
        Shape::Sphere { center, radius } => (x - center).length() - radius,
        Shape::Capsule { .. } => unreachable!("no capsule in these tests"),
    }
}

fn integrators() -> Vec<(&'static str, Integrator)> {
    let settings = NewtonSettings::default();
    vec![
        ("backward Euler", Integrator::BackwardEuler(settings)),
        ("BDF2", Integrator::Bdf2(settings)),
        ("implicit midpoint", Integrator::ImplicitMidpoint(settings)),
    ]
}

#[test]
fn a_sphere_pressing_a_particle_onto_the_ground_leaves_it_between_them() {
    // The particle rests 1 cm above the ground; a sphere of radius 0.45 comes down on it
    // at 1.56 m/s, its lowest point from 3 cm to 4 mm above the ground in one step, so
    // carried along with the sphere the particle would end 2.2 cm inside the ground.
    // After the step it must be in the 4 mm gap, outside both. The next step brings the
    // sphere 2.2 cm below the ground: no room is left, and the step is refused.
    for (name, integrator) in integrators() {
        let particle = Particle::at_rest(DVec3::new(0.0, 0.01, 0.0), 5e-4);
        let system = SpringSystem::new(&[particle], &[], material()).unwrap();
        let mut sim = Simulation::new(system, integrator).unwrap();
        let sphere = Collider::sphere(DVec3::new(0.0, 0.48, 0.0), 0.45)
            .moving(DVec3::new(0.0, -1.56, 0.0), DVec3::ZERO);
        let colliders = vec![Collider::ground(0.0), sphere];
        sim.set_contact(colliders.clone(), ContactSettings::default())
            .unwrap();
        sim.step(H)
            .unwrap_or_else(|e| panic!("{name}: the squeeze step was refused: {e}"));
        let x = sim.system().positions()[0];
        let t = sim.time();
        let (ground, above) = (distance(&colliders[0], t, x), distance(&colliders[1], t, x));
        assert!(
            ground > 0.0 && above > 0.0,
            "{name}: particle at {x} is inside a collider (ground {ground}, sphere {above})"
        );
        // The gap is 4 mm wide along the axis: the particle is in it.
        assert!(
            ground + above <= 0.004 + 1e-12,
            "{name}: particle at {x} is not in the gap ({ground} + {above})"
        );

        let before = sim.system().clone();
        let err = sim.step(H).unwrap_err();
        assert!(
            matches!(err, StepError::Contact { particle: 0, .. }),
            "{name}: {err}"
        );
        let message = err.to_string();
        assert!(
            message.contains("particle 0") && message.contains("collider"),
            "{name}: {message}"
        );
        assert_eq!(
            sim.system(),
            &before,
            "{name}: a refused step changes nothing"
        );
    }
}

#[test]
fn a_press_flattens_a_sheet_onto_the_ground_without_penetration() {
    // A 4 x 4 sheet 1 cm above the ground; a press (a half-space facing down) comes down
    // from 3 cm at 1.62 m/s, to 3 mm above the ground in one step, carrying every
    // particle with it would put the whole sheet 1.7 cm inside the ground. After the
    // step every particle is in the 3 mm gap.
    for (name, integrator) in integrators() {
        let grid = ClothGrid {
            size: 4,
            spacing: 0.05,
            origin: DVec3::new(0.0, 0.01, 0.0),
            mass: 5e-4,
            material: material(),
            fixed: Vec::new(),
        };
        let mut sim = Simulation::new(grid.build().unwrap(), integrator).unwrap();
        let press = Collider::fixed(Shape::HalfSpace {
            point: DVec3::new(0.0, 0.03, 0.0),
            normal: DVec3::NEG_Y,
        })
        .moving(DVec3::new(0.0, -1.62, 0.0), DVec3::ZERO);
        let colliders = vec![Collider::ground(0.0), press];
        sim.set_contact(
            colliders.clone(),
            ContactSettings {
                mu: 0.2,
                ..ContactSettings::default()
            },
        )
        .unwrap();
        let report = sim
            .step(H)
            .unwrap_or_else(|e| panic!("{name}: the press step was refused: {e}"));
        let t = sim.time();
        for (i, x) in sim.system().positions().iter().enumerate() {
            for (c, collider) in colliders.iter().enumerate() {
                let d = distance(collider, t, *x);
                assert!(
                    d > 0.0,
                    "{name}: particle {i} inside collider {c} (d = {d}, {report:?})"
                );
            }
            assert!(x.y > 0.0 && x.y < 0.003, "{name}: particle {i} at {x}");
        }
        // The press reaches the ground in the next step: refused, naming a particle.
        let err = sim.step(H).unwrap_err();
        assert!(matches!(err, StepError::Contact { .. }), "{name}: {err}");
    }
}
