//! Rigid colliders: a half-space (the ground), a sphere and a capsule, each static or
//! kinematic.
//!
//! A kinematic collider follows a prescribed rigid motion: its reference point (the
//! half-space's point, the sphere's centre, the capsule's midpoint) moves at a constant
//! linear velocity, and the collider turns about that point at a constant angular
//! velocity. The shape as written is the pose at the collider's `pose_time` (0 unless
//! set); [`Collider::at`] gives the pose at any time, exactly (no interpolation error),
//! and [`Collider::surface_velocity`] the velocity of the collider's material point at a
//! place, which friction and the explicit projection need.
//!
//! A collider steered as the run goes (a capsule on an animated limb) changes its motion
//! between steps: [`Collider::rebased`] keeps its pose at a time and gives it a new
//! motion from there, and [`Collider::moving_to`] the constant motion that carries its
//! pose at one time onto a target pose at a later one ([`Drive`] names the two, for the
//! integrators' `drive_collider`). The motion is piecewise constant, and the pose
//! continuous, in time.

use super::ContactError;
use sinew_math::{DQuat, DVec3};

/// The largest magnitude of a collider's coordinates (m), radius (m), speed (m/s),
/// angular speed (rad/s) and pose time (s), and of its coordinates wherever it is posed
/// for a step: far beyond any scene (1e50 m is 1e23 times the observable universe), and
/// small enough that the products and squares of such quantities in the distances, the
/// times of impact and the motion over a step stay finite in f64 (a sphere's centre at
/// 1e200 made the distance to it overflow and read as inside).
pub const MAX_COLLIDER_MAGNITUDE: f64 = 1e50;

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

/// A collider: a shape in its pose at `pose_time` and its motion.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct Collider {
    /// The shape at `pose_time`.
    pub shape: Shape,
    /// Its motion (default: static).
    #[cfg_attr(feature = "serde", serde(default))]
    pub motion: Motion,
    /// The time at which the collider is posed as `shape` (default 0); its motion runs
    /// from there, forwards and backwards alike.
    #[cfg_attr(feature = "serde", serde(default))]
    pub pose_time: f64,
}

/// How a collider is steered from the current time on (the integrators'
/// `drive_collider`): its pose now is kept, its motion changes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Drive {
    /// Move on with this motion ([`Collider::rebased`]); [`Motion::STATIC`] stops it.
    Motion(Motion),
    /// Reach `target` after `duration` seconds in one constant motion
    /// ([`Collider::moving_to`]), and keep that motion afterwards until driven again.
    /// Driving a collider before each step to where an animation puts it at the
    /// step's end makes the collider follow the animation, straight from pose to pose
    /// within each step.
    To {
        /// The pose to reach: the collider's own kind and size.
        target: Shape,
        /// Seconds from now, positive and finite.
        duration: f64,
    },
}

/// Relative tolerance of [`Collider::moving_to`] on a target's radius and axis length:
/// a rigid motion keeps both, and a pose computed by a chain of transforms (a limb from
/// forward kinematics) keeps them to round-off.
pub const TARGET_SIZE_TOLERANCE: f64 = 1e-9;

