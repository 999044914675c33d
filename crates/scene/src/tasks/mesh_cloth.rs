//! The `MeshCloth` task: one or more triangle-mesh sheets (square grids placed in space,
//! or a mesh read from an OBJ file; a sheet pinned whole, still or moved rigidly, is an
//! obstacle for the others) built as one cloth, stepped by backward Euler with
//! self-contact (the IPC barrier between the cloth's own vertices, triangles and edges,
//! the line search capped by continuous collision detection) and, optionally, rigid
//! colliders. After every step the mesh is checked for triangles passing through each
//! other by the exact check of [`sinew_exact`], which shares no code with the
//! solver; any intersection fails the task.

use super::limbs::{Held, Limbs, LimbsSpec};
use super::{RunContext, TaskOutput, TaskSpec};
use crate::limits::{
    MAX_GRID_SIZE, MAX_ITERATIONS, MAX_PARTICLE_STEPS, MAX_PARTICLES, MAX_STEPS, at_most,
};
use crate::results::{ClothFrame, ClothPictures, Csv, MeshClothMetrics, Pictures, TaskMetrics};
use serde::Deserialize;
use sinew_exact::intersecting_pairs;
use sinew_io::obj::{NumberedObj, parse_obj_numbered};
use sinew_math::DVec3;
use sinew_spring_sim::contact::collider::validate_colliders;
use sinew_spring_sim::contact::self_contact::distance::squared_distance;
use sinew_spring_sim::contact::self_contact::{Primitives, SelfContactSettings, candidates};
use sinew_spring_sim::contact::{
    Collider, ContactSettings, Drive, Shape, check_contact_distance, check_start_outside,
    signed_distance,
};
use sinew_spring_sim::{
    Bending, ClothGrid, Integrator, Material, MeshCloth, MeshClothModel, NewtonSettings, PinDriver,
    PinnedMotion, PinnedStepper, TriangleMesh,
};
use std::path::PathBuf;
use std::time::Instant;

/// Scene fields of a `MeshCloth` task.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshClothTask {
    /// Unique name in the scene.
    pub name: String,
    /// The sheets, built as one cloth (vertex indices run sheet after sheet).
    pub sheets: Vec<SheetSpec>,
    /// Mass per area, kg/m^2, lumped to the vertices (default 0.2).
    #[serde(default = "areal_density")]
    pub areal_density: f64,
    /// Stiffness of every edge spring, damping, gravity.
    #[serde(default)]
    pub material: Material,
    /// Bending (default none).
    #[serde(default)]
    pub bending: Option<Bending>,
    /// The implicit scheme (default `backward_euler`; `bdf2`, `implicit_midpoint`): the
    /// same Newton settings (the fields below), contact and self-contact in each.
    #[serde(default)]
    pub integrator: MeshScheme,
    /// Time step, s.
    pub dt: f64,
    /// Number of steps.
    pub steps: usize,
    /// Newton's iteration cap per step (default 100).
    #[serde(default = "max_iterations")]
    pub max_iterations: usize,
    /// Newton's tolerance (default sinew-spring-sim's, `NewtonSettings::tolerance`).
    #[serde(default = "tolerance")]
    pub tolerance: f64,
    /// How many times a step may be halved (default sinew-spring-sim's,
    /// `NewtonSettings::max_split_depth`; 0 turns splitting off, for a fixed cost per step).
    #[serde(default = "max_split_depth")]
    pub max_split_depth: usize,
    /// How many times a step lags friction (default 1, at the step's start;
    /// `NewtonSettings::friction_lags`: more lags it again where each round ended and
    /// minimizes again, so friction also acts in the step a contact begins).
    #[serde(default = "friction_lags")]
    pub friction_lags: usize,
    /// Self-contact settings (`dhat`, thickness, ...; defaults: sinew-spring-sim's).
    #[serde(default)]
    pub self_contact: SelfContactSettings,
    /// Rigid colliders (default none).
    #[serde(default)]
    pub colliders: Vec<Collider>,
    /// Capsules on an animated skeleton, after `colliders` in the list (default none;
    /// as in a `Cloth` task's `contact`).
    #[serde(default)]
    pub limbs: Option<LimbsSpec>,
    /// Collider contact settings (defaults: sinew-spring-sim's).
    #[serde(default)]
    pub contact: ContactSettings,
    /// Rows of grid sheets held and moved along rigid motions (default none): their
    /// vertices are pinned and follow the motion, the step cut into pieces of it when the
    /// whole move would bring the cloth too close to crossing itself.
    #[serde(default)]
    pub moving_pins: Vec<MovingPins>,
    /// The directory OBJ paths are relative to (the scene file's; set by the reader).
    #[serde(skip)]
    pub base_dir: PathBuf,
}

