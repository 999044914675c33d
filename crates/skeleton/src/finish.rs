//! The damped least-squares finish every IK solver of sinew ends with: Levenberg-Marquardt
//! steps on the local rotations of a set of joints (and on a translation of the whole
//! skeleton, when it may translate), over the residual of several effectors with position
//! and rotation rows and weights, every trial projected onto the joint limits, with a
//! sliding active set on the limits' bounds.
//!
//! The chain solvers (FABRIK, CCD) run it with one effector and the chain's joints
//! ([`ChainFinish`]); the full-body solvers with every effector of the body and the joints
//! above them ([`Movers::build`]). The derivation is in `docs/ik-finish.md`; in short:
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
//!   solved again; a swing-twist joint on its swing or twist bound whose step has a
//!   component along the bound's outward normal loses that direction, so it slides along
//!   the bound; after a rejected trial, the direction each clamped joint was pulled back
//!   along is blocked the same way and the step recomputed. An accepted step frees every
//!   joint again.
//!
//! It stops when every effector is within both tolerances, at the iteration cap, after
//! `MAX_REJECTIONS` consecutive rejections, or after `CRAWL_STEPS` accepted steps that
//! each gain almost nothing: a local minimum of the cost over the allowed set, which for
//! conflicting goals is the weighted least-squares best. A caller may also ask it to stop
//! in a local minimum when the cost has not fallen tenfold over a window of steps
//! ([`FinishJob::stall_window`]), so that it restarts rather than crawls.

use crate::ik::{Chain, EffectorGoal, SolveSettings, StopReason, rotation_angle};
use crate::limits::{JointLimit, LimitFrame};
use crate::{GlobalPose, Pose, Skeleton, SkeletonError};
use sinew_math::{DQuat, DVec3};
use std::sync::OnceLock;

/// The first damping is the smaller of this times the mean diagonal of `J J^T` and
/// `COST_DAMPING` times the weighted cost.
const INITIAL_DAMPING: f64 = 0.1;
const COST_DAMPING: f64 = 0.1;
/// Consecutive rejections before the finish declares a local minimum.
const MAX_REJECTIONS: usize = 8;
/// The damping's growth after any rejected trial (a rejection that blocked nothing grows
/// it by 10 more).
const CLAMP_GROWTH: f64 = 2.0;
/// How much further than it may end a step may take a pinned effector from its pin.
const PIN_SLACK: f64 = 1e4;
/// Accepted steps in a row that each lower the cost by less than `CRAWL_GAIN` (relative)
/// before the finish declares a local minimum.
const CRAWL_STEPS: usize = 4;
const CRAWL_GAIN: f64 = 0.02;
/// Up to this many rows the Cholesky factor is made row by row, without its transpose
/// (see [`Finish::factorize`]).
const SMALL_ROWS: usize = 6;
/// See [`FinishJob::stall_window`].
const STALL_FACTOR: f64 = 10.0;
/// An accepted step that leaves at most this fraction of the cost makes the next trial a
/// chord step (the same factor, the new residual), at most `MAX_CHORDS` in a row.
const CHORD_GAIN: f64 = 0.01;
const MAX_CHORDS: usize = 3;
/// A hinge angle this close to a bound (radians) counts as on it.
const AT_BOUND: f64 = 1e-12;
/// A projection that turns a joint by more than this (radians) counts as a clamp.
const CLAMPED: f64 = 1e-12;
/// How far inside both constraints of its limit (radians) a swing-twist joint counts as
/// off its bounds without differencing: a thousand times the difference step, so the
/// perturbed rotations cannot reach a bound.
const DEEP_INSIDE: f64 = crate::limits::DEEP_MARGIN;
/// The difference step of the outward normals (radians).
const H: f64 = 1e-7;
/// The turns by `H` and `-H` about each world axis, for the outward normals.
static NUDGES: OnceLock<[[DQuat; 2]; 3]> = OnceLock::new();
/// The dof "joint" index of the translation.
const TRANSLATION: usize = usize::MAX;
/// A movable joint without degrees of freedom (a fixed joint).
const NO_DOF: usize = usize::MAX;
/// Not a movable joint.
const NONE: usize = usize::MAX;

/// One effector's goal as the finish uses it: the weights final (a pinned effector's
/// already scaled by its caller).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Target {
    /// The effector's joint.
    pub joint: usize,
    /// Where the joint should be (world frame).
    pub position: DVec3,
    /// The global rotation it should have, normalized, if any.
    pub rotation: Option<DQuat>,
    /// The weight of the three position rows (> 0).
    pub position_weight: f64,
    /// The weight of the three rotation rows (>= 0; 0 leaves the rotation out).
    pub rotation_weight: f64,
    /// A pinned effector may not end further from its goal position than the tolerance
    /// (or than it was when the finish started, if further).
    pub pinned: bool,
}

impl Target {
    /// The target of a goal: its rotation normalized, not pinned.
    #[must_use]
    pub fn from_goal(goal: &EffectorGoal) -> Self {
        Self {
            joint: goal.joint,
            position: goal.position,
            rotation: goal.rotation.map(DQuat::normalize),
            position_weight: goal.position_weight,
            rotation_weight: goal.rotation_weight,
            pinned: false,
        }
    }

    /// Whether the rotation goal takes part in the cost (a goal with weight 0 does not).
    #[must_use]
    pub fn has_rotation(&self) -> bool {
        self.rotation.is_some() && self.rotation_weight > 0.0
    }

    /// Position and rotation errors at `global` (the rotation error 0 without a goal).
    #[must_use]
    pub fn errors(&self, global: &GlobalPose) -> (f64, f64) {
        let position = global.positions[self.joint].distance(self.position);
        let rotation = self
            .rotation
            .map_or(0.0, |q| rotation_angle(global.rotations[self.joint], q));
        (position, rotation)
    }

    /// The world rotation vector from the effector's frame to the goal's (the shorter
    /// way round), zero without a rotation goal.
    #[must_use]
    pub fn rotation_residual(&self, global: &GlobalPose) -> DVec3 {
        match self.rotation {
            Some(q) => {
                let mut d = q * global.rotations[self.joint].conjugate();
                if d.w < 0.0 {
                    d = -d;
                }
                d.normalize().to_scaled_axis()
            }
            None => DVec3::ZERO,
        }
    }

    /// This effector's term of the weighted cost,
    /// `wp^2 |t - x|^2 + wr^2 |log(q g^-1)|^2`.
    #[must_use]
    pub fn cost(&self, global: &GlobalPose) -> f64 {
        let position = (self.position - global.positions[self.joint]).length_squared();
        let mut c = self.position_weight * self.position_weight * position;
        if self.has_rotation() {
            let w = self.rotation_weight;
            c += w * w * self.rotation_residual(global).length_squared();
        }
        c
    }
}

/// The weighted cost of every target at `global`, the quantity the finish decreases.
#[must_use]
pub fn total_cost(targets: &[Target], global: &GlobalPose) -> f64 {
    targets.iter().map(|t| t.cost(global)).sum()
}

/// Whether every target is within the tolerances of `settings` at `global` (a rotation
/// goal with weight 0 does not count).
#[must_use]
pub fn all_within(targets: &[Target], global: &GlobalPose, settings: &SolveSettings) -> bool {
    targets.iter().all(|t| {
        let (p, r) = t.errors(global);
        p <= settings.tolerance && (!t.has_rotation() || r <= settings.rotation_tolerance)
    })
}

/// Whether every pinned target is within `max(tolerance, allowed[e])` of its pin.
#[must_use]
pub fn pins_hold(targets: &[Target], global: &GlobalPose, tolerance: f64, allowed: &[f64]) -> bool {
    targets.iter().zip(allowed).all(|(t, &allowed)| {
        !t.pinned || global.positions[t.joint].distance(t.position) <= tolerance.max(allowed)
    })
}

/// Forward kinematics of `pose` with every position moved by `translation`, from joint
/// `from` and its descendants only when given (the rest of `out` must already be that of
/// `pose`), else of the whole skeleton. A joint with a parent takes its position from the
/// (already translated) parent, so only a root needs the whole computation.
pub fn translated_forward_kinematics(
    skeleton: &Skeleton,
    pose: &Pose,
    translation: DVec3,
    from: Option<usize>,
    out: &mut GlobalPose,
) -> Result<(), SkeletonError> {
    if let Some(joint) = from
        && (skeleton.parent(joint).is_some() || translation == DVec3::ZERO)
        && out.positions.len() == skeleton.len()
    {
        return skeleton.forward_kinematics_from(pose, joint, out);
    }
    skeleton.forward_kinematics(pose, out)?;
    if translation != DVec3::ZERO {
        for p in &mut out.positions {
            *p += translation;
        }
    }
    Ok(())
}

/// Which joints a finish turns, and which effectors each of them moves, as compressed
/// lists. Built without allocation once its buffers have grown.
///
/// For a body ([`Movers::build`]) a joint moves an effector when it is a strict ancestor
/// of the effector's joint (its rotation carries the effector's position and frame), or
/// when it is the effector's own joint and the effector has a rotation goal (a joint's
/// rotation turns its own frame but not its position); every other joint cannot change
/// the cost. For a chain ([`Movers::chain`]) the chain's joints move its one effector.
#[derive(Clone, Debug, Default)]
pub struct Movers {
    /// The movable joints, in increasing index (topological) order.
    movable: Vec<usize>,
    /// `below[start[m]..start[m + 1]]`: the effectors (indices into the targets, in
    /// increasing order) that movable joint `m` moves.
    start: Vec<usize>,
    below: Vec<usize>,
    /// Per joint: its index in `movable`, or `NONE`.
    slot: Vec<usize>,
    /// Per joint: how many effectors it moves (then a fill cursor).
    count: Vec<usize>,
    /// The largest entry of `movable` and of `below` (`None` when empty), kept by the
    /// only two functions that write the lists, so that [`FinishJob::validate`] checks
    /// every entry against the skeleton and the targets without scanning the lists on
    /// every run.
    largest_movable: Option<usize>,
    largest_below: Option<usize>,
}

impl Movers {
    /// Recomputes the lists for `targets` on `skeleton` (every ancestor of an effector,
    /// and an effector's own joint when it has a rotation goal), in O(joints + sum of
    /// effector depths).
    pub fn build(&mut self, skeleton: &Skeleton, targets: &[Target]) {
        let n = skeleton.len();
        self.count.clear();
        self.count.resize(n, 0);
        let count = &mut self.count;
        Self::walk(skeleton, targets, |j, _| count[j] += 1);
        self.movable.clear();
        self.slot.clear();
        self.slot.resize(n, NONE);
        self.start.clear();
        let mut total = 0;
        for j in 0..n {
            if self.count[j] > 0 {
                self.slot[j] = self.movable.len();
                self.movable.push(j);
                self.start.push(total);
                total += self.count[j];
                // From here on `count` is the fill cursor of the joint's list.
                self.count[j] = self.start[self.slot[j]];
            }
        }
        self.start.push(total);
        self.below.clear();
        self.below.resize(total, 0);
        let below = &mut self.below;
        let cursor = &mut self.count;
        Self::walk(skeleton, targets, |j, e| {
            below[cursor[j]] = e;
            cursor[j] += 1;
        });
        self.note_largest();
    }

    /// Records the largest entries of the lists just written.
    fn note_largest(&mut self) {
        self.largest_movable = self.movable.iter().copied().max();
        self.largest_below = self.below.iter().copied().max();
    }

    /// The lists of a chain: the joints `movable` (in increasing order, each a descendant
    /// of the one before) all move the one effector.
    pub fn chain(&mut self, movable: &[usize]) {
        self.movable.clear();
        self.movable.extend_from_slice(movable);
        self.start.clear();
        self.start.extend(0..=movable.len());
        self.below.clear();
        self.below.resize(movable.len(), 0);
        self.slot.clear();
        self.count.clear();
        self.note_largest();
    }

    /// The movable joints, in increasing index order.
    #[must_use]
    pub fn movable(&self) -> &[usize] {
        &self.movable
    }

    /// The effectors (indices into the targets, increasing) movable joint `m` moves.
    #[must_use]
    pub fn below(&self, m: usize) -> &[usize] {
        &self.below[self.start[m]..self.start[m + 1]]
    }

    /// The index in [`Movers::movable`] of joint `j` (after [`Movers::build`]), if it is
    /// movable.
    #[must_use]
    pub fn slot(&self, j: usize) -> Option<usize> {
        self.slot.get(j).copied().filter(|&m| m != NONE)
    }

    /// Calls `f(joint, effector)` for every joint that moves each effector, effectors in
    /// order, so every joint's list comes out in increasing effector order.
    fn walk(skeleton: &Skeleton, targets: &[Target], mut f: impl FnMut(usize, usize)) {
        for (e, target) in targets.iter().enumerate() {
            if target.has_rotation() {
                f(target.joint, e);
            }
            let mut j = skeleton.parent(target.joint);
            while let Some(k) = j {
                f(k, e);
                j = skeleton.parent(k);
            }
        }
    }
}

/// What a finish works on, besides the pose.
#[derive(Clone, Copy, Debug)]
pub struct FinishJob<'a> {
    /// The skeleton, with its joint limits.
    pub skeleton: &'a Skeleton,
    /// The joints the finish turns and the effectors each one moves.
    pub movers: &'a Movers,
    /// The effectors' goals, indexed as in `movers`.
    pub targets: &'a [Target],
    /// Whether the whole skeleton may translate (three more degrees of freedom).
    pub translates: bool,
    /// A joint whose subtree holds every movable joint, so that forward kinematics after
    /// a step starts there; `None` recomputes the whole skeleton.
    pub base: Option<usize>,
    /// Tolerances and the iteration cap (the finish's steps count with `iterations`).
    pub settings: SolveSettings,
    /// Iterations the caller already spent.
    pub iterations: usize,
    /// Whether the first trial may be a chord step with the factor and columns of this
    /// [`Finish`]'s last linearization (see `docs/ik-finish.md`, "A warm frame starts
    /// with a chord step"). The caller vouches that the skeleton, the movers and the
    /// targets (joints, weights, which have rotation goals) are those of that
    /// linearization, only the goals having moved; the step is a trial like any other,
    /// kept only when it lowers the cost and keeps the pins.
    pub chord_start: bool,
    /// A finish whose cost has not fallen by `STALL_FACTOR` over this many steps stops in
    /// a local minimum (so that its caller may restart), however it got there; 0 never.
    pub stall_window: usize,
    /// After an accepted step the damping is at most this times the new cost (as well as
    /// divided by 3), so that it follows the cost down as Yamashita and Fukushima's
    /// `lambda = |r|^2` does and the last steps (and the chord steps on their factor)
    /// are nearly Gauss-Newton; `f64::INFINITY` leaves it to the division alone. See
    /// `docs/ik-finish.md` for where it pays and where it does not.
    pub damping_cap: f64,
}

