//! Helpers shared by the property files: for IK, forward kinematics into a fresh buffer,
//! the solvers under test by name, and the full check of one solve against the
//! `IkSolver` contract; for self-contact, the contact distances and the descent check
//! of a step's Newton iterates.

#![allow(dead_code)]

use proptest::prelude::*;
use proptest::test_runner::TestCaseError;
use sinew_ik::SolverOptions;
use sinew_labcheck::bounds::chain_position_allowance;
use sinew_labcheck::reference::kinematics::{scale, skeleton_bone_violation};
use sinew_labcheck::strategies::log_uniform;
use sinew_math::DVec3;
use sinew_skeleton::ik::{Chain, IkSolver, SolveReport, SolveSettings, StopReason};
use sinew_skeleton::{GlobalPose, Pose, Skeleton};

/// Forward kinematics of `pose` into a new buffer.
pub fn fk(skeleton: &Skeleton, pose: &Pose) -> GlobalPose {
    let mut global = GlobalPose::new();
    skeleton
        .forward_kinematics(pose, &mut global)
        .expect("valid pose");
    global
}

/// The solvers under test: every configuration of the library's registry
/// (`SolverOptions::NAMED`: CCD with and without extrapolation, the FABRIK hybrid and
/// plain FABRIK).
pub type SolverKind = SolverOptions;

/// Every solver of the registry.
pub fn solver_kind() -> impl Strategy<Value = SolverKind> + Clone {
    prop::sample::select(every_solver().to_vec())
}

/// Every solver of the registry, in its order.
pub fn every_solver() -> [SolverOptions; 4] {
    SolverOptions::NAMED.map(|(_, options)| options)
}

/// A solver of the given kind.
pub fn make_solver(kind: SolverKind) -> Box<dyn IkSolver> {
    kind.build()
        .expect("the registry's configurations are valid")
}

/// Solve settings over the whole range: every cap from 0 to 100, tolerance 0 or
/// log-uniform in `[1e-12, 1]`.
pub fn settings() -> impl Strategy<Value = SolveSettings> + Clone {
    (
        0usize..=100,
        prop_oneof![1 => Just(0.0), 4 => log_uniform(-12.0, 0.0)],
    )
        .prop_map(|(max_iterations, tolerance)| SolveSettings {
            max_iterations,
            tolerance,
            ..Default::default()
        })
}

/// What one checked solve returns.
pub struct Solved {
    /// The report.
    pub report: SolveReport,
    /// The pose after the solve.
    pub pose: Pose,
    /// Its forward kinematics, as the solver left it.
    pub global: GlobalPose,
}

/// Solves and checks every part of the `IkSolver` contract that holds for any input:
/// `Ok`; finite pose and global pose; `global` is forward kinematics of the pose; every
/// bone of the skeleton keeps its length (`bounds::bone_length_allowance`); the report's
/// errors are the true distances; the final error is not above the initial one; the cap
/// is respected; a `Converged` stop is within the tolerance; joints outside the chain
/// keep their local rotations; a start within the tolerance costs 0 iterations.
pub fn solve_checked(
    solver: &mut dyn IkSolver,
    skeleton: &Skeleton,
    chain: &Chain,
    start: &Pose,
    target: DVec3,
    settings: &SolveSettings,
) -> Result<Solved, TestCaseError> {
    let before = fk(skeleton, start);
    let initial = before.positions[chain.effector()].distance(target);
    let mut pose = start.clone();
    let mut global = GlobalPose::new();
    let report = solver
        .solve_position(skeleton, chain, &mut pose, &mut global, target, settings)
        .map_err(|e| TestCaseError::fail(format!("solve refused valid input: {e}")))?;
    prop_assert!(
        pose.rotations.iter().all(|q| q.is_finite()),
        "non-finite rotation"
    );
    prop_assert!(
        global.positions.iter().all(|p| p.is_finite()),
        "non-finite position"
    );
    prop_assert!(!report.error.is_nan() && !report.initial_error.is_nan());
    let fresh = fk(skeleton, &pose);
    let s = scale(fresh.positions.iter().copied());
    for (j, (a, b)) in fresh.positions.iter().zip(&global.positions).enumerate() {
        prop_assert!(
            a.distance(*b) <= chain_position_allowance(0, s),
            "global is not FK of the pose at joint {j}: {a} vs {b}"
        );
    }
    if let Some(v) = skeleton_bone_violation(skeleton, &global.positions) {
        return Err(TestCaseError::fail(format!("bone length not kept: {v:?}")));
    }
    prop_assert_eq!(report.initial_error, initial);
    let reached = global.positions[chain.effector()].distance(target);
    prop_assert_eq!(report.error, reached);
    prop_assert!(
        report.error <= report.initial_error,
        "final error {:e} above initial {:e} ({:?})",
        report.error,
        report.initial_error,
        report.stop
    );
    prop_assert!(report.iterations <= settings.max_iterations);
    if report.stop == StopReason::Converged {
        prop_assert!(report.error <= settings.tolerance);
    }
    let movable = &chain.joints()[..chain.bone_count()];
    for j in 0..skeleton.len() {
        if !movable.contains(&j) {
            prop_assert_eq!(pose.rotations[j], start.rotations[j], "joint {} changed", j);
        }
    }
    if initial <= settings.tolerance {
        prop_assert_eq!(report.iterations, 0);
        prop_assert_eq!(report.stop, StopReason::Converged);
        prop_assert_eq!(&pose, start);
    }
    Ok(Solved {
        report,
        pose,
        global,
    })
}

