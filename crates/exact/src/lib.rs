//! sinew-exact: an exact check that a triangle mesh does not pass through itself, sharing
//! no code with the self-contact solver (its distances, broad phase and continuous collision
//! detection): Shewchuk's exact orientation predicates (the `robust` crate) and a
//! triangle-triangle test written on them, with its own sweep over the triangles' boxes.
//!
//! Two closed triangles meet exactly when an edge of one meets the other (their
//! intersection, if any, is a segment or polygon with an endpoint on an edge of one of
//! them). A closed segment `ab` meets a closed triangle `pqr` when `a` and `b` are not
//! strictly on the same side of its plane and the line `ab` passes all three edges on the
//! same side (`orient3d(a, b, p, q)`, `(a, b, q, r)`, `(a, b, r, p)` all `>= 0` or all
//! `<= 0`); a segment in the plane is tested in 2D (an endpoint inside the triangle, or
//! crossing or touching an edge), projected along the normal's largest component.
//! Touching counts as meeting, so the check is strict. Pairs of triangles that share a
//! vertex are not compared (they always touch).
//!
//! The self-contact scenes' `intersections` metric, the stress grid, the property tests
//! and spring-sim's own integration tests all count intersections with this one check, so
//! the guarantee "no intersecting triangles" is judged by code the solver never runs.
//!
//! ```
//! use sinew_exact::{intersecting_pairs, triangles_meet};
//! use sinew_math::DVec3;
//!
//! let flat = [DVec3::ZERO, DVec3::X, DVec3::Y];
//! let piercing = [
//!     DVec3::new(0.2, 0.2, -1.0),
//!     DVec3::new(0.2, 0.2, 1.0),
//!     DVec3::new(3.0, 3.0, 0.5),
//! ];
//! assert!(triangles_meet(flat, piercing));
//! let x = [flat, piercing].concat();
//! assert_eq!(intersecting_pairs(&x, &[[0, 1, 2], [3, 4, 5]]), vec![(0, 1)]);
//! ```

use robust::{Coord, Coord3D, orient2d, orient3d};
use sinew_math::DVec3;

fn c3(p: DVec3) -> Coord3D<f64> {
    Coord3D {
        x: p.x,
        y: p.y,
        z: p.z,
    }
}

