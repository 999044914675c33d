//! A fixed amount of two-bone work for an instruction counter: run with
//! `valgrind --tool=callgrind target/release/examples/two_bone_count PART [SOLVES]`.
//!
//! The limb of the `two_bone` criterion bench (shoulder at the origin, upper arm 0.30 and
//! forearm 0.25 along +x, elbow hinge 0..150 degrees about z, pole (0, -1, -1)), the same
//! 256 fixed-seed targets in a ball of radius 0.6 (about a fifth out of reach), cycled,
//! warm-started from the previous solve's pose. PART is `solve` (weight 1, no softening,
//! forward kinematics of the three joints included), `prepared` (the same through a job
//! prepared once, `TwoBoneIk::prepare`), `fk` (forward kinematics of the
//! three joints alone, the part of a solve the closed form cannot avoid) or `none` (the
//! setup only). The difference of two counts divided by SOLVES is the cost of one
//! operation, a figure that does not depend on the load of the machine.

use sinew_ik_two_bone::{Hinge, TwoBoneIk};
use sinew_math::DVec3;
use sinew_skeleton::{GlobalPose, Skeleton};
use std::hint::black_box;

fn targets(n: usize) -> Vec<DVec3> {
    let mut state = 0x2b0e_u64;
    let mut next = move || {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let p = DVec3::new(next(), next(), next());
        if p.length() <= 1.0 {
            out.push(p * 0.6);
        }
    }
    out
}

fn main() {
    let mut args = std::env::args().skip(1);
    let part = args.next().unwrap_or_else(|| "solve".into());
    let solves: usize = args.next().map_or(100_000, |s| s.parse().expect("a count"));
    let skeleton = Skeleton::chain(
        DVec3::ZERO,
        &[DVec3::new(0.30, 0.0, 0.0), DVec3::new(0.25, 0.0, 0.0)],
    )
    .expect("valid limb");
    let targets = targets(256);
    let mut job = TwoBoneIk::new(0, 1, 2, DVec3::ZERO, DVec3::new(0.0, -1.0, -1.0));
    job.hinge = Hinge::new(DVec3::Z, 0.0, 150f64.to_radians());
    let mut pose = skeleton.rest_pose();
    let mut global = GlobalPose::new();
    skeleton
        .forward_kinematics(&pose, &mut global)
        .expect("valid pose");
    let mut reached = 0;
    match part.as_str() {
        "solve" => {
            for i in 0..solves {
                job.target = targets[i % targets.len()];
                let report = job
                    .run(black_box(&skeleton), &mut pose, &mut global)
                    .expect("valid job");
                reached += usize::from(report.reached);
                black_box(report);
            }
        }
        "prepared" => {
            let mut prepared = job.prepare(&skeleton).expect("valid job");
            for i in 0..solves {
                prepared.target = targets[i % targets.len()];
                let report = prepared
                    .run(black_box(&skeleton), &mut pose, &mut global)
                    .expect("valid job");
                reached += usize::from(report.reached);
                black_box(report);
            }
        }
        "fk" => {
            for _ in 0..solves {
                skeleton
                    .forward_kinematics_from(black_box(&pose), 0, &mut global)
                    .expect("valid pose");
                black_box(global.positions[2]);
            }
        }
        "none" => {}
        other => panic!("unknown part {other}: solve, prepared, fk or none"),
    }
    println!("{part}: {solves} runs, {reached} reached");
}
