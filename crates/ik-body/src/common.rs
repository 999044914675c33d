//! What every body solver does first and last, written once: validation, the starting
//! pose projected onto the limits, the resolved targets and topology, the early exit when
//! every effector is already within tolerance, and the report.

use crate::problem::{
    BodyProblem, BodyReport, BodyState, Target, all_within, finish_report, forward_kinematics,
    pins_hold, resolve_targets, total_cost,
};
use sinew_skeleton::finish::{Finish, FinishJob, Finished, Movers};

use crate::carry::Carried;
use crate::horn::BestRotation;
use crate::workload::Rng;
use sinew_math::{DQuat, DVec3, rotation_between, try_unit};
use sinew_skeleton::ik::{Chain, IkError, StopReason};
use sinew_skeleton::limits::JointLimit;
use sinew_skeleton::seed::limb_seed;
use sinew_skeleton::{GlobalPose, Skeleton};

/// A limb gets its closed-form pose ([`Common::seed_limbs`]) only when its effector is
/// further from its goal than this fraction of the limb's length.
const LIMB_SEED_DISTANCE: f64 = 0.25;

/// When a cold start places the body ([`Common::place_body`]), a limb whose effector is
/// further from its goal than this fraction of the limb's length is seeded too.
const PLACED_LIMB_SEED_DISTANCE: f64 = 0.1;

/// The spins of a limb's base about its base-to-goal line that [`Common::swivel_limbs`]
/// tries either side of the seeded one, and the angle between two of them: eight a side
/// cover the 45 degrees between two of the limb seed's own spins.
const SWIVEL_STEPS: usize = 8;
const SWIVEL_STEP: f64 = std::f64::consts::TAU / 64.0;

/// A finish whose cost has not fallen tenfold over this many steps ends in a local
/// minimum, so that the solver restarts (see `docs/ik-body.md`).
const STALL_WINDOW: usize = 10;

/// The finish's [`FinishJob::damping_cap`] on problems without pins.
const DAMPING_CAP: f64 = 1.0;

/// How far a warm frame's near restart ([`Common::seed_near`]) draws a joint on its bound
/// from its starting rotation towards the centre of its limit (a fraction of the way),
/// and how much further from the centre (a fraction of its angle from it) a rotation
/// turned that way must leave the limit for the joint to count as on its bound.
pub(crate) const NEAR_PULL: f64 = 0.03;
pub(crate) const NEAR_BOUND: f64 = 0.01;
/// A warm frame restarts near its start only when its crawl ended with every effector
/// within this many times the tolerances (`docs/ik-body.md`).
pub(crate) const NEAR_REACH: f64 = 10.0;
/// The most iterations a warm frame's near restart may take, so that one that crawls
/// too leaves the restarts from far some (`docs/ik-body.md`).
pub(crate) const NEAR_ITERATIONS: usize = 30;
/// A warm frame's corrected start ([`Common::predict`]) whose cost is under this fraction
/// of the given start's is kept without trying the first-order start.
const SURE_CORRECTION: f64 = 1e-3;

/// Buffers and per-solve data every body solver keeps.
#[derive(Clone, Debug, Default)]
pub(crate) struct Common {
    pub targets: Vec<Target>,
    pub topology: Movers,
    pub initial: Vec<(f64, f64)>,
    pub initial_cost: f64,
    pub dls: Finish,
    /// The buffers a solve writes before it reads them (see [`SolveScratch::swap_with`]).
    pub scratch: CommonScratch,
    /// The starting translation (the starting pose is [`CommonScratch::start`]).
    start_translation: DVec3,
    /// Per target: how far from its goal a pinned effector may end (the tolerance, or
    /// its distance at the start if that is larger).
    pin_allowed: Vec<f64>,
    /// The limbs [`Common::seed_limbs`] has built, kept from solve to solve so that a
    /// solve on the same skeleton builds (allocates) none.
    limbs: Vec<Chain>,
    /// The limbs a cold start seeds: (target, index into `limbs`).
    seedable: Vec<(usize, usize)>,
    /// The limbs seeded only when the body is placed (see [`PLACED_LIMB_SEED_DISTANCE`]).
    nearer: Vec<(usize, usize)>,
    /// The translation of the last extrapolated start's first-order part (its rotations
    /// are [`CommonScratch::first_order`]).
    pub first_order_translation: DVec3,
    /// Per joint: a rotation known to be its own projection onto the joint's limit, with
    /// no violation (`PreparedLimit::violation_and_fixed` says `(0, true)`), if any; filled
    /// by the finish's trials and by the reports, for the limits of this solve and of
    /// the solves that continue it ([`Carried`] checks the limits), so that neither the
    /// report nor a next solve that continues from the answer measures or projects such
    /// a joint again.
    fixed: Vec<Option<DQuat>>,
    /// Per joint: a rotation a start that did not continue a sequence found to be its own
    /// projection, under the same limits as `fixed` (kept apart from it, which the
    /// answers overwrite), so that cold starts from one pose (a rest pose) project it once.
    start_fixed: Vec<Option<DQuat>>,
}

/// The buffers of [`Common`] that a solve writes before it reads them, lent by a batch
/// (see [`SolveScratch::swap_with`]).
#[derive(Clone, Debug, Default)]
pub(crate) struct CommonScratch {
    /// A pose kept while one pass is tried, and the best pose kept while a restart is
    /// tried (two buffers: a restart runs passes).
    pub kept: Vec<DQuat>,
    pub best: Vec<DQuat>,
    /// The starting pose (projected onto the limits).
    pub start: Vec<DQuat>,
    /// The last extrapolated start's first-order part ([`Common::predict`]): per joint the
    /// extrapolated rotation and whether the joint took it.
    pub first_order: Vec<DQuat>,
    pub extrapolated: Vec<bool>,
    /// The global poses of the extrapolated start ([`Common::predict`]): the corrected
    /// one and the first-order one, computed here rather than in the state so that the
    /// state keeps the global pose of the pose given, and a start not kept (or the
    /// start of the two not kept) costs no forward kinematics to undo.
    pub predicted_global: GlobalPose,
    pub plain_global: GlobalPose,
    /// The debug build's check that a report's global pose is forward kinematics of its
    /// pose, in a buffer of its own so that the debug build does not allocate either.
    #[cfg(debug_assertions)]
    pub debug_global: GlobalPose,
}

