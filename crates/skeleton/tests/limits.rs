//! Joint limits against hand-computed cases, an independent closest-point computation
//! (dense sampling) and invariants on seeded random rotations.

mod common;

use common::shoulder;
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::limits::{Hinge, JointLimit, LimitError, SwingTwist, swing_twist};
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// The geodesic angle between two rotations, in `[0, pi]`, accurate near 0.
fn rotation_distance(a: DQuat, b: DQuat) -> f64 {
    let d = a.normalize().conjugate() * b.normalize();
    2.0 * d.xyz().length().atan2(d.w.abs())
}

/// Asserts that `a` and `b` are the same rotation to `tol` radians.
#[track_caller]
fn assert_same_rotation(a: DQuat, b: DQuat, tol: f64) {
    let d = rotation_distance(a, b);
    assert!(
        d <= tol,
        "{a} and {b} differ by {d:e} rad (tolerance {tol:e})"
    );
}

/// Largest component difference between two quaternions (no sign freedom).
fn component_difference(a: DQuat, b: DQuat) -> f64 {
    (a.to_array().iter().zip(b.to_array()))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// The seeded generator the tests draw from (splitmix64); uniform in [0, 1).
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

    fn unit3(&mut self) -> [f64; 3] {
        [self.next(), self.next(), self.next()]
    }

    /// A uniform random rotation, returned with a random sign and scale (the limits must
    /// normalise and not care about the sign).
    fn rotation(&mut self) -> DQuat {
        let q = JointLimit::Free.sample(self.unit3());
        let scale = 0.25 + 4.0 * self.next();
        let sign = if self.next() < 0.5 { -1.0 } else { 1.0 };
        q * (scale * sign)
    }
}

fn deg(d: f64) -> f64 {
    d.to_radians()
}

fn swing_twist_of(limit: &JointLimit) -> SwingTwist {
    match limit {
        JointLimit::SwingTwist(st) => *st,
        other => panic!("not a swing-twist limit: {other:?}"),
    }
}

/// The swing's rotation vector of `q` about `axis`, by the public decomposition.
fn swing_vector(q: DQuat, axis: DVec3) -> DVec3 {
    let (swing, _) = swing_twist(q, axis);
    let swing = if swing.w < 0.0 { -swing } else { swing };
    swing.to_scaled_axis()
}

/// The limits the random properties run over: every kind, round and thin ellipses, full
/// and partial twist ranges, tilted axes, ranges that exclude the identity.
fn limit_zoo() -> Vec<(&'static str, JointLimit)> {
    let tilted = DVec3::new(1.0, 2.0, 3.0);
    let tilted_a = tilted.cross(DVec3::Z);
    vec![
        ("free", JointLimit::Free),
        ("fixed", JointLimit::Fixed),
        (
            "elbow hinge",
            JointLimit::hinge(-DVec3::Y, 0.0, deg(150.0)).unwrap(),
        ),
        (
            "forearm twist",
            JointLimit::hinge(DVec3::X, deg(-80.0), deg(80.0)).unwrap(),
        ),
        (
            "tilted hinge [2, 3]",
            JointLimit::hinge(tilted, 2.0, 3.0).unwrap(),
        ),
        ("free hinge", JointLimit::hinge(DVec3::Z, -PI, PI).unwrap()),
        ("shoulder", shoulder()),
        (
            "wrist",
            JointLimit::swing_twist(
                DVec3::X,
                DVec3::Z,
                deg(80.0),
                deg(30.0),
                deg(-10.0),
                deg(10.0),
            )
            .unwrap(),
        ),
        ("cone", JointLimit::cone(DVec3::Y, deg(40.0)).unwrap()),
        (
            "thin tilted ellipse",
            JointLimit::swing_twist(tilted, tilted_a, PI, 0.05, 1.0, 2.5).unwrap(),
        ),
        (
            "full swing, twist [-1, 2]",
            JointLimit::swing_twist(DVec3::Z, DVec3::X, PI, PI, -1.0, 2.0).unwrap(),
        ),
        (
            "tall ellipse",
            JointLimit::swing_twist(DVec3::Y, DVec3::X, 0.3, 2.5, -PI, PI).unwrap(),
        ),
    ]
}

// ---------------------------------------------------------------- hinge

#[test]
fn hinge_inside_is_unchanged() {
    let elbow = JointLimit::hinge(DVec3::new(0.0, -1.0, 0.0), 0.0, deg(150.0)).unwrap();
    for angle in [0.0, 0.3, 1.0, deg(150.0)] {
        let q = DQuat::from_axis_angle(-DVec3::Y, angle);
        assert_eq!(elbow.violation(q), 0.0, "angle {angle}");
        assert_eq!(elbow.project(q), q, "angle {angle}");
    }
}

