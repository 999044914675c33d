//! `cargo xtask scale`: how the cost of a cloth step grows with the cloth's size, on one
//! thread and on every core, with the peak resident memory of each size.
//!
//! Every case runs in a child process (this same binary with `--one`), so each peak
//! resident memory (`VmHWM` of `/proc/self/status`, building the cloth included) is that
//! case's own and a large case cannot leave pages behind for the next one. The cloth is
//! the lab's spring pattern on N x N particles, 2 wide (spacing `2 / (N - 1)`), mass 1,
//! stiffness 100, no damping, two corners fixed, stepped from rest at h = 1/60 by
//! backward Euler with the default settings (tolerance 1e-9, the linear solver chosen by
//! the count model) and the thread count of the case. Two rows of the speed goals run
//! beside the sizes: W5 (11 x 11, stiffness 1e6, h = 1/30) and W6 (101 x 101) with
//! `auto`.
//!
//! Backward Euler's and `auto`'s results do not depend on the thread count (the threaded
//! passes add every term in the single-threaded order): each case prints a hash of the
//! final positions' and velocities' bits, and the run fails when two runs of one case
//! (every case runs three times, in rounds) or two thread counts of one workload end in
//! different states. Written: `scale.md` and `scale.json` (default
//! `docs/bench/`; `--quick` writes to `target/scale-quick/`) and `plots/scale.svg`.

use crate::machine::Machine;
use serde::{Deserialize, Serialize};
use sinew_spring_sim::{
    AutoSettings, ClothGrid, Integrator, NewtonSettings, Simulation, SpringSystem,
};
use sinew_viz::render::{Series, line_chart_svg};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};
use std::time::Instant;

/// `cargo xtask scale` flags.
#[derive(clap::Args)]
pub struct ScaleArgs {
    /// A smoke run: 11 x 11, 46 x 46 (above the size where threads share the work) and
    /// W5, a few steps, dev profile, written to
    /// target/scale-quick/ (the figures are not for quoting).
    #[arg(long)]
    quick: bool,
    /// Grid sizes N (N x N particles), comma-separated (default
    /// 11,31,51,101,201,317,1000).
    #[arg(long, value_delimiter = ',')]
    sizes: Vec<usize>,
    /// Thread counts, comma-separated (default 1 and every core; 0 means every core).
    #[arg(long, value_delimiter = ',')]
    threads: Vec<usize>,
    /// Steps per case (default: 30 up to 10 000 particles, 10 up to 200 000, then 5;
    /// W5 100). The first step of a run also pays the linear-solver choice's analysis
    /// of the matrix, which the median over the steps leaves out.
    #[arg(long)]
    steps: Option<usize>,
    /// Runs of every case, in rounds (default 3; 1 with --quick): each figure is the
    /// median of the runs' figures, the peak memory their largest.
    #[arg(long)]
    repeats: Option<usize>,
    /// Write scale.md, scale.json and plots/scale.svg here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Run one case in this process and print its result as JSON (what the parent runs
    /// in each child): workload (`g<N>` or `w5`), method (`be` or `auto`), threads,
    /// steps.
    #[arg(long, hide = true, num_args = 4)]
    one: Vec<String>,
}

/// The least CPU time, seconds, over which a case's CPU time per step is reported.
const CPU_CLOCK_MIN: f64 = 0.1;

/// A workload and method run at one thread count.
#[derive(Clone, Debug, PartialEq)]
struct Case {
    workload: String,
    method: Method,
    threads: usize,
    steps: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
enum Method {
    /// Backward Euler, default settings.
    Be,
    /// `Integrator::Auto` with default settings.
    Auto,
}

impl Method {
    fn parse(s: &str) -> Result<Self, String> {
        match s {
            "be" => Ok(Self::Be),
            "auto" => Ok(Self::Auto),
            other => Err(format!(
                "unknown method `{other}` (expected `be` or `auto`)"
            )),
        }
    }

    fn name(self) -> &'static str {
        match self {
            Self::Be => "be",
            Self::Auto => "auto",
        }
    }
}

