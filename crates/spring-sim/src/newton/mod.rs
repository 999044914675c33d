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
//! The summands of `g` are the terms of a [`Potential`] built once per integrator
//! ([`crate::potential`]); nothing here names a term. Each Newton iteration assembles the
//! terms' gradient and PSD-projected Hessian into the pattern built once
//! ([`HessianPattern`]) (once Newton is slow, a softened Hessian that
//! keeps part of the compressed springs' negative curvature, where it is positive
//! definite: [`Curvature::Softened`]), solves with the chosen linear solver, and
//! backtracks (Armijo) so `g` never increases. The objective changes in the line search
//! are computed from the differences themselves (see [`crate::spring::energy_change`]),
//! so the sufficient-decrease test stays meaningful when the change is far below `g`.
//! The code is split by concern: [`NewtonSettings`] (settings), the `Auto` solver choice
//! (solver_choice), the iteration (minimize) and the line search (line_search).
//! Stops when every free particle's entries of `grad g` are at most `tolerance * m_p / h^2`
//! (the residual, each particle's entries scaled by `m_min / m_p`, at most
//! `tolerance * m_min / h^2`)
//! after at least one Newton iteration (none only when the first guess is already at the
//! gradient's round-off floor), at the iteration cap, or when the line search cannot
//! decrease `g` any more.
//! The derivation and the rules are in docs/spring-sim.md.

mod couplings;
mod line_search;
mod minimize;
mod settings;
mod solver_choice;

pub use settings::{InitialGuess, MAX_FRICTION_LAGS, NewtonSettings};

use crate::contact::{Collider, ContactError, ContactTerm, Drive};
use crate::linear::{
    DirectSolver, LinearSolverChoice, LinearSolverKind, PcgOutcome, PcgSolver, SolverCosts,
};
use crate::model::{ModelError, SpringSystem, Topology, check_time_step};
use crate::pattern::{FIXED, HessianPattern};
use crate::potential::{HessianSink, Potential, StepContext, StepTiming, Term};
use crate::report::{IntegratorKind, PieceEnds, StepError, StepReport, StepStop};
use crate::spring::Curvature;
use couplings::TransientCouplings;
use sinew_math::DVec3;
use solver_choice::SolverChooser;
use std::sync::Arc;
#[cfg(feature = "parallel")]
use std::sync::{Mutex, PoisonError};

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

impl Scheme<'_> {
    /// The scheme of the pieces a split step of this scheme is taken in: the midpoint's
    /// are midpoint steps; BDF2's are backward Euler steps, its own starting step (a
    /// BDF2 step of `h/2` would need a history at spacing `h/2`, which a step of `h`
    /// does not have, and a split step is a hard one, where backward Euler's damping
    /// is wanted: docs/integrators.md, "BDF2").
    fn piece(self) -> Scheme<'static> {
        match self {
            Scheme::Midpoint => Scheme::Midpoint,
            Scheme::BackwardEuler | Scheme::Bdf2 { .. } => Scheme::BackwardEuler,
        }
    }
}

/// The backward Euler integrator: Newton on the incremental potential, with its
/// workspace (pattern, factorization, buffers) built once for a topology.
///
/// Backward Euler damps oscillations numerically (strongly at large steps), which is what
/// makes it the choice for settling:
///
/// ```
/// use sinew_spring_sim::{BackwardEuler, DVec3, Material, NewtonSettings, Particle, SpringSpec, SpringSystem};
/// // A unit mass on a vertical spring (stiffness 100, rest length 1) under Earth's gravity.
/// let particles = [
///     Particle { fixed: true, ..Particle::at_rest(DVec3::ZERO, 1.0) },
///     Particle::at_rest(DVec3::new(0.0, -1.0, 0.0), 1.0),
/// ];
/// let springs = [SpringSpec::between(0, 1)];
/// let material = Material::earth().undamped();
/// let mut system = SpringSystem::new(&particles, &springs, material).unwrap();
/// // At rest the spring carries the weight: stretched by m g / k.
/// let rest_y = -(1.0 + 9.81 / 100.0);
/// let mut stepper = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
/// for _ in 0..200 {
///     let report = stepper.step(&mut system, 0.1).unwrap();
///     assert!(report.residual <= report.tolerance);
/// }
/// assert!((system.positions()[1].y - rest_y).abs() < 1e-6);
/// assert_eq!(system.positions()[0], DVec3::ZERO); // fixed particles do not move
/// ```
#[derive(Debug)]
pub struct BackwardEuler {
    settings: NewtonSettings,
    pattern: Arc<HessianPattern>,
    direct: Option<DirectSolver>,
    /// The direct solver of a pattern widened within a step, being set up on the pool
    /// (`None` outside a minimization: it is always taken before one returns).
    #[cfg(feature = "parallel")]
    pending_direct: Option<PendingDirect>,
    pcg: PcgSolver,
    values: Vec<f64>,
    grad: Vec<f64>,
    dx: Vec<f64>,
    rhs: Vec<f64>,
    x: Vec<DVec3>,
    y: Vec<DVec3>,
    x_ref: Vec<DVec3>,
    /// The terms of `g`, assembled once.
    potential: Potential,
    /// `grad g` per particle (fixed ones included, then dropped).
    grad_particles: Vec<DVec3>,
    /// The Newton direction per particle (zero at fixed particles).
    dx_particles: Vec<DVec3>,
    prev_velocity: Vec<DVec3>,
    have_prev_velocity: bool,
    chooser: SolverChooser,
    /// The counts of the automatic solver choice, analysed the first time it needs them.
    costs: Option<SolverCosts>,
    objective_trace: Vec<f64>,
    /// Every minimization's trace in the last step, back to back, and where each starts.
    step_traces: Vec<f64>,
    step_trace_starts: Vec<usize>,
    /// The fingerprint of the system this workspace was built for, compared on each step.
    topology: Topology,
    /// Particle pairs coupled by terms other than the springs, in the pattern too.
    coupled_pairs: Vec<[usize; 2]>,
    /// Pairs coupled during the run by terms that reported them missing, in the pattern
    /// until they have been idle for a while (see [`couplings`]).
    transient: TransientCouplings,
    /// Per split depth, what a split step falls back on (allocated at the first split).
    split_saves: Vec<SplitSave>,
    /// The remaining split depth of the last piece the current step kept (the step's
    /// whole depth before it kept any).
    last_piece_depth: usize,
    /// The iterate a continued solve starts from (see `CONTINUED_CAPS`).
    continue_from: Vec<DVec3>,
    /// The end states of the pieces kept, while recording ([`Self::record_piece_ends`]).
    piece_ends: Option<PieceEnds>,
    /// Whether the current step is taken as several calls (a pinned move in pieces,
    /// [`Self::begin_joined_step`]): the step's records then span the calls.
    joined_step: bool,
    /// Row sums for the round-off floor ([`Self::gradient_floor`]).
    row_scratch: Vec<f64>,
    /// `m_min / m_p` for each free particle `p` (in the pattern's order), set at the
    /// start of each solve. The residual, the stopping test's measure, is the largest
    /// entry of `grad g` with each particle's scaled by it, so `residual <= tol m_min /
    /// h^2` holds each particle's force to `tol m_p / h^2`: a position error of about
    /// `tol` for every particle, however the masses differ (docs/spring-sim.md,
    /// "Newton, line search, stopping rule"). Equal masses give scales of exactly 1.
    mass_scales: Vec<f64>,
    /// The time the next step starts at (kinematic colliders are posed from it).
    time: f64,
    /// The current solve's times and unknowns, handed to the terms.
    timing: StepTiming,
    /// The chunks' sums of the line search's changes of `g`.
    change_partials: Vec<f64>,
    /// Per spring, its energy, for the report's energies.
    spring_energies: Vec<f64>,
    /// The springs' gather index for assembly on the thread pool, built the first time
    /// a step assembles with more than one thread.
    #[cfg(feature = "parallel")]
    gather: Option<crate::potential::SpringGather>,
}

impl BackwardEuler {
    /// A workspace for `system`'s topology.
    pub fn new(system: &SpringSystem, settings: NewtonSettings) -> Result<Self, ModelError> {
        settings.validate()?;
        let pattern = HessianPattern::new(system);
        let n = pattern.dim();
        let direct = if settings.linear_solver == LinearSolverChoice::Direct {
            Some(Self::build_direct(&pattern, &settings)?)
        } else {
            None
        };
        let pcg = Self::build_pcg(&pattern, settings.threads)?;
        Ok(Self {
            settings,
            pcg,
            values: vec![0.0; pattern.nnz()],
            grad: vec![0.0; n],
            dx: vec![0.0; n],
            rhs: vec![0.0; n],
            x: system.positions().to_vec(),
            y: system.positions().to_vec(),
            x_ref: system.positions().to_vec(),
            potential: Potential::mass_spring(system),
            grad_particles: vec![DVec3::ZERO; system.len()],
            dx_particles: vec![DVec3::ZERO; system.len()],
            prev_velocity: vec![DVec3::ZERO; system.len()],
            have_prev_velocity: false,
            chooser: SolverChooser::default(),
            costs: None,
            objective_trace: Vec::new(),
            step_traces: Vec::new(),
            step_trace_starts: Vec::new(),
            topology: system.topology(),
            coupled_pairs: Vec::new(),
            transient: TransientCouplings::default(),
            split_saves: Vec::new(),
            last_piece_depth: 0,
            continue_from: Vec::new(),
            piece_ends: None,
            joined_step: false,
            row_scratch: Vec::new(),
            mass_scales: Vec::new(),
            time: 0.0,
            timing: StepTiming {
                start: 0.0,
                length: 0.0,
                midpoint: false,
            },
            change_partials: Vec::new(),
            spring_energies: Vec::new(),
            #[cfg(feature = "parallel")]
            gather: None,
            #[cfg(feature = "parallel")]
            pending_direct: None,
            direct,
            pattern: Arc::new(pattern),
        })
    }

