//! Joint limits, one copy for every inverse-kinematics solver.
//!
//! A [`JointLimit`] bounds a joint's local rotation *relative to its rest rotation*: callers
//! pass `q_rel = rest⁻¹ * q_local`, never the incoming pose. The kinds are
//!
//! - [`JointLimit::Free`]: any rotation (the default);
//! - [`JointLimit::Fixed`]: only the identity;
//! - [`JointLimit::Hinge`]: a rotation about one axis, its angle in a range;
//! - [`JointLimit::SwingTwist`]: `q = swing * twist`, the twist about the bone's rest
//!   direction in a range and the swing's rotation vector inside an ellipse.
//!
//! Each limit offers [`JointLimit::project`] (the nearest allowed rotation, exact for a
//! hinge), [`JointLimit::violation`] (how far outside, in radians, computed independently of
//! `project`) and [`JointLimit::sample`] (allowed rotations uniform in the limit's
//! parameters, for feasible workloads). [`swing_twist`] is the decomposition they share.
//!
//! All angles are radians, in code and in scene data. Axes must be unit vectors (to 1e-9,
//! see [`JointLimit::validate`]); the constructors ([`JointLimit::hinge`],
//! [`JointLimit::cone`], [`JointLimit::swing_twist`]) normalise them for you. The
//! derivations (which point the projection picks and why, what it guarantees, how the
//! violation is measured) are in `docs/ik-limits.md`.

use sinew_math::{DQuat, DVec3, try_unit};
use std::f64::consts::{PI, TAU};
use std::fmt;

/// How far from 1 an axis's length may be, and how far from 0 the cosine between a
/// swing-twist limit's two axes may be.
pub const AXIS_TOLERANCE: f64 = 1e-9;

/// How close to a half turn [`JointLimit::sample`] lets a swing come; see there.
pub const SAMPLE_SWING_MARGIN: f64 = 1e-3;

/// A limit on a joint's rotation relative to its rest rotation; see the
/// [module docs](self).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum JointLimit {
    /// Any rotation is allowed.
    #[default]
    Free,
    /// Only the rest rotation (the identity) is allowed.
    Fixed,
    /// A rotation about one axis, its angle in a range.
    Hinge(Hinge),
    /// A swing inside an ellipse of rotation vectors followed by a twist in a range.
    SwingTwist(SwingTwist),
}

/// A hinge: rotations by `angle` about `axis` with `min <= angle <= max` (radians).
///
/// The range lies within `[-pi, pi]`; the full range `[-pi, pi]` leaves the rotation about
/// the axis free (only the off-axis part is removed).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct Hinge {
    /// The rotation axis, a unit vector in the joint's rest frame.
    pub axis: DVec3,
    /// The smallest allowed angle, radians, in `[-pi, pi]`.
    pub min: f64,
    /// The largest allowed angle, radians, in `[min, pi]`.
    pub max: f64,
}

/// Swing-twist: `q = swing * twist`, twist about `twist_axis` (the rest direction of the
/// child bone), swing about an axis perpendicular to it.
///
/// The swing's rotation vector `s` (perpendicular to `twist_axis`) is bounded by the
/// ellipse `(s.a_axis / swing_a)^2 + (s.b_axis / swing_b)^2 <= 1`, where
/// `b_axis = twist_axis x a_axis`; the twist angle lies in `[twist_min, twist_max]`. All
/// angles are radians. A cone of half-angle `c` with free twist is `swing_a = swing_b = c`
/// with the twist range `[-pi, pi]`.
///
/// Example, a shoulder whose child bone lies along +x: `twist_axis` +x, `a_axis` +z,
/// `swing_a` 100 degrees (the swing about z, in the x-y plane), `swing_b` 70 degrees (about
/// y), twist within +-80 degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct SwingTwist {
    /// The twist axis, the unit rest direction of the child bone.
    pub twist_axis: DVec3,
    /// The unit axis of the ellipse's `swing_a` semi-axis, perpendicular to `twist_axis`.
    pub a_axis: DVec3,
    /// The largest swing about `a_axis`, radians, in `(0, pi]`.
    pub swing_a: f64,
    /// The largest swing about `twist_axis x a_axis`, radians, in `(0, pi]`.
    pub swing_b: f64,
    /// The smallest twist angle, radians, in `[-pi, pi]`.
    pub twist_min: f64,
    /// The largest twist angle, radians, in `[twist_min, pi]`.
    pub twist_max: f64,
}

/// Why a limit was refused. Every variant names the offending field and its value.
#[derive(Clone, Debug, PartialEq)]
pub enum LimitError {
    /// An axis has a NaN or infinite component, or its length is not within
    /// [`AXIS_TOLERANCE`] of 1 (constructors: it is zero or not finite).
    Axis {
        /// The field, e.g. `"axis"` or `"twist_axis"`.
        field: &'static str,
        /// The value given.
        value: DVec3,
    },
    /// A swing-twist limit's `a_axis` is not perpendicular to its `twist_axis`.
    NotPerpendicular {
        /// The `a_axis` given.
        a_axis: DVec3,
        /// The `twist_axis` given.
        twist_axis: DVec3,
        /// The cosine of the angle between them (after normalisation).
        cosine: f64,
    },
    /// An angle is NaN, infinite or outside the interval allowed for its field.
    Angle {
        /// The field, e.g. `"swing_a"` or `"min"`.
        field: &'static str,
        /// The value given.
        value: f64,
        /// The interval allowed, e.g. `"[-pi, pi]"`.
        allowed: &'static str,
    },
    /// A range's lower bound is above its upper bound.
    EmptyRange {
        /// The lower bound's field.
        min_field: &'static str,
        /// The lower bound.
        min: f64,
        /// The upper bound's field.
        max_field: &'static str,
        /// The upper bound.
        max: f64,
    },
}

impl fmt::Display for LimitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Axis { field, value } => write!(
                f,
                "{field} = {value} is not a finite unit vector (its length {} must be within {AXIS_TOLERANCE:e} of 1)",
                value.length()
            ),
            Self::NotPerpendicular {
                a_axis,
                twist_axis,
                cosine,
            } => write!(
                f,
                "a_axis = {a_axis} is not perpendicular to twist_axis = {twist_axis} (cosine {cosine:e}, must be within {AXIS_TOLERANCE:e} of 0)"
            ),
            Self::Angle {
                field,
                value,
                allowed,
            } => write!(f, "{field} = {value} is not in {allowed} (radians)"),
            Self::EmptyRange {
                min_field,
                min,
                max_field,
                max,
            } => write!(
                f,
                "{min_field} = {min} is greater than {max_field} = {max}, so the range is empty"
            ),
        }
    }
}

impl std::error::Error for LimitError {}

impl JointLimit {
    /// A hinge about `axis` (normalised here) from `min` to `max` radians, validated.
    pub fn hinge(axis: DVec3, min: f64, max: f64) -> Result<Self, LimitError> {
        let axis = try_unit(axis).ok_or(LimitError::Axis {
            field: "axis",
            value: axis,
        })?;
        let limit = Self::Hinge(Hinge { axis, min, max });
        limit.validate()?;
        Ok(limit)
    }

    /// A cone of half-angle `half_angle` radians about `twist_axis` (normalised here), the
    /// twist free: a swing-twist limit with `swing_a = swing_b = half_angle` and the twist
    /// range `[-pi, pi]`. Validated.
    pub fn cone(twist_axis: DVec3, half_angle: f64) -> Result<Self, LimitError> {
        let unit = try_unit(twist_axis).ok_or(LimitError::Axis {
            field: "twist_axis",
            value: twist_axis,
        })?;
        Self::swing_twist(
            unit,
            unit.any_orthonormal_vector(),
            half_angle,
            half_angle,
            -PI,
            PI,
        )
    }

    /// A swing-twist limit (see [`SwingTwist`]), both axes normalised here, validated
    /// (which includes that the axes are perpendicular).
    pub fn swing_twist(
        twist_axis: DVec3,
        a_axis: DVec3,
        swing_a: f64,
        swing_b: f64,
        twist_min: f64,
        twist_max: f64,
    ) -> Result<Self, LimitError> {
        let twist_unit = try_unit(twist_axis).ok_or(LimitError::Axis {
            field: "twist_axis",
            value: twist_axis,
        })?;
        let a_unit = try_unit(a_axis).ok_or(LimitError::Axis {
            field: "a_axis",
            value: a_axis,
        })?;
        let limit = Self::SwingTwist(SwingTwist {
            twist_axis: twist_unit,
            a_axis: a_unit,
            swing_a,
            swing_b,
            twist_min,
            twist_max,
        });
        limit.validate()?;
        Ok(limit)
    }

