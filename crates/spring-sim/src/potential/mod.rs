//! The incremental potential as a sum of terms, each written once.
//!
//! One implicit step minimizes
//! `g(x) = 1/(2 h^2) |x - y|_M^2 + E_spring(x) + E_gravity(x) + D(x)` (see
//! [`crate::BackwardEuler`]). Each summand is a [`Term`] with its energy, its change along a
//! direction (from differences, where cancellation matters), its gradient, its
//! PSD-projected Hessian blocks (handed to a [`HessianSink`]) and, where it has one, the
//! largest safe step along a direction. The terms of this crate:
//! - [`Inertia`]: `1/(2 h^2) |x - y|_M^2` over the free particles;
//! - [`Gravity`]: `-sum_i m_i g . x_i` over the free particles (a constant external force);
//! - [`Springs`]: `sum_s k_s/2 (|x_a - x_b| - L_s)^2`, with the [`Curvature`] asked for;
//! - [`AxialDamping`]: `c/(2h) sum_s (u_s . (d_s(x) - d_s(x_ref)))^2`, the directions
//!   `u_s` frozen at the step's start.
//!
//! A [`Potential`] is the list of terms, assembled once per integrator. Newton and its line
//! search, the explicit force loop (`force = -grad` of the conservative terms) and the
//! stability bound (the Hessian of the springs and of the damping) all evaluate these
//! terms. The hooks the contact terms need (a per-step [`Term::begin_step`], a
//! per-iteration [`Term::update_active_set`], the line-search cap [`Term::max_step`], and
//! energies that are `+inf` where the state is not admissible) are described in
//! docs/potential.md, with how the pattern is rebuilt when a term couples new pairs.

mod bending;
mod damping;
pub(crate) mod end_state;
mod fused;
mod gravity;
mod inertia;
mod lanes;
pub(crate) use lanes::{Instance, energies as spring_energies};
#[cfg(feature = "parallel")]
mod parallel;
mod sink;
mod springs;

pub use bending::{
    DihedralBending, Hinge, angle_change, dihedral_angle, dihedral_angle_gradient,
    dihedral_angle_hessian,
};
pub use damping::AxialDamping;
pub use end_state::AtEndOfStep;
pub use gravity::Gravity;
pub use inertia::Inertia;
pub(crate) use sink::PairPlace;
pub use sink::{HessianSink, MissingPair, SymBlock};
pub use springs::Springs;

use crate::model::SpringSystem;
use crate::report::StepError;
use crate::spring::Curvature;
use fused::PerSpring;
pub(crate) use fused::{rate_product, rate_row_sums};
#[cfg(feature = "parallel")]
pub(crate) use parallel::SpringGather;
use sinew_math::DVec3;
use std::any::Any;

/// What stays fixed during one minimization: the system (masses, springs, material, fixed
/// flags, and its positions and velocities at the step's start), the effective step and
/// the two reference points of the step.
#[derive(Clone, Copy, Debug)]
pub struct StepContext<'a> {
    /// The system at the start of the step.
    pub system: &'a SpringSystem,
    /// The effective step `h` of the minimization (`h/2` for implicit midpoint, `2h/3`
    /// for BDF2).
    pub h: f64,
    /// The inertial prediction `y` (one per particle).
    pub y: &'a [DVec3],
    /// The point velocities are measured from, `v' = (x' - x_ref)/h`, also the damping's
    /// reference (one per particle).
    pub x_ref: &'a [DVec3],
    /// The step's times and what its unknowns are.
    pub timing: StepTiming,
}

impl<'a> StepContext<'a> {
    /// A context for `system` at effective step `h`, prediction `y` and reference
    /// `x_ref`, for a backward Euler step of length `h` starting at time 0 (see
    /// [`Self::with_timing`]).
    #[must_use]
    pub fn new(system: &'a SpringSystem, h: f64, y: &'a [DVec3], x_ref: &'a [DVec3]) -> Self {
        Self {
            system,
            h,
            y,
            x_ref,
            timing: StepTiming {
                start: 0.0,
                length: h,
                midpoint: false,
            },
        }
    }

    /// The same context for the step `timing`.
    #[must_use]
    pub fn with_timing(self, timing: StepTiming) -> Self {
        Self { timing, ..self }
    }
}

