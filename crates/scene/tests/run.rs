//! Scenes run from code: typed results against closed forms, the JSON shape of
//! `metrics.json`, and what the pictures are handed.

mod common;

use common::metric_keys;
use sinew_math::DVec3;
use sinew_scene::results::Pictures;
use sinew_scene::{RunOptions, Scene, SceneError, TaskMetrics, TaskResult};

fn scene(text: &str) -> Scene {
    Scene::from_text("test.ron", text).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn fk_result_is_the_closed_form() {
    // A quarter turn of the root about +y swings a 3-bone chain of 0.5 from +x to -z.
    let scene = scene(
        "Scene(description: \"d\", tasks: [Fk(name: \"quarter\",
            skeleton: Chain(bones: 3, length: 0.5),
            pose: [(joint: 0, axis: (0.0, 1.0, 0.0), degrees: 90.0)])])",
    );
    let results = scene.run(&RunOptions::default());
    assert_eq!(results.scene, "test");
    assert!(results.ok());
    let TaskMetrics::Fk(fk) = &results.tasks[0].metrics else {
        panic!("an Fk task gives Fk metrics");
    };
    assert_eq!(fk.joints, 4);
    let expected = [0.0, 0.0, -1.5];
    for (got, want) in fk.effector.iter().zip(expected) {
        assert!((got - want).abs() < 1e-15, "{:?}", fk.effector);
    }
    assert_eq!(fk.fk_from_diff_max, 0.0);
    assert_eq!(results.tasks[0].table.suffix, "positions.csv");
    assert_eq!(results.tasks[0].table.text.lines().count(), 5);
}

#[test]
fn metrics_serialize_with_the_documented_keys() {
    let scene = scene(
        "Scene(description: \"d\", tasks: [Ik(name: \"far\",
            skeleton: Chain(bones: 9, length: 0.1), solver: Fabrik(),
            target: Point(3.0, 1.0, 0.0))])",
    );
    let value = serde_json::to_value(scene.run(&RunOptions::default())).unwrap();
    let task = &value["tasks"][0];
    assert_eq!(task["kind"], "Ik");
    assert_eq!(task["ok"], true);
    assert!(task.get("error").is_none());
    let keys = metric_keys(task);
    assert_eq!(
        keys,
        [
            "bone_length_error_max",
            "clamped_frames",
            "closed_form_gap",
            "converged_frames",
            "error_max",
            "error_mean",
            "final_bend_max_rad",
            "frames",
            "iterations_total",
            "limit_violation_max",
            "local_minimum_frames",
            "out_of_reach_frames",
            "rotation_error_max",
            "rotation_jump_max_rad",
            "solver",
            "time_per_frame_ns_median",
            "within_tol",
        ]
    );
    // Out of reach: the straight chain aimed at the target, error = distance - reach.
    let error = task["metrics"]["error_max"].as_f64().unwrap();
    assert!((error - (10f64.sqrt() - 0.9)).abs() < 1e-12, "{error}");
}

#[test]
fn a_task_that_could_not_run_has_empty_metrics_and_its_error() {
    let failed = TaskResult::failed("t", "Cloth", 0.5, "integrator: no".into());
    let value = serde_json::to_value(&failed).unwrap();
    assert_eq!(value["metrics"], serde_json::json!({}));
    assert_eq!(value["error"], "integrator: no");
    assert_eq!(value["ok"], false);
}

#[test]
fn frames_are_kept_only_when_asked() {
    let scene = scene(
        "Scene(description: \"d\", tasks: [Ik(name: \"pts\",
            skeleton: Chain(bones: 3, length: 0.5), solver: Ccd(),
            target: Points([(1.0, 0.2, 0.0), (0.9, 0.4, 0.1), (0.8, 0.5, 0.2)]))])",
    );
    let plain = scene.run(&RunOptions::default());
    assert!(matches!(plain.tasks[0].pictures, Pictures::None));
    let kept = scene.run(&RunOptions {
        keep_frames: true,
        ..RunOptions::default()
    });
    let Pictures::Ik(p) = &kept.tasks[0].pictures else {
        panic!("an Ik task keeps Ik pictures");
    };
    assert_eq!(p.frames.len(), 3);
    assert_eq!(p.targets.len(), 3);
    assert_eq!(p.frames[2].target, p.targets[2]);
    assert_eq!(p.frames[2].joints.len(), 4);
    // Keeping frames changes no metric but the timings.
    let (TaskMetrics::Ik(a), TaskMetrics::Ik(b)) =
        (&plain.tasks[0].metrics, &kept.tasks[0].metrics)
    else {
        panic!("Ik metrics");
    };
    assert_eq!(
        (a.error_max, a.iterations_total),
        (b.error_max, b.iterations_total)
    );
}

#[test]
fn progress_is_told_every_frame() {
    let scene = scene(
        "Scene(description: \"d\", tasks: [Ik(name: \"pts\",
            skeleton: Chain(bones: 3, length: 0.5), solver: Fabrik(),
            target: Points([(1.0, 0.2, 0.0), (0.9, 0.4, 0.1)]))])",
    );
    let seen = std::cell::RefCell::new(Vec::new());
    let record = |task: &str, done: usize, total: usize| {
        seen.borrow_mut().push((task.to_string(), done, total));
    };
    let results = scene.run(&RunOptions {
        progress: Some(&record),
        ..RunOptions::default()
    });
    assert!(results.ok());
    assert_eq!(
        seen.into_inner(),
        [("pts".to_string(), 1, 2), ("pts".to_string(), 2, 2)]
    );
}

