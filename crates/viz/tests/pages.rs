//! Viewer pages converted from scene results: the frames, goals, charts and metrics a
//! page gets are the run's, and the page is valid and renders.

use sinew_scene::results::Pictures;
use sinew_scene::{RunOptions, Scene};
use sinew_viz::render::viewer_page;
use sinew_viz::viewer::{Budget, PageKind, render_page};

fn run(text: &str) -> sinew_scene::SceneResults {
    let scene = Scene::from_text("pages.ron", text).unwrap_or_else(|e| panic!("{e}"));
    scene.run(&RunOptions {
        keep_frames: true,
        ..RunOptions::default()
    })
}

#[test]
fn an_ik_track_page_has_every_frame_its_goal_and_its_charts() {
    let results = run("Scene(description: \"d\", tasks: [Ik(name: \"track\",
        skeleton: Chain(bones: 3, length: 0.5), solver: Fabrik(),
        target: Points([(1.0, 0.2, 0.0), (0.9, 0.4, 0.1), (0.8, 0.5, 0.2), (3.0, 0.0, 0.0)]))])");
    let task = &results.tasks[0];
    let page = viewer_page(task).expect("an IK track has a page");
    assert_eq!(page.kind, PageKind::IkTrack);
    assert_eq!(page.frames.len(), 4);
    let Pictures::Ik(p) = &task.pictures else {
        panic!("Ik pictures");
    };
    for (frame, target) in page.frames.iter().zip(&p.targets) {
        assert_eq!(frame.goals, vec![*target]);
        assert_eq!(frame.points.len(), 4);
    }
    assert_eq!(page.segments, vec![(0, 1), (1, 2), (2, 3)]);
    assert_eq!(page.effectors, vec![3]);
    // One chart value per page frame: the error and iterations of that frame.
    assert_eq!(page.charts[0].values, p.error);
    assert!(page.charts.iter().all(|c| c.values.len() == 4));
    // The last target is out of reach: the closed form leaves distance - reach.
    assert!((page.charts[0].values[3] - 1.5).abs() < 1e-12);
    assert!(page.metrics.iter().any(|(k, v)| k == "frames" && v == "4"));
    page.validate().unwrap();
    let rendered = render_page(&page, &Budget::default()).unwrap();
    assert_eq!(rendered.shown_frames, 4);
}

#[test]
fn a_cloth_page_has_the_start_every_frame_and_the_energy() {
    let results = run(
        "Scene(description: \"d\", tasks: [Cloth(name: \"c\", system: Grid(),
        integrator: backward_euler(tolerance: 1e-9), dt: 0.05, steps: 5)])",
    );
    let task = &results.tasks[0];
    let page = viewer_page(task).expect("a cloth has a page");
    assert_eq!(page.kind, PageKind::Cloth);
    // The start and the state after each of the 5 steps, at t = step * dt.
    assert_eq!(page.frames.len(), 6);
    for (k, frame) in page.frames.iter().enumerate() {
        assert!((frame.time - 0.05 * k as f64).abs() < 1e-15);
        assert_eq!(frame.points.len(), 121);
    }
    assert_eq!(page.segments.len(), page.rest_lengths.len());
    assert_eq!(page.fixed.len(), 2);
    let Pictures::Cloth(p) = &task.pictures else {
        panic!("Cloth pictures");
    };
    let energy: Vec<f64> = p.energy.iter().map(|e| e.1).collect();
    assert_eq!(page.charts[0].values, energy);
    page.validate().unwrap();
    render_page(&page, &Budget::default()).unwrap();
}

#[test]
fn tasks_without_an_animation_have_no_page() {
    let results = run("Scene(description: \"d\", tasks: [
        Fk(name: \"fk\", skeleton: Chain(bones: 2, length: 1.0)),
        Curve(name: \"flower\", curve: Epicycloid(petals: 5, r: 0.1), sampling: Uniform(n: 50))])");
    assert!(results.tasks.iter().all(|t| viewer_page(t).is_none()));
    let plain = Scene::from_text(
        "p.ron",
        "Scene(description: \"d\", tasks: [Ik(name: \"t\", skeleton: Chain(bones: 2, length: 1.0),
            solver: Ccd(), target: Point(1.0, 1.0, 0.0))])",
    )
    .unwrap()
    .run(&RunOptions::default());
    assert!(
        viewer_page(&plain.tasks[0]).is_none(),
        "no frames kept, no page"
    );
}
