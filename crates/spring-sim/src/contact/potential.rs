//! The contact energy of a whole system against a list of colliders, for one implicit
//! step: the barrier over every particle within `dhat` of a collider, the lagged friction
//! of the step's contacts, their gradient and PSD Hessian blocks, and the largest safe
//! line-search step (the time-of-impact cap).
//!
//! The colliders are posed once per step, at the step's end time, and held there through
//! the minimization (a kinematic collider is where it will be when the step's positions
//! are). Every evaluation sums over all particle-collider pairs within `dhat` at the
//! state it is given (no set is frozen between evaluations), so the energy, its gradient
//! and its Hessian are those of one function and the line search's decrease test is
//! exact. A broad phase skips a collider whose distance to the bounding box of the free
//! particles (for a step: of the segments they sweep) is at least `dhat`: a scene with
//! no particle near a collider pays one box test per collider per evaluation.
//!
//! `kappa` follows IPC's adaptive rule ([`super::barrier`]): it starts at
//! [`minimum_kappa`] on the first step, is set once to the balance of the other forces
//! at the contacts on the first step that begins in contact (clamped to 100 times the
//! minimum), and doubles (up to that cap) when an iterate's smallest contact distance is
//! below 1% of `dhat` and still falling.

use super::barrier::{
    AdaptiveKappa, balanced_kappa, barrier, barrier_change, barrier_first_derivative,
    barrier_second_derivative, minimum_kappa, point_barrier_gradient,
    point_barrier_projected_hessian,
};
use super::collider::{Collider, Drive, Shape, drive_in_list, validate_colliders};
use super::distance::{distance_change, distance_to, signed_distance};
use super::friction::FrictionContact;
use super::toi::{time_of_impact, time_of_impact_from};
use super::{ContactError, ContactSettings};
use crate::spring::outer;
use sinew_math::{DMat3, DVec3};

/// The contact energy of one system (see the module documentation).
#[derive(Clone, Debug)]
pub struct ContactPotential {
    colliders: Vec<Collider>,
    settings: ContactSettings,
    kappa: Option<AdaptiveKappa>,
    /// The current step's end time (the start of the next step).
    clock: f64,
    /// The current step's start time.
    step_start: f64,
    /// The colliders posed at the current step's end time.
    posed: Vec<Shape>,
    friction: Vec<(usize, FrictionContact)>,
    /// `kappa` before the last start of a step (`None` before the first), for
    /// [`Self::rewind_kappa`].
    kappa_before: Option<AdaptiveKappa>,
    /// The barrier pairs of the last iterate given to [`Self::update_kappa`].
    active: ActivePairs,
    /// The smallest distance (less the thickness) among them, `+inf` when none.
    active_min: f64,
}

/// The particle-collider pairs within `dhat` at one iterate, with the barrier's
/// derivatives at unit stiffness: Newton asks for the gradient and the Hessian at the
/// iterate it has just given to [`ContactPotential::update_kappa`], and both then come
/// from this list instead of another pass of distances and logarithms over every
/// particle. `kappa` is applied when they are read, so its growth at that update counts.
#[derive(Clone, Debug, Default)]
struct ActivePairs {
    /// The iterate (empty when none is cached).
    x: Vec<DVec3>,
    /// `(particle, unit normal, b'(d), b''(d))` for every pair with `0 < d < dhat`.
    pairs: Vec<(usize, DVec3, f64, f64)>,
}

/// One step as the contact potential sees it: its positions are the ones the barrier
/// constrains (the end-of-step positions), minimized with the effective step `h`.
#[derive(Clone, Copy, Debug)]
pub struct ContactStep<'a> {
    /// The positions at the step's start, `x_n` (friction is lagged there).
    pub positions: &'a [DVec3],
    /// The point friction's tangential displacement is measured from (`x_n` for backward
    /// Euler and for the midpoint's end state, `(4 x_n - x_{n-1})/3` for BDF2).
    pub anchor: &'a [DVec3],
    /// Which particles are fixed.
    pub fixed: &'a [bool],
    /// The particle masses (for the first `kappa`).
    pub masses: &'a [f64],
    /// Gravity's magnitude (for the first `kappa`).
    pub gravity: f64,
    /// The effective step over the constrained positions: the velocity is
    /// `(x - anchor)/h`, the inertia term's stiffness `m/h^2`.
    pub h: f64,
    /// The time at the step's start (friction's lag, the carry's start pose).
    pub start: f64,
    /// The time at the step's end (the colliders are posed there).
    pub end: f64,
    /// The gradient at `positions` of the forces the barrier is to balance (the
    /// integrators' contact term gives gravity and the springs), per particle and in the
    /// constrained positions, for IPC's
    /// balancing start of `kappa` ([`super::barrier::balanced_kappa`], applied on the
    /// first step that starts in contact); `None` leaves `kappa` to its other rules.
    pub other_gradient: Option<&'a [DVec3]>,
}