    /// Checks every field: axes finite with length within [`AXIS_TOLERANCE`] of 1 (and, for
    /// swing-twist, `a_axis` perpendicular to `twist_axis` to the same tolerance after
    /// normalisation); hinge and twist bounds finite, within `[-pi, pi]` and `min <= max`;
    /// swing half-angles in `(0, pi]`. [`Free`](Self::Free) and [`Fixed`](Self::Fixed)
    /// are always valid.
    ///
    /// [`project`](Self::project), [`violation`](Self::violation) and
    /// [`sample`](Self::sample) assume a valid limit: they do not panic on an invalid one,
    /// but their result is then unspecified. Limits read from scene data should be
    /// validated before use.
    pub fn validate(&self) -> Result<(), LimitError> {
        match self {
            Self::Free | Self::Fixed => Ok(()),
            Self::Hinge(h) => {
                check_axis("axis", h.axis)?;
                check_range("min", h.min, "max", h.max)
            }
            Self::SwingTwist(st) => {
                check_axis("twist_axis", st.twist_axis)?;
                check_axis("a_axis", st.a_axis)?;
                let cosine = st.twist_axis.normalize().dot(st.a_axis.normalize());
                // Both axes passed the checks above, so the cosine is finite.
                if cosine.abs() > AXIS_TOLERANCE {
                    return Err(LimitError::NotPerpendicular {
                        a_axis: st.a_axis,
                        twist_axis: st.twist_axis,
                        cosine,
                    });
                }
                check_half_angle("swing_a", st.swing_a)?;
                check_half_angle("swing_b", st.swing_b)?;
                check_range("twist_min", st.twist_min, "twist_max", st.twist_max)
            }
        }
    }

    /// The allowed rotation nearest to `q` (a rotation relative to the rest rotation).
    ///
    /// - [`Free`](Self::Free): `q`, normalised. [`Fixed`](Self::Fixed): the identity.
    /// - [`Hinge`](Self::Hinge): exact, the geodesically nearest allowed rotation: the
    ///   rotation about the axis by `q`'s twist angle, clamped to the range; outside the
    ///   range it goes to whichever bound is nearer on the circle (a tie goes to `max`).
    /// - [`SwingTwist`](Self::SwingTwist): `q` is decomposed by [`swing_twist`], the twist
    ///   clamped as for a hinge, the swing's rotation vector moved to the nearest point of
    ///   the ellipse (Euclidean in the plane of rotation vectors), and the two recomposed.
    ///   This is not the geodesic projection onto the whole allowed set; see
    ///   `docs/ik-limits.md` for what it guarantees.
    ///
    /// A rotation already allowed is returned unchanged (normalised). The result is
    /// normalised, never NaN, represents the same rotation for `q` and `-q`, and has the
    /// sign that makes its dot product with `q` non-negative. A zero or non-finite `q` is
    /// treated as the identity. Idempotent up to rounding.
    #[must_use]
    pub fn project(&self, q: DQuat) -> DQuat {
        let q = unit_quat(q).unwrap_or(DQuat::IDENTITY);
        match self {
            Self::Free => q,
            Self::Fixed => same_sign(DQuat::IDENTITY, q),
            Self::Hinge(h) => project_hinge(h, unit_or_x(h.axis), q),
            Self::SwingTwist(st) => project_swing_twist(st, &Frame::of(st), q),
        }
    }

    /// How far `q` is outside the limit, in radians; 0 exactly when `q` is allowed (the
    /// same test [`project`](Self::project) uses to return `q` unchanged).
    ///
    /// Computed from the decomposition directly, not from `project`:
    ///
    /// - [`Free`](Self::Free): 0. [`Fixed`](Self::Fixed): the rotation angle of `q`.
    /// - [`Hinge`](Self::Hinge): the larger of the off-axis swing angle (the angle of the
    ///   swing in [`swing_twist`]`(q, axis)`) and the twist angle's distance on the circle to
    ///   the range (0 inside it).
    /// - [`SwingTwist`](Self::SwingTwist): the larger of the twist's distance to its range
    ///   (as for a hinge) and the swing's radial excess: how far the swing's rotation vector
    ///   reaches past the ellipse along its own direction, `|s| - rho(s / |s|)` where
    ///   `rho(u)` is the ellipse's radius in direction `u` (0 inside). The radial excess is
    ///   at least the distance from `s` to the ellipse, and at most that distance times
    ///   `max(swing_a, swing_b) / min(swing_a, swing_b)`.
    ///
    /// A zero or non-finite `q` is not a rotation: its violation is infinite.
    #[must_use]
    pub fn violation(&self, q: DQuat) -> f64 {
        let Some(q) = unit_quat(q) else {
            return f64::INFINITY;
        };
        match self {
            Self::Free => 0.0,
            Self::Fixed => 2.0 * q.xyz().length().atan2(q.w.abs()),
            Self::Hinge(h) => hinge_violation(h, unit_or_x(h.axis), q),
            Self::SwingTwist(st) => {
                let (swing, twist) = st.unit_violation_parts(&Frame::of(st), None, q);
                twist.max(swing)
            }
        }
    }

    /// This limit with the constants of its quick inside test computed once (see
    /// [`PreparedLimit`]).
    #[must_use]
    pub fn prepare(&self) -> PreparedLimit {
        let fast = match self {
            Self::Free | Self::Fixed => Fast::None,
            Self::Hinge(h) => Fast::Hinge {
                axis: unit_or_x(h.axis),
                range: HalfRange::of(h.min, h.max),
                bounds: HalfRange::closed(h.min, h.max),
            },
            Self::SwingTwist(st) => Fast::SwingTwist {
                frame: Frame::of(st),
                quick: Quick::of(st),
            },
        };
        PreparedLimit { limit: *self, fast }
    }

    /// The centre of the limit's range, the seed solvers restart from when a limit holds
    /// them in a local minimum: a hinge at its middle angle, a swing-twist joint with no
    /// swing and the middle twist, a fixed joint at rest; `None` for a free joint (it has
    /// no centre and keeps whatever rotation it has).
    #[must_use]
    pub fn centre(&self) -> Option<DQuat> {
        match self {
            Self::Free => None,
            Self::Fixed => Some(DQuat::IDENTITY),
            Self::Hinge(_) => Some(self.sample([0.5, 0.0, 0.0])),
            Self::SwingTwist(_) => Some(self.sample([0.0, 0.0, 0.5])),
        }
    }

    /// An allowed rotation from `u` in `[0, 1)^3`, uniform in the limit's parameters:
    ///
    /// - [`Free`](Self::Free): uniform over all rotations (Shoemake's subgroup algorithm,
    ///   "Uniform random rotations", Graphics Gems III). [`Fixed`](Self::Fixed): identity.
    /// - [`Hinge`](Self::Hinge): the angle `min + u[0] * (max - min)`.
    /// - [`SwingTwist`](Self::SwingTwist): the swing's rotation vector uniform over the
    ///   ellipse's area (`rho = sqrt(u[0])`, `psi = 2 pi u[1]`,
    ///   `s = swing_a rho cos(psi) a_axis + swing_b rho sin(psi) b_axis`) and the twist
    ///   angle `twist_min + u[2] * (twist_max - twist_min)`. When a half-angle exceeds
    ///   `pi - SAMPLE_SWING_MARGIN`, the ellipse is shrunk by the factor that brings it to
    ///   that value, so no sample swings within [`SAMPLE_SWING_MARGIN`] of a half turn: there
    ///   the decomposition of the composed rotation is ill-conditioned (its twist and swing
    ///   direction are known only to about `eps / cos(swing / 2)`), and a sample must
    ///   decompose back inside the limit.
    ///
    /// Components of `u` are clamped to `[0, 1]`; NaN counts as 0.
    #[must_use]
    pub fn sample(&self, u: [f64; 3]) -> DQuat {
        let u = u.map(|x| if x >= 0.0 { x.min(1.0) } else { 0.0 });
        match self {
            Self::Free => {
                let (r1, r2) = ((1.0 - u[0]).sqrt(), u[0].sqrt());
                let (t1, t2) = (TAU * u[1], TAU * u[2]);
                DQuat::from_xyzw(r1 * t1.sin(), r1 * t1.cos(), r2 * t2.sin(), r2 * t2.cos())
            }
            Self::Fixed => DQuat::IDENTITY,
            Self::Hinge(h) => {
                DQuat::from_axis_angle(unit_or_x(h.axis), h.min + u[0] * (h.max - h.min))
            }
            Self::SwingTwist(st) => {
                let frame = Frame::of(st);
                let reach = (PI - SAMPLE_SWING_MARGIN) / st.swing_a.max(st.swing_b);
                let rho = u[0].sqrt() * reach.min(1.0);
                let (sin, cos) = (TAU * u[1]).sin_cos();
                let swing = DQuat::from_scaled_axis(
                    frame.a * (st.swing_a * rho * cos) + frame.b * (st.swing_b * rho * sin),
                );
                let twist = DQuat::from_axis_angle(
                    frame.twist,
                    st.twist_min + u[2] * (st.twist_max - st.twist_min),
                );
                (swing * twist).normalize()
            }
        }
    }
}

impl Hinge {
    /// Whether turning `local` (a rotation about this hinge's axis, inside its range) by
    /// `step` radians about the axis pushes it past a bound it already sits on (within
    /// `at_bound` radians). A hinge's limit is a box on its angle, so this is the exact
    /// active-set test the damped least-squares finishes (chain and full body) make before
    /// a step. The angle is read in `(-pi, pi]`, the same for `local` and `-local`.
    #[must_use]
    pub fn pushes_outwards(&self, local: DQuat, step: f64, at_bound: f64) -> bool {
        let along = local.xyz().dot(self.axis);
        let mut angle = 2.0 * along.atan2(local.w);
        if angle > PI {
            angle -= TAU;
        } else if angle <= -PI {
            angle += TAU;
        }
        (step > 0.0 && angle >= self.max - at_bound) || (step < 0.0 && angle <= self.min + at_bound)
    }
}

