//! Additive CCD for self-contact: known times of impact (point-face, edge-edge, point-edge
//! at the step's end), misses, grazing and degenerate motions, and a property test on
//! random pairs that the returned fraction is never past a crossing (checked by sampling
//! the distance densely enough that the gap's Lipschitz bound rules out a zero between
//! samples).

use crate::common::{Sample, Xorshift as Rng};
use sinew_math::DVec3;
use sinew_spring_sim::contact::self_contact::ccd::{
    additive_ccd, additive_ccd_within, clear_without_distance,
};
use sinew_spring_sim::contact::self_contact::distance::{PairKind, squared_distance};

fn v(x: f64, y: f64, z: f64) -> DVec3 {
    DVec3::new(x, y, z)
}

const KEEP: f64 = 0.1;

fn gap(kind: PairKind, x: &[DVec3; 4], dx: &[DVec3; 4], t: f64, thickness: f64) -> f64 {
    let xt: [DVec3; 4] = std::array::from_fn(|k| x[k] + t * dx[k]);
    squared_distance(kind, &xt).sqrt() - thickness
}

fn tri_with(p: DVec3) -> [DVec3; 4] {
    [p, v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0)]
}

#[test]
fn a_point_falling_onto_a_face_stops_at_the_kept_fraction_of_its_gap() {
    // Height 1, closing speed 2: impact at t = 1/2. The mean-free bound is exactly the
    // closing speed, so the first ACCD step lands at gap 0.1 = KEEP g_0 (t = 0.45) and
    // the next one would go below it.
    let x = tri_with(v(0.2, 0.2, 1.0));
    let dx = [v(0.0, 0.0, -2.0), DVec3::ZERO, DVec3::ZERO, DVec3::ZERO];
    let t = additive_ccd(PairKind::PointTriangle, &x, &dx, 0.0, KEEP);
    assert!((t - 0.45).abs() < 1e-12, "{t}");
    // With a thickness of 0.2 the gap is 0.8 and the impact (gap 0) at t = 0.4.
    let t = additive_ccd(PairKind::PointTriangle, &x, &dx, 0.2, KEEP);
    assert!((t - 0.36).abs() < 1e-12, "{t}");
    assert!((gap(PairKind::PointTriangle, &x, &dx, t, 0.2) - 0.08).abs() < 1e-12);
}

#[test]
fn crossing_edges_stop_before_their_impact() {
    // Edge b one unit above edge a, falling at 4 per step: impact at t = 1/4.
    let x = [
        v(-1.0, 0.0, 0.0),
        v(1.0, 0.0, 0.0),
        v(0.0, -1.0, 1.0),
        v(0.0, 1.0, 1.0),
    ];
    let dx = [
        DVec3::ZERO,
        DVec3::ZERO,
        v(0.0, 0.0, -4.0),
        v(0.0, 0.0, -4.0),
    ];
    let t = additive_ccd(PairKind::EdgeEdge, &x, &dx, 0.0, KEEP);
    assert!((t - 0.225).abs() < 1e-12, "{t}");
    // Both edges moving toward each other, each at 1: the same impact time 1/2.
    let dx = [
        v(0.0, 0.0, 1.0),
        v(0.0, 0.0, 1.0),
        v(0.0, 0.0, -1.0),
        v(0.0, 0.0, -1.0),
    ];
    let t = additive_ccd(PairKind::EdgeEdge, &x, &dx, 0.0, KEEP);
    assert!((t - 0.45).abs() < 1e-12, "{t}");
}

#[test]
fn an_impact_exactly_at_the_end_of_the_step_is_not_reached() {
    // The point reaches the triangle's edge exactly at t = 1.
    let x = tri_with(v(0.5, -1.0, 0.0));
    let dx = [v(0.0, 1.0, 0.0), DVec3::ZERO, DVec3::ZERO, DVec3::ZERO];
    let t = additive_ccd(PairKind::PointTriangle, &x, &dx, 0.0, KEEP);
    assert!(t < 1.0 && t > 0.5, "{t}");
    assert!(gap(PairKind::PointTriangle, &x, &dx, t, 0.0) >= KEEP * (1.0 - 1e-12));
}

