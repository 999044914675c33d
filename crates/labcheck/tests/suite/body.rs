//! Properties of the full-body solvers (sinew-ik-body) on random trees, joint limits and
//! goal sets: no limit is ever violated, the report equals forward kinematics of the
//! returned pose, pinned effectors stay where they were, and the weighted error never ends
//! above the start. Each property is listed with its reason in docs/labcheck.md.

use proptest::prelude::*;
use sinew_ik_body::{BodyEffector, BodyProblem, BodySolverOptions, BodyState, PIN_WEIGHT};
use sinew_labcheck::config;
use sinew_labcheck::strategies::chains::{self, TreeCase};
use sinew_labcheck::strategies::{SplitMix64, log_uniform};
use sinew_math::DVec3;
use sinew_skeleton::ik::{EffectorGoal, SolveSettings, rotation_angle};
use sinew_skeleton::limits::JointLimit;
use sinew_skeleton::{GlobalPose, Pose, Skeleton};

/// A tree of 1 to 40 joints with a random limit on every joint, its pose projected inside
/// the limits (a solve's start), and a seed for the goals.
fn limited_tree() -> impl Strategy<Value = (Skeleton, Pose, u64)> {
    (
        chains::tree_with(1..=40),
        prop::collection::vec(chains::joint_limit(), 40),
        any::<u64>(),
    )
        .prop_map(|(case, limits, seed): (TreeCase, Vec<JointLimit>, u64)| {
            let mut skeleton = case.skeleton;
            let mut pose = case.pose;
            for (j, limit) in limits.into_iter().enumerate().take(skeleton.len()) {
                skeleton.set_limit(j, limit).expect("a valid limit");
                pose.rotations[j] = limit.project(pose.rotations[j]);
            }
            (skeleton, pose, seed)
        })
}

/// Up to five effectors on distinct joints: goals from forward kinematics of another
/// allowed pose (feasible), or random points around the tree, or pinned where the
/// effector stands; random weights (1e-3 to 1e3), rotation goals on some.
fn effectors(skeleton: &Skeleton, start: &GlobalPose, seed: u64) -> Vec<BodyEffector> {
    let mut rng = SplitMix64(seed);
    let n = skeleton.len();
    let other = Pose {
        rotations: (0..n)
            .map(|j| {
                skeleton
                    .limit(j)
                    .sample([rng.unit(), rng.unit(), rng.unit()])
            })
            .collect(),
    };
    let mut far = GlobalPose::new();
    skeleton
        .forward_kinematics(&other, &mut far)
        .expect("a valid pose");
    let size = start
        .positions
        .iter()
        .map(|p| p.distance(start.positions[0]))
        .fold(1e-3, f64::max);
    let count = 1 + (rng.unit() * 5.0) as usize;
    let mut taken = vec![false; n];
    let mut out = Vec::new();
    for _ in 0..count {
        let j = (rng.unit() * n as f64) as usize % n;
        if taken[j] {
            continue;
        }
        taken[j] = true;
        let kind = rng.unit();
        let weight = 10f64.powf(rng.symmetric() * 3.0);
        let effector = if kind < 0.2 {
            BodyEffector::pinned(j, start.positions[j])
        } else if kind < 0.6 {
            let mut goal = EffectorGoal::at(j, far.positions[j]).with_weights(weight, weight);
            if rng.unit() < 0.3 {
                goal = goal.with_rotation(far.rotations[j]);
            }
            BodyEffector::new(goal)
        } else {
            let point = start.positions[0] + rng.vector() * (2.0 * size);
            BodyEffector::new(EffectorGoal::at(j, point).with_weights(weight, 1.0))
        };
        out.push(effector);
    }
    out
}

/// The weighted cost, computed here independently of the library: squared position
/// errors and squared rotation angles, weighted by the squared weights (times
/// `PIN_WEIGHT^2` when pinned).
fn weighted_cost(effectors: &[BodyEffector], global: &GlobalPose) -> f64 {
    effectors
        .iter()
        .map(|e| {
            let scale = if e.pinned { PIN_WEIGHT } else { 1.0 };
            let g = &e.goal;
            let wp = g.position_weight * scale;
            let mut c = wp * wp * global.positions[g.joint].distance_squared(g.position);
            if let Some(q) = g.rotation
                && g.rotation_weight > 0.0
            {
                let wr = g.rotation_weight * scale;
                let angle = rotation_angle(global.rotations[g.joint], q);
                c += wr * wr * angle * angle;
            }
            c
        })
        .sum()
}