/// A limb whose bone is 1.8e308 long: its rest pose's forward kinematics is finite, but
/// any pose that turns the bone overflows. The scene is refused at validation, naming the
/// joint (it used to validate, and a frame's forward kinematics then had no finite
/// position).
#[test]
fn a_two_bone_limb_too_long_to_turn_is_refused_at_validation() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/ik-two-bone.ron");
    let text = std::fs::read_to_string(&path).unwrap();
    let huge = text.replacen(
        "(name: \"knee\", parent: 1, offset: (0.0,",
        "(name: \"knee\", parent: 1, offset: (1.7976931348623157e308,",
        1,
    );
    assert_ne!(huge, text, "the knee's offset is in the scene");
    match Scene::from_text(&path, &huge) {
        Err(SceneError::Invalid { message, .. }) => {
            assert!(message.contains("\"knee\""), "{message}");
            assert!(
                message.contains("forward kinematics could overflow"),
                "{message}"
            );
        }
        Err(other) => panic!("refused for another reason: {other}"),
        Ok(_) => panic!("a skeleton beyond MAX_REACH was accepted"),
    }
}

/// The committed incline scene: the top sheet held by friction with the pinned sheet
/// below it (mu 0.8 > tan 30 deg) stays within a few millimetres of where it started, and
/// slides a quarter of a metre down the slope with mu 0.2 (Coulomb's `g (sin - mu cos)`
/// over 0.4 s is 0.26 m; without friction it would be 0.39 m); both with friction pairs
/// and no intersection.
#[test]
fn friction_between_sheets_holds_or_lets_slide_as_mu_says() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes/cloth-sheet-incline.ron");
    let text = std::fs::read_to_string(&path).unwrap();
    let scene = Scene::from_text(&path, &text).unwrap_or_else(|e| panic!("{e}"));
    let results = scene.run(&RunOptions::default());
    let travel: Vec<(String, f64)> = results
        .tasks
        .iter()
        .map(|t| {
            assert!(t.ok, "{}: {:?}", t.name, t.error);
            let TaskMetrics::MeshCloth(m) = &t.metrics else {
                panic!("{}: {:?}", t.name, t.metrics);
            };
            assert!(m.self_friction_pairs_max > 0, "{}", t.name);
            assert_eq!(m.intersections, 0, "{}", t.name);
            (t.name.clone(), m.free_mean_displacement)
        })
        .collect();
    assert_eq!(travel[0].0, "holds");
    assert!(travel[0].1 < 2e-3, "{travel:?}");
    assert_eq!(travel[1].0, "slides");
    assert!(travel[1].1 > 0.2 && travel[1].1 < 0.3, "{travel:?}");
}

/// The incline scene in the two second-order schemes (`integrator: bdf2` and
/// `implicit_midpoint`): self-contact and its friction act on the end-of-step state in
/// each, so the held sheet stays within a few millimetres (it slips while it settles
/// onto the barrier, which these schemes damp less than backward Euler: 2.2 mm for BDF2,
/// 7.3 mm when its first step was an undamped midpoint step, 3.8 mm for the midpoint,
/// 1.2 mm for backward Euler), the sliding one travels about
/// Coulomb's quarter metre (0.23 m in both; 0.26 m over 0.4 s from rest, 0.39 m without
/// friction), and no triangles meet.
#[test]
fn the_incline_holds_or_slides_in_bdf2_and_the_midpoint() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes/cloth-sheet-incline.ron");
    let text = std::fs::read_to_string(&path).unwrap();
    for scheme in ["bdf2", "implicit_midpoint"] {
        let edited = text.replace(
            "MeshCloth(\n            name:",
            &format!("MeshCloth(\n            integrator: {scheme},\n            name:"),
        );
        assert_eq!(edited.matches("integrator:").count(), 2, "{scheme}");
        let scene = Scene::from_text(&path, &edited).unwrap_or_else(|e| panic!("{e}"));
        let results = scene.run(&RunOptions::default());
        let travel: Vec<f64> = results
            .tasks
            .iter()
            .map(|t| {
                assert!(t.ok, "{scheme} {}: {:?}", t.name, t.error);
                let TaskMetrics::MeshCloth(m) = &t.metrics else {
                    panic!("{}: {:?}", t.name, t.metrics);
                };
                assert!(m.self_friction_pairs_max > 0, "{scheme} {}", t.name);
                assert_eq!(m.intersections, 0, "{scheme} {}", t.name);
                m.free_mean_displacement
            })
            .collect();
        let held = if scheme == "bdf2" { 5e-3 } else { 1e-2 };
        assert!(travel[0] < held, "{scheme}: {travel:?}");
        assert!(travel[1] > 0.2 && travel[1] < 0.3, "{scheme}: {travel:?}");
    }
}

/// A mesh cloth task's `friction_lags` reaches Newton's settings: the committed incline
/// scene validates with three lags a step, and a task with none is refused at validation,
/// naming the setting.
#[test]
fn a_mesh_cloths_friction_lags_are_checked() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes/cloth-sheet-incline.ron");
    let text = std::fs::read_to_string(&path).unwrap();
    let with = |lags: usize| {
        let edited = text.replacen(
            "self_contact: (dhat: 2e-3, thickness: 1e-3, mu: 0.2),",
            &format!(
                "self_contact: (dhat: 2e-3, thickness: 1e-3, mu: 0.2), friction_lags: {lags},"
            ),
            1,
        );
        assert_ne!(edited, text, "the sliding task is in the scene");
        Scene::from_text(&path, &edited)
    };
    with(3).unwrap_or_else(|e| panic!("{e}"));
    match with(0) {
        Err(SceneError::Invalid { message, .. }) => {
            assert!(message.contains("friction_lags"), "{message}");
        }
        Err(e) => panic!("refused for another reason: {e}"),
        Ok(_) => panic!("a task lagging friction no time a step was accepted"),
    }
}

