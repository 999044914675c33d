//! `cargo xtask stress`: the numerical stress grid.
//!
//! - [`cloth`]: the lab cloth at 7 stiffness decades x 5 time steps x 3 grid sizes x 5
//!   initial states, stepped by the default backward Euler; divergence, energy, Newton
//!   work, and the invariants (no NaN, no divergence, the energy inequality); steps left
//!   at Newton's cap far from converged are reported (failures with `--strict`).
//!   Contact cases: a sheet thrown onto the ground or a sphere at every stiffness, time
//!   step and drop speed; penetrations (measured independently), NaN, divergence and
//!   unconverged steps; any penetration fails the run, and with `--strict` a step left
//!   far from converged (above the springs' round-off floor), as in the self-contact
//!   cases.
//! - [`ik`]: the degenerate IK set for every solver, with the invariants every solve
//!   must keep (no NaN, bone lengths, a truthful report, the geometric error bound).
//! - [`body`]: the full-body degenerate set for every body solver configuration, with
//!   the invariants every body solve must keep (no NaN, no limit violated, a report equal
//!   to forward kinematics, the cost never above the start).
//! - `--soak`: W4 with `auto` and W1 tracking for a million steps and frames each
//!   (`sinew_bench::stress::soak`), no tables written.
//! - [`table`]: the console tables and `stress.md`.
//!
//! Prints the tables, writes `stress.md` (default `docs/bench/`; `--quick` and filtered
//! runs write to `target/` so a smoke run never overwrites the committed file) and exits
//! 1 if any case broke an invariant. What is checked and why: docs/stress.md.

pub mod table;

use clap::ValueEnum;
use sinew_bench::stress::{body, cloth, ik, self_contact};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

/// `cargo xtask stress` flags.
#[derive(clap::Args)]
pub struct StressArgs {
    /// The reduced grid CI runs (11 x 11 only, stiffness 1e1/1e4/1e7, dt 1/960, 1/60,
    /// 1/4, every state; the whole IK set); runs in the dev build.
    #[arg(long)]
    quick: bool,
    /// Write stress.md here (default: docs/bench/ for the full grid, target/stress-quick/
    /// with --quick, target/stress-partial/ when a filter is given).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Run one part only.
    #[arg(long, value_enum)]
    only: Option<Part>,
    /// Print every outcome as JSON on stdout instead of the tables.
    #[arg(long)]
    json: bool,
    /// Cloth: only these grid sizes (comma-separated), e.g. `--grid 101`.
    #[arg(long, value_delimiter = ',')]
    grid: Vec<usize>,
    /// Cloth: only these stiffnesses, e.g. `--stiffness 1e7`.
    #[arg(long, value_delimiter = ',')]
    stiffness: Vec<f64>,
    /// Cloth: only these time steps, e.g. `--dt 1/4`.
    #[arg(long, value_delimiter = ',', value_parser = cloth::parse_dt)]
    dt: Vec<f64>,
    /// Cloth: only these initial states (rest, stretched, compressed, perturbed, far).
    #[arg(long, value_delimiter = ',', value_parser = cloth::InitialState::parse)]
    state: Vec<cloth::InitialState>,
    /// Cloth: only these integrators (backward-euler, auto, bdf2).
    #[arg(long, value_delimiter = ',', value_parser = cloth::ClothIntegrator::parse)]
    integrator: Vec<cloth::ClothIntegrator>,
    /// Cloth: steps per case instead of the default (20 on 11 x 11, 3 on 51 x 51, 10 on
    /// 101 x 101).
    #[arg(long)]
    steps: Option<usize>,
    /// Cloth cases run at once (default 2: the grid's figures are counts, not timings, so
    /// running two cases side by side changes nothing but the wall time).
    #[arg(long, default_value_t = 2)]
    jobs: usize,
    /// Cloth: skip the contact and self-contact cases (for a shard of the cloth grid
    /// whose contact cases another shard runs).
    #[arg(long)]
    no_contact: bool,
    /// Also fail on steps left far from converged, in the cloth grid and the contact and
    /// self-contact cases (reported either way; see docs/stress.md).
    #[arg(long)]
    strict: bool,
    /// Run the soak instead of the grid: W4 with `auto` (damping 0.2 and 0) for
    /// `--soak-steps` steps and W1 tracking for as many frames with every registry
    /// solver, in release; exit 1 on NaN, energy gain beyond the allowance or a bone off
    /// by more than 1e-12.
    #[arg(long)]
    soak: bool,
    /// Steps (cloth) and frames (IK) of the soak.
    #[arg(long, default_value_t = 1_000_000)]
    soak_steps: usize,
}

/// Which part of the stress run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Part {
    /// The cloth grid.
    Cloth,
    /// The IK set.
    Ik,
    /// The full-body set.
    Body,
}

