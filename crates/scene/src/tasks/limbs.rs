//! Colliders on an animated skeleton: capsules along chosen bones of a skeleton whose
//! pose is keyed in time, driven before every step to where the animation puts them at
//! the step's end ([`sinew_spring_sim::contact::Drive::To`]). This is how a cloth task
//! puts a sleeve on a moving arm.
//!
//! The animation: key poses at increasing times; between two keys every joint's local
//! rotation is the spherical interpolation (shortest arc) of the two keys' rotations at
//! the fraction of the interval elapsed; before the first key the first pose holds,
//! after the last the last. Each capsule runs from one joint's position to another's
//! (forward kinematics of the interpolated pose) with a radius.

use crate::limits::{MAX_JOINTS, at_most};
use crate::spec::{JointRotation, SkeletonSpec, build_pose};
use serde::Deserialize;
use sinew_skeleton::{GlobalPose, Pose, Skeleton};
use sinew_spring_sim::contact::Shape;

/// The most key poses and capsules a scene may give (each key holds a pose of the
/// whole skeleton).
pub const MAX_KEYS: usize = 100_000;

/// An animated skeleton carrying capsule colliders, in a scene.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimbsSpec {
    /// The skeleton (its rest pose is every rotation the identity).
    pub skeleton: SkeletonSpec,
    /// Key poses, at strictly increasing times (at least one).
    pub keys: Vec<KeyPose>,
    /// The capsules, each along two joints (at least one).
    pub capsules: Vec<LimbCapsule>,
}

/// A key pose: joint rotations (as in an `Fk` task's `pose`) at a time.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyPose {
    /// Seconds from the start of the run.
    pub time: f64,
    /// Rotations of the joints that are not at rest (default: the rest pose).
    #[serde(default)]
    pub pose: Vec<JointRotation>,
}

/// A capsule from joint `from` to joint `to` (forward kinematics positions).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimbCapsule {
    /// The joint at the capsule's end `a`.
    pub from: usize,
    /// The joint at its end `b`.
    pub to: usize,
    /// Its radius, positive and finite.
    pub radius: f64,
}

/// A built [`LimbsSpec`]: poses the capsules at any time.
#[derive(Debug)]
pub struct Limbs {
    skeleton: Skeleton,
    keys: Vec<(f64, Pose)>,
    capsules: Vec<(usize, usize, f64)>,
    pose: Pose,
    global: GlobalPose,
}

impl LimbsSpec {
    /// Builds the animation, or says which item is wrong (`keys[2]: ...`,
    /// `capsules[0]: ...`).
    pub fn build(&self) -> Result<Limbs, String> {
        let skeleton = self.skeleton.build()?;
        at_most("keys", self.keys.len(), MAX_KEYS)?;
        at_most("capsules", self.capsules.len(), MAX_KEYS)?;
        at_most(
            "keys x joints",
            self.keys.len().saturating_mul(skeleton.len()),
            MAX_JOINTS,
        )?;
        if self.keys.is_empty() {
            return Err("keys: none given (at least one key pose is needed)".into());
        }
        if self.capsules.is_empty() {
            return Err("capsules: none given (at least one capsule is needed)".into());
        }
        let mut keys = Vec::with_capacity(self.keys.len());
        for (k, key) in self.keys.iter().enumerate() {
            if !key.time.is_finite() {
                return Err(format!("keys[{k}]: time = {} is not finite", key.time));
            }
            if let Some((previous, _)) = keys.last()
                && key.time <= *previous
            {
                return Err(format!(
                    "keys[{k}]: time = {} is not after the previous key's ({previous})",
                    key.time
                ));
            }
            let pose = build_pose(&skeleton, &key.pose).map_err(|e| format!("keys[{k}]: {e}"))?;
            keys.push((key.time, pose));
        }
        let mut capsules = Vec::with_capacity(self.capsules.len());
        for (c, capsule) in self.capsules.iter().enumerate() {
            for (field, joint) in [("from", capsule.from), ("to", capsule.to)] {
                if joint >= skeleton.len() {
                    return Err(format!(
                        "capsules[{c}]: {field} = {joint} is out of range (the skeleton has {} joints)",
                        skeleton.len()
                    ));
                }
            }
            if !(capsule.radius.is_finite() && capsule.radius > 0.0) {
                return Err(format!(
                    "capsules[{c}]: radius = {} is not positive and finite",
                    capsule.radius
                ));
            }
            capsules.push((capsule.from, capsule.to, capsule.radius));
        }
        let pose = skeleton.rest_pose();
        Ok(Limbs {
            skeleton,
            keys,
            capsules,
            pose,
            global: GlobalPose::default(),
        })
    }
}

impl Limbs {
    /// The number of capsules.
    #[must_use]
    pub fn len(&self) -> usize {
        self.capsules.len()
    }

