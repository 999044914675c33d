//! Arc length to a stated absolute tolerance, and its inverse, from a table built once.
//!
//! [`ArcLengthTable::new`] splits the domain at the curve's break points (cusps, corners;
//! [`ParamCurveDeriv::breaks`]), so the speed is smooth on every piece, then covers each
//! piece with panels. On each panel the speed is interpolated by a Chebyshev polynomial of
//! degree [`DEGREE`] at the Chebyshev-Lobatto points (Clenshaw-Curtis quadrature, as in
//! Trefethen, "Approximation Theory and Approximation Practice", ch. 3, 8 and 19), and
//! the polynomial is integrated exactly, which gives a polynomial `S(t)` for the arc length
//! inside the panel. Panels are refined globally (the one with the largest error bound is
//! halved) until the sum of the panel error bounds is at most the tolerance.
//!
//! What the tolerance bounds: for every `t` in the domain,
//! `|arc_length_at(t) - s(t)| <= tolerance` (so in particular the length), where `s` is
//! the exact arc length of the curve's `speed` function. Each panel's error bound is
//! `(b - a) * 2 * sum_{j = D/2+1}^{D} |c_j|`, the sum of the upper half of the
//! interpolant's Chebyshev coefficients: for a speed analytic on the panel, whose
//! coefficients decay geometrically, this exceeds the true interpolation error
//! `2 sum_{j > D} |c_j|` by a factor of at least `rho^{D/2} - 1` (docs/curves.md).
//! An estimate of rounding (speed values, transform, node positions, summation) is part
//! of the bound, and refinement stops on the same sum the final check tests; when the
//! rounding alone exceeds the tolerance the table refuses. For epicycloids and roses with
//! `k <= 16` that floor is below `2e-14` of the length (docs/curves.md).
//!
//! The inverse [`ArcParam::param_at`] finds the panel by binary search on the cumulative
//! lengths and solves `S(t) = s` inside it by Newton's method on the polynomial (whose
//! derivative is the interpolated speed), safeguarded by bisection on the panel's bracket.
//! Where the speed vanishes (the flower's cusps) Newton steps are refused and bisection
//! takes over, so the answer is always in the bracket and `S(t)` matches `s` to rounding.

use crate::error::{CurveError, positive};
use crate::traits::{ArcParam, ParamCurveDeriv};
use std::collections::BinaryHeap;
use std::f64::consts::PI;
use std::sync::OnceLock;

/// The degree of the Chebyshev interpolant of the speed on each panel.
pub const DEGREE: usize = 16;
const NODES: usize = DEGREE + 1;
/// The most panels a table may use before giving up on the tolerance.
pub const MAX_PANELS: usize = 1 << 15;
/// Panels are never narrower than this many ulps of their position.
const MIN_WIDTH_ULPS: f64 = 64.0;

/// `cos(pi i / DEGREE)` for `i` in `0..2 DEGREE`.
fn cos_table() -> &'static [f64; 2 * DEGREE] {
    static TABLE: OnceLock<[f64; 2 * DEGREE]> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut c = [0.0; 2 * DEGREE];
        for (i, v) in c.iter_mut().enumerate() {
            *v = (PI * i as f64 / DEGREE as f64).cos();
        }
        c
    })
}

/// One panel `[a, b]` with the Chebyshev series of the speed (`speed`, on `x` in
/// `[-1, 1]`, `t = mid + half x`) and of the arc length since `a` (`arc`, already scaled
/// by `half`, zero at `x = -1`).
#[derive(Clone, Debug)]
struct Panel {
    a: f64,
    b: f64,
    /// Cumulative arc length at `a`.
    s_start: f64,
    /// Arc length across the panel, `S(1)`.
    len: f64,
    /// Truncation error bound of `S` on this panel.
    bound: f64,
    /// The bound is at the rounding level of the speed values: do not split.
    converged: bool,
    /// Bound on what rounding adds to `S` on this panel.
    rounding: f64,
    speed: [f64; NODES],
    arc: [f64; NODES + 1],
    /// `S` at `x = -1 + 2k/KNOTS`, for the inverse's starting bracket and guess.
    knots: [f64; KNOTS + 1],
}

/// Sub-intervals per panel at which `S` is tabulated for the inverse.
const KNOTS: usize = 8;

