//! A warm solve allocates nothing: after the first frames of a character (its solver's
//! buffers sized for the problem's structure), no later frame of the batch allocates,
//! restarts and joints reaching curved bounds included. The counting allocator is this
//! test binary's own (`allocation-counter`), so no other test pays for it.

use sinew_ik_body::workload::{self, CLIP_FRAMES};
use sinew_ik_body::{BodyBatch, BodyEffector, BodyReport, BodyState, TreeFabrikOptions};
use sinew_skeleton::ik::SolveSettings;

/// Frames solved before counting: the first solves from rest, the first extrapolated start
/// and the first corrected one size the buffers.
const WARM_UP: usize = 3;

#[test]
fn warm_batch_frames_allocate_nothing_after_the_first() {
    // Sized for a debug test run; `SINEW_ALLOC_CHARACTERS` and `SINEW_ALLOC_FRAMES` widen
    // it (release) to look for rarer paths.
    let size = |name: &str, default: usize| {
        std::env::var(name)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let characters = size("SINEW_ALLOC_CHARACTERS", 60);
    let frames_run = size("SINEW_ALLOC_FRAMES", 200);
    let skeleton = workload::humanoid().expect("valid");
    let settings = SolveSettings::default();
    let rest = BodyState::rest(&skeleton);
    let frames: Vec<[BodyEffector; 5]> = (0..CLIP_FRAMES)
        .map(|f| workload::clip_frame(&rest.global, f))
        .collect();
    let mut states = vec![rest.clone(); characters];
    let mut reports = vec![BodyReport::UNSOLVED; characters];
    let mut batch = BodyBatch::new(TreeFabrikOptions::default()).expect("valid");
    let mut allocating = Vec::new();
    let mut restarts = 0;
    for step in 0..frames_run {
        let problems = workload::batch_problems(&skeleton, &frames, settings, characters, step);
        let info = allocation_counter::measure(|| {
            batch
                .solve(&problems, &mut states, &mut reports, 1)
                .expect("valid problems");
        });
        restarts += reports.iter().filter(|r| r.restarted).count();
        if step >= WARM_UP && info.count_total > 0 {
            allocating.push((step, info.count_total));
        }
    }
    assert!(
        allocating.is_empty(),
        "frames (step, allocations) that allocated after the warm-up: {allocating:?}"
    );
    // The frames counted took the rarer paths too (a restart keeps the best pose aside).
    assert!(restarts > 0, "no restart in {frames_run} frames");
}
