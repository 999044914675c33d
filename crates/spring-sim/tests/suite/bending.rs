//! The dihedral bending term: the angle on hand-computed hinges, its gradient against
//! central differences of the angle, its Hessian against central differences of the
//! gradient, and the term's energy, gradient, Hessian (exact and projected) and energy
//! change against each other.

use crate::common::{Sample, XorshiftStar as Rng};
use sinew_math::{DMat3, DQuat, DVec3};
use sinew_spring_sim::potential::{
    DihedralBending, HessianSink, Hinge, StepContext, Term, angle_change, dihedral_angle,
    dihedral_angle_gradient, dihedral_angle_hessian,
};
use sinew_spring_sim::spring::Curvature;
use sinew_spring_sim::{ClothGrid, SpringSystem};
use std::f64::consts::{FRAC_PI_2, FRAC_PI_3, PI};

/// A small deterministic generator (xorshift64*), so failures reproduce.
/// A hinge on the x axis from the origin to (1, 0, 0): the first opposite vertex at
/// (0.4, 1, 0) (so the first normal is +z), the second at (0.6, -cos a, sin a) turned by
/// `a` about +x from the flat position (0.6, -1, 0).
fn hinge_at(a: f64) -> [DVec3; 4] {
    let second = DQuat::from_rotation_x(a) * DVec3::new(0.6, -1.0, 0.0);
    [DVec3::ZERO, DVec3::X, DVec3::new(0.4, 1.0, 0.0), second]
}

#[test]
fn angle_on_hand_computed_hinges() {
    // Flat with the opposite vertices on opposite sides: 0.
    assert_eq!(dihedral_angle(hinge_at(0.0)), 0.0);
    // Turning the second triangle by a about the edge turns its normal by a: the angle
    // is a, with the sign of the turn.
    for a in [0.1, FRAC_PI_3, FRAC_PI_2, 2.5, -0.7, -FRAC_PI_2] {
        let theta = dihedral_angle(hinge_at(a));
        assert!((theta - a).abs() < 1e-14, "a = {a}: theta = {theta}");
    }
    // Reversing the edge (swapping its ends) and the opposite vertices keeps the angle.
    let x = hinge_at(0.8);
    let swapped = [x[1], x[0], x[3], x[2]];
    assert!((dihedral_angle(swapped) - 0.8).abs() < 1e-14);
    // Folded completely flat onto itself: pi.
    assert!((dihedral_angle(hinge_at(PI)).abs() - PI).abs() < 1e-14);
    // Degenerate hinges have angle 0 and zero derivatives.
    let collapsed = [DVec3::ZERO, DVec3::X, DVec3::new(0.5, 0.0, 0.0), DVec3::Y];
    assert_eq!(dihedral_angle(collapsed), 0.0);
    assert!(
        dihedral_angle_gradient(collapsed)
            .iter()
            .all(|g| *g == DVec3::ZERO)
    );
    // Moving out of a degenerate state changes the angle as the energy sees it.
    let lift = [
        DVec3::ZERO,
        DVec3::ZERO,
        DVec3::new(0.0, 0.5, 0.0),
        DVec3::ZERO,
    ];
    let lifted = std::array::from_fn(|k| collapsed[k] + lift[k]);
    assert!(dihedral_angle(lifted) != 0.0);
    assert_eq!(angle_change(collapsed, lift), dihedral_angle(lifted));
}

/// A random non-degenerate hinge around the unit edge.
fn random_hinge(rng: &mut Rng) -> [DVec3; 4] {
    let a = rng.next() * 5.0 - 2.5;
    let mut x = hinge_at(a);
    for p in &mut x {
        *p += rng.vec(0.2);
    }
    x
}