/// Sums a Chebyshev series `sum c_j T_j(x)` by Clenshaw's recurrence.
#[inline]
fn clenshaw(c: &[f64], x: f64) -> f64 {
    let mut b1 = 0.0;
    let mut b2 = 0.0;
    for &cj in c[1..].iter().rev() {
        let b0 = 2.0 * x * b1 - b2 + cj;
        b2 = b1;
        b1 = b0;
    }
    x * b1 - b2 + c[0]
}

/// Sums a Chebyshev series and its derivative `(f(x), f'(x))` in one pass of Clenshaw's
/// recurrence, differentiated term by term.
#[inline]
fn clenshaw_with_derivative(c: &[f64], x: f64) -> (f64, f64) {
    let (mut b1, mut b2) = (0.0, 0.0);
    let (mut d1, mut d2) = (0.0, 0.0);
    for &cj in c[1..].iter().rev() {
        let b0 = 2.0 * x * b1 - b2 + cj;
        let d0 = 2.0 * b1 + 2.0 * x * d1 - d2;
        b2 = b1;
        b1 = b0;
        d2 = d1;
        d1 = d0;
    }
    (x * b1 - b2 + c[0], b1 + x * d1 - d2)
}

impl Panel {
    /// Samples the speed at the Chebyshev-Lobatto points of `[a, b]` and builds the
    /// series and the error bound.
    fn build<C: ParamCurveDeriv + ?Sized>(curve: &C, a: f64, b: f64) -> Self {
        let cos = cos_table();
        let mid = 0.5 * (a + b);
        let half = 0.5 * (b - a);
        let mut f = [0.0; NODES];
        let mut f_max = 0.0_f64;
        for (j, fj) in f.iter_mut().enumerate() {
            // x_j = cos(pi j / D) runs from 1 down to -1; the ends are hit exactly.
            let t = match j {
                0 => b,
                DEGREE => a,
                _ => mid + half * cos[j],
            };
            let v = curve.speed(t);
            // A non-finite speed is treated as a huge value so the panel keeps being split
            // and the table fails with ToleranceNotReached instead of returning NaN.
            *fj = if v.is_finite() { v } else { 1e300 };
            f_max = f_max.max(fj.abs());
        }
        // Discrete cosine transform (DCT-I): c_k = (2/D) sum'' f_j cos(pi j k / D).
        let mut c = [0.0; NODES];
        for (k, ck) in c.iter_mut().enumerate() {
            let mut sum = 0.5 * (f[0] + if k % 2 == 0 { f[DEGREE] } else { -f[DEGREE] });
            for (j, &fj) in f.iter().enumerate().take(DEGREE).skip(1) {
                sum += fj * cos[(j * k) % (2 * DEGREE)];
            }
            *ck = sum * 2.0 / DEGREE as f64;
        }
        c[0] *= 0.5;
        c[DEGREE] *= 0.5;

        // Integral: for k >= 1, B_k = (c_{k-1} (2 if k = 1) - c_{k+1}) / (2k); then B_0
        // makes S(-1) = 0. Scaled by `half` for dt = half dx.
        let mut arc = [0.0; NODES + 1];
        for k in 1..=NODES {
            let prev = if k == 1 { 2.0 * c[0] } else { c[k - 1] };
            let next = if k < DEGREE { c[k + 1] } else { 0.0 };
            arc[k] = half * (prev - next) / (2.0 * k as f64);
        }
        let mut at_minus_one = 0.0;
        for (k, &bk) in arc.iter().enumerate().skip(1) {
            at_minus_one += if k % 2 == 0 { bk } else { -bk };
        }
        arc[0] = -at_minus_one;
        let len: f64 = arc.iter().sum();

        // Each computed coefficient carries rounding of about eps * f_max from the speed
        // values and the transform; that part is not truncation error (halving the panel
        // cannot reduce it) and is accounted for in `rounding` below, so it is taken off
        // each coefficient before the tail is summed.
        let noise = 4.0 * f64::EPSILON * f_max;
        let tail: f64 = c[DEGREE / 2 + 1..]
            .iter()
            .map(|x| (x.abs() - noise).max(0.0))
            .sum();
        let width = b - a;
        let bound = 2.0 * width * tail;
        // A tail at the noise level cannot be refined away either: such a panel is
        // final (its bound still counts).
        let converged = bound <= 16.0 * f64::EPSILON * f_max * width;
        // What rounding adds to S on this panel (an estimate of its size, docs/curves.md):
        // a few ulps of f_max from the speed values and the transform, and the nodes
        // themselves, which are off by up to eps |t| (two roundings of half an ulp),
        // moving the speed by up to that times its slope (estimated from the node values).
        let mut slope = 0.0_f64;
        for j in 0..DEGREE {
            let dt = half * (cos[j] - cos[j + 1]);
            slope = slope.max((f[j] - f[j + 1]).abs() / dt);
        }
        let t_max = a.abs().max(b.abs());
        let rounding = f64::EPSILON * width * (4.0 * f_max + t_max * slope);
        Self {
            a,
            b,
            s_start: 0.0,
            len,
            bound,
            converged,
            rounding,
            speed: c,
            knots: std::array::from_fn(|k| clenshaw(&arc, -1.0 + 2.0 * k as f64 / KNOTS as f64)),
            arc,
        }
    }

