//! Criterion benchmarks of the FABRIK solver on the reference workloads: W1 (flower
//! tracking, per frame, warm-started), W2 (cold solves from rest, per solve), W3 (out of
//! reach), one bare FABRIK pass, and a 10 000-bone chain tracking the flower (per frame).
//! Each benchmark iteration is one frame or one solve, cycling through the targets, so
//! the time criterion reports is the time per frame or per solve.

#[path = "../tests/common/mod.rs"]
mod common;

use common::{
    W3_TARGET, flower_targets, long_skeleton, w1_skeleton, w2_skeleton, w2_targets, whole,
};
use criterion::{Criterion, criterion_group, criterion_main};
use sinew_ik_fabrik::{FabrikSolver, fabrik_pass};
use sinew_math::DVec3;
use sinew_skeleton::ik::{Chain, IkSolver, SolveSettings};
use sinew_skeleton::{GlobalPose, Skeleton};
use std::hint::black_box;

fn solvers() -> [(&'static str, FabrikSolver); 2] {
    [
        ("plain", FabrikSolver::plain()),
        ("hybrid", FabrikSolver::new()),
    ]
}

/// Benchmarks one frame (warm) or one solve (cold, from rest) per iteration.
fn bench_targets(
    c: &mut Criterion,
    name: &str,
    skel: &Skeleton,
    chain: &Chain,
    targets: &[DVec3],
    cold: bool,
) {
    let settings = SolveSettings::default();
    for (mode, mut solver) in solvers() {
        let rest = skel.rest_pose();
        let mut pose = rest.clone();
        let mut global = GlobalPose::new();
        let mut i = 0;
        c.bench_function(&format!("{name}/{mode}"), |b| {
            b.iter(|| {
                if cold {
                    pose.rotations.copy_from_slice(&rest.rotations);
                }
                let report = solver
                    .solve_position(skel, chain, &mut pose, &mut global, targets[i], &settings)
                    .expect("valid workload");
                i = (i + 1) % targets.len();
                black_box(report)
            })
        });
    }
}

fn bench_workloads(c: &mut Criterion) {
    let w1 = w1_skeleton();
    bench_targets(c, "w1_frame", &w1, &whole(&w1), &flower_targets(500), false);
    let w2 = w2_skeleton();
    let w2_chain = whole(&w2);
    bench_targets(c, "w2_solve", &w2, &w2_chain, &w2_targets(10_000), true);
    bench_targets(c, "w3_solve", &w2, &w2_chain, &[W3_TARGET], true);
}

fn bench_pass(c: &mut Criterion) {
    for (name, bones) in [("w1", 7usize), ("w2", 9), ("long", 10_000)] {
        let length = 1.0 / bones as f64;
        let mut positions: Vec<DVec3> = (0..=bones)
            .map(|i| DVec3::X * (i as f64 * length))
            .collect();
        let lengths = vec![length; bones];
        let targets = [DVec3::new(0.3, 0.4, 0.1), DVec3::new(-0.2, 0.5, 0.3)];
        let mut i = 0;
        c.bench_function(&format!("pass/{name}_{bones}_bones"), |b| {
            b.iter(|| {
                i ^= 1;
                fabrik_pass(&mut positions, &lengths, black_box(targets[i])).expect("valid")
            })
        });
    }
}

fn bench_long(c: &mut Criterion) {
    let skel = long_skeleton(10_000);
    let chain = whole(&skel);
    let targets = flower_targets(500);
    let settings = SolveSettings::default();
    let mut group = c.benchmark_group("long_10000_bones_frame");
    group.sample_size(10);
    for (mode, mut solver) in solvers() {
        let mut pose = skel.rest_pose();
        let mut global = GlobalPose::new();
        let mut i = 0;
        group.bench_function(mode, |b| {
            b.iter(|| {
                let report = solver
                    .solve_position(&skel, &chain, &mut pose, &mut global, targets[i], &settings)
                    .expect("valid workload");
                i = (i + 1) % targets.len();
                black_box(report)
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_workloads, bench_pass, bench_long);
criterion_main!(benches);
