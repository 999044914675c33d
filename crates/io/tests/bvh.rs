//! The BVH reader: hierarchy and channel orders of a hand-written file, rotations against
//! hand-computed ones for several Euler orders, forward kinematics against the file's own
//! matrix composition, located errors, the shipped squat, and no panic on truncated or
//! corrupted files.

use proptest::prelude::*;
use sinew_io::{Channel, parse_bvh};
use sinew_math::{DMat3, DMat4, DVec3};

/// A small arm with three rotation orders: the root (positions, then Z X Y), the
/// shoulder (X Y Z) and the elbow (Y X Z), plus a tail with a single Z channel.
const ARM: &str = "HIERARCHY
ROOT Base
{
  OFFSET 1.0 2.0 3.0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Shoulder
  {
    OFFSET 0 1 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    JOINT Elbow
    {
      OFFSET 2 0 0
      CHANNELS 3 Yrotation Xrotation Zrotation
      End Site
      {
        OFFSET 1.5 0 0
      }
    }
  }
  JOINT Tail
  {
    OFFSET 0 -1 0
    CHANNELS 1 Zrotation
  }
}
MOTION
Frames: 3
Frame Time: 0.04
0 0 0  0 0 0  0 0 0  0 0 0  0
0.5 -1 2  90 90 0  0 0 90  30 -45 10  45
-3 4 1.25  10 20 30  -40 50 -60  70 -80 90  -135
";

fn close(a: DVec3, b: DVec3) -> bool {
    (a - b).length() < 1e-12
}

#[test]
fn hierarchy_and_channels_of_a_hand_written_file() {
    let bvh = parse_bvh(ARM).unwrap();
    let s = &bvh.skeleton;
    assert_eq!(s.len(), 5);
    let names: Vec<_> = (0..5).map(|i| s.name(i).unwrap()).collect();
    assert_eq!(names, ["Base", "Shoulder", "Elbow", "Elbow_End", "Tail"]);
    let parents: Vec<_> = (0..5).map(|i| s.parent(i)).collect();
    assert_eq!(parents, [None, Some(0), Some(1), Some(2), Some(0)]);
    assert_eq!(s.offset(0), DVec3::new(1.0, 2.0, 3.0));
    assert_eq!(s.offset(3), DVec3::new(1.5, 0.0, 0.0));
    use Channel::*;
    assert_eq!(
        bvh.channels,
        vec![
            vec![
                Xposition, Yposition, Zposition, Zrotation, Xrotation, Yrotation
            ],
            vec![Xrotation, Yrotation, Zrotation],
            vec![Yrotation, Xrotation, Zrotation],
            vec![],
            vec![Zrotation],
        ]
    );
    assert_eq!(bvh.channel_count(), 13);
    assert_eq!(bvh.frame_time, 0.04);
    assert_eq!(bvh.frames.len(), 3);
    assert_eq!(bvh.frames[1].root_translation, DVec3::new(0.5, -1.0, 2.0));
    // End sites never rotate.
    for f in &bvh.frames {
        assert_eq!(f.pose.rotations[3], sinew_math::DQuat::IDENTITY);
    }
}

#[test]
fn euler_orders_match_hand_computed_rotations() {
    let bvh = parse_bvh(ARM).unwrap();
    let f = &bvh.frames[1];
    // Root: Z 90 then X 90, R = Rz(90) Rx(90): x -> Rz x = y; y -> Rx y = z -> Rz z = z;
    // z -> Rx z = -y -> Rz (-y) = x.
    let r = f.pose.rotations[0];
    assert!(close(r * DVec3::X, DVec3::Y));
    assert!(close(r * DVec3::Y, DVec3::Z));
    assert!(close(r * DVec3::Z, DVec3::X));
    // Shoulder: X 0, Y 0, Z 90: x -> y, y -> -x.
    let r = f.pose.rotations[1];
    assert!(close(r * DVec3::X, DVec3::Y));
    assert!(close(r * DVec3::Y, -DVec3::X));
    // Elbow: Y 30, X -45, Z 10, R = Ry(30) Rx(-45) Rz(10), written out by hand with the
    // textbook matrices.
    let (a, b, c) = (
        30f64.to_radians(),
        (-45f64).to_radians(),
        10f64.to_radians(),
    );
    let ry =
        DMat3::from_cols_array(&[a.cos(), 0.0, -a.sin(), 0.0, 1.0, 0.0, a.sin(), 0.0, a.cos()]);
    let rx =
        DMat3::from_cols_array(&[1.0, 0.0, 0.0, 0.0, b.cos(), b.sin(), 0.0, -b.sin(), b.cos()]);
    let rz =
        DMat3::from_cols_array(&[c.cos(), c.sin(), 0.0, -c.sin(), c.cos(), 0.0, 0.0, 0.0, 1.0]);
    let m = ry * rx * rz;
    let r = f.pose.rotations[2];
    for v in [DVec3::X, DVec3::Y, DVec3::Z, DVec3::new(0.3, -0.7, 2.0)] {
        assert!(close(r * v, m * v), "{} vs {}", r * v, m * v);
    }
    // Tail: a single Z channel of 45 degrees.
    let r = f.pose.rotations[4];
    let h = 0.5f64.sqrt();
    assert!(close(r * DVec3::X, DVec3::new(h, h, 0.0)));
}

