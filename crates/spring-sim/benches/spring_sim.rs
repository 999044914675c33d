//! Criterion benchmarks: time per step on the shared workloads (W4, W5, W6) for each
//! linear solver, and the kernels (Newton matrix assembly, numeric factorization, one
//! Newton iteration). Accuracy of each configuration is measured by `benches/accuracy.rs`.

use criterion::{Criterion, criterion_group, criterion_main};
use sinew_spring_sim::*;
use std::hint::black_box;
use std::time::{Duration, Instant};

fn w4(damping: f64) -> SpringSystem {
    SpringSystem::cloth(&ClothGrid::lab().with_damping(damping)).unwrap()
}

fn w5(stiffness: f64) -> SpringSystem {
    let mut grid = ClothGrid::lab().with_damping(0.0);
    grid.material.stiffness = stiffness;
    SpringSystem::cloth(&grid).unwrap()
}

fn w6() -> SpringSystem {
    SpringSystem::cloth(&ClothGrid::lab_sized(101, 0.02).with_damping(0.0)).unwrap()
}

fn settings(solver: LinearSolverChoice) -> NewtonSettings {
    NewtonSettings {
        linear_solver: solver,
        ..Default::default()
    }
}

/// Times steps of a run that restarts from the initial state every `run_len` steps (the
/// restart is not timed), so the measured steps are the workload's own.
fn per_step(
    c: &mut Criterion,
    group: &str,
    name: &str,
    system: &SpringSystem,
    integrator: Integrator,
    h: f64,
    run_len: usize,
) {
    let mut g = c.benchmark_group(group);
    g.warm_up_time(Duration::from_millis(500));
    g.measurement_time(Duration::from_secs(2));
    g.sample_size(10);
    let mut sim = Simulation::new(system.clone(), integrator).unwrap();
    let mut done = 0;
    g.bench_function(name, |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                if done == run_len {
                    sim = Simulation::new(system.clone(), integrator).unwrap();
                    done = 0;
                }
                let t = Instant::now();
                black_box(sim.step(h).unwrap());
                total += t.elapsed();
                done += 1;
            }
            total
        })
    });
    g.finish();
}

fn steps(c: &mut Criterion) {
    let solvers = [
        ("auto", LinearSolverChoice::Auto),
        ("direct", LinearSolverChoice::Direct),
        ("pcg", LinearSolverChoice::Pcg),
    ];
    for (damping, tag) in [(0.0, "w4_damping0"), (0.2, "w4_damping0.2")] {
        for (name, solver) in solvers {
            let integrator = Integrator::BackwardEuler(settings(solver));
            per_step(c, tag, name, &w4(damping), integrator, 1.0 / 60.0, 600);
        }
    }
    for (k, tag) in [(1e4, "w5_k1e4"), (1e6, "w5_k1e6")] {
        for (name, solver) in solvers {
            let integrator = Integrator::BackwardEuler(settings(solver));
            per_step(c, tag, name, &w5(k), integrator, 1.0 / 30.0, 300);
        }
    }
    per_step(
        c,
        "w4_damping0.2",
        "symplectic_euler_50",
        &w4(0.2),
        Integrator::SymplecticEuler { substeps: 50 },
        1.0 / 60.0,
        600,
    );
    per_step(
        c,
        "w4_damping0.2",
        "flawed_report_method",
        &w4(0.2),
        Integrator::FlawedReportMethod,
        1.0 / 60.0,
        600,
    );
    per_step(
        c,
        "w6",
        "pcg",
        &w6(),
        Integrator::BackwardEuler(settings(LinearSolverChoice::Pcg)),
        1.0 / 60.0,
        30,
    );
}

fn kernels(c: &mut Criterion) {
    let mut g = c.benchmark_group("kernels");
    g.warm_up_time(Duration::from_millis(500));
    g.measurement_time(Duration::from_secs(2));
    g.sample_size(10);
    for (tag, system) in [("w4", w4(0.2)), ("w6", w6())] {
        for (sname, structure) in [
            ("supernodal", FactorStructure::Supernodal),
            ("simplicial", FactorStructure::Simplicial),
        ] {
            if tag == "w6" && structure == FactorStructure::Simplicial {
                continue; // 1.7 s per factorization (FAER-NOTES.md); not worth the machine time.
            }
            let s = NewtonSettings {
                factor_structure: structure,
                ..Default::default()
            };
            let mut be = BackwardEuler::new(&system, s).unwrap();
            be.assemble_newton_matrix(&system, 1.0 / 60.0);
            g.bench_function(format!("{tag}_factor_{sname}"), |b| {
                b.iter(|| assert!(be.factor_newton_matrix().unwrap()))
            });
        }
        let mut be = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
        g.bench_function(format!("{tag}_assemble"), |b| {
            b.iter(|| be.assemble_newton_matrix(black_box(&system), 1.0 / 60.0))
        });
        for (name, solver) in [
            ("direct", LinearSolverChoice::Direct),
            ("pcg", LinearSolverChoice::Pcg),
        ] {
            if tag == "w6" && solver == LinearSolverChoice::Direct {
                continue;
            }
            let one = NewtonSettings {
                max_iterations: 1,
                linear_solver: solver,
                ..Default::default()
            };
            let mut be = BackwardEuler::new(&system, one).unwrap();
            g.bench_function(format!("{tag}_one_newton_iteration_{name}"), |b| {
                b.iter_batched_ref(
                    || system.clone(),
                    |s| black_box(be.step(s, 1.0 / 60.0).unwrap()),
                    criterion::BatchSize::LargeInput,
                )
            });
        }
    }
    g.finish();
}

/// Per-step time of the new integrators and `auto` (groups `integrators_*`).
fn integrators(c: &mut Criterion) {
    let newton = NewtonSettings::default();
    let configs = [
        ("auto", Integrator::Auto(AutoSettings::default())),
        (
            "verlet_bound",
            Integrator::VelocityVerlet { substeps: None },
        ),
        ("bdf2", Integrator::Bdf2(newton)),
        ("midpoint", Integrator::ImplicitMidpoint(newton)),
        ("backward_euler", Integrator::BackwardEuler(newton)),
    ];
    for (name, integrator) in configs {
        per_step(
            c,
            "integrators_w4_damping0",
            name,
            &w4(0.0),
            integrator,
            1.0 / 60.0,
            60,
        );
        per_step(
            c,
            "integrators_w5_k1e6_h30",
            name,
            &w5(1e6),
            integrator,
            1.0 / 30.0,
            30,
        );
        if name != "auto" && name != "verlet_bound" {
            per_step(
                c,
                "integrators_w5_k1e6_h10",
                name,
                &w5(1e6),
                integrator,
                0.1,
                10,
            );
        }
    }
}

criterion_group!(benches, kernels, steps, integrators);
criterion_main!(benches);
