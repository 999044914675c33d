//! Closed-form gradient and Hessian of a pair's squared distance, and the positive
//! semidefinite projection of a function of it done in the few dimensions its Hessian
//! spans, and a mollified edge pair's derivatives by the product rule (`Mollifier`).
//! This is the hot path of [`super::SelfContactTerm`]; the dual numbers of
//! [`super::dual`] stay as the test oracle and for the degenerate pairs the closed
//! form declines.
//!
//! In every region the closest points are an affine function of at most two free
//! parameters `w` (the point-edge parameter, the triangle's barycentric pair, the two edge
//! parameters), and the vector between them is `r = sum_k c_k(w) x_k` with weights `c`
//! affine in `w`. The region's squared distance is `s(x) = min_w |r(x, w)|^2`, the
//! minimum taken over the whole affine hull, so at the minimizer the derivative in `w`
//! vanishes and (the envelope theorem, then implicit differentiation of that condition)
//!
//! - `grad s = 2 c (x) r` (vertex `k`'s block is `2 c_k r`);
//! - `hess s = 2 (c c^T) (x) I_3 - J^T M^-1 J`, where `M = 2 E^T E` with `E`'s columns
//!   `e_j = dr/dw_j`, and row `j` of `J` has vertex block `2 (a_jk r + c_k e_j)`,
//!   `a_j = dc/dw_j`.
//!
//! A function `phi(s)` (the barrier of the distance minus the thickness) then has the
//! Hessian `phi'' grad s grad s^T + phi' hess s`, which lies in the span of the three
//! vectors `c (x) e_i` and the `m` vectors `a_j (x) r` (`m` free parameters): at most five
//! dimensions. With an orthonormal basis `B` of that span (the normalized `c (x) e_i`,
//! and `b_l (x) r / |r|` with `b_l` the Gram-Schmidt orthonormalization of the `a_j`
//! against `c`) the Hessian is `B K B^T` with `K` at most 5x5, and its projection onto
//! positive semidefinite matrices is `B K_+ B^T`: eigenvalues of a matrix are those of
//! `K` plus zeros. Derivation in full: docs/contact.md.

use super::distance::{Closest, PairKind};
use super::psd12::{Mat12, symmetric_eigen_n};
use sinew_math::DVec3;

/// The largest dimension of the span of a pair's barrier Hessian: three for the
/// direction between the closest points and its two normals, two for the free parameters.
const SPAN: usize = 5;

/// A pair's squared distance in one region in the affine form of the module
/// documentation: `r = sum_k c_k x_k`, with `m` free parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegionForm {
    /// The vector between the closest points, `r = sum_k c_k x_k`.
    pub r: DVec3,
    /// The weights `c` of the pair's four vertices (zero for a vertex the region does not
    /// involve).
    pub c: [f64; 4],
    /// `a_j = dc / dw_j` for the `m` free parameters.
    pub a: [[f64; 4]; 2],
    /// `e_j = dr / dw_j = sum_k a_jk x_k`.
    pub e: [DVec3; 2],
    /// The number of free parameters (0 to 2).
    pub m: usize,
}

