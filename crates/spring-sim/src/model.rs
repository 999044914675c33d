//! The mass-spring model: particles, springs, material, their validation, and the
//! builders (the lab cloth of docs/workloads.md W4, a rope, and a user's own particles and
//! springs).
//!
//! Every constructor validates its input and returns a [`ModelError`] that names the
//! offending item (particle index, spring index, field) instead of panicking or letting a
//! NaN reach the integrators. Duplicate springs (the same unordered pair twice) are
//! rejected: they would only be a second spring in parallel, which a user writes as one
//! spring with the summed stiffness, and a duplicate is far more often a builder bug.

use sinew_math::DVec3;
use std::fmt;

/// One particle: its state and mass, and whether it is fixed in place.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct Particle {
    /// Position in scene units.
    pub position: DVec3,
    /// Velocity in scene units per second.
    pub velocity: DVec3,
    /// Mass; must be positive and finite (a fixed particle still needs one, for the
    /// energy report and the stopping rule's scale is taken over free particles only).
    pub mass: f64,
    /// A fixed particle never moves: it is removed from the unknowns of the implicit
    /// solve and skipped by the explicit integrators.
    pub fixed: bool,
}

impl Particle {
    /// A free particle at rest at `position` with mass `mass`.
    #[must_use]
    pub fn at_rest(position: DVec3, mass: f64) -> Self {
        Self {
            position,
            velocity: DVec3::ZERO,
            mass,
            fixed: false,
        }
    }
}

/// A spring as the user describes it: rest length and stiffness may be left to defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct SpringSpec {
    /// The two particle indices.
    pub particles: [usize; 2],
    /// Rest length; `None` means the initial distance between the two particles.
    pub rest_length: Option<f64>,
    /// Stiffness; `None` means [`Material::stiffness`].
    pub stiffness: Option<f64>,
}

impl SpringSpec {
    /// A spring between `a` and `b` with the initial distance as rest length and the
    /// material's stiffness.
    #[must_use]
    pub fn between(a: usize, b: usize) -> Self {
        Self {
            particles: [a, b],
            rest_length: None,
            stiffness: None,
        }
    }
}

/// A resolved spring: energy `k/2 (|x_a - x_b| - L)^2`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Spring {
    /// First particle index.
    pub a: usize,
    /// Second particle index.
    pub b: usize,
    /// Rest length `L >= 0`.
    pub rest_length: f64,
    /// Stiffness `k >= 0`.
    pub stiffness: f64,
}

/// Material constants shared by the whole system.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct Material {
    /// Default spring stiffness, used by springs that do not give their own.
    pub stiffness: f64,
    /// Axial damping coefficient `c >= 0`: each spring exerts `-c (u . (v_a - v_b)) u` on
    /// `a` (and the opposite on `b`), `u` its unit direction.
    pub damping: f64,
    /// Gravity acceleration (the lab: 0.3 along -y).
    pub gravity: DVec3,
}

impl Default for Material {
    /// The lab's material, [`Material::lab`]. It stays the default because scene files
    /// were written for the lab: a scene that gives only some fields of a material gets
    /// the lab's values for the rest. Code should say which it means with a named
    /// constructor.
    fn default() -> Self {
        Self::lab()
    }
}

impl Material {
    /// Gravity at the Earth's surface, 9.81 along -y (units of metres and seconds).
    pub const EARTH_GRAVITY: DVec3 = DVec3::new(0.0, -9.81, 0.0);

    /// The lab's material: stiffness 100, damping 0.2, and the lab's weak gravity 0.3
    /// along -y (in the lab's units, not metres per second squared).
    ///
    /// ```
    /// use sinew_spring_sim::{DVec3, Material};
    /// let lab = Material::lab();
    /// assert_eq!((lab.stiffness, lab.damping), (100.0, 0.2));
    /// assert_eq!(lab.gravity, DVec3::new(0.0, -0.3, 0.0));
    /// // The other constructors change one thing each.
    /// assert_eq!(Material::earth().gravity, Material::EARTH_GRAVITY);
    /// assert_eq!(Material::lab().undamped().damping, 0.0);
    /// assert_eq!(Material::lab().with_gravity(DVec3::ZERO).gravity, DVec3::ZERO);
    /// ```
    #[must_use]
    pub const fn lab() -> Self {
        Self {
            stiffness: 100.0,
            damping: 0.2,
            gravity: DVec3::new(0.0, -0.3, 0.0),
        }
    }

    /// The lab's stiffness and damping under Earth's gravity ([`Material::EARTH_GRAVITY`]).
    #[must_use]
    pub const fn earth() -> Self {
        Self::lab().with_gravity(Self::EARTH_GRAVITY)
    }

    /// The same material with another gravity acceleration.
    #[must_use]
    pub const fn with_gravity(mut self, gravity: DVec3) -> Self {
        self.gravity = gravity;
        self
    }

