//! Backward Euler as a minimization, solved by Newton's method on the sparse Hessian.
//!
//! One step minimizes the incremental potential
//! `g(x) = 1/(2 h^2) |x - y|_M^2 + E_spring(x) + E_gravity(x) + D(x)` over the free
//! particles, with `y = x_n + h v_n` and `D(x) = c/(2h) sum_s (u_s . (d_s(x) - d_s(x_n)))^2`
//! the axial damping with each spring's direction `u_s` frozen at the step's start. The
//! machinery is written for a general "effective step" `h` and prediction `y`, so other
//! one-step implicit integrators reduce to the same minimization (implicit midpoint:
//! `h/2` and `y = x_n + h/2 v_n`; BDF2: `2h/3` and its two-step prediction).
//!
//! Each Newton iteration assembles the gradient and the PSD-projected Hessian into the
//! pattern built once ([`HessianPattern`]) (once Newton is slow, a softened Hessian that
//! keeps part of the compressed springs' negative curvature, where it is positive
//! definite: [`Curvature::Softened`]), solves with the chosen linear solver, and
//! backtracks (Armijo) so `g` never increases. The objective changes in the line search
//! are computed from the differences themselves (see [`crate::spring::energy_change`]),
//! so the sufficient-decrease test stays meaningful when the change is far below `g`.
//! Stops when `|grad g|_inf <= tolerance * m_min / h^2` (`m_min` the smallest free mass),
//! at the iteration cap, or when the line search cannot decrease `g` any more.
//! The derivation and the rules are in docs/spring-sim.md.

use crate::linear::{
    DirectSolver, FactorStructure, LinearSolverChoice, LinearSolverKind, PcgSolver, dot,
};
use crate::model::{ModelError, SpringSystem, check_time_step};
use crate::pattern::{FIXED, HessianPattern};
use crate::report::{IntegratorKind, StepError, StepReport, StopReason};
use crate::spring::{self, Curvature};
use sinew_math::DVec3;
use std::time::Instant;

/// The Newton iteration's first guess.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum InitialGuess {
    /// The inertial prediction `y = x_n + h v_n`.
    Inertial,
    /// `y + h (v_n - v_{n-1})`: the prediction corrected by the last step's change of
    /// velocity (falls back to `y` on the first step). A system at rest starts exactly at
    /// its solution.
    #[default]
    Extrapolated,
}

/// Settings of the Newton solve.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default))]
pub struct NewtonSettings {
    /// Stop when `|grad g|_inf <= tolerance * m_min / h^2` (default 1e-9). `grad g` is a
    /// force and `m/h^2` turns a displacement into one, so this bounds roughly the
    /// position error of the solve in scene units.
    pub tolerance: f64,
    /// Newton iteration cap (default 50).
    pub max_iterations: usize,
    /// The linear solver (default: chosen per step from measured cost).
    pub linear_solver: LinearSolverChoice,
    /// Structure of the direct factorization (default supernodal).
    pub factor_structure: FactorStructure,
    /// The first guess (default extrapolated).
    pub initial_guess: InitialGuess,
    /// Armijo constant `c1` (default 1e-4).
    pub armijo: f64,
    /// Largest number of step halvings in one line search (default 40).
    pub max_backtracks: usize,
    /// PCG iteration cap per linear solve (default 2000).
    pub pcg_max_iterations: usize,
    /// Largest relative residual asked of PCG in a Newton iteration (default 1e-2; the
    /// forcing term is `min(this, |grad g| / |grad g_first|)`, measured against 0.1 and
    /// 1e-3 in docs/bench/spring-sim.md).
    pub pcg_forcing: f64,
    /// With `Auto`, how many steps may pass before the solver not chosen is timed again
    /// (default 64).
    pub reprobe_interval: usize,
    /// Record `g` at every iterate (costs one energy pass per iteration; for tests).
    pub record_objective: bool,
}

impl Default for NewtonSettings {
    fn default() -> Self {
        Self {
            tolerance: 1e-9,
            max_iterations: 50,
            linear_solver: LinearSolverChoice::Auto,
            factor_structure: FactorStructure::Supernodal,
            initial_guess: InitialGuess::Extrapolated,
            armijo: 1e-4,
            max_backtracks: 40,
            pcg_max_iterations: 2000,
            pcg_forcing: 1e-2,
            reprobe_interval: 64,
            record_objective: false,
        }
    }
}

