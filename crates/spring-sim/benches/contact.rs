//! Contact cost on the contact workloads, stepped with backward Euler (the default Newton
//! settings with an iteration cap of 100), h = 1/60 s. Collider contact, `dhat` 1e-3 m,
//! springs of 1000 N/m, damping 0.1, gravity 9.81:
//!
//! - `ground`: a 32 x 32 sheet (spacing 0.05 m, 5e-4 kg per particle) falling from
//!   0.5 m onto the ground, friction 0.3;
//! - `drape`: a 41 x 41 sheet (spacing 0.025 m, 1.25e-4 kg) released 0.5 m up, centred
//!   over a static sphere of radius 0.3 at the origin, friction 0.3;
//! - `rotating` (C3): a 61 x 61 sheet (spacing 1/30 m, 2/9000 kg) released 0.6 m up over
//!   a sphere of radius 0.5 at the origin turning at 180 degrees per second about +y,
//!   with the ground at y = -0.55, friction 0.4.
//!
//! Self-contact (`dhat` 2e-3 m, thickness 1e-3 m), triangle-mesh sheets of areal density
//! 0.2 kg/m^2 with edge springs of 500 N/m, damping 0.1, the same as
//! `scenes/long/cloth-twist.ron` and `scenes/long/cloth-stack.ron`:
//!
//! - `twist` (C4): a 50 x 50 sheet (spacing 1/49 m) in the x-z plane, no gravity, its
//!   edges i = 0 and i = 49 held and turned about the x axis through (0, 0, 0.5) in
//!   opposite directions at pi/3 rad/s, 360 steps;
//! - `stack` (C5): three 32 x 32 sheets (spacing 1 cm) 2 cm apart, the lowest 1 cm above
//!   the ground (a collider, `dhat` 1e-3, friction 0.3), each turned 0.1 rad more than
//!   the one below about y, gravity 9.81, 90 steps;
//! - `stack-workload` (C5 as the shared workload list writes it,
//!   `scenes/long/cloth-stack-workload.ron`): three 32 x 32 sheets (spacing 5 cm) at
//!   y = 0.3, 0.35 and 0.4, turned 0, 30 and 60 degrees about the vertical through their
//!   common centre, falling onto the ground (the same collider), 120 steps.
//!
//! Prints one row per workload: steps, wall time per step (median and mean), Newton
//! iterations (total and the largest in a step), linear (PCG) iterations, line-search
//! backtracks, the final collider `kappa`, the smallest particle-collider distance over
//! the run and the number of steps that ended with a particle inside a collider
//! (recomputed from the colliders' fields after every step), and for the self-contact
//! workloads the triangle pairs passing through each other over the run (the exact check
//! of `sinew-exact`, after every step, outside the timed step). Not a criterion
//! benchmark: a table for docs/bench/contact.md, run with
//! `cargo bench -p sinew-spring-sim --bench contact [-- ground|drape|rotating|twist|stack|
//! stack-workload [steps] [--trace] [mu=..] [eps_v=..] [solver=direct|pcg|auto] [reuse=..] [tol=..]
//! [exact=0|1] [threads=N] [cap=N] [split=N] [save=FILE] [against=FILE]]` (`--trace`: a line per step on stderr, with the step's intersecting triangle pairs for the self-contact workloads; `mu`, `eps_v`: the
//! collider friction settings instead of the workload's; `solver`: the linear solver,
//! `auto` by default; `reuse`: the direct solver's `factor_reuse_iterations`, 0 for a
//! factorization every Newton iteration; `tol`: `NewtonSettings::tolerance`; `cap`:
//! `NewtonSettings::max_iterations` (100 by default); `split`:
//! `NewtonSettings::max_split_depth` (the library's default; `cap=2 split=0` is a fixed
//! budget of two Newton iterations a step, docs/contact.md); `exact`:
//! `SelfContactSettings::exact_hessian` (the self-contact pairs' exact Hessians tried
//! first once Newton is slow, default 1 as the setting's default; the self-contact
//! workloads print the times the term wrote them and fell back to their projections);
//! `threads`: `NewtonSettings::threads` (0, one per core, by default; 1 gives the
//! single-thread time beside which the default's shows what the second core buys);
//! `save`:
//! write the final positions and velocities to FILE; `against`: read such a file and
//! print the largest distance of a particle's final position and velocity from it, the
//! deviation from a reference run). The last line gives the direct solver's numeric
//! factorizations and its solves and iterations preconditioned by a kept factor over the
//! run.

