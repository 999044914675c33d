//! Reference skeletons with joint limits that the tests, the benchmarks and the scene
//! runner share, so each is written once: the human arm (called W7 in the benchmark
//! reports) and poses drawn uniformly inside a skeleton's limits.

use sinew_math::{DQuat, DVec3};
use sinew_skeleton::limits::{Hinge, JointLimit, SwingTwist};
use sinew_skeleton::{JointDef, Pose, Skeleton, SkeletonError};

/// A human arm in T-pose along +x, Y up, the character facing +z, identity rest
/// rotations: joint 0 the shoulder at the origin; 1 the elbow, offset (0.30, 0, 0);
/// 2 the forearm twist, (0.125, 0, 0); 3 the wrist, (0.125, 0, 0); 4 the hand tip (the
/// effector), (0.08, 0, 0).
///
/// Limits, relative to the rest rotation (swing-twist with the twist about the bone, +x,
/// and the swing half-angle `a` about local z, `b` about local y): shoulder a 100, b 70
/// degrees, twist +-80; elbow a hinge about (0, -1, 0) from 0 to 150 degrees (it bends
/// towards +z); forearm a hinge about +x, +-80; wrist a 80, b 30, twist +-10.
pub fn human_arm() -> Result<Skeleton, SkeletonError> {
    let deg = f64::to_radians;
    let swing_twist = |a: f64, b: f64, twist: f64| {
        JointLimit::SwingTwist(SwingTwist {
            twist_axis: DVec3::X,
            a_axis: DVec3::Z,
            swing_a: deg(a),
            swing_b: deg(b),
            twist_min: -deg(twist),
            twist_max: deg(twist),
        })
    };
    let hinge = |axis: DVec3, min: f64, max: f64| {
        JointLimit::Hinge(Hinge {
            axis,
            min: deg(min),
            max: deg(max),
        })
    };
    let joint = |name: &str, parent: Option<usize>, offset: DVec3, limit: JointLimit| JointDef {
        name: Some(name.into()),
        parent,
        offset,
        limit,
    };
    Skeleton::new([
        joint(
            "shoulder",
            None,
            DVec3::ZERO,
            swing_twist(100.0, 70.0, 80.0),
        ),
        joint(
            "elbow",
            Some(0),
            DVec3::new(0.30, 0.0, 0.0),
            hinge(DVec3::NEG_Y, 0.0, 150.0),
        ),
        joint(
            "forearm",
            Some(1),
            DVec3::new(0.125, 0.0, 0.0),
            hinge(DVec3::X, -80.0, 80.0),
        ),
        joint(
            "wrist",
            Some(2),
            DVec3::new(0.125, 0.0, 0.0),
            swing_twist(80.0, 30.0, 10.0),
        ),
        joint(
            "hand",
            Some(3),
            DVec3::new(0.08, 0.0, 0.0),
            JointLimit::Free,
        ),
    ])
}

/// A pose with every limited joint's rotation drawn uniformly in its limit's parameters
/// ([`JointLimit::sample`], three draws of `uniform` per limited joint, in joint order)
/// and every free joint at the identity. `uniform` must return numbers in `[0, 1)`.
pub fn allowed_pose(skeleton: &Skeleton, mut uniform: impl FnMut() -> f64) -> Pose {
    Pose {
        rotations: (0..skeleton.len())
            .map(|j| match skeleton.limit(j) {
                JointLimit::Free => DQuat::IDENTITY,
                limit => limit.sample([uniform(), uniform(), uniform()]),
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_arm_is_valid_and_its_reach_is_the_sum_of_its_bones() {
        let arm = human_arm().unwrap();
        assert_eq!(arm.len(), 5);
        let reach: f64 = (1..5).map(|j| arm.bone_length(j)).sum();
        assert!((reach - 0.63).abs() < 1e-15);
        for j in 0..5 {
            if let JointLimit::Free = arm.limit(j) {
                continue;
            }
            arm.limit(j).validate().unwrap();
        }
    }

    #[test]
    fn allowed_poses_are_inside_the_limits() {
        let arm = human_arm().unwrap();
        let mut k = 0u32;
        // A deterministic sweep of the unit cube's corners and middles.
        let pose = allowed_pose(&arm, || {
            k += 1;
            f64::from(k % 3) * 0.49
        });
        for j in 0..arm.len() {
            assert!(arm.limit(j).violation(pose.rotations[j]) <= 1e-12);
        }
    }
}
