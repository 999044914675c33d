//! The gravity term `-sum_free m_i g . x_i`: a constant external force `m_i g`, so its
//! gradient is `-m_i g` and its Hessian is zero.

use super::{HessianSink, StepContext, Term};
use crate::spring::Curvature;
use sinew_math::DVec3;

/// `-sum_i m_i g . x_i` over the free particles, `g` the material's gravity.
#[derive(Clone, Copy, Debug, Default)]
pub struct Gravity;

impl Term for Gravity {
    fn name(&self) -> &'static str {
        "gravity"
    }

    fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        let gravity = step.system.material().gravity;
        let system = step.system;
        let mut e = 0.0;
        for (p, (&m, &fixed)) in system.masses().iter().zip(system.fixed()).enumerate() {
            if !fixed {
                e -= m * gravity.dot(x[p]);
            }
        }
        e
    }

    fn energy_change(&self, step: &StepContext<'_>, _x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        // Linear: the change is exact from the direction alone.
        let gravity = step.system.material().gravity;
        let system = step.system;
        let mut change = 0.0;
        for (p, (&m, &fixed)) in system.masses().iter().zip(system.fixed()).enumerate() {
            if !fixed {
                change -= m * gravity.dot(alpha * dx[p]);
            }
        }
        change
    }

    fn add_gradient(&self, step: &StepContext<'_>, _x: &[DVec3], gradient: &mut [DVec3]) {
        let gravity = step.system.material().gravity;
        for (g, &m) in gradient.iter_mut().zip(step.system.masses()) {
            add_gradient_at(g, m, gravity);
        }
    }

    fn add_hessian(
        &self,
        _step: &StepContext<'_>,
        _x: &[DVec3],
        _curvature: Curvature,
        _sink: &mut HessianSink<'_>,
    ) {
        // A linear term has no curvature.
    }

    fn hessian_is_block_diagonal(&self) -> bool {
        true
    }
}

/// Adds a particle's gradient `-m g` to `grad` (the term's loop and the threaded
/// gradient's gather both call it).
#[inline]
pub(super) fn add_gradient_at(grad: &mut DVec3, m: f64, gravity: DVec3) {
    *grad -= m * gravity;
}
