//! Time of impact: hand-computed cases (grazing, starting within dhat, moving away, a
//! moving sphere overtaking a particle), and an independent check by dense sampling and
//! bisection that no returned step lets a particle closer than the allowed fraction of
//! its distance, including the conservative advancement against turning colliders.

use sinew_math::DVec3;
use sinew_spring_sim::contact::{Collider, signed_distance, time_of_impact};

const S: f64 = 0.1;

fn distance(c: &Collider, x: DVec3, dx: DVec3, t0: f64, t1: f64, thickness: f64, a: f64) -> f64 {
    signed_distance(&c.at(t0 + a * (t1 - t0)), x + a * dx, thickness).distance
}

/// The reference: the first alpha in [0, 1] where the distance reaches (1 - s) d0,
/// found by dense sampling and then bisection (1 if it never does).
fn reference_toi(c: &Collider, x: DVec3, dx: DVec3, t0: f64, t1: f64, thickness: f64) -> f64 {
    let d0 = distance(c, x, dx, t0, t1, thickness, 0.0);
    let target = (1.0 - S) * d0;
    let n = 20_000;
    let mut prev = 0.0;
    for i in 1..=n {
        let a = i as f64 / n as f64;
        if distance(c, x, dx, t0, t1, thickness, a) < target {
            let (mut lo, mut hi) = (prev, a);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if distance(c, x, dx, t0, t1, thickness, mid) < target {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            return lo;
        }
        prev = a;
    }
    1.0
}

/// The safe fraction of the step `dx` from `x` against `c` held still (no time passes for
/// it) and with no thickness: the setting of most hand-computed cases.
fn still(c: &Collider, x: DVec3, dx: DVec3) -> f64 {
    time_of_impact(c, x, dx, 0.0, 0.0, 0.0, S)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

#[test]
fn plane_cases_by_hand() {
    let ground = Collider::ground(0.0);
    // Falling from y = 1 by 2: d0 = 1, the target 0.9 is reached at alpha = 0.1/2.
    let a = still(&ground, DVec3::Y, DVec3::new(0.3, -2.0, 0.0));
    assert!(close(a, 0.05, 1e-15), "{a}");
    // Starting in contact, within dhat = 1e-3: at 5e-4, moving down by 1e-3.
    let a = still(
        &ground,
        DVec3::new(0.0, 5e-4, 0.0),
        DVec3::new(0.0, -1e-3, 0.0),
    );
    assert!(close(a, 0.05, 1e-13), "{a}");
    // Sliding along the ground, grazing it: never closer, the whole step.
    assert_eq!(
        still(
            &ground,
            DVec3::new(0.0, 5e-4, 0.0),
            DVec3::new(1.0, 0.0, 0.0)
        ),
        1.0
    );
    // Moving away.
    assert_eq!(
        still(
            &ground,
            DVec3::new(0.0, 5e-4, 0.0),
            DVec3::new(0.0, 1.0, 0.0)
        ),
        1.0
    );
    // Thickness 0.1: the particle at 1.1 is at distance 1.
    let a = time_of_impact(
        &ground,
        DVec3::new(0.0, 1.1, 0.0),
        DVec3::new(0.0, -4.0, 0.0),
        0.0,
        0.0,
        0.1,
        S,
    );
    assert!(close(a, 0.025, 1e-15), "{a}");
    // A short step that stops above the target: the whole step.
    assert_eq!(still(&ground, DVec3::Y, DVec3::new(0.0, -0.05, 0.0)), 1.0);
    // Ground rising at 1 per second over [2, 2.5] (at y = 2 when t = 2) under a particle
    // at rest at y = 3: d0 = 1, relative approach 0.5, target reached at alpha = 0.2.
    let rising = Collider::ground(0.0).moving(DVec3::Y, DVec3::ZERO);
    let a = time_of_impact(
        &rising,
        DVec3::new(0.0, 3.0, 0.0),
        DVec3::ZERO,
        2.0,
        2.5,
        0.0,
        S,
    );
    assert!(close(a, 0.2, 1e-15), "{a}");
    // Starting inside: no safe step.
    assert_eq!(still(&ground, DVec3::new(0.0, -1e-3, 0.0), DVec3::Y), 0.0);
}

#[test]
fn sphere_cases_by_hand() {
    let sphere = Collider::sphere(DVec3::ZERO, 1.0);
    // Head-on from x = 3 toward the centre by 2: d0 = 2, target 1.8, |x| = 2.8 at 0.1.
    let a = still(
        &sphere,
        DVec3::new(3.0, 0.0, 0.0),
        DVec3::new(-2.0, 0.0, 0.0),
    );
    assert!(close(a, 0.1, 1e-15), "{a}");
    // Moving away radially.
    assert_eq!(
        still(
            &sphere,
            DVec3::new(3.0, 0.0, 0.0),
            DVec3::new(1.0, 0.5, 0.0)
        ),
        1.0
    );
    // Grazing: the path y = y0 passes the sphere of radius 1 + 0.9 d0 tangentially when
    // y0 = 1 + 0.9 (sqrt(a^2 + y0^2) - 1); with y0 = 2, a = sqrt((1.9/0.9)^2 - 4).
    let y0 = 2.0;
    let ax = ((1.9f64 / 0.9).powi(2) - y0 * y0).sqrt();
    let x = DVec3::new(-ax, y0, 0.0);
    let d0 = x.length() - 1.0;
    assert!(close(1.0 + 0.9 * d0, y0, 1e-15));
    // Just above the tangent path: never below the target.
    let above = DVec3::new(-ax, y0 + 1e-7, 0.0);
    assert_eq!(still(&sphere, above, DVec3::new(2.0 * ax, 0.0, 0.0)), 1.0);
    // Just below it: a hit close to the tangent point (alpha = 1/2 of the path).
    let below = DVec3::new(-ax, y0 - 1e-4, 0.0);
    let a = still(&sphere, below, DVec3::new(2.0 * ax, 0.0, 0.0));
    let r = reference_toi(
        &sphere,
        below,
        DVec3::new(2.0 * ax, 0.0, 0.0),
        0.0,
        0.0,
        0.0,
    );
    assert!(a < 0.5 && a > 0.4 && close(a, r, 1e-9), "{a} vs {r}");
    // Starting within dhat = 1e-3 of the surface, moving in by 1e-3 along the normal:
    // d0 = 4e-4, alpha = 4e-5 / 1e-3.
    let x = DVec3::new(0.0, 1.0004, 0.0);
    let a = still(&sphere, x, DVec3::new(0.0, -1e-3, 0.0));
    assert!(close(a, 0.04, 1e-9), "{a}");
}

#[test]
fn moving_sphere_overtakes_a_particle() {
    // A unit sphere at (-3, 0, 0) moving at 4 per second for one second; a particle at the
    // origin: d0 = 2, the centre must stay 2.8 away: 3 - 4 alpha = 2.8, alpha = 0.05.
    let sphere = Collider::sphere(DVec3::new(-3.0, 0.0, 0.0), 1.0)
        .moving(DVec3::new(4.0, 0.0, 0.0), DVec3::ZERO);
    let a = time_of_impact(&sphere, DVec3::ZERO, DVec3::ZERO, 0.0, 1.0, 0.0, S);
    assert!(close(a, 0.05, 1e-15), "{a}");
    // The particle flees at 1: relative approach 3, alpha = 0.2/3.
    let a = time_of_impact(
        &sphere,
        DVec3::ZERO,
        DVec3::new(1.0, 0.0, 0.0),
        0.0,
        1.0,
        0.0,
        S,
    );
    assert!(close(a, 0.2 / 3.0, 1e-15), "{a}");
    // The particle flees faster than the sphere: the whole step.
    assert_eq!(
        time_of_impact(
            &sphere,
            DVec3::ZERO,
            DVec3::new(5.0, 0.0, 0.0),
            0.0,
            1.0,
            0.0,
            S
        ),
        1.0
    );
    // Spinning as well changes nothing (a sphere's spin leaves its surface in place).
    let spinning = sphere.moving(DVec3::new(4.0, 0.0, 0.0), DVec3::new(0.0, 30.0, 7.0));
    let a = time_of_impact(&spinning, DVec3::ZERO, DVec3::ZERO, 0.0, 1.0, 0.0, S);
    assert!(close(a, 0.05, 1e-15), "{a}");
}

#[test]
fn capsule_cases_by_hand() {
    let capsule = Collider::capsule(DVec3::new(-1.0, 0.0, 0.0), DVec3::new(1.0, 0.0, 0.0), 0.5);
    // Onto the body from above: d0 = 1.5, stay 1.85 from the axis: 2 - 2 alpha = 1.85.
    let a = still(
        &capsule,
        DVec3::new(0.0, 2.0, 0.0),
        DVec3::new(0.0, -2.0, 0.0),
    );
    assert!(close(a, 0.075, 1e-15), "{a}");
    // Onto the end cap along the axis: 3 - 2 alpha - 1 = 1.85.
    let a = still(
        &capsule,
        DVec3::new(3.0, 0.0, 0.0),
        DVec3::new(-2.0, 0.0, 0.0),
    );
    assert!(close(a, 0.075, 1e-15), "{a}");
    // Along the body at constant height: grazing, the whole step.
    assert_eq!(
        still(
            &capsule,
            DVec3::new(-0.8, 0.6, 0.0),
            DVec3::new(1.6, 0.0, 0.0)
        ),
        1.0
    );
    // Away.
    assert_eq!(
        still(
            &capsule,
            DVec3::new(0.0, 0.6, 0.0),
            DVec3::new(0.0, 0.1, 0.0)
        ),
        1.0
    );
    // Spinning about its own axis: surface in place, the closed form applies.
    let spinning = capsule.moving(DVec3::ZERO, DVec3::new(5.0, 0.0, 0.0));
    let a = time_of_impact(
        &spinning,
        DVec3::new(0.0, 2.0, 0.0),
        DVec3::new(0.0, -2.0, 0.0),
        0.0,
        1.0,
        0.0,
        S,
    );
    assert!(close(a, 0.075, 1e-15), "{a}");
}

/// A deterministic sample generator.
fn sample(seed: &mut u64) -> f64 {
    *seed = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    ((*seed >> 11) as f64) / (1u64 << 53) as f64 * 2.0 - 1.0
}

fn vec(seed: &mut u64, r: f64) -> DVec3 {
    DVec3::new(sample(seed), sample(seed), sample(seed)) * r
}

#[test]
fn random_paths_never_pass_the_target_and_closed_forms_are_exact() {
    let mut seed = 42u64;
    let translating = [
        Collider::ground(0.0).moving(DVec3::new(0.2, 0.5, 0.0), DVec3::new(0.0, 2.0, 0.0)),
        Collider::sphere(DVec3::new(0.1, 0.0, 0.0), 0.4)
            .moving(DVec3::new(-0.3, 0.2, 0.1), DVec3::new(1.0, 1.0, 0.0)),
        Collider::capsule(DVec3::new(-0.5, 0.0, 0.0), DVec3::new(0.5, 0.2, 0.0), 0.2)
            .moving(DVec3::new(0.0, 0.4, -0.2), DVec3::ZERO),
        Collider::capsule(DVec3::ONE, DVec3::ONE, 0.3),
    ];
    let mut hits = 0;
    for c in &translating {
        for _ in 0..300 {
            let x = vec(&mut seed, 1.5);
            let d0 = distance(c, x, DVec3::ZERO, 0.0, 1.0, 0.01, 0.0);
            if d0 <= 1e-3 {
                continue;
            }
            let dx = vec(&mut seed, 2.0);
            let a = time_of_impact(c, x, dx, 0.0, 1.0, 0.01, S);
            let r = reference_toi(c, x, dx, 0.0, 1.0, 0.01);
            assert!(
                close(a, r, 1e-8),
                "{c:?} from {x} by {dx}: {a} vs reference {r}"
            );
            if a < 1.0 {
                hits += 1;
            }
        }
    }
    assert!(hits > 100, "too few paths hit ({hits}) to test anything");
}

#[test]
fn turning_colliders_get_a_safe_step_near_the_true_one() {
    let mut seed = 9u64;
    // A tilting ground, a capsule turning end over end, and one turning while it moves.
    let turning = [
        Collider::ground(0.0).moving(DVec3::ZERO, DVec3::new(0.0, 0.0, 1.5)),
        Collider::capsule(DVec3::new(-0.6, 0.0, 0.0), DVec3::new(0.6, 0.0, 0.0), 0.15)
            .moving(DVec3::ZERO, DVec3::new(0.0, 0.0, 3.0)),
        Collider::capsule(DVec3::new(-0.6, 0.0, 0.0), DVec3::new(0.6, 0.0, 0.0), 0.15)
            .moving(DVec3::new(0.0, -0.5, 0.0), DVec3::new(2.0, 0.0, 4.0)),
    ];
    let mut hits = 0;
    let mut worst: f64 = 1.0;
    for c in &turning {
        for _ in 0..200 {
            let x = vec(&mut seed, 1.2);
            let d0 = distance(c, x, DVec3::ZERO, 0.0, 0.5, 0.0, 0.0);
            if d0 <= 1e-3 {
                continue;
            }
            let dx = vec(&mut seed, 1.0);
            let a = time_of_impact(c, x, dx, 0.0, 0.5, 0.0, S);
            let r = reference_toi(c, x, dx, 0.0, 0.5, 0.0);
            // Never past the true time of impact (to the reference's resolution) ...
            assert!(a <= r + 1e-9, "{c:?} from {x} by {dx}: {a} past {r}");
            // ... so the distance stays above the target on [0, a] (sampled).
            for i in 0..=200 {
                let s = a * i as f64 / 200.0;
                assert!(distance(c, x, dx, 0.0, 0.5, 0.0, s) >= (1.0 - S) * d0 - 1e-12);
            }
            if r < 1.0 {
                hits += 1;
                worst = worst.min(a / r);
            }
        }
    }
    assert!(hits > 50, "too few paths hit ({hits})");
    // Conservative advancement stops within 1e-3 of the allowed approach, so it is
    // close to the true time of impact; measured worst ratio over these paths:
    assert!(
        worst > 0.5,
        "advancement too conservative: worst a/r = {worst}"
    );
    println!("worst ratio of advancement to true time of impact: {worst}");
}