/// Every joint's position by the file's own rule, independently of sinew's forward
/// kinematics: `M_joint = M_parent T(offset) R(channels)` with 4 x 4 matrices, the root
/// also translated by its position channels, and the channels' rotations multiplied as
/// 3 x 3 matrices in the listed order.
fn positions_by_matrices(text: &str, frame: usize) -> Vec<DVec3> {
    let bvh = parse_bvh(text).unwrap();
    let values: Vec<f64> = text
        .lines()
        .skip_while(|l| !l.starts_with("Frame Time"))
        .filter(|l| !l.trim().is_empty())
        .nth(1 + frame)
        .unwrap()
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    let mut next = values.into_iter();
    let mut world: Vec<DMat4> = Vec::new();
    for (j, channels) in bvh.channels.iter().enumerate() {
        let mut t = bvh.skeleton.offset(j);
        let mut r = DMat3::IDENTITY;
        for c in channels {
            let v = next.next().unwrap();
            let a = v.to_radians();
            match c {
                Channel::Xposition => t.x += v,
                Channel::Yposition => t.y += v,
                Channel::Zposition => t.z += v,
                Channel::Xrotation => r *= DMat3::from_rotation_x(a),
                Channel::Yrotation => r *= DMat3::from_rotation_y(a),
                Channel::Zrotation => r *= DMat3::from_rotation_z(a),
            }
        }
        let local = DMat4::from_translation(t) * DMat4::from_mat3(r);
        let m = match bvh.skeleton.parent(j) {
            Some(p) => world[p] * local,
            None => local,
        };
        world.push(m);
    }
    world.iter().map(|m| m.w_axis.truncate()).collect()
}

#[test]
fn forward_kinematics_matches_the_files_matrix_composition() {
    let bvh = parse_bvh(ARM).unwrap();
    for (f, frame) in bvh.frames.iter().enumerate() {
        let ours = frame.joint_positions(&bvh.skeleton).unwrap();
        let theirs = positions_by_matrices(ARM, f);
        for (j, (a, b)) in ours.iter().zip(&theirs).enumerate() {
            assert!(
                (*a - *b).length() < 1e-12,
                "frame {f} joint {j}: {a} vs {b}"
            );
        }
    }
}

const SQUAT: &str = include_str!("../../../scenes/data/squat.bvh");

#[test]
fn the_shipped_squat_keeps_its_feet_planted() {
    let bvh = parse_bvh(SQUAT).unwrap();
    assert_eq!(bvh.skeleton.len(), 26, "21 joints and 5 end sites");
    assert_eq!(bvh.frames.len(), 61);
    assert!((bvh.frame_time - 1.0 / 30.0).abs() < 1e-8);
    let index = |name: &str| {
        (0..bvh.skeleton.len())
            .find(|&i| bvh.skeleton.name(i) == Some(name))
            .unwrap()
    };
    let (hips, left_foot, right_toe) = (index("Hips"), index("LeftFoot"), index("RightToe_End"));
    let first = bvh.frames[0].joint_positions(&bvh.skeleton).unwrap();
    let mut lowest_hips = f64::INFINITY;
    for (f, frame) in bvh.frames.iter().enumerate() {
        let p = frame.joint_positions(&bvh.skeleton).unwrap();
        // Printed with six decimals in degrees: planted to about 1e-7 m.
        for j in [left_foot, right_toe] {
            assert!((p[j] - first[j]).length() < 1e-6, "frame {f}: {} moved", j);
        }
        lowest_hips = lowest_hips.min(p[hips].y);
        // The file's own composition agrees with sinew's forward kinematics everywhere.
        let theirs = positions_by_matrices(SQUAT, f);
        for (a, b) in p.iter().zip(&theirs) {
            assert!((*a - *b).length() < 1e-12);
        }
    }
    assert!((first[hips].y - 0.95).abs() < 1e-12);
    assert!(
        (lowest_hips - 0.65).abs() < 1e-3,
        "lowest hips {lowest_hips}"
    );
    assert!(first[right_toe].y.abs() < 1e-12, "toes on the floor");
}

/// Parses `text` and returns the error's (line, column, message).
fn error(text: &str) -> (usize, usize, String) {
    let e = parse_bvh(text).unwrap_err();
    assert!(
        e.to_string()
            .starts_with(&format!("line {}, column {}", e.line, e.column))
    );
    (e.line, e.column, e.message)
}