impl ContactPotential {
    /// A contact potential for `colliders` (validated; the error names the collider) with
    /// `settings` (validated; the error names the setting), starting at time `start_time`.
    pub fn new(
        colliders: Vec<Collider>,
        settings: ContactSettings,
        start_time: f64,
    ) -> Result<Self, ContactError> {
        validate_colliders(&colliders)?;
        settings.validate()?;
        if !start_time.is_finite() {
            return ContactError::bad_setting("start_time", start_time, "must be finite");
        }
        let posed = colliders.iter().map(|c| c.at(start_time)).collect();
        Ok(Self {
            colliders,
            settings,
            kappa: None,
            clock: start_time,
            step_start: start_time,
            posed,
            friction: Vec::new(),
            kappa_before: None,
            active: ActivePairs::default(),
            active_min: f64::INFINITY,
        })
    }

    /// The colliders.
    #[must_use]
    pub fn colliders(&self) -> &[Collider] {
        &self.colliders
    }

    /// The settings.
    #[must_use]
    pub fn settings(&self) -> &ContactSettings {
        &self.settings
    }

    /// Drives collider `index` from `time` on ([`Collider::driven`]: its pose at `time`
    /// kept, its motion changed) and returns it. Call it between steps, with the time
    /// the next step starts at; that step poses the collider along its new motion.
    ///
    /// # Errors
    /// [`ContactError::NoSuchCollider`] for an index out of range, and the errors of
    /// [`Collider::driven`] naming the index; the potential is then unchanged.
    pub fn drive_collider(
        &mut self,
        index: usize,
        time: f64,
        drive: &Drive,
    ) -> Result<Collider, ContactError> {
        let driven = drive_in_list(&mut self.colliders, index, time, drive)?;
        self.put_driven(index, driven);
        Ok(driven)
    }

    /// Puts `driven` (collider `index` driven already, [`Collider::driven`]) in place of
    /// collider `index`, which must exist: for a caller that drove its own copy of the
    /// list.
    pub(crate) fn put_driven(&mut self, index: usize, driven: Collider) {
        self.colliders[index] = driven;
        self.posed[index] = driven.at(self.clock);
        // Pairs collected against the old pose are stale.
        self.active.x.clear();
    }

    /// The current barrier stiffness (0 before the first step).
    #[must_use]
    pub fn kappa(&self) -> f64 {
        self.kappa.map_or(0.0, |k| k.kappa)
    }

    /// Whether the balancing start of `kappa` is still to come (see
    /// [`ContactStep::other_gradient`]): a caller may skip computing the other gradient
    /// when it is not.
    #[must_use]
    pub fn awaits_balance(&self) -> bool {
        self.kappa.is_none_or(|k| !k.balanced)
    }

    /// The time the colliders are posed at (the current step's end).
    #[must_use]
    pub fn time(&self) -> f64 {
        self.clock
    }

    /// The colliders posed at [`Self::time`].
    #[must_use]
    pub fn posed(&self) -> &[Shape] {
        &self.posed
    }

    /// The number of lagged friction contacts of the current step.
    #[must_use]
    pub fn friction_contacts(&self) -> usize {
        self.friction.len()
    }

    /// The number of particle-collider pairs within `dhat` (distance less the thickness
    /// in `(0, dhat)`) at the last iterate given to [`Self::update_kappa`] (a Newton
    /// iteration's start).
    #[must_use]
    pub fn active_pairs(&self) -> usize {
        self.active.pairs.len()
    }

    /// The smallest distance (less the thickness) among those pairs, `+inf` when none.
    #[must_use]
    pub fn active_min_distance(&self) -> f64 {
        self.active_min
    }