impl SwingTwist {
    /// The two parts of [`JointLimit::violation`] for this limit, from one decomposition:
    /// the swing's radial excess past the ellipse and the twist's distance to its range
    /// (each 0 inside). Each is the violation of the limit with the other constraint
    /// opened up (the twist range the whole circle, or both swing half-angles pi), which
    /// is what the least-squares finish differentiates for the outward normals of the two
    /// bounds. Infinite for a zero or non-finite `q`.
    #[must_use]
    pub fn violation_parts(&self, q: DQuat) -> (f64, f64) {
        self.violation_parts_in(&LimitFrame::of(self), q)
    }

    /// [`SwingTwist::violation_parts`] with the limit's frame computed once by the caller.
    pub(crate) fn violation_parts_in(&self, frame: &LimitFrame, q: DQuat) -> (f64, f64) {
        match unit_quat(q) {
            Some(q) => self.unit_violation_parts(&frame.0, frame.1.as_ref(), q),
            None => (f64::INFINITY, f64::INFINITY),
        }
    }

    /// Whether `q` is at least `margin` radians inside both constraints, in a form every
    /// rotation within a small fraction of `margin` of `q` keeps: its swing is under 3 rad
    /// (where the twist is well defined) and inside the disc of radius
    /// `min(swing_a, swing_b) - margin` (which the ellipse contains), and its twist is at
    /// least `margin` from both ends of the range (or the range is the whole circle).
    /// Such a `q` and its neighbours have both violation parts exactly 0.
    pub(crate) fn deep_inside(&self, frame: &LimitFrame, q: DQuat, margin: f64) -> bool {
        let Some(q) = unit_quat(q) else {
            return false;
        };
        // The prepared sufficient test first (the same answer when it says yes).
        if margin == DEEP_MARGIN
            && let Some(quick) = &frame.1
        {
            let v = q.xyz();
            if quick.deep_inside(&frame.0, v.dot(frame.0.twist), q.w, v) {
                return true;
            }
        }
        let parts = Parts::of(q, frame.0.twist);
        let (ra, rb) = frame.0.swing_coordinates(&parts);
        let swing = ra.hypot(rb);
        let twist = parts.twist_angle();
        let whole_circle = self.twist_min <= -PI && self.twist_max >= PI;
        swing < 3.0
            && swing <= self.swing_a.min(self.swing_b) - margin
            && (whole_circle
                || (twist >= self.twist_min + margin && twist <= self.twist_max - margin))
    }

    /// The parts for a unit `q`; with the prepared constants of the quick inside tests,
    /// a part they show to be inside is 0 without its arc tangent (the exact value is
    /// then 0 too).
    fn unit_violation_parts(&self, frame: &Frame, quick: Option<&Quick>, q: DQuat) -> (f64, f64) {
        let parts = Parts::of(q, frame.twist);
        let twist = if quick.is_some_and(|k| k.range.clearly_inside(parts.along, parts.w)) {
            0.0
        } else {
            outside_range(parts.twist_angle(), self.twist_min, self.twist_max)
        };
        if quick.is_some_and(|k| k.swing_inside(frame, parts.along, parts.w, parts.perp)) {
            return (0.0, twist);
        }
        let (ra, rb) = frame.swing_coordinates(&parts);
        let swing = if self.swing_inside(ra, rb) {
            0.0
        } else {
            let level = (ra / self.swing_a).hypot(rb / self.swing_b);
            ra.hypot(rb) * (1.0 - 1.0 / level)
        };
        (swing, twist)
    }

    /// Whether the swing with ellipse coordinates `(ra, rb)` is inside the ellipse. A full
    /// disc (both half-angles pi) holds every swing, whatever the rounding of `|s| = pi`.
    fn swing_inside(&self, ra: f64, rb: f64) -> bool {
        (self.swing_a >= PI && self.swing_b >= PI)
            || (ra / self.swing_a).powi(2) + (rb / self.swing_b).powi(2) <= 1.0
    }
}

/// A [`JointLimit`] with the constants of a quick inside test computed once
/// ([`JointLimit::prepare`]; a [`Skeleton`](crate::Skeleton) keeps one per joint):
/// [`PreparedLimit::project`] and [`PreparedLimit::violation`] return exactly what the
/// limit's own [`JointLimit::project`] and [`JointLimit::violation`] return, bit for bit,
/// but tell a rotation clearly inside the limit without an arc tangent.
///
/// Solvers project every trial pose, and most joints of a trial are inside their limits;
/// the decomposition behind the exact test costs two arc tangents and a `hypot` per joint.
/// The quick test compares with the sines and cosines of the half bounds and an upper
/// bound of the swing angle, squared, so it needs no trigonometry and no square root. It
/// only says "inside" with a margin (1e-12 on the twist, a relative 1e-9 on the swing)
/// far above the rounding of the exact test, so the exact test would say the same; every
/// other rotation takes the exact path. The derivation is in `docs/ik-limits.md`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PreparedLimit {
    limit: JointLimit,
    fast: Fast,
}

/// The precomputed parts of a [`PreparedLimit`].
#[derive(Clone, Copy, Debug, PartialEq)]
enum Fast {
    None,
    Hinge {
        axis: DVec3,
        range: HalfRange,
        /// The same with both bounds tested even at the ends of the circle, where
        /// [`Hinge::pushes_outwards`] still sees a bound.
        bounds: HalfRange,
    },
    SwingTwist {
        frame: Frame,
        quick: Quick,
    },
}

/// The constants of a swing-twist limit's quick inside tests.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Quick {
    range: HalfRange,
    /// `1 / swing_a^2` and `1 / swing_b^2`.
    inv_a2: f64,
    inv_b2: f64,
    /// For the quick deep-inside test ([`SwingTwist::deep_inside`] with
    /// [`DEEP_MARGIN`]): the twist range narrowed by the margin at both ends (no bound
    /// when the range is the whole circle), and the square of the swing bound
    /// `min(swing_a, swing_b) - DEEP_MARGIN` less a relative margin (`None` when that
    /// bound is not in `(0, 3)`, where the exact test's `swing < 3` would also need
    /// checking).
    deep_range: HalfRange,
    deep_swing2: Option<f64>,
}

impl Quick {
    fn of(st: &SwingTwist) -> Self {
        let whole_circle = st.twist_min <= -PI && st.twist_max >= PI;
        let deep_range = if whole_circle {
            HalfRange {
                lower: None,
                upper: None,
            }
        } else {
            HalfRange::of(st.twist_min + DEEP_MARGIN, st.twist_max - DEEP_MARGIN)
        };
        let bound = st.swing_a.min(st.swing_b) - DEEP_MARGIN;
        let deep_swing2 =
            (bound > 0.0 && bound < 3.0).then(|| ((1.0 - QUICK_SWING_MARGIN) * bound).powi(2));
        Self {
            range: HalfRange::of(st.twist_min, st.twist_max),
            inv_a2: 1.0 / (st.swing_a * st.swing_a),
            inv_b2: 1.0 / (st.swing_b * st.swing_b),
            deep_range,
            deep_swing2,
        }
    }

    /// A sufficient test, without trigonometry or square roots, for
    /// [`SwingTwist::deep_inside`] with [`DEEP_MARGIN`] of a unit rotation with
    /// components `along` the twist axis, `w` (scalar) and vector part `v`: the twist is
    /// inside the narrowed range (by the margin of the quick twist test), and the swing
    /// angle `2u` is under the bound, with `u <= n N / (h D)` as in
    /// [`Quick::swing_inside`], tested squared: `4 n^2 N^2 <= bound^2 h^2 D^2` with a
    /// relative margin far above the rounding of either side.
    fn deep_inside(&self, frame: &Frame, along: f64, w: f64, v: DVec3) -> bool {
        let Some(bound2) = self.deep_swing2 else {
            return false;
        };
        let h2 = along * along + w * w;
        if h2 < QUICK_SWING_MIN_H2 || !self.deep_range.clearly_inside(along, w) {
            return false;
        }
        let (va, vb) = (v.dot(frame.a), v.dot(frame.b));
        let n2 = va * va + vb * vb;
        let (h4, hn, n4) = (h2 * h2, h2 * n2, n2 * n2);
        let num = 945.0 * h4 + 735.0 * hn + 64.0 * n4;
        let den = 945.0 * h4 + 1050.0 * hn + 225.0 * n4;
        4.0 * n2 * (num * num) <= bound2 * h2 * (den * den)
    }

