//! Points along a curve: evenly spaced by arc length, at a given arc spacing, or at
//! uniform parameter steps (the baseline), each with a report of how even they are.
//!
//! Evenness is measured on the gaps between consecutive points (for a closed curve
//! including the gap from the last point back to the first):
//! - arc spacing: the arc length of each gap, `s(t_{i+1}) - s(t_i)`, from an [`ArcParam`];
//! - chord spacing: the straight-line distance `|P_{i+1} - P_i|`.
//!
//! Each is summarized by [`SpacingStats`]; `rel_dev_max = max_i |d_i - mean| / mean`.
//! Arc-length resampling makes the arc spacing even (to the table's tolerance); chord
//! spacing then still varies with curvature (a chord is shorter than its arc by about
//! `kappa^2 h^3 / 24`), which is the geometry of the curve, not an error.

use crate::error::{CurveError, positive};
use crate::traits::{ArcParam, ParamCurve};
use sinew_math::DVec3;

/// The most points a sampling may produce.
pub const MAX_POINTS: usize = 1 << 26;

/// Statistics of the gaps between consecutive points.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct SpacingStats {
    /// The number of gaps measured.
    pub gaps: usize,
    /// The smallest gap.
    pub min: f64,
    /// The largest gap.
    pub max: f64,
    /// The mean gap.
    pub mean: f64,
    /// `max_i |d_i - mean| / mean` (0 when the mean is 0).
    pub rel_dev_max: f64,
}

impl SpacingStats {
    /// Statistics of the gaps `d`.
    #[must_use]
    pub fn of(d: &[f64]) -> Self {
        if d.is_empty() {
            return Self::default();
        }
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        let min = d.iter().copied().fold(f64::INFINITY, f64::min);
        let max = d.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let rel_dev_max = if mean > 0.0 {
            ((max - mean).max(mean - min)) / mean
        } else {
            0.0
        };
        Self {
            gaps: d.len(),
            min,
            max,
            mean,
            rel_dev_max,
        }
    }
}

/// Points on a curve with their parameters and evenness report.
#[derive(Clone, Debug, PartialEq)]
pub struct Samples {
    /// The points.
    pub points: Vec<DVec3>,
    /// The curve parameter of each point.
    pub params: Vec<f64>,
    /// Whether the points are a loop (the last gap wraps to the first point).
    pub closed: bool,
    /// The curve's length from the arc-length parameterization used, if one was.
    pub length: Option<f64>,
    /// The bound on the error of `length` (and of every arc spacing), if known.
    pub length_error_bound: Option<f64>,
    /// The arc length of the final partial gap (to the end, or back to the start), which
    /// spacing-based sampling leaves over and which is excluded from the statistics;
    /// 0 for the other samplings.
    pub remainder: f64,
    /// Chord spacing statistics.
    pub chord: SpacingStats,
    /// Arc spacing statistics, if measured with an arc-length parameterization.
    pub arc: Option<SpacingStats>,
}

impl Samples {
    fn new<C: ParamCurve + ?Sized>(curve: &C, params: Vec<f64>, wrap_gap: bool) -> Self {
        let points: Vec<DVec3> = params.iter().map(|&t| curve.position(t)).collect();
        let closed = curve.is_closed();
        let chords = gaps(&points, wrap_gap, |a, b| (*b - *a).length());
        Self {
            points,
            params,
            closed,
            length: None,
            length_error_bound: None,
            remainder: 0.0,
            chord: SpacingStats::of(&chords),
            arc: None,
        }
    }

    fn wraps(&self) -> bool {
        self.closed && self.remainder == 0.0
    }

    /// Measures the arc spacing (and records the length) with `arc`, which should belong
    /// to the same curve. For arc-length resampling with a table this is circular (the
    /// table agrees with itself); the true arc spacing then deviates from it by at most
    /// `2 * length_error_bound` per gap. For uniform-parameter sampling it is the real
    /// measure of unevenness, to the same accuracy.
    pub fn measure_arc<A: ArcParam + ?Sized>(&mut self, arc: &A) {
        let s: Vec<f64> = self.params.iter().map(|&t| arc.arc_length_at(t)).collect();
        let wrap = self.wraps();
        let length = arc.length();
        let mut d: Vec<f64> = s.windows(2).map(|w| w[1] - w[0]).collect();
        if wrap && let (Some(first), Some(last)) = (s.first(), s.last()) {
            d.push(length - last + first);
        }
        self.arc = Some(SpacingStats::of(&d));
        self.length = Some(length);
        self.length_error_bound = Some(arc.length_error_bound());
    }
}

