//! IK: CCD and FABRIK (each as shipped and in its plain form) on W1 (flower tracking,
//! warm-started) and W2 (cold solves), over iteration caps and tolerances.
//!
//! Error is the final effector distance to the target, measured untimed by forward
//! kinematics of the returned pose (not taken from the solver's report; the two are
//! compared and the largest disagreement is a metric). Time is per frame (W1) or per
//! solve (W2) and covers the solves only.

use super::{Metric, Metrics, Plan, Record, Section, Timing, measure, sci};
use crate::seeded::{w2_targets, w7_ball, w7_feasible};
use serde_json::json;
use sinew_ik::SolverOptions;
use sinew_math::{DQuat, DVec3};
use sinew_scene::workloads::{w1_skeleton, w1_targets, w2_skeleton, w7_skeleton};
use sinew_skeleton::ik::{Chain, IkSolver, SolveSettings, chain_limit_violation};
use sinew_skeleton::{GlobalPose, Skeleton};

/// A solver with its label.
type NamedSolver = (&'static str, Box<dyn IkSolver>);

/// The solvers compared: the crates' defaults and their plain forms, from the library's
/// registry.
fn solvers() -> Result<Vec<NamedSolver>, String> {
    SolverOptions::NAMED
        .iter()
        .map(|&(name, options)| Ok((name, options.build().map_err(|e| e.to_string())?)))
        .collect()
}

/// The knob settings run for each solver and workload: caps at the lab tolerance, then
/// tolerances at the lab cap.
fn settings(plan: &Plan) -> Vec<SolveSettings> {
    let (caps, tolerances): (&[usize], &[f64]) = if plan.quick {
        (&[2, 100], &[1e-9])
    } else {
        (&[1, 2, 4, 8, 16, 32, 100], &[1e-3, 1e-9, 1e-12])
    };
    let mut out: Vec<SolveSettings> = caps
        .iter()
        .map(|&max_iterations| SolveSettings {
            max_iterations,
            tolerance: 1e-6,
            ..Default::default()
        })
        .collect();
    out.extend(tolerances.iter().map(|&tolerance| SolveSettings {
        max_iterations: 100,
        tolerance,
        ..Default::default()
    }));
    out
}

/// Per-target outcome of a sequence of solves.
struct Outcome {
    /// Effector distance to the target after each solve.
    errors: Vec<f64>,
    iterations: usize,
    /// Largest relative bone-length error after any solve (checked runs only).
    bone_length_error_max: f64,
    /// Largest |reported error - error by forward kinematics| (checked runs only).
    report_disagreement_max: f64,
    /// Largest joint-limit violation (radians) of a returned pose (checked runs only).
    limit_violation_max: f64,
    /// How many solves stopped for each reason.
    stops: std::collections::BTreeMap<&'static str, usize>,
}

/// Solves every target in order. `warm`: each solve starts from the previous pose (W1);
/// otherwise from the rest pose (W2). `check`: recompute forward kinematics after each
/// solve and measure the error and bone lengths from it (untimed runs only).
fn solve_all(
    solver: &mut dyn IkSolver,
    skeleton: &Skeleton,
    chain: &Chain,
    targets: &[DVec3],
    settings: &SolveSettings,
    warm: bool,
    check: bool,
) -> Result<Outcome, String> {
    let mut pose = skeleton.rest_pose();
    let mut global = GlobalPose::new();
    let mut fk = GlobalPose::new();
    let mut out = Outcome {
        errors: Vec::with_capacity(targets.len()),
        iterations: 0,
        bone_length_error_max: 0.0,
        report_disagreement_max: 0.0,
        limit_violation_max: 0.0,
        stops: std::collections::BTreeMap::new(),
    };
    let effector = chain.effector();
    for &target in targets {
        if !warm {
            pose.rotations.fill(DQuat::IDENTITY);
        }
        let report = solver
            .solve_position(skeleton, chain, &mut pose, &mut global, target, settings)
            .map_err(|e| format!("{}: {e}", solver.name()))?;
        out.iterations += report.iterations;
        if check {
            *out.stops.entry(report.stop.name()).or_insert(0) += 1;
            out.limit_violation_max = out
                .limit_violation_max
                .max(chain_limit_violation(skeleton, chain, &pose));
            skeleton
                .forward_kinematics(&pose, &mut fk)
                .map_err(|e| e.to_string())?;
            let error = fk.positions[effector].distance(target);
            out.report_disagreement_max = out
                .report_disagreement_max
                .max((error - report.error).abs());
            for (bone, &length) in chain.bone_lengths().iter().enumerate() {
                let (a, b) = (chain.joints()[bone], chain.joints()[bone + 1]);
                let measured = fk.positions[a].distance(fk.positions[b]);
                let relative = (measured - length).abs() / length.max(f64::MIN_POSITIVE);
                out.bone_length_error_max = out.bone_length_error_max.max(relative);
            }
            out.errors.push(error);
        } else {
            out.errors.push(report.error);
        }
    }
    Ok(out)
}

fn knobs(s: &SolveSettings) -> String {
    format!("cap {}, tol {}", s.max_iterations, sci(s.tolerance))
}

/// Runs the IK section.
pub fn run(plan: &Plan) -> Result<Vec<Record>, String> {
    let mut records = Vec::new();
    let w1 = w1_skeleton()?;
    let w1_chain = Chain::whole(&w1).map_err(|e| e.to_string())?;
    let w1_targets = w1_targets(500);
    let w2 = w2_skeleton()?;
    let w2_chain = Chain::whole(&w2).map_err(|e| e.to_string())?;
    let w2_targets = w2_targets(if plan.quick { 500 } else { 10_000 });
    for (name, mut solver) in solvers()? {
        for s in settings(plan) {
            let mut w1_subject = Subject {
                name,
                solver: solver.as_mut(),
                skeleton: &w1,
                chain: &w1_chain,
                settings: &s,
            };
            records.push(w1_record(plan, &mut w1_subject, &w1_targets)?);
            let mut w2_subject = Subject {
                skeleton: &w2,
                chain: &w2_chain,
                ..w1_subject
            };
            records.push(w2_record(plan, &mut w2_subject, &w2_targets)?);
        }
        eprintln!("  {name} done");
    }
    // W7, the arm with joint limits: both solvers as shipped, the lab's cap and tolerance.
    let w7 = w7_skeleton()?;
    let w7_chain = Chain::whole(&w7).map_err(|e| e.to_string())?;
    let count = if plan.quick { 200 } else { 10_000 };
    let feasible: Vec<DVec3> = w7_feasible(&w7, count)?.iter().map(|g| g.0).collect();
    let ball = w7_ball(count);
    for (name, mut solver) in solvers()? {
        if name.ends_with("-plain") {
            continue;
        }
        let s = SolveSettings::default();
        let mut subject = Subject {
            name,
            solver: solver.as_mut(),
            skeleton: &w7,
            chain: &w7_chain,
            settings: &s,
        };
        records.push(w7_record(plan, &mut subject, &feasible, &ball)?);
    }
    Ok(records)
}

/// A solver configuration on a workload's chain: what every record of this section
/// measures.
struct Subject<'a> {
    name: &'static str,
    solver: &'a mut dyn IkSolver,
    skeleton: &'a Skeleton,
    chain: &'a Chain,
    settings: &'a SolveSettings,
}

