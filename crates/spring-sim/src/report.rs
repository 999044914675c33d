//! What a step reports: the integrator, the solve (iterations, residual, backtracks, why
//! it stopped, the linear solver and its fallbacks) and the energies before and after.
//!
//! One report type serves every integrator, so a scene runner prints the same metrics
//! whatever integrator the scene chose; fields that do not apply stay at zero or `None`.

use crate::linear::LinearSolverKind;
use crate::model::Energies;

/// Which integrator made a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum IntegratorKind {
    /// Backward Euler by Newton (this crate's implicit integrator).
    BackwardEuler,
    /// Explicit symplectic Euler with substeps (the course's starter code).
    SymplecticEuler,
    /// The lab report's flawed Newton variant, for comparison only.
    FlawedReportMethod,
    /// BDF2 by Newton (second order, damps far less than backward Euler).
    Bdf2,
    /// Implicit midpoint by Newton (second order, conserves the energy of linear springs).
    ImplicitMidpoint,
    /// Explicit velocity Verlet with substeps.
    VelocityVerlet,
}

/// Why `auto` chose the integrator of a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum AutoReason {
    /// The settings ask to settle (numerical damping wanted): backward Euler.
    Settle,
    /// Velocity Verlet at the substep count from the stability bound costs no more than
    /// an implicit step (by the count model, or measured with
    /// `AutoSettings::tune_by_timing`; `StepReport::auto_costs` has the figures).
    ExplicitCheapest,
    /// The substeps the stability bound asks for cost more than an implicit step: BDF2.
    ImplicitCheaper,
    /// The bound asks for more substeps than `AutoSettings::max_substeps`: BDF2.
    SubstepCap,
    /// The simulation has contact with colliders or self-contact: BDF2, whose barriers
    /// keep every particle outside every collider and the cloth's triangles apart (the
    /// explicit integrators' projection is not guaranteed, and has nothing for
    /// self-contact).
    Contact,
    /// Velocity Verlet was tried at the bound's substep count and its energy rose by more
    /// than half the energy scale in one step (the bound, taken at the step's start, no
    /// longer held as springs shortened within the step): the step was redone from its
    /// start by backward Euler (first order and damping, but a descent on the step's
    /// incremental potential that Newton solves in a few iterations from such a state,
    /// with an energy inequality that BDF2's steps after its first lack).
    ExplicitUnstable,
}

impl AutoReason {
    /// A short lower-case name for tables and metrics; the reason in a sentence is its
    /// `Display`.
    ///
    /// ```
    /// use sinew_spring_sim::AutoReason;
    /// assert_eq!(AutoReason::SubstepCap.name(), "substep_cap");
    /// assert_eq!(
    ///     AutoReason::SubstepCap.to_string(),
    ///     "the stability bound needs more substeps than allowed: BDF2"
    /// );
    /// ```
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Settle => "settle",
            Self::ExplicitCheapest => "explicit_cheapest",
            Self::ImplicitCheaper => "implicit_cheaper",
            Self::SubstepCap => "substep_cap",
            Self::Contact => "contact",
            Self::ExplicitUnstable => "explicit_unstable",
        }
    }
}

impl std::fmt::Display for AutoReason {
    /// The reason in a sentence, for reports.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Settle => "settling asked for: backward Euler damps to rest",
            Self::ExplicitCheapest => {
                "velocity Verlet at the stability-bound substep count is the cheapest stable choice"
            }
            Self::ImplicitCheaper => {
                "the substeps the stability bound needs cost more than an implicit step: BDF2"
            }
            Self::SubstepCap => "the stability bound needs more substeps than allowed: BDF2",
            Self::Contact => {
                "contact with colliders: BDF2, whose barrier keeps every particle outside (the explicit projection is not guaranteed)"
            }
            Self::ExplicitUnstable => {
                "velocity Verlet's energy rose by more than half the energy scale in one step: redone by backward Euler"
            }
        })
    }
}

impl IntegratorKind {
    /// A short name for reports and scene files.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::BackwardEuler => "backward_euler",
            Self::SymplecticEuler => "symplectic_euler",
            Self::FlawedReportMethod => "flawed_report_method",
            Self::Bdf2 => "bdf2",
            Self::ImplicitMidpoint => "implicit_midpoint",
            Self::VelocityVerlet => "velocity_verlet",
        }
    }
}

