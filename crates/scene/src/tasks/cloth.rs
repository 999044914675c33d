//! The `Cloth` task: a mass-spring system (the lab cloth or explicit particles and
//! springs) stepped by an integrator of sinew-spring-sim, with the run's energies,
//! iterations and timing.

use super::limbs::{Held, Limbs};
use super::{RunContext, TaskOutput, TaskSpec, max_distance, non_negative};
use crate::limits::{
    MAX_GRID_SIZE, MAX_ITERATIONS, MAX_PARTICLE_STEPS, MAX_PARTICLES, MAX_STEPS, at_most,
};
use crate::results::{
    ClothFrame, ClothMetrics, ClothPictures, ContactMetrics, Csv, Pictures, TaskMetrics,
};
use serde::Deserialize;
use sinew_math::DVec3;
use sinew_spring_sim::StabilityBound;
use sinew_spring_sim::contact::{Collider, ContactSettings, Drive, Shape, signed_distance};
use sinew_spring_sim::{AutoSettings, NewtonSettings};
use sinew_spring_sim::{
    ClothGrid, Integrator, Material, Particle, Simulation, SpringSpec, SpringSystem, run,
    run_observed,
};

/// Scene fields of a `Cloth` task.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClothTask {
    /// Unique name in the scene.
    pub name: String,
    /// The system.
    pub system: SystemSpec,
    /// The integrator (default: `auto`, the cheapest integrator stable at `dt`).
    #[serde(default = "auto")]
    pub integrator: Integrator,
    /// Time step in seconds.
    pub dt: f64,
    /// Number of steps.
    pub steps: usize,
    /// Fail the task if the total energy rises by more than this (relative) in a step.
    #[serde(default)]
    pub expect_energy_increase_max: Option<f64>,
    /// Also measure the distance from the true motion after 1 s (`true_motion_error_1s`)
    /// against a velocity Verlet run far below its stability limit.
    #[serde(default)]
    pub true_motion_reference: bool,
    /// Rigid colliders and contact settings (backward Euler: IPC's barrier; explicit
    /// integrators: a projection, not guaranteed).
    #[serde(default)]
    pub contact: Option<ContactSpec>,
    /// The directory relative paths (a limbs clip) are read from: the scene file's own,
    /// set when the scene is loaded (not a scene field).
    #[serde(skip)]
    pub base_dir: std::path::PathBuf,
}

/// The colliders of a `Cloth` task and the contact settings.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactSpec {
    /// The colliders.
    pub colliders: Vec<Collider>,
    /// Capsules on an animated skeleton, after `colliders` in the list (default: none).
    #[serde(default)]
    pub limbs: Option<super::limbs::LimbsSpec>,
    /// `dhat`, thickness, `mu`, `eps_v`, the time-of-impact fraction (defaults:
    /// sinew-spring-sim's).
    #[serde(default)]
    pub settings: ContactSettings,
}

fn auto() -> Integrator {
    Integrator::Auto(AutoSettings::default())
}

/// The reference run takes this many times the stability bound's substeps; the check
/// run half as many (docs/workloads.md: halving the substep must change far less than the
/// error measured).
const REFERENCE_SUBSTEP_FACTOR: usize = 64;

/// Positions after `steps` steps of velocity Verlet at `factor` times the stability
/// bound's substep count at the start.
fn reference_positions(
    system: &SpringSystem,
    dt: f64,
    steps: usize,
    factor: usize,
) -> Result<Vec<DVec3>, String> {
    let substeps = StabilityBound::of(system).substeps(dt).max(1) * factor;
    let mut sim = Simulation::new(
        system.clone(),
        Integrator::VelocityVerlet {
            substeps: Some(substeps),
        },
    )
    .map_err(|e| format!("reference run: {e}"))?;
    let metrics = run(&mut sim, dt, steps).map_err(|e| format!("reference run: {e}"))?;
    if metrics.diverged {
        return Err("reference run diverged".into());
    }
    Ok(sim.system().positions().to_vec())
}

