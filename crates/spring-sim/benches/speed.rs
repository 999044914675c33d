//! Measurements behind the speed work, printed as tables (not criterion: each row is a
//! median over whole steps or kernel calls, with the counts it is compared against).
//!
//! `cargo bench -p sinew-spring-sim --bench speed -- <what> [options]`, `what` one of:
//! - `costs`: per cloth size and stiffness, the solver cost model's counts
//!   ([`SolverCosts`]), the measured time of one numeric factorization and of one PCG
//!   iteration, the PCG iterations per Newton iteration seen on a few steps, and the
//!   model's and the measured crossover;
//! - `steps <workload> <integrator> [steps] [repeats]`: the median time per step of a
//!   run (restarted `repeats` times from the same state), with the Newton and PCG
//!   iterations, the last particle and a hash of the final positions' and velocities'
//!   bits (to compare two builds' results). Workloads: `w4`, `w4d` (damping 0.2), `w5k4`, `w5k6`, `w6`, `w6d`,
//!   `g<N>` (an N x N lab-pattern cloth 2 wide, like W6); integrators: `be-auto`,
//!   `be-pcg`, `be-direct`, `verlet`, `se1` (symplectic Euler, 1 substep), `se<N>`,
//!   `auto`, the backward Euler ones with a `-t<N>` suffix for N threads and then a
//!   `-f<eta>` suffix for PCG's largest forcing term (`NewtonSettings::pcg_forcing`);
//! - `pcg <workload> <threads> [iterations] [batches]`: PCG's iterations alone on the
//!   workload's Newton matrix, time per iteration;
//! - `explicit ...`: the explicit steppers with a thread count (`explicit` below).

use sinew_spring_sim::*;
use std::time::Instant;

fn grid(n: usize, stiffness: f64, damping: f64) -> SpringSystem {
    let spacing = 2.0 / (n - 1) as f64;
    let mut g = if n == 11 {
        ClothGrid::lab().with_damping(damping)
    } else {
        ClothGrid::lab_sized(n, spacing).with_damping(damping)
    };
    g.material.stiffness = stiffness;
    SpringSystem::cloth(&g).unwrap()
}

fn workload(name: &str) -> (SpringSystem, f64) {
    match name {
        "w4" => (grid(11, 100.0, 0.0), 1.0 / 60.0),
        "w4d" => (grid(11, 100.0, 0.2), 1.0 / 60.0),
        "w5k4" => (grid(11, 1e4, 0.0), 1.0 / 30.0),
        "w5k6" => (grid(11, 1e6, 0.0), 1.0 / 30.0),
        "w6" => (grid(101, 100.0, 0.0), 1.0 / 60.0),
        "w6d" => (grid(101, 100.0, 0.2), 1.0 / 60.0),
        g if g.starts_with('g') => (grid(g[1..].parse().unwrap(), 100.0, 0.0), 1.0 / 60.0),
        other => panic!("unknown workload {other}"),
    }
}

fn integrator(name: &str) -> Integrator {
    // A `-f<eta>` suffix: PCG's largest forcing term (default 1e-2).
    let (name, forcing) = match name.split_once("-f") {
        Some((n, f)) => (n, f.parse().unwrap()),
        None => (name, NewtonSettings::default().pcg_forcing),
    };
    // A `-t<N>` suffix: N threads (default: one per core).
    let (name, threads) = match name.split_once("-t") {
        Some((n, t)) => (n, t.parse().unwrap()),
        None => (name, 0),
    };
    let be = |solver| {
        Integrator::BackwardEuler(NewtonSettings {
            linear_solver: solver,
            threads,
            pcg_forcing: forcing,
            ..Default::default()
        })
    };
    match name {
        "be-auto" => be(LinearSolverChoice::Auto),
        "be-pcg" => be(LinearSolverChoice::Pcg),
        "be-direct" => be(LinearSolverChoice::Direct),
        "verlet" => Integrator::VelocityVerlet { substeps: None },
        "auto" => Integrator::Auto(AutoSettings::default()),
        s if s.starts_with("se") => Integrator::SymplecticEuler {
            substeps: s[2..].parse().unwrap(),
        },
        other => panic!("unknown integrator {other}"),
    }
}

/// CPU time of this thread in seconds (Linux `schedstat`), so a kernel's cost is not
/// inflated by the time other jobs on this shared machine hold the core; falls back to
/// zero where the file does not exist.
fn thread_cpu() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .map_or(0.0, |ns| ns * 1e-9)
}

