//! Properties of the FABRIK solver against exact answers: bone lengths that never drift,
//! forward kinematics of the recovered rotations reproducing the solved positions, an
//! error that never grows, continuous twist, the closed form out of reach, defined answers
//! for every degenerate case, and the W1/W2 accuracy targets.

mod common;

use common::{
    SplitMix64, W3_TARGET, flower, flower_targets, w1_skeleton, w2_skeleton, w2_targets, whole,
};
use sinew_ik_fabrik::{FabrikMode, FabrikOptions, FabrikSolver, fabrik_pass};
use sinew_math::{DQuat, DVec3, angle_between};
use sinew_skeleton::ik::{
    Chain, IkError, IkSolver, SolveReport, SolveSettings, StopReason, largest_rotation_change,
};
use sinew_skeleton::{GlobalPose, JointDef, Pose, Skeleton};

fn both() -> [FabrikSolver; 2] {
    [FabrikSolver::plain(), FabrikSolver::new()]
}

fn mode(s: &FabrikSolver) -> FabrikMode {
    s.options().mode
}

/// Every chain bone has its rest length, to 1e-12 relative (or 1e-12 of the reach for a
/// zero-length bone).
fn assert_bone_lengths(skel: &Skeleton, chain: &Chain, global: &GlobalPose, what: &str) {
    let joints = chain.joints();
    for (c, &len) in chain.bone_lengths().iter().enumerate() {
        let got = global.positions[joints[c]].distance(global.positions[joints[c + 1]]);
        let allowed = 1e-12 * if len > 0.0 { len } else { chain.reach() };
        assert!(
            (got - len).abs() <= allowed,
            "{what}: bone {c} has length {got}, rest {len}"
        );
    }
    let _ = skel;
}

/// The solve's contract: finite pose, `global` is FK of `pose`, FK reproduces the solved
/// positions, the report's errors are the real distances, never worse than the start.
#[allow(clippy::too_many_arguments)]
fn assert_contract(
    skel: &Skeleton,
    chain: &Chain,
    solver: &FabrikSolver,
    pose: &Pose,
    global: &GlobalPose,
    target: DVec3,
    report: &SolveReport,
    settings: &SolveSettings,
    what: &str,
) {
    assert!(
        pose.rotations.iter().all(|q| q.is_finite()),
        "{what}: non-finite pose"
    );
    let mut fresh = GlobalPose::new();
    skel.forward_kinematics(pose, &mut fresh).unwrap();
    assert_eq!(&fresh, global, "{what}: global is not FK of the pose");
    let effector = global.positions[chain.effector()];
    assert_eq!(report.error, effector.distance(target), "{what}");
    assert!(report.error.is_finite() && report.initial_error.is_finite());
    assert!(
        report.error <= report.initial_error,
        "{what}: error grew from {} to {}",
        report.initial_error,
        report.error
    );
    assert!(report.iterations <= settings.max_iterations, "{what}");
    assert_eq!(
        report.stop == StopReason::Converged,
        report.error <= settings.tolerance,
        "{what}: {report:?}"
    );
    let solved = solver.solved_positions();
    assert_eq!(solved.len(), chain.joints().len());
    for (c, &j) in chain.joints().iter().enumerate() {
        let gap = global.positions[j].distance(solved[c]);
        assert!(
            gap <= 1e-12 * chain.reach().max(f64::MIN_POSITIVE),
            "{what}: joint {j} is {gap:e} from its solved position"
        );
    }
    assert_bone_lengths(skel, chain, global, what);
}

fn random_pose(n: usize, rng: &mut SplitMix64, amplitude: f64) -> Pose {
    Pose {
        rotations: (0..n)
            .map(|_| {
                let axis = DVec3::new(rng.symmetric(), rng.symmetric(), rng.symmetric());
                DQuat::from_scaled_axis(axis * amplitude)
            })
            .collect(),
    }
}

