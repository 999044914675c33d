//! sinew-ik-ccd: cyclic coordinate descent (CCD) inverse kinematics on a chain inside a
//! sinew skeleton.
//!
//! [`CcdSolver`] implements [`sinew_skeleton::ik::IkSolver`]. One *sweep* visits the
//! chain's joints from the one before the effector down to the base; at each joint `j`
//! it turns the bone subtree by the minimal rotation `q` taking "joint to effector" onto
//! "joint to target". `q` is a world-space rotation, so it is composed in the joint's
//! local frame, `L[j] <- G[p]^-1 q G[p] L[j]` with `p` the parent of `j` (the lab
//! report's CCD composes `q` onto `L[j]` directly, which is right only for a root: see
//! `docs/ik-ccd.md`).
//!
//! Cost: a sweep is O(n) for a chain of n bones. Within a sweep only the effector moves
//! as far as the joints still to be visited are concerned (rotating joint `j` moves its
//! descendants, never the joints below it nor their parents' rotations), so the effector
//! is rotated about `P[j]` in O(1) and forward kinematics runs once per sweep, from the
//! base, to measure the true error and to stop rounding drift.
//!
//! Joint limits: after its correction, each joint's local rotation is projected onto its
//! limit ([`sinew_skeleton::limits::JointLimit::project`]), and the effector is carried
//! by the turn actually applied, so the O(1) update stays exact. A projected step can
//! raise the error; the sweep that does is undone. The first time that happens the
//! sweeps start again from a second seed (every limited joint at the centre of its
//! range), with the iterations left, and the better of the two ends is kept
//! ([`SolveReport::restarted`]); the solve stops at the best pose it found with
//! [`StopReason::LocalMinimum`] (the best reachable within the limits for CCD). Targets
//! out of reach are not straightened through the limits: CCD iterates.
//!
//! The finish (on by default, [`CcdOptions::finish`]): the sweeps stop at the first one
//! that keeps more than [`SWITCH_RATIO`] of the error ([`PLAIN_SWITCH_RATIO`] without
//! extrapolation), and the damped least-squares finish
//! every sinew solver shares ([`sinew_skeleton::finish::ChainFinish`]) converges from
//! there, sliding along the joint limits, with the same second seed; it also solves
//! rotation goals, which plain CCD refuses. On W7 it takes CCD from 95.8% to all 2 000
//! feasible targets within 1e-6 (`docs/ik-ccd.md`).
//!
//! Stop rules, reported in [`StopReason`]: within the tolerance
//! ([`StopReason::Converged`]), the iteration cap ([`StopReason::IterationCap`]), or a
//! sweep that did not reduce the error ([`StopReason::Stalled`]; a sweep that made the
//! error larger, which only rounding can cause, is undone, so a report never shows an
//! error above the initial one). Targets out of reach and targets already within the
//! tolerance are handled by [`sinew_skeleton::ik::begin_solve`] with 0 sweeps.
//!
//! Acceleration (measured in `docs/bench/ik-ccd.md`):
//! - Sweep extrapolation, on in [`CcdSolver::new`] (the default), off in
//!   [`CcdSolver::plain`]. CCD's tail is linear convergence: successive sweeps change
//!   the rotations by nearly proportional amounts. After each sweep that reduced the
//!   error by the ratio `r`, one step of `r / (1 - r)` times that sweep's change is
//!   tried and kept only if it lowers the error further, so the error still never
//!   increases across a sweep. On W1 it turns 42.6 sweeps per frame (88 of 500 frames
//!   missing 1e-6 at the cap of 100) into 4.2 (none missing).
//! - Over-relaxation, [`CcdSolver::with_relaxation`]: each joint turns by `q^omega`,
//!   `omega` in `[1, 2)`; any `omega` in `[0, 2]` keeps every joint step non-increasing
//!   (the distance after turning by `phi` about `q`'s axis is symmetric about the full
//!   angle). Measured slower than plain CCD on W1 and W2, so off by default.
//!
//! ```
//! use sinew_ik_ccd::{CcdSolver, DVec3};
//! use sinew_skeleton::ik::{
//!     Chain, EffectorGoal, IkProblem, IkSolver, IkState, SolveSettings, StopReason,
//! };
//! use sinew_skeleton::{GlobalPose, Skeleton};
//!
//! // Four bones of 0.25 along x from the origin (reach 1), solved for a point inside it.
//! let arm = Skeleton::chain(DVec3::ZERO, &[DVec3::new(0.25, 0.0, 0.0); 4]).unwrap();
//! let chain = Chain::whole(&arm).unwrap();
//! let target = DVec3::new(0.3, 0.5, 0.2);
//! let goals = [EffectorGoal::at(chain.effector(), target)];
//! let problem = IkProblem::new(&arm, &chain, &goals, SolveSettings::default());
//!
//! let mut pose = arm.rest_pose();
//! let mut global = GlobalPose::new();
//! arm.forward_kinematics(&pose, &mut global).unwrap();
//! let mut solver = CcdSolver::new();
//! let report = solver.solve(&problem, &mut IkState::new(&mut pose, &mut global)).unwrap();
//!
//! // The report says how it ended; the pose and its forward kinematics agree with it.
//! assert_eq!(report.stop, StopReason::Converged);
//! assert!(report.error < 1e-6 && report.error < report.initial_error);
//! let effector = global.positions[chain.effector()];
//! assert!(((effector - target).length() - report.error).abs() < 1e-12);
//! // Rotations never stretch a bone.
//! assert!((global.positions[1] - global.positions[0]).length() - 0.25 < 1e-12);
//! ```

