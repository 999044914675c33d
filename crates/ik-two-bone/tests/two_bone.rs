//! Two-bone IK against hand-computed poses, degenerate inputs, soften and weight, invalid
//! input, and fixed-seed random limbs checked by an independent forward kinematics.

use sinew_ik_two_bone::{Hinge, PreparedTwoBone, TwoBoneError, TwoBoneIk, TwoBoneReport};
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::{GlobalPose, JointDef, Pose, Skeleton};
use std::f64::consts::{FRAC_1_SQRT_2, FRAC_PI_2, PI, SQRT_2};

/// Root at the origin, bones `upper` and `lower` (local offsets of mid and tip).
fn limb(upper: DVec3, lower: DVec3) -> Skeleton {
    Skeleton::chain(DVec3::ZERO, &[upper, lower]).unwrap()
}

fn unit_limb() -> Skeleton {
    limb(DVec3::X, DVec3::X)
}

/// Runs `job` from the rest pose; returns the report, the pose and its global pose.
fn solve(skel: &Skeleton, job: &TwoBoneIk) -> (TwoBoneReport, Pose, GlobalPose) {
    let mut pose = skel.rest_pose();
    let mut global = GlobalPose::new();
    skel.forward_kinematics(&pose, &mut global).unwrap();
    let report = job.run(skel, &mut pose, &mut global).unwrap();
    (report, pose, global)
}

fn close(a: DVec3, b: DVec3, tol: f64) -> bool {
    (a - b).length() <= tol
}

#[track_caller]
fn assert_close(a: DVec3, b: DVec3, tol: f64) {
    assert!(
        close(a, b, tol),
        "{a} vs {b} (|d| = {:e})",
        (a - b).length()
    );
}

/// The distance between two rotations as unit quaternions, either sign (glam's
/// `angle_between` goes through `acos` and cannot resolve angles below about 1e-8).
fn rotation_gap(a: DQuat, b: DQuat) -> f64 {
    let (a, b) = (a.normalize(), b.normalize());
    (a - b).length().min((a + b).length())
}

/// Forward kinematics from scratch, so no state of the solve is reused.
fn fresh_fk(skel: &Skeleton, pose: &Pose) -> GlobalPose {
    let mut g = GlobalPose::new();
    skel.forward_kinematics(pose, &mut g).unwrap();
    g
}

#[test]
fn right_angle_bend_with_the_pole_on_either_side() {
    let skel = unit_limb();
    let target = DVec3::new(1.0, 1.0, 0.0); // sqrt(2) away: a 90 degree bend
    // Pole beyond +x: the elbow at (1, 0, 0); pole beyond +y: the elbow at (0, 1, 0).
    for (pole, elbow) in [
        (DVec3::new(3.0, -1.0, 0.0), DVec3::X),
        (DVec3::new(-1.0, 3.0, 0.0), DVec3::Y),
    ] {
        let job = TwoBoneIk::new(0, 1, 2, target, pole);
        let (report, pose, g) = solve(&skel, &job);
        assert!(report.reached);
        assert!(report.error < 1e-15, "{:e}", report.error);
        assert!((report.bend_angle - FRAC_PI_2).abs() < 1e-15);
        assert_close(g.positions[0], DVec3::ZERO, 0.0);
        assert_close(g.positions[1], elbow, 1e-15);
        assert_close(g.positions[2], target, 1e-15);
        // The mid joint's local rotation is the hinge rotation: a quarter turn about z.
        assert!(rotation_gap(pose.rotations[1], DQuat::from_rotation_z(FRAC_PI_2)) < 1e-15);
    }
}

#[test]
fn elbow_limited_to_one_side_still_follows_the_pole() {
    // Hinge 0..150 degrees: only positive bends about z. The root turns the limb so the
    // elbow is on the pole's side all the same (the hinge axis flips in world space).
    let skel = unit_limb();
    let target = DVec3::new(1.0, 1.0, 0.0);
    for (pole, elbow) in [
        (DVec3::new(3.0, -1.0, 0.0), DVec3::X),
        (DVec3::new(-1.0, 3.0, 0.0), DVec3::Y),
    ] {
        let mut job = TwoBoneIk::new(0, 1, 2, target, pole);
        job.hinge = Hinge::new(DVec3::Z, 0.0, 150f64.to_radians());
        let (report, _, g) = solve(&skel, &job);
        assert!(report.reached);
        assert!((report.bend_angle - FRAC_PI_2).abs() < 1e-15);
        assert_close(g.positions[1], elbow, 1e-15);
        assert_close(g.positions[2], target, 1e-15);
    }
}

#[test]
fn straight_limb_bends_in_the_plane_the_hinge_axis_defines() {
    // Rest pose straight along x, hinge about y, pole on the target line: no bend plane
    // from the pose or the pole, so the hinge decides. A quarter turn about y takes the
    // lower bone to -z; the minimal root turn onto the target line (a -45 degree turn
    // about y) puts the elbow at (1, 0, 1)/sqrt 2.
    let skel = unit_limb();
    let target = DVec3::new(SQRT_2, 0.0, 0.0);
    let mut job = TwoBoneIk::new(0, 1, 2, target, DVec3::new(5.0, 0.0, 0.0));
    job.hinge = Hinge::free(DVec3::Y);
    let (report, _, g) = solve(&skel, &job);
    assert!(report.reached);
    assert_close(
        g.positions[1],
        DVec3::new(FRAC_1_SQRT_2, 0.0, FRAC_1_SQRT_2),
        1e-15,
    );
    assert_close(g.positions[2], target, 1e-15);
}

