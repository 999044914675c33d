//! The springs' kernels of the implicit step four springs at a time: the gradient and
//! the Hessian's blocks (one pass over the springs writing either or both), the line
//! search's change of the springs' energy at one or two step lengths, and each spring's
//! energy for the energies a step reports.
//!
//! Each kernel is one loop over batches of [`LANES`] springs written lane by lane: the
//! spring vectors are gathered per lane, then every operation (the squares, the square
//! roots, the divisions, the products) is written once over the four lanes, so the
//! compiler can issue it as one packed instruction. These portable loops run on the
//! target's baseline (SSE2 on x86_64: pairs of lanes at best); when the processor
//! reports AVX2 at run time, the same loops written with AVX2's intrinsics run instead,
//! four lanes per register. The square roots and divisions, a spring's longest chains,
//! then run four springs per instruction; the scalar loops issued one per spring.
//!
//! The results are bitwise the scalar kernels' ([`crate::spring::gradient`],
//! [`crate::spring::hessian_coefficients`] with [`SymBlock::isotropic_plus_outer`],
//! [`crate::spring::energy_change`], [`crate::spring::energy`]): each lane goes through
//! the same floating-point operations in the same order (no FMA is enabled, and Rust
//! never contracts a product and a sum), a batch with a spring outside the kernels'
//! plain case (a length outside `1e-150 < l < inf`, or a zero rest length for a block)
//! is computed spring by spring by the scalar kernels, and the energy changes are added
//! to their sum one spring at a time in spring order, skipping the springs the scalar
//! loop skips. The design is in docs/spring-sim.md ("Four springs at a time in the
//! implicit step"; the energies: "Sums kept in registers in the gathers").

use super::SymBlock;
use super::damping::kernel as damping;
use super::springs;
use crate::model::Spring;
use crate::spring::Curvature;
use sinew_math::DVec3;

/// Springs per batch.
pub(crate) const LANES: usize = 4;

/// Which compiled instance of the loops runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Instance {
    /// AVX2 when the processor has it (detected at run time), else the portable one.
    Detect,
    /// The loops compiled for the target's baseline, which the tests compare with the
    /// AVX2 one.
    #[cfg(test)]
    Portable,
}

impl Instance {
    /// Whether the AVX2 instance runs.
    #[inline]
    fn avx2(self) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            // `std` caches the answer: a load and a test per call.
            self == Self::Detect && std::arch::is_x86_feature_detected!("avx2")
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = self;
            false
        }
    }
}

/// `$avx2(args)` (a kernel of the `avx2` module) when `$instance` selects the AVX2
/// instance, else `$portable(args)`: the dispatch every kernel shares. A macro, not a
/// function taking the two kernels: the AVX2 call must stay behind the detection, in
/// the one `unsafe` block whose safety argument is written here.
macro_rules! dispatch {
    ($instance:expr, $avx2:path, $portable:path, ($($arg:expr),* $(,)?)) => {
        match $instance {
            // SAFETY: `Instance::avx2` is true only when `is_x86_feature_detected!("avx2")`
            // reported the feature on this processor, which is all a function enabling
            // AVX2 requires to be called.
            #[cfg(target_arch = "x86_64")]
            #[allow(unsafe_code)]
            instance if instance.avx2() => unsafe { $avx2($($arg),*) },
            _ => $portable($($arg),*),
        }
    };
}

/// The lengths of the kernels' plain case, the condition of [`spring::gradient`]'s and
/// [`spring::hessian_coefficients`]' fast paths written without branches (a NaN length
/// fails both comparisons, as it fails `is_finite`).
#[inline(always)]
fn plain_length(l: f64) -> bool {
    (l > 1e-150) & (l < f64::INFINITY)
}

/// The axial damping term's share of the springs a kernel is given: its coefficient
/// `c/h`, and per spring given (in the same order) its direction and its vector at the
/// step's reference positions, both frozen at the step's start. The kernels add it to
/// the springs' gradients, blocks and energy changes by the potential's fused
/// expressions (the spring's value, then the damping's added to it).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Damping<'a> {
    /// `c/h`.
    pub(crate) c: f64,
    /// The frozen directions of the springs given to the kernel.
    pub(crate) directions: &'a [DVec3],
    /// The springs' vectors `x_ref[a] - x_ref[b]` at the reference positions.
    pub(crate) references: &'a [DVec3],
}

impl Damping<'_> {
    /// The placeholder the undamped instances of the loops are given (and never read).
    const NONE: Damping<'static> = Damping {
        c: 0.0,
        directions: &[],
        references: &[],
    };

    /// Spring `e`'s damping gradient on its first particle (`s` the spring, `e` its
    /// index among the springs given to the kernel), by the damping kernel.
    #[inline(always)]
    fn gradient(&self, s: &Spring, e: usize, x: &[DVec3]) -> DVec3 {
        let d = x[s.a] - x[s.b];
        damping::gradient(self.c, self.directions[e], d, self.references[e])
    }

    /// The same share for the springs from the `first` given on (empty slices for
    /// [`Self::NONE`]).
    #[inline(always)]
    fn from(&self, first: usize) -> Self {
        Damping {
            c: self.c,
            directions: &self.directions[first.min(self.directions.len())..],
            references: &self.references[first.min(self.references.len())..],
        }
    }
}

/// The springs `range` one by one by the scalar kernels (with the damping's added when
/// `DAMPED`, as the potential's fused loop adds them), each output written at the
/// spring's own index: a batch outside the plain case, and the last short batch.
#[inline]
#[allow(clippy::too_many_arguments)]
fn fill_scalar<const GRADIENT: bool, const BLOCK: bool, const DAMPED: bool>(
    springs: &[Spring],
    range: std::ops::Range<usize>,
    x: &[DVec3],
    curvature: Curvature,
    damped: &Damping<'_>,
    gradients: &mut [DVec3],
    blocks: &mut [SymBlock],
) {
    for e in range {
        let s = &springs[e];
        if GRADIENT {
            gradients[e] = if DAMPED {
                springs::gradient(s, x) + damped.gradient(s, e, x)
            } else {
                springs::gradient(s, x)
            };
        }
        if BLOCK {
            let mut k = springs::block(s, x, curvature);
            if DAMPED {
                for (v, add) in
                    k.0.iter_mut()
                        .zip(damping::block(damped.c, damped.directions[e]).0)
                {
                    *v += add;
                }
            }
            blocks[e] = k;
        }
    }
}

/// Four lanes of one quantity.
type Lane = [f64; LANES];

/// The spring vectors `x_a - x_b` of `batch`'s springs as components, lane `i` being
/// spring `i`, and their lengths `|d|` computed as `d.length()` (`(x x + y y) + z z`,
/// then its square root).
#[inline(always)]
fn vectors_and_lengths(batch: &[Spring], x: &[DVec3]) -> ([Lane; 3], Lane) {
    let d = differences(batch, x);
    let [dx, dy, dz] = &d;
    let mut l = [0.0; LANES];
    for i in 0..LANES {
        l[i] = (dx[i] * dx[i] + dy[i] * dy[i] + dz[i] * dz[i]).sqrt();
    }
    (d, l)
}

