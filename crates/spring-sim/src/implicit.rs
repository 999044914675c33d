//! Second-order implicit integrators on the backward Euler minimization machinery:
//! implicit midpoint and BDF2.
//!
//! Both are one minimization of the incremental potential of [`crate::newton`] per step,
//! with another effective step and prediction (derivation in docs/integrators.md):
//! - implicit midpoint solves for the midpoint `z` with `h/2` and `y = x_n + h/2 v_n`,
//!   then `x' = 2z - x_n`, `v' = 2 (z - x_n)/(h/2) - v_n`; symmetric, second order,
//!   no numerical damping (it conserves the energy of linear springs exactly);
//! - BDF2 with `2h/3` and `y = (4x_n - x_{n-1})/3 + 2h/3 (4v_n - v_{n-1})/3`,
//!   `v' = (x' - (4x_n - x_{n-1})/3)/(2h/3)`; second order, damps the stiff modes
//!   (L-stable) but far less than backward Euler. Its first step, and any step after
//!   the step length or the state changed from outside, is a backward Euler step (so
//!   the method stays second order: one step's local error is `O(h^2)`).

use crate::model::{ModelError, SpringSystem};
use crate::newton::{BackwardEuler, NewtonSettings, Scheme};
use crate::report::{StepError, StepReport};
use sinew_math::DVec3;

/// Implicit midpoint by Newton. It adds no numerical damping: for linear springs
/// (a spring that only stretches along its line) it conserves the energy exactly, up to
/// the Newton tolerance.
///
/// ```
/// use sinew_spring_sim::{DVec3, ImplicitMidpoint, Material, NewtonSettings, Particle};
/// use sinew_spring_sim::{SpringSpec, SpringSystem};
/// // A unit mass on a spring stretched 0.2 beyond its rest length 1, no gravity.
/// let particles = [
///     Particle { fixed: true, ..Particle::at_rest(DVec3::ZERO, 1.0) },
///     Particle::at_rest(DVec3::new(0.0, -1.2, 0.0), 1.0),
/// ];
/// let springs = [SpringSpec { rest_length: Some(1.0), ..SpringSpec::between(0, 1) }];
/// let material = Material::lab().undamped().with_gravity(DVec3::ZERO);
/// let mut system = SpringSystem::new(&particles, &springs, material).unwrap();
/// let start = system.energies().total(); // k (0.2)^2 / 2 = 2
/// let mut stepper = ImplicitMidpoint::new(&system, NewtonSettings::default()).unwrap();
/// for _ in 0..100 {
///     stepper.step(&mut system, 0.05).unwrap();
/// }
/// assert!((system.energies().total() - start).abs() < 1e-6 * start);
/// ```
#[derive(Debug)]
pub struct ImplicitMidpoint {
    newton: BackwardEuler,
}

impl ImplicitMidpoint {
    /// A workspace for `system`'s topology.
    pub fn new(system: &SpringSystem, settings: NewtonSettings) -> Result<Self, ModelError> {
        Ok(Self {
            newton: BackwardEuler::new(system, settings)?,
        })
    }

    /// Advances `system` by `h`.
    pub fn step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        self.newton.step_scheme(system, h, Scheme::Midpoint)
    }

    /// Forgets the velocity history of the first guess.
    pub fn reset_history(&mut self) {
        self.newton.reset_history();
    }

    /// The Newton workspace.
    #[must_use]
    pub fn newton(&self) -> &BackwardEuler {
        &self.newton
    }

    /// The Newton workspace, to add terms before stepping (contact, self-contact,
    /// bending: [`crate::MeshClothModel::enable_self_contact`] and the like take it). Its
    /// own `step` would take a backward Euler step: step this integrator instead.
    pub fn newton_mut(&mut self) -> &mut BackwardEuler {
        &mut self.newton
    }
}

