//! The closed-form squared distances of self-contact ([`RegionForm`]) against the dual
//! numbers (value, gradient, Hessian) and against central differences, in every region of
//! both pair kinds; and the projection in the Hessian's span against the full 12x12
//! Jacobi projection of the same matrix, with its eigenvalues checked non-negative; the
//! exact barrier Hessian in the span against the dual numbers and against central
//! differences of the barrier's gradient (the region chosen afresh at every state); and
//! the Jacobi rotations (which update the two rows a rotation changes and mirror them)
//! against the textbook update of the whole matrix, bit for bit; and that the
//! projected and exact Hessians decline the same pairs.

// Index loops over rows and columns read as the matrix comparisons they are.
#![allow(clippy::needless_range_loop)]

use crate::common::{Sample, Xorshift as Rng};
use sinew_math::DVec3;
use sinew_spring_sim::contact::barrier::{barrier_first_derivative, barrier_second_derivative};
use sinew_spring_sim::contact::self_contact::RegionForm;
use sinew_spring_sim::contact::self_contact::distance::{
    Closest, PairKind, squared_distance_derivatives,
};
use sinew_spring_sim::contact::self_contact::psd12::{
    Mat12, project_psd12, symmetric_eigen_n, symmetric_eigen12,
};

type RegionTest = fn(&Closest) -> bool;