use sinew_math::rotation_between;
/// The math types targets and poses are given in, re-exported so a user of this crate
/// does not also have to depend on sinew-math.
pub use sinew_math::{DQuat, DVec3};
use sinew_skeleton::finish::ChainFinish;
use sinew_skeleton::ik::{
    Chain, IkError, IkProblem, IkSolver, IkState, SolveReport, SolveSettings, SolveStart,
    StopReason, begin_solve, chain_has_limits, measure, turn_towards_pole,
};
use sinew_skeleton::limits::JointLimit;
use sinew_skeleton::seed::limb_seed;
use sinew_skeleton::{GlobalPose, Pose, Skeleton, SkeletonError};

/// With the finish on, the extrapolated sweeps stop once a sweep leaves more than this
/// fraction of the error it started with: CCD's tail is linear convergence (and along a
/// limit's bound often a crawl), where each accepted least-squares step of the finish
/// roughly squares the error. A sweep with extrapolation that keeps up to 0.8 of the
/// error is still cheaper than handing over: with 0.5 the finish took over from sweeps
/// that were converging, and W1 tracking at tolerance 1e-12 took 4 308 iterations where
/// 0.8 takes 2 829 (scan and instruction counts in `docs/ik-ccd.md`).
pub const SWITCH_RATIO: f64 = 0.8;

/// [`SWITCH_RATIO`] for sweeps without extrapolation: a plain sweep that keeps more than
/// half of the error is already the slow tail (at 0.8 plain sweeps and the finish took
/// W1 to 5 839 iterations, at 0.5 2 160).
pub const PLAIN_SWITCH_RATIO: f64 = 0.5;

/// The over-relaxation factor [`CcdSolver::new`] uses: none, since over-relaxation
/// measured slower than plain CCD on W1 and W2 (`docs/bench/ik-ccd.md`).
pub const DEFAULT_RELAXATION: f64 = 1.0;

/// The options of a [`CcdSolver`], beyond the shared settings: what scene files and the
/// solver registry spell `Ccd(...)`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct CcdOptions {
    /// Sweep extrapolation (default true); `false` with relaxation 1 is plain CCD.
    pub extrapolation: bool,
    /// The over-relaxation factor `omega`, in `[1, 2)` (default [`DEFAULT_RELAXATION`]).
    pub relaxation: f64,
    /// End with the damped least-squares finish every solver shares
    /// ([`sinew_skeleton::finish`], default true): the sweeps make the large move and
    /// stop once a sweep keeps more than [`SWITCH_RATIO`] of the error
    /// ([`PLAIN_SWITCH_RATIO`] without extrapolation), then the finish
    /// converges, sliding along the joint limits, and solves rotation goals too. Off,
    /// CCD sweeps to the end and refuses a rotation goal.
    pub finish: bool,
}

