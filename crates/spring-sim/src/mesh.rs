//! Cloth from triangle meshes: a validated [`TriangleMesh`], its edges and hinges, and
//! [`MeshCloth`], which turns a mesh into a mass-spring system with masses lumped from
//! the triangles' areas, stretch springs on the edges and one of two bending models
//! ([`Bending`]): springs across each interior edge, or the discrete-shell dihedral
//! energy of [`crate::potential::DihedralBending`].
//!
//! Also here: [`ClothGrid::triangles`], the triangles of the grid cloth, so every cloth has
//! a surface, [`MeshClothModel::enable_contact`], the cloth's contact with rigid
//! colliders ([`crate::contact`]), and [`MeshClothModel::enable_self_contact`], the
//! cloth's contact with itself ([`crate::contact::self_contact`]).
//!
//! Derivations (the lumped masses, the hinge weight, the dihedral angle's derivatives):
//! docs/bending.md.

use crate::contact::self_contact::{SelfContactSettings, SelfContactStats, enable_self_contact};
use crate::contact::{
    Collider, ContactError, ContactPotential, ContactSettings, ContactStats, ContactTerm,
};
use crate::implicit::{Bdf2, ImplicitMidpoint};
use crate::integrator::Integrator;
use crate::model::{ClothGrid, Material, ModelError, Particle, SpringSpec, SpringSystem};
use crate::newton::{BackwardEuler, NewtonSettings};
use crate::pins::PinnedStepper;
use crate::potential::{DihedralBending, Hinge};
use sinew_math::DVec3;
use std::collections::HashMap;
use std::fmt;
use std::sync::Arc;

/// Why a mesh or a mesh cloth was refused. Every variant names the triangle, vertex or
/// field.
#[derive(Clone, Debug, PartialEq)]
pub enum MeshError {
    /// A mesh needs at least one triangle.
    NoTriangles,
    /// A vertex has a NaN or infinite coordinate.
    NonFiniteVertex {
        /// The vertex.
        vertex: usize,
    },
    /// A triangle refers to a vertex that does not exist.
    IndexOutOfRange {
        /// The triangle.
        triangle: usize,
        /// The index it gave.
        vertex: usize,
        /// The number of vertices.
        len: usize,
    },
    /// A triangle repeats a vertex or has (relatively) zero area.
    DegenerateTriangle {
        /// The triangle.
        triangle: usize,
        /// Its vertices.
        vertices: [usize; 3],
    },
    /// Two triangles have the same three vertices.
    DuplicateTriangle {
        /// The later triangle.
        triangle: usize,
        /// The first one with the same vertices.
        first: usize,
    },
    /// An edge is shared by more than two triangles, so it is no hinge (only an error
    /// where bending needs hinges).
    NonManifoldEdge {
        /// The edge's vertices.
        edge: [usize; 2],
        /// Three of the triangles on it.
        triangles: [usize; 3],
    },
    /// A vertex belongs to no triangle, so it would have no mass.
    UnusedVertex {
        /// The vertex.
        vertex: usize,
    },
    /// A vertex listed as fixed does not exist.
    FixedOutOfRange {
        /// The index given.
        vertex: usize,
        /// The number of vertices.
        len: usize,
    },
    /// A material field is negative, zero where it must be positive, or not finite.
    BadField {
        /// The field.
        field: &'static str,
        /// Its value.
        value: f64,
    },
    /// The mass-spring system refused what the mesh produced.
    Model(ModelError),
}

