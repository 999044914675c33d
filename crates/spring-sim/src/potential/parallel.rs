//! The per-spring part of the gradient and of the Newton matrix's values computed on a
//! thread pool, bitwise equal to the sequential loops of [`super::fused`].
//!
//! The sequential loops scatter: each spring adds its gradient to both ends and its block
//! to both diagonal blocks and to its own coupling block. Two threads cannot share a
//! scatter without racing on the shared ends or reordering their sums. So the work is
//! cut in two passes, both split by ranges fixed by the sizes alone:
//! 1. per spring (chunks of springs), its gradient or its block, into a buffer;
//! 2. per particle (chunks of particles), the sum of its springs' entries, gathered in
//!    increasing spring index: the very order in which the sequential loop adds them, so
//!    every entry is the same sum of the same numbers in the same order, whichever
//!    thread computes it and however many there are. The values of a particle's three
//!    columns (its diagonal block and the coupling blocks below it) are contiguous in
//!    the pattern's storage, so chunks of particles own disjoint ranges of the values.
//!
//! When the potential's other terms are only inertia and gravity, the gather also
//! starts each particle from their per-particle kernels (the sequential loop's first
//! additions): one pass over the values, none zeroing them or adding the inertia
//! (docs/spring-sim.md, "Fewer passes over memory"). Each spring's block is computed
//! once, in the first pass, and read at both ends: its square root and four divisions
//! computed at both ends instead cost more than the buffer's traffic (docs/spring-sim.md,
//! "Each spring's block once").

use super::fused::PerSpring;
use super::lanes::{self, Instance};
use super::{Pointwise, Potential, StepContext, SymBlock, gravity, inertia};
use crate::model::SpringSystem;
use crate::pattern::{FIXED, HessianPattern};
use crate::pool::join_if;
use crate::spring::Curvature;
use rayon::prelude::*;
use sinew_math::DVec3;

/// Springs per task of the first pass (W6's 60 198 springs: 59 tasks).
const SPRING_CHUNK: usize = 1024;
/// Particles per task of the second pass (W6's 10 199 free particles: 20 tasks, so two
/// threads end within a twentieth of the pass of each other; neither size changes a
/// bit of the result).
const PARTICLE_CHUNK: usize = 512;
/// Marks a spring whose coupling block is not in the gathering particle's columns.
const NO_COUPLING: u32 = u32::MAX;

/// `fill(first, chunk)` for the chunks of `SPRING_CHUNK` springs of `out` (`first`: the
/// chunk's first spring), on the current thread pool when `par`, else in order on the
/// calling thread.
fn fill_spring_chunks<T: Send>(par: bool, out: &mut [T], fill: impl Fn(usize, &mut [T]) + Sync) {
    let fill = |(c, chunk): (usize, &mut [T])| fill(c * SPRING_CHUNK, chunk);
    if par {
        out.par_chunks_mut(SPRING_CHUNK).enumerate().for_each(fill);
    } else {
        out.chunks_mut(SPRING_CHUNK).enumerate().for_each(fill);
    }
}

/// [`fill_spring_chunks`] of two buffers with one value per spring each.
fn fill_spring_chunk_pairs<A: Send, B: Send>(
    par: bool,
    a: &mut [A],
    b: &mut [B],
    fill: impl Fn(usize, &mut [A], &mut [B]) + Sync,
) {
    let fill = |(c, (a, b)): (usize, (&mut [A], &mut [B]))| fill(c * SPRING_CHUNK, a, b);
    if par {
        a.par_chunks_mut(SPRING_CHUNK)
            .zip(b.par_chunks_mut(SPRING_CHUNK))
            .enumerate()
            .for_each(fill);
    } else {
        a.chunks_mut(SPRING_CHUNK)
            .zip(b.chunks_mut(SPRING_CHUNK))
            .enumerate()
            .for_each(fill);
    }
}

/// `f(c, chunk)` for the chunks of `PARTICLE_CHUNK` of `data`, on the current thread
/// pool when `par`, else in order on the calling thread.
fn for_particle_chunks<T: Send>(
    par: bool,
    data: &mut [T],
    f: impl Fn((usize, &mut [T])) + Sync + Send,
) {
    if par {
        data.par_chunks_mut(PARTICLE_CHUNK).enumerate().for_each(f);
    } else {
        data.chunks_mut(PARTICLE_CHUNK).enumerate().for_each(f);
    }
}