#[test]
fn twist_turns_the_limb_about_the_target_line() {
    let skel = unit_limb();
    let target = DVec3::new(SQRT_2, 0.0, 0.0);
    let pole = DVec3::new(0.5, -1.0, 0.0);
    let mut job = TwoBoneIk::new(0, 1, 2, target, pole);
    let (_, _, g) = solve(&skel, &job);
    assert_close(
        g.positions[1],
        DVec3::new(FRAC_1_SQRT_2, -FRAC_1_SQRT_2, 0.0),
        1e-15,
    );
    // A pole a quarter turn away from that bend plane (towards +z): the limb turns a
    // quarter about the target line, -y to +z.
    let quarter_off = TwoBoneIk::new(0, 1, 2, target, DVec3::new(0.5, 0.0, 1.0));
    let (report, _, g) = solve(&skel, &quarter_off);
    assert!(report.reached);
    assert_close(
        g.positions[1],
        DVec3::new(FRAC_1_SQRT_2, 0.0, FRAC_1_SQRT_2),
        1e-15,
    );
    assert_close(g.positions[2], target, 1e-15);
    // And a twist of a quarter turn about +x takes -y to -z.
    job.twist = FRAC_PI_2;
    let (report, _, g) = solve(&skel, &job);
    assert!(report.reached);
    assert_close(
        g.positions[1],
        DVec3::new(FRAC_1_SQRT_2, 0.0, -FRAC_1_SQRT_2),
        1e-15,
    );
    assert_close(g.positions[2], target, 1e-15);
}

#[test]
fn target_beyond_reach_straightens_towards_it() {
    let skel = limb(DVec3::X, DVec3::X * 0.5);
    let target = DVec3::new(0.0, 3.0, 4.0); // 5 away, reach 1.5
    let job = TwoBoneIk::new(0, 1, 2, target, DVec3::new(0.0, 0.0, -1.0));
    let (report, _, g) = solve(&skel, &job);
    assert!(!report.reached);
    assert!((report.error - 3.5).abs() < 1e-15, "{}", report.error);
    assert!(report.bend_angle.abs() < 1e-15);
    let dir = target / 5.0;
    assert_close(g.positions[1], dir, 1e-15);
    assert_close(g.positions[2], dir * 1.5, 1e-15);
}

#[test]
fn target_closer_than_the_bone_difference_folds_the_limb() {
    let skel = limb(DVec3::X, DVec3::X * 0.4);
    let target = DVec3::new(0.0, 0.2, 0.0); // closer than 1 - 0.4
    let job = TwoBoneIk::new(0, 1, 2, target, DVec3::new(5.0, 1.0, 0.0));
    let (report, _, g) = solve(&skel, &job);
    assert!(!report.reached);
    assert!((report.error - 0.4).abs() < 1e-15, "{}", report.error);
    assert!((report.bend_angle.abs() - PI).abs() < 1e-15);
    // Folded flat: the elbow and the tip on the target line, the tip 0.6 from the root.
    assert_close(g.positions[1], DVec3::Y, 1e-15);
    assert_close(g.positions[2], DVec3::Y * 0.6, 1e-15);
}

#[test]
fn target_on_the_root() {
    // Equal bones fold onto the root exactly; the elbow turns to the pole.
    let skel = unit_limb();
    let job = TwoBoneIk::new(0, 1, 2, DVec3::ZERO, DVec3::new(0.0, 3.0, 0.0));
    let (report, _, g) = solve(&skel, &job);
    assert!(report.reached);
    assert!(report.error < 1e-15, "{:e}", report.error);
    assert_close(g.positions[1], DVec3::Y, 1e-15);
    // Unequal bones fold as far as they go, keeping the limb's direction.
    let skel = limb(DVec3::X, DVec3::X * 0.5);
    let (report, _, g) = solve(&skel, &job);
    assert!(!report.reached);
    assert!((report.error - 0.5).abs() < 1e-15);
    assert_close(g.positions[1], DVec3::X, 1e-15);
    assert_close(g.positions[2], DVec3::X * 0.5, 1e-15);
}

#[test]
fn zero_length_bones() {
    // No forearm: the tip is the elbow, at distance 1 from the root whatever the bend.
    let skel = limb(DVec3::X, DVec3::ZERO);
    let job = TwoBoneIk::new(0, 1, 2, DVec3::new(0.0, 2.0, 0.0), DVec3::Z);
    let (report, _, g) = solve(&skel, &job);
    assert!(!report.reached);
    assert!((report.error - 1.0).abs() < 1e-15);
    assert_close(g.positions[2], DVec3::Y, 1e-15);
    // A target at distance 1 is reached.
    let job = TwoBoneIk::new(0, 1, 2, DVec3::new(0.0, 0.6, 0.8), DVec3::Z);
    let (report, _, g) = solve(&skel, &job);
    assert!(report.reached);
    assert_close(g.positions[2], DVec3::new(0.0, 0.6, 0.8), 1e-15);
    // No upper arm: the elbow stays on the root, the tip aims at the target.
    let skel = limb(DVec3::ZERO, DVec3::X);
    let job = TwoBoneIk::new(0, 1, 2, DVec3::new(0.0, 0.0, -3.0), DVec3::Y);
    let (report, _, g) = solve(&skel, &job);
    assert!(!report.reached);
    assert!((report.error - 2.0).abs() < 1e-15);
    assert_close(g.positions[1], DVec3::ZERO, 0.0);
    assert_close(g.positions[2], -DVec3::Z, 1e-15);
    // No bones at all.
    let skel = limb(DVec3::ZERO, DVec3::ZERO);
    let job = TwoBoneIk::new(0, 1, 2, DVec3::ONE, DVec3::Y);
    let (report, pose, g) = solve(&skel, &job);
    assert!((report.error - 3f64.sqrt()).abs() < 1e-15);
    assert!(pose.rotations.iter().all(|q| q.is_finite()));
    assert!(g.positions.iter().all(|p| *p == DVec3::ZERO));
}

