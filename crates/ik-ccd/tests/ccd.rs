//! Integration tests of the CCD solver against exact answers: the hand-computed local
//! composition, the closed-form straight chain, the sweep's monotone error, bone lengths
//! over long tracking runs with the shared tracker, and every degenerate case.

#[path = "../benches/common/mod.rs"]
mod common;

use sinew_ik_ccd::CcdSolver;
use sinew_math::{DQuat, DVec3, angle_between};
use sinew_skeleton::ik::{
    Chain, IkError, IkSolver, IkState, SolveReport, SolveSettings, StopReason, rotation_angle,
};
use sinew_skeleton::track::{TrackSettings, TrackSummary, Tracker, track};
use sinew_skeleton::{GlobalPose, JointDef, Pose, Skeleton};
use std::f64::consts::{FRAC_PI_2, TAU};

fn settings(max_iterations: usize, tolerance: f64) -> SolveSettings {
    SolveSettings {
        max_iterations,
        tolerance,
        ..Default::default()
    }
}

/// The invariants every solve must keep: finite pose, `global` is FK of `pose`, bone
/// lengths kept, the error reported is the true one and not above the initial one.
fn check_solution(
    skel: &Skeleton,
    chain: &Chain,
    pose: &Pose,
    global: &GlobalPose,
    target: DVec3,
    report: &SolveReport,
) {
    assert!(pose.rotations.iter().all(|q| q.is_finite()), "{report:?}");
    let mut fresh = GlobalPose::new();
    skel.forward_kinematics(pose, &mut fresh).unwrap();
    assert_eq!(fresh.positions, global.positions);
    let error = global.positions[chain.effector()].distance(target);
    assert_eq!(report.error, error);
    assert!(report.error <= report.initial_error, "{report:?}");
    for i in 1..skel.len() {
        if let Some(p) = skel.parent(i) {
            let length = global.positions[i].distance(global.positions[p]);
            let rest = skel.bone_length(i);
            assert!((length - rest).abs() <= 1e-12 * rest.max(1e-3), "bone {i}");
        }
    }
}

/// Solves `chain` towards `target` and checks the solution's invariants.
fn solve_chain(
    solver: &mut CcdSolver,
    skel: &Skeleton,
    chain: &Chain,
    pose: &mut Pose,
    global: &mut GlobalPose,
    target: DVec3,
    s: &SolveSettings,
) -> SolveReport {
    let report = solver
        .solve_position(skel, chain, pose, global, target, s)
        .unwrap();
    check_solution(skel, chain, pose, global, target, &report);
    report
}

/// [`solve_chain`] on the whole skeleton with a fresh global pose.
fn solve(
    solver: &mut CcdSolver,
    skel: &Skeleton,
    pose: &mut Pose,
    target: DVec3,
    s: SolveSettings,
) -> SolveReport {
    let chain = Chain::whole(skel).unwrap();
    solve_chain(
        solver,
        skel,
        &chain,
        pose,
        &mut GlobalPose::new(),
        target,
        &s,
    )
}

/// Tracks `targets` with the default solver from the rest pose along the whole skeleton.
fn track_from_rest(tracker: &mut Tracker, skel: &Skeleton, targets: &[DVec3]) -> TrackSummary {
    let chain = Chain::whole(skel).unwrap();
    let mut pose = skel.rest_pose();
    let mut global = GlobalPose::new();
    track(
        tracker,
        &mut CcdSolver::new(),
        skel,
        &chain,
        &mut IkState::new(&mut pose, &mut global),
        targets,
    )
    .unwrap()
}