    /// The same material with another axial damping coefficient (validated when the
    /// system is built: it must be finite and non-negative).
    #[must_use]
    pub const fn with_damping(mut self, damping: f64) -> Self {
        self.damping = damping;
        self
    }

    /// The same material without damping: energy is then conserved by the exact flow,
    /// which makes the integrators' own dissipation measurable.
    #[must_use]
    pub const fn undamped(self) -> Self {
        self.with_damping(0.0)
    }

    /// The same material with another default spring stiffness.
    #[must_use]
    pub const fn with_stiffness(mut self, stiffness: f64) -> Self {
        self.stiffness = stiffness;
        self
    }
}

/// Invalid model or step input, naming the offending item.
#[derive(Clone, Debug, PartialEq)]
pub enum ModelError {
    /// A particle field is NaN or infinite.
    NonFiniteParticle {
        /// Particle index.
        particle: usize,
        /// The field: "position", "velocity" or "mass".
        field: &'static str,
    },
    /// A particle's mass is zero or negative.
    NonPositiveMass {
        /// Particle index.
        particle: usize,
        /// The mass given.
        mass: f64,
    },
    /// A spring refers to a particle that does not exist.
    ParticleOutOfRange {
        /// Spring index.
        spring: usize,
        /// The bad particle index.
        particle: usize,
        /// Number of particles.
        len: usize,
    },
    /// A spring from a particle to itself.
    SelfSpring {
        /// Spring index.
        spring: usize,
        /// The particle.
        particle: usize,
    },
    /// Two springs join the same unordered pair of particles.
    DuplicateSpring {
        /// Spring index of the second occurrence.
        spring: usize,
        /// Index of the first spring with the same pair.
        first: usize,
        /// The pair.
        particles: [usize; 2],
    },
    /// A spring's stiffness is negative or not finite.
    BadStiffness {
        /// Spring index (`None`: the material's default stiffness).
        spring: Option<usize>,
        /// The value given.
        value: f64,
    },
    /// A spring's rest length is negative or not finite.
    BadRestLength {
        /// Spring index.
        spring: usize,
        /// The value given.
        value: f64,
    },
    /// A material field other than the stiffness is invalid (negative damping, NaN).
    BadMaterial {
        /// The field: "damping" or "gravity".
        field: &'static str,
    },
    /// The time step is not positive and finite, or its square is not a normal `f64`
    /// ([`check_time_step`]).
    BadTimeStep {
        /// The value given.
        dt: f64,
    },
    /// An integrator's or solver's setting is invalid ([`SettingsError`] names the
    /// settings and the field; it is also this error's `source`).
    Settings(SettingsError),
    /// A linear solver could not be set up (faer's symbolic factorization or ordering,
    /// or the thread pool failed); [`crate::SolverError`] keeps the cause, reached by
    /// `source`.
    Solver(crate::linear::SolverError),
    /// A builder's or the model's own parameter is invalid (a grid's size or spacing, a
    /// state of the wrong length, a coupled pair out of range).
    BadParameter {
        /// The parameter's name.
        name: &'static str,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A prescribed position or motion of a pinned particle is invalid (the particle
    /// does not exist or is not pinned, the position is not finite, a motion's field is
    /// not finite or its axis is zero, a particle given twice).
    BadPin {
        /// The particle.
        particle: usize,
        /// What is wrong.
        reason: &'static str,
    },
    /// A system given to a stepper built for another topology (see [`Topology`]).
    TopologyMismatch {
        /// What differs: "particle count", "spring count", "fixed set", "spring pairs"
        /// or "masses" (the first of these that does), or "BDF2 history length".
        what: &'static str,
    },
}

impl fmt::Display for ModelError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NonFiniteParticle { particle, field } => {
                write!(f, "particle {particle}: {field} is not finite")
            }
            Self::NonPositiveMass { particle, mass } => {
                write!(f, "particle {particle}: mass {mass} is not positive")
            }
            Self::ParticleOutOfRange {
                spring,
                particle,
                len,
            } => write!(
                f,
                "spring {spring}: particle index {particle} out of range (there are {len} particles)"
            ),
            Self::SelfSpring { spring, particle } => {
                write!(f, "spring {spring}: joins particle {particle} to itself")
            }
            Self::DuplicateSpring {
                spring,
                first,
                particles,
            } => write!(
                f,
                "spring {spring}: duplicates spring {first} (particles {} and {}); duplicate springs are rejected",
                particles[0], particles[1]
            ),
            Self::BadStiffness {
                spring: Some(s),
                value,
            } => write!(f, "spring {s}: stiffness {value} is negative or not finite"),
            Self::BadStiffness {
                spring: None,
                value,
            } => write!(
                f,
                "material: default stiffness {value} is negative or not finite"
            ),
            Self::BadRestLength { spring, value } => write!(
                f,
                "spring {spring}: rest length {value} is negative or not finite"
            ),
            Self::BadMaterial { field } => {
                // A gravity is a vector: it can only fail by not being finite.
                let reason = if *field == "gravity" {
                    "is not finite (a component is NaN or infinite)"
                } else {
                    "is negative or not finite"
                };
                write!(f, "material: {field} {reason}")
            }
            Self::BadTimeStep { dt } if dt.is_finite() && *dt > 0.0 => write!(
                f,
                "time step {dt:e}: its square is not a normal f64 (the implicit integrators \
                 scale by h^2; the step must lie between {MIN_TIME_STEP:e} and \
                 {MAX_TIME_STEP:e} s)"
            ),
            Self::BadTimeStep { dt } => {
                write!(f, "time step {dt} is not positive and finite")
            }
            Self::Settings(e) => write!(f, "{e}"),
            Self::Solver(e) => write!(f, "{e}"),
            Self::BadParameter { name, reason } => write!(f, "parameter {name}: {reason}"),
            Self::BadPin { particle, reason } => {
                write!(f, "pinned particle {particle}: {reason}")
            }
            Self::TopologyMismatch { what } => write!(
                f,
                "topology: the system's {what} differ from those the integrator was built for"
            ),
        }
    }
}

