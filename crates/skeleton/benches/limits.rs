//! Criterion benchmarks of the joint limits: `project` and `violation` on 1024 uniform
//! random rotations (most of them outside the limit) for the human arm's limits (elbow
//! hinge 0..150 degrees, shoulder swing 100/70 degrees with twist +-80) and a thin tilted
//! ellipse (semi-axes pi and 0.05), where the ellipse's nearest point needs the most
//! bisection steps.

#[path = "../tests/common/mod.rs"]
mod common;

use criterion::{Criterion, criterion_group, criterion_main};
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::limits::JointLimit;
use std::hint::black_box;

/// 1024 uniform random rotations from a fixed seed (splitmix64 into `JointLimit::Free`'s
/// uniform sampler).
fn rotations() -> Vec<DQuat> {
    let mut state = 0x5EED_u64;
    let mut next = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..1024)
        .map(|_| JointLimit::Free.sample([next(), next(), next()]))
        .collect()
}

fn bench_limits(c: &mut Criterion) {
    let tilted = DVec3::new(1.0, 2.0, 3.0);
    let limits = [
        (
            "elbow_hinge",
            JointLimit::hinge(-DVec3::Y, 0.0, 150f64.to_radians()).expect("valid hinge"),
        ),
        ("shoulder", common::shoulder()),
        (
            "thin_ellipse",
            JointLimit::swing_twist(
                tilted,
                tilted.cross(DVec3::Z),
                std::f64::consts::PI,
                0.05,
                1.0,
                2.5,
            )
            .expect("valid swing-twist"),
        ),
    ];
    let qs = rotations();
    for (name, limit) in limits {
        c.bench_function(&format!("limits/project/{name}/1024"), |b| {
            b.iter(|| {
                let mut sum = DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0);
                for &q in &qs {
                    sum += limit.project(black_box(q));
                }
                sum
            })
        });
        c.bench_function(&format!("limits/violation/{name}/1024"), |b| {
            b.iter(|| {
                qs.iter()
                    .map(|&q| limit.violation(black_box(q)))
                    .sum::<f64>()
            })
        });
    }
}

criterion_group!(benches, bench_limits);
criterion_main!(benches);