    /// The quick swing test for a unit rotation with components `along` the twist axis,
    /// `w` (scalar) and vector part `v`. The swing's half-angle `u` has `tan u = x = n / h`
    /// (`n = |perp|`, `perp` the part of `v` across the axis, `h^2 = along^2 + w^2 =
    /// 1 - n^2`), and `atan x <= x (945 + 735 x^2 + 64 x^4) / (945 + 1050 x^2 + 225 x^4)`
    /// for `x >= 0` (the [5/4] Pade approximant; see `docs/ik-limits.md`), so
    /// `u <= n N / (h D)` with `N = 945 h^4 + 735 h^2 n^2 + 64 n^4` and
    /// `D = 945 h^4 + 1050 h^2 n^2 + 225 n^4`. The exact test is
    /// `(2u / n)^2 ((s.a / A)^2 + (s.b / B)^2) <= 1` with the swing's vector part
    /// `s = P / h`, `P = w perp + along (axis x perp)`; with the bound it holds when
    /// `4 ((P.a / A)^2 + (P.b / B)^2) N^2 <= h^4 D^2`, tested with a margin.
    ///
    /// Only the components `(v.a, v.b) = (perp.a, perp.b)` of `v` enter (so `v` may be
    /// `perp` itself). With `b = axis x a`, `(axis x perp).a = -perp.b` and
    /// `(axis x perp).b = perp.a`, so `P.a = w perp.a - along perp.b`,
    /// `P.b = w perp.b + along perp.a` and `n^2 = perp.a^2 + perp.b^2`: no cross product
    /// and no `perp`. The rounding of these forms (relative 1e-14 for `h >= 0.1`) is far
    /// below the margin.
    fn swing_inside(&self, frame: &Frame, along: f64, w: f64, v: DVec3) -> bool {
        let h2 = along * along + w * w;
        if h2 < QUICK_SWING_MIN_H2 {
            return false;
        }
        let (va, vb) = (v.dot(frame.a), v.dot(frame.b));
        let (pa, pb) = (w * va - along * vb, w * vb + along * va);
        let n2 = va * va + vb * vb;
        let (h4, hn, n4) = (h2 * h2, h2 * n2, n2 * n2);
        let num = 945.0 * h4 + 735.0 * hn + 64.0 * n4;
        let den = 945.0 * h4 + 1050.0 * hn + 225.0 * n4;
        4.0 * (pa * pa * self.inv_a2 + pb * pb * self.inv_b2) * (num * num)
            <= (1.0 - QUICK_SWING_MARGIN) * h4 * (den * den)
    }
}

/// How far inside (in the sine of the half-angle difference) a twist must be for the
/// quick test to call it inside.
const QUICK_TWIST_MARGIN: f64 = 1e-12;
/// The relative margin of the quick swing test.
const QUICK_SWING_MARGIN: f64 = 1e-9;
/// The margin (radians) of the finish's test for a joint deep inside its limit
/// ([`SwingTwist::deep_inside`]), for which the quick test is prepared.
pub(crate) const DEEP_MARGIN: f64 = 1e-4;
/// Below this squared cosine of half the swing angle (a swing beyond about 169 degrees)
/// the quick test leaves the answer to the exact one.
const QUICK_SWING_MIN_H2: f64 = 0.01;

/// The sine and cosine of half of each bound of an angle range in `[-pi, pi]`; `None`
/// for a bound at the end of the circle (nothing to test).
#[derive(Clone, Copy, Debug, PartialEq)]
struct HalfRange {
    lower: Option<(f64, f64)>,
    upper: Option<(f64, f64)>,
}

impl HalfRange {
    fn of(min: f64, max: f64) -> Self {
        Self {
            lower: (min > -PI).then(|| (0.5 * min).sin_cos()),
            upper: (max < PI).then(|| (0.5 * max).sin_cos()),
        }
    }

    /// Both bounds, even at the ends of the circle.
    fn closed(min: f64, max: f64) -> Self {
        Self {
            lower: Some((0.5 * min).sin_cos()),
            upper: Some((0.5 * max).sin_cos()),
        }
    }

    /// Whether the twist with quaternion components `(along, w)` about its axis (`along`
    /// the component of the vector part along the axis, `w` the scalar part, from a unit
    /// quaternion) is inside the range by the margin. The twist's half-angle `t` has
    /// `(sin t, cos t) = (a, c) / h` with `(a, c) = +-(along, w)` signed so that `c > 0`
    /// (`t` in `(-pi/2, pi/2)`, as the decomposition chooses) and `h <= 1`. For a bound
    /// `m` (a half bound, also in `[-pi/2, pi/2]`), `sin(t - m) = (a cos m - c sin m) / h`,
    /// and `t - m` is in `(-pi, pi)`, so a value above the margin means `t > m` by more
    /// than the margin; the same for `sin(M - t)` at the upper bound.
    fn clearly_inside(&self, along: f64, w: f64) -> bool {
        let (a, c) = if w > 0.0 {
            (along, w)
        } else if w < 0.0 {
            (-along, -w)
        } else {
            return false;
        };
        self.lower
            .is_none_or(|(sin, cos)| a * cos - c * sin > QUICK_TWIST_MARGIN)
            && self
                .upper
                .is_none_or(|(sin, cos)| c * sin - a * cos > QUICK_TWIST_MARGIN)
    }
}

impl PreparedLimit {
    /// The limit this was prepared from.
    #[must_use]
    pub fn limit(&self) -> &JointLimit {
        &self.limit
    }

    /// Exactly [`JointLimit::project`] of the prepared limit.
    #[must_use]
    pub fn project(&self, q: DQuat) -> DQuat {
        self.project_and_fixed(q).0
    }

    /// [`PreparedLimit::project`] of `q`, and whether it is `q` itself returned by the
    /// quick inside test with `q` unit as given: exactly the case where
    /// [`PreparedLimit::violation_and_fixed`] of the result says `(0, true)`. A solver
    /// that projects every joint it turns learns, for the same work, which joints of its
    /// answer need no violation measured and no projection when the next solve starts
    /// from it. `false` says only that the quick test did not tell.
    #[must_use]
    pub fn project_and_fixed(&self, q: DQuat) -> (DQuat, bool) {
        match &self.fast {
            Fast::None => (self.limit.project(q), false),
            Fast::Hinge { axis, range, .. } => {
                let u = unit_quat(q).unwrap_or(DQuat::IDENTITY);
                if quick_hinge_inside(*axis, range, u) {
                    // `unit_quat` returns `q` itself exactly when it is unit as given.
                    return (u, u == q);
                }
                let JointLimit::Hinge(h) = &self.limit else {
                    unreachable!("a hinge's prepared parts belong to a hinge")
                };
                (project_hinge(h, *axis, u), false)
            }
            Fast::SwingTwist { frame, .. } => {
                let u = unit_quat(q).unwrap_or(DQuat::IDENTITY);
                if self.quick_swing_twist_inside(u) {
                    return (u, u == q);
                }
                let JointLimit::SwingTwist(st) = &self.limit else {
                    unreachable!("a swing-twist's prepared parts belong to a swing-twist")
                };
                (project_swing_twist(st, frame, u), false)
            }
        }
    }

    /// Whether `q` is inside the limit by the tests [`PreparedLimit::project`] makes
    /// before it clamps (and unit to rounding, so that the projection starts from `q`
    /// itself): then the projection returns `q` to the bit. Cheaper than projecting and
    /// comparing for a rotation outside (no closest point of the ellipse, no rotation
    /// rebuilt). A rotation on a bound, a rounding outside it, is not kept here, though
    /// its projection may rebuild it to the same bits.
    #[must_use]
    pub fn keeps(&self, q: DQuat) -> bool {
        match &self.fast {
            Fast::None => self.limit.project(q) == q,
            Fast::Hinge { axis, range, .. } => {
                if unit_quat(q) != Some(q) {
                    return false;
                }
                if quick_hinge_inside(*axis, range, q) {
                    return true;
                }
                let JointLimit::Hinge(h) = &self.limit else {
                    unreachable!("a hinge's prepared parts belong to a hinge")
                };
                let parts = Parts::of(q, *axis);
                parts.perp == DVec3::ZERO && in_range(parts.twist_angle(), h.min, h.max)
            }
            Fast::SwingTwist { frame, .. } => {
                if unit_quat(q) != Some(q) {
                    return false;
                }
                if self.quick_swing_twist_inside(q) {
                    return true;
                }
                let JointLimit::SwingTwist(st) = &self.limit else {
                    unreachable!("a swing-twist's prepared parts belong to a swing-twist")
                };
                let parts = Parts::of(q, frame.twist);
                let (ra, rb) = frame.swing_coordinates(&parts);
                st.swing_inside(ra, rb) && in_range(parts.twist_angle(), st.twist_min, st.twist_max)
            }
        }
    }

    /// Exactly [`JointLimit::violation`] of the prepared limit.
    #[must_use]
    pub fn violation(&self, q: DQuat) -> f64 {
        match &self.fast {
            Fast::None => self.limit.violation(q),
            Fast::Hinge { axis, range, .. } => {
                let Some(q) = unit_quat(q) else {
                    return f64::INFINITY;
                };
                if quick_hinge_inside(*axis, range, q) {
                    return 0.0;
                }
                let JointLimit::Hinge(h) = &self.limit else {
                    unreachable!("a hinge's prepared parts belong to a hinge")
                };
                hinge_violation(h, *axis, q)
            }
            Fast::SwingTwist { frame, quick } => {
                let Some(q) = unit_quat(q) else {
                    return f64::INFINITY;
                };
                if self.quick_swing_twist_inside(q) {
                    return 0.0;
                }
                let JointLimit::SwingTwist(st) = &self.limit else {
                    unreachable!("a swing-twist's prepared parts belong to a swing-twist")
                };
                let (swing, twist) = st.unit_violation_parts(frame, Some(quick), q);
                twist.max(swing)
            }
        }
    }

