//! Velocity Verlet's substeps on the calling thread in a layout made for them: every
//! particle's position, velocity and force as four lanes `x, y, z, 0`, and the springs
//! in batches of [`BATCH`] with their ends, rest lengths and stiffnesses side by side.
//! With AVX2 (detected at run time) an instance written with its intrinsics runs the
//! same operations in 256-bit registers.
//!
//! The results are bitwise those of [`super::negated_forces`] and of the stepper's loop
//! over `DVec3`s: each lane is computed by the same floating-point operations in the same
//! order, and every particle receives its additions in spring order. The design and the
//! measurements are in docs/spring-sim.md ("Four lanes per particle").

use crate::model::SpringSystem;
use crate::potential::AxialDamping;
use crate::spring;
use sinew_math::DVec3;

/// A particle's vector as lanes `x, y, z, 0`: one packed load, subtraction or addition
/// with AVX (two with SSE2) instead of a pair and a single. Aligned to its 32 bytes, so
/// no access straddles two cache lines.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(32))]
pub(super) struct Lanes([f64; 4]);

impl std::ops::Index<usize> for Lanes {
    type Output = f64;
    #[inline(always)]
    fn index(&self, j: usize) -> &f64 {
        &self.0[j]
    }
}

impl std::ops::IndexMut<usize> for Lanes {
    #[inline(always)]
    fn index_mut(&mut self, j: usize) -> &mut f64 {
        &mut self.0[j]
    }
}

/// Springs per batch: the four `f64` lanes of an AVX register, and the batch of
/// [`spring::gradients_of_batch`], which the portable instance calls.
const BATCH: usize = 4;
const _: () = assert!(BATCH == spring::BATCH);

/// [`BATCH`] springs: lane `i` is the batch's `i`-th spring.
#[derive(Clone, Copy, Debug, Default)]
struct Batch {
    a: [u32; BATCH],
    b: [u32; BATCH],
    rest_length: [f64; BATCH],
    stiffness: [f64; BATCH],
}

/// One thread's share of a system stepped on several threads ([`super::parts`]): a
/// contiguous range of the system's particles (its own), the springs with an end among
/// them, and the other ends of those springs (its halo), which it reads and never
/// advances.
///
/// A layout holding a part numbers its particles locally: the own particles first, in
/// the system's order, then the halo. Every own particle has all its springs in the part,
/// in the system's order, so its sum is the same as the whole system's; a spring between
/// two parts is computed by both (the same operations on the same values), each adding
/// its term to its own end only (the term added to a halo particle is never read).
#[derive(Clone, Debug, Default)]
pub(super) struct Part {
    /// The system's index of each local particle: the own ones, then the halo.
    pub(super) particles: Vec<usize>,
    /// How many of `particles` are the part's own.
    pub(super) own: usize,
    /// The part's springs (an end among the own particles), the system's indices in the
    /// system's order.
    pub(super) springs: Vec<usize>,
    /// Each of `springs`' ends in the local numbering.
    pub(super) ends: Vec<(usize, usize)>,
}

/// One pass of the packed loop ([`Packed::run`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Pass {
    /// Minus the forces at the loaded state: the sums started at `0 - m g`, then the
    /// springs' terms.
    Evaluate,
    /// A substep's particle pass: the closing kick of the substep before (when
    /// `closing`), the opening kick and the drift, and the next evaluation's sums
    /// started at `0 - m g` (the force was read just before).
    Particles { closing: bool },
    /// The springs' terms added to the sums the particle pass started; with `energy`,
    /// each spring's elastic energy into [`Packed::energy`].
    Springs { energy: bool },
    /// The last substep's closing kick.
    CloseKick,
}