/// Writes the gradients (on each spring's first particle) of `springs` at `x` into
/// `gradients` when `GRADIENT`, and their blocks in the form `curvature` asks for into
/// `blocks` when `BLOCK` (each output as long as `springs`, or unused and then
/// possibly empty): bitwise `springs::gradient` and `springs::block` per spring.
#[cfg_attr(not(feature = "parallel"), allow(dead_code))]
#[inline(always)]
fn fill_lanes<const GRADIENT: bool, const BLOCK: bool, const DAMPED: bool>(
    springs: &[Spring],
    x: &[DVec3],
    curvature: Curvature,
    damped: &Damping<'_>,
    gradients: &mut [DVec3],
    blocks: &mut [SymBlock],
) {
    let whole = springs.len() / LANES * LANES;
    for first in (0..whole).step_by(LANES) {
        let batch = &springs[first..first + LANES];
        let (d, l) = vectors_and_lengths(batch, x);
        let mut plain = true;
        for i in 0..LANES {
            plain &= plain_length(l[i]);
            if BLOCK {
                // A zero rest length's block is `k I` whatever the length.
                plain &= batch[i].rest_length != 0.0;
            }
        }
        if !plain {
            let range = first..first + LANES;
            fill_scalar::<GRADIENT, BLOCK, DAMPED>(
                springs, range, x, curvature, damped, gradients, blocks,
            );
            continue;
        }
        let (rest, k) = constants(batch);
        // The frozen directions `w`, as components.
        let w = if DAMPED {
            components(&damped.directions[first..first + LANES])
        } else {
            [[0.0; LANES]; 3]
        };
        if GRADIENT {
            // `k (1 - L (1/l)) d`.
            let mut scale = [0.0; LANES];
            for i in 0..LANES {
                scale[i] = k[i] * (1.0 - rest[i] * (1.0 / l[i]));
            }
            let mut g = [[0.0; LANES]; 3];
            for (g, d) in g.iter_mut().zip(&d) {
                for i in 0..LANES {
                    g[i] = scale[i] * d[i];
                }
            }
            if DAMPED {
                // `(c e) w` added, `e = w . (d - d_ref)`.
                let d_ref = components(&damped.references[first..first + LANES]);
                let e = elongations(&w, &d, &d_ref);
                for (g, w) in g.iter_mut().zip(&w) {
                    for i in 0..LANES {
                        g[i] += damped.c * e[i] * w[i];
                    }
                }
            }
            for i in 0..LANES {
                gradients[first + i] = DVec3::new(g[0][i], g[1][i], g[2][i]);
            }
        }
        if BLOCK {
            // `u = d / l`, `1 - L/l` across the spring in the form asked for, then
            // `alpha I + beta u u^T` with `alpha = k across` and `beta = k - alpha`.
            let mut u = [[0.0; LANES]; 3];
            for (u, d) in u.iter_mut().zip(&d) {
                for i in 0..LANES {
                    u[i] = d[i] / l[i];
                }
            }
            let mut exact = [0.0; LANES];
            for i in 0..LANES {
                exact[i] = 1.0 - rest[i] / l[i];
            }
            let mut across = [0.0; LANES];
            match curvature {
                Curvature::Exact => across = exact,
                Curvature::Clamped => {
                    for i in 0..LANES {
                        across[i] = exact[i].max(0.0);
                    }
                }
                Curvature::Softened(theta) | Curvature::ExactContact(theta) => {
                    for i in 0..LANES {
                        across[i] = exact[i].max(0.0) + (1.0 - theta) * exact[i].min(0.0);
                    }
                }
            }
            let mut alpha = [0.0; LANES];
            let mut beta = [0.0; LANES];
            for i in 0..LANES {
                alpha[i] = k[i] * across[i];
                beta[i] = k[i] - alpha[i];
            }
            let [ux, uy, uz] = &u;
            for i in 0..LANES {
                let mut block = [
                    alpha[i] + beta[i] * ux[i] * ux[i],
                    beta[i] * uy[i] * ux[i],
                    beta[i] * uz[i] * ux[i],
                    alpha[i] + beta[i] * uy[i] * uy[i],
                    beta[i] * uz[i] * uy[i],
                    alpha[i] + beta[i] * uz[i] * uz[i],
                ];
                if DAMPED {
                    // The damping's block `0 I + c w w^T` added entry by entry.
                    let c = damped.c;
                    let [wx, wy, wz] = [w[0][i], w[1][i], w[2][i]];
                    let add = [
                        0.0 + c * wx * wx,
                        c * wy * wx,
                        c * wz * wx,
                        0.0 + c * wy * wy,
                        c * wz * wy,
                        0.0 + c * wz * wz,
                    ];
                    for (v, add) in block.iter_mut().zip(add) {
                        *v += add;
                    }
                }
                blocks[first + i] = SymBlock(block);
            }
        }
    }
    let tail = whole..springs.len();
    fill_scalar::<GRADIENT, BLOCK, DAMPED>(springs, tail, x, curvature, damped, gradients, blocks);
}

/// The elongations `e = w . (d - d_ref)` of a batch (the damping kernel's, `w`'s dot
/// product with the difference taken component by component first).
#[inline(always)]
fn elongations(w: &[Lane; 3], d: &[Lane; 3], d_ref: &[Lane; 3]) -> Lane {
    let mut e = [0.0; LANES];
    for i in 0..LANES {
        e[i] = w[0][i] * (d[0][i] - d_ref[0][i])
            + w[1][i] * (d[1][i] - d_ref[1][i])
            + w[2][i] * (d[2][i] - d_ref[2][i]);
    }
    e
}

/// The damping's changes `c/2 de (2 e + de)` with `de = w . delta` (the damping kernel's
/// operations lane by lane).
#[inline(always)]
fn damping_changes(c: f64, w: &[Lane; 3], e: &Lane, delta: &[Lane; 3]) -> Lane {
    let mut change = [0.0; LANES];
    for i in 0..LANES {
        let de = w[0][i] * delta[0][i] + w[1][i] * delta[1][i] + w[2][i] * delta[2][i];
        change[i] = 0.5 * c * de * (2.0 * e[i] + de);
    }
    change
}

/// The change of each spring's energy when its vector `d` moves by `delta`, by
/// [`spring::energy_change`]'s operations lane by lane, for the lanes whose `delta` is
/// not zero (`live`); the lengths `l = |d|` are given (shared by a pair of steps).
#[inline(always)]
fn energy_changes(d: &[Lane; 3], l: &Lane, delta: &[Lane; 3], rest: &Lane, k: &Lane) -> Lane {
    let [dx, dy, dz] = d;
    let [ex, ey, ez] = delta;
    // `l' = |d + delta|`, `l' - l = delta . (2d + delta) / (l' + l)`.
    let mut sum = [0.0; LANES];
    for i in 0..LANES {
        let (nx, ny, nz) = (dx[i] + ex[i], dy[i] + ey[i], dz[i] + ez[i]);
        sum[i] = l[i] + (nx * nx + ny * ny + nz * nz).sqrt();
    }
    let mut change = [0.0; LANES];
    for i in 0..LANES {
        let dot = ex[i] * (2.0 * dx[i] + ex[i])
            + ey[i] * (2.0 * dy[i] + ey[i])
            + ez[i] * (2.0 * dz[i] + ez[i]);
        let dl = dot / sum[i];
        change[i] = 0.5 * k[i] * dl * (sum[i] - 2.0 * rest[i]);
    }
    // Both lengths zero: the scalar kernel returns 0 before dividing.
    for i in 0..LANES {
        if sum[i] == 0.0 {
            change[i] = 0.0;
        }
    }
    change
}

/// `alpha dx_a - alpha dx_b` for each spring of `batch`, as components.
#[inline(always)]
fn moves(batch: &[Spring], dx: &[DVec3], alpha: f64) -> [Lane; 3] {
    let mut delta = [[0.0; LANES]; 3];
    for (i, s) in batch.iter().enumerate().take(LANES) {
        let v = alpha * dx[s.a] - alpha * dx[s.b];
        delta[0][i] = v.x;
        delta[1][i] = v.y;
        delta[2][i] = v.z;
    }
    delta
}

/// Whether lane `i`'s move is not the zero vector (the scalar loop skips such springs).
#[inline(always)]
fn moved(delta: &[Lane; 3], i: usize) -> bool {
    delta[0][i] != 0.0 || delta[1][i] != 0.0 || delta[2][i] != 0.0
}