#[test]
fn bone_lengths_hold_over_100_000_tracked_frames() {
    // A short chain so 100 000 frames run in a few seconds in debug builds; the target
    // sweeps a closed curve well inside the reach, so every frame iterates.
    let skel = Skeleton::chain(DVec3::ZERO, &[DVec3::new(0.3, 0.0, 0.0); 3]).unwrap();
    let chain = whole(&skel);
    let settings = SolveSettings::default();
    let mut solver = FabrikSolver::new();
    let mut pose = skel.rest_pose();
    let mut global = GlobalPose::new();
    let frames = 100_000;
    let mut worst = 0.0f64;
    for i in 0..frames {
        let t = std::f64::consts::TAU * i as f64 / 997.0;
        let target = DVec3::new(0.4 + 0.2 * t.cos(), 0.3 * t.sin(), 0.2 * (3.0 * t).sin());
        solver
            .solve_position(&skel, &chain, &mut pose, &mut global, target, &settings)
            .unwrap();
        for c in 0..3 {
            let got = global.positions[c].distance(global.positions[c + 1]);
            worst = worst.max((got - 0.3).abs() / 0.3);
        }
    }
    eprintln!("100 000 tracked frames: worst relative bone-length error {worst:e}");
    assert!(worst <= 1e-12, "worst relative bone-length error {worst:e}");
    // The local rotations stay unit quaternions (FK normalizes, but the stored pose
    // should not wander either).
    for q in &pose.rotations {
        assert!((q.length() - 1.0).abs() < 1e-14);
    }
}

#[test]
fn bone_lengths_hold_over_100_000_bare_passes() {
    let lengths = [0.15, 0.05, 0.3, 0.0, 0.2, 0.1];
    let mut p = vec![DVec3::ZERO];
    for l in lengths {
        let last = *p.last().unwrap();
        p.push(last + DVec3::X * l);
    }
    let mut rng = SplitMix64(7);
    let mut worst = 0.0f64;
    for _ in 0..100_000 {
        let target = DVec3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()) * 0.9;
        fabrik_pass(&mut p, &lengths, target).unwrap();
        for (c, &l) in lengths.iter().enumerate() {
            let got = p[c].distance(p[c + 1]);
            worst = worst.max(if l > 0.0 { (got - l).abs() / l } else { got });
        }
    }
    eprintln!("100 000 bare passes: worst relative bone-length error {worst:e}");
    assert!(worst <= 1e-12, "worst relative bone-length error {worst:e}");
    assert_eq!(p[0], DVec3::ZERO);
}

#[test]
fn w1_tracks_the_flower_within_tolerance_with_the_contract() {
    let skel = w1_skeleton();
    let chain = whole(&skel);
    let settings = SolveSettings::default();
    for mut solver in both() {
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        let mut worst = 0.0f64;
        let mut jump = 0.0f64;
        for (i, &target) in flower_targets(500).iter().enumerate() {
            let before = pose.clone();
            let report = solver
                .solve_position(&skel, &chain, &mut pose, &mut global, target, &settings)
                .unwrap();
            let what = format!("{:?} frame {i}", mode(&solver));
            assert_contract(
                &skel, &chain, &solver, &pose, &global, target, &report, &settings, &what,
            );
            worst = worst.max(report.error);
            if i > 0 {
                jump = jump.max(largest_rotation_change(&before, &pose, chain.joints()));
            }
        }
        assert!(worst <= 1e-6, "{:?}: worst error {worst:e}", mode(&solver));
        // Consecutive flower points are under 0.03 apart on a chain of 0.15 bones: the
        // joints turn by a few degrees per frame, never by a flip.
        assert!(
            jump < 0.3,
            "{:?}: largest per-frame change {jump}",
            mode(&solver)
        );
    }
}

/// The twist of a joint's global rotation `g` about its bone (rest direction x): `g` is
/// the swing taking x to `g x` (the minimal rotation) after a twist about x; the twist's
/// angle, in (-pi, pi].
fn twist_about_x(g: DQuat) -> f64 {
    let swing = sinew_math::rotation_between(DVec3::X, g * DVec3::X);
    let twist = swing.conjugate() * g;
    let angle = 2.0 * twist.x.atan2(twist.w);
    let a = angle.rem_euclid(std::f64::consts::TAU);
    if a > std::f64::consts::PI {
        a - std::f64::consts::TAU
    } else {
        a
    }
}