    /// Starts a step of length `h` from `positions` (the state at the step's start) at
    /// the potential's own time ([`Self::time`], advanced by `h`): backward Euler's
    /// [`ContactStep`] with the anchor at the start state (see [`Self::begin`]).
    pub fn begin_step(
        &mut self,
        positions: &[DVec3],
        fixed: &[bool],
        masses: &[f64],
        gravity: f64,
        h: f64,
    ) {
        let start = self.clock;
        self.begin(&ContactStep {
            positions,
            anchor: positions,
            fixed,
            masses,
            gravity,
            h,
            start,
            end: start + h,
            other_gradient: None,
        });
    }

    /// Starts the step `step`: sets `kappa_min` on the first step (from the mean free
    /// mass, gravity's magnitude, `step.h` and `dhat`), on the first step that starts
    /// with a free particle within `dhat` of a collider sets `kappa` from IPC's balance
    /// of the other forces there when `step.other_gradient` is given (see
    /// [`AdaptiveKappa::start_balanced`]), lags the friction contacts at
    /// `step.positions` and `step.start` with their displacement measured from
    /// `step.anchor` over `step.h`, and poses the colliders at `step.end`. The times are
    /// inputs, so a step redone (in pieces) poses the colliders again from its own start.
    pub fn begin(&mut self, step: &ContactStep<'_>) {
        let (positions, fixed, h) = (step.positions, step.fixed, step.h);
        self.kappa_before = self.kappa;
        // The colliders are posed anew: pairs collected in an earlier step are stale.
        self.active.x.clear();
        let kappa = *self.kappa.get_or_insert_with(|| {
            let (sum, count) = step
                .masses
                .iter()
                .zip(fixed)
                .filter(|(_, f)| !**f)
                .fold((0.0, 0usize), |(s, c), (m, _)| (s + m, c + 1));
            let mean = if count > 0 { sum / count as f64 } else { 1.0 };
            let kmin = minimum_kappa(self.settings.dhat, mean, step.gravity, h);
            AdaptiveKappa::new(kmin, None, self.settings.kappa)
        });
        let start = step.start;
        let kappa = match step.other_gradient {
            Some(other) if !kappa.balanced => {
                let balanced = self.balanced_kappa(positions, fixed, start, other);
                let k = self.kappa.as_mut().expect("set above");
                if let Some(b) = balanced {
                    k.start_balanced(b);
                }
                *k
            }
            _ => kappa,
        };
        self.lag_friction(positions, step.anchor, fixed, start, h, kappa.kappa);
        self.step_start = start;
        self.clock = step.end;
        self.posed = self.colliders.iter().map(|c| c.at(self.clock)).collect();
    }

    /// Lags the friction of every free particle at `positions` within `dhat` of a
    /// collider posed at time `t` (see [`FrictionContact::lagged`]) with stiffness
    /// `kappa`, each contact's displacement over a step of `h` measured from its
    /// particle's `anchor`; none when `mu` is 0.
    fn lag_friction(
        &mut self,
        positions: &[DVec3],
        anchor: &[DVec3],
        fixed: &[bool],
        t: f64,
        h: f64,
        kappa: f64,
    ) {
        self.friction.clear();
        if self.settings.mu == 0.0 {
            return;
        }
        for collider in &self.colliders {
            let shape = collider.at(t);
            if box_distance(&shape, &free_box(positions, fixed, None))
                >= self.settings.dhat + self.settings.thickness
            {
                continue;
            }
            for (i, &x) in positions.iter().enumerate() {
                if fixed[i] {
                    continue;
                }
                let lagged =
                    FrictionContact::lagged_posed(collider, &shape, x, t, h, kappa, &self.settings);
                if let Some(mut contact) = lagged {
                    // The lag point (normal, force, basis) is `positions`; the
                    // displacement is measured from the scheme's reference point.
                    contact.start = anchor[i];
                    self.friction.push((i, contact));
                }
            }
        }
    }

    /// Lags the friction again at the end state `positions` of the current step's
    /// minimizer, against the colliders posed at the step's end (their surface
    /// velocities taken there), with the current `kappa`: the contacts within `dhat` at
    /// `positions` and their normal forces, normals and bases, the displacements still
    /// measured from `anchor` over `h` (as [`Self::begin`] was given). Returns whether any
    /// particle is in friction (see [`crate::NewtonSettings::friction_lags`]).
    pub fn relag_friction(
        &mut self,
        positions: &[DVec3],
        anchor: &[DVec3],
        fixed: &[bool],
        h: f64,
    ) -> bool {
        let kappa = self.kappa();
        if kappa == 0.0 {
            self.friction.clear();
            return false;
        }
        self.lag_friction(positions, anchor, fixed, self.clock, h, kappa);
        !self.friction.is_empty()
    }