    /// [`PreparedLimit::violation`] of `q`, and whether [`PreparedLimit::project`] is
    /// known to return `q` itself, to the bit: `q` is unit to rounding (the projection
    /// starts from `q`, not from a normalized copy) and inside by the quick test (the
    /// projection then returns it unchanged, and the violation is 0). `false` says only
    /// that the quick test did not tell: the projection may still return `q`. A solver
    /// that reports the violation of its answer learns, for the same work, which joints
    /// of that answer need no projection when the next solve starts from it.
    #[must_use]
    pub fn violation_and_fixed(&self, q: DQuat) -> (f64, bool) {
        // For a `q` unit as given, the steps of `violation` (and of `project` before it
        // clamps) on `q` itself, the quick test made once. (A squared length within
        // rounding of 1 implies finite components: a NaN or an infinity would make it NaN
        // or infinite.)
        let unit_as_given = (q.length_squared() - 1.0).abs() <= 4.0 * f64::EPSILON;
        match &self.fast {
            Fast::Hinge { axis, range, .. } if unit_as_given => {
                if quick_hinge_inside(*axis, range, q) {
                    return (0.0, true);
                }
                let JointLimit::Hinge(h) = &self.limit else {
                    unreachable!("a hinge's prepared parts belong to a hinge")
                };
                (hinge_violation(h, *axis, q), false)
            }
            Fast::SwingTwist { frame, quick } if unit_as_given => {
                if self.quick_swing_twist_inside(q) {
                    return (0.0, true);
                }
                let JointLimit::SwingTwist(st) = &self.limit else {
                    unreachable!("a swing-twist's prepared parts belong to a swing-twist")
                };
                let (swing, twist) = st.unit_violation_parts(frame, Some(quick), q);
                (twist.max(swing), false)
            }
            _ => (self.violation(q), false),
        }
    }

    /// Exactly [`Hinge::pushes_outwards`] for a prepared hinge (false for any other
    /// limit), without the arc tangent when `local` is clearly inside the range: its
    /// half-angle then lies more than 1e-12 inside each bound (the quick twist test, with
    /// `local`'s component along the hinge's own axis as the exact test takes it, a
    /// near-unit `local`), so its angle is more than `at_bound <= 1e-12` from both.
    pub(crate) fn hinge_pushes_outwards(&self, local: DQuat, step: f64, at_bound: f64) -> bool {
        let (Fast::Hinge { bounds, .. }, JointLimit::Hinge(h)) = (&self.fast, &self.limit) else {
            return false;
        };
        if at_bound <= 1e-12 && bounds.clearly_inside(local.xyz().dot(h.axis), local.w) {
            return false;
        }
        h.pushes_outwards(local, step, at_bound)
    }

    /// The frame of a swing-twist limit, for the finish's outward normals.
    pub(crate) fn frame(&self) -> Option<LimitFrame> {
        match &self.fast {
            Fast::SwingTwist { frame, quick } => Some(LimitFrame(*frame, Some(*quick))),
            _ => None,
        }
    }

    /// The quick inside test of a swing-twist limit (both constraints) for a unit `q`.
    fn quick_swing_twist_inside(&self, q: DQuat) -> bool {
        let Fast::SwingTwist { frame, quick } = &self.fast else {
            return false;
        };
        let v = q.xyz();
        let along = v.dot(frame.twist);
        quick.range.clearly_inside(along, q.w) && quick.swing_inside(frame, along, q.w, v)
    }
}

/// The quick inside test of a hinge for a unit `q`: exactly about the axis (the exact
/// test's own condition, computed the same way) and the twist inside by the margin.
fn quick_hinge_inside(axis: DVec3, range: &HalfRange, q: DQuat) -> bool {
    let v = q.xyz();
    let along = v.dot(axis);
    let perp = v - axis * along;
    perp == DVec3::ZERO && range.clearly_inside(along, q.w)
}

/// The decomposition `q = swing * twist`, the twist a rotation about `axis`.
///
/// `axis` is normalised here (a zero or non-finite axis counts as +x), and a zero or
/// non-finite `q` counts as the identity. The twist has a non-negative scalar part, so its
/// angle is in `[-pi, pi]`; the swing is a rotation about an axis perpendicular to
/// `axis`, and `swing * twist` equals the normalised `q` as a quaternion (to rounding), not
/// just as a rotation.
///
/// At the singular swing of 180 degrees (`q` a half turn about an axis perpendicular to
/// `axis`) every twist fits; the answer defined there is the identity twist and
/// `swing = q`. Near it the decomposition is well-conditioned except for the twist angle,
/// which is then inherently sensitive to `q`.
#[must_use]
pub fn swing_twist(q: DQuat, axis: DVec3) -> (DQuat, DQuat) {
    let q = unit_quat(q).unwrap_or(DQuat::IDENTITY);
    let parts = Parts::of(q, unit_or_x(axis));
    let (tp, tw, sign) = parts.canonical_twist();
    let twist = DQuat::from_xyzw(parts.axis.x * tp, parts.axis.y * tp, parts.axis.z * tp, tw);
    (parts.swing() * sign, twist)
}

/// The pieces of a rotation's swing-twist decomposition about a unit axis, in the
/// convention where the swing's scalar part is `h = |(q.axis, q.w)| >= 0`.
struct Parts {
    /// The unit twist axis.
    axis: DVec3,
    /// The component of `q`'s vector part perpendicular to the axis; its length is the
    /// swing's `sin(angle / 2)`.
    perp: DVec3,
    /// The swing's vector part (perpendicular to the axis, of length `|perp|`).
    swing_vec: DVec3,
    /// The swing's scalar part, `hypot(q.axis, q.w)`: its `cos(angle / 2)`, >= 0.
    swing_w: f64,
    /// `q`'s component along the axis, and its scalar part.
    along: f64,
    w: f64,
}

impl Parts {
    /// Decomposes a unit `q` about a unit `axis`; see `docs/ik-limits.md` for why the
    /// swing's vector part is `c perp + s axis x perp` with `(c, s) = (w, along) / h`.
    fn of(q: DQuat, axis: DVec3) -> Self {
        let v = q.xyz();
        let along = v.dot(axis);
        let perp = v - axis * along;
        let h = along.hypot(q.w);
        // At h = 0 (the half-turn swing) the twist is undefined; the identity twist makes
        // the swing q itself, as (c, s) = (1, 0) gives.
        let (c, s) = if h > 0.0 {
            (q.w / h, along / h)
        } else {
            (1.0, 0.0)
        };
        let swing_vec = perp * c + axis.cross(perp) * s;
        Self {
            axis,
            perp,
            swing_vec,
            swing_w: h,
            along,
            w: q.w,
        }
    }

    /// The twist angle in `(-pi, pi]`, 0 at the singular swing. Computed on demand: a
    /// caller that knows the twist is inside its range needs no arc tangent.
    fn twist_angle(&self) -> f64 {
        let (tp, tw, _) = self.canonical_twist();
        if self.swing_w > 0.0 {
            2.0 * tp.atan2(tw)
        } else {
            0.0
        }
    }

    /// The twist's `(axis component, scalar part)` with the sign that puts its angle in
    /// `(-pi, pi]` (scalar part positive, or zero with a non-negative axis component), and
    /// that sign. The same rotation gets the same answer from `q` and `-q`.
    fn canonical_twist(&self) -> (f64, f64, f64) {
        let h = self.swing_w;
        if h == 0.0 {
            return (0.0, 1.0, 1.0);
        }
        let (p, w) = (self.along / h, self.w / h);
        if w > 0.0 || (w == 0.0 && p >= 0.0) {
            (p, w, 1.0)
        } else {
            (-p, -w, -1.0)
        }
    }

    /// The swing, with scalar part `h >= 0`.
    fn swing(&self) -> DQuat {
        DQuat::from_xyzw(
            self.swing_vec.x,
            self.swing_vec.y,
            self.swing_vec.z,
            self.swing_w,
        )
    }

    /// The swing's angle in `[0, pi]`.
    fn swing_angle(&self) -> f64 {
        2.0 * self.swing_vec.length().atan2(self.swing_w)
    }

    /// The swing's rotation vector (length in `[0, pi]`, perpendicular to the axis).
    fn swing_rotation_vector(&self) -> DVec3 {
        let n = self.swing_vec.length();
        if n > 0.0 {
            self.swing_vec * (2.0 * n.atan2(self.swing_w) / n)
        } else {
            DVec3::ZERO
        }
    }
}

/// A swing-twist limit's frame, computed once for many evaluations of its violation.
pub(crate) struct LimitFrame(Frame, Option<Quick>);

