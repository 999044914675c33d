//! W7 (the human arm with joint limits) cold solves from the rest pose, both solvers of
//! the registry, cap 100 and tolerance 1e-6: time per solve over a fixed cycle of
//! feasible targets (forward kinematics of the hand tip for poses uniform in the limits).

use criterion::{Criterion, criterion_group, criterion_main};
use sinew_ik::SolverOptions;
use sinew_ik::workloads::{allowed_pose, human_arm};
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::GlobalPose;
use sinew_skeleton::ik::{Chain, SolveSettings};
use std::hint::black_box;

/// splitmix64 with the workloads' W7 seed.
struct SplitMix64(u64);

impl SplitMix64 {
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn bench_w7(c: &mut Criterion) {
    let skeleton = human_arm().expect("the W7 arm");
    let chain = Chain::whole(&skeleton).expect("a chain");
    let mut rng = SplitMix64(0x5EED_0000_0000_0007);
    let mut global = GlobalPose::new();
    let targets: Vec<DVec3> = (0..1000)
        .map(|_| {
            let pose = allowed_pose(&skeleton, || rng.unit());
            skeleton
                .forward_kinematics(&pose, &mut global)
                .expect("valid");
            global.positions[4]
        })
        .collect();
    let settings = SolveSettings::default();
    let mut group = c.benchmark_group("w7_cold");
    for (name, options) in SolverOptions::NAMED {
        if name.ends_with("-plain") {
            continue;
        }
        let mut solver = options.build().expect("valid");
        let mut pose = skeleton.rest_pose();
        let mut i = 0;
        group.bench_function(name, |b| {
            b.iter(|| {
                pose.rotations.fill(DQuat::IDENTITY);
                let report = solver
                    .solve_position(
                        &skeleton,
                        &chain,
                        &mut pose,
                        &mut global,
                        targets[i],
                        &settings,
                    )
                    .expect("valid workload");
                i = (i + 1) % targets.len();
                black_box(report)
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_w7);
criterion_main!(benches);
