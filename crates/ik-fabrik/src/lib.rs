//! FABRIK inverse kinematics for sinew skeletons (Aristidou and Lasenby, "FABRIK: A fast,
//! iterative solver for the Inverse Kinematics problem", Graphical Models 73(5), 2011),
//! with an optional damped least-squares refinement for the targets plain FABRIK
//! approaches slowly.
//!
//! - [`FabrikSolver`] implements [`IkSolver`] on a [`Chain`] inside any skeleton (side
//!   branches move rigidly with their joint). It works on the chain's joint positions:
//!   backward and forward passes that place every joint at exactly its bone length, so
//!   lengths never drift. Rotations are recovered once at the end, each bone turned by the
//!   minimal rotation from its previous global rotation, which keeps twist continuous
//!   from frame to frame; forward kinematics of the result reproduces the solved
//!   positions.
//! - [`FabrikMode::Hybrid`] (the default) switches to damped least-squares
//!   (Levenberg-Marquardt) steps on the joint rotations once a pass reduces the error by
//!   less than [`FabrikOptions::switch_ratio`] (default 0: after the first pass); this is
//!   what takes every reachable target to the tolerance, including those near the base
//!   where plain FABRIK crawls. [`FabrikMode::Plain`] is FABRIK alone.
//! - Chains with joint limits, and goals with a rotation, take another path: one FABRIK
//!   pass (or, for a limb with a position goal, its closed-form pose:
//!   [`sinew_skeleton::seed`]), the rotations recovered and projected onto the limits, then a damped
//!   least-squares finish on the local rotations over a 3- or 6-row residual, each trial
//!   projected onto the limits, with an active set, and one restart from a second seed
//!   after a local minimum (`docs/ik-limits.md`).
//! - [`fabrik_pass`]: one backward-forward iteration on bare positions.
//!
//! [`SolveReport::iterations`] counts FABRIK passes plus refinement steps (each step,
//! accepted or rejected, costs one O(bones) evaluation). Derivations and costs:
//! `docs/ik-fabrik.md`.
//!
//! ```
//! use sinew_ik_fabrik::{DVec3, FabrikSolver};
//! use sinew_skeleton::ik::{
//!     Chain, EffectorGoal, IkProblem, IkSolver, IkState, SolveSettings, StopReason,
//! };
//! use sinew_skeleton::{GlobalPose, Skeleton};
//!
//! // Five bones of 0.2 (reach 1) and a target close to the base, where plain FABRIK
//! // crawls and the hybrid's least-squares finish converges.
//! let arm = Skeleton::chain(DVec3::ZERO, &[DVec3::new(0.2, 0.0, 0.0); 5]).unwrap();
//! let chain = Chain::whole(&arm).unwrap();
//! let target = DVec3::new(0.1, 0.15, -0.05);
//! let goals = [EffectorGoal::at(chain.effector(), target)];
//! let settings = SolveSettings { tolerance: 1e-9, ..SolveSettings::default() };
//! let problem = IkProblem::new(&arm, &chain, &goals, settings);
//!
//! let (mut pose, mut global) = (arm.rest_pose(), GlobalPose::new());
//! arm.forward_kinematics(&pose, &mut global).unwrap();
//! let report = FabrikSolver::new()
//!     .solve(&problem, &mut IkState::new(&mut pose, &mut global))
//!     .unwrap();
//! assert_eq!(report.stop, StopReason::Converged);
//! assert!(report.error <= 1e-9);
//! assert!((global.positions[chain.effector()] - target).length() <= 1e-9);
//! // FABRIK places every joint at exactly its bone length.
//! for bone in 1..arm.len() {
//!     let length = (global.positions[bone] - global.positions[bone - 1]).length();
//!     assert!((length - 0.2).abs() < 1e-12);
//! }
//! ```

mod pass;
mod refine;

pub use pass::fabrik_pass;
/// The math types targets and poses are given in, re-exported so a user of this crate
/// does not also have to depend on sinew-math.
pub use sinew_math::{DQuat, DVec3};

use refine::Refiner;
use sinew_math::rotation_between;
use sinew_skeleton::finish::ChainFinish;
use sinew_skeleton::ik::{
    Chain, IkError, IkProblem, IkSolver, IkState, SolveReport, SolveSettings, SolveStart,
    StopReason, begin_solve, chain_has_limits, measure, project_onto_limits, turn_towards_pole,
};
use sinew_skeleton::seed::limb_seed;
use sinew_skeleton::{GlobalPose, Pose, Skeleton};

