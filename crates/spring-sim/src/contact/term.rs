//! The contact energy as a term of the incremental potential: the barrier against the
//! colliders, the lagged friction, and the line-search cap, for the implicit
//! integrators' shared minimization ([`crate::potential::Term`]).
//!
//! The term wraps a [`ContactPotential`]: `begin_step` lags friction at the step's start
//! and poses the colliders at its end (the term keeps its own clock, advanced by the
//! step's `h` at every `begin_step`), `update_active_set` adapts `kappa` to the iterate,
//! and `max_step` is the smallest time of impact, so no state the line search tries has
//! a particle inside a collider. Only backward Euler is guaranteed by this argument:
//! its minimization is over the end-of-step positions themselves.

use super::ContactPotential;
use crate::potential::{HessianSink, StepContext, SymBlock, Term};
use crate::spring::Curvature;
use sinew_math::DVec3;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// The longest step the line search may try, in Newton steps (it doubles an accepted
/// full step at most 10 times).
const LINE_SEARCH_HORIZON: f64 = 1024.0;

/// Numbers a contact term publishes for reports while it is owned by an integrator.
#[derive(Debug, Default)]
pub struct ContactStats {
    kappa: AtomicU64,
    friction_contacts: AtomicU64,
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

    fn publish(&self, p: &ContactPotential) {
        self.kappa.store(p.kappa().to_bits(), Ordering::Relaxed);
        self.friction_contacts
            .store(p.friction_contacts() as u64, Ordering::Relaxed);
    }
}

/// The contact term (see the module documentation).
#[derive(Debug)]
pub struct ContactTerm {
    potential: ContactPotential,
    stats: Arc<ContactStats>,
}

impl ContactTerm {
    /// A term for `potential`; [`Self::stats`] stays readable after the term is handed
    /// to an integrator.
    #[must_use]
    pub fn new(potential: ContactPotential) -> Self {
        Self {
            potential,
            stats: Arc::new(ContactStats::default()),
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
}

impl Term for ContactTerm {
    fn name(&self) -> &'static str {
        "contact"
    }

    fn begin_step(&mut self, step: &StepContext<'_>) {
        let s = step.system;
        self.potential.begin_step(
            s.positions(),
            s.fixed(),
            s.masses(),
            s.material().gravity.length(),
            step.h,
        );
        self.stats.publish(&self.potential);
    }

    fn prepare_start(&self, step: &StepContext<'_>, x: &mut [DVec3]) {
        let (x_n, fixed) = (step.system.positions(), step.system.fixed());
        if self.potential.prepare_start(x_n, fixed, x).is_err() {
            // The guess, partly carried, is not admissible: start from x_n carried
            // instead, the state `Simulation::step` checked before the step (it refuses
            // the step when even that is inside a collider).
            x.copy_from_slice(x_n);
            let _ = self.potential.prepare_start(x_n, fixed, x);
        }
    }

    fn update_active_set(&mut self, step: &StepContext<'_>, x: &[DVec3]) {
        if self.potential.update_kappa(x, step.system.fixed()) {
            self.stats.publish(&self.potential);
        }
    }

    fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        self.potential.energy(x, step.system.fixed())
    }

    fn energy_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        self.potential
            .energy_change(x, dx, alpha, step.system.fixed())
    }

    fn add_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        self.potential
            .add_gradient(x, step.system.fixed(), gradient);
    }

    fn add_hessian(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        _curvature: Curvature,
        sink: &mut HessianSink<'_>,
    ) {
        self.potential
            .for_each_hessian_block(x, step.system.fixed(), |i, block| {
                sink.add_diagonal(i, SymBlock::from_lower(&block));
            });
    }

    fn max_step(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3]) -> f64 {
        // The line search may lengthen an accepted full step up to 2^10 times, so the
        // cap is computed over that whole range; nothing near within it: no cap.
        let alpha = self
            .potential
            .max_step(x, dx, step.system.fixed(), LINE_SEARCH_HORIZON);
        if alpha >= LINE_SEARCH_HORIZON {
            f64::INFINITY
        } else {
            alpha
        }
    }
}
