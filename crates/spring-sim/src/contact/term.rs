//! The contact energy as a term of the incremental potential: the barrier against the
//! colliders, the lagged friction, and the line-search cap, for the implicit
//! integrators' shared minimization ([`crate::potential::Term`]).
//!
//! The term wraps a [`ContactPotential`]: `begin_step` lags friction at the step's start
//! and poses the colliders at its end (both times come from the step's
//! [`crate::potential::StepTiming`], so a step redone in pieces poses them again from its own start),
//! `update_active_set` adapts `kappa` to the iterate, and `max_step` is the smallest time
//! of impact, so no state the line search tries has a particle inside a collider.
//!
//! The barrier constrains the end-of-step positions. Backward Euler and BDF2 minimize
//! over those themselves. Implicit midpoint minimizes over the midpoint `z`, and its end
//! state `w = 2 z - x_n` is what must stay outside: the term evaluates the potential at
//! `w`, with a line-search direction `dz` moving `w` by `2 dz`, the gradient times 2 and
//! the Hessian times 4 (the chain rule). Derivation: docs/contact.md.

use super::{Collider, ContactError, ContactPotential, ContactStep, Drive};
use crate::potential::end_state::{EndStates, end_step, in_end_state};
use crate::potential::{Gravity, HessianSink, Springs, StepContext, SymBlock, Term};
use crate::spring::Curvature;
use crate::{SpringSystem, StepError};
use sinew_math::DVec3;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// The longest step the line search may try, in Newton steps (it doubles an accepted
/// full step at most 10 times).
const LINE_SEARCH_HORIZON: f64 = 1024.0;

/// Numbers a contact term publishes for reports while it is owned by an integrator.
#[derive(Debug)]
pub struct ContactStats {
    kappa: AtomicU64,
    friction_contacts: AtomicU64,
    active_pairs: AtomicU64,
    min_distance: AtomicU64,
}

impl Default for ContactStats {
    fn default() -> Self {
        Self {
            kappa: AtomicU64::new(0),
            friction_contacts: AtomicU64::new(0),
            active_pairs: AtomicU64::new(0),
            min_distance: AtomicU64::new(f64::INFINITY.to_bits()),
        }
    }
}

impl ContactStats {
    /// The current barrier stiffness (0 before the first step).
    #[must_use]
    pub fn kappa(&self) -> f64 {
        f64::from_bits(self.kappa.load(Ordering::Relaxed))
    }

    /// The number of lagged friction contacts in the last step.
    #[must_use]
    pub fn friction_contacts(&self) -> usize {
        self.friction_contacts.load(Ordering::Relaxed) as usize
    }

    /// The number of particle-collider pairs within `dhat` at the last Newton
    /// iteration's start (0 before the first step).
    #[must_use]
    pub fn active_pairs(&self) -> usize {
        self.active_pairs.load(Ordering::Relaxed) as usize
    }

    /// The smallest distance (less the thickness) among them, `+inf` when none (and
    /// before the first step).
    #[must_use]
    pub fn min_distance(&self) -> f64 {
        f64::from_bits(self.min_distance.load(Ordering::Relaxed))
    }

    fn publish(&self, p: &ContactPotential) {
        self.kappa.store(p.kappa().to_bits(), Ordering::Relaxed);
        self.friction_contacts
            .store(p.friction_contacts() as u64, Ordering::Relaxed);
        self.active_pairs
            .store(p.active_pairs() as u64, Ordering::Relaxed);
        self.min_distance
            .store(p.active_min_distance().to_bits(), Ordering::Relaxed);
    }
}

/// The contact term (see the module documentation).
#[derive(Debug)]
pub struct ContactTerm {
    potential: ContactPotential,
    stats: Arc<ContactStats>,
    /// The end states the potential is evaluated at (the midpoint's `2 z - x_n`).
    ends: EndStates,
    /// Scratch for the other terms' gradient at the step's start.
    other_gradient: Vec<DVec3>,
}

impl ContactTerm {
    /// A term for `potential`; [`Self::stats`] stays readable after the term is handed
    /// to an integrator.
    #[must_use]
    pub fn new(potential: ContactPotential) -> Self {
        Self {
            potential,
            stats: Arc::new(ContactStats::default()),
            ends: EndStates::default(),
            other_gradient: Vec::new(),
        }
    }

    /// The shared statistics.
    #[must_use]
    pub fn stats(&self) -> Arc<ContactStats> {
        Arc::clone(&self.stats)
    }

    /// The wrapped potential.
    #[must_use]
    pub fn potential(&self) -> &ContactPotential {
        &self.potential
    }

    /// Drives collider `index` from `time` on: [`ContactPotential::drive_collider`].
    /// An integrator's own `drive_collider` passes its time.
    ///
    /// # Errors
    /// As [`ContactPotential::drive_collider`].
    pub fn drive_collider(
        &mut self,
        index: usize,
        time: f64,
        drive: &Drive,
    ) -> Result<Collider, ContactError> {
        self.potential.drive_collider(index, time, drive)
    }

    /// [`ContactPotential::put_driven`].
    pub(crate) fn put_driven(&mut self, index: usize, driven: Collider) {
        self.potential.put_driven(index, driven);
    }
}

