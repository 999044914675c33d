//! Contact kernels against exact answers: signed distances, the barrier and friction
//! by central finite differences and closed forms, the PSD projection by its defining
//! properties, and the barrier stiffness rule.

use sinew_math::{DMat3, DVec3};
use sinew_spring_sim::contact::barrier::{
    balanced_kappa, barrier, barrier_first_derivative, barrier_second_derivative, minimum_kappa,
    point_barrier_exact_hessian, point_barrier_gradient, point_barrier_projected_hessian,
};
use sinew_spring_sim::contact::friction::{f0, f1, f1_derivative};
use sinew_spring_sim::contact::psd::{project_psd, symmetric_eigen};
use sinew_spring_sim::contact::{
    AdaptiveKappa, Collider, ContactSettings, FrictionContact, KappaSettings, PointBarrier, Shape,
    point_barrier, signed_distance,
};

/// A small deterministic generator (splitmix64) for sample points.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
    fn vec(&mut self, r: f64) -> DVec3 {
        DVec3::new(self.range(-r, r), self.range(-r, r), self.range(-r, r))
    }
}

fn fd_gradient(f: impl Fn(DVec3) -> f64, x: DVec3, h: f64) -> DVec3 {
    let e = [DVec3::X, DVec3::Y, DVec3::Z];
    let g = |k: usize| (f(x + h * e[k]) - f(x - h * e[k])) / (2.0 * h);
    DVec3::new(g(0), g(1), g(2))
}

fn fd_jacobian(f: impl Fn(DVec3) -> DVec3, x: DVec3, h: f64) -> DMat3 {
    let e = [DVec3::X, DVec3::Y, DVec3::Z];
    let c = |k: usize| (f(x + h * e[k]) - f(x - h * e[k])) / (2.0 * h);
    DMat3::from_cols(c(0), c(1), c(2))
}

fn max_abs(m: DMat3) -> f64 {
    m.to_cols_array().iter().fold(0.0, |a, v| a.max(v.abs()))
}

fn shapes() -> Vec<Shape> {
    vec![
        Shape::HalfSpace {
            point: DVec3::new(0.1, -0.2, 0.3),
            normal: DVec3::new(1.0, 2.0, -0.5).normalize(),
        },
        Shape::Sphere {
            center: DVec3::new(0.2, -0.1, 0.05),
            radius: 0.4,
        },
        Shape::Capsule {
            a: DVec3::new(-0.5, 0.1, 0.0),
            b: DVec3::new(0.4, -0.2, 0.3),
            radius: 0.25,
        },
    ]
}

/// Whether a capsule's closest axis point is well inside one region (away from the
/// planes through the ends, where the Hessian jumps).
fn away_from_capsule_kinks(shape: &Shape, x: DVec3) -> bool {
    match *shape {
        Shape::Capsule { a, b, .. } => {
            let t = (b - a).dot(x - a) / (b - a).length_squared();
            (t - 0.0).abs() > 0.02 && (t - 1.0).abs() > 0.02
        }
        _ => true,
    }
}

#[test]
fn distances_match_closed_forms() {
    let plane = Shape::HalfSpace {
        point: DVec3::new(0.0, 1.0, 0.0),
        normal: DVec3::Y,
    };
    let sd = signed_distance(&plane, DVec3::new(3.0, 2.5, -1.0), 0.0);
    assert_eq!(sd.distance, 1.5);
    assert_eq!(sd.normal, DVec3::Y);
    assert_eq!(sd.closest_point, DVec3::new(3.0, 1.0, -1.0));
    let sd = signed_distance(&plane, DVec3::new(0.0, 0.5, 0.0), 0.1);
    assert!((sd.distance - -0.6).abs() < 1e-15, "{}", sd.distance);

    let sphere = Shape::Sphere {
        center: DVec3::new(1.0, 0.0, 0.0),
        radius: 0.5,
    };
    let sd = signed_distance(&sphere, DVec3::new(1.0, 0.0, 2.0), 0.25);
    assert_eq!(sd.distance, 1.25);
    assert_eq!(sd.normal, DVec3::Z);
    assert_eq!(sd.closest_point, DVec3::new(1.0, 0.0, 0.5));
    // Hessian (I - n n^T)/|x - c| with n = z, |x - c| = 2.
    assert_eq!(sd.hessian, DMat3::from_diagonal(DVec3::new(0.5, 0.5, 0.0)));

    let capsule = Shape::Capsule {
        a: DVec3::new(-1.0, 0.0, 0.0),
        b: DVec3::new(1.0, 0.0, 0.0),
        radius: 0.5,
    };
    // Beside the body: distance to the axis line 2 minus the radius; Hessian
    // (I - e e^T - n n^T)/rho = diag(0, 0, 1/2).
    let sd = signed_distance(&capsule, DVec3::new(0.3, 2.0, 0.0), 0.0);
    assert!((sd.distance - 1.5).abs() < 1e-15);
    assert!((sd.normal - DVec3::Y).length() < 1e-15);
    assert!(max_abs(sd.hessian - DMat3::from_diagonal(DVec3::new(0.0, 0.0, 0.5))) < 1e-15);
    // Beyond end b: distance to b.
    let sd = signed_distance(&capsule, DVec3::new(4.0, 4.0, 0.0), 0.0);
    assert!((sd.distance - 4.5).abs() < 1e-15);
    assert!((sd.normal - DVec3::new(0.6, 0.8, 0.0)).length() < 1e-15);
    // Inside, between the axis and the surface.
    let sd = signed_distance(&capsule, DVec3::new(-0.2, 0.0, 0.1), 0.0);
    assert!((sd.distance - -0.4).abs() < 1e-15);
}