/// Which algorithm a [`FabrikSolver`] runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum FabrikMode {
    /// FABRIK passes only, stopping at the tolerance, the cap, or the first pass that does
    /// not reduce the error.
    Plain,
    /// FABRIK passes until a pass reduces the error by less than
    /// [`FabrikOptions::switch_ratio`] (by default: after the first pass), then damped
    /// least-squares steps on the joint rotations. The default: it reaches every
    /// reachable W2 target within 1e-6, where plain FABRIK reaches 89% at cap 100, and it
    /// is faster on both W1 and W2.
    #[default]
    Hybrid,
}

impl FabrikMode {
    /// A short lower-case name for tables and metrics.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Plain => "plain",
            Self::Hybrid => "hybrid",
        }
    }
}

/// The options of a [`FabrikSolver`], beyond the shared [`SolveSettings`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct FabrikOptions {
    /// Plain FABRIK or the hybrid (default).
    pub mode: FabrikMode,
    /// Hybrid only: switch to the refinement once a pass leaves more than this fraction
    /// of the error it started with (`error_after > switch_ratio * error_before`). In
    /// `[0, 1]`; 1 switches only when FABRIK stalls, 0 after the first pass. The default
    /// is 0, the fastest setting measured on W1 and W2 (`docs/bench/ik-fabrik.md`): one
    /// FABRIK pass makes the large move, then each accepted least-squares step roughly
    /// squares the error, where FABRIK passes only reduce it linearly.
    pub switch_ratio: f64,
}

impl Default for FabrikOptions {
    fn default() -> Self {
        Self {
            mode: FabrikMode::Hybrid,
            switch_ratio: 0.0,
        }
    }
}

impl FabrikOptions {
    /// Plain FABRIK, no refinement.
    #[must_use]
    pub fn plain() -> Self {
        Self {
            mode: FabrikMode::Plain,
            ..Self::default()
        }
    }

    /// Checks `switch_ratio` is in `[0, 1]`.
    pub fn validate(&self) -> Result<(), IkError> {
        if (0.0..=1.0).contains(&self.switch_ratio) {
            Ok(())
        } else {
            Err(IkError::InvalidSettings(format!(
                "fabrik switch_ratio must be in [0, 1], got {}",
                self.switch_ratio
            )))
        }
    }
}

/// How the last solve spent its iterations.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FabrikStats {
    /// FABRIK backward-forward passes.
    pub passes: usize,
    /// Damped least-squares steps tried (accepted or rejected).
    pub refinement_steps: usize,
    /// Unfolding kicks: the refinement stalled on a chain lying along the line to the
    /// target, and the outer part of the chain was bent to get it moving (hybrid only).
    pub unfolds: usize,
    /// Whether the result was worse than the starting pose (only possible when the cap
    /// stops plain FABRIK after a pass that went the wrong way) and the starting pose
    /// was restored instead.
    pub restored_start: bool,
}

/// The minimal rotation taking `current` onto the direction of `wanted`, where both have
/// length `length` up to rounding (a bone before and after the solve).
///
/// For the unit vectors `a`, `b` the minimal rotation is the normalized quaternion
/// `(a x b, 1 + a . b)`; knowing the length saves the normalizations of
/// [`rotation_between`], which takes over when the angle is wide (`1 + a . b` would
/// cancel) or the bone has no length.
#[inline]
fn turn_between(current: DVec3, wanted: DVec3, length: f64) -> DQuat {
    let squared = length * length;
    if squared > 1e-200 && squared < 1e200 {
        let axis = current.cross(wanted);
        let w = squared + current.dot(wanted);
        if w > 0.25 * squared {
            return DQuat::from_xyzw(axis.x, axis.y, axis.z, w).normalize();
        }
    }
    rotation_between(current, wanted)
}