impl Default for CcdOptions {
    fn default() -> Self {
        Self {
            extrapolation: true,
            relaxation: DEFAULT_RELAXATION,
            finish: true,
        }
    }
}

impl CcdOptions {
    /// Plain CCD: no extrapolation, no relaxation, no finish.
    #[must_use]
    pub fn plain() -> Self {
        Self {
            extrapolation: false,
            relaxation: 1.0,
            finish: false,
        }
    }

    /// Checks the relaxation is in `[1, 2)`.
    pub fn validate(&self) -> Result<(), IkError> {
        if (1.0..2.0).contains(&self.relaxation) {
            Ok(())
        } else {
            Err(IkError::InvalidSettings(format!(
                "CCD relaxation must be in [1, 2), got {}",
                self.relaxation
            )))
        }
    }
}

/// Cyclic coordinate descent IK solver. Holds only a scratch buffer (the chain's local
/// rotations before the current sweep, so a sweep that increases the error can be
/// undone); a solve allocates nothing once the buffer has grown to the chain's size.
///
/// A target out of reach is answered in closed form, the chain straightened towards it
/// with no sweep at all; the error left is then the distance beyond the reach:
///
/// ```
/// use sinew_ik_ccd::{CcdSolver, DVec3};
/// use sinew_skeleton::ik::{
///     Chain, EffectorGoal, IkProblem, IkSolver, IkState, SolveSettings, StopReason,
/// };
/// use sinew_skeleton::{GlobalPose, Skeleton};
///
/// let arm = Skeleton::chain(DVec3::ZERO, &[DVec3::X; 3]).unwrap();
/// let chain = Chain::whole(&arm).unwrap();
/// let far = DVec3::new(0.0, 5.0, 0.0);
/// let goals = [EffectorGoal::at(chain.effector(), far)];
/// let problem = IkProblem::new(&arm, &chain, &goals, SolveSettings::default());
/// let (mut pose, mut global) = (arm.rest_pose(), GlobalPose::new());
/// let report = CcdSolver::plain()
///     .solve(&problem, &mut IkState::new(&mut pose, &mut global))
///     .unwrap();
/// assert_eq!((report.stop, report.iterations), (StopReason::OutOfReach, 0));
/// assert!((report.error - 2.0).abs() < 1e-12);
/// assert!((global.positions[3] - DVec3::new(0.0, 3.0, 0.0)).length() < 1e-12);
/// ```
#[derive(Clone, Debug)]
pub struct CcdSolver {
    relaxation: f64,
    extrapolate: bool,
    finish: bool,
    /// The damped least-squares finish and its buffers.
    finisher: ChainFinish,
    /// The chain's local rotations before the current sweep.
    saved: Vec<DQuat>,
    /// The chain's local rotations right after the current sweep.
    swept: Vec<DQuat>,
    /// The chain's local rotations at the end of the first descent, while a restart runs.
    best: Vec<DQuat>,
}

impl Default for CcdSolver {
    fn default() -> Self {
        Self::new()
    }
}

impl CcdSolver {
    /// The default solver: sweep extrapolation on, relaxation [`DEFAULT_RELAXATION`].
    #[must_use]
    pub fn new() -> Self {
        Self {
            relaxation: DEFAULT_RELAXATION,
            extrapolate: true,
            finish: true,
            finisher: ChainFinish::default(),
            saved: Vec::new(),
            swept: Vec::new(),
            best: Vec::new(),
        }
    }