/// Where a minimization's step lies in time, and what its unknowns are: the scheme's
/// side of a step that terms acting on the end-of-step state (contact) need.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepTiming {
    /// The time at the step's start (kinematic colliders are posed from it). An input
    /// of every step, so a step redone in pieces poses them at each piece's own times.
    pub start: f64,
    /// The real step length (backward Euler: the effective step; implicit midpoint:
    /// twice it; BDF2: 3/2 of it).
    pub length: f64,
    /// Whether the unknowns are the step's midpoint `z` (implicit midpoint: the end
    /// state is `2 z - x_n`) rather than the end-of-step positions themselves.
    pub midpoint: bool,
}

/// One summand of the incremental potential (see the module documentation).
///
/// Positions `x`, directions `dx` and gradients are indexed by particle, fixed particles
/// included: a direction is zero at fixed particles, and a gradient's entries there are
/// ignored by every caller. Energies and their changes are `+inf` where the state is not
/// admissible (a barrier inside its collider); the line search then rejects the step.
pub trait Term: Any + std::fmt::Debug + Send + Sync {
    /// A short name for reports and test messages.
    fn name(&self) -> &'static str;

    /// Called once per step before anything else, with the system at the step's start
    /// and the time it starts at: refuses a start the term cannot accept (for contact a
    /// free particle inside or on a collider, from which the barrier's guarantee cannot
    /// follow), leaving the system untouched. Accepts every start by default.
    ///
    /// # Errors
    /// The term's reason to refuse the start ([`StepError::StartsInside`] for contact).
    fn check_start(&self, system: &SpringSystem, time: f64) -> Result<(), StepError> {
        let _ = (system, time);
        Ok(())
    }

    /// Called once per step, before the minimization, with the state at the step's
    /// start (`step.system`): the place for per-step state (frozen damping directions,
    /// and for contact the lagged friction and the adaptive barrier stiffness).
    fn begin_step(&mut self, step: &StepContext<'_>) {
        let _ = step;
    }

    /// Called after a converged minimization when the Newton settings ask for friction to
    /// be lagged again ([`crate::NewtonSettings::friction_lags`]), with its minimizer `x`:
    /// lags the term's friction anew there (the contacts within reach at `x`, their
    /// normal forces, normals, tangent bases and weights at `x`), its displacements still
    /// measured from the step's reference point, so the next minimization's friction is
    /// that of the contacts the step ended in. Returns whether the term now holds lagged
    /// friction (with none, minimizing again changes nothing). The term's other state is
    /// left as it is. Nothing (and `false`) by default.
    fn relag_friction(&mut self, step: &StepContext<'_>, x: &[DVec3]) -> bool {
        let _ = (step, x);
        false
    }

    /// Called once per step after the first iterate is chosen, to move it where the term
    /// admits it (a contact term carries particles that a moving collider would run
    /// over along with the collider's rigid motion). Most terms leave it alone.
    fn prepare_start(&self, step: &StepContext<'_>, x: &mut [DVec3]) {
        let _ = (step, x);
    }

    /// Called at the start of every Newton iteration with the current iterate: the
    /// place to collect an active set (contacts within the barrier's reach). The
    /// gradient and Hessian may use the set; the energy and its change must not depend
    /// on it, because the first guess and the line search evaluate states the set was
    /// not collected at.
    fn update_active_set(&mut self, step: &StepContext<'_>, x: &[DVec3]) {
        let _ = (step, x);
    }

    /// The term's value at `x`.
    fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64;

    /// `E(x + alpha dx) - E(x)`, computed from the differences where that keeps the
    /// relative accuracy of a change far below the energy.
    fn energy_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64;

