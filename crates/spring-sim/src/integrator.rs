//! The stepping front: one [`Integrator`] choice, one [`Simulation`] that owns the system
//! and the chosen integrator's workspace, one [`StepReport`] per step.
//!
//! The implicit integrators (backward Euler, BDF2, implicit midpoint) share the Newton
//! minimization of [`crate::newton`] with their own effective step and prediction; the
//! explicit ones (symplectic Euler, velocity Verlet) take a substep count, checked against
//! or chosen from the stability bound of [`crate::stability`]; `auto` picks among them per
//! step and says why in the [`StepReport`]. The rules are in docs/integrators.md.

use crate::contact::self_contact::term::self_contact_term;
use crate::contact::self_contact::{SelfContactSettings, SelfContactStats, enable_self_contact};
use crate::contact::{
    Collider, ContactError, ContactPotential, ContactSettings, ContactStats, ContactTerm, Drive,
    project_particle, signed_distance,
};
use crate::explicit::{SymplecticEuler, VelocityVerlet};
use crate::implicit::{Bdf2, ImplicitMidpoint};
use crate::mesh::MeshClothModel;
use crate::model::{ModelError, SettingsError, SpringSystem};
use crate::newton::{BackwardEuler, NewtonSettings};
use crate::pins::{PIN_SPLIT_DEPTH, PinDriver, PinnedMotion, PinnedStepper, step_to_targets};
use crate::potential::Term;
use crate::reference::flawed_report_method::FlawedReportMethod;
use crate::report::{AutoReason, IntegratorKind, PieceEnds, StepError, StepReport};
use crate::stability::{StabilityBound, StabilityMonitor};
use sinew_math::DVec3;
use std::sync::Arc;
use std::time::Instant;

/// Which integrator advances the system, with its settings.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub enum Integrator {
    /// Backward Euler solved by Newton (the default).
    BackwardEuler(NewtonSettings),
    /// Explicit symplectic Euler with a fixed number of substeps per step.
    SymplecticEuler {
        /// Substeps per step.
        substeps: usize,
    },
    /// The lab report's flawed method, for comparison only
    /// ([`crate::reference::flawed_report_method`]).
    FlawedReportMethod,
    /// BDF2 solved by Newton (second order, little numerical damping, L-stable).
    Bdf2(NewtonSettings),
    /// Implicit midpoint solved by Newton (second order, no numerical damping).
    #[cfg_attr(feature = "serde", serde(alias = "midpoint"))]
    ImplicitMidpoint(NewtonSettings),
    /// Explicit velocity Verlet; `substeps: None` chooses the count from the stability
    /// bound every step (with its safety factor), `Some(n)` is refused (an error, the step
    /// not taken) when `n` is below the predicted stability limit.
    #[cfg_attr(feature = "serde", serde(alias = "verlet"))]
    VelocityVerlet {
        /// Substeps per step, or `None` for the stability bound's count.
        #[cfg_attr(feature = "serde", serde(default))]
        substeps: Option<usize>,
    },
    /// Explicit symplectic Euler with the substep count checked against (or, with
    /// `None`, chosen from) the stability bound, like [`Integrator::VelocityVerlet`].
    /// ([`Integrator::SymplecticEuler`] takes its count unchecked, for comparisons.)
    SymplecticEulerBounded {
        /// Substeps per step, or `None` for the stability bound's count.
        #[cfg_attr(feature = "serde", serde(default))]
        substeps: Option<usize>,
    },
    /// The cheapest integrator stable at the step (velocity Verlet at the bound's
    /// substep count, or BDF2), or backward Euler when asked to settle or when a Verlet
    /// step ran away and is redone; see [`AutoSettings`].
    Auto(AutoSettings),
}

/// Settings of [`Integrator::Auto`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct AutoSettings {
    /// Numerical damping wanted (settling to rest): always backward Euler (default false).
    pub settle: bool,
    /// Newton settings of the implicit integrators `auto` may use; their `threads` is
    /// also the thread count of the explicit steps.
    pub newton: NewtonSettings,
    /// Largest substep count `auto` accepts for velocity Verlet (default 100 000); above
    /// it BDF2 is used whatever the costs.
    pub max_substeps: usize,
    /// The cost of one implicit step in explicit substeps, assumed until an implicit step
    /// has been taken in this run (default 300; measured, docs/bench/spring-sim.md: a
    /// backward Euler or BDF2 step costs about 20 to 30 Verlet substeps on W4 and 300 to
    /// 1000 on W5 k = 1e6).
    pub implicit_cost_model: f64,
    /// Hysteresis: the other integrator must be this much cheaper to switch (default 1.25).
    pub switch_ratio: f64,
    /// Choose from wall-clock timings of this run instead of the count model (default
    /// false). The default compares costs computed from counts (springs, particles,
    /// the substeps the stability bound needs, the Newton and PCG iterations of the last
    /// implicit step, the matrix's and the factor's nonzeros; docs/integrators.md), so
    /// two identical runs make the same choices and give bitwise the same results. With
    /// `true` the costs are the fastest of the last 8 measured times of each choice: the
    /// choice then follows this machine and its load, and two identical runs can choose
    /// differently and end in different states.
    pub tune_by_timing: bool,
}

impl Default for AutoSettings {
    fn default() -> Self {
        Self {
            settle: false,
            newton: NewtonSettings::default(),
            max_substeps: 100_000,
            implicit_cost_model: 300.0,
            switch_ratio: 1.25,
            tune_by_timing: false,
        }
    }
}

impl AutoSettings {
    /// Checks the settings, naming the bad field.
    pub fn validate(&self) -> Result<(), SettingsError> {
        self.newton.validate()?;
        if self.max_substeps == 0 {
            return Err(SettingsError::new(
                "AutoSettings",
                "max_substeps",
                "must be at least 1",
            ));
        }
        if !(self.implicit_cost_model.is_finite() && self.implicit_cost_model > 0.0) {
            return Err(SettingsError::new(
                "AutoSettings",
                "implicit_cost_model",
                "must be positive and finite",
            ));
        }
        if !(self.switch_ratio.is_finite() && self.switch_ratio >= 1.0) {
            return Err(SettingsError::new(
                "AutoSettings",
                "switch_ratio",
                "must be finite and at least 1",
            ));
        }
        Ok(())
    }
}

impl Default for Integrator {
    fn default() -> Self {
        Self::BackwardEuler(NewtonSettings::default())
    }
}

#[derive(Debug)]
enum Stepper {
    BackwardEuler(Box<BackwardEuler>),
    SymplecticEuler(SymplecticEuler),
    Flawed(FlawedReportMethod),
    Bdf2(Box<Bdf2>),
    Midpoint(Box<ImplicitMidpoint>),
    Bounded(Box<BoundedExplicit>),
    Auto(Box<AutoStepper>),
}

/// An explicit integrator behind the stability bound.
#[derive(Debug)]
enum ExplicitMethod {
    SymplecticEuler(SymplecticEuler),
    Verlet(VelocityVerlet),
}

