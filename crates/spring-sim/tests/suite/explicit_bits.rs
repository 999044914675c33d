//! The explicit integrators' substep loops are written for speed (the force buffer holds
//! minus the forces, and velocity Verlet runs a substep's closing kick in the same pass as
//! the next substep's opening kick and drift). Each step must still be bit for bit the
//! textbook loop, written here plainly: forces into a buffer, `v += dt/m f`, `x += dt v`
//! for symplectic Euler; kick, drift, force, kick for velocity Verlet.

use sinew_spring_sim::potential::AxialDamping;
use sinew_spring_sim::spring;
use sinew_spring_sim::*;

/// The total force on every particle: gravity, then each spring's pull (and axial
/// damping along the current direction) added in spring order.
fn forces(system: &SpringSystem, x: &[DVec3], v: &[DVec3]) -> Vec<DVec3> {
    let m = system.material();
    // Summed as minus the gradient of the potential, then negated.
    let mut grad: Vec<DVec3> = system
        .masses()
        .iter()
        .map(|&mi| DVec3::ZERO - mi * m.gravity)
        .collect();
    for s in system.springs() {
        let mut g = spring::gradient(x[s.a], x[s.b], s.rest_length, s.stiffness);
        if m.damping > 0.0 {
            g += AxialDamping::rate_gradient(m.damping, x[s.a] - x[s.b], v[s.a] - v[s.b]);
        }
        grad[s.a] += g;
        grad[s.b] -= g;
    }
    grad.iter().map(|g| -*g).collect()
}

/// The lab cloth (11 x 11), damped, disturbed so every spring works.
fn cloth() -> SpringSystem {
    let mut system = SpringSystem::cloth(&ClothGrid::lab().with_damping(0.3)).unwrap();
    let x: Vec<DVec3> = system
        .positions()
        .iter()
        .map(|&p| p + DVec3::new(0.01 * (3.0 * p.z).sin(), 0.02 * (5.0 * p.x).cos(), 0.0))
        .collect();
    let v = vec![DVec3::new(0.0, -0.1, 0.05); x.len()];
    system.set_state(&x, &v).unwrap();
    system
}

fn assert_bits(a: &[DVec3], b: &[DVec3], what: &str) {
    let bits = |v: &[DVec3]| -> Vec<[u64; 3]> {
        v.iter()
            .map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
            .collect()
    };
    assert_eq!(bits(a), bits(b), "{what}");
}

/// The system's positions and velocities are bitwise `x` and `v` after step `step`.
fn assert_state(system: &SpringSystem, x: &[DVec3], v: &[DVec3], step: usize) {
    let after = |what: &str| format!("{what} after step {step}");
    assert_bits(system.positions(), x, &after("positions"));
    assert_bits(system.velocities(), v, &after("velocities"));
}

#[test]
fn velocity_verlet_is_bitwise_the_textbook_kick_drift_force_kick() {
    let mut system = cloth();
    let (h, substeps) = (1.0 / 60.0, 7);
    let mut stepper = VelocityVerlet::new(&system, substeps).unwrap();
    let (mut x, mut v) = (system.positions().to_vec(), system.velocities().to_vec());
    let dt = h / substeps as f64;
    let half = 0.5 * dt;
    let inv_mass: Vec<f64> = system
        .masses()
        .iter()
        .zip(system.fixed())
        .map(|(m, &fixed)| if fixed { 0.0 } else { 1.0 / m })
        .collect();
    // The stepper reuses the force at the end of its last step when nobody changed the
    // state since; so does this.
    let mut f = forces(&system, &x, &v);
    for step in 0..20 {
        stepper.step(&mut system, h).unwrap();
        for _ in 0..substeps {
            for i in 0..x.len() {
                v[i] += (half * inv_mass[i]) * f[i];
                x[i] += dt * v[i];
            }
            f = forces(&system, &x, &v);
            for i in 0..x.len() {
                v[i] += (half * inv_mass[i]) * f[i];
            }
        }
        assert_state(&system, &x, &v, step);
    }
}

#[test]
fn symplectic_euler_is_bitwise_the_textbook_loop() {
    let mut system = cloth();
    let (h, substeps) = (1.0 / 60.0, 5);
    let mut stepper = SymplecticEuler::new(&system, substeps).unwrap();
    let (mut x, mut v) = (system.positions().to_vec(), system.velocities().to_vec());
    let dt = h / substeps as f64;
    for step in 0..20 {
        stepper.step(&mut system, h).unwrap();
        for _ in 0..substeps {
            let f = forces(&system, &x, &v);
            for i in 0..x.len() {
                if !system.fixed()[i] {
                    v[i] += dt / system.masses()[i] * f[i];
                    x[i] += dt * v[i];
                }
            }
        }
        assert_state(&system, &x, &v, step);
    }
}
