//! Joint trees, poses and forward kinematics for sinew, plus the inverse-kinematics
//! vocabulary every solver shares.
//!
//! - [`Skeleton`]: joints with a parent index, in topological order (every parent comes
//!   before its children), each with a local offset from its parent and an optional name.
//!   A chain ([`Skeleton::chain`]) is the special case where joint `i` hangs from `i - 1`.
//! - [`Pose`]: one local rotation per joint.
//! - [`GlobalPose`]: what forward kinematics computes, the global rotation and position of
//!   every joint. [`Skeleton::forward_kinematics`] fills all of it;
//!   [`Skeleton::forward_kinematics_from`] recomputes one joint and its descendants only.
//! - [`finish`]: the damped least-squares finish with a sliding active set on the joint
//!   limits that every IK solver ends with, over any set of joints and effectors.
//! - [`ik`]: chains inside a skeleton, solve settings and reports, the closed-form answer
//!   for a target out of reach, and the [`ik::IkSolver`] trait the solver crates implement.
//! - [`limits`]: joint limits (free, fixed, hinge, swing-twist) relative to a joint's
//!   rest rotation, with the projection, violation measure and sampling every solver uses.
//! - [`track`]: trajectory tracking with any solver (warm starts, per-frame records,
//!   continuity measure and the optional per-frame rotation limit, the lab's Q3).
//!
//! Forward kinematics follows the course lab exactly: a root joint takes its local
//! rotation and offset as global; for a joint `i` with parent `p`,
//! `G[i] = normalize(G[p] * L[i])` and `P[i] = P[p] + G[p] * offset[i]`. So a joint's
//! rotation moves its children, not itself: the bone from `p` to `i` is turned by `L[p]`.
//!
//! ```
//! use sinew_skeleton::{DQuat, DVec3, GlobalPose, Skeleton};
//! use std::f64::consts::FRAC_PI_2;
//!
//! // Three unit bones along x from the origin: joints at x = 0, 1, 2, 3.
//! let arm = Skeleton::chain(DVec3::ZERO, &[DVec3::X; 3]).unwrap();
//! let mut pose = arm.rest_pose();
//! // Turning joint 1 a quarter about z swings the bones after it (not joint 1 itself).
//! pose.rotations[1] = DQuat::from_rotation_z(FRAC_PI_2);
//! let mut global = GlobalPose::new();
//! arm.forward_kinematics(&pose, &mut global).unwrap();
//! assert!((global.positions[1] - DVec3::X).length() < 1e-12);
//! assert!((global.positions[3] - DVec3::new(1.0, 2.0, 0.0)).length() < 1e-12);
//! ```
//!
//! Named joints and limits: see [`JointDef`] and [`Skeleton::new`].
//!
//! Architecture invariant: depends on sinew-math only (serde behind the `serde` feature).

pub mod finish;
pub mod ik;
pub mod limits;
pub mod prefetch;
pub mod seed;
pub mod track;

/// The math types a skeleton is built from, re-exported so a user of this crate does
/// not also have to depend on sinew-math.
pub use sinew_math::{DQuat, DVec3};

use limits::{JointLimit, LimitError, PreparedLimit};
use std::fmt;

/// One joint as given to [`Skeleton::new`].
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct JointDef {
    /// A name for messages and scenes; optional.
    #[cfg_attr(feature = "serde", serde(default))]
    pub name: Option<String>,
    /// The parent joint's index, which must be smaller than this joint's; `None` for a root.
    #[cfg_attr(feature = "serde", serde(default))]
    pub parent: Option<usize>,
    /// The offset from the parent joint in the parent's frame (for a root: its position).
    pub offset: DVec3,
    /// The limit on the joint's local rotation, relative to its rest rotation (the
    /// identity: the rest pose is [`Skeleton::rest_pose`]). Default: free.
    #[cfg_attr(feature = "serde", serde(default))]
    pub limit: JointLimit,
}

impl JointDef {
    /// A root joint at `position` (no parent, no name, free).
    #[must_use]
    pub fn root(position: DVec3) -> Self {
        Self {
            offset: position,
            ..Self::default()
        }
    }

    /// A joint hanging from joint `parent` (an index smaller than this joint's) at
    /// `offset` in the parent's frame.
    #[must_use]
    pub fn child(parent: usize, offset: DVec3) -> Self {
        Self {
            parent: Some(parent),
            offset,
            ..Self::default()
        }
    }

    /// The same joint with a name, which [`Skeleton::joint_by_name`] finds and every
    /// error message shows. Names must be unique within a skeleton.
    #[must_use]
    pub fn named(mut self, name: impl Into<String>) -> Self {
        self.name = Some(name.into());
        self
    }

    /// The same joint with a limit on its local rotation.
    #[must_use]
    pub fn with_limit(mut self, limit: JointLimit) -> Self {
        self.limit = limit;
        self
    }
}

