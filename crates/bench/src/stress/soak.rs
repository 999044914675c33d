//! The soak run (`cargo xtask stress --soak`): the lab's workloads for a million steps
//! each, to catch what only a long run shows (slow energy gain, drift of bone lengths,
//! a NaN after many steps).
//!
//! - W4, the lab cloth (11 x 11, stiffness 100, gravity 0.3, two pinned corners,
//!   h = 1/60), with `Integrator::Auto` and damping 0.2 and 0: no NaN and no divergence;
//!   the damped run must never gain more than the scenes' allowance of `1e-9` of the
//!   starting energy scale in one step (docs/scenes.md, "Energy rise"), the undamped
//!   one's rise is reported.
//! - W1, the lab flower tracked by the 8-joint lab chain (each frame warm-started from the
//!   last), cycling through the flower's 500 targets, with every solver of the
//!   registry: no NaN, every bone within `1e-12` of its rest length (relative) at every
//!   frame.

use serde::Serialize;
use sinew_ik::SolverOptions;
use sinew_scene::workloads::{w1_skeleton, w1_targets};
use sinew_skeleton::GlobalPose;
use sinew_skeleton::ik::{Chain, SolveSettings};
use sinew_spring_sim::{
    AutoSettings, ClothGrid, DIVERGENCE_RADIUS, Energies, Integrator, IntegratorKind, Simulation,
};
use std::time::Instant;

/// The largest rise of the total energy in one step of a damped run, relative to the
/// starting scale `kinetic + spring + |gravity|`: the scenes' `expect_energy_increase_max`
/// for the lab cloth (docs/scenes.md).
pub const DAMPED_RISE_ALLOWANCE: f64 = 1e-9;

/// The largest relative bone-length error a tracking frame may have.
pub const BONE_RELATIVE: f64 = 1e-12;

/// What a cloth soak did.
#[derive(Clone, Debug, Serialize)]
pub struct ClothSoak {
    /// The run's name.
    pub name: String,
    /// Damping of every spring.
    pub damping: f64,
    /// Steps completed.
    pub steps_run: usize,
    /// Largest rise of the total energy in one step, relative to the starting scale.
    pub rise_max: f64,
    /// Largest `(E_n - E_0) / S` over the run: how far above its start the energy ever
    /// got.
    pub above_start_max: f64,
    /// `(E_end - E_0) / S`.
    pub end_change: f64,
    /// Steps taken by velocity Verlet, by BDF2 and by backward Euler.
    pub verlet_steps: usize,
    /// Steps taken by BDF2.
    pub bdf2_steps: usize,
    /// Steps taken by backward Euler.
    pub backward_euler_steps: usize,
    /// Wall-clock seconds.
    pub seconds: f64,
    /// Broken invariants, one sentence each.
    pub failures: Vec<String>,
}

/// Runs W4 with `auto` for `steps` steps at `damping`.
#[must_use]
pub fn run_cloth(steps: usize, damping: f64) -> ClothSoak {
    let started = Instant::now();
    let mut out = ClothSoak {
        name: format!("W4 auto damping {damping}"),
        damping,
        steps_run: 0,
        rise_max: f64::NEG_INFINITY,
        above_start_max: f64::NEG_INFINITY,
        end_change: 0.0,
        verlet_steps: 0,
        bdf2_steps: 0,
        backward_euler_steps: 0,
        seconds: 0.0,
        failures: Vec::new(),
    };
    let built = ClothGrid::lab_sized(11, 0.2)
        .with_damping(damping)
        .build()
        .map_err(|e| e.to_string())
        .and_then(|system| {
            Simulation::new(system, Integrator::Auto(AutoSettings::default()))
                .map_err(|e| e.to_string())
        });
    let mut sim = match built {
        Ok(s) => s,
        Err(e) => {
            out.failures.push(format!("could not build W4: {e}"));
            return out;
        }
    };
    let dt = 1.0 / 60.0;
    let start = sim.system().energies();
    let scale = start.scale();
    let e0 = start.total();
    for n in 0..steps {
        let report = match sim.step(dt) {
            Ok(r) => r,
            Err(e) => {
                out.failures.push(format!("step {n}: {e}"));
                break;
            }
        };
        out.steps_run += 1;
        match report.integrator {
            IntegratorKind::VelocityVerlet => out.verlet_steps += 1,
            IntegratorKind::Bdf2 => out.bdf2_steps += 1,
            _ => out.backward_euler_steps += 1,
        }
        let (before, after) = (report.energy_before.total(), report.energy_after.total());
        if !(before.is_finite() && after.is_finite()) {
            out.failures.push(format!("step {n}: a non-finite energy"));
            break;
        }
        let rise = Energies::relative_rise(&start, &report.energy_before, &report.energy_after);
        out.rise_max = out.rise_max.max(rise);
        out.above_start_max = out.above_start_max.max((after - e0) / scale);
        out.end_change = (after - e0) / scale;
        if damping > 0.0 && rise > DAMPED_RISE_ALLOWANCE {
            out.failures.push(format!(
                "step {n}: the damped cloth gained {rise:.3e} of its energy scale in one step (allowance {DAMPED_RISE_ALLOWANCE:e})"
            ));
            break;
        }
        // Checking every particle every step would cost as much as a Verlet step; the
        // energy above catches a NaN at once, and a divergence shows in the positions
        // within the 1 000 steps between two looks.
        if n % 1000 == 999 || n + 1 == steps {
            let x = sim.system().positions();
            if let Some(p) = x
                .iter()
                .position(|x| !(x.is_finite() && x.length() <= DIVERGENCE_RADIUS))
            {
                out.failures.push(format!(
                    "step {n}: particle {p} non-finite or beyond {DIVERGENCE_RADIUS}"
                ));
                break;
            }
        }
    }
    out.seconds = started.elapsed().as_secs_f64();
    out
}