#[test]
fn degenerate_points_have_defined_answers() {
    let sphere = Shape::Sphere {
        center: DVec3::ONE,
        radius: 0.3,
    };
    let sd = signed_distance(&sphere, DVec3::ONE, 0.0);
    assert_eq!(sd.distance, -0.3);
    assert_eq!(sd.normal, DVec3::Y);
    assert_eq!(sd.hessian, DMat3::ZERO);
    let capsule = Shape::Capsule {
        a: DVec3::ZERO,
        b: DVec3::new(0.0, 2.0, 0.0),
        radius: 0.3,
    };
    let sd = signed_distance(&capsule, DVec3::new(0.0, 1.0, 0.0), 0.0);
    assert_eq!(sd.distance, -0.3);
    assert!((sd.normal.length() - 1.0).abs() < 1e-15);
    assert!(
        sd.normal.dot(DVec3::Y).abs() < 1e-15,
        "normal across the axis"
    );
    assert!(sd.hessian.is_finite());
    // A capsule with coincident ends is the sphere at that point.
    let pinched = Shape::Capsule {
        a: DVec3::ONE,
        b: DVec3::ONE,
        radius: 0.3,
    };
    let x = DVec3::new(0.2, 1.7, 1.1);
    let s = signed_distance(&sphere, x, 0.01);
    let c = signed_distance(&pinched, x, 0.01);
    assert_eq!(s.distance, c.distance);
    assert_eq!(s.normal, c.normal);
    assert_eq!(s.hessian, c.hessian);
}

#[test]
fn distance_derivatives_match_finite_differences() {
    let mut rng = Rng(7);
    for shape in shapes() {
        let mut checked = 0;
        while checked < 200 {
            let x = rng.vec(1.5);
            let sd = signed_distance(&shape, x, 0.0);
            if sd.distance < 0.05 || !away_from_capsule_kinks(&shape, x) {
                continue;
            }
            checked += 1;
            let h = 1e-6;
            let g = fd_gradient(|p| signed_distance(&shape, p, 0.0).distance, x, h);
            assert!(
                (g - sd.normal).length() < 1e-8,
                "{shape:?} at {x}: gradient {} vs fd {g}",
                sd.normal
            );
            assert!((sd.normal.length() - 1.0).abs() < 1e-14);
            let hess = fd_jacobian(|p| signed_distance(&shape, p, 0.0).normal, x, h);
            assert!(
                max_abs(hess - sd.hessian) < 1e-6,
                "{shape:?} at {x}: hessian {} vs fd {hess}",
                sd.hessian
            );
            // The closest point is on the surface and x is along the normal from it.
            let on = signed_distance(&shape, sd.closest_point, 0.0).distance;
            assert!(on.abs() < 1e-12, "closest point off the surface by {on}");
            assert!((x - sd.closest_point - sd.distance * sd.normal).length() < 1e-12);
        }
    }
}

