//! A whole run and the metrics a scene runner prints for it (docs/scenes.md keys:
//! `steps`, `integrator`, `newton_iterations_total`, `newton_iterations_max`,
//! `residual_max`, `energy_start`, `energy_end`, `energy_increase_max`,
//! `time_per_step_ms_median`, `diverged`), computed one way for every integrator.

use crate::integrator::Simulation;
use crate::model::Energies;
use crate::report::{StepError, StepReport};
use std::time::Instant;

/// Positions farther than this from the origin count as a divergence (docs/workloads.md W5).
pub const DIVERGENCE_RADIUS: f64 = 100.0;

/// Metrics of a run of steps.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct RunMetrics {
    /// Steps completed.
    pub steps: usize,
    /// Integrator name (`IntegratorKind::name`).
    pub integrator: String,
    /// Sum of Newton (or fixed) iterations over the steps.
    pub newton_iterations_total: usize,
    /// Largest iteration count of a step.
    pub newton_iterations_max: usize,
    /// Largest final `|grad g|_inf` of a step (a force; 0 for explicit integrators).
    pub residual_max: f64,
    /// Total energy (kinetic + spring + gravity) before the first step.
    pub energy_start: f64,
    /// Total energy after the last completed step.
    pub energy_end: f64,
    /// Largest rise of the total energy over one step, relative to the starting
    /// energies' [`Energies::scale`](crate::model::Energies::scale) (0 when it never
    /// rose).
    pub energy_increase_max: f64,
    /// Median wall-clock time of a step in milliseconds.
    pub time_per_step_ms_median: f64,
    /// Whether the run stopped on a non-finite value or a particle beyond
    /// [`DIVERGENCE_RADIUS`].
    pub diverged: bool,
    /// The error that stopped the run early, if any (input errors are returned by
    /// [`run`] instead). Serialized only when set, so a run that finished writes the
    /// same keys as before this field existed.
    #[cfg_attr(feature = "serde", serde(skip_serializing_if = "Option::is_none"))]
    pub stopped_by: Option<String>,
}

/// Runs `steps` steps of length `dt` and measures them. Invalid input (a bad `dt`) is an
/// error; a divergence ends the run and is reported in the metrics.
pub fn run(sim: &mut Simulation, dt: f64, steps: usize) -> Result<RunMetrics, StepError> {
    run_observed(sim, dt, steps, |_, _, _| {})
}

/// [`run`], calling `observe(step_index, report, sim)` after every step that succeeded
/// (for pictures, per-step plots and checks of the state, or of the pieces the step
/// recorded: [`Simulation::piece_ends`]). The observer runs outside the timed part, so
/// it cannot change `time_per_step_ms_median`. It may also steer the next step (drive
/// a collider to where an animation puts it at that step's end:
/// [`Simulation::drive_collider`]); what it changes applies from the next step on.
pub fn run_observed(
    sim: &mut Simulation,
    dt: f64,
    steps: usize,
    mut observe: impl FnMut(usize, &StepReport, &mut Simulation),
) -> Result<RunMetrics, StepError> {
    crate::model::check_time_step(dt)?;
    let start = sim.system().energies();
    let energy_start = start.total();
    let mut metrics = RunMetrics {
        steps: 0,
        integrator: String::new(),
        newton_iterations_total: 0,
        newton_iterations_max: 0,
        residual_max: 0.0,
        energy_start,
        energy_end: energy_start,
        energy_increase_max: 0.0,
        time_per_step_ms_median: 0.0,
        diverged: false,
        stopped_by: None,
    };
    let mut times = Vec::with_capacity(steps);
    for _ in 0..steps {
        let started = Instant::now();
        let result = sim.step(dt);
        times.push(started.elapsed().as_secs_f64() * 1e3);
        let report: StepReport = match result {
            Ok(r) => r,
            Err(e @ StepError::NonFinite { .. }) => {
                metrics.diverged = true;
                metrics.stopped_by = Some(e.to_string());
                break;
            }
            Err(e) => return Err(e),
        };
        metrics.steps += 1;
        metrics.integrator = report.integrator.name().to_string();
        metrics.newton_iterations_total += report.iterations;
        metrics.newton_iterations_max = metrics.newton_iterations_max.max(report.iterations);
        metrics.residual_max = metrics.residual_max.max(report.residual);
        let rise = Energies::relative_rise(&start, &report.energy_before, &report.energy_after);
        metrics.energy_increase_max = metrics.energy_increase_max.max(rise);
        metrics.energy_end = report.energy_after.total();
        observe(metrics.steps - 1, &report, sim);
        if sim
            .system()
            .positions()
            .iter()
            .any(|x| x.length() > DIVERGENCE_RADIUS)
        {
            metrics.diverged = true;
            metrics.stopped_by = Some(format!(
                "a particle left the ball of radius {DIVERGENCE_RADIUS}"
            ));
            break;
        }
    }
    times.sort_by(f64::total_cmp);
    metrics.time_per_step_ms_median = times.get(times.len() / 2).copied().unwrap_or(0.0);
    Ok(metrics)
}