impl Term for ContactTerm {
    fn name(&self) -> &'static str {
        "contact"
    }

    fn check_start(&self, system: &SpringSystem, time: f64) -> Result<(), StepError> {
        // Every iterate is admissible by induction from an admissible start
        // (docs/contact.md): from a start inside a collider the step would run with no
        // error and without that guarantee.
        super::check_step_start(
            self.potential.colliders(),
            self.potential.settings().thickness,
            time,
            system.positions(),
            system.fixed(),
        )
    }

    fn begin_step(&mut self, step: &StepContext<'_>) {
        let s = step.system;
        let timing = step.timing;
        // The step over the end state the potential constrains, and the point its
        // velocities (and friction's displacements) are measured from: backward Euler
        // and BDF2 minimize over the end state with the effective step and measure from
        // `x_ref`; the midpoint's end state moves as a backward Euler step of the real
        // length from x_n (docs/contact.md).
        let ends = end_step(step);
        let (h, anchor) = (ends.h, ends.x_ref);
        // The balancing start of kappa weighs the barrier against the elastic forces at
        // the step's start: gravity and the springs (bending and other added terms are
        // left out: the balance only picks a starting stiffness). The inertia term is
        // left out too: contact usually begins while the sheet lands, where it is the
        // momentum of the fall, and a stiffness balancing that is kept for the rest of
        // the run (docs/contact.md measures both). In the midpoint's unknowns the
        // barrier's gradient is twice its end-state gradient, so the other gradient is
        // halved to balance in end-state terms. Once the start is made it is not needed
        // again.
        let mut other = std::mem::take(&mut self.other_gradient);
        let balance = self.potential.awaits_balance();
        if balance {
            other.clear();
            other.resize(s.len(), DVec3::ZERO);
            let x_n = s.positions();
            Gravity.add_gradient(step, x_n, &mut other);
            Springs.add_gradient(step, x_n, &mut other);
            if timing.midpoint {
                for g in &mut other {
                    *g *= 0.5;
                }
            }
        }
        self.potential.begin(&ContactStep {
            positions: s.positions(),
            anchor,
            fixed: s.fixed(),
            masses: s.masses(),
            gravity: s.material().gravity.length(),
            h,
            start: timing.start,
            end: timing.start + timing.length,
            other_gradient: balance.then_some(other.as_slice()),
        });
        self.other_gradient = other;
        self.stats.publish(&self.potential);
    }

    fn relag_friction(&mut self, step: &StepContext<'_>, x: &[DVec3]) -> bool {
        let (potential, fixed) = (&mut self.potential, step.system.fixed());
        let any = self.ends.at_mut(step, x, |ends, w| {
            potential.relag_friction(w, ends.x_ref, fixed, ends.h)
        });
        self.stats.publish(&self.potential);
        any
    }

    fn prepare_start(&self, step: &StepContext<'_>, x: &mut [DVec3]) {
        let (x_n, fixed) = (step.system.positions(), step.system.fixed());
        // The carry acts on the end state; the midpoint's is 2 z - x_n.
        in_end_state(step, x, |_, x| {
            if self.potential.prepare_start(x_n, fixed, x).is_err() {
                // The guess, partly carried, is not admissible: start from x_n carried
                // instead, the state `Simulation::step` checked before the step (it
                // refuses the step when even that is inside a collider).
                x.copy_from_slice(x_n);
                let _ = self.potential.prepare_start(x_n, fixed, x);
            }
        });
    }

    fn abandon_step(&mut self) {
        self.potential.rewind_kappa();
        self.stats.publish(&self.potential);
    }

    fn update_active_set(&mut self, step: &StepContext<'_>, x: &[DVec3]) {
        let fixed = step.system.fixed();
        // Published every iteration whether or not kappa grew: the active pairs change.
        let potential = &mut self.potential;
        self.ends
            .at_mut(step, x, |_, w| potential.update_kappa(w, fixed));
        self.stats.publish(&self.potential);
    }

    fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        self.ends.at(step, x, None, |_, w, _, _| {
            self.potential.energy(w, step.system.fixed())
        })
    }

    fn energy_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        self.ends.at(step, x, Some(dx), |_, w, dw, _| {
            self.potential
                .energy_change(w, dw, alpha, step.system.fixed())
        })
    }

    fn add_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        self.ends.at(step, x, None, |_, w, _, scale| {
            self.potential
                .add_gradient_scaled(w, step.system.fixed(), scale, gradient);
        });
    }

    fn add_hessian(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        _curvature: Curvature,
        sink: &mut HessianSink<'_>,
    ) {
        self.ends.at(step, x, None, |_, w, _, scale| {
            let s2 = scale * scale;
            self.potential
                .for_each_hessian_block(w, step.system.fixed(), |i, block| {
                    sink.add_diagonal(i, SymBlock::from_lower(&(block * s2)));
                });
        });
    }

    fn hessian_is_block_diagonal(&self) -> bool {
        // A rigid collider couples no two particles: the barrier's and friction's blocks
        // are all per particle.
        true
    }

    fn max_step(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], _reach: f64) -> f64 {
        // The line search may lengthen an accepted full step up to 2^10 times, so the
        // cap is computed over that whole range whatever the reach (a pass over the
        // particles, cheap); nothing near within it: no cap. The
        // end state moves along its own direction by the same fraction alpha.
        let alpha = self.ends.at(step, x, Some(dx), |_, w, dw, _| {
            self.potential
                .max_step(w, dw, step.system.fixed(), LINE_SEARCH_HORIZON)
        });
        if alpha >= LINE_SEARCH_HORIZON {
            f64::INFINITY
        } else {
            alpha
        }
    }

    fn does_work(&self) -> bool {
        self.potential
            .colliders()
            .iter()
            .any(super::Collider::moves_surface)
    }

    fn first_swept_pass(&self, step: &StepContext<'_>, x: &[DVec3]) -> Option<(usize, usize)> {
        // The path that matters is the end state's, from x_n.
        self.ends.at(step, x, None, |_, w, _, _| {
            self.potential
                .first_swept_pass(step.system.positions(), w, step.system.fixed())
        })
    }
}
