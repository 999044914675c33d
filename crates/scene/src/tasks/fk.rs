//! The `Fk` task: forward kinematics of a skeleton in a pose, with optional expected
//! joint positions (so a scene doubles as a data-driven test).

use super::{RunContext, TaskOutput, TaskSpec, max_distance, median_time_ns, non_negative};
use crate::results::{Csv, FkMetrics, Pictures, TaskMetrics};
use crate::spec::{JointRotation, SkeletonSpec, build_pose};
use serde::Deserialize;
use sinew_math::DVec3;
use sinew_skeleton::{GlobalPose, Skeleton};

/// Scene fields of an `Fk` task.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FkTask {
    /// Unique name in the scene.
    pub name: String,
    /// The skeleton.
    pub skeleton: SkeletonSpec,
    /// Joint rotations (identity elsewhere).
    #[serde(default)]
    pub pose: Vec<JointRotation>,
    /// Expected global joint positions; the task fails when one is off by more than
    /// `tolerance`.
    #[serde(default)]
    pub expect: Vec<ExpectedPosition>,
    /// Absolute tolerance for `expect` (default 1e-12).
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
}

/// An expected global position of one joint.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExpectedPosition {
    /// The joint index.
    pub joint: usize,
    /// Its expected global position.
    pub position: DVec3,
}

fn default_tolerance() -> f64 {
    1e-12
}

impl TaskSpec for FkTask {
    fn validate(&self) -> Result<(), String> {
        let skeleton = self.skeleton.build()?;
        build_pose(&skeleton, &self.pose)?;
        for (k, e) in self.expect.iter().enumerate() {
            if e.joint >= skeleton.len() {
                return Err(format!(
                    "expect[{k}]: joint {} is out of range (the skeleton has {} joints)",
                    e.joint,
                    skeleton.len()
                ));
            }
            if !e.position.is_finite() {
                return Err(format!(
                    "expect[{k}]: position {} is not finite",
                    e.position
                ));
            }
        }
        non_negative("tolerance", Some(self.tolerance))?;
        Ok(())
    }

    fn run(&self, _ctx: &RunContext) -> Result<TaskOutput, String> {
        let skeleton = self.skeleton.build()?;
        let pose = build_pose(&skeleton, &self.pose)?;
        let mut global = GlobalPose::new();
        skeleton
            .forward_kinematics(&pose, &mut global)
            .map_err(|e| e.to_string())?;

        // Incremental FK: start from the rest pose and apply the rotations joint by
        // joint, each followed by FK from that joint only; it must equal full FK.
        let mut incremental_pose = skeleton.rest_pose();
        let mut incremental = GlobalPose::new();
        skeleton
            .forward_kinematics(&incremental_pose, &mut incremental)
            .map_err(|e| e.to_string())?;
        for j in 0..skeleton.len() {
            if pose.rotations[j] != incremental_pose.rotations[j] {
                incremental_pose.rotations[j] = pose.rotations[j];
                skeleton
                    .forward_kinematics_from(&incremental_pose, j, &mut incremental)
                    .map_err(|e| e.to_string())?;
            }
        }
        let incremental_diff = max_distance(&incremental.positions, &global.positions);

        let bone_error = bone_length_error_max(&skeleton, &global);
        let time_ns = median_time_ns(50.0, || {
            skeleton
                .forward_kinematics(std::hint::black_box(&pose), &mut global)
                .expect("validated pose");
        });

        let mut failures = Vec::new();
        let mut expect_error_max: f64 = 0.0;
        for e in &self.expect {
            let error = global.positions[e.joint].distance(e.position);
            expect_error_max = expect_error_max.max(error);
            if error > self.tolerance {
                failures.push(format!(
                    "joint {}: at {} but expected {} (off by {error:.3e} > tolerance {:.1e})",
                    e.joint, global.positions[e.joint], e.position, self.tolerance
                ));
            }
        }
        if incremental_diff > 0.0 {
            failures.push(format!(
                "FK from a joint differs from full FK by {incremental_diff:e}"
            ));
        }

        let mut csv = String::from("joint,x,y,z\n");
        for (i, p) in global.positions.iter().enumerate() {
            csv.push_str(&format!("{i},{},{},{}\n", p.x, p.y, p.z));
        }

        let effector = global.positions[skeleton.len() - 1];
        let metrics = FkMetrics {
            joints: skeleton.len(),
            effector: effector.to_array(),
            bone_length_error_max: bone_error,
            fk_from_diff_max: incremental_diff,
            expect_error_max,
            time_ns_median: time_ns,
        };
        let headline = format!(
            "{} joints, effector ({:.4}, {:.4}, {:.4}), bone length error {:.1e}",
            skeleton.len(),
            effector.x,
            effector.y,
            effector.z,
            bone_error
        );
        Ok(TaskOutput {
            metrics: TaskMetrics::Fk(metrics),
            headline,
            failures,
            table: Csv {
                suffix: "positions.csv",
                text: csv,
            },
            pictures: Pictures::None,
        })
    }
}

/// The largest relative bone-length error of a global pose (0 for zero-length bones
/// that stay zero).
pub fn bone_length_error_max(skeleton: &Skeleton, global: &GlobalPose) -> f64 {
    (0..skeleton.len())
        .filter_map(|i| skeleton.parent(i).map(|p| (i, p)))
        .map(|(i, p)| {
            let rest = skeleton.bone_length(i);
            let now = global.positions[i].distance(global.positions[p]);
            if rest > 0.0 {
                (now - rest).abs() / rest
            } else {
                now
            }
        })
        .fold(0.0, f64::max)
}
