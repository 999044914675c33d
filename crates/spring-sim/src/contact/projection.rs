//! Contact for the explicit integrators: a projection after each (sub)step. **Not
//! guaranteed**: it acts only on the state at the end of a substep, so a particle fast
//! enough to cross a thin collider within one substep (a capsule thinner than
//! `|v| dt`) passes through it unseen. The implicit integrators' barrier and
//! time-of-impact cap are the guaranteed method.
//!
//! A particle found inside a collider (signed distance, minus the thickness, below 0) is
//! pushed out along the normal to the offset surface. Its velocity relative to the
//! collider's surface, `w = v - v_s`, loses its inward normal part `w_n = n . w < 0`, and
//! Coulomb friction takes at most `mu |w_n|` off the tangential part (the impulse that
//! stopped the normal motion, times `mu`), stopping it entirely if it is smaller.

use super::collider::Collider;
use super::distance::signed_distance;
use sinew_math::DVec3;

/// A particle's state after the projection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProjectedParticle {
    /// The position, outside the collider.
    pub position: DVec3,
    /// The velocity.
    pub velocity: DVec3,
    /// Whether the particle was inside the collider (and so was moved).
    pub contact: bool,
}

/// Projects the particle at `x` with velocity `v` out of `collider` at time `t` (see the
/// module documentation; not guaranteed). A particle outside is returned unchanged.
#[must_use]
pub fn project_particle(
    collider: &Collider,
    t: f64,
    x: DVec3,
    v: DVec3,
    thickness: f64,
    mu: f64,
) -> ProjectedParticle {
    let shape = collider.at(t);
    let sd = signed_distance(&shape, x, thickness);
    if sd.distance >= 0.0 {
        return ProjectedParticle {
            position: x,
            velocity: v,
            contact: false,
        };
    }
    let n = sd.normal;
    let position = x - sd.distance * n;
    let surface = collider.surface_velocity(sd.closest_point, t);
    let w = v - surface;
    let w_n = n.dot(w);
    let mut velocity = v;
    if w_n < 0.0 {
        let tangential = w - w_n * n;
        let speed = tangential.length();
        let kept = if speed > 0.0 {
            (1.0 - mu * -w_n / speed).max(0.0)
        } else {
            0.0
        };
        velocity = surface + kept * tangential;
    }
    ProjectedParticle {
        position,
        velocity,
        contact: true,
    }
}
