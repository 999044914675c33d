//! Properties of forward kinematics (sinew-skeleton) and of the two IK solvers
//! (sinew-ik-ccd, sinew-ik-fabrik) on random chains, trees and targets of every kind.
//! Each property is listed with its reason in docs/labcheck.md.

use crate::common::{every_solver, fk, make_solver, settings, solve_checked, solver_kind};
use proptest::prelude::*;
use sinew_ik_ccd::CcdSolver;
use sinew_ik_fabrik::FabrikSolver;
use sinew_labcheck::bounds::{EPS, chain_position_allowance, sweep_allowance};
use sinew_labcheck::config;
use sinew_labcheck::reference::kinematics::{
    chain_bone_violation, depth, scale, skeleton_bone_violation,
};
use sinew_labcheck::strategies::chains::{self, ChainCase, TreeCase};
use sinew_labcheck::strategies::targets::{self, TargetKind};
use sinew_labcheck::strategies::{direction, log_uniform};
use sinew_math::try_unit;
use sinew_skeleton::ik::{
    Chain, IkSolver, SolveSettings, StopReason, chain_has_limits, chain_limit_violation,
};
use sinew_skeleton::{Pose, Skeleton};

/// A chain or a tree, as (skeleton, pose, chain).
fn any_case() -> impl Strategy<Value = (Skeleton, Pose, Chain)> {
    prop_oneof![
        chains::chain().prop_map(|c: ChainCase| (c.skeleton, c.pose, c.chain)),
        chains::tree().prop_map(|t: TreeCase| (t.skeleton, t.pose, t.chain)),
    ]
}