/// What one case measured.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct CaseResult {
    workload: String,
    method: Method,
    threads: usize,
    particles: usize,
    springs: usize,
    steps: usize,
    /// Seconds building the cloth and the stepper.
    build_seconds: f64,
    /// Median wall time of a step, seconds.
    wall_median: f64,
    /// Mean wall time of a step, seconds.
    wall_mean: f64,
    /// Mean CPU time per step of the whole process (every thread), seconds (`None`
    /// where it cannot be read, or the steps took less than [`CPU_CLOCK_MIN`] of it: the
    /// clock moves in steps of 10 ms).
    cpu_mean: Option<f64>,
    /// Newton iterations (explicit substeps for `auto` on an explicit step) per step.
    iterations_per_step: f64,
    /// Linear solver iterations per step.
    linear_per_step: f64,
    /// Peak resident memory of the process, bytes (`None` where it cannot be read).
    peak_rss: Option<u64>,
    /// The final state's fingerprint (`SpringSystem::state_fingerprint`), hexadecimal.
    state_hash: String,
}

/// The workload's cloth and time step: `g<N>` (the lab pattern on N x N, 2 wide,
/// h = 1/60) or `w5` (the lab cloth at stiffness 1e6, h = 1/30).
fn workload(name: &str) -> Result<(SpringSystem, f64), String> {
    let (grid, h) = if name == "w5" {
        let mut g = ClothGrid::lab().with_damping(0.0);
        g.material.stiffness = 1e6;
        (g, 1.0 / 30.0)
    } else {
        let n: usize = name
            .strip_prefix('g')
            .and_then(|n| n.parse().ok())
            .filter(|&n| n >= 2)
            .ok_or_else(|| {
                format!("unknown workload `{name}` (expected `w5` or `g<N>`, N >= 2)")
            })?;
        let spacing = 2.0 / (n - 1) as f64;
        (
            ClothGrid::lab_sized(n, spacing).with_damping(0.0),
            1.0 / 60.0,
        )
    };
    let system = SpringSystem::cloth(&grid).map_err(|e| format!("{name}: {e}"))?;
    Ok((system, h))
}

fn integrator(method: Method, threads: usize) -> Integrator {
    let newton = NewtonSettings {
        threads,
        ..Default::default()
    };
    match method {
        Method::Be => Integrator::BackwardEuler(newton),
        Method::Auto => Integrator::Auto(AutoSettings {
            newton,
            ..Default::default()
        }),
    }
}

/// CPU time of the whole process (every thread, user and system), seconds: fields 14
/// and 15 of `/proc/self/stat`, in Linux's user clock ticks of 1/100 s.
fn process_cpu() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The command name (field 2) is in parentheses and may hold spaces.
    let mut fields = text.rsplit_once(')')?.1.split_whitespace().skip(11);
    let user: f64 = fields.next()?.parse().ok()?;
    let system: f64 = fields.next()?.parse().ok()?;
    Some((user + system) / 100.0)
}

/// The process's peak resident memory, bytes (`VmHWM`).
fn peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Runs one case in this process.
fn run_case(case: &Case) -> Result<CaseResult, String> {
    if case.steps == 0 {
        return Err("a case needs at least one step".into());
    }
    let started = Instant::now();
    let (system, h) = workload(&case.workload)?;
    let (particles, springs) = (system.positions().len(), system.springs().len());
    let mut sim = Simulation::new(system, integrator(case.method, case.threads))
        .map_err(|e| format!("{}: {e}", case.workload))?;
    let build_seconds = started.elapsed().as_secs_f64();
    let mut wall = Vec::new();
    let (mut iterations, mut linear) = (0, 0);
    let cpu_start = process_cpu();
    for step in 0..case.steps {
        let t = Instant::now();
        let report = sim
            .step(h)
            .map_err(|e| format!("{} step {step}: {e}", case.workload))?;
        wall.push(t.elapsed().as_secs_f64());
        iterations += report.iterations;
        linear += report.linear_iterations;
    }
    let cpu = process_cpu().zip(cpu_start).map(|(b, a)| b - a);
    let n = case.steps as f64;
    Ok(CaseResult {
        workload: case.workload.clone(),
        method: case.method,
        threads: case.threads,
        particles,
        springs,
        steps: case.steps,
        build_seconds,
        wall_median: median(wall.clone()),
        wall_mean: wall.iter().sum::<f64>() / n,
        cpu_mean: cpu.filter(|&c| c >= CPU_CLOCK_MIN).map(|c| c / n),
        iterations_per_step: iterations as f64 / n,
        linear_per_step: linear as f64 / n,
        peak_rss: peak_rss(),
        state_hash: format!("{:016x}", sim.system().state_fingerprint()),
    })
}

