//! The spring term `sum_s k_s/2 (|x_a - x_b| - L_s)^2`, from the per-spring kernels of
//! [`crate::spring`]: energy, change from differences ([`spring::energy_change`]),
//! gradient, and the Hessian block `K` in the form [`Curvature`] asks for, entered as
//! `[[K, -K], [-K, K]]` on the spring's two particles.

use super::{HessianSink, StepContext, SymBlock, Term};
use crate::model::Spring;
use crate::spring::{self, Curvature};
use sinew_math::DVec3;

/// The elastic energy of every spring of the system.
#[derive(Clone, Copy, Debug, Default)]
pub struct Springs;

impl Term for Springs {
    fn name(&self) -> &'static str {
        "springs"
    }

    fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        step.system.springs().iter().map(|s| energy(s, x)).sum()
    }

    fn energy_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        let mut change = 0.0;
        for s in step.system.springs() {
            let delta = alpha * dx[s.a] - alpha * dx[s.b];
            if delta == DVec3::ZERO {
                continue;
            }
            change += energy_change(s, x, delta);
        }
        change
    }

    fn add_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        for s in step.system.springs() {
            let g = self::gradient(s, x);
            gradient[s.a] += g;
            gradient[s.b] -= g;
        }
    }

    fn add_hessian(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        sink: &mut HessianSink<'_>,
    ) {
        sink.add_edges_outer(step.system.springs().iter().enumerate().map(|(e, s)| {
            let (alpha, beta, u) = coefficients(s, x, curvature);
            (e, s.a, s.b, alpha, beta, u)
        }));
    }
}

// The per-spring kernels of the term, written once and used both by its own loops and by
// the potential's fused loop over the springs (see `Potential`).

/// Spring `s`'s energy at `x`.
#[inline]
#[must_use]
pub(super) fn energy(s: &Spring, x: &[DVec3]) -> f64 {
    spring::energy(x[s.a], x[s.b], s.rest_length, s.stiffness)
}

/// The change of spring `s`'s energy when `x_a - x_b` moves by `delta`.
#[inline]
#[must_use]
pub(super) fn energy_change(s: &Spring, x: &[DVec3], delta: DVec3) -> f64 {
    spring::energy_change(x[s.a] - x[s.b], delta, s.rest_length, s.stiffness)
}

/// Spring `s`'s gradient at `x` on its first particle (minus it on the second).
#[inline]
#[must_use]
pub(super) fn gradient(s: &Spring, x: &[DVec3]) -> DVec3 {
    spring::gradient(x[s.a], x[s.b], s.rest_length, s.stiffness)
}

/// The coefficients of spring `s`'s block `K = alpha I + beta u u^T` at `x`.
#[inline(always)]
#[must_use]
pub(super) fn coefficients(s: &Spring, x: &[DVec3], curvature: Curvature) -> (f64, f64, DVec3) {
    spring::hessian_coefficients(x[s.a] - x[s.b], s.rest_length, s.stiffness, curvature)
}

/// The block `K = alpha I + beta u u^T` of spring `s` at `x` (its six distinct entries,
/// written directly: the hot loop of assembly).
#[inline]
#[must_use]
pub(super) fn block(s: &Spring, x: &[DVec3], curvature: Curvature) -> SymBlock {
    let (alpha, beta, u) = coefficients(s, x, curvature);
    SymBlock::isotropic_plus_outer(alpha, beta, u)
}
