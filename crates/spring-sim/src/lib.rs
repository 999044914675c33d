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
//!   static or kinematic): signed distances, the log barrier, the time of impact,
//!   lagged smoothed friction, and a projection for the explicit integrators;
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
//! Derivations: docs/spring-sim.md. Measurements: docs/bench/spring-sim.md.

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
