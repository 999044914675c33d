//! Analytic two-bone inverse kinematics for sinew skeletons: a root-mid-tip limb
//! (shoulder-elbow-wrist, hip-knee-ankle) solved in closed form by the law of cosines,
//! with a pole target, a twist angle, soften, a blend weight and a hinge at the mid joint.
//!
//! The solver is a job in the manner of ozz-animation's `IKTwoBoneJob`: a
//! [`TwoBoneIk`] value holds the named inputs, [`TwoBoneIk::validate`] checks them, and
//! [`TwoBoneIk::run`] updates a [`Pose`] and its [`GlobalPose`] in place and returns a
//! [`TwoBoneReport`] (reached or not, the final tip-to-target distance, the hinge angle).
//! New inputs are new fields, not new arguments.
//!
//! - The three joints need not be parent and child: joints between root and mid, or mid
//!   and tip, keep their local rotations and move rigidly.
//! - Only the root's and the mid joint's local rotations change. The mid joint turns
//!   about its hinge axis only ([`Hinge`]: an axis in the mid joint's rest frame and a
//!   bend-angle range relative to the rest rotation, the identity), so its new local
//!   rotation is `R(axis, angle)` with `angle` in `[min, max]` (blended with the incoming
//!   rotation when `weight < 1`).
//! - The root turns so that the tip lies on the line from the root to the target, the
//!   mid joint lies in the plane through the root, the target and the pole, on the
//!   pole's side, and then the whole limb turns by `twist` about the root-target line.
//! - Degenerate input has a defined answer and never produces NaN: a target on the
//!   root, out of reach or too close, zero-length bones, a pole on the root-target line
//!   or on the root, a straight limb (the hinge axis defines the bend plane).
//!
//! ```
//! use sinew_ik_two_bone::{DVec3, Hinge, TwoBoneIk};
//! use sinew_skeleton::{GlobalPose, Skeleton};
//!
//! // Shoulder at the origin, unit upper arm and forearm along +x.
//! let skeleton = Skeleton::chain(DVec3::ZERO, &[DVec3::X, DVec3::X]).unwrap();
//! let mut pose = skeleton.rest_pose();
//! let mut global = GlobalPose::new();
//! skeleton.forward_kinematics(&pose, &mut global).unwrap();
//!
//! // A target sqrt(2) away needs a right angle at the elbow; the pole below the limb
//! // puts the elbow on the -y side.
//! let mut job = TwoBoneIk::new(0, 1, 2, DVec3::new(2f64.sqrt(), 0.0, 0.0), DVec3::new(0.5, -1.0, 0.0));
//! job.hinge = Hinge::new(DVec3::Z, 0.0, 150f64.to_radians());
//! let report = job.run(&skeleton, &mut pose, &mut global).unwrap();
//!
//! assert!(report.reached);
//! assert!(report.error < 1e-12);
//! assert!((report.bend_angle - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
//! assert!(global.positions[1].y < 0.0);
//! ```
//!
//! Derivation (law of cosines for any hinge axis, pole plane, soften curve, hinge clamp):
//! `docs/ik-two-bone.md`.

mod bend;

use bend::{Limb, half_angle, softened};
/// The math types targets and poses are given in, re-exported so a user of this crate
/// does not also have to depend on sinew-math.
pub use sinew_math::{DQuat, DVec3};
use sinew_math::{rotation_between, try_unit};
use sinew_skeleton::{GlobalPose, Pose, Skeleton, SkeletonError};
use std::f64::consts::PI;
use std::fmt;

