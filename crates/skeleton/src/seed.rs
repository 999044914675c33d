//! A closed-form starting pose for a limb: a three-degree-of-freedom root joint (a
//! shoulder or a hip), a hinge (an elbow or a knee), and whatever lies below the hinge
//! held rigid. For a position goal the hinge angle follows from the distance to the
//! target (the law of cosines, in the general form for a hinge axis not perpendicular to
//! the bones), and the root joint turns the limb's tip onto the target, choosing the turn
//! about the root-to-target line that its limit allows best. The result is inside the
//! limits; the chain solvers start their finish from it when it is closer to the goal
//! than the pose they had. The derivation is in `docs/ik-finish.md`.

use crate::ik::Chain;
use crate::limits::JointLimit;
use crate::{Pose, Skeleton};
use sinew_math::{DQuat, DVec3, rotation_between, try_unit};

/// How many turns about the root-to-target line the root joint's limit is asked about
/// (evenly spaced over a full turn).
const ROOT_TURNS: usize = 8;

/// Whether `chain` has the limb shape [`limb_seed`] handles: at least two bones, the base
/// a swing-twist or free joint, the next joint a hinge. Read from the limits only.
#[must_use]
pub fn is_limb(skeleton: &Skeleton, chain: &Chain) -> bool {
    let joints = chain.joints();
    chain.bone_count() >= 2
        && matches!(
            skeleton.limit(joints[0]),
            JointLimit::SwingTwist(_) | JointLimit::Free
        )
        && matches!(skeleton.limit(joints[1]), JointLimit::Hinge(_))
}

/// Writes the closed-form limb pose for the position `target` into the base and hinge
/// joints of `chain` in `pose` (the joints below the hinge keep their rotations and are
/// held rigid); `base_position` and `base_parent` are the base joint's world position and
/// its parent's global rotation. Returns `false`, leaving `pose` unchanged, when the chain
/// is not a limb ([`is_limb`]) or the geometry has no direction to aim along (the target
/// on the base joint, or a limb whose tip is on the base joint).
///
/// The hinge angle `theta` is the one of the two solutions of
/// `|u + exp(theta a) v| = |target - base|` inside the hinge's range (`u` the upper bone,
/// `v` the rigid rest of the limb from the hinge to the effector, `a` the hinge axis),
/// or, when the distance is out of reach, the angle in the range that comes closest; the
/// base joint's rotation is the shortest turn of the limb's tip onto the target direction
/// composed with the turn about that direction (of eight evenly spaced ones) that
/// its limit violates least, then projected onto the limit.
#[must_use]
pub fn limb_seed(
    skeleton: &Skeleton,
    chain: &Chain,
    pose: &mut Pose,
    base_position: DVec3,
    base_parent: DQuat,
    target: DVec3,
) -> bool {
    if !is_limb(skeleton, chain) {
        return false;
    }
    let joints = chain.joints();
    let (root, hinge_joint) = (joints[0], joints[1]);
    let JointLimit::Hinge(hinge) = *skeleton.limit(hinge_joint) else {
        return false;
    };
    let Some(axis) = try_unit(hinge.axis) else {
        return false;
    };
    // The rest of the limb, from the hinge to the effector, in the hinge's frame.
    let mut rest = DVec3::ZERO;
    let mut turned = DQuat::IDENTITY;
    for (k, &j) in joints.iter().enumerate().skip(2) {
        rest += turned * skeleton.offset(j);
        if k < joints.len() - 1 {
            turned = (turned * pose.rotations[j]).normalize();
        }
    }
    let upper = skeleton.offset(hinge_joint);
    let goal = base_parent.conjugate() * (target - base_position);
    let wanted = goal.length_squared();
    // |u + exp(theta a) v|^2 = c0 + A cos(theta) + B sin(theta), splitting v into its
    // part along the axis (unturned) and across it (turned by theta).
    let along = axis * axis.dot(rest);
    let across = rest - along;
    let c0 = upper.length_squared() + rest.length_squared() + 2.0 * upper.dot(along);
    let a = 2.0 * upper.dot(across);
    let b = 2.0 * upper.dot(axis.cross(across));
    let amplitude = a.hypot(b);
    let theta = if amplitude > 1e-12 * c0.max(f64::MIN_POSITIVE) {
        let phase = b.atan2(a);
        let spread = ((wanted - c0) / amplitude).clamp(-1.0, 1.0).acos();
        // Of the two solutions (each clamped to the range), the one whose distance comes
        // closer to the wanted one; the first on a tie.
        let reach = |t: f64| {
            let t = t.clamp(hinge.min, hinge.max);
            (t, ((c0 + amplitude * (t - phase).cos()) - wanted).abs())
        };
        let (t1, e1) = reach(wrap(phase + spread));
        let (t2, e2) = reach(wrap(phase - spread));
        if e2 < e1 { t2 } else { t1 }
    } else {
        // The hinge does not change the distance: keep it where it is.
        return false;
    };
    let elbow = DQuat::from_axis_angle(axis, theta);
    let tip = upper + elbow * rest;
    let (Some(tip_dir), Some(goal_dir)) = (try_unit(tip), try_unit(goal)) else {
        return false;
    };
    let aim = rotation_between(tip_dir, goal_dir);
    let limit = skeleton.prepared_limit(root);
    let current = pose.rotations[root];
    // The least violation; on a tie the one closest to the current rotation. The
    // candidates are asked in order of closeness (the first on equal closeness), so the
    // first one inside the limit is the answer and the rest need no violation.
    let mut candidates = [(0.0, DQuat::IDENTITY); ROOT_TURNS];
    for (i, slot) in candidates.iter_mut().enumerate() {
        let spin = DQuat::from_axis_angle(
            goal_dir,
            std::f64::consts::TAU * i as f64 / ROOT_TURNS as f64,
        );
        let candidate = (spin * aim).normalize();
        *slot = (candidate.dot(current).abs(), candidate);
    }
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut best = (f64::INFINITY, aim);
    for &(_, candidate) in &candidates {
        let violation = limit.violation(candidate);
        if violation < best.0 {
            best = (violation, candidate);
            if violation == 0.0 {
                break;
            }
        }
    }
    pose.rotations[root] = limit.project(best.1);
    pose.rotations[hinge_joint] = skeleton.prepared_limit(hinge_joint).project(elbow);
    true
}

