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

use super::fused::PerSpring;
use super::{Potential, StepContext, SymBlock};
use crate::model::SpringSystem;
use crate::pattern::{FIXED, HessianPattern};
use crate::spring::Curvature;
use rayon::prelude::*;
use sinew_math::DVec3;

/// Springs per task of the first pass (W6's 60 198 springs: 59 tasks).
const SPRING_CHUNK: usize = 1024;
/// Particles per task of the second pass (W6's 10 199 free particles: 20 tasks, so two
/// threads end within a twentieth of the pass of each other; neither size changes a
/// bit of the result).
const PARTICLE_CHUNK: usize = 512;

/// The gather index of one topology and the per-spring buffers.
#[derive(Debug, Default)]
pub(crate) struct SpringGather {
    /// Particle `p`'s springs are `incident[incident_ptr[p]..incident_ptr[p + 1]]`, as
    /// `2 e` when `p` is spring `e`'s first particle and `2 e + 1` when its second, in
    /// increasing `e`.
    incident_ptr: Vec<usize>,
    incident: Vec<usize>,
    /// Per spring, its gradient on its first particle.
    gradients: Vec<DVec3>,
    /// Per spring, its block `K`.
    blocks: Vec<SymBlock>,
}

impl SpringGather {
    /// The index for `system`'s springs.
    pub(crate) fn new(system: &SpringSystem) -> Self {
        let n = system.len();
        let mut counts = vec![0usize; n + 1];
        for s in system.springs() {
            counts[s.a + 1] += 1;
            counts[s.b + 1] += 1;
        }
        for p in 0..n {
            counts[p + 1] += counts[p];
        }
        let incident_ptr = counts.clone();
        let mut next = counts;
        let mut incident = vec![0usize; incident_ptr[n]];
        // Springs in increasing index, each end in the order the sequential loop treats
        // them (first particle, then second).
        for (e, s) in system.springs().iter().enumerate() {
            incident[next[s.a]] = 2 * e;
            next[s.a] += 1;
            incident[next[s.b]] = 2 * e + 1;
            next[s.b] += 1;
        }
        Self {
            incident_ptr,
            incident,
            gradients: vec![DVec3::ZERO; system.springs().len()],
            blocks: vec![SymBlock([0.0; 6]); system.springs().len()],
        }
    }

    /// Whether this index was built for `system`'s particle and spring counts (the
    /// integrator checks the rest of the topology on every step).
    pub(crate) fn fits(&self, system: &SpringSystem) -> bool {
        self.incident_ptr.len() == system.len() + 1 && self.blocks.len() == system.springs().len()
    }

    /// [`Potential::gradient`] with the springs' part on the current thread pool; the
    /// same bits.
    pub(crate) fn gradient(
        &mut self,
        potential: &Potential,
        step: &StepContext<'_>,
        x: &[DVec3],
        gradient: &mut [DVec3],
    ) {
        let per = potential.per_spring(step);
        if !per.springs {
            potential.gradient(step, x, gradient);
            return;
        }
        // The other terms (inertia, gravity, ...) on one thread while the pool's others
        // start on the springs: they write `gradient`, the springs their own buffer.
        let springs = &mut self.gradients;
        rayon::join(
            || {
                gradient.fill(DVec3::ZERO);
                for &t in &potential.other_terms {
                    potential.terms[t].add_gradient(step, x, gradient);
                }
            },
            || {
                springs
                    .par_chunks_mut(SPRING_CHUNK)
                    .enumerate()
                    .for_each(|(c, chunk)| {
                        let first = c * SPRING_CHUNK;
                        for (i, g) in chunk.iter_mut().enumerate() {
                            *g = per.spring_gradient(step, x, first + i);
                        }
                    });
            },
        );
        let (ptr, incident, gradients) = (&self.incident_ptr, &self.incident, &self.gradients);
        gradient
            .par_chunks_mut(PARTICLE_CHUNK)
            .enumerate()
            .for_each(|(c, chunk)| {
                let first = c * PARTICLE_CHUNK;
                for (i, g) in chunk.iter_mut().enumerate() {
                    let p = first + i;
                    for &code in &incident[ptr[p]..ptr[p + 1]] {
                        let spring = gradients[code / 2];
                        if code % 2 == 0 {
                            *g += spring;
                        } else {
                            *g -= spring;
                        }
                    }
                }
            });
    }

