//! The numeric supernodal Cholesky factorization on faer's symbolic structure, with
//! independent subtrees of the elimination tree factored side by side.
//!
//! faer's own supernodal factorization visits the supernodes one after the other and
//! shares only each supernode's dense kernels between threads, which on cloth matrices
//! (supernodes of a few dozen columns) costs more than it saves (docs/contact.md,
//! "faer's own threads for the factorization"). Two supernodes in disjoint subtrees of
//! the supernodal elimination tree never read each other's columns, so the tree's lower
//! part splits into two groups of whole subtrees, one per thread, and the supernodes
//! above them (the top separators) follow in order, each taking its two groups'
//! updates side by side. docs/spring-sim.md, "The factorization's subtrees on two
//! threads", has the plan's cost model and the measurements.
//!
//! The algorithm is faer's left-looking one (each supernode gathers its matrix columns,
//! subtracts the updates of its descendants in ascending order, factors its diagonal
//! block and solves for the rows below it) with faer's dense kernels, and every
//! supernode does the same arithmetic whichever thread runs it and whether or not
//! another runs beside it: the factor is the same to the bit on one thread and on two.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{
    LltRegularization, cholesky_in_place, cholesky_in_place_scratch,
};
use faer::linalg::matmul::matmul;
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::linalg::triangular_solve::solve_lower_triangular_in_place;
use faer::sparse::SparseColMatRef;
use faer::sparse::linalg::cholesky::supernodal::SymbolicSupernodalCholesky;
use faer::{Accum, MatMut, MatRef, Par};

/// Updates at least this wide compute only the lower half of their square top.
const TRIANGULAR_FROM: usize = 16;

/// The most subtrees opened in search of a split (each candidate is timed in one
/// pass over the top supernodes' updates).
const MAX_OPENED: usize = 64;

/// Factorizations of less work (multiply-adds; about a tenth of a millisecond) stay on
/// one thread: handing half to another thread costs microseconds per hand-off.
const MIN_SPLIT_WORK: f64 = 1e6;

/// The group of a supernode outside both groups of a split.
const TOP: u8 = 2;

/// A marker for "no row" in the row map.
const NONE: usize = usize::MAX;

/// What the numeric factorization needs beyond faer's symbolic structure: which
/// descendants update each supernode, where, and how the tree splits between threads.
#[derive(Clone, Debug)]
pub(crate) struct TreePlan {
    /// `update_ptr[s]..update_ptr[s + 1]` indexes the updates of supernode `s`.
    update_ptr: Vec<usize>,
    /// The updating supernode `d` (ascending within each `s`) ...
    update_from: Vec<usize>,
    /// ... the position in `d`'s row pattern of its first row inside `s` ...
    update_at: Vec<usize>,
    /// ... and how many of `d`'s rows fall inside `s`.
    update_inside: Vec<usize>,
    /// Two groups of whole subtrees (supernode ranges, each contiguous in the
    /// factor's values) factored side by side, then the supernodes above them in
    /// ascending order; `None` when the tree does not split usefully.
    split: Option<Split>,
    /// Per supernode: in the split's first group (0), its second (1), or neither
    /// ([`TOP`]; every supernode when there is no split).
    group: Vec<u8>,
    /// The largest dense update (rows times columns) and diagonal block.
    max_update: usize,
    max_cols: usize,
}

#[derive(Clone, Debug)]
struct Split {
    /// Group `g` is whole subtrees whose supernodes lie in `groups[g].0..groups[g].1`
    /// (the range also holds the top supernodes between those subtrees, which the group
    /// skips; the two ranges are disjoint).
    groups: [(usize, usize); 2],
    /// The supernodes outside both groups, ascending: each an ancestor of some group's
    /// supernodes.
    top: Vec<usize>,
}

/// The supernodes' row patterns and column ranges, read from faer's symbolic factor.
struct Shape<'a> {
    symbolic: &'a SymbolicSupernodalCholesky<usize>,
}