/// How far from 1 the length of a target's rotation may be: a normalized quaternion's
/// length is 1 to a few ulps, so this catches a rotation that was never normalized, not
/// the rounding of one that was.
const UNIT_SLACK: f64 = 1e-9;

impl FinishJob<'_> {
    /// Checks every field a finish reads, so that a bad job is an error naming the field
    /// rather than a panic (an index out of range) or NaN in the pose:
    ///
    /// - `settings.tolerance` and `settings.rotation_tolerance` finite and `>= 0`;
    ///   `iterations` (already spent) at most `settings.max_iterations` (any cap is
    ///   valid, 0 allowing no step);
    /// - `damping_cap` `> 0`, finite or `+inf` (0 or below would make every step after
    ///   the first undamped Gauss-Newton whatever the cost, NaN would be ignored by the
    ///   comparison that applies it);
    /// - `stall_window`: every value is valid (0 turns the rule off; a window longer than
    ///   the iteration cap never fires), so it is not checked;
    /// - `base` and every movable joint of `movers` joints of `skeleton`, and every
    ///   effector they list one of `targets`;
    /// - each target's joint in the skeleton, its position finite, its position weight
    ///   finite and `> 0`, its rotation weight finite and `>= 0`, its rotation (if any)
    ///   finite and of length 1.
    pub fn validate(&self) -> Result<(), SkeletonError> {
        let bad =
            |field: String, reason: String| Err(SkeletonError::InvalidFinishJob { field, reason });
        let settings = &self.settings;
        for (name, value) in [
            ("settings.tolerance", settings.tolerance),
            ("settings.rotation_tolerance", settings.rotation_tolerance),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return bad(name.into(), format!("must be finite and >= 0, got {value}"));
            }
        }
        if self.iterations > settings.max_iterations {
            return bad(
                "iterations".into(),
                format!(
                    "{} already spent exceeds the iteration cap settings.max_iterations = {}",
                    self.iterations, settings.max_iterations
                ),
            );
        }
        if self.damping_cap.is_nan() || self.damping_cap <= 0.0 {
            return bad(
                "damping_cap".into(),
                format!("must be > 0 (or +inf), got {}", self.damping_cap),
            );
        }
        let joints = self.skeleton.len();
        if let Some(base) = self.base
            && base >= joints
        {
            return bad(
                "base".into(),
                format!("joint {base} is not in the skeleton of {joints} joints"),
            );
        }
        // The lists' largest entries are kept by `Movers` as it writes them (no scan per
        // run); the entry to name is looked for only when one is bad.
        let movable = self.movers.movable();
        let targets = self.targets.len();
        if self.movers.largest_movable.is_some_and(|j| j >= joints) {
            let m = movable.iter().position(|&j| j >= joints).unwrap_or(0);
            return bad(
                format!("movers.movable[{m}]"),
                format!(
                    "joint {} is not in the skeleton of {joints} joints",
                    movable[m]
                ),
            );
        }
        if self.movers.largest_below.is_some_and(|e| e >= targets) {
            let m = (0..movable.len())
                .find(|&m| self.movers.below(m).iter().any(|&e| e >= targets))
                .unwrap_or(0);
            let e = self.movers.below(m).iter().fold(0, |a, &e| a.max(e));
            return bad(
                format!("movers.below({m})"),
                format!("effector {e} is not one of the {targets} targets"),
            );
        }
        for (e, t) in self.targets.iter().enumerate() {
            if t.joint >= joints {
                return bad(
                    format!("targets[{e}].joint"),
                    format!(
                        "joint {} is not in the skeleton of {joints} joints",
                        t.joint
                    ),
                );
            }
            if !t.position.is_finite() {
                return bad(
                    format!("targets[{e}].position"),
                    format!("{} has a NaN or infinite component", t.position),
                );
            }
            if !(t.position_weight.is_finite() && t.position_weight > 0.0) {
                return bad(
                    format!("targets[{e}].position_weight"),
                    format!("must be finite and > 0, got {}", t.position_weight),
                );
            }
            if !(t.rotation_weight.is_finite() && t.rotation_weight >= 0.0) {
                return bad(
                    format!("targets[{e}].rotation_weight"),
                    format!("must be finite and >= 0, got {}", t.rotation_weight),
                );
            }
            if let Some(q) = t.rotation
                && !(q.is_finite() && (q.length() - 1.0).abs() <= UNIT_SLACK)
            {
                return bad(
                    format!("targets[{e}].rotation"),
                    format!("{q} must be finite and normalized (length {})", q.length()),
                );
            }
        }
        Ok(())
    }
}

/// What a finish did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Finished {
    /// Why it stopped.
    pub stop: StopReason,
    /// Steps tried (accepted or not).
    pub steps: usize,
}

/// The finish's buffers, owned by a solver so that a solve does not allocate once they
/// have grown to the problem's size. See the [module docs](self).
#[derive(Clone, Debug, Default)]
pub struct Finish {
    /// First residual row of each target.
    first_row: Vec<usize>,
    /// Degrees of freedom: movable joint slot (or `TRANSLATION`) and world axis.
    dofs: Vec<(usize, DVec3)>,
    /// Sparse columns: `entries[col_start[k]..col_start[k + 1]]` are (row, value) pairs of
    /// dof `k`, rows increasing.
    col_start: Vec<usize>,
    entries: Vec<(usize, f64)>,
    /// Per movable joint: the index of its first degree of freedom (`NO_DOF` for a fixed
    /// joint).
    first_dof: Vec<usize>,
    /// The groups of three rows of the triples of columns (see `accumulate_normal`), and
    /// per degree of freedom that starts a triple the range of its groups (`None` when
    /// its columns do not split into groups).
    groups: Vec<Group>,
    groups_of: Vec<Option<(usize, usize)>>,
    /// The damped Cholesky factor `L` of the reduced `J J^T` (see `scratch.normal`), rows
    /// x rows, row-major: `L` in the lower triangle and, above the diagonal, its transpose
    /// (`factor[a][b] = L[b][a]` for `b > a`: the columns of `L` as rows, which the back
    /// substitution reads), one buffer rather than two so that a warm run brings in half
    /// as much. Beyond `SMALL_ROWS` only; a smaller factor has only its lower triangle.
    factor: Vec<f64>,
    /// Per movable joint: frozen by the active set.
    frozen: Vec<bool>,
    /// Per movable joint: the world directions of rotation the active set has blocked
    /// (orthonormal, the first `blocked_count` of them).
    blocked: Vec<[DVec3; 2]>,
    blocked_count: Vec<usize>,
    /// Per target: how far from its pin a pinned effector may end (its distance at the
    /// start of the finish, or the tolerance if larger), and how far an intermediate
    /// step may take it (`PIN_SLACK` times more).
    pin_allowed: Vec<f64>,
    pin_slack: Vec<f64>,
    /// The translation and the cost of the best pose accepted so far with every pin
    /// within `pin_allowed` (its rotations are `scratch.best`).
    best_translation: DVec3,
    best_cost: f64,
    /// Whether `factor` (of `factor_rows` rows), the columns and the active set
    /// (`frozen`, `blocked`) belong together: set by a successful factorization, cleared
    /// by any change of the active set and by [`Finish::forget`].
    factor_ok: bool,
    factor_rows: usize,
    /// Linearizations over this finish's life (see [`Finish::linearizations`]).
    linearizations: usize,
    /// Whether `dofs`, `col_start`, `first_dof` and the rows of `entries` were built for
    /// the current run (its movers and targets do not change), so that a linearization
    /// only writes the values.
    columns_built: bool,
    /// The buffers a run writes before it reads them.
    scratch: FinishScratch,
}

/// The buffers of a [`Finish`] that a run writes before it reads them, so that nothing in
/// them carries from one run to the next: a caller that runs many finishes one after
/// another (a batch of characters) can lend each the same ones
/// ([`Finish::swap_scratch`]), which then stay in the processor's cache instead of each
/// finish's own being fetched from memory. What a run reads from the last one (the
/// factor, the columns and the active set of a chord start) stays in the [`Finish`].
#[derive(Clone, Debug, Default)]
pub struct FinishScratch {
    /// Lower triangle of `J J^T` over every degree of freedom at the linearization point
    /// (rows x rows, row-major), and the same without the frozen and blocked ones.
    normal_full: Vec<f64>,
    normal: Vec<f64>,
    /// Per movable joint: the world rotation vector of the current step.
    turn: Vec<DVec3>,
    residual: Vec<f64>,
    /// The column of one blocked direction of a joint (see `reduce`).
    combined: Vec<(usize, f64)>,
    y: Vec<f64>,
    step: Vec<f64>,
    /// Per movable joint: clamped by the last trial, and the direction the last trial's
    /// projection pulled the joint back along.
    clamped: Vec<bool>,
    pulled_back: Vec<DVec3>,
    /// Per movable joint: whether the projection may have left it on its bound (it was
    /// clamped by the last accepted trial, or the finish just started), and then the
    /// outward normals of its swing bound and its twist range as local rotation vectors
    /// (zero when off that bound).
    on_bound: Vec<bool>,
    outward: Vec<[DVec3; 2]>,
    /// The movable joints' local rotations and the global pose before a trial.
    saved: Vec<DQuat>,
    saved_global: GlobalPose,
    /// The movable joints' rotations of the best pose accepted so far with every pin
    /// within `pin_allowed`.
    best: Vec<DQuat>,
    /// The cost before each step of the current run (for [`FinishJob::stall_window`]).
    history: Vec<f64>,
    /// Per movable joint: the last rotation this run's projections returned as the
    /// rotation given, by the quick inside test (see [`Finish::fixed_rotations`]).
    fixed: Vec<Option<DQuat>>,
}

/// The finish of a chain solver: the chain's one effector, turned by the chain's movable
/// joints (every chain joint but the effector), forward kinematics from the chain's base.
/// Owns its buffers, so a solve does not allocate once they have grown.
#[derive(Clone, Debug, Default)]
pub struct ChainFinish {
    finish: Finish,
    movers: Movers,
    targets: Vec<Target>,
    /// The chain joints' local rotations kept while a second seed is tried.
    best: Vec<DQuat>,
}

impl ChainFinish {
    /// The weighted cost of `goal` at `global` (see [`Target::cost`]), the quantity the
    /// finish decreases.
    #[must_use]
    pub fn cost(goal: &EffectorGoal, global: &GlobalPose) -> f64 {
        Target::from_goal(goal).cost(global)
    }

    /// Runs the finish once from `pose` (inside the limits, `global` its forward
    /// kinematics), `iterations` already spent of `settings.max_iterations`.
    ///
    /// A rotation goal with weight 0 is left out of the cost; since the chain solvers'
    /// reports still measure it against the rotation tolerance, a finish that met the
    /// position but not such a rotation says [`StopReason::LocalMinimum`], not
    /// [`StopReason::Converged`].
    #[allow(clippy::too_many_arguments)]
    pub fn run(
        &mut self,
        skeleton: &Skeleton,
        chain: &Chain,
        goal: &EffectorGoal,
        pose: &mut Pose,
        global: &mut GlobalPose,
        settings: &SolveSettings,
        iterations: usize,
    ) -> Result<Finished, SkeletonError> {
        self.targets.clear();
        self.targets.push(Target::from_goal(goal));
        self.movers.chain(&chain.joints()[..chain.bone_count()]);
        let job = FinishJob {
            skeleton,
            movers: &self.movers,
            targets: &self.targets,
            translates: false,
            base: Some(chain.base()),
            settings: *settings,
            iterations,
            chord_start: false,
            stall_window: 0,
            damping_cap: f64::INFINITY,
        };
        let mut translation = DVec3::ZERO;
        let mut finished = self.finish.run(&job, pose, &mut translation, global)?;
        if finished.stop == StopReason::Converged
            && goal.errors(global).1 > settings.rotation_tolerance
        {
            finished.stop = StopReason::LocalMinimum;
        }
        Ok(finished)
    }

    /// [`ChainFinish::run`], and when that ends in a local minimum of a chain with limits
    /// with iterations left, once more from a second seed, every limited joint at the
    /// centre of its range (hinge: the middle angle; swing-twist: no swing, the middle
    /// twist; free joints keep their rotation); the better end is kept. Returns what the
    /// finish did (steps of both runs) and whether it restarted.
    #[allow(clippy::too_many_arguments)]
    pub fn run_restarting(
        &mut self,
        skeleton: &Skeleton,
        chain: &Chain,
        goal: &EffectorGoal,
        pose: &mut Pose,
        global: &mut GlobalPose,
        settings: &SolveSettings,
        iterations: usize,
    ) -> Result<(Finished, bool), SkeletonError> {
        let first = self.run(skeleton, chain, goal, pose, global, settings, iterations)?;
        let movable = &chain.joints()[..chain.bone_count()];
        let has_limits = movable
            .iter()
            .any(|&j| !matches!(skeleton.limit(j), JointLimit::Free));
        let mut finished = first;
        if first.stop != StopReason::LocalMinimum
            || !has_limits
            || iterations + first.steps >= settings.max_iterations
        {
            return Ok((finished, false));
        }
        self.best.clear();
        self.best.extend(movable.iter().map(|&j| pose.rotations[j]));
        let best_cost = Self::cost(goal, global);
        for &j in movable {
            if let Some(seed) = skeleton.limit(j).centre() {
                pose.rotations[j] = seed;
            }
        }
        skeleton.forward_kinematics_from(pose, chain.base(), global)?;
        let second = self.run(
            skeleton,
            chain,
            goal,
            pose,
            global,
            settings,
            iterations + first.steps,
        )?;
        finished.steps += second.steps;
        if Self::cost(goal, global) < best_cost {
            finished.stop = second.stop;
        } else {
            for (&kept, &j) in self.best.iter().zip(movable) {
                pose.rotations[j] = kept;
            }
            skeleton.forward_kinematics_from(pose, chain.base(), global)?;
        }
        Ok((finished, true))
    }
}

impl Finish {
    /// Asks the processor to bring into its cache what a run that starts with a chord
    /// step reads first from this finish (the columns, the factor, the active set): a
    /// hint for a caller that runs many finishes one after another, issued while the one
    /// before runs (see [`crate::prefetch`]). Changes no result.
    pub fn prefetch(&self) {
        use crate::prefetch::prefetch;
        prefetch(&self.dofs);
        prefetch(&self.col_start);
        prefetch(&self.entries);
        prefetch(&self.first_dof);
        prefetch(&self.groups);
        prefetch(&self.groups_of);
        prefetch(&self.factor);
        prefetch(&self.frozen);
        prefetch(&self.blocked);
        prefetch(&self.blocked_count);
    }

