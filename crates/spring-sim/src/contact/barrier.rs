//! IPC's log barrier, the per-particle barrier energy against a collider, and the
//! adaptive barrier stiffness `kappa`.
//!
//! `b(d) = -(d - dhat)^2 ln(d / dhat)` for `0 < d < dhat`, 0 for `d >= dhat`, `+inf` for
//! `d <= 0`. It is twice continuously differentiable at `dhat` (value, `b'` and `b''`
//! all vanish there), positive, decreasing (`b' < 0`) and convex (`b'' > 0`) on
//! `(0, dhat)`, and grows without bound as `d -> 0`, so a minimizer of an energy that
//! includes it never reaches a collider.
//!
//! The energy of particle `x` against one collider is `kappa b(d(x))`, its gradient
//! `kappa b'(d) n` and its Hessian `kappa (b''(d) n n^T + b'(d) H_d)`. `b'' > 0`, but
//! `b' < 0` and the distance Hessian `H_d` is positive semidefinite for the convex
//! colliders, so the second term is negative semidefinite and the Hessian is indefinite;
//! its projection onto positive semidefinite matrices is `kappa b'' n n^T` in closed
//! form ([`point_barrier_projected_hessian`]).
//!
//! `kappa`'s rule (IPC's, written for distances rather than squared distances):
//! a minimum from the particles' mass, gravity, the step and `dhat`
//! ([`minimum_kappa`]), a start at the value that best balances the other forces at the
//! contacts ([`balanced_kappa`]) clamped to `[kappa_min, 100 kappa_min]` (by default),
//! and a doubling whenever the smallest distance is below a small fraction of `dhat` and
//! still falling ([`AdaptiveKappa::update`]). Derivations: docs/contact.md.

use super::ContactError;
use super::distance::SignedDistance;
use crate::spring::outer;
use sinew_math::{DMat3, DVec3};

/// `b(d) = -(d - dhat)^2 ln(d / dhat)` on `(0, dhat)`, 0 at and beyond `dhat`, `+inf` at
/// and below 0.
#[must_use]
pub fn barrier(d: f64, dhat: f64) -> f64 {
    if d <= 0.0 {
        f64::INFINITY
    } else if d >= dhat {
        0.0
    } else {
        let e = d - dhat;
        -e * e * (d / dhat).ln()
    }
}

/// `b'(d) = -2 (d - dhat) ln(d / dhat) - (d - dhat)^2 / d` on `(0, dhat)` (negative), 0
/// at and beyond `dhat`, `-inf` (its limit) at and below 0.
#[must_use]
pub fn barrier_first_derivative(d: f64, dhat: f64) -> f64 {
    if d <= 0.0 {
        f64::NEG_INFINITY
    } else if d >= dhat {
        0.0
    } else {
        let e = d - dhat;
        -2.0 * e * (d / dhat).ln() - e * e / d
    }
}

/// `b''(d) = -2 ln(d / dhat) + (dhat - d)(3 d + dhat) / d^2` on `(0, dhat)` (positive), 0
/// at and beyond `dhat`, `+inf` (its limit) at and below 0.
#[must_use]
pub fn barrier_second_derivative(d: f64, dhat: f64) -> f64 {
    if d <= 0.0 {
        f64::INFINITY
    } else if d >= dhat {
        0.0
    } else {
        -2.0 * (d / dhat).ln() + (dhat - d) * (3.0 * d + dhat) / (d * d)
    }
}