/// Why a skeleton, a pose, a chain or a finish job was refused. Every variant names the
/// joint, or the field of the job.
#[derive(Clone, Debug, PartialEq)]
pub enum SkeletonError {
    /// A skeleton needs at least one joint.
    Empty,
    /// A joint's parent does not come before it (topological order is required).
    ParentNotBefore {
        /// The joint, with its name when it has one.
        joint: String,
        /// The parent index it gave.
        parent: usize,
    },
    /// A joint's offset has a NaN or infinite component.
    NonFiniteOffset {
        /// The joint, with its name when it has one.
        joint: String,
    },
    /// A joint's distance from the world origin along the skeleton (the lengths of the
    /// offsets from its root to it, summed; a root's offset is its position) is above
    /// [`MAX_REACH`]: forward kinematics could overflow to an infinite position.
    ReachTooLarge {
        /// The joint, with its name when it has one.
        joint: String,
        /// The summed lengths (possibly infinite).
        reach: f64,
    },
    /// A chain bone's length overflows `f64` when computed from its squared components
    /// (bones from about 1.34e154; the skeleton's `MAX_REACH` keeps the sum of finite
    /// lengths finite): the chain solvers square lengths and need a finite reach.
    ChainTooLong {
        /// The chain's effector, with its name when it has one.
        effector: String,
        /// The sum of the bone lengths (infinite).
        reach: f64,
    },
    /// A joint index is not in the skeleton.
    JointOutOfRange {
        /// The index given.
        index: usize,
        /// The number of joints.
        len: usize,
    },
    /// A chain's base is not an ancestor of (or equal to) its effector.
    NotAnAncestor {
        /// The base joint.
        base: String,
        /// The effector joint.
        effector: String,
    },
    /// A pose has a different number of rotations than the skeleton has joints.
    PoseLength {
        /// Joints in the skeleton.
        expected: usize,
        /// Rotations in the pose.
        got: usize,
    },
    /// A local rotation is zero or has a NaN or infinite component.
    InvalidRotation {
        /// The joint, with its name when it has one.
        joint: String,
    },
    /// Two joints have the same name.
    DuplicateName {
        /// The first joint with the name.
        first: String,
        /// The later joint that repeats it.
        second: String,
    },
    /// No joint has the name looked up.
    UnknownName {
        /// The name looked up.
        name: String,
    },
    /// A joint's limit is invalid.
    InvalidLimit {
        /// The joint, with its name when it has one.
        joint: String,
        /// What is wrong with the limit (it names the field).
        error: LimitError,
    },
    /// A field of a [`FinishJob`](crate::finish::FinishJob) (or a buffer handed to the
    /// finish with it) is invalid.
    InvalidFinishJob {
        /// The field, with the index of the entry when it is a list (`targets[2].joint`).
        field: String,
        /// What is wrong with it.
        reason: String,
    },
}

impl fmt::Display for SkeletonError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Empty => write!(f, "the skeleton has no joints"),
            Self::ParentNotBefore { joint, parent } => write!(
                f,
                "{joint}: parent index {parent} does not come before the joint (joints must be in topological order)"
            ),
            Self::NonFiniteOffset { joint } => {
                write!(f, "{joint}: offset has a NaN or infinite component")
            }
            Self::ReachTooLarge { joint, reach } => write!(
                f,
                "{joint}: the offsets from its root sum to a length of {reach:e}, above \
                 {MAX_REACH:e}: forward kinematics could overflow f64"
            ),
            Self::ChainTooLong { effector, reach } => write!(
                f,
                "{effector}: the chain's bone lengths sum to {reach:e}: its bones are too long \
                 for f64 (a length squared overflows)"
            ),
            Self::JointOutOfRange { index, len } => write!(
                f,
                "joint index {index} is out of range (the skeleton has {len} joints)"
            ),
            Self::NotAnAncestor { base, effector } => write!(
                f,
                "{base} is not an ancestor of {effector}, so they do not bound a chain"
            ),
            Self::PoseLength { expected, got } => write!(
                f,
                "the pose has {got} rotations but the skeleton has {expected} joints"
            ),
            Self::InvalidRotation { joint } => write!(
                f,
                "{joint}: local rotation is zero or has a NaN or infinite component"
            ),
            Self::DuplicateName { first, second } => {
                write!(
                    f,
                    "{second} has the same name as {first}; names must be unique"
                )
            }
            Self::UnknownName { name } => write!(f, "no joint is named \"{name}\""),
            Self::InvalidLimit { joint, error } => write!(f, "{joint}: limit: {error}"),
            Self::InvalidFinishJob { field, reason } => {
                write!(f, "finish job: {field}: {reason}")
            }
        }
    }
}

impl std::error::Error for SkeletonError {}

/// The largest distance from the world origin a joint may have along the skeleton (its
/// offsets' lengths from its root, summed): `f64::MAX / 16`. Rotating an offset by a unit
/// quaternion has intermediate terms of up to five times its length, and a position adds
/// the rotated offsets of its path, so with every joint within this bound forward
/// kinematics of any valid pose is finite (docs/ik-ccd.md, "Forward kinematics").
pub const MAX_REACH: f64 = f64::MAX / 16.0;

/// A tree of joints in topological order; see the [crate docs](crate).
///
/// Two skeletons are equal (`==`) when their joints, names and limits are; their
/// [`Skeleton::limits_revision`]s are not compared.
#[derive(Clone, Debug)]
pub struct Skeleton {
    parents: Vec<Option<usize>>,
    offsets: Vec<DVec3>,
    names: Vec<Option<String>>,
    limits: Vec<JointLimit>,
    /// Each limit prepared for its quick inside test (see [`PreparedLimit`]).
    prepared: Vec<PreparedLimit>,
    /// One past the largest index among each joint's descendants (at least `i + 1`):
    /// every descendant of `i` lies in `i + 1 .. span_end[i]`.
    span_end: Vec<usize>,
    /// Whether each joint's descendants fill its span exactly (depth-first order, as a
    /// chain is), so forward kinematics from a joint needs no membership test.
    contiguous: bool,
    /// A hash of the parents and offsets, which is what a chain's joints and bone lengths
    /// depend on; a chain keeps it to refuse a skeleton it was not built for.
    fingerprint: u64,
    /// See [`Skeleton::limits_revision`].
    limits_revision: u64,
}

impl PartialEq for Skeleton {
    fn eq(&self, other: &Self) -> bool {
        // Everything but the revision, which says where the limits came from, not what
        // they are. (`prepared`, `span_end`, `contiguous` and `fingerprint` follow from
        // the rest.)
        self.parents == other.parents
            && self.offsets == other.offsets
            && self.names == other.names
            && self.limits == other.limits
    }
}