/// `v` rescaled to length `length` (a bone vector given back its rest length). Used where
/// bone vectors are not built at their length directly: the differences of positions
/// that start the refinement, whose error is round-off of the positions' own size, and
/// the refined bones summed back into positions. A zero-length bone comes out zero; a
/// vector with no direction at all (only possible for a bone shorter than the round-off
/// of its endpoints) is left as it is.
#[inline]
fn with_length(v: DVec3, length: f64) -> DVec3 {
    let squared = v.length_squared();
    // Same fast path as the FABRIK step: one square root and one division well inside
    // the floating-point range, `try_unit`'s rescaling anywhere else.
    if (1e-200..=1e200).contains(&squared) {
        return v * (length / squared.sqrt());
    }
    sinew_math::try_unit(v).map_or(v, |d| d * length)
}

/// The most unfolding kicks per solve (see [`unfold`]).
const MAX_UNFOLDS: usize = 2;

/// Bends a chain that the refinement cannot move: when every joint-to-effector vector is
/// parallel to the error (a chain folded or stretched along the line to the target, as
/// FABRIK leaves it for a target on the line of a straight chain), no small rotation
/// moves the effector along that line, to first order, and damped least squares stalls.
/// The kick turns the outer part of the chain by one radian about an axis perpendicular
/// to the bone at the bend (at the middle joint first, then a third of the way out, about
/// a perpendicular axis), which makes the first-order problem regular again.
fn unfold(bones: &mut [DVec3], attempt: usize) {
    let n = bones.len();
    let at = if attempt == 0 { n / 2 } else { n / 3 };
    let line = bones[at..]
        .iter()
        .find_map(|&b| sinew_math::try_unit(b))
        .unwrap_or(DVec3::X);
    let mut axis = line.any_orthonormal_vector();
    if attempt % 2 == 1 {
        axis = line.cross(axis);
    }
    let bend = DQuat::from_axis_angle(axis, 1.0);
    for bone in &mut bones[at..] {
        *bone = bend * *bone;
    }
}

/// FABRIK solver with its work buffers: a solve allocates nothing once the buffers have
/// grown to the chain's size. See the [crate docs](crate).
///
/// A goal with a rotation as well as a position (the hand turned 0.3 rad about z):
///
/// ```
/// use sinew_ik_fabrik::{DQuat, DVec3, FabrikSolver};
/// use sinew_skeleton::ik::{Chain, EffectorGoal, IkProblem, IkSolver, IkState, SolveSettings};
/// use sinew_skeleton::{GlobalPose, Skeleton};
///
/// let arm = Skeleton::chain(DVec3::ZERO, &[DVec3::new(0.3, 0.0, 0.0); 4]).unwrap();
/// let chain = Chain::whole(&arm).unwrap();
/// let hand = DQuat::from_rotation_z(0.3);
/// let goals = [EffectorGoal::at(chain.effector(), DVec3::new(0.6, 0.4, 0.1)).with_rotation(hand)];
/// let problem = IkProblem::new(&arm, &chain, &goals, SolveSettings::default());
/// let (mut pose, mut global) = (arm.rest_pose(), GlobalPose::new());
/// let report = FabrikSolver::new()
///     .solve(&problem, &mut IkState::new(&mut pose, &mut global))
///     .unwrap();
/// assert!(report.within(&problem.settings), "{report:?}");
/// assert!(report.rotation_error <= 1e-6);
/// ```
#[derive(Clone, Debug, Default)]
pub struct FabrikSolver {
    options: FabrikOptions,
    /// Chain joint positions, base first.
    positions: Vec<DVec3>,
    /// Per bone, its world vector (refinement only).
    bones: Vec<DVec3>,
    /// Bone vectors kept while an unfolding kick is tried.
    spare: Vec<DVec3>,
    /// Local rotations of the chain joints before the solve wrote them.
    saved: Vec<DQuat>,
    refiner: Refiner,
    finish: ChainFinish,
    stats: FabrikStats,
}

impl FabrikSolver {
    /// A solver with the default options (the hybrid).
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// A solver running plain FABRIK.
    #[must_use]
    pub fn plain() -> Self {
        Self {
            options: FabrikOptions::plain(),
            ..Self::default()
        }
    }

    /// A solver with the given options, validated.
    pub fn with_options(options: FabrikOptions) -> Result<Self, IkError> {
        options.validate()?;
        Ok(Self {
            options,
            ..Self::default()
        })
    }

    /// The options this solver runs with.
    #[must_use]
    pub fn options(&self) -> FabrikOptions {
        self.options
    }