impl Shape<'_> {
    fn len(&self) -> usize {
        self.symbolic.n_supernodes()
    }

    fn cols(&self, s: usize) -> (usize, usize) {
        (
            self.symbolic.supernode_begin()[s],
            self.symbolic.supernode_end()[s],
        )
    }

    fn pattern(&self, s: usize) -> &[usize] {
        self.symbolic.supernode(s).pattern()
    }

    fn values(&self, s: usize) -> (usize, usize) {
        let ptr = self.symbolic.col_ptr_for_val();
        (ptr[s], ptr[s + 1])
    }
}

impl TreePlan {
    /// The plan of `symbolic`'s factorization.
    pub(crate) fn new(symbolic: &SymbolicSupernodalCholesky<usize>) -> Self {
        let shape = Shape { symbolic };
        let ns = shape.len();
        let n = symbolic.nrows();
        let mut owner = vec![0usize; n];
        for s in 0..ns {
            let (a, b) = shape.cols(s);
            owner[a..b].fill(s);
        }
        // Each descendant `d` updates the supernodes its rows fall in, in row order;
        // costs in multiply-adds.
        let mut counts = vec![0usize; ns + 1];
        let mut own = Vec::with_capacity(ns);
        let mut max_update = 0;
        let mut max_cols = 0;
        for d in 0..ns {
            let (a, b) = shape.cols(d);
            let dn = b - a;
            max_cols = max_cols.max(dn);
            let pattern = shape.pattern(d);
            own.push((dn * dn * dn) as f64 / 6.0 + (dn * dn * pattern.len()) as f64 / 2.0);
            let mut k = 0;
            while k < pattern.len() {
                let s = owner[pattern[k]];
                let run = pattern[k..].partition_point(|&r| owner[r] == s);
                counts[s] += 1;
                max_update = max_update.max((pattern.len() - k) * run);
                k += run;
            }
        }
        let mut update_ptr = vec![0usize; ns + 1];
        for s in 0..ns {
            update_ptr[s + 1] = update_ptr[s] + counts[s];
        }
        let total = update_ptr[ns];
        let mut update_from = vec![0usize; total];
        let mut update_at = vec![0usize; total];
        let mut update_inside = vec![0usize; total];
        let mut update_cost = vec![0.0f64; total];
        let mut next = update_ptr.clone();
        for d in 0..ns {
            let (a, b) = shape.cols(d);
            let pattern = shape.pattern(d);
            let mut k = 0;
            while k < pattern.len() {
                let s = owner[pattern[k]];
                let run = pattern[k..].partition_point(|&r| owner[r] == s);
                update_from[next[s]] = d;
                update_at[next[s]] = k;
                update_inside[next[s]] = run;
                update_cost[next[s]] = ((pattern.len() - k) * run * (b - a)) as f64;
                next[s] += 1;
                k += run;
            }
        }
        let parent: Vec<Option<usize>> = (0..ns)
            .map(|s| shape.pattern(s).first().map(|&r| owner[r]))
            .collect();
        let costs = Costs {
            own: &own,
            update_ptr: &update_ptr,
            update_from: &update_from,
            update_cost: &update_cost,
        };
        let split = Split::choose(&parent, &costs);
        let mut group = vec![TOP; ns];
        if let Some(sp) = &split {
            for (g, &(s0, s1)) in sp.groups.iter().enumerate() {
                for (s, place) in group.iter_mut().enumerate().take(s1).skip(s0) {
                    if sp.top.binary_search(&s).is_err() {
                        *place = g as u8;
                    }
                }
            }
        }
        Self {
            update_ptr,
            update_from,
            update_at,
            update_inside,
            split,
            group,
            max_update,
            max_cols,
        }
    }

    /// Whether the plan factors two groups of subtrees side by side when it can.
    #[cfg(test)]
    pub(crate) fn splits(&self) -> bool {
        self.split.is_some()
    }
}

/// The work of a factorization by supernode, in multiply-adds: each supernode's own
/// (its diagonal block's factorization and the solve below it) and each update.
struct Costs<'a> {
    own: &'a [f64],
    update_ptr: &'a [usize],
    update_from: &'a [usize],
    update_cost: &'a [f64],
}

