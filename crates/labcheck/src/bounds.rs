//! The round-off allowances of the properties, each derived in `docs/labcheck.md`.
//!
//! A property compares a computed quantity with an exact statement ("every bone keeps
//! its length", "the error never increases"). Where the computation is in floating
//! point, the comparison allows for round-off, and only for round-off: each allowance is
//! a small multiple of the unit round-off `EPS` times the magnitude the rounding acts on
//! (the coordinates involved, the chain depth), never a tolerance found by trial.

use sinew_math::DVec3;

/// Machine epsilon of f64 (twice the unit round-off).
pub const EPS: f64 = f64::EPSILON;

/// The relative accuracy every bone length must keep (the 1e-12).
pub const BONE_RELATIVE: f64 = 1e-12;

/// The largest allowed `| |b - a| - rest |` for a bone from `a` to `b` of rest length
/// `rest`: `1e-12 rest + 4 EPS max(|a|, |b|)`.
///
/// The second term is the measurement floor: positions are absolute coordinates, each
/// rounded to half an ulp of its own size when it is computed (`P_child = P_parent +
/// G offset`), so their difference carries an error of order `EPS |P|` whatever the bone
/// length. A 1e-4 bone 6e4 units from the origin cannot be measured to 1e-16.
#[must_use]
pub fn bone_length_allowance(rest: f64, a: DVec3, b: DVec3) -> f64 {
    BONE_RELATIVE * rest + 4.0 * EPS * a.length().max(b.length())
}

/// The allowed increase of the effector-to-target distance across one CCD sweep of a
/// chain of `bones` bones whose joints and target lie within `scale` of the origin:
/// `16 EPS (bones + 1) scale`. Each joint step rounds the effector's position (a rotation
/// about the joint and an addition: a few EPS of `scale`), and the sweep ends with
/// forward kinematics, whose positions accumulate one rounding per joint.
#[must_use]
pub fn sweep_allowance(bones: usize, scale: f64) -> f64 {
    16.0 * EPS * (bones as f64 + 1.0) * scale
}

/// The allowed distance between a position computed by forward kinematics down `depth`
/// joints and the same point computed another way (FABRIK's solved positions, the
/// straight chain's closed form), with coordinates within `scale` of the origin:
/// `16 EPS (depth + 1) scale`. Each joint's global rotation is a normalized product with
/// its parent's, so rotation errors grow by a few EPS per level, and each position sum
/// adds half an ulp of `scale`.
#[must_use]
pub fn chain_position_allowance(depth: usize, scale: f64) -> f64 {
    16.0 * EPS * (depth as f64 + 1.0) * scale
}

/// The allowance on a sum of `terms` floating-point terms whose magnitudes add up to
/// `scale` (the sum of the absolute values of the terms, and of the cancelling parts
/// inside each term, as `docs/labcheck.md` lists them): `(terms + 16) EPS scale`.
/// Recursive summation of `n` terms errs by at most `(n - 1) u sum |x_i|` (Higham,
/// *Accuracy and Stability of Numerical Algorithms*, 2nd ed., eq. 4.4; `u = EPS / 2`),
/// and each term is a product of a handful of rounded operations, each contributing at
/// most `u` relative to the magnitude counted in `scale`.
#[must_use]
pub fn sum_allowance(terms: usize, scale: f64) -> f64 {
    (terms as f64 + 16.0) * EPS * scale
}
