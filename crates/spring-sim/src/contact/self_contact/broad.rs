//! The broad phase of self-contact: which vertex-triangle and edge-edge pairs of a mesh
//! may be within a distance `margin` of each other, at a state or anywhere along a
//! linear step, found with a uniform spatial hash over the primitives' bounding boxes.
//!
//! Every vertex, edge and triangle gets the axis-aligned box of its vertices (for a step,
//! of its vertices at both ends, which contains the whole swept primitive since every
//! point of it moves on a segment between its two ends), grown by `margin / 2` on every
//! side: two primitives closer than `margin` then have overlapping boxes, because their
//! boxes' gap along every axis is at most their distance. Pairs that share a vertex are
//! never candidates (a triangle's own vertices, edges meeting at a vertex): the barrier
//! would push the mesh's own neighbours apart.
//!
//! The hash's cells are cubes of the mean largest extent of the triangles' boxes; each
//! triangle (and each edge, in a second table) is listed in the cells its box touches,
//! and each vertex (edge) box looks up the cells it touches. A box touching more than
//! [`MAX_CELLS`] cells (a primitive swept far) is kept in a short list tested against
//! every query instead. The result is sorted and free of duplicates, and is exactly the
//! set [`candidates_brute_force`] finds by testing every pair.

use sinew_math::DVec3;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// A multiplicative hash of a cell's three integer coordinates. The keys are not chosen
/// by an adversary, so the standard library's DoS-resistant hasher, which dominated the
/// broad phase's cost, is not needed.
#[derive(Default)]
struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut word = [0u8; 8];
            word[..chunk.len()].copy_from_slice(chunk);
            self.write_u64(u64::from_le_bytes(word));
        }
    }
    fn write_i64(&mut self, i: i64) {
        self.write_u64(i as u64);
    }
    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x517c_c1b7_2722_0a95);
    }
    fn write_usize(&mut self, i: usize) {
        self.write_u64(i as u64);
    }
}

type CellMap = HashMap<[i64; 3], Vec<usize>, BuildHasherDefault<CellHasher>>;

/// A box touching more cells than this is not hashed (see the module documentation).
pub const MAX_CELLS: usize = 512;

/// A candidate pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Candidate {
    /// A vertex and a triangle (indices into the mesh's triangles) it is not part of.
    PointTriangle {
        /// The vertex.
        vertex: usize,
        /// The triangle.
        triangle: usize,
    },
    /// Two edges (indices into the mesh's edges, `a < b`) that share no vertex.
    EdgeEdge {
        /// The first edge.
        a: usize,
        /// The second edge.
        b: usize,
    },
}

/// An axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// The lower corner.
    pub min: DVec3,
    /// The upper corner.
    pub max: DVec3,
}

impl Aabb {
    const EMPTY: Self = Self {
        min: DVec3::splat(f64::INFINITY),
        max: DVec3::splat(f64::NEG_INFINITY),
    };

    fn union(self, other: Self) -> Self {
        Self {
            min: self.min.min(other.min),
            max: self.max.max(other.max),
        }
    }

    /// Whether the boxes overlap (touching counts).
    #[must_use]
    pub fn overlaps(&self, other: &Self) -> bool {
        self.min.cmple(other.max).all() && other.min.cmple(self.max).all()
    }
}

/// The primitives of a mesh: its triangles, its unique edges and the vertices they use.
#[derive(Clone, Debug, PartialEq)]
pub struct Primitives {
    /// The triangles.
    pub triangles: Vec<[usize; 3]>,
    /// The unique edges `[low, high]`, sorted.
    pub edges: Vec<[usize; 2]>,
    /// The vertices some triangle uses, sorted.
    pub vertices: Vec<usize>,
}

