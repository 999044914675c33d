//! FABRIK on a tree with several effectors (Aristidou and Lasenby, "FABRIK: A fast,
//! iterative solver for the Inverse Kinematics problem", Graphical Models 73(5), 2011,
//! section on multiple end effectors), with joint limits and the damped least-squares
//! finish over all effectors.
//!
//! One pass on the joints that lead to an effector (the active joints):
//!
//! - Backward, leaves to root: an effector's joint goes to its goal; a joint where several
//!   branches meet (a sub-base) goes to the weighted centroid of the positions each branch
//!   asks for, each branch weighted by the total weight of the effectors below it (an
//!   effector in the middle of a chain adds its goal to that centroid); each joint then
//!   asks its parent to sit one bone length away, towards the parent's current position.
//! - Forward, root to leaves: the root stays where it is (or, when the body may
//!   translate, goes where the backward pass put it); each joint is placed one bone length
//!   from its parent towards its backward position.
//! - The positions become rotations once, root first: each joint takes the smallest
//!   rotation that aims its one child bone at the child's new position, or, at a sub-base,
//!   the best rotation for all its child bones (Horn's closed form, [`BestRotation`]),
//!   and is projected onto its limit; so a pass always ends in a pose inside the limits
//!   and forward kinematics of it is exact.
//!
//! A pass is kept only when it lowers the weighted cost (and leaves every pin in place);
//! the passes stop when one gains less than `switch_ratio`, and the damped least-squares
//! finish takes over, which reaches feasible goals to the tolerance instead of
//! approaching them. A finish that ends in a local minimum short of the goals may restart
//! (a warm frame first near its start, then from the centre of the joint limits and from
//! drawn poses); the best answer is returned.

use crate::BodySolver;
use crate::carry::Carried;
use crate::common::{Begin, Common, NEAR_ITERATIONS};
use crate::horn::BestRotation;
use crate::problem::{BodyProblem, BodyReport, BodyState, forward_kinematics};
use sinew_math::{DQuat, DVec3, rotation_between, try_unit};
use sinew_skeleton::ik::{IkError, StopReason};
use sinew_skeleton::limits::JointLimit;

/// Options of [`TreeFabrikSolver`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default, deny_unknown_fields))]
pub struct TreeFabrikOptions {
    /// The most FABRIK passes before the finish (each counts as one iteration). With the
    /// finish on, the first attempt is the finish alone and the passes start the
    /// restarts. Default 0: on the humanoid with its limits, the projected passes lead
    /// into worse basins than the finish alone (see `docs/ik-body.md`).
    pub max_passes: usize,
    /// A pass that leaves more than this fraction of the cost it started from hands over
    /// to the finish. In `[0, 1]`; 1 runs all `max_passes`.
    pub switch_ratio: f64,
    /// Whether the damped least-squares finish runs after the passes.
    pub finish: bool,
    /// How many times a finish that ends in a local minimum short of the goals may
    /// restart: first the finish alone from the starting pose (skipped without passes),
    /// then from the centre of the joint limits, then from poses drawn inside them (a
    /// fixed sequence, so a solve is reproducible). The restarts share the iteration
    /// cap; the best answer is returned. When it is not 0, a warm frame that continues a
    /// sequence (its state the last answer of this solver) first restarts once more, near
    /// its start: the joints on their bounds drawn a little inwards
    /// (`docs/ik-body.md`, "A warm frame's restart stays near the last answer").
    pub restarts: usize,
}

impl Default for TreeFabrikOptions {
    fn default() -> Self {
        Self {
            max_passes: 0,
            switch_ratio: 0.5,
            finish: true,
            restarts: 3,
        }
    }
}

impl TreeFabrikOptions {
    /// Plain tree FABRIK: passes only, up to the iteration cap, no finish, no restart.
    #[must_use]
    pub fn plain() -> Self {
        Self {
            max_passes: usize::MAX,
            switch_ratio: 1.0,
            finish: false,
            restarts: 0,
        }
    }