    /// Whether there are none (never, once built).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.capsules.is_empty()
    }

    /// The capsules posed at time `t`, in the scene's order.
    ///
    /// # Errors
    /// Forward kinematics' refusal of the interpolated pose (not expected: it has the
    /// skeleton's size and unit rotations), as text.
    pub fn shapes_at(&mut self, t: f64) -> Result<Vec<Shape>, String> {
        self.pose_at(t);
        self.skeleton
            .forward_kinematics(&self.pose, &mut self.global)
            .map_err(|e| format!("limbs at t = {t}: {e}"))?;
        let x = &self.global.positions;
        Ok(self
            .capsules
            .iter()
            .map(|&(from, to, radius)| Shape::Capsule {
                a: x[from],
                b: x[to],
                radius,
            })
            .collect())
    }

    /// Sets `self.pose` to the animation's pose at `t`.
    fn pose_at(&mut self, t: f64) {
        // The first key after t; before the first or after the last, that key's pose.
        let next = self.keys.partition_point(|(time, _)| *time <= t);
        if next == 0 || next == self.keys.len() {
            let held = &self.keys[next.min(self.keys.len() - 1)].1;
            self.pose.rotations.clone_from(&held.rotations);
            return;
        }
        let ((t0, p0), (t1, p1)) = (&self.keys[next - 1], &self.keys[next]);
        let s = (t - t0) / (t1 - t0);
        for ((q, a), b) in self
            .pose
            .rotations
            .iter_mut()
            .zip(&p0.rotations)
            .zip(&p1.rotations)
        {
            *q = a.slerp(*b, s).normalize();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sinew_math::{DQuat, DVec3};

    /// A one-bone arm along +x from the origin, turned about +z by 0 degrees at t = 1
    /// and 90 degrees at t = 3.
    fn arm() -> Limbs {
        let text = "(skeleton: Chain(bones: 1, length: 0.5), \
                    keys: [(time: 1.0), (time: 3.0, pose: [(joint: 0, axis: (0.0, 0.0, 1.0), degrees: 90.0)])], \
                    capsules: [(from: 0, to: 1, radius: 0.1)])";
        ron::from_str::<LimbsSpec>(text).unwrap().build().unwrap()
    }

    fn tip(limbs: &mut Limbs, t: f64) -> DVec3 {
        match limbs.shapes_at(t).unwrap()[0] {
            Shape::Capsule { a, b, radius } => {
                assert_eq!((a, radius), (DVec3::ZERO, 0.1));
                b
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn the_pose_between_keys_turns_at_a_constant_rate_and_holds_outside_them() {
        let mut limbs = arm();
        // Held before the first key and after the last.
        assert!((tip(&mut limbs, -5.0) - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-15);
        assert!((tip(&mut limbs, 1.0) - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-15);
        assert!((tip(&mut limbs, 3.0) - DVec3::new(0.0, 0.5, 0.0)).length() < 1e-15);
        assert!((tip(&mut limbs, 9.0) - DVec3::new(0.0, 0.5, 0.0)).length() < 1e-15);
        // In between: a quarter of the interval is a quarter of the turn (slerp turns
        // at a constant rate), and the bone keeps its length.
        for (t, degrees) in [(1.5, 22.5_f64), (2.0, 45.0), (2.9, 85.5)] {
            let expected = DQuat::from_rotation_z(degrees.to_radians()) * DVec3::new(0.5, 0.0, 0.0);
            let got = tip(&mut limbs, t);
            assert!(
                (got - expected).length() < 1e-14,
                "t = {t}: {got} against {expected}"
            );
        }
    }

    #[test]
    fn bad_limbs_are_named() {
        let err = |text: &str| {
            ron::from_str::<LimbsSpec>(text)
                .unwrap()
                .build()
                .unwrap_err()
        };
        let skeleton = "skeleton: Chain(bones: 1, length: 0.5)";
        assert_eq!(
            err(&format!(
                "({skeleton}, keys: [], capsules: [(from: 0, to: 1, radius: 0.1)])"
            )),
            "keys: none given (at least one key pose is needed)"
        );
        assert_eq!(
            err(&format!("({skeleton}, keys: [(time: 0.0)], capsules: [])")),
            "capsules: none given (at least one capsule is needed)"
        );
        assert_eq!(
            err(&format!(
                "({skeleton}, keys: [(time: 0.0)], capsules: [(from: 0, to: 1, radius: 0.0)])"
            )),
            "capsules[0]: radius = 0 is not positive and finite"
        );
        assert_eq!(
            err(&format!(
                "({skeleton}, keys: [(time: 0.0), (time: inf)], capsules: [(from: 0, to: 1, radius: 0.1)])"
            )),
            "keys[1]: time = inf is not finite"
        );
        assert!(
            err(&format!(
                "({skeleton}, keys: [(time: 0.0, pose: [(joint: 4, axis: (0.0, 0.0, 1.0), degrees: 1.0)])], capsules: [(from: 0, to: 1, radius: 0.1)])"
            ))
            .starts_with("keys[0]: pose[0]: joint 4 is out of range")
        );
    }
}