impl std::error::Error for ModelError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Settings(e) => Some(e),
            Self::Solver(e) => Some(e),
            _ => None,
        }
    }
}

impl From<SettingsError> for ModelError {
    fn from(e: SettingsError) -> Self {
        Self::Settings(e)
    }
}

impl From<crate::linear::SolverError> for ModelError {
    fn from(e: crate::linear::SolverError) -> Self {
        Self::Solver(e)
    }
}

/// An invalid setting of an integrator or a solver, naming the settings and the field:
/// `NewtonSettings.tolerance: must be positive and finite`. Settings are checked when the
/// integrator is built, so a step never meets one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SettingsError {
    /// The settings: `NewtonSettings`, `AutoSettings`, `SymplecticEuler` or
    /// `VelocityVerlet` (their substep counts).
    pub settings: &'static str,
    /// The field.
    pub field: &'static str,
    /// What is wrong with its value.
    pub reason: &'static str,
}

impl SettingsError {
    /// The error for `settings.field`.
    #[must_use]
    pub const fn new(settings: &'static str, field: &'static str, reason: &'static str) -> Self {
        Self {
            settings,
            field,
            reason,
        }
    }
}

impl fmt::Display for SettingsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}: {}", self.settings, self.field, self.reason)
    }
}

impl std::error::Error for SettingsError {}

/// The smallest time step [`check_time_step`] accepts: about the square root of the
/// smallest normal `f64`, 1.49e-154 s.
pub const MIN_TIME_STEP: f64 = 1.4916681462400413e-154;
/// The largest time step [`check_time_step`] accepts: about the square root of the
/// largest `f64`, 1.34e154 s.
pub const MAX_TIME_STEP: f64 = 1.3407807929942596e154;

/// Checks a time step: positive, finite, and with a square that is a normal `f64`
/// (between [`MIN_TIME_STEP`] and [`MAX_TIME_STEP`]). The implicit integrators weigh the
/// inertia by `1 / h^2` and the forces by `h^2`: with `h^2` infinite or zero one of the two
/// is lost, and a mesh sheet given `dt = f64::MAX` by the scene fuzzing ended its first
/// step only 24.5 s into its run (set-up included), against 0.34 s for its whole original.
pub fn check_time_step(dt: f64) -> Result<(), ModelError> {
    if dt.is_finite() && (MIN_TIME_STEP..=MAX_TIME_STEP).contains(&dt) {
        Ok(())
    } else {
        Err(ModelError::BadTimeStep { dt })
    }
}

/// A validated mass-spring system: the state the integrators advance.
///
/// The topology (particle count, springs, fixed set) is fixed after construction; only
/// positions and velocities change, so integrators can build their sparsity pattern once.
#[derive(Clone, Debug, PartialEq)]
pub struct SpringSystem {
    positions: Vec<DVec3>,
    velocities: Vec<DVec3>,
    masses: Vec<f64>,
    fixed: Vec<bool>,
    springs: Vec<Spring>,
    material: Material,
    /// Computed once here: the topology cannot change after construction.
    topology: Topology,
    /// A fingerprint of the springs' rest lengths and stiffnesses (FNV-1a over their bits,
    /// in order), computed once here: they cannot change after construction either.
    spring_constants: u64,
}