/// One result from the runs of one case: the medians of their wall medians, wall means
/// and CPU times, the largest peak memory. The runs must end in the same state: the same
/// inputs give the same bits, run after run.
fn combine(runs: Vec<CaseResult>) -> Result<CaseResult, String> {
    let first = runs.first().ok_or("no run")?.clone();
    if let Some(other) = runs.iter().find(|r| r.state_hash != first.state_hash) {
        return Err(format!(
            "two runs of the same case ended in different states ({} and {})",
            first.state_hash, other.state_hash
        ));
    }
    let of = |f: fn(&CaseResult) -> f64| median(runs.iter().map(f).collect());
    let cpu: Option<Vec<f64>> = runs.iter().map(|r| r.cpu_mean).collect();
    Ok(CaseResult {
        build_seconds: of(|r| r.build_seconds),
        wall_median: of(|r| r.wall_median),
        wall_mean: of(|r| r.wall_mean),
        cpu_mean: cpu.map(median),
        peak_rss: runs.iter().filter_map(|r| r.peak_rss).max(),
        ..first
    })
}

/// Default steps of a case with `particles` particles.
fn default_steps(workload: &str, particles: usize) -> usize {
    if workload == "w5" {
        100
    } else if particles <= 10_000 {
        30
    } else if particles <= 200_000 {
        10
    } else {
        5
    }
}

/// Every case of a run, in the order they run: the sizes as given, then the `auto` rows,
/// each on every thread count.
fn plan(sizes: &[usize], threads: &[usize], steps: Option<usize>, quick: bool) -> Vec<Case> {
    let mut workloads: Vec<(String, Method)> = sizes
        .iter()
        .map(|n| (format!("g{n}"), Method::Be))
        .collect();
    workloads.push(("w5".into(), Method::Auto));
    if !quick {
        workloads.push(("g101".into(), Method::Auto));
    }
    let mut cases = Vec::new();
    for (workload, method) in workloads {
        let particles = workload
            .strip_prefix('g')
            .and_then(|n| n.parse::<usize>().ok())
            .map_or(121, |n| n * n);
        let steps = steps.unwrap_or(if quick {
            3
        } else {
            default_steps(&workload, particles)
        });
        for &t in threads {
            cases.push(Case {
                workload: workload.clone(),
                method,
                threads: t,
                steps,
            });
        }
    }
    cases
}

/// Runs `case` in a child process of this binary and reads its result.
fn run_child(case: &Case) -> Result<CaseResult, String> {
    let exe = std::env::current_exe().map_err(|e| format!("this program's path: {e}"))?;
    let output = Command::new(exe)
        .args(["scale", "--one", &case.workload, case.method.name()])
        .arg(case.threads.to_string())
        .arg(case.steps.to_string())
        .output()
        .map_err(|e| format!("starting the case {}: {e}", label(case)))?;
    if !output.status.success() {
        return Err(format!(
            "case {} failed ({}): {}",
            label(case),
            output.status,
            String::from_utf8_lossy(&output.stderr).trim()
        ));
    }
    serde_json::from_slice(&output.stdout)
        .map_err(|e| format!("case {}: unreadable result: {e}", label(case)))
}

fn label(case: &Case) -> String {
    format!(
        "{} {} threads {}",
        case.workload,
        case.method.name(),
        case.threads
    )
}

/// The workloads whose thread counts ended in different states.
fn thread_mismatches(results: &[CaseResult]) -> Vec<String> {
    let mut out = Vec::new();
    for (i, a) in results.iter().enumerate() {
        let first = results
            .iter()
            .position(|b| b.workload == a.workload && b.method == a.method)
            .unwrap_or(i);
        let b = &results[first];
        if first != i && b.state_hash != a.state_hash {
            out.push(format!(
                "{} {}: {} threads end at {}, {} threads at {}",
                a.workload,
                a.method.name(),
                b.threads,
                b.state_hash,
                a.threads,
                a.state_hash
            ));
        }
    }
    out
}

fn micros(s: f64) -> String {
    let us = s * 1e6;
    if us >= 100_000.0 {
        format!("{:.0} ms", us / 1e3)
    } else if us >= 1_000.0 {
        format!("{:.2} ms", us / 1e3)
    } else {
        format!("{us:.1} us")
    }
}

