//! The reference full-body workload (called W8 in the benchmark reports), written once for
//! the tests, the benchmark and the measurement example.
//!
//! The humanoid: 22 joints, Y up, facing +z, offsets from the parent in metres. 0 hips
//! (0, 1.0, 0), the root; 1 spine1 (0, 0.10, 0); 2 spine2 (0, 0.12, 0); 3 chest
//! (0, 0.12, 0); 4 neck (0, 0.16, 0); 5 head (0, 0.10, 0); 6 l_clavicle (0.03, 0.12, 0)
//! under the chest; 7 l_shoulder (0.15, 0, 0); 8 l_elbow (0.28, 0, 0); 9 l_wrist
//! (0.25, 0, 0); 10..13 the right arm mirrored in x; 14 l_hip (0.09, -0.05, 0) under the
//! hips; 15 l_knee (0, -0.42, 0); 16 l_ankle (0, -0.40, 0); 17 l_toe (0, -0.05, 0.12);
//! 18..21 the right leg mirrored.
//!
//! Limits in degrees, swing-twist with the twist about the joint's child bone (for a
//! leaf, the bone into it) and the swing bounded by the ellipse of half-angles `a` (about
//! the limit's `a_axis`) and `b`: spine1, spine2, chest 30/30, twist +-20; neck and head
//! 40/40, +-60; clavicles 15/15, +-5; shoulders 100/70, +-80 (`a` about z, in the x-y
//! plane); elbows hinges 0..150 with the forearm bending towards +z; wrists 80/30, +-10
//! (`a` about z); hips 100/50, +-40 (`a` about x, forward and back); knees hinges 0..150
//! with the shin bending towards -z; ankles 40/25, +-10 (`a` about x); toes hinges about
//! x, -30..50. The hips (the root) are free.
//!
//! Effectors: l_wrist, r_wrist, l_ankle, r_ankle, head; the hips translate.

use crate::problem::{BodyEffector, BodyProblem, BodyState};
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::EffectorGoal;
use sinew_skeleton::limits::{Hinge, JointLimit, SwingTwist};
use sinew_skeleton::{JointDef, Pose, Skeleton, SkeletonError};
use std::f64::consts::TAU;

/// The effector joints of the humanoid: l_wrist, r_wrist, l_ankle, r_ankle, head.
pub const EFFECTORS: [usize; 5] = [9, 13, 16, 20, 5];

/// How far (metres) the goal sets move the hips from rest, at most.
pub const HIPS_OFFSET: f64 = 0.3;

/// How far (degrees) the goal sets turn the hips from rest, at most: the hips are free, and
/// a body turned over would not be a human pose.
pub const HIPS_TURN_DEGREES: f64 = 30.0;

/// The 22-joint humanoid of the [module docs](self).
pub fn humanoid() -> Result<Skeleton, SkeletonError> {
    let deg = f64::to_radians;
    let st = |twist: DVec3, a_axis: DVec3, a: f64, b: f64, t: f64| {
        JointLimit::SwingTwist(SwingTwist {
            twist_axis: twist.normalize(),
            a_axis,
            swing_a: deg(a),
            swing_b: deg(b),
            twist_min: -deg(t),
            twist_max: deg(t),
        })
    };
    let hinge = |axis: DVec3, min: f64, max: f64| {
        JointLimit::Hinge(Hinge {
            axis,
            min: deg(min),
            max: deg(max),
        })
    };
    let joint = |name: &str, parent: Option<usize>, offset: DVec3, limit: JointLimit| JointDef {
        name: Some(name.into()),
        parent,
        offset,
        limit,
    };
    let v = DVec3::new;
    let spine = st(DVec3::Y, DVec3::X, 30.0, 30.0, 20.0);
    let neck = st(DVec3::Y, DVec3::X, 40.0, 40.0, 60.0);
    let mut joints = vec![
        joint("hips", None, v(0.0, 1.0, 0.0), JointLimit::Free),
        joint("spine1", Some(0), v(0.0, 0.10, 0.0), spine),
        joint("spine2", Some(1), v(0.0, 0.12, 0.0), spine),
        joint("chest", Some(2), v(0.0, 0.12, 0.0), spine),
        joint("neck", Some(3), v(0.0, 0.16, 0.0), neck),
        joint("head", Some(4), v(0.0, 0.10, 0.0), neck),
    ];
    for (side, sx) in [("l", 1.0), ("r", -1.0)] {
        let out = DVec3::X * sx;
        let first = joints.len();
        joints.push(joint(
            &format!("{side}_clavicle"),
            Some(3),
            v(0.03 * sx, 0.12, 0.0),
            st(out, DVec3::Z, 15.0, 15.0, 5.0),
        ));
        joints.push(joint(
            &format!("{side}_shoulder"),
            Some(first),
            v(0.15 * sx, 0.0, 0.0),
            st(out, DVec3::Z, 100.0, 70.0, 80.0),
        ));
        // Turning about -y (left) or +y (right) by a positive angle takes the forearm
        // from +-x towards +z.
        joints.push(joint(
            &format!("{side}_elbow"),
            Some(first + 1),
            v(0.28 * sx, 0.0, 0.0),
            hinge(DVec3::NEG_Y * sx, 0.0, 150.0),
        ));
        joints.push(joint(
            &format!("{side}_wrist"),
            Some(first + 2),
            v(0.25 * sx, 0.0, 0.0),
            st(out, DVec3::Z, 80.0, 30.0, 10.0),
        ));
    }
    for (side, sx) in [("l", 1.0), ("r", -1.0)] {
        let first = joints.len();
        joints.push(joint(
            &format!("{side}_hip"),
            Some(0),
            v(0.09 * sx, -0.05, 0.0),
            st(DVec3::NEG_Y, DVec3::X, 100.0, 50.0, 40.0),
        ));
        // Turning about +x by a positive angle takes the shin from -y towards -z.
        joints.push(joint(
            &format!("{side}_knee"),
            Some(first),
            v(0.0, -0.42, 0.0),
            hinge(DVec3::X, 0.0, 150.0),
        ));
        joints.push(joint(
            &format!("{side}_ankle"),
            Some(first + 1),
            v(0.0, -0.40, 0.0),
            st(v(0.0, -0.05, 0.12), DVec3::X, 40.0, 25.0, 10.0),
        ));
        joints.push(joint(
            &format!("{side}_toe"),
            Some(first + 2),
            v(0.0, -0.05, 0.12),
            hinge(DVec3::X, -30.0, 50.0),
        ));
    }
    Skeleton::new(joints)
}

