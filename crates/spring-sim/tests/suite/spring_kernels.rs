//! Finite-difference checks of the spring gradient and Hessian block, and the properties
//! of the PSD clamp, on random springs: stretched, compressed and near zero length.

use crate::common::{Sample, XorshiftStar as Rng};
use sinew_math::{DMat3, DVec3};
use sinew_spring_sim::reference::flawed_report_method::report_block;
use sinew_spring_sim::spring::{Curvature, energy, energy_change, gradient, hessian_block};

/// A random unit vector, uniform in direction (by rejection from the cube).
fn unit(rng: &mut Rng) -> DVec3 {
    loop {
        let v = rng.vec(1.0);
        if v.length() > 0.1 && v.length() < 1.0 {
            return v.normalize();
        }
    }
}

/// Random springs as (x_a, x_b, rest length, stiffness), with `l / L` in `ratio`.
fn springs(seed: u64, ratio: (f64, f64)) -> Vec<(DVec3, DVec3, f64, f64)> {
    let mut rng = Rng(seed);
    (0..200)
        .map(|_| {
            let rest = 0.1 + 2.0 * rng.next();
            let l = rest * (ratio.0 + (ratio.1 - ratio.0) * rng.next());
            let x_b = DVec3::new(rng.next(), rng.next(), rng.next()) * 4.0 - DVec3::splat(2.0);
            let x_a = x_b + unit(&mut rng) * l;
            (x_a, x_b, rest, 1.0 + 1000.0 * rng.next())
        })
        .collect()
}

fn max_abs(m: DMat3) -> f64 {
    m.to_cols_array().iter().fold(0.0f64, |a, v| a.max(v.abs()))
}

/// Central differences of the energy give the gradient; of the gradient, the exact
/// (unclamped) Hessian block `K` for `d/dx_a` and `-K` for `d/dx_b`.
fn check_finite_differences(list: &[(DVec3, DVec3, f64, f64)], eps_rel: f64) {
    for &(xa, xb, rest, k) in list {
        let l = (xa - xb).length();
        let eps = eps_rel * l;
        let g = gradient(xa, xb, rest, k);
        let mut fd = DVec3::ZERO;
        let mut fd_hess_a = [DVec3::ZERO; 3];
        let mut fd_hess_b = [DVec3::ZERO; 3];
        for c in 0..3 {
            let mut e = DVec3::ZERO;
            e[c] = eps;
            fd[c] = (energy(xa + e, xb, rest, k) - energy(xa - e, xb, rest, k)) / (2.0 * eps);
            fd_hess_a[c] =
                (gradient(xa + e, xb, rest, k) - gradient(xa - e, xb, rest, k)) / (2.0 * eps);
            fd_hess_b[c] =
                (gradient(xa, xb + e, rest, k) - gradient(xa, xb - e, rest, k)) / (2.0 * eps);
        }
        let scale = k * (l + rest);
        assert!((fd - g).length() <= 1e-6 * scale, "gradient {g} vs fd {fd}");
        let hk = hessian_block(xa, xb, rest, k, Curvature::Exact);
        let fd_a = DMat3::from_cols(fd_hess_a[0], fd_hess_a[1], fd_hess_a[2]);
        let fd_b = DMat3::from_cols(fd_hess_b[0], fd_hess_b[1], fd_hess_b[2]);
        let hscale = k * (1.0 + rest / l);
        assert!(max_abs(fd_a - hk) <= 1e-5 * hscale, "K {hk} vs fd {fd_a}");
        assert!(max_abs(fd_b + hk) <= 1e-5 * hscale, "-K {hk} vs fd {fd_b}");
        // The report's block differs from the exact one except at rest length.
        let wrong = report_block(xa, xb, rest, k);
        let off = (1.0 - rest / l).abs() * k;
        assert!(
            (max_abs(wrong - hk)
                - off * max_abs(sinew_spring_sim::spring::outer((xa - xb).normalize())))
            .abs()
                <= 1e-6 * hscale,
            "the report's block is off by exactly k (1 - L/l) u u^T"
        );
    }
}

#[test]
fn gradient_and_hessian_match_finite_differences_stretched() {
    check_finite_differences(&springs(1, (1.05, 3.0)), 1e-5);
}

#[test]
fn gradient_and_hessian_match_finite_differences_compressed() {
    check_finite_differences(&springs(2, (0.2, 0.95)), 1e-5);
}

#[test]
fn gradient_and_hessian_match_finite_differences_near_zero_length() {
    // l = 1e-3 L .. 1e-2 L: the across term is -100..-1000 times k, still exact.
    check_finite_differences(&springs(3, (1e-3, 1e-2)), 1e-6);
}

#[test]
fn clamped_block_equals_exact_when_stretched() {
    for (xa, xb, rest, k) in springs(4, (1.0, 3.0)) {
        let clamped = hessian_block(xa, xb, rest, k, Curvature::Clamped);
        let exact = hessian_block(xa, xb, rest, k, Curvature::Exact);
        assert_eq!(clamped, exact);
    }
}

