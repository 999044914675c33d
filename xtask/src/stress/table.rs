//! The stress run's console tables and `stress.md`: the cloth grid as one table per grid
//! size (rows stiffness x time step, columns initial state), a flat table of every cloth
//! case, the IK table (one row per case and solver), then the failures.

use super::StressResults;
use sinew_bench::stress::body::BodyOutcome;
use sinew_bench::stress::cloth::{ClothIntegrator, ClothOutcome, InitialState, dt_label};
use sinew_bench::stress::ik::IkOutcome;
use std::fmt::Write;

/// The (integrator, grid size) pairs present, in order: one table each.
fn grids(results: &StressResults) -> Vec<(ClothIntegrator, usize)> {
    let mut g: Vec<(ClothIntegrator, usize)> = results
        .cloth
        .iter()
        .map(|o| (o.case.integrator, o.case.grid))
        .collect();
    g.dedup();
    g
}

/// The cloth cell: `max/mean` Newton iterations, then markers: `rN` N steps stopped at
/// round-off, `FN` N steps stopped far from converged, `EN` N energy-inequality breaks,
/// `DIVERGED`; a leading `!` when the case failed.
#[must_use]
pub fn cloth_cell(o: &ClothOutcome) -> String {
    let mut s = String::new();
    if !o.failures.is_empty() {
        s.push('!');
    }
    if o.diverged.is_some() {
        s.push_str("DIVERGED");
        return s;
    }
    let _ = write!(s, "{}/{:.1}", o.iterations_max, o.iterations_mean);
    if o.roundoff_stops > 0 {
        let _ = write!(s, " r{}", o.roundoff_stops);
    }
    if o.far_stops > 0 {
        let _ = write!(s, " F{}", o.far_stops);
    }
    if o.inequality_breaks > 0 {
        let _ = write!(s, " E{}", o.inequality_breaks);
    }
    s
}

/// Rows of (stiffness, dt) of one grid size, each with its outcomes by state.
/// The steps each case of the `grid` x `grid` cloth ran for (0 when none ran).
fn steps_per_case(results: &StressResults, (integrator, grid): (ClothIntegrator, usize)) -> usize {
    results
        .cloth
        .iter()
        .find(|o| o.case.grid == grid && o.case.integrator == integrator)
        .map_or(0, |o| o.case.steps)
}

/// A markdown table of one grid: a row per stiffness and time step, a column per initial
/// state, each case's cell written by `cell` (`-` where the case did not run).
fn grid_table(
    s: &mut String,
    table: &[(f64, f64, Vec<Option<&ClothOutcome>>)],
    cell: impl Fn(&ClothOutcome) -> String,
) {
    let _ = write!(s, "| k | dt |");
    for st in InitialState::ALL {
        let _ = write!(s, " {} |", st.name());
    }
    let _ = write!(s, "\n|---:|---:|");
    for _ in InitialState::ALL {
        s.push_str("---:|");
    }
    s.push('\n');
    for (k, dt, cells) in table {
        let _ = write!(s, "| {k:.0e} | {} |", dt_label(*dt));
        for c in cells {
            let _ = write!(s, " {} |", c.map_or_else(|| "-".into(), &cell));
        }
        s.push('\n');
    }
}

fn rows(
    results: &StressResults,
    (integrator, grid): (ClothIntegrator, usize),
) -> Vec<(f64, f64, Vec<Option<&ClothOutcome>>)> {
    let mut out: Vec<(f64, f64, Vec<Option<&ClothOutcome>>)> = Vec::new();
    for o in results
        .cloth
        .iter()
        .filter(|o| o.case.grid == grid && o.case.integrator == integrator)
    {
        let col = InitialState::ALL
            .iter()
            .position(|s| *s == o.case.state)
            .unwrap_or(0);
        match out
            .iter_mut()
            .find(|(k, dt, _)| *k == o.case.stiffness && *dt == o.case.dt)
        {
            Some((_, _, cells)) => cells[col] = Some(o),
            None => {
                let mut cells = vec![None; InitialState::ALL.len()];
                cells[col] = Some(o);
                out.push((o.case.stiffness, o.case.dt, cells));
            }
        }
    }
    out
}

