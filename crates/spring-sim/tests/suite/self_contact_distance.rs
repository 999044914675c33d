//! Self-contact distances: hand-computed point-triangle and edge-edge cases in every
//! region (parallel edges included), the chosen region against a brute-force minimum,
//! the exact gradients and Hessians of the dual numbers against finite differences, the
//! mollifier, and the 12x12 PSD projection.

use crate::common::{Sample, Xorshift as Rng};
use sinew_math::DVec3;
use sinew_spring_sim::contact::self_contact::distance::{
    Closest, PairKind, beyond, edge_edge_closest, mollifier, mollifier_derivatives,
    mollifier_gradient, point_triangle_closest, separation, squared_distance,
    squared_distance_derivatives, squared_distance_gradient, squared_distance_in,
};
use sinew_spring_sim::contact::self_contact::dual::{Scalar, values};
use sinew_spring_sim::contact::self_contact::psd12::{
    project_psd12, project_psd12_pair, symmetric_eigen12,
};

fn v(x: f64, y: f64, z: f64) -> DVec3 {
    DVec3::new(x, y, z)
}

const TRI: [DVec3; 3] = [
    DVec3::new(0.0, 0.0, 0.0),
    DVec3::new(1.0, 0.0, 0.0),
    DVec3::new(0.0, 1.0, 0.0),
];

fn pt(p: DVec3) -> [DVec3; 4] {
    [p, TRI[0], TRI[1], TRI[2]]
}

#[test]
fn point_triangle_every_region_by_hand() {
    let cases = [
        (v(0.2, 0.2, 0.5), 0.25, Closest::PointPlane([0, 1, 2, 3])),
        (v(0.5, -1.0, 1.0), 2.0, Closest::PointEdge([0, 1, 2])),
        (v(1.0, 1.0, 0.0), 0.5, Closest::PointEdge([0, 2, 3])),
        (v(-2.0, 0.5, 0.0), 4.0, Closest::PointEdge([0, 3, 1])),
        (v(-1.0, -1.0, 1.0), 3.0, Closest::PointPoint([0, 1])),
        (v(2.0, -1.0, 0.0), 2.0, Closest::PointPoint([0, 2])),
        (v(-1.0, 3.0, 0.0), 5.0, Closest::PointPoint([0, 3])),
        // In the plane, inside: distance zero, face region.
        (v(0.25, 0.25, 0.0), 0.0, Closest::PointPlane([0, 1, 2, 3])),
    ];
    for (p, want, region) in cases {
        let pair = pt(p);
        assert_eq!(point_triangle_closest(&pair), region, "point {p}");
        let got = squared_distance(PairKind::PointTriangle, &pair);
        assert!((got - want).abs() < 1e-15, "point {p}: {got} vs {want}");
    }
}

