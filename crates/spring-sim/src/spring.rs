//! Per-spring kernels: energy, gradient, exact Hessian block and its positive
//! semidefinite projection, and the frozen-direction axial damping term.
//!
//! With `d = x_a - x_b`, `l = |d|`, `u = d / l` and `E = k/2 (l - L)^2`:
//! - `dE/dx_a = k (l - L) u = -dE/dx_b`;
//! - the Hessian is `[[K, -K], [-K, K]]` with `K = k [u u^T + (1 - L/l)(I - u u^T)]`;
//! - the projection onto PSD matrices clamps `1 - L/l` at 0 (the block's eigenvalues are
//!   `k` along `u` and `k (1 - L/l)` twice across it, and the 6x6 Hessian's nonzero
//!   eigenvalues are twice those of `K`, with the same eigenvectors);
//! - the softened block keeps the fraction `1 - theta` of a compressed spring's negative
//!   curvature (the projected Newton step ignores the directions a compressed sheet
//!   buckles along; see [`Curvature::Softened`]).
//!
//! The derivation is in docs/spring-sim.md. The lab report's block
//! `k [(1 - L/l) I + u u^T]` is wrong (see [`crate::reference`]).

use sinew_math::{DMat3, DVec3, try_unit};

/// `u u^T`.
#[must_use]
pub fn outer(u: DVec3) -> DMat3 {
    DMat3::from_cols(u * u.x, u * u.y, u * u.z)
}

/// The direction and length of `d`, computed without underflow; `None` for a zero (or
/// non-finite) vector.
#[must_use]
fn direction_and_length(d: DVec3) -> Option<(DVec3, f64)> {
    try_unit(d).map(|u| (u, u.dot(d)))
}

/// Spring energy `k/2 (|x_a - x_b| - L)^2`.
#[must_use]
pub fn energy(x_a: DVec3, x_b: DVec3, rest_length: f64, stiffness: f64) -> f64 {
    energy_at_length((x_a - x_b).length(), rest_length, stiffness)
}

/// Spring energy `k/2 (l - L)^2` at length `l` (the one expression of [`energy`], so a
/// caller holding the length gets the same bits).
#[inline(always)]
#[must_use]
pub(crate) fn energy_at_length(l: f64, rest_length: f64, stiffness: f64) -> f64 {
    0.5 * stiffness * (l - rest_length) * (l - rest_length)
}

/// The change of the spring energy when the spring vector goes from `d` to `d + delta`,
/// computed from the difference itself, `k/2 (l' - l)(l' + l - 2L)` with
/// `l' - l = delta . (2d + delta) / (l' + l)`, so it keeps its relative accuracy when the
/// change is far below the energy (the line search compares such changes near
/// convergence).
#[must_use]
pub fn energy_change(d: DVec3, delta: DVec3, rest_length: f64, stiffness: f64) -> f64 {
    let l = d.length();
    let l_new = (d + delta).length();
    let sum = l + l_new;
    if sum == 0.0 {
        return 0.0;
    }
    let dl = delta.dot(2.0 * d + delta) / sum;
    0.5 * stiffness * dl * (sum - 2.0 * rest_length)
}

/// Gradient of the spring energy with respect to `x_a` (the one for `x_b` is its
/// negative). Zero at zero length, where the energy has a cone point and zero is a
/// subgradient.
#[must_use]
pub fn gradient(x_a: DVec3, x_b: DVec3, rest_length: f64, stiffness: f64) -> DVec3 {
    let d = x_a - x_b;
    let l = d.length();
    // `k (l - L) u = k (1 - L/l) d`: one division, the form of the explicit integrators'
    // hot loop. The plain length is enough unless it underflows or overflows; then the
    // scaled computation keeps tiny springs' direction.
    if l > 1e-150 && l.is_finite() {
        return (stiffness * (1.0 - rest_length * (1.0 / l))) * d;
    }
    match direction_and_length(d) {
        Some((u, l)) => stiffness * (l - rest_length) * u,
        None => DVec3::ZERO,
    }
}

/// Springs per batch of the batched kernels ([`gradients_of_batch`]).
pub(crate) const BATCH: usize = 4;