/// A fingerprint of what a stepper's workspace is built from: the particle and spring
/// counts, the fixed set, the spring pairs (in order) and the masses.
///
/// Each part except the counts is a 64-bit hash (FNV-1a over the exact bits), computed
/// once when the system is built, so a stepper compares a system against the one it was
/// built for in O(1) per step. Two different systems share a part's hash only by a hash
/// collision (about 2^-64 for unrelated inputs). Stiffness, rest lengths, damping and
/// gravity are not part of it: every stepper reads them from the system at each step.
///
/// ```
/// use sinew_spring_sim::{ClothGrid, ModelError, SpringSystem};
/// let grid = ClothGrid::lab();
/// let a = SpringSystem::cloth(&grid).unwrap();
/// assert_eq!(a.topology().check(&a.clone().topology()), Ok(()));
/// let b = SpringSystem::cloth(&grid.with_damping(0.5)).unwrap();
/// assert_eq!(a.topology(), b.topology()); // damping is read at each step
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Topology {
    particles: usize,
    springs: usize,
    fixed: u64,
    pairs: u64,
    masses: u64,
}

/// FNV-1a over 64-bit words, byte by byte: deterministic across runs and platforms
/// (unlike the standard library's randomly keyed hasher).
#[derive(Clone, Copy)]
struct Fnv(u64);