impl fmt::Display for MeshError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NoTriangles => write!(f, "the mesh has no triangles"),
            Self::NonFiniteVertex { vertex } => {
                write!(f, "vertex {vertex}: a coordinate is NaN or infinite")
            }
            Self::IndexOutOfRange {
                triangle,
                vertex,
                len,
            } => write!(
                f,
                "triangle {triangle}: vertex index {vertex} out of range (the mesh has {len} vertices)"
            ),
            Self::DegenerateTriangle { triangle, vertices } => write!(
                f,
                "triangle {triangle} {vertices:?}: degenerate (a repeated vertex or zero area)"
            ),
            Self::DuplicateTriangle { triangle, first } => write!(
                f,
                "triangle {triangle}: the same vertices as triangle {first}"
            ),
            Self::NonManifoldEdge { edge, triangles } => write!(
                f,
                "edge {edge:?}: shared by more than two triangles ({triangles:?} ...), so bending has no hinge there"
            ),
            Self::UnusedVertex { vertex } => {
                write!(f, "vertex {vertex}: in no triangle, so it has no mass")
            }
            Self::FixedOutOfRange { vertex, len } => write!(
                f,
                "fixed vertex {vertex} out of range (the mesh has {len} vertices)"
            ),
            Self::BadField { field, value } => write!(
                f,
                "{field}: {value} is not allowed (negative, zero or not finite)"
            ),
            Self::Model(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for MeshError {}

impl From<ModelError> for MeshError {
    fn from(e: ModelError) -> Self {
        Self::Model(e)
    }
}

/// A triangle is degenerate when twice its area is at most this fraction of its longest
/// edge squared (relative, so the test does not depend on the mesh's units).
const DEGENERATE_RATIO: f64 = 1e-12;

/// A triangle mesh, validated: finite vertices, indices in range, no degenerate and no
/// duplicate triangles. Manifoldness is checked only where it matters
/// ([`TriangleMesh::hinges`]).
#[derive(Clone, Debug, PartialEq)]
pub struct TriangleMesh {
    positions: Vec<DVec3>,
    triangles: Vec<[usize; 3]>,
}

impl TriangleMesh {
    /// Validates and builds a mesh.
    pub fn new(positions: Vec<DVec3>, triangles: Vec<[usize; 3]>) -> Result<Self, MeshError> {
        if triangles.is_empty() {
            return Err(MeshError::NoTriangles);
        }
        if let Some(vertex) = positions.iter().position(|p| !p.is_finite()) {
            return Err(MeshError::NonFiniteVertex { vertex });
        }
        let len = positions.len();
        let mut seen: HashMap<[usize; 3], usize> = HashMap::with_capacity(triangles.len());
        for (t, tri) in triangles.iter().enumerate() {
            if let Some(&vertex) = tri.iter().find(|&&v| v >= len) {
                return Err(MeshError::IndexOutOfRange {
                    triangle: t,
                    vertex,
                    len,
                });
            }
            let [a, b, c] = tri.map(|v| positions[v]);
            let twice_area = (b - a).cross(c - a).length();
            let longest = (b - a)
                .length_squared()
                .max((c - b).length_squared())
                .max((a - c).length_squared());
            if tri[0] == tri[1]
                || tri[1] == tri[2]
                || tri[0] == tri[2]
                || twice_area.is_nan()
                || twice_area <= DEGENERATE_RATIO * longest
            {
                return Err(MeshError::DegenerateTriangle {
                    triangle: t,
                    vertices: *tri,
                });
            }
            let mut key = *tri;
            key.sort_unstable();
            if let Some(&first) = seen.get(&key) {
                return Err(MeshError::DuplicateTriangle { triangle: t, first });
            }
            seen.insert(key, t);
        }
        Ok(Self {
            positions,
            triangles,
        })
    }

    /// The vertices.
    #[must_use]
    pub fn positions(&self) -> &[DVec3] {
        &self.positions
    }

    /// The triangles (three vertex indices each).
    #[must_use]
    pub fn triangles(&self) -> &[[usize; 3]] {
        &self.triangles
    }

    /// Triangle `t`'s area.
    #[must_use]
    pub fn area(&self, t: usize) -> f64 {
        let [a, b, c] = self.triangles[t].map(|v| self.positions[v]);
        0.5 * (b - a).cross(c - a).length()
    }

    /// The unique edges, each as `[low, high]`, sorted.
    #[must_use]
    pub fn edges(&self) -> Vec<[usize; 2]> {
        unique_edges(&self.triangles)
    }

    /// Every interior edge with its two triangles' opposite vertices, as
    /// `(edge, opposite)`, in the order of [`TriangleMesh::edges`]; boundary edges have no
    /// hinge. An edge on more than two triangles is an `Err` naming it.
    pub fn hinges(&self) -> Result<Vec<EdgeHinge>, MeshError> {
        // Per edge: the triangles on it and each one's vertex opposite the edge.
        let mut on_edge: HashMap<[usize; 2], Vec<(usize, usize)>> = HashMap::new();
        for (t, &[a, b, c]) in self.triangles.iter().enumerate() {
            for (p, q, opposite) in [(a, b, c), (b, c, a), (c, a, b)] {
                on_edge
                    .entry([p.min(q), p.max(q)])
                    .or_default()
                    .push((t, opposite));
            }
        }
        let mut hinges = Vec::new();
        for edge in self.edges() {
            let list = &on_edge[&edge];
            match list.as_slice() {
                [_] => {}
                [(_, o0), (_, o1)] => hinges.push((edge, [*o0, *o1])),
                [(t0, _), (t1, _), (t2, _), ..] => {
                    return Err(MeshError::NonManifoldEdge {
                        edge,
                        triangles: [*t0, *t1, *t2],
                    });
                }
                [] => {}
            }
        }
        Ok(hinges)
    }

    /// Each vertex's share of the area: a third of the area of every triangle it belongs
    /// to (the lumped mass per unit areal density).
    #[must_use]
    pub fn vertex_areas(&self) -> Vec<f64> {
        let mut areas = vec![0.0; self.positions.len()];
        for t in 0..self.triangles.len() {
            let third = self.area(t) / 3.0;
            for v in self.triangles[t] {
                areas[v] += third;
            }
        }
        areas
    }
}

/// An interior edge `[low, high]` and the two vertices opposite it (one per triangle).
pub type EdgeHinge = ([usize; 2], [usize; 2]);

/// How a mesh cloth resists bending.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub enum Bending {
    /// No bending resistance: stretch springs only.
    None,
    /// A spring across each interior edge, between the two vertices opposite it, with
    /// this stiffness (rest length from the mesh). Cheap, but it also resists in-plane
    /// shear and its stiffness depends on the triangulation.
    Springs {
        /// The springs' stiffness.
        stiffness: f64,
    },
    /// The discrete-shell dihedral energy `k/2 w (theta - theta_rest)^2` per interior
    /// edge ([`DihedralBending`]), with `k` this stiffness.
    Dihedral {
        /// The bending stiffness `k`.
        stiffness: f64,
    },
}