#[test]
fn tiny_and_huge_limbs_are_solved_like_unit_ones() {
    // The right-angle case scaled: squared lengths would underflow or overflow, the
    // answer must not.
    for scale in [1e-300, 1e-200, 1e-120, 1e120, 1e200, 1e300] {
        let skel = limb(DVec3::X * scale, DVec3::X * scale);
        let target = DVec3::new(1.0, 1.0, 0.0) * scale;
        let job = TwoBoneIk::new(0, 1, 2, target, DVec3::new(3.0, -1.0, 0.0) * scale);
        let (report, pose, g) = solve(&skel, &job);
        assert!(report.reached, "scale {scale:e}");
        assert!(
            report.error <= 1e-15 * scale,
            "scale {scale:e}: {:e}",
            report.error
        );
        assert!(
            (report.bend_angle - FRAC_PI_2).abs() < 1e-15,
            "scale {scale:e}"
        );
        assert!(pose.rotations.iter().all(|q| q.is_finite()));
        assert_close(g.positions[1] / scale, DVec3::X, 1e-15);
        // Out of reach by far, and a target far beyond a unit limb.
        let job = TwoBoneIk::new(0, 1, 2, DVec3::new(0.0, 1e308, 0.0), DVec3::Z);
        let (report, _, g) = solve(&skel, &job);
        assert!(!report.reached);
        assert!(report.error.is_finite(), "scale {scale:e}");
        assert_close(g.positions[2] / scale, DVec3::Y * 2.0, 1e-15);
    }
}

#[test]
fn pole_on_the_target_line_or_on_the_root() {
    let skel = unit_limb();
    let target = DVec3::new(0.0, 1.2, 0.0);
    for pole in [target * 3.0, -target, DVec3::ZERO, target * 0.5] {
        let job = TwoBoneIk::new(0, 1, 2, target, pole);
        let (report, pose, g) = solve(&skel, &job);
        assert!(report.reached, "pole {pole}");
        assert!(report.error < 1e-15);
        assert!(pose.rotations.iter().all(|q| q.is_finite()));
        assert!(((g.positions[1] - g.positions[0]).length() - 1.0).abs() < 1e-15);
        assert!(((g.positions[2] - g.positions[1]).length() - 1.0).abs() < 1e-15);
    }
}

#[test]
fn hinge_range_clamps_the_bend() {
    // Equal unit bones bent by theta put the tip 2 cos(theta / 2) from the root. A bend
    // of 160 degrees with the hinge stopping at 150 ends at 150.
    let skel = unit_limb();
    let needed = 160f64.to_radians();
    let max = 150f64.to_radians();
    let target = DVec3::new(0.0, 0.0, 2.0 * (needed / 2.0).cos());
    let mut job = TwoBoneIk::new(0, 1, 2, target, DVec3::new(1.0, 0.0, 0.2));
    job.hinge = Hinge::new(DVec3::Z, 0.0, max);
    let (report, pose, g) = solve(&skel, &job);
    assert!(!report.reached);
    assert_eq!(report.bend_angle, max);
    let expected = 2.0 * (max / 2.0).cos() - 2.0 * (needed / 2.0).cos();
    assert!(
        (report.error - expected).abs() < 1e-15,
        "{} vs {expected}",
        report.error
    );
    assert!(rotation_gap(pose.rotations[1], DQuat::from_rotation_z(max)) < 1e-15);
    // Still aimed at the target, elbow towards the pole.
    assert_close(g.positions[2].normalize(), DVec3::Z, 1e-15);
    assert!(g.positions[1].x > 0.0);
    // A range that excludes the straight limb: a target out of reach ends at the bound
    // nearest to straight.
    job.hinge = Hinge::new(DVec3::Z, 0.5, 1.0);
    job.target = DVec3::new(0.0, 0.0, 5.0);
    let (report, _, g) = solve(&skel, &job);
    assert_eq!(report.bend_angle, 0.5);
    assert!((g.positions[2].length() - 2.0 * 0.25f64.cos()).abs() < 1e-15);
}

#[test]
fn soften_reaches_below_its_radius_and_is_continuous_across_it() {
    let skel = unit_limb();
    let soften = 0.9;
    let start = 1.8; // soften times the reach 2
    let dir = DVec3::new(0.0, 0.6, 0.8);
    let pole = DVec3::new(1.0, 0.0, 0.0);
    let run = |distance: f64| {
        let mut job = TwoBoneIk::new(0, 1, 2, dir * distance, pole);
        job.soften = soften;
        solve(&skel, &job)
    };
    for distance in [0.5, 1.0, 1.7, 1.8 - 1e-9] {
        let (report, _, g) = run(distance);
        assert!(report.reached, "{distance}");
        assert_close(g.positions[2], dir * distance, 1e-14);
    }
    // Across the soften radius the tip moves by about the target's move, not more.
    let (_, _, below) = run(start - 1e-9);
    let (_, _, above) = run(start + 1e-9);
    let jump = (above.positions[2] - below.positions[2]).length();
    assert!(jump < 2.5e-9, "{jump:e}");
    // Beyond it: on the target line at start + (2 - start)(1 - exp(-(d - start)/(2 - start))).
    for distance in [1.81, 1.9, 2.0, 2.5, 10.0] {
        let (report, _, g) = run(distance);
        assert!(!report.reached, "{distance}");
        let reach = 2.0;
        let softened =
            start + (reach - start) * (1.0 - (-(distance - start) / (reach - start)).exp());
        assert_close(g.positions[2], dir * softened, 1e-14);
        assert!((report.error - (distance - softened)).abs() < 1e-14);
    }
    // soften = 1 is no softening: the limb straightens at the reach.
    let mut job = TwoBoneIk::new(0, 1, 2, dir * 1.99, pole);
    job.soften = 1.0;
    let (report, _, _) = solve(&skel, &job);
    assert!(report.reached);
}