/// A sheet dropped across a forearm that swings up about the elbow (a shoulder-elbow-
/// wrist skeleton, one key pose to another), in a `Cloth` and a `MeshCloth` task: the
/// runner drives the limbs' capsules before every step and counts penetrations against
/// the animation's own capsules. None, while the sheet rests on the rising forearm
/// (within `dhat` of it), and the mesh sheet is carried up. (With the drives kept from
/// the integrator the capsule rises into the sheet: penetrations.)
/// A scene of two tasks, a `Cloth` and a `MeshCloth` 9 x 9 sheet (spacing 2 cm) 2 mm
/// above a forearm of radius 4 cm along +x at the origin, on the `limbs` given, for
/// `steps` steps of 1/60 s.
fn sheets_on_limbs(limbs: &str, steps: usize) -> String {
    format!(
        "Scene(description: \"limbs\", tasks: [
            Cloth(
                name: \"grid\",
                system: Grid(size: 9, spacing: 0.02, origin: (-0.08, 0.042, -0.08), mass: 8e-5,
                    material: (stiffness: 1000.0, damping: 0.1, gravity: (0.0, -9.81, 0.0)), fixed: []),
                integrator: backward_euler(),
                dt: 0.016666666666666666,
                steps: {steps},
                contact: (colliders: [], {limbs}, settings: (dhat: 1e-3, mu: 0.5)),
            ),
            MeshCloth(
                name: \"mesh\",
                sheets: [Grid(size: 9, spacing: 0.02, origin: (-0.08, 0.042, -0.08))],
                material: (stiffness: 1000.0, damping: 0.1, gravity: (0.0, -9.81, 0.0)),
                dt: 0.016666666666666666,
                steps: {steps},
                self_contact: (dhat: 1e-3, thickness: 5e-4),
                {limbs},
                contact: (dhat: 1e-3, mu: 0.5),
            ),
        ])"
    )
}