    /// IPC's balancing stiffness at `x` (colliders posed at `t`): the `kappa` that
    /// minimizes `|g_E + kappa g_B|` over the free particles within `dhat` of a collider,
    /// `g_B` the barrier's gradient at unit stiffness; `None` when no free particle is
    /// within `dhat` or the other forces pull away from the colliders.
    fn balanced_kappa(&self, x: &[DVec3], fixed: &[bool], t: f64, other: &[DVec3]) -> Option<f64> {
        let dhat = self.settings.dhat;
        let reach = dhat + self.settings.thickness;
        let bounds = free_box(x, fixed, None);
        let mut unit = vec![DVec3::ZERO; x.len()];
        let mut any = false;
        for collider in &self.colliders {
            let shape = collider.at(t);
            if box_distance(&shape, &bounds) >= reach {
                continue;
            }
            for (i, &p) in x.iter().enumerate() {
                if fixed[i] {
                    continue;
                }
                let sd = signed_distance(&shape, p, self.settings.thickness);
                if sd.distance > 0.0 && sd.distance < dhat {
                    unit[i] += barrier_first_derivative(sd.distance, dhat) * sd.normal;
                    any = true;
                }
            }
        }
        if !any {
            return None;
        }
        balanced_kappa(other, &unit)
    }

    /// Puts `kappa` back to its value before the last [`Self::begin`], for a step that
    /// is abandoned and redone: neither its growth during the abandoned solve nor, on the
    /// first step, its minimum (computed from the abandoned step's length) is kept.
    pub fn rewind_kappa(&mut self) {
        self.kappa = self.kappa_before;
    }

    /// [`carry_with_colliders`] for the current step (from the time of the last
    /// [`Self::begin_step`] to [`Self::time`]).
    pub fn prepare_start(
        &self,
        x_n: &[DVec3],
        fixed: &[bool],
        x: &mut [DVec3],
    ) -> Result<(), (usize, usize)> {
        carry_with_colliders(
            &self.colliders,
            &self.settings,
            self.step_start,
            self.clock,
            x_n,
            fixed,
            x,
        )
    }

