//! Explicit integrators with substeps: symplectic Euler (the course's starter integrator)
//! and velocity Verlet (second order, the same cost per substep), both the cheap choice
//! where they are stable (see [`crate::stability`] for the bound).
//!
//! These steppers take the substep count they are given, unchecked (for comparisons and
//! for finding the stability limit empirically); [`crate::Integrator::VelocityVerlet`]
//! and [`crate::Integrator::SymplecticEulerBounded`] check it against the bound, or choose
//! it, before every step.
//!
//! Each substep of length `h / substeps` updates velocities from the forces at the
//! current positions (minus the gradient of the potential's [`Gravity`] term and of the
//! springs' energy, [`crate::spring::gradient`], the kernel of the
//! [`crate::potential::Springs`] term, and the axial damping along the current spring
//! direction, [`AxialDamping::rate_gradient`]), then positions from the new velocities. Fixed particles do not move. It
//! is only conditionally stable: above its limit it explodes, and then the step is undone
//! and reported as an error rather than returning NaN.

use crate::model::{Spring, SpringSystem, check_time_step};
use crate::potential::AxialDamping;
#[cfg(doc)]
use crate::potential::Gravity;
use crate::report::{IntegratorKind, StepError, StepReport};
use crate::spring;
use sinew_math::DVec3;

mod packed;
#[cfg(feature = "parallel")]
mod parts;

/// Symplectic Euler with a fixed substep count, with its force buffer. Below its
/// stability limit its energy error stays bounded (of order `omega h`) instead of
/// drifting:
///
/// ```
/// use sinew_spring_sim::{SymplecticEuler, DVec3, Material, Particle, SpringSpec, SpringSystem};
/// // A unit mass on a spring stretched 0.2 beyond its rest length 1, no gravity:
/// // omega = 10 rad/s, energy k (0.2)^2 / 2 = 2.
/// let particles = [
///     Particle { fixed: true, ..Particle::at_rest(DVec3::ZERO, 1.0) },
///     Particle::at_rest(DVec3::new(0.0, -1.2, 0.0), 1.0),
/// ];
/// let springs = [SpringSpec { rest_length: Some(1.0), ..SpringSpec::between(0, 1) }];
/// let material = Material::lab().undamped().with_gravity(DVec3::ZERO);
/// let mut system = SpringSystem::new(&particles, &springs, material).unwrap();
/// let start = system.energies().total();
/// let mut stepper = SymplecticEuler::new(&system, 1).unwrap();
/// for _ in 0..2000 {
///     stepper.step(&mut system, 0.01).unwrap();
///     assert!((system.energies().total() - start).abs() < 0.1 * start);
/// }
/// ```
#[derive(Clone, Debug)]
pub struct SymplecticEuler {
    substeps: usize,
    /// Minus the forces of the last evaluation ([`negated_forces`]).
    neg_forces: Vec<DVec3>,
    threaded: ThreadedForces,
    work_x: Vec<DVec3>,
    work_v: Vec<DVec3>,
    /// The fingerprint of the system the force lists were built for, compared per step.
    topology: crate::model::Topology,
}

impl SymplecticEuler {
    /// `substeps` substeps per step (at least 1).
    pub fn new(system: &SpringSystem, substeps: usize) -> Result<Self, crate::model::ModelError> {
        if substeps == 0 {
            return Err(crate::model::SettingsError::new(
                "SymplecticEuler",
                "substeps",
                "must be at least 1",
            )
            .into());
        }
        Ok(Self {
            substeps,
            neg_forces: vec![DVec3::ZERO; system.len()],
            threaded: ThreadedForces::new(system, 0)?,
            work_x: system.positions().to_vec(),
            work_v: system.velocities().to_vec(),
            topology: system.topology(),
        })
    }

    /// The substep count.
    #[must_use]
    pub fn substeps(&self) -> usize {
        self.substeps
    }

    /// Sets the substep count (at least 1; 0 is taken as 1).
    pub fn set_substeps(&mut self, substeps: usize) {
        self.substeps = substeps.max(1);
    }

    /// Spreads the force loop of a system of at least [`PARALLEL_MIN_PARTICLES`]
    /// particles over `threads` threads (0, the default: one per core; 1: the calling
    /// thread). The result is bitwise the same for every count: each spring's force is computed
    /// first, then each particle adds its springs' forces in spring order.
    pub fn set_threads(
        &mut self,
        system: &SpringSystem,
        threads: usize,
    ) -> Result<(), crate::model::ModelError> {
        self.topology.check(&system.topology())?;
        self.threaded = ThreadedForces::new(system, threads)?;
        Ok(())
    }

    /// The threads the force loop runs on (1: the calling thread; also 1 for systems
    /// below [`PARALLEL_MIN_PARTICLES`] particles, which stay on the calling thread).
    #[must_use]
    pub fn threads(&self) -> usize {
        self.threaded.threads()
    }

    /// Advances `system` by `h`.
    pub fn step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        check_time_step(h)?;
        self.topology.check(&system.topology())?;
        let mut report = StepReport::new(IntegratorKind::SymplecticEuler);
        report.substeps = self.substeps;
        report.energy_before = system.energies();
        // The state is advanced in the work buffers (the system stays readable for the
        // terms) and written back only when it stayed finite.
        self.work_x.copy_from_slice(system.positions());
        self.work_v.copy_from_slice(system.velocities());
        let dt = h / self.substeps as f64;
        let (x, v) = (&mut self.work_x, &mut self.work_v);
        let (masses, fixed) = (system.masses(), system.fixed());
        for _ in 0..self.substeps {
            self.threaded
                .negated_forces(system, x, v, &mut self.neg_forces);
            for i in 0..x.len() {
                if !fixed[i] {
                    v[i] -= dt / masses[i] * self.neg_forces[i];
                    x[i] += dt * v[i];
                }
            }
        }
        if let Some(particle) = (0..x.len()).find(|&i| !(x[i].is_finite() && v[i].is_finite())) {
            return Err(StepError::NonFinite {
                integrator: IntegratorKind::SymplecticEuler,
                particle,
            });
        }
        let (positions, velocities) = system.state_mut();
        positions.copy_from_slice(x);
        velocities.copy_from_slice(v);
        report.iterations = self.substeps;
        report.energy_after = system.energies();
        Ok(report)
    }
}

/// Whether `a` and `b` hold bitwise the same vectors.
fn same_bits(a: &[DVec3], b: &[DVec3]) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|(p, q)| {
            (p.x.to_bits(), p.y.to_bits(), p.z.to_bits())
                == (q.x.to_bits(), q.y.to_bits(), q.z.to_bits())
        })
}

/// `1/m` per particle, 0 for fixed ones.
fn inverse_masses(system: &SpringSystem) -> Vec<f64> {
    system
        .masses()
        .iter()
        .zip(system.fixed())
        .map(|(m, f)| if *f { 0.0 } else { 1.0 / m })
        .collect()
}

