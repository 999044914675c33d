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
        let v = largest_eigenvector(self.matrix());
        let q = DQuat::from_xyzw(v[1], v[2], v[3], v[0]);
        let len = q.length();
        if !(len.is_finite() && len > 0.0) {
            return DQuat::IDENTITY;
        }
        let q = q / len;
        if q.w < 0.0 { -q } else { q }
    }
}

impl BestRotation {
    /// Horn's matrix `N` of the pairs (components in the order `w, x, y, z`), with the
    /// bias towards the identity.
    fn matrix(&self) -> [[f64; 4]; 4] {
        let s = &self.s;
        let (sxx, sxy, sxz) = (s[0][0], s[0][1], s[0][2]);
        let (syx, syy, syz) = (s[1][0], s[1][1], s[1][2]);
        let (szx, szy, szz) = (s[2][0], s[2][1], s[2][2]);
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
        n
    }
}

fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The unit eigenvector of the largest eigenvalue of a symmetric 4 x 4 matrix: in closed
/// form where that eigenvalue is well separated from the others
/// ([`separated_eigenvector`]), else by Jacobi rotations ([`jacobi_eigenvector`]).
fn largest_eigenvector(a: [[f64; 4]; 4]) -> [f64; 4] {
    separated_eigenvector(&a).unwrap_or_else(|| jacobi_eigenvector(a))
}

/// The indices other than the one left out, in order.
const OTHERS: [[usize; 3]; 4] = [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]];

/// The determinant of `m` without row `row` and column `col`.
fn minor(m: &[[f64; 4]; 4], row: usize, col: usize) -> f64 {
    let (r, c) = (OTHERS[row], OTHERS[col]);
    let e = |i: usize, j: usize| m[r[i]][c[j]];
    e(0, 0) * (e(1, 1) * e(2, 2) - e(1, 2) * e(2, 1))
        - e(0, 1) * (e(1, 0) * e(2, 2) - e(1, 2) * e(2, 0))
        + e(0, 2) * (e(1, 0) * e(2, 1) - e(1, 1) * e(2, 0))
}

/// How large the adjugate's largest diagonal entry must be, against the cube of the
/// matrix's scale (Gershgorin's bound on its eigenvalues), for [`separated_eigenvector`]
/// to answer (see there).
const SEPARATED: f64 = 1e-3;

/// The unit eigenvector of the largest eigenvalue `l` of a symmetric 4 x 4 matrix `A`,
/// from its characteristic polynomial `p(x) = det(x I - A)`: `l` by Newton's iteration
/// from Gershgorin's upper bound (above the largest root every derivative of a
/// polynomial with real roots is positive, so the iterates fall monotonically onto it,
/// and the iteration stops where rounding stops them falling), then the eigenvector as
/// a column of the adjugate of `A - l I`, which is `prod_k (l_k - l) v v^T` over the
/// other eigenvalues `l_k` when `l` is simple: the column of its largest diagonal entry
/// (where `v_i^2 >= 1/4`). `None` when that entry is under [`SEPARATED`] times the scale
/// cubed, that is when `l` is not clearly apart from another eigenvalue (one pair of
/// points, or all on a line): there the adjugate's rounding (and that of `l`, which it
/// magnifies by the inverse of the gaps) would spoil the answer, and Jacobi's
/// rotations, which do not mind, find it. Above the threshold the error of the direction
/// is at most about `eps / SEPARATED^2` (the rounding of `l` is `eps` times the scale
/// to the fourth over the gaps' product, and the adjugate turns an error of `l` into one
/// of the direction by a gap squared over that product again); on random well-posed fits
/// it agrees with Jacobi's to 2e-14 (tested). Also `None` for a non-finite matrix.
fn separated_eigenvector(a: &[[f64; 4]; 4]) -> Option<[f64; 4]> {
    // Gershgorin's discs: every eigenvalue is at most `upper`, and at most `scale` in
    // size. The matrix is divided by `scale` first (the eigenvectors are the same), so
    // that the minors below neither overflow nor underflow and the threshold is absolute.
    let gershgorin = |a: &[[f64; 4]; 4]| {
        let (mut upper, mut scale) = (f64::NEG_INFINITY, 0.0_f64);
        for (i, row) in a.iter().enumerate() {
            let off: f64 = row
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, x)| x.abs())
                .sum();
            upper = upper.max(row[i] + off);
            scale = scale.max(row[i].abs() + off);
        }
        (upper, scale)
    };
    let (_, scale) = gershgorin(a);
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    let a = &a.map(|row| row.map(|x| x / scale));
    let (upper, _) = gershgorin(a);
    // p(x) = x^4 + c3 x^3 + c2 x^2 + c1 x + c0: the sums of the principal minors.
    let c3 = -(a[0][0] + a[1][1] + a[2][2] + a[3][3]);
    let mut c2 = 0.0;
    for i in 0..4 {
        for j in i + 1..4 {
            c2 += a[i][i] * a[j][j] - a[i][j] * a[j][i];
        }
    }
    let c1 = -(0..4).map(|i| minor(a, i, i)).sum::<f64>();
    let c0 = (0..4)
        .map(|k| {
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            sign * a[0][k] * minor(a, 0, k)
        })
        .sum::<f64>();
    let mut l = upper;
    for _ in 0..100 {
        let p = (((l + c3) * l + c2) * l + c1) * l + c0;
        let dp = ((4.0 * l + 3.0 * c3) * l + 2.0 * c2) * l + c1;
        let next = l - p / dp;
        // (NaN, or no longer falling: rounding has the root.)
        match next.partial_cmp(&l) {
            Some(std::cmp::Ordering::Less) => l = next,
            _ => break,
        }
    }
    let mut m = *a;
    for (i, row) in m.iter_mut().enumerate() {
        row[i] -= l;
    }
    let (best, largest) =
        (0..4)
            .map(|i| (i, minor(&m, i, i)))
            .fold((0, 0.0_f64), |(bi, bv), (i, v)| {
                if v.abs() > bv.abs() { (i, v) } else { (bi, bv) }
            });
    if largest.is_nan() || largest.abs() < SEPARATED {
        return None;
    }
    let mut v = [0.0; 4];
    for (k, x) in v.iter_mut().enumerate() {
        let sign = if (best + k) % 2 == 0 { 1.0 } else { -1.0 };
        *x = sign * minor(&m, best, k);
    }
    let length = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    if !(length.is_finite() && length > 0.0) {
        return None;
    }
    Some(v.map(|x| x / length))
}