    /// The colliders not culled by the broad phase for the box `bounds` (plus the
    /// thickness and `dhat`).
    fn near<'a>(&'a self, bounds: &'a Bounds) -> impl Iterator<Item = &'a Shape> + 'a {
        let reach = self.settings.dhat + self.settings.thickness;
        self.posed
            .iter()
            .filter(move |s| box_distance(s, bounds) < reach)
    }

    /// `visit(i, shape, x[i])` for every free particle `i` and every collider
    /// [`Self::near`] keeps for the free particles' box at `x`: collider by collider, the
    /// particles in order within each, the order every sum and minimum over the pairs is
    /// taken in.
    fn for_each_near_free(
        &self,
        x: &[DVec3],
        fixed: &[bool],
        mut visit: impl FnMut(usize, &Shape, DVec3),
    ) {
        let bounds = free_box(x, fixed, None);
        for shape in self.near(&bounds) {
            for (i, &p) in x.iter().enumerate() {
                if !fixed[i] {
                    visit(i, shape, p);
                }
            }
        }
    }

    /// The smallest distance (minus the thickness) from a free particle to a collider,
    /// `+inf` when none is within `dhat` (or there are no colliders).
    #[must_use]
    pub fn min_distance(&self, x: &[DVec3], fixed: &[bool]) -> f64 {
        let mut min = f64::INFINITY;
        self.for_each_near_free(x, fixed, |_, shape, p| {
            min = min.min(distance_to(shape, p, self.settings.thickness));
        });
        if min < self.settings.dhat {
            min
        } else {
            f64::INFINITY
        }
    }

    /// Adapts `kappa` to the iterate `x` (IPC's rule, see [`AdaptiveKappa::update`]) and
    /// collects the pairs within `dhat` there, which the gradient and the Hessian at the
    /// same `x` reuse; returns whether `kappa` grew.
    pub fn update_kappa(&mut self, x: &[DVec3], fixed: &[bool]) -> bool {
        let dhat = self.settings.dhat;
        let tau = self.settings.thickness;
        let mut active = std::mem::take(&mut self.active);
        active.x.clear();
        active.x.extend_from_slice(x);
        active.pairs.clear();
        let mut min = f64::INFINITY;
        self.for_each_near_free(x, fixed, |i, shape, p| {
            let sd = signed_distance(shape, p, tau);
            min = min.min(sd.distance);
            if sd.distance > 0.0 && sd.distance < dhat {
                active.pairs.push((
                    i,
                    sd.normal,
                    barrier_first_derivative(sd.distance, dhat),
                    barrier_second_derivative(sd.distance, dhat),
                ));
            }
        });
        self.active = active;
        let d = if min < dhat { min } else { f64::INFINITY };
        self.active_min = d;
        self.kappa.as_mut().is_some_and(|k| k.update(d, dhat))
    }

    /// The pairs collected at `x` by the last [`Self::update_kappa`], if it was given
    /// this very iterate.
    fn active_at(&self, x: &[DVec3]) -> Option<&[(usize, DVec3, f64, f64)]> {
        (!self.active.x.is_empty() && self.active.x.as_slice() == x)
            .then_some(self.active.pairs.as_slice())
    }

    /// The first free particle at distance `<= 0` from a collider (touching or inside)
    /// and that collider's index, if any.
    #[must_use]
    pub fn first_penetration(&self, x: &[DVec3], fixed: &[bool]) -> Option<(usize, usize)> {
        let bounds = free_box(x, fixed, None);
        let reach = self.settings.dhat + self.settings.thickness;
        for (c, shape) in self.posed.iter().enumerate() {
            if box_distance(shape, &bounds) >= reach {
                continue;
            }
            for (i, &p) in x.iter().enumerate() {
                if !fixed[i] && distance_to(shape, p, self.settings.thickness) <= 0.0 {
                    return Some((i, c));
                }
            }
        }
        None
    }

    /// The barrier energy alone at `x` (`+inf` if a free particle touches or is inside a
    /// collider).
    #[must_use]
    pub fn barrier_energy(&self, x: &[DVec3], fixed: &[bool]) -> f64 {
        let Some(kappa) = self.kappa else {
            return 0.0;
        };
        let mut e = 0.0;
        self.for_each_near_free(x, fixed, |_, shape, p| {
            let d = distance_to(shape, p, self.settings.thickness);
            e += kappa.kappa * barrier(d, self.settings.dhat);
        });
        e
    }

    /// The friction energy alone at `x`.
    #[must_use]
    pub fn friction_energy(&self, x: &[DVec3]) -> f64 {
        self.friction.iter().map(|(i, c)| c.energy(x[*i])).sum()
    }

    /// Barrier plus friction energy at `x`.
    #[must_use]
    pub fn energy(&self, x: &[DVec3], fixed: &[bool]) -> f64 {
        self.barrier_energy(x, fixed) + self.friction_energy(x)
    }

    /// `E(x + alpha dx) - E(x)`, summed pair by pair (each pair's barrier difference and
    /// each contact's friction difference), so it keeps the accuracy of the small changes
    /// near convergence; `+inf` if the new state touches a collider.
    #[must_use]
    pub fn energy_change(&self, x: &[DVec3], dx: &[DVec3], alpha: f64, fixed: &[bool]) -> f64 {
        let mut change = 0.0;
        if let Some(kappa) = self.kappa {
            let bounds = free_box(x, fixed, Some((dx, alpha)));
            let dhat = self.settings.dhat;
            for shape in self.near(&bounds) {
                for (i, &p) in x.iter().enumerate() {
                    if fixed[i] {
                        continue;
                    }
                    let (d0, dd) =
                        distance_change(shape, p, alpha * dx[i], self.settings.thickness);
                    let d1 = d0 + dd;
                    if d1 <= 0.0 {
                        return f64::INFINITY;
                    }
                    if d0 < dhat || d1 < dhat {
                        change += kappa.kappa * barrier_change(d0, dd, dhat);
                    }
                }
            }
        }
        for (i, c) in &self.friction {
            change += c.energy_change(x[*i], alpha * dx[*i]);
        }
        change
    }

    /// Adds the gradient at `x` (one entry per particle; fixed particles get nothing).
    pub fn add_gradient(&self, x: &[DVec3], fixed: &[bool], gradient: &mut [DVec3]) {
        self.add_gradient_scaled(x, fixed, 1.0, gradient);
    }

    /// Adds `scale` times the gradient at `x` (the chain rule's factor when `x` is an
    /// affine function of the unknowns, as the midpoint's end state is).
    pub fn add_gradient_scaled(
        &self,
        x: &[DVec3],
        fixed: &[bool],
        scale: f64,
        gradient: &mut [DVec3],
    ) {
        if let (Some(kappa), Some(pairs)) = (self.kappa, self.active_at(x)) {
            for &(i, n, b1, _) in pairs {
                gradient[i] += scale * (kappa.kappa * b1 * n);
            }
        } else if let Some(kappa) = self.kappa {
            self.for_each_near_free(x, fixed, |i, shape, p| {
                let sd = signed_distance(shape, p, self.settings.thickness);
                // A particle touching or inside (never the case at an admissible state,
                // whose energy is finite) adds nothing, as before.
                if sd.distance < self.settings.dhat
                    && let Some(g) = point_barrier_gradient(kappa.kappa, self.settings.dhat, &sd)
                {
                    gradient[i] += scale * g;
                }
            });
        }
        for (i, c) in &self.friction {
            if !fixed[*i] {
                gradient[*i] += scale * c.gradient(x[*i]);
            }
        }
    }

    /// Gives every PSD-projected diagonal block `(i, H_ii)` of the Hessian at `x` to
    /// `add` (contact with a rigid collider couples no two particles, so every block is
    /// diagonal; a particle may get several blocks).
    pub fn for_each_hessian_block(
        &self,
        x: &[DVec3],
        fixed: &[bool],
        mut add: impl FnMut(usize, DMat3),
    ) {
        if let (Some(kappa), Some(pairs)) = (self.kappa, self.active_at(x)) {
            for &(i, n, _, b2) in pairs {
                add(i, outer(n) * (kappa.kappa * b2));
            }
        } else if let Some(kappa) = self.kappa {
            self.for_each_near_free(x, fixed, |i, shape, p| {
                let sd = signed_distance(shape, p, self.settings.thickness);
                if sd.distance > 0.0 && sd.distance < self.settings.dhat {
                    add(
                        i,
                        point_barrier_projected_hessian(kappa.kappa, self.settings.dhat, &sd),
                    );
                }
            });
        }
        for (i, c) in &self.friction {
            if !fixed[*i] {
                add(*i, c.hessian(x[*i]));
            }
        }
    }

    /// The largest `alpha` in `[0, horizon]` such that on `x + [0, alpha] dx` no free
    /// particle comes closer to a (posed) collider than `(1 - s)` of its distance at `x`
    /// ([`time_of_impact`] along `horizon dx`, with the colliders held at the step's
    /// end); `horizon` itself when nothing comes that close. `horizon` is the longest
    /// step the caller may try (1 for a plain Newton step; more for a line search that
    /// lengthens accepted steps). Particles whose swept segment stays `dhat` away from a
    /// collider are skipped: they stay farther than `dhat > 0` from it.
    #[must_use]
    pub fn max_step(&self, x: &[DVec3], dx: &[DVec3], fixed: &[bool], horizon: f64) -> f64 {
        let bounds = free_box(x, fixed, Some((dx, horizon)));
        let reach = self.settings.dhat + self.settings.thickness;
        let mut alpha: f64 = 1.0;
        for shape in self.near(&bounds) {
            let still = Collider::fixed(*shape);
            for (i, &p) in x.iter().enumerate() {
                if fixed[i] {
                    continue;
                }
                let sweep = horizon * dx[i];
                if box_distance(shape, &Bounds::of_segment(p, sweep)) >= reach {
                    continue;
                }
                let a = time_of_impact(
                    &still,
                    p,
                    sweep,
                    0.0,
                    0.0,
                    self.settings.thickness,
                    self.settings.toi_fraction,
                );
                alpha = alpha.min(a);
            }
        }
        alpha * horizon
    }

    /// The first free particle, and the index of the collider, for which the particle's
    /// straight path from `x_n` (the step's start) to `x` (its end) goes deeper than
    /// [`swept_allowance`] into a collider whose surface moves
    /// ([`Collider::moves_surface`]), the collider following its motion from the step's
    /// start time to its end time along the path. The minimization sees the colliders
    /// posed at the step's end only, so a collider that travels about its own size in
    /// a step can pass a particle that ends outside it; the integrators split such a
    /// step (docs/contact.md, "A kinematic collider passing the cloth within a step").
    /// Static colliders and colliders whose motion leaves their surface in place are
    /// not checked: a particle cannot be passed by a surface that stays where it is
    /// (the line search's iterates go around such a collider, never through it).
    #[must_use]
    pub fn first_swept_pass(
        &self,
        x_n: &[DVec3],
        x: &[DVec3],
        fixed: &[bool],
    ) -> Option<(usize, usize)> {
        let (t0, t1) = (self.step_start, self.clock);
        for (c, collider) in self.colliders.iter().enumerate() {
            if !collider.moves_surface() {
                continue;
            }
            // The path is measured against the collider shrunk by the allowance: a
            // particle sliding along a moving curved surface cuts its chords by the
            // sagitta, which is no pass.
            let inset =
                self.settings.thickness - swept_allowance(&collider.shape, self.settings.dhat);
            // Posed once for all the particles.
            let start = collider.at(t0);
            for (i, (&p, &q)) in x_n.iter().zip(x).enumerate() {
                if fixed[i] {
                    continue;
                }
                // The fraction 1 asks for the first time the distance reaches 0.
                let alpha = time_of_impact_from(collider, &start, p, q - p, (t0, t1), inset, 1.0);
                if alpha < 1.0 {
                    return Some((i, c));
                }
            }
        }
        None
    }
}

