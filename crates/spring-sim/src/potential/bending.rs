//! Discrete-shell bending (Grinspun, Hirani, Desbrun and Schröder, "Discrete Shells",
//! SCA 2003): for every hinge (an interior edge and the two triangles on it), the energy
//! `k/2 w (theta - theta_rest)^2`, `theta` the signed angle between the two triangles'
//! normals and `w = 3 |e_rest|^2 / (A1_rest + A2_rest)` the hinge's weight from the rest
//! shape, so the energy converges to the smooth shell's bending energy under refinement.
//!
//! The gradient of `theta` is written in closed form; its Hessian comes from
//! forward-mode differentiation (dual numbers) of that closed form, twelve directional
//! derivatives, so it is exact to round-off without a page of hand-expanded terms. The
//! Hessian of a hinge, `k w (grad theta grad theta^T + (theta - theta_rest) hess theta)`,
//! is indefinite in general; [`Curvature::Clamped`] projects the 12 x 12 matrix onto
//! positive semidefinite matrices by clamping its negative eigenvalues at 0 (cyclic
//! Jacobi on the 9 x 9 matrix left once the translations, which the Hessian maps to zero,
//! are removed), [`Curvature::Softened`] removes that fraction of them,
//! [`Curvature::Exact`] keeps them. Derivation and conventions: docs/bending.md.

use super::{HessianSink, StepContext, SymBlock, Term};
use crate::spring::Curvature;
use sinew_math::{DMat3, DVec3};
use std::ops::{Add, Div, Mul, Neg, Sub};

/// One hinge: the edge `(edge[0], edge[1])` shared by the triangles
/// `(edge[0], edge[1], opposite[0])` and `(edge[0], edge[1], opposite[1])` (up to
/// orientation), with its rest angle and weight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hinge {
    /// The shared edge's two vertices.
    pub edge: [usize; 2],
    /// The vertex of each triangle opposite the edge.
    pub opposite: [usize; 2],
    /// The signed dihedral angle at rest ([`dihedral_angle`]), in `(-pi, pi]`.
    pub rest_angle: f64,
    /// `3 |e|^2 / (A1 + A2)` at rest.
    pub weight: f64,
    /// The bending stiffness `k` (energy units: the energy is `k/2 w (theta -
    /// theta_rest)^2`).
    pub stiffness: f64,
}

impl Hinge {
    /// The hinge's four vertices in the order the derivatives use: edge start, edge end,
    /// first opposite, second opposite.
    #[must_use]
    pub fn vertices(&self) -> [usize; 4] {
        [
            self.edge[0],
            self.edge[1],
            self.opposite[0],
            self.opposite[1],
        ]
    }

    /// The hinge on `edge` with opposite vertices `opposite`, its rest angle and weight
    /// measured on `rest`; `None` when either rest triangle has zero area (no normal, so
    /// no angle).
    #[must_use]
    pub fn at_rest(
        rest: &[DVec3],
        edge: [usize; 2],
        opposite: [usize; 2],
        stiffness: f64,
    ) -> Option<Self> {
        let x = [
            rest[edge[0]],
            rest[edge[1]],
            rest[opposite[0]],
            rest[opposite[1]],
        ];
        let e = x[1] - x[0];
        let n1 = e.cross(x[2] - x[0]);
        let n2 = (x[3] - x[0]).cross(e);
        let areas = 0.5 * (n1.length() + n2.length());
        if n1.length_squared() == 0.0 || n2.length_squared() == 0.0 || !areas.is_finite() {
            return None;
        }
        Some(Self {
            edge,
            opposite,
            rest_angle: dihedral_angle(x),
            weight: 3.0 * e.length_squared() / areas,
            stiffness,
        })
    }

    /// The hinge's energy at `x`.
    #[must_use]
    pub fn energy(&self, x: &[DVec3]) -> f64 {
        let d = dihedral_angle(self.gather(x)) - self.rest_angle;
        0.5 * self.stiffness * self.weight * d * d
    }

    fn gather(&self, x: &[DVec3]) -> [DVec3; 4] {
        self.vertices().map(|v| x[v])
    }
}

