//! Curves from closures, for users' own shapes.
//!
//! [`FnCurve::with_derivative`] takes a position and a derivative closure; arc length is
//! then as accurate as for the built-in curves. [`FnCurve::new`] takes a position only and
//! differentiates it numerically with a sixth-order central difference,
//! `P'(t) ~ [45 (P(t+h) - P(t-h)) - 9 (P(t+2h) - P(t-2h)) + (P(t+3h) - P(t-3h))] / (60 h)`,
//! whose error is about `h^6/140 max|P^(7)| + 1.8 eps max|P| / h` (truncation plus
//! rounding). This error is not covered by the arc-length tolerance: it adds at most its
//! integral over the domain to the length error. The default step is
//! `h = (t1 - t0)/2048`; for a curve with `f` oscillations over its domain and size `A`
//! the derivative error is then about `A (2 pi f / 2048)^6 / (140 h) + 1.8 eps A / h`
//! (around 1e-13 relative for the lab flower, `f = 6`), so lengths are good to roughly
//! 1e-12 relative. Pass the derivative when you need more. The position closure is
//! evaluated up to `3h` outside the domain.

use crate::error::{CurveError, finite, positive};
use crate::traits::{ParamCurve, ParamCurveDeriv};
use sinew_math::DVec3;

/// Whether a curve's ends meet: a closed curve's resampling spaces the last point one
/// step before the first (the end is the start), an open curve's includes both ends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ends {
    /// The ends are distinct points (a stroke, a path).
    Open,
    /// `position(t1)` is `position(t0)` (a loop, a flower).
    Closed,
}

/// The derivative type of an [`FnCurve`] made without one (never called).
pub type NoDerivative = fn(f64) -> DVec3;

/// A curve from a position closure and, optionally, a derivative closure.
#[derive(Clone)]
pub struct FnCurve<P, D = NoDerivative> {
    position: P,
    derivative: Option<D>,
    t0: f64,
    t1: f64,
    closed: bool,
    step: f64,
    breaks: Vec<f64>,
}

impl<P, D> std::fmt::Debug for FnCurve<P, D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FnCurve")
            .field("domain", &(self.t0, self.t1))
            .field("closed", &self.closed)
            .field("has_derivative", &self.derivative.is_some())
            .field("step", &self.step)
            .field("breaks", &self.breaks)
            .finish()
    }
}

fn check_domain(t0: f64, t1: f64) -> Result<(), CurveError> {
    finite("t0", t0)?;
    finite("t1", t1)?;
    if t1 <= t0 {
        return Err(CurveError::invalid(
            "t1",
            format!("must be greater than t0 = {t0}, got {t1}"),
        ));
    }
    Ok(())
}

fn check_position<P: Fn(f64) -> DVec3>(p: &P, t0: f64, t1: f64) -> Result<(), CurveError> {
    for t in [t0, 0.5 * (t0 + t1), t1] {
        let x = p(t);
        if !x.is_finite() {
            return Err(CurveError::invalid(
                "position",
                format!("must be finite, got {x} at t = {t}"),
            ));
        }
    }
    Ok(())
}

impl<P: Fn(f64) -> DVec3> FnCurve<P> {
    /// A curve `position(t)`, `t` in `[t0, t1]`, differentiated numerically (see the
    /// module docs for the accuracy this allows). Errors name `t0`, `t1` or `position`
    /// (not finite at the ends or the middle of the domain).
    ///
    /// ```
    /// use sinew_curves::{ArcLengthTable, ArcParam, DVec3, Ends, FnCurve};
    /// use std::f64::consts::TAU;
    /// // A unit circle: length 2 pi, to far better than the default tolerance.
    /// let circle = FnCurve::new(0.0, TAU, Ends::Closed, |t| DVec3::new(t.cos(), t.sin(), 0.0))
    ///     .unwrap();
    /// let table = ArcLengthTable::new(&circle, 1e-9).unwrap();
    /// assert!((table.length() - TAU).abs() < 1e-9);
    /// ```
    pub fn new(t0: f64, t1: f64, ends: Ends, position: P) -> Result<Self, CurveError> {
        check_domain(t0, t1)?;
        check_position(&position, t0, t1)?;
        Ok(Self {
            position,
            derivative: None,
            t0,
            t1,
            closed: ends == Ends::Closed,
            step: (t1 - t0) / 2048.0,
            breaks: Vec::new(),
        })
    }
}

impl<P: Fn(f64) -> DVec3, D: Fn(f64) -> DVec3> FnCurve<P, D> {
    /// A curve `position(t)` with its exact `derivative(t)`, `t` in `[t0, t1]`.
    pub fn with_derivative(
        t0: f64,
        t1: f64,
        ends: Ends,
        position: P,
        derivative: D,
    ) -> Result<Self, CurveError> {
        check_domain(t0, t1)?;
        check_position(&position, t0, t1)?;
        check_position(&derivative, t0, t1)
            .map_err(|_| CurveError::invalid("derivative", "must be finite on the domain"))?;
        Ok(Self {
            position,
            derivative: Some(derivative),
            t0,
            t1,
            closed: ends == Ends::Closed,
            step: (t1 - t0) / 2048.0,
            breaks: Vec::new(),
        })
    }

    /// Declares the parameters where the speed is not smooth (cusps, corners); they must
    /// be finite, strictly inside the domain and increasing. Errors name `breaks[i]`.
    pub fn with_breaks(mut self, breaks: Vec<f64>) -> Result<Self, CurveError> {
        let mut previous = self.t0;
        for (i, &b) in breaks.iter().enumerate() {
            if !(b > previous && b < self.t1) {
                return Err(CurveError::invalid(
                    format!("breaks[{i}]"),
                    format!(
                        "must be inside ({}, {}) and above the previous break, got {b}",
                        self.t0, self.t1
                    ),
                ));
            }
            previous = b;
        }
        self.breaks = breaks;
        Ok(self)
    }

    /// Sets the finite-difference step `h` used when there is no derivative closure.
    /// Errors name `step`.
    pub fn with_step(mut self, step: f64) -> Result<Self, CurveError> {
        self.step = positive("step", step)?;
        Ok(self)
    }
}

impl<P: Fn(f64) -> DVec3, D> ParamCurve for FnCurve<P, D> {
    fn domain(&self) -> (f64, f64) {
        (self.t0, self.t1)
    }

    fn position(&self, t: f64) -> DVec3 {
        (self.position)(t)
    }

    fn is_closed(&self) -> bool {
        self.closed
    }
}

impl<P: Fn(f64) -> DVec3, D: Fn(f64) -> DVec3> ParamCurveDeriv for FnCurve<P, D> {
    fn derivative(&self, t: f64) -> DVec3 {
        if let Some(d) = &self.derivative {
            return d(t);
        }
        let h = self.step;
        let p = &self.position;
        let d1 = p(t + h) - p(t - h);
        let d2 = p(t + 2.0 * h) - p(t - 2.0 * h);
        let d3 = p(t + 3.0 * h) - p(t - 3.0 * h);
        (45.0 * d1 - 9.0 * d2 + d3) / (60.0 * h)
    }

    fn breaks(&self) -> Vec<f64> {
        self.breaks.clone()
    }
}
