//! The minimization of one step: Newton iterations on the terms of the potential, each
//! assembling the gradient and the (PSD-projected, or once Newton is slow, softened)
//! Hessian, solving with the chosen linear solver and searching along the step
//! ([`super::line_search`]).

use super::{BackwardEuler, Kept, line_search};
use crate::linear::{KeptFactorStatus, LinearSolverKind, PcgOutcome, dot};
use crate::model::{ModelError, SpringSystem};
use crate::potential::{HessianSink, StepContext};
use crate::report::{IntegratorKind, StepReport, StepStop};
use crate::spring::Curvature;
use sinew_math::DVec3;

/// The round-off floor's multiple of `eps` (see [`roundoff_floor`]).
const ROUNDOFF_FLOOR_ULPS: f64 = 16.0;

/// The size below which the residual is round-off: `16 eps m_min max_i (|y_i|_inf / h^2 +
/// |gravity|_inf)` over the free particles, the rounding of the inertia and gravity terms
/// (`m/h^2 (x - y)` loses `eps |y| m/h^2` in the subtraction), each particle's scaled to
/// the smallest mass as the residual is ([`BackwardEuler::mass_scales`]). Springs add their
/// own rounding, which this leaves out: a stiff system at rest may then run one Newton
/// iteration per step that ends in the line search, reported as converged.
fn roundoff_floor(system: &SpringSystem, step: &StepContext<'_>, h: f64) -> f64 {
    let g = system.material().gravity.abs().max_element();
    let inv_h2 = 1.0 / (h * h);
    let largest = step
        .y
        .iter()
        .zip(system.fixed())
        .filter(|(_, f)| !**f)
        .map(|(y, _)| y.abs().max_element() * inv_h2 + g)
        .fold(0.0f64, f64::max);
    ROUNDOFF_FLOOR_ULPS * f64::EPSILON * (system.min_free_mass() * largest)
}

/// The fraction of the round-off floor (`BackwardEuler::gradient_floor`, `16 eps |x|`
/// times the largest row sum) under which a residual that stopped falling ends the step
/// as [`StepStop::RoundOff`]: one sixteenth, so `eps |x|` times the row sum, the rounding
/// of a single operation on the coordinates. Between it and the floor a slow Newton goes
/// on (to the tolerance or the cap): with the whole floor as the threshold, the contact
/// stress cases ended steps at residuals up to 0.99 of it that a few more iterations
/// still lowered (docs/spring-sim.md).
const ROUNDOFF_STOP_BELOW: f64 = 1.0 / 16.0;

/// The relative residual a solve preconditioned by the kept factor is taken to: tight
/// enough that its direction stands for the exact one the factorization gives (the
/// Newton iterations are then those of the direct solve), yet a few iterations away
/// with a factor of a nearby matrix.
const KEPT_FACTOR_RTOL: f64 = 1e-10;

/// The softened Hessian (see [`Curvature::Softened`]): after a failed attempt `theta`
/// moves to `1 - SOFTENING_RAISE (1 - theta)` (0, 0.3, 0.51, 0.66, ...).
const SOFTENING_RAISE: f64 = 0.7;
/// The largest `theta` tried before the projected Hessian is used (10 attempts from 0).
const SOFTENING_MAX_THETA: f64 = 0.97;
/// After a success the next iteration starts from `SOFTENING_LOWER theta` ...
const SOFTENING_LOWER: f64 = 0.5;
/// ... or from the exact Hessian once `theta` is below this.
const SOFTENING_EXACT_BELOW: f64 = 0.05;

impl BackwardEuler {
    /// Minimizes `g` from `self.x` in place.
    ///
    /// With a thread pool the whole minimization runs inside it, so the calling thread
    /// hands the step over once: the parallel passes inside (assembly, PCG, the line
    /// search) are then started from one of the pool's own threads, without a hand-off
    /// between threads and a wait to be woken at every one of them.
    ///
    /// `from_minimizer`: `self.x` is the minimizer of an earlier round of the same step
    /// (friction lagged again, see [`crate::NewtonSettings::friction_lags`]), so a
    /// residual within the tolerance there ends the minimization with no iteration; a
    /// step's first guess, and a round that starts again from x_n, always get at least
    /// one.
    pub(super) fn minimize(
        &mut self,
        system: &SpringSystem,
        h: f64,
        from_minimizer: bool,
    ) -> Result<StepReport, ModelError> {
        #[cfg(feature = "parallel")]
        if let Some(pool) = self.pcg.pool().cloned() {
            return pool.install(|| {
                let report = self.minimize_here(system, h, from_minimizer);
                // A direct solver still being set up (an iteration that widened the
                // pattern and ended without a direct solve) is taken on the pool, so
                // none is left pending once the minimization returns.
                let settled = self.settle_direct();
                let report = report?;
                settled.map(|()| report)
            });
        }
        self.minimize_here(system, h, from_minimizer)
    }

