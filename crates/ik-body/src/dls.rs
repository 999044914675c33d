//! The damped least-squares finish over all effectors at once, with the joint limits.
//!
//! Levenberg-Marquardt steps on the local rotations of the movable joints (and on the
//! body's translation when it may translate), the residual stacked over every effector:
//! 3 rows for a position, 3 more for a rotation goal. The derivation is in
//! `docs/ik-body.md`; in short:
//!
//! - Degrees of freedom, as world-frame axes: a free or swing-twist joint the three world
//!   axes (a world rotation composed on the left of the joint's global rotation), a hinge
//!   its axis turned into the world by its parent's global rotation (composed on the left
//!   it stays a hinge rotation), a fixed joint none; the translation the three world axes.
//! - A rotation dof with world axis `u` at joint position `p` moves effector `e` (below it)
//!   by `u x (x_e - p)` and turns its frame by `u`, per radian; the effector's own joint
//!   turns its frame only. A translation dof moves every effector by `u`. With the
//!   weights on the rows, these are the columns of `J`.
//! - The step solves `(J J^T + lambda I) y = r` (rows x rows, Cholesky) and moves each dof
//!   by `J_k . y`. Every trial pose is projected onto the limits, so every pose the finish
//!   accepts is inside them; a trial is kept only when it lowers the weighted cost and no
//!   pinned effector moves further than the tolerance (or than it already was) from its
//!   pin, so the cost never increases.
//! - Active set: a hinge on a bound whose step points outwards is left out and the step
//!   solved again; after a rejected trial, joints the projection clamped are frozen and the
//!   step recomputed at the same damping; an accepted step frees every joint again. Only a
//!   rejection that froze nothing grows the damping.
//!
//! It stops when every effector is within both tolerances, at the iteration cap, or after
//! `MAX_REJECTIONS` consecutive rejections (a local minimum of the cost over the allowed
//! set, which for conflicting goals is the weighted least-squares best).

use crate::problem::{BodyState, Target, all_within, forward_kinematics, pins_hold, total_cost};
use crate::topology::Topology;
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::{SolveSettings, StopReason, rotation_angle};
use sinew_skeleton::limits::{JointLimit, SwingTwist};
use sinew_skeleton::{GlobalPose, Skeleton, SkeletonError};
use std::f64::consts::PI;

/// The first damping is the smaller of this times the mean diagonal of `J J^T` and
/// `COST_DAMPING` times the weighted cost.
const INITIAL_DAMPING: f64 = 0.1;
const COST_DAMPING: f64 = 0.1;
/// Consecutive rejections before the finish declares a local minimum.
const MAX_REJECTIONS: usize = 8;
/// The damping's growth after any rejected trial (a rejection that froze nothing grows
/// it by 10 more).
const CLAMP_GROWTH: f64 = 2.0;
/// How much further than it may end a step may take a pinned effector from its pin.
const PIN_SLACK: f64 = 1e4;
/// Accepted steps in a row that each lower the cost by less than `CRAWL_GAIN` (relative)
/// before the finish declares a local minimum.
const CRAWL_STEPS: usize = 4;
const CRAWL_GAIN: f64 = 0.02;
/// A hinge angle this close to a bound (radians) counts as on it.
const AT_BOUND: f64 = 1e-12;
/// A projection that turns a joint by more than this (radians) counts as a clamp.
const CLAMPED: f64 = 1e-12;
/// The dof "joint" index of the body's translation.
const TRANSLATION: usize = usize::MAX;
/// A movable joint without degrees of freedom (a fixed joint).
const NO_DOF: usize = usize::MAX;