use sinew_exact::intersecting_pairs;
use sinew_math::DVec3;
use sinew_spring_sim::contact::self_contact::{SelfContactSettings, SelfContactStats};
use sinew_spring_sim::contact::{Collider, ContactSettings, signed_distance};
use sinew_spring_sim::{
    BackwardEuler, Bending, ClothGrid, Integrator, LinearSolverChoice, Material, MeshCloth,
    NewtonSettings, PinDriver, PinnedMotion, Simulation, SpringSystem, StepReport, TriangleMesh,
};
use std::sync::Arc;
use std::time::Instant;

/// A sheet of a self-contact workload: `size x size` vertices at `origin + spacing (i u +
/// j w)`.
struct Sheet {
    size: usize,
    spacing: f64,
    origin: DVec3,
    u: DVec3,
    w: DVec3,
}

/// What a workload is made of.
enum Cloth {
    /// A lab-pattern grid (`ClothGrid`) of springs of 1000 N/m against colliders.
    Grid {
        size: usize,
        spacing: f64,
        origin: DVec3,
        mass: f64,
    },
    /// Triangle-mesh sheets with self-contact, springs of 500 N/m on the edges; the rows
    /// of sheet 0 in `turning` are held and turned about the x axis through
    /// (0, 0, 0.5) at the given rate.
    Mesh {
        sheets: Vec<Sheet>,
        gravity: DVec3,
        turning: Vec<(usize, f64)>,
    },
}

struct Workload {
    name: &'static str,
    cloth: Cloth,
    colliders: Vec<Collider>,
    mu: f64,
    steps: usize,
}

fn workloads() -> Vec<Workload> {
    let third = std::f64::consts::PI / 3.0;
    // The scene file's directions, to the digits it gives (0.1 and 0.2 rad about y), so
    // the runs are those of `scenes/long/cloth-stack.ron`.
    let directions = [
        (DVec3::X, DVec3::Z),
        (
            DVec3::new(0.995004, 0.0, 0.0998334),
            DVec3::new(-0.0998334, 0.0, 0.995004),
        ),
        (
            DVec3::new(0.980067, 0.0, 0.198669),
            DVec3::new(-0.198669, 0.0, 0.980067),
        ),
    ];
    let origins = [
        DVec3::new(0.0, 0.01, 0.0),
        DVec3::new(0.01, 0.03, -0.01),
        DVec3::new(0.02, 0.05, -0.02),
    ];
    let stack_sheet = |k: usize| Sheet {
        size: 32,
        spacing: 0.01,
        origin: origins[k],
        u: directions[k].0,
        w: directions[k].1,
    };
    vec![
        Workload {
            name: "ground",
            cloth: Cloth::Grid {
                size: 32,
                spacing: 0.05,
                origin: DVec3::new(0.0, 0.5, 0.0),
                mass: 5e-4,
            },
            colliders: vec![Collider::ground(0.0)],
            mu: 0.3,
            steps: 120,
        },
        Workload {
            name: "drape",
            cloth: Cloth::Grid {
                size: 41,
                spacing: 0.025,
                origin: DVec3::new(-0.5, 0.5, -0.5),
                mass: 1.25e-4,
            },
            colliders: vec![Collider::sphere(DVec3::ZERO, 0.3)],
            mu: 0.3,
            steps: 180,
        },
        Workload {
            name: "rotating",
            cloth: Cloth::Grid {
                size: 61,
                spacing: 2.0 / 60.0,
                origin: DVec3::new(-1.0, 0.6, -1.0),
                mass: 2.0 / 9000.0,
            },
            colliders: vec![
                Collider::sphere(DVec3::ZERO, 0.5)
                    .moving(DVec3::ZERO, DVec3::new(0.0, std::f64::consts::PI, 0.0)),
                Collider::ground(-0.55),
            ],
            mu: 0.4,
            steps: 240,
        },
        Workload {
            name: "twist",
            cloth: Cloth::Mesh {
                sheets: vec![Sheet {
                    size: 50,
                    spacing: 1.0 / 49.0,
                    origin: DVec3::ZERO,
                    u: DVec3::X,
                    w: DVec3::Z,
                }],
                gravity: DVec3::ZERO,
                turning: vec![(0, third), (49, -third)],
            },
            colliders: Vec::new(),
            mu: 0.0,
            steps: 360,
        },
        Workload {
            name: "stack",
            cloth: Cloth::Mesh {
                sheets: (0..3).map(stack_sheet).collect(),
                gravity: Material::EARTH_GRAVITY,
                turning: Vec::new(),
            },
            colliders: vec![Collider::ground(0.0)],
            mu: 0.3,
            steps: 90,
        },
        Workload {
            name: "stack-workload",
            cloth: Cloth::Mesh {
                sheets: (0..3).map(workload_sheet).collect(),
                gravity: Material::EARTH_GRAVITY,
                turning: Vec::new(),
            },
            colliders: vec![Collider::ground(0.0)],
            mu: 0.3,
            steps: 120,
        },
    ]
}

