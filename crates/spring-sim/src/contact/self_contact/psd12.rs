//! The projection of a symmetric 12x12 matrix (a contact pair's Hessian) onto positive
//! semidefinite matrices: cyclic Jacobi rotations give the eigen-decomposition, negative
//! eigenvalues are replaced by zero.
//!
//! Jacobi is chosen for the same reason as for the 3x3 blocks ([`crate::contact::psd`]):
//! it is accurate for repeated and nearly repeated eigenvalues, which a pair's Hessian
//! has (most of its twelve eigenvalues are zero), and it needs no library.
//!
//! The rotations are written once for any size ([`symmetric_eigen_n`]): the closed-form
//! path ([`super::closed`]) decomposes a pair's Hessian in the at most five dimensions it
//! spans, and the full 12x12 decomposition remains for mollified edge pairs and as the
//! test oracle.

use super::dual::VARIABLES;

/// A symmetric 12x12 matrix, rows of columns.
pub type Mat12 = [[f64; VARIABLES]; VARIABLES];

/// Largest number of sweeps; a sweep reduces the off-diagonal mass quadratically once it
/// is small, and 12x12 matrices converge in well under 15, so this guards only against
/// non-finite input.
const MAX_SWEEPS: usize = 50;

/// The eigenvalues and the eigenvectors (as the columns of the returned matrix) of the
/// symmetric part of `m`.
#[must_use]
pub fn symmetric_eigen12(m: &Mat12) -> ([f64; VARIABLES], Mat12) {
    let all: [usize; VARIABLES] = std::array::from_fn(|i| i);
    symmetric_eigen_on(m, &all)
}

/// The eigenvalues and eigenvectors (the columns of the returned matrix) of the symmetric
/// part of the leading `n x n` block of `m` (`n <= N`; the entries beyond it are
/// returned as zero).
///
/// The sizes the closed-form path uses (3 to 5) run on arrays of exactly that size, so
/// the rotations' loops have fixed bounds; the arithmetic is the same operation for
/// operation, so the result is the same bit for bit whichever size it runs at.
#[must_use]
pub fn symmetric_eigen_n<const N: usize>(m: &[[f64; N]; N], n: usize) -> ([f64; N], [[f64; N]; N]) {
    let n = n.min(N);
    match n {
        3 => eigen_exact::<N, 3>(m),
        4 => eigen_exact::<N, 4>(m),
        5 => eigen_exact::<N, 5>(m),
        _ => {
            let mut index = [0usize; N];
            for (i, slot) in index.iter_mut().enumerate() {
                *slot = i;
            }
            symmetric_eigen_on(m, &index[..n])
        }
    }
}

/// [`symmetric_eigen_n`] for `n = M` on `M x M` arrays.
// Index loops over rows and columns read as the matrix formulas they implement.
#[allow(clippy::needless_range_loop)]
fn eigen_exact<const N: usize, const M: usize>(m: &[[f64; N]; N]) -> ([f64; N], [[f64; N]; N]) {
    let mut a = [[0.0; M]; M];
    for i in 0..M.min(N) {
        for j in 0..=i {
            let s = 0.5 * (m[i][j] + m[j][i]);
            a[i][j] = s;
            a[j][i] = s;
        }
    }
    let mut v = [[0.0; M]; M];
    jacobi(&mut a, &mut v, M);
    let mut vectors = [[0.0; N]; N];
    for i in 0..M.min(N) {
        vectors[i][..M].copy_from_slice(&v[i]);
    }
    (
        std::array::from_fn(|i| if i < M { a[i][i] } else { 0.0 }),
        vectors,
    )
}

/// The eigen-decomposition of the principal submatrix of `m` on the rows and columns
/// `index` (the first `index.len()` eigenvalues and eigenvector columns of the result;
/// eigenvector `k`'s entry for `index[i]` is at row `i`).
// Index loops over rows and columns read as the matrix formulas they implement.
#[allow(clippy::needless_range_loop)]
fn symmetric_eigen_on<const N: usize>(
    m: &[[f64; N]; N],
    index: &[usize],
) -> ([f64; N], [[f64; N]; N]) {
    let n = index.len();
    let mut a = [[0.0; N]; N];
    for i in 0..n {
        for j in 0..=i {
            let s = 0.5 * (m[index[i]][index[j]] + m[index[j]][index[i]]);
            a[i][j] = s;
            a[j][i] = s;
        }
    }
    let mut v = [[0.0; N]; N];
    jacobi(&mut a, &mut v, n);
    (
        std::array::from_fn(|i| if i < n { a[i][i] } else { 0.0 }),
        v,
    )
}

