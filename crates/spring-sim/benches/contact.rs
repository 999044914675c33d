//! Collider contact cost on the three contact workloads, stepped with backward Euler (the
//! default Newton settings with an iteration cap of 100), contact distance `dhat` 1e-3 m,
//! h = 1/60 s, springs of 1000 N/m, damping 0.1, gravity 9.81:
//!
//! - `ground`: a 32 x 32 sheet (spacing 0.05 m, 5e-4 kg per particle) falling from
//!   0.5 m onto the ground, friction 0.3;
//! - `drape`: a 41 x 41 sheet (spacing 0.025 m, 1.25e-4 kg) released 0.5 m up, centred
//!   over a static sphere of radius 0.3 at the origin, friction 0.3;
//! - `rotating`: a 61 x 61 sheet (spacing 1/30 m, 2/9000 kg) released 0.6 m up over a
//!   sphere of radius 0.5 at the origin turning at 180 degrees per second about +y,
//!   with the ground at y = -0.55, friction 0.4.
//!
//! Prints one row per workload: steps, wall time per step (median and mean), Newton
//! iterations (total and the largest in a step), linear (PCG) iterations, line-search
//! backtracks, the final `kappa`, the smallest particle-collider distance over the run
//! and the number of steps that ended with a particle inside a collider (recomputed
//! from the colliders' fields after every step). Not a criterion benchmark: a table for
//! docs/contact.md, run with
//! `cargo bench -p sinew-spring-sim --bench contact [-- ground|drape|rotating [steps]
//! [--trace] [mu=..] [eps_v=..] [solver=direct|pcg|auto] [reuse=..]]` (`--trace`: a line
//! per step on stderr; `mu`, `eps_v`: the friction settings instead of the workload's;
//! `solver`: the linear solver, `auto` by default; `reuse`: the direct solver's
//! `factor_reuse_iterations`, 0 for a factorization every Newton iteration). The last
//! line gives the direct solver's numeric factorizations and its solves and iterations
//! preconditioned by a kept factor over the run.

use sinew_math::DVec3;
use sinew_spring_sim::contact::{Collider, ContactSettings};
use sinew_spring_sim::{
    ClothGrid, Integrator, LinearSolverChoice, Material, NewtonSettings, Simulation,
};
use std::time::Instant;

struct Workload {
    name: &'static str,
    size: usize,
    spacing: f64,
    origin: DVec3,
    mass: f64,
    colliders: Vec<Collider>,
    mu: f64,
    steps: usize,
}