#[test]
fn hinge_outside_goes_to_the_nearer_bound() {
    let max = deg(150.0);
    let elbow = JointLimit::hinge(-DVec3::Y, 0.0, max).unwrap();
    // (angle, expected bound, distance on the circle to it)
    let cases = [
        (2.9, max, 2.9 - max),
        (-0.3, 0.0, 0.3),
        // -2 is 2 from 0 but only 2 pi - 2 - 150 degrees (1.665) from 150 degrees the
        // other way round.
        (-2.0, max, TAU - 2.0 - max),
        (-1.0, 0.0, 1.0),
    ];
    for (angle, bound, distance) in cases {
        let q = DQuat::from_axis_angle(-DVec3::Y, angle);
        let p = elbow.project(q);
        assert_same_rotation(p, DQuat::from_axis_angle(-DVec3::Y, bound), 1e-15);
        assert!(
            (elbow.violation(q) - distance).abs() < 1e-14,
            "angle {angle}"
        );
        assert!(
            (rotation_distance(q, p) - distance).abs() < 1e-14,
            "angle {angle}"
        );
    }
}

#[test]
fn hinge_wraps_around_the_circle() {
    let wide = JointLimit::hinge(DVec3::Z, -3.0, 3.0).unwrap();
    let rz = |a: f64| DQuat::from_rotation_z(a);
    // Just short of a half turn either way: the bound on that side.
    assert_same_rotation(wide.project(rz(PI - 0.01)), rz(3.0), 1e-15);
    assert_same_rotation(wide.project(rz(-PI + 0.01)), rz(-3.0), 1e-15);
    // Across the half turn: +3.13 is 3.13 - 3 = 0.13 past +3, nearer than -3.
    assert_same_rotation(wide.project(rz(-TAU + 3.13)), rz(3.0), 1e-15);
    // Exactly a half turn: both bounds are pi - 3 away; either is right, the tie goes to
    // max, and q and -q (the same rotation) must agree.
    let half = rz(PI);
    let p = wide.project(half);
    assert!((rotation_distance(half, p) - (PI - 3.0)).abs() < 1e-14);
    assert_same_rotation(p, rz(3.0), 1e-15);
    assert_same_rotation(wide.project(-half), p, 1e-15);
    assert!((wide.violation(half) - (PI - 3.0)).abs() < 1e-14);

    // A range that starts at -pi holds the half turn, which the decomposition reads as +pi.
    let low = JointLimit::hinge(DVec3::Z, -PI, -3.0).unwrap();
    let exact_half = DQuat::from_xyzw(0.0, 0.0, 1.0, 0.0);
    assert_eq!(low.violation(exact_half), 0.0);
    assert_eq!(low.project(exact_half), exact_half);
    assert_eq!(low.project(-exact_half), -exact_half);
    assert!(low.violation(half) < 1e-15);
    assert_same_rotation(low.project(half), half, 1e-15);

    // Range [2, 3]: -3 is 2 pi - 6 = 0.283 from 3 and 5 from 2; 0 is 2 from 2.
    let narrow = JointLimit::hinge(DVec3::Z, 2.0, 3.0).unwrap();
    assert_same_rotation(narrow.project(rz(-3.0)), rz(3.0), 1e-15);
    assert!((narrow.violation(rz(-3.0)) - (TAU - 6.0)).abs() < 1e-14);
    assert_same_rotation(narrow.project(rz(0.0)), rz(2.0), 1e-15);
    assert!((narrow.violation(DQuat::IDENTITY) - 2.0).abs() < 1e-15);
}

#[test]
fn hinge_drops_the_off_axis_part() {
    let hinge = JointLimit::hinge(DVec3::Z, -1.0, 1.5).unwrap();
    // A swing of 0.4 about x (perpendicular to the hinge) after a twist of 1 about z.
    let q = DQuat::from_rotation_x(0.4) * DQuat::from_rotation_z(1.0);
    assert_same_rotation(hinge.project(q), DQuat::from_rotation_z(1.0), 1e-15);
    assert!((hinge.violation(q) - 0.4).abs() < 1e-15);
    // Off-axis and outside the range: violation is the larger of the two parts.
    let q = DQuat::from_rotation_y(0.2) * DQuat::from_rotation_z(1.8);
    assert_same_rotation(hinge.project(q), DQuat::from_rotation_z(1.5), 1e-15);
    assert!((hinge.violation(q) - 0.3).abs() < 1e-15);
}

#[test]
fn hinge_projection_is_geodesically_nearest() {
    let mut rng = Rng(11);
    let limits = [
        JointLimit::hinge(DVec3::new(1.0, 2.0, 3.0), 2.0, 3.0).unwrap(),
        JointLimit::hinge(-DVec3::Y, 0.0, deg(150.0)).unwrap(),
        JointLimit::hinge(DVec3::new(-0.3, 0.1, 1.0), -3.0, 3.0).unwrap(),
    ];
    for limit in limits {
        let JointLimit::Hinge(Hinge { axis, min, max }) = limit else {
            unreachable!()
        };
        let sweep: Vec<DQuat> = (0..=20_000)
            .map(|i| DQuat::from_axis_angle(axis, min + (max - min) * i as f64 / 20_000.0))
            .collect();
        for _ in 0..200 {
            let q = rng.rotation();
            let p = limit.project(q);
            assert!(limit.violation(p) <= 1e-12);
            let ours = rotation_distance(q, p);
            let best = sweep
                .iter()
                .map(|&s| rotation_distance(q, s))
                .fold(f64::INFINITY, f64::min);
            assert!(ours <= best + 1e-12, "{ours} vs sweep {best} for {q}");
            // Independently of the projection: the distance to the hinge set lies between
            // the violation (the larger part) and twice it (the sum of the parts).
            let v = limit.violation(q);
            assert!(
                v <= ours + 1e-12 && ours <= 2.0 * v + 1e-12,
                "{v} vs {ours}"
            );
        }
    }
}