/// The next [`Skeleton::limits_revision`]: process-wide, so that no two skeletons built
/// or changed apart share one.
fn next_limits_revision() -> u64 {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
    NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

impl Skeleton {
    /// A skeleton from its joints, validated: at least one joint, every parent index
    /// smaller than its child's, every offset finite, every limit valid, no name used
    /// twice. Each error names the joint.
    ///
    /// ```
    /// use sinew_skeleton::{DQuat, DVec3, GlobalPose, JointDef, Skeleton};
    /// use sinew_skeleton::limits::JointLimit;
    /// use std::f64::consts::FRAC_PI_2;
    ///
    /// // A shoulder at the origin, an elbow 0.3 along x that bends about z only, a wrist.
    /// let elbow_limit = JointLimit::hinge(DVec3::Z, 0.0, 2.5).unwrap();
    /// let arm = Skeleton::new([
    ///     JointDef::root(DVec3::ZERO).named("shoulder"),
    ///     JointDef::child(0, DVec3::new(0.3, 0.0, 0.0)).named("elbow").with_limit(elbow_limit),
    ///     JointDef::child(1, DVec3::new(0.25, 0.0, 0.0)).named("wrist"),
    /// ])
    /// .unwrap();
    ///
    /// // Bend the elbow a quarter turn: the forearm now points along y.
    /// let elbow = arm.joint_by_name("elbow").unwrap();
    /// let mut pose = arm.rest_pose();
    /// pose.rotations[elbow] = DQuat::from_rotation_z(FRAC_PI_2);
    /// let mut global = GlobalPose::new();
    /// arm.forward_kinematics(&pose, &mut global).unwrap();
    /// let wrist = arm.joint_index("wrist").unwrap();
    /// assert!((global.positions[wrist] - DVec3::new(0.3, 0.25, 0.0)).length() < 1e-12);
    ///
    /// // A repeated name is refused, naming both joints.
    /// let twice = Skeleton::new([
    ///     JointDef::root(DVec3::ZERO).named("hip"),
    ///     JointDef::child(0, DVec3::Y).named("hip"),
    /// ]);
    /// assert_eq!(
    ///     twice.unwrap_err().to_string(),
    ///     "joint 1 \"hip\" has the same name as joint 0 \"hip\"; names must be unique"
    /// );
    /// ```
    pub fn new(joints: impl IntoIterator<Item = JointDef>) -> Result<Self, SkeletonError> {
        let mut parents = Vec::new();
        let mut offsets = Vec::new();
        let mut names = Vec::new();
        let mut limits = Vec::new();
        for (i, joint) in joints.into_iter().enumerate() {
            let label = || joint_label(i, joint.name.as_deref());
            if let Some(parent) = joint.parent
                && parent >= i
            {
                return Err(SkeletonError::ParentNotBefore {
                    joint: label(),
                    parent,
                });
            }
            if !joint.offset.is_finite() {
                return Err(SkeletonError::NonFiniteOffset { joint: label() });
            }
            if let Err(error) = joint.limit.validate() {
                return Err(SkeletonError::InvalidLimit {
                    joint: label(),
                    error,
                });
            }
            if let Some(name) = joint.name.as_deref()
                && let Some(first) = names
                    .iter()
                    .position(|n: &Option<String>| n.as_deref() == Some(name))
            {
                return Err(SkeletonError::DuplicateName {
                    first: joint_label(first, Some(name)),
                    second: label(),
                });
            }
            parents.push(joint.parent);
            offsets.push(joint.offset);
            limits.push(joint.limit);
            names.push(joint.name);
        }
        if parents.is_empty() {
            return Err(SkeletonError::Empty);
        }
        let n = parents.len();
        let mut span_end: Vec<usize> = (1..=n).collect();
        let mut descendants = vec![0usize; n];
        for i in (0..n).rev() {
            if let Some(p) = parents[i] {
                span_end[p] = span_end[p].max(span_end[i]);
                descendants[p] += descendants[i] + 1;
            }
        }
        let contiguous = (0..n).all(|i| span_end[i] - i - 1 == descendants[i]);
        // Every joint's position is a sum of rotated offsets along its path, so its size
        // is at most the summed lengths: a bound on those keeps forward kinematics finite
        // whatever the (valid) pose.
        let mut reach = vec![0.0f64; n];
        for i in 0..n {
            let from_parent = parents[i].map_or(0.0, |p| reach[p]);
            reach[i] = from_parent + sinew_math::robust_length(offsets[i]);
            if reach[i] > MAX_REACH {
                return Err(SkeletonError::ReachTooLarge {
                    joint: joint_label(i, names[i].as_deref()),
                    reach: reach[i],
                });
            }
        }
        let fingerprint = structure_fingerprint(&parents, &offsets);
        let prepared = limits.iter().map(JointLimit::prepare).collect();
        Ok(Self {
            parents,
            offsets,
            names,
            limits,
            prepared,
            span_end,
            contiguous,
            fingerprint,
            limits_revision: next_limits_revision(),
        })
    }

    /// A serial chain: joint 0 is the root at `root`, joint `i >= 1` hangs from joint
    /// `i - 1` with local offset `offsets[i - 1]`. So `offsets.len()` bones.
    pub fn chain(root: DVec3, offsets: &[DVec3]) -> Result<Self, SkeletonError> {
        let rest = offsets
            .iter()
            .enumerate()
            .map(|(i, &offset)| JointDef::child(i, offset));
        Self::new(std::iter::once(JointDef::root(root)).chain(rest))
    }

    /// The number of joints (at least one).
    #[must_use]
    pub fn len(&self) -> usize {
        self.parents.len()
    }

    /// Always `false`: a skeleton has at least one joint. Present for API symmetry.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The parent of joint `i`, `None` for a root.
    ///
    /// # Panics
    /// If `i` is out of range.
    #[must_use]
    pub fn parent(&self, i: usize) -> Option<usize> {
        self.parents[i]
    }

    /// The local offset of joint `i` from its parent (for a root, its position).
    ///
    /// # Panics
    /// If `i` is out of range.
    #[must_use]
    pub fn offset(&self, i: usize) -> DVec3 {
        self.offsets[i]
    }

    /// The limit of joint `i` (relative to its rest rotation, the identity).
    ///
    /// # Panics
    /// If `i` is out of range.
    #[must_use]
    pub fn limit(&self, i: usize) -> &JointLimit {
        &self.limits[i]
    }

    /// The limit of joint `i` prepared for its quick inside test: its
    /// [`project`](PreparedLimit::project) and [`violation`](PreparedLimit::violation) give
    /// exactly the limit's own answers, faster for a rotation inside the limit.
    ///
    /// # Panics
    /// If `i` is out of range.
    #[must_use]
    pub fn prepared_limit(&self, i: usize) -> &PreparedLimit {
        &self.prepared[i]
    }

    /// Sets the limit of joint `i`, validated: an error naming the joint and the field
    /// otherwise (the skeleton is then unchanged).
    pub fn set_limit(&mut self, i: usize, limit: JointLimit) -> Result<(), SkeletonError> {
        self.check_index(i)?;
        limit
            .validate()
            .map_err(|error| SkeletonError::InvalidLimit {
                joint: self.label(i),
                error,
            })?;
        self.limits[i] = limit;
        self.prepared[i] = limit.prepare();
        self.limits_revision = next_limits_revision();
        Ok(())
    }

    /// The name of joint `i`, if it has one.
    ///
    /// # Panics
    /// If `i` is out of range.
    #[must_use]
    pub fn name(&self, i: usize) -> Option<&str> {
        self.names[i].as_deref()
    }

    /// The index of the joint named `name`, if any. O(joints).
    #[must_use]
    pub fn joint_by_name(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n.as_deref() == Some(name))
    }

    /// The index of the joint named `name`, or an error naming the missing joint.
    ///
    /// ```
    /// use sinew_skeleton::{DVec3, JointDef, Skeleton};
    /// let skel = Skeleton::new([JointDef::root(DVec3::ZERO).named("pelvis")]).unwrap();
    /// assert_eq!(skel.joint_index("pelvis"), Ok(0));
    /// let err = skel.joint_index("head").unwrap_err();
    /// assert_eq!(err.to_string(), "no joint is named \"head\"");
    /// ```
    pub fn joint_index(&self, name: &str) -> Result<usize, SkeletonError> {
        self.joint_by_name(name)
            .ok_or_else(|| SkeletonError::UnknownName {
                name: name.to_owned(),
            })
    }

    /// The length of the bone from joint `i`'s parent to joint `i` (0 for a root).
    ///
    /// # Panics
    /// If `i` is out of range.
    #[must_use]
    pub fn bone_length(&self, i: usize) -> f64 {
        if self.parents[i].is_some() {
            self.offsets[i].length()
        } else {
            0.0
        }
    }

    /// A 64-bit hash of this skeleton's structure (parents and offsets), deterministic
    /// across runs. Names and limits are left out. A solver that caches anything derived
    /// from the structure (a chain, a prepared two-bone job) keeps it to refuse a skeleton
    /// it was not built for: two skeletons with different structures have different
    /// fingerprints except by a hash collision.
    #[must_use]
    pub fn fingerprint(&self) -> u64 {
        self.fingerprint
    }

    /// A number that changes whenever the limits may have: a skeleton gets a new one when
    /// it is built and at every [`Skeleton::set_limit`], from a process-wide counter, and a
    /// clone keeps its original's. So two skeletons with the same revision have the same
    /// limits to the bit (one is the other, or a clone of it, with no limit set since);
    /// different revisions say nothing (a limit set to the value it had, or a skeleton
    /// built twice, gets a new one). A solver that keeps anything derived from the limits
    /// compares it first, and compares the limits themselves only when it differs. The
    /// value itself depends on the order skeletons were built in, so compare it, never
    /// store or print it as a result.
    #[must_use]
    pub fn limits_revision(&self) -> u64 {
        self.limits_revision
    }

    /// One past the largest index among the descendants of `i` (`i + 1` for a leaf):
    /// every descendant of `i` lies in `i + 1 .. subtree_end(i)`, since a parent's index
    /// is smaller than its child's. When the span holds exactly the descendants (as in a
    /// chain or any depth-first order), its length is their number.
    ///
    /// # Panics
    /// If `i` is out of range.
    #[must_use]
    pub fn subtree_end(&self, i: usize) -> usize {
        self.span_end[i]
    }

    /// "joint 3" or `joint 3 "elbow"`, for messages.
    #[must_use]
    pub fn label(&self, i: usize) -> String {
        joint_label(i, self.names.get(i).and_then(|n| n.as_deref()))
    }

    /// Checks that `i` is a joint index.
    pub fn check_index(&self, i: usize) -> Result<(), SkeletonError> {
        if i < self.len() {
            Ok(())
        } else {
            Err(SkeletonError::JointOutOfRange {
                index: i,
                len: self.len(),
            })
        }
    }

    /// Whether joint `a` is joint `b` or one of its ancestors. O(depth of `b`).
    #[must_use]
    pub fn is_ancestor_or_self(&self, a: usize, b: usize) -> bool {
        let mut j = Some(b);
        while let Some(k) = j {
            if k == a {
                return true;
            }
            if k < a {
                return false;
            }
            j = self.parents[k];
        }
        false
    }

    /// The rest pose: every local rotation the identity.
    #[must_use]
    pub fn rest_pose(&self) -> Pose {
        Pose {
            rotations: vec![DQuat::IDENTITY; self.len()],
        }
    }

    /// Forward kinematics of `pose` into `out` (resized to fit): every joint's global
    /// rotation and position. O(joints), no allocation once `out` has the right size.
    pub fn forward_kinematics(
        &self,
        pose: &Pose,
        out: &mut GlobalPose,
    ) -> Result<(), SkeletonError> {
        self.check_pose(pose)?;
        out.resize(self.len());
        let mut fk = self.fk_slices(pose, out);
        for i in 0..self.len() {
            self.update_joint(&mut fk, i)?;
        }
        Ok(())
    }

    /// Recomputes joint `joint` and its descendants only, leaving every other entry of
    /// `out` as it was. `out` must hold forward kinematics of a pose that agrees with
    /// `pose` on every joint outside that subtree (typically: the same pose before the
    /// subtree's rotations changed). Cost: O(size of the subtree) for a depth-first
    /// ordered skeleton such as a chain, O(joints after `joint`) otherwise.
    pub fn forward_kinematics_from(
        &self,
        pose: &Pose,
        joint: usize,
        out: &mut GlobalPose,
    ) -> Result<(), SkeletonError> {
        self.check_pose(pose)?;
        self.check_index(joint)?;
        if out.positions.len() != self.len() {
            // Nothing valid to start from: compute everything.
            return self.forward_kinematics(pose, out);
        }
        let span = joint + 1..self.span_end[joint];
        if self.contiguous {
            let mut fk = self.fk_slices(pose, out);
            self.update_joint(&mut fk, joint)?;
            for i in span {
                self.update_joint(&mut fk, i)?;
            }
        } else {
            out.dirty.fill(false);
            out.dirty[joint] = true;
            let mut dirty = std::mem::take(&mut out.dirty);
            let mut fk = self.fk_slices(pose, out);
            let mut result = self.update_joint(&mut fk, joint);
            for i in span {
                if result.is_err() {
                    break;
                }
                if let Some(p) = self.parents[i]
                    && dirty[p]
                {
                    dirty[i] = true;
                    result = self.update_joint(&mut fk, i);
                }
            }
            out.dirty = dirty;
            result?;
        }
        Ok(())
    }

    fn check_pose(&self, pose: &Pose) -> Result<(), SkeletonError> {
        if pose.rotations.len() == self.len() {
            Ok(())
        } else {
            Err(SkeletonError::PoseLength {
                expected: self.len(),
                got: pose.rotations.len(),
            })
        }
    }

    /// The slices forward kinematics reads and writes, each cut to the skeleton's length
    /// (`pose` checked and `out` sized by the caller), so that a loop over the joints
    /// indexes them without a bounds check.
    #[inline(always)]
    fn fk_slices<'a>(&'a self, pose: &'a Pose, out: &'a mut GlobalPose) -> FkSlices<'a> {
        let n = self.len();
        FkSlices {
            locals: &pose.rotations[..n],
            parents: &self.parents[..n],
            offsets: &self.offsets[..n],
            rotations: &mut out.rotations[..n],
            positions: &mut out.positions[..n],
        }
    }

    /// The lab's FK rule for one joint, given that its parent is up to date.
    #[inline(always)]
    fn update_joint(&self, fk: &mut FkSlices<'_>, i: usize) -> Result<(), SkeletonError> {
        let local = fk.locals[i];
        // A squared length in `(0, MAX]` says every component is finite (a NaN or an
        // infinity would make it NaN or infinite) and the length not zero: one test for
        // the usual rotation, the exact ones only when it fails (a finite quaternion whose
        // squared length overflows is still accepted).
        let length_squared = local.length_squared();
        if !(length_squared > 0.0 && length_squared <= f64::MAX)
            && (!local.is_finite() || length_squared == 0.0)
        {
            return Err(SkeletonError::InvalidRotation {
                joint: self.label(i),
            });
        }
        match fk.parents[i] {
            None => {
                fk.rotations[i] = local.normalize();
                fk.positions[i] = fk.offsets[i];
            }
            Some(p) => {
                let parent_rotation = fk.rotations[p];
                fk.rotations[i] = (parent_rotation * local).normalize();
                fk.positions[i] = fk.positions[p] + parent_rotation * fk.offsets[i];
            }
        }
        Ok(())
    }
}