#[test]
fn edge_edge_every_region_by_hand() {
    let cases = [
        // Crossing interiors one unit apart.
        (
            [
                v(-1.0, 0.0, 0.0),
                v(1.0, 0.0, 0.0),
                v(0.0, -1.0, 1.0),
                v(0.0, 1.0, 1.0),
            ],
            1.0,
            Some(Closest::LineLine([0, 1, 2, 3])),
        ),
        // a0 against the interior of b.
        (
            [
                v(0.0, 0.0, 0.0),
                v(1.0, 0.0, 0.0),
                v(-1.0, -1.0, 2.0),
                v(-1.0, 1.0, 2.0),
            ],
            5.0,
            Some(Closest::PointEdge([0, 2, 3])),
        ),
        // b1 against the interior of a.
        (
            [
                v(0.0, 0.0, 0.0),
                v(4.0, 0.0, 0.0),
                v(2.0, 5.0, 3.0),
                v(2.0, 1.0, 1.0),
            ],
            2.0,
            Some(Closest::PointEdge([3, 0, 1])),
        ),
        // Endpoints a1 and b0.
        (
            [
                v(0.0, 0.0, 0.0),
                v(1.0, 0.0, 0.0),
                v(2.0, 1.0, 0.0),
                v(3.0, 5.0, 0.0),
            ],
            2.0,
            Some(Closest::PointPoint([1, 2])),
        ),
        // Parallel and overlapping: a whole interval is closest; any endpoint form gives 1.
        (
            [
                v(0.0, 0.0, 0.0),
                v(1.0, 0.0, 0.0),
                v(0.5, 1.0, 0.0),
                v(2.0, 1.0, 0.0),
            ],
            1.0,
            None,
        ),
        // Parallel, antiparallel direction, overlapping.
        (
            [
                v(0.0, 0.0, 0.0),
                v(1.0, 0.0, 0.0),
                v(0.75, 0.0, 2.0),
                v(0.25, 0.0, 2.0),
            ],
            4.0,
            None,
        ),
        // Parallel, disjoint along the line: endpoints a1 and b0.
        (
            [
                v(0.0, 0.0, 0.0),
                v(1.0, 0.0, 0.0),
                v(3.0, 1.0, 0.0),
                v(4.0, 1.0, 0.0),
            ],
            5.0,
            Some(Closest::PointPoint([1, 2])),
        ),
        // Collinear, disjoint.
        (
            [
                v(0.0, 0.0, 0.0),
                v(1.0, 0.0, 0.0),
                v(1.5, 0.0, 0.0),
                v(3.0, 0.0, 0.0),
            ],
            0.25,
            Some(Closest::PointPoint([1, 2])),
        ),
    ];
    for (pair, want, region) in cases {
        let got = squared_distance(PairKind::EdgeEdge, &pair);
        assert!((got - want).abs() < 1e-14, "{pair:?}: {got} vs {want}");
        let closest = edge_edge_closest(&pair);
        if let Some(region) = region {
            assert_eq!(closest, region, "{pair:?}");
        } else {
            assert!(!matches!(closest, Closest::LineLine(_)), "{pair:?}");
        }
    }
}

#[test]
fn nearly_parallel_edges_keep_their_distance() {
    // Edges one unit apart, turned out of parallel by angles down to 1e-12: the distance
    // stays 1 to round-off on both sides of the parallel threshold.
    for k in 0..12 {
        let tilt = 10f64.powi(-k);
        let pair = [
            v(0.0, 0.0, 0.0),
            v(1.0, 0.0, 0.0),
            v(0.25, 1.0, -0.5 * tilt),
            v(0.75, 1.0, 0.5 * tilt),
        ];
        let d2 = squared_distance(PairKind::EdgeEdge, &pair);
        // The exact distance: the lines cross x = 0.5 at z = 0 (crossing interiors) for
        // every tilt, so it is exactly 1.
        assert!((d2 - 1.0).abs() < 1e-12, "tilt {tilt}: {d2}");
    }
}

/// The smallest squared distance between points sampled on the two primitives (an upper
/// bound of the exact one, within the sampling's resolution of it).
fn sampled(kind: PairKind, pair: &[DVec3; 4], n: usize) -> f64 {
    let mut best = f64::INFINITY;
    match kind {
        PairKind::PointTriangle => {
            for i in 0..=n {
                for j in 0..=n - i {
                    let (a, b) = (i as f64 / n as f64, j as f64 / n as f64);
                    let q = pair[1] + a * (pair[2] - pair[1]) + b * (pair[3] - pair[1]);
                    best = best.min((q - pair[0]).length_squared());
                }
            }
        }
        PairKind::EdgeEdge => {
            for i in 0..=n {
                for j in 0..=n {
                    let (s, t) = (i as f64 / n as f64, j as f64 / n as f64);
                    let a = pair[0].lerp(pair[1], s);
                    let b = pair[2].lerp(pair[3], t);
                    best = best.min((a - b).length_squared());
                }
            }
        }
    }
    best
}

#[test]
fn the_chosen_region_gives_the_true_minimum_on_random_pairs() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for case in 0..300 {
        let pair: [DVec3; 4] = std::array::from_fn(|_| rng.vec(1.0));
        for kind in [PairKind::PointTriangle, PairKind::EdgeEdge] {
            let d2 = squared_distance(kind, &pair);
            let s = sampled(kind, &pair, 200);
            // The exact minimum is below every sample and within the sampling's
            // resolution of the best one (a point is at most diameter/200 from a sample).
            let diameter = pair
                .iter()
                .flat_map(|a| pair.iter().map(move |b| (*a - *b).length()))
                .fold(0.0, f64::max);
            let slack = diameter / 200.0;
            assert!(d2 <= s + 1e-12, "case {case} {kind:?}: {d2} > sampled {s}");
            assert!(
                d2.sqrt() >= s.sqrt() - slack,
                "case {case} {kind:?}: {d2} well below sampled {s}"
            );
        }
    }
}