fn o3(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> f64 {
    orient3d(c3(a), c3(b), c3(c), c3(d))
}

/// The exact sign of `det[a - d, b - d, c - d]` (Shewchuk's `orient3d`: positive when
/// `d` lies below the plane of `a, b, c`, seen with `a, b, c` counterclockwise), as a
/// number of that sign (zero exactly when the four points are coplanar).
#[must_use]
pub fn orientation(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> f64 {
    o3(a, b, c, d)
}

/// The point with coordinate `axis` dropped (the plane's normal is not perpendicular to
/// the remaining ones, so orientations are kept up to one common sign).
fn c2(p: DVec3, axis: usize) -> Coord<f64> {
    match axis {
        0 => Coord { x: p.y, y: p.z },
        1 => Coord { x: p.z, y: p.x },
        _ => Coord { x: p.x, y: p.y },
    }
}

fn o2(a: DVec3, b: DVec3, c: DVec3, axis: usize) -> f64 {
    orient2d(c2(a, axis), c2(b, axis), c2(c, axis))
}

/// Whether the closed segments `ab` and `cd`, coplanar, meet (in the projection).
fn segments_meet_2d(a: DVec3, b: DVec3, c: DVec3, d: DVec3, axis: usize) -> bool {
    let (d1, d2) = (o2(c, d, a, axis), o2(c, d, b, axis));
    let (d3, d4) = (o2(a, b, c, axis), o2(a, b, d, axis));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return true;
    }
    // Touching or collinear overlap: a point on the other segment's line within its box.
    let on = |p: DVec3, q: DVec3, r: DVec3| {
        let (u, v, w) = (c2(p, axis), c2(q, axis), c2(r, axis));
        w.x >= u.x.min(v.x) && w.x <= u.x.max(v.x) && w.y >= u.y.min(v.y) && w.y <= u.y.max(v.y)
    };
    (d1 == 0.0 && on(c, d, a))
        || (d2 == 0.0 && on(c, d, b))
        || (d3 == 0.0 && on(a, b, c))
        || (d4 == 0.0 && on(a, b, d))
}

/// Whether point `p` lies in the closed triangle `t` (all coplanar), projected.
fn point_in_triangle_2d(p: DVec3, t: [DVec3; 3], axis: usize) -> bool {
    let s = [
        o2(t[0], t[1], p, axis),
        o2(t[1], t[2], p, axis),
        o2(t[2], t[0], p, axis),
    ];
    s.iter().all(|&x| x >= 0.0) || s.iter().all(|&x| x <= 0.0)
}

/// Whether the closed segment `ab` meets the closed triangle `t`, exactly.
#[must_use]
pub fn segment_meets_triangle(a: DVec3, b: DVec3, t: [DVec3; 3]) -> bool {
    let (oa, ob) = (o3(t[0], t[1], t[2], a), o3(t[0], t[1], t[2], b));
    if (oa > 0.0 && ob > 0.0) || (oa < 0.0 && ob < 0.0) {
        return false;
    }
    if oa == 0.0 && ob == 0.0 {
        let n = (t[1] - t[0]).cross(t[2] - t[0]).abs();
        let axis = if n.x >= n.y && n.x >= n.z {
            0
        } else if n.y >= n.z {
            1
        } else {
            2
        };
        return point_in_triangle_2d(a, t, axis)
            || point_in_triangle_2d(b, t, axis)
            || (0..3).any(|k| segments_meet_2d(a, b, t[k], t[(k + 1) % 3], axis));
    }
    let s = [
        o3(a, b, t[0], t[1]),
        o3(a, b, t[1], t[2]),
        o3(a, b, t[2], t[0]),
    ];
    s.iter().all(|&x| x >= 0.0) || s.iter().all(|&x| x <= 0.0)
}

/// Whether two closed triangles meet, exactly (touching counts).
#[must_use]
pub fn triangles_meet(p: [DVec3; 3], q: [DVec3; 3]) -> bool {
    (0..3).any(|k| segment_meets_triangle(p[k], p[(k + 1) % 3], q))
        || (0..3).any(|k| segment_meets_triangle(q[k], q[(k + 1) % 3], p))
}

/// The pairs `(i, j)`, `i < j`, of triangles sharing no vertex that meet at positions
/// `x`. Boxes are compared first by a sweep along x (sorted by the boxes' lower x; the box
/// test is exact in floating point, so no meeting pair is skipped). A non-finite position
/// makes its triangles meet everything their boxes cannot rule out.
#[must_use]
pub fn intersecting_pairs(x: &[DVec3], triangles: &[[usize; 3]]) -> Vec<(usize, usize)> {
    let boxes: Vec<(DVec3, DVec3)> = triangles
        .iter()
        .map(|t| {
            let p = t.map(|i| x[i]);
            (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]))
        })
        .collect();
    let mut order: Vec<usize> = (0..triangles.len()).collect();
    order.sort_by(|&a, &b| boxes[a].0.x.total_cmp(&boxes[b].0.x));
    let mut out = Vec::new();
    for (k, &i) in order.iter().enumerate() {
        for &j in &order[k + 1..] {
            // Sorted by lower x: once a box starts beyond this one's end, all later do.
            if boxes[j].0.x > boxes[i].1.x {
                break;
            }
            let (a, b) = (boxes[i], boxes[j]);
            if a.0.cmpgt(b.1).any() || b.0.cmpgt(a.1).any() {
                continue;
            }
            if triangles[i].iter().any(|v| triangles[j].contains(v)) {
                continue;
            }
            if triangles_meet(triangles[i].map(|v| x[v]), triangles[j].map(|v| x[v])) {
                out.push((i.min(j), i.max(j)));
            }
        }
    }
    out.sort_unstable();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_check_sees_crossing_touching_and_coplanar_overlaps() {
        let t = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let v = DVec3::new;
        let piercing = [v(0.2, 0.2, -1.0), v(0.2, 0.2, 1.0), v(3.0, 3.0, 0.5)];
        assert!(triangles_meet(t, piercing));
        let above = [v(0.2, 0.2, 1e-12), v(0.3, 0.2, 1.0), v(0.2, 0.3, 1.0)];
        assert!(!triangles_meet(t, above));
        let touching = [v(0.2, 0.2, 0.0), v(0.3, 0.2, 1.0), v(0.2, 0.3, 1.0)];
        assert!(triangles_meet(t, touching));
        let coplanar = [v(0.5, 0.5, 0.0), v(-1.0, 0.2, 0.0), v(0.2, -1.0, 0.0)];
        assert!(triangles_meet(t, coplanar));
        let apart = [v(2.0, 2.0, 0.0), v(3.0, 2.0, 0.0), v(2.0, 3.0, 0.0)];
        assert!(!triangles_meet(t, apart));
        let interlocked = (
            [v(-1.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 2.0, 0.0)],
            [v(0.0, 1.0, -1.0), v(0.0, 1.0, 1.0), v(0.0, -1.0, 0.0)],
        );
        assert!(triangles_meet(interlocked.0, interlocked.1));
    }

    #[test]
    fn the_sweep_finds_what_every_pair_finds() {
        // Two strips of triangles, the second crossing the first through its middle.
        let v = DVec3::new;
        let mut x = Vec::new();
        let mut triangles = Vec::new();
        for k in 0..6 {
            let base = x.len();
            let s = k as f64;
            x.extend([v(s, 0.0, 0.0), v(s + 1.0, 0.0, 0.0), v(s, 1.0, 0.0)]);
            triangles.push([base, base + 1, base + 2]);
        }
        let base = x.len();
        x.extend([v(2.5, 0.3, -1.0), v(2.5, 0.3, 1.0), v(2.6, 0.2, 0.5)]);
        triangles.push([base, base + 1, base + 2]);
        let mut every = Vec::new();
        for i in 0..triangles.len() {
            for j in i + 1..triangles.len() {
                let shares = triangles[i].iter().any(|w| triangles[j].contains(w));
                if !shares && triangles_meet(triangles[i].map(|w| x[w]), triangles[j].map(|w| x[w]))
                {
                    every.push((i, j));
                }
            }
        }
        let found = intersecting_pairs(&x, &triangles);
        assert_eq!(found, every);
        // Triangle 2 spans x in [2, 3] at y = 0..1 and is pierced; neighbouring triangles
        // touch at shared x only through separate vertices, which count as meeting.
        assert!(found.contains(&(2, 6)), "{found:?}");
    }
}
