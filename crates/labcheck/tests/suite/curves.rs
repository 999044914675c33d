//! Properties of sinew-curves: arc length within its stated tolerance of an independent
//! reference, evenly resampled spacing within its stated bound, and resampling
//! idempotent within its stated bound (docs/labcheck.md).

use proptest::prelude::*;
use sinew_curves::{
    ArcLengthTable, ArcParam, CurveError, Ends, Epicycloid, ParamCurve, Polyline, Rose,
    resample_evenly,
};
use sinew_labcheck::bounds::EPS;
use sinew_labcheck::config;
use sinew_labcheck::reference::curves::{
    RoseArcLength, epicycloid_arc_length, polyline_arc_length,
};
use sinew_labcheck::strategies::curves::{
    epicycloid, equal_step_polyline, polyline, polyline_points, regular_polygon,
    relative_tolerance, rose,
};
use sinew_math::DVec3;
use std::f64::consts::TAU;

/// The reference arc length of a flower curve, as a closure over its parameter.
enum Flower {
    Epicycloid(Epicycloid),
    Rose(Rose, RoseArcLength),
}

impl std::fmt::Debug for Flower {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Epicycloid(e) => write!(f, "{e:?}"),
            Self::Rose(r, _) => write!(f, "{r:?}"),
        }
    }
}

impl Flower {
    fn arc(&self, t: f64) -> f64 {
        match self {
            Self::Epicycloid(e) => epicycloid_arc_length(e.petals(), e.r(), t),
            Self::Rose(_, reference) => reference.at(t),
        }
    }

    fn length(&self) -> f64 {
        match self {
            Self::Epicycloid(e) => self.arc(e.domain().1),
            Self::Rose(r, _) => self.arc(r.domain().1),
        }
    }

    /// The table, or `None` when it refuses the tolerance as below its rounding floor
    /// (an honest answer; how low it goes is the property
    /// `tables_reach_1e_12_of_the_length`). Any other error fails the case.
    fn table(&self, tolerance: f64) -> Result<Option<ArcLengthTable>, TestCaseError> {
        let table = match self {
            Self::Epicycloid(e) => ArcLengthTable::new(e, tolerance),
            Self::Rose(r, _) => ArcLengthTable::new(r, tolerance),
        };
        match table {
            Ok(t) => Ok(Some(t)),
            Err(CurveError::ToleranceNotReached { .. }) => Ok(None),
            Err(e) => Err(TestCaseError::fail(e.to_string())),
        }
    }

    fn domain(&self) -> (f64, f64) {
        match self {
            Self::Epicycloid(e) => e.domain(),
            Self::Rose(r, _) => r.domain(),
        }
    }

    /// The curve's cusps (epicycloid) or none.
    fn cusps(&self) -> Vec<f64> {
        match self {
            Self::Epicycloid(e) => e.cusps(),
            Self::Rose(..) => Vec::new(),
        }
    }
}

fn flower() -> impl Strategy<Value = Flower> {
    prop_oneof![
        epicycloid().prop_map(Flower::Epicycloid),
        rose().prop_map(|r| {
            let reference = RoseArcLength::new(r.k(), r.a());
            Flower::Rose(r, reference)
        }),
    ]
}

/// The reference's own rounding: a handful of operations on numbers of the size of the
/// length (docs/labcheck.md).
fn reference_rounding(length: f64) -> f64 {
    16.0 * EPS * length
}