/// When compressed, the clamped block is PSD and is the projection of the exact one: it
/// keeps the eigenpair `(k, u)` and maps the negative eigenvalue `k (1 - L/l)` of every
/// direction across the spring to 0.
#[test]
fn clamped_block_is_the_psd_projection_when_compressed() {
    let mut rng = Rng(5);
    for (xa, xb, rest, k) in springs(6, (1e-3, 0.99)) {
        let clamped = hessian_block(xa, xb, rest, k, Curvature::Clamped);
        let exact = hessian_block(xa, xb, rest, k, Curvature::Exact);
        let u = (xa - xb).normalize();
        let w = u.any_orthonormal_vector();
        let w2 = u.cross(w);
        assert!((clamped * u - k * u).length() <= 1e-12 * k);
        assert!((clamped * w).length() <= 1e-12 * k);
        assert!((clamped * w2).length() <= 1e-12 * k);
        let across = k * (1.0 - rest / (xa - xb).length());
        assert!(across < 0.0);
        assert!((exact * w - across * w).length() <= 1e-9 * across.abs());
        for _ in 0..20 {
            let v = unit(&mut rng);
            assert!(v.dot(clamped * v) >= -1e-12 * k);
        }
        assert!(w.dot(exact * w) < 0.0, "the exact block is indefinite here");
    }
}

/// The softened block keeps the eigenpair `(k, u)`, has `(1 - theta) k (1 - L/l)` across
/// a compressed spring (so it is the exact block at `theta = 0`, the clamped one at 1, and
/// moves linearly between them, growing in the PSD order), and is the exact block when
/// the spring is stretched, whatever `theta`.
#[test]
fn softened_block_interpolates_the_compressed_curvature() {
    let mut rng = Rng(11);
    for (xa, xb, rest, k) in springs(12, (1e-3, 0.99)) {
        let exact = hessian_block(xa, xb, rest, k, Curvature::Exact);
        let clamped = hessian_block(xa, xb, rest, k, Curvature::Clamped);
        assert_eq!(
            hessian_block(xa, xb, rest, k, Curvature::Softened(0.0)),
            exact
        );
        assert_eq!(
            hessian_block(xa, xb, rest, k, Curvature::Softened(1.0)),
            clamped
        );
        let u = (xa - xb).normalize();
        let w = u.any_orthonormal_vector();
        let across = k * (1.0 - rest / (xa - xb).length());
        let mut previous = exact;
        for theta in [0.25, 0.5, 0.9] {
            let soft = hessian_block(xa, xb, rest, k, Curvature::Softened(theta));
            let scale = k + across.abs();
            assert!((soft * u - k * u).length() <= 1e-12 * scale);
            assert!((soft * w - (1.0 - theta) * across * w).length() <= 1e-12 * scale);
            // Larger theta: a larger quadratic form in every direction.
            for _ in 0..10 {
                let v = unit(&mut rng);
                assert!(v.dot(soft * v) >= v.dot(previous * v) - 1e-12 * scale);
            }
            previous = soft;
        }
    }
    for (xa, xb, rest, k) in springs(13, (1.0, 3.0)) {
        assert_eq!(
            hessian_block(xa, xb, rest, k, Curvature::Softened(0.5)),
            hessian_block(xa, xb, rest, k, Curvature::Exact)
        );
    }
}

#[test]
fn energy_change_matches_the_difference_of_energies() {
    let mut rng = Rng(7);
    for (xa, xb, rest, k) in springs(8, (0.01, 3.0)) {
        let delta = unit(&mut rng) * rng.next();
        let direct = energy(xa + delta, xb, rest, k) - energy(xa, xb, rest, k);
        let change = energy_change(xa - xb, delta, rest, k);
        let scale = energy(xa + delta, xb, rest, k) + energy(xa, xb, rest, k);
        assert!((direct - change).abs() <= 1e-12 * scale.max(1e-300));
    }
    // A change far below the energy keeps its sign and size.
    let d = DVec3::new(2.0, 0.0, 0.0);
    let delta = DVec3::new(-1e-13, 0.0, 0.0);
    let change = energy_change(d, delta, 1.0, 1.0);
    assert!((change - (-1e-13)).abs() <= 1e-25, "{change}");
}

#[test]
fn zero_length_spring_has_defined_values() {
    let x = DVec3::new(0.3, 0.2, 0.1);
    assert_eq!(gradient(x, x, 1.0, 5.0), DVec3::ZERO);
    assert_eq!(
        hessian_block(x, x, 1.0, 5.0, Curvature::Clamped),
        DMat3::ZERO
    );
    // A zero-rest-length spring is linear: its Hessian is k I everywhere.
    assert_eq!(
        hessian_block(x, x, 0.0, 5.0, Curvature::Clamped),
        DMat3::from_diagonal(DVec3::splat(5.0))
    );
    assert_eq!(
        hessian_block(x + DVec3::X, x, 0.0, 5.0, Curvature::Exact),
        DMat3::from_diagonal(DVec3::splat(5.0))
    );
}
