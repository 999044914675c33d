//! The reduced system's unknowns and the sparsity pattern of its Newton matrix, built once
//! per topology.
//!
//! Fixed particles are removed: only free particles get unknowns (three each, `3 f + c`
//! for free index `f` and axis `c`). The Newton matrix is stored as the lower triangle of
//! a compressed sparse column (CSC) matrix, with, for every free particle, the six lower
//! entries of its diagonal block and, for every spring between two free particles, the
//! nine entries of the off-diagonal block below the diagonal. Each spring knows the value
//! slots of its blocks, so assembly is a sweep over springs writing into a value array;
//! the structure never changes.

use crate::model::SpringSystem;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use sinew_math::DMat3;

/// Marks a fixed particle in [`HessianPattern::free_index`].
pub(crate) const FIXED: usize = usize::MAX;

/// The lower entries of a 3x3 diagonal block, in CSC order:
/// (0,0), (1,0), (2,0), (1,1), (2,1), (2,2).
const DIAG_ENTRIES: [(usize, usize); 6] = [(0, 0), (1, 0), (2, 0), (1, 1), (2, 1), (2, 2)];

/// Unknown numbering and matrix structure of the reduced Newton system.
#[derive(Debug)]
pub struct HessianPattern {
    /// Particle -> free index, or [`FIXED`].
    pub(crate) free_index: Vec<usize>,
    /// Free index -> particle.
    pub(crate) free_particles: Vec<usize>,
    /// Lower-triangular CSC structure of the `3 nfree x 3 nfree` matrix.
    pub(crate) symbolic: SymbolicSparseColMat<usize>,
    /// Per free particle: value slots of its diagonal block's lower entries.
    pub(crate) diag_slots: Vec<[usize; 6]>,
    /// Per spring: value slots of its off-diagonal block (entry `(r, c)` at `3 c + r`),
    /// `None` unless both ends are free.
    pub(crate) off_slots: Vec<Option<[usize; 9]>>,
    /// A number no other pattern built in this process has, so a term that keeps the
    /// places it looked up on a pattern knows whether they still hold.
    pub(crate) revision: u64,
}

/// The next [`HessianPattern::revision`] (from 1: 0 is never a pattern's).
static NEXT_REVISION: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

impl HessianPattern {
    /// Builds the pattern for `system`'s topology.
    #[must_use]
    pub fn new(system: &SpringSystem) -> Self {
        Self::with_pairs(system, &[])
    }