/// The implicit scheme of a `MeshCloth` task (its Newton settings are the task's own
/// fields). Contact and self-contact act on the end-of-step state in each
/// (docs/contact.md); the midpoint gains energy on crumpling cloth (docs/integrators.md).
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum MeshScheme {
    /// Backward Euler: first order, damps every mode.
    #[default]
    BackwardEuler,
    /// BDF2: second order, damps the unresolved modes.
    Bdf2,
    /// The implicit midpoint: second order, no numerical damping.
    #[serde(alias = "midpoint")]
    ImplicitMidpoint,
}

impl MeshScheme {
    /// The integrator of this scheme for `model`, with its bending term.
    fn build(
        self,
        model: &MeshClothModel,
        newton: NewtonSettings,
    ) -> Result<Box<dyn PinnedStepper>, String> {
        let integrator = match self {
            Self::BackwardEuler => Integrator::BackwardEuler(newton),
            Self::Bdf2 => Integrator::Bdf2(newton),
            Self::ImplicitMidpoint => Integrator::ImplicitMidpoint(newton),
        };
        model
            .implicit_stepper(integrator)
            .map_err(|e| format!("integrator: {e}"))
    }

    /// The scheme's name in pictures and reports.
    fn label(self) -> &'static str {
        match self {
            Self::BackwardEuler => "backward Euler",
            Self::Bdf2 => "BDF2",
            Self::ImplicitMidpoint => "implicit midpoint",
        }
    }
}

fn areal_density() -> f64 {
    0.2
}

fn max_iterations() -> usize {
    100
}

fn tolerance() -> f64 {
    NewtonSettings::default().tolerance
}

fn max_split_depth() -> usize {
    NewtonSettings::default().max_split_depth
}

fn friction_lags() -> usize {
    NewtonSettings::default().friction_lags
}

fn x_axis() -> DVec3 {
    DVec3::X
}

fn z_axis() -> DVec3 {
    DVec3::Z
}

fn one() -> f64 {
    1.0
}

/// How far from 1 the length of a grid sheet's direction `u` or `w` may be: the scenes
/// write directions to six digits.
const UNIT_TOLERANCE: f64 = 1e-6;

/// One sheet of a `MeshCloth` task.
#[derive(Debug, Deserialize)]
pub enum SheetSpec {
    /// A `size x size` square grid: vertex `(i, j)` (index `i size + j`) at
    /// `origin + spacing (i u + j w)`, two triangles per cell.
    Grid {
        /// Vertices per side.
        size: usize,
        /// Distance between neighbouring vertices, m.
        spacing: f64,
        /// The position of vertex `(0, 0)`.
        origin: DVec3,
        /// The direction of `i`, a unit vector (default +x).
        #[serde(default = "x_axis")]
        u: DVec3,
        /// The direction of `j`, a unit vector (default +z).
        #[serde(default = "z_axis")]
        w: DVec3,
        /// Pin every vertex of the border.
        #[serde(default)]
        pin_border: bool,
        /// Pin every vertex: a fixed surface for the other sheets to lie on.
        #[serde(default)]
        pin_all: bool,
        /// Initial velocity of every vertex, m/s.
        #[serde(default)]
        velocity: DVec3,
    },
    /// A triangle mesh from an OBJ file (quads and polygons fanned into triangles),
    /// scaled by `scale` about the origin, then moved by `offset`.
    Obj {
        /// The file, relative to the scene file.
        path: String,
        /// Scale factor (default 1).
        #[serde(default = "one")]
        scale: f64,
        /// Translation, m.
        #[serde(default)]
        offset: DVec3,
        /// Vertices to pin, by their `v` statements' indices in the file (from 0).
        #[serde(default)]
        fixed: Vec<usize>,
        /// Pin every vertex: the mesh is a fixed obstacle (a table, a body in its pose)
        /// that the other sheets touch through self-contact, sharp edges and all.
        #[serde(default)]
        pin_all: bool,
        /// Initial velocity of every vertex, m/s.
        #[serde(default)]
        velocity: DVec3,
    },
}