/// How deep a particle's straight path between two states may go into a moving
/// collider before the step counts as passing through it
/// ([`ContactPotential::first_swept_pass`]): `dhat`, at most half the collider's radius
/// (so the shrunk shape stays a shape).
#[must_use]
pub fn swept_allowance(shape: &Shape, dhat: f64) -> f64 {
    match *shape {
        Shape::HalfSpace { .. } => dhat,
        Shape::Sphere { radius, .. } | Shape::Capsule { radius, .. } => dhat.min(0.5 * radius),
    }
}

/// Moves a first iterate `x` so that the kinematic colliders do not run over it: with the
/// colliders moving from their poses at `t0` to those at `t1`, a free particle whose
/// distance at `x` to a collider posed at `t1` is below half of `min(d_0, dhat)` (`d_0`
/// its distance at the step's start `x_n` to the collider posed at `t0`) is put at its
/// start position carried by that collider's rigid motion from `t0` to `t1`, which keeps
/// exactly its distance `d_0 > 0` to that collider. A collider whose motion leaves its
/// surface in place (a sphere spinning about its centre) never triggers it, since it
/// does not change the distance.
///
/// When two colliders close in on a particle within the step, the carry by one may
/// leave it inside the other. Such a particle is then pushed out of the colliders posed
/// at `t1` in turn, each push along the collider's normal to a target distance (the
/// target halved when the pushes do not settle), which finds a point outside all of
/// them while they leave room between them. Returns the first free particle for which no such point was found,
/// with the index of a collider it is still inside (the colliders overlap where it is,
/// or leave a gap too thin for the search).
#[allow(clippy::too_many_arguments)]
pub fn carry_with_colliders(
    colliders: &[Collider],
    settings: &ContactSettings,
    t0: f64,
    t1: f64,
    x_n: &[DVec3],
    fixed: &[bool],
    x: &mut [DVec3],
) -> Result<(), (usize, usize)> {
    let tau = settings.thickness;
    for collider in colliders.iter().filter(|c| !c.is_static()) {
        let (start, end) = (collider.at(t0), collider.at(t1));
        let (r0, r1) = (
            collider.reference_point_at(t0),
            collider.reference_point_at(t1),
        );
        let turn = collider.rotation_at(t1) * collider.rotation_at(t0).inverse();
        for i in 0..x.len() {
            if fixed[i] {
                continue;
            }
            let d_end = distance_to(&end, x[i], tau);
            if d_end >= settings.dhat {
                continue;
            }
            let d_start = distance_to(&start, x_n[i], tau);
            if d_start > 0.0 && d_end < 0.5 * d_start.min(settings.dhat) {
                x[i] = r1 + turn * (x_n[i] - r0);
            }
        }
    }
    let shapes: Vec<Shape> = colliders.iter().map(|c| c.at(t1)).collect();
    for i in 0..x.len() {
        if fixed[i] {
            continue;
        }
        if shapes.iter().all(|s| distance_to(s, x[i], tau) > 0.0) {
            continue;
        }
        x[i] = separate(&shapes, x[i], tau, settings.dhat).map_err(|c| (i, c))?;
    }
    Ok(())
}

