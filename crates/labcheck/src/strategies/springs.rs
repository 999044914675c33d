//! Mass-spring systems: grids and random graphs, random fixed sets, stiffness, masses,
//! damping, gravity, time steps and initial states.
//!
//! The strategy generates a small [`SpringCase`] (parameters and a seed; it prints
//! readably when a property fails and shrinks field by field) and [`SpringCase::build`]
//! turns it into a [`SpringSystem`] in its initial state.
//!
//! Ranges (the issue's): grids of 2 x 2 to 20 x 20 particles with the lab's springs
//! (structural, skip-one bending, shear) and random connected graphs of 2 to 40
//! particles; fixed sets empty, random (each particle with probability 1/4) or all;
//! stiffness log-uniform in `[1, 1e7]`, each spring's stiffness spread by a further
//! factor up to `10^spread`; masses log-uniform in `[1e-3, 1e3]`, spread likewise;
//! time steps log-uniform in `[1e-4, 1]`; damping 0 or log-uniform in `[1e-3, 1e3]`;
//! gravity 0 or up to 10 in a random direction; initial states at rest (every spring at
//! its rest length), uniformly stretched, uniformly compressed, or randomly perturbed in
//! position and velocity.

use super::{SplitMix64, direction, log_uniform};
use proptest::prelude::*;
use sinew_math::DVec3;
use sinew_spring_sim::{Material, Particle, SpringSpec, SpringSystem};
use std::collections::HashSet;
use std::ops::RangeInclusive;

/// How the particles are connected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Topology {
    /// A `rows x columns` grid with the lab cloth's springs: from `(i, j)` to `(i-1, j)`,
    /// `(i-2, j)`, `(i, j-1)`, `(i, j-2)`, `(i-1, j-1)` and `(i-1, j+1)` where they exist.
    Grid {
        /// Particles along the first axis.
        rows: usize,
        /// Particles along the second axis.
        columns: usize,
    },
    /// `particles` particles at random positions, joined by a random spanning tree (so
    /// the graph is connected) plus up to `extra` random further springs.
    Graph {
        /// Number of particles.
        particles: usize,
        /// Further random springs tried (duplicates are skipped).
        extra: usize,
    },
}

/// Which particles are fixed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FixedSet {
    /// No particle is fixed.
    None,
    /// Each particle is fixed with probability 1/4 (drawn from the case's seed).
    Some,
    /// Every particle is fixed (the solve has no unknowns).
    All,
}

/// The state the system starts in, relative to its rest configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum InitialState {
    /// Every spring at its rest length, no velocity.
    AtRest,
    /// Every position scaled by `1 + f` about the centroid (every spring stretched by
    /// that factor), no velocity.
    Stretched(f64),
    /// Every position scaled by `1 - f` about the centroid, no velocity.
    Compressed(f64),
    /// Each position moved by up to `displacement` times the spacing in each coordinate
    /// and given a velocity of up to `speed` in each coordinate (from the seed).
    Perturbed {
        /// Position perturbation, relative to the spacing.
        displacement: f64,
        /// Velocity amplitude (scene units per second).
        speed: f64,
    },
}

/// One generated mass-spring system and its time step.
#[derive(Clone, Debug, PartialEq)]
pub struct SpringCase {
    /// The connectivity.
    pub topology: Topology,
    /// The grid spacing, and the length scale of random graphs.
    pub spacing: f64,
    /// The base stiffness.
    pub stiffness: f64,
    /// Each spring's stiffness is the base times `10^(spread u)`, `u` uniform in [0, 1).
    pub stiffness_spread: f64,
    /// The base mass.
    pub mass: f64,
    /// Each particle's mass is the base times `10^(spread u)`.
    pub mass_spread: f64,
    /// Axial damping coefficient (>= 0).
    pub damping: f64,
    /// Gravity acceleration.
    pub gravity: DVec3,
    /// Which particles are fixed.
    pub fixed: FixedSet,
    /// The initial state.
    pub state: InitialState,
    /// The time step.
    pub h: f64,
    /// Seed of the bulk random numbers (positions of graphs, spreads, perturbations).
    pub seed: u64,
}