#[test]
fn errors_name_the_line_column_and_what_was_expected() {
    let (l, c, m) = error("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 zero 0\n");
    assert_eq!((l, c), (4, 12));
    assert!(
        m.contains("finite number") && m.contains("OFFSET's y") && m.contains("`zero`"),
        "{m}"
    );

    let (l, c, m) = error("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 1 Wrotation\n}\n");
    assert_eq!((l, c), (5, 14));
    assert!(m.contains("channel name") && m.contains("Wrotation"), "{m}");

    let (l, _, m) = error(
        "HIERARCHY\nROOT A\n{\n OFFSET 0 0 0\n CHANNELS 0\n JOINT B\n {\n  OFFSET 0 1 0\n  CHANNELS 1 Xposition\n }\n}\n",
    );
    assert_eq!(l, 9);
    assert!(m.contains("joint `B`") && m.contains("root only"), "{m}");

    let (l, c, m) = error("HIERARCHY\nROOT A\n{\n OFFSET 0 0 0\n CHANNELS 1 Xrotation\n");
    assert_eq!((l, c), (5, 22));
    assert!(m.contains("end of the file"), "{m}");

    let motion =
        "HIERARCHY\nROOT A\n{\n OFFSET 0 0 0\n CHANNELS 2 Xrotation Yrotation\n}\nMOTION\n";
    let (l, c, m) = error(&format!("{motion}Frames: 2\nFrame Time: 0.1\n1 2\n3\n"));
    assert_eq!((l, c), (11, 1));
    assert!(m.contains("expected 2 values on frame 1, found 1"), "{m}");

    let (l, c, m) = error(&format!("{motion}Frames: 2\nFrame Time: 0.1\n1 2\n"));
    assert_eq!((l, c), (8, 1));
    assert!(m.contains("declares 2 frames but has 1"), "{m}");

    let (l, c, m) = error(&format!("{motion}Frames: 1\nFrame Time: 0.1\n1 2\n3 4\n"));
    assert_eq!((l, c), (11, 1));
    assert!(m.contains("end of the file after 1 frames"), "{m}");

    let (l, c, m) = error(&format!("{motion}Frames: 1\nFrame Time: -0.1\n1 2\n"));
    assert_eq!((l, c), (9, 13));
    assert!(m.contains("positive frame time"), "{m}");

    let (l, c, m) = error(&format!("{motion}Frames: 1\nFrame Time: 0.1\n1 nan\n"));
    assert_eq!((l, c), (10, 3));
    assert!(m.contains("Yrotation") && m.contains("joint `A`"), "{m}");

    let (l, c, m) = error("HIERARCHY\nROOT A\n{\n OFFSET 0 0 0\n CHANNELS 0\n}\nROOT B\n");
    assert_eq!((l, c), (7, 1));
    assert!(m.contains("only one ROOT"), "{m}");

    let (l, c, m) = error("HIERARCHY\nROOT A\n{\n OFFSET 0 0 0\n CHANNELS 0\n BONE B\n");
    assert_eq!((l, c), (6, 2));
    assert!(m.contains("`JOINT`, `End Site` or `}`"), "{m}");

    let (l, c, m) = error("");
    assert_eq!((l, c), (1, 1));
    assert!(m.contains("`HIERARCHY`"), "{m}");
}

#[test]
fn braces_against_words_and_blank_lines_are_accepted() {
    let text = "HIERARCHY\nROOT A{\n OFFSET 0 0 0\n CHANNELS 1 Zrotation\n End Site{ OFFSET 1 0 0 }}\n\nMOTION\nFrames: 1\nFrame Time: 0.5\n\n90\n\n";
    let bvh = parse_bvh(text).unwrap();
    assert_eq!(bvh.skeleton.len(), 2);
    let p = bvh.frames[0].joint_positions(&bvh.skeleton).unwrap();
    assert!(close(p[1], DVec3::Y));
}

#[test]
fn every_truncation_and_many_byte_flips_give_err_or_ok_never_a_panic() {
    // Truncating at every character (the test passes if nothing panics; a prefix that
    // cuts the hierarchy short must be an error).
    let motion_at = ARM.find("MOTION").unwrap();
    for (cut, _) in ARM.char_indices() {
        let r = parse_bvh(&ARM[..cut]);
        if cut < motion_at {
            assert!(r.is_err(), "prefix of {cut} bytes parsed");
        }
    }
    // Flipping each byte of the file to a handful of values.
    let bytes = ARM.as_bytes();
    for i in 0..bytes.len() {
        for b in [b'0', b'{', b'}', b' ', b'\n', b'-', b'e', 0xff, b'9'] {
            let mut v = bytes.to_vec();
            v[i] = b;
            let _ = parse_bvh(&String::from_utf8_lossy(&v));
        }
    }
}

proptest! {
    // A fixed seed: the same corruptions on every run, so a CI verdict is reproducible.
    #![proptest_config(ProptestConfig {
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed_0b5f),
        ..ProptestConfig::with_cases(256)
    })]
    #[test]
    fn random_corruption_never_panics(
        flips in proptest::collection::vec((0usize..10_000, any::<u8>()), 1..8),
        cut in 0usize..10_000,
    ) {
        let mut v = SQUAT.as_bytes().to_vec();
        for (i, b) in flips {
            let i = i % v.len();
            v[i] = b;
        }
        v.truncate(cut.max(1) * v.len() / 10_000);
        let _ = parse_bvh(&String::from_utf8_lossy(&v));
    }
}