fn gaps<F: Fn(&DVec3, &DVec3) -> f64>(points: &[DVec3], wrap: bool, f: F) -> Vec<f64> {
    let mut d: Vec<f64> = points.windows(2).map(|w| f(&w[0], &w[1])).collect();
    if wrap && points.len() > 1 {
        d.push(f(&points[points.len() - 1], &points[0]));
    }
    d
}

fn check_count(n: usize, closed: bool) -> Result<(), CurveError> {
    let min = if closed { 1 } else { 2 };
    if n < min || n > MAX_POINTS {
        return Err(CurveError::invalid(
            "n",
            format!(
                "must be in {min}..={MAX_POINTS} for {} curve, got {n}",
                if closed { "a closed" } else { "an open" }
            ),
        ));
    }
    Ok(())
}

/// `n` points at uniform parameter steps: `t_i = t0 + (t1 - t0) i / n`, `i < n`, for a
/// closed curve (the end is the start again); `t_i = t0 + (t1 - t0) i / (n - 1)` for an
/// open one (both ends included). The baseline; reports chord spacing only (call
/// [`Samples::measure_arc`] for arc spacing). Errors name `n`.
pub fn sample_uniform<C: ParamCurve + ?Sized>(curve: &C, n: usize) -> Result<Samples, CurveError> {
    let closed = curve.is_closed();
    check_count(n, closed)?;
    let (t0, t1) = curve.domain();
    let steps = if closed { n } else { n - 1 } as f64;
    let params: Vec<f64> = (0..n)
        .map(|i| {
            if !closed && i + 1 == n {
                t1
            } else {
                t0 + (t1 - t0) * (i as f64 / steps)
            }
        })
        .collect();
    Ok(Samples::new(curve, params, closed))
}

/// `n` points evenly spaced along the curve by arc length, using `arc` (an
/// [`crate::ArcLengthTable`] of the curve, or a [`crate::Polyline`] itself): at
/// `s_i = L i / n`, `i < n`, for a closed curve (so the gaps, including the wrap-around
/// one, are all `L / n`); at `s_i = L i / (n - 1)` for an open one (both ends included).
/// The report includes the arc spacing per `arc`. Errors name `n`.
pub fn resample_evenly<C, A>(curve: &C, arc: &A, n: usize) -> Result<Samples, CurveError>
where
    C: ParamCurve + ?Sized,
    A: ArcParam + ?Sized,
{
    let closed = curve.is_closed();
    check_count(n, closed)?;
    let length = arc.length();
    let (_, t1) = curve.domain();
    let steps = if closed { n } else { n - 1 } as f64;
    let params: Vec<f64> = (0..n)
        .map(|i| {
            if !closed && i + 1 == n {
                t1
            } else {
                arc.param_at(length * (i as f64 / steps))
            }
        })
        .collect();
    let mut samples = Samples::new(curve, params, closed);
    samples.measure_arc(arc);
    Ok(samples)
}

/// Points at arc-length spacing `spacing` from the start: `s_j = j * spacing` for every
/// `s_j <= L` (up to `1e-12 L`, so a spacing dividing the length gives its last point on the
/// end, or for a closed curve no duplicate of the start). The leftover gap, to the end or
/// back to the start, is [`Samples::remainder`] and is excluded from the statistics.
/// Errors name `spacing` (not finite and positive, or giving more than [`MAX_POINTS`]).
pub fn resample_by_spacing<C, A>(curve: &C, arc: &A, spacing: f64) -> Result<Samples, CurveError>
where
    C: ParamCurve + ?Sized,
    A: ArcParam + ?Sized,
{
    positive("spacing", spacing)?;
    let closed = curve.is_closed();
    let length = arc.length();
    let slack = 1e-12 * length;
    let full = ((length + slack) / spacing).floor();
    if full + 1.0 > MAX_POINTS as f64 {
        return Err(CurveError::invalid(
            "spacing",
            format!("{spacing} gives more than {MAX_POINTS} points on a curve of length {length}"),
        ));
    }
    let full = full as usize;
    let mut remainder = (length - full as f64 * spacing).max(0.0);
    if remainder <= slack {
        remainder = 0.0;
    }
    // A closed curve whose length is a multiple of the spacing: the last point would be
    // the start again.
    let count = if closed && remainder == 0.0 && full > 0 {
        full
    } else {
        full + 1
    };
    let params: Vec<f64> = (0..count)
        .map(|j| arc.param_at(spacing * j as f64))
        .collect();
    let mut samples = Samples::new(curve, params, closed && remainder == 0.0);
    samples.closed = closed;
    samples.remainder = remainder;
    samples.measure_arc(arc);
    Ok(samples)
}