/// Rows of a grid sheet, or a whole sheet, held and moved rigidly: at time `t` a vertex
/// that started at `r` is at `point + R(axis, angular_speed t) (r - point) + velocity t`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MovingPins {
    /// The sheet (index in `sheets`).
    pub sheet: usize,
    /// The rows `i` of a grid sheet whose vertices move (each row is the `size` vertices
    /// `(i, 0..size)`); none (the default) moves every vertex of the sheet, a grid's or an
    /// OBJ sheet's: a moving obstacle when the sheet is pinned whole.
    #[serde(default)]
    pub rows: Vec<usize>,
    /// A point on the rotation axis (default the origin).
    #[serde(default)]
    pub point: DVec3,
    /// The rotation axis (default +x), counterclockwise for a positive rate.
    #[serde(default = "x_axis")]
    pub axis: DVec3,
    /// Rotation rate, rad/s (default 0).
    #[serde(default)]
    pub angular_speed: f64,
    /// Translation velocity, m/s (default zero).
    #[serde(default)]
    pub velocity: DVec3,
}

/// The assembled cloth: positions, triangles, pinned vertices, initial velocities.
struct Assembled {
    positions: Vec<DVec3>,
    triangles: Vec<[usize; 3]>,
    fixed: Vec<usize>,
    velocities: Vec<DVec3>,
    /// The moving pins' motions (their vertices are in `fixed` too).
    motions: Vec<PinnedMotion>,
    /// The vertices each of the limbs' attachments holds (in `fixed` too).
    held: Vec<Vec<usize>>,
    /// The vertices of the sheets pinned whole (`pin_all`): obstacles, whose vertices the
    /// pictures do not mark as pinned one by one.
    obstacles: Vec<bool>,
}

impl Assembled {
    /// Marks of the pinned vertices so far.
    fn pinned_marks(&self) -> Vec<bool> {
        let mut marks = vec![false; self.positions.len()];
        for &v in &self.fixed {
            marks[v] = true;
        }
        marks
    }
}

/// The vertices of sheet `k` of `sheets` (each its first vertex and, for a grid, its
/// size): from its first to the next sheet's first, or to `len` for the last.
fn sheet_vertices(
    sheets: &[(usize, Option<usize>)],
    k: usize,
    len: usize,
) -> std::ops::Range<usize> {
    sheets[k].0..sheets.get(k + 1).map_or(len, |&(next, _)| next)
}

