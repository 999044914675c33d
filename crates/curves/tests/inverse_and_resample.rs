//! The inverse t(s) at and near cusps, and resampling: evenness against the closed form,
//! spacing-based sampling, idempotence, and the uniform-parameter baseline.

mod common;

use common::{grid, tolerances};
use sinew_curves::{
    ArcLengthTable, ArcParam, Ends, Epicycloid, ParamCurve, Plane, Polyline, resample_by_spacing,
    resample_evenly, sample_uniform,
};
use std::f64::consts::TAU;

/// Rate at which the flower's speed grows away from a cusp: d/dt 12 a |sin(5t/2)| = 30 a.
const CUSP_SLOPE: f64 = 3.0;

#[test]
fn inverse_is_within_tolerance_of_the_closed_form_everywhere() {
    let f = Epicycloid::lab_flower();
    for tol in tolerances() {
        let table = ArcLengthTable::new(&f, tol).unwrap();
        let mut previous = -1.0;
        for s in grid(0.0, 4.8, 1999) {
            let (t, iterations) = table.param_at_with_iterations(s);
            assert!(iterations <= 60, "s {s}: {iterations} iterations");
            let err = (f.exact_arc_length(t) - s).abs();
            assert!(err <= tol + 1e-14, "tol {tol:e} s {s}: {err:e}");
            assert!(t >= previous, "not monotone at s {s}");
            previous = t;
            // And back: s(t(s)) from the table matches s to rounding.
            assert!((table.arc_length_at(t) - s).abs() <= 1e-14);
        }
    }
}

#[test]
fn inverse_at_and_near_cusps() {
    let f = Epicycloid::lab_flower();
    for tol in [1e-6, 1e-9, 1e-12] {
        let table = ArcLengthTable::new(&f, tol).unwrap();
        for (j, &tc) in f.cusps().iter().enumerate() {
            let sc = f.exact_arc_length(tc);
            assert!((sc - 0.96 * j as f64).abs() < 1e-14);
            // At the cusp: an s error e moves t by sqrt(2 e / slope) there.
            let t = table.param_at(sc);
            let allowed = (2.0 * (tol + 1e-14) / CUSP_SLOPE).sqrt() + 1e-12;
            assert!(
                (t - tc).abs() <= allowed,
                "cusp {j} tol {tol:e}: {t} vs {tc}"
            );
            for ds in [1e-15, 1e-12, 1e-9, 1e-6, 1e-3] {
                for s in [sc - ds, sc + ds] {
                    if !(0.0..=4.8).contains(&s) {
                        continue;
                    }
                    let (t, iterations) = table.param_at_with_iterations(s);
                    assert!(iterations <= 60);
                    let err = (f.exact_arc_length(t) - s).abs();
                    assert!(err <= tol + 1e-14, "cusp {j} ds {ds:e}: {err:e}");
                    // On the right side of the cusp.
                    if ds > tol {
                        assert_eq!(t > tc, s > sc, "cusp {j} ds {ds:e}");
                    }
                }
            }
        }
    }
}

#[test]
fn inverse_clamps_and_never_returns_nan() {
    let f = Epicycloid::lab_flower();
    let table = ArcLengthTable::new(&f, 1e-9).unwrap();
    assert_eq!(table.param_at(f64::NAN), 0.0);
    assert_eq!(table.param_at(-1.0), 0.0);
    assert_eq!(table.param_at(1e9), TAU);
    assert_eq!(table.param_at(f64::INFINITY), TAU);
    assert_eq!(table.arc_length_at(f64::NAN), 0.0);
    assert!((table.arc_length_at(100.0) - 4.8).abs() < 1e-9);
}

#[test]
fn even_resampling_of_the_flower_is_even_by_the_closed_form() {
    let f = Epicycloid::lab_flower();
    let n = 500;
    let h = 4.8 / n as f64;
    for tol in tolerances() {
        let table = ArcLengthTable::new(&f, tol).unwrap();
        let samples = resample_evenly(&f, &table, n).unwrap();
        assert_eq!(samples.points.len(), n);
        assert_eq!(samples.params[0], 0.0);
        assert!(samples.closed);
        // Exact arc spacing, including the wrap-around gap.
        let s: Vec<f64> = samples
            .params
            .iter()
            .map(|&t| f.exact_arc_length(t))
            .collect();
        let mut worst: f64 = 0.0;
        for i in 0..n {
            let gap = if i + 1 < n {
                s[i + 1] - s[i]
            } else {
                4.8 - s[i] + s[0]
            };
            worst = worst.max((gap - h).abs() / h);
        }
        // Each point is within tol of its target, so each gap within 2 tol.
        assert!(worst <= 2.0 * (tol + 1e-14) / h, "tol {tol:e}: {worst:e}");
        let arc = samples.arc.unwrap();
        assert_eq!(arc.gaps, n);
        assert!(arc.rel_dev_max <= 1e-11);
        assert!((samples.length.unwrap() - 4.8).abs() <= tol);
        // Points are the curve's.
        for (p, &t) in samples.points.iter().zip(&samples.params) {
            assert_eq!(*p, f.position(t));
        }
        if tol <= 1e-12 {
            assert!(worst <= 1e-9, "{worst:e}");
        }
    }
}

