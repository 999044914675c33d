//! Cloth from triangle meshes: validation errors naming the triangle, vertex or edge;
//! lumped masses, edges and hinges by hand; the grid's triangles; and whole runs with
//! dihedral bending under backward Euler (a damped settle loses energy, a flat sheet
//! pulled in its plane stays flat, a bent sheet without gravity unbends).

use sinew_math::{DQuat, DVec3};
use sinew_spring_sim::potential::dihedral_angle;
use sinew_spring_sim::{
    Bending, ClothGrid, Material, MeshCloth, MeshClothModel, MeshError, NewtonSettings,
    TriangleMesh,
};

fn square() -> (Vec<DVec3>, Vec<[usize; 3]>) {
    (
        vec![DVec3::ZERO, DVec3::X, DVec3::new(1.0, 0.0, 1.0), DVec3::Z],
        vec![[0, 1, 2], [0, 2, 3]],
    )
}

#[test]
fn bad_meshes_are_errors_naming_the_item() {
    let (p, _) = square();
    let check = |positions: Vec<DVec3>, triangles: Vec<[usize; 3]>, expected: MeshError| {
        let err = TriangleMesh::new(positions, triangles).unwrap_err();
        assert_eq!(err, expected);
        assert!(!err.to_string().is_empty());
    };
    check(p.clone(), vec![], MeshError::NoTriangles);
    let mut nan = p.clone();
    nan[2].y = f64::NAN;
    check(
        nan,
        vec![[0, 1, 2]],
        MeshError::NonFiniteVertex { vertex: 2 },
    );
    check(
        p.clone(),
        vec![[0, 1, 2], [0, 2, 7]],
        MeshError::IndexOutOfRange {
            triangle: 1,
            vertex: 7,
            len: 4,
        },
    );
    check(
        p.clone(),
        vec![[0, 1, 2], [3, 3, 1]],
        MeshError::DegenerateTriangle {
            triangle: 1,
            vertices: [3, 3, 1],
        },
    );
    // Collinear: zero area.
    let mut line = p.clone();
    line.push(DVec3::new(2.0, 0.0, 0.0));
    check(
        line,
        vec![[0, 1, 4]],
        MeshError::DegenerateTriangle {
            triangle: 0,
            vertices: [0, 1, 4],
        },
    );
    check(
        p.clone(),
        vec![[0, 1, 2], [0, 2, 3], [2, 1, 0]],
        MeshError::DuplicateTriangle {
            triangle: 2,
            first: 0,
        },
    );
    // Three triangles on edge (0, 2): fine as a mesh, an error where bending needs hinges.
    let mut fin = p.clone();
    fin.push(DVec3::new(0.5, 1.0, 0.5));
    let mesh = TriangleMesh::new(fin, vec![[0, 1, 2], [0, 2, 3], [0, 2, 4]]).unwrap();
    let expected = MeshError::NonManifoldEdge {
        edge: [0, 2],
        triangles: [0, 1, 2],
    };
    assert_eq!(mesh.hinges().unwrap_err(), expected);
    let cloth = |bending| MeshCloth {
        areal_density: 1.0,
        material: Material::default(),
        bending,
        fixed: vec![],
    };
    assert_eq!(
        cloth(Bending::Dihedral { stiffness: 1.0 })
            .build(&mesh)
            .unwrap_err(),
        expected
    );
    assert_eq!(
        cloth(Bending::Springs { stiffness: 1.0 })
            .build(&mesh)
            .unwrap_err(),
        expected
    );
    assert!(cloth(Bending::None).build(&mesh).is_ok());
    // Builder fields.
    let mesh = TriangleMesh::new(p.clone(), square().1).unwrap();
    let mut bad = cloth(Bending::None);
    bad.areal_density = -1.0;
    assert!(matches!(
        bad.build(&mesh).unwrap_err(),
        MeshError::BadField {
            field: "areal_density",
            ..
        }
    ));
    let mut bad = cloth(Bending::Dihedral {
        stiffness: f64::NAN,
    });
    bad.fixed = vec![];
    assert!(matches!(
        bad.build(&mesh).unwrap_err(),
        MeshError::BadField { .. }
    ));
    let mut bad = cloth(Bending::None);
    bad.fixed = vec![9];
    assert_eq!(
        bad.build(&mesh).unwrap_err(),
        MeshError::FixedOutOfRange { vertex: 9, len: 4 }
    );
    let mut extra = p.clone();
    extra.push(DVec3::ONE);
    let mesh = TriangleMesh::new(extra, square().1).unwrap();
    assert_eq!(
        cloth(Bending::None).build(&mesh).unwrap_err(),
        MeshError::UnusedVertex { vertex: 4 }
    );
}

