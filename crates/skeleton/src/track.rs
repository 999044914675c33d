//! Trajectory tracking: solving a sequence of targets with any [`IkSolver`], each frame
//! warm-started from the previous frame's pose, with per-frame records and a summary.
//!
//! One copy shared by every solver (the scene runner and the benchmarks use it for CCD
//! and FABRIK alike). Besides the solver's own report, each frame records the largest
//! change of a chain joint's local rotation from the previous frame
//! ([`largest_rotation_change`]), the measure of continuity the lab's Q3 is about.
//!
//! The lab's Q3 as an option, [`TrackSettings::max_rotation_change`]: a frame whose
//! solution turns some joint by more than the limit is redone from the previous frame's
//! pose with every joint's change clamped to the limit (each local rotation is turned
//! from its previous value towards the solved one, about the same axis, by at most the
//! limit), then forward kinematics. The clamped frame is the frame's answer, usually
//! farther from its target, and it is counted in [`TrackSummary::clamped_frames`].
//! Details and the reasoning are in `docs/tracking.md`.
//!
//! A frame allocates nothing once the tracker has seen its first frame, except for
//! appending its [`FrameRecord`] when records are kept (reserve them with
//! [`Tracker::reserve`]).

use crate::ik::{
    Chain, EffectorGoal, IkError, IkProblem, IkSolver, IkState, SolveSettings, StopReason,
    chain_limit_violation, largest_rotation_change, rotation_angle,
};
use crate::{GlobalPose, Pose, Skeleton};
use sinew_math::{DQuat, DVec3, try_unit};

/// How a trajectory is tracked.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct TrackSettings {
    /// The settings of every frame's solve.
    pub solve: SolveSettings,
    /// The lab's Q3: the largest change (radians) of any chain joint's local rotation
    /// from one frame to the next. `None`: no limit. Must be finite and positive.
    pub max_rotation_change: Option<f64>,
}

impl TrackSettings {
    /// Checks the solve settings and the rotation limit.
    pub fn validate(&self) -> Result<(), IkError> {
        self.solve.validate()?;
        match self.max_rotation_change {
            Some(limit) if !(limit.is_finite() && limit > 0.0) => Err(IkError::InvalidSettings(
                format!("max_rotation_change must be finite and > 0 radians, got {limit}"),
            )),
            _ => Ok(()),
        }
    }
}

/// What happened on one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct FrameRecord {
    /// The goal position of this frame.
    pub target: DVec3,
    /// Effector-to-target distance at the end of the frame (after any clamping).
    pub error: f64,
    /// Angle (radians) between the effector's rotation and the goal rotation at the end
    /// of the frame; 0 without a rotation goal.
    pub rotation_error: f64,
    /// The largest joint-limit violation (radians) of the frame's pose; 0 without limits.
    pub limit_violation: f64,
    /// Iterations the solver used.
    pub iterations: usize,
    /// Why the solver stopped (the solver's own answer, before any clamping).
    pub stop: StopReason,
    /// The largest change (radians) of a chain joint's local rotation from the previous
    /// frame's pose (for the first frame: from the starting pose), after any clamping.
    pub rotation_change: f64,
    /// Whether the solution jumped more than [`TrackSettings::max_rotation_change`] and
    /// was clamped.
    pub clamped: bool,
    /// The largest difference (scene units) between a chain bone's length in this
    /// frame's pose and its rest length.
    pub bone_length_error: f64,
}

