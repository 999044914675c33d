//! The `TwoBone` task: analytic two-bone IK (sinew-ik-two-bone) on a limb whose tip
//! follows a path frame by frame, with every guarantee the solver makes checked here by
//! independent measurements: the mid joint's hinge limit (through the skeleton's own
//! `JointLimit`, not the solver's clamp), the bend on the pole's side, bone lengths, and
//! the reported error against forward kinematics of the result.

use super::fk::bone_length_error_max;
use super::{RunContext, TaskOutput, TaskSpec, median, median_time_ns, non_negative};
use crate::limits::{MAX_FRAMES, at_most};
use crate::results::{Pictures, TaskMetrics, TwoBoneMetrics};
use crate::spec::SkeletonSpec;
use serde::Deserialize;
use sinew_ik_two_bone::{Hinge, TwoBoneIk};
use sinew_math::{DVec3, try_unit};
use sinew_skeleton::limits::{self, JointLimit};
use sinew_skeleton::{GlobalPose, Skeleton};
use std::f64::consts::PI;

/// Scene fields of a `TwoBone` task.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TwoBoneTask {
    /// Unique name in the scene.
    pub name: String,
    /// The skeleton holding the limb.
    pub skeleton: SkeletonSpec,
    /// The root joint (hip, shoulder).
    pub root: usize,
    /// The mid joint (knee, elbow).
    pub mid: usize,
    /// The tip joint (ankle, wrist).
    pub tip: usize,
    /// The mid joint's hinge: axis in its rest frame, bend range in radians.
    pub hinge: Hinge,
    /// The pole: the point the bend plane turns towards (world coordinates).
    pub pole: DVec3,
    /// The fraction of the reach below which targets are reached exactly (default 1).
    #[serde(default = "one")]
    pub soften: f64,
    /// The tip's path.
    pub target: TipPath,
    /// Reached frames must end within this distance (default 1e-12 of scene units).
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
}

fn one() -> f64 {
    1.0
}

fn default_tolerance() -> f64 {
    1e-12
}

/// Where the tip goes, frame by frame.
#[derive(Debug, Deserialize)]
pub enum TipPath {
    /// Explicit points, one per frame.
    Points(Vec<DVec3>),
    /// A walking foot's cycle about `centre`, `frames` frames per cycle, `cycles` cycles:
    /// for the first half of a cycle the foot is planted and slides back from
    /// `+stride/2` to `-stride/2` along `forward` (the body moving over it); for the
    /// second half it swings forward again, lifted by `lift sin(pi s)` along +y (`s` the
    /// fraction of the swing).
    Step {
        /// The middle of the stride.
        centre: DVec3,
        /// The walking direction (need not be unit).
        forward: DVec3,
        /// Length of a stride.
        stride: f64,
        /// Highest lift of the swinging foot.
        lift: f64,
        /// Frames per cycle (at least 2).
        frames: usize,
        /// Number of cycles (default 1).
        #[serde(default = "one_cycle")]
        cycles: usize,
    },
}

fn one_cycle() -> usize {
    1
}