impl NewtonSettings {
    /// Checks the settings, naming the bad field.
    pub fn validate(&self) -> Result<(), ModelError> {
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return Err(ModelError::BadParameter {
                name: "tolerance",
                reason: "must be positive and finite",
            });
        }
        if !(self.pcg_forcing > 0.0 && self.pcg_forcing < 1.0) {
            return Err(ModelError::BadParameter {
                name: "pcg_forcing",
                reason: "must be in (0, 1)",
            });
        }
        if !(self.armijo > 0.0 && self.armijo < 0.5) {
            return Err(ModelError::BadParameter {
                name: "armijo",
                reason: "must be in (0, 0.5)",
            });
        }
        Ok(())
    }
}

/// The most doublings of an accepted full Newton step in one line search (a step up to
/// 2^10 times the Newton step).
const MAX_EXPANSIONS: usize = 10;

/// The softened Hessian (see [`Curvature::Softened`]): after a failed attempt `theta`
/// moves to `1 - SOFTENING_RAISE (1 - theta)` (0, 0.3, 0.51, 0.66, ...).
const SOFTENING_RAISE: f64 = 0.7;
/// The largest `theta` tried before the projected Hessian is used (10 attempts from 0).
const SOFTENING_MAX_THETA: f64 = 0.97;
/// After a success the next iteration starts from `SOFTENING_LOWER theta` ...
const SOFTENING_LOWER: f64 = 0.5;
/// ... or from the exact Hessian once `theta` is below this.
const SOFTENING_EXACT_BELOW: f64 = 0.05;

/// Per-solver timing for the automatic choice (index 0: PCG, 1: direct).
///
/// The estimate is the smallest of the last [`TIMING_WINDOW`] measured step times: on a
/// shared machine noise only ever adds time, so the minimum is the robust figure, and a
/// single preempted step cannot hand the choice to the slower solver.
#[derive(Clone, Copy, Debug)]
struct SolverTiming {
    /// The last step times in seconds (a ring; infinity where not measured).
    recent: [f64; TIMING_WINDOW],
    /// Next ring slot.
    next: usize,
    /// Steps since this solver was last used.
    steps_since_used: usize,
}

/// Step times remembered per solver.
const TIMING_WINDOW: usize = 8;

impl Default for SolverTiming {
    fn default() -> Self {
        Self {
            recent: [f64::INFINITY; TIMING_WINDOW],
            next: 0,
            steps_since_used: 0,
        }
    }
}

impl SolverTiming {
    fn seconds_per_step(&self) -> Option<f64> {
        let m = self.recent.iter().copied().fold(f64::INFINITY, f64::min);
        m.is_finite().then_some(m)
    }

    fn record(&mut self, seconds: f64) {
        self.recent[self.next] = seconds;
        self.next = (self.next + 1) % TIMING_WINDOW;
        self.steps_since_used = 0;
    }
}

/// Records a step's time for the automatic solver choice. A step that converged with no
/// Newton iteration never ran the linear solver, so its time (the gradient alone) says
/// nothing about the solver's cost and is not recorded: recording it made the solver
/// probed on such a step look almost free, and `auto` then kept a solver 10x slower for
/// a dozen steps (W6 at tolerance 1e-6, found by `cargo xtask bench`).
fn record_step_time(
    timing: &mut [SolverTiming; 2],
    kind: LinearSolverKind,
    seconds: f64,
    iterations: usize,
) {
    if iterations == 0 {
        return;
    }
    let index = match kind {
        LinearSolverKind::Pcg => 0,
        LinearSolverKind::Direct => 1,
    };
    for (k, t) in timing.iter_mut().enumerate() {
        if k == index {
            t.record(seconds);
        } else {
            t.steps_since_used += 1;
        }
    }
}

/// Which one-step (or two-step) implicit scheme a minimization implements.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Scheme<'a> {
    /// `h_eff = h`, `y = x_n + h v_n`.
    BackwardEuler,
    /// The midpoint `z`: `h_eff = h/2`, `y = x_n + h/2 v_n`; `x' = 2z - x_n`.
    Midpoint,
    /// `h_eff = 2h/3`, `y = (4 x_n - x_{n-1})/3 + h_eff (4 v_n - v_{n-1})/3`.
    Bdf2 {
        /// `x_{n-1}`.
        prev_x: &'a [DVec3],
        /// `v_{n-1}`.
        prev_v: &'a [DVec3],
    },
}

/// The objective's pieces that stay fixed during one minimization.
struct Problem<'a> {
    h: f64,
    y: &'a [DVec3],
    x_ref: &'a [DVec3],
    directions: &'a [DVec3],
}