#[test]
fn kinematic_pose_and_surface_velocity() {
    use std::f64::consts::FRAC_PI_2;
    // A capsule along x about its midpoint (1, 0, 0), moving at (0, 1, 0) and turning
    // a quarter turn per second about z.
    let c = Collider::capsule(DVec3::new(0.0, 0.0, 0.0), DVec3::new(2.0, 0.0, 0.0), 0.1)
        .moving(DVec3::Y, DVec3::new(0.0, 0.0, FRAC_PI_2));
    let Shape::Capsule { a, b, .. } = c.at(1.0) else {
        panic!("shape changed kind");
    };
    assert!((a - DVec3::new(1.0, 0.0, 0.0)).length() < 1e-15, "{a}");
    assert!((b - DVec3::new(1.0, 2.0, 0.0)).length() < 1e-15, "{b}");
    // Velocity of the material point at end b at t = 1: v + omega x (b - r) =
    // (0, 1, 0) + (pi/2) z x (0, 1, 0) = (-pi/2, 1, 0); compare with the motion of b.
    let v = c.surface_velocity(b, 1.0);
    let Shape::Capsule { b: b_after, .. } = c.at(1.0 + 1e-6) else {
        panic!()
    };
    let Shape::Capsule { b: b_before, .. } = c.at(1.0 - 1e-6) else {
        panic!()
    };
    let fd = (b_after - b_before) / 2e-6;
    assert!((v - DVec3::new(-FRAC_PI_2, 1.0, 0.0)).length() < 1e-15);
    assert!((v - fd).length() < 1e-8, "{v} vs {fd}");
    // A spinning sphere stays where its centre is.
    let s = Collider::sphere(DVec3::ONE, 0.5).moving(DVec3::ZERO, DVec3::new(1.0, 2.0, 3.0));
    assert_eq!(
        s.at(3.7),
        Shape::Sphere {
            center: DVec3::ONE,
            radius: 0.5
        }
    );
    // A tilting half-space keeps a unit normal.
    let g = Collider::ground(0.0).moving(DVec3::ZERO, DVec3::new(0.3, 0.0, 0.0));
    let Shape::HalfSpace { normal, point } = g.at(2.0) else {
        panic!()
    };
    assert!((normal - DVec3::new(0.0, 0.6f64.cos(), 0.6f64.sin())).length() < 1e-15);
    assert_eq!(point, DVec3::ZERO);
}

#[test]
fn barrier_derivatives_match_finite_differences_and_signs() {
    for dhat in [1e-3, 1.0, 7.0] {
        for i in 1..200 {
            let d = dhat * i as f64 / 200.0;
            let h = 1e-6 * d.min(dhat - d);
            let b1 = (barrier(d + h, dhat) - barrier(d - h, dhat)) / (2.0 * h);
            let b2 = (barrier_first_derivative(d + h, dhat)
                - barrier_first_derivative(d - h, dhat))
                / (2.0 * h);
            let e1 = barrier_first_derivative(d, dhat);
            let e2 = barrier_second_derivative(d, dhat);
            assert!((b1 - e1).abs() <= 1e-6 * e1.abs().max(dhat), "b' at {d}");
            assert!((b2 - e2).abs() <= 1e-6 * e2.abs().max(1.0), "b'' at {d}");
            assert!(
                barrier(d, dhat) > 0.0 && e1 < 0.0 && e2 > 0.0,
                "signs at {d}"
            );
        }
        // C2 at dhat: all three vanish there and stay zero beyond.
        for d in [dhat, 1.5 * dhat] {
            assert_eq!(barrier(d, dhat), 0.0);
            assert_eq!(barrier_first_derivative(d, dhat), 0.0);
            assert_eq!(barrier_second_derivative(d, dhat), 0.0);
        }
        let near = dhat * (1.0 - 1e-6);
        assert!(barrier(near, dhat) < 1e-17 * dhat * dhat);
        assert!(barrier_first_derivative(near, dhat).abs() < 1e-11 * dhat);
        assert!(barrier_second_derivative(near, dhat) < 1e-5);
        // Infinite at and inside contact, and growing without bound toward it.
        assert_eq!(barrier(0.0, dhat), f64::INFINITY);
        assert_eq!(barrier(-dhat, dhat), f64::INFINITY);
        assert!(barrier(1e-12 * dhat, dhat) > 20.0 * dhat * dhat);
    }
    // A value by hand: d = dhat/2 gives (dhat/2)^2 ln 2 and b' = -dhat (ln 2 + 1/2).
    let dhat = 2.0;
    assert!((barrier(1.0, dhat) - std::f64::consts::LN_2).abs() < 1e-15);
    assert!(
        (barrier_first_derivative(1.0, dhat) + 2.0 * (std::f64::consts::LN_2 + 0.5)).abs() < 1e-15
    );
}

