//! Contact between the particles and rigid colliders, after Incremental Potential
//! Contact (IPC: Li et al., "Incremental Potential Contact", SIGGRAPH 2020), as separate,
//! pure and tested pieces.
//!
//! - [`collider`]: half-space, sphere and capsule colliders, static or kinematic (a
//!   constant linear velocity plus a constant angular velocity about the collider's own
//!   reference point), their validation and their pose at a time.
//! - [`distance`]: the signed distance from a point to a posed collider, its gradient (the
//!   unit normal) and its Hessian, with an optional thickness offset.
//! - [`barrier`]: IPC's log barrier `b(d)`, its derivatives, the per-particle barrier
//!   energy with its PSD-projected Hessian, and the adaptive barrier stiffness `kappa`.
//! - [`psd`]: a robust eigen-decomposition of symmetric 3x3 matrices and the projection
//!   onto positive semidefinite matrices.
//! - [`toi`]: the time of impact along a line-search direction, the cap that keeps
//!   every iterate outside every collider.
//! - [`friction`]: lagged, smoothed Coulomb friction per contact.
//! - [`potential`]: [`ContactPotential`], the barrier and friction energy of a whole
//!   system for one implicit step, with a broad phase and the line-search cap.
//! - [`term`]: [`ContactTerm`], that potential as a term of the implicit integrators'
//!   minimization ([`crate::potential::Term`]).
//! - [`self_contact`]: contact of a triangle-mesh cloth with itself (point-triangle and
//!   edge-edge barriers, the broad phase and continuous collision detection).
//! - [`projection`]: the position and velocity projection for the explicit integrators
//!   (not guaranteed: see its documentation).
//!
//! The derivations, `kappa`'s rule, the time-of-impact formulas and the argument for the
//! guarantee (no accepted state has a particle inside a collider) are in
//! docs/contact.md.

pub mod barrier;
pub mod collider;
pub mod distance;
pub mod friction;
pub mod potential;
pub mod projection;
pub mod psd;
pub mod self_contact;
pub mod term;
pub mod toi;

pub use barrier::{AdaptiveKappa, KappaSettings, MAX_KAPPA_RATIO, PointBarrier, point_barrier};
pub use collider::{Collider, Drive, MAX_COLLIDER_MAGNITUDE, Motion, Shape};
pub use distance::{SignedDistance, signed_distance};
pub use friction::FrictionContact;
pub use potential::{ContactPotential, ContactStep, swept_allowance};
pub use projection::{ProjectedParticle, project_particle};
pub use term::{ContactStats, ContactTerm};
pub use toi::time_of_impact;

use std::fmt;

