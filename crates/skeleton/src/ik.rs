//! The inverse-kinematics vocabulary both solver crates share, written once here.
//!
//! IK is a *job*, in the manner of ozz-animation's jobs: named inputs, a validation, and
//! named outputs, so a new input is a new field, not a new argument in every signature.
//!
//! - [`IkProblem`]: the inputs: the skeleton, the [`Chain`], the goals
//!   ([`EffectorGoal`]: a position, optionally a rotation, weights and a pole, per
//!   effector) and the [`SolveSettings`]. [`IkProblem::validate`] names the offending
//!   goal, field or joint.
//! - [`IkState`]: what a solve updates, the pose and its forward kinematics.
//! - [`SolveReport`]: the outputs: iterations used, position and rotation error before
//!   and after, the largest joint-limit violation of the returned pose, whether a second
//!   seed pose was tried, and the [`StopReason`].
//! - [`Chain`]: the path from a base joint to an effector joint inside a skeleton, with
//!   its bone lengths and reach.
//! - [`straighten_towards`]: the closed-form answer for a target out of reach (every
//!   bone aimed at the target, the lab's Q1).
//! - [`begin_solve`] and [`measure`]: the checks and early exits every solver makes first
//!   (bad input, already within tolerance, out of reach), and the errors every report
//!   carries, computed the same way everywhere.
//! - [`IkSolver`]: the trait the solvers implement, so the scene runner and the
//!   property suite can run any solver alike.
//!
//! Tolerances are absolute: distances in scene units between the effector and its goal
//! position, and angles in radians between the effector's global rotation and its goal
//! rotation.

use crate::limits::JointLimit;
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
    /// The skeleton's [`Skeleton::fingerprint`]: a skeleton of the same size but other
    /// parents or offsets would give other joints or bone lengths, so it is refused too.
    skeleton_fingerprint: u64,
}