/// The sums over `springs` of their energies' changes along `alphas[j] dx` (`PAIR`:
/// both lengths, else the first only, the second sum then being 0), each added in
/// spring order and skipping the springs whose move is zero: bitwise the scalar loops'.
#[inline(always)]
fn energy_change_lanes<const PAIR: bool, const DAMPED: bool>(
    springs: &[Spring],
    x: &[DVec3],
    dx: &[DVec3],
    [a1, a2]: [f64; 2],
    damped: &Damping<'_>,
) -> [f64; 2] {
    let mut sums = [0.0; 2];
    let whole = springs.len() / LANES * LANES;
    for first in (0..whole).step_by(LANES) {
        let batch = &springs[first..first + LANES];
        let (d, l) = vectors_and_lengths(batch, x);
        let (rest, k) = constants(batch);
        let (w, e) = if DAMPED {
            let w = components(&damped.directions[first..first + LANES]);
            let d_ref = components(&damped.references[first..first + LANES]);
            let e = elongations(&w, &d, &d_ref);
            (w, e)
        } else {
            ([[0.0; LANES]; 3], [0.0; LANES])
        };
        // The first length, then the second with `PAIR` (a loop of a constant one or
        // two trips, unrolled), each sum taking its own batch's changes in lane order.
        let lengths = if PAIR { 2 } else { 1 };
        for (sum, alpha) in sums.iter_mut().zip([a1, a2]).take(lengths) {
            let delta = moves(batch, dx, alpha);
            let mut changes = energy_changes(&d, &l, &delta, &rest, &k);
            if DAMPED {
                let damping = damping_changes(damped.c, &w, &e, &delta);
                for (change, damping) in changes.iter_mut().zip(damping) {
                    *change += damping;
                }
            }
            for (i, change) in changes.iter().enumerate() {
                if moved(&delta, i) {
                    *sum += change;
                }
            }
        }
    }
    let tail = &springs[whole..];
    energy_change_tail::<PAIR, DAMPED>(tail, x, dx, [a1, a2], sums, &damped.from(whole))
}

/// The sums `sums` continued over the springs `rest` (fewer than a batch) one at a
/// time by the scalar kernels (the damping's change added to the spring's when
/// `DAMPED`, `damped` being the springs' `rest`'s).
#[inline(always)]
fn energy_change_tail<const PAIR: bool, const DAMPED: bool>(
    rest: &[Spring],
    x: &[DVec3],
    dx: &[DVec3],
    [a1, a2]: [f64; 2],
    [mut c1, mut c2]: [f64; 2],
    damped: &Damping<'_>,
) -> [f64; 2] {
    let change = |j: usize, s: &Spring, delta: DVec3| {
        if DAMPED {
            let d = x[s.a] - x[s.b];
            let (w, d_ref) = (damped.directions[j], damped.references[j]);
            springs::energy_change(s, x, delta)
                + damping::energy_change(damped.c, w, d, d_ref, delta)
        } else {
            springs::energy_change(s, x, delta)
        }
    };
    for (j, s) in rest.iter().enumerate() {
        let (da, db) = (dx[s.a], dx[s.b]);
        let delta1 = a1 * da - a1 * db;
        if delta1 != DVec3::ZERO {
            c1 += change(j, s, delta1);
        }
        if PAIR {
            let delta2 = a2 * da - a2 * db;
            if delta2 != DVec3::ZERO {
                c2 += change(j, s, delta2);
            }
        }
    }
    [c1, c2]
}

/// Each spring's energy `k/2 (l - L)^2` at `x` into `energies` (as long as
/// `springs`), four springs at a time: [`crate::spring::energy`]'s operations lane by
/// lane (`l = |x_a - x_b|` as `d.length()`, then `((0.5 k) (l - L)) (l - L)`), with no
/// branch to take, so every batch is a plain one; the short tail by the scalar kernel.
#[inline(always)]
fn energies_lanes(springs: &[Spring], x: &[DVec3], energies: &mut [f64]) {
    let whole = springs.len() / LANES * LANES;
    for first in (0..whole).step_by(LANES) {
        let batch = &springs[first..first + LANES];
        let (_, l) = vectors_and_lengths(batch, x);
        let (rest, k) = constants(batch);
        for i in 0..LANES {
            energies[first + i] = 0.5 * k[i] * (l[i] - rest[i]) * (l[i] - rest[i]);
        }
    }
    for (e, s) in energies[whole..].iter_mut().zip(&springs[whole..]) {
        *e = crate::spring::energy(x[s.a], x[s.b], s.rest_length, s.stiffness);
    }
}

/// Each spring's damping direction at `x` into `directions` (as long as `springs`),
/// four springs at a time: [`sinew_math::try_unit`]'s operations lane by lane (the
/// vector divided by its largest absolute component, then by that quotient's length
/// `((w_x w_x + w_y w_y) + w_z w_z)^(1/2)`). A batch with a vector that is zero or not
/// finite (no direction: the zero vector) goes spring by spring through
/// [`crate::spring::damping_direction`], as does the short tail.
#[inline(always)]
fn directions_lanes(springs: &[Spring], x: &[DVec3], directions: &mut [DVec3]) {
    let whole = springs.len() / LANES * LANES;
    for first in (0..whole).step_by(LANES) {
        let batch = &springs[first..first + LANES];
        let d = differences(batch, x);
        let mut scale = [0.0; LANES];
        let mut plain = true;
        for i in 0..LANES {
            let (ax, ay, az) = (d[0][i].abs(), d[1][i].abs(), d[2][i].abs());
            scale[i] = ax.max(ay.max(az));
            plain &= (ax < f64::INFINITY)
                & (ay < f64::INFINITY)
                & (az < f64::INFINITY)
                & (scale[i] > 0.0);
        }
        if !plain {
            directions_scalar(batch, x, &mut directions[first..first + LANES]);
            continue;
        }
        let mut w = [[0.0; LANES]; 3];
        for (w, d) in w.iter_mut().zip(&d) {
            for i in 0..LANES {
                w[i] = d[i] / scale[i];
            }
        }
        let mut l = [0.0; LANES];
        for i in 0..LANES {
            l[i] = (w[0][i] * w[0][i] + w[1][i] * w[1][i] + w[2][i] * w[2][i]).sqrt();
        }
        for i in 0..LANES {
            directions[first + i] = DVec3::new(w[0][i] / l[i], w[1][i] / l[i], w[2][i] / l[i]);
        }
    }
    directions_scalar(&springs[whole..], x, &mut directions[whole..]);
}

/// [`crate::spring::damping_direction`] of each of `springs` into `directions`.
#[inline(always)]
fn directions_scalar(springs: &[Spring], x: &[DVec3], directions: &mut [DVec3]) {
    for (w, s) in directions.iter_mut().zip(springs) {
        *w = crate::spring::damping_direction(x[s.a], x[s.b]);
    }
}

/// The rest lengths and stiffnesses of `batch`'s springs (a batch's first [`LANES`]).
#[inline(always)]
fn constants(batch: &[Spring]) -> (Lane, Lane) {
    let mut rest = [0.0; LANES];
    let mut k = [0.0; LANES];
    for (i, s) in batch.iter().enumerate().take(LANES) {
        rest[i] = s.rest_length;
        k[i] = s.stiffness;
    }
    (rest, k)
}

/// Per lane `v[s.a] - v[s.b]` of `batch`'s springs (a batch's first [`LANES`]), as
/// components.
#[inline(always)]
fn differences(batch: &[Spring], v: &[DVec3]) -> [Lane; 3] {
    let mut d = [[0.0; LANES]; 3];
    for (i, s) in batch.iter().enumerate().take(LANES) {
        let e = v[s.a] - v[s.b];
        d[0][i] = e.x;
        d[1][i] = e.y;
        d[2][i] = e.z;
    }
    d
}

/// The first [`LANES`] vectors of `v` as components, lane `i` being `v[i]`.
#[inline(always)]
fn components(v: &[DVec3]) -> [Lane; 3] {
    let mut c = [[0.0; LANES]; 3];
    for (i, v) in v.iter().enumerate().take(LANES) {
        (c[0][i], c[1][i], c[2][i]) = (v.x, v.y, v.z);
    }
    c
}

/// Per lane `v[s.a]` and `v[s.b]` of `batch`'s springs, as components.
#[inline(always)]
fn ends(batch: &[Spring], v: &[DVec3]) -> ([Lane; 3], [Lane; 3]) {
    let (mut a, mut b) = ([[0.0; LANES]; 3], [[0.0; LANES]; 3]);
    for (i, s) in batch.iter().enumerate().take(LANES) {
        let (p, q) = (v[s.a], v[s.b]);
        (a[0][i], a[1][i], a[2][i]) = (p.x, p.y, p.z);
        (b[0][i], b[1][i], b[2][i]) = (q.x, q.y, q.z);
    }
    (a, b)
}

