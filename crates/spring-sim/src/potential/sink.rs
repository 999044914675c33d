//! Where a term's Hessian blocks go: the value slots of the Newton matrix's pattern, the
//! absolute row sums of the Gershgorin bound, or a product with a vector.
//!
//! A term never sees the storage. It hands over 3x3 blocks by particle: a symmetric
//! diagonal block for `(i, i)` ([`HessianSink::add_diagonal`]), the 6x6 block
//! `[[K, -K], [-K, K]]` of a pair the pattern was built from
//! ([`HessianSink::add_edge`], the springs' fast path), or a general block for a pair
//! `(i, j)` ([`HessianSink::add_pair`], found in the pattern's structure; a pair that is
//! not there is reported, not dropped). Fixed particles are not unknowns, so blocks on
//! their rows and columns are skipped here, once, instead of in every term.

use crate::pattern::{FIXED, HessianPattern};
use sinew_math::{DMat3, DVec3};

/// A symmetric 3x3 block given by its lower entries in the order
/// `(0,0), (1,0), (2,0), (1,1), (2,1), (2,2)` (the pattern's storage order).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SymBlock(pub [f64; 6]);

impl SymBlock {
    /// `s I`.
    #[must_use]
    pub fn scaled_identity(s: f64) -> Self {
        Self([s, 0.0, 0.0, s, 0.0, s])
    }

    /// `alpha I + beta u u^T`, the form of every spring-like block.
    #[must_use]
    #[inline]
    pub fn isotropic_plus_outer(alpha: f64, beta: f64, u: DVec3) -> Self {
        Self([
            alpha + beta * u.x * u.x,
            beta * u.y * u.x,
            beta * u.z * u.x,
            alpha + beta * u.y * u.y,
            beta * u.z * u.y,
            alpha + beta * u.z * u.z,
        ])
    }

    /// The lower triangle of `m` (`m` is taken as symmetric; its upper half is ignored).
    #[must_use]
    pub fn from_lower(m: &DMat3) -> Self {
        Self([
            m.x_axis.x, m.x_axis.y, m.x_axis.z, m.y_axis.y, m.y_axis.z, m.z_axis.z,
        ])
    }

    /// The full symmetric matrix.
    #[must_use]
    pub fn to_mat3(&self) -> DMat3 {
        let [xx, yx, zx, yy, zy, zz] = self.0;
        DMat3::from_cols_array(&[xx, yx, zx, yx, yy, zy, zx, zy, zz])
    }

    /// The absolute row sums (the block's contribution to Gershgorin's discs).
    #[must_use]
    #[inline]
    fn abs_row_sums(&self) -> DVec3 {
        let [xx, yx, zx, yy, zy, zz] = self.0.map(f64::abs);
        DVec3::new(xx + yx + zx, yx + yy + zy, zx + zy + zz)
    }

    /// `B v`.
    #[must_use]
    #[inline]
    fn mul(&self, v: DVec3) -> DVec3 {
        let [xx, yx, zx, yy, zy, zz] = self.0;
        DVec3::new(
            xx * v.x + yx * v.y + zx * v.z,
            yx * v.x + yy * v.y + zy * v.z,
            zx * v.x + zy * v.y + zz * v.z,
        )
    }
}

/// What the blocks are accumulated into.
#[derive(Debug)]
enum Target<'a> {
    /// The lower-triangle values of the Newton matrix on its pattern.
    Values {
        pattern: &'a HessianPattern,
        values: &'a mut [f64],
    },
    /// Per particle, the absolute row sums of its three rows (free rows and columns only).
    RowSums {
        fixed: &'a [bool],
        rows: &'a mut [DVec3],
    },
    /// `out += H z` over the particles (fixed rows and columns are left out).
    Product {
        fixed: &'a [bool],
        z: &'a [DVec3],
        out: &'a mut [DVec3],
    },
    /// The diagonal blocks alone, one per free particle (indexed by free index), for
    /// terms that give no others: a coupling block only sets `coupled`. (Only the
    /// threaded assembly's gather collects them.)
    #[cfg_attr(not(feature = "parallel"), allow(dead_code))]
    Diagonal {
        pattern: &'a HessianPattern,
        blocks: &'a mut [SymBlock],
        coupled: bool,
    },
}

/// A pair `(i, j)` of free particles whose block the pattern has no slots for (a term
/// coupling particles no spring couples; the pattern must be rebuilt with the pair).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MissingPair {
    /// First particle.
    pub i: usize,
    /// Second particle.
    pub j: usize,
}