impl Collider {
    /// A static collider.
    #[must_use]
    pub fn fixed(shape: Shape) -> Self {
        Self {
            shape,
            motion: Motion::STATIC,
            pose_time: 0.0,
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

    /// Checks every field: all finite and within [`MAX_COLLIDER_MAGNITUDE`], radius
    /// positive, the half-space's normal of unit length to within 1e-9. The error names
    /// the shape and the field; use [`validate_colliders`] to have it name the
    /// collider's index too.
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
        let beyond = "is beyond 1e50 in magnitude (MAX_COLLIDER_MAGNITUDE, the range in \
                      which the contact geometry's products and squares stay finite)";
        let vector = |field, v: DVec3| {
            if !v.is_finite() {
                bad(field, finite)
            } else if v.abs().max_element() > MAX_COLLIDER_MAGNITUDE {
                bad(field, beyond)
            } else {
                Ok(())
            }
        };
        let radius_ok = |radius: f64| {
            if !(radius.is_finite() && radius > 0.0) {
                bad("radius", "is not positive and finite")
            } else if radius > MAX_COLLIDER_MAGNITUDE {
                bad("radius", beyond)
            } else {
                Ok(())
            }
        };
        match self.shape {
            Shape::HalfSpace { point, normal } => {
                vector("point", point)?;
                if !normal.is_finite() {
                    return bad("normal", finite);
                }
                if (normal.length() - 1.0).abs() > 1e-9 {
                    return bad("normal", "is not of unit length (to 1e-9)");
                }
            }
            Shape::Sphere { center, radius } => {
                vector("center", center)?;
                radius_ok(radius)?;
            }
            Shape::Capsule { a, b, radius } => {
                vector("a", a)?;
                vector("b", b)?;
                radius_ok(radius)?;
            }
        }
        vector("linear_velocity", self.motion.linear_velocity)?;
        vector("angular_velocity", self.motion.angular_velocity)?;
        if !self.pose_time.is_finite() {
            return bad("pose_time", finite);
        }
        if self.pose_time.abs() > MAX_COLLIDER_MAGNITUDE {
            return bad("pose_time", beyond);
        }
        Ok(())
    }

    /// Whether the collider posed at `t` ([`Self::at`]) has every coordinate finite and
    /// within [`MAX_COLLIDER_MAGNITUDE`]: a kinematic collider run far enough, or posed
    /// at a time that is not finite, has not.
    #[must_use]
    pub fn pose_in_range(&self, t: f64) -> bool {
        let within = |v: DVec3| v.is_finite() && v.abs().max_element() <= MAX_COLLIDER_MAGNITUDE;
        match self.at(t) {
            Shape::HalfSpace { point, normal } => within(point) && normal.is_finite(),
            Shape::Sphere { center, .. } => within(center),
            Shape::Capsule { a, b, .. } => within(a) && within(b),
        }
    }

    /// The rotation the collider has turned through from `pose_time` to `t`.
    #[must_use]
    pub fn rotation_at(&self, t: f64) -> DQuat {
        DQuat::from_scaled_axis(self.motion.angular_velocity * (t - self.pose_time))
    }

    /// The reference point at time `t`.
    #[must_use]
    pub fn reference_point_at(&self, t: f64) -> DVec3 {
        self.shape.reference_point() + self.motion.linear_velocity * (t - self.pose_time)
    }

    /// The shape in its pose at time `t` (exact for the prescribed motion; at
    /// `pose_time` it is `shape` itself, bit for bit).
    #[must_use]
    pub fn at(&self, t: f64) -> Shape {
        if self.is_static() || t == self.pose_time {
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

    /// The collider in its pose at `time`, moving on from there with `motion`: the pose
    /// is continuous at `time` (the new `shape` is [`Self::at`]`(time)`, so the two
    /// agree there bit for bit) and the velocities change there.
    #[must_use]
    pub fn rebased(&self, time: f64, motion: Motion) -> Self {
        Self {
            shape: self.at(time),
            motion,
            pose_time: time,
        }
    }

    /// The collider moving from its pose at `start` onto `target` at `end`, in one
    /// constant motion: the reference point at constant velocity, and a constant turn
    /// about it by the shortest rotation that takes the capsule's axis (from `a` to `b`)
    /// or the half-space's normal onto the target's. A turn that two poses do not
    /// determine (a sphere's spin, a capsule's about its own axis, a half-space's about
    /// its normal) is taken as none; give it with [`Self::rebased`]. The pose reached at
    /// `end` is the target to round-off, with the collider's own radius and axis length.
    ///
    /// # Errors
    /// [`ContactError::BadCollider`] (field `"target"`, or `"start"` / `"end"`) when the
    /// times are not finite or `end` is not after `start`, when the target is not finite,
    /// is another kind of shape, or differs from the collider in radius or axis length by
    /// more than [`TARGET_SIZE_TOLERANCE`] relative (a rigid motion keeps both), or when
    /// a half-space target's normal is not of unit length.
    pub fn moving_to(&self, start: f64, target: &Shape, end: f64) -> Result<Self, ContactError> {
        let bad = |field, reason| {
            Err(ContactError::BadCollider {
                collider: None,
                shape: self.shape.kind(),
                field,
                reason,
            })
        };
        if !start.is_finite() {
            return bad("start", "is not finite");
        }
        if !(end.is_finite() && end > start) {
            return bad("end", "is not finite and after the start");
        }
        let probe = Self::fixed(*target);
        if probe.validate().is_err() {
            return bad(
                "target",
                "is not a valid shape (finite, unit normal, positive radius)",
            );
        }
        let now = self.at(start);
        let size_differs = |mine: f64, theirs: f64, scale: f64| {
            (mine - theirs).abs() > TARGET_SIZE_TOLERANCE * scale
        };
        // The turn as an axis (unit) times an angle: the shortest rotation from one
        // direction to the other, by atan2 so that small and near-half turns keep their
        // precision.
        let turn = |from: DVec3, to: DVec3| -> DVec3 {
            let (from, to) = (from.normalize(), to.normalize());
            let axis = from.cross(to);
            let sin = axis.length();
            let cos = from.dot(to);
            if sin == 0.0 {
                return if cos > 0.0 {
                    DVec3::ZERO
                } else {
                    from.any_orthonormal_vector() * std::f64::consts::PI
                };
            }
            axis / sin * sin.atan2(cos)
        };
        let angular = match (now, *target) {
            (Shape::HalfSpace { normal, .. }, Shape::HalfSpace { normal: to, .. }) => {
                turn(normal, to)
            }
            (Shape::Sphere { radius, .. }, Shape::Sphere { radius: r, .. }) => {
                if size_differs(radius, r, radius) {
                    return bad("target", "has another radius than the collider");
                }
                DVec3::ZERO
            }
            (
                Shape::Capsule { a, b, radius },
                Shape::Capsule {
                    a: ta,
                    b: tb,
                    radius: r,
                },
            ) => {
                if size_differs(radius, r, radius) {
                    return bad("target", "has another radius than the collider");
                }
                let (length, target_length) = ((b - a).length(), (tb - ta).length());
                if size_differs(length, target_length, length.max(radius)) {
                    return bad("target", "has another axis length than the collider");
                }
                if length == 0.0 || target_length == 0.0 {
                    DVec3::ZERO
                } else {
                    turn(b - a, tb - ta)
                }
            }
            _ => return bad("target", "is another kind of shape than the collider"),
        };
        let duration = end - start;
        let motion = Motion {
            linear_velocity: (target.reference_point() - now.reference_point()) / duration,
            angular_velocity: angular / duration,
        };
        Ok(Self {
            shape: now,
            motion,
            pose_time: start,
        })
    }

    /// The collider driven at `time` by `drive` ([`Self::rebased`] or
    /// [`Self::moving_to`] from `time`).
    ///
    /// # Errors
    /// As [`Self::moving_to`]; a motion that is not finite is refused as
    /// [`Self::validate`] refuses it.
    pub fn driven(&self, time: f64, drive: &Drive) -> Result<Self, ContactError> {
        let driven = match *drive {
            Drive::Motion(motion) => self.rebased(time, motion),
            Drive::To { target, duration } => {
                if !(duration.is_finite() && duration > 0.0) {
                    return Err(ContactError::BadCollider {
                        collider: None,
                        shape: self.shape.kind(),
                        field: "duration",
                        reason: "is not positive and finite",
                    });
                }
                self.moving_to(time, &target, time + duration)?
            }
        };
        driven.validate()?;
        Ok(driven)
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
        c.validate().map_err(|e| naming_index(e, i))?;
    }
    Ok(())
}

/// Drives collider `index` of `colliders` at `time` ([`Collider::driven`]) and returns
/// the driven collider; on error (naming the index) the list is unchanged.
pub(crate) fn drive_in_list(
    colliders: &mut [Collider],
    index: usize,
    time: f64,
    drive: &Drive,
) -> Result<Collider, ContactError> {
    let count = colliders.len();
    let collider = colliders
        .get_mut(index)
        .ok_or(ContactError::NoSuchCollider { index, count })?;
    let driven = collider
        .driven(time, drive)
        .map_err(|e| naming_index(e, index))?;
    *collider = driven;
    Ok(driven)
}

/// `error` with the collider's index in it, when it is about one collider.
fn naming_index(error: ContactError, index: usize) -> ContactError {
    match error {
        ContactError::BadCollider {
            shape,
            field,
            reason,
            ..
        } => ContactError::BadCollider {
            collider: Some(index),
            shape,
            field,
            reason,
        },
        other => other,
    }
}