#[test]
fn point_barrier_derivatives_and_projection() {
    let mut rng = Rng(11);
    let dhat = 0.2;
    let kappa = 3.0;
    for shape in shapes() {
        let mut checked = 0;
        while checked < 100 {
            let x = rng.vec(1.2);
            let sd = signed_distance(&shape, x, 0.01);
            let usable = sd.distance > 0.02
                && sd.distance < 0.98 * dhat
                && away_from_capsule_kinks(&shape, x);
            if !usable {
                continue;
            }
            checked += 1;
            let energy =
                |p: DVec3| kappa * barrier(signed_distance(&shape, p, 0.01).distance, dhat);
            let gradient =
                |p: DVec3| match point_barrier(kappa, dhat, &signed_distance(&shape, p, 0.01)) {
                    PointBarrier::Active { gradient, .. } => gradient,
                    other => panic!("{other:?}"),
                };
            let PointBarrier::Active {
                energy: e,
                gradient: g,
                hessian,
            } = point_barrier(kappa, dhat, &sd)
            else {
                panic!("inactive inside dhat");
            };
            assert_eq!(e, energy(x));
            let h = 1e-7;
            let fd_g = fd_gradient(energy, x, h);
            assert!(
                (fd_g - g).length() <= 1e-6 * g.length().max(1e-3),
                "{shape:?} {x}: {g} vs {fd_g}"
            );
            let exact = point_barrier_exact_hessian(kappa, dhat, &sd);
            let fd_h = fd_jacobian(gradient, x, h);
            assert!(
                max_abs(fd_h - exact) <= 1e-5 * max_abs(exact),
                "{shape:?} {x}: {exact} vs {fd_h}"
            );
            // n is an eigenvector of H_d with eigenvalue 0 and the others are >= 0, so
            // with b' < 0 the exact projection is kappa b'' n n^T.
            let b2 = barrier_second_derivative(sd.distance, dhat);
            let expected = DMat3::from_cols(
                sd.normal * sd.normal.x,
                sd.normal * sd.normal.y,
                sd.normal * sd.normal.z,
            ) * (kappa * b2);
            assert!(
                max_abs(hessian - expected) <= 1e-10 * max_abs(expected),
                "{shape:?}: projected {hessian} vs {expected}"
            );
            // The closed form is the general eigen-decomposition projection of the exact
            // Hessian, and the gradient-only kernel gives the same gradient.
            let general = project_psd(exact);
            assert!(
                max_abs(hessian - general) <= 1e-10 * max_abs(general),
                "{shape:?}: closed form {hessian} vs projected {general}"
            );
            assert_eq!(
                point_barrier_projected_hessian(kappa, dhat, &sd),
                hessian,
                "{shape:?}"
            );
            assert_eq!(
                point_barrier_gradient(kappa, dhat, &sd),
                Some(g),
                "{shape:?}"
            );
        }
    }
    let plane = &shapes()[0];
    assert_eq!(
        point_barrier(
            kappa,
            dhat,
            &signed_distance(
                plane,
                DVec3::new(0.1, -0.2, 0.3) + 0.5 * DVec3::new(1.0, 2.0, -0.5).normalize(),
                0.0
            )
        ),
        PointBarrier::Inactive
    );
    assert_eq!(
        point_barrier(
            kappa,
            dhat,
            &signed_distance(plane, DVec3::new(0.1, -0.2, 0.3), 0.0)
        ),
        PointBarrier::Penetrating
    );
}

fn random_symmetric(rng: &mut Rng) -> DMat3 {
    let m = DMat3::from_cols(rng.vec(1.0), rng.vec(1.0), rng.vec(1.0));
    m + m.transpose()
}

fn check_eigen(m: DMat3) {
    let (values, vectors) = symmetric_eigen(m);
    let scale = max_abs(m).max(1e-300);
    let rebuilt = vectors * DMat3::from_diagonal(values) * vectors.transpose();
    assert!(
        max_abs(rebuilt - m) <= 1e-13 * scale,
        "{m}: rebuilt {rebuilt}"
    );
    assert!(max_abs(vectors.transpose() * vectors - DMat3::IDENTITY) <= 1e-14);
    assert!(values.x <= values.y && values.y <= values.z);
    let p = project_psd(m);
    let (pv, _) = symmetric_eigen(p);
    assert!(pv.x >= -1e-14 * scale, "projection has eigenvalue {}", pv.x);
    assert!(
        max_abs(project_psd(p) - p) <= 1e-13 * scale,
        "not idempotent"
    );
    assert!(max_abs(p - p.transpose()) == 0.0 || max_abs(p - p.transpose()) <= 1e-15 * scale);
    // The clamped eigenvalues are exactly what the projection removes.
    let removed: f64 = values.min(DVec3::ZERO).length_squared();
    let dist = (m - p).to_cols_array().iter().map(|v| v * v).sum::<f64>();
    assert!(
        (dist - removed).abs() <= 1e-12 * scale * scale,
        "{dist} vs {removed}"
    );
}