impl StressArgs {
    fn filtered(&self) -> bool {
        !(self.grid.is_empty()
            && self.stiffness.is_empty()
            && self.dt.is_empty()
            && self.state.is_empty()
            && self.integrator.is_empty()
            && self.steps.is_none()
            && self.only.is_none()
            && !self.no_contact)
    }

    fn cloth_cases(&self) -> Vec<cloth::ClothCase> {
        let mut spec = if self.quick {
            cloth::ClothGridSpec::quick()
        } else {
            cloth::ClothGridSpec::full()
        };
        if !self.grid.is_empty() {
            spec.grids.clone_from(&self.grid);
        }
        if !self.stiffness.is_empty() {
            spec.stiffnesses.clone_from(&self.stiffness);
        }
        if !self.dt.is_empty() {
            spec.dts.clone_from(&self.dt);
        }
        if !self.state.is_empty() {
            spec.states.clone_from(&self.state);
        }
        if !self.integrator.is_empty() {
            spec.integrators.clone_from(&self.integrator);
        }
        let mut cases = spec.cases();
        if let Some(steps) = self.steps {
            for c in &mut cases {
                c.steps = steps;
            }
        }
        cases
    }
}

/// Everything one run produced.
#[derive(serde::Serialize)]
pub struct StressResults {
    /// The machine and build.
    pub machine: crate::machine::Machine,
    /// The command line after `cargo xtask stress` (to reproduce).
    pub command: String,
    /// Whether this was the reduced grid.
    pub quick: bool,
    /// Cloth outcomes, grid-major.
    pub cloth: Vec<cloth::ClothOutcome>,
    /// Wall-clock seconds of the cloth part.
    pub cloth_seconds: f64,
    /// Contact outcomes (a sheet thrown onto the ground or a sphere).
    pub contact: Vec<cloth::ContactOutcome>,
    /// Wall-clock seconds of the contact cases.
    pub contact_seconds: f64,
    /// Self-contact outcomes (a free sheet thrown onto a pinned one, one mesh).
    pub self_contact: Vec<self_contact::SelfContactOutcome>,
    /// Wall-clock seconds of the self-contact cases.
    pub self_contact_seconds: f64,
    /// IK outcomes, case-major.
    pub ik: Vec<ik::IkOutcome>,
    /// Wall-clock seconds of the IK part.
    pub ik_seconds: f64,
    /// Full-body outcomes, case-major.
    pub body: Vec<body::BodyOutcome>,
    /// Wall-clock seconds of the full-body part.
    pub body_seconds: f64,
}

impl StressResults {
    /// A run with no outcome yet.
    #[must_use]
    pub fn empty(machine: crate::machine::Machine, command: String, quick: bool) -> Self {
        Self {
            machine,
            command,
            quick,
            cloth: Vec::new(),
            cloth_seconds: 0.0,
            contact: Vec::new(),
            contact_seconds: 0.0,
            self_contact: Vec::new(),
            self_contact_seconds: 0.0,
            ik: Vec::new(),
            ik_seconds: 0.0,
            body: Vec::new(),
            body_seconds: 0.0,
        }
    }

    /// Every failure, as `part: case: sentence` (with `strict`, the steps left far from
    /// converged too).
    #[must_use]
    pub fn failures(&self, strict: bool) -> Vec<String> {
        let mut out = Vec::new();
        for c in &self.cloth {
            for f in &c.failures {
                out.push(format!("cloth {}: {f}", c.case.label()));
            }
            if strict && let Some(u) = &c.unconverged {
                out.push(format!("cloth {}: {u}", c.case.label()));
            }
        }
        for c in &self.contact {
            for f in &c.failures {
                out.push(format!("contact {}: {f}", c.case.label()));
            }
            if strict && let Some(u) = &c.far.first {
                out.push(format!("contact {}: {u}", c.case.label()));
            }
        }
        for c in &self.self_contact {
            for f in &c.failures {
                out.push(format!("self-contact {}: {f}", c.case.label()));
            }
            if strict && let Some(u) = &c.far.first {
                out.push(format!("self-contact {}: {u}", c.case.label()));
            }
        }
        for o in &self.ik {
            for f in &o.failures {
                out.push(format!("ik {} [{}]: {f}", o.case, o.solver));
            }
        }
        for o in &self.body {
            for f in &o.violations {
                out.push(format!("body {} [{}]: {f}", o.case, o.solver));
            }
        }
        out
    }

