//! Time of impact: how far a particle may move along a line-search direction before it
//! comes closer to a collider than a fraction of its current distance.
//!
//! The particle moves from `x` to `x + alpha dx` while the collider moves from its pose at
//! `t0` to its pose at `t1` (pose at `t0 + alpha (t1 - t0)`, its exact prescribed
//! motion). [`time_of_impact`] returns the largest `alpha` in `[0, 1]` such that the
//! particle's (thickness-offset) distance stays at least `(1 - s) d0` on all of
//! `[0, alpha]`, `d0` its distance at `alpha = 0` and `s` the fraction (default 0.9: a tenth kept, as in IPC), or a
//! smaller, safe value where no closed form exists:
//!
//! - closed forms when the collider only translates (its surface is then the same set
//!   shifted, so the particle's motion relative to it is linear): a linear equation for
//!   the half-space, a quadratic for the sphere, and for the capsule the first of the
//!   entries into its two end balls and its lateral cylinder. A rotation that leaves the
//!   surface in place counts as no rotation: any spin of a sphere about its centre, of a
//!   half-space about its normal, of a capsule about its own axis;
//! - otherwise conservative advancement: the distance is 1-Lipschitz in the particle's
//!   position in the collider's own frame, and that position moves at most
//!   `L = |dx - v dt| + |omega dt| (|x - r0| + |dx - v dt|)` per unit `alpha`, so from
//!   `alpha` with distance `d > (1 - s) d0` the particle is safe until
//!   `alpha + (d - (1 - s) d0)/L`. The advancement stops when the remaining margin is
//!   below 1e-3 of the allowed approach, returning a value that is never past the true
//!   time of impact.
//!
//! Derivations and the guarantee's argument: docs/contact.md.

use super::collider::{Collider, Shape, spin_keeps_surface};
use super::distance::distance_to;
use sinew_math::DVec3;

/// Largest number of conservative-advancement iterations. Each returns a safe `alpha`,
/// so the cap only makes a slowly converging case stop short, never unsafe.
const MAX_ADVANCEMENT_ITERATIONS: usize = 200;

/// The advancement stops once the margin above the target distance is below this
/// fraction of the allowed approach `s d0`.
const ADVANCEMENT_TOLERANCE: f64 = 1e-3;

/// The largest step fraction `alpha` in `[0, 1]` along `dx` such that the particle at
/// `x + alpha' dx` stays at distance at least `(1 - fraction) d0` from `collider` (posed
/// at `t0 + alpha' (t1 - t0)`) for every `alpha'` in `[0, alpha]`, where `d0` is its
/// distance at `alpha' = 0` and distances are measured from the surface offset by
/// `thickness`. Exact for a collider that does not rotate (or spins without moving its
/// surface), a safe lower bound otherwise (see the module documentation). A particle
/// that starts at distance `d0 <= 0` (touching or inside: never the case for an
/// admissible state) gets 0.
#[must_use]
pub fn time_of_impact(
    collider: &Collider,
    x: DVec3,
    dx: DVec3,
    t0: f64,
    t1: f64,
    thickness: f64,
    fraction: f64,
) -> f64 {
    time_of_impact_from(
        collider,
        &collider.at(t0),
        x,
        dx,
        (t0, t1),
        thickness,
        fraction,
    )
}

/// [`time_of_impact`] with the collider already posed at `t0` (`start`), for a caller
/// that asks about many particles against one collider over the same interval.
pub(crate) fn time_of_impact_from(
    collider: &Collider,
    start: &Shape,
    x: DVec3,
    dx: DVec3,
    (t0, t1): (f64, f64),
    thickness: f64,
    fraction: f64,
) -> f64 {
    let d0 = distance_to(start, x, thickness);
    if d0 <= 0.0 || d0.is_nan() {
        return 0.0;
    }
    let target = (1.0 - fraction) * d0;
    let dt = t1 - t0;
    let relative = dx - collider.motion.linear_velocity * dt;
    let omega = collider.motion.angular_velocity;
    if omega == DVec3::ZERO || spin_keeps_surface(start, omega) {
        return translating(start, x, relative, d0, target, thickness);
    }
    advance(collider, x, dx, t0, dt, relative, d0, target, thickness)
}

