//! The whole-system contact potential: gradient and Hessian blocks against finite
//! differences, the energy change against the energy difference, the line-search cap
//! against the per-particle time of impact, and the broad phase's answers where it
//! skips everything.

use sinew_math::{DMat3, DVec3};
use sinew_spring_sim::contact::barrier::{barrier_first_derivative, minimum_kappa};
use sinew_spring_sim::contact::{
    Collider, ContactPotential, ContactSettings, KappaSettings, signed_distance, time_of_impact,
};

fn setup() -> (ContactPotential, Vec<DVec3>, Vec<bool>, Vec<f64>) {
    let colliders = vec![
        Collider::ground(0.0),
        Collider::sphere(DVec3::new(0.0, 0.5, 0.0), 0.2).moving(DVec3::ZERO, DVec3::Y),
        Collider::capsule(DVec3::new(5.0, 0.0, 0.0), DVec3::new(6.0, 0.0, 0.0), 0.1),
    ];
    let settings = ContactSettings {
        dhat: 0.01,
        thickness: 0.001,
        mu: 0.3,
        eps_v: 0.01,
        toi_fraction: 0.1,
        kappa: KappaSettings::default(),
    };
    let mut p = ContactPotential::new(colliders, settings, 0.0).unwrap();
    // Particles: two near the ground, one near the sphere's top, one far, one fixed in
    // contact range (ignored).
    let x = vec![
        DVec3::new(1.0, 0.004, 0.0),
        DVec3::new(-1.0, 0.009, 0.5),
        DVec3::new(0.0, 0.706, 0.001),
        DVec3::new(2.0, 1.0, 0.0),
        DVec3::new(3.0, 0.005, 0.0),
    ];
    let fixed = vec![false, false, false, false, true];
    let masses = vec![0.1; 5];
    p.begin_step(&x, &fixed, &masses, 9.81, 0.01);
    (p, x, fixed, masses)
}

#[test]
fn kappa_and_friction_are_set_at_the_first_step() {
    let (p, _, _, _) = setup();
    let expected = minimum_kappa(0.01, 0.1, 9.81, 0.01);
    assert_eq!(p.kappa(), expected);
    // Three free particles within dhat at the start: three friction contacts.
    assert_eq!(p.friction_contacts(), 3);
    assert!((p.time() - 0.01).abs() < 1e-18);
}

#[test]
fn the_stiffness_rule_is_the_settings_one() {
    // A particle a thousandth of `dhat` above the ground and falling: too close, so
    // `kappa` grows by the settings' factor up to their ratio.
    let rule = KappaSettings {
        max_ratio: 5.0,
        too_close: 0.5,
        growth: 3.0,
    };
    let settings = ContactSettings {
        dhat: 0.01,
        kappa: rule,
        ..ContactSettings::default()
    };
    let mut p = ContactPotential::new(vec![Collider::ground(0.0)], settings, 0.0).unwrap();
    let fixed = [false];
    p.begin_step(&[DVec3::new(0.0, 1.0, 0.0)], &fixed, &[0.1], 9.81, 0.01);
    let kmin = minimum_kappa(0.01, 0.1, 9.81, 0.01);
    assert_eq!(p.kappa(), kmin);
    // At 0.4 dhat: below too_close = 0.5 dhat and falling (from +inf).
    assert!(p.update_kappa(&[DVec3::new(0.0, 0.004, 0.0)], &fixed));
    assert_eq!(p.kappa(), 3.0 * kmin);
    // Still falling: 9 kmin is clamped to the ratio's 5 kmin.
    assert!(p.update_kappa(&[DVec3::new(0.0, 0.002, 0.0)], &fixed));
    assert_eq!(p.kappa(), 5.0 * kmin);
    // With the default rule (0.01 dhat, 100 kmin) neither distance is too close.
    let mut q = ContactPotential::new(
        vec![Collider::ground(0.0)],
        ContactSettings {
            kappa: KappaSettings::default(),
            ..settings
        },
        0.0,
    )
    .unwrap();
    q.begin_step(&[DVec3::new(0.0, 1.0, 0.0)], &fixed, &[0.1], 9.81, 0.01);
    assert!(!q.update_kappa(&[DVec3::new(0.0, 0.004, 0.0)], &fixed));
    assert!(!q.update_kappa(&[DVec3::new(0.0, 0.002, 0.0)], &fixed));
    assert_eq!(q.kappa(), kmin);
}