#[test]
fn gradient_matches_central_differences() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for _ in 0..200 {
        let x = random_hinge(&mut rng);
        let g = dihedral_angle_gradient(x);
        let eps = 1e-6;
        for v in 0..4 {
            for c in 0..3 {
                let (mut plus, mut minus) = (x, x);
                plus[v][c] += eps;
                minus[v][c] -= eps;
                let fd = (dihedral_angle(plus) - dihedral_angle(minus)) / (2.0 * eps);
                assert!(
                    (fd - g[v][c]).abs() < 1e-7 * (1.0 + fd.abs()),
                    "vertex {v} axis {c}: analytic {} vs differences {fd}",
                    g[v][c]
                );
            }
        }
        // Translation invariance: the gradients sum to zero.
        let sum: DVec3 = g.iter().copied().sum();
        assert!(sum.length() < 1e-12 * g[2].length().max(1.0));
    }
}

#[test]
fn hessian_matches_central_differences_of_the_gradient() {
    let mut rng = Rng(0x1234_5678_9abc_def1);
    for _ in 0..100 {
        let x = random_hinge(&mut rng);
        let h = dihedral_angle_hessian(x);
        let eps = 1e-6;
        for j in 0..4 {
            for c in 0..3 {
                let (mut plus, mut minus) = (x, x);
                plus[j][c] += eps;
                minus[j][c] -= eps;
                let (gp, gm) = (
                    dihedral_angle_gradient(plus),
                    dihedral_angle_gradient(minus),
                );
                for i in 0..4 {
                    let fd = (gp[i] - gm[i]) / (2.0 * eps);
                    let col = h[i][j].col(c);
                    assert!(
                        (fd - col).abs().max_element() < 1e-6 * (1.0 + fd.abs().max_element()),
                        "block ({i}, {j}) column {c}: {col} vs differences {fd}"
                    );
                }
            }
        }
        // Symmetric to round-off.
        for (i, row) in h.iter().enumerate() {
            for (j, block) in row.iter().enumerate() {
                let d = *block - h[j][i].transpose();
                assert!(d.abs().to_cols_array().iter().all(|&e| e < 1e-9));
            }
        }
    }
}

/// A 3 x 3 grid cloth whose 8 triangles give the hinges, every vertex free, moved
/// randomly out of plane, with a context to evaluate the term in.
struct Case {
    system: SpringSystem,
    term: DihedralBending,
    x: Vec<DVec3>,
}

fn case(seed: u64) -> Case {
    let mut rng = Rng(seed);
    let grid = ClothGrid {
        fixed: Vec::new(),
        ..ClothGrid::lab_sized(3, 0.5).with_damping(0.0)
    };
    let system = SpringSystem::cloth(&grid).unwrap();
    let rest = system.positions().to_vec();
    let mesh = sinew_spring_sim::TriangleMesh::new(rest.clone(), grid.triangles()).unwrap();
    let hinges: Vec<Hinge> = mesh
        .hinges()
        .unwrap()
        .into_iter()
        .map(|(e, o)| Hinge::at_rest(&rest, e, o, 0.7).unwrap())
        .collect();
    assert_eq!(hinges.len(), 8, "a 3 x 3 grid has 8 interior edges");
    let x = rest.iter().map(|&p| p + rng.vec(0.15)).collect();
    Case {
        system,
        term: DihedralBending::new(hinges),
        x,
    }
}