/// The gather index of one topology and the per-spring buffers.
#[derive(Debug)]
pub(crate) struct SpringGather {
    /// The particle and spring counts the index was built for.
    size: (usize, usize),
    /// Whether an index does not fit the index's 32 bits (a system of 2^31 springs or
    /// more): the assembly then runs the sequential loops, which give the same bits.
    oversized: bool,
    /// Particle `p`'s springs are `incident[incident_ptr[p]..incident_ptr[p + 1]]`, as
    /// `2 e` when `p` is spring `e`'s first particle and `2 e + 1` when its second, in
    /// increasing `e`.
    incident_ptr: Vec<usize>,
    incident: Vec<u32>,
    /// The Hessian's index on the pattern it was last used with.
    coupling: Option<CouplingIndex>,
    /// Per spring, its gradient on its first particle.
    gradients: Vec<DVec3>,
    /// Per spring, its block `K`.
    blocks: Vec<SymBlock>,
    /// Per free particle, the sum of the other terms' diagonal blocks, when they all
    /// give diagonal blocks alone (see [`Start::Diagonal`]).
    diagonal: Vec<SymBlock>,
}

/// Free particle `f`'s springs for the Hessian, `entries[ptr[f]..ptr[f + 1]]` in
/// increasing spring index: `[e, k]` with `k` the position of the spring's coupling
/// block among the neighbour blocks of `f`'s columns when `f` holds it (the other end is
/// free with a larger free index), else [`NO_COUPLING`]. Everything the gather needs of
/// the pattern besides `col_ptr`, in 8 bytes per spring end, instead of the spring, the
/// other end's free index and the spring's nine slots.
#[derive(Debug)]
struct CouplingIndex {
    /// The dimension and stored entries of the pattern it was built for (a pattern is
    /// only ever widened, which adds entries).
    pattern_size: (usize, usize),
    ptr: Vec<usize>,
    entries: Vec<[u32; 2]>,
    /// Per free particle, whether its springs' coupling blocks cover its columns'
    /// neighbour blocks exactly once each (no neighbour block without a spring, as a
    /// pair added for another term has, and no two springs on one pair): its gather
    /// then writes every stored value of its columns without zeroing them first.
    covered: Vec<bool>,
}

impl CouplingIndex {
    /// The index for `system`'s springs on `pattern`, from the springs' incidence lists.
    fn new(
        system: &SpringSystem,
        pattern: &HessianPattern,
        incident_ptr: &[usize],
        incident: &[u32],
    ) -> Self {
        let springs = system.springs();
        let col_ptr = pattern.symbolic.col_ptr();
        let mut ptr = Vec::with_capacity(pattern.free_particles.len() + 1);
        ptr.push(0);
        let mut entries = Vec::with_capacity(incident.len());
        let mut covered = Vec::with_capacity(pattern.free_particles.len());
        let mut seen = Vec::new();
        for (f, &p) in pattern.free_particles.iter().enumerate() {
            let first = entries.len();
            for &code in &incident[incident_ptr[p]..incident_ptr[p + 1]] {
                let e = (code / 2) as usize;
                let s = &springs[e];
                let other = if code % 2 == 0 { s.b } else { s.a };
                let g = pattern.free_index[other];
                // The coupling block sits in the columns of the end with the smaller
                // free index; column `3 f` holds three diagonal entries, then three
                // rows per neighbour block. `k` is below the particle count, which
                // fits 32 bits (checked when the incidence lists were built).
                let k = match &pattern.off_slots[e] {
                    Some(slots) if g != FIXED && g > f => (slots[0] - col_ptr[3 * f] - 3) / 3,
                    _ => NO_COUPLING as usize,
                };
                entries.push([code / 2, k as u32]);
            }
            ptr.push(entries.len());
            // Column `3 f` holds the diagonal block's three entries, then three rows per
            // neighbour block.
            let neighbours = (col_ptr[3 * f + 1] - col_ptr[3 * f] - 3) / 3;
            seen.clear();
            seen.resize(neighbours, false);
            let mut once = true;
            for &[_, k] in &entries[first..] {
                if k != NO_COUPLING {
                    match seen.get_mut(k as usize) {
                        Some(s) if !*s => *s = true,
                        _ => once = false,
                    }
                }
            }
            covered.push(once && seen.iter().all(|&s| s));
        }
        Self {
            pattern_size: (pattern.dim(), pattern.nnz()),
            ptr,
            entries,
            covered,
        }
    }
}