/// Why a step's solve stopped. (The IK solvers' reason is a different type,
/// `sinew_skeleton::ik::StopReason`.)
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum StepStop {
    /// The residual reached the tolerance.
    Converged,
    /// The iteration cap was reached first.
    IterationCap,
    /// The residual is at the rounding of its evaluation, at most `eps |x|_max` times
    /// the largest row sum of inertia, springs and damping, each scaled as the residual
    /// is, `max_p m_min/m_p (m_p/h^2 + sum over the springs at p of (k_s + c/h))` (a
    /// sixteenth of the round-off floor that decides a split), and the last iteration did
    /// not halve it: the tolerance lies below what the arithmetic can resolve at this
    /// state (a tight tolerance with stiff springs or strong damping, or a very long
    /// step), and the iterate is as converged as it can be.
    RoundOff,
    /// The line search could not decrease `g` (the iterate is at round-off level of a
    /// minimum, or the direction was useless); the last accepted iterate is kept.
    LineSearchStalled,
    /// A fixed number of iterations or substeps, no convergence test (explicit
    /// integrators and the flawed reference).
    FixedWork,
    /// A non-finite value appeared in a solve's gradient. Never the stop of a step
    /// returned `Ok`: a solve that stops so is refused ([`StepError::NonFinite`]).
    NonFinite,
    /// The line search found the potential infinite (or NaN) at every step length it
    /// tried along the Newton direction, down to `2^-max_backtracks` of it: the forces
    /// are beyond what `f64` can hold over this step (a gravity of 1e300, say). A whole
    /// step that stops so is refused ([`StepError::Overflow`]); splitting it could not
    /// help, since the line search already tried shorter moves than any split makes.
    Overflow,
}