    /// Adds the gradient at `x` to `gradient` (one entry per particle).
    fn add_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]);

    /// Adds the Hessian at `x`, projected to be positive semidefinite block by block (or
    /// in the form `curvature` asks for, for terms with a choice), to `sink`.
    fn add_hessian(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        sink: &mut HessianSink<'_>,
    );

    /// Whether [`Term::add_hessian`] gives only diagonal blocks (`(i, i)`: no particle
    /// coupled to another), as inertia, gravity and contact with rigid colliders do. The
    /// threaded assembly then collects such terms' blocks per particle instead of
    /// zeroing every stored value of the Newton matrix first. `false` by default; a term
    /// that answers `true` and still gives a coupling block is detected by the sink, and
    /// the matrix is then assembled the general way (correct, only slower).
    fn hessian_is_block_diagonal(&self) -> bool {
        false
    }

    /// Whether the Hessian this term gives at the current active set for
    /// [`Curvature::ExactContact`] differs from the one for [`Curvature::Softened`] at the
    /// same `theta` (the self-contact barrier's exact pair Hessians against their
    /// projections): the Newton iteration then tries the exact form first. `false` by
    /// default.
    fn gives_exact_contact(&self) -> bool {
        false
    }

    /// The largest `alpha` for which every state on `x + [0, alpha] dx` is admissible
    /// (the line search never tries beyond it); unlimited by default. The caller will
    /// try nothing beyond `reach`, so a term may stop looking there: when the segment up
    /// to `reach` is admissible it may answer any admissible `alpha >= reach` instead
    /// (`reach` 1 when only the step itself is asked about, infinite for the largest).
    fn max_step(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], reach: f64) -> f64 {
        let _ = (step, x, dx, reach);
        f64::INFINITY
    }

    /// Called when the solve begun by the last [`Term::begin_step`] is abandoned and its
    /// step redone in pieces: the place to undo what the solve adapted (contact's barrier
    /// stiffness), so the pieces run as if they had been asked for one by one. Nothing by
    /// default.
    fn abandon_step(&mut self) {}

    /// The particle pairs (`[low, high]`) this term coupled since the last call without a
    /// slot in the Hessian pattern (it then wrote only the blocks the pattern has). The
    /// Newton loop takes them at the start of every iteration and widens its pattern, so
    /// the next iteration's matrix has the pairs' full blocks, and drops their slots again
    /// once the blocks have stayed zero for several steps; none by default.
    fn take_missing_pairs(&mut self) -> Vec<[usize; 2]> {
        Vec::new()
    }

    /// A free particle, and a collider, such that the particle's straight path from the
    /// step's start to the end state of the iterate `x` goes through the collider as it
    /// moves over the step (contact: see
    /// [`crate::contact::ContactPotential::first_swept_pass`]); the integrators split
    /// such a step. `None` by default.
    fn first_swept_pass(&self, step: &StepContext<'_>, x: &[DVec3]) -> Option<(usize, usize)> {
        let _ = (step, x);
        None
    }

    /// Whether a prescribed motion in this term does work on the system (a kinematic
    /// collider whose surface moves): backward Euler's energy inequality then does not
    /// hold, and a split step is not checked against it. `false` by default.
    fn does_work(&self) -> bool {
        false
    }

    /// Whether the term's passes are worth a thread pool at the next step whatever the
    /// system's size: its work grows with something other than the particles
    /// (self-contact: the pairs, many per vertex where sheets lie on each other or on an
    /// obstacle held still). The integrator then runs the step on its pool even for a
    /// system too small for PCG's chunks; asked before every step, so the answer may
    /// change as the work does. `false` by default.
    fn wants_threads(&self) -> bool {
        false
    }
}

/// The terms of one minimization, evaluated in order and summed.
///
/// Springs per chunk of [`Potential::energy_change_chunked`]'s sums: fixed, so the sums' order does not depend on
/// the threads.
pub(crate) const CHANGE_CHUNK: usize = 4096;

/// `sum_c part(chunk c)` over the chunks of [`CHANGE_CHUNK`] springs of `0..n` (at
/// least one, possibly empty), each computed on the current thread pool when `par`,
/// then added in chunk order starting from the first: one chunk gives `part(0..n)`
/// itself.
fn chunked_sum(
    n: usize,
    par: bool,
    partials: &mut Vec<f64>,
    part: impl Fn(std::ops::Range<usize>) -> f64 + Sync + Send,
) -> f64 {
    let chunks = n.div_ceil(CHANGE_CHUNK).max(1);
    let range = |c: usize| c * CHANGE_CHUNK..((c + 1) * CHANGE_CHUNK).min(n);
    #[cfg(feature = "parallel")]
    if par {
        use rayon::prelude::*;
        (0..chunks)
            .into_par_iter()
            .map(|c| part(range(c)))
            .collect_into_vec(partials);
        return partials[1..].iter().fold(partials[0], |sum, p| sum + p);
    }
    let _ = par;
    partials.clear();
    partials.extend((0..chunks).map(|c| part(range(c))));
    partials[1..].iter().fold(partials[0], |sum, p| sum + p)
}