/// Where the coupling block of two distinct particles goes in a values sink, looked up
/// once ([`PairPlace::find`]) so that a term writing many blocks can look its pairs up on
/// several threads, keep them, and add its blocks by parts of the matrix
/// ([`HessianSink::values_mut`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) enum PairPlace {
    /// A fixed particle: nothing is added.
    #[default]
    Skip,
    /// Two free particles the pattern has no slots for.
    Missing,
    /// The block's place ([`HessianPattern::off_block_position`]), and whether the
    /// stored block is the given one's transpose (the first particle's free index is
    /// the lower one). Kept in 32 bits each: a term keeps six per pair for tens of
    /// thousands of pairs, and reads them all at every assembly.
    At { col: u32, k: u32, transposed: bool },
}

impl PairPlace {
    /// The place of the block of particles `i != j` on `pattern`.
    pub(crate) fn find(pattern: &HessianPattern, i: usize, j: usize) -> Self {
        let (fi, fj) = (pattern.free_index[i], pattern.free_index[j]);
        if fi == FIXED || fj == FIXED {
            return Self::Skip;
        }
        match pattern.off_block_position(fi, fj) {
            // A pattern's columns and blocks per column fit 32 bits (the matrix's
            // dimension does, for faer's indices); a place that did not would be looked
            // up as missing rather than wrapped.
            Some((col, k)) => match (u32::try_from(col), u32::try_from(k)) {
                (Ok(col), Ok(k)) => Self::At {
                    col,
                    k,
                    transposed: fi < fj,
                },
                _ => Self::Missing,
            },
            None => Self::Missing,
        }
    }
}

/// The receiver of a term's Hessian blocks (see the module documentation).
#[derive(Debug)]
pub struct HessianSink<'a> {
    target: Target<'a>,
}

impl<'a> HessianSink<'a> {
    /// Accumulates into `values`, the lower-triangle values on `pattern` (not cleared).
    #[must_use]
    pub fn values(pattern: &'a HessianPattern, values: &'a mut [f64]) -> Self {
        debug_assert_eq!(values.len(), pattern.nnz());
        Self {
            target: Target::Values { pattern, values },
        }
    }

    /// Accumulates, per particle, the absolute row sums of its rows over the free
    /// unknowns (not cleared): Gershgorin's bound is the largest, divided by the mass.
    #[must_use]
    pub fn row_sums(fixed: &'a [bool], rows: &'a mut [DVec3]) -> Self {
        Self {
            target: Target::RowSums { fixed, rows },
        }
    }

    /// Accumulates `out += H z` with `H` over the free unknowns (entries of `z` at
    /// fixed particles are ignored and `out` is not written there).
    #[must_use]
    pub fn product(fixed: &'a [bool], z: &'a [DVec3], out: &'a mut [DVec3]) -> Self {
        Self {
            target: Target::Product { fixed, z, out },
        }
    }

    /// Accumulates the diagonal blocks alone into `blocks`, one per free particle of
    /// `pattern` (by free index; not cleared), each entry added as the values target
    /// adds it to its slot. A coupling block (an edge or a pair of two particles) is not
    /// stored anywhere: it only marks the sink as [`Self::coupled`], and the caller then
    /// assembles the matrix the general way.
    #[must_use]
    #[cfg_attr(not(feature = "parallel"), allow(dead_code))]
    pub(crate) fn diagonal(pattern: &'a HessianPattern, blocks: &'a mut [SymBlock]) -> Self {
        debug_assert_eq!(blocks.len(), pattern.free_particles.len());
        Self {
            target: Target::Diagonal {
                pattern,
                blocks,
                coupled: false,
            },
        }
    }

    /// Whether a diagonal-blocks sink ([`Self::diagonal`]) was given a coupling block
    /// (then its blocks are not the matrix's); false for the other targets.
    #[must_use]
    #[cfg_attr(not(feature = "parallel"), allow(dead_code))]
    pub(crate) fn coupled(&self) -> bool {
        matches!(self.target, Target::Diagonal { coupled: true, .. })
    }

    /// Marks a diagonal-blocks sink as given a coupling block.
    #[inline]
    fn mark_coupled(&mut self) {
        if let Target::Diagonal { coupled, .. } = &mut self.target {
            *coupled = true;
        }
    }

