//! The damped least-squares finish for chains with joint limits or a rotation goal:
//! Levenberg-Marquardt steps on the chain's local rotations, each step projected onto the
//! joint limits, with an active set, over a residual of 3 rows (position) or 6 (position
//! and rotation).
//!
//! Unlike the position-only refinement (`refine.rs`, which works on free bone vectors),
//! this one works on the pose itself, because a limit constrains a joint's local rotation
//! and the rotation goal needs the effector's frame:
//!
//! - Degrees of freedom per joint, as world-frame rotation axes, in two groups a limit
//!   can stop separately: a free joint has the three world axes; a hinge its axis turned
//!   into the world by its parent's global rotation (a hinge rotation composed on the left
//!   stays a hinge rotation); a swing-twist joint its twist axis turned by its own global
//!   rotation (composed on the right, it changes the twist only) and its two swing axes
//!   turned by its parent's; a fixed joint none.
//! - A degree of freedom with world axis `u` at the joint's position `P` moves the
//!   effector `E` by `u x (E - P)` and turns it by `u`, per radian: the Jacobian columns.
//!   The weighted residual is `e = (wp (target - E), wr log(goal G_E^-1))`; the damped
//!   step solves `(J J^T + lambda I) y = e` (3 x 3 or 6 x 6, by Cholesky) and moves each
//!   degree of freedom by `J_k . y`.
//! - Every trial pose is projected onto the limits joint by joint, so every pose the
//!   finish accepts is inside them. A trial is kept only when it lowers `|e|^2`.
//! - Hinges: a hinge on a bound whose step points outwards is left out before the trial
//!   and the step solved again (its constraint is a box on its angle, so this part of the
//!   active set is exact).
//! - Active set: a joint the projection clamped (the step pushed it out of its limit) is
//!   frozen, its columns left out (its groups are not independent: a swing step composed
//!   on the left also moves the twist, so the whole joint); after a rejected trial that
//!   froze a joint the step is recomputed at the same damping, so the other joints do
//!   the work. An accepted step starts a new active set (every joint free again). Only a
//!   rejection that froze nothing grows the damping.
//!
//! It stops within both tolerances, at the iteration cap, or after `MAX_REJECTIONS`
//! consecutive rejections (the damping then 1e8 times larger): a local minimum of the
//! error over the allowed set. The argument is in `docs/ik-limits.md`.

use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::{Chain, EffectorGoal, StopReason, rotation_angle};
use sinew_skeleton::limits::{JointLimit, swing_twist};
use sinew_skeleton::{GlobalPose, Pose, Skeleton, SkeletonError};

/// Relative to the trace of `J J^T`: the first damping (nearly Gauss-Newton).
const INITIAL_DAMPING: f64 = 1e-6;
/// Consecutive rejections before the finish declares a local minimum.
const MAX_REJECTIONS: usize = 8;
/// A hinge angle this close to a bound (radians) counts as on it.
const AT_BOUND: f64 = 1e-12;
/// A projection that turns a joint by more than this (radians) counts as a clamp.
const CLAMPED: f64 = 1e-12;

/// A joint's degrees of freedom come in two groups that its limit can stop separately:
/// the twist (for a hinge: its one axis) and the swing (the two axes across the bone).
const TWIST: usize = 0;
const SWING: usize = 1;