/// [`chunked_sum`] of two sums at once: `part` returns both of a chunk's sums (kept in
/// `partials` as consecutive pairs), and each of the two totals is added in chunk order
/// from the first chunk, as [`chunked_sum`] adds its one.
fn chunked_sum2(
    n: usize,
    par: bool,
    partials: &mut Vec<f64>,
    part: impl Fn(std::ops::Range<usize>) -> [f64; 2] + Sync + Send,
) -> [f64; 2] {
    let chunks = n.div_ceil(CHANGE_CHUNK).max(1);
    let range = |c: usize| c * CHANGE_CHUNK..((c + 1) * CHANGE_CHUNK).min(n);
    partials.resize(2 * chunks, 0.0);
    let write = |(c, out): (usize, &mut [f64])| out.copy_from_slice(&part(range(c)));
    #[cfg(feature = "parallel")]
    if par {
        use rayon::prelude::*;
        partials.par_chunks_mut(2).enumerate().for_each(write);
    } else {
        partials.chunks_mut(2).enumerate().for_each(write);
    }
    #[cfg(not(feature = "parallel"))]
    {
        let _ = par;
        partials.chunks_mut(2).enumerate().for_each(write);
    }
    let mut sums = [partials[0], partials[1]];
    for pair in partials[2..].chunks_exact(2) {
        sums[0] += pair[0];
        sums[1] += pair[1];
    }
    sums
}

/// What [`Potential::energy_change_pair_chunked`] computed of the change at its second
/// step length, completed by [`Potential::second_change`].
#[derive(Clone, Copy, Debug)]
pub(crate) enum SecondChange {
    /// Nothing yet (a potential without the spring term).
    Whole {
        /// The step length.
        alpha: f64,
    },
    /// The springs' part, and the other terms' part when it was cheap enough to
    /// compute at once.
    Others {
        /// The step length.
        alpha: f64,
        /// The springs' (and the damping's) change.
        springs: f64,
        /// The other terms' change, when computed.
        others: Option<f64>,
    },
}

/// The first [`Springs`] and the first [`AxialDamping`] among the terms are evaluated
/// together in one loop over the springs (each term's per-spring formulas stay in its own
/// module; the loop calls both on the same spring), and a damping term is skipped when
/// the material has no damping. Every other term is evaluated on its own, in order. Only
/// the order of the floating-point sums differs from evaluating every term separately.
#[derive(Debug)]
pub struct Potential {
    terms: Vec<Box<dyn Term>>,
    /// Index of the spring term evaluated in the fused loop.
    springs: Option<usize>,
    /// Index of the damping term evaluated in the fused loop.
    damping: Option<usize>,
    /// Indices of the other terms.
    other_terms: Vec<usize>,
    /// The other terms in order, when every one of them is an [`Inertia`] or a
    /// [`Gravity`] (per particle and known here, so the threaded assembly folds them
    /// into its pass over the particles); `None` when another term is among them.
    pointwise_others: Option<Vec<Pointwise>>,
}

impl Default for Potential {
    fn default() -> Self {
        Self {
            terms: Vec::new(),
            springs: None,
            damping: None,
            other_terms: Vec::new(),
            pointwise_others: Some(Vec::new()),
        }
    }
}

/// A term whose gradient and Hessian act on each particle alone, with a kernel the
/// threaded assembly calls per particle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Pointwise {
    /// [`Inertia`].
    Inertia,
    /// [`Gravity`].
    Gravity,
}

impl Potential {
    /// The incremental potential of a mass-spring system: [`Inertia`], [`Gravity`],
    /// [`Springs`] and [`AxialDamping`] (which reads the damping coefficient from the
    /// material at every evaluation, so it costs nothing when that is zero).
    #[must_use]
    pub fn mass_spring(system: &SpringSystem) -> Self {
        Self::from_terms(vec![
            Box::new(Inertia),
            Box::new(Gravity),
            Box::new(Springs),
            Box::new(AxialDamping::new(system)),
        ])
    }