    /// How the last solve spent its iterations.
    #[must_use]
    pub fn last_stats(&self) -> FabrikStats {
        self.stats
    }

    /// The chain joint positions (base first) the last solve computed before turning
    /// them into rotations; forward kinematics of the returned pose reproduces them to
    /// rounding. Empty before the first solve; after a solve that ended before iterating
    /// (within tolerance, out of reach) or restored its start, the forward-kinematics
    /// positions of the chain.
    #[must_use]
    pub fn solved_positions(&self) -> &[DVec3] {
        &self.positions
    }

    fn copy_chain_positions(&mut self, chain: &Chain, global: &GlobalPose) {
        self.positions.clear();
        self.positions
            .extend(chain.joints().iter().map(|&j| global.positions[j]));
    }

    /// The hybrid's refinement of `self.bones`, with up to [`MAX_UNFOLDS`] unfolding
    /// kicks when it stalls away from the target (see [`unfold`]); returns the error and
    /// why it stopped, and counts steps and kicks in `self.stats`.
    fn refine(
        &mut self,
        base: DVec3,
        target: DVec3,
        mut error: f64,
        passes: usize,
        settings: &SolveSettings,
    ) -> (f64, StopReason) {
        let run = |solver: &mut Self, error: f64| {
            let refined = solver.refiner.run(
                &mut solver.bones,
                base,
                target,
                error,
                settings.tolerance,
                passes + solver.stats.refinement_steps,
                settings.max_iterations,
            );
            solver.stats.refinement_steps += refined.steps;
            refined
        };
        let mut refined = run(self, error);
        error = refined.error;
        let mut stop = refined.stop;
        let mut attempt = 0;
        while stop == StopReason::Stalled && attempt < MAX_UNFOLDS && self.bones.len() >= 2 {
            // Keep the stalled chain in case the unfolded one ends up worse.
            self.spare.clear();
            self.spare.extend_from_slice(&self.bones);
            unfold(&mut self.bones, attempt);
            attempt += 1;
            self.stats.unfolds += 1;
            let kicked = (base + self.bones.iter().sum::<DVec3>()).distance(target);
            refined = run(self, kicked);
            if refined.error < error {
                error = refined.error;
                stop = refined.stop;
            } else {
                std::mem::swap(&mut self.bones, &mut self.spare);
                if refined.stop == StopReason::IterationCap {
                    stop = StopReason::IterationCap;
                }
            }
        }
        (error, stop)
    }

    /// Turns the solved positions back into rotations, once, base outwards. Each bone
    /// turns by the minimal rotation from its current direction (its global rotation in
    /// the starting pose) to its solved one, which keeps the bone's twist; then
    /// `L[j] = G_new[parent]^-1 G_new[j]` with the parent's new global rotation (the
    /// base's parent is outside the chain and keeps its rotation). The chain's previous
    /// local rotations are kept in `self.saved`; `global` ends as forward kinematics.
    fn recover_rotations(
        &mut self,
        skeleton: &Skeleton,
        chain: &Chain,
        pose: &mut Pose,
        global: &mut GlobalPose,
    ) -> Result<(), IkError> {
        let joints = chain.joints();
        let lengths = chain.bone_lengths();
        self.saved.clear();
        let mut parent_global = skeleton.parent(joints[0]).map(|p| global.rotations[p]);
        for c in 0..chain.bone_count() {
            let (j, k) = (joints[c], joints[c + 1]);
            let current = global.rotations[j] * skeleton.offset(k);
            let wanted = self.positions[c + 1] - self.positions[c];
            let turn = turn_between(current, wanted, lengths[c]);
            let new_global = (turn * global.rotations[j]).normalize();
            self.saved.push(pose.rotations[j]);
            pose.rotations[j] = match parent_global {
                Some(parent) => (parent.conjugate() * new_global).normalize(),
                None => new_global,
            };
            parent_global = Some(new_global);
        }
        skeleton.forward_kinematics_from(pose, joints[0], global)?;
        Ok(())
    }