    /// Plain CCD: every joint turns by exactly the minimal rotation (`omega = 1`), no
    /// sweep extrapolation, no finish.
    #[must_use]
    pub fn plain() -> Self {
        Self {
            relaxation: 1.0,
            extrapolate: false,
            finish: false,
            finisher: ChainFinish::default(),
            saved: Vec::new(),
            swept: Vec::new(),
            best: Vec::new(),
        }
    }

    /// Plain CCD turning each joint by `q^omega` instead of `q` (over-relaxation), no
    /// extrapolation (add it with [`CcdSolver::with_extrapolation`]).
    /// `omega` must be in `[1, 2)`: below 1 only slows CCD down, and at 2 a joint step
    /// no longer reduces the error at all. An `Err` naming the value otherwise.
    pub fn with_relaxation(omega: f64) -> Result<Self, IkError> {
        Self::with_options(CcdOptions {
            relaxation: omega,
            ..CcdOptions::plain()
        })
    }

    /// A solver with the given options, validated.
    pub fn with_options(options: CcdOptions) -> Result<Self, IkError> {
        options.validate()?;
        Ok(Self {
            relaxation: options.relaxation,
            extrapolate: options.extrapolation,
            finish: options.finish,
            finisher: ChainFinish::default(),
            saved: Vec::new(),
            swept: Vec::new(),
            best: Vec::new(),
        })
    }

    /// The options this solver runs with.
    #[must_use]
    pub fn options(&self) -> CcdOptions {
        CcdOptions {
            extrapolation: self.extrapolate,
            relaxation: self.relaxation,
            finish: self.finish,
        }
    }

    /// The same solver with sweep extrapolation on or off (see `docs/ik-ccd.md`).
    #[must_use]
    pub fn with_extrapolation(mut self, on: bool) -> Self {
        self.extrapolate = on;
        self
    }

    /// The same solver with the damped least-squares finish on or off (see
    /// [`CcdOptions::finish`]).
    #[must_use]
    pub fn with_finish(mut self, on: bool) -> Self {
        self.finish = on;
        self
    }

    /// Whether the solve ends with the damped least-squares finish.
    #[must_use]
    pub fn finish(&self) -> bool {
        self.finish
    }

    /// Whether sweep extrapolation is on.
    #[must_use]
    pub fn extrapolation(&self) -> bool {
        self.extrapolate
    }

    /// The over-relaxation factor `omega` (1 for plain CCD).
    #[must_use]
    pub fn relaxation(&self) -> f64 {
        self.relaxation
    }

    /// One CCD sweep (from the joint before the effector down to the base), then forward
    /// kinematics from the base. Returns the effector-to-target distance afterwards.
    ///
    /// `global` should hold forward kinematics of `pose` (it is recomputed when its size
    /// does not match the skeleton). Unlike [`IkSolver::solve`], no early exit and no
    /// undo: this is the raw step, exposed so the property "a sweep never increases the
    /// error" can be checked from outside. An `Err` for a NaN or infinite target, a
    /// chain built for another skeleton, or a pose of the wrong size or with an invalid
    /// rotation.
    pub fn sweep(
        &self,
        skeleton: &Skeleton,
        chain: &Chain,
        pose: &mut Pose,
        global: &mut GlobalPose,
        target: DVec3,
    ) -> Result<f64, IkError> {
        if !target.is_finite() {
            return Err(IkError::NonFiniteTarget { target });
        }
        chain.check_skeleton(skeleton)?;
        if pose.rotations.len() != skeleton.len() {
            return Err(SkeletonError::PoseLength {
                expected: skeleton.len(),
                got: pose.rotations.len(),
            }
            .into());
        }
        if global.positions.len() != skeleton.len() || global.rotations.len() != skeleton.len() {
            skeleton.forward_kinematics(pose, global)?;
        }
        Ok(sweep_unchecked(
            self.relaxation,
            skeleton,
            chain,
            pose,
            global,
            target,
        )?)
    }
}