    /// A potential made of `terms`.
    #[must_use]
    pub fn from_terms(terms: Vec<Box<dyn Term>>) -> Self {
        let mut potential = Self::default();
        for t in terms {
            potential.push(t);
        }
        potential
    }

    /// Appends a term.
    pub fn push(&mut self, term: Box<dyn Term>) {
        let index = self.terms.len();
        let any: &dyn Any = term.as_ref();
        if any.is::<Springs>() && self.springs.is_none() {
            self.springs = Some(index);
        } else if any.is::<AxialDamping>() && self.damping.is_none() {
            self.damping = Some(index);
        } else {
            self.other_terms.push(index);
            let kind = if any.is::<Inertia>() {
                Some(Pointwise::Inertia)
            } else if any.is::<Gravity>() {
                Some(Pointwise::Gravity)
            } else {
                None
            };
            match (kind, self.pointwise_others.as_mut()) {
                (Some(kind), Some(list)) => list.push(kind),
                _ => self.pointwise_others = None,
            }
        }
        self.terms.push(term);
    }

    /// The per-spring terms for the fused loop at `step` (the damping only when its
    /// coefficient is nonzero).
    fn per_spring(&self, step: &StepContext<'_>) -> PerSpring<'_> {
        let damping = self.damping.and_then(|i| {
            let any: &dyn Any = self.terms[i].as_ref();
            let term = any.downcast_ref::<AxialDamping>()?;
            AxialDamping::active_coefficient(step).map(|c| (term, c))
        });
        PerSpring {
            springs: self.springs.is_some(),
            damping,
        }
    }
    /// The terms, in evaluation order.
    #[must_use]
    pub fn terms(&self) -> &[Box<dyn Term>] {
        &self.terms
    }

    /// The first term of type `T`, if any, to change between steps (a contact term's
    /// colliders are driven this way). What the potential learned of the terms when
    /// they were added (which are springs, damping, pointwise) depends on their types
    /// only, so it stays true.
    pub fn term_mut<T: Term>(&mut self) -> Option<&mut T> {
        self.terms.iter_mut().find_map(|t| {
            let any: &mut dyn Any = t.as_mut();
            any.downcast_mut::<T>()
        })
    }

    /// [`Term::check_start`] on every term, in order; the first refusal.
    ///
    /// # Errors
    /// The first term's refusal of the start.
    pub fn check_start(&self, system: &SpringSystem, time: f64) -> Result<(), StepError> {
        self.terms
            .iter()
            .try_for_each(|t| t.check_start(system, time))
    }

    /// [`Term::begin_step`] on every term.
    pub fn begin_step(&mut self, step: &StepContext<'_>) {
        for t in &mut self.terms {
            t.begin_step(step);
        }
    }

    /// [`Term::relag_friction`] on every term: whether any now holds lagged friction.
    pub fn relag_friction(&mut self, step: &StepContext<'_>, x: &[DVec3]) -> bool {
        let mut any = false;
        for t in &mut self.terms {
            any |= t.relag_friction(step, x);
        }
        any
    }

    /// [`Term::abandon_step`] on every term.
    pub fn abandon_step(&mut self) {
        for t in &mut self.terms {
            t.abandon_step();
        }
    }

    /// [`Term::prepare_start`] on every term.
    pub fn prepare_start(&self, step: &StepContext<'_>, x: &mut [DVec3]) {
        for t in &self.terms {
            t.prepare_start(step, x);
        }
    }

    /// Every term's [`Term::take_missing_pairs`], sorted and without repeats.
    pub fn take_missing_pairs(&mut self) -> Vec<[usize; 2]> {
        let mut pairs: Vec<[usize; 2]> = self
            .terms
            .iter_mut()
            .flat_map(|t| t.take_missing_pairs())
            .collect();
        pairs.sort_unstable();
        pairs.dedup();
        pairs
    }

    /// [`Term::update_active_set`] on every term.
    pub fn update_active_set(&mut self, step: &StepContext<'_>, x: &[DVec3]) {
        for t in &mut self.terms {
            t.update_active_set(step, x);
        }
    }

    /// `g(x)`, the sum of the terms' energies.
    #[must_use]
    pub fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        let others: f64 = self
            .other_terms
            .iter()
            .map(|&t| self.terms[t].energy(step, x))
            .sum();
        others + self.per_spring(step).energy(step, x)
    }

