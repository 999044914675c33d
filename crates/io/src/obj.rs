//! Wavefront OBJ triangle meshes, read with the `tobj` crate: every face of every object
//! and group, polygons triangulated as fans from their first vertex, into one
//! [`TriangleMesh`]. Only `v` and `f` matter; normals, texture coordinates and materials
//! are ignored (a material library is never opened).
//!
//! `tobj` gives each object or group its own vertex list, so a vertex shared by two
//! groups arrives twice; the reader welds vertices with bit-identical coordinates across
//! objects (never within one), so a garment split into groups stays one connected cloth.
//! `tobj`'s errors say what failed (a position that does not parse, a face index out of
//! bounds) but not on which line.

use crate::TriangleMesh;
use sinew_math::DVec3;
use std::collections::HashMap;
use std::fmt;

/// Why an OBJ file was refused.
#[derive(Clone, Debug, PartialEq)]
pub enum ObjError {
    /// `tobj` refused the file (its message).
    Parse(String),
    /// The file has no faces.
    NoTriangles,
    /// A vertex has a NaN or infinite coordinate.
    NonFiniteVertex {
        /// The object (or group) name.
        object: String,
        /// The vertex's index within that object.
        vertex: usize,
    },
    /// A face refers to a vertex the object does not have.
    IndexOutOfRange {
        /// The object (or group) name.
        object: String,
        /// The triangle's index within that object.
        triangle: usize,
    },
}

impl fmt::Display for ObjError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Parse(m) => write!(f, "OBJ: {m}"),
            Self::NoTriangles => write!(f, "OBJ: the file has no faces"),
            Self::NonFiniteVertex { object, vertex } => write!(
                f,
                "OBJ object `{object}`: vertex {vertex} has a NaN or infinite coordinate"
            ),
            Self::IndexOutOfRange { object, triangle } => write!(
                f,
                "OBJ object `{object}`: triangle {triangle} refers to a vertex out of range"
            ),
        }
    }
}

impl std::error::Error for ObjError {}

/// Reads an OBJ file from its text (see the module documentation).
///
/// # Example
///
/// A unit square given as one quad becomes two triangles over its four vertices.
///
/// ```
/// use sinew_io::obj::parse_obj;
///
/// let mesh = parse_obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")?;
/// assert_eq!(mesh.positions.len(), 4);
/// assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
/// # Ok::<(), sinew_io::obj::ObjError>(())
/// ```
pub fn parse_obj(text: &str) -> Result<TriangleMesh, ObjError> {
    // The struct update stays although every field is given today: `tobj` features that
    // another crate may turn on add fields.
    #[allow(clippy::needless_update)]
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
        ..tobj::LoadOptions::default()
    };
    let mut reader = std::io::BufReader::new(text.as_bytes());
    // No material library is read: an OBJ's `mtllib` names a file we do not open.
    let (models, _) = tobj::load_obj_buf(&mut reader, &options, |_| {
        Err(tobj::LoadError::OpenFileFailed)
    })
    .map_err(|e| ObjError::Parse(e.to_string()))?;
    let mut mesh = TriangleMesh::default();
    // Bit patterns of positions from earlier objects, for welding across objects.
    let mut welded: HashMap<[u64; 3], usize> = HashMap::new();
    for model in &models {
        let m = &model.mesh;
        let mut local = Vec::with_capacity(m.positions.len() / 3);
        let mut added: Vec<([u64; 3], usize)> = Vec::new();
        for (v, p) in m.positions.chunks_exact(3).enumerate() {
            let p = DVec3::new(p[0], p[1], p[2]);
            if !p.is_finite() {
                return Err(ObjError::NonFiniteVertex {
                    object: model.name.clone(),
                    vertex: v,
                });
            }
            // +0.0 and -0.0 are the same point.
            let key = (p + DVec3::ZERO).to_array().map(f64::to_bits);
            let index = if let Some(&i) = welded.get(&key) {
                i
            } else {
                mesh.positions.push(p);
                added.push((key, mesh.positions.len() - 1));
                mesh.positions.len() - 1
            };
            local.push(index);
        }
        for (t, tri) in m.indices.chunks_exact(3).enumerate() {
            let mut out = [0usize; 3];
            for (o, &i) in out.iter_mut().zip(tri) {
                let Some(&g) = local.get(i as usize) else {
                    return Err(ObjError::IndexOutOfRange {
                        object: model.name.clone(),
                        triangle: t,
                    });
                };
                *o = g;
            }
            mesh.triangles.push(out);
        }
        welded.extend(added);
    }
    if mesh.triangles.is_empty() {
        return Err(ObjError::NoTriangles);
    }
    Ok(mesh)
}