impl Costs<'_> {
    /// Supernode `s`'s work: its own and the updates it takes.
    fn of(&self, s: usize) -> f64 {
        self.own[s]
            + self.update_cost[self.update_ptr[s]..self.update_ptr[s + 1]]
                .iter()
                .sum::<f64>()
    }
}

impl Split {
    /// Two groups of whole subtrees, found by opening the costliest subtree of the
    /// frontier (its root goes to the top) and cutting the frontier, in index order,
    /// where its two sides' work is closest; each candidate is timed as the factorization
    /// runs it: the groups side by side, then each top supernode with its two groups'
    /// updates side by side and the rest after. The best candidate is kept if it takes
    /// at most 0.9 of the work on one thread; `None` otherwise, or when a subtree's
    /// supernodes are not contiguous (faer numbers them in postorder).
    fn choose(parent: &[Option<usize>], costs: &Costs<'_>) -> Option<Self> {
        let ns = parent.len();
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); ns];
        let mut roots = Vec::new();
        for (s, &up) in parent.iter().enumerate() {
            match up {
                Some(p) if p > s => children[p].push(s),
                Some(_) => return None,
                None => roots.push(s),
            }
        }
        // Subtree work and first supernode (postorder: a subtree is `first..=root`).
        let mut sub: Vec<f64> = (0..ns).map(|s| costs.of(s)).collect();
        let total: f64 = sub.iter().sum();
        let mut first: Vec<usize> = (0..ns).collect();
        let mut size = vec![1usize; ns];
        for s in 0..ns {
            if let Some(p) = parent[s] {
                sub[p] += sub[s];
                first[p] = first[p].min(first[s]);
                size[p] += size[s];
            }
        }
        if (0..ns).any(|s| s + 1 - first[s] != size[s]) {
            return None;
        }
        let mut frontier = roots;
        let mut top: Vec<usize> = Vec::new();
        let mut is_top = vec![false; ns];
        let mut best: Option<(f64, Self)> = None;
        for _ in 0..MAX_OPENED {
            frontier.sort_unstable();
            let sum: f64 = frontier.iter().map(|&r| sub[r]).sum();
            let mut prefix = 0.0;
            let mut cut = None;
            for c in 1..frontier.len() {
                prefix += sub[frontier[c - 1]];
                let worst = prefix.max(sum - prefix);
                if cut.is_none_or(|(w, _)| worst < w) {
                    cut = Some((worst, c));
                }
            }
            if let Some((worst, c)) = cut {
                let range = |rs: &[usize]| (first[rs[0]], rs[rs.len() - 1] + 1);
                let groups = [range(&frontier[..c]), range(&frontier[c..])];
                let in_a = |d: usize| groups[0].0 <= d && d < groups[0].1;
                let mut time = worst;
                for &s in &top {
                    let [mut a, mut b, mut rest] = [0.0; 3];
                    for u in costs.update_ptr[s]..costs.update_ptr[s + 1] {
                        let d = costs.update_from[u];
                        let w = costs.update_cost[u];
                        if is_top[d] {
                            rest += w;
                        } else if in_a(d) {
                            a += w;
                        } else {
                            b += w;
                        }
                    }
                    time += a.max(b) + rest + costs.own[s];
                }
                if best.as_ref().is_none_or(|(t, _)| time < *t) {
                    let mut sorted = top.clone();
                    sorted.sort_unstable();
                    best = Some((
                        time,
                        Self {
                            groups,
                            top: sorted,
                        },
                    ));
                }
            }
            // Open the costliest subtree that has children.
            let Some(k) = (0..frontier.len())
                .filter(|&k| !children[frontier[k]].is_empty())
                .max_by(|&a, &b| sub[frontier[a]].total_cmp(&sub[frontier[b]]))
            else {
                break;
            };
            let r = frontier.swap_remove(k);
            top.push(r);
            is_top[r] = true;
            frontier.extend(&children[r]);
        }
        best.filter(|(time, _)| total >= MIN_SPLIT_WORK && *time <= 0.9 * total)
            .map(|(_, split)| split)
    }
}