/// The backward Euler integrator: Newton on the incremental potential, with its
/// workspace (pattern, factorization, buffers) built once for a topology.
#[derive(Debug)]
pub struct BackwardEuler {
    settings: NewtonSettings,
    pattern: HessianPattern,
    direct: Option<DirectSolver>,
    pcg: PcgSolver,
    values: Vec<f64>,
    grad: Vec<f64>,
    dx: Vec<f64>,
    rhs: Vec<f64>,
    x: Vec<DVec3>,
    y: Vec<DVec3>,
    x_ref: Vec<DVec3>,
    directions: Vec<DVec3>,
    prev_velocity: Vec<DVec3>,
    have_prev_velocity: bool,
    timing: [SolverTiming; 2],
    objective_trace: Vec<f64>,
    particle_count: usize,
    spring_count: usize,
}

impl BackwardEuler {
    /// A workspace for `system`'s topology.
    pub fn new(system: &SpringSystem, settings: NewtonSettings) -> Result<Self, ModelError> {
        settings.validate()?;
        let pattern = HessianPattern::new(system);
        let n = pattern.dim();
        let direct = if settings.linear_solver == LinearSolverChoice::Direct {
            Some(Self::build_direct(&pattern, settings.factor_structure)?)
        } else {
            None
        };
        Ok(Self {
            settings,
            pcg: PcgSolver::new(&pattern),
            values: vec![0.0; pattern.nnz()],
            grad: vec![0.0; n],
            dx: vec![0.0; n],
            rhs: vec![0.0; n],
            x: system.positions().to_vec(),
            y: system.positions().to_vec(),
            x_ref: system.positions().to_vec(),
            directions: vec![DVec3::ZERO; system.springs().len()],
            prev_velocity: vec![DVec3::ZERO; system.len()],
            have_prev_velocity: false,
            timing: [SolverTiming::default(); 2],
            objective_trace: Vec::new(),
            particle_count: system.len(),
            spring_count: system.springs().len(),
            direct,
            pattern,
        })
    }

    fn build_direct(
        pattern: &HessianPattern,
        structure: FactorStructure,
    ) -> Result<DirectSolver, ModelError> {
        DirectSolver::new(pattern, structure).map_err(|_| ModelError::BadParameter {
            name: "linear_solver",
            reason: "the symbolic Cholesky factorization failed",
        })
    }

    /// The settings.
    #[must_use]
    pub fn settings(&self) -> &NewtonSettings {
        &self.settings
    }

    /// The sparsity pattern (for inspection and benchmarks).
    #[must_use]
    pub fn pattern(&self) -> &HessianPattern {
        &self.pattern
    }

    /// The direct solver, once it exists.
    #[must_use]
    pub fn direct_solver(&self) -> Option<&DirectSolver> {
        self.direct.as_ref()
    }

    /// `g` at every iterate of the last step, when `record_objective` is set.
    #[must_use]
    pub fn objective_trace(&self) -> &[f64] {
        &self.objective_trace
    }

    /// Assembles the (PSD-projected) Newton matrix at the system's current positions into
    /// the workspace, with damping directions frozen there (a kernel for benchmarks).
    pub fn assemble_newton_matrix(&mut self, system: &SpringSystem, h: f64) {
        for (dir, s) in self.directions.iter_mut().zip(system.springs()) {
            *dir = spring::damping_direction(system.positions()[s.a], system.positions()[s.b]);
        }
        assemble_hessian_values(
            &self.pattern,
            system,
            h,
            system.positions(),
            &self.directions,
            &mut self.values,
            Curvature::Clamped,
        );
    }

    /// Numerically factors the last assembled Newton matrix (building the symbolic
    /// factorization first if needed); false if it is not positive definite (a kernel for
    /// benchmarks).
    pub fn factor_newton_matrix(&mut self) -> Result<bool, ModelError> {
        if self.direct.is_none() {
            self.direct = Some(Self::build_direct(
                &self.pattern,
                self.settings.factor_structure,
            )?);
        }
        Ok(self
            .direct
            .as_mut()
            .is_some_and(|d| d.factor_only(&self.pattern, &self.values)))
    }

    /// Forgets the velocity history used by the extrapolated first guess (call after
    /// changing the state by hand).
    pub fn reset_history(&mut self) {
        self.have_prev_velocity = false;
    }

    fn check_topology(&self, system: &SpringSystem) -> Result<(), ModelError> {
        if system.len() != self.particle_count || system.springs().len() != self.spring_count {
            return Err(ModelError::TopologyMismatch);
        }
        Ok(())
    }

