//! Self-contact in backward Euler, BDF2 and the implicit midpoint (whose unknowns are the
//! step's midpoint: the barrier acts on its end state): a sheet dropped onto a sheet
//! pinned below it, and a hanging sheet collapsing onto the ground and folding onto
//! itself. At every accepted
//! state an independent exact check (Shewchuk's orientation predicates from the `robust`
//! crate, with sinew-exact's triangle-triangle test on top of them) finds no two
//! triangles that share no vertex intersecting; the incremental potential recorded at
//! every Newton iterate never increases within a step; and the smallest gap over all
//! such pairs, by brute force, stays positive.

use crate::common::{SCHEMES, Scheme};
use crate::sheets::{self, grid};
use sinew_exact::{intersecting_pairs, triangles_meet};
use sinew_math::DVec3;
use sinew_spring_sim::contact::self_contact::distance::{PairKind, squared_distance};
use sinew_spring_sim::contact::self_contact::{SelfContactSettings, SelfContactStats};
use sinew_spring_sim::contact::{Collider, ContactPotential, ContactSettings, ContactTerm};
use sinew_spring_sim::{
    MeshClothModel, NewtonSettings, PinnedStepper, SpringSystem, StepError, TriangleMesh,
};
use std::sync::Arc;

const H: f64 = 1.0 / 60.0;

// ---------------------------------------------------------------------------------------
// The independent intersection check.

#[test]
fn the_intersection_check_sees_crossing_touching_and_coplanar_overlaps() {
    let t = [DVec3::ZERO, DVec3::X, DVec3::Y];
    let v = DVec3::new;
    // Piercing.
    assert!(triangles_meet(
        t,
        [v(0.2, 0.2, -1.0), v(0.2, 0.2, 1.0), v(3.0, 3.0, 0.5)]
    ));
    // Just above: apart.
    assert!(!triangles_meet(
        t,
        [v(0.2, 0.2, 1e-12), v(0.3, 0.2, 1.0), v(0.2, 0.3, 1.0)]
    ));
    // Touching with a vertex on the face.
    assert!(triangles_meet(
        t,
        [v(0.2, 0.2, 0.0), v(0.3, 0.2, 1.0), v(0.2, 0.3, 1.0)]
    ));
    // Coplanar overlap and coplanar disjoint.
    assert!(triangles_meet(
        t,
        [v(0.5, 0.5, 0.0), v(-1.0, 0.2, 0.0), v(0.2, -1.0, 0.0)]
    ));
    assert!(!triangles_meet(
        t,
        [v(2.0, 2.0, 0.0), v(3.0, 2.0, 0.0), v(2.0, 3.0, 0.0)]
    ));
    // One inside the other, coplanar.
    assert!(triangles_meet(
        t,
        [v(0.1, 0.1, 0.0), v(0.2, 0.1, 0.0), v(0.1, 0.2, 0.0)]
    ));
    // An edge through an edge: the other triangle's edge from (0.5, -0.5) to
    // (0.25, 0.25) crosses the edge along x at (0.417, 0), leaving the plane upward.
    assert!(triangles_meet(
        t,
        [v(0.5, -0.5, 0.0), v(0.25, 0.25, 0.0), v(0.5, -0.5, 1.0)]
    ));
    // Interlocked like chain links, no vertex inside the other.
    assert!(triangles_meet(
        [v(-1.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 2.0, 0.0)],
        [v(0.0, 1.0, -1.0), v(0.0, 1.0, 1.0), v(0.0, -1.0, 0.0)]
    ));
}

// ---------------------------------------------------------------------------------------
// The runs.

/// The smallest gap (distance minus `thickness`) over every vertex-triangle and edge-edge
/// pair sharing no vertex, by brute force.
fn min_gap(x: &[DVec3], triangles: &[[usize; 3]], thickness: f64) -> f64 {
    let mesh = TriangleMesh::new(x.to_vec(), triangles.to_vec()).unwrap();
    let edges = mesh.edges();
    let mut min = f64::INFINITY;
    for (v, _) in x.iter().enumerate() {
        for t in triangles {
            if !t.contains(&v) {
                let pair = [x[v], x[t[0]], x[t[1]], x[t[2]]];
                min = min.min(squared_distance(PairKind::PointTriangle, &pair));
            }
        }
    }
    for (i, a) in edges.iter().enumerate() {
        for b in &edges[i + 1..] {
            if !a.iter().any(|v| b.contains(v)) {
                let pair = [x[a[0]], x[a[1]], x[b[0]], x[b[1]]];
                min = min.min(squared_distance(PairKind::EdgeEdge, &pair));
            }
        }
    }
    min.sqrt() - thickness
}

