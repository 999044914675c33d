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
    /// The end state and its direction, reused from call to call.
    scratch: Mutex<(Vec<DVec3>, Vec<DVec3>)>,
}

impl<T: Term> AtEndOfStep<T> {
    /// Wraps `inner`.
    #[must_use]
    pub fn new(inner: T) -> Self {
        Self {
            inner,
            scratch: Mutex::new((Vec::new(), Vec::new())),
        }
    }

    /// The wrapped term.
    #[must_use]
    pub fn inner(&self) -> &T {
        &self.inner
    }

    /// Runs `f` with the context the wrapped term sees, the end state of the iterate `x`,
    /// the end state's direction for `dx` (empty when `None`) and the chain rule's factor
    /// `dw/dz` (1, or 2 for the midpoint).
    fn at_end<R>(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        dx: Option<&[DVec3]>,
        f: impl FnOnce(&StepContext<'_>, &[DVec3], &[DVec3], f64) -> R,
    ) -> R {
        if !step.timing.midpoint {
            return f(step, x, dx.unwrap_or(&[]), 1.0);
        }
        let ends = end_step(step);
        let mut scratch = self.scratch.lock().unwrap_or_else(PoisonError::into_inner);
        let (w, dw) = &mut *scratch;
        end_state(step.system, x, w);
        dw.clear();
        if let Some(dx) = dx {
            dw.extend(dx.iter().map(|d| 2.0 * *d));
        }
        f(&ends, w, dw, 2.0)
    }

    /// [`Self::at_end`] for the hooks that take the term mutably.
    fn at_end_mut<R>(
        &mut self,
        step: &StepContext<'_>,
        x: &[DVec3],
        f: impl FnOnce(&mut T, &StepContext<'_>, &[DVec3]) -> R,
    ) -> R {
        if !step.timing.midpoint {
            return f(&mut self.inner, step, x);
        }
        let ends = end_step(step);
        let scratch = self
            .scratch
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner);
        end_state(step.system, x, &mut scratch.0);
        f(&mut self.inner, &ends, &scratch.0)
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

/// Replaces the midpoint `z` in `x` by its end state `2 z - x_n`.
pub(crate) fn to_end_state(x_n: &[DVec3], x: &mut [DVec3]) {
    for (z, x0) in x.iter_mut().zip(x_n) {
        *z = 2.0 * *z - *x0;
    }
}

/// Replaces the end state `w` in `x` by its midpoint `(w + x_n)/2`.
pub(crate) fn to_midpoint(x_n: &[DVec3], x: &mut [DVec3]) {
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
        self.at_end_mut(step, x, |t, s, w| t.relag_friction(s, w))
    }

    fn prepare_start(&self, step: &StepContext<'_>, x: &mut [DVec3]) {
        if !step.timing.midpoint {
            self.inner.prepare_start(step, x);
            return;
        }
        let x_n = step.system.positions();
        to_end_state(x_n, x);
        self.inner.prepare_start(&end_step(step), x);
        to_midpoint(x_n, x);
    }

    fn update_active_set(&mut self, step: &StepContext<'_>, x: &[DVec3]) {
        self.at_end_mut(step, x, |t, s, w| t.update_active_set(s, w));
    }

    fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        self.at_end(step, x, None, |s, w, _, _| self.inner.energy(s, w))
    }

    fn energy_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        if !step.timing.midpoint {
            return self.inner.energy_change(step, x, dx, alpha);
        }
        self.at_end(step, x, Some(dx), |s, w, dw, _| {
            self.inner.energy_change(s, w, dw, alpha)
        })
    }

    fn add_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        if !step.timing.midpoint {
            self.inner.add_gradient(step, x, gradient);
            return;
        }
        self.at_end(step, x, None, |s, w, _, scale| {
            let mut own = vec![DVec3::ZERO; gradient.len()];
            self.inner.add_gradient(s, w, &mut own);
            for (g, o) in gradient.iter_mut().zip(&own) {
                *g += scale * *o;
            }
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
        self.at_end(step, x, None, |s, w, _, scale| {
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
        if !step.timing.midpoint {
            return self.inner.max_step(step, x, dx, reach);
        }
        // The end state moves along its own direction by the same fraction alpha.
        self.at_end(step, x, Some(dx), |s, w, dw, _| {
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
        self.at_end(step, x, None, |s, w, _, _| {
            self.inner.first_swept_pass(s, w)
        })
    }

    fn does_work(&self) -> bool {
        self.inner.does_work()
    }
}