/// Buffers of the finish, owned by the solver so that a solve does not allocate once
/// they have grown to the problem's size.
#[derive(Clone, Debug, Default)]
pub(crate) struct Dls {
    /// First residual row of each target.
    first_row: Vec<usize>,
    /// Degrees of freedom: movable joint slot (or `TRANSLATION`) and world axis.
    dofs: Vec<(usize, DVec3)>,
    /// Sparse columns: `entries[col_start[k]..col_start[k + 1]]` are (row, value) pairs of
    /// dof `k`, rows increasing.
    col_start: Vec<usize>,
    entries: Vec<(usize, f64)>,
    /// Lower triangle of `J J^T` over every degree of freedom at the linearization point
    /// (rows x rows, row-major); the same without the frozen and blocked ones; and its
    /// damped Cholesky factor.
    normal_full: Vec<f64>,
    normal: Vec<f64>,
    /// Per movable joint: the index of its first degree of freedom (`NO_DOF` for a fixed
    /// joint), and the world rotation vector of the current step.
    first_dof: Vec<usize>,
    turn: Vec<DVec3>,
    factor: Vec<f64>,
    residual: Vec<f64>,
    y: Vec<f64>,
    step: Vec<f64>,
    /// Per movable joint: frozen by the active set, and clamped by the last trial.
    frozen: Vec<bool>,
    clamped: Vec<bool>,
    /// Per movable joint: the world directions of rotation the active set has blocked
    /// (orthonormal, the first `blocked_count` of them), and the direction the last
    /// trial's projection pulled the joint back along.
    blocked: Vec<[DVec3; 2]>,
    blocked_count: Vec<usize>,
    pulled_back: Vec<DVec3>,
    /// Per movable joint: whether the projection may have left it on its bound (it was
    /// clamped by the last accepted trial, or the finish just started), and then the
    /// outward normal of the bound as a local rotation vector (zero when inside).
    on_bound: Vec<bool>,
    outward: Vec<[DVec3; 2]>,
    /// The movable joints' local rotations and the global pose before a trial.
    saved: Vec<DQuat>,
    saved_global: GlobalPose,
    /// Per target: how far from its pin a pinned effector may end (its distance at the
    /// start of the finish, or the tolerance if larger), and how far an intermediate
    /// step may take it (`PIN_SLACK` times more).
    pin_allowed: Vec<f64>,
    pin_slack: Vec<f64>,
    /// The best pose accepted so far with every pin within `pin_allowed`: the movable
    /// joints' rotations, the translation, and its cost.
    best: Vec<DQuat>,
    best_translation: DVec3,
    best_cost: f64,
}

/// What a finish did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Finished {
    pub stop: StopReason,
    pub steps: usize,
}

impl Dls {
    /// Runs the finish on `state` (inside the limits, its global pose exact) until every
    /// effector is within the tolerances, `iterations + steps` reaches the cap, or steps
    /// stop helping.
    #[allow(clippy::too_many_arguments)]
    pub fn run(
        &mut self,
        skeleton: &Skeleton,
        topology: &Topology,
        targets: &[Target],
        state: &mut BodyState,
        root_translates: bool,
        settings: &SolveSettings,
        iterations: usize,
    ) -> Result<Finished, SkeletonError> {
        let movable = &topology.movable;
        self.first_row.clear();
        let mut rows = 0;
        for t in targets {
            self.first_row.push(rows);
            rows += if t.has_rotation() { 6 } else { 3 };
        }
        self.pin_allowed.clear();
        self.pin_allowed.extend(targets.iter().map(|t| {
            let d = state.global.positions[t.joint].distance(t.position);
            if t.pinned {
                d.max(settings.tolerance)
            } else {
                0.0
            }
        }));
        self.pin_slack.clear();
        self.pin_slack
            .extend(self.pin_allowed.iter().map(|&a| a * PIN_SLACK));
        self.best.clear();
        self.best
            .extend(movable.iter().map(|&j| state.pose.rotations[j]));
        self.best_translation = state.root_translation;
        self.best_cost = total_cost(targets, &state.global);
        let finished = self.iterate(
            skeleton,
            topology,
            targets,
            state,
            root_translates,
            settings,
            iterations,
            rows,
        )?;
        // A step may move a pin by up to the slack, so that one step can fix the other
        // goals and the next bring the pin back; an ending that has not brought it back
        // returns to the best pose that kept every pin.
        if !pins_hold(
            targets,
            &state.global,
            settings.tolerance,
            &self.pin_allowed,
        ) {
            for (&saved, &j) in self.best.iter().zip(movable) {
                state.pose.rotations[j] = saved;
            }
            state.root_translation = self.best_translation;
            forward_kinematics(
                skeleton,
                &state.pose,
                state.root_translation,
                &mut state.global,
            )?;
            return Ok(Finished {
                stop: StopReason::LocalMinimum,
                steps: finished.steps,
            });
        }
        Ok(finished)
    }