    /// PCG on `pattern` with a thread pool of its own. A widened pattern's solver keeps
    /// the threads the settings ask for by sharing its predecessor's pool (a rebuilt
    /// solver without them ran every later step of a term with coupled pairs on one
    /// thread).
    fn build_pcg(pattern: &HessianPattern, threads: usize) -> Result<PcgSolver, ModelError> {
        let mut pcg = PcgSolver::new(pattern);
        pcg.set_threads(threads)?;
        Ok(pcg)
    }

    fn build_direct(
        pattern: &HessianPattern,
        settings: &NewtonSettings,
    ) -> Result<DirectSolver, ModelError> {
        let mut direct = DirectSolver::new(pattern, settings.factor_structure)?;
        // A second factor's memory only where the kept factor is used.
        direct.set_keep_factor(settings.factor_reuse_iterations > 0);
        Ok(direct)
    }

    /// Takes the direct solver being set up in the background ([`Self::widen`]), waiting
    /// for it (or setting it up on this thread if no other thread has begun it); an
    /// `Err` when its set-up failed. Nothing to do without one.
    pub(super) fn settle_direct(&mut self) -> Result<(), ModelError> {
        #[cfg(feature = "parallel")]
        if let Some(pending) = self.pending_direct.take() {
            self.direct = Some(pending.wait()?);
        }
        Ok(())
    }