#[test]
fn derivatives_match_finite_differences() {
    let (p, x0, fixed, _) = setup();
    // Move the particles a little from the lagged start so friction is active.
    let x: Vec<DVec3> = x0
        .iter()
        .enumerate()
        .map(|(i, &q)| q + DVec3::new(1e-4 * (i as f64 + 1.0), -1e-4, 2e-5 * i as f64))
        .collect();
    let mut g = vec![DVec3::ZERO; x.len()];
    p.add_gradient(&x, &fixed, &mut g);
    let mut blocks = vec![DMat3::ZERO; x.len()];
    p.for_each_hessian_block(&x, &fixed, |i, b| blocks[i] += b);
    let h = 1e-8;
    for i in 0..x.len() {
        let mut fd = DVec3::ZERO;
        let mut fd_h = DMat3::ZERO;
        for k in 0..3 {
            let mut e = DVec3::ZERO;
            e[k] = h;
            let mut plus = x.clone();
            let mut minus = x.clone();
            plus[i] += e;
            minus[i] -= e;
            fd[k] = (p.energy(&plus, &fixed) - p.energy(&minus, &fixed)) / (2.0 * h);
            let mut gp = vec![DVec3::ZERO; x.len()];
            let mut gm = vec![DVec3::ZERO; x.len()];
            p.add_gradient(&plus, &fixed, &mut gp);
            p.add_gradient(&minus, &fixed, &mut gm);
            let col = (gp[i] - gm[i]) / (2.0 * h);
            *fd_h.col_mut(k) = col;
        }
        if fixed[i] {
            assert_eq!(g[i], DVec3::ZERO);
            assert_eq!(blocks[i], DMat3::ZERO);
            continue;
        }
        let scale = g[i].length().max(1e-6);
        assert!(
            (fd - g[i]).length() <= 1e-5 * scale,
            "particle {i}: {} vs {fd}",
            g[i]
        );
        // Along the normal the projected block is exact; compare the ground particles'
        // blocks in full (plane: H_d = 0, so nothing is projected away).
        if i < 2 {
            let err = (fd_h - blocks[i])
                .to_cols_array()
                .iter()
                .fold(0.0f64, |a, v| a.max(v.abs()));
            let size = blocks[i]
                .to_cols_array()
                .iter()
                .fold(0.0f64, |a, v| a.max(v.abs()));
            assert!(err <= 1e-4 * size, "particle {i}: {} vs {fd_h}", blocks[i]);
        }
    }
    assert_eq!(g[3], DVec3::ZERO, "a far particle feels nothing");
    // The ground pushes up.
    assert!(g[0].y < 0.0);
    let ground_force = -p.kappa() * barrier_first_derivative(x[0].y - 0.001, 0.01);
    assert!((g[0].y + ground_force).abs() <= 1e-9 * ground_force);
}

#[test]
fn energy_change_matches_the_difference() {
    let (p, x, fixed, _) = setup();
    let dx: Vec<DVec3> = (0..x.len())
        .map(|i| DVec3::new(1e-3, -2e-3 + 1e-3 * i as f64, 5e-4))
        .collect();
    for alpha in [1.0, 0.5, 0.25, 1e-3] {
        let moved: Vec<DVec3> = x.iter().zip(&dx).map(|(a, b)| *a + alpha * *b).collect();
        let direct = p.energy(&moved, &fixed) - p.energy(&x, &fixed);
        let change = p.energy_change(&x, &dx, alpha, &fixed);
        assert!(
            (direct - change).abs() <= 1e-10 * direct.abs().max(1e-12),
            "{alpha}: {direct} vs {change}"
        );
    }
    // Into the ground: infinite.
    let mut down = vec![DVec3::ZERO; x.len()];
    down[0] = DVec3::new(0.0, -1.0, 0.0);
    assert_eq!(p.energy_change(&x, &down, 1.0, &fixed), f64::INFINITY);
}

