//! The terms of the incremental potential, one by one: gradient against central
//! differences of the energy, exact Hessian against central differences of the gradient,
//! the projected Hessian positive semidefinite, the energy change along a direction
//! against the difference of energies; and their sum against an independent formula of
//! the whole objective on the lab cloth.

use crate::common::{Sample, XorshiftStar as Rng};
use sinew_math::DVec3;
use sinew_spring_sim::potential::{
    AxialDamping, Gravity, HessianSink, Inertia, MissingPair, Potential, Springs, StepContext,
    Term, incremental_potential,
};
use sinew_spring_sim::spring::Curvature;
use sinew_spring_sim::{ClothGrid, HessianPattern, SpringSystem};

/// A small deterministic generator (xorshift64*), so failures reproduce.
/// A 4 x 4 sheet (two fixed corners) with damping, moved and set in motion so springs are
/// stretched and compressed, and its step data: prediction `y = x_n + h v_n`, reference
/// `x_n`.
struct Case {
    system: SpringSystem,
    h: f64,
    y: Vec<DVec3>,
    x_ref: Vec<DVec3>,
}

fn case(seed: u64) -> Case {
    let mut rng = Rng(seed);
    let mut system = SpringSystem::cloth(&ClothGrid::lab_sized(4, 0.2).with_damping(0.3)).unwrap();
    let fixed = system.fixed().to_vec();
    let x: Vec<DVec3> = system
        .positions()
        .iter()
        .zip(&fixed)
        .map(|(&p, &f)| if f { p } else { p + rng.vec(0.08) })
        .collect();
    let v: Vec<DVec3> = (0..x.len()).map(|_| rng.vec(1.0)).collect();
    system.set_state(&x, &v).unwrap();
    let h = 1.0 / 60.0;
    let x_ref = system.positions().to_vec();
    let y = x_ref
        .iter()
        .zip(system.velocities())
        .zip(&fixed)
        .map(|((&p, &v), &f)| if f { p } else { p + h * v })
        .collect();
    Case {
        system,
        h,
        y,
        x_ref,
    }
}

impl Case {
    fn step(&self) -> StepContext<'_> {
        StepContext::new(&self.system, self.h, &self.y, &self.x_ref)
    }

    /// A point to evaluate at: the start moved at random (fixed particles stay).
    fn point(&self, rng: &mut Rng) -> Vec<DVec3> {
        self.x_ref
            .iter()
            .zip(self.system.fixed())
            .map(|(&p, &f)| if f { p } else { p + rng.vec(0.05) })
            .collect()
    }

    /// A direction, zero at fixed particles.
    fn direction(&self, rng: &mut Rng, scale: f64) -> Vec<DVec3> {
        self.system
            .fixed()
            .iter()
            .map(|&f| if f { DVec3::ZERO } else { rng.vec(scale) })
            .collect()
    }
}

/// Every term of the mass-spring potential, its per-step state set for `case`.
fn terms(case: &Case) -> Vec<Box<dyn Term>> {
    let mut list: Vec<Box<dyn Term>> = vec![
        Box::new(Inertia),
        Box::new(Gravity),
        Box::new(Springs),
        Box::new(AxialDamping::new(&case.system)),
    ];
    for t in &mut list {
        t.begin_step(&case.step());
    }
    list
}

fn gradient(term: &dyn Term, case: &Case, x: &[DVec3]) -> Vec<DVec3> {
    let mut g = vec![DVec3::ZERO; x.len()];
    term.add_gradient(&case.step(), x, &mut g);
    g
}

/// The term's Hessian over the free unknowns as a dense matrix (row-major, `3n x 3n`
/// over all particles, zero on fixed rows and columns), column by column from the
/// product sink.
fn dense_hessian(term: &dyn Term, case: &Case, x: &[DVec3], curvature: Curvature) -> Vec<f64> {
    let n = x.len();
    let fixed = case.system.fixed();
    let mut h = vec![0.0; 9 * n * n];
    for col in 0..3 * n {
        let mut z = vec![DVec3::ZERO; n];
        z[col / 3][col % 3] = 1.0;
        let mut out = vec![DVec3::ZERO; n];
        term.add_hessian(
            &case.step(),
            x,
            curvature,
            &mut HessianSink::product(fixed, &z, &mut out),
        );
        for (p, o) in out.iter().enumerate() {
            for c in 0..3 {
                h[(3 * p + c) * 3 * n + col] = o[c];
            }
        }
    }
    h
}

fn free_rows(case: &Case) -> Vec<usize> {
    (0..3 * case.system.len())
        .filter(|r| !case.system.fixed()[r / 3])
        .collect()
}

