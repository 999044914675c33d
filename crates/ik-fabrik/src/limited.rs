//! The damped least-squares finish for chains with joint limits or a rotation goal:
//! Levenberg-Marquardt steps on the chain's local rotations, each step projected onto the
//! joint limits, with an active set, over a residual of 3 rows (position) or 6 (position
//! and rotation).
//!
//! Unlike the position-only refinement (`refine.rs`, which works on free bone vectors),
//! this one works on the pose itself, because a limit constrains a joint's local rotation
//! and the rotation goal needs the effector's frame:
//!
//! - Degrees of freedom per joint, as world-frame rotation axes: a hinge its axis turned
//!   into the world by its parent's global rotation (a hinge rotation composed on the left
//!   stays a hinge rotation); a free or swing-twist joint the three world axes (a world
//!   rotation composed on the left of its global rotation), less the directions its
//!   active set blocks; a fixed joint none.
//! - A degree of freedom with world axis `u` at the joint's position `P` moves the
//!   effector `E` by `u x (E - P)` and turns it by `u`, per radian: the Jacobian columns.
//!   The weighted residual is `e = (wp (target - E), wr log(goal G_E^-1))`; the damped
//!   step solves `(J J^T + lambda I) y = e` (3 x 3 or 6 x 6, by Cholesky) and moves each
//!   degree of freedom by `J_k . y`.
//! - Every trial pose is projected onto the limits joint by joint, so every pose the
//!   finish accepts is inside them. A trial is kept only when it lowers `|e|^2`.
//! - Active set, decided before the trial where it can be: a hinge on a bound whose step
//!   points outwards is frozen (its constraint is a box on its angle), and a swing-twist
//!   joint on its swing or twist bound whose step has a component along the bound's
//!   outward normal gets that direction blocked; the step is solved again, so the joint
//!   slides along its bound. After a rejected trial, the direction each clamped joint was
//!   pulled back along is blocked the same way and the damping doubles. An accepted step
//!   starts a new active set. This is the one-effector case of the full-body finish of
//!   `sinew-ik-body`, with dense columns.
//! - The first damping follows the cost; a run of accepted steps that each gain under 2%
//!   is crawling and ends the finish as a local minimum, so the solver can restart.
//!
//! It stops within both tolerances, at the iteration cap, after `MAX_REJECTIONS`
//! consecutive rejections, or after `CRAWL_STEPS` crawling steps: a local minimum of the
//! error over the allowed set. The argument is in `docs/ik-limits.md`.

use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::{Chain, EffectorGoal, StopReason, rotation_angle};
use sinew_skeleton::limits::{JointLimit, SwingTwist};
use sinew_skeleton::{GlobalPose, Pose, Skeleton, SkeletonError};
use std::f64::consts::PI;

/// The first damping is the smaller of this times the mean diagonal of `J J^T` and
/// `COST_DAMPING` times the weighted cost.
const INITIAL_DAMPING: f64 = 0.1;
const COST_DAMPING: f64 = 0.1;
/// Consecutive rejections before the finish declares a local minimum.
const MAX_REJECTIONS: usize = 8;
/// The damping's growth after any rejected trial (a rejection that blocked nothing grows
/// it by 10 more).
const CLAMP_GROWTH: f64 = 2.0;
/// Accepted steps in a row that each lower the cost by less than `CRAWL_GAIN` (relative)
/// before the finish declares a local minimum.
const CRAWL_STEPS: usize = 4;
const CRAWL_GAIN: f64 = 0.02;
/// A hinge angle this close to a bound (radians) counts as on it.
const AT_BOUND: f64 = 1e-12;
/// A projection that turns a joint by more than this (radians) counts as a clamp.
const CLAMPED: f64 = 1e-12;

/// The active set of one movable chain joint.
#[derive(Clone, Copy, Debug, Default)]
struct Active {
    /// Frozen: none of its degrees of freedom moves (a hinge at a bound pushed outwards,
    /// or a three-axis joint with a third direction blocked).
    frozen: bool,
    /// The world directions of rotation blocked (orthonormal, the first `blocked_count`).
    blocked: [DVec3; 2],
    blocked_count: usize,
    /// The direction the last trial's projection pulled the joint back along (world).
    pulled_back: DVec3,
    /// Whether the last trial's projection clamped it.
    clamped: bool,
    /// Whether it may sit on its bound (clamped by an accepted trial, or the finish just
    /// started), and then the outward normals of its swing bound and its twist range as
    /// local rotation vectors (zero when off that bound or already blocked).
    on_bound: bool,
    outward: [DVec3; 2],
}