/// The signed angle between the normals of the triangles `(x0, x1, x2)` and
/// `(x0, x1, x3)` hinged on the edge `x0 -> x1`: 0 when the four points are flat with
/// `x2` and `x3` on opposite sides of the edge, positive when the second triangle is
/// turned about `x1 - x0` (right-handed) from the first. With `e = x1 - x0`,
/// `n1 = e x (x2 - x0)`, `n2 = (x3 - x0) x e`:
/// `theta = atan2((n1 x n2) . e / |e|, n1 . n2)`. A degenerate hinge (a zero normal or
/// a zero edge) has angle 0.
#[must_use]
pub fn dihedral_angle(x: [DVec3; 4]) -> f64 {
    let e = x[1] - x[0];
    let n1 = e.cross(x[2] - x[0]);
    let n2 = (x[3] - x[0]).cross(e);
    let len = e.length();
    if len == 0.0 || n1.length_squared() == 0.0 || n2.length_squared() == 0.0 {
        return 0.0;
    }
    n1.cross(n2).dot(e / len).atan2(n1.dot(n2))
}

/// The gradient of [`dihedral_angle`] with respect to `x0 .. x3`, zero for a degenerate
/// hinge (docs/bending.md derives it):
/// `grad_2 = -|e| n1 / |n1|^2`, `grad_3 = -|e| n2 / |n2|^2`,
/// `grad_0 = -(1 - s2) grad_2 - (1 - s3) grad_3`, `grad_1 = -s2 grad_2 - s3 grad_3`,
/// `s_i = (x_i - x0) . e / |e|^2`.
#[must_use]
pub fn dihedral_angle_gradient(x: [DVec3; 4]) -> [DVec3; 4] {
    let g = angle_gradient(x.map(V3::<f64>::from));
    g.map(V3::to_dvec3)
}

/// The Hessian of [`dihedral_angle`] as 4 x 4 blocks (`[i][j]` is `d^2 theta / dx_i
/// dx_j`), from forward-mode differentiation of [`dihedral_angle_gradient`]; zero for a
/// degenerate hinge.
// Index loops over blocks and matrix entries read like the formulas they implement.
#[allow(clippy::needless_range_loop)]
#[must_use]
pub fn dihedral_angle_hessian(x: [DVec3; 4]) -> [[DMat3; 4]; 4] {
    let mut h = [[DMat3::ZERO; 4]; 4];
    for j in 0..4 {
        for axis in 0..3 {
            // The directional derivative of the gradient along unknown (j, axis) is
            // column (j, axis) of the Hessian.
            let seeded = std::array::from_fn(|v| {
                let mut p = V3::<Dual>::from_values(x[v]);
                if v == j {
                    p.seed(axis);
                }
                p
            });
            let g = angle_gradient(seeded);
            for (i, gi) in g.iter().enumerate() {
                let col = DVec3::new(gi.x.d, gi.y.d, gi.z.d);
                // Block (i, j): entry (r, c) = d grad_i[r] / d x_j[c]; column c is `col`.
                let mut m = h[i][j];
                *m.col_mut(axis) = col;
                h[i][j] = m;
            }
        }
    }
    h
}

/// `dihedral_angle(x + delta) - dihedral_angle(x)` computed from the changes of the
/// normals and the edge direction, so a tiny `delta` gives a change with full relative
/// precision (docs/bending.md). When either state is degenerate (a zero edge or normal)
/// it is the plain difference of the two angles, each 0 where degenerate, as the energy
/// sees them.
#[must_use]
pub fn angle_change(x: [DVec3; 4], delta: [DVec3; 4]) -> f64 {
    let e = x[1] - x[0];
    let de = delta[1] - delta[0];
    let (a, da) = (x[2] - x[0], delta[2] - delta[0]);
    let (b, db) = (x[3] - x[0], delta[3] - delta[0]);
    let n1 = e.cross(a);
    let n2 = b.cross(e);
    // The changes of the (unnormalized) normals, expanded so no large terms cancel.
    let dn1 = de.cross(a) + e.cross(da) + de.cross(da);
    let dn2 = db.cross(e) + b.cross(de) + db.cross(de);
    let plain = || {
        let moved = std::array::from_fn(|k| x[k] + delta[k]);
        dihedral_angle(moved) - dihedral_angle(x)
    };
    let (len, len_new) = (e.length(), (e + de).length());
    if len == 0.0 || len_new == 0.0 {
        return plain();
    }
    let unit = e / len;
    let unit_new = (e + de) / len_new;
    // unit_new - unit = (de - unit (|e + de| - |e|)) / |e + de|.
    let dlen = de.dot(2.0 * e + de) / (len_new + len);
    let dunit = (de - unit * dlen) / len_new;
    let m = n1.cross(n2);
    let dm = dn1.cross(n2) + n1.cross(dn2) + dn1.cross(dn2);
    let (c, s) = (n1.dot(n2), m.dot(unit));
    let dc = dn1.dot(n2) + n1.dot(dn2) + dn1.dot(dn2);
    let ds = dm.dot(unit_new) + m.dot(dunit);
    let (c_new, s_new) = (c + dc, s + ds);
    if (c == 0.0 && s == 0.0) || (c_new == 0.0 && s_new == 0.0) {
        return plain();
    }
    // arg((c' + i s')(c - i s)), with s' c - c' s = ds c - dc s.
    (ds * c - dc * s).atan2(c_new * c + s_new * s)
}