/// Buffers of the finish, owned by the solver so a solve does not allocate once grown.
#[derive(Clone, Debug, Default)]
pub(crate) struct LimitedRefiner {
    /// Degrees of freedom: the chain position of the joint, its group, the world axis.
    dofs: Vec<(usize, usize, DVec3)>,
    /// Per movable chain joint and group: frozen by the active set (at its limit, with
    /// the residual pushing it outwards).
    frozen: Vec<[bool; 2]>,
    /// Per movable chain joint and group: whether the last trial's projection clamped it.
    clamped: Vec<[bool; 2]>,
    /// The chain's local rotations before a trial.
    saved: Vec<DQuat>,
    /// The step of each degree of freedom (radians).
    step: Vec<f64>,
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

/// Which groups of `limit` the projection from `turned` to `projected` moved.
fn clamped_groups(limit: &JointLimit, turned: DQuat, projected: DQuat) -> [bool; 2] {
    match limit {
        JointLimit::Free | JointLimit::Fixed => [false, false],
        JointLimit::Hinge(_) => [rotation_angle(turned, projected) > CLAMPED, false],
        JointLimit::SwingTwist(st) => {
            let (swing_a, twist_a) = swing_twist(turned, st.twist_axis);
            let (swing_b, twist_b) = swing_twist(projected, st.twist_axis);
            [
                rotation_angle(twist_a, twist_b) > CLAMPED,
                rotation_angle(swing_a, swing_b) > CLAMPED,
            ]
        }
    }
}

/// The world axes of joint `j`'s degrees of freedom, by group, given its parent's global
/// rotation and its own local rotation: a free joint the world axes (one group, never
/// clamped), a hinge its axis turned into the world by the parent (a hinge rotation
/// composed on the left stays one), a swing-twist joint its twist axis turned by its own
/// global rotation (composed on the right, it changes the twist only) and its two swing
/// axes turned by the parent.
fn joint_axes(limit: &JointLimit, parent: DQuat, local: DQuat, mut push: impl FnMut(usize, DVec3)) {
    match limit {
        JointLimit::Fixed => {}
        JointLimit::Free => {
            for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
                push(SWING, axis);
            }
        }
        JointLimit::Hinge(h) => push(TWIST, (parent * h.axis).normalize()),
        JointLimit::SwingTwist(_) => {
            // The world axes: any three spanning axes are exact (the columns are world
            // rotations composed on the left), and these never lose rank, where the
            // limit's own frame would at a swing of a quarter turn.
            let _ = (parent, local);
            for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
                push(SWING, axis);
            }
        }
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
        self.frozen.clear();
        self.frozen.resize(n, [false; 2]);
        self.clamped.clear();
        self.clamped.resize(n, [false; 2]);
        let rows = if goal.rotation.is_some() { 6 } else { 3 };
        let (mut r, mut cost) = residual(goal, global);
        let mut damping = f64::NAN;
        let mut rejections = 0;
        let mut steps = 0;
        // Whether this pass recomputes the last step with fewer joints (not a new step).
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
            // The degrees of freedom of the joints the active set leaves free.
            self.dofs.clear();
            for (c, &j) in movable.iter().enumerate() {
                let parent = skeleton
                    .parent(j)
                    .map_or(DQuat::IDENTITY, |p| global.rotations[p]);
                let limit = skeleton.limit(j);
                let frozen = self.frozen[c];
                let dofs = &mut self.dofs;
                joint_axes(limit, parent, pose.rotations[j], |group, axis| {
                    if !frozen[group] {
                        dofs.push((c, group, axis));
                    }
                });
            }
            if self.dofs.is_empty() {
                return Ok(Finished {
                    stop: StopReason::LocalMinimum,
                    steps,
                });
            }
            let mut normal = [[0.0; 6]; 6];
            for &(c, _, u) in &self.dofs {
                let col = column(c, u);
                for a in 0..rows {
                    for b in 0..=a {
                        normal[a][b] += col[a] * col[b];
                    }
                }
            }
            if damping.is_nan() {
                let trace: f64 = (0..rows).map(|a| normal[a][a]).sum();
                damping = INITIAL_DAMPING * trace / rows as f64;
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
            for &(c, _, u) in &self.dofs {
                let col = column(c, u);
                self.step.push((0..rows).map(|a| col[a] * y[a]).sum());
            }
            // A hinge is a box constraint on its angle, so its active set is exact: a hinge
            // at a bound whose step points outwards would only be clamped back, while the
            // other joints moved as if it had turned. Leave it out and solve again (the
            // same step, not counted twice), so the step is the reduced problem's.
            for (&(c, _, _), &step) in self.dofs.iter().zip(&self.step) {
                let j = movable[c];
                if let JointLimit::Hinge(h) = skeleton.limit(j)
                    && h.pushes_outwards(pose.rotations[j], step, AT_BOUND)
                {
                    self.frozen[c] = [true; 2];
                    resolving = true;
                }
            }
            if resolving {
                continue;
            }
            // Trial: turn each joint by its degrees of freedom (world axes taken into the
            // parent's frame of the linearization), project it onto its limit.
            self.saved.clear();
            self.saved
                .extend(movable.iter().map(|&j| pose.rotations[j]));
            let mut k = 0;
            for (c, &j) in movable.iter().enumerate() {
                let mut w = DVec3::ZERO;
                while k < self.dofs.len() && self.dofs[k].0 == c {
                    w += self.dofs[k].2 * self.step[k];
                    k += 1;
                }
                self.clamped[c] = [false; 2];
                if w == DVec3::ZERO {
                    continue;
                }
                let local = match skeleton.parent(j) {
                    Some(p) => global.rotations[p].conjugate() * w,
                    None => w,
                };
                let turned = (DQuat::from_scaled_axis(local) * pose.rotations[j]).normalize();
                let limit = skeleton.limit(j);
                if matches!(limit, JointLimit::Free) {
                    pose.rotations[j] = turned;
                } else {
                    let projected = limit.project(turned);
                    self.clamped[c] = clamped_groups(limit, turned, projected);
                    pose.rotations[j] = projected;
                }
            }
            skeleton.forward_kinematics_from(pose, chain.base(), global)?;
            let (trial_r, trial_cost) = residual(goal, global);
            if trial_cost < cost {
                r = trial_r;
                cost = trial_cost;
                damping /= 3.0;
                rejections = 0;
                // A new point, a new active set: every joint may move again.
                for frozen in &mut self.frozen {
                    *frozen = [false; 2];
                }
                continue;
            }
            for (&saved, &j) in self.saved.iter().zip(movable) {
                pose.rotations[j] = saved;
            }
            skeleton.forward_kinematics_from(pose, chain.base(), global)?;
            // Joints the projection clamped are at their limit with the step pushing
            // outwards: freeze them and retry at the same damping.
            let mut newly_frozen = false;
            for (frozen, clamped) in self.frozen.iter_mut().zip(&self.clamped) {
                // The groups of a joint are not independent (a swing step composed on
                // the left also moves the twist), so a clamp freezes the whole joint.
                if *clamped != [false; 2] && *frozen != [true; 2] {
                    *frozen = [true; 2];
                    newly_frozen = true;
                }
            }
            if !newly_frozen {
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