#[test]
fn max_step_is_the_smallest_time_of_impact() {
    let (p, x, fixed, _) = setup();
    let dx: Vec<DVec3> = vec![
        DVec3::new(0.0, -0.01, 0.0),
        DVec3::new(0.0, -0.004, 0.0),
        DVec3::new(0.0, -0.3, 0.0),
        DVec3::new(0.0, -5.0, 0.0),
        DVec3::new(0.0, -1.0, 0.0),
    ];
    let alpha = p.max_step(&x, &dx, &fixed, 1.0);
    let mut expected: f64 = 1.0;
    for (i, (&q, &d)) in x.iter().zip(&dx).enumerate() {
        if fixed[i] {
            continue;
        }
        for c in p.posed() {
            let still = Collider::fixed(*c);
            expected = expected.min(time_of_impact(&still, q, d, 0.0, 0.0, 0.001, 0.1));
        }
    }
    assert_eq!(alpha, expected);
    assert!(alpha < 1.0);
    // A longer horizon finds the same first impact (the closed forms are exact).
    let longer = p.max_step(&x, &dx, &fixed, 4.0);
    assert!(
        (longer - alpha).abs() <= 1e-12 * alpha,
        "{longer} vs {alpha}"
    );
    // Every particle stays at least 0.9 of its distance along the capped step.
    for (i, (&q, &d)) in x.iter().zip(&dx).enumerate() {
        if fixed[i] {
            continue;
        }
        for c in p.posed() {
            let d0 = signed_distance(c, q, 0.001).distance;
            for k in 0..=100 {
                let s = alpha * k as f64 / 100.0;
                assert!(signed_distance(c, q + s * d, 0.001).distance >= 0.9 * d0 - 1e-15);
            }
        }
    }
    assert!(p.first_penetration(&x, &fixed).is_none());
    let inside: Vec<DVec3> = x
        .iter()
        .map(|q| *q - DVec3::new(0.0, 0.0085, 0.0))
        .collect();
    assert_eq!(p.first_penetration(&inside, &fixed), Some((0, 0)));
}

#[test]
fn far_from_every_collider_nothing_is_computed() {
    let colliders = vec![
        Collider::ground(-10.0),
        Collider::sphere(DVec3::new(50.0, 0.0, 0.0), 1.0),
    ];
    let mut p = ContactPotential::new(
        colliders,
        ContactSettings {
            mu: 0.5,
            toi_fraction: 0.1,
            ..ContactSettings::default()
        },
        0.0,
    )
    .unwrap();
    let x = vec![DVec3::new(0.0, 1.0, 0.0), DVec3::new(1.0, 1.0, 0.0)];
    let fixed = vec![false, false];
    p.begin_step(&x, &fixed, &[1.0, 1.0], 9.81, 0.01);
    assert_eq!(p.friction_contacts(), 0);
    assert_eq!(p.energy(&x, &fixed), 0.0);
    assert_eq!(p.min_distance(&x, &fixed), f64::INFINITY);
    let dx = vec![DVec3::new(0.0, -1.0, 0.0); 2];
    assert_eq!(p.max_step(&x, &dx, &fixed, 1.0), 1.0);
    let mut blocks = 0;
    p.for_each_hessian_block(&x, &fixed, |_, _| blocks += 1);
    assert_eq!(blocks, 0);
    // A step long enough to reach the ground is capped.
    let far = vec![DVec3::new(0.0, -20.0, 0.0); 2];
    let a = p.max_step(&x, &far, &fixed, 1.0);
    assert!((a - 1.1 / 20.0).abs() < 1e-15, "{a}");
    // Along a unit step nothing is near within 1, but a line search that may lengthen
    // the step 1024 times meets the ground's limit at 1.1 (d0 = 11, 0.9 d0 = 9.9).
    let a = p.max_step(&x, &dx, &fixed, 1024.0);
    assert!((a - 1.1).abs() < 1e-12, "{a}");
    let up = vec![DVec3::new(0.0, 1.0, 0.0); 2];
    assert_eq!(p.max_step(&x, &up, &fixed, 1024.0), 1024.0);
}

#[test]
fn bad_input_is_named() {
    let err = ContactPotential::new(
        vec![Collider::ground(0.0), Collider::sphere(DVec3::ZERO, -1.0)],
        ContactSettings::default(),
        0.0,
    )
    .unwrap_err();
    assert!(
        err.to_string().starts_with("collider 1 (sphere): radius"),
        "{err}"
    );
    let err = ContactPotential::new(
        vec![],
        ContactSettings {
            dhat: -1.0,
            ..ContactSettings::default()
        },
        0.0,
    )
    .unwrap_err();
    assert!(err.to_string().contains("dhat"), "{err}");
}