// ---------------------------------------------------------------- swing-twist

#[test]
fn a_swing_on_the_ellipse_stays() {
    let limit = shoulder();
    let (a, b) = (deg(100.0), deg(70.0));
    for psi in [0.0, 0.7, FRAC_PI_2, 2.0, 4.0] {
        // Rotation vector on the ellipse: a cos psi along z, b sin psi along x cross z = -y.
        let s = DVec3::Z * (a * f64::cos(psi)) - DVec3::Y * (b * f64::sin(psi));
        let q = DQuat::from_scaled_axis(s) * DQuat::from_rotation_x(0.5);
        assert!(
            limit.violation(q) <= 1e-15,
            "psi {psi}: {}",
            limit.violation(q)
        );
        assert!(
            component_difference(limit.project(q), q) <= 1e-15,
            "psi {psi}"
        );
    }
}

#[test]
fn swing_past_the_vertices_lands_on_them() {
    let limit = shoulder();
    // 120 degrees about a_axis (z) goes to the a-vertex, 100 degrees about z.
    let q = DQuat::from_rotation_z(deg(120.0));
    assert_same_rotation(limit.project(q), DQuat::from_rotation_z(deg(100.0)), 1e-15);
    assert!((limit.violation(q) - deg(20.0)).abs() < 1e-15);
    // 80 degrees about b_axis (-y) or about +y goes to 70 degrees about the same axis.
    for axis in [DVec3::Y, -DVec3::Y] {
        let q = DQuat::from_axis_angle(axis, deg(80.0));
        assert_same_rotation(
            limit.project(q),
            DQuat::from_axis_angle(axis, deg(70.0)),
            1e-15,
        );
        assert!((limit.violation(q) - deg(10.0)).abs() < 1e-15);
    }
    // With a twist inside the range, the twist is kept.
    let twist = DQuat::from_rotation_x(deg(30.0));
    let q = DQuat::from_rotation_z(deg(-150.0)) * twist;
    assert_same_rotation(
        limit.project(q),
        DQuat::from_rotation_z(deg(-100.0)) * twist,
        1e-15,
    );
}

/// The nearest point of the ellipse `(x/a)^2 + (y/b)^2 = 1` to `(px, py)` by dense
/// sampling of its parameter: independent of the library's bisection.
fn nearest_by_sampling(a: f64, b: f64, px: f64, py: f64) -> (f64, f64, f64) {
    let n = 400_000;
    let mut best = (f64::INFINITY, 0.0, 0.0);
    for i in 0..n {
        let t = TAU * i as f64 / n as f64;
        let (x, y) = (a * t.cos(), b * t.sin());
        let d = (x - px).hypot(y - py);
        if d < best.0 {
            best = (d, x, y);
        }
    }
    best
}

#[test]
fn diagonal_swings_go_to_the_nearest_point_of_the_ellipse() {
    let thin = JointLimit::swing_twist(DVec3::X, DVec3::Z, 3.0, 0.2, -PI, PI).unwrap();
    let tall = JointLimit::swing_twist(DVec3::X, DVec3::Z, 0.4, 1.9, -PI, PI).unwrap();
    // Points in ellipse coordinates (along a_axis = z, along b_axis = -y), outside.
    let cases = [
        (
            shoulder(),
            [(1.6, 1.3), (-2.0, 0.5), (0.3, -1.5), (-1.9, -2.2)],
        ),
        (thin, [(2.0, 0.5), (3.02, 0.01), (-0.5, -0.3), (1.0, 2.5)]),
        (tall, [(0.5, 0.1), (1.0, 1.0), (-0.45, -1.0), (0.05, 2.0)]),
    ];
    for (limit, points) in cases {
        let st = swing_twist_of(&limit);
        for (pa, pb) in points {
            let s = DVec3::Z * pa - DVec3::Y * pb;
            let q = DQuat::from_scaled_axis(s);
            let got = swing_vector(limit.project(q), DVec3::X);
            let (ga, gb) = (got.dot(DVec3::Z), -got.dot(DVec3::Y));
            // On the ellipse.
            let level = (ga / st.swing_a).powi(2) + (gb / st.swing_b).powi(2);
            assert!((level - 1.0).abs() < 1e-13, "({pa}, {pb}): level {level}");
            // As near as the densely sampled nearest point, and at it.
            let (best, ba, bb) = nearest_by_sampling(st.swing_a, st.swing_b, pa, pb);
            let ours = (ga - pa).hypot(gb - pb);
            assert!(ours <= best + 1e-12, "({pa}, {pb}): {ours} vs {best}");
            assert!(
                (ga - ba).hypot(gb - bb) < 1e-4,
                "({pa}, {pb}): ({ga}, {gb}) vs ({ba}, {bb})"
            );
            // The violation (radial excess) brackets that distance: at least it, at most it
            // times the ratio of the semi-axes.
            let ratio = st.swing_a.max(st.swing_b) / st.swing_a.min(st.swing_b);
            let v = limit.violation(q);
            assert!(
                v >= ours - 1e-13 && v <= ratio * ours + 1e-13,
                "{v} vs {ours}"
            );
        }
    }
}

