//! Kinematic (prescribed) pinned particles: cloth held by handles that move.
//!
//! A pinned particle is not an unknown of the implicit integrators; by default it stays
//! where it is. Here the user prescribes where pinned particles are at the end of each
//! step, either as positions ([`step_to_targets`]) or as rigid motions of pinned groups
//! ([`PinnedMotion`]: a rotation about an axis through a point at a constant rate plus
//! a constant translation, driven by [`PinDriver`]). A step then
//!
//! 1. checks the targets (each particle exists, is pinned, appears once, and its target
//!    is finite; the error names the particle);
//! 2. asks the integrator's terms for the largest safe fraction of the *pinned-only*
//!    move (the pinned particles going from their start to their end positions with the
//!    free particles held): self-contact answers with its continuous collision
//!    detection, capped so a tenth of every gap is kept;
//! 3. if the whole move is safe, puts the pinned particles at their targets with the
//!    velocity of that move, `(target - start) / h`, and takes the integrator's step,
//!    which starts from that admissible state; the pinned velocity is what damping sees
//!    and what the kinetic energy reports;
//! 4. otherwise cuts the step into two halves of the prescribed motion (a rigid motion
//!    is evaluated at the half time; given positions are interpolated linearly), the
//!    free particles responding between them, recursively up to
//!    [`PinDriver::max_split_depth`] times; when even the smallest piece is not safe the
//!    step is refused with [`StepError::PinnedMove`] and nothing changes.
//!
//! Colliders act on free particles only (a pinned particle is where the user puts it),
//! so only self-contact constrains the move. The derivation and the scheme details are in
//! docs/self-contact.md, "Moving pins".

use crate::implicit::{Bdf2, ImplicitMidpoint};
use crate::model::{ModelError, SpringSystem};
use crate::newton::BackwardEuler;
use crate::potential::{StepContext, StepTiming};
use crate::report::{StepError, StepReport};
use sinew_math::{DQuat, DVec3};

/// A rigid motion of a group of pinned particles: at time `t` (seconds since the motion
/// started) a particle that was at `r` is at
/// `point + R(axis, angular_speed t) (r - point) + velocity t`, a rotation about the axis
/// through `point` followed by a translation.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct PinnedMotion {
    /// The pinned particles that move together.
    pub particles: Vec<usize>,
    /// A point on the rotation axis (default the origin).
    #[cfg_attr(feature = "serde", serde(default))]
    pub point: DVec3,
    /// The rotation axis (any length but zero; default +x). The rotation is
    /// counterclockwise about it for a positive `angular_speed`.
    #[cfg_attr(feature = "serde", serde(default = "x_axis"))]
    pub axis: DVec3,
    /// Rotation rate, rad/s (default 0).
    #[cfg_attr(feature = "serde", serde(default))]
    pub angular_speed: f64,
    /// Translation velocity, m/s (default zero).
    #[cfg_attr(feature = "serde", serde(default))]
    pub velocity: DVec3,
}

#[cfg(feature = "serde")]
fn x_axis() -> DVec3 {
    DVec3::X
}

impl PinnedMotion {
    /// A rotation of `particles` about the axis through `point` along `axis` at
    /// `angular_speed` rad/s, without translation.
    #[must_use]
    pub fn rotation(particles: Vec<usize>, point: DVec3, axis: DVec3, angular_speed: f64) -> Self {
        Self {
            particles,
            point,
            axis,
            angular_speed,
            velocity: DVec3::ZERO,
        }
    }

    /// A translation of `particles` at `velocity`.
    #[must_use]
    pub fn translation(particles: Vec<usize>, velocity: DVec3) -> Self {
        Self {
            particles,
            point: DVec3::ZERO,
            axis: DVec3::X,
            angular_speed: 0.0,
            velocity,
        }
    }

    /// Where a particle that was at `reference` when the motion started is `t` seconds
    /// later.
    #[must_use]
    pub fn position(&self, reference: DVec3, t: f64) -> DVec3 {
        let turn = DQuat::from_axis_angle(self.axis.normalize(), self.angular_speed * t);
        self.point + turn * (reference - self.point) + self.velocity * t
    }