/// Minus the total force on every particle at positions `x` and velocities `v` (`out`
/// is overwritten): the gradient of the potential's conservative terms ([`Gravity`], and
/// the springs through their kernel [`spring::gradient`]) and of the axial damping along
/// the current spring directions ([`AxialDamping::rate_gradient`]). The hot loop of the
/// explicit integrators: one square root and one division per spring, and a division per
/// damped spring. The integrators subtract it (`v - c s` is the floating-point operation
/// `v + c (-s)`, and negation is exact), so no pass over the particles negates it.
#[inline]
pub(crate) fn negated_forces(system: &SpringSystem, x: &[DVec3], v: &[DVec3], out: &mut [DVec3]) {
    // Zero, minus gravity's gradient: `Gravity::add_gradient` on a zeroed buffer, in
    // one pass (as the threaded gather below does). Zeroing the buffer first was a
    // `memset` call, 5% of a substep on the lab cloth; `0 - m g` is the same operation
    // either way, so the same bits.
    let gravity = system.material().gravity;
    for (f, &m) in out.iter_mut().zip(system.masses()) {
        *f = DVec3::ZERO;
        *f -= m * gravity;
    }
    // The spring term's and the damping's per-spring kernels in one pass over the
    // springs (two passes cost a quarter more per substep on the lab cloth). The
    // buffers are cut to one length, so a spring's end is checked against it once for
    // all of them rather than once per buffer (the same bits).
    let n = out.len();
    let (x, v) = (&x[..n], &v[..n]);
    let c = system.material().damping;
    for_each_spring_force(system.springs(), x, v, c, |_, s, g| {
        out[s.a] += g;
        out[s.b] -= g;
    });
}

/// One spring's share of [`negated_forces`] on its first particle (minus it on the
/// second): the spring kernel, plus the axial damping when `c > 0`.
#[inline(always)]
fn spring_force(s: &Spring, x: &[DVec3], v: &[DVec3], c: f64) -> DVec3 {
    let mut g = spring::gradient(x[s.a], x[s.b], s.rest_length, s.stiffness);
    if c > 0.0 {
        g += AxialDamping::rate_gradient(c, x[s.a] - x[s.b], v[s.a] - v[s.b]);
    }
    g
}

/// Calls `f(k, spring, g)` for each spring `k` of `springs` in order, `g` its
/// [`spring_force`] ([`for_each_spring`] without the energies).
#[inline(always)]
fn for_each_spring_force(
    springs: &[Spring],
    x: &[DVec3],
    v: &[DVec3],
    c: f64,
    mut f: impl FnMut(usize, &Spring, DVec3),
) {
    for_each_spring::<false>(springs, x, v, c, |k, s, g, _| f(k, s, g));
}

/// Calls `f(k, spring, g, e)` for each spring `k` of `springs` in order, `g` its
/// [`spring_force`] and, with `ENERGY`, `e` its [`spring::energy`] (0 without). The
/// forces are computed a batch of [`spring::BATCH`] springs at a time
/// ([`spring::gradients_of_batch`], the same bits) before `f` sees the first of them,
/// so the batch's square roots and divisions overlap instead of each waiting for the
/// previous spring's stores; the energies from the batch's lengths (the same bits as
/// from the positions). A batch with a length outside the plain range is computed
/// spring by spring.
#[inline(always)]
fn for_each_spring<const ENERGY: bool>(
    springs: &[Spring],
    x: &[DVec3],
    v: &[DVec3],
    c: f64,
    mut f: impl FnMut(usize, &Spring, DVec3, f64),
) {
    let scalar_energy = |s: &Spring| {
        if ENERGY {
            spring::energy(x[s.a], x[s.b], s.rest_length, s.stiffness)
        } else {
            0.0
        }
    };
    let mut batches = springs.chunks_exact(spring::BATCH);
    let mut k = 0;
    for batch in &mut batches {
        let mut b = spring::SpringBatch::default();
        for (i, s) in batch.iter().enumerate() {
            let d = x[s.a] - x[s.b];
            [b.d[0][i], b.d[1][i], b.d[2][i]] = [d.x, d.y, d.z];
            if c > 0.0 {
                let dv = v[s.a] - v[s.b];
                [b.dv[0][i], b.dv[1][i], b.dv[2][i]] = [dv.x, dv.y, dv.z];
            }
            b.rest_length[i] = s.rest_length;
            b.stiffness[i] = s.stiffness;
        }
        if let Some((g, l)) = spring::gradients_of_batch(&b, c) {
            for (i, s) in batch.iter().enumerate() {
                let e = if ENERGY {
                    spring::energy_at_length(l[i], s.rest_length, s.stiffness)
                } else {
                    0.0
                };
                f(k + i, s, DVec3::new(g[0][i], g[1][i], g[2][i]), e);
            }
        } else {
            for (i, s) in batch.iter().enumerate() {
                f(k + i, s, spring_force(s, x, v, c), scalar_energy(s));
            }
        }
        k += spring::BATCH;
    }
    for (i, s) in batches.remainder().iter().enumerate() {
        f(k + i, s, spring_force(s, x, v, c), scalar_energy(s));
    }
}

/// Particles from which the explicit force loop runs on threads (with the `parallel`
/// feature): below, a parallel pass costs more than it saves.
pub const PARALLEL_MIN_PARTICLES: usize = 2048;

/// The explicit integrators' force loop, spread over threads for large systems, with bitwise
/// the same result as the sequential loop.
///
/// The sequential loop scatters each spring's force onto its two particles in spring
/// order, which two threads cannot share. Here each spring's force is computed first
/// (springs in chunks, any thread), then each particle gathers its springs' forces in
/// spring order, starting from its gravity: the same additions in the same order on
/// every particle as the scatter makes (`f - g` and `f + (-g)` are the same
/// floating-point operation), so the result does not depend on the thread count.
#[derive(Clone, Debug, Default)]
pub struct ThreadedForces {
    /// Particle `i`'s springs are `entries[ptr[i]..ptr[i + 1]]`: `(spring, whether the
    /// particle is the spring's first end)`, in spring order.
    #[cfg(feature = "parallel")]
    ptr: Vec<usize>,
    #[cfg(feature = "parallel")]
    entries: Vec<(usize, bool)>,
    /// Each spring's force term of the last evaluation.
    #[cfg(feature = "parallel")]
    per_spring: Vec<DVec3>,
    /// Each spring's elastic energy of the last evaluation that asked for it.
    #[cfg(feature = "parallel")]
    per_spring_energy: Vec<f64>,
    #[cfg(feature = "parallel")]
    pool: Option<std::sync::Arc<rayon::ThreadPool>>,
}

