//! The `FullBody` task: several effectors on one skeleton tree (hands, feet, head, hips)
//! solved together by a full-body solver of `sinew_ik_body`, frame after frame, each
//! frame warm-started from the previous one. Two clips: the reference squat of the
//! 22-joint humanoid (both ankles pinned, the head descending, the hands circling), and
//! a motion-capture clip read from a BVH file, whose chosen joints (hands, head, hips)
//! the body follows while other joints (the feet) stay pinned where they stand on the
//! first frame (foot locking).

use super::{RunContext, TaskOutput, TaskSpec, median, non_negative};
use crate::limits::{self, at_most, check_solve_work};
use crate::results::{BodyFrame, BodyMetrics, BodyPictures, Pictures, TaskMetrics};
use serde::Deserialize;
use sinew_ik_body::{BodyEffector, BodyProblem, BodySolverOptions, BodyState, workload};
use sinew_math::DVec3;
use sinew_skeleton::ik::SolveSettings;
use sinew_skeleton::{GlobalPose, Pose, Skeleton};
use std::path::PathBuf;
use std::time::Instant;

/// Scene fields of a `FullBody` task.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FullBodyTask {
    /// Unique name in the scene.
    pub name: String,
    /// The skeleton and the goals of each frame.
    pub clip: ClipSpec,
    /// The body solver and its options: `Fabrik(...)` or `Ccd(...)`, every option
    /// defaulted (default: `Fabrik()`).
    #[serde(default)]
    pub solver: BodySolverOptions,
    /// Iteration cap and tolerances, per effector (default 100 and 1e-6).
    #[serde(default)]
    pub settings: SolveSettings,
    /// Fail the task if the worst effector error of a frame exceeds this.
    #[serde(default)]
    pub expect_error_max: Option<f64>,
    /// Fail the task if fewer frames than this end with every effector within the
    /// tolerance.
    #[serde(default)]
    pub expect_within_tol_min: Option<usize>,
    /// The directory relative paths in the clip are read from: the scene file's own,
    /// set when the scene is loaded (not a scene field).
    #[serde(skip)]
    pub base_dir: PathBuf,
}

/// Where the skeleton and the goals come from.
#[derive(Debug, Deserialize)]
pub enum ClipSpec {
    /// The reference squat of the 22-joint humanoid with human-like joint limits: both
    /// ankles pinned where they stand, the head's goal descending by up to 0.4 m and
    /// rising again, each wrist following a circle of radius 0.15 m in front of the
    /// chest; the hips translate. One squat lasts 600 frames.
    Squat {
        /// Frames to solve (default 600, one whole squat).
        #[serde(default = "squat_frames")]
        frames: usize,
    },
    /// A BVH file's skeleton and motion: the joints of `follow` track their positions
    /// in the file frame by frame, the joints of `pinned` stay where they are on the
    /// first frame; the solve starts from the first frame's pose, and the hips (the
    /// root) translate. BVH joints have no limits.
    Bvh {
        /// The file, relative to the scene file's directory.
        file: String,
        /// Joint names whose positions in the file are followed (e.g. the hands, the
        /// head, the hips).
        follow: Vec<String>,
        /// Joint names pinned where they stand on the first frame (e.g. the feet).
        #[serde(default)]
        pinned: Vec<String>,
        /// Solve only the first this many frames (default: all of them).
        #[serde(default)]
        frames: Option<usize>,
    },
}

fn squat_frames() -> usize {
    workload::CLIP_FRAMES
}

/// A clip ready to run: the skeleton, the starting state and every frame's effectors.
struct Built {
    skeleton: Skeleton,
    start_pose: Pose,
    start_translation: DVec3,
    frames: Vec<Vec<BodyEffector>>,
}