/// Every region of both kinds, with a name for the messages.
fn regions() -> [(&'static str, PairKind, RegionTest); 6] {
    [
        ("pt plane", PairKind::PointTriangle, |c| {
            matches!(c, Closest::PointPlane(_))
        }),
        ("pt edge", PairKind::PointTriangle, |c| {
            matches!(c, Closest::PointEdge(_))
        }),
        ("pt point", PairKind::PointTriangle, |c| {
            matches!(c, Closest::PointPoint(_))
        }),
        ("ee line", PairKind::EdgeEdge, |c| {
            matches!(c, Closest::LineLine(_))
        }),
        ("ee edge", PairKind::EdgeEdge, |c| {
            matches!(c, Closest::PointEdge(_))
        }),
        ("ee point", PairKind::EdgeEdge, |c| {
            matches!(c, Closest::PointPoint(_))
        }),
    ]
}

/// Random pairs of `kind` in the region `want` (rejection sampling), some of them with
/// the second primitive moved close to the first (the barrier acts at small distances).
fn pairs_in(kind: PairKind, want: RegionTest, count: usize, seed: u64) -> Vec<[DVec3; 4]> {
    let mut rng = Rng(seed);
    let mut out = Vec::new();
    while out.len() < count {
        let mut pair: [DVec3; 4] = std::array::from_fn(|_| rng.vec(1.0));
        if out.len() % 2 == 1 {
            // Move the first primitive along the vector between the closest points until
            // the two are 1e-3 apart (the region stays the same: only the distance along
            // that vector changes).
            let d = RegionForm::of(kind, &pair).r;
            let len = d.length();
            if len > 0.0 {
                let shift = d * ((1e-3 - len) / len);
                match kind {
                    PairKind::PointTriangle => pair[0] += shift,
                    PairKind::EdgeEdge => {
                        pair[0] += shift;
                        pair[1] += shift;
                    }
                }
            }
        }
        if want(&kind.closest(&pair)) && RegionForm::of(kind, &pair).value() > 0.0 {
            out.push(pair);
        }
    }
    out
}

fn max_abs(m: &Mat12) -> f64 {
    m.iter().flatten().fold(0.0f64, |a, x| a.max(x.abs()))
}

fn perturbed(pair: &[DVec3; 4], var: usize, delta: f64) -> [DVec3; 4] {
    let mut out = *pair;
    out[var / 3][var % 3] += delta;
    out
}

#[test]
fn closed_forms_equal_the_dual_numbers_in_every_region() {
    for (r, (name, kind, want)) in regions().into_iter().enumerate() {
        for pair in pairs_in(kind, want, 40, 11 + r as u64) {
            let closed = RegionForm::of(kind, &pair);
            let dual = squared_distance_derivatives(kind, &pair);
            let value = closed.value();
            assert!(
                (value - dual.value).abs() <= 1e-12 * dual.value.max(1e-300),
                "{name}: value {value} vs {}",
                dual.value
            );
            let g = closed.gradient();
            let gscale = dual.gradient.iter().fold(0.0f64, |a, x| a.max(x.abs()));
            for i in 0..12 {
                assert!(
                    (g[i] - dual.gradient[i]).abs() <= 1e-9 * gscale,
                    "{name}: gradient {i}: {} vs {}",
                    g[i],
                    dual.gradient[i]
                );
            }
            let h = closed.hessian();
            let hscale = max_abs(&dual.hessian);
            for i in 0..12 {
                for j in 0..12 {
                    assert!(
                        (h[i][j] - dual.hessian[i][j]).abs() <= 1e-8 * hscale,
                        "{name}: hessian {i},{j}: {} vs {}",
                        h[i][j],
                        dual.hessian[i][j]
                    );
                }
            }
        }
    }
}

#[test]
fn closed_forms_match_central_differences_in_every_region() {
    for (r, (name, kind, want)) in regions().into_iter().enumerate() {
        for pair in pairs_in(kind, want, 20, 31 + r as u64) {
            let closed = RegionForm::of(kind, &pair);
            let closest = kind.closest(&pair);
            // The region is held fixed, as the derivatives are those of its closed form.
            let form = |q: &[DVec3; 4]| RegionForm::new(q, closest);
            let step = 1e-6;
            let g = closed.gradient();
            let h = closed.hessian();
            let gscale = 1.0 + g.iter().fold(0.0f64, |a, x| a.max(x.abs()));
            let hscale = 1.0 + max_abs(&h);
            for i in 0..12 {
                let (plus, minus) = (
                    form(&perturbed(&pair, i, step)),
                    form(&perturbed(&pair, i, -step)),
                );
                let fd = (plus.value() - minus.value()) / (2.0 * step);
                assert!(
                    (fd - g[i]).abs() < 1e-6 * gscale,
                    "{name}: gradient {i}: {} vs {fd}",
                    g[i]
                );
                let (gp, gm) = (plus.gradient(), minus.gradient());
                for j in 0..12 {
                    let fd = (gp[j] - gm[j]) / (2.0 * step);
                    assert!(
                        (fd - h[i][j]).abs() < 1e-5 * hscale,
                        "{name}: hessian {i},{j}: {} vs {fd}",
                        h[i][j]
                    );
                }
            }
        }
    }
}

/// `second g g^T + first H` from the dual numbers: the matrix the projection acts on.
fn full_barrier_hessian(kind: PairKind, pair: &[DVec3; 4], first: f64, second: f64) -> Mat12 {
    let dual = squared_distance_derivatives(kind, pair);
    std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            second * dual.gradient[i] * dual.gradient[j] + first * dual.hessian[i][j]
        })
    })
}

#[test]
fn the_projection_in_the_span_equals_the_12x12_projection_and_is_psd() {
    let mut rng = Rng(77);
    for (r, (name, kind, want)) in regions().into_iter().enumerate() {
        for pair in pairs_in(kind, want, 40, 51 + r as u64) {
            // The barrier's derivatives: phi' < 0 and phi'' > 0, over a range of ratios
            // (and a few of either sign, which the projection must handle too).
            let first = -(10f64).powf(4.0 * rng.next() - 2.0);
            let second = (10f64).powf(8.0 * rng.next() - 2.0);
            let signs = [(1.0, 1.0), (-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)];
            for (sf, ss) in signs {
                let (first, second) = (sf * first, ss * second);
                let full = full_barrier_hessian(kind, &pair, first, second);
                let oracle = project_psd12(&full);
                let ours = RegionForm::of(kind, &pair)
                    .projected_hessian(first, second)
                    .expect("a non-degenerate pair");
                let scale = max_abs(&full);
                for i in 0..12 {
                    for j in 0..12 {
                        assert!(
                            (ours[i][j] - oracle[i][j]).abs() <= 1e-10 * scale,
                            "{name} ({first}, {second}): {i},{j}: {} vs {}",
                            ours[i][j],
                            oracle[i][j]
                        );
                        assert_eq!(ours[i][j], ours[j][i]);
                    }
                }
                let (values, _) = symmetric_eigen12(&ours);
                let smallest = values.iter().fold(f64::INFINITY, |a, &x| a.min(x));
                assert!(
                    smallest >= -1e-12 * scale,
                    "{name}: eigenvalue {smallest} of a projected matrix"
                );
            }
        }
    }
}