    /// Checks `switch_ratio` is in `[0, 1]`.
    pub fn validate(&self) -> Result<(), IkError> {
        if !(0.0..=1.0).contains(&self.switch_ratio) {
            return Err(IkError::InvalidSettings(format!(
                "switch_ratio must be in [0, 1], got {}",
                self.switch_ratio
            )));
        }
        Ok(())
    }
}

/// Tree FABRIK with the damped least-squares finish; see the [module docs](self).
///
/// # Example
///
/// Goals made by forward kinematics of a random pose inside the limits (so one exact
/// answer exists): both wrists, both ankles and the head, the hips free to move.
///
/// ```
/// use sinew_ik_body::{BodyProblem, BodySolver, BodyState, TreeFabrikSolver, workload};
/// use sinew_skeleton::ik::SolveSettings;
///
/// let skeleton = workload::humanoid()?;
/// let goals = &workload::goal_sets(&skeleton, 1, 7, false)[0];
/// let settings = SolveSettings::default();
/// let problem =
///     BodyProblem::new(&skeleton, &goals.effectors, settings).with_root_translation(true);
/// let mut state = BodyState::rest(&skeleton);
///
/// let mut solver = TreeFabrikSolver::new();
/// let report = solver.solve(&problem, &mut state)?;
/// assert!(report.within(&settings), "{report:?}");
/// assert!(report.cost <= report.initial_cost);
/// assert!(report.limit_violation <= 1e-9);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug, Default)]
pub struct TreeFabrikSolver {
    options: TreeFabrikOptions,
    common: Common,
    passes: Passes,
    /// The last answers, for the next warm frame's start.
    carried: Carried,
    /// Whether the last solve's answer came from its extrapolated start.
    from_prediction: bool,
    /// Whether `passes` holds this solve's topology.
    passes_ready: bool,
}

/// Buffers of the FABRIK passes.
#[derive(Clone, Debug, Default)]
struct Passes {
    /// Per joint: on a path to an effector.
    active: Vec<bool>,
    /// Per joint: the weighted sum of requested positions, and the weights.
    sum: Vec<DVec3>,
    weight: Vec<f64>,
    /// Per joint: backward and forward positions.
    backward: Vec<DVec3>,
    forward: Vec<DVec3>,
    /// Active children: `children[child_start[j]..child_start[j + 1]]`.
    child_start: Vec<usize>,
    children: Vec<usize>,
    /// Per joint: the target index of an effector on it, if any.
    effector: Vec<Option<usize>>,
}

impl TreeFabrikSolver {
    /// Asks the processor to bring what a warm solve of `state` reads first into its
    /// cache (a hint; see [`BodyBatch`]).
    ///
    /// [`BodyBatch`]: crate::BodyBatch
    pub(crate) fn prefetch(&self, state: &crate::BodyState) {
        self.common.prefetch();
        self.carried.prefetch();
        sinew_skeleton::prefetch::prefetch(&state.pose.rotations);
        state.global.prefetch();
    }

    /// Exchanges this solver's scratch buffers with `scratch` (see [`BodyBatch`]).
    ///
    /// [`BodyBatch`]: crate::BodyBatch
    pub(crate) fn swap_scratch(&mut self, scratch: &mut crate::common::SolveScratch) {
        scratch.swap_with(&mut self.common);
    }

    /// The solver with default options.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// The solver with `options`, validated.
    pub fn with_options(options: TreeFabrikOptions) -> Result<Self, IkError> {
        options.validate()?;
        Ok(Self {
            options,
            ..Self::default()
        })
    }

    /// The options.
    #[must_use]
    pub fn options(&self) -> TreeFabrikOptions {
        self.options
    }