/// The loops written with AVX2's intrinsics: a batch's four springs are one 256-bit
/// register per quantity, and every operation of the portable loops is one packed
/// instruction of the same IEEE operation (the compiler left most of the portable
/// loops' divisions in pairs and singles when compiled for AVX2).
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{Curvature, DVec3, Damping, LANES, Lane, Spring, SymBlock};
    use std::arch::x86_64::{
        __m256d, _CMP_EQ_OQ, _CMP_GT_OQ, _CMP_LT_OQ, _CMP_NEQ_UQ, _mm256_add_pd, _mm256_and_pd,
        _mm256_andnot_pd, _mm256_cmp_pd, _mm256_cvtsd_f64, _mm256_div_pd, _mm256_max_pd,
        _mm256_min_pd, _mm256_movemask_pd, _mm256_mul_pd, _mm256_or_pd, _mm256_permute4x64_pd,
        _mm256_set1_pd, _mm256_setr_pd, _mm256_setzero_pd, _mm256_sqrt_pd, _mm256_sub_pd,
    };

    /// A register as lanes.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn lanes(r: __m256d) -> Lane {
        [
            _mm256_cvtsd_f64(r),
            _mm256_cvtsd_f64(_mm256_permute4x64_pd::<1>(r)),
            _mm256_cvtsd_f64(_mm256_permute4x64_pd::<2>(r)),
            _mm256_cvtsd_f64(_mm256_permute4x64_pd::<3>(r)),
        ]
    }

    /// Lanes as a register.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn load(l: Lane) -> __m256d {
        _mm256_setr_pd(l[0], l[1], l[2], l[3])
    }

    /// Per lane `v[s.a] - v[s.b]` of `batch`'s springs, as three registers of components
    /// (the gather is plain code the compiler inlines, so only the loads are here).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn differences(batch: &[Spring], v: &[DVec3]) -> [__m256d; 3] {
        let [x, y, z] = super::differences(batch, v);
        [load(x), load(y), load(z)]
    }

    /// The first four vectors of `v` as three registers of components.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn components(v: &[DVec3]) -> [__m256d; 3] {
        let [x, y, z] = super::components(v);
        [load(x), load(y), load(z)]
    }

    /// `w . (d - d_ref)` per lane, the damping kernel's elongation.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn elongation(
        [wx, wy, wz]: [__m256d; 3],
        [dx, dy, dz]: [__m256d; 3],
        r: [__m256d; 3],
    ) -> __m256d {
        _mm256_add_pd(
            _mm256_add_pd(
                _mm256_mul_pd(wx, _mm256_sub_pd(dx, r[0])),
                _mm256_mul_pd(wy, _mm256_sub_pd(dy, r[1])),
            ),
            _mm256_mul_pd(wz, _mm256_sub_pd(dz, r[2])),
        )
    }

    /// The rest lengths and stiffnesses of `batch`'s springs.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn constants(batch: &[Spring]) -> (__m256d, __m256d) {
        let (s0, s1, s2, s3) = (&batch[0], &batch[1], &batch[2], &batch[3]);
        (
            _mm256_setr_pd(
                s0.rest_length,
                s1.rest_length,
                s2.rest_length,
                s3.rest_length,
            ),
            _mm256_setr_pd(s0.stiffness, s1.stiffness, s2.stiffness, s3.stiffness),
        )
    }

    /// `((x x + y y) + z z)`, `d.length_squared()`'s order.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn squared_length([x, y, z]: [__m256d; 3]) -> __m256d {
        _mm256_add_pd(
            _mm256_add_pd(_mm256_mul_pd(x, x), _mm256_mul_pd(y, y)),
            _mm256_mul_pd(z, z),
        )
    }

    /// The lanes of a comparison's mask as four bits.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn bits(mask: __m256d) -> i32 {
        _mm256_movemask_pd(mask)
    }

    /// [`super::fill_lanes`] in 256-bit registers.
    #[cfg_attr(not(feature = "parallel"), allow(dead_code))]
    #[target_feature(enable = "avx2")]
    pub(super) fn fill<const GRADIENT: bool, const BLOCK: bool, const DAMPED: bool>(
        springs: &[Spring],
        x: &[DVec3],
        curvature: Curvature,
        damped: &Damping<'_>,
        gradients: &mut [DVec3],
        blocks: &mut [SymBlock],
    ) {
        let c = _mm256_set1_pd(damped.c);
        let (one, zero) = (_mm256_set1_pd(1.0), _mm256_setzero_pd());
        let (tiny, infinity) = (_mm256_set1_pd(1e-150), _mm256_set1_pd(f64::INFINITY));
        let whole = springs.len() / LANES * LANES;
        for first in (0..whole).step_by(LANES) {
            let batch = &springs[first..first + LANES];
            let d = differences(batch, x);
            let [dx, dy, dz] = d;
            let (rest, k) = constants(batch);
            let l = _mm256_sqrt_pd(squared_length(d));
            let mut plain = _mm256_and_pd(
                _mm256_cmp_pd::<_CMP_GT_OQ>(l, tiny),
                _mm256_cmp_pd::<_CMP_LT_OQ>(l, infinity),
            );
            if BLOCK {
                plain = _mm256_and_pd(plain, _mm256_cmp_pd::<_CMP_NEQ_UQ>(rest, zero));
            }
            if bits(plain) != 0b1111 {
                let range = first..first + LANES;
                super::fill_scalar::<GRADIENT, BLOCK, DAMPED>(
                    springs, range, x, curvature, damped, gradients, blocks,
                );
                continue;
            }
            let w = if DAMPED {
                components(&damped.directions[first..first + LANES])
            } else {
                [zero; 3]
            };
            if GRADIENT {
                let inverse = _mm256_div_pd(one, l);
                let scale = _mm256_mul_pd(k, _mm256_sub_pd(one, _mm256_mul_pd(rest, inverse)));
                let mut g = [
                    _mm256_mul_pd(scale, dx),
                    _mm256_mul_pd(scale, dy),
                    _mm256_mul_pd(scale, dz),
                ];
                if DAMPED {
                    // `(c e) w` added.
                    let d_ref = components(&damped.references[first..first + LANES]);
                    let e = elongation(w, d, d_ref);
                    let ce = _mm256_mul_pd(c, e);
                    for (g, w) in g.iter_mut().zip(w) {
                        *g = _mm256_add_pd(*g, _mm256_mul_pd(ce, w));
                    }
                }
                // Each register taken apart by a direct call: a closure (`g.map(..)`) would
                // lack this function's AVX2 feature, so `lanes` could not inline into it
                // and every batch would pay calls through an out-of-line `array::map`.
                let [gx, gy, gz] = [lanes(g[0]), lanes(g[1]), lanes(g[2])];
                for i in 0..LANES {
                    gradients[first + i] = DVec3::new(gx[i], gy[i], gz[i]);
                }
            }
            if BLOCK {
                let (ux, uy, uz) = (
                    _mm256_div_pd(dx, l),
                    _mm256_div_pd(dy, l),
                    _mm256_div_pd(dz, l),
                );
                let exact = _mm256_sub_pd(one, _mm256_div_pd(rest, l));
                // `max` and `min` return their second operand when the first is NaN, as
                // `f64::max` and `f64::min` return the number (and `exact` is never -0).
                let across = match curvature {
                    Curvature::Exact => exact,
                    Curvature::Clamped => _mm256_max_pd(exact, zero),
                    Curvature::Softened(theta) | Curvature::ExactContact(theta) => _mm256_add_pd(
                        _mm256_max_pd(exact, zero),
                        _mm256_mul_pd(_mm256_set1_pd(1.0 - theta), _mm256_min_pd(exact, zero)),
                    ),
                };
                let alpha = _mm256_mul_pd(k, across);
                let beta = _mm256_sub_pd(k, alpha);
                let (bx, by, bz) = (
                    _mm256_mul_pd(beta, ux),
                    _mm256_mul_pd(beta, uy),
                    _mm256_mul_pd(beta, uz),
                );
                let mut entries = [
                    _mm256_add_pd(alpha, _mm256_mul_pd(bx, ux)),
                    _mm256_mul_pd(by, ux),
                    _mm256_mul_pd(bz, ux),
                    _mm256_add_pd(alpha, _mm256_mul_pd(by, uy)),
                    _mm256_mul_pd(bz, uy),
                    _mm256_add_pd(alpha, _mm256_mul_pd(bz, uz)),
                ];
                if DAMPED {
                    // The damping's block `0 I + c w w^T` added entry by entry.
                    let [wx, wy, wz] = w;
                    let (cx, cy, cz) = (
                        _mm256_mul_pd(c, wx),
                        _mm256_mul_pd(c, wy),
                        _mm256_mul_pd(c, wz),
                    );
                    let add = [
                        _mm256_add_pd(zero, _mm256_mul_pd(cx, wx)),
                        _mm256_mul_pd(cy, wx),
                        _mm256_mul_pd(cz, wx),
                        _mm256_add_pd(zero, _mm256_mul_pd(cy, wy)),
                        _mm256_mul_pd(cz, wy),
                        _mm256_add_pd(zero, _mm256_mul_pd(cz, wz)),
                    ];
                    for (v, add) in entries.iter_mut().zip(add) {
                        *v = _mm256_add_pd(*v, add);
                    }
                }
                // Direct calls, as for the gradients.
                let [xx, yx, zx, yy, zy, zz] = [
                    lanes(entries[0]),
                    lanes(entries[1]),
                    lanes(entries[2]),
                    lanes(entries[3]),
                    lanes(entries[4]),
                    lanes(entries[5]),
                ];
                for i in 0..LANES {
                    blocks[first + i] = SymBlock([xx[i], yx[i], zx[i], yy[i], zy[i], zz[i]]);
                }
            }
        }
        let tail = whole..springs.len();
        super::fill_scalar::<GRADIENT, BLOCK, DAMPED>(
            springs, tail, x, curvature, damped, gradients, blocks,
        );
    }

    /// The changes of a batch's energies along the moves `alpha (dx_a - dx_b)` (as
    /// [`super::energy_changes`]), and which lanes moved.
    #[inline]
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    fn changes(
        alpha: f64,
        (da, db): ([__m256d; 3], [__m256d; 3]),
        [dx, dy, dz]: [__m256d; 3],
        l: __m256d,
        half_k: __m256d,
        twice_rest: __m256d,
        damping: Option<([__m256d; 3], __m256d, __m256d)>,
    ) -> (Lane, i32) {
        let (zero, two) = (_mm256_setzero_pd(), _mm256_set1_pd(2.0));
        let a = _mm256_set1_pd(alpha);
        // `alpha dx_a - alpha dx_b` per component.
        let ex = _mm256_sub_pd(_mm256_mul_pd(a, da[0]), _mm256_mul_pd(a, db[0]));
        let ey = _mm256_sub_pd(_mm256_mul_pd(a, da[1]), _mm256_mul_pd(a, db[1]));
        let ez = _mm256_sub_pd(_mm256_mul_pd(a, da[2]), _mm256_mul_pd(a, db[2]));
        let moved = bits(_mm256_or_pd(
            _mm256_or_pd(
                _mm256_cmp_pd::<_CMP_NEQ_UQ>(ex, zero),
                _mm256_cmp_pd::<_CMP_NEQ_UQ>(ey, zero),
            ),
            _mm256_cmp_pd::<_CMP_NEQ_UQ>(ez, zero),
        ));
        let moved_vector = [
            _mm256_add_pd(dx, ex),
            _mm256_add_pd(dy, ey),
            _mm256_add_pd(dz, ez),
        ];
        let sum = _mm256_add_pd(l, _mm256_sqrt_pd(squared_length(moved_vector)));
        // `delta . (2 d + delta)`.
        let dot = _mm256_add_pd(
            _mm256_add_pd(
                _mm256_mul_pd(ex, _mm256_add_pd(_mm256_mul_pd(two, dx), ex)),
                _mm256_mul_pd(ey, _mm256_add_pd(_mm256_mul_pd(two, dy), ey)),
            ),
            _mm256_mul_pd(ez, _mm256_add_pd(_mm256_mul_pd(two, dz), ez)),
        );
        let dl = _mm256_div_pd(dot, sum);
        let change = _mm256_mul_pd(_mm256_mul_pd(half_k, dl), _mm256_sub_pd(sum, twice_rest));
        // Both lengths zero: the scalar kernel's 0 (`andnot` clears those lanes to +0).
        let mut change = _mm256_andnot_pd(_mm256_cmp_pd::<_CMP_EQ_OQ>(sum, zero), change);
        if let Some(([wx, wy, wz], e, half_c)) = damping {
            // The damping's `((c/2) de) (2 e + de)`, `de = w . delta`, added.
            let de = _mm256_add_pd(
                _mm256_add_pd(_mm256_mul_pd(wx, ex), _mm256_mul_pd(wy, ey)),
                _mm256_mul_pd(wz, ez),
            );
            let damping = _mm256_mul_pd(
                _mm256_mul_pd(half_c, de),
                _mm256_add_pd(_mm256_mul_pd(two, e), de),
            );
            change = _mm256_add_pd(change, damping);
        }
        (lanes(change), moved)
    }

    /// [`super::energy_change_lanes`] in 256-bit registers.
    #[target_feature(enable = "avx2")]
    pub(super) fn energy_change<const PAIR: bool, const DAMPED: bool>(
        springs: &[Spring],
        x: &[DVec3],
        dx: &[DVec3],
        [a1, a2]: [f64; 2],
        damped: &Damping<'_>,
    ) -> [f64; 2] {
        let (mut c1, mut c2) = (0.0, 0.0);
        let (half, two) = (_mm256_set1_pd(0.5), _mm256_set1_pd(2.0));
        // `0.5 c`, the damping kernel's first product.
        let half_c = _mm256_set1_pd(0.5 * damped.c);
        let whole = springs.len() / LANES * LANES;
        for first in (0..whole).step_by(LANES) {
            let batch = &springs[first..first + LANES];
            let d = differences(batch, x);
            let (rest, k) = constants(batch);
            let l = _mm256_sqrt_pd(squared_length(d));
            // `0.5 k` and `2 L`, the kernel's first product and its subtrahend.
            let (half_k, twice_rest) = (_mm256_mul_pd(half, k), _mm256_mul_pd(two, rest));
            let (da, db) = super::ends(batch, dx);
            let moves = (
                [load(da[0]), load(da[1]), load(da[2])],
                [load(db[0]), load(db[1]), load(db[2])],
            );
            // No closure (`DAMPED.then(..)`): it would not inherit the AVX2 feature.
            let damping = if DAMPED {
                let w = components(&damped.directions[first..first + LANES]);
                let d_ref = components(&damped.references[first..first + LANES]);
                let e = elongation(w, d, d_ref);
                Some((w, e, half_c))
            } else {
                None
            };
            let (change, moved) = changes(a1, moves, d, l, half_k, twice_rest, damping);
            for (i, change) in change.iter().enumerate() {
                if moved & (1 << i) != 0 {
                    c1 += change;
                }
            }
            if PAIR {
                let (change, moved) = changes(a2, moves, d, l, half_k, twice_rest, damping);
                for (i, change) in change.iter().enumerate() {
                    if moved & (1 << i) != 0 {
                        c2 += change;
                    }
                }
            }
        }
        let (tail, sums) = (&springs[whole..], [c1, c2]);
        let damped = damped.from(whole);
        super::energy_change_tail::<PAIR, DAMPED>(tail, x, dx, [a1, a2], sums, &damped)
    }

    /// [`super::energies_lanes`] in 256-bit registers.
    #[target_feature(enable = "avx2")]
    pub(super) fn energies(springs: &[Spring], x: &[DVec3], energies: &mut [f64]) {
        let half = _mm256_set1_pd(0.5);
        let whole = springs.len() / LANES * LANES;
        for first in (0..whole).step_by(LANES) {
            let batch = &springs[first..first + LANES];
            let l = _mm256_sqrt_pd(squared_length(differences(batch, x)));
            let (rest, k) = constants(batch);
            let stretch = _mm256_sub_pd(l, rest);
            let e = _mm256_mul_pd(_mm256_mul_pd(_mm256_mul_pd(half, k), stretch), stretch);
            energies[first..first + LANES].copy_from_slice(&lanes(e));
        }
        for (e, s) in energies[whole..].iter_mut().zip(&springs[whole..]) {
            *e = crate::spring::energy(x[s.a], x[s.b], s.rest_length, s.stiffness);
        }
    }

    /// [`super::directions_lanes`] in 256-bit registers.
    #[target_feature(enable = "avx2")]
    pub(super) fn directions(springs: &[Spring], x: &[DVec3], directions: &mut [DVec3]) {
        let (zero, infinity) = (_mm256_setzero_pd(), _mm256_set1_pd(f64::INFINITY));
        // `andnot` with `-0.0` clears the sign bit: `f64::abs`.
        let sign = _mm256_set1_pd(-0.0);
        let whole = springs.len() / LANES * LANES;
        for first in (0..whole).step_by(LANES) {
            let batch = &springs[first..first + LANES];
            let [dx, dy, dz] = differences(batch, x);
            let (ax, ay, az) = (
                _mm256_andnot_pd(sign, dx),
                _mm256_andnot_pd(sign, dy),
                _mm256_andnot_pd(sign, dz),
            );
            // Exact on the plain lanes (finite, not negative), as `f64::max` is.
            let scale = _mm256_max_pd(ax, _mm256_max_pd(ay, az));
            let finite = _mm256_and_pd(
                _mm256_and_pd(
                    _mm256_cmp_pd::<_CMP_LT_OQ>(ax, infinity),
                    _mm256_cmp_pd::<_CMP_LT_OQ>(ay, infinity),
                ),
                _mm256_cmp_pd::<_CMP_LT_OQ>(az, infinity),
            );
            let plain = _mm256_and_pd(finite, _mm256_cmp_pd::<_CMP_GT_OQ>(scale, zero));
            if bits(plain) != 0b1111 {
                super::directions_scalar(batch, x, &mut directions[first..first + LANES]);
                continue;
            }
            let w = [
                _mm256_div_pd(dx, scale),
                _mm256_div_pd(dy, scale),
                _mm256_div_pd(dz, scale),
            ];
            let l = _mm256_sqrt_pd(squared_length(w));
            let [ux, uy, uz] = [
                lanes(_mm256_div_pd(w[0], l)),
                lanes(_mm256_div_pd(w[1], l)),
                lanes(_mm256_div_pd(w[2], l)),
            ];
            for i in 0..LANES {
                directions[first + i] = DVec3::new(ux[i], uy[i], uz[i]);
            }
        }
        super::directions_scalar(&springs[whole..], x, &mut directions[whole..]);
    }
}