#[test]
fn a_twisted_start_keeps_its_twist() {
    // Every joint of W1 twisted 0.8 rad about its bone (the x axis): the same positions
    // as the rest pose, a different orientation. Recovering rotations from the rest
    // direction would drop the twist to 0 on the first frame. The minimal rotation from
    // the previous pose adds no twist at all: each frame, each bone's global rotation
    // changes by a rotation whose axis is perpendicular to the bone.
    let skel = w1_skeleton();
    let chain = whole(&skel);
    let settings = SolveSettings::default();
    let joints = chain.joints();
    for mut solver in both() {
        let mut pose = Pose {
            rotations: vec![DQuat::from_rotation_x(0.8); skel.len()],
        };
        let mut global = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut global).unwrap();
        let start = global.positions[chain.effector()];
        let (mut jump, mut twist_added) = (0.0f64, 0.0f64);
        for i in 1..=200 {
            let s = i as f64 / 200.0;
            let target =
                start + DVec3::new(-0.5 * s, -0.3 * (std::f64::consts::PI * s).sin(), 0.4 * s);
            let before = pose.clone();
            let old = global.clone();
            let report = solver
                .solve_position(&skel, &chain, &mut pose, &mut global, target, &settings)
                .unwrap();
            assert!(report.error <= report.initial_error);
            jump = jump.max(largest_rotation_change(&before, &pose, joints));
            for c in 0..chain.bone_count() {
                let j = joints[c];
                let bone = old.rotations[j] * skel.offset(joints[c + 1]);
                let change = global.rotations[j] * old.rotations[j].conjugate();
                let along = change.xyz().dot(bone.normalize());
                twist_added = twist_added.max((2.0 * along.atan2(change.w.abs())).abs());
            }
            if i == 1 {
                // After a small first move the twist of 0.8 is still there.
                assert!((twist_about_x(global.rotations[0]) - 0.8).abs() < 0.05);
            }
        }
        let what = format!("{:?}", mode(&solver));
        assert!(jump < 0.3, "{what}: per-frame rotation change {jump}");
        assert!(twist_added < 1e-12, "{what}: twist added {twist_added:e}");
    }
}

#[test]
fn w2_every_reachable_target_within_tolerance_with_the_hybrid() {
    let skel = w2_skeleton();
    let chain = whole(&skel);
    let settings = SolveSettings::default();
    let mut solver = FabrikSolver::new();
    let rest = skel.rest_pose();
    let mut global = GlobalPose::new();
    let mut reachable = 0;
    for (i, &target) in w2_targets(500).iter().enumerate() {
        let mut pose = rest.clone();
        let report = solver
            .solve_position(&skel, &chain, &mut pose, &mut global, target, &settings)
            .unwrap();
        let what = format!("W2 target {i} {target}");
        assert_contract(
            &skel, &chain, &solver, &pose, &global, target, &report, &settings, &what,
        );
        if target.length() < chain.reach() {
            reachable += 1;
            assert!(report.error <= 1e-6, "{what}: {report:?}");
        } else {
            assert_eq!(report.stop, StopReason::OutOfReach, "{what}");
            let expected = target.length() - chain.reach();
            assert!((report.error - expected).abs() < 1e-14, "{what}");
        }
    }
    assert!(reachable > 400, "{reachable}");
}

#[test]
fn w3_gives_the_straight_chain() {
    let skel = w2_skeleton();
    let chain = whole(&skel);
    let settings = SolveSettings::default();
    let mut rng = SplitMix64(3);
    for mut solver in both() {
        for start in [skel.rest_pose(), random_pose(skel.len(), &mut rng, 1.0)] {
            let mut pose = start;
            let mut global = GlobalPose::new();
            let report = solver
                .solve_position(&skel, &chain, &mut pose, &mut global, W3_TARGET, &settings)
                .unwrap();
            assert_eq!(report.stop, StopReason::OutOfReach);
            assert_eq!(report.iterations, 0);
            let excess = report.error - (W3_TARGET.length() - chain.reach());
            assert!(excess.abs() <= 1e-12, "{excess:e}");
            let p = &global.positions;
            for i in 1..9 {
                let bend = angle_between(p[i] - p[i - 1], p[i + 1] - p[i]);
                assert!(bend <= 1e-12, "bend {bend:e} at joint {i}");
            }
            assert_bone_lengths(&skel, &chain, &global, "W3");
        }
    }
}

