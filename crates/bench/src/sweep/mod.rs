//! The time-against-error sweeps behind `cargo xtask bench`: every method across its
//! knobs on the shared workloads (docs/workloads.md), each configuration a [`Record`] of
//! its median time per unit of work next to its error against an exact answer or a
//! converged reference.
//!
//! Every figure is the median of several timed repeats with the spread (smallest and
//! largest repeat) beside it; errors are measured once per configuration, untimed.
//! docs/bench.md describes the method.

pub mod cloth;
pub mod curves;
pub mod ik;

use serde::Serialize;
use std::time::Instant;

/// A part of the benchmark.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Section {
    /// CCD and FABRIK on W1 and W2.
    Ik,
    /// Uniform-parameter sampling against arc-length resampling on the lab flower.
    Curves,
    /// Every integrator on W4, W5 and W6.
    Cloth,
}

impl Section {
    /// Every section, in the order the benchmark runs them.
    pub const ALL: [Section; 3] = [Section::Ik, Section::Curves, Section::Cloth];

    /// The section's name as the command line and `results.json` spell it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Section::Ik => "ik",
            Section::Curves => "curves",
            Section::Cloth => "cloth",
        }
    }

    /// The section named `name` (as [`Section::name`] spells it); the error lists the
    /// names there are.
    pub fn parse(name: &str) -> Result<Section, String> {
        Section::ALL
            .into_iter()
            .find(|s| s.name() == name)
            .ok_or_else(|| format!("unknown section `{name}` (expected ik, curves or cloth)"))
    }
}

/// A metric of a benchmark record: the keys of [`Record::metrics`], spelt in
/// `results.json` as [`Metric::name`] says. A rename is a compile error wherever the
/// metric is read (the headline targets, the tables), not a silently missing row.
///
/// Variants are in the alphabetical order of their names, so `results.json` lists them
/// as it always has.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Metric {
    /// Line-search step halvings over the run.
    Backtracks,
    /// Mean final error over the targets drawn in the ball around the chain (W2 with limits).
    BallErrorMean,
    /// Solves of targets drawn in the ball around the chain.
    BallSolves,
    /// Why the ball solves stopped, counted by reason.
    BallStops,
    /// Ball solves that ended within 1e-6.
    BallWithin1e6,
    /// Largest bone-length error, in scene units.
    BoneLengthErrorMax,
    /// Whether the run diverged or stopped early.
    Diverged,
    /// The time step, in seconds.
    Dt,
    /// Largest rise of the total energy in one step, relative to the starting energy scale.
    EnergyIncreaseMax,
    /// Largest final error.
    ErrorMax,
    /// Mean final error.
    ErrorMean,
    /// Mean final error over targets drawn inside the joint limits.
    FeasibleErrorMean,
    /// Why the feasible solves stopped, counted by reason.
    FeasibleStops,
    /// Feasible solves that ended within 1e-6.
    FeasibleWithin1e6,
    /// Share of the feasible solves that ended within 1e-6.
    FeasibleWithinShare,
    /// Frames tracked.
    Frames,
    /// Frames that ended within 1e-6.
    FramesWithin1e6,
    /// Most iterations of one step.
    IterationsMax,
    /// Iterations over the whole workload.
    IterationsTotal,
    /// Distance of the measured length from the exact one.
    LengthError,
    /// Largest joint-limit violation, in radians.
    LimitViolationMax,
    /// Points taken.
    Points,
    /// Targets within reach.
    Reachable,
    /// Largest final error over the reachable targets.
    ReachableErrorMax,
    /// Mean final error over the reachable targets.
    ReachableErrorMean,
    /// Reachable targets solved within 1e-6.
    ReachableWithin1e6,
    /// Largest difference between a solver's reported error and forward kinematics'.
    ReportDisagreementMax,
    /// Largest final residual over Newton's tolerance.
    ResidualOverToleranceMax,
    /// Distance after 1 s from a converged backward Euler reference (the solver error).
    SolverError1s,
    /// Distance at the end from a converged backward Euler reference.
    SolverErrorEnd,
    /// Solves run.
    Solves,
    /// Largest relative deviation of the arc spacing from its mean.
    SpacingDeviation,
    /// The stability bound's substeps per step at the start.
    StabilityBoundSubsteps,
    /// Backward Euler at a tolerance: the largest distance, over the steps of the first
    /// second of the converged reference run, of one step taken from the reference's state
    /// from the same step solved to the reference's tolerance (the error from the exact step).
    StepErrorMax,
    /// Steps asked for.
    Steps,
    /// Steps completed.
    StepsDone,
    /// Substeps of the last step (explicit integrators).
    SubstepsLastStep,
    /// Median time per point taken, in seconds.
    TimePerPointS,
    /// Median wall time per simulated second, in seconds.
    TimePerSimulatedSecondS,
    /// How much halving the reference substep changes it after 1 s.
    TrueMotionCheck1s,
    /// How much halving the reference substep changes it at the end.
    TrueMotionCheckEnd,
    /// Distance after 1 s from the true motion (a velocity Verlet reference far below its stability limit).
    TrueMotionError1s,
    /// Distance at the end from the true motion.
    TrueMotionErrorEnd,
    /// Steps left at Newton's cap or with a stalled line search.
    UnconvergedSteps,
    /// Largest final error of an unreachable target beyond the least possible (distance - reach).
    UnreachableExcessMax,
}