#[test]
fn psd_projection_of_random_and_repeated_eigenvalues() {
    let mut rng = Rng(3);
    for _ in 0..500 {
        check_eigen(random_symmetric(&mut rng));
    }
    // Repeated and nearly repeated eigenvalues, rotated; diagonal and zero matrices.
    let q = sinew_math::DQuat::from_scaled_axis(DVec3::new(0.3, -1.1, 0.7));
    let r = DMat3::from_quat(q);
    for diag in [
        DVec3::new(1.0, 1.0, -1.0),
        DVec3::new(-2.0, -2.0, -2.0),
        DVec3::new(1.0, 1.0 + 1e-12, -3.0),
        DVec3::new(0.0, 0.0, 0.0),
        DVec3::new(1e-200, -1e-200, 5e-201),
        DVec3::new(1e150, -1e150, 3.0),
    ] {
        let m = r * DMat3::from_diagonal(diag) * r.transpose();
        check_eigen(m);
        check_eigen(DMat3::from_diagonal(diag));
        let p = project_psd(m);
        let expected = r * DMat3::from_diagonal(diag.max(DVec3::ZERO)) * r.transpose();
        assert!(
            max_abs(p - expected) <= 1e-13 * max_abs(m).max(1e-300),
            "{diag}: {p} vs {expected}"
        );
    }
    // The projection is no farther from m than any PSD matrix sampled.
    for _ in 0..100 {
        let m = random_symmetric(&mut rng);
        let p = project_psd(m);
        let dist = |a: DMat3| (m - a).to_cols_array().iter().map(|v| v * v).sum::<f64>();
        for _ in 0..20 {
            let b = DMat3::from_cols(rng.vec(1.0), rng.vec(1.0), rng.vec(1.0));
            let psd = b * b.transpose();
            assert!(dist(p) <= dist(psd) + 1e-14);
        }
    }
}

#[test]
fn kappa_rule() {
    let (dhat, mass, g, h) = (1e-3, 5e-4, 9.81, 1.0 / 60.0);
    let kmin = minimum_kappa(dhat, mass, g, h);
    // At half dhat the barrier force equals the force scale m (|g| + dhat/h^2).
    let force = -kmin * barrier_first_derivative(0.5 * dhat, dhat);
    assert!((force - mass * (g + dhat / (h * h))).abs() <= 1e-14 * force);
    // Balancing: g_E = -c g_B is cancelled exactly by kappa = c.
    let gb = [
        DVec3::new(0.0, -2.0, 0.0),
        DVec3::ZERO,
        DVec3::new(0.1, -1.0, 0.3),
    ];
    let ge: Vec<DVec3> = gb.iter().map(|b| -7.5 * *b).collect();
    let k = balanced_kappa(&ge, &gb).unwrap();
    assert!((k - 7.5).abs() < 1e-14);
    assert_eq!(balanced_kappa(&ge, &[DVec3::ZERO; 3]), None);
    let away: Vec<DVec3> = gb.iter().map(|b| 2.0 * *b).collect();
    assert_eq!(balanced_kappa(&away, &gb), None);
    // Clamped to [kmin, 100 kmin].
    let s = KappaSettings::default();
    assert_eq!(AdaptiveKappa::new(kmin, None, s).kappa, kmin);
    assert_eq!(AdaptiveKappa::new(kmin, Some(1e-9 * kmin), s).kappa, kmin);
    assert_eq!(
        AdaptiveKappa::new(kmin, Some(3.0 * kmin), s).kappa,
        3.0 * kmin
    );
    assert_eq!(
        AdaptiveKappa::new(kmin, Some(1e9 * kmin), s).kappa,
        100.0 * kmin
    );
    // Doubling only while the distance is too small and falling, up to the cap.
    let mut a = AdaptiveKappa::new(kmin, None, s);
    assert!(!a.update(0.5 * dhat, dhat));
    assert!(a.update(0.005 * dhat, dhat));
    assert_eq!(a.kappa, 2.0 * kmin);
    assert!(!a.update(0.006 * dhat, dhat), "rising distance: no growth");
    assert!(a.update(0.004 * dhat, dhat));
    assert_eq!(a.kappa, 4.0 * kmin);
    for i in 0..20 {
        a.update(1e-4 * dhat / (i + 1) as f64, dhat);
    }
    assert_eq!(a.kappa, 100.0 * kmin);
}

