//! The `Ik` task: a chain tracks a target (a point, a list of points, or a sampled
//! curve) with CCD or FABRIK, each frame warm-started from the previous one, through the
//! shared tracker (`sinew_skeleton::track`). Covers the lab's W1 flower, Q1 (a target out
//! of reach), Q2 (a low iteration cap) and Q3 (a per-frame rotation limit).

use super::{RunContext, TaskOutput, TaskSpec, median, non_negative};
use crate::limits::check_solve_work;
use crate::results::{IkFrame, IkMetrics, IkPictures, Pictures, TaskMetrics};
use crate::spec::{SkeletonSpec, build_sampled};
use serde::Deserialize;
use sinew_curves::{CurveSpec, Sampling};
use sinew_ik::SolverOptions;
use sinew_math::{DQuat, DVec3, angle_between};
use sinew_skeleton::ik::{Chain, EffectorGoal, IkSolver, IkState, SolveSettings, StopReason};
use sinew_skeleton::track::{TrackSettings, Tracker};
use sinew_skeleton::{GlobalPose, Skeleton};
use std::time::Instant;

/// Scene fields of an `Ik` task.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IkTask {
    /// Unique name in the scene.
    pub name: String,
    /// The skeleton.
    pub skeleton: SkeletonSpec,
    /// The chain inside it (default: joint 0 to the last joint).
    #[serde(default)]
    pub chain: Option<ChainSpec>,
    /// The solver and its options, from the library's registry: `Ccd(...)` or
    /// `Fabrik(...)`.
    pub solver: SolverOptions,
    /// Iteration cap and tolerance (default 100 and 1e-6).
    #[serde(default)]
    pub settings: SolveSettings,
    /// The lab's Q3: the largest local rotation change of any joint between frames, in
    /// radians; a frame that jumps more is clamped to it (default: no limit).
    #[serde(default)]
    pub max_rotation_change: Option<f64>,
    /// What to track.
    pub target: TargetSpec,
    /// Fail the task if the largest final error of a frame exceeds this.
    #[serde(default)]
    pub expect_error_max: Option<f64>,
}

/// The chain's ends.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChainSpec {
    /// The base joint (its position does not move).
    pub base: usize,
    /// The effector joint.
    pub effector: usize,
}

/// One frame's goal beyond a position: what `Goals` lists.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GoalSpec {
    /// Where the effector should be.
    pub position: DVec3,
    /// The effector's goal rotation, a quaternion `(x, y, z, w)` (default: none).
    #[serde(default)]
    pub rotation: Option<DQuat>,
    /// A point the chain's bend plane should turn towards (default: none).
    #[serde(default)]
    pub pole: Option<DVec3>,
}

/// The targets, one per frame.
#[derive(Debug, Deserialize)]
pub enum TargetSpec {
    /// Full goals (position, optional rotation and pole), one per frame.
    Goals(Vec<GoalSpec>),
    /// One target, one frame.
    Point(DVec3),
    /// A list of targets, one per frame.
    Points(Vec<DVec3>),
    /// Points on a curve, one per frame.
    Curve {
        /// The curve.
        curve: CurveSpec,
        /// How to take the points.
        sampling: Sampling,
    },
}

impl TargetSpec {
    /// The goals of the frames: positions with any rotation and pole.
    fn goals(&self, effector: usize) -> Result<Vec<EffectorGoal>, String> {
        if let Self::Goals(goals) = self {
            if goals.is_empty() {
                return Err("target: no goals".into());
            }
            return goals
                .iter()
                .enumerate()
                .map(|(k, g)| {
                    let goal = EffectorGoal {
                        rotation: g.rotation,
                        pole: g.pole,
                        ..EffectorGoal::at(effector, g.position)
                    };
                    goal.validate(k, &dummy_skeleton(effector))
                        .map_err(|e| format!("target: {e}"))?;
                    Ok(goal)
                })
                .collect();
        }
        Ok(self
            .points()?
            .into_iter()
            .map(|p| EffectorGoal::at(effector, p))
            .collect())
    }