/// [`fill_lanes`] in the instance `instance` selects, damped or not.
#[cfg_attr(not(feature = "parallel"), allow(dead_code))]
fn fill<const GRADIENT: bool, const BLOCK: bool>(
    instance: Instance,
    springs: &[Spring],
    x: &[DVec3],
    curvature: Curvature,
    damping: Option<Damping<'_>>,
    gradients: &mut [DVec3],
    blocks: &mut [SymBlock],
) {
    if let Some(d) = &damping {
        assert_eq!(d.directions.len(), springs.len());
    }
    match &damping {
        Some(d) => dispatch!(
            instance,
            avx2::fill::<GRADIENT, BLOCK, true>,
            fill_lanes::<GRADIENT, BLOCK, true>,
            (springs, x, curvature, d, gradients, blocks)
        ),
        None => dispatch!(
            instance,
            avx2::fill::<GRADIENT, BLOCK, false>,
            fill_lanes::<GRADIENT, BLOCK, false>,
            (springs, x, curvature, &Damping::NONE, gradients, blocks)
        ),
    }
}

/// Each spring's gradient on its first particle at `x` (with its damping's added when
/// `damping` is given) into `gradients` (as long as `springs`): bitwise the potential's
/// per-spring expressions (`springs::gradient`, plus the damping kernel's gradient).
#[cfg_attr(not(feature = "parallel"), allow(dead_code))]
pub(crate) fn gradients(
    instance: Instance,
    springs: &[Spring],
    x: &[DVec3],
    damping: Option<Damping<'_>>,
    gradients: &mut [DVec3],
) {
    assert_eq!(gradients.len(), springs.len());
    let curvature = Curvature::Clamped;
    fill::<true, false>(instance, springs, x, curvature, damping, gradients, &mut []);
}