/// A cloth made from a triangle mesh (see the module documentation).
///
/// # Example
///
/// A unit square of two triangles: each vertex gets a third of the area of its
/// triangles as mass, every edge becomes a spring, and the shared diagonal becomes the
/// one hinge of the dihedral bending term.
///
/// ```
/// use sinew_spring_sim::{Bending, DVec3, Material, MeshCloth, NewtonSettings, TriangleMesh};
///
/// let corners = vec![DVec3::ZERO, DVec3::X, DVec3::new(1.0, 1.0, 0.0), DVec3::Y];
/// let mesh = TriangleMesh::new(corners, vec![[0, 1, 2], [0, 2, 3]])?;
/// let cloth = MeshCloth {
///     areal_density: 3.0,
///     material: Material::earth(),
///     bending: Bending::Dihedral { stiffness: 1e-3 },
///     fixed: vec![0],
/// };
/// let model = cloth.build(&mesh)?;
/// // Areas 1/2 each: vertices 0 and 2 are in both triangles, 1 and 3 in one.
/// for (got, want) in model.system.masses().iter().zip([1.0, 0.5, 1.0, 0.5]) {
///     assert!((got - want).abs() < 1e-15);
/// }
/// assert_eq!(model.system.springs().len(), 5);
/// let bending = model.bending.as_ref().expect("dihedral bending asked for");
/// assert_eq!(bending.hinges()[0].vertices(), [0, 2, 1, 3]);
/// // Backward Euler with the bending term's Hessian pairs added.
/// let _integrator = model.backward_euler(NewtonSettings::default())?;
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct MeshCloth {
    /// Mass per unit area; each vertex gets a third of the area of its triangles times it.
    pub areal_density: f64,
    /// The stretch springs' stiffness, the axial damping and gravity.
    pub material: Material,
    /// The bending model.
    pub bending: Bending,
    /// Vertices held in place. A part of the mesh held whole is a fixed obstacle of any
    /// shape (sharp edges included) for the rest: self-contact forms no pair of two held
    /// primitives (its broad phase hashes them apart and looks them up only from the
    /// free ones).
    pub fixed: Vec<usize>,
}