/// The mid joint's hinge: its local rotation is `R(axis, angle)` with `angle` in
/// `[min, max]`, relative to the joint's rest rotation (the identity).
///
/// `axis` is in the mid joint's rest frame, which is the frame of the mid joint's parent
/// (the rest rotation being the identity); a positive angle turns the lower bone about
/// `axis` by the right-hand rule. This is the meaning of a hinge joint limit
/// `{ axis, min, max }` in sinew-skeleton.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct Hinge {
    /// The hinge axis in the mid joint's rest frame; any finite non-zero length (it is
    /// normalized).
    pub axis: DVec3,
    /// The smallest bend angle, radians.
    pub min: f64,
    /// The largest bend angle, radians; at least `min`.
    pub max: f64,
}

impl Hinge {
    /// A hinge about `axis` limited to `[min, max]` radians.
    #[must_use]
    pub fn new(axis: DVec3, min: f64, max: f64) -> Self {
        Self { axis, min, max }
    }

    /// A hinge about `axis` with no limit (the range `[-pi, pi]`, every angle).
    #[must_use]
    pub fn free(axis: DVec3) -> Self {
        Self::new(axis, -PI, PI)
    }
}

/// The skeleton's hinge limit has the same meaning (a rotation about `axis` by an angle
/// in `[min, max]`, relative to the rest rotation), so a limb whose mid joint carries a
/// hinge limit can hand it to the solver unchanged.
impl From<sinew_skeleton::limits::Hinge> for Hinge {
    fn from(limit: sinew_skeleton::limits::Hinge) -> Self {
        Self::new(limit.axis, limit.min, limit.max)
    }
}

/// A two-bone IK job: every input of a solve, by name. See the [crate docs](crate).
///
/// A target beyond the limb's reach straightens it towards the target; the report says
/// the target was not reached and by how much:
///
/// ```
/// use sinew_ik_two_bone::{DVec3, TwoBoneIk};
/// use sinew_skeleton::{GlobalPose, Skeleton};
///
/// let leg = Skeleton::chain(DVec3::ZERO, &[DVec3::new(0.0, -0.5, 0.0); 2]).unwrap();
/// let (mut pose, mut global) = (leg.rest_pose(), GlobalPose::new());
/// leg.forward_kinematics(&pose, &mut global).unwrap();
/// let job = TwoBoneIk::new(0, 1, 2, DVec3::new(1.5, 0.0, 0.0), DVec3::Z);
/// let report = job.run(&leg, &mut pose, &mut global).unwrap();
/// assert!(!report.reached);
/// assert!((report.error - 0.5).abs() < 1e-12);
/// assert!((global.positions[2] - DVec3::X).length() < 1e-12);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct TwoBoneIk {
    /// The root joint (shoulder, hip): the first joint the solve turns.
    pub root: usize,
    /// The mid joint (elbow, knee): a descendant of `root`, turned about its hinge.
    pub mid: usize,
    /// The tip joint (wrist, ankle): a descendant of `mid`, placed on the target.
    pub tip: usize,
    /// Where the tip should go, in world coordinates.
    pub target: DVec3,
    /// A point in world coordinates the bend plane turns towards: the mid joint ends in
    /// the plane through the root, the target and the pole, on the pole's side.
    pub pole: DVec3,
    /// A turn of the whole limb about the root-target line after the pole is applied,
    /// radians (right-hand rule about the direction from root to target). Default 0.
    #[cfg_attr(feature = "serde", serde(default))]
    pub twist: f64,
    /// In `[0, 1]`: the fraction of the reach below which the target is reached exactly;
    /// beyond it the limb extends smoothly towards full extension instead of snapping
    /// straight (`docs/ik-two-bone.md`, section 3). Default 1: no softening.
    #[cfg_attr(feature = "serde", serde(default = "one"))]
    pub soften: f64,
    /// In `[0, 1]`: the blend between the incoming local rotations (0) and the solved
    /// ones (1), by spherical linear interpolation. Default 1.
    #[cfg_attr(feature = "serde", serde(default = "one"))]
    pub weight: f64,
    /// The mid joint's hinge. Default: a free hinge about the rest frame's z axis.
    #[cfg_attr(feature = "serde", serde(default = "default_hinge"))]
    pub hinge: Hinge,
}

