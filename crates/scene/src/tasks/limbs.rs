//! Colliders on an animated skeleton: capsules along chosen bones of a skeleton whose
//! pose is keyed in time, driven before every step to where the animation puts them at
//! the step's end ([`sinew_spring_sim::contact::Drive::To`]). This is how a cloth task
//! puts a sleeve on a moving arm.
//!
//! The animation: key poses at increasing times; between two keys every joint's local
//! rotation is the spherical interpolation (shortest arc) of the two keys' rotations at
//! the fraction of the interval elapsed; before the first key the first pose holds,
//! after the last the last. Each capsule runs from one joint's position to another's
//! (forward kinematics of the interpolated pose) with a radius. A key may also move the
//! whole skeleton (root motion): that translation is linear between keys.
//!
//! A reach puts inverse kinematics on top: a chain of the skeleton reaches for a target
//! keyed in time (linear between keys, held outside them), optionally with a pole. The
//! pose at time `t` is the chain's solve for the target at `t`, started from the key pose
//! at `t` (not from the previous call's answer), so the animation stays a function of
//! time: asking for the same `t` twice gives the same capsules, whatever was asked in
//! between.
//!
//! The animation is key poses on a given skeleton, or a BVH clip (its skeleton, each
//! frame a key pose); joints are named by index or by name. Attachments name grid
//! particles a joint holds; the cloth runner carries them with the joint's frame
//! ([`Limbs::joint_frame`]).

use crate::limits::{MAX_JOINTS, at_most, check_solve_work};
use crate::spec::{JointRotation, SkeletonSpec, build_pose};
use serde::Deserialize;
use sinew_ik::SolverOptions;
use sinew_io::obj::NumberedObj;
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::{Chain, EffectorGoal, IkProblem, IkSolver, IkState, SolveSettings};
use sinew_skeleton::{GlobalPose, Pose, Skeleton};
use sinew_spring_sim::PinnedMotion;
use sinew_spring_sim::contact::Shape;
use sinew_spring_sim::contact::collider::TARGET_SIZE_TOLERANCE;
use std::path::Path;

/// The most key poses and capsules a scene may give (each key holds a pose of the
/// whole skeleton).
pub const MAX_KEYS: usize = 100_000;

/// An animated skeleton carrying capsule colliders, in a scene: a skeleton with key
/// poses, or a motion clip read from a file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimbsSpec {
    /// The skeleton (its rest pose is every rotation the identity); with `keys`, unless
    /// `clip` gives both.
    #[serde(default)]
    pub skeleton: Option<SkeletonSpec>,
    /// Key poses, at strictly increasing times (at least one, with `skeleton`).
    #[serde(default)]
    pub keys: Vec<KeyPose>,
    /// A BVH file whose skeleton and frames are the skeleton and the key poses (instead
    /// of `skeleton` and `keys`).
    #[serde(default)]
    pub clip: Option<LimbClip>,
    /// The capsules, each along two joints (at least one).
    pub capsules: Vec<LimbCapsule>,
    /// A chain that reaches for a keyed target on top of the key poses (default: none).
    #[serde(default)]
    pub reach: Option<ReachSpec>,
    /// Particles of a grid cloth held by joints (default: none): pinned, and carried
    /// rigidly with the joint's frame (a cape's top edge on the shoulders).
    #[serde(default)]
    pub attach: Vec<Attachment>,
}

/// Particles of a grid cloth carried by a joint.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Attachment {
    /// The joint whose frame carries them (an index or a name).
    pub joint: JointRef,
    /// The grid sheet they are on (a `MeshCloth` task's `sheets` index; default 0, the
    /// only grid of a `Cloth` task).
    #[serde(default)]
    pub sheet: usize,
    /// The particles of a grid, by grid coordinates `(i, j)` as in the grid's `fixed`;
    /// they are pinned. Give these or `vertices`.
    #[serde(default)]
    pub particles: Vec<(usize, usize)>,
    /// The particles by index in their sheet (a grid's `i * size + j`, an explicit
    /// system's particle, an OBJ sheet's vertex by its `v` statement's index in the file,
    /// from 0); they are pinned.
    #[serde(default)]
    pub vertices: Vec<usize>,
    /// Every particle of the sheet whose start position is within `radius` of `point`
    /// (how to pick the vertices of a mesh read from a file); they are pinned.
    #[serde(default)]
    pub near: Option<Near>,
}

/// A ball around a point, choosing the particles that start inside it.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Near {
    /// The ball's centre (scene units, the world frame).
    pub point: DVec3,
    /// Its radius, positive and finite.
    pub radius: f64,
}

impl Attachment {
    /// The held particles' indices in their sheet, whose particles start at `start`
    /// (`grid`: its size when it is a grid), in the order given (`near`: in index
    /// order), or what is wrong. Exactly one of `particles`, `vertices` and `near` is
    /// given.
    pub(crate) fn indices(
        &self,
        grid: Option<usize>,
        start: &[DVec3],
        file: Option<&NumberedObj>,
    ) -> Result<Vec<usize>, String> {
        let count = start.len();
        let given = [
            !self.particles.is_empty(),
            !self.vertices.is_empty(),
            self.near.is_some(),
        ];
        match given.iter().filter(|&&g| g).count() {
            0 => return Err("particles, vertices, near: none given (give one)".into()),
            1 => {}
            _ => {
                return Err(
                    "particles, vertices, near: more than one given (grid coordinates, indices or a ball, one of them)"
                        .into(),
                );
            }
        }
        if let Some(Near { point, radius }) = self.near {
            if !point.is_finite() {
                return Err(format!("near: point = {point} is not finite"));
            }
            if !(radius.is_finite() && radius > 0.0) {
                return Err(format!(
                    "near: radius = {radius} is not positive and finite"
                ));
            }
            let inside: Vec<usize> = (0..count)
                .filter(|&v| start[v].distance(point) <= radius)
                .collect();
            if inside.is_empty() {
                return Err(format!(
                    "near: no particle starts within {radius} of {point}"
                ));
            }
            return Ok(inside);
        }
        if self.particles.is_empty() {
            return self
                .vertices
                .iter()
                .map(|&v| match file {
                    // An OBJ sheet's vertices are named by the file's numbering.
                    Some(file) => file.vertex(v),
                    None if v < count => Ok(v),
                    None => Err(format!("vertex {v} does not exist (there are {count})")),
                })
                .collect();
        }
        let Some(n) = grid else {
            return Err("particles: grid coordinates need a Grid (give vertices or near)".into());
        };
        self.particles
            .iter()
            .map(|&(i, j)| {
                if i < n && j < n {
                    Ok(i * n + j)
                } else {
                    Err(format!("particle ({i}, {j}) is outside the {n} x {n} grid"))
                }
            })
            .collect()
    }