/// The packed state and springs of a [`super::VelocityVerlet`] stepping on the calling
/// thread, or of one part of the system on one of several threads ([`Part`]). The state
/// is loaded at every step (on several threads, only when the layout may not hold it);
/// the masses and gravity when `dt` or the gravity changed, the rest lengths and
/// stiffnesses when their fingerprint changed; the spring order and the batches' ends,
/// which depend only on the spring pairs, at the first.
#[derive(Clone, Debug, Default)]
pub(super) struct Packed {
    /// The springs in the order they are computed ([`schedule`]), and the batches' ends,
    /// built at the first load: the stepper only steps systems of its own spring pairs
    /// (its topology check).
    order: Vec<usize>,
    batches: Vec<Batch>,
    /// The particle arrays' length less one, a power of two less one: a spring's end
    /// masked by it is in bounds of all of them, so indexing needs no check. The arrays
    /// hold two particles more than the system at least ([`Self::load`]).
    mask: usize,
    x: Vec<Lanes>,
    v: Vec<Lanes>,
    /// Minus the forces of the last evaluation.
    neg_forces: Vec<Lanes>,
    /// Minus gravity's force, `0 - m g`, the start of every evaluation.
    gravity: Vec<Lanes>,
    /// `dt/2 / m`, 0 for fixed particles and for the padding.
    half_inv_mass: Vec<f64>,
    /// The part of the system this layout holds ([`Part`]); `None`: the whole system,
    /// numbered as the system numbers it.
    part: Option<Part>,
    /// Each scheduled spring's elastic energy at the last [`Pass::Springs`] that asked
    /// for it, by its place in `order`.
    energies: Vec<f64>,
    /// The system's index of the spring at each place of `order`.
    spring_of_slot: Vec<usize>,
    /// The bits of `dt` and of the gravity `gravity` and `half_inv_mass` were filled
    /// for.
    loaded: Option<(u64, [u64; 3])>,
    /// The fingerprint ([`SpringSystem::spring_constants`]) of the rest lengths and
    /// stiffnesses in the batches.
    constants: Option<u64>,
    /// Whether to run the AVX2 instance (the processor has it).
    #[cfg(target_arch = "x86_64")]
    avx2: bool,
}

/// Which instance of the packed code runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Instance {
    /// AVX2 when the processor has it, else [`Instance::Portable`].
    Detect,
    /// The code compiled for the target's baseline (SSE2 on x86_64), which the
    /// tests compare with the AVX2 one.
    #[cfg(test)]
    Portable,
}

