//! Writes a benchmark run: `results.json` (every record, the machine, the plan),
//! `README.md` (the headline table against the issues' targets, then one table and one
//! plot per workload) and `plots/*.svg`.

use super::Results;
use sinew_bench::sweep::cloth::tolerance_knobs;
use sinew_bench::sweep::{Metric, Record, Section, Timing};
use sinew_viz::render::plot::{Point, pareto_front, time_error_svg};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// Seconds as text with a unit that keeps 3 significant digits readable.
pub fn fmt_time(s: f64) -> String {
    if !s.is_finite() {
        return "-".into();
    }
    let (v, unit) = if s >= 1.0 {
        (s, "s")
    } else if s >= 1e-3 {
        (s * 1e3, "ms")
    } else if s >= 1e-6 {
        (s * 1e6, "us")
    } else {
        (s * 1e9, "ns")
    };
    if v >= 100.0 {
        format!("{v:.0} {unit}")
    } else if v >= 10.0 {
        format!("{v:.1} {unit}")
    } else {
        format!("{v:.2} {unit}")
    }
}

fn fmt_timing(t: &Timing) -> String {
    format!(
        "{} [{} .. {}]",
        fmt_time(t.median),
        fmt_time(t.min),
        fmt_time(t.max)
    )
}

/// An error or other small number in short scientific notation.
pub fn fmt_err(x: f64) -> String {
    if x.is_nan() {
        "-".into()
    } else if x.is_infinite() {
        "diverged".into()
    } else if x == 0.0 {
        "0".into()
    } else {
        format!("{x:.1e}")
    }
}

fn metric(r: &Record, key: Metric) -> Option<f64> {
    r.metrics.get(&key).and_then(serde_json::Value::as_f64)
}

fn metric_text(r: &Record, key: Metric) -> String {
    metric(r, key).map_or("-".into(), fmt_err)
}

fn metric_count(r: &Record, key: Metric) -> String {
    r.metrics
        .get(&key)
        .and_then(serde_json::Value::as_u64)
        .map_or("-".into(), |v| v.to_string())
}

/// The area a headline target belongs to (the table's first column).
#[derive(Clone, Copy)]
enum Area {
    Ik,
    Cloth,
    Integrators,
}

impl Area {
    fn name(self) -> &'static str {
        match self {
            Area::Ik => "IK",
            Area::Cloth => "cloth",
            Area::Integrators => "integrators",
        }
    }
}

/// A headline target: the record it is measured on, its time limit and error check.
struct Target {
    area: Area,
    what: String,
    workload: &'static str,
    method: &'static str,
    knobs: &'static str,
    /// Time per unit at most this many seconds.
    time: f64,
    /// The error check: metric key and largest allowed value.
    error: Option<(Metric, f64)>,
}