#[test]
fn uniform_parameter_sampling_is_uneven_at_any_count() {
    let f = Epicycloid::lab_flower();
    let table = ArcLengthTable::new(&f, 1e-12).unwrap();
    for n in [500, 2000, 20_000] {
        let mut samples = sample_uniform(&f, n).unwrap();
        assert_eq!(samples.params[1], TAU / n as f64);
        assert!(samples.arc.is_none());
        samples.measure_arc(&table);
        let arc = samples.arc.unwrap();
        // Speed runs from 0 to 12 a, mean 48 a / 2 pi: gaps from ~0 to pi/2 times the mean.
        assert!(arc.rel_dev_max > 0.5, "n {n}: {}", arc.rel_dev_max);
        assert!(samples.chord.rel_dev_max > 0.5);
    }
}

#[test]
fn resampling_an_evenly_resampled_polyline_changes_little() {
    let f = Epicycloid::lab_flower();
    let table = ArcLengthTable::new(&f, 1e-12).unwrap();
    let n = 500;
    let first = resample_evenly(&f, &table, n).unwrap();
    let poly = Polyline::new(first.points.clone(), Ends::Closed).unwrap();
    let second = resample_evenly(&poly, &poly, n).unwrap();
    // Vertex i sits at polyline arc C_i; the new point i at i L'/n. The new point is on
    // the polyline within |C_i - i L'/n| (along it) of vertex i, which bounds the
    // displacement exactly.
    let total = poly.length();
    let mut worst_ratio: f64 = 0.0;
    for i in 0..n {
        let ci = poly.arc_length_at(i as f64);
        let target = total * i as f64 / n as f64;
        let moved = (second.points[i] - first.points[i]).length();
        assert!(moved <= (ci - target).abs() + 1e-13, "i {i}: {moved:e}");
        worst_ratio = worst_ratio.max(moved / (total / n as f64));
    }
    // How much: chords are shorter than arcs by kappa^2 h^3/24, so the polyline's own
    // spacing is uneven by its chord deviation; measured, the points move by under 5%
    // of a spacing (and by much less away from the cusps).
    assert!(worst_ratio < 0.05, "{worst_ratio}");
    // Resampling the polyline again is exact: it is already even in its own arc length.
    let third = resample_evenly(&poly, &poly, n).unwrap();
    assert_eq!(third.points, second.points);
}

#[test]
fn resampling_by_spacing() {
    let f = Epicycloid::lab_flower();
    let table = ArcLengthTable::new(&f, 1e-12).unwrap();
    // A spacing that divides the length: a closed loop of n points, no remainder.
    let s = resample_by_spacing(&f, &table, 4.8 / 480.0).unwrap();
    assert_eq!(s.points.len(), 480);
    assert_eq!(s.remainder, 0.0);
    assert_eq!(s.arc.unwrap().gaps, 480);
    // One that does not: floor(L/h) + 1 points, the leftover reported and excluded.
    let h = 0.007;
    let s = resample_by_spacing(&f, &table, h).unwrap();
    let full = (4.8_f64 / h).floor();
    assert_eq!(s.points.len(), full as usize + 1);
    assert!((s.remainder - (4.8 - full * h)).abs() < 1e-12);
    let arc = s.arc.unwrap();
    assert_eq!(arc.gaps, full as usize);
    assert!((arc.mean - h).abs() < 1e-12);
    assert!(arc.rel_dev_max < 1e-9);
    for (j, &t) in s.params.iter().enumerate() {
        assert!((f.exact_arc_length(t) - h * j as f64).abs() < 1e-11);
    }
}

#[test]
fn open_curves_include_both_ends() {
    let p = Polyline::new(
        vec![
            sinew_math::DVec3::ZERO,
            sinew_math::DVec3::X,
            sinew_math::DVec3::new(1.0, 3.0, 0.0),
        ],
        Ends::Open,
    )
    .unwrap();
    let s = resample_evenly(&p, &p, 5).unwrap();
    assert_eq!(s.points.first(), Some(&sinew_math::DVec3::ZERO));
    assert_eq!(
        s.points.last(),
        Some(&sinew_math::DVec3::new(1.0, 3.0, 0.0))
    );
    assert_eq!(s.arc.unwrap().gaps, 4);
    assert!(s.arc.unwrap().rel_dev_max < 1e-15);
    assert!((s.points[2] - sinew_math::DVec3::new(1.0, 1.0, 0.0)).length() < 1e-15);
    let u = sample_uniform(&p, 3).unwrap();
    assert_eq!(u.params, vec![0.0, 1.0, 2.0]);
    // A chord along a polyline segment is its arc.
    assert_eq!(u.chord.max, 3.0);
    let _ = Plane::lab();
}
