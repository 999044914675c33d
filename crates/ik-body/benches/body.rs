//! Criterion benchmarks of the full-body solvers on the reference humanoid (22 joints,
//! five effectors, the hips translating): one cold solve from the rest pose per iteration
//! (cycling through 200 feasible goal sets), one warm frame of the 600-frame squat clip per
//! iteration (cycling through the clip), and 1 000 characters each solving one warm frame
//! through the batch API on one and on two threads. `cargo bench -p sinew-ik-body`.

use criterion::{Criterion, criterion_group, criterion_main};
use sinew_ik_body::workload::{self, CLIP_FRAMES};
use sinew_ik_body::{
    BodyBatch, BodyEffector, BodyProblem, BodyReport, BodySolverOptions, BodyState,
    TreeFabrikOptions,
};
use sinew_skeleton::ik::SolveSettings;
use std::hint::black_box;

fn cold(c: &mut Criterion) {
    let skel = workload::humanoid().expect("valid");
    let settings = SolveSettings::default();
    let sets = workload::goal_sets(&skel, 200, 8, false);
    let rest = BodyState::rest(&skel);
    for name in ["dls", "fabrik", "ccd"] {
        let mut solver = BodySolverOptions::by_name(name)
            .and_then(|o| o.build())
            .expect("named");
        let mut state = rest.clone();
        let mut i = 0;
        c.bench_function(&format!("w8-cold/{name}"), |b| {
            b.iter(|| {
                state.copy_pose_from(&rest.pose, rest.root_translation);
                let problem = BodyProblem::new(&skel, &sets[i].effectors, settings)
                    .with_root_translation(true);
                let report = solver.solve(&problem, &mut state).expect("valid");
                i = (i + 1) % sets.len();
                black_box(report)
            });
        });
    }
}

fn warm(c: &mut Criterion) {
    let skel = workload::humanoid().expect("valid");
    let settings = SolveSettings::default();
    let rest = BodyState::rest(&skel);
    let frames: Vec<[BodyEffector; 5]> = (0..CLIP_FRAMES)
        .map(|f| workload::clip_frame(&rest.global, f))
        .collect();
    for name in ["dls", "ccd"] {
        let mut solver = BodySolverOptions::by_name(name)
            .and_then(|o| o.build())
            .expect("named");
        let mut state = rest.clone();
        let mut f = 0;
        c.bench_function(&format!("w8-clip/{name}"), |b| {
            b.iter(|| {
                let problem =
                    BodyProblem::new(&skel, &frames[f], settings).with_root_translation(true);
                let report = solver.solve(&problem, &mut state).expect("valid");
                f = (f + 1) % CLIP_FRAMES;
                black_box(report)
            });
        });
    }
}

fn batch(c: &mut Criterion) {
    let skel = workload::humanoid().expect("valid");
    let settings = SolveSettings::default();
    let rest = BodyState::rest(&skel);
    let frames: Vec<[BodyEffector; 5]> = (0..CLIP_FRAMES)
        .map(|f| workload::clip_frame(&rest.global, f))
        .collect();
    let characters = 1000;
    let empty = BodyReport::UNSOLVED;
    let mut group = c.benchmark_group("w8-batch");
    group.sample_size(10);
    for threads in [1, 2] {
        let mut states = vec![rest.clone(); characters];
        let mut reports = vec![empty; characters];
        let mut batch = BodyBatch::new(TreeFabrikOptions::default()).expect("valid");
        let mut step = 0;
        let label = if threads == 1 { "thread" } else { "threads" };
        group.bench_function(format!("1000-characters/{threads}-{label}"), |b| {
            b.iter(|| {
                let problems = workload::batch_problems(&skel, &frames, settings, characters, step);
                batch
                    .solve(&problems, &mut states, &mut reports, threads)
                    .expect("valid");
                step += 1;
                black_box(&reports);
            });
        });
    }
    group.finish();
}

criterion_group!(benches, cold, warm, batch);
criterion_main!(benches);