/// Passes of pushes per target distance in [`separate`].
const SEPARATION_PASSES: usize = 32;
/// Halvings of the target distance in [`separate`] (from `dhat / 2` down to about
/// `1e-6 dhat`).
const SEPARATION_HALVINGS: usize = 20;

/// A point outside every shape (distance minus `thickness` positive to each), found from
/// `x` by pushes: each pass moves the point, for every shape it is closer to than the
/// target `m`, along that shape's normal to distance `m`. Between two convex colliders
/// facing each other across a gap wider than `2 m` (a sphere coming down on the ground,
/// a press on a table) a pass or two ends outside both. When passes do not settle, the
/// target is halved (the gap may be narrower than `2 m`) and the pushes restart from
/// `x`. Returns the index of a shape the point is still inside when every target
/// fails: the colliders overlap there, or the gap is too thin to be found this way.
fn separate(shapes: &[Shape], x: DVec3, thickness: f64, dhat: f64) -> Result<DVec3, usize> {
    let mut target = 0.5 * dhat;
    for _ in 0..SEPARATION_HALVINGS {
        let mut p = x;
        for _ in 0..SEPARATION_PASSES {
            let mut moved = false;
            for shape in shapes {
                let sd = signed_distance(shape, p, thickness);
                if sd.distance < target {
                    p += (target - sd.distance) * sd.normal;
                    moved = true;
                }
            }
            if !moved {
                break;
            }
        }
        if shapes.iter().all(|s| distance_to(s, p, thickness) > 0.0) {
            return Ok(p);
        }
        target *= 0.5;
    }
    Err(shapes
        .iter()
        .position(|s| distance_to(s, x, thickness) <= 0.0)
        .unwrap_or(0))
}