fn mebibytes(bytes: Option<u64>) -> String {
    bytes.map_or("-".into(), |b| {
        let mib = b as f64 / (1024.0 * 1024.0);
        if mib >= 1024.0 {
            format!("{:.2} GiB", mib / 1024.0)
        } else {
            format!("{mib:.1} MiB")
        }
    })
}

/// The speed-up of `r` over the same workload on the first thread count listed.
fn speed_up(results: &[CaseResult], r: &CaseResult) -> Option<f64> {
    let base = results
        .iter()
        .find(|b| b.workload == r.workload && b.method == r.method)?;
    (base.threads != r.threads).then(|| base.wall_median / r.wall_median)
}

/// The markdown report.
fn markdown(
    results: &[CaseResult],
    repeats: usize,
    machine: &Machine,
    load_at_end: Option<f64>,
) -> String {
    let mut s = String::from(
        "# Cost against size, and threads\n\n\
         Written by `cargo xtask scale` (xtask/src/scale.rs says how each figure is taken; \
         docs/bench.md the method). Each case runs in its own process: the lab's spring \
         pattern on N x N particles, 2 wide, stiffness 100, no damping, stepped from rest \
         at h = 1/60 by backward Euler with the default settings (`be`), and two goal \
         rows with `auto`: W5 (11 x 11, stiffness 1e6, h = 1/30) and W6 (101 x 101). \
         Wall times are the medians over the runs of each run's median and mean over \
         its steps; CPU is the process's (every thread) per step, over all steps; peak \
         memory is the process's (`VmHWM`), building the cloth included. Speed-up is the \
         first thread count's wall median over this one's. W5 (121 particles) is below \
         `PARALLEL_MIN_PARTICLES` and runs on the calling thread at every thread count: \
         its rows differ by the machine's noise only.\n\n",
    );
    let _ = writeln!(
        s,
        "Each case ran {repeats} time{} in its own process, in rounds over all cases.\n",
        if repeats == 1 { "" } else { "s" }
    );
    let _ = writeln!(
        s,
        "Machine: {}{}.\n",
        machine.describe(),
        load_at_end.map_or(String::new(), |l| format!(", load {l:.2} at end"))
    );
    s.push_str(
        "| workload | method | particles | springs | threads | steps | wall per step | wall mean | CPU per step | wall per particle | speed-up | iterations / step | linear / step | peak memory | state |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in results {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2} us | {} | {:.2} | {:.1} | {} | `{}` |",
            r.workload,
            r.method.name(),
            r.particles,
            r.springs,
            r.threads,
            r.steps,
            micros(r.wall_median),
            micros(r.wall_mean),
            r.cpu_mean.map_or("-".into(), micros),
            r.wall_median / r.particles as f64 * 1e6,
            speed_up(results, r).map_or("-".into(), |x| format!("{x:.2}")),
            r.iterations_per_step,
            r.linear_per_step,
            mebibytes(r.peak_rss),
            r.state_hash,
        );
    }
    let mismatches = thread_mismatches(results);
    if mismatches.is_empty() {
        s.push_str(
            "\nEvery workload ends in bitwise the same state on every thread count (the \
             `state` column).\n",
        );
    } else {
        s.push_str("\n**Thread counts that ended in different states:**\n\n");
        for m in &mismatches {
            let _ = writeln!(s, "- {m}");
        }
    }
    s.push_str("\n![cost per particle against size](plots/scale.svg)\n");
    s
}

/// One line per thread count: the backward Euler cases' wall time per particle per step
/// against log10 of the particle count.
fn plot(results: &[CaseResult], path: &Path) -> Result<(), String> {
    let mut threads: Vec<usize> = results.iter().map(|r| r.threads).collect();
    threads.sort_unstable();
    threads.dedup();
    let lines: Vec<(String, Vec<(f64, f64)>)> = threads
        .iter()
        .map(|&t| {
            let points = results
                .iter()
                .filter(|r| r.threads == t && r.method == Method::Be)
                .map(|r| {
                    (
                        (r.particles as f64).log10(),
                        r.wall_median / r.particles as f64 * 1e6,
                    )
                })
                .collect();
            let name = match t {
                0 => "every core".to_string(),
                1 => "1 thread".to_string(),
                t => format!("{t} threads"),
            };
            (name, points)
        })
        .collect();
    let series: Vec<Series> = lines
        .iter()
        .map(|(name, points)| Series { name, points })
        .collect();
    line_chart_svg(
        path,
        "Backward Euler to 1e-9, wall time per particle per step",
        "log10(particles)",
        "us per particle per step",
        &series,
        false,
    )
}