    /// How a held particle of index `v` in its sheet is named in errors: by its grid
    /// coordinates when it was given by them.
    pub(crate) fn name(&self, v: usize, grid: Option<usize>) -> String {
        match grid {
            Some(n) if !self.particles.is_empty() => format!("particle ({}, {})", v / n, v % n),
            _ => format!("vertex {v}"),
        }
    }
}

/// The most a held particle may drift from its joint's frame over a run, m (the runners
/// fail a task beyond it).
pub(crate) const ATTACH_TOLERANCE: f64 = 1e-9;

/// Particles held by a joint, as a runner carries them: their place in the joint's
/// frame at the start, and the frame at the end of the step driven last.
#[derive(Debug)]
pub(crate) struct Held {
    joint: usize,
    particles: Vec<usize>,
    local: Vec<DVec3>,
    frame: (DVec3, DQuat),
}

impl Held {
    /// Particles `particles` (indices into `positions`) held by `joint`, whose frame is
    /// the one of `limbs`' last pose.
    pub(crate) fn new(
        limbs: &Limbs,
        joint: usize,
        particles: Vec<usize>,
        positions: &[DVec3],
    ) -> Self {
        let (x, r) = limbs.joint_frame(joint);
        let to_local = r.inverse();
        let local = particles
            .iter()
            .map(|&p| to_local * (positions[p] - x))
            .collect();
        Self {
            joint,
            particles,
            local,
            frame: (x, r),
        }
    }

    /// The rigid motion that carries the particles over the next step of `dt`, from the
    /// frame of the last step's end to the frame of `limbs`' last pose (which becomes
    /// the frame of this step's end): the turn about the joint's start position, and
    /// its move, so `x1 + r1 l = x0 + (r1 r0^-1)(x0 + r0 l - x0) + (x1 - x0)`.
    pub(crate) fn step_motion(&mut self, limbs: &Limbs, dt: f64) -> PinnedMotion {
        let ((x0, r0), (x1, r1)) = (self.frame, limbs.joint_frame(self.joint));
        self.frame = (x1, r1);
        let (axis, angle) = (r1 * r0.inverse()).normalize().to_axis_angle();
        PinnedMotion {
            particles: self.particles.clone(),
            point: x0,
            axis,
            angular_speed: angle / dt,
            velocity: (x1 - x0) / dt,
        }
    }

    /// The largest distance of a held particle in `positions` from where the frame of
    /// the step's end puts it.
    pub(crate) fn error(&self, positions: &[DVec3]) -> f64 {
        let (x, r) = self.frame;
        self.particles
            .iter()
            .zip(&self.local)
            .map(|(&p, &l)| positions[p].distance(x + r * l))
            .fold(0.0, f64::max)
    }
}

/// A motion clip as the limbs' animation: the file's skeleton, and each of its frames a
/// key pose (its joints' rotations and the root's translation).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimbClip {
    /// The BVH file, relative to the scene file's directory.
    pub file: String,
    /// The time of the file's first frame, seconds (default 0); frame `k` is at
    /// `start + k * frame_time`.
    #[serde(default)]
    pub start: f64,
    /// Use only the first this many frames (default: all of them).
    #[serde(default)]
    pub frames: Option<usize>,
}

/// A joint, by its index or, in a skeleton whose joints have names (a clip's), by name.
#[derive(Clone, Debug, Deserialize)]
#[serde(untagged)]
pub enum JointRef {
    /// The joint's index.
    Index(usize),
    /// The joint's name.
    Name(String),
}

impl JointRef {
    /// The joint's index in `skeleton`, or what is wrong (`field` names the item).
    fn resolve(&self, skeleton: &Skeleton, field: &str) -> Result<usize, String> {
        match self {
            Self::Index(j) if *j < skeleton.len() => Ok(*j),
            Self::Index(j) => Err(format!(
                "{field} = {j} is out of range (the skeleton has {} joints)",
                skeleton.len()
            )),
            Self::Name(name) => skeleton
                .joint_by_name(name)
                .ok_or_else(|| format!("{field} = {name:?}: no joint has that name")),
        }
    }
}

/// A reach's chain: its base joint and the effector below it.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReachChain {
    /// The base joint (its position does not move).
    pub base: JointRef,
    /// The effector joint.
    pub effector: JointRef,
}

/// A chain of the skeleton solved by inverse kinematics for a target keyed in time.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReachSpec {
    /// The chain's base and effector joints.
    pub chain: ReachChain,
    /// The solver and its options, from the library's registry: `Ccd(...)` or
    /// `Fabrik(...)`.
    pub solver: SolverOptions,
    /// Iteration cap and tolerance of each solve (default 100 and 1e-6).
    #[serde(default)]
    pub settings: SolveSettings,
    /// Where the effector should be, at strictly increasing times (at least one).
    pub targets: Vec<KeyTarget>,
}

/// A target of a reach at a time.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyTarget {
    /// Seconds from the start of the run.
    pub time: f64,
    /// Where the effector should be (world frame).
    pub position: DVec3,
    /// A point the chain's bend plane should turn towards (world frame; default none).
    /// Either every target has one or none has.
    #[serde(default)]
    pub pole: Option<DVec3>,
}

