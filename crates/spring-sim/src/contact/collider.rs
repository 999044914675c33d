//! Rigid colliders: a half-space (the ground), a sphere and a capsule, each static or
//! kinematic.
//!
//! A kinematic collider follows a prescribed rigid motion: its reference point (the
//! half-space's point, the sphere's centre, the capsule's midpoint) moves at a constant
//! linear velocity, and the collider turns about that point at a constant angular
//! velocity. The shape as written is the pose at time 0; [`Collider::at`] gives the pose
//! at any time, exactly (no interpolation error), and [`Collider::surface_velocity`] the
//! velocity of the collider's material point at a place, which friction and the explicit
//! projection need.

use super::ContactError;
use sinew_math::{DQuat, DVec3};

/// The geometry of a collider, in its pose at time 0 (or, from [`Collider::at`], at a
/// given time).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub enum Shape {
    /// The half-space `{x : normal . (x - point) <= 0}`: the solid lies below the plane
    /// through `point`, and `normal` (unit) points out of it, into free space.
    HalfSpace {
        /// A point of the boundary plane, and the collider's reference point.
        point: DVec3,
        /// The unit outward normal.
        normal: DVec3,
    },
    /// A solid ball.
    Sphere {
        /// The centre, and the collider's reference point.
        center: DVec3,
        /// The radius, positive.
        radius: f64,
    },
    /// The points within `radius` of the segment from `a` to `b`. A capsule whose ends
    /// coincide (`a == b`) is accepted and is exactly the sphere of that radius at `a`.
    Capsule {
        /// First end of the axis segment.
        a: DVec3,
        /// Second end of the axis segment.
        b: DVec3,
        /// The radius, positive.
        radius: f64,
    },
}

impl Shape {
    /// The shape's name in error messages.
    #[must_use]
    pub fn kind(&self) -> &'static str {
        match self {
            Self::HalfSpace { .. } => "half-space",
            Self::Sphere { .. } => "sphere",
            Self::Capsule { .. } => "capsule",
        }
    }

    /// The reference point the collider turns about: the half-space's point, the
    /// sphere's centre, the capsule's midpoint.
    #[must_use]
    pub fn reference_point(&self) -> DVec3 {
        match *self {
            Self::HalfSpace { point, .. } => point,
            Self::Sphere { center, .. } => center,
            Self::Capsule { a, b, .. } => 0.5 * (a + b),
        }
    }
}

/// A prescribed rigid motion: constant linear velocity of the reference point and
/// constant angular velocity about it. The default is at rest (a static collider).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct Motion {
    /// Velocity of the reference point, scene units per second.
    pub linear_velocity: DVec3,
    /// Angular velocity (axis times rate, radians per second) about the reference point.
    pub angular_velocity: DVec3,
}

impl Motion {
    /// At rest.
    pub const STATIC: Self = Self {
        linear_velocity: DVec3::ZERO,
        angular_velocity: DVec3::ZERO,
    };
}

/// A collider: a shape in its pose at time 0 and its motion.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct Collider {
    /// The shape at time 0.
    pub shape: Shape,
    /// Its motion (default: static).
    #[cfg_attr(feature = "serde", serde(default))]
    pub motion: Motion,
}

impl Collider {
    /// A static collider.
    #[must_use]
    pub fn fixed(shape: Shape) -> Self {
        Self {
            shape,
            motion: Motion::STATIC,
        }
    }

    /// The static ground: the half-space below the plane `y = height`, normal `+y`.
    #[must_use]
    pub fn ground(height: f64) -> Self {
        Self::fixed(Shape::HalfSpace {
            point: DVec3::new(0.0, height, 0.0),
            normal: DVec3::Y,
        })
    }

    /// A static sphere.
    #[must_use]
    pub fn sphere(center: DVec3, radius: f64) -> Self {
        Self::fixed(Shape::Sphere { center, radius })
    }

    /// A static capsule.
    #[must_use]
    pub fn capsule(a: DVec3, b: DVec3, radius: f64) -> Self {
        Self::fixed(Shape::Capsule { a, b, radius })
    }

    /// The same collider with the given motion.
    #[must_use]
    pub fn moving(self, linear_velocity: DVec3, angular_velocity: DVec3) -> Self {
        Self {
            motion: Motion {
                linear_velocity,
                angular_velocity,
            },
            ..self
        }
    }

    /// Whether the collider never moves.
    #[must_use]
    pub fn is_static(&self) -> bool {
        self.motion.linear_velocity == DVec3::ZERO && self.motion.angular_velocity == DVec3::ZERO
    }