/// A mass-spring system in a scene.
#[derive(Debug, Deserialize)]
pub enum SystemSpec {
    /// A square cloth grid (fields default to the lab cloth, W4).
    Grid(#[serde(default)] ClothGrid),
    /// Explicit particles and springs.
    Explicit {
        /// The particles.
        particles: Vec<Particle>,
        /// The springs (rest length defaults to the initial distance, stiffness to the
        /// material's).
        springs: Vec<SpringSpec>,
        /// Stiffness, damping, gravity.
        #[serde(default)]
        material: Material,
    },
}

/// The most frames a picture animates.
const MAX_FRAMES: usize = 100;
/// The most frames kept for the interactive viewer (a 101 x 101 cloth frame is about
/// 245 kB in memory).
const MAX_TRACK_FRAMES: usize = 300;

impl ClothTask {
    /// The particles each of the limbs' attachments holds (`contact: limbs: attach`),
    /// by index, checked against the system's particles at their `start` positions
    /// (`grid`: its size when it is a grid).
    fn attached(&self, grid: Option<usize>, start: &[DVec3]) -> Result<Vec<Vec<usize>>, String> {
        let Some(limbs) = self.contact.as_ref().and_then(|c| c.limbs.as_ref()) else {
            return Ok(Vec::new());
        };
        let count = start.len();
        let mut all = Vec::with_capacity(limbs.attach.len());
        // Marks of the particles held so far.
        let mut held = vec![false; if limbs.attach.is_empty() { 0 } else { count }];
        for (k, a) in limbs.attach.iter().enumerate() {
            let err = |e: String| format!("contact: limbs: attach[{k}]: {e}");
            if a.sheet != 0 {
                return Err(err(format!(
                    "sheet = {}, but a Cloth task has one system (sheet 0)",
                    a.sheet
                )));
            }
            let indices = a.indices(grid, start, None).map_err(err)?;
            for &v in &indices {
                if std::mem::replace(&mut held[v], true) {
                    return Err(err(format!("{} is held twice", a.name(v, grid))));
                }
            }
            all.push(indices);
        }
        Ok(all)
    }

    /// The system of the scene with the particles `pinned` (indices) fixed as well.
    fn system(&self, pinned: &[usize]) -> Result<SpringSystem, String> {
        match &self.system {
            SystemSpec::Grid(grid) if pinned.is_empty() => SpringSystem::cloth(grid),
            SystemSpec::Grid(grid) => {
                let n = grid.size;
                let mut grid = grid.clone();
                grid.fixed.extend(pinned.iter().map(|&v| (v / n, v % n)));
                SpringSystem::cloth(&grid)
            }
            SystemSpec::Explicit {
                particles,
                springs,
                material,
            } if pinned.is_empty() => SpringSystem::new(particles, springs, *material),
            SystemSpec::Explicit {
                particles,
                springs,
                material,
            } => {
                let mut particles = particles.clone();
                for &v in pinned {
                    particles[v].fixed = true;
                }
                SpringSystem::new(&particles, springs, *material)
            }
        }
        .map_err(|e| format!("system: {e}"))
    }

