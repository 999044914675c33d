//! The IK degenerate set: every solver (CCD and FABRIK, each with and without its
//! acceleration) on chains of 1, 2 and 10 000 bones, bone lengths spanning 1e-6 to 1e6,
//! targets at the base, 1e-12 from it, 1e12 away, exactly at the reach, on the chain's
//! own axis, zero-length bones, a cap of 0, a tolerance of 0, and bad input. Each solve
//! is checked against invariants that hold for any correct solver (docs/stress.md).
//!
//! The two-bone limbs of the set also run the analytic two-bone solver (`two-bone`):
//! the target on the root, the pole on the root-target line or on the root, zero-length
//! bones, out of reach, a hinge range that cannot fold far enough, and bad input; the
//! same invariants, plus a bend angle inside the hinge range and a `reached` claim that
//! forward kinematics confirms.

use serde::Serialize;
use sinew_ik::{CcdOptions, SolverOptions};
use sinew_ik_two_bone::{Hinge, TwoBoneIk};
use sinew_math::{DQuat, DVec3, EulerRot};
use sinew_skeleton::ik::{Chain, IkSolver, SolveReport, SolveSettings, StopReason};
use sinew_skeleton::{GlobalPose, Pose, Skeleton};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::time::Instant;

/// Machine epsilon of f64.
const EPS: f64 = f64::EPSILON;

/// The relative accuracy every bone length must keep (the 1e-12).
const BONE_RELATIVE: f64 = 1e-12;

/// Every solver configuration the set runs: the registry's `SolverOptions::NAMED`, then
/// the two CCD combinations of extrapolation and finish it does not name (extrapolated
/// sweeps without the finish, plain sweeps with it), so each on/off setting of the finish
/// is stressed with each kind of sweep. Each label is `SolverOptions::label` of its
/// options.
#[must_use]
pub fn solvers() -> Vec<(&'static str, SolverOptions)> {
    let mut out = SolverOptions::NAMED.to_vec();
    for (extrapolation, finish) in [(true, false), (false, true)] {
        let options = SolverOptions::Ccd(CcdOptions {
            extrapolation,
            finish,
            ..CcdOptions::default()
        });
        out.push((options.label(), options));
    }
    out
}

/// The solver of the configuration labelled `name` (one of [`solvers`]).
fn make_solver(name: &str) -> Result<Box<dyn IkSolver>, String> {
    solvers()
        .into_iter()
        .find(|(label, _)| *label == name)
        .ok_or_else(|| format!("unknown solver {name:?}"))
        .and_then(|(_, options)| options.build().map_err(|e| e.to_string()))
}

/// What a case expects of every solver.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Expect {
    /// A solve (`Ok`) that keeps every invariant.
    Solve,
    /// An `Err` whose message contains this text (it names the bad input).
    Error(&'static str),
}

/// One IK case.
#[derive(Clone, Debug)]
pub struct IkCase {
    /// What the case is.
    pub name: String,
    /// The root joint's position.
    pub root: DVec3,
    /// Offsets of joints 1.. (bones), in their parent's frame.
    pub offsets: Vec<DVec3>,
    /// Local rotations of the starting pose (`None`: the rest pose, a straight chain
    /// along the offsets).
    pub start: Option<Vec<DQuat>>,
    /// The target.
    pub target: DVec3,
    /// Cap and tolerance.
    pub settings: SolveSettings,
    /// What must happen.
    pub expect: Expect,
    /// For a two-bone limb: also run the two-bone solver with this pole and hinge.
    pub two_bone: Option<TwoBoneSetup>,
}

/// The two-bone solver's inputs besides the limb and the target.
#[derive(Clone, Debug)]
pub struct TwoBoneSetup {
    /// The pole the bend plane turns towards.
    pub pole: DVec3,
    /// The mid joint's hinge.
    pub hinge: Hinge,
    /// What must happen with the two-bone solver.
    pub expect: Expect,
}

/// The label of the two-bone solver in the outcomes.
pub const TWO_BONE: &str = "two-bone";

fn xs(lengths: &[f64]) -> Vec<DVec3> {
    lengths.iter().map(|&l| DVec3::X * l).collect()
}

fn case(name: impl Into<String>, offsets: Vec<DVec3>, target: DVec3) -> IkCase {
    IkCase {
        name: name.into(),
        root: DVec3::ZERO,
        offsets,
        start: None,
        target,
        settings: SolveSettings::default(),
        expect: Expect::Solve,
        two_bone: None,
    }
}

/// A two-bone case: the limb with upper bone `upper` and lower bone `lower` along +x
/// (the rest pose straight), the pole and the hinge (about z).
fn limb(
    name: &str,
    upper: f64,
    lower: f64,
    target: DVec3,
    pole: DVec3,
    hinge: (f64, f64),
) -> IkCase {
    let mut c = case(
        format!("two-bone limb, {name}"),
        xs(&[upper, lower]),
        target,
    );
    c.two_bone = Some(TwoBoneSetup {
        pole,
        hinge: Hinge::new(DVec3::Z, hinge.0, hinge.1),
        expect: Expect::Solve,
    });
    c
}