/// Two unit bones, the root turned a quarter about z so the chain points along +y:
/// joints at (0,0,0), (0,1,0), (0,2,0). Target (0,1,1): at joint 1 the world rotation
/// is a quarter about x. Composed in the local frame it is G0^-1 q G0, a quarter about
/// -y, and puts the effector on the target in one step. The lab's composition `q L[1]`
/// turns the bone about its own axis instead and leaves the effector where it was.
#[test]
fn the_turn_is_composed_in_the_local_frame_not_onto_the_local_rotation() {
    let skel = Skeleton::chain(DVec3::ZERO, &[DVec3::X, DVec3::X]).unwrap();
    let chain = Chain::whole(&skel).unwrap();
    let mut pose = skel.rest_pose();
    let root = DQuat::from_rotation_z(FRAC_PI_2);
    pose.rotations[0] = root;
    let mut global = GlobalPose::new();
    skel.forward_kinematics(&pose, &mut global).unwrap();
    let target = DVec3::new(0.0, 1.0, 1.0);
    let error = CcdSolver::plain()
        .sweep(&skel, &chain, &mut pose, &mut global, target)
        .unwrap();
    assert!(error < 1e-15, "{error}");
    let expected = DQuat::from_rotation_y(-FRAC_PI_2);
    assert!(rotation_angle(pose.rotations[1], expected) < 1e-15);
    // The root did not need to move.
    assert!(rotation_angle(pose.rotations[0], root) < 1e-15);
    // What the lab's composition gives: L[1] = q L[1] with q the world quarter about x.
    let mut wrong = skel.rest_pose();
    wrong.rotations[0] = root;
    wrong.rotations[1] = DQuat::from_rotation_x(FRAC_PI_2);
    let mut g = GlobalPose::new();
    skel.forward_kinematics(&wrong, &mut g).unwrap();
    assert!(g.positions[2].distance(DVec3::new(0.0, 2.0, 0.0)) < 1e-15);
    assert!((g.positions[2].distance(target) - 2f64.sqrt()).abs() < 1e-15);
}

#[test]
fn a_sweep_never_increases_the_error() {
    let skel = common::w2_skeleton();
    let chain = Chain::whole(&skel).unwrap();
    let solvers = [
        CcdSolver::plain(),
        CcdSolver::with_relaxation(1.5).unwrap(),
        CcdSolver::with_relaxation(1.9).unwrap(),
    ];
    let mut global = GlobalPose::new();
    for solver in &solvers {
        for &target in common::w2_targets(200).iter() {
            let mut pose = skel.rest_pose();
            skel.forward_kinematics(&pose, &mut global).unwrap();
            let mut error = global.positions[chain.effector()].distance(target);
            for _ in 0..30 {
                let next = solver
                    .sweep(&skel, &chain, &mut pose, &mut global, target)
                    .unwrap();
                // Exact arithmetic gives next <= error; allow rounding of positions
                // of size ~1.
                assert!(
                    next <= error + 8.0 * f64::EPSILON,
                    "omega {}: {next:e} > {error:e} for {target}",
                    solver.relaxation()
                );
                error = next;
            }
        }
    }
}

#[test]
fn solves_never_report_more_than_the_initial_error_and_say_why_they_stopped() {
    let skel = common::w2_skeleton();
    let reach = 0.9;
    for mut solver in [CcdSolver::new(), CcdSolver::plain()] {
        for &target in common::w2_targets(300).iter() {
            let mut pose = skel.rest_pose();
            let report = solve(&mut solver, &skel, &mut pose, target, settings(100, 1e-6));
            match report.stop {
                StopReason::Converged => assert!(report.error <= 1e-6),
                StopReason::OutOfReach => {
                    assert!(target.length() >= reach);
                    assert_eq!(report.iterations, 0);
                    assert!((report.error - (target.length() - reach)).abs() < 1e-12);
                }
                StopReason::IterationCap => assert_eq!(report.iterations, 100),
                StopReason::Stalled => assert!(report.iterations <= 100),
                StopReason::LocalMinimum => panic!("a chain without limits: {report:?}"),
            }
        }
    }
}