#[test]
fn misses_rigid_motions_and_degenerate_cases() {
    let x = tri_with(v(0.2, 0.2, 1.0));
    // Moving parallel to the plane, far above: the full step.
    let dx = [v(3.0, 0.0, 0.0), DVec3::ZERO, DVec3::ZERO, DVec3::ZERO];
    assert_eq!(
        additive_ccd(PairKind::PointTriangle, &x, &dx, 0.0, KEEP),
        1.0
    );
    // Everything translating together, however fast: no relative motion.
    let dx = [v(0.0, 0.0, -50.0); 4];
    assert_eq!(
        additive_ccd(PairKind::PointTriangle, &x, &dx, 0.0, KEEP),
        1.0
    );
    // No motion.
    assert_eq!(
        additive_ccd(PairKind::PointTriangle, &x, &[DVec3::ZERO; 4], 0.0, KEEP),
        1.0
    );
    // Moving away.
    let dx = [v(0.0, 0.0, 5.0), DVec3::ZERO, DVec3::ZERO, DVec3::ZERO];
    assert_eq!(
        additive_ccd(PairKind::PointTriangle, &x, &dx, 0.0, KEEP),
        1.0
    );
    // Already touching: nothing may move.
    let touching = tri_with(v(0.2, 0.2, 0.0));
    let dx = [v(0.0, 0.0, 1.0), DVec3::ZERO, DVec3::ZERO, DVec3::ZERO];
    assert_eq!(
        additive_ccd(PairKind::PointTriangle, &touching, &dx, 0.0, KEEP),
        0.0
    );
    // Within the thickness: the gap is negative, nothing may move.
    assert_eq!(
        additive_ccd(PairKind::PointTriangle, &x, &dx, 2.0, KEEP),
        0.0
    );
    // Parallel edges sliding along each other and closing: impact at t = 1/2.
    let x = [
        v(0.0, 0.0, 0.0),
        v(1.0, 0.0, 0.0),
        v(0.5, 0.0, 1.0),
        v(1.5, 0.0, 1.0),
    ];
    let dx = [
        DVec3::ZERO,
        DVec3::ZERO,
        v(-1.0, 0.0, -2.0),
        v(-1.0, 0.0, -2.0),
    ];
    let t = additive_ccd(PairKind::EdgeEdge, &x, &dx, 0.0, KEEP);
    assert!(t > 0.0 && t < 0.5, "{t}");
    assert!(gap(PairKind::EdgeEdge, &x, &dx, t, 0.0) >= KEEP * (1.0 - 1e-12));
}

#[test]
fn grazing_motions_stay_positive() {
    // A point sliding over the face at a tiny height: the gap never falls, but the bound
    // cannot know that, so ACCD creeps (and stops at its iteration cap): whatever it
    // returns keeps the gap.
    let x = tri_with(v(0.1, 0.2, 1e-6));
    let dx = [v(0.5, 0.0, 0.0), DVec3::ZERO, DVec3::ZERO, DVec3::ZERO];
    let t = additive_ccd(PairKind::PointTriangle, &x, &dx, 0.0, KEEP);
    assert!(t > 0.0, "{t}");
    assert!(gap(PairKind::PointTriangle, &x, &dx, t, 0.0) > 0.0);
    // A point passing just over a vertex, the closest approach 1e-3 from it.
    let x = tri_with(v(-1.0, -1.0, 1e-3));
    let dx = [v(2.0, 2.0, 0.0), DVec3::ZERO, DVec3::ZERO, DVec3::ZERO];
    let t = additive_ccd(PairKind::PointTriangle, &x, &dx, 0.0, KEEP);
    assert!(t > 0.0 && t < 1.0, "{t}");
    assert!(gap(PairKind::PointTriangle, &x, &dx, t, 0.0) > 0.0);
}