    /// The steps of [`Dls::run`], with `rows` residual rows.
    #[allow(clippy::too_many_arguments)]
    fn iterate(
        &mut self,
        skeleton: &Skeleton,
        topology: &Topology,
        targets: &[Target],
        state: &mut BodyState,
        root_translates: bool,
        settings: &SolveSettings,
        iterations: usize,
        rows: usize,
    ) -> Result<Finished, SkeletonError> {
        let movable = &topology.movable;
        self.frozen.clear();
        self.frozen.resize(movable.len(), false);
        self.clamped.clear();
        self.clamped.resize(movable.len(), false);
        self.blocked.clear();
        self.blocked.resize(movable.len(), [DVec3::ZERO; 2]);
        self.blocked_count.clear();
        self.blocked_count.resize(movable.len(), 0);
        self.pulled_back.clear();
        self.pulled_back.resize(movable.len(), DVec3::ZERO);
        self.on_bound.clear();
        self.on_bound.resize(movable.len(), true);
        self.outward.clear();
        self.outward.resize(movable.len(), [DVec3::ZERO; 2]);
        self.find_outward(skeleton, movable, state);
        self.normal.resize(rows * rows, 0.0);
        self.normal_full.resize(rows * rows, 0.0);
        self.factor.resize(rows * rows, 0.0);
        self.turn.clear();
        self.turn.resize(movable.len(), DVec3::ZERO);
        self.residual.resize(rows, 0.0);
        self.y.resize(rows, 0.0);
        let mut cost = total_cost(targets, &state.global);
        let mut damping = f64::NAN;
        let mut rejections = 0;
        let mut crawl = 0;
        let mut steps = 0;
        let mut resolving = false;
        // Whether the columns and `normal_full` are those of the current pose: a rejected
        // trial or a change of the active set keeps them, only an accepted step moves
        // the linearization point.
        let mut fresh = false;
        loop {
            if all_within(targets, &state.global, settings) {
                return Ok(Finished {
                    stop: StopReason::Converged,
                    steps,
                });
            }
            if iterations + steps >= settings.max_iterations {
                return Ok(Finished {
                    stop: StopReason::IterationCap,
                    steps,
                });
            }
            if rejections >= MAX_REJECTIONS || rows == 0 {
                return Ok(Finished {
                    stop: StopReason::LocalMinimum,
                    steps,
                });
            }
            if !fresh {
                self.linearize(skeleton, topology, targets, state, root_translates);
                self.accumulate_normal(rows);
                fresh = true;
            }
            if !self.reduce(skeleton, movable, rows) {
                return Ok(Finished {
                    stop: StopReason::LocalMinimum,
                    steps,
                });
            }
            if damping.is_nan() {
                let trace: f64 = (0..rows).map(|a| self.normal[a * rows + a]).sum();
                // Far from the goals (a cold start) a cautious first step, near them (a warm
                // frame) a nearly Gauss-Newton one: the damping follows the cost, as in
                // Yamashita and Fukushima's choice `lambda = |r|^2`, capped by the scale
                // of `J J^T`.
                damping = (INITIAL_DAMPING * trace / rows as f64).min(COST_DAMPING * cost);
            }
            if !resolving {
                steps += 1;
            }
            resolving = false;
            if !self.solve(rows, damping) {
                damping = damping.max(f64::MIN_POSITIVE) * 10.0;
                rejections += 1;
                continue;
            }
            let shift = self.turns(movable);
            // A hinge is a box on its angle, so this part of the active set is exact: a
            // hinge on a bound stepping outwards would be clamped back while the others
            // moved as if it had turned. Leave it out and solve the same step again.
            for (m, &j) in movable.iter().enumerate() {
                if let JointLimit::Hinge(h) = skeleton.limit(j)
                    && !self.frozen[m]
                {
                    let k = self.first_dof[m];
                    if k != NO_DOF
                        && h.pushes_outwards(state.pose.rotations[j], self.step[k], AT_BOUND)
                    {
                        self.frozen[m] = true;
                        resolving = true;
                    }
                }
            }
            // The same for a swing-twist joint on its bound: the step's component along
            // the bound's outward normal would be projected away; block that direction
            // (the joint keeps sliding along the bound) and solve again.
            for (m, &j) in movable.iter().enumerate() {
                let w = self.turn[m];
                if self.outward[m] == [DVec3::ZERO; 2] || w == DVec3::ZERO {
                    continue;
                }
                let parent = skeleton
                    .parent(j)
                    .map_or(DQuat::IDENTITY, |p| state.global.rotations[p]);
                let local = parent.conjugate() * w;
                for g in 0..2 {
                    let n = self.outward[m][g];
                    if n != DVec3::ZERO && local.dot(n) > 0.0 && !self.frozen[m] {
                        self.pulled_back[m] = parent * n;
                        self.block(skeleton.limit(j), m);
                        // Blocked once per linearization: the normal is not asked again.
                        self.outward[m][g] = DVec3::ZERO;
                        resolving = true;
                        break;
                    }
                }
            }
            if resolving {
                continue;
            }
            self.saved.clear();
            self.saved
                .extend(movable.iter().map(|&j| state.pose.rotations[j]));
            let saved_translation = state.root_translation;
            self.saved_global
                .rotations
                .clone_from(&state.global.rotations);
            self.saved_global
                .positions
                .clone_from(&state.global.positions);
            self.apply_step(skeleton, movable, state, shift);
            forward_kinematics(
                skeleton,
                &state.pose,
                state.root_translation,
                &mut state.global,
            )?;
            let trial_cost = total_cost(targets, &state.global);
            if trial_cost < cost
                && pins_hold(targets, &state.global, settings.tolerance, &self.pin_slack)
            {
                if trial_cost < self.best_cost
                    && pins_hold(
                        targets,
                        &state.global,
                        settings.tolerance,
                        &self.pin_allowed,
                    )
                {
                    self.best.clear();
                    self.best
                        .extend(movable.iter().map(|&j| state.pose.rotations[j]));
                    self.best_translation = state.root_translation;
                    self.best_cost = trial_cost;
                }
                // Crawling along the bounds: accepted steps that each gain almost nothing
                // are a local minimum in all but name; say so, so that the caller may
                // restart, rather than spend the iterations.
                if trial_cost > (1.0 - CRAWL_GAIN) * cost {
                    crawl += 1;
                } else {
                    crawl = 0;
                }
                cost = trial_cost;
                if crawl >= CRAWL_STEPS {
                    return Ok(Finished {
                        stop: StopReason::LocalMinimum,
                        steps,
                    });
                }
                damping /= 3.0;
                rejections = 0;
                fresh = false;
                self.frozen.fill(false);
                self.blocked_count.fill(0);
                for (on, &clamped) in self.on_bound.iter_mut().zip(&self.clamped) {
                    *on |= clamped;
                }
                self.find_outward(skeleton, movable, state);
                continue;
            }
            for (&saved, &j) in self.saved.iter().zip(movable) {
                state.pose.rotations[j] = saved;
            }
            state.root_translation = saved_translation;
            state
                .global
                .rotations
                .clone_from(&self.saved_global.rotations);
            state
                .global
                .positions
                .clone_from(&self.saved_global.positions);
            // A rejected trial means the step was too long for the linearization or for
            // the bounds: shorten the next one too, whether or not a joint was frozen;
            // left out, the finish crawls along the bounds (`docs/ik-body.md` has the
            // measurements).
            let mut newly_frozen = false;
            damping *= CLAMP_GROWTH;
            for (m, &j) in movable.iter().enumerate() {
                if self.clamped[m] && !self.frozen[m] {
                    self.block(skeleton.limit(j), m);
                    newly_frozen = true;
                }
            }
            if !newly_frozen {
                damping = (damping * 10.0).max(f64::MIN_POSITIVE);
                rejections += 1;
            }
        }
    }

