//! Typed results of a scene run: one metrics struct per task kind (serialized under
//! `"metrics"` in `metrics.json`, with the keys docs/scenes.md lists), the task's table
//! (CSV) and what its pictures need.
//!
//! A metric is a field, so renaming one is a compile error everywhere it is read, not a
//! silently missing row.

use serde::Serialize;
use sinew_math::DVec3;
use sinew_spring_sim::RunMetrics;
pub use sinew_spring_sim::contact::Shape;

/// Everything one run of a scene produced; serialized, this is `metrics.json`.
#[derive(Clone, Debug, Serialize)]
pub struct SceneResults {
    /// The scene's name (its file stem).
    pub scene: String,
    /// The scene's description.
    pub description: String,
    /// One result per task, in the scene's order.
    pub tasks: Vec<TaskResult>,
}

impl SceneResults {
    /// Whether every task ran and met the expectations written in the scene.
    #[must_use]
    pub fn ok(&self) -> bool {
        self.tasks.iter().all(|t| t.ok)
    }
}

/// The result of one task.
#[derive(Clone, Debug, Serialize)]
pub struct TaskResult {
    /// The task's name.
    pub name: String,
    /// The task kind, as the scene file spells it (`Fk`, `Ik`, ...).
    pub kind: &'static str,
    /// Wall time of the task, in seconds.
    pub wall_time_s: f64,
    /// Whether the task ran and met its expectations.
    pub ok: bool,
    /// Why the task could not run, if it could not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The task's metrics (empty when it could not run).
    pub metrics: TaskMetrics,
    /// A short human summary for a table.
    #[serde(skip)]
    pub headline: String,
    /// Expectations written in the scene that did not hold.
    #[serde(skip)]
    pub failures: Vec<String>,
    /// The task's per-frame table (empty when it could not run).
    #[serde(skip)]
    pub table: Csv,
    /// What the task's pictures need (empty unless the run kept frames).
    #[serde(skip)]
    pub pictures: Pictures,
}

/// A table as CSV text, with the suffix of the file it is written to
/// (`<task>.<suffix>`).
#[derive(Clone, Debug, Default)]
pub struct Csv {
    /// The file suffix, e.g. `frames.csv`.
    pub suffix: &'static str,
    /// The CSV text, header line first.
    pub text: String,
}

/// The metrics of a task, by kind.
#[derive(Clone, Debug, Serialize)]
#[serde(untagged)]
pub enum TaskMetrics {
    /// An `Fk` task's.
    Fk(FkMetrics),
    /// An `Ik` task's.
    Ik(IkMetrics),
    /// A `TwoBone` task's.
    TwoBone(TwoBoneMetrics),
    /// A `Curve` task's.
    Curve(CurveMetrics),
    /// A `Cloth` task's.
    Cloth(ClothMetrics),
    /// A `FullBody` task's.
    Body(BodyMetrics),
    /// A `MeshCloth` task's.
    MeshCloth(MeshClothMetrics),
    /// None: the task could not run (serialized as `{}`).
    None(NoMetrics),
}

/// The metrics of a task that could not run: serialized as `{}`.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct NoMetrics {}

/// An `Fk` task's metrics.
#[derive(Clone, Debug, Serialize)]
pub struct FkMetrics {
    /// Joints in the skeleton.
    pub joints: usize,
    /// The last joint's global position.
    pub effector: [f64; 3],
    /// Largest relative bone-length error of the posed skeleton.
    pub bone_length_error_max: f64,
    /// Largest distance between FK restarted from each joint and full FK (must be 0).
    pub fk_from_diff_max: f64,
    /// Largest distance of an expected joint position from the computed one.
    pub expect_error_max: f64,
    /// Median time of one full FK, in nanoseconds.
    pub time_ns_median: f64,
}

/// An `Ik` task's metrics.
#[derive(Clone, Debug, Serialize)]
pub struct IkMetrics {
    /// The solver's label, from the registry.
    pub solver: String,
    /// Frames tracked.
    pub frames: usize,
    /// Mean final effector-to-target distance.
    pub error_mean: f64,
    /// Largest final effector-to-target distance.
    pub error_max: f64,
    /// Iterations over all frames.
    pub iterations_total: usize,
    /// Frames that ended within the tolerance.
    pub converged_frames: usize,
    /// Frames whose target was out of reach (solved in closed form).
    pub out_of_reach_frames: usize,
    /// Frames that ended within the tolerance (the same count as `converged_frames`,
    /// under the name the other IK kinds use).
    pub within_tol: usize,
    /// Largest joint-limit violation of any frame's pose, in radians.
    pub limit_violation_max: f64,
    /// Largest final rotation error, in radians (0 without rotation goals).
    pub rotation_error_max: f64,
    /// Frames that ended at the best pose within the joint limits the solver found.
    pub local_minimum_frames: usize,
    /// Frames clamped by `max_rotation_change`.
    pub clamped_frames: usize,
    /// Largest bone-length error over all frames, in scene units.
    pub bone_length_error_max: f64,
    /// Largest change of a joint's local rotation between frames, in radians.
    pub rotation_jump_max_rad: f64,
    /// Median time of one frame's solve, in nanoseconds.
    pub time_per_frame_ns_median: f64,
    /// The final pose's largest angle between consecutive bones, in radians.
    pub final_bend_max_rad: f64,
    /// For a last target out of reach: the last error less the least possible one
    /// (distance - reach); `None` when the last target is within reach.
    pub closed_form_gap: Option<f64>,
}