impl Metric {
    /// Every metric, in the order of their names.
    pub const ALL: [Metric; 45] = [
        Metric::Backtracks,
        Metric::BallErrorMean,
        Metric::BallSolves,
        Metric::BallStops,
        Metric::BallWithin1e6,
        Metric::BoneLengthErrorMax,
        Metric::Diverged,
        Metric::Dt,
        Metric::EnergyIncreaseMax,
        Metric::ErrorMax,
        Metric::ErrorMean,
        Metric::FeasibleErrorMean,
        Metric::FeasibleStops,
        Metric::FeasibleWithin1e6,
        Metric::FeasibleWithinShare,
        Metric::Frames,
        Metric::FramesWithin1e6,
        Metric::IterationsMax,
        Metric::IterationsTotal,
        Metric::LengthError,
        Metric::LimitViolationMax,
        Metric::Points,
        Metric::Reachable,
        Metric::ReachableErrorMax,
        Metric::ReachableErrorMean,
        Metric::ReachableWithin1e6,
        Metric::ReportDisagreementMax,
        Metric::ResidualOverToleranceMax,
        Metric::SolverError1s,
        Metric::SolverErrorEnd,
        Metric::Solves,
        Metric::SpacingDeviation,
        Metric::StabilityBoundSubsteps,
        Metric::StepErrorMax,
        Metric::Steps,
        Metric::StepsDone,
        Metric::SubstepsLastStep,
        Metric::TimePerPointS,
        Metric::TimePerSimulatedSecondS,
        Metric::TrueMotionCheck1s,
        Metric::TrueMotionCheckEnd,
        Metric::TrueMotionError1s,
        Metric::TrueMotionErrorEnd,
        Metric::UnconvergedSteps,
        Metric::UnreachableExcessMax,
    ];

