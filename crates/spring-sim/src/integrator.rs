//! The stepping front: one [`Integrator`] choice, one [`Simulation`] that owns the system
//! and the chosen integrator's workspace, one [`StepReport`] per step.
//!
//! The implicit integrators (backward Euler, BDF2, implicit midpoint) share the Newton
//! minimization of [`crate::newton`] with their own effective step and prediction; the
//! explicit ones (symplectic Euler, velocity Verlet) take a substep count, checked against
//! or chosen from the stability bound of [`crate::stability`]; `auto` picks among them per
//! step and says why in the [`StepReport`]. The rules are in docs/integrators.md.

use crate::contact::{
    Collider, ContactError, ContactPotential, ContactSettings, ContactStats, ContactTerm,
    project_particle, signed_distance,
};
use crate::explicit::{SymplecticEuler, VelocityVerlet};
use crate::implicit::{Bdf2, ImplicitMidpoint};
use crate::model::{ModelError, SpringSystem};
use crate::newton::{BackwardEuler, NewtonSettings};
use crate::reference::flawed_report_method::FlawedReportMethod;
use crate::report::{AutoReason, IntegratorKind, StepError, StepReport};
use crate::stability::{StabilityBound, StabilityMonitor};
use sinew_math::DVec3;
use std::sync::Arc;
use std::time::Instant;

/// Which integrator advances the system, with its settings.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
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
    /// substep count, or BDF2), or backward Euler when asked to settle; see
    /// [`AutoSettings`].
    Auto(AutoSettings),
}

/// Settings of [`Integrator::Auto`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default))]
pub struct AutoSettings {
    /// Numerical damping wanted (settling to rest): always backward Euler (default false).
    pub settle: bool,
    /// Newton settings of the implicit integrators `auto` may use.
    pub newton: NewtonSettings,
    /// Largest substep count `auto` accepts for velocity Verlet (default 100 000); above
    /// it BDF2 is used whatever the costs.
    pub max_substeps: usize,
    /// The cost of one implicit step in explicit substeps, assumed until an implicit step
    /// has been timed (default 300; measured, docs/bench/spring-sim.md: a backward Euler or
    /// BDF2 step costs about 20 Verlet substeps on W4 and 300 to 1000 on W5 k = 1e6).
    pub implicit_cost_model: f64,
    /// Hysteresis: the other integrator must be this much cheaper to switch (default 1.25).
    pub switch_ratio: f64,
}

impl Default for AutoSettings {
    fn default() -> Self {
        Self {
            settle: false,
            newton: NewtonSettings::default(),
            max_substeps: 100_000,
            implicit_cost_model: 300.0,
            switch_ratio: 1.25,
        }
    }
}

impl AutoSettings {
    /// Checks the settings, naming the bad field.
    pub fn validate(&self) -> Result<(), ModelError> {
        self.newton.validate()?;
        if self.max_substeps == 0 {
            return Err(ModelError::BadParameter {
                name: "max_substeps",
                reason: "must be at least 1",
            });
        }
        if !(self.implicit_cost_model.is_finite() && self.implicit_cost_model > 0.0) {
            return Err(ModelError::BadParameter {
                name: "implicit_cost_model",
                reason: "must be positive and finite",
            });
        }
        if !(self.switch_ratio.is_finite() && self.switch_ratio >= 1.0) {
            return Err(ModelError::BadParameter {
                name: "switch_ratio",
                reason: "must be finite and at least 1",
            });
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
/// implicit one.
const PROBES: usize = 3;

/// The `auto` integrator: velocity Verlet at the bound's substep count or BDF2, whichever
/// costs less per step (measured, or modelled before measured), or backward Euler when
/// asked to settle.
#[derive(Debug)]
struct AutoStepper {
    settings: AutoSettings,
    monitor: StabilityMonitor,
    verlet: VelocityVerlet,
    bdf2: Option<Box<Bdf2>>,
    settle: Option<Box<BackwardEuler>>,
    current: Option<IntegratorKind>,
    /// Seconds per explicit substep.
    substep_time: Timing,
    /// Seconds per implicit step.
    implicit_time: Timing,
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
            verlet: VelocityVerlet::new(system, 1)?,
            bdf2: None,
            settle,
            current: None,
            substep_time: Timing::default(),
            implicit_time: Timing::default(),
        })
    }

    fn reset_history(&mut self) {
        if let Some(b) = &mut self.bdf2 {
            b.reset_history();
        }
        if let Some(b) = &mut self.settle {
            b.reset_history();
        }
    }

