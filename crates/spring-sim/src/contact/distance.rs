//! Signed distance from a point to a posed collider, with its gradient (the unit outward
//! normal) and its Hessian.
//!
//! - Half-space: `d = n . (x - p)`, gradient `n`, Hessian 0.
//! - Sphere: `d = |x - c| - r`, gradient `n = (x - c)/|x - c|`, Hessian
//!   `(I - n n^T)/|x - c|`.
//! - Capsule: the distance to the axis segment minus the radius. Where the closest axis
//!   point is inside the segment the Hessian is that of the distance to the axis line,
//!   `(I - e e^T - n n^T)/rho` (`e` the unit axis, `rho` the distance to the line); where
//!   it is an end, the sphere's about that end. The distance is continuously
//!   differentiable everywhere outside the axis; its Hessian jumps across the planes
//!   through the ends, and on them the end's (sphere) Hessian is used.
//!
//! A thickness `tau >= 0` offsets the surface outward: the returned distance is
//! `d - tau`, with the same gradient and Hessian.
//!
//! Degenerate points, where the distance has no gradient (a sphere's centre, a point on
//! a capsule's axis), get a defined answer: a fixed unit normal (`+y` for the sphere,
//! a fixed unit vector perpendicular to the axis for the capsule) and a zero Hessian.
//! They are deep inside the collider, where the barrier is infinite, so no admissible
//! state ever evaluates them. Derivations: docs/contact.md.

use super::collider::Shape;
use crate::spring::outer;
use sinew_math::{DMat3, DVec3};

/// The signed distance from a point to a collider and its first two derivatives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SignedDistance {
    /// Signed distance (negative inside), minus the thickness.
    pub distance: f64,
    /// Its gradient with respect to the point: the unit outward normal at the closest
    /// surface point.
    pub normal: DVec3,
    /// Its Hessian with respect to the point (positive semidefinite for all three
    /// shapes, which are convex).
    pub hessian: DMat3,
    /// The closest point of the collider's surface (not offset by the thickness).
    pub closest_point: DVec3,
}

/// The `distance` of [`signed_distance`] alone, with the same arithmetic (so the same
/// bits): the barrier's energy, the time of impact and the line search's changes read
/// only the distance, and building the normal, Hessian and closest point for every
/// particle of a cloth resting on the ground was a pass's worth of work per call.
#[must_use]
#[inline]
pub(crate) fn distance_to(shape: &Shape, x: DVec3, thickness: f64) -> f64 {
    match *shape {
        Shape::HalfSpace { point, normal } => normal.dot(x - point) - thickness,
        _ => signed_distance(shape, x, thickness).distance,
    }
}