/// Invalid contact input, naming the offending collider or setting and field.
#[derive(Clone, Debug, PartialEq)]
pub enum ContactError {
    /// A collider field is invalid.
    BadCollider {
        /// Index of the collider in its list (`None` when a single collider was checked
        /// on its own, by [`Collider::validate`]).
        collider: Option<usize>,
        /// The collider's shape: "half-space", "sphere" or "capsule".
        shape: &'static str,
        /// The field: "point", "normal", "center", "radius", "a", "b",
        /// "linear_velocity", "angular_velocity" or "pose_time"; when a collider is
        /// driven ([`Drive`]), "target", "duration", "start" or "end"; "pose" for its
        /// pose at the integrator's time.
        field: &'static str,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// Contact was asked of an integrator (or in a way) that does not support it.
    Unsupported {
        /// What is not supported (an integrator's name, or the request).
        what: &'static str,
    },
    /// Self-contact was asked of an integrator without a Newton workspace to hold its
    /// barrier (the explicit integrators, the flawed reference method).
    SelfContactUnsupported {
        /// The integrator's name.
        integrator: &'static str,
    },
    /// Self-contact was given a bad mesh or state: a triangle refers to a particle that
    /// does not exist, or two primitives start closer than the thickness.
    BadMesh {
        /// The item: "triangle 4", or the pair, "vertex 3 and triangle 7".
        item: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A contact setting is invalid.
    BadSetting {
        /// The setting's name ("dhat", "thickness", "mu", "eps_v", ...).
        name: &'static str,
        /// The value given.
        value: f64,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A contact distance below what the positions can resolve: under
    /// [`MIN_RELATIVE_DHAT`] of their largest coordinate ([`check_contact_distance`]).
    BelowResolution {
        /// The setting's name ("dhat").
        name: &'static str,
        /// The value given.
        value: f64,
        /// The positions' largest coordinate (absolute value).
        scale: f64,
    },
    /// Contact of one kind ("contact" with colliders, or "self-contact") was added to an
    /// integrator that has it already: one term holds every collider (and every pair of
    /// the cloth), and a second would add a second barrier.
    AddedTwice {
        /// The kind of contact.
        what: &'static str,
    },
    /// A contact distance above the diagonal of the positions' bounding box
    /// ([`check_contact_distance`]).
    BeyondExtent {
        /// The setting's name ("dhat").
        name: &'static str,
        /// The value given.
        value: f64,
        /// The diagonal of the positions' bounding box.
        extent: f64,
    },
    /// A collider was driven ([`Drive`]) by an index that is not in the list.
    NoSuchCollider {
        /// The index given.
        index: usize,
        /// The number of colliders (0 without contact).
        count: usize,
    },
    /// A free particle starts inside or on a collider ([`check_start_outside`]).
    StartsInside {
        /// The particle.
        particle: usize,
        /// The collider's index.
        collider: usize,
        /// Its distance to the collider's surface, less the thickness (`<= 0`).
        distance: f64,
    },
}

impl fmt::Display for ContactError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::BadCollider {
                collider,
                shape,
                field,
                reason,
            } => {
                match collider {
                    Some(i) => write!(f, "collider {i} ({shape})")?,
                    None => write!(f, "collider ({shape})")?,
                }
                write!(f, ": {field} {reason}")
            }
            Self::BadSetting {
                name,
                value,
                reason,
            } => write!(f, "contact setting {name} = {}: {reason}", Readable(*value)),
            Self::BadMesh { item, reason } => write!(f, "self-contact: {item} {reason}"),
            Self::BelowResolution { name, value, scale } => write!(
                f,
                "contact setting {name} = {value:e} is below {MIN_RELATIVE_DHAT:e} of the \
                 positions' largest coordinate ({scale:e}): distances that small are \
                 rounding"
            ),
            Self::BeyondExtent {
                name,
                value,
                extent,
            } => write!(
                f,
                "contact setting {name} = {} is above the diagonal of the cloth's bounding \
                 box ({extent:.3e}): a barrier reaching that far acts on every particle at \
                 once",
                Readable(*value)
            ),
            Self::StartsInside {
                particle,
                collider,
                distance,
            } => write!(
                f,
                "particle {particle} starts inside collider {collider} (its distance to the \
                 surface, less the thickness, is {distance:e}): contact needs every free \
                 particle outside every collider at the start"
            ),
            Self::NoSuchCollider { index, count } => write!(
                f,
                "there is no collider {index} to drive (there are {count})"
            ),
            Self::AddedTwice { what } => write!(
                f,
                "{what} was added to this integrator already (one term holds all of it; a \
                 second would add a second barrier)"
            ),
            Self::Unsupported { what } => write!(
                f,
                "contact is not supported for {what} (backward Euler, BDF2 and implicit midpoint have the guaranteed barrier; the explicit integrators a projection)"
            ),
            Self::SelfContactUnsupported { integrator } => write!(
                f,
                "self-contact is not supported for {integrator}: its barrier is a term of the \
                 implicit integrators' potential (backward Euler, BDF2, implicit midpoint), \
                 and no projection keeps triangles from passing through each other"
            ),
        }
    }
}

impl std::error::Error for ContactError {}