#[cfg(feature = "serde")]
fn one() -> f64 {
    1.0
}

#[cfg(feature = "serde")]
fn default_hinge() -> Hinge {
    Hinge::free(DVec3::Z)
}

/// What a [`TwoBoneIk::run`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct TwoBoneReport {
    /// Whether the target was reached: the weight is 1, the target lies below the soften
    /// distance, and a hinge angle inside the range puts the tip at the target's distance
    /// from the root. Then `error` is rounding only (about 1e-15 of the limb's size).
    pub reached: bool,
    /// The distance from the tip to the target after the solve, measured on the updated
    /// global pose.
    pub error: f64,
    /// The hinge angle the solve chose for the mid joint, radians, in the hinge range.
    /// With `weight < 1` the pose holds the blend of this rotation with the incoming one.
    pub bend_angle: f64,
}

/// Why a two-bone job was refused. Every variant names the field or the joint at fault.
#[derive(Clone, Debug, PartialEq)]
pub enum TwoBoneError {
    /// A joint index field (`root`, `mid` or `tip`) is not in the skeleton.
    JointOutOfRange {
        /// The field.
        field: &'static str,
        /// The index it holds.
        index: usize,
        /// The number of joints.
        len: usize,
    },
    /// `mid` is not a strict descendant of `root`, or `tip` of `mid`.
    NotADescendant {
        /// The field that should be the descendant (`mid` or `tip`).
        field: &'static str,
        /// That joint, with its name when it has one.
        joint: String,
        /// The field that should be its ancestor (`root` or `mid`).
        ancestor_field: &'static str,
        /// That joint, with its name when it has one.
        ancestor: String,
    },
    /// A number or vector field has a NaN or infinite component.
    NonFinite {
        /// The field (`target`, `pole`, `twist`, `soften`, `weight`, `hinge.axis`,
        /// `hinge.min`, `hinge.max`).
        field: &'static str,
    },
    /// `soften` or `weight` is outside `[0, 1]`.
    OutOfUnitInterval {
        /// The field.
        field: &'static str,
        /// Its value.
        value: f64,
    },
    /// `hinge.axis` is the zero vector.
    ZeroHingeAxis,
    /// `hinge.min` is greater than `hinge.max`.
    HingeRange {
        /// The smallest angle given.
        min: f64,
        /// The largest angle given.
        max: f64,
    },
    /// The pose does not fit the skeleton, or a local rotation the solve reads is zero or
    /// not finite, or forward kinematics refused the pose.
    Skeleton(SkeletonError),
    /// The global pose holds a NaN or infinite rotation or position for a joint the solve
    /// reads, so it is not forward kinematics of a valid pose.
    InvalidGlobalPose {
        /// The joint, with its name when it has one.
        joint: String,
    },
}

impl fmt::Display for TwoBoneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::JointOutOfRange { field, index, len } => write!(
                f,
                "two-bone IK `{field}`: joint index {index} is out of range (the skeleton has {len} joints)"
            ),
            Self::NotADescendant {
                field,
                joint,
                ancestor_field,
                ancestor,
            } => write!(
                f,
                "two-bone IK `{field}`: {joint} is not a descendant of `{ancestor_field}` ({ancestor})"
            ),
            Self::NonFinite { field } => {
                write!(f, "two-bone IK `{field}` has a NaN or infinite component")
            }
            Self::OutOfUnitInterval { field, value } => {
                write!(f, "two-bone IK `{field}` must be in [0, 1], got {value}")
            }
            Self::ZeroHingeAxis => write!(f, "two-bone IK `hinge.axis` is the zero vector"),
            Self::HingeRange { min, max } => write!(
                f,
                "two-bone IK `hinge.min` ({min}) is greater than `hinge.max` ({max})"
            ),
            Self::Skeleton(e) => write!(f, "two-bone IK: {e}"),
            Self::InvalidGlobalPose { joint } => write!(
                f,
                "two-bone IK: the global pose of {joint} is not finite (run forward kinematics of a valid pose first)"
            ),
        }
    }
}

