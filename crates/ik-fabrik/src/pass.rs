//! One FABRIK iteration on joint positions: the backward pass (effector pinned on the
//! target, walking to the base) and the forward pass (base pinned back, walking out).
//!
//! Every step places the next joint at exactly the bone length along a unit direction,
//! so each pass restores every bone length from scratch: lengths cannot drift, however
//! many passes or frames run (see `docs/ik-fabrik.md`).

use sinew_math::{DVec3, try_unit};
use sinew_skeleton::ik::IkError;

/// The step of length `length` from `from` towards `to`. Where the two coincide there is
/// no direction, and the bone keeps its own direction from before the step (from its
/// previous far joint `previous_from`); if even that is gone (a zero-length bone) the x
/// axis, which is harmless because it is multiplied by a zero length.
#[inline]
fn step(from: DVec3, to: DVec3, previous_from: DVec3, length: f64) -> DVec3 {
    let v = to - from;
    let squared = v.length_squared();
    // Fast path: for lengths well inside the floating-point range, one square root and
    // one division, with no overflow or underflow (the comparisons also reject NaN).
    // Anything else goes through `try_unit`, which rescales first.
    if (1e-200..=1e200).contains(&squared) {
        return v * (length / squared.sqrt());
    }
    let d = try_unit(v)
        .or_else(|| try_unit(to - previous_from))
        .unwrap_or(DVec3::X);
    d * length
}

/// One backward and one forward pass over `positions` (base first, effector last), with
/// the base pinned at `base`. Returns the effector's distance to `target` afterwards.
/// The caller guarantees `positions.len() == bone_lengths.len() + 1`.
#[inline]
pub(crate) fn pass_unchecked(
    positions: &mut [DVec3],
    bone_lengths: &[f64],
    base: DVec3,
    target: DVec3,
) -> f64 {
    let n = bone_lengths.len();
    // Backward: effector onto the target, then each joint at its bone length from the
    // joint after it, along the line to where it was.
    let mut previous_next = positions[n];
    positions[n] = target;
    for c in (0..n).rev() {
        let here = positions[c];
        positions[c] =
            positions[c + 1] + step(positions[c + 1], here, previous_next, bone_lengths[c]);
        previous_next = here;
    }
    // Forward: base back in place, then each joint at its bone length from the one before.
    let mut previous_before = positions[0];
    positions[0] = base;
    for c in 0..n {
        let here = positions[c + 1];
        positions[c + 1] =
            positions[c] + step(positions[c], here, previous_before, bone_lengths[c]);
        previous_before = here;
    }
    positions[n].distance(target)
}

