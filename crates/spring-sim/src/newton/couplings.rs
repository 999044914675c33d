//! The particle pairs a term couples only for a while (self-contact between particles no
//! spring joins): given Hessian slots when they appear, and dropped again once their
//! blocks have stayed zero for a number of steps.
//!
//! A contact pair's coupling blocks are written only while the pair is within `dhat`.
//! Kept for the whole run, the slots of every pair that ever touched fill the Newton
//! matrix with blocks of zeros: on the wound twist (a 50 x 50 sheet wrung into a rope)
//! the pattern held 279 324 entries after 320 steps where the pairs in contact in the
//! step before needed 188 046, and the factor 1.61 million values against 1.25 million
//! (docs/bench/contact.md, "A pattern that forgets the pairs that left"). A coupling whose
//! block was zero in every Newton matrix of [`IDLE_STEPS`] consecutive steps is idle;
//! once idle pairs are many (see [`TransientCouplings::narrowing_due`]), the pattern is
//! rebuilt without them. A pair that comes back is reported missing by its term and
//! widened in again, as any new pair is. Which pairs are idle is a function of the
//! matrices' values, which do not depend on the thread count, so neither does the
//! pattern.

use crate::pattern::{FIXED, HessianPattern};

/// Consecutive steps a transient coupling's block must stay zero before it may be
/// dropped: long enough that a pair bouncing in and out of `dhat` keeps its slots.
pub(super) const IDLE_STEPS: u32 = 15;

/// Idle pairs are dropped only when they are at least this many ...
const MIN_DROP: usize = 64;
/// ... and at least this fraction of the transient pairs: each narrowing costs one
/// rebuild of the pattern and of the direct solver's set-up.
const DROP_FRACTION: f64 = 0.25;

/// The transient couplings, sorted and distinct (`[min, max]` particle indices), with
/// each one's idle count and its block's place in the current pattern.
#[derive(Clone, Debug, Default)]
pub(super) struct TransientCouplings {
    pairs: Vec<[usize; 2]>,
    /// Consecutive finished steps whose Newton matrices all had the pair's block zero.
    idle: Vec<u32>,
    /// Whether a Newton matrix of the current step had the pair's block nonzero.
    used: Vec<bool>,
    /// Per pair, where each of its block's three columns holds the block's three rows
    /// in the pattern's values; `None` when the pattern has no slot for it (a fixed
    /// particle).
    slots: Vec<Option<[usize; 3]>>,
}

impl TransientCouplings {
    /// The pairs, sorted and distinct.
    pub(super) fn pairs(&self) -> &[[usize; 2]] {
        &self.pairs
    }

    /// These couplings with `added` merged in (counted as used in the current step:
    /// a term has just coupled them); the others keep their counts. The slots are left
    /// to [`Self::locate`].
    pub(super) fn with_added(&self, added: &[[usize; 2]]) -> Self {
        let mut new: Vec<[usize; 2]> = added.iter().map(|&[a, b]| [a.min(b), a.max(b)]).collect();
        new.sort_unstable();
        new.dedup();
        let mut out = Self::default();
        let (mut i, mut j) = (0, 0);
        while i < self.pairs.len() || j < new.len() {
            let take_old = j == new.len() || (i < self.pairs.len() && self.pairs[i] <= new[j]);
            if take_old {
                let fresh = j < new.len() && self.pairs[i] == new[j];
                out.pairs.push(self.pairs[i]);
                out.idle.push(if fresh { 0 } else { self.idle[i] });
                out.used.push(fresh || self.used[i]);
                i += 1;
                j += usize::from(fresh);
            } else {
                out.pairs.push(new[j]);
                out.idle.push(0);
                out.used.push(true);
                j += 1;
            }
        }
        out
    }

    /// These couplings without the idle ones, and how many were dropped.
    pub(super) fn without_idle(&self) -> (Self, usize) {
        let mut out = Self::default();
        for (k, &pair) in self.pairs.iter().enumerate() {
            if self.idle[k] < IDLE_STEPS {
                out.pairs.push(pair);
                out.idle.push(self.idle[k]);
                out.used.push(self.used[k]);
            }
        }
        let dropped = self.pairs.len() - out.pairs.len();
        (out, dropped)
    }