/// The two-bone cases (each also runs every chain solver).
fn two_bone_cases() -> Vec<IkCase> {
    use std::f64::consts::PI;
    let free = (-PI, PI);
    let elbow = (0.0, 150f64.to_radians());
    let up = DVec3::Y;
    let mut out = vec![
        limb("reachable", 0.3, 0.25, DVec3::new(0.2, 0.3, 0.1), up, elbow),
        limb(
            "equal bones, target on the root",
            0.3,
            0.3,
            DVec3::ZERO,
            up,
            free,
        ),
        limb(
            "unequal bones, target on the root (unreachable)",
            0.3,
            0.25,
            DVec3::ZERO,
            up,
            free,
        ),
        limb(
            "pole on the root-target line",
            0.3,
            0.25,
            DVec3::new(0.2, 0.3, 0.1),
            DVec3::new(0.4, 0.6, 0.2),
            free,
        ),
        limb(
            "pole on the root",
            0.3,
            0.25,
            DVec3::new(0.2, 0.3, 0.1),
            DVec3::ZERO,
            free,
        ),
        limb(
            "target on its axis in front (straight limb)",
            0.3,
            0.25,
            DVec3::new(0.4, 0.0, 0.0),
            up,
            free,
        ),
        limb(
            "zero-length upper bone",
            0.0,
            0.25,
            DVec3::new(0.1, 0.2, 0.0),
            up,
            free,
        ),
        limb(
            "zero-length lower bone",
            0.3,
            0.0,
            DVec3::new(0.1, 0.2, 0.0),
            up,
            free,
        ),
        limb(
            "both bones of length 0",
            0.0,
            0.0,
            DVec3::new(0.1, 0.2, 0.0),
            up,
            free,
        ),
        limb(
            "target out of reach",
            0.3,
            0.25,
            DVec3::new(0.0, 2.0, 0.0),
            up,
            elbow,
        ),
        limb(
            "target 1e12 away",
            0.3,
            0.25,
            DVec3::new(0.0, 0.0, 1e12),
            up,
            elbow,
        ),
        limb(
            "target exactly at the reach",
            0.3,
            0.25,
            DVec3::new(0.0, 0.55, 0.0),
            up,
            elbow,
        ),
        limb(
            "hinge 0..150 degrees, target nearer than the fold allows",
            0.3,
            0.25,
            DVec3::new(0.0, 0.1, 0.0),
            up,
            elbow,
        ),
    ];
    // Bad input: the two-bone solver's error names the field. The chain solvers take
    // no pole, so for them only the bad target is bad input.
    let mut nan_target = limb(
        "NaN target",
        0.3,
        0.25,
        DVec3::new(f64::NAN, 0.0, 0.0),
        up,
        elbow,
    );
    nan_target.expect = Expect::Error("goal 0: position");
    if let Some(setup) = &mut nan_target.two_bone {
        setup.expect = Expect::Error("`target`");
    }
    out.push(nan_target);
    let mut bad_pole = limb(
        "infinite pole",
        0.3,
        0.25,
        DVec3::new(0.2, 0.3, 0.1),
        DVec3::new(0.0, f64::INFINITY, 0.0),
        elbow,
    );
    if let Some(setup) = &mut bad_pole.two_bone {
        setup.expect = Expect::Error("`pole`");
    }
    out.push(bad_pole);
    out
}

/// A bent starting pose: joint `i` turned by a fixed, varied set of angles.
fn bent(joints: usize) -> Vec<DQuat> {
    (0..joints)
        .map(|i| {
            let t = i as f64;
            DQuat::from_euler(
                EulerRot::XYZ,
                0.3 * (t * 1.3).sin(),
                -0.2,
                0.25 * (t * 0.7).cos(),
            )
        })
        .collect()
}

/// The W2 chain: 9 bones of 0.1 from the origin.
fn w2() -> Vec<DVec3> {
    xs(&[0.1; 9])
}