#[test]
fn a_sheet_on_an_animated_forearm_is_carried_without_a_penetration() {
    let limbs = "limbs: (
        skeleton: Joints([
            (name: \"shoulder\", offset: (-0.5, 0.0, 0.0)),
            (name: \"elbow\", parent: 0, offset: (0.3, 0.0, 0.0)),
            (name: \"wrist\", parent: 1, offset: (0.3, 0.0, 0.0)),
        ]),
        keys: [(time: 0.2), (time: 0.5, pose: [(joint: 1, axis: (0.0, 0.0, 1.0), degrees: 20.0)])],
        capsules: [(from: 0, to: 1, radius: 0.04), (from: 1, to: 2, radius: 0.04)],
    )";
    let text = sheets_on_limbs(limbs, 30);
    let results = scene(&text).run(&RunOptions::default());
    for t in &results.tasks {
        assert!(t.ok, "{}: {:?}", t.name, t.error);
        let (penetrations, min_distance, path) = match &t.metrics {
            TaskMetrics::Cloth(m) => {
                let c = m.contact.as_ref().expect("contact metrics");
                (c.penetrations, c.min_distance, c.max_path_depth)
            }
            TaskMetrics::MeshCloth(m) => {
                assert_eq!(m.intersections, 0, "{}", t.name);
                // Carried: the forearm's middle under the sheet rose about 7 cm.
                assert!(m.free_mean_displacement > 0.03, "{m:?}");
                (m.penetrations, m.min_distance, m.max_path_depth)
            }
            other => panic!("{}: {other:?}", t.name),
        };
        assert_eq!(penetrations, 0, "{}", t.name);
        // The forearm holds still until 0.2 s while the sheet drapes around it, then
        // turns: every step's path starts where the step before ended, and stays within
        // the allowance `min(dhat, r/2)` = 1 mm of the capsules.
        let path = path.expect("the forearm moves");
        assert!(path <= 1e-3, "{}: max_path_depth {path:e}", t.name);
        let d = min_distance.expect("the sheet reached the forearm");
        assert!(d > 0.0 && d < 1e-3, "{}: min_distance {d:e}", t.name);
    }
}

#[test]
fn a_sheet_on_an_arm_posed_by_inverse_kinematics_is_carried_without_a_penetration() {
    // The arm's rest pose bends the elbow 10 degrees in the horizontal plane; FABRIK
    // then puts the wrist on a target that rises 8 cm (and comes 3 cm closer) between 0.1 s
    // and 0.5 s, from where the wrist rests.
    let wrist = (
        -0.2 + 0.3 * 10f64.to_radians().cos(),
        -0.3 * 10f64.to_radians().sin(),
    );
    let limbs = format!(
        "limbs: (
        skeleton: Joints([
            (name: \"shoulder\", offset: (-0.5, 0.0, 0.0)),
            (name: \"elbow\", parent: 0, offset: (0.3, 0.0, 0.0)),
            (name: \"wrist\", parent: 1, offset: (0.3, 0.0, 0.0)),
        ]),
        keys: [(time: 0.0, pose: [(joint: 1, axis: (0.0, 1.0, 0.0), degrees: 10.0)])],
        capsules: [(from: 0, to: 1, radius: 0.04), (from: 1, to: 2, radius: 0.04)],
        reach: (chain: (base: 0, effector: 2), solver: Fabrik(), settings: (max_iterations: 100, tolerance: 1e-9),
            targets: [(time: 0.1, position: ({x:?}, 0.0, {z:?})), (time: 0.5, position: ({x2:?}, 0.08, {z:?}))]),
    )",
        x = wrist.0,
        x2 = wrist.0 - 0.03,
        z = wrist.1
    );
    let text = sheets_on_limbs(&limbs, 36);
    // The same arm without the reach: the rest pose throughout.
    let reach_at = text.find("        reach: (").unwrap();
    let reach_end = reach_at + text[reach_at..].find("]),\n").unwrap() + 4;
    let still = scene(&text.replace(&text[reach_at..reach_end], "")).run(&RunOptions::default());
    let results = scene(&text).run(&RunOptions::default());
    // A sheet of 81 particles of 8e-5 kg under 9.81 m/s^2: its gravity energy per metre
    // of mean height.
    let weight = 81.0 * 8e-5 * 9.81;
    for (t, s) in results.tasks.iter().zip(&still.tasks) {
        assert!(t.ok && s.ok, "{}: {:?} {:?}", t.name, t.error, s.error);
        // Carried: with the reach the sheet ends higher on average than on the still arm
        // by more than 5 mm (1.2 cm and 1.3 cm measured; the forearm's middle rises
        // about 4 cm and the sheet's edges hang).
        let (penetrations, min_distance, reach_error_max) = match (&t.metrics, &s.metrics) {
            (TaskMetrics::Cloth(m), TaskMetrics::Cloth(still)) => {
                let rise = (m.run.energy_end - still.run.energy_end) / weight;
                assert!(rise > 5e-3, "{}: {rise}", t.name);
                let c = m.contact.as_ref().expect("contact metrics");
                (c.penetrations, c.min_distance, c.reach_error_max)
            }
            (TaskMetrics::MeshCloth(m), TaskMetrics::MeshCloth(still)) => {
                assert_eq!(m.intersections, 0, "{}", t.name);
                assert!(still.reach_error_max.is_none());
                let more = m.free_mean_displacement - still.free_mean_displacement;
                assert!(more > 5e-3, "{}: {more}", t.name);
                (m.penetrations, m.min_distance, m.reach_error_max)
            }
            other => panic!("{}: {other:?}", t.name),
        };
        assert_eq!(penetrations, 0, "{}", t.name);
        let d = min_distance.expect("the sheet reached the forearm");
        assert!(d > 0.0 && d < 1e-3, "{}: min_distance {d:e}", t.name);
        let e = reach_error_max.expect("a reach reports its error");
        assert!(e <= 1e-9, "{}: reach_error_max {e:e}", t.name);
    }
}

#[test]
fn a_shawl_on_a_squatting_clip_goes_down_and_up_with_the_body() {
    // A 13 x 13 sheet (0.48 m) dropped on the shoulders and neck of scenes/data/squat.bvh,
    // which squats from 0.2 s (the hips 0.3 m lower at 1.2 s) and stands again by 2.2 s.
    let run = |steps: usize| {
        let text = format!(
            "Scene(description: \"shawl\", tasks: [Cloth(
                name: \"shawl\",
                system: Grid(size: 13, spacing: 0.04, origin: (-0.24, 1.54, -0.24), mass: 3e-4,
                    material: (stiffness: 1000.0, damping: 0.1, gravity: (0.0, -9.81, 0.0)), fixed: []),
                integrator: backward_euler(),
                dt: 0.03333333333333333,
                steps: {steps},
                contact: (colliders: [], limbs: (
                    clip: (file: \"data/squat.bvh\", start: 0.2),
                    capsules: [
                        (from: \"Chest\", to: \"Neck\", radius: 0.08),
                        (from: \"LeftShoulder\", to: \"LeftArm\", radius: 0.06),
                        (from: \"RightShoulder\", to: \"RightArm\", radius: 0.06),
                    ],
                ), settings: (dhat: 1e-3, mu: 0.5)),
            )])"
        );
        // Named as a file in scenes/, so the clip is read from scenes/data.
        let scene = Scene::from_text(
            concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/shawl.ron"),
            &text,
        )
        .unwrap();
        let results = scene.run(&RunOptions::default());
        let t = &results.tasks[0];
        assert!(t.ok, "{:?}", t.error);
        match &t.metrics {
            TaskMetrics::Cloth(m) => {
                let c = m.contact.as_ref().unwrap();
                assert_eq!(c.penetrations, 0);
                let d = c.min_distance.expect("the sheet reached the body");
                assert!(d > 0.0 && d < 1e-3, "min_distance {d:e}");
                m.run.energy_end
            }
            other => panic!("{other:?}"),
        }
    };
    // Gravity energy per metre of the sheet's mean height.
    let weight = 169.0 * 3e-4 * 9.81;
    let (start, bottom, end) = (run(6), run(36), run(66));
    // The shoulders go down 0.33 m and up again; the sheet's mean height follows them
    // (measured: 0.38 m down from 0.2 s to 1.2 s, 0.34 m up by 2.2 s). A sheet the body
    // did not carry could not rise.
    let (down, up) = ((start - bottom) / weight, (end - bottom) / weight);
    assert!(down > 0.25 && up > 0.25, "down {down}, up {up}");
}

/// A 7 x 7 cape (0.24 m) whose row `j = 6` the chest of scenes/data/squat.bvh holds, 2 cm
/// behind the torso's capsule, the rest of it reaching back horizontally (with
/// `CAPE_GRID` and `CAPE_ROW`); the integrator, the system and the attachments as given.
fn cape_scene(integrator: &str, system: &str, attach: &str) -> String {
    let limbs = cape_limbs(attach);
    format!(
        "Scene(description: \"cape\", tasks: [Cloth(
            name: \"cape\",
            system: {system},
            integrator: {integrator},
            dt: 0.03333333333333333,
            steps: 24,
            contact: (colliders: [], {limbs}, settings: (dhat: 1e-3, mu: 0.3)),
        )])"
    )
}

/// The squatting clip's torso as capsules, holding the cape by `attach`.
fn cape_limbs(attach: &str) -> String {
    format!(
        "limbs: (
            clip: (file: \"data/squat.bvh\", start: 0.2),
            capsules: [
                (from: \"Spine\", to: \"Chest\", radius: 0.12),
                (from: \"Chest\", to: \"Neck\", radius: 0.13),
                (from: \"Hips\", to: \"Spine\", radius: 0.12),
            ],
            attach: {attach},
        )"
    )
}

const CAPE_GRID: &str = "Grid(size: 7, spacing: 0.04, origin: (-0.12, 1.42, -0.39), mass: 3e-4,
    material: (stiffness: 1000.0, damping: 0.1, gravity: (0.0, -9.81, 0.0)), fixed: [])";
const CAPE_ROW: &str =
    "[(joint: \"Chest\", particles: [(0, 6), (1, 6), (2, 6), (3, 6), (4, 6), (5, 6), (6, 6)])]";

/// Loads scene text as a file in scenes/ (so a clip is read from scenes/data).
fn scene_in_scenes(text: &str) -> Result<Scene, SceneError> {
    Scene::from_text(
        concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/test.ron"),
        text,
    )
}

/// The cape of `cape_scene` as a `MeshCloth` task (self-contact on) with the
/// attachments and more task fields (`extra`) as given.
fn mesh_cape_scene(attach: &str, extra: &str) -> String {
    mesh_cape_sheet(CAPE_MESH_GRID, attach, extra)
}

/// The 7 x 7 grid of the mesh cape.
const CAPE_MESH_GRID: &str = "Grid(size: 7, spacing: 0.04, origin: (-0.12, 1.42, -0.39))";

/// A mesh cape of the sheet given, as `mesh_cape_scene`.
fn mesh_cape_sheet(sheet: &str, attach: &str, extra: &str) -> String {
    let limbs = cape_limbs(attach);
    format!(
        "Scene(description: \"cape\", tasks: [MeshCloth(
            name: \"mesh-cape\",
            sheets: [{sheet}],
            material: (stiffness: 1000.0, damping: 0.1, gravity: (0.0, -9.81, 0.0)),
            dt: 0.03333333333333333,
            steps: 24,
            self_contact: (dhat: 1e-3, thickness: 5e-4),
            {limbs},
            contact: (dhat: 1e-3, mu: 0.3),
            {extra}
        )])"
    )
}

#[test]
fn a_cape_held_by_a_squatting_clip_goes_where_the_chest_takes_it() {
    let grid_row: Vec<usize> = (0..7).map(|i| i * 7 + 6).collect();
    // scenes/data/sheet.obj, scaled to 0.24 m and placed as the grid: the vertices
    // within 5 cm of its back edge's middle held, chosen by position (by number:
    // `an_obj_sheets_pins_and_held_vertices_are_the_files`).
    let (centre, radius) = (DVec3::new(0.0, 1.42, -0.15), 0.05);
    let obj = mesh_cape_sheet(
        "Obj(path: \"data/sheet.obj\", scale: 0.24, offset: (-0.12, 1.42, -0.39))",
        "[(joint: \"Chest\", near: (point: (0.0, 1.42, -0.15), radius: 0.05))]",
        "",
    );
    for (text, row) in [
        (
            cape_scene("backward_euler()", CAPE_GRID, CAPE_ROW),
            Some(&grid_row),
        ),
        (mesh_cape_scene(CAPE_ROW, ""), Some(&grid_row)),
        (obj, None),
    ] {
        let scene = scene_in_scenes(&text).unwrap();
        let results = scene.run(&RunOptions {
            keep_frames: true,
            ..RunOptions::default()
        });
        let t = &results.tasks[0];
        assert!(t.ok, "{}: {:?} {:?}", t.name, t.error, t.failures);
        let (penetrations, held, path) = match &t.metrics {
            TaskMetrics::Cloth(m) => {
                let c = m.contact.as_ref().unwrap();
                (c.penetrations, c.attach_error_max, c.max_path_depth)
            }
            TaskMetrics::MeshCloth(m) => {
                assert_eq!(m.intersections, 0);
                (m.penetrations, m.attach_error_max, m.max_path_depth)
            }
            other => panic!("{other:?}"),
        };
        assert_eq!(penetrations, 0, "{}", t.name);
        // The capsules hold still for the first 0.2 s, then move: each step's path
        // starts where the last step ended (not where the last moving step did), and
        // stays within the allowance `min(dhat, r/2)` = 1 mm of every capsule.
        let path = path.expect("the capsules move");
        assert!(path <= 1e-3, "{}: max_path_depth {path:e}", t.name);
        // The held row ends where the chest's frame puts it, to round-off (the runner's
        // check, from forward kinematics, not from the library's pinned motion).
        let held = held.expect("held particles are checked");
        assert!(held < 1e-12, "{}: {held:e}", t.name);
        // And the chest took it down with the squat (0.8 s in: the hips 0.25 m lower).
        let Pictures::Cloth(p) = &t.pictures else {
            panic!("no pictures")
        };
        let (first, last) = (
            &p.frames[0].positions,
            &p.frames[p.frames.len() - 1].positions,
        );
        let row: Vec<usize> = match row {
            Some(row) => row.clone(),
            None => (0..first.len())
                .filter(|&k| first[k].distance(centre) <= radius)
                .collect(),
        };
        assert!(row.len() >= 5, "{}: {row:?}", t.name);
        for &k in &row {
            assert!(
                first[k].y - last[k].y > 0.15,
                "{}: particle {k}: {} -> {}",
                t.name,
                first[k],
                last[k]
            );
        }
    }
}

#[test]
fn bad_attachments_are_named() {
    let grid = |attach: &str| cape_scene("backward_euler()", CAPE_GRID, attach);
    let explicit = "Explicit(particles: [(position: (0.0, 1.42, -0.4), velocity: (0.0, 0.0, 0.0), mass: 1e-3, fixed: false)], springs: [])";
    let cases = [
        (
            grid("[(joint: \"Chest\", particles: [(7, 0)])]"),
            "contact: limbs: attach[0]: particle (7, 0) is outside the 7 x 7 grid",
        ),
        (
            grid("[(joint: \"Chest\", particles: [(0, 6)]), (joint: 0, particles: [(0, 6)])]"),
            "contact: limbs: attach[1]: particle (0, 6) is held twice",
        ),
        (
            grid("[(joint: \"Tail\", particles: [(0, 6)])]"),
            "contact: limbs: attach[0]: joint = \"Tail\": no joint has that name",
        ),
        (
            cape_scene(
                "backward_euler()",
                explicit,
                "[(joint: \"Chest\", particles: [(0, 0)])]",
            ),
            "contact: limbs: attach[0]: particles: grid coordinates need a Grid (give vertices or near)",
        ),
        (
            cape_scene(
                "backward_euler()",
                explicit,
                "[(joint: \"Chest\", vertices: [1])]",
            ),
            "contact: limbs: attach[0]: vertex 1 does not exist (there are 1)",
        ),
        (
            grid("[(joint: \"Chest\", sheet: 1, particles: [(0, 6)])]"),
            "contact: limbs: attach[0]: sheet = 1, but a Cloth task has one system (sheet 0)",
        ),
        (
            grid("[(joint: \"Chest\", particles: [(0, 6)], vertices: [6])]"),
            "contact: limbs: attach[0]: particles, vertices, near: more than one given (grid coordinates, indices or a ball, one of them)",
        ),
        (
            grid("[(joint: \"Chest\")]"),
            "contact: limbs: attach[0]: particles, vertices, near: none given (give one)",
        ),
        (
            grid("[(joint: \"Chest\", near: (point: (0.0, 1.42, -0.15), radius: 0.0))]"),
            "contact: limbs: attach[0]: near: radius = 0 is not positive and finite",
        ),
        (
            grid("[(joint: \"Chest\", near: (point: (0.0, 3.0, -0.15), radius: 0.01))]"),
            "contact: limbs: attach[0]: near: no particle starts within 0.01 of [0, 3, -0.15]",
        ),
        (
            grid("[(joint: \"Chest\", particles: [(0, 6)]), (joint: \"Chest\", vertices: [6])]"),
            "contact: limbs: attach[1]: vertex 6 is held twice",
        ),
        // A mesh cloth: the sheet must exist and be a grid, and its pins move one way.
        (
            mesh_cape_scene("[(joint: \"Chest\", sheet: 1, particles: [(0, 6)])]", ""),
            "limbs: attach[0]: sheet = 1 does not exist (there are 1)",
        ),
        (
            mesh_cape_scene(
                CAPE_ROW,
                "moving_pins: [(sheet: 0, rows: [0], velocity: (0.0, 0.1, 0.0))],",
            ),
            "limbs: attach: given with moving_pins (pins move either with a joint or along a motion, in one task not both)",
        ),
        (
            mesh_cape_sheet(
                "Obj(path: \"data/sheet.obj\", scale: 0.24, offset: (-0.12, 1.42, -0.39))",
                "[(joint: \"Chest\", particles: [(0, 6)])]",
                "",
            ),
            "limbs: attach[0]: particles: grid coordinates need a Grid (give vertices or near)",
        ),
        (
            mesh_cape_sheet(
                "Obj(path: \"data/sheet.obj\", scale: 0.24, offset: (-0.12, 1.42, -0.39))",
                "[(joint: \"Chest\", vertices: [121])]",
                "",
            ),
            "limbs: attach[0]: vertex 121 does not exist (the file has 121 vertices)",
        ),
        (
            mesh_cape_scene("[(joint: \"Chest\", particles: [(0, 6), (0, 6)])]", ""),
            "limbs: attach[0]: particle (0, 6) is held twice",
        ),
    ];
    for (text, expected) in cases {
        match scene_in_scenes(&text) {
            Err(e) => assert!(e.to_string().ends_with(expected), "{e}"),
            Ok(_) => panic!("accepted: {text}"),
        }
    }
    // Moving pins need an implicit integrator: the run says so.
    let scene = scene_in_scenes(&cape_scene("verlet()", CAPE_GRID, CAPE_ROW)).unwrap();
    let t = &scene.run(&RunOptions::default()).tasks[0];
    assert!(!t.ok);
    let e = t.error.as_deref().unwrap_or_default();
    assert!(
        e.starts_with("contact: limbs: attach: ") && e.contains("implicit integrator"),
        "{e}"
    );
}

/// The `v` statements of scenes/data/sheet.obj, in the file's order.
fn sheet_obj_vertices() -> Vec<DVec3> {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../scenes/data/sheet.obj"
    ))
    .unwrap();
    text.lines()
        .filter_map(|l| {
            let mut w = l.split_whitespace();
            (w.next() == Some("v")).then(|| {
                let c: Vec<f64> = w.map(|x| x.parse().unwrap()).collect();
                DVec3::new(c[0], c[1], c[2])
            })
        })
        .collect()
}

