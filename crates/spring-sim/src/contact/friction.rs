//! Lagged, smoothed Coulomb friction per contact, as in IPC.
//!
//! At the start of a step, for each particle within `dhat` of a collider, the contact's
//! normal force magnitude `lambda = -kappa b'(d) > 0`, its unit normal `n` and an
//! orthonormal tangent basis `T = [t1 t2]` of the plane across `n` are computed and then
//! held fixed ("lagged") through the step's minimization. The tangential relative
//! displacement over the step is
//!
//! ```text
//! u(x) = T^T (x - x_n - h v_s),
//! ```
//!
//! `v_s` the velocity of the collider's material point at the contact (zero for a static
//! collider), so friction acts on the motion relative to the collider's surface. The
//! friction energy is `D(x) = mu lambda f0(|u|)`, with `f0' = f1` IPC's mollifier of the
//! sliding direction,
//!
//! ```text
//! f1(y) = 2 y/eps - y^2/eps^2   (y < eps),   1   (y >= eps),   eps = eps_v h,
//! f0(y) = y^2/eps - y^3/(3 eps^2) + eps/3   (y < eps),   y   (y >= eps),
//! ```
//!
//! so the friction force `-grad D` has magnitude `mu lambda` once the particle slides
//! faster than `eps_v` relative to the surface (exact Coulomb), and falls smoothly to 0
//! with the relative speed below it (static friction approximated by a slow creep). The
//! Hessian in the tangent plane has the eigenvalue `mu lambda f1'(y)` along the sliding
//! direction and `mu lambda f1(y)/y` across it; both are non-negative for this
//! mollifier, and they are clamped at 0 anyway, which is the exact projection onto
//! positive semidefinite matrices. Derivations: docs/contact.md.

use super::ContactSettings;
use super::barrier::barrier_first_derivative;
use super::collider::{Collider, Shape};
use super::distance::signed_distance;
use crate::spring::outer;
use sinew_math::{DMat3, DVec3};

/// `f0(y)`: the mollified `|u|`, continuously differentiable, with `f0' = f1`.
#[must_use]
pub fn f0(y: f64, eps: f64) -> f64 {
    if y >= eps {
        y
    } else {
        y * y / eps - y * y * y / (3.0 * eps * eps) + eps / 3.0
    }
}

/// `f1(y)`: the mollified friction force magnitude per `mu lambda`, in `[0, 1]`.
#[must_use]
pub fn f1(y: f64, eps: f64) -> f64 {
    if y >= eps {
        1.0
    } else {
        2.0 * y / eps - y * y / (eps * eps)
    }
}

/// `f1'(y)`: `2/eps - 2 y/eps^2` below `eps`, 0 beyond.
#[must_use]
pub fn f1_derivative(y: f64, eps: f64) -> f64 {
    if y >= eps {
        0.0
    } else {
        2.0 / eps - 2.0 * y / (eps * eps)
    }
}

/// `f1(y)/y`, with its limit `2/eps` at `y = 0`.
#[must_use]
fn f1_over_y(y: f64, eps: f64) -> f64 {
    if y >= eps {
        1.0 / y
    } else {
        2.0 / eps - y / (eps * eps)
    }
}

/// One lagged friction contact between a particle and a collider.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrictionContact {
    /// `mu lambda`: the friction coefficient times the lagged normal force magnitude,
    /// the largest friction force.
    pub max_force: f64,
    /// The lagged unit normal.
    pub normal: DVec3,
    /// The lagged tangent basis (orthonormal, across `normal`).
    pub basis: [DVec3; 2],
    /// The particle's position at the step's start, `x_n`.
    pub start: DVec3,
    /// The collider surface's displacement over the step at the contact, `h v_s`.
    pub surface_displacement: DVec3,
    /// The smoothing displacement `eps = eps_v h`.
    pub epsilon: f64,
}

impl FrictionContact {
    /// The contact of the particle at `x_n` (time `t_n`) with `collider`, lagged for a
    /// step of length `h` with barrier stiffness `kappa`: `None` when the particle is not
    /// within `(0, dhat)` of the collider or when `mu = 0` (no friction to add).
    #[must_use]
    pub fn lagged(
        collider: &Collider,
        x_n: DVec3,
        t_n: f64,
        h: f64,
        kappa: f64,
        settings: &ContactSettings,
    ) -> Option<Self> {
        Self::lagged_posed(collider, &collider.at(t_n), x_n, t_n, h, kappa, settings)
    }