/// Scratch of one thread: the row map, the dense update, a supernode-sized buffer
/// for a top supernode's updates from the second group, and the diagonal block's
/// factorization.
pub(crate) struct Work {
    local: Vec<usize>,
    update: Vec<f64>,
    rows: Vec<usize>,
    gathered: Vec<f64>,
    chol: MemBuffer,
}

impl Work {
    /// The scratch of one thread for the factorizations of `plan` (`n` unknowns).
    pub(crate) fn new(n: usize, plan: &TreePlan) -> Self {
        Self {
            local: vec![NONE; n],
            update: vec![0.0; plan.max_update],
            rows: Vec::new(),
            gathered: Vec::new(),
            chol: MemBuffer::new(cholesky_in_place_scratch::<f64>(
                plan.max_cols,
                Par::Seq,
                Default::default(),
            )),
        }
    }
}

/// Runs `a` and `b`, side by side on the caller's pool when `parallel`.
fn both<A: Send, B: Send>(
    parallel: bool,
    a: impl FnOnce() -> A + Send,
    b: impl FnOnce() -> B + Send,
) -> (A, B) {
    #[cfg(feature = "parallel")]
    if parallel {
        return rayon::join(a, b);
    }
    let _ = parallel;
    (a(), b())
}

/// Factors `a` (the lower triangle of the permuted matrix, on `symbolic`'s structure)
/// into `l` (`symbolic.len_val()` values). Returns false when a pivot is not positive
/// (the matrix is not numerically positive definite); `l` is then unspecified. With
/// `parallel`, the plan's two groups run on the caller's rayon pool side by side; the
/// arithmetic, and so the factor, is the same either way.
pub(crate) fn factorize(
    symbolic: &SymbolicSupernodalCholesky<usize>,
    plan: &TreePlan,
    a: SparseColMatRef<'_, usize, f64>,
    l: &mut [f64],
    works: &mut [Work; 2],
    parallel: bool,
) -> bool {
    debug_assert!(works.iter().all(|w| w.local.len() == symbolic.nrows()));
    let shape = Shape { symbolic };
    l.fill(0.0);
    // The supernodes `s0..s1` of group `g` in order, each whole, into `values` (the
    // factor's values from offset `base`, holding them and their descendants).
    let run =
        |(s0, s1): (usize, usize), g: u8, base: usize, values: &mut [f64], work: &mut Work| {
            (s0..s1).filter(|&s| plan.group[s] == g).all(|s| {
                let (v0, v1) = shape.values(s);
                let (head, tail) = values.split_at_mut(v0 - base);
                let ls = &mut tail[..v1 - v0];
                prepare(&shape, s, work);
                assemble(&shape, a, s, ls, work);
                let updates = plan.update_ptr[s]..plan.update_ptr[s + 1];
                apply_updates(&shape, plan, updates, head, base, s, ls, work);
                finish(&shape, s, ls, work)
            })
        };
    let Some(split) = &plan.split else {
        return run((0, shape.len()), TOP, 0, l, &mut works[0]);
    };
    let [(a0, a1), (b0, b1)] = split.groups;
    let (va0, va1) = (shape.values(a0).0, shape.values(a1 - 1).1);
    let (vb0, vb1) = (shape.values(b0).0, shape.values(b1 - 1).1);
    {
        let (low, rest) = l.split_at_mut(vb0);
        let group_a = &mut low[va0..va1];
        let group_b = &mut rest[..vb1 - vb0];
        let [work_a, work_b] = works;
        let (ok_a, ok_b) = both(
            parallel,
            || run((a0, a1), 0, va0, group_a, work_a),
            || run((b0, b1), 1, vb0, group_b, work_b),
        );
        if !(ok_a && ok_b) {
            return false;
        }
    }

    // A top supernode takes its first group's updates in its own columns and its second
    // group's in a buffer, side by side, then subtracts the buffer and the top
    // descendants' updates.
    split.top.iter().all(|&s| {
        let (v0, v1) = shape.values(s);
        let (head, tail) = l.split_at_mut(v0);
        let head = &*head;
        let ls = &mut tail[..v1 - v0];
        let range = plan.update_ptr[s]..plan.update_ptr[s + 1];
        let of = |g: u8| {
            range
                .clone()
                .filter(move |&u| plan.group[plan.update_from[u]] == g)
        };
        let [work_a, work_b] = &mut *works;
        let len = ls.len();
        both(
            parallel,
            || {
                prepare(&shape, s, work_a);
                assemble(&shape, a, s, ls, work_a);
                apply_updates(&shape, plan, of(0), head, 0, s, ls, work_a);
            },
            || {
                prepare(&shape, s, work_b);
                let mut gathered = std::mem::take(&mut work_b.gathered);
                gathered.clear();
                gathered.resize(len, 0.0);
                apply_updates(&shape, plan, of(1), head, 0, s, &mut gathered, work_b);
                work_b.gathered = gathered;
                reset(&shape, s, work_b);
            },
        );
        for (v, g) in ls.iter_mut().zip(&works[1].gathered) {
            *v += g;
        }
        apply_updates(&shape, plan, of(TOP), head, 0, s, ls, &mut works[0]);
        finish(&shape, s, ls, &mut works[0])
    })
}