impl LimitFrame {
    /// The frame of `st`.
    pub(crate) fn of(st: &SwingTwist) -> Self {
        Self(Frame::of(st), Some(Quick::of(st)))
    }
}

/// A swing-twist limit's orthonormal frame: the twist axis and the ellipse's two axes.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Frame {
    twist: DVec3,
    a: DVec3,
    b: DVec3,
}

impl Frame {
    /// The frame of a (valid) limit, made exactly orthonormal: the axes are within 1e-9 of
    /// unit and perpendicular, and the ellipse coordinates should not inherit that error.
    fn of(st: &SwingTwist) -> Self {
        let twist = unit_or_x(st.twist_axis);
        let a = try_unit(st.a_axis - twist * st.a_axis.dot(twist))
            .unwrap_or_else(|| twist.any_orthonormal_vector());
        Self {
            twist,
            a,
            b: twist.cross(a),
        }
    }

    /// The swing's rotation vector in ellipse coordinates `(along a, along b)`. At the
    /// half-turn swing `s` and `-s` are the same rotation; the representative with a
    /// positive `a` coordinate (or zero and a positive `b` one) is chosen, so that `q` and
    /// `-q` project to the same rotation.
    fn swing_coordinates(&self, parts: &Parts) -> (f64, f64) {
        let r = parts.swing_rotation_vector();
        let (ra, rb) = (r.dot(self.a), r.dot(self.b));
        if parts.swing_w == 0.0 && (ra < 0.0 || (ra == 0.0 && rb < 0.0)) {
            (-ra, -rb)
        } else {
            (ra, rb)
        }
    }
}

/// `q / |q|`, or `None` for a zero or non-finite `q`. Scales by the largest component
/// first so that tiny quaternions do not underflow to zero length.
fn unit_quat(q: DQuat) -> Option<DQuat> {
    // A quaternion that is unit to rounding is kept bit for bit, so that an allowed
    // rotation comes back exactly as it went in. Tested first: a squared length that
    // close to 1 says every component is finite (a NaN or an infinity would make it NaN
    // or infinite), so the finiteness test is needed only for the others.
    let length_squared = q.length_squared();
    if (length_squared - 1.0).abs() <= 4.0 * f64::EPSILON {
        return Some(q);
    }
    if !q.is_finite() {
        return None;
    }
    let scale = q.to_array().iter().fold(0.0f64, |m, c| m.max(c.abs()));
    if scale == 0.0 {
        return None;
    }
    Some((q * (1.0 / scale)).normalize())
}

fn unit_or_x(v: DVec3) -> DVec3 {
    try_unit(v).unwrap_or(DVec3::X)
}

/// Whether `angle`, in `(-pi, pi]`, is in `[min, max]`. A half turn is `pi` after the
/// decomposition's sign choice, and it is the same rotation as `-pi`, so it is also inside
/// a range that starts at `-pi`.
fn in_range(angle: f64, min: f64, max: f64) -> bool {
    (min <= angle && angle <= max) || (angle == PI && min == -PI)
}

/// The distance between two angles in `[-pi, pi]` along the circle, in `[0, pi]`.
fn circular_distance(x: f64, y: f64) -> f64 {
    let d = (x - y).abs();
    if d > PI { TAU - d } else { d }
}

/// How far `angle` is from `[min, max]` along the circle (0 inside).
fn outside_range(angle: f64, min: f64, max: f64) -> f64 {
    if in_range(angle, min, max) {
        0.0
    } else {
        circular_distance(angle, min).min(circular_distance(angle, max))
    }
}

/// `angle` clamped to `[min, max]` on the circle: unchanged inside, otherwise the bound
/// nearer along the circle (a tie goes to `max`).
fn clamp_circular(angle: f64, min: f64, max: f64) -> f64 {
    if in_range(angle, min, max) {
        angle
    } else if circular_distance(angle, max) <= circular_distance(angle, min) {
        max
    } else {
        min
    }
}

/// `projected` with the sign that makes its dot product with `q` non-negative.
fn same_sign(projected: DQuat, q: DQuat) -> DQuat {
    if projected.dot(q) < 0.0 {
        -projected
    } else {
        projected
    }
}

/// [`JointLimit::project`] for a hinge with unit axis `axis`, `q` unit.
fn project_hinge(h: &Hinge, axis: DVec3, q: DQuat) -> DQuat {
    let parts = Parts::of(q, axis);
    let twist_angle = parts.twist_angle();
    if parts.perp == DVec3::ZERO && in_range(twist_angle, h.min, h.max) {
        return q;
    }
    let angle = clamp_circular(twist_angle, h.min, h.max);
    same_sign(DQuat::from_axis_angle(axis, angle), q)
}

/// [`JointLimit::project`] for a swing-twist limit with frame `frame`, `q` unit.
fn project_swing_twist(st: &SwingTwist, frame: &Frame, q: DQuat) -> DQuat {
    let parts = Parts::of(q, frame.twist);
    let (ra, rb) = frame.swing_coordinates(&parts);
    let swing_inside = st.swing_inside(ra, rb);
    let twist_angle = parts.twist_angle();
    let twist_inside = in_range(twist_angle, st.twist_min, st.twist_max);
    if swing_inside && twist_inside {
        return q;
    }
    let swing = if swing_inside {
        parts.swing()
    } else {
        let (xa, xb) = closest_on_ellipse(st.swing_a, st.swing_b, ra, rb);
        DQuat::from_scaled_axis(frame.a * xa + frame.b * xb)
    };
    let angle = clamp_circular(twist_angle, st.twist_min, st.twist_max);
    same_sign(
        (swing * DQuat::from_axis_angle(frame.twist, angle)).normalize(),
        q,
    )
}

/// [`JointLimit::violation`] for a hinge with unit axis `axis`, `q` unit.
fn hinge_violation(h: &Hinge, axis: DVec3, q: DQuat) -> f64 {
    let parts = Parts::of(q, axis);
    parts
        .swing_angle()
        .max(outside_range(parts.twist_angle(), h.min, h.max))
}

/// The point of the ellipse `(x / ea)^2 + (y / eb)^2 = 1` nearest to `(ya, yb)`.
fn closest_on_ellipse(ea: f64, eb: f64, ya: f64, yb: f64) -> (f64, f64) {
    // The robust algorithm wants the major semi-axis first.
    if ea >= eb {
        closest_on_ellipse_ordered(ea, eb, ya, yb)
    } else {
        let (xb, xa) = closest_on_ellipse_ordered(eb, ea, yb, ya);
        (xa, xb)
    }
}

/// The point of the ellipse `(x0 / e0)^2 + (x1 / e1)^2 = 1`, `e0 >= e1 > 0`, nearest to
/// `(y0, y1)`: Eberly's bisection ("Distance from a Point to an Ellipse, an Ellipsoid, or a
/// Hyperellipsoid", Geometric Tools, 2013), derived in `docs/ik-limits.md`.
fn closest_on_ellipse_ordered(e0: f64, e1: f64, y0: f64, y1: f64) -> (f64, f64) {
    // By symmetry work in the first quadrant and restore the signs at the end.
    let (z0, z1) = (y0.abs(), y1.abs());
    let (x0, x1) = if z1 > 0.0 {
        if z0 > 0.0 {
            let (n0, n1) = (z0 / e0, z1 / e1);
            let g = n0 * n0 + n1 * n1 - 1.0;
            if g == 0.0 {
                (z0, z1)
            } else {
                let r0 = (e0 / e1).powi(2);
                let t = ellipse_root(r0, n0, n1, g);
                (r0 * z0 / (t + r0), z1 / (t + 1.0))
            }
        } else {
            (0.0, e1)
        }
    } else {
        // On the major axis: outside or near its end the vertex is nearest; deep inside,
        // a point off the axis is.
        let numer = e0 * z0;
        let denom = e0 * e0 - e1 * e1;
        if numer < denom {
            let ratio = numer / denom;
            (e0 * ratio, e1 * (1.0 - ratio * ratio).max(0.0).sqrt())
        } else {
            (e0, 0.0)
        }
    };
    (x0.copysign(y0), x1.copysign(y1))
}

/// The root `t` of `F(t) = (r0 n0 / (t + r0))^2 + (n1 / (t + 1))^2 - 1` (decreasing for
/// `t > -1`) by bisection until the midpoint repeats an end point. `g = F(0)`.
fn ellipse_root(r0: f64, n0: f64, n1: f64, g: f64) -> f64 {
    let rn0 = r0 * n0;
    let mut lo = n1 - 1.0;
    let mut hi = if g < 0.0 { 0.0 } else { rn0.hypot(n1) - 1.0 };
    let mut t = lo;
    // The bracket is at most ~r0 wide and the root only matters to rounding relative to
    // `t + 1 >= 1`, so 200 halvings are ample even for the thinnest ellipse allowed.
    for _ in 0..200 {
        t = 0.5 * (lo + hi);
        if t == lo || t == hi {
            break;
        }
        let f = (rn0 / (t + r0)).powi(2) + (n1 / (t + 1.0)).powi(2) - 1.0;
        if f > 0.0 {
            lo = t;
        } else if f < 0.0 {
            hi = t;
        } else {
            break;
        }
    }
    t
}

