//! The best rotation for several weighted point pairs about a fixed centre, in closed
//! form (B. K. P. Horn, "Closed-form solution of absolute orientation using unit
//! quaternions", J. Opt. Soc. Am. A 4(4), 1987).
//!
//! Given pairs `(a_i, b_i)` (vectors from the centre) and weights `w_i >= 0`, the rotation
//! `R` minimising `sum w_i |R a_i - b_i|^2` maximises `sum w_i b_i . R a_i`, which for the
//! unit quaternion `q` of `R` is the quadratic form `q^T N q` of a symmetric 4 x 4 matrix
//! `N` built from `S = sum w_i a_i b_i^T`; the best `q` is the eigenvector of `N`'s
//! largest eigenvalue. The derivation, and why a small bias towards the identity picks the
//! smallest rotation where the answer is not unique, are in `docs/ik-body.md`.

use sinew_math::{DQuat, DVec3};

/// Accumulates weighted point pairs and returns their best rotation.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BestRotation {
    /// `S = sum w a b^T`, row-major.
    s: [[f64; 3]; 3],
    /// `sum w (|a|^2 + |b|^2) / 2`, the scale of the problem.
    scale: f64,
}

impl BestRotation {
    /// No pairs yet.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds the pair `a -> b` with weight `weight` (non-finite or negative weights and
    /// non-finite vectors are skipped).
    pub fn add(&mut self, a: DVec3, b: DVec3, weight: f64) {
        if !(weight.is_finite() && weight > 0.0 && a.is_finite() && b.is_finite()) {
            return;
        }
        let (a, b) = (a.to_array(), b.to_array());
        for (i, row) in self.s.iter_mut().enumerate() {
            for (j, s) in row.iter_mut().enumerate() {
                *s += weight * a[i] * b[j];
            }
        }
        self.scale += 0.5 * weight * (dot(&a, &a) + dot(&b, &b));
    }