    /// The solve with joint limits or a rotation goal: one FABRIK pass for the large move
    /// (unconstrained, on positions; a limb with a position goal takes its closed-form
    /// pose instead, [`limb_seed`]), the rotations recovered and projected onto the
    /// limits (kept only if that lowered the weighted residual), then the limited damped
    /// least-squares finish ([`sinew_skeleton::finish`]). When the finish ends in a local minimum of a
    /// chain with limits, it is run once more from a second seed, every limited joint at
    /// the centre of its range (hinge: the middle angle; swing-twist: no swing, the middle
    /// twist; free joints keep their rotation), and the better of the two is returned.
    fn solve_constrained(
        &mut self,
        problem: &IkProblem<'_>,
        state: &mut IkState<'_>,
        initial: (f64, f64),
    ) -> Result<SolveReport, IkError> {
        let (skeleton, chain, settings) = (problem.skeleton, problem.chain, &problem.settings);
        let goal = problem.goal()?;
        let has_limits = chain_has_limits(skeleton, chain);
        let (pose, global) = (&mut *state.pose, &mut *state.global);
        let movable = &chain.joints()[..chain.bone_count()];
        let mut passes = 0;
        if settings.max_iterations > 0 {
            let start_cost = ChainFinish::cost(goal, global);
            self.copy_chain_positions(chain, global);
            let base = self.positions[0];
            let base_parent = skeleton
                .parent(chain.base())
                .map_or(DQuat::IDENTITY, |p| global.rotations[p]);
            self.saved.clear();
            self.saved
                .extend(movable.iter().map(|&j| pose.rotations[j]));
            if goal.rotation.is_none()
                && limb_seed(skeleton, chain, pose, base, base_parent, goal.position)
            {
                skeleton.forward_kinematics_from(pose, chain.base(), global)?;
            } else {
                pass::pass_unchecked(
                    &mut self.positions,
                    chain.bone_lengths(),
                    base,
                    goal.position,
                );
                passes = 1;
                self.recover_rotations(skeleton, chain, pose, global)?;
                if has_limits && project_onto_limits(skeleton, chain, pose) {
                    skeleton.forward_kinematics_from(pose, chain.base(), global)?;
                }
            }
            if ChainFinish::cost(goal, global) > start_cost {
                for (&j, &saved) in movable.iter().zip(&self.saved) {
                    pose.rotations[j] = saved;
                }
                skeleton.forward_kinematics_from(pose, chain.base(), global)?;
                self.stats.restored_start = true;
            }
        }
        self.stats.passes = passes;
        let (finished, restarted) = self
            .finish
            .run_restarting(skeleton, chain, goal, pose, global, settings, passes)?;
        self.stats.refinement_steps = finished.steps;
        let mut stop = finished.stop;
        if stop == StopReason::LocalMinimum && !has_limits {
            // Nothing but the goal holds the chain: the finish simply stopped helping.
            stop = StopReason::Stalled;
        }
        turn_towards_pole(problem, state)?;
        self.copy_chain_positions(chain, state.global);
        let mut report = measure(
            problem,
            state,
            goal,
            self.stats.passes + self.stats.refinement_steps,
            initial,
            stop,
        );
        report.restarted = restarted;
        Ok(report)
    }

    /// FABRIK passes from the current positions. Returns the error, the stop reason (or
    /// `None` when the hybrid should refine) and the passes used.
    fn run_passes(
        &mut self,
        chain: &Chain,
        target: DVec3,
        mut error: f64,
        settings: &SolveSettings,
    ) -> (f64, Option<StopReason>, usize) {
        let lengths = chain.bone_lengths();
        let base = self.positions[0];
        let mut passes = 0;
        loop {
            if error <= settings.tolerance {
                return (error, Some(StopReason::Converged), passes);
            }
            if passes >= settings.max_iterations {
                return (error, Some(StopReason::IterationCap), passes);
            }
            let next = pass::pass_unchecked(&mut self.positions, lengths, base, target);
            passes += 1;
            let slow = match self.options.mode {
                FabrikMode::Plain => next >= error,
                FabrikMode::Hybrid => next > self.options.switch_ratio * error,
            };
            error = next;
            if slow && error > settings.tolerance && passes < settings.max_iterations {
                return match self.options.mode {
                    FabrikMode::Plain => (error, Some(StopReason::Stalled), passes),
                    // A pass that made things worse is still a fine start for the
                    // refinement, whose steps only ever decrease the error.
                    FabrikMode::Hybrid => (error, None, passes),
                };
            }
        }
    }
}