impl RegionForm {
    /// The form of the pair `v` in region `closest`. The vector `r` of the point-plane and
    /// line-line regions is computed along the normal, `((x_0 - a) . n / |n|^2) n`, so
    /// its direction does not carry the round-off of the in-plane parameters.
    #[must_use]
    pub fn new(v: &[DVec3; 4], closest: Closest) -> Self {
        let mut f = Self {
            r: DVec3::ZERO,
            c: [0.0; 4],
            a: [[0.0; 4]; 2],
            e: [DVec3::ZERO; 2],
            m: 0,
        };
        match closest {
            Closest::PointPoint([i, j]) => {
                f.r = v[i] - v[j];
                f.c[i] = 1.0;
                f.c[j] = -1.0;
            }
            Closest::PointEdge([p, a, b]) => {
                let d = v[b] - v[a];
                let t = (v[p] - v[a]).dot(d) / d.length_squared();
                f.r = v[p] - v[a] - t * d;
                f.c[p] = 1.0;
                f.c[a] = -(1.0 - t);
                f.c[b] = -t;
                // r = x_p - x_a - t (x_b - x_a).
                f.m = 1;
                f.a[0][a] = 1.0;
                f.a[0][b] = -1.0;
                f.e[0] = -d;
            }
            Closest::PointPlane([p, a, b, c]) => {
                let (e1, e2, w) = (v[b] - v[a], v[c] - v[a], v[p] - v[a]);
                let (g11, g12, g22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
                let (h1, h2) = (w.dot(e1), w.dot(e2));
                let det = g11 * g22 - g12 * g12;
                let u = (g22 * h1 - g12 * h2) / det;
                let t = (g11 * h2 - g12 * h1) / det;
                let n = e1.cross(e2);
                f.r = (w.dot(n) / n.length_squared()) * n;
                // r = x_p - x_a - u (x_b - x_a) - t (x_c - x_a).
                f.c[p] = 1.0;
                f.c[a] = -(1.0 - u - t);
                f.c[b] = -u;
                f.c[c] = -t;
                f.m = 2;
                f.a[0][a] = 1.0;
                f.a[0][b] = -1.0;
                f.a[1][a] = 1.0;
                f.a[1][c] = -1.0;
                f.e = [-e1, -e2];
            }
            Closest::LineLine([a0, a1, b0, b1]) => {
                let (ea, eb, w) = (v[a1] - v[a0], v[b1] - v[b0], v[a0] - v[b0]);
                let (aa, ab, bb) = (ea.dot(ea), ea.dot(eb), eb.dot(eb));
                let (d, e) = (ea.dot(w), eb.dot(w));
                let det = aa * bb - ab * ab;
                let s = (ab * e - bb * d) / det;
                let t = (aa * e - ab * d) / det;
                let n = ea.cross(eb);
                f.r = (w.dot(n) / n.length_squared()) * n;
                // r = x_a0 + s (x_a1 - x_a0) - x_b0 - t (x_b1 - x_b0).
                f.c[a0] = 1.0 - s;
                f.c[a1] = s;
                f.c[b0] = -(1.0 - t);
                f.c[b1] = -t;
                f.m = 2;
                f.a[0][a0] = -1.0;
                f.a[0][a1] = 1.0;
                f.a[1][b0] = 1.0;
                f.a[1][b1] = -1.0;
                f.e = [ea, -eb];
            }
        }
        f
    }

    /// The form of the pair `v` of kind `kind` in the region of its closest points.
    #[must_use]
    pub fn of(kind: PairKind, v: &[DVec3; 4]) -> Self {
        Self::new(v, kind.closest(v))
    }

    /// The squared distance `|r|^2`.
    #[must_use]
    pub fn value(&self) -> f64 {
        self.r.length_squared()
    }

    /// The gradient `2 c (x) r` (vertex `k`'s coordinates at `3k..3k + 3`).
    #[must_use]
    pub fn gradient(&self) -> [f64; 12] {
        std::array::from_fn(|i| 2.0 * self.c[i / 3] * self.r[i % 3])
    }

    /// `M^-1`, `M = 2 E^T E` (the leading `m x m` block; the rest is zero).
    fn m_inverse(&self) -> [[f64; 2]; 2] {
        let [e0, e1] = self.e;
        match self.m {
            0 => [[0.0; 2]; 2],
            1 => [[0.5 / e0.length_squared(), 0.0], [0.0, 0.0]],
            _ => {
                let (p, q, s) = (e0.dot(e0), e0.dot(e1), e1.dot(e1));
                let k = 0.5 / (p * s - q * q);
                [[k * s, -k * q], [-k * q, k * p]]
            }
        }
    }

    /// The exact Hessian `2 (c c^T) (x) I_3 - J^T M^-1 J` in full.
    // Index loops over rows and columns read as the matrix formulas they implement.
    #[allow(clippy::needless_range_loop)]
    #[must_use]
    pub fn hessian(&self) -> Mat12 {
        let minv = self.m_inverse();
        let j: [[f64; 12]; 2] = std::array::from_fn(|row| {
            std::array::from_fn(|i| {
                let (k, x) = (i / 3, i % 3);
                2.0 * (self.a[row][k] * self.r[x] + self.c[k] * self.e[row][x])
            })
        });
        let mut h = [[0.0; 12]; 12];
        for i in 0..12 {
            for l in 0..12 {
                let mut v = if i % 3 == l % 3 {
                    2.0 * self.c[i / 3] * self.c[l / 3]
                } else {
                    0.0
                };
                for p in 0..self.m {
                    for q in 0..self.m {
                        v -= j[p][i] * minv[p][q] * j[q][l];
                    }
                }
                h[i][l] = v;
            }
        }
        h
    }

    /// The positive semidefinite projection of the Hessian of `phi(s)` at this pair,
    /// `second grad s grad s^T + first hess s` with `first = phi'(s)` and
    /// `second = phi''(s)`, computed in the span of the module documentation. `None`
    /// when the pair is degenerate (`r = 0`, or a region's parametrization singular), so
    /// the caller can fall back to the full decomposition.
    #[must_use]
    pub fn projected_hessian(&self, first: f64, second: f64) -> Option<Mat12> {
        let mut out = [[0.0; 12]; 12];
        self.projected_hessian_into(first, second, &mut out)
            .then_some(out)
    }

    /// [`Self::projected_hessian`] written into `out` (every entry overwritten): true when
    /// written, false (with `out` unspecified) when the pair is degenerate.
    pub fn projected_hessian_into(&self, first: f64, second: f64, out: &mut Mat12) -> bool {
        self.span_hessian_into(first, second, true, out)
    }

    /// The exact Hessian of `phi(s)` at this pair, `second grad s grad s^T + first hess s`
    /// (indefinite in general: a point-plane or line-line pair has at least two negative
    /// eigenvalues where `first > 0`), computed as `B K B^T` in the span of the module
    /// documentation, without the eigen-decomposition of `K` the projection needs.
    /// `None` for the pairs [`Self::projected_hessian`] declines (the same test), so a
    /// caller takes the same path for a pair whichever form it asks for.
    #[must_use]
    pub fn exact_hessian(&self, first: f64, second: f64) -> Option<Mat12> {
        let mut out = [[0.0; 12]; 12];
        self.exact_hessian_into(first, second, &mut out)
            .then_some(out)
    }

    /// [`Self::exact_hessian`] written into `out` (every entry overwritten): true when
    /// written, false (with `out` unspecified) when the pair is degenerate.
    pub fn exact_hessian_into(&self, first: f64, second: f64, out: &mut Mat12) -> bool {
        self.span_hessian_into(first, second, false, out)
    }

    /// `B K_+ B^T` when `project`, else `B K B^T` (see the module documentation).
    fn span_hessian_into(&self, first: f64, second: f64, project: bool, out: &mut Mat12) -> bool {
        match self.span(first, second) {
            Some(span) => {
                span.hessian_into(project, out);
                true
            }
            None => false,
        }
    }

    /// The Hessian of `phi(s)` in the coordinates of the span's orthonormal basis (the
    /// module documentation), with what the basis is built from; `None` when the pair is
    /// degenerate (`r = 0`, a region's parametrization singular) or `K` is not finite.
    // Index loops over rows and columns read as the matrix formulas they implement.
    #[allow(clippy::needless_range_loop)]
    pub(crate) fn span(&self, first: f64, second: f64) -> Option<Span> {
        let Basis {
            c_len,
            r_len,
            c_hat,
            r_hat,
            b,
        } = self.basis()?;
        let n = 3 + self.m;
        // The coordinates in the basis of grad s (U part 2 |c| r) and of the rows of J
        // (U part 2 ((a_j . c_hat) r + |c| e_j), V part 2 |r| (a_j . b_l)).
        let mut grad = [0.0; SPAN];
        for x in 0..3 {
            grad[x] = 2.0 * c_len * self.r[x];
        }
        let mut jrows = [[0.0; SPAN]; 2];
        for j in 0..self.m {
            let ac: f64 = (0..4).map(|k| self.a[j][k] * c_hat[k]).sum();
            for x in 0..3 {
                jrows[j][x] = 2.0 * (ac * self.r[x] + c_len * self.e[j][x]);
            }
            for l in 0..self.m {
                let ab: f64 = (0..4).map(|k| self.a[j][k] * b[l][k]).sum();
                jrows[j][3 + l] = 2.0 * r_len * ab;
            }
        }
        let minv = self.m_inverse();
        let mut k = [[0.0; SPAN]; SPAN];
        for p in 0..n {
            for q in 0..n {
                let mut hess_s = if p == q && p < 3 {
                    2.0 * c_len * c_len
                } else {
                    0.0
                };
                for i in 0..self.m {
                    for j in 0..self.m {
                        hess_s -= jrows[i][p] * minv[i][j] * jrows[j][q];
                    }
                }
                k[p][q] = second * grad[p] * grad[q] + first * hess_s;
            }
        }
        if !k.iter().flatten().all(|x| x.is_finite()) {
            return None;
        }
        Some(Span {
            k,
            n,
            c_hat,
            r_hat,
            b,
        })
    }
}

/// What [`RegionForm::span`] builds its basis from: `|c|`, `|r|`, `c / |c|`, `r / |r|`
/// and the `b_l`, the `a_j` orthonormalized against `c / |c|` and each other.
struct Basis {
    c_len: f64,
    r_len: f64,
    c_hat: [f64; 4],
    r_hat: DVec3,
    b: [[f64; 4]; 2],
}

/// The bound below which every factor of `K` keeps its products finite. With every
/// factor below it (and the unit vectors' components at most 1), a row of `J` is below
/// `1e61`, so `second grad grad^T` is below `4e150` and `first J^T M^-1 J` (four
/// terms) below `4e182`: `K` is finite, far from the largest `f64` (about `1.8e308`).
const FACTOR_BOUND: f64 = 1e30;

impl RegionForm {
    /// [`RegionForm::span`]'s basis, `None` when the pair is degenerate (`r = 0`, or a
    /// region's parametrization singular).
    // Index loops over the four weights read as the formulas they implement.
    #[allow(clippy::needless_range_loop)]
    fn basis(&self) -> Option<Basis> {
        let c_len = self.c.iter().map(|c| c * c).sum::<f64>().sqrt();
        let r_len = self.r.length();
        if !(c_len > 0.0 && r_len > 0.0 && c_len.is_finite() && r_len.is_finite()) {
            return None;
        }
        let c_hat = self.c.map(|c| c / c_len);
        let r_hat = self.r / r_len;
        // b_l: Gram-Schmidt of the a_j against c_hat and each other.
        let mut b = [[0.0; 4]; 2];
        let remove = |v: &mut [f64; 4], u: &[f64; 4]| {
            let d: f64 = (0..4).map(|k| v[k] * u[k]).sum();
            (0..4).for_each(|k| v[k] -= d * u[k]);
        };
        for j in 0..self.m {
            let mut v = self.a[j];
            remove(&mut v, &c_hat);
            for l in 0..j {
                let u = b[l];
                remove(&mut v, &u);
            }
            let len = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            if !(len > 0.0 && len.is_finite()) {
                return None;
            }
            b[j] = v.map(|x| x / len);
        }
        Some(Basis {
            c_len,
            r_len,
            c_hat,
            r_hat,
            b,
        })
    }

