//! Cloth: every integrator of sinew-spring-sim on W4 (damping 0 and 0.2), W5 (k = 1e4
//! and 1e6) and W6, over its knobs (backward Euler: Newton tolerance and linear solver;
//! explicit integrators: substeps as multiples of the stability bound's count), `auto`,
//! and the lab report's flawed method as a reference.
//!
//! Two errors per run, each after 1 s and at the end (max distance over particles):
//! - from backward Euler solved to `|grad g|_inf <= 1e-12 m/h^2` at the same step (the
//!   implicit solver's error; only meaningful for backward Euler itself);
//! - from the true motion: velocity Verlet at 64 times the stability bound's substeps,
//!   checked against 32 times (docs/workloads.md). The check is stored beside the error.
//!
//! Backward Euler at each tolerance is also measured one step at a time: from each state of
//! the converged reference's first second, one step at the tolerance against the same step
//! solved to 1e-12 (the error from the exact step, without the accumulation over steps).
//!
//! Stiff runs are ranked (plotted) by the 1 s figure: after 10 s a stiff cloth's motion is
//! chaotic. W6 runs 30 steps (0.5 s), so its figures are at 0.5 s.

use super::{Metric, Metrics, Plan, Record, Section, sci, timing_of};
use serde_json::json;
use sinew_math::DVec3;
use sinew_spring_sim::DIVERGENCE_RADIUS;
use sinew_spring_sim::StabilityBound;
use sinew_spring_sim::{
    AutoSettings, Energies, Integrator, LinearSolverChoice, NewtonSettings, Simulation,
    SpringSystem, StepStop,
};
use std::time::Instant;

use sinew_scene::workloads::ClothWorkload as Workload;

fn workloads(plan: &Plan) -> Result<Vec<Workload>, String> {
    sinew_scene::workloads::cloth(plan.quick)
}

fn newton(tolerance: f64, linear_solver: LinearSolverChoice) -> NewtonSettings {
    NewtonSettings {
        tolerance,
        linear_solver,
        ..NewtonSettings::default()
    }
}

/// Backward Euler's Newton tolerances (`|grad g|_inf <= tol m/h^2`), linear solver `auto`:
/// every decade from 1e-3 to 1e-12 in the full run, so the table shows the error from the
/// exact step shrinking with the tolerance; the quick run keeps the two ends' neighbours.
pub fn tolerances(plan: &Plan) -> &'static [f64] {
    if plan.quick {
        &[1e-3, 1e-9]
    } else {
        &[
            1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12,
        ]
    }
}

/// The knobs label of backward Euler at tolerance `tol` with the linear solver `auto`.
#[must_use]
pub fn tolerance_knobs(tol: f64) -> String {
    format!("tol {}, linear auto", sci(tol))
}

/// The integrators and knobs run on a workload whose stability bound asks for `bound`
/// substeps per step.
fn integrators(plan: &Plan, bound: usize) -> Vec<(&'static str, String, Integrator)> {
    use LinearSolverChoice::{Auto, Direct, Pcg};
    let mut out = Vec::new();
    for &tol in tolerances(plan) {
        out.push((
            "backward_euler",
            tolerance_knobs(tol),
            Integrator::BackwardEuler(newton(tol, Auto)),
        ));
    }
    if !plan.quick {
        for (name, choice) in [("direct", Direct), ("pcg", Pcg)] {
            out.push((
                "backward_euler",
                format!("tol 1e-9, linear {name}"),
                Integrator::BackwardEuler(newton(1e-9, choice)),
            ));
        }
        out.push((
            "implicit_midpoint",
            "tol 1e-9".into(),
            Integrator::ImplicitMidpoint(NewtonSettings::default()),
        ));
    }
    out.push((
        "bdf2",
        "tol 1e-9".into(),
        Integrator::Bdf2(NewtonSettings::default()),
    ));
    let factors: &[usize] = if plan.quick { &[1] } else { &[1, 4, 16] };
    for &f in factors {
        let substeps = bound * f;
        out.push((
            "symplectic_euler",
            format!("{substeps} substeps ({f}x bound)"),
            Integrator::SymplecticEuler { substeps },
        ));
    }
    out.push((
        "velocity_verlet",
        "substeps from the bound".into(),
        Integrator::VelocityVerlet { substeps: None },
    ));
    if !plan.quick {
        for f in [4, 16] {
            let substeps = bound * f;
            out.push((
                "velocity_verlet",
                format!("{substeps} substeps ({f}x bound)"),
                Integrator::VelocityVerlet {
                    substeps: Some(substeps),
                },
            ));
        }
    }
    out.push((
        "auto",
        "default".into(),
        Integrator::Auto(AutoSettings::default()),
    ));
    out.push((
        "flawed_report_method",
        "reference only (32 fixed iterations)".into(),
        Integrator::FlawedReportMethod,
    ));
    out
}

