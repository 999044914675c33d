//! Capability traits: what a curve can do, in the style of kurbo's `ParamCurve` family.
//!
//! A curve type implements the traits it can; the algorithms in this crate
//! ([`crate::ArcLengthTable`], [`crate::resample_evenly`], [`crate::sample_uniform`]) are
//! written against them, so a user's own curve gets arc length and resampling by
//! implementing two small traits.

use sinew_math::DVec3;

/// A curve parameterized over a closed interval `[t0, t1]`.
pub trait ParamCurve {
    /// The parameter interval `(t0, t1)`, with `t0 < t1`, both finite.
    #[must_use]
    fn domain(&self) -> (f64, f64);

    /// The point at parameter `t`. Defined (finite) for every `t` in the domain.
    #[must_use]
    fn position(&self, t: f64) -> DVec3;

    /// Whether the curve is closed: `position(t1) == position(t0)` (up to rounding) and
    /// the curve is meant to be traversed as a loop. Resampling wraps around closed curves.
    #[must_use]
    fn is_closed(&self) -> bool;
}

/// A curve with a first derivative, hence a speed `|dP/dt|` and an arc length.
pub trait ParamCurveDeriv: ParamCurve {
    /// The derivative `dP/dt` at `t`.
    #[must_use]
    fn derivative(&self, t: f64) -> DVec3;

    /// The speed `|dP/dt|` at `t`, the integrand of arc length. Curves override this
    /// when a cheaper or more accurate formula is known; it must agree with
    /// `derivative(t).length()` to rounding.
    #[must_use]
    fn speed(&self, t: f64) -> f64 {
        self.derivative(t).length()
    }

    /// Parameters strictly inside the domain, in increasing order, where the speed may
    /// fail to be smooth (analytic): cusps, where the speed has a kink `|t - t_c|`, and
    /// polyline vertices, where it jumps. Arc-length quadrature never integrates across
    /// one of these, because its error estimate assumes a smooth integrand on each panel.
    /// The default is none: the speed is smooth on the whole domain.
    #[must_use]
    fn breaks(&self) -> Vec<f64> {
        Vec::new()
    }
}

impl<C: ParamCurve + ?Sized> ParamCurve for &C {
    fn domain(&self) -> (f64, f64) {
        (**self).domain()
    }
    fn position(&self, t: f64) -> DVec3 {
        (**self).position(t)
    }
    fn is_closed(&self) -> bool {
        (**self).is_closed()
    }
}

impl<C: ParamCurveDeriv + ?Sized> ParamCurveDeriv for &C {
    fn derivative(&self, t: f64) -> DVec3 {
        (**self).derivative(t)
    }
    fn speed(&self, t: f64) -> f64 {
        (**self).speed(t)
    }
    fn breaks(&self) -> Vec<f64> {
        (**self).breaks()
    }
}

/// An arc-length parameterization of a curve: the map `t -> s(t)` and its inverse.
///
/// Implemented by [`crate::ArcLengthTable`] (to a stated tolerance, for any
/// [`ParamCurveDeriv`]) and by [`crate::Polyline`] (exactly). Resampling is written
/// against this trait.
pub trait ArcParam {
    /// The total length `s(t1)`.
    #[must_use]
    fn length(&self) -> f64;

    /// A bound on `|s_computed(t) - s(t)|` for every `t` (which includes the length).
    #[must_use]
    fn length_error_bound(&self) -> f64;

    /// The arc length from the domain start to `t` (clamped to the domain; NaN gives 0).
    #[must_use]
    fn arc_length_at(&self, t: f64) -> f64;

    /// The parameter at arc length `s` (clamped to `[0, length]`; NaN gives the domain
    /// start). Where the speed is zero over an interval, any parameter in it is a valid
    /// answer; one is returned.
    #[must_use]
    fn param_at(&self, s: f64) -> f64;
}
