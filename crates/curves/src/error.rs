//! The error type shared by every fallible call in the crate.

use std::fmt;

/// Why a curve, a table or a sampling was refused. Every variant names what was wrong.
#[derive(Clone, Debug, PartialEq)]
pub enum CurveError {
    /// An input field has an invalid value.
    Invalid {
        /// The offending field, e.g. `"petals"`, `"r"`, `"points[3]"`, `"tolerance"`.
        field: String,
        /// What is wrong with it, including the value given.
        reason: String,
    },
    /// Arc-length quadrature could not bring its error bound down to the tolerance within
    /// its panel budget (the tolerance is below what rounding allows for this curve, or
    /// the speed is not smooth between the curve's declared break points).
    ToleranceNotReached {
        /// The tolerance asked for.
        tolerance: f64,
        /// The error bound reached when the budget ran out.
        reached: f64,
        /// Panels used.
        panels: usize,
    },
}

impl CurveError {
    /// Shorthand for [`CurveError::Invalid`].
    pub(crate) fn invalid(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::Invalid {
            field: field.into(),
            reason: reason.into(),
        }
    }
}

impl fmt::Display for CurveError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Invalid { field, reason } => write!(f, "{field}: {reason}"),
            Self::ToleranceNotReached {
                tolerance,
                reached,
                panels,
            } => write!(
                f,
                "tolerance: arc-length error bound {reached:e} after {panels} panels, \
                 above the tolerance {tolerance:e} (too small for this curve in f64, or the \
                 speed has a kink that is not declared as a break point)"
            ),
        }
    }
}

impl std::error::Error for CurveError {}

/// `Ok(x)` when `x` is finite, else an error naming `field`.
pub(crate) fn finite(field: &str, x: f64) -> Result<f64, CurveError> {
    if x.is_finite() {
        Ok(x)
    } else {
        Err(CurveError::invalid(
            field,
            format!("must be finite, got {x}"),
        ))
    }
}

/// `Ok(x)` when `x` is finite and strictly positive, else an error naming `field`.
pub(crate) fn positive(field: &str, x: f64) -> Result<f64, CurveError> {
    if x.is_finite() && x > 0.0 {
        Ok(x)
    } else {
        Err(CurveError::invalid(
            field,
            format!("must be finite and > 0, got {x}"),
        ))
    }
}
