//! A fixed number of steps on the lab cloth, for counting instructions with
//! `valgrind --tool=callgrind` (timings on a shared machine are too noisy to compare two
//! builds; instruction counts are not).
//!
//! Usage: `cargo bench -p sinew-spring-sim --bench w4_steps -- <mode> [steps]` (or the
//! executable `cargo bench --no-run` names, under valgrind), where `mode` is one of
//! - `direct0`, `direct02`, `pcg0`, `pcg02`: the 11x11 lab cloth (stiffness 100, h = 1/60)
//!   with damping 0 or 0.2, backward Euler with the default Newton settings but the
//!   linear solver fixed to the direct Cholesky or to PCG;
//! - `verlet0`, `verlet02`: the same cloth by velocity Verlet at its stability bound;
//! - `w6pcg`: the 101x101 lab cloth (spacing 0.02, no damping) by backward Euler with PCG.
//!
//! It prints the final position of the last particle so the work cannot be optimized
//! away and two builds can be checked to agree.

use sinew_spring_sim::{
    ClothGrid, Integrator, LinearSolverChoice, NewtonSettings, Simulation, SpringSystem,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // Cargo passes `--bench` (and libtest-style flags) to a bench target: skip them.
    let args: Vec<String> = std::env::args()
        .take(1)
        .chain(std::env::args().skip(1).filter(|a| !a.starts_with("--")))
        .collect();
    let mode = args.get(1).map_or("direct0", String::as_str);
    let default_steps = if mode == "w6pcg" { 3 } else { 60 };
    let steps: usize = match args.get(2) {
        Some(s) => s.parse()?,
        None => default_steps,
    };
    let newton = |solver| {
        Integrator::BackwardEuler(NewtonSettings {
            linear_solver: solver,
            ..Default::default()
        })
    };
    let (grid, integrator) = match mode {
        "direct0" => (
            ClothGrid::lab().with_damping(0.0),
            newton(LinearSolverChoice::Direct),
        ),
        "direct02" => (ClothGrid::lab(), newton(LinearSolverChoice::Direct)),
        "pcg0" => (
            ClothGrid::lab().with_damping(0.0),
            newton(LinearSolverChoice::Pcg),
        ),
        "pcg02" => (ClothGrid::lab(), newton(LinearSolverChoice::Pcg)),
        "verlet0" => (
            ClothGrid::lab().with_damping(0.0),
            Integrator::VelocityVerlet { substeps: None },
        ),
        "verlet02" => (
            ClothGrid::lab(),
            Integrator::VelocityVerlet { substeps: None },
        ),
        "w6pcg" => (
            ClothGrid::lab_sized(101, 0.02).with_damping(0.0),
            newton(LinearSolverChoice::Pcg),
        ),
        other => return Err(format!("unknown mode {other:?}").into()),
    };
    let mut sim = Simulation::new(SpringSystem::cloth(&grid)?, integrator)?;
    for _ in 0..steps {
        sim.step(1.0 / 60.0)?;
    }
    let last = sim.system().positions().last().copied().unwrap_or_default();
    println!("{mode} {steps} steps: last particle at {last:?}");
    Ok(())
}