/// A `TwoBone` task's metrics.
#[derive(Clone, Debug, Serialize)]
pub struct TwoBoneMetrics {
    /// Frames solved.
    pub frames: usize,
    /// Frames whose target the limb reached.
    pub reached: usize,
    /// Reached frames that ended within the tolerance.
    pub within_tol: usize,
    /// Largest tip-to-target distance.
    pub error_max: f64,
    /// Largest tip-to-target distance of a reached frame.
    pub reached_error_max: f64,
    /// Largest difference between the reported error and forward kinematics'.
    pub report_fk_diff_max: f64,
    /// Largest hinge-limit violation of the mid joint, in radians.
    pub limit_violation_max: f64,
    /// How far the mid joint bent away from the pole, at most.
    pub wrong_side_max: f64,
    /// Largest relative bone-length error.
    pub bone_length_error_max: f64,
    /// Smallest bend angle, in radians.
    pub bend_angle_min: f64,
    /// Largest bend angle, in radians.
    pub bend_angle_max: f64,
    /// Median time of one solve, in nanoseconds.
    pub time_per_solve_ns_median: f64,
}

/// A `Curve` task's metrics.
#[derive(Clone, Debug, Serialize)]
pub struct CurveMetrics {
    /// The sampling: `uniform`, `arc_length` or `arc_spacing`.
    pub sampling: &'static str,
    /// Points taken.
    pub points: usize,
    /// The length the method yields (the arc-length table's, or the sum of chords for
    /// uniform sampling).
    pub length: f64,
    /// Distance of `length` from the exact length, when the curve has one.
    pub length_error: Option<f64>,
    /// Largest relative deviation of the arc spacing from its mean.
    pub spacing_rel_dev_max: Option<f64>,
    /// Largest relative deviation of the chord spacing from its mean.
    pub chord_spacing_rel_dev_max: f64,
    /// Median time of the sampling, in nanoseconds.
    pub time_ns: f64,
}

/// A `Cloth` task's metrics.
#[derive(Clone, Debug, Serialize)]
pub struct ClothMetrics {
    /// The run as spring-sim measures it (steps, integrator, Newton iterations,
    /// residual, energies, the largest per-step energy rise on the scale
    /// docs/scenes.md gives, median step time, divergence). Flattened, so its keys
    /// stand beside the ones below in `metrics.json`; `stopped_by` appears only when
    /// a step failed.
    #[serde(flatten)]
    pub run: RunMetrics,
    /// Why `auto` chose its integrator (the last step's reason), if it did.
    pub auto_reason: Option<String>,
    /// Substeps of the last step (explicit integrators).
    pub substeps: usize,
    /// Distance from the true motion after 1 s, when the scene asks for it.
    pub true_motion_error_1s: Option<f64>,
    /// How much halving the reference's substep changes it (must be far below the
    /// error).
    pub true_motion_reference_check: Option<f64>,
    /// Contact metrics, when the task has colliders.
    #[serde(flatten)]
    pub contact: Option<ContactMetrics>,
}

/// Contact metrics of a `Cloth` task with colliders, measured after every step
/// independently of the integrator's own bookkeeping.
#[derive(Clone, Debug, Serialize)]
pub struct ContactMetrics {
    /// Smallest particle-collider distance over the run (`None` with no free particle).
    pub min_distance: Option<f64>,
    /// Particle-collider pairs at distance <= 0, over all steps (must be 0).
    pub penetrations: usize,
    /// Most particle-collider pairs within the contact distance in one step.
    pub contact_pairs_max: usize,
    /// The barrier stiffness used.
    pub kappa: Option<f64>,
    /// Pieces the integrator kept although a kinematic collider passed a particle in
    /// them (`StepReport::swept_passes`, summed over the run; must be 0).
    pub swept_passes: usize,
    /// The deepest any particle's straight path between two consecutive states went into
    /// a collider whose surface moves, sampled by the runner (positive: inside); `None`
    /// without such a collider.
    pub max_path_depth: Option<f64>,
    /// With limbs that reach: the largest distance between the reaching chain's
    /// effector and its target after a solve, over the run; `None` otherwise.
    pub reach_error_max: Option<f64>,
    /// With limbs that hold particles: the largest distance between a held particle and
    /// where its joint's frame puts it, after every step; `None` otherwise.
    pub attach_error_max: Option<f64>,
}