/// The lengths for which [`gradient`] takes its plain form `k (1 - L (1/l)) d`, the
/// condition of its fast path written without branches so a batch tests all its lanes
/// at once (a NaN length fails both comparisons, as it fails `is_finite`).
#[inline(always)]
fn plain_length(l: f64) -> bool {
    (l > 1e-150) & (l < f64::INFINITY)
}

/// A batch of [`BATCH`] springs as components: the spring vectors `d = x_a - x_b`, the
/// relative velocities `v_a - v_b` (read only with damping), the rest lengths and the
/// stiffnesses, lane `i` being the batch's `i`-th spring.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct SpringBatch {
    pub(crate) d: [[f64; BATCH]; 3],
    pub(crate) dv: [[f64; BATCH]; 3],
    pub(crate) rest_length: [f64; BATCH],
    pub(crate) stiffness: [f64; BATCH],
}

/// Each spring's [`gradient`] of a batch, plus its axial damping's
/// [`crate::potential::AxialDamping::rate_gradient`] when `c > 0`, by the same
/// floating-point operations in the same order as the scalar kernels, lane by lane, and
/// the lengths `|d|` (bitwise `d.length()`, for a caller that wants the energies too);
/// `None` when a length is outside the plain range `1e-150 < l < inf` (the caller then
/// uses the scalar kernels, whose other branches handle it).
///
/// Why a batch: the scalar loop is a chain per spring (square root, division, products)
/// followed by stores to the two particles, which the next spring sharing a particle
/// must wait for, so the processor overlaps few springs. Here the batch's chains have no
/// store between them, and each operation is written once over all lanes so the
/// compiler can pair lanes in packed square roots and divisions (the same correctly
/// rounded operations as the scalar ones). In the plain range the damping's `|d|^2` is
/// positive (`l > 0`), so its zero-length branch cannot be taken either.
#[inline(always)]
#[must_use]
pub(crate) fn gradients_of_batch(
    b: &SpringBatch,
    c: f64,
) -> Option<([[f64; BATCH]; 3], [f64; BATCH])> {
    let [dx, dy, dz] = &b.d;
    // `d.length()`: `(x x + y y) + z z`, then its square root.
    let mut l2 = [0.0; BATCH];
    for i in 0..BATCH {
        l2[i] = dx[i] * dx[i] + dy[i] * dy[i] + dz[i] * dz[i];
    }
    let mut l = [0.0; BATCH];
    for i in 0..BATCH {
        l[i] = l2[i].sqrt();
    }
    let mut plain = true;
    for &li in &l {
        plain &= plain_length(li);
    }
    if !plain {
        return None;
    }
    // `k (1 - L (1/l))`, the factor of `d`.
    let mut scale = [0.0; BATCH];
    for i in 0..BATCH {
        scale[i] = b.stiffness[i] * (1.0 - b.rest_length[i] * (1.0 / l[i]));
    }
    let mut g = [[0.0; BATCH]; 3];
    for (g, d) in g.iter_mut().zip(&b.d) {
        for i in 0..BATCH {
            g[i] = scale[i] * d[i];
        }
    }
    if c > 0.0 {
        // `(c (d . dv) / |d|^2) d`, added to the spring's term.
        let [vx, vy, vz] = &b.dv;
        let mut rate = [0.0; BATCH];
        for i in 0..BATCH {
            rate[i] = c * (dx[i] * vx[i] + dy[i] * vy[i] + dz[i] * vz[i]) / l2[i];
        }
        for (g, d) in g.iter_mut().zip(&b.d) {
            for i in 0..BATCH {
                g[i] += rate[i] * d[i];
            }
        }
    }
    Some((g, l))
}