/// Totals over the frames tracked so far. The field names are the scene metric keys.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct TrackSummary {
    /// Frames tracked.
    pub frames: usize,
    /// Mean final effector-to-target distance.
    pub error_mean: f64,
    /// Largest final effector-to-target distance.
    pub error_max: f64,
    /// Iterations over all frames.
    pub iterations_total: usize,
    /// Frames that ended within the tolerance.
    pub converged_frames: usize,
    /// Largest final rotation error (radians); 0 without rotation goals.
    pub rotation_error_max: f64,
    /// Largest joint-limit violation (radians) of any frame's pose; 0 without limits.
    pub limit_violation_max: f64,
    /// Frames whose solve ended at the best pose within the joint limits it found
    /// ([`StopReason::LocalMinimum`]).
    pub local_minimum_frames: usize,
    /// Largest difference (scene units) between a chain bone's length and its rest
    /// length over all frames.
    pub bone_length_error_max: f64,
    /// Largest change (radians) of a chain joint's local rotation between consecutive
    /// frames. The first frame's change from the starting pose is not counted here: it
    /// is not a change between frames (it is in the first [`FrameRecord`]).
    pub rotation_jump_max_rad: f64,
    /// Frames whose solution was clamped by [`TrackSettings::max_rotation_change`].
    pub clamped_frames: usize,
}

/// Tracks a sequence of targets frame by frame; see the [module docs](self).
#[derive(Clone, Debug)]
pub struct Tracker {
    settings: TrackSettings,
    /// The pose at the end of the previous frame (empty before the first frame).
    previous: Pose,
    keep_records: bool,
    records: Vec<FrameRecord>,
    summary: TrackSummary,
    error_sum: f64,
}

impl Tracker {
    /// A tracker with validated settings, keeping a [`FrameRecord`] per frame.
    pub fn new(settings: TrackSettings) -> Result<Self, IkError> {
        settings.validate()?;
        Ok(Self {
            settings,
            previous: Pose {
                rotations: Vec::new(),
            },
            keep_records: true,
            records: Vec::new(),
            summary: TrackSummary::default(),
            error_sum: 0.0,
        })
    }

    /// The same tracker keeping per-frame records or not (the summary is always kept).
    #[must_use]
    pub fn keep_records(mut self, keep: bool) -> Self {
        self.keep_records = keep;
        self
    }

    /// Reserves room for `frames` more records, so tracking them allocates nothing.
    pub fn reserve(&mut self, frames: usize) {
        if self.keep_records {
            self.records.reserve(frames);
        }
    }

    /// The settings.
    #[must_use]
    pub fn settings(&self) -> &TrackSettings {
        &self.settings
    }

    /// The records of the frames tracked so far (empty when records are not kept).
    #[must_use]
    pub fn records(&self) -> &[FrameRecord] {
        &self.records
    }

    /// Totals over the frames tracked so far.
    #[must_use]
    pub fn summary(&self) -> TrackSummary {
        let mut summary = self.summary;
        if summary.frames > 0 {
            summary.error_mean = self.error_sum / summary.frames as f64;
        }
        summary
    }

    /// Forgets every frame, so the next frame starts a new trajectory (buffers kept).
    pub fn reset(&mut self) {
        self.previous.rotations.clear();
        self.records.clear();
        self.summary = TrackSummary::default();
        self.error_sum = 0.0;
    }