#[test]
fn the_exact_hessian_in_the_span_equals_the_dual_numbers() {
    let mut rng = Rng(91);
    for (r, (name, kind, want)) in regions().into_iter().enumerate() {
        for pair in pairs_in(kind, want, 40, 61 + r as u64) {
            let first = -(10f64).powf(4.0 * rng.next() - 2.0);
            let second = (10f64).powf(8.0 * rng.next() - 2.0);
            for (sf, ss) in [(1.0, 1.0), (-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)] {
                let (first, second) = (sf * first, ss * second);
                let full = full_barrier_hessian(kind, &pair, first, second);
                let ours = RegionForm::of(kind, &pair)
                    .exact_hessian(first, second)
                    .expect("a non-degenerate pair");
                let scale = max_abs(&full);
                for i in 0..12 {
                    for j in 0..12 {
                        assert!(
                            (ours[i][j] - full[i][j]).abs() <= 1e-10 * scale,
                            "{name} ({first}, {second}): {i},{j}: {} vs {}",
                            ours[i][j],
                            full[i][j]
                        );
                        assert_eq!(ours[i][j], ours[j][i]);
                    }
                }
            }
        }
    }
}

/// The barrier of a pair at squared distance `s` as the term has it (`kappa` 1): its
/// first and second derivatives in `s`, for a reach `dhat` and a thickness `xi`.
fn barrier_in_s(s: f64, dhat: f64, xi: f64) -> (f64, f64) {
    let d = s.sqrt();
    let (b1, b2) = (
        barrier_first_derivative(d - xi, dhat),
        barrier_second_derivative(d - xi, dhat),
    );
    (b1 / (2.0 * d), b2 / (4.0 * s) - b1 / (4.0 * s * d))
}

/// The barrier's gradient at `q`, its region chosen at `q` itself.
fn barrier_gradient(kind: PairKind, q: &[DVec3; 4], dhat: f64, xi: f64) -> [f64; 12] {
    let form = RegionForm::of(kind, q);
    let (first, _) = barrier_in_s(form.value(), dhat, xi);
    form.gradient().map(|g| first * g)
}

#[test]
fn the_exact_barrier_hessian_matches_central_differences_of_its_gradient() {
    for (r, (name, kind, want)) in regions().into_iter().enumerate() {
        // The odd-numbered pairs are 1e-3 apart: the barrier acts there.
        let pairs = pairs_in(kind, want, 24, 71 + r as u64);
        for pair in pairs.iter().skip(1).step_by(2) {
            let form = RegionForm::of(kind, pair);
            let d = form.value().sqrt();
            // A reach and a thickness that put the gap in the barrier's range.
            let (dhat, xi) = (2.0 * d, 0.3 * d);
            let (first, second) = barrier_in_s(form.value(), dhat, xi);
            let h = form
                .exact_hessian(first, second)
                .expect("a non-degenerate pair");
            let scale = max_abs(&h);
            let step = 1e-7 * d;
            for i in 0..12 {
                let gp = barrier_gradient(kind, &perturbed(pair, i, step), dhat, xi);
                let gm = barrier_gradient(kind, &perturbed(pair, i, -step), dhat, xi);
                for j in 0..12 {
                    let fd = (gp[j] - gm[j]) / (2.0 * step);
                    assert!(
                        (fd - h[i][j]).abs() <= 1e-5 * scale,
                        "{name}: {i},{j}: {} vs {fd} (scale {scale})",
                        h[i][j]
                    );
                }
            }
            // Where the projection acts: a point-plane or line-line pair's exact Hessian
            // has at least two negative eigenvalues, which the projection drops.
            if matches!(
                kind.closest(pair),
                Closest::PointPlane(_) | Closest::LineLine(_)
            ) {
                let (values, _) = symmetric_eigen12(&h);
                let negative = values.iter().filter(|&&v| v < -1e-9 * scale).count();
                assert!(negative >= 2, "{name}: {values:?}");
            }
        }
    }
}

