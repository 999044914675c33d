//! Shared f64 math for sinew.
//!
//! Every sinew crate uses the glam types re-exported here, so there is one set of vector
//! and rotation types in the workspace. On top of glam this crate adds only what two or
//! more crates need, each defined for the degenerate inputs that simulation meets:
//!
//! - [`try_unit`]: normalization that reports failure (zero, non-finite) instead of
//!   producing NaN, and that works for vectors far below `f64::MIN_POSITIVE.sqrt()`.
//! - [`rotation_between`]: the minimal rotation taking one direction onto another,
//!   defined for parallel, antiparallel and zero vectors.
//! - [`angle_between`]: the angle between two vectors, accurate near 0 and near pi.
//!
//! ```
//! use sinew_math::{DQuat, DVec3, angle_between, rotation_between, try_unit};
//! // The rotation taking x onto y is a quarter turn about z; it maps x exactly onto y.
//! let q: DQuat = rotation_between(DVec3::X, DVec3::Y);
//! assert!((q * DVec3::X - DVec3::Y).length() < 1e-15);
//! assert!((angle_between(DVec3::X, DVec3::Y) - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
//! // A zero vector has no direction: None, never NaN.
//! assert_eq!(try_unit(DVec3::ZERO), None);
//! ```
//!
//! Architecture invariant: this crate depends on glam only.

pub use glam::{DMat3, DMat4, DQuat, DVec2, DVec3, DVec4, EulerRot};

/// The unit vector along `v`, or `None` when `v` has no direction: a zero vector, or a
/// vector with a NaN or infinite component.
///
/// Unlike `v / v.length()`, this never produces NaN, and it does not underflow: `v` is
/// first scaled by its largest component, so a vector of length 1e-300 still has a
/// direction.
///
/// ```
/// use sinew_math::{try_unit, DVec3};
/// assert_eq!(try_unit(DVec3::new(0.0, 3.0, 4.0)), Some(DVec3::new(0.0, 0.6, 0.8)));
/// assert_eq!(try_unit(DVec3::ZERO), None);
/// assert!(try_unit(DVec3::new(1e-300, 0.0, 0.0)).is_some());
/// assert_eq!(try_unit(DVec3::new(f64::NAN, 0.0, 0.0)), None);
/// ```
#[must_use]
pub fn try_unit(v: DVec3) -> Option<DVec3> {
    // `max_element` skips NaN, so finiteness is checked on the vector itself.
    let scale = v.abs().max_element();
    if !v.is_finite() || scale == 0.0 {
        return None;
    }
    let w = v / scale;
    // `w` has its largest component at +-1, so its length is in [1, sqrt 3]: no
    // overflow, no underflow.
    Some(w / w.length())
}

/// The length of `v`, without overflow or underflow in the squares where the length
/// itself is representable: `v.length()` when that is finite and above 1e-150, else
/// computed from `v` scaled by its largest component.
///
/// ```
/// use sinew_math::{robust_length, DVec3};
/// assert_eq!(robust_length(DVec3::new(0.0, 3.0, 4.0)), 5.0);
/// assert_eq!(robust_length(DVec3::new(1e200, 0.0, 0.0)), 1e200);
/// assert!((robust_length(DVec3::new(0.0, 3e-300, 4e-300)) / 5e-300 - 1.0).abs() < 1e-15);
/// assert_eq!(robust_length(DVec3::new(f64::MAX, 0.0, 0.0)), f64::MAX);
/// ```
#[inline]
#[must_use]
pub fn robust_length(v: DVec3) -> f64 {
    let fast = v.length();
    if fast.is_finite() && fast > 1e-150 {
        return fast;
    }
    let scale = v.abs().max_element();
    if scale == 0.0 || !scale.is_finite() {
        fast
    } else {
        (v / scale).length() * scale
    }
}

/// The unit vector along `v`, or `fallback` when `v` has no direction (see [`try_unit`]).
#[must_use]
pub fn unit_or(v: DVec3, fallback: DVec3) -> DVec3 {
    try_unit(v).unwrap_or(fallback)
}