#[test]
fn w3_gives_the_straight_chain() {
    let skel = common::w2_skeleton();
    let chain = Chain::whole(&skel).unwrap();
    let mut pose = skel.rest_pose();
    let mut global = GlobalPose::new();
    let target = common::W3_TARGET;
    let report = solve_chain(
        &mut CcdSolver::new(),
        &skel,
        &chain,
        &mut pose,
        &mut global,
        target,
        &SolveSettings::default(),
    );
    assert_eq!(report.stop, StopReason::OutOfReach);
    assert_eq!(report.iterations, 0);
    assert!((report.error - (target.length() - chain.reach())).abs() < 1e-12);
    let bones: Vec<DVec3> = (1..skel.len())
        .map(|i| global.positions[i] - global.positions[i - 1])
        .collect();
    let largest = bones
        .windows(2)
        .map(|w| angle_between(w[0], w[1]))
        .fold(0.0, f64::max);
    assert!(largest < 1e-12, "{largest:e}");
}

/// Just inside the reach the solution is nearly the straight chain: with the effector
/// within `e` of a target at distance `D = L (1 - delta)` from the base, the bones'
/// projections onto the base-target line sum to at least `D - e`, so every bone `k`
/// satisfies `l_k (1 - cos theta_k) <= L delta + e`. CCD iterated to convergence must
/// meet that bound, which shrinks to the closed form (all angles 0) as delta -> 0.
#[test]
fn just_inside_the_reach_converges_to_the_closed_form() {
    let skel = common::w2_skeleton();
    let chain = Chain::whole(&skel).unwrap();
    let direction = DVec3::new(0.3, -0.5, 0.8).normalize();
    for delta in [1e-2, 1e-4, 1e-6, 1e-8] {
        let target = direction * chain.reach() * (1.0 - delta);
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        let report = solve_chain(
            &mut CcdSolver::new(),
            &skel,
            &chain,
            &mut pose,
            &mut global,
            target,
            &settings(100_000, 1e-10),
        );
        // Near full extension CCD crawls (docs/ik-ccd.md): 1e-10 is reached for
        // delta >= 1e-4, about 1e-6 after the cap for the closer ones.
        assert!(report.error <= 2e-6, "delta {delta}: {report:?}");
        for i in 1..skel.len() {
            let bone = global.positions[i] - global.positions[i - 1];
            let theta = angle_between(bone, direction);
            let bound = ((chain.reach() * delta + report.error) / 0.1).min(2.0);
            assert!(
                1.0 - theta.cos() <= bound * (1.0 + 1e-6) + 1e-15,
                "delta {delta}, bone {i}: angle {theta}"
            );
        }
    }
}

#[test]
fn within_tolerance_is_zero_iterations_and_untouched() {
    let skel = common::w1_skeleton();
    let mut pose = skel.rest_pose();
    pose.rotations[3] = DQuat::from_rotation_y(0.3);
    let before = pose.clone();
    let mut global = GlobalPose::new();
    skel.forward_kinematics(&pose, &mut global).unwrap();
    let target = global.positions[7] + DVec3::new(0.0, 5e-7, 0.0);
    let report = solve(
        &mut CcdSolver::new(),
        &skel,
        &mut pose,
        target,
        settings(100, 1e-6),
    );
    assert_eq!(report.iterations, 0);
    assert_eq!(report.stop, StopReason::Converged);
    assert_eq!(pose, before);
}

#[test]
fn nan_or_infinite_targets_are_errors() {
    let skel = common::w1_skeleton();
    let chain = Chain::whole(&skel).unwrap();
    let mut global = GlobalPose::new();
    for bad in [
        DVec3::new(f64::NAN, 0.0, 0.0),
        DVec3::new(0.0, f64::INFINITY, 0.0),
        DVec3::new(0.0, 0.0, f64::NEG_INFINITY),
    ] {
        let mut pose = skel.rest_pose();
        let solved = CcdSolver::new().solve_position(
            &skel,
            &chain,
            &mut pose,
            &mut global,
            bad,
            &SolveSettings::default(),
        );
        assert!(matches!(
            solved,
            Err(IkError::InvalidGoal {
                goal: 0,
                field: "position",
                ..
            })
        ));
        let swept = CcdSolver::new().sweep(&skel, &chain, &mut pose, &mut global, bad);
        assert!(matches!(swept, Err(IkError::NonFiniteTarget { .. })));
        assert_eq!(pose, skel.rest_pose());
    }
    // A pose of the wrong size is an error too, not a panic.
    let mut short = Pose {
        rotations: vec![DQuat::IDENTITY; 3],
    };
    let err = CcdSolver::new()
        .sweep(&skel, &chain, &mut short, &mut global, DVec3::X)
        .unwrap_err();
    assert!(err.to_string().contains("rotations"), "{err}");
}