impl Chain {
    /// The chain from `base` to `effector` in `skeleton`. An error when either index is
    /// out of range, `base` is not an ancestor of `effector`, or the bone lengths do not
    /// have a finite sum.
    ///
    /// ```
    /// use sinew_skeleton::{DVec3, Skeleton};
    /// use sinew_skeleton::ik::Chain;
    /// // Seven bones of 1e200: the skeleton is within `MAX_REACH`, but a bone length's
    /// // square overflows, so the chain solvers could not measure it.
    /// let huge = Skeleton::chain(DVec3::ZERO, &[DVec3::X * 1e200; 7]).unwrap();
    /// let err = Chain::whole(&huge).unwrap_err();
    /// assert!(err.to_string().starts_with("joint 7: the chain's bone lengths sum to inf"));
    /// ```
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
            // The error's labels are formatted only if it happens (a formatted label per
            // joint was most of the cost of building a chain).
            j = skeleton
                .parent(j)
                .ok_or_else(|| SkeletonError::NotAnAncestor {
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
        let reach: f64 = bone_lengths.iter().sum();
        // Bones of 1e160 and more have an infinite length here (its square overflows): the
        // solvers square lengths and distances, so such a chain is refused. (The skeleton's
        // own bound, `MAX_REACH`, keeps the lengths' sum finite.)
        if !reach.is_finite() {
            return Err(SkeletonError::ChainTooLong {
                effector: skeleton.label(effector),
                reach,
            });
        }
        Ok(Self {
            joints,
            bone_lengths,
            reach,
            skeleton_len: skeleton.len(),
            skeleton_fingerprint: skeleton.fingerprint(),
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

    /// Checks that this chain was built for `skeleton`, or for one with the same parents
    /// and offsets (limits and names may differ: the chain depends on neither).
    ///
    /// ```
    /// use sinew_skeleton::DVec3;
    /// use sinew_skeleton::Skeleton;
    /// use sinew_skeleton::ik::Chain;
    /// let arm = Skeleton::chain(DVec3::ZERO, &[DVec3::X; 2]).unwrap();
    /// let leg = Skeleton::chain(DVec3::ZERO, &[DVec3::NEG_Y; 2]).unwrap();
    /// let chain = Chain::whole(&arm).unwrap();
    /// assert!(chain.check_skeleton(&arm).is_ok());
    /// // Same number of joints, other bones: refused.
    /// assert!(chain.check_skeleton(&leg).is_err());
    /// ```
    pub fn check_skeleton(&self, skeleton: &Skeleton) -> Result<(), IkError> {
        if self.skeleton_len == skeleton.len()
            && self.skeleton_fingerprint == skeleton.fingerprint()
        {
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
    /// Stop once the effector is this close to its goal position (absolute, scene units).
    pub tolerance: f64,
    /// With a rotation goal, stop only once the effector's global rotation is also
    /// within this angle (radians) of it. Ignored without a rotation goal.
    pub rotation_tolerance: f64,
}

impl Default for SolveSettings {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            tolerance: 1e-6,
            rotation_tolerance: 1e-6,
        }
    }
}

impl SolveSettings {
    /// Checks both tolerances are finite and not negative.
    pub fn validate(&self) -> Result<(), IkError> {
        for (name, value) in [
            ("tolerance", self.tolerance),
            ("rotation_tolerance", self.rotation_tolerance),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(IkError::InvalidSettings(format!(
                    "{name} must be finite and >= 0, got {value}"
                )));
            }
        }
        Ok(())
    }
}

/// What one effector should reach: a position, optionally a rotation and a pole.
///
/// A problem holds a slice of goals so that several effectors on one tree fit without
/// another change of shape; the solvers of this workspace solve one chain, so they take
/// exactly one goal, on the chain's effector ([`IkProblem::validate`] says so).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct EffectorGoal {
    /// The joint that should reach the goal.
    pub joint: usize,
    /// Where the joint should be (world frame).
    pub position: DVec3,
    /// The global rotation the joint should have, if any. The effector's own local
    /// rotation is not part of the chain, so it is reached by turning the chain's joints.
    #[cfg_attr(feature = "serde", serde(default))]
    pub rotation: Option<DQuat>,
    /// How much the position counts against the rotation where both cannot be met
    /// (the residual's position rows are multiplied by it). Finite and > 0; default 1.
    #[cfg_attr(feature = "serde", serde(default = "one"))]
    pub position_weight: f64,
    /// How much the rotation counts, per radian, against the position per scene unit.
    /// Finite and >= 0; default 1. Ignored without a rotation goal.
    #[cfg_attr(feature = "serde", serde(default = "one"))]
    pub rotation_weight: f64,
    /// A point the chain's bend plane should turn towards, if any (see the solvers'
    /// documentation for what it means for a chain of more than two bones).
    #[cfg_attr(feature = "serde", serde(default))]
    pub pole: Option<DVec3>,
}

#[cfg(feature = "serde")]
fn one() -> f64 {
    1.0
}

impl EffectorGoal {
    /// A position goal for `joint`, weight 1, no rotation, no pole.
    #[must_use]
    pub fn at(joint: usize, position: DVec3) -> Self {
        Self {
            joint,
            position,
            rotation: None,
            position_weight: 1.0,
            rotation_weight: 1.0,
            pole: None,
        }
    }

    /// The same goal with a rotation goal.
    #[must_use]
    pub fn with_rotation(mut self, rotation: DQuat) -> Self {
        self.rotation = Some(rotation);
        self
    }

    /// The same goal with a pole.
    #[must_use]
    pub fn with_pole(mut self, pole: DVec3) -> Self {
        self.pole = Some(pole);
        self
    }

    /// The same goal with the given position and rotation weights.
    #[must_use]
    pub fn with_weights(mut self, position_weight: f64, rotation_weight: f64) -> Self {
        self.position_weight = position_weight;
        self.rotation_weight = rotation_weight;
        self
    }

    /// Checks every field on its own (goal `index` of its problem, for messages).
    pub fn validate(&self, index: usize, skeleton: &Skeleton) -> Result<(), IkError> {
        let bad = |field: &'static str, reason: String| {
            Err(IkError::InvalidGoal {
                goal: index,
                field,
                reason,
            })
        };
        if skeleton.check_index(self.joint).is_err() {
            return bad(
                "joint",
                format!(
                    "joint index {} is out of range (the skeleton has {} joints)",
                    self.joint,
                    skeleton.len()
                ),
            );
        }
        self.validate_position_and_rotation(index)?;
        if !(self.position_weight.is_finite() && self.position_weight > 0.0) {
            return bad(
                "position_weight",
                format!("must be finite and > 0, got {}", self.position_weight),
            );
        }
        if !(self.rotation_weight.is_finite() && self.rotation_weight >= 0.0) {
            return bad(
                "rotation_weight",
                format!("must be finite and >= 0, got {}", self.rotation_weight),
            );
        }
        self.validate_pole(index)
    }

    /// The checks of [`EffectorGoal::validate`] on the fields that move from frame to
    /// frame (the position, the rotation, the pole), in the same order and with the same
    /// errors: for a goal whose joint and weights are those of a goal `validate` accepted
    /// (an animation's next frame), the same answer as `validate`, for less.
    pub fn validate_moving(&self, index: usize) -> Result<(), IkError> {
        self.validate_position_and_rotation(index)?;
        self.validate_pole(index)
    }

    fn validate_position_and_rotation(&self, index: usize) -> Result<(), IkError> {
        let bad = |field: &'static str, reason: String| {
            Err(IkError::InvalidGoal {
                goal: index,
                field,
                reason,
            })
        };
        if !self.position.is_finite() {
            return bad(
                "position",
                format!("{} has a NaN or infinite component", self.position),
            );
        }
        if let Some(q) = self.rotation
            && !(q.is_finite() && q.length_squared() > 0.0)
        {
            return bad("rotation", format!("{q} is zero or not finite"));
        }
        Ok(())
    }