/// Cyclic Jacobi on the leading `n x n` block of the symmetric `a` (the rest zero): on
/// return its diagonal holds the eigenvalues and the leading block of `v` the
/// eigenvectors as columns.
///
/// `a` stays symmetric bit for bit (every entry below the diagonal is computed by the
/// same operations as its mirror), so each rotation computes the two rows it changes
/// once and mirrors them into the columns, rather than rotating the columns and then the
/// rows of the whole matrix: half the arithmetic, and the same values, including the
/// two diagonal entries, whose operations (the columns' rotation, then the rows') are
/// written out as the full update performs them.
// Index loops over rows and columns read as the matrix formulas they implement.
#[allow(clippy::needless_range_loop)]
fn jacobi<const N: usize>(a: &mut [[f64; N]; N], v: &mut [[f64; N]; N], n: usize) {
    for i in 0..n {
        v[i][i] = 1.0;
    }
    let scale: f64 = a.iter().flatten().map(|x| x * x).sum::<f64>().sqrt();
    // Converged when the off-diagonal part is below 1e-14 of the matrix: the projected
    // matrix is then within that relative distance of the exact projection.
    let tol = (1e-14 * scale).powi(2);
    // An entry far below the off-diagonal target is not worth a rotation.
    let skip = 1e-4 * tol / (n * n) as f64;
    for _ in 0..MAX_SWEEPS {
        let mut off = 0.0;
        for i in 0..n {
            for j in 0..i {
                off += a[i][j] * a[i][j];
            }
        }
        if !(off.is_finite() && off > tol) {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = a[p][q];
                if apq * apq <= skip {
                    continue;
                }
                let (c, s) = crate::contact::psd::jacobi_rotation(a[p][p], a[q][q], apq);
                let (app, aqq) = (a[p][p], a[q][q]);
                for k in 0..n {
                    if k == p || k == q {
                        continue;
                    }
                    let (rp, rq) = (a[k][p], a[k][q]);
                    let (np, nq) = (c * rp - s * rq, s * rp + c * rq);
                    a[k][p] = np;
                    a[p][k] = np;
                    a[k][q] = nq;
                    a[q][k] = nq;
                }
                // The columns' rotation of the 2x2 block, then the rows'.
                let (pp, pq) = (c * app - s * apq, s * app + c * apq);
                let (qp, qq) = (c * apq - s * aqq, s * apq + c * aqq);
                a[p][p] = c * pp - s * qp;
                a[q][q] = s * pq + c * qq;
                a[p][q] = 0.0;
                a[q][p] = 0.0;
                for row in v.iter_mut().take(n) {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
}

/// The positive semidefinite matrix nearest to the symmetric part of `m` in the
/// Frobenius norm: eigenvectors kept, negative eigenvalues set to 0. Rows and columns
/// that are entirely zero (the vertices a pair's closest points do not involve) are left
/// out of the decomposition, which is then of a smaller matrix (a vertex-vertex pair's is
/// 6x6, an eighth of the work).
// Index loops over rows and columns read as the matrix formulas they implement.
#[allow(clippy::needless_range_loop)]
#[must_use]
pub fn project_psd12(m: &Mat12) -> Mat12 {
    const N: usize = VARIABLES;
    let mut index = [0usize; N];
    let mut n = 0;
    for i in 0..N {
        if (0..N).any(|j| m[i][j] != 0.0 || m[j][i] != 0.0) {
            index[n] = i;
            n += 1;
        }
    }
    let index = &index[..n];
    let (values, vectors) = symmetric_eigen_on(m, index);
    let mut out = [[0.0; N]; N];
    for (k, &lambda) in values.iter().take(n).enumerate() {
        if lambda <= 0.0 {
            continue;
        }
        for i in 0..n {
            let vi = lambda * vectors[i][k];
            if vi == 0.0 {
                continue;
            }
            for j in 0..n {
                out[index[i]][index[j]] += vi * vectors[j][k];
            }
        }
    }
    out
}

/// The directions orthogonal to a common translation of a pair's four vertices, per
/// coordinate: vertex differences `(1, -1, 0, 0) / sqrt 2`, `(0, 0, 1, -1) / sqrt 2`
/// and `(1, 1, -1, -1) / 2`, an orthonormal basis of the vectors whose four entries
/// sum to zero.
const DIFFERENCES: [[f64; 4]; 3] = [
    [
        std::f64::consts::FRAC_1_SQRT_2,
        -std::f64::consts::FRAC_1_SQRT_2,
        0.0,
        0.0,
    ],
    [
        0.0,
        0.0,
        std::f64::consts::FRAC_1_SQRT_2,
        -std::f64::consts::FRAC_1_SQRT_2,
    ],
    [0.5, 0.5, -0.5, -0.5],
];

/// [`project_psd12`] for the Hessian of a pair's energy, which does not change when all
/// four vertices move together: the translations are in its null space, so it is
/// decomposed in the nine directions orthogonal to them (`Q^T m Q`, with `Q`'s columns
/// the vertex differences `(1, -1, 0, 0) / sqrt 2`, `(0, 0, 1, -1) / sqrt 2` and
/// `(1, 1, -1, -1) / 2` along each axis) instead of twelve, about two fifths of the
/// rotations' work, and the result is `Q P Q^T` with `P` the projection of the reduced
/// matrix. For a translation-invariant `m` this is the projection of `m` itself (the
/// round-off of `m`'s translation components, which are zero in exact arithmetic, is
/// dropped). A matrix with an all-zero row (a pair whose closest points leave a vertex
/// out) takes [`project_psd12`], which already decomposes a smaller matrix.
// Index loops over rows and columns read as the matrix formulas they implement.
#[allow(clippy::needless_range_loop)]
#[must_use]
pub fn project_psd12_pair(m: &Mat12) -> Mat12 {
    const N: usize = VARIABLES;
    if (0..N).any(|i| (0..N).all(|j| m[i][j] == 0.0 && m[j][i] == 0.0)) {
        return project_psd12(m);
    }
    // mq = m Q (12 x 9), then reduced = Q^T m Q (9 x 9); column `3 a + c` of Q is
    // DIFFERENCES[a] on coordinate `c` of the four vertices.
    let mut mq = [[0.0; 9]; N];
    for i in 0..N {
        for a in 0..3 {
            for c in 0..3 {
                mq[i][3 * a + c] = (0..4).map(|k| DIFFERENCES[a][k] * m[i][3 * k + c]).sum();
            }
        }
    }
    let mut reduced = [[0.0; 9]; 9];
    for a in 0..3 {
        for c in 0..3 {
            for j in 0..9 {
                reduced[3 * a + c][j] = (0..4).map(|k| DIFFERENCES[a][k] * mq[3 * k + c][j]).sum();
            }
        }
    }
    let (values, vectors) = symmetric_eigen_n(&reduced, 9);
    // The projection in the reduced space, then back: out = Q P Q^T.
    let mut p = [[0.0; 9]; 9];
    for (k, &lambda) in values.iter().enumerate() {
        if lambda <= 0.0 {
            continue;
        }
        for i in 0..9 {
            let vi = lambda * vectors[i][k];
            for j in 0..9 {
                p[i][j] += vi * vectors[j][k];
            }
        }
    }
    let mut pq = [[0.0; N]; 9];
    for i in 0..9 {
        for l in 0..4 {
            for d in 0..3 {
                pq[i][3 * l + d] = (0..3).map(|b| DIFFERENCES[b][l] * p[i][3 * b + d]).sum();
            }
        }
    }
    let mut out = [[0.0; N]; N];
    for k in 0..4 {
        for c in 0..3 {
            for j in 0..N {
                out[3 * k + c][j] = (0..3).map(|a| DIFFERENCES[a][k] * pq[3 * a + c][j]).sum();
            }
        }
    }
    // Symmetric bit for bit, as the full projection is.
    for i in 0..N {
        for j in 0..i {
            let s = 0.5 * (out[i][j] + out[j][i]);
            out[i][j] = s;
            out[j][i] = s;
        }
    }
    out
}