    /// Checks the motion's own fields (at least one particle; point, velocity and rate
    /// finite; axis finite and not zero); the error names the group's first particle (or
    /// `usize::MAX` for a group without particles). Whether the particles exist and are
    /// pinned is checked against a system by [`PinDriver::new`].
    pub fn validate(&self) -> Result<(), ModelError> {
        let particle = self.particles.first().copied().unwrap_or(usize::MAX);
        let bad = |reason| Err(ModelError::BadPin { particle, reason });
        if self.particles.is_empty() {
            return bad("a pinned motion needs at least one particle");
        }
        if !(self.point.is_finite() && self.velocity.is_finite()) {
            return bad("the motion's point or velocity is not finite");
        }
        if !self.angular_speed.is_finite() {
            return bad("the motion's angular_speed is not finite");
        }
        let len = self.axis.length();
        if !(len.is_finite() && len > 0.0) {
            return bad("the motion's axis is zero or not finite");
        }
        Ok(())
    }
}

/// Checks that every particle of `particles` exists in `system`, is pinned and appears
/// once; the error names the particle.
fn check_members(
    system: &SpringSystem,
    particles: impl IntoIterator<Item = usize>,
) -> Result<(), ModelError> {
    let mut seen = vec![false; system.len()];
    for i in particles {
        if i >= system.len() {
            return Err(ModelError::BadPin {
                particle: i,
                reason: "no such particle",
            });
        }
        if !system.fixed()[i] {
            return Err(ModelError::BadPin {
                particle: i,
                reason: "the particle is not pinned (only pinned particles can be moved)",
            });
        }
        if std::mem::replace(&mut seen[i], true) {
            return Err(ModelError::BadPin {
                particle: i,
                reason: "the particle is given twice",
            });
        }
    }
    Ok(())
}

/// An implicit integrator that can take a step with moving pins: its Newton workspace
/// answers the safe-move question, and it steps.
pub trait PinnedStepper {
    /// The Newton workspace (its terms check the pinned move).
    fn newton(&self) -> &BackwardEuler;
    /// The Newton workspace, to add terms before stepping (contact, self-contact).
    fn newton_mut(&mut self) -> &mut BackwardEuler;
    /// Marks the start of a step taken as several calls to [`Self::take_step`] (pieces of
    /// the pinned motion): the step's records ([`BackwardEuler::piece_ends`],
    /// [`BackwardEuler::step_objective_traces`]) span the calls. Nothing by default.
    fn begin_joined_step(&mut self) {}
    /// Marks its end; a refused step (`refused`) leaves no records. Nothing by default.
    fn end_joined_step(&mut self, refused: bool) {
        let _ = refused;
    }
    /// The time the next step starts at.
    fn time(&self) -> f64 {
        self.newton().time()
    }
    /// Sets the time the next step starts at (to undo the pieces of a refused step).
    fn set_time(&mut self, time: f64);
    /// One step of length `h`.
    fn take_step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError>;
}

impl PinnedStepper for BackwardEuler {
    fn newton(&self) -> &BackwardEuler {
        self
    }
    fn newton_mut(&mut self) -> &mut BackwardEuler {
        self
    }
    fn begin_joined_step(&mut self) {
        BackwardEuler::begin_joined_step(self);
    }
    fn end_joined_step(&mut self, refused: bool) {
        BackwardEuler::end_joined_step(self, refused);
    }
    fn set_time(&mut self, time: f64) {
        BackwardEuler::set_time(self, time);
    }
    fn take_step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        self.step(system, h)
    }
}

impl PinnedStepper for Bdf2 {
    fn newton(&self) -> &BackwardEuler {
        Bdf2::newton(self)
    }
    fn newton_mut(&mut self) -> &mut BackwardEuler {
        Bdf2::newton_mut(self)
    }
    fn begin_joined_step(&mut self) {
        self.newton_mut().begin_joined_step();
    }
    fn end_joined_step(&mut self, refused: bool) {
        self.newton_mut().end_joined_step(refused);
    }
    fn set_time(&mut self, time: f64) {
        self.newton_mut().set_time(time);
    }
    fn take_step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        self.step(system, h)
    }
}

impl PinnedStepper for ImplicitMidpoint {
    fn newton(&self) -> &BackwardEuler {
        ImplicitMidpoint::newton(self)
    }
    fn newton_mut(&mut self) -> &mut BackwardEuler {
        ImplicitMidpoint::newton_mut(self)
    }
    fn begin_joined_step(&mut self) {
        self.newton_mut().begin_joined_step();
    }
    fn end_joined_step(&mut self, refused: bool) {
        self.newton_mut().end_joined_step(refused);
    }
    fn set_time(&mut self, time: f64) {
        self.newton_mut().set_time(time);
    }
    fn take_step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        self.step(system, h)
    }
}

/// The default number of times a step may be halved to make the pinned move safe (64
/// pieces).
pub const PIN_SPLIT_DEPTH: usize = 6;