/// `cargo xtask scale`.
pub fn run(args: &ScaleArgs) -> ExitCode {
    if !args.one.is_empty() {
        return one(&args.one);
    }
    if !args.quick
        && let Some(code) = crate::machine::rerun_in_release()
    {
        return code;
    }
    let machine = Machine::read();
    let sizes = match (args.sizes.is_empty(), args.quick) {
        (false, _) => args.sizes.clone(),
        (true, true) => vec![11, 46],
        (true, false) => vec![11, 31, 51, 101, 201, 317, 1000],
    };
    if let Some(&n) = sizes.iter().find(|&&n| n < 2) {
        eprintln!("error: a grid size must be at least 2 (got {n})");
        return ExitCode::FAILURE;
    }
    let threads = if args.threads.is_empty() {
        let mut t = vec![1, machine.cores];
        t.dedup();
        t
    } else {
        args.threads.clone()
    };
    if args.steps == Some(0) {
        eprintln!("error: --steps must be at least 1");
        return ExitCode::FAILURE;
    }
    let out = args.out.clone().unwrap_or_else(|| {
        crate::project_root().join(if args.quick {
            "target/scale-quick"
        } else {
            "docs/bench"
        })
    });
    eprintln!("scale on {}", machine.describe());
    let cases = plan(&sizes, &threads, args.steps, args.quick);
    let repeats = args.repeats.unwrap_or(if args.quick { 1 } else { 3 });
    if repeats == 0 {
        eprintln!("error: --repeats must be at least 1");
        return ExitCode::FAILURE;
    }
    // Round after round over every case, so a slow spell of the shared machine falls on
    // all cases alike rather than on one.
    let mut runs: Vec<Vec<CaseResult>> = vec![Vec::new(); cases.len()];
    for round in 0..repeats {
        for (case, runs) in cases.iter().zip(&mut runs) {
            eprint!("round {} of {repeats}: {} ... ", round + 1, label(case));
            match run_child(case) {
                Ok(r) => {
                    eprintln!("{} per step", micros(r.wall_median));
                    runs.push(r);
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::FAILURE;
                }
            }
        }
    }
    let mut results = Vec::new();
    for (case, runs) in cases.iter().zip(runs) {
        match combine(runs) {
            Ok(r) => results.push(r),
            Err(e) => {
                eprintln!("error: {}: {e}", label(case));
                return ExitCode::FAILURE;
            }
        }
    }
    let load_at_end = std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|t| t.split_whitespace().next()?.parse().ok());
    let text = markdown(&results, repeats, &machine, load_at_end);
    let written = std::fs::create_dir_all(out.join("plots"))
        .map_err(|e| format!("{}: {e}", out.display()))
        .and_then(|()| {
            std::fs::write(out.join("scale.md"), &text)
                .map_err(|e| format!("{}: {e}", out.join("scale.md").display()))
        })
        .and_then(|()| {
            let json = serde_json::to_string_pretty(&results).map_err(|e| e.to_string())?;
            std::fs::write(out.join("scale.json"), json)
                .map_err(|e| format!("{}: {e}", out.join("scale.json").display()))
        })
        .and_then(|()| plot(&results, &out.join("plots/scale.svg")));
    println!("{text}");
    if let Err(e) = written {
        eprintln!("error: {e}");
        return ExitCode::FAILURE;
    }
    println!("wrote {}", out.display());
    let mismatches = thread_mismatches(&results);
    if mismatches.is_empty() {
        ExitCode::SUCCESS
    } else {
        for m in mismatches {
            eprintln!("error: results depend on the thread count: {m}");
        }
        ExitCode::FAILURE
    }
}