/// What an IK soak did.
#[derive(Clone, Debug, Serialize)]
pub struct IkSoak {
    /// The solver's label.
    pub solver: &'static str,
    /// Frames solved.
    pub frames: usize,
    /// Largest relative bone-length error over every frame and bone.
    pub bone_error_max: f64,
    /// Largest reported effector error.
    pub error_max: f64,
    /// Mean reported effector error.
    pub error_mean: f64,
    /// Wall-clock seconds.
    pub seconds: f64,
    /// Broken invariants, one sentence each.
    pub failures: Vec<String>,
}

/// Tracks the W1 flower for `frames` frames with the registry's solver `solver`.
#[must_use]
pub fn run_ik(frames: usize, solver: &'static str) -> IkSoak {
    let started = Instant::now();
    let mut out = IkSoak {
        solver,
        frames: 0,
        bone_error_max: 0.0,
        error_max: 0.0,
        error_mean: 0.0,
        seconds: 0.0,
        failures: Vec::new(),
    };
    let setup = w1_skeleton().and_then(|skeleton| {
        let chain = Chain::whole(&skeleton).map_err(|e| e.to_string())?;
        let ik = SolverOptions::by_name(solver)
            .and_then(|o| o.build())
            .map_err(|e| e.to_string())?;
        Ok((skeleton, chain, ik))
    });
    let (skeleton, chain, mut ik) = match setup {
        Ok(s) => s,
        Err(e) => {
            out.failures.push(format!("could not build W1: {e}"));
            return out;
        }
    };
    let targets = w1_targets(500);
    let settings = SolveSettings::default();
    let mut pose = skeleton.rest_pose();
    let mut global = GlobalPose::new();
    let mut fk = GlobalPose::new();
    let mut error_sum = 0.0;
    for frame in 0..frames {
        let target = targets[frame % targets.len()];
        let report =
            match ik.solve_position(&skeleton, &chain, &mut pose, &mut global, target, &settings) {
                Ok(r) => r,
                Err(e) => {
                    out.failures.push(format!("frame {frame}: {e}"));
                    break;
                }
            };
        out.frames += 1;
        if !report.error.is_finite() {
            out.failures
                .push(format!("frame {frame}: a non-finite error"));
            break;
        }
        out.error_max = out.error_max.max(report.error);
        error_sum += report.error;
        // Bone lengths measured on forward kinematics of the returned pose, so the
        // check does not rely on the solver's own global pose.
        if let Err(e) = skeleton.forward_kinematics(&pose, &mut fk) {
            out.failures.push(format!("frame {frame}: {e}"));
            break;
        }
        let mut worst: f64 = 0.0;
        for (bone, &length) in chain.bone_lengths().iter().enumerate() {
            let (a, b) = (chain.joints()[bone], chain.joints()[bone + 1]);
            let measured = fk.positions[a].distance(fk.positions[b]);
            // NaN-safe: a NaN length gives an infinite error.
            let relative = (measured - length).abs() / length;
            worst = worst.max(if relative.is_nan() {
                f64::INFINITY
            } else {
                relative
            });
        }
        out.bone_error_max = out.bone_error_max.max(worst);
        if worst > BONE_RELATIVE {
            out.failures.push(format!(
                "frame {frame}: a bone {worst:.3e} off its rest length (relative; allowed {BONE_RELATIVE:e})"
            ));
            break;
        }
    }
    if out.frames > 0 {
        out.error_mean = error_sum / out.frames as f64;
    }
    out.seconds = started.elapsed().as_secs_f64();
    out
}

/// Every IK soak: W1 with each solver of `SolverOptions::NAMED`.
#[must_use]
pub fn run_all_ik(frames: usize) -> Vec<IkSoak> {
    SolverOptions::NAMED
        .iter()
        .map(|(name, _)| run_ik(frames, name))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_short_cloth_soak_keeps_its_invariants() {
        for damping in [0.2, 0.0] {
            let out = run_cloth(120, damping);
            assert!(out.failures.is_empty(), "{:?}", out.failures);
            assert_eq!(out.steps_run, 120);
            assert_eq!(
                out.verlet_steps + out.bdf2_steps + out.backward_euler_steps,
                120
            );
            assert!(out.rise_max.is_finite());
        }
    }

    #[test]
    fn a_short_tracking_soak_keeps_bone_lengths() {
        for out in run_all_ik(600) {
            assert!(
                out.failures.is_empty(),
                "{}: {:?}",
                out.solver,
                out.failures
            );
            assert_eq!(out.frames, 600);
            assert!(out.bone_error_max <= BONE_RELATIVE);
            // Tracking the flower, every solver ends each frame near its target.
            assert!(out.error_mean < 1e-3, "{}: {}", out.solver, out.error_mean);
        }
    }
}