/// The unit eigenvector of the largest eigenvalue of a symmetric 4 x 4 matrix, by cyclic
/// Jacobi rotations (converges quadratically; a handful of sweeps reach rounding).
fn jacobi_eigenvector(mut a: [[f64; 4]; 4]) -> [f64; 4] {
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

    /// The closed form against Jacobi's rotations on the same matrices: on well-posed
    /// fits (three to six noisy pairs, random weights, any rotation) it answers nearly
    /// always and agrees to a few ulps; where the largest eigenvalue is not apart from
    /// the next (one pair, pairs on one line through the centre) it declines, and the
    /// rotation is Jacobi's.
    #[test]
    fn the_closed_form_agrees_with_jacobi_and_declines_where_it_would_not() {
        let mut seed = 0x0123_4567_89AB_CDEF_u64;
        let mut uniform = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let vector = |scale: f64, u: &mut dyn FnMut() -> f64| {
            DVec3::new(2.0 * u() - 1.0, 2.0 * u() - 1.0, 2.0 * u() - 1.0) * scale
        };
        let (mut answered, mut worst) = (0, 0.0_f64);
        let cases = 2000;
        for case in 0..cases {
            let axis = vector(1.0, &mut uniform).normalize();
            let r = DQuat::from_axis_angle(axis, std::f64::consts::PI * uniform());
            let mut best = BestRotation::new();
            for _ in 0..3 + case % 4 {
                let a = vector(1.0, &mut uniform);
                let noise = vector(0.05, &mut uniform);
                best.add(a, r * a + noise, 0.1 + uniform());
            }
            let n = best.matrix();
            let jacobi = jacobi_eigenvector(n);
            if let Some(v) = separated_eigenvector(&n) {
                answered += 1;
                let dot: f64 = v.iter().zip(&jacobi).map(|(x, y)| x * y).sum();
                let sign = dot.signum();
                let apart = v
                    .iter()
                    .zip(&jacobi)
                    .map(|(x, y)| (x - sign * y).powi(2))
                    .sum::<f64>()
                    .sqrt();
                let length: f64 = v.iter().map(|x| x * x).sum();
                assert!((length - 1.0).abs() <= 1e-15, "case {case}: {length}");
                worst = worst.max(apart);
            }
        }
        assert!(answered * 100 >= cases * 95, "{answered} of {cases}");
        assert!(worst <= 1e-12, "worst |v - v_jacobi| = {worst:e}");
        // Not apart: one pair, and pairs on one line through the centre.
        let (a, b) = (DVec3::new(1.0, 0.0, 0.0), DVec3::new(0.3, 0.8, -0.2));
        let mut one = BestRotation::new();
        one.add(a, b, 2.0);
        assert_eq!(separated_eigenvector(&one.matrix()), None);
        one.add(a * -3.0, b * -3.0, 1.0);
        assert_eq!(separated_eigenvector(&one.matrix()), None);
        let nan = [[f64::NAN; 4]; 4];
        assert_eq!(separated_eigenvector(&nan), None);
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