/// `angle` wrapped into `(-pi, pi]`.
fn wrap(angle: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let mut a = angle % TAU;
    if a > PI {
        a -= TAU;
    } else if a <= -PI {
        a += TAU;
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::limits::{Hinge, test_shoulder};
    use crate::{GlobalPose, JointDef};

    /// An arm: a base joint with `base_limit`, an elbow hinge about -y (0 to 150
    /// degrees), a forearm twist hinge about x, a wrist, and the hand.
    fn arm(base_limit: JointLimit) -> Skeleton {
        let joint = |parent: Option<usize>, offset: DVec3, limit: JointLimit| JointDef {
            name: None,
            parent,
            offset,
            limit,
        };
        let hinge = |axis: DVec3, min: f64, max: f64| {
            JointLimit::Hinge(Hinge {
                axis,
                min: min.to_radians(),
                max: max.to_radians(),
            })
        };
        Skeleton::new([
            joint(None, DVec3::new(0.1, 0.2, 0.3), base_limit),
            joint(
                Some(0),
                DVec3::new(0.30, 0.0, 0.0),
                hinge(DVec3::NEG_Y, 0.0, 150.0),
            ),
            joint(
                Some(1),
                DVec3::new(0.125, 0.0, 0.0),
                hinge(DVec3::X, -80.0, 80.0),
            ),
            joint(Some(2), DVec3::new(0.125, 0.0, 0.0), JointLimit::Free),
            joint(Some(3), DVec3::new(0.08, 0.0, 0.0), JointLimit::Free),
        ])
        .unwrap()
    }

    /// Seeds `pose` for `target` and returns the hand's distance to it.
    fn seeded_error(skeleton: &Skeleton, pose: &mut Pose, target: DVec3) -> f64 {
        let chain = Chain::whole(skeleton).unwrap();
        let mut global = GlobalPose::new();
        skeleton.forward_kinematics(pose, &mut global).unwrap();
        assert!(limb_seed(
            skeleton,
            &chain,
            pose,
            global.positions[0],
            DQuat::IDENTITY,
            target
        ));
        skeleton.forward_kinematics(pose, &mut global).unwrap();
        for j in 0..skeleton.len() {
            assert!(
                skeleton.limit(j).violation(pose.rotations[j]) <= 1e-12,
                "{j}"
            );
        }
        global.positions[4].distance(target)
    }

    #[test]
    fn a_free_base_reaches_every_target_the_hinge_range_allows() {
        // With a free base joint the closed form is exact: the hinge sets the distance,
        // the base the direction. A bent wrist (kept rigid) makes the axis split matter.
        let skeleton = arm(JointLimit::Free);
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut unit = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut global = GlobalPose::new();
        for _ in 0..200 {
            let mut pose = skeleton.rest_pose();
            pose.rotations[0] = JointLimit::Free.sample([unit(), unit(), unit()]);
            pose.rotations[1] = skeleton.limit(1).sample([unit(), 0.0, 0.0]);
            pose.rotations[3] = DQuat::from_rotation_z(0.6 * unit() - 0.3);
            skeleton.forward_kinematics(&pose, &mut global).unwrap();
            let target = global.positions[4];
            // Start from another base rotation and elbow angle, the same wrist.
            pose.rotations[0] = DQuat::IDENTITY;
            pose.rotations[1] = DQuat::IDENTITY;
            let error = seeded_error(&skeleton, &mut pose, target);
            assert!(error <= 1e-12, "{error}");
        }
    }

    #[test]
    fn a_limited_base_stays_inside_and_reaches_most_targets() {
        let skeleton = arm(test_shoulder());
        let mut global = GlobalPose::new();
        let mut reached = 0;
        let count = 100;
        for i in 0..count {
            let u = (i as f64 + 0.5) / count as f64;
            let mut pose = skeleton.rest_pose();
            pose.rotations[0] = test_shoulder().sample([u, (7.0 * u) % 1.0, (3.0 * u) % 1.0]);
            pose.rotations[1] = skeleton.limit(1).sample([(5.0 * u) % 1.0, 0.0, 0.0]);
            skeleton.forward_kinematics(&pose, &mut global).unwrap();
            let target = global.positions[4];
            let mut start = skeleton.rest_pose();
            // Inside the limits whatever it reaches (asserted in `seeded_error`).
            reached += usize::from(seeded_error(&skeleton, &mut start, target) <= 1e-12);
        }
        // Every target is reachable with this wrist; the seed picks one of eight turns
        // about the target line, so a few land on the shoulder's bound and miss.
        assert!(reached >= 90, "{reached} of {count}");
    }

    #[test]
    fn out_of_reach_the_limb_points_at_the_target_at_full_stretch() {
        let skeleton = arm(JointLimit::Free);
        let target = DVec3::new(0.1, 0.2, 0.3) + DVec3::new(-0.3, 1.0, 0.5);
        let mut pose = skeleton.rest_pose();
        let error = seeded_error(&skeleton, &mut pose, target);
        // Straight: the hand 0.63 from the base, on the line to the target.
        let distance = DVec3::new(-0.3, 1.0, 0.5).length();
        assert!((error - (distance - 0.63)).abs() <= 1e-12, "{error}");
        // Too close for the hinge's 150 degrees: the fullest bend, still aimed.
        let near = DVec3::new(0.1, 0.2, 0.3) + DVec3::new(0.01, 0.0, 0.0);
        let error = seeded_error(&skeleton, &mut pose, near);
        let folded = (0.09f64 + 0.1089 + 2.0 * 0.3 * 0.33 * 150f64.to_radians().cos()).sqrt();
        assert!(
            (error - (folded - 0.01)).abs() <= 1e-12,
            "{error} vs {folded}"
        );
    }

    #[test]
    fn other_shapes_and_degenerate_targets_leave_the_pose() {
        // Two hinges in a row are not a limb.
        let joint = |parent: Option<usize>, limit: JointLimit| JointDef {
            name: None,
            parent,
            offset: DVec3::X,
            limit,
        };
        let hinge = JointLimit::hinge(DVec3::Z, -1.0, 1.0).unwrap();
        let skeleton = Skeleton::new([
            joint(None, hinge),
            joint(Some(0), hinge),
            joint(Some(1), JointLimit::Free),
        ])
        .unwrap();
        let chain = Chain::whole(&skeleton).unwrap();
        assert!(!is_limb(&skeleton, &chain));
        let mut pose = skeleton.rest_pose();
        let before = pose.clone();
        assert!(!limb_seed(
            &skeleton,
            &chain,
            &mut pose,
            DVec3::X,
            DQuat::IDENTITY,
            DVec3::Y
        ));
        assert_eq!(pose, before);
        // A target on the base joint gives no direction to aim along.
        let skeleton = arm(test_shoulder());
        let chain = Chain::whole(&skeleton).unwrap();
        assert!(is_limb(&skeleton, &chain));
        let mut pose = skeleton.rest_pose();
        let before = pose.clone();
        let base = DVec3::new(0.1, 0.2, 0.3);
        assert!(!limb_seed(
            &skeleton,
            &chain,
            &mut pose,
            base,
            DQuat::IDENTITY,
            base
        ));
        assert_eq!(pose, before);
    }
}