/// The result of [`MeshCloth::build`]: the mass-spring system, the dihedral bending term
/// when the material asks for it, and the triangles (for contact later).
#[derive(Clone, Debug)]
pub struct MeshClothModel {
    /// Particles (one per vertex, in the mesh's order) and springs: the edges first, in
    /// the order of [`TriangleMesh::edges`], then the bending springs if any.
    pub system: SpringSystem,
    /// The dihedral bending term, for [`Bending::Dihedral`].
    pub bending: Option<DihedralBending>,
    /// The mesh's triangles.
    pub triangles: Vec<[usize; 3]>,
}

impl MeshClothModel {
    /// Backward Euler for this cloth: the mass-spring potential plus, with dihedral
    /// bending, the bending term (with the Hessian pattern widened for its hinge pairs).
    pub fn backward_euler(&self, settings: NewtonSettings) -> Result<BackwardEuler, ModelError> {
        let mut integrator = BackwardEuler::new(&self.system, settings)?;
        self.add_bending(&mut integrator)?;
        Ok(integrator)
    }

    /// BDF2 for this cloth, with the bending term as [`Self::backward_euler`] adds it.
    /// Contact and self-contact are added to its workspace ([`Bdf2::newton_mut`]).
    pub fn bdf2(&self, settings: NewtonSettings) -> Result<Bdf2, ModelError> {
        let mut integrator = Bdf2::new(&self.system, settings)?;
        self.add_bending(integrator.newton_mut())?;
        Ok(integrator)
    }

    /// The implicit midpoint for this cloth, with the bending term as
    /// [`Self::backward_euler`] adds it. Contact and self-contact are added to its
    /// workspace ([`ImplicitMidpoint::newton_mut`]); both act on the end-of-step state.
    pub fn implicit_midpoint(
        &self,
        settings: NewtonSettings,
    ) -> Result<ImplicitMidpoint, ModelError> {
        let mut integrator = ImplicitMidpoint::new(&self.system, settings)?;
        self.add_bending(integrator.newton_mut())?;
        Ok(integrator)
    }

    /// The implicit integrator `integrator` names (backward Euler, BDF2 or the implicit
    /// midpoint, with its Newton settings) for this cloth, with the bending term as
    /// [`Self::backward_euler`] adds it, behind [`PinnedStepper`] (to step, and to add
    /// contact and self-contact to its workspace, [`PinnedStepper::newton_mut`]). The
    /// explicit integrators, `auto` and the flawed reference method are an error naming
    /// the integrator field.
    pub fn implicit_stepper(
        &self,
        integrator: Integrator,
    ) -> Result<Box<dyn PinnedStepper>, ModelError> {
        Ok(match integrator {
            Integrator::BackwardEuler(s) => Box::new(self.backward_euler(s)?),
            Integrator::Bdf2(s) => Box::new(self.bdf2(s)?),
            Integrator::ImplicitMidpoint(s) => Box::new(self.implicit_midpoint(s)?),
            _ => {
                return Err(ModelError::BadParameter {
                    name: "integrator",
                    reason: "a mesh cloth's stepper is implicit: backward Euler, BDF2 or implicit midpoint",
                });
            }
        })
    }