#[test]
fn masses_edges_and_hinges_by_hand() {
    let (p, t) = square();
    let mesh = TriangleMesh::new(p, t).unwrap();
    assert_eq!(mesh.edges(), vec![[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]]);
    assert_eq!(mesh.hinges().unwrap(), vec![([0, 2], [1, 3])]);
    // Each triangle has area 1/2: vertices 0 and 2 are in both (1/3), 1 and 3 in one (1/6).
    let model = MeshCloth {
        areal_density: 3.0,
        material: Material::default(),
        bending: Bending::Springs { stiffness: 5.0 },
        fixed: vec![0],
    }
    .build(&mesh)
    .unwrap();
    let m = model.system.masses();
    for (got, want) in m.iter().zip([1.0, 0.5, 1.0, 0.5]) {
        assert!((got - want).abs() < 1e-15, "{m:?}");
    }
    assert_eq!(model.system.fixed(), &[true, false, false, false]);
    // Five edge springs at the material's stiffness, one bending spring across (1, 3).
    let s = model.system.springs();
    assert_eq!(s.len(), 6);
    assert_eq!((s[5].a, s[5].b, s[5].stiffness), (1, 3, 5.0));
    assert!((s[5].rest_length - 2f64.sqrt()).abs() < 1e-15);
    assert!(model.bending.is_none());
    let model = MeshCloth {
        areal_density: 3.0,
        material: Material::default(),
        bending: Bending::Dihedral { stiffness: 5.0 },
        fixed: vec![],
    }
    .build(&mesh)
    .unwrap();
    assert_eq!(model.system.springs().len(), 5);
    let term = model.bending.unwrap();
    assert_eq!(term.hinges().len(), 1);
    assert_eq!(term.hinges()[0].vertices(), [0, 2, 1, 3]);
    // Edge length sqrt 2, areas 1/2 + 1/2: w = 3 * 2 / 1.
    assert!((term.hinges()[0].weight - 6.0).abs() < 1e-14);
}

#[test]
fn grid_triangles_cover_the_grid_once() {
    for n in [1, 2, 3, 11] {
        let grid = ClothGrid::lab_sized(n, 0.2).with_damping(0.0);
        let tris = grid.triangles();
        assert_eq!(tris.len(), 2 * (n - 1) * (n - 1));
        if n < 2 {
            continue;
        }
        let system = grid.build().unwrap();
        let mesh = TriangleMesh::new(system.positions().to_vec(), tris).unwrap();
        let area: f64 = (0..mesh.triangles().len()).map(|t| mesh.area(t)).sum();
        let side = 0.2 * (n - 1) as f64;
        assert!((area - side * side).abs() < 1e-12);
        // Interior edges of a triangulated grid: (n-1)(n-2) per direction plus one
        // diagonal per cell.
        let hinges = mesh.hinges().unwrap().len();
        assert_eq!(hinges, 2 * (n - 1) * (n - 2) + (n - 1) * (n - 1));
        // Every triangle edge is a spring of the grid (structural or shear), so the grid
        // cloth's surface is made of its own springs.
        for [a, b] in mesh.edges() {
            assert!(
                system
                    .springs()
                    .iter()
                    .any(|s| (s.a, s.b) == (a, b) || (s.a, s.b) == (b, a)),
                "edge ({a}, {b}) is no spring"
            );
        }
        // Consistently wound: every interior edge is crossed in opposite directions.
        for &[a, b, c] in mesh.triangles() {
            for (p, q) in [(a, b), (b, c), (c, a)] {
                let same = mesh
                    .triangles()
                    .iter()
                    .filter(|t| (0..3).any(|k| t[k] == p && t[(k + 1) % 3] == q))
                    .count();
                assert_eq!(same, 1);
            }
        }
    }
}