/// A `MeshCloth` task's metrics: the work, the self-contact statistics, and the checks
/// measured after every step independently of the integrator.
#[derive(Clone, Debug, Serialize)]
pub struct MeshClothMetrics {
    /// Vertices of the cloth (all sheets).
    pub vertices: usize,
    /// Triangles of the cloth.
    pub triangles: usize,
    /// Steps taken.
    pub steps: usize,
    /// Newton iterations over the run.
    pub newton_iterations_total: usize,
    /// Most Newton iterations in a step.
    pub newton_iterations_max: usize,
    /// Median wall time of a step, ms.
    pub time_per_step_ms_median: f64,
    /// The median step time per vertex, microseconds.
    pub time_per_vertex_step_us_median: f64,
    /// Most self-contact pairs within `dhat` at a Newton iterate's start, over the run.
    pub self_contact_pairs_max: usize,
    /// Most self-contact pairs with friction lagged at a step's start, over the run (0
    /// without `self_contact.mu`).
    pub self_friction_pairs_max: usize,
    /// The mean distance of the free vertices' end positions from their start
    /// positions, m (0 when every vertex is pinned).
    pub free_mean_displacement: f64,
    /// Pairs of triangles sharing no vertex that meet, summed over the states after
    /// every step, by an exact check sharing no code with the solver (must be 0).
    pub intersections: usize,
    /// Smallest distance between a vertex and a triangle, or two edges, sharing no
    /// vertex, among the pairs closer than `dhat` plus the thickness, over the states
    /// after every step (`None` when no pair came that close).
    pub min_self_distance: Option<f64>,
    /// Smallest vertex-collider distance over the run (`None` without colliders).
    pub min_distance: Option<f64>,
    /// Vertex-collider pairs at distance <= 0 over the run (must be 0).
    pub penetrations: usize,
    /// Pieces kept although a kinematic collider passed a vertex in them (must be 0).
    pub swept_passes: usize,
    /// The deepest any vertex's straight path between two consecutive states went into a
    /// collider whose surface moves (positive: inside); `None` without such a collider.
    pub max_path_depth: Option<f64>,
    /// With limbs that reach: the largest distance between the reaching chain's
    /// effector and its target after a solve, over the run; `None` otherwise.
    pub reach_error_max: Option<f64>,
    /// With limbs that hold vertices: the largest distance between a held vertex and
    /// where its joint's frame puts it, after every step; `None` otherwise.
    pub attach_error_max: Option<f64>,
    /// The self-contact barrier stiffness at the end.
    pub kappa: f64,
}

/// What a task's pictures need, by kind; `None` when the run kept no frames or the
/// kind draws nothing.
#[derive(Clone, Debug, Default)]
pub enum Pictures {
    /// Nothing to draw.
    #[default]
    None,
    /// An `Ik` task's animation and charts.
    Ik(IkPictures),
    /// A `Curve` task's comparison of samplings.
    Curve(CurvePictures),
    /// A `Cloth` task's animation and charts.
    Cloth(ClothPictures),
    /// A `FullBody` task's animation and charts.
    Body(BodyPictures),
}

/// One animation frame of an IK chain.
#[derive(Clone, Debug)]
pub struct IkFrame {
    /// The chain's joint positions, base first.
    pub joints: Vec<DVec3>,
    /// The frame's target.
    pub target: DVec3,
}

/// What an `Ik` task's pictures need.
#[derive(Clone, Debug)]
pub struct IkPictures {
    /// The solver's label.
    pub solver: String,
    /// The frames shown (at most a fixed number, the last always among them).
    pub frames: Vec<IkFrame>,
    /// A finer selection of frames for the interactive viewer (evenly spaced, at most
    /// a thousand, the first and last among them).
    pub track: Vec<IkFrame>,
    /// The frame index of each of `track`.
    pub track_frames: Vec<usize>,
    /// Every frame's target, the path drawn.
    pub targets: Vec<DVec3>,
    /// Every frame's final error.
    pub error: Vec<f64>,
    /// Every frame's iterations.
    pub iterations: Vec<usize>,
}

/// What a `Curve` task's picture needs: the curve's line and the same number of points
/// taken at uniform parameter steps and evenly by arc length.
#[derive(Clone, Debug)]
pub struct CurvePictures {
    /// Dense, evenly spaced points drawn as the curve's line.
    pub line: Vec<DVec3>,
    /// Points at uniform parameter steps.
    pub uniform: Vec<DVec3>,
    /// Points evenly spaced by arc length.
    pub even: Vec<DVec3>,
}