#[test]
fn weight_blends_with_the_incoming_pose() {
    let skel = unit_limb();
    let mut incoming = skel.rest_pose();
    incoming.rotations[0] = DQuat::from_rotation_y(0.3);
    incoming.rotations[1] = DQuat::from_rotation_x(0.2);
    let mut global = fresh_fk(&skel, &incoming);
    let mut job = TwoBoneIk::new(0, 1, 2, DVec3::new(0.2, 1.0, 0.3), DVec3::X);
    job.weight = 0.0;
    let mut pose = incoming.clone();
    let before = global.clone();
    let report = job.run(&skel, &mut pose, &mut global).unwrap();
    assert_eq!(pose, incoming);
    assert_eq!(global, before);
    assert!(!report.reached);
    assert_eq!(report.error, (before.positions[2] - job.target).length());

    // Full weight, then half: the half-weight rotations are the slerps.
    job.weight = 1.0;
    let mut full = incoming.clone();
    let mut g = before.clone();
    assert!(job.run(&skel, &mut full, &mut g).unwrap().reached);
    job.weight = 0.5;
    let mut half = incoming.clone();
    let mut g = before.clone();
    let report = job.run(&skel, &mut half, &mut g).unwrap();
    assert!(!report.reached);
    for j in 0..2 {
        let expected = incoming.rotations[j].slerp(full.rotations[j], 0.5);
        assert!(
            rotation_gap(half.rotations[j], expected) < 1e-14,
            "joint {j}"
        );
    }
    assert_eq!(g, fresh_fk(&skel, &half));
    assert_eq!(report.error, (g.positions[2] - job.target).length());
}

#[test]
fn invalid_input_names_the_field() {
    let skel = unit_limb();
    let pose = skel.rest_pose();
    let base = TwoBoneIk::new(0, 1, 2, DVec3::X, DVec3::Y);
    let check = |job: TwoBoneIk, field: &str| {
        let err = job.validate(&skel, &pose).unwrap_err();
        let message = err.to_string();
        assert!(message.contains(field), "{field}: {message}");
        let mut p = pose.clone();
        let mut g = GlobalPose::new();
        assert_eq!(job.run(&skel, &mut p, &mut g).unwrap_err(), err);
        assert_eq!(p, pose, "{field}: the pose must not change");
        err
    };
    let nan = f64::NAN;
    assert_eq!(
        check(TwoBoneIk { tip: 3, ..base }, "`tip`"),
        TwoBoneError::JointOutOfRange {
            field: "tip",
            index: 3,
            len: 3
        }
    );
    check(TwoBoneIk { root: 7, ..base }, "`root`");
    check(TwoBoneIk { mid: 0, ..base }, "`mid`");
    check(TwoBoneIk { tip: 1, ..base }, "`tip`");
    check(
        TwoBoneIk {
            root: 2,
            mid: 1,
            tip: 0,
            ..base
        },
        "`mid`",
    );
    check(
        TwoBoneIk {
            target: DVec3::new(0.0, nan, 0.0),
            ..base
        },
        "`target`",
    );
    check(
        TwoBoneIk {
            pole: DVec3::new(f64::INFINITY, 0.0, 0.0),
            ..base
        },
        "`pole`",
    );
    check(TwoBoneIk { twist: nan, ..base }, "`twist`");
    check(
        TwoBoneIk {
            soften: nan,
            ..base
        },
        "`soften`",
    );
    check(
        TwoBoneIk {
            soften: 1.5,
            ..base
        },
        "`soften`",
    );
    check(
        TwoBoneIk {
            weight: -0.1,
            ..base
        },
        "`weight`",
    );
    check(
        TwoBoneIk {
            hinge: Hinge::new(DVec3::ZERO, 0.0, 1.0),
            ..base
        },
        "`hinge.axis`",
    );
    check(
        TwoBoneIk {
            hinge: Hinge::new(DVec3::new(nan, 0.0, 1.0), 0.0, 1.0),
            ..base
        },
        "`hinge.axis`",
    );
    check(
        TwoBoneIk {
            hinge: Hinge::new(DVec3::Z, nan, 1.0),
            ..base
        },
        "`hinge.min`",
    );
    check(
        TwoBoneIk {
            hinge: Hinge::new(DVec3::Z, 0.0, f64::INFINITY),
            ..base
        },
        "`hinge.max`",
    );
    let err = check(
        TwoBoneIk {
            hinge: Hinge::new(DVec3::Z, 1.0, 0.5),
            ..base
        },
        "`hinge.min`",
    );
    assert!(err.to_string().contains("`hinge.max`"));

    // Named joints appear in ancestry errors; a bad pose is refused before anything moves.
    let named = Skeleton::new([
        JointDef {
            name: Some("shoulder".into()),
            parent: None,
            offset: DVec3::ZERO,
            ..JointDef::default()
        },
        JointDef {
            name: Some("elbow".into()),
            parent: Some(0),
            offset: DVec3::X,
            ..JointDef::default()
        },
        JointDef {
            name: Some("other".into()),
            parent: Some(0),
            offset: DVec3::Y,
            ..JointDef::default()
        },
    ])
    .unwrap();
    let err = TwoBoneIk::new(0, 1, 2, DVec3::X, DVec3::Y)
        .validate(&named, &named.rest_pose())
        .unwrap_err();
    assert!(err.to_string().contains("\"other\""), "{err}");
    assert!(err.to_string().contains("\"elbow\""), "{err}");
    let mut bad = skel.rest_pose();
    bad.rotations[1] = DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0);
    assert!(
        base.validate(&skel, &bad)
            .unwrap_err()
            .to_string()
            .contains("joint 1")
    );
    let short = Pose {
        rotations: vec![DQuat::IDENTITY; 2],
    };
    assert!(base.validate(&skel, &short).is_err());
}

