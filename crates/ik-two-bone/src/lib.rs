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
use sinew_math::{robust_length as length, rotation_between, try_unit};
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
    /// A [`PreparedTwoBone`] was run on a skeleton other than the one it was prepared
    /// for (another size, or other parents or offsets).
    OtherSkeleton {
        /// The number of joints of the skeleton given.
        joints: usize,
        /// The number of joints of the skeleton prepared for.
        prepared_joints: usize,
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
            Self::OtherSkeleton {
                joints,
                prepared_joints,
            } => write!(
                f,
                "two-bone IK `skeleton`: the job was prepared for another skeleton ({prepared_joints} joints; this one has {joints}, or other parents or offsets)"
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

/// The minimal rotation taking the direction of `from` onto the unit vector `to`, as a
/// quaternion of norm in `[1, 2]` (not normalized: the caller normalizes once, at the
/// end of a product).
///
/// For a unit `a` it is `(a x to, 1 + a . to)`, of norm `sqrt(2 (1 + a . to))`; with
/// `a = from / |from|` that needs one division. The `w` term cancels as the angle nears a
/// half turn, so beyond 120 degrees `rotation_between` (exact there, and slower, and
/// normalized) takes over.
///
/// Beyond 120 degrees the answer is a rotation taking `from` onto `to` that is not the
/// minimal one (the second value is then `false`): a half turn about an axis
/// perpendicular to `from`, which takes it to its opposite, followed by the minimal
/// rotation from the opposite onto `to`, an angle below 60 degrees where the formula above
/// has no cancellation. That costs a fraction of `rotation_between`, which is exact at a
/// half turn too; a caller that needs the minimal rotation there calls it instead.
#[inline]
fn turn_onto(from: DVec3, to: DVec3) -> (DQuat, bool) {
    let size = from.length();
    let dot = from.dot(to);
    if !(size > 1e-100 && size < 1e100) {
        return (rotation_between(from, to), true);
    }
    let inverse = 1.0 / size;
    if dot > -0.5 * size {
        let axis = from.cross(to) * inverse;
        (
            DQuat::from_xyzw(axis.x, axis.y, axis.z, 1.0 + dot * inverse),
            true,
        )
    } else {
        let opposite = from * -inverse;
        let half_turn_axis = opposite.any_orthonormal_vector();
        let axis = opposite.cross(to);
        let acute = DQuat::from_xyzw(axis.x, axis.y, axis.z, 1.0 - dot * inverse);
        let half_turn = DQuat::from_xyzw(half_turn_axis.x, half_turn_axis.y, half_turn_axis.z, 0.0);
        (acute * half_turn, false)
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
        self.check_structure(skeleton)?;
        check_inputs(self.target, self.pole, self.twist, self.soften, self.weight)?;
        check_hinge(&self.hinge)?;
        check_pose(skeleton, pose, [self.root, self.mid])
    }

    /// The joint indices: in range and in ancestor order.
    fn check_structure(&self, skeleton: &Skeleton) -> Result<(), TwoBoneError> {
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
        Ok(())
    }

    /// This job checked once against `skeleton`, for solving many times: everything that
    /// does not depend on the target, the pole, the twist, the soften ratio or the weight
    /// (the joint indices and their ancestry, the hinge) is checked here, and what the
    /// solve derives from the skeleton alone is kept. The per-call inputs are copied into
    /// the prepared job's public fields and checked by each [`PreparedTwoBone::run`].
    /// The error names the field, as [`TwoBoneIk::validate`] does.
    pub fn prepare(&self, skeleton: &Skeleton) -> Result<PreparedTwoBone, TwoBoneError> {
        self.check_structure(skeleton)?;
        check_hinge(&self.hinge)?;
        Ok(self.prepare_checked(skeleton))
    }

    /// [`TwoBoneIk::prepare`] after the structure and the hinge were checked.
    fn prepare_checked(&self, skeleton: &Skeleton) -> PreparedTwoBone {
        let (root, mid, tip) = (self.root, self.mid, self.tip);
        // `mid` is a strict descendant of `root`, so it has a parent.
        let mid_parent = skeleton.parent(mid).unwrap_or(root);
        // The root's subtree is exactly root, mid, tip in a row when the tip is the mid
        // joint's child, the mid joint the root's, and no index past the tip descends from
        // the root (descendants come after their ancestors). Forward kinematics after a
        // solve then touches those three joints only, and the solve does it inline.
        let limb_only = (mid_parent == root
            && skeleton.parent(tip) == Some(mid)
            && mid == root + 1
            && tip == root + 2
            && skeleton.subtree_end(root) == root + 3)
            .then(|| (skeleton.offset(mid), skeleton.offset(tip)));
        PreparedTwoBone {
            target: self.target,
            pole: self.pole,
            twist: self.twist,
            soften: self.soften,
            weight: self.weight,
            root,
            mid,
            tip,
            hinge: self.hinge,
            // The hinge was checked: finite and non-zero.
            axis: unit(self.hinge.axis).unwrap_or(DVec3::Z),
            mid_parent,
            root_parent: skeleton.parent(root),
            joints: skeleton.len(),
            fingerprint: skeleton.fingerprint(),
            limb_only,
        }
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
    ///
    /// To solve the same limb many times, [`TwoBoneIk::prepare`] it once and call
    /// [`PreparedTwoBone::run`]: the same answer, bit for bit, without the checks that
    /// depend on the skeleton alone.
    pub fn run(
        &self,
        skeleton: &Skeleton,
        pose: &mut Pose,
        global: &mut GlobalPose,
    ) -> Result<TwoBoneReport, TwoBoneError> {
        self.validate(skeleton, pose)?;
        self.prepare_checked(skeleton)
            .solve_checked(skeleton, pose, global)
    }
}

/// The inputs that change from call to call: vectors finite, numbers finite, `soften` and
/// `weight` in `[0, 1]`. One test on the usual path, the located error otherwise.
#[inline]
fn check_inputs(
    target: DVec3,
    pole: DVec3,
    twist: f64,
    soften: f64,
    weight: f64,
) -> Result<(), TwoBoneError> {
    // A NaN is in no interval, so this also refuses NaN soften and weight.
    if target.is_finite()
        && pole.is_finite()
        && twist.is_finite()
        && (0.0..=1.0).contains(&soften)
        && (0.0..=1.0).contains(&weight)
    {
        return Ok(());
    }
    for (field, v) in [("target", target), ("pole", pole)] {
        if !v.is_finite() {
            return Err(TwoBoneError::NonFinite { field });
        }
    }
    for (field, x) in [("twist", twist), ("soften", soften), ("weight", weight)] {
        if !x.is_finite() {
            return Err(TwoBoneError::NonFinite { field });
        }
    }
    for (field, value) in [("soften", soften), ("weight", weight)] {
        if !(0.0..=1.0).contains(&value) {
            return Err(TwoBoneError::OutOfUnitInterval { field, value });
        }
    }
    Ok(())
}

/// The hinge: a finite non-zero axis, finite bounds, `min <= max`.
fn check_hinge(hinge: &Hinge) -> Result<(), TwoBoneError> {
    if !hinge.axis.is_finite() {
        return Err(TwoBoneError::NonFinite {
            field: "hinge.axis",
        });
    }
    for (field, x) in [("hinge.min", hinge.min), ("hinge.max", hinge.max)] {
        if !x.is_finite() {
            return Err(TwoBoneError::NonFinite { field });
        }
    }
    if hinge.axis == DVec3::ZERO {
        return Err(TwoBoneError::ZeroHingeAxis);
    }
    if hinge.min > hinge.max {
        return Err(TwoBoneError::HingeRange {
            min: hinge.min,
            max: hinge.max,
        });
    }
    Ok(())
}

/// The pose: the skeleton's size, and usable local rotations at `joints`.
#[inline]
fn check_pose<const N: usize>(
    skeleton: &Skeleton,
    pose: &Pose,
    joints: [usize; N],
) -> Result<(), TwoBoneError> {
    if pose.rotations.len() != skeleton.len() {
        return Err(SkeletonError::PoseLength {
            expected: skeleton.len(),
            got: pose.rotations.len(),
        }
        .into());
    }
    for joint in joints {
        if !usable_rotation(pose.rotations[joint]) {
            return Err(SkeletonError::InvalidRotation {
                joint: skeleton.label(joint),
            }
            .into());
        }
    }
    Ok(())
}

/// A [`TwoBoneIk`] prepared for one skeleton by [`TwoBoneIk::prepare`]: the joints and the
/// hinge are fixed and checked, the inputs that change per call are public fields.
///
/// ```
/// use sinew_ik_two_bone::{DVec3, Hinge, TwoBoneIk};
/// use sinew_skeleton::{GlobalPose, Skeleton};
///
/// let arm = Skeleton::chain(DVec3::ZERO, &[DVec3::X, DVec3::X]).unwrap();
/// let (mut pose, mut global) = (arm.rest_pose(), GlobalPose::new());
/// arm.forward_kinematics(&pose, &mut global).unwrap();
/// let mut job = TwoBoneIk::new(0, 1, 2, DVec3::ZERO, DVec3::new(0.5, -1.0, 0.0));
/// job.hinge = Hinge::new(DVec3::Z, 0.0, 150f64.to_radians());
/// let mut prepared = job.prepare(&arm).unwrap();
/// for k in 4..=12 {
///     prepared.target = DVec3::new(0.15 * k as f64, 0.3, 0.0);
///     let report = prepared.run(&arm, &mut pose, &mut global).unwrap();
///     assert!(report.reached && report.error < 1e-12);
/// }
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PreparedTwoBone {
    /// Where the tip should go, in world coordinates ([`TwoBoneIk::target`]).
    pub target: DVec3,
    /// The point the bend plane turns towards ([`TwoBoneIk::pole`]).
    pub pole: DVec3,
    /// The turn about the root-target line, radians ([`TwoBoneIk::twist`]).
    pub twist: f64,
    /// The soften ratio in `[0, 1]` ([`TwoBoneIk::soften`]).
    pub soften: f64,
    /// The blend weight in `[0, 1]` ([`TwoBoneIk::weight`]).
    pub weight: f64,
    root: usize,
    mid: usize,
    tip: usize,
    hinge: Hinge,
    /// `hinge.axis` normalized.
    axis: DVec3,
    /// The mid joint's parent (the root itself for a bare limb).
    mid_parent: usize,
    root_parent: Option<usize>,
    /// The size and the structure's fingerprint of the skeleton it was prepared for.
    joints: usize,
    fingerprint: u64,
    /// The offsets of the mid joint and the tip when the root's subtree is exactly the
    /// root, the mid joint and the tip in a row: forward kinematics is then done inline.
    limb_only: Option<(DVec3, DVec3)>,
}

impl PreparedTwoBone {
    /// The joints `(root, mid, tip)`.
    #[must_use]
    pub fn joints(&self) -> (usize, usize, usize) {
        (self.root, self.mid, self.tip)
    }

    /// The mid joint's hinge.
    #[must_use]
    pub fn hinge(&self) -> Hinge {
        self.hinge
    }

    /// Solves as [`TwoBoneIk::run`] does, with the same answer bit for bit, checking only
    /// what can change between calls: the skeleton is the one prepared for (its size and
    /// structure), the per-call fields (target, pole and twist finite, soften and weight
    /// in `[0, 1]`), the pose's size and the local rotations the solve reads, and the
    /// global pose of the joints it reads. Each error names the field or the joint, and
    /// nothing is changed then.
    pub fn run(
        &self,
        skeleton: &Skeleton,
        pose: &mut Pose,
        global: &mut GlobalPose,
    ) -> Result<TwoBoneReport, TwoBoneError> {
        if skeleton.len() != self.joints || skeleton.fingerprint() != self.fingerprint {
            return Err(TwoBoneError::OtherSkeleton {
                joints: skeleton.len(),
                prepared_joints: self.joints,
            });
        }
        check_inputs(self.target, self.pole, self.twist, self.soften, self.weight)?;
        check_pose(skeleton, pose, [self.root, self.mid])?;
        self.solve_checked(skeleton, pose, global)
    }

    /// The solve, once the job, the skeleton and the pose's size and the root's and the
    /// mid joint's rotations were checked.
    fn solve_checked(
        &self,
        skeleton: &Skeleton,
        pose: &mut Pose,
        global: &mut GlobalPose,
    ) -> Result<TwoBoneReport, TwoBoneError> {
        if global.positions.len() != skeleton.len() || global.rotations.len() != skeleton.len() {
            skeleton.forward_kinematics(pose, global)?;
        }
        let (root, mid, tip, mid_parent, root_parent) = (
            self.root,
            self.mid,
            self.tip,
            self.mid_parent,
            self.root_parent,
        );
        // Forward kinematics of the result reads the tip's local rotation when it is done
        // inline: refuse an unusable one before anything changes.
        if self.limb_only.is_some() && !usable_rotation(pose.rotations[tip]) {
            return Err(SkeletonError::InvalidRotation {
                joint: skeleton.label(tip),
            }
            .into());
        }
        // The global pose of every joint the solve reads must be usable. A bare limb
        // reads the root's position and rotation, the mid joint's position and the root
        // parent's rotation (the mid joint's parent is the root, the lower bone is the
        // tip's offset, and the mid joint's and the tip's global rotations are rewritten
        // by the inline forward kinematics without being read).
        let usable_global =
            |j: usize| global.positions[j].is_finite() && usable_rotation(global.rotations[j]);
        let fine = if self.limb_only.is_some() {
            usable_global(root)
                && global.positions[mid].is_finite()
                && root_parent.is_none_or(usable_global)
        } else {
            usable_global(root)
                && usable_global(mid)
                && usable_global(tip)
                && usable_global(mid_parent)
                && root_parent.is_none_or(usable_global)
        };
        if !fine {
            let bad = if self.limb_only.is_some() {
                [Some(root), root_parent]
                    .into_iter()
                    .flatten()
                    .find(|&j| !usable_global(j))
                    .unwrap_or(mid)
            } else {
                [
                    Some(root),
                    Some(mid),
                    Some(tip),
                    Some(mid_parent),
                    root_parent,
                ]
                .into_iter()
                .flatten()
                .find(|&j| !usable_global(j))
                .unwrap_or(root)
            };
            return Err(TwoBoneError::InvalidGlobalPose {
                joint: skeleton.label(bad),
            });
        }

        let root_position = global.positions[root];
        let mid_position = global.positions[mid];
        let mid_parent_rotation = global.rotations[mid_parent];
        // The hinge axis and the lower bone as they would be with the mid joint at rest,
        // in world axes (the mid joint's rest frame is its parent's frame).
        let axis = self.axis;
        let world_axis = mid_parent_rotation * axis;
        // For a bare limb the lower bone in the mid joint's frame is the tip's offset
        // (forward kinematics put the tip there); otherwise joints in between may turn it.
        let lower_in_mid = match self.limb_only {
            Some((_, tip_offset)) => tip_offset,
            None => global.rotations[mid].inverse() * (global.positions[tip] - mid_position),
        };
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
            match self.limb_only {
                Some((mid_offset, tip_offset)) => {
                    // Forward kinematics of the three joints, the same operations in the
                    // same order as `Skeleton::forward_kinematics_from` (so the same bits);
                    // the root's position does not depend on its own rotation. Every
                    // rotation read is usable: the solved ones are unit, the tip's and the
                    // root parent's were checked.
                    let root_rotation = match root_parent {
                        Some(p) => (global.rotations[p] * pose.rotations[root]).normalize(),
                        None => pose.rotations[root].normalize(),
                    };
                    let mid_rotation = (root_rotation * pose.rotations[mid]).normalize();
                    let mid_position = global.positions[root] + root_rotation * mid_offset;
                    global.rotations[root] = root_rotation;
                    global.rotations[mid] = mid_rotation;
                    global.positions[mid] = mid_position;
                    global.rotations[tip] = (mid_rotation * pose.rotations[tip]).normalize();
                    global.positions[tip] = mid_position + mid_rotation * tip_offset;
                }
                None => {
                    if let Err(e) = skeleton.forward_kinematics_from(pose, root, global) {
                        pose.rotations[root] = incoming.0;
                        pose.rotations[mid] = incoming.1;
                        return Err(e.into());
                    }
                }
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
        // `onto` takes the tip onto the line; it is the minimal such rotation unless
        // `is_minimal` says otherwise (see `turn_onto`).
        let (aim, onto, is_minimal) = match aim {
            Some(aim) => {
                let (onto, is_minimal) = turn_onto(tip_offset, aim);
                (aim, onto, is_minimal)
            }
            None => match unit(tip_offset).filter(|_| tip_offset.length() > negligible) {
                Some(aim) => (aim, DQuat::IDENTITY, true),
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
        // Any rotation taking the tip onto the line serves here: the turn about the line
        // that follows is measured from where it leaves the mid joint, and the two
        // together are the one rotation that puts the tip on the line and the mid joint
        // towards the pole. The perpendicular distance of the mid joint from the line
        // does not depend on which rotation it was, so neither does the test for a
        // straight limb.
        let mid = onto * upper;
        let mid_across = mid - aim * aim.dot(mid);
        let pole_across = to_pole - aim * aim.dot(to_pole);
        let twist = (self.twist != 0.0).then(|| DQuat::from_axis_angle(aim, self.twist));
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
        let turn = match spin {
            Some((cos, sin)) => turn_about(aim, cos, sin) * onto,
            // Without a turn towards the pole, the bend plane is where the minimal
            // rotation onto the line leaves it.
            None if is_minimal => onto,
            None => rotation_between(tip_offset, aim),
        };
        match twist {
            Some(twist) => twist * turn,
            None => turn,
        }
    }
}