/// One animation frame of a cloth.
#[derive(Clone, Debug)]
pub struct ClothFrame {
    /// Particle positions.
    pub positions: Vec<DVec3>,
    /// The colliders, posed at the frame's time.
    pub colliders: Vec<Shape>,
}

/// What a `Cloth` task's pictures need.
#[derive(Clone, Debug)]
pub struct ClothPictures {
    /// The integrator's name.
    pub integrator: String,
    /// Springs as (particle, particle, rest length).
    pub springs: Vec<(usize, usize, f64)>,
    /// The fixed particles.
    pub fixed: Vec<usize>,
    /// The frames shown (at most a fixed number, the first and last among them).
    pub frames: Vec<ClothFrame>,
    /// A finer selection of frames for the interactive viewer (evenly spaced, at most
    /// a few hundred, the start and the last step among them).
    pub track: Vec<ClothFrame>,
    /// The step after which each of `track` was taken (0: the start).
    pub track_steps: Vec<usize>,
    /// The time step, in seconds.
    pub dt: f64,
    /// (time, total energy), from the start.
    pub energy: Vec<(f64, f64)>,
    /// (time, Newton iterations) per step.
    pub iterations: Vec<(f64, f64)>,
}

/// A `FullBody` task's metrics (the keys documented in `docs/scenes.md`).
#[derive(Clone, Debug, Serialize)]
pub struct BodyMetrics {
    /// Effectors solved together on every frame (followed and pinned).
    pub effectors: usize,
    /// Frames solved.
    pub frames: usize,
    /// Frames that ended with every effector within the tolerances.
    pub within_tol: usize,
    /// Largest joint-limit violation of any frame's returned pose, in radians.
    pub limit_violation_max: f64,
    /// Largest distance of any effector from its goal, over every frame.
    pub error_max: f64,
    /// Median wall time of one frame's solve, in microseconds.
    pub time_per_solve_us_median: f64,
}

/// One animation frame of a body: every joint's position and every effector's goal.
#[derive(Clone, Debug)]
pub struct BodyFrame {
    /// Every joint's global position, in the skeleton's order.
    pub joints: Vec<DVec3>,
    /// Every effector's goal position, in the order of [`BodyPictures::effectors`].
    pub goals: Vec<DVec3>,
    /// The frame's worst effector error.
    pub error: f64,
}

/// What a `FullBody` task's pictures need.
#[derive(Clone, Debug)]
pub struct BodyPictures {
    /// The solver's label.
    pub solver: String,
    /// Each joint's parent (`None` for a root): the bones drawn.
    pub parents: Vec<Option<usize>>,
    /// The effectors' joints.
    pub effectors: Vec<usize>,
    /// Whether each effector is pinned.
    pub pinned: Vec<bool>,
    /// The frames shown (at most a fixed number, the last always among them).
    pub frames: Vec<BodyFrame>,
    /// A finer selection of frames for the interactive viewer (evenly spaced, at most a
    /// thousand, the first and last among them).
    pub track: Vec<BodyFrame>,
    /// The frame index of each of `track`.
    pub track_frames: Vec<usize>,
    /// Every frame's worst effector error.
    pub error: Vec<f64>,
    /// Every frame's iterations.
    pub iterations: Vec<usize>,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The run's metrics are embedded but flattened, so `metrics.json` keeps one flat
    /// object per cloth task with the keys docs/scenes.md lists.
    #[test]
    fn cloth_metrics_serialize_flat_with_the_documented_keys() {
        let mut metrics = ClothMetrics {
            run: RunMetrics {
                steps: 3,
                integrator: "backward_euler".into(),
                newton_iterations_total: 6,
                newton_iterations_max: 2,
                residual_max: 1e-10,
                energy_start: 1.0,
                energy_end: 0.5,
                energy_increase_max: 0.0,
                time_per_step_ms_median: 0.1,
                diverged: false,
                stopped_by: None,
            },
            auto_reason: None,
            substeps: 1,
            true_motion_error_1s: None,
            true_motion_reference_check: None,
            contact: None,
        };
        let keys = |m: &ClothMetrics| -> Vec<String> {
            let value = serde_json::to_value(TaskMetrics::Cloth(m.clone())).unwrap();
            value.as_object().unwrap().keys().cloned().collect()
        };
        let expected = [
            "auto_reason",
            "diverged",
            "energy_end",
            "energy_increase_max",
            "energy_start",
            "integrator",
            "newton_iterations_max",
            "newton_iterations_total",
            "residual_max",
            "steps",
            "substeps",
            "time_per_step_ms_median",
            "true_motion_error_1s",
            "true_motion_reference_check",
        ];
        assert_eq!(keys(&metrics), expected);
        metrics.run.stopped_by = Some("step 3: non-finite state".into());
        assert!(keys(&metrics).contains(&"stopped_by".to_string()));
    }
}