/// The largest safe fraction of moving the pinned particles to `targets` with the free
/// particles held, by the integrator's terms (self-contact's CCD keeps a tenth of every
/// gap); infinite when nothing constrains the move.
#[must_use]
pub fn pinned_move_fraction(
    newton: &BackwardEuler,
    system: &SpringSystem,
    h: f64,
    targets: &[(usize, DVec3)],
) -> f64 {
    let x = system.positions();
    let mut dx = vec![DVec3::ZERO; x.len()];
    let mut moves = false;
    for &(i, target) in targets {
        dx[i] = target - x[i];
        moves |= dx[i] != DVec3::ZERO;
    }
    if !moves {
        return f64::INFINITY;
    }
    let step = StepContext::new(system, h, x, x).with_timing(StepTiming {
        start: newton.time(),
        length: h,
        midpoint: false,
    });
    newton.potential().max_step(&step, x, &dx, f64::INFINITY)
}

/// One step of length `h` of `stepper` with the pinned particles of `targets` moved to
/// the given positions at its end (every other pinned particle held still). Split into
/// pieces of the move (interpolated linearly) at most `max_split_depth` times when the
/// whole move is not safe. On error the system is unchanged.
pub fn step_to_targets<S: PinnedStepper + ?Sized>(
    stepper: &mut S,
    system: &mut SpringSystem,
    h: f64,
    targets: &[(usize, DVec3)],
    max_split_depth: usize,
) -> Result<StepReport, StepError> {
    crate::model::check_time_step(h)?;
    check_members(system, targets.iter().map(|t| t.0))?;
    if let Some(&(particle, _)) = targets.iter().find(|t| !t.1.is_finite()) {
        return Err(ModelError::BadPin {
            particle,
            reason: "the target position is not finite",
        }
        .into());
    }
    let starts: Vec<DVec3> = targets.iter().map(|t| system.positions()[t.0]).collect();
    let members: Vec<usize> = targets.iter().map(|t| t.0).collect();
    let path = |k: usize, s: f64| starts[k].lerp(targets[k].1, s);
    step_along(stepper, system, h, &members, &path, max_split_depth)
}

/// Drives groups of pinned particles along rigid motions ([`PinnedMotion`]), one
/// implicit step at a time, from the positions they had when the driver was built (its
/// time 0).
#[derive(Clone, Debug)]
pub struct PinDriver {
    motions: Vec<PinnedMotion>,
    /// Per moving particle: the particle, its motion, its position at time 0.
    members: Vec<(usize, usize, DVec3)>,
    /// Seconds since the motions started.
    time: f64,
    /// Times a step may be halved to make the pinned move safe (default
    /// [`PIN_SPLIT_DEPTH`]).
    pub max_split_depth: usize,
}

impl PinDriver {
    /// A driver for `motions` of `system`'s pinned particles, starting now from their
    /// current positions. The error names the first bad particle (not pinned, out of
    /// range, in two groups) or the group whose fields are bad.
    pub fn new(system: &SpringSystem, motions: Vec<PinnedMotion>) -> Result<Self, ModelError> {
        for m in &motions {
            m.validate()?;
        }
        check_members(
            system,
            motions.iter().flat_map(|m| m.particles.iter().copied()),
        )?;
        let members = motions
            .iter()
            .enumerate()
            .flat_map(|(k, m)| m.particles.iter().map(move |&i| (i, k)))
            .map(|(i, k)| (i, k, system.positions()[i]))
            .collect();
        Ok(Self {
            motions,
            members,
            time: 0.0,
            max_split_depth: PIN_SPLIT_DEPTH,
        })
    }

    /// The motions.
    #[must_use]
    pub fn motions(&self) -> &[PinnedMotion] {
        &self.motions
    }

    /// Seconds since the motions started (the sum of the steps taken).
    #[must_use]
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Moves the driver's clock on by `dt` (a step taken with other targets).
    pub(crate) fn advance_time(&mut self, dt: f64) {
        self.time += dt;
    }

    /// Where the moving pinned particles are at `t` seconds after the start.
    #[must_use]
    pub fn targets_at(&self, t: f64) -> Vec<(usize, DVec3)> {
        self.members
            .iter()
            .map(|&(i, k, r)| (i, self.motions[k].position(r, t)))
            .collect()
    }