    /// The threads the step runs on (1: the calling thread, as for systems too small to
    /// split): PCG's work, the springs' part of the assembly, the line search, the
    /// terms' passes and the passes over the particles of systems above 6 144
    /// unknowns, and of smaller systems, all but PCG's and the springs' part, while a
    /// term wants them ([`crate::potential::Term::wants_threads`]: self-contact with
    /// many pairs at the last step).
    #[must_use]
    pub fn threads(&self) -> usize {
        self.pcg.threads()
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

    /// `g` at every iterate of the last minimization run, when `record_objective` is set:
    /// the last step's, or for a step split in pieces (`StepReport::pieces`), its last
    /// piece's (the `g` of that piece's own length).
    #[must_use]
    pub fn objective_trace(&self) -> &[f64] {
        &self.objective_trace
    }

    /// `g` at every iterate of every minimization the last step ran (a step with moving
    /// pins taken in pieces of the pinned motion is one step), in the order run,
    /// when `record_objective` is set, one slice per stretch of iterates over which the
    /// function stayed the same: a step taken whole has one per minimization; a split
    /// step also has its abandoned attempts (each stopped far from converged, or passed
    /// by a moving collider) and each piece's solve; a continued solve
    /// (`CONTINUED_CAPS`) is a minimization of its own, from the iterate the last one
    /// stopped at; and a minimization in which a term changed the function between two
    /// iterates (the contact barrier's stiffness doubled: `g` at the same iterate before
    /// and after the term's update differs) is cut there into two slices. So each slice
    /// may be checked for descent on its own. The record of `Self::objective_trace` is
    /// kept as it was (the last minimization's, uncut).
    pub fn step_objective_traces(&self) -> impl Iterator<Item = &[f64]> {
        let starts = &self.step_trace_starts;
        let all = &self.step_traces;
        (0..starts.len()).map(move |k| {
            let end = starts.get(k + 1).copied().unwrap_or(all.len());
            &all[starts[k]..end]
        })
    }

    /// Assembles the (PSD-projected) Newton matrix at the system's current positions into
    /// the workspace, with damping directions frozen there (a kernel for benchmarks).
    pub fn assemble_newton_matrix(&mut self, system: &SpringSystem, h: f64) {
        // The Hessian does not depend on the prediction: the positions stand in for it.
        let x = system.positions();
        let step = StepContext::new(system, h, x, x);
        self.potential.begin_step(&step);
        self.values.fill(0.0);
        let mut sink = HessianSink::values(&self.pattern, &mut self.values);
        self.potential
            .add_hessian(&step, x, Curvature::Clamped, &mut sink);
    }

    /// The terms of the incremental potential this integrator minimizes.
    #[must_use]
    pub fn potential(&self) -> &Potential {
        &self.potential
    }

    /// The first term of type `T` in the incremental potential, to change between steps
    /// ([`Potential::term_mut`]).
    pub fn term_mut<T: Term>(&mut self) -> Option<&mut T> {
        self.potential.term_mut::<T>()
    }

    /// Drives collider `index` of the contact term from the time the next step starts
    /// at ([`Self::time`]) on: [`ContactTerm::drive_collider`].
    ///
    /// # Errors
    /// [`ContactError::NoSuchCollider`] (with a count of 0 when there is no contact
    /// term), and the errors of [`Collider::driven`] naming the index; nothing changes
    /// then.
    pub fn drive_collider(
        &mut self,
        index: usize,
        drive: &Drive,
    ) -> Result<Collider, ContactError> {
        let time = self.time;
        match self.potential.term_mut::<ContactTerm>() {
            Some(term) => term.drive_collider(index, time, drive),
            None => Err(ContactError::NoSuchCollider { index, count: 0 }),
        }
    }

    /// Adds a term to the incremental potential (a contact barrier, friction). A term
    /// that couples particles no spring joins must not be added here: the Hessian pattern
    /// is built from the springs (particle-collider contact adds diagonal blocks only);
    /// use [`BackwardEuler::add_coupled_term`] for it.
    pub fn add_term(&mut self, term: Box<dyn Term>) {
        self.potential.push(term);
    }

    /// Adds a term that couples the particle pairs `pairs` besides the springs' pairs
    /// (dihedral bending couples the two vertices opposite a hinge): the Hessian pattern
    /// is rebuilt with slots for them and the linear solvers are rebuilt on it. Pairs
    /// added by earlier calls are kept. An index out of range is an `Err` naming it, and
    /// nothing changes.
    pub fn add_coupled_term(
        &mut self,
        system: &SpringSystem,
        term: Box<dyn Term>,
        pairs: &[[usize; 2]],
    ) -> Result<(), ModelError> {
        self.add_coupled_pairs(system, pairs)?;
        self.potential.push(term);
        Ok(())
    }

    /// Widens the Hessian pattern with slots for the particle pairs `pairs` (kept with
    /// those of earlier calls) without adding a term, for a term whose coupled pairs
    /// appear during a run (each step already does this for the pairs its terms report
    /// through `Term::take_missing_pairs`). The linear solvers are rebuilt on the new
    /// pattern. An index out of range is an `Err` naming it, and nothing changes.
    pub fn add_coupled_pairs(
        &mut self,
        system: &SpringSystem,
        pairs: &[[usize; 2]],
    ) -> Result<(), ModelError> {
        self.widen(system, pairs, Kept::ForGood, false)
    }

    /// [`Self::add_coupled_pairs`], the pairs kept as `kept` says; with `in_background`,
    /// when the caller runs on a pool of more than one thread and a direct solver
    /// exists, that solver's set-up for the widened pattern (its ordering and symbolic
    /// factorization, sequential work) runs as a job on the pool while the caller goes
    /// on with the iteration (the active set, the gradient, the Newton matrix), and is
    /// taken by [`Self::settle_direct`] before the first direct solve. The solver is the
    /// same whichever thread sets it up and whenever, so the results do not depend on
    /// it. A set-up that fails is then reported by `settle_direct`, with the pattern
    /// already widened (and no direct solver until one is built again).
    pub(super) fn widen(
        &mut self,
        system: &SpringSystem,
        pairs: &[[usize; 2]],
        kept: Kept,
        in_background: bool,
    ) -> Result<(), ModelError> {
        self.settle_direct()?;
        self.check_topology(system)?;
        if pairs.iter().flatten().any(|&p| p >= system.len()) {
            return Err(ModelError::BadParameter {
                name: "pairs",
                reason: "a coupled particle index is out of range",
            });
        }
        let (coupled, transient) = match kept {
            Kept::ForGood => (
                [&self.coupled_pairs[..], pairs].concat(),
                self.transient.clone(),
            ),
            Kept::WhileUsed => (self.coupled_pairs.clone(), self.transient.with_added(pairs)),
        };
        self.rebuild_pattern(system, coupled, transient, in_background)
    }

    /// Rebuilds the pattern without the transient pairs that have been idle long enough
    /// (see [`couplings`]) when they are many, the direct solver's set-up in the
    /// background (see [`Self::widen`]); returns how many were dropped.
    pub(super) fn narrow_if_due(&mut self, system: &SpringSystem) -> Result<usize, ModelError> {
        if !self.transient.narrowing_due() {
            return Ok(0);
        }
        self.settle_direct()?;
        let (transient, dropped) = self.transient.without_idle();
        self.rebuild_pattern(system, self.coupled_pairs.clone(), transient, true)?;
        Ok(dropped)
    }

    /// The pattern of the springs, `coupled` and `transient`'s pairs, with the linear
    /// solvers rebuilt on it (see [`Self::widen`] for `in_background`).
    fn rebuild_pattern(
        &mut self,
        system: &SpringSystem,
        coupled: Vec<[usize; 2]>,
        mut transient: TransientCouplings,
        in_background: bool,
    ) -> Result<(), ModelError> {
        let all: Vec<[usize; 2]> = coupled.iter().chain(transient.pairs()).copied().collect();
        let pattern = Arc::new(HessianPattern::with_pairs(system, &all));
        transient.locate(&pattern);
        #[cfg(feature = "parallel")]
        let background = in_background && self.direct.is_some() && crate::pool::shared();
        #[cfg(not(feature = "parallel"))]
        let background = {
            let _ = in_background;
            false
        };
        // Both solvers are built before either is replaced, so an error leaves the
        // integrator as it was (except for a set-up in the background, see above).
        let direct = match self.direct {
            Some(_) if !background => Some(Self::build_direct(&pattern, &self.settings)?),
            _ => None,
        };
        // The background set-up starts first, so the PCG solver is built beside it.
        #[cfg(feature = "parallel")]
        let pending = background.then(|| PendingDirect::spawn(Arc::clone(&pattern), self.settings));
        // The new PCG solver runs on the old one's thread pool: the dimension is the
        // same, and starting a pool (and stopping the old one) at every widening is
        // thread creation a contact step would pay several times.
        let mut pcg = PcgSolver::new(&pattern);
        if !pcg.share_threads(&self.pcg)
            && let Err(error) = pcg.set_threads(self.settings.threads)
        {
            // The pattern is not taken: the job's solver is waited for and dropped.
            #[cfg(feature = "parallel")]
            if let Some(pending) = pending {
                let _ = pending.wait();
            }
            return Err(error.into());
        }
        self.pcg = pcg;
        if direct.is_some() {
            self.direct = direct;
        }
        #[cfg(feature = "parallel")]
        if pending.is_some() {
            self.direct = None;
            self.pending_direct = pending;
        }
        self.coupled_pairs = coupled;
        self.transient = transient;
        // Zeroed at the new size, the storage reused.
        self.values.clear();
        self.values.resize(pattern.nnz(), 0.0);
        self.pattern = pattern;
        // The solver choice's counts were those of the narrower pattern: the widened one
        // has more entries to factor, so they are analysed again when a choice next
        // needs them.
        self.costs = None;
        Ok(())
    }

    /// Numerically factors the last assembled Newton matrix (building the symbolic
    /// factorization first if needed); false if it is not positive definite (a kernel for
    /// benchmarks).
    pub fn factor_newton_matrix(&mut self) -> Result<bool, ModelError> {
        self.settle_direct()?;
        if self.direct.is_none() {
            self.direct = Some(Self::build_direct(&self.pattern, &self.settings)?);
        }
        Ok(self
            .direct
            .as_mut()
            .is_some_and(|d| d.factor_only(&self.pattern, &self.values)))
    }

    /// The time the next step starts at: 0 at first, advanced by every step.
    #[must_use]
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Sets the time the next step starts at (a simulation that also steps by other
    /// means, or starts its colliders' clock elsewhere, says where the step begins).
    pub fn set_time(&mut self, time: f64) {
        self.time = time;
    }

    /// Starts (`true`) or stops recording the end state of every piece each step keeps
    /// ([`PieceEnds`]), for a check of the paths between them; off by default, and
    /// stopping forgets what was recorded. Each step starts the record afresh (a step
    /// with moving pins taken in pieces of the pinned motion is one step), so it holds
    /// the last step's pieces: one copy of the positions per piece kept.
    pub fn record_piece_ends(&mut self, on: bool) {
        if on {
            self.piece_ends.get_or_insert_with(PieceEnds::default);
        } else {
            self.piece_ends = None;
        }
    }

    /// The pieces of the last step (none after a refused one), `None` when not
    /// recording.
    #[must_use]
    pub fn piece_ends(&self) -> Option<&PieceEnds> {
        self.piece_ends.as_ref()
    }

    /// Forgets the last step's records (its pieces and its traces of `g`).
    pub(crate) fn clear_step_records(&mut self) {
        if let Some(record) = &mut self.piece_ends {
            record.clear();
        }
        self.step_traces.clear();
        self.step_trace_starts.clear();
    }

    /// Starts a step taken as several calls to the stepper (a pinned move in pieces of
    /// its motion): the records are cleared now and span the calls until
    /// [`Self::end_joined_step`].
    pub(crate) fn begin_joined_step(&mut self) {
        self.clear_step_records();
        self.joined_step = true;
    }

    /// Ends what [`Self::begin_joined_step`] began; a refused step (`refused`) leaves
    /// no records.
    pub(crate) fn end_joined_step(&mut self, refused: bool) {
        self.joined_step = false;
        if refused {
            self.clear_step_records();
        }
    }

    /// Forgets the velocity history used by the extrapolated first guess (call after
    /// changing the state by hand).
    pub fn reset_history(&mut self) {
        self.have_prev_velocity = false;
    }

    /// The pattern, the factorization and the potential's per-particle state were built
    /// for one topology: another system of the same counts but other pins, pairs or masses
    /// would run silently on them, so the fingerprints are compared (O(1)).
    pub(crate) fn check_topology(&self, system: &SpringSystem) -> Result<(), ModelError> {
        self.topology.check(&system.topology())
    }

    /// Advances `system` by one backward Euler step of length `h`.
    pub fn step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        self.step_scheme(system, h, Scheme::BackwardEuler)
    }

    /// Advances `system` by one step of length `h` of `scheme`, each one the same
    /// minimization with its own effective step, prediction and velocity update
    /// (docs/integrators.md).
    ///
    /// With a thread pool the whole step runs inside it (as the minimization did
    /// before): the calling thread hands the step over once instead of four times (the
    /// report's two energies, the first guess's test, the minimization), and the passes
    /// over the particles between them (the prediction, the end-of-step update) run
    /// on the pool's threads, in chunks, instead of on the calling thread while the
    /// pool's threads sleep.
    pub(crate) fn step_scheme(
        &mut self,
        system: &mut SpringSystem,
        h: f64,
        scheme: Scheme<'_>,
    ) -> Result<StepReport, StepError> {
        // A system too small for PCG's chunks runs this step on the pool when a term's
        // work asks for it (self-contact with many pairs), asked afresh every step: the
        // results are the same bits either way.
        self.pcg
            .use_small_pool(self.settings.threads, self.potential.wants_threads())
            .map_err(crate::model::ModelError::from)?;
        #[cfg(feature = "parallel")]
        if let Some(pool) = self.pcg.pool().cloned() {
            return pool.install(|| self.step_scheme_here(system, h, scheme));
        }
        self.step_scheme_here(system, h, scheme)
    }

    /// [`Self::step_scheme`] on the current thread (and the pool it runs in, if any).
    fn step_scheme_here(
        &mut self,
        system: &mut SpringSystem,
        h: f64,
        scheme: Scheme<'_>,
    ) -> Result<StepReport, StepError> {
        if !self.joined_step {
            self.clear_step_records();
        }
        check_time_step(h)?;
        self.check_topology(system)?;
        self.potential.check_start(system, self.time)?;
        if let Scheme::Bdf2 { prev_x, prev_v } = scheme
            && (prev_x.len() != system.len() || prev_v.len() != system.len())
        {
            return Err(ModelError::TopologyMismatch {
                what: "BDF2 history length",
            }
            .into());
        }
        let energy_before = self.energies(system);
        // Every piece is given its own start time (kinematic colliders are posed from
        // it) and the terms rewind what an abandoned solve changed, so any step may be
        // redone in pieces, moving colliders included.
        let depth = self.settings.max_split_depth + self.extra_split_depth();
        let start = self.time;
        self.last_piece_depth = depth;
        let recorded = self.piece_ends.as_ref().map_or(0, PieceEnds::len);
        let mut report = match self.step_in_pieces(system, h, scheme, depth, true, start) {
            Ok(report) => report,
            Err(e) => {
                // The pieces of a refused step are not in the record.
                if let Some(record) = &mut self.piece_ends {
                    record.truncate(recorded);
                }
                return Err(e);
            }
        };
        self.time = start + h;
        report.energy_before = energy_before;
        report.energy_after = self.energies(system);
        // Pairs a term coupled without Hessian slots (self-contact between particles no
        // spring joins) get slots for the next steps, and a step that found none
        // rebuilds nothing; pairs that have left are counted idle (see `couplings`).
        self.transient.end_step();
        let missing = self.potential.take_missing_pairs();
        if !missing.is_empty() {
            self.widen(system, &missing, Kept::WhileUsed, false)?;
            report.pattern_pairs_added += missing.len();
        }
        Ok(report)
    }

    /// One step of `scheme`, split in two halves (recursively, at most `depth` times)
    /// when its solve stops far from converged. The system is written only by a solve
    /// that is kept, so an abandoned attempt needs no undo: each half starts from the
    /// state and the velocity history the attempt started from, exactly as if the
    /// halves had been asked for one by one.
    fn step_in_pieces(
        &mut self,
        system: &mut SpringSystem,
        h: f64,
        scheme: Scheme<'_>,
        depth: usize,
        whole_step: bool,
        start: f64,
    ) -> Result<StepReport, StepError> {
        // A piece more than one level coarser than the last piece the step kept is not
        // attempted: that piece needed two or more halvings more than this one has, so
        // a solve of this length would almost surely stop far from converged again, and
        // it costs the whole iteration cap to find out. It is split at once. The whole
        // step is always attempted (its iterate is what a rejected split falls back on).
        if !whole_step && depth > 0 && self.last_piece_depth + 1 < depth {
            return self.split_without_attempt(system, h, scheme, depth, start);
        }
        let (mut attempt, h_eff) = self.solve(system, h, scheme, start, Resume::Guess)?;
        if whole_step
            && attempt.stop == StepStop::Overflow
            && self.settings.max_backtracks >= 2 * depth
        {
            // Nothing is committed yet. No split can help: a piece's Newton move is at
            // least about `4^-depth` of this one (the prediction's fall `g h^2` shrinks
            // with the square of the piece, and its inertia `m/h^2` grows as it
            // shortens), and the line search has already tried moves down to
            // `2^-max_backtracks` of it.
            self.potential.abandon_step();
            return Err(StepError::Overflow {
                integrator: attempt.integrator,
                iterations: attempt.iterations.saturating_sub(1),
            });
        }
        if attempt.stop == StepStop::NonFinite {
            // The gradient at the solve's iterate is not finite (forces beyond f64, or a
            // term's NaN): that iterate is no state to keep, and a piece of it would not
            // be either. Nothing of this attempt is committed.
            self.potential.abandon_step();
            // The residual reads the free particles' entries only (a fixed particle's
            // gradient is ignored by every caller).
            let particle = (self.pattern.free_particles.iter())
                .copied()
                .find(|&p| !self.grad_particles[p].is_finite())
                .unwrap_or(0);
            return Err(StepError::NonFinite {
                integrator: attempt.integrator,
                particle,
            });
        }
        let mut far = self.far_from_converged(system, &attempt, h_eff);
        let extra = self.extra_split_depth();
        let unsplittable = far && depth > 0 && split_cannot_help(system, h_eff, depth);
        if far
            && (depth == extra || depth == 0 || unsplittable)
            && self.settings.max_split_depth > 0
        {
            // A piece at the deepest split the settings ask for (`depth == extra`), at
            // the last of the extra levels below it (`depth == 0`), or one whose pieces
            // would all be static (`unsplittable`): its solve, which was still lowering
            // `g`, is continued from its iterate one iteration cap at a time (at most
            // `CONTINUED_CAPS` more). At the settings' depth a piece still far from
            // converged after that is halved again (`EXTRA_SPLIT_DEPTH`); at the last
            // level, and when unsplittable, it is kept.
            let mut from = std::mem::take(&mut self.continue_from);
            for _ in 0..CONTINUED_CAPS {
                if !far || attempt.stop != StepStop::IterationCap {
                    break;
                }
                from.clear();
                from.extend_from_slice(&self.x);
                let previous = attempt;
                attempt = self.solve(system, h, scheme, start, Resume::From(&from))?.0;
                attempt.add_work(&previous);
                far = self.far_from_converged(system, &attempt, h_eff);
            }
            self.continue_from = from;
        }
        // A kinematic collider that passed a particle within the step (the solve sees it
        // posed at the step's end only) is resolved by shorter pieces, over which it
        // travels less: the collider meets the particle at a piece's end and carries it.
        let passed = self.swept_pass(system, h_eff);
        if (!far && !passed) || depth == 0 || (unsplittable && !passed) {
            self.commit(system, (h_eff, start + h), scheme, attempt.integrator)?;
            self.last_piece_depth = depth;
            let mut report = attempt;
            report.unconverged_pieces = usize::from(far);
            report.swept_passes = usize::from(passed);
            return Ok(report);
        }
        // The attempt is abandoned: the terms forget what its solve adapted (contact's
        // barrier stiffness), so the pieces run as if asked for one by one.
        self.potential.abandon_step();
        let piece = scheme.piece();
        // Backward Euler promises its energy inequality for the step asked for (below),
        // not for each piece: it is checked once, for the whole step, with the start
        // state and the abandoned iterate kept to fall back on.
        // Not checked when a kinematic collider does work on the cloth (a step split
        // because one passed a particle would otherwise fall back on the pass), since
        // the inequality holds for a system that no outside motion drives.
        let guard =
            whole_step && matches!(scheme, Scheme::BackwardEuler) && !self.potential.does_work();
        let mut save = if guard {
            let mut save = self.take_split_save(depth);
            save.x_n.clear();
            save.x_n.extend_from_slice(system.positions());
            save.v_n.clear();
            save.v_n.extend_from_slice(system.velocities());
            save.attempt.clear();
            save.attempt.extend_from_slice(&self.x);
            save.energy = system.energies();
            Some(save)
        } else {
            None
        };
        let recorded = self.piece_ends.as_ref().map_or(0, PieceEnds::len);
        let first = self.step_in_pieces(system, 0.5 * h, piece, depth - 1, false, start)?;
        let second =
            self.step_in_pieces(system, 0.5 * h, piece, depth - 1, false, start + 0.5 * h)?;
        let combined = combine_pieces(&attempt, &first, &second);
        let Some(saved) = save.as_mut() else {
            return Ok(combined);
        };
        let kept = keeps_energy_inequality(system, saved);
        let report = if kept {
            combined
        } else {
            // The pieces together broke the inequality a backward Euler step of h keeps
            // (a shorter step dissipates less, and a split trajectory need not stay
            // below the energy of one step of h). The abandoned solve of h, whose every
            // iterate keeps the inequality (`g` never rises from the start state), is
            // continued from its iterate, one iteration cap at a time (at most
            // `CONTINUED_CAPS` more), and is the step after all. If it is still far from
            // converged then, the solve of h starts once more from the pieces' end
            // positions (when `g` there is no higher than at the start state, so the
            // inequality still holds for every iterate) and is continued the same way:
            // on a stiff stretched sheet the continued iterates did not settle in 800
            // iterations, and from the pieces' end (the same motion in finer steps) the
            // solve converged in 255 (docs/spring-sim.md). Only a solve still far from
            // converged after that, or whose line search stalled, is reported so.
            saved.split_end.clear();
            saved.split_end.extend_from_slice(system.positions());
            system.set_state(&saved.x_n, &saved.v_n)?;
            if let Some(record) = &mut self.piece_ends {
                record.truncate(recorded);
            }
            let mut spent = attempt;
            for part in [&first, &second] {
                spent.add_work(part);
            }
            let (mut report, mut far) = (StepReport::new(attempt.integrator), true);
            for taken_up in [false, true] {
                let resume = if taken_up {
                    if !far {
                        break;
                    }
                    spent.add_work(&report);
                    saved.attempt.copy_from_slice(&self.x);
                    Resume::SplitEndOr {
                        split_end: &saved.split_end,
                        otherwise: &saved.attempt,
                    }
                } else {
                    Resume::From(&saved.attempt)
                };
                report = self.solve(system, h, scheme, start, resume)?.0;
                far = self.far_from_converged(system, &report, h_eff);
                for _ in 1..CONTINUED_CAPS {
                    if !far || report.stop != StepStop::IterationCap {
                        break;
                    }
                    saved.attempt.copy_from_slice(&self.x);
                    spent.add_work(&report);
                    report = self
                        .solve(system, h, scheme, start, Resume::From(&saved.attempt))?
                        .0;
                    far = self.far_from_converged(system, &report, h_eff);
                }
            }
            self.commit(system, (h_eff, start + h), scheme, attempt.integrator)?;
            report.add_work(&spent);
            report.unconverged_pieces = usize::from(far);
            report.rejected_splits = 1 + first.rejected_splits + second.rejected_splits;
            report
        };
        self.split_saves[depth - 1] = save.take().expect("guarded");
        Ok(report)
    }

    /// Whether a term reports a particle passed by a moving collider on the straight
    /// path from the step's start to the end state of the current iterate `self.x`
    /// ([`Potential::first_swept_pass`]), for the step the last solve set up.
    fn swept_pass(&self, system: &SpringSystem, h_eff: f64) -> bool {
        let step = StepContext::new(system, h_eff, &self.y, &self.x_ref).with_timing(self.timing);
        self.potential.first_swept_pass(&step, &self.x).is_some()
    }

    /// The levels of halving below `NewtonSettings::max_split_depth` that a piece still
    /// far from converged after its continued solve may take (none with splitting off).
    fn extra_split_depth(&self) -> usize {
        if self.settings.max_split_depth > 0 {
            EXTRA_SPLIT_DEPTH
        } else {
            0
        }
    }

    /// A piece of a split step taken as its two halves without a solve of its own
    /// length (see [`Self::step_in_pieces`]); never the whole step, so there is no
    /// energy inequality to guard here.
    fn split_without_attempt(
        &mut self,
        system: &mut SpringSystem,
        h: f64,
        scheme: Scheme<'_>,
        depth: usize,
        start: f64,
    ) -> Result<StepReport, StepError> {
        let piece = scheme.piece();
        let skipped = StepReport::new(match scheme {
            Scheme::BackwardEuler => IntegratorKind::BackwardEuler,
            Scheme::Midpoint => IntegratorKind::ImplicitMidpoint,
            Scheme::Bdf2 { .. } => IntegratorKind::Bdf2,
        });
        let first = self.step_in_pieces(system, 0.5 * h, piece, depth - 1, false, start)?;
        let second =
            self.step_in_pieces(system, 0.5 * h, piece, depth - 1, false, start + 0.5 * h)?;
        Ok(combine_pieces(&skipped, &first, &second))
    }

    /// The buffers of the split at remaining depth `depth` (at least 1), grown the
    /// first time a split that deep happens and reused after.
    fn take_split_save(&mut self, depth: usize) -> SplitSave {
        if self.split_saves.len() < depth {
            self.split_saves.resize_with(depth, SplitSave::default);
        }
        std::mem::take(&mut self.split_saves[depth - 1])
    }

    /// Whether a solve stopped without converging (at the cap or in a stalled line
    /// search) with its residual above both its tolerance and the round-off floor
    /// ([`Self::gradient_floor`]): only then can a shorter step help; a solve stopped at
    /// round-off is as good as converged.
    fn far_from_converged(&mut self, system: &SpringSystem, report: &StepReport, h: f64) -> bool {
        if !matches!(
            report.stop,
            StepStop::IterationCap | StepStop::LineSearchStalled | StepStop::Overflow
        ) || report.residual <= report.tolerance
        {
            return false;
        }
        report.residual > self.gradient_floor(system, h).max(self.curvature_floor())
    }

    /// The largest coordinate of the current iterate, in absolute value: the scale of the
    /// rounding both round-off floors are measured in.
    fn x_max(&self) -> f64 {
        self.x
            .iter()
            .fold(0.0f64, |m, x| m.max(x.abs().max_element()))
    }

    /// The round-off floor of the residual from the last assembled Newton matrix:
    /// `16 eps |x|_max max_p (m_min/m_p) max_c H_(3p+c, 3p+c)` over the free particles,
    /// the largest diagonal entry of every term's curvature, each particle's scaled as the
    /// residual is. [`Self::gradient_floor`] counts inertia, springs and damping only; a
    /// contact barrier or friction can be far stiffer (the self-contact of a twisting
    /// sheet flung by a gravity of 1e8), and its gradient carries rounding of
    /// `eps |x|` times that stiffness: a solve stopped there is as converged as the
    /// arithmetic allows, and splitting it only repeats the stop at every depth. For
    /// inertia, springs and damping alone it is at most `gradient_floor` (each spring's
    /// diagonal entries are at most its stiffness).
    fn curvature_floor(&self) -> f64 {
        let x_max = self.x_max();
        let largest = self
            .pattern
            .diag_slots
            .iter()
            .zip(&self.mass_scales)
            .map(|(slots, scale)| {
                let d = self.values[slots[0]]
                    .max(self.values[slots[3]])
                    .max(self.values[slots[5]]);
                scale * d
            })
            .fold(0.0f64, f64::max);
        16.0 * f64::EPSILON * x_max * largest
    }

    /// The round-off floor of the residual at `self.x`:
    /// `16 eps |x|_max max_p m_min/m_p (m_p/h^2 + sum over the springs at p of (k_s +
    /// c/h))` over the free particles, `c` the damping (its term's curvature along each
    /// spring is `c/h`), each particle's scaled to the smallest mass as the residual is
    /// ([`Self::mass_scales`]). Moving a coordinate by one ulp of `|x|_max` changes
    /// `grad g` by up to the Newton matrix's row sum times that ulp, and the terms'
    /// gradients, computed from absolute positions, carry rounding of that order: no
    /// solver can be asked for less. (The stress grid checks every stop short of the
    /// tolerance against the same bound, computed on its own.)
    pub(super) fn gradient_floor(&mut self, system: &SpringSystem, h: f64) -> f64 {
        let x_max = self.x_max();
        let damping = system.material().damping / h;
        let row = &mut self.row_scratch;
        row.clear();
        row.resize(system.len(), 0.0);
        for s in system.springs() {
            row[s.a] += s.stiffness + damping;
            row[s.b] += s.stiffness + damping;
        }
        let inv_h2 = 1.0 / (h * h);
        let m_min = system.min_free_mass();
        let largest = system
            .masses()
            .iter()
            .zip(row.iter())
            .zip(system.fixed())
            .filter(|(_, f)| !**f)
            .map(|((m, k), _)| m_min / m * (m * inv_h2 + k))
            .fold(0.0f64, f64::max);
        16.0 * f64::EPSILON * x_max * largest
    }

    /// Sets up and runs the minimization of one step of `scheme` from `system`'s state,
    /// leaving the minimizer in `self.x` and the system untouched; returns the report and
    /// the effective step.
    /// `resume` says where the minimization starts: the step's own first guess, or a
    /// point taken up again (see [`Resume`]).
    fn solve(
        &mut self,
        system: &SpringSystem,
        h: f64,
        scheme: Scheme<'_>,
        start: f64,
        resume: Resume<'_>,
    ) -> Result<(StepReport, f64), StepError> {
        self.timing = StepTiming {
            start,
            length: h,
            midpoint: matches!(scheme, Scheme::Midpoint),
        };
        let (kind, h_eff) = match scheme {
            Scheme::BackwardEuler => (IntegratorKind::BackwardEuler, h),
            Scheme::Midpoint => (IntegratorKind::ImplicitMidpoint, 0.5 * h),
            Scheme::Bdf2 { .. } => (IntegratorKind::Bdf2, 2.0 * h / 3.0),
        };
        let fixed = system.fixed();
        let (positions, velocities) = (system.positions(), system.velocities());
        let extrapolate =
            self.settings.initial_guess == InitialGuess::Extrapolated && self.have_prev_velocity;
        let prev_velocity = &self.prev_velocity;
        // Per particle: `x_ref`, `y`, the first guess `x`, and the straight path from
        // the safe start x_n to the guess, `x - x_n`, for both tests below.
        let predict = |i: usize, [x_ref, y, guess, path]: [&mut DVec3; 4]| {
            let (x, v) = (positions[i], velocities[i]);
            if fixed[i] {
                // A pinned particle sits at its end-of-step position `x` and moved with
                // the prescribed velocity `v` over the step (zero for a particle held
                // still): it enters the potential at the scheme's evaluation point
                // (the midpoint's `z` is halfway along its move), and its reference
                // point is where that velocity started it, so damping sees its motion.
                let (at, start) = match scheme {
                    Scheme::Midpoint => (x - h_eff * v, x - 2.0 * h_eff * v),
                    Scheme::BackwardEuler | Scheme::Bdf2 { .. } => (x, x - h_eff * v),
                };
                *x_ref = start;
                *y = at;
                *guess = at;
            } else {
                // x_ref: the point the new velocity is measured from, v' = (x' -
                // x_ref)/h_eff (also the damping's reference); y: the inertial prediction.
                let (start, v_ref) = match scheme {
                    Scheme::BackwardEuler | Scheme::Midpoint => (x, v),
                    Scheme::Bdf2 { prev_x, prev_v } => {
                        ((4.0 * x - prev_x[i]) / 3.0, (4.0 * v - prev_v[i]) / 3.0)
                    }
                };
                *x_ref = start;
                *y = start + h_eff * v_ref;
                *guess = *y;
                if extrapolate {
                    *guess += h_eff * (v - prev_velocity[i]);
                }
            }
            *path = *guess - x;
        };
        per_particle(
            &self.pcg,
            [
                &mut self.x_ref,
                &mut self.y,
                &mut self.x,
                &mut self.dx_particles,
            ],
            predict,
        );
        // Per-step state of the terms (damping directions frozen at the step's start).
        let timing = self.timing;
        self.potential
            .begin_step(&StepContext::new(system, h_eff, &self.y, &self.x_ref).with_timing(timing));
        let step = StepContext::new(system, h_eff, &self.y, &self.x_ref).with_timing(timing);
        // Start from x_n when the predicted guess is worse (backward Euler only): Newton
        // with the line search never increases g from its starting point, so then every
        // step has g(x_{n+1}) <= g(x_n), which is what the energy inequality of
        // docs/labcheck.md rests on.
        let guess_is_acceptable = start_is_acceptable(
            &self.potential,
            &self.pcg,
            &mut self.change_partials,
            &step,
            system.positions(),
            &self.dx_particles,
            matches!(scheme, Scheme::BackwardEuler),
        );
        // The Newton direction is written at the free particles only: a moving pin's
        // entry (nonzero in the midpoint scheme) must not stay behind.
        for (d, f) in self.dx_particles.iter_mut().zip(fixed) {
            if *f {
                *d = DVec3::ZERO;
            }
        }
        if !guess_is_acceptable {
            start_at(&mut self.x, system.positions(), &self.y, fixed);
        }
        match resume {
            Resume::Guess => {}
            Resume::From(iterate) => self.x.copy_from_slice(iterate),
            Resume::SplitEndOr {
                split_end,
                otherwise,
            } => {
                // The same test as the first guess's, on the straight path from x_n
                // to the pieces' end.
                let positions = system.positions();
                straight_path(&mut self.dx_particles, positions, split_end, fixed);
                if start_is_acceptable(
                    &self.potential,
                    &self.pcg,
                    &mut self.change_partials,
                    &step,
                    positions,
                    &self.dx_particles,
                    true,
                ) {
                    start_at(&mut self.x, split_end, &self.y, fixed);
                } else {
                    self.x.copy_from_slice(otherwise);
                }
            }
        }
        self.potential.prepare_start(&step, &mut self.x);
        let mut report = self.minimize(system, h_eff, false)?;
        for _ in 1..self.settings.friction_lags {
            if !matches!(report.stop, StepStop::Converged | StepStop::RoundOff) {
                break;
            }
            let Some(at_minimizer) = self.relag_friction(system, h_eff, scheme) else {
                break;
            };
            let mut round = self.minimize(system, h_eff, at_minimizer)?;
            let iterations = round.iterations;
            round.add_work(&report);
            round.friction_relags += 1;
            round.friction_restarts += usize::from(!at_minimizer);
            report = round;
            if iterations == 0 {
                break;
            }
        }
        report.integrator = kind;
        Ok((report, h_eff))
    }

    /// Lags the terms' friction again at the minimizer in `self.x` and chooses where
    /// the next round's minimization starts: there, or, for backward Euler, at x_n when
    /// `g` with the new lag is higher at the minimizer than at x_n, so every round, like
    /// the first, ends with `g(x_{n+1}) <= g(x_n)` for its own function (the energy
    /// inequality's ground). Unlike a first guess the minimizer needs no test of the
    /// straight path from x_n: it was reached by admissible iterates, each move capped
    /// by the terms' largest safe step (a landing sheet's straight path from x_n, which
    /// that cap cuts short of its contacts, would never pass). Returns whether the round
    /// starts at the minimizer (`true`) or at x_n (`false`, which then gets at least one
    /// iteration, as a step's first guess does), or `None` when no term holds friction
    /// (there is nothing to redo).
    fn relag_friction(
        &mut self,
        system: &SpringSystem,
        h_eff: f64,
        scheme: Scheme<'_>,
    ) -> Option<bool> {
        let step = StepContext::new(system, h_eff, &self.y, &self.x_ref).with_timing(self.timing);
        if !self.potential.relag_friction(&step, &self.x) {
            return None;
        }
        if !matches!(scheme, Scheme::BackwardEuler) {
            return Some(true);
        }
        let positions = system.positions();
        // Zero at the pinned particles, which the minimizer holds at their prescribed
        // end (`x_n` itself for backward Euler): the Newton direction that this buffer
        // holds next is written at the free particles only.
        straight_path(&mut self.dx_particles, positions, &self.x, system.fixed());
        let change = change_on_pool(
            &self.potential,
            &self.pcg,
            &mut self.change_partials,
            &step,
            positions,
            &self.dx_particles,
        );
        // A NaN counts as higher, as in the first guess's test.
        if change <= 0.0 {
            return Some(true);
        }
        start_at(&mut self.x, positions, &self.y, system.fixed());
        self.potential.prepare_start(&step, &mut self.x);
        Some(false)
    }

    /// Writes the minimizer in `self.x` to `system` as the end of a step of `scheme`
    /// with effective step `h_eff`, ending at time `end`, and moves the velocity history
    /// on.
    fn commit(
        &mut self,
        system: &mut SpringSystem,
        (h_eff, end): (f64, f64),
        scheme: Scheme<'_>,
        kind: IntegratorKind,
    ) -> Result<(), StepError> {
        if let Some(particle) = first_non_finite(&self.pcg, &self.x) {
            // Not reached with finite input (every iterate passed the line search); kept
            // so a NaN can never leave this call.
            return Err(StepError::NonFinite {
                integrator: kind,
                particle,
            });
        }
        let (positions, velocities) = system.state_mut();
        let (x, x_ref, pattern) = (&self.x, &self.x_ref, &self.pattern);
        let update = |i: usize, [position, velocity, prev]: [&mut DVec3; 3]| {
            *prev = *velocity;
            if !fixed_at(pattern, i) {
                let v_mean = (x[i] - x_ref[i]) / h_eff;
                if matches!(scheme, Scheme::Midpoint) {
                    // x is the midpoint z: x' = 2 z - x_n, v' = 2 v_mean - v_n.
                    *velocity = 2.0 * v_mean - *velocity;
                    *position = 2.0 * x[i] - x_ref[i];
                } else {
                    *velocity = v_mean;
                    *position = x[i];
                }
            }
        };
        per_particle(
            &self.pcg,
            [positions, velocities, &mut self.prev_velocity],
            update,
        );
        self.have_prev_velocity = true;
        if let Some(record) = &mut self.piece_ends {
            record.push(end, system.positions());
        }
        Ok(())
    }

    /// `system.energies()`, bit for bit, with the springs' energies computed four
    /// springs at a time ([`crate::potential::spring_energies`]), on the thread pool
    /// when there is one. A step reports the energies before and after it,
    /// and computed on the calling thread alone they kept the pool's other threads
    /// waiting (about 8% of a two-thread W6 step). Each spring's energy is the same
    /// expression wherever it is computed, and the three sums are added in the order of
    /// [`SpringSystem::energies`] (the springs' sum beside the particles' two), so the
    /// result does not depend on the threads (`tests/suite/thread_counts.rs` compares it
    /// with [`SpringSystem::energies`]).
    fn energies(&mut self, system: &SpringSystem) -> crate::model::Energies {
        #[cfg(feature = "parallel")]
        if let Some(pool) = self.pcg.pool() {
            use rayon::prelude::*;
            let x = system.positions();
            let springs = system.springs();
            let buffer = &mut self.spring_energies;
            buffer.resize(springs.len(), 0.0);
            let (spring, (kinetic, gravity)) = pool.install(|| {
                buffer
                    .par_chunks_mut(ENERGY_CHUNK)
                    .zip(springs.par_chunks(ENERGY_CHUNK))
                    .for_each(|(e, s)| {
                        // Four springs at a time, bitwise `spring::energy` per spring.
                        crate::potential::spring_energies(
                            crate::potential::Instance::Detect,
                            s,
                            x,
                            e,
                        );
                    });
                let buffer = &*buffer;
                rayon::join(
                    || buffer.iter().copied().sum::<f64>(),
                    || system.particle_energies_of(system.positions(), system.velocities()),
                )
            });
            return crate::model::Energies {
                kinetic,
                spring,
                gravity,
            };
        }
        // On one thread, the same kernel into the same buffer and the same sum: four
        // springs at a time, where the scalar loop of `system.energies()` took a square
        // root per spring (4% of the ground contact workload's instructions).
        let springs = system.springs();
        let buffer = &mut self.spring_energies;
        buffer.resize(springs.len(), 0.0);
        crate::potential::spring_energies(
            crate::potential::Instance::Detect,
            springs,
            system.positions(),
            buffer,
        );
        let spring = buffer.iter().copied().sum::<f64>();
        let (kinetic, gravity) =
            system.particle_energies_of(system.positions(), system.velocities());
        crate::model::Energies {
            kinetic,
            spring,
            gravity,
        }
    }

    /// The counts the automatic linear-solver choice is made from (analysing the pattern
    /// now if that has not happened yet).
    pub fn solver_costs(&mut self) -> Result<SolverCosts, ModelError> {
        if let Some(c) = self.costs {
            return Ok(c);
        }
        let c = SolverCosts::analyze(&self.pattern)?;
        self.costs = Some(c);
        Ok(c)
    }

    /// Runs PCG on the last assembled Newton matrix against the right-hand side of the
    /// last step, from zero, for exactly `iterations` iterations unless it converges to
    /// round-off first (a kernel for benchmarks of one PCG iteration).
    pub fn pcg_iterations_on_newton_matrix(&mut self, iterations: usize) -> PcgOutcome {
        if self.rhs.iter().all(|r| *r == 0.0) {
            self.rhs.fill(1.0);
        }
        self.dx.fill(0.0);
        self.pcg.solve(
            &self.pattern,
            &self.values,
            &self.rhs,
            &mut self.dx,
            1e-300,
            iterations,
        )
    }

    /// The counts that decide a choice for `observed` PCG iterations per Newton
    /// iteration: the analysed ones once they exist; before that, the bound of
    /// [`SolverCosts::lower_bound`] when `observed` is below its crossover (then below
    /// the analysed one as well, so the choice is the same, PCG), and only otherwise the
    /// analysis. The soft cloths (about 2.7 PCG iterations per Newton iteration on W6,
    /// a bound of about 8) never pay for the analysis: 55 M instructions on W6, 573 M on
    /// 317 x 317, once per run.
    fn deciding_costs(&mut self, observed: f64) -> Result<SolverCosts, ModelError> {
        if let Some(c) = self.costs {
            return Ok(c);
        }
        let bound = SolverCosts::lower_bound(&self.pattern);
        // The margin keeps the rounding of the bound's few operations from mattering.
        if observed <= BOUND_MARGIN * bound.crossover_iterations() {
            return Ok(bound);
        }
        self.solver_costs()
    }

    fn choose_solver(&mut self, dim: usize) -> Result<LinearSolverKind, ModelError> {
        let choice = self.settings.linear_solver;
        let costs = match self.chooser.observed() {
            Some(observed) if self.chooser.needs_costs(choice) => {
                Some(self.deciding_costs(observed)?)
            }
            _ => None,
        };
        let kind = self
            .chooser
            .choose(choice, self.settings.reprobe_interval, costs.as_ref());
        self.settle_direct()?;
        if kind == LinearSolverKind::Direct && self.direct.is_none() && dim > 0 {
            self.direct = Some(Self::build_direct(&self.pattern, &self.settings)?);
        }
        Ok(kind)
    }

    /// The solver for the rest of a step that has run `newton_iterations` Newton
    /// iterations on `kind` with `linear_iterations` PCG iterations: the direct solve
    /// once PCG's count shows it costs more (solver_choice), else `kind`.
    pub(super) fn reconsider_solver(
        &mut self,
        kind: LinearSolverKind,
        newton_iterations: usize,
        linear_iterations: usize,
    ) -> Result<LinearSolverKind, ModelError> {
        let choice = self.settings.linear_solver;
        if kind != LinearSolverKind::Pcg
            || choice != LinearSolverChoice::Auto
            || newton_iterations < solver_choice::PCG_PROBE_NEWTON_ITERATIONS
            || self.pattern.dim() == 0
        {
            return Ok(kind);
        }
        let costs = self.deciding_costs(linear_iterations as f64 / newton_iterations as f64)?;
        if !self
            .chooser
            .switch_mid_step(choice, newton_iterations, linear_iterations, &costs)
        {
            return Ok(kind);
        }
        self.settle_direct()?;
        if self.direct.is_none() {
            self.direct = Some(Self::build_direct(&self.pattern, &self.settings)?);
        }
        Ok(LinearSolverKind::Direct)
    }
}

/// A direct solver being set up by a job on the caller's thread pool
/// ([`BackwardEuler::widen`]): the job writes its result into the shared slot.
#[cfg(feature = "parallel")]
struct PendingDirect {
    result: Arc<Mutex<Option<Result<DirectSolver, ModelError>>>>,
}

#[cfg(feature = "parallel")]
impl std::fmt::Debug for PendingDirect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("PendingDirect")
    }
}