#[test]
fn degenerate_cases_give_finite_poses_and_say_what_happened() {
    let skel = common::w2_skeleton();
    let s = settings(100, 1e-6);
    // Target on the base joint: no direction at the base; the chain folds towards it.
    let mut pose = skel.rest_pose();
    let report = solve(&mut CcdSolver::new(), &skel, &mut pose, DVec3::ZERO, s);
    assert!(report.error < report.initial_error, "{report:?}");
    // Target exactly on the chain: on a joint (that joint is skipped) and mid-bone.
    for target in [DVec3::new(0.3, 0.0, 0.0), DVec3::new(0.45, 0.0, 0.0)] {
        let mut pose = skel.rest_pose();
        let report = solve(&mut CcdSolver::new(), &skel, &mut pose, target, s);
        assert_eq!(report.stop, StopReason::Converged, "{target}: {report:?}");
    }
    // A straight chain pointing exactly away from the target: every joint sees the
    // effector and the target antiparallel and turns a defined half turn.
    let target = DVec3::new(-0.5, 0.0, 0.0);
    let mut pose = skel.rest_pose();
    let report = solve(
        &mut CcdSolver::plain(),
        &skel,
        &mut pose,
        target,
        settings(1, 0.0),
    );
    assert_eq!(
        (report.iterations, report.stop),
        (1, StopReason::IterationCap)
    );
    assert!(report.error < report.initial_error);
    let mut pose = skel.rest_pose();
    let report = solve(&mut CcdSolver::new(), &skel, &mut pose, target, s);
    assert_eq!(report.stop, StopReason::Converged, "{report:?}");
}

#[test]
fn zero_length_bones_and_an_effector_on_its_joint() {
    // Bones 2 and 4 have zero length; the last bone too, so the effector sits on the
    // joint before it (that joint sees no direction and is skipped).
    let offsets = [
        DVec3::X * 0.2,
        DVec3::ZERO,
        DVec3::X * 0.2,
        DVec3::ZERO,
        DVec3::X * 0.2,
        DVec3::ZERO,
    ];
    let skel = Skeleton::chain(DVec3::new(0.0, 1.0, 0.0), &offsets).unwrap();
    for target in [
        DVec3::new(0.1, 1.3, 0.2),
        DVec3::new(0.0, 1.0, 0.0),
        DVec3::new(-0.4, 1.0, 0.0),
        DVec3::new(0.0, 1.6, 0.0),
    ] {
        let mut pose = skel.rest_pose();
        let report = solve(
            &mut CcdSolver::new(),
            &skel,
            &mut pose,
            target,
            settings(100, 1e-6),
        );
        assert!(
            matches!(
                report.stop,
                StopReason::Converged | StopReason::OutOfReach | StopReason::Stalled
            ),
            "{target}: {report:?}"
        );
    }
}

