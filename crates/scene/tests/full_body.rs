//! The `FullBody` task run from code: its metric keys, the BVH clip's foot locking
//! checked against the file's own joint positions, and located errors for bad clips.

mod common;

use common::metric_keys;
use sinew_scene::results::Pictures;
use sinew_scene::{RunOptions, Scene, TaskMetrics};
use std::path::PathBuf;

/// The shipped scenes directory, so BVH clips resolve against `scenes/data/`.
fn scenes_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes")
}

fn scene(text: &str) -> Result<Scene, String> {
    Scene::from_text(scenes_dir().join("test.ron"), text).map_err(|e| e.to_string())
}

#[test]
fn squat_metrics_have_the_documented_keys_and_hold_the_contract() {
    let scene = scene(
        "Scene(description: \"d\", tasks: [FullBody(name: \"w8\", clip: Squat(frames: 12))])",
    )
    .unwrap();
    let results = scene.run(&RunOptions::default());
    assert!(results.ok(), "{:?}", results.tasks[0].failures);
    let value = serde_json::to_value(&results).unwrap();
    let task = &value["tasks"][0];
    assert_eq!(task["kind"], "FullBody");
    let keys = metric_keys(task);
    assert_eq!(
        keys,
        [
            "effectors",
            "error_max",
            "frames",
            "limit_violation_max",
            "time_per_solve_us_median",
            "within_tol",
        ]
    );
    let TaskMetrics::Body(m) = &results.tasks[0].metrics else {
        panic!("a FullBody task gives Body metrics");
    };
    assert_eq!((m.effectors, m.frames), (5, 12));
    assert!(m.limit_violation_max <= 1e-12);
    assert!(m.error_max.is_finite() && m.time_per_solve_us_median > 0.0);
    // One table row per frame, after the header.
    assert_eq!(results.tasks[0].table.text.lines().count(), 13);
}

#[test]
fn bvh_clip_keeps_the_feet_where_they_stand() {
    let scene = scene(
        "Scene(description: \"d\", tasks: [FullBody(name: \"lock\", clip: Bvh(
            file: \"data/squat.bvh\", follow: [\"LeftHand\", \"Head\", \"Hips\"],
            pinned: [\"LeftFoot\", \"RightFoot\"], frames: 15), settings: (tolerance: 1e-5))])",
    )
    .unwrap();
    let results = scene.run(&RunOptions {
        keep_frames: true,
        ..RunOptions::default()
    });
    assert!(results.ok(), "{:?}", results.tasks[0].failures);
    let Pictures::Body(p) = &results.tasks[0].pictures else {
        panic!("a FullBody task keeps Body pictures");
    };
    assert_eq!(p.effectors.len(), 5);
    assert_eq!(p.pinned, [false, false, false, true, true]);
    // The pinned feet's goals are their first-frame positions on every frame, and the
    // solved feet stay within the tolerance (plus the file's six-decimal rounding) of them.
    let first = &p.track[0];
    for frame in &p.track {
        for k in 3..5 {
            assert_eq!(frame.goals[k], first.goals[k]);
            let foot = frame.joints[p.effectors[k]];
            assert!(foot.distance(first.goals[k]) <= 1e-5, "{foot}");
        }
    }
    let TaskMetrics::Body(m) = &results.tasks[0].metrics else {
        panic!("Body metrics");
    };
    assert_eq!(m.frames, 15);
    assert_eq!(m.within_tol, 15, "every frame of the file is reachable");
}

#[test]
fn bad_clips_are_named() {
    let err = scene(
        "Scene(description: \"d\", tasks: [FullBody(name: \"b\", clip: Bvh(
            file: \"data/missing.bvh\", follow: [\"Head\"]))])",
    )
    .unwrap_err();
    assert!(
        err.contains("task \"b\": clip: file") && err.contains("missing.bvh"),
        "{err}"
    );
    let err = scene(
        "Scene(description: \"d\", tasks: [FullBody(name: \"b\", clip: Bvh(
            file: \"data/squat.bvh\", follow: [\"Head\"], frames: 1000))])",
    )
    .unwrap_err();
    assert!(err.contains("clip: frames = 1000, must be 1..=61"), "{err}");
    let err =
        scene("Scene(description: \"d\", tasks: [FullBody(name: \"b\", clip: Squat(frames: 0))])")
            .unwrap_err();
    assert!(err.contains("task \"b\": clip: frames = 0"), "{err}");
    let err = scene(
        "Scene(description: \"d\", tasks: [FullBody(name: \"b\", clip: Squat(),
            solver: Fabrik(switch_ratio: 2.0))])",
    )
    .unwrap_err();
    assert!(
        err.contains("task \"b\": solver: ") && err.contains("switch_ratio"),
        "{err}"
    );
}
