//! Which joints a body problem can turn, and which effectors each of them moves.
//!
//! A joint moves an effector when it is a strict ancestor of the effector's joint (its
//! rotation carries the effector's position and frame), or when it is the effector's own
//! joint and the effector has a rotation goal (a joint's rotation turns its own frame but
//! not its position). Every other joint cannot change the cost, so the solvers leave it
//! alone. Built once per solve in O(joints + sum of effector depths), without allocation
//! once the buffers have grown.

use crate::problem::Target;
use sinew_skeleton::Skeleton;

/// Not a movable joint.
const NONE: usize = usize::MAX;

/// The movable joints of a problem and the effectors below each, as compressed lists.
#[derive(Clone, Debug, Default)]
pub(crate) struct Topology {
    /// The movable joints, in increasing index (topological) order.
    pub movable: Vec<usize>,
    /// `below[start[m]..start[m + 1]]`: the effectors (indices into the targets, in
    /// increasing order) that movable joint `m` moves.
    pub start: Vec<usize>,
    /// See `start`.
    pub below: Vec<usize>,
    /// Per joint: its index in `movable`, or `NONE`.
    slot: Vec<usize>,
    /// Per joint: how many effectors it moves (then a fill cursor).
    count: Vec<usize>,
}

impl Topology {
    /// Recomputes the lists for `targets` on `skeleton`.
    pub fn build(&mut self, skeleton: &Skeleton, targets: &[Target]) {
        let n = skeleton.len();
        self.count.clear();
        self.count.resize(n, 0);
        self.for_each_mover(skeleton, targets, |count, j, _| count[j] += 1);
        self.movable.clear();
        self.slot.clear();
        self.slot.resize(n, NONE);
        self.start.clear();
        let mut total = 0;
        for j in 0..n {
            if self.count[j] > 0 {
                self.slot[j] = self.movable.len();
                self.movable.push(j);
                self.start.push(total);
                total += self.count[j];
                // From here on `count` is the fill cursor of the joint's list.
                self.count[j] = self.start[self.slot[j]];
            }
        }
        self.start.push(total);
        self.below.clear();
        self.below.resize(total, 0);
        let below = &mut self.below;
        let mut cursor = std::mem::take(&mut self.count);
        Self::walk(skeleton, targets, |j, e| {
            below[cursor[j]] = e;
            cursor[j] += 1;
        });
        self.count = cursor;
    }

    /// The effectors movable joint `m` moves.
    pub fn below(&self, m: usize) -> &[usize] {
        &self.below[self.start[m]..self.start[m + 1]]
    }

    /// Movable joint index of joint `j`, if it is movable.
    #[cfg(test)]
    pub fn slot(&self, j: usize) -> Option<usize> {
        self.slot.get(j).copied().filter(|&m| m != NONE)
    }

    fn for_each_mover(
        &mut self,
        skeleton: &Skeleton,
        targets: &[Target],
        mut f: impl FnMut(&mut Vec<usize>, usize, usize),
    ) {
        let count = &mut self.count;
        Self::walk(skeleton, targets, |j, e| f(count, j, e));
    }

    /// Calls `f(joint, effector)` for every joint that moves each effector, effectors in
    /// order, so every joint's list comes out in increasing effector order.
    fn walk(skeleton: &Skeleton, targets: &[Target], mut f: impl FnMut(usize, usize)) {
        for (e, target) in targets.iter().enumerate() {
            if target.has_rotation() {
                f(target.joint, e);
            }
            let mut j = skeleton.parent(target.joint);
            while let Some(k) = j {
                f(k, e);
                j = skeleton.parent(k);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::{BodyEffector, BodyProblem, resolve_targets};
    use sinew_math::{DQuat, DVec3};
    use sinew_skeleton::JointDef;
    use sinew_skeleton::ik::{EffectorGoal, SolveSettings};

    #[test]
    fn movers_are_the_ancestors_and_a_rotation_goal_s_own_joint() {
        // 0 -> 1 -> 2, 0 -> 3 -> 4, 0 -> 5 (no effector below 5).
        let parents = [None, Some(0), Some(1), Some(0), Some(3), Some(0)];
        let skel = Skeleton::new(parents.iter().map(|&parent| JointDef {
            parent,
            offset: DVec3::X,
            ..JointDef::default()
        }))
        .unwrap();
        let effectors = [
            BodyEffector::at(2, DVec3::Y),
            BodyEffector::new(EffectorGoal::at(4, DVec3::Z).with_rotation(DQuat::IDENTITY)),
            BodyEffector::at(1, DVec3::Z),
        ];
        let problem = BodyProblem::new(&skel, &effectors, SolveSettings::default());
        let mut targets = Vec::new();
        resolve_targets(&problem, &mut targets);
        let mut topo = Topology::default();
        topo.build(&skel, &targets);
        assert_eq!(topo.movable, [0, 1, 3, 4]);
        assert_eq!(topo.below(0), [0, 1, 2]);
        assert_eq!(topo.below(1), [0]);
        assert_eq!(topo.below(2), [1]);
        assert_eq!(topo.below(3), [1]);
        assert_eq!(topo.slot(5), None);
        assert_eq!(topo.slot(4), Some(3));
        // Rebuilding with fewer effectors shrinks the lists.
        topo.build(&skel, &targets[..1]);
        assert_eq!(topo.movable, [0, 1]);
        assert_eq!(topo.below(0), [0]);
    }
}