/// BDF2 by Newton, with its one step of history. Second order and L-stable: it damps
/// far less than backward Euler at the same step, but still settles a stiff oscillation.
///
/// ```
/// use sinew_spring_sim::{Bdf2, DVec3, Material, NewtonSettings, Particle, SpringSpec, SpringSystem};
/// // A unit mass on a vertical spring (stiffness 100, rest length 1) under Earth's gravity.
/// let particles = [
///     Particle { fixed: true, ..Particle::at_rest(DVec3::ZERO, 1.0) },
///     Particle::at_rest(DVec3::new(0.0, -1.0, 0.0), 1.0),
/// ];
/// let springs = [SpringSpec::between(0, 1)];
/// let material = Material::earth().undamped();
/// let mut system = SpringSystem::new(&particles, &springs, material).unwrap();
/// // At rest the spring carries the weight: stretched by m g / k.
/// let rest_y = -(1.0 + 9.81 / 100.0);
/// let mut stepper = Bdf2::new(&system, NewtonSettings::default()).unwrap();
/// for _ in 0..600 {
///     stepper.step(&mut system, 0.1).unwrap();
/// }
/// assert!((system.positions()[1].y - rest_y).abs() < 1e-6);
/// ```
#[derive(Debug)]
pub struct Bdf2 {
    newton: BackwardEuler,
    prev_x: Vec<DVec3>,
    prev_v: Vec<DVec3>,
    start_x: Vec<DVec3>,
    start_v: Vec<DVec3>,
    /// The step length of the last step, when the history is valid.
    prev_h: Option<f64>,
}

impl Bdf2 {
    /// A workspace for `system`'s topology.
    pub fn new(system: &SpringSystem, settings: NewtonSettings) -> Result<Self, ModelError> {
        Ok(Self {
            newton: BackwardEuler::new(system, settings)?,
            prev_x: system.positions().to_vec(),
            prev_v: system.velocities().to_vec(),
            start_x: system.positions().to_vec(),
            start_v: system.velocities().to_vec(),
            prev_h: None,
        })
    }

    /// Advances `system` by `h`: BDF2 when the last step had the same length, else a
    /// backward Euler step that starts the history (reported as BDF2 either way).
    pub fn step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        // Checked before the history buffers are touched (the Newton step checks again).
        self.newton.check_topology(system)?;
        self.start_x.copy_from_slice(system.positions());
        self.start_v.copy_from_slice(system.velocities());
        let mut report = if self.prev_h == Some(h) {
            self.newton.step_scheme(
                system,
                h,
                Scheme::Bdf2 {
                    prev_x: &self.prev_x,
                    prev_v: &self.prev_v,
                },
            )?
        } else {
            // Backward Euler, not the midpoint: a state not at equilibrium (a cloth
            // released inside the contact distance, a compressed sheet) is damped instead
            // of thrown, which the undamped midpoint does (docs/integrators.md, "BDF2").
            self.newton.step_scheme(system, h, Scheme::BackwardEuler)?
        };
        // The starting step is part of the BDF2 integrator.
        report.integrator = crate::report::IntegratorKind::Bdf2;
        std::mem::swap(&mut self.prev_x, &mut self.start_x);
        std::mem::swap(&mut self.prev_v, &mut self.start_v);
        // A step split in pieces ended with a piece shorter than h: the state
        // before it is not one step of h back, so the history restarts.
        self.prev_h = (report.pieces == 1).then_some(h);
        Ok(report)
    }

    /// Forgets the history (the next step is a backward Euler step); call after changing the
    /// state by hand.
    pub fn reset_history(&mut self) {
        self.prev_h = None;
        self.newton.reset_history();
    }

    /// The Newton workspace.
    #[must_use]
    pub fn newton(&self) -> &BackwardEuler {
        &self.newton
    }

    /// The Newton workspace, to add terms before stepping (contact, self-contact,
    /// bending: [`crate::MeshClothModel::enable_self_contact`] and the like take it). Its
    /// own `step` would take a backward Euler step: step this integrator instead.
    pub fn newton_mut(&mut self) -> &mut BackwardEuler {
        &mut self.newton
    }
}