    fn validate_pole(&self, index: usize) -> Result<(), IkError> {
        if let Some(pole) = self.pole
            && !pole.is_finite()
        {
            return Err(IkError::InvalidGoal {
                goal: index,
                field: "pole",
                reason: format!("{pole} has a NaN or infinite component"),
            });
        }
        Ok(())
    }

    /// The goal's position error and rotation error (radians; 0 without a rotation goal)
    /// of the global pose `global`.
    #[must_use]
    pub fn errors(&self, global: &GlobalPose) -> (f64, f64) {
        let position = global.positions[self.joint].distance(self.position);
        let rotation = self
            .rotation
            .map_or(0.0, |q| rotation_angle(global.rotations[self.joint], q));
        (position, rotation)
    }
}

/// The inputs of an IK solve: see the [module docs](self).
#[derive(Clone, Copy, Debug)]
pub struct IkProblem<'a> {
    /// The skeleton (with its joint limits).
    pub skeleton: &'a Skeleton,
    /// The chain whose joints the solve turns.
    pub chain: &'a Chain,
    /// One goal per effector. The chain solvers take exactly one, on the chain's effector.
    pub goals: &'a [EffectorGoal],
    /// Iteration cap and tolerances.
    pub settings: SolveSettings,
}

impl<'a> IkProblem<'a> {
    /// A problem from its parts (not validated: see [`IkProblem::validate`]).
    #[must_use]
    pub fn new(
        skeleton: &'a Skeleton,
        chain: &'a Chain,
        goals: &'a [EffectorGoal],
        settings: SolveSettings,
    ) -> Self {
        Self {
            skeleton,
            chain,
            goals,
            settings,
        }
    }

    /// Checks the settings, the chain against the skeleton and every goal, naming the
    /// offending goal and field. The chain solvers solve one effector, so there must be
    /// exactly one goal and it must be on the chain's effector joint.
    pub fn validate(&self) -> Result<(), IkError> {
        self.settings.validate()?;
        self.chain.check_skeleton(self.skeleton)?;
        if self.goals.len() != 1 {
            return Err(IkError::GoalCount {
                got: self.goals.len(),
            });
        }
        for (i, goal) in self.goals.iter().enumerate() {
            goal.validate(i, self.skeleton)?;
            if goal.joint != self.chain.effector() {
                return Err(IkError::InvalidGoal {
                    goal: i,
                    field: "joint",
                    reason: format!(
                        "{} is not the chain's effector, {}",
                        self.skeleton.label(goal.joint),
                        self.skeleton.label(self.chain.effector())
                    ),
                });
            }
        }
        Ok(())
    }

    /// The single goal of a chain problem. Call after [`IkProblem::validate`]; an error
    /// (not a panic) when there is no goal.
    pub fn goal(&self) -> Result<&'a EffectorGoal, IkError> {
        self.goals.first().ok_or(IkError::GoalCount { got: 0 })
    }
}

/// What a solve updates: the pose (local rotations) and its forward kinematics.
#[derive(Debug)]
pub struct IkState<'a> {
    /// The pose; on entry the starting pose (warm start), on return the solution.
    pub pose: &'a mut Pose,
    /// Forward kinematics of `pose`; any content on entry (it is recomputed), forward
    /// kinematics of the solution on return.
    pub global: &'a mut GlobalPose,
}

impl<'a> IkState<'a> {
    /// A state over a pose and a global pose.
    #[must_use]
    pub fn new(pose: &'a mut Pose, global: &'a mut GlobalPose) -> Self {
        Self { pose, global }
    }
}

/// Why a solve stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum StopReason {
    /// The effector is within the tolerance of the goal (possibly after 0 iterations).
    Converged,
    /// The iteration cap was reached first.
    IterationCap,
    /// An iteration no longer reduced the error.
    Stalled,
    /// The target is at or beyond the reach of an unconstrained chain: solved in closed
    /// form by the straight chain aimed at it (0 iterations).
    OutOfReach,
    /// The joint limits hold the chain: the error stopped decreasing at a pose where
    /// every step the solver can take leaves a limit, the best reachable within the
    /// limits that the solver found (a local minimum of the error over the allowed set).
    LocalMinimum,
}