    /// How many times the damped least-squares finish has linearized over this solver's
    /// life ([`Finish::linearizations`](sinew_skeleton::finish::Finish::linearizations)):
    /// with chord steps, the number of trials no longer tells the work.
    #[must_use]
    pub fn linearizations(&self) -> usize {
        self.common.dls.linearizations()
    }

    /// Passes then the finish, from the pose in `state`; returns the iterations used and
    /// the stop reason. With `chord_start` the finish's first trial may reuse the factor
    /// of its last linearization ([`Common::finish`]).
    fn attempt(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
        mut iterations: usize,
        max_passes: usize,
        chord_start: bool,
    ) -> Result<(usize, StopReason), IkError> {
        let settings = &problem.settings;
        let mut cost = self.common.cost(state);
        let mut stop = StopReason::Stalled;
        let mut passes = 0;
        if max_passes > 0 && !self.passes_ready {
            self.passes.prepare(problem, &self.common);
            self.passes_ready = true;
        }
        while passes < max_passes {
            if iterations >= settings.max_iterations {
                stop = StopReason::IterationCap;
                break;
            }
            let kept_translation = self.common.keep(state);
            self.passes.pass(problem, &self.common, state)?;
            iterations += 1;
            passes += 1;
            let new_cost = self.common.cost(state);
            if !(new_cost < cost && self.common.pins_hold(problem, state)) {
                self.common.restore(problem, state, kept_translation)?;
                break;
            }
            let ratio = new_cost / cost;
            cost = new_cost;
            if crate::problem::all_within(&self.common.targets, &state.global, settings) {
                return Ok((iterations, StopReason::Converged));
            }
            if ratio > self.options.switch_ratio {
                break;
            }
        }
        if self.options.finish {
            let finished =
                self.common
                    .finish(problem, state, iterations, chord_start && passes == 0)?;
            return Ok((iterations + finished.steps, finished.stop));
        }
        if crate::problem::all_within(&self.common.targets, &state.global, settings) {
            stop = StopReason::Converged;
        }
        Ok((iterations, stop))
    }
}

impl BodySolver for TreeFabrikSolver {
    fn name(&self) -> &'static str {
        "fabrik"
    }

    fn solve(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
    ) -> Result<BodyReport, IkError> {
        let same_problem = self.carried.same_problem(problem);
        let continued = same_problem && self.carried.continues(state);
        let global_exact = continued && self.carried.global_unchanged(state);
        let result = self.solve_from(problem, state, same_problem, continued, global_exact);
        match &result {
            Ok(_) => {
                self.carried.record(problem, state, same_problem, continued);
                if self.from_prediction {
                    self.carried.record_correction(
                        state,
                        &self.common.scratch.first_order,
                        &self.common.scratch.extrapolated,
                        self.common.first_order_translation,
                    );
                } else {
                    self.carried.has_correction = false;
                }
            }
            Err(_) => self.carried.invalidate(),
        }
        result
    }
}