/// The closed-form gradient, generic over the scalar so that dual numbers differentiate
/// it once more.
fn angle_gradient<S: Scalar>(x: [V3<S>; 4]) -> [V3<S>; 4] {
    let e = x[1] - x[0];
    let n1 = e.cross(x[2] - x[0]);
    let n2 = (x[3] - x[0]).cross(e);
    let (e2, n1sq, n2sq) = (e.dot(e), n1.dot(n1), n2.dot(n2));
    if e2.value() == 0.0 || n1sq.value() == 0.0 || n2sq.value() == 0.0 {
        return [V3::zero(); 4];
    }
    let len = e2.sqrt();
    let g2 = n1 * (-len / n1sq);
    let g3 = n2 * (-len / n2sq);
    let s2 = (x[2] - x[0]).dot(e) / e2;
    let s3 = (x[3] - x[0]).dot(e) / e2;
    let one = S::from_f64(1.0);
    let g0 = -(g2 * (one - s2) + g3 * (one - s3));
    let g1 = -(g2 * s2 + g3 * s3);
    [g0, g1, g2, g3]
}

/// The hinges' bending energy, a [`Term`] of the incremental potential. Its Hessian
/// couples the two opposite vertices of each hinge, a pair no edge spring joins: add it
/// with [`crate::BackwardEuler::add_coupled_term`] and [`DihedralBending::coupled_pairs`].
///
/// # Example
///
/// Two unit right triangles flat along the edge from vertex 0 to vertex 1; folding
/// vertex 3 by an angle `theta` about that edge gives the closed form
/// `k/2 w theta^2`, with `w = 3 |e|^2 / (A1 + A2) = 3`.
///
/// ```
/// use sinew_spring_sim::DVec3;
/// use sinew_spring_sim::potential::{DihedralBending, Hinge};
///
/// let (k, theta) = (2.0, 0.3_f64);
/// let mut x = vec![DVec3::ZERO, DVec3::X, DVec3::Y, -DVec3::Y];
/// let hinge = Hinge::at_rest(&x, [0, 1], [2, 3], k).expect("both triangles have area");
/// let term = DihedralBending::new(vec![hinge]);
/// // The Hessian couples all six pairs of the hinge's vertices, among them the
/// // opposite vertices, which no edge spring joins.
/// assert_eq!(term.coupled_pairs().len(), 6);
/// assert!(term.coupled_pairs().contains(&[2, 3]));
/// assert!(term.hinges()[0].energy(&x).abs() < 1e-15);
///
/// x[3] = DVec3::new(0.0, -theta.cos(), theta.sin());
/// let expected = 0.5 * k * 3.0 * theta * theta;
/// assert!((term.hinges()[0].energy(&x) - expected).abs() < 1e-12);
/// ```
#[derive(Clone, Debug, Default)]
pub struct DihedralBending {
    hinges: Vec<Hinge>,
}

impl DihedralBending {
    /// The term for `hinges`.
    #[must_use]
    pub fn new(hinges: Vec<Hinge>) -> Self {
        Self { hinges }
    }

    /// The hinges.
    #[must_use]
    pub fn hinges(&self) -> &[Hinge] {
        &self.hinges
    }

    /// Every pair of particles the term's Hessian couples: all six pairs of each hinge's
    /// four vertices.
    #[must_use]
    pub fn coupled_pairs(&self) -> Vec<[usize; 2]> {
        let mut pairs = Vec::with_capacity(6 * self.hinges.len());
        for h in &self.hinges {
            let v = h.vertices();
            for i in 0..4 {
                for j in i + 1..4 {
                    pairs.push([v[i], v[j]]);
                }
            }
        }
        pairs
    }