    /// Adds the dihedral bending term, if the material has one, with the Hessian pattern
    /// widened for its hinge pairs.
    pub(crate) fn add_bending(&self, integrator: &mut BackwardEuler) -> Result<(), ModelError> {
        if let Some(term) = &self.bending {
            let pairs = term.coupled_pairs();
            integrator.add_coupled_term(&self.system, Box::new(term.clone()), &pairs)?;
        }
        Ok(())
    }

    /// Adds contact with rigid `colliders` to `integrator` (built for this model, e.g. by
    /// [`Self::backward_euler`]): IPC's barrier and lagged friction against each collider,
    /// with the line search capped by the time of impact, so no accepted state has a
    /// particle inside a collider (docs/contact.md). Kinematic colliders are posed at the
    /// integrator's time ([`BackwardEuler::time`]). Returns the term's statistics.
    ///
    /// Checked as [`crate::Simulation::set_contact`] checks them: the colliders (the
    /// error names the collider), the settings (the error names the setting), `dhat`
    /// against the rounding and the extent of the model's positions
    /// ([`crate::contact::check_contact_distance`]), and the model's current state (a free
    /// particle within the thickness of a collider: the error names the particle and the
    /// collider). One contact term holds every collider: an integrator that has one
    /// already refuses a second ([`ContactError::AddedTwice`]).
    pub fn enable_contact(
        &self,
        integrator: &mut BackwardEuler,
        colliders: Vec<Collider>,
        settings: ContactSettings,
    ) -> Result<Arc<ContactStats>, ContactError> {
        crate::contact::refuse_second(integrator, "contact")?;
        let time = integrator.time();
        crate::contact::check_contact_setup(
            &colliders,
            &settings,
            time,
            self.system.positions(),
            self.system.fixed(),
        )?;
        let term = ContactTerm::new(ContactPotential::new(colliders, settings, time)?);
        let stats = term.stats();
        integrator.add_term(Box::new(term));
        Ok(stats)
    }

    /// Adds self-contact of the cloth with itself to `integrator` (built for this model,
    /// e.g. by [`Self::backward_euler`]): the IPC barrier between every vertex and
    /// triangle and every two edges that share no vertex, with the line search capped by
    /// continuous collision detection ([`crate::contact::self_contact`]). Returns the
    /// term's statistics. The settings are checked (the error names the setting), and so
    /// is the current state (two primitives within the thickness: the error names them).
    /// An integrator that has self-contact already refuses a second
    /// ([`ContactError::AddedTwice`]).
    pub fn enable_self_contact(
        &self,
        integrator: &mut BackwardEuler,
        settings: SelfContactSettings,
    ) -> Result<Arc<SelfContactStats>, ContactError> {
        enable_self_contact(integrator, &self.system, &self.triangles, settings)
    }
}

/// The unique edges of `triangles`, each as `[low, high]`, sorted: the mesh's edges and
/// the self-contact broad phase's edge primitives.
pub(crate) fn unique_edges(triangles: &[[usize; 3]]) -> Vec<[usize; 2]> {
    let mut edges: Vec<[usize; 2]> = triangles
        .iter()
        .flat_map(|&[a, b, c]| [[a, b], [b, c], [c, a]])
        .map(|[a, b]| [a.min(b), a.max(b)])
        .collect();
    edges.sort_unstable();
    edges.dedup();
    edges
}

fn check_field(field: &'static str, value: f64, positive: bool) -> Result<(), MeshError> {
    let ok = value.is_finite() && if positive { value > 0.0 } else { value >= 0.0 };
    if ok {
        Ok(())
    } else {
        Err(MeshError::BadField { field, value })
    }
}