proptest! {
    #![proptest_config(config::standard())]

    /// FK keeps every bone length, on chains and branching trees.
    #[test]
    fn fk_keeps_bone_lengths((skeleton, pose, _) in any_case()) {
        let global = fk(&skeleton, &pose);
        prop_assert!(global.positions.iter().all(|p| p.is_finite()));
        if let Some(v) = skeleton_bone_violation(&skeleton, &global.positions) {
            return Err(TestCaseError::fail(format!("{v:?}")));
        }
    }

    /// Every solver, every cap and tolerance, every target kind: the whole IkSolver
    /// contract (bone lengths, no NaN, final error <= initial error, reported errors
    /// true, cap respected, nothing outside the chain moved, 0 iterations within
    /// tolerance).
    #[test]
    fn solve_keeps_the_contract(
        (skeleton, pose, chain) in any_case(),
        kind in solver_kind(),
        target in targets::target(),
        settings in settings(),
    ) {
        let t = target.place(&chain, &fk(&skeleton, &pose));
        let mut solver = make_solver(kind);
        solve_checked(solver.as_mut(), &skeleton, &chain, &pose, t, &settings)?;
    }

    /// Chains with a random limit on every joint, every solver, every target kind:
    /// no returned pose leaves a limit by more than 1e-12 rad (recomputed from the pose),
    /// the report's error and limit violation are those of forward kinematics of the
    /// returned pose, and the error never ends above the start's (the start is inside
    /// the limits; the allowance is the positions' round-off).
    #[test]
    fn limits_are_never_left(
        case in chains::limited_chain(),
        kind in solver_kind(),
        target in targets::target(),
        settings in settings(),
    ) {
        let start = fk(&case.skeleton, &case.pose);
        let t = target.place(&case.chain, &start);
        let mut solver = make_solver(kind);
        let mut pose = case.pose.clone();
        let mut global = sinew_skeleton::GlobalPose::new();
        let report = solver
            .solve_position(&case.skeleton, &case.chain, &mut pose, &mut global, t, &settings)
            .map_err(|e| TestCaseError::fail(format!("solve refused valid input: {e}")))?;
        let violation = chain_limit_violation(&case.skeleton, &case.chain, &pose);
        prop_assert!(violation <= 1e-12, "violation {:e} ({:?})", violation, report);
        prop_assert_eq!(report.limit_violation, violation);
        let fresh = fk(&case.skeleton, &pose);
        prop_assert_eq!(&fresh.positions, &global.positions);
        prop_assert_eq!(report.error, fresh.positions[case.chain.effector()].distance(t));
        let s = scale(fresh.positions.iter().copied().chain([t]));
        prop_assert!(
            report.error <= report.initial_error + chain_position_allowance(case.chain.bone_count(), s),
            "final error {:e} above initial {:e} ({:?})", report.error, report.initial_error, report.stop
        );
        if chain_has_limits(&case.skeleton, &case.chain) {
            prop_assert_ne!(report.stop, StopReason::OutOfReach);
        }
    }

    /// A CCD sweep never increases the effector-to-target distance (beyond round-off),
    /// for plain and over-relaxed CCD, sweep after sweep.
    #[test]
    fn ccd_sweep_never_increases_the_error(
        (skeleton, pose, chain) in any_case(),
        target in targets::target(),
        omega in prop_oneof![Just(1.0), 1.0f64..1.99],
        sweeps in 1usize..=20,
    ) {
        let solver = CcdSolver::with_relaxation(omega).expect("omega in [1, 2)");
        let mut pose = pose;
        let mut global = fk(&skeleton, &pose);
        let t = target.place(&chain, &global);
        let mut error = global.positions[chain.effector()].distance(t);
        for sweep in 0..sweeps {
            let s = scale(chain.joints().iter().map(|&j| global.positions[j])) + t.length();
            let next = solver
                .sweep(&skeleton, &chain, &mut pose, &mut global, t)
                .map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert!(!next.is_nan());
            let allowance = sweep_allowance(chain.bone_count(), s);
            prop_assert!(
                next <= error + allowance,
                "sweep {sweep}: error {next:e} > {error:e} + {allowance:e}"
            );
            if let Some(v) = skeleton_bone_violation(&skeleton, &global.positions) {
                return Err(TestCaseError::fail(format!("sweep {sweep}: {v:?}")));
            }
            error = next;
        }
    }

    /// A target at or beyond the reach gives the straight chain aimed at it, 0
    /// iterations, error |target - base| - reach; for every solver.
    #[test]
    fn out_of_reach_gives_the_straight_chain(
        (skeleton, pose, chain) in any_case(),
        kind in solver_kind(),
        target in targets::target_of(&[TargetKind::Unreachable, TargetKind::Far]),
        settings in settings(),
    ) {
        let start = fk(&skeleton, &pose);
        let t = target.place(&chain, &start);
        let base = start.positions[chain.base()];
        prop_assume!(start.positions[chain.effector()].distance(t) > settings.tolerance);
        let mut solver = make_solver(kind);
        let solved = solve_checked(solver.as_mut(), &skeleton, &chain, &pose, t, &settings)?;
        prop_assert_eq!(solved.report.stop, StopReason::OutOfReach);
        prop_assert_eq!(solved.report.iterations, 0);
        let aim = try_unit(t - base).expect("target off the base");
        let joints = chain.joints();
        let positions = &solved.global.positions;
        let s = scale(joints.iter().map(|&j| positions[j]));
        let mut total_allowance = 0.0;
        for (c, &length) in chain.bone_lengths().iter().enumerate() {
            let bone = positions[joints[c + 1]] - positions[joints[c]];
            let allowance =
                chain_position_allowance(depth(&skeleton, joints[c + 1]), length) + 8.0 * EPS * s;
            total_allowance += allowance;
            prop_assert!(
                (bone - aim * length).length() <= allowance,
                "bone {c} (length {length:e}) is not aimed at the target: off by {:e} > {allowance:e}",
                (bone - aim * length).length()
            );
        }
        let expected = base.distance(t) - chain.reach();
        let rounding = total_allowance + 8.0 * EPS * (t.length() + s);
        prop_assert!(
            (solved.report.error - expected).abs() <= rounding,
            "error {:e} vs |target - base| - reach = {expected:e}",
            solved.report.error
        );
    }

    /// Forward kinematics of FABRIK's recovered rotations reproduces its solved
    /// positions (hybrid and plain).
    #[test]
    fn fabrik_rotations_reproduce_its_positions(
        (skeleton, pose, chain) in any_case(),
        plain in any::<bool>(),
        target in targets::target(),
        settings in settings(),
    ) {
        let t = target.place(&chain, &fk(&skeleton, &pose));
        let mut solver = if plain { FabrikSolver::plain() } else { FabrikSolver::new() };
        let solved = solve_checked(&mut solver, &skeleton, &chain, &pose, t, &settings)?;
        let solved_positions = solver.solved_positions();
        let joints = chain.joints();
        prop_assert_eq!(solved_positions.len(), joints.len());
        if let Some(v) = chain_bone_violation(&chain, solved_positions) {
            return Err(TestCaseError::fail(format!("solved positions: {v:?}")));
        }
        let s = scale(joints.iter().map(|&j| solved.global.positions[j])) + chain.reach();
        for (c, &j) in joints.iter().enumerate() {
            let allowance = chain_position_allowance(depth(&skeleton, j), s);
            let off = solved.global.positions[j].distance(solved_positions[c]);
            prop_assert!(
                off <= allowance,
                "chain joint {c}: FK is {off:e} from the solved position (allowed {allowance:e}, {:?})",
                solved.report.stop
            );
        }
    }

    /// A target already within the tolerance costs zero iterations and leaves the pose
    /// untouched (every solver).
    #[test]
    fn within_tolerance_costs_zero_iterations(
        (skeleton, pose, chain) in any_case(),
        kind in solver_kind(),
        tolerance in log_uniform(-12.0, 0.0),
        offset_direction in direction(),
        fraction in 0.0f64..0.999,
        max_iterations in 0usize..=100,
    ) {
        let start = fk(&skeleton, &pose);
        let effector = start.positions[chain.effector()];
        let t = effector + offset_direction * (fraction * tolerance);
        prop_assume!(effector.distance(t) <= tolerance);
        let settings = SolveSettings { max_iterations, tolerance, ..Default::default() };
        let mut solver = make_solver(kind);
        let solved = solve_checked(solver.as_mut(), &skeleton, &chain, &pose, t, &settings)?;
        prop_assert_eq!(solved.report.iterations, 0);
        prop_assert_eq!(solved.report.stop, StopReason::Converged);
        prop_assert_eq!(&solved.pose, &pose);
    }
}

