//! Pole goals through the registry, both solvers: the chain's bend plane turns towards
//! the pole while the effector stays on its target.

use sinew_ik::SolverOptions;
use sinew_math::DVec3;
use sinew_skeleton::ik::{Chain, EffectorGoal, IkProblem, IkState, SolveSettings};
use sinew_skeleton::{GlobalPose, Skeleton};

/// The angle, seen along the base-effector line, between the chain's bend direction
/// (the sum of the interior joints' offsets across the line) and the pole.
fn bend_to_pole(global: &GlobalPose, chain: &Chain, pole: DVec3) -> f64 {
    let base = global.positions[chain.base()];
    let axis = (global.positions[chain.effector()] - base).normalize();
    let across = |v: DVec3| v - axis * axis.dot(v);
    let joints = chain.joints();
    let bend: DVec3 = joints[1..joints.len() - 1]
        .iter()
        .map(|&j| across(global.positions[j] - base))
        .sum();
    sinew_math::angle_between(bend, across(pole - base))
}

#[test]
fn the_bend_plane_turns_towards_the_pole_and_the_effector_stays() {
    for bones in [2, 4] {
        let skeleton =
            Skeleton::chain(DVec3::ZERO, &vec![DVec3::X * (1.0 / bones as f64); bones]).unwrap();
        let chain = Chain::whole(&skeleton).unwrap();
        let target = DVec3::new(0.5, 0.3, 0.1);
        for pole in [
            DVec3::new(0.0, 0.0, 2.0),
            DVec3::new(0.3, -1.0, 0.0),
            DVec3::new(-1.0, 0.5, -0.5),
        ] {
            for (name, options) in SolverOptions::NAMED {
                let mut solver = options.build().unwrap();
                let goals = [EffectorGoal::at(chain.effector(), target).with_pole(pole)];
                let problem = IkProblem::new(&skeleton, &chain, &goals, SolveSettings::default());
                let mut pose = skeleton.rest_pose();
                // A bent start, so the chain has a bend plane to turn.
                pose.rotations[1] = sinew_math::DQuat::from_rotation_z(0.5);
                let mut global = GlobalPose::new();
                let report = solver
                    .solve(&problem, &mut IkState::new(&mut pose, &mut global))
                    .unwrap();
                let what = format!("{bones} bones, {name}, pole {pole}: {report:?}");
                assert!(report.error <= 1e-6, "{what}");
                let mut fresh = GlobalPose::new();
                skeleton.forward_kinematics(&pose, &mut fresh).unwrap();
                assert_eq!(fresh.positions, global.positions, "{what}");
                let angle = bend_to_pole(&global, &chain, pole);
                assert!(angle < 1e-9, "{what}: bend {angle} rad from the pole");
            }
        }
    }
}

#[test]
fn a_goal_too_far_to_measure_is_refused_by_every_solver() {
    // A coordinate of 1e200 is finite, but the square of the distance overflows: no
    // solver could report a finite error. 1e150 still squares within f64, so it is
    // solved (out of reach: the chain is straightened towards it).
    let skeleton = Skeleton::chain(DVec3::ZERO, &[DVec3::X * 0.5; 3]).unwrap();
    let chain = Chain::whole(&skeleton).unwrap();
    for (name, options) in SolverOptions::NAMED {
        let mut solver = options.build().unwrap();
        for far in [
            DVec3::new(1e200, 0.0, 0.0),
            DVec3::new(0.0, -1e300, 1.0),
            DVec3::splat(f64::MAX),
        ] {
            let goals = [EffectorGoal::at(chain.effector(), far)];
            let problem = IkProblem::new(&skeleton, &chain, &goals, SolveSettings::default());
            let mut pose = skeleton.rest_pose();
            let kept = pose.clone();
            let mut global = GlobalPose::new();
            let err = solver
                .solve(&problem, &mut IkState::new(&mut pose, &mut global))
                .unwrap_err();
            let message = err.to_string();
            assert!(
                message.contains("goal 0: position") && message.contains("overflows"),
                "{name}, {far}: {message}"
            );
            assert_eq!(pose, kept, "{name}: a refused solve leaves the pose");
        }
        let near = [EffectorGoal::at(
            chain.effector(),
            DVec3::new(1e150, 0.0, 0.0),
        )];
        let problem = IkProblem::new(&skeleton, &chain, &near, SolveSettings::default());
        let mut pose = skeleton.rest_pose();
        let mut global = GlobalPose::new();
        let report = solver
            .solve(&problem, &mut IkState::new(&mut pose, &mut global))
            .unwrap();
        assert!(report.error.is_finite(), "{name}: {report:?}");
        assert!(
            (report.error - (1e150 - 1.5)).abs() <= 1e135,
            "{name}: {report:?}"
        );
    }
}