/// Random pairs whose region is `want` with the kind `kind` (rejection sampling).
fn pairs_in(
    kind: PairKind,
    want: fn(&Closest) -> bool,
    count: usize,
    seed: u64,
) -> Vec<[DVec3; 4]> {
    let mut rng = Rng(seed);
    let mut out = Vec::new();
    while out.len() < count {
        let pair: [DVec3; 4] = std::array::from_fn(|_| rng.vec(1.0));
        if want(&kind.closest(&pair)) {
            out.push(pair);
        }
    }
    out
}

fn perturbed(pair: &[DVec3; 4], var: usize, delta: f64) -> [DVec3; 4] {
    let mut out = *pair;
    out[var / 3][var % 3] += delta;
    out
}

/// Checks the dual gradient against central differences of the value and the dual Hessian
/// against central differences of the dual gradient, in the pair's region.
fn check_derivatives(kind: PairKind, pair: &[DVec3; 4]) {
    let closest = kind.closest(pair);
    let f = |q: &[DVec3; 4]| squared_distance_in(&values(q), closest);
    let dual = squared_distance_derivatives(kind, pair);
    assert!((dual.value - f(pair)).abs() <= 1e-14 * (1.0 + dual.value));
    let h = 1e-6;
    let scale = 1.0 + dual.gradient.iter().fold(0.0f64, |m, g| m.max(g.abs()));
    for i in 0..12 {
        let fd = (f(&perturbed(pair, i, h)) - f(&perturbed(pair, i, -h))) / (2.0 * h);
        assert!(
            (fd - dual.gradient[i]).abs() < 1e-6 * scale,
            "{closest:?} gradient {i}: {} vs {fd}",
            dual.gradient[i]
        );
        let plus = squared_distance_in(
            &sinew_spring_sim::contact::self_contact::dual::variables(&perturbed(pair, i, h)),
            closest,
        );
        let minus = squared_distance_in(
            &sinew_spring_sim::contact::self_contact::dual::variables(&perturbed(pair, i, -h)),
            closest,
        );
        let hscale = 1.0
            + dual
                .hessian
                .iter()
                .flatten()
                .fold(0.0f64, |m, x| m.max(x.abs()));
        for j in 0..12 {
            let fd = (plus.gradient[j] - minus.gradient[j]) / (2.0 * h);
            assert!(
                (fd - dual.hessian[i][j]).abs() < 1e-5 * hscale,
                "{closest:?} hessian {i},{j}: {} vs {fd}",
                dual.hessian[i][j]
            );
            assert_eq!(dual.hessian[i][j], dual.hessian[j][i]);
        }
    }
}

/// Whether a region is the one a case wants.
type RegionTest = fn(&Closest) -> bool;

#[test]
fn gradients_and_hessians_match_finite_differences_in_every_region() {
    let regions: [(PairKind, RegionTest); 7] = [
        (PairKind::PointTriangle, |c| {
            matches!(c, Closest::PointPlane(_))
        }),
        (PairKind::PointTriangle, |c| {
            matches!(c, Closest::PointEdge(_))
        }),
        (PairKind::PointTriangle, |c| {
            matches!(c, Closest::PointPoint(_))
        }),
        (PairKind::EdgeEdge, |c| matches!(c, Closest::LineLine(_))),
        (PairKind::EdgeEdge, |c| matches!(c, Closest::PointEdge(_))),
        (PairKind::EdgeEdge, |c| matches!(c, Closest::PointPoint(_))),
        (PairKind::EdgeEdge, |_| true),
    ];
    for (r, (kind, want)) in regions.iter().enumerate() {
        for pair in pairs_in(*kind, *want, 20, 1 + r as u64) {
            check_derivatives(*kind, &pair);
        }
    }
}