/// The self-contact properties' contact distance and thickness (m).
pub const SELF_CONTACT_DHAT: f64 = 2e-3;
pub const SELF_CONTACT_THICKNESS: f64 = 1e-3;

/// The self-contact properties' cloth: areal density 0.2 kg/m^2, springs of
/// `stiffness`, damping 0.1, gravity 9.81 down, no bending, the vertices `fixed` held.
pub fn sheet_cloth(stiffness: f64, fixed: Vec<usize>) -> sinew_spring_sim::MeshCloth {
    sinew_spring_sim::MeshCloth {
        areal_density: 0.2,
        material: sinew_spring_sim::Material {
            stiffness,
            damping: 0.1,
            gravity: DVec3::new(0.0, -9.81, 0.0),
        },
        bending: sinew_spring_sim::Bending::None,
        fixed,
    }
}

/// The guarantee at every state the last step ended at: each piece's end (recorded by
/// `record_piece_ends`; the last piece's is the step's own end state, `system`'s) has
/// no two of `triangles` meeting (the exact check) and passes `kept` (an `Err` naming
/// what it broke); the step did not stop non-finite and the state is finite.
pub fn check_step_ends(
    newton: &sinew_spring_sim::BackwardEuler,
    report: &sinew_spring_sim::StepReport,
    system: &sinew_spring_sim::SpringSystem,
    triangles: &[[usize; 3]],
    step: usize,
    kept: impl Fn(&[DVec3]) -> Result<(), &'static str>,
) -> Result<(), TestCaseError> {
    let pieces = newton.piece_ends().expect("recording");
    prop_assert_eq!(
        pieces.len(),
        report.pieces,
        "step {}: pieces recorded",
        step
    );
    for (k, (_, x)) in pieces.iter().enumerate().take(pieces.len() - 1) {
        let bad = sinew_exact::intersecting_pairs(x, triangles);
        prop_assert!(
            bad.is_empty(),
            "step {step}, piece {k}: triangles {bad:?} meet"
        );
        kept(x)
            .map_err(|broken| TestCaseError::fail(format!("step {step}, piece {k}: {broken}")))?;
    }
    prop_assert!(
        report.stop != sinew_spring_sim::StepStop::NonFinite,
        "step {step}: non-finite"
    );
    let x = system.positions();
    prop_assert!(x.iter().all(|x| x.is_finite()), "step {step}: NaN position");
    prop_assert!(
        system.velocities().iter().all(|v| v.is_finite()),
        "step {step}: NaN velocity"
    );
    let bad = sinew_exact::intersecting_pairs(x, triangles);
    prop_assert!(bad.is_empty(), "step {step}: triangles {bad:?} meet");
    kept(x).map_err(|broken| TestCaseError::fail(format!("step {step}: {broken}")))?;
    Ok(())
}

/// `g` never rises over any slice of the last step's Newton iterates (every
/// minimization of the step: a split step's abandoned attempts and pieces too, cut by
/// the library where a stiffness changed the function), but for the round-off of
/// evaluating `g` twice.
pub fn check_descent(
    newton: &sinew_spring_sim::BackwardEuler,
    step: usize,
) -> Result<(), TestCaseError> {
    for (m, w) in newton.step_objective_traces().enumerate() {
        for (k, w) in w.windows(2).enumerate() {
            prop_assert!(
                w[1] <= w[0] + 1e-12 * w[0].abs().max(f64::MIN_POSITIVE),
                "step {step}, slice {m}, iterate {k}: g rose from {} to {}",
                w[0],
                w[1]
            );
        }
    }
    Ok(())
}
