//! Criterion benchmarks of forward kinematics: the W1 chain (8 joints) and a 10 000-bone
//! chain, full FK and FK from the middle joint.

use criterion::{Criterion, criterion_group, criterion_main};
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::{GlobalPose, Skeleton};
use std::hint::black_box;

fn bench_fk(c: &mut Criterion) {
    for bones in [7usize, 10_000] {
        let skel = Skeleton::chain(
            DVec3::new(0.0, 0.5, 0.0),
            &vec![DVec3::new(0.15, 0.0, 0.0); bones],
        )
        .expect("valid chain");
        let mut pose = skel.rest_pose();
        for (i, r) in pose.rotations.iter_mut().enumerate() {
            *r = DQuat::from_rotation_z(0.01 * i as f64);
        }
        let mut global = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut global)
            .expect("valid pose");
        c.bench_function(&format!("fk/full/{bones}_bones"), |b| {
            b.iter(|| {
                skel.forward_kinematics(black_box(&pose), &mut global)
                    .expect("valid pose")
            })
        });
        let middle = skel.len() / 2;
        c.bench_function(&format!("fk/from_middle/{bones}_bones"), |b| {
            b.iter(|| {
                skel.forward_kinematics_from(black_box(&pose), middle, &mut global)
                    .expect("valid pose")
            })
        });
    }
}

criterion_group!(benches, bench_fk);
criterion_main!(benches);
