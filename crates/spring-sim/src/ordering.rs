//! Fill-reducing orderings of the particle graph for the direct solve: nested dissection,
//! and the counts of the Cholesky factor an ordering gives.
//!
//! The Newton matrix is made of 3x3 blocks, one block row and column per free particle,
//! so an ordering of the particles (each particle's three unknowns kept together) is an
//! ordering of the matrix, and the factor's block structure is the particle graph's.
//! Nested dissection (George, 1973) splits the graph by a small vertex separator, numbers
//! the separator last and the two halves first, each ordered the same way: no entry of
//! the factor ever couples the two halves, so on a 2-D sheet (separators of `O(sqrt n)`
//! particles) the factor has `O(n log n)` entries and the factorization `O(n^1.5)`
//! multiply-adds, far fewer than minimum degree leaves on the large sheets
//! (docs/spring-sim.md, "Nested dissection").
//!
//! Everything here is a function of the graph alone: breadth-first searches in index
//! order, ties broken by the smaller index, no hashing, no threads and no clock.

use crate::pattern::HessianPattern;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::SymbolicSparseColMat;
use faer::sparse::linalg::cholesky::simplicial;

/// The particle graph of a pattern: an edge between two free particles wherever the
/// matrix has a block between them. Symmetric, no loops, each list sorted.
#[derive(Clone, Debug)]
pub(crate) struct ParticleGraph {
    /// Particle `p`'s neighbours are `adj[ptr[p]..ptr[p + 1]]`.
    pub(crate) ptr: Vec<usize>,
    pub(crate) adj: Vec<usize>,
}

impl ParticleGraph {
    /// The graph of `pattern`'s off-diagonal blocks, read from the first scalar column
    /// of each particle's block column (its diagonal block's three entries, then three
    /// rows per neighbour below it).
    pub(crate) fn new(pattern: &HessianPattern) -> Self {
        let particles = pattern.free_particles.len();
        let col_ptr = pattern.symbolic.col_ptr();
        let row_idx = pattern.symbolic.row_idx();
        let below = |p: usize| {
            row_idx[col_ptr[3 * p] + 3..col_ptr[3 * p + 1]]
                .iter()
                .step_by(3)
                .map(|r| r / 3)
        };
        let mut degree = vec![0usize; particles];
        for p in 0..particles {
            for q in below(p) {
                degree[p] += 1;
                degree[q] += 1;
            }
        }
        let mut ptr = Vec::with_capacity(particles + 1);
        ptr.push(0);
        for d in &degree {
            ptr.push(ptr[ptr.len() - 1] + d);
        }
        let mut fill = ptr[..particles].to_vec();
        let mut adj = vec![0usize; ptr[particles]];
        // Column by column: `q`'s list receives the smaller `p` in increasing order
        // before its own neighbours below it, so every list comes out sorted.
        for p in 0..particles {
            for q in below(p) {
                adj[fill[p]] = q;
                fill[p] += 1;
                adj[fill[q]] = p;
                fill[q] += 1;
            }
        }
        Self { ptr, adj }
    }

    /// Number of particles.
    pub(crate) fn len(&self) -> usize {
        self.ptr.len() - 1
    }

    fn neighbours(&self, p: usize) -> &[usize] {
        &self.adj[self.ptr[p]..self.ptr[p + 1]]
    }

    /// The lower triangle with the diagonal, as faer's orderings read it.
    pub(crate) fn lower(&self) -> SymbolicSparseColMat<usize> {
        let n = self.len();
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut rows = Vec::with_capacity(self.adj.len() / 2 + n);
        col_ptr.push(0);
        for p in 0..n {
            rows.push(p);
            rows.extend(self.neighbours(p).iter().copied().filter(|&q| q > p));
            col_ptr.push(rows.len());
        }
        SymbolicSparseColMat::new_checked(n, n, col_ptr, None, rows)
    }
}

/// The factor a particle ordering gives the scalar matrix (each particle's three
/// unknowns consecutive, a dense 3x3 block per edge).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct FactorCounts {
    /// Entries below the diagonal.
    pub(crate) nonzeros: f64,
    /// Multiply-adds of the factorization, `sum_j d_j (d_j + 1) / 2` over the columns
    /// with `d_j` entries below the diagonal.
    pub(crate) multiply_adds: f64,
}