struct Run {
    model: MeshClothModel,
    system: SpringSystem,
    integrator: Box<dyn PinnedStepper>,
    stats: Arc<SelfContactStats>,
    settings: SelfContactSettings,
}

fn build(
    positions: Vec<DVec3>,
    triangles: Vec<[usize; 3]>,
    fixed: Vec<usize>,
    colliders: Vec<Collider>,
    settings: SelfContactSettings,
) -> Run {
    build_with(
        Scheme::BackwardEuler,
        positions,
        triangles,
        fixed,
        colliders,
        settings,
    )
}

fn build_with(
    scheme: Scheme,
    positions: Vec<DVec3>,
    triangles: Vec<[usize; 3]>,
    fixed: Vec<usize>,
    colliders: Vec<Collider>,
    settings: SelfContactSettings,
) -> Run {
    let mesh = TriangleMesh::new(positions, triangles).unwrap();
    let cloth = sheets::cloth(fixed);
    let model = cloth.build(&mesh).unwrap();
    let newton = NewtonSettings {
        record_objective: true,
        ..NewtonSettings::default()
    };
    let mut integrator = scheme.build(&model, newton);
    let workspace = integrator.newton_mut();
    if !colliders.is_empty() {
        let contact = ContactPotential::new(colliders, ContactSettings::default(), 0.0).unwrap();
        workspace.add_term(Box::new(ContactTerm::new(contact)));
    }
    let stats = model.enable_self_contact(workspace, settings).unwrap();
    let system = model.system.clone();
    Run {
        model,
        system,
        integrator,
        stats,
        settings,
    }
}

/// Steps `run` `steps` times, checking every accepted state; returns the smallest gap
/// seen and the number of particle pairs the pattern was widened by.
fn run_checked(run: &mut Run, steps: usize) -> (f64, usize) {
    let triangles = run.model.triangles.clone();
    let mut smallest = f64::INFINITY;
    let mut widened = 0;
    for step in 0..steps {
        let nnz = run.integrator.newton().pattern().nnz();
        let report = run.integrator.take_step(&mut run.system, H).unwrap();
        // The integrator gives the pairs contact coupled slots, so later steps get their
        // full blocks, and drops those of pairs that have left; the report says how many
        // of each, and the pattern must have grown, shrunk or stayed as it says.
        let (added, dropped) = (report.pattern_pairs_added, report.pattern_pairs_dropped);
        let after = run.integrator.newton().pattern().nnz();
        match (added > 0, dropped > 0) {
            (false, false) => assert_eq!(after, nnz, "step {step}"),
            (true, false) => assert!(after > nnz, "step {step}"),
            (false, true) => assert!(after < nnz, "step {step}"),
            (true, true) => {}
        }
        widened += added;
        let trace = run.integrator.newton().objective_trace();
        for (k, w) in trace.windows(2).enumerate() {
            // Only the round-off of evaluating g twice separates equal values.
            assert!(
                w[1] <= w[0] + 1e-12 * w[0].abs(),
                "step {step}, iterate {k}: g rose from {} to {}",
                w[0],
                w[1]
            );
        }
        let x = run.system.positions();
        let bad = intersecting_pairs(x, &triangles);
        assert!(bad.is_empty(), "step {step}: triangles {bad:?} intersect");
        let gap = min_gap(x, &triangles, run.settings.thickness);
        assert!(gap > 0.0, "step {step}: smallest gap {gap}");
        smallest = smallest.min(gap);
    }
    (smallest, widened)
}