    /// The residual and the sparse columns of the weighted Jacobian at `state`.
    fn linearize(
        &mut self,
        skeleton: &Skeleton,
        topology: &Topology,
        targets: &[Target],
        state: &BodyState,
        root_translates: bool,
    ) {
        let global = &state.global;
        for (t, &row) in targets.iter().zip(&self.first_row) {
            let p = (t.position - global.positions[t.joint]) * t.position_weight;
            self.residual[row..row + 3].copy_from_slice(&[p.x, p.y, p.z]);
            if t.has_rotation() {
                let r = t.rotation_residual(global) * t.rotation_weight;
                self.residual[row + 3..row + 6].copy_from_slice(&[r.x, r.y, r.z]);
            }
        }
        self.dofs.clear();
        self.col_start.clear();
        self.entries.clear();
        self.first_dof.clear();
        for (m, &j) in topology.movable.iter().enumerate() {
            let axes: [DVec3; 3];
            let axes: &[DVec3] = match skeleton.limit(j) {
                JointLimit::Fixed => &[],
                JointLimit::Hinge(h) => {
                    let parent = skeleton
                        .parent(j)
                        .map_or(DQuat::IDENTITY, |p| global.rotations[p]);
                    axes = [(parent * h.axis).normalize(), DVec3::ZERO, DVec3::ZERO];
                    &axes[..1]
                }
                // The world axes: exact for a rotation composed on the left, and never
                // short of rank, where the limit's own frame would be at a quarter-turn
                // swing.
                JointLimit::Free | JointLimit::SwingTwist(_) => &[DVec3::X, DVec3::Y, DVec3::Z],
            };
            self.first_dof.push(if axes.is_empty() {
                NO_DOF
            } else {
                self.dofs.len()
            });
            let at = global.positions[j];
            for &u in axes {
                self.col_start.push(self.entries.len());
                self.dofs.push((m, u));
                for &e in topology.below(m) {
                    let t = &targets[e];
                    let row = self.first_row[e];
                    if t.joint != j {
                        let v = u.cross(global.positions[t.joint] - at) * t.position_weight;
                        self.entries
                            .extend([(row, v.x), (row + 1, v.y), (row + 2, v.z)]);
                    }
                    if t.has_rotation() {
                        let w = u * t.rotation_weight;
                        self.entries
                            .extend([(row + 3, w.x), (row + 4, w.y), (row + 5, w.z)]);
                    }
                }
            }
        }
        if root_translates {
            for u in [DVec3::X, DVec3::Y, DVec3::Z] {
                self.col_start.push(self.entries.len());
                self.dofs.push((TRANSLATION, u));
                for (t, &row) in targets.iter().zip(&self.first_row) {
                    let v = u * t.position_weight;
                    self.entries
                        .extend([(row, v.x), (row + 1, v.y), (row + 2, v.z)]);
                }
            }
        }
        self.col_start.push(self.entries.len());
    }

