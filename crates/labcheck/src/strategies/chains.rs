//! Chains and branching trees of joints, with random poses.
//!
//! Ranges (the issue's): 1 to 64 joints ([`chain`], [`tree`]), plus 1 000-joint chains
//! ([`long_chain`], to be used with few cases); bone lengths log-uniform in
//! `[1e-4, 1e3]` with one bone in ten of length exactly zero ([`bone_length`]); local
//! rotations uniform in axis and angle, with exact identities, quarter and half turns and
//! unnormalized quaternions mixed in ([`rotation`]); the root anywhere in `[-10, 10]^3` or
//! at the origin. A chain comes in one of three [`Shape`]s, because the degenerate IK
//! cases live in the special shapes: random, straight (every bone along one line, so
//! every joint's lever is parallel to the chain) and folded (bones alternating back and
//! forth along one line, so the effector sits near the base).
//!
//! Shrinking goes to fewer joints, shorter bones, identity rotations and the root at the
//! origin.

use super::{direction, log_uniform, point};
use proptest::prelude::*;
use proptest::sample::Index;
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::Chain;
use sinew_skeleton::limits::JointLimit;
use sinew_skeleton::{JointDef, Pose, Skeleton};
use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::ops::RangeInclusive;

/// The shortest non-zero bone generated.
pub const MIN_BONE: f64 = 1e-4;
/// The longest bone generated.
pub const MAX_BONE: f64 = 1e3;

/// A bone length: log-uniform in `[MIN_BONE, MAX_BONE]`, or exactly 0 one time in ten.
pub fn bone_length() -> impl Strategy<Value = f64> + Clone {
    prop_oneof![9 => log_uniform(-4.0, 3.0), 1 => Just(0.0)]
}

/// A local rotation: mostly uniform axis and angle in `[-pi, pi]`; also the exact
/// identity, exact quarter and half turns (the angles where formulas switch branches),
/// and quaternions scaled by `[1e-3, 1e3]` (forward kinematics must normalize them).
pub fn rotation() -> impl Strategy<Value = DQuat> + Clone {
    prop_oneof![
        6 => (direction(), -PI..=PI).prop_map(|(axis, angle)| DQuat::from_axis_angle(axis, angle)),
        1 => Just(DQuat::IDENTITY),
        1 => (direction(), prop::sample::select(vec![FRAC_PI_2, PI, -FRAC_PI_2]))
            .prop_map(|(axis, angle)| DQuat::from_axis_angle(axis, angle)),
        1 => (direction(), -PI..=PI, log_uniform(-3.0, 3.0))
            .prop_map(|(axis, angle, scale)| DQuat::from_axis_angle(axis, angle) * scale),
    ]
}

/// Where the root joint is: the origin, or anywhere in `[-10, 10]^3`.
pub fn root_position() -> impl Strategy<Value = DVec3> + Clone {
    prop_oneof![1 => Just(DVec3::ZERO), 3 => point(10.0)]
}

/// The layout of a generated chain.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    /// Random bone directions and random local rotations.
    Random,
    /// Every bone along one direction, local rotations the identity except the root's:
    /// a straight chain (the antiparallel and at-reach cases of IK are exact here).
    Straight,
    /// Bones alternating between one direction and its opposite, local rotations the
    /// identity except the root's: a chain folded onto a line, effector near the base.
    Folded,
}

/// A shape: random half the time, straight or folded a quarter each.
pub fn shape() -> impl Strategy<Value = Shape> + Clone {
    prop_oneof![2 => Just(Shape::Random), 1 => Just(Shape::Straight), 1 => Just(Shape::Folded)]
}

/// A serial skeleton, a pose of it, and the whole chain (joint 0 to the last joint).
#[derive(Clone, Debug)]
pub struct ChainCase {
    /// The skeleton: joint `i` hangs from joint `i - 1`.
    pub skeleton: Skeleton,
    /// A pose (one local rotation per joint).
    pub pose: Pose,
    /// The chain from joint 0 to the last joint.
    pub chain: Chain,
    /// How it was laid out.
    pub shape: Shape,
}

/// Chains with a joint count in `joints` (a chain of `n` joints has `n - 1` bones; one
/// joint is a chain of no bones, which every solver must accept).
///
/// # Panics
/// If `joints` starts at 0 (a skeleton has at least one joint).
pub fn chain_with(joints: RangeInclusive<usize>) -> impl Strategy<Value = ChainCase> {
    assert!(*joints.start() >= 1, "a chain has at least one joint");
    let bones = joints.start() - 1..=joints.end() - 1;
    (
        root_position(),
        rotation(),
        shape(),
        direction(),
        prop::collection::vec((bone_length(), direction(), rotation()), bones),
    )
        .prop_map(|(root, root_rotation, shape, line, bones)| {
            let offsets: Vec<DVec3> = bones
                .iter()
                .enumerate()
                .map(|(c, &(length, dir, _))| match shape {
                    Shape::Random => dir * length,
                    Shape::Straight => line * length,
                    Shape::Folded if c % 2 == 0 => line * length,
                    Shape::Folded => -line * length,
                })
                .collect();
            let skeleton = Skeleton::chain(root, &offsets).expect("finite offsets");
            let mut rotations = vec![root_rotation];
            rotations.extend(bones.iter().map(|&(_, _, q)| match shape {
                Shape::Random => q,
                Shape::Straight | Shape::Folded => DQuat::IDENTITY,
            }));
            let chain = Chain::whole(&skeleton).expect("a serial chain");
            ChainCase {
                skeleton,
                pose: Pose { rotations },
                chain,
                shape,
            }
        })
}