impl Fnv {
    const fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }

    fn word(&mut self, w: u64) {
        for b in w.to_le_bytes() {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

impl Topology {
    /// The fingerprint of `particles` (mass, fixed) and `springs` (pairs) in O(n).
    fn compute(masses: &[f64], fixed: &[bool], springs: &[Spring]) -> Self {
        let (mut f, mut p, mut m) = (Fnv::new(), Fnv::new(), Fnv::new());
        // The indices of the fixed particles, so the hash sees the set, not only its size.
        for (i, _) in fixed.iter().enumerate().filter(|(_, x)| **x) {
            f.word(i as u64);
        }
        for s in springs {
            p.word(s.a as u64);
            p.word(s.b as u64);
        }
        for x in masses {
            m.word(x.to_bits());
        }
        Self {
            particles: masses.len(),
            springs: springs.len(),
            fixed: f.0,
            pairs: p.0,
            masses: m.0,
        }
    }

    /// `Ok` when `other` is the same topology; otherwise the mismatch, naming the first
    /// part that differs (particle count, spring count, fixed set, spring pairs, masses).
    pub fn check(&self, other: &Self) -> Result<(), ModelError> {
        let what = if self.particles != other.particles {
            "particle count"
        } else if self.springs != other.springs {
            "spring count"
        } else if self.fixed != other.fixed {
            "fixed set"
        } else if self.pairs != other.pairs {
            "spring pairs"
        } else if self.masses != other.masses {
            "masses"
        } else {
            return Ok(());
        };
        Err(ModelError::TopologyMismatch { what })
    }

    /// The particle count.
    #[must_use]
    pub fn particles(&self) -> usize {
        self.particles
    }

    /// The spring count.
    #[must_use]
    pub fn springs(&self) -> usize {
        self.springs
    }
}

impl SpringSystem {
    /// Validates and builds a system from the user's particles and springs.
    pub fn new(
        particles: &[Particle],
        springs: &[SpringSpec],
        material: Material,
    ) -> Result<Self, ModelError> {
        if !(material.stiffness.is_finite() && material.stiffness >= 0.0) {
            return Err(ModelError::BadStiffness {
                spring: None,
                value: material.stiffness,
            });
        }
        if !(material.damping.is_finite() && material.damping >= 0.0) {
            return Err(ModelError::BadMaterial { field: "damping" });
        }
        if !material.gravity.is_finite() {
            return Err(ModelError::BadMaterial { field: "gravity" });
        }
        for (i, p) in particles.iter().enumerate() {
            if !p.position.is_finite() {
                return Err(ModelError::NonFiniteParticle {
                    particle: i,
                    field: "position",
                });
            }
            if !p.velocity.is_finite() {
                return Err(ModelError::NonFiniteParticle {
                    particle: i,
                    field: "velocity",
                });
            }
            if !p.mass.is_finite() {
                return Err(ModelError::NonFiniteParticle {
                    particle: i,
                    field: "mass",
                });
            }
            if p.mass <= 0.0 {
                return Err(ModelError::NonPositiveMass {
                    particle: i,
                    mass: p.mass,
                });
            }
        }
        let n = particles.len();
        let mut resolved = Vec::with_capacity(springs.len());
        // First spring seen for each unordered pair, to reject duplicates with a name.
        let mut seen = std::collections::HashMap::with_capacity(springs.len());
        for (s, spec) in springs.iter().enumerate() {
            let [a, b] = spec.particles;
            for p in [a, b] {
                if p >= n {
                    return Err(ModelError::ParticleOutOfRange {
                        spring: s,
                        particle: p,
                        len: n,
                    });
                }
            }
            if a == b {
                return Err(ModelError::SelfSpring {
                    spring: s,
                    particle: a,
                });
            }
            let key = (a.min(b), a.max(b));
            if let Some(&first) = seen.get(&key) {
                return Err(ModelError::DuplicateSpring {
                    spring: s,
                    first,
                    particles: [a, b],
                });
            }
            seen.insert(key, s);
            let stiffness = spec.stiffness.unwrap_or(material.stiffness);
            if !(stiffness.is_finite() && stiffness >= 0.0) {
                return Err(ModelError::BadStiffness {
                    spring: Some(s),
                    value: stiffness,
                });
            }
            let rest_length = spec
                .rest_length
                .unwrap_or_else(|| particles[a].position.distance(particles[b].position));
            if !(rest_length.is_finite() && rest_length >= 0.0) {
                return Err(ModelError::BadRestLength {
                    spring: s,
                    value: rest_length,
                });
            }
            resolved.push(Spring {
                a,
                b,
                rest_length,
                stiffness,
            });
        }
        let masses: Vec<f64> = particles.iter().map(|p| p.mass).collect();
        let fixed: Vec<bool> = particles.iter().map(|p| p.fixed).collect();
        let topology = Topology::compute(&masses, &fixed, &resolved);
        let mut constants = Fnv::new();
        for s in &resolved {
            constants.word(s.rest_length.to_bits());
            constants.word(s.stiffness.to_bits());
        }
        Ok(Self {
            positions: particles.iter().map(|p| p.position).collect(),
            velocities: particles
                .iter()
                .map(|p| if p.fixed { DVec3::ZERO } else { p.velocity })
                .collect(),
            masses,
            fixed,
            springs: resolved,
            material,
            topology,
            spring_constants: constants.0,
        })
    }

    /// The lab cloth (docs/workloads.md W4 and its variants): see [`ClothGrid`].
    pub fn cloth(grid: &ClothGrid) -> Result<Self, ModelError> {
        grid.build()
    }

    /// A rope: see [`Rope`].
    pub fn rope(rope: &Rope) -> Result<Self, ModelError> {
        rope.build()
    }

    /// Number of particles.
    #[must_use]
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Whether there are no particles.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Particle positions.
    #[must_use]
    pub fn positions(&self) -> &[DVec3] {
        &self.positions
    }

    /// Particle velocities (zero for fixed particles).
    #[must_use]
    pub fn velocities(&self) -> &[DVec3] {
        &self.velocities
    }

    /// A fingerprint of the state's exact bits: FNV-1a over every position's and then
    /// every velocity's coordinates, O(n). Two runs that end in the same state, to the
    /// bit, have the same fingerprint, and two states that differ in any bit have
    /// different ones but for a hash collision (about 2^-64): what a regression test or
    /// a replay compares to check that the same inputs gave the same outputs.
    #[must_use]
    pub fn state_fingerprint(&self) -> u64 {
        let mut h = Fnv::new();
        for p in self.positions.iter().chain(&self.velocities) {
            for c in [p.x, p.y, p.z] {
                h.word(c.to_bits());
            }
        }
        h.0
    }

    /// Particle masses.
    #[must_use]
    pub fn masses(&self) -> &[f64] {
        &self.masses
    }

    /// Which particles are fixed.
    #[must_use]
    pub fn fixed(&self) -> &[bool] {
        &self.fixed
    }

    /// The resolved springs.
    #[must_use]
    pub fn springs(&self) -> &[Spring] {
        &self.springs
    }

    /// The material.
    #[must_use]
    pub fn material(&self) -> &Material {
        &self.material
    }

    /// Sets the damping coefficient (a material change, not a topology change).
    pub fn set_damping(&mut self, damping: f64) -> Result<(), ModelError> {
        if !(damping.is_finite() && damping >= 0.0) {
            return Err(ModelError::BadMaterial { field: "damping" });
        }
        self.material.damping = damping;
        Ok(())
    }

    /// Replaces the whole state; lengths must match and every value be finite. Velocities
    /// of fixed particles are stored as zero.
    pub fn set_state(
        &mut self,
        positions: &[DVec3],
        velocities: &[DVec3],
    ) -> Result<(), ModelError> {
        if positions.len() != self.len() || velocities.len() != self.len() {
            return Err(ModelError::BadParameter {
                name: "state",
                reason: "length differs from the particle count",
            });
        }
        for (i, (x, v)) in positions.iter().zip(velocities).enumerate() {
            if !x.is_finite() {
                return Err(ModelError::NonFiniteParticle {
                    particle: i,
                    field: "position",
                });
            }
            if !v.is_finite() {
                return Err(ModelError::NonFiniteParticle {
                    particle: i,
                    field: "velocity",
                });
            }
        }
        self.positions.copy_from_slice(positions);
        for (i, v) in velocities.iter().enumerate() {
            self.velocities[i] = if self.fixed[i] { DVec3::ZERO } else { *v };
        }
        Ok(())
    }

    /// Moves the pinned particles of `targets` (validated by the caller) to their
    /// positions at the end of a step of length `h` and gives them the velocity of that
    /// move, `(target - position) / h`; every other pinned particle is held still (zero
    /// velocity). The implicit integrators read a pinned particle's velocity as the
    /// prescribed motion over the step (docs/self-contact.md, "Moving pins").
    pub(crate) fn move_pinned(&mut self, targets: &[(usize, DVec3)], h: f64) {
        for (v, f) in self.velocities.iter_mut().zip(&self.fixed) {
            if *f {
                *v = DVec3::ZERO;
            }
        }
        for &(i, target) in targets {
            self.velocities[i] = (target - self.positions[i]) / h;
            self.positions[i] = target;
        }
    }

    /// Puts pinned particles back at `positions` with velocities `velocities` (undoing
    /// [`SpringSystem::move_pinned`] after a refused step, or restoring the velocities
    /// of a kept one).
    pub(crate) fn restore_pinned(&mut self, particles: &[(usize, DVec3, DVec3)]) {
        for &(i, x, v) in particles {
            self.positions[i] = x;
            self.velocities[i] = v;
        }
    }

    /// Mutable access to positions and velocities together, for integrators in this crate.
    pub(crate) fn state_mut(&mut self) -> (&mut [DVec3], &mut [DVec3]) {
        (&mut self.positions, &mut self.velocities)
    }

    /// Smallest mass over free particles (the scale of the stopping rule); 1 if none.
    #[must_use]
    pub fn min_free_mass(&self) -> f64 {
        let m = self
            .masses
            .iter()
            .zip(&self.fixed)
            .filter(|(_, f)| !**f)
            .map(|(m, _)| *m)
            .fold(f64::INFINITY, f64::min);
        if m.is_finite() { m } else { 1.0 }
    }

    /// The energies of the current state.
    #[must_use]
    pub fn energies(&self) -> Energies {
        self.energies_of(&self.positions, &self.velocities)
    }

    /// The energies of the state `(x, v)` of this system (same lengths as its own).
    pub(crate) fn energies_of(&self, x: &[DVec3], v: &[DVec3]) -> Energies {
        let spring = self
            .springs
            .iter()
            .map(|s| crate::spring::energy(x[s.a], x[s.b], s.rest_length, s.stiffness))
            .sum();
        let (kinetic, gravity) = self.particle_energies_of(x, v);
        Energies {
            kinetic,
            spring,
            gravity,
        }
    }

    /// The kinetic and gravitational energies of the state `(x, v)`, each summed over the
    /// particles in order: the part of [`Self::energies_of`] that has no springs (the
    /// Newton stepper sums the springs' part on its thread pool and adds this).
    pub(crate) fn particle_energies_of(&self, x: &[DVec3], v: &[DVec3]) -> (f64, f64) {
        let kinetic = self
            .masses
            .iter()
            .zip(v)
            .map(|(m, v)| 0.5 * m * v.length_squared())
            .sum();
        let gravity = self
            .masses
            .iter()
            .zip(x)
            .map(|(m, x)| -m * self.material.gravity.dot(*x))
            .sum();
        (kinetic, gravity)
    }

    /// The fingerprint of the topology, computed when the system was built (O(1)).
    #[must_use]
    pub fn topology(&self) -> Topology {
        self.topology
    }

    /// The fingerprint of the springs' rest lengths and stiffnesses, computed when the
    /// system was built (O(1)): a stepper that keeps a copy of them compares it with
    /// the fingerprint of the copy's system instead of reading them all again. Two
    /// systems with other constants share it only by a hash collision (about 2^-64).
    pub(crate) fn spring_constants(&self) -> u64 {
        self.spring_constants
    }

    /// Whether two systems have the same topology (particle count, fixed set, spring
    /// pairs, masses), so a stepper built for one fits the other; compares the
    /// fingerprints, O(1).
    #[must_use]
    pub fn same_topology(&self, other: &Self) -> bool {
        self.topology == other.topology
    }
}

/// Mechanical energies of a state.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Energies {
    /// `sum m |v|^2 / 2`.
    pub kinetic: f64,
    /// `sum k (l - L)^2 / 2`.
    pub spring: f64,
    /// `-sum m g . x` (zero at the origin).
    pub gravity: f64,
}

impl Energies {
    /// Kinetic + spring + gravity.
    #[must_use]
    pub fn total(&self) -> f64 {
        self.kinetic + self.spring + self.gravity
    }

    /// The scale a rise of the total energy is measured against: kinetic + spring +
    /// |gravity|, the sum of the terms' sizes (at least `f64::MIN_POSITIVE`). Unlike
    /// |total| it does not vanish when gravity's energy (negative below the origin)
    /// cancels the others, so a relative rise stays meaningful; docs/scenes.md
    /// ("Energy rise") defines the metric that uses it.
    ///
    /// ```
    /// use sinew_spring_sim::Energies;
    /// // Gravity's energy cancels the rest: the total is 0, the scale is not.
    /// let e = Energies { kinetic: 1.0, spring: 2.0, gravity: -3.0 };
    /// assert_eq!((e.total(), e.scale()), (0.0, 6.0));
    /// ```
    #[must_use]
    pub fn scale(&self) -> f64 {
        self.size().max(f64::MIN_POSITIVE)
    }

    /// kinetic + spring + |gravity|, zero exactly when every energy is.
    fn size(&self) -> f64 {
        self.kinetic + self.spring + self.gravity.abs()
    }

    /// The rise of the total energy over one step, from `before` to `after`, relative to
    /// a run's scale: kinetic + spring + |gravity| of the run's start `start` (its
    /// [`Self::scale`]) or, when every energy of the start is zero (a cloth at rest,
    /// unstretched, at the height where gravity's energy is zero), the larger of the
    /// step's two ends'. Against the start's scale alone such a run's rises were divided
    /// by `f64::MIN_POSITIVE`, a round-off rise of 1e-17 reading as 1e291; a step whose
    /// ends have no energy either has no rise (0). The one definition of the runner's,
    /// the benchmark's and the stress grid's rise (docs/scenes.md, "Energy rise").
    ///
    /// ```
    /// use sinew_spring_sim::Energies;
    /// let zero = Energies { kinetic: 0.0, spring: 0.0, gravity: 0.0 };
    /// let start = Energies { kinetic: 1.0, spring: 2.0, gravity: -3.0 };
    /// let fell = Energies { kinetic: 1.5, spring: 2.0, gravity: -3.0 };
    /// // Measured against the start's scale, 6.
    /// assert_eq!(Energies::relative_rise(&start, &start, &fell), 0.5 / 6.0);
    /// // A run that started with no energy: against the step's larger scale, 6.5.
    /// assert_eq!(Energies::relative_rise(&zero, &start, &fell), 0.5 / 6.5);
    /// assert_eq!(Energies::relative_rise(&zero, &zero, &zero), 0.0);
    /// ```
    #[must_use]
    pub fn relative_rise(start: &Energies, before: &Energies, after: &Energies) -> f64 {
        let rise = after.total() - before.total();
        let scale = if start.size() > 0.0 {
            start.size()
        } else {
            before.size().max(after.size())
        };
        if scale > 0.0 { rise / scale } else { rise }
    }
}

/// The lab cloth on an `n x n` grid (docs/workloads.md W4): particle `(i, j)` at
/// `origin + (spacing i, 0, spacing j)`, index `i n + j`; springs from `(i, j)` to
/// `(i-1, j)`, `(i-2, j)`, `(i, j-1)`, `(i, j-2)`, `(i-1, j-1)`, `(i-1, j+1)` where they
/// exist (structural, bending skip-one, shear), rest length = initial distance.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct ClothGrid {
    /// Particles per side (the lab: 11).
    pub size: usize,
    /// Grid spacing (the lab: 0.2).
    pub spacing: f64,
    /// Position of particle (0, 0) (the lab: (0, 1.5, -1)).
    pub origin: DVec3,
    /// Mass per particle.
    pub mass: f64,
    /// Material (stiffness of every spring, damping, gravity).
    pub material: Material,
    /// Fixed particles as grid coordinates (the lab: (0, 0) and (0, size - 1)).
    pub fixed: Vec<(usize, usize)>,
}