/// The angle in radians, in `[0, pi]`, between `a` and `b`.
///
/// Computed as `atan2(|a x b|, a . b)`, which keeps full relative accuracy for tiny
/// angles and for angles near pi, where `acos` of the normalized dot product loses half
/// the digits. The inputs need not be unit vectors. Returns 0 when either vector is zero
/// or not finite (there is no angle to measure; 0 is the defined answer).
///
/// ```
/// use sinew_math::{angle_between, DVec3};
/// let a = angle_between(DVec3::X, DVec3::new(1.0, 1e-12, 0.0));
/// assert!((a - 1e-12).abs() < 1e-27);
/// ```
#[must_use]
pub fn angle_between(a: DVec3, b: DVec3) -> f64 {
    match (try_unit(a), try_unit(b)) {
        (Some(a), Some(b)) => a.cross(b).length().atan2(a.dot(b)),
        _ => 0.0,
    }
}

/// The rotation of smallest angle that takes the direction of `from` onto the direction
/// of `to`. The inputs need not be unit vectors; only their directions matter.
///
/// Defined answers for every input:
/// - parallel directions (including equal ones): the identity;
/// - antiparallel directions: a half turn about an axis perpendicular to `from`
///   (`from.any_orthonormal_vector()`, so the same input always gives the same axis);
/// - a zero or non-finite vector on either side: the identity (there is no direction to
///   rotate).
///
/// The result is always a finite unit quaternion, and it is accurate to rounding for
/// all angles including those within 1e-8 of pi: near-antiparallel inputs are handled as
/// a half turn followed by a small rotation about the same axis, instead of through the
/// ill-conditioned `1 + cos` of the usual formula.
///
/// ```
/// use sinew_math::{rotation_between, DVec3};
/// let q = rotation_between(DVec3::X, DVec3::Y);
/// assert!((q * DVec3::X - DVec3::Y).length() < 1e-15);
/// let flip = rotation_between(DVec3::X, -DVec3::X);
/// assert!((flip * DVec3::X + DVec3::X).length() < 1e-15);
/// ```
#[must_use]
pub fn rotation_between(from: DVec3, to: DVec3) -> DQuat {
    let (Some(a), Some(b)) = (try_unit(from), try_unit(to)) else {
        return DQuat::IDENTITY;
    };
    if a.dot(b) >= 0.0 {
        return half_angle_rotation(a, b);
    }
    // Obtuse angle: rotate a half turn about an axis n perpendicular to both a and b
    // (taking a to -a), then the acute rotation from -a to b, which is about the same
    // axis n. Two rotations about one axis compose to the minimal rotation.
    //
    // Near antiparallel, a x b is tiny and its rounding error is not: its direction can
    // lean out of the plane perpendicular to a by ~eps / |a x b|, and a half turn about
    // such an axis misses -a by as much. Projecting n back onto that plane makes the half
    // turn exact; what is left of the rounding only tilts the axis within the plane.
    let n = try_unit(a.cross(b))
        .and_then(|n| try_unit(n - a * a.dot(n)))
        .unwrap_or_else(|| a.any_orthonormal_vector());
    let half_turn = DQuat::from_xyzw(n.x, n.y, n.z, 0.0);
    (half_angle_rotation(-a, b) * half_turn).normalize()
}