/// Every case of the set (the same with `--quick`: the whole set takes under a second).
#[must_use]
pub fn cases() -> Vec<IkCase> {
    let w2_reach: f64 = [0.1; 9].iter().sum();
    let spanning: Vec<f64> = (-6..=6).map(|e| 10f64.powi(e)).collect();
    let spanning_reach: f64 = spanning.iter().sum();
    let mut reversed = spanning.clone();
    reversed.reverse();
    let long = vec![1e-4; 10_000];
    let mut out = vec![
        case("1 bone, target on its sphere", xs(&[1.0]), DVec3::Y),
        case(
            "1 bone, target inside (unreachable)",
            xs(&[1.0]),
            0.5 * DVec3::Y,
        ),
        case("1 bone, target beyond", xs(&[1.0]), 3.0 * DVec3::Y),
        case(
            "2 bones, reachable",
            xs(&[1.0, 1.0]),
            DVec3::new(1.0, 1.0, 0.2),
        ),
        case(
            "2 equal bones, target at the base",
            xs(&[1.0, 1.0]),
            DVec3::ZERO,
        ),
        case(
            "2 unequal bones, target at the base (unreachable)",
            xs(&[1.0, 0.5]),
            DVec3::ZERO,
        ),
        case(
            "W2 chain, target 1e-12 from the base",
            w2(),
            DVec3::new(0.0, 1e-12, 0.0),
        ),
        case(
            "W2 chain, target 1e12 away",
            w2(),
            DVec3::new(0.0, 1e12, 0.0),
        ),
        case(
            "W2 chain, target exactly at the reach",
            w2(),
            DVec3::new(0.0, w2_reach, 0.0),
        ),
        case(
            "W2 chain, target just inside the reach (1 - 1e-9)",
            w2(),
            DVec3::new(0.0, w2_reach * (1.0 - 1e-9), 0.0),
        ),
        case(
            "W2 chain, target on its axis in front",
            w2(),
            DVec3::new(0.5, 0.0, 0.0),
        ),
        case(
            "W2 chain, target on its axis behind",
            w2(),
            DVec3::new(-0.5, 0.0, 0.0),
        ),
        case("W2 chain, target at the base", w2(), DVec3::ZERO),
        case(
            "W2 chain, target equal to the effector",
            w2(),
            DVec3::new(w2_reach, 0.0, 0.0),
        ),
        case(
            "zero-length bones inside the chain",
            vec![
                0.1 * DVec3::X,
                DVec3::ZERO,
                0.1 * DVec3::X,
                DVec3::ZERO,
                DVec3::ZERO,
                0.1 * DVec3::X,
            ],
            DVec3::new(0.1, 0.2, 0.0),
        ),
        case(
            "all bones of length 0",
            vec![DVec3::ZERO; 4],
            DVec3::new(0.5, 0.0, 0.0),
        ),
        case(
            "all bones of length 0, target at the base",
            vec![DVec3::ZERO; 4],
            DVec3::ZERO,
        ),
        case(
            "lengths 1e-6 .. 1e6, reachable off axis",
            xs(&spanning),
            DVec3::new(6e5, 8e5, 0.0),
        ),
        case(
            "lengths 1e6 .. 1e-6, reachable off axis",
            xs(&reversed),
            DVec3::new(6e5, 8e5, 0.0),
        ),
        case(
            "lengths 1e-6 .. 1e6, target at the base (unreachable)",
            xs(&spanning),
            DVec3::ZERO,
        ),
        case(
            "lengths 1e-6 .. 1e6, target just inside the reach",
            xs(&spanning),
            DVec3::new(0.0, 0.0, spanning_reach * (1.0 - 1e-9)),
        ),
        case(
            "lengths 1e-6 .. 1e6, target 1e12 away",
            xs(&spanning),
            DVec3::new(0.0, 1e12, 0.0),
        ),
        case(
            "10 000 bones of 1e-4, reachable",
            long.iter().map(|&l| DVec3::X * l).collect(),
            DVec3::new(0.3, 0.5, 0.2),
        ),
        case(
            "10 000 bones of 1e-4, out of reach",
            long.iter().map(|&l| DVec3::X * l).collect(),
            DVec3::new(0.0, 2.0, 0.0),
        ),
    ];
    let mut far_root = case(
        "W2 chain rooted 1e6 from the origin, reachable",
        w2(),
        DVec3::new(1e6 + 0.3, 0.4, 0.1),
    );
    far_root.root = DVec3::new(1e6, 0.0, 0.0);
    out.push(far_root);
    let mut bent_start = case(
        "W2 chain from a bent pose, reachable",
        w2(),
        DVec3::new(-0.2, 0.3, 0.4),
    );
    bent_start.start = Some(bent(10));
    out.push(bent_start);
    let mut cap0 = case("W2 chain, cap 0", w2(), DVec3::new(0.3, 0.4, 0.0));
    cap0.settings.max_iterations = 0;
    out.push(cap0);
    let mut tol0 = case("W2 chain, tolerance 0", w2(), DVec3::new(0.3, 0.4, 0.1));
    tol0.settings.tolerance = 0.0;
    out.push(tol0);
    for (name, target, expect) in [
        (
            "NaN target",
            DVec3::new(f64::NAN, 0.0, 0.0),
            "goal 0: position",
        ),
        (
            "infinite target",
            DVec3::new(0.0, f64::INFINITY, 0.0),
            "goal 0: position",
        ),
        (
            "-infinite target",
            DVec3::new(0.0, 0.0, f64::NEG_INFINITY),
            "goal 0: position",
        ),
    ] {
        let mut c = case(name, w2(), target);
        c.expect = Expect::Error(expect);
        out.push(c);
    }
    for (name, tolerance) in [
        ("negative tolerance", -1e-6),
        ("NaN tolerance", f64::NAN),
        ("infinite tolerance", f64::INFINITY),
    ] {
        let mut c = case(name, w2(), DVec3::new(0.3, 0.4, 0.0));
        c.settings.tolerance = tolerance;
        c.expect = Expect::Error("tolerance");
        out.push(c);
    }
    out.extend(two_bone_cases());
    out
}