/// The buffers a solve writes before it reads them, [`CommonScratch`] and the finish's,
/// which a batch of characters solved one after another lends each solver in turn.
#[derive(Clone, Debug, Default)]
pub(crate) struct SolveScratch {
    common: CommonScratch,
    finish: sinew_skeleton::finish::FinishScratch,
}

/// More cached limbs than this (many skeletons through one solver) and the cache starts
/// over.
const MAX_CACHED_LIMBS: usize = 64;

/// The outcome of [`Common::begin`].
pub(crate) enum Begin {
    /// Nothing to iterate: the report is final.
    Done(BodyReport),
    /// Iterate from the (projected) starting pose.
    Iterate,
}

impl SolveScratch {
    /// Exchanges `common`'s scratch buffers (its own and its finish's) with these.
    pub fn swap_with(&mut self, common: &mut Common) {
        std::mem::swap(&mut self.common, &mut common.scratch);
        common.dls.swap_scratch(&mut self.finish);
    }
}

impl Common {
    /// Asks the processor to bring what a warm solve reads first of these buffers into
    /// its cache (a hint): the rotations known to be their own projections, the targets
    /// and the finish's chord start.
    pub(crate) fn prefetch(&self) {
        sinew_skeleton::prefetch::prefetch(&self.fixed);
        sinew_skeleton::prefetch::prefetch(&self.targets);
        self.dls.prefetch();
    }

    /// Validates the problem and the state, projects the starting pose onto the limits,
    /// resolves the targets and the topology, and exits early when every effector is
    /// already within tolerance. With `same_problem` (the problem has the structure of
    /// this solver's last solve, which was validated: [`Carried::same_problem`]) only
    /// what may have moved is validated, the topology is the last one and is not
    /// rebuilt, and the rotations known to be their own projections under the same
    /// limits are kept. With `global_exact` (only with `continued`: the state's
    /// global pose is, to the bit, the one the last solve returned) forward kinematics is
    /// not computed again. With `continued` (also the state is, to the bit, the answer of
    /// that solve: [`Carried`]) only the movable joints are
    /// projected: the others are as the last solve left them, projected by its start or
    /// by a FABRIK pass (the finish does not turn them). (The movable ones are still
    /// projected: the last answer is inside its limits, but not always to the bit a
    /// fixed point of the projection, and skipping them changed the clip's path; see
    /// `docs/ik-body.md`.) A joint whose rotation is known to be its own projection (by
    /// a report's quick inside test, a trial's or a start's projection) is not projected:
    /// its projection would return it unchanged.
    pub fn begin(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
        same_problem: bool,
        continued: bool,
        global_exact: bool,
    ) -> Result<Begin, IkError> {
        debug_assert!(
            same_problem || !continued,
            "a continued solve has the same problem"
        );
        // A problem of the last one's structure has its skeleton, weights and settings,
        // which were validated: only what moves is checked.
        if same_problem {
            problem.validate_moving()?;
        } else {
            problem.validate()?;
        }
        let skeleton = problem.skeleton;
        if !state.root_translation.is_finite() {
            return Err(IkError::InvalidSettings(format!(
                "state: root_translation {} has a NaN or infinite component",
                state.root_translation
            )));
        }
        // Checks the pose (its length, every rotation) before anything reads it; a
        // continued state whose global pose is the one the last solve returned has both
        // checked and exact already.
        if !global_exact {
            state.update_global(skeleton)?;
        }
        let mut moved = false;
        // The rotations known to be their own projections hold for the same limits only,
        // which a problem of the last one's structure has (`Carried` compares them to the
        // bit); a continued state is the last answer, whose report found which of its
        // rotations are, and a cold start from a pose the solver has seen before (the
        // rest pose) has them from that start's projections.
        if !same_problem {
            self.fixed.clear();
            self.start_fixed.clear();
        }
        // The poses kept aside for a pass or a restart, sized now: a restart may come
        // hundreds of frames after the first solve, and a warm solve must not allocate
        // then. And the extrapolated starts' global poses (each written whole by forward
        // kinematics before it is read), the first-order one used only now and then.
        // Sized at a change of structure, and when a batch has lent buffers of another
        // size.
        let scratch = &mut self.scratch;
        if !same_problem || scratch.predicted_global.rotations.len() != skeleton.len() {
            for kept in [&mut scratch.kept, &mut scratch.best] {
                kept.clear();
                kept.reserve(skeleton.len());
            }
            scratch.predicted_global.clone_from(&state.global);
            scratch.plain_global.clone_from(&state.global);
            #[cfg(debug_assertions)]
            scratch.debug_global.clone_from(&state.global);
        }
        self.fixed.resize(skeleton.len(), None);
        if continued {
            for j in 0..skeleton.len() {
                let limit = skeleton.prepared_limit(j);
                if matches!(limit.limit(), JointLimit::Free)
                    || self.topology.slot(j).is_none()
                    || self.fixed[j] == Some(state.pose.rotations[j])
                {
                    continue;
                }
                let projected = limit.project(state.pose.rotations[j]);
                moved |= projected != state.pose.rotations[j];
                state.pose.rotations[j] = projected;
            }
        } else {
            moved = self.project_cold_start(skeleton, state);
        }
        if moved {
            state.update_global(skeleton)?;
        }
        self.scratch.start.clear();
        self.scratch.start.extend_from_slice(&state.pose.rotations);
        self.start_translation = state.root_translation;
        resolve_targets(problem, &mut self.targets);
        if !same_problem {
            self.topology.build(skeleton, &self.targets);
        }
        self.initial.clear();
        self.initial
            .extend(self.targets.iter().map(|t| t.errors(&state.global)));
        self.initial_cost = total_cost(&self.targets, &state.global);
        let tolerance = problem.settings.tolerance;
        self.pin_allowed.clear();
        self.pin_allowed
            .extend(self.initial.iter().map(|&(p, _)| p.max(tolerance)));
        if all_within(&self.targets, &state.global, &problem.settings) {
            return Ok(Begin::Done(self.report(
                problem,
                state,
                0,
                StopReason::Converged,
                false,
            )?));
        }
        Ok(Begin::Iterate)
    }

