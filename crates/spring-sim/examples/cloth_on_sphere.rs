//! A square of cloth dropped onto a sphere: build a sheet, add a collider, step, and
//! check after every step that no particle went inside the sphere.
//!
//! Run with `cargo run --release -p sinew-spring-sim --example cloth_on_sphere`.
//!
//! The sheet is 21 x 21 particles, 1 m wide, 20 g in all, with springs of 200 N/m (the
//! lab's pattern: structural, skip-one bending, shear) and light damping, released flat
//! and at rest 0.2 m above a sphere of radius 0.3 under Earth's gravity. Contact is
//! backward Euler with the IPC barrier and friction 0.3.

use sinew_spring_sim::contact::{Collider, ContactSettings};
use sinew_spring_sim::{
    ClothGrid, DVec3, Integrator, Material, NewtonSettings, Simulation, SpringSystem,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let size = 21;
    let spacing = 1.0 / (size - 1) as f64;
    let (center, radius) = (DVec3::ZERO, 0.3);
    let grid = ClothGrid {
        size,
        spacing,
        origin: DVec3::new(-0.5, radius + 0.2, -0.5),
        mass: 0.02 / (size * size) as f64,
        material: Material::earth().with_stiffness(200.0).with_damping(0.05),
        // Nothing pinned: the sheet falls freely onto the sphere.
        fixed: Vec::new(),
    };
    let cloth: SpringSystem = grid.build()?;
    let mut sim = Simulation::new(cloth, Integrator::BackwardEuler(NewtonSettings::default()))?;
    let settings = ContactSettings {
        mu: 0.3,
        ..ContactSettings::default()
    };
    sim.set_contact(vec![Collider::sphere(center, radius)], settings)?;

    let h = 1.0 / 60.0;
    let mut iterations = 0;
    for step in 1..=90 {
        let report = sim.step(h)?;
        iterations += report.iterations;
        // The barrier keeps every accepted state outside the sphere: check it directly.
        let closest = sim
            .system()
            .positions()
            .iter()
            .map(|p| (*p - center).length() - radius)
            .fold(f64::INFINITY, f64::min);
        assert!(
            closest > 0.0,
            "step {step}: a particle is inside the sphere"
        );
        if step % 15 == 0 {
            let lowest = sim
                .system()
                .positions()
                .iter()
                .map(|p| p.y)
                .fold(f64::INFINITY, f64::min);
            println!(
                "t = {:.2} s: closest to the sphere {closest:.2e} m, lowest point y = {lowest:.3} m, {} Newton iterations",
                sim.time(),
                report.iterations
            );
        }
    }
    // Draped: the sheet's edges have fallen below the sphere's top, its centre rests on it.
    let positions = sim.system().positions();
    let middle = positions[(size / 2) * size + size / 2];
    let corner = positions[0];
    println!(
        "after {:.1} s ({iterations} Newton iterations): centre at y = {:.3}, corner at y = {:.3}",
        sim.time(),
        middle.y,
        corner.y
    );
    assert!(
        corner.y < middle.y,
        "the corners should hang below the centre"
    );
    Ok(())
}
