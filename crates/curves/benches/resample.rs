//! Time against evenness on the lab flower, and per-point inverse cost against kurbo.
//!
//! Groups:
//! - `flower_uniform/N`: uniform-parameter sampling (the lab report's approach), N points.
//! - `flower_dense_polyline/M`: M uniform samples turned into a polyline, resampled to 500
//!   points by its exact chord length (what dense sampling can buy at best).
//! - `flower_arclen_500/tol`: table build plus 500 evenly spaced points.
//! - `flower_arclen_500_reused/tol`: 500 points with the table already built.
//! - `inverse_per_point`: one `param_at` (plus position) per call, 1e-9, on the flower and
//!   on kurbo's test cubic via `FnCurve`, next to kurbo's `inv_arclen` on the same cubic.
//!
//! Before the timings, the evenness of each configuration (exact arc spacing from the
//! closed form) is printed to stderr, so time and evenness can be put side by side.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use kurbo::{CubicBez, ParamCurveArclen};
use sinew_curves::{
    ArcLengthTable, ArcParam, Ends, Epicycloid, FnCurve, ParamCurve, Polyline, Samples,
    resample_evenly, sample_uniform,
};
use sinew_math::DVec3;
use std::hint::black_box;

const TOLERANCES: [f64; 6] = [1e-3, 1e-6, 1e-9, 1e-10, 1e-11, 1e-12];

/// Largest relative deviation of the exact arc spacing (closed form), wrap gap included.
fn exact_arc_rel_dev(f: &Epicycloid, s: &Samples) -> f64 {
    let arc: Vec<f64> = s.params.iter().map(|&t| f.exact_arc_length(t)).collect();
    let n = arc.len();
    let h = f.exact_length() / n as f64;
    let mut worst: f64 = 0.0;
    for i in 0..n {
        let gap = if i + 1 < n {
            arc[i + 1] - arc[i]
        } else {
            f.exact_length() - arc[i] + arc[0]
        };
        worst = worst.max((gap - h).abs() / h);
    }
    worst
}

fn dense_polyline(f: &Epicycloid, m: usize, n: usize) -> Samples {
    let dense = sample_uniform(f, m).unwrap();
    let poly = Polyline::new(dense.points, Ends::Closed).unwrap();
    let mut s = resample_evenly(&poly, &poly, n).unwrap();
    // Map back to flower parameters: polyline vertex i is the flower at 2 pi i / m.
    for t in &mut s.params {
        *t *= std::f64::consts::TAU / m as f64;
    }
    s
}

fn evenness_report() {
    let f = Epicycloid::lab_flower();
    eprintln!("evenness (exact arc spacing, largest relative deviation), lab flower:");
    for n in [500, 2000, 20_000, 50_000] {
        let s = sample_uniform(&f, n).unwrap();
        eprintln!(
            "  uniform N={n}: arc {:.3e}, chord {:.3e}",
            exact_arc_rel_dev(&f, &s),
            s.chord.rel_dev_max
        );
    }
    for m in [2000, 20_000, 50_000] {
        let s = dense_polyline(&f, m, 500);
        eprintln!(
            "  dense polyline M={m} -> 500: arc {:.3e} (point positions are on the polyline, \
             so within its chord error of the curve)",
            exact_arc_rel_dev(&f, &s)
        );
    }
    for tol in TOLERANCES {
        let table = ArcLengthTable::new(&f, tol).unwrap();
        let s = resample_evenly(&f, &table, 500).unwrap();
        eprintln!(
            "  arc-length N=500 tol {tol:.0e}: arc {:.3e}, chord {:.3e}, panels {}, length error {:.1e}",
            exact_arc_rel_dev(&f, &s),
            s.chord.rel_dev_max,
            table.panel_count(),
            table.length() - 4.8
        );
    }
}

