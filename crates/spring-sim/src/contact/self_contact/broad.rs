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
//! The hash's cells are boxes whose side along each axis is the triangles' boxes' mean
//! extent along it (but at least a quarter of the largest such side): the boxes of a
//! sheet swept along its normal are several times taller than wide, and cubic cells the
//! size of their height would hold many times the triangles a box can meet. Each
//! triangle (and each edge, in a second table) is listed in the cells its box touches,
//! and each vertex (edge) box looks up the cells it touches. The table is flat (a
//! counting sort of the boxes by their cells' buckets), so a rebuild allocates a few
//! arrays, not a list per cell. A box touching more than
//! [`MAX_CELLS`] cells (a primitive swept far) is kept in a short list tested against
//! every query instead. Each query's pairs are sorted on their own and appended in the
//! queries' order (vertices, then edges, ascending), which is the sorted order of the
//! whole list; the queries run in chunks on the caller's thread pool when there is one
//! (each chunk's pairs are its own, joined in the chunks' order, so the list does not
//! depend on the threads). The result is sorted and free of duplicates, and is exactly
//! the set [`candidates_brute_force`] finds by testing every pair.

use super::distance::PairKind;
use sinew_math::DVec3;

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

impl Candidate {
    /// The pair's kind and its four particles in the order the distance functions take
    /// them: the vertex, then the triangle's three; or the first edge's two, then the
    /// second's.
    #[must_use]
    pub fn kind_and_particles(self, prims: &Primitives) -> (PairKind, [usize; 4]) {
        match self {
            Candidate::PointTriangle { vertex, triangle } => {
                let [a, b, t] = prims.triangles[triangle];
                (PairKind::PointTriangle, [vertex, a, b, t])
            }
            Candidate::EdgeEdge { a, b } => {
                let (ea, eb) = (prims.edges[a], prims.edges[b]);
                (PairKind::EdgeEdge, [ea[0], ea[1], eb[0], eb[1]])
            }
        }
    }
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
        let edges = crate::mesh::unique_edges(triangles);
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

/// A uniform hash of boxes (see the module documentation), stored flat: the cells are
/// hashed into a power-of-two table of buckets, and the boxes' indices are laid out bucket
/// after bucket by a counting sort (`start[k]..start[k + 1]` of `items` is bucket `k`).
/// Building it costs a few allocations rather than one per cell, which the hash map it
/// replaces spent most of its time on. Two cells may share a bucket; the queries then see
/// a few boxes from the other cell, which the exact overlap test of every candidate
/// removes.
struct Grid {
    cell: DVec3,
    /// `64 - log2(buckets)`: the top bits of the multiplied key pick the bucket.
    shift: u32,
    start: Vec<usize>,
    items: Vec<usize>,
    large: Vec<usize>,
}

/// A cell's bucket: the coordinates mixed by large odd multipliers and the product's top
/// bits kept (Fibonacci hashing), which spreads neighbouring cells over the table.
fn bucket_of(c: [i64; 3], shift: u32) -> usize {
    let h = (c[0] as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
        ^ (c[1] as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f)
        ^ (c[2] as u64).wrapping_mul(0x1656_67b1_9e37_79f9);
    (h.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> shift) as usize
}

/// Calls `visit` with every cell of the inclusive range `lo..=hi`.
fn for_cells(lo: [i64; 3], hi: [i64; 3], mut visit: impl FnMut([i64; 3])) {
    for cx in lo[0]..=hi[0] {
        for cy in lo[1]..=hi[1] {
            for cz in lo[2]..=hi[2] {
                visit([cx, cy, cz]);
            }
        }
    }
}

fn cell_range(cell: DVec3, b: &Aabb) -> Option<([i64; 3], [i64; 3])> {
    let lo = (b.min / cell).floor();
    let hi = (b.max / cell).floor();
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

impl Grid {
    fn new(boxes: &[Aabb], cell: DVec3) -> Self {
        let ranges: Vec<Option<([i64; 3], [i64; 3])>> =
            boxes.iter().map(|b| cell_range(cell, b)).collect();
        let entries: usize = ranges
            .iter()
            .flatten()
            .map(|(lo, hi)| {
                (0..3)
                    .map(|k| (hi[k] - lo[k] + 1) as usize)
                    .product::<usize>()
            })
            .sum();
        // About two buckets per entry keeps the collisions rare.
        let buckets = (2 * entries).next_power_of_two().max(2);
        let shift = 64 - buckets.trailing_zeros();
        let mut start = vec![0usize; buckets + 1];
        let mut large = Vec::new();
        for (i, range) in ranges.iter().enumerate() {
            match range {
                Some((lo, hi)) => for_cells(*lo, *hi, |c| start[bucket_of(c, shift) + 1] += 1),
                None => large.push(i),
            }
        }
        for k in 0..buckets {
            start[k + 1] += start[k];
        }
        let mut fill = start.clone();
        let mut items = vec![0usize; entries];
        for (i, range) in ranges.iter().enumerate() {
            if let Some((lo, hi)) = range {
                for_cells(*lo, *hi, |c| {
                    let k = bucket_of(c, shift);
                    items[fill[k]] = i;
                    fill[k] += 1;
                });
            }
        }
        Self {
            cell,
            shift,
            start,
            items,
            large,
        }
    }

    /// Calls `found` with every hashed box index sharing a bucket with a cell of `b`
    /// (possibly more than once) and every large one; a query box too large to hash
    /// visits all `count`.
    fn query(&self, b: &Aabb, count: usize, mut found: impl FnMut(usize)) {
        match cell_range(self.cell, b) {
            Some((lo, hi)) => {
                for_cells(lo, hi, |c| {
                    let k = bucket_of(c, self.shift);
                    self.items[self.start[k]..self.start[k + 1]]
                        .iter()
                        .for_each(|&i| found(i));
                });
                self.large.iter().for_each(|&i| found(i));
            }
            None => (0..count).for_each(found),
        }
    }
}

/// The hash's cell: per axis the mean extent of `boxes` along it, at least a quarter of
/// the largest of the three (a flat sheet's boxes have no extent across it), or a unit
/// cube when the boxes give no finite positive size.
fn cell_size(boxes: &[Aabb]) -> DVec3 {
    let mean = boxes
        .iter()
        .fold(DVec3::ZERO, |sum, b| sum + (b.max - b.min))
        / boxes.len() as f64;
    let largest = mean.max_element();
    if mean.is_finite() && largest > 0.0 {
        mean.max(DVec3::splat(0.25 * largest))
    } else {
        DVec3::ONE
    }
}

/// The primitives' boxes and the hash's cell (see [`candidates`]), or `None` when the
/// mesh has no triangle (no pair).
fn boxes_and_cell(
    prims: &Primitives,
    x: &[DVec3],
    dx: Option<&[DVec3]>,
    margin: f64,
) -> Option<(Boxes, DVec3)> {
    if prims.triangles.is_empty() {
        return None;
    }
    let boxes = Boxes::new(prims, x, dx, margin);
    let cell = cell_size(&boxes.triangle);
    Some((boxes, cell))
}

/// Queries per task when the broad phase runs on a pool: a query costs about a
/// microsecond, so a task is a few hundred microseconds.
const QUERIES_PER_TASK: usize = 512;

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
    match boxes_and_cell(prims, x, dx, margin) {
        Some((boxes, cell)) => candidates_of(prims, &boxes, cell, skip),
        None => Vec::new(),
    }
}

/// [`candidates`] for the primitives' `boxes` and the hash's `cell`.
///
/// A primitive whose vertices are all skipped (a piece of an obstacle pinned whole)
/// pairs only with primitives that have a free vertex, so the skipped primitives are
/// hashed apart from the others and only free vertices and edges with a free vertex
/// look them up: an obstacle meshed far more finely than the cloth costs its own
/// hashing and its primitives' lookups among the free ones, not a lookup of every
/// obstacle primitive among its neighbours, each then refused. A query's pairs from the
/// two tables are sorted together, so the list is the same as with one table.
fn candidates_of(prims: &Primitives, boxes: &Boxes, cell: DVec3, skip: &[bool]) -> Vec<Candidate> {
    // Which primitives have every vertex skipped (none to mark when no vertex is).
    let all_skipped = |vertices: &[usize]| vertices.iter().all(|&w| skip[w]);
    let (skipped_triangles, skipped_edges): (Vec<bool>, Vec<bool>) = if skip.contains(&true) {
        (
            prims.triangles.iter().map(|t| all_skipped(t)).collect(),
            prims.edges.iter().map(|e| all_skipped(e)).collect(),
        )
    } else {
        (Vec::new(), Vec::new())
    };
    // The vertex-triangle pairs and the edge-edge pairs side by side, each pair of
    // tables built by one thread while the other builds its own (built one after the
    // other, the two hashes were 5% of the twisted sheet's minimizing thread, the other
    // thread idle), then the queries of both shared.
    let (mut out, mut edge_pairs) = crate::pool::join_if(
        crate::pool::shared(),
        || {
            let tables = Tables::new(&boxes.triangle, &skipped_triangles, cell);
            tables.queries(prims.vertices.len(), |tables, range, part| {
                let mut found = Found::new(prims.triangles.len());
                for &v in &prims.vertices[range] {
                    tables.query(&boxes.vertex[v], !skip[v], |t| {
                        found.meet(t, v, || point_triangle_kept(prims, boxes, skip, v, t));
                    });
                    found.append(part, |t| Candidate::PointTriangle {
                        vertex: v,
                        triangle: t,
                    });
                }
            })
        },
        || {
            let tables = Tables::new(&boxes.edge, &skipped_edges, cell);
            tables.queries(prims.edges.len(), |tables, range, part| {
                let mut found = Found::new(prims.edges.len());
                for a in range {
                    let free = skipped_edges.get(a).is_none_or(|s| !s);
                    tables.query(&boxes.edge[a], free, |b| {
                        if b > a {
                            found.meet(b, a, || edge_edge_kept(prims, boxes, skip, a, b));
                        }
                    });
                    found.append(part, |b| Candidate::EdgeEdge { a, b });
                }
            })
        },
    );
    out.append(&mut edge_pairs);
    out
}

/// The boxes of one kind of primitive hashed in two tables: those with a free vertex,
/// and those whose vertices are all skipped (`skipped[i]`; none when `skipped` is
/// empty). A query reports the boxes' own indices.
struct Tables {
    free: Subset,
    skipped: Subset,
}

/// Some of the boxes hashed: `index[k]` is the `k`-th hashed box's own index (all of
/// them, in order, when `index` is `None`).
struct Subset {
    grid: Grid,
    index: Option<Vec<usize>>,
    count: usize,
}

impl Subset {
    fn new(all: &[Aabb], index: Option<Vec<usize>>, cell: DVec3) -> Self {
        let (grid, count) = match &index {
            Some(index) => {
                let some: Vec<Aabb> = index.iter().map(|&i| all[i]).collect();
                (Grid::new(&some, cell), index.len())
            }
            None => (Grid::new(all, cell), all.len()),
        };
        Self { grid, index, count }
    }

    fn query(&self, b: &Aabb, mut found: impl FnMut(usize)) {
        match &self.index {
            Some(index) => self.grid.query(b, self.count, |k| found(index[k])),
            None => self.grid.query(b, self.count, found),
        }
    }
}

impl Tables {
    fn new(boxes: &[Aabb], skipped: &[bool], cell: DVec3) -> Self {
        let (free, skipped) = if skipped.contains(&true) {
            let (held, free): (Vec<usize>, Vec<usize>) =
                (0..boxes.len()).partition(|&i| skipped[i]);
            (Some(free), held)
        } else {
            (None, Vec::new())
        };
        Self {
            free: Subset::new(boxes, free, cell),
            skipped: Subset::new(boxes, Some(skipped), cell),
        }
    }

    /// Calls `found` with every box that may overlap `b` among those with a free
    /// vertex, and among the skipped ones too when `free` (the querying primitive has a
    /// free vertex; see [`Grid::query`] for repeats).
    fn query(&self, b: &Aabb, free: bool, mut found: impl FnMut(usize)) {
        self.free.query(b, &mut found);
        if free && self.skipped.count > 0 {
            self.skipped.query(b, found);
        }
    }

    /// What `scan(self, range, part)` appends for the consecutive ranges of
    /// [`QUERIES_PER_TASK`] queries covering `0..queries`, in order (as tasks on the
    /// caller's pool when there is one, see `spread::concat_chunks`).
    fn queries(
        &self,
        queries: usize,
        scan: impl Fn(&Self, std::ops::Range<usize>, &mut Vec<Candidate>) + Sync + Send,
    ) -> Vec<Candidate> {
        let mut out = Vec::new();
        super::spread::concat_chunks(&mut out, queries, QUERIES_PER_TASK, |range, part| {
            scan(self, range, part);
        });
        out
    }
}

/// The pairs `(edge, triangle)` of an edge and a triangle sharing no vertex whose boxes
/// at `x` overlap, in edge order then triangle order, leaving out pairs for which `skip`
/// holds for every vertex of both (two fixed primitives), and, when `moved` is given
/// (indexed by vertex), pairs with no vertex in it: the pairs in which an edge may pass
/// through a triangle (see [`super::crossing`]). Runs on the calling thread: it serves
/// the check of a start state (at most once per step, and with `moved` over the few
/// primitives a driven move touches), not the iterations.
#[must_use]
pub fn edge_triangle_candidates(
    prims: &Primitives,
    x: &[DVec3],
    skip: &[bool],
    moved: Option<&[bool]>,
) -> Vec<(usize, usize)> {
    let Some((boxes, cell)) = boxes_and_cell(prims, x, None, 0.0) else {
        return Vec::new();
    };
    let touches = |vertices: &[usize]| moved.is_none_or(|m| vertices.iter().any(|&v| m[v]));
    // An edge that moved looks up every triangle; one that did not, the triangles that
    // moved (hashed apart, and only when some did not).
    let every = Subset::new(&boxes.triangle, None, cell);
    let moved_triangles = moved.map(|_| {
        let some = (0..prims.triangles.len()).filter(|&t| touches(&prims.triangles[t]));
        Subset::new(&boxes.triangle, Some(some.collect()), cell)
    });
    let mut found = Found::new(prims.triangles.len());
    let mut out = Vec::new();
    for (e, &[a, b]) in prims.edges.iter().enumerate() {
        let table = match &moved_triangles {
            Some(table) if !touches(&[a, b]) => table,
            _ => &every,
        };
        table.query(&boxes.edge[e], |t| {
            found.meet(t, e, || {
                let tri = prims.triangles[t];
                let shares = tri.contains(&a) || tri.contains(&b);
                let both_skipped = skip[a] && skip[b] && tri.iter().all(|&w| skip[w]);
                !shares && !both_skipped && boxes.edge[e].overlaps(&boxes.triangle[t])
            });
        });
        found.kept.sort_unstable();
        out.extend(found.kept.drain(..).map(|t| (e, t)));
    }
    out
}

/// The pairs of [`candidates`]`(prims, x, dx, margin, skip)` that have a vertex in
/// `moving` (indexed by vertex), in the same order, without hashing the whole mesh
/// against itself: for a step that moves a few vertices (the pinned particles of a
/// driven move), only the boxes of the primitives touching a moving vertex are hashed,
/// and every other primitive looks them up (a moving vertex, triangle or edge met by a
/// query is then tested exactly as [`candidates`] tests it). Runs on the calling thread:
/// the moving primitives are few.
#[must_use]
pub fn candidates_touching(
    prims: &Primitives,
    x: &[DVec3],
    dx: Option<&[DVec3]>,
    margin: f64,
    skip: &[bool],
    moving: &[bool],
) -> Vec<Candidate> {
    let Some((boxes, cell)) = boxes_and_cell(prims, x, dx, margin) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    // A vertex that moves against every triangle: its box hashed, each triangle's box
    // looking it up.
    let vertices = prims.vertices.iter().copied().filter(|&v| moving[v]);
    let hashed = Subset::new(&boxes.vertex, Some(vertices.collect()), cell);
    let mut found = Found::new(boxes.vertex.len());
    for (t, b) in boxes.triangle.iter().enumerate() {
        hashed.query(b, |v| {
            found.meet(v, t, || point_triangle_kept(prims, &boxes, skip, v, t));
        });
        out.extend(found.kept.drain(..).map(|v| Candidate::PointTriangle {
            vertex: v,
            triangle: t,
        }));
    }
    // A vertex that stands still against every triangle that moves.
    let triangles = (0..prims.triangles.len())
        .filter(|&t| prims.triangles[t].iter().any(|&v| moving[v]))
        .collect();
    let hashed = Subset::new(&boxes.triangle, Some(triangles), cell);
    let mut found = Found::new(prims.triangles.len());
    for &v in prims.vertices.iter().filter(|&&v| !moving[v]) {
        hashed.query(&boxes.vertex[v], |t| {
            found.meet(t, v, || point_triangle_kept(prims, &boxes, skip, v, t));
        });
        out.extend(found.kept.drain(..).map(|t| Candidate::PointTriangle {
            vertex: v,
            triangle: t,
        }));
    }
    // Every edge against the edges that move (a pair of two moving edges is met from
    // both, and kept once).
    let edges = (0..prims.edges.len())
        .filter(|&e| prims.edges[e].iter().any(|&v| moving[v]))
        .collect();
    let hashed = Subset::new(&boxes.edge, Some(edges), cell);
    let mut found = Found::new(prims.edges.len());
    for (a, b) in boxes.edge.iter().enumerate() {
        hashed.query(b, |e| {
            let (lo, hi) = (a.min(e), a.max(e));
            found.meet(e, a, || {
                lo != hi && edge_edge_kept(prims, &boxes, skip, lo, hi)
            });
        });
        out.extend(found.kept.drain(..).map(|e| Candidate::EdgeEdge {
            a: a.min(e),
            b: a.max(e),
        }));
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// One task's record of the boxes its queries met: a box is met once per shared cell
/// (and per bucket collision), and `seen[i]` holds the last query that met box `i`, so
/// each pair is tested once without sorting the hits; the kept ones of the current query
/// wait in `kept` to be sorted and appended.
struct Found {
    seen: Vec<usize>,
    kept: Vec<usize>,
}

impl Found {
    fn new(boxes: usize) -> Self {
        Self {
            seen: vec![usize::MAX; boxes],
            kept: Vec::new(),
        }
    }

    /// Box `i` met by query `query`: tested by `keep` the first time.
    fn meet(&mut self, i: usize, query: usize, keep: impl FnOnce() -> bool) {
        if self.seen[i] != query {
            self.seen[i] = query;
            if keep() {
                self.kept.push(i);
            }
        }
    }

    /// The current query's kept boxes, ascending, appended to `out` as pairs.
    fn append(&mut self, out: &mut Vec<Candidate>, pair: impl Fn(usize) -> Candidate) {
        self.kept.sort_unstable();
        out.extend(self.kept.drain(..).map(pair));
    }
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

/// The broad phase's pairs over one region of state space, kept so later queries inside
/// it filter the list instead of hashing the mesh again.
///
/// Built like [`candidates`] (`x`, an optional step `dx`, `margin`, `skip`), it keeps the
/// grown box of every vertex and the pairs found. A later query (the same primitives,
/// `x'`, `dx'`, the same `margin` and `skip`) is covered when every vertex's grown box for the query lies
/// inside the kept one. Then every edge and triangle box of the query (a union of its
/// vertices' boxes) lies inside the kept box of the same primitive, so two primitives
/// whose query boxes overlap also had overlapping kept boxes: every pair the query would
/// find is in the list, and testing the listed pairs' query boxes for overlap gives
/// exactly [`candidates`]'s answer for the query (the same set, in the same sorted order).
#[derive(Clone, Debug, Default)]
pub struct CandidateCache {
    vertex: Vec<Aabb>,
    margin: f64,
    skip: Vec<bool>,
    list: Vec<Candidate>,
}

impl CandidateCache {
    /// The pairs of [`candidates`] for `x`, `dx`, `margin` and `skip`, kept with their
    /// region.
    #[must_use]
    pub fn new(
        prims: &Primitives,
        x: &[DVec3],
        dx: Option<&[DVec3]>,
        margin: f64,
        skip: &[bool],
    ) -> Self {
        Self::with_slack(prims, x, dx, margin, 0.0, skip)
    }

    /// As [`Self::new`], with every kept box grown by a further `slack / 2` (`slack >=
    /// 0`): the list is [`candidates`] with the margin `margin + slack`, so it holds
    /// every pair whose grown boxes overlap, and the region covers queries (with
    /// `margin`) that reach up to that much farther. The argument of the type's
    /// documentation holds as it is: the list is exactly the set of pairs whose kept
    /// boxes overlap, and a covered query's boxes lie inside the kept ones.
    #[must_use]
    pub fn with_slack(
        prims: &Primitives,
        x: &[DVec3],
        dx: Option<&[DVec3]>,
        margin: f64,
        slack: f64,
        skip: &[bool],
    ) -> Self {
        let reach = margin + slack;
        let (vertex, list) = match boxes_and_cell(prims, x, dx, reach) {
            Some((boxes, cell)) => {
                let list = candidates_of(prims, &boxes, cell, skip);
                (boxes.vertex, list)
            }
            None => (Boxes::new(prims, x, dx, reach).vertex, Vec::new()),
        };
        Self {
            vertex,
            margin,
            skip: skip.to_vec(),
            list,
        }
    }

    /// Whether a query (see [`Self::query`]) is covered by the kept region.
    #[must_use]
    pub fn covers(
        &self,
        prims: &Primitives,
        x: &[DVec3],
        dx: Option<&[DVec3]>,
        margin: f64,
        skip: &[bool],
    ) -> bool {
        self.covering_boxes(prims, x, dx, margin, skip).is_some()
    }

    /// The query's boxes when the kept region covers it.
    fn covering_boxes(
        &self,
        prims: &Primitives,
        x: &[DVec3],
        dx: Option<&[DVec3]>,
        margin: f64,
        skip: &[bool],
    ) -> Option<Boxes> {
        if margin != self.margin || skip != self.skip.as_slice() || x.len() != self.vertex.len() {
            return None;
        }
        let boxes = Boxes::new(prims, x, dx, margin);
        let inside = prims.vertices.iter().all(|&v| {
            let (q, k) = (&boxes.vertex[v], &self.vertex[v]);
            q.min.cmpge(k.min).all() && q.max.cmple(k.max).all()
        });
        inside.then_some(boxes)
    }

    /// Whether the list was built for the fixed flags `skip` (a query with others is
    /// never covered).
    #[must_use]
    pub fn skips(&self, skip: &[bool]) -> bool {
        self.skip.as_slice() == skip
    }

    /// The number of pairs kept.
    #[must_use]
    pub fn len(&self) -> usize {
        self.list.len()
    }

    /// Whether no pair is kept.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    /// The kept pairs, in [`candidates`]'s order.
    #[must_use]
    pub fn list(&self) -> &[Candidate] {
        &self.list
    }

    /// Exactly [`candidates`]`(prims, x, dx, margin, skip)` when the query is covered
    /// (see the type's documentation), by filtering the kept list; `None` when it is not.
    #[must_use]
    pub fn query(
        &self,
        prims: &Primitives,
        x: &[DVec3],
        dx: Option<&[DVec3]>,
        margin: f64,
        skip: &[bool],
    ) -> Option<Vec<Candidate>> {
        self.query_indices(prims, x, dx, margin, skip)
            .map(|found| found.into_iter().map(|i| self.list[i]).collect())
    }

    /// The positions in [`Self::list`] of the pairs [`Self::query`] answers (ascending,
    /// so the pairs come in the same order); `None` when the query is not covered. A
    /// caller keeping values per kept pair (each pair's gap at the state the list was
    /// built at) looks them up by these positions.
    #[must_use]
    pub fn query_indices(
        &self,
        prims: &Primitives,
        x: &[DVec3],
        dx: Option<&[DVec3]>,
        margin: f64,
        skip: &[bool],
    ) -> Option<Vec<usize>> {
        let mut out = Vec::new();
        self.query_indices_into(prims, x, dx, margin, skip, &mut out)
            .then_some(out)
    }

    /// [`Self::query_indices`] into `out` (cleared first, its storage reused): true when
    /// the query is covered and `out` holds the answer. The box tests run on the
    /// caller's thread pool when it has one (each test is independent and the positions
    /// are gathered in order, so the answer does not depend on the threads).
    pub fn query_indices_into(
        &self,
        prims: &Primitives,
        x: &[DVec3],
        dx: Option<&[DVec3]>,
        margin: f64,
        skip: &[bool],
        out: &mut Vec<usize>,
    ) -> bool {
        out.clear();
        let Some(boxes) = self.covering_boxes(prims, x, dx, margin, skip) else {
            return false;
        };
        // A listed pair shares no vertex and has a free vertex (the list was built with
        // the same `skip`, checked above): only its boxes' overlap is left to test.
        let list = &self.list;
        super::spread::filter_indices(list.len(), out, |i| match list[i] {
            Candidate::PointTriangle { vertex, triangle } => {
                boxes.vertex[vertex].overlaps(&boxes.triangle[triangle])
            }
            Candidate::EdgeEdge { a, b } => boxes.edge[a].overlaps(&boxes.edge[b]),
        });
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two 24 x 24 sheets 0.02 apart (more queries than one task takes), the lower one
    /// swept 0.1 along its normal and slightly sheared, so the swept boxes are five times
    /// taller than wide and the cells are not cubes.
    fn stacked_sheets() -> (Vec<DVec3>, Vec<DVec3>, Vec<[usize; 3]>) {
        const N: usize = 24;
        let mut x = Vec::new();
        let mut dx = Vec::new();
        let mut triangles = Vec::new();
        for sheet in 0..2 {
            let base = x.len();
            for i in 0..N {
                for j in 0..N {
                    let wobble = 1e-3 * ((7 * i + 3 * j) % 5) as f64;
                    x.push(DVec3::new(
                        0.01 * i as f64,
                        0.02 * sheet as f64 + wobble,
                        0.01 * j as f64,
                    ));
                    let lift = if sheet == 0 { 0.1 } else { 0.0 };
                    dx.push(DVec3::new(1e-3 * (j % 3) as f64, lift, 0.0));
                }
            }
            for i in 0..N - 1 {
                for j in 0..N - 1 {
                    let a = base + i * N + j;
                    triangles.push([a, a + N, a + 1]);
                    triangles.push([a + 1, a + N, a + N + 1]);
                }
            }
        }
        (x, dx, triangles)
    }

    #[test]
    fn the_cells_follow_the_boxes_and_the_pairs_are_the_brute_force_ones() {
        let (x, dx, triangles) = stacked_sheets();
        let prims = Primitives::new(&triangles);
        let skip = vec![false; x.len()];
        let boxes = Boxes::new(&prims, &x, Some(&dx), 3e-3);
        let cell = cell_size(&boxes.triangle);
        assert!(cell.y > 3.0 * cell.x && cell.y > 3.0 * cell.z, "{cell}");
        assert!(prims.vertices.len() > QUERIES_PER_TASK);
        for sweep in [None, Some(dx.as_slice())] {
            let slow = candidates_brute_force(&prims, &x, sweep, 3e-3, &skip);
            let fast = candidates(&prims, &x, sweep, 3e-3, &skip);
            assert_eq!(fast, slow, "sweep {}", sweep.is_some());
            assert!(!fast.is_empty());
            #[cfg(feature = "parallel")]
            for threads in [2, 3] {
                let on_pool = super::super::spread::pool(threads)
                    .install(|| candidates(&prims, &x, sweep, 3e-3, &skip));
                assert_eq!(
                    on_pool,
                    slow,
                    "{threads} threads, sweep {}",
                    sweep.is_some()
                );
            }
        }
    }

    /// With the lower sheet held whole (an obstacle) and a row and a few scattered
    /// vertices of the upper one held, the skipped primitives hash apart and only free
    /// queries look them up: the list is still the brute-force one, on any pool, it
    /// holds pairs of a free primitive with a skipped one of both kinds, and none of
    /// two skipped ones.
    #[test]
    fn an_obstacle_held_whole_gives_the_brute_force_pairs() {
        let (x, dx, triangles) = stacked_sheets();
        let prims = Primitives::new(&triangles);
        let mut skip = vec![false; x.len()];
        for v in (0..576).chain(576..600).chain((600..x.len()).step_by(41)) {
            skip[v] = true;
        }
        let skipped = |c: Candidate| pair_vertices(&prims, c);
        for sweep in [None, Some(dx.as_slice())] {
            let slow = candidates_brute_force(&prims, &x, sweep, 3e-3, &skip);
            let fast = candidates(&prims, &x, sweep, 3e-3, &skip);
            assert_eq!(fast, slow, "sweep {}", sweep.is_some());
            #[cfg(feature = "parallel")]
            for threads in [2, 3] {
                let on_pool = super::super::spread::pool(threads)
                    .install(|| candidates(&prims, &x, sweep, 3e-3, &skip));
                assert_eq!(on_pool, slow, "{threads} threads");
            }
            // Pairs of a free primitive with one held whole, of both kinds.
            let held = |v: &[usize]| v.iter().all(|&w| skip[w]);
            let with_held = |kind: usize| {
                fast.iter().any(|&c| {
                    let v = skipped(c);
                    let (first, second) = match c {
                        Candidate::PointTriangle { .. } => v.split_at(3),
                        Candidate::EdgeEdge { .. } => v.split_at(2),
                    };
                    let k = usize::from(matches!(c, Candidate::EdgeEdge { .. }));
                    k == kind && held(first) != held(second)
                })
            };
            assert!(with_held(0) && with_held(1), "sweep {}", sweep.is_some());
            assert!(fast.iter().all(|&c| !held(&skipped(c))));
        }
    }

    /// The vertices of a pair (a vertex and a triangle's three, or two edges' four).
    fn pair_vertices(prims: &Primitives, c: Candidate) -> Vec<usize> {
        match c {
            Candidate::PointTriangle { vertex, triangle } => {
                let mut v = prims.triangles[triangle].to_vec();
                v.push(vertex);
                v
            }
            Candidate::EdgeEdge { a, b } => [prims.edges[a], prims.edges[b]].concat(),
        }
    }

    #[test]
    fn the_pairs_touching_a_moving_vertex_are_the_full_lists_pairs_that_touch_one() {
        let (x, dx, triangles) = stacked_sheets();
        let prims = Primitives::new(&triangles);
        // The lower sheet's first row and a scattered few of the upper sheet's vertices
        // move; one vertex of the upper sheet is skipped (fixed) too.
        let mut moving = vec![false; x.len()];
        for v in (0..24).chain((600..x.len()).step_by(37)) {
            moving[v] = true;
        }
        let mut skip = vec![false; x.len()];
        skip[600] = true;
        skip[0] = true;
        for sweep in [None, Some(dx.as_slice())] {
            let all = candidates(&prims, &x, sweep, 3e-3, &skip);
            let touching: Vec<Candidate> = all
                .iter()
                .copied()
                .filter(|&c| pair_vertices(&prims, c).iter().any(|&v| moving[v]))
                .collect();
            let fast = candidates_touching(&prims, &x, sweep, 3e-3, &skip, &moving);
            assert!(
                fast == touching,
                "sweep {}: {} pairs against {}",
                sweep.is_some(),
                fast.len(),
                touching.len()
            );
            assert!(fast.len() < all.len());
            for kind in [0, 1] {
                assert!(
                    fast.iter()
                        .any(|c| matches!(c, Candidate::PointTriangle { .. }) == (kind == 0)),
                    "sweep {}: no pair of kind {kind}",
                    sweep.is_some()
                );
            }
        }
        // Nothing moving: no pair; everything moving: every pair.
        let none = vec![false; x.len()];
        assert!(candidates_touching(&prims, &x, Some(&dx), 3e-3, &skip, &none).is_empty());
        let every = vec![true; x.len()];
        assert_eq!(
            candidates_touching(&prims, &x, Some(&dx), 3e-3, &skip, &every),
            candidates(&prims, &x, Some(&dx), 3e-3, &skip)
        );
    }

    #[test]
    fn flat_and_empty_boxes_get_usable_cells() {
        let flat = [Aabb {
            min: DVec3::ZERO,
            max: DVec3::new(1.0, 0.0, 2.0),
        }];
        assert_eq!(cell_size(&flat), DVec3::new(1.0, 0.5, 2.0));
        let point = [Aabb {
            min: DVec3::ONE,
            max: DVec3::ONE,
        }];
        assert_eq!(cell_size(&point), DVec3::ONE);
        let nan = [Aabb {
            min: DVec3::splat(f64::NAN),
            max: DVec3::ONE,
        }];
        assert_eq!(cell_size(&nan), DVec3::ONE);
    }
}