impl TreeFabrikSolver {
    /// [`BodySolver::solve`], `same_problem` saying whether the problem has the last
    /// solve's structure ([`Carried::same_problem`]), `continued` whether `state` is
    /// also that solve's answer (then the frame starts from the extrapolation of the last
    /// two answers, when that is better) and `global_exact` whether its global pose is
    /// the one that solve returned.
    fn solve_from(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
        same_problem: bool,
        continued: bool,
        global_exact: bool,
    ) -> Result<BodyReport, IkError> {
        self.from_prediction = false;
        if !continued {
            // The finish's last factor belongs to another problem (or to none).
            self.common.dls.forget();
        }
        let start = self
            .common
            .begin(problem, state, same_problem, continued, global_exact)?;
        if let Begin::Done(report) = start {
            return Ok(report);
        }
        // The passes' topology is built when a pass first runs: the default options run
        // none on a frame that converges from its first attempt.
        self.passes_ready = false;
        let first_passes = if self.options.finish {
            0
        } else {
            self.options.max_passes
        };
        let mut spent = 0;
        if continued
            && self.carried.has_before
            && self.common.predict(problem, state, &self.carried)?
        {
            // From the extrapolated start; kept only when it reaches every goal with the
            // pins where they may be, else the frame is solved from the pose given.
            let (used, stop) = self.attempt(problem, state, 0, first_passes, true)?;
            if stop == StopReason::Converged && self.common.pins_hold(problem, state) {
                self.from_prediction = true;
                return Ok(self.common.report_exact(problem, state, used, stop, false));
            }
            spent = used;
            self.common.seed(problem, state, 0)?;
        }
        self.common.seed_limbs(problem, state)?;
        let (mut iterations, mut stop) =
            self.attempt(problem, state, spent, first_passes, false)?;
        let mut restarted = false;
        // A frame that continues a sequence and ends in a local minimum near its goals
        // first restarts near where it started (the last frame's answer, drawn a little
        // off the bounds), the finish alone: the restarts below start far from it, and an
        // answer found from there may be far from the last frame's, a visible pop in an
        // animation. A frame that ended far from its goals is in another basin, which the
        // restarts from far are for.
        if continued
            && self.options.finish
            && self.options.restarts > 0
            && stop == StopReason::LocalMinimum
            && iterations < problem.settings.max_iterations
            && self.common.ended_near(problem, state)
        {
            let best_translation = self.common.keep_best(state);
            self.common.seed_near(problem, state)?;
            // With its own share of the iterations: a near restart that crawls too must
            // leave the far restarts some.
            let mut near = *problem;
            near.settings.max_iterations = problem
                .settings
                .max_iterations
                .min(iterations.saturating_add(NEAR_ITERATIONS));
            let (used, next_stop) = self.attempt(&near, state, iterations, 0, false)?;
            iterations = used;
            // Only a converged answer is kept, even at a higher cost than the crawl's end
            // (which is short of the tolerance); any other leaves the restarts below to
            // compare theirs with the crawl's end, as without this one (kept at a lower
            // cost, it made them drop converged answers: measured in `docs/ik-body.md`).
            if next_stop == StopReason::Converged && self.common.pins_hold(problem, state) {
                stop = next_stop;
                restarted = true;
            } else {
                self.common.restore_best(problem, state, best_translation)?;
            }
        }
        let mut seed = 0;
        while seed < self.options.restarts
            && stop == StopReason::LocalMinimum
            && iterations < problem.settings.max_iterations
        {
            let best_cost = self.common.cost(state);
            let best_translation = self.common.keep_best(state);
            // The first restart is the passes then the finish from the starting pose
            // (when the first attempt was the finish alone): the passes lead into
            // other basins than the finish does.
            if seed == 0 && (self.options.max_passes == 0 || !self.options.finish) {
                seed = 1;
            }
            self.common.seed(problem, state, seed)?;
            let passes = self.options.max_passes;
            seed += 1;
            let (used, next_stop) = self.attempt(problem, state, iterations, passes, false)?;
            iterations = used;
            if self.common.cost(state) < best_cost && self.common.pins_hold(problem, state) {
                stop = next_stop;
                restarted = true;
            } else {
                self.common.restore_best(problem, state, best_translation)?;
            }
        }
        Ok(self
            .common
            .report_exact(problem, state, iterations, stop, restarted))
    }
}