/// Which form of a spring's Hessian block to use. Only the curvature across a
/// compressed spring differs between them (the block's eigenvalues are `k` along the
/// spring and `k (1 - L/l)` twice across it; docs/spring-sim.md).
///
/// A [`crate::potential::Term`] written outside this crate receives it: new forms may be
/// added (as `ExactContact` was), so it is `#[non_exhaustive]` and such a term's `match`
/// needs a catch-all arm (read an unknown form as the projection, the safe one).
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum Curvature {
    /// The exact Hessian: `k (1 - L/l)` across the spring, negative when compressed.
    Exact,
    /// The projection onto positive semidefinite matrices: `k max(0, 1 - L/l)` across.
    Clamped,
    /// `k (1 - L/l)` across a stretched spring and `(1 - theta) k (1 - L/l)` across a
    /// compressed one: the fraction `theta` in `[0, 1]` of the negative curvature is
    /// removed (`Softened(0)` is [`Curvature::Exact`], `Softened(1)` is
    /// [`Curvature::Clamped`]). The Newton matrix built from it grows with `theta`, so
    /// backward Euler raises `theta` until that matrix is positive definite.
    Softened(f64),
    /// [`Curvature::Softened`]`(theta)` for the springs (and bending), with the exact
    /// Hessians of the self-contact barrier's pairs instead of their projection, whose
    /// negative curvature no `theta` removes: backward Euler tries it first in every
    /// iteration of a system whose terms give such Hessians (at `theta` 1, the clamped
    /// springs, until Newton is slow), and falls back to `Softened(theta)` when the
    /// matrix is not positive definite (docs/contact.md). Terms without an exact form
    /// read it as `Softened(theta)`.
    ExactContact(f64),
}

/// The 3x3 block `K` of the spring Hessian (it enters as `+K` on the `(a, a)` and
/// `(b, b)` blocks and `-K` on `(a, b)` and `(b, a)`), in the form `curvature` asks for.
///
/// [`Curvature::Clamped`] clamps `1 - L/l` at 0, the exact projection of the spring's
/// Hessian onto positive semidefinite matrices; [`Curvature::Exact`] is the exact,
/// possibly indefinite Hessian. At zero length there is no direction: a zero-rest-length
/// spring has the exact Hessian `k I`; otherwise the clamped block is 0 (the projection of
/// every nearby Hessian is `k u u^T` for some `u`, and no `u` is preferred) and the
/// exact one does not exist, so 0 is returned for every form.
#[must_use]
pub fn hessian_block(
    x_a: DVec3,
    x_b: DVec3,
    rest_length: f64,
    stiffness: f64,
    curvature: Curvature,
) -> DMat3 {
    let (isotropic, axial, u) = hessian_coefficients(x_a - x_b, rest_length, stiffness, curvature);
    DMat3::from_diagonal(DVec3::splat(isotropic)) + outer(u) * axial
}

/// The block of [`hessian_block`] as `K = isotropic I + axial u u^T` (with
/// `isotropic = k (1 - L/l)` in the form `curvature` asks for, and `axial = k -
/// isotropic`), for `d = x_a - x_b`: the form the assembly uses to write the six distinct
/// entries directly.
#[must_use]
#[inline]
pub fn hessian_coefficients(
    d: DVec3,
    rest_length: f64,
    stiffness: f64,
    curvature: Curvature,
) -> (f64, f64, DVec3) {
    if rest_length == 0.0 {
        return (stiffness, 0.0, DVec3::ZERO);
    }
    // The plain length is enough unless it underflows; then fall back to the scaled
    // computation so tiny springs keep their direction.
    let l = d.length();
    let (u, l) = if l > 1e-150 && l.is_finite() {
        (d / l, l)
    } else {
        match direction_and_length(d) {
            Some(ul) => ul,
            None => return (0.0, 0.0, DVec3::ZERO),
        }
    };
    let exact = 1.0 - rest_length / l;
    let across = match curvature {
        Curvature::Exact => exact,
        Curvature::Clamped => exact.max(0.0),
        Curvature::Softened(theta) | Curvature::ExactContact(theta) => {
            exact.max(0.0) + (1.0 - theta) * exact.min(0.0)
        }
    };
    let isotropic = stiffness * across;
    (isotropic, stiffness - isotropic, u)
}

/// The frozen direction of a spring for the axial damping term: the unit vector along
/// `x_a - x_b` at the start of the step, or zero for a zero-length spring (which then
/// has no axial damping in that step).
#[must_use]
pub fn damping_direction(x_a: DVec3, x_b: DVec3) -> DVec3 {
    try_unit(x_a - x_b).unwrap_or(DVec3::ZERO)
}