/// An `n x n` sheet in the xz plane with side 1, triangulated like the grid cloth.
fn sheet(n: usize) -> TriangleMesh {
    let spacing = 1.0 / (n - 1) as f64;
    let grid = ClothGrid::lab_sized(n, spacing).with_damping(0.0);
    let positions = (0..n * n)
        .map(|k| DVec3::new(spacing * (k / n) as f64, 0.0, spacing * (k % n) as f64))
        .collect();
    TriangleMesh::new(positions, grid.triangles()).unwrap()
}

fn total_energy(model: &MeshClothModel, x: &[DVec3], v: &[DVec3]) -> f64 {
    let system = &model.system;
    let mut e = 0.0;
    for i in 0..x.len() {
        if !system.fixed()[i] {
            e += 0.5 * system.masses()[i] * v[i].length_squared()
                - system.masses()[i] * system.material().gravity.dot(x[i]);
        }
    }
    for s in system.springs() {
        let d = x[s.a].distance(x[s.b]) - s.rest_length;
        e += 0.5 * s.stiffness * d * d;
    }
    if let Some(b) = &model.bending {
        e += b.hinges().iter().map(|h| h.energy(x)).sum::<f64>();
    }
    e
}

fn largest_angle(model: &MeshClothModel, x: &[DVec3]) -> f64 {
    model
        .bending
        .as_ref()
        .unwrap()
        .hinges()
        .iter()
        .map(|h| dihedral_angle(h.vertices().map(|v| x[v])).abs())
        .fold(0.0, f64::max)
}

#[test]
fn damped_settle_with_dihedral_bending_loses_energy() {
    let n = 7;
    let mesh = sheet(n);
    let model = MeshCloth {
        areal_density: 1.0,
        material: Material {
            stiffness: 200.0,
            damping: 0.5,
            gravity: DVec3::new(0.0, -9.8, 0.0),
        },
        bending: Bending::Dihedral { stiffness: 0.05 },
        // One edge held: the sheet swings down and settles as a hanging flap.
        fixed: (0..n).collect(),
    }
    .build(&mesh)
    .unwrap();
    let mut be = model.backward_euler(NewtonSettings::default()).unwrap();
    let mut system = model.system.clone();
    let start = total_energy(&model, system.positions(), system.velocities());
    let mut previous = start;
    let mut bent = 0.0f64;
    for step in 0..200 {
        let report = be.step(&mut system, 1.0 / 60.0).unwrap();
        assert!(
            report.residual <= report.tolerance,
            "step {step}: {report:?}"
        );
        let e = total_energy(&model, system.positions(), system.velocities());
        // Backward Euler with damping dissipates: the energy never rises (beyond the
        // Newton tolerance's round-off).
        assert!(
            e <= previous + 1e-9 * start.abs().max(1.0),
            "step {step}: {e} > {previous}"
        );
        previous = e;
        bent = bent.max(largest_angle(&model, system.positions()));
        assert!(system.positions().iter().all(|p| p.is_finite()));
    }
    assert!(previous < start - 1.0, "energy {start} -> {previous}");
    // The sheet did bend (the term was exercised).
    assert!(bent > 0.05, "largest angle {bent}");
}

#[test]
fn flat_sheet_pulled_in_its_plane_stays_flat() {
    let n = 6;
    let mesh = sheet(n);
    let model = MeshCloth {
        areal_density: 1.0,
        material: Material {
            stiffness: 50.0,
            damping: 0.1,
            // In the sheet's plane (xz): a pull that stretches the sheet.
            gravity: DVec3::new(3.0, 0.0, 1.0),
        },
        bending: Bending::Dihedral { stiffness: 0.5 },
        fixed: (0..n).collect(),
    }
    .build(&mesh)
    .unwrap();
    let mut be = model.backward_euler(NewtonSettings::default()).unwrap();
    let mut system = model.system.clone();
    let before = system.positions().to_vec();
    for _ in 0..60 {
        be.step(&mut system, 1.0 / 30.0).unwrap();
    }
    let moved = system
        .positions()
        .iter()
        .zip(&before)
        .map(|(a, b)| a.distance(*b))
        .fold(0.0, f64::max);
    assert!(moved > 0.01, "the load did not stretch the sheet ({moved})");
    let off_plane = system
        .positions()
        .iter()
        .map(|p| p.y.abs())
        .fold(0.0, f64::max);
    assert!(off_plane < 1e-12, "left the plane by {off_plane}");
    assert!(largest_angle(&model, system.positions()) < 1e-12);
}