    /// Whether [`Self::span`] certainly returns `Some` for `first` and `second`, decided
    /// without building `K`: the basis exists, and every factor `K` is built from (the
    /// weights and vectors of the form, `|c|`, `|r|`, `M^-1`, `first` and `second`) is
    /// finite and below [`FACTOR_BOUND`], so no entry of `K` can overflow or be NaN. A
    /// caller that has the gradient now and may want the Hessian later keeps the inputs
    /// and builds the span then, the same function of the same numbers.
    pub(crate) fn spans_certainly(&self, first: f64, second: f64) -> bool {
        let small = |x: f64| x.abs() < FACTOR_BOUND;
        let Some(basis) = self.basis() else {
            return false;
        };
        let minv = self.m_inverse();
        small(first)
            && small(second)
            && small(basis.c_len)
            && small(basis.r_len)
            && self.c.iter().all(|&x| small(x))
            && self.a.iter().flatten().all(|&x| small(x))
            && self
                .e
                .iter()
                .all(|e| e.to_array().iter().all(|&x| small(x)))
            && self.r.to_array().iter().all(|&x| small(x))
            && minv.iter().flatten().all(|&x| small(x))
    }
}

/// IPC's mollifier of an edge pair below its threshold, in closed form. With
/// `u = x_1 - x_0`, `w = x_3 - x_2` and `c = |u x w|^2`, the mollifier is `m = (2 - y) y`,
/// `y = c / eps_x` (1 from `c = eps_x` on, see [`super::distance::mollifier_in`]). Its
/// derivatives in `c` are `m' = 2 (1 - y) / eps_x` and `m'' = -2 / eps_x^2`; those of `c`
/// in `u` and `w` are `2 w x (u x w)` and `2 (u x w) x u`, and its Hessian's blocks
///
/// `c_uu = 2 |w|^2 I - 2 w w^T`, `c_ww = 2 |u|^2 I - 2 u u^T`,
/// `c_uw = 4 u w^T - 2 w u^T - 2 (u . w) I` (entry `(i, j)` is `d^2 c / du_i dw_j`),
///
/// vertex `k`'s coordinates entering `u` or `w` with the sign `-1, +1, -1, +1`
/// (docs/contact.md, "The mollified pairs in closed form").
#[derive(Clone, Copy, Debug)]
pub(crate) struct Mollifier {
    /// `m`.
    pub(crate) value: f64,
    /// `m'(c)`.
    first: f64,
    /// `m''(c)`.
    second: f64,
    u: DVec3,
    w: DVec3,
    /// `u x w`.
    n: DVec3,
}

/// The sign with which vertex `k`'s coordinates enter `u` (`k` = 0, 1) or `w` (2, 3).
const EDGE_SIGN: [f64; 4] = [-1.0, 1.0, -1.0, 1.0];

impl Mollifier {
    /// The mollifier of the edge pair `v` when it is below its threshold `eps_x` (the
    /// same `c`, computed the same way, as [`super::distance::mollifier`]'s, so the two
    /// agree on which pairs are mollified); `None` where it is identically 1.
    #[must_use]
    pub(crate) fn below(v: &[DVec3; 4], eps_x: f64) -> Option<Self> {
        let (u, w) = (v[1] - v[0], v[3] - v[2]);
        let n = u.cross(w);
        let c = n.length_squared();
        if c.is_nan() || c >= eps_x {
            return None;
        }
        let y = c * (1.0 / eps_x);
        Some(Self {
            value: (2.0 - y) * y,
            first: 2.0 * (1.0 - y) / eps_x,
            second: -2.0 / (eps_x * eps_x),
            u,
            w,
            n,
        })
    }

