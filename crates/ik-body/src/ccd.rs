//! Cyclic coordinate descent on a tree with several effectors.
//!
//! A sweep visits the movable joints from the leaves to the root. Each joint takes the
//! rotation about its own position that best brings every effector below it onto its goal
//! in the weighted least-squares sense: for the positions, the pairs (joint to effector,
//! joint to goal) weighted by the squared position weight; for a rotation goal, the
//! effector's three frame axes paired with the goal's, weighted by half the squared
//! rotation weight (so that a small angle `theta` costs `w^2 theta^2`, as in the cost).
//! That best rotation is Horn's closed form ([`BestRotation`]). The turned joint is
//! projected onto its limit and forward kinematics redone from it; the turn is kept only
//! when it lowers the cost of the effectors below the joint (and moves no pin), so the
//! cost never increases. When the body may translate, a sweep ends with the translation
//! that best fits the position residuals (their weighted mean), kept on the same terms.
//!
//! The solve stops when every effector is within tolerance, at the iteration cap, or when a
//! sweep no longer lowers the cost. With `finish` on, the damped least-squares finish of
//! the FABRIK solver takes over from there (after at most `max_sweeps` sweeps).

use crate::BodySolver;
use crate::common::{Begin, Common};
use crate::horn::BestRotation;
use crate::problem::{BodyProblem, BodyReport, BodyState, all_within, forward_kinematics_from};
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::{IkError, StopReason};
use sinew_skeleton::limits::JointLimit;

/// Options of [`TreeCcdSolver`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct TreeCcdOptions {
    /// Whether the damped least-squares finish runs once the sweeps stop. Default: off,
    /// plain CCD.
    pub finish: bool,
    /// The most sweeps before the finish takes over (each counts as one iteration, and
    /// the finish's steps share the iteration cap). Ignored without the finish.
    pub max_sweeps: usize,
}

impl Default for TreeCcdOptions {
    fn default() -> Self {
        Self {
            finish: false,
            max_sweeps: 10,
        }
    }
}

impl TreeCcdOptions {
    /// CCD sweeps then the damped least-squares finish.
    #[must_use]
    pub fn with_finish() -> Self {
        Self {
            finish: true,
            ..Self::default()
        }
    }

    /// Checks the options (every combination is valid today).
    pub fn validate(&self) -> Result<(), IkError> {
        Ok(())
    }
}

/// Tree CCD; see the [module docs](self).
///
/// # Example
///
/// Plain CCD lowers the weighted cost of a feasible goal set; with the damped
/// least-squares finish it reaches every goal to the tolerance.
///
/// ```
/// use sinew_ik_body::{BodyProblem, BodySolver, BodyState, TreeCcdOptions, TreeCcdSolver, workload};
/// use sinew_skeleton::ik::SolveSettings;
///
/// let skeleton = workload::humanoid()?;
/// let goals = &workload::goal_sets(&skeleton, 1, 7, false)[0];
/// let settings = SolveSettings::default();
/// let problem =
///     BodyProblem::new(&skeleton, &goals.effectors, settings).with_root_translation(true);
///
/// let mut state = BodyState::rest(&skeleton);
/// let plain = TreeCcdSolver::new().solve(&problem, &mut state)?;
/// assert!(plain.cost < plain.initial_cost, "{plain:?}");
///
/// let mut state = BodyState::rest(&skeleton);
/// let mut finished = TreeCcdSolver::with_options(TreeCcdOptions::with_finish())?;
/// let report = finished.solve(&problem, &mut state)?;
/// assert!(report.within(&settings), "{report:?}");
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug, Default)]
pub struct TreeCcdSolver {
    options: TreeCcdOptions,
    common: Common,
}

impl TreeCcdSolver {
    /// Plain tree CCD.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// The solver with `options`, validated.
    pub fn with_options(options: TreeCcdOptions) -> Result<Self, IkError> {
        options.validate()?;
        Ok(Self {
            options,
            ..Self::default()
        })
    }

    /// The weighted cost of the effectors movable joint `m` moves.
    fn cost_below(&self, m: usize, state: &BodyState) -> f64 {
        self.common
            .topology
            .below(m)
            .iter()
            .map(|&e| self.common.targets[e].cost(&state.global))
            .sum()
    }