    /// Solves one frame: `state.pose` must hold the previous frame's answer (or the
    /// starting pose for the first frame), and holds this frame's answer on return, with
    /// `state.global` its forward kinematics. Errors are the solver's (bad goal, pose or
    /// chain); a frame that fails is not recorded.
    pub fn step(
        &mut self,
        solver: &mut dyn IkSolver,
        skeleton: &Skeleton,
        chain: &Chain,
        state: &mut IkState<'_>,
        goal: EffectorGoal,
    ) -> Result<FrameRecord, IkError> {
        let first = self.summary.frames == 0;
        let pose = &mut *state.pose;
        if first || self.previous.rotations.len() != pose.rotations.len() {
            self.previous.rotations.clear();
            self.previous.rotations.extend_from_slice(&pose.rotations);
        }
        let goals = [goal];
        let problem = IkProblem::new(skeleton, chain, &goals, self.settings.solve);
        let report = solver.solve(&problem, state)?;
        let (pose, global) = (&mut *state.pose, &mut *state.global);
        let mut error = report.error;
        let mut rotation_error = report.rotation_error;
        let mut limit_violation = report.limit_violation;
        let mut rotation_change = largest_rotation_change(&self.previous, pose, chain.joints());
        let mut clamped = false;
        if let Some(limit) = self.settings.max_rotation_change
            && !first
            && rotation_change > limit
        {
            clamp_towards(&self.previous, pose, chain.joints(), limit);
            skeleton.forward_kinematics_from(pose, chain.base(), global)?;
            (error, rotation_error) = goal.errors(global);
            limit_violation = chain_limit_violation(skeleton, chain, pose);
            rotation_change = largest_rotation_change(&self.previous, pose, chain.joints());
            clamped = true;
        }
        let bone_length_error = bone_length_error(chain, global);
        let record = FrameRecord {
            target: goal.position,
            error,
            rotation_error,
            limit_violation,
            iterations: report.iterations,
            stop: report.stop,
            rotation_change,
            clamped,
            bone_length_error,
        };
        let s = &mut self.summary;
        s.frames += 1;
        self.error_sum += error;
        s.error_max = s.error_max.max(error);
        s.iterations_total += report.iterations;
        s.converged_frames += usize::from(
            error <= self.settings.solve.tolerance
                && rotation_error <= self.settings.solve.rotation_tolerance,
        );
        s.rotation_error_max = s.rotation_error_max.max(rotation_error);
        s.limit_violation_max = s.limit_violation_max.max(limit_violation);
        s.local_minimum_frames += usize::from(report.stop == StopReason::LocalMinimum);
        s.bone_length_error_max = s.bone_length_error_max.max(bone_length_error);
        if !first {
            s.rotation_jump_max_rad = s.rotation_jump_max_rad.max(rotation_change);
        }
        s.clamped_frames += usize::from(clamped);
        if self.keep_records {
            self.records.push(record);
        }
        for &j in chain.joints() {
            self.previous.rotations[j] = pose.rotations[j];
        }
        Ok(record)
    }
}

/// Tracks `targets` (goal positions of the chain's effector) in order from the starting
/// `state.pose` and returns the summary; the per-frame records stay in `tracker`
/// ([`Tracker::records`]).
pub fn track(
    tracker: &mut Tracker,
    solver: &mut dyn IkSolver,
    skeleton: &Skeleton,
    chain: &Chain,
    state: &mut IkState<'_>,
    targets: &[DVec3],
) -> Result<TrackSummary, IkError> {
    tracker.reserve(targets.len());
    for &target in targets {
        let goal = EffectorGoal::at(chain.effector(), target);
        tracker.step(solver, skeleton, chain, state, goal)?;
    }
    Ok(tracker.summary())
}

/// Turns each chain joint's local rotation from `previous` towards its value in `pose`
/// by at most `limit` radians, about the axis of the change (so a joint within the limit
/// keeps its solved rotation, and one beyond it ends exactly `limit` from where it was).
fn clamp_towards(previous: &Pose, pose: &mut Pose, joints: &[usize], limit: f64) {
    for &j in joints {
        let from = previous.rotations[j].normalize();
        let to = pose.rotations[j].normalize();
        if rotation_angle(from, to) <= limit {
            continue;
        }
        // The change in the joint's own frame, as the shorter of q and -q.
        let mut change = from.conjugate() * to;
        if change.w < 0.0 {
            change = -change;
        }
        let Some(axis) = try_unit(change.xyz()) else {
            continue;
        };
        pose.rotations[j] = (from * DQuat::from_axis_angle(axis, limit)).normalize();
    }
}