    /// The key in `results.json`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Metric::Backtracks => "backtracks",
            Metric::BallErrorMean => "ball_error_mean",
            Metric::BallSolves => "ball_solves",
            Metric::BallStops => "ball_stops",
            Metric::BallWithin1e6 => "ball_within_1e-6",
            Metric::BoneLengthErrorMax => "bone_length_error_max",
            Metric::Diverged => "diverged",
            Metric::Dt => "dt",
            Metric::EnergyIncreaseMax => "energy_increase_max",
            Metric::ErrorMax => "error_max",
            Metric::ErrorMean => "error_mean",
            Metric::FeasibleErrorMean => "feasible_error_mean",
            Metric::FeasibleStops => "feasible_stops",
            Metric::FeasibleWithin1e6 => "feasible_within_1e-6",
            Metric::FeasibleWithinShare => "feasible_within_share",
            Metric::Frames => "frames",
            Metric::FramesWithin1e6 => "frames_within_1e-6",
            Metric::IterationsMax => "iterations_max",
            Metric::IterationsTotal => "iterations_total",
            Metric::LengthError => "length_error",
            Metric::LimitViolationMax => "limit_violation_max",
            Metric::Points => "points",
            Metric::Reachable => "reachable",
            Metric::ReachableErrorMax => "reachable_error_max",
            Metric::ReachableErrorMean => "reachable_error_mean",
            Metric::ReachableWithin1e6 => "reachable_within_1e-6",
            Metric::ReportDisagreementMax => "report_disagreement_max",
            Metric::ResidualOverToleranceMax => "residual_over_tolerance_max",
            Metric::SolverError1s => "solver_error_1s",
            Metric::SolverErrorEnd => "solver_error_end",
            Metric::Solves => "solves",
            Metric::SpacingDeviation => "spacing_deviation",
            Metric::StabilityBoundSubsteps => "stability_bound_substeps",
            Metric::StepErrorMax => "step_error_max",
            Metric::Steps => "steps",
            Metric::StepsDone => "steps_done",
            Metric::SubstepsLastStep => "substeps_last_step",
            Metric::TimePerPointS => "time_per_point_s",
            Metric::TimePerSimulatedSecondS => "time_per_simulated_second_s",
            Metric::TrueMotionCheck1s => "true_motion_check_1s",
            Metric::TrueMotionCheckEnd => "true_motion_check_end",
            Metric::TrueMotionError1s => "true_motion_error_1s",
            Metric::TrueMotionErrorEnd => "true_motion_error_end",
            Metric::UnconvergedSteps => "unconverged_steps",
            Metric::UnreachableExcessMax => "unreachable_excess_max",
        }
    }
}

impl Serialize for Metric {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

/// The metrics of a record, keyed by [`Metric`].
pub type Metrics = std::collections::BTreeMap<Metric, serde_json::Value>;

/// How long and how often each configuration is timed.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Plan {
    /// Reduced workloads.
    pub quick: bool,
    /// Timed repeats of fast configurations (IK, curves).
    pub repeats: usize,
    /// Timed repeats of a whole cloth run.
    pub cloth_repeats: usize,
    /// A repeat of a fast configuration runs it this many seconds at least (it is
    /// repeated inside the timed region), so the clock's resolution does not matter.
    pub min_repeat_seconds: f64,
}

/// Median, smallest and largest of the timed repeats, in seconds per unit of work.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Timing {
    /// Median over the repeats.
    pub median: f64,
    /// Fastest repeat.
    pub min: f64,
    /// Slowest repeat.
    pub max: f64,
    /// Number of repeats.
    pub repeats: usize,
}

/// One configuration's result.
#[derive(Clone, Debug, Serialize)]
pub struct Record {
    /// The section.
    pub section: Section,
    /// Workload (and variant), e.g. "W1" or "W5 k=1e6".
    pub workload: String,
    /// Method, e.g. "fabrik" or "backward_euler".
    pub method: String,
    /// The knob settings, e.g. "cap 100, tol 1e-6".
    pub knobs: String,
    /// What a unit of work is ("frame", "solve", "step", "call").
    pub unit: &'static str,
    /// Time per unit of work.
    pub time: Timing,
    /// The error that the plot and the Pareto front use (`f64::INFINITY` for a run that
    /// diverged or failed).
    pub error: f64,
    /// What [`Record::error`] is.
    pub error_name: &'static str,
    /// Every other metric of the configuration (errors, iterations, counts).
    pub metrics: Metrics,
    /// Why a run stopped early or what else a reader must know (empty when nothing).
    pub note: String,
}