#[test]
fn balancing_start_is_applied_once_and_clamped() {
    let kmin = 2.0;
    let s = KappaSettings::default();
    // Within the bounds: taken as is, once.
    let mut a = AdaptiveKappa::new(kmin, None, s);
    assert!(!a.balanced);
    assert!(!a.start_balanced(-1.0), "no balance: nothing set");
    assert!(!a.start_balanced(f64::NAN));
    assert!(!a.balanced && a.kappa == kmin);
    assert!(a.start_balanced(7.0));
    assert_eq!(a.kappa, 7.0);
    assert!(!a.start_balanced(30.0), "only the first balance counts");
    assert_eq!(a.kappa, 7.0);
    // Clamped to [kmin, 100 kmin].
    let mut low = AdaptiveKappa::new(kmin, None, s);
    assert!(low.start_balanced(1e-6));
    assert_eq!(low.kappa, kmin);
    let mut high = AdaptiveKappa::new(kmin, None, s);
    assert!(high.start_balanced(1e9));
    assert_eq!(high.kappa, 100.0 * kmin);
    // A stiffness the growth rule already raised is not lowered.
    let mut grown = AdaptiveKappa::new(kmin, None, s);
    assert!(grown.update(1e-6, 1.0));
    assert_eq!(grown.kappa, 2.0 * kmin);
    assert!(grown.start_balanced(1.5 * kmin));
    assert_eq!(grown.kappa, 2.0 * kmin);
    // A start given at construction counts as the balancing start.
    assert!(AdaptiveKappa::new(kmin, Some(3.0), s).balanced);
}

#[test]
fn mollifier_derivatives() {
    let eps = 1e-3 / 60.0;
    for i in 1..400 {
        let y = 2.0 * eps * i as f64 / 400.0;
        if (y - eps).abs() < 1e-3 * eps {
            continue;
        }
        let h = 1e-7 * eps;
        let d0 = (f0(y + h, eps) - f0(y - h, eps)) / (2.0 * h);
        let d1 = (f1(y + h, eps) - f1(y - h, eps)) / (2.0 * h);
        assert!((d0 - f1(y, eps)).abs() < 1e-7, "f0' at {y}");
        assert!(
            (d1 - f1_derivative(y, eps)).abs() < 1e-6 / eps,
            "f1' at {y}"
        );
    }
    // C1 at eps: f0 and f1 match y and 1 there; f1 rises from 0.
    assert!((f0(eps * (1.0 - 1e-12), eps) - eps).abs() < 1e-12 * eps);
    assert!((f1(eps * (1.0 - 1e-9), eps) - 1.0).abs() < 1e-9);
    assert_eq!(f1(0.0, eps), 0.0);
    assert_eq!(f0(0.0, eps), eps / 3.0);
}

