//! Criterion benchmarks of one two-bone solve on a 3-joint limb (shoulder at the origin,
//! upper arm 0.30 and forearm 0.25 along +x, elbow hinge 0..150 degrees about z), forward
//! kinematics of the three joints included. Each iteration is one solve, cycling through
//! 256 fixed-seed targets in a ball of radius 0.6 around the shoulder (about 20% beyond the
//! reach of 0.55), warm-started from the previous solve's pose:
//!
//! - `two_bone/solve`: weight 1, no softening;
//! - `two_bone/solve_soft_blend`: soften 0.9 and weight 0.7 (two slerps more);
//! - `two_bone/prepared`: the `solve` case through a job prepared once
//!   (`TwoBoneIk::prepare`), which checks only the per-call inputs on each run;
//! - `two_bone/fk_only`: forward kinematics of the same three joints alone (what every
//!   solve includes), as the yardstick for the machine the numbers come from.

mod common;

use common::{job, limb, rest, targets};
use criterion::{Criterion, criterion_group, criterion_main};
use sinew_ik_two_bone::TwoBoneIk;
use std::hint::black_box;

fn bench_solve(c: &mut Criterion) {
    let skeleton = limb();
    let targets = targets(256);
    let base = job();
    let soft = TwoBoneIk {
        soften: 0.9,
        weight: 0.7,
        ..base
    };
    for (name, job) in [
        ("two_bone/solve", base),
        ("two_bone/solve_soft_blend", soft),
    ] {
        let (mut pose, mut global) = rest(&skeleton);
        let mut job = job;
        let mut i = 0;
        c.bench_function(name, |b| {
            b.iter(|| {
                job.target = targets[i];
                i = (i + 1) % targets.len();
                let report = job
                    .run(black_box(&skeleton), &mut pose, &mut global)
                    .expect("valid job");
                black_box(report)
            })
        });
    }
}

fn bench_prepared(c: &mut Criterion) {
    let skeleton = limb();
    let targets = targets(256);
    let mut prepared = job().prepare(&skeleton).expect("valid job");
    let (mut pose, mut global) = rest(&skeleton);
    let mut i = 0;
    c.bench_function("two_bone/prepared", |b| {
        b.iter(|| {
            prepared.target = targets[i];
            i = (i + 1) % targets.len();
            let report = prepared
                .run(black_box(&skeleton), &mut pose, &mut global)
                .expect("valid job");
            black_box(report)
        })
    });
}

fn bench_fk_only(c: &mut Criterion) {
    let skeleton = limb();
    let (pose, mut global) = rest(&skeleton);
    c.bench_function("two_bone/fk_only", |b| {
        b.iter(|| {
            skeleton
                .forward_kinematics_from(black_box(&pose), 0, &mut global)
                .expect("valid pose");
            black_box(global.positions[2])
        })
    });
}

criterion_group!(benches, bench_solve, bench_prepared, bench_fk_only);
criterion_main!(benches);