/// A run's trajectory samples and statistics.
struct Run {
    at_one_second: Option<Vec<DVec3>>,
    end: Vec<DVec3>,
    steps_done: usize,
    seconds: f64,
    iterations_total: usize,
    iterations_max: usize,
    substeps_last: usize,
    backtracks: usize,
    unconverged_steps: usize,
    residual_over_tolerance_max: f64,
    energy_increase_max: f64,
    stopped_by: Option<String>,
}

/// The step after which the simulated time is closest to 1 s, if the run gets there.
fn one_second_step(w: &Workload) -> Option<usize> {
    let s = ((1.0 / w.dt).round() as usize).max(1);
    (s <= w.steps).then_some(s)
}

/// Runs `integrator` on the workload; the steps alone are timed.
fn simulate(w: &Workload, integrator: Integrator) -> Result<Run, String> {
    let mut sim = Simulation::new(w.system.clone(), integrator).map_err(|e| e.to_string())?;
    let one_second = one_second_step(w);
    // The scene runner's rise (docs/scenes.md, "Energy rise").
    let start = sim.system().energies();
    let mut run = Run {
        at_one_second: None,
        end: Vec::new(),
        steps_done: 0,
        seconds: 0.0,
        iterations_total: 0,
        iterations_max: 0,
        substeps_last: 0,
        backtracks: 0,
        unconverged_steps: 0,
        residual_over_tolerance_max: 0.0,
        energy_increase_max: 0.0,
        stopped_by: None,
    };
    for step in 0..w.steps {
        // Only the step is timed: the statistics and the divergence check below are the
        // harness's, not the integrator's.
        let started = Instant::now();
        let result = sim.step(w.dt);
        run.seconds += started.elapsed().as_secs_f64();
        let report = match result {
            Ok(r) => r,
            Err(e) => {
                run.stopped_by = Some(format!("step {}: {e}", step + 1));
                break;
            }
        };
        run.steps_done += 1;
        run.iterations_total += report.iterations;
        run.iterations_max = run.iterations_max.max(report.iterations);
        run.substeps_last = report.substeps;
        run.backtracks += report.backtracks;
        if matches!(
            report.stop,
            StepStop::IterationCap | StepStop::LineSearchStalled
        ) {
            run.unconverged_steps += 1;
        }
        if report.tolerance > 0.0 {
            run.residual_over_tolerance_max = run
                .residual_over_tolerance_max
                .max(report.residual / report.tolerance);
        }
        let rise = Energies::relative_rise(&start, &report.energy_before, &report.energy_after);
        run.energy_increase_max = run.energy_increase_max.max(rise);
        if Some(step + 1) == one_second {
            run.at_one_second = Some(sim.system().positions().to_vec());
        }
        if sim
            .system()
            .positions()
            .iter()
            .any(|p| !p.is_finite() || p.length() > DIVERGENCE_RADIUS)
        {
            run.stopped_by = Some(format!(
                "step {}: a particle left the ball of radius {DIVERGENCE_RADIUS}",
                step + 1
            ));
            break;
        }
    }
    run.end = sim.system().positions().to_vec();
    Ok(run)
}