#[test]
fn cone_projection_is_geodesically_nearest() {
    // A cone of half-angle c with free twist: the projection moves q by exactly
    // max(0, phi - c), phi its swing angle, and no allowed rotation is nearer.
    let c = 0.6;
    let limit = JointLimit::cone(DVec3::new(0.2, 1.0, -0.4), c).unwrap();
    let axis = swing_twist_of(&limit).twist_axis;
    let mut rng = Rng(19);
    let allowed: Vec<DQuat> = (0..20_000).map(|_| limit.sample(rng.unit3())).collect();
    for _ in 0..200 {
        let q = rng.rotation();
        let p = limit.project(q);
        let phi = swing_vector(q, axis).length();
        let d = rotation_distance(q, p);
        assert!((d - (phi - c).max(0.0)).abs() < 1e-13, "{d} vs {phi} - {c}");
        let best = allowed
            .iter()
            .map(|&s| rotation_distance(q, s))
            .fold(f64::INFINITY, f64::min);
        assert!(d <= best + 1e-13, "{d} vs sampled {best}");
    }
}

#[test]
fn half_turn_swings_have_a_defined_answer() {
    let limit = shoulder();
    // A half turn about y: the swing is singular (every twist fits). The swing's rotation
    // vector pi y is outside the ellipse along b; its nearest point is the b-vertex.
    let q = DQuat::from_rotation_y(PI);
    let p = limit.project(q);
    assert!(p.is_finite());
    let about_y = DQuat::from_rotation_y(deg(70.0));
    let about_minus_y = DQuat::from_rotation_y(-deg(70.0));
    assert!(
        rotation_distance(p, about_y) <= 1e-15 || rotation_distance(p, about_minus_y) <= 1e-15,
        "{p}"
    );
    assert_same_rotation(limit.project(-q), p, 1e-15);
    assert!((limit.violation(q) - (PI - deg(70.0))).abs() < 1e-14);
    assert!((limit.violation(-q) - (PI - deg(70.0))).abs() < 1e-14);

    // A half turn about a diagonal axis in the swing plane: on the ellipse, finite, the
    // same for q and -q, and as near as the nearer of the two equivalent vectors allows.
    let st = swing_twist_of(&limit);
    let dir = (DVec3::Z * 0.8 - DVec3::Y * 0.6).normalize();
    let q = DQuat::from_axis_angle(dir, PI);
    for q in [q, -q] {
        let p = limit.project(q);
        assert!(p.is_finite());
        assert_same_rotation(limit.project(-q), p, 1e-15);
        let got = swing_vector(p, DVec3::X);
        let (ga, gb) = (got.dot(DVec3::Z), -got.dot(DVec3::Y));
        let level = (ga / st.swing_a).powi(2) + (gb / st.swing_b).powi(2);
        assert!((level - 1.0).abs() < 1e-13);
        let (pa, pb) = (PI * 0.8, PI * 0.6);
        let best = nearest_by_sampling(st.swing_a, st.swing_b, pa, pb).0;
        let ours = (ga.abs() - pa).hypot(gb.abs() - pb);
        assert!(ours <= best + 1e-12, "{ours} vs {best}");
    }

    // The decomposition itself: a half turn about y around the x axis is all swing.
    let (swing, twist) = swing_twist(DQuat::from_rotation_y(PI), DVec3::X);
    assert_eq!(twist, DQuat::IDENTITY);
    assert_same_rotation(swing, DQuat::from_rotation_y(PI), 1e-15);
}

#[test]
fn twist_wraps_around_the_circle() {
    // Twist range [2, 3] about x, swing a small cone.
    let limit = JointLimit::swing_twist(DVec3::X, DVec3::Z, 0.5, 0.5, 2.0, 3.0).unwrap();
    let swing = DQuat::from_rotation_z(0.2);
    let q = swing * DQuat::from_rotation_x(-3.0);
    assert_same_rotation(limit.project(q), swing * DQuat::from_rotation_x(3.0), 1e-15);
    assert!((limit.violation(q) - (TAU - 6.0)).abs() < 1e-14);
    let q = swing * DQuat::from_rotation_x(0.5);
    assert_same_rotation(limit.project(q), swing * DQuat::from_rotation_x(2.0), 1e-15);
    assert!((limit.violation(q) - 1.5).abs() < 1e-14);
}