impl ExplicitMethod {
    fn kind(&self) -> IntegratorKind {
        match self {
            Self::SymplecticEuler(_) => IntegratorKind::SymplecticEuler,
            Self::Verlet(_) => IntegratorKind::VelocityVerlet,
        }
    }

    fn step(
        &mut self,
        system: &mut SpringSystem,
        h: f64,
        substeps: usize,
    ) -> Result<StepReport, StepError> {
        match self {
            Self::SymplecticEuler(se) => {
                se.set_substeps(substeps);
                se.step(system, h)
            }
            Self::Verlet(vv) => {
                vv.set_substeps(substeps);
                vv.step(system, h)
            }
        }
    }
}

/// An explicit integrator whose substep count is checked against, or chosen from, the
/// stability bound before every step.
#[derive(Debug)]
struct BoundedExplicit {
    requested: Option<usize>,
    monitor: StabilityMonitor,
    method: ExplicitMethod,
}

impl BoundedExplicit {
    fn new(
        system: &SpringSystem,
        requested: Option<usize>,
        verlet: bool,
    ) -> Result<Self, ModelError> {
        let n = requested.unwrap_or(1);
        let method = if verlet {
            ExplicitMethod::Verlet(VelocityVerlet::new(system, n)?)
        } else {
            ExplicitMethod::SymplecticEuler(SymplecticEuler::new(system, n)?)
        };
        Ok(Self {
            requested,
            monitor: StabilityMonitor::new(),
            method,
        })
    }

    fn step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        crate::model::check_time_step(h)?;
        let bound = self.monitor.update(system, h);
        let recommended = bound.substeps(h);
        let needed = bound.critical_substeps(h);
        let substeps = match self.requested {
            None => recommended,
            Some(n) if n >= needed => n,
            Some(n) => {
                return Err(StepError::BelowStabilityBound {
                    integrator: self.method.kind(),
                    substeps: n,
                    needed,
                    recommended,
                    omega_max: bound.omega_max(),
                    dt: h,
                });
            }
        };
        let mut report = self.method.step(system, h, substeps)?;
        report.omega_max = bound.omega_max();
        report.stable_substeps = recommended;
        Ok(report)
    }
}

/// The last few measured times of one choice; the estimate is their minimum (noise on a
/// shared machine only adds time).
#[derive(Clone, Copy, Debug)]
struct Timing {
    recent: [f64; 8],
    next: usize,
    samples: usize,
}

impl Default for Timing {
    fn default() -> Self {
        Self {
            recent: [f64::INFINITY; 8],
            next: 0,
            samples: 0,
        }
    }
}

impl Timing {
    fn record(&mut self, seconds: f64) {
        self.recent[self.next] = seconds;
        self.next = (self.next + 1) % self.recent.len();
        self.samples += 1;
    }

    fn estimate(&self) -> Option<f64> {
        let m = self.recent.iter().copied().fold(f64::INFINITY, f64::min);
        m.is_finite().then_some(m)
    }
}

/// Explicit steps `auto` times before trusting the explicit cost against a measured
/// implicit one (with `tune_by_timing`).
const PROBES: usize = 3;

/// The count model's costs, in multiply-adds of PCG's sparse product (the unit of
/// [`crate::SolverCosts`], about 0.54 ns here). One Verlet substep: the force pass per
/// spring and the updates per particle (measured 2.7 us per substep on W5: 600 springs,
/// 121 particles).
const SUBSTEP_PER_SPRING: f64 = 7.0;
/// See [`SUBSTEP_PER_SPRING`].
const SUBSTEP_PER_PARTICLE: f64 = 6.0;
/// One Newton iteration besides its linear solve: the gradient, the Hessian's assembly
/// and the line search's energy changes, per spring and per particle (about 31 us per
/// iteration on W4 besides PCG).
const NEWTON_PER_SPRING: f64 = 80.0;
/// See [`NEWTON_PER_SPRING`].
const NEWTON_PER_PARTICLE: f64 = 40.0;
/// One implicit step besides its Newton iterations: the first guess's two evaluations of
/// `g`, the terms' per-step state and the energies of the report, per spring.
const STEP_PER_SPRING: f64 = 20.0;

/// The count model's cost of one Verlet substep of `system`.
fn substep_cost(system: &SpringSystem) -> f64 {
    SUBSTEP_PER_SPRING * system.springs().len() as f64 + SUBSTEP_PER_PARTICLE * system.len() as f64
}

/// The costs `auto` compared for a step, and in what unit.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct AutoCosts {
    /// Velocity Verlet at the stability bound's substep count.
    pub explicit: f64,
    /// One BDF2 step.
    pub implicit: f64,
    /// True: seconds, measured (`AutoSettings::tune_by_timing`); false: the count
    /// model's multiply-adds.
    pub timed: bool,
    /// Whether the implicit cost comes from an implicit step of this run (false: the
    /// prior `AutoSettings::implicit_cost_model` substeps).
    pub implicit_observed: bool,
}

/// The `auto` integrator: velocity Verlet at the bound's substep count or BDF2, whichever
/// costs less per step (by the count model, or measured when asked), or backward Euler
/// when asked to settle or to redo a Verlet step that ran away.
#[derive(Debug)]
struct AutoStepper {
    settings: AutoSettings,
    monitor: StabilityMonitor,
    verlet: VelocityVerlet,
    bdf2: Option<Box<Bdf2>>,
    settle: Option<Box<BackwardEuler>>,
    current: Option<IntegratorKind>,
    /// The count model's cost of the last implicit step (`None` before one).
    implicit_counted: Option<f64>,
    /// Seconds per explicit substep (`tune_by_timing`).
    substep_time: Timing,
    /// Seconds per implicit step (`tune_by_timing`).
    implicit_time: Timing,
    /// Whether contact or self-contact is set: then every step is implicit (BDF2, or
    /// backward Euler when settling), the integrators with the guaranteed barriers.
    contact: bool,
    /// The contact and self-contact terms, until BDF2 (built at its first step) takes
    /// them.
    pending_terms: Vec<Box<dyn Term>>,
    /// The time the next step starts at, for the implicit integrators' terms.
    time: f64,
    /// Backward Euler, which redoes a step whose Verlet attempt ran away (built at the
    /// first such step).
    fallback: Option<Box<BackwardEuler>>,
    /// The pieces of the last step, while recording: copied from the implicit
    /// integrator that took it, or the Verlet step's end state.
    pieces: Option<PieceEnds>,
}

