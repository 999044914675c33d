//! Curve and sampling descriptions, as scene files name them, and the curve they build.
//!
//! [`CurveSpec`] and [`Sampling`] derive serde's traits with the `serde` feature. A
//! [`CurveSpec`] is checked by [`CurveSpec::build`], which returns a [`Curve`] (an enum
//! over the built-in curves implementing the capability traits) or an error naming the
//! bad field. [`Curve::sample`] runs a [`Sampling`].

use crate::arclen::ArcLengthTable;
use crate::epicycloid::Epicycloid;
use crate::error::CurveError;
use crate::fn_curve::Ends;
use crate::plane::{Plane, PlaneAxes};
use crate::polyline::Polyline;
use crate::resample::{Samples, resample_by_spacing, resample_evenly, sample_uniform};
use crate::rose::Rose;
use crate::traits::{ParamCurve, ParamCurveDeriv};
use sinew_math::DVec3;

/// A curve description.
///
/// The lab flower in RON: `Epicycloid(petals: 5, r: 0.1, center: (0.0, 0.0, 0.0), plane: XZ)`
/// (`center` and `plane` may be left out; they default to the origin and `XZ`).
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub enum CurveSpec {
    /// An [`Epicycloid`] with `petals` cusps and rolling radius `r`.
    Epicycloid {
        /// Number of petals (cusps) `k >= 1`.
        petals: u32,
        /// Rolling circle radius `r > 0` (`R = k r`); the lab's `a`.
        r: f64,
        /// Center of the plane.
        #[cfg_attr(feature = "serde", serde(default))]
        center: DVec3,
        /// Orientation of the plane.
        #[cfg_attr(feature = "serde", serde(default))]
        plane: PlaneAxes,
    },
    /// A [`Rose`] `r = a cos(k theta)`.
    Rose {
        /// Frequency `k >= 1` (`k` petals for odd `k`, `2k` for even).
        k: u32,
        /// Petal length `a > 0`.
        a: f64,
        /// Center of the plane.
        #[cfg_attr(feature = "serde", serde(default))]
        center: DVec3,
        /// Orientation of the plane.
        #[cfg_attr(feature = "serde", serde(default))]
        plane: PlaneAxes,
    },
    /// A [`Polyline`] through `points`.
    Polyline {
        /// At least 2 finite points.
        points: Vec<DVec3>,
        /// Whether to close the loop back to the first point.
        #[cfg_attr(feature = "serde", serde(default))]
        closed: bool,
    },
}

impl CurveSpec {
    /// The lab's five-petal flower: `Epicycloid { petals: 5, r: 0.1, center: 0, plane: XZ }`.
    #[must_use]
    pub fn lab_flower() -> Self {
        Self::Epicycloid {
            petals: 5,
            r: 0.1,
            center: DVec3::ZERO,
            plane: PlaneAxes::XZ,
        }
    }

    /// Checks the description and builds the curve. Errors name the field: `petals`,
    /// `r`, `k`, `a`, `center.x`, `plane.u`, `points`, `points[i]`, ...
    pub fn build(&self) -> Result<Curve, CurveError> {
        Ok(match self {
            Self::Epicycloid {
                petals,
                r,
                center,
                plane,
            } => Curve::Epicycloid(Epicycloid::with_petals(
                *petals,
                *r,
                Plane::new(*center, *plane)?,
            )?),
            Self::Rose {
                k,
                a,
                center,
                plane,
            } => Curve::Rose(Rose::from_frequency(*k, *a, Plane::new(*center, *plane)?)?),
            Self::Polyline { points, closed } => Curve::Polyline(Polyline::new(
                points.clone(),
                if *closed { Ends::Closed } else { Ends::Open },
            )?),
        })
    }
}