    /// Adds the symmetric block `b` at `(i, i)`.
    #[inline]
    pub fn add_diagonal(&mut self, i: usize, b: SymBlock) {
        match &mut self.target {
            Target::Diagonal {
                pattern, blocks, ..
            } => {
                let f = pattern.free_index[i];
                if f != FIXED {
                    for (sum, v) in blocks[f].0.iter_mut().zip(b.0) {
                        *sum += v;
                    }
                }
            }
            Target::Values { pattern, values } => {
                let f = pattern.free_index[i];
                if f != FIXED {
                    for (slot, v) in pattern.diag_slots[f].iter().zip(b.0) {
                        values[*slot] += v;
                    }
                }
            }
            Target::RowSums { fixed, rows } => {
                if !fixed[i] {
                    rows[i] += b.abs_row_sums();
                }
            }
            Target::Product { fixed, z, out } => {
                if !fixed[i] {
                    out[i] += b.mul(z[i]);
                }
            }
        }
    }

    /// Adds `[[K, -K], [-K, K]]` on the particles `(a, b)` of `edge`, a pair the pattern
    /// was built from (the index of a spring in [`crate::SpringSystem::springs`]); the
    /// coupling block is written to the slots the pattern keeps for that edge.
    #[inline]
    pub fn add_edge(&mut self, edge: usize, a: usize, b: usize, k: SymBlock) {
        match &mut self.target {
            Target::Values { pattern, values } => edge_values(pattern, values, edge, a, b, k),
            Target::RowSums { fixed, rows } => edge_row_sums(fixed, rows, a, b, k.abs_row_sums()),
            Target::Product { fixed, z, out } => edge_product(fixed, z, out, a, b, |d| k.mul(d)),
            Target::Diagonal { .. } => self.mark_coupled(),
        }
    }

    /// [`HessianSink::add_edge`] for the block `K = alpha I + beta u u^T` (the form of
    /// every spring-like block), which the row-sum and product targets apply from its
    /// three parameters instead of its nine entries: the stability bound reads the
    /// springs' blocks only through those targets, once or more per explicit step.
    #[inline]
    pub fn add_edge_outer(
        &mut self,
        edge: usize,
        a: usize,
        b: usize,
        alpha: f64,
        beta: f64,
        u: DVec3,
    ) {
        match &mut self.target {
            Target::Values { .. } => {
                self.add_edge(edge, a, b, SymBlock::isotropic_plus_outer(alpha, beta, u));
            }
            Target::RowSums { fixed, rows } => {
                edge_row_sums(fixed, rows, a, b, outer_abs_row_sums(alpha, beta, u));
            }
            Target::Product { fixed, z, out } => {
                edge_product(fixed, z, out, a, b, |d| alpha * d + beta * u.dot(d) * u);
            }
            Target::Diagonal { .. } => self.mark_coupled(),
        }
    }

    /// [`HessianSink::add_edge_outer`] for every `(edge, a, b, alpha, beta, u)` of
    /// `edges`, choosing the target once for the whole sequence rather than per edge (the
    /// springs' loops: the per-edge choice cost more than the row sums themselves).
    #[inline]
    pub fn add_edges_outer(
        &mut self,
        edges: impl Iterator<Item = (usize, usize, usize, f64, f64, DVec3)>,
    ) {
        match &mut self.target {
            Target::Values { .. } => {
                for (edge, a, b, alpha, beta, u) in edges {
                    self.add_edge(edge, a, b, SymBlock::isotropic_plus_outer(alpha, beta, u));
                }
            }
            Target::RowSums { fixed, rows } => {
                for (_, a, b, alpha, beta, u) in edges {
                    edge_row_sums(fixed, rows, a, b, outer_abs_row_sums(alpha, beta, u));
                }
            }
            Target::Product { fixed, z, out } => {
                for (_, a, b, alpha, beta, u) in edges {
                    edge_product(fixed, z, out, a, b, |d| alpha * d + beta * u.dot(d) * u);
                }
            }
            Target::Diagonal { coupled, .. } => {
                let mut edges = edges;
                *coupled |= edges.next().is_some();
            }
        }
    }

    /// [`HessianSink::add_edge`] for every `(edge, a, b, k)` of `edges`, choosing the
    /// target once for the whole sequence.
    #[inline]
    pub fn add_edges(&mut self, edges: impl Iterator<Item = (usize, usize, usize, SymBlock)>) {
        match &mut self.target {
            Target::Values { pattern, values } => {
                for (edge, a, b, k) in edges {
                    edge_values(pattern, values, edge, a, b, k);
                }
            }
            Target::RowSums { fixed, rows } => {
                for (_, a, b, k) in edges {
                    edge_row_sums(fixed, rows, a, b, k.abs_row_sums());
                }
            }
            Target::Product { fixed, z, out } => {
                for (_, a, b, k) in edges {
                    edge_product(fixed, z, out, a, b, |d| k.mul(d));
                }
            }
            Target::Diagonal { coupled, .. } => {
                let mut edges = edges;
                *coupled |= edges.next().is_some();
            }
        }
    }

