//! A term written over the end-of-step positions, made to serve every implicit scheme.
//!
//! Backward Euler and BDF2 minimize over the end-of-step positions themselves; the
//! implicit midpoint minimizes over the step's midpoint `z`, whose end state is
//! `w = 2 z - x_n` (docs/integrators.md). A term whose meaning is tied to the end state
//! (a barrier that must keep it admissible, friction measured by its displacement) is
//! evaluated there: its energy `E(w(z))`, gradient `2 grad E(w)`, Hessian `4 H(w)`, and
//! along a direction `dz` the end state moves along `2 dz` by the same fraction, so the
//! line-search cap is the term's own at `w`. The term sees a backward Euler step of the
//! real length from `x_n` (velocities `(w - x_n)/length`, the step's mean), as the
//! collider contact term does (docs/contact.md).

use super::{HessianSink, StepContext, StepTiming, Term};
use crate::model::SpringSystem;
use crate::report::StepError;
use crate::spring::Curvature;
use sinew_math::DVec3;
use std::sync::{Mutex, PoisonError};

/// `T`, a term over the end-of-step positions, evaluated at the end state of whatever
/// the minimization's unknowns are: the same term for backward Euler and BDF2, the
/// chain rule through `w = 2 z - x_n` for the implicit midpoint.
#[derive(Debug)]
pub struct AtEndOfStep<T> {
    inner: T,
    ends: EndStates,
}

impl<T: Term> AtEndOfStep<T> {
    /// Wraps `inner`.
    #[must_use]
    pub fn new(inner: T) -> Self {
        Self {
            inner,
            ends: EndStates::default(),
        }
    }

    /// The wrapped term.
    #[must_use]
    pub fn inner(&self) -> &T {
        &self.inner
    }
}

/// The end states of a term over the end-of-step positions: what it sees of a step and
/// of an iterate, and the storage for them, reused from call to call (every Newton
/// iteration and line-search trial asks).
#[derive(Debug, Default)]
pub(crate) struct EndStates {
    scratch: Mutex<EndScratch>,
}

/// An iterate's end state, its direction, and a gradient there.
#[derive(Debug, Default)]
struct EndScratch {
    w: Vec<DVec3>,
    dw: Vec<DVec3>,
    gradient: Vec<DVec3>,
}

impl EndStates {
    /// Runs `f` with the step a term over the end state sees ([`end_step`]), the end
    /// state of the iterate `x`, the end state's direction for `dx` (empty when `None`)
    /// and the chain rule's factor `dw/dz`: `x` itself and 1, or for the midpoint
    /// `2 x - x_n` and 2.
    pub(crate) fn at<R>(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        dx: Option<&[DVec3]>,
        f: impl FnOnce(&StepContext<'_>, &[DVec3], &[DVec3], f64) -> R,
    ) -> R {
        if !step.timing.midpoint {
            return f(step, x, dx.unwrap_or(&[]), 1.0);
        }
        let mut scratch = self.scratch.lock().unwrap_or_else(PoisonError::into_inner);
        let s = &mut *scratch;
        end_state(step.system, x, &mut s.w);
        s.dw.clear();
        if let Some(dx) = dx {
            s.dw.extend(dx.iter().map(|d| 2.0 * *d));
        }
        f(&end_step(step), &s.w, &s.dw, 2.0)
    }

    /// [`Self::at`] for the hooks that take the term mutably (no direction).
    pub(crate) fn at_mut<R>(
        &mut self,
        step: &StepContext<'_>,
        x: &[DVec3],
        f: impl FnOnce(&StepContext<'_>, &[DVec3]) -> R,
    ) -> R {
        if !step.timing.midpoint {
            return f(step, x);
        }
        let s = self
            .scratch
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner);
        end_state(step.system, x, &mut s.w);
        f(&end_step(step), &s.w)
    }

    /// Adds to `gradient` the gradient in the unknowns of a term that `add` adds to a
    /// gradient over the end state: the term's own for backward Euler and BDF2, twice
    /// its gradient at the end state (collected in a zeroed vector of the scratch) for
    /// the midpoint.
    pub(crate) fn add_gradient(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        gradient: &mut [DVec3],
        add: impl FnOnce(&StepContext<'_>, &[DVec3], &mut [DVec3]),
    ) {
        if !step.timing.midpoint {
            add(step, x, gradient);
            return;
        }
        let mut scratch = self.scratch.lock().unwrap_or_else(PoisonError::into_inner);
        let EndScratch {
            w, gradient: own, ..
        } = &mut *scratch;
        end_state(step.system, x, w);
        own.clear();
        own.resize(gradient.len(), DVec3::ZERO);
        add(&end_step(step), w, own);
        for (g, o) in gradient.iter_mut().zip(own.iter()) {
            *g += 2.0 * *o;
        }
    }
}

/// The midpoint's end state `w = 2 z - x_n` of the iterate `z`, into `w`.
pub(crate) fn end_state(system: &SpringSystem, z: &[DVec3], w: &mut Vec<DVec3>) {
    w.clear();
    w.extend(
        z.iter()
            .zip(system.positions())
            .map(|(z, x0)| 2.0 * *z - *x0),
    );
}

/// Runs `f` on the end state of the iterate `x`, in place, with the step a term over
/// the end state sees, and leaves in `x` the iterate of the end state `f` leaves (for
/// the midpoint: `x` replaced by `2 x - x_n`, then by `(w + x_n)/2`).
pub(crate) fn in_end_state(
    step: &StepContext<'_>,
    x: &mut [DVec3],
    f: impl FnOnce(&StepContext<'_>, &mut [DVec3]),
) {
    if !step.timing.midpoint {
        f(step, x);
        return;
    }
    let x_n = step.system.positions();
    for (z, x0) in x.iter_mut().zip(x_n) {
        *z = 2.0 * *z - *x0;
    }
    f(&end_step(step), x);
    for (w, x0) in x.iter_mut().zip(x_n) {
        *w = 0.5 * (*w + *x0);
    }
}

/// The step a term over the end state sees: the step itself for backward Euler and BDF2
/// (whose unknowns are the end state), and in a midpoint step a backward Euler step of
/// the real length from `x_n` (the prediction is the caller's, unused by such terms).
pub(crate) fn end_step<'a>(step: &StepContext<'a>) -> StepContext<'a> {
    if !step.timing.midpoint {
        return *step;
    }
    StepContext {
        h: step.timing.length,
        x_ref: step.system.positions(),
        timing: StepTiming {
            midpoint: false,
            ..step.timing
        },
        ..*step
    }
}

impl<T: Term> Term for AtEndOfStep<T> {
    fn name(&self) -> &'static str {
        self.inner.name()
    }