/// What one solver did on one case.
#[derive(Clone, Debug, Serialize)]
pub struct IkOutcome {
    /// The case's name.
    pub case: String,
    /// The solver.
    pub solver: &'static str,
    /// Bones in the chain.
    pub bones: usize,
    /// `|target - base|`.
    pub distance: f64,
    /// The chain's reach.
    pub reach: f64,
    /// The least error any pose can have: `max(0, d - reach, r_min - d)` with
    /// `r_min = max(0, 2 L_max - reach)` the inner radius of the reachable shell.
    pub error_bound: f64,
    /// The report (`None` on an error or a panic).
    pub stop: Option<StopReason>,
    /// Iterations reported.
    pub iterations: usize,
    /// Error reported.
    pub error: f64,
    /// The error measured on forward kinematics of the returned pose.
    pub measured_error: f64,
    /// Worst bone-length error relative to its allowance (above 1 breaks the invariant).
    pub bone_error_ratio: f64,
    /// The error message, for an `Err`.
    pub message: Option<String>,
    /// Reachable (`error_bound` 0) and the solver did not reach the tolerance: reported,
    /// not an invariant break.
    pub not_converged: bool,
    /// Wall-clock seconds of the solve.
    pub seconds: f64,
    /// Broken invariants, one sentence each.
    pub failures: Vec<String>,
}

impl IkOutcome {
    /// `solver` on `case` before it runs: nothing measured, nothing broken.
    fn before_run(case: &IkCase, solver: &'static str) -> Self {
        Self {
            case: case.name.clone(),
            solver,
            bones: case.offsets.len(),
            distance: 0.0,
            reach: 0.0,
            error_bound: 0.0,
            stop: None,
            iterations: 0,
            error: f64::NAN,
            measured_error: f64::NAN,
            bone_error_ratio: 0.0,
            message: None,
            not_converged: false,
            seconds: 0.0,
            failures: Vec::new(),
        }
    }
}

/// The case's skeleton, a chain from its root and offsets; `None`, the failure recorded
/// in `out` naming the skeleton `what`, when it cannot be built.
fn build_skeleton(case: &IkCase, what: &str, out: &mut IkOutcome) -> Option<Skeleton> {
    match Skeleton::chain(case.root, &case.offsets) {
        Ok(s) => Some(s),
        Err(e) => {
            out.failures
                .push(format!("could not build the {what}: {e}"));
            None
        }
    }
}

/// The case's start pose (the rest pose unless the case gives one) and forward
/// kinematics of it; `None`, the failure recorded in `out`, when that fails.
fn starting_pose(
    skeleton: &Skeleton,
    case: &IkCase,
    out: &mut IkOutcome,
) -> Option<(Pose, GlobalPose)> {
    let mut pose = skeleton.rest_pose();
    if let Some(start) = &case.start {
        pose.rotations.copy_from_slice(start);
    }
    let mut global = GlobalPose::new();
    if let Err(e) = skeleton.forward_kinematics(&pose, &mut global) {
        out.failures
            .push(format!("forward kinematics of the start: {e}"));
        return None;
    }
    Some((pose, global))
}

/// `max(0, d - reach, inner - d)` for a target at distance `d` from the base of a chain
/// whose reachable shell has inner radius `inner`; NaN for a non-finite distance.
fn least_error(distance: f64, reach: f64, inner: f64) -> f64 {
    if distance.is_finite() {
        (distance - reach).max(inner - distance).max(0.0)
    } else {
        f64::NAN
    }
}

/// `16 EPS (depth + 1) scale`: how far two computations of one chain position may
/// differ by rounding (docs/labcheck.md "Round-off allowances").
fn position_allowance(depth: usize, scale: f64) -> f64 {
    16.0 * EPS * (depth as f64 + 1.0) * scale
}

/// `1e-12 rest + 4 EPS max(|a|, |b|)` (docs/labcheck.md).
fn bone_allowance(rest: f64, a: DVec3, b: DVec3) -> f64 {
    BONE_RELATIVE * rest + 4.0 * EPS * a.length().max(b.length())
}

/// Runs one solver on one case and checks the invariants.
#[must_use]
pub fn run_case(case: &IkCase, solver_name: &'static str) -> IkOutcome {
    let mut out = IkOutcome::before_run(case, solver_name);
    let Some(skeleton) = build_skeleton(case, "chain", &mut out) else {
        return out;
    };
    let chain = match Chain::whole(&skeleton) {
        Ok(c) => c,
        Err(e) => {
            out.failures.push(format!("could not build the chain: {e}"));
            return out;
        }
    };
    let Some((mut pose, start_global)) = starting_pose(&skeleton, case, &mut out) else {
        return out;
    };
    let start_pose = pose.clone();
    let base = start_global.positions[chain.base()];
    out.distance = case.target.distance(base);
    out.reach = chain.reach();
    let longest = chain.bone_lengths().iter().copied().fold(0.0, f64::max);
    let inner = (2.0 * longest - chain.reach()).max(0.0);
    out.error_bound = least_error(out.distance, out.reach, inner);
    let mut global = GlobalPose::new();
    let mut solver = match make_solver(solver_name) {
        Ok(solver) => solver,
        Err(e) => {
            out.failures.push(format!("no solver: {e}"));
            return out;
        }
    };
    let started = Instant::now();
    let result = catch_unwind(AssertUnwindSafe(|| {
        solver.solve_position(
            &skeleton,
            &chain,
            &mut pose,
            &mut global,
            case.target,
            &case.settings,
        )
    }));
    out.seconds = started.elapsed().as_secs_f64();
    let Some(report) = judge(result, &case.expect, &mut out) else {
        return out;
    };
    check_solve(
        &mut out,
        case,
        &skeleton,
        &chain,
        &start_pose,
        &pose,
        &global,
        &report,
    );
    out
}