#[test]
fn a_global_pose_that_is_not_fk_of_the_pose_is_refused_without_changes() {
    let skel = Skeleton::chain(DVec3::ZERO, &[DVec3::X, DVec3::X, DVec3::X]).unwrap();
    let job = TwoBoneIk::new(0, 1, 2, DVec3::new(1.0, 1.0, 0.0), DVec3::X * 3.0);
    // A NaN in the global pose of a joint the solve reads.
    let pose = skel.rest_pose();
    let mut global = fresh_fk(&skel, &pose);
    global.positions[2].y = f64::NAN;
    let mut p = pose.clone();
    let err = job.run(&skel, &mut p, &mut global).unwrap_err();
    assert_eq!(
        err,
        TwoBoneError::InvalidGlobalPose {
            joint: "joint 2".into()
        }
    );
    assert_eq!(p, pose);
    // An unusable rotation below the tip, which forward kinematics of the result meets:
    // the error is passed on and the two solved rotations are put back.
    let mut bad = skel.rest_pose();
    let mut global = fresh_fk(&skel, &bad);
    bad.rotations[3] = DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0);
    let before = bad.clone();
    let err = job.run(&skel, &mut bad, &mut global).unwrap_err();
    assert!(err.to_string().contains("joint 3"), "{err}");
    assert_eq!(bad.rotations[..3], before.rotations[..3]);
}

#[test]
fn unnormalized_incoming_rotations_and_a_rotated_parent() {
    // The limb hangs from a turned joint and carries scaled quaternions; the solve must
    // reach the same target and keep the parent's rotation.
    let skel = Skeleton::chain(
        DVec3::new(0.0, 1.0, 0.0),
        &[DVec3::Y * 0.5, DVec3::X, DVec3::X],
    )
    .unwrap();
    let mut pose = skel.rest_pose();
    pose.rotations[0] = DQuat::from_rotation_y(0.7) * 2.0;
    pose.rotations[1] = DQuat::from_rotation_x(0.3) * 0.25;
    pose.rotations[2] = DQuat::from_rotation_z(-0.4) * 5.0;
    let mut global = fresh_fk(&skel, &pose);
    let shoulder = global.positions[1];
    let target = shoulder + DVec3::new(0.3, -1.2, 0.9);
    let mut job = TwoBoneIk::new(1, 2, 3, target, shoulder + DVec3::Z);
    job.hinge = Hinge::new(DVec3::new(0.0, 0.0, 2.0), -0.1, 2.8);
    let parent = pose.rotations[0];
    let report = job.run(&skel, &mut pose, &mut global).unwrap();
    assert!(report.reached);
    assert!(report.error < 1e-15, "{:e}", report.error);
    assert_eq!(pose.rotations[0], parent);
    assert_eq!(global, fresh_fk(&skel, &pose));
    assert!((global.positions[1] - shoulder).length() < 1e-15);
}

/// A small fixed-seed generator (splitmix64), so the random tests need no dependency.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi).
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }

    fn vector(&mut self, size: f64) -> DVec3 {
        DVec3::new(
            self.uniform(-size, size),
            self.uniform(-size, size),
            self.uniform(-size, size),
        )
    }

    fn rotation(&mut self) -> DQuat {
        let axis = self.vector(1.0) + DVec3::new(0.0, 0.0, 1e-3);
        DQuat::from_axis_angle(axis.normalize(), self.uniform(-PI, PI))
    }
}

/// A limb inside a larger skeleton: a spine above the root (so the root has a rotated
/// parent), a joint between root and mid, one between mid and tip, and a branch off the
/// mid joint that is not on the limb. Offsets are not collinear or perpendicular.
fn random_skeleton(rng: &mut Rng) -> Skeleton {
    let j = |parent: Option<usize>, offset: DVec3| JointDef {
        name: None,
        parent,
        offset,
        ..JointDef::default()
    };
    Skeleton::new([
        j(None, rng.vector(1.0)),    // 0 spine
        j(Some(0), rng.vector(0.5)), // 1 root (shoulder)
        j(Some(1), rng.vector(0.6)), // 2 upper-arm twist
        j(Some(2), rng.vector(0.4)), // 3 mid (elbow)
        j(Some(3), rng.vector(0.3)), // 4 side branch
        j(Some(3), rng.vector(0.5)), // 5 forearm twist
        j(Some(5), rng.vector(0.3)), // 6 tip (wrist)
        j(Some(6), rng.vector(0.1)), // 7 hand
    ])
    .unwrap()
}

const ROOT: usize = 1;
const MID: usize = 3;
const TIP: usize = 6;

fn random_pose(rng: &mut Rng, n: usize) -> Pose {
    Pose {
        rotations: (0..n).map(|_| rng.rotation()).collect(),
    }
}