#[test]
fn gradients_match_central_differences_of_the_energies() {
    for seed in 1..=5 {
        let case = case(seed);
        let mut rng = Rng(seed * 7919);
        let x = case.point(&mut rng);
        for term in terms(&case) {
            let g = gradient(term.as_ref(), &case, &x);
            let scale = g.iter().fold(0.0f64, |m, v| m.max(v.abs().max_element()));
            assert!(scale > 0.0, "{}: zero gradient", term.name());
            let eps = 1e-6;
            for r in free_rows(&case) {
                let (p, c) = (r / 3, r % 3);
                let mut plus = x.clone();
                plus[p][c] += eps;
                let mut minus = x.clone();
                minus[p][c] -= eps;
                let step = case.step();
                let fd = (term.energy(&step, &plus) - term.energy(&step, &minus)) / (2.0 * eps);
                let err = (fd - g[p][c]).abs();
                assert!(
                    err <= 1e-6 * scale,
                    "{} seed {seed}, particle {p} axis {c}: gradient {} vs differences {fd}",
                    term.name(),
                    g[p][c]
                );
            }
        }
    }
}

#[test]
fn exact_hessians_match_central_differences_of_the_gradients() {
    for seed in 1..=5 {
        let case = case(seed);
        let mut rng = Rng(seed * 104_729);
        let x = case.point(&mut rng);
        let n = x.len();
        for term in terms(&case) {
            let h = dense_hessian(term.as_ref(), &case, &x, Curvature::Exact);
            let scale = h.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let eps = 1e-6;
            let mut worst = 0.0f64;
            for col in free_rows(&case) {
                let (p, c) = (col / 3, col % 3);
                let mut plus = x.clone();
                plus[p][c] += eps;
                let mut minus = x.clone();
                minus[p][c] -= eps;
                let gp = gradient(term.as_ref(), &case, &plus);
                let gm = gradient(term.as_ref(), &case, &minus);
                for row in free_rows(&case) {
                    let fd = (gp[row / 3][row % 3] - gm[row / 3][row % 3]) / (2.0 * eps);
                    worst = worst.max((fd - h[row * 3 * n + col]).abs());
                }
            }
            assert!(
                worst <= 1e-6 * scale.max(1.0),
                "{} seed {seed}: Hessian off its differences by {worst:e} (scale {scale:e})",
                term.name()
            );
        }
    }
}

