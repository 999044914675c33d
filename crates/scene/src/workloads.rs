//! The reference workloads of docs/workloads.md that are built in code, in one place,
//! so every figure of the benchmark and the stress grid uses the same chains, targets
//! and cloths:
//!
//! - W1 (the lab flower tracked by the lab chain): [`w1_skeleton`], [`w1_targets`];
//! - W2 (10 000 seeded cold solves of a 10-joint chain): [`w2_skeleton`], [`w2_targets`];
//! - W4, W5, W6 (the lab cloth, stiff, and 101 x 101): [`cloth`];
//! - W7 (the human arm with joint limits): [`w7_skeleton`], [`w7_feasible`], [`w7_ball`].
//!
//! The others are scene files: W3 (a target out of reach) is `scenes/ik-too-far.ron`;
//! the contact workloads C1, C2 and C3 are `scenes/cloth-ground.ron`,
//! `scenes/cloth-drape-sphere.ron` and `scenes/cloth-rotating-sphere.ron`. W8 (a
//! humanoid with five effectors) and C4, C5 (self-contact) have no code here yet.
//!
//! The W2 targets come from splitmix64 with the seed of sinew-ik-fabrik's tests and
//! benchmarks (`W2_SEED`), which gives 8 554 reachable targets of 10 000.

use sinew_math::{DQuat, DVec3};
use sinew_skeleton::{GlobalPose, Skeleton};
use sinew_spring_sim::{ClothGrid, SpringSystem};
use std::f64::consts::TAU;

/// W1: 8 joints, root offset (0, 0.5, 0), joints 1..7 offset (0.15, 0, 0). Reach 1.05.
pub fn w1_skeleton() -> Result<Skeleton, String> {
    Skeleton::chain(DVec3::new(0.0, 0.5, 0.0), &[DVec3::new(0.15, 0.0, 0.0); 7])
        .map_err(|e| format!("W1 chain: {e}"))
}

/// W1 targets: `count` points of the lab flower `a(6 cos t - cos 6t), 0,
/// a(6 sin t - sin 6t)`, a = 0.1, at `t = 2 pi i / count`.
pub fn w1_targets(count: usize) -> Vec<DVec3> {
    let a = 0.1;
    (0..count)
        .map(|i| {
            let t = TAU * i as f64 / count as f64;
            DVec3::new(
                a * (6.0 * t.cos() - (6.0 * t).cos()),
                0.0,
                a * (6.0 * t.sin() - (6.0 * t).sin()),
            )
        })
        .collect()
}

/// W2 (and W3): 10 joints, root at the origin, joints 1..9 offset (0.1, 0, 0). Reach 0.9.
pub fn w2_skeleton() -> Result<Skeleton, String> {
    Skeleton::chain(DVec3::ZERO, &[DVec3::new(0.1, 0.0, 0.0); 9])
        .map_err(|e| format!("W2 chain: {e}"))
}

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
pub fn w2_targets(count: usize) -> Vec<DVec3> {
    let mut rng = SplitMix64(W2_SEED);
    (0..count).map(|_| in_ball(&mut rng, 0.95)).collect()
}

/// W7: the human arm with joint limits ([`sinew_ik::workloads::human_arm`]).
pub fn w7_skeleton() -> Result<Skeleton, String> {
    sinew_ik::workloads::human_arm().map_err(|e| format!("W7 arm: {e}"))
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
pub fn w7_ball(count: usize) -> Vec<DVec3> {
    let mut rng = SplitMix64(W7_SEED + 1);
    (0..count).map(|_| in_ball(&mut rng, 0.63)).collect()
}

/// A cloth workload: a system, a time step and a step count.
pub struct ClothWorkload {
    /// The workload and its variant, e.g. "W5 k=1e6".
    pub name: &'static str,
    /// The system at the start.
    pub system: SpringSystem,
    /// Time step in seconds.
    pub dt: f64,
    /// Steps to take.
    pub steps: usize,
}

/// W4 (the lab cloth, damping 0 and 0.2), W5 (k = 1e4 and 1e6) and W6 (101 x 101),
/// W5 and W6 with the lab's damping 0.2 as in their scenes; `quick` gives the reduced
/// set a smoke run uses (W4 with damping 0.2 and W5 with k = 1e6, a tenth of the steps).
pub fn cloth(quick: bool) -> Result<Vec<ClothWorkload>, String> {
    // (name, particles per side, spacing, damping, stiffness, dt, steps).
    let specs: &[(&'static str, usize, f64, f64, f64, f64, usize)] = if quick {
        &[
            ("W4 d=0.2", 11, 0.2, 0.2, 100.0, 1.0 / 60.0, 60),
            ("W5 k=1e6", 11, 0.2, 0.2, 1e6, 1.0 / 30.0, 30),
        ]
    } else {
        &[
            ("W4 d=0", 11, 0.2, 0.0, 100.0, 1.0 / 60.0, 600),
            ("W4 d=0.2", 11, 0.2, 0.2, 100.0, 1.0 / 60.0, 600),
            ("W5 k=1e4", 11, 0.2, 0.2, 1e4, 1.0 / 30.0, 300),
            ("W5 k=1e6", 11, 0.2, 0.2, 1e6, 1.0 / 30.0, 300),
            ("W6", 101, 0.02, 0.2, 100.0, 1.0 / 60.0, 30),
        ]
    };
    specs
        .iter()
        .map(|&(name, size, spacing, damping, stiffness, dt, steps)| {
            let mut grid = ClothGrid::lab_sized(size, spacing).with_damping(damping);
            grid.material.stiffness = stiffness;
            let system = grid.build().map_err(|e| format!("{name}: {e}"))?;
            Ok(ClothWorkload {
                name,
                system,
                dt,
                steps,
            })
        })
        .collect()
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
    fn w1_targets_lie_on_the_flower() {
        let t = w1_targets(500);
        assert_eq!(t.len(), 500);
        // t = 0: a(6 - 1, 0, 0) = (0.5, 0, 0).
        assert!((t[0] - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-15);
        assert_eq!(w1_skeleton().unwrap().len(), 8);
    }
}
