//! Every stepper refuses a system whose topology differs from the one it was built for,
//! even when the particle and spring counts agree, and names what differs.

use sinew_spring_sim::{
    BackwardEuler, Bdf2, DVec3, ImplicitMidpoint, Integrator, Material, ModelError, NewtonSettings,
    Particle, Simulation, SpringSpec, SpringSystem, StepError, SymplecticEuler, VelocityVerlet,
};

/// A hanging chain of four particles: `pinned` fixed, springs `pairs`, masses `masses`.
fn chain(pinned: &[usize], pairs: &[[usize; 2]], masses: [f64; 4]) -> SpringSystem {
    let particles: Vec<Particle> = (0..4)
        .map(|i| Particle {
            fixed: pinned.contains(&i),
            ..Particle::at_rest(DVec3::new(0.3 * i as f64, -(i as f64), 0.0), masses[i])
        })
        .collect();
    let springs: Vec<SpringSpec> = pairs
        .iter()
        .map(|p| SpringSpec::between(p[0], p[1]))
        .collect();
    SpringSystem::new(&particles, &springs, Material::earth()).unwrap()
}

const PAIRS: [[usize; 2]; 3] = [[0, 1], [1, 2], [2, 3]];
/// As many springs as `PAIRS`, joining other particles.
const OTHER_PAIRS: [[usize; 2]; 3] = [[0, 1], [1, 2], [1, 3]];
const MASSES: [f64; 4] = [1.0; 4];

fn base() -> SpringSystem {
    chain(&[0], &PAIRS, MASSES)
}

/// The same counts, each differing in one part of the topology, with the name expected.
fn variants() -> Vec<(SpringSystem, &'static str)> {
    vec![
        (chain(&[3], &PAIRS, MASSES), "fixed set"),
        (chain(&[0], &OTHER_PAIRS, MASSES), "spring pairs"),
        (chain(&[0], &PAIRS, [1.0, 1.0, 2.0, 1.0]), "masses"),
    ]
}

/// Runs `step` on every variant and checks the error names what differs and the system
/// is left unchanged; then checks the step still works on a system equal to `base()`.
fn check<F>(name: &str, mut step: F)
where
    F: FnMut(&mut SpringSystem) -> Result<(), StepError>,
{
    for (mut other, what) in variants() {
        assert_eq!(
            other.len(),
            base().len(),
            "{name}: the variant has the same count"
        );
        assert_eq!(other.springs().len(), base().springs().len());
        let before = other.clone();
        let err = step(&mut other).expect_err(name);
        assert_eq!(
            err,
            StepError::Invalid(ModelError::TopologyMismatch { what }),
            "{name}"
        );
        assert!(err.to_string().contains(what), "{name}: {err}");
        assert_eq!(other, before, "{name}: the refused system was changed");
    }
    let mut same = base();
    step(&mut same).unwrap_or_else(|e| panic!("{name}: same topology refused: {e}"));
    assert_ne!(
        same.positions(),
        base().positions(),
        "{name}: nothing moved"
    );
}

#[test]
fn backward_euler_refuses_other_pins_pairs_and_masses() {
    let mut s = BackwardEuler::new(&base(), NewtonSettings::default()).unwrap();
    check("backward Euler", |sys| s.step(sys, 0.01).map(|_| ()));
}

#[test]
fn bdf2_and_midpoint_refuse_other_pins_pairs_and_masses() {
    let mut b = Bdf2::new(&base(), NewtonSettings::default()).unwrap();
    check("BDF2", |sys| b.step(sys, 0.01).map(|_| ()));
    let mut m = ImplicitMidpoint::new(&base(), NewtonSettings::default()).unwrap();
    check("implicit midpoint", |sys| m.step(sys, 0.01).map(|_| ()));
}

#[test]
fn explicit_steppers_refuse_other_pins_pairs_and_masses() {
    let mut se = SymplecticEuler::new(&base(), 10).unwrap();
    check("symplectic Euler", |sys| se.step(sys, 0.01).map(|_| ()));
    let mut vv = VelocityVerlet::new(&base(), 10).unwrap();
    check("velocity Verlet", |sys| vv.step(sys, 0.01).map(|_| ()));
    // Rebuilding the force lists on another topology is refused as well.
    let (other, what) = variants().remove(1);
    assert_eq!(
        vv.set_threads(&other, 1),
        Err(ModelError::TopologyMismatch { what })
    );
}

#[test]
fn simulation_refuses_a_replaced_system_for_every_integrator() {
    let integrators = [
        Integrator::BackwardEuler(NewtonSettings::default()),
        Integrator::Bdf2(NewtonSettings::default()),
        Integrator::ImplicitMidpoint(NewtonSettings::default()),
        Integrator::SymplecticEuler { substeps: 10 },
        Integrator::VelocityVerlet { substeps: None },
        Integrator::Auto(Default::default()),
    ];
    for integrator in integrators {
        for (other, what) in variants() {
            let mut sim = Simulation::new(base(), integrator).unwrap();
            sim.step(0.01).unwrap();
            *sim.system_mut() = other.clone();
            let err = sim.step(0.01).expect_err(what);
            assert_eq!(
                err,
                StepError::Invalid(ModelError::TopologyMismatch { what }),
                "{integrator:?}"
            );
            assert_eq!(sim.system(), &other, "{integrator:?}: the system changed");
        }
    }
}

#[test]
fn material_and_state_changes_keep_the_topology() {
    let a = base();
    let mut b = base();
    b.set_damping(3.0).unwrap();
    let moved: Vec<DVec3> = a.positions().iter().map(|x| *x + DVec3::X).collect();
    b.set_state(&moved, a.velocities()).unwrap();
    assert!(a.same_topology(&b));
    assert_eq!(a.topology().check(&b.topology()), Ok(()));
    let mut s = BackwardEuler::new(&a, NewtonSettings::default()).unwrap();
    s.step(&mut b, 0.01).unwrap();
    for (other, _) in variants() {
        assert!(!a.same_topology(&other));
    }
}

/// The state's fingerprint is FNV-1a over the positions' and then the velocities'
/// coordinate bits (written again here, byte by byte), so it changes with any one bit of
/// the state and not with anything else (the masses, the springs).
#[test]
fn the_state_fingerprint_is_fnv_of_the_state_bits_and_sees_one_bit() {
    let fnv = |values: &[f64]| {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for v in values {
            for byte in v.to_bits().to_le_bytes() {
                h = (h ^ u64::from(byte)).wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
        h
    };
    let mut system = SpringSystem::cloth(&sinew_spring_sim::ClothGrid::lab()).unwrap();
    let n = system.len();
    let x: Vec<DVec3> = system.positions().to_vec();
    let v: Vec<DVec3> = (0..n)
        .map(|i| DVec3::new(i as f64 * 0.25, -0.5, 1e-3))
        .collect();
    system.set_state(&x, &v).unwrap();
    let coordinates: Vec<f64> = system
        .positions()
        .iter()
        .chain(system.velocities())
        .flat_map(|p| [p.x, p.y, p.z])
        .collect();
    assert_eq!(system.state_fingerprint(), fnv(&coordinates));
    let mut other = system.clone();
    let mut x1 = x.clone();
    x1[n / 2].y = f64::from_bits(x1[n / 2].y.to_bits() + 1);
    other
        .set_state(&x1, other.velocities().to_vec().as_slice())
        .unwrap();
    assert_ne!(other.state_fingerprint(), system.state_fingerprint());
    other.set_state(&x, system.velocities()).unwrap();
    assert_eq!(other.state_fingerprint(), system.state_fingerprint());
}
