//! `cargo xtask bench`: run time against error for every method and knob on the shared
//! workloads (docs/workloads.md), written as tables (`docs/bench/README.md`), raw
//! numbers (`docs/bench/results.json`) and SVG plots with the Pareto front marked.
//!
//! Every figure is the median of several timed repeats with the spread (smallest and
//! largest repeat) beside it; errors are measured once per configuration, untimed, against
//! exact answers or converged references. The full run re-runs itself in release
//! ([`crate::machine::rerun_in_release`]); `--quick` is a smoke run in the dev profile on
//! reduced workloads that writes to `target/bench-quick/` so the published files are never
//! overwritten by unquotable numbers. docs/bench.md describes the method.

mod cloth;
mod curves;
mod ik;
mod report;
pub mod workloads;

use crate::machine::Machine;
use serde::Serialize;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

/// `cargo xtask bench` flags.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// A smoke run: reduced workloads, one repeat, dev profile, output to
    /// target/bench-quick/ (the figures are not for quoting).
    #[arg(long)]
    quick: bool,
    /// Only these sections (default: all).
    #[arg(long, value_enum, num_args = 1..)]
    only: Vec<Section>,
    /// Timed repeats per configuration (default 7, cloth 3; 1 with --quick).
    #[arg(long)]
    repeats: Option<usize>,
    /// Write the tables, JSON and plots here (default docs/bench/, or
    /// target/bench-quick/ with --quick).
    #[arg(long)]
    out: Option<PathBuf>,
}

/// A part of the benchmark.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Section {
    /// CCD and FABRIK on W1 and W2.
    Ik,
    /// Uniform-parameter sampling against arc-length resampling on the lab flower.
    Curves,
    /// Every integrator on W4, W5 and W6.
    Cloth,
}

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
    pub metrics: serde_json::Map<String, serde_json::Value>,
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

/// Everything one run of the benchmark produced.
#[derive(Serialize)]
pub struct Results {
    /// The machine and build.
    pub machine: Machine,
    /// The plan (repeats, quick).
    pub plan: Plan,
    /// Wall time of the whole benchmark, seconds.
    pub wall_seconds: f64,
    /// One record per configuration.
    pub records: Vec<Record>,
}

/// `cargo xtask bench`.
pub fn run(args: &BenchArgs) -> ExitCode {
    if !args.quick
        && let Some(code) = crate::machine::rerun_in_release()
    {
        return code;
    }
    let plan = Plan {
        quick: args.quick,
        repeats: args.repeats.unwrap_or(if args.quick { 1 } else { 7 }),
        cloth_repeats: args.repeats.unwrap_or(if args.quick { 1 } else { 3 }),
        min_repeat_seconds: if args.quick { 0.0 } else { 0.05 },
    };
    let out = args.out.clone().unwrap_or_else(|| {
        crate::project_root().join(if args.quick {
            "target/bench-quick"
        } else {
            "docs/bench"
        })
    });
    let sections = if args.only.is_empty() {
        vec![Section::Ik, Section::Curves, Section::Cloth]
    } else {
        args.only.clone()
    };
    let machine = Machine::read();
    eprintln!("bench on {}", machine.describe());
    let started = Instant::now();
    let mut records = Vec::new();
    for section in &sections {
        eprintln!("== {section:?}");
        let result = match section {
            Section::Ik => ik::run(&plan),
            Section::Curves => curves::run(&plan),
            Section::Cloth => cloth::run(&plan),
        };
        match result {
            Ok(mut r) => records.append(&mut r),
            Err(e) => {
                eprintln!("error: {section:?}: {e}");
                return ExitCode::FAILURE;
            }
        }
    }
    let results = Results {
        machine,
        plan,
        wall_seconds: started.elapsed().as_secs_f64(),
        records,
    };
    match report::write(&results, &sections, &out) {
        Ok(summary) => {
            println!("{summary}");
            println!("wrote {}", out.display());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
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
    fn knob_values_print_short() {
        assert_eq!(sci(1e-6), "1e-6");
        assert_eq!(sci(1e4), "1e4");
        assert_eq!(sci(2.5e-3), "2.5e-3");
    }
}
