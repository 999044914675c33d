//! Lagged, smoothed Coulomb friction between the cloth's own primitives, as in IPC.
//!
//! At the start of a step every vertex-triangle and edge-edge pair within `dhat` is
//! lagged: the weights `w` of its closest points (a point and its projection on the
//! triangle, or the two edges' closest points; [`RegionForm`]'s `c` in the region the
//! barrier found), so that `z(x) = sum_k w_k x_k` is the vector between the two closest
//! points, its unit normal `n = z / |z|`, a tangent basis `T` across it, and the normal
//! force the barrier exerts there, `lambda = -kappa m b'(d - xi)` (`m` the edge pair's
//! mollifier, 1 for a vertex-triangle pair). Through the step the pair's friction energy is the collider
//! friction's ([`crate::contact::friction`]) on the relative displacement of the two
//! closest points,
//!
//! ```text
//! u(x) = T^T (z(x) - z(x_ref)),    D(x) = mu lambda f0(|u|),
//! ```
//!
//! whose gradient on vertex `k` is `w_k grad D(z)` and whose Hessian block `(k, l)` is
//! `w_k w_l H(z)`, `H` the collider friction's 3x3 Hessian: the pair's 12x12 Hessian is
//! `w w^T (x) H`, the Kronecker product of two positive semidefinite matrices, so it is
//! positive semidefinite as written (no projection). The weights sum to zero (each side's
//! weights sum to one), so a rigid translation of the pair moves nothing: only the two
//! primitives' motion relative to each other is resisted. Derivations: docs/contact.md.

use super::closed::RegionForm;
use super::distance::{Closest, PairKind};
use crate::contact::friction::FrictionContact;
use sinew_math::{DMat3, DVec3};

/// One lagged friction pair: its particles, the weights of its closest points and the
/// friction of the relative displacement `z(x) = sum_k w_k x_k` (see the module
/// documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrictionPair {
    /// Vertex-triangle or edge-edge.
    pub kind: PairKind,
    /// The pair's four particles (`[p, t0, t1, t2]` or `[a0, a1, b0, b1]`).
    pub particles: [usize; 4],
    /// The closest points' weights, one per particle.
    pub weights: [f64; 4],
    /// The friction of `z`, lagged at the step's start, with `z` at the step's reference
    /// point as its start and no surface displacement.
    pub contact: FrictionContact,
}

impl FrictionPair {
    /// The pair of `kind` on `particles` whose closest points at the lag point `x_lag`
    /// (the step's start, or where a round of the step ended when friction is lagged
    /// again) lie in region `closest`, with the largest friction force `max_force` (`mu lambda`,
    /// `lambda` the barrier's normal force there) and the smoothing displacement
    /// `epsilon` (`eps_v h`), its displacement measured from `x_ref`: `None` when the
    /// weights or the normal are not finite (a degenerate edge or triangle), or there is
    /// no force.
    ///
    /// # Panics
    /// If a particle is out of the range of `x_lag` or `x_ref` (the term passes its own
    /// pairs and the step's states).
    #[must_use]
    pub fn lagged(
        kind: PairKind,
        particles: [usize; 4],
        closest: Closest,
        x_lag: &[DVec3],
        x_ref: &[DVec3],
        max_force: f64,
        epsilon: f64,
    ) -> Option<Self> {
        // The form's `r` is computed along the normal in the point-plane and line-line
        // regions, so the normal does not carry the in-plane parameters' round-off.
        let form = RegionForm::new(&particles.map(|i| x_lag[i]), closest);
        let weights = form.c;
        let normal = form.r.normalize_or_zero();
        if weights.iter().any(|w| !w.is_finite())
            || normal == DVec3::ZERO
            || !(max_force.is_finite() && max_force > 0.0)
        {
            return None;
        }
        let (t1, t2) = normal.any_orthonormal_pair();
        let start = weighted(&weights, &particles.map(|i| x_ref[i]));
        Some(Self {
            kind,
            particles,
            weights,
            contact: FrictionContact {
                max_force,
                normal,
                basis: [t1, t2],
                start,
                surface_displacement: DVec3::ZERO,
                epsilon,
            },
        })
    }

    /// `z = sum_k w_k v_k` of per-particle vectors `v` (positions or directions).
    ///
    /// # Panics
    /// If a particle is out of the range of `v`.
    #[must_use]
    pub fn relative(&self, v: &[DVec3]) -> DVec3 {
        weighted(&self.weights, &self.particles.map(|i| v[i]))
    }