    /// Advances `system` by one backward Euler step of length `h`.
    pub fn step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        self.step_scheme(system, h, Scheme::BackwardEuler)
    }

    /// Advances `system` by one step of length `h` of `scheme`, each one the same
    /// minimization with its own effective step, prediction and velocity update
    /// (docs/integrators.md).
    pub(crate) fn step_scheme(
        &mut self,
        system: &mut SpringSystem,
        h: f64,
        scheme: Scheme<'_>,
    ) -> Result<StepReport, StepError> {
        check_time_step(h)?;
        self.check_topology(system)?;
        if let Scheme::Bdf2 { prev_x, prev_v } = scheme
            && (prev_x.len() != system.len() || prev_v.len() != system.len())
        {
            return Err(ModelError::TopologyMismatch.into());
        }
        let (kind, h_eff) = match scheme {
            Scheme::BackwardEuler => (IntegratorKind::BackwardEuler, h),
            Scheme::Midpoint => (IntegratorKind::ImplicitMidpoint, 0.5 * h),
            Scheme::Bdf2 { .. } => (IntegratorKind::Bdf2, 2.0 * h / 3.0),
        };
        let energy_before = system.energies();
        let fixed = system.fixed();
        for (i, (&x, &v)) in system
            .positions()
            .iter()
            .zip(system.velocities())
            .enumerate()
        {
            if fixed[i] {
                self.x_ref[i] = x;
                self.y[i] = x;
                self.x[i] = x;
                continue;
            }
            // x_ref: the point the new velocity is measured from, v' = (x' - x_ref)/h_eff
            // (also the damping's reference); y: the inertial prediction.
            let (x_ref, v_ref) = match scheme {
                Scheme::BackwardEuler | Scheme::Midpoint => (x, v),
                Scheme::Bdf2 { prev_x, prev_v } => {
                    ((4.0 * x - prev_x[i]) / 3.0, (4.0 * v - prev_v[i]) / 3.0)
                }
            };
            self.x_ref[i] = x_ref;
            self.y[i] = x_ref + h_eff * v_ref;
            self.x[i] = self.y[i];
            if self.settings.initial_guess == InitialGuess::Extrapolated && self.have_prev_velocity
            {
                self.x[i] += h_eff * (v - self.prev_velocity[i]);
            }
        }
        // Damping directions frozen at the start of the step.
        for (dir, s) in self.directions.iter_mut().zip(system.springs()) {
            *dir = spring::damping_direction(system.positions()[s.a], system.positions()[s.b]);
        }
        if matches!(scheme, Scheme::BackwardEuler) {
            // Start from x_n when the predicted guess is worse: Newton with the line
            // search never increases g from its starting point, so then every step has
            // g(x_{n+1}) <= g(x_n), which is what the energy inequality of
            // docs/labcheck.md rests on. Costs two evaluations of g per step.
            let problem = Problem {
                h: h_eff,
                y: &self.y,
                x_ref: &self.x_ref,
                directions: &self.directions,
            };
            let g_guess = objective(system, &problem, &self.x);
            let g_start = objective(system, &problem, &self.x_ref);
            // A NaN guess counts as worse, so it is never kept.
            let guess_is_no_worse = matches!(
                g_guess.partial_cmp(&g_start),
                Some(std::cmp::Ordering::Less | std::cmp::Ordering::Equal)
            );
            if !guess_is_no_worse {
                self.x.copy_from_slice(&self.x_ref);
            }
        }
        let mut report = self.minimize(system, h_eff)?;
        report.integrator = kind;
        if let Some(particle) = self.x.iter().position(|x| !x.is_finite()) {
            // Not reached with finite input (every iterate passed the line search); kept
            // so a NaN can never leave this call.
            return Err(StepError::NonFinite {
                integrator: kind,
                particle,
            });
        }
        let (positions, velocities) = system.state_mut();
        for i in 0..positions.len() {
            self.prev_velocity[i] = velocities[i];
            if !fixed_at(&self.pattern, i) {
                let v_mean = (self.x[i] - self.x_ref[i]) / h_eff;
                if matches!(scheme, Scheme::Midpoint) {
                    // self.x is the midpoint z: x' = 2 z - x_n, v' = 2 v_mean - v_n.
                    velocities[i] = 2.0 * v_mean - velocities[i];
                    positions[i] = 2.0 * self.x[i] - self.x_ref[i];
                } else {
                    velocities[i] = v_mean;
                    positions[i] = self.x[i];
                }
            }
        }
        self.have_prev_velocity = true;
        report.energy_before = energy_before;
        report.energy_after = system.energies();
        Ok(report)
    }

    fn choose_solver(&mut self, dim: usize) -> Result<LinearSolverKind, ModelError> {
        let kind = match self.settings.linear_solver {
            LinearSolverChoice::Direct => LinearSolverKind::Direct,
            LinearSolverChoice::Pcg => LinearSolverKind::Pcg,
            LinearSolverChoice::Auto => {
                let [pcg, direct] = self.timing;
                match (pcg.seconds_per_step(), direct.seconds_per_step()) {
                    (None, _) => LinearSolverKind::Pcg,
                    (_, None) => LinearSolverKind::Direct,
                    (Some(tp), Some(td)) => {
                        let (best, other, other_timing) = if tp <= td {
                            (LinearSolverKind::Pcg, LinearSolverKind::Direct, direct)
                        } else {
                            (LinearSolverKind::Direct, LinearSolverKind::Pcg, pcg)
                        };
                        if other_timing.steps_since_used >= self.settings.reprobe_interval {
                            other
                        } else {
                            best
                        }
                    }
                }
            }
        };
        if kind == LinearSolverKind::Direct && self.direct.is_none() && dim > 0 {
            self.direct = Some(Self::build_direct(
                &self.pattern,
                self.settings.factor_structure,
            )?);
        }
        Ok(kind)
    }

    /// Minimizes `g` from `self.x` in place.
    fn minimize(&mut self, system: &SpringSystem, h: f64) -> Result<StepReport, ModelError> {
        let dim = self.pattern.dim();
        let kind = self.choose_solver(dim)?;
        let started = Instant::now();
        let tol_abs = self.settings.tolerance * system.min_free_mass() / (h * h);
        let mut report = StepReport::new(IntegratorKind::BackwardEuler);
        report.linear_solver = Some(kind);
        report.tolerance = tol_abs;
        self.objective_trace.clear();
        let y = std::mem::take(&mut self.y);
        let x_ref = std::mem::take(&mut self.x_ref);
        let directions = std::mem::take(&mut self.directions);
        let problem = Problem {
            h,
            y: &y,
            x_ref: &x_ref,
            directions: &directions,
        };
        let mut first_residual_l2 = 0.0;
        let mut previous_residual = f64::INFINITY;
        // Once an iteration is slow, every later one of the step tries the softened
        // Hessian first, starting from `theta` (see `SOFTENING_*`).
        let mut softening = false;
        let mut theta = 0.0f64;
        loop {
            if self.settings.record_objective {
                self.objective_trace
                    .push(objective(system, &problem, &self.x));
            }
            self.assemble_gradient(system, &problem);
            let residual = self.grad.iter().fold(0.0f64, |m, g| m.max(g.abs()));
            report.residual = residual;
            if !residual.is_finite() {
                report.stop = StopReason::NonFinite;
                break;
            }
            if residual <= tol_abs {
                report.stop = StopReason::Converged;
                break;
            }
            if report.iterations >= self.settings.max_iterations {
                report.stop = StopReason::IterationCap;
                break;
            }
            report.iterations += 1;
            for (r, g) in self.rhs.iter_mut().zip(&self.grad) {
                *r = -g;
            }
            let residual_l2 = dot(&self.grad, &self.grad).sqrt();
            if report.iterations == 1 {
                first_residual_l2 = residual_l2;
            }
            let mut solved = false;
            // The PSD projection drops the negative curvature of compressed springs, so
            // the projected step ignores the directions along which a compressed sheet
            // buckles, and Newton crawls (hundreds of iterations from a sheet compressed
            // to half size, docs/stress.md). Once an iteration reduced the residual by
            // less than 4x, every later iteration of the step first tries the softened
            // Hessian `H(theta)`, which keeps the fraction `1 - theta` of that negative
            // curvature: the exact Hessian at `theta = 0`, the projected one at 1. It is
            // used when it is positive definite (the direct solver factors it without
            // shifts; PCG meets no non-positive curvature), `theta` is raised towards 1
            // while it is not, and lowered again after a success, so the step keeps as
            // much of the true curvature as the matrix can take (docs/spring-sim.md).
            softening |= report.iterations > 1 && residual > 0.25 * previous_residual;
            previous_residual = residual;
            // Inexact Newton for PCG: the forcing term tightens as the gradient falls,
            // and never asks for more than what ends the step.
            let forcing = (residual_l2 / first_residual_l2).min(self.settings.pcg_forcing);
            let floor = 0.1 * tol_abs / residual_l2;
            let rtol = forcing.max(floor).max(1e-13);
            if softening {
                while theta <= SOFTENING_MAX_THETA {
                    self.assemble_hessian(system, &problem, Curvature::Softened(theta));
                    if kind == LinearSolverKind::Direct {
                        if let Some(direct) = self.direct.as_mut() {
                            self.dx.copy_from_slice(&self.rhs);
                            solved =
                                direct.solve_unshifted(&self.pattern, &self.values, &mut self.dx);
                        }
                    } else {
                        // CG meets a direction of non-positive curvature exactly when the
                        // matrix is not positive definite along the Krylov space it
                        // explores.
                        self.dx.fill(0.0);
                        let outcome = self.pcg.solve(
                            &self.pattern,
                            &self.values,
                            &self.rhs,
                            &mut self.dx,
                            rtol,
                            self.settings.pcg_max_iterations,
                        );
                        report.linear_iterations += outcome.iterations;
                        solved = !outcome.negative_curvature;
                    }
                    if solved {
                        break;
                    }
                    theta = 1.0 - SOFTENING_RAISE * (1.0 - theta);
                }
                if solved {
                    report.exact_hessian_iterations += 1;
                    theta = if theta < SOFTENING_EXACT_BELOW {
                        0.0
                    } else {
                        SOFTENING_LOWER * theta
                    };
                } else {
                    // Start the next iteration's attempts from the largest theta tried.
                    theta = SOFTENING_MAX_THETA;
                    self.assemble_hessian(system, &problem, Curvature::Clamped);
                }
            } else {
                self.assemble_hessian(system, &problem, Curvature::Clamped);
            }
            if !solved
                && kind == LinearSolverKind::Direct
                && let Some(direct) = self.direct.as_mut()
            {
                self.dx.copy_from_slice(&self.rhs);
                let outcome = direct.solve(&self.pattern, &self.values, &mut self.dx);
                report.shifted_factorizations += outcome.shifts;
                if outcome.failed {
                    report.direct_failures += 1;
                } else {
                    solved = true;
                }
            }
            if !solved {
                self.dx.fill(0.0);
                let outcome = self.pcg.solve(
                    &self.pattern,
                    &self.values,
                    &self.rhs,
                    &mut self.dx,
                    rtol,
                    self.settings.pcg_max_iterations,
                );
                report.linear_iterations += outcome.iterations;
            }
            let mut slope = dot(&self.grad, &self.dx);
            if slope.is_nan() || slope >= 0.0 {
                // Not a descent direction (only from a solve gone wrong): fall back to
                // the steepest descent direction scaled by the mass matrix.
                for (f, &p) in self.pattern.free_particles.iter().enumerate() {
                    let scale = h * h / system.masses()[p];
                    for c in 0..3 {
                        self.dx[3 * f + c] = -scale * self.grad[3 * f + c];
                    }
                }
                slope = dot(&self.grad, &self.dx);
                report.descent_fallbacks += 1;
            }
            let mut alpha = 1.0;
            let mut accepted = None;
            for _ in 0..=self.settings.max_backtracks {
                let change = self.objective_change(system, &problem, alpha);
                if change <= self.settings.armijo * alpha * slope {
                    accepted = Some(change);
                    break;
                }
                report.backtracks += 1;
                alpha *= 0.5;
            }
            let Some(mut best) = accepted else {
                report.stop = StopReason::LineSearchStalled;
                break;
            };
            if alpha == 1.0 {
                // The full step was accepted: where compressed springs make g non-convex,
                // the projected Hessian overstates the curvature and its step is too
                // short, so Newton crawls (hundreds of iterations on a sheet compressed
                // to half size, docs/stress.md). Double the step while g keeps falling
                // and Armijo holds. Near a minimum of a quadratic model the doubled step
                // gives no decrease at all, so this costs one evaluation of the change of
                // g there and never changes a step that was already right.
                for _ in 0..MAX_EXPANSIONS {
                    let trial = self.objective_change(system, &problem, 2.0 * alpha);
                    if trial < best && trial <= self.settings.armijo * 2.0 * alpha * slope {
                        alpha *= 2.0;
                        best = trial;
                    } else {
                        break;
                    }
                }
            }
            for (f, &p) in self.pattern.free_particles.iter().enumerate() {
                self.x[p] +=
                    alpha * DVec3::new(self.dx[3 * f], self.dx[3 * f + 1], self.dx[3 * f + 2]);
            }
        }
        self.y = y;
        self.x_ref = x_ref;
        self.directions = directions;
        record_step_time(
            &mut self.timing,
            kind,
            started.elapsed().as_secs_f64(),
            report.iterations,
        );
        Ok(report)
    }

    fn assemble_gradient(&mut self, system: &SpringSystem, problem: &Problem<'_>) {
        let h = problem.h;
        let inv_h2 = 1.0 / (h * h);
        let gravity = system.material().gravity;
        let damping = system.material().damping / h;
        let masses = system.masses();
        for (f, &p) in self.pattern.free_particles.iter().enumerate() {
            let g = masses[p] * (inv_h2 * (self.x[p] - problem.y[p]) - gravity);
            self.grad[3 * f] = g.x;
            self.grad[3 * f + 1] = g.y;
            self.grad[3 * f + 2] = g.z;
        }
        let free = &self.pattern.free_index;
        for (s, sp) in system.springs().iter().enumerate() {
            let (xa, xb) = (self.x[sp.a], self.x[sp.b]);
            let mut force = spring::gradient(xa, xb, sp.rest_length, sp.stiffness);
            if damping > 0.0 {
                let u = problem.directions[s];
                let stretch = (xa - xb) - (problem.x_ref[sp.a] - problem.x_ref[sp.b]);
                force += damping * u.dot(stretch) * u;
            }
            let fa = free[sp.a];
            if fa != FIXED {
                self.grad[3 * fa] += force.x;
                self.grad[3 * fa + 1] += force.y;
                self.grad[3 * fa + 2] += force.z;
            }
            let fb = free[sp.b];
            if fb != FIXED {
                self.grad[3 * fb] -= force.x;
                self.grad[3 * fb + 1] -= force.y;
                self.grad[3 * fb + 2] -= force.z;
            }
        }
    }

    fn assemble_hessian(
        &mut self,
        system: &SpringSystem,
        problem: &Problem<'_>,
        curvature: Curvature,
    ) {
        assemble_hessian_values(
            &self.pattern,
            system,
            problem.h,
            &self.x,
            problem.directions,
            &mut self.values,
            curvature,
        );
    }

    /// `g(x + alpha dx) - g(x)`, from the differences.
    fn objective_change(&self, system: &SpringSystem, problem: &Problem<'_>, alpha: f64) -> f64 {
        let h = problem.h;
        let inv_2h2 = 0.5 / (h * h);
        let gravity = system.material().gravity;
        let damping = system.material().damping / h;
        let masses = system.masses();
        let step = |p: usize| -> DVec3 {
            let f = self.pattern.free_index[p];
            if f == FIXED {
                DVec3::ZERO
            } else {
                alpha * DVec3::new(self.dx[3 * f], self.dx[3 * f + 1], self.dx[3 * f + 2])
            }
        };
        let mut change = 0.0;
        for &p in &self.pattern.free_particles {
            let delta = step(p);
            let m = masses[p];
            change += m
                * (inv_2h2 * delta.dot(2.0 * (self.x[p] - problem.y[p]) + delta)
                    - gravity.dot(delta));
        }
        for (s, sp) in system.springs().iter().enumerate() {
            let delta = step(sp.a) - step(sp.b);
            if delta == DVec3::ZERO {
                continue;
            }
            let d = self.x[sp.a] - self.x[sp.b];
            change += spring::energy_change(d, delta, sp.rest_length, sp.stiffness);
            if damping > 0.0 {
                let u = problem.directions[s];
                let e = u.dot(d - (problem.x_ref[sp.a] - problem.x_ref[sp.b]));
                let de = u.dot(delta);
                change += 0.5 * damping * de * (2.0 * e + de);
            }
        }
        change
    }
}

