//! The seeded parts of the reference workloads (docs/workloads.md), drawn with the
//! property suite's generator so the benchmark, the stress grid and the property tests
//! share one implementation of it:
//!
//! - W2 (10 000 seeded cold solves of a 10-joint chain): [`w2_targets`];
//! - W7 (the human arm with joint limits): [`w7_feasible`], [`w7_ball`].
//!
//! The chains, the W1 targets and the cloths are built from fixed numbers alone and live
//! in [`sinew_scene::workloads`].
//!
//! The W2 targets come from splitmix64 with the seed of sinew-ik-fabrik's tests and
//! benchmarks (`W2_SEED`), which gives 8 554 reachable targets of 10 000.

use sinew_math::{DQuat, DVec3};
use sinew_skeleton::{GlobalPose, Skeleton};

/// The seed of the W2 targets (the same as sinew-ik-fabrik's workloads).
pub const W2_SEED: u64 = 0x5EED_0000_0000_0002;

/// The seeded generator of the workloads: labcheck's splitmix64, one implementation for
/// the property suite, the benchmarks and the stress grid.
pub use sinew_labcheck::strategies::SplitMix64;

/// Uniform in the ball of radius `r` about the origin (rejection from the cube).
pub fn in_ball(rng: &mut SplitMix64, r: f64) -> DVec3 {
    loop {
        let v = rng.vector();
        if v.length_squared() <= 1.0 {
            return r * v;
        }
    }
}

/// W2 targets: the first `count` points uniform in the ball of radius 0.95 about the
/// origin (rejection from the cube), from [`W2_SEED`].
#[must_use]
pub fn w2_targets(count: usize) -> Vec<DVec3> {
    let mut rng = SplitMix64(W2_SEED);
    (0..count).map(|_| in_ball(&mut rng, 0.95)).collect()
}

/// The seed of the W7 poses and ball points.
pub const W7_SEED: u64 = 0x5EED_0000_0000_0007;

/// W7 feasible set: forward kinematics of the hand tip (position and global rotation) of
/// `count` poses uniform in every joint's limit parameters, from [`W7_SEED`].
pub fn w7_feasible(skeleton: &Skeleton, count: usize) -> Result<Vec<(DVec3, DQuat)>, String> {
    let mut rng = SplitMix64(W7_SEED);
    let mut global = GlobalPose::new();
    let effector = skeleton.len() - 1;
    (0..count)
        .map(|_| {
            let pose = sinew_ik::workloads::allowed_pose(skeleton, || rng.unit());
            skeleton
                .forward_kinematics(&pose, &mut global)
                .map_err(|e| e.to_string())?;
            Ok((global.positions[effector], global.rotations[effector]))
        })
        .collect()
}

/// W7 ball set: `count` points uniform in the ball of radius 0.63 (the arm's reach)
/// about the shoulder, from the seed after [`W7_SEED`].
#[must_use]
pub fn w7_ball(count: usize) -> Vec<DVec3> {
    let mut rng = SplitMix64(W7_SEED + 1);
    (0..count).map(|_| in_ball(&mut rng, 0.63)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn w2_has_the_documented_reachable_count_and_is_in_the_ball() {
        let targets = w2_targets(10_000);
        assert!(targets.iter().all(|p| p.length() <= 0.95 + 1e-15));
        let reachable = targets.iter().filter(|p| p.length() <= 0.9).count();
        assert_eq!(reachable, 8_554);
        // Uniform in the ball: the share within 0.9 is (0.9/0.95)^3 = 0.8503.
        assert!((reachable as f64 / 1e4 - 0.8503).abs() < 0.01);
    }

    #[test]
    fn w7_sets_are_in_reach_and_seeded() {
        let arm = sinew_scene::workloads::w7_skeleton().unwrap();
        let feasible = w7_feasible(&arm, 200).unwrap();
        assert_eq!(feasible, w7_feasible(&arm, 200).unwrap());
        let shoulder = arm.offset(0);
        for (p, q) in &feasible {
            assert!((*p - shoulder).length() <= 0.63 + 1e-12);
            assert!((q.length() - 1.0).abs() < 1e-12);
        }
        assert!(w7_ball(500).iter().all(|p| p.length() <= 0.63 + 1e-15));
    }
}