    /// The cases with a step left far from converged, as `part case: sentence`.
    #[must_use]
    pub fn unconverged(&self) -> Vec<String> {
        let cloth = self.cloth.iter().filter_map(|c| {
            c.unconverged
                .as_ref()
                .map(|u| format!("cloth {}: {u}", c.case.label()))
        });
        let contact = self.contact.iter().filter_map(|c| {
            c.far
                .first
                .as_ref()
                .map(|u| format!("contact {}: {u}", c.case.label()))
        });
        let self_contact = self.self_contact.iter().filter_map(|c| {
            c.far
                .first
                .as_ref()
                .map(|u| format!("self-contact {}: {u}", c.case.label()))
        });
        cloth.chain(contact).chain(self_contact).collect()
    }
}

/// Runs the cloth cases on `jobs` threads, each taking the next case in turn; the
/// outcomes come back in case order.
fn run_cloth_cases(
    cases: &[cloth::ClothCase],
    jobs: usize,
    bar: &indicatif::ProgressBar,
) -> Vec<cloth::ClothOutcome> {
    use std::sync::Mutex;
    use std::sync::atomic::{AtomicUsize, Ordering};
    let next = AtomicUsize::new(0);
    let done: Mutex<Vec<Option<cloth::ClothOutcome>>> = Mutex::new(vec![None; cases.len()]);
    std::thread::scope(|scope| {
        for _ in 0..jobs.max(1) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(case) = cases.get(i) else { break };
                    bar.set_message(case.label());
                    let outcome = cloth::run_case(case);
                    if let Ok(mut d) = done.lock() {
                        d[i] = Some(outcome);
                    }
                    bar.inc(1);
                }
            });
        }
    });
    done.into_inner()
        .unwrap_or_default()
        .into_iter()
        .flatten()
        .collect()
}

/// Runs the soak (`--soak`): prints one line per run and exits 1 on any failure.
fn run_soak(args: &StressArgs) -> ExitCode {
    use sinew_bench::stress::soak;
    let n = args.soak_steps;
    let machine = crate::machine::Machine::read();
    println!("soak: {n} steps / frames each; {machine:?}");
    let mut failures = Vec::new();
    for damping in [0.2, 0.0] {
        let o = soak::run_cloth(n, damping);
        println!(
            "{}: {} steps in {:.1} s (verlet {}, bdf2 {}, backward euler {}); largest one-step rise {:.3e}, largest E - E0 {:.3e}, end E - E0 {:.3e} (relative to the starting scale)",
            o.name,
            o.steps_run,
            o.seconds,
            o.verlet_steps,
            o.bdf2_steps,
            o.backward_euler_steps,
            o.rise_max,
            o.above_start_max,
            o.end_change
        );
        failures.extend(o.failures.iter().map(|f| format!("{}: {f}", o.name)));
    }
    for o in soak::run_all_ik(n) {
        println!(
            "W1 tracking {}: {} frames in {:.1} s; largest relative bone error {:.3e}; effector error mean {:.3e}, max {:.3e}",
            o.solver, o.frames, o.seconds, o.bone_error_max, o.error_mean, o.error_max
        );
        failures.extend(o.failures.iter().map(|f| format!("W1 {}: {f}", o.solver)));
    }
    println!(
        "load at the end: {:?}",
        crate::machine::Machine::read().load_at_start
    );
    if failures.is_empty() {
        println!("soak: no failure");
        ExitCode::SUCCESS
    } else {
        println!("soak failures ({}):", failures.len());
        for f in &failures {
            println!("  {f}");
        }
        ExitCode::FAILURE
    }
}

