//! glTF 2.0 skins, read with the `gltf` crate: a skin's joints (names, parents, rest
//! translations and rotations) into a [`Skeleton`] and its rest [`Pose`].
//!
//! A joint's offset and rest rotation are its node's translation and rotation relative
//! to the nearest ancestor that is also a joint of the skin, composed through any nodes in
//! between (for a joint with no joint ancestor: through all its ancestors, so the root's
//! offset and rotation are its place in the scene). Joints come out in depth-first order
//! (parents first, siblings in the skin's order); [`GltfSkeleton::skin_to_joint`] maps the
//! skin's joint indices (the ones vertex weights use) to the skeleton's.
//!
//! The rest rotations are the rest pose, not part of the skeleton: sinew's forward
//! kinematics reproduces the file's rest positions from [`GltfSkeleton::rest_pose`], and
//! its identity pose ([`Skeleton::rest_pose`]) is not the file's rest shape. Joint limits
//! in sinew are measured from the identity rotation, so a limit set on a loaded skeleton
//! constrains the rotation relative to the parent's frame, not the change from the file's
//! rest rotation: a limit meant around the rest shape must be centred on the rest
//! rotation by the caller (docs/io.md).
//!
//! Scale is not supported (sinew's bones are rigid): a joint, or a node between joints,
//! whose scale differs from 1 by more than 1e-6 is an error naming the node. Only the
//! JSON is read (node transforms); buffers (inverse bind matrices, meshes) are not.

use sinew_math::{DQuat, DVec3};
use sinew_skeleton::{JointDef, Pose, Skeleton};
use std::fmt;

/// Why a glTF skin was refused; every variant about a node names it.
#[derive(Clone, Debug, PartialEq)]
pub enum GltfError {
    /// The `gltf` crate refused the document (its message).
    Document(String),
    /// The document has no skin with this index.
    NoSuchSkin {
        /// The index asked for.
        index: usize,
        /// The number of skins.
        skins: usize,
    },
    /// The skin lists no joints.
    EmptySkin {
        /// The skin's index.
        skin: usize,
    },
    /// A node is the child of two nodes, or is its own ancestor.
    BadHierarchy {
        /// The node, with its name when it has one.
        node: String,
    },
    /// A node's scale is not 1 (sinew's bones do not scale).
    Scaled {
        /// The node, with its name when it has one.
        node: String,
        /// Its scale.
        scale: [f64; 3],
    },
    /// A node's rotation is a zero quaternion.
    ZeroRotation {
        /// The node, with its name when it has one.
        node: String,
    },
    /// A node is listed twice among the skin's joints.
    DuplicateJoint {
        /// The node, with its name when it has one.
        node: String,
    },
}

impl fmt::Display for GltfError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Document(m) => write!(f, "glTF: {m}"),
            Self::NoSuchSkin { index, skins } => {
                write!(f, "glTF: no skin {index} (the file has {skins})")
            }
            Self::EmptySkin { skin } => write!(f, "glTF skin {skin}: no joints"),
            Self::BadHierarchy { node } => write!(
                f,
                "glTF {node}: the child of two nodes, or its own ancestor"
            ),
            Self::Scaled { node, scale } => write!(
                f,
                "glTF {node}: scale {scale:?} is not 1 (sinew's bones do not scale)"
            ),
            Self::ZeroRotation { node } => write!(f, "glTF {node}: zero rotation quaternion"),
            Self::DuplicateJoint { node } => {
                write!(f, "glTF {node}: listed twice among the skin's joints")
            }
        }
    }
}

impl std::error::Error for GltfError {}

/// A skeleton read from a glTF skin.
#[derive(Clone, Debug, PartialEq)]
pub struct GltfSkeleton {
    /// The joints (named after their nodes; `node N` when unnamed), parents first.
    pub skeleton: Skeleton,
    /// The rest rotations, relative to each joint's parent joint (the root's: global).
    pub rest_pose: Pose,
    /// Per skeleton joint, its node index in the document.
    pub nodes: Vec<usize>,
    /// Per skin joint (the skin's order), its index in [`GltfSkeleton::skeleton`].
    pub skin_to_joint: Vec<usize>,
}

/// Scale within this of 1 counts as 1 (glTF stores f32).
const SCALE_TOLERANCE: f64 = 1e-6;

/// A node's label for messages.
fn label(node: &gltf::Node<'_>) -> String {
    match node.name() {
        Some(name) => format!("node {} `{name}`", node.index()),
        None => format!("node {}", node.index()),
    }
}

/// A node's translation and rotation (scale checked to be 1).
fn rigid(node: &gltf::Node<'_>) -> Result<(DVec3, DQuat), GltfError> {
    let (t, r, s) = node.transform().decomposed();
    let scale = s.map(f64::from);
    if scale.iter().any(|c| (c - 1.0).abs() > SCALE_TOLERANCE) {
        return Err(GltfError::Scaled {
            node: label(node),
            scale,
        });
    }
    let q = DQuat::from_xyzw(r[0].into(), r[1].into(), r[2].into(), r[3].into());
    let len = q.length();
    if !(len.is_finite() && len > 0.0) {
        return Err(GltfError::ZeroRotation { node: label(node) });
    }
    Ok((DVec3::new(t[0].into(), t[1].into(), t[2].into()), q / len))
}