impl std::error::Error for TwoBoneError {}

impl From<SkeletonError> for TwoBoneError {
    fn from(e: SkeletonError) -> Self {
        Self::Skeleton(e)
    }
}

/// The unit vector along `v`, or `None` when it has no direction: one square root and one
/// division in the usual range of lengths, `try_unit` (which rescales first, so it
/// neither underflows nor overflows) outside it.
#[inline]
fn unit(v: DVec3) -> Option<DVec3> {
    let squared = v.length_squared();
    if squared > 1e-200 && squared < 1e200 {
        Some(v * (1.0 / squared.sqrt()))
    } else {
        try_unit(v)
    }
}

/// The length of `v`, without overflow or underflow in the squares where the length
/// itself is representable.
#[inline]
fn length(v: DVec3) -> f64 {
    let fast = v.length();
    if fast.is_finite() && fast > 1e-150 {
        return fast;
    }
    let scale = v.abs().max_element();
    if scale == 0.0 || !scale.is_finite() {
        fast
    } else {
        (v / scale).length() * scale
    }
}

/// The minimal rotation taking the direction of `from` onto the unit vector `to`, as a
/// quaternion of norm in `[1, 2]` (not normalized: the caller normalizes once, at the
/// end of a product).
///
/// For a unit `a` it is `(a x to, 1 + a . to)`, of norm `sqrt(2 (1 + a . to))`; with
/// `a = from / |from|` that needs one division. The `w` term cancels as the angle nears a
/// half turn, so beyond 120 degrees `rotation_between` (exact there, and slower, and
/// normalized) takes over.
#[inline]
fn turn_onto(from: DVec3, to: DVec3) -> DQuat {
    let size = from.length();
    let dot = from.dot(to);
    if size > 1e-100 && size < 1e100 && dot > -0.5 * size {
        let inverse = 1.0 / size;
        let axis = from.cross(to) * inverse;
        DQuat::from_xyzw(axis.x, axis.y, axis.z, 1.0 + dot * inverse)
    } else {
        rotation_between(from, to)
    }
}

/// The rotation about the unit vector `axis` by the angle whose cosine and sine are
/// `cos / r` and `sin / r` for some `r > 0` whose square is a normal floating-point
/// number, as a quaternion of norm in `[1, 2]` (not normalized).
///
/// With `C`, `S` the unit cosine and sine, `(1 + C, S)` and `(S, 1 - C)` are both
/// proportional to `(cos(x/2), sin(x/2))` (by `2 cos(x/2)` and `2 sin(x/2)`); the first
/// is used for `C >= 0`, the second otherwise, so no term cancels. One square root (for
/// `r`) and one division.
#[inline]
fn turn_about(axis: DVec3, cos: f64, sin: f64) -> DQuat {
    let inverse = 1.0 / (cos * cos + sin * sin).sqrt();
    let (c, s) = (cos * inverse, sin * inverse);
    let (w, along) = if c >= 0.0 { (1.0 + c, s) } else { (s, 1.0 - c) };
    DQuat::from_xyzw(axis.x * along, axis.y * along, axis.z * along, w)
}

/// A pose entry counts as unusable when it is zero or not finite, as forward kinematics
/// counts it.
#[inline]
fn usable_rotation(q: DQuat) -> bool {
    q.is_finite() && q.length_squared() != 0.0
}

impl TwoBoneIk {
    /// A job for the limb `root`-`mid`-`tip` reaching for `target` with the bend towards
    /// `pole`; no twist, no softening (`soften = 1`), full weight, and a free hinge about
    /// the rest frame's z axis. Set the other fields directly.
    #[must_use]
    pub fn new(root: usize, mid: usize, tip: usize, target: DVec3, pole: DVec3) -> Self {
        Self {
            root,
            mid,
            tip,
            target,
            pole,
            twist: 0.0,
            soften: 1.0,
            weight: 1.0,
            hinge: Hinge::free(DVec3::Z),
        }
    }