    /// The gradient of `c` (vertex `k`'s coordinates at `3k..3k + 3`).
    fn c_gradient(&self) -> [f64; 12] {
        let (du, dw) = (2.0 * self.w.cross(self.n), 2.0 * self.n.cross(self.u));
        std::array::from_fn(|i| {
            let k = i / 3;
            let d = if k < 2 { du } else { dw };
            EDGE_SIGN[k] * d[i % 3]
        })
    }

    /// The Hessian of `c` in the `(u, w)` blocks: `[c_uu, c_uw, c_ww]`.
    fn c_blocks(&self) -> [[[f64; 3]; 3]; 3] {
        let (u, w) = (self.u.to_array(), self.w.to_array());
        let (uu, ww, uw) = (self.u.dot(self.u), self.w.dot(self.w), self.u.dot(self.w));
        let delta = |i: usize, j: usize| if i == j { 1.0 } else { 0.0 };
        [
            std::array::from_fn(|i| {
                std::array::from_fn(|j| 2.0 * ww * delta(i, j) - 2.0 * w[i] * w[j])
            }),
            std::array::from_fn(|i| {
                std::array::from_fn(|j| {
                    4.0 * u[i] * w[j] - 2.0 * w[i] * u[j] - 2.0 * uw * delta(i, j)
                })
            }),
            std::array::from_fn(|i| {
                std::array::from_fn(|j| 2.0 * uu * delta(i, j) - 2.0 * u[i] * u[j])
            }),
        ]
    }

    /// The gradient of `m phi(s)` for the pair whose squared distance has the form
    /// `form`, with `phi` the barrier's value and `first = phi'(s)`:
    /// `m phi' grad s + phi m' grad c`.
    #[must_use]
    pub(crate) fn gradient(&self, form: &RegionForm, phi: f64, first: f64) -> [f64; 12] {
        let (gs, gc) = (form.gradient(), self.c_gradient());
        let (a, b) = (self.value * first, phi * self.first);
        std::array::from_fn(|i| a * gs[i] + b * gc[i])
    }