impl Default for ClothGrid {
    /// The lab cloth, [`ClothGrid::lab`] (the default of scene files that give only
    /// some of its fields).
    fn default() -> Self {
        Self::lab()
    }
}

impl ClothGrid {
    /// The lab's spring pattern on an `n x n` grid whose particle `(i, j)` has index
    /// `i * n + j`: each particle joined to `(i-1, j)`, `(i-2, j)`, `(i, j-1)`, `(i, j-2)`,
    /// `(i-1, j-1)` and `(i-1, j+1)` where they exist (structural, skip-one bend, shear),
    /// for systems built on other grids than [`ClothGrid::build`]'s (a tilted sheet).
    #[must_use]
    pub fn spring_pattern(n: usize) -> Vec<SpringSpec> {
        let idx = |i: usize, j: usize| i * n + j;
        let mut springs = Vec::with_capacity(6 * n * n);
        for i in 0..n {
            for j in 0..n {
                let here = idx(i, j);
                if i >= 1 {
                    springs.push(SpringSpec::between(here, idx(i - 1, j)));
                }
                if i >= 2 {
                    springs.push(SpringSpec::between(here, idx(i - 2, j)));
                }
                if j >= 1 {
                    springs.push(SpringSpec::between(here, idx(i, j - 1)));
                }
                if j >= 2 {
                    springs.push(SpringSpec::between(here, idx(i, j - 2)));
                }
                if i >= 1 && j >= 1 {
                    springs.push(SpringSpec::between(here, idx(i - 1, j - 1)));
                }
                if i >= 1 && j + 1 < n {
                    springs.push(SpringSpec::between(here, idx(i - 1, j + 1)));
                }
            }
        }
        springs
    }

