//! Self-contact cost: a sheet dropped onto a sheet pinned along its border below it
//! (both `n x n`, spacing 5 cm and 4 cm, the top one 2 cm up and turned by 0.1 rad;
//! `dhat` 2 mm, thickness 1 mm, h = 1/60, backward Euler with the default Newton
//! settings), stepped 45 times by default (the integrator widens its Hessian pattern at
//! every Newton iteration by the pairs contact coupled without slots). Prints, per `n`, the wall time
//! per step and per vertex per step, the Newton iterations, and the active pairs at the
//! end. Not a criterion
//! benchmark: a table for docs/bench/contact.md, run with
//! `cargo bench -p sinew-spring-sim --bench self_contact [-- n... [steps=N] [trace]]` (45
//! steps unless `steps=` says otherwise). With `trace`, every Newton iteration prints a
//! row to stderr: the step, the iteration, the pairs within `dhat`, `kappa`, the smallest
//! gap, the line-search cap from CCD, the step length accepted, and the largest entry of
//! the whole gradient (the mass-spring terms plus self-contact) over the free particles.

// The tests' scene: the dropped sheets and their cloth.
#[path = "../tests/suite/sheets.rs"]
mod sheets;

use sinew_math::DVec3;
use sinew_spring_sim::contact::self_contact::{SelfContactSettings, SelfContactTerm};
use sinew_spring_sim::potential::{HessianSink, Potential, StepContext, Term};
use sinew_spring_sim::spring::Curvature;
use sinew_spring_sim::{NewtonSettings, TriangleMesh};
use std::sync::Mutex;
use std::time::Instant;

/// The self-contact term with a trace of every Newton iteration (see the file's
/// documentation): it hands every call to the term and watches the iterates.
#[derive(Debug)]
struct Traced {
    inner: SelfContactTerm,
    /// The mass-spring terms, for the whole gradient's size.
    rest: Potential,
    step: usize,
    iteration: usize,
    /// The last iterate and the last capped direction with its cap.
    last: Option<Vec<DVec3>>,
    cap: Mutex<Option<(Vec<DVec3>, f64)>>,
}

impl Term for Traced {
    fn name(&self) -> &'static str {
        "self-contact (traced)"
    }
    fn begin_step(&mut self, step: &StepContext<'_>) {
        self.step += 1;
        self.iteration = 0;
        self.last = None;
        self.rest.begin_step(step);
        self.inner.begin_step(step);
    }
    fn prepare_start(&self, step: &StepContext<'_>, x: &mut [DVec3]) {
        self.inner.prepare_start(step, x);
    }
    fn update_active_set(&mut self, step: &StepContext<'_>, x: &[DVec3]) {
        self.inner.update_active_set(step, x);
        let fixed = step.system.fixed();
        let mut g = vec![DVec3::ZERO; x.len()];
        self.rest.gradient(step, x, &mut g);
        self.inner.add_gradient(step, x, &mut g);
        let norm = g
            .iter()
            .zip(fixed)
            .filter(|(_, f)| !**f)
            .fold(0.0f64, |m, (v, _)| m.max(v.abs().max_element()));
        let (cap, alpha) = match (&self.last, self.cap.lock().unwrap().take()) {
            (Some(prev), Some((dx, cap))) => {
                let (num, den) = prev
                    .iter()
                    .zip(x)
                    .zip(&dx)
                    .fold((0.0, 0.0), |(n, d), ((p, q), v)| {
                        (n + (*q - *p).dot(*v), d + v.dot(*v))
                    });
                (cap, num / den)
            }
            _ => (f64::NAN, f64::NAN),
        };
        let stats = self.inner.stats();
        eprintln!(
            "{} {} {} {:.3e} {:.3e} {:.4} {:.4} {:.3e}",
            self.step,
            self.iteration,
            stats.active_pairs(),
            stats.kappa(),
            stats.min_gap(),
            cap,
            alpha,
            norm
        );
        self.iteration += 1;
        self.last = Some(x.to_vec());
    }
    fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        self.inner.energy(step, x)
    }
    fn energy_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        self.inner.energy_change(step, x, dx, alpha)
    }
    fn add_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        self.inner.add_gradient(step, x, gradient);
    }
    fn add_hessian(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        sink: &mut HessianSink<'_>,
    ) {
        self.inner.add_hessian(step, x, curvature, sink);
    }
    fn max_step(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], reach: f64) -> f64 {
        let cap = self.inner.max_step(step, x, dx, reach);
        if self.last.is_some() {
            *self.cap.lock().unwrap() = Some((dx.to_vec(), cap));
        }
        cap
    }
    fn abandon_step(&mut self) {
        self.inner.abandon_step();
    }
    fn take_missing_pairs(&mut self) -> Vec<[usize; 2]> {
        self.inner.take_missing_pairs()
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let sizes: Vec<usize> = args.iter().filter_map(|a| a.parse().ok()).collect();
    // `steps=N` shortens the run (large sheets take seconds per step).
    let steps = args
        .iter()
        .find_map(|a| a.strip_prefix("steps=").and_then(|n| n.parse().ok()))
        .unwrap_or(45);
    let trace = args.iter().any(|a| a == "trace");
    let sizes = if sizes.is_empty() { vec![7, 12] } else { sizes };
    println!(
        "| n | vertices | pairs given slots | steps | Newton iterations | active pairs (end) | ms per step | us per vertex per step |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    for n in sizes {
        let s = 0.05 * 7.0 / n as f64;
        let (x, t, fixed) = sheets::dropped(n, s);
        let mesh = TriangleMesh::new(x, t).unwrap();
        let cloth = sheets::cloth(fixed);
        let model = cloth.build(&mesh).unwrap();
        let mut be = model.backward_euler(NewtonSettings::default()).unwrap();
        let settings = SelfContactSettings {
            dhat: 2e-3,
            thickness: 1e-3,
            ..SelfContactSettings::default()
        };
        let stats = if trace {
            let inner = SelfContactTerm::new(&model.system, &model.triangles, settings).unwrap();
            let stats = inner.stats();
            be.add_term(Box::new(Traced {
                inner,
                rest: Potential::mass_spring(&model.system),
                step: 0,
                iteration: 0,
                last: None,
                cap: Mutex::new(None),
            }));
            eprintln!("step iteration pairs kappa min_gap cap alpha grad_inf");
            stats
        } else {
            model.enable_self_contact(&mut be, settings).unwrap()
        };
        let mut system = model.system.clone();
        let mut iterations = 0;
        let mut widened = 0;
        let start = Instant::now();
        for _ in 0..steps {
            let report = be.step(&mut system, 1.0 / 60.0).unwrap();
            iterations += report.iterations;
            widened += report.pattern_pairs_added;
        }
        let elapsed = start.elapsed().as_secs_f64();
        let verts = system.len();
        println!(
            "| {n} | {verts} | {} | {steps} | {iterations} | {} | {:.1} | {:.1} |",
            widened,
            stats.active_pairs(),
            1e3 * elapsed / steps as f64,
            1e6 * elapsed / (steps * verts) as f64
        );
    }
}