    /// Projects every limited joint of a start that does not continue a sequence onto
    /// its limit, recording the rotations that are their own projections (in `fixed`,
    /// for the report, and in `start_fixed`, which the answers do not overwrite, so that
    /// the next cold start from the same pose projects none of them again); returns
    /// whether any rotation moved. (A continued frame's report learns which of its
    /// rotations are fixed points itself; a cold start's report would otherwise measure
    /// every joint it did not turn.) Kept out of line: the warm frames' start stays as
    /// it was compiled before.
    #[inline(never)]
    fn project_cold_start(&mut self, skeleton: &Skeleton, state: &mut BodyState) -> bool {
        let mut moved = false;
        self.start_fixed.resize(skeleton.len(), None);
        for j in 0..skeleton.len() {
            let limit = skeleton.prepared_limit(j);
            let q = state.pose.rotations[j];
            if matches!(limit.limit(), JointLimit::Free) {
                continue;
            }
            if self.start_fixed[j] == Some(q) {
                self.fixed[j] = Some(q);
                continue;
            }
            if self.fixed[j] == Some(q) {
                continue;
            }
            let (projected, fixed) = limit.project_and_fixed(q);
            if fixed {
                self.fixed[j] = Some(q);
                self.start_fixed[j] = Some(q);
            }
            moved |= projected != q;
            state.pose.rotations[j] = projected;
        }
        moved
    }

    /// The damped least-squares finish over every effector from `state` (see
    /// [`sinew_skeleton::finish`]), `iterations` already spent of the cap; with
    /// `chord_start` (a warm frame continuing a sequence, see [`Carried`]) its first trial
    /// may be a chord step on the factor of the last linearization.
    pub fn finish(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
        iterations: usize,
        chord_start: bool,
    ) -> Result<Finished, IkError> {
        let pinned = self.targets.iter().any(|t| t.pinned);
        let job = FinishJob {
            skeleton: problem.skeleton,
            movers: &self.topology,
            targets: &self.targets,
            translates: problem.root_translates,
            base: None,
            settings: problem.settings,
            iterations,
            chord_start,
            // A pinned problem (the clip, a batch of characters) restarts only from poses
            // that keep its pins; it is left to converge, however slowly.
            stall_window: if pinned { 0 } else { STALL_WINDOW },
            // The damping follows the cost down only without pins: a pinned problem's
            // steps trade the pins against the other goals, and nearly Gauss-Newton steps
            // there lost warm frames of the 1 000-character batch (`docs/ik-body.md`).
            damping_cap: if pinned { f64::INFINITY } else { DAMPING_CAP },
        };
        let finished = self.dls.run(
            &job,
            &mut state.pose,
            &mut state.root_translation,
            &mut state.global,
        )?;
        // The rotations its trials found to be their own projections, for the report.
        for (&j, &q) in self
            .topology
            .movable()
            .iter()
            .zip(self.dls.fixed_rotations())
        {
            if q.is_some() {
                self.fixed[j] = q;
            }
        }
        Ok(finished)
    }

    /// The report of the pose in `state`, after forward kinematics of it from the root
    /// (incremental updates of a translated body round differently, and the global pose
    /// returned must be exactly [`forward_kinematics`] of the pose).
    pub fn report(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
        iterations: usize,
        stop: StopReason,
        restarted: bool,
    ) -> Result<BodyReport, IkError> {
        state.update_global(problem.skeleton)?;
        Ok(self.report_exact(problem, state, iterations, stop, restarted))
    }

    /// [`Common::report`] for a solver whose every step leaves `state.global` exactly
    /// [`forward_kinematics`] of the pose and translation (the finish's trials and the
    /// poses it restores, the FABRIK passes, the seeds and the extrapolated start all
    /// compute it from the root), so it is not computed again.
    pub fn report_exact(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
        iterations: usize,
        stop: StopReason,
        restarted: bool,
    ) -> BodyReport {
        #[cfg(debug_assertions)]
        {
            let check = &mut self.scratch.debug_global;
            let _ = crate::problem::forward_kinematics(
                problem.skeleton,
                &state.pose,
                state.root_translation,
                check,
            );
            debug_assert!(
                check.rotations == state.global.rotations
                    && check.positions == state.global.positions,
                "the global pose is not forward kinematics of the pose"
            );
        }
        finish_report(
            problem,
            &self.targets,
            state,
            &mut self.fixed,
            &self.initial,
            self.initial_cost,
            iterations,
            stop,
            restarted,
        )
    }

    /// Whether every pinned effector is within the tolerance of its goal at `state`, or
    /// no further than it started.
    pub fn pins_hold(&self, problem: &BodyProblem<'_>, state: &BodyState) -> bool {
        pins_hold(
            &self.targets,
            &state.global,
            problem.settings.tolerance,
            &self.pin_allowed,
        )
    }

    /// Keeps `state`'s pose aside (see [`Common::restore`]).
    pub fn keep(&mut self, state: &BodyState) -> DVec3 {
        self.scratch.kept.clear();
        self.scratch.kept.extend_from_slice(&state.pose.rotations);
        state.root_translation
    }

    /// Keeps `state`'s pose aside as the best so far (see [`Common::restore_best`]).
    pub fn keep_best(&mut self, state: &BodyState) -> DVec3 {
        self.scratch.best.clear();
        self.scratch.best.extend_from_slice(&state.pose.rotations);
        state.root_translation
    }

    /// Puts the best pose back and recomputes forward kinematics.
    pub fn restore_best(
        &self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
        translation: DVec3,
    ) -> Result<(), IkError> {
        put_back(&self.scratch.best, problem, state, translation)
    }