impl Active {
    /// Blocks the direction the projection pulled the joint back along: a hinge is
    /// frozen; a free or swing-twist joint loses that one direction and keeps sliding
    /// along its bound in the others, until a third direction would be blocked.
    fn block(&mut self, limit: &JointLimit) {
        if !matches!(limit, JointLimit::SwingTwist(_)) {
            self.frozen = true;
            return;
        }
        let mut d = self.pulled_back;
        for b in &self.blocked[..self.blocked_count] {
            d -= *b * b.dot(d);
        }
        match d.try_normalize() {
            Some(unit)
                if self.blocked_count < 2 && d.length() > 1e-3 * self.pulled_back.length() =>
            {
                self.blocked[self.blocked_count] = unit;
                self.blocked_count += 1;
            }
            _ => self.frozen = true,
        }
    }

    /// The outward normals of a swing-twist joint's bounds at `local`, by one-sided
    /// differences of the limit's violation (0 inside, growing linearly outside).
    fn find_outward(&mut self, limit: &JointLimit, local: DQuat) {
        const H: f64 = 1e-7;
        self.outward = [DVec3::ZERO; 2];
        if !self.on_bound {
            return;
        }
        let JointLimit::SwingTwist(st) = limit else {
            self.on_bound = false;
            return;
        };
        // The swing bound and the twist range are two constraints that can both be active
        // (a corner): one normal each, from the limit with the other one opened up.
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
        for (g, limit) in [swing_only, twist_only].iter().enumerate() {
            let mut n = DVec3::ZERO;
            for e in [DVec3::X, DVec3::Y, DVec3::Z] {
                let plus = limit.violation(DQuat::from_scaled_axis(e * H) * local);
                let minus = limit.violation(DQuat::from_scaled_axis(e * -H) * local);
                n += e * (plus - minus);
            }
            self.outward[g] = n.try_normalize().unwrap_or(DVec3::ZERO);
        }
        // Off both bounds: not watched again until a projection clamps it.
        self.on_bound = self.outward != [DVec3::ZERO; 2];
    }
}

/// Buffers of the finish, owned by the solver so a solve does not allocate once grown.
#[derive(Clone, Debug, Default)]
pub(crate) struct LimitedRefiner {
    /// Degrees of freedom: the chain position of the joint and the world axis.
    dofs: Vec<(usize, DVec3)>,
    /// Per movable chain joint: its active set.
    active: Vec<Active>,
    /// The chain's local rotations before a trial.
    saved: Vec<DQuat>,
    /// The step of each degree of freedom (radians).
    step: Vec<f64>,
    /// Per movable chain joint: the world rotation vector of the step.
    turn: Vec<DVec3>,
}

/// What a finish did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Finished {
    /// Why it stopped.
    pub stop: StopReason,
    /// Steps tried (accepted or not).
    pub steps: usize,
}

/// The weighted residual of `goal` at `global`: 3 position rows, then 3 rotation rows
/// (zero without a rotation goal or with rotation weight 0), and its squared norm.
fn residual(goal: &EffectorGoal, global: &GlobalPose) -> ([f64; 6], f64) {
    let to_target = (goal.position - global.positions[goal.joint]) * goal.position_weight;
    let mut r = [to_target.x, to_target.y, to_target.z, 0.0, 0.0, 0.0];
    if let Some(q) = goal.rotation {
        // The world rotation taking the effector's frame onto the goal's, as a rotation
        // vector (the shorter way round).
        let mut d = q.normalize() * global.rotations[goal.joint].conjugate();
        if d.w < 0.0 {
            d = -d;
        }
        let v = d.to_scaled_axis() * goal.rotation_weight;
        r[3] = v.x;
        r[4] = v.y;
        r[5] = v.z;
    }
    let norm = r.iter().map(|x| x * x).sum();
    (r, norm)
}

/// The weighted squared residual `|e|^2` of `goal` at `global`, the quantity the finish
/// decreases.
pub(crate) fn cost(goal: &EffectorGoal, global: &GlobalPose) -> f64 {
    residual(goal, global).1
}