    /// The Hessian of hinge `h`'s energy at `x` as 4 x 4 blocks, in the form `curvature`
    /// asks for.
    #[must_use]
    // Index loops over blocks and matrix entries read like the formulas they implement.
    #[allow(clippy::needless_range_loop)]
    pub fn hinge_hessian(h: &Hinge, x: &[DVec3], curvature: Curvature) -> [[DMat3; 4]; 4] {
        let p = h.gather(x);
        let g = dihedral_angle_gradient(p);
        let d = dihedral_angle(p) - h.rest_angle;
        let kw = h.stiffness * h.weight;
        let second = if d == 0.0 {
            [[DMat3::ZERO; 4]; 4]
        } else {
            dihedral_angle_hessian(p)
        };
        let mut m = [[0.0; 12]; 12];
        for i in 0..4 {
            for j in 0..4 {
                let outer = outer(g[i], g[j]);
                let block = kw * (outer + d * second[i][j]);
                for c in 0..3 {
                    for r in 0..3 {
                        m[3 * i + r][3 * j + c] = block.col(c)[r];
                    }
                }
            }
        }
        // Symmetrize: the dual-number Hessian is symmetric only to round-off.
        for r in 0..12 {
            for c in r + 1..12 {
                let s = 0.5 * (m[r][c] + m[c][r]);
                m[r][c] = s;
                m[c][r] = s;
            }
        }
        let removed = match curvature {
            Curvature::Exact => 0.0,
            Curvature::Clamped => 1.0,
            Curvature::Softened(theta) | Curvature::ExactContact(theta) => theta.clamp(0.0, 1.0),
        };
        // With theta at rest the second part vanishes and the matrix is k w g g^T, already
        // positive semidefinite: no eigen-decomposition needed.
        if removed > 0.0 && d != 0.0 {
            m = remove_negative_curvature(m, removed);
        }
        let mut blocks = [[DMat3::ZERO; 4]; 4];
        for (i, row) in blocks.iter_mut().enumerate() {
            for (j, block) in row.iter_mut().enumerate() {
                *block = DMat3::from_cols_array(&std::array::from_fn(|k| {
                    let (c, r) = (k / 3, k % 3);
                    m[3 * i + r][3 * j + c]
                }));
            }
        }
        blocks
    }
}

impl Term for DihedralBending {
    fn name(&self) -> &'static str {
        "dihedral bending"
    }

    fn energy(&self, _step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        self.hinges.iter().map(|h| h.energy(x)).sum()
    }

    fn energy_change(&self, _step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        let mut change = 0.0;
        for h in &self.hinges {
            let v = h.vertices();
            if v.iter().all(|&i| dx[i] == DVec3::ZERO) {
                continue;
            }
            let p = h.gather(x);
            let delta = v.map(|i| alpha * dx[i]);
            let before = dihedral_angle(p);
            let after = dihedral_angle(std::array::from_fn(|k| p[k] + delta[k]));
            // (a^2 - b^2) as (a - b)(a + b), with a - b from the differences of the
            // normals: near convergence the line search compares changes far below what
            // the difference of two angles resolves.
            let mut turn = angle_change(p, delta);
            if (after - before - turn).abs() > 1.0 {
                // The angle wrapped through pi: the energies use the wrapped values.
                turn = after - before;
            }
            change += 0.5 * h.stiffness * h.weight * turn * (after + before - 2.0 * h.rest_angle);
        }
        change
    }

    fn add_gradient(&self, _step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        for h in &self.hinges {
            let p = h.gather(x);
            let d = dihedral_angle(p) - h.rest_angle;
            if d == 0.0 {
                continue;
            }
            let g = dihedral_angle_gradient(p);
            let scale = h.stiffness * h.weight * d;
            for (v, gv) in h.vertices().into_iter().zip(g) {
                gradient[v] += scale * gv;
            }
        }
    }

    fn add_hessian(
        &self,
        _step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        sink: &mut HessianSink<'_>,
    ) {
        for h in &self.hinges {
            let blocks = Self::hinge_hessian(h, x, curvature);
            let v = h.vertices();
            for i in 0..4 {
                sink.add_diagonal(v[i], SymBlock::from_lower(&blocks[i][i]));
                for j in i + 1..4 {
                    let added = sink.add_pair(v[i], v[j], &blocks[i][j]);
                    // The term is added with its coupled pairs, so the pattern has them;
                    // a missing pair is a wiring error, not bad input.
                    debug_assert!(added.is_ok(), "the Hessian pattern lacks a hinge pair");
                }
            }
        }
    }
}