    fn build(&self) -> Result<(Simulation, Option<Limbs>, Vec<Held>), String> {
        // The size is checked before the system is built: a grid's particles are
        // allocated by the build.
        let particles = match &self.system {
            SystemSpec::Grid(grid) => {
                at_most("system: size", grid.size, MAX_GRID_SIZE)?;
                grid.size * grid.size
            }
            SystemSpec::Explicit { particles, .. } => particles.len(),
        };
        at_most("system: particles", particles, MAX_PARTICLES)?;
        at_most("steps", self.steps, MAX_STEPS)?;
        let size = match &self.system {
            SystemSpec::Grid(grid) => Some(grid.size),
            SystemSpec::Explicit { .. } => None,
        };
        let system = self.system(&[])?;
        // The held particles are chosen among the built system's particles, and pinned:
        // the system is built again with them fixed.
        let attached = self.attached(size, system.positions())?;
        let system = if attached.is_empty() {
            system
        } else {
            self.system(&attached.concat())?
        };
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(format!("dt = {}, must be finite and > 0", self.dt));
        }
        sinew_spring_sim::check_time_step(self.dt).map_err(|e| format!("dt: {e}"))?;
        self.check_work(&system)?;
        let mut sim =
            Simulation::new(system, self.integrator).map_err(|e| format!("integrator: {e}"))?;
        let mut limbs = None;
        let mut held = Vec::new();
        if let Some(contact) = &self.contact {
            let mut colliders = contact.colliders.clone();
            if let Some(spec) = &contact.limbs {
                let mut built = spec
                    .build(self.steps.saturating_add(1), &self.base_dir)
                    .map_err(|e| format!("contact: limbs: {e}"))?;
                let shapes = built
                    .shapes_at(0.0)
                    .map_err(|e| format!("contact: limbs: {e}"))?;
                colliders.extend(shapes.into_iter().map(Collider::fixed));
                for (&joint, particles) in built.held_joints().iter().zip(&attached) {
                    held.push(Held::new(
                        &built,
                        joint,
                        particles.clone(),
                        sim.system().positions(),
                    ));
                }
                limbs = Some(built);
            }
            sim.set_contact(colliders, contact.settings)
                .map_err(|e| format!("contact: {e}"))?;
        }
        Ok((sim, limbs, held))
    }
}

impl ClothTask {
    /// Checks the particle steps the run asks for: particles x steps x the work of a
    /// step (the substeps of an explicit integrator, the Newton iteration cap of an
    /// implicit one), and those of the reference run when it is asked for.
    fn check_work(&self, system: &SpringSystem) -> Result<(), String> {
        let bound = || StabilityBound::of(system).substeps(self.dt);
        let newton_cap = |n: &NewtonSettings| -> Result<usize, String> {
            at_most(
                "integrator: max_iterations",
                n.max_iterations,
                MAX_ITERATIONS,
            )?;
            // Each lag of friction after the first may run another minimization.
            Ok(n.max_iterations.saturating_mul(n.friction_lags))
        };
        let per_step = match &self.integrator {
            Integrator::BackwardEuler(n)
            | Integrator::Bdf2(n)
            | Integrator::ImplicitMidpoint(n) => newton_cap(n)?,
            Integrator::SymplecticEuler { substeps } => *substeps,
            Integrator::VelocityVerlet { substeps }
            | Integrator::SymplecticEulerBounded { substeps } => substeps.unwrap_or_else(bound),
            Integrator::FlawedReportMethod => 1,
            // Auto takes the explicit substeps when they are below its cap, else Newton.
            Integrator::Auto(a) => bound().min(a.max_substeps).max(newton_cap(&a.newton)?),
        };
        let work = system.len() as f64 * self.steps as f64 * per_step.max(1) as f64;
        if work > MAX_PARTICLE_STEPS {
            return Err(format!(
                "steps = {} of {} particles at {per_step} substeps or iterations a step asks \
                 for {work:.2e} particle steps, above the limit of {MAX_PARTICLE_STEPS:.0e} \
                 (docs/scenes.md, \"Limits\")",
                self.steps,
                system.len()
            ));
        }
        if self.true_motion_reference {
            let substeps = bound().max(1).saturating_mul(REFERENCE_SUBSTEP_FACTOR);
            let work = system.len() as f64 * substeps as f64 * self.steps_to_one_second() as f64;
            if work > MAX_PARTICLE_STEPS {
                return Err(format!(
                    "true_motion_reference = true asks for {work:.2e} particle steps of the \
                     reference run ({substeps} substeps a step for 1 s), above the limit of \
                     {MAX_PARTICLE_STEPS:.0e} (docs/scenes.md, \"Limits\")"
                ));
            }
        }
        Ok(())
    }

    /// The step after which the simulated time is closest to 1 s.
    fn steps_to_one_second(&self) -> usize {
        ((1.0 / self.dt).round() as usize).max(1)
    }
}