/// What forward kinematics reads (the local rotations, the parents and offsets) and
/// writes (the global rotations and positions), one entry per joint.
struct FkSlices<'a> {
    locals: &'a [DQuat],
    parents: &'a [Option<usize>],
    offsets: &'a [DVec3],
    rotations: &'a mut [DQuat],
    positions: &'a mut [DVec3],
}

/// A 64-bit hash of a skeleton's parents and offsets (each mixed in by the splitmix64
/// finalizer), deterministic across runs. Limits and names are left out: they can change
/// without invalidating a chain, and a chain caches neither.
fn structure_fingerprint(parents: &[Option<usize>], offsets: &[DVec3]) -> u64 {
    fn mix(h: u64, word: u64) -> u64 {
        let mut z = (h ^ word).wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    let mut h = mix(0, parents.len() as u64);
    for (parent, offset) in parents.iter().zip(offsets) {
        h = mix(h, parent.map_or(u64::MAX, |p| p as u64));
        for c in offset.to_array() {
            // +0 and -0 are the same offset.
            h = mix(h, (c + 0.0).to_bits());
        }
    }
    h
}

fn joint_label(i: usize, name: Option<&str>) -> String {
    match name {
        Some(name) => format!("joint {i} \"{name}\""),
        None => format!("joint {i}"),
    }
}

/// A pose: one local rotation per joint, in the skeleton's joint order.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Pose {
    /// Local rotation of each joint relative to its parent (for a root: global).
    pub rotations: Vec<DQuat>,
}

