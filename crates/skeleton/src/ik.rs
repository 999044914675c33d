//! The inverse-kinematics vocabulary both solver crates share, written once here.
//!
//! - [`Chain`]: the path from a base joint to an effector joint inside a skeleton, with
//!   its bone lengths and reach.
//! - [`SolveSettings`] (iteration cap, absolute tolerance) and [`SolveReport`]
//!   (iterations used, error reached, [`StopReason`]).
//! - [`straighten_towards`]: the closed-form answer for a target out of reach (every
//!   bone aimed at the target, the lab's Q1).
//! - [`begin_solve`]: the checks and early exits every solver makes first (bad input,
//!   already within tolerance, out of reach), so they are made the same way everywhere.
//! - [`IkSolver`]: the trait the solvers implement, so the scene runner and the
//!   property suite can run any solver alike.
//!
//! Tolerances are absolute distances in scene units between the effector and the target.

use crate::{GlobalPose, Pose, Skeleton, SkeletonError};
use sinew_math::{DQuat, DVec3, rotation_between, try_unit};
use std::fmt;

/// The path of joints from a base joint to an effector joint (the base an ancestor of the
/// effector, or the same joint), with the bones between them.
///
/// The bone from `joints[c]` to `joints[c + 1]` is turned by the local rotation of
/// `joints[c]`; the base's own position does not depend on the chain's rotations.
#[derive(Clone, Debug, PartialEq)]
pub struct Chain {
    joints: Vec<usize>,
    bone_lengths: Vec<f64>,
    reach: f64,
    skeleton_len: usize,
}

impl Chain {
    /// The chain from `base` to `effector` in `skeleton`. An error when either index is
    /// out of range or `base` is not an ancestor of `effector`.
    pub fn new(skeleton: &Skeleton, base: usize, effector: usize) -> Result<Self, SkeletonError> {
        skeleton.check_index(base)?;
        skeleton.check_index(effector)?;
        if !skeleton.is_ancestor_or_self(base, effector) {
            return Err(SkeletonError::NotAnAncestor {
                base: skeleton.label(base),
                effector: skeleton.label(effector),
            });
        }
        let mut joints = vec![effector];
        let mut j = effector;
        while j != base {
            // `base` is an ancestor, so the walk reaches it before running out of parents.
            j = skeleton.parent(j).ok_or(SkeletonError::NotAnAncestor {
                base: skeleton.label(base),
                effector: skeleton.label(effector),
            })?;
            joints.push(j);
        }
        joints.reverse();
        let bone_lengths: Vec<f64> = joints[1..]
            .iter()
            .map(|&j| skeleton.offset(j).length())
            .collect();
        let reach = bone_lengths.iter().sum();
        Ok(Self {
            joints,
            bone_lengths,
            reach,
            skeleton_len: skeleton.len(),
        })
    }

    /// The whole of a serial chain skeleton: from joint 0 to the last joint.
    pub fn whole(skeleton: &Skeleton) -> Result<Self, SkeletonError> {
        Self::new(skeleton, 0, skeleton.len() - 1)
    }

    /// The joints from base to effector, inclusive.
    #[must_use]
    pub fn joints(&self) -> &[usize] {
        &self.joints
    }

    /// The base joint.
    #[must_use]
    pub fn base(&self) -> usize {
        self.joints[0]
    }

    /// The effector joint.
    #[must_use]
    pub fn effector(&self) -> usize {
        self.joints[self.joints.len() - 1]
    }

    /// The number of bones (joints minus one).
    #[must_use]
    pub fn bone_count(&self) -> usize {
        self.bone_lengths.len()
    }

    /// Length of each bone, base outwards: `bone_lengths()[c]` joins `joints()[c]` and
    /// `joints()[c + 1]`.
    #[must_use]
    pub fn bone_lengths(&self) -> &[f64] {
        &self.bone_lengths
    }

    /// The sum of the bone lengths: the farthest the effector can be from the base.
    #[must_use]
    pub fn reach(&self) -> f64 {
        self.reach
    }