#[test]
fn random_limbs_reach_reachable_targets_exactly_and_keep_bone_lengths() {
    let mut rng = Rng(0x5eed_2b0e);
    let mut worst = 0.0f64;
    for case in 0..2000 {
        let skel = random_skeleton(&mut rng);
        let axis = rng.vector(1.0) + DVec3::new(0.0, 1e-3, 0.0);
        let (min, max) = {
            let a = rng.uniform(-PI, PI);
            let b = rng.uniform(-PI, PI);
            (a.min(b), a.max(b))
        };
        let hinge = Hinge::new(axis, min, max);
        // A reachable target: forward kinematics of a pose whose mid rotation is a hinge
        // angle inside the range.
        let mut goal_pose = random_pose(&mut rng, skel.len());
        let goal_angle = rng.uniform(min, max);
        goal_pose.rotations[MID] = DQuat::from_axis_angle(axis.normalize(), goal_angle);
        let target = fresh_fk(&skel, &goal_pose).positions[TIP];

        // Solve from another pose that agrees above the root (the root's parent) only.
        let mut pose = random_pose(&mut rng, skel.len());
        pose.rotations[0] = goal_pose.rotations[0];
        // The joints between root and mid, and mid and tip, are rigid in the solve.
        pose.rotations[2] = goal_pose.rotations[2];
        pose.rotations[5] = goal_pose.rotations[5];
        let mut global = fresh_fk(&skel, &pose);
        let before = global.clone();
        let incoming = pose.clone();
        let pole = rng.vector(2.0);
        let mut job = TwoBoneIk::new(ROOT, MID, TIP, target, pole);
        job.hinge = hinge;
        let report = job.run(&skel, &mut pose, &mut global).unwrap();

        let check = fresh_fk(&skel, &pose);
        assert_eq!(
            global, check,
            "case {case}: the global pose is FK of the pose"
        );
        let error = (check.positions[TIP] - target).length();
        assert_eq!(report.error, error, "case {case}");
        assert!(report.reached, "case {case}: error {error:e}");
        assert!(error < 1e-12, "case {case}: error {error:e}");
        worst = worst.max(error);
        assert!((min..=max).contains(&report.bend_angle), "case {case}");
        let expected_mid = DQuat::from_axis_angle(axis.normalize(), report.bend_angle);
        assert!(
            rotation_gap(pose.rotations[MID], expected_mid) < 1e-14,
            "case {case}"
        );
        // Bone lengths: root to mid, mid to tip.
        for (a, b) in [(ROOT, MID), (MID, TIP)] {
            let l0 = (before.positions[b] - before.positions[a]).length();
            let l1 = (check.positions[b] - check.positions[a]).length();
            assert!(
                (l0 - l1).abs() < 1e-14,
                "case {case}: bone {a}-{b} {l0} -> {l1}"
            );
        }
        // Only the root and mid local rotations change; the root stays in place.
        for j in [0, 2, 4, 5, 6, 7] {
            assert_eq!(
                pose.rotations[j], incoming.rotations[j],
                "case {case}: joint {j}"
            );
        }
        assert_eq!(check.positions[ROOT], before.positions[ROOT]);
        // The mid joint in the root-target-pole plane, on the pole's side.
        let root = check.positions[ROOT];
        let line = (target - root).normalize();
        let across = |p: DVec3| (p - root) - line * line.dot(p - root);
        let mid_across = across(check.positions[MID]);
        let pole_across = across(pole);
        if mid_across.length() > 1e-6 && pole_across.length() > 1e-6 {
            let normal = line.cross(pole_across).normalize();
            assert!(
                normal.dot(check.positions[MID] - root).abs() < 1e-13,
                "case {case}"
            );
            assert!(mid_across.dot(pole_across) > 0.0, "case {case}");
        }
    }
    eprintln!("worst tip error over 2000 reachable random limbs: {worst:e}");
}

#[test]
fn random_targets_never_give_nan_and_report_the_fk_error() {
    let mut rng = Rng(42);
    for case in 0..3000 {
        let skel = random_skeleton(&mut rng);
        let mut pose = random_pose(&mut rng, skel.len());
        let mut global = fresh_fk(&skel, &pose);
        let incoming = pose.clone();
        let (min, max) = {
            let a = rng.uniform(-4.0, 4.0);
            (a, a + rng.uniform(0.0, 3.0))
        };
        // Some targets on the root, some poles on the root or the target line.
        let root = global.positions[ROOT];
        let target = match case % 5 {
            0 => root,
            1 => root + rng.vector(10.0),
            _ => root + rng.vector(1.5),
        };
        let pole = match case % 7 {
            0 => root,
            1 => root + (target - root) * rng.uniform(-2.0, 2.0),
            _ => rng.vector(3.0),
        };
        let job = TwoBoneIk {
            twist: rng.uniform(-4.0, 4.0),
            soften: rng.uniform(0.0, 1.0),
            weight: if case % 3 == 0 {
                1.0
            } else {
                rng.uniform(0.0, 1.0)
            },
            hinge: Hinge::new(rng.vector(1.0) + DVec3::new(1e-3, 0.0, 0.0), min, max),
            ..TwoBoneIk::new(ROOT, MID, TIP, target, pole)
        };
        let report = job.run(&skel, &mut pose, &mut global).unwrap();
        assert!(
            report.error.is_finite() && report.bend_angle.is_finite(),
            "case {case}"
        );
        assert!((min..=max).contains(&report.bend_angle), "case {case}");
        assert!(pose.rotations.iter().all(|q| q.is_finite()), "case {case}");
        let check = fresh_fk(&skel, &pose);
        assert!(check.positions.iter().all(|p| p.is_finite()), "case {case}");
        assert_eq!(
            report.error,
            (check.positions[TIP] - target).length(),
            "case {case}"
        );
        for j in [0, 2, 4, 5, 6, 7] {
            assert_eq!(
                pose.rotations[j], incoming.rotations[j],
                "case {case}: joint {j}"
            );
        }
    }
}

#[test]
fn a_skeleton_hinge_limit_converts_to_the_same_hinge() {
    let limit = sinew_skeleton::limits::Hinge {
        axis: DVec3::new(0.0, -1.0, 0.0),
        min: 0.0,
        max: 2.5,
    };
    let hinge = Hinge::from(limit);
    assert_eq!(
        (hinge.axis, hinge.min, hinge.max),
        (limit.axis, limit.min, limit.max)
    );
}

