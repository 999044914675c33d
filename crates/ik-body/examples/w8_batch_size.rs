//! W8's warm batch frame, per character, against the batch's size: how much of a batch's
//! time is its characters' state coming from memory (see `docs/ik-body.md`, "The warm
//! batch waits for memory").
//!
//! ```sh
//! cargo run --release -p sinew-ik-body --example w8_batch_size -- 200 400 1000 1500
//! ```
//!
//! For each size, a batch of that many characters (each at its own frame of the squat, as
//! in the `w8` example) solves 32 warm frames on one thread; the median per character of
//! the last 30 is printed. From about 100 characters on, every size has the same mix of
//! frames, so the work per character is the same; what grows is the memory the batch
//! walks through.

use sinew_ik_body::workload::{self, CLIP_FRAMES};
use sinew_ik_body::{BodyBatch, BodyReport, BodyState, TreeFabrikOptions};
use sinew_skeleton::ik::SolveSettings;
use std::time::Instant;

fn main() {
    let sizes: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse().expect("batch sizes are whole numbers"))
        .collect();
    let sizes = if sizes.is_empty() {
        vec![200, 400, 1000, 1500]
    } else {
        sizes
    };
    let skeleton = workload::humanoid().expect("the humanoid is valid");
    let settings = SolveSettings::default();
    let rest = BodyState::rest(&skeleton);
    let frames: Vec<_> = (0..CLIP_FRAMES)
        .map(|f| workload::clip_frame(&rest.global, f))
        .collect();
    for characters in sizes.into_iter().filter(|&n| n > 0) {
        let mut states = vec![rest.clone(); characters];
        let mut reports = vec![BodyReport::UNSOLVED; characters];
        let mut batch = BodyBatch::new(TreeFabrikOptions::default()).expect("default options");
        let mut times = Vec::new();
        let mut within = 0;
        for step in 0..32 {
            let problems = workload::batch_problems(&skeleton, &frames, settings, characters, step);
            let start = Instant::now();
            batch
                .solve(&problems, &mut states, &mut reports, 1)
                .expect("valid workload");
            let per_character = start.elapsed().as_secs_f64() * 1e6 / characters as f64;
            // The first two frames warm the buffers and bring every character onto its clip.
            if step >= 2 {
                times.push(per_character);
                within += reports.iter().filter(|r| r.within(&settings)).count();
            }
        }
        times.sort_by(f64::total_cmp);
        println!(
            "{characters} characters: median {:.2} us per character a warm frame (fastest {:.2}); {within} of {} solves within 1e-6",
            times[times.len() / 2],
            times[0],
            times.len() * characters
        );
    }
}
