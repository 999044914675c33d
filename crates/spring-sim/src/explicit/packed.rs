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

/// The packed state and springs of a [`super::VelocityVerlet`] stepping on the calling
/// thread. The state, masses, gravity, rest lengths and stiffnesses are refilled from
/// the system and the stepper at every step (one pass over the particles and the springs
/// against the tens of substeps it serves); the spring order and the batches' ends,
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

    /// Whether a system fits the layout (its particles and the two padding ones are
    /// numbered in 32 bits).
    pub(super) fn fits(system: &SpringSystem) -> bool {
        system.len() < u32::MAX as usize
    }

    /// Fills the layout from `system`'s springs, masses and gravity and from the state
    /// `x`, `v` and minus the forces `neg_forces` (the stepper's buffers), for substeps of
    /// `dt`.
    pub(super) fn load(
        &mut self,
        system: &SpringSystem,
        inv_mass: &[f64],
        x: &[DVec3],
        v: &[DVec3],
        neg_forces: &[DVec3],
        dt: f64,
    ) {
        let n = system.len();
        // Two padding particles, `n` at (1, 0, 0) and `n + 1` at the origin, fixed
        // (their `dt/2 / m` is 0): a spring of stiffness 0 and rest length 1 between
        // them fills the last batch's missing lanes. Its length 1 is plain and its term
        // `0 (1 - 1 (1/1)) d` is zero, added to the padding particles only, so every
        // batch is whole and no lane count is tested in the loop.
        let size = (n + 2).next_power_of_two();
        self.mask = size - 1;
        let lanes = |p: &DVec3| Lanes([p.x, p.y, p.z, 0.0]);
        for (buffer, from) in [
            (&mut self.x, x),
            (&mut self.v, v),
            (&mut self.neg_forces, neg_forces),
        ] {
            buffer.clear();
            buffer.extend(from.iter().map(lanes));
            buffer.resize(size, Lanes::default());
        }
        self.x[n] = Lanes([1.0, 0.0, 0.0, 0.0]);
        let gravity = system.material().gravity;
        self.gravity.clear();
        self.gravity.extend(system.masses().iter().map(|&m| {
            // `DVec3::ZERO - m g`, the start of `negated_forces`.
            let mut f = DVec3::ZERO;
            f -= m * gravity;
            lanes(&f)
        }));
        self.gravity.resize(size, Lanes::default());
        let half = 0.5 * dt;
        self.half_inv_mass.clear();
        self.half_inv_mass.extend(inv_mass.iter().map(|w| half * w));
        self.half_inv_mass.resize(size, 0.0);
        let springs = system.springs();
        if self.order.len() != springs.len() {
            self.order = schedule(n, springs);
            self.batches.clear();
            for chunk in self.order.chunks(BATCH) {
                let mut b = Batch {
                    a: [n as u32; BATCH],
                    b: [n as u32 + 1; BATCH],
                    rest_length: [1.0; BATCH],
                    stiffness: [0.0; BATCH],
                };
                for (i, &k) in chunk.iter().enumerate() {
                    (b.a[i], b.b[i]) = (springs[k].a as u32, springs[k].b as u32);
                }
                self.batches.push(b);
            }
        }
        // The rest lengths and stiffnesses are read at every step, the ends (like the
        // order) only with the order.
        for (b, chunk) in self.batches.iter_mut().zip(self.order.chunks(BATCH)) {
            for (i, &k) in chunk.iter().enumerate() {
                b.rest_length[i] = springs[k].rest_length;
                b.stiffness[i] = springs[k].stiffness;
            }
        }
    }

    /// Writes the state and minus the forces back into the stepper's buffers.
    pub(super) fn store(&self, x: &mut [DVec3], v: &mut [DVec3], neg_forces: &mut [DVec3]) {
        for (buffer, from) in [(x, &self.x), (v, &self.v), (neg_forces, &self.neg_forces)] {
            for (p, l) in buffer.iter_mut().zip(from) {
                *p = DVec3::new(l[0], l[1], l[2]);
            }
        }
    }

    /// Minus the forces at the loaded state ([`super::negated_forces`]), with damping `c`.
    pub(super) fn evaluate(&mut self, c: f64) {
        self.run(c, 0.0, 0, true);
    }

    /// `substeps` Verlet substeps of `dt` from the loaded state, whose forces are loaded
    /// or evaluated, ending with the last substep's closing kick (as
    /// [`super::VelocityVerlet::step`]).
    pub(super) fn substeps(&mut self, c: f64, dt: f64, substeps: usize) {
        self.run(c, dt, substeps, false);
    }

    /// The AVX2 instance when detected, else the portable one.
    fn run(&mut self, c: f64, dt: f64, substeps: usize, evaluate_only: bool) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only when `is_x86_feature_detected!("avx2")`
            // reported the feature on this processor (`Packed::new`), which is all
            // `avx2::run` requires to be called.
            #[allow(unsafe_code)]
            unsafe {
                avx2::run(self, c, dt, substeps, evaluate_only);
            }
            return;
        }
        run_portable(self, c, dt, substeps, evaluate_only);
    }
}

