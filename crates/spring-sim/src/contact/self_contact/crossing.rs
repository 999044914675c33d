//! Whether a mesh passes through itself at a given state: an edge meeting a triangle it
//! shares no vertex with.
//!
//! The barrier and the line search's cap keep every state the minimization accepts free
//! of crossings, by induction from a start that has none. The gaps (distance minus
//! thickness) checked at the start cannot see a crossing: an edge that pierces a
//! triangle's interior may be far from the triangle's vertices and edges, and its own
//! vertices far from the triangle's plane. So a start state is checked here too.
//!
//! Two closed triangles meet exactly when an edge of one meets the other, so testing
//! every edge against every triangle sharing no vertex with it finds every meeting pair
//! of triangles sharing no vertex. An edge meets a triangle either across the triangle's
//! plane (an end on each side, or on it) or, both ends in the plane, inside it.
//!
//! The orientation signs come from floating point with Shewchuk's static error bounds
//! (the first filters of his `orient3d` and `orient2d`): where a bound cannot decide a
//! sign, the sign counts as zero, which reads as touching. An edge with both ends within
//! rounding of the triangle's plane (coplanar, as in a flat sheet) is tested in the
//! projection onto the coordinate plane the triangle faces most: a projection of two
//! meeting sets meets, so only a meeting the projection rules out with decided signs (or
//! with disjoint coordinate ranges, an exact comparison) is passed. So the test may
//! refuse a state in which an edge passes within rounding of a triangle, and accepts none
//! in which an edge meets one. Derivation: docs/contact.md, "A start that passes through
//! itself".

use super::broad::{Primitives, edge_triangle_candidates};
use sinew_math::DVec3;

/// Shewchuk's bound on the rounding error of the orientation determinant computed in
/// floating point from the differences `a - d`, `b - d`, `c - d`, relative to its
/// permanent: `(7 + 56 eps) eps` with `eps = 2^-53`.
const ORIENT_ERROR_BOUND: f64 = (7.0 + 56.0 * f64::EPSILON / 2.0) * f64::EPSILON / 2.0;

