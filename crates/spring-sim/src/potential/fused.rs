//! The per-spring terms of the mass-spring potential ([`Springs`] and [`AxialDamping`])
//! evaluated in one loop over the springs.
//!
//! Each term's per-spring formulas are written once, in its own module's kernels; this
//! loop only calls both kernels on the same spring. Separate passes, one per term behind
//! dynamic dispatch, reread every spring's particles and rewrote every Hessian slot once
//! per term, which made Newton's assembly markedly slower than a single pass.

use super::damping::{AxialDamping, kernel as damping};
use super::lanes::{self, Instance};
use super::springs::{self, Springs};
use super::{HessianSink, StepContext, SymBlock, Term};
use crate::model::SpringSystem;
use crate::spring::{self, Curvature};
use sinew_math::DVec3;

/// Springs per chunk of the sequential loops that compute a chunk's gradients or blocks
/// four springs at a time into a buffer on the stack before adding them.
const CHUNK: usize = 64;

/// The per-spring terms a potential holds, with the damping's coefficient `c/h` when it
/// is active (a material without damping skips it).
#[derive(Clone, Copy, Debug)]
pub(super) struct PerSpring<'t> {
    /// Whether the potential has the spring term.
    pub(super) springs: bool,
    /// The damping term and its coefficient `c/h`, when present and nonzero.
    pub(super) damping: Option<(&'t AxialDamping, f64)>,
}