#[test]
fn friction_derivatives_and_force_limits() {
    let settings = ContactSettings {
        dhat: 1e-2,
        mu: 0.4,
        eps_v: 1e-2,
        ..ContactSettings::default()
    };
    let (h, kappa) = (0.05, 20.0);
    let colliders = [
        Collider::ground(0.0),
        Collider::sphere(DVec3::ZERO, 0.5)
            .moving(DVec3::new(0.1, 0.0, 0.0), DVec3::new(0.0, 3.0, 0.0)),
        Collider::capsule(DVec3::new(-1.0, 0.0, 0.0), DVec3::new(1.0, 0.0, 0.0), 0.3)
            .moving(DVec3::ZERO, DVec3::new(0.0, 0.0, 1.0)),
    ];
    let starts = [
        DVec3::new(0.2, 0.004, -0.1),
        DVec3::new(0.0, 0.504, 0.0),
        DVec3::new(0.3, 0.304, 0.0),
    ];
    let mut rng = Rng(5);
    for (c, x_n) in colliders.iter().zip(starts) {
        let contact = FrictionContact::lagged(c, x_n, 0.0, h, kappa, &settings).unwrap();
        let sd = signed_distance(&c.at(0.0), x_n, 0.0);
        let lambda = -kappa * barrier_first_derivative(sd.distance, settings.dhat);
        assert!((contact.max_force - settings.mu * lambda).abs() <= 1e-14 * contact.max_force);
        let eps = contact.epsilon;
        assert_eq!(eps, settings.eps_v * h);
        // Basis orthonormal and across the normal.
        let [t1, t2] = contact.basis;
        assert!(
            t1.dot(t2).abs() < 1e-15
                && t1.dot(sd.normal).abs() < 1e-15
                && t2.dot(sd.normal).abs() < 1e-15
        );
        // Moving with the surface: no friction.
        let along = x_n + contact.surface_displacement;
        assert!(contact.gradient(along).length() <= 1e-12 * contact.max_force);
        // Static ground: the surface does not move; the spinning sphere's surface does.
        if c.is_static() {
            assert_eq!(contact.surface_displacement, DVec3::ZERO);
        } else {
            let vs = c.surface_velocity(sd.closest_point, 0.0);
            assert_eq!(contact.surface_displacement, h * vs);
        }
        let mut checked = 0;
        while checked < 100 {
            // Displacements from well inside the smoothing zone to well outside it.
            let x = along + rng.vec(3.0 * eps);
            let [u1, u2] = contact.tangential_displacement(x);
            let y = u1.hypot(u2);
            if (y - eps).abs() < 0.02 * eps || y < 0.01 * eps {
                continue;
            }
            checked += 1;
            let g = contact.gradient(x);
            let step = 1e-6 * eps;
            let fd_g = fd_gradient(|p| contact.energy(p), x, step);
            assert!(
                (fd_g - g).length() <= 1e-6 * contact.max_force,
                "{g} vs {fd_g}"
            );
            let fd_h = fd_jacobian(|p| contact.gradient(p), x, step);
            let hess = contact.hessian(x);
            assert!(
                max_abs(fd_h - hess) <= 1e-5 * max_abs(hess),
                "{hess} vs {fd_h}"
            );
            let (values, _) = symmetric_eigen(hess);
            assert!(values.x >= -1e-12 * max_abs(hess), "not PSD");
            // Force magnitude mu lambda f1(y), in the tangent plane, against the slip.
            assert!(
                (g.length() - contact.max_force * f1(y, eps)).abs() <= 1e-12 * contact.max_force
            );
            assert!(g.dot(sd.normal).abs() <= 1e-12 * contact.max_force);
            if y > eps {
                assert!((g.length() - contact.max_force).abs() <= 1e-12 * contact.max_force);
            }
        }
        // At zero slip: the limit (2/eps) mu lambda on the tangent plane.
        let h0 = contact.hessian(along);
        let plane = DMat3::IDENTITY
            - DMat3::from_cols(
                sd.normal * sd.normal.x,
                sd.normal * sd.normal.y,
                sd.normal * sd.normal.z,
            );
        assert!(max_abs(h0 - plane * (2.0 / eps * contact.max_force)) <= 1e-9 * max_abs(h0));
    }
    // No friction contact beyond dhat or without friction.
    assert!(
        FrictionContact::lagged(
            &colliders[0],
            DVec3::new(0.0, 0.02, 0.0),
            0.0,
            h,
            kappa,
            &settings
        )
        .is_none()
    );
    let frictionless = ContactSettings {
        mu: 0.0,
        ..settings
    };
    assert!(
        FrictionContact::lagged(&colliders[0], starts[0], 0.0, h, kappa, &frictionless).is_none()
    );
}