/// A small deterministic generator (SplitMix64) for the workloads, so that every tool
/// draws the same goal sets from the same seed without a dependency.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator from `seed`.
    #[must_use]
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// A number uniform in `[0, 1)`.
    pub fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A point uniform in the ball of radius `radius` about the origin.
    pub fn in_ball(&mut self, radius: f64) -> DVec3 {
        let z = 2.0 * self.uniform() - 1.0;
        let phi = TAU * self.uniform();
        let r = radius * self.uniform().cbrt();
        let s = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(s * phi.cos(), s * phi.sin(), z) * r
    }
}

/// A pose with every limited joint drawn uniformly in its limit's parameters
/// ([`JointLimit::sample`]) and every free joint turned by at most `free_turn` radians about
/// a random axis.
pub fn random_pose(skeleton: &Skeleton, rng: &mut Rng, free_turn: f64) -> Pose {
    let mut pose = skeleton.rest_pose();
    for (j, rotation) in pose.rotations.iter_mut().enumerate() {
        let limit = skeleton.limit(j);
        *rotation = if matches!(limit, JointLimit::Free) {
            let axis = rng.in_ball(1.0).try_normalize().unwrap_or(DVec3::Y);
            DQuat::from_axis_angle(axis, free_turn * rng.uniform())
        } else {
            limit.sample([rng.uniform(), rng.uniform(), rng.uniform()])
        };
    }
    pose
}

/// One goal set: the effectors' goals, made by forward kinematics of a random pose inside
/// the limits with the hips moved (so feasible by construction), and that pose.
#[derive(Clone, Debug)]
pub struct GoalSet {
    /// The five effectors, in [`EFFECTORS`] order.
    pub effectors: Vec<BodyEffector>,
    /// The pose and translation the goals were made from (one exact answer).
    pub pose: Pose,
    /// The hips' translation of that answer.
    pub root_translation: DVec3,
}

/// `count` goal sets from `seed`: random limit-respecting poses, the hips turned by up to
/// [`HIPS_TURN_DEGREES`] and moved by up to [`HIPS_OFFSET`] (uniform in the ball); with
/// `rotations`, the wrists also get their rotation as a goal.
pub fn goal_sets(skeleton: &Skeleton, count: usize, seed: u64, rotations: bool) -> Vec<GoalSet> {
    let mut rng = Rng::new(seed);
    (0..count)
        .map(|_| {
            let pose = random_pose(skeleton, &mut rng, HIPS_TURN_DEGREES.to_radians());
            let root_translation = rng.in_ball(HIPS_OFFSET);
            let mut state = BodyState::rest(skeleton);
            state.pose = pose.clone();
            state.root_translation = root_translation;
            // The pose is valid for the skeleton, so forward kinematics cannot fail.
            let _ = crate::problem::forward_kinematics(
                skeleton,
                &state.pose,
                root_translation,
                &mut state.global,
            );
            let effectors = EFFECTORS
                .iter()
                .enumerate()
                .map(|(k, &j)| {
                    let mut goal = EffectorGoal::at(j, state.global.positions[j]);
                    if rotations && k < 2 {
                        goal = goal.with_rotation(state.global.rotations[j]);
                    }
                    BodyEffector::new(goal)
                })
                .collect();
            GoalSet {
                effectors,
                pose,
                root_translation,
            }
        })
        .collect()
}