#[test]
fn the_default_fraction_lets_a_step_close_ninety_percent_of_the_distance() {
    // A particle 1 above the ground moving 10 down: the default keeps a tenth of its
    // distance (0.1), so the cap is 0.9 / 10. (The earlier default, 0.1, capped it at
    // 0.01: a tenth of the distance per Newton iteration, which made landings slow.)
    let mut p = ContactPotential::new(vec![Collider::ground(0.0)], ContactSettings::default(), 0.0)
        .unwrap();
    let x = vec![DVec3::new(0.0, 1.0, 0.0)];
    let fixed = vec![false];
    p.begin_step(&x, &fixed, &[1.0], 9.81, 0.01);
    let dx = vec![DVec3::new(0.0, -10.0, 0.0)];
    let a = p.max_step(&x, &dx, &fixed, 1.0);
    assert!((a - 0.09).abs() < 1e-15, "{a}");
    let end = x[0] + a * dx[0];
    assert!((end.y - 0.1).abs() < 1e-15 && end.y > 0.0, "{end}");
}

/// A backward Euler step of 1/60 s from `positions` at time `t`, three free particles
/// of 5e-4 kg under gravity 9.81.
fn three_particle_step<'a>(
    positions: &'a [DVec3],
    other: Option<&'a [DVec3]>,
    t: f64,
) -> sinew_spring_sim::contact::ContactStep<'a> {
    sinew_spring_sim::contact::ContactStep {
        positions,
        anchor: positions,
        fixed: &[false, false, false],
        masses: &[5e-4, 5e-4, 5e-4],
        gravity: 9.81,
        h: 1.0 / 60.0,
        start: t,
        end: t + 1.0 / 60.0,
        other_gradient: other,
    }
}

#[test]
fn kappa_starts_at_the_balance_of_the_other_forces_on_the_first_step_in_contact() {
    let dhat = 1e-3;
    let settings = ContactSettings {
        dhat,
        ..ContactSettings::default()
    };
    let (m, g, h) = (5e-4, 9.81, 1.0 / 60.0);
    let kmin = minimum_kappa(dhat, m, g, h);
    let mut p = ContactPotential::new(
        vec![
            Collider::ground(0.0),
            Collider::sphere(DVec3::new(5.0, 0.0, 0.0), 0.5),
        ],
        settings,
        0.0,
    )
    .unwrap();
    // Two particles on the ground at 0.3 dhat and 0.5 dhat, one far away. The other
    // forces press the two onto the ground with 20 times their weight (gradient
    // +f y), and push the far one sideways, which no barrier can balance.
    let f = 20.0 * m * g;
    let rest = [
        DVec3::new(0.0, 0.3 * dhat, 0.0),
        DVec3::new(1.0, 0.5 * dhat, 0.0),
        DVec3::new(2.0, 1.0, 0.0),
    ];
    let pressed = [
        DVec3::new(0.0, f, 0.0),
        DVec3::new(0.0, f, 0.0),
        DVec3::new(3.0, f, 0.0),
    ];
    // A first step with nothing in contact: kappa_min, and the balance still to come.
    let high = [rest[0] + DVec3::Y, rest[1] + DVec3::Y, rest[2]];
    assert!(p.awaits_balance());
    p.begin(&three_particle_step(&high, Some(&pressed), 0.0));
    assert_eq!(p.kappa(), kmin);
    assert!(p.awaits_balance(), "no contact: no balance yet");
    // The first step in contact: kappa = -(g_E . g_B)/|g_B|^2 with g_B = b'(d_i) y for
    // the two resting particles (the far one has no barrier gradient):
    // kappa = f (|b'(d_0)| + |b'(d_1)|) / (b'(d_0)^2 + b'(d_1)^2).
    let (b0, b1) = (
        barrier_first_derivative(0.3 * dhat, dhat),
        barrier_first_derivative(0.5 * dhat, dhat),
    );
    let expected = f * (-b0 - b1) / (b0 * b0 + b1 * b1);
    assert!(
        expected > kmin && expected < 100.0 * kmin,
        "{expected} vs {kmin}"
    );
    p.begin(&three_particle_step(&rest, Some(&pressed), h));
    assert!(
        (p.kappa() - expected).abs() <= 1e-12 * expected,
        "{} vs {expected}",
        p.kappa()
    );
    assert!(!p.awaits_balance());
    // Applied once: a later step with another balance leaves kappa alone.
    let harder = pressed.map(|v| 10.0 * v);
    p.begin(&three_particle_step(&rest, Some(&harder), 2.0 * h));
    assert!((p.kappa() - expected).abs() <= 1e-12 * expected);
    // Rewinding the step that made the start undoes it (a step redone in pieces).
    let mut q = ContactPotential::new(vec![Collider::ground(0.0)], settings, 0.0).unwrap();
    q.begin(&three_particle_step(&high, Some(&pressed), 0.0));
    q.begin(&three_particle_step(&rest, Some(&pressed), h));
    assert!(!q.awaits_balance());
    q.rewind_kappa();
    assert!(q.awaits_balance());
    assert_eq!(q.kappa(), kmin);
}