/// The headline targets, derived from one short table per area: within an area the
/// method knobs, the unit and the kind of error check are shared, so a row holds only
/// what differs and the sentence is written from it.
fn targets() -> Vec<Target> {
    let mut out = Vec::new();
    // IK on the lab chain, iteration cap 100 and tolerance 1e-6:
    // (workload, method, microseconds per unit, unit, error metric checked against 1e-6).
    for (workload, method, us, unit, check) in [
        ("W1", "fabrik", 1.5, "frame", Some(Metric::ErrorMax)),
        ("W1", "ccd", 10.0, "frame", Some(Metric::ErrorMax)),
        (
            "W2",
            "fabrik",
            8.0,
            "solve",
            Some(Metric::ReachableErrorMax),
        ),
        ("W2", "ccd", 40.0, "solve", None),
    ] {
        let within = match check {
            Some(Metric::ErrorMax) => ", all frames within 1e-6",
            Some(_) => ", every reachable target within 1e-6",
            None => " (share within 1e-6 reported)",
        };
        let name = method.to_uppercase();
        out.push(Target {
            area: Area::Ik,
            what: format!("{workload} {name} <= {us} us/{unit}{within}"),
            workload,
            method,
            knobs: "cap 100, tol 1e-6",
            time: us * 1e-6,
            error: check.map(|m| (m, 1e-6)),
        });
    }
    // Cloth stepped by backward Euler solved to 1e-9, and the automatic integrator
    // held to 1e-4 of the true motion after 1 s: (workload, its label, time per step
    // in milliseconds for backward Euler and in microseconds for the automatic one).
    let be = [
        ("W4 d=0", "W4 (damping 0)", 0.15),
        ("W4 d=0.2", "W4 (damping 0.2)", 0.15),
        ("W5 k=1e6", "W5 k=1e6", 1.0),
        ("W6", "W6", 16.7),
    ];
    let auto = [
        ("W4 d=0", "W4 (damping 0)", 20.0),
        ("W4 d=0.2", "W4 (damping 0.2)", 20.0),
        ("W5 k=1e6", "W5 k=1e6", 200.0),
    ];
    let cloth = be.into_iter().map(|row| (Area::Cloth, row));
    let integrators = auto.into_iter().map(|row| (Area::Integrators, row));
    for (area, (workload, label, shown)) in cloth.chain(integrators) {
        let (method, knobs, time, what, error) = match area {
            Area::Cloth => (
                "backward_euler",
                "tol 1e-9, linear auto",
                shown * 1e-3,
                format!("{label} backward Euler to 1e-9 <= {shown} ms/step"),
                None,
            ),
            _ => (
                "auto",
                "default",
                shown * 1e-6,
                format!("{label} auto <= {shown} us/step, within 1e-4 of the true motion at 1 s"),
                Some((Metric::TrueMotionError1s, 1e-4)),
            ),
        };
        out.push(Target {
            area,
            what,
            workload,
            method,
            knobs,
            time,
            error,
        });
    }
    out
}

fn find<'a>(
    records: &'a [Record],
    workload: &str,
    method: &str,
    knobs: &str,
) -> Option<&'a Record> {
    records
        .iter()
        .find(|r| r.workload == workload && r.method == method && r.knobs == knobs)
}

/// The headline table (also printed on stdout).
fn headline(records: &[Record]) -> String {
    let mut s = String::from(
        "| area | target | measured (median [min .. max]) | error | time ratio |\n|---|---|---|---|---|\n",
    );
    for t in &targets() {
        let Some(r) = find(records, t.workload, t.method, t.knobs) else {
            continue;
        };
        let error = match t.error {
            Some((key, limit)) => {
                let v = metric(r, key).unwrap_or(f64::NAN);
                let verdict = if v <= limit { "met" } else { "NOT met" };
                format!("{} {} ({verdict})", key.name(), fmt_err(v))
            }
            None => headline_error(r),
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} per {} | {} | {:.2} |",
            t.area.name(),
            t.what,
            fmt_timing(&r.time),
            r.unit,
            error,
            r.time.median / t.time
        );
    }
    // Arc-length resampling against 50 000 uniform samples.
    let arclen = find(records, "flower", "arc length", "N 500, tol 1e-9");
    let uniform = find(records, "flower", "uniform parameter", "N 50000");
    if let (Some(a), Some(u)) = (arclen, uniform) {
        let _ = writeln!(
            s,
            "| curves | flower, 500 points at spacing deviation <= 1e-9, faster than 50 000 uniform samples ({} per call, deviation {}) | {} per call | deviation {} ({}) | {:.3} |",
            fmt_time(u.time.median),
            fmt_err(u.error),
            fmt_timing(&a.time),
            fmt_err(a.error),
            if a.error <= 1e-9 { "met" } else { "NOT met" },
            a.time.median / u.time.median
        );
    }
    s
}