/// A topology: a grid with sides in `sides`, or a random graph with up to 40 particles.
pub fn topology(sides: RangeInclusive<usize>) -> impl Strategy<Value = Topology> + Clone {
    prop_oneof![
        (sides.clone(), sides).prop_map(|(rows, columns)| Topology::Grid { rows, columns }),
        (2usize..=40, 0usize..=80)
            .prop_map(|(particles, extra)| Topology::Graph { particles, extra }),
    ]
}

/// A fixed set: none, some or all, equally likely.
pub fn fixed_set() -> impl Strategy<Value = FixedSet> + Clone {
    prop_oneof![
        Just(FixedSet::None),
        Just(FixedSet::Some),
        Just(FixedSet::All)
    ]
}

/// An initial state: at rest, stretched by 1% to 100%, compressed by 1% to 90%, or
/// perturbed by up to half a spacing and 10 units per second.
pub fn initial_state() -> impl Strategy<Value = InitialState> + Clone {
    prop_oneof![
        Just(InitialState::AtRest),
        (0.01f64..=1.0).prop_map(InitialState::Stretched),
        (0.01f64..=0.9).prop_map(InitialState::Compressed),
        (0.0f64..=0.5, 0.0f64..=10.0).prop_map(|(displacement, speed)| {
            InitialState::Perturbed {
                displacement,
                speed,
            }
        }),
    ]
}

/// Systems over the whole range, with grids of `sides` particles per side.
pub fn spring_case_with(
    sides: RangeInclusive<usize>,
    states: BoxedStrategy<InitialState>,
    fixed: BoxedStrategy<FixedSet>,
) -> impl Strategy<Value = SpringCase> {
    let gravity = prop_oneof![
        Just(DVec3::ZERO),
        (direction(), 0.0f64..=10.0).prop_map(|(d, g)| d * g)
    ];
    let damping = prop_oneof![Just(0.0), log_uniform(-3.0, 3.0)];
    (
        (topology(sides), log_uniform(-2.0, 0.0), fixed, states),
        (
            log_uniform(0.0, 7.0),
            0.0f64..=2.0,
            log_uniform(-3.0, 3.0),
            0.0f64..=2.0,
        ),
        (damping, gravity, log_uniform(-4.0, 0.0), any::<u64>()),
    )
        .prop_map(
            |(
                (topology, spacing, fixed, state),
                (stiffness, stiffness_spread, mass, mass_spread),
                (damping, gravity, h, seed),
            )| SpringCase {
                topology,
                spacing,
                stiffness,
                stiffness_spread,
                mass,
                mass_spread,
                damping,
                gravity,
                fixed,
                state,
                h,
                seed,
            },
        )
}

/// Systems over the whole range of the issue: grids 2 x 2 to 20 x 20, every fixed set,
/// every initial state.
pub fn spring_case() -> impl Strategy<Value = SpringCase> {
    spring_case_with(2..=20, initial_state().boxed(), fixed_set().boxed())
}