impl SpringGather {
    /// The index for `system`'s springs.
    pub(crate) fn new(system: &SpringSystem) -> Self {
        let n = system.len();
        let springs = system.springs();
        let size = (n, springs.len());
        // Codes `2 e + 1` and neighbour positions below `NO_COUPLING`.
        if springs.len() >= (u32::MAX / 2) as usize || n >= u32::MAX as usize {
            return Self {
                size,
                oversized: true,
                incident_ptr: Vec::new(),
                incident: Vec::new(),
                coupling: None,
                gradients: Vec::new(),
                blocks: Vec::new(),
                diagonal: Vec::new(),
            };
        }
        let mut counts = vec![0usize; n + 1];
        for s in springs {
            counts[s.a + 1] += 1;
            counts[s.b + 1] += 1;
        }
        for p in 0..n {
            counts[p + 1] += counts[p];
        }
        let incident_ptr = counts.clone();
        let mut next = counts;
        let mut incident = vec![0u32; incident_ptr[n]];
        // Springs in increasing index, each end in the order the sequential loop treats
        // them (first particle, then second). The casts fit: checked above.
        for (e, s) in springs.iter().enumerate() {
            incident[next[s.a]] = (2 * e) as u32;
            next[s.a] += 1;
            incident[next[s.b]] = (2 * e + 1) as u32;
            next[s.b] += 1;
        }
        Self {
            size,
            oversized: false,
            incident_ptr,
            incident,
            coupling: None,
            gradients: vec![DVec3::ZERO; springs.len()],
            blocks: vec![SymBlock([0.0; 6]); springs.len()],
            diagonal: Vec::new(),
        }
    }

    /// Whether this index was built for `system`'s particle and spring counts (the
    /// integrator checks the rest of the topology on every step).
    pub(crate) fn fits(&self, system: &SpringSystem) -> bool {
        self.size == (system.len(), system.springs().len())
    }