fn workloads() -> Vec<Workload> {
    vec![
        Workload {
            name: "ground",
            size: 32,
            spacing: 0.05,
            origin: DVec3::new(0.0, 0.5, 0.0),
            mass: 5e-4,
            colliders: vec![Collider::ground(0.0)],
            mu: 0.3,
            steps: 120,
        },
        Workload {
            name: "drape",
            size: 41,
            spacing: 0.025,
            origin: DVec3::new(-0.5, 0.5, -0.5),
            mass: 1.25e-4,
            colliders: vec![Collider::sphere(DVec3::ZERO, 0.3)],
            mu: 0.3,
            steps: 180,
        },
        Workload {
            name: "rotating",
            size: 61,
            spacing: 2.0 / 60.0,
            origin: DVec3::new(-1.0, 0.6, -1.0),
            mass: 2.0 / 9000.0,
            colliders: vec![
                Collider::sphere(DVec3::ZERO, 0.5)
                    .moving(DVec3::ZERO, DVec3::new(0.0, std::f64::consts::PI, 0.0)),
                Collider::ground(-0.55),
            ],
            mu: 0.4,
            steps: 240,
        },
    ]
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let chosen: Vec<&str> = args
        .iter()
        .filter(|a| a.parse::<usize>().is_err() && !a.starts_with('-') && !a.contains('='))
        .map(String::as_str)
        .collect();
    let steps_override = args.iter().find_map(|a| a.parse::<usize>().ok());
    // `--trace`: one line per step on stderr (iterations, stop reason, kappa, distance).
    let trace = args.iter().any(|a| a == "--trace");
    // `key=value` overrides of the workloads' settings, for experiments: `mu=`, `eps_v=`
    // (friction), `solver=direct|pcg|auto` (the linear solver), `reuse=` (the iterations
    // preconditioned by a kept factor before a factorization).
    let value = |key: &str| {
        args.iter()
            .find_map(|a| a.strip_prefix(key).and_then(|v| v.strip_prefix('=')))
    };
    let number = |key: &str| {
        value(key).map(|v| {
            v.parse::<f64>()
                .unwrap_or_else(|_| panic!("{key}={v}: not a number"))
        })
    };
    let solver = match value("solver") {
        None | Some("auto") => LinearSolverChoice::Auto,
        Some("direct") => LinearSolverChoice::Direct,
        Some("pcg") => LinearSolverChoice::Pcg,
        Some(other) => panic!("solver={other}: expected direct, pcg or auto"),
    };
    println!(
        "| workload | particles | steps | ms per step (median) | ms per step (mean) | Newton iterations | most in a step | PCG iterations | backtracks | kappa (end) | smallest distance (m) | steps with a penetration |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for w in workloads() {
        if !chosen.is_empty() && !chosen.contains(&w.name) {
            continue;
        }
        let steps = steps_override.unwrap_or(w.steps);
        let grid = ClothGrid {
            size: w.size,
            spacing: w.spacing,
            origin: w.origin,
            mass: w.mass,
            material: Material::earth().with_stiffness(1000.0).with_damping(0.1),
            fixed: Vec::new(),
        };
        let system = grid.build().expect("the grid is valid");
        let defaults = NewtonSettings::default();
        let settings = NewtonSettings {
            max_iterations: 100,
            linear_solver: solver,
            factor_reuse_iterations: number("reuse")
                .map_or(defaults.factor_reuse_iterations, |r| r as usize),
            ..defaults
        };
        let mut sim = Simulation::new(system, Integrator::BackwardEuler(settings))
            .expect("the integrator is valid");
        sim.set_contact(
            w.colliders.clone(),
            ContactSettings {
                dhat: 1e-3,
                mu: number("mu").unwrap_or(w.mu),
                eps_v: number("eps_v").unwrap_or(ContactSettings::default().eps_v),
                ..ContactSettings::default()
            },
        )
        .expect("the contact settings are valid");
        let h = 1.0 / 60.0;
        let mut times = Vec::with_capacity(steps);
        let (mut newton, mut most, mut linear, mut backtracks) = (0, 0, 0, 0);
        let (mut smallest, mut penetrating) = (f64::INFINITY, 0);
        let (mut factorizations, mut kept_solves, mut kept_iterations) = (0, 0, 0);
        for _ in 0..steps {
            let start = Instant::now();
            let report = sim.step(h).expect("the step succeeds");
            times.push(start.elapsed().as_secs_f64() * 1e3);
            newton += report.iterations;
            most = most.max(report.iterations);
            linear += report.linear_iterations;
            backtracks += report.backtracks;
            factorizations += report.factorizations;
            kept_solves += report.kept_factor_solves;
            kept_iterations += report.kept_factor_iterations;
            let (d, _) = sim.contact_distances().expect("contact is set");
            if trace {
                eprintln!(
                    "{} step {}: {} Newton, {} PCG, {} factorizations, {} kept-factor solves ({} iterations), {} backtracks, {:?}, {} pieces, kappa {:.4}, d {d:.3e}, {:.2} ms",
                    w.name,
                    times.len(),
                    report.iterations,
                    report.linear_iterations,
                    report.factorizations,
                    report.kept_factor_solves,
                    report.kept_factor_iterations,
                    report.backtracks,
                    report.stop,
                    report.pieces,
                    sim.contact_kappa().unwrap_or(0.0),
                    times.last().copied().unwrap_or(0.0),
                );
            }
            smallest = smallest.min(d);
            if d <= 0.0 {
                penetrating += 1;
            }
        }
        let mean = times.iter().sum::<f64>() / steps as f64;
        times.sort_by(f64::total_cmp);
        let median = times[steps / 2];
        println!(
            "| {} | {} | {steps} | {median:.2} | {mean:.2} | {newton} | {most} | {linear} | {backtracks} | {:.4} | {smallest:.2e} | {penetrating} |",
            w.name,
            w.size * w.size,
            sim.contact_kappa().unwrap_or(0.0),
        );
        println!(
            "{}: {factorizations} factorizations, {kept_solves} kept-factor solves, {kept_iterations} kept-factor iterations",
            w.name
        );
    }
}