    /// The choice for a step of `h` with `needed` substeps for Verlet.
    fn choose(&self, needed: usize) -> AutoReason {
        if needed > self.settings.max_substeps {
            return AutoReason::SubstepCap;
        }
        // Costs in seconds when measured; before, in units of one explicit substep.
        let (explicit, implicit) =
            match (self.substep_time.estimate(), self.implicit_time.estimate()) {
                // Fewer than PROBES explicit timings: time another explicit step (safe,
                // at the bound's count), so one preempted step cannot decide for good.
                (Some(_), Some(_)) if self.substep_time.samples < PROBES => {
                    return AutoReason::ExplicitCheapest;
                }
                (Some(t), Some(ti)) => (needed as f64 * t, ti),
                (Some(t), None) => (needed as f64 * t, self.settings.implicit_cost_model * t),
                // An implicit step was timed but no explicit one: time one explicit step
                // (stable at the bound's count, so the probe is safe).
                (None, Some(_)) => return AutoReason::ExplicitCheapest,
                (None, None) => (needed as f64, self.settings.implicit_cost_model),
            };
        let ratio = self.settings.switch_ratio;
        let explicit_wins = match self.current {
            Some(IntegratorKind::Bdf2) => explicit * ratio < implicit,
            Some(IntegratorKind::VelocityVerlet) => explicit < implicit * ratio,
            _ => explicit <= implicit,
        };
        if explicit_wins {
            AutoReason::ExplicitCheapest
        } else {
            AutoReason::ImplicitCheaper
        }
    }

    fn step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        crate::model::check_time_step(h)?;
        if let Some(be) = &mut self.settle {
            let mut report = be.step(system, h)?;
            report.auto_reason = Some(AutoReason::Settle);
            return Ok(report);
        }
        let bound = self.monitor.update(system, h);
        let needed = bound.substeps(h);
        let reason = self.choose(needed);
        let started = Instant::now();
        let mut report = if reason == AutoReason::ExplicitCheapest {
            self.verlet.set_substeps(needed);
            let report = self.verlet.step(system, h)?;
            self.substep_time
                .record(started.elapsed().as_secs_f64() / needed as f64);
            self.current = Some(IntegratorKind::VelocityVerlet);
            report
        } else {
            if self.bdf2.is_none() {
                self.bdf2 = Some(Box::new(Bdf2::new(system, self.settings.newton)?));
            }
            let bdf2 = self.bdf2.as_mut().expect("built above");
            if self.current != Some(IntegratorKind::Bdf2) {
                // Coming from Verlet: the BDF2 history is stale.
                bdf2.reset_history();
            }
            let report = bdf2.step(system, h)?;
            self.implicit_time.record(started.elapsed().as_secs_f64());
            self.current = Some(IntegratorKind::Bdf2);
            report
        };
        report.auto_reason = Some(reason);
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
        })
    }

    /// Adds contact with `colliders` (validated; the error names the collider or the
    /// setting). With backward Euler, contact is IPC's barrier and lagged friction in the
    /// minimization, with the line search capped by the time of impact, so no accepted
    /// state has a particle inside a collider (docs/contact.md). With the explicit
    /// integrators ([`Integrator::SymplecticEuler`], [`Integrator::VelocityVerlet`],
    /// [`Integrator::SymplecticEulerBounded`]) every particle is projected out of every
    /// collider after each step ([`crate::contact::projection`]): **not guaranteed**.
    /// BDF2, implicit midpoint, `auto` and the flawed reference method have no contact
    /// yet: an error. Contact can be set once.
    pub fn set_contact(
        &mut self,
        colliders: Vec<Collider>,
        settings: ContactSettings,
    ) -> Result<(), ContactError> {
        if self.contact.is_some() {
            return Err(ContactError::Unsupported {
                what: "setting contact twice",
            });
        }
        crate::contact::collider::validate_colliders(&colliders)?;
        settings.validate()?;
        let stats = match &mut self.stepper {
            Stepper::BackwardEuler(be) => {
                if colliders.iter().any(|c| !c.is_static()) {
                    // The contact term advances its own clock at every start of a step,
                    // so a step redone in pieces would pose moving colliders at the
                    // wrong times.
                    be.forbid_splitting();
                }
                let term = ContactTerm::new(ContactPotential::new(
                    colliders.clone(),
                    settings,
                    self.time,
                )?);
                let stats = term.stats();
                be.add_term(Box::new(term));
                Some(stats)
            }
            Stepper::SymplecticEuler(_) | Stepper::Bounded(_) => None,
            Stepper::Bdf2(_) => return Err(ContactError::Unsupported { what: "BDF2" }),
            Stepper::Midpoint(_) => {
                return Err(ContactError::Unsupported {
                    what: "implicit midpoint",
                });
            }
            Stepper::Auto(_) => return Err(ContactError::Unsupported { what: "auto" }),
            Stepper::Flawed(_) => {
                return Err(ContactError::Unsupported {
                    what: "the flawed reference method",
                });
            }
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

    /// The barrier stiffness `kappa` of backward Euler's contact term (`None` without
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

    /// Advances by `dt`. On error the system is unchanged.
    pub fn step(&mut self, dt: f64) -> Result<StepReport, StepError> {
        crate::model::check_time_step(dt)?;
        self.topology.check(&self.system.topology())?;
        if let (Some(contact), Stepper::BackwardEuler(_)) = (&mut self.contact, &self.stepper) {
            // The minimization starts from an admissible state: the step's start, with
            // particles a kinematic collider would run over carried along with it
            // (the contact term does the same to Newton's first iterate). Two colliders
            // closing in on one particle within one step make that impossible.
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
        let report = self.step_integrator(dt)?;
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

    fn step_integrator(&mut self, dt: f64) -> Result<StepReport, StepError> {
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