/// The report of one step.
///
/// Read-only for users: the integrators fill it, and it gains fields as they learn to
/// report more (the contact counters did), so it is `#[non_exhaustive]`: a literal or an
/// exhaustive pattern outside this crate would break on each new field (patterns need
/// `..`).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[non_exhaustive]
pub struct StepReport {
    /// The integrator.
    pub integrator: IntegratorKind,
    /// Newton (or fixed) iterations.
    pub iterations: usize,
    /// The final residual (a force): the largest entry of `grad g`, each particle's
    /// scaled by `m_min / m_p` (`m_min` the smallest free mass), so that the tolerance
    /// holds every particle to about the same position error; `|grad g|_inf` itself when
    /// the free masses are equal. 0 for explicit integrators.
    pub residual: f64,
    /// The absolute tolerance `tol * m_min / h^2` the residual was held to.
    pub tolerance: f64,
    /// Implicit steps: the effective step `h` of the solve whose `residual` and
    /// `tolerance` are reported, the one whose inertia `m / h^2` the Newton matrix holds:
    /// the length of the step (or of its piece, for a split step) for backward Euler,
    /// two thirds of it for BDF2 (whose starting step and pieces are backward Euler
    /// steps), half of it for the implicit midpoint. 0 for the explicit integrators.
    #[cfg_attr(feature = "serde", serde(default))]
    pub effective_step: f64,
    /// Step halvings in the line searches.
    pub backtracks: usize,
    /// Why the solve stopped.
    pub stop: StepStop,
    /// The linear solver used for this step.
    pub linear_solver: Option<LinearSolverKind>,
    /// Total PCG iterations (also counts PCG used as a fallback).
    pub linear_iterations: usize,
    /// Factorizations retried on a shifted matrix.
    pub shifted_factorizations: usize,
    /// Numeric Cholesky factorizations of the direct solver, the failed and the shifted
    /// ones included.
    #[cfg_attr(feature = "serde", serde(default))]
    pub factorizations: usize,
    /// Newton iterations of the direct solver whose system was solved by conjugate
    /// gradients preconditioned with the last factor, without a factorization of their
    /// own (`NewtonSettings::factor_reuse_iterations`).
    #[cfg_attr(feature = "serde", serde(default))]
    pub kept_factor_solves: usize,
    /// Conjugate-gradient iterations preconditioned with the last factor (each a product
    /// with the matrix and a pair of triangular solves), those of attempts that ran out
    /// of their budget and ended in a factorization included; not in
    /// `linear_iterations`.
    #[cfg_attr(feature = "serde", serde(default))]
    pub kept_factor_iterations: usize,
    /// Iterations where every factorization failed and PCG solved instead.
    pub direct_failures: usize,
    /// Iterations where the solve gave no descent direction and the mass-scaled
    /// gradient was used.
    pub descent_fallbacks: usize,
    /// Newton iterations that used the exact or softened Hessian (part of the compressed
    /// springs' negative curvature kept; `spring::Curvature::Softened`) because it was
    /// positive definite and the projected one was converging slowly.
    pub exact_hessian_iterations: usize,
    /// Newton matrices with the contact pairs' exact Hessians that were refused (not
    /// positive definite) and replaced at once by the same matrix with the pairs'
    /// projections (`spring::Curvature::ExactContact`; 0 without self-contact).
    #[cfg_attr(feature = "serde", serde(default))]
    pub contact_projection_fallbacks: usize,
    /// Explicit substeps (1 for implicit steps).
    pub substeps: usize,
    /// Energies at the start of the step.
    pub energy_before: Energies,
    /// Energies at the end of the step.
    pub energy_after: Energies,
    /// With `auto`: why this step's integrator was chosen (`None` otherwise).
    pub auto_reason: Option<AutoReason>,
    /// With `auto`: the costs the choice compared (`None` otherwise, and when no
    /// comparison was made: settling, the substep cap, a timing probe).
    pub auto_costs: Option<crate::integrator::AutoCosts>,
    /// The estimated largest effective frequency `omega_eff` (rad/s) of the stability
    /// bound, when it was computed for this step (explicit bounded integrators and `auto`;
    /// 0 otherwise).
    pub omega_max: f64,
    /// The substep count the stability bound asks for at this step (0 when not computed).
    pub stable_substeps: usize,
    /// Implicit steps: the pieces the step was taken in (1 when it was not split; see
    /// `NewtonSettings::max_split_depth`). A split step is that many ordinary steps of
    /// the lengths `h / 2^d` they were split to, taken one after the other; `iterations`
    /// and the other counts include the abandoned attempts, and `residual`, `tolerance`
    /// and `stop` are those of the piece with the largest `residual / tolerance`.
    pub pieces: usize,
    /// How many times the shortest piece was halved (0 when not split); up to
    /// `NewtonSettings::max_split_depth + 2`, the two extra levels taken only by pieces
    /// still far from converged at the settings' depth after their continued solve.
    pub split_depth: usize,
    /// Pieces kept although they stopped far from converged (their residual above both
    /// the tolerance and the round-off floor), because the split was at its deepest
    /// level (two below `NewtonSettings::max_split_depth`) or splitting is off (then the whole step counts as one piece): 0 when
    /// every piece converged or stopped at round-off. The step's `stop` then says why the
    /// worst one stopped (the iteration cap or a stalled line search).
    pub unconverged_pieces: usize,
    /// Pieces kept although a particle's straight path from the piece's start to its
    /// end went through a moving collider (deeper than
    /// [`crate::contact::swept_allowance`]), because the split was at its deepest level
    /// or splitting is off: 0 when no collider passed a particle. Such a step is split
    /// like one far from converged (docs/contact.md, "A kinematic collider passing the
    /// cloth within a step").
    pub swept_passes: usize,
    /// Backward Euler: splits computed and then discarded because the pieces together
    /// broke the energy inequality a step of `h` keeps (`E_spring + E_gravity +
    /// 1/2 |v' - v_n|_M^2 <= E_total` at the start); the abandoned unsplit solve is
    /// then continued from its iterate (and, if still far from converged, from the
    /// pieces' end positions) and is the step, counted in `unconverged_pieces` only if
    /// it is still far from converged.
    pub rejected_splits: usize,
    /// Particle pairs given Hessian slots during or after this step because a term
    /// (self-contact) coupled them without one; the Newton matrices from the next
    /// iteration on have their full blocks.
    pub pattern_pairs_added: usize,
    /// Particle pairs whose Hessian slots were dropped at the start of this step (or of
    /// one of its pieces) because their blocks had stayed zero for several steps (pairs
    /// in contact earlier that have separated); a pair that comes back is added again.
    pub pattern_pairs_dropped: usize,
    /// Rounds in which friction was lagged again at a solve's minimizer and the step
    /// minimized again (`NewtonSettings::friction_lags`; 0 with the default of one lag
    /// per step); their Newton iterations are in `iterations`.
    pub friction_relags: usize,
    /// Of those rounds, the ones that started again from the step's start `x_n` instead
    /// of the last round's minimizer, because backward Euler's `g` with the new lag was
    /// higher at the minimizer than at `x_n` (docs/contact.md).
    pub friction_restarts: usize,
}

