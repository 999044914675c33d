//! Newton's assembly on a thread pool (the springs' gradient and Hessian blocks computed
//! per spring, then gathered per particle in spring order) gives bitwise what the
//! sequential loops give: whole steps on one thread and on two are compared bit for
//! bit, for the undamped and the damped spring terms, the projected and the softened
//! Hessian, and the direct solver as well as PCG.

use sinew_math::DVec3;
use sinew_spring_sim::potential::{DihedralBending, Hinge};
use sinew_spring_sim::*;

/// `steps` backward Euler steps of `h` on `threads` threads; the end state and the
/// reports' sums of Newton, PCG and softened-Hessian iterations.
fn run(
    system: &SpringSystem,
    solver: LinearSolverChoice,
    threads: usize,
    h: f64,
    steps: usize,
) -> (SpringSystem, [usize; 3]) {
    run_with(system, solver, threads, h, steps, |_| {})
}

/// [`run`] with `extend` adding terms to the integrator first.
fn run_with(
    system: &SpringSystem,
    solver: LinearSolverChoice,
    threads: usize,
    h: f64,
    steps: usize,
    extend: impl Fn(&mut BackwardEuler),
) -> (SpringSystem, [usize; 3]) {
    let settings = NewtonSettings {
        linear_solver: solver,
        threads,
        ..Default::default()
    };
    let mut be = BackwardEuler::new(system, settings).unwrap();
    extend(&mut be);
    // A term that widens the pattern rebuilds the solvers, which keep their threads.
    assert_eq!(be.threads(), crate::common::expected_threads(threads));
    let mut s = system.clone();
    let mut counts = [0; 3];
    for _ in 0..steps {
        let r = be.step(&mut s, h).unwrap();
        counts[0] += r.iterations;
        counts[1] += r.linear_iterations;
        counts[2] += r.exact_hessian_iterations;
    }
    (s, counts)
}

fn assert_same(name: &str, a: &(SpringSystem, [usize; 3]), b: &(SpringSystem, [usize; 3])) {
    assert_eq!(a.1, b.1, "{name}: iteration counts differ");
    assert_eq!(a.0.positions(), b.0.positions(), "{name}: positions differ");
    assert_eq!(
        a.0.velocities(),
        b.0.velocities(),
        "{name}: velocities differ"
    );
}

/// W6 undamped (101 x 101, two corners pinned): PCG and the direct solver each read the
/// assembled matrix, so both must see the same bits on one and two threads.
#[test]
fn undamped_w6_steps_are_bitwise_the_same_on_one_and_two_threads() {
    let system = SpringSystem::cloth(&ClothGrid::lab_sized(101, 0.02).with_damping(0.0)).unwrap();
    for solver in [LinearSolverChoice::Pcg, LinearSolverChoice::Direct] {
        let one = run(&system, solver, 1, 1.0 / 60.0, 2);
        let two = run(&system, solver, 2, 1.0 / 60.0, 2);
        assert!(one.1[0] > 0, "{solver:?}: no Newton iteration ran");
        assert_same(&format!("{solver:?}"), &one, &two);
    }
}

/// A damped 61 x 61 sheet (above one chunk of unknowns, so it has a pool) compressed to
/// 0.6 of its size about its centre at stiffness 1e3: Newton is slow on the projected
/// Hessian there, so the softened one is assembled too, with its own curvature.
#[test]
fn a_compressed_damped_sheet_steps_bitwise_alike_on_one_and_two_threads() {
    let mut grid = ClothGrid::lab_sized(61, 0.03).with_damping(0.2);
    grid.material.stiffness = 1e3;
    let mut system = SpringSystem::cloth(&grid).unwrap();
    crate::common::scale_about_centre(&mut system, 0.6);
    let one = run(&system, LinearSolverChoice::Pcg, 1, 1.0 / 30.0, 2);
    let two = run(&system, LinearSolverChoice::Pcg, 2, 1.0 / 30.0, 2);
    eprintln!("Newton, PCG, softened iterations: {:?}", one.1);
    assert!(one.1[0] > 0);
    assert_same("compressed", &one, &two);
}

/// With a term besides inertia, gravity, springs and damping (dihedral bending, which
/// also widens the Hessian's pattern with the pairs across its hinges), the pool's
/// assembly cannot fold the other terms into its gather and runs them first: the same
/// bits as one thread still, on a sheet bent out of plane so the hinges act.
#[test]
fn a_bent_sheet_with_bending_steps_bitwise_alike_on_one_and_two_threads() {
    let grid = ClothGrid::lab_sized(61, 0.03).with_damping(0.0);
    let mut system = SpringSystem::cloth(&grid).unwrap();
    let rest = system.positions().to_vec();
    let mesh = TriangleMesh::new(rest.clone(), grid.triangles()).unwrap();
    let hinges: Vec<Hinge> = mesh
        .hinges()
        .unwrap()
        .into_iter()
        .filter_map(|(e, o)| Hinge::at_rest(&rest, e, o, 1e-2))
        .collect();
    assert!(hinges.len() > 10_000, "{} hinges", hinges.len());
    // A ripple across the sheet: every hinge starts away from its rest angle.
    let x: Vec<DVec3> = rest
        .iter()
        .map(|&p| p + DVec3::new(0.0, 0.05 * (7.0 * p.x).sin() * (5.0 * p.z).cos(), 0.0))
        .collect();
    let v = vec![DVec3::ZERO; x.len()];
    system.set_state(&x, &v).unwrap();
    let add_bending = |be: &mut BackwardEuler| {
        let term = DihedralBending::new(hinges.clone());
        let pairs = term.coupled_pairs();
        be.add_coupled_term(&system, Box::new(term), &pairs)
            .unwrap();
    };
    for solver in [LinearSolverChoice::Pcg, LinearSolverChoice::Direct] {
        let one = run_with(&system, solver, 1, 1.0 / 60.0, 2, add_bending);
        let two = run_with(&system, solver, 2, 1.0 / 60.0, 2, add_bending);
        assert!(one.1[0] > 0, "{solver:?}: no Newton iteration ran");
        assert_same(&format!("bending, {solver:?}"), &one, &two);
    }
}