proptest! {
    #![proptest_config(config::standard())]

    /// `|arc_length_at(t) - s(t)| <= tolerance` at random parameters, at every cusp and
    /// next to it, and for the total length; the table's own bound is within the
    /// tolerance.
    #[test]
    fn arc_length_within_tolerance(
        curve in flower(),
        relative in relative_tolerance(),
        ts in prop::collection::vec(0.0f64..=1.0, 16),
    ) {
        let length = curve.length();
        let tolerance = relative * length;
        let Some(table) = curve.table(tolerance)? else {
            return Ok(());
        };
        prop_assert!(table.length_error_bound() <= tolerance);
        let allowed = tolerance + reference_rounding(length);
        prop_assert!(
            (table.length() - length).abs() <= allowed,
            "length {} vs {length}: off by {:e} > {allowed:e}",
            table.length(),
            (table.length() - length).abs()
        );
        let (t0, t1) = curve.domain();
        let mut params: Vec<f64> = ts.iter().map(|u| t0 + (t1 - t0) * u).collect();
        for c in curve.cusps() {
            params.extend([c, c - 1e-9, c + 1e-9, c - 1e-4, c + 1e-4]);
        }
        for t in params.into_iter().filter(|t| (t0..=t1).contains(t)) {
            let off = (table.arc_length_at(t) - curve.arc(t)).abs();
            prop_assert!(off <= allowed, "s({t}): off by {off:e} > {allowed:e}");
        }
    }

    /// The table is built (not refused) for every tolerance down to 1e-12 of the
    /// curve's length: docs/curves.md says refusals happen only below about 1e-13 for
    /// curves of length 10 or more, i.e. where rounding of the speed values alone
    /// approaches the tolerance (a few hundred EPS of the length).
    #[test]
    fn tables_reach_1e_12_of_the_length(curve in flower(), relative in relative_tolerance()) {
        let length = curve.length();
        let refused = curve.table(relative * length)?.is_none();
        prop_assert!(!refused, "refused tolerance {:e} (relative {relative:e})", relative * length);
    }

    /// Evenly resampled points are evenly spaced in true arc length: every gap is within
    /// `2 tolerance` (plus rounding) of `length / n`, as docs/curves.md states.
    #[test]
    fn resampled_spacing_within_its_bound(
        curve in flower(),
        relative in relative_tolerance(),
        n in 1usize..=400,
    ) {
        let length = curve.length();
        let tolerance = relative * length;
        let Some(table) = curve.table(tolerance)? else {
            return Ok(());
        };
        let samples = match &curve {
            Flower::Epicycloid(e) => resample_evenly(e, &table, n),
            Flower::Rose(r, _) => resample_evenly(r, &table, n),
        }
        .map_err(|e| TestCaseError::fail(e.to_string()))?;
        prop_assert_eq!(samples.points.len(), n);
        let s: Vec<f64> = samples.params.iter().map(|&t| curve.arc(t)).collect();
        let mut gaps: Vec<f64> = s.windows(2).map(|w| w[1] - w[0]).collect();
        gaps.push(length - s[n - 1] + s[0]);
        let wanted = table.length() / n as f64;
        let allowed = 2.0 * tolerance + 2.0 * reference_rounding(length);
        for (i, d) in gaps.iter().enumerate() {
            prop_assert!(
                (d - wanted).abs() <= allowed,
                "gap {i}: {d} vs {wanted}, off by {:e} > {allowed:e}",
                (d - wanted).abs()
            );
        }
    }

    /// Random polylines (zero-length segments included) are their own exact arc-length
    /// parameterization: their length and resampled gaps agree with a direct sum.
    #[test]
    fn polyline_resampling_is_exactly_even(line in polyline(), n in 2usize..=200) {
        let points = line.points().to_vec();
        let closed = line.is_closed();
        let length = line.length();
        let direct = polyline_arc_length(&points, closed, line.domain().1);
        let rounding = 16.0 * EPS * (length + points.iter().map(|p| p.length()).sum::<f64>());
        prop_assert!((length - direct).abs() <= rounding);
        let samples = resample_evenly(&line, &line, n).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let s: Vec<f64> = samples.params.iter().map(|&t| polyline_arc_length(&points, closed, t)).collect();
        let mut gaps: Vec<f64> = s.windows(2).map(|w| w[1] - w[0]).collect();
        let wanted = if closed {
            gaps.push(direct - s[n - 1] + s[0]);
            length / n as f64
        } else {
            length / (n - 1) as f64
        };
        for (i, d) in gaps.iter().enumerate() {
            prop_assert!((d - wanted).abs() <= 2.0 * rounding, "gap {i}: {d} vs {wanted}");
        }
    }

    /// Points already evenly spaced are a fixed point of even resampling: an open
    /// polyline with equal segments, resampled to as many points, returns its vertices.
    #[test]
    fn resampling_equal_steps_changes_nothing(points in equal_step_polyline()) {
        check_fixed_point(points, false)?;
    }

    /// The same for a closed polyline with equal sides (a regular polygon).
    #[test]
    fn resampling_a_regular_polygon_changes_nothing(points in regular_polygon()) {
        check_fixed_point(points, true)?;
    }

    /// Resampling an evenly resampled curve again, through the polyline of its points,
    /// moves each point by at most the stated bound `|C_i - i L_poly / n|` (docs/curves.md:
    /// `C_i` the polyline arc length at vertex `i`).
    #[test]
    fn resampling_twice_moves_points_within_the_bound(
        curve in flower(),
        n in 3usize..=300,
    ) {
        let length = curve.length();
        let Some(table) = curve.table(1e-10 * length)? else {
            return Err(TestCaseError::fail("refused a tolerance of 1e-10 of the length"));
        };
        let first = match &curve {
            Flower::Epicycloid(e) => resample_evenly(e, &table, n),
            Flower::Rose(r, _) => resample_evenly(r, &table, n),
        }
        .map_err(|e| TestCaseError::fail(e.to_string()))?;
        let vertices = first.points.clone();
        let line = Polyline::new(vertices.clone(), Ends::Closed).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let second = resample_evenly(&line, &line, n).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let poly_length = line.length();
        let scale: f64 = vertices.iter().map(|p| p.length()).fold(0.0, f64::max) + poly_length;
        for (i, (v, p)) in vertices.iter().zip(&second.points).enumerate() {
            let c_i = polyline_arc_length(&vertices, true, i as f64);
            let bound = (c_i - poly_length * i as f64 / n as f64).abs();
            let allowed = bound + 16.0 * EPS * (n as f64 + 1.0) * scale;
            prop_assert!(
                v.distance(*p) <= allowed,
                "point {i} moved {:e} > {allowed:e}",
                v.distance(*p)
            );
        }
    }
}