    /// Writes the Newton matrix's values like zeroing `values` and calling
    /// [`Potential::add_hessian`] with a values sink on `pattern`, with the springs' part
    /// on the current thread pool; the same bits.
    pub(crate) fn hessian(
        &mut self,
        potential: &mut Potential,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        pattern: &HessianPattern,
        values: &mut [f64],
    ) {
        if !potential.per_spring(step).springs {
            values.fill(0.0);
            let mut sink = super::HessianSink::values(pattern, values);
            potential.add_hessian(step, x, curvature, &mut sink);
            return;
        }
        let potential: &Potential = potential;
        let per = potential.per_spring(step);
        // Zeroing the values and the other terms' blocks (a pass over every stored
        // entry, then the inertia's diagonal) on one thread while the pool's others start
        // on the springs' blocks, which are written to their own buffer.
        let blocks = &mut self.blocks;
        rayon::join(
            || {
                values.fill(0.0);
                let mut sink = super::HessianSink::values(pattern, values);
                for &t in &potential.other_terms {
                    potential.terms[t].add_hessian(step, x, curvature, &mut sink);
                }
            },
            || {
                blocks
                    .par_chunks_mut(SPRING_CHUNK)
                    .enumerate()
                    .for_each(|(c, chunk)| {
                        let first = c * SPRING_CHUNK;
                        for (i, k) in chunk.iter_mut().enumerate() {
                            *k = per.spring_block(step, x, curvature, first + i);
                        }
                    });
            },
        );
        let chunks = pattern.free_particles.len().div_ceil(PARTICLE_CHUNK);
        let gather = Gather {
            pattern,
            incident_ptr: &self.incident_ptr,
            incident: &self.incident,
            blocks: &self.blocks,
            springs: step.system.springs(),
        };
        gather.run(0, chunks, values, 0);
    }
}

/// What the second pass of the Hessian reads.
struct Gather<'a> {
    pattern: &'a HessianPattern,
    incident_ptr: &'a [usize],
    incident: &'a [usize],
    blocks: &'a [SymBlock],
    springs: &'a [crate::model::Spring],
}

impl Gather<'_> {
    /// The first value slot of free particle `f`'s columns (`f` may be one past the
    /// last, giving the end of the values).
    fn first_slot(&self, f: usize) -> usize {
        self.pattern.symbolic.col_ptr()[3 * f]
    }

    /// Gathers the chunks `first..last` of free particles into `values`, the slots from
    /// `offset` on, halving the range over the pool (no allocation: the value ranges are
    /// split in place).
    fn run(&self, first: usize, last: usize, values: &mut [f64], offset: usize) {
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
    /// blocks stored in its columns, in increasing spring index.
    fn particle(&self, f: usize, values: &mut [f64], offset: usize) {
        let p = self.pattern.free_particles[f];
        let diag = &self.pattern.diag_slots[f];
        for &code in &self.incident[self.incident_ptr[p]..self.incident_ptr[p + 1]] {
            let e = code / 2;
            let k = self.blocks[e];
            for (slot, v) in diag.iter().zip(k.0) {
                values[slot - offset] += v;
            }
            // The coupling block sits in the columns of the end with the smaller free
            // index; the other end's pass skips it.
            let s = &self.springs[e];
            let other = if code % 2 == 0 { s.b } else { s.a };
            let g = self.pattern.free_index[other];
            if g != FIXED
                && g > f
                && let Some(slots) = &self.pattern.off_slots[e]
            {
                let [xx, yx, zx, yy, zy, zz] = k.0;
                let full = [xx, yx, zx, yx, yy, zy, zx, zy, zz];
                for (slot, v) in slots.iter().zip(full) {
                    values[slot - offset] -= v;
                }
            }
        }
    }
}

impl PerSpring<'_> {
    /// Spring `e`'s gradient on its first particle: the sequential loop's expression.
    #[inline]
    pub(super) fn spring_gradient(&self, step: &StepContext<'_>, x: &[DVec3], e: usize) -> DVec3 {
        let s = &step.system.springs()[e];
        match self.damping {
            Some((term, c)) => {
                let w = term.directions()[e];
                let d = x[s.a] - x[s.b];
                let d_ref = step.x_ref[s.a] - step.x_ref[s.b];
                super::springs::gradient(s, x) + super::damping::kernel::gradient(c, w, d, d_ref)
            }
            None => super::springs::gradient(s, x),
        }
    }

    /// Spring `e`'s block: the sequential loop's expression.
    #[inline]
    pub(super) fn spring_block(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        e: usize,
    ) -> SymBlock {
        let s = &step.system.springs()[e];
        match self.damping {
            Some((term, c)) => {
                let w = term.directions()[e];
                let mut k = super::springs::block(s, x, curvature);
                for (v, add) in k.0.iter_mut().zip(super::damping::kernel::block(c, w).0) {
                    *v += add;
                }
                k
            }
            None => {
                let (alpha, beta, u) = super::springs::coefficients(s, x, curvature);
                SymBlock::isotropic_plus_outer(alpha, beta, u)
            }
        }
    }
}
