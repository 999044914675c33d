//! Your own curve, two ways, resampled at even arc-length spacing.
//!
//! Run with `cargo run --release -p sinew-curves --example custom_curve`.
//!
//! 1. A type implementing [`ParamCurve`] and [`ParamCurveDeriv`]: an ellipse, with its
//!    exact derivative, so arc length is as accurate as the tolerance asked for.
//! 2. The same ellipse from a closure with [`FnCurve`], differentiated numerically.
//!
//! The ellipse's length has no elementary closed form; both are checked against the
//! complete elliptic integral, `4 a E(1 - b^2/a^2)`.

use sinew_curves::{
    ArcLengthTable, ArcParam, DVec3, Ends, FnCurve, ParamCurve, ParamCurveDeriv,
    complete_elliptic_e, resample_evenly,
};
use std::f64::consts::TAU;

/// An ellipse in the x-z plane with semi-axes `a` (along x) and `b` (along z).
struct Ellipse {
    a: f64,
    b: f64,
}

impl ParamCurve for Ellipse {
    fn domain(&self) -> (f64, f64) {
        (0.0, TAU)
    }

    fn position(&self, t: f64) -> DVec3 {
        DVec3::new(self.a * t.cos(), 0.0, self.b * t.sin())
    }

    fn is_closed(&self) -> bool {
        true
    }
}

impl ParamCurveDeriv for Ellipse {
    fn derivative(&self, t: f64) -> DVec3 {
        DVec3::new(-self.a * t.sin(), 0.0, self.b * t.cos())
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (a, b) = (0.5, 0.2);
    let exact = 4.0 * a * complete_elliptic_e(1.0 - (b * b) / (a * a));

    // 1. The trait implementation, to 1e-12.
    let ellipse = Ellipse { a, b };
    let table = ArcLengthTable::new(&ellipse, 1e-12)?;
    println!(
        "ellipse (own type): length {:.15} (exact {exact:.15}, error {:.1e})",
        table.length(),
        (table.length() - exact).abs()
    );
    assert!((table.length() - exact).abs() <= 1e-12);

    let samples = resample_evenly(&ellipse, &table, 64)?;
    let arc = samples
        .arc
        .expect("an arc-length resampling reports its evenness");
    println!(
        "64 points at even spacing: largest relative deviation of a gap {:.1e}",
        arc.rel_dev_max
    );
    assert!(arc.rel_dev_max < 1e-9);

    // 2. A closure, with the derivative left to a sixth-order central difference.
    let from_closure = FnCurve::new(0.0, TAU, Ends::Closed, |t: f64| {
        DVec3::new(a * t.cos(), 0.0, b * t.sin())
    })?;
    let table = ArcLengthTable::new(&from_closure, 1e-10)?;
    println!(
        "ellipse (closure):  length {:.15} (error {:.1e})",
        table.length(),
        (table.length() - exact).abs()
    );
    assert!((table.length() - exact).abs() <= 1e-9);
    Ok(())
}