fn ik_status(o: &IkOutcome) -> &'static str {
    if !o.failures.is_empty() {
        "FAIL"
    } else if o.message.is_some() {
        "error (expected)"
    } else if o.not_converged {
        "not converged (reported)"
    } else {
        "ok"
    }
}

fn ik_stop(o: &IkOutcome) -> String {
    o.stop.map_or_else(|| "-".into(), |s| s.name().to_string())
}

/// The console report.
#[must_use]
pub fn console(results: &StressResults, failures: &[String], unconverged: &[String]) -> String {
    let mut s = String::new();
    for table in grids(results) {
        let steps = steps_per_case(results, table);
        let (integrator, grid) = table;
        let integrator = integrator.name();
        let _ = writeln!(
            s,
            "\ncloth {grid}x{grid} {integrator}, {steps} steps per case: Newton iterations max/mean (r: stops at round-off, F: far from converged, E: energy inequality broken, !: failed)"
        );
        let _ = write!(s, "{:>6} {:>7}", "k", "dt");
        for st in InitialState::ALL {
            let _ = write!(s, " {:>14}", st.name());
        }
        s.push('\n');
        for (k, dt, cells) in rows(results, table) {
            let _ = write!(s, "{k:>6.0e} {:>7}", dt_label(dt));
            for c in cells {
                let _ = write!(s, " {:>14}", c.map_or_else(|| "-".into(), cloth_cell));
            }
            s.push('\n');
        }
    }
    if !results.cloth.is_empty() {
        let worst_rise = results
            .cloth
            .iter()
            .map(|o| o.energy_increase_max)
            .fold(0.0, f64::max);
        let _ = writeln!(
            s,
            "cloth: {} cases in {:.1} s; largest relative energy increase in one step {worst_rise:.2e}",
            results.cloth.len(),
            results.cloth_seconds
        );
    }
    if !results.ik.is_empty() {
        let _ = writeln!(
            s,
            "\n{:<52} {:<12} {:>6} {:>14} {:>5} {:>10} {:>10} {:>8}  status",
            "ik case", "solver", "bones", "stop", "iter", "error", "bound", "bone/al"
        );
        for o in &results.ik {
            let _ = writeln!(
                s,
                "{:<52} {:<12} {:>6} {:>14} {:>5} {:>10.3e} {:>10.3e} {:>8.3}  {}",
                o.case,
                o.solver,
                o.bones,
                ik_stop(o),
                o.iterations,
                o.measured_error,
                o.error_bound,
                o.bone_error_ratio,
                ik_status(o)
            );
        }
        let _ = writeln!(
            s,
            "ik: {} solves in {:.1} s",
            results.ik.len(),
            results.ik_seconds
        );
    }
    if !results.body.is_empty() {
        let _ = writeln!(
            s,
            "\n{:<40} {:<12} {:>10} {:>10} {:>10} {:>10} {:>10}  status",
            "body case", "solver", "error", "cost 0", "cost", "limit", "fk gap"
        );
        for o in &results.body {
            let figures = [o.max_error, o.cost.0, o.cost.1, o.limit_violation, o.fk_gap];
            let figures: String = figures.iter().map(|x| format!(" {x:>10.3e}")).collect();
            let status = body_status(o);
            let _ = writeln!(s, "{:<40} {:<12}{figures}  {status}", o.case, o.solver);
        }
        let (count, seconds) = (results.body.len(), results.body_seconds);
        let _ = writeln!(s, "body: {count} solves in {seconds:.1} s");
    }
    if !unconverged.is_empty() {
        let _ = writeln!(
            s,
            "\ncases with a step left far from converged ({}; reported, not failures unless --strict):",
            unconverged.len()
        );
        for u in unconverged {
            let _ = writeln!(s, "  {u}");
        }
    }
    if failures.is_empty() {
        let _ = writeln!(s, "\nfailures: none");
    } else {
        let _ = writeln!(s, "\nfailures ({}):", failures.len());
        for f in failures {
            let _ = writeln!(s, "  {f}");
        }
    }
    s
}