/// The world axes of a joint's free degrees of freedom: none for a fixed or frozen joint,
/// a hinge's axis turned into the world by its parent's global rotation (a hinge rotation
/// composed on the left stays one), for a free or swing-twist joint an orthonormal basis
/// of the world directions its active set has not blocked (the world axes when none is:
/// exact for a rotation composed on the left, and never short of rank where the limit's
/// own frame would be at a quarter-turn swing).
fn joint_axes(limit: &JointLimit, parent: DQuat, active: &Active, mut push: impl FnMut(DVec3)) {
    if active.frozen {
        return;
    }
    match limit {
        JointLimit::Fixed => {}
        JointLimit::Hinge(h) => push((parent * h.axis).normalize()),
        JointLimit::Free | JointLimit::SwingTwist(_) => match active.blocked_count {
            0 => {
                for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
                    push(axis);
                }
            }
            1 => {
                let (u, v) = active.blocked[0].any_orthonormal_pair();
                push(u);
                push(v);
            }
            _ => {
                if let Some(u) = active.blocked[0].cross(active.blocked[1]).try_normalize() {
                    push(u);
                }
            }
        },
    }
}

impl LimitedRefiner {
    /// Runs the finish from `pose` (inside the limits; `global` its forward kinematics)
    /// until both tolerances are met, `iterations + steps` reaches `cap`, or it stops
    /// helping. Only steps that lower the weighted residual are kept.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn run(
        &mut self,
        skeleton: &Skeleton,
        chain: &Chain,
        goal: &EffectorGoal,
        pose: &mut Pose,
        global: &mut GlobalPose,
        tolerances: (f64, f64),
        iterations: usize,
        cap: usize,
    ) -> Result<Finished, SkeletonError> {
        let movable = &chain.joints()[..chain.bone_count()];
        let n = movable.len();
        self.active.clear();
        self.active.resize(
            n,
            Active {
                on_bound: true,
                ..Active::default()
            },
        );
        for (active, &j) in self.active.iter_mut().zip(movable) {
            active.find_outward(skeleton.limit(j), pose.rotations[j]);
        }
        self.turn.clear();
        self.turn.resize(n, DVec3::ZERO);
        let rows = if goal.rotation.is_some() { 6 } else { 3 };
        let (mut r, mut cost) = residual(goal, global);
        let mut damping = f64::NAN;
        let mut rejections = 0;
        let mut crawl = 0;
        let mut steps = 0;
        // Whether this pass recomputes the last step with fewer directions (not a new
        // step).
        let mut resolving = false;
        loop {
            let (position, rotation) = goal.errors(global);
            if position <= tolerances.0 && rotation <= tolerances.1 {
                return Ok(Finished {
                    stop: StopReason::Converged,
                    steps,
                });
            }
            if iterations + steps >= cap {
                return Ok(Finished {
                    stop: StopReason::IterationCap,
                    steps,
                });
            }
            if rejections >= MAX_REJECTIONS {
                return Ok(Finished {
                    stop: StopReason::LocalMinimum,
                    steps,
                });
            }
            let effector = global.positions[goal.joint];
            let column = |c: usize, u: DVec3| -> [f64; 6] {
                let p = u.cross(effector - global.positions[movable[c]]) * goal.position_weight;
                let w = u * goal.rotation_weight;
                [p.x, p.y, p.z, w.x, w.y, w.z]
            };
            // The directions the active set leaves free.
            self.dofs.clear();
            for (c, &j) in movable.iter().enumerate() {
                let parent = skeleton
                    .parent(j)
                    .map_or(DQuat::IDENTITY, |p| global.rotations[p]);
                let dofs = &mut self.dofs;
                joint_axes(skeleton.limit(j), parent, &self.active[c], |axis| {
                    dofs.push((c, axis));
                });
            }
            if self.dofs.is_empty() {
                return Ok(Finished {
                    stop: StopReason::LocalMinimum,
                    steps,
                });
            }
            let mut normal = [[0.0; 6]; 6];
            for &(c, u) in &self.dofs {
                let col = column(c, u);
                for a in 0..rows {
                    for b in 0..=a {
                        normal[a][b] += col[a] * col[b];
                    }
                }
            }
            if damping.is_nan() {
                let trace: f64 = (0..rows).map(|a| normal[a][a]).sum();
                // Far from the goal a cautious first step, near it a nearly Gauss-Newton
                // one: the damping follows the cost (Yamashita and Fukushima's choice
                // `lambda = |r|^2`), capped by the scale of `J J^T`.
                damping = (INITIAL_DAMPING * trace / rows as f64).min(COST_DAMPING * cost);
            }
            if !resolving {
                steps += 1;
            }
            resolving = false;
            let Some(y) = solve_damped(&normal, rows, damping, &r) else {
                damping = damping.max(f64::MIN_POSITIVE) * 10.0;
                rejections += 1;
                continue;
            };
            self.step.clear();
            self.turn.fill(DVec3::ZERO);
            for &(c, u) in &self.dofs {
                let col = column(c, u);
                let s: f64 = (0..rows).map(|a| col[a] * y[a]).sum();
                self.step.push(s);
                self.turn[c] += u * s;
            }
            // A hinge is a box constraint on its angle, so its active set is exact: a hinge
            // at a bound whose step points outwards would only be clamped back, while the
            // other joints moved as if it had turned. Leave it out and solve again (the
            // same step, not counted twice), so the step is the reduced problem's.
            for (&(c, _), &step) in self.dofs.iter().zip(&self.step) {
                let j = movable[c];
                if let JointLimit::Hinge(h) = skeleton.limit(j)
                    && h.pushes_outwards(pose.rotations[j], step, AT_BOUND)
                {
                    self.active[c].frozen = true;
                    resolving = true;
                }
            }
            // The same for a swing-twist joint on its bound: the step's component along
            // the bound's outward normal would be projected away; block that direction
            // (the joint keeps sliding along the bound) and solve again.
            for (c, &j) in movable.iter().enumerate() {
                let w = self.turn[c];
                let active = &mut self.active[c];
                if active.frozen || active.outward == [DVec3::ZERO; 2] || w == DVec3::ZERO {
                    continue;
                }
                let parent = skeleton
                    .parent(j)
                    .map_or(DQuat::IDENTITY, |p| global.rotations[p]);
                let local = parent.conjugate() * w;
                for g in 0..2 {
                    let normal = active.outward[g];
                    if normal != DVec3::ZERO && local.dot(normal) > 0.0 {
                        active.pulled_back = parent * normal;
                        active.block(skeleton.limit(j));
                        // Blocked once per linearization: the normal is not asked again.
                        active.outward[g] = DVec3::ZERO;
                        resolving = true;
                        break;
                    }
                }
            }
            if resolving {
                continue;
            }
            // Trial: turn each joint by its step (world axes taken into the parent's
            // frame of the linearization), project it onto its limit.
            self.saved.clear();
            self.saved
                .extend(movable.iter().map(|&j| pose.rotations[j]));
            for (c, &j) in movable.iter().enumerate() {
                let w = self.turn[c];
                let active = &mut self.active[c];
                active.clamped = false;
                if w == DVec3::ZERO {
                    continue;
                }
                let parent = skeleton.parent(j).map(|p| global.rotations[p]);
                let local = parent.map_or(w, |p| p.conjugate() * w);
                let turned = (DQuat::from_scaled_axis(local) * pose.rotations[j]).normalize();
                let limit = skeleton.limit(j);
                if matches!(limit, JointLimit::Free) {
                    pose.rotations[j] = turned;
                } else {
                    let projected = limit.project(turned);
                    active.clamped = rotation_angle(turned, projected) > CLAMPED;
                    if active.clamped {
                        // The pull-back as a world rotation vector: composed on the left
                        // in the parent's frame, then turned into the world like the step.
                        let mut back = projected * turned.conjugate();
                        if back.w < 0.0 {
                            back = -back;
                        }
                        let back = back.to_scaled_axis();
                        active.pulled_back = parent.map_or(back, |p| p * back);
                    }
                    pose.rotations[j] = projected;
                }
            }
            skeleton.forward_kinematics_from(pose, chain.base(), global)?;
            let (trial_r, trial_cost) = residual(goal, global);
            if trial_cost < cost {
                // Crawling along the bounds: accepted steps that each gain almost nothing
                // are a local minimum in all but name; say so, so that the caller may
                // restart, rather than spend the iterations.
                if trial_cost > (1.0 - CRAWL_GAIN) * cost {
                    crawl += 1;
                } else {
                    crawl = 0;
                }
                r = trial_r;
                cost = trial_cost;
                if crawl >= CRAWL_STEPS {
                    return Ok(Finished {
                        stop: StopReason::LocalMinimum,
                        steps,
                    });
                }
                damping /= 3.0;
                rejections = 0;
                // A new point, a new active set: every joint may move again, and the
                // ones a projection left on a bound are watched there.
                for (active, &j) in self.active.iter_mut().zip(movable) {
                    active.frozen = false;
                    active.blocked_count = 0;
                    active.on_bound |= active.clamped;
                    active.find_outward(skeleton.limit(j), pose.rotations[j]);
                }
                continue;
            }
            for (&saved, &j) in self.saved.iter().zip(movable) {
                pose.rotations[j] = saved;
            }
            skeleton.forward_kinematics_from(pose, chain.base(), global)?;
            // A rejected trial means the step was too long for the linearization or for
            // the bounds: shorten the next one too, whether or not a joint was blocked.
            // Joints the projection clamped lose the direction they were pulled back
            // along, and the step is recomputed.
            damping *= CLAMP_GROWTH;
            let mut newly_blocked = false;
            for (active, &j) in self.active.iter_mut().zip(movable) {
                if active.clamped && !active.frozen {
                    active.block(skeleton.limit(j));
                    newly_blocked = true;
                }
            }
            if !newly_blocked {
                damping = (damping * 10.0).max(f64::MIN_POSITIVE);
                rejections += 1;
            }
        }
    }
}