/// CPU seconds per call of `f`, over batches of at least 0.2 s of CPU time (at least 3
/// calls), the median of 5 batches.
fn cpu_per_call(mut f: impl FnMut()) -> f64 {
    let mut batches = Vec::new();
    for _ in 0..5 {
        let start = thread_cpu();
        let mut calls = 0;
        while calls < 3 || thread_cpu() - start < 0.2 {
            f();
            calls += 1;
        }
        batches.push((thread_cpu() - start) / calls as f64);
    }
    median(batches)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn costs() {
    println!(
        "| case | unknowns | matrix nnz | factor nnz | factor madds | analysis ms | factor ms | cg iter us | measured ratio | model ratio | PCG its / Newton it |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for (n, k, h) in [
        (11, 100.0, 1.0 / 60.0),
        (11, 1e4, 1.0 / 30.0),
        (11, 1e6, 1.0 / 30.0),
        (31, 100.0, 1.0 / 60.0),
        (51, 100.0, 1.0 / 60.0),
        (101, 100.0, 1.0 / 60.0),
    ] {
        let system = grid(n, k, 0.0);
        let mut be = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
        let t = Instant::now();
        let c: SolverCosts = be.solver_costs().unwrap();
        let analysis = t.elapsed().as_secs_f64();
        be.assemble_newton_matrix(&system, h);
        assert!(be.factor_newton_matrix().unwrap());
        let factor = cpu_per_call(|| assert!(be.factor_newton_matrix().unwrap()));
        let its = 50;
        let cg = cpu_per_call(|| {
            assert_eq!(be.pcg_iterations_on_newton_matrix(its).iterations, its);
        }) / its as f64;
        // PCG iterations per Newton iteration over a few steps of the workload.
        let pcg = NewtonSettings {
            linear_solver: LinearSolverChoice::Pcg,
            ..Default::default()
        };
        let mut sim = Simulation::new(system.clone(), Integrator::BackwardEuler(pcg)).unwrap();
        let (mut newton, mut linear) = (0, 0);
        for _ in 0..if n >= 101 { 5 } else { 30 } {
            let r = sim.step(h).unwrap();
            newton += r.iterations;
            linear += r.linear_iterations;
        }
        println!(
            "| {n}x{n} k={k:e} | {} | {} | {:.3e} | {:.3e} | {:.2} | {:.3} | {:.2} | {:.1} | {:.1} | {:.1} |",
            c.dim,
            c.matrix_nonzeros,
            c.factor_nonzeros,
            c.factor_multiply_adds,
            analysis * 1e3,
            factor * 1e3,
            cg * 1e6,
            factor / cg,
            c.crossover_iterations(),
            linear as f64 / newton.max(1) as f64,
        );
    }
}

fn steps(args: &[String]) {
    let (system, h) = workload(&args[0]);
    let integ = integrator(&args[1]);
    let steps: usize = args.get(2).map_or(30, |s| s.parse().unwrap());
    let repeats: usize = args.get(3).map_or(3, |s| s.parse().unwrap());
    let mut times = Vec::new();
    let mut cpu = Vec::new();
    let (mut newton, mut linear, mut direct_steps) = (0, 0, 0);
    let mut last = DVec3Like::default();
    let mut hash = 0;
    for _ in 0..repeats {
        let mut sim = Simulation::new(system.clone(), integ).unwrap();
        for _ in 0..steps {
            let (t, c) = (Instant::now(), thread_cpu());
            let r = sim.step(h).unwrap();
            times.push(t.elapsed().as_secs_f64());
            cpu.push(thread_cpu() - c);
            newton += r.iterations;
            linear += r.linear_iterations;
            if r.linear_solver == Some(LinearSolverKind::Direct) {
                direct_steps += 1;
            }
        }
        let p = sim.system().positions().last().copied().unwrap();
        last = DVec3Like([p.x, p.y, p.z]);
        hash = sim.system().state_fingerprint();
    }
    let mean = cpu.iter().sum::<f64>() / cpu.len() as f64;
    println!(
        "{} {}: wall median {:.1} us/step; CPU (this thread) median {:.1}, mean {:.1} us/step over {} steps; iterations/step {:.2}, linear/step {:.1}, direct steps {}; last particle {:?}; state hash {:016x}",
        args[0],
        args[1],
        median(times.clone()) * 1e6,
        median(cpu.clone()) * 1e6,
        mean * 1e6,
        times.len(),
        newton as f64 / times.len() as f64,
        linear as f64 / times.len() as f64,
        direct_steps,
        last.0,
        hash
    );
}

/// `pcg <workload> <threads> [iterations] [batches]`: PCG alone on the workload's Newton
/// matrix at its starting state (right-hand side all ones), `iterations` iterations per
/// call; prints the medians over `batches` calls of the wall time and of this thread's
/// CPU time per iteration (with one thread the two agree but for waiting; with two
/// the CPU time is the calling thread's share only). Two builds are compared by
/// alternating their runs.
fn pcg(args: &[String]) {
    let (system, h) = workload(&args[0]);
    let threads: usize = args[1].parse().unwrap();
    let iterations: usize = args.get(2).map_or(20, |s| s.parse().unwrap());
    let batches: usize = args.get(3).map_or(15, |s| s.parse().unwrap());
    let settings = NewtonSettings {
        linear_solver: LinearSolverChoice::Pcg,
        threads,
        ..Default::default()
    };
    let mut be = BackwardEuler::new(&system, settings).unwrap();
    be.assemble_newton_matrix(&system, h);
    let (mut wall, mut cpu) = (Vec::new(), Vec::new());
    for _ in 0..batches {
        let (t, c) = (Instant::now(), thread_cpu());
        let outcome = be.pcg_iterations_on_newton_matrix(iterations);
        assert_eq!(outcome.iterations, iterations);
        wall.push(t.elapsed().as_secs_f64() / iterations as f64);
        cpu.push((thread_cpu() - c) / iterations as f64);
    }
    println!(
        "{} pcg threads {}: wall median {:.1} us/iteration, CPU (this thread) median {:.1} us/iteration ({} batches of {} iterations)",
        args[0],
        be.threads(),
        median(wall) * 1e6,
        median(cpu) * 1e6,
        batches,
        iterations
    );
}

/// FNV-1a over the bits of every position and velocity: two runs ended in the same
/// state exactly when their hashes agree (up to a collision).

#[derive(Default, Debug, Clone, Copy)]
struct DVec3Like([f64; 3]);

/// `explicit <workload> <verlet|se> <substeps> <threads> [steps] [repeats]`: the stepper
/// types directly, with a thread count.
fn explicit(args: &[String]) {
    let (system, h) = workload(&args[0]);
    let verlet = args[1] == "verlet";
    let substeps: usize = args[2].parse().unwrap();
    let threads: usize = args[3].parse().unwrap();
    let steps: usize = args.get(4).map_or(30, |s| s.parse().unwrap());
    let repeats: usize = args.get(5).map_or(5, |s| s.parse().unwrap());
    let mut wall = Vec::new();
    let mut cpu = 0.0;
    for _ in 0..repeats {
        let mut s = system.clone();
        let mut vv = VelocityVerlet::new(&s, substeps).unwrap();
        let mut se = SymplecticEuler::new(&s, substeps).unwrap();
        vv.set_threads(&s, threads).unwrap();
        se.set_threads(&s, threads).unwrap();
        for _ in 0..steps {
            let (t, c) = (Instant::now(), thread_cpu());
            if verlet {
                vv.step(&mut s, h).unwrap();
            } else {
                se.step(&mut s, h).unwrap();
            }
            wall.push(t.elapsed().as_secs_f64());
            cpu += thread_cpu() - c;
        }
    }
    let n = wall.len() as f64;
    println!(
        "{} {} x{substeps} threads {threads}: wall median {:.1} us/step, mean {:.1}; CPU of this thread mean {:.1} us/step",
        args[0],
        args[1],
        median(wall.clone()) * 1e6,
        wall.iter().sum::<f64>() / n * 1e6,
        cpu / n * 1e6
    );
}

fn main() {
    // `cargo bench` passes `--bench`; drop flags.
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    match args.first().map(String::as_str) {
        Some("costs") => costs(),
        Some("steps") => steps(&args[1..]),
        Some("explicit") => explicit(&args[1..]),
        Some("pcg") => pcg(&args[1..]),
        _ => {
            eprintln!("usage: speed costs | speed steps <workload> <integrator> [steps] [repeats]")
        }
    }
}