impl IkSolver for CcdSolver {
    fn name(&self) -> &'static str {
        "ccd"
    }

    fn solve(
        &mut self,
        problem: &IkProblem<'_>,
        state: &mut IkState<'_>,
    ) -> Result<SolveReport, IkError> {
        let (initial_error, initial_rotation_error) = match begin_solve(problem, state)? {
            SolveStart::Done(report) => return Ok(report),
            SolveStart::Iterate {
                initial_error,
                initial_rotation_error,
            } => (initial_error, initial_rotation_error),
        };
        let goal = problem.goal()?;
        if goal.rotation.is_some() && !self.finish {
            return Err(IkError::InvalidGoal {
                goal: 0,
                field: "rotation",
                reason: "CCD without its finish solves position goals only (turn \
                         CcdOptions::finish on for a rotation goal)"
                    .into(),
            });
        }
        let (skeleton, chain, settings) = (problem.skeleton, problem.chain, &problem.settings);
        let (pose, global) = (&mut *state.pose, &mut *state.global);
        let target = goal.position;
        let movable = &chain.joints()[..chain.bone_count()];
        self.saved.clear();
        self.saved.resize(movable.len(), DQuat::IDENTITY);
        self.swept.clear();
        self.swept.resize(movable.len(), DQuat::IDENTITY);
        let switch = match (self.finish, self.extrapolate) {
            (false, _) => 1.0,
            (true, true) => SWITCH_RATIO,
            (true, false) => PLAIN_SWITCH_RATIO,
        };
        // A limb (a three-degree-of-freedom base joint, then a hinge) with a position
        // goal tries its closed-form pose first, which usually reaches the target
        // outright. It is kept only when it does: started from the seed, the sweeps and
        // the finish lost a W7 target that they reach from the pose given.
        let mut initial_error = initial_error;
        if self.finish && goal.rotation.is_none() && settings.max_iterations > 0 {
            self.best.clear();
            self.best.extend(movable.iter().map(|&j| pose.rotations[j]));
            let base_parent = skeleton
                .parent(chain.base())
                .map_or(DQuat::IDENTITY, |p| global.rotations[p]);
            let base = global.positions[chain.base()];
            if limb_seed(skeleton, chain, pose, base, base_parent, target) {
                skeleton.forward_kinematics_from(pose, chain.base(), global)?;
                let seeded = global.positions[chain.effector()].distance(target);
                if seeded <= settings.tolerance {
                    initial_error = seeded;
                } else {
                    for (&kept, &j) in self.best.iter().zip(movable) {
                        pose.rotations[j] = kept;
                    }
                    skeleton.forward_kinematics_from(pose, chain.base(), global)?;
                }
            }
        }
        let (mut stop, mut error, mut iterations) = if initial_error <= settings.tolerance {
            (StopReason::Converged, initial_error, 0)
        } else {
            self.descend(
                skeleton,
                chain,
                pose,
                global,
                target,
                settings,
                initial_error,
                0,
                switch,
            )?
        };
        let mut restarted = false;
        if self.finish {
            // The sweeps stopped at the tolerance, the cap, a local minimum or a slow
            // sweep: the finish takes over unless both errors are met, with the second
            // seed of the chain solvers when it ends in a local minimum.
            let (position, rotation) = goal.errors(global);
            let met = position <= settings.tolerance && rotation <= settings.rotation_tolerance;
            if !met && iterations < settings.max_iterations {
                let (finished, restart) = self
                    .finisher
                    .run_restarting(skeleton, chain, goal, pose, global, settings, iterations)?;
                iterations += finished.steps;
                restarted = restart;
                stop = finished.stop;
                if stop == StopReason::LocalMinimum && !chain_has_limits(skeleton, chain) {
                    // Nothing but the goal holds the chain: the finish simply stopped
                    // helping.
                    stop = StopReason::Stalled;
                }
            } else if !met && stop == StopReason::Converged {
                // The position was met by the sweeps at the cap, the rotation was not.
                stop = StopReason::IterationCap;
            }
            error = global.positions[chain.effector()].distance(target);
        } else if stop == StopReason::LocalMinimum && iterations < settings.max_iterations {
            // CCD is local: a limit can hold it away from a target that another branch of
            // the chain's poses reaches. Run once more from a second seed, every limited
            // joint at the centre of its range, and keep the better end.
            self.best.clear();
            self.best.extend(movable.iter().map(|&j| pose.rotations[j]));
            for &j in movable {
                if let Some(seed) = skeleton.limit(j).centre() {
                    pose.rotations[j] = seed;
                }
            }
            skeleton.forward_kinematics_from(pose, chain.base(), global)?;
            let seeded = global.positions[chain.effector()].distance(target);
            let second = self.descend(
                skeleton, chain, pose, global, target, settings, seeded, iterations, 1.0,
            )?;
            restarted = true;
            iterations = second.2;
            if second.1 < error {
                (stop, error) = (second.0, second.1);
            } else {
                for (&kept, &j) in self.best.iter().zip(movable) {
                    pose.rotations[j] = kept;
                }
                skeleton.forward_kinematics_from(pose, chain.base(), global)?;
            }
        }
        // A pole turns the solved chain about its base-effector line (the effector stays).
        turn_towards_pole(problem, state)?;
        // The report measures the error again, with the rotation and limit figures, on
        // the same forward kinematics the loop measured.
        let report = measure(
            problem,
            state,
            goal,
            iterations,
            (initial_error, initial_rotation_error),
            stop,
        );
        debug_assert!((report.error - error).abs() <= 1e-9 * (1.0 + error));
        let mut report = report;
        report.restarted = restarted;
        Ok(report)
    }
}