impl AutoStepper {
    fn new(system: &SpringSystem, settings: AutoSettings) -> Result<Self, ModelError> {
        settings.validate()?;
        let settle = if settings.settle {
            Some(Box::new(BackwardEuler::new(system, settings.newton)?))
        } else {
            None
        };
        Ok(Self {
            settings,
            monitor: StabilityMonitor::new(),
            verlet: {
                let mut verlet = VelocityVerlet::new(system, 1)?;
                verlet.keep_start_if_runaway = true;
                // One thread setting for every step `auto` takes (0, the default, is
                // what the stepper starts with).
                if settings.newton.threads != 0 {
                    verlet.set_threads(system, settings.newton.threads)?;
                }
                verlet
            },
            bdf2: None,
            settle,
            current: None,
            implicit_counted: None,
            substep_time: Timing::default(),
            implicit_time: Timing::default(),
            contact: false,
            pending_terms: Vec::new(),
            time: 0.0,
            fallback: None,
            pieces: None,
        })
    }

    /// Starts or stops recording the pieces of each step (every implicit workspace
    /// records, those built later too; see [`Simulation::record_piece_ends`]).
    fn record_piece_ends(&mut self, on: bool) {
        if on {
            self.pieces.get_or_insert_with(PieceEnds::default);
        } else {
            self.pieces = None;
        }
        for newton in [
            self.settle.as_deref_mut(),
            self.fallback.as_deref_mut(),
            self.bdf2.as_deref_mut().map(Bdf2::newton_mut),
        ]
        .into_iter()
        .flatten()
        {
            newton.record_piece_ends(on);
        }
    }

    /// The last step's pieces into `record` (emptied at the step's start by
    /// [`Simulation`]), when recording: `newton`'s, the workspace that took the step, or
    /// (`None`) the Verlet step's end state.
    fn note_pieces(
        record: &mut Option<PieceEnds>,
        newton: Option<&BackwardEuler>,
        end: f64,
        system: &SpringSystem,
    ) {
        let Some(record) = record else {
            return;
        };
        match newton.and_then(BackwardEuler::piece_ends) {
            Some(taken) => record.extend_from(taken),
            None => record.push(end, system.positions()),
        }
    }

    /// The workspace of the implicit integrator that takes every step once contact is
    /// set: backward Euler when settling, else BDF2 (`None` before BDF2 is built).
    fn contact_workspace_mut(&mut self) -> Option<&mut BackwardEuler> {
        match (&mut self.settle, &mut self.bdf2) {
            (Some(be), _) => Some(&mut **be),
            (None, Some(b)) => Some(b.newton_mut()),
            (None, None) => None,
        }
    }

    /// Adds a contact or self-contact term to the implicit integrator that will take
    /// every step from now on: backward Euler when settling, else BDF2 (now, or when it
    /// is built). A second term of the same kind is [`ContactError::AddedTwice`].
    fn add_contact_term(
        &mut self,
        term: Box<dyn Term>,
        what: &'static str,
    ) -> Result<(), ContactError> {
        if self.pending_terms.iter().any(|t| t.name() == what) {
            return Err(ContactError::AddedTwice { what });
        }
        match self.contact_workspace_mut() {
            Some(newton) => {
                crate::contact::refuse_second(newton, what)?;
                newton.add_term(term);
            }
            None => self.pending_terms.push(term),
        }
        self.contact = true;
        Ok(())
    }

    /// The contact term: in the workspace that takes every step, or still waiting for it.
    fn contact_term_mut(&mut self) -> Option<&mut ContactTerm> {
        let is_contact = |t: &dyn Term| {
            let any: &dyn std::any::Any = t;
            any.is::<ContactTerm>()
        };
        if let Some(k) = self
            .pending_terms
            .iter()
            .position(|t| is_contact(t.as_ref()))
        {
            let any: &mut dyn std::any::Any = self.pending_terms[k].as_mut();
            return any.downcast_mut::<ContactTerm>();
        }
        self.contact_workspace_mut()?.term_mut::<ContactTerm>()
    }

    /// Sets the time the next step starts at.
    fn set_time(&mut self, time: f64) {
        self.time = time;
        if let Some(be) = &mut self.settle {
            be.set_time(time);
        }
        if let Some(b) = &mut self.bdf2 {
            b.newton_mut().set_time(time);
        }
        if let Some(be) = &mut self.fallback {
            be.set_time(time);
        }
    }

    fn reset_history(&mut self) {
        if let Some(b) = &mut self.bdf2 {
            b.reset_history();
        }
        if let Some(b) = &mut self.settle {
            b.reset_history();
        }
        if let Some(b) = &mut self.fallback {
            b.reset_history();
        }
    }

    /// The costs of the two choices for a step with `needed` Verlet substeps, by the
    /// count model: `needed` substeps of [`substep_cost`] against the last implicit
    /// step's counted cost (before one, `implicit_cost_model` substeps).
    fn counted_costs(&self, system: &SpringSystem, needed: usize) -> AutoCosts {
        let substep = substep_cost(system);
        let (implicit, implicit_observed) = match self.implicit_counted {
            Some(c) => (c, true),
            None => (self.settings.implicit_cost_model * substep, false),
        };
        AutoCosts {
            explicit: needed as f64 * substep,
            implicit,
            timed: false,
            implicit_observed,
        }
    }

    /// The costs by the measured times (`tune_by_timing`); `None` when an explicit probe
    /// must be timed first (see docs/integrators.md).
    fn timed_costs(&self, needed: usize) -> Option<AutoCosts> {
        let costs = |explicit, implicit, implicit_observed| AutoCosts {
            explicit,
            implicit,
            timed: true,
            implicit_observed,
        };
        match (self.substep_time.estimate(), self.implicit_time.estimate()) {
            // Fewer than PROBES explicit timings: time another explicit step (safe, at
            // the bound's count), so one preempted step cannot decide for good.
            (Some(_), Some(_)) if self.substep_time.samples < PROBES => None,
            (Some(t), Some(ti)) => Some(costs(needed as f64 * t, ti, true)),
            (Some(t), None) => Some(costs(
                needed as f64 * t,
                self.settings.implicit_cost_model * t,
                false,
            )),
            // An implicit step was timed but no explicit one: time one explicit step
            // (stable at the bound's count, so the probe is safe).
            (None, Some(_)) => None,
            (None, None) => Some(costs(
                needed as f64,
                self.settings.implicit_cost_model,
                false,
            )),
        }
    }

    /// The choice for a step of `h` with `needed` substeps for Verlet, and the costs it
    /// was made from.
    fn choose(&self, system: &SpringSystem, needed: usize) -> (AutoReason, Option<AutoCosts>) {
        if needed > self.settings.max_substeps {
            return (AutoReason::SubstepCap, None);
        }
        let costs = if self.settings.tune_by_timing {
            match self.timed_costs(needed) {
                Some(c) => c,
                None => return (AutoReason::ExplicitCheapest, None),
            }
        } else {
            self.counted_costs(system, needed)
        };
        let (explicit, implicit) = (costs.explicit, costs.implicit);
        let ratio = self.settings.switch_ratio;
        let explicit_wins = match self.current {
            Some(IntegratorKind::Bdf2) => explicit * ratio < implicit,
            Some(IntegratorKind::VelocityVerlet) => explicit < implicit * ratio,
            _ => explicit <= implicit,
        };
        let reason = if explicit_wins {
            AutoReason::ExplicitCheapest
        } else {
            AutoReason::ImplicitCheaper
        };
        (reason, Some(costs))
    }

