//! The exact triangle-triangle intersection check shared by the integration tests that
//! promise no crossing (self-contact dynamics, moving pins): written on top of Shewchuk's
//! orientation predicates (the `robust` crate), independent of the solver it checks.

// Each test binary includes this module and uses a part of it.
#![allow(dead_code)]

use robust::{Coord, Coord3D, orient2d, orient3d};
use sinew_math::DVec3;

pub fn c3(p: DVec3) -> Coord3D<f64> {
    Coord3D {
        x: p.x,
        y: p.y,
        z: p.z,
    }
}

pub fn o3(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> f64 {
    orient3d(c3(a), c3(b), c3(c), c3(d))
}

/// Exact coplanar tests after dropping the coordinate `axis` (the plane's normal is not
/// perpendicular to the remaining ones, so orientations are preserved up to one sign).
pub fn c2(p: DVec3, axis: usize) -> Coord<f64> {
    match axis {
        0 => Coord { x: p.y, y: p.z },
        1 => Coord { x: p.z, y: p.x },
        _ => Coord { x: p.x, y: p.y },
    }
}

pub fn o2(a: DVec3, b: DVec3, c: DVec3, axis: usize) -> f64 {
    orient2d(c2(a, axis), c2(b, axis), c2(c, axis))
}

/// Whether the closed segments `ab` and `cd`, all four points collinear or coplanar in
/// the projection, meet.
pub fn segments_meet_2d(a: DVec3, b: DVec3, c: DVec3, d: DVec3, axis: usize) -> bool {
    let (d1, d2) = (o2(c, d, a, axis), o2(c, d, b, axis));
    let (d3, d4) = (o2(a, b, c, axis), o2(a, b, d, axis));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return true;
    }
    // Touching or collinear overlap: a point on the other segment's line within its box.
    let on = |p: DVec3, q: DVec3, r: DVec3| {
        let (u, v) = (c2(p, axis), c2(q, axis));
        let w = c2(r, axis);
        w.x >= u.x.min(v.x) && w.x <= u.x.max(v.x) && w.y >= u.y.min(v.y) && w.y <= u.y.max(v.y)
    };
    (d1 == 0.0 && on(c, d, a))
        || (d2 == 0.0 && on(c, d, b))
        || (d3 == 0.0 && on(a, b, c))
        || (d4 == 0.0 && on(a, b, d))
}

/// Whether point `p` lies in the closed triangle `t` (all coplanar), projected.
pub fn point_in_triangle_2d(p: DVec3, t: [DVec3; 3], axis: usize) -> bool {
    let s = [
        o2(t[0], t[1], p, axis),
        o2(t[1], t[2], p, axis),
        o2(t[2], t[0], p, axis),
    ];
    s.iter().all(|&x| x >= 0.0) || s.iter().all(|&x| x <= 0.0)
}

/// Whether the closed segment `ab` meets the closed triangle `t`, exactly.
pub fn segment_meets_triangle(a: DVec3, b: DVec3, t: [DVec3; 3]) -> bool {
    let (oa, ob) = (o3(t[0], t[1], t[2], a), o3(t[0], t[1], t[2], b));
    if (oa > 0.0 && ob > 0.0) || (oa < 0.0 && ob < 0.0) {
        return false;
    }
    if oa == 0.0 && ob == 0.0 {
        // The segment lies in the triangle's plane: 2D tests on the plane's projection
        // along the normal's largest component.
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
    // The segment crosses (or touches) the plane at one point; it is in the closed
    // triangle exactly when the line ab passes every edge on the same side.
    let s = [
        o3(a, b, t[0], t[1]),
        o3(a, b, t[1], t[2]),
        o3(a, b, t[2], t[0]),
    ];
    s.iter().all(|&x| x >= 0.0) || s.iter().all(|&x| x <= 0.0)
}

/// Whether two closed triangles meet: their intersection, if any, has an endpoint on an
/// edge of one of them, which then meets the other triangle.
pub fn triangles_meet(p: [DVec3; 3], q: [DVec3; 3]) -> bool {
    (0..3).any(|k| segment_meets_triangle(p[k], p[(k + 1) % 3], q))
        || (0..3).any(|k| segment_meets_triangle(q[k], q[(k + 1) % 3], p))
}

/// The pairs of triangles sharing no vertex that meet at `x` (boxes compared first; the
/// box test is exact in floating point).
pub fn intersecting_pairs(x: &[DVec3], triangles: &[[usize; 3]]) -> Vec<(usize, usize)> {
    let boxes: Vec<(DVec3, DVec3)> = triangles
        .iter()
        .map(|t| {
            let p = t.map(|i| x[i]);
            (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]))
        })
        .collect();
    let mut out = Vec::new();
    for i in 0..triangles.len() {
        for j in i + 1..triangles.len() {
            if triangles[i].iter().any(|v| triangles[j].contains(v)) {
                continue;
            }
            let (a, b) = (boxes[i], boxes[j]);
            if a.0.cmpgt(b.1).any() || b.0.cmpgt(a.1).any() {
                continue;
            }
            if triangles_meet(triangles[i].map(|v| x[v]), triangles[j].map(|v| x[v])) {
                out.push((i, j));
            }
        }
    }
    out
}