proptest! {
    #![proptest_config(config::with_cases(64))]

    /// Every body solver of the registry, on random limited trees and goal sets, with and
    /// without the root translating, at random caps: the returned pose is inside every
    /// limit, the report and the per-effector errors are those of forward kinematics of
    /// the returned pose (recomputed here), pinned effectors end within the tolerance of
    /// where they stood, the weighted cost (recomputed here) never ends above the start,
    /// and the iterations respect the cap.
    #[test]
    fn body_solves_keep_the_contract(
        (skeleton, pose, seed) in limited_tree(),
        which in 0..BodySolverOptions::NAMED.len(),
        root_translates in any::<bool>(),
        max_iterations in 0usize..=60,
        tolerance in log_uniform(-9.0, -3.0),
    ) {
        let mut start = GlobalPose::new();
        skeleton.forward_kinematics(&pose, &mut start).expect("a valid pose");
        let effectors = effectors(&skeleton, &start, seed);
        let settings = SolveSettings { max_iterations, tolerance, rotation_tolerance: tolerance };
        let problem = BodyProblem::new(&skeleton, &effectors, settings)
            .with_root_translation(root_translates);
        let mut solver = BodySolverOptions::NAMED[which].1.build().expect("valid options");
        let mut state = BodyState::rest(&skeleton);
        state.pose = pose.clone();
        let report = solver.solve(&problem, &mut state).expect("a valid problem");

        // No limit violated, nothing non-finite.
        for j in 0..skeleton.len() {
            let v = skeleton.limit(j).violation(state.pose.rotations[j]);
            prop_assert!(v <= 1e-12, "joint {}: violation {}", j, v);
        }
        prop_assert!(report.limit_violation <= 1e-12);
        prop_assert!(state.root_translation.is_finite());
        prop_assert!(root_translates || state.root_translation == DVec3::ZERO);

        // The report is forward kinematics of the returned pose.
        let mut fk = GlobalPose::new();
        skeleton.forward_kinematics(&state.pose, &mut fk).expect("a valid pose");
        for p in &mut fk.positions {
            *p += state.root_translation;
        }
        prop_assert_eq!(&fk.positions, &state.global.positions);
        prop_assert_eq!(&fk.rotations, &state.global.rotations);
        let mut worst: f64 = 0.0;
        for (e, (effector, errors)) in effectors.iter().zip(&state.effectors).enumerate() {
            let g = &effector.goal;
            let distance = fk.positions[g.joint].distance(g.position);
            prop_assert!((distance - errors.position).abs() <= 1e-12 * (1.0 + distance),
                "effector {}: {} vs {}", e, distance, errors.position);
            let angle = g.rotation.map_or(0.0, |q| rotation_angle(fk.rotations[g.joint], q));
            prop_assert!((angle - errors.rotation).abs() <= 1e-12, "effector {}", e);
            worst = worst.max(distance);
        }
        prop_assert!((worst - report.max_error).abs() <= 1e-12 * (1.0 + worst));

        // Pinned effectors stay where they stood.
        for effector in effectors.iter().filter(|e| e.pinned) {
            let j = effector.goal.joint;
            let drift = fk.positions[j].distance(start.positions[j]);
            prop_assert!(drift <= tolerance, "pinned joint {}: drift {}", j, drift);
        }

        // The weighted error never ends above the start.
        let before = weighted_cost(&effectors, &start);
        let after = weighted_cost(&effectors, &fk);
        // Round-off: the solver re-projects the (already projected) start, which moves it
        // by rounding; compare square roots with an allowance for positions of the
        // tree's size, weighted by the largest weight.
        let size = start.positions.iter().map(|p| p.length()).fold(1.0, f64::max);
        let weight = effectors
            .iter()
            .map(|e| e.goal.position_weight.max(e.goal.rotation_weight) * PIN_WEIGHT)
            .fold(1.0, f64::max);
        prop_assert!(after.sqrt() <= before.sqrt() * (1.0 + 1e-12) + 1e-12 * size * weight,
            "{} > {}", after, before);
        prop_assert!(report.iterations <= max_iterations,
            "{} iterations for a cap of {}", report.iterations, max_iterations);
    }
}
