//! Whole backward Euler steps are bitwise the same on one, two and three threads on a
//! sheet just above the size from which the work goes to a thread pool (its chunks of
//! unknowns, of particles and of springs all end in a short one), with the line search,
//! the assembly and PCG on the pool; a step's reported energies are the system's own, bit
//! for bit.

use sinew_spring_sim::*;

fn assert_same_energies(a: &Energies, b: &Energies, threads: usize) {
    let bits = |e: &Energies| [e.kinetic, e.spring, e.gravity].map(f64::to_bits);
    assert_eq!(bits(a), bits(b), "{threads} threads: {a:?} against {b:?}");
}

#[test]
fn a_sheet_just_above_the_pool_size_steps_alike_on_one_two_and_three_threads() {
    // 46 x 46, damped, two corners pinned: 6 342 unknowns (the pool starts above 6 144).
    let system = SpringSystem::cloth(&ClothGrid::lab_sized(46, 0.04).with_damping(0.2)).unwrap();
    let run = |threads: usize| {
        let settings = NewtonSettings {
            linear_solver: LinearSolverChoice::Pcg,
            threads,
            ..Default::default()
        };
        let mut be = BackwardEuler::new(&system, settings).unwrap();
        assert_eq!(be.threads(), crate::common::expected_threads(threads));
        let mut s = system.clone();
        let (mut newton, mut linear) = (0, 0);
        for _ in 0..3 {
            let before = s.energies();
            let r = be.step(&mut s, 1.0 / 60.0).unwrap();
            // The report's energies are computed on the pool, as the system's own.
            assert_same_energies(&r.energy_before, &before, threads);
            assert_same_energies(&r.energy_after, &s.energies(), threads);
            newton += r.iterations;
            linear += r.linear_iterations;
        }
        (s, newton, linear)
    };
    let one = run(1);
    assert!(one.1 > 0 && one.2 > 0, "no Newton or PCG iteration ran");
    for threads in [2, 3] {
        let other = run(threads);
        assert_eq!((other.1, other.2), (one.1, one.2), "{threads} threads");
        assert_eq!(other.0.positions(), one.0.positions(), "{threads} threads");
        assert_eq!(
            other.0.velocities(),
            one.0.velocities(),
            "{threads} threads"
        );
    }
}