fn fixed_at(pattern: &HessianPattern, particle: usize) -> bool {
    pattern.free_index[particle] == FIXED
}

/// Writes the Newton matrix `M/h^2 + sum_s (K_s + c/h u_s u_s^T)` (PSD-clamped spring
/// blocks, fixed particles removed) into `values` on `pattern`.
pub(crate) fn assemble_hessian_values(
    pattern: &HessianPattern,
    system: &SpringSystem,
    h: f64,
    x: &[DVec3],
    directions: &[DVec3],
    values: &mut [f64],
    curvature: Curvature,
) {
    values.fill(0.0);
    let inv_h2 = 1.0 / (h * h);
    let damping = system.material().damping / h;
    let masses = system.masses();
    for (f, &p) in pattern.free_particles.iter().enumerate() {
        let m = masses[p] * inv_h2;
        let s = &pattern.diag_slots[f];
        values[s[0]] += m;
        values[s[3]] += m;
        values[s[5]] += m;
    }
    for (s, sp) in system.springs().iter().enumerate() {
        // K = alpha I + beta u u^T + gamma w w^T (w the frozen damping direction): the six
        // distinct entries are written directly, the hot loop of assembly.
        let (alpha, beta, u) = spring::hessian_coefficients(
            x[sp.a] - x[sp.b],
            sp.rest_length,
            sp.stiffness,
            curvature,
        );
        let w = directions[s];
        let gamma = damping;
        let entry = |r: usize, c: usize| beta * u[r] * u[c] + gamma * w[r] * w[c];
        let xx = alpha + entry(0, 0);
        let yx = entry(1, 0);
        let zx = entry(2, 0);
        let yy = alpha + entry(1, 1);
        let zy = entry(2, 1);
        let zz = alpha + entry(2, 2);
        let lower = [xx, yx, zx, yy, zy, zz];
        let (fa, fb) = (pattern.free_index[sp.a], pattern.free_index[sp.b]);
        for f in [fa, fb] {
            if f != FIXED {
                let slots = &pattern.diag_slots[f];
                for (slot, v) in slots.iter().zip(lower) {
                    values[*slot] += v;
                }
            }
        }
        if let Some(slots) = &pattern.off_slots[s] {
            // Entry (r, c) at slot 3c + r; the block is symmetric.
            let full = [xx, yx, zx, yx, yy, zy, zx, zy, zz];
            for (slot, v) in slots.iter().zip(full) {
                values[*slot] -= v;
            }
        }
    }
}

