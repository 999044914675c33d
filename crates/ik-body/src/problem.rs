//! The full-body IK job: the problem (skeleton, effectors, settings, whether the body may
//! translate), its validation, the state a solve updates, and the report it returns.
//!
//! The weighted cost every solver of this crate decreases is
//!
//! ```text
//! C = sum_e  wp_e^2 |t_e - x_e|^2  +  wr_e^2 |log(q_e g_e^-1)|^2
//! ```
//!
//! over the effectors `e` (position `x_e`, global rotation `g_e`, goal position `t_e`,
//! goal rotation `q_e` when there is one), the rotation term being the squared angle of the
//! rotation from the effector's frame to the goal's. A pinned effector's weights are
//! multiplied by [`PIN_WEIGHT`].

use sinew_math::{DQuat, DVec3};
pub(crate) use sinew_skeleton::finish::{Target, all_within, pins_hold, total_cost};
use sinew_skeleton::ik::{EffectorGoal, IkError, SolveSettings, StopReason};
use sinew_skeleton::{GlobalPose, Pose, Skeleton, SkeletonError};

/// How much more a pinned effector counts than its own weights say, so that a conflict
/// between a pin and another goal is settled mostly in the pin's favour; the solvers also
/// refuse any step that moves a pinned effector away from its pin.
pub const PIN_WEIGHT: f64 = 10.0;

/// One effector of a body problem: a goal on one joint, and whether it is pinned.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct BodyEffector {
    /// The joint, its goal position, optional goal rotation and weights. The pole is not
    /// used by the body solvers.
    pub goal: EffectorGoal,
    /// A pinned effector (a planted foot) is a goal with priority: its weights are
    /// multiplied by [`PIN_WEIGHT`], and no step may leave it further from its goal
    /// position than the tolerance (or than it was at the start of the solve, if that was
    /// further). With the goal where the effector stands, it stays there.
    #[cfg_attr(feature = "serde", serde(default))]
    pub pinned: bool,
}

impl BodyEffector {
    /// A free (not pinned) effector with the given goal.
    #[must_use]
    pub fn new(goal: EffectorGoal) -> Self {
        Self {
            goal,
            pinned: false,
        }
    }

    /// A position goal, weight 1, not pinned.
    #[must_use]
    pub fn at(joint: usize, position: DVec3) -> Self {
        Self::new(EffectorGoal::at(joint, position))
    }

    /// A pinned position goal (see [`BodyEffector::pinned`](Self#structfield.pinned)).
    #[must_use]
    pub fn pinned(joint: usize, position: DVec3) -> Self {
        Self {
            goal: EffectorGoal::at(joint, position),
            pinned: true,
        }
    }
}

/// The inputs of a full-body solve.
#[derive(Clone, Copy, Debug)]
pub struct BodyProblem<'a> {
    /// The skeleton, with its joint limits.
    pub skeleton: &'a Skeleton,
    /// The effectors, at most one per joint.
    pub effectors: &'a [BodyEffector],
    /// Iteration cap and tolerances (per effector: every effector must be within them).
    pub settings: SolveSettings,
    /// Whether the whole body may translate (the hips follow the body): the solve then
    /// also changes [`BodyState::root_translation`].
    pub root_translates: bool,
}

impl<'a> BodyProblem<'a> {
    /// A problem from its parts, the root fixed (not validated).
    #[must_use]
    pub fn new(
        skeleton: &'a Skeleton,
        effectors: &'a [BodyEffector],
        settings: SolveSettings,
    ) -> Self {
        Self {
            skeleton,
            effectors,
            settings,
            root_translates: false,
        }
    }

    /// The same problem with the root free to translate or not.
    #[must_use]
    pub fn with_root_translation(mut self, root_translates: bool) -> Self {
        self.root_translates = root_translates;
        self
    }