impl CcdSolver {
    /// Sweeps from the current pose (`error` its effector distance, `iterations` already
    /// spent) until the tolerance, the cap, a sweep that does not lower the error
    /// (undone), or a sweep that keeps more than `switch` of the error
    /// ([`StopReason::Stalled`]; never for a `switch` of 1). Returns the stop reason, the
    /// error and the iterations spent in all.
    #[allow(clippy::too_many_arguments)]
    fn descend(
        &mut self,
        skeleton: &Skeleton,
        chain: &Chain,
        pose: &mut Pose,
        global: &mut GlobalPose,
        target: DVec3,
        settings: &SolveSettings,
        mut error: f64,
        mut iterations: usize,
        switch: f64,
    ) -> Result<(StopReason, f64, usize), IkError> {
        let has_limits = chain_has_limits(skeleton, chain);
        let movable = &chain.joints()[..chain.bone_count()];
        let stop = loop {
            if iterations >= settings.max_iterations {
                break StopReason::IterationCap;
            }
            for (saved, &j) in self.saved.iter_mut().zip(movable) {
                *saved = pose.rotations[j];
            }
            let swept = sweep_unchecked(self.relaxation, skeleton, chain, pose, global, target)?;
            iterations += 1;
            if swept <= settings.tolerance {
                error = swept;
                break StopReason::Converged;
            }
            if swept >= error {
                if swept > error {
                    // Only rounding can make a sweep worse (each joint step is
                    // non-increasing in exact arithmetic); keep the better pose.
                    for (&saved, &j) in self.saved.iter().zip(movable) {
                        pose.rotations[j] = saved;
                    }
                    skeleton.forward_kinematics_from(pose, chain.base(), global)?;
                }
                break if has_limits {
                    StopReason::LocalMinimum
                } else {
                    StopReason::Stalled
                };
            }
            let ratio = swept / error;
            error = swept;
            if ratio > switch {
                break StopReason::Stalled;
            }
            if self.extrapolate {
                error = self.extrapolate(skeleton, chain, pose, global, target, error, ratio)?;
                if error <= settings.tolerance {
                    break StopReason::Converged;
                }
            }
        };
        Ok((stop, error, iterations))
    }