proptest! {
    // 1 000-joint chains cost ~100x a short chain per solve: 16 cases at the default
    // setting (scaled with PROPTEST_CASES), each running all four solvers.
    #![proptest_config(config::with_cases(16))]

    /// The solve contract, out-of-reach straightening included, on 1 000-joint chains.
    #[test]
    fn long_chains_keep_the_contract(
        case in chains::long_chain(),
        target in targets::target(),
        settings in settings(),
    ) {
        let t = target.place(&case.chain, &fk(&case.skeleton, &case.pose));
        for kind in every_solver() {
            let mut solver = make_solver(kind);
            solve_checked(solver.as_mut(), &case.skeleton, &case.chain, &case.pose, t, &settings)?;
        }
    }
}

/// The 1 000-joint strategy really makes 1 000 joints (a guard on the generator).
#[test]
fn long_chain_strategy_has_1000_joints() {
    use proptest::strategy::ValueTree;
    let mut runner = proptest::test_runner::TestRunner::deterministic();
    let case = chains::long_chain()
        .new_tree(&mut runner)
        .expect("a value")
        .current();
    assert_eq!(case.skeleton.len(), 1000);
    assert_eq!(case.chain.bone_count(), 999);
}

/// The solver trait object names, to make sure the four kinds are four solvers.
#[test]
fn solver_kinds_are_distinct() {
    let names: Vec<&str> = every_solver()
        .into_iter()
        .map(|k| make_solver(k).name())
        .collect();
    assert_eq!(names, ["ccd", "ccd", "fabrik", "fabrik"]);
    let _: &dyn IkSolver = &CcdSolver::plain();
}
