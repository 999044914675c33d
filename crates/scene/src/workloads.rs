//! The reference workloads that are built in code from fixed numbers alone, in one
//! place, so every figure of the benchmark and the stress grid uses the same chains,
//! targets and cloths:
//!
//! - W1 (the lab flower tracked by the lab chain): [`w1_skeleton`], [`w1_targets`];
//! - W2 (10 000 seeded cold solves of a 10-joint chain): the chain, [`w2_skeleton`];
//! - W4, W5, W6 (the lab cloth, stiff, and 101 x 101): [`cloth`];
//! - W7 (the human arm with joint limits): the arm, [`w7_skeleton`].
//!
//! The seeded parts (the W2 targets, the W7 poses and ball points) are drawn with the
//! property suite's generator and live beside the benchmark in the unpublished
//! sinew-bench crate, so this crate needs no test-only dependency. The others are scene
//! files: W3 (a target out of reach) is `scenes/ik-too-far.ron`; W8 (a humanoid with
//! five effectors) is `scenes/ik-full-body.ron`; the contact workloads C1, C2 and C3 are
//! `scenes/cloth-ground.ron`, `scenes/cloth-drape-sphere.ron` and
//! `scenes/cloth-rotating-sphere.ron`.

use sinew_math::DVec3;
use sinew_skeleton::Skeleton;
use sinew_spring_sim::{ClothGrid, SpringSystem};
use std::f64::consts::TAU;

/// W1: 8 joints, root offset (0, 0.5, 0), joints 1..7 offset (0.15, 0, 0). Reach 1.05.
pub fn w1_skeleton() -> Result<Skeleton, String> {
    Skeleton::chain(DVec3::new(0.0, 0.5, 0.0), &[DVec3::new(0.15, 0.0, 0.0); 7])
        .map_err(|e| format!("W1 chain: {e}"))
}

/// W1 targets: `count` points of the lab flower `a(6 cos t - cos 6t), 0,
/// a(6 sin t - sin 6t)`, a = 0.1, at `t = 2 pi i / count`.
#[must_use]
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

/// W7: the human arm with joint limits ([`sinew_ik::workloads::human_arm`]).
pub fn w7_skeleton() -> Result<Skeleton, String> {
    sinew_ik::workloads::human_arm().map_err(|e| format!("W7 arm: {e}"))
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
    fn w1_targets_lie_on_the_flower() {
        let t = w1_targets(500);
        assert_eq!(t.len(), 500);
        // t = 0: a(6 - 1, 0, 0) = (0.5, 0, 0).
        assert!((t[0] - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-15);
        // Every point is on the flower: |p|^2 = a^2 (37 - 12 cos 5t).
        for (i, p) in t.iter().enumerate() {
            let s = TAU * i as f64 / 500.0;
            let expected = 0.01 * (37.0 - 12.0 * (5.0 * s).cos());
            assert!((p.length_squared() - expected).abs() < 1e-14, "target {i}");
        }
        assert_eq!(w1_skeleton().unwrap().len(), 8);
    }

    #[test]
    fn the_chains_have_the_documented_reach() {
        let reach = |s: &Skeleton| (1..s.len()).map(|i| s.offset(i).length()).sum::<f64>();
        assert!((reach(&w1_skeleton().unwrap()) - 1.05).abs() < 1e-12);
        assert!((reach(&w2_skeleton().unwrap()) - 0.9).abs() < 1e-12);
    }

    #[test]
    fn the_quick_cloth_set_is_a_subset_of_the_full_one() {
        let full = cloth(false).unwrap();
        let quick = cloth(true).unwrap();
        assert_eq!(full.len(), 5);
        assert_eq!(full[4].system.len(), 101 * 101);
        for q in &quick {
            let f = full.iter().find(|f| f.name == q.name).unwrap();
            assert_eq!((q.dt, q.system.len()), (f.dt, f.system.len()), "{}", q.name);
            assert!(q.steps < f.steps);
        }
    }
}
