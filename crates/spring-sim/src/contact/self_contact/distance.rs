//! Squared distances between the primitives of a triangle mesh, point-triangle and
//! edge-edge, with the region of the closest points chosen robustly, their exact gradient
//! and Hessian in the twelve coordinates of the pair, and IPC's mollifier for nearly
//! parallel edges.
//!
//! A pair is four vertices: `[p, t0, t1, t2]` for a point and a triangle, `[a0, a1, b0,
//! b1]` for two edges. Once the region of the closest points is known (a [`Closest`]),
//! the squared distance is one of four closed forms in the vertices involved:
//!
//! - point-point `|x_i - x_j|^2`;
//! - point-line `|(a - p) x (b - p)|^2 / |b - a|^2`;
//! - point-plane `((p - a) . n)^2 / |n|^2`, `n = (b - a) x (c - a)`;
//! - line-line `((a0 - b0) . n)^2 / |n|^2`, `n = (a1 - a0) x (b1 - b0)`.
//!
//! Each is a rational function of the coordinates, written once over [`Scalar`], so the
//! same code gives the value in `f64` and the exact gradient and Hessian in [`Dual12`].
//! The squared distance is continuous across regions and so is its gradient (at a region
//! boundary two forms agree to first order), which is what the barrier and the line
//! search need. Derivations and the region rules: docs/contact.md.

use super::dual::{Dual12, Gradient12, Scalar, Vec3, gradient_variables, values, variables};
use sinew_math::DVec3;

/// The region of the closest points of a pair: which closed form, on which of the pair's
/// four vertices (indices into the pair).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Closest {
    /// Two vertices are closest.
    PointPoint([usize; 2]),
    /// A vertex and the interior of an edge `[point, edge0, edge1]`.
    PointEdge([usize; 3]),
    /// A vertex and the interior of a triangle `[point, t0, t1, t2]`.
    PointPlane([usize; 4]),
    /// The interiors of two edges `[a0, a1, b0, b1]`.
    LineLine([usize; 4]),
}

/// Two edges are treated as parallel when `|e_a x e_b|^2 <= PARALLEL |e_a|^2 |e_b|^2`
/// (the sine of their angle below 1e-7). The line-line form divides by `|e_a x e_b|^2`,
/// so its closest-point parameters carry a round-off error of about `eps / sin^2` and the
/// distance one of about `eps L / sin` (`L` the edges' length); taking the nearest
/// endpoint form instead errs by at most `L sin`, the distance's variation along the
/// edges. The threshold keeps both below `1e-7 L`.
pub const PARALLEL: f64 = 1e-14;