    /// Turns movable joint `m` by its best rotation, keeping it only if it helps.
    fn turn(
        &self,
        problem: &BodyProblem<'_>,
        m: usize,
        state: &mut BodyState,
    ) -> Result<(), IkError> {
        let skeleton = problem.skeleton;
        let j = self.common.topology.movable()[m];
        if matches!(skeleton.limit(j), JointLimit::Fixed) {
            return Ok(());
        }
        let at = state.global.positions[j];
        let mut best = BestRotation::new();
        for &e in self.common.topology.below(m) {
            let t = &self.common.targets[e];
            if t.joint != j {
                best.add(
                    state.global.positions[t.joint] - at,
                    t.position - at,
                    t.position_weight * t.position_weight,
                );
            }
            if t.has_rotation()
                && let Some(goal) = t.rotation
            {
                let frame = state.global.rotations[t.joint];
                for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
                    best.add(
                        frame * axis,
                        goal * axis,
                        0.5 * t.rotation_weight * t.rotation_weight,
                    );
                }
            }
        }
        let q = best.rotation();
        if q == DQuat::IDENTITY {
            return Ok(());
        }
        let before = self.cost_below(m, state);
        let kept = state.pose.rotations[j];
        let parent_rotation = skeleton
            .parent(j)
            .map_or(DQuat::IDENTITY, |p| state.global.rotations[p]);
        let turned = (parent_rotation.conjugate() * q * state.global.rotations[j]).normalize();
        let limit = skeleton.prepared_limit(j);
        state.pose.rotations[j] = if matches!(limit.limit(), JointLimit::Free) {
            turned
        } else {
            limit.project(turned)
        };
        forward_kinematics_from(
            skeleton,
            &state.pose,
            state.root_translation,
            j,
            &mut state.global,
        )?;
        if !(self.cost_below(m, state) < before && self.common.pins_hold(problem, state)) {
            state.pose.rotations[j] = kept;
            forward_kinematics_from(
                skeleton,
                &state.pose,
                state.root_translation,
                j,
                &mut state.global,
            )?;
        }
        Ok(())
    }

    /// Moves the body by the weighted mean position residual, if that helps.
    fn translate(&self, problem: &BodyProblem<'_>, state: &mut BodyState) -> Result<(), IkError> {
        let (mut sum, mut weight) = (DVec3::ZERO, 0.0);
        for t in &self.common.targets {
            let w = t.position_weight * t.position_weight;
            sum += (t.position - state.global.positions[t.joint]) * w;
            weight += w;
        }
        if weight == 0.0 || sum == DVec3::ZERO {
            return Ok(());
        }
        let before = self.common.cost(state);
        let kept = state.root_translation;
        state.root_translation += sum / weight;
        state.update_global(problem.skeleton)?;
        if !(self.common.cost(state) < before && self.common.pins_hold(problem, state)) {
            state.root_translation = kept;
            state.update_global(problem.skeleton)?;
        }
        Ok(())
    }
}

impl BodySolver for TreeCcdSolver {
    fn name(&self) -> &'static str {
        "ccd"
    }

    fn solve(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
    ) -> Result<BodyReport, IkError> {
        if let Begin::Done(report) = self.common.begin(problem, state, false, false, false)? {
            return Ok(report);
        }
        let settings = &problem.settings;
        let mut iterations = 0;
        let mut cost = self.common.cost(state);
        let stop = loop {
            if all_within(&self.common.targets, &state.global, settings) {
                break StopReason::Converged;
            }
            if iterations >= settings.max_iterations
                || (self.options.finish && iterations >= self.options.max_sweeps)
            {
                break StopReason::IterationCap;
            }
            for m in (0..self.common.topology.movable().len()).rev() {
                self.turn(problem, m, state)?;
            }
            if problem.root_translates {
                self.translate(problem, state)?;
            }
            iterations += 1;
            let new_cost = self.common.cost(state);
            if new_cost >= cost || new_cost.is_nan() {
                break StopReason::Stalled;
            }
            cost = new_cost;
        };
        let (iterations, stop) = if self.options.finish && stop != StopReason::Converged {
            // The finish's steps share the cap with the sweeps.
            let finished = self.common.finish(
                problem,
                state,
                iterations.min(settings.max_iterations),
                false,
            )?;
            (iterations + finished.steps, finished.stop)
        } else {
            (iterations, stop)
        };
        self.common.report(problem, state, iterations, stop, false)
    }
}
