//! Both solvers, built through the registry, on chains with joint limits: the W7 human
//! arm (feasible targets from forward kinematics of random allowed poses, and points of
//! the ball around the shoulder), the W1 flower tracked with a 45-degree cone on every
//! joint, and W7 with rotation goals. Every returned pose is checked against the limits
//! independently of the report (violation recomputed from the pose), and every report
//! against forward kinematics of the returned pose.

use sinew_ik::{CcdOptions, FabrikOptions, SolverOptions};
use sinew_math::DVec3;
use sinew_skeleton::ik::{
    Chain, EffectorGoal, IkProblem, IkSolver, IkState, SolveReport, SolveSettings, StopReason,
    chain_limit_violation,
};
use sinew_skeleton::limits::JointLimit;
use sinew_skeleton::track::{TrackSettings, Tracker};
use sinew_skeleton::{GlobalPose, Pose, Skeleton};
use std::f64::consts::TAU;

/// The largest violation any returned pose may have (radians).
const LIMIT_TOLERANCE: f64 = 1e-12;

/// splitmix64, the generator of the workloads (a fixed seed).
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn deg(d: f64) -> f64 {
    d.to_radians()
}

/// The human arm with joint limits (W7).
fn w7() -> Skeleton {
    sinew_ik::workloads::human_arm().unwrap()
}

/// A pose uniform in every joint's limit parameters.
fn allowed_pose(skeleton: &Skeleton, rng: &mut SplitMix64) -> Pose {
    sinew_ik::workloads::allowed_pose(skeleton, || rng.unit())
}

fn fk(skeleton: &Skeleton, pose: &Pose) -> GlobalPose {
    let mut global = GlobalPose::new();
    skeleton.forward_kinematics(pose, &mut global).unwrap();
    global
}

/// Solves `goal` from the rest pose and checks the contract: the pose is inside the
/// limits (recomputed), the report's errors are those of forward kinematics of the
/// pose, and the error is not above the start.
fn solve_checked(
    solver: &mut dyn IkSolver,
    skeleton: &Skeleton,
    chain: &Chain,
    goal: EffectorGoal,
    settings: SolveSettings,
    what: &str,
) -> SolveReport {
    let mut pose = skeleton.rest_pose();
    let mut global = GlobalPose::new();
    let goals = [goal];
    let problem = IkProblem::new(skeleton, chain, &goals, settings);
    let report = solver
        .solve(&problem, &mut IkState::new(&mut pose, &mut global))
        .unwrap();
    let violation = chain_limit_violation(skeleton, chain, &pose);
    assert!(
        violation <= LIMIT_TOLERANCE,
        "{what}: violation {violation:e} {report:?}"
    );
    assert_eq!(report.limit_violation, violation, "{what}");
    let fresh = fk(skeleton, &pose);
    assert_eq!(
        fresh.positions, global.positions,
        "{what}: global is not FK of the pose"
    );
    let (error, rotation_error) = goal.errors(&fresh);
    assert_eq!(report.error, error, "{what}");
    assert_eq!(report.rotation_error, rotation_error, "{what}");
    assert!(pose.rotations.iter().all(|q| q.is_finite()), "{what}");
    if goal.rotation.is_none() {
        assert!(report.error <= report.initial_error, "{what}: {report:?}");
    }
    assert_ne!(
        report.stop,
        StopReason::OutOfReach,
        "{what}: straightened through the limits"
    );
    report
}

fn feasible_goals(skeleton: &Skeleton, count: usize, with_rotation: bool) -> Vec<EffectorGoal> {
    let mut rng = SplitMix64(0x5EED_0000_0000_0007);
    (0..count)
        .map(|_| {
            let global = fk(skeleton, &allowed_pose(skeleton, &mut rng));
            let goal = EffectorGoal::at(4, global.positions[4]);
            if with_rotation {
                goal.with_rotation(global.rotations[4])
            } else {
                goal
            }
        })
        .collect()
}

