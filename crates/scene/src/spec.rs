//! Scene-file descriptions shared by several task kinds: skeletons and joint rotations.
//! They build the library types and check every value on the way, naming the item.

use crate::limits::{MAX_JOINTS, MAX_PETALS, MAX_SAMPLES, at_most};
use serde::Deserialize;
use sinew_math::{DQuat, DVec3, try_unit};
use sinew_skeleton::limits::JointLimit;
use sinew_skeleton::{JointDef, Pose, Skeleton};

/// A skeleton in a scene.
#[derive(Debug, Deserialize)]
pub enum SkeletonSpec {
    /// A serial chain: the root at `root`, then `bones` bones of `length` along `direction`.
    Chain {
        /// Root position (default the origin).
        #[serde(default)]
        root: DVec3,
        /// Number of bones (joints minus one).
        bones: usize,
        /// Length of every bone.
        length: f64,
        /// Direction of every bone's rest offset (default +x).
        #[serde(default = "default_direction")]
        direction: DVec3,
        /// A joint limit given to every joint (default: none), relative to the rest
        /// pose; radians. E.g. `SwingTwist(twist_axis: (1, 0, 0), a_axis: (0, 0, 1),
        /// swing_a: 0.785, swing_b: 0.785, twist_min: -3.14159, twist_max: 3.14159)`.
        #[serde(default)]
        limit: JointLimit,
    },
    /// Explicit joints in topological order.
    Joints(Vec<JointDef>),
}

fn default_direction() -> DVec3 {
    DVec3::X
}

impl SkeletonSpec {
    /// Builds the skeleton, or says which item is wrong.
    pub fn build(&self) -> Result<Skeleton, String> {
        match self {
            Self::Chain {
                root,
                bones,
                length,
                direction,
                limit,
            } => {
                at_most("skeleton: bones", *bones, MAX_JOINTS - 1)?;
                if !(length.is_finite() && *length >= 0.0) {
                    return Err(format!(
                        "skeleton: length = {length}, must be finite and >= 0"
                    ));
                }
                let Some(dir) = try_unit(*direction) else {
                    return Err(format!(
                        "skeleton: direction = {direction} has no direction (zero or NaN)"
                    ));
                };
                let mut skeleton = Skeleton::chain(*root, &vec![dir * *length; *bones])
                    .map_err(|e| format!("skeleton: {e}"))?;
                for j in 0..skeleton.len() {
                    skeleton
                        .set_limit(j, *limit)
                        .map_err(|e| format!("skeleton: {e}"))?;
                }
                Ok(skeleton)
            }
            Self::Joints(joints) => {
                at_most("skeleton: joints", joints.len(), MAX_JOINTS)?;
                Skeleton::new(joints.iter().cloned()).map_err(|e| format!("skeleton: {e}"))
            }
        }
    }
}

/// A rotation of one joint, given as an axis and an angle in degrees. Several entries for
/// one joint compose in order (each later one applied after the earlier ones).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointRotation {
    /// The joint index.
    pub joint: usize,
    /// The rotation axis (any length but zero), in the parent's frame.
    pub axis: DVec3,
    /// The angle in degrees (right-handed about the axis).
    pub degrees: f64,
}

/// The pose given by `rotations` on `skeleton`: identity everywhere else.
pub fn build_pose(skeleton: &Skeleton, rotations: &[JointRotation]) -> Result<Pose, String> {
    let mut pose = skeleton.rest_pose();
    for (k, r) in rotations.iter().enumerate() {
        if r.joint >= skeleton.len() {
            return Err(format!(
                "pose[{k}]: joint {} is out of range (the skeleton has {} joints)",
                r.joint,
                skeleton.len()
            ));
        }
        let Some(axis) = try_unit(r.axis) else {
            return Err(format!(
                "pose[{k}]: axis {} has no direction (zero or NaN)",
                r.axis
            ));
        };
        if !r.degrees.is_finite() {
            return Err(format!("pose[{k}]: degrees = {} is not finite", r.degrees));
        }
        let q = DQuat::from_axis_angle(axis, r.degrees.to_radians());
        pose.rotations[r.joint] = (q * pose.rotations[r.joint]).normalize();
    }
    Ok(pose)
}

/// Builds `curve` and checks `sampling` against it, naming the bad field.
pub fn build_sampled(
    curve: &sinew_curves::CurveSpec,
    sampling: &sinew_curves::Sampling,
) -> Result<sinew_curves::Curve, String> {
    use sinew_curves::{CurveSpec, Sampling};
    // The work of measuring a curve grows with its petals (an arc-length table refines
    // every petal), so their number is bounded before anything is built.
    match curve {
        CurveSpec::Epicycloid { petals, .. } => at_most("curve: petals", *petals, MAX_PETALS)?,
        CurveSpec::Rose { k, .. } => at_most("curve: k", *k, MAX_PETALS)?,
        CurveSpec::Polyline { points, .. } => at_most("curve: points", points.len(), MAX_SAMPLES)?,
    }
    let curve = curve.build().map_err(|e| format!("curve: {e}"))?;
    match *sampling {
        Sampling::Uniform { n } | Sampling::ArcLength { n, .. } => {
            at_most("sampling: n", n, MAX_SAMPLES)?;
        }
        Sampling::ArcSpacing { spacing, .. } => {
            let length = curve.exact_length().unwrap_or(0.0);
            if spacing > 0.0 && length / spacing > MAX_SAMPLES as f64 {
                return Err(format!(
                    "sampling: spacing = {spacing} gives {:.3e} points, above the limit of \
                     {MAX_SAMPLES} (docs/scenes.md, \"Limits\")",
                    length / spacing
                ));
            }
        }
    }
    Ok(curve)
}
