//! Wavefront OBJ triangle meshes, read with the `tobj` crate: every face of every object
//! and group, polygons triangulated as fans from their first vertex, into one
//! [`TriangleMesh`]. Only `v` and `f` matter; normals, texture coordinates and materials
//! are ignored (a material library is never opened).
//!
//! Vertices keep the file's numbering. OBJ numbers its `v` statements through the whole
//! file, but `tobj` gives each object or group its own vertex list, in the order the
//! object's faces first use them, so a vertex shared by two groups arrives twice and
//! the file's numbering is lost. The reader therefore hands `tobj` the text with each
//! `v` statement's index written as its colour (an OBJ vertex may carry `r g b` after
//! its coordinates; colours are otherwise ignored here), and reads the index back from
//! every vertex `tobj` returns: copies of one file vertex are one vertex, two file
//! vertices at the same place stay two, and the mesh's vertices are the file's vertices
//! that some face uses, in the file's order ([`NumberedObj::file_vertices`] maps them
//! back; with no unused vertex, vertex `i` of the mesh is the file's `v` statement `i`,
//! from 0). A vertex given with a weight `w` (`v x y z w`) is divided by it, as `tobj`
//! does.
//!
//! `tobj`'s errors say what failed (a position that does not parse, a face index out of
//! bounds) but not on which line; a face index out of range is found first here and named
//! with its line and value ([`ObjError::FaceIndex`]).