    /// The outward normal of the bound of every swing-twist joint that may sit on it,
    /// as a local rotation vector, by one-sided differences of the limit's violation
    /// (0 inside, growing linearly outside): zero for a joint inside its limit.
    fn find_outward(&mut self, skeleton: &Skeleton, movable: &[usize], state: &BodyState) {
        const H: f64 = 1e-7;
        for (m, &j) in movable.iter().enumerate() {
            self.outward[m] = [DVec3::ZERO; 2];
            if !self.on_bound[m] {
                continue;
            }
            let JointLimit::SwingTwist(st) = skeleton.limit(j) else {
                self.on_bound[m] = false;
                continue;
            };
            // The swing bound and the twist range are two constraints, which can both
            // be active (a corner): one normal each, from the limit with the other one
            // opened up.
            let swing_only = JointLimit::SwingTwist(SwingTwist {
                twist_min: -PI,
                twist_max: PI,
                ..*st
            });
            let twist_only = JointLimit::SwingTwist(SwingTwist {
                swing_a: PI,
                swing_b: PI,
                ..*st
            });
            let local = state.pose.rotations[j];
            for (g, limit) in [swing_only, twist_only].iter().enumerate() {
                let mut n = DVec3::ZERO;
                for e in [DVec3::X, DVec3::Y, DVec3::Z] {
                    let plus = limit.violation(DQuat::from_scaled_axis(e * H) * local);
                    let minus = limit.violation(DQuat::from_scaled_axis(e * -H) * local);
                    n += e * (plus - minus);
                }
                self.outward[m][g] = n.try_normalize().unwrap_or(DVec3::ZERO);
            }
            // Off both bounds: no longer watched until a projection clamps it again.
            self.on_bound[m] = self.outward[m] != [DVec3::ZERO; 2];
        }
    }

