//! The self-contact guarantee against an obstacle held whole, checked independently on
//! random small crumpled sheets thrown onto random bumpy terrains meshed more finely
//! than the sheet, with large steps: no two triangles that share no vertex ever meet
//! (the exact check of `sinew_exact`, robust's orientation predicates, no code shared
//! with the solver) over the sheet's and the terrain's triangles together, after every
//! step and every piece of a split step; no vertex of the terrain ever moves (to the
//! bit); the incremental potential never increases over a step's Newton iterates; and
//! nothing is NaN.
//!
//! A case is a terrain of `m x m` vertices 1.2 cm apart (14 to 18 a side, so it is wider
//! than the sheet), each at a random height up to `bumps` (up to 1.5 cm: slopes up to
//! about 50 degrees between neighbours), every vertex pinned: the library forms no pair
//! of two pinned primitives, so it is an obstacle, hashed apart from the free primitives
//! by the broad phase. Above it, centred, a horizontal sheet of `n x n` vertices 3 cm
//! apart (4 to 6 a side), 5 mm above the terrain's highest vertex and crumpled upwards by
//! up to a third of its spacing, thrown down at up to 2 m/s, falls under gravity at a
//! step of 1/30 to 1/4 s onto the bumps (and past the terrain's border, where it hangs).
//! Backward Euler or BDF2, stiffness 1e2 or 1e4, friction `mu` 0 or 0.4 between the
//! primitives (the sheet's own and the sheet against the terrain).

use crate::common::{
    SELF_CONTACT_DHAT as DHAT, SELF_CONTACT_THICKNESS as THICKNESS, check_descent, check_step_ends,
    sheet_cloth,
};
use proptest::prelude::*;
use sinew_exact::intersecting_pairs;
use sinew_labcheck::config;
use sinew_math::DVec3;
use sinew_spring_sim::contact::self_contact::SelfContactSettings;
use sinew_spring_sim::{ClothGrid, NewtonSettings, PinnedStepper, TriangleMesh};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Accepted steps over all cases, and those that ended with some pair within `dhat`
/// (the property is not vacuous only if these are common).
static STEPS: AtomicUsize = AtomicUsize::new(0);
static STEPS_IN_CONTACT: AtomicUsize = AtomicUsize::new(0);

const SHEET_SPACING: f64 = 0.03;
const TERRAIN_SPACING: f64 = 0.012;

#[derive(Clone, Debug)]
struct Case {
    n: usize,
    m: usize,
    bumps: f64,
    heights: Vec<f64>,
    crumple: Vec<f64>,
    speed: f64,
    h: f64,
    stiffness: f64,
    mu: f64,
    bdf2: bool,
}

fn case() -> impl Strategy<Value = Case> {
    (
        4usize..=6,
        14usize..=18,
        0.0f64..0.015,
        0.0f64..2.0,
        0usize..3,
        0usize..2,
        any::<bool>(),
        any::<bool>(),
    )
        .prop_flat_map(|(n, m, bumps, speed, h, k, f, bdf2)| {
            (
                prop::collection::vec(0.0f64..1.0, m * m),
                prop::collection::vec(0.0f64..1.0, n * n),
            )
                .prop_map(move |(heights, crumple)| Case {
                    n,
                    m,
                    bumps,
                    heights,
                    crumple,
                    speed,
                    h: [1.0 / 30.0, 0.1, 0.25][h],
                    stiffness: [1e2, 1e4][k],
                    mu: if f { 0.4 } else { 0.0 },
                    bdf2,
                })
        })
}

