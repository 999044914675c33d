//! Explicit symplectic Euler with substeps: the course's starter integrator, kept for
//! comparison (and as the cheap choice where it is stable; see issue 9).
//!
//! Each substep of length `h / substeps` updates velocities from the forces at the
//! current positions (springs, gravity, axial damping along the current spring
//! direction), then positions from the new velocities. Fixed particles do not move. It
//! is only conditionally stable: above its limit it explodes, and then the step is undone
//! and reported as an error rather than returning NaN.

use crate::model::{SpringSystem, check_time_step};
use crate::report::{IntegratorKind, StepError, StepReport};
use crate::spring;
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
            for (f, m) in self.forces.iter_mut().zip(masses) {
                *f = *m * gravity;
            }
            for s in springs {
                let mut force = -spring::gradient(x[s.a], x[s.b], s.rest_length, s.stiffness);
                if damping > 0.0 {
                    let u = spring::damping_direction(x[s.a], x[s.b]);
                    force -= damping * u.dot(v[s.a] - v[s.b]) * u;
                }
                self.forces[s.a] += force;
                self.forces[s.b] -= force;
            }
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