/// The closed form against a shape fixed at `shape` for the relative displacement
/// `relative`.
fn translating(
    shape: &Shape,
    x: DVec3,
    relative: DVec3,
    d0: f64,
    target: f64,
    thickness: f64,
) -> f64 {
    let hit = match *shape {
        Shape::HalfSpace { normal, .. } => {
            // d(alpha) = d0 + alpha n . dx: reaches the target only when approaching.
            let rate = normal.dot(relative);
            (rate < 0.0).then(|| (d0 - target) / -rate)
        }
        Shape::Sphere { center, radius } => {
            ball_entry(x - center, relative, radius + thickness + target)
        }
        Shape::Capsule { a, b, radius } => {
            let rho = radius + thickness + target;
            let ends = [
                ball_entry(x - a, relative, rho),
                ball_entry(x - b, relative, rho),
            ];
            let lateral = cylinder_entry(x - a, relative, b - a, rho);
            ends.into_iter().chain([lateral]).flatten().reduce(f64::min)
        }
    };
    hit.map_or(1.0, |alpha| alpha.clamp(0.0, 1.0))
}

/// The first `alpha >= 0` with `|p + alpha dp| = rho` for a start outside the ball
/// (`|p| > rho`), if the path enters it; `Some(0)` for a start inside.
fn ball_entry(p: DVec3, dp: DVec3, rho: f64) -> Option<f64> {
    let c = p.length_squared() - rho * rho;
    if c <= 0.0 {
        return Some(0.0);
    }
    let half_b = p.dot(dp);
    if half_b >= 0.0 {
        return None;
    }
    let a = dp.length_squared();
    let disc = half_b * half_b - a * c;
    // A tangent path (disc = 0) touches the sphere of radius rho and leaves it: the
    // distance never goes below the target, so it is not an entry.
    if disc <= 0.0 {
        return None;
    }
    // The smaller root (-b - sqrt(disc))/a, written as c/(-b + sqrt(disc)) so it keeps
    // its accuracy when a is tiny.
    Some(c / (-half_b + disc.sqrt()))
}

/// The first entry of `p + alpha dp` into the lateral surface of the cylinder of radius
/// `rho` about the segment from 0 to `axis`, if it happens between the segment's ends.
/// Entries through the end caps are entries into the end balls, which the caller
/// handles.
fn cylinder_entry(p: DVec3, dp: DVec3, axis: DVec3, rho: f64) -> Option<f64> {
    let len = axis.length();
    if len == 0.0 || !len.is_finite() {
        return None;
    }
    let e = axis / len;
    let across = |v: DVec3| v - v.dot(e) * e;
    let p_across = across(p);
    if p_across.length_squared() <= rho * rho {
        // Already within the infinite cylinder (beyond an end): no lateral entry.
        return None;
    }
    let alpha = ball_entry(p_across, across(dp), rho)?;
    let along = (p + alpha * dp).dot(e);
    (0.0..=len).contains(&along).then_some(alpha)
}

/// Conservative advancement against a collider that turns in a way that moves its
/// surface. Every returned value is safe (see the module documentation).
#[allow(clippy::too_many_arguments)]
fn advance(
    collider: &Collider,
    x: DVec3,
    dx: DVec3,
    t0: f64,
    dt: f64,
    relative: DVec3,
    d0: f64,
    target: f64,
    thickness: f64,
) -> f64 {
    let lever = (x - collider.reference_point_at(t0)).length() + relative.length();
    let lipschitz = relative.length() + (collider.motion.angular_velocity * dt).length() * lever;
    if lipschitz == 0.0 || !lipschitz.is_finite() {
        return if lipschitz == 0.0 { 1.0 } else { 0.0 };
    }
    let tolerance = ADVANCEMENT_TOLERANCE * (d0 - target);
    let mut alpha = 0.0;
    let mut d = d0;
    for _ in 0..MAX_ADVANCEMENT_ITERATIONS {
        let margin = d - target;
        if margin <= tolerance {
            break;
        }
        let next = alpha + margin / lipschitz;
        if next >= 1.0 {
            return 1.0;
        }
        alpha = next;
        let shape = collider.at(t0 + alpha * dt);
        d = distance_to(&shape, x + alpha * dx, thickness);
    }
    alpha
}