impl ThreadedForces {
    /// Threads for `system` (0: one per core); nothing is built below
    /// [`PARALLEL_MIN_PARTICLES`] particles, for one thread, or without the `parallel`
    /// feature.
    fn new(system: &SpringSystem, threads: usize) -> Result<Self, crate::model::ModelError> {
        #[cfg(feature = "parallel")]
        {
            let count = if threads == 0 {
                std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
            } else {
                threads
            };
            if count > 1 && system.len() >= PARALLEL_MIN_PARTICLES {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(count)
                    .build()
                    .map_err(|e| crate::linear::SolverError::thread_pool(count, e))?;
                let mut lists: Vec<Vec<(usize, bool)>> = vec![Vec::new(); system.len()];
                for (k, s) in system.springs().iter().enumerate() {
                    lists[s.a].push((k, true));
                    lists[s.b].push((k, false));
                }
                let mut ptr = Vec::with_capacity(system.len() + 1);
                ptr.push(0);
                let mut entries = Vec::with_capacity(2 * system.springs().len());
                for list in lists {
                    entries.extend(list);
                    ptr.push(entries.len());
                }
                return Ok(Self {
                    ptr,
                    entries,
                    per_spring: vec![DVec3::ZERO; system.springs().len()],
                    per_spring_energy: vec![0.0; system.springs().len()],
                    pool: Some(std::sync::Arc::new(pool)),
                });
            }
        }
        let _ = (system, threads);
        Ok(Self::default())
    }

    /// The threads the force loop runs on (1: the calling thread).
    #[must_use]
    pub fn threads(&self) -> usize {
        #[cfg(feature = "parallel")]
        if let Some(pool) = &self.pool {
            return pool.current_num_threads();
        }
        1
    }

    /// Minus the forces at `x`, `v` into `out` ([`negated_forces`]), on the threads
    /// when there are any.
    fn negated_forces(
        &mut self,
        system: &SpringSystem,
        x: &[DVec3],
        v: &[DVec3],
        out: &mut [DVec3],
    ) {
        let _ = self.run(system, x, v, out, false);
    }

    /// [`Self::negated_forces`], and with threads also the springs' elastic energy at
    /// `x`; `None` without threads (the caller then sums it itself).
    ///
    /// On a large system summing the energy apart on the calling thread, while the
    /// pool's threads wait, took about a third of a Verlet step at one substep (W6).
    /// Here each spring's energy is computed in the forces' parallel pass, then summed in
    /// spring order: the same values in the same order as
    /// [`SpringSystem::energies`]'s spring sum, so the same bits.
    fn negated_forces_and_spring_energy(
        &mut self,
        system: &SpringSystem,
        x: &[DVec3],
        v: &[DVec3],
        out: &mut [DVec3],
    ) -> Option<f64> {
        self.run(system, x, v, out, true)
    }

    /// The force loop; with `energy`, on threads, also the springs' energy.
    fn run(
        &mut self,
        system: &SpringSystem,
        x: &[DVec3],
        v: &[DVec3],
        out: &mut [DVec3],
        energy: bool,
    ) -> Option<f64> {
        #[cfg(feature = "parallel")]
        if let Some(pool) = &self.pool {
            use rayon::prelude::*;
            const SPRINGS_PER_TASK: usize = 4096;
            const PARTICLES_PER_TASK: usize = 1024;
            let c = system.material().damping;
            let gravity = system.material().gravity;
            let masses = system.masses();
            let springs = system.springs();
            let (ptr, entries, per_spring) = (&self.ptr, &self.entries, &mut self.per_spring);
            let per_spring_energy = &mut self.per_spring_energy;
            pool.install(|| {
                springs
                    .par_chunks(SPRINGS_PER_TASK)
                    .zip(per_spring.par_chunks_mut(SPRINGS_PER_TASK))
                    .zip(per_spring_energy.par_chunks_mut(SPRINGS_PER_TASK))
                    .for_each(|((springs, out), energies)| {
                        if energy {
                            for_each_spring::<true>(springs, x, v, c, |k, _, g, e| {
                                out[k] = g;
                                energies[k] = e;
                            });
                        } else {
                            for_each_spring_force(springs, x, v, c, |k, _, g| out[k] = g);
                        }
                    });
                let per_spring = &*per_spring;
                out.par_chunks_mut(PARTICLES_PER_TASK)
                    .enumerate()
                    .for_each(|(chunk, out)| {
                        for (k, f) in out.iter_mut().enumerate() {
                            let i = chunk * PARTICLES_PER_TASK + k;
                            // As the sequential loop: zero, minus gravity's gradient,
                            // then the springs in order.
                            let mut sum = DVec3::ZERO;
                            sum -= masses[i] * gravity;
                            for &(s, first) in &entries[ptr[i]..ptr[i + 1]] {
                                if first {
                                    sum += per_spring[s];
                                } else {
                                    sum -= per_spring[s];
                                }
                            }
                            *f = sum;
                        }
                    });
            });
            return energy.then(|| self.per_spring_energy.iter().sum());
        }
        let _ = energy;
        negated_forces(system, x, v, out);
        None
    }
}

/// Velocity Verlet (kick-drift-kick) with a fixed substep count, with its buffers.
///
/// Each substep of length `dt`: `v += dt/2 a`, `x += dt v`, `a = M^-1 f(x, v)`,
/// `v += dt/2 a`. The force at the end of a substep is the one at the start of the next,
/// so a substep costs one force evaluation (plus one per step when the state was changed
/// from outside). With damping, the force at the end of a substep uses the half-step
/// velocity (the damping term is then first order; the springs keep second order).
///
/// Second order: at the same step its energy error is far smaller than symplectic
/// Euler's (of order `(omega h)^2`):
///
/// ```
/// use sinew_spring_sim::{VelocityVerlet, DVec3, Material, Particle, SpringSpec, SpringSystem};
/// // A unit mass on a spring stretched 0.2 beyond its rest length 1, no gravity:
/// // omega = 10 rad/s, energy k (0.2)^2 / 2 = 2.
/// let particles = [
///     Particle { fixed: true, ..Particle::at_rest(DVec3::ZERO, 1.0) },
///     Particle::at_rest(DVec3::new(0.0, -1.2, 0.0), 1.0),
/// ];
/// let springs = [SpringSpec { rest_length: Some(1.0), ..SpringSpec::between(0, 1) }];
/// let material = Material::lab().undamped().with_gravity(DVec3::ZERO);
/// let mut system = SpringSystem::new(&particles, &springs, material).unwrap();
/// let start = system.energies().total();
/// let mut stepper = VelocityVerlet::new(&system, 1).unwrap();
/// for _ in 0..2000 {
///     let report = stepper.step(&mut system, 0.01).unwrap();
///     assert_eq!(report.substeps, 1);
///     assert!((system.energies().total() - start).abs() < 0.01 * start);
/// }
/// ```
#[derive(Clone, Debug)]
pub struct VelocityVerlet {
    substeps: usize,
    /// Minus the forces of the last evaluation ([`negated_forces`]).
    neg_forces: Vec<DVec3>,
    threaded: ThreadedForces,
    /// The state being advanced; after a step that was written back (`end_energy` is
    /// then set), the state it wrote.
    work_x: Vec<DVec3>,
    work_v: Vec<DVec3>,
    /// The energy after the last step written back, to reuse it and its forces when
    /// nobody changed the system's state since (it is then bitwise `work_x`, `work_v`).
    end_energy: Option<crate::model::Energies>,
    /// [`material_key`] of the system of that end state.
    end_material: (u64, [u64; 3], u64),
    /// `1/m`, 0 for fixed particles (whose velocity is 0), so the update has no branch.
    inv_mass: Vec<f64>,
    /// The substeps' layout on the calling thread ([`packed`]); boxed, as the stepper
    /// sits in the integrators' enum beside smaller ones.
    packed: Box<packed::Packed>,
    /// The substeps' layouts on several threads ([`parts`]), built at the first step
    /// that runs on threads.
    #[cfg(feature = "parallel")]
    parts: Option<Box<parts::Parts>>,
    /// The fingerprint of the system `inv_mass` and the force lists were built for: a
    /// system of equal counts but other masses, pins or pairs would run on them silently.
    topology: crate::model::Topology,
    /// Leave the system at its start state when the step ran away ([`ran_away`]); the
    /// report's energies say so. Set by `auto`, which then redoes the step implicitly.
    pub(crate) keep_start_if_runaway: bool,
}

