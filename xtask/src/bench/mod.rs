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

mod report;

use crate::machine::Machine;
use serde::Serialize;
use sinew_bench::sweep::{Plan, Record, Section, cloth, curves, ik};
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
    /// Only these sections (default: all): ik, curves, cloth.
    #[arg(long, num_args = 1.., value_parser = Section::parse)]
    only: Vec<Section>,
    /// Timed repeats per configuration (default 7, cloth 3; 1 with --quick).
    #[arg(long)]
    repeats: Option<usize>,
    /// Write the tables, JSON and plots here (default docs/bench/, or
    /// target/bench-quick/ with --quick).
    #[arg(long)]
    out: Option<PathBuf>,
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
        Section::ALL.to_vec()
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
