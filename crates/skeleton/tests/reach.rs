//! The reach bound: a skeleton whose joints lie within `MAX_REACH` of the origin along
//! the skeleton is accepted, and forward kinematics of any valid pose of it is finite; a
//! joint beyond it is refused, naming the joint.

use sinew_math::{DQuat, DVec3};
use sinew_skeleton::{GlobalPose, JointDef, MAX_REACH, Pose, Skeleton, SkeletonError};

/// A deterministic generator (xorshift64*), uniform in `[0, 1)`.
struct Uniform(u64);

impl Uniform {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A rotation, uniform enough to meet every sign of every component, scaled by a
    /// factor far from 1 (forward kinematics normalizes it).
    fn rotation(&mut self) -> DQuat {
        let v = [self.next(), self.next(), self.next(), self.next()].map(|c| 2.0 * c - 1.0);
        DQuat::from_xyzw(v[0], v[1], v[2], v[3]) * (1e-3 + 1e3 * self.next())
    }
}

/// `|v|` without squaring a component above 1e154.
fn norm(v: DVec3) -> f64 {
    let m = v.abs().max_element();
    if m == 0.0 { 0.0 } else { m * (v / m).length() }
}

/// A chain of `n` bones along `direction`, each `length` long, from a root at `root`.
fn chain(root: DVec3, direction: DVec3, length: f64, n: usize) -> Result<Skeleton, SkeletonError> {
    let bone = direction.normalize() * length;
    Skeleton::chain(root, &vec![bone; n])
}

/// Joints as far as the bound allows (the summed lengths a little below it, every
/// direction of the offsets), turned every which way: every position is finite.
#[test]
fn forward_kinematics_of_a_skeleton_at_the_bound_is_finite() {
    let mut random = Uniform(0x00DD_BA11);
    let directions = [
        DVec3::X,
        DVec3::new(1.0, 1.0, 1.0),
        DVec3::new(-1.0, 2.0, -0.5),
        DVec3::new(0.0, -1.0, 1.0),
    ];
    for (k, &direction) in directions.iter().enumerate() {
        for bones in [1, 2, 7] {
            // The root at a third of the bound, the bones sharing the rest.
            let root = direction.normalize() * (MAX_REACH / 3.0);
            let length = (MAX_REACH * (2.0 / 3.0) / bones as f64) * (1.0 - 1e-12);
            let skeleton = chain(root, direction, length, bones).unwrap_or_else(|e| {
                panic!("direction {k}, {bones} bones: refused within the bound: {e}")
            });
            let mut global = GlobalPose::new();
            for trial in 0..200 {
                let pose = Pose {
                    rotations: (0..skeleton.len()).map(|_| random.rotation()).collect(),
                };
                skeleton.forward_kinematics(&pose, &mut global).unwrap();
                for (j, p) in global.positions.iter().enumerate() {
                    assert!(
                        p.is_finite(),
                        "direction {k}, {bones} bones, trial {trial}: joint {j} at {p}"
                    );
                    assert!(norm(*p) <= MAX_REACH * (1.0 + 1e-9), "joint {j} at {p}");
                }
            }
        }
    }
}

/// One bone of 1.8e308 (finite, and its rest pose's forward kinematics finite too) is
/// refused, and so is a joint whose lengths only add up past the bound; the error names
/// the first joint beyond it.
#[test]
fn a_joint_beyond_the_bound_is_refused_by_name() {
    let refused = Skeleton::new([
        JointDef::root(DVec3::ZERO).named("hip"),
        JointDef::child(0, DVec3::new(f64::MAX, 0.0, 0.0)).named("knee"),
        JointDef::child(1, DVec3::X).named("ankle"),
    ])
    .unwrap_err();
    match &refused {
        SkeletonError::ReachTooLarge { joint, reach } => {
            assert_eq!(joint, "joint 1 \"knee\"");
            assert_eq!(*reach, f64::MAX);
        }
        other => panic!("{other:?}"),
    }
    assert!(
        refused
            .to_string()
            .contains("forward kinematics could overflow")
    );

    // Each offset below the bound, the third joint's summed lengths above it.
    let half = 0.6 * MAX_REACH;
    let refused = chain(DVec3::ZERO, DVec3::Y, half, 3).unwrap_err();
    assert!(
        matches!(&refused, SkeletonError::ReachTooLarge { joint, .. } if joint == "joint 2"),
        "{refused:?}"
    );
    // Branches are summed along each path only: two children of 0.6 of the bound each,
    // on different branches, are accepted.
    Skeleton::new([
        JointDef::root(DVec3::ZERO),
        JointDef::child(0, DVec3::X * half),
        JointDef::child(0, DVec3::Y * half),
    ])
    .unwrap();
    // A root's offset is its position: a root beyond the bound is refused.
    let refused = Skeleton::new([JointDef::root(DVec3::Z * -(2.0 * MAX_REACH))]).unwrap_err();
    assert!(
        matches!(refused, SkeletonError::ReachTooLarge { .. }),
        "{refused:?}"
    );
    // Components above 1e154 (whose squares overflow) are measured without overflow.
    Skeleton::new([JointDef::root(DVec3::splat(1e200))]).unwrap();
}