    /// Checks the settings and every effector, naming the offending effector (its index
    /// in `effectors`) and field: each goal on its own ([`EffectorGoal::validate`]: joint
    /// in range, finite position and rotation, weights finite, the position weight > 0 and
    /// the rotation weight >= 0), and no two effectors on the same joint.
    pub fn validate(&self) -> Result<(), IkError> {
        self.settings.validate()?;
        for (i, effector) in self.effectors.iter().enumerate() {
            effector.goal.validate(i, self.skeleton)?;
            if let Some(first) = self.effectors[..i]
                .iter()
                .position(|other| other.goal.joint == effector.goal.joint)
            {
                return Err(IkError::InvalidGoal {
                    goal: i,
                    field: "joint",
                    reason: format!(
                        "{} already has effector {first}; one effector per joint",
                        self.skeleton.label(effector.goal.joint)
                    ),
                });
            }
        }
        Ok(())
    }

    /// [`BodyProblem::validate`] of a problem that differs from one `validate` accepted
    /// only in its goals' positions, rotations and poles (the same skeleton, effector
    /// joints, pins, weights, settings: a warm frame that continues a sequence, whose
    /// solver compares all of them): the same answer, only the fields that can have
    /// changed checked ([`EffectorGoal::validate_moving`]).
    pub(crate) fn validate_moving(&self) -> Result<(), IkError> {
        for (i, effector) in self.effectors.iter().enumerate() {
            effector.goal.validate_moving(i)?;
        }
        Ok(())
    }
}

/// The errors of one effector, before and after a solve.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct EffectorErrors {
    /// Distance from the goal position (for a pinned effector: from its pin) at the start.
    pub initial_position: f64,
    /// Angle (radians) from the goal rotation at the start; 0 without a rotation goal.
    pub initial_rotation: f64,
    /// Distance from the goal position after the solve.
    pub position: f64,
    /// Angle (radians) from the goal rotation after the solve; 0 without one.
    pub rotation: f64,
}

/// What a body solve updates: the pose, the body's translation and their forward
/// kinematics, and the per-effector errors of the last solve.
#[derive(Clone, Debug, PartialEq)]
pub struct BodyState {
    /// Local rotations; on entry the starting pose (warm start), on return the solution.
    pub pose: Pose,
    /// A translation of the whole body, added to every joint's position (the root's
    /// offset stays the skeleton's). Only changed by problems whose root translates.
    pub root_translation: DVec3,
    /// Forward kinematics of `pose` moved by `root_translation` ([`forward_kinematics`]);
    /// recomputed on entry, exact for the solution on return.
    pub global: GlobalPose,
    /// One entry per effector of the last solve, in the problem's order.
    pub effectors: Vec<EffectorErrors>,
}

impl BodyState {
    /// The rest pose of `skeleton`, no translation, its forward kinematics filled in.
    #[must_use]
    pub fn rest(skeleton: &Skeleton) -> Self {
        let pose = skeleton.rest_pose();
        let mut global = GlobalPose::new();
        // The rest pose is valid for its own skeleton, so this cannot fail.
        let _ = forward_kinematics(skeleton, &pose, DVec3::ZERO, &mut global);
        Self {
            pose,
            root_translation: DVec3::ZERO,
            global,
            effectors: Vec::new(),
        }
    }

    /// Recomputes `global` as forward kinematics of the pose moved by the translation
    /// ([`forward_kinematics`]), after the pose or the translation changed.
    pub(crate) fn update_global(&mut self, skeleton: &Skeleton) -> Result<(), SkeletonError> {
        forward_kinematics(
            skeleton,
            &self.pose,
            self.root_translation,
            &mut self.global,
        )
    }

    /// Copies `other`'s pose and translation into this state without allocating (once the
    /// sizes match); the global pose is recomputed by the next solve.
    pub fn copy_pose_from(&mut self, pose: &Pose, root_translation: DVec3) {
        self.pose.rotations.clear();
        self.pose.rotations.extend_from_slice(&pose.rotations);
        self.root_translation = root_translation;
    }
}

