//! The inertia term `1/(2 h^2) |x - y|_M^2 = sum_free m_i/(2 h^2) |x_i - y_i|^2`: its
//! gradient `m_i (x_i - y_i)/h^2`, its Hessian `m_i/h^2 I` on the diagonal blocks.

use super::{HessianSink, StepContext, SymBlock, Term};
use crate::spring::Curvature;
use sinew_math::DVec3;

/// `1/(2 h^2) |x - y|_M^2` over the free particles.
#[derive(Clone, Copy, Debug, Default)]
pub struct Inertia;

impl Term for Inertia {
    fn name(&self) -> &'static str {
        "inertia"
    }

    fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        let h = step.h;
        let system = step.system;
        let mut e = 0.0;
        for (p, (&m, &fixed)) in system.masses().iter().zip(system.fixed()).enumerate() {
            if !fixed {
                e += 0.5 * m / (h * h) * (x[p] - step.y[p]).length_squared();
            }
        }
        e
    }

    fn energy_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        // m/(2h^2) (|x + delta - y|^2 - |x - y|^2) = m/(2h^2) delta . (2 (x - y) + delta),
        // with no cancellation between two nearly equal squares.
        let inv_2h2 = 0.5 / (step.h * step.h);
        let system = step.system;
        let mut change = 0.0;
        for (p, (&m, &fixed)) in system.masses().iter().zip(system.fixed()).enumerate() {
            if !fixed {
                let delta = alpha * dx[p];
                change += m * (inv_2h2 * delta.dot(2.0 * (x[p] - step.y[p]) + delta));
            }
        }
        change
    }

    fn add_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        let inv_h2 = 1.0 / (step.h * step.h);
        for (p, (g, &m)) in gradient.iter_mut().zip(step.system.masses()).enumerate() {
            add_gradient_at(g, m, inv_h2, x[p], step.y[p]);
        }
    }

    fn add_hessian(
        &self,
        step: &StepContext<'_>,
        _x: &[DVec3],
        _curvature: Curvature,
        sink: &mut HessianSink<'_>,
    ) {
        let inv_h2 = 1.0 / (step.h * step.h);
        for (p, &m) in step.system.masses().iter().enumerate() {
            sink.add_diagonal(p, block(m, inv_h2));
        }
    }

    fn hessian_is_block_diagonal(&self) -> bool {
        true
    }
}

// The per-particle kernels, written once for the term's loops and for the threaded
// assembly's gather, which folds them into its pass over the particles.

/// Adds particle gradient `m (x - y) / h^2` to `g` (`inv_h2 = 1/h^2`).
#[inline]
pub(super) fn add_gradient_at(g: &mut DVec3, m: f64, inv_h2: f64, x: DVec3, y: DVec3) {
    *g += m * (inv_h2 * (x - y));
}

/// A particle's diagonal block `m/h^2 I` (`inv_h2 = 1/h^2`).
#[inline]
pub(super) fn block(m: f64, inv_h2: f64) -> SymBlock {
    SymBlock::scaled_identity(m * inv_h2)
}
