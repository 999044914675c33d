//! Criterion benchmarks of CCD on the shared workloads: W1 (tracking the 500-point lab
//! flower, warm starts), W2 (10 000 cold solves in the ball of radius 0.95), W3 (a
//! target out of reach) and a 10 000-bone chain tracking the flower scaled to its reach.
//! Each W1/W2 iteration runs the whole workload: divide by 500 frames or 10 000 solves.

mod common;

use criterion::{Criterion, criterion_group, criterion_main};
use sinew_ik_ccd::CcdSolver;
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::{Chain, IkSolver, SolveSettings};
use sinew_skeleton::{GlobalPose, Skeleton};
use std::hint::black_box;

fn track_all(
    solver: &mut CcdSolver,
    skel: &Skeleton,
    chain: &Chain,
    targets: &[DVec3],
    settings: &SolveSettings,
    global: &mut GlobalPose,
) -> f64 {
    let mut pose = skel.rest_pose();
    let mut worst: f64 = 0.0;
    for &target in targets {
        let report = solver
            .solve_position(skel, chain, &mut pose, global, black_box(target), settings)
            .expect("solve");
        worst = worst.max(report.error);
    }
    worst
}

fn cold_all(
    solver: &mut CcdSolver,
    skel: &Skeleton,
    chain: &Chain,
    targets: &[DVec3],
    settings: &SolveSettings,
    global: &mut GlobalPose,
) -> f64 {
    let mut pose = skel.rest_pose();
    let mut sum = 0.0;
    for &target in targets {
        pose.rotations.fill(DQuat::IDENTITY);
        let report = solver
            .solve_position(skel, chain, &mut pose, global, black_box(target), settings)
            .expect("solve");
        sum += report.error;
    }
    sum
}

fn bench_ccd(c: &mut Criterion) {
    let settings = SolveSettings::default();
    let mut global = GlobalPose::new();
    let variants = [("default", CcdSolver::new()), ("plain", CcdSolver::plain())];

    let w1 = common::w1_skeleton();
    let w1_chain = Chain::whole(&w1).expect("chain");
    let flower = common::w1_targets();
    let mut group = c.benchmark_group("ccd/w1_500_frames");
    for (name, solver) in &variants {
        let mut solver = solver.clone();
        group.bench_function(*name, |b| {
            b.iter(|| track_all(&mut solver, &w1, &w1_chain, &flower, &settings, &mut global))
        });
    }
    group.finish();

    let w2 = common::w2_skeleton();
    let w2_chain = Chain::whole(&w2).expect("chain");
    let random = common::w2_targets(10_000);
    let mut group = c.benchmark_group("ccd/w2_10000_solves");
    group.sample_size(10);
    for (name, solver) in &variants {
        let mut solver = solver.clone();
        group.bench_function(*name, |b| {
            b.iter(|| cold_all(&mut solver, &w2, &w2_chain, &random, &settings, &mut global))
        });
    }
    group.finish();

    let mut solver = CcdSolver::new();
    c.bench_function("ccd/w3", |b| {
        b.iter(|| {
            let mut pose = w2.rest_pose();
            solver
                .solve_position(
                    &w2,
                    &w2_chain,
                    &mut pose,
                    &mut global,
                    black_box(common::W3_TARGET),
                    &settings,
                )
                .expect("solve")
        })
    });

    let long = common::long_skeleton(10_000, 1.05);
    let long_chain = Chain::whole(&long).expect("chain");
    let scaled = common::scaled_flower(1.05, 12);
    let mut group = c.benchmark_group("ccd/10000_bones_12_frames");
    group.sample_size(10);
    group.bench_function("default", |b| {
        b.iter(|| {
            track_all(
                &mut solver,
                &long,
                &long_chain,
                &scaled,
                &settings,
                &mut global,
            )
        })
    });
    group.finish();
}

criterion_group!(benches, bench_ccd);
criterion_main!(benches);
