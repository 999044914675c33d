//! Flower curves, arc length to a stated tolerance, and evenly spaced resampling.
//!
//! Modelled on kurbo: capability traits in one module ([`ParamCurve`],
//! [`ParamCurveDeriv`], [`ArcParam`]), curves that implement them ([`Epicycloid`],
//! [`Rose`], [`Polyline`], [`FnCurve`]), and algorithms written against the traits, each
//! taking its accuracy explicitly:
//!
//! - [`ArcLengthTable::new`]`(&curve, tolerance)`: arc length by panel-wise Clenshaw-Curtis
//!   quadrature, split at the curve's cusps, refined until a conservative error bound is
//!   below the absolute `tolerance`; the bound holds for `s(t)` at every `t`, not only for
//!   the total. Built once per curve and reused.
//! - [`ArcParam::param_at`]: the inverse `t(s)` by Newton's method safeguarded with
//!   bisection, correct at cusps where the speed vanishes.
//! - [`resample_evenly`], [`resample_by_spacing`] and the baseline [`sample_uniform`],
//!   returning [`Samples`] with their own evenness report.
//! - [`CurveSpec`] and [`Sampling`]: descriptions for scene files (serde with the `serde`
//!   feature).
//!
//! ```
//! use sinew_curves::{ArcLengthTable, ArcParam, Epicycloid, resample_evenly};
//! let flower = Epicycloid::lab_flower();
//! let table = ArcLengthTable::new(&flower, 1e-12).unwrap();
//! assert!((table.length() - 4.8).abs() <= 1e-12);
//! let samples = resample_evenly(&flower, &table, 500).unwrap();
//! assert_eq!(samples.points.len(), 500);
//! assert!(samples.arc.unwrap().rel_dev_max < 1e-9);
//! ```
//!
//! Derivations, and exactly what each tolerance bounds: docs/curves.md.
//!
//! Architecture invariant: depends on sinew-math only (serde behind the `serde` feature).

mod arclen;
mod epicycloid;
mod error;
mod fn_curve;
mod plane;
mod polyline;
mod resample;
mod rose;
mod spec;
mod traits;

pub use arclen::{ArcLengthTable, DEGREE, MAX_PANELS};
pub use epicycloid::Epicycloid;
pub use error::CurveError;
pub use fn_curve::{Ends, FnCurve, NoDerivative};
pub use plane::{Plane, PlaneAxes};
pub use polyline::Polyline;
pub use resample::{
    MAX_POINTS, Samples, SpacingStats, resample_by_spacing, resample_evenly, sample_uniform,
};
pub use rose::{Rose, complete_elliptic_e};
/// The math types curves are evaluated in, re-exported so a user of this crate does not
/// also have to depend on sinew-math.
pub use sinew_math::{DVec2, DVec3};
pub use spec::{Curve, CurveSpec, Sampling};
pub use traits::{ArcParam, ParamCurve, ParamCurveDeriv};