/// The same bits in `f64`s, so `-0.0` and `0.0` differ and a NaN fails.
fn bits(values: &[f64]) -> Vec<u64> {
    values.iter().map(|v| v.to_bits()).collect()
}

#[test]
fn the_first_order_duals_give_the_second_order_ones_value_and_gradient_bit_for_bit() {
    let mut checked = 0;
    for (seed, kind) in [PairKind::PointTriangle, PairKind::EdgeEdge]
        .into_iter()
        .enumerate()
    {
        for pair in pairs_in(kind, |_| true, 200, 40 + seed as u64) {
            let full = squared_distance_derivatives(kind, &pair);
            let first = squared_distance_gradient(kind, &pair);
            assert_eq!(first.value.to_bits(), full.value.to_bits());
            assert_eq!(
                bits(&first.gradient),
                bits(&full.gradient),
                "{kind:?} {pair:?}"
            );
            checked += 1;
        }
    }
    // The mollifier below its threshold (every random pair of edges is, at 100), where
    // its derivatives are not constant.
    let mut rng = Rng(47);
    for _ in 0..200 {
        let pair: [DVec3; 4] = std::array::from_fn(|_| rng.vec(1.0));
        let full = mollifier_derivatives(&pair, 100.0);
        let first = mollifier_gradient(&pair, 100.0);
        assert!(full.value < 1.0 && full.gradient.iter().any(|g| *g != 0.0));
        assert_eq!(first.value.to_bits(), full.value.to_bits());
        assert_eq!(bits(&first.gradient), bits(&full.gradient), "{pair:?}");
        checked += 1;
    }
    assert_eq!(checked, 600);
}

#[test]
fn the_mollifier_vanishes_for_parallel_edges_and_is_one_beyond_its_threshold() {
    let parallel = [
        v(0.0, 0.0, 0.0),
        v(1.0, 0.0, 0.0),
        v(0.0, 1.0, 0.0),
        v(2.0, 1.0, 0.0),
    ];
    assert_eq!(mollifier(&parallel, 1e-3), 0.0);
    let crossing = [
        v(0.0, 0.0, 0.0),
        v(1.0, 0.0, 0.0),
        v(0.0, 1.0, 0.0),
        v(0.0, 1.0, 1.0),
    ];
    // |e_a x e_b|^2 = 1 >= eps_x.
    assert_eq!(mollifier(&crossing, 0.5), 1.0);
    // Tilted: e_a = x, e_b = (1, 0, s), |e_a x e_b|^2 = s^2; with eps_x = 1e-2 and
    // s = 0.05, x = 0.25 and m = (2 - 0.25) 0.25 = 0.4375.
    let tilted = [
        v(0.0, 0.0, 0.0),
        v(1.0, 0.0, 0.0),
        v(0.0, 1.0, 0.0),
        v(1.0, 1.0, 0.05),
    ];
    assert!((mollifier(&tilted, 1e-2) - 0.4375).abs() < 1e-15);
    // Derivatives against finite differences below the threshold.
    let dual = mollifier_derivatives(&tilted, 1e-2);
    let h = 1e-7;
    for i in 0..12 {
        let fd = (mollifier(&perturbed(&tilted, i, h), 1e-2)
            - mollifier(&perturbed(&tilted, i, -h), 1e-2))
            / (2.0 * h);
        assert!(
            (fd - dual.gradient[i]).abs() < 1e-6,
            "{i}: {fd} vs {}",
            dual.gradient[i]
        );
        let plus = mollifier_derivatives(&perturbed(&tilted, i, h), 1e-2);
        let minus = mollifier_derivatives(&perturbed(&tilted, i, -h), 1e-2);
        for j in 0..12 {
            let fd = (plus.gradient[j] - minus.gradient[j]) / (2.0 * h);
            assert!((fd - dual.hessian[i][j]).abs() < 1e-4, "{i},{j}");
        }
    }
}

