//! A forward-mode, second-order dual number over the twelve coordinates of a contact pair
//! (four vertices), its first-order part alone ([`Gradient12`]), and the [`Scalar`] trait
//! the distance formulas are written over, so one formula gives the value (over `f64`),
//! the exact gradient (over [`Gradient12`]) and the exact gradient and Hessian (over
//! [`Dual12`]).
//!
//! A [`Dual12`] carries a value `f`, its gradient `g` and its Hessian `H` with respect to
//! the twelve variables. Sums add all three; a product is
//! `(f_a f_b, f_a g_b + f_b g_a, f_a H_b + f_b H_a + g_a g_b^T + g_b g_a^T)`; and a smooth
//! function `phi` of one dual is `(phi(f), phi'(f) g, phi'(f) H + phi''(f) g g^T)` (the
//! chain rule to second order). These are the exact rules of differentiation applied to
//! the operations in the order the formula performs them, so the derivatives are exact up
//! to the round-off of those operations: no step size, no truncation error.

use std::ops::{Add, Mul, Neg, Sub};

/// The number of variables: four vertices, three coordinates each; variable `3 k + c` is
/// coordinate `c` of vertex `k`.
pub const VARIABLES: usize = 12;

/// A value with its exact gradient and Hessian in twelve variables (see the module
/// documentation). The Hessian is exactly symmetric: every operation computes its lower
/// triangle and mirrors it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dual12 {
    /// The value.
    pub value: f64,
    /// The gradient.
    pub gradient: [f64; VARIABLES],
    /// The Hessian (symmetric, stored in full).
    pub hessian: [[f64; VARIABLES]; VARIABLES],
}

impl Dual12 {
    /// A constant: zero gradient and Hessian.
    #[must_use]
    pub fn constant(value: f64) -> Self {
        Self {
            value,
            gradient: [0.0; VARIABLES],
            hessian: [[0.0; VARIABLES]; VARIABLES],
        }
    }

    /// Variable `index` at `value`: unit gradient along it, zero Hessian.
    #[must_use]
    pub fn variable(index: usize, value: f64) -> Self {
        let mut d = Self::constant(value);
        d.gradient[index] = 1.0;
        d
    }

    /// `phi(self)` for a function with `phi(f) = value`, `phi'(f) = first` and
    /// `phi''(f) = second` at `f = self.value`.
    #[must_use]
    pub fn chain(&self, value: f64, first: f64, second: f64) -> Self {
        let mut out = Self::constant(value);
        for i in 0..VARIABLES {
            out.gradient[i] = first * self.gradient[i];
            for j in 0..=i {
                let h = first * self.hessian[i][j] + second * self.gradient[i] * self.gradient[j];
                out.hessian[i][j] = h;
                out.hessian[j][i] = h;
            }
        }
        out
    }

    /// `self * s` for a constant `s`.
    #[must_use]
    pub fn scale(&self, s: f64) -> Self {
        let mut out = *self;
        out.value *= s;
        out.gradient.iter_mut().for_each(|g| *g *= s);
        out.hessian.iter_mut().flatten().for_each(|h| *h *= s);
        out
    }
}

impl Add for Dual12 {
    type Output = Self;
    fn add(mut self, rhs: Self) -> Self {
        self.value += rhs.value;
        for i in 0..VARIABLES {
            self.gradient[i] += rhs.gradient[i];
            for j in 0..VARIABLES {
                self.hessian[i][j] += rhs.hessian[i][j];
            }
        }
        self
    }
}

impl Sub for Dual12 {
    type Output = Self;
    fn sub(self, rhs: Self) -> Self {
        self + (-rhs)
    }
}

impl Neg for Dual12 {
    type Output = Self;
    fn neg(self) -> Self {
        self.scale(-1.0)
    }
}

impl Mul for Dual12 {
    type Output = Self;
    fn mul(self, rhs: Self) -> Self {
        let (a, b) = (&self, &rhs);
        let mut out = Self::constant(a.value * b.value);
        for i in 0..VARIABLES {
            out.gradient[i] = a.value * b.gradient[i] + b.value * a.gradient[i];
            // The lower triangle, mirrored: the Hessian is symmetric bit for bit.
            for j in 0..=i {
                let h = a.value * b.hessian[i][j]
                    + b.value * a.hessian[i][j]
                    + a.gradient[i] * b.gradient[j]
                    + b.gradient[i] * a.gradient[j];
                out.hessian[i][j] = h;
                out.hessian[j][i] = h;
            }
        }
        out
    }
}

/// A value with its exact gradient in twelve variables: [`Dual12`] without the Hessian,
/// for the passes that need the gradient alone (a tenth of the work). Every operation
/// computes the value and the gradient by the same arithmetic, in the same order, as
/// [`Dual12`]'s (whose gradient never reads its Hessian), so the two give the same bits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gradient12 {
    /// The value.
    pub value: f64,
    /// The gradient.
    pub gradient: [f64; VARIABLES],
}

impl Gradient12 {
    /// A constant: zero gradient.
    #[must_use]
    pub fn constant(value: f64) -> Self {
        Self {
            value,
            gradient: [0.0; VARIABLES],
        }
    }

    /// Variable `index` at `value`: unit gradient along it.
    #[must_use]
    pub fn variable(index: usize, value: f64) -> Self {
        let mut d = Self::constant(value);
        d.gradient[index] = 1.0;
        d
    }

    /// `phi(self)` for a function with `phi(f) = value` and `phi'(f) = first` at
    /// `f = self.value`.
    #[must_use]
    pub fn chain(&self, value: f64, first: f64) -> Self {
        Self {
            value,
            gradient: self.gradient.map(|g| first * g),
        }
    }