/// Reads skin `skin` of a glTF document (JSON `.gltf`, or binary `.glb`).
///
/// # Example
///
/// A skin of two joints: the hips one unit up, the spine half a unit above them.
///
/// ```
/// use sinew_io::gltf::read_gltf_skin;
/// use sinew_math::DVec3;
///
/// let document = r#"{
///   "asset": {"version": "2.0"},
///   "nodes": [
///     {"name": "Hips", "translation": [0, 1, 0], "children": [1]},
///     {"name": "Spine", "translation": [0, 0.5, 0]}
///   ],
///   "skins": [{"joints": [0, 1]}]
/// }"#;
/// let read = read_gltf_skin(document.as_bytes(), 0)?;
/// let skeleton = &read.skeleton;
/// let spine = skeleton.joint_index("Spine")?;
/// assert_eq!(skeleton.len(), 2);
/// assert!(skeleton.offset(spine).distance(DVec3::new(0.0, 0.5, 0.0)) < 1e-12);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn read_gltf_skin(bytes: &[u8], skin: usize) -> Result<GltfSkeleton, GltfError> {
    let gltf = gltf::Gltf::from_slice(bytes).map_err(|e| GltfError::Document(e.to_string()))?;
    let doc = &gltf.document;
    let skins = doc.skins().count();
    let Some(s) = doc.skins().nth(skin) else {
        return Err(GltfError::NoSuchSkin { index: skin, skins });
    };
    let nodes: Vec<gltf::Node<'_>> = doc.nodes().collect();
    let n = nodes.len();
    let mut parent: Vec<Option<usize>> = vec![None; n];
    for node in &nodes {
        for child in node.children() {
            let c = child.index();
            if parent[c].is_some() || c == node.index() {
                return Err(GltfError::BadHierarchy {
                    node: label(&child),
                });
            }
            parent[c] = Some(node.index());
        }
    }
    let joints: Vec<usize> = s.joints().map(|j| j.index()).collect();
    if joints.is_empty() {
        return Err(GltfError::EmptySkin { skin });
    }
    // Node -> position in the skin's joint list.
    let mut skin_index: Vec<Option<usize>> = vec![None; n];
    for (k, &j) in joints.iter().enumerate() {
        if skin_index[j].is_some() {
            return Err(GltfError::DuplicateJoint {
                node: label(&nodes[j]),
            });
        }
        skin_index[j] = Some(k);
    }
    // Per skin joint: the nearest joint ancestor (by skin index) and the transform from
    // it, composed through the nodes in between.
    let mut joint_parent: Vec<Option<usize>> = vec![None; joints.len()];
    let mut local: Vec<(DVec3, DQuat)> = Vec::with_capacity(joints.len());
    for (k, &j) in joints.iter().enumerate() {
        let (mut t, mut r) = rigid(&nodes[j])?;
        let mut at = j;
        let mut steps = 0;
        while let Some(p) = parent[at] {
            steps += 1;
            if steps > n {
                return Err(GltfError::BadHierarchy {
                    node: label(&nodes[j]),
                });
            }
            if let Some(pk) = skin_index[p] {
                joint_parent[k] = Some(pk);
                break;
            }
            // A node between joints (or above the root joint): fold its transform in.
            let (pt, pr) = rigid(&nodes[p])?;
            t = pt + pr * t;
            r = pr * r;
            at = p;
        }
        local.push((t, r.normalize()));
    }
    // Depth-first order, parents first, siblings in skin order.
    let mut children: Vec<Vec<usize>> = vec![Vec::new(); joints.len()];
    let mut roots = Vec::new();
    for (k, p) in joint_parent.iter().enumerate() {
        match p {
            Some(p) => children[*p].push(k),
            None => roots.push(k),
        }
    }
    let mut order = Vec::with_capacity(joints.len());
    let mut stack: Vec<usize> = roots.into_iter().rev().collect();
    while let Some(k) = stack.pop() {
        order.push(k);
        stack.extend(children[k].iter().rev());
    }
    // Every joint's parent chain ends at a root (cycles were refused), so `order` holds
    // every joint exactly once.
    let mut skin_to_joint = vec![0; joints.len()];
    for (i, &k) in order.iter().enumerate() {
        skin_to_joint[k] = i;
    }
    let defs = order.iter().map(|&k| JointDef {
        name: Some(
            nodes[joints[k]]
                .name()
                .map_or_else(|| format!("node {}", joints[k]), str::to_string),
        ),
        parent: joint_parent[k].map(|p| skin_to_joint[p]),
        offset: local[k].0,
        ..JointDef::default()
    });
    let skeleton = Skeleton::new(defs).map_err(|e| GltfError::Document(e.to_string()))?;
    Ok(GltfSkeleton {
        skeleton,
        rest_pose: Pose {
            rotations: order.iter().map(|&k| local[k].1).collect(),
        },
        nodes: order.iter().map(|&k| joints[k]).collect(),
        skin_to_joint,
    })
}
