//! Polylines: a recorded trajectory as a curve, with exact arc length.
//!
//! The parameter of a polyline with segments `0..n` runs over `[0, n]`; segment `i` is
//! `t` in `[i, i + 1]`, linear in `t`. A closed polyline has an extra segment from the last
//! point back to the first. The speed is constant on each segment (the segment's length)
//! and jumps at vertices, which are reported as break points. Arc length is exact (a sum
//! of segment lengths), so a polyline is its own [`ArcParam`].

use crate::error::CurveError;
use crate::fn_curve::Ends;
use crate::traits::{ArcParam, ParamCurve, ParamCurveDeriv};
use sinew_math::DVec3;

/// A polyline through a list of points, open or closed.
#[derive(Clone, Debug, PartialEq)]
pub struct Polyline {
    points: Vec<DVec3>,
    closed: bool,
    /// `cumulative[i]` is the length of segments `0..i`; one entry per segment plus one.
    cumulative: Vec<f64>,
}

impl Polyline {
    /// A polyline through `points` (at least 2, all finite). A closed polyline
    /// ([`Ends::Closed`]) gets a closing segment from the last point to the first. Errors
    /// name `points` or `points[i]`. Repeated points are allowed (a zero-length segment).
    ///
    /// ```
    /// use sinew_curves::{ArcLengthTable, ArcParam, DVec3, Ends, Polyline};
    /// let corners = vec![DVec3::ZERO, DVec3::X, DVec3::new(1.0, 1.0, 0.0)];
    /// let open = Polyline::new(corners.clone(), Ends::Open).unwrap();
    /// let closed = Polyline::new(corners, Ends::Closed).unwrap();
    /// let length = |p: &Polyline| ArcLengthTable::new(p, 1e-12).unwrap().length();
    /// assert!((length(&open) - 2.0).abs() < 1e-12);
    /// assert!((length(&closed) - (2.0 + 2f64.sqrt())).abs() < 1e-12);
    /// ```
    pub fn new(points: Vec<DVec3>, ends: Ends) -> Result<Self, CurveError> {
        let closed = ends == Ends::Closed;
        if points.len() < 2 {
            return Err(CurveError::invalid(
                "points",
                format!("a polyline needs at least 2 points, got {}", points.len()),
            ));
        }
        if let Some(i) = points.iter().position(|p| !p.is_finite()) {
            return Err(CurveError::invalid(
                format!("points[{i}]"),
                format!("must be finite, got {}", points[i]),
            ));
        }
        let segments = if closed {
            points.len()
        } else {
            points.len() - 1
        };
        let mut cumulative = Vec::with_capacity(segments + 1);
        let mut total = 0.0;
        cumulative.push(0.0);
        for i in 0..segments {
            total += (points[(i + 1) % points.len()] - points[i]).length();
            cumulative.push(total);
        }
        Ok(Self {
            points,
            closed,
            cumulative,
        })
    }

    /// The points.
    #[must_use]
    pub fn points(&self) -> &[DVec3] {
        &self.points
    }

    /// The number of segments (the parameter runs over `[0, segments]`).
    #[must_use]
    pub fn segments(&self) -> usize {
        self.cumulative.len() - 1
    }

    /// The segment holding parameter `t` (clamped) and the fraction along it.
    fn locate(&self, t: f64) -> (usize, f64) {
        let n = self.segments();
        let t = if t.is_nan() {
            0.0
        } else {
            t.clamp(0.0, n as f64)
        };
        // Truncation is the floor here: t >= 0.
        let i = (t as usize).min(n - 1);
        (i, t - i as f64)
    }

    fn segment(&self, i: usize) -> (DVec3, DVec3) {
        (self.points[i], self.points[(i + 1) % self.points.len()])
    }
}

impl ParamCurve for Polyline {
    fn domain(&self) -> (f64, f64) {
        (0.0, self.segments() as f64)
    }

    fn position(&self, t: f64) -> DVec3 {
        let (i, f) = self.locate(t);
        let (a, b) = self.segment(i);
        a.lerp(b, f)
    }

    fn is_closed(&self) -> bool {
        self.closed
    }
}

impl ParamCurveDeriv for Polyline {
    fn derivative(&self, t: f64) -> DVec3 {
        let (i, _) = self.locate(t);
        let (a, b) = self.segment(i);
        b - a
    }

    /// The interior vertices `1, 2, .., segments - 1`.
    fn breaks(&self) -> Vec<f64> {
        (1..self.segments()).map(|i| i as f64).collect()
    }
}

impl ArcParam for Polyline {
    fn length(&self) -> f64 {
        self.cumulative[self.segments()]
    }

    /// Zero: the arc length of a polyline is the exact sum of its segment lengths (up to
    /// rounding in that sum).
    fn length_error_bound(&self) -> f64 {
        0.0
    }

    fn arc_length_at(&self, t: f64) -> f64 {
        let (i, f) = self.locate(t);
        let seg = self.cumulative[i + 1] - self.cumulative[i];
        self.cumulative[i] + f * seg
    }

    fn param_at(&self, s: f64) -> f64 {
        let n = self.segments();
        if s.is_nan() || s <= 0.0 {
            return 0.0;
        }
        if s >= self.length() {
            return n as f64;
        }
        // The first segment whose end is past s; zero-length segments are skipped.
        let i = self.cumulative[1..].partition_point(|&c| c <= s).min(n - 1);
        let seg = self.cumulative[i + 1] - self.cumulative[i];
        let f = if seg > 0.0 {
            ((s - self.cumulative[i]) / seg).clamp(0.0, 1.0)
        } else {
            0.0
        };
        i as f64 + f
    }
}