    /// `g(x + alpha dx) - g(x)`, the sum of the terms' changes.
    #[must_use]
    pub fn energy_change(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        dx: &[DVec3],
        alpha: f64,
    ) -> f64 {
        let others: f64 = self
            .other_terms
            .iter()
            .map(|&t| self.terms[t].energy_change(step, x, dx, alpha))
            .sum();
        others + self.per_spring(step).energy_change(step, x, dx, alpha)
    }

    /// [`Self::energy_change`] with the springs' part summed in fixed chunks of
    /// [`CHANGE_CHUNK`] springs (each in order, then the chunks' sums in order), computed
    /// on the current thread pool when `par`: the same bits for any number of threads.
    /// A system of at most one chunk (the 11 x 11 lab cloths) gets exactly the bits of
    /// [`Self::energy_change`]. `partials` is a buffer for the chunks' sums.
    pub(crate) fn energy_change_chunked(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        dx: &[DVec3],
        alpha: f64,
        par: bool,
        partials: &mut Vec<f64>,
    ) -> f64 {
        let per = self.per_spring(step);
        if !per.springs {
            return self.energy_change(step, x, dx, alpha);
        }
        let others = || self.others_change(step, x, dx, alpha);
        let springs = |partials: &mut Vec<f64>| {
            chunked_sum(step.system.springs().len(), par, partials, |range| {
                per.energy_change_over(step, x, dx, alpha, range)
            })
        };
        // On the pool the other terms (a pass over the particles) run beside the
        // springs' chunks instead of before them; the two totals are added as before.
        #[cfg(feature = "parallel")]
        if par {
            let (others, springs) = rayon::join(others, || springs(partials));
            return others + springs;
        }
        others() + springs(partials)
    }

    /// [`Self::energy_change_chunked`] at the first of the two step lengths `alphas`,
    /// with the springs' part at the second computed in the same pass over the springs
    /// (the line search's full step and its doubling, which it almost always asks for
    /// one after the other): the springs' positions, directions and lengths are read
    /// once instead of twice. The change at the second length is completed by
    /// [`Self::second_change`]; both are bit for bit what
    /// [`Self::energy_change_chunked`] gives at their lengths, for any number of
    /// threads. The other terms' change at the second length is computed here too when
    /// they are all per particle (inertia and gravity: a cheap pass, run beside the
    /// springs' chunks), and otherwise only if it is asked for, so an expensive term
    /// (contact) costs nothing more when the first length is rejected. `partials` is a
    /// buffer for the chunks' sums.
    pub(crate) fn energy_change_pair_chunked(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        dx: &[DVec3],
        [a1, a2]: [f64; 2],
        par: bool,
        partials: &mut Vec<f64>,
    ) -> (f64, SecondChange) {
        let per = self.per_spring(step);
        if !per.springs {
            let first = self.energy_change(step, x, dx, a1);
            return (first, SecondChange::Whole { alpha: a2 });
        }
        let eager = self.pointwise_others.is_some();
        let others = || -> (f64, Option<f64>) {
            let first = self.others_change(step, x, dx, a1);
            (first, eager.then(|| self.others_change(step, x, dx, a2)))
        };
        let springs = |partials: &mut Vec<f64>| {
            chunked_sum2(step.system.springs().len(), par, partials, |range| {
                per.energy_change_pair_over(step, x, dx, [a1, a2], range)
            })
        };
        #[cfg(feature = "parallel")]
        let ((o1, o2), [s1, s2]) = if par {
            rayon::join(others, || springs(partials))
        } else {
            (others(), springs(partials))
        };
        #[cfg(not(feature = "parallel"))]
        let ((o1, o2), [s1, s2]) = (others(), springs(partials));
        let second = SecondChange::Others {
            alpha: a2,
            springs: s2,
            others: o2,
        };
        (o1 + s1, second)
    }