    /// Checks that this chain was built for a skeleton of `skeleton`'s size.
    pub fn check_skeleton(&self, skeleton: &Skeleton) -> Result<(), IkError> {
        if self.skeleton_len == skeleton.len() {
            Ok(())
        } else {
            Err(IkError::ChainMismatch {
                chain_joints: self.skeleton_len,
                skeleton_joints: skeleton.len(),
            })
        }
    }
}

/// How far a solver may go.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct SolveSettings {
    /// The most iterations (sweeps or passes) a solve may use. The lab uses 100.
    pub max_iterations: usize,
    /// Stop once the effector is this close to the target (absolute, scene units).
    pub tolerance: f64,
}

impl Default for SolveSettings {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            tolerance: 1e-6,
        }
    }
}

impl SolveSettings {
    /// Checks the tolerance is finite and not negative.
    pub fn validate(&self) -> Result<(), IkError> {
        if self.tolerance.is_finite() && self.tolerance >= 0.0 {
            Ok(())
        } else {
            Err(IkError::InvalidSettings(format!(
                "tolerance must be finite and >= 0, got {}",
                self.tolerance
            )))
        }
    }
}

/// Why a solve stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum StopReason {
    /// The effector is within the tolerance of the target (possibly after 0 iterations).
    Converged,
    /// The iteration cap was reached first.
    IterationCap,
    /// An iteration no longer reduced the error.
    Stalled,
    /// The target is at or beyond the chain's reach: solved in closed form by the
    /// straight chain aimed at it (0 iterations).
    OutOfReach,
}

impl StopReason {
    /// A short lower-case name for tables and metrics.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Converged => "converged",
            Self::IterationCap => "iteration_cap",
            Self::Stalled => "stalled",
            Self::OutOfReach => "out_of_reach",
        }
    }
}

impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// What a solve reached.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct SolveReport {
    /// Iterations used (sweeps for CCD, backward-forward passes for FABRIK, plus any
    /// refinement steps the solver documents).
    pub iterations: usize,
    /// Effector-to-target distance before the solve.
    pub initial_error: f64,
    /// Effector-to-target distance after the solve.
    pub error: f64,
    /// Why the solve stopped.
    pub stop: StopReason,
}

/// Why a solve was refused.
#[derive(Clone, Debug, PartialEq)]
pub enum IkError {
    /// The skeleton, pose or chain is invalid.
    Skeleton(SkeletonError),
    /// The target has a NaN or infinite component.
    NonFiniteTarget {
        /// The target given.
        target: DVec3,
    },
    /// The settings are invalid; the message says which field and why.
    InvalidSettings(String),
    /// The chain was built for a skeleton of another size.
    ChainMismatch {
        /// Joints of the skeleton the chain was built for.
        chain_joints: usize,
        /// Joints of the skeleton passed to the solve.
        skeleton_joints: usize,
    },
}

impl fmt::Display for IkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Skeleton(e) => e.fmt(f),
            Self::NonFiniteTarget { target } => {
                write!(f, "target {target} has a NaN or infinite component")
            }
            Self::InvalidSettings(msg) => write!(f, "invalid solve settings: {msg}"),
            Self::ChainMismatch {
                chain_joints,
                skeleton_joints,
            } => write!(
                f,
                "the chain was built for a skeleton of {chain_joints} joints, not this one of {skeleton_joints}"
            ),
        }
    }
}

impl std::error::Error for IkError {}

impl From<SkeletonError> for IkError {
    fn from(e: SkeletonError) -> Self {
        Self::Skeleton(e)
    }
}

/// An inverse-kinematics solver: moves a chain's effector onto a target by changing the
/// local rotations of the chain's joints (every joint of the chain but the effector).
///
/// Contract for implementors:
/// - call [`begin_solve`] first, and return its report when it has one;
/// - on `Ok`, `pose` holds the solution and `global` holds forward kinematics of it;
/// - bone lengths are kept (only rotations change), nothing outside the chain's
///   subtrees changes, and no NaN is produced for any finite input;
/// - no allocation once the solver's buffers have grown to the chain's size.
pub trait IkSolver {
    /// A short name for reports ("ccd", "fabrik").
    fn name(&self) -> &'static str;