/// A barrier-like energy of a pair, `m(x) b(d)` with `b(d) = -ln(d)` of the squared
/// distance's root, so its Hessian has negative eigenvalues where `b' < 0` bends it and
/// (for edges below `eps_x`) the mollifier's over all twelve coordinates.
fn pair_energy_hessian(kind: PairKind, pair: &[DVec3; 4], eps_x: Option<f64>) -> [[f64; 12]; 12] {
    let d = squared_distance_derivatives(kind, pair).sqrt();
    let b = d.chain(-d.value.ln(), -1.0 / d.value, 1.0 / (d.value * d.value));
    match eps_x {
        Some(eps) => (mollifier_derivatives(pair, eps) * b).hessian,
        None => b.hessian,
    }
}

// Index loops read as the matrix formulas.
#[allow(clippy::needless_range_loop)]
#[test]
fn a_pairs_hessian_projected_in_the_nine_directions_beside_translation_is_the_full_projection() {
    let mut indefinite = 0;
    let mut reduced = 0;
    for (seed, kind, eps_x) in [
        (61, PairKind::EdgeEdge, Some(100.0)),
        (62, PairKind::EdgeEdge, None),
        (63, PairKind::PointTriangle, None),
    ] {
        for pair in pairs_in(kind, |_| true, 100, seed) {
            let m = pair_energy_hessian(kind, &pair, eps_x);
            let full = project_psd12(&m);
            let nine = project_psd12_pair(&m);
            let every_row = m.iter().all(|row| row.iter().any(|&x| x != 0.0));
            let scale = m.iter().flatten().fold(0.0f64, |a, x| a.max(x.abs()));
            for i in 0..12 {
                for j in 0..12 {
                    assert!(
                        (nine[i][j] - full[i][j]).abs() <= 1e-10 * scale,
                        "{kind:?} {i},{j}: {} against {}",
                        nine[i][j],
                        full[i][j]
                    );
                    if every_row {
                        assert_eq!(nine[i][j].to_bits(), nine[j][i].to_bits());
                    }
                }
            }
            // A common translation of the four vertices is in the result's null space.
            for c in 0..3 {
                for i in 0..12 {
                    let row: f64 = (0..4).map(|k| nine[i][3 * k + c]).sum();
                    assert!(row.abs() <= 1e-12 * scale, "{row}");
                }
            }
            let (values, _) = symmetric_eigen12(&m);
            indefinite += usize::from(values.iter().any(|&v| v < -1e-9 * scale));
            reduced += usize::from(every_row);
        }
    }
    // The cases are not vacuous: every Hessian is indefinite, and more than half have
    // every row (the nine-direction path, not the fallback for a vertex left out).
    assert!(indefinite == 300 && reduced > 150, "{indefinite} {reduced}");
}