    /// Builds the pattern for `system`'s topology with slots also for the particle pairs
    /// `pairs` (a term coupling particles no spring joins, such as dihedral bending across
    /// a hinge). Pairs with a fixed end, repeated pairs and pairs a spring already joins
    /// add nothing; the caller checks that every index is in range.
    #[must_use]
    pub fn with_pairs(system: &SpringSystem, pairs: &[[usize; 2]]) -> Self {
        let mut free_index = vec![FIXED; system.len()];
        let mut free_particles = Vec::new();
        for (p, &fixed) in system.fixed().iter().enumerate() {
            if !fixed {
                free_index[p] = free_particles.len();
                free_particles.push(p);
            }
        }
        let nfree = free_particles.len();
        // For each free particle, the free neighbours with a larger free index (the
        // block rows below its diagonal block), sorted and distinct: `neighbours[ptr[p]..
        // ptr[p + 1]]` for particle `p`, laid out by a counting sort in one vector (the
        // integrator rebuilds the pattern whenever contact couples new pairs, and a list
        // per particle was thousands of allocations each time).
        let links = || {
            let spring_pairs = system.springs().iter().map(|s| [s.a, s.b]);
            spring_pairs
                .chain(pairs.iter().copied())
                .filter_map(|[a, b]| {
                    let (fa, fb) = (free_index[a], free_index[b]);
                    (fa != FIXED && fb != FIXED && fa != fb).then(|| (fa.min(fb), fa.max(fb)))
                })
        };
        let mut ptr = vec![0usize; nfree + 1];
        for (lo, _) in links() {
            ptr[lo + 1] += 1;
        }
        for p in 0..nfree {
            ptr[p + 1] += ptr[p];
        }
        let mut next = ptr.clone();
        let mut neighbours = vec![0usize; ptr[nfree]];
        for (lo, hi) in links() {
            neighbours[next[lo]] = hi;
            next[lo] += 1;
        }
        // Each list sorted and its repeats dropped, compacted towards the front.
        let mut kept = 0;
        for p in 0..nfree {
            let (from, to) = (ptr[p], ptr[p + 1]);
            neighbours[from..to].sort_unstable();
            ptr[p] = kept;
            for i in from..to {
                if i == from || neighbours[i] != neighbours[i - 1] {
                    neighbours[kept] = neighbours[i];
                    kept += 1;
                }
            }
        }
        ptr[nfree] = kept;
        neighbours.truncate(kept);
        let below = |p: usize| &neighbours[ptr[p]..ptr[p + 1]];
        let n = 3 * nfree;
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::with_capacity(6 * nfree + 9 * kept);
        col_ptr.push(0usize);
        for p in 0..nfree {
            for c in 0..3 {
                for r in c..3 {
                    row_idx.push(3 * p + r);
                }
                for &q in below(p) {
                    for r in 0..3 {
                        row_idx.push(3 * q + r);
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        let diag_slots = (0..nfree)
            .map(|p| DIAG_ENTRIES.map(|(r, c)| col_ptr[3 * p + c] + (r - c)))
            .collect();
        let off_slots = system
            .springs()
            .iter()
            .map(|s| {
                let (fa, fb) = (free_index[s.a], free_index[s.b]);
                if fa == FIXED || fb == FIXED {
                    return None;
                }
                let (col, row) = (fa.min(fb), fa.max(fb));
                // The neighbour list was built from these very springs.
                let k = below(col).binary_search(&row).unwrap_or(0);
                let mut slots = [0usize; 9];
                for c in 0..3 {
                    for r in 0..3 {
                        slots[3 * c + r] = col_ptr[3 * col + c] + (3 - c) + 3 * k + r;
                    }
                }
                Some(slots)
            })
            .collect();
        let symbolic = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
        Self {
            free_index,
            free_particles,
            symbolic,
            diag_slots,
            off_slots,
            revision: NEXT_REVISION.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        }
    }

    /// Number of unknowns (three per free particle).
    #[must_use]
    pub fn dim(&self) -> usize {
        3 * self.free_particles.len()
    }

    /// Number of stored (lower-triangle) entries.
    #[must_use]
    pub fn nnz(&self) -> usize {
        self.symbolic.row_idx().len()
    }

    /// The matrix with the given values (lower triangle).
    #[must_use]
    pub(crate) fn matrix<'a>(&'a self, values: &'a [f64]) -> SparseColMatRef<'a, usize, f64> {
        SparseColMatRef::new(self.symbolic.as_ref(), values)
    }

    /// Where the block below the diagonal coupling free particles `fi` and `fj` is kept:
    /// its column particle `min(fi, fj)` and the row particle's position among that
    /// column's neighbours, or `None` when the pattern holds no such pair (or
    /// `fi == fj`). A binary search in the column.
    #[must_use]
    pub(crate) fn off_block_position(&self, fi: usize, fj: usize) -> Option<(usize, usize)> {
        let (col, row) = (fi.min(fj), fi.max(fj));
        if col == row || row >= self.free_particles.len() {
            return None;
        }
        let col_ptr = self.symbolic.col_ptr();
        let row_idx = self.symbolic.row_idx();
        // Column 3 col: three diagonal-block entries, then three rows per neighbour.
        let start = col_ptr[3 * col] + 3;
        let neighbours = (col_ptr[3 * col + 1] - start) / 3;
        // The neighbours are sorted: binary search without allocating.
        let (mut lo, mut hi) = (0, neighbours);
        while lo < hi {
            let mid = (lo + hi) / 2;
            if row_idx[start + 3 * mid] < 3 * row {
                lo = mid + 1;
            } else {
                hi = mid;
            }
        }
        if lo == neighbours || row_idx[start + 3 * lo] != 3 * row {
            return None;
        }
        Some((col, lo))
    }

    /// The value slots of the block at [`Self::off_block_position`] `(col, k)`.
    #[must_use]
    pub(crate) fn off_block_slots_at(&self, col: usize, k: usize) -> [usize; 9] {
        let col_ptr = self.symbolic.col_ptr();
        let mut slots = [0usize; 9];
        for c in 0..3 {
            for r in 0..3 {
                slots[3 * c + r] = col_ptr[3 * col + c] + (3 - c) + 3 * k + r;
            }
        }
        slots
    }

    /// The diagonal block of free particle `f` read back from `values`.
    #[must_use]
    pub(crate) fn diag_block(&self, values: &[f64], f: usize) -> DMat3 {
        let s = &self.diag_slots[f];
        let (a00, a10, a20, a11, a21, a22) = (
            values[s[0]],
            values[s[1]],
            values[s[2]],
            values[s[3]],
            values[s[4]],
            values[s[5]],
        );
        DMat3::from_cols_array(&[a00, a10, a20, a10, a11, a21, a20, a21, a22])
    }

    /// `y = A x` for the symmetric matrix whose lower triangle has `values`.
    ///
    /// Column `3 p + c` holds its diagonal entry, the `2 - c` entries below it in `p`'s
    /// diagonal block, then three consecutive rows per neighbour block (the structure
    /// [`HessianPattern::with_pairs`] builds), the same neighbours in the same order in
    /// each of `p`'s three columns. The loop takes a particle's three columns together:
    /// one row index per neighbour block instead of one per entry (or per column and
    /// block), and the block's three rows of `y` and `x` are read once for the three
    /// columns instead of once per column. Each entry of `y` still gets the additions of
    /// the entry-by-entry product in its order (within a particle's columns a row of
    /// `y` is added to column by column, and no other column adds to it in between),
    /// and each column's sum the products in its order, so the result is the same bit
    /// for bit.
    pub(crate) fn sym_matvec(&self, values: &[f64], x: &[f64], y: &mut [f64]) {
        y.fill(0.0);
        let col_ptr = self.symbolic.col_ptr();
        let row_idx = self.symbolic.row_idx();
        for j in (0..self.dim()).step_by(3) {
            let (s0, s1, s2, end) = (col_ptr[j], col_ptr[j + 1], col_ptr[j + 2], col_ptr[j + 3]);
            let (x0, x1, x2) = (x[j], x[j + 1], x[j + 2]);
            // The diagonal block: column j's three entries, j + 1's two, j + 2's one.
            let (d0, d1) = (&values[s0..s0 + 3], &values[s1..s1 + 2]);
            let mut acc0 = d0[0] * x0;
            y[j + 1] += d0[1] * x0;
            acc0 += d0[1] * x1;
            y[j + 2] += d0[2] * x0;
            acc0 += d0[2] * x2;
            let mut acc1 = d1[0] * x1;
            y[j + 2] += d1[1] * x1;
            acc1 += d1[1] * x2;
            let mut acc2 = values[s2] * x2;
            let (v0, v1, v2) = (
                &values[s0 + 3..s1],
                &values[s1 + 2..s2],
                &values[s2 + 1..end],
            );
            debug_assert!(v0.len() % 3 == 0 && v1.len() == v0.len() && v2.len() == v0.len());
            let rows = &row_idx[s0 + 3..s1];
            for (((v0, v1), v2), &i) in v0
                .chunks_exact(3)
                .zip(v1.chunks_exact(3))
                .zip(v2.chunks_exact(3))
                .zip(rows.iter().step_by(3))
            {
                let (yi, xi) = (&mut y[i..i + 3], &x[i..i + 3]);
                for r in 0..3 {
                    yi[r] += v0[r] * x0;
                    yi[r] += v1[r] * x1;
                    yi[r] += v2[r] * x2;
                    acc0 += v0[r] * xi[r];
                    acc1 += v1[r] * xi[r];
                    acc2 += v2[r] * xi[r];
                }
            }
            y[j] += acc0;
            y[j + 1] += acc1;
            y[j + 2] += acc2;
        }
    }
}