    /// Puts the kept pose back and recomputes forward kinematics.
    pub fn restore(
        &self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
        translation: DVec3,
    ) -> Result<(), IkError> {
        put_back(&self.scratch.kept, problem, state, translation)
    }

    /// The seed of restart number `k >= 1` after a local minimum, from the starting pose:
    /// for `k = 1` every movable joint with a limit at the limit's centre, after that at a
    /// rotation drawn inside its limit (from a fixed sequence, so solves are
    /// reproducible); free joints keep their starting rotation, the body its starting
    /// translation. `k = 0` is the starting pose itself.
    pub fn seed(
        &self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
        k: usize,
    ) -> Result<(), IkError> {
        state.pose.rotations.copy_from_slice(&self.scratch.start);
        state.root_translation = self.start_translation;
        let mut rng = Rng::new(0x5EED_0000 + k as u64);
        for &j in self.topology.movable() {
            let limit = problem.skeleton.limit(j);
            if k == 0 || matches!(limit, JointLimit::Free) {
                continue;
            }
            state.pose.rotations[j] = if k == 1 {
                limit.centre().unwrap_or(DQuat::IDENTITY)
            } else {
                limit.sample([rng.uniform(), rng.uniform(), rng.uniform()])
            };
        }
        state.update_global(problem.skeleton)?;
        Ok(())
    }

    /// Whether every effector is within [`NEAR_REACH`] times the tolerances of its goal at
    /// `state` (a rotation goal with weight 0 does not count): a local minimum that close
    /// is a crawl short of the goals, which a restart near the start may finish.
    pub fn ended_near(&self, problem: &BodyProblem<'_>, state: &BodyState) -> bool {
        let settings = &problem.settings;
        self.targets.iter().all(|t| {
            let (p, r) = t.errors(&state.global);
            p <= NEAR_REACH * settings.tolerance
                && (!t.has_rotation() || r <= NEAR_REACH * settings.rotation_tolerance)
        })
    }

    /// The seed of a warm frame's near restart: the starting pose (the last frame's
    /// answer, projected) with every movable joint that is on a bound of its limit (turned
    /// [`NEAR_BOUND`] of its angle further from the limit's centre, it leaves the limit)
    /// drawn [`NEAR_PULL`] of the way towards that centre (spherical interpolation, then
    /// projected onto the limit); the other joints and the body's translation as they
    /// started. A finish that crawled into a local minimum along curved bounds starts
    /// again just off those bounds, near where the frame started, so that its answer stays
    /// near the last frame's instead of jumping to wherever a restart from the centre of
    /// the limits lands. Deterministic: the same starting pose gives the same seed.
    pub fn seed_near(
        &self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
    ) -> Result<(), IkError> {
        state.pose.rotations.copy_from_slice(&self.scratch.start);
        state.root_translation = self.start_translation;
        for &j in self.topology.movable() {
            let limit = problem.skeleton.prepared_limit(j);
            let Some(centre) = limit.limit().centre() else {
                continue;
            };
            let q = state.pose.rotations[j];
            // On its bound: turned a little further away from the centre, it leaves the
            // limit. A joint inside keeps its rotation, so the seed moves only what the
            // crawl is stuck on.
            let mut away = q * centre.conjugate();
            if away.w < 0.0 {
                away = -away;
            }
            let further =
                (DQuat::from_scaled_axis(away.to_scaled_axis() * NEAR_BOUND) * q).normalize();
            if limit.violation(further) == 0.0 {
                continue;
            }
            state.pose.rotations[j] = limit.project(q.slerp(centre, NEAR_PULL).normalize());
        }
        state.update_global(problem.skeleton)?;
        Ok(())
    }

    /// A cold start's closed-form limb poses: each position-only effector with a limb
    /// above it (a hinge whose parent has three degrees of freedom, `sinew_skeleton::seed`)
    /// that moves no other effector, and that is further from its goal than a quarter of
    /// the limb's length, gets the limb's closed-form pose for its goal from where the
    /// limb's base now is. When some limb is that far and no effector is pinned, the body
    /// is first placed as a whole ([`Common::place_body`]), so that the limbs are seeded
    /// from where their bases will roughly be. A warm frame, whose effectors are near
    /// their goals, keeps its pose (and the continuity of the swivel about the
    /// base-to-goal line). The seeded pose is kept only when it lowers the cost and keeps
    /// the pins; returns whether it was kept.
    pub fn seed_limbs(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
    ) -> Result<bool, IkError> {
        let skeleton = problem.skeleton;
        let before = self.cost(state);
        self.scratch.kept.clear();
        self.scratch.kept.extend_from_slice(&state.pose.rotations);
        let kept_translation = state.root_translation;
        self.seedable.clear();
        self.nearer.clear();
        for (e, t) in self.targets.iter().enumerate() {
            if t.rotation.is_some() {
                continue;
            }
            // The nearest hinge above the effector whose parent turns freely or within a
            // swing-twist limit.
            let mut limb = None;
            let mut j = t.joint;
            while let Some(p) = skeleton.parent(j) {
                if matches!(skeleton.limit(p), JointLimit::Hinge(_))
                    && let Some(base) = skeleton.parent(p)
                    && matches!(
                        skeleton.limit(base),
                        JointLimit::SwingTwist(_) | JointLimit::Free
                    )
                {
                    limb = Some(base);
                    break;
                }
                j = p;
            }
            let Some(base) = limb else {
                continue;
            };
            let Some(slot) = self.topology.slot(base) else {
                continue;
            };
            if self.topology.below(slot).len() != 1 {
                continue;
            }
            let cached = self.limbs.iter().position(|c| {
                c.base() == base && c.effector() == t.joint && c.check_skeleton(skeleton).is_ok()
            });
            let k = match cached {
                Some(k) => k,
                None => {
                    let Ok(chain) = Chain::new(skeleton, base, t.joint) else {
                        continue;
                    };
                    if self.limbs.len() >= MAX_CACHED_LIMBS {
                        // Entries found earlier in this loop index into the cache.
                        self.limbs.clear();
                        self.seedable.clear();
                    }
                    self.limbs.push(chain);
                    self.limbs.len() - 1
                }
            };
            let distance = state.global.positions[t.joint].distance(t.position);
            if distance > LIMB_SEED_DISTANCE * self.limbs[k].reach() {
                self.seedable.push((e, k));
            } else if distance > PLACED_LIMB_SEED_DISTANCE * self.limbs[k].reach() {
                self.nearer.push((e, k));
            }
        }
        if self.seedable.is_empty() {
            return Ok(false);
        }
        let mut moved = false;
        if !self.targets.iter().any(|t| t.pinned) {
            // The placement moves every limb's base: one nearer its goal than the warm
            // frames' gate is seeded too, rather than left to the finish.
            self.seedable.extend_from_slice(&self.nearer);
            moved = self.place_body(problem, state)?;
        }
        for &(e, k) in &self.seedable {
            let t = &self.targets[e];
            let chain = &self.limbs[k];
            let base = chain.base();
            let base_parent = skeleton
                .parent(base)
                .map_or(DQuat::IDENTITY, |p| state.global.rotations[p]);
            moved |= limb_seed(
                skeleton,
                chain,
                &mut state.pose,
                state.global.positions[base],
                base_parent,
                t.position,
            );
        }
        if !moved {
            return Ok(false);
        }
        state.update_global(skeleton)?;
        if self.swivel_limbs(problem, state) {
            state.update_global(skeleton)?;
        }
        if self.cost(state) < before && self.pins_hold(problem, state) {
            return Ok(true);
        }
        state.pose.rotations.copy_from_slice(&self.scratch.kept);
        state.root_translation = kept_translation;
        state.update_global(skeleton)?;
        Ok(false)
    }