fn flower(c: &mut Criterion) {
    evenness_report();
    let f = Epicycloid::lab_flower();
    let mut g = c.benchmark_group("flower_uniform");
    for n in [500, 2000, 20_000, 50_000] {
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, &n| {
            b.iter(|| sample_uniform(black_box(&f), n).unwrap())
        });
    }
    g.finish();
    let mut g = c.benchmark_group("flower_dense_polyline");
    for m in [2000, 20_000, 50_000] {
        g.bench_with_input(BenchmarkId::from_parameter(m), &m, |b, &m| {
            b.iter(|| dense_polyline(black_box(&f), m, 500))
        });
    }
    g.finish();
    let mut g = c.benchmark_group("flower_arclen_500");
    for tol in TOLERANCES {
        g.bench_with_input(BenchmarkId::from_parameter(tol), &tol, |b, &tol| {
            b.iter(|| {
                let table = ArcLengthTable::new(black_box(&f), tol).unwrap();
                resample_evenly(&f, &table, 500).unwrap()
            })
        });
    }
    g.finish();
    let mut g = c.benchmark_group("flower_arclen_500_reused");
    for tol in TOLERANCES {
        let table = ArcLengthTable::new(&f, tol).unwrap();
        g.bench_with_input(BenchmarkId::from_parameter(tol), &tol, |b, _| {
            b.iter(|| resample_evenly(black_box(&f), &table, 500).unwrap())
        });
    }
    g.finish();
}

fn cubic(t: f64) -> DVec3 {
    let u = 1.0 - t;
    DVec3::new(0.3, 1.0, 0.0) * 3.0 * u * u * t
        + DVec3::new(0.7, -1.0, 0.0) * 3.0 * u * t * t
        + DVec3::new(1.0, 0.0, 0.0) * t * t * t
}

fn cubic_derivative(t: f64) -> DVec3 {
    let u = 1.0 - t;
    3.0 * (DVec3::new(0.3, 1.0, 0.0) * u * u
        + DVec3::new(0.4, -2.0, 0.0) * 2.0 * u * t
        + DVec3::new(0.3, 1.0, 0.0) * t * t)
}

fn inverse(c: &mut Criterion) {
    const CALLS: usize = 1000;
    let mut g = c.benchmark_group("inverse_per_point");
    let f = Epicycloid::lab_flower();
    let table = ArcLengthTable::new(&f, 1e-9).unwrap();
    let len = table.length();
    g.bench_function("sinew_flower_1e-9_x1000", |b| {
        b.iter(|| {
            let mut acc = DVec3::ZERO;
            for i in 0..CALLS {
                let t = table.param_at(black_box(len * (i as f64 + 0.5) / CALLS as f64));
                acc += f.position(t);
            }
            acc
        })
    });
    let bez = FnCurve::with_derivative(0.0, 1.0, Ends::Open, cubic, cubic_derivative).unwrap();
    let btable = ArcLengthTable::new(&bez, 1e-9).unwrap();
    let blen = btable.length();
    g.bench_function("sinew_cubic_1e-9_x1000", |b| {
        b.iter(|| {
            let mut acc = DVec3::ZERO;
            for i in 0..CALLS {
                let t = btable.param_at(black_box(blen * (i as f64 + 0.5) / CALLS as f64));
                acc += bez.position(t);
            }
            acc
        })
    });
    g.bench_function("sinew_cubic_table_build_1e-9", |b| {
        b.iter(|| ArcLengthTable::new(black_box(&bez), 1e-9).unwrap())
    });
    let kb = CubicBez::new((0.0, 0.0), (0.3, 1.0), (0.7, -1.0), (1.0, 0.0));
    let klen = kb.arclen(1e-12);
    eprintln!(
        "cubic length: sinew {blen:.15} (bound {:.0e}), kurbo arclen(1e-12) {klen:.15}",
        btable.error_bound()
    );
    g.bench_function("kurbo_cubic_inv_arclen_1e-9_x1000", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for i in 0..CALLS {
                acc += kb.inv_arclen(black_box(klen * (i as f64 + 0.5) / CALLS as f64), 1e-9);
            }
            acc
        })
    });
    g.finish();
    // Accuracy of both inverses against a tight sinew table (bound 1e-13).
    let reference = ArcLengthTable::new(&bez, 1e-13).unwrap();
    let (mut worst_sinew, mut worst_kurbo) = (0.0_f64, 0.0_f64);
    for i in 0..CALLS {
        let s = blen * (i as f64 + 0.5) / CALLS as f64;
        worst_sinew = worst_sinew.max((reference.arc_length_at(btable.param_at(s)) - s).abs());
        worst_kurbo = worst_kurbo.max((reference.arc_length_at(kb.inv_arclen(s, 1e-9)) - s).abs());
    }
    eprintln!(
        "cubic inverse at 1e-9, worst |s(t(s)) - s|: sinew {worst_sinew:.1e}, kurbo {worst_kurbo:.1e}"
    );
}

criterion_group!(benches, flower, inverse);
criterion_main!(benches);