    /// The change of `g` at the second length of [`Self::energy_change_pair_chunked`]
    /// (`x` and `dx` must be the ones given there): the bits of
    /// [`Self::energy_change_chunked`] at that length.
    pub(crate) fn second_change(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        dx: &[DVec3],
        second: SecondChange,
    ) -> f64 {
        match second {
            SecondChange::Whole { alpha } => self.energy_change(step, x, dx, alpha),
            SecondChange::Others {
                alpha,
                springs,
                others,
            } => others.unwrap_or_else(|| self.others_change(step, x, dx, alpha)) + springs,
        }
    }

    /// The sum of the changes of the terms outside the fused loop over the springs.
    fn others_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        self.other_terms
            .iter()
            .map(|&t| self.terms[t].energy_change(step, x, dx, alpha))
            .sum()
    }

    /// Writes `grad g(x)` into `gradient` (one entry per particle; overwritten).
    pub fn gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        gradient.fill(DVec3::ZERO);
        for &t in &self.other_terms {
            self.terms[t].add_gradient(step, x, gradient);
        }
        self.per_spring(step).add_gradient(step, x, gradient);
    }

    /// Adds every term's Hessian blocks at `x` to `sink`: the other terms first, then the
    /// spring and damping terms in one pass writing the sum of their blocks once per
    /// spring (assembly is dominated by those writes).
    pub fn add_hessian(
        &mut self,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        sink: &mut HessianSink<'_>,
    ) {
        for &t in &self.other_terms {
            self.terms[t].add_hessian(step, x, curvature, sink);
        }
        self.per_spring(step).add_hessian(step, x, curvature, sink);
    }

    /// Whether a term gives exact contact blocks that differ from their projections at
    /// its current active set ([`Term::gives_exact_contact`]).
    #[must_use]
    pub fn gives_exact_contact(&self) -> bool {
        self.terms.iter().any(|t| t.gives_exact_contact())
    }

    /// The smallest of the terms' [`Term::max_step`] (looking as far as `reach`).
    #[must_use]
    pub fn max_step(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], reach: f64) -> f64 {
        self.terms
            .iter()
            .map(|t| t.max_step(step, x, dx, reach))
            .fold(f64::INFINITY, f64::min)
    }

    /// The first term's [`Term::first_swept_pass`] at `x`, if any.
    #[must_use]
    pub fn first_swept_pass(&self, step: &StepContext<'_>, x: &[DVec3]) -> Option<(usize, usize)> {
        self.terms.iter().find_map(|t| t.first_swept_pass(step, x))
    }

    /// Whether a term's prescribed motion does work on the system ([`Term::does_work`]).
    #[must_use]
    pub fn does_work(&self) -> bool {
        self.terms.iter().any(|t| t.does_work())
    }

    /// Whether a term wants a thread pool whatever the system's size
    /// ([`Term::wants_threads`]).
    #[must_use]
    pub fn wants_threads(&self) -> bool {
        self.terms.iter().any(|t| t.wants_threads())
    }
}