    /// The count model's cost of the implicit step `report` (Newton iterations, PCG
    /// iterations, the direct solve's modelled cost when it ran) on `newton`'s pattern.
    fn implicit_step_cost(
        system: &SpringSystem,
        newton: &mut BackwardEuler,
        report: &StepReport,
    ) -> Result<f64, ModelError> {
        let springs = system.springs().len() as f64;
        let particles = system.len() as f64;
        let pattern = newton.pattern();
        let cg_iteration = 2.0 * pattern.nnz() as f64 + 9.0 * pattern.dim() as f64;
        let direct_solves = if report.linear_solver == Some(crate::linear::LinearSolverKind::Direct)
        {
            report.iterations.saturating_sub(report.direct_failures) as f64
        } else {
            0.0
        };
        let direct = if direct_solves > 0.0 {
            direct_solves * newton.solver_costs()?.direct_cost()
        } else {
            0.0
        };
        Ok(STEP_PER_SPRING * springs
            + report.iterations as f64
                * (NEWTON_PER_SPRING * springs + NEWTON_PER_PARTICLE * particles)
            + report.linear_iterations as f64 * cg_iteration
            + direct)
    }

    fn step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        crate::model::check_time_step(h)?;
        let end = self.time + h;
        if let Some(be) = &mut self.settle {
            let mut report = be.step(system, h)?;
            report.auto_reason = Some(AutoReason::Settle);
            Self::note_pieces(&mut self.pieces, Some(be), end, system);
            return Ok(report);
        }
        let bound = self.monitor.update(system, h);
        let needed = bound.substeps(h);
        let (mut reason, costs) = if self.contact {
            (AutoReason::Contact, None)
        } else {
            self.choose(system, needed)
        };
        let timing = self.settings.tune_by_timing;
        // The clock is read only when asked to tune by it.
        let started = timing.then(Instant::now);
        let mut explicit = None;
        if reason == AutoReason::ExplicitCheapest {
            self.verlet.set_substeps(needed);
            let report = self.verlet.step(system, h)?;
            // A run-away step left the system at its start: it is taken implicitly.
            if crate::explicit::ran_away(&report.energy_before, &report.energy_after) {
                reason = AutoReason::ExplicitUnstable;
            } else {
                explicit = Some(report);
            }
        }
        let mut report = if let Some(report) = explicit {
            if let Some(started) = started {
                self.substep_time
                    .record(started.elapsed().as_secs_f64() / needed as f64);
            }
            self.current = Some(IntegratorKind::VelocityVerlet);
            report
        } else if reason == AutoReason::ExplicitUnstable {
            // Backward Euler, not BDF2: a descent with an energy inequality, from a state
            // this far from equilibrium (when BDF2 restarted with an undamped midpoint
            // step there, Newton took hundreds of iterations and split pieces where
            // backward Euler's damped step takes tens: docs/integrators.md, `auto`).
            if self.fallback.is_none() {
                let mut be = Box::new(BackwardEuler::new(system, self.settings.newton)?);
                be.set_time(self.time);
                be.record_piece_ends(self.pieces.is_some());
                self.fallback = Some(be);
            }
            let be = self.fallback.as_mut().expect("built above");
            if self.current != Some(IntegratorKind::BackwardEuler) {
                // Coming from another integrator: the first guess's history is stale.
                be.reset_history();
            }
            let report = be.step(system, h)?;
            if let Some(started) = started {
                self.implicit_time.record(started.elapsed().as_secs_f64());
            }
            self.implicit_counted = Some(Self::implicit_step_cost(system, be, &report)?);
            self.current = Some(IntegratorKind::BackwardEuler);
            report
        } else {
            if self.bdf2.is_none() {
                let mut bdf2 = Box::new(Bdf2::new(system, self.settings.newton)?);
                bdf2.newton_mut().set_time(self.time);
                bdf2.newton_mut().record_piece_ends(self.pieces.is_some());
                for term in self.pending_terms.drain(..) {
                    bdf2.newton_mut().add_term(term);
                }
                self.bdf2 = Some(bdf2);
            }
            let bdf2 = self.bdf2.as_mut().expect("built above");
            if self.current != Some(IntegratorKind::Bdf2) {
                // Coming from Verlet or a backward Euler redo: the BDF2 history is stale.
                bdf2.reset_history();
            }
            let report = bdf2.step(system, h)?;
            if let Some(started) = started {
                self.implicit_time.record(started.elapsed().as_secs_f64());
            }
            self.implicit_counted = Some(Self::implicit_step_cost(
                system,
                bdf2.newton_mut(),
                &report,
            )?);
            self.current = Some(IntegratorKind::Bdf2);
            report
        };
        let newton = match self.current {
            Some(IntegratorKind::BackwardEuler) => self.fallback.as_deref(),
            Some(IntegratorKind::Bdf2) => self.bdf2.as_deref().map(Bdf2::newton),
            _ => None,
        };
        Self::note_pieces(&mut self.pieces, newton, end, system);
        report.auto_reason = Some(reason);
        report.auto_costs = costs;
        report.omega_max = bound.omega_max();
        report.stable_substeps = needed;
        Ok(report)
    }
}

/// A system and the integrator that advances it.
///
/// With [`Integrator::Auto`] each step says which integrator it chose and why:
///
/// ```
/// use sinew_spring_sim::{AutoSettings, ClothGrid, Integrator, IntegratorKind, Simulation};
/// let cloth = ClothGrid::lab().build().unwrap();
/// let corners = [cloth.positions()[0], cloth.positions()[10]];
/// let mut sim = Simulation::new(cloth, Integrator::Auto(AutoSettings::default())).unwrap();
/// for _ in 0..30 {
///     let report = sim.step(1.0 / 60.0).unwrap();
///     assert!(report.auto_reason.is_some());
///     assert!(matches!(
///         report.integrator,
///         IntegratorKind::VelocityVerlet | IntegratorKind::Bdf2 | IntegratorKind::BackwardEuler
///     ));
/// }
/// // The cloth has fallen (gravity), its pinned corners have not moved.
/// let system = sim.system();
/// assert!(system.positions()[60].y < 1.5);
/// assert_eq!([system.positions()[0], system.positions()[10]], corners);
/// assert!((sim.time() - 0.5).abs() < 1e-12);
/// ```
#[derive(Debug)]
pub struct Simulation {
    system: SpringSystem,
    stepper: Stepper,
    /// Time since the start (the sum of the steps taken), the time kinematic colliders
    /// are posed at.
    time: f64,
    contact: Option<Contact>,
    /// The fingerprint of the system the stepper was built for: [`Simulation::system_mut`]
    /// allows replacing the whole system, and `auto` builds BDF2 lazily on whatever
    /// system it is given, so the check is made here once per step as well.
    topology: crate::model::Topology,
    /// Rigid motions of pinned groups, when set ([`Simulation::set_pinned_motion`]).
    pins: Option<PinDriver>,
}