#[cfg(feature = "parallel")]
impl PendingDirect {
    /// The set-up of the direct solver of `pattern` as a job on the caller's pool.
    fn spawn(pattern: Arc<HessianPattern>, settings: NewtonSettings) -> Self {
        let result = Arc::new(Mutex::new(None));
        let slot = Arc::clone(&result);
        rayon::spawn(move || {
            let built = BackwardEuler::build_direct(&pattern, &settings);
            *slot.lock().unwrap_or_else(PoisonError::into_inner) = Some(built);
        });
        Self { result }
    }

    /// The job's result, once it has run: while it has not, this thread runs pending
    /// jobs of its pool (the set-up itself, when no other thread has taken it) or
    /// yields to the thread running it.
    fn wait(self) -> Result<DirectSolver, ModelError> {
        loop {
            if let Some(built) = self
                .result
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .take()
            {
                return built;
            }
            if rayon::yield_now() != Some(rayon::Yield::Executed) {
                std::thread::yield_now();
            }
        }
    }
}

/// What a split backward Euler step keeps to fall back on: the start state, the
/// abandoned iterate and the start's energies.
#[derive(Debug, Default)]
struct SplitSave {
    x_n: Vec<DVec3>,
    v_n: Vec<DVec3>,
    attempt: Vec<DVec3>,
    /// The pieces' end positions, when their split was rejected.
    split_end: Vec<DVec3>,
    energy: crate::model::Energies,
}