    fn points(&self) -> Result<Vec<DVec3>, String> {
        let points = match self {
            Self::Goals(goals) => goals.iter().map(|g| g.position).collect(),
            Self::Point(p) => vec![*p],
            Self::Points(ps) => ps.clone(),
            Self::Curve { curve, sampling } => {
                let curve = build_sampled(curve, sampling).map_err(|e| format!("target: {e}"))?;
                curve
                    .sample(sampling)
                    .map_err(|e| format!("target: sampling: {e}"))?
                    .points
            }
        };
        if points.is_empty() {
            return Err("target: no points".into());
        }
        if let Some(k) = points.iter().position(|p| !p.is_finite()) {
            return Err(format!("target: point {k} ({}) is not finite", points[k]));
        }
        Ok(points)
    }
}

/// A skeleton with `effector + 1` joints, only so a goal's fields can be checked before
/// the task's own skeleton is at hand (the joint index is checked against the chain).
fn dummy_skeleton(effector: usize) -> Skeleton {
    Skeleton::chain(DVec3::ZERO, &vec![DVec3::X; effector]).expect("a plain chain")
}

/// Everything an `Ik` task runs with, built from its fields.
struct Built {
    skeleton: Skeleton,
    chain: Chain,
    solver: Box<dyn IkSolver>,
    tracker: Tracker,
    goals: Vec<EffectorGoal>,
}

impl IkTask {
    fn build(&self) -> Result<Built, String> {
        let skeleton = self.skeleton.build()?;
        let chain = match &self.chain {
            None => Chain::whole(&skeleton),
            Some(c) => Chain::new(&skeleton, c.base, c.effector),
        }
        .map_err(|e| format!("chain: {e}"))?;
        let solver = self.solver.build().map_err(|e| format!("solver: {e}"))?;
        let tracker = Tracker::new(TrackSettings {
            solve: self.settings,
            max_rotation_change: self.max_rotation_change,
        })
        .map_err(|e| format!("settings: {e}"))?;
        let goals = self.target.goals(chain.effector())?;
        Ok(Built {
            skeleton,
            chain,
            solver,
            tracker,
            goals,
        })
    }
}

impl TaskSpec for IkTask {
    fn validate(&self) -> Result<(), String> {
        let built = self.build()?;
        check_solve_work(
            built.goals.len(),
            self.settings.max_iterations,
            1,
            built.skeleton.len(),
        )?;
        non_negative("expect_error_max", self.expect_error_max)?;
        Ok(())
    }

