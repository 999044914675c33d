//! Backward Euler by Newton against exact answers: the closed-form recurrence of one
//! particle on a spring, monotone decrease of `g`, the static equilibrium reached by a
//! heavily damped run (checked by forces and second-order perturbations, independently of
//! the stepper), agreement of the direct and PCG solves, and stability of W5.

use sinew_math::DVec3;
use sinew_spring_sim::*;

fn settings(solver: LinearSolverChoice, tolerance: f64) -> NewtonSettings {
    NewtonSettings {
        linear_solver: solver,
        tolerance,
        ..Default::default()
    }
}

/// One free particle hanging below a fixed one on a spring, moving along the spring's
/// axis (gravity and the initial velocity along it). Along the axis the spring force is
/// linear in the length (for any `l > 0`), so backward Euler is the linear recurrence
/// `(m/h^2 + k + c/h) s' = m/h^2 (s + h v) + k L + m g + c/h s`, `v' = (s' - s)/h`
/// for the length `s`, which Newton must reproduce to round-off.
#[test]
fn single_spring_matches_the_closed_form_recurrence() {
    let (m, k, rest, c, g, h) = (2.0, 50.0, 1.0, 0.7, 0.3, 0.05);
    for solver in [LinearSolverChoice::Direct, LinearSolverChoice::Pcg] {
        let particles = [
            Particle {
                position: DVec3::ZERO,
                velocity: DVec3::ZERO,
                mass: 1.0,
                fixed: true,
            },
            Particle {
                position: DVec3::new(0.0, -1.4, 0.0),
                velocity: DVec3::new(0.0, 0.8, 0.0),
                mass: m,
                fixed: false,
            },
        ];
        let material = Material {
            stiffness: k,
            damping: c,
            gravity: DVec3::new(0.0, -g, 0.0),
        };
        let spring = SpringSpec {
            particles: [0, 1],
            rest_length: Some(rest),
            stiffness: None,
        };
        let system = SpringSystem::new(&particles, &[spring], material).unwrap();
        let mut sim =
            Simulation::new(system, Integrator::BackwardEuler(settings(solver, 1e-13))).unwrap();
        let (mut s, mut v) = (1.4, -0.8);
        let mut min_len = f64::INFINITY;
        for _ in 0..200 {
            let report = sim.step(h).unwrap();
            assert_eq!(report.stop, StepStop::Converged);
            let s_new = (m / (h * h) * (s + h * v) + k * rest + m * g + c / h * s)
                / (m / (h * h) + k + c / h);
            v = (s_new - s) / h;
            s = s_new;
            min_len = min_len.min(s);
            let x = sim.system().positions()[1];
            let vel = sim.system().velocities()[1];
            assert!((x.y + s).abs() <= 1e-12, "{} vs {}", x.y, -s);
            assert_eq!((x.x, x.z), (0.0, 0.0));
            assert!((vel.y + v).abs() <= 1e-10);
        }
        // The run goes through compression too, where the PSD clamp is active.
        assert!(min_len < rest, "min length {min_len}");
    }
}

/// A crumpled lab cloth (every particle pushed at random, so springs are compressed and
/// stretched) at a large step: `g` never increases over the Newton iterations, and the
/// line search really had to backtrack somewhere.
#[test]
fn objective_never_increases() {
    let mut system = SpringSystem::cloth(&ClothGrid::lab_sized(6, 0.2).with_damping(0.5)).unwrap();
    let mut seed = 12345u64;
    let mut rnd = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let positions: Vec<DVec3> = system
        .positions()
        .iter()
        .zip(system.fixed())
        .map(|(x, f)| {
            if *f {
                *x
            } else {
                *x + 0.3 * DVec3::new(rnd(), rnd(), rnd())
            }
        })
        .collect();
    let velocities = vec![DVec3::ZERO; positions.len()];
    system.set_state(&positions, &velocities).unwrap();
    let mut total_backtracks = 0;
    for solver in [LinearSolverChoice::Direct, LinearSolverChoice::Pcg] {
        let mut s = settings(solver, 1e-10);
        s.record_objective = true;
        let mut sim = Simulation::new(system.clone(), Integrator::BackwardEuler(s)).unwrap();
        for _ in 0..10 {
            let report = sim.step(0.5).unwrap();
            assert_eq!(report.stop, StepStop::Converged);
            total_backtracks += report.backtracks;
            let trace = sim.backward_euler().unwrap().objective_trace();
            assert_eq!(trace.len(), report.iterations + 1);
            for w in trace.windows(2) {
                assert!(
                    w[1] <= w[0] + 1e-13 * w[0].abs(),
                    "g rose: {} -> {}",
                    w[0],
                    w[1]
                );
            }
        }
    }
    assert!(
        total_backtracks > 0,
        "the test should exercise the line search"
    );
}