impl MeshClothTask {
    fn assemble(&self) -> Result<Assembled, String> {
        let mut a = Assembled {
            positions: Vec::new(),
            triangles: Vec::new(),
            fixed: Vec::new(),
            velocities: Vec::new(),
            motions: Vec::new(),
            held: Vec::new(),
            obstacles: Vec::new(),
        };
        // Per sheet: its first vertex and, for a grid, its size; for an OBJ sheet, the
        // file's numbering of its vertices (its mesh taken out).
        let mut sheets: Vec<(usize, Option<usize>)> = Vec::new();
        let mut files: Vec<Option<NumberedObj>> = Vec::new();
        if self.sheets.is_empty() {
            return Err("sheets: at least one sheet is needed".into());
        }
        for (k, sheet) in self.sheets.iter().enumerate() {
            let offset = a.positions.len();
            sheets.push((
                offset,
                match sheet {
                    SheetSpec::Grid { size, .. } => Some(*size),
                    SheetSpec::Obj { .. } => None,
                },
            ));
            files.push(None);
            match sheet {
                SheetSpec::Grid {
                    size,
                    spacing,
                    origin,
                    u,
                    w,
                    pin_border,
                    pin_all,
                    velocity,
                } => {
                    let n = *size;
                    if n < 2 {
                        return Err(format!("sheets[{k}]: size = {n}, must be at least 2"));
                    }
                    // The side first: `n * n` of a side near `usize::MAX` wraps round to a
                    // small number in a release build (and panics in a debug one).
                    at_most(&format!("sheets[{k}]: size"), n, MAX_GRID_SIZE)?;
                    at_most(&format!("sheets[{k}]: vertices"), n * n, MAX_PARTICLES)?;
                    if !(spacing.is_finite() && *spacing > 0.0) {
                        return Err(format!(
                            "sheets[{k}]: spacing = {spacing}, must be finite and > 0"
                        ));
                    }
                    // `spacing` sets the sheet's size; a direction of another length
                    // would scale it again, unseen.
                    for (name, d) in [("u", u), ("w", w)] {
                        if !(d.is_finite() && (d.length() - 1.0).abs() <= UNIT_TOLERANCE) {
                            return Err(format!(
                                "sheets[{k}]: {name} = {d}, must be a unit vector (to \
                                 {UNIT_TOLERANCE:e}; its length is {})",
                                d.length()
                            ));
                        }
                    }
                    a.obstacles.extend(std::iter::repeat_n(*pin_all, n * n));
                    for i in 0..n {
                        for j in 0..n {
                            a.positions
                                .push(*origin + *spacing * (i as f64 * *u + j as f64 * *w));
                            a.velocities.push(*velocity);
                            let border = i == 0 || j == 0 || i == n - 1 || j == n - 1;
                            if *pin_all || (*pin_border && border) {
                                a.fixed.push(offset + i * n + j);
                            }
                        }
                    }
                    let grid = ClothGrid {
                        size: n,
                        ..ClothGrid::lab()
                    };
                    a.triangles
                        .extend(grid.triangles().into_iter().map(|t| t.map(|v| v + offset)));
                }
                SheetSpec::Obj {
                    path,
                    scale,
                    offset: shift,
                    fixed,
                    pin_all,
                    velocity,
                } => {
                    let file = self.base_dir.join(path);
                    let text = std::fs::read_to_string(&file)
                        .map_err(|e| format!("sheets[{k}]: {}: {e}", file.display()))?;
                    let mut read = parse_obj_numbered(&text)
                        .map_err(|e| format!("sheets[{k}]: {}: {e}", file.display()))?;
                    let mesh = std::mem::take(&mut read.mesh);
                    let len = mesh.positions.len();
                    // Pinned by the file's numbering (checked with `pin_all` too), or
                    // every vertex once.
                    let listed = fixed
                        .iter()
                        .map(|&v| read.vertex(v).map(|at| at + offset))
                        .collect::<Result<Vec<usize>, _>>()
                        .map_err(|e| format!("sheets[{k}]: fixed: {e}"))?;
                    if *pin_all {
                        a.fixed.extend(offset..offset + len);
                    } else {
                        a.fixed.extend(listed);
                    }
                    a.positions
                        .extend(mesh.positions.iter().map(|p| *scale * *p + *shift));
                    a.velocities.extend(std::iter::repeat_n(*velocity, len));
                    a.obstacles.extend(std::iter::repeat_n(*pin_all, len));
                    a.triangles
                        .extend(mesh.triangles.iter().map(|t| t.map(|v| v + offset)));
                    files[k] = Some(read);
                }
            }
        }
        at_most("sheets: vertices", a.positions.len(), MAX_PARTICLES)?;
        let mut pinned = a.pinned_marks();
        for (k, m) in self.moving_pins.iter().enumerate() {
            let Some(&(offset, size)) = sheets.get(m.sheet) else {
                return Err(format!(
                    "moving_pins[{k}]: sheet {} does not exist (there are {})",
                    m.sheet,
                    sheets.len()
                ));
            };
            let particles: Vec<usize> = if m.rows.is_empty() {
                sheet_vertices(&sheets, m.sheet, a.positions.len()).collect()
            } else {
                let Some(n) = size else {
                    return Err(format!(
                        "moving_pins[{k}]: sheet {} is not a Grid (rows are a grid's; \
                         leave rows out to move the whole sheet)",
                        m.sheet
                    ));
                };
                if let Some(&row) = m.rows.iter().find(|&&r| r >= n) {
                    return Err(format!(
                        "moving_pins[{k}]: row {row} does not exist (the grid has {n} rows)"
                    ));
                }
                m.rows
                    .iter()
                    .flat_map(|&i| (0..n).map(move |j| offset + i * n + j))
                    .collect()
            };
            for &p in &particles {
                if !std::mem::replace(&mut pinned[p], true) {
                    a.fixed.push(p);
                }
            }
            let motion = PinnedMotion {
                particles,
                point: m.point,
                axis: m.axis,
                angular_speed: m.angular_speed,
                velocity: m.velocity,
            };
            motion
                .validate()
                .map_err(|e| format!("moving_pins[{k}]: {e}"))?;
            a.motions.push(motion);
        }
        self.assemble_held(&mut a, &sheets, &files)?;
        Ok(a)
    }