/// `b(d0 + change) - b(d0)`, computed from `change` itself where both distances lie in
/// `(0, dhat)`, so that it keeps its relative accuracy when the change is far below
/// `b`: with `e = d - dhat`, `b(d1) - b(d0) = -(change (e0 + e1) ln(d1/dhat) + e0^2
/// ln(1 + change/d0))` (the difference of `e^2` factored, and of the logarithms taken
/// as one `ln_1p`). A line search near convergence compares energy changes many orders
/// of magnitude below a contact's barrier energy, and the difference of the two
/// rounded values would bury them. `+inf` when `d0 + change <= 0`; the plain
/// difference where a distance is at or beyond `dhat` (one of the two values is then 0).
#[must_use]
pub fn barrier_change(d0: f64, change: f64, dhat: f64) -> f64 {
    let d1 = d0 + change;
    if d1 <= 0.0 {
        return f64::INFINITY;
    }
    if d0 <= 0.0 || d0 >= dhat || d1 >= dhat {
        return barrier(d1, dhat) - barrier(d0, dhat);
    }
    let (e0, e1) = (d0 - dhat, d1 - dhat);
    -(change * (e0 + e1) * (d1 / dhat).ln() + e0 * e0 * (change / d0).ln_1p())
}

/// The barrier energy of one particle against one collider.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PointBarrier {
    /// The distance is at least `dhat`: no energy, no force.
    Inactive,
    /// `0 < d < dhat`.
    Active {
        /// `kappa b(d)`.
        energy: f64,
        /// `kappa b'(d) n` (the contact force on the particle is its negative, along `+n`).
        gradient: DVec3,
        /// `kappa (b'' n n^T + b' H_d)` projected onto positive semidefinite matrices.
        hessian: DMat3,
    },
    /// `d <= 0`: the particle touches or is inside the collider, the energy is
    /// infinite. An admissible state never has one; the caller reports it naming the
    /// particle.
    Penetrating,
}

/// The barrier energy, gradient and projected Hessian of a particle whose signed
/// distance to a collider is `sd` (see [`super::signed_distance`]).
#[must_use]
pub fn point_barrier(kappa: f64, dhat: f64, sd: &SignedDistance) -> PointBarrier {
    let d = sd.distance;
    if d <= 0.0 {
        return PointBarrier::Penetrating;
    }
    if d >= dhat {
        return PointBarrier::Inactive;
    }
    let b1 = barrier_first_derivative(d, dhat);
    PointBarrier::Active {
        energy: kappa * barrier(d, dhat),
        gradient: kappa * b1 * sd.normal,
        hessian: point_barrier_projected_hessian(kappa, dhat, sd),
    }
}

/// The barrier's gradient `kappa b'(d) n` alone (zero at and beyond `dhat`; the limit
/// `-inf` times the normal at and below 0 is not returned: `None` there).
#[must_use]
pub fn point_barrier_gradient(kappa: f64, dhat: f64, sd: &SignedDistance) -> Option<DVec3> {
    let d = sd.distance;
    if d <= 0.0 {
        None
    } else if d >= dhat {
        Some(DVec3::ZERO)
    } else {
        Some(kappa * barrier_first_derivative(d, dhat) * sd.normal)
    }
}

/// The exact Hessian projected onto positive semidefinite matrices, in closed form:
/// `kappa b''(d) n n^T` on `(0, dhat)`, zero elsewhere. The exact Hessian is
/// `kappa (b'' n n^T + b' H_d)` with `b'' > 0`, `b' < 0`, and for every collider shape
/// `n` is an eigenvector of `H_d` with eigenvalue 0 while its other eigenvalues are
/// `>= 0`; so `n` is an eigenvector of the whole with eigenvalue `kappa b'' > 0` and the
/// others are `kappa b' lambda_k <= 0`, which the projection clamps at 0. This equals
/// [`super::psd::project_psd`] of [`point_barrier_exact_hessian`] (tested), without its
/// eigen-decomposition.
#[must_use]
pub fn point_barrier_projected_hessian(kappa: f64, dhat: f64, sd: &SignedDistance) -> DMat3 {
    let d = sd.distance;
    if d <= 0.0 || d >= dhat {
        return DMat3::ZERO;
    }
    outer(sd.normal) * (kappa * barrier_second_derivative(d, dhat))
}

