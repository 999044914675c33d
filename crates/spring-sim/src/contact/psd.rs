//! The eigen-decomposition of a symmetric 3x3 matrix by cyclic Jacobi rotations, and the
//! projection onto positive semidefinite matrices that clamps negative eigenvalues at 0.
//!
//! Jacobi is used rather than the closed-form cubic because it is accurate for every
//! input, including repeated and nearly repeated eigenvalues, where the closed form
//! loses the eigenvectors: each rotation zeroes one off-diagonal entry, the sum of
//! squares of the off-diagonal entries falls monotonically and, for a 3x3 matrix, reaches
//! round-off in a handful of sweeps.
//!
//! The projection is the Frobenius-nearest positive semidefinite matrix: keep the
//! eigenvectors and replace negative eigenvalues by 0.

use sinew_math::{DMat3, DVec3};

/// Largest number of Jacobi sweeps; convergence is quadratic and a 3x3 matrix needs
/// about five, so this cap is only a guard against a non-finite input.
const MAX_SWEEPS: usize = 32;

/// The Jacobi rotation that zeroes the off-diagonal entry `apq` of a symmetric matrix
/// whose diagonal entries at `p` and `q` are `app` and `aqq`: its cosine and sine. `t =
/// tan(angle)` is the smaller root of `t^2 + 2 theta t - 1 = 0`, so `|angle| <= pi/4`
/// and the rotation is stable (an overflowing `theta^2` takes the root's limit
/// `1 / (2 theta)`). The 3 x 3 and the 12 x 12 solvers both rotate by it.
#[inline]
pub(crate) fn jacobi_rotation(app: f64, aqq: f64, apq: f64) -> (f64, f64) {
    let theta = (aqq - app) / (2.0 * apq);
    let t = if theta.abs() > 1e150 {
        0.5 / theta
    } else {
        theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
    };
    let c = 1.0 / (t * t + 1.0).sqrt();
    (c, t * c)
}

/// The eigenvalues (ascending) and the orthonormal eigenvectors (the columns, in the same
/// order) of the symmetric part `(m + m^T)/2` of a finite matrix `m`.
#[must_use]
pub fn symmetric_eigen(m: DMat3) -> (DVec3, DMat3) {
    let s = (m + m.transpose()) * 0.5;
    let mut a = [
        [s.x_axis.x, s.y_axis.x, s.z_axis.x],
        [s.x_axis.y, s.y_axis.y, s.z_axis.y],
        [s.x_axis.z, s.y_axis.z, s.z_axis.z],
    ];
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..MAX_SWEEPS {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        if off == 0.0 || !off.is_finite() {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            let apq = a[p][q];
            if apq == 0.0 {
                continue;
            }
            // An entry below round-off of both diagonal entries is set to zero rather than
            // rotated: the rotation would change nothing representable.
            let scale = a[p][p].abs() + a[q][q].abs();
            if apq.abs() <= 1e-3 * f64::EPSILON * scale {
                a[p][q] = 0.0;
                a[q][p] = 0.0;
                continue;
            }
            let (c, sn) = jacobi_rotation(a[p][p], a[q][q], apq);
            // a <- J^T a J with J the identity except J[p][p] = J[q][q] = c,
            // J[p][q] = sn, J[q][p] = -sn.
            for row in &mut a {
                let (rp, rq) = (row[p], row[q]);
                row[p] = c * rp - sn * rq;
                row[q] = sn * rp + c * rq;
            }
            let (row_p, row_q) = (a[p], a[q]);
            a[p] = std::array::from_fn(|k| c * row_p[k] - sn * row_q[k]);
            a[q] = std::array::from_fn(|k| sn * row_p[k] + c * row_q[k]);
            a[p][q] = 0.0;
            a[q][p] = 0.0;
            for row in &mut v {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - sn * vq;
                row[q] = sn * vp + c * vq;
            }
        }
    }
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| a[i][i].total_cmp(&a[j][j]));
    let values = DVec3::new(
        a[order[0]][order[0]],
        a[order[1]][order[1]],
        a[order[2]][order[2]],
    );
    let column = |k: usize| DVec3::new(v[0][k], v[1][k], v[2][k]);
    let vectors = DMat3::from_cols(column(order[0]), column(order[1]), column(order[2]));
    (values, vectors)
}

/// The positive semidefinite matrix nearest (in the Frobenius norm) to the symmetric part
/// of a finite `m`: its eigenvectors kept, its negative eigenvalues replaced by 0.
#[must_use]
pub fn project_psd(m: DMat3) -> DMat3 {
    let (values, vectors) = symmetric_eigen(m);
    if values.x >= 0.0 {
        return (m + m.transpose()) * 0.5;
    }
    let clamped = values.max(DVec3::ZERO);
    vectors * DMat3::from_diagonal(clamped) * vectors.transpose()
}