/// The gradient and the Hessian blocks (in the order given) at `x`.
fn derivatives(
    p: &ContactPotential,
    x: &[DVec3],
    fixed: &[bool],
) -> (Vec<DVec3>, Vec<(usize, DMat3)>) {
    let mut g = vec![DVec3::ZERO; x.len()];
    p.add_gradient(x, fixed, &mut g);
    let mut blocks = Vec::new();
    p.for_each_hessian_block(x, fixed, |i, b| blocks.push((i, b)));
    (g, blocks)
}

#[test]
fn derivatives_from_the_collected_pairs_equal_the_full_pass_and_never_go_stale() {
    let (mut p, x0, fixed, masses) = setup();
    let x: Vec<DVec3> = x0
        .iter()
        .enumerate()
        .map(|(i, &q)| q + DVec3::new(1e-4 * (i as f64 + 1.0), -1e-4, 2e-5 * i as f64))
        .collect();
    // Without collected pairs: the full pass over every particle and collider.
    let full = derivatives(&p, &x, &fixed);
    let kappa = p.kappa();
    p.update_kappa(&x, &fixed);
    assert_eq!(p.kappa(), kappa, "no growth at these distances");
    // From the pairs collected at x: the same numbers, bit for bit.
    assert_eq!(derivatives(&p, &x, &fixed), full);
    // At another state the pairs are not used.
    let other: Vec<DVec3> = x.iter().map(|q| *q + DVec3::new(0.0, 1e-3, 0.0)).collect();
    let fresh = setup().0;
    assert_eq!(
        derivatives(&p, &other, &fixed),
        derivatives(&fresh, &other, &fixed)
    );
    // A new step poses the colliders anew: pairs collected before it are dropped. The
    // ground rises by 2 mm per step here, so the same state has other distances.
    let settings = ContactSettings {
        dhat: 0.01,
        ..ContactSettings::default()
    };
    let rising = vec![Collider::ground(0.0).moving(DVec3::new(0.0, 0.2, 0.0), DVec3::ZERO)];
    let mut q = ContactPotential::new(rising.clone(), settings, 0.0).unwrap();
    let low = vec![DVec3::new(0.0, 0.007, 0.0), DVec3::new(1.0, 0.009, 0.0)];
    let free = vec![false, false];
    q.begin_step(&low, &free, &masses[..2], 9.81, 0.01);
    q.update_kappa(&low, &free);
    q.begin_step(&low, &free, &masses[..2], 9.81, 0.01);
    let mut r = ContactPotential::new(rising, settings, 0.0).unwrap();
    r.begin_step(&low, &free, &masses[..2], 9.81, 0.01);
    r.begin_step(&low, &free, &masses[..2], 9.81, 0.01);
    assert_eq!(q.kappa(), r.kappa());
    let (moved, _) = derivatives(&q, &low, &free);
    assert_eq!(moved, derivatives(&r, &low, &free).0);
    // And the ground's rise shows: the particle at 7 mm is now 3 mm from it (the pose at
    // the second step's end, t = 0.02), pushed harder than at 5 mm.
    assert!(moved[0].y < 0.0 && moved[0].y < moved[1].y, "{moved:?}");
}