/// A key pose: joint rotations (as in an `Fk` task's `pose`) at a time.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyPose {
    /// Seconds from the start of the run.
    pub time: f64,
    /// Rotations of the joints that are not at rest (default: the rest pose).
    #[serde(default)]
    pub pose: Vec<JointRotation>,
    /// A translation of the whole skeleton from where its joints' offsets put it (root
    /// motion, scene units; default none).
    #[serde(default)]
    pub root: DVec3,
}

/// A capsule from joint `from` to joint `to` (forward kinematics positions).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimbCapsule {
    /// The joint at the capsule's end `a`.
    pub from: JointRef,
    /// The joint at its end `b`.
    pub to: JointRef,
    /// Its radius, positive and finite.
    pub radius: f64,
}

/// A built [`LimbsSpec`]: poses the capsules at any time.
#[derive(Debug)]
pub struct Limbs {
    skeleton: Skeleton,
    keys: Vec<Key>,
    capsules: Vec<(usize, usize, f64)>,
    /// Each capsule's length in the first key pose: a drive cannot stretch a collider.
    lengths: Vec<f64>,
    reach: Option<Reach>,
    /// The attachments' joints, in the scene's order.
    attach: Vec<usize>,
    pose: Pose,
    global: GlobalPose,
    /// The root translation of the last pose.
    root: DVec3,
}

/// A key pose as built: its time, the joints' rotations and the root's translation.
type Key = (f64, Pose, DVec3);

/// A built [`ReachSpec`].
struct Reach {
    chain: Chain,
    solver: Box<dyn IkSolver>,
    settings: SolveSettings,
    targets: Vec<KeyTarget>,
    /// The largest effector-to-target distance after a solve, so far.
    error_max: Option<f64>,
}

impl std::fmt::Debug for Reach {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reach")
            .field("chain", &self.chain)
            .field("solver", &self.solver.name())
            .field("settings", &self.settings)
            .field("targets", &self.targets)
            .field("error_max", &self.error_max)
            .finish()
    }
}

/// Where `t` falls among `keys` at strictly increasing times (`time` reads one; at
/// least one key): `(k, k, 0)` before the first key or from the last on (that key
/// holds), else `(k, k + 1, s)` with `s` the fraction of the interval elapsed.
fn bracket<T>(keys: &[T], time: impl Fn(&T) -> f64, t: f64) -> (usize, usize, f64) {
    let next = keys.partition_point(|k| time(k) <= t);
    if next == 0 || next == keys.len() {
        let held = next.min(keys.len() - 1);
        return (held, held, 0.0);
    }
    let (t0, t1) = (time(&keys[next - 1]), time(&keys[next]));
    (next - 1, next, (t - t0) / (t1 - t0))
}

/// Checks that keyed times are finite and strictly increasing; `what` names the list.
fn check_times(what: &str, times: impl Iterator<Item = f64>) -> Result<(), String> {
    let mut previous: Option<f64> = None;
    for (k, time) in times.enumerate() {
        if !time.is_finite() {
            return Err(format!("{what}[{k}]: time = {time} is not finite"));
        }
        if let Some(previous) = previous
            && time <= previous
        {
            return Err(format!(
                "{what}[{k}]: time = {time} is not after the previous key's ({previous})"
            ));
        }
        previous = Some(time);
    }
    Ok(())
}

impl ReachSpec {
    /// Builds the reach on `skeleton` for `solves` solves, or says which item is wrong
    /// (prefixed `reach: `).
    fn build(&self, skeleton: &Skeleton, solves: usize) -> Result<Reach, String> {
        let err = |e: String| format!("reach: {e}");
        let base = self
            .chain
            .base
            .resolve(skeleton, "chain: base")
            .map_err(err)?;
        let effector = self
            .chain
            .effector
            .resolve(skeleton, "chain: effector")
            .map_err(err)?;
        let chain = Chain::new(skeleton, base, effector).map_err(|e| err(format!("chain: {e}")))?;
        let solver = self
            .solver
            .build()
            .map_err(|e| err(format!("solver: {e}")))?;
        self.settings
            .validate()
            .map_err(|e| err(format!("settings: {e}")))?;
        check_solve_work(
            solves,
            self.settings.max_iterations,
            1,
            chain.joints().len(),
        )
        .map_err(err)?;
        at_most("targets", self.targets.len(), MAX_KEYS).map_err(err)?;
        if self.targets.is_empty() {
            return Err(err("targets: none given (at least one is needed)".into()));
        }
        check_times("targets", self.targets.iter().map(|t| t.time)).map_err(err)?;
        if let Some(k) = self.targets.iter().position(|t| !t.position.is_finite()) {
            return Err(err(format!(
                "targets[{k}]: position = {} is not finite",
                self.targets[k].position
            )));
        }
        let poles = self.targets[0].pole.is_some();
        for (k, target) in self.targets.iter().enumerate() {
            match target.pole {
                Some(pole) if !pole.is_finite() => {
                    return Err(err(format!("targets[{k}]: pole = {pole} is not finite")));
                }
                // Between a target with a pole and one without, the pole is undefined.
                Some(_) if !poles => {
                    return Err(err(format!(
                        "targets[{k}]: pole given, but targets[0] has none (either every target has a pole or none has)"
                    )));
                }
                None if poles => {
                    return Err(err(format!(
                        "targets[{k}]: no pole, but targets[0] has one (either every target has a pole or none has)"
                    )));
                }
                _ => {}
            }
        }
        Ok(Reach {
            chain,
            solver,
            settings: self.settings,
            targets: self.targets.clone(),
            error_max: None,
        })
    }
}

impl Reach {
    /// The target and its pole at `t`: linear between keys, the nearest key's outside
    /// them.
    fn target_at(&self, t: f64) -> (DVec3, Option<DVec3>) {
        let (k0, k1, s) = bracket(&self.targets, |g| g.time, t);
        let (g0, g1) = (self.targets[k0], self.targets[k1]);
        if k0 == k1 {
            return (g0.position, g0.pole);
        }
        let pole = g0.pole.zip(g1.pole).map(|(a, b)| a.lerp(b, s));
        (g0.position.lerp(g1.position, s), pole)
    }
}