    /// Whether the collider's surface moves: it translates, or it turns about an axis
    /// that does not map its surface onto itself (a sphere spinning about its centre, a
    /// half-space about its normal, a capsule about its own axis leave their surface in
    /// place). Only such a collider can run into a particle that stays still.
    #[must_use]
    pub fn moves_surface(&self) -> bool {
        let omega = self.motion.angular_velocity;
        self.motion.linear_velocity != DVec3::ZERO
            || !(omega == DVec3::ZERO || spin_keeps_surface(&self.shape, omega))
    }

    /// Checks every field: all finite, radius positive, the half-space's normal of unit
    /// length to within 1e-9. The error names the shape and the field; use
    /// [`validate_colliders`] to have it name the collider's index too.
    pub fn validate(&self) -> Result<(), ContactError> {
        let shape = self.shape.kind();
        let bad = |field, reason| {
            Err(ContactError::BadCollider {
                collider: None,
                shape,
                field,
                reason,
            })
        };
        let finite = "is not finite";
        match self.shape {
            Shape::HalfSpace { point, normal } => {
                if !point.is_finite() {
                    return bad("point", finite);
                }
                if !normal.is_finite() {
                    return bad("normal", finite);
                }
                if (normal.length() - 1.0).abs() > 1e-9 {
                    return bad("normal", "is not of unit length (to 1e-9)");
                }
            }
            Shape::Sphere { center, radius } => {
                if !center.is_finite() {
                    return bad("center", finite);
                }
                if !(radius.is_finite() && radius > 0.0) {
                    return bad("radius", "is not positive and finite");
                }
            }
            Shape::Capsule { a, b, radius } => {
                if !a.is_finite() {
                    return bad("a", finite);
                }
                if !b.is_finite() {
                    return bad("b", finite);
                }
                if !(radius.is_finite() && radius > 0.0) {
                    return bad("radius", "is not positive and finite");
                }
            }
        }
        if !self.motion.linear_velocity.is_finite() {
            return bad("linear_velocity", finite);
        }
        if !self.motion.angular_velocity.is_finite() {
            return bad("angular_velocity", finite);
        }
        Ok(())
    }

    /// The rotation the collider has turned through from time 0 to `t`.
    #[must_use]
    pub fn rotation_at(&self, t: f64) -> DQuat {
        DQuat::from_scaled_axis(self.motion.angular_velocity * t)
    }

    /// The reference point at time `t`.
    #[must_use]
    pub fn reference_point_at(&self, t: f64) -> DVec3 {
        self.shape.reference_point() + self.motion.linear_velocity * t
    }

    /// The shape in its pose at time `t` (exact for the prescribed motion).
    #[must_use]
    pub fn at(&self, t: f64) -> Shape {
        if self.is_static() {
            return self.shape;
        }
        let r0 = self.shape.reference_point();
        let r = self.reference_point_at(t);
        let q = self.rotation_at(t);
        match self.shape {
            Shape::HalfSpace { normal, .. } => Shape::HalfSpace {
                point: r,
                // Renormalised so a long run cannot drift the normal off unit length.
                normal: (q * normal).normalize(),
            },
            // The centre is the reference point: a spin leaves the ball where it is.
            Shape::Sphere { radius, .. } => Shape::Sphere { center: r, radius },
            Shape::Capsule { a, b, radius } => Shape::Capsule {
                a: r + q * (a - r0),
                b: r + q * (b - r0),
                radius,
            },
        }
    }

    /// The velocity at time `t` of the collider's material point that is at `point`:
    /// `v + omega x (point - r(t))`.
    #[must_use]
    pub fn surface_velocity(&self, point: DVec3, t: f64) -> DVec3 {
        self.motion.linear_velocity
            + self
                .motion
                .angular_velocity
                .cross(point - self.reference_point_at(t))
    }
}

/// Whether turning about the reference point with angular velocity `omega` maps the
/// shape's surface onto itself (then only the translation matters).
pub(crate) fn spin_keeps_surface(shape: &Shape, omega: DVec3) -> bool {
    match *shape {
        Shape::Sphere { .. } => true,
        Shape::HalfSpace { normal, .. } => omega.cross(normal) == DVec3::ZERO,
        Shape::Capsule { a, b, .. } => a == b || omega.cross(b - a) == DVec3::ZERO,
    }
}

/// Validates a list of colliders; the error names the index of the first bad one.
pub fn validate_colliders(colliders: &[Collider]) -> Result<(), ContactError> {
    for (i, c) in colliders.iter().enumerate() {
        c.validate().map_err(|e| match e {
            ContactError::BadCollider {
                shape,
                field,
                reason,
                ..
            } => ContactError::BadCollider {
                collider: Some(i),
                shape,
                field,
                reason,
            },
            other => other,
        })?;
    }
    Ok(())
}