use crate::TriangleMesh;
use sinew_math::DVec3;
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
    /// A face statement refers to a vertex the file does not have (a positive index
    /// beyond the file's `v` statements, a negative one reaching back before the first,
    /// or 0).
    FaceIndex {
        /// The line of the `f` statement, from 1.
        line: usize,
        /// The index as written.
        index: i64,
        /// The `v` statements the index could refer to: all of the file's for a
        /// positive index, those before the line for a negative one.
        vertices: usize,
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
            Self::FaceIndex {
                line,
                index,
                vertices,
            } => write!(
                f,
                "OBJ line {line}: face vertex index {index} is out of range ({vertices} \
                 vertices it could refer to; indices count from 1, negative ones back from \
                 the last vertex before the face)"
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
    parse_obj_numbered(text).map(|n| n.mesh)
}

/// A mesh read from an OBJ file, with the file's numbering of its vertices.
#[derive(Clone, Debug, PartialEq)]
pub struct NumberedObj {
    /// The mesh: the file's vertices that some face uses, in the file's order.
    pub mesh: TriangleMesh,
    /// For each vertex of the mesh, the index of its `v` statement in the file (from 0),
    /// increasing.
    pub file_vertices: Vec<usize>,
    /// How many `v` statements the file has.
    pub file_vertex_count: usize,
}

impl NumberedObj {
    /// The mesh vertex of the file's vertex `v` (the index of its `v` statement, from
    /// 0), or why there is none: `Err` with a message naming `v`.
    ///
    /// # Errors
    /// `v` is not below the file's vertex count, or no face uses it.
    pub fn vertex(&self, v: usize) -> Result<usize, String> {
        if v >= self.file_vertex_count {
            return Err(format!(
                "vertex {v} does not exist (the file has {} vertices)",
                self.file_vertex_count
            ));
        }
        self.file_vertices
            .binary_search(&v)
            .map_err(|_| format!("vertex {v} is used by no face"))
    }
}

/// Reads an OBJ file from its text, keeping the file's numbering of its vertices (see
/// the module documentation).
///
/// # Errors
/// As [`parse_obj`].
///
/// # Example
///
/// A file whose face uses its vertices out of order, after a loose vertex: the mesh's
/// vertices are in the file's order, and the loose one is left out.
///
/// ```
/// use sinew_io::obj::parse_obj_numbered;
///
/// let read = parse_obj_numbered("v 9 9 9\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 4 2 3\n")?;
/// assert_eq!(read.file_vertices, vec![1, 2, 3]);
/// assert_eq!(read.mesh.triangles, vec![[2, 0, 1]]);
/// assert_eq!(read.vertex(3), Ok(2));
/// assert!(read.vertex(0).is_err());
/// # Ok::<(), sinew_io::obj::ObjError>(())
/// ```
pub fn parse_obj_numbered(text: &str) -> Result<NumberedObj, ObjError> {
    let (numbered, count) = with_vertex_numbers(text);
    check_face_indices(text, count)?;
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
    let mut reader = std::io::BufReader::new(numbered.as_bytes());
    // No material library is read: an OBJ's `mtllib` names a file we do not open.
    let (models, _) = tobj::load_obj_buf(&mut reader, &options, |_| {
        Err(tobj::LoadError::OpenFileFailed)
    })
    .map_err(|e| ObjError::Parse(e.to_string()))?;
    // Every object's vertices as file indices, and each file vertex's position.
    let mut position: Vec<Option<DVec3>> = vec![None; count];
    let mut objects: Vec<Vec<usize>> = Vec::with_capacity(models.len());
    for model in &models {
        let m = &model.mesh;
        let n = m.positions.len() / 3;
        if m.vertex_color.len() != 3 * n {
            return Err(ObjError::Parse(format!(
                "object `{}`: a vertex without its number (a `v` statement the reader could not read)",
                model.name
            )));
        }
        let mut local = Vec::with_capacity(n);
        for (p, c) in m
            .positions
            .chunks_exact(3)
            .zip(m.vertex_color.chunks_exact(3))
        {
            let v = c[0];
            // The numbers were written as integers below `count`.
            if !(v >= 0.0 && v < count as f64 && v.fract() == 0.0) {
                return Err(ObjError::Parse(format!(
                    "object `{}`: a vertex without its number",
                    model.name
                )));
            }
            let v = v as usize;
            let p = DVec3::new(p[0], p[1], p[2]);
            if !p.is_finite() {
                return Err(ObjError::NonFiniteVertex {
                    object: model.name.clone(),
                    vertex: v,
                });
            }
            position[v] = Some(p);
            local.push(v);
        }
        objects.push(local);
    }
    // The used file vertices in the file's order.
    let mut mesh_index = vec![usize::MAX; count];
    let mut mesh = TriangleMesh::default();
    let mut file_vertices = Vec::new();
    for (v, p) in position.iter().enumerate() {
        if let Some(p) = p {
            mesh_index[v] = mesh.positions.len();
            mesh.positions.push(*p);
            file_vertices.push(v);
        }
    }
    for (model, local) in models.iter().zip(&objects) {
        for (t, tri) in model.mesh.indices.chunks_exact(3).enumerate() {
            let mut out = [0usize; 3];
            for (o, &i) in out.iter_mut().zip(tri) {
                let Some(&v) = local.get(i as usize) else {
                    return Err(ObjError::IndexOutOfRange {
                        object: model.name.clone(),
                        triangle: t,
                    });
                };
                *o = mesh_index[v];
            }
            mesh.triangles.push(out);
        }
    }
    if mesh.triangles.is_empty() {
        return Err(ObjError::NoTriangles);
    }
    Ok(NumberedObj {
        mesh,
        file_vertices,
        file_vertex_count: count,
    })
}

/// `text` with every `v` statement rewritten as `v x y z k 0 0`, `k` its index from 0
/// (as a colour, which `tobj` keeps with each copy of the vertex), and the number of
/// `v` statements. A weight `w` (`v x y z w`) is applied as `tobj` applies it (`x/w`,
/// written so it reads back to the same number); a colour given in the file is dropped;
/// a statement with fewer than three values, or a weight that does not parse or is
/// zero, is left as it is for `tobj` to refuse.
fn with_vertex_numbers(text: &str) -> (String, usize) {
    let mut out = String::with_capacity(text.len() + text.len() / 4);
    let mut count = 0usize;
    for line in text.lines() {
        let mut words = line.split_whitespace();
        if words.next() == Some("v") {
            let values: Vec<&str> = words.collect();
            let numbered = match values.len() {
                0..=2 => None,
                4 => weighted(&values),
                _ => Some(format!("{} {} {}", values[0], values[1], values[2])),
            };
            // Counted either way: the file's numbering counts every `v` statement.
            count += 1;
            if let Some(xyz) = numbered {
                out.push_str(&format!("v {xyz} {} 0 0\n", count - 1));
                continue;
            }
        }
        out.push_str(line);
        out.push('\n');
    }
    (out, count)
}

/// The first vertex reference of an `f` statement that is out of range, with its line:
/// `tobj` refuses it too, but without the line or the index. A positive index is
/// checked against all of the file's `v` statements (one that names a vertex given
/// after the face, if `tobj` refuses it, keeps `tobj`'s message); a negative one counts
/// back from the last `v` statement before the face. References that do not parse as
/// integers are left for `tobj` to refuse.
fn check_face_indices(text: &str, count: usize) -> Result<(), ObjError> {
    let mut seen = 0usize;
    for (k, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => seen += 1,
            Some("f") => {
                for word in words {
                    let Some(Ok(index)) = word.split('/').next().map(str::parse::<i64>) else {
                        continue;
                    };
                    let vertices = if index < 0 { seen } else { count };
                    if index == 0 || index.unsigned_abs() > vertices as u64 {
                        return Err(ObjError::FaceIndex {
                            line: k + 1,
                            index,
                            vertices,
                        });
                    }
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// `x/w y/w z/w` of `v x y z w`, each written so it parses back to the same number;
/// `None` when a value does not parse or `w` is zero.
fn weighted(values: &[&str]) -> Option<String> {
    let parsed: Vec<f64> = values
        .iter()
        .map(|v| v.parse::<f64>().ok())
        .collect::<Option<_>>()?;
    let w = parsed[3];
    if w == 0.0 {
        return None;
    }
    Some(format!(
        "{:?} {:?} {:?}",
        parsed[0] / w,
        parsed[1] / w,
        parsed[2] / w
    ))
}