/// Where a solve starts.
#[derive(Clone, Copy, Debug)]
enum Resume<'a> {
    /// The step's first guess (the extrapolated prediction, or x_n when that is worse).
    Guess,
    /// An earlier solve's iterate of the same step, abandoned at its cap; it has `g` no
    /// larger than at the start state, so continuing from it keeps backward Euler's
    /// energy inequality.
    From(&'a [DVec3]),
    /// The end positions of the step's rejected split, when `g` there is no higher than
    /// at the start state and their straight path from x_n is admissible (so the
    /// inequality still holds for every iterate), else `otherwise` (as in `From`).
    SplitEndOr {
        split_end: &'a [DVec3],
        otherwise: &'a [DVec3],
    },
}

/// Whether `system`, after the pieces of a step from `save`'s start state, keeps backward
/// Euler's energy inequality for the whole step,
/// `E_spring(x') + E_gravity(x') + 1/2 |v' - v_n|_M^2 <= E_total(x_n, v_n)`, up to
/// `64 eps` of the terms' sizes. One backward Euler step keeps it because
/// `g(x_{n+1}) <= g(x_n)` (docs/spring-sim.md); pieces need not.
fn keeps_energy_inequality(system: &SpringSystem, save: &SplitSave) -> bool {
    let after = system.energies();
    let velocity_change: f64 = system
        .velocities()
        .iter()
        .zip(&save.v_n)
        .zip(system.masses())
        .map(|((v, v0), m)| 0.5 * m * (*v - *v0).length_squared())
        .sum();
    let lhs = after.spring + after.gravity + velocity_change;
    let rhs = save.energy.total();
    let scale = save.energy.scale() + after.scale() + velocity_change;
    lhs <= rhs + 64.0 * f64::EPSILON * scale
}

