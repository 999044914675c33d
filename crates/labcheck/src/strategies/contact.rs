//! Random contact cases for backward Euler with IPC contact: a small sheet above one to
//! three colliders (the ground, a sphere, a capsule; static or moving), thrown at them
//! with random velocities, stiffness up to 1e6 and steps up to 1/4 s.
//!
//! Every collider is placed entirely below the sheet's plane, at a random gap from it, so
//! the start is admissible (every particle outside every collider) by construction; a
//! collider's motion (rising, sliding, turning) may then carry it into the sheet, which
//! is what the property is about. During the run a collider may be driven: given a new
//! motion from the start of a step on.

use super::{SplitMix64, direction, log_uniform};
use proptest::prelude::*;
use sinew_math::DVec3;
use sinew_spring_sim::contact::{Collider, ContactSettings, Shape};
use sinew_spring_sim::{ClothGrid, Integrator, Material, NewtonSettings, SpringSystem};

/// Gravity along -y, SI units.
pub const GRAVITY: f64 = 9.81;
/// Areal density of the sheets, kg/m^2, lumped per particle.
pub const AREAL_DENSITY: f64 = 0.2;

/// Which shape a collider has.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ColliderKind {
    /// The half-space below a horizontal plane.
    Ground,
    /// A ball.
    Sphere,
    /// A capsule with a random axis.
    Capsule,
}

/// One collider, described by how it sits under the sheet.
#[derive(Clone, Debug, PartialEq)]
pub struct ColliderSpec {
    /// The shape.
    pub kind: ColliderKind,
    /// Gap between the collider's top and the sheet's plane at the start (> 0).
    pub gap: f64,
    /// Horizontal offset of the collider's centre from the sheet's centre, as a fraction
    /// of the sheet's width (in `[-1, 1]^2`).
    pub offset: (f64, f64),
    /// Radius as a fraction of the sheet's width (sphere and capsule).
    pub radius: f64,
    /// The capsule's axis direction and half-length as a fraction of the sheet's width.
    pub axis: DVec3,
    /// The capsule's half-length, fraction of the sheet's width.
    pub half_length: f64,
    /// Linear velocity, m/s (zero for a static collider).
    pub linear_velocity: DVec3,
    /// Angular velocity, rad/s, about the collider's reference point.
    pub angular_velocity: DVec3,
}

/// A whole contact case.
#[derive(Clone, Debug, PartialEq)]
pub struct ContactCase {
    /// Particles per side of the square sheet.
    pub side: usize,
    /// Grid spacing, m.
    pub spacing: f64,
    /// Stiffness of every spring, N/m.
    pub stiffness: f64,
    /// Damping coefficient.
    pub damping: f64,
    /// The time step, s.
    pub h: f64,
    /// Steps to take.
    pub steps: usize,
    /// Common initial velocity of the sheet, m/s.
    pub velocity: DVec3,
    /// Amplitude of a per-particle random velocity added to it, m/s.
    pub jitter: f64,
    /// Seed of the per-particle velocities.
    pub seed: u64,
    /// Friction coefficient.
    pub mu: f64,
    /// The colliders.
    pub colliders: Vec<ColliderSpec>,
    /// Colliders given a new motion during the run, from the start of a step on (the
    /// pose kept, the velocities changed: `Simulation::drive_collider`).
    pub drives: Vec<DriveSpec>,
}

/// A collider driven before a step: from then on it moves with a new motion.
#[derive(Clone, Debug, PartialEq)]
pub struct DriveSpec {
    /// The step it is driven before (none when past the case's last step).
    pub step: usize,
    /// The collider, modulo the number of colliders.
    pub collider: usize,
    /// The new linear velocity, m/s.
    pub linear_velocity: DVec3,
    /// The new angular velocity, rad/s, about the collider's reference point.
    pub angular_velocity: DVec3,
}

/// The sheet's plane, y = this.
pub const SHEET_HEIGHT: f64 = 0.5;

impl ContactCase {
    /// The case's implicit integrator with `settings`: backward Euler for an even
    /// `seed`, BDF2 for an odd one (taken from the seed, so the strategy draws what it
    /// drew before the scheme was varied; a shrunk seed of 0 is backward Euler). The
    /// implicit midpoint is not drawn: docs/labcheck.md says why.
    #[must_use]
    pub fn integrator(&self, settings: NewtonSettings) -> Integrator {
        if self.seed.is_multiple_of(2) {
            Integrator::BackwardEuler(settings)
        } else {
            Integrator::Bdf2(settings)
        }
    }

    /// The sheet's width.
    #[must_use]
    pub fn width(&self) -> f64 {
        self.spacing * (self.side - 1) as f64
    }

    /// The sheet, centred over the origin at [`SHEET_HEIGHT`], with its initial
    /// velocities.
    #[must_use]
    pub fn build_system(&self) -> SpringSystem {
        let w = self.width();
        let grid = ClothGrid {
            size: self.side,
            spacing: self.spacing,
            origin: DVec3::new(-0.5 * w, SHEET_HEIGHT, -0.5 * w),
            mass: AREAL_DENSITY * self.spacing * self.spacing,
            material: Material {
                stiffness: self.stiffness,
                damping: self.damping,
                gravity: DVec3::new(0.0, -GRAVITY, 0.0),
            },
            fixed: Vec::new(),
        };
        let mut system = SpringSystem::cloth(&grid).expect("the generated sheet is valid");
        let mut rng = SplitMix64(self.seed);
        let velocities: Vec<DVec3> = (0..system.len())
            .map(|_| self.velocity + self.jitter * rng.vector())
            .collect();
        let positions = system.positions().to_vec();
        system
            .set_state(&positions, &velocities)
            .expect("sizes match");
        system
    }