impl Subject<'_> {
    /// Solves every target (see [`solve_all`]).
    fn solve(&mut self, targets: &[DVec3], warm: bool, check: bool) -> Result<Outcome, String> {
        solve_all(
            self.solver,
            self.skeleton,
            self.chain,
            targets,
            self.settings,
            warm,
            check,
        )
    }

    /// The record of this configuration on `workload`.
    fn record(
        &self,
        workload: &str,
        unit: &'static str,
        time: Timing,
        (error, error_name): (f64, &'static str),
        metrics: Metrics,
    ) -> Record {
        Record {
            section: Section::Ik,
            workload: workload.into(),
            method: self.name.into(),
            knobs: knobs(self.settings),
            unit,
            time,
            error,
            error_name,
            metrics,
            note: String::new(),
        }
    }
}

/// W7: cold solves of the feasible targets (timed, the headline error), and the ball's
/// points, reported separately (stop reasons, errors; untimed).
fn w7_record(
    plan: &Plan,
    subject: &mut Subject,
    feasible: &[DVec3],
    ball: &[DVec3],
) -> Result<Record, String> {
    let checked = subject.solve(feasible, false, true)?;
    let (time, _) = measure(plan, plan.repeats, feasible.len(), || {
        subject.solve(feasible, false, false)
    });
    let outside = subject.solve(ball, false, true)?;
    let within = checked.errors.iter().filter(|&&e| e <= 1e-6).count();
    let error_max = checked.errors.iter().copied().fold(0.0, f64::max);
    let mut metrics = Metrics::new();
    metrics.insert(Metric::Solves, json!(feasible.len()));
    metrics.insert(Metric::FeasibleWithin1e6, json!(within));
    metrics.insert(
        Metric::FeasibleWithinShare,
        json!(within as f64 / feasible.len() as f64),
    );
    metrics.insert(Metric::FeasibleErrorMean, json!(mean(&checked.errors)));
    metrics.insert(Metric::FeasibleStops, json!(checked.stops));
    metrics.insert(
        Metric::LimitViolationMax,
        json!(checked.limit_violation_max.max(outside.limit_violation_max)),
    );
    metrics.insert(Metric::BallSolves, json!(ball.len()));
    metrics.insert(Metric::BallErrorMean, json!(mean(&outside.errors)));
    metrics.insert(
        Metric::BallWithin1e6,
        json!(outside.errors.iter().filter(|&&e| e <= 1e-6).count()),
    );
    metrics.insert(Metric::BallStops, json!(outside.stops));
    metrics.insert(Metric::IterationsTotal, json!(checked.iterations));
    checks_into(&mut metrics, &checked, false);
    Ok(subject.record(
        "W7",
        "solve",
        time,
        (
            error_max,
            "largest final distance over the feasible targets",
        ),
        metrics,
    ))
}