#[test]
fn twist_and_swing_both_outside() {
    let limit = shoulder();
    let q = DQuat::from_rotation_z(deg(120.0)) * DQuat::from_rotation_x(deg(110.0));
    let expected = DQuat::from_rotation_z(deg(100.0)) * DQuat::from_rotation_x(deg(80.0));
    assert_same_rotation(limit.project(q), expected, 1e-15);
    // The larger part: the twist is 30 degrees out, the swing 20.
    assert!((limit.violation(q) - deg(30.0)).abs() < 1e-14);
    let q = DQuat::from_rotation_y(deg(-95.0)) * DQuat::from_rotation_x(deg(-85.0));
    let expected = DQuat::from_rotation_y(deg(-70.0)) * DQuat::from_rotation_x(deg(-80.0));
    assert_same_rotation(limit.project(q), expected, 1e-15);
    assert!((limit.violation(q) - deg(25.0)).abs() < 1e-14);
}

#[test]
fn decomposition_recomposes_exactly() {
    let mut rng = Rng(5);
    for _ in 0..2000 {
        let q = rng.rotation();
        let axis = DVec3::new(rng.next() - 0.5, rng.next() - 0.5, rng.next() - 0.5);
        let (swing, twist) = swing_twist(q, axis);
        let unit_axis = axis.normalize();
        // q = swing * twist as quaternions, the twist about the axis with w >= 0, the
        // swing about an axis perpendicular to it.
        assert!(component_difference(swing * twist, q.normalize()) <= 1e-15);
        assert!(twist.w >= 0.0);
        assert!(twist.xyz().cross(unit_axis).length() <= 1e-15);
        assert!(swing.xyz().dot(unit_axis).abs() <= 1e-15);
    }
}

// ---------------------------------------------------------------- properties

#[test]
fn projection_properties_on_random_rotations() {
    let mut rng = Rng(2024);
    for (name, limit) in limit_zoo() {
        let mut moved = 0;
        for _ in 0..3000 {
            let q = rng.rotation();
            let p = limit.project(q);
            assert!(
                p.is_finite() && (p.length() - 1.0).abs() <= 1e-15,
                "{name}: {p}"
            );
            assert!(p.dot(q) >= 0.0, "{name}: sign");
            let v = limit.violation(p);
            assert!(v <= 1e-12, "{name}: violation {v:e} after projecting {q}");
            let again = limit.project(p);
            let drift = component_difference(again, p);
            assert!(drift <= 1e-15, "{name}: not idempotent ({drift:e}) at {q}");
            // q and -q are one rotation.
            assert_same_rotation(limit.project(-q), p, 1e-14);
            if limit.violation(q) == 0.0 {
                let drift = component_difference(p, q.normalize());
                assert!(
                    drift <= 1e-15,
                    "{name}: an allowed rotation moved {drift:e}"
                );
                // A unit quaternion that is allowed comes back bit for bit.
                let unit = q.normalize();
                assert_eq!(limit.project(unit), unit, "{name}");
            } else {
                moved += 1;
                assert!(
                    rotation_distance(p, q) > 0.0,
                    "{name}: violation but no move"
                );
            }
        }
        // Every kind except Free has rotations outside.
        assert_eq!(moved == 0, name == "free", "{name}: {moved} moved");
    }
}

#[test]
fn samples_are_allowed() {
    let mut rng = Rng(77);
    for (name, limit) in limit_zoo() {
        for _ in 0..3000 {
            let q = limit.sample(rng.unit3());
            let v = limit.violation(q);
            assert!(v <= 1e-12, "{name}: sample {q} has violation {v:e}");
            assert!((q.length() - 1.0).abs() <= 1e-15);
            assert!(rotation_distance(limit.project(q), q) <= 1e-12, "{name}");
        }
        // The corners of the unit cube and out-of-range input are allowed too.
        for u in [[0.0; 3], [1.0; 3], [f64::NAN, -1.0, 7.0]] {
            let q = limit.sample(u);
            assert!(
                q.is_finite() && limit.violation(q) <= 1e-12,
                "{name}: {u:?} {q} {}",
                limit.violation(q)
            );
        }
    }
}

#[test]
fn samples_follow_the_parameters() {
    let elbow = JointLimit::hinge(-DVec3::Y, 0.0, deg(150.0)).unwrap();
    assert_same_rotation(
        elbow.sample([0.5, 0.9, 0.1]),
        DQuat::from_axis_angle(-DVec3::Y, deg(75.0)),
        1e-15,
    );
    let limit = shoulder();
    // rho = 0: no swing, the twist at its lower bound.
    assert_same_rotation(
        limit.sample([0.0, 0.3, 0.0]),
        DQuat::from_rotation_x(deg(-80.0)),
        1e-15,
    );
    // rho = 1/2 at psi = 0: half the a semi-axis about a_axis, twist at mid-range.
    assert_same_rotation(
        limit.sample([0.25, 0.0, 0.5]),
        DQuat::from_rotation_z(deg(50.0)),
        1e-15,
    );
    // The swing vectors fill the ellipse uniformly: a quarter of the area lies within
    // half its size (rho <= 1/2), so about a quarter of the samples do.
    let st = swing_twist_of(&limit);
    let mut rng = Rng(3);
    let n = 20_000;
    let inner = (0..n)
        .filter(|_| {
            let s = swing_vector(limit.sample(rng.unit3()), DVec3::X);
            let (a, b) = (s.dot(DVec3::Z), -s.dot(DVec3::Y));
            (a / st.swing_a).powi(2) + (b / st.swing_b).powi(2) <= 0.25
        })
        .count();
    let fraction = inner as f64 / n as f64;
    // Binomial standard deviation sqrt(0.25 * 0.75 / n) = 0.003; allow 5 of them.
    assert!((fraction - 0.25).abs() < 0.015, "{fraction}");
}