impl Primitives {
    /// The primitives of `triangles` (indices are not checked here).
    #[must_use]
    pub fn new(triangles: &[[usize; 3]]) -> Self {
        let mut edges: Vec<[usize; 2]> = triangles
            .iter()
            .flat_map(|&[a, b, c]| [[a, b], [b, c], [c, a]])
            .map(|[a, b]| [a.min(b), a.max(b)])
            .collect();
        edges.sort_unstable();
        edges.dedup();
        let mut vertices: Vec<usize> = triangles.iter().flatten().copied().collect();
        vertices.sort_unstable();
        vertices.dedup();
        Self {
            triangles: triangles.to_vec(),
            edges,
            vertices,
        }
    }
}

/// The boxes of every vertex (indexed by vertex), edge and triangle at `x`, or swept
/// from `x` to `x + dx` when `dx` is given, grown by `margin / 2`.
struct Boxes {
    vertex: Vec<Aabb>,
    edge: Vec<Aabb>,
    triangle: Vec<Aabb>,
}

impl Boxes {
    fn new(prims: &Primitives, x: &[DVec3], dx: Option<&[DVec3]>, margin: f64) -> Self {
        let grow = DVec3::splat(0.5 * margin);
        let mut vertex = vec![Aabb::EMPTY; x.len()];
        for &v in &prims.vertices {
            let end = dx.map_or(x[v], |d| x[v] + d[v]);
            vertex[v] = Aabb {
                min: x[v].min(end) - grow,
                max: x[v].max(end) + grow,
            };
        }
        let edge = prims
            .edges
            .iter()
            .map(|&[a, b]| vertex[a].union(vertex[b]))
            .collect();
        let triangle = prims
            .triangles
            .iter()
            .map(|&[a, b, c]| vertex[a].union(vertex[b]).union(vertex[c]))
            .collect();
        Self {
            vertex,
            edge,
            triangle,
        }
    }
}

/// A uniform hash of boxes (see the module documentation).
struct Grid {
    cell: f64,
    cells: CellMap,
    large: Vec<usize>,
}

impl Grid {
    fn range(&self, b: &Aabb) -> Option<([i64; 3], [i64; 3])> {
        let lo = (b.min / self.cell).floor();
        let hi = (b.max / self.cell).floor();
        let count = (hi - lo + DVec3::ONE).max(DVec3::ZERO);
        // A box whose cell range is not finite or too large is not hashed.
        if !(lo.is_finite() && hi.is_finite()) || count.x * count.y * count.z > MAX_CELLS as f64 {
            return None;
        }
        Some((
            [lo.x as i64, lo.y as i64, lo.z as i64],
            [hi.x as i64, hi.y as i64, hi.z as i64],
        ))
    }

    fn new(boxes: &[Aabb], cell: f64) -> Self {
        let mut grid = Self {
            cell,
            cells: CellMap::default(),
            large: Vec::new(),
        };
        for (i, b) in boxes.iter().enumerate() {
            match grid.range(b) {
                Some((lo, hi)) => {
                    for cx in lo[0]..=hi[0] {
                        for cy in lo[1]..=hi[1] {
                            for cz in lo[2]..=hi[2] {
                                grid.cells.entry([cx, cy, cz]).or_default().push(i);
                            }
                        }
                    }
                }
                None => grid.large.push(i),
            }
        }
        grid
    }

    /// Calls `found` with every hashed box index sharing a cell with `b` (possibly more
    /// than once) and every large one; a query box too large to hash visits all `count`.
    fn query(&self, b: &Aabb, count: usize, mut found: impl FnMut(usize)) {
        match self.range(b) {
            Some((lo, hi)) => {
                for cx in lo[0]..=hi[0] {
                    for cy in lo[1]..=hi[1] {
                        for cz in lo[2]..=hi[2] {
                            if let Some(list) = self.cells.get(&[cx, cy, cz]) {
                                list.iter().for_each(|&i| found(i));
                            }
                        }
                    }
                }
                self.large.iter().for_each(|&i| found(i));
            }
            None => (0..count).for_each(found),
        }
    }
}