impl StopReason {
    /// A short lower-case name for tables and metrics.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Converged => "converged",
            Self::IterationCap => "iteration_cap",
            Self::Stalled => "stalled",
            Self::OutOfReach => "out_of_reach",
            Self::LocalMinimum => "local_minimum",
        }
    }
}

impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// What a solve reached.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct SolveReport {
    /// Iterations used (sweeps for CCD, backward-forward passes for FABRIK, plus any
    /// refinement steps the solver documents).
    pub iterations: usize,
    /// Effector-to-goal distance before the solve.
    pub initial_error: f64,
    /// Effector-to-goal distance after the solve.
    pub error: f64,
    /// Angle (radians) between the effector's global rotation and the goal rotation
    /// before the solve; 0 without a rotation goal.
    pub initial_rotation_error: f64,
    /// The same angle after the solve; 0 without a rotation goal.
    pub rotation_error: f64,
    /// The largest joint-limit violation (radians) of the returned pose over the
    /// chain's joints; 0 for a chain without limits.
    pub limit_violation: f64,
    /// Whether the solver restarted from a second seed pose after a local minimum.
    pub restarted: bool,
    /// Why the solve stopped.
    pub stop: StopReason,
}

impl SolveReport {
    /// Whether the solve met both tolerances of `settings`.
    #[must_use]
    pub fn within(&self, settings: &SolveSettings) -> bool {
        self.error <= settings.tolerance && self.rotation_error <= settings.rotation_tolerance
    }
}