    /// The lab cloth W4: 11 x 11, spacing 0.2, origin (0, 1.5, -1), mass 1, the lab's
    /// material ([`Material::lab`]: stiffness 100, damping 0.2, gravity 0.3 along -y),
    /// corners (0, 0) and (0, 10) fixed.
    ///
    /// ```
    /// use sinew_spring_sim::{ClothGrid, Material};
    /// // The lab cloth without damping, and a finer 21 x 21 sheet of the same size under
    /// // Earth's gravity.
    /// let undamped = ClothGrid::lab().with_damping(0.0);
    /// assert_eq!(undamped.material.damping, 0.0);
    /// let fine = ClothGrid::lab_sized(21, 0.1).with_material(Material::earth());
    /// let system = fine.build().unwrap();
    /// assert_eq!(system.len(), 21 * 21);
    /// assert_eq!(system.fixed().iter().filter(|&&f| f).count(), 2);
    /// ```
    #[must_use]
    pub fn lab() -> Self {
        Self::lab_sized(11, 0.2)
    }

    /// W4's pattern with `size` particles per side and the given spacing, placed like the
    /// lab (origin (0, 1.5, -1)), mass 1 per particle, the lab's material, corners (0, 0)
    /// and (0, size - 1) fixed.
    #[must_use]
    pub fn lab_sized(size: usize, spacing: f64) -> Self {
        Self {
            size,
            spacing,
            origin: DVec3::new(0.0, 1.5, -1.0),
            mass: 1.0,
            material: Material::lab(),
            fixed: vec![(0, 0), (0, size.saturating_sub(1))],
        }
    }