/// Whether an explicit step from energies `before` to `after` ran away: the total is no
/// longer finite, or it rose by more than half the energy scale (the sum of the parts'
/// magnitudes at the start). A stable Verlet step changes the total by its integration
/// error, at most 3e-3 of the scale per step over 10^6 undamped W4 steps at the bound;
/// a step whose substep count the state outgrew within the step (springs shortening
/// towards zero length stiffen without limit) grows without bound, 7e4 to 1e17 in one
/// step on a compressed sheet. The threshold is orders of magnitude from both.
#[must_use]
pub(crate) fn ran_away(before: &crate::model::Energies, after: &crate::model::Energies) -> bool {
    let scale = before.kinetic.abs() + before.spring.abs() + before.gravity.abs();
    let total = after.total();
    !total.is_finite() || total - before.total() > 0.5 * scale
}

impl VelocityVerlet {
    /// `substeps` substeps per step (at least 1).
    pub fn new(system: &SpringSystem, substeps: usize) -> Result<Self, crate::model::ModelError> {
        if substeps == 0 {
            return Err(crate::model::SettingsError::new(
                "VelocityVerlet",
                "substeps",
                "must be at least 1",
            )
            .into());
        }
        Ok(Self {
            substeps,
            neg_forces: vec![DVec3::ZERO; system.len()],
            threaded: ThreadedForces::new(system, 0)?,
            work_x: system.positions().to_vec(),
            work_v: system.velocities().to_vec(),
            end_energy: None,
            end_material: material_key(system),
            inv_mass: inverse_masses(system),
            packed: Box::new(packed::Packed::new(packed::Instance::Detect)),
            #[cfg(feature = "parallel")]
            parts: None,
            topology: system.topology(),
            keep_start_if_runaway: false,
        })
    }

    /// The substep count.
    #[must_use]
    pub fn substeps(&self) -> usize {
        self.substeps
    }

    /// Sets the substep count (at least 1; 0 is taken as 1).
    pub fn set_substeps(&mut self, substeps: usize) {
        self.substeps = substeps.max(1);
    }

    /// Spreads the substeps of a system of at least [`PARALLEL_MIN_PARTICLES`]
    /// particles over `threads` threads (0, the default: one per core; 1: the calling
    /// thread). The result is bitwise the same for every count: the particles are cut
    /// into one contiguous range per thread, and each thread computes every spring with
    /// an end in its range and adds the terms to its own particles in spring order, as
    /// the single-threaded loop adds them (a spring between two ranges is computed by
    /// both threads).
    pub fn set_threads(
        &mut self,
        system: &SpringSystem,
        threads: usize,
    ) -> Result<(), crate::model::ModelError> {
        self.topology.check(&system.topology())?;
        self.threaded = ThreadedForces::new(system, threads)?;
        #[cfg(feature = "parallel")]
        {
            self.parts = None;
        }
        Ok(())
    }

    /// The threads the force loop runs on (1: the calling thread; also 1 for systems
    /// below [`PARALLEL_MIN_PARTICLES`] particles, which stay on the calling thread).
    #[must_use]
    pub fn threads(&self) -> usize {
        self.threaded.threads()
    }

    /// The substeps of [`Self::step`] in the work buffers through [`ThreadedForces`],
    /// evaluating the start state's forces unless `unchanged`; with threads, the end
    /// state's spring energy into `end_spring_energy`.
    fn threaded_substeps(
        &mut self,
        system: &SpringSystem,
        unchanged: bool,
        dt: f64,
        end_spring_energy: &mut Option<f64>,
    ) {
        let (x, v) = (&mut self.work_x, &mut self.work_v);
        if !unchanged {
            self.threaded
                .negated_forces(system, x, v, &mut self.neg_forces);
        }
        let half = 0.5 * dt;
        let inv_mass = &self.inv_mass;
        // A substep's closing kick and the next one's opening kick and drift read the
        // same force and nothing between them reads the state, so they run in one pass
        // over the particles: the same operations on every particle in the same order,
        // one pass fewer per substep.
        for substep in 0..self.substeps {
            let closing = substep > 0;
            for (((xi, vi), f), w) in x
                .iter_mut()
                .zip(v.iter_mut())
                .zip(&self.neg_forces)
                .zip(inv_mass)
            {
                if closing {
                    *vi -= (half * w) * *f;
                }
                *vi -= (half * w) * *f;
                *xi += dt * *vi;
            }
            if substep + 1 == self.substeps {
                *end_spring_energy = self.threaded.negated_forces_and_spring_energy(
                    system,
                    x,
                    v,
                    &mut self.neg_forces,
                );
            } else {
                self.threaded
                    .negated_forces(system, x, v, &mut self.neg_forces);
            }
        }
        for ((vi, f), w) in v.iter_mut().zip(&self.neg_forces).zip(inv_mass) {
            *vi -= (half * w) * *f;
        }
    }