/// [`ContactError::AddedTwice`] when `integrator` holds the term named `what` already
/// (its [`crate::potential::Term::name`]).
pub(crate) fn refuse_second(
    integrator: &crate::BackwardEuler,
    what: &'static str,
) -> Result<(), ContactError> {
    if integrator
        .potential()
        .terms()
        .iter()
        .any(|t| t.name() == what)
    {
        return Err(ContactError::AddedTwice { what });
    }
    Ok(())
}

/// A value as written in a message: plain between 1e-4 and 1e6 (and 0), else in
/// scientific notation, so a huge or tiny setting does not print 300 digits.
struct Readable(f64);

impl fmt::Display for Readable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let a = self.0.abs();
        if a == 0.0 || !a.is_finite() || (1e-4..1e6).contains(&a) {
            write!(f, "{}", self.0)
        } else {
            write!(f, "{:e}", self.0)
        }
    }
}

/// The contact settings shared by the barrier, the time of impact and friction.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct ContactSettings {
    /// Contact distance `dhat`: the barrier acts where the (thickness-offset) distance
    /// is below it (default 1e-3, a millimetre in SI scenes).
    pub dhat: f64,
    /// Cloth thickness: distances are measured from the collider's surface offset
    /// outward by this much (default 0).
    pub thickness: f64,
    /// Coulomb friction coefficient, `0 <= mu <=` [`MAX_MU`] (default 0, frictionless).
    pub mu: f64,
    /// Friction's velocity threshold `eps_v` (scene units per second, default 1e-3):
    /// below this tangential speed friction is smoothed (static friction is
    /// approximated by a very slow creep), above it it is exactly Coulomb.
    pub eps_v: f64,
    /// The time of impact keeps every particle at least `(1 - s)` of its current
    /// distance from every collider, `s` this fraction (default 0.9: a line search may
    /// close up to 90% of a particle's distance, keeping a tenth, as IPC's conservative
    /// rescaling does; with 0.1 a particle closed only a tenth of its distance per Newton
    /// iteration, and a sheet landing on a sphere took dozens of iterations per step).
    pub toi_fraction: f64,
    /// The adaptive barrier stiffness rule's constants (default IPC's: `kappa_max = 100
    /// kappa_min`, doubling below `0.01 dhat`).
    pub kappa: KappaSettings,
}

impl Default for ContactSettings {
    fn default() -> Self {
        Self {
            dhat: 1e-3,
            thickness: 0.0,
            mu: 0.0,
            eps_v: 1e-3,
            toi_fraction: 0.9,
            kappa: KappaSettings::default(),
        }
    }
}

impl ContactError {
    /// The error [`ContactError::BadSetting`] of the setting `name` given `value`, with
    /// what is wrong with it: the one way every settings check reports.
    pub(crate) fn bad_setting<T>(
        name: &'static str,
        value: f64,
        reason: &'static str,
    ) -> Result<T, Self> {
        Err(Self::BadSetting {
            name,
            value,
            reason,
        })
    }
}

/// The checks every barrier's settings share: `dhat > 0` and `thickness >= 0`, both
/// finite; the error names the setting.
pub(crate) fn check_gap_settings(dhat: f64, thickness: f64) -> Result<(), ContactError> {
    if !(dhat.is_finite() && dhat > 0.0) {
        return ContactError::bad_setting("dhat", dhat, "must be positive and finite");
    }
    if !(thickness.is_finite() && thickness >= 0.0) {
        return ContactError::bad_setting(
            "thickness",
            thickness,
            "must be non-negative and finite",
        );
    }
    Ok(())
}

/// The checks every friction's settings share: `0 <= mu <=` [`MAX_MU`] and `eps_v > 0`,
/// both finite; the error names the setting.
pub(crate) fn check_friction_settings(mu: f64, eps_v: f64) -> Result<(), ContactError> {
    let bad = ContactError::bad_setting;
    if !(mu.is_finite() && mu >= 0.0) {
        return bad("mu", mu, "must be non-negative and finite");
    }
    if mu > MAX_MU {
        return bad("mu", mu, "must be at most 100 (MAX_MU)");
    }
    if !(eps_v.is_finite() && eps_v > 0.0) {
        return bad("eps_v", eps_v, "must be positive and finite");
    }
    Ok(())
}