    /// One step of length `h` of `stepper`, the pinned groups moved along their motions
    /// to the step's end. On error the system and the driver are unchanged.
    pub fn step<S: PinnedStepper + ?Sized>(
        &mut self,
        stepper: &mut S,
        system: &mut SpringSystem,
        h: f64,
    ) -> Result<StepReport, StepError> {
        crate::model::check_time_step(h)?;
        let members: Vec<usize> = self.members.iter().map(|m| m.0).collect();
        let t0 = self.time;
        let path = |k: usize, s: f64| {
            let (_, motion, r) = self.members[k];
            self.motions[motion].position(r, t0 + s * h)
        };
        let report = step_along(stepper, system, h, &members, &path, self.max_split_depth)?;
        self.time = t0 + h;
        Ok(report)
    }
}

/// The step of length `h` with pinned particle `members[k]` at `path(k, s)` at the
/// fraction `s` of the step, in pieces when needed; on error the system and the
/// stepper's time are as they were.
fn step_along<S: PinnedStepper + ?Sized>(
    stepper: &mut S,
    system: &mut SpringSystem,
    h: f64,
    members: &[usize],
    path: &dyn Fn(usize, f64) -> DVec3,
    max_split_depth: usize,
) -> Result<StepReport, StepError> {
    let x0 = system.positions().to_vec();
    let v0 = system.velocities().to_vec();
    let time = stepper.time();
    // The pieces of the pinned motion are one step: its records span them.
    stepper.begin_joined_step();
    let result = advance(
        stepper,
        system,
        h,
        members,
        path,
        (0.0, 1.0),
        max_split_depth,
    );
    stepper.end_joined_step(result.is_err());
    if result.is_err() {
        let (x, v) = system.state_mut();
        x.copy_from_slice(&x0);
        v.copy_from_slice(&v0);
        stepper.set_time(time);
    }
    result
}

/// The piece `span` of the step (fractions of it), halved while its pinned move is not
/// safe and `depth` allows.
fn advance<S: PinnedStepper + ?Sized>(
    stepper: &mut S,
    system: &mut SpringSystem,
    h: f64,
    members: &[usize],
    path: &dyn Fn(usize, f64) -> DVec3,
    span: (f64, f64),
    depth: usize,
) -> Result<StepReport, StepError> {
    let (s0, s1) = span;
    let h_piece = h * (s1 - s0);
    let targets: Vec<(usize, DVec3)> = members
        .iter()
        .enumerate()
        .map(|(k, &i)| (i, path(k, s1)))
        .collect();
    if let Some(&(particle, _)) = targets.iter().find(|t| !t.1.is_finite()) {
        return Err(ModelError::BadPin {
            particle,
            reason: "the motion's position is not finite",
        }
        .into());
    }
    let safe = pinned_move_fraction(stepper.newton(), system, h_piece, &targets);
    if safe >= 1.0 {
        system.move_pinned(&targets, h_piece);
        let moved: Vec<(usize, DVec3, DVec3)> = targets
            .iter()
            .map(|&(i, x)| (i, x, system.velocities()[i]))
            .collect();
        let report = stepper.take_step(system, h_piece)?;
        // A step that fell back on its start state rewrote the velocities of the whole
        // system (pinned ones as zero): the pinned velocities are those of their move.
        system.restore_pinned(&moved);
        return Ok(report);
    }
    if depth == 0 {
        let particle = targets
            .iter()
            .map(|&(i, x)| (i, (x - system.positions()[i]).length()))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(usize::MAX, |m| m.0);
        let pieces = (1.0 / (s1 - s0)).round() as usize;
        return Err(StepError::PinnedMove {
            particle,
            pieces,
            safe_fraction: safe,
        });
    }
    let mid = 0.5 * (s0 + s1);
    let first = advance(stepper, system, h, members, path, (s0, mid), depth - 1)?;
    let second = advance(stepper, system, h, members, path, (mid, s1), depth - 1)?;
    Ok(merge(&first, &second))
}

/// The report of two consecutive pieces: the second's end state and convergence, the
/// work of both.
fn merge(first: &StepReport, second: &StepReport) -> StepReport {
    let mut r = *second;
    r.add_work(first);
    r.pieces += first.pieces;
    r.split_depth = 1 + first.split_depth.max(second.split_depth);
    r.unconverged_pieces += first.unconverged_pieces;
    r.swept_passes += first.swept_passes;
    r.rejected_splits += first.rejected_splits;
    // The piece furthest from its tolerance speaks for the step's convergence.
    if first.residual / first.tolerance > second.residual / second.tolerance {
        r.residual = first.residual;
        r.tolerance = first.tolerance;
        r.effective_step = first.effective_step;
        r.stop = first.stop;
    }
    r.energy_before = first.energy_before;
    r
}