    /// The exact Hessian of `m phi(s)` (`second = phi''(s)`):
    ///
    /// `m (phi'' grad s grad s^T + phi' hess s) + phi (m'' grad c grad c^T + m' hess c)
    ///  + phi' m' (grad s grad c^T + grad c grad s^T)`.
    // Index loops over rows and columns read as the matrix formulas they implement.
    #[allow(clippy::needless_range_loop)]
    #[must_use]
    pub(crate) fn hessian(&self, form: &RegionForm, phi: f64, first: f64, second: f64) -> Mat12 {
        let mut h = form.hessian();
        let (gs, gc) = (form.gradient(), self.c_gradient());
        let blocks = self.c_blocks();
        let (mss, ms, pcc, pc, cross) = (
            self.value * second,
            self.value * first,
            phi * self.second,
            phi * self.first,
            first * self.first,
        );
        for i in 0..12 {
            for l in 0..12 {
                let (ki, kl) = (i / 3, l / 3);
                // The (u, w) block the two vertices' coordinates fall in.
                let hc = match (ki < 2, kl < 2) {
                    (true, true) => blocks[0][i % 3][l % 3],
                    (true, false) => blocks[1][i % 3][l % 3],
                    (false, true) => blocks[1][l % 3][i % 3],
                    (false, false) => blocks[2][i % 3][l % 3],
                };
                let hc = EDGE_SIGN[ki] * EDGE_SIGN[kl] * hc;
                h[i][l] = mss * gs[i] * gs[l]
                    + ms * h[i][l]
                    + pcc * gc[i] * gc[l]
                    + pc * hc
                    + cross * (gs[i] * gc[l] + gc[i] * gs[l]);
            }
        }
        h
    }
}

/// [`RegionForm::span`]'s result: `K` (leading `n x n`), `c / |c|`, `r / |r|` and the
/// orthonormalized `b_l`; all a pair's Hessian needs, so a caller that has the gradient
/// now and may want the Hessian later keeps this instead of the region's form.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Span {
    k: [[f64; SPAN]; SPAN],
    n: usize,
    c_hat: [f64; 4],
    r_hat: DVec3,
    b: [[f64; 4]; 2],
}

impl Span {
    /// `B K_+ B^T` into `out` when `project`, else `B K B^T` (every entry overwritten).
    pub(crate) fn hessian_into(&self, project: bool, out: &mut Mat12) {
        let f = self.factors(project);
        for i in 0..4 {
            for j in 0..=i {
                let block = f.lower_block(i, j);
                for (y, row) in block.iter().enumerate() {
                    // A diagonal block gives its lower entries, mirrored like the rest.
                    let columns = if i == j { y + 1 } else { 3 };
                    for (x, &v) in row.iter().enumerate().take(columns) {
                        out[3 * i + y][3 * j + x] = v;
                        out[3 * j + x][3 * i + y] = v;
                    }
                }
            }
        }
    }

    /// [`Self::hessian_into`]'s blocks that a pair adds to the matrix into `out`: each
    /// entry the same bits as the full matrix's (the same products), without the other
    /// half of the matrix.
    pub(crate) fn blocks_into(&self, project: bool, out: &mut PairBlocks) {
        let f = self.factors(project);
        for (k, d) in out.diagonal.iter_mut().enumerate() {
            // The lower entries (r >= c) of the diagonal block, column by column.
            let block = f.lower_block(k, k);
            let mut n = 0;
            for c in 0..3 {
                for row in &block[c..] {
                    d[n] = row[c];
                    n += 1;
                }
            }
        }
        for (n, &(a, b)) in PAIR_BLOCKS.iter().enumerate() {
            // Block (a, b), a < b, sits above the diagonal: entry (x, y) is the computed
            // lower entry (3b + y, 3a + x).
            let block = f.lower_block(b, a);
            out.coupling[n] = std::array::from_fn(|e| block[e / 3][e % 3]);
        }
    }

    /// `K_+` (`project`) or `K`: the Hessian in the span's coordinates.
    // Index loops over rows and columns read as the matrix formulas they implement.
    #[allow(clippy::needless_range_loop)]
    fn reduced(&self, project: bool) -> [[f64; SPAN]; SPAN] {
        let (k, n) = (self.k, self.n);
        if !project {
            return k;
        }
        let (values, vectors) = symmetric_eigen_n(&k, n);
        // K_+ = Q diag(max(lambda, 0)) Q^T in the reduced coordinates.
        let mut kp = [[0.0; SPAN]; SPAN];
        for (e, &lambda) in values.iter().take(n).enumerate() {
            if lambda <= 0.0 {
                continue;
            }
            for p in 0..n {
                for q in 0..n {
                    kp[p][q] += lambda * vectors[p][e] * vectors[q][e];
                }
            }
        }
        kp
    }

    /// What the Hessian's 3x3 blocks are made of: [`Self::reduced`] split along the
    /// basis' two kinds of columns (see [`Factors`]).
    // Index loops over rows and columns read as the matrix formulas they implement.
    #[allow(clippy::needless_range_loop)]
    fn factors(&self, project: bool) -> Factors {
        let (m, b) = (self.n - 3, self.b);
        let kp = self.reduced(project);
        let mut uu = [[0.0; 3]; 3];
        for (y, row) in uu.iter_mut().enumerate() {
            row.copy_from_slice(&kp[y][..3]);
        }
        // Per vertex a: g_a = K_UV beta_a and t_a = K_VV beta_a, beta_a = (b_l[a])_l.
        let mut g = [[0.0; 3]; 4];
        let mut t = [[0.0; 2]; 4];
        let mut beta = [[0.0; 2]; 4];
        for a in 0..4 {
            for l in 0..m {
                beta[a][l] = b[l][a];
            }
            for y in 0..3 {
                g[a][y] = (0..m).map(|l| kp[y][3 + l] * beta[a][l]).sum();
            }
            for l in 0..m {
                t[a][l] = (0..m).map(|q| kp[3 + l][3 + q] * beta[a][q]).sum();
            }
        }
        Factors {
            uu,
            c: self.c_hat,
            g,
            t,
            beta,
            r: self.r_hat.to_array(),
        }
    }
}