    /// Advances `system` by `h`. A non-finite value undoes the step and is an error.
    pub fn step(&mut self, system: &mut SpringSystem, h: f64) -> Result<StepReport, StepError> {
        check_time_step(h)?;
        self.topology.check(&system.topology())?;
        let mut report = StepReport::new(IntegratorKind::VelocityVerlet);
        report.substeps = self.substeps;
        // Compared bit for bit: only then are the kept forces and energy exactly the
        // state's (`==` would take -0.0 for 0.0); and with the same springs and
        // material, which another system of the same topology, or a change of damping,
        // need not have.
        let unchanged = self.end_energy.is_some()
            && self.end_material == material_key(system)
            && same_bits(&self.work_x, system.positions())
            && same_bits(&self.work_v, system.velocities());
        report.energy_before = match (unchanged, self.end_energy) {
            (true, Some(e)) => e,
            _ => system.energies(),
        };
        // Advanced in the work buffers, written back only when finite (as in
        // [`SymplecticEuler::step`]); they already hold the state when it is unchanged.
        if !unchanged {
            self.work_x.copy_from_slice(system.positions());
            self.work_v.copy_from_slice(system.velocities());
        }
        let dt = h / self.substeps as f64;
        // The springs' energy at the end state, when the last force evaluation
        // computed it (on threads).
        let mut end_spring_energy = None;
        #[cfg(feature = "parallel")]
        let on_parts = self.threaded.threads() > 1 && packed::Packed::fits(system);
        #[cfg(not(feature = "parallel"))]
        let on_parts = false;
        if on_parts {
            // On several threads each thread steps a part of the particles in its own
            // packed layout ([`parts`]), with the same bits.
            #[cfg(feature = "parallel")]
            if let Some(pool) = self.threaded.pool.clone() {
                let threads = pool.current_num_threads();
                let parts = self
                    .parts
                    .get_or_insert_with(|| Box::new(parts::Parts::new(system, threads)));
                let (inv_mass, substeps) = (&self.inv_mass, self.substeps);
                let (x, v, f) = (&mut self.work_x, &mut self.work_v, &mut self.neg_forces);
                end_spring_energy =
                    Some(pool.install(|| {
                        parts.step(system, inv_mass, x, v, f, unchanged, dt, substeps)
                    }));
            }
        } else if self.threaded.threads() == 1 && packed::Packed::fits(system) {
            // On the calling thread the substeps run in their own layout, with the
            // same bits ([`packed`]).
            let c = system.material().damping;
            let packed = &mut self.packed;
            packed.load(
                system,
                &self.inv_mass,
                &self.work_x,
                &self.work_v,
                &self.neg_forces,
                dt,
            );
            if !unchanged {
                packed.evaluate(c);
            }
            packed.substeps(c, dt, self.substeps);
            packed.store(&mut self.work_x, &mut self.work_v, &mut self.neg_forces);
        } else {
            self.threaded_substeps(system, unchanged, dt, &mut end_spring_energy);
        }
        let (x, v) = (&self.work_x, &self.work_v);
        let finite = (0..x.len()).find(|&i| !(x[i].is_finite() && v[i].is_finite()));
        // The end state's energies, computed before anything is written (the same sums
        // over the same values as `system.energies()` after writing).
        let end_energies = |x: &[DVec3], v: &[DVec3]| match end_spring_energy {
            Some(spring) => {
                let (kinetic, gravity) = system.particle_energies_of(x, v);
                crate::model::Energies {
                    kinetic,
                    spring,
                    gravity,
                }
            }
            None => system.energies_of(x, v),
        };
        let mut guarded_after = None;
        if self.keep_start_if_runaway {
            let after = match finite {
                Some(_) => crate::model::Energies {
                    kinetic: f64::INFINITY,
                    ..crate::model::Energies::default()
                },
                None => end_energies(x, v),
            };
            guarded_after = Some(after);
            if ran_away(&report.energy_before, &after) {
                // The system still holds the start state: nothing was written.
                self.end_energy = None;
                report.iterations = self.substeps;
                report.energy_after = after;
                return Ok(report);
            }
        }
        if let Some(particle) = finite {
            self.end_energy = None;
            return Err(StepError::NonFinite {
                integrator: IntegratorKind::VelocityVerlet,
                particle,
            });
        }
        let after = guarded_after.unwrap_or_else(|| end_energies(x, v));
        let (positions, velocities) = system.state_mut();
        positions.copy_from_slice(x);
        velocities.copy_from_slice(v);
        report.iterations = self.substeps;
        report.energy_after = after;
        self.end_energy = Some(report.energy_after);
        self.end_material = material_key(system);
        Ok(report)
    }
}