/// Point `p` against the segment `a b`: the closest-point parameter `t` clamped to
/// `[0, 1]` and the squared distance.
fn point_segment(p: DVec3, a: DVec3, b: DVec3) -> (f64, f64) {
    let e = b - a;
    let len2 = e.length_squared();
    let t = if len2 > 0.0 {
        ((p - a).dot(e) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (t, (a + t * e - p).length_squared())
}

/// The point-segment region for pair vertices `[point, e0, e1]`, and its squared distance.
fn point_segment_region(v: &[DVec3; 4], point: usize, e0: usize, e1: usize) -> (Closest, f64) {
    let (t, d2) = point_segment(v[point], v[e0], v[e1]);
    let closest = if t <= 0.0 {
        Closest::PointPoint([point, e0])
    } else if t >= 1.0 {
        Closest::PointPoint([point, e1])
    } else {
        Closest::PointEdge([point, e0, e1])
    };
    (closest, d2)
}

/// The region of the closest points of point `v[0]` and triangle `v[1] v[2] v[3]`.
///
/// The point's projection is inside the triangle when it is on the inner side of each
/// edge's plane through the normal, tested by the sign of `((v_{k+1} - v_k) x (p - v_k))
/// . n`: then the face is closest. Otherwise the closest point is on the boundary, and
/// the nearest of the three point-segment distances decides the edge or vertex (taking
/// the minimum of all three needs no case analysis of the outer regions and is exact).
#[must_use]
pub fn point_triangle_closest(v: &[DVec3; 4]) -> Closest {
    let p = v[0];
    let n = (v[2] - v[1]).cross(v[3] - v[1]);
    let inside = (0..3).all(|k| {
        let (a, b) = (v[1 + k], v[1 + (k + 1) % 3]);
        (b - a).cross(p - a).dot(n) >= 0.0
    });
    if inside && n.length_squared() > 0.0 {
        return Closest::PointPlane([0, 1, 2, 3]);
    }
    let mut best = point_segment_region(v, 0, 1, 2);
    for (e0, e1) in [(2, 3), (3, 1)] {
        let candidate = point_segment_region(v, 0, e0, e1);
        if candidate.1 < best.1 {
            best = candidate;
        }
    }
    best.0
}

/// The region of the closest points of edges `v[0] v[1]` and `v[2] v[3]`.
///
/// The squared distance `|a0 + s e_a - b0 - t e_b|^2` is convex in `(s, t)`. When the
/// edges are not parallel (see [`PARALLEL`]) and its unconstrained minimizer lies inside
/// `(0, 1)^2`, the interiors are closest. Otherwise the minimum over the square is on its
/// boundary, where one parameter is 0 or 1: the nearest of the four endpoint-segment
/// distances decides it.
#[must_use]
pub fn edge_edge_closest(v: &[DVec3; 4]) -> Closest {
    let (ea, eb, r) = (v[1] - v[0], v[3] - v[2], v[0] - v[2]);
    let (a, b, c) = (ea.dot(ea), ea.dot(eb), eb.dot(eb));
    let (d, e) = (ea.dot(r), eb.dot(r));
    let det = a * c - b * b;
    if det > PARALLEL * a * c {
        let s = (b * e - c * d) / det;
        let t = (a * e - b * d) / det;
        if s > 0.0 && s < 1.0 && t > 0.0 && t < 1.0 {
            return Closest::LineLine([0, 1, 2, 3]);
        }
    }
    let mut best = point_segment_region(v, 0, 2, 3);
    for (point, e0, e1) in [(1, 2, 3), (2, 0, 1), (3, 0, 1)] {
        let candidate = point_segment_region(v, point, e0, e1);
        if candidate.1 < best.1 {
            best = candidate;
        }
    }
    best.0
}

/// The squared distance in region `closest` of the pair `v`, over any [`Scalar`].
#[must_use]
pub fn squared_distance_in<S: Scalar>(v: &[Vec3<S>; 4], closest: Closest) -> S {
    match closest {
        Closest::PointPoint([i, j]) => v[i].sub(&v[j]).length_squared(),
        Closest::PointEdge([p, a, b]) => {
            let (pa, pb) = (v[a].sub(&v[p]), v[b].sub(&v[p]));
            pa.cross(&pb)
                .length_squared()
                .div(v[b].sub(&v[a]).length_squared())
        }
        Closest::PointPlane([p, a, b, c]) => {
            let n = v[b].sub(&v[a]).cross(&v[c].sub(&v[a]));
            let h = v[p].sub(&v[a]).dot(&n);
            (h * h).div(n.length_squared())
        }
        Closest::LineLine([a0, a1, b0, b1]) => {
            let n = v[a1].sub(&v[a0]).cross(&v[b1].sub(&v[b0]));
            let h = v[a0].sub(&v[b0]).dot(&n);
            (h * h).div(n.length_squared())
        }
    }
}

/// The kind of a pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PairKind {
    /// `[p, t0, t1, t2]`.
    PointTriangle,
    /// `[a0, a1, b0, b1]`.
    EdgeEdge,
}

impl PairKind {
    /// The region of the closest points of `v`.
    #[must_use]
    pub fn closest(self, v: &[DVec3; 4]) -> Closest {
        match self {
            Self::PointTriangle => point_triangle_closest(v),
            Self::EdgeEdge => edge_edge_closest(v),
        }
    }
}

/// A lower bound of the pair's distance, at a few dot products instead of the region
/// choice and a closed form: the gap between the primitives' vertex sets (the point and
/// the triangle's vertices, or the two edges' ends) projected on the line through their
/// centroids. Each primitive lies in the hull of its vertices and a projection never
/// lengthens a segment, so no two points of the primitives are closer than that gap. The
/// line separates the neighbouring primitives of a sheet that share no vertex, which the
/// broad phase's boxes cannot (a right triangle's box holds the corner it lacks). 0 when
/// the sets' projections overlap, NaN when a coordinate is not finite.
#[must_use]
pub fn separation(kind: PairKind, v: &[DVec3; 4]) -> f64 {
    // Positions from the first vertex, so the projections keep their digits far from the
    // origin; the axis is not normalised until the end (one square root, one division).
    let r = [v[1] - v[0], v[2] - v[0], v[3] - v[0]];
    let gap = match kind {
        PairKind::PointTriangle => {
            // The point is the origin; the axis runs to the triangle's centroid.
            let d = r[0] + r[1] + r[2];
            let low = r[0].dot(d).min(r[1].dot(d)).min(r[2].dot(d));
            low / d.length()
        }
        PairKind::EdgeEdge => {
            // The axis runs from the first edge's midpoint to the second's (twice).
            let d = r[1] + r[2] - r[0];
            let high = r[0].dot(d).max(0.0);
            let low = r[1].dot(d).min(r[2].dot(d));
            (low - high) / d.length()
        }
    };
    if !(v[0] + v[1] + v[2] + v[3]).is_finite() {
        return f64::NAN;
    }
    // Coincident centroids (0 / 0, NaN) say nothing.
    if gap > 0.0 { gap } else { 0.0 }
}

/// The relative margin by which a pair's [`separation`] must pass a reach before
/// [`beyond`] takes the pair to be beyond it without its exact distance. The closed forms
/// err by far less (and so does the separation): a relative round-off of order `1e-16 L / d` (`L` an edge's length,
/// `d` the distance), and for the line-line form of edges near the [`PARALLEL`] limit
/// about `eps L / sin`, at most `2.2e-9 L`, below `1e-4 d` while `L < 4e4 d`. So a pair
/// taken to be beyond is also beyond by its exact distance, and skipping that distance
/// changes no answer (docs/self-contact.md).
pub const SEPARATION_MARGIN: f64 = 1e-4;

/// Whether the pair's distance is certainly at least `reach`, read from its
/// [`separation`] (at least `(1 + SEPARATION_MARGIN) reach`): the exact distance is then
/// not needed to know it. False for a non-finite coordinate.
#[must_use]
pub fn beyond(kind: PairKind, v: &[DVec3; 4], reach: f64) -> bool {
    separation(kind, v) >= reach * (1.0 + SEPARATION_MARGIN)
}

/// The squared distance of the pair `v` of kind `kind`.
#[must_use]
pub fn squared_distance(kind: PairKind, v: &[DVec3; 4]) -> f64 {
    squared_distance_in(&values(v), kind.closest(v))
}

/// The squared distance of the pair `v` with its exact gradient and Hessian in the
/// twelve coordinates (vertex `k`'s coordinates at `3k..3k + 3`).
#[must_use]
pub fn squared_distance_derivatives(kind: PairKind, v: &[DVec3; 4]) -> Dual12 {
    squared_distance_in(&variables(v), kind.closest(v))
}

/// The mollifier of an edge pair over any [`Scalar`]: with `c = |e_a x e_b|^2` and
/// `x = c / eps_x`, `m = (2 - x) x` for `c < eps_x` and 1 beyond. It is 0 for parallel
/// edges and rises to 1 with a zero slope at `eps_x`, so `m b(d)` is continuously
/// differentiable where the edge-edge distance jumps regions as the edges turn parallel
/// (there the point-triangle pairs carry the contact).
#[must_use]
pub fn mollifier_in<S: Scalar>(v: &[Vec3<S>; 4], eps_x: f64) -> S {
    let c = v[1].sub(&v[0]).cross(&v[3].sub(&v[2])).length_squared();
    if c.value() >= eps_x {
        return S::from_f64(1.0);
    }
    let x = c * S::from_f64(1.0 / eps_x);
    (S::from_f64(2.0) - x) * x
}

/// The mollifier of the edge pair `v` (see [`mollifier_in`]).
#[must_use]
pub fn mollifier(v: &[DVec3; 4], eps_x: f64) -> f64 {
    mollifier_in(&values(v), eps_x)
}

/// The mollifier of the edge pair `v` with its exact gradient and Hessian.
#[must_use]
pub fn mollifier_derivatives(v: &[DVec3; 4], eps_x: f64) -> Dual12 {
    mollifier_in(&variables(v), eps_x)
}

/// The squared distance of the pair `v` with its exact gradient alone: the value and
/// gradient of [`squared_distance_derivatives`], bit for bit.
#[must_use]
pub fn squared_distance_gradient(kind: PairKind, v: &[DVec3; 4]) -> Gradient12 {
    squared_distance_in(&gradient_variables(v), kind.closest(v))
}

/// The mollifier of the edge pair `v` with its exact gradient alone: the value and
/// gradient of [`mollifier_derivatives`], bit for bit.
#[must_use]
pub fn mollifier_gradient(v: &[DVec3; 4], eps_x: f64) -> Gradient12 {
    mollifier_in(&gradient_variables(v), eps_x)
}
