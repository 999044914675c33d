//! The numeric supernodal Cholesky factorization on faer's symbolic structure, with
//! independent subtrees of the elimination tree factored side by side.
//!
//! faer's own supernodal factorization visits the supernodes one after the other and
//! shares only each supernode's dense kernels between threads, which on cloth matrices
//! (supernodes of a few dozen columns) costs more than it saves (docs/bench/contact.md,
//! "faer's own threads for the factorization"). Two supernodes in disjoint subtrees of
//! the supernodal elimination tree never read each other's columns, so the tree's lower
//! part splits into two groups of whole subtrees, one per thread, and each thread then
//! subtracts its group's updates of the supernodes above them (the top separators),
//! into the top supernode where its slice of the factor holds it and into a buffer
//! where the other's does. The top supernodes follow in order, each by panels of its
//! columns that the two threads claim in turn. docs/spring-sim.md, "The factorization's
//! subtrees on two threads", has the plan's cost model and the measurements.
//!
//! The algorithm is faer's left-looking one (each supernode gathers its matrix columns,
//! subtracts the updates of its descendants in ascending order, factors its diagonal
//! block and solves for the rows below it) with faer's dense kernels, and every
//! supernode (every panel of a top one) does the same arithmetic whichever thread runs
//! it and whether or not another runs beside it: the factor is the same to the bit on
//! one thread and on two.
//!
//! The triangular solves with the factor ([`solve`]) split the same way: forward, the two
//! groups side by side and then the top; backward, the top and then the two groups.

use crate::pool::join_if;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{
    LltRegularization, cholesky_in_place, cholesky_in_place_scratch,
};
use faer::linalg::matmul::matmul;
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::sparse::SparseColMatRef;
use faer::sparse::linalg::cholesky::supernodal::SymbolicSupernodalCholesky;
use faer::{Accum, MatMut, MatRef, Par};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, OnceLock};

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

