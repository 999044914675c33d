//! The spring term `sum_s k_s/2 (|x_a - x_b| - L_s)^2`, from the per-spring kernels of
//! [`crate::spring`]: energy, change from differences ([`spring::energy_change`]),
//! gradient, and the Hessian block `K` in the form [`Curvature`] asks for, entered as
//! `[[K, -K], [-K, K]]` on the spring's two particles.

use super::{HessianSink, StepContext, SymBlock, Term};
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
        step.system
            .springs()
            .iter()
            .map(|s| spring::energy(x[s.a], x[s.b], s.rest_length, s.stiffness))
            .sum()
    }

    fn energy_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        let mut change = 0.0;
        for s in step.system.springs() {
            let delta = alpha * dx[s.a] - alpha * dx[s.b];
            if delta == DVec3::ZERO {
                continue;
            }
            change += spring::energy_change(x[s.a] - x[s.b], delta, s.rest_length, s.stiffness);
        }
        change
    }

    fn add_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        for s in step.system.springs() {
            let g = spring::gradient(x[s.a], x[s.b], s.rest_length, s.stiffness);
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
        for (e, s) in step.system.springs().iter().enumerate() {
            sink.add_edge(e, s.a, s.b, block(s, x, curvature));
        }
    }

    fn has_spring_blocks(&self) -> bool {
        true
    }

    fn add_spring_blocks(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        blocks: &mut [SymBlock],
    ) {
        for (s, b) in step.system.springs().iter().zip(blocks.iter_mut()) {
            let k = block(s, x, curvature);
            for (sum, v) in b.0.iter_mut().zip(k.0) {
                *sum += v;
            }
        }
    }
}

/// The block `K = alpha I + beta u u^T` of spring `s` at `x` (its six distinct entries,
/// written directly: the hot loop of assembly).
#[inline]
fn block(s: &crate::model::Spring, x: &[DVec3], curvature: Curvature) -> SymBlock {
    let (alpha, beta, u) =
        spring::hessian_coefficients(x[s.a] - x[s.b], s.rest_length, s.stiffness, curvature);
    SymBlock::isotropic_plus_outer(alpha, beta, u)
}