/// Each spring's block at `x` in the form `curvature` asks for (with its damping's
/// block added when `damping` is given) into `blocks` (as long as `springs`): bitwise
/// `springs::block` per spring, plus the damping kernel's block entry by entry.
#[cfg_attr(not(feature = "parallel"), allow(dead_code))]
pub(crate) fn blocks(
    instance: Instance,
    springs: &[Spring],
    x: &[DVec3],
    curvature: Curvature,
    damping: Option<Damping<'_>>,
    blocks: &mut [SymBlock],
) {
    assert_eq!(blocks.len(), springs.len());
    fill::<false, true>(instance, springs, x, curvature, damping, &mut [], blocks);
}

/// [`gradients`] and [`blocks`] in one pass over the springs.
#[cfg_attr(not(feature = "parallel"), allow(dead_code))]
pub(crate) fn gradients_and_blocks(
    instance: Instance,
    springs: &[Spring],
    x: &[DVec3],
    curvature: Curvature,
    damping: Option<Damping<'_>>,
    gradients: &mut [DVec3],
    blocks: &mut [SymBlock],
) {
    assert_eq!(gradients.len(), springs.len());
    assert_eq!(blocks.len(), springs.len());
    fill::<true, true>(instance, springs, x, curvature, damping, gradients, blocks);
}

/// [`energy_change_lanes`] in the instance `instance` selects, damped or not.
fn energy_change<const PAIR: bool>(
    instance: Instance,
    springs: &[Spring],
    x: &[DVec3],
    dx: &[DVec3],
    alphas: [f64; 2],
    damping: Option<Damping<'_>>,
) -> [f64; 2] {
    if let Some(d) = &damping {
        assert_eq!(d.directions.len(), springs.len());
    }
    match &damping {
        Some(d) => dispatch!(
            instance,
            avx2::energy_change::<PAIR, true>,
            energy_change_lanes::<PAIR, true>,
            (springs, x, dx, alphas, d)
        ),
        None => dispatch!(
            instance,
            avx2::energy_change::<PAIR, false>,
            energy_change_lanes::<PAIR, false>,
            (springs, x, dx, alphas, &Damping::NONE)
        ),
    }
}

/// The sum over `springs`, in their order, of their energies' changes along
/// `alpha dx` (each with its damping's change added when `damping` is given), skipping
/// the springs whose move is zero: bitwise the scalar loop's.
pub(crate) fn energy_change_sum(
    instance: Instance,
    springs: &[Spring],
    x: &[DVec3],
    dx: &[DVec3],
    alpha: f64,
    damping: Option<Damping<'_>>,
) -> f64 {
    energy_change::<false>(instance, springs, x, dx, [alpha, 0.0], damping)[0]
}

/// [`energy_change_sum`] at two step lengths in one pass over the springs.
pub(crate) fn energy_change_pair_sum(
    instance: Instance,
    springs: &[Spring],
    x: &[DVec3],
    dx: &[DVec3],
    alphas: [f64; 2],
    damping: Option<Damping<'_>>,
) -> [f64; 2] {
    energy_change::<true>(instance, springs, x, dx, alphas, damping)
}