#[test]
fn far_target_converges_to_the_closed_form_when_iterated() {
    // Just inside the reach the solver iterates; its answer must approach the straight
    // chain of the closed form used beyond it. Joints of a chain that reaches within
    // `gap` of full extension lie within about sqrt(2 gap bone) of the line.
    let skel = w2_skeleton();
    let chain = whole(&skel);
    let direction = W3_TARGET.normalize();
    let gap = 1e-8;
    let target = direction * (chain.reach() - gap);
    let settings = SolveSettings {
        max_iterations: 1000,
        tolerance: 1e-12,
        ..Default::default()
    };
    let mut solver = FabrikSolver::new();
    let mut pose = skel.rest_pose();
    let mut global = GlobalPose::new();
    let report = solver
        .solve_position(&skel, &chain, &mut pose, &mut global, target, &settings)
        .unwrap();
    assert_eq!(report.stop, StopReason::Converged, "{report:?}");
    for i in 1..10 {
        let expected = direction * (0.1 * i as f64);
        let off = global.positions[i].distance(expected);
        assert!(
            off < 2.0 * (2.0 * gap * 0.1f64).sqrt(),
            "joint {i}: {off:e}"
        );
    }
    // Plain FABRIK creeps near full extension: it gets closer every pass but not to
    // 1e-12 in 1000 passes; it must still be nearly straight and never worse.
    let mut plain = FabrikSolver::plain();
    let mut pose = skel.rest_pose();
    let report = plain
        .solve_position(&skel, &chain, &mut pose, &mut global, target, &settings)
        .unwrap();
    eprintln!("plain FABRIK, {gap:e} inside the reach: {report:?}");
    assert!(report.error < 1e-2 * report.initial_error, "{report:?}");
    for i in 1..10 {
        assert!(global.positions[i].distance(direction * (0.1 * i as f64)) < 0.05);
    }
}

/// Solves and checks the contract; returns the report.
fn solve_checked(
    solver: &mut FabrikSolver,
    skel: &Skeleton,
    chain: &Chain,
    pose: &mut Pose,
    target: DVec3,
    what: &str,
) -> SolveReport {
    let settings = SolveSettings::default();
    let mut global = GlobalPose::new();
    let report = solver
        .solve_position(skel, chain, pose, &mut global, target, &settings)
        .unwrap();
    let what = format!("{what} ({:?})", mode(solver));
    assert_contract(
        skel, chain, solver, pose, &global, target, &report, &settings, &what,
    );
    report
}

#[test]
fn degenerate_targets_have_defined_answers() {
    let skel = w2_skeleton();
    let chain = whole(&skel);
    let cases = [
        ("target on the base joint", DVec3::ZERO),
        ("target on a joint of the chain", DVec3::new(0.4, 0.0, 0.0)),
        ("target on the middle of a bone", DVec3::new(0.45, 0.0, 0.0)),
        (
            "target on the chain near the effector",
            DVec3::new(0.85, 0.0, 0.0),
        ),
        (
            "joint-to-effector antiparallel to joint-to-target",
            DVec3::new(-0.35, 0.0, 0.0),
        ),
    ];
    for mut solver in both() {
        for (what, target) in cases {
            let mut pose = skel.rest_pose();
            let report = solve_checked(&mut solver, &skel, &chain, &mut pose, target, what);
            assert!(report.iterations > 0, "{what}: {report:?}");
            if mode(&solver) == FabrikMode::Hybrid {
                assert_eq!(report.stop, StopReason::Converged, "{what}: {report:?}");
            } else {
                assert_ne!(report.stop, StopReason::OutOfReach, "{what}");
            }
        }
    }
}