    /// Blocks, after a rejected trial that clamped movable joint `m`, the direction its
    /// projection pulled it back along: a hinge (one axis) is frozen; a free or
    /// swing-twist joint loses that one direction of rotation and keeps sliding along
    /// its bound in the others, until a third direction would be blocked.
    fn block(&mut self, limit: &JointLimit, m: usize) {
        if !matches!(limit, JointLimit::SwingTwist(_)) {
            self.frozen[m] = true;
            return;
        }
        let mut d = self.pulled_back[m];
        for b in &self.blocked[m][..self.blocked_count[m]] {
            d -= *b * b.dot(d);
        }
        match (d.try_normalize(), self.blocked_count[m]) {
            (Some(unit), count)
                if count < 2 && d.length() > 1e-3 * self.pulled_back[m].length() =>
            {
                self.blocked[m][count] = unit;
                self.blocked_count[m] = count + 1;
            }
            _ => self.frozen[m] = true,
        }
    }

    /// `J J^T` (lower triangle) from the sparse columns.
    fn accumulate_normal(&mut self, rows: usize) {
        self.normal_full[..rows * rows].fill(0.0);
        for k in 0..self.dofs.len() {
            let col = &self.entries[self.col_start[k]..self.col_start[k + 1]];
            for (i, &(a, va)) in col.iter().enumerate() {
                let line = &mut self.normal_full[a * rows..a * rows + a + 1];
                for &(b, vb) in &col[..=i] {
                    line[b] += va * vb;
                }
            }
        }
    }

    /// `J J^T` over the active degrees of freedom into `normal`: `normal_full` less the
    /// columns of the frozen joints and, for a joint with blocked directions `b`, less
    /// `c(b) c(b)^T` (its three world-axis columns `C` span `C C^T`, and the allowed
    /// directions `P = I - sum b b^T` leave `C P C^T`). False when nothing may move.
    fn reduce(&mut self, skeleton: &Skeleton, movable: &[usize], rows: usize) -> bool {
        self.normal[..rows * rows].copy_from_slice(&self.normal_full[..rows * rows]);
        let mut active = self.dofs.last().is_some_and(|d| d.0 == TRANSLATION);
        for (m, &j) in movable.iter().enumerate() {
            let k0 = self.first_dof[m];
            if k0 == NO_DOF {
                continue;
            }
            let count = match skeleton.limit(j) {
                JointLimit::Hinge(_) => 1,
                _ => 3,
            };
            if self.frozen[m] {
                for k in k0..k0 + count {
                    let (a, b) = (self.col_start[k], self.col_start[k + 1]);
                    subtract_outer(&mut self.normal, rows, self.entries[a..b].iter().copied());
                }
                continue;
            }
            active = true;
            for i in 0..self.blocked_count[m] {
                let d = self.blocked[m][i];
                let len = self.col_start[k0 + 1] - self.col_start[k0];
                let (x, y, z) = (
                    self.col_start[k0],
                    self.col_start[k0 + 1],
                    self.col_start[k0 + 2],
                );
                let combined = (0..len).map(|e| {
                    let row = self.entries[x + e].0;
                    let v = d.x * self.entries[x + e].1
                        + d.y * self.entries[y + e].1
                        + d.z * self.entries[z + e].1;
                    (row, v)
                });
                subtract_outer(&mut self.normal, rows, combined);
            }
        }
        active
    }