    /// The rotation `R` minimising `sum w |R a - b|^2`, a unit quaternion with `w >= 0`.
    /// Without pairs (or when every pair is zero), the identity. Where the minimiser is not
    /// unique (one pair, or all pairs along one line), the one of smallest angle.
    #[must_use]
    pub fn rotation(&self) -> DQuat {
        if !(self.scale > 0.0 && self.scale.is_finite()) {
            return DQuat::IDENTITY;
        }
        let s = &self.s;
        let (sxx, sxy, sxz) = (s[0][0], s[0][1], s[0][2]);
        let (syx, syy, syz) = (s[1][0], s[1][1], s[1][2]);
        let (szx, szy, szz) = (s[2][0], s[2][1], s[2][2]);
        // Components in the order (w, x, y, z).
        let mut n = [
            [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
            [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
            [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
            [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
        ];
        // A bias towards the identity, far below the gap between the eigenvalues of any
        // well-posed problem: it only decides between rotations that fit equally well,
        // and there it picks the one with the largest w, the smallest angle.
        n[0][0] += 1e-9 * self.scale;
        let v = largest_eigenvector(n);
        let q = DQuat::from_xyzw(v[1], v[2], v[3], v[0]);
        let len = q.length();
        if !(len.is_finite() && len > 0.0) {
            return DQuat::IDENTITY;
        }
        let q = q / len;
        if q.w < 0.0 { -q } else { q }
    }
}

fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The unit eigenvector of the largest eigenvalue of a symmetric 4 x 4 matrix, by cyclic
/// Jacobi rotations (converges quadratically; a handful of sweeps reach rounding).
fn largest_eigenvector(mut a: [[f64; 4]; 4]) -> [f64; 4] {
    let mut v = [[0.0; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..16 {
        let off: f64 = (0..4)
            .flat_map(|p| (p + 1..4).map(move |q| (p, q)))
            .map(|(p, q)| a[p][q] * a[p][q])
            .sum();
        let diag: f64 = (0..4).map(|p| a[p][p] * a[p][p]).sum();
        if off <= 1e-32 * diag || off == 0.0 {
            break;
        }
        for p in 0..4 {
            for q in p + 1..4 {
                if a[p][q] == 0.0 {
                    continue;
                }
                // The rotation zeroing a[p][q] (Golub and Van Loan's symmetric Schur).
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + theta.hypot(1.0));
                let c = 1.0 / t.hypot(1.0);
                let s = t * c;
                for row in &mut a {
                    let (akp, akq) = (row[p], row[q]);
                    row[p] = c * akp - s * akq;
                    row[q] = s * akp + c * akq;
                }
                let (row_p, row_q) = (a[p], a[q]);
                for (k, (&apk, &aqk)) in row_p.iter().zip(&row_q).enumerate() {
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in &mut v {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let best = (0..4)
        .max_by(|&i, &j| a[i][i].total_cmp(&a[j][j]))
        .unwrap_or(0);
    [v[0][best], v[1][best], v[2][best], v[3][best]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use sinew_math::rotation_between;

    fn points() -> [DVec3; 5] {
        [
            DVec3::new(1.0, 0.2, -0.3),
            DVec3::new(-0.4, 0.9, 0.1),
            DVec3::new(0.3, -0.5, 1.2),
            DVec3::new(0.0, 0.0, 0.7),
            DVec3::new(-1.0, -1.0, 0.5),
        ]
    }

    #[test]
    fn recovers_an_exact_rotation() {
        for (axis, angle) in [
            (DVec3::new(1.0, 2.0, 3.0), 0.7),
            (DVec3::Z, 3.0),
            (DVec3::new(-1.0, 0.5, 0.2), 1e-7),
            (DVec3::Y, std::f64::consts::PI - 1e-9),
        ] {
            let r = DQuat::from_axis_angle(axis.normalize(), angle);
            let mut best = BestRotation::new();
            for (i, a) in points().into_iter().enumerate() {
                best.add(a, r * a, 1.0 + i as f64);
            }
            let q = best.rotation();
            assert!(
                q.angle_between(r) < 1e-8,
                "{axis} {angle}: {}",
                q.angle_between(r)
            );
        }
    }

    #[test]
    fn beats_every_nearby_rotation_on_noisy_pairs() {
        let r = DQuat::from_axis_angle(DVec3::new(0.3, -1.0, 0.4).normalize(), 1.1);
        let mut best = BestRotation::new();
        let noise = [
            DVec3::new(0.1, 0.0, -0.05),
            DVec3::new(-0.02, 0.08, 0.0),
            DVec3::new(0.0, -0.1, 0.1),
            DVec3::new(0.05, 0.05, 0.05),
            DVec3::new(-0.1, 0.02, 0.0),
        ];
        let pairs: Vec<(DVec3, DVec3, f64)> = points()
            .into_iter()
            .zip(noise)
            .enumerate()
            .map(|(i, (a, n))| (a, r * a + n, 0.5 + i as f64))
            .collect();
        for &(a, b, w) in &pairs {
            best.add(a, b, w);
        }
        let q = best.rotation();
        let cost = |q: DQuat| -> f64 {
            pairs
                .iter()
                .map(|&(a, b, w)| w * (q * a - b).length_squared())
                .sum()
        };
        let c0 = cost(q);
        for axis in [
            DVec3::X,
            DVec3::Y,
            DVec3::Z,
            DVec3::new(1.0, 1.0, -1.0).normalize(),
        ] {
            for h in [1e-3, -1e-3, 1e-5, -1e-5] {
                let turned = DQuat::from_axis_angle(axis, h) * q;
                assert!(cost(turned) >= c0 - 1e-12 * c0, "{axis} {h}");
            }
        }
    }

    #[test]
    fn one_pair_gives_the_smallest_rotation() {
        let (a, b) = (DVec3::new(1.0, 0.0, 0.0), DVec3::new(0.3, 0.8, -0.2));
        let mut best = BestRotation::new();
        best.add(a, b, 2.0);
        let q = best.rotation();
        let minimal = rotation_between(a, b);
        assert!(
            q.angle_between(minimal) < 1e-6,
            "{}",
            q.angle_between(minimal)
        );
        // Two pairs on one line through the centre: the same answer.
        best.add(a * 3.0, b * 3.0, 1.0);
        assert!(best.rotation().angle_between(minimal) < 1e-6);
    }

    #[test]
    fn no_pairs_or_bad_pairs_give_the_identity() {
        assert_eq!(BestRotation::new().rotation(), DQuat::IDENTITY);
        let mut best = BestRotation::new();
        best.add(DVec3::ZERO, DVec3::X, 1.0);
        best.add(DVec3::X, DVec3::new(f64::NAN, 0.0, 0.0), 1.0);
        best.add(DVec3::X, DVec3::Y, f64::INFINITY);
        best.add(DVec3::X, DVec3::Y, -1.0);
        assert_eq!(best.rotation(), DQuat::IDENTITY);
    }
}