#[test]
fn straight_chain_pointing_away_from_an_unreachable_target() {
    let skel = w2_skeleton();
    let chain = whole(&skel);
    for mut solver in both() {
        let mut pose = skel.rest_pose();
        let target = DVec3::new(-3.0, 0.0, 0.0);
        let report = solve_checked(&mut solver, &skel, &chain, &mut pose, target, "away");
        assert_eq!(report.stop, StopReason::OutOfReach);
        assert!((report.error - 2.1).abs() < 1e-14, "{report:?}");
        let mut global = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut global).unwrap();
        assert!(global.positions[9].distance(DVec3::new(-0.9, 0.0, 0.0)) < 1e-14);
    }
}

#[test]
fn zero_length_bones_are_finite_and_reach_the_target() {
    // Zero-length bones at the base, in the middle and at the effector.
    let offsets = [
        DVec3::ZERO,
        DVec3::new(0.2, 0.0, 0.0),
        DVec3::ZERO,
        DVec3::ZERO,
        DVec3::new(0.0, 0.2, 0.0),
        DVec3::new(0.1, 0.0, 0.1),
        DVec3::ZERO,
    ];
    let skel = Skeleton::chain(DVec3::new(0.1, 0.2, 0.3), &offsets).unwrap();
    let chain = whole(&skel);
    for mut solver in both() {
        for target in [
            DVec3::new(0.3, 0.3, 0.2),
            DVec3::new(0.1, 0.2, 0.3),
            DVec3::new(-0.1, 0.1, 0.4),
        ] {
            let mut pose = skel.rest_pose();
            let report = solve_checked(&mut solver, &skel, &chain, &mut pose, target, "zero");
            if mode(&solver) == FabrikMode::Hybrid {
                assert_eq!(report.stop, StopReason::Converged, "{target}: {report:?}");
            }
        }
    }
    // Only zero-length bones: the reach is 0, every target is out of reach.
    let skel = Skeleton::chain(DVec3::ZERO, &[DVec3::ZERO; 3]).unwrap();
    let chain = whole(&skel);
    for mut solver in both() {
        let mut pose = skel.rest_pose();
        let report = solve_checked(&mut solver, &skel, &chain, &mut pose, DVec3::X, "all zero");
        assert_eq!(report.stop, StopReason::OutOfReach);
        assert_eq!(report.error, 1.0);
    }
}

#[test]
fn non_finite_targets_are_errors_and_leave_the_pose() {
    let skel = w1_skeleton();
    let chain = whole(&skel);
    for mut solver in both() {
        for bad in [
            DVec3::new(f64::NAN, 0.0, 0.0),
            DVec3::new(0.0, f64::INFINITY, 0.0),
            DVec3::new(0.0, 0.0, f64::NEG_INFINITY),
        ] {
            let mut pose = skel.rest_pose();
            let mut global = GlobalPose::new();
            let err = solver
                .solve_position(
                    &skel,
                    &chain,
                    &mut pose,
                    &mut global,
                    bad,
                    &SolveSettings::default(),
                )
                .unwrap_err();
            assert!(
                matches!(
                    err,
                    IkError::InvalidGoal {
                        goal: 0,
                        field: "position",
                        ..
                    }
                ),
                "{err}"
            );
            assert_eq!(pose, skel.rest_pose());
        }
    }
}

#[test]
fn within_tolerance_takes_zero_iterations_and_leaves_the_pose() {
    let skel = w1_skeleton();
    let chain = whole(&skel);
    let mut rng = SplitMix64(11);
    for mut solver in both() {
        let start = random_pose(skel.len(), &mut rng, 0.7);
        let mut global = GlobalPose::new();
        skel.forward_kinematics(&start, &mut global).unwrap();
        let target = global.positions[chain.effector()] + DVec3::new(3e-7, -4e-7, 0.0);
        let mut pose = start.clone();
        let report = solver
            .solve_position(
                &skel,
                &chain,
                &mut pose,
                &mut global,
                target,
                &SolveSettings::default(),
            )
            .unwrap();
        assert_eq!(report.iterations, 0);
        assert_eq!(report.stop, StopReason::Converged);
        assert_eq!(pose, start);
        // A cap of 0 leaves the pose untouched as well.
        let report = solver
            .solve_position(
                &skel,
                &chain,
                &mut pose,
                &mut global,
                DVec3::new(0.3, 0.2, 0.1),
                &SolveSettings {
                    max_iterations: 0,
                    tolerance: 1e-6,
                    ..Default::default()
                },
            )
            .unwrap();
        assert_eq!(
            (report.iterations, report.stop),
            (0, StopReason::IterationCap)
        );
        assert_eq!(report.error, report.initial_error);
        assert_eq!(pose, start);
    }
}