fn with_step<R>(c: &Case, f: impl FnOnce(&StepContext<'_>) -> R) -> R {
    let pos = c.system.positions();
    let step = StepContext::new(&c.system, 1.0 / 60.0, pos, pos);
    f(&step)
}

fn gradient(c: &Case, step: &StepContext<'_>, x: &[DVec3]) -> Vec<DVec3> {
    let mut g = vec![DVec3::ZERO; x.len()];
    c.term.add_gradient(step, x, &mut g);
    g
}

/// `H z` through the sink's product target (no pattern needed, nothing fixed).
fn hessian_product(
    c: &Case,
    step: &StepContext<'_>,
    x: &[DVec3],
    curvature: Curvature,
    z: &[DVec3],
) -> Vec<DVec3> {
    let fixed = vec![false; x.len()];
    let mut out = vec![DVec3::ZERO; x.len()];
    let mut sink = HessianSink::product(&fixed, z, &mut out);
    c.term.add_hessian(step, x, curvature, &mut sink);
    out
}

#[test]
fn term_gradient_matches_central_differences_of_the_energy() {
    for seed in 1..6 {
        let c = case(seed);
        with_step(&c, |step| {
            let g = gradient(&c, step, &c.x);
            let eps = 1e-6;
            for p in 0..c.x.len() {
                for a in 0..3 {
                    let (mut plus, mut minus) = (c.x.clone(), c.x.clone());
                    plus[p][a] += eps;
                    minus[p][a] -= eps;
                    let fd =
                        (c.term.energy(step, &plus) - c.term.energy(step, &minus)) / (2.0 * eps);
                    assert!(
                        (fd - g[p][a]).abs() < 1e-6 * (1.0 + fd.abs()),
                        "seed {seed} particle {p} axis {a}: {} vs {fd}",
                        g[p][a]
                    );
                }
            }
        });
    }
}

#[test]
fn exact_term_hessian_matches_central_differences_of_the_gradient() {
    let mut rng = Rng(77);
    for seed in 1..6 {
        let c = case(seed);
        with_step(&c, |step| {
            let z: Vec<DVec3> = (0..c.x.len()).map(|_| rng.vec(1.0)).collect();
            let hz = hessian_product(&c, step, &c.x, Curvature::Exact, &z);
            let eps = 1e-6;
            let plus: Vec<DVec3> = c.x.iter().zip(&z).map(|(&x, &d)| x + eps * d).collect();
            let minus: Vec<DVec3> = c.x.iter().zip(&z).map(|(&x, &d)| x - eps * d).collect();
            let (gp, gm) = (gradient(&c, step, &plus), gradient(&c, step, &minus));
            for p in 0..c.x.len() {
                let fd = (gp[p] - gm[p]) / (2.0 * eps);
                assert!(
                    (fd - hz[p]).abs().max_element() < 1e-5 * (1.0 + fd.abs().max_element()),
                    "seed {seed} particle {p}: {} vs {fd}",
                    hz[p]
                );
            }
        });
    }
}

#[test]
fn projected_hessian_is_positive_semidefinite_and_exact_where_that_already_is() {
    let mut rng = Rng(5);
    let mut indefinite_seen = false;
    for seed in 1..20 {
        let c = case(seed);
        with_step(&c, |step| {
            for _ in 0..20 {
                let z: Vec<DVec3> = (0..c.x.len()).map(|_| rng.vec(1.0)).collect();
                let dot = |a: &[DVec3]| a.iter().zip(&z).map(|(u, v)| u.dot(*v)).sum::<f64>();
                let clamped = dot(&hessian_product(&c, step, &c.x, Curvature::Clamped, &z));
                let exact = dot(&hessian_product(&c, step, &c.x, Curvature::Exact, &z));
                let half = dot(&hessian_product(
                    &c,
                    step,
                    &c.x,
                    Curvature::Softened(0.5),
                    &z,
                ));
                assert!(clamped >= -1e-10, "seed {seed}: z^T H z = {clamped}");
                // Removing negative curvature only raises the quadratic form, more the
                // more is removed.
                assert!(half >= exact - 1e-10 && clamped >= half - 1e-10);
                indefinite_seen |= exact < 0.0;
            }
        });
    }
    assert!(indefinite_seen, "no case exercised the projection");
    // At rest the Hessian is k w g g^T, already positive semidefinite: the projection
    // leaves it alone, and the exact and projected forms agree.
    let c = case(1);
    let rest = c.system.positions().to_vec();
    with_step(&c, |step| {
        let z: Vec<DVec3> = (0..rest.len()).map(|_| rng.vec(1.0)).collect();
        let a = hessian_product(&c, step, &rest, Curvature::Exact, &z);
        let b = hessian_product(&c, step, &rest, Curvature::Clamped, &z);
        for (u, v) in a.iter().zip(&b) {
            assert!((*u - *v).length() < 1e-12);
        }
    });
}

#[test]
fn projection_of_a_single_hinge_keeps_the_positive_part() {
    // A strongly bent hinge far from its flat rest angle: the exact Hessian has a
    // negative eigenvalue; the projection must be PSD and differ from the exact matrix
    // by a PSD matrix (it only removes negative curvature).
    let x = hinge_at(2.0);
    let rest = hinge_at(0.0);
    let h = Hinge::at_rest(&rest, [0, 1], [2, 3], 1.0).unwrap();
    let exact = DihedralBending::hinge_hessian(&h, &x, Curvature::Exact);
    let clamped = DihedralBending::hinge_hessian(&h, &x, Curvature::Clamped);
    let mut rng = Rng(11);
    let quad = |m: &[[DMat3; 4]; 4], z: &[DVec3; 4]| -> f64 {
        let mut s = 0.0;
        for i in 0..4 {
            for j in 0..4 {
                s += z[i].dot(m[i][j] * z[j]);
            }
        }
        s
    };
    let mut negative = false;
    for _ in 0..2000 {
        let z = [rng.vec(1.0), rng.vec(1.0), rng.vec(1.0), rng.vec(1.0)];
        let (e, p) = (quad(&exact, &z), quad(&clamped, &z));
        negative |= e < 0.0;
        assert!(p >= -1e-10, "projected z^T H z = {p}");
        assert!(p >= e - 1e-10);
    }
    assert!(negative, "the exact Hessian should be indefinite here");
}

#[test]
fn energy_change_matches_the_difference_of_energies() {
    let mut rng = Rng(3);
    for seed in 1..6 {
        let c = case(seed);
        with_step(&c, |step| {
            let dx: Vec<DVec3> = (0..c.x.len()).map(|_| rng.vec(0.05)).collect();
            for alpha in [1.0, 0.25, 1e-3] {
                let moved: Vec<DVec3> = c.x.iter().zip(&dx).map(|(&x, &d)| x + alpha * d).collect();
                let diff = c.term.energy(step, &moved) - c.term.energy(step, &c.x);
                let change = c.term.energy_change(step, &c.x, &dx, alpha);
                assert!(
                    (diff - change).abs() < 1e-12 * (1.0 + c.term.energy(step, &c.x)),
                    "alpha {alpha}: {change} vs {diff}"
                );
            }
        });
    }
}

#[test]
fn hinge_weight_and_energy_by_hand() {
    // Two right triangles of legs 1 on the unit edge: areas 1/2 each, so
    // w = 3 |e|^2 / (A1 + A2) = 3. Turned by a = 0.3: E = k/2 * 3 * 0.09.
    let rest = [DVec3::ZERO, DVec3::X, DVec3::Y, -DVec3::Y];
    let h = Hinge::at_rest(&rest, [0, 1], [2, 3], 2.0).unwrap();
    assert!((h.weight - 3.0).abs() < 1e-15);
    assert_eq!(h.rest_angle, 0.0);
    let bent = [
        DVec3::ZERO,
        DVec3::X,
        DVec3::Y,
        DQuat::from_rotation_x(0.3) * -DVec3::Y,
    ];
    assert!((h.energy(&bent) - 0.5 * 2.0 * 3.0 * 0.09).abs() < 1e-14);
    // A degenerate rest triangle has no hinge.
    let flat = [DVec3::ZERO, DVec3::X, DVec3::new(2.0, 0.0, 0.0), -DVec3::Y];
    assert!(Hinge::at_rest(&flat, [0, 1], [2, 3], 1.0).is_none());
}

#[test]
fn angle_change_keeps_its_precision_for_tiny_moves() {
    let mut rng = Rng(0xabcd);
    for _ in 0..200 {
        let x = random_hinge(&mut rng);
        let d = [rng.vec(1.0), rng.vec(1.0), rng.vec(1.0), rng.vec(1.0)];
        // Moderate moves: equal to the difference of the angles.
        for t in [0.3, 0.05] {
            let moved = std::array::from_fn(|k| x[k] + t * d[k]);
            let delta = d.map(|v| t * v);
            let diff = dihedral_angle(moved) - dihedral_angle(x);
            if diff.abs() < 3.0 {
                assert!((angle_change(x, delta) - diff).abs() < 1e-12, "{diff}");
            }
        }
        // Tiny moves: against the second-order expansion g.d t + d^T H d t^2 / 2, whose
        // error is O(t^3); the difference of two angles is off by about 1e-16 absolute,
        // a relative error of 1e-16 / t here.
        let g = dihedral_angle_gradient(x);
        let h = dihedral_angle_hessian(x);
        let first: f64 = (0..4).map(|i| g[i].dot(d[i])).sum();
        let mut second = 0.0;
        for i in 0..4 {
            for j in 0..4 {
                second += d[i].dot(h[i][j] * d[j]);
            }
        }
        for t in [1e-7, 1e-9, 1e-11] {
            let expected = first * t + 0.5 * second * t * t;
            let got = angle_change(x, d.map(|v| t * v));
            assert!(
                (got - expected).abs() <= 1e-9 * expected.abs() + 1e-30,
                "t {t}: {got} vs {expected}"
            );
        }
    }
}

/// The 12 x 12 matrix of a hinge's 4 x 4 blocks (row `3 i + r`, column `3 j + c`).
fn dense(blocks: &[[DMat3; 4]; 4]) -> [[f64; 12]; 12] {
    let mut m = [[0.0; 12]; 12];
    for (i, row) in blocks.iter().enumerate() {
        for (j, b) in row.iter().enumerate() {
            for c in 0..3 {
                for r in 0..3 {
                    m[3 * i + r][3 * j + c] = b.col(c)[r];
                }
            }
        }
    }
    m
}

#[test]
fn clamped_hessian_is_the_positive_part_of_the_exact_one() {
    // H = P - D with P and D positive semidefinite and P D = 0 characterizes the positive
    // part P (the Frobenius-nearest PSD matrix) uniquely; P must also keep the exact
    // Hessian's null space of translations.
    let mut rng = Rng(21);
    let rest = hinge_at(0.0);
    for _ in 0..50 {
        let x = random_hinge(&mut rng);
        let h = Hinge::at_rest(&rest, [0, 1], [2, 3], 1.3).unwrap();
        let exact = dense(&DihedralBending::hinge_hessian(&h, &x, Curvature::Exact));
        let p = dense(&DihedralBending::hinge_hessian(&h, &x, Curvature::Clamped));
        let norm: f64 = exact.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
        let mut worst: f64 = 0.0;
        for r in 0..12 {
            for c in 0..12 {
                // (P D)[r][c] with D = P - H.
                let pd: f64 = (0..12).map(|k| p[r][k] * (p[k][c] - exact[k][c])).sum();
                worst = worst.max(pd.abs());
            }
        }
        assert!(worst < 1e-10 * norm * norm, "|P D| = {worst}, |H| = {norm}");
        for axis in 0..3 {
            for row in &p {
                let pt: f64 = (0..4).map(|v| row[3 * v + axis]).sum();
                assert!(pt.abs() < 1e-10 * norm, "translation not in the null space");
            }
        }
        // D = P - H is positive semidefinite.
        for _ in 0..20 {
            let z: Vec<f64> = (0..12).map(|_| rng.next() - 0.5).collect();
            let q: f64 = (0..12)
                .flat_map(|r| (0..12).map(move |c| (r, c)))
                .map(|(r, c)| z[r] * (p[r][c] - exact[r][c]) * z[c])
                .sum();
            assert!(q >= -1e-10 * norm);
        }
    }
}