    /// Drops the factor of the last linearization, so that no later run starts with a
    /// chord step on it (for a caller whose problem changed).
    pub fn forget(&mut self) {
        self.factor_ok = false;
    }

    /// Exchanges this finish's scratch buffers with `scratch`: a caller running many
    /// finishes one after another lends each the same buffers before its run and takes
    /// them back after, so that they stay in cache. A run writes every scratch buffer
    /// before reading it, so its results are the same to the bit whatever buffers it was
    /// lent (of any size or content); only [`Finish::fixed_rotations`] reads the lent
    /// buffers, and so must be read before they are taken back.
    pub fn swap_scratch(&mut self, scratch: &mut FinishScratch) {
        std::mem::swap(&mut self.scratch, scratch);
    }

    /// How many times this finish has linearized (computed the columns and `J J^T`) over
    /// its life: the measure of its work that the number of trials is not, a chord step
    /// being a trial without a linearization.
    #[must_use]
    pub fn linearizations(&self) -> usize {
        self.linearizations
    }

    /// Per movable joint of the last run (in the order of its movers), the last rotation
    /// one of its trials turned the joint to that the projection returned unchanged by
    /// its quick inside test ([`PreparedLimit::project_and_fixed`]), if any: a rotation
    /// whose [`PreparedLimit::violation_and_fixed`] is `(0, true)`, so that a caller whose
    /// answer holds it (compared by value) knows its violation and its projection without
    /// measuring them again. Only for the skeleton of that run.
    ///
    /// [`PreparedLimit::project_and_fixed`]: crate::limits::PreparedLimit::project_and_fixed
    /// [`PreparedLimit::violation_and_fixed`]: crate::limits::PreparedLimit::violation_and_fixed
    #[must_use]
    pub fn fixed_rotations(&self) -> &[Option<DQuat>] {
        &self.scratch.fixed
    }

    /// Frees every joint of the active set (which then no longer matches the factor).
    fn free_active_set(&mut self) {
        self.frozen.fill(false);
        self.blocked_count.fill(0);
        self.factor_ok = false;
    }

    /// Runs the finish from `pose` moved by `translation` (inside the limits, `global`
    /// its exact forward kinematics) until every effector is within the tolerances,
    /// `job.iterations + steps` reaches the cap, or steps stop helping. `translation`
    /// only changes when `job.translates`.
    ///
    /// # Errors
    ///
    /// [`SkeletonError::InvalidFinishJob`] naming the field when the job is invalid
    /// ([`FinishJob::validate`]), or when `global` is not of the skeleton's size or
    /// `translation` is not finite; [`SkeletonError::PoseLength`] for a pose of another
    /// size; a forward kinematics error for an invalid rotation.
    pub fn run(
        &mut self,
        job: &FinishJob<'_>,
        pose: &mut Pose,
        translation: &mut DVec3,
        global: &mut GlobalPose,
    ) -> Result<Finished, SkeletonError> {
        job.validate()?;
        let (skeleton, targets, settings) = (job.skeleton, job.targets, &job.settings);
        let joints = skeleton.len();
        if pose.rotations.len() != joints {
            return Err(SkeletonError::PoseLength {
                expected: joints,
                got: pose.rotations.len(),
            });
        }
        if global.rotations.len() != joints || global.positions.len() != joints {
            return Err(SkeletonError::InvalidFinishJob {
                field: "global".into(),
                reason: format!(
                    "{} rotations and {} positions for a skeleton of {joints} joints (it must be forward kinematics of the pose)",
                    global.rotations.len(),
                    global.positions.len()
                ),
            });
        }
        if !translation.is_finite() {
            return Err(SkeletonError::InvalidFinishJob {
                field: "translation".into(),
                reason: format!("{translation} has a NaN or infinite component"),
            });
        }
        let movable = job.movers.movable();
        self.scratch.fixed.clear();
        self.scratch.fixed.resize(movable.len(), None);
        self.first_row.clear();
        let mut rows = 0;
        for t in targets {
            self.first_row.push(rows);
            rows += if t.has_rotation() { 6 } else { 3 };
        }
        self.pin_allowed.clear();
        self.pin_allowed.extend(targets.iter().map(|t| {
            let d = global.positions[t.joint].distance(t.position);
            if t.pinned {
                d.max(settings.tolerance)
            } else {
                0.0
            }
        }));
        self.pin_slack.clear();
        self.pin_slack
            .extend(self.pin_allowed.iter().map(|&a| a * PIN_SLACK));
        self.scratch.best.clear();
        self.scratch
            .best
            .extend(movable.iter().map(|&j| pose.rotations[j]));
        self.best_translation = *translation;
        self.best_cost = total_cost(targets, global);
        self.columns_built = false;
        let finished = self.iterate(job, pose, translation, global, rows)?;
        // A step may move a pin by up to the slack, so that one step can fix the other
        // goals and the next bring the pin back; an ending that has not brought it back
        // returns to the best pose that kept every pin.
        if !pins_hold(targets, global, settings.tolerance, &self.pin_allowed) {
            for (&saved, &j) in self.scratch.best.iter().zip(movable) {
                pose.rotations[j] = saved;
            }
            *translation = self.best_translation;
            translated_forward_kinematics(skeleton, pose, *translation, job.base, global)?;
            return Ok(Finished {
                stop: StopReason::LocalMinimum,
                steps: finished.steps,
            });
        }
        Ok(finished)
    }

