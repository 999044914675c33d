//! The OBJ reader: triangles and quads (triangulated), objects welded at shared
//! vertices, errors, the shipped sheet; and a cloth built from an OBJ written here,
//! with dihedral bending under backward Euler: a hanging flap settles while its energy
//! falls, and a folded sheet without gravity unbends.

use sinew_io::obj::{ObjError, parse_obj, parse_obj_numbered};
use sinew_math::{DQuat, DVec3};
use sinew_spring_sim::potential::dihedral_angle;
use sinew_spring_sim::{Bending, Material, MeshCloth, NewtonSettings, TriangleMesh};

#[test]
fn quads_are_triangulated_and_indices_kept() {
    let text = "# a unit square as one quad, and a triangle\n\
                v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nv 2 0 0\n\
                vn 0 1 0\n\
                f 1//1 2//1 3//1 4//1\n\
                f 2 5 3\n";
    let mesh = parse_obj(text).unwrap();
    assert_eq!(mesh.positions.len(), 5);
    assert_eq!(mesh.positions[2], DVec3::new(1.0, 0.0, 1.0));
    // The quad as a fan from its first vertex, then the triangle (indices from 0).
    assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3], [1, 4, 2]]);
}

#[test]
fn objects_sharing_vertices_stay_connected() {
    // Two groups using vertices 2 and 3 each: tobj gives each group its own copy; the
    // reader makes them one again by their numbers in the file.
    let text = "v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nv 2 0 1\n\
                g left\nf 1 2 3\nf 1 3 4\n\
                g right\nf 2 5 3\n";
    let mesh = parse_obj(text).unwrap();
    assert_eq!(mesh.positions.len(), 5);
    let m = TriangleMesh::new(mesh.positions.clone(), mesh.triangles.clone()).unwrap();
    assert_eq!(
        m.hinges().unwrap().len(),
        2,
        "the groups meet at edges (0,2) and (1,2)"
    );
}

#[test]
fn vertices_keep_the_files_numbering() {
    // The shipped sheet's faces use its vertices out of the `v` lines' order (`tobj`
    // alone numbers them by first use: its vertex 10 came out in the middle of a row).
    // Every vertex of the mesh is the file's `v` statement of the same index, read here
    // from the text directly.
    let text = include_str!("../../../scenes/data/sheet.obj");
    let lines: Vec<DVec3> = text
        .lines()
        .filter_map(|l| {
            let mut w = l.split_whitespace();
            (w.next() == Some("v")).then(|| {
                let c: Vec<f64> = w.map(|x| x.parse().unwrap()).collect();
                DVec3::new(c[0], c[1], c[2])
            })
        })
        .collect();
    let read = parse_obj_numbered(text).unwrap();
    assert_eq!(read.file_vertex_count, lines.len());
    assert_eq!(read.file_vertices, (0..lines.len()).collect::<Vec<_>>());
    assert_eq!(read.mesh.positions, lines);
    // The triangles are the file's faces, fanned from their first corner, read from the
    // text directly (`f a b c d` gives `a b c` and `a c d`; OBJ counts from 1): the
    // reader's vertex numbers are the file's.
    let faces: Vec<[usize; 3]> = text
        .lines()
        .filter_map(|l| {
            let mut w = l.split_whitespace();
            (w.next() == Some("f")).then(|| {
                w.map(|c| c.split('/').next().unwrap().parse::<usize>().unwrap() - 1)
                    .collect::<Vec<_>>()
            })
        })
        .flat_map(|f| (1..f.len() - 1).map(move |k| [f[0], f[k], f[k + 1]]))
        .collect();
    assert!(faces.len() > 100);
    assert_eq!(read.mesh.triangles, faces);
}

#[test]
fn two_vertices_at_one_place_stay_two_and_loose_ones_are_left_out() {
    // Objects a and b meet at the origin through two distinct file vertices (a seam):
    // two vertices, not welded. Vertex 7 is used by no face; vertex 6 has a weight.
    let text = "v 0 0 0\nv 1 0 0\nv 0 1 0 0 0 1\nv 0 0 0\nv -1 0 0\nv 0 -1 0\n\
                v 0 0 2 2\nv 5 5 5\n\
                g a\nf 1 2 3\nf 1 3 7\ng b\nf 4 5 6\n";
    let read = parse_obj_numbered(text).unwrap();
    assert_eq!(read.file_vertex_count, 8);
    assert_eq!(read.file_vertices, vec![0, 1, 2, 3, 4, 5, 6]);
    assert_eq!(read.mesh.positions[0], read.mesh.positions[3]);
    assert_eq!(read.mesh.positions[6], DVec3::new(0.0, 0.0, 1.0));
    assert_eq!(read.mesh.triangles, vec![[0, 1, 2], [0, 2, 6], [3, 4, 5]]);
    assert_eq!(read.vertex(6), Ok(6));
    assert_eq!(
        read.vertex(7),
        Err("vertex 7 is used by no face".to_string())
    );
    assert!(read.vertex(8).unwrap_err().contains("does not exist"));
    // A weight of zero, or one that does not parse, is `tobj`'s error as before.
    for bad in [
        "v 1 0 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n",
        "v 1 0 0 x\nv 0 1 0\nv 0 0 1\nf 1 2 3\n",
    ] {
        assert!(matches!(parse_obj(bad), Err(ObjError::Parse(_))), "{bad}");
    }
}