/// Why a solve was refused.
#[derive(Clone, Debug, PartialEq)]
pub enum IkError {
    /// The skeleton, pose or chain is invalid.
    Skeleton(SkeletonError),
    /// A raw step's target has a NaN or infinite component.
    NonFiniteTarget {
        /// The target given.
        target: DVec3,
    },
    /// A goal is invalid: which goal, which field, and why.
    InvalidGoal {
        /// The goal's index in the problem.
        goal: usize,
        /// The offending field.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// The chain solvers solve exactly one goal.
    GoalCount {
        /// The number of goals given.
        got: usize,
    },
    /// The settings are invalid; the message says which field and why.
    InvalidSettings(String),
    /// The chain was built for another skeleton: one of another size, or of the same
    /// size with other parents or offsets.
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
            Self::InvalidGoal {
                goal,
                field,
                reason,
            } => write!(f, "goal {goal}: {field}: {reason}"),
            Self::GoalCount { got } => write!(
                f,
                "a chain solve takes exactly one goal, on the chain's effector; got {got}"
            ),
            Self::InvalidSettings(msg) => write!(f, "invalid solve settings: {msg}"),
            Self::ChainMismatch {
                chain_joints,
                skeleton_joints,
            } if chain_joints == skeleton_joints => write!(
                f,
                "the chain was built for another skeleton of {chain_joints} joints, with other parents or offsets than this one"
            ),
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

/// An inverse-kinematics solver: moves a chain's effector onto its goal by changing the
/// local rotations of the chain's joints (every joint of the chain but the effector).
///
/// Contract for implementors:
/// - call [`begin_solve`] first, and return its report when it has one;
/// - on `Ok`, `state.pose` holds the solution and `state.global` forward kinematics of
///   it, and the report's errors are those of `state.global` ([`measure`]);
/// - bone lengths are kept (only rotations change), nothing outside the chain's
///   subtrees changes, and no NaN is produced for any finite input;
/// - no allocation once the solver's buffers have grown to the chain's size.
pub trait IkSolver {
    /// A short name for reports ("ccd", "fabrik").
    fn name(&self) -> &'static str;

    /// Solves `problem`, starting from `state.pose` (warm start).
    fn solve(
        &mut self,
        problem: &IkProblem<'_>,
        state: &mut IkState<'_>,
    ) -> Result<SolveReport, IkError>;

    /// The common case as one call: the job with a single position goal on the chain's
    /// effector, weight 1, no rotation and no pole.
    fn solve_position(
        &mut self,
        skeleton: &Skeleton,
        chain: &Chain,
        pose: &mut Pose,
        global: &mut GlobalPose,
        target: DVec3,
        settings: &SolveSettings,
    ) -> Result<SolveReport, IkError> {
        let goals = [EffectorGoal::at(chain.effector(), target)];
        let problem = IkProblem::new(skeleton, chain, &goals, *settings);
        self.solve(&problem, &mut IkState::new(pose, global))
    }
}

/// The outcome of [`begin_solve`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SolveStart {
    /// Nothing left to iterate: the report is final (within tolerance already, or out
    /// of reach and solved in closed form).
    Done(SolveReport),
    /// The solver should iterate, starting from these errors.
    Iterate {
        /// Effector-to-goal distance of the starting pose.
        initial_error: f64,
        /// Rotation error (radians) of the starting pose; 0 without a rotation goal.
        initial_rotation_error: f64,
    },
}

/// The report of a finished solve, measured on `state.global` (which must hold forward
/// kinematics of `state.pose`): the goal's errors and the limit violation of the chain.
#[must_use]
pub fn measure(
    problem: &IkProblem<'_>,
    state: &IkState<'_>,
    goal: &EffectorGoal,
    iterations: usize,
    initial: (f64, f64),
    stop: StopReason,
) -> SolveReport {
    let (error, rotation_error) = goal.errors(state.global);
    SolveReport {
        iterations,
        initial_error: initial.0,
        error,
        initial_rotation_error: initial.1,
        rotation_error,
        limit_violation: chain_limit_violation(problem.skeleton, problem.chain, state.pose),
        restarted: false,
        stop,
    }
}

/// The largest joint-limit violation (radians) of `pose` over the chain's movable
/// joints (every chain joint but the effector, whose rotation the chain solvers do not
/// change); 0 for a chain without limits.
#[must_use]
pub fn chain_limit_violation(skeleton: &Skeleton, chain: &Chain, pose: &Pose) -> f64 {
    chain.joints()[..chain.bone_count()]
        .iter()
        .map(|&j| skeleton.prepared_limit(j).violation(pose.rotations[j]))
        .fold(0.0, f64::max)
}

/// Whether any movable joint of the chain has a joint limit (anything but free).
#[must_use]
pub fn chain_has_limits(skeleton: &Skeleton, chain: &Chain) -> bool {
    chain.joints()[..chain.bone_count()]
        .iter()
        .any(|&j| !matches!(skeleton.limit(j), JointLimit::Free))
}

/// Projects the local rotation of every movable joint of the chain onto its limit
/// ([`JointLimit::project`]); returns whether any joint moved. Forward kinematics is
/// the caller's.
pub fn project_onto_limits(skeleton: &Skeleton, chain: &Chain, pose: &mut Pose) -> bool {
    let mut moved = false;
    for &j in &chain.joints()[..chain.bone_count()] {
        let limit = skeleton.prepared_limit(j);
        if matches!(limit.limit(), JointLimit::Free) {
            continue;
        }
        let projected = limit.project(pose.rotations[j]);
        moved |= projected != pose.rotations[j];
        pose.rotations[j] = projected;
    }
    moved
}

/// The checks and early exits every solver makes first, in this order:
///
/// 1. [`IkProblem::validate`], then forward kinematics of the pose into the state's
///    global pose (which checks the pose). A goal whose distance from the chain's base
///    or effector overflows f64 (a coordinate beyond about 1e154) is refused with
///    [`IkError::InvalidGoal`]: no error could be reported for it. A chain with limits
///    has its starting pose projected onto them ([`project_onto_limits`]), so every
///    solve returns a pose inside the limits.
/// 2. Already within both tolerances: done, 0 iterations, pose untouched.
/// 3. Goal position at or beyond the reach of a chain without joint limits:
///    [`straighten_towards`], 0 iterations (the straight chain is the only pose that
///    minimizes the distance, so a rotation goal cannot change it). A chain with limits
///    is never straightened through them: it iterates.
pub fn begin_solve(
    problem: &IkProblem<'_>,
    state: &mut IkState<'_>,
) -> Result<SolveStart, IkError> {
    problem.validate()?;
    let goal = problem.goal()?;
    let (skeleton, chain, settings) = (problem.skeleton, problem.chain, &problem.settings);
    // The forward kinematics below checks the pose before anything reads it.
    skeleton.forward_kinematics(state.pose, state.global)?;
    let initial = goal.errors(state.global);
    let distance = state.global.positions[chain.base()].distance(goal.position);
    if !(distance.is_finite() && initial.0.is_finite()) {
        // A finite target can still be too far to measure: a coordinate of 1e300 has a
        // distance whose square overflows f64. No solve could report a finite error, so
        // the goal is refused rather than answered with an infinite one.
        return Err(IkError::InvalidGoal {
            goal: 0,
            field: "position",
            reason: format!(
                "{} is too far from the chain to measure: its distance from the chain's \
                 base or effector overflows f64",
                goal.position
            ),
        });
    }
    if chain_has_limits(skeleton, chain) && project_onto_limits(skeleton, chain, state.pose) {
        // A solve returns a pose inside the limits even when it starts outside them;
        // the initial errors stay those of the pose given.
        skeleton.forward_kinematics_from(state.pose, chain.base(), state.global)?;
    }
    let now = goal.errors(state.global);
    if now.0 <= settings.tolerance && now.1 <= settings.rotation_tolerance {
        return Ok(SolveStart::Done(measure(
            problem,
            state,
            goal,
            0,
            initial,
            StopReason::Converged,
        )));
    }
    if distance >= chain.reach() && !chain_has_limits(skeleton, chain) {
        // No pose comes closer than `distance - reach`. A pose already there to
        // round-off (straight, pointing at the goal) could come out of the closed form a
        // few ulps further away, so it is kept when it is at least as close. Only then is
        // the chain's pose copied, so a solve far from the floor allocates nothing.
        let floor = distance - chain.reach();
        let near_floor =
            now.0 <= floor + 16.0 * f64::EPSILON * (chain.bone_count() as f64 + 1.0) * distance;
        let saved: Option<Vec<DQuat>> = near_floor.then(|| {
            chain
                .joints()
                .iter()
                .map(|&j| state.pose.rotations[j])
                .collect()
        });
        straighten_towards(skeleton, chain, state.pose, state.global, goal.position)?;
        if let Some(saved) = saved
            && state.global.positions[chain.effector()].distance(goal.position) > now.0
        {
            for (&j, &r) in chain.joints().iter().zip(&saved) {
                state.pose.rotations[j] = r;
            }
            skeleton.forward_kinematics_from(state.pose, chain.base(), state.global)?;
        }
        return Ok(SolveStart::Done(measure(
            problem,
            state,
            goal,
            0,
            initial,
            StopReason::OutOfReach,
        )));
    }
    Ok(SolveStart::Iterate {
        initial_error: initial.0,
        initial_rotation_error: initial.1,
    })
}

/// The pole goal: turns the whole chain rigidly about the line from its base to its
/// effector so that its bend plane faces the goal's pole; returns whether it turned.
///
/// The bend plane is the plane through that line and the chain's bend direction, the sum
/// of the interior joints' offsets from the line (perpendicular to it). For two bones
/// it is the plane of the three joints, the usual meaning; for more bones it is the
/// plane the chain bulges into on average, and the turn makes that bulge point at the
/// pole (seen along the line). The effector lies on the axis, so it does not move (to
/// round-off); only the base joint's local rotation changes.
///
/// Nothing happens without a pole, with a rotation goal (the turn would move the
/// effector's frame), for fewer than two bones, for a straight chain or a pole on the
/// line (no plane, no direction), or when the turned pose would leave a joint limit or
/// lose the position the solve reached (then the turn is undone). `state.global` must
/// hold forward kinematics of `state.pose`, and does again on return.
pub fn turn_towards_pole(
    problem: &IkProblem<'_>,
    state: &mut IkState<'_>,
) -> Result<bool, IkError> {
    let goal = problem.goal()?;
    let (skeleton, chain) = (problem.skeleton, problem.chain);
    let Some(pole) = goal.pole else {
        return Ok(false);
    };
    if goal.rotation.is_some() || chain.bone_count() < 2 {
        return Ok(false);
    }
    let joints = chain.joints();
    let base = state.global.positions[chain.base()];
    let Some(axis) = try_unit(state.global.positions[chain.effector()] - base) else {
        return Ok(false);
    };
    let across = |v: DVec3| v - axis * axis.dot(v);
    let bend: DVec3 = joints[1..joints.len() - 1]
        .iter()
        .map(|&j| across(state.global.positions[j] - base))
        .sum();
    let (Some(from), Some(to)) = (try_unit(bend), try_unit(across(pole - base))) else {
        return Ok(false);
    };
    let angle = from.cross(to).dot(axis).atan2(from.dot(to));
    if angle == 0.0 {
        return Ok(false);
    }
    let (error_before, _) = goal.errors(state.global);
    let b = chain.base();
    let kept = state.pose.rotations[b];
    let turned = (DQuat::from_axis_angle(axis, angle) * state.global.rotations[b]).normalize();
    state.pose.rotations[b] = match skeleton.parent(b) {
        Some(p) => (state.global.rotations[p].conjugate() * turned).normalize(),
        None => turned,
    };
    skeleton.forward_kinematics_from(state.pose, b, state.global)?;
    let (error, _) = goal.errors(state.global);
    let inside = skeleton
        .prepared_limit(b)
        .violation(state.pose.rotations[b])
        == 0.0;
    if inside && (error <= problem.settings.tolerance || error <= error_before) {
        return Ok(true);
    }
    state.pose.rotations[b] = kept;
    skeleton.forward_kinematics_from(state.pose, b, state.global)?;
    Ok(false)
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

    /// The job with one position goal on the chain's effector.
    fn start(
        skeleton: &Skeleton,
        chain: &Chain,
        pose: &mut Pose,
        global: &mut GlobalPose,
        target: DVec3,
        settings: &SolveSettings,
    ) -> Result<SolveStart, IkError> {
        let goals = [EffectorGoal::at(chain.effector(), target)];
        let problem = IkProblem::new(skeleton, chain, &goals, *settings);
        begin_solve(&problem, &mut IkState::new(pose, global))
    }

    /// [`start`] with the default settings where the job is settled before any iteration
    /// (out of reach or already within the tolerance): its report.
    fn done_at_start(
        skeleton: &Skeleton,
        chain: &Chain,
        pose: &mut Pose,
        global: &mut GlobalPose,
        target: DVec3,
    ) -> SolveReport {
        let settings = SolveSettings::default();
        let start = start(skeleton, chain, pose, global, target, &settings).unwrap();
        let SolveStart::Done(report) = start else {
            panic!("expected done at the start: {start:?}")
        };
        report
    }

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
                ..JointDef::default()
            },
            JointDef {
                name: None,
                parent: Some(0),
                offset: DVec3::X,
                ..JointDef::default()
            },
            JointDef {
                name: Some("arm".into()),
                parent: Some(0),
                offset: DVec3::Y * 2.0,
                ..JointDef::default()
            },
            JointDef {
                name: None,
                parent: Some(2),
                offset: DVec3::Z * 3.0,
                ..JointDef::default()
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
    fn an_already_straight_chain_out_of_reach_is_never_moved_further_away() {
        // Chains with uneven and zero-length bones, straightened towards far targets, then
        // asked again: each pose is already the closed-form answer to round-off, and the
        // second answer may not be further away than the pose given.
        let offsets = [
            DVec3::new(0.3, 0.0, 0.0),
            DVec3::ZERO,
            DVec3::new(0.0, 0.7, 0.1),
            DVec3::new(0.011, 0.0, -0.2),
            DVec3::ZERO,
            DVec3::new(1.3, 0.2, 0.0),
        ];
        let skel = Skeleton::chain(DVec3::new(0.1, -0.4, 0.25), &offsets).unwrap();
        let chain = Chain::whole(&skel).unwrap();
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        let mut uniform = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for _ in 0..2000 {
            let direction = DVec3::new(uniform(), uniform(), uniform());
            let target = direction.normalize() * (4.0 + 10.0 * uniform().abs());
            for _ in 0..2 {
                let report = done_at_start(&skel, &chain, &mut pose, &mut global, target);
                assert_eq!(report.stop, StopReason::OutOfReach);
                assert!(
                    report.error <= report.initial_error,
                    "{:e} > {:e}",
                    report.error,
                    report.initial_error
                );
            }
        }
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
        let report = done_at_start(&skel, &chain, &mut pose, &mut global, target);
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
        let report = done_at_start(&skel, &chain, &mut pose, &mut global, target);
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
        let report = done_at_start(&skel, &chain, &mut pose, &mut global, target);
        assert_eq!((report.iterations, report.stop), (0, StopReason::Converged));
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
            start(
                &skel,
                &chain,
                &mut pose,
                &mut global,
                nan,
                &SolveSettings::default()
            ),
            Err(IkError::InvalidGoal {
                goal: 0,
                field: "position",
                ..
            })
        ));
        let bad = SolveSettings {
            tolerance: -1.0,
            ..Default::default()
        };
        let err = start(&skel, &chain, &mut pose, &mut global, DVec3::X, &bad).unwrap_err();
        assert!(err.to_string().contains("tolerance"));
        let other = Skeleton::chain(DVec3::ZERO, &[DVec3::X]).unwrap();
        assert!(matches!(
            start(
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
    fn a_chain_refuses_another_skeleton_of_the_same_size() {
        let arm = Skeleton::chain(DVec3::ZERO, &[DVec3::X; 3]).unwrap();
        let chain = Chain::whole(&arm).unwrap();
        // Same size, one offset differs: the chain's bone lengths would be wrong.
        let longer = Skeleton::chain(DVec3::ZERO, &[DVec3::X, DVec3::X, DVec3::X * 2.0]).unwrap();
        // Same size and offsets, other parents: a tree, not a chain.
        let tree = Skeleton::new([
            crate::JointDef::root(DVec3::ZERO),
            crate::JointDef::child(0, DVec3::X),
            crate::JointDef::child(0, DVec3::X),
            crate::JointDef::child(2, DVec3::X),
        ])
        .unwrap();
        for other in [&longer, &tree] {
            let err = chain.check_skeleton(other).unwrap_err();
            assert_eq!(
                err,
                IkError::ChainMismatch {
                    chain_joints: 4,
                    skeleton_joints: 4
                }
            );
            assert!(err.to_string().contains("other parents or offsets"));
        }
        // A copy, or the same structure with limits and names added, is accepted.
        assert!(chain.check_skeleton(&arm.clone()).is_ok());
        let mut limited = Skeleton::new([
            crate::JointDef::root(DVec3::ZERO).named("base"),
            crate::JointDef::child(0, DVec3::X),
            crate::JointDef::child(1, DVec3::X),
            crate::JointDef::child(2, DVec3::X).named("tip"),
        ])
        .unwrap();
        limited
            .set_limit(1, JointLimit::hinge(DVec3::Z, -1.0, 1.0).unwrap())
            .unwrap();
        assert!(chain.check_skeleton(&limited).is_ok());
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

    #[test]
    fn validate_names_the_goal_and_the_field() {
        let skel = lab_chain();
        let chain = Chain::whole(&skel).unwrap();
        let settings = SolveSettings::default();
        let ok = EffectorGoal::at(7, DVec3::new(0.3, 0.2, 0.1));
        let check = |goals: &[EffectorGoal]| {
            IkProblem::new(&skel, &chain, goals, settings)
                .validate()
                .map_err(|e| e.to_string())
        };
        assert_eq!(check(&[ok]), Ok(()));
        let with_all = ok
            .with_rotation(DQuat::from_rotation_y(0.5))
            .with_pole(DVec3::Z)
            .with_weights(2.0, 0.0);
        assert_eq!(check(&[with_all]), Ok(()));
        let cases: [(EffectorGoal, &str); 7] = [
            (
                EffectorGoal::at(3, ok.position),
                "goal 0: joint: joint 3 is not the chain's effector, joint 7",
            ),
            (
                EffectorGoal::at(9, ok.position),
                "goal 0: joint: joint index 9 is out of range",
            ),
            (
                EffectorGoal::at(7, DVec3::new(0.0, f64::INFINITY, 0.0)),
                "goal 0: position",
            ),
            (
                ok.with_rotation(DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0)),
                "goal 0: rotation",
            ),
            (ok.with_weights(0.0, 1.0), "goal 0: position_weight"),
            (ok.with_weights(1.0, f64::NAN), "goal 0: rotation_weight"),
            (ok.with_pole(DVec3::new(f64::NAN, 0.0, 0.0)), "goal 0: pole"),
        ];
        for (goal, expected) in cases {
            let err = check(&[goal]).unwrap_err();
            assert!(err.starts_with(expected), "{err} (expected {expected})");
        }
        assert!(check(&[]).unwrap_err().contains("exactly one goal"));
        assert!(check(&[ok, ok]).unwrap_err().contains("got 2"));
        let bad_rotation_tolerance = SolveSettings {
            rotation_tolerance: -1.0,
            ..settings
        };
        let err = IkProblem::new(&skel, &chain, &[ok], bad_rotation_tolerance)
            .validate()
            .unwrap_err();
        assert!(err.to_string().contains("rotation_tolerance"), "{err}");
    }

    #[test]
    fn a_rotation_goal_keeps_the_solve_going_until_both_are_met() {
        // A bent chain's effector is on its goal position (inside the reach), but
        // turned 0.5 rad from the goal rotation: not done; with the rotation met, done
        // with both errors 0.
        let skel = lab_chain();
        let chain = Chain::whole(&skel).unwrap();
        let mut pose = skel.rest_pose();
        pose.rotations[3] = DQuat::from_rotation_z(0.4);
        let mut global = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut global).unwrap();
        let (here, facing) = (global.positions[7], global.rotations[7]);
        let turned =
            [EffectorGoal::at(7, here).with_rotation(facing * DQuat::from_rotation_x(0.5))];
        let problem = IkProblem::new(&skel, &chain, &turned, SolveSettings::default());
        let start = begin_solve(&problem, &mut IkState::new(&mut pose, &mut global)).unwrap();
        let SolveStart::Iterate {
            initial_error,
            initial_rotation_error,
        } = start
        else {
            panic!("expected to iterate: {start:?}")
        };
        assert!(initial_error < 1e-15);
        assert!((initial_rotation_error - 0.5).abs() < 1e-14);
        let met = [EffectorGoal::at(7, here).with_rotation(facing)];
        let problem = IkProblem::new(&skel, &chain, &met, SolveSettings::default());
        let start = begin_solve(&problem, &mut IkState::new(&mut pose, &mut global)).unwrap();
        let SolveStart::Done(report) = start else {
            panic!("expected done: {start:?}")
        };
        assert_eq!(report.stop, StopReason::Converged);
        assert!(report.rotation_error < 1e-15 && report.error < 1e-15);
    }
}