fn max_distance(a: &[DVec3], b: &[DVec3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| p.distance(*q))
        .fold(0.0, f64::max)
}

/// Positions of a reference run at 1 s (if reached) and at the end.
struct Reference {
    at_one_second: Option<Vec<DVec3>>,
    end: Vec<DVec3>,
    residual_over_tolerance_max: f64,
}

fn reference(w: &Workload, integrator: Integrator, what: &str) -> Result<Reference, String> {
    let run = simulate(w, integrator)?;
    if let Some(why) = run.stopped_by {
        return Err(format!("{}: {what} reference stopped: {why}", w.name));
    }
    Ok(Reference {
        at_one_second: run.at_one_second,
        end: run.end,
        residual_over_tolerance_max: run.residual_over_tolerance_max,
    })
}

/// Distance of `run` from `reference` at 1 s and at the end (`INFINITY` when the run did
/// not get there).
fn errors(run: &Run, reference: &Reference, steps: usize) -> (Option<f64>, f64) {
    let at_one = match (&run.at_one_second, &reference.at_one_second) {
        (Some(a), Some(b)) => Some(max_distance(a, b)),
        (None, Some(_)) => Some(f64::INFINITY),
        _ => None,
    };
    let end = if run.steps_done == steps && run.stopped_by.is_none() {
        max_distance(&run.end, &reference.end)
    } else {
        f64::INFINITY
    };
    (at_one, end)
}

/// The converged reference's states before each step of its first second (all of its
/// steps when it is shorter), each with the positions one step later solved to 1e-12 by a
/// simulation started afresh at that state.
struct StepReference {
    states: Vec<SpringSystem>,
    exact: Vec<Vec<DVec3>>,
}

/// One backward Euler step at `tolerance` from `state`, in a simulation started afresh
/// there: its first guess is the prediction without the last step's correction, the same
/// for every tolerance and for the exact step.
fn one_step(state: &SpringSystem, dt: f64, tolerance: f64) -> Result<Vec<DVec3>, String> {
    let integrator = Integrator::BackwardEuler(newton(tolerance, LinearSolverChoice::Auto));
    let mut sim = Simulation::new(state.clone(), integrator).map_err(|e| e.to_string())?;
    sim.step(dt).map_err(|e| e.to_string())?;
    Ok(sim.system().positions().to_vec())
}

fn step_reference(w: &Workload) -> Result<StepReference, String> {
    let steps = one_second_step(w).unwrap_or(w.steps);
    let integrator = Integrator::BackwardEuler(newton(1e-12, LinearSolverChoice::Auto));
    let mut sim = Simulation::new(w.system.clone(), integrator).map_err(|e| e.to_string())?;
    let mut states = Vec::with_capacity(steps);
    let mut exact = Vec::with_capacity(steps);
    for step in 0..steps {
        states.push(sim.system().clone());
        exact.push(one_step(sim.system(), w.dt, 1e-12)?);
        sim.step(w.dt)
            .map_err(|e| format!("{}: step reference, step {}: {e}", w.name, step + 1))?;
    }
    Ok(StepReference { states, exact })
}

/// The largest distance of one step at `tolerance` from the exact step, over the reference's
/// states.
fn step_error(w: &Workload, reference: &StepReference, tolerance: f64) -> Result<f64, String> {
    let mut worst: f64 = 0.0;
    for (state, exact) in reference.states.iter().zip(&reference.exact) {
        let end = one_step(state, w.dt, tolerance)?;
        worst = worst.max(max_distance(&end, exact));
    }
    Ok(worst)
}