    /// After the limb seeds: a seeded limb whose hinge reaches its goal's distance but
    /// whose effector misses it was turned off its goal by the projection of its base
    /// joint, when none of the seed's eight spins about the base-to-goal line is inside
    /// the base's limit. Those spins are 45 degrees apart; the spins inside a shoulder's
    /// or a hip's limit often form a narrower arc between two of them. So the base is
    /// tried at finer spins either side of the one nearest its seeded rotation (the
    /// tip kept on the goal), nearest first, and takes the first that its limit keeps as
    /// it is ([`PreparedLimit::keeps`](sinew_skeleton::limits::PreparedLimit::keeps): its
    /// projection returns it unchanged). Returns whether a base moved; `state.global` is
    /// then stale.
    fn swivel_limbs(&self, problem: &BodyProblem<'_>, state: &mut BodyState) -> bool {
        let skeleton = problem.skeleton;
        let tolerance = problem.settings.tolerance;
        let mut moved = false;
        // The half-angle of one spin step, for the rotation of (cos, sin) pairs below.
        let (step_sin, step_cos) = (0.5 * SWIVEL_STEP).sin_cos();
        for &(e, k) in &self.seedable {
            let t = &self.targets[e];
            let base = self.limbs[k].base();
            let at = state.global.positions[t.joint];
            if at.distance(t.position) <= tolerance {
                continue;
            }
            let base_at = state.global.positions[base];
            let parent = skeleton
                .parent(base)
                .map_or(DQuat::IDENTITY, |p| state.global.rotations[p]);
            // The tip in the base's own frame and the goal in its parent's: the base's
            // rotation takes one onto the other exactly when the tip is on the goal.
            let tip = state.global.rotations[base].conjugate() * (at - base_at);
            let goal = parent.conjugate() * (t.position - base_at);
            if (tip.length() - goal.length()).abs() > tolerance {
                // The hinge could not reach the goal's distance: no spin can help.
                continue;
            }
            let Some(axis) = try_unit(goal) else {
                continue;
            };
            // Every rotation taking the tip onto the goal: `cos(h) aim + sin(h) side`,
            // the shortest one turned by `2 h` about the goal's direction.
            let aim = rotation_between(tip, goal);
            let side = DQuat::from_xyzw(axis.x, axis.y, axis.z, 0.0) * aim;
            let current = state.pose.rotations[base];
            // The member nearest the seeded rotation: `h` maximising its dot product.
            let (c0, s0) = {
                let h = side.dot(current).atan2(aim.dot(current));
                let (s, c) = h.sin_cos();
                (c, s)
            };
            let candidate = |c: f64, s: f64| (aim * c + side * s).normalize();
            let limit = skeleton.prepared_limit(base);
            let mut found = None;
            let (mut up, mut down) = ((c0, s0), (c0, s0));
            if limit.keeps(candidate(c0, s0)) {
                found = Some(candidate(c0, s0));
            }
            for _ in 0..SWIVEL_STEPS {
                if found.is_some() {
                    break;
                }
                up = (
                    up.0 * step_cos - up.1 * step_sin,
                    up.1 * step_cos + up.0 * step_sin,
                );
                down = (
                    down.0 * step_cos + down.1 * step_sin,
                    down.1 * step_cos - down.0 * step_sin,
                );
                for (c, s) in [up, down] {
                    let q = candidate(c, s);
                    if limit.keeps(q) {
                        found = Some(q);
                        break;
                    }
                }
            }
            if let Some(q) = found {
                state.pose.rotations[base] = q;
                moved = true;
            }
        }
        moved
    }