/// The factor's counts under the ordering `perm` (`perm[new] = old`): the elimination
/// tree's column counts of the permuted particle graph (faer's
/// `prefactorize_symbolic_cholesky`), a block column of `c` blocks (its diagonal one
/// included) expanded to three scalar columns with `3 (c - 1) + 2`, `+ 1` and `+ 0`
/// entries below the diagonal.
pub(crate) fn factor_counts(graph: &ParticleGraph, perm: &[usize]) -> FactorCounts {
    let n = graph.len();
    let mut inverse = vec![0usize; n];
    for (new, &old) in perm.iter().enumerate() {
        inverse[old] = new;
    }
    // The permuted graph's upper triangle with the diagonal, rows sorted.
    let mut columns: Vec<Vec<usize>> = (0..n).map(|j| vec![j]).collect();
    for p in 0..n {
        for &q in graph.neighbours(p) {
            let (a, b) = (inverse[p], inverse[q]);
            if a < b {
                columns[b].push(a);
            }
        }
    }
    let mut ptr = Vec::with_capacity(n + 1);
    let mut rows = Vec::with_capacity(graph.adj.len() / 2 + n);
    ptr.push(0usize);
    for mut column in columns {
        column.sort_unstable();
        rows.extend(column);
        ptr.push(rows.len());
    }
    let upper = SymbolicSparseColMat::new_checked(n, n, ptr, None, rows);
    let mut etree = vec![0isize; n];
    let mut counts = vec![0usize; n];
    let mut work = MemBuffer::new(simplicial::prefactorize_symbolic_cholesky_scratch::<usize>(
        n,
        upper.row_idx().len(),
    ));
    simplicial::prefactorize_symbolic_cholesky(
        &mut etree,
        &mut counts,
        upper.as_ref(),
        MemStack::new(&mut work),
    );
    let mut nonzeros = 0.0;
    let mut multiply_adds = 0.0;
    for &c in &counts {
        for r in 0..3 {
            let d = (3 * (c - 1) + 2 - r) as f64;
            nonzeros += d;
            multiply_adds += 0.5 * d * (d + 1.0);
        }
    }
    FactorCounts {
        nonzeros,
        multiply_adds,
    }
}

/// How a part small enough to stop dissecting is ordered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum LeafOrder {
    /// As the breadth-first search that cut it off met its particles.
    Search,
    /// Minimum degree on the part's own graph (ties: the earlier in search order).
    MinimumDegree,
    /// faer's approximate minimum degree on the part's own graph.
    Amd,
}

/// How the separator's level is chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Cut {
    /// Where the particles met reach half the part's.
    Half,
    /// The level `l` of least `|S| / (|A| |B|)`.
    Ratio,
}

/// The settings of [`nested_dissection`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Dissection {
    /// Parts of at most this many particles are not dissected further.
    pub(crate) leaf: usize,
    /// How those parts are ordered.
    pub(crate) leaf_order: LeafOrder,
    /// How the separator is chosen.
    pub(crate) cut: Cut,
}

impl Default for Dissection {
    fn default() -> Self {
        Self {
            leaf: 64,
            leaf_order: LeafOrder::MinimumDegree,
            cut: Cut::Half,
        }
    }
}

/// A part still to be ordered: its particles, the first position it fills and its label.
struct Part {
    vertices: Vec<usize>,
    first: usize,
    label: usize,
}

/// Labels of particles already numbered.
const NUMBERED: usize = usize::MAX;

/// A breadth-first search inside one part, with its level structure.
struct Search {
    /// The particles met, in order.
    order: Vec<usize>,
    /// Level `l` is `order[levels[l]..levels[l + 1]]`.
    levels: Vec<usize>,
}

impl Search {
    fn new() -> Self {
        Self {
            order: Vec::new(),
            levels: Vec::new(),
        }
    }

    /// Writes each met particle's level into `distance`.
    fn record(&self, distance: &mut [usize]) {
        for l in 0..self.depth() {
            for &p in self.level(l) {
                distance[p] = l;
            }
        }
    }

    fn depth(&self) -> usize {
        self.levels.len() - 1
    }

    fn level(&self, l: usize) -> &[usize] {
        &self.order[self.levels[l]..self.levels[l + 1]]
    }

    /// Searches from `root` over the particles labelled `label`; `seen[p] == mark` marks
    /// the particles met (a fresh `mark` per search, so `seen` is never cleared).
    #[allow(clippy::too_many_arguments)]
    fn run(
        &mut self,
        graph: &ParticleGraph,
        labels: &[usize],
        label: usize,
        root: usize,
        seen: &mut [usize],
        mark: usize,
    ) {
        self.order.clear();
        self.levels.clear();
        self.order.push(root);
        seen[root] = mark;
        self.levels.push(0);
        let mut start = 0;
        while start < self.order.len() {
            let end = self.order.len();
            self.levels.push(end);
            for k in start..end {
                let p = self.order[k];
                for &q in graph.neighbours(p) {
                    if labels[q] == label && seen[q] != mark {
                        seen[q] = mark;
                        self.order.push(q);
                    }
                }
            }
            start = end;
        }
    }
}