/// `stress.md`.
#[must_use]
pub fn markdown(results: &StressResults, failures: &[String], unconverged: &[String]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Stress grid\n");
    let _ = writeln!(
        s,
        "Generated by `cargo xtask stress{}{}` on {}. Cloth: {} cases in {:.0} s; IK: {} solves in {:.1} s; full body: {} solves in {:.1} s. What is checked and why: [docs/stress.md](../stress.md).\n",
        if results.command.is_empty() { "" } else { " " },
        results.command,
        results.machine.describe(),
        results.cloth.len(),
        results.cloth_seconds,
        results.ik.len(),
        results.ik_seconds,
        results.body.len(),
        results.body_seconds
    );
    let _ = writeln!(
        s,
        "Failures (NaN, divergence, a broken invariant, a wrong report): {}. Cases (cloth, contact, self-contact) with a step left far from converged (reported, not failures; `--strict` fails on them): {}.\n",
        if failures.is_empty() {
            "none".to_string()
        } else {
            format!("{} (listed at the end)", failures.len())
        },
        if unconverged.is_empty() {
            "none".to_string()
        } else {
            format!("{} (listed at the end)", unconverged.len())
        }
    );
    if !results.cloth.is_empty() {
        cloth_markdown(&mut s, results);
    }
    if !results.ik.is_empty() {
        ik_markdown(&mut s, results);
    }
    if !results.body.is_empty() {
        body_markdown(&mut s, results);
    }
    if !unconverged.is_empty() {
        let _ = writeln!(
            s,
            "## Steps left far from converged\n\nThe first such step of each case (the solver reported `IterationCap`, `LineSearchStalled` or `RoundOff`; a broken invariant of the case would be listed under Failures):\n"
        );
        for u in unconverged {
            let _ = writeln!(s, "- {u}");
        }
        s.push('\n');
    }
    let _ = writeln!(s, "## Failures\n");
    if failures.is_empty() {
        let _ = writeln!(s, "None.");
    } else {
        for f in failures {
            let _ = writeln!(s, "- {f}");
        }
    }
    s
}

fn cloth_markdown(s: &mut String, results: &StressResults) {
    let _ = writeln!(s, "## Cloth\n");
    let _ = writeln!(
        s,
        "The lab cloth (W4's springs, corners (0, 0) and (0, n-1) pinned, the sheet 2 wide, mass 1, gravity 0.3, no damping) stepped by the default backward Euler (`NewtonSettings::default()`: tolerance 1e-9 m/h^2, cap 50, raised to 200 where k h^2 / m >= 1e5, docs/stress.md), by `auto` (its defaults, the same Newton settings for its BDF2 steps) and by BDF2 (the same Newton settings); the energy inequality is checked on backward Euler steps only (BDF2's starting steps are not). Cell: Newton iterations per step, max/mean; `rN`: N steps stopped (cap or stalled line search) at or below the round-off floor; `FN`: N steps stopped far from converged (reported); `EN`: N energy-inequality breaks; `DIVERGED`; `!`: the case failed.\n"
    );
    for pair in grids(results) {
        let steps = steps_per_case(results, pair);
        let (integrator, grid) = pair;
        let integrator = integrator.name();
        let _ = writeln!(
            s,
            "### {grid} x {grid}, {integrator} ({steps} steps per case)\n"
        );
        let table = rows(results, pair);
        grid_table(s, &table, cloth_cell);
        let _ = writeln!(
            s,
            "\nLargest rise of the total energy in one step, relative to the run's starting `kinetic + spring + |gravity|` (0: never rose):\n"
        );
        grid_table(s, &table, |o| sci(o.energy_increase_max));
        s.push('\n');
    }
    let _ = writeln!(
        s,
        "<details><summary>Every cloth case</summary>\n\n| case | steps | it max | it mean | backtracks | residual/tol max | cap | stalled | round-off stop | at round-off | far | unconverged residual / max(tol, floor) | energy rise max | inequality excess / slack max | s |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for o in &results.cloth {
        let _ = writeln!(
            s,
            "| {}{} | {} | {} | {:.2} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2} |",
            o.case.label(),
            if o.failures.is_empty() {
                ""
            } else {
                " **FAIL**"
            },
            o.steps_run,
            o.iterations_max,
            o.iterations_mean,
            o.backtracks,
            sci(o.residual_ratio_max),
            o.cap_steps,
            o.stalled_steps,
            o.roundoff_claims,
            o.roundoff_stops,
            o.far_stops,
            if o.cap_steps + o.stalled_steps + o.roundoff_claims == 0 {
                "-".into()
            } else {
                sci(o.unconverged_ratio_max)
            },
            sci(o.energy_increase_max),
            sci(o.inequality_excess_max),
            o.seconds
        );
    }
    let _ = writeln!(s, "\n</details>\n");
}