#[test]
fn fixed_and_free() {
    let q = DQuat::from_rotation_x(0.3) * DQuat::from_rotation_y(-0.2);
    assert_eq!(JointLimit::Fixed.project(q), DQuat::IDENTITY);
    assert!((JointLimit::Fixed.violation(q) - rotation_distance(q, DQuat::IDENTITY)).abs() < 1e-15);
    assert_eq!(JointLimit::Fixed.violation(DQuat::IDENTITY), 0.0);
    assert_eq!(JointLimit::Free.project(q * 2.0), q.normalize());
    assert_eq!(JointLimit::Free.violation(q), 0.0);
    assert_eq!(JointLimit::default(), JointLimit::Free);
}

#[test]
fn non_rotations_are_handled() {
    let nan = DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0);
    let zero = DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0);
    let tiny = DQuat::from_rotation_z(2.9) * 1e-300;
    let narrow = JointLimit::hinge(DVec3::Z, 2.0, 3.0).unwrap();
    for (name, limit) in limit_zoo().into_iter().chain([("narrow", narrow)]) {
        for q in [nan, zero] {
            // Not a rotation: projected as the identity would be, infinitely violating.
            assert_eq!(limit.project(q), limit.project(DQuat::IDENTITY), "{name}");
            assert_eq!(limit.violation(q), f64::INFINITY, "{name}");
        }
        // A tiny quaternion is still a rotation.
        assert_same_rotation(
            limit.project(tiny),
            limit.project(DQuat::from_rotation_z(2.9)),
            1e-15,
        );
    }
    assert_same_rotation(narrow.project(nan), DQuat::from_rotation_z(2.0), 1e-15);
}

// ---------------------------------------------------------------- validation

#[track_caller]
fn assert_refused(limit: JointLimit, field: &str, value: &str) {
    let err = limit.validate().expect_err("should be refused");
    let message = err.to_string();
    assert!(
        message.contains(field) && message.contains(value),
        "{message:?} should name {field} and {value}"
    );
}

#[test]
fn validate_names_each_bad_field() {
    let hinge = Hinge {
        axis: DVec3::Z,
        min: -1.0,
        max: 1.0,
    };
    assert!(JointLimit::Hinge(hinge).validate().is_ok());
    let h = |f: fn(&mut Hinge)| {
        let mut h = hinge;
        f(&mut h);
        JointLimit::Hinge(h)
    };
    assert_refused(
        h(|h| h.axis = DVec3::new(0.0, 0.0, 2.0)),
        "axis",
        "[0, 0, 2]",
    );
    assert_refused(h(|h| h.axis = DVec3::ZERO), "axis", "[0, 0, 0]");
    assert_refused(h(|h| h.axis.x = f64::NAN), "axis", "NaN");
    assert_refused(h(|h| h.min = f64::NAN), "min", "NaN");
    assert_refused(h(|h| h.min = -3.5), "min", "-3.5");
    assert_refused(h(|h| h.max = 4.0), "max", "4");
    assert_refused(h(|h| h.max = f64::INFINITY), "max", "inf");
    assert_refused(h(|h| h.min = 1.5), "min = 1.5", "max = 1");

    let st = swing_twist_of(&shoulder());
    let s = |f: fn(&mut SwingTwist)| {
        let mut s = st;
        f(&mut s);
        JointLimit::SwingTwist(s)
    };
    assert_refused(
        s(|s| s.twist_axis = DVec3::new(0.5, 0.0, 0.0)),
        "twist_axis",
        "[0.5, 0, 0]",
    );
    assert_refused(
        s(|s| s.a_axis = DVec3::new(0.0, 0.0, 1.1)),
        "a_axis",
        "[0, 0, 1.1]",
    );
    let err = s(|s| s.a_axis = DVec3::new(0.1, 0.0, 1.0).normalize())
        .validate()
        .unwrap_err();
    assert!(matches!(err, LimitError::NotPerpendicular { .. }));
    let message = err.to_string();
    assert!(
        message.contains("a_axis") && message.contains("twist_axis"),
        "{message}"
    );
    assert_refused(s(|s| s.swing_a = 0.0), "swing_a", "0");
    assert_refused(s(|s| s.swing_a = -0.5), "swing_a", "-0.5");
    assert_refused(s(|s| s.swing_b = 3.2), "swing_b", "3.2");
    assert_refused(s(|s| s.swing_b = f64::NAN), "swing_b", "NaN");
    assert_refused(s(|s| s.twist_min = -4.0), "twist_min", "-4");
    assert_refused(s(|s| s.twist_max = f64::NEG_INFINITY), "twist_max", "-inf");
    assert_refused(s(|s| s.twist_min = 1.5), "twist_min = 1.5", "twist_max");
    // The edges of the allowed intervals are allowed.
    assert!(
        s(|s| {
            s.swing_a = PI;
            s.twist_min = -PI;
            s.twist_max = PI;
        })
        .validate()
        .is_ok()
    );
    // Within the tolerances.
    assert!(
        s(|s| s.a_axis = DVec3::new(1e-10, 0.0, 1.0 + 1e-10))
            .validate()
            .is_ok()
    );
}