impl PerSpring<'_> {
    /// The damping of the springs `range` for the four-spring kernels ([`lanes`]), when
    /// the damping term is active.
    pub(super) fn lanes_damping(
        &self,
        range: std::ops::Range<usize>,
    ) -> Option<lanes::Damping<'_>> {
        self.damping.map(|(term, c)| lanes::Damping {
            c,
            directions: &term.directions()[range.clone()],
            references: &term.reference_vectors()[range],
        })
    }

    /// The sum of the terms' energies.
    pub(super) fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        match (self.springs, self.damping) {
            (true, Some((term, c))) => {
                let mut e = 0.0;
                let frozen = term.directions().iter().zip(term.reference_vectors());
                for (s, (&w, &d_ref)) in step.system.springs().iter().zip(frozen) {
                    let d = x[s.a] - x[s.b];
                    e += springs::energy(s, x) + damping::energy(c, w, d, d_ref);
                }
                e
            }
            (true, None) => Springs.energy(step, x),
            (false, Some((term, _))) => term.energy(step, x),
            (false, None) => 0.0,
        }
    }

    /// The sum of the terms' changes along `alpha dx`.
    pub(super) fn energy_change(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        dx: &[DVec3],
        alpha: f64,
    ) -> f64 {
        match (self.springs, self.damping) {
            (true, Some(_)) => {
                self.energy_change_over(step, x, dx, alpha, 0..step.system.springs().len())
            }
            (true, None) => Springs.energy_change(step, x, dx, alpha),
            (false, Some((term, _))) => term.energy_change(step, x, dx, alpha),
            (false, None) => 0.0,
        }
    }

    /// [`Self::energy_change`] over the springs `range` only, with the same per-spring
    /// expressions and the same order of additions within the range; the spring term
    /// must be present (the caller falls back to the whole sum otherwise).
    pub(super) fn energy_change_over(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        dx: &[DVec3],
        alpha: f64,
        range: std::ops::Range<usize>,
    ) -> f64 {
        debug_assert!(self.springs);
        let springs = &step.system.springs()[range.clone()];
        if let Some((term, c)) = self.damping {
            // Damped, spring by spring: the four-spring kernel gives the same bits but
            // takes a quarter more instructions on the ground contact workload (its
            // gathers of the springs' ends into lanes cost more than the packed square
            // roots and division save at one step length; measured again with the
            // reference vectors cached: 96.5 M against 77.3 M over the run), and no
            // measurable time (docs/contact.md).
            let mut change = 0.0;
            let frozen = term.directions()[range.clone()]
                .iter()
                .zip(&term.reference_vectors()[range]);
            for (s, (&w, &d_ref)) in springs.iter().zip(frozen) {
                let delta = alpha * dx[s.a] - alpha * dx[s.b];
                if delta == DVec3::ZERO {
                    continue;
                }
                let d = x[s.a] - x[s.b];
                change += springs::energy_change(s, x, delta)
                    + damping::energy_change(c, w, d, d_ref, delta);
            }
            return change;
        }
        lanes::energy_change_sum(Instance::Detect, springs, x, dx, alpha, None)
    }

    /// [`Self::energy_change_over`] at two step lengths in one pass over the springs
    /// `range`: each spring's positions and direction are read once for both, and each
    /// of the two sums is the one [`Self::energy_change_over`] makes at its length, the
    /// same bits.
    pub(super) fn energy_change_pair_over(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        dx: &[DVec3],
        [a1, a2]: [f64; 2],
        range: std::ops::Range<usize>,
    ) -> [f64; 2] {
        debug_assert!(self.springs);
        let springs = &step.system.springs()[range.clone()];
        // Four springs at a time, the damping's change added to each spring's as the
        // loop of `Self::energy_change` adds it: the same bits.
        let damping = self.lanes_damping(range);
        lanes::energy_change_pair_sum(Instance::Detect, springs, x, dx, [a1, a2], damping)
    }

    /// Adds the sum of the terms' gradients to `gradient`.
    pub(super) fn add_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        match (self.springs, self.damping) {
            (true, _) => {
                // A chunk's gradients four springs at a time ([`lanes`], the damping's
                // added to each spring's) into a buffer, then the chunk's scatter in
                // spring order: the same values added in the same order as the loop
                // calling both kernels per spring, so the same bits.
                let mut buffer = [DVec3::ZERO; CHUNK];
                let springs = step.system.springs();
                for first in (0..springs.len()).step_by(CHUNK) {
                    let range = first..(first + CHUNK).min(springs.len());
                    let g = &mut buffer[..range.len()];
                    let damping = self.lanes_damping(range.clone());
                    let chunk = &springs[range];
                    lanes::gradients(Instance::Detect, chunk, x, damping, g);
                    for (s, &g) in chunk.iter().zip(&*g) {
                        gradient[s.a] += g;
                        gradient[s.b] -= g;
                    }
                }
            }
            (false, Some((term, _))) => term.add_gradient(step, x, gradient),
            (false, None) => {}
        }
    }

    /// Adds the sum of the terms' blocks, one edge block per spring, to `sink`.
    pub(super) fn add_hessian(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        sink: &mut HessianSink<'_>,
    ) {
        match (self.springs, self.damping) {
            (true, Some(_)) => {
                // A chunk's blocks four springs at a time ([`lanes`]: the spring's block
                // plus the damping's, entry by entry, the same bits), then the chunk's
                // edges in spring order.
                let mut buffer = [SymBlock([0.0; 6]); CHUNK];
                let springs = step.system.springs();
                for first in (0..springs.len()).step_by(CHUNK) {
                    let range = first..(first + CHUNK).min(springs.len());
                    let b = &mut buffer[..range.len()];
                    let damping = self.lanes_damping(range.clone());
                    let chunk = &springs[range];
                    lanes::blocks(Instance::Detect, chunk, x, curvature, damping, b);
                    let edges = chunk.iter().zip(&*b).enumerate();
                    sink.add_edges(edges.map(|(i, (s, &k))| (first + i, s.a, s.b, k)));
                }
            }
            (true, None) => Springs.add_hessian(step, x, curvature, sink),
            (false, Some((term, _))) => term.add_hessian(step, x, curvature, sink),
            (false, None) => {}
        }
    }
}

