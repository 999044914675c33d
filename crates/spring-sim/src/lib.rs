//! sinew-spring-sim: mass-spring systems (the lab cloth, ropes, your own) integrated by
//! backward Euler solved as a minimization with Newton's method on a sparse Hessian
//! (faer), and, for comparison, by explicit symplectic Euler and by the lab report's
//! flawed method.
//!
//! Everything needed to build and step a system is at the crate root, reached by that
//! one path: the model ([`SpringSystem`], [`ClothGrid`] for docs/workloads.md W4-W6,
//! [`Rope`], [`Material`], validation with errors naming the item), the steppers
//! ([`Simulation`] and [`Integrator`], the one stepping call for every integrator;
//! [`BackwardEuler`], Newton with Armijo backtracking on the incremental potential over
//! the free particles, stopping when every free particle's force is at most
//! `tol m_p / h^2`; [`Bdf2`] and [`ImplicitMidpoint`] on the same minimization;
//! [`SymplecticEuler`] and [`VelocityVerlet`] with substeps), the linear solver choice ([`LinearSolverChoice`]:
//! sparse Cholesky, symbolic once per topology, or block-Jacobi PCG), what a step reports
//! ([`StepReport`]), the explicit integrators' stability bound ([`StabilityBound`], from
//! which [`Integrator::VelocityVerlet`] and [`Integrator::Auto`] choose the substep count
//! and which refuses a count below it) and whole runs ([`run`], the metrics scene
//! runners print). The specialised parts are public modules whose items are reached only
//! there:
//!
//! - [`contact`]: contact with rigid colliders after IPC (half-space, sphere, capsule,
//!   static, kinematic, or driven step by step along an animation:
//!   [`Simulation::drive_collider`]): signed distances, the log barrier, the time of
//!   impact, lagged smoothed friction, and a projection for the explicit integrators;
//! - [`potential`]: the incremental potential as a sum of terms (inertia, gravity,
//!   springs, axial damping), each written once with its energy, change along a
//!   direction, gradient, PSD-projected Hessian blocks and largest safe step, and the
//!   [`potential::Term`] trait for your own;
//! - [`spring`]: per-spring energy, gradient, exact Hessian block and its PSD projection;
//! - [`mod@reference`]: the lab report's flawed method, for comparison only.
//!
//! Linear solver choice (`Auto`): PCG while the PCG iterations it needs per Newton
//! iteration stay below a crossover computed from counts ([`linear::SolverCosts`]: the
//! factor's size under a fill-reducing ordering, the matrix's nonzeros), the direct solve
//! above it; PCG is observed again every `reprobe_interval` steps. No timing, so two
//! identical runs give bitwise the same results.
//!
//! ```
//! use sinew_spring_sim::{ClothGrid, Integrator, Simulation, SpringSystem};
//! let cloth = SpringSystem::cloth(&ClothGrid::lab()).unwrap();
//! let mut sim = Simulation::new(cloth, Integrator::default()).unwrap();
//! let report = sim.step(1.0 / 60.0).unwrap();
//! assert!(report.residual <= report.tolerance);
//! ```
//!
//! A triangle-mesh sheet dropped over a ball lying on the ground, with friction against
//! both and self-contact: backward Euler with the colliders' barrier as a term and the
//! cloth's own barrier between its vertices, triangles and edges. Each accepted state is
//! checked here independently of the solver: every particle outside every collider (its
//! signed distance positive) and no two triangles of the sheet meeting (the exact test of
//! the separate crate `sinew-exact`).
//!
//! ```
//! use sinew_spring_sim::contact::self_contact::SelfContactSettings;
//! use sinew_spring_sim::contact::{Collider, ContactSettings, signed_distance};
//! use sinew_spring_sim::{Bending, ClothGrid, DVec3, Material, MeshCloth, NewtonSettings};
//! use sinew_spring_sim::TriangleMesh;
//!
//! // A 12 x 12 sheet, 0.44 m wide, flat 2 cm above a ball of radius 0.1 on the ground.
//! let origin = DVec3::new(-0.22, 0.22, -0.22);
//! let grid = ClothGrid { size: 12, spacing: 0.04, origin, ..ClothGrid::lab() };
//! let (positions, triangles) = grid.sheet(DVec3::X, DVec3::Z, 0);
//! let mesh = TriangleMesh::new(positions, triangles)?;
//! let gravity = DVec3::new(0.0, -9.81, 0.0);
//! let cloth = MeshCloth {
//!     areal_density: 0.2,
//!     material: Material { stiffness: 200.0, damping: 0.1, gravity },
//!     bending: Bending::None,
//!     fixed: vec![],
//! };
//! let model = cloth.build(&mesh)?;
//! let newton = NewtonSettings { tolerance: 1e-6, ..NewtonSettings::default() };
//! let mut integrator = model.backward_euler(newton)?;
//! let ball = Collider::sphere(DVec3::new(0.0, 0.1, 0.0), 0.1);
//! let colliders = vec![ball, Collider::ground(0.0)];
//! let contact = ContactSettings { dhat: 1e-3, mu: 0.3, ..ContactSettings::default() };
//! model.enable_contact(&mut integrator, colliders.clone(), contact)?;
//! let own = SelfContactSettings { dhat: 1e-3, thickness: 5e-4, ..Default::default() };
//! let stats = model.enable_self_contact(&mut integrator, own)?;
//! let mut system = model.system.clone();
//! let mut most_pairs = 0;
//! for _ in 0..30 {
//!     let report = integrator.step(&mut system, 1.0 / 60.0)?;
//!     most_pairs = most_pairs.max(stats.active_pairs());
//!     assert!(report.residual <= report.tolerance);
//!     for x in system.positions() {
//!         for c in &colliders {
//!             // Static colliders: their pose at any time is their pose at 0.
//!             assert!(signed_distance(&c.at(0.0), *x, 0.0).distance > 0.0);
//!         }
//!     }
//!     let meeting = sinew_exact::intersecting_pairs(system.positions(), &model.triangles);
//!     assert!(meeting.is_empty());
//! }
//! // The sheet's edges fell past the ball to the ground, and its folds brought parts of
//! // it within `dhat` of each other (measured: 180 pairs at most, the lowest vertex 0.6
//! // mm above the ground).
//! let lowest = system.positions().iter().map(|x| x.y).fold(f64::INFINITY, f64::min);
//! assert!(lowest < 0.01, "lowest point {lowest}");
//! assert!(most_pairs > 0);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Derivations: docs/spring-sim.md and, for contact, docs/contact.md. Measurements:
//! docs/bench/spring-sim.md and docs/bench/contact.md.