    /// Solves for `target`, starting from `pose` (warm start).
    fn solve(
        &mut self,
        skeleton: &Skeleton,
        chain: &Chain,
        pose: &mut Pose,
        global: &mut GlobalPose,
        target: DVec3,
        settings: &SolveSettings,
    ) -> Result<SolveReport, IkError>;
}

/// The outcome of [`begin_solve`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SolveStart {
    /// Nothing left to iterate: the report is final (within tolerance already, or out
    /// of reach and solved in closed form).
    Done(SolveReport),
    /// The solver should iterate, starting from this effector-to-target distance.
    Iterate {
        /// Effector-to-target distance of the starting pose.
        initial_error: f64,
    },
}

/// The checks and early exits every solver makes first, in this order:
///
/// 1. Validate the settings, the target, the chain against the skeleton, and the pose
///    (forward kinematics of `pose` is computed into `global`).
/// 2. Already within tolerance: done, 0 iterations, pose untouched.
/// 3. Target at or beyond the reach: [`straighten_towards`], 0 iterations.
pub fn begin_solve(
    skeleton: &Skeleton,
    chain: &Chain,
    pose: &mut Pose,
    global: &mut GlobalPose,
    target: DVec3,
    settings: &SolveSettings,
) -> Result<SolveStart, IkError> {
    settings.validate()?;
    if !target.is_finite() {
        return Err(IkError::NonFiniteTarget { target });
    }
    chain.check_skeleton(skeleton)?;
    skeleton.forward_kinematics(pose, global)?;
    let initial_error = global.positions[chain.effector()].distance(target);
    if initial_error <= settings.tolerance {
        return Ok(SolveStart::Done(SolveReport {
            iterations: 0,
            initial_error,
            error: initial_error,
            stop: StopReason::Converged,
        }));
    }
    if global.positions[chain.base()].distance(target) >= chain.reach() {
        straighten_towards(skeleton, chain, pose, global, target)?;
        let error = global.positions[chain.effector()].distance(target);
        return Ok(SolveStart::Done(SolveReport {
            iterations: 0,
            initial_error,
            error,
            stop: StopReason::OutOfReach,
        }));
    }
    Ok(SolveStart::Iterate { initial_error })
}

/// The closed-form answer for a target out of reach: every bone of the chain aimed
/// along the direction from the base to `target`, so the effector lands at distance
/// `|target - base| - reach` from the target, the least possible.
///
/// Each joint turns by the minimal rotation from its bone's current direction, so twist
/// is kept. Zero-length bones are left as they are; if the target is on the base there is
/// no direction and the pose is unchanged. `global` must hold forward kinematics of
/// `pose` on entry and holds it again on return. O(joints after the base).
pub fn straighten_towards(
    skeleton: &Skeleton,
    chain: &Chain,
    pose: &mut Pose,
    global: &mut GlobalPose,
    target: DVec3,
) -> Result<(), SkeletonError> {
    let base = chain.base();
    let Some(direction) = try_unit(target - global.positions[base]) else {
        return Ok(());
    };
    let joints = chain.joints();
    for c in 0..chain.bone_count() {
        let (j, k) = (joints[c], joints[c + 1]);
        let bone = global.rotations[j] * skeleton.offset(k);
        if bone == DVec3::ZERO {
            // Nothing to aim, but the next joint's global rotation must still follow
            // this joint's (possibly turned) one, or a later bone is aimed from a stale
            // frame.
            global.rotations[k] = (global.rotations[j] * pose.rotations[k]).normalize();
            global.positions[k] = global.positions[j];
            continue;
        }
        let turned = (rotation_between(bone, direction) * global.rotations[j]).normalize();
        pose.rotations[j] = match skeleton.parent(j) {
            Some(p) => (global.rotations[p].conjugate() * turned).normalize(),
            None => turned,
        };
        // Update only what the rest of the loop reads: this joint and the next one.
        global.rotations[j] = turned;
        global.rotations[k] = (turned * pose.rotations[k]).normalize();
        global.positions[k] = global.positions[j] + turned * skeleton.offset(k);
    }
    // One pass for everything else hanging off the chain (and exact FK of the result).
    skeleton.forward_kinematics_from(pose, base, global)
}