/// A nested-dissection ordering of `graph`, `perm[new] = old`.
///
/// Each connected part larger than `settings.leaf` is cut by a separator found from
/// breadth-first distances: `d_u` from a pseudo-peripheral particle `u` (found by
/// searching again from the farthest level's particle of least degree while the depth
/// grows), `d_v` from the farthest particle `v` of that search and `d_w` from the particle
/// `w` farthest from both. Each of `d_u`, `d_w` (a level, width 1) and the differences
/// `d_u - d_v`, `d_u - d_w`, `d_v - d_w` (width 2: an edge changes a distance by at most 1,
/// so a difference by at most 2) is a key; the particles whose key lies in
/// `[t, t + width)` separate those below from those above, since no edge spans the
/// window. The candidate of least `|S| / (|A| |B|)` over all keys and `t` is taken (the
/// differences of two corners' distances cut a sheet straight across, where a single
/// search's levels cut it diagonally or in an L). A separator particle with no
/// neighbour on one side is then moved to the other, which thins it. The separator is
/// numbered after the two sides, which are ordered in turn. A part that is not
/// connected is ordered one component after the other, with no separator. Parts of at
/// most `settings.leaf` particles, and parts too shallow to cut, are ordered by
/// `settings.leaf_order`.
pub(crate) fn nested_dissection(graph: &ParticleGraph, settings: Dissection) -> Vec<usize> {
    dissect(graph, settings).0
}

/// [`nested_dissection`], with the sizes of the first cut's two sides and separator
/// (the first side at positions `0..a`, the second at `a..a + b`, the separator last).
fn dissect(graph: &ParticleGraph, settings: Dissection) -> (Vec<usize>, Option<[usize; 3]>) {
    let n = graph.len();
    let mut top = None;
    let mut perm = vec![0usize; n];
    let mut labels = vec![0usize; n];
    let mut next_label = 1;
    let mut seen = vec![0usize; n];
    let mut mark = 0;
    let mut search = Search::new();
    let mut other = Search::new();
    // Distances from u, v and w, written for the current part's particles only.
    let mut distance = [vec![0usize; n], vec![0usize; n], vec![0usize; n]];
    let mut keys: Vec<isize> = Vec::new();
    let mut counts: Vec<usize> = Vec::new();
    let mut parts = vec![Part {
        vertices: (0..n).collect(),
        first: 0,
        label: 0,
    }];
    let degree = |p: usize| graph.ptr[p + 1] - graph.ptr[p];
    while let Some(part) = parts.pop() {
        let size = part.vertices.len();
        if size == 0 {
            continue;
        }
        // The root: least degree, then the first in the part's order.
        let mut root = part.vertices[0];
        for &p in &part.vertices {
            if degree(p) < degree(root) {
                root = p;
            }
        }
        mark += 1;
        search.run(graph, &labels, part.label, root, &mut seen, mark);
        if search.order.len() < size {
            // Not connected: the component met, then the rest (dissected on its own).
            let rest: Vec<usize> = part
                .vertices
                .iter()
                .copied()
                .filter(|&p| seen[p] != mark)
                .collect();
            let component = std::mem::take(&mut search.order);
            let first_rest = part.first + component.len();
            for (vertices, first) in [(rest, first_rest), (component, part.first)] {
                for &p in &vertices {
                    labels[p] = next_label;
                }
                parts.push(Part {
                    vertices,
                    first,
                    label: next_label,
                });
                next_label += 1;
            }
            continue;
        }
        if size > settings.leaf {
            // The pseudo-peripheral particle: search again from the deepest level's
            // particle of least degree while that deepens the search.
            for _ in 0..8 {
                let candidate = least_degree(graph, search.level(search.depth() - 1));
                mark += 1;
                other.run(graph, &labels, part.label, candidate, &mut seen, mark);
                if other.depth() > search.depth() {
                    std::mem::swap(&mut search, &mut other);
                } else {
                    break;
                }
            }
        }
        // A cut needs a level with levels on both sides.
        let cut = if size <= settings.leaf || search.depth() < 3 {
            None
        } else {
            // d_u from the search, d_v from its deepest level, d_w from the particle
            // farthest from both.
            search.record(&mut distance[0]);
            let v = least_degree(graph, search.level(search.depth() - 1));
            mark += 1;
            other.run(graph, &labels, part.label, v, &mut seen, mark);
            other.record(&mut distance[1]);
            let mut w = v;
            let far = |p: usize| distance[0][p].min(distance[1][p]);
            for &p in &search.order {
                if far(p) > far(w) {
                    w = p;
                }
            }
            mark += 1;
            other.run(graph, &labels, part.label, w, &mut seen, mark);
            other.record(&mut distance[2]);
            best_cut(
                &search.order,
                &distance,
                settings.cut,
                &mut keys,
                &mut counts,
            )
        };
        let Some((key, low, high)) = cut else {
            let order = std::mem::take(&mut search.order);
            let ordered = order_leaf(graph, &labels, part.label, order, settings.leaf_order);
            for (k, &p) in ordered.iter().enumerate() {
                perm[part.first + k] = p;
                labels[p] = NUMBERED;
            }
            continue;
        };
        let (a_label, b_label, s_label) = (next_label, next_label + 1, next_label + 2);
        next_label += 3;
        for &p in &search.order {
            let k = key.of(&distance, p);
            labels[p] = if k < low {
                a_label
            } else if k >= high {
                b_label
            } else {
                s_label
            };
        }
        // Thinning: a separator particle with no neighbour on one side joins the other.
        for &p in &search.order {
            if labels[p] != s_label {
                continue;
            }
            let touches = |side: usize| graph.neighbours(p).iter().any(|&q| labels[q] == side);
            if !touches(b_label) {
                labels[p] = a_label;
            } else if !touches(a_label) {
                labels[p] = b_label;
            }
        }
        let (mut a, mut b, mut s) = (Vec::new(), Vec::new(), Vec::new());
        for &p in &search.order {
            match labels[p] {
                l if l == a_label => a.push(p),
                l if l == b_label => b.push(p),
                _ => s.push(p),
            }
        }
        if part.label == 0 {
            top = Some([a.len(), b.len(), s.len()]);
        }
        let last = part.first + size - s.len();
        for (k, &p) in s.iter().enumerate() {
            perm[last + k] = p;
            labels[p] = NUMBERED;
        }
        let first_b = part.first + a.len();
        parts.push(Part {
            vertices: b,
            first: first_b,
            label: b_label,
        });
        parts.push(Part {
            vertices: a,
            first: part.first,
            label: a_label,
        });
    }
    (perm, top)
}