    /// Whether [`Self::add_pair`] would accept the pair `(i, j)`: always for the row-sum
    /// and product targets; for the matrix values, when `i == j`, either particle is
    /// fixed, or the pattern has slots for the pair. A term whose pairs change from one
    /// iteration to the next (self-contact) asks first, so it can keep its blocks
    /// positive semidefinite when some pairs have no slots.
    #[must_use]
    pub fn has_pair(&self, i: usize, j: usize) -> bool {
        match &self.target {
            Target::Values { pattern, .. } | Target::Diagonal { pattern, .. } => {
                let (fi, fj) = (pattern.free_index[i], pattern.free_index[j]);
                i == j || fi == FIXED || fj == FIXED || pattern.off_block_position(fi, fj).is_some()
            }
            Target::RowSums { .. } | Target::Product { .. } => true,
        }
    }

    /// Adds `scale` times what `add` adds to a sink of the same kind: `add` fills a
    /// zeroed sink of its own (same pattern, fixed flags or vector), which is then added
    /// here scaled (row sums by `|scale|`). For a term written over other unknowns than
    /// the minimization's, whose Hessian is its own times a constant (the chain rule of a
    /// linear map, as the implicit midpoint's end state `2 z - x_n`), whatever way the
    /// term adds its blocks (one by one, or by parts of the matrix).
    pub(crate) fn add_scaled(&mut self, scale: f64, add: impl FnOnce(&mut HessianSink<'_>)) {
        match &mut self.target {
            Target::Values { pattern, values } => {
                let mut own = vec![0.0; values.len()];
                add(&mut HessianSink::values(pattern, &mut own));
                for (v, o) in values.iter_mut().zip(&own) {
                    *v += scale * o;
                }
            }
            Target::RowSums { fixed, rows } => {
                let mut own = vec![DVec3::ZERO; rows.len()];
                add(&mut HessianSink::row_sums(fixed, &mut own));
                for (r, o) in rows.iter_mut().zip(&own) {
                    *r += scale.abs() * *o;
                }
            }
            Target::Product { fixed, z, out } => {
                let mut own = vec![DVec3::ZERO; out.len()];
                add(&mut HessianSink::product(fixed, z, &mut own));
                for (r, o) in out.iter_mut().zip(&own) {
                    *r += scale * *o;
                }
            }
            Target::Diagonal {
                pattern,
                blocks,
                coupled,
            } => {
                let mut own = vec![SymBlock([0.0; 6]); blocks.len()];
                let mut inner = HessianSink::diagonal(pattern, &mut own);
                add(&mut inner);
                *coupled |= inner.coupled();
                for (b, o) in blocks.iter_mut().zip(&own) {
                    for (sum, v) in b.0.iter_mut().zip(o.0) {
                        *sum += scale * v;
                    }
                }
            }
        }
    }

    /// The pattern and the values of a sink that accumulates matrix values (`None` for
    /// the other targets), for a term that adds its blocks by parts of the matrix.
    pub(crate) fn values_mut(&mut self) -> Option<(&HessianPattern, &mut [f64])> {
        match &mut self.target {
            Target::Values { pattern, values } => Some((pattern, values)),
            _ => None,
        }
    }

    /// Adds the block `b` at `(i, j)` (and `b^T` at `(j, i)`), looking the pair up in the
    /// pattern's structure. `i == j` adds the symmetric part of `b` on the diagonal.
    /// Blocks touching a fixed particle are skipped. A pair of free particles the
    /// pattern has no slots for is an `Err` and nothing is added.
    pub fn add_pair(&mut self, i: usize, j: usize, b: &DMat3) -> Result<(), MissingPair> {
        if i == j {
            let sym = (*b + b.transpose()) * 0.5;
            self.add_diagonal(i, SymBlock::from_lower(&sym));
            return Ok(());
        }
        match &mut self.target {
            Target::Values { pattern, values } => {
                let (fi, fj) = (pattern.free_index[i], pattern.free_index[j]);
                if fi == FIXED || fj == FIXED {
                    return Ok(());
                }
                let Some((col, k)) = pattern.off_block_position(fi, fj) else {
                    return Err(MissingPair { i, j });
                };
                // The stored block sits below the diagonal: row particle max(fi, fj).
                add_at(pattern, values, col, k, fi < fj, b);
            }
            Target::RowSums { fixed, rows } => {
                if fixed[i] || fixed[j] {
                    return Ok(());
                }
                let abs = b.abs();
                rows[i] += abs.x_axis + abs.y_axis + abs.z_axis;
                let t = abs.transpose();
                rows[j] += t.x_axis + t.y_axis + t.z_axis;
            }
            Target::Product { fixed, z, out } => {
                if fixed[i] || fixed[j] {
                    return Ok(());
                }
                out[i] += *b * z[j];
                out[j] += b.transpose() * z[i];
            }
            Target::Diagonal { .. } => self.mark_coupled(),
        }
        Ok(())
    }
}

/// Adds `b` (or `b^T` when `transposed`) to the off-diagonal block at `(col, k)` of
/// [`HessianPattern::off_block_position`].
fn add_at(
    pattern: &HessianPattern,
    values: &mut [f64],
    col: usize,
    k: usize,
    transposed: bool,
    b: &DMat3,
) {
    let slots = pattern.off_block_slots_at(col, k);
    let stored = if transposed { b.transpose() } else { *b };
    for c in 0..3 {
        for r in 0..3 {
            values[slots[3 * c + r]] += stored.col(c)[r];
        }
    }
}

/// Adds `[[K, -K], [-K, K]]` on edge `(a, b)` to the pattern's values.
///
/// The pattern's rows are sorted within each column, so the slots of one column of a
/// block are consecutive: `(0,0), (1,0), (2,0)`, then `(1,1), (2,1)`, then `(2,2)` of a
/// diagonal block, and three rows per column of an off-diagonal one. Writing each
/// column as one slice reads a third of the slot indices and checks a third of the
/// bounds; every slot still gets the same single addition, so the values are the same
/// bit for bit.
#[inline]
fn edge_values(
    pattern: &HessianPattern,
    values: &mut [f64],
    edge: usize,
    a: usize,
    b: usize,
    k: SymBlock,
) {
    let [xx, yx, zx, yy, zy, zz] = k.0;
    for f in [pattern.free_index[a], pattern.free_index[b]] {
        if f != FIXED {
            let s = &pattern.diag_slots[f];
            debug_assert!(s[1] == s[0] + 1 && s[2] == s[0] + 2 && s[4] == s[3] + 1);
            let first = &mut values[s[0]..s[0] + 3];
            first[0] += xx;
            first[1] += yx;
            first[2] += zx;
            let second = &mut values[s[3]..s[3] + 2];
            second[0] += yy;
            second[1] += zy;
            values[s[5]] += zz;
        }
    }
    if let Some(slots) = &pattern.off_slots[edge] {
        // Entry (r, c) at slot 3c + r; the block is symmetric.
        let full = [[xx, yx, zx], [yx, yy, zy], [zx, zy, zz]];
        for (c, column) in full.into_iter().enumerate() {
            let start = slots[3 * c];
            debug_assert!(slots[3 * c + 1] == start + 1 && slots[3 * c + 2] == start + 2);
            let target = &mut values[start..start + 3];
            target[0] -= column[0];
            target[1] -= column[1];
            target[2] -= column[2];
        }
    }
}

/// The absolute row sums of `alpha I + beta u u^T`: row `c` is
/// `|alpha + beta u_c^2| + |beta| |u_c| (|u|_1 - |u_c|)`.
#[inline]
fn outer_abs_row_sums(alpha: f64, beta: f64, u: DVec3) -> DVec3 {
    let au = u.abs();
    let diagonal = (DVec3::splat(alpha) + beta * u * u).abs();
    diagonal + beta.abs() * au * (DVec3::splat(au.element_sum()) - au)
}

/// Adds an edge block's absolute row sums `r` to the rows of its free ends.
#[inline]
fn edge_row_sums(fixed: &[bool], rows: &mut [DVec3], a: usize, b: usize, r: DVec3) {
    // The block appears on the diagonal and, when the other end is free, again as the
    // coupling block of the same row.
    let (fa, fb) = (fixed[a], fixed[b]);
    let both = if fa || fb { 1.0 } else { 2.0 };
    let r = both * r;
    if !fa {
        rows[a] += r;
    }
    if !fb {
        rows[b] += r;
    }
}

/// `out += [[K, -K], [-K, K]] z` on the free ends of edge `(a, b)`, with `K d` given by
/// `apply`.
#[inline]
fn edge_product(
    fixed: &[bool],
    z: &[DVec3],
    out: &mut [DVec3],
    a: usize,
    b: usize,
    apply: impl Fn(DVec3) -> DVec3,
) {
    let za = if fixed[a] { DVec3::ZERO } else { z[a] };
    let zb = if fixed[b] { DVec3::ZERO } else { z[b] };
    let t = apply(za - zb);
    if !fixed[a] {
        out[a] += t;
    }
    if !fixed[b] {
        out[b] -= t;
    }
}