impl ClipSpec {
    fn build(&self, base_dir: &std::path::Path) -> Result<Built, String> {
        match self {
            Self::Squat { frames } => {
                if *frames == 0 {
                    return Err("clip: frames = 0, must be at least 1".into());
                }
                at_most("clip: frames", *frames, limits::MAX_FRAMES)?;
                let skeleton =
                    workload::humanoid().map_err(|e| format!("clip: the humanoid: {e}"))?;
                let rest = BodyState::rest(&skeleton);
                let goals = (0..*frames)
                    .map(|k| workload::clip_frame(&rest.global, k).to_vec())
                    .collect();
                Ok(Built {
                    start_pose: skeleton.rest_pose(),
                    start_translation: DVec3::ZERO,
                    skeleton,
                    frames: goals,
                })
            }
            Self::Bvh {
                file,
                follow,
                pinned,
                frames,
            } => {
                let path = base_dir.join(file);
                let text = std::fs::read_to_string(&path)
                    .map_err(|e| format!("clip: file {}: {e}", path.display()))?;
                let bvh = sinew_io::parse_bvh(&text)
                    .map_err(|e| format!("clip: file {}: {e}", path.display()))?;
                let available = bvh.frames.len();
                let count = frames.unwrap_or(available);
                if count == 0 || count > available {
                    return Err(format!(
                        "clip: frames = {count}, must be 1..={available} (the file's frames)"
                    ));
                }
                if follow.is_empty() && pinned.is_empty() {
                    return Err("clip: follow and pinned are both empty; name a joint".into());
                }
                let skeleton = bvh.skeleton;
                let joint = |list: &str, name: &str| {
                    skeleton.joint_by_name(name).ok_or_else(|| {
                        format!(
                            "clip: {list}: no joint named {name:?} in {}",
                            path.display()
                        )
                    })
                };
                let follow_joints: Vec<usize> = follow
                    .iter()
                    .map(|n| joint("follow", n))
                    .collect::<Result<_, _>>()?;
                let pinned_joints: Vec<usize> = pinned
                    .iter()
                    .map(|n| joint("pinned", n))
                    .collect::<Result<_, _>>()?;
                let mut seen = std::collections::HashSet::new();
                for (list, names, joints) in [
                    ("follow", follow, &follow_joints),
                    ("pinned", pinned, &pinned_joints),
                ] {
                    for (name, &j) in names.iter().zip(joints) {
                        if !seen.insert(j) {
                            return Err(format!(
                                "clip: {list}: joint {name:?} is named twice; one effector per joint"
                            ));
                        }
                    }
                }
                let positions = |k: usize| {
                    bvh.frames[k]
                        .joint_positions(&skeleton)
                        .map_err(|e| format!("clip: frame {k}: {e}"))
                };
                let first = positions(0)?;
                let mut goals = Vec::with_capacity(count);
                for k in 0..count {
                    let at = positions(k)?;
                    goals.push(
                        follow_joints
                            .iter()
                            .map(|&j| BodyEffector::at(j, at[j]))
                            .chain(
                                pinned_joints
                                    .iter()
                                    .map(|&j| BodyEffector::pinned(j, first[j])),
                            )
                            .collect(),
                    );
                }
                Ok(Built {
                    start_pose: bvh.frames[0].pose.clone(),
                    start_translation: bvh.frames[0].root_translation,
                    skeleton,
                    frames: goals,
                })
            }
        }
    }
}

impl FullBodyTask {
    fn build(&self) -> Result<Built, String> {
        self.solver.validate().map_err(|e| format!("solver: {e}"))?;
        let built = self.clip.build(&self.base_dir)?;
        // Every frame's problem is checked here, so a bad goal is named before any run.
        for (k, effectors) in built.frames.iter().enumerate() {
            BodyProblem::new(&built.skeleton, effectors, self.settings)
                .validate()
                .map_err(|e| format!("clip: frame {k}: {e}"))?;
        }
        Ok(built)
    }
}

impl TaskSpec for FullBodyTask {
    fn validate(&self) -> Result<(), String> {
        self.settings
            .validate()
            .map_err(|e| format!("settings: {e}"))?;
        non_negative("expect_error_max", self.expect_error_max)?;
        let built = self.build()?;
        let attempts = match self.solver {
            BodySolverOptions::Fabrik(o) => o.restarts.saturating_add(1),
            BodySolverOptions::Ccd(_) => 1,
        };
        check_solve_work(
            built.frames.len(),
            self.settings.max_iterations,
            attempts,
            built.skeleton.len(),
        )?;
        Ok(())
    }