/// `a b^T`.
fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// Largest number of Jacobi sweeps for the eigen-decomposition; convergence is quadratic
/// and about eight sweeps reach round-off, so the cap only guards against a non-finite
/// input.
const MAX_SWEEPS: usize = 50;

/// An orthonormal basis of the vectors of R^4 orthogonal to `(1, 1, 1, 1)` (Helmert's),
/// as rows per vertex: `HELMERT[p][i]` is entry `p` of basis vector `i`. With it, the
/// hinge's 12 unknowns split into the three translations and nine other directions.
const HELMERT: [[f64; 3]; 4] = {
    let (a, b, c) = (
        std::f64::consts::FRAC_1_SQRT_2,
        0.408_248_290_463_863,   // 1/sqrt(6)
        0.288_675_134_594_812_9, // 1/sqrt(12)
    );
    [
        [a, b, c],
        [-a, b, c],
        [0.0, -2.0 * b, c],
        [0.0, 0.0, -3.0 * c],
    ]
};

/// `m` with the fraction `removed` of each negative eigenvalue taken away (1: the
/// Frobenius-nearest positive semidefinite matrix).
///
/// A hinge's energy does not change when all four vertices move together, so its
/// Hessian maps the three translations to zero and is determined by the 9 x 9 matrix
/// `Q^T m Q` on the other directions (`Q` = Helmert's basis, per axis): that smaller
/// matrix is decomposed (cyclic Jacobi) and each negative eigenvector `u` is mapped back
/// as `Q u`. Half the work of decomposing the 12 x 12 matrix.
// Index loops over blocks and matrix entries read like the formulas they implement.
#[allow(clippy::needless_range_loop)]
fn remove_negative_curvature(m: [[f64; 12]; 12], removed: f64) -> [[f64; 12]; 12] {
    // Unknown (vertex p, axis a) is 3p + a; reduced unknown (basis vector i, axis a) is
    // 3i + a. First w = m Q (12 x 9), then r = Q^T w (9 x 9).
    let mut w = [[0.0; 9]; 12];
    for row in 0..12 {
        for j in 0..3 {
            for b in 0..3 {
                w[row][3 * j + b] = (0..4).map(|q| m[row][3 * q + b] * HELMERT[q][j]).sum();
            }
        }
    }
    let mut r = [[0.0; 9]; 9];
    for i in 0..3 {
        for a in 0..3 {
            for col in 0..9 {
                r[3 * i + a][col] = (0..4).map(|p| HELMERT[p][i] * w[3 * p + a][col]).sum();
            }
        }
    }
    let (lambda, v) = symmetric_eigen(r);
    let mut out = m;
    for k in 0..9 {
        if lambda[k] < 0.0 {
            let cut = -removed * lambda[k];
            // The eigenvector in the hinge's unknowns: Q u.
            let mut full = [0.0; 12];
            for p in 0..4 {
                for a in 0..3 {
                    full[3 * p + a] = (0..3).map(|i| HELMERT[p][i] * v[3 * i + a][k]).sum();
                }
            }
            for row in 0..12 {
                for col in 0..12 {
                    out[row][col] += cut * full[row] * full[col];
                }
            }
        }
    }
    out
}