fn check_axis(field: &'static str, value: DVec3) -> Result<(), LimitError> {
    if value.is_finite() && (value.length() - 1.0).abs() <= AXIS_TOLERANCE {
        Ok(())
    } else {
        Err(LimitError::Axis { field, value })
    }
}

fn check_half_angle(field: &'static str, value: f64) -> Result<(), LimitError> {
    if value > 0.0 && value <= PI {
        Ok(())
    } else {
        Err(LimitError::Angle {
            field,
            value,
            allowed: "(0, pi]",
        })
    }
}

fn check_range(
    min_field: &'static str,
    min: f64,
    max_field: &'static str,
    max: f64,
) -> Result<(), LimitError> {
    for (field, value) in [(min_field, min), (max_field, max)] {
        if !(-PI..=PI).contains(&value) {
            return Err(LimitError::Angle {
                field,
                value,
                allowed: "[-pi, pi]",
            });
        }
    }
    if min > max {
        return Err(LimitError::EmptyRange {
            min_field,
            min,
            max_field,
            max,
        });
    }
    Ok(())
}

/// The human shoulder of the W7 and W8 workloads, the crate's unit tests' common limit:
/// bone along +x, swing 100 degrees about z, 70 about y, twist +-80 degrees (the
/// integration tests and the benchmarks share the same in `tests/common`).
#[cfg(test)]
pub(crate) fn test_shoulder() -> JointLimit {
    JointLimit::swing_twist(
        DVec3::X,
        DVec3::Z,
        100f64.to_radians(),
        70f64.to_radians(),
        -80f64.to_radians(),
        80f64.to_radians(),
    )
    .expect("valid swing-twist")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The [5/4] Pade bound the quick swing test rests on is above the arc tangent
    /// (checked on a grid where the exact `atan` is accurate to an ulp, far below the
    /// bound's gap except near 0, where both agree to rounding and the gap is
    /// `64 x^11 / 43659`).
    #[test]
    fn the_pade_bound_is_above_the_arc_tangent() {
        for i in 0..=4000 {
            let x = f64::from(i) * 0.0025;
            let x2 = x * x;
            let bound =
                x * (945.0 + 735.0 * x2 + 64.0 * x2 * x2) / (945.0 + 1050.0 * x2 + 225.0 * x2 * x2);
            assert!(bound >= x.atan() * (1.0 - 4.0 * f64::EPSILON), "{x}");
        }
    }

    /// The quick swing test takes a swing a relative 1e-4 (in the squared ellipse level)
    /// inside an ellipse of up to 60 degrees, and never one outside it; the twist is kept
    /// well inside its range so that only the swing decides.
    #[test]
    fn the_quick_swing_test_is_tight_and_never_takes_an_outside_swing() {
        let st = SwingTwist {
            twist_axis: DVec3::new(0.2, 1.0, -0.1).normalize(),
            a_axis: DVec3::X,
            swing_a: 60f64.to_radians(),
            swing_b: 35f64.to_radians(),
            twist_min: -1.0,
            twist_max: 1.0,
        };
        let limit = JointLimit::SwingTwist(st).prepare();
        let Fast::SwingTwist { frame, .. } = limit.fast else {
            panic!("a prepared swing-twist");
        };
        let twist = DQuat::from_axis_angle(frame.twist, 0.3);
        for k in 0..360 {
            let phi = f64::from(k).to_radians();
            let (xa, xb) = (st.swing_a * phi.cos(), st.swing_b * phi.sin());
            for (level, inside) in [(1.0_f64 - 1e-4, true), (1.0 + 1e-9, false), (1.2, false)] {
                let r = (frame.a * xa + frame.b * xb) * level.sqrt();
                let q = (DQuat::from_scaled_axis(r) * twist).normalize();
                if inside {
                    assert!(limit.quick_swing_twist_inside(q), "{phi} {level}");
                    assert_eq!(limit.project(q), q);
                } else {
                    assert!(!limit.quick_swing_twist_inside(q), "{phi} {level}");
                    assert!(limit.violation(q) > 0.0, "{phi} {level}");
                }
            }
        }
    }

    /// A swing-twist limit, a cone, a hinge, a free and a fixed joint: one of each kind.
    fn five_limits() -> [JointLimit; 5] {
        [
            test_shoulder(),
            JointLimit::cone(DVec3::Y, 0.5).unwrap(),
            JointLimit::hinge(-DVec3::Y, 0.0, 150f64.to_radians()).unwrap(),
            JointLimit::Free,
            JointLimit::Fixed,
        ]
    }

    /// Uniform numbers in `[0, 1)` from a 64-bit linear congruential generator seeded
    /// with `seed` (deterministic, no dependency).
    fn uniform_from(mut state: u64) -> impl FnMut() -> f64 {
        move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// The quick test must actually take the rotations well inside (or it saves nothing):
    /// every sample of the inner part of the W7 shoulder and elbow ranges.
    /// `keeps` never keeps a rotation the projection moves, keeps every rotation drawn
    /// inside, and keeps none of those turned outside by more than rounding, nor one
    /// slightly off unit length; checked with a swing-twist limit, a cone, a hinge, a free
    /// and a fixed joint. A rotation on a bound (a projection of one outside) may go either
    /// way; the count of those kept and not is only printed.
    #[test]
    fn keeps_only_what_the_projection_returns_unchanged() {
        let limits = five_limits();
        let mut uniform = uniform_from(0x1234_5678_9abc_def0_u64);
        let mut on_bound_kept = [0, 0];
        for limit in limits {
            let prepared = limit.prepare();
            for _ in 0..2000 {
                let inside = limit.sample([uniform(), uniform(), uniform()]);
                let axis = DVec3::new(uniform() - 0.5, uniform() - 0.5, uniform() - 0.5);
                let turn = DQuat::from_scaled_axis(axis * (0.1 + 4.0 * uniform()).powi(3));
                let outside = (turn * inside).normalize();
                let on_bound = prepared.project(outside);
                for q in [inside, outside, on_bound, inside * (1.0 + 1e-6)] {
                    let keeps = prepared.keeps(q);
                    let unchanged = prepared.project(q) == q;
                    assert!(
                        !keeps || unchanged,
                        "{limit:?}: kept {q:?}, projected elsewhere"
                    );
                    if q == inside {
                        assert!(keeps, "{limit:?}: {q:?} drawn inside, not kept");
                    } else if q == on_bound {
                        on_bound_kept[usize::from(keeps)] += 1;
                    } else if !unchanged {
                        assert!(!keeps, "{limit:?}: kept {q:?} outside");
                    }
                }
            }
        }
        println!(
            "on a bound: {} not kept, {} kept",
            on_bound_kept[0], on_bound_kept[1]
        );
    }

    /// The violation it returns is `violation`'s to the bit, and a rotation it says is
    /// fixed is returned by the projection to the bit (with violation 0); rotations
    /// drawn well inside are said to be fixed (the quick test takes them).
    /// `project_and_fixed` returns the projection's bits and says fixed exactly when
    /// `violation_and_fixed` does.
    #[test]
    fn violation_and_fixed_agrees_with_the_violation_and_the_projection() {
        let limits = five_limits();
        let mut uniform = uniform_from(0x0f1e_2d3c_4b5a_6978_u64);
        let bits = |q: DQuat| q.to_array().map(f64::to_bits);
        let mut fixed_count = 0;
        for limit in limits {
            let prepared = limit.prepare();
            for _ in 0..2000 {
                let inside = limit.sample([uniform(), uniform(), uniform()]);
                let well_inside =
                    limit.sample([0.25 * uniform(), uniform(), 0.4 + 0.2 * uniform()]);
                let axis = DVec3::new(uniform() - 0.5, uniform() - 0.5, uniform() - 0.5);
                let turn = DQuat::from_scaled_axis(axis * (0.1 + 4.0 * uniform()).powi(3));
                let outside = (turn * inside).normalize();
                let on_bound = prepared.project(outside);
                for q in [
                    inside,
                    well_inside,
                    outside,
                    on_bound,
                    inside * (1.0 + 1e-6),
                ] {
                    let (violation, fixed) = prepared.violation_and_fixed(q);
                    // The projection's own answer: the projection's bits, and said fixed
                    // exactly when the violation's steps say so.
                    let (projected, projected_fixed) = prepared.project_and_fixed(q);
                    assert_eq!(
                        bits(projected),
                        bits(prepared.project(q)),
                        "{limit:?}: {q:?}"
                    );
                    assert_eq!(projected_fixed, fixed, "{limit:?}: {q:?}");
                    if projected_fixed {
                        assert_eq!(bits(projected), bits(q), "{limit:?}: {q:?}");
                        assert_eq!(prepared.violation_and_fixed(projected), (0.0, true));
                    }
                    assert_eq!(
                        violation.to_bits(),
                        prepared.violation(q).to_bits(),
                        "{limit:?}: {q:?}"
                    );
                    if fixed {
                        assert_eq!(bits(prepared.project(q)), bits(q), "{limit:?}: {q:?}");
                        assert_eq!(violation, 0.0);
                        fixed_count += 1;
                    }
                    if matches!(limit, JointLimit::Hinge(_) | JointLimit::SwingTwist(_))
                        && q == well_inside
                    {
                        assert!(fixed, "{limit:?}: {q:?} well inside, not said fixed");
                    }
                }
            }
        }
        assert!(fixed_count >= 6000, "{fixed_count}");
    }

    #[test]
    fn the_quick_test_takes_rotations_well_inside() {
        let shoulder = test_shoulder().prepare();
        let elbow = JointLimit::hinge(-DVec3::Y, 0.0, 150f64.to_radians())
            .unwrap()
            .prepare();
        for i in 0..=20 {
            let f = 0.05 + 0.85 * f64::from(i) / 20.0;
            for k in 0..8 {
                let u = [f * f, f64::from(k) / 8.0, 0.5 + 0.45 * (f - 0.5)];
                let q = shoulder.limit().sample(u);
                assert!(shoulder.quick_swing_twist_inside(q), "shoulder {u:?}");
            }
            let q = elbow.limit().sample([f, 0.0, 0.0]);
            let Fast::Hinge { axis, range, .. } = &elbow.fast else {
                panic!("a prepared hinge");
            };
            assert!(quick_hinge_inside(*axis, range, q), "elbow {f}");
        }
    }

    /// `unit_quat` tests the squared length before finiteness: a quaternion unit to
    /// rounding comes back itself, one with an infinity or a NaN (whose squared length is
    /// never near 1) or of zero length is `None`, and any other is normalized.
    #[test]
    fn unit_quat_keeps_the_unit_refuses_the_non_finite_and_normalizes_the_rest() {
        let unit = DQuat::from_xyzw(0.0, 0.0, 0.6, 0.8);
        let nudged = DQuat::from_xyzw(0.0, 0.0, 0.6, 0.8 + f64::EPSILON);
        for q in [unit, nudged, DQuat::IDENTITY, -DQuat::IDENTITY] {
            assert_eq!(
                unit_quat(q).map(|u| u.to_array()),
                Some(q.to_array()),
                "{q}"
            );
        }
        for q in [
            DQuat::from_xyzw(f64::INFINITY, 0.0, 0.0, 0.0),
            DQuat::from_xyzw(0.0, f64::NEG_INFINITY, 0.0, 1.0),
            DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0),
            DQuat::from_xyzw(0.0, 0.0, 0.0, f64::NAN),
            DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0),
        ] {
            assert_eq!(unit_quat(q), None, "{q}");
        }
        for q in [
            DQuat::from_xyzw(0.0, 0.0, 3.0, 4.0),
            DQuat::from_xyzw(1e-170, 0.0, 0.0, 1e-170),
            DQuat::from_xyzw(1e200, 0.0, 0.0, 1e200),
        ] {
            let u = unit_quat(q).expect("a finite non-zero quaternion");
            assert!((u.length() - 1.0).abs() <= 4.0 * f64::EPSILON, "{q} -> {u}");
            assert!(u.dot(q) > 0.0, "{q} -> {u}");
        }
    }

    /// The prepared hinge's outward test gives the exact test's answer, at and near the
    /// bounds (where the quick test must step aside) and well inside.
    #[test]
    fn the_prepared_hinge_pushes_outwards_exactly_as_the_hinge() {
        let axis = DVec3::new(0.3, -0.4, 0.5).normalize();
        for (min, max) in [
            (0.0, 150f64.to_radians()),
            (-1.0, 0.5),
            (-PI, PI),
            (-PI, 0.2),
        ] {
            let limit = JointLimit::hinge(axis, min, max).unwrap();
            let JointLimit::Hinge(h) = limit else {
                panic!("a hinge");
            };
            let prepared = limit.prepare();
            let mut angles = vec![min, max, 0.5 * (min + max)];
            for d in [1e-15, 1e-13, 1e-12, 2e-12, 1e-11, 1e-6] {
                angles.extend([min + d, min - d, max + d, max - d]);
            }
            for angle in angles {
                let local = DQuat::from_axis_angle(axis, angle);
                for q in [local, -local] {
                    for step in [1.0, -1.0, 0.0] {
                        for at_bound in [1e-12, 1e-6] {
                            assert_eq!(
                                prepared.hinge_pushes_outwards(q, step, at_bound),
                                h.pushes_outwards(q, step, at_bound),
                                "range [{min}, {max}], angle {angle}, step {step}"
                            );
                        }
                    }
                }
            }
        }
    }

    /// The violation parts with the quick tests are those without, bit for bit, on
    /// random rotations and rotations on and near the bounds, for round, thin, tilted and
    /// full-circle limits.
    #[test]
    fn the_quick_violation_parts_are_the_exact_ones() {
        let tilted = DVec3::new(1.0, 2.0, 3.0).normalize();
        let JointLimit::SwingTwist(shoulder) = test_shoulder() else {
            unreachable!("the shoulder is a swing-twist limit")
        };
        let limits = [
            shoulder,
            SwingTwist {
                twist_axis: tilted,
                a_axis: tilted.any_orthonormal_vector(),
                swing_a: PI,
                swing_b: 0.05,
                twist_min: 1.0,
                twist_max: 2.5,
            },
            SwingTwist {
                twist_axis: DVec3::Y,
                a_axis: DVec3::X,
                swing_a: 0.3,
                swing_b: 2.5,
                twist_min: -PI,
                twist_max: PI,
            },
        ];
        let mut seed = 0x5EED_0000_0000_00B2_u64;
        let mut unit = move || {
            seed = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = seed;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        for st in limits {
            let limit = JointLimit::SwingTwist(st);
            let (frame, quick) = (Frame::of(&st), Quick::of(&st));
            let mut zeros = 0;
            for _ in 0..20_000 {
                let random = JointLimit::Free.sample([unit(), unit(), unit()]);
                let on_bound = limit.project(random);
                let inside = limit.sample([unit(), unit(), unit()]);
                let nudge = DVec3::new(unit(), unit(), unit()) * 2.0 - DVec3::ONE;
                let scale = 10f64.powf(-15.0 + 14.0 * unit());
                for q in [random, on_bound, inside] {
                    let q = (DQuat::from_scaled_axis(nudge * scale) * q).normalize();
                    let exact = st.unit_violation_parts(&frame, None, q);
                    let fast = st.unit_violation_parts(&frame, Some(&quick), q);
                    assert_eq!(exact.0.to_bits(), fast.0.to_bits(), "{q}");
                    assert_eq!(exact.1.to_bits(), fast.1.to_bits(), "{q}");
                    zeros += usize::from(exact == (0.0, 0.0));
                }
            }
            assert!(zeros > 10_000, "{zeros}");
        }
    }

    #[test]
    fn the_quick_deep_inside_test_never_says_yes_where_the_exact_one_says_no() {
        // Rotations sampled over each limit and nudged towards and past its bounds (a
        // thin and a wide ellipse, a full twist circle, and a range at the end of the
        // circle): the quick test says "deep inside" only where the exact test does, and
        // says it for most rotations well inside.
        let limits = [
            JointLimit::swing_twist(DVec3::X, DVec3::Z, 1.745, 1.222, -1.396, 1.396),
            JointLimit::swing_twist(DVec3::Y, DVec3::X, 0.6, 0.6, -0.35, 0.35),
            JointLimit::swing_twist(DVec3::Z, DVec3::X, 0.05, 1.5, -PI, PI),
            JointLimit::swing_twist(DVec3::NEG_Y, DVec3::X, 1.745, 0.873, -PI, 0.2),
        ];
        for limit in limits {
            let limit = limit.unwrap();
            let JointLimit::SwingTwist(st) = limit else {
                unreachable!("swing-twist limits")
            };
            let frame = LimitFrame::of(&st);
            let (mut quick_yes, mut exact_yes) = (0, 0);
            for i in 0..40 {
                for k in 0..40 {
                    let u = [
                        (f64::from(i) + 0.5) / 40.0,
                        f64::from(k) / 40.0,
                        (f64::from(i * 7 + k * 3) % 40.0 + 0.5) / 40.0,
                    ];
                    let sample = limit.sample(u);
                    for scale in [0.5, 0.99, 0.9999, 1.0, 1.0001, 1.5] {
                        let q = DQuat::from_scaled_axis(sample.to_scaled_axis() * scale);
                        let exact = {
                            let no_quick = LimitFrame(frame.0, None);
                            st.deep_inside(&no_quick, q, DEEP_MARGIN)
                        };
                        let v = q.xyz();
                        let Some(quick) = &frame.1 else {
                            unreachable!("a prepared frame")
                        };
                        let fast = quick.deep_inside(&frame.0, v.dot(frame.0.twist), q.w, v);
                        assert!(!fast || exact, "{st:?} {q:?}");
                        assert_eq!(st.deep_inside(&frame, q, DEEP_MARGIN), exact);
                        quick_yes += usize::from(fast);
                        exact_yes += usize::from(exact);
                    }
                }
            }
            assert!(
                quick_yes * 10 >= exact_yes * 9,
                "{quick_yes} of {exact_yes}"
            );
        }
    }
}