#[test]
fn a_limb_folded_onto_its_root_or_near_it_lands_to_rounding() {
    // Equal bones folded flat put the tip on the root: the fold is exactly reachable,
    // and `reached` promises rounding only. The opening angle's sine comes from the
    // squared distances, not from `1 +- cos` after rounding, or the fold would be off by
    // sqrt(2 eps) rad (4.5e-9 at the tip of 0.3 bones). Targets a small distance from
    // the root are reached to rounding too (closer than about 1e-12 of the limb the aim
    // has no reliable direction; section 5 of the docs).
    for (length, scale) in [(0.3, 1.0), (1.0, 1.0), (0.3, 1e-6), (0.3, 1e6)] {
        let skel = limb(DVec3::X * length * scale, DVec3::X * length * scale);
        for distance in [0.0, 1e-9, 1e-6, 1e-3] {
            let target = DVec3::new(0.6, -0.8, 0.0) * distance * scale;
            let mut job = TwoBoneIk::new(0, 1, 2, target, DVec3::Y * scale);
            job.hinge = Hinge::free(DVec3::Z);
            let (report, pose, global) = solve(&skel, &job);
            let what = format!("bones {length} x {scale}, target at {distance}");
            assert!(report.reached, "{what}: {report:?}");
            let fk = fresh_fk(&skel, &pose);
            let error = fk.positions[2].distance(target);
            assert!(error <= 4e-16 * scale, "{what}: error {error:e}");
            assert_eq!(global.positions[2], fk.positions[2], "{what}");
        }
    }
}

/// A prepared job with the per-call fields of `job`.
fn prepared_for(skel: &Skeleton, job: &TwoBoneIk) -> PreparedTwoBone {
    let mut prepared = job.prepare(skel).unwrap();
    prepared.target = job.target;
    prepared.pole = job.pole;
    prepared.twist = job.twist;
    prepared.soften = job.soften;
    prepared.weight = job.weight;
    prepared
}

#[test]
fn a_prepared_job_gives_the_same_bits_as_run_and_fk_of_its_pose() {
    // Bare limbs (the three joints alone, forward kinematics inline), a bare limb under a
    // turned parent, and the limb inside the larger skeleton with joints in between,
    // warm-started over many targets, with and without twist, soften and weight.
    let mut rng = Rng(0x0b0e_5eed);
    let bare = Skeleton::chain(
        DVec3::ZERO,
        &[DVec3::new(0.3, 0.05, 0.0), DVec3::new(0.25, 0.0, 0.02)],
    )
    .unwrap();
    let under_parent = Skeleton::chain(
        DVec3::new(0.1, 1.0, 0.0),
        &[DVec3::Y, DVec3::X * 0.4, DVec3::X * 0.35],
    )
    .unwrap();
    let cases: [(Skeleton, usize, usize, usize); 3] = [
        (bare, 0, 1, 2),
        (under_parent, 1, 2, 3),
        (random_skeleton(&mut rng), ROOT, MID, TIP),
    ];
    for (skel, root, mid, tip) in cases {
        let mut pose_a = random_pose(&mut rng, skel.len());
        let mut pose_b = pose_a.clone();
        let mut global_a = fresh_fk(&skel, &pose_a);
        let mut global_b = global_a.clone();
        let mut job = TwoBoneIk::new(root, mid, tip, DVec3::ZERO, DVec3::Y);
        job.hinge = Hinge::new(rng.vector(1.0) + DVec3::Z, -0.5, 2.5);
        let mut prepared = job.prepare(&skel).unwrap();
        assert_eq!(prepared.joints(), (root, mid, tip));
        assert_eq!(prepared.hinge(), job.hinge);
        for k in 0..400 {
            job.target = skel.offset(0) + rng.vector(1.2);
            job.pole = rng.vector(2.0);
            job.twist = if k % 3 == 0 {
                rng.uniform(-PI, PI)
            } else {
                0.0
            };
            job.soften = if k % 4 == 0 {
                rng.uniform(0.0, 1.0)
            } else {
                1.0
            };
            job.weight = if k % 5 == 0 {
                rng.uniform(0.0, 1.0)
            } else {
                1.0
            };
            prepared.target = job.target;
            prepared.pole = job.pole;
            prepared.twist = job.twist;
            prepared.soften = job.soften;
            prepared.weight = job.weight;
            let a = job.run(&skel, &mut pose_a, &mut global_a).unwrap();
            let b = prepared.run(&skel, &mut pose_b, &mut global_b).unwrap();
            assert_eq!(a, b, "joints {root} {mid} {tip}, target {k}");
            assert_eq!(pose_a, pose_b);
            assert_eq!(global_a, global_b);
            // The inline forward kinematics is the skeleton's, bit for bit.
            assert_eq!(global_b, fresh_fk(&skel, &pose_b), "target {k}");
            assert!(a.error.is_finite() && a.bend_angle.is_finite());
        }
    }
}