impl TipPath {
    fn points(&self) -> Result<Vec<DVec3>, String> {
        match self {
            Self::Points(points) => {
                if points.is_empty() {
                    return Err("target: Points is empty".into());
                }
                if let Some(k) = points.iter().position(|p| !p.is_finite()) {
                    return Err(format!("target: point {k} is not finite"));
                }
                at_most("target: points", points.len(), MAX_FRAMES)?;
                Ok(points.clone())
            }
            Self::Step {
                centre,
                forward,
                stride,
                lift,
                frames,
                cycles,
            } => {
                if !centre.is_finite() {
                    return Err(format!("target: centre {centre} is not finite"));
                }
                let Some(forward) = try_unit(*forward) else {
                    return Err(format!(
                        "target: forward {forward} has no direction (zero or not finite)"
                    ));
                };
                if !(stride.is_finite() && *stride >= 0.0) {
                    return Err(format!(
                        "target: stride = {stride}, must be finite and >= 0"
                    ));
                }
                if !lift.is_finite() {
                    return Err(format!("target: lift = {lift} is not finite"));
                }
                if *frames < 2 || *cycles == 0 {
                    return Err(format!(
                        "target: frames = {frames}, cycles = {cycles}: need frames >= 2 and \
                         cycles >= 1"
                    ));
                }
                at_most(
                    "target: frames x cycles",
                    frames.saturating_mul(*cycles),
                    MAX_FRAMES,
                )?;
                let half = frames / 2;
                let points = (0..frames * cycles)
                    .map(|i| {
                        let k = i % frames;
                        if k < half {
                            let s = k as f64 / half as f64;
                            *centre + forward * (stride * (0.5 - s))
                        } else {
                            let s = (k - half) as f64 / (frames - half) as f64;
                            *centre
                                + forward * (stride * (s - 0.5))
                                + DVec3::Y * (lift * (PI * s).sin())
                        }
                    })
                    .collect();
                Ok(points)
            }
        }
    }
}

impl TwoBoneTask {
    fn job(&self, target: DVec3) -> TwoBoneIk {
        let mut job = TwoBoneIk::new(self.root, self.mid, self.tip, target, self.pole);
        job.soften = self.soften;
        job.hinge = self.hinge;
        job
    }
}

/// How far the mid joint is on the wrong side of the root-tip line, seen from the pole:
/// 0 when the bend points towards the pole's side (or the limb is straight, where there
/// is no side), else the distance of the mid joint from that line.
fn wrong_side(root: DVec3, mid: DVec3, tip: DVec3, pole: DVec3) -> f64 {
    let Some(line) = try_unit(tip - root) else {
        return 0.0;
    };
    let off = |p: DVec3| (p - root) - line * (p - root).dot(line);
    let (mid_off, pole_off) = (off(mid), off(pole));
    if mid_off.dot(pole_off) >= 0.0 {
        0.0
    } else {
        mid_off.length()
    }
}

impl TaskSpec for TwoBoneTask {
    fn validate(&self) -> Result<(), String> {
        let skeleton = self.skeleton.build()?;
        let pose = skeleton.rest_pose();
        let points = self.target.points()?;
        self.job(points[0])
            .validate(&skeleton, &pose)
            .map_err(|e| e.to_string())?;
        non_negative("tolerance", Some(self.tolerance))?;
        Ok(())
    }