    /// Checks every input against `skeleton` and `pose`: the joint indices in range and
    /// in ancestor order (`mid` a strict descendant of `root`, `tip` of `mid`), every
    /// number finite, `soften` and `weight` in `[0, 1]`, a non-zero hinge axis,
    /// `hinge.min <= hinge.max`, the pose the skeleton's size with usable rotations at
    /// `root` and `mid`. The error names the field.
    pub fn validate(&self, skeleton: &Skeleton, pose: &Pose) -> Result<(), TwoBoneError> {
        let len = skeleton.len();
        for (field, index) in [("root", self.root), ("mid", self.mid), ("tip", self.tip)] {
            if index >= len {
                return Err(TwoBoneError::JointOutOfRange { field, index, len });
            }
        }
        for (field, ancestor_field, joint, ancestor) in [
            ("mid", "root", self.mid, self.root),
            ("tip", "mid", self.tip, self.mid),
        ] {
            if joint == ancestor || !skeleton.is_ancestor_or_self(ancestor, joint) {
                return Err(TwoBoneError::NotADescendant {
                    field,
                    joint: skeleton.label(joint),
                    ancestor_field,
                    ancestor: skeleton.label(ancestor),
                });
            }
        }
        let vectors = [
            ("target", self.target),
            ("pole", self.pole),
            ("hinge.axis", self.hinge.axis),
        ];
        for (field, v) in vectors {
            if !v.is_finite() {
                return Err(TwoBoneError::NonFinite { field });
            }
        }
        let numbers = [
            ("twist", self.twist),
            ("soften", self.soften),
            ("weight", self.weight),
            ("hinge.min", self.hinge.min),
            ("hinge.max", self.hinge.max),
        ];
        for (field, x) in numbers {
            if !x.is_finite() {
                return Err(TwoBoneError::NonFinite { field });
            }
        }
        for (field, value) in [("soften", self.soften), ("weight", self.weight)] {
            if !(0.0..=1.0).contains(&value) {
                return Err(TwoBoneError::OutOfUnitInterval { field, value });
            }
        }
        if self.hinge.axis == DVec3::ZERO {
            return Err(TwoBoneError::ZeroHingeAxis);
        }
        if self.hinge.min > self.hinge.max {
            return Err(TwoBoneError::HingeRange {
                min: self.hinge.min,
                max: self.hinge.max,
            });
        }
        if pose.rotations.len() != len {
            return Err(SkeletonError::PoseLength {
                expected: len,
                got: pose.rotations.len(),
            }
            .into());
        }
        for joint in [self.root, self.mid] {
            if !usable_rotation(pose.rotations[joint]) {
                return Err(SkeletonError::InvalidRotation {
                    joint: skeleton.label(joint),
                }
                .into());
            }
        }
        Ok(())
    }