    fn check_start(&self, system: &SpringSystem, time: f64) -> Result<(), StepError> {
        self.inner.check_start(system, time)
    }

    fn begin_step(&mut self, step: &StepContext<'_>) {
        self.inner.begin_step(&end_step(step));
    }

    fn relag_friction(&mut self, step: &StepContext<'_>, x: &[DVec3]) -> bool {
        let inner = &mut self.inner;
        self.ends.at_mut(step, x, |s, w| inner.relag_friction(s, w))
    }

    fn prepare_start(&self, step: &StepContext<'_>, x: &mut [DVec3]) {
        in_end_state(step, x, |s, w| self.inner.prepare_start(s, w));
    }

    fn update_active_set(&mut self, step: &StepContext<'_>, x: &[DVec3]) {
        let inner = &mut self.inner;
        self.ends
            .at_mut(step, x, |s, w| inner.update_active_set(s, w));
    }

    fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        self.ends
            .at(step, x, None, |s, w, _, _| self.inner.energy(s, w))
    }

    fn energy_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        self.ends.at(step, x, Some(dx), |s, w, dw, _| {
            self.inner.energy_change(s, w, dw, alpha)
        })
    }

    fn add_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        self.ends.add_gradient(step, x, gradient, |s, w, g| {
            self.inner.add_gradient(s, w, g);
        });
    }

    fn add_hessian(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        sink: &mut HessianSink<'_>,
    ) {
        if !step.timing.midpoint {
            self.inner.add_hessian(step, x, curvature, sink);
            return;
        }
        self.ends.at(step, x, None, |s, w, _, scale| {
            sink.add_scaled(scale * scale, |own| {
                self.inner.add_hessian(s, w, curvature, own);
            });
        });
    }

    fn hessian_is_block_diagonal(&self) -> bool {
        self.inner.hessian_is_block_diagonal()
    }

    fn gives_exact_contact(&self) -> bool {
        self.inner.gives_exact_contact()
    }

    fn max_step(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], reach: f64) -> f64 {
        // The end state moves along its own direction by the same fraction alpha.
        self.ends.at(step, x, Some(dx), |s, w, dw, _| {
            self.inner.max_step(s, w, dw, reach)
        })
    }

    fn abandon_step(&mut self) {
        self.inner.abandon_step();
    }

    fn take_missing_pairs(&mut self) -> Vec<[usize; 2]> {
        self.inner.take_missing_pairs()
    }

    fn first_swept_pass(&self, step: &StepContext<'_>, x: &[DVec3]) -> Option<(usize, usize)> {
        self.ends.at(step, x, None, |s, w, _, _| {
            self.inner.first_swept_pass(s, w)
        })
    }

    fn does_work(&self) -> bool {
        self.inner.does_work()
    }

    fn wants_threads(&self) -> bool {
        self.inner.wants_threads()
    }
}
