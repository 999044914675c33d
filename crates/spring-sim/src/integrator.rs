//! The stepping front: one [`Integrator`] choice, one [`Simulation`] that owns the system
//! and the chosen integrator's workspace, one [`StepReport`] per step.
//!
//! New integrators (BDF2, implicit midpoint, velocity Verlet, an automatic choice) are new
//! variants of [`Integrator`] and [`crate::IntegratorKind`]; the implicit ones reuse the Newton
//! minimization of [`crate::newton`] with another effective step and prediction.

use crate::explicit::SymplecticEuler;
use crate::model::{ModelError, SpringSystem};
use crate::newton::{BackwardEuler, NewtonSettings};
use crate::reference::flawed_report_method::FlawedReportMethod;
use crate::report::{StepError, StepReport};

/// Which integrator advances the system, with its settings.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum Integrator {
    /// Backward Euler solved by Newton (the default).
    BackwardEuler(NewtonSettings),
    /// Explicit symplectic Euler with a fixed number of substeps per step.
    SymplecticEuler {
        /// Substeps per step.
        substeps: usize,
    },
    /// The lab report's flawed method, for comparison only
    /// ([`crate::reference::flawed_report_method`]).
    FlawedReportMethod,
}

impl Default for Integrator {
    fn default() -> Self {
        Self::BackwardEuler(NewtonSettings::default())
    }
}

#[derive(Debug)]
enum Stepper {
    BackwardEuler(Box<BackwardEuler>),
    SymplecticEuler(SymplecticEuler),
    Flawed(FlawedReportMethod),
}

/// A system and the integrator that advances it.
#[derive(Debug)]
pub struct Simulation {
    system: SpringSystem,
    stepper: Stepper,
}

impl Simulation {
    /// Builds the integrator's workspace for `system`.
    pub fn new(system: SpringSystem, integrator: Integrator) -> Result<Self, ModelError> {
        let stepper = match integrator {
            Integrator::BackwardEuler(settings) => {
                Stepper::BackwardEuler(Box::new(BackwardEuler::new(&system, settings)?))
            }
            Integrator::SymplecticEuler { substeps } => {
                Stepper::SymplecticEuler(SymplecticEuler::new(&system, substeps)?)
            }
            Integrator::FlawedReportMethod => Stepper::Flawed(FlawedReportMethod::new(&system)),
        };
        Ok(Self { system, stepper })
    }

    /// Advances by `dt`. On error the system is unchanged.
    pub fn step(&mut self, dt: f64) -> Result<StepReport, StepError> {
        match &mut self.stepper {
            Stepper::BackwardEuler(be) => be.step(&mut self.system, dt),
            Stepper::SymplecticEuler(se) => se.step(&mut self.system, dt),
            Stepper::Flawed(fl) => fl.step(&mut self.system, dt),
        }
    }

    /// The system.
    #[must_use]
    pub fn system(&self) -> &SpringSystem {
        &self.system
    }

    /// The system, for state or material changes that keep the topology.
    pub fn system_mut(&mut self) -> &mut SpringSystem {
        if let Stepper::BackwardEuler(be) = &mut self.stepper {
            be.reset_history();
        }
        &mut self.system
    }

    /// The backward Euler workspace, when that is the integrator.
    #[must_use]
    pub fn backward_euler(&self) -> Option<&BackwardEuler> {
        match &self.stepper {
            Stepper::BackwardEuler(be) => Some(be),
            _ => None,
        }
    }

    /// Gives the system back.
    #[must_use]
    pub fn into_system(self) -> SpringSystem {
        self.system
    }
}