/// A joint limit of any kind, valid: free, fixed, a hinge about a random axis over a
/// random range within `[-pi, pi]`, or a swing-twist about a random twist axis with
/// half-angles in `[0.05, pi)` and a random twist range within `[-pi, pi]`.
pub fn joint_limit() -> impl Strategy<Value = JointLimit> + Clone {
    prop_oneof![
        1 => Just(JointLimit::Free),
        1 => Just(JointLimit::Fixed),
        3 => (direction(), -PI..PI, 0.0..TAU).prop_map(|(axis, min, width)| {
            JointLimit::hinge(axis, min, (min + width).min(PI)).expect("a valid hinge")
        }),
        3 => (direction(), 0.05..PI, 0.05..PI, -PI..PI, 0.0..TAU).prop_map(
            |(twist, a, b, twist_min, width)| {
                JointLimit::swing_twist(
                    twist,
                    twist.any_orthonormal_vector(),
                    a,
                    b,
                    twist_min,
                    (twist_min + width).min(PI),
                )
                .expect("a valid swing-twist limit")
            }
        ),
    ]
}

/// Chains of 2 to 12 joints with a random limit on every joint ([`joint_limit`]), the
/// pose projected inside the limits (a solve's start, so "never above the start" is a
/// fair test).
pub fn limited_chain() -> impl Strategy<Value = ChainCase> {
    (chain_with(2..=12), prop::collection::vec(joint_limit(), 12)).prop_map(|(mut case, limits)| {
        for (j, limit) in limits.into_iter().enumerate().take(case.skeleton.len()) {
            case.skeleton.set_limit(j, limit).expect("a valid limit");
            case.pose.rotations[j] = limit.project(case.pose.rotations[j]);
        }
        case
    })
}

/// Chains of 1 to 64 joints.
pub fn chain() -> impl Strategy<Value = ChainCase> {
    chain_with(1..=64)
}

/// Chains of exactly 1 000 joints (use with a small case count).
pub fn long_chain() -> impl Strategy<Value = ChainCase> {
    chain_with(1000..=1000)
}

/// A branching skeleton, a pose, and a chain inside it from `base` to `effector`.
#[derive(Clone, Debug)]
pub struct TreeCase {
    /// The skeleton, in topological order.
    pub skeleton: Skeleton,
    /// A pose.
    pub pose: Pose,
    /// The chain from an ancestor of the effector (or the effector itself) to the
    /// effector.
    pub chain: Chain,
}

/// Trees of `joints` joints: each joint after the root hangs from a uniformly chosen
/// earlier joint (so the trees branch, and are rarely depth-first ordered), with the
/// same bone lengths and rotations as [`chain`]; the chain runs from a random ancestor
/// of a random effector to that effector.
///
/// # Panics
/// If `joints` starts at 0.
pub fn tree_with(joints: RangeInclusive<usize>) -> impl Strategy<Value = TreeCase> {
    assert!(*joints.start() >= 1, "a tree has at least one joint");
    let others = joints.start() - 1..=joints.end() - 1;
    (
        root_position(),
        rotation(),
        prop::collection::vec(
            (any::<Index>(), bone_length(), direction(), rotation()),
            others,
        ),
        any::<Index>(),
        any::<Index>(),
    )
        .prop_map(|(root, root_rotation, joints, effector, base)| {
            let mut defs = vec![JointDef {
                name: None,
                parent: None,
                offset: root,
                ..JointDef::default()
            }];
            let mut rotations = vec![root_rotation];
            for (i, &(parent, length, dir, q)) in joints.iter().enumerate() {
                defs.push(JointDef {
                    name: None,
                    parent: Some(parent.index(i + 1)),
                    offset: dir * length,
                    ..JointDef::default()
                });
                rotations.push(q);
            }
            let skeleton = Skeleton::new(defs).expect("a valid tree");
            let effector = effector.index(skeleton.len());
            let mut ancestors = vec![effector];
            while let Some(p) = skeleton.parent(*ancestors.last().expect("non-empty")) {
                ancestors.push(p);
            }
            let base = ancestors[base.index(ancestors.len())];
            let chain = Chain::new(&skeleton, base, effector).expect("base is an ancestor");
            TreeCase {
                skeleton,
                pose: Pose { rotations },
                chain,
            }
        })
}

/// Trees of 1 to 64 joints.
pub fn tree() -> impl Strategy<Value = TreeCase> {
    tree_with(1..=64)
}