fn headline_error(r: &Record) -> String {
    match r.section {
        Section::Ik => format!(
            "{} of {} reachable within 1e-6",
            metric_count(r, Metric::ReachableWithin1e6),
            metric_count(r, Metric::Reachable)
        ),
        Section::Cloth => match metric(r, Metric::SolverError1s) {
            Some(e) => format!("from backward Euler at 1e-12: {} at 1 s", fmt_err(e)),
            None => format!(
                "from backward Euler at 1e-12: {} at the end",
                metric_text(r, Metric::SolverErrorEnd)
            ),
        },
        Section::Curves => fmt_err(r.error),
    }
}

/// What a table cell shows of a record.
#[derive(Clone, Copy)]
enum Cell {
    /// The timing: median and spread.
    Timing,
    /// A metric as a short number (`-` when missing).
    Value(Metric),
    /// A count (`-` when missing).
    Count(Metric),
    /// `a / b` of two counts.
    OutOf(Metric, Metric),
    /// `total (max)` of two counts.
    WithMax(Metric, Metric),
    /// A time in seconds with its unit.
    Seconds(Metric),
    /// The record's note.
    Note,
}

impl Cell {
    fn text(self, r: &Record) -> String {
        match self {
            Cell::Timing => fmt_timing(&r.time),
            Cell::Value(m) => metric_text(r, m),
            Cell::Count(m) => metric_count(r, m),
            Cell::OutOf(a, b) => format!("{} / {}", metric_count(r, a), metric_count(r, b)),
            Cell::WithMax(a, b) => format!("{} ({})", metric_count(r, a), metric_count(r, b)),
            Cell::Seconds(m) => fmt_time(metric(r, m).unwrap_or(f64::NAN)),
            Cell::Note => r.note.clone(),
        }
    }
}

/// The columns after `method` and `knobs`, per section (W2 reports its reachable and
/// unreachable targets apart): header and cell.
fn columns(section: Section, w2: bool) -> Vec<(&'static str, Cell)> {
    use Cell::{Count, Note, OutOf, Seconds, Timing, Value, WithMax};
    // The IK tables end alike.
    let ik_tail = [
        ("iterations", Count(Metric::IterationsTotal)),
        ("bone length error", Value(Metric::BoneLengthErrorMax)),
    ];
    // The IK tables: time, share within 1e-6, mean and largest error, then alike.
    let ik = |unit, within, count, mean, max| {
        vec![
            (unit, Timing),
            (
                if w2 {
                    "reachable within 1e-6"
                } else {
                    "frames within 1e-6"
                },
                OutOf(within, count),
            ),
            (
                if w2 {
                    "reachable error mean"
                } else {
                    "error mean"
                },
                Value(mean),
            ),
            (
                if w2 {
                    "reachable error max"
                } else {
                    "error max"
                },
                Value(max),
            ),
        ]
    };
    let mut columns = match (section, w2) {
        (Section::Ik, true) => {
            let mut c = ik(
                "time per solve",
                Metric::ReachableWithin1e6,
                Metric::Reachable,
                Metric::ReachableErrorMean,
                Metric::ReachableErrorMax,
            );
            c.push((
                "unreachable excess max",
                Value(Metric::UnreachableExcessMax),
            ));
            c
        }
        (Section::Ik, false) => ik(
            "time per frame",
            Metric::FramesWithin1e6,
            Metric::Frames,
            Metric::ErrorMean,
            Metric::ErrorMax,
        ),
        (Section::Curves, _) => vec![
            ("time per call", Timing),
            ("time per point", Seconds(Metric::TimePerPointS)),
            ("spacing deviation", Value(Metric::SpacingDeviation)),
            ("length error", Value(Metric::LengthError)),
        ],
        (Section::Cloth, _) => vec![
            ("time per step", Timing),
            ("per simulated s", Seconds(Metric::TimePerSimulatedSecondS)),
            ("from true motion, 1 s", Value(Metric::TrueMotionError1s)),
            ("from true motion, end", Value(Metric::TrueMotionErrorEnd)),
            ("from BE 1e-12, 1 s", Value(Metric::SolverError1s)),
            ("from BE 1e-12, end", Value(Metric::SolverErrorEnd)),
            (
                "iterations (max)",
                WithMax(Metric::IterationsTotal, Metric::IterationsMax),
            ),
            ("energy rise max", Value(Metric::EnergyIncreaseMax)),
            ("note", Note),
        ],
    };
    if section == Section::Ik {
        columns.extend(ik_tail);
    }
    columns
}