/// The candidate pairs within `margin` at `x` (`dx = None`) or anywhere on the step from
/// `x` to `x + dx`, sorted, by the spatial hash. Vertex-triangle pairs and edge-edge
/// pairs whose primitives share a vertex are left out, and so are pairs for which
/// `skip` holds for every vertex of both primitives (two fixed primitives).
#[must_use]
pub fn candidates(
    prims: &Primitives,
    x: &[DVec3],
    dx: Option<&[DVec3]>,
    margin: f64,
    skip: &[bool],
) -> Vec<Candidate> {
    let boxes = Boxes::new(prims, x, dx, margin);
    if prims.triangles.is_empty() {
        return Vec::new();
    }
    let mean_extent = boxes
        .triangle
        .iter()
        .map(|b| (b.max - b.min).max_element())
        .sum::<f64>()
        / prims.triangles.len() as f64;
    let cell = if mean_extent.is_finite() && mean_extent > 0.0 {
        mean_extent
    } else {
        1.0
    };
    let mut out = Vec::new();
    let triangles = Grid::new(&boxes.triangle, cell);
    let mut found = Vec::new();
    for &v in &prims.vertices {
        found.clear();
        triangles.query(&boxes.vertex[v], prims.triangles.len(), |t| found.push(t));
        found.sort_unstable();
        found.dedup();
        for &t in &found {
            if point_triangle_kept(prims, &boxes, skip, v, t) {
                out.push(Candidate::PointTriangle {
                    vertex: v,
                    triangle: t,
                });
            }
        }
    }
    let edges = Grid::new(&boxes.edge, cell);
    for a in 0..prims.edges.len() {
        found.clear();
        edges.query(&boxes.edge[a], prims.edges.len(), |b| {
            if b > a {
                found.push(b);
            }
        });
        found.sort_unstable();
        found.dedup();
        for &b in &found {
            if edge_edge_kept(prims, &boxes, skip, a, b) {
                out.push(Candidate::EdgeEdge { a, b });
            }
        }
    }
    out.sort_unstable();
    out
}

fn point_triangle_kept(
    prims: &Primitives,
    boxes: &Boxes,
    skip: &[bool],
    v: usize,
    t: usize,
) -> bool {
    let tri = prims.triangles[t];
    let shares = tri.contains(&v);
    let both_skipped = skip[v] && tri.iter().all(|&w| skip[w]);
    !shares && !both_skipped && boxes.vertex[v].overlaps(&boxes.triangle[t])
}

fn edge_edge_kept(prims: &Primitives, boxes: &Boxes, skip: &[bool], a: usize, b: usize) -> bool {
    let (ea, eb) = (prims.edges[a], prims.edges[b]);
    let shares = ea.iter().any(|v| eb.contains(v));
    let both_skipped = ea.iter().chain(&eb).all(|&w| skip[w]);
    !shares && !both_skipped && boxes.edge[a].overlaps(&boxes.edge[b])
}

/// The same set as [`candidates`], by testing every pair (for tests and tiny meshes).
#[must_use]
pub fn candidates_brute_force(
    prims: &Primitives,
    x: &[DVec3],
    dx: Option<&[DVec3]>,
    margin: f64,
    skip: &[bool],
) -> Vec<Candidate> {
    let boxes = Boxes::new(prims, x, dx, margin);
    let mut out = Vec::new();
    for &v in &prims.vertices {
        for t in 0..prims.triangles.len() {
            if point_triangle_kept(prims, &boxes, skip, v, t) {
                out.push(Candidate::PointTriangle {
                    vertex: v,
                    triangle: t,
                });
            }
        }
    }
    for a in 0..prims.edges.len() {
        for b in a + 1..prims.edges.len() {
            if edge_edge_kept(prims, &boxes, skip, a, b) {
                out.push(Candidate::EdgeEdge { a, b });
            }
        }
    }
    out.sort_unstable();
    out
}