    /// `self * s` for a constant `s`.
    #[must_use]
    pub fn scale(&self, s: f64) -> Self {
        Self {
            value: self.value * s,
            gradient: self.gradient.map(|g| g * s),
        }
    }
}

impl Add for Gradient12 {
    type Output = Self;
    fn add(mut self, rhs: Self) -> Self {
        self.value += rhs.value;
        for i in 0..VARIABLES {
            self.gradient[i] += rhs.gradient[i];
        }
        self
    }
}

impl Sub for Gradient12 {
    type Output = Self;
    fn sub(self, rhs: Self) -> Self {
        self + (-rhs)
    }
}

impl Neg for Gradient12 {
    type Output = Self;
    fn neg(self) -> Self {
        self.scale(-1.0)
    }
}

impl Mul for Gradient12 {
    type Output = Self;
    fn mul(self, rhs: Self) -> Self {
        let (a, b) = (&self, &rhs);
        let mut out = Self::constant(a.value * b.value);
        for i in 0..VARIABLES {
            out.gradient[i] = a.value * b.gradient[i] + b.value * a.gradient[i];
        }
        out
    }
}

/// The arithmetic the distance formulas need, implemented by `f64` (values only) and by
/// [`Dual12`] (values with exact first and second derivatives).
pub trait Scalar:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Neg<Output = Self>
{
    /// A constant.
    fn from_f64(value: f64) -> Self;
    /// The value.
    fn value(&self) -> f64;
    /// `1 / self` (the caller guarantees a nonzero value).
    #[must_use]
    fn recip(&self) -> Self;
    /// `sqrt(self)` (the caller guarantees a positive value).
    #[must_use]
    fn sqrt(&self) -> Self;
    /// `self / rhs`.
    #[must_use]
    fn div(&self, rhs: Self) -> Self {
        *self * rhs.recip()
    }
}

impl Scalar for f64 {
    fn from_f64(value: f64) -> Self {
        value
    }
    fn value(&self) -> f64 {
        *self
    }
    fn recip(&self) -> Self {
        1.0 / self
    }
    fn sqrt(&self) -> Self {
        f64::sqrt(*self)
    }
    fn div(&self, rhs: Self) -> Self {
        self / rhs
    }
}

impl Scalar for Dual12 {
    fn from_f64(value: f64) -> Self {
        Self::constant(value)
    }
    fn value(&self) -> f64 {
        self.value
    }
    fn recip(&self) -> Self {
        let r = 1.0 / self.value;
        self.chain(r, -r * r, 2.0 * r * r * r)
    }
    fn sqrt(&self) -> Self {
        let s = self.value.sqrt();
        self.chain(s, 0.5 / s, -0.25 / (s * self.value))
    }
}

impl Scalar for Gradient12 {
    fn from_f64(value: f64) -> Self {
        Self::constant(value)
    }
    fn value(&self) -> f64 {
        self.value
    }
    fn recip(&self) -> Self {
        let r = 1.0 / self.value;
        self.chain(r, -r * r)
    }
    fn sqrt(&self) -> Self {
        let s = self.value.sqrt();
        self.chain(s, 0.5 / s)
    }
}

/// A 3-vector of scalars, for the distance formulas.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vec3<S> {
    /// x.
    pub x: S,
    /// y.
    pub y: S,
    /// z.
    pub z: S,
}

impl<S: Scalar> Vec3<S> {
    /// `self - rhs`.
    #[must_use]
    pub fn sub(&self, rhs: &Self) -> Self {
        Self {
            x: self.x - rhs.x,
            y: self.y - rhs.y,
            z: self.z - rhs.z,
        }
    }

    /// `self . rhs`.
    #[must_use]
    pub fn dot(&self, rhs: &Self) -> S {
        self.x * rhs.x + self.y * rhs.y + self.z * rhs.z
    }

    /// `self x rhs`.
    #[must_use]
    pub fn cross(&self, rhs: &Self) -> Self {
        Self {
            x: self.y * rhs.z - self.z * rhs.y,
            y: self.z * rhs.x - self.x * rhs.z,
            z: self.x * rhs.y - self.y * rhs.x,
        }
    }

    /// `|self|^2`.
    #[must_use]
    pub fn length_squared(&self) -> S {
        self.dot(self)
    }
}

/// The four vertices of a pair as `f64` vectors.
#[must_use]
pub fn values(v: &[sinew_math::DVec3; 4]) -> [Vec3<f64>; 4] {
    v.map(|p| Vec3 {
        x: p.x,
        y: p.y,
        z: p.z,
    })
}

/// The four vertices of a pair as dual vectors, vertex `k`'s coordinates the variables
/// `3k..3k + 3`.
#[must_use]
pub fn variables(v: &[sinew_math::DVec3; 4]) -> [Vec3<Dual12>; 4] {
    std::array::from_fn(|k| Vec3 {
        x: Dual12::variable(3 * k, v[k].x),
        y: Dual12::variable(3 * k + 1, v[k].y),
        z: Dual12::variable(3 * k + 2, v[k].z),
    })
}

/// The four vertices of a pair as first-order dual vectors, vertex `k`'s coordinates the
/// variables `3k..3k + 3`.
#[must_use]
pub fn gradient_variables(v: &[sinew_math::DVec3; 4]) -> [Vec3<Gradient12>; 4] {
    std::array::from_fn(|k| Vec3 {
        x: Gradient12::variable(3 * k, v[k].x),
        y: Gradient12::variable(3 * k + 1, v[k].y),
        z: Gradient12::variable(3 * k + 2, v[k].z),
    })
}
