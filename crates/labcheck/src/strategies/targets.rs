//! IK targets of every kind the issue lists, placed relative to a chain in a pose.
//!
//! A target depends on the chain and its pose (its base, reach, joints and effector), so
//! the strategy generates a [`TargetSpec`] (a kind and the random numbers it needs) and
//! [`TargetSpec::place`] turns it into a point once forward kinematics of the pose is
//! known. Shrinking goes towards [`TargetKind::Reachable`] and towards the first joint.

use super::direction;
use proptest::prelude::*;
use proptest::sample::Index;
use sinew_math::{DVec3, try_unit};
use sinew_skeleton::GlobalPose;
use sinew_skeleton::ik::Chain;

/// What a target is, relative to the chain.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TargetKind {
    /// At a distance from the base inside the chain's workspace: in
    /// `[max(0, 2 l_max - reach), reach)`, the annulus a chain with longest bone `l_max`
    /// can reach.
    Reachable,
    /// Beyond the reach, by `1e-9` to `10` times the reach (or `MIN_BONE`, if larger).
    Unreachable,
    /// At exactly the reach (to rounding of the placement) from the base.
    AtReach,
    /// Exactly on the base joint.
    OnBase,
    /// Exactly on one of the chain's joints (the effector included).
    OnJoint,
    /// On one of the chain's bones, between its two joints.
    OnBone,
    /// On the far side of the base from the effector: `base - f reach unit(effector -
    /// base)`, `f` in `[0, 1)`, antiparallel to the base-to-effector direction (for a
    /// straight chain, to every joint's lever).
    Antiparallel,
    /// Enormously far (`1e150` from the base), finite.
    Far,
}

/// Every kind, in shrinking order.
pub const ALL_KINDS: [TargetKind; 8] = [
    TargetKind::Reachable,
    TargetKind::Unreachable,
    TargetKind::AtReach,
    TargetKind::OnBase,
    TargetKind::OnJoint,
    TargetKind::OnBone,
    TargetKind::Antiparallel,
    TargetKind::Far,
];

/// A target kind and the random numbers that place it.
#[derive(Clone, Copy, Debug)]
pub struct TargetSpec {
    /// The kind.
    pub kind: TargetKind,
    /// A direction from the base (used by the kinds placed at a distance).
    pub direction: DVec3,
    /// A number in `[0, 1)`: where in the kind's range of distances, or along a bone.
    pub fraction: f64,
    /// Which joint or bone, for [`TargetKind::OnJoint`] and [`TargetKind::OnBone`].
    pub index: Index,
}

/// Targets of the given kinds, equally likely.
pub fn target_of(kinds: &[TargetKind]) -> impl Strategy<Value = TargetSpec> + Clone {
    (
        prop::sample::select(kinds.to_vec()),
        direction(),
        0.0f64..1.0,
        any::<Index>(),
    )
        .prop_map(|(kind, direction, fraction, index)| TargetSpec {
            kind,
            direction,
            fraction,
            index,
        })
}

/// Targets of every kind.
pub fn target() -> impl Strategy<Value = TargetSpec> + Clone {
    target_of(&ALL_KINDS)
}

/// The inner radius of the chain's workspace: `max(0, 2 l_max - reach)`. (A chain can
/// put its effector at any distance from the base between this and the reach.)
#[must_use]
pub fn inner_radius(chain: &Chain) -> f64 {
    let longest = chain.bone_lengths().iter().copied().fold(0.0, f64::max);
    (2.0 * longest - chain.reach()).max(0.0)
}

impl TargetSpec {
    /// The target point for `chain` in the pose whose forward kinematics is `global`.
    #[must_use]
    pub fn place(&self, chain: &Chain, global: &GlobalPose) -> DVec3 {
        let base = global.positions[chain.base()];
        let reach = chain.reach();
        let joints = chain.joints();
        match self.kind {
            TargetKind::Reachable => {
                let inner = inner_radius(chain);
                base + self.direction * (inner + self.fraction * (reach - inner))
            }
            TargetKind::Unreachable => {
                let scale = reach.max(super::chains::MIN_BONE);
                let beyond = scale * 10f64.powf(-9.0 + 10.0 * self.fraction);
                base + self.direction * (reach + beyond)
            }
            TargetKind::AtReach => base + self.direction * reach,
            TargetKind::OnBase => base,
            TargetKind::OnJoint => global.positions[joints[self.index.index(joints.len())]],
            TargetKind::OnBone => {
                if chain.bone_count() == 0 {
                    return base;
                }
                let c = self.index.index(chain.bone_count());
                let (a, b) = (global.positions[joints[c]], global.positions[joints[c + 1]]);
                a.lerp(b, self.fraction)
            }
            TargetKind::Antiparallel => {
                let effector = global.positions[chain.effector()];
                let away = try_unit(effector - base).unwrap_or(self.direction);
                base - away * (self.fraction * reach)
            }
            TargetKind::Far => base + self.direction * 1e150,
        }
    }
}