    /// The same grid with another damping coefficient (the rest of the material kept).
    #[must_use]
    pub fn with_damping(mut self, damping: f64) -> Self {
        self.material.damping = damping;
        self
    }

    /// The same grid with another material.
    #[must_use]
    pub fn with_material(mut self, material: Material) -> Self {
        self.material = material;
        self
    }

    /// Builds the system.
    pub fn build(&self) -> Result<SpringSystem, ModelError> {
        let n = self.size;
        if n == 0 {
            return Err(ModelError::BadParameter {
                name: "size",
                reason: "must be at least 1",
            });
        }
        if !(self.spacing.is_finite() && self.spacing > 0.0) {
            return Err(ModelError::BadParameter {
                name: "spacing",
                reason: "must be positive and finite",
            });
        }
        if !self.origin.is_finite() {
            return Err(ModelError::BadParameter {
                name: "origin",
                reason: "must be finite",
            });
        }
        let mut particles = Vec::with_capacity(n * n);
        for i in 0..n {
            for j in 0..n {
                let position =
                    self.origin + DVec3::new(self.spacing * i as f64, 0.0, self.spacing * j as f64);
                particles.push(Particle::at_rest(position, self.mass));
            }
        }
        for &(i, j) in &self.fixed {
            if i >= n || j >= n {
                return Err(ModelError::BadParameter {
                    name: "fixed",
                    reason: "grid coordinate out of range",
                });
            }
            particles[i * n + j].fixed = true;
        }
        let springs = Self::spring_pattern(n);
        SpringSystem::new(&particles, &springs, self.material)
    }
}

/// A rope: `segments + 1` particles on a straight line from `start` in `direction`, each
/// `segment_length` apart, neighbours joined by springs, particle 0 fixed.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct Rope {
    /// Number of springs.
    pub segments: usize,
    /// Rest length of each spring (the initial spacing).
    pub segment_length: f64,
    /// First (fixed) particle.
    pub start: DVec3,
    /// Direction of the rope (need not be unit).
    pub direction: DVec3,
    /// Mass per particle.
    pub mass: f64,
    /// Material.
    pub material: Material,
}

impl Rope {
    /// Builds the system.
    pub fn build(&self) -> Result<SpringSystem, ModelError> {
        if self.segments == 0 {
            return Err(ModelError::BadParameter {
                name: "segments",
                reason: "must be at least 1",
            });
        }
        if !(self.segment_length.is_finite() && self.segment_length > 0.0) {
            return Err(ModelError::BadParameter {
                name: "segment_length",
                reason: "must be positive and finite",
            });
        }
        let Some(dir) = sinew_math::try_unit(self.direction) else {
            return Err(ModelError::BadParameter {
                name: "direction",
                reason: "must be a finite non-zero vector",
            });
        };
        if !self.start.is_finite() {
            return Err(ModelError::BadParameter {
                name: "start",
                reason: "must be finite",
            });
        }
        let mut particles: Vec<Particle> = (0..=self.segments)
            .map(|i| {
                Particle::at_rest(
                    self.start + dir * (self.segment_length * i as f64),
                    self.mass,
                )
            })
            .collect();
        particles[0].fixed = true;
        let springs: Vec<SpringSpec> = (1..=self.segments)
            .map(|i| SpringSpec {
                particles: [i - 1, i],
                rest_length: Some(self.segment_length),
                stiffness: None,
            })
            .collect();
        SpringSystem::new(&particles, &springs, self.material)
    }
}