/// The particle of least degree in `particles`, the first of them on a tie.
fn least_degree(graph: &ParticleGraph, particles: &[usize]) -> usize {
    let degree = |p: usize| graph.ptr[p + 1] - graph.ptr[p];
    let mut best = particles[0];
    for &p in particles {
        if degree(p) < degree(best) {
            best = p;
        }
    }
    best
}

/// A key a separator is a window of: a distance or a difference of two.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Key {
    Distance(usize),
    Difference(usize, usize),
}

impl Key {
    const ALL: [Key; 5] = [
        Key::Distance(0),
        Key::Distance(2),
        Key::Difference(0, 1),
        Key::Difference(0, 2),
        Key::Difference(1, 2),
    ];

    fn of(self, distance: &[Vec<usize>; 3], p: usize) -> isize {
        match self {
            Key::Distance(a) => distance[a][p] as isize,
            Key::Difference(a, b) => distance[a][p] as isize - distance[b][p] as isize,
        }
    }

    /// How many consecutive key values a separator spans.
    fn width(self) -> isize {
        match self {
            Key::Distance(_) => 1,
            Key::Difference(..) => 2,
        }
    }
}

/// The separator window `[low, high)` of one key over the part `order`, of least
/// `|S| / (|A| |B|)` (or, for [`Cut::Half`], of the first single search's level where the
/// particles below reach half); `None` when no window leaves particles on both sides.
fn best_cut(
    order: &[usize],
    distance: &[Vec<usize>; 3],
    rule: Cut,
    keys: &mut Vec<isize>,
    counts: &mut Vec<usize>,
) -> Option<(Key, isize, isize)> {
    let size = order.len();
    let mut best: Option<(f64, Key, isize, isize)> = None;
    let candidates: &[Key] = match rule {
        Cut::Half => &Key::ALL[..1],
        Cut::Ratio => &Key::ALL,
    };
    for &key in candidates {
        keys.clear();
        keys.extend(order.iter().map(|&p| key.of(distance, p)));
        let min = *keys.iter().min()?;
        let max = *keys.iter().max()?;
        let span = (max - min + 1) as usize;
        counts.clear();
        counts.resize(span + 1, 0);
        // counts[k] = particles with key below min + k.
        for &k in keys.iter() {
            counts[(k - min) as usize + 1] += 1;
        }
        for k in 1..=span {
            counts[k] += counts[k - 1];
        }
        let width = key.width();
        for low in min + 1..=max - width {
            let high = low + width;
            let a = counts[(low - min) as usize];
            let below_high = counts[(high - min) as usize];
            let (s, b) = (below_high - a, size - below_high);
            if a == 0 || b == 0 {
                continue;
            }
            let score = match rule {
                Cut::Ratio => s as f64 / (a as f64 * b as f64),
                Cut::Half => {
                    if below_high < size / 2 && high < max {
                        continue;
                    }
                    0.0
                }
            };
            if best.is_none_or(|(best_score, ..)| score < best_score) {
                best = Some((score, key, low, high));
            }
            if rule == Cut::Half {
                break;
            }
        }
    }
    best.map(|(_, key, low, high)| (key, low, high))
}

