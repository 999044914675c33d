//! Whether a mesh passes through itself at a given state: an edge through a triangle it
//! shares no vertex with.
//!
//! The barrier and the line search's cap keep every state the minimization accepts free
//! of crossings, by induction from a start that has none. The gaps (distance minus
//! thickness) checked at the start cannot see a crossing: an edge that pierces a
//! triangle's interior may be far from the triangle's vertices and edges, and its own
//! vertices far from the triangle's plane. So a start state is checked here too.
//!
//! Two triangles sharing no vertex meet in one of two ways: one's edge meets the other's
//! interior or boundary across its plane (found here), or both lie in one plane and
//! overlap, when a vertex of one lies on the other or two of their edges meet: a zero
//! distance, which the gap check refuses. So this test and the gap check together refuse
//! every state in which two triangles sharing no vertex meet.
//!
//! The orientation signs come from floating point with Shewchuk's static error bound
//! (the first filter of his `orient3d`): where the bound cannot decide a sign, the sign
//! counts as zero, which reads as touching. So the test may refuse a state in which an
//! edge passes within rounding of a triangle, and accepts none in which an edge passes
//! through it across its plane. One case is left to the gaps alone: an edge with both
//! ends within rounding of the triangle's plane (coplanar, as in a flat sheet, but
//! possibly tilted by rounding), which the gap check refuses only when its distance is
//! at most the thickness; with a thickness of zero, such an edge crossing the triangle
//! at a distance of a few ulps would pass both. Derivation: docs/contact.md, "A start that passes through itself".

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

/// Whether the closed segment `p q` may meet the closed triangle `t` across the
/// triangle's plane: `false` only where the floating-point signs prove the two apart, or
/// where the segment lies in the triangle's plane (its meeting the triangle there is a
/// zero distance, see the module documentation).
#[must_use]
pub fn segment_may_cross_triangle(p: DVec3, q: DVec3, t: [DVec3; 3]) -> bool {
    let sp = orientation_sign(t[0], t[1], t[2], p);
    let sq = orientation_sign(t[0], t[1], t[2], q);
    if sp == 0 && sq == 0 {
        // In the plane, to rounding: left to the gaps.
        return false;
    }
    if sp == sq {
        // Both ends strictly on one side.
        return false;
    }
    // The segment reaches the plane: it meets the triangle where its line passes inside
    // or on the triangle's three edges, all seen turning one way.
    let s = [
        orientation_sign(p, q, t[0], t[1]),
        orientation_sign(p, q, t[1], t[2]),
        orientation_sign(p, q, t[2], t[0]),
    ];
    !(s.contains(&1) && s.contains(&-1))
}

/// The first edge (in the primitives' order, then the triangle's) that may pass through a
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
            segment_may_cross_triangle(x[a], x[b], prims.triangles[t].map(|v| x[v]))
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
        assert!(segment_may_cross_triangle(
            v(0.2, 0.2, -1.0),
            v(0.2, 0.2, 1.0),
            T
        ));
        assert!(segment_may_cross_triangle(
            v(0.2, 0.2, 1.0),
            v(0.3, 0.1, -1e-9),
            T
        ));
        // Through the plane outside the triangle, beyond each edge.
        assert!(!segment_may_cross_triangle(
            v(0.6, 0.6, -1.0),
            v(0.6, 0.6, 1.0),
            T
        ));
        assert!(!segment_may_cross_triangle(
            v(-0.1, 0.2, -1.0),
            v(-0.1, 0.2, 1.0),
            T
        ));
        assert!(!segment_may_cross_triangle(
            v(0.2, -0.1, -1.0),
            v(0.2, -0.1, 1.0),
            T
        ));
        // Both ends on one side, above the interior.
        assert!(!segment_may_cross_triangle(
            v(0.2, 0.2, 1e-9),
            v(0.2, 0.2, 1.0),
            T
        ));
        // Stopping short of the plane.
        assert!(!segment_may_cross_triangle(
            v(0.2, 0.2, -1.0),
            v(0.2, 0.2, -1e-12),
            T
        ));
    }

    #[test]
    fn touching_counts_as_crossing_and_lying_in_the_plane_is_left_to_the_gaps() {
        // An end on the triangle's interior, its edge, its vertex.
        assert!(segment_may_cross_triangle(
            v(0.2, 0.2, 0.0),
            v(0.2, 0.2, 1.0),
            T
        ));
        assert!(segment_may_cross_triangle(
            v(0.5, 0.0, 0.0),
            v(0.5, 1.0, 1.0),
            T
        ));
        assert!(segment_may_cross_triangle(
            v(0.0, 0.0, 0.0),
            v(-1.0, -1.0, -1.0),
            T
        ));
        // Through the triangle's edge x + y = 1 exactly.
        assert!(segment_may_cross_triangle(
            v(0.5, 0.5, -1.0),
            v(0.5, 0.5, 1.0),
            T
        ));
        // In the plane, crossing the triangle or not: the gaps' business.
        assert!(!segment_may_cross_triangle(
            v(-1.0, 0.2, 0.0),
            v(2.0, 0.2, 0.0),
            T
        ));
        assert!(!segment_may_cross_triangle(
            v(2.0, 2.0, 0.0),
            v(3.0, 2.0, 0.0),
            T
        ));
    }

    #[test]
    fn the_signs_agree_with_the_exact_predicates_wherever_they_decide() {
        // Random points, and points nearly on the plane, against exact arithmetic: a
        // decided sign is never wrong, and a segment the exact test says crosses (not in
        // the plane) is never passed.
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut unit = move || {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut point = |scale: f64| v(unit() - 0.5, unit() - 0.5, (unit() - 0.5) * scale);
        let (mut decided, mut undecided) = (0, 0);
        for k in 0..20_000 {
            let scale = [1.0, 1e-8, 1e-15, 0.0][k % 4];
            let t = [point(scale), point(scale), point(scale)];
            let (p, q) = (point(1.0), point(scale));
            let sign = orientation_sign(t[0], t[1], t[2], q);
            let exact = sinew_exact::orientation(t[0], t[1], t[2], q);
            if sign == 0 {
                undecided += 1;
            } else {
                decided += 1;
                assert_eq!(f64::from(sign), exact.signum(), "case {k}");
            }
            if sinew_exact::orientation(t[0], t[1], t[2], p) != 0.0 && exact != 0.0 {
                let meets = sinew_exact::segment_meets_triangle(p, q, t);
                if meets {
                    assert!(segment_may_cross_triangle(p, q, t), "case {k}");
                }
            }
        }
        // Most signs are decided, and the near-plane cases leave some undecided.
        assert!(decided > 10_000 && undecided > 0, "{decided} {undecided}");
    }
}