/// The largest friction coefficient `mu`: 100, a slope of 89.4 degrees held by friction.
/// Real pairs of materials stay below about 5. Far above, friction's curvature
/// (`mu lambda / (eps_v h)`, about `mu g h / eps_v` times the inertia's) sets the
/// rounding of the Newton solve, which the split rule's round-off floor (inertia, springs
/// and damping) does not count: the sheet dropped on the sphere of
/// `scenes/cloth-drape-folds.ron` takes 154 Newton iterations over its 20 steps at `mu` =
/// 100, 599 at 1e5, 16 283 at 1e6 and did not finish in a minute at 1e8.
pub const MAX_MU: f64 = 100.0;

/// The smallest contact distance `dhat`, as a fraction of the largest coordinate of the
/// positions it separates: 1e-9, about four million units in the last place of that
/// coordinate. Distances are differences of positions, so they carry a rounding of a few
/// `eps |x|` (`eps` = 2.2e-16); a barrier band `(0, dhat)` narrower than a few of those
/// is rounding, and its guarantee with it: a sheet given `dhat` = 5e-324 ended the run
/// with 17 vertices at distance <= 0 from a sphere. The shipped scenes' `dhat` is about
/// 1e-3 of their largest coordinate.
pub const MIN_RELATIVE_DHAT: f64 = 1e-9;

/// Checks that the contact distance `dhat` (named `name` in the error) is at least
/// [`MIN_RELATIVE_DHAT`] of the largest coordinate of `positions`
/// ([`ContactError::BelowResolution`] if not) and, when the positions span a box of
/// positive diagonal, at most that diagonal ([`ContactError::BeyondExtent`] if not): a
/// barrier reaching farther than the whole cloth is wide acts on every particle at once,
/// a stiff force field rather than contact (a sheet 0.3 m across over a sphere took 263
/// Newton iterations over its 30 steps with `dhat` = 1e-3, 413 and seven times the time
/// at 10, and did not finish in a minute at 1 000).
pub fn check_contact_distance(
    name: &'static str,
    dhat: f64,
    positions: &[sinew_math::DVec3],
) -> Result<(), ContactError> {
    let scale = positions
        .iter()
        .fold(0.0f64, |m, x| m.max(x.abs().max_element()));
    if dhat < MIN_RELATIVE_DHAT * scale {
        return Err(ContactError::BelowResolution {
            name,
            value: dhat,
            scale,
        });
    }
    let Some(&first) = positions.first() else {
        return Ok(());
    };
    let (lo, hi) = positions
        .iter()
        .fold((first, first), |(lo, hi), &x| (lo.min(x), hi.max(x)));
    let extent = (hi - lo).length();
    if extent > 0.0 && dhat > extent {
        return Err(ContactError::BeyondExtent {
            name,
            value: dhat,
            extent,
        });
    }
    Ok(())
}

/// Checks that every free particle of `positions` is outside every collider posed at time
/// `t`: its distance to the surface, less `thickness`, is positive. The guarantee (no
/// accepted state has a particle inside a collider) holds by induction from such a
/// start; a particle inside at the start would be pushed out to the surface by the first
/// step, however far that is (a sheet inside a sphere of radius 1e9 moved 1e9 m in one
/// step), so it is refused instead ([`ContactError::StartsInside`], naming the first
/// such particle, by collider then particle, and the collider).
pub fn check_start_outside(
    colliders: &[Collider],
    thickness: f64,
    t: f64,
    positions: &[sinew_math::DVec3],
    fixed: &[bool],
) -> Result<(), ContactError> {
    match first_inside(colliders, thickness, t, positions, fixed) {
        Some((particle, collider, distance)) => Err(ContactError::StartsInside {
            particle,
            collider,
            distance,
        }),
        None => Ok(()),
    }
}