/// [`Span::factors`]. The basis is a Kronecker product: vertex `a`'s rows of its columns
/// are `c_a I_3` (the three `c_hat (x) e_p`) and `r_hat beta_a^T` (the `b_l (x) r_hat`,
/// `beta_a = (b_l[a])_l`). So the Hessian's block `(a, b)` of `B K B^T` is
///
/// `c_a c_b K_UU + c_a (K_UV beta_b) r_hat^T + c_b r_hat (K_UV beta_a)^T
///  + (beta_a . K_VV beta_b) r_hat r_hat^T`,
///
/// a few operations per entry, where the product through the 12 x 5 basis took two
/// sums of five per entry.
struct Factors {
    /// `K_UU`, the span's leading 3x3.
    uu: [[f64; 3]; 3],
    /// `c_hat`.
    c: [f64; 4],
    /// `K_UV beta_a` per vertex.
    g: [[f64; 3]; 4],
    /// `K_VV beta_a` per vertex.
    t: [[f64; 2]; 4],
    /// `beta_a` per vertex (zero beyond the span's `m`).
    beta: [[f64; 2]; 4],
    /// `r_hat`.
    r: [f64; 3],
}

impl Factors {
    /// The Hessian's block `(i, j)`, `i >= j`: entry `[y][x]` is the matrix's
    /// `(3 i + y, 3 j + x)`.
    #[inline]
    fn lower_block(&self, i: usize, j: usize) -> [[f64; 3]; 3] {
        let (ci, cj) = (self.c[i], self.c[j]);
        let (gi, gj, r) = (self.g[i], self.g[j], self.r);
        let s = self.beta[i][0] * self.t[j][0] + self.beta[i][1] * self.t[j][1];
        let cc = ci * cj;
        std::array::from_fn(|y| {
            std::array::from_fn(|x| {
                cc * self.uu[y][x] + ci * gj[y] * r[x] + cj * r[y] * gi[x] + s * r[y] * r[x]
            })
        })
    }
}

/// The four particles' pairs of a pair's coupling blocks, in the order
/// [`PairBlocks::coupling`] and the term write them.
pub(crate) const PAIR_BLOCKS: [(usize, usize); 6] =
    [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];

/// The blocks of a pair's 12x12 Hessian that its assembly adds: the lower entries of
/// the four diagonal blocks (`(0,0), (1,0), (2,0), (1,1), (2,1), (2,2)`) and the six
/// coupling blocks `(a, b)`, `a < b`, of [`PAIR_BLOCKS`] (entry `(r, c)` at `3 c + r`).
/// 78 numbers where the matrix has 144: the half a term writes and reads back.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PairBlocks {
    pub(crate) diagonal: [[f64; 6]; 4],
    pub(crate) coupling: [[f64; 9]; 6],
}

impl Default for PairBlocks {
    fn default() -> Self {
        Self {
            diagonal: [[0.0; 6]; 4],
            coupling: [[0.0; 9]; 6],
        }
    }
}