    /// [`Self::lagged`] with the collider's pose at `t_n` given (`posed`, which must be
    /// `collider.at(t_n)`): a step lags every particle against the same pose, computed
    /// once instead of once per particle.
    #[must_use]
    pub(crate) fn lagged_posed(
        collider: &Collider,
        posed: &Shape,
        x_n: DVec3,
        t_n: f64,
        h: f64,
        kappa: f64,
        settings: &ContactSettings,
    ) -> Option<Self> {
        let sd = signed_distance(posed, x_n, settings.thickness);
        if !(sd.distance > 0.0 && sd.distance < settings.dhat) || settings.mu == 0.0 {
            return None;
        }
        let lambda = -kappa * barrier_first_derivative(sd.distance, settings.dhat);
        let (t1, t2) = sd.normal.any_orthonormal_pair();
        Some(Self {
            max_force: settings.mu * lambda,
            normal: sd.normal,
            basis: [t1, t2],
            start: x_n,
            surface_displacement: h * collider.surface_velocity(sd.closest_point, t_n),
            epsilon: settings.eps_v * h,
        })
    }

    /// The tangential relative displacement `T^T (x - x_n - h v_s)`, as its two
    /// coordinates in the basis.
    #[must_use]
    pub fn tangential_displacement(&self, x: DVec3) -> [f64; 2] {
        let w = x - self.start - self.surface_displacement;
        [self.basis[0].dot(w), self.basis[1].dot(w)]
    }

    /// The same displacement as a vector in the tangent plane, `T T^T w`.
    #[must_use]
    fn tangential_vector(&self, x: DVec3) -> DVec3 {
        let [u1, u2] = self.tangential_displacement(x);
        u1 * self.basis[0] + u2 * self.basis[1]
    }

    /// `mu lambda f0(|u|)`.
    #[must_use]
    pub fn energy(&self, x: DVec3) -> f64 {
        let [u1, u2] = self.tangential_displacement(x);
        self.max_force * f0(u1.hypot(u2), self.epsilon)
    }

    /// `E(x + delta) - E(x)`, computed from `delta` itself (`|u'| - |u| = du . (2u + du)
    /// / (|u'| + |u|)`, and the mollifier's difference factored by it) so that it keeps
    /// its relative accuracy when the change is far below the energy, as the line search
    /// needs near convergence.
    #[must_use]
    pub fn energy_change(&self, x: DVec3, delta: DVec3) -> f64 {
        let [u1, u2] = self.tangential_displacement(x);
        let du = [self.basis[0].dot(delta), self.basis[1].dot(delta)];
        let y0 = u1.hypot(u2);
        let y1 = (u1 + du[0]).hypot(u2 + du[1]);
        let sum = y0 + y1;
        if sum == 0.0 {
            return 0.0;
        }
        let dy = (du[0] * (2.0 * u1 + du[0]) + du[1] * (2.0 * u2 + du[1])) / sum;
        let eps = self.epsilon;
        let change = if y0 >= eps && y1 >= eps {
            dy
        } else if y0 < eps && y1 < eps {
            // f0(y1) - f0(y0) = (y1^2 - y0^2)/eps - (y1^3 - y0^3)/(3 eps^2).
            dy * (sum / eps - (y1 * y1 + y1 * y0 + y0 * y0) / (3.0 * eps * eps))
        } else {
            f0(y1, eps) - f0(y0, eps)
        };
        self.max_force * change
    }

    /// `mu lambda f1(|u|) T u/|u|` (0 at `u = 0`); the friction force is its negative.
    #[must_use]
    pub fn gradient(&self, x: DVec3) -> DVec3 {
        let t = self.tangential_vector(x);
        self.max_force * f1_over_y(t.length(), self.epsilon) * t
    }

    /// The Hessian `mu lambda [f1'(y) s s^T + f1(y)/y (P - s s^T)]`, `s` the unit sliding
    /// direction and `P = I - n n^T` the projection onto the tangent plane, with both
    /// coefficients clamped at 0 (the exact projection onto PSD matrices); at `y = 0`
    /// its limit `mu lambda (2/eps) P`.
    #[must_use]
    pub fn hessian(&self, x: DVec3) -> DMat3 {
        let t = self.tangential_vector(x);
        let y = t.length();
        let plane = DMat3::IDENTITY - outer(self.normal);
        let across = f1_over_y(y, self.epsilon).max(0.0);
        if y == 0.0 || !y.is_finite() {
            return plane * (self.max_force * across);
        }
        let s = t / y;
        let along = f1_derivative(y, self.epsilon).max(0.0);
        let ss = outer(s);
        (ss * along + (plane - ss) * across) * self.max_force
    }
}