impl IkSolver for FabrikSolver {
    fn name(&self) -> &'static str {
        "fabrik"
    }

    fn solve(
        &mut self,
        problem: &IkProblem<'_>,
        state: &mut IkState<'_>,
    ) -> Result<SolveReport, IkError> {
        self.stats = FabrikStats::default();
        let (skeleton, chain, settings) = (problem.skeleton, problem.chain, &problem.settings);
        let initial = match begin_solve(problem, state)? {
            SolveStart::Done(report) => {
                self.copy_chain_positions(chain, state.global);
                return Ok(report);
            }
            SolveStart::Iterate {
                initial_error,
                initial_rotation_error,
            } => (initial_error, initial_rotation_error),
        };
        let goal = problem.goal()?;
        if goal.rotation.is_some() || chain_has_limits(skeleton, chain) {
            return self.solve_constrained(problem, state, initial);
        }
        let initial_error = initial.0;
        let target = goal.position;
        let (pose, global) = (&mut *state.pose, &mut *state.global);
        self.copy_chain_positions(chain, global);
        let (mut error, stop, passes) = self.run_passes(chain, target, initial_error, settings);
        let stop_is_refine = stop.is_none();
        self.stats.passes = passes;
        if passes == 0 {
            // A cap of 0: nothing was done and the pose is untouched.
            return Ok(measure(
                problem,
                state,
                goal,
                0,
                initial,
                stop.unwrap_or(StopReason::IterationCap),
            ));
        }

        let joints = chain.joints();
        let n = chain.bone_count();
        let lengths = chain.bone_lengths();
        let mut stop = stop.unwrap_or(StopReason::Stalled);
        if stop_is_refine {
            // Refine on bone vectors, then rebuild the positions from the base: the
            // rotations are still recovered once, below.
            //
            // Both conversions restore every bone's rest length. A bone vector taken as
            // the difference of two positions carries their round-off, `u |P|` whatever
            // the bone's length: a 1.7e-3 bone that a pass left 240 units out comes back
            // 6.6e-15 (4e-12 of it) short, and the refinement, which only rotates bones,
            // would carry that error home to wherever the bone ends up (near the origin,
            // where its endpoints round to 3e-17). The refinement's rotations and the
            // unfolding kick also keep lengths only to a few `u` per step, so the sum
            // renormalizes again: the rebuilt positions are then exact to the round-off
            // of the running sum, `u |P|` at each joint's own position.
            self.bones.clear();
            self.bones.extend(
                self.positions
                    .windows(2)
                    .zip(lengths)
                    .map(|(w, &length)| with_length(w[1] - w[0], length)),
            );
            let base = self.positions[0];
            // The error is measured again on forward kinematics of the result below.
            stop = self.refine(base, target, error, passes, settings).1;
            let mut p = base;
            for ((position, bone), &length) in
                self.positions[1..].iter_mut().zip(&self.bones).zip(lengths)
            {
                p += with_length(*bone, length);
                *position = p;
            }
        }

        // Recover the rotations once, base outwards. Each bone turns by the minimal
        // rotation from its current direction (its global rotation from the starting pose)
        // to its solved one, which keeps the bone's twist; then
        // L[j] = G_new[parent]^-1 G_new[j] with the parent's new global rotation (the
        // base's parent is outside the chain and keeps its rotation).
        self.recover_rotations(skeleton, chain, pose, global)?;
        error = global.positions[chain.effector()].distance(target);

        if error > initial_error {
            // Never hand back something worse than the start.
            for (&j, &saved) in joints[..n].iter().zip(&self.saved) {
                pose.rotations[j] = saved;
            }
            skeleton.forward_kinematics_from(pose, joints[0], global)?;
            self.copy_chain_positions(chain, global);
            self.stats.restored_start = true;
            error = global.positions[chain.effector()].distance(target);
            stop = StopReason::Stalled;
        }
        if error <= settings.tolerance {
            stop = StopReason::Converged;
        } else if stop == StopReason::Converged {
            // The solved positions met the tolerance but forward kinematics of the
            // rotations lands a rounding error outside it: no further progress possible.
            stop = StopReason::Stalled;
        }
        if turn_towards_pole(problem, state)? {
            self.copy_chain_positions(chain, state.global);
        }
        Ok(measure(
            problem,
            state,
            goal,
            self.stats.passes + self.stats.refinement_steps,
            initial,
            stop,
        ))
    }
}
