//! The axial damping term `D(x) = c/(2h) sum_s (u_s . (d_s(x) - d_s(x_ref)))^2`, with
//! `d_s = x_a - x_b` and each spring's direction `u_s` frozen at the step's start
//! ([`Term::begin_step`]), so `D` is a convex quadratic: gradient `c/h e_s u_s` on `a`
//! (minus on `b`) with `e_s = u_s . (d_s(x) - d_s(x_ref))`, Hessian block `c/h u_s u_s^T`.
//! Its minimizer condition is the force `-c u (u . (v_a - v_b))` at `v = (x - x_ref)/h`.

use super::{HessianSink, StepContext, SymBlock, Term};
use crate::model::SpringSystem;
use crate::spring::Curvature;
use sinew_math::DVec3;

/// Axial damping along the springs' directions at the step's start.
///
/// The directions and the springs' vectors at the step's reference positions
/// `d_s(x_ref)` are both frozen by [`Term::begin_step`], so the term's evaluations until
/// the next one read the `x_ref` of that step.
#[derive(Clone, Debug, Default)]
pub struct AxialDamping {
    /// Per spring, the unit direction at the step's start (zero for a zero-length
    /// spring, which then has no axial damping in that step).
    directions: Vec<DVec3>,
    /// Per spring, `d_s(x_ref) = x_ref[a] - x_ref[b]` of the step: the same in every
    /// evaluation of a step, so it is computed once there instead of gathered from the
    /// two ends in every pass over the springs.
    references: Vec<DVec3>,
}

impl AxialDamping {
    /// The term for `system`'s springs (directions set by [`Term::begin_step`]).
    #[must_use]
    pub fn new(system: &SpringSystem) -> Self {
        Self {
            directions: vec![DVec3::ZERO; system.springs().len()],
            references: vec![DVec3::ZERO; system.springs().len()],
        }
    }

    /// The frozen directions, one per spring, as of the last step started with damping
    /// (a step of a material without damping leaves them as they were: the term is
    /// zero then and reads none).
    #[must_use]
    pub fn directions(&self) -> &[DVec3] {
        &self.directions
    }

    /// The springs' vectors at the reference positions of the last step started with
    /// damping, one per spring (kept as [`Self::directions`] are).
    #[must_use]
    pub fn reference_vectors(&self) -> &[DVec3] {
        &self.references
    }

    /// `c/h`, or `None` when the material has no damping (the term is then zero).
    fn coefficient(step: &StepContext<'_>) -> Option<f64> {
        let c = step.system.material().damping;
        (c > 0.0).then(|| c / step.h)
    }

    /// `c/h`, or `None` when the material has no damping (the term is then zero): for
    /// the potential's fused loop over the springs.
    pub(super) fn active_coefficient(step: &StepContext<'_>) -> Option<f64> {
        Self::coefficient(step)
    }
}

/// The per-spring kernels of the term, written once and used both by its own loops and by
/// the potential's fused loop over the springs (see [`super::Potential`]). `w` is the
/// spring's frozen direction, `d = x_a - x_b` at the iterate and `d_ref` the same at the
/// reference, and `c` is `c/h`.
pub(super) mod kernel {
    use super::SymBlock;
    use sinew_math::DVec3;

    /// `u_s . (d_s(x) - d_s(x_ref))`.
    #[inline]
    #[must_use]
    pub(in crate::potential) fn elongation(w: DVec3, d: DVec3, d_ref: DVec3) -> f64 {
        w.dot(d - d_ref)
    }

    /// The spring's share of the energy, `c/2 e^2`.
    #[inline]
    #[must_use]
    pub(in crate::potential) fn energy(c: f64, w: DVec3, d: DVec3, d_ref: DVec3) -> f64 {
        let el = elongation(w, d, d_ref);
        0.5 * c * el * el
    }

    /// The change of the spring's share when `d` moves by `delta`.
    #[inline]
    #[must_use]
    pub(in crate::potential) fn energy_change(
        c: f64,
        w: DVec3,
        d: DVec3,
        d_ref: DVec3,
        delta: DVec3,
    ) -> f64 {
        // c/2 ((e + de)^2 - e^2) = c/2 de (2e + de), from the difference.
        let e = elongation(w, d, d_ref);
        let de = w.dot(delta);
        0.5 * c * de * (2.0 * e + de)
    }

    /// The gradient on the spring's first particle (minus it on the second).
    #[inline]
    #[must_use]
    pub(in crate::potential) fn gradient(c: f64, w: DVec3, d: DVec3, d_ref: DVec3) -> DVec3 {
        c * elongation(w, d, d_ref) * w
    }

    /// The Hessian block `c w w^T` as the coefficients `(alpha, beta, u)` of
    /// `alpha I + beta u u^T`.
    #[inline]
    #[must_use]
    pub(in crate::potential) fn coefficients(c: f64, w: DVec3) -> (f64, f64, DVec3) {
        (0.0, c, w)
    }