/// Whether splitting a step of effective length `h` down to `depth` more halvings
/// cannot help the solve it is stuck on: even in the deepest piece (`h / 2^depth`) the
/// inertia `m / h^2` of the heaviest free particle is below `1 / STATIC_RATIO` of the
/// stiffness of the softest spring with a free end. Every piece is then nearly the same
/// static problem (springs against gravity and the pins) as the whole step, so the
/// pieces redo the static solve the abandoned attempts had begun, and the whole step's
/// solve is continued from its iterate instead (docs/spring-sim.md, "Steps too long to
/// split").
fn split_cannot_help(system: &SpringSystem, h: f64, depth: usize) -> bool {
    let fixed = system.fixed();
    let k_min = system
        .springs()
        .iter()
        .filter(|s| s.stiffness > 0.0 && !(fixed[s.a] && fixed[s.b]))
        .map(|s| s.stiffness)
        .fold(f64::INFINITY, f64::min);
    let m_max = system
        .masses()
        .iter()
        .zip(fixed)
        .filter(|(_, f)| !**f)
        .map(|(m, _)| *m)
        .fold(0.0f64, f64::max);
    let piece = h / 2f64.powi(depth.min(1000) as i32);
    k_min.is_finite() && m_max > 0.0 && k_min * piece * piece >= STATIC_RATIO * m_max
}