impl Packed {
    /// An empty layout; [`Self::load`] fills it.
    pub(super) fn new(instance: Instance) -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            // `std` caches the answer.
            let avx2 = std::arch::is_x86_feature_detected!("avx2");
            Self {
                avx2: instance == Instance::Detect && avx2,
                ..Self::default()
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = instance;
            Self::default()
        }
    }

    /// A layout for `part` of a system ([`Part`]); [`Self::load`] fills it.
    #[cfg(feature = "parallel")]
    pub(super) fn for_part(instance: Instance, part: Part) -> Self {
        Self {
            part: Some(part),
            ..Self::new(instance)
        }
    }

    /// Whether a system fits the layout (its particles and the two padding ones are
    /// numbered in 32 bits).
    pub(super) fn fits(system: &SpringSystem) -> bool {
        system.len() < u32::MAX as usize
    }

    /// The part this layout holds, `None` for the whole system.
    #[cfg(feature = "parallel")]
    pub(super) fn part(&self) -> Option<&Part> {
        self.part.as_ref()
    }

    /// The elastic energy of the spring at place `slot` of the schedule, from the last
    /// [`Pass::Springs`] with `energy`.
    #[cfg(feature = "parallel")]
    pub(super) fn energy(&self, slot: usize) -> f64 {
        self.energies[slot]
    }

    /// The place in the schedule of each of the held springs (the part's, or the
    /// system's), by their index among them.
    #[cfg(feature = "parallel")]
    pub(super) fn slots(&self) -> Vec<usize> {
        let mut slots = vec![0; self.order.len()];
        for (slot, &k) in self.order.iter().enumerate() {
            slots[k] = slot;
        }
        slots
    }

    /// Fills the layout from `system`'s springs, masses and gravity and from the state
    /// `x`, `v` and minus the forces `neg_forces` (the stepper's buffers, the whole
    /// system's), for substeps of `dt`: [`Self::prepare`], then [`Self::load_state`].
    pub(super) fn load(
        &mut self,
        system: &SpringSystem,
        inv_mass: &[f64],
        x: &[DVec3],
        v: &[DVec3],
        neg_forces: &[DVec3],
        dt: f64,
    ) {
        self.prepare(system, inv_mass, dt);
        self.load_state(x, v, neg_forces);
    }

    /// Fills everything but the state: the arrays' sizes, the padding, the schedule and
    /// the batches' ends at the first call (the stepper only steps systems of its own
    /// masses, pins and spring pairs: its topology check); each particle's `0 - m g` and
    /// `dt/2 / m` when the gravity or `dt` differ from the last call's; the springs' rest
    /// lengths and stiffnesses when their fingerprint differs from the last call's
    /// (another system of the same topology may have others).
    pub(super) fn prepare(&mut self, system: &SpringSystem, inv_mass: &[f64], dt: f64) {
        let n = self
            .part
            .as_ref()
            .map_or(system.len(), |p| p.particles.len());
        let springs = system.springs();
        let held = self
            .part
            .as_ref()
            .map_or(springs.len(), |p| p.springs.len());
        // Two padding particles, `n` at (1, 0, 0) and `n + 1` at the origin, fixed
        // (their `dt/2 / m` is 0): a spring of stiffness 0 and rest length 1 between
        // them fills the last batch's missing lanes. Its length 1 is plain and its term
        // `0 (1 - 1 (1/1)) d` is zero, added to the padding particles only, so every
        // batch is whole and no lane count is tested in the loop. Nothing moves them.
        let size = (n + 2).next_power_of_two();
        if self.mask != size - 1 || self.order.len() != held || self.x.len() != size {
            self.mask = size - 1;
            for buffer in [
                &mut self.x,
                &mut self.v,
                &mut self.neg_forces,
                &mut self.gravity,
            ] {
                buffer.clear();
                buffer.resize(size, Lanes::default());
            }
            self.half_inv_mass.clear();
            self.half_inv_mass.resize(size, 0.0);
            self.x[n] = Lanes([1.0, 0.0, 0.0, 0.0]);
            self.loaded = None;
            self.constants = None;
            let ends: Vec<(usize, usize)> = match &self.part {
                None => springs.iter().map(|s| (s.a, s.b)).collect(),
                Some(part) => part.ends.clone(),
            };
            self.order = schedule(n, &ends);
            self.batches.clear();
            self.spring_of_slot.clear();
            for chunk in self.order.chunks(BATCH) {
                let mut b = Batch {
                    a: [n as u32; BATCH],
                    b: [n as u32 + 1; BATCH],
                    rest_length: [1.0; BATCH],
                    stiffness: [0.0; BATCH],
                };
                for (i, &k) in chunk.iter().enumerate() {
                    (b.a[i], b.b[i]) = (ends[k].0 as u32, ends[k].1 as u32);
                    let spring = self.part.as_ref().map_or(k, |p| p.springs[k]);
                    self.spring_of_slot.push(spring);
                }
                self.batches.push(b);
            }
            self.energies = vec![0.0; self.batches.len() * BATCH];
        }
        let gravity = system.material().gravity;
        let key = (dt.to_bits(), gravity.to_array().map(f64::to_bits));
        if self.loaded != Some(key) {
            self.loaded = Some(key);
            // `DVec3::ZERO - m g`, the start of `negated_forces`.
            let start = |m: f64| {
                let mut f = DVec3::ZERO;
                f -= m * gravity;
                Lanes([f.x, f.y, f.z, 0.0])
            };
            let half = 0.5 * dt;
            let masses = system.masses();
            let mut fill = |j: usize, i: usize| {
                self.gravity[j] = start(masses[i]);
                self.half_inv_mass[j] = half * inv_mass[i];
            };
            match &self.part {
                None => (0..n).for_each(|i| fill(i, i)),
                // The halo is never advanced: no gravity and no kick (the defaults it
                // keeps), so its sums, which nobody reads, stay those of its cut springs.
                Some(part) => {
                    for (j, &i) in part.particles[..part.own].iter().enumerate() {
                        fill(j, i);
                    }
                }
            }
        }
        if self.constants != Some(system.spring_constants()) {
            self.constants = Some(system.spring_constants());
            for (b, slots) in self
                .batches
                .iter_mut()
                .zip(self.spring_of_slot.chunks(BATCH))
            {
                for (i, &k) in slots.iter().enumerate() {
                    let s = &springs[k];
                    b.rest_length[i] = s.rest_length;
                    b.stiffness[i] = s.stiffness;
                }
            }
        }
    }

    /// Loads the state `x`, `v` and minus the forces `neg_forces` (the whole system's)
    /// into the prepared layout.
    pub(super) fn load_state(&mut self, x: &[DVec3], v: &[DVec3], neg_forces: &[DVec3]) {
        let lanes = |p: &DVec3| Lanes([p.x, p.y, p.z, 0.0]);
        match &self.part {
            None => {
                for (buffer, from) in [
                    (&mut self.x, x),
                    (&mut self.v, v),
                    (&mut self.neg_forces, neg_forces),
                ] {
                    for (l, p) in buffer.iter_mut().zip(from) {
                        *l = lanes(p);
                    }
                }
            }
            Some(part) => {
                for (j, &i) in part.particles.iter().enumerate() {
                    self.x[j] = lanes(&x[i]);
                    self.v[j] = lanes(&v[i]);
                    self.neg_forces[j] = lanes(&neg_forces[i]);
                }
            }
        }
    }

    /// Writes the state and minus the forces back into the stepper's buffers: the whole
    /// system's, or for a part the slices of its own particles.
    pub(super) fn store(&self, x: &mut [DVec3], v: &mut [DVec3], neg_forces: &mut [DVec3]) {
        for (buffer, from) in [(x, &self.x), (v, &self.v), (neg_forces, &self.neg_forces)] {
            for (p, l) in buffer.iter_mut().zip(from) {
                *p = DVec3::new(l[0], l[1], l[2]);
            }
        }
    }

    /// The position and velocity of local particle `i`.
    #[cfg(feature = "parallel")]
    pub(super) fn particle(&self, i: usize) -> (Lanes, Lanes) {
        (self.x[i], self.v[i])
    }

    /// Sets the position and velocity of local particle `i` (a halo particle, from the
    /// part that owns it).
    #[cfg(feature = "parallel")]
    pub(super) fn set_particle(&mut self, i: usize, (x, v): (Lanes, Lanes)) {
        (self.x[i], self.v[i]) = (x, v);
    }

    /// Minus the forces at the loaded state ([`super::negated_forces`]), with damping `c`.
    pub(super) fn evaluate(&mut self, c: f64) {
        self.run(c, 0.0, Pass::Evaluate);
    }

    /// `substeps` Verlet substeps of `dt` from the loaded state, whose forces are loaded
    /// or evaluated, ending with the last substep's closing kick (as
    /// [`super::VelocityVerlet::step`]).
    pub(super) fn substeps(&mut self, c: f64, dt: f64, substeps: usize) {
        for substep in 0..substeps {
            self.run(
                c,
                dt,
                Pass::Particles {
                    closing: substep > 0,
                },
            );
            self.run(c, dt, Pass::Springs { energy: false });
        }
        self.run(c, dt, Pass::CloseKick);
    }

    /// One pass, in the AVX2 instance when detected, else in the portable one.
    pub(super) fn run(&mut self, c: f64, dt: f64, pass: Pass) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only when `is_x86_feature_detected!("avx2")`
            // reported the feature on this processor (`Packed::new`), which is all
            // `avx2::run` requires to be called.
            #[allow(unsafe_code)]
            unsafe {
                avx2::run(self, c, dt, pass);
            }
            return;
        }
        run_portable(self, c, dt, pass);
    }
}