/// The child's side: one case, its result as JSON on stdout.
fn one(args: &[String]) -> ExitCode {
    let case = (|| -> Result<Case, String> {
        let [workload, method, threads, steps] = args else {
            return Err("--one takes a workload, a method, threads and steps".into());
        };
        Ok(Case {
            workload: workload.clone(),
            method: Method::parse(method)?,
            threads: threads
                .parse()
                .map_err(|e| format!("threads `{threads}`: {e}"))?,
            steps: steps.parse().map_err(|e| format!("steps `{steps}`: {e}"))?,
        })
    })();
    match case.and_then(|c| run_case(&c)) {
        Ok(r) => match serde_json::to_string(&r) {
            Ok(json) => {
                println!("{json}");
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("error: {e}");
                ExitCode::FAILURE
            }
        },
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn result(workload: &str, threads: usize, wall: f64, hash: &str) -> CaseResult {
        CaseResult {
            workload: workload.into(),
            method: Method::Be,
            threads,
            particles: 100,
            springs: 500,
            steps: 3,
            build_seconds: 0.0,
            wall_median: wall,
            wall_mean: wall,
            cpu_mean: Some(wall),
            iterations_per_step: 1.0,
            linear_per_step: 2.0,
            peak_rss: Some(3 << 20),
            state_hash: hash.into(),
        }
    }

    #[test]
    fn a_case_steps_its_cloth_and_two_thread_counts_agree_to_the_bit() {
        let case = |threads| Case {
            // Above `PARALLEL_MIN_PARTICLES`, so two threads share the passes.
            workload: "g46".into(),
            method: Method::Be,
            threads,
            steps: 2,
        };
        let one = run_case(&case(1)).unwrap();
        let two = run_case(&case(2)).unwrap();
        assert_eq!((one.particles, one.steps), (2116, 2));
        assert!(one.particles >= sinew_spring_sim::PARALLEL_MIN_PARTICLES);
        assert!(one.iterations_per_step >= 1.0);
        assert!(one.wall_median > 0.0 && one.wall_median.is_finite());
        assert_eq!(one.state_hash, two.state_hash);
        assert!(thread_mismatches(&[one, two]).is_empty());
    }

    #[test]
    fn bad_cases_are_errors_naming_what_is_wrong() {
        let err = workload("g1").unwrap_err();
        assert!(err.contains("g1"), "{err}");
        let err = workload("w6").unwrap_err();
        assert!(err.contains("w6"), "{err}");
        assert!(Method::parse("verlet").unwrap_err().contains("verlet"));
        let zero = Case {
            workload: "g11".into(),
            method: Method::Be,
            threads: 1,
            steps: 0,
        };
        assert!(run_case(&zero).is_err());
    }

    #[test]
    fn states_that_differ_between_thread_counts_are_reported() {
        let rows = [
            result("g11", 1, 2e-3, "aa"),
            result("g11", 2, 1e-3, "aa"),
            result("g31", 1, 4e-3, "bb"),
            result("g31", 2, 2e-3, "cc"),
        ];
        let m = thread_mismatches(&rows);
        assert_eq!(m.len(), 1);
        assert!(m[0].starts_with("g31 be"), "{}", m[0]);
        assert_eq!(speed_up(&rows, &rows[1]), Some(2.0));
        assert_eq!(speed_up(&rows, &rows[0]), None);
        let text = markdown(&rows, 3, &Machine::read(), None);
        assert!(text.contains("Thread counts that ended in different states"));
        assert_eq!(
            text.lines().filter(|l| l.starts_with("| g")).count(),
            rows.len()
        );
    }

    #[test]
    fn runs_combine_into_medians_and_must_end_alike() {
        let runs = vec![
            result("g11", 1, 3e-3, "aa"),
            result("g11", 1, 1e-3, "aa"),
            result("g11", 1, 2e-3, "aa"),
        ];
        let combined = combine(runs.clone()).unwrap();
        assert_eq!(combined.wall_median, 2e-3);
        assert_eq!(combined.state_hash, "aa");
        let mut other = runs;
        other[2].state_hash = "ab".into();
        let err = combine(other).unwrap_err();
        assert!(err.contains("different states"), "{err}");
        assert!(combine(Vec::new()).is_err());
    }

    #[test]
    fn the_plan_runs_every_size_on_every_thread_count_and_the_goal_rows() {
        let cases = plan(&[11, 1000], &[1, 2], None, false);
        let names: Vec<String> = cases.iter().map(label).collect();
        assert_eq!(cases.len(), 8, "{names:?}");
        assert_eq!(cases[0].steps, 30);
        assert_eq!(cases[2].steps, 5);
        assert!(cases.iter().any(|c| c.workload == "w5" && c.steps == 100));
        assert!(
            cases
                .iter()
                .any(|c| c.workload == "g101" && c.method == Method::Auto)
        );
    }
}