fn solvers() -> [(&'static str, SolverOptions); 2] {
    [
        ("ccd", SolverOptions::Ccd(CcdOptions::default())),
        ("fabrik", SolverOptions::Fabrik(FabrikOptions::default())),
    ]
}

#[test]
fn w7_feasible_targets_are_reached_inside_the_limits() {
    let skeleton = w7();
    let chain = Chain::whole(&skeleton).unwrap();
    let goals = feasible_goals(&skeleton, 2_000, false);
    for (name, options) in solvers() {
        let mut solver = options.build().unwrap();
        let mut within = 0;
        let mut restarts = 0;
        let mut worst_violation: f64 = 0.0;
        let mut missed = std::collections::BTreeMap::new();
        for (k, &goal) in goals.iter().enumerate() {
            let what = format!("{name} feasible {k}");
            let report = solve_checked(
                solver.as_mut(),
                &skeleton,
                &chain,
                goal,
                SolveSettings::default(),
                &what,
            );
            within += usize::from(report.error <= 1e-6);
            restarts += usize::from(report.restarted);
            worst_violation = worst_violation.max(report.limit_violation);
            if report.error > 1e-6 {
                *missed.entry(report.stop.name()).or_insert(0) += 1;
            }
        }
        eprintln!(
            "W7 {name}: {within} of {} feasible targets within 1e-6, {restarts} restarts; missed: {missed:?}; limit violation max {worst_violation:e} rad",
            goals.len()
        );
        // The workload's bar is 99.9% of the feasible targets at the cap of 100. FABRIK's
        // finish, which slides along the swing-twist bounds, measured 1 999 of 2 000 here
        // (96.9% before it did). CCD measured 95.8% (1 916) sweeping to the end; ending
        // with the same finish it measured 2 000 of 2 000.
        let floor = 0.999;
        assert!(
            within as f64 >= floor * goals.len() as f64,
            "{name}: {within} of {}",
            goals.len()
        );
    }
}

#[test]
fn w7_ball_targets_end_inside_the_limits_and_say_why() {
    let skeleton = w7();
    let chain = Chain::whole(&skeleton).unwrap();
    let mut rng = SplitMix64(0x5EED_0000_0000_0077);
    let targets: Vec<DVec3> = (0..1_000)
        .map(|_| {
            loop {
                let v = DVec3::new(rng.unit(), rng.unit(), rng.unit()) * 2.0 - DVec3::ONE;
                if v.length_squared() <= 1.0 {
                    break v * 0.63;
                }
            }
        })
        .collect();
    for (name, options) in solvers() {
        let mut solver = options.build().unwrap();
        let mut stops = std::collections::BTreeMap::new();
        for (k, &target) in targets.iter().enumerate() {
            let what = format!("{name} ball {k}");
            let report = solve_checked(
                solver.as_mut(),
                &skeleton,
                &chain,
                EffectorGoal::at(4, target),
                SolveSettings::default(),
                &what,
            );
            *stops.entry(report.stop.name()).or_insert(0) += 1;
            if report.stop == StopReason::Converged {
                assert!(report.error <= 1e-6, "{what}");
            }
        }
        eprintln!("W7 ball {name}: stops {stops:?}");
    }
}

#[test]
fn the_flower_with_a_45_degree_cone_on_every_joint_never_leaves_a_limit() {
    let offsets = [DVec3::new(0.15, 0.0, 0.0); 7];
    let mut skeleton = Skeleton::chain(DVec3::new(0.0, 0.5, 0.0), &offsets).unwrap();
    for j in 0..skeleton.len() {
        skeleton
            .set_limit(j, JointLimit::cone(DVec3::X, deg(45.0)).unwrap())
            .unwrap();
    }
    let chain = Chain::whole(&skeleton).unwrap();
    let targets: Vec<DVec3> = (0..500)
        .map(|i| {
            let t = TAU * i as f64 / 500.0;
            DVec3::new(
                6.0 * t.cos() - (6.0 * t).cos(),
                0.0,
                6.0 * t.sin() - (6.0 * t).sin(),
            ) * 0.1
        })
        .collect();
    for (name, options) in solvers() {
        let mut solver = options.build().unwrap();
        let mut tracker = Tracker::new(TrackSettings::default()).unwrap();
        let mut pose = skeleton.rest_pose();
        let mut global = GlobalPose::new();
        for &target in &targets {
            let record = tracker
                .step(
                    solver.as_mut(),
                    &skeleton,
                    &chain,
                    &mut IkState::new(&mut pose, &mut global),
                    EffectorGoal::at(chain.effector(), target),
                )
                .unwrap();
            assert!(
                record.limit_violation <= LIMIT_TOLERANCE,
                "{name}: {record:?}"
            );
            assert_eq!(
                chain_limit_violation(&skeleton, &chain, &pose),
                record.limit_violation
            );
            if record.error > 1e-6 {
                assert!(
                    matches!(
                        record.stop,
                        StopReason::LocalMinimum | StopReason::IterationCap
                    ),
                    "{name}: a frame off target must say why: {record:?}"
                );
            }
        }
        let summary = tracker.summary();
        eprintln!(
            "flower with 45-degree cones, {name}: {} of 500 within 1e-6, {} local minima, error max {:.3e}, largest rotation change per frame {:.4} rad, violation max {:e}",
            summary.converged_frames,
            summary.local_minimum_frames,
            summary.error_max,
            summary.rotation_jump_max_rad,
            summary.limit_violation_max
        );
        assert!(summary.limit_violation_max <= LIMIT_TOLERANCE);
    }
}

#[test]
fn w7_rotation_goals_converge_both_errors() {
    let skeleton = w7();
    let chain = Chain::whole(&skeleton).unwrap();
    let goals = feasible_goals(&skeleton, 1_000, true);
    let settings = SolveSettings::default();
    for (name, options) in solvers() {
        let mut solver = options.build().unwrap();
        let mut within = 0;
        for (k, &goal) in goals.iter().enumerate() {
            let what = format!("{name} rotation goal {k}");
            let report = solve_checked(solver.as_mut(), &skeleton, &chain, goal, settings, &what);
            within += usize::from(report.within(&settings));
        }
        eprintln!(
            "W7 rotation goals, {name}: {within} of {} within 1e-6 and 1e-6 rad",
            goals.len()
        );
        // FABRIK measured 982 of 1000 since the finish slides along the swing-twist
        // bounds (799 before); CCD, which refused rotation goals before it ended with the
        // same finish, measured 990. This guards the measured figures, short of the
        // workload's bar.
        let floor = if name == "fabrik" { 978 } else { 985 };
        assert!(within >= floor, "{name}: {within} of {}", goals.len());
    }
}