/// The columns of a top supernode's panel (the two threads' unit of its work).
const PANEL: usize = 64;

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
    /// Per top supernode, the thread whose slice of the factor holds its values (1 when
    /// they lie in the second group's range, between its subtrees, else 0: they follow
    /// the first group's); it assembles the supernode there, and the other thread
    /// subtracts its updates into its buffer ...
    held_by: Vec<u8>,
    /// ... from this place ...
    at: Vec<usize>,
    /// ... whose length, per thread, is the values of the top supernodes it does not hold.
    buffer: [usize; 2],
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

    fn width(&self, s: usize) -> usize {
        let (a, b) = self.cols(s);
        b - a
    }

    fn pattern(&self, s: usize) -> &[usize] {
        self.symbolic.supernode(s).pattern()
    }

    /// The rows of supernode `s`'s block of the factor: its diagonal block's, then the
    /// rows below it.
    fn rows(&self, s: usize) -> usize {
        self.width(s) + self.pattern(s).len()
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
        Self {
            update_ptr,
            update_from,
            update_at,
            update_inside,
            split: None,
            group: vec![TOP; ns],
            max_update,
            max_cols,
        }
        .with_split(symbolic, split)
    }

    /// The plan with `split` (groups and top supernodes chosen by [`Split::choose`] or
    /// by a test): each supernode's group, and which thread holds each top supernode
    /// and where the other buffers its updates.
    fn with_split(
        mut self,
        symbolic: &SymbolicSupernodalCholesky<usize>,
        mut split: Option<Split>,
    ) -> Self {
        let shape = Shape { symbolic };
        self.group.fill(TOP);
        if let Some(split) = &mut split {
            let [_, (b0, b1)] = split.groups;
            let second = shape.values(b0).0..shape.values(b1 - 1).1;
            split.held_by.clear();
            split.at.clear();
            split.buffer = [0; 2];
            for &s in &split.top {
                let (v0, v1) = shape.values(s);
                let holder = u8::from(second.contains(&v0));
                let other = usize::from(1 - holder);
                split.held_by.push(holder);
                split.at.push(split.buffer[other]);
                split.buffer[other] += v1 - v0;
            }
            for (g, &(s0, s1)) in split.groups.iter().enumerate() {
                for s in s0..s1 {
                    if split.top.binary_search(&s).is_err() {
                        self.group[s] = g as u8;
                    }
                }
            }
        }
        self.split = split;
        self
    }

    /// Whether the plan factors two groups of subtrees side by side when it can.
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
    /// where its two sides' work is closest, a side's work being its subtrees' and
    /// their updates of the top supernodes (its thread does both); each candidate is
    /// timed as the larger side plus the top supernodes' own work and their updates
    /// from each other, counted as on one thread (their panels share it between the
    /// threads, which the count leaves out). The best candidate is kept if it takes at
    /// most 0.9 of the work on one thread; `None` otherwise, or when a subtree's
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
            if frontier.len() >= 2 {
                // Each group's thread also takes its supernodes' updates into the top
                // ones, so a frontier subtree weighs its own work and those updates.
                let mut weight: Vec<f64> = frontier.iter().map(|&r| sub[r]).collect();
                let mut serial = 0.0;
                for &s in &top {
                    for u in costs.update_ptr[s]..costs.update_ptr[s + 1] {
                        let d = costs.update_from[u];
                        let w = costs.update_cost[u];
                        if is_top[d] {
                            serial += w;
                        } else {
                            let k = frontier.partition_point(|&r| r < d);
                            weight[k] += w;
                        }
                    }
                    serial += costs.own[s];
                }
                let sum: f64 = weight.iter().sum();
                let mut prefix = 0.0;
                let mut cut = (f64::INFINITY, 0);
                for c in 1..frontier.len() {
                    prefix += weight[c - 1];
                    let worst = prefix.max(sum - prefix);
                    if worst < cut.0 {
                        cut = (worst, c);
                    }
                }
                let (worst, c) = cut;
                let time = worst + serial;
                if best.as_ref().is_none_or(|(t, _)| time < *t) {
                    let range = |rs: &[usize]| (first[rs[0]], rs[rs.len() - 1] + 1);
                    let mut sorted = top.clone();
                    sorted.sort_unstable();
                    best = Some((
                        time,
                        Self {
                            groups: [range(&frontier[..c]), range(&frontier[c..])],
                            top: sorted,
                            held_by: Vec::new(),
                            at: Vec::new(),
                            buffer: [0; 2],
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

/// Scratch of one thread: for the factorization the row map, the dense update, a
/// buffer for its group's updates of the top supernodes held by the other thread, and
/// the diagonal block's factorization; for the triangular solves the vectors below.
pub(crate) struct Work {
    local: Vec<usize>,
    update: Vec<f64>,
    rows: Vec<usize>,
    buffer: Vec<f64>,
    /// The solve's subtractions from rows outside the thread's group (zero between
    /// solves) ...
    gathered: Vec<f64>,
    /// ... a supernode's products with its rows below its diagonal block ...
    below: Vec<f64>,
    /// ... and the first thread's copy of the solution for the backward solve.
    copy: Vec<f64>,
    chol: MemBuffer,
}

impl Work {
    /// The scratch of thread `thread` (0 or 1) for the factorizations of `plan` (`n`
    /// unknowns).
    pub(crate) fn new(n: usize, plan: &TreePlan, thread: usize) -> Self {
        Self {
            local: vec![NONE; n],
            update: vec![0.0; plan.max_update],
            rows: Vec::new(),
            buffer: vec![0.0; plan.split.as_ref().map_or(0, |split| split.buffer[thread])],
            gathered: Vec::new(),
            below: Vec::new(),
            copy: Vec::new(),
            chol: MemBuffer::new(cholesky_in_place_scratch::<f64>(
                plan.max_cols,
                Par::Seq,
                Default::default(),
            )),
        }
    }
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
    // Set by the first group to meet a non-positive pivot: the other group stops at its
    // next supernode instead of factoring the rest of its subtrees for nothing (under
    // contact, about one factorization in five to nine is refused: the softened Newton
    // matrix tries the springs' exact curvature first). Whether the factorization is
    // refused does not depend on when the other group stops.
    let refused = AtomicBool::new(false);
    // The supernodes `s0..s1` of group `g` in order, each whole, into `values` (the
    // factor's values from offset `base`, holding them and their descendants).
    let run =
        |(s0, s1): (usize, usize), g: u8, base: usize, values: &mut [f64], work: &mut Work| {
            (s0..s1).filter(|&s| plan.group[s] == g).all(|s| {
                if refused.load(Ordering::Relaxed) {
                    return false;
                }
                let (v0, v1) = shape.values(s);
                let (head, tail) = values.split_at_mut(v0 - base);
                let ls = &mut tail[..v1 - v0];
                prepare(&shape, s, work);
                assemble(&shape, a, s, ls, work);
                let updates = plan.update_ptr[s]..plan.update_ptr[s + 1];
                apply_updates(
                    &shape,
                    plan,
                    updates,
                    head,
                    base,
                    s,
                    (0, shape.width(s)),
                    ls,
                    work,
                );
                let factored = finish(&shape, s, ls, work);
                if !factored {
                    refused.store(true, Ordering::Relaxed);
                }
                factored
            })
        };
    let Some(split) = &plan.split else {
        return run((0, shape.len()), TOP, 0, l, &mut works[0]);
    };
    let [(a0, a1), (b0, b1)] = split.groups;
    let (va0, va1) = (shape.values(a0).0, shape.values(a1 - 1).1);
    let (vb0, vb1) = (shape.values(b0).0, shape.values(b1 - 1).1);
    // The thread whose slice holds a top supernode assembles it and subtracts its
    // group's updates there, the other subtracts its group's into its buffer.
    let tops = || split.top.iter().zip(&split.held_by).zip(&split.at);
    {
        let (front, rest) = l.split_at_mut(vb0);
        let (mid, back) = rest.split_at_mut(vb1 - vb0);
        let [work_a, work_b] = works;
        let (ok_a, ok_b) = join_if(
            parallel,
            || {
                run((a0, a1), 0, va0, &mut front[va0..va1], work_a) && {
                    let mut buffer = std::mem::take(&mut work_a.buffer);
                    for ((&s, &holder), &at) in tops() {
                        let (v0, v1) = shape.values(s);
                        let (head, target) = if holder == 1 {
                            (&*front, Target::Buffer(&mut buffer[at..][..v1 - v0]))
                        } else if v0 < vb0 {
                            let (head, tail) = front.split_at_mut(v0);
                            (&*head, Target::Own(&mut tail[..v1 - v0]))
                        } else {
                            (&*front, Target::Own(&mut back[v0 - vb1..v1 - vb1]))
                        };
                        take_updates(&shape, plan, a, s, 0, head, 0, target, work_a);
                    }
                    work_a.buffer = buffer;
                    true
                }
            },
            || {
                run((b0, b1), 1, vb0, mid, work_b) && {
                    let mut buffer = std::mem::take(&mut work_b.buffer);
                    for ((&s, &holder), &at) in tops() {
                        let (v0, v1) = shape.values(s);
                        let (head, target) = if holder == 1 {
                            let (head, tail) = mid.split_at_mut(v0 - vb0);
                            (&*head, Target::Own(&mut tail[..v1 - v0]))
                        } else {
                            (&*mid, Target::Buffer(&mut buffer[at..][..v1 - v0]))
                        };
                        take_updates(&shape, plan, a, s, 1, head, vb0, target, work_b);
                    }
                    work_b.buffer = buffer;
                    true
                }
            },
        );
        if !(ok_a && ok_b) {
            return false;
        }
    }

    // Then each top supernode in order, by panels of its columns.
    tops().all(|((&s, &holder), &at)| {
        let (v0, v1) = shape.values(s);
        let (head, tail) = l.split_at_mut(v0);
        let other = usize::from(1 - holder);
        let buffer = std::mem::take(&mut works[other].buffer);
        let buffer_s = &buffer[at..][..v1 - v0];
        let factored = top_by_panels(
            &shape,
            plan,
            s,
            head,
            &mut tail[..v1 - v0],
            buffer_s,
            works,
            parallel,
        );
        works[other].buffer = buffer;
        factored
    })
}

/// Finishes top supernode `s` (the group updates already in `ls` and in `buffer`, the
/// other thread's) by panels of [`PANEL`] columns, which the two threads take in order
/// from a shared iterator: a panel adds its columns of `buffer`, subtracts the top
/// descendants' updates of its columns (their values in `head`, the factor's values
/// before `s`'s) and then each earlier panel's, waiting for that panel to be factored,
/// and factors itself (its diagonal block and the rows below). Every panel does the same arithmetic whichever
/// thread claims it, so the factor is the same on one thread and on two; a thread
/// waits only for panels claimed before its own, each held by a running thread that
/// waits only for earlier ones, so no wait is for work that is not under way (and one
/// thread alone claims every panel in order). False on a non-positive pivot.
#[allow(clippy::too_many_arguments)]
fn top_by_panels(
    shape: &Shape<'_>,
    plan: &TreePlan,
    s: usize,
    head: &[f64],
    ls: &mut [f64],
    buffer: &[f64],
    works: &mut [Work; 2],
    parallel: bool,
) -> bool {
    let (s0, s1) = shape.cols(s);
    let sn = s1 - s0;
    let rows = shape.rows(s);
    // The panels in order, each handed out once; a claimed panel is published here once
    // factored, for the later panels to read.
    let unclaimed = Mutex::new(ls.chunks_mut(PANEL * rows).enumerate());
    let factored: Vec<OnceLock<&[f64]>> =
        (0..sn.div_ceil(PANEL)).map(|_| OnceLock::new()).collect();
    let failed = AtomicBool::new(false);
    let updates = plan.update_ptr[s]..plan.update_ptr[s + 1];
    let worker = |work: &mut Work| {
        prepare(shape, s, work);
        while !failed.load(Ordering::Acquire) {
            let claimed = unclaimed
                .lock()
                .unwrap_or_else(|poisoned| poisoned.into_inner())
                .next();
            let Some((p, panel)) = claimed else { break };
            let c0 = p * PANEL;
            let w = panel.len() / rows;
            for c in 0..w {
                let (col, from) = (&mut panel[c * rows..][..rows], (c0 + c) * rows);
                for (v, b) in col[c0 + c..]
                    .iter_mut()
                    .zip(&buffer[from + c0 + c..from + rows])
                {
                    *v += b;
                }
            }
            let top = updates
                .clone()
                .filter(|&u| plan.group[plan.update_from[u]] == TOP);
            apply_updates(shape, plan, top, head, 0, s, (c0, w), panel, work);
            let mut ok = true;
            for earlier in &factored[..p] {
                let Some(src) = wait_for(earlier, &failed) else {
                    ok = false;
                    break;
                };
                let src = MatRef::from_column_major_slice(src, rows, src.len() / rows);
                let target = MatMut::from_column_major_slice_mut(panel, rows, w);
                subtract_outer(
                    target.subrows_mut(c0, rows - c0),
                    src.subrows(c0, rows - c0),
                );
            }
            if ok {
                let block = MatMut::from_column_major_slice_mut(panel, rows, w);
                ok = factor_block(block.subrows_mut(c0, rows - c0), work);
            }
            if !ok {
                failed.store(true, Ordering::Release);
                break;
            }
            let _ = factored[p].set(panel);
        }
        reset(shape, s, work);
    };
    let [work_a, work_b] = works;
    join_if(parallel, || worker(work_a), || worker(work_b));
    !failed.load(Ordering::Acquire)
}

/// `block` (a supernode's or a panel's columns: the diagonal block on top, then the rows
/// below) factored in place: false on a non-positive pivot.
fn factor_block(block: MatMut<'_, f64>, work: &mut Work) -> bool {
    let w = block.ncols();
    let (mut top, mut bottom) = block.split_at_row_mut(w);
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
    factored
}

/// The value `slot` gets, waiting for it; `None` once `failed` is set instead.
fn wait_for<'a>(slot: &OnceLock<&'a [f64]>, failed: &AtomicBool) -> Option<&'a [f64]> {
    let mut spins = 0u32;
    loop {
        if let Some(&values) = slot.get() {
            return Some(values);
        }
        if failed.load(Ordering::Acquire) {
            return None;
        }
        if spins < 1 << 12 {
            spins += 1;
            std::hint::spin_loop();
        } else {
            std::thread::yield_now();
        }
    }
}

/// `target` (its top square and the rows below) minus the lower part of `p` times the
/// transpose of `p`'s top rows (as many as `target` has columns).
fn subtract_outer(target: MatMut<'_, f64>, p: MatRef<'_, f64>) {
    let width = target.ncols();
    let (top, bottom) = target.split_at_row_mut(width);
    let q = p.subrows(0, width);
    triangular::matmul(
        top,
        BlockStructure::TriangularLower,
        Accum::Add,
        q,
        BlockStructure::Rectangular,
        q.transpose(),
        BlockStructure::Rectangular,
        -1.0,
        Par::Seq,
    );
    matmul(
        bottom,
        Accum::Add,
        p.subrows(width, p.nrows() - width),
        q.transpose(),
        -1.0,
        Par::Seq,
    );
}

/// Where a group's thread puts its updates of a top supernode.
enum Target<'a> {
    /// The supernode's own values, its matrix columns assembled there first.
    Own(&'a mut [f64]),
    /// The thread's buffer for it, cleared first.
    Buffer(&'a mut [f64]),
}

/// Subtracts group `g`'s updates of top supernode `s` (its descendants' factor values
/// read from `head`, the factor's values from offset `base`) into `target`.
#[allow(clippy::too_many_arguments)]
fn take_updates(
    shape: &Shape<'_>,
    plan: &TreePlan,
    a: SparseColMatRef<'_, usize, f64>,
    s: usize,
    g: u8,
    head: &[f64],
    base: usize,
    target: Target<'_>,
    work: &mut Work,
) {
    prepare(shape, s, work);
    let ls = match target {
        Target::Own(ls) => {
            assemble(shape, a, s, ls, work);
            ls
        }
        Target::Buffer(buffer) => {
            let (s0, s1) = shape.cols(s);
            let rows = shape.rows(s);
            for_lower(s1 - s0, rows, |k| buffer[k] = 0.0);
            buffer
        }
    };
    let updates = plan.update_ptr[s]..plan.update_ptr[s + 1];
    let of_g = updates.filter(|&u| plan.group[plan.update_from[u]] == g);
    apply_updates(
        shape,
        plan,
        of_g,
        head,
        base,
        s,
        (0, shape.width(s)),
        ls,
        work,
    );
    reset(shape, s, work);
}

/// Calls `f` with the index of every value on or below the diagonal of a column-major
/// block of `cols` columns and `rows` rows (the part updates write).
fn for_lower(cols: usize, rows: usize, mut f: impl FnMut(usize)) {
    for c in 0..cols {
        for k in c * rows + c..(c + 1) * rows {
            f(k);
        }
    }
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

/// Writes the matrix's columns of supernode `s` (lower triangle) into its block `ls`,
/// zeros elsewhere (by the thread that factors it: the block is in its cache after).
fn assemble(
    shape: &Shape<'_>,
    a: SparseColMatRef<'_, usize, f64>,
    s: usize,
    ls: &mut [f64],
    work: &Work,
) {
    let (s0, s1) = shape.cols(s);
    let rows = shape.rows(s);
    ls.fill(0.0);
    for j in s0..s1 {
        let col = &mut ls[(j - s0) * rows..][..rows];
        for (&i, &v) in a.row_idx_of_col_raw(j).iter().zip(a.val_of_col(j)) {
            if i >= j {
                col[work.local[i]] += v;
            }
        }
    }
}

/// Subtracts from `target` (columns `c0..c0 + w` of a block shaped as supernode `s`'s)
/// the updates `updates` (indices into the plan's lists of `s`, in ascending order of
/// the descendant) of those columns, the descendants' factor values read from `head`
/// (the factor's values from offset `base`). The whole block (`c0 = 0`, `w` its
/// columns) and any window of it compute each value alike.
#[allow(clippy::too_many_arguments)]
fn apply_updates(
    shape: &Shape<'_>,
    plan: &TreePlan,
    updates: impl Iterator<Item = usize>,
    head: &[f64],
    base: usize,
    s: usize,
    (c0, w): (usize, usize),
    target: &mut [f64],
    work: &mut Work,
) {
    let rows = shape.rows(s);
    for u in updates {
        let d = plan.update_from[u];
        let at = plan.update_at[u];
        let (d0, d1) = shape.cols(d);
        let dn = d1 - d0;
        let dpat = shape.pattern(d);
        let drows = shape.rows(d);
        let inside = plan.update_inside[u];
        work.rows.clear();
        work.rows.extend(dpat[at..].iter().map(|&r| work.local[r]));
        // The update's columns inside the window (its rows inside `s` are ascending).
        let j0 = work.rows[..inside].partition_point(|&c| c < c0);
        let j1 = work.rows[..inside].partition_point(|&c| c < c0 + w);
        if j0 == j1 {
            continue;
        }
        let (m, cols) = (dpat.len() - at - j0, j1 - j0);
        let (w0, w1) = shape.values(d);
        let ld = MatRef::from_column_major_slice(&head[w0 - base..w1 - base], drows, dn);
        let below = ld.subrows(dn + at + j0, m);
        let mid = ld.subrows(dn + at + j0, cols);
        let mut upd = MatMut::from_column_major_slice_mut(&mut work.update[..m * cols], m, cols);
        if cols >= TRIANGULAR_FROM {
            // The update's square top is symmetric: only its lower half is computed.
            let (upd_top, upd_bottom) = upd.as_mut().split_at_row_mut(cols);
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
                below.subrows(cols, m - cols),
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
        let places = &work.rows[j0..];
        for j in 0..cols {
            let col = &mut target[(places[j] - c0) * rows..][..rows];
            let src = &work.update[j * m..][..m];
            for i in j..m {
                col[places[i]] -= src[i];
            }
        }
    }
}

/// Factors supernode `s`'s diagonal block and solves for the rows below it, then clears
/// its row map. False on a non-positive pivot.
fn finish(shape: &Shape<'_>, s: usize, ls: &mut [f64], work: &mut Work) -> bool {
    let (s0, s1) = shape.cols(s);
    let sn = s1 - s0;
    let rows = shape.rows(s);
    let factored = factor_block(MatMut::from_column_major_slice_mut(ls, rows, sn), work);
    reset(shape, s, work);
    factored
}

/// Solves `L L^T x = b` in place (`x` holds `b` on entry), `L` the factor `l` computed
/// with the same plan, in the factorization's order (the caller applies the ordering).
/// With a split, the forward solve runs the two groups side by side, then the top; the
/// backward solve runs the top, then the two groups side by side. A group's supernode
/// subtracts from its rows below the diagonal block, which are its ancestors' columns:
/// its own group's, which lie in the group's range of `x`, and top supernodes', which
/// may lie anywhere (between another group's subtrees too). A group subtracts from rows
/// inside its range in `x` and from the others in its own buffer, and the buffers are
/// added to the top supernodes' rows after both groups, the first's then the second's.
/// Backward, each group reads the top's rows, final by then, from a copy. As in
/// [`factorize`], the arithmetic is the plan's alone, so the solution is the same on
/// one thread and on two.
pub(crate) fn solve(
    symbolic: &SymbolicSupernodalCholesky<usize>,
    plan: &TreePlan,
    l: &[f64],
    x: &mut [f64],
    works: &mut [Work; 2],
    parallel: bool,
) {
    let f = Factor {
        shape: Shape { symbolic },
        l,
    };
    let n = x.len();
    let Some(split) = &plan.split else {
        let all = 0..f.shape.len();
        let tmp = &mut works[0].below;
        forward(&f, all.clone(), Rows { x, col0: 0 }, &mut [], tmp);
        backward(&f, all.rev(), Rows { x, col0: 0 }, &[], tmp);
        return;
    };
    let [(a0, a1), (b0, b1)] = split.groups;
    let in_group = |g: u8| move |s: &usize| plan.group[*s] == g;
    let cols = |(s0, s1): (usize, usize)| (f.shape.cols(s0).0, f.shape.cols(s1 - 1).1);
    let ((ca0, ca1), (cb0, cb1)) = (cols((a0, a1)), cols((b0, b1)));
    let [work_a, work_b] = works;
    // The buffers are zero outside a solve: each top row is taken back to zero below.
    for work in [&mut *work_a, &mut *work_b] {
        if work.gathered.len() != n {
            work.gathered.clear();
            work.gathered.resize(n, 0.0);
        }
    }
    {
        let [rows_a, rows_b] = Rows::pair(x, (ca0, ca1), (cb0, cb1));
        let (acc_a, tmp_a) = (&mut work_a.gathered, &mut work_a.below);
        let (acc_b, tmp_b) = (&mut work_b.gathered, &mut work_b.below);
        join_if(
            parallel,
            || forward(&f, (a0..a1).filter(in_group(0)), rows_a, acc_a, tmp_a),
            || forward(&f, (b0..b1).filter(in_group(1)), rows_b, acc_b, tmp_b),
        );
    }
    // Only top rows get another group's subtractions (a group's buffer stays zero at
    // its own rows, and at the other group's: no supernode of one group is an ancestor
    // of one of the other's).
    for &s in &split.top {
        let (c0, c1) = f.shape.cols(s);
        let (from_a, from_b) = (&mut work_a.gathered[c0..c1], &mut work_b.gathered[c0..c1]);
        for ((x, a), b) in x[c0..c1].iter_mut().zip(from_a).zip(from_b) {
            *x += std::mem::take(a);
            *x += std::mem::take(b);
        }
    }
    let top = split.top.iter().copied();
    let tmp = &mut work_a.below;
    forward(&f, top.clone(), Rows { x, col0: 0 }, &mut [], tmp);
    backward(&f, top.rev(), Rows { x, col0: 0 }, &[], tmp);
    let copy = &mut work_a.copy;
    copy.clear();
    copy.extend_from_slice(x);
    let [rows_a, rows_b] = Rows::pair(x, (ca0, ca1), (cb0, cb1));
    let (copy, tmp_a, tmp_b) = (&*copy, &mut work_a.below, &mut work_b.below);
    join_if(
        parallel,
        || backward(&f, (a0..a1).rev().filter(in_group(0)), rows_a, copy, tmp_a),
        || backward(&f, (b0..b1).rev().filter(in_group(1)), rows_b, copy, tmp_b),
    );
}

/// A factor to solve with: its supernodes' shapes and its values.
struct Factor<'a> {
    shape: Shape<'a>,
    l: &'a [f64],
}

impl Factor<'_> {
    /// Supernode `s`'s diagonal block and its rows below it.
    fn blocks(&self, s: usize) -> (MatRef<'_, f64>, MatRef<'_, f64>) {
        let (c0, c1) = self.shape.cols(s);
        let sn = c1 - c0;
        let (v0, v1) = self.shape.values(s);
        let rows = self.shape.rows(s);
        MatRef::from_column_major_slice(&self.l[v0..v1], rows, sn).split_at_row(sn)
    }
}

/// The rows `col0..col0 + x.len()` of the solution: a group's range of the unknowns, or
/// all of them.
struct Rows<'a> {
    x: &'a mut [f64],
    col0: usize,
}

impl<'a> Rows<'a> {
    /// The rows `a0..a1` and `b0..b1` of `x` (`a1 <= b0`).
    fn pair(x: &'a mut [f64], (a0, a1): (usize, usize), (b0, b1): (usize, usize)) -> [Self; 2] {
        let (low, rest) = x.split_at_mut(b0);
        [
            Rows {
                x: &mut low[a0..a1],
                col0: a0,
            },
            Rows {
                x: &mut rest[..b1 - b0],
                col0: b0,
            },
        ]
    }

    /// Where row `r` is in `x`, if it is there.
    fn at(&self, r: usize) -> Option<usize> {
        r.checked_sub(self.col0).filter(|&i| i < self.x.len())
    }
}

/// The forward solve `L y = b` over `supernodes` (ascending), on `rows` holding their
/// columns: a subtraction from a row outside `rows` goes to `acc` (indexed by row).
fn forward(
    f: &Factor<'_>,
    supernodes: impl Iterator<Item = usize>,
    rows: Rows<'_>,
    acc: &mut [f64],
    tmp: &mut Vec<f64>,
) {
    for s in supernodes {
        let (c0, c1) = f.shape.cols(s);
        let (top, below) = f.blocks(s);
        let width = c1 - c0;
        let xs = &mut rows.x[c0 - rows.col0..c1 - rows.col0];
        solve_lower_triangular_in_place(
            top,
            MatMut::from_column_major_slice_mut(xs, width, 1),
            Par::Seq,
        );
        let pattern = f.shape.pattern(s);
        tmp.clear();
        tmp.resize(pattern.len(), 0.0);
        matmul(
            MatMut::from_column_major_slice_mut(tmp, pattern.len(), 1),
            Accum::Replace,
            below,
            MatRef::from_column_major_slice(xs, width, 1),
            1.0,
            Par::Seq,
        );
        for (&r, &v) in pattern.iter().zip(tmp.iter()) {
            match rows.at(r) {
                Some(i) => rows.x[i] -= v,
                None => acc[r] -= v,
            }
        }
    }
}

/// The backward solve `L^T x = y` over `supernodes` (descending), on `rows` holding
/// their columns: a row outside `rows` is read from `outside` (indexed by row).
fn backward(
    f: &Factor<'_>,
    supernodes: impl Iterator<Item = usize>,
    rows: Rows<'_>,
    outside: &[f64],
    tmp: &mut Vec<f64>,
) {
    for s in supernodes {
        let (c0, c1) = f.shape.cols(s);
        let (top, below) = f.blocks(s);
        let pattern = f.shape.pattern(s);
        tmp.clear();
        tmp.extend(
            pattern
                .iter()
                .map(|&r| rows.at(r).map_or_else(|| outside[r], |i| rows.x[i])),
        );
        let width = c1 - c0;
        let mut xs = MatMut::from_column_major_slice_mut(
            &mut rows.x[c0 - rows.col0..c1 - rows.col0],
            width,
            1,
        );
        matmul(
            xs.as_mut(),
            Accum::Add,
            below.transpose(),
            MatRef::from_column_major_slice(tmp, pattern.len(), 1),
            -1.0,
            Par::Seq,
        );
        solve_upper_triangular_in_place(top.transpose(), xs, Par::Seq);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linear::{DirectSolver, FactorStructure};
    use crate::model::{ClothGrid, SpringSystem};
    use crate::newton::newton_matrix_triplets;
    use crate::pattern::{FIXED, HessianPattern};
    use faer::Conj;
    use faer::linalg::cholesky::llt::factor::LltRegularization;
    use faer::sparse::linalg::cholesky::{SymbolicCholeskyRaw, supernodal};

    /// The Newton matrix of a stretched free `n x n` lab-pattern sheet, on a pattern
    /// widened by `pairs`, each pair given a spring-like block `c (I, -I; -I, I)` so the
    /// matrix stays positive definite: its pattern and values.
    fn matrix(n: usize, pairs: &[[usize; 2]]) -> (HessianPattern, Vec<f64>) {
        matrix_fixing(n, Vec::new(), pairs)
    }

    /// [`matrix`] with the particles `fixed` (row, column) held, so without unknowns;
    /// `pairs` are particle indices, those with a held end left out.
    fn matrix_fixing(
        n: usize,
        fixed: Vec<(usize, usize)>,
        pairs: &[[usize; 2]],
    ) -> (HessianPattern, Vec<f64>) {
        let grid = ClothGrid {
            fixed,
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
        let free = |p: usize| Some(pattern.free_index[p]).filter(|&f| f != FIXED);
        for &[p, q] in pairs {
            let (Some(p), Some(q)) = (free(p), free(q)) else {
                continue;
            };
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
        let run = |parallel: bool| {
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
        let (one, two) = alone_and_paired(run);
        [faer_ok.then_some(faer_l), one, two]
    }

    /// `run(false)` on the calling thread, then `run(true)` on a pool of two threads.
    fn alone_and_paired<T: Send>(mut run: impl FnMut(bool) -> T + Send) -> (T, T) {
        let alone = run(false);
        #[cfg(feature = "parallel")]
        let paired = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap()
            .install(|| run(true));
        #[cfg(not(feature = "parallel"))]
        let paired = run(true);
        (alone, paired)
    }

    fn largest(values: &[f64]) -> f64 {
        values.iter().fold(0.0, |m, v| m.max(v.abs()))
    }

    /// `b` is `a` to `tolerance` of `a`'s largest entry, and `c` is `b` to the bit.
    fn assert_close_then_same(a: &[f64], b: &[f64], c: &[f64], tolerance: f64, what: &str) {
        let scale = largest(a);
        let diff = a
            .iter()
            .zip(b)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        assert!(diff <= tolerance * scale, "{what}: {diff:e} of {scale:e}");
        assert!(
            b.iter().zip(c).all(|(x, y)| x.to_bits() == y.to_bits()),
            "{what}: one and two threads differ"
        );
    }

    /// The three factors of [`factors`] exist, this module's is faer's to 1e-13 of its
    /// largest entry, and it is the same to the bit on one thread and on two; and so
    /// are the solutions of a system with each (faer's solve with faer's factor, this
    /// module's on one thread and on two with its own), to 1e-10 of the largest entry
    /// of faer's solution.
    fn assert_alike(solver: &mut DirectSolver, values: &[f64], what: &str) {
        let [faer_l, one, two] = factors(solver, values);
        let (faer_l, one, two) = (faer_l.unwrap(), one.unwrap(), two.unwrap());
        assert_close_then_same(&faer_l, &one, &two, 1e-13, &format!("{what}: factor"));
        let SymbolicCholeskyRaw::Supernodal(symbolic) = solver.symbolic.raw() else {
            unreachable!("the structure is supernodal");
        };
        let permuted = solver.permuted.as_mut().unwrap();
        let n = symbolic.nrows();
        let b: Vec<f64> = (0..n).map(|i| ((i * 7 + 3) % 11) as f64 - 5.0).collect();
        let mut by_faer = b.clone();
        supernodal::SupernodalLltRef::new(symbolic, &faer_l).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut by_faer, n, 1),
            Par::Seq,
            MemStack::new(&mut MemBuffer::new(
                symbolic.solve_in_place_scratch::<f64>(1, Par::Seq),
            )),
        );
        let (alone, paired) = alone_and_paired(|parallel| {
            let mut x = b.clone();
            let works = &mut permuted.works;
            solve(symbolic, &permuted.plan, &one, &mut x, works, parallel);
            x
        });
        assert_close_then_same(
            &by_faer,
            &alone,
            &paired,
            1e-10,
            &format!("{what}: solution"),
        );
    }

    /// On a sheet's matrix and on one widened by far pairs, the plan splits, the factor
    /// is faer's to round-off, and it is the same to the bit on one thread and on two.
    #[test]
    fn the_factor_is_faers_to_round_off_and_the_same_bits_on_one_and_two_threads() {
        for (n, pairs) in [(31, Vec::new()), (24, far_pairs(24))] {
            let (pattern, values) = matrix(n, &pairs);
            let mut solver = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
            assert!(solver.permuted.as_ref().unwrap().plan.splits(), "{n}");
            assert_alike(&mut solver, &values, &format!("{n}"));
        }
    }

    /// A matrix with a negative pivot in either group or in the top (its first panel or
    /// its last) is refused on one thread and on two, as faer refuses it; the good
    /// matrix factored after it gives the same bits as before (no scratch state is left
    /// behind by a failure).
    #[test]
    fn a_matrix_that_is_not_positive_definite_is_refused_and_leaves_nothing_behind() {
        let (pattern, values) = matrix(31, &[]);
        let mut solver = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
        let good = factors(&mut solver, &values)[1].clone().unwrap();
        let (plan, begins, ends) = {
            let SymbolicCholeskyRaw::Supernodal(symbolic) = solver.symbolic.raw() else {
                unreachable!()
            };
            let plan = solver.permuted.as_ref().unwrap().plan.clone();
            let [begins, ends] = [symbolic.supernode_begin(), symbolic.supernode_end()];
            (plan, begins.to_vec(), ends.to_vec())
        };
        let perm = solver.symbolic.perm().unwrap().arrays().0.to_vec();
        // One column in each place: the first group's first supernode, the second's, the
        // first top supernode's first column, and the last column of the last top
        // supernode (its last panel, which waits for the panels before it).
        let first = |g: u8| (0..plan.group.len()).find(|&s| plan.group[s] == g).unwrap();
        let last = plan.group.len() - 1;
        assert!(plan.group[last] == TOP && ends[last] - begins[last] > PANEL);
        let places = [
            (0, begins[first(0)]),
            (1, begins[first(1)]),
            (TOP, begins[first(TOP)]),
            (TOP, ends[last] - 1),
        ];
        for (g, permuted_column) in places {
            let column = perm[permuted_column];
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

    /// Random sheets of 18 to 37 particles a side, widened by pairs near each other and
    /// a few far apart, every other one cut in two by two held middle rows (a forest of
    /// two trees, as separate sheets give): the factor is faer's to round-off and the
    /// same bits on one thread and on two, on the plans that split and those that do not.
    #[test]
    fn random_sheets_factor_alike_on_one_and_two_threads() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = |m: usize| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 33) as usize % m
        };
        let mut split = 0;
        for case in 0..10 {
            let n = 18 + next(20);
            let cut = (case % 2 == 1).then(|| n / 3 + next(n / 3));
            let fixed: Vec<(usize, usize)> = cut
                .iter()
                .flat_map(|&r| (0..n).flat_map(move |c| [(r, c), (r + 1, c)]))
                .collect();
            let mut pairs = Vec::new();
            for _ in 0..next(n * n / 2) {
                let p = next(n * n);
                pairs.push([p, (p + 1 + next(3 * n)) % (n * n)]);
            }
            for _ in 0..next(6) {
                pairs.push([next(n * n), next(n * n)]);
            }
            // A cut sheet keeps its pairs on one side or the other: two trees.
            let side = |p: usize| cut.map(|r| p / n > r);
            pairs.retain(|&[p, q]| p != q && side(p) == side(q));
            let (pattern, values) = matrix_fixing(n, fixed, &pairs);
            let mut solver = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
            split += usize::from(solver.permuted.as_ref().unwrap().plan.splits());
            assert_alike(&mut solver, &values, &format!("case {case}"));
        }
        assert!(split >= 5, "{split} of 10 split");
    }

    /// A top supernode may lie inside the second group's range (between its subtrees):
    /// that group's thread then assembles it and the first group's updates of it go to
    /// a buffer, and in the forward solve the first group's subtractions from its rows
    /// too. Such a split, built by hand (the search picks none on these sheets): the
    /// factor and a solution are faer's to round-off and the same bits on one thread
    /// and on two.
    #[test]
    fn a_top_supernode_inside_the_second_group_is_factored_and_solved_alike() {
        let (pattern, values) = matrix(31, &[]);
        let mut solver = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
        let SymbolicCholeskyRaw::Supernodal(symbolic) = solver.symbolic.raw() else {
            unreachable!()
        };
        let ns = symbolic.n_supernodes();
        let owner = |row: usize| symbolic.supernode_end().partition_point(|&e| e <= row);
        let parent = |s: usize| symbolic.supernode(s).pattern().first().map(|&r| owner(r));
        let children = |p: usize| {
            (0..ns)
                .filter(|&s| parent(s) == Some(p))
                .collect::<Vec<_>>()
        };
        // Down the root's chain to the first supernode with two children or more; its
        // first child `t` (the subtree from supernode 0) and `t`'s first child `x`.
        let mut top = vec![ns - 1];
        while children(top[top.len() - 1]).len() == 1 {
            top.push(children(top[top.len() - 1])[0]);
        }
        let q = top[top.len() - 1];
        let t = children(q)[0];
        let x = *children(t).first().expect("t has children");
        assert!(children(t).len() >= 2, "t = {t} has one child");
        top.push(t);
        top.sort_unstable();
        let split = Split {
            groups: [(0, x + 1), (x + 1, q)],
            top,
            held_by: Vec::new(),
            at: Vec::new(),
            buffer: [0; 2],
        };
        let permuted = solver.permuted.as_mut().unwrap();
        let plan = permuted.plan.clone().with_split(symbolic, Some(split));
        let v0 = symbolic.col_ptr_for_val()[t];
        let vb = symbolic.col_ptr_for_val()[x + 1]..symbolic.col_ptr_for_val()[q];
        assert!(vb.contains(&v0) && plan.group[t] == TOP && plan.group[x + 1] == 1);
        assert_eq!(plan.split.as_ref().unwrap().held_by, [1, 0]);
        permuted.works = std::array::from_fn(|g| Work::new(symbolic.nrows(), &plan, g));
        permuted.plan = plan;
        assert_alike(&mut solver, &values, "");
    }

    /// A small matrix is not worth a second thread: no split, and faer's factor.
    #[test]
    fn a_small_matrix_stays_on_one_thread() {
        let (pattern, values) = matrix(6, &[]);
        let mut solver = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
        assert!(!solver.permuted.as_ref().unwrap().plan.splits());
        assert_alike(&mut solver, &values, "");
    }
}
