//! A mesh cloth through the high-level `Simulation`: `from_mesh_cloth` adds the dihedral
//! bending term as the model's own integrators do (the same steps, bit for bit), and
//! `set_self_contact` adds self-contact to backward Euler, BDF2 and the implicit midpoint
//! (the same steps as the term added by hand, and no two triangles meeting after any
//! step, by the exact check), and `auto` then steps implicitly (as BDF2 does, or backward
//! Euler when settling); the integrators without a place for these are errors that name
//! them.

use crate::common::SCHEMES;
use crate::sheets;
use sinew_exact::intersecting_pairs;
use sinew_math::DVec3;
use sinew_spring_sim::contact::ContactError;
use sinew_spring_sim::contact::self_contact::SelfContactSettings;
use sinew_spring_sim::{
    AutoReason, AutoSettings, Bending, Integrator, IntegratorKind, MeshClothModel, ModelError,
    NewtonSettings, Simulation, SpringSystem, TriangleMesh,
};

const H: f64 = 1.0 / 60.0;

/// The positions and velocities as bits.
fn bits(system: &SpringSystem) -> Vec<u64> {
    system
        .positions()
        .iter()
        .chain(system.velocities())
        .flat_map(|v| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()])
        .collect()
}

/// A 6 x 6 sheet held along one edge, with dihedral bending.
fn bending_sheet() -> MeshClothModel {
    let (x, t) = sheets::grid(6, DVec3::ZERO, DVec3::X, DVec3::Z, 0.05, 0);
    let mut cloth = sheets::cloth((0..6).collect());
    cloth.bending = Bending::Dihedral { stiffness: 1e-2 };
    cloth.build(&TriangleMesh::new(x, t).unwrap()).unwrap()
}

/// Self-contact of the dropped sheets: `dhat` 2 mm, thickness 1 mm, friction `mu`.
fn contact_settings(mu: f64) -> SelfContactSettings {
    SelfContactSettings {
        dhat: 2e-3,
        thickness: 1e-3,
        mu,
        ..SelfContactSettings::default()
    }
}

/// The sheet dropped onto a sheet pinned along its border (6 x 6 each).
fn dropped_sheets() -> MeshClothModel {
    let (x, t, fixed) = sheets::dropped(6, 0.05);
    sheets::cloth(fixed)
        .build(&TriangleMesh::new(x, t).unwrap())
        .unwrap()
}

#[test]
fn a_mesh_cloths_simulation_steps_as_its_own_integrators_with_bending() {
    let model = bending_sheet();
    for scheme in SCHEMES {
        let mut sim = Simulation::from_mesh_cloth(&model, scheme.integrator()).unwrap();
        let mut by_hand = scheme.build(&model, NewtonSettings::default());
        let mut system = model.system.clone();
        for step in 0..20 {
            sim.step(H).unwrap();
            by_hand.take_step(&mut system, H).unwrap();
            assert_eq!(bits(sim.system()), bits(&system), "{scheme:?} step {step}");
        }
        // The bending term acts: the same sheet without it ends elsewhere.
        let mut plain = Simulation::new(model.system.clone(), scheme.integrator()).unwrap();
        for _ in 0..20 {
            plain.step(H).unwrap();
        }
        assert_ne!(bits(plain.system()), bits(sim.system()), "{scheme:?}");
    }
}

/// Every integrator without a Newton workspace of its own for a mesh cloth's terms.
fn not_implicit() -> [Integrator; 4] {
    [
        Integrator::VelocityVerlet { substeps: None },
        Integrator::SymplecticEuler { substeps: 4 },
        Integrator::Auto(AutoSettings::default()),
        Integrator::FlawedReportMethod,
    ]
}

#[test]
fn dihedral_bending_needs_an_implicit_integrator() {
    let model = bending_sheet();
    for integrator in not_implicit() {
        match Simulation::from_mesh_cloth(&model, integrator) {
            Err(ModelError::BadParameter { name, reason }) => {
                assert_eq!(name, "integrator", "{integrator:?}");
                assert!(reason.contains("dihedral bending"), "{reason}");
            }
            other => panic!("{integrator:?}: {other:?}"),
        }
    }
    // Bending springs are springs: every integrator takes them, and the simulation is
    // the system's own (no term added).
    let (x, t) = sheets::grid(6, DVec3::ZERO, DVec3::X, DVec3::Z, 0.05, 0);
    let mut cloth = sheets::cloth((0..6).collect());
    cloth.bending = Bending::Springs { stiffness: 10.0 };
    let springs = cloth.build(&TriangleMesh::new(x, t).unwrap()).unwrap();
    let verlet = Integrator::VelocityVerlet { substeps: None };
    let mut sim = Simulation::from_mesh_cloth(&springs, verlet).unwrap();
    let mut plain = Simulation::new(springs.system.clone(), verlet).unwrap();
    for step in 0..5 {
        sim.step(H).unwrap();
        plain.step(H).unwrap();
        assert_eq!(bits(sim.system()), bits(plain.system()), "step {step}");
    }
}