    fn run(&self, ctx: &RunContext) -> Result<TaskOutput, String> {
        let skeleton: Skeleton = self.skeleton.build()?;
        let points = self.target.points()?;
        // The check uses the skeleton's limit code, not the solver's own clamp.
        let limit = JointLimit::Hinge(limits::Hinge {
            axis: self.hinge.axis.normalize(),
            min: self.hinge.min,
            max: self.hinge.max,
        });
        let mut pose = skeleton.rest_pose();
        let mut global = GlobalPose::new();
        skeleton
            .forward_kinematics(&pose, &mut global)
            .map_err(|e| e.to_string())?;

        let mut failures = Vec::new();
        let (mut reached, mut within_tol) = (0usize, 0usize);
        let (mut error_max, mut reached_error_max, mut report_fk_diff): (f64, f64, f64) =
            (0.0, 0.0, 0.0);
        let (mut limit_violation_max, mut wrong_side_max, mut bone_error_max): (f64, f64, f64) =
            (0.0, 0.0, 0.0);
        let (mut bend_min, mut bend_max) = (f64::INFINITY, f64::NEG_INFINITY);
        let mut times = Vec::with_capacity(points.len());
        let mut csv = String::from("frame,target_x,target_y,target_z,error,reached,bend_angle\n");
        let mut progress = ctx.progress(&self.name, points.len());
        for (frame, &target) in points.iter().enumerate() {
            let job = self.job(target);
            let report = job
                .run(&skeleton, &mut pose, &mut global)
                .map_err(|e| format!("frame {frame}: {e}"))?;
            // Each frame is timed on its own (a warm solve from the previous frame's pose);
            // the median over frames is reported.
            let mut scratch_pose = pose.clone();
            let mut scratch_global = global.clone();
            // The timed solves start from the pose just returned, not the one given: if a
            // warm solve from it is refused, that is the frame's error, not a panic. (The
            // case found, a bone of 1.8e308 whose turned forward kinematics overflowed, is
            // now refused with the skeleton, by `MAX_REACH`.)
            let mut timed_error = None;
            times.push(median_time_ns(0.2, || {
                if let Err(e) = job.run(&skeleton, &mut scratch_pose, &mut scratch_global) {
                    timed_error.get_or_insert(e);
                }
            }));
            if let Some(e) = timed_error {
                return Err(format!(
                    "frame {frame}: solving again from the returned pose: {e}"
                ));
            }

            // Independent checks, from the returned pose only.
            let mut check = GlobalPose::new();
            skeleton
                .forward_kinematics(&pose, &mut check)
                .map_err(|e| e.to_string())?;
            let error = check.positions[self.tip].distance(target);
            report_fk_diff = report_fk_diff.max((error - report.error).abs());
            error_max = error_max.max(error);
            if report.reached {
                reached += 1;
                reached_error_max = reached_error_max.max(error);
                if error <= self.tolerance {
                    within_tol += 1;
                }
            }
            limit_violation_max =
                limit_violation_max.max(limit.violation(pose.rotations[self.mid]));
            wrong_side_max = wrong_side_max.max(wrong_side(
                check.positions[self.root],
                check.positions[self.mid],
                check.positions[self.tip],
                self.pole,
            ));
            bone_error_max = bone_error_max.max(bone_length_error_max(&skeleton, &check));
            bend_min = bend_min.min(report.bend_angle);
            bend_max = bend_max.max(report.bend_angle);
            csv.push_str(&format!(
                "{frame},{},{},{},{error:e},{},{}\n",
                target.x, target.y, target.z, report.reached, report.bend_angle
            ));
            progress.inc();
        }
        drop(progress);

        if within_tol < reached {
            failures.push(format!(
                "{} reached frames end farther than tolerance {:.1e} (worst {reached_error_max:.3e})",
                reached - within_tol,
                self.tolerance
            ));
        }
        if limit_violation_max > 1e-12 {
            failures.push(format!(
                "the mid joint left its hinge limit by {limit_violation_max:.3e} rad"
            ));
        }
        if wrong_side_max > 1e-12 {
            failures.push(format!(
                "the mid joint bent away from the pole (by {wrong_side_max:.3e})"
            ));
        }
        if report_fk_diff > 1e-12 {
            failures.push(format!(
                "reported error differs from forward kinematics by {report_fk_diff:.3e}"
            ));
        }

        let time_ns = median(&mut times);
        let metrics = TwoBoneMetrics {
            frames: points.len(),
            reached,
            within_tol,
            error_max,
            reached_error_max,
            report_fk_diff_max: report_fk_diff,
            limit_violation_max,
            wrong_side_max,
            bone_length_error_max: bone_error_max,
            bend_angle_min: bend_min,
            bend_angle_max: bend_max,
            time_per_solve_ns_median: time_ns,
        };
        let headline = format!(
            "two-bone {} frames: {reached} reached, error max {error_max:.1e}, bend {:.1}..{:.1} deg, {time_ns:.0} ns/solve",
            points.len(),
            bend_min.to_degrees(),
            bend_max.to_degrees()
        );
        Ok(TaskOutput::per_frame(
            TaskMetrics::TwoBone(metrics),
            headline,
            failures,
            csv,
            Pictures::None,
        ))
    }
}