/// Per particle, the absolute row sums over the free unknowns of the springs'
/// PSD-projected Hessian `K` (into `k_rows`) and of the damping matrix `C` along the
/// springs' current directions (into `c_rows`, zero without damping) at `system`'s
/// state; both overwritten. This is the Hessian of [`Springs`] and of [`AxialDamping`]
/// with `h = 1` and its directions frozen now, from the same kernels, in one loop: the
/// stability bound reads it before every explicit step, and separate passes per term
/// (with the damping's directions stored first) made those steps a third slower.
pub(crate) fn rate_row_sums(
    system: &SpringSystem,
    k_rows: &mut Vec<DVec3>,
    c_rows: &mut Vec<DVec3>,
) {
    let n = system.len();
    let fixed = system.fixed();
    let x = system.positions();
    k_rows.clear();
    k_rows.resize(n, DVec3::ZERO);
    c_rows.clear();
    c_rows.resize(n, DVec3::ZERO);
    let c = system.material().damping;
    // Each block appears on the diagonal and, when the other end is free, again as the
    // coupling block of the same row. The damping is tested once, not per spring.
    let ends = |a: usize, b: usize| {
        let (fa, fb) = (fixed[a], fixed[b]);
        (fa, fb, if fa || fb { 1.0 } else { 2.0 })
    };
    if c > 0.0 {
        for s in system.springs() {
            let (alpha, beta, u) = springs::coefficients(s, x, Curvature::Clamped);
            let rk = nonnegative_row_sums(alpha, beta, u);
            let w = spring::damping_direction(x[s.a], x[s.b]);
            let (alpha, beta, u) = damping::coefficients(c, w);
            let rc = nonnegative_row_sums(alpha, beta, u);
            let (fa, fb, both) = ends(s.a, s.b);
            if !fa {
                k_rows[s.a] += both * rk;
                c_rows[s.a] += both * rc;
            }
            if !fb {
                k_rows[s.b] += both * rk;
                c_rows[s.b] += both * rc;
            }
        }
    } else {
        for s in system.springs() {
            let (alpha, beta, u) = springs::coefficients(s, x, Curvature::Clamped);
            let rk = nonnegative_row_sums(alpha, beta, u);
            let (fa, fb, both) = ends(s.a, s.b);
            if !fa {
                k_rows[s.a] += both * rk;
            }
            if !fb {
                k_rows[s.b] += both * rk;
            }
        }
    }
}

/// The absolute row sums of `alpha I + beta u u^T` for `alpha, beta >= 0` (the
/// PSD-projected spring block and the damping block): row `c` is
/// `alpha + beta |u_c| |u|_1`, every entry being nonnegative up to its sign pattern.
#[inline]
fn nonnegative_row_sums(alpha: f64, beta: f64, u: DVec3) -> DVec3 {
    debug_assert!(alpha >= 0.0 && beta >= 0.0);
    let au = u.abs();
    DVec3::splat(alpha) + (beta * au.element_sum()) * au
}

/// `y += K z` over the free unknowns, `K` the springs' PSD-projected Hessian at
/// `system`'s state (entries of `z` at fixed particles are taken as zero and `y` is not
/// written there): the product the stability bound's Lanczos iteration repeats, in one
/// loop from the spring term's kernel.
pub(crate) fn rate_product(system: &SpringSystem, z: &[DVec3], y: &mut [DVec3]) {
    let fixed = system.fixed();
    let x = system.positions();
    for s in system.springs() {
        let (alpha, beta, u) = springs::coefficients(s, x, Curvature::Clamped);
        let za = if fixed[s.a] { DVec3::ZERO } else { z[s.a] };
        let zb = if fixed[s.b] { DVec3::ZERO } else { z[s.b] };
        let d = za - zb;
        let t = alpha * d + beta * u.dot(d) * u;
        if !fixed[s.a] {
            y[s.a] += t;
        }
        if !fixed[s.b] {
            y[s.b] -= t;
        }
    }
}
