//! Helpers shared by the integration tests: independent reference quadrature and grids.

#![allow(dead_code)]

/// Composite Simpson's rule with `n` (even) panels: an independent reference for smooth
/// integrands, truncation error `(b - a) h^4 max|f^(4)| / 180`. The sum is compensated
/// (Neumaier), so many panels do not pile up rounding.
pub fn simpson<F: Fn(f64) -> f64>(f: F, a: f64, b: f64, n: usize) -> f64 {
    assert!(n.is_multiple_of(2));
    let h = (b - a) / n as f64;
    let mut sum = 0.0_f64;
    let mut comp = 0.0_f64;
    let mut add = |x: f64| {
        let t = sum + x;
        comp += if sum.abs() >= x.abs() {
            (sum - t) + x
        } else {
            (x - t) + sum
        };
        sum = t;
    };
    add(f(a));
    add(f(b));
    for i in 1..n {
        let w = if i % 2 == 1 { 4.0 } else { 2.0 };
        add(w * f(a + (b - a) * (i as f64 / n as f64)));
    }
    (sum + comp) * h / 3.0
}

/// The tolerances every accuracy test sweeps: 1e-3, 1e-4, ..., 1e-13.
pub fn tolerances() -> impl Iterator<Item = f64> {
    (3..=13).map(|e| 10f64.powi(-e))
}

/// `n + 1` evenly spaced parameters over `[t0, t1]`.
pub fn grid(t0: f64, t1: f64, n: usize) -> Vec<f64> {
    (0..=n)
        .map(|i| t0 + (t1 - t0) * i as f64 / n as f64)
        .collect()
}