impl StepReport {
    /// Adds the work counters of `part` (iterations, backtracks, linear iterations,
    /// factorizations, fallbacks and the Hessian slots it added, which stay in the
    /// pattern whether or not `part`'s solve was kept).
    pub(crate) fn add_work(&mut self, part: &StepReport) {
        self.iterations += part.iterations;
        self.backtracks += part.backtracks;
        self.linear_iterations += part.linear_iterations;
        self.shifted_factorizations += part.shifted_factorizations;
        self.factorizations += part.factorizations;
        self.kept_factor_solves += part.kept_factor_solves;
        self.kept_factor_iterations += part.kept_factor_iterations;
        self.direct_failures += part.direct_failures;
        self.descent_fallbacks += part.descent_fallbacks;
        self.exact_hessian_iterations += part.exact_hessian_iterations;
        self.contact_projection_fallbacks += part.contact_projection_fallbacks;
        self.pattern_pairs_added += part.pattern_pairs_added;
        self.pattern_pairs_dropped += part.pattern_pairs_dropped;
        self.friction_relags += part.friction_relags;
        self.friction_restarts += part.friction_restarts;
    }

    /// An empty report for `integrator`.
    #[must_use]
    pub fn new(integrator: IntegratorKind) -> Self {
        Self {
            integrator,
            iterations: 0,
            residual: 0.0,
            tolerance: 0.0,
            effective_step: 0.0,
            backtracks: 0,
            stop: StepStop::FixedWork,
            linear_solver: None,
            linear_iterations: 0,
            shifted_factorizations: 0,
            factorizations: 0,
            kept_factor_solves: 0,
            kept_factor_iterations: 0,
            direct_failures: 0,
            descent_fallbacks: 0,
            exact_hessian_iterations: 0,
            contact_projection_fallbacks: 0,
            substeps: 1,
            energy_before: Energies::default(),
            energy_after: Energies::default(),
            auto_reason: None,
            auto_costs: None,
            omega_max: 0.0,
            stable_substeps: 0,
            pieces: 1,
            split_depth: 0,
            unconverged_pieces: 0,
            swept_passes: 0,
            rejected_splits: 0,
            pattern_pairs_added: 0,
            pattern_pairs_dropped: 0,
            friction_relags: 0,
            friction_restarts: 0,
        }
    }

    /// Fallback events of any kind in this step (shifted factorizations, failed
    /// factorizations, descent fallbacks).
    #[must_use]
    pub fn fallback_events(&self) -> usize {
        self.shifted_factorizations + self.direct_failures + self.descent_fallbacks
    }
}