/// An OBJ sheet's `fixed` and an attachment's `vertices` name the file's vertices (the
/// indices of its `v` statements): the two vertices a sheet hanging under gravity keeps
/// still are where the file's vertices 0 and 10 are; and a cape held by the file's
/// vertices within 5 cm of its back edge's middle, given by number, runs bit for bit as
/// the same cape held by the ball `near`.
#[test]
fn an_obj_sheets_pins_and_held_vertices_are_the_files() {
    let file = sheet_obj_vertices();
    let scene = scene_in_scenes(
        "Scene(description: \"pins\", tasks: [MeshCloth(
            name: \"hung\",
            sheets: [Obj(path: \"data/sheet.obj\", scale: 0.3, fixed: [0, 10])],
            material: (stiffness: 500.0, damping: 0.1, gravity: (0.0, -9.81, 0.0)),
            dt: 0.016666666666666666,
            steps: 10,
            self_contact: (dhat: 2e-3, thickness: 1e-3),
        )])",
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let frames = cloth_frames(&scene);
    let (first, last) = (&frames[0], &frames[frames.len() - 1]);
    let still: Vec<DVec3> = (0..first.len())
        .filter(|&k| first[k] == last[k])
        .map(|k| first[k])
        .collect();
    assert_eq!(still, vec![0.3 * file[0], 0.3 * file[10]]);
    // A vertex the file does not have is an error naming it.
    let err = scene_in_scenes(
        "Scene(description: \"pins\", tasks: [MeshCloth(
            name: \"hung\",
            sheets: [Obj(path: \"data/sheet.obj\", fixed: [121])],
            dt: 0.016666666666666666,
            steps: 1,
        )])",
    )
    .map(|s| s.run(&RunOptions::default()));
    let message = match err {
        Err(e) => e.to_string(),
        Ok(r) => format!("{:?}", r.tasks[0].error),
    };
    assert!(
        message.contains("fixed: vertex 121 does not exist"),
        "{message}"
    );

    // The cape: by number and by the ball.
    let (scale, offset) = (0.24, DVec3::new(-0.12, 1.42, -0.39));
    let (centre, radius) = (DVec3::new(0.0, 1.42, -0.15), 0.05);
    let held: Vec<String> = (0..file.len())
        .filter(|&v| (scale * file[v] + offset).distance(centre) <= radius)
        .map(|v| v.to_string())
        .collect();
    assert!(held.len() >= 3, "{held:?}");
    let sheet = "Obj(path: \"data/sheet.obj\", scale: 0.24, offset: (-0.12, 1.42, -0.39))";
    let by_number = format!("[(joint: \"Chest\", vertices: [{}])]", held.join(", "));
    let by_ball = "[(joint: \"Chest\", near: (point: (0.0, 1.42, -0.15), radius: 0.05))]";
    let run = |attach: &str| {
        let text = mesh_cape_sheet(sheet, attach, "").replace("steps: 24", "steps: 8");
        let frames = cloth_frames(&scene_in_scenes(&text).unwrap());
        frames[frames.len() - 1].clone()
    };
    assert_eq!(run(&by_number), run(by_ball));
}