#[test]
fn the_closed_form_declines_a_pair_at_zero_distance() {
    let p = DVec3::new(0.2, 0.0, 0.2);
    let pair = [
        p,
        DVec3::ZERO,
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(0.0, 0.0, 1.0),
    ];
    let form = RegionForm::of(PairKind::PointTriangle, &pair);
    assert_eq!(form.value(), 0.0);
    assert!(form.projected_hessian(-1.0, 1.0).is_none());
    assert!(form.exact_hessian(-1.0, 1.0).is_none());
}

#[test]
fn the_projected_and_exact_hessians_decline_the_same_pairs() {
    // The term keeps a pair's span with its gradient and computes whichever form is
    // asked for later from it, taking the dual numbers where the span is declined: the
    // two forms must decline the same pairs, in every region, at ordinary, degenerate
    // and non-finite inputs.
    let mut cases: Vec<(PairKind, [DVec3; 4])> = Vec::new();
    for (i, (_, kind, want)) in regions().into_iter().enumerate() {
        for pair in pairs_in(kind, want, 40, 97 + i as u64) {
            cases.push((kind, pair));
        }
    }
    let (o, x, z) = (DVec3::ZERO, DVec3::X, DVec3::Z);
    // A point on its triangle (r = 0), a collinear triangle, parallel and crossing edges.
    cases.push((PairKind::PointTriangle, [0.2 * x + 0.2 * z, o, x, z]));
    cases.push((PairKind::PointTriangle, [DVec3::Y, o, x, 2.0 * x]));
    cases.push((PairKind::EdgeEdge, [o, x, DVec3::Y, DVec3::Y + x]));
    cases.push((PairKind::EdgeEdge, [-x, x, -z, z]));
    let derivatives = [
        (-1.0, 1.0),
        (2.5e3, -7.0),
        (0.0, 0.0),
        (f64::INFINITY, 1.0),
        (-1.0, f64::NAN),
    ];
    let mut declined = 0;
    for (kind, pair) in &cases {
        let form = RegionForm::of(*kind, pair);
        for &(first, second) in &derivatives {
            let projected = form.projected_hessian(first, second).is_some();
            let exact = form.exact_hessian(first, second).is_some();
            assert_eq!(projected, exact, "{kind:?} {pair:?} {first} {second}");
            declined += usize::from(!projected);
        }
    }
    // Both answers occur: the non-finite derivatives decline every pair, and the point
    // on its triangle declines the finite ones too.
    assert!(declined >= 2 * cases.len() + 3, "{declined}");
    assert!(declined < derivatives.len() * cases.len(), "{declined}");
}