/// Runs the cloth section.
pub fn run(plan: &Plan) -> Result<Vec<Record>, String> {
    let mut records = Vec::new();
    for w in workloads(plan)? {
        let bound = StabilityBound::of(&w.system).substeps(w.dt).max(1);
        let be_ref = reference(
            &w,
            Integrator::BackwardEuler(newton(1e-12, LinearSolverChoice::Auto)),
            "backward Euler 1e-12",
        )?;
        let truth = reference(
            &w,
            Integrator::VelocityVerlet {
                substeps: Some(64 * bound),
            },
            "velocity Verlet 64x bound",
        )?;
        let check = reference(
            &w,
            Integrator::VelocityVerlet {
                substeps: Some(32 * bound),
            },
            "velocity Verlet 32x bound",
        )?;
        let truth_check_1s = match (&truth.at_one_second, &check.at_one_second) {
            (Some(a), Some(b)) => Some(max_distance(a, b)),
            _ => None,
        };
        let truth_check_end = max_distance(&truth.end, &check.end);
        let steps_reference = step_reference(&w)?;
        eprintln!(
            "  {}: bound {bound} substeps; true-motion reference check {:.1e} at 1 s, {:.1e} at the end; backward Euler 1e-12 reference residual/tol <= {:.2}",
            w.name,
            truth_check_1s.unwrap_or(f64::NAN),
            truth_check_end,
            be_ref.residual_over_tolerance_max
        );
        for (method, knobs, integrator) in integrators(plan, bound) {
            let first = simulate(&w, integrator)?;
            let mut times: Vec<f64> = Vec::with_capacity(plan.cloth_repeats);
            if first.stopped_by.is_none() {
                for _ in 0..plan.cloth_repeats {
                    let r = simulate(&w, integrator)?;
                    times.push(r.seconds / r.steps_done.max(1) as f64);
                }
            } else {
                times.push(first.seconds / first.steps_done.max(1) as f64);
            }
            let time = timing_of(&mut times);
            let (solver_1s, solver_end) = errors(&first, &be_ref, w.steps);
            let (true_1s, true_end) = errors(&first, &truth, w.steps);
            let mut metrics = Metrics::new();
            metrics.insert(Metric::Dt, json!(w.dt));
            metrics.insert(Metric::Steps, json!(w.steps));
            metrics.insert(Metric::StepsDone, json!(first.steps_done));
            metrics.insert(Metric::TimePerSimulatedSecondS, json!(time.median / w.dt));
            metrics.insert(Metric::TrueMotionError1s, json!(true_1s));
            metrics.insert(Metric::TrueMotionErrorEnd, json!(true_end));
            metrics.insert(Metric::SolverError1s, json!(solver_1s));
            metrics.insert(Metric::SolverErrorEnd, json!(solver_end));
            if let Integrator::BackwardEuler(settings) = integrator
                && matches!(settings.linear_solver, LinearSolverChoice::Auto)
            {
                let e = step_error(&w, &steps_reference, settings.tolerance)?;
                metrics.insert(Metric::StepErrorMax, json!(e));
            }
            metrics.insert(Metric::TrueMotionCheck1s, json!(truth_check_1s));
            metrics.insert(Metric::TrueMotionCheckEnd, json!(truth_check_end));
            metrics.insert(Metric::StabilityBoundSubsteps, json!(bound));
            metrics.insert(Metric::IterationsTotal, json!(first.iterations_total));
            metrics.insert(Metric::IterationsMax, json!(first.iterations_max));
            metrics.insert(Metric::SubstepsLastStep, json!(first.substeps_last));
            metrics.insert(Metric::Backtracks, json!(first.backtracks));
            metrics.insert(Metric::UnconvergedSteps, json!(first.unconverged_steps));
            metrics.insert(
                Metric::ResidualOverToleranceMax,
                json!(first.residual_over_tolerance_max),
            );
            metrics.insert(Metric::EnergyIncreaseMax, json!(first.energy_increase_max));
            metrics.insert(Metric::Diverged, json!(first.stopped_by.is_some()));
            let (error, error_name) = match true_1s {
                Some(e) => (e, "distance from the true motion after 1 s"),
                None => (true_end, "distance from the true motion at the end (0.5 s)"),
            };
            records.push(Record {
                section: Section::Cloth,
                workload: w.name.into(),
                method: method.into(),
                knobs,
                unit: "step",
                time,
                error,
                error_name,
                metrics,
                note: first.stopped_by.unwrap_or_default(),
            });
        }
        eprintln!("  {} done", w.name);
    }
    Ok(records)
}