/// Whether the symmetric `m x m` matrix `a` (row-major) is positive semidefinite up to a
/// shift of `1e-12` of its largest entry: Cholesky of `a + shift I` succeeds.
fn is_psd(a: &[f64], m: usize) -> bool {
    let scale = a
        .iter()
        .fold(0.0f64, |s, v| s.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    let mut l = vec![0.0; m * m];
    for j in 0..m {
        let mut d = a[j * m + j] + 1e-12 * scale;
        for k in 0..j {
            d -= l[j * m + k] * l[j * m + k];
        }
        if d <= 0.0 {
            return false;
        }
        let d = d.sqrt();
        l[j * m + j] = d;
        for i in j + 1..m {
            let mut s = a[i * m + j];
            for k in 0..j {
                s -= l[i * m + k] * l[j * m + k];
            }
            l[i * m + j] = s / d;
        }
    }
    true
}

/// The free rows and columns of a dense Hessian.
fn reduced(case: &Case, h: &[f64]) -> (Vec<f64>, usize) {
    let rows = free_rows(case);
    let n3 = 3 * case.system.len();
    let m = rows.len();
    let mut out = vec![0.0; m * m];
    for (i, &r) in rows.iter().enumerate() {
        for (j, &c) in rows.iter().enumerate() {
            out[i * m + j] = h[r * n3 + c];
        }
    }
    (out, m)
}

#[test]
fn projected_hessians_are_positive_semidefinite_and_the_exact_one_is_not_always() {
    let mut indefinite_seen = false;
    for seed in 1..=5 {
        let case = case(seed);
        // Compress the sheet to 60% around its first particle so many springs are
        // compressed: the exact spring Hessian is then indefinite.
        let origin = case.x_ref[0];
        let mut rng = Rng(seed * 31);
        let x: Vec<DVec3> = case
            .point(&mut rng)
            .iter()
            .zip(case.system.fixed())
            .map(|(&p, &f)| if f { p } else { origin + 0.6 * (p - origin) })
            .collect();
        for term in terms(&case) {
            let h = dense_hessian(term.as_ref(), &case, &x, Curvature::Clamped);
            let (a, m) = reduced(&case, &h);
            assert!(
                is_psd(&a, m),
                "{} seed {seed}: projected Hessian not PSD",
                term.name()
            );
            let exact = dense_hessian(term.as_ref(), &case, &x, Curvature::Exact);
            let (a, m) = reduced(&case, &exact);
            indefinite_seen |= !is_psd(&a, m);
        }
    }
    // The check above could not pass by being blind: it does reject an indefinite matrix.
    assert!(
        indefinite_seen,
        "no indefinite exact Hessian: the PSD test is untested"
    );
}

#[test]
fn energy_changes_agree_with_differences_of_energies() {
    for seed in 1..=5 {
        let case = case(seed);
        let mut rng = Rng(seed * 65_537);
        let x = case.point(&mut rng);
        for scale in [1e-1, 1e-3] {
            let dx = case.direction(&mut rng, scale);
            for term in terms(&case) {
                let step = case.step();
                for alpha in [1.0, 0.5, 2.0, 1e-3] {
                    let moved: Vec<DVec3> =
                        x.iter().zip(&dx).map(|(&p, &d)| p + alpha * d).collect();
                    let e0 = term.energy(&step, &x);
                    let e1 = term.energy(&step, &moved);
                    let change = term.energy_change(&step, &x, &dx, alpha);
                    let err = (change - (e1 - e0)).abs();
                    // The difference of energies carries the round-off of the energies
                    // themselves; the change computed from differences is the more
                    // accurate of the two.
                    let allowance = 1e-12 * (e0.abs() + e1.abs()) + 1e-300;
                    assert!(
                        err <= allowance,
                        "{} seed {seed} alpha {alpha}: change {change:e}, difference {:e}",
                        term.name(),
                        e1 - e0
                    );
                    assert!(term.max_step(&step, &x, &dx, f64::INFINITY) == f64::INFINITY);
                }
            }
        }
    }
}

#[test]
fn a_tiny_change_keeps_its_relative_accuracy() {
    // Near convergence the line search compares changes far below g: along a direction
    // of 1e-9 the spring term's change from differences matches its first-order value
    // grad . dx to 1e-6 relative, where a difference of energies has lost it.
    let case = case(11);
    let mut rng = Rng(99);
    let x = case.point(&mut rng);
    let dx = case.direction(&mut rng, 1.0);
    let step = case.step();
    let term = Springs;
    let g = gradient(&term, &case, &x);
    let slope: f64 = g.iter().zip(&dx).map(|(a, b)| a.dot(*b)).sum();
    let alpha = 1e-9;
    let change = term.energy_change(&step, &x, &dx, alpha);
    assert!(
        (change - alpha * slope).abs() <= 1e-6 * (alpha * slope).abs(),
        "change {change:e}, first order {:e}",
        alpha * slope
    );
}

#[test]
fn the_sum_of_terms_is_the_incremental_potential_on_the_lab_cloth() {
    // An independent formula of the objective: the inertia and gravity of the free
    // particles, every spring's energy, the damping along the directions at x_n.
    let mut system = SpringSystem::cloth(&ClothGrid::lab()).unwrap();
    let mut rng = Rng(2024);
    let fixed = system.fixed().to_vec();
    let xn: Vec<DVec3> = system
        .positions()
        .iter()
        .zip(&fixed)
        .map(|(&p, &f)| if f { p } else { p + rng.vec(0.05) })
        .collect();
    let vn: Vec<DVec3> = (0..xn.len()).map(|_| rng.vec(0.5)).collect();
    system.set_state(&xn, &vn).unwrap();
    let vn = system.velocities().to_vec();
    let h = 1.0 / 60.0;
    let x: Vec<DVec3> = xn
        .iter()
        .zip(&fixed)
        .map(|(&p, &f)| if f { p } else { p + rng.vec(0.02) })
        .collect();
    let m = system.masses();
    let gravity = system.material().gravity;
    let c = system.material().damping;
    let mut expected = 0.0;
    let mut magnitude = 0.0;
    for i in 0..x.len() {
        if !fixed[i] {
            let y = xn[i] + h * vn[i];
            let inertia = 0.5 * m[i] / (h * h) * (x[i] - y).length_squared();
            let potential = -m[i] * gravity.dot(x[i]);
            expected += inertia + potential;
            magnitude += inertia + potential.abs();
        }
    }
    for s in system.springs() {
        let l = (x[s.a] - x[s.b]).length();
        let elastic = 0.5 * s.stiffness * (l - s.rest_length).powi(2);
        let dn = xn[s.a] - xn[s.b];
        let u = dn / dn.length();
        let e = u.dot((x[s.a] - x[s.b]) - dn);
        let damping = 0.5 * c / h * e * e;
        expected += elastic + damping;
        magnitude += elastic + damping;
    }
    let got = incremental_potential(&system, h, &x);
    assert!(
        (got - expected).abs() <= 1e-13 * magnitude,
        "terms {got}, formula {expected} (difference {:e})",
        got - expected
    );
    // And through the integrator's own list of terms.
    let be = sinew_spring_sim::BackwardEuler::new(&system, Default::default()).unwrap();
    let names: Vec<&str> = be.potential().terms().iter().map(|t| t.name()).collect();
    assert_eq!(names, ["inertia", "gravity", "springs", "axial damping"]);
}

#[test]
fn the_pattern_sink_matches_the_product_sink_and_finds_general_pairs() {
    let case = case(3);
    let mut rng = Rng(5);
    let x = case.point(&mut rng);
    let pattern = HessianPattern::new(&case.system);
    let mut potential = {
        let mut p = Potential::mass_spring(&case.system);
        p.begin_step(&case.step());
        p
    };
    // y = H z through the assembled pattern (its symmetric product) and through the
    // product sink.
    let n = x.len();
    let z = case.direction(&mut rng, 1.0);
    let mut by_product = vec![DVec3::ZERO; n];
    potential.add_hessian(
        &case.step(),
        &x,
        Curvature::Clamped,
        &mut HessianSink::product(case.system.fixed(), &z, &mut by_product),
    );
    let triplets = sinew_spring_sim::newton_matrix_triplets(&case.system, case.h);
    // newton_matrix_triplets assembles at the system's positions: compare there.
    let mut at_start = vec![DVec3::ZERO; n];
    potential.add_hessian(
        &case.step(),
        &case.x_ref,
        Curvature::Clamped,
        &mut HessianSink::product(case.system.fixed(), &z, &mut at_start),
    );
    let free: Vec<usize> = (0..n).filter(|&p| !case.system.fixed()[p]).collect();
    let zr: Vec<f64> = free.iter().flat_map(|&p| z[p].to_array()).collect();
    let mut yr = vec![0.0; zr.len()];
    for &(r, c, v) in &triplets {
        yr[r] += v * zr[c];
        if r != c {
            yr[c] += v * zr[r];
        }
    }
    let scale = yr.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (f, &p) in free.iter().enumerate() {
        for c in 0..3 {
            assert!(
                (yr[3 * f + c] - at_start[p][c]).abs() <= 1e-12 * scale,
                "particle {p} axis {c}: pattern {} vs product {}",
                yr[3 * f + c],
                at_start[p][c]
            );
        }
    }
    assert!(by_product.iter().all(|v| v.is_finite()));
    // A general pair the pattern has: adding B at (a, b) through add_pair equals adding
    // it as the coupling of an edge; a pair it lacks is reported and changes nothing.
    let fixed = case.system.fixed();
    let (edge, s) = case
        .system
        .springs()
        .iter()
        .enumerate()
        .find(|(_, s)| !fixed[s.a] && !fixed[s.b])
        .unwrap();
    let (a, b) = (s.a, s.b);
    let k = sinew_math::DMat3::from_cols_array(&[2.0, 0.5, 0.1, 0.5, 3.0, 0.2, 0.1, 0.2, 4.0]);
    let mut v1 = vec![0.0; pattern.nnz()];
    let mut v2 = vec![0.0; pattern.nnz()];
    {
        let mut sink = HessianSink::values(&pattern, &mut v1);
        sink.add_pair(a, a, &k).unwrap();
        sink.add_pair(b, b, &k).unwrap();
        sink.add_pair(a, b, &(-k)).unwrap();
    }
    {
        let mut sink = HessianSink::values(&pattern, &mut v2);
        sink.add_edge(
            edge,
            a,
            b,
            sinew_spring_sim::potential::SymBlock::from_lower(&k),
        );
    }
    let worst = v1
        .iter()
        .zip(&v2)
        .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
    assert!(worst <= 1e-15, "add_pair and add_edge differ by {worst:e}");
    assert!(v1.iter().any(|&v| v != 0.0));
    // Particles 0 and 15 are opposite corners of the 4 x 4 sheet: no spring joins them.
    let far = case.system.len() - 1;
    let free_pair = (1, far - 1);
    let mut v3 = vec![0.0; pattern.nnz()];
    let mut sink = HessianSink::values(&pattern, &mut v3);
    assert_eq!(
        sink.add_pair(free_pair.0, free_pair.1, &k),
        Err(MissingPair {
            i: free_pair.0,
            j: free_pair.1
        })
    );
    assert!(v3.iter().all(|&v| v == 0.0));
}