/// Runs the stress grid; exit code 1 when an invariant broke, 2 on an I/O error.
pub fn run(args: &StressArgs) -> ExitCode {
    if !args.quick
        && let Some(code) = crate::machine::rerun_in_release()
    {
        return code;
    }
    if args.soak {
        return run_soak(args);
    }
    let machine = crate::machine::Machine::read();
    let command = std::env::args().skip(2).collect::<Vec<_>>().join(" ");
    let mut results = StressResults::empty(machine, command, args.quick);
    let runs = |part: Part| args.only.is_none_or(|only| only == part);
    if runs(Part::Cloth) {
        let cases = args.cloth_cases();
        let started = Instant::now();
        let bar = indicatif::ProgressBar::new(cases.len() as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template("cloth {bar:40} {pos}/{len} {elapsed} {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        results.cloth = run_cloth_cases(&cases, args.jobs, &bar);
        bar.finish_and_clear();
        results.cloth_seconds = started.elapsed().as_secs_f64();
        // The contact cases are not narrowed by the cloth filters (they have their own
        // grid); a filtered run still runs them unless `--only ik`.
        if !args.no_contact {
            let started = Instant::now();
            results.contact = cloth::contact_cases(args.quick)
                .iter()
                .map(cloth::run_contact_case)
                .collect();
            results.contact_seconds = started.elapsed().as_secs_f64();
            let started = Instant::now();
            results.self_contact = self_contact::self_contact_cases(args.quick)
                .iter()
                .map(self_contact::run_self_contact_case)
                .collect();
            results.self_contact_seconds = started.elapsed().as_secs_f64();
        }
    }
    if runs(Part::Ik) {
        let started = Instant::now();
        results.ik = ik::run_all(&ik::cases());
        results.ik_seconds = started.elapsed().as_secs_f64();
    }
    if runs(Part::Body) {
        let started = Instant::now();
        results.body = body::run_all(&body::cases());
        results.body_seconds = started.elapsed().as_secs_f64();
    }
    let failures = results.failures(args.strict);
    let unconverged = results.unconverged();
    if args.json {
        match serde_json::to_string_pretty(&results) {
            Ok(s) => println!("{s}"),
            Err(e) => {
                eprintln!("error: {e}");
                return ExitCode::from(2);
            }
        }
    } else {
        print!("{}", table::console(&results, &failures, &unconverged));
        println!(
            "\ncontact: a sheet thrown onto the ground or a sphere ({:.1} s)\n{}",
            results.contact_seconds,
            cloth::contact_table(&results.contact)
        );
        println!(
            "\nself-contact: a sheet thrown onto a pinned sheet ({:.1} s)\n{}",
            results.self_contact_seconds,
            self_contact::self_contact_table(&results.self_contact)
        );
    }
    let out_dir = args.out.clone().unwrap_or_else(|| {
        let root = crate::project_root();
        if args.quick {
            root.join("target/stress-quick")
        } else if args.filtered() {
            root.join("target/stress-partial")
        } else {
            root.join("docs/bench")
        }
    });
    let path = out_dir.join("stress.md");
    let written = std::fs::create_dir_all(&out_dir)
        .and_then(|()| {
        let mut text = table::markdown(&results, &failures, &unconverged);
        text.push_str(&format!(
            "\n## Contact\n\nA free sheet (spacing 0.05 m, 0.2 kg/m^2, damping 0.1, gravity 9.81) thrown down from 0.1 m above the ground or a sphere of radius 0.2 (top at y = 0), backward Euler with IPC contact (dhat 1e-3, friction 0.3, Newton cap 100); penetrations measured independently after every step ({:.1} s).\n\n{}",
            results.contact_seconds,
            cloth::contact_table(&results.contact)
        ));
        text.push_str(&format!(
            "\n## Self-contact\n\nA free n x n sheet (spacing 0.04 m, turned 0.1 rad) thrown down from 2 cm above an n x n sheet (spacing 0.05 m) pinned along its border, both one mesh with self-contact (dhat 2e-3, thickness 1e-3, 0.2 kg/m^2, damping 0.1, Newton cap 100), by backward Euler and by BDF2 (marked `bdf2`); triangles passing through each other counted after every step by an exact check independent of the solver ({:.1} s).\n\n{}",
            results.self_contact_seconds,
            self_contact::self_contact_table(&results.self_contact)
        ));
        std::fs::write(&path, text)
    });
    if let Err(e) = written {
        eprintln!("error: could not write {}: {e}", path.display());
        return ExitCode::from(2);
    }
    eprintln!(
        "wrote {} (cloth {:.1} s, ik {:.1} s, body {:.1} s; {} failure(s); {} case(s) with a step left far from converged{})",
        path.display(),
        results.cloth_seconds,
        results.ik_seconds,
        results.body_seconds,
        failures.len(),
        unconverged.len(),
        if args.strict {
            ", failing with --strict"
        } else {
            ", reported"
        }
    );
    if failures.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn results(contact: Vec<cloth::ContactOutcome>) -> StressResults {
        StressResults {
            contact,
            ..StressResults::empty(crate::machine::Machine::read(), String::new(), true)
        }
    }

    #[test]
    fn a_contact_step_far_from_converged_fails_only_under_strict() {
        let case = cloth::ContactCase {
            grid: 3,
            stiffness: 1e2,
            dt: 1.0 / 60.0,
            speed: 0.0,
            target: cloth::ContactTarget::Ground,
            steps: 1,
        };
        let mut far = cloth::run_contact_case(&case);
        assert!(far.failures.is_empty(), "{:?}", far.failures);
        assert!(results(vec![far.clone()]).failures(true).is_empty());
        // The same outcome with a step marked far, as `FarSteps::note` marks it.
        far.far.count = 1;
        far.far.first = Some("step 0: stopped far from converged".to_string());
        let r = results(vec![far]);
        assert!(r.failures(false).is_empty(), "{:?}", r.failures(false));
        let strict = r.failures(true);
        assert_eq!(strict.len(), 1, "{strict:?}");
        assert!(strict[0].starts_with("contact "), "{strict:?}");
        assert_eq!(r.unconverged(), strict);
    }
}