/// One FABRIK iteration (a backward and a forward pass) on a chain given by its joint
/// positions, base first: the base stays at `positions[0]`, bone `c` joins
/// `positions[c]` and `positions[c + 1]` with length `bone_lengths[c]`. Returns the
/// effector's distance to `target` after the pass.
///
/// Where two joints coincide, so the line to follow has no direction, the bone keeps the
/// direction it had before the step; the result is always finite for finite input.
///
/// An error (naming the offending item) when `positions` does not have one more entry
/// than `bone_lengths`, when a position or the target is not finite, or when a bone
/// length is negative or not finite.
///
/// ```
/// use sinew_ik_fabrik::fabrik_pass;
/// use sinew_math::DVec3;
/// let mut p = vec![DVec3::ZERO, DVec3::X, DVec3::X * 2.0];
/// let error = fabrik_pass(&mut p, &[1.0, 1.0], DVec3::new(1.0, 1.0, 0.0)).unwrap();
/// assert!(error < 0.5);
/// assert_eq!(p[0], DVec3::ZERO);
/// assert!(((p[2] - p[1]).length() - 1.0).abs() < 1e-15);
/// ```
pub fn fabrik_pass(
    positions: &mut [DVec3],
    bone_lengths: &[f64],
    target: DVec3,
) -> Result<f64, IkError> {
    if positions.len() != bone_lengths.len() + 1 {
        return Err(IkError::InvalidSettings(format!(
            "fabrik_pass: {} positions for {} bones (need one more position than bones)",
            positions.len(),
            bone_lengths.len()
        )));
    }
    if !target.is_finite() {
        return Err(IkError::NonFiniteTarget { target });
    }
    if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
        return Err(IkError::InvalidSettings(format!(
            "fabrik_pass: position {i} has a NaN or infinite component"
        )));
    }
    if let Some(c) = bone_lengths
        .iter()
        .position(|l| !(l.is_finite() && *l >= 0.0))
    {
        return Err(IkError::InvalidSettings(format!(
            "fabrik_pass: bone {c} has length {}, which is not finite and >= 0",
            bone_lengths[c]
        )));
    }
    let base = positions[0];
    Ok(pass_unchecked(positions, bone_lengths, base, target))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lengths_of(p: &[DVec3]) -> Vec<f64> {
        p.windows(2).map(|w| w[0].distance(w[1])).collect()
    }

    #[test]
    fn a_pass_restores_every_length_and_pins_the_base() {
        // Start from positions whose bones have the wrong lengths: one pass fixes them.
        let mut p = vec![
            DVec3::new(0.1, 0.2, 0.3),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(1.0, 3.0, 0.0),
            DVec3::new(-2.0, 1.0, 0.5),
        ];
        let lengths = [0.5, 0.25, 1.5];
        let base = p[0];
        let err = fabrik_pass(&mut p, &lengths, DVec3::new(0.5, 0.5, 0.5)).unwrap();
        assert_eq!(p[0], base);
        for (got, want) in lengths_of(&p).iter().zip(lengths) {
            assert!(
                (got - want).abs() <= 4.0 * f64::EPSILON * want,
                "{got} vs {want}"
            );
        }
        assert_eq!(err, p[3].distance(DVec3::new(0.5, 0.5, 0.5)));
    }

    #[test]
    fn a_reachable_target_is_approached_and_never_left() {
        let mut p: Vec<DVec3> = (0..6).map(|i| DVec3::X * i as f64).collect();
        let lengths = [1.0; 5];
        let target = DVec3::new(1.0, 2.0, -1.0);
        let mut err = f64::INFINITY;
        for _ in 0..50 {
            let next = fabrik_pass(&mut p, &lengths, target).unwrap();
            // Monotone until rounding noise (a few ulps of the positions) takes over.
            assert!(next <= err || next < 1e-14, "{next} > {err}");
            err = next;
        }
        assert!(err < 1e-12, "{err}");
    }

    #[test]
    fn coincident_joints_keep_their_previous_direction() {
        // The target sits exactly on joint 1, so the backward pass finds joint 1 on top of
        // the relocated effector; the bone keeps its old direction instead of making NaN.
        let mut p = vec![DVec3::ZERO, DVec3::X, DVec3::X * 2.0];
        let err = fabrik_pass(&mut p, &[1.0, 1.0], DVec3::X).unwrap();
        assert!(p.iter().all(|q| q.is_finite()));
        assert!(err.is_finite());
        for l in lengths_of(&p) {
            assert!((l - 1.0).abs() < 1e-15);
        }
    }

    #[test]
    fn zero_length_bones_give_coincident_joints_not_nan() {
        let mut p = vec![DVec3::ZERO, DVec3::ZERO, DVec3::Y, DVec3::Y];
        let lengths = [0.0, 1.0, 0.0];
        for _ in 0..10 {
            fabrik_pass(&mut p, &lengths, DVec3::new(0.3, 0.4, 0.0)).unwrap();
        }
        assert!(p.iter().all(|q| q.is_finite()));
        assert_eq!(p[0], p[1]);
        assert_eq!(p[2], p[3]);
        assert!((p[1].distance(p[2]) - 1.0).abs() < 1e-15);
    }

    #[test]
    fn bad_input_is_an_error_naming_it() {
        let mut p = vec![DVec3::ZERO, DVec3::X];
        let e = fabrik_pass(&mut p, &[1.0, 1.0], DVec3::X).unwrap_err();
        assert!(e.to_string().contains("2 positions for 2 bones"), "{e}");
        let e = fabrik_pass(&mut p, &[-1.0], DVec3::X).unwrap_err();
        assert!(e.to_string().contains("bone 0"), "{e}");
        let e = fabrik_pass(&mut p, &[1.0], DVec3::new(0.0, f64::NAN, 0.0)).unwrap_err();
        assert!(matches!(e, IkError::NonFiniteTarget { .. }));
        let mut q = vec![DVec3::ZERO, DVec3::INFINITY];
        let e = fabrik_pass(&mut q, &[1.0], DVec3::X).unwrap_err();
        assert!(e.to_string().contains("position 1"), "{e}");
    }
}