/// Maps the rows of supernode `s` (its columns, then its pattern) to their places in
/// its dense block.
fn prepare(shape: &Shape<'_>, s: usize, work: &mut Work) {
    let (s0, s1) = shape.cols(s);
    let sn = s1 - s0;
    for c in 0..sn {
        work.local[s0 + c] = c;
    }
    for (i, &r) in shape.pattern(s).iter().enumerate() {
        work.local[r] = sn + i;
    }
}

/// Clears the row map of supernode `s`.
fn reset(shape: &Shape<'_>, s: usize, work: &mut Work) {
    let (s0, s1) = shape.cols(s);
    work.local[s0..s1].fill(NONE);
    for &r in shape.pattern(s) {
        work.local[r] = NONE;
    }
}

/// Adds the matrix's columns of supernode `s` (lower triangle) into its block `ls`.
fn assemble(
    shape: &Shape<'_>,
    a: SparseColMatRef<'_, usize, f64>,
    s: usize,
    ls: &mut [f64],
    work: &Work,
) {
    let (s0, s1) = shape.cols(s);
    let rows = s1 - s0 + shape.pattern(s).len();
    for j in s0..s1 {
        let col = &mut ls[(j - s0) * rows..][..rows];
        for (&i, &v) in a.row_idx_of_col_raw(j).iter().zip(a.val_of_col(j)) {
            if i >= j {
                col[work.local[i]] += v;
            }
        }
    }
}

