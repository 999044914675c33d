//! Curves: evenly spaced points on the lab flower (length exactly 4.8), by
//! uniform-parameter sampling (the lab report's approach), by resampling a dense
//! uniform polyline, and by sinew-curves' arc-length resampling, over sample counts and
//! tolerances.
//!
//! Errors, both against the closed forms: the spacing deviation (largest relative
//! deviation of the exact arc length between consecutive points, wrap gap included,
//! from the even spacing L/N) and the length error (|length the method reports or
//! implies - 4.8|). Time is per call (everything needed to produce the points, table
//! build included unless the knobs say "table reused").

use super::{Metric, Metrics, Plan, Record, Section, measure, sci};
use serde_json::json;
use sinew_curves::{
    ArcLengthTable, ArcParam, Ends, Epicycloid, Polyline, Samples, resample_evenly, sample_uniform,
};
use sinew_math::DVec3;
use std::f64::consts::TAU;

/// Largest relative deviation of the exact arc spacing from `L / N`, wrap gap included.
fn spacing_deviation(flower: &Epicycloid, params: &[f64]) -> f64 {
    let length = flower.exact_length();
    let arc: Vec<f64> = params.iter().map(|&t| flower.exact_arc_length(t)).collect();
    let n = arc.len();
    let even = length / n as f64;
    (0..n)
        .map(|i| {
            let gap = if i + 1 < n {
                arc[i + 1] - arc[i]
            } else {
                length - arc[i] + arc[0]
            };
            (gap - even).abs() / even
        })
        .fold(0.0, f64::max)
}

/// Length of the closed polyline through `points`.
fn closed_length(points: &[DVec3]) -> f64 {
    let n = points.len();
    (0..n)
        .map(|i| points[i].distance(points[(i + 1) % n]))
        .sum()
}

/// 500 points from a dense uniform polyline of `m` vertices, resampled evenly along the
/// polyline; the returned parameters are the flower's (vertex i is the flower at
/// `2 pi i / m`, linear in between), so the spacing can be measured exactly.
fn dense_polyline(flower: &Epicycloid, m: usize, n: usize) -> Result<(Samples, f64), String> {
    let dense = sample_uniform(flower, m).map_err(|e| e.to_string())?;
    let poly = Polyline::new(dense.points, Ends::Closed).map_err(|e| e.to_string())?;
    let length = closed_length(poly.points());
    let mut s = resample_evenly(&poly, &poly, n).map_err(|e| e.to_string())?;
    for t in &mut s.params {
        *t *= TAU / m as f64;
    }
    Ok((s, length))
}

struct Config {
    method: &'static str,
    knobs: String,
    points: usize,
    run: Box<dyn Fn() -> Result<(Samples, f64), String>>,
}

/// Runs the curves section.
pub fn run(plan: &Plan) -> Result<Vec<Record>, String> {
    let flower = Epicycloid::lab_flower();
    let exact = flower.exact_length();
    let mut configs: Vec<Config> = Vec::new();
    let (uniform_counts, dense_counts, tolerances, arclen_counts): (
        &[usize],
        &[usize],
        &[f64],
        &[usize],
    ) = if plan.quick {
        (&[500, 5_000], &[5_000], &[1e-3, 1e-9], &[5_000])
    } else {
        (
            &[500, 2_000, 10_000, 50_000],
            &[5_000, 50_000, 500_000],
            &[1e-3, 1e-6, 1e-9, 1e-12],
            &[2_000, 10_000, 50_000],
        )
    };
    for &n in uniform_counts {
        let f = flower;
        configs.push(Config {
            method: "uniform parameter",
            knobs: format!("N {n}"),
            points: n,
            run: Box::new(move || {
                let s = sample_uniform(&f, n).map_err(|e| e.to_string())?;
                let length = closed_length(&s.points);
                Ok((s, length))
            }),
        });
    }
    for &m in dense_counts {
        let f = flower;
        configs.push(Config {
            method: "dense polyline",
            knobs: format!("M {m} -> N 500"),
            points: 500,
            run: Box::new(move || dense_polyline(&f, m, 500)),
        });
    }
    let arclen = |n: usize, tol: f64| -> Config {
        let f = flower;
        Config {
            method: "arc length",
            knobs: format!("N {n}, tol {}", sci(tol)),
            points: n,
            run: Box::new(move || {
                let table = ArcLengthTable::new(&f, tol).map_err(|e| e.to_string())?;
                let s = resample_evenly(&f, &table, n).map_err(|e| e.to_string())?;
                Ok((s, table.length()))
            }),
        }
    };
    for &tol in tolerances {
        configs.push(arclen(500, tol));
    }
    for &n in arclen_counts {
        configs.push(arclen(n, 1e-9));
    }
    let table = ArcLengthTable::new(&flower, 1e-9).map_err(|e| e.to_string())?;
    let reused_length = table.length();
    let f = flower;
    configs.push(Config {
        method: "arc length",
        knobs: "N 500, tol 1e-9, table reused".into(),
        points: 500,
        run: Box::new(move || {
            let s = resample_evenly(&f, &table, 500).map_err(|e| e.to_string())?;
            Ok((s, reused_length))
        }),
    });

    let mut records = Vec::new();
    for c in &configs {
        let (time, first) = measure(plan, plan.repeats, 1, || (c.run)());
        let (samples, length) = first?;
        let deviation = spacing_deviation(&flower, &samples.params);
        let mut metrics = Metrics::new();
        metrics.insert(Metric::Points, json!(c.points));
        metrics.insert(Metric::SpacingDeviation, json!(deviation));
        metrics.insert(Metric::LengthError, json!((length - exact).abs()));
        metrics.insert(Metric::TimePerPointS, json!(time.median / c.points as f64));
        records.push(Record {
            section: Section::Curves,
            workload: "flower".into(),
            method: c.method.into(),
            knobs: c.knobs.clone(),
            unit: "call",
            time,
            error: deviation,
            error_name: "largest relative deviation of the exact arc spacing",
            metrics,
            note: String::new(),
        });
    }
    eprintln!("  {} configurations done", records.len());
    Ok(records)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn even_parameters_of_the_flower_are_uneven_and_exact_ones_are_even() {
        let f = Epicycloid::lab_flower();
        // Uniform parameters: near a cusp the arc spacing is far below L/N.
        let uniform: Vec<f64> = (0..500).map(|i| TAU * i as f64 / 500.0).collect();
        assert!(spacing_deviation(&f, &uniform) > 0.5);
        // Parameters at exactly even arc length (inverting the closed form on the first
        // arch by bisection) are even to round-off.
        let arch = f.exact_length() / 5.0;
        let even: Vec<f64> = (0..500)
            .map(|i| {
                let s = f.exact_length() * i as f64 / 500.0;
                let j = (s / arch).floor();
                let (mut lo, mut hi) = (TAU * j / 5.0, TAU * (j + 1.0) / 5.0);
                for _ in 0..200 {
                    let mid = 0.5 * (lo + hi);
                    if f.exact_arc_length(mid) < s {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                0.5 * (lo + hi)
            })
            .collect();
        assert!(spacing_deviation(&f, &even) < 1e-10);
    }
}