impl Passes {
    /// The active joints, their active children and the effector on each joint.
    fn prepare(&mut self, problem: &BodyProblem<'_>, common: &Common) {
        let skeleton = problem.skeleton;
        let n = skeleton.len();
        self.active.clear();
        self.active.resize(n, false);
        self.effector.clear();
        self.effector.resize(n, None);
        for (e, t) in common.targets.iter().enumerate() {
            self.effector[t.joint] = Some(e);
            let mut j = Some(t.joint);
            while let Some(k) = j {
                if self.active[k] {
                    break;
                }
                self.active[k] = true;
                j = skeleton.parent(k);
            }
        }
        // Children lists by counting (the count of j's children goes into slot j + 1).
        self.child_start.clear();
        self.child_start.resize(n + 1, 0);
        for j in 0..n {
            if self.active[j]
                && let Some(p) = skeleton.parent(j)
            {
                self.child_start[p + 1] += 1;
            }
        }
        for j in 0..n {
            self.child_start[j + 1] += self.child_start[j];
        }
        self.children.clear();
        self.children.resize(self.child_start[n], 0);
        // Fill in joint order, so each list is increasing; `weight` is the cursor here.
        self.weight.clear();
        self.weight.resize(n, 0.0);
        for j in 0..n {
            if self.active[j]
                && let Some(p) = skeleton.parent(j)
            {
                let slot = self.child_start[p] + self.weight[p] as usize;
                self.children[slot] = j;
                self.weight[p] += 1.0;
            }
        }
        self.sum.resize(n, DVec3::ZERO);
        self.backward.resize(n, DVec3::ZERO);
        self.forward.resize(n, DVec3::ZERO);
    }