impl SpringCase {
    /// The rest positions and the springs (pairs), before any state change.
    #[must_use]
    pub fn rest_configuration(&self) -> (Vec<DVec3>, Vec<[usize; 2]>) {
        let mut rng = SplitMix64(self.seed);
        match self.topology {
            Topology::Grid { rows, columns } => {
                let index = |i: usize, j: usize| i * columns + j;
                let mut positions = Vec::with_capacity(rows * columns);
                for i in 0..rows {
                    for j in 0..columns {
                        positions.push(DVec3::new(
                            self.spacing * i as f64,
                            0.0,
                            self.spacing * j as f64,
                        ));
                    }
                }
                let mut springs = Vec::new();
                for i in 0..rows {
                    for j in 0..columns {
                        let here = index(i, j);
                        if i >= 1 {
                            springs.push([here, index(i - 1, j)]);
                        }
                        if i >= 2 {
                            springs.push([here, index(i - 2, j)]);
                        }
                        if j >= 1 {
                            springs.push([here, index(i, j - 1)]);
                        }
                        if j >= 2 {
                            springs.push([here, index(i, j - 2)]);
                        }
                        if i >= 1 && j >= 1 {
                            springs.push([here, index(i - 1, j - 1)]);
                        }
                        if i >= 1 && j + 1 < columns {
                            springs.push([here, index(i - 1, j + 1)]);
                        }
                    }
                }
                (positions, springs)
            }
            Topology::Graph { particles, extra } => {
                // A cube holding about one particle per spacing^3.
                let side = self.spacing * (particles as f64).cbrt();
                let positions: Vec<DVec3> = (0..particles)
                    .map(|_| rng.vector() * (0.5 * side))
                    .collect();
                let mut seen = HashSet::new();
                let mut springs = Vec::new();
                for i in 1..particles {
                    let j = (rng.next_u64() % i as u64) as usize;
                    seen.insert((j, i));
                    springs.push([i, j]);
                }
                for _ in 0..extra {
                    let a = (rng.next_u64() % particles as u64) as usize;
                    let b = (rng.next_u64() % particles as u64) as usize;
                    if a != b && seen.insert((a.min(b), a.max(b))) {
                        springs.push([a, b]);
                    }
                }
                (positions, springs)
            }
        }
    }

    /// The system in its initial state.
    ///
    /// # Panics
    /// If the spring-sim crate refuses the system (every generated value is valid, so
    /// that would be a bug there).
    #[must_use]
    pub fn build(&self) -> SpringSystem {
        let (rest, pairs) = self.rest_configuration();
        // A second stream, so the rest configuration does not change with the spreads.
        let mut rng = SplitMix64(self.seed ^ 0x5EED_5EED_5EED_5EED);
        let particles: Vec<Particle> = rest
            .iter()
            .map(|&position| {
                let fixed = match self.fixed {
                    FixedSet::None => false,
                    FixedSet::All => true,
                    FixedSet::Some => rng.unit() < 0.25,
                };
                Particle {
                    position,
                    velocity: DVec3::ZERO,
                    mass: self.mass * 10f64.powf(self.mass_spread * rng.unit()),
                    fixed,
                }
            })
            .collect();
        let springs: Vec<SpringSpec> = pairs
            .iter()
            .map(|&[a, b]| SpringSpec {
                particles: [a, b],
                rest_length: None,
                stiffness: Some(self.stiffness * 10f64.powf(self.stiffness_spread * rng.unit())),
            })
            .collect();
        let material = Material {
            stiffness: self.stiffness,
            damping: self.damping,
            gravity: self.gravity,
        };
        let mut system =
            SpringSystem::new(&particles, &springs, material).expect("generated systems are valid");
        let centroid = rest.iter().copied().sum::<DVec3>() / rest.len() as f64;
        let (positions, velocities): (Vec<DVec3>, Vec<DVec3>) = match self.state {
            InitialState::AtRest => (rest.clone(), vec![DVec3::ZERO; rest.len()]),
            InitialState::Stretched(f) => (
                rest.iter()
                    .map(|&x| centroid + (x - centroid) * (1.0 + f))
                    .collect(),
                vec![DVec3::ZERO; rest.len()],
            ),
            InitialState::Compressed(f) => (
                rest.iter()
                    .map(|&x| centroid + (x - centroid) * (1.0 - f))
                    .collect(),
                vec![DVec3::ZERO; rest.len()],
            ),
            InitialState::Perturbed {
                displacement,
                speed,
            } => rest
                .iter()
                .map(|&x| {
                    (
                        x + rng.vector() * (displacement * self.spacing),
                        rng.vector() * speed,
                    )
                })
                .unzip(),
        };
        system
            .set_state(&positions, &velocities)
            .expect("finite state");
        system
    }
}