    fn run(&self, ctx: &RunContext) -> Result<TaskOutput, String> {
        let Built {
            skeleton,
            start_pose,
            start_translation,
            frames,
        } = self.build()?;
        let label = self.solver_label();
        let mut solver = self.solver.build().map_err(|e| format!("solver: {e}"))?;
        let mut state = BodyState::rest(&skeleton);
        state.copy_pose_from(&start_pose, start_translation);
        let mut check = GlobalPose::new();
        let scale = skeleton_scale(&skeleton).max(start_translation.length());

        let frame_every = frames.len().div_ceil(MAX_FRAMES).max(1);
        let track_every = frames.len().div_ceil(MAX_TRACK_FRAMES).max(1);
        let mut shown = Vec::new();
        let mut track = Vec::new();
        let mut track_frames = Vec::new();
        let mut solve_us = Vec::with_capacity(frames.len());
        let mut errors = Vec::with_capacity(frames.len());
        let mut iterations = Vec::with_capacity(frames.len());
        let mut within_tol = 0;
        let mut limit_violation_max: f64 = 0.0;
        let mut error_max: f64 = 0.0;
        let mut fk_gap_max: f64 = 0.0;
        let mut report_gap_max: f64 = 0.0;
        let mut pin_excess_max: f64 = 0.0;
        let mut cost_rise_frames = Vec::new();
        let mut csv = String::from(
            "frame,error_max,pinned_error_max,iterations,stop,initial_cost,cost,limit_violation,solve_us\n",
        );
        let mut progress = ctx.progress(&self.name, frames.len());
        for (k, effectors) in frames.iter().enumerate() {
            let problem =
                BodyProblem::new(&skeleton, effectors, self.settings).with_root_translation(true);
            let start = Instant::now();
            let report = solver
                .solve(&problem, &mut state)
                .map_err(|e| format!("frame {k}: {e}"))?;
            let us = start.elapsed().as_secs_f64() * 1e6;
            solve_us.push(us);

            // The report is checked against forward kinematics of the returned pose,
            // computed here independently of the solver (outside the timed part).
            sinew_ik_body::forward_kinematics(
                &skeleton,
                &state.pose,
                state.root_translation,
                &mut check,
            )
            .map_err(|e| format!("frame {k}: {e}"))?;
            fk_gap_max = fk_gap_max.max(super::max_distance(
                &check.positions,
                &state.global.positions,
            ));
            let distance =
                |e: &BodyEffector| e.goal.position.distance(check.positions[e.goal.joint]);
            let worst = effectors.iter().map(distance).fold(0.0, f64::max);
            report_gap_max = report_gap_max.max((worst - report.max_error).abs());
            let mut pinned_error: f64 = 0.0;
            for (e, errors) in effectors.iter().zip(&state.effectors) {
                if e.pinned {
                    let d = distance(e);
                    pinned_error = pinned_error.max(d);
                    // A pinned effector may not end further from its pin than the
                    // tolerance, or than it started if that was further.
                    let allowed = self.settings.tolerance.max(errors.initial_position);
                    pin_excess_max = pin_excess_max.max(d - allowed);
                }
            }
            if report.cost > report.initial_cost {
                cost_rise_frames.push(k);
            }
            if report.within(&self.settings) {
                within_tol += 1;
            }
            limit_violation_max = limit_violation_max.max(report.limit_violation);
            error_max = error_max.max(report.max_error);
            errors.push(report.max_error);
            iterations.push(report.iterations);
            csv.push_str(&format!(
                "{k},{},{pinned_error},{},{},{},{},{},{us}\n",
                report.max_error,
                report.iterations,
                report.stop,
                report.initial_cost,
                report.cost,
                report.limit_violation,
            ));

            let last = k + 1 == frames.len();
            if ctx.keep_frames && (k % track_every == 0 || last) {
                let frame = BodyFrame {
                    joints: state.global.positions.clone(),
                    goals: effectors.iter().map(|e| e.goal.position).collect(),
                    error: report.max_error,
                };
                if k % frame_every == 0 || last {
                    shown.push(frame.clone());
                }
                track.push(frame);
                track_frames.push(k);
            }
            progress.inc();
        }
        drop(progress);

        let mut failures = Vec::new();
        if let Some(limit) = self.expect_error_max
            && error_max > limit
        {
            failures.push(format!(
                "worst effector error {error_max:.3e} > expected at most {limit:.1e}"
            ));
        }
        if let Some(min) = self.expect_within_tol_min
            && within_tol < min
        {
            failures.push(format!(
                "{within_tol} frames within tolerance < expected at least {min}"
            ));
        }
        // The solvers' contract, checked on every frame: no limit violated (beyond the
        // projections' round-off), the state's global pose and the report's worst error
        // are those of forward kinematics, pins hold, the cost never rises.
        if limit_violation_max > 1e-12 {
            failures.push(format!(
                "a frame's pose leaves a joint limit by {limit_violation_max:.3e} rad"
            ));
        }
        if fk_gap_max > 1e-12 * scale {
            failures.push(format!(
                "the returned global pose differs from forward kinematics by {fk_gap_max:.3e}"
            ));
        }
        if report_gap_max > 1e-12 * scale {
            failures.push(format!(
                "the reported worst error differs from forward kinematics' by {report_gap_max:.3e}"
            ));
        }
        if pin_excess_max > 1e-12 * scale {
            failures.push(format!(
                "a pinned effector ends {pin_excess_max:.3e} beyond what its pin allows"
            ));
        }
        if let Some(&k) = cost_rise_frames.first() {
            failures.push(format!(
                "the weighted cost ends above its start on {} frames (first: frame {k})",
                cost_rise_frames.len()
            ));
        }

        let pictures = if ctx.keep_frames {
            Pictures::Body(BodyPictures {
                solver: label.clone(),
                parents: (0..skeleton.len()).map(|j| skeleton.parent(j)).collect(),
                effectors: frames[0].iter().map(|e| e.goal.joint).collect(),
                pinned: frames[0].iter().map(|e| e.pinned).collect(),
                frames: shown,
                track,
                track_frames,
                error: errors.clone(),
                iterations: iterations.clone(),
            })
        } else {
            Pictures::None
        };
        let metrics = BodyMetrics {
            effectors: frames[0].len(),
            frames: frames.len(),
            within_tol,
            limit_violation_max,
            error_max,
            time_per_solve_us_median: median(&mut solve_us),
        };
        let headline = format!(
            "{label} {} effectors, {} frames: {}/{} within tol, worst error {:.1e}, median solve {:.1} us",
            metrics.effectors,
            metrics.frames,
            within_tol,
            metrics.frames,
            error_max,
            metrics.time_per_solve_us_median
        );
        Ok(TaskOutput::per_frame(
            TaskMetrics::Body(metrics),
            headline,
            failures,
            csv,
            pictures,
        ))
    }
}

impl FullBodyTask {
    /// The registry's label of the chosen configuration when it is a named one,
    /// otherwise the solver kind.
    fn solver_label(&self) -> String {
        BodySolverOptions::NAMED
            .iter()
            .find(|(_, o)| *o == self.solver)
            .map_or_else(
                || match self.solver {
                    BodySolverOptions::Fabrik(_) => "fabrik (custom)".to_string(),
                    BodySolverOptions::Ccd(_) => "ccd (custom)".to_string(),
                },
                |(n, _)| (*n).to_string(),
            )
    }
}

/// The skeleton's size for round-off allowances: the sum of its bone lengths, at least 1.
fn skeleton_scale(skeleton: &Skeleton) -> f64 {
    (0..skeleton.len())
        .map(|j| skeleton.offset(j).length())
        .sum::<f64>()
        .max(1.0)
}

/// The most frames a body animation shows.
const MAX_FRAMES: usize = 120;
/// The most frames kept for the interactive viewer.
const MAX_TRACK_FRAMES: usize = 1000;