/// The positions of every kept frame of `scene`'s first task, a cloth, run with frames
/// kept; the task must succeed.
fn cloth_frames(scene: &Scene) -> Vec<Vec<DVec3>> {
    let results = scene.run(&RunOptions {
        keep_frames: true,
        ..RunOptions::default()
    });
    let t = &results.tasks[0];
    assert!(t.ok, "{}: {:?} {:?}", t.name, t.error, t.failures);
    let Pictures::Cloth(p) = &t.pictures else {
        panic!("{}: no pictures", t.name)
    };
    p.frames.iter().map(|f| f.positions.clone()).collect()
}

/// The triangles of a `MeshCloth` made of `scenes/data/<obj>` (its faces fanned, as the
/// reader does) followed by an `n x n` grid sheet, read apart from the task: what the
/// exact intersection check is given.
fn obj_then_grid_triangles(obj: &str, n: usize) -> Vec<[usize; 3]> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes/data")
        .join(obj);
    let mesh = sinew_io::obj::parse_obj(&std::fs::read_to_string(path).unwrap()).unwrap();
    let offset = mesh.positions.len();
    let grid = sinew_spring_sim::ClothGrid {
        size: n,
        ..sinew_spring_sim::ClothGrid::lab()
    };
    mesh.triangles
        .into_iter()
        .chain(grid.triangles().into_iter().map(|t| t.map(|v| v + offset)))
        .collect()
}