/// Every check made where colliders are added to a stepper, in order: the colliders
/// (the error names the collider), the settings (the error names the setting), `dhat`
/// against the positions ([`check_contact_distance`]) and the start
/// ([`check_start_outside`] at time `t`).
pub(crate) fn check_contact_setup(
    colliders: &[Collider],
    settings: &ContactSettings,
    t: f64,
    positions: &[sinew_math::DVec3],
    fixed: &[bool],
) -> Result<(), ContactError> {
    collider::validate_colliders(colliders)?;
    settings.validate()?;
    if let Some(i) = colliders.iter().position(|c| !c.pose_in_range(t)) {
        return Err(ContactError::BadCollider {
            collider: Some(i),
            shape: colliders[i].shape.kind(),
            field: "pose",
            reason: "at the integrator's time is not finite or beyond 1e50 in magnitude \
                     (MAX_COLLIDER_MAGNITUDE)",
        });
    }
    check_contact_distance("dhat", settings.dhat, positions)?;
    check_start_outside(colliders, settings.thickness, t, positions, fixed)
}

/// [`check_start_outside`] for a stepper: the same check, refused as
/// [`StepError::StartsInside`](crate::StepError::StartsInside) so that a step from an
/// inadmissible start fails before anything is written.
pub(crate) fn check_step_start(
    colliders: &[Collider],
    thickness: f64,
    t: f64,
    positions: &[sinew_math::DVec3],
    fixed: &[bool],
) -> Result<(), crate::StepError> {
    if let Some(collider) = colliders.iter().position(|c| !c.pose_in_range(t)) {
        return Err(crate::StepError::ColliderOutOfRange { collider, time: t });
    }
    match first_inside(colliders, thickness, t, positions, fixed) {
        Some((particle, collider, distance)) => Err(crate::StepError::StartsInside {
            particle,
            collider,
            distance,
        }),
        None => Ok(()),
    }
}

/// The first free particle (by collider, then particle) inside or on a collider posed
/// at `t`, as `(particle, collider, distance less thickness)`.
pub(crate) fn first_inside(
    colliders: &[Collider],
    thickness: f64,
    t: f64,
    positions: &[sinew_math::DVec3],
    fixed: &[bool],
) -> Option<(usize, usize, f64)> {
    colliders.iter().enumerate().find_map(|(collider, c)| {
        let shape = c.at(t);
        positions.iter().enumerate().find_map(|(particle, x)| {
            if fixed.get(particle).copied().unwrap_or(false) {
                return None;
            }
            let distance = distance::distance_to(&shape, *x, thickness);
            // A NaN distance is inside too.
            (distance.is_nan() || distance <= 0.0).then_some((particle, collider, distance))
        })
    })
}

/// The share of the distance to impact a line search may close: `0 < f < 1`.
pub(crate) fn check_toi_fraction(fraction: f64) -> Result<(), ContactError> {
    if fraction > 0.0 && fraction < 1.0 {
        Ok(())
    } else {
        ContactError::bad_setting(
            "toi_fraction",
            fraction,
            "must lie strictly between 0 and 1",
        )
    }
}

impl ContactSettings {
    /// Checks every setting: `dhat > 0`, `thickness >= 0`, `0 <= mu <= MAX_MU`, `eps_v > 0`,
    /// `0 < toi_fraction < 1`, all finite, and the stiffness rule's constants
    /// ([`KappaSettings::validate`]). The error names the setting.
    pub fn validate(&self) -> Result<(), ContactError> {
        check_gap_settings(self.dhat, self.thickness)?;
        check_friction_settings(self.mu, self.eps_v)?;
        check_toi_fraction(self.toi_fraction)?;
        self.kappa.validate()
    }
}