/// The exact (unprojected, generally indefinite) Hessian `kappa (b'' n n^T + b' H_d)`;
/// zero outside `(0, dhat)`.
#[must_use]
pub fn point_barrier_exact_hessian(kappa: f64, dhat: f64, sd: &SignedDistance) -> DMat3 {
    let d = sd.distance;
    if d <= 0.0 || d >= dhat {
        return DMat3::ZERO;
    }
    let b1 = barrier_first_derivative(d, dhat);
    let b2 = barrier_second_derivative(d, dhat);
    (outer(sd.normal) * b2 + sd.hessian * b1) * kappa
}

/// `|b'(dhat / 2)| / dhat = ln 2 + 1/2`: the barrier's force at half the contact
/// distance, per unit `kappa` and `dhat`.
const HALF_DHAT_FORCE: f64 = std::f64::consts::LN_2 + 0.5;

/// The smallest barrier stiffness: the one whose barrier holds the force `f = m (|g| +
/// dhat / h^2)` at half the contact distance, `kappa_min = f / (dhat |b'(dhat/2)|/dhat)
/// = f / ((ln 2 + 1/2) dhat)`. `m |g|` is a resting particle's weight; `m dhat / h^2` is
/// the force that moves the particle by `dhat` in one step, so even without gravity the
/// barrier is stiff enough to matter against the inertia term over the contact band.
/// `average_mass` is the mean mass of the free particles, `gravity` the magnitude of the
/// gravity acceleration and `h` the (effective) time step; the result is positive for
/// positive `average_mass`, `dhat` and `h`.
#[must_use]
pub fn minimum_kappa(dhat: f64, average_mass: f64, gravity: f64, h: f64) -> f64 {
    let force = average_mass * (gravity.abs() + dhat / (h * h));
    force / (HALF_DHAT_FORCE * dhat)
}

/// IPC's balancing stiffness: the `kappa` that minimizes `|g_E + kappa g_B|`, with `g_E`
/// the gradient of the rest of the incremental potential and `g_B` the barrier's gradient
/// at unit stiffness (both over the same particles, zero where there is no contact):
/// `kappa = -(g_E . g_B) / |g_B|^2`. `None` when no particle is in contact (`g_B = 0`) or
/// the other forces pull away from the colliders (`kappa <= 0`).
#[must_use]
pub fn balanced_kappa(energy_gradient: &[DVec3], barrier_gradient: &[DVec3]) -> Option<f64> {
    let (num, den) = energy_gradient
        .iter()
        .zip(barrier_gradient)
        .fold((0.0, 0.0), |(num, den), (e, b)| {
            (num - e.dot(*b), den + b.length_squared())
        });
    let kappa = num / den;
    (den > 0.0 && kappa.is_finite() && kappa > 0.0).then_some(kappa)
}

/// The largest [`KappaSettings::max_ratio`] accepted. Beyond about `1e4 kappa_min` the
/// barrier's stiffness, not the cloth's, sets Newton's pace: on two 4 x 4 sheets dropped
/// onto each other with `kappa` sent straight to its bound (`growth` 1e300, `too_close`
/// 0.999), the worst step took 13 Newton iterations at a ratio of 1e4, 117 (in 3
/// pieces) at 1e5, 1 704 at 1e6, 31 641 at 1e12 and 224 446 at 1e16; at 1e300 the steps
/// in contact stalled (docs/contact.md, "The barrier stiffness `kappa`"). IPC's ratio,
/// the default, is 100.
pub const MAX_KAPPA_RATIO: f64 = 1e4;

/// The constants of the adaptive stiffness rule.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct KappaSettings {
    /// `kappa_max = max_ratio * kappa_min` (default 100, IPC's).
    pub max_ratio: f64,
    /// A distance below `too_close * dhat` is too small (default 0.01).
    pub too_close: f64,
    /// The factor `kappa` grows by when a distance is too small and falling (default 2).
    pub growth: f64,
}

impl Default for KappaSettings {
    fn default() -> Self {
        Self {
            max_ratio: 100.0,
            too_close: 0.01,
            growth: 2.0,
        }
    }
}