/// No zero of the gap on `[0, t]`: samples `n` points and requires each sample's gap to
/// exceed how far the gap can fall within half a sample interval (`lp dt / 2`, `lp`
/// bounded here by the sum of the largest displacements, which is at least ACCD's bound).
fn assert_no_crossing(kind: PairKind, x: &[DVec3; 4], dx: &[DVec3; 4], t: f64, thickness: f64) {
    let lp = 2.0 * dx.iter().map(|d| d.length()).fold(0.0, f64::max);
    let n = 4000;
    let dt = t / n as f64;
    for i in 0..=n {
        let g = gap(kind, x, dx, i as f64 * dt, thickness);
        assert!(
            g > 0.5 * lp * dt,
            "{kind:?} {x:?} {dx:?}: gap {g} at {} of the returned {t}",
            i as f64 * dt
        );
    }
}

#[test]
fn moving_by_the_returned_fraction_never_crosses_on_random_pairs() {
    let mut rng = Rng(0x51ed_2701);
    let mut stopped = 0;
    for case in 0..400 {
        let kind = if case % 2 == 0 {
            PairKind::PointTriangle
        } else {
            PairKind::EdgeEdge
        };
        let x: [DVec3; 4] = std::array::from_fn(|_| rng.vec(1.0));
        // The first primitive is thrown at the second (twice their centres' offset, so
        // most cases would collide), with some random motion of every vertex on top.
        let first = if kind == PairKind::PointTriangle {
            1
        } else {
            2
        };
        let centre = |r: std::ops::Range<usize>| {
            let n = r.len() as f64;
            r.map(|k| x[k]).fold(DVec3::ZERO, |a, b| a + b) / n
        };
        let throw = 2.0 * (centre(first..4) - centre(0..first));
        let dx: [DVec3; 4] = std::array::from_fn(|k| {
            let noise = rng.vec(0.5);
            if k < first { throw + noise } else { noise }
        });
        let thickness = if case % 3 == 0 { 0.01 } else { 0.0 };
        if gap(kind, &x, &dx, 0.0, thickness) < 0.05 {
            continue;
        }
        let t = additive_ccd(kind, &x, &dx, thickness, KEEP);
        assert!((0.0..=1.0).contains(&t));
        assert_no_crossing(kind, &x, &dx, t, thickness);
        if t < 1.0 {
            stopped += 1;
            let g0 = gap(kind, &x, &dx, 0.0, thickness);
            assert!(gap(kind, &x, &dx, t, thickness) >= KEEP * g0 * (1.0 - 1e-9));
        }
    }
    // Many of the random motions do come close: the property is exercised.
    assert!(stopped > 150, "only {stopped} cases stopped early");
}