/// Global rotations and positions of every joint, as forward kinematics computes them.
#[derive(Debug, Default, PartialEq)]
pub struct GlobalPose {
    /// Global rotation of each joint.
    pub rotations: Vec<DQuat>,
    /// Global position of each joint.
    pub positions: Vec<DVec3>,
    /// Scratch for forward kinematics from a joint in non-depth-first skeletons.
    dirty: Vec<bool>,
}

impl Clone for GlobalPose {
    fn clone(&self) -> Self {
        Self {
            rotations: self.rotations.clone(),
            positions: self.positions.clone(),
            dirty: self.dirty.clone(),
        }
    }

    /// Copies `source` into `self`'s buffers, which allocates nothing when they are
    /// large enough (the derived `clone_from` would build a new pose and drop the old).
    fn clone_from(&mut self, source: &Self) {
        self.rotations.clone_from(&source.rotations);
        self.positions.clone_from(&source.positions);
        self.dirty.clone_from(&source.dirty);
    }
}

impl GlobalPose {
    /// Asks the processor to bring the rotations and positions into its cache (a hint,
    /// see [`crate::prefetch`]).
    pub fn prefetch(&self) {
        crate::prefetch::prefetch(&self.rotations);
        crate::prefetch::prefetch(&self.positions);
    }