/// Subtracts from `target` (a block shaped as supernode `s`'s) the updates `updates`
/// (indices into the plan's lists of `s`, in ascending order of the descendant), the
/// descendants' factor values read from `head` (the factor's values from offset `base`).
#[allow(clippy::too_many_arguments)]
fn apply_updates(
    shape: &Shape<'_>,
    plan: &TreePlan,
    updates: impl Iterator<Item = usize>,
    head: &[f64],
    base: usize,
    s: usize,
    target: &mut [f64],
    work: &mut Work,
) {
    let (s0, s1) = shape.cols(s);
    let rows = s1 - s0 + shape.pattern(s).len();
    for u in updates {
        let d = plan.update_from[u];
        let at = plan.update_at[u];
        let (d0, d1) = shape.cols(d);
        let dn = d1 - d0;
        let dpat = shape.pattern(d);
        let drows = dn + dpat.len();
        let inside = plan.update_inside[u];
        let m = dpat.len() - at;
        let (w0, w1) = shape.values(d);
        let ld = MatRef::from_column_major_slice(&head[w0 - base..w1 - base], drows, dn);
        let below = ld.subrows(dn + at, m);
        let mid = ld.subrows(dn + at, inside);
        let mut upd =
            MatMut::from_column_major_slice_mut(&mut work.update[..m * inside], m, inside);
        if inside >= TRIANGULAR_FROM {
            // The update's square top is symmetric: only its lower half is computed.
            let (upd_top, upd_bottom) = upd.as_mut().split_at_row_mut(inside);
            triangular::matmul(
                upd_top,
                BlockStructure::TriangularLower,
                Accum::Replace,
                mid,
                BlockStructure::Rectangular,
                mid.transpose(),
                BlockStructure::Rectangular,
                1.0,
                Par::Seq,
            );
            matmul(
                upd_bottom,
                Accum::Replace,
                below.subrows(inside, m - inside),
                mid.transpose(),
                1.0,
                Par::Seq,
            );
        } else {
            matmul(
                upd.as_mut(),
                Accum::Replace,
                below,
                mid.transpose(),
                1.0,
                Par::Seq,
            );
        }
        work.rows.clear();
        work.rows.extend(dpat[at..].iter().map(|&r| work.local[r]));
        for j in 0..inside {
            let c = work.rows[j];
            let col = &mut target[c * rows..][..rows];
            let src = &work.update[j * m..][..m];
            for i in j..m {
                col[work.rows[i]] -= src[i];
            }
        }
    }
}