    /// Finds each pair's block in `pattern` (built with slots for every pair).
    pub(super) fn locate(&mut self, pattern: &HessianPattern) {
        let free_index = &pattern.free_index;
        self.slots = self
            .pairs
            .iter()
            .map(|&[a, b]| {
                let (fa, fb) = (free_index[a], free_index[b]);
                if fa == FIXED || fb == FIXED {
                    return None;
                }
                let (col, k) = pattern.off_block_position(fa, fb)?;
                // The block's columns' rows are consecutive: each column's first slot.
                let slots = pattern.off_block_slots_at(col, k);
                Some([slots[0], slots[3], slots[6]])
            })
            .collect();
    }

    /// Records which pairs' blocks are nonzero in the Newton matrix `values`.
    pub(super) fn mark_used(&mut self, values: &[f64]) {
        for (used, slots) in self.used.iter_mut().zip(&self.slots) {
            if *used {
                continue;
            }
            if let Some(starts) = slots {
                *used = starts
                    .iter()
                    .any(|&s| values[s..s + 3].iter().any(|&v| v != 0.0));
            }
        }
    }

    /// Ends a step: a pair unused in it is idle one step longer, a used one not at all.
    pub(super) fn end_step(&mut self) {
        for (idle, used) in self.idle.iter_mut().zip(&mut self.used) {
            *idle = if *used { 0 } else { idle.saturating_add(1) };
            *used = false;
        }
    }

    /// Whether enough pairs are idle to rebuild the pattern without them.
    pub(super) fn narrowing_due(&self) -> bool {
        let idle = self.idle.iter().filter(|&&n| n >= IDLE_STEPS).count();
        idle >= MIN_DROP && idle as f64 >= DROP_FRACTION * self.pairs.len() as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Material, Particle, SpringSpec, SpringSystem};
    use crate::potential::{HessianSink, SymBlock};
    use sinew_math::{DMat3, DVec3};

    /// Ten free particles on a line (one fixed at the end), springs between neighbours.
    fn chain() -> SpringSystem {
        let particles: Vec<Particle> = (0..10)
            .map(|i| Particle {
                fixed: i == 9,
                ..Particle::at_rest(DVec3::new(i as f64, 0.0, 0.0), 1.0)
            })
            .collect();
        let springs: Vec<SpringSpec> = (0..9).map(|i| SpringSpec::between(i, i + 1)).collect();
        SpringSystem::new(&particles, &springs, Material::default()).unwrap()
    }

    #[test]
    fn added_pairs_merge_sorted_and_distinct_keeping_the_others_counts() {
        let a = TransientCouplings::default().with_added(&[[5, 2], [0, 7], [2, 5]]);
        assert_eq!(a.pairs(), &[[0, 7], [2, 5]]);
        let mut a = a;
        a.end_step();
        a.end_step();
        // [0, 7] and [2, 5] were used in the step they were added, then idle once.
        assert_eq!(a.idle, [1, 1]);
        let b = a.with_added(&[[7, 0], [1, 3]]);
        assert_eq!(b.pairs(), &[[0, 7], [1, 3], [2, 5]]);
        // [0, 7] is coupled again (used now, its count restarted); [2, 5] keeps its own.
        assert_eq!(b.idle, [0, 0, 1]);
        assert_eq!(b.used, [true, true, false]);
    }

