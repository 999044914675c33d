//! The self-contact broad phase: the spatial hash finds exactly the pairs brute force
//! finds on random crumpled meshes (at a state and over a step, with a primitive swept
//! far, with fixed vertices), never a pair sharing a vertex, and every pair closer than
//! the margin; the list kept for a line-search segment answers every query inside the
//! segment with exactly the broad phase's set and declines every query outside it.

use crate::common::{Sample, Xorshift as Rng};
use sinew_math::DVec3;
use sinew_spring_sim::ClothGrid;
use sinew_spring_sim::contact::self_contact::broad::{
    Candidate, CandidateCache, Primitives, candidates, candidates_brute_force,
};
use sinew_spring_sim::contact::self_contact::distance::{PairKind, squared_distance};

/// An `n x n` grid of spacing 0.1 crumpled by random offsets of size `crumple`.
fn crumpled(n: usize, crumple: f64, rng: &mut Rng) -> (Vec<DVec3>, Vec<[usize; 3]>) {
    let mut x = Vec::new();
    for i in 0..n {
        for j in 0..n {
            x.push(DVec3::new(0.1 * i as f64, 0.1 * j as f64, 0.0) + rng.vec(crumple));
        }
    }
    let grid = ClothGrid {
        size: n,
        ..ClothGrid::lab()
    };
    (x, grid.triangles())
}

#[test]
fn the_hash_finds_the_brute_force_pairs_on_random_meshes() {
    let mut rng = Rng(12345);
    let mut total = 0;
    for case in 0..24 {
        let n = 4 + case % 5;
        let (x, triangles) = crumpled(n, 0.02 + 0.03 * (case % 4) as f64, &mut rng);
        let prims = Primitives::new(&triangles);
        let dx: Vec<DVec3> = x
            .iter()
            .map(|_| rng.vec(0.05 * (case % 3) as f64))
            .collect();
        let mut skip = vec![false; x.len()];
        if case % 2 == 1 {
            for s in skip.iter_mut().take(n * 2) {
                *s = true;
            }
        }
        let margin = 0.01 * (1 + case % 6) as f64;
        for sweep in [None, Some(dx.as_slice())] {
            let fast = candidates(&prims, &x, sweep, margin, &skip);
            let slow = candidates_brute_force(&prims, &x, sweep, margin, &skip);
            assert_eq!(fast, slow, "case {case}, sweep {}", sweep.is_some());
            total += fast.len();
            for c in &fast {
                match *c {
                    Candidate::PointTriangle { vertex, triangle } => {
                        assert!(!triangles[triangle].contains(&vertex));
                    }
                    Candidate::EdgeEdge { a, b } => {
                        assert!(a < b);
                        let (ea, eb) = (prims.edges[a], prims.edges[b]);
                        assert!(!ea.iter().any(|v| eb.contains(v)));
                    }
                }
            }
        }
    }
    // The cases are not vacuous.
    assert!(total > 1000, "{total} candidates in all");
}

#[test]
fn the_segment_list_gives_the_broad_phase_set_inside_the_segment_and_declines_outside() {
    let mut rng = Rng(777);
    let (mut answered, mut declined, mut total) = (0, 0, 0);
    for case in 0..12 {
        let n = 5 + case % 4;
        let (x, triangles) = crumpled(n, 0.03 + 0.02 * (case % 3) as f64, &mut rng);
        let prims = Primitives::new(&triangles);
        let dx: Vec<DVec3> = x.iter().map(|_| rng.vec(0.04)).collect();
        let mut skip = vec![false; x.len()];
        if case % 2 == 1 {
            skip.iter_mut().take(n).for_each(|s| *s = true);
        }
        let margin = 0.015;
        // The segment x + [0, 8] dx, as the line search's cap collects it.
        let long: Vec<DVec3> = dx.iter().map(|d| 8.0 * *d).collect();
        let kept = CandidateCache::new(&prims, &x, Some(&long), margin, &skip);
        for alpha in [0.0, 0.25, 1.0, 3.0, 8.0] {
            let end: Vec<DVec3> = x.iter().zip(&dx).map(|(p, d)| *p + alpha * *d).collect();
            let sweep: Vec<DVec3> = dx.iter().map(|d| alpha * *d).collect();
            for (state, step) in [(&x, Some(sweep.as_slice())), (&end, None)] {
                let exact = candidates(&prims, state, step, margin, &skip);
                let got = kept.query(&prims, state, step, margin, &skip);
                assert_eq!(got.as_ref(), Some(&exact), "case {case}, alpha {alpha}");
                total += exact.len();
                answered += 1;
            }
        }
        // Past the segment's end, or with another margin or skip, it declines.
        let past: Vec<DVec3> = dx.iter().map(|d| 9.0 * *d).collect();
        assert!(kept.query(&prims, &x, Some(&past), margin, &skip).is_none());
        assert!(kept.query(&prims, &x, None, 2.0 * margin, &skip).is_none());
        let other: Vec<bool> = skip.iter().map(|s| !s).collect();
        assert!(kept.query(&prims, &x, None, margin, &other).is_none());
        declined += 3;
    }
    assert_eq!((answered, declined), (120, 36));
    // The cases are not vacuous.
    assert!(total > 1000, "{total} candidates in all");
}