/// Factors supernode `s`'s diagonal block and solves for the rows below it, then clears
/// its row map. False on a non-positive pivot.
fn finish(shape: &Shape<'_>, s: usize, ls: &mut [f64], work: &mut Work) -> bool {
    let (s0, s1) = shape.cols(s);
    let sn = s1 - s0;
    let rows = sn + shape.pattern(s).len();
    let mut lmat = MatMut::from_column_major_slice_mut(ls, rows, sn);
    let (mut top, mut bottom) = lmat.as_mut().split_at_row_mut(sn);
    let factored = cholesky_in_place(
        top.as_mut(),
        LltRegularization::default(),
        Par::Seq,
        MemStack::new(&mut work.chol),
        Default::default(),
    )
    .is_ok();
    if factored {
        solve_lower_triangular_in_place(
            top.as_ref().conjugate(),
            bottom.as_mut().transpose_mut(),
            Par::Seq,
        );
    }
    reset(shape, s, work);
    factored
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linear::{DirectSolver, FactorStructure};
    use crate::model::{ClothGrid, SpringSystem};
    use crate::newton::newton_matrix_triplets;
    use crate::pattern::HessianPattern;
    use faer::linalg::cholesky::llt::factor::LltRegularization;
    use faer::sparse::linalg::cholesky::{SymbolicCholeskyRaw, supernodal};

    /// The Newton matrix of a stretched free `n x n` lab-pattern sheet, on a pattern
    /// widened by `pairs`, each pair given a spring-like block `c (I, -I; -I, I)` so the
    /// matrix stays positive definite: its pattern and values.
    fn matrix(n: usize, pairs: &[[usize; 2]]) -> (HessianPattern, Vec<f64>) {
        let grid = ClothGrid {
            fixed: Vec::new(),
            ..ClothGrid::lab_sized(n, 2.0 / (n as f64 - 1.0))
        };
        let mut system = SpringSystem::cloth(&grid.with_damping(0.2)).unwrap();
        let x: Vec<_> = system.positions().iter().map(|p| *p * 1.2).collect();
        let v = vec![sinew_math::DVec3::ZERO; x.len()];
        system.set_state(&x, &v).unwrap();
        let pattern = HessianPattern::with_pairs(&system, pairs);
        let (col_ptr, row_idx) = (pattern.symbolic.col_ptr(), pattern.symbolic.row_idx());
        let slot = |i: usize, j: usize| {
            let (i, j) = (i.max(j), i.min(j));
            (col_ptr[j]..col_ptr[j + 1])
                .find(|&k| row_idx[k] == i)
                .unwrap()
        };
        let mut values = vec![0.0; pattern.nnz()];
        for (i, j, value) in newton_matrix_triplets(&system, 1.0 / 60.0) {
            values[slot(i, j)] += value;
        }
        for &[p, q] in pairs {
            for k in 0..3 {
                values[slot(3 * p + k, 3 * p + k)] += 50.0;
                values[slot(3 * q + k, 3 * q + k)] += 50.0;
                values[slot(3 * p + k, 3 * q + k)] -= 50.0;
            }
        }
        (pattern, values)
    }

    /// Pairs between particles far apart in the sheet (as a folded cloth's contacts are).
    fn far_pairs(n: usize) -> Vec<[usize; 2]> {
        (0..n * n / 4)
            .map(|i| [4 * i % (n * n), (4 * i * 7919 + 3) % (n * n)])
            .filter(|[p, q]| p != q)
            .collect()
    }

    /// faer's supernodal factor of `values` on `solver`'s structure, and this module's on
    /// one thread and on a pool of two.
    fn factors(solver: &mut DirectSolver, values: &[f64]) -> [Option<Vec<f64>>; 3] {
        let permuted = solver.permuted.as_mut().expect("a supernodal structure");
        for (v, &k) in permuted.values.iter_mut().zip(&permuted.slots) {
            *v = values[k];
        }
        let SymbolicCholeskyRaw::Supernodal(symbolic) = solver.symbolic.raw() else {
            unreachable!("the structure is supernodal");
        };
        let a = SparseColMatRef::new(permuted.symbolic.as_ref(), &permuted.values);
        let mut faer_l = vec![0.0; symbolic.len_val()];
        let faer_ok = supernodal::factorize_supernodal_numeric_llt(
            &mut faer_l,
            a,
            LltRegularization::default(),
            symbolic,
            Par::Seq,
            MemStack::new(&mut MemBuffer::new(
                solver
                    .symbolic
                    .factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
            )),
            Default::default(),
        )
        .is_ok();
        let mut run = |parallel: bool| {
            let mut l = vec![0.0; symbolic.len_val()];
            factorize(
                symbolic,
                &permuted.plan,
                a,
                &mut l,
                &mut permuted.works,
                parallel,
            )
            .then_some(l)
        };
        let one = run(false);
        #[cfg(feature = "parallel")]
        let two = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap()
            .install(|| run(true));
        #[cfg(not(feature = "parallel"))]
        let two = run(true);
        [faer_ok.then_some(faer_l), one, two]
    }

    fn largest(values: &[f64]) -> f64 {
        values.iter().fold(0.0, |m, v| m.max(v.abs()))
    }

    /// On a sheet's matrix and on one widened by far pairs, the plan splits, the factor
    /// is faer's to round-off, and it is the same to the bit on one thread and on two.
    #[test]
    fn the_factor_is_faers_to_round_off_and_the_same_bits_on_one_and_two_threads() {
        for (n, pairs) in [(31, Vec::new()), (24, far_pairs(24))] {
            let (pattern, values) = matrix(n, &pairs);
            let mut solver = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
            assert!(solver.permuted.as_ref().unwrap().plan.splits(), "{n}");
            let [faer_l, one, two] = factors(&mut solver, &values);
            let (faer_l, one, two) = (faer_l.unwrap(), one.unwrap(), two.unwrap());
            let scale = largest(&faer_l);
            let diff = faer_l
                .iter()
                .zip(&one)
                .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
            assert!(diff <= 1e-13 * scale, "{n}: {diff:e} of {scale:e}");
            assert!(
                one.iter()
                    .zip(&two)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{n}: one and two threads differ"
            );
        }
    }

    /// A matrix with a negative pivot in either group or in the top is refused on one
    /// thread and on two, as faer refuses it; the good matrix factored after it gives the
    /// same bits as before (no scratch state is left behind by a failure).
    #[test]
    fn a_matrix_that_is_not_positive_definite_is_refused_and_leaves_nothing_behind() {
        let (pattern, values) = matrix(31, &[]);
        let mut solver = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
        let good = factors(&mut solver, &values)[1].clone().unwrap();
        let (plan, begins) = {
            let SymbolicCholeskyRaw::Supernodal(symbolic) = solver.symbolic.raw() else {
                unreachable!()
            };
            let plan = solver.permuted.as_ref().unwrap().plan.clone();
            (plan, symbolic.supernode_begin().to_vec())
        };
        let perm = solver.symbolic.perm().unwrap().arrays().0.to_vec();
        // One column in each place: the first group, the second and the top.
        for g in [0, 1, TOP] {
            let s = (0..plan.group.len()).find(|&s| plan.group[s] == g).unwrap();
            let column = perm[begins[s]];
            let mut bad = values.clone();
            let diagonal = pattern.symbolic.col_ptr()[column];
            assert_eq!(pattern.symbolic.row_idx()[diagonal], column);
            bad[diagonal] = -1e6;
            let [faer_l, one, two] = factors(&mut solver, &bad);
            assert!(
                faer_l.is_none() && one.is_none() && two.is_none(),
                "group {g}"
            );
            let [_, one, two] = factors(&mut solver, &values);
            for l in [one.unwrap(), two.unwrap()] {
                assert!(l.iter().zip(&good).all(|(a, b)| a.to_bits() == b.to_bits()));
            }
        }
    }

    /// The groups are whole subtrees: a grouped supernode's parent is in its group or in
    /// the top, a top supernode's parent in the top, every update comes from a
    /// descendant of the same group (or any supernode, for a top one), and the groups'
    /// supernode ranges are disjoint.
    #[test]
    fn the_split_takes_whole_subtrees() {
        for (n, pairs) in [(31, Vec::new()), (24, far_pairs(24)), (45, Vec::new())] {
            let (pattern, _) = matrix(n, &pairs);
            let solver = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
            let SymbolicCholeskyRaw::Supernodal(symbolic) = solver.symbolic.raw() else {
                unreachable!()
            };
            let plan = &solver.permuted.as_ref().unwrap().plan;
            let split = plan.split.as_ref().unwrap();
            let [(a0, a1), (b0, b1)] = split.groups;
            assert!(a0 < a1 && a1 <= b0 && b0 < b1, "{:?}", split.groups);
            assert!(split.top.windows(2).all(|w| w[0] < w[1]));
            let ns = symbolic.n_supernodes();
            let owner = |row: usize| symbolic.supernode_end().partition_point(|&e| e <= row);
            for s in 0..ns {
                let parent = symbolic.supernode(s).pattern().first().map(|&r| owner(r));
                let g = plan.group[s];
                assert_eq!(g == TOP, split.top.binary_search(&s).is_ok(), "{s}");
                if let Some(p) = parent {
                    assert!(plan.group[p] == g || plan.group[p] == TOP, "{s} -> {p}");
                    if g == TOP {
                        assert_eq!(plan.group[p], TOP, "{s} -> {p}");
                    }
                }
                for u in plan.update_ptr[s]..plan.update_ptr[s + 1] {
                    let d = plan.update_from[u];
                    assert!(d < s);
                    assert!(g == TOP || plan.group[d] == g, "{d} -> {s}");
                }
            }
        }
    }

    /// A small matrix is not worth a second thread: no split, and faer's factor.
    #[test]
    fn a_small_matrix_stays_on_one_thread() {
        let (pattern, values) = matrix(6, &[]);
        let mut solver = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
        assert!(!solver.permuted.as_ref().unwrap().plan.splits());
        let [faer_l, one, two] = factors(&mut solver, &values);
        let (faer_l, one, two) = (faer_l.unwrap(), one.unwrap(), two.unwrap());
        let scale = largest(&faer_l);
        assert!(
            faer_l
                .iter()
                .zip(&one)
                .all(|(a, b)| (a - b).abs() <= 1e-13 * scale)
        );
        assert!(
            one.iter()
                .zip(&two)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
    }
}