#[test]
fn constructors_normalise_and_validate() {
    let JointLimit::Hinge(h) = JointLimit::hinge(DVec3::new(0.0, -2.0, 0.0), 0.0, 2.618).unwrap()
    else {
        panic!("not a hinge")
    };
    assert_eq!(h.axis, -DVec3::Y);
    assert!(matches!(
        JointLimit::hinge(DVec3::ZERO, 0.0, 1.0),
        Err(LimitError::Axis { field: "axis", .. })
    ));
    assert!(matches!(
        JointLimit::hinge(DVec3::X, 1.0, 0.0),
        Err(LimitError::EmptyRange { .. })
    ));
    let st = swing_twist_of(
        &JointLimit::swing_twist(DVec3::X * 3.0, DVec3::Z * 0.5, 1.0, 0.5, -0.1, 0.1).unwrap(),
    );
    assert_eq!((st.twist_axis, st.a_axis), (DVec3::X, DVec3::Z));
    assert!(matches!(
        JointLimit::swing_twist(DVec3::X, DVec3::new(1.0, 1.0, 0.0), 1.0, 0.5, -0.1, 0.1),
        Err(LimitError::NotPerpendicular { .. })
    ));
    assert!(matches!(
        JointLimit::swing_twist(
            DVec3::X,
            DVec3::new(f64::NAN, 0.0, 1.0),
            1.0,
            0.5,
            -0.1,
            0.1
        ),
        Err(LimitError::Axis {
            field: "a_axis",
            ..
        })
    ));
    let cone = swing_twist_of(&JointLimit::cone(DVec3::new(0.0, 0.0, -5.0), 0.7).unwrap());
    assert_eq!(cone.twist_axis, -DVec3::Z);
    assert!(cone.a_axis.dot(cone.twist_axis).abs() < 1e-15);
    assert_eq!(
        (cone.swing_a, cone.swing_b, cone.twist_min, cone.twist_max),
        (0.7, 0.7, -PI, PI)
    );
    assert!(matches!(
        JointLimit::cone(DVec3::Y, 0.0),
        Err(LimitError::Angle {
            field: "swing_a",
            ..
        })
    ));
}

#[test]
fn centres_are_the_middle_of_each_range() {
    let hinge = JointLimit::hinge(DVec3::Z, 0.2, 1.0).unwrap();
    let centre = hinge.centre().unwrap();
    let expected = DQuat::from_axis_angle(DVec3::Z, 0.6);
    assert!(centre.dot(expected).abs() > 1.0 - 1e-15, "{centre:?}");
    let st = JointLimit::swing_twist(DVec3::X, DVec3::Z, 1.0, 0.5, -0.2, 0.6).unwrap();
    let centre = st.centre().unwrap();
    let expected = DQuat::from_axis_angle(DVec3::X, 0.2);
    assert!(centre.dot(expected).abs() > 1.0 - 1e-15, "{centre:?}");
    assert_eq!(JointLimit::Fixed.centre(), Some(DQuat::IDENTITY));
    assert_eq!(JointLimit::Free.centre(), None);
}

#[test]
fn a_hinge_pushes_outwards_only_from_a_bound_it_sits_on() {
    let hinge = Hinge {
        axis: DVec3::NEG_Y,
        min: 0.0,
        max: 150f64.to_radians(),
    };
    let at = |angle: f64| DQuat::from_axis_angle(hinge.axis, angle);
    let pushes = |q: DQuat, step: f64| hinge.pushes_outwards(q, step, 1e-12);
    // At the lower bound: a negative step leaves the range, a positive one enters it.
    assert!(pushes(at(0.0), -1e-3));
    assert!(!pushes(at(0.0), 1e-3));
    // At the upper bound, the other way round.
    assert!(pushes(at(hinge.max), 1e-3));
    assert!(!pushes(at(hinge.max), -1e-3));
    // Inside the range, no step is blocked (only a bound the joint sits on counts).
    for angle in [1e-6, 1.0, hinge.max - 1e-6] {
        assert!(!pushes(at(angle), 1e-3), "{angle}");
        assert!(!pushes(at(angle), -1e-3), "{angle}");
    }
    // The quaternion's sign does not change the angle read.
    assert!(pushes(-at(hinge.max), 1e-3));
    // `at_bound` widens the bound: 1e-6 inside counts as on it with a 1e-5 allowance.
    assert!(hinge.pushes_outwards(at(hinge.max - 1e-6), 1e-3, 1e-5));
    // A range reaching past a half turn reads the angle in (-pi, pi].
    let wide = Hinge {
        axis: DVec3::X,
        min: -PI,
        max: PI,
    };
    assert!(!wide.pushes_outwards(DQuat::from_axis_angle(DVec3::X, 3.0), 1e-3, 1e-12));
}