/// The backward Euler incremental potential of a step of length `h` from `system`'s
/// state, evaluated at `x` by the terms of [`Potential::mass_spring`] (`y = x_n + h v_n`,
/// damping directions and reference at `x_n`). Allocates; for tests and checks.
#[must_use]
pub fn incremental_potential(system: &SpringSystem, h: f64, x: &[DVec3]) -> f64 {
    let x_ref = system.positions();
    let y: Vec<DVec3> = x_ref
        .iter()
        .zip(system.velocities())
        .zip(system.fixed())
        .map(|((&p, &v), &fixed)| if fixed { p } else { p + h * v })
        .collect();
    let step = StepContext::new(system, h, &y, x_ref);
    let mut potential = Potential::mass_spring(system);
    potential.begin_step(&step);
    potential.energy(&step, x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ClothGrid;

    /// A damped 41 x 41 lab-pattern cloth (9 600 springs: three chunks of
    /// [`CHANGE_CHUNK`], the last one short) moved off its rest state, a step context
    /// whose prediction and reference differ from the positions (every term changes),
    /// the potential with its damping directions frozen, and a direction that is zero at
    /// the fixed particles.
    fn case() -> (SpringSystem, Vec<DVec3>, Vec<DVec3>, Vec<DVec3>) {
        let mut system =
            SpringSystem::cloth(&ClothGrid::lab_sized(41, 0.05).with_damping(0.2)).unwrap();
        let wave =
            |i: usize, f: f64| DVec3::new((f * i as f64).sin(), (1.3 * f * i as f64).cos(), 0.5);
        let x: Vec<DVec3> = system
            .positions()
            .iter()
            .enumerate()
            .map(|(i, p)| *p * 1.1 + 0.01 * wave(i, 0.7))
            .collect();
        let v = vec![DVec3::ZERO; x.len()];
        system.set_state(&x, &v).unwrap();
        let y: Vec<DVec3> = x
            .iter()
            .enumerate()
            .map(|(i, p)| *p + 0.02 * wave(i, 0.3))
            .collect();
        let x_ref: Vec<DVec3> = x
            .iter()
            .enumerate()
            .map(|(i, p)| *p - 0.01 * wave(i, 1.9))
            .collect();
        let dx: Vec<DVec3> = (0..x.len())
            .map(|i| {
                if system.fixed()[i] {
                    DVec3::ZERO
                } else {
                    0.003 * wave(i, 2.3)
                }
            })
            .collect();
        (system, y, x_ref, dx)
    }

    /// The paired evaluation gives each length's change bit for bit as a separate
    /// evaluation does, on the calling thread and on pools of two and three threads, and
    /// those are changes of `g` (checked against the difference of two energies); with a
    /// term that is not per particle among the others (a second damping term), the
    /// second length's other terms are left for [`Potential::second_change`].
    #[test]
    fn paired_energy_changes_are_the_single_ones_bit_for_bit() {
        let (system, y, x_ref, dx) = case();
        assert!(system.springs().len() > 2 * CHANGE_CHUNK);
        let x = system.positions();
        let step = StepContext::new(&system, 1.0 / 60.0, &y, &x_ref);
        let mut mass_spring = Potential::mass_spring(&system);
        let mut with_other = Potential::mass_spring(&system);
        with_other.push(Box::new(AxialDamping::new(&system)));
        for (potential, eager) in [(&mut mass_spring, true), (&mut with_other, false)] {
            potential.begin_step(&step);
            let potential = &*potential;
            assert!(potential.per_spring(&step).damping.is_some());
            assert_eq!(potential.pointwise_others.is_some(), eager);
            let mut partials = Vec::new();
            for alphas in [[1.0, 2.0], [0.5, 0.25], [1.0, 0.0]] {
                let single = alphas.map(|alpha| {
                    potential.energy_change_chunked(&step, x, &dx, alpha, false, &mut partials)
                });
                let pair = |par: bool, partials: &mut Vec<f64>| {
                    let (first, second) =
                        potential.energy_change_pair_chunked(&step, x, &dx, alphas, par, partials);
                    match second {
                        SecondChange::Others { others, .. } => {
                            assert_eq!(others.is_some(), eager);
                        }
                        SecondChange::Whole { .. } => panic!("the springs were not paired"),
                    }
                    [first, potential.second_change(&step, x, &dx, second)]
                };
                let paired = pair(false, &mut partials);
                assert_eq!(
                    single.map(f64::to_bits),
                    paired.map(f64::to_bits),
                    "{alphas:?}"
                );
                for (alpha, change) in alphas.into_iter().zip(single) {
                    let moved: Vec<DVec3> =
                        x.iter().zip(&dx).map(|(x, d)| *x + alpha * *d).collect();
                    let difference = potential.energy(&step, &moved) - potential.energy(&step, x);
                    let scale = potential.energy(&step, x).abs();
                    assert!(
                        (change - difference).abs() <= 1e-10 * scale,
                        "{alpha}: {change} against {difference}"
                    );
                    if alpha != 0.0 {
                        assert!(change.abs() > 1e-6 * scale, "{alpha}: {change}");
                    }
                }
                #[cfg(feature = "parallel")]
                for threads in [2, 3] {
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .unwrap();
                    let on_pool = pool.install(|| pair(true, &mut partials));
                    assert_eq!(
                        single.map(f64::to_bits),
                        on_pool.map(f64::to_bits),
                        "{threads}"
                    );
                }
            }
        }
    }
}