/// How to place points on a curve.
///
/// In RON: `ArcLength(n: 500, tolerance: 1e-12)`, `Uniform(n: 500)`,
/// `ArcSpacing(spacing: 0.01, tolerance: 1e-12)`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub enum Sampling {
    /// `n` points at uniform parameter steps ([`sample_uniform`]), the baseline.
    Uniform {
        /// Number of points.
        n: usize,
    },
    /// `n` points evenly spaced by arc length ([`resample_evenly`]).
    ArcLength {
        /// Number of points.
        n: usize,
        /// Absolute arc-length tolerance of the table (ignored for polylines, which are
        /// exact).
        tolerance: f64,
    },
    /// Points at a fixed arc spacing from the start ([`resample_by_spacing`]).
    ArcSpacing {
        /// The spacing.
        spacing: f64,
        /// Absolute arc-length tolerance of the table (ignored for polylines).
        tolerance: f64,
    },
}

/// One of the built-in curves, as built from a [`CurveSpec`].
#[derive(Clone, Debug, PartialEq)]
pub enum Curve {
    /// An epicycloid.
    Epicycloid(Epicycloid),
    /// A rose.
    Rose(Rose),
    /// A polyline.
    Polyline(Polyline),
}

impl Curve {
    /// The exact length where a closed form exists: `8 (R + r)` for an epicycloid, the
    /// elliptic-integral formula for a rose, the segment sum for a polyline.
    #[must_use]
    pub fn exact_length(&self) -> Option<f64> {
        match self {
            Self::Epicycloid(c) => Some(c.exact_length()),
            Self::Rose(c) => Some(c.exact_length()),
            Self::Polyline(c) => Some(crate::ArcParam::length(c)),
        }
    }

    /// The arc-length table at `tolerance` (not needed for polylines, which are exact).
    pub fn table(&self, tolerance: f64) -> Result<ArcLengthTable, CurveError> {
        ArcLengthTable::new(self, tolerance)
    }

    /// Runs `sampling` on this curve, building an arc-length table if needed (polylines
    /// use their exact arc length). Uniform sampling reports chord spacing only; to
    /// measure its arc spacing, call [`Samples::measure_arc`] with a table.
    pub fn sample(&self, sampling: &Sampling) -> Result<Samples, CurveError> {
        match (sampling, self) {
            (Sampling::Uniform { n }, _) => sample_uniform(self, *n),
            (Sampling::ArcLength { n, .. }, Self::Polyline(p)) => resample_evenly(p, p, *n),
            (Sampling::ArcLength { n, tolerance }, _) => {
                resample_evenly(self, &self.table(*tolerance)?, *n)
            }
            (Sampling::ArcSpacing { spacing, .. }, Self::Polyline(p)) => {
                resample_by_spacing(p, p, *spacing)
            }
            (Sampling::ArcSpacing { spacing, tolerance }, _) => {
                resample_by_spacing(self, &self.table(*tolerance)?, *spacing)
            }
        }
    }
}

impl ParamCurve for Curve {
    fn domain(&self) -> (f64, f64) {
        match self {
            Self::Epicycloid(c) => c.domain(),
            Self::Rose(c) => c.domain(),
            Self::Polyline(c) => c.domain(),
        }
    }

    fn position(&self, t: f64) -> DVec3 {
        match self {
            Self::Epicycloid(c) => c.position(t),
            Self::Rose(c) => c.position(t),
            Self::Polyline(c) => c.position(t),
        }
    }

    fn is_closed(&self) -> bool {
        match self {
            Self::Epicycloid(c) => c.is_closed(),
            Self::Rose(c) => c.is_closed(),
            Self::Polyline(c) => c.is_closed(),
        }
    }
}

impl ParamCurveDeriv for Curve {
    fn derivative(&self, t: f64) -> DVec3 {
        match self {
            Self::Epicycloid(c) => c.derivative(t),
            Self::Rose(c) => c.derivative(t),
            Self::Polyline(c) => c.derivative(t),
        }
    }

    fn speed(&self, t: f64) -> f64 {
        match self {
            Self::Epicycloid(c) => c.speed(t),
            Self::Rose(c) => c.speed(t),
            Self::Polyline(c) => c.speed(t),
        }
    }

    fn breaks(&self) -> Vec<f64> {
        match self {
            Self::Epicycloid(c) => c.breaks(),
            Self::Rose(c) => c.breaks(),
            Self::Polyline(c) => c.breaks(),
        }
    }
}