/// What a body solve reached; the per-effector errors are in [`BodyState::effectors`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct BodyReport {
    /// Iterations used: sweeps or passes, plus damped least-squares steps.
    pub iterations: usize,
    /// Why the solve stopped.
    pub stop: StopReason,
    /// The weighted cost (see the [module docs](self)) of the starting pose, after its
    /// projection onto the joint limits.
    pub initial_cost: f64,
    /// The weighted cost of the returned pose; never above `initial_cost`.
    pub cost: f64,
    /// The largest effector position error of the returned pose.
    pub max_error: f64,
    /// The largest effector rotation error (radians) of the returned pose.
    pub max_rotation_error: f64,
    /// The largest joint-limit violation (radians) over every joint of the returned pose.
    pub limit_violation: f64,
    /// Whether the solver restarted from the centre of the joint limits after a local
    /// minimum.
    pub restarted: bool,
}

impl BodyReport {
    /// A report of no solve (0 iterations, every figure 0, stop [`StopReason::Stalled`]):
    /// what a caller fills a [`BodyBatch`](crate::BodyBatch)'s report buffer with before
    /// the first batch, which overwrites every entry.
    pub const UNSOLVED: Self = Self {
        iterations: 0,
        stop: StopReason::Stalled,
        initial_cost: 0.0,
        cost: 0.0,
        max_error: 0.0,
        max_rotation_error: 0.0,
        limit_violation: 0.0,
        restarted: false,
    };

    /// Whether every effector met both tolerances of `settings`.
    #[must_use]
    pub fn within(&self, settings: &SolveSettings) -> bool {
        self.max_error <= settings.tolerance
            && self.max_rotation_error <= settings.rotation_tolerance
    }
}

/// Forward kinematics of `pose`, every position then moved by `translation`. No
/// allocation once `out` has the skeleton's size.
pub fn forward_kinematics(
    skeleton: &Skeleton,
    pose: &Pose,
    translation: DVec3,
    out: &mut GlobalPose,
) -> Result<(), SkeletonError> {
    skeleton.forward_kinematics(pose, out)?;
    if translation != DVec3::ZERO {
        for p in &mut out.positions {
            *p += translation;
        }
    }
    Ok(())
}

/// Forward kinematics from joint `joint` only, as [`Skeleton::forward_kinematics_from`],
/// for a translated body: a joint with a parent takes its position from the (already
/// translated) parent, so only a root needs the whole computation.
pub(crate) fn forward_kinematics_from(
    skeleton: &Skeleton,
    pose: &Pose,
    translation: DVec3,
    joint: usize,
    out: &mut GlobalPose,
) -> Result<(), SkeletonError> {
    if skeleton.parent(joint).is_some() && out.positions.len() == skeleton.len() {
        skeleton.forward_kinematics_from(pose, joint, out)
    } else {
        forward_kinematics(skeleton, pose, translation, out)
    }
}

/// The largest joint-limit violation (radians) of `pose` over every joint.
#[must_use]
pub fn limit_violation(skeleton: &Skeleton, pose: &Pose) -> f64 {
    (0..skeleton.len())
        .map(|j| skeleton.prepared_limit(j).violation(pose.rotations[j]))
        .fold(0.0, f64::max)
}

/// The targets of `problem` with their final weights.
pub(crate) fn resolve_targets(problem: &BodyProblem<'_>, out: &mut Vec<Target>) {
    out.clear();
    for effector in problem.effectors {
        let goal = &effector.goal;
        let scale = if effector.pinned { PIN_WEIGHT } else { 1.0 };
        out.push(Target {
            joint: goal.joint,
            position: goal.position,
            rotation: goal.rotation.map(DQuat::normalize),
            position_weight: goal.position_weight * scale,
            rotation_weight: goal.rotation_weight * scale,
            pinned: effector.pinned,
        });
    }
}