    /// Places the body as a whole before its limbs are seeded: a rigid motion fitted to
    /// the effectors' positions and goals (the weights squared as in the cost), first of
    /// all for the effectors no limb seed will serve. With a free root that may
    /// translate, the translation brings the weighted centroid of those effectors (of
    /// every effector when each is served by a limb seed) onto that of their goals, and
    /// the rotation, taken about the root, is the best fit of every effector's position
    /// about that centroid onto its goal about the goals' (Horn's closed form,
    /// [`BestRotation`](crate::BestRotation)); without the translation, the best rotation
    /// about the root; with a root that is not free, the translation alone. A seeded limb
    /// reaches its goal from wherever its base lands, the head only moves with the body:
    /// on a cold start from the rest pose the head is then on its goal and the limbs'
    /// bases roughly where the goals put them, so the finish starts much nearer (measured
    /// in `docs/ik-body.md`). `state.global` is forward kinematics of the result; returns
    /// whether anything moved.
    fn place_body(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
    ) -> Result<bool, IkError> {
        let skeleton = problem.skeleton;
        let root = 0;
        let turns = skeleton.parent(root).is_none()
            && matches!(skeleton.limit(root), JointLimit::Free)
            && self.topology.slot(root).is_some();
        if !turns && !problem.root_translates {
            return Ok(false);
        }
        // The effectors the root moves are every effector below it; an effector on the
        // root itself turns with it about its own position, which changes nothing.
        // The centroids the translation matches: those of the effectors no limb seed
        // will serve (the head, a limb near its goal, an effector with a rotation goal)
        // when there are any, else those of every effector. A seeded limb reaches its
        // goal from wherever its base lands, the others only move with the body, so the
        // body is placed for them first (the limbs still weigh in the rotation).
        let mut weight = 0.0;
        let mut centre = DVec3::ZERO;
        let mut goal_centre = DVec3::ZERO;
        let mut fixed_weight = 0.0;
        let mut fixed_centre = DVec3::ZERO;
        let mut fixed_goal_centre = DVec3::ZERO;
        for (e, t) in self.targets.iter().enumerate() {
            let w = t.position_weight * t.position_weight;
            let (at, goal) = (state.global.positions[t.joint] * w, t.position * w);
            weight += w;
            centre += at;
            goal_centre += goal;
            if !self.seedable.iter().any(|&(s, _)| s == e) {
                fixed_weight += w;
                fixed_centre += at;
                fixed_goal_centre += goal;
            }
        }
        if fixed_weight > 0.0 {
            (weight, centre, goal_centre) = (fixed_weight, fixed_centre, fixed_goal_centre);
        }
        if weight <= 0.0 {
            return Ok(false);
        }
        centre /= weight;
        goal_centre /= weight;
        let at = state.global.positions[root];
        let (from, to) = if problem.root_translates {
            (centre, goal_centre)
        } else {
            (at, at)
        };
        let mut turn = DQuat::IDENTITY;
        if turns {
            let mut best = BestRotation::new();
            for t in &self.targets {
                best.add(
                    state.global.positions[t.joint] - from,
                    t.position - to,
                    t.position_weight * t.position_weight,
                );
            }
            turn = best.rotation();
        }
        let shift = if problem.root_translates {
            // The root turns about its own position: the centroid goes to
            // `at + turn (centre - at)`, and the translation takes it to the goals'.
            goal_centre - (at + turn * (centre - at))
        } else {
            DVec3::ZERO
        };
        if turn == DQuat::IDENTITY && shift == DVec3::ZERO {
            return Ok(false);
        }
        state.pose.rotations[root] = (turn * state.pose.rotations[root]).normalize();
        state.root_translation += shift;
        state.update_global(skeleton)?;
        Ok(true)
    }

    /// The start of a warm frame that continues a sequence ([`Carried`]), extrapolated
    /// from the last two answers: every movable joint turned once more by its turn
    /// between them (`d = q1 q0^-1`, then `d q1`) and the translation moved once more by
    /// its step. When the last answer came from such a start, the correction that took
    /// that start to the answer (`Carried::correction`) is composed on too, so that the
    /// start is off by the motion's third difference instead of its second; a corrected
    /// start that is not clearly better than the given pose is compared with the
    /// first-order one and the better kept. A joint whose start would leave its limit
    /// keeps its rotation. Kept only when it lowers the cost; returns whether it was
    /// kept. Called right after [`Common::begin`], on the state it left. `first_order`,
    /// `extrapolated` and `first_order_translation` say what the first-order start was,
    /// for the next frame's correction.
    pub fn predict(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
        carried: &Carried,
    ) -> Result<bool, IkError> {
        let skeleton = problem.skeleton;
        // The state is still the one `begin` measured.
        let before = self.initial_cost;
        self.scratch.kept.clear();
        self.scratch.kept.extend_from_slice(&state.pose.rotations);
        let kept_translation = state.root_translation;
        let joints = state.pose.rotations.len();
        let corrected = carried.has_correction && carried.correction.len() == joints;
        self.scratch.first_order.clear();
        self.scratch.first_order.resize(joints, DQuat::IDENTITY);
        self.scratch.extrapolated.clear();
        self.scratch.extrapolated.resize(joints, false);
        let mut moved = false;
        for &j in self.topology.movable() {
            let (now, then) = (carried.last[j], carried.before[j]);
            if now == then {
                continue;
            }
            let mut d = now * then.conjugate();
            if d.w < 0.0 {
                d = -d;
            }
            let first = (d * now).normalize();
            // The last frame's answer ended off its own extrapolation by the second
            // difference of the motion; the next one will too, nearly.
            let next = if corrected {
                (carried.correction[j] * first).normalize()
            } else {
                first
            };
            let limit = skeleton.prepared_limit(j);
            // A joint whose extrapolation leaves its limit keeps its rotation: projected,
            // it would start the frame on a bound it did not reach by itself. (The inside
            // test of the projection, without the projection: a rotation outside is not
            // clamped only to be dropped.)
            if matches!(limit.limit(), JointLimit::Free) || limit.keeps(next) {
                state.pose.rotations[j] = next;
                self.scratch.first_order[j] = first;
                self.scratch.extrapolated[j] = true;
                moved = true;
            }
        }
        if problem.root_translates {
            let step = carried.last_translation - carried.before_translation;
            moved |= step != DVec3::ZERO;
            state.root_translation += step;
            self.first_order_translation = state.root_translation;
            if corrected {
                moved |= carried.correction_translation != DVec3::ZERO;
                state.root_translation += carried.correction_translation;
            }
        } else {
            self.first_order_translation = state.root_translation;
        }
        // The state's global pose stays that of the pose given (exact forward kinematics
        // of it, which `begin` measured) until a start is kept: a start not kept then
        // only restores the local rotations and the translation.
        if !moved {
            return Ok(false);
        }
        forward_kinematics(
            skeleton,
            &state.pose,
            state.root_translation,
            &mut self.scratch.predicted_global,
        )?;
        let mut cost = total_cost(&self.targets, &self.scratch.predicted_global);
        // The corrected start is nearly always far better than the first-order one (its
        // error is the motion's third difference instead of its second); where it is
        // not clearly so (after the motion or the active set changed, the correction is
        // stale for a frame or two), the first-order start is tried too and the better
        // one kept (measured in `docs/ik-body.md`).
        if corrected && cost >= SURE_CORRECTION * before {
            let corrected_translation = state.root_translation;
            self.swap_first_order(state);
            forward_kinematics(
                skeleton,
                &state.pose,
                self.first_order_translation,
                &mut self.scratch.plain_global,
            )?;
            let plain = total_cost(&self.targets, &self.scratch.plain_global);
            if plain <= cost {
                // Kept; `first_order` now holds the corrected rotations, which the
                // answer's correction must not be measured from.
                for &j in self.topology.movable() {
                    if self.scratch.extrapolated[j] {
                        self.scratch.first_order[j] = state.pose.rotations[j];
                    }
                }
                state.root_translation = self.first_order_translation;
                std::mem::swap(
                    &mut self.scratch.predicted_global,
                    &mut self.scratch.plain_global,
                );
                cost = plain;
            } else {
                self.swap_first_order(state);
                state.root_translation = corrected_translation;
            }
        }
        if cost < before {
            std::mem::swap(&mut state.global, &mut self.scratch.predicted_global);
            return Ok(true);
        }
        state.pose.rotations.copy_from_slice(&self.scratch.kept);
        state.root_translation = kept_translation;
        Ok(false)
    }