/// Sheet `k` of C5 as the workload list writes it (`scenes/long/cloth-stack-workload.ron`):
/// 32 x 32, spacing 5 cm, at y = 0.3 + 0.05 k, turned 30 k degrees about the vertical
/// through the sheets' common centre (0.775, y, 0.775). The origins are the scene file's,
/// to the digits it gives.
fn workload_sheet(k: usize) -> Sheet {
    let (sin, cos) = (k as f64 * std::f64::consts::FRAC_PI_6).sin_cos();
    let origins = [
        DVec3::new(0.0, 0.3, 0.0),
        DVec3::new(0.4913303, 0.35, -0.2836697),
        DVec3::new(1.0586697, 0.4, -0.2836697),
    ];
    Sheet {
        size: 32,
        spacing: 0.05,
        origin: origins[k],
        u: DVec3::new(cos, 0.0, sin),
        w: DVec3::new(-sin, 0.0, cos),
    }
}

/// A workload ready to step: either the `Simulation` of a grid, or a mesh cloth's
/// integrator, system and pin driver with its triangles for the intersection check.
enum Running {
    Grid(Box<Simulation>),
    Mesh(Box<MeshRun>),
}

/// A mesh cloth being stepped (see [`Running`]).
struct MeshRun {
    integrator: BackwardEuler,
    system: SpringSystem,
    pins: Option<PinDriver>,
    self_contact: Arc<SelfContactStats>,
    triangles: Vec<[usize; 3]>,
    colliders: Vec<Collider>,
    time: f64,
}

impl Running {
    fn new(
        w: &Workload,
        settings: NewtonSettings,
        contact: ContactSettings,
        exact_hessian: bool,
    ) -> Self {
        match &w.cloth {
            Cloth::Grid {
                size,
                spacing,
                origin,
                mass,
            } => {
                let grid = ClothGrid {
                    size: *size,
                    spacing: *spacing,
                    origin: *origin,
                    mass: *mass,
                    material: Material::earth().with_stiffness(1000.0).with_damping(0.1),
                    fixed: Vec::new(),
                };
                let system = grid.build().expect("the grid is valid");
                let mut sim = Simulation::new(system, Integrator::BackwardEuler(settings))
                    .expect("the integrator is valid");
                sim.set_contact(w.colliders.clone(), contact)
                    .expect("the contact settings are valid");
                Self::Grid(Box::new(sim))
            }
            Cloth::Mesh {
                sheets,
                gravity,
                turning,
            } => {
                let (mut positions, mut triangles) = (Vec::new(), Vec::new());
                for s in sheets {
                    let offset = positions.len();
                    for i in 0..s.size {
                        for j in 0..s.size {
                            positions
                                .push(s.origin + s.spacing * (i as f64 * s.u + j as f64 * s.w));
                        }
                    }
                    let grid = ClothGrid {
                        size: s.size,
                        ..ClothGrid::lab()
                    };
                    triangles.extend(grid.triangles().into_iter().map(|t| t.map(|v| v + offset)));
                }
                let n = sheets[0].size;
                let motions: Vec<PinnedMotion> = turning
                    .iter()
                    .map(|&(row, rate)| {
                        PinnedMotion::rotation(
                            (0..n).map(|j| row * n + j).collect(),
                            DVec3::new(0.0, 0.0, 0.5),
                            DVec3::X,
                            rate,
                        )
                    })
                    .collect();
                let fixed: Vec<usize> = motions.iter().flat_map(|m| m.particles.clone()).collect();
                let mesh =
                    TriangleMesh::new(positions, triangles.clone()).expect("the mesh is valid");
                let model = MeshCloth {
                    areal_density: 0.2,
                    material: Material::earth()
                        .with_stiffness(500.0)
                        .with_damping(0.1)
                        .with_gravity(*gravity),
                    bending: Bending::None,
                    fixed,
                }
                .build(&mesh)
                .expect("the cloth is valid");
                let mut integrator = model
                    .backward_euler(settings)
                    .expect("the integrator is valid");
                if !w.colliders.is_empty() {
                    model
                        .enable_contact(&mut integrator, w.colliders.clone(), contact)
                        .expect("the contact settings are valid");
                }
                let self_contact = model
                    .enable_self_contact(
                        &mut integrator,
                        SelfContactSettings {
                            dhat: 2e-3,
                            thickness: 1e-3,
                            exact_hessian,
                            ..SelfContactSettings::default()
                        },
                    )
                    .expect("the self-contact settings are valid");
                let system = model.system.clone();
                let pins = (!motions.is_empty())
                    .then(|| PinDriver::new(&system, motions).expect("the pins are valid"));
                Self::Mesh(Box::new(MeshRun {
                    integrator,
                    system,
                    pins,
                    self_contact,
                    triangles,
                    colliders: w.colliders.clone(),
                    time: 0.0,
                }))
            }
        }
    }