/// Resamples the polyline through `points` to as many points and checks every point comes
/// back onto its vertex, up to the rounding of the cumulative lengths (docs/labcheck.md).
fn check_fixed_point(points: Vec<DVec3>, closed: bool) -> Result<(), TestCaseError> {
    let n = points.len();
    let line = Polyline::new(
        points.clone(),
        if closed { Ends::Closed } else { Ends::Open },
    )
    .map_err(|e| TestCaseError::fail(e.to_string()))?;
    let samples =
        resample_evenly(&line, &line, n).map_err(|e| TestCaseError::fail(e.to_string()))?;
    let scale = points.iter().map(|p| p.length()).fold(0.0, f64::max) + line.length();
    let allowed = 16.0 * EPS * (n as f64 + 1.0) * scale;
    for (i, (v, p)) in points.iter().zip(&samples.points).enumerate() {
        prop_assert!(
            v.distance(*p) <= allowed,
            "vertex {i} moved by {:e} > {allowed:e}",
            v.distance(*p)
        );
    }
    Ok(())
}

/// The independent rose reference agrees with the closed form `2 k a E(1 - 1/k^2)`
/// (odd `k`) or `4 k a E(1 - 1/k^2)` (even `k`) that sinew-curves computes by the AGM:
/// two different methods, agreeing to rounding.
#[test]
fn rose_reference_agrees_with_the_elliptic_closed_form() {
    for k in 1..=12u32 {
        let rose = Rose::from_frequency(k, 0.7, sinew_curves::Plane::default()).expect("valid");
        let reference = RoseArcLength::new(k, 0.7);
        let mine = reference.at(rose.domain().1);
        let theirs = rose.exact_length();
        assert!(
            (mine - theirs).abs() <= 16.0 * EPS * theirs,
            "k = {k}: {mine} vs {theirs}"
        );
    }
    // The circle (k = 1) has length pi a.
    let circle = RoseArcLength::new(1, 2.0);
    assert!((circle.at(std::f64::consts::PI) - 2.0 * std::f64::consts::PI).abs() < 1e-14);
}

/// The epicycloid closed form: the lab flower is 4.8 long, and each arch is `48 a / 5`.
#[test]
fn epicycloid_reference_matches_the_lab_flower() {
    assert!((epicycloid_arc_length(5, 0.1, TAU) - 4.8).abs() < 1e-15);
    assert!((epicycloid_arc_length(5, 0.1, TAU / 5.0) - 0.96).abs() < 1e-15);
    assert!((epicycloid_arc_length(5, 0.1, TAU / 10.0) - 0.48).abs() < 1e-15);
}

/// Unused-strategy guard: random polyline points include repeats.
#[test]
fn polyline_points_strategy_is_usable() {
    use proptest::strategy::ValueTree;
    let mut runner = proptest::test_runner::TestRunner::deterministic();
    let points = polyline_points(2..=5)
        .new_tree(&mut runner)
        .expect("a value")
        .current();
    assert!((2..=5).contains(&points.len()));
}
