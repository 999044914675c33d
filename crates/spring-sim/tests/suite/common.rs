//! Set-ups shared by several test modules.

use sinew_spring_sim::contact::{Collider, ContactSettings, Shape};
use sinew_spring_sim::{
    ClothGrid, DVec3, Integrator, Material, MeshClothModel, NewtonSettings, Particle,
    PinnedStepper, Simulation, SpringSystem, StepReport,
};

/// The threads a solver asked for `threads` runs on: those, or the calling thread alone
/// when the crate is built without its `parallel` feature (the thread-count tests then
/// still compare the runs, which must agree all the more).
pub fn expected_threads(threads: usize) -> usize {
    if cfg!(feature = "parallel") {
        threads
    } else {
        1
    }
}

/// Gravity's size in the contact tests.
pub const G: f64 = 9.81;

/// The contact tests' springs: stiffness 1000, damping 0.1, gravity `G` along -y.
pub fn contact_material() -> Material {
    Material {
        stiffness: 1000.0,
        damping: 0.1,
        gravity: DVec3::new(0.0, -G, 0.0),
    }
}

/// An `n x n` sheet with the lab's spring pattern (structural, shear and skip-one) in the
/// plane through `origin` spanned by `u` and `w`, areal density 0.2 lumped, at rest.
pub fn contact_sheet(n: usize, spacing: f64, origin: DVec3, u: DVec3, w: DVec3) -> SpringSystem {
    let mass = 0.2 * spacing * spacing;
    let mut particles = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let p = origin + spacing * (i as f64 * u + j as f64 * w);
            particles.push(Particle::at_rest(p, mass));
        }
    }
    SpringSystem::new(
        &particles,
        &ClothGrid::spring_pattern(n),
        contact_material(),
    )
    .unwrap()
}

/// A 4 x 4 sheet resting on a plane inclined by `theta` (about z) with friction `mu`, run
/// by `integrator` for `steps` steps of `h`, every step converged and every particle
/// outside the plane; the mean velocity along the downhill direction after each step.
pub fn incline_run(integrator: Integrator, theta: f64, mu: f64, steps: usize, h: f64) -> Vec<f64> {
    let normal = DVec3::new(theta.sin(), theta.cos(), 0.0);
    let downhill = DVec3::new(theta.cos(), -theta.sin(), 0.0);
    let settings = ContactSettings {
        mu,
        ..ContactSettings::default()
    };
    let system = contact_sheet(4, 0.05, 0.5 * settings.dhat * normal, downhill, DVec3::Z);
    let mut sim = Simulation::new(system, integrator).unwrap();
    let plane = Collider::fixed(Shape::HalfSpace {
        point: DVec3::ZERO,
        normal,
    });
    sim.set_contact(vec![plane], settings).unwrap();
    let mut speeds = Vec::new();
    for step in 0..steps {
        let report = sim.step(h).unwrap();
        assert!(
            report.residual <= report.tolerance,
            "step {step}: {report:?}"
        );
        let (min, _) = sim.contact_distances().unwrap();
        assert!(min > 0.0, "step {step}: a particle at distance {min}");
        let v = sim.system().velocities();
        speeds.push(v.iter().map(|v| v.dot(downhill)).sum::<f64>() / v.len() as f64);
    }
    speeds
}