impl LimbsSpec {
    /// Builds the animation for a run that asks for its capsules `solves` times (each
    /// may run the reach's solver once), or says which item is wrong (`keys[2]: ...`,
    /// `capsules[0]: ...`, `reach: targets[1]: ...`).
    pub fn build(&self, solves: usize, base_dir: &Path) -> Result<Limbs, String> {
        let (skeleton, keys) = match (&self.clip, &self.skeleton) {
            (Some(_), Some(_)) => {
                return Err(
                    "clip: given with a skeleton (give a clip, or a skeleton with keys)".into(),
                );
            }
            (Some(_), None) if !self.keys.is_empty() => {
                return Err("clip: given with keys (a clip's frames are its key poses)".into());
            }
            (Some(clip), None) => clip.read(base_dir)?,
            (None, None) => {
                return Err("skeleton: none given (give a skeleton with keys, or a clip)".into());
            }
            (None, Some(skeleton)) => {
                let skeleton = skeleton.build()?;
                let keys = self.keys(&skeleton)?;
                (skeleton, keys)
            }
        };
        at_most("capsules", self.capsules.len(), MAX_KEYS)?;
        if self.capsules.is_empty() {
            return Err("capsules: none given (at least one capsule is needed)".into());
        }
        let mut capsules = Vec::with_capacity(self.capsules.len());
        for (c, capsule) in self.capsules.iter().enumerate() {
            let from = capsule
                .from
                .resolve(&skeleton, "from")
                .map_err(|e| format!("capsules[{c}]: {e}"))?;
            let to = capsule
                .to
                .resolve(&skeleton, "to")
                .map_err(|e| format!("capsules[{c}]: {e}"))?;
            if !(capsule.radius.is_finite() && capsule.radius > 0.0) {
                return Err(format!(
                    "capsules[{c}]: radius = {} is not positive and finite",
                    capsule.radius
                ));
            }
            capsules.push((from, to, capsule.radius));
        }
        let reach = self
            .reach
            .as_ref()
            .map(|r| r.build(&skeleton, solves))
            .transpose()?;
        let mut attach = Vec::with_capacity(self.attach.len());
        for (k, a) in self.attach.iter().enumerate() {
            let joint = a
                .joint
                .resolve(&skeleton, "joint")
                .map_err(|e| format!("attach[{k}]: {e}"))?;
            attach.push(joint);
        }
        let pose = skeleton.rest_pose();
        let mut limbs = Limbs {
            skeleton,
            keys,
            capsules,
            lengths: Vec::new(),
            reach,
            attach,
            pose,
            global: GlobalPose::default(),
            root: DVec3::ZERO,
        };
        let first = limbs.keys[0].0;
        let root = limbs.pose_at(first);
        limbs.lengths = limbs
            .place(root)
            .map_err(|e| format!("keys[0]: {e}"))?
            .iter()
            .map(|shape| match *shape {
                Shape::Capsule { a, b, .. } => (b - a).length(),
                _ => 0.0,
            })
            .collect();
        Ok(limbs)
    }
}

impl LimbsSpec {
    /// The key poses given in the scene, checked against `skeleton`.
    fn keys(&self, skeleton: &Skeleton) -> Result<Vec<Key>, String> {
        at_most("keys", self.keys.len(), MAX_KEYS)?;
        at_most(
            "keys x joints",
            self.keys.len().saturating_mul(skeleton.len()),
            MAX_JOINTS,
        )?;
        if self.keys.is_empty() {
            return Err("keys: none given (at least one key pose is needed)".into());
        }
        check_times("keys", self.keys.iter().map(|k| k.time))?;
        let mut keys = Vec::with_capacity(self.keys.len());
        for (k, key) in self.keys.iter().enumerate() {
            if !key.root.is_finite() {
                return Err(format!("keys[{k}]: root = {} is not finite", key.root));
            }
            let pose = build_pose(skeleton, &key.pose).map_err(|e| format!("keys[{k}]: {e}"))?;
            keys.push((key.time, pose, key.root));
        }
        Ok(keys)
    }
}

impl LimbClip {
    /// The file's skeleton and its frames as key poses.
    fn read(&self, base_dir: &Path) -> Result<(Skeleton, Vec<Key>), String> {
        let path = base_dir.join(&self.file);
        let text = std::fs::read_to_string(&path)
            .map_err(|e| format!("clip: file {}: {e}", path.display()))?;
        let bvh = sinew_io::parse_bvh(&text)
            .map_err(|e| format!("clip: file {}: {e}", path.display()))?;
        let available = bvh.frames.len();
        let count = self.frames.unwrap_or(available);
        if count == 0 || count > available {
            return Err(format!(
                "clip: frames = {count}, must be 1..={available} (the file's frames)"
            ));
        }
        if !self.start.is_finite() {
            return Err(format!("clip: start = {} is not finite", self.start));
        }
        at_most(
            "clip: frames x joints",
            count.saturating_mul(bvh.skeleton.len()),
            MAX_JOINTS,
        )?;
        let keys: Vec<_> = bvh.frames[..count]
            .iter()
            .enumerate()
            .map(|(k, f)| {
                (
                    self.start + k as f64 * bvh.frame_time,
                    f.pose.clone(),
                    f.root_translation,
                )
            })
            .collect();
        // A frame time of 0 (or one too small to tell frames apart at `start`) leaves no
        // interval to interpolate over.
        check_times("clip: frame", keys.iter().map(|k| k.0))?;
        Ok((bvh.skeleton, keys))
    }
}

impl Limbs {
    /// The number of capsules.
    #[must_use]
    pub fn len(&self) -> usize {
        self.capsules.len()
    }