#[test]
fn a_prepared_job_refuses_what_validate_refuses_with_the_same_error() {
    let skel = unit_limb();
    let pose = skel.rest_pose();
    let base = TwoBoneIk::new(0, 1, 2, DVec3::X, DVec3::Y);
    let nan = f64::NAN;
    // Structure and hinge: refused by `prepare`.
    for job in [
        TwoBoneIk { tip: 3, ..base },
        TwoBoneIk { mid: 0, ..base },
        TwoBoneIk {
            root: 2,
            mid: 1,
            tip: 0,
            ..base
        },
        TwoBoneIk {
            hinge: Hinge::new(DVec3::ZERO, 0.0, 1.0),
            ..base
        },
        TwoBoneIk {
            hinge: Hinge::new(DVec3::new(nan, 0.0, 1.0), 0.0, 1.0),
            ..base
        },
        TwoBoneIk {
            hinge: Hinge::new(DVec3::Z, 0.0, f64::INFINITY),
            ..base
        },
        TwoBoneIk {
            hinge: Hinge::new(DVec3::Z, 1.0, 0.5),
            ..base
        },
    ] {
        let expected = job.validate(&skel, &pose).unwrap_err();
        assert_eq!(job.prepare(&skel).unwrap_err(), expected);
    }
    // Per-call inputs: refused by each run, with nothing changed.
    for (job, field) in [
        (
            TwoBoneIk {
                target: DVec3::new(0.0, nan, 0.0),
                ..base
            },
            "`target`",
        ),
        (
            TwoBoneIk {
                pole: DVec3::new(f64::INFINITY, 0.0, 0.0),
                ..base
            },
            "`pole`",
        ),
        (TwoBoneIk { twist: nan, ..base }, "`twist`"),
        (
            TwoBoneIk {
                soften: nan,
                ..base
            },
            "`soften`",
        ),
        (
            TwoBoneIk {
                soften: 1.5,
                ..base
            },
            "`soften`",
        ),
        (
            TwoBoneIk {
                weight: -0.1,
                ..base
            },
            "`weight`",
        ),
        (
            TwoBoneIk {
                weight: nan,
                ..base
            },
            "`weight`",
        ),
    ] {
        let expected = job.validate(&skel, &pose).unwrap_err();
        assert!(expected.to_string().contains(field), "{field}: {expected}");
        let prepared = prepared_for(&skel, &job);
        let mut p = pose.clone();
        let mut g = fresh_fk(&skel, &pose);
        let g0 = g.clone();
        assert_eq!(prepared.run(&skel, &mut p, &mut g).unwrap_err(), expected);
        assert_eq!((p.clone(), g.clone()), (pose.clone(), g0), "{field}");
    }
    // The pose: wrong size, unusable rotation at the root or the mid joint, and (forward
    // kinematics being inline for a bare limb) at the tip.
    let prepared = base.prepare(&skel).unwrap();
    let mut short = Pose {
        rotations: vec![DQuat::IDENTITY; 2],
    };
    let mut g = fresh_fk(&skel, &pose);
    assert_eq!(
        prepared.run(&skel, &mut short, &mut g).unwrap_err(),
        base.validate(&skel, &short).unwrap_err()
    );
    for joint in 0..3 {
        let mut bad = skel.rest_pose();
        bad.rotations[joint] = DQuat::from_xyzw(0.0, nan, 0.0, 1.0);
        let before = bad.clone();
        let mut g = fresh_fk(&skel, &pose);
        let g0 = g.clone();
        let err = prepared.run(&skel, &mut bad, &mut g).unwrap_err();
        assert!(err.to_string().contains(&format!("joint {joint}")), "{err}");
        assert_eq!(
            err,
            base.run(&skel, &mut bad.clone(), &mut g0.clone())
                .unwrap_err()
        );
        // NaN is not equal to itself: compare what is printed.
        assert_eq!(
            format!("{:?}", (bad, g)),
            format!("{:?}", (before, g0)),
            "joint {joint}: nothing changes"
        );
    }
    // A NaN in the global pose of a joint the solve reads (a bare limb reads the mid
    // joint's position, not its rotation): refused, nothing changed.
    let mut p = pose.clone();
    let mut g = fresh_fk(&skel, &pose);
    g.positions[1].x = nan;
    let err = prepared.run(&skel, &mut p, &mut g).unwrap_err();
    assert_eq!(
        err,
        TwoBoneError::InvalidGlobalPose {
            joint: "joint 1".into()
        }
    );
    assert_eq!(
        err,
        base.run(&skel, &mut p.clone(), &mut g.clone()).unwrap_err()
    );
    assert_eq!(p, pose);
    // A NaN where the solve writes without reading (the global rotations of the mid
    // joint and the tip of a bare limb) is overwritten by forward kinematics.
    let mut g = fresh_fk(&skel, &pose);
    g.rotations[1].x = nan;
    g.rotations[2].y = nan;
    let report = prepared.run(&skel, &mut p, &mut g).unwrap();
    assert!(report.reached);
    assert_eq!(g, fresh_fk(&skel, &p));
}

#[test]
fn a_prepared_job_refuses_another_skeleton() {
    let skel = unit_limb();
    let prepared = TwoBoneIk::new(0, 1, 2, DVec3::X, DVec3::Y)
        .prepare(&skel)
        .unwrap();
    // Same size, another bone; and another size.
    for other in [
        limb(DVec3::X, DVec3::Y),
        Skeleton::chain(DVec3::ZERO, &[DVec3::X; 3]).unwrap(),
    ] {
        let mut pose = other.rest_pose();
        let mut global = fresh_fk(&other, &pose);
        let before = (pose.clone(), global.clone());
        let err = prepared.run(&other, &mut pose, &mut global).unwrap_err();
        assert_eq!(
            err,
            TwoBoneError::OtherSkeleton {
                joints: other.len(),
                prepared_joints: 3
            }
        );
        assert!(err.to_string().contains("`skeleton`"), "{err}");
        assert_eq!((pose, global), before);
    }
    // The skeleton it was prepared for, or an equal copy, is accepted.
    let copy = skel.clone();
    let mut pose = copy.rest_pose();
    let mut global = fresh_fk(&copy, &pose);
    assert!(prepared.run(&copy, &mut pose, &mut global).unwrap().reached);
}

#[test]
fn a_turn_of_more_than_120_degrees_onto_the_line_without_a_pole_plane_is_minimal() {
    // The limb lies in the xy plane and bends about z; the target is behind the root, so
    // the tip turns by about 140 degrees onto the target line, and the pole is on that
    // line, so no pole plane fixes the turn about it. The minimal rotation between two
    // directions in the xy plane is about z: the limb stays in the xy plane.
    let skel = unit_limb();
    let target = DVec3::new(-1.4, -0.1, 0.0);
    for pole in [target * 3.0, DVec3::ZERO] {
        let job = TwoBoneIk::new(0, 1, 2, target, pole);
        let (report, _, g) = solve(&skel, &job);
        assert!(report.reached);
        assert_close(g.positions[2], target, 1e-15);
        assert!(g.positions[1].z.abs() < 1e-15, "{}", g.positions[1]);
        let prepared = job.prepare(&skel).unwrap();
        let mut pose = skel.rest_pose();
        let mut global = fresh_fk(&skel, &pose);
        assert_eq!(prepared.run(&skel, &mut pose, &mut global).unwrap(), report);
        assert_eq!(global, g);
    }
}