/// See [`split_cannot_help`]: `k h^2 / m` of the deepest piece from which a split is not
/// tried. The stress grid's stiffest steps (`k h^2 / m` up to 6.25e5 for the whole step,
/// under 10 in its deepest pieces), which splitting made converge, stay far below it.
const STATIC_RATIO: f64 = 1e6;

/// How many more iteration caps a solve that cannot be split further is given, from its
/// last iterate: the whole step's after its split was rejected, and a piece at the
/// deepest split allowed (see `BackwardEuler::step_in_pieces`).
const CONTINUED_CAPS: usize = 16;

/// How many more halvings a piece at `NewtonSettings::max_split_depth` may take when its
/// continued solve still stops far from converged. The continuation comes first because
/// it converged every such piece of the 51 x 51 stress grid, so every step that converged
/// without these levels is computed exactly as before; a compressed 101 x 101 sheet
/// (k = 1e4, h = 1/4) left one piece of `h/64` far from converged after 16 more caps, and
/// its pieces of `h/128` converge (docs/stress.md).
const EXTRA_SPLIT_DEPTH: usize = 2;

/// The report of a step split into `first` and `second` after the solve `attempt` was
/// abandoned: the work of all three, the pieces of both halves, and the residual,
/// tolerance and stop of the piece furthest from its tolerance.
fn combine_pieces(attempt: &StepReport, first: &StepReport, second: &StepReport) -> StepReport {
    let worst = if second.residual / second.tolerance > first.residual / first.tolerance {
        second
    } else {
        first
    };
    let mut report = *worst;
    report.integrator = attempt.integrator;
    report.linear_solver = second.linear_solver;
    // A piece that converged reports Converged; the step converged only if both did.
    report.stop = match (first.stop, second.stop) {
        (StepStop::Converged, StepStop::Converged) => StepStop::Converged,
        (StepStop::Converged, other) | (other, _) => other,
    };
    for part in [attempt, first, second] {
        if std::ptr::eq(part, worst) {
            continue;
        }
        report.add_work(part);
    }
    report.pieces = first.pieces + second.pieces;
    report.split_depth = 1 + first.split_depth.max(second.split_depth);
    report.unconverged_pieces = first.unconverged_pieces + second.unconverged_pieces;
    report.swept_passes = first.swept_passes + second.swept_passes;
    report.rejected_splits = first.rejected_splits + second.rejected_splits;
    report
}