/// Why a step could not be taken. The system is left as it was before the step.
#[derive(Clone, Debug, PartialEq)]
pub enum StepError {
    /// Invalid input (time step, topology), naming the item.
    Invalid(crate::model::ModelError),
    /// A linear solver needed by the step could not be set up (the direct solver is
    /// built at the first step that chooses it); the cause is this error's `source`.
    Solver(crate::linear::SolverError),
    /// A non-finite value appeared (an explicit integrator above its stability limit,
    /// the flawed reference method, or an implicit solve whose gradient became NaN or
    /// infinite); names the first particle affected. The step's solve is not kept; in a
    /// step split into pieces, the pieces before the failing one stay written (the
    /// stepper's time is not advanced).
    NonFinite {
        /// The integrator.
        integrator: IntegratorKind,
        /// The first particle with a non-finite position or velocity.
        particle: usize,
    },
    /// An explicit integrator was given fewer substeps than its stability bound asks for
    /// at this step; the step was refused (not taken).
    BelowStabilityBound {
        /// The integrator.
        integrator: IntegratorKind,
        /// The substeps given.
        substeps: usize,
        /// The substeps needed: the predicted stability limit `ceil(h omega_max / 2)`.
        needed: usize,
        /// The count the bound recommends (with its safety factor), what `substeps: None`
        /// uses.
        recommended: usize,
        /// The estimated largest effective frequency `omega_eff`, rad/s.
        omega_max: f64,
        /// The step.
        dt: f64,
    },
    /// The incremental potential was infinite (or NaN) at every step length the line
    /// search tried along the step's first Newton direction ([`StepStop::Overflow`]):
    /// forces or a step beyond the range of `f64` (a gravity of 1e300 makes the inertia
    /// of a fall of `g h^2` overflow). The step was refused (not taken).
    Overflow {
        /// The integrator.
        integrator: IntegratorKind,
        /// The step's Newton iterations before the one whose line search found no finite
        /// value.
        iterations: usize,
    },
    /// The prescribed move of the pinned particles (the free ones held) would bring two
    /// parts of the cloth within a tenth of their gap of crossing even when the step is
    /// cut into `pieces` equal pieces of the motion; the step was refused.
    PinnedMove {
        /// The pinned particle that moves farthest over the first piece that could not
        /// be made safe.
        particle: usize,
        /// The pieces the step was cut into at most.
        pieces: usize,
        /// The fraction of that piece's move that is safe.
        safe_fraction: f64,
    },
    /// A particle cannot start a step outside every collider posed at the step's end
    /// time: kinematic colliders closed in on it from two sides within one step and
    /// leave no room (a particle one collider runs over is carried along with it, then
    /// pushed out of each collider in turn, and was still inside `collider`). The step
    /// was refused.
    Contact {
        /// The particle.
        particle: usize,
        /// The collider's index.
        collider: usize,
    },
    /// A free particle is inside or on a collider at the step's start (the state was
    /// set there through `Simulation::system_mut`, or by hand for a stepper given a
    /// contact term by hand; `Simulation::set_contact` refuses such a start with
    /// `ContactError::StartsInside`). The step was refused.
    StartsInside {
        /// The particle.
        particle: usize,
        /// The collider's index.
        collider: usize,
        /// Its distance to the collider's surface, less the thickness (`<= 0`).
        distance: f64,
    },
    /// A kinematic collider posed at the step's start time has a coordinate that is not
    /// finite or beyond [`crate::contact::MAX_COLLIDER_MAGNITUDE`] (it has run that far,
    /// or the stepper's time was set to a value that is not finite or far off). The step
    /// was refused.
    ColliderOutOfRange {
        /// The collider's index.
        collider: usize,
        /// The step's start time.
        time: f64,
    },
    /// Two primitives of a self-contact mesh (a vertex and a triangle, or two edges)
    /// are within the thickness of each other at the step's start (the state was set
    /// by hand, through `SpringSystem::set_state` or `Simulation::system_mut`; an
    /// accepted state never is, and the self-contact term refuses such a state when it
    /// is built). The step was refused.
    SelfContactStart {
        /// The pair, as "vertex 12 and triangle 40" or "edge [3, 4] and edge [17, 18]".
        pair: String,
        /// Its distance less the thickness (`<= 0`, or NaN for a degenerate pair).
        gap: f64,
    },
    /// An edge of a self-contact mesh passes through a triangle it shares no vertex
    /// with at the step's start, or within rounding of it (a state set by hand, as for
    /// [`Self::SelfContactStart`]; the self-contact term refuses such a state when it is
    /// built). The step was refused.
    SelfContactCrossing {
        /// The pair, as "edge [3, 4] and triangle 40 [7, 8, 9]".
        pair: String,
    },
}