    /// [`Self::minimize`] on the current thread.
    fn minimize_here(
        &mut self,
        system: &SpringSystem,
        h: f64,
        from_minimizer: bool,
    ) -> Result<StepReport, ModelError> {
        // Transient couplings idle for long enough leave the pattern (see `couplings`);
        // the direct solver's set-up runs beside the first iteration's work.
        let dropped = self.narrow_if_due(system)?;
        let dim = self.pattern.dim();
        let mut kind = self.choose_solver(dim)?;
        let m_min = system.min_free_mass();
        let tol_abs = self.settings.tolerance * m_min / (h * h);
        self.mass_scales.clear();
        self.mass_scales.extend(
            self.pattern
                .free_particles
                .iter()
                .map(|&p| m_min / system.masses()[p]),
        );
        let mut report = StepReport::new(IntegratorKind::BackwardEuler);
        report.linear_solver = Some(kind);
        report.tolerance = tol_abs;
        report.effective_step = h;
        report.pattern_pairs_dropped = dropped;
        self.objective_trace.clear();
        if self.settings.record_objective {
            self.step_trace_starts.push(self.step_traces.len());
        }
        let y = std::mem::take(&mut self.y);
        let x_ref = std::mem::take(&mut self.x_ref);
        let step = StepContext::new(system, h, &y, &x_ref).with_timing(self.timing);
        // Each step starts from a factorization of its own first matrix, so a step does
        // not depend on the solves of the step (or abandoned attempt) before it.
        if let Some(direct) = self.direct.as_mut() {
            direct.forget_factor();
        }
        let mut first_residual_l2 = 0.0;
        let mut previous_residual = f64::INFINITY;
        // Once an iteration is slow, every later one of the step tries the softened
        // Hessian first, starting from `theta` (see `SOFTENING_*`).
        let mut softening = false;
        let mut theta = 0.0f64;
        // Whether asking for the exact contact blocks can change the Newton matrix: false
        // once a refused matrix with them equalled the one without (no term of this
        // system has them), so the rest of the step does not try them in vain.
        let mut exact_contact_differs = true;
        // The refused matrix, kept for that comparison (allocated on the first refusal).
        let mut saved: Vec<f64> = Vec::new();
        // Whether the iterations before Newton is slow still try the exact contact
        // blocks first: not after one such matrix was refused in the step.
        let mut exact_first = true;
        // Whether the last iteration's matrix with the exact contact blocks was refused:
        // this iteration then asks for the projected blocks at once (see below).
        let mut exact_refused_last = false;
        loop {
            // Pairs a term coupled without Hessian slots in the last iteration (self-contact
            // meeting particles no spring joins) get slots now rather than after the step:
            // without their off-diagonal blocks the Newton matrix misses the contact's
            // coupling and Newton converges only linearly, typically to the iteration cap.
            let missing = self.potential.take_missing_pairs();
            if !missing.is_empty() {
                self.widen(system, &missing, Kept::WhileUsed, true)?;
                report.pattern_pairs_added += missing.len();
            }
            // With the trace recorded, `g` is also evaluated before the active set's
            // update: a term that changed the function there (the contact barrier's
            // stiffness doubled) starts a new slice of the step's traces, so each slice
            // is one function's descent. (The same function at the same point gives
            // the same bits.)
            let before = (self.settings.record_objective && report.iterations > 0)
                .then(|| self.potential.energy(&step, &self.x));
            self.potential.update_active_set(&step, &self.x);
            if self.settings.record_objective {
                let g = self.potential.energy(&step, &self.x);
                if before.is_some_and(|b| b.to_bits() != g.to_bits()) {
                    self.step_trace_starts.push(self.step_traces.len());
                }
                self.objective_trace.push(g);
                self.step_traces.push(g);
            }
            // The step's first Newton iteration follows its first gradient (unless that
            // is at the round-off floor) and assembles the projected Hessian at the same
            // positions: the springs' blocks are computed in the gradient's pass over the
            // springs. Later gradients are usually the step's last (converged), so they
            // compute the gradient alone.
            let blocks = (report.iterations == 0 && !softening).then_some(Curvature::Clamped);
            let (residual, residual_l2_squared, blocks_ready) =
                self.assemble_gradient(&step, blocks);
            report.residual = residual;
            if !residual.is_finite() {
                report.stop = StepStop::NonFinite;
                break;
            }
            // The guess alone does not end a step: a loose tolerance (`tol m/h^2` above the
            // gravity force) would pass the prediction itself and no iteration would ever
            // correct it, and a settled cloth would freeze at rest short of equilibrium.
            // At least one Newton iteration runs unless the residual is already at the
            // round-off floor of the gradient's evaluation, so the error from the exact
            // step shrinks with the tolerance (docs/spring-sim.md, "Stopping test"). A
            // round started at an earlier round's minimizer has had its iterations.
            if residual <= tol_abs
                && (report.iterations > 0
                    || from_minimizer
                    || residual <= roundoff_floor(system, &step, h))
            {
                report.stop = StepStop::Converged;
                break;
            }
            // A tolerance below the round-off floor of the gradient (inertia, springs and
            // damping) cannot be reached: once the residual is a good way below that floor
            // (`ROUNDOFF_STOP_BELOW`) and an iteration no longer halves it, the iterations
            // are moving round-off about, and the step ends there rather than at the cap
            // (which would also send it to be split, for nothing). While the residual
            // still falls fast, they go on: the floor is a bound, and the rounding is often
            // well below it.
            if report.iterations > 0
                && residual > 0.5 * previous_residual
                && residual <= ROUNDOFF_STOP_BELOW * self.gradient_floor(system, h)
            {
                report.stop = StepStop::RoundOff;
                break;
            }
            if report.iterations >= self.settings.max_iterations {
                report.stop = StepStop::IterationCap;
                break;
            }
            // PCG far above the cost model's crossover finishes the step on the direct
            // solve (solver_choice).
            kind = self.reconsider_solver(kind, report.iterations, report.linear_iterations)?;
            report.linear_solver = Some(kind);
            report.iterations += 1;
            let residual_l2 = residual_l2_squared.sqrt();
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
            // and never asks for more than what ends the step. The exception is the
            // iteration the rule above asks for from a residual already below the
            // tolerance: there "what ends the step" is nothing at all, PCG would return
            // the zero direction from its zero start, and the iteration would correct
            // nothing while its line search halved a steepest-descent fallback down to
            // round-off (a dozen evaluations of the potential). Its relative tolerance is
            // held at or below one half, so PCG takes at least one step and the correction
            // still scales with the tolerance.
            let forcing = (residual_l2 / first_residual_l2).min(self.settings.pcg_forcing);
            let floor = if residual <= tol_abs {
                (0.1 * tol_abs / residual_l2).min(0.5)
            } else {
                0.1 * tol_abs / residual_l2
            };
            let rtol = forcing.max(floor).max(1e-13);
            // Once Newton is slow, the contact pairs' exact Hessians are tried first with
            // the softened springs (`Curvature::ExactContact`, for terms that have them
            // and are set to give them): the projection drops each pair's negative
            // curvature, and the Newton step then converges only linearly (docs/bench/contact.md,
            // "The exact pair Hessian first"). That negative curvature is the barrier's,
            // which no `theta` removes, so a matrix with them that is not positive definite
            // is replaced at once by the one with their projections, at the same `theta`.
            // A refusal is usually followed by another at the next iterate (seven times in
            // eight on the wound twist), each a failed solve (a factorization, or PCG meeting
            // non-positive curvature) and an assembly for nothing, so the iteration after a
            // refusal skips the exact blocks and the one after that tries them again
            // (docs/bench/contact.md, "A refused exact matrix skips the next iteration's").
            let mut exact_contact =
                exact_contact_differs && softening && !std::mem::take(&mut exact_refused_last);
            if softening {
                let mut assembled = false;
                while theta <= SOFTENING_MAX_THETA {
                    if !assembled {
                        let curvature = if exact_contact {
                            Curvature::ExactContact(theta)
                        } else {
                            Curvature::Softened(theta)
                        };
                        self.assemble_hessian(&step, curvature);
                    }
                    assembled = false;
                    self.settle_direct()?;
                    solved = self.unshifted_direction(kind, rtol, &mut report);
                    if solved {
                        break;
                    }
                    if exact_contact {
                        exact_contact = false;
                        if self.reassembled_differs(&step, Curvature::Softened(theta), &mut saved) {
                            report.contact_projection_fallbacks += 1;
                            exact_refused_last = true;
                            assembled = true;
                            continue;
                        }
                        exact_contact_differs = false;
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
                    self.assemble_hessian(&step, Curvature::Clamped);
                }
            } else if exact_first && exact_contact_differs && self.potential.gives_exact_contact() {
                // Before Newton is slow too, the contact pairs' exact Hessians first, with
                // the springs' clamped blocks (`ExactContact(1)`: `Softened(1)` is
                // `Clamped` bit for bit, so the blocks the gradient's pass computed serve);
                // their projections when that matrix is refused (docs/bench/contact.md, "The
                // exact pair Hessian from the first iteration").
                self.assemble_hessian_with(&step, Curvature::ExactContact(1.0), blocks_ready);
                self.settle_direct()?;
                solved = self.unshifted_direction(kind, rtol, &mut report);
                if !solved {
                    exact_first = false;
                    saved.clear();
                    saved.extend_from_slice(&self.values);
                    self.assemble_hessian_with(&step, Curvature::Clamped, blocks_ready);
                    if saved == self.values {
                        exact_contact_differs = false;
                    } else {
                        report.contact_projection_fallbacks += 1;
                    }
                }
            } else {
                self.assemble_hessian_with(&step, Curvature::Clamped, blocks_ready);
            }
            self.settle_direct()?;
            if !solved && kind == LinearSolverKind::Direct && self.direct.is_some() {
                solved = self.direct_direction(true, &mut report);
            }
            if !solved {
                let outcome = self.pcg_direction(rtol);
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
            for (f, &p) in self.pattern.free_particles.iter().enumerate() {
                self.dx_particles[p] =
                    DVec3::new(self.dx[3 * f], self.dx[3 * f + 1], self.dx[3 * f + 2]);
            }
            // An iteration that starts within the tolerance only polishes a step that is
            // already acceptable (the forced iteration above): its full Newton step is
            // taken without the doubling trials, which exist for the crawl through
            // non-convex regions far from the solution and would cost one more energy
            // change for nothing here (on a resting sheet, the only line search of the
            // step).
            let expand = residual > tol_abs;
            let outcome = self.line_search(&step, slope, expand);
            report.backtracks += outcome.backtracks;
            let Some(alpha) = outcome.alpha else {
                // Below the tolerance already (an iteration the rule above asked for from
                // a residual just above the round-off floor) the step is converged.
                report.stop = if residual <= tol_abs {
                    StepStop::Converged
                } else if outcome.none_finite {
                    StepStop::Overflow
                } else {
                    StepStop::LineSearchStalled
                };
                break;
            };
            for &p in &self.pattern.free_particles {
                self.x[p] += alpha * self.dx_particles[p];
            }
        }
        self.y = y;
        self.x_ref = x_ref;
        self.chooser
            .record(kind, report.iterations, report.linear_iterations);
        Ok(report)
    }

    /// The Newton direction of the assembled matrix into `dx`, only if the matrix is
    /// positive definite (no shifts): whether it was found.
    fn unshifted_direction(
        &mut self,
        kind: LinearSolverKind,
        rtol: f64,
        report: &mut StepReport,
    ) -> bool {
        if kind == LinearSolverKind::Direct {
            self.direct.is_some() && self.direct_direction(false, report)
        } else {
            // CG meets a direction of non-positive curvature exactly when the matrix is
            // not positive definite along the Krylov space it explores.
            let outcome = self.pcg_direction(rtol);
            report.linear_iterations += outcome.iterations;
            !outcome.negative_curvature
        }
    }

    /// Assembles the Newton matrix in the form `curvature` asks for in place of the
    /// refused one (kept in `saved`), and returns whether the two differ: when they do
    /// not, no term distinguished the refused form from this one, and this matrix is
    /// refused as well.
    fn reassembled_differs(
        &mut self,
        step: &StepContext<'_>,
        curvature: Curvature,
        saved: &mut Vec<f64>,
    ) -> bool {
        saved.clear();
        saved.extend_from_slice(&self.values);
        self.assemble_hessian(step, curvature);
        *saved != self.values
    }

    /// The Newton direction of the assembled matrix on the direct solver, into `dx`:
    /// first by conjugate gradients preconditioned with the kept factor, within
    /// `factor_reuse_iterations` iterations, else by a factorization of the matrix
    /// itself (with the shifted retries when `shifted`). Returns whether a direction was
    /// found. Without `shifted` (the softened Hessian, used only when positive definite)
    /// it is false when the matrix is shown not to be positive definite: by a direction
    /// of non-positive curvature, or by a failed factorization.
    fn direct_direction(&mut self, shifted: bool, report: &mut StepReport) -> bool {
        let Some(direct) = self.direct.as_mut() else {
            return false;
        };
        self.dx.copy_from_slice(&self.rhs);
        let budget = self.settings.factor_reuse_iterations;
        if budget > 0 {
            let outcome = direct.solve_with_kept_factor(
                &self.pattern,
                &self.values,
                &mut self.dx,
                KEPT_FACTOR_RTOL,
                budget,
            );
            report.kept_factor_iterations += outcome.iterations;
            match outcome.status {
                KeptFactorStatus::Converged => {
                    report.kept_factor_solves += 1;
                    return true;
                }
                KeptFactorStatus::NonPositiveCurvature if !shifted => return false,
                _ => {}
            }
        }
        if shifted {
            let outcome = direct.solve(&self.pattern, &self.values, &mut self.dx);
            report.factorizations += 1 + outcome.shifts;
            report.shifted_factorizations += outcome.shifts;
            if outcome.failed {
                report.direct_failures += 1;
            }
            !outcome.failed
        } else {
            report.factorizations += 1;
            direct.solve_unshifted(&self.pattern, &self.values, &mut self.dx)
        }
    }

    /// The Newton direction by PCG from zero, solving the assembled matrix against the
    /// right-hand side to the relative residual `rtol`, into `dx`.
    fn pcg_direction(&mut self, rtol: f64) -> PcgOutcome {
        self.dx.fill(0.0);
        self.pcg.solve(
            &self.pattern,
            &self.values,
            &self.rhs,
            &mut self.dx,
            rtol,
            self.settings.pcg_max_iterations,
        )
    }

    /// Writes `grad g` at `self.x` over the free unknowns into `self.grad` and its
    /// negative into `self.rhs`, and returns `(residual, |grad g|_2^2, blocks ready)`,
    /// the residual the largest entry of `grad g` with each particle's scaled by
    /// `m_min / m_p` ([`BackwardEuler::mass_scales`]): with `blocks`, the springs'
    /// Hessian blocks in that form may be computed in the same pass (the third value says
    /// whether they were, for [`Self::assemble_hessian_with`]).
    ///
    /// One pass for the four: these run on one thread between the parallel regions, so
    /// on two threads each pass over the unknowns is time the other thread waits. The
    /// maximum and the sum are taken in the order of the unknowns, from the starting
    /// values of the separate passes they replace, so they are the same bits.
    fn assemble_gradient(
        &mut self,
        step: &StepContext<'_>,
        blocks: Option<Curvature>,
    ) -> (f64, f64, bool) {
        let blocks_ready = match self.gradient_on_pool(step, blocks) {
            Some(ready) => ready,
            None => {
                self.potential
                    .gradient(step, &self.x, &mut self.grad_particles);
                false
            }
        };
        let mut max = 0.0f64;
        let mut sum: f64 = std::iter::empty::<f64>().sum();
        for (((grad, rhs), &p), &scale) in self
            .grad
            .chunks_exact_mut(3)
            .zip(self.rhs.chunks_exact_mut(3))
            .zip(&self.pattern.free_particles)
            .zip(&self.mass_scales)
        {
            let g = self.grad_particles[p];
            for (c, v) in [g.x, g.y, g.z].into_iter().enumerate() {
                grad[c] = v;
                rhs[c] = -v;
                // `f64::max` drops a NaN: a gradient of NaNs read as a residual of zero,
                // a false convergence (a friction threshold whose square underflowed).
                let a = v.abs() * scale;
                if a > max || a.is_nan() {
                    max = a;
                }
                sum += v * v;
            }
        }
        (max, sum, blocks_ready)
    }

    /// Writes the Newton matrix at `self.x` in the form `curvature` asks for into
    /// `self.values`.
    fn assemble_hessian(&mut self, step: &StepContext<'_>, curvature: Curvature) {
        self.assemble_hessian_with(step, curvature, false);
    }

    /// [`Self::assemble_hessian`], told whether the springs' blocks at `self.x` in the
    /// form `curvature` are already in the gather's buffer (`blocks_ready`, from
    /// [`Self::assemble_gradient`] at the same positions).
    fn assemble_hessian_with(
        &mut self,
        step: &StepContext<'_>,
        curvature: Curvature,
        blocks_ready: bool,
    ) {
        if !self.hessian_on_pool(step, curvature, blocks_ready) {
            self.values.fill(0.0);
            let mut sink = HessianSink::values(&self.pattern, &mut self.values);
            self.potential
                .add_hessian(step, &self.x, curvature, &mut sink);
        }
        self.transient.mark_used(&self.values);
    }
    /// With a thread pool (on systems above one PCG chunk), the gradient's per-spring
    /// part runs as a pass over the springs and a gather per particle
    /// (`potential::parallel`), bitwise equal to the sequential scatter; with `blocks`
    /// the pass over the springs also writes their Hessian blocks for the gather of the
    /// Newton matrix (on one thread, the scatter does). Returns whether the blocks were
    /// written, `None` when nothing was done (one thread without blocks: the caller's
    /// scatter).
    #[cfg(feature = "parallel")]
    fn gradient_on_pool(
        &mut self,
        step: &StepContext<'_>,
        blocks: Option<Curvature>,
    ) -> Option<bool> {
        // A system of one chunk on the calling thread (too small for the pool).
        let pool = self
            .pcg
            .is_chunked()
            .then(|| self.pcg.pool().cloned())
            .flatten();
        // On one thread without blocks to compute, the sequential scatter below.
        if pool.is_none() && blocks.is_none() {
            return None;
        }
        let mut gather = self.gather_for(step);
        let (potential, x, out) = (&self.potential, &self.x, &mut self.grad_particles);
        let ready = match pool {
            Some(pool) => pool.install(|| gather.gradient(potential, step, x, out, true, blocks)),
            None => gather.gradient(potential, step, x, out, false, blocks),
        };
        self.gather = Some(gather);
        Some(ready)
    }

    #[cfg(not(feature = "parallel"))]
    fn gradient_on_pool(
        &mut self,
        _step: &StepContext<'_>,
        _blocks: Option<Curvature>,
    ) -> Option<bool> {
        None
    }

    /// The Newton matrix's values by the springs' gather, as [`Self::gradient_on_pool`].
    /// On one thread this saves the scatter's pass zeroing every stored value (602 886
    /// on W6) and its reads of nine value slots per spring. Systems of one PCG chunk
    /// gain from the gather too (the ground contact workload's 1 024 particles: 3.8% of
    /// its instructions, though its contact term still has the values zeroed), so every
    /// system takes it (one chunk on the calling thread).
    #[cfg(feature = "parallel")]
    fn hessian_on_pool(
        &mut self,
        step: &StepContext<'_>,
        curvature: Curvature,
        blocks_ready: bool,
    ) -> bool {
        let pool = self
            .pcg
            .is_chunked()
            .then(|| self.pcg.pool().cloned())
            .flatten();
        let mut gather = self.gather_for(step);
        let (potential, x, pattern, values) = (
            &mut self.potential,
            &self.x,
            &self.pattern,
            &mut self.values,
        );
        match pool {
            Some(pool) => pool.install(|| {
                gather.hessian(
                    potential,
                    step,
                    x,
                    curvature,
                    pattern,
                    values,
                    true,
                    blocks_ready,
                );
            }),
            None => gather.hessian(
                potential,
                step,
                x,
                curvature,
                pattern,
                values,
                false,
                blocks_ready,
            ),
        }
        self.gather = Some(gather);
        true
    }

    #[cfg(not(feature = "parallel"))]
    fn hessian_on_pool(
        &mut self,
        _step: &StepContext<'_>,
        _curvature: Curvature,
        _blocks_ready: bool,
    ) -> bool {
        false
    }

    /// The gather index (taken out of `self` while it is used), built on first use.
    #[cfg(feature = "parallel")]
    fn gather_for(&mut self, step: &StepContext<'_>) -> crate::potential::SpringGather {
        match self.gather.take() {
            Some(g) if g.fits(step.system) => g,
            _ => crate::potential::SpringGather::new(step.system),
        }
    }

    /// The line search along `dx_particles`, on the thread pool when there is one.
    fn line_search(
        &mut self,
        step: &StepContext<'_>,
        slope: f64,
        expand: bool,
    ) -> line_search::Outcome {
        let (potential, x, dx, settings, partials) = (
            &self.potential,
            &self.x,
            &self.dx_particles,
            &self.settings,
            &mut self.change_partials,
        );
        #[cfg(feature = "parallel")]
        if let Some(pool) = self.pcg.pool() {
            return pool.install(|| {
                line_search::search(
                    potential, step, x, dx, slope, settings, expand, true, partials,
                )
            });
        }
        line_search::search(
            potential, step, x, dx, slope, settings, expand, false, partials,
        )
    }
}