/// The eigenvalues and eigenvectors (the columns of the second result, `v[r][k]` is
/// entry `r` of eigenvector `k`) of the symmetric matrix `m`, by cyclic Jacobi rotations.
#[allow(clippy::needless_range_loop)]
fn symmetric_eigen<const N: usize>(m: [[f64; N]; N]) -> ([f64; N], [[f64; N]; N]) {
    let mut a = m;
    let mut v = [[0.0; N]; N];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    let scale: f64 = a.iter().flatten().map(|x| x * x).sum::<f64>();
    for _ in 0..MAX_SWEEPS {
        let off: f64 = (0..N)
            .flat_map(|p| (p + 1..N).map(move |q| (p, q)))
            .map(|(p, q)| a[p][q] * a[p][q])
            .sum();
        if off.is_nan() || off <= 1e-32 * scale {
            break;
        }
        for p in 0..N {
            for q in p + 1..N {
                let apq = a[p][q];
                if apq == 0.0 {
                    continue;
                }
                let tau = (a[q][q] - a[p][p]) / (2.0 * apq);
                let t = if tau == 0.0 {
                    1.0
                } else {
                    tau.signum() / (tau.abs() + (1.0 + tau * tau).sqrt())
                };
                let c = 1.0 / (1.0 + t * t).sqrt();
                let s = t * c;
                for k in 0..N {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..N {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    (std::array::from_fn(|k| a[k][k]), v)
}

/// The arithmetic the closed-form gradient needs, for `f64` and for dual numbers.
trait Scalar:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    fn from_f64(v: f64) -> Self;
    fn value(self) -> f64;
    fn sqrt(self) -> Self;
}

impl Scalar for f64 {
    fn from_f64(v: f64) -> Self {
        v
    }
    fn value(self) -> f64 {
        self
    }
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
}

/// A dual number `v + d eps`, `eps^2 = 0`: arithmetic on it carries one directional
/// derivative exactly.
#[derive(Clone, Copy, Debug)]
struct Dual {
    v: f64,
    d: f64,
}

impl Add for Dual {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self {
            v: self.v + o.v,
            d: self.d + o.d,
        }
    }
}

impl Sub for Dual {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        Self {
            v: self.v - o.v,
            d: self.d - o.d,
        }
    }
}

impl Mul for Dual {
    type Output = Self;
    fn mul(self, o: Self) -> Self {
        Self {
            v: self.v * o.v,
            d: self.d * o.v + self.v * o.d,
        }
    }
}

impl Div for Dual {
    type Output = Self;
    fn div(self, o: Self) -> Self {
        Self {
            v: self.v / o.v,
            d: (self.d * o.v - self.v * o.d) / (o.v * o.v),
        }
    }
}

impl Neg for Dual {
    type Output = Self;
    fn neg(self) -> Self {
        Self {
            v: -self.v,
            d: -self.d,
        }
    }
}

impl Scalar for Dual {
    fn from_f64(v: f64) -> Self {
        Self { v, d: 0.0 }
    }
    fn value(self) -> f64 {
        self.v
    }
    fn sqrt(self) -> Self {
        let r = self.v.sqrt();
        Self {
            v: r,
            d: self.d / (2.0 * r),
        }
    }
}

/// A 3-vector over a [`Scalar`].
#[derive(Clone, Copy, Debug)]
struct V3<S> {
    x: S,
    y: S,
    z: S,
}

impl<S: Scalar> V3<S> {
    fn zero() -> Self {
        let z = S::from_f64(0.0);
        Self { x: z, y: z, z }
    }

    fn from_values(v: DVec3) -> Self {
        Self {
            x: S::from_f64(v.x),
            y: S::from_f64(v.y),
            z: S::from_f64(v.z),
        }
    }

    fn dot(self, o: Self) -> S {
        self.x * o.x + self.y * o.y + self.z * o.z
    }

    fn cross(self, o: Self) -> Self {
        Self {
            x: self.y * o.z - self.z * o.y,
            y: self.z * o.x - self.x * o.z,
            z: self.x * o.y - self.y * o.x,
        }
    }
}

impl V3<f64> {
    fn to_dvec3(self) -> DVec3 {
        DVec3::new(self.x, self.y, self.z)
    }
}

impl From<DVec3> for V3<f64> {
    fn from(v: DVec3) -> Self {
        Self::from_values(v)
    }
}

impl V3<Dual> {
    /// Sets the derivative of component `axis` to 1.
    fn seed(&mut self, axis: usize) {
        match axis {
            0 => self.x.d = 1.0,
            1 => self.y.d = 1.0,
            _ => self.z.d = 1.0,
        }
    }
}

impl<S: Scalar> Add for V3<S> {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self {
            x: self.x + o.x,
            y: self.y + o.y,
            z: self.z + o.z,
        }
    }
}

impl<S: Scalar> Sub for V3<S> {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        Self {
            x: self.x - o.x,
            y: self.y - o.y,
            z: self.z - o.z,
        }
    }
}

impl<S: Scalar> Mul<S> for V3<S> {
    type Output = Self;
    fn mul(self, s: S) -> Self {
        Self {
            x: self.x * s,
            y: self.y * s,
            z: self.z * s,
        }
    }
}

impl<S: Scalar> Neg for V3<S> {
    type Output = Self;
    fn neg(self) -> Self {
        Self {
            x: -self.x,
            y: -self.y,
            z: -self.z,
        }
    }
}