/// The invariants of a returned solve.
#[allow(clippy::too_many_arguments)]
fn check_solve(
    out: &mut IkOutcome,
    case: &IkCase,
    skeleton: &Skeleton,
    chain: &Chain,
    start_pose: &Pose,
    pose: &Pose,
    global: &GlobalPose,
    report: &SolveReport,
) {
    out.stop = Some(report.stop);
    out.iterations = report.iterations;
    out.error = report.error;
    if !pose.rotations.iter().all(|q| q.is_finite()) {
        out.failures
            .push("NaN or infinity in the returned pose".into());
        return;
    }
    if !(report.error.is_finite() && report.initial_error.is_finite()) {
        out.failures.push(format!(
            "NaN or infinity in the report: error {}, initial error {}",
            report.error, report.initial_error
        ));
        return;
    }
    let mut fk = GlobalPose::new();
    if let Err(e) = skeleton.forward_kinematics(pose, &mut fk) {
        out.failures
            .push(format!("the returned pose is invalid: {e}"));
        return;
    }
    let mut start = GlobalPose::new();
    let _ = skeleton.forward_kinematics(start_pose, &mut start);
    let joints = chain.joints();
    let depth = chain.bone_count();
    let scale = joints
        .iter()
        .map(|&j| fk.positions[j].length().max(start.positions[j].length()))
        .fold(0.0, f64::max)
        + case.target.length();
    let allowance = position_allowance(depth, scale);
    if !fk.positions.iter().all(|p| p.is_finite()) {
        out.failures
            .push("NaN or infinity in forward kinematics of the pose".into());
        return;
    }
    // The returned global pose is forward kinematics of the returned pose.
    let stale = joints
        .iter()
        .map(|&j| fk.positions[j].distance(global.positions[j]))
        .fold(0.0, f64::max);
    if stale > allowance {
        out.failures.push(format!(
            "the returned global pose is not forward kinematics of the pose (off by {stale:.3e}, allowance {allowance:.3e})"
        ));
    }
    // Bone lengths, measured on forward kinematics of the result.
    for (c, &rest) in chain.bone_lengths().iter().enumerate() {
        let (a, b) = (fk.positions[joints[c]], fk.positions[joints[c + 1]]);
        let err = ((b - a).length() - rest).abs();
        let ratio = err / bone_allowance(rest, a, b);
        if ratio > out.bone_error_ratio {
            out.bone_error_ratio = ratio;
        }
    }
    if out.bone_error_ratio > 1.0 {
        out.failures.push(format!(
            "a bone length changed by {:.2} times its allowance 1e-12 L + 4 EPS |P|",
            out.bone_error_ratio
        ));
    }
    let effector = fk.positions[chain.effector()];
    out.measured_error = effector.distance(case.target);
    // The report tells the truth about the error and the start.
    if (report.error - out.measured_error).abs() > allowance {
        out.failures.push(format!(
            "reported error {:.6e} but forward kinematics gives {:.6e}",
            report.error, out.measured_error
        ));
    }
    let initial = start.positions[chain.effector()].distance(case.target);
    if (report.initial_error - initial).abs() > allowance {
        out.failures.push(format!(
            "reported initial error {:.6e} but the start pose gives {:.6e}",
            report.initial_error, initial
        ));
    }
    // Never worse than the start (both solvers restore or undo a worsening step).
    if out.measured_error > initial + allowance {
        out.failures.push(format!(
            "the solve made the error worse: {:.6e} from {:.6e}",
            out.measured_error, initial
        ));
    }
    // No pose beats the geometric bound.
    if out.measured_error < out.error_bound - allowance {
        out.failures.push(format!(
            "error {:.6e} below the least possible {:.6e}: the measurement or the chain is wrong",
            out.measured_error, out.error_bound
        ));
    }
    if report.stop == StopReason::Converged
        && out.measured_error > case.settings.tolerance + allowance
    {
        out.failures.push(format!(
            "claims convergence at error {:.3e} above the tolerance {:.3e}",
            out.measured_error, case.settings.tolerance
        ));
    }
    if out.distance >= out.reach {
        // Out of reach: the chain straightens at the target, the error is d - reach.
        let gap = (out.measured_error - (out.distance - out.reach)).abs();
        if gap > allowance {
            out.failures.push(format!(
                "target beyond the reach: error {:.9e} differs from d - reach = {:.9e} by {gap:.3e} (allowance {allowance:.3e})",
                out.measured_error,
                out.distance - out.reach
            ));
        }
    } else if out.error_bound == 0.0 && out.measured_error > case.settings.tolerance {
        // Reachable but not reached: reported, not a failure (a false `Converged` claim
        // was caught above).
        out.not_converged = true;
    }
}