/// Springs per scheduled chunk ([`schedule`]): a multiple of [`BATCH`], so no batch
/// straddles two chunks.
pub(super) const SCHEDULE_CHUNK: usize = 1024;
const _: () = assert!(SCHEDULE_CHUNK.is_multiple_of(BATCH));

/// The springs' indices (into `ends`, each spring's two particles) in the order the
/// packed loop computes and adds them: in chunks of [`SCHEDULE_CHUNK`] consecutive
/// springs, in order, and within a chunk by level, a spring's level being one more than
/// the highest level of the chunk's springs before it that share a particle with it (in
/// the given order within a level).
///
/// Every particle still receives its springs' terms in the given order (the chunks keep
/// their order, and along the springs at one particle the level rises within a chunk),
/// so its sums are the same bits; and the springs of one level share no particle, so
/// the additions of neighbouring springs in the loop do not wait for each other. In the
/// given order a particle's springs come one after another (the lab pattern lists up to
/// six per particle), and each addition to its sum waited for the store of the one
/// before. The chunks keep the loop's memory local: levelled over a whole large sheet,
/// each level swept every particle again (about a dozen sweeps per force pass), while a
/// chunk of a grid's springs touches a band of a few hundred particles.
fn schedule(particles: usize, ends: &[(usize, usize)]) -> Vec<usize> {
    // The level a particle's next spring in the chunk takes at least.
    let mut next = vec![0_usize; particles];
    let mut level = Vec::with_capacity(SCHEDULE_CHUNK);
    let mut order: Vec<usize> = Vec::with_capacity(ends.len());
    for (c, chunk) in ends.chunks(SCHEDULE_CHUNK).enumerate() {
        let first = c * SCHEDULE_CHUNK;
        level.clear();
        for &(a, b) in chunk {
            let l = next[a].max(next[b]);
            level.push(l);
            (next[a], next[b]) = (l + 1, l + 1);
        }
        for &(a, b) in chunk {
            (next[a], next[b]) = (0, 0);
        }
        let start = order.len();
        order.extend(first..first + chunk.len());
        // Stable: the given order within a level.
        order[start..].sort_by_key(|&k| level[k - first]);
    }
    order
}