/// The terrain's vertices (the first `m * m`) and the sheet's, and the triangles of both
/// (the terrain's first).
fn mesh(c: &Case) -> (Vec<DVec3>, Vec<[usize; 3]>) {
    let terrain = ClothGrid {
        size: c.m,
        ..ClothGrid::lab()
    };
    let mut x: Vec<DVec3> = (0..c.m * c.m)
        .map(|k| {
            let (i, j) = (k / c.m, k % c.m);
            DVec3::new(
                i as f64 * TERRAIN_SPACING,
                c.bumps * c.heights[k],
                j as f64 * TERRAIN_SPACING,
            )
        })
        .collect();
    let mut triangles = terrain.triangles();
    let top = x.iter().map(|p| p.y).fold(0.0, f64::max);
    // Centred over the terrain. The crumple moves a vertex only out of the sheet's plane,
    // by at most a third of the spacing, so primitives sharing no vertex (at least
    // s / sqrt(2) apart in the flat sheet) stay far beyond the thickness.
    let centre = 0.5 * (c.m - 1) as f64 * TERRAIN_SPACING;
    let corner = centre - 0.5 * (c.n - 1) as f64 * SHEET_SPACING;
    for k in 0..c.n * c.n {
        let (i, j) = (k / c.n, k % c.n);
        x.push(DVec3::new(
            corner + i as f64 * SHEET_SPACING,
            top + 0.005 + SHEET_SPACING / 3.0 * c.crumple[k],
            corner + j as f64 * SHEET_SPACING,
        ));
    }
    let sheet = ClothGrid {
        size: c.n,
        ..ClothGrid::lab()
    };
    let offset = c.m * c.m;
    triangles.extend(sheet.triangles().into_iter().map(|t| t.map(|v| v + offset)));
    (x, triangles)
}

proptest! {
    #![proptest_config(config::with_cases(12))]

    /// No triangles meet at any accepted state or piece's end, the terrain never moves,
    /// g never rises over the iterates of a step, everything finite.
    #[test]
    fn sheets_thrown_on_a_pinned_terrain_never_pass_through_it(c in case()) {
        let (x, triangles) = mesh(&c);
        let terrain = c.m * c.m;
        let mesh = TriangleMesh::new(x, triangles.clone()).expect("a valid mesh");
        let model = sheet_cloth(c.stiffness, (0..terrain).collect()).build(&mesh).expect("a valid cloth");
        let newton = NewtonSettings {
            record_objective: true,
            max_iterations: 100,
            ..NewtonSettings::default()
        };
        let mut integrator: Box<dyn PinnedStepper> = if c.bdf2 {
            Box::new(model.bdf2(newton).expect("BDF2"))
        } else {
            Box::new(model.backward_euler(newton).expect("backward Euler"))
        };
        let settings = SelfContactSettings { dhat: DHAT, thickness: THICKNESS, mu: c.mu, ..SelfContactSettings::default() };
        let stats = model.enable_self_contact(integrator.newton_mut(), settings).expect("a valid start");
        let mut system = model.system.clone();
        let mut velocities = system.velocities().to_vec();
        for v in &mut velocities[terrain..] {
            v.y = -c.speed;
        }
        let start = system.positions().to_vec();
        system.set_state(&start, &velocities).expect("a finite state");
        let held = system.positions()[..terrain].to_vec();
        prop_assert!(intersecting_pairs(system.positions(), &triangles).is_empty(), "the start intersects");
        integrator.newton_mut().record_piece_ends(true);
        for step in 0..6 {
            let report = integrator.take_step(&mut system, c.h)
                .map_err(|e| TestCaseError::fail(format!("step {step} refused: {e}")))?;
            let newton = integrator.newton();
            // Every piece's end and the step's: no intersection, the terrain where it
            // started, everything finite.
            check_step_ends(newton, &report, &system, &triangles, step, |x| {
                (x[..terrain] == held[..]).then_some(()).ok_or("the terrain moved")
            })?;
            // Every minimization of the step (a split step's abandoned attempts and
            // pieces too): no collider here, so no stiffness changes within a step.
            for (m, w) in newton.step_objective_traces().enumerate() {
                prop_assert!(w.iter().all(|g| g.is_finite()), "step {step}, slice {m}: g not finite");
            }
            check_descent(newton, step)?;
            STEPS.fetch_add(1, Ordering::Relaxed);
            if stats.min_gap() < DHAT {
                STEPS_IN_CONTACT.fetch_add(1, Ordering::Relaxed);
            }
        }
        // Not vacuous: over the run so far, the barrier acted in a good share of steps.
        let (steps, contact) = (STEPS.load(Ordering::Relaxed), STEPS_IN_CONTACT.load(Ordering::Relaxed));
        if std::env::var_os("SINEW_CONTACT_COUNTS").is_some() {
            eprintln!("steps {steps}, self-contact acting in {contact}");
        }
        if steps >= 30 {
            prop_assert!(4 * contact >= steps, "self-contact acted in only {contact} of {steps} steps");
        }
    }
}