    fn run(&self, ctx: &RunContext) -> Result<TaskOutput, String> {
        let Built {
            skeleton,
            chain,
            mut solver,
            mut tracker,
            goals,
        } = self.build()?;
        let targets: Vec<DVec3> = goals.iter().map(|g| g.position).collect();
        tracker.reserve(targets.len());
        let mut pose = skeleton.rest_pose();
        let mut global = GlobalPose::new();
        skeleton
            .forward_kinematics(&pose, &mut global)
            .map_err(|e| e.to_string())?;
        let mut frame_ns = Vec::with_capacity(targets.len());
        // Pictures animate at most MAX_FRAMES frames (the last always among them); the
        // positions are copied outside the timed part.
        let frame_every = targets.len().div_ceil(MAX_FRAMES).max(1);
        // The interactive viewer gets a finer selection (it thins it to its own budget).
        let track_every = targets.len().div_ceil(MAX_TRACK_FRAMES).max(1);
        let mut track: Vec<IkFrame> = Vec::new();
        let mut track_frames: Vec<usize> = Vec::new();
        let mut shown: Vec<IkFrame> = Vec::new();
        let mut progress = ctx.progress(&self.name, targets.len());
        for (k, (&target, &goal)) in targets.iter().zip(&goals).enumerate() {
            let start = Instant::now();
            tracker
                .step(
                    solver.as_mut(),
                    &skeleton,
                    &chain,
                    &mut IkState::new(&mut pose, &mut global),
                    goal,
                )
                .map_err(|e| e.to_string())?;
            frame_ns.push(start.elapsed().as_secs_f64() * 1e9);
            let last = k + 1 == targets.len();
            if ctx.keep_frames && (k % track_every == 0 || last) {
                let joints: Vec<DVec3> = chain
                    .joints()
                    .iter()
                    .map(|&j| global.positions[j])
                    .collect();
                if k % frame_every == 0 || last {
                    shown.push(IkFrame {
                        joints: joints.clone(),
                        target,
                    });
                }
                track.push(IkFrame { joints, target });
                track_frames.push(k);
            }
            progress.inc();
        }
        let summary = tracker.summary();
        let records = tracker.records();

        let mut csv = String::from(
            "frame,target_x,target_y,target_z,error,iterations,stop,rotation_change,clamped\n",
        );
        for (i, r) in records.iter().enumerate() {
            csv.push_str(&format!(
                "{i},{},{},{},{},{},{},{},{}\n",
                r.target.x,
                r.target.y,
                r.target.z,
                r.error,
                r.iterations,
                r.stop,
                r.rotation_change,
                r.clamped
            ));
        }
        drop(progress);
        let pictures = if ctx.keep_frames {
            Pictures::Ik(IkPictures {
                solver: self.solver.label().to_string(),
                frames: shown,
                track,
                track_frames,
                targets: targets.clone(),
                error: records.iter().map(|r| r.error).collect(),
                iterations: records.iter().map(|r| r.iterations).collect(),
            })
        } else {
            Pictures::None
        };

        let out_of_reach = records
            .iter()
            .filter(|r| r.stop == StopReason::OutOfReach)
            .count();
        // The final pose's shape: the largest angle between consecutive bones (0 for a
        // straight chain), and for a target out of reach how far the error is from the
        // least possible, distance - reach (0 for the closed-form answer).
        let joints = chain.joints();
        let bend_max = joints
            .windows(3)
            .map(|w| {
                let a = global.positions[w[1]] - global.positions[w[0]];
                let b = global.positions[w[2]] - global.positions[w[1]];
                angle_between(a, b)
            })
            .fold(0.0, f64::max);
        let last = targets[targets.len() - 1];
        let distance = global.positions[chain.base()].distance(last);
        let closed_form_gap = (distance >= chain.reach())
            .then(|| records[records.len() - 1].error - (distance - chain.reach()));
        let mut failures = Vec::new();
        if let Some(limit) = self.expect_error_max
            && summary.error_max > limit
        {
            failures.push(format!(
                "largest frame error {:.3e} > expected at most {limit:.1e}",
                summary.error_max
            ));
        }
        // Joint limits are an invariant of every solver (the projections' round-off is
        // far below 1e-12 rad).
        if summary.limit_violation_max > 1e-12 {
            failures.push(format!(
                "a frame's pose leaves a joint limit by {:.3e} rad",
                summary.limit_violation_max
            ));
        }
        // Bone lengths are an invariant of every solver: check them always, relative
        // to the chain's reach (positions carry round-off of their own size).
        let scale = chain
            .reach()
            .max(global.positions[chain.base()].length())
            .max(1.0);
        if summary.bone_length_error_max > 1e-12 * scale {
            failures.push(format!(
                "bone length error {:.3e} exceeds 1e-12 of the chain's scale",
                summary.bone_length_error_max
            ));
        }
        let metrics = IkMetrics {
            solver: self.solver.label().to_string(),
            frames: summary.frames,
            error_mean: summary.error_mean,
            error_max: summary.error_max,
            iterations_total: summary.iterations_total,
            converged_frames: summary.converged_frames,
            out_of_reach_frames: out_of_reach,
            within_tol: summary.converged_frames,
            limit_violation_max: summary.limit_violation_max,
            rotation_error_max: summary.rotation_error_max,
            local_minimum_frames: summary.local_minimum_frames,
            clamped_frames: summary.clamped_frames,
            bone_length_error_max: summary.bone_length_error_max,
            rotation_jump_max_rad: summary.rotation_jump_max_rad,
            time_per_frame_ns_median: median(&mut frame_ns),
            final_bend_max_rad: bend_max,
            closed_form_gap,
        };
        let headline = format!(
            "{} {} frames: error mean {:.1e} max {:.1e}, {}/{} within tol, {} iterations",
            self.solver.label(),
            summary.frames,
            summary.error_mean,
            summary.error_max,
            summary.converged_frames,
            summary.frames,
            summary.iterations_total
        );
        Ok(TaskOutput::per_frame(
            TaskMetrics::Ik(metrics),
            headline,
            failures,
            csv,
            pictures,
        ))
    }
}

/// The most frames an IK animation shows.
const MAX_FRAMES: usize = 120;
/// The most frames kept for the interactive viewer.
const MAX_TRACK_FRAMES: usize = 1000;
