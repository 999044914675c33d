//! sinew-spring-sim: mass-spring systems (the lab cloth, ropes, your own) integrated by
//! backward Euler solved as a minimization with Newton's method on a sparse Hessian
//! (faer), and, for comparison, by explicit symplectic Euler and by the lab report's
//! flawed method.
//!
//! - [`model`]: particles, springs, material, validation with errors naming the item,
//!   builders ([`ClothGrid`] for docs/workloads.md W4-W6, [`Rope`]).
//! - [`spring`]: per-spring energy, gradient, exact Hessian block and its PSD projection.
//! - [`potential`]: the incremental potential as a sum of terms (inertia, gravity,
//!   springs, axial damping), each written once with its energy, change along a
//!   direction, gradient, PSD-projected Hessian blocks and largest safe step.
//! - [`newton`]: [`BackwardEuler`], Newton with Armijo backtracking on the incremental
//!   potential over the free particles, stopping at `|grad g|_inf <= tol m_min / h^2`.
//! - [`linear`]: the sparse Cholesky (symbolic once per topology) and block-Jacobi PCG
//!   solvers behind one choice, [`LinearSolverChoice`].
//! - [`integrator`]: [`Simulation`] and [`Integrator`], the one stepping call for every
//!   integrator; [`report`]: [`StepReport`].
//! - [`implicit`]: [`Bdf2`] and [`ImplicitMidpoint`] on the same Newton minimization.
//! - [`explicit`]: symplectic Euler and [`VelocityVerlet`] with substeps;
//!   [`stability`]: their stability bound ([`StabilityBound`]), from which
//!   [`Integrator::VelocityVerlet`] and `auto` ([`Integrator::Auto`]) choose the substep
//!   count and which refuses a count below it. [`mod@reference`]: comparison only.
//! - [`metrics`]: [`metrics::run`], a whole run with the metrics scene runners print.
//! - [`contact`]: contact with rigid colliders after IPC (half-space, sphere, capsule,
//!   static or kinematic): signed distances, the log barrier, the time of impact,
//!   lagged smoothed friction, and a projection for the explicit integrators.
//!
//! Linear solver choice (`Auto`): PCG while the PCG iterations it needs per Newton
//! iteration stay below a crossover computed from counts ([`linear::SolverCosts`]: the
//! factor's size under a fill-reducing ordering, the matrix's nonzeros), the direct solve
//! above it; PCG is observed again every `reprobe_interval` steps. No timing, so two
//! identical runs give bitwise the same results.
//!
//! ```
//! use sinew_spring_sim::{ClothGrid, Integrator, Simulation, SpringSystem};
//! let cloth = SpringSystem::cloth(&ClothGrid::lab(0.2)).unwrap();
//! let mut sim = Simulation::new(cloth, Integrator::default()).unwrap();
//! let report = sim.step(1.0 / 60.0).unwrap();
//! assert!(report.residual <= report.tolerance);
//! ```
//!
//! Derivations: docs/spring-sim.md. Measurements: docs/bench/spring-sim.md.

pub mod contact;
pub mod explicit;
pub mod implicit;
pub mod integrator;
pub mod linear;
pub mod metrics;
pub mod model;
pub mod newton;
mod pattern;
pub mod potential;
pub mod reference;
pub mod report;
pub mod spring;
pub mod stability;

pub use explicit::{SymplecticEuler, VelocityVerlet};
pub use implicit::{Bdf2, ImplicitMidpoint};
pub use integrator::{AutoSettings, Integrator, Simulation};
pub use linear::{FactorStructure, LinearSolverChoice, LinearSolverKind};
pub use metrics::{RunMetrics, run, run_observed};
pub use model::{
    ClothGrid, Energies, Material, ModelError, Particle, Rope, Spring, SpringSpec, SpringSystem,
};
pub use newton::{BackwardEuler, InitialGuess, NewtonSettings};
pub use pattern::HessianPattern;
pub use report::{AutoReason, IntegratorKind, StepError, StepReport, StopReason};
pub use stability::{StabilityBound, StabilityMonitor};
