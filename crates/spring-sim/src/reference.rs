//! Reference methods kept for comparison only. Do not use them to simulate.
//!
//! [`flawed_report_method`] reproduces the lab report's Newton variant with its mistakes
//! (SEED-NOTES.md items 1-4), so benchmarks can show what they cost.

/// **Flawed, for comparison only**: the lab report's "Newton" method.
///
/// What it does, and what is wrong with it (see docs/spring-sim.md):
/// - `y = x_n + h v_n + h^2 M^-1 f_ext` (gravity folded into the prediction, which is
///   fine);
/// - the spring block is taken as `k [(1 - L/l) I + u u^T]`, wrong by `k (1 - L/l) u u^T`
///   (exact only at rest length), indefinite for compressed springs with no projection;
/// - the coupling blocks between the two ends are left out, so the "Hessian" is block
///   diagonal and each particle is solved on its own (a block-Jacobi sweep, not Newton);
/// - exactly 32 iterations, no convergence test, no line search, so `g` may increase.
///
/// The report also writes the update with `+grad g`; that sign would make every step
/// ascend `g` and explode at once, so the descent sign is used here to keep the
/// comparison about the Hessian and the loop. The damping force (frozen direction, as in
/// the correct solver) enters the gradient but not the "Hessian".
pub mod flawed_report_method {
    use crate::model::{SpringSystem, check_time_step};
    use crate::report::{IntegratorKind, StepError, StepReport};
    use crate::spring;
    use sinew_math::{DMat3, DVec3};

    /// The report's fixed iteration count.
    pub const ITERATIONS: usize = 32;

    /// The report's (wrong) spring block `k [(1 - L/l) I + u u^T]`.
    #[must_use]
    pub fn report_block(x_a: DVec3, x_b: DVec3, rest_length: f64, stiffness: f64) -> DMat3 {
        match sinew_math::try_unit(x_a - x_b) {
            Some(u) => {
                let l = u.dot(x_a - x_b);
                (DMat3::IDENTITY * (1.0 - rest_length / l) + spring::outer(u)) * stiffness
            }
            None => DMat3::ZERO,
        }
    }

    /// The flawed stepper with its buffers.
    #[derive(Clone, Debug)]
    pub struct FlawedReportMethod {
        x: Vec<DVec3>,
        y: Vec<DVec3>,
        x_ref: Vec<DVec3>,
        grad: Vec<DVec3>,
        blocks: Vec<DMat3>,
        directions: Vec<DVec3>,
        /// The fingerprint of the system the buffers were sized for.
        topology: crate::model::Topology,
    }

    impl FlawedReportMethod {
        /// Buffers for `system`.
        #[must_use]
        pub fn new(system: &SpringSystem) -> Self {
            let n = system.len();
            Self {
                x: vec![DVec3::ZERO; n],
                y: vec![DVec3::ZERO; n],
                x_ref: vec![DVec3::ZERO; n],
                grad: vec![DVec3::ZERO; n],
                blocks: vec![DMat3::ZERO; n],
                directions: vec![DVec3::ZERO; system.springs().len()],
                topology: system.topology(),
            }
        }

        /// One step of length `h`: 32 block-diagonal "Newton" sweeps with the report's
        /// block. Errors (and undoes the step) when a value becomes non-finite.
        pub fn step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
            check_time_step(h)?;
            self.topology.check(&system.topology())?;
            let mut report = StepReport::new(IntegratorKind::FlawedReportMethod);
            report.energy_before = system.energies();
            let gravity = system.material().gravity;
            let damping = system.material().damping / h;
            let inv_h2 = 1.0 / (h * h);
            for i in 0..system.len() {
                let (x, v) = (system.positions()[i], system.velocities()[i]);
                self.x_ref[i] = x;
                self.y[i] = if system.fixed()[i] {
                    x
                } else {
                    x + h * v + h * h * gravity
                };
                self.x[i] = self.y[i];
            }
            for (d, s) in self.directions.iter_mut().zip(system.springs()) {
                *d = spring::damping_direction(self.x_ref[s.a], self.x_ref[s.b]);
            }
            for _ in 0..ITERATIONS {
                for i in 0..system.len() {
                    let m = system.masses()[i] * inv_h2;
                    self.grad[i] = m * (self.x[i] - self.y[i]);
                    self.blocks[i] = DMat3::IDENTITY * m;
                }
                for (s, sp) in system.springs().iter().enumerate() {
                    let (xa, xb) = (self.x[sp.a], self.x[sp.b]);
                    let u = self.directions[s];
                    let stretch = (xa - xb) - (self.x_ref[sp.a] - self.x_ref[sp.b]);
                    let force = spring::gradient(xa, xb, sp.rest_length, sp.stiffness)
                        + damping * u.dot(stretch) * u;
                    let block = report_block(xa, xb, sp.rest_length, sp.stiffness);
                    self.grad[sp.a] += force;
                    self.grad[sp.b] -= force;
                    // The report adds its block to both diagonal blocks and drops the
                    // coupling blocks.
                    self.blocks[sp.a] += block;
                    self.blocks[sp.b] += block;
                }
                for i in 0..system.len() {
                    if system.fixed()[i] {
                        continue;
                    }
                    let block = self.blocks[i];
                    let det = block.determinant();
                    if det.is_finite() && det != 0.0 {
                        self.x[i] -= block.inverse().mul_vec3(self.grad[i]);
                    }
                }
            }
            report.iterations = ITERATIONS;
            report.effective_step = h;
            report.residual = self
                .grad
                .iter()
                .zip(system.fixed())
                .filter(|(_, f)| !**f)
                .fold(0.0f64, |m, (g, _)| m.max(g.abs().max_element()));
            if let Some(particle) = self.x.iter().position(|x| !x.is_finite()) {
                return Err(StepError::NonFinite {
                    integrator: IntegratorKind::FlawedReportMethod,
                    particle,
                });
            }
            let (positions, velocities) = system.state_mut();
            for i in 0..positions.len() {
                velocities[i] = (self.x[i] - self.x_ref[i]) / h;
                positions[i] = self.x[i];
            }
            report.energy_after = system.energies();
            Ok(report)
        }
    }
}