/// The signed distance from `x` to `shape` (already posed, see
/// [`super::Collider::at`]), minus `thickness`.
#[must_use]
pub fn signed_distance(shape: &Shape, x: DVec3, thickness: f64) -> SignedDistance {
    match *shape {
        Shape::HalfSpace { point, normal } => {
            let d = normal.dot(x - point);
            SignedDistance {
                distance: d - thickness,
                normal,
                hessian: DMat3::ZERO,
                closest_point: x - d * normal,
            }
        }
        Shape::Sphere { center, radius } => ball(center, radius, x, thickness, DVec3::Y),
        Shape::Capsule { a, b, radius } => {
            let axis = b - a;
            let len2 = axis.length_squared();
            let t = if len2 > 0.0 {
                (axis.dot(x - a) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            // A fixed direction across the axis, for the degenerate point on the axis.
            let across = if len2 > 0.0 {
                (axis / len2.sqrt()).any_orthonormal_vector()
            } else {
                DVec3::Y
            };
            if t <= 0.0 {
                return ball(a, radius, x, thickness, across);
            }
            if t >= 1.0 {
                return ball(b, radius, x, thickness, across);
            }
            let e = axis / len2.sqrt();
            let foot = a + t * axis;
            let w = x - foot;
            let rho = length(w);
            if rho > 0.0 && rho.is_finite() {
                let n = w / rho;
                let hessian = (DMat3::IDENTITY - outer(e) - outer(n)) * (1.0 / rho);
                SignedDistance {
                    distance: rho - radius - thickness,
                    normal: n,
                    hessian,
                    closest_point: foot + radius * n,
                }
            } else {
                SignedDistance {
                    distance: -radius - thickness,
                    normal: across,
                    hessian: DMat3::ZERO,
                    closest_point: foot + radius * across,
                }
            }
        }
    }
}

/// `|w|`, also where `|w|^2` overflows (a point farther than about 1.3e154 from the
/// centre read as at the centre, inside, before this was scaled).
fn length(w: DVec3) -> f64 {
    let rho = w.length();
    if rho.is_infinite() && w.is_finite() {
        let m = w.abs().max_element();
        m * (w / m).length()
    } else {
        rho
    }
}

/// Distance to a ball; `fallback` is the normal at the centre.
fn ball(center: DVec3, radius: f64, x: DVec3, thickness: f64, fallback: DVec3) -> SignedDistance {
    let w = x - center;
    let rho = length(w);
    if rho > 0.0 && rho.is_finite() {
        let n = w / rho;
        SignedDistance {
            distance: rho - radius - thickness,
            normal: n,
            hessian: (DMat3::IDENTITY - outer(n)) * (1.0 / rho),
            closest_point: center + radius * n,
        }
    } else {
        SignedDistance {
            distance: -radius - thickness,
            normal: fallback,
            hessian: DMat3::ZERO,
            closest_point: center + radius * fallback,
        }
    }
}

/// The signed distances (minus `thickness`) of `x` and of `x + delta` to `shape`, the
/// second computed as the first plus a change evaluated from `delta` itself wherever the
/// closest feature is the same at both points (the plane; the ball or the lateral surface
/// of the same piece of a capsule): `|p + delta| - |p| = delta . (2p + delta) /
/// (|p + delta| + |p|)`. A line search near convergence compares energy changes many
/// orders of magnitude below the energies, and the difference of two rounded distances
/// would bury them.
#[must_use]
pub fn distance_pair(shape: &Shape, x: DVec3, delta: DVec3, thickness: f64) -> (f64, f64) {
    let (d0, change) = distance_change(shape, x, delta, thickness);
    (d0, d0 + change)
}

/// The signed distance `d0` (minus `thickness`) of `x` to `shape` and its change
/// `d1 - d0` at `x + delta`, the change evaluated from `delta` itself wherever the
/// closest feature is the same at both points (see [`distance_pair`]), otherwise as the
/// difference of the two distances. Kept apart from `d0` so that a change far below
/// the distance's last digit survives (`d0 + change` would round it to an ulp of `d0`).
#[must_use]
pub fn distance_change(shape: &Shape, x: DVec3, delta: DVec3, thickness: f64) -> (f64, f64) {
    let d0 = distance_to(shape, x, thickness);
    let radial = |p: DVec3, dp: DVec3| {
        let (l0, l1) = (p.length(), (p + dp).length());
        let sum = l0 + l1;
        (sum > 0.0).then(|| dp.dot(2.0 * p + dp) / sum)
    };
    let change = match *shape {
        Shape::HalfSpace { normal, .. } => Some(normal.dot(delta)),
        Shape::Sphere { center, .. } => radial(x - center, delta),
        Shape::Capsule { a, b, .. } => {
            let axis = b - a;
            let len2 = axis.length_squared();
            let param = |p: DVec3| {
                if len2 > 0.0 {
                    axis.dot(p - a) / len2
                } else {
                    0.0
                }
            };
            let (t0, t1) = (param(x), param(x + delta));
            if t0 <= 0.0 && t1 <= 0.0 {
                radial(x - a, delta)
            } else if t0 >= 1.0 && t1 >= 1.0 {
                radial(x - b, delta)
            } else if t0 > 0.0 && t0 < 1.0 && t1 > 0.0 && t1 < 1.0 {
                let e = axis / len2.sqrt();
                let across = |v: DVec3| v - v.dot(e) * e;
                radial(across(x - a), across(delta))
            } else {
                None
            }
        }
    };
    let change = match change {
        Some(c) => c,
        None => distance_to(shape, x + delta, thickness) - d0,
    };
    (d0, change)
}