/// Runs every case with every solver.
#[must_use]
pub fn run_all(cases: &[IkCase]) -> Vec<IkOutcome> {
    let mut out = Vec::new();
    let solvers = solvers();
    for c in cases {
        for &(s, _) in &solvers {
            out.push(run_case(c, s));
        }
        if let Some(setup) = &c.two_bone {
            out.push(run_two_bone_case(c, setup));
        }
    }
    out
}

/// A solve's result judged against what the case expects, for every solver of the set:
/// a panic, a refused valid input, an error that does not name the bad item, or bad input
/// accepted is a failure in `out`. The report, when there is one to check further.
fn judge<R, E: std::fmt::Display>(
    result: std::thread::Result<Result<R, E>>,
    expect: &Expect,
    out: &mut IkOutcome,
) -> Option<R> {
    match (result, expect) {
        (Err(panic), _) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| (*s).to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            out.failures.push(format!("panicked: {what}"));
            None
        }
        (Ok(Err(e)), Expect::Error(text)) => {
            let message = e.to_string();
            if !message.contains(text) {
                out.failures
                    .push(format!("the error does not name the {text}: {message}"));
            }
            out.message = Some(message);
            None
        }
        (Ok(Err(e)), Expect::Solve) => {
            out.failures.push(format!("refused a valid input: {e}"));
            out.message = Some(e.to_string());
            None
        }
        (Ok(Ok(report)), Expect::Error(text)) => {
            out.failures.push(format!(
                "accepted bad input (expected an error naming the {text})"
            ));
            Some(report)
        }
        (Ok(Ok(report)), Expect::Solve) => Some(report),
    }
}