    fn splittable(&self) -> bool {
        if self.converged {
            return false;
        }
        let scale = self.a.abs().max(self.b.abs()).max(f64::MIN_POSITIVE);
        self.b - self.a > MIN_WIDTH_ULPS * f64::EPSILON * scale
    }
}

/// The rounding of the compensated sum of the panel lengths, per unit of length: the
/// cumulative lengths carry about `2 eps L` (docs/curves.md, rounding).
const SUMMATION_EPS: f64 = 2.0 * f64::EPSILON;

/// The bound the table certifies for these panels (docs/curves.md): panel truncation
/// bounds, panel rounding estimates, and the rounding of summing the panel lengths,
/// `2 eps sum |len|` (at least `2 eps L`). Refinement stops on this and the final check
/// uses it, so the two cannot disagree.
fn certified_bound(panels: &[Panel]) -> f64 {
    let (mut truncation, mut rounding, mut length) = (0.0, 0.0, 0.0);
    for p in panels {
        truncation += p.bound;
        rounding += p.rounding;
        length += p.len.abs();
    }
    truncation + rounding + SUMMATION_EPS * length
}

/// A panel's share of [`certified_bound`], for the running total during refinement.
fn panel_share(p: &Panel) -> f64 {
    p.bound + p.rounding + SUMMATION_EPS * p.len.abs()
}