/// Cyclic Jacobi as first written: every rotation rotates the columns `p` and `q` of the
/// whole matrix, then its rows `p` and `q`. The reference for the bitwise test below.
fn jacobi_full_update<const N: usize>(m: &[[f64; N]; N], n: usize) -> ([f64; N], [[f64; N]; N]) {
    let mut a = [[0.0; N]; N];
    for i in 0..n {
        for j in 0..=i {
            let s = 0.5 * (m[i][j] + m[j][i]);
            a[i][j] = s;
            a[j][i] = s;
        }
    }
    let mut v = [[0.0; N]; N];
    for i in 0..n {
        v[i][i] = 1.0;
    }
    let scale: f64 = a.iter().flatten().map(|x| x * x).sum::<f64>().sqrt();
    let tol = (1e-14 * scale).powi(2);
    for _ in 0..50 {
        let mut off = 0.0;
        for i in 0..n {
            for j in 0..i {
                off += a[i][j] * a[i][j];
            }
        }
        if !(off.is_finite() && off > tol) {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = a[p][q];
                if apq * apq <= 1e-4 * tol / (n * n) as f64 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
                let t = if theta.abs() > 1e150 {
                    0.5 / theta
                } else {
                    theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
                };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for row in a.iter_mut().take(n) {
                    let (rp, rq) = (row[p], row[q]);
                    row[p] = c * rp - s * rq;
                    row[q] = s * rp + c * rq;
                }
                for k in 0..n {
                    let (rp, rq) = (a[p][k], a[q][k]);
                    a[p][k] = c * rp - s * rq;
                    a[q][k] = s * rp + c * rq;
                }
                a[p][q] = 0.0;
                a[q][p] = 0.0;
                for row in v.iter_mut().take(n) {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    (
        std::array::from_fn(|i| if i < n { a[i][i] } else { 0.0 }),
        v,
    )
}

/// A random symmetric `n x n` matrix (in an `N x N` array) of the kinds a pair's Hessian
/// gives: full rank, low rank (zero and repeated eigenvalues), with exact zero entries,
/// and entries over many decades.
fn random_symmetric<const N: usize>(rng: &mut Rng, n: usize, kind: usize) -> [[f64; N]; N] {
    let mut m = [[0.0; N]; N];
    match kind % 3 {
        0 => {
            for i in 0..n {
                for j in 0..=i {
                    let x = (2.0 * rng.next() - 1.0) * (10f64).powf(6.0 * rng.next() - 3.0);
                    m[i][j] = x;
                    m[j][i] = x;
                }
            }
        }
        1 => {
            // A sum of two outer products: rank two, the rest of the eigenvalues zero.
            for _ in 0..2 {
                let u: Vec<f64> = (0..n).map(|_| 2.0 * rng.next() - 1.0).collect();
                let w = 2.0 * rng.next() - 1.0;
                for i in 0..n {
                    for j in 0..n {
                        m[i][j] += w * u[i] * u[j];
                    }
                }
            }
        }
        _ => {
            // Sparse: about half the entries exactly zero.
            for i in 0..n {
                for j in 0..=i {
                    if rng.next() < 0.5 {
                        let x = 2.0 * rng.next() - 1.0;
                        m[i][j] = x;
                        m[j][i] = x;
                    }
                }
            }
        }
    }
    m
}

#[test]
fn the_jacobi_rotations_equal_the_full_update_bit_for_bit() {
    let mut rng = Rng(2024);
    let bits = |x: f64| x.to_bits();
    for case in 0..600 {
        let kind = case / 200;
        // The closed form's sizes (3 to 5) on 5x5 arrays, the 12x12 projection's on 12x12.
        let n5 = 3 + case % 3;
        let m5 = random_symmetric::<5>(&mut rng, n5, kind);
        let (values, vectors) = symmetric_eigen_n(&m5, n5);
        let (want_values, want_vectors) = jacobi_full_update(&m5, n5);
        assert_eq!(values.map(bits), want_values.map(bits), "5x5 case {case}");
        assert_eq!(
            vectors.map(|r| r.map(bits)),
            want_vectors.map(|r| r.map(bits)),
            "5x5 case {case}"
        );
        let n12 = 6 + case % 7;
        let m12 = random_symmetric::<12>(&mut rng, n12, kind);
        let (values, vectors) = symmetric_eigen_n(&m12, n12);
        let (want_values, want_vectors) = jacobi_full_update(&m12, n12);
        assert_eq!(values.map(bits), want_values.map(bits), "12x12 case {case}");
        assert_eq!(
            vectors.map(|r| r.map(bits)),
            want_vectors.map(|r| r.map(bits)),
            "12x12 case {case}"
        );
        if n12 == 12 {
            let (values, _) = symmetric_eigen12(&m12);
            assert_eq!(values.map(bits), want_values.map(bits), "12x12 case {case}");
        }
    }
}