#[test]
fn a_chain_inside_a_tree_moves_only_its_subtrees() {
    let joint = |parent: Option<usize>, offset: DVec3| JointDef {
        name: None,
        parent,
        offset,
        ..JointDef::default()
    };
    let skel = Skeleton::new([
        joint(None, DVec3::ZERO),
        joint(Some(0), DVec3::Y),       // 1: spine
        joint(Some(1), DVec3::X * 0.5), // 2: shoulder (chain base)
        joint(Some(0), -DVec3::Y),      // 3: other branch
        joint(Some(2), DVec3::X * 0.5), // 4: elbow
        joint(Some(4), DVec3::X * 0.5), // 5: hand (effector)
        joint(Some(4), DVec3::Z * 0.1), // 6: hangs off the elbow
    ])
    .unwrap();
    let chain = Chain::new(&skel, 2, 5).unwrap();
    let mut pose = skel.rest_pose();
    pose.rotations[1] = DQuat::from_rotation_z(0.4);
    let mut global = GlobalPose::new();
    skel.forward_kinematics(&pose, &mut global).unwrap();
    let before = global.clone();
    let target = global.positions[2] + DVec3::new(0.2, 0.5, 0.4);
    let report = solve_chain(
        &mut CcdSolver::new(),
        &skel,
        &chain,
        &mut pose,
        &mut global,
        target,
        &SolveSettings::default(),
    );
    assert_eq!(report.stop, StopReason::Converged);
    for i in [0, 1, 2, 3] {
        assert_eq!(global.positions[i], before.positions[i], "joint {i}");
    }
    assert_eq!(pose.rotations[5], DQuat::IDENTITY);
}

/// 10 000 frames around the flower (four laps of 2 500) with the shared tracker: every
/// frame converges and no bone drifts from its length (1e-12 relative).
#[test]
fn bone_lengths_hold_over_ten_thousand_tracked_frames() {
    let skel = common::w1_skeleton();
    let targets: Vec<DVec3> = (0..10_000)
        .map(|i| common::flower_point(0.1, TAU * i as f64 / 2_500.0))
        .collect();
    let mut tracker = Tracker::new(TrackSettings::default())
        .unwrap()
        .keep_records(false);
    let summary = track_from_rest(&mut tracker, &skel, &targets);
    assert_eq!(summary.frames, 10_000);
    assert_eq!(summary.converged_frames, 10_000, "{summary:?}");
    assert!(summary.error_max <= 1e-6);
    assert!(
        summary.bone_length_error_max <= 1e-12 * 0.15,
        "{:e}",
        summary.bone_length_error_max
    );
    assert!(summary.rotation_jump_max_rad.is_finite());
}

/// W1 with the default solver: all 500 frames within 1e-6 at the lab's cap of 100, and
/// the continuity limit (Q3) is honoured when switched on.
#[test]
fn w1_tracks_every_frame_and_honours_the_rotation_limit() {
    let skel = common::w1_skeleton();
    let targets = common::w1_targets();
    for limit in [None, Some(0.05)] {
        let mut tracker = Tracker::new(TrackSettings {
            max_rotation_change: limit,
            ..Default::default()
        })
        .unwrap();
        let summary = track_from_rest(&mut tracker, &skel, &targets);
        assert_eq!(summary.frames, 500);
        match limit {
            None => {
                assert_eq!(summary.converged_frames, 500, "{summary:?}");
                assert_eq!(summary.clamped_frames, 0);
            }
            Some(limit) => {
                assert!(
                    summary.rotation_jump_max_rad <= limit + 1e-12,
                    "{summary:?}"
                );
                let clamped = tracker.records().iter().filter(|r| r.clamped).count();
                assert_eq!(clamped, summary.clamped_frames);
            }
        }
    }
}