#[test]
fn the_violation_parts_are_the_violations_with_the_other_constraint_opened_up() {
    let st = SwingTwist {
        twist_axis: DVec3::Y,
        a_axis: DVec3::Z,
        swing_a: 1.1,
        swing_b: 0.4,
        twist_min: -0.3,
        twist_max: 0.8,
    };
    let swing_only = JointLimit::SwingTwist(SwingTwist {
        twist_min: -PI,
        twist_max: PI,
        ..st
    });
    let twist_only = JointLimit::SwingTwist(SwingTwist {
        swing_a: PI,
        swing_b: PI,
        ..st
    });
    let whole = JointLimit::SwingTwist(st);
    // A fixed walk over rotations inside, outside and on the far side of the limit.
    let mut outside = 0;
    for k in 0..500 {
        let t = k as f64;
        let axis = DVec3::new((t * 0.37).sin(), (t * 0.91).cos(), (t * 0.53).sin() + 0.1);
        let q = DQuat::from_axis_angle(axis.normalize(), (t * 0.0123) % TAU - PI);
        let (swing, twist) = st.violation_parts(q);
        assert_eq!(swing, swing_only.violation(q), "{q}");
        assert_eq!(twist, twist_only.violation(q), "{q}");
        assert_eq!(swing.max(twist), whole.violation(q), "{q}");
        outside += usize::from(swing > 0.0 && twist > 0.0);
    }
    // The walk does reach the corner where both constraints are violated.
    assert!(outside > 10, "{outside}");
    assert_eq!(
        st.violation_parts(DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0)),
        (f64::INFINITY, f64::INFINITY)
    );
}

// ---------------------------------------------------------------- prepared limits

/// Bit-for-bit equality of two quaternions (`==` would let `-0.0` pass for `0.0`).
fn same_bits(a: DQuat, b: DQuat) -> bool {
    a.to_array()
        .iter()
        .zip(b.to_array())
        .all(|(x, y)| x.to_bits() == y.to_bits())
}

#[test]
fn a_prepared_limit_answers_exactly_as_the_limit_itself() {
    // Random rotations, rotations inside each limit (its samples), the same pushed just
    // across the bounds by tiny turns, hinge rotations a rounding off their axis, and
    // rotations that are not unit or not rotations at all: the quick inside test may only
    // ever short-cut to the answer the exact test gives.
    let mut rng = Rng(0x5EED_0000_0000_00A1);
    let mut zoo = limit_zoo();
    zoo.push(("fixed", JointLimit::Fixed));
    zoo.push((
        "elbow",
        JointLimit::hinge(DVec3::new(0.0, -1.0, 0.0), 0.0, deg(150.0)).unwrap(),
    ));
    zoo.push((
        "tilted hinge",
        JointLimit::hinge(DVec3::new(0.3, -0.4, 0.5), -1.0, 0.5).unwrap(),
    ));
    let mut quick_inside = 0;
    let mut total = 0;
    for (name, limit) in &zoo {
        let prepared = limit.prepare();
        assert_eq!(prepared.limit(), limit);
        let mut check = |q: DQuat| {
            let (exact, fast) = (limit.project(q), prepared.project(q));
            assert!(
                same_bits(exact, fast),
                "{name}: project {q}: {exact} vs {fast}"
            );
            let (exact, fast) = (limit.violation(q), prepared.violation(q));
            assert_eq!(exact.to_bits(), fast.to_bits(), "{name}: violation {q}");
            total += 1;
            quick_inside += usize::from(exact == 0.0);
        };
        for _ in 0..4000 {
            check(rng.rotation());
            let inside = limit.sample(rng.unit3());
            check(inside);
            check(inside * (1.0 + 1e-14));
            for scale in [1e-15, 1e-12, 1e-9, 1e-6, 1e-3] {
                let axis = DVec3::new(rng.next(), rng.next(), rng.next()) * 2.0 - DVec3::ONE;
                check((DQuat::from_scaled_axis(axis * scale) * inside).normalize());
            }
            // The bounds themselves, approached from both sides.
            let bound = limit.project(rng.rotation());
            for scale in [0.0, 1e-15, 1e-13, 1e-11] {
                let axis = DVec3::new(rng.next(), rng.next(), rng.next()) * 2.0 - DVec3::ONE;
                check((DQuat::from_scaled_axis(axis * scale) * bound).normalize());
            }
        }
        check(DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0));
        check(DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0));
        check(DQuat::from_xyzw(0.0, 0.0, 0.0, -1.0));
        check(DQuat::from_xyzw(1e-300, 0.0, 0.0, 1e-300));
    }
    // Inside answers are common, so the comparison covers the quick path.
    assert!(quick_inside > total / 10, "{quick_inside} of {total}");
}