#[test]
fn bad_files_are_errors() {
    assert_eq!(parse_obj("v 0 0 0\nv 1 0 0\n"), Err(ObjError::NoTriangles));
    // Face indices out of range name the line, the index and the vertices it could
    // refer to: beyond the file's vertices, 0, or back before the first.
    let three = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    for (face, index, vertices) in [("f 1 2 9", 9, 3), ("f 0 1 2", 0, 3), ("f -1 -2 -9", -9, 3)] {
        let e = parse_obj(&format!("{three}{face}\n")).unwrap_err();
        assert_eq!(
            e,
            ObjError::FaceIndex {
                line: 4,
                index,
                vertices
            }
        );
        assert!(
            e.to_string().starts_with("OBJ line 4: face vertex index"),
            "{e}"
        );
    }
    // A negative index counts only the vertices before the face.
    assert_eq!(
        parse_obj("v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n").unwrap_err(),
        ObjError::FaceIndex {
            line: 3,
            index: -3,
            vertices: 2
        }
    );
    assert!(parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -3\n").is_ok());
    assert!(matches!(
        parse_obj("v 0 zero 0\nf 1 1 1\n"),
        Err(ObjError::Parse(_))
    ));
    let e = parse_obj("o cloth\nv 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n").unwrap_err();
    assert_eq!(
        e,
        ObjError::NonFiniteVertex {
            object: "cloth".into(),
            vertex: 1
        }
    );
    assert!(e.to_string().contains("vertex 1"));
}

#[test]
fn corrupted_files_never_panic() {
    let text = include_str!("../../../scenes/data/sheet.obj");
    let bytes = text.as_bytes();
    let step = (bytes.len() / 300).max(1);
    for cut in (0..bytes.len()).step_by(step) {
        let _ = parse_obj(&String::from_utf8_lossy(&bytes[..cut]));
    }
    for i in (0..bytes.len()).step_by(step) {
        for b in [b'0', b'-', b'/', b' ', b'\n', b'f', b'v', 0xff] {
            let mut v = bytes.to_vec();
            v[i] = b;
            let _ = parse_obj(&String::from_utf8_lossy(&v));
        }
    }
}

#[test]
fn the_shipped_sheet_is_a_clean_cloth_mesh() {
    let mesh = parse_obj(include_str!("../../../scenes/data/sheet.obj")).unwrap();
    let m = TriangleMesh::new(mesh.positions, mesh.triangles).unwrap();
    // A 1 x 1 square in the xz plane.
    let area: f64 = (0..m.triangles().len()).map(|t| m.area(t)).sum();
    assert!((area - 1.0).abs() < 1e-12, "area {area}");
    assert!(m.positions().iter().all(|p| p.y == 0.0));
    assert!(m.hinges().is_ok());
}

/// The shipped table: a closed box (every edge in exactly two triangles, so the surface
/// has no border), its area the box's `2 (0.5 x 0.5) + 4 (0.5 x 0.05)`, every vertex on
/// the box's surface, and every triangle wound with its normal pointing out of the box
/// (away from its centre, along the face's axis), as docs/io.md says.
#[test]
fn the_shipped_table_is_a_closed_box_wound_outwards() {
    let mesh = parse_obj(include_str!("../../../scenes/data/table.obj")).unwrap();
    let m = TriangleMesh::new(mesh.positions, mesh.triangles).unwrap();
    assert_eq!((m.positions().len(), m.triangles().len()), (242, 480));
    let mut uses = std::collections::HashMap::new();
    for &[a, b, c] in m.triangles() {
        for (p, q) in [(a, b), (b, c), (c, a)] {
            *uses.entry((p.min(q), p.max(q))).or_insert(0) += 1;
        }
    }
    assert!(
        uses.values().all(|&n| n == 2),
        "an edge not in two triangles"
    );
    let area: f64 = (0..m.triangles().len()).map(|t| m.area(t)).sum();
    assert!((area - (0.5 + 0.1)).abs() < 1e-12, "area {area}");
    let (low, high) = (DVec3::new(-0.25, 0.35, -0.25), DVec3::new(0.25, 0.40, 0.25));
    let centre = 0.5 * (low + high);
    for p in m.positions() {
        let on_a_face = (0..3).any(|k| p[k] == low[k] || p[k] == high[k]);
        let within = (0..3).all(|k| p[k] >= low[k] && p[k] <= high[k]);
        assert!(on_a_face && within, "{p}");
    }
    for &[a, b, c] in m.triangles() {
        let x = m.positions();
        let normal = (x[b] - x[a]).cross(x[c] - x[a]);
        let out = (x[a] + x[b] + x[c]) / 3.0 - centre;
        // The face's axis: the normal's largest component, which points away from the
        // centre along it.
        let k = (0..3)
            .max_by(|&i, &j| normal[i].abs().total_cmp(&normal[j].abs()))
            .unwrap();
        assert!(
            normal[k] * out[k] > 0.0,
            "triangle {a} {b} {c} wound inwards"
        );
    }
}

/// An `n x n` sheet of side 1 in the xz plane, written as OBJ text with one quad per
/// cell (the reader triangulates them).
fn sheet_obj(n: usize) -> String {
    let mut s = String::from("# test sheet\no sheet\n");
    let h = 1.0 / (n - 1) as f64;
    for i in 0..n {
        for j in 0..n {
            s += &format!("v {} 0 {}\n", h * i as f64, h * j as f64);
        }
    }
    for i in 0..n - 1 {
        for j in 0..n - 1 {
            let v = |a: usize, b: usize| a * n + b + 1;
            s += &format!(
                "f {} {} {} {}\n",
                v(i, j),
                v(i, j + 1),
                v(i + 1, j + 1),
                v(i + 1, j)
            );
        }
    }
    s
}

fn largest_angle(cloth: &sinew_spring_sim::MeshClothModel, x: &[DVec3]) -> f64 {
    cloth
        .bending
        .as_ref()
        .unwrap()
        .hinges()
        .iter()
        .map(|h| dihedral_angle(h.vertices().map(|v| x[v])).abs())
        .fold(0.0, f64::max)
}

fn energy(cloth: &sinew_spring_sim::MeshClothModel, x: &[DVec3], v: &[DVec3]) -> f64 {
    let s = &cloth.system;
    let mut e: f64 = s
        .springs()
        .iter()
        .map(|sp| 0.5 * sp.stiffness * (x[sp.a].distance(x[sp.b]) - sp.rest_length).powi(2))
        .sum();
    for i in 0..x.len() {
        if !s.fixed()[i] {
            e += 0.5 * s.masses()[i] * v[i].length_squared()
                - s.masses()[i] * s.material().gravity.dot(x[i]);
        }
    }
    e + cloth
        .bending
        .as_ref()
        .unwrap()
        .hinges()
        .iter()
        .map(|h| h.energy(x))
        .sum::<f64>()
}

#[test]
fn cloth_from_an_obj_settles_and_unbends_with_dihedral_bending() {
    let n = 6;
    let read = parse_obj(&sheet_obj(n)).unwrap();
    assert_eq!(read.triangles.len(), 2 * (n - 1) * (n - 1));
    let mesh = TriangleMesh::new(read.positions, read.triangles).unwrap();

    // A damped settle: one edge held, gravity, the energy never rises and ends lower.
    let cloth = MeshCloth {
        areal_density: 0.5,
        material: Material {
            stiffness: 100.0,
            damping: 0.5,
            gravity: DVec3::new(0.0, -9.8, 0.0),
        },
        bending: Bending::Dihedral { stiffness: 0.02 },
        fixed: (0..n).collect(),
    }
    .build(&mesh)
    .unwrap();
    let mut be = cloth.backward_euler(NewtonSettings::default()).unwrap();
    let mut system = cloth.system.clone();
    let start = energy(&cloth, system.positions(), system.velocities());
    let mut previous = start;
    for step in 0..120 {
        let r = be.step(&mut system, 1.0 / 60.0).unwrap();
        assert!(r.residual <= r.tolerance, "step {step}: {r:?}");
        let e = energy(&cloth, system.positions(), system.velocities());
        assert!(
            e <= previous + 1e-9 * start.abs().max(1.0),
            "step {step}: {e} > {previous}"
        );
        previous = e;
    }
    assert!(previous < start - 0.5, "energy {start} -> {previous}");
    assert!(
        largest_angle(&cloth, system.positions()) > 0.05,
        "the sheet never bent"
    );

    // A folded sheet without gravity unbends: fold the half z > 0.6 by 90 degrees about
    // the grid line z = 0.6 (a rigid turn, so no edge is stretched).
    let cloth = MeshCloth {
        areal_density: 0.5,
        material: Material {
            stiffness: 300.0,
            damping: 0.2,
            gravity: DVec3::ZERO,
        },
        bending: Bending::Dihedral { stiffness: 0.1 },
        fixed: vec![],
    }
    .build(&mesh)
    .unwrap();
    let pivot = DVec3::new(0.0, 0.0, 0.6);
    let turn = DQuat::from_rotation_x(-std::f64::consts::FRAC_PI_2);
    let folded: Vec<DVec3> = mesh
        .positions()
        .iter()
        .map(|&p| {
            if p.z > 0.6 + 1e-9 {
                pivot + turn * (p - pivot)
            } else {
                p
            }
        })
        .collect();
    let mut system = cloth.system.clone();
    system
        .set_state(&folded, &vec![DVec3::ZERO; folded.len()])
        .unwrap();
    let before = largest_angle(&cloth, &folded);
    assert!((before - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    let mut be = cloth.backward_euler(NewtonSettings::default()).unwrap();
    for _ in 0..300 {
        be.step(&mut system, 1.0 / 30.0).unwrap();
    }
    let after = largest_angle(&cloth, system.positions());
    assert!(after < 0.02 * before, "angle {before} -> {after}");
}