    #[test]
    fn a_pair_is_idle_only_after_steps_whose_matrices_all_had_its_block_zero() {
        let system = chain();
        let mut t = TransientCouplings::default().with_added(&[[0, 4], [2, 7], [3, 9]]);
        let pattern = HessianPattern::with_pairs(&system, t.pairs());
        t.locate(&pattern);
        // [3, 9] has a fixed particle: no slot.
        assert!(t.slots[0].is_some() && t.slots[1].is_some() && t.slots[2].is_none());
        t.end_step();
        let mut values = vec![0.0; pattern.nnz()];
        // Every spring block and diagonal block nonzero, and the block of [2, 7] nonzero
        // in one entry only, written through the sink as a term writes it.
        {
            let mut sink = HessianSink::values(&pattern, &mut values);
            for i in 0..10 {
                sink.add_diagonal(i, SymBlock::scaled_identity(2.0));
            }
            for i in 0..9 {
                sink.add_pair(i, i + 1, &(-DMat3::IDENTITY)).unwrap();
            }
            let mut one = DMat3::ZERO;
            one.y_axis.z = 1e-300;
            sink.add_pair(7, 2, &one).unwrap();
        }
        t.mark_used(&values);
        assert_eq!(t.used, [false, true, false]);
        // A later matrix of the same step with the block zero does not undo it.
        t.mark_used(&vec![0.0; pattern.nnz()]);
        assert_eq!(t.used, [false, true, false]);
        t.end_step();
        assert_eq!(t.idle, [1, 0, 1]);
        for _ in 1..IDLE_STEPS {
            t.end_step();
        }
        assert_eq!(t.idle, [IDLE_STEPS, IDLE_STEPS - 1, IDLE_STEPS]);
        let (kept, dropped) = t.without_idle();
        assert_eq!((kept.pairs(), dropped), (&[[2, 7]][..], 2));
    }

    #[test]
    fn every_entry_of_a_pairs_block_marks_it_used_and_no_other_entry_does() {
        let system = chain();
        let mut t = TransientCouplings::default().with_added(&[[1, 6], [4, 8]]);
        let pattern = HessianPattern::with_pairs(&system, t.pairs());
        t.locate(&pattern);
        // Each of the nine entries of [1, 6]'s block alone, either way round.
        for (i, j) in [(1, 6), (6, 1)] {
            for entry in 0..9 {
                let mut values = vec![0.0; pattern.nnz()];
                let mut block = DMat3::ZERO;
                block.col_mut(entry / 3)[entry % 3] = -1e-300;
                HessianSink::values(&pattern, &mut values)
                    .add_pair(i, j, &block)
                    .unwrap();
                t.end_step();
                t.mark_used(&values);
                assert_eq!(t.used, [true, false], "({i}, {j}) entry {entry}");
            }
        }
        // Everything but the two pairs' blocks nonzero: neither is used.
        let mut values = vec![0.0; pattern.nnz()];
        {
            let mut sink = HessianSink::values(&pattern, &mut values);
            for i in 0..10 {
                sink.add_diagonal(i, SymBlock::scaled_identity(2.0));
            }
            for i in 0..9 {
                sink.add_pair(i, i + 1, &DMat3::from_cols_array(&[1.0; 9]))
                    .unwrap();
            }
        }
        t.end_step();
        t.mark_used(&values);
        assert_eq!(t.used, [false, false]);
    }

    #[test]
    fn the_pattern_narrows_only_when_idle_pairs_are_many() {
        let pairs: Vec<[usize; 2]> = (0..400).map(|i| [i, i + 1000]).collect();
        // Used in the step they were added, then idle for `IDLE_STEPS` steps.
        let mut t = TransientCouplings::default().with_added(&pairs);
        for _ in 0..=IDLE_STEPS {
            t.end_step();
        }
        assert!(t.narrowing_due());
        // 99 of 400 idle: below a quarter.
        let mut u = t.clone();
        for k in 99..400 {
            u.used[k] = true;
        }
        u.end_step();
        assert!(!u.narrowing_due());
        // 63 of 100 idle: a large fraction but below the least worth a rebuild.
        let mut v = TransientCouplings::default().with_added(&pairs[..100]);
        for _ in 0..=IDLE_STEPS {
            v.end_step();
        }
        for k in 63..100 {
            v.used[k] = true;
        }
        v.end_step();
        assert!(!v.narrowing_due());
        assert_eq!(v.idle.iter().filter(|&&n| n >= IDLE_STEPS).count(), 63);
    }
}