/// Orders panels by error bound for the refinement heap.
struct ByBound(f64, usize);
impl PartialEq for ByBound {
    fn eq(&self, other: &Self) -> bool {
        self.0.total_cmp(&other.0).is_eq()
    }
}
impl Eq for ByBound {}
impl PartialOrd for ByBound {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for ByBound {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// The arc length of a curve as a function of its parameter, and the inverse, to an
/// absolute tolerance; built once per curve and reused (see the module docs).
#[derive(Clone, Debug)]
pub struct ArcLengthTable {
    panels: Vec<Panel>,
    t0: f64,
    t1: f64,
    length: f64,
    tolerance: f64,
    bound: f64,
    evaluations: usize,
}

impl ArcLengthTable {
    /// Builds the table for `curve` so that `|arc_length_at(t) - s(t)| <= tolerance` for
    /// all `t` (module docs). Errors: `tolerance` not finite and positive; the domain or a
    /// break point not finite; [`CurveError::ToleranceNotReached`] when [`MAX_PANELS`]
    /// panels do not suffice.
    pub fn new<C: ParamCurveDeriv + ?Sized>(curve: &C, tolerance: f64) -> Result<Self, CurveError> {
        positive("tolerance", tolerance)?;
        let (t0, t1) = curve.domain();
        if !(t0.is_finite() && t1.is_finite() && t0 < t1) {
            return Err(CurveError::invalid(
                "domain",
                format!("must be finite with t0 < t1, got ({t0}, {t1})"),
            ));
        }
        let mut edges = vec![t0];
        for (i, b) in curve.breaks().into_iter().enumerate() {
            if !(b.is_finite() && b > *edges.last().unwrap_or(&t0) && b < t1) {
                return Err(CurveError::invalid(
                    format!("breaks[{i}]"),
                    format!("must be increasing and inside ({t0}, {t1}), got {b}"),
                ));
            }
            edges.push(b);
        }
        edges.push(t1);

        // Start with at least 8 panels over the domain, so that a speed oscillating a few
        // times over the domain cannot hide between the nodes of a single panel.
        let min_panels = 8.0;
        let mut panels = Vec::new();
        for w in edges.windows(2) {
            let parts = ((w[1] - w[0]) / (t1 - t0) * min_panels).ceil().max(1.0) as usize;
            for i in 0..parts {
                let a = w[0] + (w[1] - w[0]) * i as f64 / parts as f64;
                let b = if i + 1 == parts {
                    w[1]
                } else {
                    w[0] + (w[1] - w[0]) * (i + 1) as f64 / parts as f64
                };
                panels.push(Panel::build(curve, a, b));
            }
        }

        let mut heap: BinaryHeap<ByBound> = panels
            .iter()
            .enumerate()
            .filter(|(_, p)| p.splittable())
            .map(|(i, p)| ByBound(p.bound, i))
            .collect();
        // Only the truncation part can be refined away; the rounding and summation parts
        // are in the total so that refinement aims at what the final check tests.
        let mut total = certified_bound(&panels);
        while total > tolerance {
            let Some(ByBound(_, i)) = heap.pop() else {
                break;
            };
            if panels.len() + 1 > MAX_PANELS {
                // Stop refining; reported below.
                break;
            }
            let (a, b) = (panels[i].a, panels[i].b);
            let m = 0.5 * (a + b);
            let left = Panel::build(curve, a, m);
            let right = Panel::build(curve, m, b);
            total += panel_share(&left) + panel_share(&right) - panel_share(&panels[i]);
            panels[i] = left;
            panels.push(right);
            let j = panels.len() - 1;
            for k in [i, j] {
                if panels[k].splittable() {
                    heap.push(ByBound(panels[k].bound, k));
                }
            }
            if total <= tolerance {
                // The running total accumulates rounding; decide on the exact sum.
                total = certified_bound(&panels);
            }
        }
        // Recompute (the loop may also have stopped on MAX_PANELS or an empty heap).
        let bound = certified_bound(&panels);
        panels.sort_by(|p, q| p.a.total_cmp(&q.a));
        // Cumulative lengths by compensated (Neumaier) summation, so the running sum adds
        // only about 2 eps L however many panels there are (the summation term of the
        // bound).
        let mut s = 0.0_f64;
        let mut compensation = 0.0_f64;
        for p in &mut panels {
            p.s_start = s + compensation;
            let next = s + p.len;
            compensation += if s.abs() >= p.len.abs() {
                (s - next) + p.len
            } else {
                (p.len - next) + s
            };
            s = next;
        }
        let length = s + compensation;
        if bound > tolerance {
            return Err(CurveError::ToleranceNotReached {
                tolerance,
                reached: bound,
                panels: panels.len(),
            });
        }
        let evaluations = panels.len() * NODES;
        Ok(Self {
            panels,
            t0,
            t1,
            length,
            tolerance,
            bound,
            evaluations,
        })
    }

    /// The tolerance the table was built for.
    #[must_use]
    pub fn tolerance(&self) -> f64 {
        self.tolerance
    }

    /// The error bound actually reached: panel truncation bounds plus the rounding
    /// estimate, summation included (at most the tolerance).
    #[must_use]
    pub fn error_bound(&self) -> f64 {
        self.bound
    }

    /// The number of panels.
    #[must_use]
    pub fn panel_count(&self) -> usize {
        self.panels.len()
    }

    /// The number of speed evaluations in the final panels (a lower bound on the work:
    /// panels that were split also cost evaluations).
    #[must_use]
    pub fn speed_evaluations(&self) -> usize {
        self.evaluations
    }

    /// The panel boundaries `t` and cumulative lengths there (for plots and checks).
    #[must_use]
    pub fn boundaries(&self) -> Vec<(f64, f64)> {
        let mut v: Vec<(f64, f64)> = self.panels.iter().map(|p| (p.a, p.s_start)).collect();
        v.push((self.t1, self.length));
        v
    }

