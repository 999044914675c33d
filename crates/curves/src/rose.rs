//! Rose curves `r = a cos(k theta)` and the complete elliptic integral that gives their
//! length.
//!
//! In the plane, `P(theta) = a cos(k theta) (cos theta, sin theta)`. For odd `k` the curve
//! has `k` petals and is traced once as `theta` runs over `[0, pi]` (on `[pi, 2 pi]` it
//! retraces itself, since `r(theta + pi) = -r(theta)` gives the same point); for even `k`
//! it has `2k` petals and needs `[0, 2 pi]`. The domain is chosen accordingly, so the
//! length is that of the curve drawn once.
//!
//! Speed: `a sqrt(1 + (k^2 - 1) sin^2(k theta))`, smooth and never zero (the curve passes
//! through the origin with speed `a`), so a rose has no break points. Length: with
//! `m = 1 - 1/k^2`, each stretch of `pi/k` in `theta` has length `2 a E(m)`, so the
//! total is `2 k a E(m)` (odd `k`) or `4 k a E(m)` (even `k`); see docs/curves.md.

use crate::error::{CurveError, positive};
use crate::plane::Plane;
use crate::traits::{ParamCurve, ParamCurveDeriv};
use sinew_math::{DVec2, DVec3};
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// A rose `r = a cos(k theta)` placed by a [`Plane`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rose {
    k: u32,
    a: f64,
    plane: Plane,
}

impl Rose {
    /// The rose with `petals` petals and size `a > 0` (the petal length): frequency
    /// `k = petals` for an odd count, `k = petals / 2` for a multiple of four. Other
    /// counts (2, 6, 10, ...) no rose `r = a cos(k theta)` has; they are an error naming
    /// `petals`, as is a bad `a` naming `a`. [`Epicycloid::with_petals`] counts the same
    /// way.
    ///
    /// [`Epicycloid::with_petals`]: crate::Epicycloid::with_petals
    ///
    /// ```
    /// use sinew_curves::{Plane, Rose};
    /// let three = Rose::with_petals(3, 1.0, Plane::default()).unwrap();
    /// assert_eq!((three.petal_count(), three.k()), (3, 3));
    /// let four = Rose::with_petals(4, 1.0, Plane::default()).unwrap();
    /// assert_eq!((four.petal_count(), four.k()), (4, 2));
    /// let err = Rose::with_petals(6, 1.0, Plane::default()).unwrap_err();
    /// assert!(err.to_string().contains("petals"));
    /// ```
    pub fn with_petals(petals: u32, a: f64, plane: Plane) -> Result<Self, CurveError> {
        let k = match petals {
            0 => return Err(CurveError::invalid("petals", "must be at least 1, got 0")),
            p if p % 2 == 1 => p,
            p if p % 4 == 0 => p / 2,
            p => {
                return Err(CurveError::invalid(
                    "petals",
                    format!(
                        "a rose has an odd number of petals or a multiple of 4 (k or 2k for r = a cos(k theta)), got {p}"
                    ),
                ));
            }
        };
        Self::from_frequency(k, a, plane)
    }

    /// A rose `r = a cos(k theta)` with integer frequency `k >= 1` and size `a > 0` (the
    /// petal length); it has `k` petals for odd `k` and `2k` for even `k`. Errors name
    /// `k` or `a`.
    pub fn from_frequency(k: u32, a: f64, plane: Plane) -> Result<Self, CurveError> {
        if k == 0 {
            return Err(CurveError::invalid("k", "must be at least 1, got 0"));
        }
        positive("a", a)?;
        Ok(Self { k, a, plane })
    }

    /// The frequency `k`.
    #[must_use]
    pub fn k(&self) -> u32 {
        self.k
    }

    /// The size `a`.
    #[must_use]
    pub fn a(&self) -> f64 {
        self.a
    }

    /// The number of petals: `k` for odd `k`, `2k` for even `k`.
    #[must_use]
    pub fn petal_count(&self) -> u32 {
        if self.k % 2 == 1 { self.k } else { 2 * self.k }
    }

    /// The exact length of the curve drawn once, `2 k a E(1 - 1/k^2)` for odd `k` and
    /// `4 k a E(1 - 1/k^2)` for even `k`, with `E` from [`complete_elliptic_e`].
    #[must_use]
    pub fn exact_length(&self) -> f64 {
        let k = f64::from(self.k);
        let m = 1.0 - 1.0 / (k * k);
        let stretches = if self.k % 2 == 1 { k } else { 2.0 * k };
        stretches * 2.0 * self.a * complete_elliptic_e(m)
    }
}

impl ParamCurve for Rose {
    fn domain(&self) -> (f64, f64) {
        (0.0, if self.k % 2 == 1 { PI } else { TAU })
    }

    fn position(&self, theta: f64) -> DVec3 {
        let radius = self.a * (f64::from(self.k) * theta).cos();
        let (s, c) = theta.sin_cos();
        self.plane.point(DVec2::new(radius * c, radius * s))
    }

    fn is_closed(&self) -> bool {
        true
    }
}

impl ParamCurveDeriv for Rose {
    fn derivative(&self, theta: f64) -> DVec3 {
        let k = f64::from(self.k);
        let (sk, ck) = (k * theta).sin_cos();
        let radius = self.a * ck;
        let radius_rate = -self.a * k * sk;
        let (s, c) = theta.sin_cos();
        self.plane.vector(DVec2::new(
            radius_rate * c - radius * s,
            radius_rate * s + radius * c,
        ))
    }

    /// The closed form `a sqrt(1 + (k^2 - 1) sin^2(k theta))`.
    fn speed(&self, theta: f64) -> f64 {
        let k = f64::from(self.k);
        let s = (k * theta).sin();
        self.a * (1.0 + (k * k - 1.0) * s * s).sqrt()
    }
}

/// The complete elliptic integral of the second kind,
/// `E(m) = integral_0^{pi/2} sqrt(1 - m sin^2 phi) d phi`, for `0 <= m <= 1`, by the
/// arithmetic-geometric mean (Abramowitz and Stegun 17.6): with `a_0 = 1`,
/// `b_0 = sqrt(1 - m)`, `c_0^2 = m`, `c_{n+1} = (a_n - b_n)/2`,
/// `E = K (1 - sum_n 2^{n-1} c_n^2)`, `K = pi / (2 AGM(1, sqrt(1 - m)))`. Converges
/// quadratically; accurate to a few ulps. Returns NaN for `m` outside `[0, 1]`
/// (`E(1) = 1`).
#[must_use]
pub fn complete_elliptic_e(m: f64) -> f64 {
    if !(0.0..=1.0).contains(&m) {
        return f64::NAN;
    }
    if m == 1.0 {
        return 1.0;
    }
    let mut a = 1.0_f64;
    let mut b = (1.0 - m).sqrt();
    let mut weight = 0.5;
    let mut sum = weight * m;
    for _ in 0..64 {
        let c = 0.5 * (a - b);
        weight *= 2.0;
        sum += weight * c * c;
        let next_a = 0.5 * (a + b);
        b = (a * b).sqrt();
        a = next_a;
        // The next c is about c^2 / (4a) <= 2.5e-19 a, below rounding, and so is the
        // remaining change in a. Waiting for c itself to reach rounding level would not do:
        // a - b stalls at an ulp while the weight keeps doubling.
        if c.abs() <= 1e-9 * a {
            break;
        }
    }
    FRAC_PI_2 / a * (1.0 - sum)
}