    /// [`Potential::gradient`] with the springs' part on the current thread pool when
    /// `par` (else on the calling thread, by the sequential scatter); the same bits.
    ///
    /// With `blocks`, the pass over the springs also writes each spring's Hessian block
    /// in that form to the blocks' buffer, for a [`Self::hessian`] at the same `x` that
    /// is told so: the Newton iteration that follows a gradient needs the blocks at the
    /// same positions, and one pass computing both reads the springs and their ends once
    /// instead of twice and is one parallel region less. Returns whether it wrote them.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn gradient(
        &mut self,
        potential: &Potential,
        step: &StepContext<'_>,
        x: &[DVec3],
        gradient: &mut [DVec3],
        par: bool,
        blocks: Option<Curvature>,
    ) -> bool {
        let per = potential.per_spring(step);
        if !per.springs || self.oversized {
            potential.gradient(step, x, gradient);
            return false;
        }
        if !par {
            // On one thread the sequential scatter is the cheaper gradient (the gather's
            // buffer and its pass over the particles cost more than the scatter's
            // random writes): the same loop, each spring's block written beside it.
            gradient.fill(DVec3::ZERO);
            for &t in &potential.other_terms {
                potential.terms[t].add_gradient(step, x, gradient);
            }
            let springs = step.system.springs();
            // A chunk's gradients (and blocks) four springs at a time into their
            // buffers (the damping's added to each spring's), then the chunk's scatter
            // in spring order: the same additions in the same order.
            for first in (0..springs.len()).step_by(SPRING_CHUNK) {
                let range = first..(first + SPRING_CHUNK).min(springs.len());
                let chunk = &springs[range.clone()];
                let damping = per.lanes_damping(range.clone());
                let g = &mut self.gradients[range.clone()];
                match blocks {
                    Some(curvature) => lanes::gradients_and_blocks(
                        Instance::Detect,
                        chunk,
                        x,
                        curvature,
                        damping,
                        g,
                        &mut self.blocks[range],
                    ),
                    None => lanes::gradients(Instance::Detect, chunk, x, damping, g),
                }
                for (s, &g) in chunk.iter().zip(&*g) {
                    gradient[s.a] += g;
                    gradient[s.b] -= g;
                }
            }
            return blocks.is_some();
        }
        let (springs, block_buffer) = (&mut self.gradients, &mut self.blocks);
        let all = step.system.springs();
        // Four springs at a time (`lanes`, the damping's added to each spring's), the
        // same bits.
        let mut spring_pass = move || match blocks {
            Some(curvature) => {
                fill_spring_chunk_pairs(par, springs, block_buffer, |first, g, b| {
                    let range = first..first + g.len();
                    let damping = per.lanes_damping(range.clone());
                    let chunk = &all[range];
                    let i = Instance::Detect;
                    lanes::gradients_and_blocks(i, chunk, x, curvature, damping, g, b);
                });
            }
            None => fill_spring_chunks(par, springs, |first, g| {
                let range = first..first + g.len();
                let damping = per.lanes_damping(range.clone());
                lanes::gradients(Instance::Detect, &all[range], x, damping, g);
            }),
        };
        // With only inertia and gravity besides the springs, each particle's gather
        // starts from their terms, added in the terms' order as the sequential loop
        // does after zeroing: one pass over the gradient instead of three.
        let pointwise = potential.pointwise_others.as_deref();
        if pointwise.is_some() {
            spring_pass();
        } else {
            // The other terms on one thread while the pool's others start on the
            // springs: they write `gradient`, the springs their own buffer.
            join_if(
                par,
                || {
                    gradient.fill(DVec3::ZERO);
                    for &t in &potential.other_terms {
                        potential.terms[t].add_gradient(step, x, gradient);
                    }
                },
                spring_pass,
            );
        }
        let (ptr, incident, gradients) = (&self.incident_ptr, &self.incident, &self.gradients);
        let masses = step.system.masses();
        let inv_h2 = 1.0 / (step.h * step.h);
        let g_vec = step.system.material().gravity;
        for_particle_chunks(par, gradient, |(c, chunk)| {
            let first = c * PARTICLE_CHUNK;
            for (i, g) in chunk.iter_mut().enumerate() {
                let p = first + i;
                // The sum is kept in a local over the springs and stored once (added in
                // place, it went through memory at every spring): the same additions.
                let mut sum = *g;
                if let Some(kinds) = pointwise {
                    sum = DVec3::ZERO;
                    for kind in kinds {
                        match kind {
                            Pointwise::Inertia => inertia::add_gradient_at(
                                &mut sum, masses[p], inv_h2, x[p], step.y[p],
                            ),
                            Pointwise::Gravity => {
                                gravity::add_gradient_at(&mut sum, masses[p], g_vec);
                            }
                        }
                    }
                }
                for &code in &incident[ptr[p]..ptr[p + 1]] {
                    let spring = gradients[(code / 2) as usize];
                    if code % 2 == 0 {
                        sum += spring;
                    } else {
                        sum -= spring;
                    }
                }
                *g = sum;
            }
        });
        blocks.is_some()
    }

    /// Writes the Newton matrix's values like zeroing `values` and calling
    /// [`Potential::add_hessian`] with a values sink on `pattern`, with the springs' part
    /// on the current thread pool when `par` (else on the calling thread, by the same
    /// passes); the same bits. `blocks_ready`: the blocks' buffer already holds the
    /// springs' blocks at `x` in the form `curvature` (written by [`Self::gradient`]),
    /// so they are not computed again.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn hessian(
        &mut self,
        potential: &mut Potential,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        pattern: &HessianPattern,
        values: &mut [f64],
        par: bool,
        blocks_ready: bool,
    ) {
        if !potential.per_spring(step).springs || self.oversized {
            values.fill(0.0);
            let mut sink = super::HessianSink::values(pattern, values);
            potential.add_hessian(step, x, curvature, &mut sink);
            return;
        }
        let potential: &Potential = potential;
        let per = potential.per_spring(step);
        let size = (pattern.dim(), pattern.nnz());
        if self
            .coupling
            .as_ref()
            .is_some_and(|c| c.pattern_size != size)
        {
            self.coupling = None;
        }
        let (incident_ptr, incident) = (&self.incident_ptr, &self.incident);
        let index = self.coupling.get_or_insert_with(|| {
            CouplingIndex::new(step.system, pattern, incident_ptr, incident)
        });
        let chunks = pattern.free_particles.len().div_ceil(PARTICLE_CHUNK);
        let inertia_terms = potential.pointwise_others.as_deref().map(|kinds| {
            kinds
                .iter()
                .filter(|k| matches!(k, Pointwise::Inertia))
                .count()
        });
        let mut diagonal_start = false;
        if inertia_terms.is_some() {
            // Only inertia and gravity besides the springs (gravity has no curvature):
            // each particle's gather zeroes its own columns and adds the inertia's
            // diagonal block before its springs' blocks, the sequential loop's order, so
            // no pass zeroes every stored entry and none adds the inertia. The springs'
            // blocks are computed first, once each, into their buffer: computed where
            // they are needed, at both ends, the block's square root and four divisions
            // ran twice per spring, and the gather waited on the divider more than
            // the buffer's 48 bytes per spring, written and read back, cost.
            if !blocks_ready {
                per.fill_spring_blocks(par, step, x, curvature, &mut self.blocks);
            }
        } else if potential
            .other_terms
            .iter()
            .all(|&t| potential.terms[t].hessian_is_block_diagonal())
        {
            // The other terms give diagonal blocks alone (inertia and contact with rigid
            // colliders): their sums per particle, added in the terms' order from zero
            // as into the zeroed values, are collected in a buffer of one block per free
            // particle, and each particle's gather starts its diagonal from them. No pass
            // zeroes the 0.47 MB of the ground workload's values (the gather writes every
            // stored value of a covered particle's columns), and the other terms' blocks
            // go to consecutive memory instead of the pattern's slots.
            let (diagonal, blocks) = (&mut self.diagonal, &mut self.blocks);
            diagonal.clear();
            diagonal.resize(pattern.free_particles.len(), SymBlock([0.0; 6]));
            let mut coupled = false;
            join_if(
                par,
                || {
                    let mut sink = super::HessianSink::diagonal(pattern, diagonal);
                    for &t in &potential.other_terms {
                        potential.terms[t].add_hessian(step, x, curvature, &mut sink);
                    }
                    coupled = sink.coupled();
                },
                || {
                    if !blocks_ready {
                        per.fill_spring_blocks(par, step, x, curvature, blocks);
                    }
                },
            );
            if coupled {
                // A term said it had diagonal blocks alone and gave a coupling block:
                // the general way, with the values zeroed and every term's blocks in them.
                values.fill(0.0);
                let mut sink = super::HessianSink::values(pattern, values);
                for &t in &potential.other_terms {
                    potential.terms[t].add_hessian(step, x, curvature, &mut sink);
                }
            } else {
                diagonal_start = true;
            }
        } else {
            // Zeroing the values and the other terms' blocks (a pass over every stored
            // entry, then the inertia's diagonal) on one thread while the pool's others
            // start on the springs' blocks, which are written to their own buffer.
            let blocks = &mut self.blocks;
            join_if(
                par,
                || {
                    values.fill(0.0);
                    let mut sink = super::HessianSink::values(pattern, values);
                    for &t in &potential.other_terms {
                        potential.terms[t].add_hessian(step, x, curvature, &mut sink);
                    }
                },
                || {
                    if !blocks_ready {
                        per.fill_spring_blocks(par, step, x, curvature, blocks);
                    }
                },
            );
        }
        let blocks = &self.blocks;
        let start = match inertia_terms {
            Some(count) => Start::Fold(Fold {
                count,
                inv_h2: 1.0 / (step.h * step.h),
                masses: step.system.masses(),
            }),
            None if diagonal_start => Start::Diagonal(&self.diagonal),
            None => Start::Values,
        };
        let gather = Gather {
            par,
            pattern,
            coupling_ptr: &index.ptr,
            coupling: &index.entries,
            covered: &index.covered,
            blocks: |e| blocks[e],
            start,
        };
        gather.run(0, chunks, values, 0);
    }
}