    /// The interpolated speed at `t` (clamped to the domain): the derivative of
    /// [`ArcParam::arc_length_at`].
    #[must_use]
    pub fn speed_at(&self, t: f64) -> f64 {
        let (p, x) = self.locate_t(t);
        clenshaw(&p.speed, x)
    }

    fn locate_t(&self, t: f64) -> (&Panel, f64) {
        let t = if t.is_nan() {
            self.t0
        } else {
            t.clamp(self.t0, self.t1)
        };
        let i = self.panels.partition_point(|p| p.a <= t).saturating_sub(1);
        let p = &self.panels[i];
        let x = ((2.0 * t - p.a - p.b) / (p.b - p.a)).clamp(-1.0, 1.0);
        (p, x)
    }

    /// The parameter at arc length `s` and the number of Newton/bisection iterations used
    /// (for tests and benchmarks; [`ArcParam::param_at`] drops the count).
    #[must_use]
    pub fn param_at_with_iterations(&self, s: f64) -> (f64, u32) {
        if s.is_nan() || s <= 0.0 {
            return (self.t0, 0);
        }
        if s >= self.length {
            return (self.t1, 0);
        }
        let i = self
            .panels
            .partition_point(|p| p.s_start <= s)
            .saturating_sub(1);
        let p = &self.panels[i];
        let target = s - p.s_start;
        if target >= p.len {
            return (p.b, 0);
        }
        let half = 0.5 * (p.b - p.a);
        // S(x) matches target to the rounding of the cumulative length.
        let tol = 4.0 * f64::EPSILON * (p.s_start + p.len);
        // Start from the tabulated sub-interval holding the target and linear
        // interpolation inside it; it brackets the root (S is increasing).
        let k = p.knots[1..KNOTS].partition_point(|&v| v <= target);
        let step = 2.0 / KNOTS as f64;
        let (mut lo, mut hi) = (-1.0 + step * k as f64, -1.0 + step * (k + 1) as f64);
        let (s_lo, s_hi) = (p.knots[k], p.knots[k + 1]);
        let mut x = if s_hi > s_lo {
            lo + step * ((target - s_lo) / (s_hi - s_lo)).clamp(0.0, 1.0)
        } else {
            0.5 * (lo + hi)
        };
        // The tabulated values carry rounding; widen the bracket by a hair so the root
        // is inside it.
        lo = (lo - 1e-12).max(-1.0);
        hi = (hi + 1e-12).min(1.0);
        let mut iterations = 0;
        while iterations < 200 {
            iterations += 1;
            // S and dS/dx (the interpolated speed times half) together.
            let (value, slope) = clenshaw_with_derivative(&p.arc, x);
            let g = value - target;
            if g.abs() <= tol {
                break;
            }
            if g < 0.0 {
                lo = x;
            } else {
                hi = x;
            }
            let newton = x - g / slope;
            // Newton only when the slope is positive and the step stays inside the
            // bracket; at a cusp the slope goes to zero and this falls back to bisection.
            if slope > 0.0 && newton > lo && newton < hi {
                // A Newton step this small leaves an error of about S'' dx^2 / 2, far
                // below rounding: accept it without another evaluation.
                let done = (newton - x).abs() <= 1e-9;
                x = newton;
                if done {
                    break;
                }
            } else {
                x = 0.5 * (lo + hi);
                if hi - lo <= 4.0 * f64::EPSILON {
                    break;
                }
            }
        }
        ((p.a + (x + 1.0) * half).clamp(p.a, p.b), iterations)
    }
}

impl ArcParam for ArcLengthTable {
    fn length(&self) -> f64 {
        self.length
    }

    /// The tolerance (the sum of the panel bounds, rounding included, is at most this;
    /// [`ArcLengthTable::error_bound`] is that sum).
    fn length_error_bound(&self) -> f64 {
        self.tolerance
    }

    fn arc_length_at(&self, t: f64) -> f64 {
        // The ends exactly (the series matches them only to rounding).
        if t.is_nan() || t <= self.t0 {
            return 0.0;
        }
        if t >= self.t1 {
            return self.length;
        }
        let (p, x) = self.locate_t(t);
        p.s_start + clenshaw(&p.arc, x)
    }

    fn param_at(&self, s: f64) -> f64 {
        self.param_at_with_iterations(s).0
    }
}