/// The springs' indices in the order the packed loop computes and adds them: by level,
/// a spring's level being one more than the highest level of the springs before it
/// (in the system's order) that share a particle with it, and in the system's order
/// within a level.
///
/// Every particle still receives its springs' terms in the system's order (along the
/// springs at one particle the level rises), so its sums are the same bits; and the
/// springs of one level share no particle, so the additions of neighbouring springs
/// in the loop do not wait for each other. In the system's order a particle's springs
/// come one after another (the lab pattern lists up to six per particle), and each
/// addition to its sum waited for the store of the one before.
fn schedule(particles: usize, springs: &[crate::model::Spring]) -> Vec<usize> {
    // The level a particle's next spring takes at least.
    let mut next = vec![0_usize; particles];
    let mut level = Vec::with_capacity(springs.len());
    for s in springs {
        let l = next[s.a].max(next[s.b]);
        level.push(l);
        (next[s.a], next[s.b]) = (l + 1, l + 1);
    }
    let mut order: Vec<usize> = (0..springs.len()).collect();
    // Stable: the system's order within a level.
    order.sort_by_key(|&k| level[k]);
    order
}

/// [`run_lanes`] for the target's baseline (SSE2 on x86_64).
fn run_portable(p: &mut Packed, c: f64, dt: f64, substeps: usize, evaluate_only: bool) {
    run_lanes(p, c, dt, substeps, evaluate_only);
}

/// The portable body: one force evaluation, or the substeps.
///
/// A substep's closing kick, the next one's opening kick and drift read the same force
/// and nothing between them reads the state, so they run in one pass over the
/// particles, which also starts the next evaluation's sums at `0 - m g` (the force was
/// read just before): the same operations on every particle in the same order as the
/// stepper's loop over `DVec3`s.
#[inline(always)]
fn run_lanes(p: &mut Packed, c: f64, dt: f64, substeps: usize, evaluate_only: bool) {
    let size = p.mask + 1;
    let (x, v, f) = (
        &mut p.x[..size],
        &mut p.v[..size],
        &mut p.neg_forces[..size],
    );
    let (gravity, w) = (&p.gravity[..size], &p.half_inv_mass[..size]);
    if evaluate_only {
        f.copy_from_slice(gravity);
        add_springs(&p.batches, p.mask, x, v, c, f);
        return;
    }
    for substep in 0..substeps {
        let kicks = if substep > 0 { 2 } else { 1 };
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
        add_springs(&p.batches, p.mask, x, v, c, f);
    }
    for ((vi, fi), &wi) in v.iter_mut().zip(f.iter()).zip(w) {
        let mut vn = *vi;
        for j in 0..4 {
            vn[j] -= wi * fi[j];
        }
        *vi = vn;
    }
}

/// Adds each spring's term of minus the force to `f` (its gradient, plus the axial
/// damping's when `c > 0`), in spring order: `+g` on its first particle, `-g` on its
/// second.
#[inline(always)]
fn add_springs(batches: &[Batch], mask: usize, x: &[Lanes], v: &[Lanes], c: f64, f: &mut [Lanes]) {
    let (x, v, f) = (&x[..=mask], &v[..=mask], &mut f[..=mask]);
    for b in batches {
        add_batch(b, mask, x, v, c, f);
    }
}

/// One batch's terms.
#[inline(always)]
fn add_batch(b: &Batch, mask: usize, x: &[Lanes], v: &[Lanes], c: f64, f: &mut [Lanes]) {
    let ends = |i: usize| (b.a[i] as usize & mask, b.b[i] as usize & mask);
    match gradients(b, mask, x, v, c) {
        Some(g) => {
            for (i, g) in g.iter().enumerate() {
                let (a, e) = ends(i);
                for j in 0..4 {
                    f[a][j] += g[j];
                }
                for j in 0..4 {
                    f[e][j] -= g[j];
                }
            }
        }
        None => add_scalar(b, mask, x, v, c, f),
    }
}