    /// The step of every degree of freedom (`J_k . y`), and from them each movable joint's
    /// world rotation vector (zero when frozen, its blocked directions projected out);
    /// returns the translation's step.
    fn turns(&mut self, movable: &[usize]) -> DVec3 {
        self.step.clear();
        for k in 0..self.dofs.len() {
            let s = self.entries[self.col_start[k]..self.col_start[k + 1]]
                .iter()
                .map(|&(row, v)| v * self.y[row])
                .sum();
            self.step.push(s);
        }
        let mut shift = DVec3::ZERO;
        self.turn.fill(DVec3::ZERO);
        for (&(m, u), &s) in self.dofs.iter().zip(&self.step) {
            if m == TRANSLATION {
                shift += u * s;
            } else if !self.frozen[m] {
                self.turn[m] += u * s;
            }
        }
        for m in 0..movable.len() {
            for i in 0..self.blocked_count[m] {
                let b = self.blocked[m][i];
                let w = self.turn[m];
                self.turn[m] = w - b * b.dot(w);
            }
        }
        shift
    }

    /// Solves `(J J^T + damping I) y = residual` by Cholesky into `self.y`; false when a
    /// pivot is not a positive finite number.
    fn solve(&mut self, rows: usize, damping: f64) -> bool {
        let (n, l) = (&self.normal, &mut self.factor);
        for a in 0..rows {
            for b in 0..=a {
                let mut sum = n[a * rows + b] + if a == b { damping } else { 0.0 };
                for k in 0..b {
                    sum -= l[a * rows + k] * l[b * rows + k];
                }
                if a == b {
                    if !(sum.is_finite() && sum > 0.0) {
                        return false;
                    }
                    l[a * rows + a] = sum.sqrt();
                } else {
                    l[a * rows + b] = sum / l[b * rows + b];
                }
            }
        }
        for a in 0..rows {
            let mut sum = self.residual[a];
            for k in 0..a {
                sum -= l[a * rows + k] * self.y[k];
            }
            self.y[a] = sum / l[a * rows + a];
        }
        for a in (0..rows).rev() {
            let mut sum = self.y[a];
            for k in a + 1..rows {
                sum -= l[k * rows + a] * self.y[k];
            }
            self.y[a] = sum / l[a * rows + a];
        }
        self.y[..rows].iter().all(|v| v.is_finite())
    }

    /// Turns each movable joint by its step `turn` (world axes taken into the parent's
    /// frame), projects it onto its limit, and moves the body by `shift`.
    fn apply_step(
        &mut self,
        skeleton: &Skeleton,
        movable: &[usize],
        state: &mut BodyState,
        shift: DVec3,
    ) {
        self.clamped.fill(false);
        state.root_translation += shift;
        for (m, &j) in movable.iter().enumerate() {
            let w = self.turn[m];
            if w == DVec3::ZERO {
                continue;
            }
            let local = match skeleton.parent(j) {
                Some(p) => state.global.rotations[p].conjugate() * w,
                None => w,
            };
            let turned = (DQuat::from_scaled_axis(local) * state.pose.rotations[j]).normalize();
            let limit = skeleton.limit(j);
            if matches!(limit, JointLimit::Free) {
                state.pose.rotations[j] = turned;
            } else {
                let projected = limit.project(turned);
                self.clamped[m] = rotation_angle(turned, projected) > CLAMPED;
                if self.clamped[m] {
                    // The pull-back as a world rotation vector: composed on the left in the
                    // parent's frame, then turned into the world like the step.
                    let mut back = projected * turned.conjugate();
                    if back.w < 0.0 {
                        back = -back;
                    }
                    let back = back.to_scaled_axis();
                    self.pulled_back[m] = match skeleton.parent(j) {
                        Some(p) => state.global.rotations[p] * back,
                        None => back,
                    };
                }
                state.pose.rotations[j] = projected;
            }
        }
    }
}