/// Runs `work` (one unit of work per call is `units` units) `plan.repeats` times after
/// one warm-up call, each repeat calling it enough times to last
/// `plan.min_repeat_seconds`; returns seconds per unit and the warm-up call's result.
pub fn measure<R>(
    plan: &Plan,
    repeats: usize,
    units: usize,
    mut work: impl FnMut() -> R,
) -> (Timing, R) {
    let started = Instant::now();
    let first = work();
    let once = started.elapsed().as_secs_f64().max(1e-9);
    let calls = ((plan.min_repeat_seconds / once).ceil() as usize).clamp(1, 1_000_000);
    let repeats = repeats.max(1);
    let mut per_unit = Vec::with_capacity(repeats);
    for _ in 0..repeats {
        let started = Instant::now();
        for _ in 0..calls {
            std::hint::black_box(work());
        }
        per_unit.push(started.elapsed().as_secs_f64() / (calls * units.max(1)) as f64);
    }
    (timing_of(&mut per_unit), first)
}

/// Median, min and max of measured times.
pub fn timing_of(times: &mut [f64]) -> Timing {
    times.sort_by(f64::total_cmp);
    let n = times.len();
    let median = if n == 0 {
        0.0
    } else if n % 2 == 1 {
        times[n / 2]
    } else {
        0.5 * (times[n / 2 - 1] + times[n / 2])
    };
    Timing {
        median,
        min: times.first().copied().unwrap_or(0.0),
        max: times.last().copied().unwrap_or(0.0),
        repeats: n,
    }
}

/// `1e-6`-style text for a knob value.
pub fn sci(x: f64) -> String {
    if x == 0.0 {
        return "0".into();
    }
    let e = x.abs().log10().floor();
    let m = x / 10f64.powf(e);
    if (m - 1.0).abs() < 1e-9 {
        format!("1e{e}")
    } else {
        format!("{x:.1e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timing_takes_the_median_and_the_extremes() {
        let t = timing_of(&mut [3.0, 1.0, 2.0, 10.0, 4.0]);
        assert_eq!((t.median, t.min, t.max, t.repeats), (3.0, 1.0, 10.0, 5));
        let t = timing_of(&mut [4.0, 1.0, 2.0, 3.0]);
        assert_eq!(t.median, 2.5);
    }

    #[test]
    fn measure_counts_units_and_returns_the_first_result() {
        let plan = Plan {
            quick: true,
            repeats: 3,
            cloth_repeats: 1,
            min_repeat_seconds: 0.0,
        };
        let mut calls = 0;
        let (t, first) = measure(&plan, 3, 10, || {
            calls += 1;
            calls
        });
        // One warm-up call plus one call per repeat.
        assert_eq!((first, calls, t.repeats), (1, 4, 3));
        assert!(t.min <= t.median && t.median <= t.max);
    }

    #[test]
    fn section_names_round_trip() {
        for s in Section::ALL {
            assert_eq!(Section::parse(s.name()), Ok(s));
        }
        assert!(Section::parse("cloths").unwrap_err().contains("cloths"));
    }

    #[test]
    fn metric_names_are_sorted_and_unique() {
        // The map's order is the variants' order; it must be the names' order so
        // results.json keeps its key order.
        let names: Vec<&str> = Metric::ALL.iter().map(|m| m.name()).collect();
        assert!(names.windows(2).all(|w| w[0] < w[1]), "{names:?}");
        let mut sorted = Metric::ALL;
        sorted.sort();
        assert_eq!(sorted, Metric::ALL);
    }

    #[test]
    fn knob_values_print_short() {
        assert_eq!(sci(1e-6), "1e-6");
        assert_eq!(sci(1e4), "1e4");
        assert_eq!(sci(2.5e-3), "2.5e-3");
    }
}