    /// Solves: validates, turns the root's and the mid joint's local rotations in `pose`
    /// (blended with the incoming ones by `weight`), and redoes forward kinematics of the
    /// root's subtree into `global`.
    ///
    /// `global` must hold forward kinematics of `pose` (as after
    /// [`Skeleton::forward_kinematics`]); if it is not the skeleton's size it is computed
    /// first. Allocates nothing except for an error message. If forward kinematics of the
    /// result fails (an unusable rotation elsewhere in the root's subtree, so `global` was
    /// not forward kinematics of `pose`), the two rotations are restored in `pose` and the
    /// error returned; `global` must then be recomputed.
    pub fn run(
        &self,
        skeleton: &Skeleton,
        pose: &mut Pose,
        global: &mut GlobalPose,
    ) -> Result<TwoBoneReport, TwoBoneError> {
        self.validate(skeleton, pose)?;
        if global.positions.len() != skeleton.len() || global.rotations.len() != skeleton.len() {
            skeleton.forward_kinematics(pose, global)?;
        }
        let (root, mid, tip) = (self.root, self.mid, self.tip);
        // `mid` is a strict descendant of `root`, so it has a parent.
        let mid_parent = skeleton.parent(mid).unwrap_or(root);
        let root_parent = skeleton.parent(root);
        for joint in [
            Some(root),
            Some(mid),
            Some(tip),
            Some(mid_parent),
            root_parent,
        ]
        .into_iter()
        .flatten()
        {
            if !global.positions[joint].is_finite() || !usable_rotation(global.rotations[joint]) {
                return Err(TwoBoneError::InvalidGlobalPose {
                    joint: skeleton.label(joint),
                });
            }
        }

        let root_position = global.positions[root];
        let mid_position = global.positions[mid];
        let mid_parent_rotation = global.rotations[mid_parent];
        // The hinge axis and the lower bone as they would be with the mid joint at rest,
        // in world axes (the mid joint's rest frame is its parent's frame).
        let axis = unit(self.hinge.axis).unwrap_or(DVec3::Z);
        let world_axis = mid_parent_rotation * axis;
        let lower_in_mid = global.rotations[mid].inverse() * (global.positions[tip] - mid_position);
        let lower_rest = mid_parent_rotation * lower_in_mid;
        let upper = mid_position - root_position;
        let to_target = self.target - root_position;
        let distance = length(to_target);
        let aim = if distance > 1e-100 && distance < 1e100 {
            Some(to_target * (1.0 / distance))
        } else {
            unit(to_target)
        };
        // The bend works with squared lengths, which overflow for limbs beyond about
        // 1e150 and lose digits below about 1e-150. Such limbs are solved scaled to unit
        // size, which changes no angle and no direction.
        let size = upper
            .abs()
            .max_element()
            .max(lower_rest.abs().max_element());
        let (upper, lower_rest, distance) = if size > 0.0 && !(1e-100..=1e100).contains(&size) {
            (upper / size, lower_rest / size, distance / size)
        } else {
            (upper, lower_rest, distance)
        };
        let limb = Limb::new(upper, lower_rest, world_axis);
        // soften = 1 never softens, and the reach costs a square root.
        let goal = if self.soften < 1.0 {
            softened(distance, limb.max_distance(), self.soften)
        } else {
            distance
        };
        let bend = limb.choose(goal, self.hinge.min, self.hinge.max);
        let tip_offset = limb.tip(bend.cos, bend.sin);
        // With the target on the root, a folded limb's tip offset below this is rounding,
        // not a direction.
        let negligible = if distance == 0.0 {
            1e-12 * (upper.length() + lower_rest.length())
        } else {
            0.0
        };

        let turn = self.root_turn(
            aim,
            tip_offset,
            negligible,
            upper,
            self.pole - root_position,
        );
        // `turn` is a product of rotations scaled by factors of order 1 (see `root_turn`):
        // one normalization here makes the product a unit quaternion.
        let root_rotation = (turn * global.rotations[root]).normalize();
        // A product of unit quaternions, so unit to rounding (forward kinematics
        // normalizes global rotations in any case).
        let solved_root = match root_parent {
            Some(p) => global.rotations[p].inverse() * root_rotation,
            None => root_rotation,
        };
        // R(axis, angle) from the angle's cosine and sine, without trigonometric calls;
        // unit to rounding like its inputs.
        let (c, s) = half_angle(bend.cos, bend.sin);
        let solved_mid = DQuat::from_xyzw(axis.x * s, axis.y * s, axis.z * s, c);

        let incoming = (pose.rotations[root], pose.rotations[mid]);
        if self.weight > 0.0 {
            if self.weight < 1.0 {
                pose.rotations[root] = incoming.0.normalize().slerp(solved_root, self.weight);
                pose.rotations[mid] = incoming.1.normalize().slerp(solved_mid, self.weight);
            } else {
                pose.rotations[root] = solved_root;
                pose.rotations[mid] = solved_mid;
            }
            if let Err(e) = skeleton.forward_kinematics_from(pose, root, global) {
                pose.rotations[root] = incoming.0;
                pose.rotations[mid] = incoming.1;
                return Err(e.into());
            }
        }
        Ok(TwoBoneReport {
            reached: bend.exact && goal == distance && self.weight == 1.0,
            error: length(global.positions[tip] - self.target),
            bend_angle: bend.angle,
        })
    }