impl MeshCloth {
    /// Builds the cloth for `mesh`, at rest in the mesh's shape (rest lengths and rest
    /// angles measured there).
    pub fn build(&self, mesh: &TriangleMesh) -> Result<MeshClothModel, MeshError> {
        check_field("areal_density", self.areal_density, true)?;
        let len = mesh.positions().len();
        let areas = mesh.vertex_areas();
        // A vertex in no triangle would get no mass: it is not part of the cloth.
        if let Some(vertex) = areas.iter().position(|&a| a <= 0.0) {
            return Err(MeshError::UnusedVertex { vertex });
        }
        let mut particles: Vec<Particle> = mesh
            .positions()
            .iter()
            .zip(&areas)
            .map(|(&p, &a)| Particle::at_rest(p, self.areal_density * a))
            .collect();
        for &v in &self.fixed {
            let Some(p) = particles.get_mut(v) else {
                return Err(MeshError::FixedOutOfRange { vertex: v, len });
            };
            p.fixed = true;
        }
        let mut springs: Vec<SpringSpec> = mesh
            .edges()
            .into_iter()
            .map(|[a, b]| SpringSpec::between(a, b))
            .collect();
        let mut bending = None;
        match self.bending {
            Bending::None => {}
            Bending::Springs { stiffness } => {
                check_field("bending stiffness", stiffness, false)?;
                let mut seen: HashMap<[usize; 2], ()> =
                    springs.iter().map(|s| (s.particles, ())).collect();
                for (_, [o0, o1]) in mesh.hinges()? {
                    // Two hinges can share their opposite pair (a tetrahedron-like fold),
                    // and an opposite pair can already be an edge: one spring per pair.
                    let key = [o0.min(o1), o0.max(o1)];
                    if seen.insert(key, ()).is_none() {
                        springs.push(SpringSpec {
                            stiffness: Some(stiffness),
                            ..SpringSpec::between(key[0], key[1])
                        });
                    }
                }
            }
            Bending::Dihedral { stiffness } => {
                check_field("bending stiffness", stiffness, false)?;
                let mut hinges = Vec::new();
                for (edge, opposite) in mesh.hinges()? {
                    // Validated triangles have nonzero area, so every hinge has normals.
                    if let Some(h) = Hinge::at_rest(mesh.positions(), edge, opposite, stiffness) {
                        hinges.push(h);
                    }
                }
                bending = Some(DihedralBending::new(hinges));
            }
        }
        let system = SpringSystem::new(&particles, &springs, self.material)?;
        Ok(MeshClothModel {
            system,
            bending,
            triangles: mesh.triangles().to_vec(),
        })
    }
}

impl ClothGrid {
    /// The grid's triangles, two per cell, each cell `(i, j)..(i + 1, j + 1)` split along
    /// its diagonal from `(i, j)` to `(i + 1, j + 1)` (one of the shear springs), all
    /// wound the same way; indices as in [`ClothGrid::build`] (`i n + j`).
    #[must_use]
    pub fn triangles(&self) -> Vec<[usize; 3]> {
        let n = self.size;
        let idx = |i: usize, j: usize| i * n + j;
        let mut triangles = Vec::with_capacity(2 * n.saturating_sub(1).pow(2));
        for i in 0..n.saturating_sub(1) {
            for j in 0..n - 1 {
                triangles.push([idx(i, j), idx(i, j + 1), idx(i + 1, j + 1)]);
                triangles.push([idx(i, j), idx(i + 1, j + 1), idx(i + 1, j)]);
            }
        }
        triangles
    }

    /// The grid laid out along the directions `u` and `w` (unit vectors, normally
    /// orthogonal) instead of the x-z plane: vertex `i n + j + offset` at `origin +
    /// spacing (i u + j w)`, with [`ClothGrid::triangles`] shifted by `offset`. For
    /// building one triangle mesh from several sheets (placed and turned), as the
    /// self-contact workloads do; `origin`, `spacing` and `size` are the grid's own.
    #[must_use]
    pub fn sheet(&self, u: DVec3, w: DVec3, offset: usize) -> (Vec<DVec3>, Vec<[usize; 3]>) {
        let (n, origin, s) = (self.size, self.origin, self.spacing);
        let x = (0..n)
            .flat_map(|i| (0..n).map(move |j| origin + s * (i as f64 * u + j as f64 * w)))
            .collect();
        let t = self
            .triangles()
            .into_iter()
            .map(|t| t.map(|v| v + offset))
            .collect();
        (x, t)
    }
}