/// Whether a solve may start at `x + dx` instead of the safe start `x` (x_n): with
/// `check_change`, the change `g(x + dx) - g(x)` is not positive, computed once and summed
/// term by term as in the line search (half the passes of two evaluations of `g`, and
/// free of the cancellation of two large totals; a NaN counts as worse); and the
/// straight path from `x` is admissible for a term with a barrier (contact): a point
/// beyond a thin collider is outside it but was reached through it. The safe start is
/// x_n for every scheme (the end state of backward Euler and BDF2; the midpoint
/// `z = x_n` has the end state `2 z - x_n = x_n`), not BDF2's `x_ref`, an extrapolation
/// that may lie inside a collider. Without such a term the cap is infinite.
fn start_is_acceptable(
    potential: &Potential,
    pcg: &PcgSolver,
    partials: &mut Vec<f64>,
    step: &StepContext<'_>,
    x: &[DVec3],
    dx: &[DVec3],
    check_change: bool,
) -> bool {
    // The cap first, and always: a self-contact term's cap collects its pairs along the
    // path, state the solve that follows starts from, and keeps their values at `x`,
    // which the change then takes instead of computing them again.
    let admissible = potential.max_step(step, x, dx, 1.0) >= 1.0;
    let no_higher = !check_change || change_on_pool(potential, pcg, partials, step, x, dx) <= 0.0;
    no_higher && admissible
}

/// `to - from` at every free particle into `path`, zero at the fixed ones.
fn straight_path(path: &mut [DVec3], from: &[DVec3], to: &[DVec3], fixed: &[bool]) {
    for ((d, (t, f0)), f) in path.iter_mut().zip(to.iter().zip(from)).zip(fixed) {
        *d = if *f { DVec3::ZERO } else { *t - *f0 };
    }
}

/// Copies `from` into `x`, then puts the pinned particles at their evaluation point
/// `y` (it differs from the system's position only for a moving pin in the midpoint
/// scheme).
fn start_at(x: &mut [DVec3], from: &[DVec3], y: &[DVec3], fixed: &[bool]) {
    x.copy_from_slice(from);
    for ((x, y), f) in x.iter_mut().zip(y).zip(fixed) {
        if *f {
            *x = *y;
        }
    }
}

/// `g(x + dx) - g(x)` on the solver's thread pool when it has one (the same bits for
/// any number of threads).
fn change_on_pool(
    potential: &Potential,
    pcg: &PcgSolver,
    partials: &mut Vec<f64>,
    step: &StepContext<'_>,
    x: &[DVec3],
    dx: &[DVec3],
) -> f64 {
    #[cfg(feature = "parallel")]
    if let Some(pool) = pcg.pool() {
        return pool.install(|| potential.energy_change_chunked(step, x, dx, 1.0, true, partials));
    }
    #[cfg(not(feature = "parallel"))]
    let _ = pcg;
    potential.energy_change_chunked(step, x, dx, 1.0, false, partials)
}

/// Particles per task of a step's passes over the particles on the thread pool.
#[cfg(feature = "parallel")]
const PARTICLE_CHUNK: usize = 1024;

/// `f(i, [&mut a[i], ...])` for every particle `i` of the `N` equally long arrays, in
/// chunks on the solver's thread pool when it has one (each particle is computed alone,
/// so the same bits on any number of threads), else in order on the calling thread.
fn per_particle<const N: usize>(
    pcg: &PcgSolver,
    arrays: [&mut [DVec3]; N],
    f: impl Fn(usize, [&mut DVec3; N]) + Sync + Send,
) {
    let len = arrays[0].len();
    debug_assert!(arrays.iter().all(|a| a.len() == len));
    let run = |first: usize, mut chunk: [&mut [DVec3]; N]| {
        for k in 0..chunk[0].len() {
            f(first + k, chunk.each_mut().map(|a| &mut a[k]));
        }
    };
    #[cfg(feature = "parallel")]
    if let Some(pool) = pcg.pool() {
        // Split every array at the same chunk boundaries, halving the range over the
        // pool (no allocation).
        fn split<const N: usize>(
            first: usize,
            arrays: [&mut [DVec3]; N],
            run: &(impl Fn(usize, [&mut [DVec3]; N]) + Sync),
        ) {
            let len = arrays[0].len();
            if len <= PARTICLE_CHUNK {
                run(first, arrays);
                return;
            }
            let mid = (len / PARTICLE_CHUNK).div_ceil(2) * PARTICLE_CHUNK;
            let mut low = arrays;
            let high = low.each_mut().map(|a| {
                let (l, h) = std::mem::take(a).split_at_mut(mid);
                *a = l;
                h
            });
            rayon::join(|| split(first, low, run), || split(first + mid, high, run));
        }
        pool.install(|| split(0, arrays, &run));
        return;
    }
    #[cfg(not(feature = "parallel"))]
    let _ = pcg;
    run(0, arrays);
}

/// The first particle of `x` that is not finite, searched on the solver's thread pool
/// when it has one.
fn first_non_finite(pcg: &PcgSolver, x: &[DVec3]) -> Option<usize> {
    #[cfg(feature = "parallel")]
    if let Some(pool) = pcg.pool() {
        use rayon::prelude::*;
        return pool.install(|| {
            x.par_chunks(PARTICLE_CHUNK)
                .enumerate()
                .find_map_first(|(c, chunk)| {
                    chunk
                        .iter()
                        .position(|x| !x.is_finite())
                        .map(|k| c * PARTICLE_CHUNK + k)
                })
        });
    }
    #[cfg(not(feature = "parallel"))]
    let _ = pcg;
    x.iter().position(|x| !x.is_finite())
}

/// The fraction of [`SolverCosts::lower_bound`]'s crossover below which a PCG count is
/// taken as below the analysed crossover.
const BOUND_MARGIN: f64 = 0.99;

/// Springs per task of the report's energies on the pool.
#[cfg(feature = "parallel")]
const ENERGY_CHUNK: usize = 4096;

/// How long the pairs of a widening keep their slots.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kept {
    /// For the rest of the run (a term's fixed couplings, a caller's pairs).
    ForGood,
    /// While their blocks are used (pairs a term reported missing, see [`couplings`]).
    WhileUsed,
}

fn fixed_at(pattern: &HessianPattern, particle: usize) -> bool {
    pattern.free_index[particle] == FIXED
}

/// The assembled Newton matrix of `system` at its current positions for step `h`, as
/// dense lower-triangle triplets `(row, col, value)` over the reduced unknowns (for
/// tests and benchmarks of assembly; damping directions frozen at the current state).
#[must_use]
pub fn newton_matrix_triplets(system: &SpringSystem, h: f64) -> Vec<(usize, usize, f64)> {
    let pattern = HessianPattern::new(system);
    let mut values = vec![0.0; pattern.nnz()];
    let x = system.positions();
    let step = StepContext::new(system, h, x, x);
    let mut potential = Potential::mass_spring(system);
    potential.begin_step(&step);
    potential.add_hessian(
        &step,
        x,
        Curvature::Clamped,
        &mut HessianSink::values(&pattern, &mut values),
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