/// The iteration count and the report's agreement with forward kinematics (and, with
/// `bones`, the bone-length error) every IK record carries.
fn checks_into(metrics: &mut Metrics, checked: &Outcome, bones: bool) {
    if bones {
        metrics.insert(
            Metric::BoneLengthErrorMax,
            json!(checked.bone_length_error_max),
        );
    }
    metrics.insert(
        Metric::ReportDisagreementMax,
        json!(checked.report_disagreement_max),
    );
}

fn w1_record(plan: &Plan, subject: &mut Subject, targets: &[DVec3]) -> Result<Record, String> {
    let checked = subject.solve(targets, true, true)?;
    let (time, timed) = measure(plan, plan.repeats, targets.len(), || {
        subject.solve(targets, true, false)
    });
    let timed = timed?;
    let errors = &checked.errors;
    let error_max = errors.iter().copied().fold(0.0, f64::max);
    let within = errors.iter().filter(|&&e| e <= 1e-6).count();
    let mut metrics = Metrics::new();
    metrics.insert(Metric::Frames, json!(targets.len()));
    metrics.insert(Metric::ErrorMean, json!(mean(errors)));
    metrics.insert(Metric::ErrorMax, json!(error_max));
    metrics.insert(Metric::FramesWithin1e6, json!(within));
    // Warm-started tracking: the timed run's iterations are the ones that count.
    metrics.insert(Metric::IterationsTotal, json!(timed.iterations));
    checks_into(&mut metrics, &checked, true);
    Ok(subject.record(
        "W1",
        "frame",
        time,
        (error_max, "largest final distance over the 500 frames"),
        metrics,
    ))
}

fn w2_record(plan: &Plan, subject: &mut Subject, targets: &[DVec3]) -> Result<Record, String> {
    let checked = subject.solve(targets, false, true)?;
    let (time, _) = measure(plan, plan.repeats, targets.len(), || {
        subject.solve(targets, false, false)
    });
    let reach = subject.chain.reach();
    let root = DVec3::ZERO;
    let (mut reachable, mut unreachable_excess_max) = (Vec::new(), 0.0_f64);
    for (target, &error) in targets.iter().zip(&checked.errors) {
        let distance = target.distance(root);
        if distance <= reach {
            reachable.push(error);
        } else {
            // Out of reach the best possible error is distance - reach.
            unreachable_excess_max = unreachable_excess_max.max(error - (distance - reach));
        }
    }
    let within = reachable.iter().filter(|&&e| e <= 1e-6).count();
    let reachable_max = reachable.iter().copied().fold(0.0, f64::max);
    let mut metrics = Metrics::new();
    metrics.insert(Metric::Solves, json!(targets.len()));
    metrics.insert(Metric::Reachable, json!(reachable.len()));
    metrics.insert(Metric::ReachableWithin1e6, json!(within));
    metrics.insert(Metric::ReachableErrorMean, json!(mean(&reachable)));
    metrics.insert(Metric::ReachableErrorMax, json!(reachable_max));
    metrics.insert(Metric::UnreachableExcessMax, json!(unreachable_excess_max));
    metrics.insert(Metric::IterationsTotal, json!(checked.iterations));
    checks_into(&mut metrics, &checked, true);
    Ok(subject.record(
        "W2",
        "solve",
        time,
        (
            reachable_max,
            "largest final distance over the reachable targets",
        ),
        metrics,
    ))
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        0.0
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}