/// Orders a part's particles (`order`, all labelled `label`) by `rule`.
fn order_leaf(
    graph: &ParticleGraph,
    labels: &[usize],
    label: usize,
    order: Vec<usize>,
    rule: LeafOrder,
) -> Vec<usize> {
    match rule {
        LeafOrder::Search => order,
        LeafOrder::Amd => {
            let m = order.len();
            let mut local = std::collections::BTreeMap::new();
            for (k, &p) in order.iter().enumerate() {
                local.insert(p, k);
            }
            let mut col_ptr = vec![0usize];
            let mut rows = Vec::new();
            for (k, &p) in order.iter().enumerate() {
                let mut col: Vec<usize> = graph
                    .neighbours(p)
                    .iter()
                    .filter(|&&q| labels[q] == label)
                    .map(|q| local[q])
                    .filter(|&j| j > k)
                    .collect();
                col.push(k);
                col.sort_unstable();
                rows.extend(col);
                col_ptr.push(rows.len());
            }
            let lower = SymbolicSparseColMat::new_checked(m, m, col_ptr, None, rows);
            let mut perm = vec![0usize; m];
            let mut inv = vec![0usize; m];
            let mut work = MemBuffer::new(faer::sparse::linalg::amd::order_scratch::<usize>(
                m,
                lower.row_idx().len(),
            ));
            match faer::sparse::linalg::amd::order(
                &mut perm,
                &mut inv,
                lower.as_ref(),
                faer::sparse::linalg::amd::Control::default(),
                MemStack::new(&mut work),
            ) {
                Ok(_) => perm.iter().map(|&k| order[k]).collect(),
                Err(_) => order,
            }
        }
        LeafOrder::MinimumDegree => {
            // The part's elimination graph, explicitly (parts are small): local indices
            // in search order, each neighbour set sorted.
            let m = order.len();
            let mut local = std::collections::BTreeMap::new();
            for (k, &p) in order.iter().enumerate() {
                local.insert(p, k);
            }
            let mut sets: Vec<Vec<usize>> = order
                .iter()
                .map(|&p| {
                    let mut s: Vec<usize> = graph
                        .neighbours(p)
                        .iter()
                        .filter(|&&q| labels[q] == label)
                        .map(|q| local[q])
                        .collect();
                    s.sort_unstable();
                    s
                })
                .collect();
            let mut eliminated = vec![false; m];
            let mut result = Vec::with_capacity(m);
            for _ in 0..m {
                let mut best = usize::MAX;
                for k in 0..m {
                    if !eliminated[k] && (best == usize::MAX || sets[k].len() < sets[best].len()) {
                        best = k;
                    }
                }
                eliminated[best] = true;
                result.push(order[best]);
                let clique = std::mem::take(&mut sets[best]);
                for &u in &clique {
                    let mut merged: Vec<usize> = sets[u]
                        .iter()
                        .chain(&clique)
                        .copied()
                        .filter(|&w| w != u && w != best)
                        .collect();
                    merged.sort_unstable();
                    merged.dedup();
                    sets[u] = merged;
                }
            }
            result
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{Bending, MeshCloth, TriangleMesh};
    use crate::model::{ClothGrid, Material, SpringSystem};
    use faer::Side;
    use faer::dyn_stack::MemBuffer;
    use faer::perm::PermRef;
    use faer::sparse::linalg::SupernodalThreshold;
    use faer::sparse::linalg::amd;
    use faer::sparse::linalg::cholesky::{
        CholeskySymbolicParams, SymbolicCholeskyRaw, SymmetricOrdering, factorize_symbolic_cholesky,
    };
    use sinew_math::DVec3;

    fn grid(size: usize) -> SpringSystem {
        ClothGrid {
            fixed: Vec::new(),
            ..ClothGrid::lab_sized(size, 2.0 / (size - 1) as f64)
        }
        .build()
        .unwrap()
    }

    fn mesh(sheets: &[(usize, DVec3, DVec3, DVec3)], fixed: Vec<usize>) -> SpringSystem {
        let (mut x, mut t) = (Vec::new(), Vec::new());
        for &(size, origin, u, w) in sheets {
            let g = ClothGrid {
                size,
                spacing: 0.01,
                origin,
                ..ClothGrid::lab()
            };
            let (xs, ts) = g.sheet(u, w, x.len());
            x.extend(xs);
            t.extend(ts);
        }
        let mesh = TriangleMesh::new(x, t).unwrap();
        MeshCloth {
            areal_density: 0.2,
            material: Material::earth().with_stiffness(500.0),
            bending: Bending::None,
            fixed,
        }
        .build(&mesh)
        .unwrap()
        .system
    }

    fn amd_perm(graph: &ParticleGraph) -> Vec<usize> {
        let n = graph.len();
        let lower = graph.lower();
        let mut perm = vec![0usize; n];
        let mut inv = vec![0usize; n];
        let mut work = MemBuffer::new(amd::order_scratch::<usize>(n, lower.row_idx().len()));
        amd::order(
            &mut perm,
            &mut inv,
            lower.as_ref(),
            amd::Control::default(),
            MemStack::new(&mut work),
        )
        .unwrap();
        perm
    }

    /// Scalar counts from faer's simplicial symbolic factorization of the pattern.
    fn faer_counts(pattern: &HessianPattern, perm: Option<&[usize]>) -> FactorCounts {
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SIMPLICIAL,
            ..Default::default()
        };
        let (fwd, inv);
        let ordering = match perm {
            None => SymmetricOrdering::Amd,
            Some(p) => {
                fwd = p
                    .iter()
                    .flat_map(|&q| [3 * q, 3 * q + 1, 3 * q + 2])
                    .collect::<Vec<_>>();
                let mut i = vec![0usize; fwd.len()];
                for (k, &q) in fwd.iter().enumerate() {
                    i[q] = k;
                }
                inv = i;
                SymmetricOrdering::Custom(PermRef::new_checked(&fwd, &inv, fwd.len()))
            }
        };
        let s =
            factorize_symbolic_cholesky(pattern.symbolic.as_ref(), Side::Lower, ordering, params)
                .unwrap();
        let SymbolicCholeskyRaw::Simplicial(s) = s.raw() else {
            panic!()
        };
        let cp = s.col_ptr();
        let (mut nonzeros, mut multiply_adds) = (0.0, 0.0);
        for j in 0..cp.len() - 1 {
            let d = (cp[j + 1] - cp[j] - 1) as f64;
            nonzeros += d;
            multiply_adds += 0.5 * d * (d + 1.0);
        }
        FactorCounts {
            nonzeros,
            multiply_adds,
        }
    }

    /// The first cut of a lab-pattern sheet (skip-one bend springs: a separator two rows
    /// thick) and of a triangle mesh really separates: no edge joins the two sides, each
    /// side is at least a quarter of the sheet (the ratio rule trades balance for a
    /// smaller separator), and the separator is at most two rows.
    /// The ordering is a permutation, the same twice, and its counts are faer's own.
    #[test]
    fn the_dissection_separates_and_is_a_deterministic_permutation() {
        let twist_fixed: Vec<usize> = (0..30).chain(29 * 30..30 * 30).collect();
        for (system, side) in [
            (grid(31), 31),
            (
                mesh(&[(30, DVec3::ZERO, DVec3::X, DVec3::Z)], twist_fixed),
                30,
            ),
        ] {
            let pattern = HessianPattern::new(&system);
            let graph = ParticleGraph::new(&pattern);
            let n = graph.len();
            for settings in [
                Dissection::default(),
                Dissection {
                    leaf: 16,
                    leaf_order: LeafOrder::Search,
                    cut: Cut::Ratio,
                },
            ] {
                let (perm, top) = dissect(&graph, settings);
                let mut sorted = perm.clone();
                sorted.sort_unstable();
                assert_eq!(sorted, (0..n).collect::<Vec<_>>());
                assert_eq!(dissect(&graph, settings), (perm.clone(), top));
                let [a, b, s] = top.unwrap();
                assert_eq!(a + b + s, n);
                assert!(4 * a >= n && 4 * b >= n, "{a} {b} {s}");
                assert!(s <= 2 * side, "{s}");
                let mut position = vec![0; n];
                for (k, &p) in perm.iter().enumerate() {
                    position[p] = k;
                }
                for p in 0..n {
                    for &q in graph.neighbours(p) {
                        let (x, y) = (position[p], position[q]);
                        assert!(!(x < a && (a..a + b).contains(&y)), "{p} {q}");
                    }
                }
                assert_eq!(
                    factor_counts(&graph, &perm),
                    faer_counts(&pattern, Some(&perm))
                );
            }
        }
    }

    /// The direct solve under the dissection's ordering agrees with the one under faer's
    /// AMD to round-off, on a stretched 11 x 11 lab cloth's Newton matrix.
    #[test]
    fn the_dissected_solve_agrees_with_the_amd_solve() {
        use crate::linear::{DirectSolver, FactorStructure};
        let mut system = grid(21);
        let x: Vec<DVec3> = system
            .positions()
            .iter()
            .enumerate()
            .map(|(i, p)| *p * 1.2 + DVec3::new(0.0, 0.01 * (i as f64).sin(), 0.0))
            .collect();
        let v = vec![DVec3::ZERO; x.len()];
        system.set_state(&x, &v).unwrap();
        let pattern = HessianPattern::new(&system);
        let values: Vec<f64> = crate::newton::newton_matrix_triplets(&system, 1.0 / 60.0)
            .iter()
            .map(|t| t.2)
            .collect();
        let perm = nested_dissection(
            &ParticleGraph::new(&pattern),
            Dissection {
                leaf: 16,
                leaf_order: LeafOrder::Search,
                cut: Cut::Ratio,
            },
        );
        let b: Vec<f64> = (0..pattern.dim()).map(|i| (i as f64 * 0.7).cos()).collect();
        let (mut amd, mut nd) = (b.clone(), b.clone());
        let mut solver = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
        assert!(solver.solve_unshifted(&pattern, &values, &mut amd));
        let mut solver =
            DirectSolver::with_particle_ordering(&pattern, FactorStructure::Supernodal, &perm)
                .unwrap();
        assert!(solver.solve_unshifted(&pattern, &values, &mut nd));
        let scale = amd.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let gap = amd
            .iter()
            .zip(&nd)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(gap <= 1e-10 * scale, "{gap} {scale}");
        assert!(amd != nd || perm.iter().enumerate().all(|(k, &p)| k == p));
    }

    #[test]
    #[ignore = "prints the table of docs/spring-sim.md"]
    fn print_orderings() {
        let third = |k: f64| {
            (
                DVec3::new(k.cos(), 0.0, k.sin()),
                DVec3::new(-k.sin(), 0.0, k.cos()),
            )
        };
        let stack: Vec<_> = (0..3)
            .map(|k| {
                let (u, w) = third(0.1 * k as f64);
                (
                    32,
                    DVec3::new(0.01 * k as f64, 0.01 + 0.02 * k as f64, 0.0),
                    u,
                    w,
                )
            })
            .collect();
        let twist_fixed: Vec<usize> = (0..50).chain(49 * 50..50 * 50).collect();
        let cases: Vec<(&str, SpringSystem)> = vec![
            ("lab 61", grid(61)),
            ("lab 101", grid(101)),
            ("lab 11", grid(11)),
            ("lab 31", grid(31)),
            (
                "mesh 50 (C4)",
                mesh(&[(50, DVec3::ZERO, DVec3::X, DVec3::Z)], twist_fixed),
            ),
            ("3 x mesh 32 (C5)", mesh(&stack, Vec::new())),
        ];
        for (name, system) in &cases {
            let pattern = HessianPattern::new(system);
            let graph = ParticleGraph::new(&pattern);
            let t = std::time::Instant::now();
            let amd = factor_counts(&graph, &amd_perm(&graph));
            let t_amd = t.elapsed().as_secs_f64() * 1e3;
            let scalar = faer_counts(&pattern, None);
            println!(
                "{name}: n {} | scalar AMD nnz {:.3e} F {:.3e} | particle AMD nnz {:.3e} F {:.3e} ({t_amd:.2} ms)",
                pattern.dim(),
                scalar.nonzeros,
                scalar.multiply_adds,
                amd.nonzeros,
                amd.multiply_adds
            );
            for (leaf_order, cut) in [
                (LeafOrder::Search, Cut::Half),
                (LeafOrder::Amd, Cut::Half),
                (LeafOrder::Search, Cut::Ratio),
                (LeafOrder::Amd, Cut::Ratio),
            ] {
                for leaf in [16, 32, 64, 128, 256, 512] {
                    let t = std::time::Instant::now();
                    let perm = nested_dissection(
                        &graph,
                        Dissection {
                            leaf,
                            leaf_order,
                            cut,
                        },
                    );
                    let t_nd = t.elapsed().as_secs_f64() * 1e3;
                    let nd = factor_counts(&graph, &perm);
                    let check = faer_counts(&pattern, Some(&perm));
                    assert_eq!(nd, check);
                    println!(
                        "  ND {leaf_order:?} {cut:?} {leaf}: nnz {:.3e} ({:.3}) F {:.3e} ({:.3}) [{t_nd:.2} ms]",
                        nd.nonzeros,
                        nd.nonzeros / scalar.nonzeros,
                        nd.multiply_adds,
                        nd.multiply_adds / scalar.multiply_adds
                    );
                }
            }
        }
    }

    /// `ND_CASE=<i> ND_ORDER=amd|nd<leaf> ND_REPS=<r>`: factors case `i`'s Newton
    /// matrix (stretched 1.2x) `r` times after one warm-up, printing the CPU time per
    /// factorization (instruction counts: callgrind with two values of `r`).
    #[test]
    #[ignore = "a measurement for docs/spring-sim.md"]
    fn factor_with_ordering() {
        use crate::linear::{DirectSolver, FactorStructure};
        let Ok(case) = std::env::var("ND_CASE") else {
            return;
        };
        let order = std::env::var("ND_ORDER").unwrap_or_else(|_| "amd".into());
        let reps: usize = std::env::var("ND_REPS").map_or(3, |r| r.parse().unwrap());
        let third = |k: f64| {
            (
                DVec3::new(k.cos(), 0.0, k.sin()),
                DVec3::new(-k.sin(), 0.0, k.cos()),
            )
        };
        let stack: Vec<_> = (0..3)
            .map(|k| {
                let (u, w) = third(0.1 * k as f64);
                (
                    32,
                    DVec3::new(0.01 * k as f64, 0.01 + 0.02 * k as f64, 0.0),
                    u,
                    w,
                )
            })
            .collect();
        let twist_fixed: Vec<usize> = (0..50).chain(49 * 50..50 * 50).collect();
        let mut system = match case.as_str() {
            "61" => grid(61),
            "101" => grid(101),
            "31" => grid(31),
            "11" => grid(11),
            "c4" => mesh(&[(50, DVec3::ZERO, DVec3::X, DVec3::Z)], twist_fixed),
            "c5" => mesh(&stack, Vec::new()),
            other => panic!("{other}"),
        };
        let x: Vec<DVec3> = system
            .positions()
            .iter()
            .enumerate()
            .map(|(i, p)| *p * 1.2 + DVec3::new(0.0, 0.01 * (i as f64).sin(), 0.0))
            .collect();
        let v = vec![DVec3::ZERO; x.len()];
        system.set_state(&x, &v).unwrap();
        let pattern = HessianPattern::new(&system);
        let triplets = crate::newton::newton_matrix_triplets(&system, 1.0 / 60.0);
        let values: Vec<f64> = triplets.iter().map(|t| t.2).collect();
        let graph = ParticleGraph::new(&pattern);
        let t = std::time::Instant::now();
        let side = (graph.len() as f64).sqrt() as usize;
        if let Some(rest) = order.strip_prefix("geo") {
            let (thick, leaf) = rest.split_once('-').unwrap();
            let perm = geometric(side, thick.parse().unwrap(), leaf.parse().unwrap());
            let c = factor_counts(&graph, &perm);
            println!(
                "geo counts nnz {:.4e} F {:.4e}",
                c.nonzeros, c.multiply_adds
            );
        }
        let perm = match order.strip_prefix("geo") {
            Some(rest) => {
                let (thick, leaf) = rest.split_once('-').unwrap();
                Some(geometric(
                    side,
                    thick.parse().unwrap(),
                    leaf.parse().unwrap(),
                ))
            }
            None => match order.strip_prefix("nd") {
                Some(leaf) => {
                    let (leaf, leaf_order) = match leaf.strip_prefix("amd") {
                        Some(l) => (l, LeafOrder::Amd),
                        None => (leaf, LeafOrder::Search),
                    };
                    Some(nested_dissection(
                        &graph,
                        Dissection {
                            leaf: leaf.parse().unwrap(),
                            leaf_order,
                            cut: Cut::Ratio,
                        },
                    ))
                }
                None => None,
            },
        };
        let mut solver = match &perm {
            Some(perm) => {
                DirectSolver::with_particle_ordering(&pattern, FactorStructure::Supernodal, perm)
            }
            None => DirectSolver::new(&pattern, FactorStructure::Supernodal),
        }
        .unwrap();
        let setup = t.elapsed().as_secs_f64() * 1e3;
        assert!(solver.factor_only(&pattern, &values));
        let cpu = || {
            std::fs::read_to_string("/proc/thread-self/schedstat")
                .ok()
                .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
                .map_or(0.0, |ns| ns * 1e-9)
        };
        let mut times = Vec::new();
        for _ in 0..reps {
            let t = cpu();
            assert!(solver.factor_only(&pattern, &values));
            times.push((cpu() - t) * 1e3);
        }
        times.sort_by(f64::total_cmp);
        println!(
            "{case} {order}: setup {setup:.2} ms, factor len {}, CPU per factorization median {:.2} ms (min {:.2})",
            solver.factor_len(),
            times.get(times.len() / 2).copied().unwrap_or(0.0),
            times.first().copied().unwrap_or(0.0)
        );
    }

    /// Nested dissection of a `side x side` grid (index `i side + j`) by straight cuts
    /// `thick` lines wide across the longer side, leaves of at most `leaf` particles in
    /// row order: the best separators a sheet has, for comparison.
    fn geometric(side: usize, thick: usize, leaf: usize) -> Vec<usize> {
        fn go(r: [usize; 4], side: usize, thick: usize, leaf: usize, out: &mut Vec<usize>) {
            let [i0, i1, j0, j1] = r;
            let (h, w) = (i1 - i0, j1 - j0);
            if h * w <= leaf || (h <= thick + 1 && w <= thick + 1) {
                for i in i0..i1 {
                    for j in j0..j1 {
                        out.push(i * side + j);
                    }
                }
                return;
            }
            if h >= w {
                let m = i0 + (h - thick) / 2;
                go([i0, m, j0, j1], side, thick, leaf, out);
                go([m + thick, i1, j0, j1], side, thick, leaf, out);
                go([m, m + thick, j0, j1], side, thick, usize::MAX, out);
            } else {
                let m = j0 + (w - thick) / 2;
                go([i0, i1, j0, m], side, thick, leaf, out);
                go([i0, i1, m + thick, j1], side, thick, leaf, out);
                go([i0, i1, m, m + thick], side, thick, usize::MAX, out);
            }
        }
        let mut out = Vec::new();
        go([0, side, 0, side], side, thick, leaf, &mut out);
        out
    }
}