/// Drives the limbs' capsules (the colliders from `first` on) to the animation's pose at
/// the end of the next step of `dt`, moves the held particles along the rigid motion of
/// their joint's frame over the step, and returns the capsules' poses.
fn drive_limbs(
    sim: &mut Simulation,
    limbs: &mut Limbs,
    held: &mut [Held],
    first: usize,
    dt: f64,
) -> Result<Vec<Shape>, String> {
    let shapes = limbs.shapes_at(sim.time() + dt)?;
    if !held.is_empty() {
        let motions = held.iter_mut().map(|h| h.step_motion(limbs, dt)).collect();
        sim.set_pinned_motion(motions)
            .map_err(|e| format!("contact: limbs: attach: {e}"))?;
    }
    for (k, &target) in shapes.iter().enumerate() {
        sim.drive_collider(
            first + k,
            &Drive::To {
                target,
                duration: dt,
            },
        )
        .map_err(|e| format!("contact: limbs: capsules[{k}]: {e}"))?;
    }
    Ok(shapes)
}

impl TaskSpec for ClothTask {
    fn validate(&self) -> Result<(), String> {
        self.build()?;
        non_negative(
            "expect_energy_increase_max",
            self.expect_energy_increase_max,
        )?;
        Ok(())
    }

    fn run(&self, ctx: &RunContext) -> Result<TaskOutput, String> {
        let (mut sim, mut limbs, mut held) = self.build()?;
        let start = sim.system().clone();
        let one_second = self.steps_to_one_second();
        let mut at_one_second: Option<Vec<DVec3>> = None;
        let mut last_reason: Option<String> = None;
        let mut last_substeps = 0;
        let springs: Vec<(usize, usize, f64)> = sim
            .system()
            .springs()
            .iter()
            .map(|s| (s.a, s.b, s.rest_length))
            .collect();
        let fixed: Vec<usize> = (0..sim.system().len())
            .filter(|&i| sim.system().fixed()[i])
            .collect();
        let frame_every = self.steps.div_ceil(MAX_FRAMES).max(1);
        // The interactive viewer gets a finer selection (it thins it to its own budget):
        // the start, then after every `track_every`-th step and the last.
        let track_every = self.steps.div_ceil(MAX_TRACK_FRAMES).max(1);
        let mut track: Vec<ClothFrame> = Vec::new();
        let mut track_steps: Vec<usize> = Vec::new();
        let mut frames: Vec<Vec<DVec3>> = Vec::new();
        // The colliders posed at each frame's time, for the pictures.
        let mut frame_colliders: Vec<Vec<Shape>> = Vec::new();
        if ctx.keep_frames {
            frames.push(sim.system().positions().to_vec());
            frame_colliders.push(sim.colliders().iter().map(|c| c.at(sim.time())).collect());
            track.push(ClothFrame {
                positions: sim.system().positions().to_vec(),
                colliders: sim.colliders().iter().map(|c| c.at(sim.time())).collect(),
            });
            track_steps.push(0);
        }
        let mut csv = String::from(
            "step,time,kinetic,spring,gravity,total,iterations,residual,linear_solver\n",
        );
        let mut energy = vec![(0.0, sim.system().energies().total())];
        let mut iterations = Vec::with_capacity(self.steps);
        let dt = self.dt;
        // Contact metrics, from distances computed here after every step (independent
        // of the integrator's own bookkeeping). The limbs' capsules, last in the list,
        // are posed by the animation itself (the targets of the step's drive, from
        // forward kinematics), not by the library's driven colliders.
        let colliders: Vec<Collider> = sim.colliders().to_vec();
        let fixed_motion = colliders.len() - limbs.as_ref().map_or(0, Limbs::len);
        let mut drive_error: Option<String> = None;
        let mut targets = match &mut limbs {
            Some(limbs) => drive_limbs(&mut sim, limbs, &mut held, fixed_motion, dt)?,
            None => Vec::new(),
        };
        // The colliders at a step's end, one buffer for the run.
        let mut posed: Vec<Shape> = Vec::with_capacity(colliders.len());
        let contact_settings = sim.contact_settings().copied();
        let mut min_distance = f64::INFINITY;
        let mut penetrations = 0usize;
        let mut contact_pairs_max = 0usize;
        let mut swept_passes = 0usize;
        let mut max_path_depth: Option<f64> = None;
        // The most a piece's path went beyond a collider's allowance, over the steps an
        // implicit integrator took (those that record their pieces and promise it).
        let mut path_excess: Option<f64> = None;
        let mut attach_error_max: Option<f64> = None;
        let mut previous = sim.system().positions().to_vec();
        let mut progress = ctx.progress(&self.name, self.steps);
        // The paths a moving collider must not cross are those of each piece of a step
        // (one piece for a step taken whole): the implicit integrators and `auto` record
        // the pieces' end states for this check; the explicit ones promise nothing, and
        // their steps' straight paths are checked whole.
        let moving = colliders.iter().any(Collider::moves_surface) || limbs.is_some();
        if moving {
            let _ = sim.record_piece_ends(true);
        }
        let metrics = run_observed(&mut sim, dt, self.steps, |step, report, sim| {
            let system = sim.system();
            progress.inc();
            if step + 1 == one_second {
                at_one_second = Some(system.positions().to_vec());
            }
            last_reason = report.auto_reason.map(|r| r.to_string());
            last_substeps = report.substeps;
            let time = (step + 1) as f64 * dt;
            let e = report.energy_after;
            csv.push_str(&format!(
                "{},{time},{},{},{},{},{},{},{:?}\n",
                step + 1,
                e.kinetic,
                e.spring,
                e.gravity,
                e.total(),
                report.iterations,
                report.residual,
                report.linear_solver
            ));
            energy.push((time, e.total()));
            iterations.push((time, report.iterations as f64));
            // The colliders at the step's end: those of constant motion where it puts
            // them, the limbs where the animation does.
            posed.clear();
            posed.extend(colliders[..fixed_motion].iter().map(|c| c.at(time)));
            posed.extend_from_slice(&targets);
            let system = sim.system();
            if let Some(settings) = &contact_settings {
                let mut pairs = 0;
                for shape in &posed {
                    for (x, fixed) in system.positions().iter().zip(system.fixed()) {
                        if *fixed {
                            continue;
                        }
                        let d = signed_distance(shape, *x, settings.thickness).distance;
                        min_distance = min_distance.min(d);
                        penetrations += usize::from(d <= 0.0);
                        pairs += usize::from(d < settings.dhat);
                    }
                }
                contact_pairs_max = contact_pairs_max.max(pairs);
                swept_passes += report.swept_passes;
                // Without a record (the explicit integrators) the step is one piece.
                let record = sim.piece_ends();
                let recorded = record.is_some();
                let pieces: Vec<(f64, &[DVec3])> = match record {
                    Some(record) => record.iter().collect(),
                    None => vec![(time, system.positions())],
                };
                // The motions of the step just taken (a limb is driven for the next
                // one below).
                let paths = super::deepest_swept_path(
                    sim.colliders(),
                    (settings.thickness, settings.dhat),
                    (time - dt, &previous),
                    pieces.iter().copied(),
                    system.fixed(),
                );
                if let Some(d) = paths {
                    max_path_depth = Some(max_path_depth.map_or(d.depth, |m| m.max(d.depth)));
                    if recorded {
                        path_excess = Some(path_excess.map_or(d.excess, |m| m.max(d.excess)));
                    }
                }
            }
            // Every step's end starts the next step's paths, whether or not a collider
            // moved in this one (a limb held still, then moving).
            previous.copy_from_slice(system.positions());
            // The held particles against their joint's frame at the step's end (the
            // animation's, not the library's pinned motion).
            for h in &held {
                let e = h.error(system.positions());
                attach_error_max = Some(attach_error_max.map_or(e, |m: f64| m.max(e)));
            }
            let last = step + 1 == self.steps;
            if ctx.keep_frames && ((step + 1) % frame_every == 0 || last) {
                frames.push(system.positions().to_vec());
                frame_colliders.push(posed.clone());
            }
            if ctx.keep_frames && ((step + 1) % track_every == 0 || last) {
                track.push(ClothFrame {
                    positions: system.positions().to_vec(),
                    colliders: posed.clone(),
                });
                track_steps.push(step + 1);
            }
            if let Some(limbs) = &mut limbs
                && !last
            {
                match drive_limbs(sim, limbs, &mut held, fixed_motion, dt) {
                    Ok(next) => targets = next,
                    Err(e) => {
                        drive_error.get_or_insert(e);
                    }
                }
            }
        })
        .map_err(|e| e.to_string())?;
        if let Some(e) = drive_error {
            return Err(e);
        }
        drop(progress);
        let pictures = if ctx.keep_frames {
            Pictures::Cloth(ClothPictures {
                integrator: metrics.integrator.clone(),
                springs,
                fixed,
                frames: frames
                    .into_iter()
                    .zip(frame_colliders)
                    .map(|(positions, colliders)| ClothFrame {
                        positions,
                        colliders,
                    })
                    .collect(),
                track,
                track_steps,
                dt,
                energy,
                iterations,
            })
        } else {
            Pictures::None
        };
        let mut failures = Vec::new();
        let mut true_motion = None;
        if self.true_motion_reference
            && let Some(positions) = &at_one_second
        {
            let reference = reference_positions(&start, dt, one_second, REFERENCE_SUBSTEP_FACTOR)?;
            let half = reference_positions(&start, dt, one_second, REFERENCE_SUBSTEP_FACTOR / 2)?;
            let error = max_distance(positions, &reference);
            let check = max_distance(&reference, &half);
            if check >= 0.1 * error && check > 0.0 {
                failures.push(format!(
                    "the reference is not converged enough to measure this error: halving its substep changes it by {check:.2e}, the error is {error:.2e}"
                ));
            }
            true_motion = Some((error, check));
        }
        if penetrations > 0 {
            failures.push(format!(
                "{penetrations} particle-collider pairs at distance <= 0 over the run"
            ));
        }
        super::moving_body_failures("particle", path_excess, attach_error_max, &mut failures);
        if swept_passes > 0 {
            failures.push(format!(
                "{swept_passes} piece(s) kept with a particle passed by a moving collider"
            ));
        }
        if metrics.diverged {
            failures.push(format!(
                "diverged: {}",
                metrics.stopped_by.as_deref().unwrap_or("non-finite state")
            ));
        }
        if let Some(limit) = self.expect_energy_increase_max
            && metrics.energy_increase_max > limit
        {
            failures.push(format!(
                "energy rose by {:.3e} (relative) in a step > expected at most {limit:.1e}",
                metrics.energy_increase_max
            ));
        }
        let contact = contact_settings.is_some().then(|| ContactMetrics {
            min_distance: min_distance.is_finite().then_some(min_distance),
            penetrations,
            contact_pairs_max,
            kappa: sim.contact_kappa(),
            swept_passes,
            max_path_depth,
            reach_error_max: limbs.as_ref().and_then(Limbs::reach_error_max),
            attach_error_max,
        });
        let out = ClothMetrics {
            run: metrics.clone(),
            auto_reason: last_reason,
            substeps: last_substeps,
            true_motion_error_1s: true_motion.map(|t| t.0),
            true_motion_reference_check: true_motion.map(|t| t.1),
            contact,
        };
        // Explicit integrators report substeps where implicit ones report Newton
        // iterations (the metric keys keep one name for both; docs/scenes.md says so).
        let work =
            if metrics.integrator.contains("verlet") || metrics.integrator.contains("symplectic") {
                format!("{last_substeps} substeps per step")
            } else {
                format!(
                    "{} Newton iterations (max {})",
                    metrics.newton_iterations_total, metrics.newton_iterations_max
                )
            };
        let headline = format!(
            "{} {} steps: {work}, energy {:.4} -> {:.4}, {:.3} ms/step{}{}",
            metrics.integrator,
            metrics.steps,
            metrics.energy_start,
            metrics.energy_end,
            metrics.time_per_step_ms_median,
            if metrics.diverged { ", DIVERGED" } else { "" },
            true_motion.map_or(String::new(), |(e, _)| format!(
                ", {e:.1e} from the true motion at 1 s"
            ))
        );
        Ok(TaskOutput {
            metrics: TaskMetrics::Cloth(out),
            headline,
            failures,
            table: Csv {
                suffix: "steps.csv",
                text: csv,
            },
            pictures,
        })
    }
}