    fn step(&mut self, h: f64) -> StepReport {
        match self {
            Self::Grid(sim) => sim.step(h).expect("the step succeeds"),
            Self::Mesh(run) => {
                let MeshRun {
                    integrator,
                    system,
                    pins,
                    time,
                    ..
                } = run.as_mut();
                *time += h;
                match pins {
                    Some(driver) => driver.step(integrator, system, h),
                    None => integrator.step(system, h),
                }
                .expect("the step succeeds")
            }
        }
    }

    fn system(&self) -> &SpringSystem {
        match self {
            Self::Grid(sim) => sim.system(),
            Self::Mesh(run) => &run.system,
        }
    }

    /// The smallest particle-collider distance now (infinite without colliders) and the
    /// triangle pairs passing through each other (0 for a grid, which has no triangles).
    fn check(&self) -> (f64, usize) {
        match self {
            Self::Grid(sim) => (sim.contact_distances().map_or(f64::INFINITY, |d| d.0), 0),
            Self::Mesh(run) => {
                let MeshRun {
                    system,
                    triangles,
                    colliders,
                    time,
                    ..
                } = run.as_ref();
                let x = system.positions();
                let mut smallest = f64::INFINITY;
                for c in colliders {
                    let shape = c.at(*time);
                    for (p, pinned) in x.iter().zip(system.fixed()) {
                        if !pinned {
                            smallest = smallest.min(signed_distance(&shape, *p, 0.0).distance);
                        }
                    }
                }
                (smallest, intersecting_pairs(x, triangles).len())
            }
        }
    }

    fn kappa(&self) -> f64 {
        match self {
            Self::Grid(sim) => sim.contact_kappa().unwrap_or(0.0),
            Self::Mesh(_) => 0.0,
        }
    }
}

/// The final state as little-endian f64s: the positions, then the velocities.
fn state_bytes(system: &SpringSystem) -> Vec<u8> {
    system
        .positions()
        .iter()
        .chain(system.velocities())
        .flat_map(|p| [p.x, p.y, p.z])
        .flat_map(f64::to_le_bytes)
        .collect()
}