/// The inertia folded into the Hessian's gather: how many inertia terms, `1/h^2` and
/// the masses.
struct Fold<'a> {
    count: usize,
    inv_h2: f64,
    masses: &'a [f64],
}

/// Where each particle's diagonal block starts from in the gather, before its springs'
/// blocks are added.
enum Start<'a> {
    /// The values as the other terms left them in the zeroed matrix (the general way):
    /// the gather adds to what is stored, in the diagonal block and the coupling blocks.
    Values,
    /// The inertia folded in: the particle's columns are written from zero, the
    /// diagonal block from the inertia's.
    Fold(Fold<'a>),
    /// The other terms' diagonal blocks collected per free particle: the particle's
    /// columns are written from zero, the diagonal block from the collected one.
    Diagonal(&'a [SymBlock]),
}

/// What the second pass of the Hessian reads.
struct Gather<'a, B> {
    /// Whether the chunks are spread over the current thread pool.
    par: bool,
    pattern: &'a HessianPattern,
    coupling_ptr: &'a [usize],
    coupling: &'a [[u32; 2]],
    /// [`CouplingIndex::covered`].
    covered: &'a [bool],
    blocks: B,
    start: Start<'a>,
}

impl<B: Fn(usize) -> SymBlock + Sync> Gather<'_, B> {
    /// The first value slot of free particle `f`'s columns (`f` may be one past the
    /// last, giving the end of the values).
    fn first_slot(&self, f: usize) -> usize {
        self.pattern.symbolic.col_ptr()[3 * f]
    }

    /// Gathers the chunks `first..last` of free particles into `values`, the slots from
    /// `offset` on, halving the range over the pool (no allocation: the value ranges are
    /// split in place).
    fn run(&self, first: usize, last: usize, values: &mut [f64], offset: usize) {
        if !self.par {
            let nfree = self.pattern.free_particles.len();
            for f in first * PARTICLE_CHUNK..(last * PARTICLE_CHUNK).min(nfree) {
                self.particle(f, values, offset);
            }
            return;
        }
        if last - first > 1 {
            let mid = first + (last - first) / 2;
            let split = self.first_slot(mid * PARTICLE_CHUNK) - offset;
            let (low, high) = values.split_at_mut(split);
            rayon::join(
                || self.run(first, mid, low, offset),
                || self.run(mid, last, high, offset + split),
            );
            return;
        }
        if first == last {
            return;
        }
        let nfree = self.pattern.free_particles.len();
        let end = ((first + 1) * PARTICLE_CHUNK).min(nfree);
        for f in first * PARTICLE_CHUNK..end {
            self.particle(f, values, offset);
        }
    }

    /// Adds free particle `f`'s springs to its diagonal block and writes their coupling
    /// blocks stored in its columns, in increasing spring index, from the start
    /// [`Self::start`] says.
    ///
    /// The slots follow from the structure [`HessianPattern::with_pairs`] builds: column
    /// `3 f + c` holds the `3 - c` lower entries of the diagonal block's column `c`, then
    /// three rows per neighbour block, so the diagonal entries sit at the columns' starts
    /// and neighbour block `k`'s column `c` at `3 - c + 3 k` past them.
    fn particle(&self, f: usize, values: &mut [f64], offset: usize) {
        let col_ptr = self.pattern.symbolic.col_ptr();
        let c0 = col_ptr[3 * f] - offset;
        let c1 = col_ptr[3 * f + 1] - offset;
        let c2 = col_ptr[3 * f + 2] - offset;
        let end = col_ptr[3 * f + 3] - offset;
        let cols = &mut values[c0..end];
        let (c1, c2) = (c1 - c0, c2 - c0);
        let diag = [0, 1, 2, c1, c1 + 1, c2];
        // The diagonal block's six sums are kept in registers over the springs and
        // stored once. Added in place, each went through memory at every spring (the
        // coupling blocks' stores might alias them, as far as the compiler knows): a
        // chain of a load, an addition and a store per spring and entry. The same
        // additions in the same order, from the same start (the zeroed value or what
        // the other terms stored).
        let mut sums = [0.0; 6];
        // Whether the columns are written from zero (else added to), and whether every
        // value of them is written by the loop below (then they are not zeroed first).
        let (from_zero, covered) = match &self.start {
            Start::Values => {
                for (sum, &slot) in sums.iter_mut().zip(&diag) {
                    *sum = cols[slot];
                }
                (false, false)
            }
            Start::Fold(fold) => {
                let m = fold.masses[self.pattern.free_particles[f]];
                for _ in 0..fold.count {
                    for (sum, v) in sums.iter_mut().zip(inertia::block(m, fold.inv_h2).0) {
                        *sum += v;
                    }
                }
                (true, self.covered[f])
            }
            Start::Diagonal(blocks) => {
                sums = blocks[f].0;
                (true, self.covered[f])
            }
        };
        if from_zero && !covered {
            cols.fill(0.0);
        }
        let springs = &self.coupling[self.coupling_ptr[f]..self.coupling_ptr[f + 1]];
        if covered {
            self.add_springs::<true>(springs, cols, c1, c2, &mut sums);
        } else {
            self.add_springs::<false>(springs, cols, c1, c2, &mut sums);
        }
        for (&slot, sum) in diag.iter().zip(sums) {
            cols[slot] = sum;
        }
    }

    /// Adds the blocks of a particle's `springs` (its entries of the coupling index) to
    /// its diagonal block's `sums` and subtracts each from its coupling slots in the
    /// particle's columns `cols` (`c1`, `c2`: where its second and third columns start):
    /// from the stored value, or with `WRITE` (each slot is that one spring's alone) from
    /// zero without reading it: `0.0 - v`, what `-=` gives on a zeroed slot, so the same
    /// bits, `-0.0` included.
    #[inline(always)]
    fn add_springs<const WRITE: bool>(
        &self,
        springs: &[[u32; 2]],
        cols: &mut [f64],
        c1: usize,
        c2: usize,
        sums: &mut [f64; 6],
    ) {
        for &[e, k] in springs {
            let block = (self.blocks)(e as usize);
            for (sum, v) in sums.iter_mut().zip(block.0) {
                *sum += v;
            }
            if k != NO_COUPLING {
                // The block's three columns, each three consecutive slots written as one
                // slice (one bounds check instead of three).
                let k = 3 * k as usize;
                let [xx, yx, zx, yy, zy, zz] = block.0;
                for (first, column) in [
                    (3 + k, [xx, yx, zx]),
                    (c1 + 2 + k, [yx, yy, zy]),
                    (c2 + 1 + k, [zx, zy, zz]),
                ] {
                    let slots = &mut cols[first..first + 3];
                    for (slot, v) in slots.iter_mut().zip(column) {
                        if WRITE {
                            *slot = 0.0 - v;
                        } else {
                            *slot -= v;
                        }
                    }
                }
            }
        }
    }
}