    /// The pair's friction energy at `x`.
    #[must_use]
    pub fn energy(&self, x: &[DVec3]) -> f64 {
        self.contact.energy(self.relative(x))
    }

    /// `D(x + alpha dx) - D(x)`, from the difference itself.
    #[must_use]
    pub fn energy_change(&self, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        self.contact
            .energy_change(self.relative(x), alpha * self.relative(dx))
    }

    /// The gradient of `D` with respect to `z` at `x`; the gradient on particle `k` is
    /// `weights[k]` times it.
    #[must_use]
    pub fn gradient(&self, x: &[DVec3]) -> DVec3 {
        self.contact.gradient(self.relative(x))
    }

    /// The Hessian of `D` with respect to `z` at `x` (positive semidefinite); the block
    /// of particles `k` and `l` is `weights[k] weights[l]` times it.
    #[must_use]
    pub fn hessian(&self, x: &[DVec3]) -> DMat3 {
        self.contact.hessian(self.relative(x))
    }
}

/// `sum_k w_k v_k`.
fn weighted(w: &[f64; 4], v: &[DVec3; 4]) -> DVec3 {
    w[0] * v[0] + w[1] * v[1] + w[2] * v[2] + w[3] * v[3]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contact::self_contact::distance::squared_distance;

    fn pair_closest(kind: PairKind, p: &[DVec3; 4]) -> Closest {
        kind.closest(p)
    }

    #[test]
    fn a_lagged_pairs_weights_give_the_vector_between_the_closest_points_in_every_region() {
        let v = DVec3::new;
        // Each case: a pair, and the region its closest points must lie in.
        let cases: [(PairKind, [DVec3; 4]); 6] = [
            // A point over the triangle's inside.
            (
                PairKind::PointTriangle,
                [
                    v(0.2, 0.3, 0.5),
                    v(0.0, 0.0, 0.0),
                    v(1.0, 0.0, 0.0),
                    v(0.0, 1.0, 0.0),
                ],
            ),
            // A point beside an edge.
            (
                PairKind::PointTriangle,
                [
                    v(0.5, -0.3, 0.2),
                    v(0.0, 0.0, 0.0),
                    v(1.0, 0.0, 0.0),
                    v(0.0, 1.0, 0.0),
                ],
            ),
            // A point beyond a vertex.
            (
                PairKind::PointTriangle,
                [
                    v(-0.3, -0.4, 0.1),
                    v(0.0, 0.0, 0.0),
                    v(1.0, 0.0, 0.0),
                    v(0.0, 1.0, 0.0),
                ],
            ),
            // Two crossing edges, closest inside both.
            (
                PairKind::EdgeEdge,
                [
                    v(0.0, 0.0, 0.0),
                    v(1.0, 0.0, 0.0),
                    v(0.3, -0.5, 0.2),
                    v(0.4, 0.5, 0.25),
                ],
            ),
            // An edge's end against the other's inside.
            (
                PairKind::EdgeEdge,
                [
                    v(0.0, 0.0, 0.0),
                    v(1.0, 0.0, 0.0),
                    v(1.3, -0.5, 0.2),
                    v(1.3, 0.5, 0.2),
                ],
            ),
            // Ends against ends.
            (
                PairKind::EdgeEdge,
                [
                    v(0.0, 0.0, 0.0),
                    v(1.0, 0.0, 0.0),
                    v(1.2, 0.3, 0.1),
                    v(2.0, 1.0, 0.0),
                ],
            ),
        ];
        let mut regions = Vec::new();
        for (kind, p) in cases {
            let closest = pair_closest(kind, &p);
            regions.push(std::mem::discriminant(&closest));
            let pair =
                FrictionPair::lagged(kind, [0, 1, 2, 3], closest, &p, &p, 1.0, 1e-5).unwrap();
            let (w, z) = (pair.weights, pair.relative(&p));
            assert!(
                (pair.contact.normal - z.normalize()).length() <= 1e-14,
                "{closest:?}"
            );
            // Its length is the pair's distance, and each side's weights sum to one.
            let d = squared_distance(kind, &p).sqrt();
            assert!(
                (z.length() - d).abs() <= 1e-15,
                "{closest:?}: {} {d}",
                z.length()
            );
            assert!(w.iter().sum::<f64>().abs() <= 1e-15, "{w:?}");
            let sides = match kind {
                PairKind::PointTriangle => [w[0], w[1] + w[2] + w[3]],
                PairKind::EdgeEdge => [w[0] + w[1], w[2] + w[3]],
            };
            assert!((sides[0].abs() - 1.0).abs() <= 1e-15, "{w:?}");
            // The vector between the closest points is across the primitives where they
            // are flat: normal to the triangle, or to both edges.
            match closest {
                Closest::PointPlane(_) => {
                    let n = (p[2] - p[1]).cross(p[3] - p[1]);
                    assert!(z.cross(n).length() <= 1e-15 * n.length(), "{z} {n}");
                }
                Closest::LineLine(_) => {
                    assert!(z.dot(p[1] - p[0]).abs() <= 1e-15);
                    assert!(z.dot(p[3] - p[2]).abs() <= 1e-15);
                }
                _ => {}
            }
        }
        // Every region was met.
        regions.sort_by_key(|r| format!("{r:?}"));
        regions.dedup();
        assert_eq!(regions.len(), 4, "{regions:?}");
    }

    /// A lagged pair 0.4 mm apart, the point moved a little since: energy, gradient and
    /// Hessian against central differences, in both of the mollifier's regimes.
    #[test]
    fn a_pairs_friction_derivatives_match_finite_differences() {
        let v = DVec3::new;
        let x_n = vec![
            v(0.2, 0.3, 4e-4),
            v(0.0, 0.0, 0.0),
            v(1.0, 0.0, 0.0),
            v(0.0, 1.0, 0.0),
        ];
        let particles = [0, 1, 2, 3];
        let closest = pair_closest(PairKind::PointTriangle, &[x_n[0], x_n[1], x_n[2], x_n[3]]);
        let epsilon = 1e-3 / 60.0;
        let pair = FrictionPair::lagged(
            PairKind::PointTriangle,
            particles,
            closest,
            &x_n,
            &x_n,
            1.0,
            epsilon,
        )
        .unwrap();
        assert_eq!(pair.contact.max_force, 1.0);
        assert!((pair.contact.normal - DVec3::Z).length() <= 1e-15);
        // Relative slides below and above the smoothing displacement.
        for slide in [0.3 * epsilon, 5.0 * epsilon] {
            let mut x = x_n.clone();
            x[0] += v(slide, 0.4 * slide, 1e-5);
            x[2] += v(-0.2 * slide, 0.1 * slide, 0.0);
            let e = 1e-3 * epsilon;
            for i in 0..4 {
                for c in 0..3 {
                    let mut plus = x.clone();
                    let mut minus = x.clone();
                    plus[i][c] += e;
                    minus[i][c] -= e;
                    let fd = (pair.energy(&plus) - pair.energy(&minus)) / (2.0 * e);
                    let g = pair.weights[i] * pair.gradient(&x);
                    assert!(
                        (fd - g[c]).abs() <= 1e-6 * pair.contact.max_force,
                        "slide {slide}, particle {i}, axis {c}: {fd} vs {}",
                        g[c]
                    );
                    // The Hessian's column (i, c): differences of the gradient.
                    for j in 0..4 {
                        let fd = (pair.weights[j] * (pair.gradient(&plus) - pair.gradient(&minus)))
                            / (2.0 * e);
                        let h = pair.weights[j] * pair.weights[i] * pair.hessian(&x).col(c);
                        assert!(
                            (fd - h).length() <= 1e-5 * pair.contact.max_force / epsilon,
                            "slide {slide}, block ({j}, {i}), column {c}: {fd} vs {h}"
                        );
                    }
                }
            }
            // The change along a direction from the difference itself.
            let dx: Vec<DVec3> = (0..4).map(|k| v(1e-7 * k as f64, 2e-7, -1e-7)).collect();
            let moved: Vec<DVec3> = x.iter().zip(&dx).map(|(a, b)| *a + 0.5 * *b).collect();
            let direct = pair.energy(&moved) - pair.energy(&x);
            let change = pair.energy_change(&x, &dx, 0.5);
            assert!(
                (change - direct).abs() <= 1e-9 * direct.abs().max(1e-12),
                "{change} vs {direct}"
            );
        }
        // A rigid translation of the whole pair costs nothing.
        let moved: Vec<DVec3> = x_n.iter().map(|p| *p + v(0.3, -0.1, 0.2)).collect();
        assert!((pair.energy(&moved) - pair.energy(&x_n)).abs() <= 1e-18);
    }
}