    /// Whether there are none (never, once built).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.capsules.is_empty()
    }

    /// The largest distance between the reach's effector and its target after a solve,
    /// over the calls so far (`None` without a reach or before the first call).
    #[must_use]
    pub fn reach_error_max(&self) -> Option<f64> {
        self.reach.as_ref().and_then(|r| r.error_max)
    }

    /// The capsules posed at time `t`, in the scene's order.
    ///
    /// # Errors
    /// Forward kinematics' or the reach solver's refusal, as text (not expected: the
    /// pose has the skeleton's size and unit rotations, and the targets were checked).
    pub fn shapes_at(&mut self, t: f64) -> Result<Vec<Shape>, String> {
        let root = self.pose_at(t);
        if let Some(reach) = &mut self.reach {
            // The skeleton's frame is the world's moved by `root`: the goal in that frame.
            let (target, pole) = reach.target_at(t);
            let goals = [EffectorGoal {
                pole: pole.map(|p| p - root),
                ..EffectorGoal::at(reach.chain.effector(), target - root)
            }];
            let problem = IkProblem::new(&self.skeleton, &reach.chain, &goals, reach.settings);
            let report = reach
                .solver
                .solve(
                    &problem,
                    &mut IkState::new(&mut self.pose, &mut self.global),
                )
                .map_err(|e| format!("limbs at t = {t}: reach: {e}"))?;
            reach.error_max = Some(
                reach
                    .error_max
                    .map_or(report.error, |m| m.max(report.error)),
            );
        }
        let shapes = self
            .place(root)
            .map_err(|e| format!("limbs at t = {t}: {e}"))?;
        // A capsule across a joint that turns (from the hips to the neck, say) changes
        // length; the library's drive refuses that, and here the scene is named.
        for (k, (shape, &first)) in shapes.iter().zip(&self.lengths).enumerate() {
            if let Shape::Capsule { a, b, radius } = *shape {
                let length = (b - a).length();
                if (length - first).abs() > TARGET_SIZE_TOLERANCE * first.max(radius) {
                    let (from, to, _) = self.capsules[k];
                    return Err(format!(
                        "limbs at t = {t}: capsules[{k}]: {} and {} are {length} apart, \
                         {first} in the first key pose: a capsule must keep its length (put \
                         it on one bone)",
                        self.skeleton.label(from),
                        self.skeleton.label(to)
                    ));
                }
            }
        }
        Ok(shapes)
    }

    /// The joint of each attachment, in the scene's order.
    #[must_use]
    pub fn held_joints(&self) -> &[usize] {
        &self.attach
    }

    /// A joint's global position and rotation in the pose of the last
    /// [`Limbs::shapes_at`] (root motion included).
    #[must_use]
    pub fn joint_frame(&self, joint: usize) -> (DVec3, DQuat) {
        (
            self.global.positions[joint] + self.root,
            self.global.rotations[joint],
        )
    }

    /// The capsules on the current pose moved by `root` (forward kinematics).
    fn place(&mut self, root: DVec3) -> Result<Vec<Shape>, String> {
        self.root = root;
        self.skeleton
            .forward_kinematics(&self.pose, &mut self.global)
            .map_err(|e| e.to_string())?;
        let x = &self.global.positions;
        Ok(self
            .capsules
            .iter()
            .map(|&(from, to, radius)| Shape::Capsule {
                a: x[from] + root,
                b: x[to] + root,
                radius,
            })
            .collect())
    }

    /// Sets `self.pose` to the animation's pose at `t` and returns its root translation.
    fn pose_at(&mut self, t: f64) -> DVec3 {
        let (k0, k1, s) = bracket(&self.keys, |key| key.0, t);
        let ((_, p0, r0), (_, p1, r1)) = (&self.keys[k0], &self.keys[k1]);
        if k0 == k1 {
            self.pose.rotations.clone_from(&p0.rotations);
            return *r0;
        }
        for ((q, a), b) in self
            .pose
            .rotations
            .iter_mut()
            .zip(&p0.rotations)
            .zip(&p1.rotations)
        {
            *q = a.slerp(*b, s).normalize();
        }
        r0.lerp(*r1, s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parses limbs as a scene file does (an option's value without `Some`).
    fn spec(text: &str) -> LimbsSpec {
        ron::Options::default()
            .with_default_extension(
                ron::extensions::Extensions::IMPLICIT_SOME
                    | ron::extensions::Extensions::UNWRAP_VARIANT_NEWTYPES,
            )
            .from_str(text)
            .unwrap()
    }

    /// A one-bone arm along +x from the origin, turned about +z by 0 degrees at t = 1
    /// and 90 degrees at t = 3.
    fn arm() -> Limbs {
        let text = "(skeleton: Chain(bones: 1, length: 0.5), \
                    keys: [(time: 1.0), (time: 3.0, pose: [(joint: 0, axis: (0.0, 0.0, 1.0), degrees: 90.0)])], \
                    capsules: [(from: 0, to: 1, radius: 0.1)])";
        spec(text).build(10, Path::new("")).unwrap()
    }

    fn tip(limbs: &mut Limbs, t: f64) -> DVec3 {
        match limbs.shapes_at(t).unwrap()[0] {
            Shape::Capsule { a, b, radius } => {
                assert_eq!((a, radius), (DVec3::ZERO, 0.1));
                b
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn the_pose_between_keys_turns_at_a_constant_rate_and_holds_outside_them() {
        let mut limbs = arm();
        // Held before the first key and after the last.
        assert!((tip(&mut limbs, -5.0) - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-15);
        assert!((tip(&mut limbs, 1.0) - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-15);
        assert!((tip(&mut limbs, 3.0) - DVec3::new(0.0, 0.5, 0.0)).length() < 1e-15);
        assert!((tip(&mut limbs, 9.0) - DVec3::new(0.0, 0.5, 0.0)).length() < 1e-15);
        // In between: a quarter of the interval is a quarter of the turn (slerp turns
        // at a constant rate), and the bone keeps its length.
        for (t, degrees) in [(1.5, 22.5_f64), (2.0, 45.0), (2.9, 85.5)] {
            let expected = DQuat::from_rotation_z(degrees.to_radians()) * DVec3::new(0.5, 0.0, 0.0);
            let got = tip(&mut limbs, t);
            assert!(
                (got - expected).length() < 1e-14,
                "t = {t}: {got} against {expected}"
            );
        }
    }

    /// A two-bone arm (shoulder at the origin, 0.3 + 0.3 along +x), its shoulder keyed to
    /// turn 30 degrees about +y between t = 0 and 2, and its elbow-to-wrist chain (one
    /// bone) or shoulder-to-wrist chain reaching for `targets`.
    fn reaching_arm(base: usize, targets: &str) -> Limbs {
        let text = format!(
            "(skeleton: Chain(bones: 2, length: 0.3), \
             keys: [(time: 0.0), (time: 2.0, pose: [(joint: 0, axis: (0.0, 1.0, 0.0), degrees: 30.0)])], \
             capsules: [(from: 0, to: 1, radius: 0.05), (from: 1, to: 2, radius: 0.04)], \
             reach: (chain: (base: {base}, effector: 2), solver: Fabrik(), \
                     settings: (max_iterations: 200, tolerance: 1e-9), targets: {targets}))"
        );
        spec(&text).build(10, Path::new("")).unwrap()
    }

    fn ends(shapes: &[Shape]) -> Vec<(DVec3, DVec3)> {
        shapes
            .iter()
            .map(|s| match *s {
                Shape::Capsule { a, b, .. } => (a, b),
                other => panic!("{other:?}"),
            })
            .collect()
    }

    #[test]
    fn a_reach_puts_the_effector_on_the_target_keyed_in_time() {
        let mut limbs = reaching_arm(
            0,
            "[(time: 0.5, position: (0.3, 0.3, 0.0)), (time: 1.5, position: (0.2, 0.1, 0.3))]",
        );
        assert_eq!(limbs.reach_error_max(), None);
        for t in [-1.0, 0.5, 0.8, 1.0, 1.5, 4.0] {
            // The target as the scene keys it: held outside the keys, linear between.
            let s = ((t - 0.5) / 1.0_f64).clamp(0.0, 1.0);
            let target = DVec3::new(0.3, 0.3, 0.0) * (1.0 - s) + DVec3::new(0.2, 0.1, 0.3) * s;
            let e = ends(&limbs.shapes_at(t).unwrap());
            assert_eq!(e[0].0, DVec3::ZERO, "the chain's base does not move");
            assert_eq!(e[0].1, e[1].0, "the capsules meet at the elbow");
            assert!(
                (e[1].1 - target).length() < 1e-9,
                "t = {t}: {:?} against {target}",
                e[1].1
            );
            for (a, b) in e {
                assert!(
                    ((b - a).length() - 0.3).abs() < 1e-14,
                    "a bone changed length"
                );
            }
        }
        assert!(limbs.reach_error_max().unwrap() < 1e-9);
        // A function of time: the same t gives the same capsules to the bit, whatever was
        // asked before.
        let at_one = limbs.shapes_at(1.0).unwrap();
        limbs.shapes_at(-1.0).unwrap();
        assert_eq!(limbs.shapes_at(1.0).unwrap(), at_one);
    }

    #[test]
    fn a_target_out_of_reach_straightens_the_chain_towards_it() {
        let mut limbs = reaching_arm(0, "[(time: 0.0, position: (0.0, 2.0, 0.0))]");
        let e = ends(&limbs.shapes_at(1.0).unwrap());
        assert!(
            (e[1].1 - DVec3::new(0.0, 0.6, 0.0)).length() < 1e-12,
            "{e:?}"
        );
        // The least possible error: distance - reach.
        assert!((limbs.reach_error_max().unwrap() - 1.4).abs() < 1e-12);
    }

    #[test]
    fn joints_outside_the_reaching_chain_follow_the_keys() {
        // Only the forearm reaches: the upper arm turns as keyed (15 degrees at t = 1),
        // and the wrist goes as near the target as a forearm from that elbow can.
        let target = DVec3::new(0.4, 0.3, 0.0);
        let mut limbs = reaching_arm(1, "[(time: 0.0, position: (0.4, 0.3, 0.0))]");
        let e = ends(&limbs.shapes_at(1.0).unwrap());
        let elbow =
            sinew_math::DQuat::from_rotation_y(15f64.to_radians()) * DVec3::new(0.3, 0.0, 0.0);
        assert!((e[0].1 - elbow).length() < 1e-15, "{e:?}");
        let wrist = elbow + (target - elbow).normalize() * 0.3;
        assert!(
            (e[1].1 - wrist).length() < 1e-9,
            "{:?} against {wrist}",
            e[1].1
        );
        let least = (target - elbow).length() - 0.3;
        assert!((limbs.reach_error_max().unwrap() - least).abs() < 1e-9);
    }

    #[test]
    fn root_motion_carries_the_whole_skeleton_and_the_reach_follows_it() {
        // The one-bone arm of `arm`, its root moved 1 m along +x and 0.5 m along +z
        // between t = 1 and 3 while it turns.
        let text = "(skeleton: Chain(bones: 1, length: 0.5), \
                    keys: [(time: 1.0), (time: 3.0, root: (1.0, 0.0, 0.5), pose: [(joint: 0, axis: (0.0, 0.0, 1.0), degrees: 90.0)])], \
                    capsules: [(from: 0, to: 1, radius: 0.1)])";
        let mut limbs = spec(text).build(10, Path::new("")).unwrap();
        for (t, root, degrees) in [
            (0.0, DVec3::ZERO, 0.0_f64),
            (2.0, DVec3::new(0.5, 0.0, 0.25), 45.0),
            (5.0, DVec3::new(1.0, 0.0, 0.5), 90.0),
        ] {
            let e = ends(&limbs.shapes_at(t).unwrap());
            let tip =
                root + DQuat::from_rotation_z(degrees.to_radians()) * DVec3::new(0.5, 0.0, 0.0);
            assert!((e[0].0 - root).length() < 1e-15, "t = {t}: {e:?}");
            assert!(
                (e[0].1 - tip).length() < 1e-15,
                "t = {t}: {e:?} against {tip}"
            );
        }
        // A two-bone arm walking 0.4 m along +x while its wrist reaches for a point fixed
        // in the world: the base goes with the root, the wrist stays on the point.
        let text = "(skeleton: Chain(bones: 2, length: 0.3), \
                    keys: [(time: 0.0, pose: [(joint: 1, axis: (0.0, 1.0, 0.0), degrees: 10.0)]), \
                           (time: 1.0, root: (0.4, 0.0, 0.0), pose: [(joint: 1, axis: (0.0, 1.0, 0.0), degrees: 10.0)])], \
                    capsules: [(from: 0, to: 1, radius: 0.05), (from: 1, to: 2, radius: 0.04)], \
                    reach: (chain: (base: 0, effector: 2), solver: Fabrik(), \
                            settings: (max_iterations: 200, tolerance: 1e-9), \
                            targets: [(time: 0.0, position: (0.45, 0.1, 0.0))]))";
        let mut limbs = spec(text).build(10, Path::new("")).unwrap();
        for t in [0.0, 0.25, 0.5, 1.0] {
            let e = ends(&limbs.shapes_at(t).unwrap());
            assert!(
                (e[0].0 - DVec3::new(0.4 * t, 0.0, 0.0)).length() < 1e-15,
                "t = {t}: {e:?}"
            );
            let target = DVec3::new(0.45, 0.1, 0.0);
            assert!((e[1].1 - target).length() < 1e-9, "t = {t}: {e:?}");
        }
        assert!(limbs.reach_error_max().unwrap() <= 1e-9);
    }

    #[test]
    fn a_pole_keyed_with_the_target_chooses_the_side_the_elbow_bends_to() {
        // A straight two-bone arm along +x reaching for a point 0.4 m ahead: which way
        // the elbow goes is the pole's choice.
        let elbow_z = |pole_z: f64| {
            let text = format!(
                "(skeleton: Chain(bones: 2, length: 0.3), keys: [(time: 0.0)], \
                 capsules: [(from: 0, to: 1, radius: 0.05)], \
                 reach: (chain: (base: 0, effector: 2), solver: Fabrik(), \
                         settings: (max_iterations: 200, tolerance: 1e-9), \
                         targets: [(time: 0.0, position: (0.4, 0.0, 0.0), pole: (0.2, 0.0, {pole_z:?})), \
                                   (time: 1.0, position: (0.4, 0.0, 0.0), pole: (0.2, 0.0, {pole_z:?}))]))"
            );
            let mut limbs = spec(&text).build(10, Path::new("")).unwrap();
            let e = ends(&limbs.shapes_at(0.5).unwrap());
            assert!(limbs.reach_error_max().unwrap() <= 1e-9);
            // The bend is in the plane of the arm's base, target and pole: y = 0.
            assert!(e[0].1.y.abs() < 1e-9, "{e:?}");
            e[0].1.z
        };
        // The elbow of a 0.3 + 0.3 arm reaching 0.4 m: sqrt(0.09 - 0.04) from the line.
        let offset = 0.05_f64.sqrt();
        assert!((elbow_z(0.5) - offset).abs() < 1e-9);
        assert!((elbow_z(-0.5) + offset).abs() < 1e-9);
    }

    /// The repository's `scenes/data` directory.
    fn data_dir() -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/data")
    }

    #[test]
    fn a_clip_poses_the_capsules_as_its_frames_do() {
        let text = "(clip: (file: \"squat.bvh\", start: 0.5, frames: 20), \
                    capsules: [(from: \"LeftUpLeg\", to: \"LeftLeg\", radius: 0.07), (from: 0, to: \"Spine\", radius: 0.12)])";
        let mut limbs = spec(text).build(10, &data_dir()).unwrap();
        // The file read again by the io crate, its joints placed by the frames' own
        // positions (forward kinematics plus the root's translation).
        let bvh =
            sinew_io::parse_bvh(&std::fs::read_to_string(data_dir().join("squat.bvh")).unwrap())
                .unwrap();
        let joint = |name: &str| bvh.skeleton.joint_by_name(name).unwrap();
        let (hips, spine, up_leg, leg) = (
            joint("Hips"),
            joint("Spine"),
            joint("LeftUpLeg"),
            joint("LeftLeg"),
        );
        assert_eq!(hips, 0);
        let at = |k: usize| bvh.frames[k].joint_positions(&bvh.skeleton).unwrap();
        let close = |a: DVec3, b: DVec3| (a - b).length() < 1e-14;
        for k in [0, 7, 19] {
            let x = at(k);
            let e = ends(&limbs.shapes_at(0.5 + k as f64 * bvh.frame_time).unwrap());
            assert!(
                close(e[0].0, x[up_leg]) && close(e[0].1, x[leg]),
                "frame {k}: {e:?}"
            );
            assert!(
                close(e[1].0, x[hips]) && close(e[1].1, x[spine]),
                "frame {k}: {e:?}"
            );
        }
        // Before `start` the first frame holds; after the last frame used, the last.
        assert!(close(
            ends(&limbs.shapes_at(0.0).unwrap())[1].0,
            at(0)[hips]
        ));
        assert!(close(
            ends(&limbs.shapes_at(9.0).unwrap())[1].0,
            at(19)[hips]
        ));
        // Half-way between two frames the root is half-way (it translates linearly).
        let half = ends(&limbs.shapes_at(0.5 + 3.5 * bvh.frame_time).unwrap())[1].0;
        assert!(close(half, (at(3)[hips] + at(4)[hips]) / 2.0), "{half}");
    }

    #[test]
    fn bad_limbs_are_named() {
        let err = |text: &str| spec(text).build(10, Path::new("")).unwrap_err();
        let skeleton = "skeleton: Chain(bones: 1, length: 0.5)";
        assert_eq!(
            err(&format!(
                "({skeleton}, keys: [], capsules: [(from: 0, to: 1, radius: 0.1)])"
            )),
            "keys: none given (at least one key pose is needed)"
        );
        assert_eq!(
            err(&format!("({skeleton}, keys: [(time: 0.0)], capsules: [])")),
            "capsules: none given (at least one capsule is needed)"
        );
        assert_eq!(
            err(&format!(
                "({skeleton}, keys: [(time: 0.0)], capsules: [(from: 0, to: 1, radius: 0.0)])"
            )),
            "capsules[0]: radius = 0 is not positive and finite"
        );
        assert_eq!(
            err(&format!(
                "({skeleton}, keys: [(time: 0.0), (time: inf)], capsules: [(from: 0, to: 1, radius: 0.1)])"
            )),
            "keys[1]: time = inf is not finite"
        );
        assert!(
            err(&format!(
                "({skeleton}, keys: [(time: 0.0, pose: [(joint: 4, axis: (0.0, 0.0, 1.0), degrees: 1.0)])], capsules: [(from: 0, to: 1, radius: 0.1)])"
            ))
            .starts_with("keys[0]: pose[0]: joint 4 is out of range")
        );
        let reach = |fields: &str| {
            err(&format!(
                "({skeleton}, keys: [(time: 0.0)], capsules: [(from: 0, to: 1, radius: 0.1)], \
                 reach: ({fields}))"
            ))
        };
        let solver = "solver: Fabrik()";
        assert!(
            reach(&format!("chain: (base: 0, effector: 3), {solver}, targets: [(time: 0.0, position: (1.0, 0.0, 0.0))]"))
                .starts_with("reach: chain: "),
        );
        assert_eq!(
            reach(&format!(
                "chain: (base: 0, effector: 1), {solver}, targets: []"
            )),
            "reach: targets: none given (at least one is needed)"
        );
        assert_eq!(
            reach(&format!(
                "chain: (base: 0, effector: 1), {solver}, targets: [(time: 1.0, position: (1.0, 0.0, 0.0)), (time: 1.0, position: (1.0, 0.0, 0.0))]"
            )),
            "reach: targets[1]: time = 1 is not after the previous key's (1)"
        );
        assert_eq!(
            reach(&format!(
                "chain: (base: 0, effector: 1), {solver}, targets: [(time: 0.0, position: (1.0, NaN, 0.0))]"
            )),
            "reach: targets[0]: position = [1, NaN, 0] is not finite"
        );
        assert!(
            reach(&format!("chain: (base: 0, effector: 1), {solver}, settings: (max_iterations: 100, tolerance: -1.0), targets: [(time: 0.0, position: (1.0, 0.0, 0.0))]"))
                .starts_with("reach: settings: "),
        );
        assert_eq!(
            reach(&format!(
                "chain: (base: 0, effector: 1), {solver}, targets: [(time: 0.0, position: (1.0, 0.0, 0.0)), (time: 1.0, position: (1.0, 0.0, 0.0), pole: (0.0, 1.0, 0.0))]"
            )),
            "reach: targets[1]: pole given, but targets[0] has none (either every target has a pole or none has)"
        );
        assert_eq!(
            reach(&format!(
                "chain: (base: 0, effector: 1), {solver}, targets: [(time: 0.0, position: (1.0, 0.0, 0.0), pole: (0.0, inf, 0.0))]"
            )),
            "reach: targets[0]: pole = [0, inf, 0] is not finite"
        );
        assert_eq!(
            err(&format!(
                "({skeleton}, keys: [(time: 0.0, root: (0.0, NaN, 0.0))], capsules: [(from: 0, to: 1, radius: 0.1)])"
            )),
            "keys[0]: root = [0, NaN, 0] is not finite"
        );
        let dir = data_dir();
        let clip_err = |text: &str| spec(text).build(10, &dir).unwrap_err();
        let capsule = "capsules: [(from: \"Hips\", to: \"Chest\", radius: 0.1)]";
        assert_eq!(
            clip_err(&format!(
                "(clip: (file: \"squat.bvh\"), {skeleton}, {capsule})"
            )),
            "clip: given with a skeleton (give a clip, or a skeleton with keys)"
        );
        assert_eq!(
            clip_err(&format!(
                "(clip: (file: \"squat.bvh\"), keys: [(time: 0.0)], {capsule})"
            )),
            "clip: given with keys (a clip's frames are its key poses)"
        );
        assert_eq!(
            clip_err(&format!("(keys: [(time: 0.0)], {capsule})")),
            "skeleton: none given (give a skeleton with keys, or a clip)"
        );
        assert!(
            clip_err(&format!("(clip: (file: \"missing.bvh\"), {capsule})"))
                .starts_with("clip: file ")
        );
        assert_eq!(
            clip_err(&format!(
                "(clip: (file: \"squat.bvh\", frames: 0), {capsule})"
            )),
            "clip: frames = 0, must be 1..=61 (the file's frames)"
        );
        assert_eq!(
            clip_err(
                "(clip: (file: \"squat.bvh\"), capsules: [(from: \"Hips\", to: \"Tail\", radius: 0.1)])"
            ),
            "capsules[0]: to = \"Tail\": no joint has that name"
        );
        assert_eq!(
            clip_err("(clip: (file: \"squat.bvh\"), capsules: [(from: 0, to: 99, radius: 0.1)])"),
            "capsules[0]: to = 99 is out of range (the skeleton has 26 joints)"
        );
        // A capsule over the bending spine changes length as the clip squats: named at
        // the first time it differs.
        let mut limbs = spec("(clip: (file: \"squat.bvh\"), capsules: [(from: \"Hips\", to: \"Neck\", radius: 0.1)])")
            .build(10, &dir)
            .unwrap();
        limbs.shapes_at(0.0).unwrap();
        let e = limbs.shapes_at(1.0).unwrap_err();
        assert!(
            e.starts_with("limbs at t = 1: capsules[0]: joint 0 \"Hips\" and joint 3 \"Neck\" are ")
                && e.ends_with("apart, 0.5 in the first key pose: a capsule must keep its length (put it on one bone)"),
            "{e}"
        );
        // The work of every solve the run may ask for is bounded like an Ik task's.
        let text = format!(
            "({skeleton}, keys: [(time: 0.0)], capsules: [(from: 0, to: 1, radius: 0.1)], \
             reach: (chain: (base: 0, effector: 1), {solver}, settings: (max_iterations: 10000, tolerance: 1e-6), \
                     targets: [(time: 0.0, position: (1.0, 0.0, 0.0))]))"
        );
        let spec = spec(&text);
        assert!(spec.build(1000, Path::new("")).is_ok());
        assert!(
            spec.build(1_000_000, Path::new(""))
                .unwrap_err()
                .starts_with("reach: settings: max_iterations = 10000 over 1000000 frames"),
        );
    }
}