/// The largest |bone length - rest length| over the chain's bones in `global`.
fn bone_length_error(chain: &Chain, global: &GlobalPose) -> f64 {
    let joints = chain.joints();
    joints
        .windows(2)
        .zip(chain.bone_lengths())
        .map(|(pair, &rest)| {
            (global.positions[pair[1]].distance(global.positions[pair[0]]) - rest).abs()
        })
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ik::{SolveStart, begin_solve, measure};
    use std::f64::consts::{FRAC_PI_2, PI};

    /// A test solver: the closed-form early exits, and otherwise turns the base joint by
    /// the minimal rotation aiming the effector at the target (exact for a one-bone
    /// chain), one "iteration".
    struct AimBase;

    impl IkSolver for AimBase {
        fn name(&self) -> &'static str {
            "aim-base"
        }

        fn solve(
            &mut self,
            problem: &IkProblem<'_>,
            state: &mut IkState<'_>,
        ) -> Result<crate::ik::SolveReport, IkError> {
            let initial = match begin_solve(problem, state)? {
                SolveStart::Done(report) => return Ok(report),
                SolveStart::Iterate {
                    initial_error,
                    initial_rotation_error,
                } => (initial_error, initial_rotation_error),
            };
            let (skeleton, chain) = (problem.skeleton, problem.chain);
            let goal = problem.goal()?;
            let target = goal.position;
            let base = chain.base();
            let p = state.global.positions[base];
            let turn = sinew_math::rotation_between(
                state.global.positions[chain.effector()] - p,
                target - p,
            );
            state.pose.rotations[base] = (turn * state.pose.rotations[base]).normalize();
            skeleton.forward_kinematics(state.pose, state.global)?;
            let error = state.global.positions[chain.effector()].distance(target);
            let stop = if error <= problem.settings.tolerance {
                StopReason::Converged
            } else {
                StopReason::IterationCap
            };
            Ok(measure(problem, state, goal, 1, initial, stop))
        }
    }

    /// One bone of length 1 from the origin along x: the effector lies on the unit circle.
    fn arm() -> (Skeleton, Chain) {
        let skel = Skeleton::chain(DVec3::ZERO, &[DVec3::X]).unwrap();
        let chain = Chain::whole(&skel).unwrap();
        (skel, chain)
    }

    fn circle(angle: f64, radius: f64) -> DVec3 {
        DVec3::new(angle.cos(), angle.sin(), 0.0) * radius
    }

    #[test]
    fn summary_adds_up_the_frames() {
        let (skel, chain) = arm();
        let mut tracker = Tracker::new(TrackSettings::default()).unwrap();
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        // 0.1 rad steps on the unit circle (at the reach: solved exactly in closed form,
        // 0 iterations), then a target at radius 0.5 (inside: one iteration aims the arm
        // at it, error 0.5), then one at radius 3 (out of reach, error 2).
        let mut targets: Vec<DVec3> = (1..=5).map(|k| circle(0.1 * k as f64, 1.0)).collect();
        targets.push(circle(0.5, 0.5));
        targets.push(circle(0.5, 3.0));
        let summary = track(
            &mut tracker,
            &mut AimBase,
            &skel,
            &chain,
            &mut IkState::new(&mut pose, &mut global),
            &targets,
        )
        .unwrap();
        assert_eq!(summary.frames, 7);
        assert_eq!(summary.converged_frames, 5);
        assert_eq!(summary.clamped_frames, 0);
        let records = tracker.records();
        assert_eq!(records.len(), 7);
        assert!((records[5].error - 0.5).abs() < 1e-15);
        assert_eq!(records[6].stop, StopReason::OutOfReach);
        assert!((records[6].error - 2.0).abs() < 1e-15);
        assert!((summary.error_max - 2.0).abs() < 1e-15);
        let sum: f64 = records.iter().map(|r| r.error).sum();
        assert!((summary.error_mean - sum / 7.0).abs() < 1e-15);
        assert_eq!(summary.iterations_total, 1);
        assert_eq!(records[5].iterations, 1);
        assert_eq!(records[0].stop, StopReason::OutOfReach);
        // Each step on the circle turns the joint by 0.1 rad; the inward target needs no
        // turn; the first frame's turn from the rest pose is not a jump between frames.
        for r in &records[..5] {
            assert!(
                (r.rotation_change - 0.1).abs() < 1e-14,
                "{}",
                r.rotation_change
            );
        }
        assert!(records[5].rotation_change < 1e-14);
        assert!((summary.rotation_jump_max_rad - 0.1).abs() < 1e-14);
        assert!(summary.bone_length_error_max < 1e-15);
    }

    #[test]
    fn a_jump_beyond_the_limit_is_clamped_and_counted() {
        let (skel, chain) = arm();
        let settings = TrackSettings {
            max_rotation_change: Some(0.25),
            ..Default::default()
        };
        let mut tracker = Tracker::new(settings).unwrap();
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        let targets = [
            // The first frame is not limited (there is no previous frame).
            circle(FRAC_PI_2, 1.0),
            // 0.2 rad: within the limit.
            circle(FRAC_PI_2 + 0.2, 1.0),
            // 1 rad: clamped to 0.25 rad, so the effector ends at angle pi/2 + 0.45.
            circle(FRAC_PI_2 + 1.2, 1.0),
        ];
        track(
            &mut tracker,
            &mut AimBase,
            &skel,
            &chain,
            &mut IkState::new(&mut pose, &mut global),
            &targets,
        )
        .unwrap();
        let r = tracker.records();
        assert!(!r[0].clamped && !r[1].clamped && r[2].clamped);
        assert!((r[2].rotation_change - 0.25).abs() < 1e-14);
        let reached = circle(FRAC_PI_2 + 0.45, 1.0);
        assert!(global.positions[1].distance(reached) < 1e-14);
        // The error is the chord between the reached and the wanted angle (0.75 rad).
        let chord = 2.0 * (0.75f64 / 2.0).sin();
        assert!((r[2].error - chord).abs() < 1e-14);
        let summary = tracker.summary();
        assert_eq!(summary.clamped_frames, 1);
        assert_eq!(summary.converged_frames, 2);
        assert!((summary.rotation_jump_max_rad - 0.25).abs() < 1e-14);
        // global is forward kinematics of the clamped pose.
        let mut fresh = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut fresh).unwrap();
        assert_eq!(fresh.positions, global.positions);
    }

    #[test]
    fn a_half_turn_jump_is_clamped_without_nan() {
        let (skel, chain) = arm();
        let settings = TrackSettings {
            max_rotation_change: Some(0.5),
            ..Default::default()
        };
        let mut tracker = Tracker::new(settings).unwrap();
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        for target in [DVec3::X, -DVec3::X] {
            tracker
                .step(
                    &mut AimBase,
                    &skel,
                    &chain,
                    &mut IkState::new(&mut pose, &mut global),
                    EffectorGoal::at(1, target),
                )
                .unwrap();
        }
        let r = tracker.records()[1];
        assert!(r.clamped && r.error.is_finite());
        assert!((r.rotation_change - 0.5).abs() < 1e-14);
        assert!(pose.rotations.iter().all(|q| q.is_finite()));
        assert!(r.rotation_change < PI);
    }

    #[test]
    fn bad_settings_and_targets_are_errors() {
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let settings = TrackSettings {
                max_rotation_change: Some(bad),
                ..Default::default()
            };
            let err = Tracker::new(settings).unwrap_err();
            assert!(err.to_string().contains("max_rotation_change"), "{err}");
        }
        let (skel, chain) = arm();
        let mut tracker = Tracker::new(TrackSettings::default()).unwrap();
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        let nan = DVec3::new(0.0, f64::NAN, 0.0);
        assert!(matches!(
            tracker.step(
                &mut AimBase,
                &skel,
                &chain,
                &mut IkState::new(&mut pose, &mut global),
                EffectorGoal::at(1, nan)
            ),
            Err(IkError::InvalidGoal {
                goal: 0,
                field: "position",
                ..
            })
        ));
        assert_eq!(tracker.summary().frames, 0);
        assert!(tracker.records().is_empty());
    }

    #[test]
    fn reset_starts_a_new_trajectory_and_records_are_optional() {
        let (skel, chain) = arm();
        let mut tracker = Tracker::new(TrackSettings::default())
            .unwrap()
            .keep_records(false);
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        tracker
            .step(
                &mut AimBase,
                &skel,
                &chain,
                &mut IkState::new(&mut pose, &mut global),
                EffectorGoal::at(1, DVec3::Y),
            )
            .unwrap();
        assert!(tracker.records().is_empty());
        assert_eq!(tracker.summary().frames, 1);
        tracker.reset();
        assert_eq!(tracker.summary(), TrackSummary::default());
    }
}