/// The colliders of a simulation and how they act (see [`Simulation::set_contact`]).
#[derive(Debug)]
struct Contact {
    colliders: Vec<Collider>,
    settings: ContactSettings,
    /// The barrier term's statistics (backward Euler), or `None` for the explicit
    /// projection.
    stats: Option<Arc<ContactStats>>,
    /// Particle-collider projections applied by the explicit integrators so far.
    projections: usize,
    /// Positions for the admissibility check before a step.
    scratch: Vec<DVec3>,
}

impl Simulation {
    /// Builds the integrator's workspace for `system`.
    pub fn new(system: SpringSystem, integrator: Integrator) -> Result<Self, ModelError> {
        let stepper = match integrator {
            Integrator::BackwardEuler(settings) => {
                Stepper::BackwardEuler(Box::new(BackwardEuler::new(&system, settings)?))
            }
            Integrator::SymplecticEuler { substeps } => {
                Stepper::SymplecticEuler(SymplecticEuler::new(&system, substeps)?)
            }
            Integrator::FlawedReportMethod => Stepper::Flawed(FlawedReportMethod::new(&system)),
            Integrator::Bdf2(settings) => Stepper::Bdf2(Box::new(Bdf2::new(&system, settings)?)),
            Integrator::ImplicitMidpoint(settings) => {
                Stepper::Midpoint(Box::new(ImplicitMidpoint::new(&system, settings)?))
            }
            Integrator::VelocityVerlet { substeps } => {
                Stepper::Bounded(Box::new(BoundedExplicit::new(&system, substeps, true)?))
            }
            Integrator::SymplecticEulerBounded { substeps } => {
                Stepper::Bounded(Box::new(BoundedExplicit::new(&system, substeps, false)?))
            }
            Integrator::Auto(settings) => {
                Stepper::Auto(Box::new(AutoStepper::new(&system, settings)?))
            }
        };
        Ok(Self {
            topology: system.topology(),
            system,
            stepper,
            time: 0.0,
            contact: None,
            pins: None,
        })
    }

    /// A simulation of a mesh cloth ([`crate::MeshCloth::build`]): its system stepped by
    /// `integrator`, with the dihedral bending term (for [`crate::Bending::Dihedral`]) in
    /// the integrator's potential, as [`MeshClothModel::backward_euler`] adds it. Add
    /// self-contact with [`Self::set_self_contact`] and the model's triangles.
    ///
    /// The dihedral term is a term of the implicit integrators' potential: with the
    /// explicit integrators, `auto` or the flawed reference method it is an error naming
    /// the integrator (bending springs, [`crate::Bending::Springs`], run in every
    /// integrator).
    ///
    /// ```
    /// use sinew_spring_sim::contact::self_contact::SelfContactSettings;
    /// use sinew_spring_sim::{Bending, ClothGrid, DVec3, Integrator, Material, MeshCloth};
    /// use sinew_spring_sim::{NewtonSettings, Simulation, TriangleMesh};
    ///
    /// // An 8 x 8 sheet held along one edge, with dihedral bending and self-contact.
    /// let grid = ClothGrid { size: 8, spacing: 0.05, ..ClothGrid::lab() };
    /// let (positions, triangles) = grid.sheet(DVec3::X, DVec3::Z, 0);
    /// let mesh = TriangleMesh::new(positions, triangles)?;
    /// let cloth = MeshCloth {
    ///     areal_density: 0.2,
    ///     material: Material::earth(),
    ///     bending: Bending::Dihedral { stiffness: 1e-3 },
    ///     fixed: (0..8).collect(),
    /// };
    /// let model = cloth.build(&mesh)?;
    /// let mut sim =
    ///     Simulation::from_mesh_cloth(&model, Integrator::Bdf2(NewtonSettings::default()))?;
    /// let settings = SelfContactSettings { dhat: 1e-3, ..SelfContactSettings::default() };
    /// sim.set_self_contact(&model.triangles, settings)?;
    /// for _ in 0..10 {
    ///     let report = sim.step(1.0 / 60.0)?;
    ///     assert!(report.residual <= report.tolerance);
    ///     let meeting = sinew_exact::intersecting_pairs(sim.system().positions(), &model.triangles);
    ///     assert!(meeting.is_empty());
    /// }
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn from_mesh_cloth(
        model: &MeshClothModel,
        integrator: Integrator,
    ) -> Result<Self, ModelError> {
        let mut sim = Self::new(model.system.clone(), integrator)?;
        if model.bending.is_some() {
            let Some(newton) = sim.newton_workspace_mut() else {
                return Err(ModelError::BadParameter {
                    name: "integrator",
                    reason: "only backward Euler, BDF2 and implicit midpoint have a place for the dihedral bending term (the explicit integrators and auto's explicit steps take springs only, the flawed reference method its own springs): choose one of them, or bending springs",
                });
            };
            model.add_bending(newton)?;
        }
        Ok(sim)
    }

    /// Adds self-contact of the cloth with itself, its surface the given `triangles`
    /// (a mesh cloth's [`MeshClothModel::triangles`], a grid's
    /// [`crate::ClothGrid::triangles`]): IPC's barrier between every vertex and triangle
    /// and every two edges that share no vertex, with the line search capped by
    /// continuous collision detection, so no accepted state (and no piece's end state)
    /// has two triangles passing through each other
    /// ([`crate::contact::self_contact::enable_self_contact`], docs/contact.md). Returns
    /// the term's statistics. Backward Euler, BDF2 and implicit midpoint; with `auto`,
    /// every step from then on is implicit (BDF2, or backward Euler when settling;
    /// `AutoReason::Contact`), as with colliders. The explicit integrators and the flawed
    /// reference method are [`ContactError::SelfContactUnsupported`]. The settings, the
    /// triangles and the current state are checked (the error names the setting, the
    /// triangle or the two primitives); a second call is [`ContactError::AddedTwice`].
    pub fn set_self_contact(
        &mut self,
        triangles: &[[usize; 3]],
        settings: SelfContactSettings,
    ) -> Result<Arc<SelfContactStats>, ContactError> {
        let integrator = self.integrator_name();
        let newton = match &mut self.stepper {
            Stepper::BackwardEuler(be) => &mut **be,
            Stepper::Bdf2(b) => b.newton_mut(),
            Stepper::Midpoint(m) => m.newton_mut(),
            Stepper::Auto(a) => {
                // Every step is implicit from now on (AutoReason::Contact), as with
                // colliders.
                let (term, stats) = self_contact_term(&self.system, triangles, settings)?;
                a.add_contact_term(term, "self-contact")?;
                return Ok(stats);
            }
            _ => return Err(ContactError::SelfContactUnsupported { integrator }),
        };
        enable_self_contact(newton, &self.system, triangles, settings)
    }