fn ik_markdown(s: &mut String, results: &StressResults) {
    let _ = writeln!(s, "## IK\n");
    let _ = writeln!(
        s,
        "Every case with every solver (`ccd` = `CcdSolver::new()`, `ccd-plain` = `CcdSolver::plain()`, `fabrik` = `FabrikSolver::new()` (hybrid), `fabrik-plain` = `FabrikSolver::plain()`), cap 100 and tolerance 1e-6 unless the case says otherwise, from the rest pose (a straight chain along +x) unless it says otherwise. `d`: target distance from the base; `least`: the least error any pose can have, `max(0, d - reach, r_min - d)`; `error`: measured on forward kinematics of the returned pose; `bone/allow`: the worst bone-length error over its allowance `1e-12 L + 4 EPS |P|` (at most 1).\n"
    );
    let _ = writeln!(
        s,
        "| case | solver | bones | d | reach | least | stop | iterations | error | bone/allow | ms | status |\n|---|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---|"
    );
    for o in &results.ik {
        let status = match &o.message {
            Some(m) if o.failures.is_empty() => format!("error (expected): {m}"),
            _ => ik_status(o).to_string(),
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.3} | {:.2} | {} |",
            o.case,
            o.solver,
            o.bones,
            sci(o.distance),
            sci(o.reach),
            sci(o.error_bound),
            ik_stop(o),
            o.iterations,
            sci(o.measured_error),
            o.bone_error_ratio,
            o.seconds * 1e3,
            status.replace('|', "\\|")
        );
    }
    s.push('\n');
}

/// `ok`, the solver's error, or the first broken invariant of a full-body solve.
fn body_status(o: &BodyOutcome) -> String {
    match (o.violations.first(), &o.error) {
        (Some(v), _) => format!("FAIL: {v}"),
        (None, Some(e)) => format!("error: {e}"),
        (None, None) => "ok".into(),
    }
}

fn body_markdown(s: &mut String, results: &StressResults) {
    let _ = writeln!(
        s,
        "## Full body
"
    );
    let _ = writeln!(
        s,
        "Every case with every configuration of `BodySolverOptions::NAMED`, from the rest pose ({} solves in {:.1} s). `error`: the reported worst effector error; `cost 0`, `cost`: the weighted cost at the start and the end (never higher at the end); `limit`: the largest joint-limit violation of the returned pose (radians); `fk gap`: the largest distance between the returned global pose and forward kinematics of the returned pose, computed here.\n",
        results.body.len(),
        results.body_seconds
    );
    let _ = writeln!(
        s,
        "| case | solver | error | cost 0 | cost | limit | fk gap | status |\n|---|---|---:|---:|---:|---:|---:|---|"
    );
    for o in &results.body {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} |",
            o.case,
            o.solver,
            sci(o.max_error),
            sci(o.cost.0),
            sci(o.cost.1),
            sci(o.limit_violation),
            sci(o.fk_gap),
            body_status(o).replace('|', "\\|")
        );
    }
    s.push('\n');
}

/// `1.23e-4`, `0`, or `-` for NaN.
fn sci(x: f64) -> String {
    if x.is_nan() {
        "-".into()
    } else if x == 0.0 {
        "0".into()
    } else {
        format!("{x:.2e}")
    }
}