/// The largest rotation angle (radians) between corresponding local rotations of two
/// poses of the same skeleton, over the given joints: how far a pose jumped.
#[must_use]
pub fn largest_rotation_change(before: &Pose, after: &Pose, joints: &[usize]) -> f64 {
    joints
        .iter()
        .map(|&j| rotation_angle(before.rotations[j], after.rotations[j]))
        .fold(0.0, f64::max)
}

/// The angle (radians, in `[0, pi]`) of the rotation taking `a` to `b`, accurate for
/// tiny angles (atan2, not acos).
#[must_use]
pub fn rotation_angle(a: DQuat, b: DQuat) -> f64 {
    let d = a.normalize().conjugate() * b.normalize();
    2.0 * d.xyz().length().atan2(d.w.abs())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::JointDef;
    use sinew_math::{EulerRot, angle_between};

    fn lab_chain() -> Skeleton {
        Skeleton::chain(DVec3::new(0.0, 0.5, 0.0), &[DVec3::new(0.15, 0.0, 0.0); 7]).unwrap()
    }

    #[test]
    fn chain_inside_a_tree() {
        let skel = Skeleton::new([
            JointDef {
                name: None,
                parent: None,
                offset: DVec3::ZERO,
            },
            JointDef {
                name: None,
                parent: Some(0),
                offset: DVec3::X,
            },
            JointDef {
                name: Some("arm".into()),
                parent: Some(0),
                offset: DVec3::Y * 2.0,
            },
            JointDef {
                name: None,
                parent: Some(2),
                offset: DVec3::Z * 3.0,
            },
        ])
        .unwrap();
        let chain = Chain::new(&skel, 0, 3).unwrap();
        assert_eq!(chain.joints(), &[0, 2, 3]);
        assert_eq!(chain.bone_lengths(), &[2.0, 3.0]);
        assert_eq!(chain.reach(), 5.0);
        let err = Chain::new(&skel, 1, 3).unwrap_err();
        assert!(
            err.to_string()
                .contains("joint 1 is not an ancestor of joint 3"),
            "{err}"
        );
        assert!(Chain::new(&skel, 0, 9).is_err());
        let single = Chain::new(&skel, 2, 2).unwrap();
        assert_eq!((single.bone_count(), single.reach()), (0, 0.0));
    }

    #[test]
    fn out_of_reach_gives_the_straight_chain() {
        let skel = lab_chain();
        let chain = Chain::whole(&skel).unwrap();
        // A bent starting pose.
        let mut pose = skel.rest_pose();
        for (i, r) in pose.rotations.iter_mut().enumerate() {
            *r = DQuat::from_euler(EulerRot::XYZ, 0.3 * i as f64, -0.2, 0.1 * i as f64);
        }
        let mut global = GlobalPose::new();
        let target = DVec3::new(3.0, 1.0, -0.5);
        let start = begin_solve(
            &skel,
            &chain,
            &mut pose,
            &mut global,
            target,
            &SolveSettings::default(),
        )
        .unwrap();
        let SolveStart::Done(report) = start else {
            panic!("expected closed form")
        };
        assert_eq!(report.stop, StopReason::OutOfReach);
        assert_eq!(report.iterations, 0);
        let base = global.positions[0];
        let expected_error = (target - base).length() - chain.reach();
        assert!(
            (report.error - expected_error).abs() < 1e-14,
            "{} vs {expected_error}",
            report.error
        );
        // Straight: consecutive bones parallel, all pointing at the target.
        let dir = (target - base).normalize();
        for i in 1..skel.len() {
            let bone = global.positions[i] - global.positions[i - 1];
            assert!(angle_between(bone, dir) < 1e-14);
            assert!((bone.length() - 0.15).abs() < 1e-15);
        }
        // global is FK of pose.
        let mut fresh = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut fresh).unwrap();
        assert_eq!(fresh, global);
    }

    #[test]
    fn straight_chain_through_consecutive_zero_length_bones() {
        // The property suite's minimal failing case: before the fix, the bone after two
        // zero-length bones kept its stale direction and the effector ended at (-1, 1, 0).
        let skel =
            Skeleton::chain(DVec3::ZERO, &[DVec3::X, DVec3::ZERO, DVec3::ZERO, DVec3::X]).unwrap();
        let chain = Chain::whole(&skel).unwrap();
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        let target = DVec3::new(0.0, 10.0, 0.0);
        let start = begin_solve(
            &skel,
            &chain,
            &mut pose,
            &mut global,
            target,
            &SolveSettings::default(),
        )
        .unwrap();
        let SolveStart::Done(report) = start else {
            panic!("expected closed form")
        };
        assert_eq!(report.stop, StopReason::OutOfReach);
        assert!(
            (global.positions[4] - DVec3::new(0.0, 2.0, 0.0)).length() < 1e-15,
            "{}",
            global.positions[4]
        );
        assert!((report.error - 8.0).abs() < 1e-14);
    }

    #[test]
    fn within_tolerance_is_untouched() {
        let skel = lab_chain();
        let chain = Chain::whole(&skel).unwrap();
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        let target = DVec3::new(1.05 + 1e-7, 0.5, 0.0);
        let before = pose.clone();
        let start = begin_solve(
            &skel,
            &chain,
            &mut pose,
            &mut global,
            target,
            &SolveSettings::default(),
        )
        .unwrap();
        assert!(matches!(
            start,
            SolveStart::Done(SolveReport {
                iterations: 0,
                stop: StopReason::Converged,
                ..
            })
        ));
        assert_eq!(pose, before);
    }

    #[test]
    fn bad_targets_and_settings_are_errors() {
        let skel = lab_chain();
        let chain = Chain::whole(&skel).unwrap();
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        let nan = DVec3::new(f64::NAN, 0.0, 0.0);
        assert!(matches!(
            begin_solve(
                &skel,
                &chain,
                &mut pose,
                &mut global,
                nan,
                &SolveSettings::default()
            ),
            Err(IkError::NonFiniteTarget { .. })
        ));
        let bad = SolveSettings {
            tolerance: -1.0,
            ..Default::default()
        };
        let err = begin_solve(&skel, &chain, &mut pose, &mut global, DVec3::X, &bad).unwrap_err();
        assert!(err.to_string().contains("tolerance"));
        let other = Skeleton::chain(DVec3::ZERO, &[DVec3::X]).unwrap();
        assert!(matches!(
            begin_solve(
                &other,
                &chain,
                &mut other.rest_pose(),
                &mut global,
                DVec3::X,
                &SolveSettings::default()
            ),
            Err(IkError::ChainMismatch { .. })
        ));
    }

    #[test]
    fn rotation_angle_is_accurate_and_sign_blind() {
        let tiny = DQuat::from_rotation_y(1e-10);
        assert!((rotation_angle(DQuat::IDENTITY, tiny) - 1e-10).abs() < 1e-25);
        let a = DQuat::from_rotation_y(0.3);
        let b = DQuat::from_rotation_y(0.3 + 1e-6);
        assert!((rotation_angle(a, b) - 1e-6).abs() < 1e-15);
        assert!((rotation_angle(a, a * DQuat::from_rotation_x(3.0)) - 3.0).abs() < 1e-14);
        assert!(rotation_angle(a, -a) < 1e-15);
    }
}