/// [`run_lanes`] for the target's baseline (SSE2 on x86_64).
fn run_portable(p: &mut Packed, c: f64, dt: f64, pass: Pass) {
    run_lanes(p, c, dt, pass);
}

/// The portable body of one pass.
///
/// A substep's closing kick, the next one's opening kick and drift read the same force
/// and nothing between them reads the state, so they run in one pass over the
/// particles, which also starts the next evaluation's sums at `0 - m g` (the force was
/// read just before): the same operations on every particle in the same order as the
/// stepper's loop over `DVec3`s.
#[inline(always)]
fn run_lanes(p: &mut Packed, c: f64, dt: f64, pass: Pass) {
    let size = p.mask + 1;
    let (x, v, f) = (
        &mut p.x[..size],
        &mut p.v[..size],
        &mut p.neg_forces[..size],
    );
    let (gravity, w) = (&p.gravity[..size], &p.half_inv_mass[..size]);
    match pass {
        Pass::Evaluate => {
            f.copy_from_slice(gravity);
            add_springs::<false>(&p.batches, p.mask, x, v, c, f, &mut []);
        }
        Pass::Particles { closing } => {
            let kicks = if closing { 2 } else { 1 };
            for ((((xi, vi), fi), gi), &wi) in x
                .iter_mut()
                .zip(v.iter_mut())
                .zip(f.iter_mut())
                .zip(gravity)
                .zip(w)
            {
                let (mut xn, mut vn, fo) = (*xi, *vi, *fi);
                for _ in 0..kicks {
                    for j in 0..4 {
                        vn[j] -= wi * fo[j];
                    }
                }
                for j in 0..4 {
                    xn[j] += dt * vn[j];
                }
                (*xi, *vi, *fi) = (xn, vn, *gi);
            }
        }
        Pass::Springs { energy: false } => {
            add_springs::<false>(&p.batches, p.mask, x, v, c, f, &mut []);
        }
        Pass::Springs { energy: true } => {
            add_springs::<true>(&p.batches, p.mask, x, v, c, f, &mut p.energies);
        }
        Pass::CloseKick => {
            for ((vi, fi), &wi) in v.iter_mut().zip(f.iter()).zip(w) {
                let mut vn = *vi;
                for j in 0..4 {
                    vn[j] -= wi * fi[j];
                }
                *vi = vn;
            }
        }
    }
}

/// Adds each spring's term of minus the force to `f` (its gradient, plus the axial
/// damping's when `c > 0`), in spring order: `+g` on its first particle, `-g` on its
/// second; with `ENERGY`, each spring's elastic energy into `energies` (by its place in
/// the schedule).
#[inline(always)]
fn add_springs<const ENERGY: bool>(
    batches: &[Batch],
    mask: usize,
    x: &[Lanes],
    v: &[Lanes],
    c: f64,
    f: &mut [Lanes],
    energies: &mut [f64],
) {
    let (x, v, f) = (&x[..=mask], &v[..=mask], &mut f[..=mask]);
    for (k, b) in batches.iter().enumerate() {
        let e = add_batch(b, mask, x, v, c, f);
        if ENERGY {
            energies[k * BATCH..(k + 1) * BATCH].copy_from_slice(&e);
        }
    }
}

/// One batch's terms; returns the batch's elastic energies.
#[inline(always)]
fn add_batch(
    b: &Batch,
    mask: usize,
    x: &[Lanes],
    v: &[Lanes],
    c: f64,
    f: &mut [Lanes],
) -> [f64; BATCH] {
    let ends = |i: usize| (b.a[i] as usize & mask, b.b[i] as usize & mask);
    match gradients(b, mask, x, v, c) {
        Some((g, l)) => {
            for (i, g) in g.iter().enumerate() {
                let (a, e) = ends(i);
                for j in 0..4 {
                    f[a][j] += g[j];
                }
                for j in 0..4 {
                    f[e][j] -= g[j];
                }
            }
            let mut energies = [0.0; BATCH];
            for (i, e) in energies.iter_mut().enumerate() {
                *e = spring::energy_at_length(l[i], b.rest_length[i], b.stiffness[i]);
            }
            energies
        }
        None => add_scalar(b, mask, x, v, c, f),
    }
}