#[test]
fn bent_sheet_without_gravity_unbends() {
    let n = 7;
    let mesh = sheet(n);
    let model = MeshCloth {
        areal_density: 1.0,
        material: Material {
            stiffness: 500.0,
            damping: 0.2,
            gravity: DVec3::ZERO,
        },
        bending: Bending::Dihedral { stiffness: 0.2 },
        fixed: vec![],
    }
    .build(&mesh)
    .unwrap();
    // Fold the sheet along the grid line x = 0.5 by 60 degrees: a rigid rotation of the
    // half x > 0.5 about that line, so every edge keeps its rest length and only the
    // hinges on the fold are bent.
    let axis_point = DVec3::new(0.5, 0.0, 0.0);
    let turn = DQuat::from_rotation_z(std::f64::consts::FRAC_PI_3);
    let folded: Vec<DVec3> = mesh
        .positions()
        .iter()
        .map(|&p| {
            if p.x > 0.5 + 1e-9 {
                axis_point + turn * (p - axis_point)
            } else {
                p
            }
        })
        .collect();
    let mut system = model.system.clone();
    system
        .set_state(&folded, &vec![DVec3::ZERO; folded.len()])
        .unwrap();
    let start_angle = largest_angle(&model, &folded);
    assert!((start_angle - std::f64::consts::FRAC_PI_3).abs() < 1e-12);
    let mut be = model.backward_euler(NewtonSettings::default()).unwrap();
    let start = total_energy(&model, &folded, system.velocities());
    for _ in 0..400 {
        let report = be.step(&mut system, 1.0 / 30.0).unwrap();
        assert!(report.residual <= report.tolerance);
    }
    let end_angle = largest_angle(&model, system.positions());
    let end = total_energy(&model, system.positions(), system.velocities());
    assert!(
        end_angle < 0.02 * start_angle,
        "angle {start_angle} -> {end_angle}"
    );
    assert!(end < 0.01 * start, "energy {start} -> {end}");
}

#[test]
fn coupled_term_pairs_are_checked_and_widen_the_pattern() {
    let mesh = sheet(3);
    let model = MeshCloth {
        areal_density: 1.0,
        material: Material::default(),
        bending: Bending::Dihedral { stiffness: 1.0 },
        fixed: vec![],
    }
    .build(&mesh)
    .unwrap();
    let term = model.bending.clone().unwrap();
    let plain =
        sinew_spring_sim::BackwardEuler::new(&model.system, NewtonSettings::default()).unwrap();
    let widened = model.backward_euler(NewtonSettings::default()).unwrap();
    // The pairs across hinges that no edge joins add blocks: the pattern grows.
    assert!(widened.pattern().nnz() > plain.pattern().nnz());
    let mut be =
        sinew_spring_sim::BackwardEuler::new(&model.system, NewtonSettings::default()).unwrap();
    let before = be.pattern().nnz();
    let err = be
        .add_coupled_term(&model.system, Box::new(term.clone()), &[[0, 99]])
        .unwrap_err();
    assert!(err.to_string().contains("pairs"), "{err}");
    assert_eq!(be.pattern().nnz(), before, "nothing changes on error");
    assert_eq!(
        be.potential().terms().len(),
        plain.potential().terms().len()
    );
    // A system of another topology is refused.
    let other = MeshCloth {
        areal_density: 1.0,
        material: Material::default(),
        bending: Bending::None,
        fixed: vec![],
    }
    .build(&sheet(4))
    .unwrap();
    assert!(
        be.add_coupled_term(&other.system, Box::new(term), &[])
            .is_err()
    );
}