impl std::fmt::Display for StepError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Invalid(e) => write!(f, "{e}"),
            Self::Solver(e) => write!(f, "{e}"),
            Self::NonFinite {
                integrator,
                particle,
            } => write!(
                f,
                "{}: particle {particle} became non-finite (its position, velocity or force); \
                 the step's solve was not kept",
                integrator.name()
            ),
            Self::Overflow {
                integrator,
                iterations,
            } => write!(
                f,
                "{}: the incremental potential is not finite at any step length the line search tried (after {iterations} Newton iterations): forces or a step beyond the range of f64 (gravity, stiffness or step length); the step was refused",
                integrator.name()
            ),
            Self::PinnedMove {
                particle,
                pieces,
                safe_fraction,
            } => write!(
                f,
                "the prescribed move of the pinned particles (pinned particle {particle} moves farthest) would make the cloth cross itself even with the step cut into {pieces} pieces (only {safe_fraction:.3} of a piece's move is safe); the step was refused"
            ),
            Self::Contact { particle, collider } => write!(
                f,
                "particle {particle} cannot be placed outside every collider at the step's end time: carried along by the moving colliders and pushed out of each in turn, it is still inside collider {collider} (the colliders close in on it within one step and leave no room); the step was refused"
            ),
            Self::StartsInside {
                particle,
                collider,
                distance,
            } => write!(
                f,
                "particle {particle} is inside collider {collider} at the step's start (its \
                 distance to the surface, less the thickness, is {distance:e}); the step was \
                 refused"
            ),
            Self::ColliderOutOfRange { collider, time } => write!(
                f,
                "collider {collider} posed at the step's start time {time:e} is not finite or \
                 beyond 1e50 in magnitude (MAX_COLLIDER_MAGNITUDE); the step was refused"
            ),
            Self::SelfContactCrossing { pair } => write!(
                f,
                "self-contact: {pair} pass through each other at the step's start: a \
                 self-contact step needs a start in which the mesh does not cross itself; \
                 the step was refused"
            ),
            Self::SelfContactStart { pair, gap } => write!(
                f,
                "self-contact: {pair} are within the thickness of each other at the step's \
                 start (their distance less the thickness is {gap:e}): a self-contact step \
                 needs every pair apart at its start; the step was refused"
            ),
            Self::BelowStabilityBound {
                integrator,
                substeps,
                needed,
                recommended,
                omega_max,
                dt,
            } => write!(
                f,
                "{}: {substeps} substeps per step of {dt} is above the stability bound (omega_max = {omega_max:.4e} rad/s); at least {needed} substeps are needed ({recommended} recommended), or use an implicit integrator; the step was refused",
                integrator.name()
            ),
        }
    }
}

impl std::error::Error for StepError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Invalid(e) => Some(e),
            Self::Solver(e) => Some(e),
            _ => None,
        }
    }
}

impl From<crate::model::ModelError> for StepError {
    /// A solver failure stays one ([`StepError::Solver`]); anything else is input the
    /// step refused.
    fn from(e: crate::model::ModelError) -> Self {
        match e {
            crate::model::ModelError::Solver(e) => Self::Solver(e),
            e => Self::Invalid(e),
        }
    }
}

impl From<crate::linear::SolverError> for StepError {
    fn from(e: crate::linear::SolverError) -> Self {
        Self::Solver(e)
    }
}

/// The end states of the pieces of the steps taken while recording is on
/// ([`crate::BackwardEuler::record_piece_ends`], [`crate::Simulation::record_piece_ends`]):
/// for each piece a step kept, in order, the time it ends at and every particle's
/// position then. A step taken whole adds one entry (its end state); a step split in
/// pieces (`StepReport::pieces`) adds one per piece, the last being the step's end state.
/// The straight path from one entry to the next (from the step's start state to the
/// first) is the path of a solve, the one the collider guarantees are made for, so an
/// independent check of those guarantees reads them here (docs/contact.md, "Checking
/// every piece").
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PieceEnds {
    times: Vec<f64>,
    positions: Vec<crate::DVec3>,
}

impl PieceEnds {
    /// The number of pieces recorded.
    #[must_use]
    pub fn len(&self) -> usize {
        self.times.len()
    }

    /// Whether no piece is recorded.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.times.is_empty()
    }

    /// Piece `k`'s end time and positions.
    #[must_use]
    pub fn get(&self, k: usize) -> Option<(f64, &[crate::DVec3])> {
        let t = *self.times.get(k)?;
        let n = self.positions.len() / self.times.len();
        Some((t, &self.positions[k * n..(k + 1) * n]))
    }

    /// The pieces in order: end time and positions.
    pub fn iter(&self) -> impl Iterator<Item = (f64, &[crate::DVec3])> + Clone {
        (0..self.len()).filter_map(|k| self.get(k))
    }

    /// Forgets every piece (the buffers are kept).
    pub fn clear(&mut self) {
        self.times.clear();
        self.positions.clear();
    }

    /// Appends a piece ending at `time` with `positions`.
    pub(crate) fn push(&mut self, time: f64, positions: &[crate::DVec3]) {
        self.times.push(time);
        self.positions.extend_from_slice(positions);
    }

    /// Appends `other`'s pieces.
    pub(crate) fn extend_from(&mut self, other: &PieceEnds) {
        self.times.extend_from_slice(&other.times);
        self.positions.extend_from_slice(&other.positions);
    }

    /// Keeps the first `len` pieces (a split whose pieces were discarded).
    pub(crate) fn truncate(&mut self, len: usize) {
        if len < self.times.len() {
            let n = self.positions.len() / self.times.len();
            self.times.truncate(len);
            self.positions.truncate(len * n);
        }
    }
}