    /// The vertices the limbs' attachments hold, by sheet and grid coordinates; they
    /// are pinned.
    fn assemble_held(
        &self,
        a: &mut Assembled,
        sheets: &[(usize, Option<usize>)],
        files: &[Option<NumberedObj>],
    ) -> Result<(), String> {
        let Some(limbs) = &self.limbs else {
            return Ok(());
        };
        if !limbs.attach.is_empty() && !self.moving_pins.is_empty() {
            return Err(
                "limbs: attach: given with moving_pins (pins move either with a joint or along a motion, in one task not both)"
                    .into(),
            );
        }
        // Marks of the vertices held so far, and of the pinned ones.
        let mut held = vec![false; a.positions.len()];
        let mut pinned = a.pinned_marks();
        for (k, at) in limbs.attach.iter().enumerate() {
            let err = |e: String| format!("limbs: attach[{k}]: {e}");
            let Some(&(offset, grid)) = sheets.get(at.sheet) else {
                return Err(err(format!(
                    "sheet = {} does not exist (there are {})",
                    at.sheet,
                    sheets.len()
                )));
            };
            let file = files[at.sheet].as_ref();
            let range = sheet_vertices(sheets, at.sheet, a.positions.len());
            let mut vertices = at.indices(grid, &a.positions[range], file).map_err(err)?;
            for v in &mut vertices {
                // Named as given: an OBJ sheet's vertex by the file's numbering.
                let local = file.map_or(*v, |f| f.file_vertices[*v]);
                *v += offset;
                if std::mem::replace(&mut held[*v], true) {
                    return Err(err(format!("{} is held twice", at.name(local, grid))));
                }
                if !std::mem::replace(&mut pinned[*v], true) {
                    a.fixed.push(*v);
                }
            }
            a.held.push(vertices);
        }
        Ok(())
    }

    /// Newton's settings for the task: the library's defaults with the task's cap,
    /// tolerance, split depth and friction lags.
    fn newton_settings(&self) -> NewtonSettings {
        NewtonSettings {
            max_iterations: self.max_iterations,
            tolerance: self.tolerance,
            max_split_depth: self.max_split_depth,
            friction_lags: self.friction_lags,
            ..NewtonSettings::default()
        }
    }

    /// The colliders with the limbs' capsules appended (posed at time 0, static until
    /// driven), and the limbs' animation.
    fn all_colliders(&self) -> Result<(Vec<Collider>, Option<Limbs>), String> {
        let mut colliders = self.colliders.clone();
        let Some(spec) = &self.limbs else {
            return Ok((colliders, None));
        };
        let mut limbs = spec
            .build(self.steps.saturating_add(1), &self.base_dir)
            .map_err(|e| format!("limbs: {e}"))?;
        let shapes = limbs.shapes_at(0.0).map_err(|e| format!("limbs: {e}"))?;
        colliders.extend(shapes.into_iter().map(Collider::fixed));
        Ok((colliders, Some(limbs)))
    }

    fn check(&self) -> Result<Assembled, String> {
        let a = self.assemble()?;
        at_most("steps", self.steps, MAX_STEPS)?;
        at_most("max_iterations", self.max_iterations, MAX_ITERATIONS)?;
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return Err(format!(
                "tolerance = {}, must be finite and > 0",
                self.tolerance
            ));
        }
        // The library's own check of its settings (a split depth past its limit), its
        // error told with the task's field, which has the setting's name.
        self.newton_settings()
            .validate()
            .map_err(|e| format!("{}: {}", e.field, e.reason))?;
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(format!("dt = {}, must be finite and > 0", self.dt));
        }
        sinew_spring_sim::check_time_step(self.dt).map_err(|e| format!("dt: {e}"))?;
        // Each lag of friction after the first may run another minimization.
        let work = a.positions.len() as f64
            * self.steps as f64
            * self.max_iterations.saturating_mul(self.friction_lags) as f64;
        if work > MAX_PARTICLE_STEPS {
            return Err(format!(
                "steps = {} of {} vertices at up to {} Newton iterations asks for {work:.2e} \
                 particle steps, above the limit of {MAX_PARTICLE_STEPS:.0e} (docs/scenes.md, \
                 \"Limits\")",
                self.steps,
                a.positions.len(),
                self.max_iterations.saturating_mul(self.friction_lags)
            ));
        }
        self.self_contact
            .validate()
            .map_err(|e| format!("self_contact: {e}"))?;
        // The distances' rounding, checked before the run as the library checks it when
        // contact is added (so validation alone finds it).
        check_contact_distance("dhat", self.self_contact.dhat, &a.positions)
            .map_err(|e| format!("self_contact: {e}"))?;
        let (colliders, _) = self.all_colliders()?;
        if !colliders.is_empty() {
            validate_colliders(&colliders).map_err(|e| format!("colliders: {e}"))?;
            self.contact
                .validate()
                .map_err(|e| format!("contact: {e}"))?;
            check_contact_distance("dhat", self.contact.dhat, &a.positions)
                .map_err(|e| format!("contact: {e}"))?;
            let mut fixed = vec![false; a.positions.len()];
            for &v in &a.fixed {
                if let Some(f) = fixed.get_mut(v) {
                    *f = true;
                }
            }
            check_start_outside(
                &colliders,
                self.contact.thickness,
                0.0,
                &a.positions,
                &fixed,
            )
            .map_err(|e| format!("colliders: {e}"))?;
        }
        Ok(a)
    }
}

