//! Explicit integrators with substeps: symplectic Euler (the course's starter integrator)
//! and velocity Verlet (second order, the same cost per substep), both the cheap choice
//! where they are stable (see [`crate::stability`] for the bound and issue 9).
//!
//! These steppers take the substep count they are given, unchecked (for comparisons and
//! for finding the stability limit empirically); [`crate::Integrator::VelocityVerlet`]
//! and [`crate::Integrator::SymplecticEulerBounded`] check it against the bound, or choose
//! it, before every step.
//!
//! Each substep of length `h / substeps` updates velocities from the forces at the
//! current positions (springs, gravity, axial damping along the current spring
//! direction), then positions from the new velocities. Fixed particles do not move. It
//! is only conditionally stable: above its limit it explodes, and then the step is undone
//! and reported as an error rather than returning NaN.

use crate::model::{SpringSystem, check_time_step};
use crate::report::{IntegratorKind, StepError, StepReport};
use sinew_math::DVec3;

/// Symplectic Euler with a fixed substep count, with its force buffer.
#[derive(Clone, Debug)]
pub struct SymplecticEuler {
    substeps: usize,
    forces: Vec<DVec3>,
    backup_x: Vec<DVec3>,
    backup_v: Vec<DVec3>,
}

impl SymplecticEuler {
    /// `substeps` substeps per step (at least 1).
    pub fn new(system: &SpringSystem, substeps: usize) -> Result<Self, crate::model::ModelError> {
        if substeps == 0 {
            return Err(crate::model::ModelError::BadParameter {
                name: "substeps",
                reason: "must be at least 1",
            });
        }
        Ok(Self {
            substeps,
            forces: vec![DVec3::ZERO; system.len()],
            backup_x: system.positions().to_vec(),
            backup_v: system.velocities().to_vec(),
        })
    }

    /// The substep count.
    #[must_use]
    pub fn substeps(&self) -> usize {
        self.substeps
    }

    /// Sets the substep count (at least 1; 0 is taken as 1).
    pub fn set_substeps(&mut self, substeps: usize) {
        self.substeps = substeps.max(1);
    }

    /// Advances `system` by `h`.
    pub fn step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        check_time_step(h)?;
        if self.forces.len() != system.len() {
            return Err(crate::model::ModelError::TopologyMismatch.into());
        }
        let mut report = StepReport::new(IntegratorKind::SymplecticEuler);
        report.substeps = self.substeps;
        report.energy_before = system.energies();
        self.backup_x.copy_from_slice(system.positions());
        self.backup_v.copy_from_slice(system.velocities());
        let dt = h / self.substeps as f64;
        let parts = system.parts_mut();
        let (x, v) = (parts.positions, parts.velocities);
        let (masses, fixed, springs) = (parts.masses, parts.fixed, parts.springs);
        let gravity = parts.material.gravity;
        let damping = parts.material.damping;
        for _ in 0..self.substeps {
            forces(x, v, masses, springs, gravity, damping, &mut self.forces);
            for i in 0..x.len() {
                if !fixed[i] {
                    v[i] += dt / masses[i] * self.forces[i];
                    x[i] += dt * v[i];
                }
            }
        }
        if let Some(particle) = (0..x.len()).find(|&i| !(x[i].is_finite() && v[i].is_finite())) {
            x.copy_from_slice(&self.backup_x);
            v.copy_from_slice(&self.backup_v);
            return Err(StepError::NonFinite {
                integrator: IntegratorKind::SymplecticEuler,
                particle,
            });
        }
        report.iterations = self.substeps;
        report.energy_after = system.energies();
        Ok(report)
    }
}

/// `1/m` per particle, 0 for fixed ones.
fn inverse_masses(system: &SpringSystem) -> Vec<f64> {
    system
        .masses()
        .iter()
        .zip(system.fixed())
        .map(|(m, f)| if *f { 0.0 } else { 1.0 / m })
        .collect()
}

/// Total force on every particle: gravity, springs, and axial damping along the current
/// spring direction (`out` is overwritten). The hot loop of the
/// explicit integrators: one square root and one division per spring.
#[inline]
pub(crate) fn forces(
    x: &[DVec3],
    v: &[DVec3],
    masses: &[f64],
    springs: &[crate::model::Spring],
    gravity: DVec3,
    damping: f64,
    out: &mut [DVec3],
) {
    for (f, m) in out.iter_mut().zip(masses) {
        *f = *m * gravity;
    }
    for s in springs {
        let d = x[s.a] - x[s.b];
        let l = d.length();
        // -k (l - L) u - c (u . (v_a - v_b)) u with u = d / l; a zero-length spring has no
        // direction and exerts nothing.
        let force = if l > 0.0 {
            let inv_l = 1.0 / l;
            let mut scale = -s.stiffness * (1.0 - s.rest_length * inv_l);
            if damping > 0.0 {
                scale -= damping * inv_l * inv_l * d.dot(v[s.a] - v[s.b]);
            }
            scale * d
        } else {
            DVec3::ZERO
        };
        out[s.a] += force;
        out[s.b] -= force;
    }
}