/// Fills `state.effectors` and the report's measured fields from `state.global`, and
/// `fixed` per joint with whether the projection onto its limit is known to return the
/// pose's rotation unchanged (see [`PreparedLimit::violation_and_fixed`]).
///
/// [`PreparedLimit::violation_and_fixed`]: sinew_skeleton::limits::PreparedLimit::violation_and_fixed
#[allow(clippy::too_many_arguments)]
pub(crate) fn finish_report(
    problem: &BodyProblem<'_>,
    targets: &[Target],
    state: &mut BodyState,
    fixed: &mut Vec<Option<DQuat>>,
    initial: &[(f64, f64)],
    initial_cost: f64,
    iterations: usize,
    stop: StopReason,
    restarted: bool,
) -> BodyReport {
    state.effectors.clear();
    let mut max_error: f64 = 0.0;
    let mut max_rotation_error: f64 = 0.0;
    for (target, &(p0, r0)) in targets.iter().zip(initial) {
        let (p, r) = target.errors(&state.global);
        max_error = max_error.max(p);
        max_rotation_error = max_rotation_error.max(r);
        state.effectors.push(EffectorErrors {
            initial_position: p0,
            initial_rotation: r0,
            position: p,
            rotation: r,
        });
    }
    // The same figure as `limit_violation`, joint by joint; a rotation already known to
    // be its own projection (by a trial's projection or an earlier report, for the same
    // limits) has no violation, which is what `violation_and_fixed` would say of it.
    let skeleton = problem.skeleton;
    fixed.resize(state.pose.rotations.len(), None);
    let mut violation: f64 = 0.0;
    for (j, (&q, known)) in state
        .pose
        .rotations
        .iter()
        .zip(fixed.iter_mut())
        .enumerate()
    {
        if *known == Some(q) {
            continue;
        }
        let (v, unchanged) = skeleton.prepared_limit(j).violation_and_fixed(q);
        violation = violation.max(v);
        if unchanged {
            *known = Some(q);
        }
    }
    BodyReport {
        iterations,
        stop,
        initial_cost,
        cost: total_cost(targets, &state.global),
        max_error,
        max_rotation_error,
        limit_violation: violation,
        restarted,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tree() -> Skeleton {
        Skeleton::new([
            sinew_skeleton::JointDef {
                name: Some("hips".into()),
                ..Default::default()
            },
            sinew_skeleton::JointDef {
                parent: Some(0),
                offset: DVec3::X,
                ..Default::default()
            },
            sinew_skeleton::JointDef {
                parent: Some(0),
                offset: -DVec3::X,
                ..Default::default()
            },
        ])
        .unwrap()
    }

    #[test]
    fn validate_names_the_effector_and_the_field() {
        let skel = tree();
        let settings = SolveSettings::default();
        let check = |effectors: &[BodyEffector]| {
            BodyProblem::new(&skel, effectors, settings)
                .validate()
                .map_err(|e| e.to_string())
        };
        assert_eq!(check(&[]), Ok(()));
        assert_eq!(
            check(&[BodyEffector::at(1, DVec3::Y), BodyEffector::at(2, DVec3::Z)]),
            Ok(())
        );
        let err =
            check(&[BodyEffector::at(1, DVec3::Y), BodyEffector::at(1, DVec3::Z)]).unwrap_err();
        assert!(
            err.starts_with("goal 1: joint: joint 1 already has effector 0"),
            "{err}"
        );
        let err = check(&[BodyEffector::at(5, DVec3::Y)]).unwrap_err();
        assert!(err.starts_with("goal 0: joint: joint index 5"), "{err}");
        let err = check(&[
            BodyEffector::at(0, DVec3::Y),
            BodyEffector::new(EffectorGoal::at(2, DVec3::Y).with_weights(1.0, -1.0)),
        ])
        .unwrap_err();
        assert!(err.starts_with("goal 1: rotation_weight"), "{err}");
        let err = check(&[BodyEffector::at(2, DVec3::new(f64::NAN, 0.0, 0.0))]).unwrap_err();
        assert!(err.starts_with("goal 0: position"), "{err}");
        let bad = SolveSettings {
            tolerance: f64::NAN,
            ..settings
        };
        let err = BodyProblem::new(&skel, &[], bad).validate().unwrap_err();
        assert!(err.to_string().contains("tolerance"), "{err}");
    }

    #[test]
    fn translated_forward_kinematics_moves_every_joint() {
        let skel = tree();
        let mut pose = skel.rest_pose();
        pose.rotations[0] = DQuat::from_rotation_z(0.5);
        let t = DVec3::new(0.25, -1.0, 2.0);
        let mut plain = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut plain).unwrap();
        let mut moved = GlobalPose::new();
        forward_kinematics(&skel, &pose, t, &mut moved).unwrap();
        for j in 0..3 {
            assert_eq!(moved.positions[j], plain.positions[j] + t);
            assert_eq!(moved.rotations[j], plain.rotations[j]);
        }
        // From a child joint, the translation comes through the parent.
        pose.rotations[1] = DQuat::from_rotation_y(0.3);
        forward_kinematics_from(&skel, &pose, t, 1, &mut moved).unwrap();
        let mut full = GlobalPose::new();
        forward_kinematics(&skel, &pose, t, &mut full).unwrap();
        assert_eq!(moved.positions, full.positions);
    }

    #[test]
    fn cost_is_the_weighted_sum_of_squares() {
        let skel = tree();
        let state = BodyState::rest(&skel);
        let goal = EffectorGoal::at(1, DVec3::new(1.0, 2.0, 0.0))
            .with_rotation(DQuat::from_rotation_z(0.3))
            .with_weights(2.0, 3.0);
        let effectors = [BodyEffector::new(goal)];
        let problem = BodyProblem::new(&skel, &effectors, SolveSettings::default());
        let mut targets = Vec::new();
        resolve_targets(&problem, &mut targets);
        let expected = 4.0 * 4.0 + 9.0 * 0.09;
        assert!((total_cost(&targets, &state.global) - expected).abs() < 1e-14);
        // A pinned effector counts PIN_WEIGHT times more.
        let pinned = [BodyEffector { goal, pinned: true }];
        let problem = BodyProblem::new(&skel, &pinned, SolveSettings::default());
        resolve_targets(&problem, &mut targets);
        let scaled = PIN_WEIGHT * PIN_WEIGHT * expected;
        assert!((total_cost(&targets, &state.global) - scaled).abs() < 1e-12 * scaled);
        assert_eq!(targets[0].position_weight, 2.0 * PIN_WEIGHT);
    }

    #[test]
    fn movers_are_the_ancestors_and_a_rotation_goal_s_own_joint() {
        // 0 -> 1 -> 2, 0 -> 3 -> 4, 0 -> 5 (no effector below 5).
        let parents = [None, Some(0), Some(1), Some(0), Some(3), Some(0)];
        let skel = Skeleton::new(parents.iter().map(|&parent| sinew_skeleton::JointDef {
            parent,
            offset: DVec3::X,
            ..sinew_skeleton::JointDef::default()
        }))
        .unwrap();
        let effectors = [
            BodyEffector::at(2, DVec3::Y),
            BodyEffector::new(EffectorGoal::at(4, DVec3::Z).with_rotation(DQuat::IDENTITY)),
            BodyEffector::at(1, DVec3::Z),
        ];
        let problem = BodyProblem::new(&skel, &effectors, SolveSettings::default());
        let mut targets = Vec::new();
        resolve_targets(&problem, &mut targets);
        let mut topo = sinew_skeleton::finish::Movers::default();
        topo.build(&skel, &targets);
        assert_eq!(topo.movable(), [0, 1, 3, 4]);
        assert_eq!(topo.below(0), [0, 1, 2]);
        assert_eq!(topo.below(1), [0]);
        assert_eq!(topo.below(2), [1]);
        assert_eq!(topo.below(3), [1]);
        assert_eq!(topo.slot(5), None);
        assert_eq!(topo.slot(4), Some(3));
        // Rebuilding with fewer effectors shrinks the lists.
        topo.build(&skel, &targets[..1]);
        assert_eq!(topo.movable(), [0, 1]);
        assert_eq!(topo.below(0), [0]);
    }
}
