//! The closed-form squared distances of self-contact ([`RegionForm`]) against the dual
//! numbers (value, gradient, Hessian) and against central differences, in every region of
//! both pair kinds; and the projection in the Hessian's span against the full 12x12
//! Jacobi projection of the same matrix, with its eigenvalues checked non-negative.

// Index loops over rows and columns read as the matrix comparisons they are.
#![allow(clippy::needless_range_loop)]

use sinew_math::DVec3;
use sinew_spring_sim::contact::self_contact::RegionForm;
use sinew_spring_sim::contact::self_contact::distance::{
    Closest, PairKind, squared_distance_derivatives,
};
use sinew_spring_sim::contact::self_contact::psd12::{Mat12, project_psd12, symmetric_eigen12};

/// A small deterministic generator (xorshift), so the random cases are reproducible.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn vec(&mut self, scale: f64) -> DVec3 {
        scale
            * DVec3::new(
                2.0 * self.next() - 1.0,
                2.0 * self.next() - 1.0,
                2.0 * self.next() - 1.0,
            )
    }
}

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
}