/// A batch's springs by the scalar kernels ([`spring::gradient`] and
/// [`AxialDamping::rate_gradient`]), spring by spring: the batch has a length outside
/// the plain range, which those kernels' other branches handle.
fn add_scalar(b: &Batch, mask: usize, x: &[Lanes], v: &[Lanes], c: f64, f: &mut [Lanes]) {
    let vector = |l: &Lanes| DVec3::new(l[0], l[1], l[2]);
    for i in 0..BATCH {
        let (a, e) = (b.a[i] as usize & mask, b.b[i] as usize & mask);
        let (xa, xb) = (vector(&x[a]), vector(&x[e]));
        let mut g = spring::gradient(xa, xb, b.rest_length[i], b.stiffness[i]);
        if c > 0.0 {
            g += AxialDamping::rate_gradient(c, xa - xb, vector(&v[a]) - vector(&v[e]));
        }
        let g = [g.x, g.y, g.z];
        for j in 0..3 {
            f[a][j] += g[j];
        }
        for j in 0..3 {
            f[e][j] -= g[j];
        }
    }
}

/// The batch's terms `g` as lanes (the fourth 0), by [`spring::gradients_of_batch`]
/// (whose lanes the compiler pairs into SSE2's packed square roots and divisions);
/// `None` when a length is outside `1e-150 < l < inf`.
#[inline(always)]
fn gradients(b: &Batch, mask: usize, x: &[Lanes], v: &[Lanes], c: f64) -> Option<[Lanes; BATCH]> {
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
    let (g, _) = spring::gradients_of_batch(&s, c)?;
    let mut lanes = [Lanes::default(); BATCH];
    for (i, lanes) in lanes.iter_mut().enumerate() {
        *lanes = Lanes([g[0][i], g[1][i], g[2][i], 0.0]);
    }
    Some(lanes)
}

/// The AVX2 instance: a particle's lanes, and a batch's springs, are one 256-bit
/// register. Every lane goes through the floating-point operations of the portable
/// instance in the same order (no FMA is enabled, and Rust never contracts a product
/// and a sum), so the results are the same bits; the intrinsics only choose the
/// shuffles (docs/spring-sim.md).
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{BATCH, Batch, Lanes, Packed, add_scalar};
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

    /// The substeps (or one evaluation) of [`super::run_lanes`] in 256-bit registers.
    #[target_feature(enable = "avx2")]
    pub(super) fn run(p: &mut Packed, c: f64, dt: f64, substeps: usize, evaluate_only: bool) {
        let size = p.mask + 1;
        let (x, v, f) = (
            &mut p.x[..size],
            &mut p.v[..size],
            &mut p.neg_forces[..size],
        );
        let (gravity, w) = (&p.gravity[..size], &p.half_inv_mass[..size]);
        if evaluate_only {
            f.copy_from_slice(gravity);
            add_springs(&p.batches, p.mask, x, v, c, f);
            return;
        }
        let step = _mm256_set1_pd(dt);
        for substep in 0..substeps {
            let closing = substep > 0;
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
            add_springs(&p.batches, p.mask, x, v, c, f);
        }
        for ((vi, fi), &wi) in v.iter_mut().zip(f.iter()).zip(w) {
            let kick = _mm256_mul_pd(_mm256_set1_pd(wi), load(fi));
            *vi = lanes(_mm256_sub_pd(load(vi), kick));
        }
    }

    /// [`super::add_springs`] in 256-bit registers: each batch's terms as
    /// [`super::gradients`] computes them, added as [`super::add_batch`] adds them, with
    /// the damping's test made once (`DAMPED` is `c > 0`). (One function: a
    /// `#[target_feature]` function cannot be `#[inline(always)]`, and a call per batch
    /// cost its registers.)
    #[inline]
    #[target_feature(enable = "avx2")]
    fn add_springs(
        batches: &[Batch],
        mask: usize,
        x: &[Lanes],
        v: &[Lanes],
        c: f64,
        f: &mut [Lanes],
    ) {
        if c > 0.0 {
            add_springs_with::<true>(batches, mask, x, v, c, f);
        } else {
            add_springs_with::<false>(batches, mask, x, v, c, f);
        }
    }

    /// [`add_springs`] with the damping (`DAMPED`) or without.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn add_springs_with<const DAMPED: bool>(
        batches: &[Batch],
        mask: usize,
        x: &[Lanes],
        v: &[Lanes],
        c: f64,
        f: &mut [Lanes],
    ) {
        let (x, v, f) = (&x[..=mask], &v[..=mask], &mut f[..=mask]);
        for b in batches {
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
                add_scalar(b, mask, x, v, c, f);
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
        }
    }
}