    /// The Hessian block `c w w^T`.
    #[inline]
    #[must_use]
    pub(in crate::potential) fn block(c: f64, w: DVec3) -> SymBlock {
        let (alpha, beta, u) = coefficients(c, w);
        SymBlock::isotropic_plus_outer(alpha, beta, u)
    }
}

impl AxialDamping {
    /// Adds the damping force's negative, `c u (u . (v_a - v_b))` on `a` (minus on `b`),
    /// along each spring's current direction `u` at `x`, to `gradient`: the gradient of
    /// this term at `x = x_ref + h v` with the directions frozen at `x`, which is what an
    /// explicit integrator applies (it needs no frozen state, so it is not a method of
    /// [`Term`]). A zero-length spring exerts nothing.
    pub fn add_rate_gradient(
        system: &SpringSystem,
        x: &[DVec3],
        v: &[DVec3],
        gradient: &mut [DVec3],
    ) {
        let c = system.material().damping;
        if c <= 0.0 {
            return;
        }
        for s in system.springs() {
            let g = Self::rate_gradient(c, x[s.a] - x[s.b], v[s.a] - v[s.b]);
            gradient[s.a] += g;
            gradient[s.b] -= g;
        }
    }

    /// One spring's share of [`AxialDamping::add_rate_gradient`] on its first particle:
    /// `c u (u . dv)` for the spring vector `d` (`u = d/|d|`) and the relative velocity
    /// `dv = v_a - v_b`; zero for a zero-length spring.
    #[must_use]
    #[inline]
    pub fn rate_gradient(c: f64, d: DVec3, dv: DVec3) -> DVec3 {
        let l2 = d.length_squared();
        if l2 > 0.0 {
            // c (d . dv) / |d|^2 d, with no square root.
            (c * d.dot(dv) / l2) * d
        } else {
            DVec3::ZERO
        }
    }
}

impl Term for AxialDamping {
    fn name(&self) -> &'static str {
        "axial damping"
    }

    fn begin_step(&mut self, step: &StepContext<'_>) {
        // Without damping the term is zero and reads no direction: the pass over the
        // springs (3% of an undamped W6 step) is skipped.
        if Self::coefficient(step).is_none() {
            return;
        }
        // Four springs at a time (the same bits as `spring::damping_direction` per
        // spring): its two divisions by a scalar and its square root per spring were
        // 4% of the damped ground contact workload's instructions.
        let springs = step.system.springs();
        self.directions.resize(springs.len(), DVec3::ZERO);
        let x = step.system.positions();
        super::lanes::damping_directions(
            super::lanes::Instance::Detect,
            springs,
            x,
            &mut self.directions,
        );
        let x_ref = step.x_ref;
        self.references.clear();
        self.references
            .extend(springs.iter().map(|s| x_ref[s.a] - x_ref[s.b]));
    }

    fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        let Some(c) = Self::coefficient(step) else {
            return 0.0;
        };
        let mut e = 0.0;
        let frozen = self.directions.iter().zip(&self.references);
        for (sp, (&w, &d_ref)) in step.system.springs().iter().zip(frozen) {
            let d = x[sp.a] - x[sp.b];
            e += kernel::energy(c, w, d, d_ref);
        }
        e
    }

    fn energy_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        let Some(c) = Self::coefficient(step) else {
            return 0.0;
        };
        let mut change = 0.0;
        let frozen = self.directions.iter().zip(&self.references);
        for (sp, (&w, &d_ref)) in step.system.springs().iter().zip(frozen) {
            let delta = alpha * dx[sp.a] - alpha * dx[sp.b];
            if delta == DVec3::ZERO {
                continue;
            }
            let d = x[sp.a] - x[sp.b];
            change += kernel::energy_change(c, w, d, d_ref, delta);
        }
        change
    }

    fn add_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        let Some(c) = Self::coefficient(step) else {
            return;
        };
        let frozen = self.directions.iter().zip(&self.references);
        for (sp, (&w, &d_ref)) in step.system.springs().iter().zip(frozen) {
            let d = x[sp.a] - x[sp.b];
            let g = kernel::gradient(c, w, d, d_ref);
            gradient[sp.a] += g;
            gradient[sp.b] -= g;
        }
    }

    fn add_hessian(
        &self,
        step: &StepContext<'_>,
        _x: &[DVec3],
        _curvature: Curvature,
        sink: &mut HessianSink<'_>,
    ) {
        let Some(c) = Self::coefficient(step) else {
            return;
        };
        sink.add_edges_outer(
            step.system
                .springs()
                .iter()
                .zip(&self.directions)
                .enumerate()
                .map(|(s, (sp, &w))| {
                    let (alpha, beta, u) = kernel::coefficients(c, w);
                    (s, sp.a, sp.b, alpha, beta, u)
                }),
        );
    }
}