/// Frames of the squat clip.
pub const CLIP_FRAMES: usize = 600;

/// One step of the batch workload: `characters` problems on `skeleton`, character `c`
/// at frame `(7 c + step) mod CLIP_FRAMES` of `frames` (the clip's frames, so the
/// characters stand at staggered points of the squat), the root free to translate.
#[must_use]
pub fn batch_problems<'a>(
    skeleton: &'a Skeleton,
    frames: &'a [[BodyEffector; 5]],
    settings: sinew_skeleton::ik::SolveSettings,
    characters: usize,
    step: usize,
) -> Vec<BodyProblem<'a>> {
    (0..characters)
        .map(|c| {
            BodyProblem::new(skeleton, &frames[(c * 7 + step) % frames.len()], settings)
                .with_root_translation(true)
        })
        .collect()
}

/// The effectors of frame `frame` of the squat clip, given the rest pose's forward
/// kinematics `rest`: both ankles pinned where they stand, the head's goal descending
/// 0.4 and rising again with the hips (a squat, `0.2 (1 - cos(2 pi f / 600))`), and each
/// wrist following a circle of radius 0.15 in the x-y plane, 0.3 in front of the chest
/// and 0.2 below it, centred 0.2 out from the middle, descending with the squat.
#[must_use]
pub fn clip_frame(rest: &sinew_skeleton::GlobalPose, frame: usize) -> [BodyEffector; 5] {
    let phase = TAU * frame as f64 / CLIP_FRAMES as f64;
    let drop = DVec3::new(0.0, -0.2 * (1.0 - phase.cos()), 0.0);
    let chest = rest.positions[3];
    let circle = |sx: f64, turn: f64| {
        let centre = chest + DVec3::new(0.2 * sx, -0.2, 0.3) + drop;
        let angle = 2.0 * phase + turn;
        centre + DVec3::new(angle.cos(), angle.sin(), 0.0) * 0.15
    };
    [
        BodyEffector::at(EFFECTORS[0], circle(1.0, 0.0)),
        BodyEffector::at(EFFECTORS[1], circle(-1.0, std::f64::consts::PI)),
        BodyEffector::pinned(EFFECTORS[2], rest.positions[EFFECTORS[2]]),
        BodyEffector::pinned(EFFECTORS[3], rest.positions[EFFECTORS[3]]),
        BodyEffector::at(EFFECTORS[4], rest.positions[5] + drop),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use sinew_skeleton::GlobalPose;

    #[test]
    fn the_humanoid_has_the_documented_shape() {
        let skel = humanoid().unwrap();
        assert_eq!(skel.len(), 22);
        let mut g = GlobalPose::new();
        skel.forward_kinematics(&skel.rest_pose(), &mut g).unwrap();
        let close = |a: DVec3, b: DVec3| (a - b).length() < 1e-12;
        assert!(close(g.positions[5], DVec3::new(0.0, 1.60, 0.0)));
        assert!(close(g.positions[9], DVec3::new(0.71, 1.46, 0.0)));
        assert!(close(g.positions[13], DVec3::new(-0.71, 1.46, 0.0)));
        assert!(close(g.positions[16], DVec3::new(0.09, 0.13, 0.0)));
        assert!(close(g.positions[21], DVec3::new(-0.09, 0.08, 0.12)));
        for (j, name) in [
            (9, "l_wrist"),
            (13, "r_wrist"),
            (16, "l_ankle"),
            (20, "r_ankle"),
            (5, "head"),
        ] {
            assert_eq!(skel.name(j), Some(name));
        }
        // The hinges bend the way the workload says: elbows towards +z, knees towards -z.
        let mut bend = |j: usize, child: usize| {
            let mut pose = skel.rest_pose();
            pose.rotations[j] = skel.limit(j).sample([0.5, 0.0, 0.0]);
            skel.forward_kinematics(&pose, &mut g).unwrap();
            g.positions[child] - g.positions[j]
        };
        assert!(bend(8, 9).z > 0.1 && bend(12, 13).z > 0.1);
        assert!(bend(15, 16).z < -0.1 && bend(19, 20).z < -0.1);
    }

    #[test]
    fn goal_sets_are_reproducible_and_inside_the_limits() {
        let skel = humanoid().unwrap();
        let a = goal_sets(&skel, 20, 7, true);
        let b = goal_sets(&skel, 20, 7, true);
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(x.effectors, y.effectors);
            assert!(crate::limit_violation(&skel, &x.pose) <= 1e-12);
            assert!(x.root_translation.length() <= HIPS_OFFSET);
            assert!(
                x.effectors[0].goal.rotation.is_some() && x.effectors[2].goal.rotation.is_none()
            );
        }
    }
}