#[test]
fn the_error_never_grows_and_caps_are_kept() {
    let skel = w2_skeleton();
    let chain = whole(&skel);
    let mut rng = SplitMix64(5);
    for cap in [1, 2, 3, 5, 100] {
        let settings = SolveSettings {
            max_iterations: cap,
            tolerance: 1e-9,
            ..Default::default()
        };
        for mut solver in both() {
            for k in 0..40 {
                let mut pose = random_pose(skel.len(), &mut rng, 2.0);
                let target = DVec3::new(rng.symmetric(), rng.symmetric(), rng.symmetric()) * 0.8;
                let mut global = GlobalPose::new();
                let report = solver
                    .solve_position(&skel, &chain, &mut pose, &mut global, target, &settings)
                    .unwrap();
                let what = format!("cap {cap} case {k} {:?}", mode(&solver));
                assert_contract(
                    &skel, &chain, &solver, &pose, &global, target, &report, &settings, &what,
                );
            }
        }
    }
}

#[test]
fn a_chain_inside_a_tree_moves_its_side_branches_rigidly() {
    // 0 root -> 1 spine -> 2 shoulder -> 3 elbow -> 4 hand, with a side branch 5 off the
    // elbow and 6 off the spine. The chain runs from the shoulder (not the root) to the
    // hand; the root has a rotation of its own.
    let joint = |parent: Option<usize>, offset: DVec3| JointDef {
        name: None,
        parent,
        offset,
        ..JointDef::default()
    };
    let skel = Skeleton::new([
        joint(None, DVec3::new(0.0, 1.0, 0.0)),
        joint(Some(0), DVec3::new(0.0, 0.4, 0.0)),
        joint(Some(1), DVec3::new(0.2, 0.1, 0.0)),
        joint(Some(2), DVec3::new(0.3, 0.0, 0.0)),
        joint(Some(3), DVec3::new(0.25, 0.0, 0.05)),
        joint(Some(3), DVec3::new(0.0, 0.1, 0.0)),
        joint(Some(1), DVec3::new(-0.2, 0.1, 0.0)),
    ])
    .unwrap();
    let chain = Chain::new(&skel, 2, 4).unwrap();
    assert_eq!(chain.joints(), &[2, 3, 4]);
    let settings = SolveSettings::default();
    for mut solver in both() {
        let mut pose = skel.rest_pose();
        pose.rotations[0] = DQuat::from_rotation_y(0.4);
        pose.rotations[1] = DQuat::from_rotation_z(0.2);
        let start = pose.clone();
        let mut before = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut before).unwrap();
        let target = before.positions[2] + DVec3::new(0.1, -0.3, 0.25);
        let mut global = GlobalPose::new();
        let report = solver
            .solve_position(&skel, &chain, &mut pose, &mut global, target, &settings)
            .unwrap();
        let what = format!("tree {:?}", mode(&solver));
        assert_contract(
            &skel, &chain, &solver, &pose, &global, target, &report, &settings, &what,
        );
        assert!(report.error <= 1e-6, "{what}: {report:?}");
        // Only the chain's joints (not the effector) changed their local rotation.
        for j in [0, 1, 4, 5, 6] {
            assert_eq!(pose.rotations[j], start.rotations[j], "{what}: joint {j}");
        }
        // Joints outside the chain's subtree did not move.
        for j in [0, 1, 2, 6] {
            assert_eq!(
                global.positions[j], before.positions[j],
                "{what}: joint {j}"
            );
        }
        // The side branch off the elbow keeps its place in the elbow's frame.
        let local = global.rotations[3].conjugate() * (global.positions[5] - global.positions[3]);
        assert!(local.distance(DVec3::new(0.0, 0.1, 0.0)) < 1e-15);
    }
}