/// A batch's springs by the scalar kernels ([`spring::gradient`] and
/// [`AxialDamping::rate_gradient`]), spring by spring: the batch has a length outside
/// the plain range, which those kernels' other branches handle. Returns the springs'
/// elastic energies ([`spring::energy`]).
fn add_scalar(
    b: &Batch,
    mask: usize,
    x: &[Lanes],
    v: &[Lanes],
    c: f64,
    f: &mut [Lanes],
) -> [f64; BATCH] {
    let vector = |l: &Lanes| DVec3::new(l[0], l[1], l[2]);
    let mut energies = [0.0; BATCH];
    for (i, energy) in energies.iter_mut().enumerate() {
        let (a, e) = (b.a[i] as usize & mask, b.b[i] as usize & mask);
        let (xa, xb) = (vector(&x[a]), vector(&x[e]));
        let mut g = spring::gradient(xa, xb, b.rest_length[i], b.stiffness[i]);
        if c > 0.0 {
            g += AxialDamping::rate_gradient(c, xa - xb, vector(&v[a]) - vector(&v[e]));
        }
        *energy = spring::energy(xa, xb, b.rest_length[i], b.stiffness[i]);
        let g = [g.x, g.y, g.z];
        for j in 0..3 {
            f[a][j] += g[j];
        }
        for j in 0..3 {
            f[e][j] -= g[j];
        }
    }
    energies
}

/// The batch's terms `g` as lanes (the fourth 0) and its lengths, by
/// [`spring::gradients_of_batch`] (whose lanes the compiler pairs into SSE2's packed
/// square roots and divisions); `None` when a length is outside `1e-150 < l < inf`.
#[inline(always)]
fn gradients(
    b: &Batch,
    mask: usize,
    x: &[Lanes],
    v: &[Lanes],
    c: f64,
) -> Option<([Lanes; BATCH], [f64; BATCH])> {
    let mut s = spring::SpringBatch {
        rest_length: b.rest_length,
        stiffness: b.stiffness,
        ..Default::default()
    };
    for i in 0..BATCH {
        let (a, e) = (b.a[i] as usize & mask, b.b[i] as usize & mask);
        for (j, d) in s.d.iter_mut().enumerate() {
            d[i] = x[a][j] - x[e][j];
        }
        if c > 0.0 {
            for (j, dv) in s.dv.iter_mut().enumerate() {
                dv[i] = v[a][j] - v[e][j];
            }
        }
    }
    let (g, l) = spring::gradients_of_batch(&s, c)?;
    let mut lanes = [Lanes::default(); BATCH];
    for (i, lanes) in lanes.iter_mut().enumerate() {
        *lanes = Lanes([g[0][i], g[1][i], g[2][i], 0.0]);
    }
    Some((lanes, l))
}