/// The minimal rotation between unit vectors `a` and `b` with `a . b >= 0`, from the
/// half vector `h = (a + b)/|a + b|`: `q = (a x h, a . h)`. `|a + b| >= sqrt 2` here, so
/// there is no cancellation.
fn half_angle_rotation(a: DVec3, b: DVec3) -> DQuat {
    let h = (a + b).normalize();
    let axis = a.cross(h);
    DQuat::from_xyzw(axis.x, axis.y, axis.z, a.dot(h)).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn check_rotation(from: DVec3, to: DVec3) {
        let q = rotation_between(from, to);
        assert!(q.is_finite(), "non-finite for {from} -> {to}");
        assert!((q.length() - 1.0).abs() < 1e-15);
        let a = try_unit(from).unwrap();
        let b = try_unit(to).unwrap();
        let err = (q * a - b).length();
        assert!(err < 2e-15, "{from} -> {to}: |q a - b| = {err:e}");
        // Minimal: the rotation angle equals the angle between the vectors.
        let angle = 2.0 * q.xyz().length().atan2(q.w.abs());
        let expected = angle_between(a, b);
        assert!((angle - expected).abs() < 1e-15, "{angle} vs {expected}");
        // Minimal: the axis is perpendicular to both (when the angle is not 0 or pi).
        if expected > 1e-6 && expected < PI - 1e-6 {
            let axis = q.xyz().normalize();
            assert!(axis.dot(a).abs() < 1e-14 && axis.dot(b).abs() < 1e-14);
        }
    }

    #[test]
    fn unit_handles_zero_nan_tiny_and_huge() {
        assert_eq!(try_unit(DVec3::ZERO), None);
        assert_eq!(try_unit(DVec3::new(0.0, f64::NAN, 1.0)), None);
        assert_eq!(try_unit(DVec3::new(0.0, f64::INFINITY, 1.0)), None);
        let tiny = try_unit(DVec3::new(3e-310, 4e-310, 0.0)).unwrap();
        assert!((tiny - DVec3::new(0.6, 0.8, 0.0)).length() < 1e-15);
        let huge = try_unit(DVec3::new(3e307, 4e307, 0.0)).unwrap();
        assert!((huge - DVec3::new(0.6, 0.8, 0.0)).length() < 1e-15);
        assert_eq!(unit_or(DVec3::ZERO, DVec3::Y), DVec3::Y);
    }

    #[test]
    fn angle_is_accurate_at_both_ends() {
        for &t in &[
            1e-15_f64,
            1e-9,
            1e-4,
            0.5,
            1.0,
            2.0,
            PI - 1e-4,
            PI - 1e-9,
            PI - 1e-13,
        ] {
            let b = DVec3::new(t.cos(), t.sin(), 0.0);
            let got = angle_between(DVec3::X * 2.0, b * 7.0);
            assert!(
                (got - t).abs() <= 4.0 * f64::EPSILON * t,
                "angle {t}: got {got}, error {:e}",
                got - t
            );
        }
        assert_eq!(angle_between(DVec3::X, -DVec3::X), PI);
        assert_eq!(angle_between(DVec3::ZERO, DVec3::X), 0.0);
        assert_eq!(angle_between(DVec3::NAN, DVec3::X), 0.0);
    }

    #[test]
    fn rotation_between_general_directions() {
        let dirs = [
            DVec3::X,
            DVec3::Y,
            DVec3::new(1.0, 2.0, 3.0),
            DVec3::new(-0.3, 0.1, -2.0),
            DVec3::new(1e-200, -1e-200, 3e-200),
            DVec3::new(5.0, -7.0, 0.25),
        ];
        for &a in &dirs {
            for &b in &dirs {
                check_rotation(a, b);
            }
        }
    }

    #[test]
    fn rotation_between_near_parallel_and_antiparallel() {
        for &eps in &[0.0_f64, 1e-14, 1e-10, 1e-6, 1e-3] {
            let b = DVec3::new(eps.cos(), eps.sin(), 0.0);
            check_rotation(DVec3::X, b);
            let c = DVec3::new(-eps.cos(), eps.sin(), 0.0);
            check_rotation(DVec3::X, c);
        }
    }

    #[test]
    fn rotation_between_nearly_antiparallel_found_by_labcheck() {
        // The property suite's minimal failing case: before the axis was projected
        // perpendicular to `a`, |q a - b| was 4.4e-8.
        let a = DVec3::new(-0.3792979770333347, 0.9067545476240882, 0.18419890059784472);
        let b = DVec3::new(
            0.37929797742080984,
            -0.9067545476240882,
            -0.18419890059784472,
        );
        check_rotation(a, b);
        // And a sweep of angles within 1e-6 .. 1e-16 of pi about awkward axes.
        for k in 1..=10 {
            let eps = 10f64.powi(-(k + 6));
            let a = DVec3::new(0.3, -0.8, 0.52).normalize();
            let perp = a.any_orthonormal_vector();
            let b = -a * eps.cos() + perp * eps.sin();
            check_rotation(a, b);
        }
    }

    #[test]
    fn rotation_between_exactly_antiparallel_is_a_half_turn_about_a_perpendicular() {
        for &a in &[DVec3::X, DVec3::Y, DVec3::Z, DVec3::new(1.0, -2.0, 0.5)] {
            let q = rotation_between(a, -a);
            assert!((q * a + a).length() < 1e-14 * a.length());
            assert!(q.w.abs() < 1e-15, "not a half turn: {q}");
            assert!(q.xyz().dot(a).abs() < 1e-15);
            // Deterministic.
            assert_eq!(q, rotation_between(a, -a));
        }
    }

    #[test]
    fn rotation_between_zero_or_nan_is_identity() {
        assert_eq!(rotation_between(DVec3::ZERO, DVec3::X), DQuat::IDENTITY);
        assert_eq!(rotation_between(DVec3::X, DVec3::ZERO), DQuat::IDENTITY);
        assert_eq!(rotation_between(DVec3::NAN, DVec3::X), DQuat::IDENTITY);
        assert_eq!(rotation_between(DVec3::X, DVec3::X * 3.0), DQuat::IDENTITY);
    }
}