    /// The colliders, in their poses at time 0.
    #[must_use]
    pub fn build_colliders(&self) -> Vec<Collider> {
        let w = self.width();
        self.colliders
            .iter()
            .map(|c| {
                let centre_xz = DVec3::new(c.offset.0 * w, 0.0, c.offset.1 * w);
                let top = SHEET_HEIGHT - c.gap;
                let r = c.radius * w;
                let shape = match c.kind {
                    ColliderKind::Ground => Shape::HalfSpace {
                        point: DVec3::new(0.0, top, 0.0),
                        normal: DVec3::Y,
                    },
                    ColliderKind::Sphere => Shape::Sphere {
                        center: centre_xz + DVec3::new(0.0, top - r, 0.0),
                        radius: r,
                    },
                    ColliderKind::Capsule => {
                        let half = c.half_length * w * c.axis;
                        // The highest point of the capsule is the higher end's top.
                        let centre = centre_xz + DVec3::new(0.0, top - r - half.y.abs(), 0.0);
                        Shape::Capsule {
                            a: centre - half,
                            b: centre + half,
                            radius: r,
                        }
                    }
                };
                Collider::fixed(shape).moving(c.linear_velocity, c.angular_velocity)
            })
            .collect()
    }

    /// Contact settings: dhat 1e-3 (the contact scenes' value), the case's friction.
    #[must_use]
    pub fn settings(&self) -> ContactSettings {
        ContactSettings {
            dhat: 1e-3,
            mu: self.mu,
            ..ContactSettings::default()
        }
    }
}

/// A collider's motion: static half the time; otherwise a velocity up to 2 m/s (biased
/// upwards, into the sheet) and a turn up to pi rad/s.
fn motion() -> impl Strategy<Value = (DVec3, DVec3)> {
    prop_oneof![
        Just((DVec3::ZERO, DVec3::ZERO)),
        (
            direction(),
            0.0f64..=2.0,
            direction(),
            0.0f64..=std::f64::consts::PI
        )
            .prop_map(|(d, speed, axis, rate)| {
                let d = DVec3::new(d.x, d.y.abs(), d.z);
                (speed * d, rate * axis)
            }),
    ]
}

/// One collider under the sheet.
pub fn collider_spec() -> impl Strategy<Value = ColliderSpec> {
    (
        prop::sample::select(vec![
            ColliderKind::Ground,
            ColliderKind::Sphere,
            ColliderKind::Capsule,
        ]),
        log_uniform(-4.0, -0.5),
        (-0.6f64..=0.6, -0.6f64..=0.6),
        0.05f64..=0.6,
        direction(),
        0.0f64..=0.6,
        motion(),
    )
        .prop_map(
            |(kind, gap, offset, radius, axis, half_length, (v, w))| ColliderSpec {
                kind,
                gap,
                offset,
                radius,
                axis,
                half_length,
                linear_velocity: v,
                angular_velocity: w,
            },
        )
}

/// A drive: before one of the first six steps, one collider takes a new motion (at rest
/// half the time, as [`collider_spec`]'s).
pub fn drive_spec() -> impl Strategy<Value = DriveSpec> {
    (0usize..6, 0usize..3, motion()).prop_map(|(step, collider, (v, w))| DriveSpec {
        step,
        collider,
        linear_velocity: v,
        angular_velocity: w,
    })
}

/// A whole case: sheets of 2 x 2 to 6 x 6 particles, spacing 2 cm to 20 cm, stiffness
/// 10 to 1e6 N/m, steps 1/600 s to 1/4 s, one to six steps, a downward throw up to 5 m/s
/// with per-particle jitter up to 2 m/s, friction 0 to 0.5, one to three colliders, and
/// none to three drives that change a collider's motion during the run.
pub fn contact_case() -> impl Strategy<Value = ContactCase> {
    (
        2usize..=6,
        0.02f64..=0.2,
        log_uniform(1.0, 6.0),
        prop_oneof![Just(0.0), 0.0f64..=1.0],
        log_uniform((1.0f64 / 600.0).log10(), 0.25f64.log10()),
        1usize..=6,
        (direction(), 0.0f64..=5.0),
        (0.0f64..=2.0, any::<u64>()),
        prop_oneof![Just(0.0), 0.0f64..=0.5],
        (
            prop::collection::vec(collider_spec(), 1..=3),
            prop::collection::vec(drive_spec(), 0..=3),
        ),
    )
        .prop_map(
            |(
                side,
                spacing,
                stiffness,
                damping,
                h,
                steps,
                (dir, speed),
                (jitter, seed),
                mu,
                (colliders, drives),
            )| {
                // Thrown downwards (towards the colliders) or sideways, never away.
                let velocity = speed * DVec3::new(dir.x, -dir.y.abs(), dir.z);
                ContactCase {
                    side,
                    spacing,
                    stiffness,
                    damping,
                    h,
                    steps,
                    velocity,
                    jitter,
                    seed,
                    mu,
                    colliders,
                    drives,
                }
            },
        )
}