    /// The integrator's name, for messages.
    fn integrator_name(&self) -> &'static str {
        match &self.stepper {
            Stepper::BackwardEuler(_) => "backward Euler",
            Stepper::SymplecticEuler(_) => "symplectic Euler",
            Stepper::Flawed(_) => "the flawed reference method",
            Stepper::Bdf2(_) => "BDF2",
            Stepper::Midpoint(_) => "implicit midpoint",
            Stepper::Bounded(b) => match b.method {
                ExplicitMethod::Verlet(_) => "velocity Verlet",
                ExplicitMethod::SymplecticEuler(_) => "symplectic Euler (bounded)",
            },
            Stepper::Auto(_) => "auto",
        }
    }

    /// The implicit stepper, for moving pins (`None` for the explicit integrators and
    /// `auto`).
    fn pinned_stepper(&mut self) -> Option<&mut dyn PinnedStepper> {
        match &mut self.stepper {
            Stepper::BackwardEuler(be) => Some(&mut **be),
            Stepper::Bdf2(b) => Some(&mut **b),
            Stepper::Midpoint(m) => Some(&mut **m),
            _ => None,
        }
    }

    /// Moves groups of pinned particles along rigid motions from now on (their current
    /// positions are the motions' time 0), replacing motions set before: every step puts
    /// them where their motion has them at the step's end, with the velocity of that
    /// move, after checking that the move (free particles held) is safe for self-contact
    /// and cutting the step into pieces when it is not (`crate::pins`). Needs backward
    /// Euler, BDF2 or implicit midpoint: the explicit integrators and `auto` are an
    /// error, as is a particle that is not pinned, out of range or in two groups, or a
    /// non-finite field (the error names the particle).
    pub fn set_pinned_motion(&mut self, motions: Vec<PinnedMotion>) -> Result<(), ModelError> {
        if self.pinned_stepper().is_none() {
            return Err(ModelError::BadParameter {
                name: "integrator",
                reason: "moving pins need an implicit integrator (backward Euler, BDF2 or implicit midpoint)",
            });
        }
        self.pins = Some(PinDriver::new(&self.system, motions)?);
        Ok(())
    }

    /// The rigid motions of the pinned groups, if set.
    #[must_use]
    pub fn pinned_motion(&self) -> Option<&PinDriver> {
        self.pins.as_ref()
    }

    /// Advances by `dt` with the pinned particles of `targets` moved to the given
    /// positions at the step's end (other pinned particles follow their motion, if one
    /// is set, or stay still), in pieces of the move when the whole move is not safe
    /// for self-contact. Needs backward Euler, BDF2 or implicit midpoint. On error the
    /// system is unchanged.
    pub fn step_to(
        &mut self,
        dt: f64,
        targets: &[(usize, DVec3)],
    ) -> Result<StepReport, StepError> {
        if self.pinned_stepper().is_none() {
            return Err(ModelError::BadParameter {
                name: "integrator",
                reason: "moving pins need an implicit integrator (backward Euler, BDF2 or implicit midpoint)",
            }
            .into());
        }
        self.step_inner(dt, Some(targets))
    }

    /// Adds contact with `colliders` (validated; the error names the collider or the
    /// setting). With backward Euler, BDF2 and implicit midpoint, contact is IPC's barrier
    /// and lagged friction in the minimization, with the line search capped by the time
    /// of impact, so no accepted state has a particle inside a collider (docs/contact.md;
    /// for the midpoint the barrier acts on the end state). With the explicit
    /// integrators ([`Integrator::SymplecticEuler`], [`Integrator::VelocityVerlet`],
    /// [`Integrator::SymplecticEulerBounded`]) every particle is projected out of every
    /// collider after each step ([`crate::contact::projection`]): **not guaranteed**.
    /// With `auto`, every step from then on is implicit (BDF2, or backward Euler when
    /// settling; `AutoReason::Contact`), so the guarantee holds. The flawed reference
    /// method has no contact: an error. Contact can be set once ([`ContactError::AddedTwice`]).
    pub fn set_contact(
        &mut self,
        colliders: Vec<Collider>,
        settings: ContactSettings,
    ) -> Result<(), ContactError> {
        if self.contact.is_some() {
            return Err(ContactError::AddedTwice { what: "contact" });
        }
        crate::contact::check_contact_setup(
            &colliders,
            &settings,
            self.time,
            self.system.positions(),
            self.system.fixed(),
        )?;
        let term = |time| -> Result<(ContactTerm, Arc<ContactStats>), ContactError> {
            let term = ContactTerm::new(ContactPotential::new(colliders.clone(), settings, time)?);
            let stats = term.stats();
            Ok((term, stats))
        };
        let newton = match &mut self.stepper {
            Stepper::BackwardEuler(be) => Some(&mut **be),
            Stepper::Bdf2(b) => Some(b.newton_mut()),
            Stepper::Midpoint(m) => Some(m.newton_mut()),
            Stepper::SymplecticEuler(_) | Stepper::Bounded(_) => None,
            Stepper::Auto(a) => {
                // Every step is implicit from now on (AutoReason::Contact): the explicit
                // projection is not guaranteed, the barrier is.
                let (t, stats) = term(self.time)?;
                a.add_contact_term(Box::new(t), "contact")?;
                self.contact = Some(Contact {
                    colliders,
                    settings,
                    stats: Some(stats),
                    projections: 0,
                    scratch: Vec::new(),
                });
                return Ok(());
            }
            Stepper::Flawed(_) => {
                return Err(ContactError::Unsupported {
                    what: "the flawed reference method",
                });
            }
        };
        let stats = match newton {
            Some(newton) => {
                let (t, stats) = term(self.time)?;
                newton.add_term(Box::new(t));
                Some(stats)
            }
            None => None,
        };
        self.contact = Some(Contact {
            colliders,
            settings,
            stats,
            projections: 0,
            scratch: Vec::new(),
        });
        Ok(())
    }

    /// Drives collider `index` from the current time on ([`Drive`]): its pose now is
    /// kept and its motion changes, for this and every later step until it is driven
    /// again. A collider on an animated body is driven before each step with
    /// [`Drive::To`] its pose at the step's end. The guarantee of the implicit
    /// integrators holds for a driven collider as for any other: the barrier and the
    /// time-of-impact cap see it where its new motion puts it.
    ///
    /// # Errors
    /// [`ContactError::NoSuchCollider`] for an index out of range (a count of 0 without
    /// contact) and the errors of [`Collider::driven`] naming the index; nothing
    /// changes then.
    ///
    /// ```
    /// use sinew_spring_sim::contact::{Collider, ContactSettings, Drive, Shape, signed_distance};
    /// use sinew_spring_sim::{ClothGrid, DVec3, Integrator, Material, NewtonSettings};
    /// use sinew_spring_sim::{Simulation, SpringSystem};
    ///
    /// // A forearm: a capsule from the elbow to the wrist, turning up about the elbow by
    /// // 0.6 rad a second (an animation's pose at time t).
    /// let forearm = |t: f64| {
    ///     let elbow = DVec3::new(-0.25, -0.035, 0.0);
    ///     let wrist = elbow + 0.45 * DVec3::new((0.6 * t).cos(), (0.6 * t).sin(), 0.0);
    ///     Shape::Capsule { a: elbow, b: wrist, radius: 0.03 }
    /// };
    /// // A 9 x 9 sheet, 0.4 m wide, lying 5 mm above it.
    /// let material = Material { stiffness: 1000.0, damping: 0.1, gravity: DVec3::new(0.0, -9.81, 0.0) };
    /// let origin = DVec3::new(-0.2, 0.0, -0.2);
    /// let grid = ClothGrid { size: 9, spacing: 0.05, origin, mass: 5e-4, material, fixed: vec![] };
    /// let newton = Integrator::BackwardEuler(NewtonSettings::default());
    /// let mut sim = Simulation::new(SpringSystem::cloth(&grid)?, newton)?;
    /// let grip = ContactSettings { mu: 0.5, ..ContactSettings::default() };
    /// sim.set_contact(vec![Collider::fixed(forearm(0.0))], grip)?;
    /// let h = 1.0 / 60.0;
    /// for _ in 0..60 {
    ///     // Where the animation puts the forearm at the step's end.
    ///     let target = forearm(sim.time() + h);
    ///     sim.drive_collider(0, &Drive::To { target, duration: h })?;
    ///     sim.step(h)?;
    ///     for x in sim.system().positions() {
    ///         assert!(signed_distance(&target, *x, 0.0).distance > 0.0);
    ///     }
    /// }
    /// // Carried: the sheet lies on the forearm, risen with it.
    /// let top = sim.system().positions().iter().map(|x| x.y).fold(f64::MIN, f64::max);
    /// assert!(top > 0.1, "highest particle at {top}");
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn drive_collider(&mut self, index: usize, drive: &Drive) -> Result<(), ContactError> {
        let time = self.time;
        let Some(contact) = &mut self.contact else {
            return Err(ContactError::NoSuchCollider { index, count: 0 });
        };
        // Driven once (the list is left as it was on an error); the term holds the same
        // colliders and takes the driven one as it is.
        let driven =
            crate::contact::collider::drive_in_list(&mut contact.colliders, index, time, drive)?;
        if let Some(term) = self.contact_term_mut() {
            term.put_driven(index, driven);
        }
        Ok(())
    }

    /// The implicit integrators' contact term, wherever it is held.
    fn contact_term_mut(&mut self) -> Option<&mut ContactTerm> {
        match &mut self.stepper {
            Stepper::BackwardEuler(be) => be.term_mut::<ContactTerm>(),
            Stepper::Bdf2(b) => b.newton_mut().term_mut::<ContactTerm>(),
            Stepper::Midpoint(m) => m.newton_mut().term_mut::<ContactTerm>(),
            Stepper::Auto(a) => a.contact_term_mut(),
            Stepper::SymplecticEuler(_) | Stepper::Bounded(_) | Stepper::Flawed(_) => None,
        }
    }

    /// The colliders, if contact is set.
    #[must_use]
    pub fn colliders(&self) -> &[Collider] {
        self.contact.as_ref().map_or(&[], |c| &c.colliders)
    }

    /// The contact settings, if contact is set.
    #[must_use]
    pub fn contact_settings(&self) -> Option<&ContactSettings> {
        self.contact.as_ref().map(|c| &c.settings)
    }

    /// The barrier stiffness `kappa` of the implicit integrators' contact term (`None` without
    /// one; 0 before the first step).
    #[must_use]
    pub fn contact_kappa(&self) -> Option<f64> {
        self.contact
            .as_ref()
            .and_then(|c| c.stats.as_ref())
            .map(|s| s.kappa())
    }

    /// Particle-collider projections the explicit integrators applied so far.
    #[must_use]
    pub fn contact_projections(&self) -> usize {
        self.contact.as_ref().map_or(0, |c| c.projections)
    }

    /// The smallest signed distance (minus the thickness) from a free particle to a
    /// collider posed at the current time, and the number of particle-collider pairs
    /// closer than `dhat`; `None` without contact. Computed afresh (`O(particles x
    /// colliders)`), independently of the integrator.
    #[must_use]
    pub fn contact_distances(&self) -> Option<(f64, usize)> {
        let contact = self.contact.as_ref()?;
        let mut min = f64::INFINITY;
        let mut pairs = 0;
        for c in &contact.colliders {
            let shape = c.at(self.time);
            for (x, fixed) in self.system.positions().iter().zip(self.system.fixed()) {
                if *fixed {
                    continue;
                }
                let d = signed_distance(&shape, *x, contact.settings.thickness).distance;
                min = min.min(d);
                if d < contact.settings.dhat {
                    pairs += 1;
                }
            }
        }
        Some((min, pairs))
    }

    /// Time since the start: the sum of the steps taken.
    #[must_use]
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Advances by `dt` (moving the pinned groups along their motions, if set). On error
    /// the system is unchanged.
    pub fn step(&mut self, dt: f64) -> Result<StepReport, StepError> {
        self.step_inner(dt, None)
    }

    /// The Newton workspace of backward Euler, BDF2 or the implicit midpoint rule.
    fn newton_workspace_mut(&mut self) -> Option<&mut BackwardEuler> {
        match &mut self.stepper {
            Stepper::BackwardEuler(be) => Some(be),
            Stepper::Bdf2(b) => Some(b.newton_mut()),
            Stepper::Midpoint(m) => Some(m.newton_mut()),
            _ => None,
        }
    }

    /// The Newton workspace of backward Euler, BDF2 or the implicit midpoint rule (`None`
    /// for the others), with its records of the last step
    /// ([`BackwardEuler::objective_trace`], [`BackwardEuler::step_objective_traces`],
    /// [`BackwardEuler::piece_ends`]).
    #[must_use]
    pub fn newton_workspace(&self) -> Option<&BackwardEuler> {
        match &self.stepper {
            Stepper::BackwardEuler(be) => Some(be),
            Stepper::Bdf2(b) => Some(b.newton()),
            Stepper::Midpoint(m) => Some(m.newton()),
            _ => None,
        }
    }

    /// Starts (`true`) or stops recording the end state of every piece of each step
    /// ([`PieceEnds`]): what an independent check of the collider guarantees needs, since
    /// a step split in pieces promises them for each piece's straight path. Backward
    /// Euler, BDF2, the implicit midpoint rule and `auto` (the pieces of whichever
    /// integrator took the step; a Verlet step is one piece, its end state); the
    /// explicit integrators, whose projection promises nothing, are refused.
    pub fn record_piece_ends(&mut self, on: bool) -> Result<(), ModelError> {
        if let Stepper::Auto(a) = &mut self.stepper {
            a.record_piece_ends(on);
            return Ok(());
        }
        let newton = match self.newton_workspace_mut() {
            Some(newton) => newton,
            None => {
                return Err(ModelError::BadParameter {
                    name: "integrator",
                    reason: "piece ends are recorded by backward Euler, BDF2, the implicit midpoint rule and auto only",
                });
            }
        };
        newton.record_piece_ends(on);
        Ok(())
    }

    /// Forgets the last step's records, so a step refused before its integrator runs
    /// leaves none (each implicit step starts its own afresh; `auto`'s is kept here).
    fn clear_step_records(&mut self) {
        if let Stepper::Auto(a) = &mut self.stepper
            && let Some(record) = &mut a.pieces
        {
            record.clear();
        }
        if let Some(newton) = self.newton_workspace_mut() {
            newton.clear_step_records();
        }
    }

    /// The end states of the pieces of the last step, in order (one for a step taken
    /// whole, the last being the step's end state; none after a refused step); `None`
    /// when not recording ([`Self::record_piece_ends`]).
    #[must_use]
    pub fn piece_ends(&self) -> Option<&PieceEnds> {
        if let Stepper::Auto(a) = &self.stepper {
            return a.pieces.as_ref();
        }
        self.newton_workspace().and_then(BackwardEuler::piece_ends)
    }

    fn step_inner(
        &mut self,
        dt: f64,
        targets: Option<&[(usize, DVec3)]>,
    ) -> Result<StepReport, StepError> {
        self.clear_step_records();
        crate::model::check_time_step(dt)?;
        self.topology.check(&self.system.topology())?;
        // The implicit integrators' step starts at the simulation's time (their terms
        // pose kinematic colliders from it).
        match &mut self.stepper {
            Stepper::BackwardEuler(be) => be.set_time(self.time),
            Stepper::Bdf2(b) => b.newton_mut().set_time(self.time),
            Stepper::Midpoint(m) => m.newton_mut().set_time(self.time),
            Stepper::Auto(a) => a.set_time(self.time),
            _ => {}
        }
        if let Some(contact) = &mut self.contact
            && contact.stats.is_some()
        {
            // The minimization starts from an admissible state: the step's start, with
            // particles a kinematic collider would run over carried along with it
            // (the contact term does the same to Newton's first iterate). Two colliders
            // closing in on one particle within one step make that impossible. The step's
            // start itself must be outside every collider: accepted states are, but a
            // state set through `system_mut` may not be.
            crate::contact::check_step_start(
                &contact.colliders,
                contact.settings.thickness,
                self.time,
                self.system.positions(),
                self.system.fixed(),
            )?;
            contact.scratch.clear();
            contact.scratch.extend_from_slice(self.system.positions());
            crate::contact::potential::carry_with_colliders(
                &contact.colliders,
                &contact.settings,
                self.time,
                self.time + dt,
                self.system.positions(),
                self.system.fixed(),
                &mut contact.scratch,
            )
            .map_err(|(particle, collider)| StepError::Contact { particle, collider })?;
        }
        let report = self.step_integrator(dt, targets)?;
        self.time += dt;
        if let Some(contact) = &mut self.contact
            && contact.stats.is_none()
        {
            // Explicit integrators: project after the step (not guaranteed).
            for i in 0..self.system.len() {
                if self.system.fixed()[i] {
                    continue;
                }
                let mut x = self.system.positions()[i];
                let mut v = self.system.velocities()[i];
                let mut moved = false;
                for collider in &contact.colliders {
                    let p = project_particle(
                        collider,
                        self.time,
                        x,
                        v,
                        contact.settings.thickness,
                        contact.settings.mu,
                    );
                    if p.contact {
                        (x, v) = (p.position, p.velocity);
                        moved = true;
                        contact.projections += 1;
                    }
                }
                if moved {
                    let (positions, velocities) = self.system.state_mut();
                    positions[i] = x;
                    velocities[i] = v;
                }
            }
        }
        Ok(report)
    }

    fn step_integrator(
        &mut self,
        dt: f64,
        targets: Option<&[(usize, DVec3)]>,
    ) -> Result<StepReport, StepError> {
        if targets.is_some() || self.pins.is_some() {
            let mut all: Vec<(usize, DVec3)> = match &self.pins {
                Some(driver) => driver.targets_at(driver.time() + dt),
                None => Vec::new(),
            };
            if let Some(given) = targets {
                // Given positions win over a motion's for the same particle.
                all.retain(|(i, _)| !given.iter().any(|(j, _)| j == i));
                all.extend_from_slice(given);
            }
            let depth = self
                .pins
                .as_ref()
                .map_or(PIN_SPLIT_DEPTH, |p| p.max_split_depth);
            let (system, stepper) = (&mut self.system, &mut self.stepper);
            let stepper: &mut dyn PinnedStepper = match stepper {
                Stepper::BackwardEuler(be) => &mut **be,
                Stepper::Bdf2(b) => &mut **b,
                Stepper::Midpoint(m) => &mut **m,
                _ => {
                    return Err(ModelError::BadParameter {
                        name: "integrator",
                        reason: "moving pins need an implicit integrator (backward Euler, BDF2 or implicit midpoint)",
                    }
                    .into());
                }
            };
            let report = if targets.is_none()
                && let Some(driver) = &mut self.pins
            {
                driver.step(stepper, system, dt)?
            } else {
                let report = step_to_targets(stepper, system, dt, &all, depth)?;
                if let Some(driver) = &mut self.pins {
                    driver.advance_time(dt);
                }
                report
            };
            return Ok(report);
        }
        match &mut self.stepper {
            Stepper::BackwardEuler(be) => be.step(&mut self.system, dt),
            Stepper::SymplecticEuler(se) => se.step(&mut self.system, dt),
            Stepper::Flawed(fl) => fl.step(&mut self.system, dt),
            Stepper::Bdf2(b) => b.step(&mut self.system, dt),
            Stepper::Midpoint(m) => m.step(&mut self.system, dt),
            Stepper::Bounded(b) => b.step(&mut self.system, dt),
            Stepper::Auto(a) => a.step(&mut self.system, dt),
        }
    }

    /// The stability bound of the explicit integrators at the current state (computed
    /// afresh; `O(springs)` Gershgorin plus a Lanczos estimate).
    #[must_use]
    pub fn stability_bound(&self) -> StabilityBound {
        StabilityBound::of(&self.system)
    }

    /// The system.
    #[must_use]
    pub fn system(&self) -> &SpringSystem {
        &self.system
    }

    /// The system, for state or material changes that keep the topology.
    pub fn system_mut(&mut self) -> &mut SpringSystem {
        match &mut self.stepper {
            Stepper::BackwardEuler(be) => be.reset_history(),
            Stepper::Bdf2(b) => b.reset_history(),
            Stepper::Midpoint(m) => m.reset_history(),
            Stepper::Auto(a) => a.reset_history(),
            _ => {}
        }
        &mut self.system
    }

    /// The backward Euler workspace, when that is the integrator.
    #[must_use]
    pub fn backward_euler(&self) -> Option<&BackwardEuler> {
        match &self.stepper {
            Stepper::BackwardEuler(be) => Some(be),
            _ => None,
        }
    }

    /// Gives the system back.
    #[must_use]
    pub fn into_system(self) -> SpringSystem {
        self.system
    }
}