/// What, beside the state, the forces and energies depend on: the fingerprint of the
/// springs' rest lengths and stiffnesses, and the bits of the gravity and the damping.
fn material_key(system: &SpringSystem) -> (u64, [u64; 3], u64) {
    let material = system.material();
    (
        system.spring_constants(),
        material.gravity.to_array().map(f64::to_bits),
        material.damping.to_bits(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Material, Particle, SpringSpec};

    /// A line of particles whose neighbours sit at plain distances, at the same point, at
    /// distances whose squares underflow, near the plain range's lower end, and one
    /// particle so far away that the squared length overflows; springs between
    /// neighbours and next neighbours (some of zero rest length), 43 of them, so the
    /// last batch is cut short.
    fn odd_line(damping: f64) -> SpringSystem {
        let offsets = [
            0.2, 0.0, 0.3, 1e-160, 0.25, 1e-155, 0.2, 2e-150, 0.3, 0.2, 0.0, 0.0, 0.3, 0.2, 0.25,
            1e200, 0.3, 0.2, 0.2, 5e-151, 0.3, 0.2,
        ];
        let mut particles = vec![Particle::at_rest(DVec3::ZERO, 1.0)];
        let mut at = DVec3::ZERO;
        for (i, &o) in offsets.iter().enumerate() {
            // Not along an axis, so every component of a spring's force is worked.
            let bend = 0.1 * (i as f64).sin();
            let step = o * DVec3::new(1.0, bend, 0.5 - bend).normalize();
            // The far particle is an outlier: the line goes on from its neighbour.
            let position = at + step;
            if o < 1.0 {
                at = position;
            }
            particles.push(Particle {
                velocity: DVec3::new(0.1 * (i as f64).cos(), -0.2, 0.05 * i as f64),
                ..Particle::at_rest(position, 1.0 + 0.1 * i as f64)
            });
        }
        particles[0].fixed = true;
        let n = particles.len();
        let mut springs = Vec::new();
        for step in [1, 2] {
            for a in 0..n - step {
                springs.push(SpringSpec {
                    rest_length: Some(if a % 7 == 3 { 0.0 } else { 0.21 * step as f64 }),
                    stiffness: Some(50.0 + a as f64),
                    ..SpringSpec::between(a, a + step)
                });
            }
        }
        SpringSystem::new(&particles, &springs, Material::lab().with_damping(damping)).unwrap()
    }

    /// The scalar loop the batches replace: gravity, then each spring's kernels and its
    /// scatter, in spring order.
    fn scalar_negated_forces(system: &SpringSystem, x: &[DVec3], v: &[DVec3]) -> Vec<DVec3> {
        let c = system.material().damping;
        let mut out: Vec<DVec3> = system
            .masses()
            .iter()
            .map(|&m| {
                let mut f = DVec3::ZERO;
                f -= m * system.material().gravity;
                f
            })
            .collect();
        for s in system.springs() {
            let mut g = spring::gradient(x[s.a], x[s.b], s.rest_length, s.stiffness);
            if c > 0.0 {
                g += AxialDamping::rate_gradient(c, x[s.a] - x[s.b], v[s.a] - v[s.b]);
            }
            out[s.a] += g;
            out[s.b] -= g;
        }
        out
    }

    fn bits(f: &[DVec3]) -> Vec<[u64; 3]> {
        f.iter()
            .map(|g| [g.x.to_bits(), g.y.to_bits(), g.z.to_bits()])
            .collect()
    }

    fn energy_bits(e: &crate::model::Energies) -> [u64; 3] {
        [e.kinetic.to_bits(), e.spring.to_bits(), e.gravity.to_bits()]
    }

    /// A threaded Verlet step takes its end energies' spring part from the last force
    /// pass; they must be bitwise the system's own energies of the end state, guarded
    /// (as `auto` runs it) or not, damped or not, at one and several substeps; and the
    /// state is the one-thread stepper's.
    #[cfg(feature = "parallel")]
    #[test]
    fn threaded_verlet_reports_the_systems_own_end_energies() {
        for (damping, substeps, guarded) in [(0.0, 1, false), (0.2, 3, true), (0.0, 2, true)] {
            let mut system = crate::ClothGrid::lab_sized(51, 0.04)
                .with_damping(damping)
                .build()
                .unwrap();
            // Off rest, so every spring has energy and force.
            let (positions, _) = system.state_mut();
            for (i, p) in positions.iter_mut().enumerate() {
                let t = i as f64;
                *p += 0.003 * DVec3::new(t.sin(), (1.7 * t).cos(), (0.3 * t).sin());
            }
            let mut serial = system.clone();
            let mut threaded = VelocityVerlet::new(&system, substeps).unwrap();
            threaded.set_threads(&system, 2).unwrap();
            assert_eq!(threaded.threads(), 2);
            threaded.keep_start_if_runaway = guarded;
            let mut one = VelocityVerlet::new(&serial, substeps).unwrap();
            one.set_threads(&serial, 1).unwrap();
            one.keep_start_if_runaway = guarded;
            for step in 0..4 {
                let report = threaded.step(&mut system, 1.0 / 240.0).unwrap();
                let report_one = one.step(&mut serial, 1.0 / 240.0).unwrap();
                assert_eq!(
                    energy_bits(&report.energy_after),
                    energy_bits(&system.energies()),
                    "damping {damping}, {substeps} substeps, guarded {guarded}, step {step}"
                );
                assert_eq!(
                    energy_bits(&report.energy_after),
                    energy_bits(&report_one.energy_after)
                );
                assert_eq!(bits(system.positions()), bits(serial.positions()));
                assert_eq!(bits(system.velocities()), bits(serial.velocities()));
            }
        }
    }

    /// Verlet keeps the last end state's forces and energy for the next step only while
    /// the system still holds that state bit for bit: unchanged and undamped, the kept
    /// ones must be what a fresh stepper computes (with damping the kept force used the
    /// half-step velocity, by design); changed between steps (a position moved, or a
    /// pinned particle's zero velocity given the other sign, which `==` would not see),
    /// the state is stepped as a fresh stepper steps it, damped or not.
    #[test]
    fn verlet_steps_a_state_changed_between_steps_as_a_fresh_stepper() {
        /// A name, the damping, and the change made between the two steps.
        type Change = (&'static str, f64, fn(&mut SpringSystem));
        let changes: [Change; 5] = [
            ("none", 0.0, |_| {}),
            ("a position moved", 0.0, |system| {
                system.state_mut().0[12].y += 1e-3;
            }),
            ("a zero's sign flipped", 0.0, |system| {
                let v = &mut system.state_mut().1[0];
                assert_eq!(v.x.to_bits(), 0.0f64.to_bits());
                v.x = -0.0;
            }),
            ("a position moved", 0.1, |system| {
                system.state_mut().0[12].y += 1e-3;
            }),
            ("a zero's sign flipped", 0.1, |system| {
                // Particle 0 is pinned: its velocity stays exactly +0.0.
                let v = &mut system.state_mut().1[0];
                assert_eq!(v.x.to_bits(), 0.0f64.to_bits());
                v.x = -0.0;
            }),
        ];
        for (name, damping, change) in changes {
            let mut system = crate::ClothGrid::lab_sized(7, 0.2)
                .with_damping(damping)
                .build()
                .unwrap();
            assert!(system.fixed()[0]);
            let mut kept = VelocityVerlet::new(&system, 3).unwrap();
            kept.step(&mut system, 1.0 / 60.0).unwrap();
            change(&mut system);
            let mut copy = system.clone();
            let second = kept.step(&mut system, 1.0 / 60.0).unwrap();
            let fresh = VelocityVerlet::new(&copy, 3)
                .unwrap()
                .step(&mut copy, 1.0 / 60.0)
                .unwrap();
            let case = format!("{name}, damping {damping}");
            assert_eq!(bits(system.positions()), bits(copy.positions()), "{case}");
            assert_eq!(bits(system.velocities()), bits(copy.velocities()), "{case}");
            assert_eq!(
                (
                    second.energy_before.total().to_bits(),
                    second.energy_after.total().to_bits()
                ),
                (
                    fresh.energy_before.total().to_bits(),
                    fresh.energy_after.total().to_bits()
                ),
                "{name}"
            );
        }
    }

    /// `system` at its state with its particles renumbered (new particle `j` is old
    /// particle `order[j]`; the springs keep their order), every spring's stiffness times
    /// `stiffness` and rest length times `rest`, under `gravity`.
    fn rebuilt(
        system: &SpringSystem,
        order: &[usize],
        stiffness: f64,
        rest: f64,
        gravity: DVec3,
    ) -> SpringSystem {
        let mut new_index = vec![0; order.len()];
        for (j, &i) in order.iter().enumerate() {
            new_index[i] = j;
        }
        let (x, v) = (system.positions(), system.velocities());
        let particles: Vec<Particle> = order
            .iter()
            .map(|&i| Particle {
                fixed: system.fixed()[i],
                velocity: v[i],
                ..Particle::at_rest(x[i], system.masses()[i])
            })
            .collect();
        let springs: Vec<SpringSpec> = system
            .springs()
            .iter()
            .map(|s| SpringSpec {
                rest_length: Some(rest * s.rest_length),
                stiffness: Some(stiffness * s.stiffness),
                ..SpringSpec::between(new_index[s.a], new_index[s.b])
            })
            .collect();
        let material = system.material().with_gravity(gravity);
        SpringSystem::new(&particles, &springs, material).unwrap()
    }

    /// Verlet keeps, between steps, the springs' constants, each particle's kick and
    /// gravity (and, on threads, the state in its layouts): after a step, another `h`, then
    /// another system of the same topology and the same state (other stiffnesses, rest
    /// lengths and gravity), then a change of damping, are each stepped as a fresh stepper
    /// steps them, on one thread and on two.
    #[test]
    fn verlet_steps_other_constants_and_steps_as_a_fresh_stepper() {
        for threads in [1, 2] {
            let mut system = crate::ClothGrid::lab_sized(51, 0.04)
                .with_damping(0.0)
                .build()
                .unwrap();
            let mut stepper = VelocityVerlet::new(&system, 2).unwrap();
            stepper.set_threads(&system, threads).unwrap();
            if cfg!(feature = "parallel") {
                assert_eq!(stepper.threads(), threads);
            }
            let fresh_step = |system: &SpringSystem, h: f64| {
                let mut copy = system.clone();
                let mut fresh = VelocityVerlet::new(&copy, 2).unwrap();
                fresh.set_threads(&copy, threads).unwrap();
                let report = fresh.step(&mut copy, h).unwrap();
                (copy, report)
            };
            stepper.step(&mut system, 1.0 / 60.0).unwrap();
            // Each change starts from the state the stepper ended with last, so only the
            // change tells it that its kept forces and energy are not the system's.
            type Change = (&'static str, fn(&mut SpringSystem));
            let changes: [Change; 3] = [
                ("another h", |_| {}),
                ("other constants", |system| {
                    let order: Vec<usize> = (0..system.len()).collect();
                    let gravity = DVec3::new(0.1, -2.0, 0.0);
                    *system = rebuilt(system, &order, 1.5, 1.01, gravity);
                }),
                ("a change of damping", |system| {
                    system.set_damping(0.3).unwrap()
                }),
            ];
            for (name, change) in changes {
                change(&mut system);
                let h = 1.0 / 50.0;
                let (expected, fresh) = fresh_step(&system, h);
                let report = stepper.step(&mut system, h).unwrap();
                let case = format!("{name}, {threads} threads");
                assert_eq!(
                    bits(system.positions()),
                    bits(expected.positions()),
                    "{case}"
                );
                assert_eq!(
                    bits(system.velocities()),
                    bits(expected.velocities()),
                    "{case}"
                );
                assert_eq!(
                    energy_bits(&report.energy_before),
                    energy_bits(&fresh.energy_before),
                    "{case}"
                );
                assert_eq!(
                    energy_bits(&report.energy_after),
                    energy_bits(&fresh.energy_after),
                    "{case}"
                );
            }
        }
    }

    /// The packed layout's instances ([`packed::Instance`]): AVX2 where the processor
    /// has it (else the portable one again), and the portable one.
    const INSTANCES: [packed::Instance; 2] = [packed::Instance::Detect, packed::Instance::Portable];

    /// Minus the forces through the packed layout's `instance`.
    fn packed_negated_forces(
        system: &SpringSystem,
        x: &[DVec3],
        v: &[DVec3],
        instance: packed::Instance,
    ) -> Vec<DVec3> {
        let mut p = packed::Packed::new(instance);
        let mut out = vec![DVec3::splat(f64::NAN); system.len()];
        let (mut x, mut v) = (x.to_vec(), v.to_vec());
        p.load(system, &inverse_masses(system), &x, &v, &out, 0.0);
        p.evaluate(system.material().damping);
        p.store(&mut x, &mut v, &mut out);
        out
    }

    /// Moves every particle of `cloth` off its rest place and gives it a velocity, each
    /// by its own amount, so every spring has a force and a damping term.
    fn off_rest(cloth: &mut SpringSystem) {
        let (positions, velocities) = cloth.state_mut();
        for (i, (p, v)) in positions.iter_mut().zip(velocities).enumerate() {
            let t = i as f64;
            *p += 0.01 * DVec3::new(t.sin(), (1.7 * t).cos(), (0.3 * t).sin());
            *v = DVec3::new((0.7 * t).cos(), 0.5 * t.sin(), -0.2);
        }
    }

    /// The packed layout's forces, in both instances, are bitwise the scalar loop's:
    /// on the line of odd lengths (batches computed spring by spring, a last batch of
    /// three springs and the padding spring) and on a cloth off rest (121 particles,
    /// padded to 128; 618 springs, a last batch of two and two padding springs), damped
    /// and not.
    #[test]
    fn packed_forces_are_bitwise_the_scalar_loop() {
        for damping in [0.0, 0.3] {
            let mut cloth = crate::ClothGrid::lab()
                .with_damping(damping)
                .build()
                .unwrap();
            off_rest(&mut cloth);
            assert_eq!(cloth.springs().len() % 4, 2);
            for system in [odd_line(damping), cloth] {
                let (x, v) = (system.positions(), system.velocities());
                let expected = scalar_negated_forces(&system, x, v);
                assert!(expected.iter().all(|f| f.is_finite()));
                for instance in INSTANCES {
                    let got = packed_negated_forces(&system, x, v, instance);
                    assert_eq!(
                        bits(&got),
                        bits(&expected),
                        "{instance:?}, damping {damping}"
                    );
                }
            }
        }
    }

    /// Velocity Verlet's substeps in the packed layout, in both instances, are bitwise
    /// those of the loop over `DVec3`s with the scalar forces, damped and not, with the
    /// start forces evaluated and loaded, on a cloth of one scheduled chunk of springs and
    /// on one of three.
    #[test]
    fn packed_verlet_substeps_are_bitwise_the_scalar_loop() {
        let (h, substeps) = (1.0 / 60.0, 7);
        let dt = h / substeps as f64;
        for (size, damping) in [(9, 0.0), (9, 0.2), (21, 0.0), (21, 0.2)] {
            let system = crate::ClothGrid::lab_sized(size, 0.1)
                .with_damping(damping)
                .build()
                .unwrap();
            let chunks = system.springs().len().div_ceil(packed::SCHEDULE_CHUNK);
            assert_eq!(chunks, if size == 9 { 1 } else { 3 });
            let c = system.material().damping;
            let w = inverse_masses(&system);
            // The reference: the stepper's loop, one kick at a time.
            let (mut x, mut v) = (system.positions().to_vec(), system.velocities().to_vec());
            let mut f = scalar_negated_forces(&system, &x, &v);
            let start_forces = f.clone();
            for _ in 0..substeps {
                for i in 0..x.len() {
                    v[i] -= (0.5 * dt * w[i]) * f[i];
                    x[i] += dt * v[i];
                }
                f = scalar_negated_forces(&system, &x, &v);
                for i in 0..x.len() {
                    v[i] -= (0.5 * dt * w[i]) * f[i];
                }
            }
            for instance in INSTANCES {
                for evaluate in [true, false] {
                    let mut p = packed::Packed::new(instance);
                    let (mut px, mut pv) =
                        (system.positions().to_vec(), system.velocities().to_vec());
                    let mut pf = if evaluate {
                        vec![DVec3::splat(f64::NAN); x.len()]
                    } else {
                        start_forces.clone()
                    };
                    p.load(&system, &w, &px, &pv, &pf, dt);
                    if evaluate {
                        p.evaluate(c);
                    }
                    p.substeps(c, dt, substeps);
                    p.store(&mut px, &mut pv, &mut pf);
                    let case = format!("{instance:?}, damping {damping}, evaluate {evaluate}");
                    assert_eq!(bits(&px), bits(&x), "{case}");
                    assert_eq!(bits(&pv), bits(&v), "{case}");
                    assert_eq!(bits(&pf), bits(&f), "{case}");
                }
            }
        }
    }

    /// Velocity Verlet's substeps on parts ([`parts`]) are bitwise the single packed
    /// layout's (itself bitwise the scalar loop, above), and the spring energy they report
    /// is bitwise the system's of the end state: 1 to 7 parts on 1 to 3 threads, both
    /// instances, damped and not, the start forces evaluated and then kept, on the line
    /// of odd lengths, on a cloth off rest, and on that cloth numbered at random (most
    /// springs cut between parts, halos of most of the other parts' particles).
    #[cfg(feature = "parallel")]
    #[test]
    fn parts_substeps_are_bitwise_the_packed_loop() {
        let (h, substeps) = (1.0 / 60.0, 5);
        let dt = h / substeps as f64;
        for damping in [0.0, 0.2] {
            let mut cloth = crate::ClothGrid::lab_sized(15, 0.1)
                .with_damping(damping)
                .build()
                .unwrap();
            off_rest(&mut cloth);
            // A random order (xorshift, Fisher-Yates).
            let mut order: Vec<usize> = (0..cloth.len()).collect();
            let mut state = 0x2545_f491_4f6c_dd1d_u64;
            for i in (1..order.len()).rev() {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                order.swap(i, (state % (i as u64 + 1)) as usize);
            }
            let gravity = cloth.material().gravity;
            let shuffled = rebuilt(&cloth, &order, 1.0, 1.0, gravity);
            for (name, system) in [
                ("odd line", odd_line(damping)),
                ("cloth", cloth),
                ("shuffled cloth", shuffled),
            ] {
                let c = system.material().damping;
                let w = inverse_masses(&system);
                let n = system.len();
                // The reference: two steps of the single layout, the second from the
                // first's kept forces.
                let mut p = packed::Packed::new(packed::Instance::Detect);
                let mut states = Vec::new();
                let mut first = (Vec::new(), Vec::new(), Vec::new());
                let (mut x, mut v) = (system.positions().to_vec(), system.velocities().to_vec());
                let mut f = vec![DVec3::splat(f64::NAN); n];
                for kept in [false, true] {
                    p.load(&system, &w, &x, &v, &f, dt);
                    if !kept {
                        p.evaluate(c);
                    }
                    p.substeps(c, dt, substeps);
                    p.store(&mut x, &mut v, &mut f);
                    let spring = system.energies_of(&x, &v).spring;
                    states.push((bits(&x), bits(&v), bits(&f), spring.to_bits()));
                    if !kept {
                        first = (x.clone(), v.clone(), f.clone());
                    }
                }
                for instance in INSTANCES {
                    for (count, threads) in [(1, 1), (2, 2), (3, 2), (7, 3)] {
                        let mut parts = parts::Parts::with_instance(&system, count, instance);
                        assert_eq!(parts.len(), count);
                        let pool = rayon::ThreadPoolBuilder::new()
                            .num_threads(threads)
                            .build()
                            .unwrap();
                        let (mut x, mut v) =
                            (system.positions().to_vec(), system.velocities().to_vec());
                        let mut f = vec![DVec3::splat(f64::NAN); n];
                        for (kept, expected) in [false, true].into_iter().zip(&states) {
                            let spring = pool.install(|| {
                                parts.step(&system, &w, &mut x, &mut v, &mut f, kept, dt, substeps)
                            });
                            let case = format!(
                                "{name}, {instance:?}, {count} parts, damping {damping}, kept {kept}"
                            );
                            assert_eq!(bits(&x), expected.0, "{case}");
                            assert_eq!(bits(&v), expected.1, "{case}");
                            assert_eq!(bits(&f), expected.2, "{case}");
                            assert_eq!(spring.to_bits(), expected.3, "{case}");
                        }
                        // Fresh parts given the first step's end state and its kept
                        // forces load them, and step as the parts that held them.
                        let mut fresh = parts::Parts::with_instance(&system, count, instance);
                        let (mut x, mut v, mut f) = first.clone();
                        let spring = pool.install(|| {
                            fresh.step(&system, &w, &mut x, &mut v, &mut f, true, dt, substeps)
                        });
                        let case =
                            format!("{name}, {instance:?}, {count} fresh parts, damping {damping}");
                        assert_eq!(bits(&x), states[1].0, "{case}");
                        assert_eq!(bits(&v), states[1].1, "{case}");
                        assert_eq!(bits(&f), states[1].2, "{case}");
                        assert_eq!(spring.to_bits(), states[1].3, "{case}");
                    }
                }
            }
        }
    }

    #[test]
    fn batched_forces_are_bitwise_the_scalar_loop_with_odd_lengths() {
        for damping in [0.0, 0.3] {
            let system = odd_line(damping);
            assert_eq!(system.springs().len() % spring::BATCH, 43 % spring::BATCH);
            let (x, v) = (system.positions(), system.velocities());
            // Both kinds of batch occur: all lengths plain, and some not.
            let (mut plain, mut odd) = (0, 0);
            for batch in system.springs().chunks_exact(spring::BATCH) {
                let mut b = spring::SpringBatch::default();
                for (i, s) in batch.iter().enumerate() {
                    let d = x[s.a] - x[s.b];
                    [b.d[0][i], b.d[1][i], b.d[2][i]] = [d.x, d.y, d.z];
                    let dv = v[s.a] - v[s.b];
                    [b.dv[0][i], b.dv[1][i], b.dv[2][i]] = [dv.x, dv.y, dv.z];
                    b.rest_length[i] = s.rest_length;
                    b.stiffness[i] = s.stiffness;
                }
                match spring::gradients_of_batch(&b, damping) {
                    Some(_) => plain += 1,
                    None => odd += 1,
                }
            }
            assert!(plain >= 2 && odd >= 4, "plain {plain}, odd {odd}");
            let mut out = vec![DVec3::splat(f64::NAN); system.len()];
            negated_forces(&system, x, v, &mut out);
            let expected = scalar_negated_forces(&system, x, v);
            assert!(expected.iter().all(|f| f.is_finite()));
            assert_eq!(bits(&out), bits(&expected), "damping {damping}");
            // The threaded path's per-spring pass, on one batch list.
            let mut per_spring = vec![DVec3::ZERO; system.springs().len()];
            for_each_spring_force(system.springs(), x, v, damping, |k, _, g| {
                per_spring[k] = g;
            });
            let scalar: Vec<DVec3> = system
                .springs()
                .iter()
                .map(|s| spring_force(s, x, v, damping))
                .collect();
            assert_eq!(bits(&per_spring), bits(&scalar), "damping {damping}");
            // With the energies: the same forces, and each energy bitwise the scalar
            // kernel's from the positions (from the batch's lengths where it is plain).
            let mut energies = vec![f64::NAN; system.springs().len()];
            for_each_spring::<true>(system.springs(), x, v, damping, |k, _, g, e| {
                per_spring[k] = g;
                energies[k] = e;
            });
            assert_eq!(bits(&per_spring), bits(&scalar), "damping {damping}");
            let expected: Vec<u64> = system
                .springs()
                .iter()
                .map(|s| spring::energy(x[s.a], x[s.b], s.rest_length, s.stiffness).to_bits())
                .collect();
            let got: Vec<u64> = energies.iter().map(|e| e.to_bits()).collect();
            assert_eq!(got, expected, "damping {damping}");
        }
    }
}