/// The smallest distance among the vertex-triangle and edge-edge pairs (sharing no
/// vertex) closer than `reach`, if any.
fn min_pair_distance(prims: &Primitives, x: &[DVec3], reach: f64, skip: &[bool]) -> Option<f64> {
    candidates(prims, x, None, reach, skip)
        .into_iter()
        .map(|c| {
            let (kind, v) = c.kind_and_particles(prims);
            squared_distance(kind, &v.map(|i| x[i])).sqrt()
        })
        .filter(|&d| d < reach)
        .reduce(f64::min)
}

/// The most frames a picture animates.
const MAX_FRAMES: usize = 100;

impl TaskSpec for MeshClothTask {
    fn validate(&self) -> Result<(), String> {
        let a = self.check()?;
        TriangleMesh::new(a.positions, a.triangles).map_err(|e| format!("sheets: {e}"))?;
        Ok(())
    }

    // One run loop: building, stepping, the independent checks and the pictures read
    // best in order.
    #[allow(clippy::too_many_lines)]
    fn run(&self, ctx: &RunContext) -> Result<TaskOutput, String> {
        let a = self.check()?;
        let triangles = a.triangles.clone();
        let mesh =
            TriangleMesh::new(a.positions, a.triangles).map_err(|e| format!("sheets: {e}"))?;
        let model = MeshCloth {
            areal_density: self.areal_density,
            material: self.material,
            bending: self.bending.unwrap_or(Bending::None),
            fixed: a.fixed,
        }
        .build(&mesh)
        .map_err(|e| format!("cloth: {e}"))?;
        let newton = self.newton_settings();
        let mut integrator = self.integrator.build(&model, newton)?;
        // The colliders as the run goes: the limbs' capsules (after the first
        // `fixed_motion`) are driven before every step, and this copy takes each driven
        // collider the library returns (its pose within the step, for the pieces'
        // checks); at each step's end they are also checked against the animation's
        // own pose.
        let (mut colliders, mut limbs) = self.all_colliders()?;
        let fixed_motion = self.colliders.len();
        if !colliders.is_empty() {
            model
                .enable_contact(integrator.newton_mut(), colliders.clone(), self.contact)
                .map_err(|e| format!("contact: {e}"))?;
        }
        let stats = model
            .enable_self_contact(integrator.newton_mut(), self.self_contact)
            .map_err(|e| format!("self_contact: {e}"))?;
        let mut system = model.system.clone();
        let start = system.positions().to_vec();
        system
            .set_state(&start, &a.velocities)
            .map_err(|e| format!("initial state: {e}"))?;
        let mut pins = if a.motions.is_empty() {
            None
        } else {
            Some(PinDriver::new(&system, a.motions).map_err(|e| format!("moving_pins: {e}"))?)
        };
        // The vertices the limbs hold, carried with their joints' frames: a driver of
        // the step's rigid motions before every step.
        let mut held: Vec<Held> = match &limbs {
            Some(limbs) => limbs
                .held_joints()
                .iter()
                .zip(a.held)
                .map(|(&joint, vertices)| Held::new(limbs, joint, vertices, system.positions()))
                .collect(),
            None => Vec::new(),
        };
        let mut attach_error_max: Option<f64> = None;
        let prims = Primitives::new(&triangles);
        let reach = self.self_contact.dhat + self.self_contact.thickness;
        let no_skip = vec![false; system.len()];
        let springs: Vec<(usize, usize, f64)> = system
            .springs()
            .iter()
            .map(|s| (s.a, s.b, s.rest_length))
            .collect();
        // The pinned vertices the pictures mark: not an obstacle's (every one of them).
        let fixed: Vec<usize> = (0..system.len())
            .filter(|&i| system.fixed()[i] && !a.obstacles[i])
            .collect();
        let frame_every = self.steps.div_ceil(MAX_FRAMES).max(1);
        let mut frames: Vec<ClothFrame> = Vec::new();
        let mut frame_steps: Vec<usize> = Vec::new();
        let shapes = |colliders: &[Collider], t: f64| -> Vec<_> {
            colliders.iter().map(|c| c.at(t)).collect()
        };
        if ctx.keep_frames {
            frames.push(ClothFrame {
                positions: system.positions().to_vec(),
                colliders: shapes(&colliders, 0.0),
            });
            frame_steps.push(0);
        }
        let mut csv = String::from(
            "step,time,iterations,residual,self_contact_pairs,min_gap,intersections\n",
        );
        let mut energy = vec![(0.0, system.energies().total())];
        let mut iteration_series = Vec::with_capacity(self.steps);
        let mut step_ms = Vec::with_capacity(self.steps);
        let (mut iterations_total, mut iterations_max) = (0usize, 0usize);
        let mut pairs_max = 0usize;
        let mut friction_pairs_max = 0usize;
        let mut intersections = 0usize;
        let mut first_intersection: Option<(usize, (usize, usize))> = None;
        let mut min_self_distance: Option<f64> = None;
        let mut min_collider_distance: Option<f64> = None;
        let mut penetrations = 0usize;
        let mut swept_passes = 0usize;
        let mut max_path_depth: Option<f64> = None;
        // The most a piece's path went beyond a collider's allowance.
        let mut path_excess: Option<f64> = None;
        let mut previous = system.positions().to_vec();
        // The guarantees hold at every piece's end state, and the paths a moving
        // collider must not cross are those of each piece (one piece for a step taken
        // whole): the integrator records the pieces' end states for these checks.
        integrator.newton_mut().record_piece_ends(true);
        let mut progress = ctx.progress(&self.name, self.steps);
        // The limbs' poses at the current step's end (the targets of its drives).
        let mut targets: Vec<Shape> = Vec::new();
        for step in 0..self.steps {
            if let Some(limbs) = &mut limbs {
                targets = limbs.shapes_at(integrator.time() + self.dt)?;
                for (k, &target) in targets.iter().enumerate() {
                    let drive = Drive::To {
                        target,
                        duration: self.dt,
                    };
                    colliders[fixed_motion + k] = integrator
                        .newton_mut()
                        .drive_collider(fixed_motion + k, &drive)
                        .map_err(|e| format!("step {step}: limbs: capsules[{k}]: {e}"))?;
                }
                if !held.is_empty() {
                    let motions = held
                        .iter_mut()
                        .map(|h| h.step_motion(limbs, self.dt))
                        .collect();
                    pins = Some(
                        PinDriver::new(&system, motions)
                            .map_err(|e| format!("step {step}: limbs: attach: {e}"))?,
                    );
                }
            }
            let started = Instant::now();
            let report = match &mut pins {
                Some(driver) => driver.step(&mut *integrator, &mut system, self.dt),
                None => integrator.take_step(&mut system, self.dt),
            }
            .map_err(|e| format!("step {step}: {e}"))?;
            step_ms.push(1e3 * started.elapsed().as_secs_f64());
            progress.inc();
            iterations_total += report.iterations;
            iterations_max = iterations_max.max(report.iterations);
            pairs_max = pairs_max.max(stats.active_pairs());
            friction_pairs_max = friction_pairs_max.max(stats.friction_pairs());
            let x = system.positions();
            // The held vertices against their joints' frames at the step's end (the
            // animation's, from forward kinematics, not the library's pinned motion).
            for h in &held {
                let e = h.error(x);
                attach_error_max = Some(attach_error_max.map_or(e, |m: f64| m.max(e)));
            }
            if x.iter().any(|p| !p.is_finite()) {
                return Err(format!("step {step}: a non-finite position"));
            }
            let pieces = integrator.newton().piece_ends().expect("recording");
            let mut meeting = Vec::new();
            for (_, y) in pieces.iter().take(pieces.len().saturating_sub(1)) {
                meeting.extend(intersecting_pairs(y, &triangles));
            }
            meeting.extend(intersecting_pairs(x, &triangles));
            if let Some(&pair) = meeting.first() {
                first_intersection.get_or_insert((step, pair));
            }
            intersections += meeting.len();
            if let Some(d) = min_pair_distance(&prims, x, reach, &no_skip) {
                min_self_distance = Some(min_self_distance.map_or(d, |m: f64| m.min(d)));
            }
            let time = (step + 1) as f64 * self.dt;
            // Every piece's end state (the step's own end is the last piece's).
            let mut outside = |shape: &Shape, y: &[DVec3]| {
                for (p, pinned) in y.iter().zip(system.fixed()) {
                    if *pinned {
                        continue;
                    }
                    let d = signed_distance(shape, *p, self.contact.thickness).distance;
                    min_collider_distance =
                        Some(min_collider_distance.map_or(d, |m: f64| m.min(d)));
                    penetrations += usize::from(d <= 0.0);
                }
            };
            for (end, y) in pieces.iter() {
                for c in &colliders {
                    outside(&c.at(end), y);
                }
            }
            // The limbs where the animation puts them at the step's end (the drives'
            // targets, from forward kinematics here), not the library's driven colliders.
            for shape in &targets {
                outside(shape, x);
            }
            swept_passes += report.swept_passes;
            let paths = super::deepest_swept_path(
                &colliders,
                (self.contact.thickness, self.contact.dhat),
                (time - self.dt, &previous),
                pieces.iter(),
                system.fixed(),
            );
            if let Some(d) = paths {
                max_path_depth = Some(max_path_depth.map_or(d.depth, |m| m.max(d.depth)));
                path_excess = Some(path_excess.map_or(d.excess, |m| m.max(d.excess)));
            }
            // Every step's end starts the next step's paths, whether or not a collider
            // moved in this one (a limb held still, then moving).
            previous.copy_from_slice(x);
            csv.push_str(&format!(
                "{},{time},{},{},{},{},{}\n",
                step + 1,
                report.iterations,
                report.residual,
                stats.active_pairs(),
                stats.min_gap(),
                meeting.len()
            ));
            energy.push((time, report.energy_after.total()));
            iteration_series.push((time, report.iterations as f64));
            if ctx.keep_frames && ((step + 1) % frame_every == 0 || step + 1 == self.steps) {
                frames.push(ClothFrame {
                    positions: x.to_vec(),
                    colliders: shapes(&colliders, time),
                });
                frame_steps.push(step + 1);
            }
        }
        drop(progress);
        let vertices = system.len();
        let free: Vec<f64> = system
            .positions()
            .iter()
            .zip(&start)
            .zip(system.fixed())
            .filter(|(_, pinned)| !**pinned)
            .map(|((x, x0), _)| (*x - *x0).length())
            .collect();
        let free_mean_displacement = if free.is_empty() {
            0.0
        } else {
            free.iter().sum::<f64>() / free.len() as f64
        };
        let median = {
            let mut sorted = step_ms.clone();
            sorted.sort_by(f64::total_cmp);
            if sorted.is_empty() {
                0.0
            } else {
                sorted[sorted.len() / 2]
            }
        };
        let mut failures = Vec::new();
        if let Some((step, (p, q))) = first_intersection {
            failures.push(format!(
                "{intersections} triangle pair(s) passing through each other over the run (first: triangles {p} and {q} after step {})",
                step + 1
            ));
        }
        if penetrations > 0 {
            failures.push(format!(
                "{penetrations} vertex-collider pairs at distance <= 0 over the run"
            ));
        }
        super::moving_body_failures("vertex", path_excess, attach_error_max, &mut failures);
        if swept_passes > 0 {
            failures.push(format!(
                "{swept_passes} piece(s) kept with a vertex passed by a moving collider"
            ));
        }
        let metrics = MeshClothMetrics {
            vertices,
            triangles: triangles.len(),
            steps: self.steps,
            newton_iterations_total: iterations_total,
            newton_iterations_max: iterations_max,
            time_per_step_ms_median: median,
            time_per_vertex_step_us_median: 1e3 * median / vertices as f64,
            self_contact_pairs_max: pairs_max,
            self_friction_pairs_max: friction_pairs_max,
            free_mean_displacement,
            intersections,
            min_self_distance,
            min_distance: min_collider_distance,
            penetrations,
            swept_passes,
            max_path_depth,
            reach_error_max: limbs.as_ref().and_then(Limbs::reach_error_max),
            attach_error_max,
            kappa: stats.kappa(),
        };
        let headline = format!(
            "{} vertices, {} steps: {} Newton iterations (max {}), {} self-contact pairs at most, {} intersections, {:.1} ms/step",
            vertices,
            self.steps,
            iterations_total,
            iterations_max,
            pairs_max,
            intersections,
            median
        );
        let pictures = if ctx.keep_frames {
            Pictures::Cloth(ClothPictures {
                integrator: format!("{} with self-contact", self.integrator.label()),
                springs,
                fixed,
                track: frames.clone(),
                track_steps: frame_steps,
                frames,
                dt: self.dt,
                energy,
                iterations: iteration_series,
            })
        } else {
            Pictures::None
        };
        Ok(TaskOutput {
            metrics: TaskMetrics::MeshCloth(metrics),
            headline,
            failures,
            table: Csv {
                suffix: "steps.csv",
                text: csv,
            },
            pictures,
        })
    }
}