fn table(section: Section, records: &[&Record], front: &[usize]) -> String {
    let w2 = records.first().is_some_and(|r| r.workload == "W2");
    let columns = columns(section, w2);
    let mut s = String::from("| method | knobs |");
    for (header, _) in &columns {
        let _ = write!(s, " {header} |");
    }
    s.push_str("\n|---|---|");
    s.push_str(&"---|".repeat(columns.len()));
    s.push('\n');
    for (i, r) in records.iter().enumerate() {
        let star = if front.contains(&i) { " *" } else { "" };
        let _ = write!(s, "| {}{star} | {} |", r.method, r.knobs);
        for (_, cell) in &columns {
            let _ = write!(s, " {} |", cell.text(r));
        }
        s.push('\n');
    }
    s
}

fn slug(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '-'
            }
        })
        .collect::<String>()
        .split('-')
        .filter(|p| !p.is_empty())
        .collect::<Vec<_>>()
        .join("-")
}

const PREAMBLE: &str = "\
Every figure is the median of the timed repeats, with the fastest and the slowest repeat in
brackets. Errors are measured once per configuration, untimed, against exact answers (IK:
the effector's distance by forward kinematics of the returned pose; curves: the flower's
closed-form arc length) or converged references (cloth: velocity Verlet at 64x the
stability bound's substeps, checked against 32x, for the true motion; backward Euler to
1e-12 m/h^2 for the implicit solver's error). A `*` after a method marks a configuration on
the Pareto front of its workload (no other configuration is both faster and more accurate
by the plotted error). How the figures are taken, and why: [docs/bench.md](../bench.md).
";

/// Writes every output into `out` and returns the headline table for stdout.
pub fn write(results: &Results, sections: &[Section], out: &Path) -> Result<String, String> {
    std::fs::create_dir_all(out.join("plots")).map_err(|e| format!("{}: {e}", out.display()))?;
    let json = serde_json::to_string_pretty(results).map_err(|e| e.to_string())?;
    let json_path = out.join("results.json");
    std::fs::write(&json_path, json + "\n").map_err(|e| format!("{}: {e}", json_path.display()))?;

    let head = headline(&results.records);
    let mut md = String::new();
    let _ = writeln!(md, "# Benchmarks: run time against error\n");
    let _ = writeln!(
        md,
        "Written by `cargo xtask bench{}` on {} in {:.0} s of wall time; raw numbers in \
         [results.json](results.json). Re-run with `cargo xtask bench` (a few minutes \
         here; `--only ik|curves|cloth` for one section).\n",
        if results.plan.quick { " --quick" } else { "" },
        results.machine.describe(),
        results.wall_seconds
    );
    if results.plan.quick {
        md.push_str("**A `--quick` smoke run: reduced workloads, one repeat, dev profile. Not for quoting.**\n\n");
    }
    md.push_str(PREAMBLE);
    let _ = writeln!(
        md,
        "\n## Headline: the lab workloads against the issues' targets\n\nRatio = measured median time / target time (below 1 is better than the target).\n\n{head}"
    );
    md.push_str(
        "\n## Criterion kernels\n\nMicro-benchmarks of the kernels stay in the crates (`cargo bench -p <crate>`); \
         their tables: [IK overview](ik.md), [CCD](ik-ccd.md) (one sweep, W1, W2, 10 000 bones), \
         [full body](ik-body.md) (W8: cold solves, the squat, the batch of 1 000), \
         [FABRIK](ik-fabrik.md) (one pass, W1 frame, W2 solve, long chain), \
         [curves](curves.md) (table build, per-point inverse against kurbo), \
         [spring-sim](spring-sim.md) (Hessian assembly, numeric factorization, one Newton \
         iteration, PCG, integrators). FK is timed inside every IK figure above and in \
         `cargo bench -p sinew-skeleton`.\n",
    );

    let mut groups: BTreeMap<(u8, String), Vec<&Record>> = BTreeMap::new();
    for r in &results.records {
        groups
            .entry((r.section as u8, r.workload.clone()))
            .or_default()
            .push(r);
    }
    for section in sections {
        let title = match section {
            Section::Ik => "IK: CCD and FABRIK on W1 and W2",
            Section::Curves => "Curves: evenly spaced points on the lab flower",
            Section::Cloth => "Cloth: every integrator on W4, W5 and W6",
        };
        let _ = writeln!(md, "\n## {title}\n");
        for ((s, workload), records) in groups.iter().filter(|((s, _), _)| *s == *section as u8) {
            let _ = s;
            let points: Vec<Point> = records.iter().map(|r| (r.time.median, r.error)).collect();
            let front = pareto_front(&points);
            let mut series: Vec<(String, Vec<Point>)> = Vec::new();
            for r in records {
                match series.iter_mut().find(|(m, _)| *m == r.method) {
                    Some((_, p)) => p.push((r.time.median, r.error)),
                    None => series.push((r.method.clone(), vec![(r.time.median, r.error)])),
                }
            }
            let file = format!("plots/{}.svg", slug(workload));
            let error_name = records.first().map_or("error", |r| r.error_name);
            let unit = records.first().map_or("unit", |r| r.unit);
            time_error_svg(
                &out.join(&file),
                &format!("{workload}: time against error"),
                &format!("time per {unit} (s, median)"),
                error_name,
                &series,
            )?;
            let context = match (section, records.first()) {
                (Section::Cloth, Some(r)) => format!(
                    " Time step {} s, {} steps; the stability bound asks for {} substeps per step at the start. True-motion reference check (64x against 32x the bound's substeps): {} after 1 s, {} at the end.",
                    metric(r, Metric::Dt).map_or("-".into(), |dt| format!("{dt:.5}")),
                    metric_count(r, Metric::Steps),
                    metric_count(r, Metric::StabilityBoundSubsteps),
                    metric_text(r, Metric::TrueMotionCheck1s),
                    metric_text(r, Metric::TrueMotionCheckEnd),
                ),
                _ => String::new(),
            };
            let _ = writeln!(
                md,
                "### {workload}\n\nPlotted error: {error_name}.{context}\n\n![{workload}: time against error]({file})\n\n{}",
                table(*section, records, &front)
            );
        }
        if *section == Section::Cloth {
            md.push_str(&tolerance_table(&results.records));
        }
        md.push_str(section_notes(*section));
    }
    let md_path = out.join("README.md");
    std::fs::write(&md_path, md).map_err(|e| format!("{}: {e}", md_path.display()))?;
    Ok(head)
}

/// Backward Euler (linear solver `auto`) at every Newton tolerance the run has, in two
/// tables, one column per workload: the distance from backward Euler solved to 1e-12 at
/// the same steps (after 1 s, or at the end for runs shorter than 1 s), and the largest
/// error of one step from the exact step (from the same states); each with whether the
/// error never grows as the tolerance tightens, the second also with whether it stays
/// within the tolerance. Empty when the run has fewer than two tolerances.
fn tolerance_table(records: &[Record]) -> String {
    let decades: Vec<f64> = (3..=12).map(|e| 10f64.powi(-e)).collect();
    let mut workloads: Vec<&str> = Vec::new();
    for r in records.iter().filter(|r| r.section == Section::Cloth) {
        if !workloads.contains(&r.workload.as_str()) {
            workloads.push(&r.workload);
        }
    }
    // (tolerance, per workload: the record if it ran at that tolerance).
    let rows: Vec<(f64, Vec<Option<&Record>>)> = decades
        .iter()
        .map(|&tol| {
            let knobs = tolerance_knobs(tol);
            let cells = workloads
                .iter()
                .map(|w| find(records, w, "backward_euler", &knobs))
                .collect();
            (tol, cells)
        })
        .filter(|(_, cells): &(f64, Vec<Option<&Record>>)| cells.iter().any(Option::is_some))
        .collect();
    if rows.len() < 2 {
        return String::new();
    }
    let trajectory = |r: &Record| {
        metric(r, Metric::SolverError1s)
            .or_else(|| metric(r, Metric::SolverErrorEnd))
            .unwrap_or(f64::NAN)
    };
    let mut s = String::from(
        "\n### Backward Euler: tolerance against error\n\nThe distance from backward Euler \
         solved to 1e-12 at the same steps (after 1 s; W6, which runs 0.5 s, at its end), and \
         the median time per step, for every Newton tolerance (`|grad g|_inf <= tol m/h^2`, \
         linear solver `auto`). The last row says whether the distance never grows as the \
         tolerance tightens.\n\n",
    );
    s.push_str(&tolerance_rows(&workloads, &rows, trajectory, false));
    if rows.iter().any(|(_, cells)| {
        cells
            .iter()
            .flatten()
            .any(|r| metric(r, Metric::StepErrorMax).is_some())
    }) {
        s.push_str(
            "\nOne step at a time: from each state of the 1e-12 run's first second (W6: its \
             30 steps), one step at the tolerance in a simulation started afresh there, \
             against the same step solved to 1e-12; the largest distance over the steps (the \
             error from the exact step, without the accumulation over steps), and the median \
             time per step of the run above. The last rows say whether it never grows as the \
             tolerance tightens and whether it stays within the tolerance (a distance: the \
             stopping test bounds the gradient by `tol m/h^2`).\n\n",
        );
        let step = |r: &Record| metric(r, Metric::StepErrorMax).unwrap_or(f64::NAN);
        s.push_str(&tolerance_rows(&workloads, &rows, step, true));
    }
    // A blank line ends the last table: the section's notes that follow are a paragraph,
    // not one more row.
    s.push('\n');
    s
}

/// One tolerance table: a row per tolerance (`error (median time)`), then the verdicts.
fn tolerance_rows(
    workloads: &[&str],
    rows: &[(f64, Vec<Option<&Record>>)],
    error: impl Fn(&Record) -> f64,
    within_tolerance: bool,
) -> String {
    let mut s = String::from("| tolerance |");
    for w in workloads {
        let _ = write!(s, " {w} |");
    }
    s.push_str("\n|---|");
    s.push_str(&"---|".repeat(workloads.len()));
    s.push('\n');
    for (tol, cells) in rows {
        let _ = write!(s, "| {} |", sinew_bench::sweep::sci(*tol));
        for cell in cells {
            match cell {
                Some(r) => {
                    let _ = write!(s, " {} ({}) |", fmt_err(error(r)), fmt_time(r.time.median));
                }
                None => s.push_str(" - |"),
            }
        }
        s.push('\n');
    }
    // (tolerance, error) pairs of one workload, loosest first.
    type Judge<'a> = &'a dyn Fn(&[(f64, f64)]) -> bool;
    let verdicts = |s: &mut String, name: &str, holds: Judge| {
        let _ = write!(s, "| {name} |");
        for i in 0..workloads.len() {
            let errors: Vec<(f64, f64)> = rows
                .iter()
                .filter_map(|(tol, c)| c[i].map(|r| (*tol, error(r))))
                .collect();
            let verdict = if errors.len() < 2 {
                "-"
            } else if holds(&errors) {
                "yes"
            } else {
                "NO"
            };
            let _ = write!(s, " {verdict} |");
        }
        s.push('\n');
    };
    verdicts(&mut s, "non-increasing", &|e| {
        e.windows(2).all(|p| p[1].1 <= p[0].1)
    });
    if within_tolerance {
        verdicts(&mut s, "within the tolerance", &|e| {
            e.iter().all(|&(tol, err)| err <= tol)
        });
    }
    s
}

fn section_notes(section: Section) -> &'static str {
    match section {
        Section::Ik => {
            "\
Knobs: iteration caps at the lab tolerance 1e-6, then tolerances at the lab cap 100. `ccd` and
`fabrik` are the crates' defaults (CCD with sweep extrapolation; FABRIK with the damped
least-squares finish), `-plain` their textbook forms. W2's unreachable targets are solved in
closed form by every solver (excess over `distance - reach` is listed); its plotted error is
over the reachable targets only. Bone length error is relative, the largest over all solves.
"
        }
        Section::Curves => {
            "\
`uniform parameter`: the lab report's sampling at even parameter steps; `dense polyline`: M
uniform samples joined into a polyline and resampled evenly along it (its points lie on the
polyline, not the curve); `arc length`: sinew-curves' table (build included unless reused)
and Newton-bisection inverse. The length error is that of the length each method works with
(the polyline's, or the table's).
"
        }
        Section::Cloth => {
            "\
Explicit substep counts are multiples of the stability bound's count at the start (the
`bound` in results.json); `velocity_verlet` with substeps from the bound recomputes it as the
cloth moves. The distance from backward Euler at 1e-12 measures the implicit solver's error;
for the other integrators it mostly measures how far backward Euler's damping is from them.
The flawed report method is a reference, not a method to use. `energy rise max` is the
largest rise of the total energy over one step relative to the starting energy.
"
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derived_targets_keep_their_sentences_and_limits() {
        let all = targets();
        assert_eq!(all.len(), 11);
        let by_what = |what: &str| {
            all.iter()
                .find(|t| t.what == what)
                .unwrap_or_else(|| panic!("no target reads {what:?}"))
        };
        let w1 = by_what("W1 FABRIK <= 1.5 us/frame, all frames within 1e-6");
        assert_eq!((w1.workload, w1.method), ("W1", "fabrik"));
        assert!((w1.time - 1.5e-6).abs() < 1e-18);
        let w2 = by_what("W2 CCD <= 40 us/solve (share within 1e-6 reported)");
        assert!(w2.error.is_none() && (w2.time - 40e-6).abs() < 1e-18);
        let w6 = by_what("W6 backward Euler to 1e-9 <= 16.7 ms/step");
        assert_eq!(
            (w6.knobs, w6.area.name()),
            ("tol 1e-9, linear auto", "cloth")
        );
        assert!((w6.time - 16.7e-3).abs() < 1e-15);
        let w5 = by_what("W5 k=1e6 auto <= 200 us/step, within 1e-4 of the true motion at 1 s");
        assert_eq!((w5.workload, w5.area.name()), ("W5 k=1e6", "integrators"));
        assert!(matches!(w5.error, Some((Metric::TrueMotionError1s, l)) if l == 1e-4));
    }

    #[test]
    fn every_table_row_has_a_cell_per_header() {
        let record = |section, workload: &str| Record {
            section,
            workload: workload.into(),
            method: "m".into(),
            knobs: "k".into(),
            unit: "step",
            time: Timing {
                median: 1e-6,
                min: 1e-6,
                max: 2e-6,
                repeats: 3,
            },
            error: 1e-9,
            error_name: "e",
            metrics: Default::default(),
            note: String::new(),
        };
        for (section, workload) in [
            (Section::Ik, "W1"),
            (Section::Ik, "W2"),
            (Section::Curves, "flower"),
            (Section::Cloth, "W4 d=0"),
        ] {
            let (a, b) = (record(section, workload), record(section, workload));
            let text = table(section, &[&a, &b], &[1]);
            let cells: Vec<usize> = text.lines().map(|l| l.matches('|').count()).collect();
            assert_eq!(cells.len(), 4, "{text}");
            assert!(cells.iter().all(|&c| c == cells[0]), "{text}");
            // Only the second row is on the front; missing metrics print as "-".
            assert!(
                text.lines().nth(3).unwrap().starts_with("| m * |"),
                "{text}"
            );
            assert!(text.lines().nth(2).unwrap().contains("| - |"), "{text}");
        }
    }

    #[test]
    fn the_tolerance_table_judges_each_workload_apart() {
        // W4 shrinks with every tolerance; W6 (no 1 s figure: its end is used) grows once.
        let record = |workload: &str, tol: f64, key: Metric, error: f64| {
            let mut metrics = sinew_bench::sweep::Metrics::new();
            metrics.insert(key, serde_json::json!(error));
            Record {
                section: Section::Cloth,
                workload: workload.into(),
                method: "backward_euler".into(),
                knobs: tolerance_knobs(tol),
                unit: "step",
                time: Timing {
                    median: 1e-3,
                    min: 1e-3,
                    max: 1e-3,
                    repeats: 3,
                },
                error: 0.0,
                error_name: "e",
                metrics,
                note: String::new(),
            }
        };
        let records = vec![
            record("W4 d=0", 1e-3, Metric::SolverError1s, 1e-2),
            record("W4 d=0", 1e-6, Metric::SolverError1s, 1e-5),
            record("W4 d=0", 1e-9, Metric::SolverError1s, 1e-8),
            record("W6", 1e-3, Metric::SolverErrorEnd, 1e-4),
            record("W6", 1e-6, Metric::SolverErrorEnd, 2e-4),
            record("W6", 1e-9, Metric::SolverErrorEnd, 1e-9),
        ];
        let text = tolerance_table(&records);
        let rows: Vec<&str> = text.lines().filter(|l| l.starts_with("| ")).collect();
        assert_eq!(rows.len(), 5, "{text}");
        assert_eq!(rows[0], "| tolerance | W4 d=0 | W6 |", "{text}");
        assert_eq!(
            rows[1], "| 1e-3 | 1.0e-2 (1.00 ms) | 1.0e-4 (1.00 ms) |",
            "{text}"
        );
        assert_eq!(rows[4], "| non-increasing | yes | NO |", "{text}");
        // One tolerance is not a table.
        assert_eq!(tolerance_table(&records[..1]), "");

        // With the one-step errors, a second table with its two verdicts: W4's errors
        // shrink but one is above its tolerance; W6's grow once, each within its tolerance.
        let mut records = records;
        for (r, e) in records
            .iter_mut()
            .zip([5e-3, 1e-7, 1e-11, 1e-7, 5e-7, 1e-10])
        {
            r.metrics.insert(Metric::StepErrorMax, serde_json::json!(e));
        }
        let text = tolerance_table(&records);
        let rows: Vec<&str> = text.lines().filter(|l| l.starts_with("| ")).collect();
        assert_eq!(rows.len(), 11, "{text}");
        assert_eq!(rows[5], "| tolerance | W4 d=0 | W6 |", "{text}");
        assert_eq!(
            rows[6], "| 1e-3 | 5.0e-3 (1.00 ms) | 1.0e-7 (1.00 ms) |",
            "{text}"
        );
        assert_eq!(rows[9], "| non-increasing | yes | NO |", "{text}");
        assert_eq!(rows[10], "| within the tolerance | NO | yes |", "{text}");
        // A blank line after the last table, so the notes after it are not a row.
        assert!(text.ends_with(" |\n\n"), "{text}");
    }

    #[test]
    fn times_and_errors_format_compactly() {
        assert_eq!(fmt_time(1.4e-6), "1.40 us");
        assert_eq!(fmt_time(0.0152), "15.2 ms");
        assert_eq!(fmt_time(234e-3), "234 ms");
        assert_eq!(fmt_err(f64::INFINITY), "diverged");
        assert_eq!(fmt_err(1.17e-5), "1.2e-5");
        assert_eq!(slug("W5 k=1e6"), "w5-k-1e6");
    }
}
