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

#[path = "../benches/common/mod.rs"]
mod common;

use common::{job, limb, rest, targets};
use std::hint::black_box;

fn main() {
    let mut args = std::env::args().skip(1);
    let part = args.next().unwrap_or_else(|| "solve".into());
    let solves: usize = args.next().map_or(100_000, |s| s.parse().expect("a count"));
    let skeleton = limb();
    let targets = targets(256);
    let mut job = job();
    let (mut pose, mut global) = rest(&skeleton);
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
