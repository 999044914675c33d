//! The settings of the Newton solve and of its first guess, with their validation.

use crate::linear::{FactorStructure, LinearSolverChoice};
use crate::model::SettingsError;

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
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct NewtonSettings {
    /// Stop when every free particle's entries of `grad g` are at most
    /// `tolerance * m_p / h^2`, `m_p` its mass (default 1e-9). `grad g` is a force and
    /// `m/h^2` turns a displacement into one, so this bounds roughly the position error
    /// of the solve in scene units, alike for every particle. The first guess alone never passes
    /// (at least one Newton iteration runs unless its residual is at round-off), so the
    /// error from the exact step shrinks with this tolerance.
    pub tolerance: f64,
    /// Newton iteration cap (default 50).
    pub max_iterations: usize,
    /// The linear solver (default: chosen per step by a cost model from counts).
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
    /// Largest relative residual asked of PCG in a Newton iteration (default 1e-3; the
    /// forcing term is `min(this, |grad g| / |grad g_first|)`). Looser terms (1e-2 up to
    /// 0.9, as the Eisenstat-Walker rules start from) cost more Newton iterations than
    /// they save PCG iterations on the lab cloths and W6, measured in
    /// docs/spring-sim.md ("Inexact Newton").
    pub pcg_forcing: f64,
    /// On the direct solve, the conjugate-gradient iterations a Newton iteration may
    /// spend preconditioned by the last numeric factor before it factors its own matrix
    /// (default 0: off, a new factorization every Newton iteration; on the rotating-sphere
    /// workload 8 cost more than it saved). The factor is kept within a step only; see
    /// docs/spring-sim.md ("Linear solvers").
    pub factor_reuse_iterations: usize,
    /// With `Auto`, how many steps may pass on the direct solve before PCG runs a step
    /// again to observe its iteration count (default 64).
    pub reprobe_interval: usize,
    /// Record `g` at every iterate (costs one energy pass per iteration; for tests).
    pub record_objective: bool,
    /// Threads for the PCG work, the springs' part of the assembly, the line search and
    /// the direct solver's factorization (two subtrees of its elimination tree side by
    /// side, then the separators above them by panels) of systems above 6 144 unknowns
    /// (2 048 free particles), and for the line search, the terms' passes and the passes
    /// over the particles of smaller systems whose self-contact pairs, not their
    /// particles, are most of a step's work (more than 512 pairs within reach at the last
    /// step: sheets lying on each other, a small cloth on a finely meshed obstacle)
    /// (default 0: one per core; 1: the calling thread only). The results are bitwise
    /// the same for every value (fixed chunks, sums in chunk order, a factorization
    /// plan fixed by the matrix's structure); without the `parallel` feature it is
    /// ignored.
    pub threads: usize,
    /// How many times a step may be halved when its solve does not converge (default
    /// 6: pieces down to `h/64`; 0 turns splitting off).
    ///
    /// The rule: when the Newton solve of a step stops at the iteration cap or in a
    /// stalled line search with `|grad g|_inf` above both the tolerance and the round-off
    /// floor `16 eps |x|_max max_p (m_p/h^2 + sum of the stiffnesses at p)`, the step is
    /// redone from its start state as two steps of `h/2` (each of which may be split
    /// again, down to `h / 2^max_split_depth`). Each piece is an ordinary step of its
    /// own length, so a split step is bitwise the same as those smaller steps taken one
    /// by one. Within a split step, a piece more than one level coarser than the last
    /// piece kept is split at once without a solve of its own length (that solve would
    /// almost surely fail again, at the price of a whole iteration cap); the whole step
    /// is always tried first. Backward Euler checks its energy inequality for the whole
    /// step: when the pieces together break it, they are discarded and the whole step's
    /// solve is continued from its last iterate, one iteration cap at a time (at most 16
    /// more), which keeps the inequality at every iterate; if it is still far from
    /// converged then, it starts once more from the pieces' end positions (when `g`
    /// there is no higher than at the start state) and is continued the same way. A
    /// piece at the deepest split that stops at the cap far from converged is continued
    /// the same way; if it is still far from converged then, it is halved up to two
    /// more times (pieces down to
    /// `h / 2^(max_split_depth + 2)`, the last of them continued again before it is kept),
    /// so [`crate::StepReport::split_depth`] can exceed this setting by 2. A stiff sheet
    /// buckling from compression needs that: its pieces of `h / 2^6` can stay far from
    /// converged after 16 more caps while those of `h / 2^7` converge, because the inertia
    /// term `m / h^2` grows fourfold per halving against the springs' negative curvature.
    /// Only when splitting is on: with 0 the cap is the cap.
    /// [`crate::StepReport::pieces`] says how many pieces a step took and
    /// [`crate::StepReport::unconverged_pieces`] how many pieces at the deepest split
    /// still stopped far from converged (their stop is the step's `stop`). A step that
    /// converges at once is never split and costs nothing more. Implicit midpoint is
    /// split into midpoint steps; a BDF2 step into backward Euler steps (its own
    /// starting step), after which BDF2 restarts its history. Steps with kinematic colliders are
    /// split too: each piece is given its own start time, from which the contact term
    /// poses the colliders, and an abandoned solve's barrier stiffness is rewound. A
    /// solve whose end state leaves a particle passed by a kinematic collider (its
    /// straight path from the step's start goes through the collider as it moves) is
    /// split the same way, and the energy inequality is not checked when a collider's
    /// surface moves (it does work on the cloth); a pass left at the deepest split is
    /// counted in [`crate::StepReport::swept_passes`] (docs/contact.md, "A kinematic
    /// collider passing the cloth within a step").
    pub max_split_depth: usize,
    /// How many times a step lags friction (contact with colliders, and between the
    /// cloth's own primitives), at most [`MAX_FRICTION_LAGS`] (default 1). Friction is
    /// lagged at the step's start: its normal forces, normals and tangent bases, and the
    /// contacts it acts on, are those of `x_n`, so a contact that closes during the step
    /// carries no friction in it. With `k > 1`, a converged solve is followed by up to
    /// `k - 1` more rounds: the friction is lagged again at the solve's minimizer and the
    /// step minimized again from there (IPC's lagged iterations). A round ends the step
    /// when its minimizer already meets the tolerance with the new lag (no Newton
    /// iteration), when no term holds friction, or when its solve does not converge.
    /// Each round's minimization is a slice of its own in
    /// [`crate::BackwardEuler::step_objective_traces`]; [`crate::StepReport::friction_relags`]
    /// counts the rounds a step ran (docs/contact.md, "Lagging friction again").
    pub friction_lags: usize,
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
            pcg_forcing: 1e-3,
            factor_reuse_iterations: 0,
            reprobe_interval: 64,
            record_objective: false,
            threads: 0,
            max_split_depth: 6,
            friction_lags: 1,
        }
    }
}