/// Subtracts the outer product of a sparse column (rows increasing) from the lower
/// triangle of a rows x rows matrix.
fn subtract_outer(
    matrix: &mut [f64],
    rows: usize,
    column: impl Iterator<Item = (usize, f64)> + Clone,
) {
    for (i, (a, va)) in column.clone().enumerate() {
        for (b, vb) in column.clone().take(i + 1) {
            matrix[a * rows + b] -= va * vb;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[allow(clippy::needless_range_loop)]
    fn the_normal_matrix_is_j_j_transpose_and_the_solve_inverts_it() {
        let mut dls = Dls::default();
        let rows = 4;
        dls.dofs = vec![(0, DVec3::X), (1, DVec3::Y), (2, DVec3::Z)];
        dls.col_start = vec![0, 2, 5, 7];
        dls.entries = vec![
            (0, 1.0),
            (2, -2.0),
            (0, 0.5),
            (1, 3.0),
            (3, 1.5),
            (2, 0.25),
            (3, -1.0),
        ];
        dls.normal_full.resize(rows * rows, 0.0);
        dls.normal.resize(rows * rows, 0.0);
        dls.factor.resize(rows * rows, 0.0);
        dls.accumulate_normal(rows);
        dls.normal.copy_from_slice(&dls.normal_full);
        // Dense J, rows x dofs.
        let mut j = [[0.0; 3]; 4];
        for k in 0..3 {
            for &(r, v) in &dls.entries[dls.col_start[k]..dls.col_start[k + 1]] {
                j[r][k] = v;
            }
        }
        for a in 0..rows {
            for b in 0..=a {
                let expected: f64 = (0..3).map(|k| j[a][k] * j[b][k]).sum();
                assert!((dls.normal[a * rows + b] - expected).abs() < 1e-15);
            }
        }
        dls.residual = vec![1.0, -2.0, 0.5, 3.0];
        dls.y.resize(rows, 0.0);
        let damping = 0.1;
        assert!(dls.solve(rows, damping));
        for a in 0..rows {
            let mut back = damping * dls.y[a];
            for b in 0..rows {
                let n: f64 = (0..3).map(|k| j[a][k] * j[b][k]).sum();
                back += n * dls.y[b];
            }
            assert!((back - dls.residual[a]).abs() < 1e-12, "row {a}");
        }
        // J J^T is singular here (rank 3 of 4): without damping there is no solution,
        // and the solve says so instead of returning NaN.
        assert!(!dls.solve(rows, 0.0) || dls.y.iter().all(|v| v.is_finite()));
    }

    #[test]
    #[allow(clippy::field_reassign_with_default)]
    fn blocking_a_direction_leaves_the_normal_matrix_of_the_other_two() {
        // One swing-twist joint with world-axis columns over 3 rows; blocking `b` must
        // leave exactly the normal matrix of two columns along a basis orthogonal to `b`.
        let limit = JointLimit::cone(DVec3::X, 1.0).unwrap();
        let skel = Skeleton::new([sinew_skeleton::JointDef {
            limit,
            ..Default::default()
        }])
        .unwrap();
        let cols = [[0.3, -1.2, 0.5], [1.1, 0.4, -0.7], [-0.2, 0.9, 1.3]];
        let rows = 3;
        let mut dls = Dls::default();
        dls.dofs = vec![(0, DVec3::X), (0, DVec3::Y), (0, DVec3::Z)];
        dls.col_start = vec![0, 3, 6, 9];
        dls.entries = cols
            .iter()
            .flat_map(|c| (0..3).map(move |r| (r, c[r])))
            .collect();
        dls.first_dof = vec![0];
        dls.frozen = vec![false];
        let b = DVec3::new(1.0, 2.0, -2.0) / 3.0;
        dls.blocked = vec![[b, DVec3::ZERO]];
        dls.blocked_count = vec![1];
        dls.normal_full.resize(9, 0.0);
        dls.normal.resize(9, 0.0);
        dls.accumulate_normal(rows);
        assert!(dls.reduce(&skel, &[0], rows));
        let column = |u: DVec3| -> [f64; 3] {
            std::array::from_fn(|r| u.x * cols[0][r] + u.y * cols[1][r] + u.z * cols[2][r])
        };
        let (u, v) = b.any_orthonormal_pair();
        let (cu, cv) = (column(u), column(v));
        for a in 0..rows {
            for c in 0..=a {
                let expected = cu[a] * cu[c] + cv[a] * cv[c];
                assert!(
                    (dls.normal[a * rows + c] - expected).abs() < 1e-14,
                    "{a} {c}"
                );
            }
        }
        // Frozen: nothing of the joint is left.
        dls.frozen = vec![true];
        assert!(!dls.reduce(&skel, &[0], rows));
        assert!(dls.normal.iter().all(|x| x.abs() < 1e-14));
    }
}
