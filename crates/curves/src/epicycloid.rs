//! Epicycloids with `k` petals (cusps): the lab's flower and its family.
//!
//! A circle of radius `r` rolls outside a fixed circle of radius `R = k r`; a point on the
//! rolling circle traces
//! `P(t) = (R + r)(cos t, sin t) - r (cos((R + r) t / r), sin((R + r) t / r))`,
//! `t` in `[0, 2 pi]`, with `(R + r)/r = k + 1`. Its speed is `2 (R + r) |sin(R t / 2r)|`,
//! zero at the `k` cusps `t = 2 pi j / k`. Between two cusps (one arch) the arc length
//! from the arch's start is `(4 r (R + r)/R)(1 - cos(R t / 2r))`; each arch is
//! `8 r (R + r)/R` long and the whole curve `8 (R + r)`. Derivations: docs/curves.md.
//!
//! The lab flower `x = a(6 cos t - cos 6t)`, `z = a(6 sin t - sin 6t)`, `a = 0.1` is
//! `k = 5`, `r = a` in the plane `y = 0` ([`Epicycloid::lab_flower`]); its length is
//! exactly `48 a = 4.8`.

use crate::error::{CurveError, positive};
use crate::plane::Plane;
use crate::traits::{ParamCurve, ParamCurveDeriv};
use sinew_math::{DVec2, DVec3};
use std::f64::consts::TAU;

/// An epicycloid with `petals` cusps, rolling-circle radius `r`, placed by a [`Plane`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Epicycloid {
    petals: u32,
    r: f64,
    plane: Plane,
}

impl Epicycloid {
    /// An epicycloid with `petals >= 1` cusps and rolling radius `r > 0` (fixed circle
    /// radius `R = petals * r`). Errors name `petals` or `r`. [`Rose::with_petals`] counts
    /// the same way.
    ///
    /// [`Rose::with_petals`]: crate::Rose::with_petals
    ///
    /// ```
    /// use sinew_curves::{ArcLengthTable, ArcParam, Epicycloid, Plane, resample_by_spacing};
    /// // Three cusps, rolling radius 0.2: length 8 (R + r) = 8 (0.6 + 0.2) = 6.4.
    /// let flower = Epicycloid::with_petals(3, 0.2, Plane::default()).unwrap();
    /// assert!((flower.exact_length() - 6.4).abs() < 1e-12);
    /// let table = ArcLengthTable::new(&flower, 1e-10).unwrap();
    /// assert!((table.length() - 6.4).abs() <= 1e-10);
    /// // Points 0.1 apart along the curve: 64 of them around the closed flower.
    /// let samples = resample_by_spacing(&flower, &table, 0.1).unwrap();
    /// assert_eq!(samples.points.len(), 64);
    /// ```
    pub fn with_petals(petals: u32, r: f64, plane: Plane) -> Result<Self, CurveError> {
        if petals == 0 {
            return Err(CurveError::invalid("petals", "must be at least 1, got 0"));
        }
        positive("r", r)?;
        Ok(Self { petals, r, plane })
    }

    /// The lab's five-petal flower: `k = 5`, `r = a = 0.1`, in the plane `y = 0`.
    #[must_use]
    pub fn lab_flower() -> Self {
        Self {
            petals: 5,
            r: 0.1,
            plane: Plane::lab(),
        }
    }

    /// The number of petals (cusps) `k`.
    #[must_use]
    pub fn petals(&self) -> u32 {
        self.petals
    }

    /// The rolling circle's radius `r`.
    #[must_use]
    pub fn r(&self) -> f64 {
        self.r
    }

    /// The placement.
    #[must_use]
    pub fn plane(&self) -> &Plane {
        &self.plane
    }

    /// `R + r = (k + 1) r`.
    fn outer(&self) -> f64 {
        f64::from(self.petals + 1) * self.r
    }

    /// The cusp parameters `2 pi j / k`, `j = 0..=k` (both domain ends included).
    #[must_use]
    pub fn cusps(&self) -> Vec<f64> {
        let k = f64::from(self.petals);
        (0..=self.petals).map(|j| TAU * f64::from(j) / k).collect()
    }

    /// The exact total length `8 (R + r)`.
    #[must_use]
    pub fn exact_length(&self) -> f64 {
        8.0 * self.outer()
    }

    /// The exact arc length from `t = 0` to `t` (clamped to `[0, 2 pi]`), in closed form:
    /// `j * 8 r (R + r)/R + (8 r (R + r)/R) sin^2(R tau / 4r)` with `j` the arch index and
    /// `tau` the parameter since the arch's start cusp. (`1 - cos x = 2 sin^2(x/2)` keeps
    /// full relative accuracy near the cusps.)
    #[must_use]
    pub fn exact_arc_length(&self, t: f64) -> f64 {
        let k = f64::from(self.petals);
        let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, TAU) };
        let arch_len = 8.0 * self.outer() / k;
        let j = (t * k / TAU).floor().min(k - 1.0).max(0.0);
        let tau = t - TAU * j / k;
        let half = (k * tau / 4.0).sin();
        j * arch_len + arch_len * half * half
    }

    /// The exact speed `2 (R + r) |sin(R t / 2r)|`.
    #[must_use]
    pub fn exact_speed(&self, t: f64) -> f64 {
        2.0 * self.outer() * (0.5 * f64::from(self.petals) * t).sin().abs()
    }
}

impl ParamCurve for Epicycloid {
    fn domain(&self) -> (f64, f64) {
        (0.0, TAU)
    }

    fn position(&self, t: f64) -> DVec3 {
        let (s1, c1) = t.sin_cos();
        let (sk, ck) = (f64::from(self.petals + 1) * t).sin_cos();
        let big = self.outer();
        self.plane
            .point(DVec2::new(big * c1 - self.r * ck, big * s1 - self.r * sk))
    }

    fn is_closed(&self) -> bool {
        true
    }
}

impl ParamCurveDeriv for Epicycloid {
    fn derivative(&self, t: f64) -> DVec3 {
        // d/dt of r cos((k+1) t) is -(k+1) r sin((k+1) t) = -(R + r) sin((k+1) t).
        let (s1, c1) = t.sin_cos();
        let (sk, ck) = (f64::from(self.petals + 1) * t).sin_cos();
        let big = self.outer();
        self.plane
            .vector(DVec2::new(big * (sk - s1), big * (c1 - ck)))
    }

    /// The closed form `2 (R + r) |sin(k t / 2)|` (one sine instead of two sine-cosine
    /// pairs); tests check it against `derivative(t).length()`.
    fn speed(&self, t: f64) -> f64 {
        self.exact_speed(t)
    }

    /// The interior cusps `2 pi j / k`, `j = 1..k`, where the speed has a kink.
    fn breaks(&self) -> Vec<f64> {
        let c = self.cusps();
        c[1..c.len() - 1].to_vec()
    }
}