#[test]
fn self_contact_through_a_simulation_is_the_term_added_by_hand() {
    let model = dropped_sheets();
    let settings = contact_settings(0.3);
    for scheme in SCHEMES {
        let mut sim = Simulation::from_mesh_cloth(&model, scheme.integrator()).unwrap();
        let stats = sim.set_self_contact(&model.triangles, settings).unwrap();
        let mut by_hand = scheme.build(&model, NewtonSettings::default());
        model
            .enable_self_contact(by_hand.newton_mut(), settings)
            .unwrap();
        let mut system = model.system.clone();
        let mut touched = false;
        for step in 0..30 {
            let report = sim.step(H).unwrap();
            assert!(
                report.residual <= report.tolerance,
                "{scheme:?} step {step}"
            );
            by_hand.take_step(&mut system, H).unwrap();
            assert_eq!(bits(sim.system()), bits(&system), "{scheme:?} step {step}");
            let meeting = intersecting_pairs(sim.system().positions(), &model.triangles);
            assert!(meeting.is_empty(), "{scheme:?} step {step}: {meeting:?}");
            touched |= stats.active_pairs() > 0;
        }
        assert!(touched, "{scheme:?}: the sheets never came within dhat");
        assert!(stats.min_gap() > 0.0, "{scheme:?}");
    }
}

#[test]
fn self_contact_needs_an_implicit_integrator_and_is_added_once() {
    let model = dropped_sheets();
    let settings = SelfContactSettings::default();
    for (integrator, name) in [
        (
            Integrator::VelocityVerlet { substeps: None },
            "velocity Verlet",
        ),
        (
            Integrator::SymplecticEuler { substeps: 4 },
            "symplectic Euler",
        ),
    ] {
        let mut sim = Simulation::from_mesh_cloth(&model, integrator).unwrap();
        let err = sim
            .set_self_contact(&model.triangles, settings)
            .unwrap_err();
        assert!(
            matches!(err, ContactError::SelfContactUnsupported { integrator } if integrator == name),
            "{err}"
        );
        assert!(err.to_string().contains(name), "{err}");
    }
    let mut sim =
        Simulation::from_mesh_cloth(&model, Integrator::BackwardEuler(NewtonSettings::default()))
            .unwrap();
    // A triangle naming a particle the cloth lacks.
    let mut bad = model.triangles.clone();
    bad[3][1] = model.system.len();
    let err = sim.set_self_contact(&bad, settings).unwrap_err();
    assert!(
        matches!(&err, ContactError::BadMesh { item, .. } if item.starts_with("triangle 3 ")),
        "{err}"
    );
    sim.set_self_contact(&model.triangles, settings).unwrap();
    let err = sim
        .set_self_contact(&model.triangles, settings)
        .unwrap_err();
    assert!(matches!(err, ContactError::AddedTwice { .. }), "{err}");
}

/// With self-contact `auto` takes every step implicitly: BDF2 with its Newton settings
/// for the reason `Contact` (the same steps as BDF2 asked for, bit for bit), or backward
/// Euler when asked to settle (as backward Euler asked for); no two triangles meet after
/// any step. A second self-contact is refused.
#[test]
fn auto_with_self_contact_steps_implicitly() {
    let model = dropped_sheets();
    // Without friction.
    let settings = contact_settings(0.0);
    for settle in [false, true] {
        let auto = AutoSettings {
            settle,
            ..AutoSettings::default()
        };
        let (same, kind, reason) = if settle {
            (
                Integrator::BackwardEuler(auto.newton),
                IntegratorKind::BackwardEuler,
                AutoReason::Settle,
            )
        } else {
            (
                Integrator::Bdf2(auto.newton),
                IntegratorKind::Bdf2,
                AutoReason::Contact,
            )
        };
        let mut sim = Simulation::from_mesh_cloth(&model, Integrator::Auto(auto)).unwrap();
        let stats = sim.set_self_contact(&model.triangles, settings).unwrap();
        let err = sim
            .set_self_contact(&model.triangles, settings)
            .unwrap_err();
        assert!(matches!(err, ContactError::AddedTwice { .. }), "{err}");
        let mut reference = Simulation::from_mesh_cloth(&model, same).unwrap();
        reference
            .set_self_contact(&model.triangles, settings)
            .unwrap();
        let mut touched = false;
        for step in 0..30 {
            let report = sim.step(H).unwrap();
            assert_eq!(report.integrator, kind, "settle {settle}, step {step}");
            assert_eq!(
                report.auto_reason,
                Some(reason),
                "settle {settle}, step {step}"
            );
            reference.step(H).unwrap();
            assert_eq!(
                bits(sim.system()),
                bits(reference.system()),
                "settle {settle}, step {step}"
            );
            let meeting = intersecting_pairs(sim.system().positions(), &model.triangles);
            assert!(
                meeting.is_empty(),
                "settle {settle}, step {step}: {meeting:?}"
            );
            touched |= stats.active_pairs() > 0;
        }
        assert!(
            touched,
            "settle {settle}: the sheets never came within dhat"
        );
    }
}

/// `MeshClothModel::implicit_stepper` builds the implicit schemes (the tests above step
/// them against `Simulation`) and refuses every other integrator, naming the field.
#[test]
fn a_mesh_cloths_implicit_stepper_refuses_the_others() {
    let model = bending_sheet();
    for integrator in not_implicit() {
        match model.implicit_stepper(integrator) {
            Err(ModelError::BadParameter { name, .. }) => assert_eq!(name, "integrator"),
            Err(other) => panic!("{integrator:?}: {other}"),
            Ok(_) => panic!("{integrator:?}: built"),
        }
    }
}