#[test]
fn a_region_kept_with_slack_gives_the_broad_phase_set_beyond_its_segment() {
    let mut rng = Rng(4242);
    let (mut beyond, mut total) = (0, 0);
    for case in 0..8 {
        let n = 5 + case % 4;
        let (x, triangles) = crumpled(n, 0.03 + 0.02 * (case % 3) as f64, &mut rng);
        let prims = Primitives::new(&triangles);
        let dx: Vec<DVec3> = x.iter().map(|_| rng.vec(0.04)).collect();
        let skip = vec![false; x.len()];
        let margin = 0.015;
        let slack = margin;
        let long: Vec<DVec3> = dx.iter().map(|d| 8.0 * *d).collect();
        let kept = CandidateCache::with_slack(&prims, &x, Some(&long), margin, slack, &skip);
        let plain = CandidateCache::new(&prims, &x, Some(&long), margin, &skip);
        assert!(kept.len() >= plain.len());
        // Iterates on the segment sweeping on along a shorter or a sideways direction,
        // some of them past the segment's own boxes but inside the slack.
        for alpha in [0.0, 0.5, 2.0, 8.0] {
            let start: Vec<DVec3> = x.iter().zip(&dx).map(|(p, d)| *p + alpha * *d).collect();
            let next: Vec<DVec3> = dx.iter().map(|d| 0.5 * *d + rng.vec(0.2 * slack)).collect();
            for state_sweep in [None, Some(next.as_slice())] {
                let exact = candidates(&prims, &start, state_sweep, margin, &skip);
                let covered = kept.covers(&prims, &start, state_sweep, margin, &skip);
                let got = kept.query(&prims, &start, state_sweep, margin, &skip);
                assert_eq!(covered, got.is_some());
                if let Some(got) = got {
                    assert_eq!(got, exact, "case {case}, alpha {alpha}");
                    let at = kept
                        .query_indices(&prims, &start, state_sweep, margin, &skip)
                        .unwrap();
                    let listed: Vec<_> = at.iter().map(|&k| kept.list()[k]).collect();
                    assert_eq!(listed, exact);
                    total += exact.len();
                    let without = plain.covers(&prims, &start, state_sweep, margin, &skip);
                    beyond += usize::from(!without);
                }
            }
        }
        // Far beyond the slack it declines.
        let far: Vec<DVec3> = x.iter().zip(&dx).map(|(p, d)| *p + 20.0 * *d).collect();
        assert!(!kept.covers(&prims, &far, None, margin, &skip));
    }
    // Some queries were answered only thanks to the slack, and the cases are not vacuous.
    assert!(beyond > 0, "no query needed the slack");
    assert!(total > 500, "{total} candidates in all");
}

#[test]
fn a_primitive_swept_far_is_still_found() {
    let mut rng = Rng(99);
    let (x, triangles) = crumpled(6, 0.01, &mut rng);
    let prims = Primitives::new(&triangles);
    let mut dx = vec![DVec3::ZERO; x.len()];
    // One corner sweeps across the whole sheet and far beyond: its boxes touch more
    // cells than the hash lists, so they go to the large list.
    dx[0] = DVec3::new(40.0, 40.0, 3.0);
    let skip = vec![false; x.len()];
    let fast = candidates(&prims, &x, Some(&dx), 0.01, &skip);
    let slow = candidates_brute_force(&prims, &x, Some(&dx), 0.01, &skip);
    assert_eq!(fast, slow);
    assert!(
        fast.iter().any(
            |c| matches!(c, Candidate::PointTriangle { vertex: 0, triangle } if *triangle > 40)
        )
    );
}

#[test]
fn every_pair_closer_than_the_margin_is_a_candidate() {
    let mut rng = Rng(2024);
    for _ in 0..10 {
        let (x, triangles) = crumpled(6, 0.08, &mut rng);
        let prims = Primitives::new(&triangles);
        let skip = vec![false; x.len()];
        let margin = 0.03;
        let found = candidates(&prims, &x, None, margin, &skip);
        for &v in &prims.vertices {
            for (t, tri) in triangles.iter().enumerate() {
                if tri.contains(&v) {
                    continue;
                }
                let pair = [x[v], x[tri[0]], x[tri[1]], x[tri[2]]];
                if squared_distance(PairKind::PointTriangle, &pair) < margin * margin {
                    assert!(found.contains(&Candidate::PointTriangle {
                        vertex: v,
                        triangle: t
                    }));
                }
            }
        }
        for a in 0..prims.edges.len() {
            for b in a + 1..prims.edges.len() {
                let (ea, eb) = (prims.edges[a], prims.edges[b]);
                if ea.iter().any(|v| eb.contains(v)) {
                    continue;
                }
                let pair = [x[ea[0]], x[ea[1]], x[eb[0]], x[eb[1]]];
                if squared_distance(PairKind::EdgeEdge, &pair) < margin * margin {
                    assert!(found.contains(&Candidate::EdgeEdge { a, b }));
                }
            }
        }
    }
}