impl NewtonSettings {
    /// Checks the settings, naming the bad field.
    pub fn validate(&self) -> Result<(), SettingsError> {
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return Err(SettingsError::new(
                "NewtonSettings",
                "tolerance",
                "must be positive and finite",
            ));
        }
        if self.max_iterations == 0 {
            // No iteration cannot move the step; the split and continuation rules would
            // then spend their whole budget on pieces that do nothing (a fuzzed scene:
            // 0.8 s a step, the sheet frozen).
            return Err(SettingsError::new(
                "NewtonSettings",
                "max_iterations",
                "must be at least 1",
            ));
        }
        if !(self.pcg_forcing > 0.0 && self.pcg_forcing < 1.0) {
            return Err(SettingsError::new(
                "NewtonSettings",
                "pcg_forcing",
                "must be in (0, 1)",
            ));
        }
        if !(self.armijo > 0.0 && self.armijo < 0.5) {
            return Err(SettingsError::new(
                "NewtonSettings",
                "armijo",
                "must be in (0, 0.5)",
            ));
        }
        if self.max_split_depth > MAX_SPLIT_DEPTH {
            return Err(SettingsError::new(
                "NewtonSettings",
                "max_split_depth",
                "must be at most 20 (pieces of h / 2^20)",
            ));
        }
        if !(1..=MAX_FRICTION_LAGS).contains(&self.friction_lags) {
            return Err(SettingsError::new(
                "NewtonSettings",
                "friction_lags",
                "must be between 1 (friction lagged at the step's start only) and 16",
            ));
        }
        Ok(())
    }
}

/// The largest [`NewtonSettings::friction_lags`] accepted: each round is a minimization,
/// and IPC's examples converge their lagged friction in a few.
pub const MAX_FRICTION_LAGS: usize = 16;

/// The largest [`NewtonSettings::max_split_depth`] accepted: a million pieces per step
/// is already far past any use.
pub(crate) const MAX_SPLIT_DEPTH: usize = 20;