/// Each spring's energy at `x` into `energies` (as long as `springs`): bitwise
/// [`crate::spring::energy`] per spring.
pub(crate) fn energies(instance: Instance, springs: &[Spring], x: &[DVec3], energies: &mut [f64]) {
    assert_eq!(energies.len(), springs.len());
    dispatch!(
        instance,
        avx2::energies,
        energies_lanes,
        (springs, x, energies)
    );
}

/// Each spring's damping direction at `x` into `directions` (as long as `springs`):
/// bitwise [`crate::spring::damping_direction`] per spring.
pub(crate) fn damping_directions(
    instance: Instance,
    springs: &[Spring],
    x: &[DVec3],
    directions: &mut [DVec3],
) {
    assert_eq!(directions.len(), springs.len());
    dispatch!(
        instance,
        avx2::directions,
        directions_lanes,
        (springs, x, directions)
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Positions and springs of every kind the kernels branch on, interleaved with
    /// ordinary ones so that each kind lands in every lane: stretched and compressed
    /// springs of varied stiffness (zero among them), zero rest lengths, zero lengths,
    /// lengths below and just above the plain range's `1e-150`, a length whose square
    /// underflows to zero, and lengths whose square overflows.
    fn cases() -> (Vec<DVec3>, Vec<Spring>) {
        let mut x: Vec<DVec3> = (0..40)
            .map(|i| {
                let t = f64::from(i);
                DVec3::new((0.7 * t).sin(), 0.5 * (1.3 * t).cos(), 0.1 * t)
            })
            .collect();
        let special = x.len();
        x.extend([
            DVec3::ZERO,
            DVec3::ZERO,
            DVec3::new(1e-160, 0.0, 0.0),
            DVec3::new(2e-150, 1e-151, 0.0),
            DVec3::new(1e-170, 0.0, 0.0),
            DVec3::new(1e200, 1e200, 0.0),
            DVec3::new(-1e300, 0.0, 1e300),
        ]);
        let ordinary = |i: usize| {
            let (a, b) = ((7 * i) % 40, (7 * i + 1 + i % 5) % 40);
            let l = (x[a] - x[b]).length();
            Spring {
                a,
                b,
                rest_length: [0.5, 0.9, 1.0, 1.3, 2.0][i % 5] * l,
                stiffness: [1.0, 1e4, 0.0, 37.5][i % 4],
            }
        };
        let z = special;
        let specials = [
            (z, z + 1, 0.2, 10.0),
            (z, z + 2, 0.2, 10.0),
            (z + 3, z, 1e-150, 3.0),
            (z + 4, z, 1.0, 3.0),
            (z + 5, z, 1.0, 2.0),
            (z + 6, z, 1.0, 2.0),
            (3, 4, 0.0, 5.0),
            (z + 2, 5, 0.0, 5.0),
        ];
        let mut springs = Vec::new();
        for (i, &(a, b, rest_length, stiffness)) in specials.iter().enumerate() {
            for j in 0..=i % LANES + 2 {
                springs.push(ordinary(3 * i + j));
            }
            springs.push(Spring {
                a,
                b,
                rest_length,
                stiffness,
            });
        }
        for i in 0..13 {
            springs.push(ordinary(100 + i));
        }
        (x, springs)
    }

    fn instances() -> [Instance; 2] {
        [Instance::Detect, Instance::Portable]
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|f| f.to_bits()).collect()
    }

    /// Every prefix of the cases in both instances, bitwise the scalar kernel's energies
    /// (overflowing and underflowing lengths, zero rest lengths and stiffnesses in
    /// every lane).
    #[test]
    fn energies_are_bitwise_the_scalar_kernel() {
        let (x, springs) = cases();
        for n in 0..=springs.len() {
            let springs = &springs[..n];
            let scalar: Vec<f64> = springs
                .iter()
                .map(|s| crate::spring::energy(x[s.a], x[s.b], s.rest_length, s.stiffness))
                .collect();
            for instance in instances() {
                let mut e = vec![f64::NAN; n];
                energies(instance, springs, &x, &mut e);
                assert_eq!(bits(&e), bits(&scalar), "{n} {instance:?}");
            }
        }
    }

    /// Every prefix of the cases in both instances, bitwise the scalar kernel's damping
    /// directions (zero, overflowing and underflowing vectors in every lane), and the
    /// cases do give both kinds of batch (with and without a vector of no direction).
    #[test]
    fn damping_directions_are_bitwise_the_scalar_kernel() {
        let (x, springs) = cases();
        let scalar: Vec<DVec3> = springs
            .iter()
            .map(|s| crate::spring::damping_direction(x[s.a], x[s.b]))
            .collect();
        assert!(scalar.contains(&DVec3::ZERO));
        assert!(
            scalar
                .chunks(LANES)
                .any(|b| b.iter().all(|w| *w != DVec3::ZERO))
        );
        let flat = |v: &[DVec3]| -> Vec<f64> { v.iter().flat_map(|w| w.to_array()).collect() };
        for n in 0..=springs.len() {
            for instance in instances() {
                let mut w = vec![DVec3::splat(f64::NAN); n];
                damping_directions(instance, &springs[..n], &x, &mut w);
                assert_eq!(
                    bits(&flat(&w)),
                    bits(&flat(&scalar[..n])),
                    "{n} {instance:?}"
                );
            }
        }
    }

    /// Every prefix of `springs` (every batch position and remainder, the empty one
    /// included) in both instances, with the damping `damped(n)` of the first `n`
    /// springs: the gradients and the blocks in every form, computed alone and together,
    /// bitwise `gradient(e)` and `block(e, curvature)` of each spring `e`.
    fn assert_fills_are<'a>(
        springs: &[Spring],
        x: &[DVec3],
        damped: impl Fn(usize) -> Option<Damping<'a>>,
        gradient: impl Fn(usize) -> DVec3,
        block: impl Fn(usize, Curvature) -> SymBlock,
    ) {
        let curvatures = [
            Curvature::Exact,
            Curvature::Clamped,
            Curvature::Softened(0.3),
            Curvature::ExactContact(0.7),
        ];
        let flat_gradients =
            |g: &[DVec3]| bits(&g.iter().flat_map(|g| g.to_array()).collect::<Vec<_>>());
        let flat_blocks = |b: &[SymBlock]| bits(&b.iter().flat_map(|b| b.0).collect::<Vec<_>>());
        for n in 0..=springs.len() {
            let (damped, springs) = (damped(n), &springs[..n]);
            let scalar: Vec<DVec3> = (0..n).map(&gradient).collect();
            for instance in instances() {
                let mut g = vec![DVec3::splat(f64::NAN); n];
                gradients(instance, springs, x, damped, &mut g);
                assert_eq!(
                    flat_gradients(&g),
                    flat_gradients(&scalar),
                    "{n} {instance:?}"
                );
                for curvature in curvatures {
                    let scalar_blocks: Vec<SymBlock> =
                        (0..n).map(|e| block(e, curvature)).collect();
                    let mut b = vec![SymBlock([f64::NAN; 6]); n];
                    blocks(instance, springs, x, curvature, damped, &mut b);
                    assert_eq!(
                        flat_blocks(&b),
                        flat_blocks(&scalar_blocks),
                        "{n} {curvature:?}"
                    );
                    let mut g = vec![DVec3::splat(f64::NAN); n];
                    let mut b = vec![SymBlock([f64::NAN; 6]); n];
                    gradients_and_blocks(instance, springs, x, curvature, damped, &mut g, &mut b);
                    assert_eq!(
                        flat_blocks(&b),
                        flat_blocks(&scalar_blocks),
                        "{n} {curvature:?}"
                    );
                    assert_eq!(
                        flat_gradients(&g),
                        flat_gradients(&scalar),
                        "{n} {curvature:?}"
                    );
                }
            }
        }
    }

    /// Every prefix of the cases (every batch position and remainder, the empty one
    /// included) in both instances, bitwise the scalar kernels' gradients and blocks in
    /// every form, computed alone and together.
    #[test]
    fn gradients_and_blocks_are_bitwise_the_scalar_kernels() {
        let (x, springs) = cases();
        assert_fills_are(
            &springs,
            &x,
            |_| None,
            |e| springs::gradient(&springs[e], &x),
            |e, curvature| springs::block(&springs[e], &x, curvature),
        );
        // The cases reach the branches they are meant to: a gradient of zero (zero
        // length), a block `k I` (zero rest length), a non-finite length.
        assert!(
            springs
                .iter()
                .any(|s| springs::gradient(s, &x) == DVec3::ZERO)
        );
        assert!(springs.iter().any(|s| s.rest_length == 0.0));
        assert!(
            springs
                .iter()
                .any(|s| !(x[s.a] - x[s.b]).length().is_finite())
        );
    }

    /// Moves of `n` particles, zero at every third.
    fn test_moves(n: usize) -> Vec<DVec3> {
        (0..n)
            .map(|i| {
                let t = i as f64;
                if i % 3 == 0 {
                    DVec3::ZERO
                } else {
                    DVec3::new(0.01 * (2.3 * t).sin(), 0.02 * (0.4 * t).cos(), -0.003 * t)
                }
            })
            .collect()
    }

    /// Every prefix of `springs` in both instances, with the damping `damped(n)` of the
    /// first `n` springs, at one and at two step lengths (zero among them, which skips
    /// every spring): the sums along `dx` bitwise `scalar(n, alpha)`.
    fn assert_changes_are<'a>(
        springs: &[Spring],
        x: &[DVec3],
        dx: &[DVec3],
        damped: impl Fn(usize) -> Option<Damping<'a>>,
        scalar: impl Fn(usize, f64) -> f64,
    ) {
        for n in 0..=springs.len() {
            let (damped, springs) = (damped(n), &springs[..n]);
            for [a1, a2] in [[1.0, 2.0], [0.5, 0.25], [1.0, 0.0], [0.0, -1.0]] {
                let sums = [a1, a2].map(|a| scalar(n, a));
                for instance in instances() {
                    let pair = energy_change_pair_sum(instance, springs, x, dx, [a1, a2], damped);
                    assert_eq!(pair.map(f64::to_bits), sums.map(f64::to_bits), "{n} {a1}");
                    let single = energy_change_sum(instance, springs, x, dx, a1, damped);
                    assert_eq!(single.to_bits(), sums[0].to_bits(), "{n} {a1}");
                }
            }
        }
    }

    /// The scalar loop the line search ran: each spring's change added in spring order,
    /// skipping the springs whose move is zero.
    fn scalar_change(springs: &[Spring], x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        let mut change = 0.0;
        for s in springs {
            let delta = alpha * dx[s.a] - alpha * dx[s.b];
            if delta == DVec3::ZERO {
                continue;
            }
            change += springs::energy_change(s, x, delta);
        }
        change
    }

    /// Every prefix of the cases with a finite length in both instances, at one and at
    /// two step lengths (zero among them, which skips every spring), bitwise the scalar
    /// loop's sums;
    /// the moves are zero at some particles (skipped springs in every lane) and move
    /// a spring whose lengths both underflow to zero (the kernel's `0` before its
    /// division) and the coincident particles apart.
    #[test]
    fn energy_changes_are_bitwise_the_scalar_loop() {
        let (x, mut springs) = cases();
        // A length whose square overflows makes the change NaN in both (the line search
        // never sees one): left out, so the sums stay comparable past it.
        springs.retain(|s| (x[s.a] - x[s.b]).length().is_finite());
        let mut dx = test_moves(x.len());
        let z = 40;
        dx[z + 4] = DVec3::new(1e-170, 0.0, 0.0);
        dx[z] = DVec3::ZERO;
        dx[z + 1] = DVec3::new(0.0, 1e-3, 0.0);
        assert_eq!(springs::energy_change(&springs[0], &x, DVec3::ZERO), 0.0);
        let scalar = |n: usize, alpha| scalar_change(&springs[..n], &x, &dx, alpha);
        assert_changes_are(&springs, &x, &dx, |_| None, scalar);
    }

    /// The damping of the cases' springs: a coefficient, directions that are unit
    /// vectors, zero (a zero-length spring's) and of other lengths (the kernels take any
    /// vector), and reference positions away from `x`, equal to it at some particles.
    fn damping_of(x: &[DVec3], springs: &[Spring]) -> (f64, Vec<DVec3>, Vec<DVec3>) {
        let directions = springs
            .iter()
            .enumerate()
            .map(|(e, s)| match e % 5 {
                0 => DVec3::ZERO,
                1 => DVec3::new(0.3, -1.7, 0.25),
                _ => crate::spring::damping_direction(x[s.a], x[s.b]),
            })
            .collect();
        let x_ref = x
            .iter()
            .enumerate()
            .map(|(i, &p)| {
                let t = i as f64;
                if i % 4 == 0 {
                    p
                } else {
                    p + DVec3::new(0.02 * (1.1 * t).cos(), -0.01 * t.sin(), 0.003 * t)
                }
            })
            .collect();
        (3.7, directions, x_ref)
    }

    /// Every prefix of the cases in both instances, with damping: the gradients and
    /// blocks (every form, alone and together) bitwise the potential's fused per-spring
    /// expressions, the spring kernel's value plus the damping kernel's.
    #[test]
    fn damped_gradients_and_blocks_are_bitwise_the_scalar_kernels() {
        let (x, springs) = cases();
        let (c, directions, x_ref) = damping_of(&x, &springs);
        let references: Vec<DVec3> = springs.iter().map(|s| x_ref[s.a] - x_ref[s.b]).collect();
        let scalar_gradient = |e: usize| {
            let s = &springs[e];
            let (d, d_ref) = (x[s.a] - x[s.b], x_ref[s.a] - x_ref[s.b]);
            springs::gradient(s, &x) + damping::gradient(c, directions[e], d, d_ref)
        };
        let scalar_block = |e: usize, curvature| {
            let mut k = springs::block(&springs[e], &x, curvature);
            for (v, add) in k.0.iter_mut().zip(damping::block(c, directions[e]).0) {
                *v += add;
            }
            k
        };
        let damped = |n: usize| {
            Some(Damping {
                c,
                directions: &directions[..n],
                references: &references[..n],
            })
        };
        assert_fills_are(&springs, &x, damped, scalar_gradient, scalar_block);
        // The damping is not zero on the springs of the plain batches: the comparison
        // sees its terms.
        let e = 2;
        assert_ne!(
            scalar_gradient(e).to_array().map(f64::to_bits),
            springs::gradient(&springs[e], &x)
                .to_array()
                .map(f64::to_bits)
        );
    }

    /// Every prefix of the cases with a finite length in both instances, with damping, at
    /// one and two step lengths: bitwise the scalar loop of the fused potential (each
    /// moved spring's change plus its damping's, added in spring order).
    #[test]
    fn damped_energy_changes_are_bitwise_the_scalar_loop() {
        let (x, mut springs) = cases();
        springs.retain(|s| (x[s.a] - x[s.b]).length().is_finite());
        let (c, directions, x_ref) = damping_of(&x, &springs);
        let references: Vec<DVec3> = springs.iter().map(|s| x_ref[s.a] - x_ref[s.b]).collect();
        let dx = test_moves(x.len());
        let scalar_change = |n: usize, alpha: f64| {
            let mut change = 0.0;
            for (s, &w) in springs[..n].iter().zip(&directions) {
                let delta = alpha * dx[s.a] - alpha * dx[s.b];
                if delta == DVec3::ZERO {
                    continue;
                }
                let (d, d_ref) = (x[s.a] - x[s.b], x_ref[s.a] - x_ref[s.b]);
                change += springs::energy_change(s, &x, delta)
                    + damping::energy_change(c, w, d, d_ref, delta);
            }
            change
        };
        let damped = |n: usize| {
            Some(Damping {
                c,
                directions: &directions[..n],
                references: &references[..n],
            })
        };
        assert_changes_are(&springs, &x, &dx, damped, scalar_change);
        // The damping changes the sums the comparison checks.
        let n = springs.len();
        let undamped = energy_change_sum(Instance::Detect, &springs, &x, &dx, 1.0, None);
        assert_ne!(undamped.to_bits(), scalar_change(n, 1.0).to_bits());
    }
}