#[test]
fn a_sweep_the_separation_clears_is_one_the_exact_ccd_clears_too() {
    // Random pairs, a second primitive offset by up to 2, steps from 1e-3 to 1 of the
    // pairs' size, thicknesses 0 and 0.05: whenever the separation shows the sweep clear, the
    // exact ACCD returns the whole step, bit for bit 1.
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    let (mut clear, mut cases) = (0, 0);
    for _ in 0..20_000 {
        let offset = rng.vec(2.0);
        // The point (or first edge) near the origin, the triangle (or second edge) offset.
        let x: [DVec3; 4] = std::array::from_fn(|k| {
            let near_origin = k == 0;
            rng.vec(0.5) + if near_origin { DVec3::ZERO } else { offset }
        });
        let size = 10f64.powf(-3.0 * rng.next());
        let dx: [DVec3; 4] = std::array::from_fn(|_| rng.vec(size));
        for kind in [PairKind::PointTriangle, PairKind::EdgeEdge] {
            for thickness in [0.0, 0.05] {
                cases += 1;
                if clear_without_distance(kind, &x, &dx, thickness, KEEP) {
                    clear += 1;
                    let t = additive_ccd(kind, &x, &dx, thickness, KEEP);
                    assert_eq!(t, 1.0, "{kind:?} {x:?} {dx:?} {thickness}");
                }
            }
        }
    }
    // The test is not vacuous: most of these far pairs are shown clear.
    assert!(clear > cases / 4, "{clear} of {cases}");
    // A pair already within the thickness, or a motion that is not finite, is never clear.
    let x = tri_with(v(0.2, 0.2, 0.01));
    let still = [DVec3::ZERO; 4];
    assert!(!clear_without_distance(
        PairKind::PointTriangle,
        &x,
        &still,
        0.02,
        KEEP
    ));
    let x = tri_with(v(0.2, 0.2, 1.0));
    let wild = [v(f64::NAN, 0.0, 0.0), DVec3::ZERO, DVec3::ZERO, DVec3::ZERO];
    assert!(!clear_without_distance(
        PairKind::PointTriangle,
        &x,
        &wild,
        0.0,
        KEEP
    ));
    let far = [
        v(f64::INFINITY, 0.0, 0.0),
        DVec3::ZERO,
        DVec3::ZERO,
        DVec3::ZERO,
    ];
    assert!(!clear_without_distance(
        PairKind::PointTriangle,
        &far,
        &still,
        0.0,
        KEEP
    ));
}

/// A sweep limited to the smallest fraction found so far returns the smaller of its
/// whole-sweep answer and the limit, so the smallest fraction over a
/// set of pairs is the same bits whatever the order they are swept in: checked on random
/// sets of pairs thrown at each other, swept forwards and backwards with the running
/// minimum as the limit, against the minimum of the whole sweeps.
#[test]
fn limited_sweeps_give_the_same_smallest_fraction_in_any_order() {
    let mut rng = Rng(0x0dd_c0de);
    let mut limited_below_whole = 0;
    for set in 0..200 {
        let pairs: Vec<(PairKind, [DVec3; 4], [DVec3; 4])> = (0..8)
            .map(|i| {
                let kind = if (set + i) % 2 == 0 {
                    PairKind::PointTriangle
                } else {
                    PairKind::EdgeEdge
                };
                let x: [DVec3; 4] = std::array::from_fn(|_| rng.vec(1.0));
                let throw = rng.vec(3.0);
                let dx: [DVec3; 4] = std::array::from_fn(|k| {
                    let noise = rng.vec(0.5);
                    if k == 0 { throw + noise } else { noise }
                });
                (kind, x, dx)
            })
            .filter(|(kind, x, dx)| gap(*kind, x, dx, 0.0, 0.0) > 0.05)
            .collect();
        let whole: Vec<f64> = pairs
            .iter()
            .map(|(kind, x, dx)| additive_ccd(*kind, x, dx, 0.0, KEEP))
            .collect();
        let smallest = whole.iter().copied().fold(1.0, f64::min);
        for order in [false, true] {
            let mut limit = 1.0f64;
            for i in 0..pairs.len() {
                let k = if order { pairs.len() - 1 - i } else { i };
                let (kind, x, dx) = &pairs[k];
                let gap0 = gap(*kind, x, dx, 0.0, 0.0);
                let t = additive_ccd_within(*kind, x, dx, 0.0, KEEP, gap0, limit);
                assert_eq!(
                    t.to_bits(),
                    whole[k].min(limit).to_bits(),
                    "set {set} pair {k}: {t} {limit} {}",
                    whole[k]
                );
                limited_below_whole += usize::from(t < whole[k]);
                limit = limit.min(t);
            }
            assert_eq!(limit.to_bits(), smallest.to_bits(), "set {set}");
        }
    }
    // Many answers are the limit, below the whole sweep's: the property is exercised.
    assert!(limited_below_whole > 50, "{limited_below_whole}");
}