/// An axis-aligned box (empty when `min > max`).
#[derive(Clone, Copy, Debug)]
struct Bounds {
    min: DVec3,
    max: DVec3,
}

impl Bounds {
    const EMPTY: Self = Self {
        min: DVec3::INFINITY,
        max: DVec3::NEG_INFINITY,
    };

    fn of_segment(p: DVec3, dp: DVec3) -> Self {
        Self {
            min: p.min(p + dp),
            max: p.max(p + dp),
        }
    }

    fn is_empty(&self) -> bool {
        self.min.x > self.max.x
    }
}

/// The box around the free particles, or around the segments `x + [0, alpha] dx` they
/// sweep.
fn free_box(x: &[DVec3], fixed: &[bool], step: Option<(&[DVec3], f64)>) -> Bounds {
    let mut b = Bounds::EMPTY;
    for (i, &p) in x.iter().enumerate() {
        if fixed[i] {
            continue;
        }
        b.min = b.min.min(p);
        b.max = b.max.max(p);
        if let Some((dx, alpha)) = step {
            let q = p + alpha * dx[i];
            b.min = b.min.min(q);
            b.max = b.max.max(q);
        }
    }
    b
}

/// A lower bound on the signed distance from any point of `bounds` to `shape` (`+inf`
/// for an empty box).
fn box_distance(shape: &Shape, bounds: &Bounds) -> f64 {
    if bounds.is_empty() {
        return f64::INFINITY;
    }
    let gap = |lo: DVec3, hi: DVec3| {
        // Distance between two boxes (0 when they overlap).
        let d = (lo - bounds.max).max(bounds.min - hi).max(DVec3::ZERO);
        d.length()
    };
    match *shape {
        Shape::HalfSpace { point, normal } => {
            // The minimum of a linear function over a box is at the corner the normal
            // points away from.
            let corner = DVec3::select(normal.cmpge(DVec3::ZERO), bounds.min, bounds.max);
            normal.dot(corner - point)
        }
        Shape::Sphere { center, radius } => gap(center, center) - radius,
        Shape::Capsule { a, b, radius } => gap(a.min(b), a.max(b)) - radius,
    }
}