/// The distance from `x` to the axis-aligned box `[low, high]`, negative inside (minus
/// the distance to its nearest face).
fn box_signed_distance(x: DVec3, low: DVec3, high: DVec3) -> f64 {
    let outside = (low - x).max(x - high).max(DVec3::ZERO).length();
    let inside = (x - low).min(high - x).min_element();
    if inside > 0.0 { -inside } else { outside }
}

/// The committed tablecloth scene: a 21 x 21 sheet dropped onto a table read from
/// scenes/data/table.obj and pinned whole (`pin_all`), touching it through self-contact
/// only. Checked here from the frames, apart from the solver: the table's vertices never
/// move; every cloth vertex stays farther than the thickness (1 mm) from the box in every
/// frame (the box's distance in closed form); no two triangles of the cloth and the table
/// meet at the end (the exact check); and the cloth drapes: its middle rests on the top
/// within `dhat + thickness`, the middles of its borders hang below the top's edges and
/// the corners, which overhang the table's corners by 0.21 m, fall below the top too.
#[test]
fn a_tablecloth_drapes_over_a_pinned_mesh_table_and_never_enters_it() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cloth-table.ron");
    let text = std::fs::read_to_string(&path).unwrap();
    let scene = Scene::from_text(&path, &text).unwrap_or_else(|e| panic!("{e}"));
    let frames = cloth_frames(&scene);
    let (low, high) = (DVec3::new(-0.25, 0.35, -0.25), DVec3::new(0.25, 0.40, 0.25));
    let table = 242;
    let (first, last) = (&frames[0], &frames[frames.len() - 1]);
    assert_eq!(first.len(), table + 21 * 21);
    for x in &first[..table] {
        // Every table vertex is on the box's surface.
        assert!(box_signed_distance(*x, low, high).abs() < 1e-12, "{x}");
    }
    let mut closest = f64::INFINITY;
    for f in &frames {
        assert_eq!(&f[..table], &first[..table]);
        for x in &f[table..] {
            closest = closest.min(box_signed_distance(*x, low, high));
        }
    }
    assert!(closest > 1e-3, "a cloth vertex {closest} m from the table");
    let triangles = obj_then_grid_triangles("table.obj", 21);
    let meeting = sinew_exact::intersecting_pairs(last, &triangles);
    assert!(meeting.is_empty(), "{meeting:?}");
    let cloth = |i: usize, j: usize| last[table + 21 * i + j];
    // Measured: the middle 2.83 mm above the top, the borders' middles 13 cm below it and
    // 3.7 cm out from the sides, the corners 3.6 and 19.1 cm below it.
    let middle = cloth(10, 10);
    assert!(middle.y > 0.401 && middle.y <= 0.403, "{middle}");
    for (x, along_x) in [(cloth(0, 10), true), (cloth(20, 10), true)]
        .into_iter()
        .chain([(cloth(10, 0), false), (cloth(10, 20), false)])
    {
        let out = if along_x { x.x } else { x.z };
        assert!(x.y < 0.30 && out.abs() > 0.25, "a border's middle at {x}");
    }
    for corner in [cloth(0, 0), cloth(0, 20), cloth(20, 0), cloth(20, 20)] {
        assert!(corner.y < 0.39, "a corner at {corner}");
    }
}