/// Velocity Verlet (kick-drift-kick) with a fixed substep count, with its buffers.
///
/// Each substep of length `dt`: `v += dt/2 a`, `x += dt v`, `a = M^-1 f(x, v)`,
/// `v += dt/2 a`. The force at the end of a substep is the one at the start of the next,
/// so a substep costs one force evaluation (plus one per step when the state was changed
/// from outside). With damping, the force at the end of a substep uses the half-step
/// velocity (the damping term is then first order; the springs keep second order).
#[derive(Clone, Debug)]
pub struct VelocityVerlet {
    substeps: usize,
    forces: Vec<DVec3>,
    backup_x: Vec<DVec3>,
    backup_v: Vec<DVec3>,
    /// The state after the last step and the energy there, to reuse the forces and
    /// energies when nobody changed it.
    end_x: Vec<DVec3>,
    end_v: Vec<DVec3>,
    end_energy: Option<crate::model::Energies>,
    /// `1/m`, 0 for fixed particles (whose velocity is 0), so the update has no branch.
    inv_mass: Vec<f64>,
}

impl VelocityVerlet {
    /// `substeps` substeps per step (at least 1).
    pub fn new(system: &SpringSystem, substeps: usize) -> Result<Self, crate::model::ModelError> {
        if substeps == 0 {
            return Err(crate::model::ModelError::BadParameter {
                name: "substeps",
                reason: "must be at least 1",
            });
        }
        Ok(Self {
            substeps,
            forces: vec![DVec3::ZERO; system.len()],
            backup_x: system.positions().to_vec(),
            backup_v: system.velocities().to_vec(),
            end_x: Vec::new(),
            end_v: Vec::new(),
            end_energy: None,
            inv_mass: inverse_masses(system),
        })
    }

    /// The substep count.
    #[must_use]
    pub fn substeps(&self) -> usize {
        self.substeps
    }

    /// Sets the substep count (at least 1; 0 is taken as 1).
    pub fn set_substeps(&mut self, substeps: usize) {
        self.substeps = substeps.max(1);
    }

    /// Advances `system` by `h`. A non-finite value undoes the step and is an error.
    pub fn step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        check_time_step(h)?;
        if self.forces.len() != system.len() {
            return Err(crate::model::ModelError::TopologyMismatch.into());
        }
        let mut report = StepReport::new(IntegratorKind::VelocityVerlet);
        report.substeps = self.substeps;
        let unchanged = self.end_energy.is_some()
            && self.end_x == system.positions()
            && self.end_v == system.velocities();
        report.energy_before = match (unchanged, self.end_energy) {
            (true, Some(e)) => e,
            _ => system.energies(),
        };
        self.backup_x.copy_from_slice(system.positions());
        self.backup_v.copy_from_slice(system.velocities());
        let dt = h / self.substeps as f64;
        let parts = system.parts_mut();
        let (x, v) = (parts.positions, parts.velocities);
        let (masses, springs) = (parts.masses, parts.springs);
        let gravity = parts.material.gravity;
        let damping = parts.material.damping;
        if !unchanged {
            forces(x, v, masses, springs, gravity, damping, &mut self.forces);
        }
        let half = 0.5 * dt;
        let inv_mass = &self.inv_mass;
        for _ in 0..self.substeps {
            for (((xi, vi), f), w) in x
                .iter_mut()
                .zip(v.iter_mut())
                .zip(&self.forces)
                .zip(inv_mass)
            {
                *vi += (half * w) * *f;
                *xi += dt * *vi;
            }
            forces(x, v, masses, springs, gravity, damping, &mut self.forces);
            for ((vi, f), w) in v.iter_mut().zip(&self.forces).zip(inv_mass) {
                *vi += (half * w) * *f;
            }
        }
        if let Some(particle) = (0..x.len()).find(|&i| !(x[i].is_finite() && v[i].is_finite())) {
            x.copy_from_slice(&self.backup_x);
            v.copy_from_slice(&self.backup_v);
            self.end_energy = None;
            return Err(StepError::NonFinite {
                integrator: IntegratorKind::VelocityVerlet,
                particle,
            });
        }
        report.iterations = self.substeps;
        report.energy_after = system.energies();
        self.end_x.clear();
        self.end_x.extend_from_slice(system.positions());
        self.end_v.clear();
        self.end_v.extend_from_slice(system.velocities());
        self.end_energy = Some(report.energy_after);
        Ok(report)
    }
}