// Index loops read as the matrix formulas.
#[allow(clippy::needless_range_loop)]
#[test]
fn the_12x12_projection_keeps_psd_matrices_and_clamps_negative_eigenvalues() {
    let mut rng = Rng(77);
    for _ in 0..20 {
        let mut m = [[0.0; 12]; 12];
        for i in 0..12 {
            for j in 0..=i {
                let x = 2.0 * rng.next() - 1.0;
                m[i][j] = x;
                m[j][i] = x;
            }
        }
        let (values, vectors) = symmetric_eigen12(&m);
        // V diag(values) V^T reconstructs m, and V is orthonormal.
        for i in 0..12 {
            for j in 0..12 {
                let r: f64 = (0..12)
                    .map(|k| vectors[i][k] * values[k] * vectors[j][k])
                    .sum();
                assert!((r - m[i][j]).abs() < 1e-12);
                let o: f64 = (0..12).map(|k| vectors[k][i] * vectors[k][j]).sum();
                assert!((o - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        let p = project_psd12(&m);
        let (pv, _) = symmetric_eigen12(&p);
        for (k, &lambda) in pv.iter().enumerate() {
            assert!(lambda > -1e-12, "eigenvalue {k}: {lambda}");
        }
        // Its positive eigenvalues are m's: the traces agree.
        let positive: f64 = values.iter().filter(|&&x| x > 0.0).sum();
        let trace: f64 = (0..12).map(|i| p[i][i]).sum();
        assert!((positive - trace).abs() < 1e-11);
        // A PSD matrix (m m^T) is unchanged.
        let mut g = [[0.0; 12]; 12];
        for i in 0..12 {
            for j in 0..12 {
                g[i][j] = (0..12).map(|k| m[i][k] * m[j][k]).sum();
            }
        }
        let q = project_psd12(&g);
        for i in 0..12 {
            for j in 0..12 {
                assert!((q[i][j] - g[i][j]).abs() < 1e-11);
            }
        }
    }
}

#[test]
fn the_separation_bounds_the_distance_from_below_and_beyond_agrees_with_it() {
    // By hand: a point beyond a triangle's corner, on the line through the centroid; a
    // sheet's neighbours that share no vertex (the corner a right triangle lacks, two
    // edges of a row apart), whose boxes meet; crossing edges, whose centroid line is
    // their common normal.
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-15;
    let corner = pt(v(1.0, 1.0, 0.0));
    let d = squared_distance(PairKind::PointTriangle, &corner).sqrt();
    assert!(close(d, 0.5f64.sqrt()));
    assert!(close(separation(PairKind::PointTriangle, &corner), d));
    let rows = [
        v(0.0, 0.0, 0.0),
        v(1.0, 0.0, 0.0),
        v(0.0, 0.0, 1.0),
        v(1.0, 0.0, 1.0),
    ];
    assert!(close(separation(PairKind::EdgeEdge, &rows), 1.0));
    let crossing = [
        v(-1.0, 0.0, 0.0),
        v(1.0, 0.0, 0.0),
        v(0.0, -1.0, 0.5),
        v(0.0, 1.0, 0.5),
    ];
    assert!(close(separation(PairKind::EdgeEdge, &crossing), 0.5));
    // Overlapping projections give 0, not a negative bound.
    let through = pt(v(0.2, 0.2, 0.0));
    assert_eq!(separation(PairKind::PointTriangle, &through), 0.0);
    // Random pairs at scales 1e-4 to 1, the second primitive offset, nearly parallel edges
    // among them: the separation never exceeds the distance, and `beyond` at reaches
    // around the distance holds only where the exact distance reaches too.
    let mut rng = Rng(0x853c_49e6_748f_ea9b);
    let (mut shown, mut cases) = (0, 0);
    for case in 0..20_000 {
        let scale = 10f64.powf(-4.0 * rng.next());
        let offset = rng.vec(3.0 * scale);
        let mut pair: [DVec3; 4] = std::array::from_fn(|_| rng.vec(scale));
        if case % 4 == 3 {
            // The second edge the first one moved by `offset` and turned by 1e-9 to 1e-5.
            let turn = 10f64.powf(-9.0 + 4.0 * rng.next()) * scale;
            pair[2] = pair[0] + offset;
            pair[3] = pair[1] + offset + rng.vec(turn);
        } else {
            pair[1] += offset;
            pair[2] += offset;
            pair[3] += offset;
        }
        for kind in [PairKind::PointTriangle, PairKind::EdgeEdge] {
            let d = squared_distance(kind, &pair).sqrt();
            let s = separation(kind, &pair);
            assert!(
                (0.0..=d * (1.0 + 1e-12)).contains(&s),
                "case {case} {kind:?}: separation {s} against distance {d}"
            );
            for ratio in [0.5, 0.9, 0.999, 0.9999, 0.99999, 1.0, 1.00001] {
                let reach = ratio * d;
                cases += 1;
                if beyond(kind, &pair, reach) {
                    shown += 1;
                    assert!(d >= reach, "case {case} {kind:?}: {d} within {reach}");
                }
            }
        }
    }
    assert!(shown > cases / 10, "{shown} of {cases}");
    // A coordinate that is not finite gives NaN, and no pair is then beyond anything.
    let mut pair = pt(v(5.0, 5.0, 5.0));
    pair[2] = v(f64::NAN, 0.0, 0.0);
    assert!(separation(PairKind::PointTriangle, &pair).is_nan());
    assert!(!beyond(PairKind::PointTriangle, &pair, 1e-3));
    pair[2] = v(f64::INFINITY, 0.0, 0.0);
    assert!(!beyond(PairKind::PointTriangle, &pair, 1e-3));
}