/// The largest distance of a particle's position and of its velocity from the state in
/// `bytes` (written by [`state_bytes`] for the same workload).
fn deviation(system: &SpringSystem, bytes: &[u8]) -> (f64, f64) {
    let values: Vec<f64> = bytes
        .chunks_exact(8)
        .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
        .collect();
    let n = system.len();
    assert_eq!(
        values.len(),
        6 * n,
        "the saved state is of another workload"
    );
    let at = |k: usize| DVec3::new(values[3 * k], values[3 * k + 1], values[3 * k + 2]);
    let largest = |now: &[DVec3], first: usize| {
        now.iter()
            .enumerate()
            .map(|(p, v)| (*v - at(first + p)).length())
            .fold(0.0f64, f64::max)
    };
    (
        largest(system.positions(), 0),
        largest(system.velocities(), n),
    )
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
    // preconditioned by a kept factor before a factorization), `tol=` (the Newton
    // tolerance), `cap=` (the Newton iteration cap, default 100) and `split=` (how many
    // times a step may be halved, default the library's; 0 with a small cap is a fixed
    // budget of Newton iterations a step); `save=` and `against=` write and compare
    // final states.
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
        "| workload | particles | steps | ms per step (median) | ms per step (mean) | Newton iterations | most in a step | PCG iterations | backtracks | kappa (end) | smallest distance (m) | steps with a penetration | intersections |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for w in workloads() {
        if !chosen.is_empty() && !chosen.contains(&w.name) {
            continue;
        }
        let steps = steps_override.unwrap_or(w.steps);
        let defaults = NewtonSettings::default();
        let settings = NewtonSettings {
            max_iterations: number("cap").map_or(100, |c| c as usize),
            max_split_depth: number("split").map_or(defaults.max_split_depth, |d| d as usize),
            linear_solver: solver,
            factor_reuse_iterations: number("reuse")
                .map_or(defaults.factor_reuse_iterations, |r| r as usize),
            tolerance: number("tol").unwrap_or(defaults.tolerance),
            threads: number("threads").map_or(defaults.threads, |t| t as usize),
            ..defaults
        };
        let contact = ContactSettings {
            dhat: 1e-3,
            mu: number("mu").unwrap_or(w.mu),
            eps_v: number("eps_v").unwrap_or(ContactSettings::default().eps_v),
            ..ContactSettings::default()
        };
        let exact =
            number("exact").map_or(SelfContactSettings::default().exact_hessian, |e| e != 0.0);
        let mut run = Running::new(&w, settings, contact, exact);
        let h = 1.0 / 60.0;
        let mut times = Vec::with_capacity(steps);
        let (mut newton, mut most, mut linear, mut backtracks) = (0, 0, 0, 0);
        let (mut smallest, mut penetrating, mut intersections) = (f64::INFINITY, 0, 0);
        let (mut factorizations, mut kept_solves, mut kept_iterations) = (0, 0, 0);
        for _ in 0..steps {
            let start = Instant::now();
            let report = run.step(h);
            times.push(start.elapsed().as_secs_f64() * 1e3);
            newton += report.iterations;
            most = most.max(report.iterations);
            linear += report.linear_iterations;
            backtracks += report.backtracks;
            factorizations += report.factorizations;
            kept_solves += report.kept_factor_solves;
            kept_iterations += report.kept_factor_iterations;
            let (d, meeting) = run.check();
            if trace {
                eprintln!(
                    "{} step {}: {} Newton, {} PCG, {} factorizations, {} kept-factor solves ({} iterations), {} backtracks, {:?}, {} pieces, kappa {:.4}, d {d:.3e}, residual {:.3e}, {:.2} ms, {meeting} intersecting triangle pairs",
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
                    run.kappa(),
                    report.residual,
                    times.last().copied().unwrap_or(0.0),
                );
            }
            smallest = smallest.min(d);
            if d <= 0.0 {
                penetrating += 1;
            }
            intersections += meeting;
        }
        let mean = times.iter().sum::<f64>() / steps as f64;
        times.sort_by(f64::total_cmp);
        let median = times[steps / 2];
        println!(
            "| {} | {} | {steps} | {median:.2} | {mean:.2} | {newton} | {most} | {linear} | {backtracks} | {:.4} | {smallest:.2e} | {penetrating} | {intersections} |",
            w.name,
            run.system().len(),
            run.kappa(),
        );
        println!(
            "{}: {factorizations} factorizations, {kept_solves} kept-factor solves, {kept_iterations} kept-factor iterations",
            w.name
        );
        if let Running::Mesh(mesh) = &run {
            println!(
                "{}: exact pair Hessians written {} times, projected after them {} times",
                w.name,
                mesh.self_contact.exact_hessians(),
                mesh.self_contact.projected_after_exact(),
            );
        }
        if let Some(path) = value("save") {
            std::fs::write(path, state_bytes(run.system()))
                .unwrap_or_else(|e| panic!("save={path}: {e}"));
        }
        if let Some(path) = value("against") {
            let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("against={path}: {e}"));
            let (dx, dv) = deviation(run.system(), &bytes);
            println!(
                "{}: deviation from {path}: position {dx:.3e} m, velocity {dv:.3e} m/s",
                w.name
            );
        }
    }
}