#[test]
fn a_sheet_dropped_onto_a_pinned_sheet_rests_on_it_without_crossing() {
    let n = 7;
    let s = 0.05;
    // The top sheet 2 cm up, shifted and turned; the bottom one pinned along its border.
    let (x, t, fixed) = sheets::dropped(n, s);
    let settings = SelfContactSettings {
        dhat: 2e-3,
        thickness: 1e-3,
        ..SelfContactSettings::default()
    };
    for scheme in SCHEMES {
        let mut run = build_with(
            scheme,
            x.clone(),
            t.clone(),
            fixed.clone(),
            Vec::new(),
            settings,
        );
        let (smallest, widened) = run_checked(&mut run, 45);
        // Contact coupled particles no spring joins, and the pattern gained their slots.
        assert!(widened > 0, "{scheme:?}");
        // The top sheet landed: it came within the barrier's reach and stays there,
        // resting on the bottom sheet rather than falling through it.
        assert!(
            smallest < settings.dhat,
            "{scheme:?}: smallest gap {smallest}"
        );
        let x = run.system.positions();
        let top_low = x[n * n..].iter().map(|p| p.y).fold(f64::INFINITY, f64::min);
        let bottom_high = x[..n * n]
            .iter()
            .map(|p| p.y)
            .fold(f64::NEG_INFINITY, f64::max);
        assert!(
            top_low > bottom_high - 0.05,
            "{scheme:?}: {top_low} {bottom_high}"
        );
        assert!(run.stats.kappa() > 0.0, "{scheme:?}");
        // Every top vertex is still above the bottom sheet's plane region it is over.
        let centre_top = x[n * n + n * n / 2];
        let centre_bottom = x[n * n / 2];
        assert!(
            centre_top.y > centre_bottom.y,
            "{scheme:?}: {centre_top} {centre_bottom}"
        );
    }
}

#[test]
fn a_hanging_sheet_collapses_onto_the_ground_and_folds_onto_itself_without_crossing() {
    let n = 8;
    let s = 0.04;
    // A vertical sheet, bottom edge 5 mm above the ground, leaning a little so it folds.
    let up = DVec3::new(0.0, 0.995, 0.0998);
    let (x, t) = grid(n, DVec3::new(0.0, 0.005, 0.0), DVec3::X, up, s, 0);
    let settings = SelfContactSettings {
        dhat: 2e-3,
        thickness: 1e-3,
        ..SelfContactSettings::default()
    };
    for scheme in SCHEMES {
        let ground = vec![Collider::ground(0.0)];
        let mut run = build_with(scheme, x.clone(), t.clone(), Vec::new(), ground, settings);
        let (smallest, _) = run_checked(&mut run, 40);
        if scheme == Scheme::Midpoint {
            // The guarantees hold (checked above), but the midpoint adds no damping and
            // its nonlinear springs gain energy as the sheet crumples: the total energy
            // goes from 0.022 J to 3.3 J over the 40 steps (28.8 J without self-contact),
            // and the sheet rises again instead of piling up (docs/integrators.md).
            continue;
        }
        let x = run.system.positions();
        // It fell: the top edge came down from 0.28 m to a pile.
        let top = x.iter().map(|p| p.y).fold(f64::NEG_INFINITY, f64::max);
        assert!(top < 0.15, "{scheme:?}: top at {top}");
        // And it touched itself (a pair came within the barrier's reach).
        assert!(
            smallest < settings.dhat,
            "{scheme:?}: smallest gap {smallest}"
        );
        assert!(x.iter().all(|p| p.y > 0.0), "{scheme:?}");
    }
}