    /// One backward-forward pass and the rotations it implies, projected onto the limits;
    /// `state.global` is exact forward kinematics of the result.
    fn pass(
        &mut self,
        problem: &BodyProblem<'_>,
        common: &Common,
        state: &mut BodyState,
    ) -> Result<(), IkError> {
        let skeleton = problem.skeleton;
        let n = skeleton.len();
        let positions = &state.global.positions;
        self.sum.fill(DVec3::ZERO);
        self.weight.fill(0.0);
        // Backward: leaves to root.
        for j in (0..n).rev() {
            if !self.active[j] {
                continue;
            }
            if let Some(e) = self.effector[j] {
                let t = &common.targets[e];
                let w = t.position_weight * t.position_weight;
                self.sum[j] += t.position * w;
                self.weight[j] += w;
            }
            let here = if self.weight[j] > 0.0 {
                self.sum[j] / self.weight[j]
            } else {
                positions[j]
            };
            self.backward[j] = here;
            if let Some(p) = skeleton.parent(j) {
                let length = skeleton.offset(j).length();
                let direction = try_unit(positions[p] - here)
                    .or_else(|| try_unit(positions[p] - positions[j]))
                    .unwrap_or(DVec3::ZERO);
                let asked = here + direction * length;
                self.sum[p] += asked * self.weight[j];
                self.weight[p] += self.weight[j];
            }
        }
        // Forward: root to leaves.
        for j in 0..n {
            if !self.active[j] {
                continue;
            }
            self.forward[j] = match skeleton.parent(j) {
                None if problem.root_translates => self.backward[j],
                None => positions[j],
                Some(p) => {
                    let length = skeleton.offset(j).length();
                    let direction = try_unit(self.backward[j] - self.forward[p])
                        .or_else(|| try_unit(positions[j] - positions[p]))
                        .unwrap_or(DVec3::ZERO);
                    self.forward[p] + direction * length
                }
            };
        }
        // The body's translation follows the first root.
        if problem.root_translates && self.active[0] {
            state.root_translation += self.forward[0] - positions[0];
        }
        // Rotations, root first, each joint aiming its active children; the global pose
        // is updated in place as it goes (parents before children).
        let global = &mut state.global;
        for j in 0..n {
            if !self.active[j] {
                continue;
            }
            let (parent_rotation, position) = match skeleton.parent(j) {
                Some(p) => (
                    global.rotations[p],
                    global.positions[p] + global.rotations[p] * skeleton.offset(j),
                ),
                None => (DQuat::IDENTITY, skeleton.offset(j) + state.root_translation),
            };
            let current = (parent_rotation * state.pose.rotations[j]).normalize();
            let children = &self.children[self.child_start[j]..self.child_start[j + 1]];
            let turn = match children {
                [] => DQuat::IDENTITY,
                &[c] => rotation_between(current * skeleton.offset(c), self.forward[c] - position),
                several => {
                    let mut best = BestRotation::new();
                    for &c in several {
                        best.add(
                            current * skeleton.offset(c),
                            self.forward[c] - position,
                            self.weight[c],
                        );
                    }
                    best.rotation()
                }
            };
            let mut local = (parent_rotation.conjugate() * turn * current).normalize();
            let limit = skeleton.prepared_limit(j);
            if !matches!(limit.limit(), JointLimit::Free) {
                local = limit.project(local);
            }
            state.pose.rotations[j] = local;
            global.rotations[j] = (parent_rotation * local).normalize();
            global.positions[j] = position;
        }
        // Exact forward kinematics of the result, including the joints off the paths.
        forward_kinematics(skeleton, &state.pose, state.root_translation, global)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::common::Begin;
    use crate::problem::forward_kinematics;
    use crate::workload::{self, CLIP_FRAMES};
    use crate::{BodySolver, BodyState};
    use sinew_skeleton::ik::SolveSettings;

    /// The extrapolated start of a warm frame computes its global poses apart from the
    /// state: a start it does not keep leaves the state as `begin` left it, to the bit
    /// (pose, translation and global pose), and a start it keeps has the exact forward
    /// kinematics of its pose and translation. The clip is played forwards, then
    /// backwards, so that the motion's reversals give starts that are not kept.
    #[test]
    fn the_extrapolated_start_leaves_the_state_as_given_or_exact() {
        let skel = workload::humanoid().unwrap();
        let settings = SolveSettings::default();
        let rest = BodyState::rest(&skel);
        let mut state = rest.clone();
        let mut solver = TreeFabrikSolver::new();
        let order: Vec<usize> = (0..90).chain((40..90).rev()).chain(40..70).collect();
        let (mut kept, mut dropped) = (0, 0);
        let mut exact = rest.global.clone();
        let bits = |g: &sinew_skeleton::GlobalPose| -> Vec<u64> {
            g.rotations
                .iter()
                .flat_map(|q| q.to_array())
                .chain(g.positions.iter().flat_map(|p| p.to_array()))
                .map(f64::to_bits)
                .collect()
        };
        for &f in &order {
            let effectors = workload::clip_frame(&rest.global, f % CLIP_FRAMES);
            let problem = BodyProblem::new(&skel, &effectors, settings).with_root_translation(true);
            let same = solver.carried.same_problem(&problem);
            let continued = same && solver.carried.continues(&state);
            if continued && solver.carried.has_before {
                let global_exact = solver.carried.global_unchanged(&state);
                let mut probe = state.clone();
                let begun = solver
                    .common
                    .begin(&problem, &mut probe, same, continued, global_exact)
                    .unwrap();
                if matches!(begun, Begin::Iterate) {
                    let given = probe.clone();
                    let mut common = solver.common.clone();
                    if common
                        .predict(&problem, &mut probe, &solver.carried)
                        .unwrap()
                    {
                        kept += 1;
                        forward_kinematics(&skel, &probe.pose, probe.root_translation, &mut exact)
                            .unwrap();
                        assert_eq!(bits(&probe.global), bits(&exact), "frame {f}");
                    } else {
                        dropped += 1;
                        let local = |s: &BodyState| -> Vec<u64> {
                            s.pose
                                .rotations
                                .iter()
                                .flat_map(|q| q.to_array())
                                .chain(s.root_translation.to_array())
                                .map(f64::to_bits)
                                .collect()
                        };
                        assert_eq!(local(&probe), local(&given), "frame {f}");
                        assert_eq!(bits(&probe.global), bits(&given.global), "frame {f}");
                    }
                }
            }
            let report = solver.solve(&problem, &mut state).unwrap();
            assert!(report.within(&settings), "frame {f}");
        }
        assert!(kept > 50, "{kept} starts kept");
        assert!(dropped > 0, "{dropped} starts not kept");
    }
}