/// Solves `(N + damping I) y = r` for the symmetric positive semidefinite `N` (its lower
/// triangle in `normal`, `rows` x `rows`) by Cholesky. `None` when a pivot is not a
/// positive finite number.
fn solve_damped(
    normal: &[[f64; 6]; 6],
    rows: usize,
    damping: f64,
    r: &[f64; 6],
) -> Option<[f64; 6]> {
    let mut l = [[0.0; 6]; 6];
    for a in 0..rows {
        for b in 0..=a {
            let mut sum = normal[a][b] + if a == b { damping } else { 0.0 };
            sum -= (0..b).map(|k| l[a][k] * l[b][k]).sum::<f64>();
            if a == b {
                if !(sum.is_finite() && sum > 0.0) {
                    return None;
                }
                l[a][a] = sum.sqrt();
            } else {
                l[a][b] = sum / l[b][b];
            }
        }
    }
    let mut z = [0.0; 6];
    for a in 0..rows {
        let sum = r[a] - (0..a).map(|k| l[a][k] * z[k]).sum::<f64>();
        z[a] = sum / l[a][a];
    }
    let mut y = [0.0; 6];
    for a in (0..rows).rev() {
        let sum = z[a] - (a + 1..rows).map(|k| l[k][a] * y[k]).sum::<f64>();
        y[a] = sum / l[a][a];
    }
    y.iter().all(|v| v.is_finite()).then_some(y)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_damped_cholesky_solve_inverts_the_matrix() {
        let cols = [
            [1.0, 0.5, -0.3, 0.2, 0.0, 1.0],
            [0.0, 2.0, 0.1, -1.0, 0.3, 0.0],
            [0.7, -0.2, 1.5, 0.0, 0.9, 0.4],
        ];
        let mut normal = [[0.0; 6]; 6];
        for col in &cols {
            for a in 0..6 {
                for b in 0..=a {
                    normal[a][b] += col[a] * col[b];
                }
            }
        }
        let r = [1.0, -2.0, 0.5, 0.25, 3.0, -1.0];
        let damping = 0.1;
        let y = solve_damped(&normal, 6, damping, &r).unwrap();
        for a in 0..6 {
            let mut back = damping * y[a];
            for b in 0..6 {
                let n = if b <= a { normal[a][b] } else { normal[b][a] };
                back += n * y[b];
            }
            assert!((back - r[a]).abs() < 1e-12, "row {a}: {back} vs {}", r[a]);
        }
        // The zero matrix without damping: a zero pivot, no solution rather than NaN.
        assert_eq!(solve_damped(&[[0.0; 6]; 6], 6, 0.0, &r), None);
    }
}