    /// An empty global pose; forward kinematics sizes it.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    fn resize(&mut self, n: usize) {
        self.rotations.resize(n, DQuat::IDENTITY);
        self.positions.resize(n, DVec3::ZERO);
        self.dirty.resize(n, false);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, PI};

    fn joint(parent: Option<usize>, offset: DVec3) -> JointDef {
        JointDef {
            parent,
            offset,
            ..JointDef::default()
        }
    }

    fn close(a: DVec3, b: DVec3, tol: f64) -> bool {
        (a - b).length() <= tol
    }

    #[test]
    fn subtree_end_bounds_the_descendants_and_fingerprint_the_structure() {
        // 0 -> 1 -> 2, 0 -> 3, 1 -> 4: joint 1's descendants are 2 and 4, not in a row.
        let skel = Skeleton::new([
            joint(None, DVec3::ZERO),
            joint(Some(0), DVec3::X),
            joint(Some(1), DVec3::X),
            joint(Some(0), DVec3::Y),
            joint(Some(1), DVec3::Z),
        ])
        .unwrap();
        let ends: Vec<usize> = (0..skel.len()).map(|i| skel.subtree_end(i)).collect();
        assert_eq!(ends, [5, 5, 3, 4, 5]);
        for i in 0..skel.len() {
            for j in 0..skel.len() {
                if i != j && skel.is_ancestor_or_self(i, j) {
                    assert!((i + 1..skel.subtree_end(i)).contains(&j), "{i} {j}");
                }
            }
        }
        let chain = Skeleton::chain(DVec3::ZERO, &[DVec3::X, DVec3::X]).unwrap();
        assert_eq!(chain.subtree_end(0), 3);
        assert_eq!(chain.fingerprint(), chain.clone().fingerprint());
        let other = Skeleton::chain(DVec3::ZERO, &[DVec3::X, DVec3::Y]).unwrap();
        assert_ne!(chain.fingerprint(), other.fingerprint());
    }

    #[test]
    fn the_limits_revision_changes_with_the_limits_and_is_kept_by_a_clone() {
        let offsets = [DVec3::X, DVec3::X];
        let mut a = Skeleton::chain(DVec3::ZERO, &offsets).unwrap();
        let clone = a.clone();
        assert_eq!(a.limits_revision(), clone.limits_revision());
        let built_again = Skeleton::chain(DVec3::ZERO, &offsets).unwrap();
        assert_ne!(a.limits_revision(), built_again.limits_revision());
        assert_eq!(a, built_again, "the revision is not compared");
        let first = a.limits_revision();
        let hinge = JointLimit::hinge(DVec3::Z, -1.0, 1.0).unwrap();
        a.set_limit(1, hinge).unwrap();
        assert_ne!(a.limits_revision(), first);
        assert_ne!(a, clone);
        let second = a.limits_revision();
        a.set_limit(1, hinge).unwrap();
        assert_ne!(
            a.limits_revision(),
            second,
            "a limit set again gets a new one too"
        );
        let third = a.limits_revision();
        assert!(a.set_limit(7, JointLimit::Free).is_err());
        assert_eq!(
            a.limits_revision(),
            third,
            "a refused limit changes nothing"
        );
    }

    #[test]
    fn rejects_bad_skeletons_naming_the_joint() {
        assert_eq!(Skeleton::new([]), Err(SkeletonError::Empty));
        let bad_parent = Skeleton::new([
            joint(None, DVec3::ZERO),
            JointDef {
                name: Some("elbow".into()),
                parent: Some(1),
                offset: DVec3::X,
                ..JointDef::default()
            },
        ]);
        let err = bad_parent.unwrap_err();
        assert_eq!(
            err,
            SkeletonError::ParentNotBefore {
                joint: "joint 1 \"elbow\"".into(),
                parent: 1
            }
        );
        assert!(err.to_string().contains("joint 1 \"elbow\""));
        let nan = Skeleton::chain(DVec3::ZERO, &[DVec3::X, DVec3::new(f64::NAN, 0.0, 0.0)]);
        assert_eq!(
            nan.unwrap_err(),
            SkeletonError::NonFiniteOffset {
                joint: "joint 2".into()
            }
        );
        let inf = Skeleton::chain(DVec3::new(0.0, f64::INFINITY, 0.0), &[]);
        assert!(matches!(inf, Err(SkeletonError::NonFiniteOffset { .. })));
    }

    #[test]
    fn builders_fill_the_fields_they_name() {
        let limit = JointLimit::hinge(DVec3::Z, -1.0, 1.0).unwrap();
        let knee = JointDef::child(2, DVec3::new(0.0, -0.4, 0.0))
            .named("knee")
            .with_limit(limit);
        assert_eq!(
            knee,
            JointDef {
                name: Some("knee".into()),
                parent: Some(2),
                offset: DVec3::new(0.0, -0.4, 0.0),
                limit,
            }
        );
        assert_eq!(JointDef::root(DVec3::Y).parent, None);
        assert_eq!(JointDef::root(DVec3::Y).offset, DVec3::Y);
    }

    #[test]
    fn joints_are_found_by_name_and_names_are_unique() {
        let skel = Skeleton::new([
            JointDef::root(DVec3::ZERO).named("pelvis"),
            JointDef::child(0, DVec3::Y),
            JointDef::child(1, DVec3::Y).named("head"),
        ])
        .unwrap();
        assert_eq!(skel.joint_by_name("pelvis"), Some(0));
        assert_eq!(skel.joint_by_name("head"), Some(2));
        assert_eq!(skel.joint_by_name(""), None);
        assert_eq!(
            skel.joint_index("tail"),
            Err(SkeletonError::UnknownName {
                name: "tail".into()
            })
        );
        // Unnamed joints never collide with each other.
        assert!(Skeleton::chain(DVec3::ZERO, &[DVec3::X; 3]).is_ok());
        let twice = Skeleton::new([
            JointDef::root(DVec3::ZERO).named("a"),
            JointDef::child(0, DVec3::Y).named("b"),
            JointDef::child(1, DVec3::Y).named("a"),
        ]);
        assert_eq!(
            twice,
            Err(SkeletonError::DuplicateName {
                first: "joint 0 \"a\"".into(),
                second: "joint 2 \"a\"".into(),
            })
        );
    }

    #[test]
    fn quarter_turns_on_a_chain() {
        // Three unit bones along x; joint 1 turns a quarter about z, joint 2 another.
        let skel = Skeleton::chain(DVec3::new(1.0, 2.0, 3.0), &[DVec3::X; 3]).unwrap();
        let mut pose = skel.rest_pose();
        let quarter = DQuat::from_rotation_z(FRAC_PI_2);
        pose.rotations[1] = quarter;
        pose.rotations[2] = quarter;
        let mut g = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut g).unwrap();
        let base = DVec3::new(1.0, 2.0, 3.0);
        let expected = [
            base,
            base + DVec3::X,
            base + DVec3::X + DVec3::Y,
            base + DVec3::X + DVec3::Y - DVec3::X,
        ];
        for (i, e) in expected.iter().enumerate() {
            assert!(
                close(g.positions[i], *e, 1e-15),
                "joint {i}: {} vs {e}",
                g.positions[i]
            );
        }
        // The effector's global rotation is the half turn about z.
        assert!(g.rotations[2].angle_between(DQuat::from_rotation_z(PI)) < 1e-15);
    }

    #[test]
    fn a_full_turn_is_the_rest_pose() {
        let skel = Skeleton::chain(DVec3::ZERO, &[DVec3::new(0.3, 0.1, -0.2); 5]).unwrap();
        let mut pose = skel.rest_pose();
        let mut rest = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut rest).unwrap();
        // Four quarter turns about a tilted axis on every joint: each joint's product is
        // a full turn (-1 as a quaternion), which is the same rotation.
        let axis = DVec3::new(1.0, 2.0, 2.0) / 3.0;
        let quarter = DQuat::from_axis_angle(axis, FRAC_PI_2);
        pose.rotations = vec![quarter * quarter * quarter * quarter; 6];
        let mut g = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut g).unwrap();
        for i in 0..6 {
            assert!(close(g.positions[i], rest.positions[i], 1e-14));
        }
    }

    /// Root at origin; two branches: 1 (x) -> 3 (x), and 2 (y) -> 4 (z). Joint order is
    /// topological but not depth-first.
    fn three_level_tree() -> Skeleton {
        Skeleton::new([
            joint(None, DVec3::ZERO),
            joint(Some(0), DVec3::X),
            joint(Some(0), DVec3::Y),
            joint(Some(1), DVec3::X),
            joint(Some(2), DVec3::Z),
        ])
        .unwrap()
    }

    #[test]
    fn three_level_tree_by_hand() {
        let skel = three_level_tree();
        let mut pose = skel.rest_pose();
        // Root: quarter about z, so x -> y and y -> -x.
        pose.rotations[0] = DQuat::from_rotation_z(FRAC_PI_2);
        // Joint 2: quarter about x in its parent's frame, so its child's offset z -> -y,
        // then the root's rotation maps -y -> x.
        pose.rotations[2] = DQuat::from_rotation_x(FRAC_PI_2);
        let mut g = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut g).unwrap();
        let expected = [
            DVec3::ZERO,
            DVec3::Y,
            -DVec3::X,
            DVec3::Y * 2.0,
            -DVec3::X + DVec3::X,
        ];
        for (i, e) in expected.iter().enumerate() {
            assert!(
                close(g.positions[i], *e, 1e-15),
                "joint {i}: {} vs {e}",
                g.positions[i]
            );
        }
    }

    fn wobbly_pose(n: usize, seed: u64) -> Pose {
        let mut state = seed;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        Pose {
            rotations: (0..n)
                .map(|_| {
                    DQuat::from_axis_angle(
                        DVec3::new(next(), next(), next() + 2.0).normalize(),
                        3.0 * next(),
                    )
                })
                .collect(),
        }
    }

    #[test]
    fn fk_from_a_joint_equals_full_fk() {
        let chain =
            Skeleton::chain(DVec3::new(0.0, 0.5, 0.0), &[DVec3::new(0.15, 0.0, 0.0); 7]).unwrap();
        for skel in [three_level_tree(), chain] {
            let n = skel.len();
            let before = wobbly_pose(n, 1);
            let mut incremental = GlobalPose::new();
            skel.forward_kinematics(&before, &mut incremental).unwrap();
            for joint in 0..n {
                // Change the subtree of `joint` only, then update from it.
                let mut after = before.clone();
                let other = wobbly_pose(n, 7 + joint as u64);
                for i in 0..n {
                    if skel.is_ancestor_or_self(joint, i) {
                        after.rotations[i] = other.rotations[i];
                    }
                }
                let mut g = incremental.clone();
                skel.forward_kinematics_from(&after, joint, &mut g).unwrap();
                let mut full = GlobalPose::new();
                skel.forward_kinematics(&after, &mut full).unwrap();
                assert_eq!(g.positions, full.positions, "from joint {joint}");
                assert_eq!(g.rotations, full.rotations, "from joint {joint}");
            }
        }
    }

    #[test]
    fn fk_from_a_joint_stops_at_the_first_invalid_rotation_of_its_subtree() {
        // On a tree whose subtrees are not contiguous (the dirty marks are used) and on a
        // chain: the first invalid rotation below the joint is the error, and the global
        // pose can be updated again afterwards.
        let chain =
            Skeleton::chain(DVec3::new(0.0, 0.5, 0.0), &[DVec3::new(0.15, 0.0, 0.0); 4]).unwrap();
        for (skel, bad) in [(three_level_tree(), [3, 4]), (chain, [2, 3])] {
            let n = skel.len();
            let mut g = GlobalPose::new();
            skel.forward_kinematics(&skel.rest_pose(), &mut g).unwrap();
            let mut pose = wobbly_pose(n, 3);
            pose.rotations[bad[0]] = DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0);
            pose.rotations[bad[1]] = DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0);
            assert_eq!(
                skel.forward_kinematics_from(&pose, 0, &mut g),
                Err(SkeletonError::InvalidRotation {
                    joint: format!("joint {}", bad[0])
                })
            );
            let good = wobbly_pose(n, 5);
            skel.forward_kinematics_from(&good, 0, &mut g).unwrap();
            let mut full = GlobalPose::new();
            skel.forward_kinematics(&good, &mut full).unwrap();
            assert_eq!(g.positions, full.positions);
            assert_eq!(g.rotations, full.rotations);
        }
    }

    #[test]
    fn fk_preserves_bone_lengths() {
        let offsets: Vec<DVec3> = (0..200)
            .map(|i| DVec3::new(1.0 + i as f64, -0.5, 0.25 * i as f64) * 10f64.powi(i % 7 - 3))
            .collect();
        let skel = Skeleton::chain(DVec3::ZERO, &offsets).unwrap();
        let pose = wobbly_pose(skel.len(), 42);
        let mut g = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut g).unwrap();
        for i in 1..skel.len() {
            let length = (g.positions[i] - g.positions[i - 1]).length();
            let rest = skel.bone_length(i);
            // Positions are absolute, so their difference carries round-off of the
            // positions' size; 1e-12 relative holds wherever that is below the bone.
            let roundoff =
                4.0 * f64::EPSILON * g.positions[i].length().max(g.positions[i - 1].length());
            assert!(
                (length - rest).abs() <= 1e-12 * rest + roundoff,
                "bone {i}: {length} vs {rest}"
            );
        }
    }

    #[test]
    fn clone_from_copies_a_global_pose_into_the_buffers_it_has() {
        // Solvers size scratch global poses with `clone_from` so that a later structure
        // change does not allocate: the buffers must be kept, the contents equal.
        let skel = Skeleton::chain(DVec3::ZERO, &[DVec3::X, DVec3::Y, DVec3::Z]).unwrap();
        let mut pose = skel.rest_pose();
        pose.rotations[1] = DQuat::from_rotation_z(0.3);
        let mut source = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut source).unwrap();
        let mut target = GlobalPose::new();
        skel.forward_kinematics(&skel.rest_pose(), &mut target)
            .unwrap();
        let buffers = (target.rotations.as_ptr(), target.positions.as_ptr());
        target.clone_from(&source);
        assert_eq!(target, source);
        assert_eq!(
            (target.rotations.as_ptr(), target.positions.as_ptr()),
            buffers
        );
        assert_eq!(source.clone(), source);
    }

    #[test]
    fn a_rotation_is_refused_exactly_when_not_finite_or_of_zero_length() {
        // The one test on the squared length must refuse and accept what the two exact
        // tests do: an infinity, a NaN, zero, and a finite rotation whose squared length
        // underflows to zero are refused; one whose squared length overflows is not.
        let skel = Skeleton::chain(DVec3::ZERO, &[DVec3::X; 2]).unwrap();
        let mut g = GlobalPose::new();
        for (q, refused) in [
            (DQuat::from_xyzw(f64::INFINITY, 0.0, 0.0, 1.0), true),
            (DQuat::from_xyzw(0.0, f64::NEG_INFINITY, 0.0, 0.0), true),
            (DQuat::from_xyzw(0.0, 0.0, f64::NAN, 1.0), true),
            (DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0), true),
            (DQuat::from_xyzw(0.0, 0.0, 0.0, -0.0), true),
            (DQuat::from_xyzw(1e-170, 0.0, 0.0, 1e-170), true),
            (DQuat::from_xyzw(1e200, 0.0, 0.0, 0.0), false),
            (DQuat::from_xyzw(0.0, f64::MAX, 0.0, f64::MAX), false),
            (DQuat::from_xyzw(1e-150, 0.0, 0.0, 0.0), false),
            (DQuat::from_xyzw(0.0, 0.0, 0.6, 0.8), false),
        ] {
            let exact = !q.is_finite() || q.length_squared() == 0.0;
            assert_eq!(exact, refused, "{q}");
            for joint in 0..3 {
                let mut pose = skel.rest_pose();
                pose.rotations[joint] = q;
                let result = skel.forward_kinematics(&pose, &mut g);
                if refused {
                    assert_eq!(
                        result,
                        Err(SkeletonError::InvalidRotation {
                            joint: format!("joint {joint}")
                        }),
                        "{q} at joint {joint}"
                    );
                } else {
                    assert_eq!(result, Ok(()), "{q} at joint {joint}");
                }
            }
        }
    }

    #[test]
    fn bad_poses_are_errors() {
        let skel = Skeleton::chain(DVec3::ZERO, &[DVec3::X; 2]).unwrap();
        let mut g = GlobalPose::new();
        let short = Pose {
            rotations: vec![DQuat::IDENTITY; 2],
        };
        assert_eq!(
            skel.forward_kinematics(&short, &mut g),
            Err(SkeletonError::PoseLength {
                expected: 3,
                got: 2
            })
        );
        let mut nan = skel.rest_pose();
        nan.rotations[1] = DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0);
        assert_eq!(
            skel.forward_kinematics(&nan, &mut g),
            Err(SkeletonError::InvalidRotation {
                joint: "joint 1".into()
            })
        );
        let mut zero = skel.rest_pose();
        zero.rotations[2] = DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0);
        assert!(skel.forward_kinematics(&zero, &mut g).is_err());
        assert!(matches!(
            skel.forward_kinematics_from(&skel.rest_pose(), 3, &mut g),
            Err(SkeletonError::JointOutOfRange { index: 3, len: 3 })
        ));
    }

    #[test]
    fn unnormalized_rotations_are_normalized() {
        let skel = Skeleton::chain(DVec3::ZERO, &[DVec3::X; 2]).unwrap();
        let mut pose = skel.rest_pose();
        pose.rotations[1] = DQuat::from_rotation_z(FRAC_PI_2) * 3.0;
        let mut g = GlobalPose::new();
        skel.forward_kinematics(&pose, &mut g).unwrap();
        assert!(close(g.positions[2], DVec3::new(1.0, 1.0, 0.0), 1e-15));
    }
}