    /// The steps of [`Finish::run`], with `rows` residual rows, from the pose whose cost
    /// `run` left in `best_cost`.
    fn iterate(
        &mut self,
        job: &FinishJob<'_>,
        pose: &mut Pose,
        translation: &mut DVec3,
        global: &mut GlobalPose,
        rows: usize,
    ) -> Result<Finished, SkeletonError> {
        let (skeleton, targets, settings) = (job.skeleton, job.targets, &job.settings);
        let movable = job.movers.movable();
        // A chord step first needs the last factor with the active set it was made with.
        let chord_start = job.chord_start
            && self.factor_ok
            && self.factor_rows == rows
            && self.first_dof.len() == movable.len()
            && self.frozen.len() == movable.len()
            && self.blocked_count.len() == movable.len();
        if !chord_start {
            self.factor_ok = false;
            self.frozen.clear();
            self.frozen.resize(movable.len(), false);
            self.blocked.clear();
            self.blocked.resize(movable.len(), [DVec3::ZERO; 2]);
            self.blocked_count.clear();
            self.blocked_count.resize(movable.len(), 0);
        }
        self.scratch.clamped.clear();
        self.scratch.clamped.resize(movable.len(), false);
        self.scratch.pulled_back.clear();
        self.scratch.pulled_back.resize(movable.len(), DVec3::ZERO);
        self.scratch.on_bound.clear();
        self.scratch.on_bound.resize(movable.len(), true);
        self.scratch.outward.clear();
        self.scratch.outward.resize(movable.len(), [DVec3::ZERO; 2]);
        // A start already within the tolerances (a closed-form seed usually is) needs no
        // outward normals: the loop below returns before its first step.
        if all_within(targets, global, settings) {
            return Ok(Finished {
                stop: StopReason::Converged,
                steps: 0,
            });
        }
        self.scratch.normal.resize(rows * rows, 0.0);
        self.scratch.normal_full.resize(rows * rows, 0.0);
        self.scratch.turn.clear();
        self.scratch.turn.resize(movable.len(), DVec3::ZERO);
        self.scratch.residual.resize(rows, 0.0);
        // A blocked direction's column has at most `rows` entries: sized here, not when a
        // joint first reaches a curved bound, so that a warm run does not allocate then.
        self.scratch.combined.clear();
        self.scratch.combined.reserve(rows);
        self.scratch.y.resize(rows, 0.0);
        // `run` has just measured this pose's cost as the best so far.
        let mut cost = self.best_cost;
        let mut damping = f64::NAN;
        let mut rejections = 0;
        let mut crawl = 0;
        let mut steps = 0;
        let mut resolving = false;
        // Whether the columns and `normal_full` are those of the current pose: a rejected
        // trial or a change of the active set keeps them, only an accepted step moves
        // the linearization point.
        let mut fresh = false;
        // Whether the next trial is a chord step, how many chord steps the current
        // factor has served, and whether the outward normals are those of an earlier
        // pose (they are found when a full step needs them: those of the start just
        // before the first full step, none if chord steps end the finish).
        let mut chord = chord_start;
        let mut chords = 0;
        let mut outward_stale = true;
        self.scratch.history.clear();
        // Whether the pose is one already found outside the tolerances: the start (tested
        // above), and again after a rejected trial (which restores the pose, the
        // translation and the global pose to their bits) or a solve again after the active
        // set changed; only an accepted step moves it.
        let mut known_outside = true;
        loop {
            if !known_outside && all_within(targets, global, settings) {
                return Ok(Finished {
                    stop: StopReason::Converged,
                    steps,
                });
            }
            known_outside = true;
            if job.stall_window > 0 {
                while self.scratch.history.len() <= steps {
                    self.scratch.history.push(cost);
                }
                if steps >= job.stall_window
                    && cost * STALL_FACTOR > self.scratch.history[steps - job.stall_window]
                {
                    return Ok(Finished {
                        stop: StopReason::LocalMinimum,
                        steps,
                    });
                }
            }
            if job.iterations + steps >= settings.max_iterations {
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
            let shift = if chord {
                // A chord step: the factor of the last linearization, the residual of
                // the pose it led to (see the module docs). No active-set checks: the
                // factor is of the reduced matrix they left, and a trial that a bound
                // spoils is rejected like any other.
                self.residual_at(targets, global);
                steps += 1;
                if !self.substitute(rows) {
                    chord = false;
                    self.free_active_set();
                    continue;
                }
                self.turns(movable)
            } else {
                if !fresh {
                    self.linearize(job, global);
                    self.accumulate_normal(rows);
                    fresh = true;
                }
                if outward_stale {
                    self.find_outward(skeleton, movable, pose);
                    outward_stale = false;
                }
                if !self.reduce(skeleton, movable, rows) {
                    return Ok(Finished {
                        stop: StopReason::LocalMinimum,
                        steps,
                    });
                }
                if damping.is_nan() {
                    let trace: f64 = (0..rows).map(|a| self.scratch.normal[a * rows + a]).sum();
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
                    self.factor_ok = false;
                    damping = damping.max(f64::MIN_POSITIVE) * 10.0;
                    rejections += 1;
                    continue;
                }
                self.factor_ok = true;
                self.factor_rows = rows;
                let shift = self.turns(movable);
                // A hinge is a box on its angle, so this part of the active set is exact: a
                // hinge on a bound stepping outwards would be clamped back while the others
                // moved as if it had turned. Leave it out and solve the same step again.
                for (m, &j) in movable.iter().enumerate() {
                    if let JointLimit::Hinge(_) = skeleton.limit(j)
                        && !self.frozen[m]
                    {
                        let k = self.first_dof[m];
                        if k != NO_DOF
                            && skeleton.prepared_limit(j).hinge_pushes_outwards(
                                pose.rotations[j],
                                self.scratch.step[k],
                                AT_BOUND,
                            )
                        {
                            self.frozen[m] = true;
                            self.factor_ok = false;
                            resolving = true;
                        }
                    }
                }
                // The same for a swing-twist joint on its bound: the step's component along
                // the bound's outward normal would be projected away; block that direction
                // (the joint keeps sliding along the bound) and solve again.
                for (m, &j) in movable.iter().enumerate() {
                    let w = self.scratch.turn[m];
                    if self.scratch.outward[m] == [DVec3::ZERO; 2] || w == DVec3::ZERO {
                        continue;
                    }
                    let parent = skeleton
                        .parent(j)
                        .map_or(DQuat::IDENTITY, |p| global.rotations[p]);
                    let local = parent.conjugate() * w;
                    for g in 0..2 {
                        let n = self.scratch.outward[m][g];
                        if n != DVec3::ZERO && local.dot(n) > 0.0 && !self.frozen[m] {
                            self.scratch.pulled_back[m] = parent * n;
                            self.block(skeleton.limit(j), m);
                            // Blocked once per linearization: the normal is not asked again.
                            self.scratch.outward[m][g] = DVec3::ZERO;
                            resolving = true;
                            break;
                        }
                    }
                }
                if resolving {
                    continue;
                }
                shift
            };
            self.scratch.saved.clear();
            self.scratch
                .saved
                .extend(movable.iter().map(|&j| pose.rotations[j]));
            let saved_translation = *translation;
            // Without a base, forward kinematics writes every joint and reads nothing of
            // the global pose it overwrites: the pose before the trial is kept by handing
            // its buffers over (swapped back on a rejection) instead of copied.
            let mut before = std::mem::take(&mut self.scratch.saved_global);
            if job.base.is_none() {
                std::mem::swap(global, &mut before);
            } else {
                before.rotations.clone_from(&global.rotations);
                before.positions.clone_from(&global.positions);
            }
            self.apply_step(skeleton, movable, pose, &before);
            self.scratch.saved_global = before;
            *translation += shift;
            translated_forward_kinematics(skeleton, pose, *translation, job.base, global)?;
            let trial_cost = total_cost(targets, global);
            if trial_cost < cost && pins_hold(targets, global, settings.tolerance, &self.pin_slack)
            {
                if trial_cost < self.best_cost
                    && pins_hold(targets, global, settings.tolerance, &self.pin_allowed)
                {
                    self.scratch.best.clear();
                    self.scratch
                        .best
                        .extend(movable.iter().map(|&j| pose.rotations[j]));
                    self.best_translation = *translation;
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
                let gain = trial_cost / cost;
                cost = trial_cost;
                if crawl >= CRAWL_STEPS {
                    return Ok(Finished {
                        stop: StopReason::LocalMinimum,
                        steps,
                    });
                }
                damping /= 3.0;
                // (A damping not yet set, NaN after a chord start, stays unset: the first
                // full step sets it from the scale of `J J^T`.)
                if damping > job.damping_cap * trial_cost {
                    damping = job.damping_cap * trial_cost;
                }
                rejections = 0;
                fresh = false;
                known_outside = false;
                for (on, &clamped) in self.scratch.on_bound.iter_mut().zip(&self.scratch.clamped) {
                    *on |= clamped;
                }
                outward_stale = true;
                // A step that gained this much is in the quadratic range of Gauss-Newton:
                // the next one may reuse the factor (a chord step), keeping the active set
                // it was made with.
                if gain <= CHORD_GAIN && chords < MAX_CHORDS {
                    chord = true;
                    chords += 1;
                } else {
                    chord = false;
                    chords = 0;
                    self.free_active_set();
                }
                continue;
            }
            for (&saved, &j) in self.scratch.saved.iter().zip(movable) {
                pose.rotations[j] = saved;
            }
            *translation = saved_translation;
            if job.base.is_none() {
                std::mem::swap(global, &mut self.scratch.saved_global);
            } else {
                global
                    .rotations
                    .clone_from(&self.scratch.saved_global.rotations);
                global
                    .positions
                    .clone_from(&self.scratch.saved_global.positions);
            }
            if chord {
                // The chord step did not pay: linearize here, as after any accepted step.
                chord = false;
                chords = 0;
                self.free_active_set();
                continue;
            }
            // A rejected trial means the step was too long for the linearization or for
            // the bounds: shorten the next one too, whether or not a joint was frozen;
            // left out, the finish crawls along the bounds (`docs/ik-finish.md` has the
            // measurements).
            let mut newly_frozen = false;
            damping *= CLAMP_GROWTH;
            for (m, &j) in movable.iter().enumerate() {
                if self.scratch.clamped[m] && !self.frozen[m] {
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
    fn linearize(&mut self, job: &FinishJob<'_>, global: &GlobalPose) {
        let skeleton = job.skeleton;
        let targets = job.targets;
        self.linearizations += 1;
        self.residual_at(targets, global);
        self.groups_of.clear();
        if self.columns_built {
            self.relinearize(job, global);
            return;
        }
        self.columns_built = true;
        self.dofs.clear();
        self.col_start.clear();
        self.entries.clear();
        self.first_dof.clear();
        for (m, &j) in job.movers.movable().iter().enumerate() {
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
                for &e in job.movers.below(m) {
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
        if job.translates {
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

    /// [`Finish::linearize`] once the columns' structure is built for this run: the same
    /// loops, the same values, written over the old ones (the rows, the degrees of
    /// freedom and the column starts stay; a hinge's axis is written anew).
    fn relinearize(&mut self, job: &FinishJob<'_>, global: &GlobalPose) {
        let skeleton = job.skeleton;
        let targets = job.targets;
        let mut at_entry = 0;
        for (m, &j) in job.movers.movable().iter().enumerate() {
            let k0 = self.first_dof[m];
            let axes: [DVec3; 3];
            let axes: &[DVec3] = match skeleton.limit(j) {
                JointLimit::Fixed => &[],
                JointLimit::Hinge(h) => {
                    let parent = skeleton
                        .parent(j)
                        .map_or(DQuat::IDENTITY, |p| global.rotations[p]);
                    axes = [(parent * h.axis).normalize(), DVec3::ZERO, DVec3::ZERO];
                    self.dofs[k0].1 = axes[0];
                    &axes[..1]
                }
                JointLimit::Free | JointLimit::SwingTwist(_) => &[DVec3::X, DVec3::Y, DVec3::Z],
            };
            let at = global.positions[j];
            for &u in axes {
                for &e in job.movers.below(m) {
                    let t = &targets[e];
                    if t.joint != j {
                        let v = u.cross(global.positions[t.joint] - at) * t.position_weight;
                        let slots = &mut self.entries[at_entry..at_entry + 3];
                        slots[0].1 = v.x;
                        slots[1].1 = v.y;
                        slots[2].1 = v.z;
                        at_entry += 3;
                    }
                    if t.has_rotation() {
                        let w = u * t.rotation_weight;
                        let slots = &mut self.entries[at_entry..at_entry + 3];
                        slots[0].1 = w.x;
                        slots[1].1 = w.y;
                        slots[2].1 = w.z;
                        at_entry += 3;
                    }
                }
            }
        }
        // The translation's columns are constant (the weights along the axes): as built.
        let translation_entries = if job.translates { 9 * targets.len() } else { 0 };
        debug_assert_eq!(
            at_entry + translation_entries,
            self.entries.len(),
            "the columns' structure is the run's"
        );
    }

    /// The weighted residual at `global` into `residual`.
    fn residual_at(&mut self, targets: &[Target], global: &GlobalPose) {
        for (t, &row) in targets.iter().zip(&self.first_row) {
            let p = (t.position - global.positions[t.joint]) * t.position_weight;
            self.scratch.residual[row..row + 3].copy_from_slice(&[p.x, p.y, p.z]);
            if t.has_rotation() {
                let r = t.rotation_residual(global) * t.rotation_weight;
                self.scratch.residual[row + 3..row + 6].copy_from_slice(&[r.x, r.y, r.z]);
            }
        }
    }

    /// The outward normal of the bound of every swing-twist joint that may sit on it,
    /// as a local rotation vector, by one-sided differences of the limit's violation
    /// (0 inside, growing linearly outside): zero for a joint inside its limit.
    fn find_outward(&mut self, skeleton: &Skeleton, movable: &[usize], pose: &Pose) {
        for (m, &j) in movable.iter().enumerate() {
            self.scratch.outward[m] = [DVec3::ZERO; 2];
            if !self.scratch.on_bound[m] {
                continue;
            }
            let JointLimit::SwingTwist(st) = skeleton.limit(j) else {
                self.scratch.on_bound[m] = false;
                continue;
            };
            // The swing bound and the twist range are two constraints, which can both
            // be active (a corner): one normal each, from the violation of the limit with
            // the other one opened up (the two parts of one decomposition).
            let frame = skeleton
                .prepared_limit(j)
                .frame()
                .unwrap_or_else(|| LimitFrame::of(st));
            let local = pose.rotations[j];
            // A joint well inside its limit has both normals exactly zero (every
            // perturbed rotation is inside): one decomposition tells, instead of six.
            // Most joints of a warm frame are.
            if st.deep_inside(&frame, local, DEEP_INSIDE) {
                self.scratch.on_bound[m] = false;
                continue;
            }
            // The six small turns are the same every time: made once per process.
            let nudges = NUDGES.get_or_init(|| {
                [DVec3::X, DVec3::Y, DVec3::Z].map(|e| {
                    [
                        DQuat::from_scaled_axis(e * H),
                        DQuat::from_scaled_axis(e * -H),
                    ]
                })
            });
            let mut normals = [DVec3::ZERO; 2];
            for (e, [up, down]) in [DVec3::X, DVec3::Y, DVec3::Z].into_iter().zip(nudges) {
                let plus = st.violation_parts_in(&frame, *up * local);
                let minus = st.violation_parts_in(&frame, *down * local);
                normals[0] += e * (plus.0 - minus.0);
                normals[1] += e * (plus.1 - minus.1);
            }
            self.scratch.outward[m] = normals.map(|n| n.try_normalize().unwrap_or(DVec3::ZERO));
            // Off both bounds: no longer watched until a projection clamps it again.
            self.scratch.on_bound[m] = self.scratch.outward[m] != [DVec3::ZERO; 2];
        }
    }

    /// Blocks, after a rejected trial that clamped movable joint `m`, the direction its
    /// projection pulled it back along: a hinge (one axis) is frozen; a free or
    /// swing-twist joint loses that one direction of rotation and keeps sliding along
    /// its bound in the others, until a third direction would be blocked.
    fn block(&mut self, limit: &JointLimit, m: usize) {
        self.factor_ok = false;
        if !matches!(limit, JointLimit::SwingTwist(_)) {
            self.frozen[m] = true;
            return;
        }
        let mut d = self.scratch.pulled_back[m];
        for b in &self.blocked[m][..self.blocked_count[m]] {
            d -= *b * b.dot(d);
        }
        match (d.try_normalize(), self.blocked_count[m]) {
            (Some(unit), count)
                if count < 2 && d.length() > 1e-3 * self.scratch.pulled_back[m].length() =>
            {
                self.blocked[m][count] = unit;
                self.blocked_count[m] = count + 1;
            }
            _ => self.frozen[m] = true,
        }
    }

    /// Whether dofs `k`, `k + 1`, `k + 2` are the three world axes of one joint (or of
    /// the translation): their columns then have the same rows, in the same order.
    fn is_triple(&self, k: usize) -> bool {
        k + 2 < self.dofs.len()
            && self.dofs[k].0 == self.dofs[k + 1].0
            && self.dofs[k].0 == self.dofs[k + 2].0
    }

    /// `J J^T` (lower triangle) from the sparse columns. The three columns of a joint's
    /// world axes share their rows, so they are summed in one pass, each entry of the
    /// normal matrix taking the three products in the order the columns come (the same
    /// additions, in the same order, as one column after another).
    ///
    /// A triple's rows come in groups of three consecutive rows (an effector's position
    /// or rotation rows), and most of a group's nine values are structurally zero: a
    /// position group of a joint (`u x d`) has a zero where the axis meets its own row,
    /// a rotation group (`u w`) and the translation's groups only there. The groups are
    /// added block by block, leaving out the products with a factor that is zero (told
    /// from the values, so any columns are summed right). Adding a zero product leaves an
    /// entry that is not `-0` unchanged, and no entry is ever `-0` (each starts at `+0`,
    /// and a sum is `-0` only when both terms are), so the bits are those of every
    /// product added.
    fn accumulate_normal(&mut self, rows: usize) {
        self.scratch.normal_full[..rows * rows].fill(0.0);
        self.groups.clear();
        self.groups_of.clear();
        self.groups_of.resize(self.dofs.len(), None);
        let mut k = 0;
        while k < self.dofs.len() {
            let (a0, a1) = (self.col_start[k], self.col_start[k + 1]);
            if self.is_triple(k) {
                let (a2, a3) = (self.col_start[k + 2], self.col_start[k + 3]);
                let (cx, cy, cz) = (
                    &self.entries[a0..a1],
                    &self.entries[a1..a2],
                    &self.entries[a2..a3],
                );
                let first = self.groups.len();
                if gather_groups(cx, cy, cz, &mut self.groups) {
                    self.groups_of[k] = Some((first, self.groups.len()));
                    add_groups(
                        &mut self.scratch.normal_full[..rows * rows],
                        rows,
                        &self.groups[first..],
                    );
                    k += 3;
                    continue;
                }
                for (i, ((&(a, xa), &(_, ya)), &(_, za))) in cx.iter().zip(cy).zip(cz).enumerate() {
                    let line = &mut self.scratch.normal_full[a * rows..a * rows + a + 1];
                    for ((&(b, xb), &(_, yb)), &(_, zb)) in
                        cx[..=i].iter().zip(&cy[..=i]).zip(&cz[..=i])
                    {
                        let mut e = line[b];
                        e += xa * xb;
                        e += ya * yb;
                        e += za * zb;
                        line[b] = e;
                    }
                }
                k += 3;
                continue;
            }
            let col = &self.entries[a0..a1];
            for (i, &(a, va)) in col.iter().enumerate() {
                let line = &mut self.scratch.normal_full[a * rows..a * rows + a + 1];
                for &(b, vb) in &col[..=i] {
                    line[b] += va * vb;
                }
            }
            k += 1;
        }
    }

    /// `J J^T` over the active degrees of freedom into `normal`: `normal_full` less the
    /// columns of the frozen joints and, for a joint with blocked directions `b`, less
    /// `c(b) c(b)^T` (its three world-axis columns `C` span `C C^T`, and the allowed
    /// directions `P = I - sum b b^T` leave `C P C^T`). False when nothing may move.
    fn reduce(&mut self, skeleton: &Skeleton, movable: &[usize], rows: usize) -> bool {
        self.scratch.normal[..rows * rows]
            .copy_from_slice(&self.scratch.normal_full[..rows * rows]);
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
                    subtract_outer(&mut self.scratch.normal, rows, &self.entries[a..b]);
                }
                continue;
            }
            active = true;
            for i in 0..self.blocked_count[m] {
                let d = self.blocked[m][i];
                let (x, y, z, end) = (
                    self.col_start[k0],
                    self.col_start[k0 + 1],
                    self.col_start[k0 + 2],
                    self.col_start[k0 + 3],
                );
                // The column of the blocked direction, made once: the outer product
                // reads each entry as often as the column has rows.
                self.scratch.combined.clear();
                self.scratch.combined.extend(
                    self.entries[x..y]
                        .iter()
                        .zip(&self.entries[y..z])
                        .zip(&self.entries[z..end])
                        .map(|((&(row, vx), &(_, vy)), &(_, vz))| {
                            (row, d.x * vx + d.y * vy + d.z * vz)
                        }),
                );
                subtract_outer(&mut self.scratch.normal, rows, &self.scratch.combined);
            }
        }
        active
    }

    /// The step of every degree of freedom (`J_k . y`), and from them each movable joint's
    /// world rotation vector (zero when frozen, its blocked directions projected out);
    /// returns the translation's step.
    fn turns(&mut self, movable: &[usize]) -> DVec3 {
        let dofs = self.dofs.len();
        self.scratch.step.clear();
        self.scratch.step.resize(dofs, 0.0);
        self.scratch.turn.fill(DVec3::ZERO);
        let columns = Columns {
            dofs: &self.dofs,
            col_start: &self.col_start,
            entries: &self.entries,
            groups: &self.groups,
            groups_of: if self.groups_of.len() == dofs {
                &self.groups_of
            } else {
                &[]
            },
        };
        let shift = steps_and_turns(
            &columns,
            &self.scratch.y,
            &self.frozen,
            &mut self.scratch.step,
            &mut self.scratch.turn,
        );
        for m in 0..movable.len() {
            for i in 0..self.blocked_count[m] {
                let b = self.blocked[m][i];
                let w = self.scratch.turn[m];
                self.scratch.turn[m] = w - b * b.dot(w);
            }
        }
        shift
    }

    /// Solves `(J J^T + damping I) y = residual` by Cholesky into `self.scratch.y`; false when a
    /// pivot is not a positive finite number.
    fn solve(&mut self, rows: usize, damping: f64) -> bool {
        self.factorize(rows, damping) && self.substitute(rows)
    }

    /// The Cholesky factor of `normal + damping I` into `factor`'s lower triangle
    /// (row-major) and its transpose into the upper one; false when a pivot is not a
    /// positive finite number.
    ///
    /// Column by column: the pivot of column `b`, then every entry below it,
    /// `L[a][b] = (N[a][b] - sum_k L[a][k] L[b][k]) / L[b][b]` with the sum over `k < b`
    /// in increasing order, two rows at once sharing the loads of row `b`. Every entry is
    /// the same sum in the same order as the row-by-row textbook loop, and the pivots are
    /// checked in the same order, so the factor is the same to the bit; the column order
    /// lets each entry also be stored in the transpose, whose rows the back substitution
    /// reads.
    fn factorize(&mut self, rows: usize, damping: f64) -> bool {
        let size = rows * rows;
        if self.factor.len() < size {
            self.factor.resize(size, 0.0);
        }
        if rows <= SMALL_ROWS {
            return self.factorize_small(rows, damping);
        }
        // Rows come three per position goal and six per position and rotation goal; up to
        // 24 the loops' bounds are made constants.
        match rows {
            9 => return self.factorize_rows::<9>(damping),
            12 => return self.factorize_rows::<12>(damping),
            15 => return self.factorize_rows::<15>(damping),
            18 => return self.factorize_rows::<18>(damping),
            21 => return self.factorize_rows::<21>(damping),
            24 => return self.factorize_rows::<24>(damping),
            _ => {}
        }
        let n = &self.scratch.normal[..size];
        let l = &mut self.factor[..size];
        for b in 0..rows {
            let (upper, lower) = l.split_at_mut((b + 1) * rows);
            let (left_b, diagonal) = upper[b * rows..].split_at_mut(b);
            let left_b: &[f64] = left_b;
            let mut sum = n[b * rows + b] + damping;
            for x in left_b {
                sum -= x * x;
            }
            if !(sum.is_finite() && sum > 0.0) {
                return false;
            }
            let pivot = sum.sqrt();
            // Row `b` from the diagonal on: the pivot, then (the transpose, above the
            // diagonal) column `b` of the factor below it.
            diagonal[0] = pivot;
            let below = &mut diagonal[1..];
            // The rows below, four, then two, then one at a time, each sum in its own
            // register in the order of `k`.
            let mut rest = lower;
            let mut a = b + 1;
            while rest.len() >= 4 * rows {
                let (four, tail) = rest.split_at_mut(4 * rows);
                let (r0, four) = four.split_at_mut(rows);
                let (r1, four) = four.split_at_mut(rows);
                let (r2, r3) = four.split_at_mut(rows);
                let mut s = [
                    n[a * rows + b],
                    n[(a + 1) * rows + b],
                    n[(a + 2) * rows + b],
                    n[(a + 3) * rows + b],
                ];
                for ((((x0, x1), x2), x3), y) in r0[..b]
                    .iter()
                    .zip(&r1[..b])
                    .zip(&r2[..b])
                    .zip(&r3[..b])
                    .zip(left_b)
                {
                    s[0] -= x0 * y;
                    s[1] -= x1 * y;
                    s[2] -= x2 * y;
                    s[3] -= x3 * y;
                }
                let v = s.map(|s| s / pivot);
                r0[b] = v[0];
                r1[b] = v[1];
                r2[b] = v[2];
                r3[b] = v[3];
                below[a - b - 1..a - b + 3].copy_from_slice(&v);
                rest = tail;
                a += 4;
            }
            while rest.len() >= rows {
                let (r0, tail) = rest.split_at_mut(rows);
                let mut s0 = n[a * rows + b];
                for (x0, y) in r0[..b].iter().zip(left_b) {
                    s0 -= x0 * y;
                }
                let v0 = s0 / pivot;
                r0[b] = v0;
                below[a - b - 1] = v0;
                rest = tail;
                a += 1;
            }
        }
        true
    }

    /// [`Finish::factorize`] for `N` rows, with the buffers seen as rows of `N`.
    fn factorize_rows<const N: usize>(&mut self, damping: f64) -> bool {
        let size = N * N;
        factorize_fixed::<N>(
            self.scratch.normal[..size].as_chunks::<N>().0,
            self.factor[..size].as_chunks_mut::<N>().0,
            damping,
        )
    }

    /// [`Finish::substitute`] for `N` rows (the same sums in the same order), with the
    /// bounds of the loops constants.
    // Indices rather than iterators: over rows of constant length the checks drop out.
    #[allow(clippy::needless_range_loop)]
    fn substitute_rows<const N: usize>(&mut self) -> bool {
        let size = N * N;
        let l = &self.factor[..size].as_chunks::<N>().0[..N];
        let r = &self.scratch.residual[..N];
        let y = &mut self.scratch.y[..N];
        let mut a = 0;
        while a + 1 < N {
            let (mut s0, mut s1) = (r[a], r[a + 1]);
            for k in 0..a {
                s0 -= l[a][k] * y[k];
                s1 -= l[a + 1][k] * y[k];
            }
            let y0 = s0 / l[a][a];
            s1 -= l[a + 1][a] * y0;
            y[a] = y0;
            y[a + 1] = s1 / l[a + 1][a + 1];
            a += 2;
        }
        if a < N {
            let mut sum = r[a];
            for k in 0..a {
                sum -= l[a][k] * y[k];
            }
            y[a] = sum / l[a][a];
        }
        // Above the diagonal, row `a` holds column `a` of the factor.
        for a in (0..N).rev() {
            let mut sum = y[a];
            for b in a + 1..N {
                sum -= l[a][b] * y[b];
            }
            y[a] = sum / l[a][a];
        }
        y.iter().all(|v| v.is_finite())
    }

    /// [`Finish::factorize`] for a few rows (a chain's 3 or 6), row by row into `factor`
    /// only: there the column order's bookkeeping costs more than it saves, and
    /// [`Finish::substitute`] reads the columns of so small a factor in place.
    fn factorize_small(&mut self, rows: usize, damping: f64) -> bool {
        let n = &self.scratch.normal[..rows * rows];
        let l = &mut self.factor[..rows * rows];
        for a in 0..rows {
            let (above, from_a) = l.split_at_mut(a * rows);
            let row_a = &mut from_a[..rows];
            for b in 0..a {
                let row_b = &above[b * rows..b * rows + b + 1];
                let mut sum = n[a * rows + b];
                for (x, y) in row_a[..b].iter().zip(&row_b[..b]) {
                    sum -= x * y;
                }
                row_a[b] = sum / row_b[b];
            }
            let mut sum = n[a * rows + a] + damping;
            for x in &row_a[..a] {
                sum -= x * x;
            }
            if !(sum.is_finite() && sum > 0.0) {
                return false;
            }
            row_a[a] = sum.sqrt();
        }
        true
    }

    /// `y` from the factor of the last [`Finish::factorize`] and the current residual
    /// (forward substitution on the rows of the factor, back substitution on the rows of
    /// its transpose); false when an entry is not finite.
    fn substitute(&mut self, rows: usize) -> bool {
        match rows {
            9 => return self.substitute_rows::<9>(),
            12 => return self.substitute_rows::<12>(),
            15 => return self.substitute_rows::<15>(),
            18 => return self.substitute_rows::<18>(),
            21 => return self.substitute_rows::<21>(),
            24 => return self.substitute_rows::<24>(),
            _ => {}
        }
        let l = &self.factor[..rows * rows];
        let y = &mut self.scratch.y[..rows];
        // Two rows at a time: the sums over the entries both rows have share the loads of
        // `y`; the second row then takes the first's new entry. Each sum runs in the
        // same order as row by row, so the same bits.
        let mut a = 0;
        while a + 1 < rows {
            let (row0, row1) = (
                &l[a * rows..=a * rows + a],
                &l[(a + 1) * rows..=(a + 1) * rows + a + 1],
            );
            let (mut s0, mut s1) = (self.scratch.residual[a], self.scratch.residual[a + 1]);
            for ((x0, x1), v) in row0[..a].iter().zip(&row1[..a]).zip(&y[..a]) {
                s0 -= x0 * v;
                s1 -= x1 * v;
            }
            let y0 = s0 / row0[a];
            s1 -= row1[a] * y0;
            y[a] = y0;
            y[a + 1] = s1 / row1[a + 1];
            a += 2;
        }
        if a < rows {
            let row_a = &l[a * rows..=a * rows + a];
            let mut sum = self.scratch.residual[a];
            for (x, v) in row_a[..a].iter().zip(&y[..a]) {
                sum -= x * v;
            }
            y[a] = sum / row_a[a];
        }
        if rows <= SMALL_ROWS {
            for a in (0..rows).rev() {
                let mut sum = y[a];
                let below = l[(a + 1) * rows..].chunks_exact(rows);
                for (row_b, v) in below.zip(&y[a + 1..]) {
                    sum -= row_b[a] * v;
                }
                y[a] = sum / l[a * rows + a];
            }
            return y.iter().all(|v| v.is_finite());
        }
        for a in (0..rows).rev() {
            // Column `a` of the factor from the diagonal down is row `a` from the diagonal
            // on (the transpose above it). (Its sum runs over the rows below in
            // increasing order, the newest entry of `y` first, so two rows cannot share a
            // pass here.)
            let column = &l[a * rows + a..(a + 1) * rows];
            let (head, tail) = y.split_at_mut(a + 1);
            let mut sum = head[a];
            for (x, v) in column[1..].iter().zip(&*tail) {
                sum -= x * v;
            }
            head[a] = sum / column[0];
        }
        y.iter().all(|v| v.is_finite())
    }

    /// Turns each movable joint by its step `turn` (world axes taken into the parent's
    /// frame of the linearization, `global`) and projects it onto its limit.
    fn apply_step(
        &mut self,
        skeleton: &Skeleton,
        movable: &[usize],
        pose: &mut Pose,
        global: &GlobalPose,
    ) {
        self.scratch.clamped.fill(false);
        for (m, &j) in movable.iter().enumerate() {
            let w = self.scratch.turn[m];
            if w == DVec3::ZERO {
                continue;
            }
            let local = match skeleton.parent(j) {
                Some(p) => global.rotations[p].conjugate() * w,
                None => w,
            };
            let turned = (DQuat::from_scaled_axis(local) * pose.rotations[j]).normalize();
            let limit = skeleton.prepared_limit(j);
            if matches!(limit.limit(), JointLimit::Free) {
                pose.rotations[j] = turned;
            } else {
                let (projected, fixed) = limit.project_and_fixed(turned);
                if fixed {
                    self.scratch.fixed[m] = Some(projected);
                }
                // A rotation inside its limit comes back unchanged; only one that moved
                // needs its angle measured.
                self.scratch.clamped[m] =
                    projected != turned && moved_more_than_clamped(turned, projected);
                if self.scratch.clamped[m] {
                    // The pull-back as a world rotation vector: composed on the left in the
                    // parent's frame, then turned into the world like the step.
                    let mut back = projected * turned.conjugate();
                    if back.w < 0.0 {
                        back = -back;
                    }
                    let back = back.to_scaled_axis();
                    self.scratch.pulled_back[m] = match skeleton.parent(j) {
                        Some(p) => global.rotations[p] * back,
                        None => back,
                    };
                }
                pose.rotations[j] = projected;
            }
        }
    }
}

/// `rotation_angle(a, b) > CLAMPED`, the same answer, with the arc tangent only when the
/// angle is within a factor of ten of `CLAMPED`: the angle is `2 atan2(n, w)` for the
/// vector and scalar parts of the difference, and `atan x` is between `x (1 - x^2 / 3)`
/// and `x`, so `n > 10 CLAMPED w` means more than `CLAMPED` and `n < CLAMPED w / 10`
/// less.
fn moved_more_than_clamped(a: DQuat, b: DQuat) -> bool {
    let d = a.normalize().conjugate() * b.normalize();
    let (n, w) = (d.xyz().length(), d.w.abs());
    if n > 10.0 * CLAMPED * w {
        true
    } else if n < 0.1 * CLAMPED * w {
        false
    } else {
        rotation_angle(a, b) > CLAMPED
    }
}

/// The sparse columns of a linearization, read by [`steps_and_turns`].
struct Columns<'a> {
    dofs: &'a [(usize, DVec3)],
    col_start: &'a [usize],
    entries: &'a [(usize, f64)],
    groups: &'a [Group],
    /// Per degree of freedom that starts a triple, its groups; empty when the groups are
    /// not those of these columns.
    groups_of: &'a [Option<(usize, usize)>],
}

/// [`Finish::turns`] before the blocked directions: the step of every degree of freedom
/// (`J_k . y`) into `step` (zeroed, one per degree of freedom), each unfrozen joint's sum
/// of its axes times their steps into `turn` (zeroed), and the translation's shift
/// returned. The outputs are parameters of their own, so the compiler knows that writing
/// them changes none of the columns or `y`, and keeps those in registers.
///
/// The three columns of a joint's world axes share their rows: one pass reads each entry
/// of `y` once for the three sums (each summed in the column's order from -0.0, as
/// `Iterator::sum` does). Over the groups of three rows the products with a zero factor
/// are left out: adding a zero changes a sum only from -0.0 to +0.0, and a step that is
/// zero either way turns nothing and points neither way. A joint's turn is summed axis by
/// axis from its entry in `turn`, as for single columns.
fn steps_and_turns(
    columns: &Columns<'_>,
    y: &[f64],
    frozen: &[bool],
    step: &mut [f64],
    turn: &mut [DVec3],
) -> DVec3 {
    let Columns {
        dofs,
        col_start,
        entries,
        groups,
        groups_of,
    } = *columns;
    let mut shift = DVec3::ZERO;
    let mut k = 0;
    while k < dofs.len() {
        let (m, u) = dofs[k];
        // Groups are gathered only for triples of these columns (see `accumulate_normal`).
        let grouped = groups_of.get(k).copied().flatten();
        let triple =
            grouped.is_some() || (k + 2 < dofs.len() && dofs[k + 1].0 == m && dofs[k + 2].0 == m);
        debug_assert!(
            grouped.is_none() || (k + 2 < dofs.len() && dofs[k + 1].0 == m && dofs[k + 2].0 == m)
        );
        if !triple {
            let mut sum = -0.0;
            for &(row, v) in &entries[col_start[k]..col_start[k + 1]] {
                sum += v * y[row];
            }
            step[k] = sum;
            if m == TRANSLATION {
                shift += u * sum;
            } else if !frozen[m] {
                turn[m] += u * sum;
            }
            k += 1;
            continue;
        }
        let (mut sx, mut sy, mut sz) = (-0.0, -0.0, -0.0);
        if let Some((g0, g1)) = grouped {
            for g in &groups[g0..g1] {
                let [y0, y1, y2] = y[g.row..g.row + 3] else {
                    unreachable!("a group has three rows")
                };
                let v = &g.v;
                match g.kind {
                    GroupKind::Cross => {
                        sx += v[0][1] * y1;
                        sx += v[0][2] * y2;
                        sy += v[1][0] * y0;
                        sy += v[1][2] * y2;
                        sz += v[2][0] * y0;
                        sz += v[2][1] * y1;
                    }
                    GroupKind::Axis => {
                        sx += v[0][0] * y0;
                        sy += v[1][1] * y1;
                        sz += v[2][2] * y2;
                    }
                    GroupKind::Dense => {
                        for (i, yi) in [y0, y1, y2].into_iter().enumerate() {
                            sx += v[0][i] * yi;
                            sy += v[1][i] * yi;
                            sz += v[2][i] * yi;
                        }
                    }
                }
            }
        } else {
            let (a0, a1, a2, a3) = (
                col_start[k],
                col_start[k + 1],
                col_start[k + 2],
                col_start[k + 3],
            );
            for ((&(row, x), &(_, yv)), &(_, z)) in entries[a0..a1]
                .iter()
                .zip(&entries[a1..a2])
                .zip(&entries[a2..a3])
            {
                let v = y[row];
                sx += x * v;
                sy += yv * v;
                sz += z * v;
            }
        }
        step[k..k + 3].copy_from_slice(&[sx, sy, sz]);
        let axes = [u, dofs[k + 1].1, dofs[k + 2].1];
        if m == TRANSLATION {
            for (u, s) in axes.into_iter().zip([sx, sy, sz]) {
                shift += u * s;
            }
        } else if !frozen[m] {
            let mut w = turn[m];
            for (u, s) in axes.into_iter().zip([sx, sy, sz]) {
                w += u * s;
            }
            turn[m] = w;
        }
        k += 3;
    }
    shift
}

/// [`Finish::factorize`] for `N` rows known at compile time: the same sums in the same
/// order, column by column, the rows below four (then two, then one) at a time; with the
/// bounds constants the compiler drops the index checks and unrolls.
// Indices rather than iterators: over rows of constant length the checks drop out, and
// each sum reads two rows at the same index.
#[allow(clippy::needless_range_loop)]
fn factorize_fixed<const N: usize>(n: &[[f64; N]], l: &mut [[f64; N]], damping: f64) -> bool {
    let (n, l) = (&n[..N], &mut l[..N]);
    for b in 0..N {
        let mut sum = n[b][b] + damping;
        for k in 0..b {
            sum -= l[b][k] * l[b][k];
        }
        if !(sum.is_finite() && sum > 0.0) {
            return false;
        }
        let pivot = sum.sqrt();
        l[b][b] = pivot;
        let mut a = b + 1;
        while a + 3 < N {
            let mut s = [n[a][b], n[a + 1][b], n[a + 2][b], n[a + 3][b]];
            for k in 0..b {
                let y = l[b][k];
                s[0] -= l[a][k] * y;
                s[1] -= l[a + 1][k] * y;
                s[2] -= l[a + 2][k] * y;
                s[3] -= l[a + 3][k] * y;
            }
            let v = s.map(|s| s / pivot);
            l[a][b] = v[0];
            l[a + 1][b] = v[1];
            l[a + 2][b] = v[2];
            l[a + 3][b] = v[3];
            l[b][a..a + 4].copy_from_slice(&v);
            a += 4;
        }
        while a + 1 < N {
            let (mut s0, mut s1) = (n[a][b], n[a + 1][b]);
            for k in 0..b {
                let y = l[b][k];
                s0 -= l[a][k] * y;
                s1 -= l[a + 1][k] * y;
            }
            let (v0, v1) = (s0 / pivot, s1 / pivot);
            l[a][b] = v0;
            l[a + 1][b] = v1;
            l[b][a] = v0;
            l[b][a + 1] = v1;
            a += 2;
        }
        if a < N {
            let mut s = n[a][b];
            for k in 0..b {
                s -= l[a][k] * l[b][k];
            }
            let v = s / pivot;
            l[a][b] = v;
            l[b][a] = v;
        }
    }
    true
}

/// Three consecutive rows of a triple of world-axis columns: the first row, the values
/// `v[k][i]` of column `k` at row `row + i`, and which of them may be non-zero.
#[derive(Clone, Copy, Debug)]
struct Group {
    row: usize,
    v: [[f64; 3]; 3],
    kind: GroupKind,
}

/// Which values of a [`Group`] may be non-zero (the others are exactly zero).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum GroupKind {
    /// `v[k][k] == 0`: a position group of a joint's columns, `u_k x d`.
    Cross,
    /// `v[k][i] == 0` for `i != k`: a rotation group, or the translation's, `u_k w`.
    Axis,
    /// Any values.
    Dense,
}

impl GroupKind {
    /// Whether `v[k][i]` may be non-zero.
    #[inline(always)]
    const fn may_be_nonzero(self, k: usize, i: usize) -> bool {
        match self {
            GroupKind::Cross => k != i,
            GroupKind::Axis => k == i,
            GroupKind::Dense => true,
        }
    }
}

/// Splits the three columns of a triple (the same rows in the same order) into groups of
/// three consecutive rows, appended to `groups`; false (and nothing appended) when they
/// do not split so.
fn gather_groups(
    cx: &[(usize, f64)],
    cy: &[(usize, f64)],
    cz: &[(usize, f64)],
    groups: &mut Vec<Group>,
) -> bool {
    let before = groups.len();
    if !cx.len().is_multiple_of(3) || cy.len() != cx.len() || cz.len() != cx.len() {
        return false;
    }
    for ((x, y), z) in cx
        .chunks_exact(3)
        .zip(cy.chunks_exact(3))
        .zip(cz.chunks_exact(3))
    {
        let row = x[0].0;
        if x[1].0 != row + 1 || x[2].0 != row + 2 {
            groups.truncate(before);
            return false;
        }
        let v = [
            [x[0].1, x[1].1, x[2].1],
            [y[0].1, y[1].1, y[2].1],
            [z[0].1, z[1].1, z[2].1],
        ];
        let kind = if v[0][0] == 0.0 && v[1][1] == 0.0 && v[2][2] == 0.0 {
            GroupKind::Cross
        } else if v[0][1] == 0.0
            && v[0][2] == 0.0
            && v[1][0] == 0.0
            && v[1][2] == 0.0
            && v[2][0] == 0.0
            && v[2][1] == 0.0
        {
            GroupKind::Axis
        } else {
            GroupKind::Dense
        };
        groups.push(Group { row, v, kind });
    }
    true
}

/// Adds the products of every pair of `groups` (one triple's) to the lower triangle of
/// `normal` (`rows` x `rows`), each later group with every earlier one, then with itself.
/// For the usual sizes (three rows per position goal, six with a rotation goal) the
/// matrix is seen as rows of a length known at compile time, so that a block's three
/// lines take one bounds check each way instead of one each and the index products fold.
fn add_groups(normal: &mut [f64], rows: usize, groups: &[Group]) {
    match rows {
        9 => add_groups_fixed::<9>(normal.as_chunks_mut::<9>().0, groups),
        12 => add_groups_fixed::<12>(normal.as_chunks_mut::<12>().0, groups),
        15 => add_groups_fixed::<15>(normal.as_chunks_mut::<15>().0, groups),
        18 => add_groups_fixed::<18>(normal.as_chunks_mut::<18>().0, groups),
        21 => add_groups_fixed::<21>(normal.as_chunks_mut::<21>().0, groups),
        24 => add_groups_fixed::<24>(normal.as_chunks_mut::<24>().0, groups),
        _ => {
            for (g, group) in groups.iter().enumerate() {
                for other in &groups[..g] {
                    let mut block = load_block(normal, rows, group, other);
                    add_group_pair::<false>(&mut block, group, other);
                    store_block(normal, rows, group, other, &block);
                }
                let mut block = load_block(normal, rows, group, group);
                add_group_pair::<true>(&mut block, group, group);
                store_block(normal, rows, group, group, &block);
            }
        }
    }
}

/// [`add_groups`] over rows of `N`.
fn add_groups_fixed<const N: usize>(normal: &mut [[f64; N]], groups: &[Group]) {
    for (g, group) in groups.iter().enumerate() {
        let lines: &mut [[f64; N]; 3] = (&mut normal[group.row..group.row + 3])
            .try_into()
            .expect("three lines");
        for other in &groups[..g] {
            add_group_pair_fixed::<false, N>(lines, group, other);
        }
        add_group_pair_fixed::<true, N>(lines, group, group);
    }
}

/// [`add_group_pair`] on the block of the three `lines` of `g` at the columns of `h`.
#[inline(always)]
fn add_group_pair_fixed<const DIAGONAL: bool, const N: usize>(
    lines: &mut [[f64; N]; 3],
    g: &Group,
    h: &Group,
) {
    let mut block = [[0.0; 3]; 3];
    for (b, line) in block.iter_mut().zip(lines.iter()) {
        b.copy_from_slice(&line[h.row..h.row + 3]);
    }
    add_group_pair::<DIAGONAL>(&mut block, g, h);
    for (b, line) in block.iter().zip(lines.iter_mut()) {
        line[h.row..h.row + 3].copy_from_slice(b);
    }
}

/// The block of `normal` (`rows` x `rows`) at the rows of `g` and the columns of `h`.
#[inline(always)]
fn load_block(normal: &[f64], rows: usize, g: &Group, h: &Group) -> [[f64; 3]; 3] {
    let mut block = [[0.0; 3]; 3];
    for (i, b) in block.iter_mut().enumerate() {
        let start = (g.row + i) * rows + h.row;
        b.copy_from_slice(&normal[start..start + 3]);
    }
    block
}

/// Writes back a block read by [`load_block`].
#[inline(always)]
fn store_block(normal: &mut [f64], rows: usize, g: &Group, h: &Group, block: &[[f64; 3]; 3]) {
    for (i, b) in block.iter().enumerate() {
        let start = (g.row + i) * rows + h.row;
        normal[start..start + 3].copy_from_slice(b);
    }
}

/// Adds the products of group `g` (the later rows) and group `h` to `block`, the
/// entries of the normal matrix at the rows of `g` and the columns of `h`, each entry
/// taking the three columns' products in order, those with a zero factor left out; with
/// `DIAGONAL` (`g` is `h`) only the entries on and below the diagonal (the others are
/// left as they are).
#[inline(always)]
fn add_group_pair<const DIAGONAL: bool>(block: &mut [[f64; 3]; 3], g: &Group, h: &Group) {
    match (g.kind, h.kind) {
        (GroupKind::Cross, GroupKind::Cross) => {
            add_block::<DIAGONAL>(block, g, h, GroupKind::Cross, GroupKind::Cross);
        }
        (GroupKind::Cross, GroupKind::Axis) => {
            add_block::<DIAGONAL>(block, g, h, GroupKind::Cross, GroupKind::Axis);
        }
        (GroupKind::Axis, GroupKind::Cross) => {
            add_block::<DIAGONAL>(block, g, h, GroupKind::Axis, GroupKind::Cross);
        }
        (GroupKind::Axis, GroupKind::Axis) => {
            add_block::<DIAGONAL>(block, g, h, GroupKind::Axis, GroupKind::Axis);
        }
        _ => add_block::<DIAGONAL>(block, g, h, GroupKind::Dense, GroupKind::Dense),
    }
}

/// The block of [`add_group_pair`] for the kinds `kg` and `kh` (constants once inlined, so
/// the loops unroll and the zero products drop out).
#[inline(always)]
fn add_block<const DIAGONAL: bool>(
    block: &mut [[f64; 3]; 3],
    g: &Group,
    h: &Group,
    kg: GroupKind,
    kh: GroupKind,
) {
    for (i, line) in block.iter_mut().enumerate() {
        let last = if DIAGONAL { i } else { 2 };
        for (j, entry) in line[..=last].iter_mut().enumerate() {
            let mut e = *entry;
            for k in 0..3 {
                if kg.may_be_nonzero(k, i) && kh.may_be_nonzero(k, j) {
                    e += g.v[k][i] * h.v[k][j];
                }
            }
            *entry = e;
        }
    }
}

/// Subtracts the outer product of a sparse column (rows increasing) from the lower
/// triangle of a rows x rows matrix.
fn subtract_outer(matrix: &mut [f64], rows: usize, column: &[(usize, f64)]) {
    for (i, &(a, va)) in column.iter().enumerate() {
        let line = &mut matrix[a * rows..=a * rows + a];
        for &(b, vb) in &column[..=i] {
            line[b] -= va * vb;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The translation's three columns over three position rows of the given weights (rows
    /// 0, 3 and 6), as `linearize` writes them.
    fn push_translation_columns(fin: &mut Finish, weights: [f64; 3]) {
        for u in [DVec3::X, DVec3::Y, DVec3::Z] {
            fin.col_start.push(fin.entries.len());
            fin.dofs.push((TRANSLATION, u));
            for (row, w) in [0, 3, 6].into_iter().zip(weights) {
                let v = u * w;
                fin.entries
                    .extend([(row, v.x), (row + 1, v.y), (row + 2, v.z)]);
            }
        }
    }

    /// Joint 0's three columns, one per axis `u`, as `linearize` writes a joint's triple
    /// over two position rows (0 and 6, arms `d` from the joint, weights `w[0]` and
    /// `w[1]`) and a rotation row (9, weight `w[2]`).
    fn push_joint_triple(fin: &mut Finish, d: [DVec3; 2], w: [f64; 3]) {
        for u in [DVec3::X, DVec3::Y, DVec3::Z] {
            fin.col_start.push(fin.entries.len());
            fin.dofs.push((0, u));
            for (row, v) in [
                (0, u.cross(d[0]) * w[0]),
                (6, u.cross(d[1]) * w[1]),
                (9, u * w[2]),
            ] {
                fin.entries
                    .extend([(row, v.x), (row + 1, v.y), (row + 2, v.z)]);
            }
        }
    }

    /// Numbers uniform in [-1, 1) from a xorshift generator started at `seed`.
    fn uniform(mut seed: u64) -> impl FnMut() -> f64 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        }
    }

    #[test]
    fn the_quick_clamp_test_agrees_with_the_angle() {
        // Pairs of rotations apart by angles from far below to far above the threshold,
        // about assorted axes.
        let base = DQuat::from_axis_angle(DVec3::new(1.0, 2.0, -0.5).normalize(), 0.7);
        for k in 0..200 {
            let t = f64::from(k);
            let axis = DVec3::new((t * 0.37).sin(), (t * 0.91).cos(), 0.2).normalize();
            let angle = CLAMPED * 10f64.powf(-3.0 + 6.0 * t / 199.0);
            let other = DQuat::from_axis_angle(axis, angle) * base;
            for (a, b) in [(base, other), (other, base), (base, -other)] {
                assert_eq!(
                    moved_more_than_clamped(a, b),
                    rotation_angle(a, b) > CLAMPED,
                    "angle {angle:e}"
                );
            }
        }
    }

    #[test]
    fn a_joint_deep_inside_its_limit_has_no_bound_within_the_difference_step() {
        let st = crate::limits::SwingTwist {
            twist_axis: DVec3::X,
            a_axis: DVec3::Z,
            swing_a: 1.2,
            swing_b: 0.5,
            twist_min: -0.4,
            twist_max: 0.9,
        };
        let frame = LimitFrame::of(&st);
        let (mut deep, mut near) = (0, 0);
        for k in 0..2000 {
            let t = k as f64;
            let axis = DVec3::new((t * 0.71).sin(), (t * 0.29).cos(), (t * 0.13).sin());
            let q = DQuat::from_scaled_axis(axis * (0.2 + (t * 0.007) % 1.0));
            if st.deep_inside(&frame, q, DEEP_INSIDE) {
                deep += 1;
                // Each rotation the differences of `find_outward` evaluate is inside.
                for e in [DVec3::X, DVec3::Y, DVec3::Z] {
                    for h in [1e-7, -1e-7] {
                        let moved = DQuat::from_scaled_axis(e * h) * q;
                        assert_eq!(st.violation_parts(moved), (0.0, 0.0), "{q}");
                    }
                }
            } else if st.violation_parts(q) == (0.0, 0.0) {
                near += 1;
            }
        }
        // Both kinds occur: joints deep inside, and joints inside but near a bound (or
        // off the inscribed disc), which are left to the differences.
        assert!(deep > 100 && near > 100, "{deep} {near}");
    }

    #[test]
    fn a_chain_s_joints_all_move_its_effector() {
        let mut movers = Movers::default();
        movers.chain(&[2, 3, 4]);
        assert_eq!(movers.movable(), [2, 3, 4]);
        for m in 0..3 {
            assert_eq!(movers.below(m), [0]);
        }
    }

    #[test]
    #[allow(clippy::needless_range_loop)]
    fn the_normal_matrix_is_j_j_transpose_and_the_solve_inverts_it() {
        let mut fin = Finish::default();
        let rows = 4;
        fin.dofs = vec![(0, DVec3::X), (1, DVec3::Y), (2, DVec3::Z)];
        fin.col_start = vec![0, 2, 5, 7];
        fin.entries = vec![
            (0, 1.0),
            (2, -2.0),
            (0, 0.5),
            (1, 3.0),
            (3, 1.5),
            (2, 0.25),
            (3, -1.0),
        ];
        fin.scratch.normal_full.resize(rows * rows, 0.0);
        fin.scratch.normal.resize(rows * rows, 0.0);
        fin.factor.resize(rows * rows, 0.0);
        fin.accumulate_normal(rows);
        fin.scratch.normal.copy_from_slice(&fin.scratch.normal_full);
        // Dense J, rows x dofs.
        let mut j = [[0.0; 3]; 4];
        for k in 0..3 {
            for &(r, v) in &fin.entries[fin.col_start[k]..fin.col_start[k + 1]] {
                j[r][k] = v;
            }
        }
        for a in 0..rows {
            for b in 0..=a {
                let expected: f64 = (0..3).map(|k| j[a][k] * j[b][k]).sum();
                assert!((fin.scratch.normal[a * rows + b] - expected).abs() < 1e-15);
            }
        }
        fin.scratch.residual = vec![1.0, -2.0, 0.5, 3.0];
        fin.scratch.y.resize(rows, 0.0);
        let damping = 0.1;
        assert!(fin.solve(rows, damping));
        for a in 0..rows {
            let mut back = damping * fin.scratch.y[a];
            for b in 0..rows {
                let n: f64 = (0..3).map(|k| j[a][k] * j[b][k]).sum();
                back += n * fin.scratch.y[b];
            }
            assert!((back - fin.scratch.residual[a]).abs() < 1e-12, "row {a}");
        }
        // J J^T is singular here (rank 3 of 4): without damping there is no solution,
        // and the solve says so instead of returning NaN.
        assert!(!fin.solve(rows, 0.0) || fin.scratch.y.iter().all(|v| v.is_finite()));
    }

    #[test]
    #[allow(clippy::field_reassign_with_default)]
    fn blocking_a_direction_leaves_the_normal_matrix_of_the_other_two() {
        // One swing-twist joint with world-axis columns over 3 rows; blocking `b` must
        // leave exactly the normal matrix of two columns along a basis orthogonal to `b`.
        let limit = JointLimit::cone(DVec3::X, 1.0).unwrap();
        let skel = Skeleton::new([crate::JointDef {
            limit,
            ..Default::default()
        }])
        .unwrap();
        let cols = [[0.3, -1.2, 0.5], [1.1, 0.4, -0.7], [-0.2, 0.9, 1.3]];
        let rows = 3;
        let mut fin = Finish::default();
        fin.dofs = vec![(0, DVec3::X), (0, DVec3::Y), (0, DVec3::Z)];
        fin.col_start = vec![0, 3, 6, 9];
        fin.entries = cols
            .iter()
            .flat_map(|c| (0..3).map(move |r| (r, c[r])))
            .collect();
        fin.first_dof = vec![0];
        fin.frozen = vec![false];
        let b = DVec3::new(1.0, 2.0, -2.0) / 3.0;
        fin.blocked = vec![[b, DVec3::ZERO]];
        fin.blocked_count = vec![1];
        fin.scratch.normal_full.resize(9, 0.0);
        fin.scratch.normal.resize(9, 0.0);
        fin.accumulate_normal(rows);
        assert!(fin.reduce(&skel, &[0], rows));
        let column = |u: DVec3| -> [f64; 3] {
            std::array::from_fn(|r| u.x * cols[0][r] + u.y * cols[1][r] + u.z * cols[2][r])
        };
        let (u, v) = b.any_orthonormal_pair();
        let (cu, cv) = (column(u), column(v));
        for a in 0..rows {
            for c in 0..=a {
                let expected = cu[a] * cu[c] + cv[a] * cv[c];
                assert!(
                    (fin.scratch.normal[a * rows + c] - expected).abs() < 1e-14,
                    "{a} {c}"
                );
            }
        }
        // Frozen: nothing of the joint is left.
        fin.frozen = vec![true];
        assert!(!fin.reduce(&skel, &[0], rows));
        assert!(fin.scratch.normal.iter().all(|x| x.abs() < 1e-14));
    }

    /// The row-by-row textbook Cholesky factor and substitutions, for the bits of the
    /// column-by-column ones.
    #[allow(clippy::needless_range_loop)]
    fn textbook_solve(n: &[f64], r: &[f64], rows: usize, damping: f64) -> Option<Vec<f64>> {
        let mut l = vec![0.0; rows * rows];
        for a in 0..rows {
            for b in 0..a {
                let mut sum = n[a * rows + b];
                for k in 0..b {
                    sum -= l[a * rows + k] * l[b * rows + k];
                }
                l[a * rows + b] = sum / l[b * rows + b];
            }
            let mut sum = n[a * rows + a] + damping;
            for k in 0..a {
                sum -= l[a * rows + k] * l[a * rows + k];
            }
            if !(sum.is_finite() && sum > 0.0) {
                return None;
            }
            l[a * rows + a] = sum.sqrt();
        }
        let mut y = vec![0.0; rows];
        for a in 0..rows {
            let mut sum = r[a];
            for k in 0..a {
                sum -= l[a * rows + k] * y[k];
            }
            y[a] = sum / l[a * rows + a];
        }
        for a in (0..rows).rev() {
            let mut sum = y[a];
            for b in a + 1..rows {
                sum -= l[b * rows + a] * y[b];
            }
            y[a] = sum / l[a * rows + a];
        }
        Some(y)
    }

    #[test]
    #[allow(clippy::field_reassign_with_default)]
    fn the_column_by_column_factor_solves_to_the_bits_of_the_textbook_loops() {
        // Random J J^T of every size from 1 to 27 rows (row by row up to `SMALL_ROWS`,
        // then by columns, the sizes that are multiples of three up to 24 with constant
        // bounds, the rows below taken four at a time ending every way), solved both ways
        // with the same bits; a matrix with a negative pivot is refused by both.
        let mut next = uniform(0x2545_f491_4f6c_dd1d_u64);
        for rows in 1..=27 {
            let cols = rows + 2;
            let j: Vec<f64> = (0..rows * cols).map(|_| next()).collect();
            let mut fin = Finish::default();
            fin.scratch.normal = vec![0.0; rows * rows];
            for a in 0..rows {
                for b in 0..=a {
                    fin.scratch.normal[a * rows + b] =
                        (0..cols).map(|k| j[a * cols + k] * j[b * cols + k]).sum();
                }
            }
            fin.scratch.residual = (0..rows).map(|_| next()).collect();
            fin.scratch.y = vec![0.0; rows];
            let expected = textbook_solve(&fin.scratch.normal, &fin.scratch.residual, rows, 0.01)
                .expect("SPD");
            assert!(fin.solve(rows, 0.01));
            for (a, (got, want)) in fin.scratch.y.iter().zip(&expected).enumerate() {
                assert_eq!(got.to_bits(), want.to_bits(), "{rows} rows, entry {a}");
            }
            for a in (0..rows).filter(|_| rows > SMALL_ROWS) {
                for b in 0..=a {
                    assert_eq!(fin.factor[a * rows + b], fin.factor[b * rows + a]);
                }
            }
            fin.scratch.normal[(rows - 1) * rows + rows - 1] = -1.0;
            assert!(
                textbook_solve(&fin.scratch.normal, &fin.scratch.residual, rows, 0.01).is_none()
            );
            assert!(!fin.solve(rows, 0.01));
        }
    }

    #[test]
    #[allow(clippy::field_reassign_with_default)]
    fn the_normal_matrix_by_groups_has_the_bits_of_every_product_added() {
        // A joint's triple over two effectors (one with a rotation goal, one its own
        // joint's rotation only), the translation's triple and a hinge column, as
        // `linearize` makes them (with exact zeros, some components of `d` zero too),
        // against the products of every pair of entries added in column order; in a
        // matrix of the rows the columns reach (12), and in larger ones, of a size with
        // the rows' length a constant (15, 24) and of others (13, 27).
        let mut next = uniform(0x9e37_79b9_7f4a_7c15_u64);
        for (round, rows) in (0..40).zip([12, 13, 15, 24, 27].into_iter().cycle()) {
            let mut fin = Finish::default();
            let mut d = [
                DVec3::new(next(), next(), next()),
                DVec3::new(next(), 0.0, next()),
            ];
            if round % 2 == 1 {
                d[0].x = -0.0;
            }
            let (w0, w1, wr) = (1.0 + next().abs(), 0.5, 2.0);
            push_joint_triple(&mut fin, d, [w0, w1, wr]);
            fin.col_start.push(fin.entries.len());
            fin.dofs.push((1, DVec3::Y));
            fin.entries.extend([(0, next()), (2, next()), (7, next())]);
            push_translation_columns(&mut fin, [w0, 1.5, w1]);
            fin.col_start.push(fin.entries.len());
            fin.scratch.normal_full.resize(rows * rows, 0.0);
            fin.accumulate_normal(rows);
            let mut expected = vec![0.0f64; rows * rows];
            for k in 0..fin.dofs.len() {
                let col = &fin.entries[fin.col_start[k]..fin.col_start[k + 1]];
                for &(a, va) in col {
                    for &(b, vb) in col.iter().filter(|(b, _)| *b <= a) {
                        expected[a * rows + b] += va * vb;
                    }
                }
            }
            for a in 0..rows {
                for b in 0..=a {
                    let (got, want) = (
                        fin.scratch.normal_full[a * rows + b],
                        expected[a * rows + b],
                    );
                    assert_eq!(
                        got.to_bits(),
                        want.to_bits(),
                        "round {round}, {rows} rows: {a} {b}"
                    );
                }
            }
        }
    }

    #[test]
    #[allow(clippy::field_reassign_with_default)]
    fn the_steps_and_turns_by_groups_have_the_bits_of_the_column_sums() {
        // Two joints' triples (one over groups of three rows, one over rows that do not
        // split so), a hinge column, the translation's triple; some joints frozen or with
        // a blocked direction; against each column's sum over all its entries in order
        // and the turns summed axis by axis from them. Leaving out the zero products may
        // change a zero sum's sign only.
        let mut next = uniform(0x2545_f491_4f6c_dd1d_u64);
        let same =
            |got: f64, want: f64| got.to_bits() == want.to_bits() || (got == 0.0 && want == 0.0);
        for round in 0..24 {
            let rows = [12, 15][round % 2];
            let mut fin = Finish::default();
            let d = [
                DVec3::new(next(), next(), next()),
                DVec3::new(next(), 0.0, next()),
            ];
            let (w0, w1, wr) = (1.0 + next().abs(), 0.5, 2.0);
            push_joint_triple(&mut fin, d, [w0, w1, wr]);
            for u in [DVec3::X, DVec3::Y, DVec3::Z] {
                fin.col_start.push(fin.entries.len());
                fin.dofs.push((1, u));
                fin.entries.extend([(1, next()), (4, u.x), (8, next())]);
            }
            fin.col_start.push(fin.entries.len());
            fin.dofs
                .push((2, DVec3::new(next(), next(), next()).normalize()));
            fin.entries.extend([(0, next()), (2, next()), (7, next())]);
            push_translation_columns(&mut fin, [w0, 1.5, w1]);
            fin.col_start.push(fin.entries.len());
            fin.scratch.normal_full.resize(rows * rows, 0.0);
            fin.accumulate_normal(rows);
            assert!(fin.groups_of[0].is_some() && fin.groups_of[3].is_none());
            fin.scratch.y = (0..rows).map(|_| next()).collect();
            if round % 3 == 0 {
                fin.scratch.y[1] = 0.0;
                fin.scratch.y[2] = -0.0;
            }
            fin.frozen = vec![round % 4 == 1, round % 4 == 2, round % 5 == 3];
            fin.blocked = vec![[DVec3::ZERO; 2]; 3];
            fin.blocked_count = vec![0; 3];
            if round % 3 == 2 {
                fin.blocked[0][0] = DVec3::new(next(), next(), next()).normalize();
                fin.blocked_count[0] = 1;
            }
            fin.scratch.turn = vec![DVec3::ZERO; 3];
            let shift = fin.turns(&[10, 11, 12]);

            let mut want_turn = [DVec3::ZERO; 3];
            let mut want_shift = DVec3::ZERO;
            for (k, &(m, u)) in fin.dofs.iter().enumerate() {
                let col = &fin.entries[fin.col_start[k]..fin.col_start[k + 1]];
                let step: f64 = col.iter().map(|&(row, v)| v * fin.scratch.y[row]).sum();
                assert!(same(fin.scratch.step[k], step), "round {round}: dof {k}");
                if m == TRANSLATION {
                    want_shift += u * step;
                } else if !fin.frozen[m] {
                    want_turn[m] += u * step;
                }
            }
            if fin.blocked_count[0] == 1 {
                let b = fin.blocked[0][0];
                want_turn[0] -= b * b.dot(want_turn[0]);
            }
            for (m, (got, want)) in fin.scratch.turn.iter().zip(&want_turn).enumerate() {
                for (got, want) in got.to_array().into_iter().zip(want.to_array()) {
                    assert!(same(got, want), "round {round}: joint {m}");
                }
            }
            for (got, want) in shift.to_array().into_iter().zip(want_shift.to_array()) {
                assert!(same(got, want), "round {round}: shift");
            }
        }
    }

    /// A three-joint chain from the origin along +y, free joints, one effector on its tip.
    fn small_problem() -> (Skeleton, Vec<Target>, Movers) {
        let skeleton = Skeleton::new([
            crate::JointDef::root(DVec3::ZERO),
            crate::JointDef::child(0, DVec3::Y),
            crate::JointDef::child(1, DVec3::Y),
        ])
        .expect("valid");
        let targets = vec![Target {
            joint: 2,
            position: DVec3::new(0.8, 1.2, 0.3),
            rotation: None,
            position_weight: 1.0,
            rotation_weight: 0.0,
            pinned: false,
        }];
        let mut movers = Movers::default();
        movers.build(&skeleton, &targets);
        (skeleton, targets, movers)
    }

    fn job<'a>(skeleton: &'a Skeleton, movers: &'a Movers, targets: &'a [Target]) -> FinishJob<'a> {
        FinishJob {
            skeleton,
            movers,
            targets,
            translates: true,
            base: None,
            settings: SolveSettings::default(),
            iterations: 0,
            chord_start: false,
            stall_window: 10,
            damping_cap: 1.0,
        }
    }

    /// The field a refusal names, or a panic saying what came instead.
    fn refused_field(result: Result<(), SkeletonError>) -> String {
        match result {
            Err(SkeletonError::InvalidFinishJob { field, reason }) => {
                let message = SkeletonError::InvalidFinishJob {
                    field: field.clone(),
                    reason,
                }
                .to_string();
                assert!(message.contains(&field), "{message}");
                field
            }
            other => panic!("not refused by field: {other:?}"),
        }
    }

    #[test]
    fn a_bad_finish_job_is_refused_naming_the_field() {
        let (skeleton, targets, movers) = small_problem();
        let good = job(&skeleton, &movers, &targets);
        assert_eq!(good.validate(), Ok(()));
        // Every value a caller may mean is accepted: no cap on the damping, no stall
        // rule or a window past the cap, no iteration left, a zero tolerance.
        for accepted in [
            FinishJob {
                damping_cap: f64::INFINITY,
                ..good
            },
            FinishJob {
                damping_cap: 1e-300,
                ..good
            },
            FinishJob {
                stall_window: 0,
                ..good
            },
            FinishJob {
                stall_window: usize::MAX,
                ..good
            },
            FinishJob {
                iterations: good.settings.max_iterations,
                ..good
            },
            FinishJob {
                settings: SolveSettings {
                    tolerance: 0.0,
                    rotation_tolerance: 0.0,
                    max_iterations: 0,
                },
                ..good
            },
        ] {
            assert_eq!(accepted.validate(), Ok(()), "{accepted:?}");
        }
        let settings = good.settings;
        let cases: Vec<(FinishJob<'_>, &str)> = vec![
            (
                FinishJob {
                    damping_cap: f64::NAN,
                    ..good
                },
                "damping_cap",
            ),
            (
                FinishJob {
                    damping_cap: 0.0,
                    ..good
                },
                "damping_cap",
            ),
            (
                FinishJob {
                    damping_cap: -1.0,
                    ..good
                },
                "damping_cap",
            ),
            (
                FinishJob {
                    damping_cap: f64::NEG_INFINITY,
                    ..good
                },
                "damping_cap",
            ),
            (
                FinishJob {
                    iterations: settings.max_iterations + 1,
                    ..good
                },
                "iterations",
            ),
            (
                FinishJob {
                    settings: SolveSettings {
                        tolerance: f64::NAN,
                        ..settings
                    },
                    ..good
                },
                "settings.tolerance",
            ),
            (
                FinishJob {
                    settings: SolveSettings {
                        tolerance: -1e-6,
                        ..settings
                    },
                    ..good
                },
                "settings.tolerance",
            ),
            (
                FinishJob {
                    settings: SolveSettings {
                        rotation_tolerance: f64::INFINITY,
                        ..settings
                    },
                    ..good
                },
                "settings.rotation_tolerance",
            ),
            (
                FinishJob {
                    base: Some(3),
                    ..good
                },
                "base",
            ),
        ];
        for (bad, field) in cases {
            assert_eq!(refused_field(bad.validate()), field, "{bad:?}");
        }
        // Targets: each field of the second target spoiled in turn.
        type Spoil = fn(&mut Target);
        let spoil: [(Spoil, &str); 8] = [
            (|t| t.joint = 3, "targets[1].joint"),
            (|t| t.position.y = f64::NAN, "targets[1].position"),
            (|t| t.position_weight = 0.0, "targets[1].position_weight"),
            (
                |t| t.position_weight = f64::INFINITY,
                "targets[1].position_weight",
            ),
            (|t| t.rotation_weight = -1.0, "targets[1].rotation_weight"),
            (
                |t| t.rotation_weight = f64::NAN,
                "targets[1].rotation_weight",
            ),
            (
                |t| t.rotation = Some(DQuat::from_xyzw(0.0, 0.0, 0.0, 2.0)),
                "targets[1].rotation",
            ),
            (
                |t| t.rotation = Some(DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0)),
                "targets[1].rotation",
            ),
        ];
        for (change, field) in spoil {
            let mut two = vec![targets[0]; 2];
            change(&mut two[1]);
            // The movers of the good targets (a joint out of range cannot be walked).
            let mut movers = Movers::default();
            movers.build(&skeleton, &[targets[0], targets[0]]);
            assert_eq!(
                refused_field(job(&skeleton, &movers, &two).validate()),
                field
            );
        }
        // Movers that do not belong to the skeleton or the targets.
        let mut far = Movers::default();
        far.chain(&[0, 5]);
        assert_eq!(
            refused_field(job(&skeleton, &far, &targets).validate()),
            "movers.movable[1]"
        );
        assert_eq!(
            refused_field(job(&skeleton, &movers, &[]).validate()),
            "movers.below(0)"
        );
        // The movers' largest entries, which the validation compares, follow every
        // rebuild: the same buffers written again for a problem they fit are accepted,
        // and for one they do not fit refused again.
        far.chain(&[0, 1]);
        assert_eq!(job(&skeleton, &far, &targets).validate(), Ok(()));
        far.chain(&[1, 3]);
        assert_eq!(
            refused_field(job(&skeleton, &far, &targets).validate()),
            "movers.movable[1]"
        );
        let mut rebuilt = Movers::default();
        rebuilt.build(&skeleton, &[targets[0], targets[0]]);
        assert_eq!(
            refused_field(job(&skeleton, &rebuilt, &targets).validate()),
            "movers.below(0)"
        );
        rebuilt.build(&skeleton, &targets);
        assert_eq!(job(&skeleton, &rebuilt, &targets).validate(), Ok(()));
        rebuilt.chain(&[]);
        assert_eq!(job(&skeleton, &rebuilt, &[]).validate(), Ok(()));
        // The run checks the job and the buffers it is handed, and changes nothing.
        let mut pose = skeleton.rest_pose();
        let mut global = GlobalPose::new();
        skeleton
            .forward_kinematics(&pose, &mut global)
            .expect("valid");
        let (pose0, global0) = (pose.clone(), global.clone());
        let mut translation = DVec3::ZERO;
        let mut finish = Finish::default();
        let bad = FinishJob {
            damping_cap: f64::NAN,
            ..good
        };
        assert!(matches!(
            finish.run(&bad, &mut pose, &mut translation, &mut global),
            Err(SkeletonError::InvalidFinishJob { field, .. }) if field == "damping_cap"
        ));
        let mut nan = DVec3::new(0.0, f64::NAN, 0.0);
        assert!(matches!(
            finish.run(&good, &mut pose, &mut nan, &mut global),
            Err(SkeletonError::InvalidFinishJob { field, .. }) if field == "translation"
        ));
        let mut short = GlobalPose::new();
        assert!(matches!(
            finish.run(&good, &mut pose, &mut translation, &mut short),
            Err(SkeletonError::InvalidFinishJob { field, .. }) if field == "global"
        ));
        let mut short_pose = Pose {
            rotations: vec![DQuat::IDENTITY; 2],
        };
        assert!(matches!(
            finish.run(&good, &mut short_pose, &mut translation, &mut global),
            Err(SkeletonError::PoseLength {
                expected: 3,
                got: 2
            })
        ));
        assert_eq!((pose, global, translation), (pose0, global0, DVec3::ZERO));
        // And the good job runs to its goal.
        let mut pose = skeleton.rest_pose();
        let mut global = GlobalPose::new();
        skeleton
            .forward_kinematics(&pose, &mut global)
            .expect("valid");
        let done = finish
            .run(&good, &mut pose, &mut translation, &mut global)
            .expect("a valid job");
        assert_eq!(done.stop, StopReason::Converged, "{done:?}");
    }

    /// After a run the global pose is, to the bit, forward kinematics of the pose it
    /// returns moved by its translation, with or without a base (the trials' global poses
    /// are swapped with the finish's buffer, not copied, when there is none), over runs
    /// on limited joints whose trials are rejected and clamped.
    #[test]
    fn a_run_leaves_the_global_pose_of_its_answer() {
        use crate::limits::{Hinge, SwingTwist};
        let shoulder = JointLimit::SwingTwist(SwingTwist {
            twist_axis: DVec3::Y,
            a_axis: DVec3::X,
            swing_a: 0.6,
            swing_b: 0.3,
            twist_min: -0.4,
            twist_max: 0.2,
        });
        let elbow = JointLimit::Hinge(Hinge {
            axis: DVec3::Z,
            min: 0.0,
            max: 1.2,
        });
        let skeleton = Skeleton::new([
            crate::JointDef::root(DVec3::ZERO),
            crate::JointDef::child(0, DVec3::Y).with_limit(shoulder),
            crate::JointDef::child(1, DVec3::Y).with_limit(elbow),
            crate::JointDef::child(2, DVec3::Y),
            crate::JointDef::child(0, DVec3::X).with_limit(shoulder),
            crate::JointDef::child(4, DVec3::Y),
        ])
        .expect("valid");
        let mut random = uniform(7);
        let mut runs = 0;
        let mut steps = 0;
        for base in [None, Some(0)] {
            let mut finish = Finish::default();
            for _ in 0..40 {
                let mut goal = || DVec3::new(random(), random(), random()) * 2.0;
                let targets = [(3, goal()), (5, goal())].map(|(joint, position)| Target {
                    joint,
                    position,
                    rotation: None,
                    position_weight: 1.0,
                    rotation_weight: 0.0,
                    pinned: false,
                });
                let targets = if base.is_some() {
                    &targets[..1]
                } else {
                    &targets[..]
                };
                let mut movers = Movers::default();
                movers.build(&skeleton, targets);
                let job = FinishJob {
                    translates: base.is_none(),
                    base,
                    ..job(&skeleton, &movers, targets)
                };
                let mut pose = skeleton.rest_pose();
                let mut translation = DVec3::ZERO;
                let mut global = GlobalPose::new();
                skeleton
                    .forward_kinematics(&pose, &mut global)
                    .expect("valid");
                let done = finish
                    .run(&job, &mut pose, &mut translation, &mut global)
                    .expect("a valid job");
                runs += 1;
                steps += done.steps;
                let mut exact = GlobalPose::new();
                translated_forward_kinematics(&skeleton, &pose, translation, None, &mut exact)
                    .expect("valid");
                assert_eq!(global.rotations, exact.rotations, "{base:?} {done:?}");
                assert_eq!(global.positions, exact.positions, "{base:?} {done:?}");
            }
        }
        assert!(steps > 2 * runs, "{steps} steps in {runs} runs");
    }

    /// The residual left after `steps` steps of the finish on a problem whose model is
    /// exact: a lone root that only translates, its one effector on itself, so that
    /// `J = I` and a step damped by `lambda` leaves `lambda / (1 + lambda)` of the
    /// residual. The tolerance is 0, so the finish stops at the cap of `steps` (or at an
    /// exact answer).
    fn translation_residual(goal: DVec3, damping_cap: f64, steps: usize) -> f64 {
        let skeleton = Skeleton::new([crate::JointDef::root(DVec3::ZERO)]).expect("valid");
        let targets = [Target {
            joint: 0,
            position: goal,
            rotation: None,
            position_weight: 1.0,
            rotation_weight: 0.0,
            pinned: false,
        }];
        let mut movers = Movers::default();
        movers.build(&skeleton, &targets);
        assert!(movers.movable().is_empty());
        let job = FinishJob {
            settings: SolveSettings {
                max_iterations: steps,
                tolerance: 0.0,
                rotation_tolerance: 0.0,
            },
            stall_window: 0,
            damping_cap,
            ..job(&skeleton, &movers, &targets)
        };
        let mut pose = skeleton.rest_pose();
        let mut global = GlobalPose::new();
        skeleton
            .forward_kinematics(&pose, &mut global)
            .expect("valid");
        let mut translation = DVec3::ZERO;
        let done = Finish::default()
            .run(&job, &mut pose, &mut translation, &mut global)
            .expect("a valid job");
        // (Tolerance 0 is met only by an exact answer, which a nearly Gauss-Newton step
        // on this linear problem may give.)
        assert!(
            done.steps == steps || done.stop == StopReason::Converged,
            "{done:?}"
        );
        global.positions[0].distance(goal)
    }

    #[test]
    fn the_damping_cap_makes_a_later_step_nearly_gauss_newton() {
        let goal = DVec3::new(0.3, 0.4, 0.0);
        let (r0, cost0) = (goal.length(), goal.length_squared());
        // The first damping (`J J^T = I`, three rows) and the floor the division by 3 after
        // each accepted step puts under the damping of step `k` (counted from 1).
        let first = (INITIAL_DAMPING).min(COST_DAMPING * cost0);
        let floor = |k: i32| first / 3f64.powi(k - 1);
        let contraction = |lambda: f64| lambda / (1.0 + lambda);
        let rounding = 4.0 * f64::EPSILON * r0;
        let steps = 6;
        let uncapped: Vec<f64> = (0..=steps)
            .map(|k| translation_residual(goal, f64::INFINITY, k))
            .collect();
        let capped: Vec<f64> = (0..=steps)
            .map(|k| translation_residual(goal, 1.0, k))
            .collect();
        assert_eq!(uncapped[0], r0);
        // The first step is the same either way (no step accepted yet), and exact.
        assert_eq!(capped[1], uncapped[1]);
        assert!((uncapped[1] - r0 * contraction(first)).abs() <= rounding);
        // Without a cap, no step's damping falls under the division's floor (checked
        // while the residual is far above rounding).
        for k in 2..=5 {
            let ratio = uncapped[k] / uncapped[k - 1];
            assert!(
                ratio >= 0.99 * contraction(floor(k as i32)),
                "step {k}: {ratio:e}"
            );
        }
        // With the cap 1, some step after the first is damped by at most the cost it
        // starts from (`damping <= cap * cost`, cost `= r^2` here): it leaves at most that
        // fraction of the residual, far under what the division alone allows.
        let gauss_newton = (2..=steps).find(|&k| {
            let before = capped[k - 1];
            capped[k] <= before * (before * before) + rounding
                && capped[k] < 0.01 * before * contraction(floor(k as i32))
        });
        assert!(
            gauss_newton.is_some(),
            "capped {capped:?}, uncapped {uncapped:?}"
        );
    }
}
