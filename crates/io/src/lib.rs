//! sinew-io: file readers for sinew, kept out of the core crates' dependencies.
//!
//! - [`bvh`] (always on, hand-written): Biovision hierarchy files into a
//!   [`sinew_skeleton::Skeleton`] and one [`sinew_skeleton::Pose`] plus a root translation
//!   per frame, with errors naming the line and column.
//! - `gltf` (feature `gltf`, the `gltf` crate without its image and file import
//!   support): a glTF 2.0 skin's joints into a skeleton and its rest pose, with errors
//!   naming the node.
//! - `obj` (feature `obj`, the `tobj` crate): Wavefront OBJ faces, polygons triangulated,
//!   into a plain [`TriangleMesh`].
//!
//! BVH is small and line-oriented, so a parser of a few hundred lines with located errors
//! costs less than a dependency and keeps the always-on part of the crate free of them;
//! glTF (JSON with a schema, buffers, accessors) and OBJ (many optional statements) are
//! read with well-kept crates behind features, so a user who needs neither compiles
//! neither. Conventions and limits: docs/io.md.
//!
//! # Example
//!
//! A two-bone BVH: the hips lifted by 2 and the spine turned 90 degrees about z, so the
//! end of the spine, one unit above it, swings to point along -x.
//!
//! ```
//! use sinew_io::parse_bvh;
//! use sinew_math::DVec3;
//!
//! const BVH: &str = "HIERARCHY
//! ROOT Hips
//! {
//!   OFFSET 0 0 0
//!   CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
//!   JOINT Spine
//!   {
//!     OFFSET 0 1 0
//!     CHANNELS 3 Zrotation Xrotation Yrotation
//!     End Site
//!     {
//!       OFFSET 0 1 0
//!     }
//!   }
//! }
//! MOTION
//! Frames: 1
//! Frame Time: 0.04
//! 0 2 0 0 0 0 90 0 0";
//!
//! let bvh = parse_bvh(BVH)?;
//! assert_eq!(bvh.skeleton.len(), 3); // Hips, Spine and the end site
//! assert_eq!(bvh.frames.len(), 1);
//! let spine = bvh.skeleton.joint_index("Spine")?;
//! let at = bvh.frames[0].joint_positions(&bvh.skeleton)?;
//! assert!(at[spine].distance(DVec3::new(0.0, 3.0, 0.0)) < 1e-12);
//! assert!(at[spine + 1].distance(DVec3::new(-1.0, 3.0, 0.0)) < 1e-12);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod bvh;
#[cfg(feature = "gltf")]
pub mod gltf;
#[cfg(feature = "obj")]
pub mod obj;

pub use bvh::{Bvh, BvhError, BvhFrame, Channel, parse_bvh};

use sinew_math::DVec3;

/// A triangle mesh as read from a file: vertex positions and triangles of three vertex
/// indices. Not validated beyond the indices being in range and the positions finite;
/// `sinew_spring_sim::TriangleMesh::new` checks what a cloth needs (degenerate,
/// duplicate and non-manifold triangles).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriangleMesh {
    /// Vertex positions.
    pub positions: Vec<DVec3>,
    /// Triangles, three indices into `positions` each.
    pub triangles: Vec<[usize; 3]>,
}
