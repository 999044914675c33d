//! Properties of trajectory tracking (sinew_skeleton::track) with every solver: over many
//! frames, warm-started from each other, with or without the per-frame rotation limit,
//! every bone keeps its length, nothing becomes NaN, and the per-frame records tell the
//! truth (docs/labcheck.md).

use crate::common::{fk, make_solver, settings, solver_kind};
use proptest::prelude::*;
use sinew_labcheck::config;
use sinew_labcheck::reference::kinematics::skeleton_bone_violation;
use sinew_labcheck::strategies::chains::{self, ChainCase, TreeCase};
use sinew_labcheck::strategies::targets;
use sinew_labcheck::strategies::{direction, log_uniform};
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::{Chain, EffectorGoal, IkState};
use sinew_skeleton::track::{TrackSettings, Tracker};
use sinew_skeleton::{Pose, Skeleton};
use std::f64::consts::TAU;

/// The frames' targets: a smooth circle around the base (radius a random fraction of the
/// reach, random axis) or a sequence of targets of random kinds.
#[derive(Clone, Debug)]
enum Path {
    Circle {
        axis: DVec3,
        radius: f64,
        frames: usize,
    },
    Jumps(Vec<targets::TargetSpec>),
}

fn path() -> impl Strategy<Value = Path> {
    prop_oneof![
        (direction(), 0.0f64..1.5, 1usize..=60).prop_map(|(axis, radius, frames)| Path::Circle {
            axis,
            radius,
            frames
        }),
        prop::collection::vec(targets::target(), 1..=30).prop_map(Path::Jumps),
    ]
}

fn any_case() -> impl Strategy<Value = (Skeleton, Pose, Chain)> {
    prop_oneof![
        chains::chain().prop_map(|c: ChainCase| (c.skeleton, c.pose, c.chain)),
        chains::tree().prop_map(|t: TreeCase| (t.skeleton, t.pose, t.chain)),
    ]
}

proptest! {
    #![proptest_config(config::standard())]

    /// Bone lengths kept and no NaN on every frame of a tracked trajectory, for every
    /// solver, cap, tolerance and rotation limit; each record's bone-length error and
    /// final error are the true ones.
    #[test]
    fn tracking_keeps_bone_lengths_on_every_frame(
        (skeleton, start, chain) in any_case(),
        kind in solver_kind(),
        solve in settings(),
        limit in prop_oneof![Just(None), log_uniform(-3.0, 0.5).prop_map(Some)],
        path in path(),
    ) {
        let first = fk(&skeleton, &start);
        let base = first.positions[chain.base()];
        let frame_targets: Vec<DVec3> = match &path {
            Path::Circle { axis, radius, frames } => {
                let arm = axis.any_orthonormal_vector() * (radius * chain.reach());
                (0..*frames)
                    .map(|i| base + DQuat::from_axis_angle(*axis, TAU * i as f64 / *frames as f64) * arm)
                    .collect()
            }
            Path::Jumps(specs) => specs.iter().map(|s| s.place(&chain, &first)).collect(),
        };
        let mut tracker = Tracker::new(TrackSettings { solve, max_rotation_change: limit })
            .map_err(|e| TestCaseError::fail(e.to_string()))?;
        let mut solver = make_solver(kind);
        let mut pose = start.clone();
        let mut global = first.clone();
        for (frame, &target) in frame_targets.iter().enumerate() {
            let record = tracker
                .step(solver.as_mut(), &skeleton, &chain, &mut IkState::new(&mut pose, &mut global), EffectorGoal::at(chain.effector(), target))
                .map_err(|e| TestCaseError::fail(format!("frame {frame}: {e}")))?;
            prop_assert!(pose.rotations.iter().all(|q| q.is_finite()), "frame {}: NaN rotation", frame);
            prop_assert!(global.positions.iter().all(|p| p.is_finite()), "frame {}: NaN position", frame);
            let fresh = fk(&skeleton, &pose);
            if let Some(v) = skeleton_bone_violation(&skeleton, &fresh.positions) {
                return Err(TestCaseError::fail(format!("frame {frame}: {v:?}")));
            }
            prop_assert_eq!(&fresh.positions, &global.positions, "frame {}: global is not FK", frame);
            let reached = global.positions[chain.effector()].distance(target);
            prop_assert_eq!(record.error, reached, "frame {}", frame);
            let worst = chain
                .joints()
                .windows(2)
                .zip(chain.bone_lengths())
                .map(|(j, &rest)| (global.positions[j[1]].distance(global.positions[j[0]]) - rest).abs())
                .fold(0.0, f64::max);
            prop_assert_eq!(record.bone_length_error, worst, "frame {}", frame);
            if let (Some(limit), true) = (limit, frame > 0) {
                prop_assert!(record.rotation_change <= limit * (1.0 + 1e-9) + 1e-12,
                    "frame {frame}: joint turned {} > limit {limit}", record.rotation_change);
            }
        }
        prop_assert_eq!(tracker.summary().frames, frame_targets.len());
    }
}
