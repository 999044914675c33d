//! The projection of a symmetric 12x12 matrix (a contact pair's Hessian) onto positive
//! semidefinite matrices: cyclic Jacobi rotations give the eigen-decomposition, negative
//! eigenvalues are replaced by zero.
//!
//! Jacobi is chosen for the same reason as for the 3x3 blocks ([`crate::contact::psd`]):
//! it is accurate for repeated and nearly repeated eigenvalues, which a pair's Hessian
//! has (most of its twelve eigenvalues are zero), and it needs no library.

use super::dual::VARIABLES;

/// A symmetric 12x12 matrix, rows of columns.
pub type Mat12 = [[f64; VARIABLES]; VARIABLES];

/// Largest number of sweeps; a sweep reduces the off-diagonal mass quadratically once it
/// is small, and 12x12 matrices converge in well under 15, so this guards only against
/// non-finite input.
const MAX_SWEEPS: usize = 50;

/// The eigenvalues and the eigenvectors (as the columns of the returned matrix) of the
/// symmetric part of `m`.
// Index loops over rows and columns read as the matrix formulas they implement.
#[allow(clippy::needless_range_loop)]
#[must_use]
pub fn symmetric_eigen12(m: &Mat12) -> ([f64; VARIABLES], Mat12) {
    const N: usize = VARIABLES;
    let mut a = *m;
    for i in 0..N {
        for j in 0..i {
            let s = 0.5 * (a[i][j] + a[j][i]);
            a[i][j] = s;
            a[j][i] = s;
        }
    }
    let mut v = [[0.0; N]; N];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    let scale: f64 = a.iter().flatten().map(|x| x * x).sum::<f64>().sqrt();
    for _ in 0..MAX_SWEEPS {
        let off: f64 = (0..N)
            .flat_map(|i| (0..i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if !(off.is_finite() && off > (1e-15 * scale).powi(2)) {
            break;
        }
        for p in 0..N {
            for q in p + 1..N {
                let apq = a[p][q];
                if apq == 0.0 {
                    continue;
                }
                // The rotation that zeroes a[p][q], with |angle| <= pi/4 for stability.
                let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
                let t = if theta.abs() > 1e150 {
                    0.5 / theta
                } else {
                    theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
                };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for row in &mut a {
                    let (rp, rq) = (row[p], row[q]);
                    row[p] = c * rp - s * rq;
                    row[q] = s * rp + c * rq;
                }
                for k in 0..N {
                    let (rp, rq) = (a[p][k], a[q][k]);
                    a[p][k] = c * rp - s * rq;
                    a[q][k] = s * rp + c * rq;
                }
                a[p][q] = 0.0;
                a[q][p] = 0.0;
                for row in &mut v {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    (std::array::from_fn(|i| a[i][i]), v)
}

/// The positive semidefinite matrix nearest to the symmetric part of `m` in the
/// Frobenius norm: eigenvectors kept, negative eigenvalues set to 0.
#[must_use]
pub fn project_psd12(m: &Mat12) -> Mat12 {
    const N: usize = VARIABLES;
    let (values, vectors) = symmetric_eigen12(m);
    let mut out = [[0.0; N]; N];
    for (k, &lambda) in values.iter().enumerate() {
        if lambda <= 0.0 {
            continue;
        }
        for i in 0..N {
            let vi = lambda * vectors[i][k];
            if vi == 0.0 {
                continue;
            }
            for j in 0..N {
                out[i][j] += vi * vectors[j][k];
            }
        }
    }
    out
}