#[test]
fn energy_changes_from_differences_match_direct_ones() {
    use sinew_spring_sim::contact::distance::distance_pair;
    let mut rng = Rng(17);
    for shape in shapes() {
        for _ in 0..300 {
            let x = rng.vec(1.5);
            let delta = rng.vec(0.3);
            let (d0, d1) = distance_pair(&shape, x, delta, 0.01);
            assert_eq!(d0, signed_distance(&shape, x, 0.01).distance);
            let direct = signed_distance(&shape, x + delta, 0.01).distance;
            assert!(
                (d1 - direct).abs() <= 1e-14 * direct.abs().max(1.0),
                "{shape:?}: {d1} vs {direct}"
            );
        }
        // A tiny step: d1 is d0 plus the change, so it is off by at most the rounding of
        // that sum (an ulp of d0), not of the coordinates (checked against the first
        // order change n . delta, exact to O(|delta|^2)).
        let x = match shape {
            Shape::HalfSpace { point, normal } => point + 0.3 * normal,
            Shape::Sphere { center, radius } => center + DVec3::new(0.0, radius + 0.3, 0.0),
            Shape::Capsule { a, b, radius } => {
                0.5 * (a + b) + (radius + 0.3) * (b - a).any_orthonormal_vector()
            }
        };
        let delta = DVec3::new(1e-13, -2e-13, 3e-13);
        let (d0, d1) = distance_pair(&shape, x, delta, 0.0);
        let first_order = signed_distance(&shape, x, 0.0).normal.dot(delta);
        assert!(
            ((d1 - d0) - first_order).abs() <= 2.0 * f64::EPSILON * d0.abs(),
            "{shape:?}: {} vs {first_order}",
            d1 - d0
        );
    }
    let settings = ContactSettings {
        dhat: 1e-2,
        mu: 0.4,
        eps_v: 1e-2,
        ..ContactSettings::default()
    };
    let contact = FrictionContact::lagged(
        &Collider::ground(0.0),
        DVec3::new(0.0, 0.004, 0.0),
        0.0,
        0.05,
        20.0,
        &settings,
    )
    .unwrap();
    let eps = contact.epsilon;
    for _ in 0..300 {
        let x = contact.start + rng.vec(3.0 * eps);
        let delta = rng.vec(2.0 * eps);
        let direct = contact.energy(x + delta) - contact.energy(x);
        let change = contact.energy_change(x, delta);
        assert!(
            (direct - change).abs() <= 1e-12 * contact.max_force * eps,
            "{direct} vs {change}"
        );
    }
    // Sliding far from the start, a tiny move: the change is the force times the move.
    let x = contact.start + DVec3::new(10.0, 0.0, 0.0);
    let delta = DVec3::new(1e-14, 0.0, 0.0);
    let change = contact.energy_change(x, delta);
    assert!(
        (change - contact.max_force * 1e-14).abs() <= 1e-9 * contact.max_force * 1e-14,
        "{change}"
    );
}

#[test]
fn barrier_change_keeps_its_accuracy_for_tiny_changes() {
    use sinew_spring_sim::contact::barrier::barrier_change;
    let dhat = 1e-3;
    for &d0 in &[1e-6, 1e-5, 1.05e-4, 5e-4, 9.9e-4] {
        // Ordinary changes: the plain difference of the two values, to rounding.
        for &frac in &[-0.5, -0.1, 0.05, 0.3] {
            let c = frac * d0;
            let plain = barrier(d0 + c, dhat) - barrier(d0, dhat);
            let got = barrier_change(d0, c, dhat);
            assert!(
                (got - plain).abs() <= 1e-12 * plain.abs().max(barrier(d0, dhat)),
                "d0 {d0} change {c}: {got} vs {plain}"
            );
        }
        // Tiny changes: against the Taylor expansion b' c + b'' c^2 / 2 (its error,
        // of order b''' c^3, is far below the tolerance), where the difference of two
        // rounded values of b would have no correct digit at all.
        for &frac in &[1e-15, -3e-14, 2e-11, -1e-9] {
            let c = frac * d0;
            let taylor = barrier_first_derivative(d0, dhat) * c
                + 0.5 * barrier_second_derivative(d0, dhat) * c * c;
            let got = barrier_change(d0, c, dhat);
            assert!(
                (got - taylor).abs() <= 1e-9 * taylor.abs(),
                "d0 {d0} change {c}: {got} vs {taylor}"
            );
        }
    }
    let naive_error = {
        let (d0, c) = (1.05e-4, 1e-15 * 1.05e-4);
        let taylor = barrier_first_derivative(d0, dhat) * c;
        ((barrier(d0 + c, dhat) - barrier(d0, dhat)) - taylor).abs() / taylor.abs()
    };
    assert!(
        naive_error > 1e-3,
        "the naive difference is {naive_error} off"
    );
    // Into the collider: +inf; across dhat: the plain difference (one side is 0).
    assert_eq!(barrier_change(1e-4, -1e-4, dhat), f64::INFINITY);
    assert_eq!(barrier_change(5e-4, 6e-4, dhat), -barrier(5e-4, dhat));
    assert_eq!(barrier_change(2e-3, -1.5e-3, dhat), barrier(5e-4, dhat));
    assert_eq!(barrier_change(2e-3, 1e-3, dhat), 0.0);
}