#[test]
fn bad_input_is_an_error_naming_it() {
    let (x, t) = grid(3, DVec3::ZERO, DVec3::X, DVec3::Z, 0.1, 0);
    let mesh = TriangleMesh::new(x.clone(), t.clone()).unwrap();
    let cloth = sheets::cloth(vec![]);
    let model = cloth.build(&mesh).unwrap();
    let mut be = model.backward_euler(NewtonSettings::default()).unwrap();
    let err = model
        .enable_self_contact(
            &mut be,
            SelfContactSettings {
                dhat: -1.0,
                ..SelfContactSettings::default()
            },
        )
        .unwrap_err();
    assert!(err.to_string().contains("dhat"), "{err}");
    let err = sinew_spring_sim::contact::self_contact::enable_self_contact(
        &mut be,
        &model.system,
        &[[0, 1, 99]],
        SelfContactSettings::default(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("triangle 0"), "{err}");
    // A barrier's reach (dhat plus the thickness) not below the shortest edge (0.1
    // here) is refused, naming the edge; just below it is accepted.
    for (dhat, thickness) in [(0.1, 0.0), (0.05, 0.05), (1e300, 0.0)] {
        let mut be = model.backward_euler(NewtonSettings::default()).unwrap();
        let settings = SelfContactSettings {
            dhat,
            thickness,
            ..SelfContactSettings::default()
        };
        let err = model.enable_self_contact(&mut be, settings).unwrap_err();
        assert!(err.to_string().contains("shortest edge"), "{err}");
    }
    let mut be = model.backward_euler(NewtonSettings::default()).unwrap();
    let settings = SelfContactSettings {
        dhat: 0.09,
        ..SelfContactSettings::default()
    };
    model.enable_self_contact(&mut be, settings).unwrap();
    // Two sheets 0.5 mm apart with a 1 mm thickness: the start is refused, naming a pair.
    let (mut x2, mut t2) = grid(3, DVec3::ZERO, DVec3::X, DVec3::Z, 0.1, 0);
    let (xb, tb) = grid(3, DVec3::new(0.01, 5e-4, 0.01), DVec3::X, DVec3::Z, 0.1, 9);
    x2.extend(xb);
    t2.extend(tb);
    let mesh = TriangleMesh::new(x2, t2).unwrap();
    let model = cloth.build(&mesh).unwrap();
    let mut be = model.backward_euler(NewtonSettings::default()).unwrap();
    let err = model
        .enable_self_contact(
            &mut be,
            SelfContactSettings {
                thickness: 1e-3,
                ..SelfContactSettings::default()
            },
        )
        .unwrap_err();
    assert!(
        err.to_string().contains("vertex") || err.to_string().contains("edge"),
        "{err}"
    );
}

/// A 3 x 3 sheet in the xz plane (spacing 0.1) and a 3 x 3 sheet standing in the xy
/// plane at z = 0.15 through it, placed so that its edges along y and its diagonals
/// pierce the flat sheet's triangles away from their edges: every vertex-triangle and
/// edge-edge distance is over 5 mm, yet the two sheets pass through each other.
fn crossed_sheets() -> (Vec<DVec3>, Vec<[usize; 3]>) {
    sheets::stacked(
        3,
        0.1,
        DVec3::new(0.03, -0.05, 0.15),
        DVec3::X,
        DVec3::Y,
        0.1,
    )
}

#[test]
fn a_mesh_that_starts_through_itself_is_refused_naming_an_edge_and_a_triangle() {
    let (x, t) = crossed_sheets();
    // The premise: the start crosses, by the exact check, and no pair is within 5 mm.
    assert!(!intersecting_pairs(&x, &t).is_empty());
    assert!(min_gap(&x, &t, 0.0) > 0.005, "{}", min_gap(&x, &t, 0.0));
    let settings = SelfContactSettings {
        dhat: 1e-3,
        ..SelfContactSettings::default()
    };
    // Free, and with the standing sheet held whole as an obstacle: refused either way.
    for fixed in [Vec::new(), (9..18).collect()] {
        let model = sheets::cloth(fixed)
            .build(&TriangleMesh::new(x.clone(), t.clone()).unwrap())
            .unwrap();
        let mut be = model.backward_euler(NewtonSettings::default()).unwrap();
        let err = model.enable_self_contact(&mut be, settings).unwrap_err();
        let text = err.to_string();
        assert!(
            text.contains("edge [") && text.contains("and triangle"),
            "{text}"
        );
        assert!(text.contains("pass through each other"), "{text}");
    }
    // Both sheets held whole: no pair has a free vertex, nothing to refuse.
    let model = sheets::cloth((0..18).collect())
        .build(&TriangleMesh::new(x, t).unwrap())
        .unwrap();
    let mut be = model.backward_euler(NewtonSettings::default()).unwrap();
    model.enable_self_contact(&mut be, settings).unwrap();
}

/// A 2 x 2 sheet in the xz plane (two triangles, spacing 1) and a 2 x 2 sheet of spacing
/// 0.1 standing in the xy plane at z = 0.3 through the inside of one of its triangles:
/// only the small sheet's edges pass through a triangle (the large one's edges are far
/// from it), every distance is over 4 cm.
fn pierced_triangle() -> (Vec<DVec3>, Vec<[usize; 3]>) {
    let (mut x, mut t) = grid(2, DVec3::ZERO, DVec3::X, DVec3::Z, 1.0, 0);
    let (xs, ts) = grid(2, DVec3::new(0.1, -0.05, 0.3), DVec3::X, DVec3::Y, 0.1, 4);
    x.extend(xs);
    t.extend(ts);
    (x, t)
}

#[test]
fn a_step_from_a_state_set_through_itself_is_refused_and_writes_nothing() {
    let (x, t) = pierced_triangle();
    assert!(!intersecting_pairs(&x, &t).is_empty());
    assert!(min_gap(&x, &t, 0.0) > 0.04, "{}", min_gap(&x, &t, 0.0));
    // The small sheet first set 0.3 m up (clear of the large one), the term built
    // there, then the crossing state set by hand.
    let lift = |x: &[DVec3], sheet: std::ops::Range<usize>, dy: f64| -> Vec<DVec3> {
        let mut x = x.to_vec();
        for k in sheet {
            x[k].y += dy;
        }
        x
    };
    let lifted = lift(&x, 4..8, 0.3);
    let settings = SelfContactSettings {
        dhat: 1e-3,
        ..SelfContactSettings::default()
    };
    let Run {
        mut system,
        integrator: mut be,
        ..
    } = build(lifted.clone(), t.clone(), Vec::new(), Vec::new(), settings);
    let v0 = system.velocities().to_vec();
    system.set_state(&x, &v0).unwrap();
    let err = be.take_step(&mut system, H).unwrap_err();
    let StepError::SelfContactCrossing { pair } = &err else {
        panic!("{err:?}");
    };
    assert!(
        pair.starts_with("edge [") && pair.contains("and triangle"),
        "{pair}"
    );
    assert!(err.to_string().contains("pass through each other"), "{err}");
    assert_eq!(system.positions(), x.as_slice());
    assert_eq!(system.velocities(), v0.as_slice());
    // Back at the clear state the steps go on.
    system.set_state(&lifted, &v0).unwrap();
    for _ in 0..3 {
        be.take_step(&mut system, H).unwrap();
    }
    // From an accepted state only the pairs with a moved vertex are checked again: the
    // small sheet moved down through the large one (its edges moved), or the large one
    // moved up onto it (its triangle moved, the edges through it not), both sheets
    // having fallen alike.
    let (x1, v1) = (system.positions().to_vec(), system.velocities().to_vec());
    for (sheet, dy) in [(4..8, -0.3), (0..4, 0.3)] {
        let x = lift(&x1, sheet, dy);
        assert!(!intersecting_pairs(&x, &t).is_empty());
        system.set_state(&x, &v1).unwrap();
        let err = be.take_step(&mut system, H).unwrap_err();
        assert!(
            matches!(err, StepError::SelfContactCrossing { .. }),
            "{err:?}"
        );
        assert_eq!(system.positions(), x.as_slice());
    }
    system.set_state(&x1, &v1).unwrap();
    be.take_step(&mut system, H).unwrap();
}

#[test]
fn a_step_from_a_state_set_with_a_pair_within_the_thickness_is_refused_naming_it() {
    // Two flat 5 x 5 sheets 4 mm apart (1 cm spacing, the top one shifted so no vertex
    // lies above a vertex), dhat 2 mm, thickness 1 mm, the lower one held at its corners.
    let (n, s) = (5, 0.01);
    let (x, t) = sheets::stacked(n, s, DVec3::new(0.003, 0.004, 0.004), DVec3::X, DVec3::Z, s);
    let settings = SelfContactSettings {
        dhat: 2e-3,
        thickness: 1e-3,
        ..SelfContactSettings::default()
    };
    let fixed = vec![0, n - 1, n * (n - 1), n * n - 1];
    let Run {
        mut system,
        integrator: mut be,
        ..
    } = build(x, t.clone(), fixed, Vec::new(), settings);
    // The top sheet's middle vertex set 0.5 mm above the lower sheet's plane, over the
    // inside of a triangle (0.3 mm and 0.4 mm from the grid lines): its distance to that
    // triangle is 0.5 mm, half the thickness.
    let middle = n * n + n * n / 2;
    let (x0, v0) = (system.positions().to_vec(), system.velocities().to_vec());
    let mut x = x0.clone();
    x[middle].y = 5e-4;
    system.set_state(&x, &v0).unwrap();
    let err = be.take_step(&mut system, H).unwrap_err();
    let StepError::SelfContactStart { pair, gap } = &err else {
        panic!("{err:?}");
    };
    assert!(
        pair.starts_with(&format!("vertex {middle} and triangle")),
        "{pair}"
    );
    assert!((gap + 5e-4).abs() < 1e-15, "{gap}");
    assert!(err.to_string().contains("within the thickness"), "{err}");
    // Refused before anything is written.
    assert_eq!(system.positions(), x.as_slice());
    assert_eq!(system.velocities(), v0.as_slice());
    // Pushed through the lower sheet: refused as well (its vertices near the crossing are
    // within the thickness of the top sheet's triangles).
    x[middle].y = -5e-4;
    system.set_state(&x, &v0).unwrap();
    assert!(matches!(
        be.take_step(&mut system, H),
        Err(StepError::SelfContactStart { .. })
    ));
    // The term is not left in a bad state: from an admissible start it steps on, and
    // the steps after it (from accepted states) are not refused.
    system.set_state(&x0, &v0).unwrap();
    for _ in 0..5 {
        be.take_step(&mut system, H).unwrap();
    }
    assert!(min_gap(system.positions(), &t, 1e-3) > 0.0);
}