/// The AVX2 instance: a particle's lanes, and a batch's springs, are one 256-bit
/// register. Every lane goes through the floating-point operations of the portable
/// instance in the same order (no FMA is enabled, and Rust never contracts a product
/// and a sum), so the results are the same bits; the intrinsics only choose the
/// shuffles (docs/spring-sim.md).
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{BATCH, Batch, Lanes, Packed, Pass, add_scalar};
    use std::arch::x86_64::{
        __m256d, _CMP_GT_OQ, _CMP_LT_OQ, _mm256_add_pd, _mm256_and_pd, _mm256_cmp_pd,
        _mm256_cvtsd_f64, _mm256_div_pd, _mm256_movemask_pd, _mm256_mul_pd, _mm256_permute2f128_pd,
        _mm256_permute4x64_pd, _mm256_set1_pd, _mm256_setr_pd, _mm256_sqrt_pd, _mm256_sub_pd,
        _mm256_unpackhi_pd, _mm256_unpacklo_pd,
    };

    /// A particle's lanes as a register (the compiler makes it one load).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn load(l: &Lanes) -> __m256d {
        _mm256_setr_pd(l[0], l[1], l[2], l[3])
    }

    /// A register as lanes (the compiler makes it one store).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn lanes(r: __m256d) -> Lanes {
        Lanes([
            _mm256_cvtsd_f64(r),
            _mm256_cvtsd_f64(_mm256_permute4x64_pd::<1>(r)),
            _mm256_cvtsd_f64(_mm256_permute4x64_pd::<2>(r)),
            _mm256_cvtsd_f64(_mm256_permute4x64_pd::<3>(r)),
        ])
    }

    /// `(p0 + p1) + p2` of each of four registers `p_i = (p0, p1, p2, _)`, lane `i` from
    /// `p_i`: the order of `glam`'s `dot` and `length_squared`. The three used lanes are
    /// transposed into one register each, so the fourth lane takes no part.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn sums(p: [__m256d; BATCH]) -> __m256d {
        // (a0, b0, a2, b2) and (a1, b1, a3, b3) for the pairs (0, 1) and (2, 3).
        let low01 = _mm256_unpacklo_pd(p[0], p[1]);
        let high01 = _mm256_unpackhi_pd(p[0], p[1]);
        let low23 = _mm256_unpacklo_pd(p[2], p[3]);
        let high23 = _mm256_unpackhi_pd(p[2], p[3]);
        let first = _mm256_permute2f128_pd::<0x20>(low01, low23);
        let second = _mm256_permute2f128_pd::<0x20>(high01, high23);
        let third = _mm256_permute2f128_pd::<0x31>(low01, low23);
        _mm256_add_pd(_mm256_add_pd(first, second), third)
    }

    /// One lane of `r` in every lane: `I` is the permutation's immediate, `0x00`,
    /// `0x55`, `0xAA` or `0xFF` for lane 0, 1, 2 or 3.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn splat<const I: i32>(r: __m256d) -> __m256d {
        _mm256_permute4x64_pd::<I>(r)
    }

    /// One pass of [`super::run_lanes`] in 256-bit registers.
    #[target_feature(enable = "avx2")]
    pub(super) fn run(p: &mut Packed, c: f64, dt: f64, pass: Pass) {
        let size = p.mask + 1;
        let (x, v, f) = (
            &mut p.x[..size],
            &mut p.v[..size],
            &mut p.neg_forces[..size],
        );
        let (gravity, w) = (&p.gravity[..size], &p.half_inv_mass[..size]);
        match pass {
            Pass::Evaluate => {
                f.copy_from_slice(gravity);
                add_springs::<false>(&p.batches, p.mask, x, v, c, f, &mut []);
            }
            Pass::Particles { closing } => {
                let step = _mm256_set1_pd(dt);
                for ((((xi, vi), fi), gi), &wi) in x
                    .iter_mut()
                    .zip(v.iter_mut())
                    .zip(f.iter_mut())
                    .zip(gravity)
                    .zip(w)
                {
                    let kick = _mm256_mul_pd(_mm256_set1_pd(wi), load(fi));
                    let mut vn = load(vi);
                    if closing {
                        vn = _mm256_sub_pd(vn, kick);
                    }
                    vn = _mm256_sub_pd(vn, kick);
                    *xi = lanes(_mm256_add_pd(load(xi), _mm256_mul_pd(step, vn)));
                    *vi = lanes(vn);
                    *fi = *gi;
                }
            }
            Pass::Springs { energy: false } => {
                add_springs::<false>(&p.batches, p.mask, x, v, c, f, &mut []);
            }
            Pass::Springs { energy: true } => {
                add_springs::<true>(&p.batches, p.mask, x, v, c, f, &mut p.energies);
            }
            Pass::CloseKick => {
                for ((vi, fi), &wi) in v.iter_mut().zip(f.iter()).zip(w) {
                    let kick = _mm256_mul_pd(_mm256_set1_pd(wi), load(fi));
                    *vi = lanes(_mm256_sub_pd(load(vi), kick));
                }
            }
        }
    }

    /// [`super::add_springs`] in 256-bit registers: each batch's terms as
    /// [`super::gradients`] computes them, added as [`super::add_batch`] adds them, with
    /// the damping's test made once (`DAMPED` is `c > 0`); with `ENERGY`, each spring's
    /// elastic energy into `energies`. (One function: a `#[target_feature]` function
    /// cannot be `#[inline(always)]`, and a call per batch cost its registers.)
    #[inline]
    #[target_feature(enable = "avx2")]
    fn add_springs<const ENERGY: bool>(
        batches: &[Batch],
        mask: usize,
        x: &[Lanes],
        v: &[Lanes],
        c: f64,
        f: &mut [Lanes],
        energies: &mut [f64],
    ) {
        if c > 0.0 {
            add_springs_with::<true, ENERGY>(batches, mask, x, v, c, f, energies);
        } else {
            add_springs_with::<false, ENERGY>(batches, mask, x, v, c, f, energies);
        }
    }

    /// [`add_springs`] with the damping (`DAMPED`) or without.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn add_springs_with<const DAMPED: bool, const ENERGY: bool>(
        batches: &[Batch],
        mask: usize,
        x: &[Lanes],
        v: &[Lanes],
        c: f64,
        f: &mut [Lanes],
        energies: &mut [f64],
    ) {
        let (x, v, f) = (&x[..=mask], &v[..=mask], &mut f[..=mask]);
        for (k, b) in batches.iter().enumerate() {
            let mut ends = [(0, 0); BATCH];
            for (i, end) in ends.iter_mut().enumerate() {
                *end = (b.a[i] as usize & mask, b.b[i] as usize & mask);
            }
            let difference =
                |y: &[Lanes], (a, e): (usize, usize)| _mm256_sub_pd(load(&y[a]), load(&y[e]));
            let d = [
                difference(x, ends[0]),
                difference(x, ends[1]),
                difference(x, ends[2]),
                difference(x, ends[3]),
            ];
            let l2 = sums([
                _mm256_mul_pd(d[0], d[0]),
                _mm256_mul_pd(d[1], d[1]),
                _mm256_mul_pd(d[2], d[2]),
                _mm256_mul_pd(d[3], d[3]),
            ]);
            let l = _mm256_sqrt_pd(l2);
            let plain = _mm256_and_pd(
                _mm256_cmp_pd::<_CMP_GT_OQ>(l, _mm256_set1_pd(1e-150)),
                _mm256_cmp_pd::<_CMP_LT_OQ>(l, _mm256_set1_pd(f64::INFINITY)),
            );
            if _mm256_movemask_pd(plain) != 0b1111 {
                let e = add_scalar(b, mask, x, v, c, f);
                if ENERGY {
                    energies[k * BATCH..(k + 1) * BATCH].copy_from_slice(&e);
                }
                continue;
            }
            let one = _mm256_set1_pd(1.0);
            let inverse = _mm256_div_pd(one, l);
            let rest = _mm256_setr_pd(
                b.rest_length[0],
                b.rest_length[1],
                b.rest_length[2],
                b.rest_length[3],
            );
            let stiffness = _mm256_setr_pd(
                b.stiffness[0],
                b.stiffness[1],
                b.stiffness[2],
                b.stiffness[3],
            );
            let scale = _mm256_mul_pd(stiffness, _mm256_sub_pd(one, _mm256_mul_pd(rest, inverse)));
            let mut g = [
                _mm256_mul_pd(splat::<0x00>(scale), d[0]),
                _mm256_mul_pd(splat::<0x55>(scale), d[1]),
                _mm256_mul_pd(splat::<0xAA>(scale), d[2]),
                _mm256_mul_pd(splat::<0xFF>(scale), d[3]),
            ];
            if DAMPED {
                let dot = sums([
                    _mm256_mul_pd(d[0], difference(v, ends[0])),
                    _mm256_mul_pd(d[1], difference(v, ends[1])),
                    _mm256_mul_pd(d[2], difference(v, ends[2])),
                    _mm256_mul_pd(d[3], difference(v, ends[3])),
                ]);
                let rate = _mm256_div_pd(_mm256_mul_pd(_mm256_set1_pd(c), dot), l2);
                g[0] = _mm256_add_pd(g[0], _mm256_mul_pd(splat::<0x00>(rate), d[0]));
                g[1] = _mm256_add_pd(g[1], _mm256_mul_pd(splat::<0x55>(rate), d[1]));
                g[2] = _mm256_add_pd(g[2], _mm256_mul_pd(splat::<0xAA>(rate), d[2]));
                g[3] = _mm256_add_pd(g[3], _mm256_mul_pd(splat::<0xFF>(rate), d[3]));
            }
            for (&(a, e), &g) in ends.iter().zip(&g) {
                f[a] = lanes(_mm256_add_pd(load(&f[a]), g));
                f[e] = lanes(_mm256_sub_pd(load(&f[e]), g));
            }
            if ENERGY {
                // `k/2 (l - L)^2` as `spring::energy_at_length` orders it:
                // `((0.5 k) (l - L)) (l - L)`.
                let stretch = _mm256_sub_pd(l, rest);
                let e = _mm256_mul_pd(
                    _mm256_mul_pd(_mm256_mul_pd(_mm256_set1_pd(0.5), stiffness), stretch),
                    stretch,
                );
                let e = lanes(e);
                energies[k * BATCH..(k + 1) * BATCH].copy_from_slice(&e.0);
            }
        }
    }
}