#[test]
fn the_finish_reaches_rotation_goals_and_plain_ccd_refuses_them() {
    use sinew_skeleton::ik::{EffectorGoal, IkProblem};
    // Four bones in a bent chain; the goal is the effector's frame in a known pose, so
    // both errors can reach 0.
    let arm = Skeleton::chain(
        DVec3::ZERO,
        &[
            DVec3::X * 0.3,
            DVec3::X * 0.25,
            DVec3::new(0.2, 0.05, 0.0),
            DVec3::X * 0.15,
        ],
    )
    .unwrap();
    let chain = Chain::whole(&arm).unwrap();
    let mut wanted = arm.rest_pose();
    wanted.rotations[0] = DQuat::from_rotation_z(0.4);
    wanted.rotations[1] = DQuat::from_rotation_y(-0.7);
    wanted.rotations[2] = DQuat::from_euler(glam_order(), 0.3, 0.5, -0.2);
    wanted.rotations[3] = DQuat::from_rotation_x(0.9);
    let mut goal_global = GlobalPose::new();
    arm.forward_kinematics(&wanted, &mut goal_global).unwrap();
    let effector = chain.effector();
    let goals = [EffectorGoal::at(effector, goal_global.positions[effector])
        .with_rotation(goal_global.rotations[effector])];
    let settings = SolveSettings::default();
    let problem = IkProblem::new(&arm, &chain, &goals, settings);
    let (mut pose, mut global) = (arm.rest_pose(), GlobalPose::new());
    arm.forward_kinematics(&pose, &mut global).unwrap();
    let report = CcdSolver::new()
        .solve(&problem, &mut IkState::new(&mut pose, &mut global))
        .unwrap();
    assert_eq!(report.stop, StopReason::Converged, "{report:?}");
    assert!(report.within(&settings), "{report:?}");
    // The report's errors are the true ones.
    let true_rotation = rotation_angle(global.rotations[effector], goals[0].rotation.unwrap());
    assert_eq!(report.rotation_error, true_rotation);
    assert!(true_rotation <= settings.rotation_tolerance);
    // Without the finish, a rotation goal is refused, naming the field.
    let (mut pose, mut global) = (arm.rest_pose(), GlobalPose::new());
    let err = CcdSolver::plain()
        .solve(&problem, &mut IkState::new(&mut pose, &mut global))
        .unwrap_err();
    assert!(
        matches!(
            err,
            IkError::InvalidGoal {
                field: "rotation",
                ..
            }
        ),
        "{err}"
    );
}

fn glam_order() -> sinew_math::EulerRot {
    sinew_math::EulerRot::XYZ
}

/// Iterations over W1's 500 frames, each solve warm-started from the last (cap 100).
fn w1_iterations(solver: &mut CcdSolver, tolerance: f64) -> usize {
    let skel = common::w1_skeleton();
    let chain = Chain::whole(&skel).unwrap();
    let (mut pose, mut global) = (skel.rest_pose(), GlobalPose::new());
    let mut iterations = 0;
    for target in common::w1_targets() {
        let report = solver
            .solve_position(
                &skel,
                &chain,
                &mut pose,
                &mut global,
                target,
                &settings(100, tolerance),
            )
            .unwrap();
        assert!(report.error <= tolerance, "{report:?}");
        iterations += report.iterations;
    }
    iterations
}

/// The finish takes over only once the sweeps have slowed. Extrapolated sweeps that still
/// converge are cheaper than the finish: with it, W1 never takes more iterations than the
/// same sweeps alone (handing over at a sweep keeping half of the error took 4 308 at
/// 1e-12 against 3 167). Plain sweeps slow down earlier: with the finish they stay within
/// twice the extrapolated solver's count (handing over at 0.8 of the error, as the
/// extrapolated sweeps do, they took 3 to 5 times as many).
#[test]
fn the_sweeps_hand_over_to_the_finish_only_once_they_slow() {
    for tolerance in [1e-6, 1e-9, 1e-12] {
        let with_finish = w1_iterations(&mut CcdSolver::new(), tolerance);
        let sweeps_alone = w1_iterations(&mut CcdSolver::new().with_finish(false), tolerance);
        let plain_with_finish = w1_iterations(&mut CcdSolver::plain().with_finish(true), tolerance);
        assert!(
            with_finish <= sweeps_alone,
            "tolerance {tolerance:e}: {with_finish} iterations with the finish, {sweeps_alone} without"
        );
        assert!(
            plain_with_finish <= 2 * with_finish,
            "tolerance {tolerance:e}: plain sweeps and the finish {plain_with_finish}, extrapolated {with_finish}"
        );
    }
}