impl PerSpring<'_> {
    /// Every spring's block into `blocks` (one per spring), on the current thread pool
    /// in fixed chunks when `par`.
    fn fill_spring_blocks(
        &self,
        par: bool,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        blocks: &mut [SymBlock],
    ) {
        // Four springs at a time (`lanes`, the damping's added to each spring's), the
        // same bits.
        let all = step.system.springs();
        fill_spring_chunks(par, blocks, |first, b| {
            let range = first..first + b.len();
            let damping = self.lanes_damping(range.clone());
            lanes::blocks(Instance::Detect, &all[range], x, curvature, damping, b);
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ClothGrid;
    use crate::potential::{HessianSink, Term};

    /// A lab sheet of `size x size` particles (spacing 0.05, the given damping) at rest
    /// in a state moved off its rest positions (shrunk and rippled), and that state.
    fn moved_sheet(size: usize, damping: f64) -> (SpringSystem, Vec<DVec3>) {
        let mut system =
            SpringSystem::cloth(&ClothGrid::lab_sized(size, 0.05).with_damping(damping)).unwrap();
        let x: Vec<DVec3> = system
            .positions()
            .iter()
            .enumerate()
            .map(|(i, p)| *p * 0.9 + 0.01 * DVec3::new((0.7 * i as f64).sin(), 0.0, 0.3))
            .collect();
        let v = vec![DVec3::ZERO; x.len()];
        system.set_state(&x, &v).unwrap();
        (system, x)
    }

    /// The gather's gradient and Newton matrix, on the calling thread and on pools of two
    /// and three threads, with the springs' blocks computed in their own pass or in the
    /// gradient's, are bitwise the sequential scatter's, for an undamped and a damped
    /// sheet moved off its rest state and for the projected and a softened Hessian.
    #[test]
    fn the_gather_is_the_scatter_bit_for_bit() {
        for damping in [0.0, 0.2] {
            let (system, x) = moved_sheet(41, damping);
            let y: Vec<DVec3> = x.iter().map(|p| *p + DVec3::new(0.0, -0.01, 0.0)).collect();
            let x_ref: Vec<DVec3> = x.iter().map(|p| *p * 1.01).collect();
            let step = StepContext::new(&system, 1.0 / 60.0, &y, &x_ref);
            let mut potential = Potential::mass_spring(&system);
            potential.begin_step(&step);
            let pattern = HessianPattern::new(&system);
            for curvature in [Curvature::Clamped, Curvature::Softened(0.5)] {
                let mut scatter = vec![0.0; pattern.nnz()];
                potential.add_hessian(
                    &step,
                    &x,
                    curvature,
                    &mut HessianSink::values(&pattern, &mut scatter),
                );
                let mut scatter_gradient = vec![DVec3::ZERO; x.len()];
                potential.gradient(&step, &x, &mut scatter_gradient);
                let run = |par: bool, potential: &mut Potential| {
                    let mut answers = Vec::new();
                    for blocks in [None, Some(curvature)] {
                        // A fresh gather each time, so blocks the Hessian reads as ready
                        // can only be the gradient's.
                        let mut gather = SpringGather::new(&system);
                        let mut gradient = vec![DVec3::ONE; x.len()];
                        let ready =
                            gather.gradient(potential, &step, &x, &mut gradient, par, blocks);
                        assert_eq!(ready, blocks.is_some());
                        let mut values = vec![1.0; pattern.nnz()];
                        gather.hessian(
                            potential,
                            &step,
                            &x,
                            curvature,
                            &pattern,
                            &mut values,
                            par,
                            ready,
                        );
                        answers.push((gradient, values));
                    }
                    answers
                };
                let mut all = run(false, &mut potential);
                for threads in [2, 3] {
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .unwrap();
                    all.extend(pool.install(|| run(true, &mut potential)));
                }
                assert_eq!(all.len(), 6);
                for (gradient, values) in &all {
                    let bits = |v: &[f64]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(values), bits(&scatter), "{damping} {curvature:?}");
                    for (p, (a, b)) in gradient.iter().zip(&scatter_gradient).enumerate() {
                        if !system.fixed()[p] {
                            assert_eq!(
                                bits(&a.to_array()),
                                bits(&b.to_array()),
                                "{damping} {curvature:?} {p}"
                            );
                        }
                    }
                }
            }
        }
    }

    /// A test term with one diagonal block and one coupling block (spring 0's pair),
    /// which says it has diagonal blocks alone when `claims_diagonal` (a term that is
    /// wrong about itself).
    #[derive(Debug)]
    struct Coupler {
        claims_diagonal: bool,
    }

    impl Term for Coupler {
        fn name(&self) -> &'static str {
            "coupler"
        }
        fn energy(&self, _: &StepContext<'_>, _: &[DVec3]) -> f64 {
            0.0
        }
        fn energy_change(&self, _: &StepContext<'_>, _: &[DVec3], _: &[DVec3], _: f64) -> f64 {
            0.0
        }
        fn add_gradient(&self, _: &StepContext<'_>, _: &[DVec3], _: &mut [DVec3]) {}
        fn add_hessian(
            &self,
            step: &StepContext<'_>,
            _: &[DVec3],
            _: Curvature,
            sink: &mut HessianSink<'_>,
        ) {
            let s = step.system.springs()[0];
            sink.add_diagonal(s.b, SymBlock([0.3, 0.1, 0.0, 0.7, 0.2, 0.9]));
            sink.add_edge(0, s.a, s.b, SymBlock([1.5, 0.25, -0.5, 2.0, 0.125, 3.0]));
        }
        fn hessian_is_block_diagonal(&self) -> bool {
            self.claims_diagonal
        }
    }

    /// With other terms besides inertia and gravity, the gather is the scatter bit for
    /// bit on the calling thread and on a pool of two: contact with the ground (diagonal
    /// blocks alone, collected per particle, some particles within `dhat`), with a term
    /// coupling two particles (the values zeroed first), and with a term that says it
    /// has diagonal blocks alone and gives a coupling block (detected, assembled the
    /// general way); on the springs' pattern, where every particle's columns are its
    /// springs' blocks alone, and on one widened by a pair no spring joins (the columns
    /// of its lower particle zeroed first).
    #[test]
    fn the_gather_with_other_terms_is_the_scatter_bit_for_bit() {
        use crate::contact::{Collider, ContactPotential, ContactSettings, ContactTerm};
        let (system, x) = moved_sheet(21, 0.2);
        let lowest = x.iter().map(|p| p.y).fold(f64::INFINITY, f64::min);
        let ground = Collider::ground(lowest - 5e-4);
        let settings = ContactSettings {
            mu: 0.3,
            ..ContactSettings::default()
        };
        let y: Vec<DVec3> = x.iter().map(|p| *p + DVec3::new(0.0, -0.01, 0.0)).collect();
        let x_ref: Vec<DVec3> = x.iter().map(|p| *p * 1.01).collect();
        let step = StepContext::new(&system, 1.0 / 60.0, &y, &x_ref);
        let far = (1..system.len())
            .find(|&p| system.springs().iter().all(|s| [s.a, s.b] != [0, p]))
            .unwrap();
        let patterns = [
            HessianPattern::new(&system),
            HessianPattern::with_pairs(&system, &[[0, far]]),
        ];
        let bits = |v: &[f64]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        for coupler in [None, Some(false), Some(true)] {
            let mut potential = Potential::mass_spring(&system);
            let contact = ContactPotential::new(vec![ground], settings, 0.0).unwrap();
            potential.push(Box::new(ContactTerm::new(contact)));
            if let Some(claims_diagonal) = coupler {
                potential.push(Box::new(Coupler { claims_diagonal }));
            }
            potential.begin_step(&step);
            potential.update_active_set(&step, &x);
            for pattern in &patterns {
                let mut scatter = vec![0.0; pattern.nnz()];
                let mut sink = HessianSink::values(pattern, &mut scatter);
                potential.add_hessian(&step, &x, Curvature::Clamped, &mut sink);
                // The contact's blocks are in the matrix.
                let mut inertia_springs = vec![0.0; pattern.nnz()];
                let mut without = Potential::mass_spring(&system);
                without.begin_step(&step);
                let mut sink = HessianSink::values(pattern, &mut inertia_springs);
                without.add_hessian(&step, &x, Curvature::Clamped, &mut sink);
                assert_ne!(bits(&scatter), bits(&inertia_springs));
                let mut run = |par: bool| {
                    let mut gather = SpringGather::new(&system);
                    let mut values = vec![1.0; pattern.nnz()];
                    let (p, c) = (&mut potential, Curvature::Clamped);
                    gather.hessian(p, &step, &x, c, pattern, &mut values, par, false);
                    assert_eq!(bits(&values), bits(&scatter), "{coupler:?} {par}");
                };
                run(false);
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(2)
                    .build()
                    .unwrap();
                pool.install(|| run(true));
            }
        }
    }
}