/// The signed distance from `x` to `collider` at time `t`, computed here from the
/// collider's fields, independently of the library's distance functions.
pub fn independent_distance(collider: &Collider, t: f64, x: DVec3) -> f64 {
    match collider.at(t) {
        Shape::HalfSpace { point, normal } => (x - point).dot(normal),
        Shape::Sphere { center, radius } => (x - center).length() - radius,
        Shape::Capsule { a, b, radius } => {
            // The closest point on the segment: the projection onto its line, clamped
            // to the segment (a point for a = b).
            let ab = b - a;
            let len2 = ab.length_squared();
            let s = if len2 > 0.0 {
                ((x - a).dot(ab) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (x - (a + s * ab)).length() - radius
        }
    }
}

/// Checks every particle of `positions` strictly outside every collider at time `t`
/// (by [`independent_distance`]), naming `when` in a failure; the smallest distance to
/// each collider.
pub fn outside_colliders(
    colliders: &[Collider],
    t: f64,
    positions: &[DVec3],
    when: &str,
) -> Vec<f64> {
    colliders
        .iter()
        .enumerate()
        .map(|(c, collider)| {
            let mut nearest = f64::INFINITY;
            for (i, x) in positions.iter().enumerate() {
                let d = independent_distance(collider, t, *x);
                assert!(
                    d > 0.0,
                    "{when}: particle {i} inside collider {c} (d = {d})"
                );
                nearest = nearest.min(d);
            }
            nearest
        })
        .collect()
}

/// Puts every particle of `system` at `factor` times its offset from the particles'
/// mean position (2 stretches the sheet, 0.5 compresses it), at rest.
pub fn scale_about_centre(system: &mut SpringSystem, factor: f64) {
    let rest = system.positions();
    let centre = rest.iter().copied().sum::<DVec3>() / rest.len() as f64;
    let x: Vec<DVec3> = rest
        .iter()
        .map(|&p| centre + factor * (p - centre))
        .collect();
    let v = vec![DVec3::ZERO; x.len()];
    system.set_state(&x, &v).unwrap();
}

/// Uniform samples from a deterministic generator, so random cases are reproducible.
pub trait Sample {
    /// A sample in [0, 1).
    fn next(&mut self) -> f64;

    /// A sample in [-1, 1).
    fn signed(&mut self) -> f64 {
        2.0 * self.next() - 1.0
    }

    /// A vector with each coordinate in [-scale, scale).
    fn vec(&mut self, scale: f64) -> DVec3 {
        scale * DVec3::new(self.signed(), self.signed(), self.signed())
    }
}

/// Marsaglia's xorshift with shifts (13, 7, 17), its top 53 bits as the sample.
pub struct Xorshift(pub u64);

impl Sample for Xorshift {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Vigna's xorshift* with shifts (12, 25, 27), the product's top 53 bits as the sample.
pub struct XorshiftStar(pub u64);

impl Sample for XorshiftStar {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The static force `-grad (E_spring + E_gravity)` on every free particle, largest
/// component (computed here from the springs, independently of the stepper).
pub fn static_force(system: &SpringSystem) -> f64 {
    let x = system.positions();
    let mut f: Vec<DVec3> = system
        .masses()
        .iter()
        .map(|m| *m * system.material().gravity)
        .collect();
    for s in system.springs() {
        let d = x[s.a] - x[s.b];
        let l = d.length();
        let pull = s.stiffness * (l - s.rest_length) / l * d;
        f[s.a] -= pull;
        f[s.b] += pull;
    }
    f.iter()
        .zip(system.fixed())
        .filter(|(_, fixed)| !**fixed)
        .map(|(f, _)| f.abs().max_element())
        .fold(0.0, f64::max)
}

/// Checks a body that lands within one step of `h` moving at (1, -1, 0) m/s with
/// friction `mu`, given the reports and velocities (`v`: a particle's, or a sheet's
/// momentum over its mass) after that step with friction lagged once (`once`) and again
/// (`again`). Lagged at the step's start only, nothing is in contact there: the step
/// has no friction and the tangential velocity stays 1 (to `kept`). Lagged again at the
/// minimizer, friction acts with the normal forces the step ends with, whose impulse
/// per mass is `v'_y - v_y + g h` (backward Euler's normal balance; a sheet's springs'
/// forces cancel in it), and the body slides throughout, so Coulomb's law takes `mu`
/// times that impulse from the tangential velocity (to 1e-6, the rounds' tolerance).
pub fn assert_coulomb_landing(
    mu: f64,
    h: f64,
    once: (&StepReport, DVec3),
    again: (&StepReport, DVec3),
    kept: f64,
) {
    assert_eq!(once.0.friction_relags, 0);
    assert!((once.1.x - 1.0).abs() <= kept, "{}", once.1);
    let (report, v) = again;
    assert!(report.friction_relags >= 1, "{report:?}");
    let impulse = v.y - (-1.0) + G * h;
    let expected = 1.0 - mu * impulse;
    println!("landing: v {v}, normal impulse per mass {impulse}, v_x expected {expected}");
    assert!(impulse > 0.3, "{impulse}");
    assert!((v.x - expected).abs() <= 1e-6, "{} vs {expected}", v.x);
}

/// The implicit schemes a mesh cloth's terms (contact, self-contact, bending) act in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Scheme {
    BackwardEuler,
    Bdf2,
    Midpoint,
}

/// Every [`Scheme`].
pub const SCHEMES: [Scheme; 3] = [Scheme::BackwardEuler, Scheme::Bdf2, Scheme::Midpoint];

impl Scheme {
    /// The scheme with `newton` as an integrator.
    pub fn integrator_with(self, newton: NewtonSettings) -> Integrator {
        match self {
            Self::BackwardEuler => Integrator::BackwardEuler(newton),
            Self::Bdf2 => Integrator::Bdf2(newton),
            Self::Midpoint => Integrator::ImplicitMidpoint(newton),
        }
    }

    /// The scheme with the default Newton settings.
    pub fn integrator(self) -> Integrator {
        self.integrator_with(NewtonSettings::default())
    }

    /// The scheme's integrator for `model` (with its bending term).
    pub fn build(self, model: &MeshClothModel, newton: NewtonSettings) -> Box<dyn PinnedStepper> {
        model
            .implicit_stepper(self.integrator_with(newton))
            .unwrap()
    }
}