pub mod contact;
mod explicit;
mod implicit;
mod integrator;
mod linear;
mod mesh;
mod metrics;
mod model;
mod newton;
mod pattern;
mod pins;
mod pool;
pub mod potential;
pub mod reference;
mod report;
pub mod spring;
mod stability;

pub use explicit::{PARALLEL_MIN_PARTICLES, SymplecticEuler, VelocityVerlet};
pub use implicit::{Bdf2, ImplicitMidpoint};
pub use integrator::{AutoCosts, AutoSettings, Integrator, Simulation};
pub use linear::{
    DirectSolver, FactorStructure, KeptFactorOutcome, KeptFactorStatus, LinearSolverChoice,
    LinearSolverKind, SolverCosts, SolverError,
};
pub use mesh::{Bending, EdgeHinge, MeshCloth, MeshClothModel, MeshError, TriangleMesh};
pub use metrics::{DIVERGENCE_RADIUS, RunMetrics, run, run_observed};
pub use model::{
    ClothGrid, Energies, MAX_TIME_STEP, MIN_TIME_STEP, Material, ModelError, Particle, Rope,
    SettingsError, Spring, SpringSpec, SpringSystem, Topology, check_time_step,
};
pub use newton::{
    BackwardEuler, InitialGuess, MAX_FRICTION_LAGS, NewtonSettings, newton_matrix_triplets,
};
pub use pattern::HessianPattern;
pub use pins::{
    PIN_SPLIT_DEPTH, PinDriver, PinnedMotion, PinnedStepper, pinned_move_fraction, step_to_targets,
};
pub use report::{AutoReason, IntegratorKind, PieceEnds, StepError, StepReport, StepStop};
/// The vector type positions, velocities and forces are given in, re-exported so a user
/// of this crate does not also have to depend on sinew-math.
pub use sinew_math::DVec3;
pub use stability::{StabilityBound, StabilityMonitor, uniform_bound};