    /// Sweep extrapolation: CCD's tail is linear convergence, each sweep changing the
    /// joint rotations by nearly the same amount as the one before, shrinking by the
    /// ratio `r` of successive errors. Continuing that geometric series to its sum is a
    /// step of `r / (1 - r)` times the last sweep's change. The step is tried on the
    /// local rotations (linear extrapolation of the quaternions, normalized) and kept
    /// only if it lowers the error, so the error still never increases.
    #[allow(clippy::too_many_arguments)]
    fn extrapolate(
        &mut self,
        skeleton: &Skeleton,
        chain: &Chain,
        pose: &mut Pose,
        global: &mut GlobalPose,
        target: DVec3,
        error: f64,
        ratio: f64,
    ) -> Result<f64, SkeletonError> {
        let movable = &chain.joints()[..chain.bone_count()];
        let factor = (ratio / (1.0 - ratio)).min(MAX_EXTRAPOLATION);
        if factor.is_nan() || factor <= 0.0 {
            return Ok(error);
        }
        for ((swept, &before), &j) in self.swept.iter_mut().zip(&self.saved).zip(movable) {
            let after = pose.rotations[j];
            *swept = after;
            // q and -q are one rotation: extrapolate from the representative nearer
            // to `after`, so a sign flip is not read as a large change.
            let before = if before.dot(after) < 0.0 {
                -before
            } else {
                before
            };
            // Extrapolated rotations are projected onto the limits like any other.
            let extrapolated = (after + (after - before) * factor).normalize();
            let limit = skeleton.prepared_limit(j);
            pose.rotations[j] = if matches!(limit.limit(), JointLimit::Free) {
                extrapolated
            } else {
                limit.project(extrapolated)
            };
        }
        skeleton.forward_kinematics_from(pose, chain.base(), global)?;
        let tried = global.positions[chain.effector()].distance(target);
        if tried < error {
            return Ok(tried);
        }
        for (&swept, &j) in self.swept.iter().zip(movable) {
            pose.rotations[j] = swept;
        }
        skeleton.forward_kinematics_from(pose, chain.base(), global)?;
        Ok(error)
    }
}

/// The largest extrapolation factor tried (an error ratio of 0.97 per sweep).
const MAX_EXTRAPOLATION: f64 = 32.0;

/// One sweep without input checks: `global` must be forward kinematics of `pose`.
///
/// Why the O(1) update per joint is exact: turning joint `j` changes the global frames of
/// `j`'s descendants only. Every joint still to be visited in this sweep is an ancestor
/// of `j` (the sweep goes down the chain), so its position `P[k]` and its parent's
/// rotation `G[parent(k)]` are still those of `global`, computed before the sweep; only
/// the effector moved, and it is carried along by rotating it about `P[j]`.
fn sweep_unchecked(
    relaxation: f64,
    skeleton: &Skeleton,
    chain: &Chain,
    pose: &mut Pose,
    global: &mut GlobalPose,
    target: DVec3,
) -> Result<f64, SkeletonError> {
    let joints = chain.joints();
    let mut effector = global.positions[chain.effector()];
    for &j in joints[..chain.bone_count()].iter().rev() {
        let pivot = global.positions[j];
        let to_effector = effector - pivot;
        // The identity when either vector has no direction (effector or target on the
        // joint): the joint is skipped. Antiparallel: a defined half turn.
        let mut turn = aim(to_effector, target - pivot);
        if turn == DQuat::IDENTITY {
            continue;
        }
        if relaxation != 1.0 {
            turn = power(turn, relaxation);
        }
        // `turn` acts in world space; in the frame of `j`'s parent it is the same
        // rotation with its axis expressed in that frame: G[p]^-1 q G[p].
        let local_turn = match skeleton.parent(j) {
            Some(p) => {
                let axis = global.rotations[p].conjugate() * turn.xyz();
                DQuat::from_xyzw(axis.x, axis.y, axis.z, turn.w)
            }
            None => turn,
        };
        let turned = (local_turn * pose.rotations[j]).normalize();
        let limit = skeleton.prepared_limit(j);
        if matches!(limit.limit(), JointLimit::Free) {
            pose.rotations[j] = turned;
            effector = pivot + turn * to_effector;
        } else {
            // The joint's limit may take part of the turn back: project, then carry the
            // effector by the turn actually applied, G[p] (new old^-1) G[p]^-1.
            let old = pose.rotations[j].normalize();
            let new = limit.project(turned);
            pose.rotations[j] = new;
            let applied_local = (new * old.conjugate()).normalize();
            let applied = match skeleton.parent(j) {
                Some(p) => {
                    let axis = global.rotations[p] * applied_local.xyz();
                    DQuat::from_xyzw(axis.x, axis.y, axis.z, applied_local.w)
                }
                None => applied_local,
            };
            effector = pivot + applied * to_effector;
        }
    }
    skeleton.forward_kinematics_from(pose, chain.base(), global)?;
    Ok(global.positions[chain.effector()].distance(target))
}