impl KappaSettings {
    /// Checks the constants: `1 <= max_ratio <=` [`MAX_KAPPA_RATIO`], `growth >= 1` and
    /// finite, `0 < too_close < 1`. The error names the setting (`kappa.max_ratio`, ...).
    pub fn validate(&self) -> Result<(), ContactError> {
        let bad = ContactError::bad_setting;
        if !(self.max_ratio >= 1.0 && self.max_ratio <= MAX_KAPPA_RATIO) {
            return bad(
                "kappa.max_ratio",
                self.max_ratio,
                "must lie between 1 and 1e4 (MAX_KAPPA_RATIO)",
            );
        }
        if !(self.growth.is_finite() && self.growth >= 1.0) {
            return bad("kappa.growth", self.growth, "must be at least 1 and finite");
        }
        if !(self.too_close > 0.0 && self.too_close < 1.0) {
            return bad(
                "kappa.too_close",
                self.too_close,
                "must lie strictly between 0 and 1",
            );
        }
        Ok(())
    }
}

/// The barrier stiffness over a run, adapted as IPC does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdaptiveKappa {
    /// The current stiffness.
    pub kappa: f64,
    /// Its lower bound ([`minimum_kappa`]).
    pub kappa_min: f64,
    /// Its upper bound, `max_ratio * kappa_min`.
    pub kappa_max: f64,
    /// The smallest contact distance seen at the last update (`+inf` before the first).
    pub previous_min_distance: f64,
    /// The rule's constants.
    pub settings: KappaSettings,
    /// Whether the balancing start ([`Self::start_balanced`]) has been applied.
    pub balanced: bool,
}

impl AdaptiveKappa {
    /// The starting stiffness: `balanced` (see [`balanced_kappa`]) clamped to
    /// `[kappa_min, max_ratio kappa_min]`, or `kappa_min` without one.
    #[must_use]
    pub fn new(kappa_min: f64, balanced: Option<f64>, settings: KappaSettings) -> Self {
        let kappa_max = settings.max_ratio * kappa_min;
        let kappa = balanced.map_or(kappa_min, |k| k.clamp(kappa_min, kappa_max));
        Self {
            kappa,
            kappa_min,
            kappa_max,
            previous_min_distance: f64::INFINITY,
            settings,
            balanced: balanced.is_some(),
        }
    }

    /// IPC's balancing start, applied once: the first time it is given a balance (see
    /// [`balanced_kappa`]; the caller computes one at the start of a step that begins
    /// with particles in contact), `kappa` becomes that balance clamped to `[kappa_min,
    /// kappa_max]`, or stays if the growth rule already took it higher (contact usually
    /// begins within a step, where a barrier found too weak has grown). Later calls
    /// change nothing: from then on only the growth rule acts, so the potential changes
    /// between steps only where the barrier is losing, and a conservative scheme (the
    /// midpoint) is not pumped by a stiffness that follows its oscillations. Returns
    /// whether `kappa` was set.
    pub fn start_balanced(&mut self, balanced: f64) -> bool {
        if self.balanced || !(balanced.is_finite() && balanced > 0.0) {
            return false;
        }
        self.balanced = true;
        self.kappa = self
            .kappa
            .max(balanced.clamp(self.kappa_min, self.kappa_max));
        true
    }

    /// After an iterate with smallest contact distance `min_distance` (`+inf` when
    /// nothing is within `dhat`): if it is below `too_close * dhat` and smaller than the
    /// previous one, the particles are being pushed toward the colliders faster than the
    /// barrier resists, so `kappa` grows by `growth` (up to `kappa_max`). Returns whether
    /// it grew.
    pub fn update(&mut self, min_distance: f64, dhat: f64) -> bool {
        let grow = min_distance < self.settings.too_close * dhat
            && min_distance < self.previous_min_distance
            && self.kappa < self.kappa_max;
        self.previous_min_distance = min_distance;
        if grow {
            self.kappa = (self.kappa * self.settings.growth).min(self.kappa_max);
        }
        grow
    }
}