#[test]
fn invalid_options_are_errors() {
    for ratio in [-0.1, 1.5, f64::NAN] {
        let err = FabrikSolver::with_options(FabrikOptions {
            mode: FabrikMode::Hybrid,
            switch_ratio: ratio,
        })
        .unwrap_err();
        assert!(err.to_string().contains("switch_ratio"), "{err}");
    }
    assert!(FabrikSolver::with_options(FabrikOptions::default()).is_ok());
    assert_eq!(FabrikSolver::new().name(), "fabrik");
}

#[test]
fn the_flower_helper_is_the_lab_flower() {
    // t = 0 is the outer tip (a(6 - 1), 0, 0); the curve is closed.
    assert!(flower(0.0, 0.1).distance(DVec3::new(0.5, 0.0, 0.0)) < 1e-15);
    assert!(flower(std::f64::consts::TAU, 0.1).distance(flower(0.0, 0.1)) < 1e-14);
}

/// `docs/labcheck.md`'s bone-length bound: `| |b - a| - rest | <= 1e-12 rest + 4 EPS
/// max(|a|, |b|)`, the 1e-12 relative plus the round-off of the bone's own two
/// endpoints (their absolute coordinates cannot represent it any better).
fn assert_bone_bound(positions: &[DVec3], lengths: &[f64], what: &str) {
    for (c, &rest) in lengths.iter().enumerate() {
        let (a, b) = (positions[c], positions[c + 1]);
        let length = a.distance(b);
        let allowed = 1e-12 * rest + 4.0 * f64::EPSILON * a.length().max(b.length());
        assert!(
            (length - rest).abs() <= allowed,
            "{what}: bone {c} has length {length:e}, rest {rest:e}, off by {:e} > {allowed:e}",
            (length - rest).abs()
        );
    }
}

#[test]
fn a_short_bone_keeps_its_length_after_the_refinement_folds_the_chain_home() {
    // labcheck's `fabrik_rotations_reproduce_its_positions` regression: a straight chain
    // with bones of 795, 966, 413 and 0.0017 aimed at a target on its base. The first
    // pass leaves the last bone hundreds of units from the origin; the refinement then
    // brings it within 0.15 of it, where round-off is ~3e-17. The last bone used to come
    // back 6.6e-15 short (4e-12 of it): its vector was the difference of two positions
    // of size ~400, which the refinement kept rotating without restoring its length.
    let offsets = [
        DVec3::new(689.686594913305, 0.0, -396.1166613515587),
        DVec3::new(837.8231326654785, 0.0, -481.197843429552),
        DVec3::new(358.46048124451255, 0.0, -205.87926473313294),
        DVec3::new(0.0014447552238814154, 0.0, -0.0008297850356596653),
    ];
    let skel = Skeleton::chain(DVec3::ZERO, &offsets).unwrap();
    let chain = whole(&skel);
    let settings = SolveSettings {
        max_iterations: 16,
        tolerance: 0.0,
        ..Default::default()
    };
    for mut solver in both() {
        let what = format!("{:?}", mode(&solver));
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        let report = solver
            .solve_position(
                &skel,
                &chain,
                &mut pose,
                &mut global,
                DVec3::ZERO,
                &settings,
            )
            .unwrap();
        assert!(report.error <= report.initial_error, "{what}: {report:?}");
        assert_bone_bound(
            solver.solved_positions(),
            chain.bone_lengths(),
            &format!("{what}: solved positions"),
        );
        let mut fresh = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut fresh).unwrap();
        assert_eq!(fresh, global, "{what}: global is not FK of the pose");
        let fk: Vec<DVec3> = chain.joints().iter().map(|&j| fresh.positions[j]).collect();
        assert_bone_bound(
            &fk,
            chain.bone_lengths(),
            &format!("{what}: FK of the pose"),
        );
    }
}