/// The minimal rotation taking the direction of `from` onto that of `to`: the same as
/// [`rotation_between`] (which defines every degenerate case), with a fast path for the
/// case that dominates CCD's tail, an acute angle between vectors of moderate length.
/// There `q = (from x to, |from||to| + from . to)` normalized has no cancellation
/// (`w >= |from||to|`), and it costs one square root less than going through unit
/// vectors. Tiny or huge vectors, whose squared lengths could underflow or overflow,
/// take the careful path.
#[inline]
fn aim(from: DVec3, to: DVec3) -> DQuat {
    let d = from.dot(to);
    if d > 0.0 {
        let c = from.cross(to);
        let w = (from.length_squared() * to.length_squared()).sqrt() + d;
        let q = DQuat::from_xyzw(c.x, c.y, c.z, w);
        let n2 = q.length_squared();
        if n2 > 1e-280 && n2 < 1e280 {
            return q * (1.0 / n2.sqrt());
        }
    }
    rotation_between(from, to)
}

/// `q^omega` for a unit quaternion: the same axis, `omega` times the angle (taken in
/// `[0, pi]`).
fn power(q: DQuat, omega: f64) -> DQuat {
    let q = if q.w < 0.0 { -q } else { q };
    let v = q.xyz();
    let s = v.length();
    if s == 0.0 {
        return q;
    }
    let half = s.atan2(q.w) * omega;
    let (sin, cos) = half.sin_cos();
    let axis = v * (sin / s);
    DQuat::from_xyzw(axis.x, axis.y, axis.z, cos)
}

#[cfg(test)]
mod tests {
    use super::*;
    use sinew_skeleton::ik::rotation_angle;

    #[test]
    fn aim_agrees_with_rotation_between() {
        let dirs = [
            DVec3::X,
            DVec3::new(1.0, 1e-9, 0.0),
            DVec3::new(1.0, 2.0, 3.0),
            DVec3::new(-0.3, 0.1, -2.0),
            DVec3::new(1e-200, -1e-200, 3e-200),
            DVec3::new(5e200, -7e200, 0.25),
            DVec3::ZERO,
            -DVec3::X,
        ];
        for &a in &dirs {
            for &b in &dirs {
                let fast = aim(a, b);
                let careful = rotation_between(a, b);
                assert!(fast.is_finite());
                assert!(
                    rotation_angle(fast, careful) < 1e-14,
                    "{a} -> {b}: {fast} vs {careful}"
                );
            }
        }
    }

    #[test]
    fn power_scales_the_angle() {
        let q = DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 2.0) / 3.0, 0.8);
        let p = power(q, 1.5);
        let expected = DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 2.0) / 3.0, 1.2);
        assert!(rotation_angle(p, expected) < 1e-15);
        // Negative w: the same rotation, the angle taken in [0, pi].
        assert!(rotation_angle(power(-q, 1.5), expected) < 1e-15);
        assert_eq!(power(DQuat::IDENTITY, 1.7), DQuat::IDENTITY);
    }

    #[test]
    fn relaxation_is_validated() {
        assert!(CcdSolver::with_relaxation(1.5).is_ok());
        for bad in [0.5, 2.0, f64::NAN, f64::INFINITY] {
            let err = CcdSolver::with_relaxation(bad).unwrap_err();
            assert!(err.to_string().contains("relaxation"), "{err}");
        }
    }
}