    /// Swaps the extrapolated joints' rotations in `state` with `first_order`.
    fn swap_first_order(&mut self, state: &mut BodyState) {
        for &j in self.topology.movable() {
            if self.scratch.extrapolated[j] {
                std::mem::swap(
                    &mut state.pose.rotations[j],
                    &mut self.scratch.first_order[j],
                );
            }
        }
    }

    /// The weighted cost at `state`.
    pub fn cost(&self, state: &BodyState) -> f64 {
        total_cost(&self.targets, &state.global)
    }
}

/// Puts `rotations` and `translation` back as `state`'s pose (one kept by
/// [`Common::keep`] or [`Common::keep_best`]) and recomputes forward kinematics.
fn put_back(
    rotations: &[DQuat],
    problem: &BodyProblem<'_>,
    state: &mut BodyState,
    translation: DVec3,
) -> Result<(), IkError> {
    state.pose.rotations.copy_from_slice(rotations);
    state.root_translation = translation;
    state.update_global(problem.skeleton)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::workload;
    use sinew_skeleton::ik::{SolveSettings, rotation_angle};

    /// A cold start of `problem` from the rest pose, begun and limb-seeded as a solve
    /// does: `None` when no limb was seeded.
    fn seeded_from_rest(problem: &BodyProblem<'_>) -> Option<(Common, BodyState)> {
        let mut state = BodyState::rest(problem.skeleton);
        let mut common = Common::default();
        assert!(matches!(
            common.begin(problem, &mut state, false, false, false),
            Ok(Begin::Iterate)
        ));
        common
            .seed_limbs(problem, &mut state)
            .expect("valid")
            .then_some((common, state))
    }

    /// A cold start places the body for the effector no limb serves (the head) and seeds
    /// the limbs from there: on goals made from poses with the spine and clavicles at
    /// rest (the hips turned and moved, the limbs drawn inside their limits), the head
    /// lands on its goal to rounding (with a limb near its goal, unseeded, the centroid of
    /// the two) and the spine is left at rest.
    #[test]
    fn a_cold_start_places_the_body_for_the_effectors_no_limb_serves() {
        let skeleton = workload::humanoid().expect("valid");
        let settings = SolveSettings::default();
        let spine_and_clavicles = [1, 2, 3, 4, 5, 6, 10];
        let mut rng = Rng::new(0x00B0_D1E5);
        let (mut seeded, mut all_limbs) = (0, 0);
        for _ in 0..20 {
            let mut pose = workload::random_pose(&skeleton, &mut rng, 0.5);
            for j in spine_and_clavicles {
                pose.rotations[j] = DQuat::IDENTITY;
            }
            let mut goal = BodyState::rest(&skeleton);
            goal.pose = pose;
            goal.root_translation = rng.in_ball(0.3);
            goal.update_global(&skeleton).expect("valid");
            let effectors: Vec<_> = workload::EFFECTORS
                .iter()
                .map(|&j| {
                    crate::BodyEffector::new(sinew_skeleton::ik::EffectorGoal::at(
                        j,
                        goal.global.positions[j],
                    ))
                })
                .collect();
            let problem =
                BodyProblem::new(&skeleton, &effectors, settings).with_root_translation(true);
            let Some((common, state)) = seeded_from_rest(&problem) else {
                continue;
            };
            seeded += 1;
            // The effectors no limb seed served (the head, and any limb that started near
            // its goal): their centroid is on their goals' (all weights are 1 here).
            let (mut at, mut goal, mut count) = (DVec3::ZERO, DVec3::ZERO, 0.0);
            for (e, t) in common.targets.iter().enumerate() {
                if !common.seedable.iter().any(|&(s, _)| s == e) {
                    at += state.global.positions[t.joint];
                    goal += t.position;
                    count += 1.0;
                }
            }
            assert!(count >= 1.0);
            let error = at.distance(goal) / count;
            assert!(error <= 1e-12, "centroid {error}");
            if common.seedable.len() == 4 {
                let head = common.targets[4].errors(&state.global).0;
                assert!(head <= 1e-12, "head {head}");
                all_limbs += 1;
            }
            for j in spine_and_clavicles {
                assert_eq!(state.pose.rotations[j], DQuat::IDENTITY, "joint {j}");
            }
        }
        assert!(
            seeded >= 15 && all_limbs >= 5,
            "{seeded} of 20 seeded, {all_limbs} with every limb"
        );
    }

    /// A seeded limb spun about its base-to-goal line out of its base's limit and then
    /// projected onto it (the seed's failure: the tip, at the goal's distance, is moved
    /// off the goal) is swiveled back onto its goal with its base inside the limit, and
    /// only its base turned; with the hinge bent as well (the tip no longer at the goal's
    /// distance) nothing is turned.
    #[test]
    fn a_limb_projected_off_its_goal_is_swiveled_back_onto_it() {
        let skeleton = workload::humanoid().expect("valid");
        let settings = SolveSettings::default();
        let (mut tried, mut swiveled) = (0, 0);
        for goals in &workload::goal_sets(&skeleton, 40, 11, false) {
            let problem =
                BodyProblem::new(&skeleton, &goals.effectors, settings).with_root_translation(true);
            let Some((common, state)) = seeded_from_rest(&problem) else {
                continue;
            };
            let seeded = state.clone();
            for (e, k) in common.seedable.clone() {
                let t = common.targets[e];
                let base = common.limbs[k].base();
                let hinge = common.limbs[k].joints()[1];
                let limit = skeleton.prepared_limit(base);
                if seeded.global.positions[t.joint].distance(t.position) > 1e-9 {
                    continue;
                }
                for angle in [0.4, -0.6, 1.0, -1.5, 2.5] {
                    let mut state = seeded.clone();
                    let parent = skeleton
                        .parent(base)
                        .map_or(DQuat::IDENTITY, |p| state.global.rotations[p]);
                    let line = parent.conjugate() * (t.position - state.global.positions[base]);
                    let spin = DQuat::from_axis_angle(line.normalize(), angle);
                    let spun = (spin * state.pose.rotations[base]).normalize();
                    state.pose.rotations[base] = limit.project(spun);
                    state.update_global(&skeleton).expect("valid");
                    if state.global.positions[t.joint].distance(t.position) <= 1e-6 {
                        // Still inside the limit (or nearly): nothing to swivel.
                        continue;
                    }
                    tried += 1;
                    let projected = state.clone();
                    if !common.swivel_limbs(&problem, &mut state) {
                        continue;
                    }
                    swiveled += 1;
                    state.update_global(&skeleton).expect("valid");
                    let error = state.global.positions[t.joint].distance(t.position);
                    assert!(error <= 1e-9, "limb {k} at {angle}: {error}");
                    assert_eq!(limit.violation(state.pose.rotations[base]), 0.0);
                    for j in (0..skeleton.len()).filter(|&j| j != base) {
                        assert_eq!(state.pose.rotations[j], projected.pose.rotations[j]);
                    }
                    // The hinge bent too: the tip is off the goal's distance, no spin of
                    // the base reaches the goal, and nothing turns.
                    let JointLimit::Hinge(h) = skeleton.limit(hinge) else {
                        unreachable!("a limb's second joint is a hinge");
                    };
                    let mut bent = projected.clone();
                    bent.pose.rotations[hinge] = (bent.pose.rotations[hinge]
                        * DQuat::from_axis_angle(h.axis, 0.05))
                    .normalize();
                    bent.update_global(&skeleton).expect("valid");
                    let before = bent.clone();
                    assert!(!common.swivel_limbs(&problem, &mut bent));
                    assert_eq!(bent.pose, before.pose);
                }
            }
        }
        assert!(
            tried >= 20 && swiveled * 2 >= tried,
            "{swiveled} of {tried} swiveled"
        );
    }

    #[test]
    fn the_near_seed_draws_only_the_joints_on_their_bounds_a_little_inwards() {
        let skeleton = workload::humanoid().expect("valid");
        let goals = &workload::goal_sets(&skeleton, 1, 3, false)[0];
        let settings = SolveSettings::default();
        let problem =
            BodyProblem::new(&skeleton, &goals.effectors, settings).with_root_translation(true);
        // A pose drawn inside the limits (every joint off its limit's centre), with the
        // elbows and knees put at the straight end of their hinges (on a bound).
        let (elbows, knees) = ([8, 12], [15, 19]);
        let mut state = BodyState::rest(&skeleton);
        state.pose.rotations.copy_from_slice(&goals.pose.rotations);
        for j in elbows.into_iter().chain(knees) {
            state.pose.rotations[j] = DQuat::IDENTITY;
        }
        let mut common = Common::default();
        assert!(matches!(
            common.begin(&problem, &mut state, false, false, false),
            Ok(Begin::Iterate)
        ));
        let start = state.pose.clone();
        common.seed_near(&problem, &mut state).expect("valid");
        let seeded = state.clone();
        let mut moved = Vec::new();
        for &j in common.topology.movable() {
            let limit = skeleton.limit(j);
            let (q0, q) = (start.rotations[j], seeded.pose.rotations[j]);
            assert!(limit.violation(q) <= 1e-12, "joint {j} leaves its limit");
            let Some(centre) = limit.centre() else {
                assert_eq!(q, q0, "joint {j} is free and keeps its rotation");
                continue;
            };
            if q == q0 {
                continue;
            }
            moved.push(j);
            // Drawn towards the centre by the pull, along the arc between them.
            let (step, whole) = (rotation_angle(q0, q), rotation_angle(q0, centre));
            assert!(
                (step - NEAR_PULL * whole).abs() <= 1e-9,
                "joint {j}: {step} of {whole}"
            );
            assert!(rotation_angle(q, centre) < whole, "joint {j}");
        }
        // Exactly the joints put on their bounds moved (the drawn ones are inside).
        let mut on_bound: Vec<usize> = elbows.into_iter().chain(knees).collect();
        on_bound.sort_unstable();
        assert_eq!(moved, on_bound);
        assert_eq!(seeded.root_translation, state.root_translation);
        // The same start gives the same seed, to the bit.
        common.seed_near(&problem, &mut state).expect("valid");
        assert_eq!(state, seeded);
    }
}