    /// The world rotation of the root, up to a non-zero factor of order 1 (the caller
    /// normalizes), that takes the solved limb (tip at `tip_offset`,
    /// mid joint at `upper`, both relative to the root with the root's current rotation)
    /// onto the target line, turns the mid joint towards the pole and applies the twist.
    /// `aim` is the unit vector from the root to the target (`None` for a target on the
    /// root), `to_pole` is relative to the root; a tip offset no longer than `negligible`
    /// counts as the tip on the root.
    fn root_turn(
        &self,
        aim: Option<DVec3>,
        tip_offset: DVec3,
        negligible: f64,
        upper: DVec3,
        to_pole: DVec3,
    ) -> DQuat {
        // The line the tip must lie on. A target on the root has no direction; the tip's
        // own direction is then kept (the solve folded the limb as far as it goes).
        let (aim, minimal) = match aim {
            Some(aim) => (aim, turn_onto(tip_offset, aim)),
            None => match unit(tip_offset).filter(|_| tip_offset.length() > negligible) {
                Some(aim) => (aim, DQuat::IDENTITY),
                None => {
                    // The tip is on the root too: there is no line, only the mid
                    // joint's direction left to turn towards the pole.
                    return rotation_between(upper, to_pole);
                }
            },
        };
        // Turn about the aim line so the mid joint's offset from the line points the way
        // the pole's does. A straight limb (mid on the line) or a pole on the line has no
        // such direction: that turn is skipped, the twist still applies.
        let mid = minimal * upper;
        let mid_across = mid - aim * aim.dot(mid);
        let pole_across = to_pole - aim * aim.dot(to_pole);
        let twist = if self.twist == 0.0 {
            DQuat::IDENTITY
        } else {
            DQuat::from_axis_angle(aim, self.twist)
        };
        // The turn between two directions perpendicular to the aim line is about that
        // line: their cosine and sine give its quaternion directly (no atan2; and a half
        // turn is about the aim line, where a generic minimal rotation could pick any
        // perpendicular axis). The squared lengths serve while they are safely inside the
        // floating-point range (so the product of the two lengths squared is too), the
        // rescaling `length` and `unit` otherwise.
        let (mid_squared, pole_squared) =
            (mid_across.length_squared(), pole_across.length_squared());
        let safe = |x: f64| x > 1e-150 && x < 1e150;
        let spin = if safe(mid_squared) && safe(pole_squared) {
            (mid_squared > 1e-24 * mid.length_squared()
                && pole_squared > 1e-24 * to_pole.length_squared())
            .then(|| {
                (
                    mid_across.dot(pole_across),
                    aim.dot(mid_across.cross(pole_across)),
                )
            })
        } else {
            let off_line = length(mid_across) > 1e-12 * length(mid)
                && length(pole_across) > 1e-12 * length(to_pole);
            match (unit(mid_across), unit(pole_across)) {
                (Some(from), Some(to)) if off_line => Some((from.dot(to), aim.dot(from.cross(to)))),
                _ => None,
            }
        };
        match spin {
            Some((cos, sin)) => twist * turn_about(aim, cos, sin) * minimal,
            None => twist * minimal,
        }
    }
}