/// `g(x)` evaluated directly (for tests and the recorded trace).
fn objective(system: &SpringSystem, problem: &Problem<'_>, x: &[DVec3]) -> f64 {
    let h = problem.h;
    let damping = system.material().damping / h;
    let gravity = system.material().gravity;
    let mut g = 0.0;
    for (p, (&m, &fixed)) in system.masses().iter().zip(system.fixed()).enumerate() {
        if !fixed {
            g += 0.5 * m / (h * h) * (x[p] - problem.y[p]).length_squared() - m * gravity.dot(x[p]);
        }
    }
    for (s, sp) in system.springs().iter().enumerate() {
        g += spring::energy(x[sp.a], x[sp.b], sp.rest_length, sp.stiffness);
        let e = problem.directions[s]
            .dot((x[sp.a] - x[sp.b]) - (problem.x_ref[sp.a] - problem.x_ref[sp.b]));
        g += 0.5 * damping * e * e;
    }
    g
}

/// The assembled Newton matrix of `system` at its current positions for step `h`, as
/// dense lower-triangle triplets `(row, col, value)` over the reduced unknowns (for
/// tests and benchmarks of assembly; damping directions frozen at the current state).
#[must_use]
pub fn newton_matrix_triplets(system: &SpringSystem, h: f64) -> Vec<(usize, usize, f64)> {
    let pattern = HessianPattern::new(system);
    let mut values = vec![0.0; pattern.nnz()];
    let directions: Vec<DVec3> = system
        .springs()
        .iter()
        .map(|s| spring::damping_direction(system.positions()[s.a], system.positions()[s.b]))
        .collect();
    assemble_hessian_values(
        &pattern,
        system,
        h,
        system.positions(),
        &directions,
        &mut values,
        Curvature::Clamped,
    );
    let col_ptr = pattern.symbolic.col_ptr();
    let row_idx = pattern.symbolic.row_idx();
    let mut out = Vec::with_capacity(values.len());
    for j in 0..pattern.dim() {
        for k in col_ptr[j]..col_ptr[j + 1] {
            out.push((row_idx[k], j, values[k]));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_without_newton_iterations_does_not_time_the_solver() {
        let mut timing = [SolverTiming::default(); 2];
        record_step_time(&mut timing, LinearSolverKind::Pcg, 0.010, 2);
        // The direct probe lands on a step that converged at once: 1 us of gradient work.
        record_step_time(&mut timing, LinearSolverKind::Direct, 1e-6, 0);
        assert_eq!(timing[0].seconds_per_step(), Some(0.010));
        assert_eq!(
            timing[1].seconds_per_step(),
            None,
            "direct is still unmeasured"
        );
        // Its first step with a solve is what counts.
        record_step_time(&mut timing, LinearSolverKind::Direct, 0.190, 1);
        assert_eq!(timing[1].seconds_per_step(), Some(0.190));
        assert_eq!(timing[0].steps_since_used, 1);
        assert_eq!(timing[1].steps_since_used, 0);
    }
}