/// A sheet of `scenes/data/sheet.obj` (scaled to 0.5 m, 5 cm spacing) pinned whole at
/// y = 0.3 and moved along +x at 0.5 m/s (`moving_pins` without rows: every vertex of the
/// sheet), with a 4 x 4 grid sheet released at rest at its resting gap above it;
/// self-contact friction `mu`; 24 steps of 1/60 s.
fn belt_scene(mu: f64) -> String {
    format!(
        "Scene(description: \"belt\", tasks: [MeshCloth(
            name: \"belt\",
            sheets: [
                Obj(path: \"data/sheet.obj\", scale: 0.5, offset: (-0.25, 0.3, -0.25), pin_all: true),
                Grid(size: 4, spacing: 0.05, origin: (-0.075, 0.30273, -0.075)),
            ],
            material: (stiffness: 500.0, damping: 0.1, gravity: (0.0, -9.81, 0.0)),
            dt: 0.016666666666666666,
            steps: 24,
            self_contact: (dhat: 2e-3, thickness: 1e-3, mu: {mu:?}),
            moving_pins: [(sheet: 0, velocity: (0.5, 0.0, 0.0))],
        )])"
    )
}

/// A moving mesh obstacle carries a sheet as Coulomb says: on the belt of [`belt_scene`]
/// (an OBJ sheet pinned whole and moved by `moving_pins` without rows) the sheet lying on
/// it speeds up at `mu g` (0.8 x 9.81: 0.131 m/s a step) until it moves with the belt,
/// then moves with it (static friction: within `eps_v`, 1 mm/s); without friction it stays
/// within a centimetre of where it was while the belt slides 0.2 m under it. The belt's
/// vertices are where the motion puts them in every frame (`r + v t`, to 1e-12), and no
/// triangles meet at the end.
#[test]
fn a_sheet_on_a_moving_mesh_belt_is_carried_at_coulombs_acceleration() {
    let belt = 121;
    let h = 1.0 / 60.0;
    let run = |mu: f64| {
        let frames = cloth_frames(&scene_in_scenes(&belt_scene(mu)).unwrap());
        assert_eq!(frames.len(), 25);
        for (k, f) in frames.iter().enumerate() {
            let t = k as f64 * h;
            for (x, r) in f[..belt].iter().zip(&frames[0][..belt]) {
                assert!((*x - (*r + DVec3::new(0.5 * t, 0.0, 0.0))).length() < 1e-12);
            }
        }
        let triangles = obj_then_grid_triangles("sheet.obj", 4);
        let last = &frames[frames.len() - 1];
        let meeting = sinew_exact::intersecting_pairs(last, &triangles);
        assert!(meeting.is_empty(), "{meeting:?}");
        // The top sheet's mean x, frame by frame.
        frames
            .iter()
            .map(|f| f[belt..].iter().map(|x| x.x).sum::<f64>() / 16.0)
            .collect::<Vec<f64>>()
    };
    let carried = run(0.8);
    let v: Vec<f64> = carried.windows(2).map(|w| (w[1] - w[0]) / h).collect();
    // Measured: 0.069 in the first step (its friction is lagged from the release state;
    // not checked, and not traced), then 0.126, 0.135 and 0.131 m/s more a step, 0.49986
    // in the fifth and 0.50000 from the sixth on.
    let coulomb = 0.8 * 9.81 * h;
    for k in 1..4 {
        let dv = v[k] - v[k - 1];
        assert!(
            (dv / coulomb - 1.0).abs() < 0.05,
            "step {}: {dv} m/s more",
            k + 1
        );
    }
    for (k, vk) in v.iter().enumerate().skip(5) {
        assert!((vk - 0.5).abs() < 1e-3, "step {}: {vk} m/s", k + 1);
    }
    // Without friction nothing but the discrete surfaces' own lateral forces acts along
    // the belt: the barrier is a sum over vertex-triangle and edge-edge pairs, and pairs
    // near the belt's edges (distances that change with the lateral offset) come and go
    // as it slides. Measured: the sheet drifts 2.0 mm against the belt's motion, in jumps
    // every third step (half the belt's spacing), against the 0.2 m the belt travels.
    let still = run(0.0);
    let drift = still[still.len() - 1] - still[0];
    assert!(drift.abs() < 0.01, "the frictionless sheet moved {drift} m");
    // Rows are a grid's: asked of the OBJ sheet, they are an error that says how to move
    // it whole.
    let text = belt_scene(0.8).replace("(sheet: 0, velocity", "(sheet: 0, rows: [0], velocity");
    let message = match scene_in_scenes(&text) {
        Err(e) => e.to_string(),
        Ok(s) => format!("{:?}", s.run(&RunOptions::default()).tasks[0].error),
    };
    assert!(
        message.contains("moving_pins[0]: sheet 0 is not a Grid")
            && message.contains("leave rows out to move the whole sheet"),
        "{message}"
    );
}