/// Runs the two-bone solver on a two-bone case (root joint 0, mid 1, tip 2, from the
/// rest pose) and checks the invariants: no panic, an `Err` naming the field for bad
/// input, otherwise a finite pose and report, the global pose forward kinematics of the
/// pose, the reported error that of forward kinematics, the bone lengths kept, no error
/// below the geometric bound, the bend angle inside the hinge range, a `reached` claim
/// confirmed to rounding, and out of reach (the straight limb allowed) the error
/// `d - reach`. `stop` says what the closed form did: `converged` when it reached the
/// target, `out_of_reach` beyond the reach, `local_minimum` otherwise (the hinge range or
/// the geometry stopped it short).
#[must_use]
pub fn run_two_bone_case(case: &IkCase, setup: &TwoBoneSetup) -> IkOutcome {
    let mut out = IkOutcome::before_run(case, TWO_BONE);
    if case.offsets.len() != 2 {
        out.failures
            .push("a two-bone case needs exactly two bones".into());
        return out;
    }
    let Some(skeleton) = build_skeleton(case, "limb", &mut out) else {
        return out;
    };
    let Some((mut pose, mut global)) = starting_pose(&skeleton, case, &mut out) else {
        return out;
    };
    let (upper, lower) = (case.offsets[0].length(), case.offsets[1].length());
    out.distance = case.target.distance(global.positions[0]);
    out.reach = upper + lower;
    out.error_bound = least_error(out.distance, out.reach, (upper - lower).abs());
    let mut job = TwoBoneIk::new(0, 1, 2, case.target, setup.pole);
    job.hinge = setup.hinge;
    let started = Instant::now();
    let result = catch_unwind(AssertUnwindSafe(|| {
        job.run(&skeleton, &mut pose, &mut global)
    }));
    out.seconds = started.elapsed().as_secs_f64();
    let Some(report) = judge(result, &setup.expect, &mut out) else {
        return out;
    };
    out.error = report.error;
    if !pose.rotations.iter().all(|q| q.is_finite())
        || !report.error.is_finite()
        || !report.bend_angle.is_finite()
    {
        out.failures.push(format!(
            "NaN or infinity in the pose or the report: {report:?}"
        ));
        return out;
    }
    let mut fk = GlobalPose::new();
    if let Err(e) = skeleton.forward_kinematics(&pose, &mut fk) {
        out.failures
            .push(format!("the returned pose is invalid: {e}"));
        return out;
    }
    let scale = fk.positions.iter().map(|p| p.length()).fold(0.0, f64::max)
        + case.target.length()
        + out.reach;
    let allowance = position_allowance(2, scale);
    let stale = (0..3)
        .map(|j| fk.positions[j].distance(global.positions[j]))
        .fold(0.0, f64::max);
    if stale > allowance {
        out.failures.push(format!(
            "the returned global pose is not forward kinematics of the pose (off by {stale:.3e}, allowance {allowance:.3e})"
        ));
    }
    for (c, rest) in [upper, lower].into_iter().enumerate() {
        let (a, b) = (fk.positions[c], fk.positions[c + 1]);
        let ratio = ((b - a).length() - rest).abs() / bone_allowance(rest, a, b);
        out.bone_error_ratio = out.bone_error_ratio.max(ratio);
    }
    if out.bone_error_ratio > 1.0 {
        out.failures.push(format!(
            "a bone length changed by {:.2} times its allowance 1e-12 L + 4 EPS |P|",
            out.bone_error_ratio
        ));
    }
    out.measured_error = fk.positions[2].distance(case.target);
    if (report.error - out.measured_error).abs() > allowance {
        out.failures.push(format!(
            "reported error {:.6e} but forward kinematics gives {:.6e}",
            report.error, out.measured_error
        ));
    }
    if out.measured_error < out.error_bound - allowance {
        out.failures.push(format!(
            "error {:.6e} below the least possible {:.6e}",
            out.measured_error, out.error_bound
        ));
    }
    let (min, max) = (setup.hinge.min, setup.hinge.max);
    if report.bend_angle < min - 1e-12 || report.bend_angle > max + 1e-12 {
        out.failures.push(format!(
            "bend angle {} outside the hinge range [{min}, {max}]",
            report.bend_angle
        ));
    }
    if report.reached && out.measured_error > allowance {
        out.failures.push(format!(
            "claims to have reached the target at error {:.3e} (allowance {allowance:.3e})",
            out.measured_error
        ));
    }
    let straight_allowed = min <= 0.0 && 0.0 <= max;
    if out.distance >= out.reach && straight_allowed {
        let gap = (out.measured_error - (out.distance - out.reach)).abs();
        if gap > allowance {
            out.failures.push(format!(
                "target beyond the reach: error {:.9e} differs from d - reach = {:.9e} by {gap:.3e} (allowance {allowance:.3e})",
                out.measured_error,
                out.distance - out.reach
            ));
        }
    }
    out.stop = Some(if report.reached {
        StopReason::Converged
    } else if out.distance >= out.reach {
        StopReason::OutOfReach
    } else {
        StopReason::LocalMinimum
    });
    let free = min <= -std::f64::consts::PI && max >= std::f64::consts::PI;
    if out.error_bound == 0.0 && !report.reached && free {
        // A free hinge and a target in the reachable shell: the closed form should have
        // reached it; reported, as for the iterative solvers.
        out.not_converged = out.measured_error > case.settings.tolerance;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_set_runs_every_named_solver_and_both_finish_settings_of_ccd() {
        let labels: Vec<&str> = solvers().iter().map(|(l, _)| *l).collect();
        for (name, _) in SolverOptions::NAMED {
            assert!(labels.contains(&name), "{name}");
        }
        for extra in ["ccd-no-finish", "ccd-plain-finish"] {
            assert!(labels.contains(&extra), "{extra}");
        }
        // Distinct labels: each names one configuration.
        let mut unique = labels.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), labels.len());
        // Each label is the library's own for its options, and every one builds.
        for (label, options) in solvers() {
            assert_eq!(options.label(), label);
            assert!(make_solver(label).is_ok(), "{label}");
        }
    }

    #[test]
    fn every_solver_passes_a_plain_reachable_case() {
        let c = case("2 bones", xs(&[1.0, 1.0]), DVec3::new(1.0, 1.0, 0.2));
        for (s, _) in solvers() {
            let out = run_case(&c, s);
            assert!(out.failures.is_empty(), "{s}: {:?}", out.failures);
            assert_eq!(out.stop, Some(StopReason::Converged), "{s}");
            assert!(!out.not_converged);
        }
    }

    #[test]
    fn every_two_bone_case_keeps_the_invariants_with_every_solver() {
        let cases: Vec<IkCase> = cases()
            .into_iter()
            .filter(|c| c.two_bone.is_some())
            .collect();
        assert!(cases.len() >= 15, "{}", cases.len());
        let outcomes = run_all(&cases);
        let two_bone: Vec<&IkOutcome> = outcomes.iter().filter(|o| o.solver == TWO_BONE).collect();
        assert_eq!(two_bone.len(), cases.len());
        for o in &outcomes {
            assert!(
                o.failures.is_empty(),
                "{} {}: {:?}",
                o.case,
                o.solver,
                o.failures
            );
        }
        // What the closed form did, case by case: it reaches every target in its shell
        // with a free hinge, and both bad inputs are errors naming the field.
        for o in &two_bone {
            assert!(!o.not_converged, "{}: {o:?}", o.case);
        }
        let stop = |name: &str| {
            two_bone
                .iter()
                .find(|o| o.case.ends_with(name))
                .unwrap_or_else(|| panic!("no case {name}"))
                .stop
        };
        assert_eq!(
            stop("equal bones, target on the root"),
            Some(StopReason::Converged)
        );
        assert_eq!(
            stop("pole on the root-target line"),
            Some(StopReason::Converged)
        );
        assert_eq!(stop("pole on the root"), Some(StopReason::Converged));
        assert_eq!(stop("target out of reach"), Some(StopReason::OutOfReach));
        assert_eq!(
            stop("hinge 0..150 degrees, target nearer than the fold allows"),
            Some(StopReason::LocalMinimum)
        );
        let errors = two_bone.iter().filter(|o| o.message.is_some()).count();
        assert_eq!(errors, 2);
    }

    #[test]
    fn the_two_bone_checks_catch_a_wrong_hinge_range() {
        // The same case judged against a narrower hinge than the solver ran with: the
        // bend angle must be reported outside it. Run with the real hinge, then check
        // the claim against the narrow one by hand.
        let c = limb(
            "check",
            0.3,
            0.25,
            DVec3::new(0.2, 0.3, 0.1),
            DVec3::Y,
            (0.0, 2.5),
        );
        let setup = c.two_bone.clone().expect("a two-bone case");
        let ok = run_two_bone_case(&c, &setup);
        assert!(ok.failures.is_empty(), "{:?}", ok.failures);
        let mut wrong = c.clone();
        let mut narrow = setup.clone();
        narrow.hinge.max = 0.1;
        wrong.two_bone = Some(narrow.clone());
        // With the narrow hinge the solver cannot reach the target, and says so.
        let out = run_two_bone_case(&wrong, &narrow);
        assert!(out.failures.is_empty(), "{:?}", out.failures);
        assert_eq!(out.stop, Some(StopReason::LocalMinimum));
        assert!(out.measured_error > 1e-3, "{out:?}");
    }

    #[test]
    fn a_bad_target_must_be_an_error_naming_it() {
        let mut c = case("nan", w2(), DVec3::new(f64::NAN, 0.0, 0.0));
        c.expect = Expect::Error("goal 0: position");
        let out = run_case(&c, "ccd");
        assert!(out.failures.is_empty(), "{:?}", out.failures);
        assert!(out.message.unwrap().contains("goal 0: position"));
        // A valid target where an error was expected is a failure.
        c.target = DVec3::new(0.3, 0.4, 0.0);
        let out = run_case(&c, "ccd");
        assert!(
            out.failures
                .iter()
                .any(|f| f.contains("accepted bad input"))
        );
    }

    #[test]
    fn the_checks_catch_a_lying_report() {
        // A report that claims convergence for an untouched pose far from the target.
        let c = case("lie", w2(), DVec3::new(0.3, 0.4, 0.0));
        let skeleton = Skeleton::chain(c.root, &c.offsets).unwrap();
        let chain = Chain::whole(&skeleton).unwrap();
        let pose = skeleton.rest_pose();
        let mut global = GlobalPose::new();
        skeleton.forward_kinematics(&pose, &mut global).unwrap();
        let report = SolveReport {
            iterations: 1,
            initial_error: global.positions[9].distance(c.target),
            error: 0.0,
            initial_rotation_error: 0.0,
            rotation_error: 0.0,
            limit_violation: 0.0,
            restarted: false,
            stop: StopReason::Converged,
        };
        let mut out = run_case(&c, "ccd");
        out.failures.clear();
        check_solve(
            &mut out, &c, &skeleton, &chain, &pose, &pose, &global, &report,
        );
        assert!(out.failures.iter().any(|f| f.contains("reported error")));
        assert!(
            out.failures
                .iter()
                .any(|f| f.contains("claims convergence"))
        );
    }

    #[test]
    fn the_checks_catch_a_stretched_bone_and_a_short_straight_chain() {
        // A chain whose second bone is scaled by a rotation that is not unit cannot be
        // made through the API, so the check is fed a skeleton with a longer bone than
        // the chain it is measured against.
        let c = case("beyond", xs(&[1.0, 1.0]), DVec3::new(0.0, 5.0, 0.0));
        let skeleton = Skeleton::chain(c.root, &c.offsets).unwrap();
        let chain = Chain::whole(&skeleton).unwrap();
        let longer = Skeleton::chain(c.root, &xs(&[1.0, 1.0 + 1e-9])).unwrap();
        let pose = skeleton.rest_pose();
        let mut global = GlobalPose::new();
        longer.forward_kinematics(&pose, &mut global).unwrap();
        let report = SolveReport {
            iterations: 0,
            initial_error: global.positions[2].distance(c.target),
            error: global.positions[2].distance(c.target),
            initial_rotation_error: 0.0,
            rotation_error: 0.0,
            limit_violation: 0.0,
            restarted: false,
            stop: StopReason::OutOfReach,
        };
        let mut out = run_case(&c, "ccd");
        out.failures.clear();
        out.bone_error_ratio = 0.0;
        check_solve(
            &mut out, &c, &longer, &chain, &pose, &pose, &global, &report,
        );
        assert!(out.bone_error_ratio > 1.0);
        // The rest pose points along x, not at the target: not straightened at it.
        assert!(out.failures.iter().any(|f| f.contains("beyond the reach")));
    }

    #[test]
    fn error_bound_uses_the_inner_radius() {
        let c = case("inner", xs(&[1.0, 0.5]), DVec3::ZERO);
        let out = run_case(&c, "fabrik");
        assert_eq!(out.error_bound, 0.5);
        assert!(out.failures.is_empty(), "{:?}", out.failures);
    }
}