/// The sign of `det[a - d, b - d, c - d]` (positive when `d` is below the plane of
/// `a, b, c` seen with `a, b, c` counterclockwise): `1` or `-1` where floating point
/// decides it, `0` where the determinant is within its error bound of zero (or not
/// finite).
pub fn orientation_sign(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> i8 {
    let (ad, bd, cd) = (a - d, b - d, c - d);
    let bc = bd.x * cd.y - cd.x * bd.y;
    let ca = cd.x * ad.y - ad.x * cd.y;
    let ab = ad.x * bd.y - bd.x * ad.y;
    let det = ad.z * bc + bd.z * ca + cd.z * ab;
    let permanent = ((bd.x * cd.y).abs() + (cd.x * bd.y).abs()) * ad.z.abs()
        + ((cd.x * ad.y).abs() + (ad.x * cd.y).abs()) * bd.z.abs()
        + ((ad.x * bd.y).abs() + (bd.x * ad.y).abs()) * cd.z.abs();
    let bound = ORIENT_ERROR_BOUND * permanent;
    if det > bound {
        1
    } else if -det > bound {
        -1
    } else {
        0
    }
}

/// Shewchuk's bound on the rounding error of the 2D orientation determinant computed in
/// floating point from the differences `a - c`, `b - c`, relative to its permanent:
/// `(3 + 16 eps) eps` with `eps = 2^-53`.
const ORIENT_2D_ERROR_BOUND: f64 = (3.0 + 16.0 * f64::EPSILON / 2.0) * f64::EPSILON / 2.0;

/// The sign of `det[a - c, b - c]` for points in the plane: `1` (counterclockwise) or
/// `-1` where floating point decides it, `0` where the determinant is within its error
/// bound of zero (or not finite).
fn orientation_sign_2d(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> i8 {
    let left = (a[0] - c[0]) * (b[1] - c[1]);
    let right = (a[1] - c[1]) * (b[0] - c[0]);
    let det = left - right;
    let bound = ORIENT_2D_ERROR_BOUND * (left.abs() + right.abs());
    if det > bound {
        1
    } else if -det > bound {
        -1
    } else {
        0
    }
}

/// Whether three signs leave a point possibly in a closed triangle (or a line possibly
/// through it): not both a decided `1` and a decided `-1`.
fn not_both_sides(s: [i8; 3]) -> bool {
    !(s.contains(&1) && s.contains(&-1))
}

/// Whether the closed segments `a b` and `c d` in the plane may meet: `false` only where
/// their coordinate ranges are disjoint or decided signs put one segment strictly on one
/// side of the other's line.
fn segments_may_meet_2d(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> bool {
    for k in 0..2 {
        if a[k].max(b[k]) < c[k].min(d[k]) || c[k].max(d[k]) < a[k].min(b[k]) {
            return false;
        }
    }
    let one_side = |s: i8, t: i8| s != 0 && s == t;
    let (sc, sd) = (orientation_sign_2d(a, b, c), orientation_sign_2d(a, b, d));
    let (sa, sb) = (orientation_sign_2d(c, d, a), orientation_sign_2d(c, d, b));
    !(one_side(sc, sd) || one_side(sa, sb))
}

/// Whether the closed segment `p q`, both ends within rounding of the plane of `t`, may
/// meet the closed triangle `t`, tested in the projection onto the coordinate plane
/// normal to the axis the triangle's normal is largest along (any projection is sound;
/// this one keeps the most of the triangle's area).
fn coplanar_segment_may_meet_triangle(p: DVec3, q: DVec3, t: [DVec3; 3]) -> bool {
    // A NaN reads as 0 in every sign (so it lands here), and the range comparisons below
    // would drop it: a point that is not finite may meet anything.
    if !(p.is_finite() && q.is_finite() && t.iter().all(|v| v.is_finite())) {
        return true;
    }
    let n = (t[1] - t[0]).cross(t[2] - t[0]).abs();
    let drop = if n.x >= n.y && n.x >= n.z {
        0
    } else if n.y >= n.z {
        1
    } else {
        2
    };
    let flat = |v: DVec3| match drop {
        0 => [v.y, v.z],
        1 => [v.z, v.x],
        _ => [v.x, v.y],
    };
    let (p, q, t) = (flat(p), flat(q), t.map(flat));
    // The segment meets the triangle's boundary, or (meeting none of it) lies wholly
    // inside or wholly outside, as its end p does.
    (0..3).any(|k| segments_may_meet_2d(p, q, t[k], t[(k + 1) % 3]))
        || not_both_sides([
            orientation_sign_2d(t[0], t[1], p),
            orientation_sign_2d(t[1], t[2], p),
            orientation_sign_2d(t[2], t[0], p),
        ])
}

/// Whether the closed segment `p q` may meet the closed triangle `t`: `false` only where
/// floating-point signs with their error bounds prove the two apart.
#[must_use]
pub fn segment_may_meet_triangle(p: DVec3, q: DVec3, t: [DVec3; 3]) -> bool {
    let sp = orientation_sign(t[0], t[1], t[2], p);
    let sq = orientation_sign(t[0], t[1], t[2], q);
    if sp == 0 && sq == 0 {
        return coplanar_segment_may_meet_triangle(p, q, t);
    }
    if sp == sq {
        // Both ends strictly on one side.
        return false;
    }
    // The segment reaches the plane: it meets the triangle where its line passes inside
    // or on the triangle's three edges, all seen turning one way.
    not_both_sides([
        orientation_sign(p, q, t[0], t[1]),
        orientation_sign(p, q, t[1], t[2]),
        orientation_sign(p, q, t[2], t[0]),
    ])
}

/// The first edge (in the primitives' order, then the triangle's) that may meet a
/// triangle sharing none of its vertices at `x`, as `(edge, triangle)` indices into
/// `prims`; pairs whose every vertex is `skip`ped (two fixed primitives) are left out.
/// With `moved` (indexed by vertex), only pairs with a vertex in it are tested: from a
/// state known to cross nothing with the same `skip`, a pair none of whose vertices
/// moved cannot cross now (its four positions are the same).
#[must_use]
pub fn first_crossing(
    prims: &Primitives,
    x: &[DVec3],
    skip: &[bool],
    moved: Option<&[bool]>,
) -> Option<(usize, usize)> {
    edge_triangle_candidates(prims, x, skip, moved)
        .into_iter()
        .find(|&(e, t)| {
            let [a, b] = prims.edges[e];
            segment_may_meet_triangle(x[a], x[b], prims.triangles[t].map(|v| x[v]))
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, y: f64, z: f64) -> DVec3 {
        DVec3::new(x, y, z)
    }

    /// The triangle of the tests: in the plane z = 0.
    const T: [DVec3; 3] = [
        DVec3::new(0.0, 0.0, 0.0),
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(0.0, 1.0, 0.0),
    ];

    #[test]
    fn a_segment_through_the_interior_crosses_and_one_beside_it_does_not() {
        assert!(segment_may_meet_triangle(
            v(0.2, 0.2, -1.0),
            v(0.2, 0.2, 1.0),
            T
        ));
        assert!(segment_may_meet_triangle(
            v(0.2, 0.2, 1.0),
            v(0.3, 0.1, -1e-9),
            T
        ));
        // Through the plane outside the triangle, beyond each edge.
        assert!(!segment_may_meet_triangle(
            v(0.6, 0.6, -1.0),
            v(0.6, 0.6, 1.0),
            T
        ));
        assert!(!segment_may_meet_triangle(
            v(-0.1, 0.2, -1.0),
            v(-0.1, 0.2, 1.0),
            T
        ));
        assert!(!segment_may_meet_triangle(
            v(0.2, -0.1, -1.0),
            v(0.2, -0.1, 1.0),
            T
        ));
        // Both ends on one side, above the interior.
        assert!(!segment_may_meet_triangle(
            v(0.2, 0.2, 1e-9),
            v(0.2, 0.2, 1.0),
            T
        ));
        // Stopping short of the plane.
        assert!(!segment_may_meet_triangle(
            v(0.2, 0.2, -1.0),
            v(0.2, 0.2, -1e-12),
            T
        ));
    }

    #[test]
    fn touching_counts_as_meeting() {
        // An end on the triangle's interior, its edge, its vertex.
        assert!(segment_may_meet_triangle(
            v(0.2, 0.2, 0.0),
            v(0.2, 0.2, 1.0),
            T
        ));
        assert!(segment_may_meet_triangle(
            v(0.5, 0.0, 0.0),
            v(0.5, 1.0, 1.0),
            T
        ));
        assert!(segment_may_meet_triangle(
            v(0.0, 0.0, 0.0),
            v(-1.0, -1.0, -1.0),
            T
        ));
        // Through the triangle's edge x + y = 1 exactly.
        assert!(segment_may_meet_triangle(
            v(0.5, 0.5, -1.0),
            v(0.5, 0.5, 1.0),
            T
        ));
    }

    #[test]
    fn in_the_plane_a_segment_meets_the_triangle_only_where_it_overlaps_it() {
        let meets = |p, q| segment_may_meet_triangle(p, q, T);
        // Across the triangle, wholly inside, from outside to inside, along an edge.
        assert!(meets(v(-1.0, 0.2, 0.0), v(2.0, 0.2, 0.0)));
        assert!(meets(v(0.1, 0.1, 0.0), v(0.2, 0.1, 0.0)));
        assert!(meets(v(-1.0, -1.0, 0.0), v(0.1, 0.2, 0.0)));
        assert!(meets(v(0.2, 0.0, 0.0), v(0.7, 0.0, 0.0)));
        // Touching a vertex end to end, and an edge's line at its middle.
        assert!(meets(v(1.0, 0.0, 0.0), v(2.0, 0.0, 0.0)));
        assert!(meets(v(0.5, 0.5, 0.0), v(1.0, 1.0, 0.0)));
        // Apart: beside it, on an edge's line beyond the edge (as the next edges along a
        // flat sheet's row are), beyond the hypotenuse, and behind the right angle.
        assert!(!meets(v(2.0, 2.0, 0.0), v(3.0, 2.0, 0.0)));
        assert!(!meets(v(2.0, 0.0, 0.0), v(3.0, 0.0, 0.0)));
        assert!(!meets(v(0.0, -2.0, 0.0), v(0.0, -1.0, 0.0)));
        assert!(!meets(v(0.6, 0.6, 0.0), v(2.0, 0.6, 0.0)));
        assert!(!meets(v(-0.1, -0.1, 0.0), v(-1.0, -0.5, 0.0)));
        // The same in a plane the coordinates cannot hold exactly: the triangle and the
        // segment turned about x by 0.3 rad (to rounding in the plane), the segment
        // crossing the triangle and passing beside it.
        let (c, s) = (0.3f64.cos(), 0.3f64.sin());
        let turn = |p: DVec3| v(p.x, c * p.y - s * p.z, s * p.y + c * p.z);
        let t = T.map(turn);
        let inside = [v(-1.0, 0.2, 0.0), v(2.0, 0.2, 0.0)].map(turn);
        let beside = [v(2.0, 2.0, 0.0), v(3.0, 2.0, 0.0)].map(turn);
        assert!(segment_may_meet_triangle(inside[0], inside[1], t));
        // An end that is not finite may meet anything.
        assert!(meets(v(3.0, 2.0, 0.0), v(f64::NAN, 2.0, 0.0)));
        assert!(!segment_may_meet_triangle(beside[0], beside[1], t));
    }

    #[test]
    fn the_signs_agree_with_the_exact_predicates_wherever_they_decide() {
        // Random points, and points nearly or exactly on the triangle's plane, against
        // exact arithmetic: a decided sign is never wrong, and a segment the exact test
        // says meets the triangle (across its plane or in it) is never passed.
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut unit = move || {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut point = |scale: f64| v(unit() - 0.5, unit() - 0.5, (unit() - 0.5) * scale);
        let (mut decided, mut undecided) = (0, 0);
        let (mut in_plane_apart, mut in_plane_passed, mut in_plane_met) = (0, 0, 0);
        for k in 0..20_000 {
            let scale = [1.0, 1e-8, 1e-15, 0.0][k % 4];
            let t = [point(scale), point(scale), point(scale)];
            // In the plane cases both ends are near it; otherwise one end is anywhere.
            let p = if k % 8 == 3 { point(scale) } else { point(1.0) };
            let q = point(scale);
            let sign = orientation_sign(t[0], t[1], t[2], q);
            let exact = sinew_exact::orientation(t[0], t[1], t[2], q);
            if sign == 0 {
                undecided += 1;
            } else {
                decided += 1;
                assert_eq!(f64::from(sign), exact.signum(), "case {k}");
            }
            let meets = sinew_exact::segment_meets_triangle(p, q, t);
            let may = segment_may_meet_triangle(p, q, t);
            if meets {
                assert!(may, "case {k}");
            }
            if scale == 0.0 && k % 8 == 3 {
                if meets {
                    in_plane_met += 1;
                } else {
                    in_plane_apart += 1;
                    in_plane_passed += usize::from(!may);
                }
            }
        }
        // Most signs are decided, and the near-plane cases leave some undecided.
        assert!(decided > 10_000 && undecided > 0, "{decided} {undecided}");
        // Segments in the plane meet the triangle in some cases; of those apart, the
        // projection passes all.
        assert!(in_plane_met > 100, "{in_plane_met}");
        assert_eq!(
            in_plane_passed, in_plane_apart,
            "{in_plane_passed} of {in_plane_apart}"
        );
    }
}