impl PairBlocks {
    /// The blocks of the full matrix `h` (the entries [`Span::blocks_into`] writes).
    pub(crate) fn from_matrix(h: &Mat12) -> Self {
        let mut out = Self::default();
        for (k, d) in out.diagonal.iter_mut().enumerate() {
            let mut n = 0;
            for c in 0..3 {
                for r in c..3 {
                    d[n] = h[3 * k + r][3 * k + c];
                    n += 1;
                }
            }
        }
        for (n, &(a, b)) in PAIR_BLOCKS.iter().enumerate() {
            out.coupling[n] = std::array::from_fn(|e| {
                let (c, r) = (e / 3, e % 3);
                h[3 * a + r][3 * b + c]
            });
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Coordinates from the additive recurrence of the golden ratio (a Weyl sequence):
    /// spread over [-1, 1) without a generator's state.
    fn weyl() -> impl FnMut() -> f64 {
        let mut index = 0u32;
        move || {
            index += 1;
            (f64::from(index) * 0.618_033_988_749_894_9).fract() * 2.0 - 1.0
        }
    }

    /// The blocks a pair adds, written straight from its span, are the entries of its
    /// full Hessian (`B K B^T` and `B K_+ B^T`) bit for bit, for random pairs of both
    /// kinds (every region the random states fall in) and both signs of the barrier's
    /// second derivative.
    #[test]
    fn a_pairs_blocks_are_its_full_hessians_entries_bit_for_bit() {
        let mut next = weyl();
        let mut compared = 0;
        for n in 0..400 {
            let kind = if n % 2 == 0 {
                PairKind::PointTriangle
            } else {
                PairKind::EdgeEdge
            };
            let p: [DVec3; 4] = std::array::from_fn(|_| DVec3::new(next(), next(), next()));
            let (first, second) = (next() * 3.0, next() * 50.0);
            let Some(span) = RegionForm::new(&p, kind.closest(&p)).span(first, second) else {
                continue;
            };
            for project in [false, true] {
                let mut full = [[f64::NAN; 12]; 12];
                span.hessian_into(project, &mut full);
                let mut blocks = PairBlocks::default();
                span.blocks_into(project, &mut blocks);
                let want = PairBlocks::from_matrix(&full);
                let bits = |b: &PairBlocks| {
                    let d = b.diagonal.iter().flatten();
                    d.chain(b.coupling.iter().flatten())
                        .map(|v| v.to_bits())
                        .collect::<Vec<_>>()
                };
                assert_eq!(bits(&blocks), bits(&want), "pair {n}, project {project}");
                // The coupling blocks are the matrix's upper blocks, whose transposes
                // are its lower ones.
                for (k, &(a, b)) in PAIR_BLOCKS.iter().enumerate() {
                    for (e, &v) in blocks.coupling[k].iter().enumerate() {
                        let (c, r) = (e / 3, e % 3);
                        assert_eq!(v.to_bits(), full[3 * b + c][3 * a + r].to_bits());
                    }
                }
                compared += 1;
            }
        }
        assert!(compared > 700, "only {compared} spans compared");
    }

    /// The blocks from the basis' Kronecker form are `B K B^T` and `B K_+ B^T` computed
    /// through the whole 12 x n basis (written out here, entry by entry), to round-off
    /// of the largest entry, for random pairs of both kinds, every region the random
    /// states fall in, and barrier derivatives of both signs over four decades.
    #[test]
    fn the_blocks_of_the_kronecker_form_are_the_product_through_the_whole_basis() {
        let mut next = weyl();
        let (mut compared, mut worst) = (0, 0.0f64);
        let mut spans = [0; 3];
        for n in 0..600 {
            let kind = if n % 2 == 0 {
                PairKind::PointTriangle
            } else {
                PairKind::EdgeEdge
            };
            let mut p: [DVec3; 4] = std::array::from_fn(|_| DVec3::new(next(), next(), next()));
            if n % 4 == 2 {
                // The point in the Voronoi region of the triangle's first vertex (a
                // point-point pair, span 3).
                let out = (p[1] - p[2]).normalize() + (p[1] - p[3]).normalize();
                p[0] = p[1] + (0.5 + next().abs()) * out;
            }
            let magnitude = [1e-2, 1.0, 1e2][n % 3];
            let (first, second) = (next() * magnitude, next() * 50.0 * magnitude);
            let Some(span) = RegionForm::new(&p, kind.closest(&p)).span(first, second) else {
                continue;
            };
            spans[span.n - 3] += 1;
            let basis: [[f64; SPAN]; 12] = std::array::from_fn(|i| {
                let (vk, x) = (i / 3, i % 3);
                let mut row = [0.0; SPAN];
                row[x] = span.c_hat[vk];
                for l in 0..span.n - 3 {
                    row[3 + l] = span.b[l][vk] * span.r_hat[x];
                }
                row
            });
            for project in [false, true] {
                let k = span.reduced(project);
                let mut want = [[0.0; 12]; 12];
                for (i, row) in want.iter_mut().enumerate() {
                    for (l, v) in row.iter_mut().enumerate() {
                        for p in 0..span.n {
                            for q in 0..span.n {
                                *v += basis[i][p] * k[p][q] * basis[l][q];
                            }
                        }
                    }
                }
                let mut got = [[f64::NAN; 12]; 12];
                span.hessian_into(project, &mut got);
                let scale = want.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
                for i in 0..12 {
                    for l in 0..12 {
                        // A projection of a negative definite K is zero, entry by entry.
                        let error = (got[i][l] - want[i][l]).abs() / scale.max(f64::MIN_POSITIVE);
                        assert!(
                            error <= 1e-14,
                            "pair {n}, project {project}: entry ({i}, {l}) {} against {}",
                            got[i][l],
                            want[i][l]
                        );
                        worst = worst.max(error);
                    }
                }
                compared += 1;
            }
        }
        assert!(compared > 1000, "only {compared} spans compared");
        // Every span size the regions give: point-point 3, point-edge 4, the rest 5.
        assert!(spans.iter().all(|&s| s > 0), "span sizes seen: {spans:?}");
        assert!(
            worst > 0.0,
            "no round-off at all: the oracle is not independent"
        );
    }

    /// The closed-form gradient and Hessian of a mollified edge pair's `m phi(s)` are the
    /// dual numbers' (the distance and the mollifier over [`crate::contact::self_contact::Dual12`],
    /// multiplied), to round-off of the largest entry: nearly parallel edge pairs in
    /// every region the random states fall in, the mollifier from nearly 0 to nearly 1,
    /// and barrier derivatives of both signs over four decades.
    #[test]
    fn a_mollified_pairs_closed_derivatives_are_the_dual_numbers() {
        use super::super::distance::{
            mollifier, mollifier_derivatives, squared_distance_derivatives,
        };
        let mut next = weyl();
        let mut compared = 0;
        // The line-line form's round-off grows as 1 / sin^2 of the edges' angle (in both
        // computations), so the tolerance does too: 1e-16 / angle^2, at least 1e-12.
        let mut worst_by_angle = [0.0f64; 4];
        let mut regions = [0; 4];
        for n in 0..800 {
            let p0 = DVec3::new(next(), next(), next());
            let u = DVec3::new(next(), next(), next());
            // The second edge nearly parallel to the first: turned off it by an angle
            // from 1e-4 to 0.1 rad, placed near it (overlapping, beside or beyond its end).
            let side = DVec3::new(next(), next(), next())
                .cross(u)
                .normalize_or_zero()
                * u.length();
            let angle = [1e-4, 1e-3, 1e-2, 0.1][n % 4] * (0.5 + next().abs());
            let w = (u + angle * side) * (0.5 + next().abs());
            let p2 = p0 + DVec3::new(next(), next(), next()) * 0.3 + u * (next() * 1.2);
            let p = [p0, p0 + u, p2, p2 + w];
            let closest = PairKind::EdgeEdge.closest(&p);
            let form = RegionForm::new(&p, closest);
            // A threshold above c, so the pair is mollified (m from about 0 to about 1).
            let c = u.cross(w).length_squared();
            let eps = c / [0.999, 0.5, 0.1, 1e-3][(n / 4) % 4];
            let Some(moll) = Mollifier::below(&p, eps) else {
                panic!("pair {n}: c {c} below eps {eps}, yet not mollified");
            };
            assert_eq!(
                moll.value.to_bits(),
                mollifier(&p, eps).to_bits(),
                "pair {n}"
            );
            if form.basis().is_none() {
                continue;
            }
            let magnitude = [1e-2, 1.0, 1e2][n % 3];
            let (phi, first, second) = (
                next().abs() * magnitude,
                next() * magnitude,
                next() * 50.0 * magnitude,
            );
            let want = mollifier_derivatives(&p, eps)
                * squared_distance_derivatives(PairKind::EdgeEdge, &p).chain(phi, first, second);
            let tolerance = (1e-16 / (angle * angle)).max(1e-12);
            let gradient = moll.gradient(&form, phi, first);
            let hessian = moll.hessian(&form, phi, first, second);
            let g_scale = want.gradient.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (i, (&got, &w)) in gradient.iter().zip(&want.gradient).enumerate() {
                let error = (got - w).abs() / g_scale.max(f64::MIN_POSITIVE);
                assert!(
                    error <= tolerance,
                    "pair {n}: gradient {i}: {got} against {w}"
                );
                worst_by_angle[n % 4] = worst_by_angle[n % 4].max(error);
            }
            let h_scale = want
                .hessian
                .iter()
                .flatten()
                .fold(0.0f64, |m, v| m.max(v.abs()));
            for (i, (row, want_row)) in hessian.iter().zip(&want.hessian).enumerate() {
                for (l, (&got, &w)) in row.iter().zip(want_row).enumerate() {
                    let error = (got - w).abs() / h_scale.max(f64::MIN_POSITIVE);
                    assert!(
                        error <= tolerance,
                        "pair {n}: Hessian ({i}, {l}): {got} against {w}"
                    );
                    worst_by_angle[n % 4] = worst_by_angle[n % 4].max(error);
                }
            }
            regions[match closest {
                Closest::PointPoint(_) => 0,
                Closest::PointEdge(_) => 1,
                Closest::PointPlane(_) => 2,
                Closest::LineLine(_) => 3,
            }] += 1;
            compared += 1;
        }
        let worst = worst_by_angle.iter().fold(0.0f64, |m, &w| m.max(w));
        assert!(compared > 600, "only {compared} pairs compared");
        // Edge pairs have no point-plane region; every other one is seen.
        assert!(
            regions[0] > 0 && regions[1] > 0 && regions[3] > 0,
            "regions seen: {regions:?}"
        );
        assert!(
            worst > 0.0,
            "no round-off at all: the oracle is not independent"
        );
    }

    /// Where `spans_certainly` holds, `span` gives a span (the caller then builds it only
    /// when a Hessian is asked for): over random pairs of both kinds at unit scale, the
    /// same pairs scaled up to 1e20 and 1e100 (where it may not hold, and `K` may
    /// overflow), degenerate pairs (a point on the triangle's plane, parallel edges,
    /// coincident vertices) and barrier derivatives from 1e-3 to 1e150.
    #[test]
    fn a_span_certain_from_its_inputs_is_built() {
        let mut next = weyl();
        let (mut certain, mut declined, mut uncertain_built) = (0, 0, 0);
        for n in 0..600 {
            let kind = if n % 2 == 0 {
                PairKind::PointTriangle
            } else {
                PairKind::EdgeEdge
            };
            let scale = [1.0, 1e20, 1e100][n % 3];
            let mut p: [DVec3; 4] =
                std::array::from_fn(|_| scale * DVec3::new(next(), next(), next()));
            match n % 7 {
                // The point in the triangle's plane, or the second edge parallel to the
                // first.
                0 => p[0] = 0.25 * (p[1] + p[2]) + 0.5 * p[3],
                1 => p[3] = p[2] + 2.0 * (p[1] - p[0]),
                2 => p[1] = p[0],
                _ => {}
            }
            let magnitude = [1e-3, 1.0, 1e10, 1e28, 1e150][n % 5];
            let (first, second) = (next() * magnitude, next() * magnitude);
            let form = RegionForm::new(&p, kind.closest(&p));
            let span = form.span(first, second);
            if form.spans_certainly(first, second) {
                assert!(span.is_some(), "pair {n}: certain, but no span");
                certain += 1;
            } else if span.is_some() {
                uncertain_built += 1;
            } else {
                declined += 1;
            }
        }
        assert!(certain > 150, "only {certain} certain");
        assert!(
            declined > 0 && uncertain_built > 0,
            "{declined} declined, {uncertain_built} built without certainty"
        );
    }
}