fn potential(system: &SpringSystem, x: &[DVec3]) -> f64 {
    let springs: f64 = system
        .springs()
        .iter()
        .map(|s| spring::energy(x[s.a], x[s.b], s.rest_length, s.stiffness))
        .sum();
    let gravity: f64 = system
        .masses()
        .iter()
        .zip(x)
        .map(|(m, x)| -m * system.material().gravity.dot(*x))
        .sum();
    springs + gravity
}

/// Heavy damping and a large step settle a small cloth to rest. The final state is
/// checked without the stepper: the net force on every free particle vanishes, and the
/// potential energy rises under every random small perturbation (a minimum, not a
/// saddle).
#[test]
fn heavily_damped_large_steps_settle_to_the_static_equilibrium() {
    let mut grid = ClothGrid::lab_sized(5, 0.2).with_damping(20.0);
    grid.material.gravity = DVec3::new(0.0, -9.81, 0.0);
    let system = SpringSystem::cloth(&grid).unwrap();
    let mut sim = Simulation::new(
        system,
        Integrator::BackwardEuler(settings(LinearSolverChoice::Auto, 1e-12)),
    )
    .unwrap();
    for _ in 0..400 {
        sim.step(0.25).unwrap();
    }
    let system = sim.system();
    let force = crate::common::static_force(system);
    assert!(force <= 1e-8, "net force {force}");
    let speed = system
        .velocities()
        .iter()
        .fold(0.0f64, |m, v| m.max(v.length()));
    assert!(speed <= 1e-8, "speed {speed}");
    let x0 = system.positions().to_vec();
    let e0 = potential(system, &x0);
    let mut seed = 99u64;
    for _ in 0..50 {
        let x: Vec<DVec3> = x0
            .iter()
            .zip(system.fixed())
            .map(|(x, f)| {
                let mut r = || {
                    seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
                    (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                };
                if *f {
                    *x
                } else {
                    *x + 1e-4 * DVec3::new(r(), r(), r())
                }
            })
            .collect();
        assert!(potential(system, &x) > e0, "not a minimum");
    }
    // The cloth hangs below its fixed corners.
    assert!(x0.iter().all(|x| x.y <= 1.5 + 1e-12));
}

/// Direct and PCG Newton give the same trajectory to within the solve tolerance.
#[test]
fn direct_and_pcg_agree() {
    let system = SpringSystem::cloth(&ClothGrid::lab()).unwrap();
    let run = |solver| {
        let mut sim = Simulation::new(
            system.clone(),
            Integrator::BackwardEuler(settings(solver, 1e-11)),
        )
        .unwrap();
        let mut used = Vec::new();
        for _ in 0..60 {
            used.push(sim.step(1.0 / 60.0).unwrap().linear_solver);
        }
        (sim.into_system(), used)
    };
    let (direct, used_d) = run(LinearSolverChoice::Direct);
    let (pcg, used_p) = run(LinearSolverChoice::Pcg);
    assert!(used_d.iter().all(|u| *u == Some(LinearSolverKind::Direct)));
    assert!(used_p.iter().all(|u| *u == Some(LinearSolverKind::Pcg)));
    let gap = direct
        .positions()
        .iter()
        .zip(pcg.positions())
        .fold(0.0f64, |m, (a, b)| m.max(a.distance(*b)));
    assert!(gap <= 1e-9, "direct and PCG differ by {gap}");
    assert!(gap > 0.0 || direct.positions() == pcg.positions());
}

/// W5: stiff lab cloth at h = 1/30 stays finite and bounded, every step converges, and
/// the report says so.
#[test]
fn stiff_cloth_is_stable_at_large_steps() {
    for stiffness in [1e4, 1e6] {
        let mut grid = ClothGrid::lab().with_damping(0.0);
        grid.material.stiffness = stiffness;
        let system = SpringSystem::cloth(&grid).unwrap();
        let mut sim = Simulation::new(system, Integrator::default()).unwrap();
        for _ in 0..30 {
            let report = sim.step(1.0 / 30.0).unwrap();
            assert_eq!(report.stop, StepStop::Converged);
            assert!(report.residual <= report.tolerance);
            assert!(report.energy_after.total().is_finite());
        }
        assert!(
            sim.system()
                .positions()
                .iter()
                .all(|x| x.is_finite() && x.length() < 100.0)
        );
    }
}

/// With damping on, backward Euler's total energy never rises from one step to the
/// next by more than 1e-9 relative (W4 and W5 k = 1e4 with the lab's damping 0.2).
#[test]
fn damped_energy_never_rises() {
    for (stiffness, h) in [(100.0, 1.0 / 60.0), (1e4, 1.0 / 30.0)] {
        let mut grid = ClothGrid::lab();
        grid.material.stiffness = stiffness;
        let system = SpringSystem::cloth(&grid).unwrap();
        let mut sim = Simulation::new(system, Integrator::default()).unwrap();
        for _ in 0..60 {
            let r = sim.step(h).unwrap();
            let (e0, e1) = (r.energy_before.total(), r.energy_after.total());
            assert!(e1 <= e0 + 1e-9 * e0.abs(), "energy rose: {e0} -> {e1}");
        }
    }
}

/// A system at rest at its equilibrium (to round-off) costs no Newton iteration.
#[test]
fn system_at_rest_is_already_solved() {
    let particles = [
        Particle {
            position: DVec3::ZERO,
            velocity: DVec3::ZERO,
            mass: 1.0,
            fixed: true,
        },
        Particle::at_rest(DVec3::new(0.0, -1.0 - 0.3 / 100.0, 0.0), 1.0),
    ];
    let system = SpringSystem::new(
        &particles,
        &[SpringSpec {
            particles: [0, 1],
            rest_length: Some(1.0),
            stiffness: None,
        }],
        Material {
            damping: 0.0,
            ..Material::lab()
        },
    )
    .unwrap();
    let mut sim = Simulation::new(system, Integrator::default()).unwrap();
    for _ in 0..3 {
        assert_eq!(sim.step(1.0 / 60.0).unwrap().iterations, 0);
    }
}

/// Symplectic Euler above its stability limit is an error with the system unchanged, not
/// NaN; the flawed reference runs and is labelled as such.
#[test]
fn explicit_blowup_is_reported_and_undone() {
    let mut grid = ClothGrid::lab().with_damping(0.0);
    grid.material.stiffness = 1e6;
    let system = SpringSystem::cloth(&grid).unwrap();
    let mut sim =
        Simulation::new(system.clone(), Integrator::SymplecticEuler { substeps: 1 }).unwrap();
    let mut failed = None;
    for step in 0..200 {
        let before = sim.system().clone();
        match sim.step(1.0 / 30.0) {
            Ok(_) => {}
            Err(e) => {
                assert!(matches!(e, StepError::NonFinite { .. }));
                assert_eq!(sim.system(), &before);
                failed = Some(step);
                break;
            }
        }
    }
    assert!(
        failed.is_some(),
        "one substep at k = 1e6, h = 1/30 must blow up"
    );
    let mut flawed = Simulation::new(system, Integrator::FlawedReportMethod).unwrap();
    let report = flawed.step(1.0 / 30.0).unwrap();
    assert_eq!(report.integrator, IntegratorKind::FlawedReportMethod);
    assert_eq!(report.iterations, 32);
}

/// The run metrics count what happened: steps, iterations, energies, divergence.
#[test]
fn run_metrics_report_the_run() {
    let system = SpringSystem::cloth(&ClothGrid::lab()).unwrap();
    let mut sim = Simulation::new(system.clone(), Integrator::default()).unwrap();
    let m = run(&mut sim, 1.0 / 60.0, 20).unwrap();
    assert_eq!(m.steps, 20);
    assert_eq!(m.integrator, "backward_euler");
    assert!(m.newton_iterations_total >= m.newton_iterations_max);
    assert!(m.newton_iterations_max >= 1 && m.newton_iterations_max <= 50);
    assert!(!m.diverged && m.stopped_by.is_none());
    assert_eq!(m.energy_start, system.energies().total());
    assert_eq!(m.energy_end, sim.system().energies().total());
    assert!(m.energy_increase_max <= 1e-9);
    assert!(m.residual_max <= 1e-9 * 3600.0);
    let mut grid = ClothGrid::lab().with_damping(0.0);
    grid.material.stiffness = 1e6;
    let stiff = SpringSystem::cloth(&grid).unwrap();
    let mut explicit = Simulation::new(stiff, Integrator::SymplecticEuler { substeps: 1 }).unwrap();
    let m = run(&mut explicit, 1.0 / 30.0, 300).unwrap();
    assert!(m.diverged && m.steps < 300 && m.stopped_by.is_some());
    assert!(run(&mut sim, -1.0, 1).is_err());
}

/// Regression from the stress grid (docs/stress.md): the lab cloth with every particle
/// scaled by 2 about the sheet's centre, stiffness 1e7, no damping, one step of 1/60.
/// The full projected-Newton step is accepted every iteration but is far too short while
/// the sheet snaps back through the non-convex (compressed) region, so Newton crawled to
/// the cap of 50 at a residual of 1.8e2 (tolerance 3.6e-6). The line search now doubles an
/// accepted full step while `g` keeps falling; the step converges within the default cap
/// and `g` still never rises.
#[test]
fn stretched_stiff_sheet_converges_within_the_default_cap() {
    let mut grid = ClothGrid::lab().with_damping(0.0);
    grid.material.stiffness = 1e7;
    let mut system = SpringSystem::cloth(&grid).unwrap();
    crate::common::scale_about_centre(&mut system, 2.0);
    let settings = NewtonSettings {
        record_objective: true,
        ..NewtonSettings::default()
    };
    let mut be = BackwardEuler::new(&system, settings).unwrap();
    let report = be.step(&mut system, 1.0 / 60.0).unwrap();
    assert_eq!(report.stop, StepStop::Converged, "{report:?}");
    assert!(report.residual <= report.tolerance);
    let trace = be.objective_trace();
    assert!(trace.windows(2).all(|w| w[1] <= w[0]), "g rose: {trace:?}");
}

/// A sheet compressed to half size (every spring, pins too) must buckle out of its plane:
/// `g` is not convex there, and Newton on the projected Hessian (or the exact Hessian
/// only where it is positive definite) hit the cap of 50 at a residual 2.5e5 times the
/// tolerance with the direct solver. The softened Hessian, which keeps as much of the
/// compressed springs' negative curvature as stays positive definite, converges within
/// the default cap; `g` still never rises and the softened matrix was used.
#[test]
fn compressed_sheet_converges_within_the_default_cap() {
    let mut grid = ClothGrid::lab().with_damping(0.0);
    grid.material.stiffness = 1e3;
    let mut system = SpringSystem::cloth(&grid).unwrap();
    crate::common::scale_about_centre(&mut system, 0.5);
    let y0 = system.positions()[0].y;
    let settings = NewtonSettings {
        record_objective: true,
        linear_solver: LinearSolverChoice::Direct,
        ..NewtonSettings::default()
    };
    let mut be = BackwardEuler::new(&system, settings).unwrap();
    let report = be.step(&mut system, 1.0 / 15.0).unwrap();
    assert_eq!(report.stop, StepStop::Converged, "{report:?}");
    assert!(report.residual <= report.tolerance);
    assert!(report.exact_hessian_iterations > 0, "{report:?}");
    // g evaluated directly rounds at about 1e-16 of its terms; the line search decides
    // on the exact differences (as in `objective_never_increases`).
    let trace = be.objective_trace();
    assert!(
        trace.windows(2).all(|w| w[1] <= w[0] + 1e-13 * w[0].abs()),
        "g rose: {trace:?}"
    );
    // It did buckle: the sheet left its plane.
    assert!(system.positions().iter().any(|p| (p.y - y0).abs() > 1e-3));
}

/// `Auto` chooses the linear solver from counts, never from a clock, so two identical runs
/// are bitwise identical: the lab cloth settled with the default integrator at h = 0.5 (a
/// case that once ended up to 6e-8 apart when the choice was timed), and W5 k = 1e6, where
/// the choice moves from PCG to the direct solve (and back to PCG once every
/// `reprobe_interval` steps, here 8) by the cost model's crossover.
#[test]
fn auto_gives_bitwise_identical_runs() {
    let run = |system: &SpringSystem, integrator: Integrator, h: f64, steps: usize| {
        let mut sim = Simulation::new(system.clone(), integrator).unwrap();
        // Per step: the solver it ended on and whether PCG ran in it (a step that
        // starts on PCG may finish on the direct solve).
        let solvers: Vec<_> = (0..steps)
            .map(|_| {
                let report = sim.step(h).unwrap();
                (report.linear_solver, report.linear_iterations > 0)
            })
            .collect();
        (sim.into_system(), solvers)
    };
    let lab = SpringSystem::cloth(&ClothGrid::lab()).unwrap();
    let (a, _) = run(&lab, Integrator::default(), 0.5, 40);
    let (b, _) = run(&lab, Integrator::default(), 0.5, 40);
    assert_eq!(a.positions(), b.positions());
    assert_eq!(a.velocities(), b.velocities());

    let mut grid = ClothGrid::lab().with_damping(0.0);
    grid.material.stiffness = 1e6;
    let stiff = SpringSystem::cloth(&grid).unwrap();
    let auto = Integrator::BackwardEuler(NewtonSettings {
        reprobe_interval: 8,
        ..Default::default()
    });
    let (a, solvers_a) = run(&stiff, auto, 1.0 / 30.0, 30);
    let (b, solvers_b) = run(&stiff, auto, 1.0 / 30.0, 30);
    assert_eq!(a.positions(), b.positions());
    assert_eq!(a.velocities(), b.velocities());
    assert_eq!(solvers_a, solvers_b);
    // Once the sheet is moving, PCG needs about 35 iterations per Newton iteration here,
    // above the crossover of about 23 for this 357-unknown matrix: the direct solve, with
    // PCG observed again after every 8 direct steps (such a step may move to the direct
    // solve after its first Newton iterations).
    use LinearSolverKind::{Direct, Pcg};
    assert_eq!(solvers_a[0].0, Some(Pcg));
    assert!(solvers_a[0].1);
    let direct = solvers_a.iter().filter(|s| s.0 == Some(Direct)).count();
    assert!(direct >= 20, "{solvers_a:?}");
    let longest_run_without_pcg = solvers_a.split(|s| s.1).map(<[_]>::len).max().unwrap();
    assert_eq!(longest_run_without_pcg, 8, "{solvers_a:?}");
}

/// On soft cloths PCG needs a few iterations per Newton iteration, far below the
/// crossover, and `Auto` never builds the direct solver.
#[test]
fn auto_stays_on_pcg_for_soft_cloths() {
    for system in [
        SpringSystem::cloth(&ClothGrid::lab()).unwrap(),
        SpringSystem::cloth(&ClothGrid::lab_sized(41, 0.05).with_damping(0.0)).unwrap(),
    ] {
        let mut be = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
        let mut s = system.clone();
        for _ in 0..10 {
            let r = be.step(&mut s, 1.0 / 60.0).unwrap();
            assert_eq!(r.linear_solver, Some(LinearSolverKind::Pcg));
        }
        assert!(be.direct_solver().is_none());
        let costs = be.solver_costs().unwrap();
        assert!(costs.crossover_iterations() > 10.0, "{costs:?}");
    }
}

/// The cost model's counts against a hand count: a chain of three free particles hanging
/// from a fixed one (a path graph, no fill under any ordering that eliminates an end
/// first). Block columns have 2, 2 and 1 blocks: scalar columns with 5, 4, 3 | 5, 4, 3 |
/// 2, 1, 0 entries below the diagonal.
#[test]
fn solver_costs_count_a_chain_exactly() {
    let particles: Vec<Particle> = (0..4)
        .map(|i| Particle {
            fixed: i == 0,
            ..Particle::at_rest(DVec3::new(0.0, -(i as f64), 0.0), 1.0)
        })
        .collect();
    let springs: Vec<SpringSpec> = (0..3).map(|i| SpringSpec::between(i, i + 1)).collect();
    let system = SpringSystem::new(&particles, &springs, Material::default()).unwrap();
    let mut be = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
    let c = be.solver_costs().unwrap();
    assert_eq!(c.dim, 9);
    // Lower triangle: 3 diagonal blocks of 6 entries and 2 coupling blocks of 9.
    assert_eq!(c.matrix_nonzeros, 36);
    let d = [5.0, 4.0, 3.0, 5.0, 4.0, 3.0, 2.0, 1.0, 0.0];
    assert_eq!(c.factor_nonzeros, d.iter().sum::<f64>());
    let madds: f64 = d.iter().map(|d| 0.5 * d * (d + 1.0)).sum();
    assert_eq!(c.factor_multiply_adds, madds);
    // The counts match faer's own symbolic factorization of the scalar matrix.
    be.assemble_newton_matrix(&system, 1.0 / 60.0);
    assert!(be.factor_newton_matrix().unwrap());
    let faer_len = be.direct_solver().unwrap().factor_len();
    assert!(
        faer_len as f64 >= c.factor_nonzeros + c.dim as f64,
        "{faer_len}"
    );
}

/// PCG's work on a system above one chunk (W6: 30 597 unknowns) is cut in chunks fixed by
/// the dimension and its dot products summed in chunk order, so 1 and 2 threads (and the
/// `parallel` feature off) give bitwise the same steps.
#[test]
fn w6_is_bitwise_the_same_on_one_and_two_threads() {
    let system = SpringSystem::cloth(&ClothGrid::lab_sized(101, 0.02).with_damping(0.2)).unwrap();
    let run = |threads: usize| {
        let settings = NewtonSettings {
            linear_solver: LinearSolverChoice::Pcg,
            threads,
            ..Default::default()
        };
        let mut be = BackwardEuler::new(&system, settings).unwrap();
        let mut s = system.clone();
        let mut linear = 0;
        for _ in 0..3 {
            linear += be.step(&mut s, 1.0 / 60.0).unwrap().linear_iterations;
        }
        (s, linear)
    };
    let (one, linear_one) = run(1);
    let (two, linear_two) = run(2);
    assert!(linear_one > 0);
    assert_eq!(linear_one, linear_two);
    assert_eq!(one.positions(), two.positions());
    assert_eq!(one.velocities(), two.velocities());
    // And the default (one thread per core) is the same run.
    let (all, _) = run(0);
    assert_eq!(one.positions(), all.positions());
}

/// A run that starts with every energy zero (the lab cloth at rest at the height where
/// gravity's energy is zero) measures its rises against the steps' own energy scale: an
/// undamped explicit run's rises are small fractions of it, not round-off divided by the
/// smallest positive double.
#[test]
fn a_run_from_zero_energy_measures_its_rises_against_the_steps_energy() {
    let mut grid = ClothGrid::lab().with_damping(0.0);
    grid.origin = DVec3::ZERO;
    let system = SpringSystem::cloth(&grid).unwrap();
    let start = system.energies();
    assert_eq!(
        (start.kinetic, start.spring, start.gravity),
        (0.0, 0.0, 0.0)
    );
    let mut sim = Simulation::new(system, Integrator::SymplecticEuler { substeps: 50 }).unwrap();
    let mut largest_step_scale = 0.0f64;
    let mut rose = 0;
    let m = run_observed(&mut sim, 1.0 / 60.0, 600, |_, report, _| {
        if report.energy_after.total() > report.energy_before.total() {
            rose += 1;
        }
        largest_step_scale = largest_step_scale.max(report.energy_after.scale());
    })
    .unwrap();
    // The undamped run's energy does rise in some steps (so the metric is exercised),
    // each time by a small fraction of the energy the cloth has by then.
    assert!(rose > 0, "no step's energy rose");
    assert!(
        m.energy_increase_max > 0.0 && m.energy_increase_max < 1e-4,
        "energy_increase_max {:e} (largest scale {largest_step_scale:e})",
        m.energy_increase_max
    );
}
