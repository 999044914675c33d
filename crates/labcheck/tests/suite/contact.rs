//! The contact guarantee of sinew-spring-sim's backward Euler and BDF2 (IPC barrier, line
//! search capped by the time of impact; half the cases each), checked independently: after every accepted step no
//! free particle is inside or on any collider, with the distances computed here from the
//! colliders' fields and prescribed motion (not by the crate's `signed_distance`), nor
//! after any piece of a step split in pieces, and no particle's straight path over a
//! piece goes deeper than the allowance into a moving collider (colliders may be driven,
//! given a new motion, between steps: the test follows them from its own record of their
//! poses); the incremental potential never increases over a step's Newton iterations
//! while the barrier stiffness is unchanged; no NaN; a refused step is a named error,
//! counted, and rare. The properties are described in docs/labcheck.md.

use proptest::prelude::*;
use sinew_labcheck::config;
use sinew_labcheck::strategies::contact::{AREAL_DENSITY, GRAVITY, contact_case};
use sinew_math::{DQuat, DVec3};
use sinew_spring_sim::contact::{Collider, Drive, Motion, Shape};
use sinew_spring_sim::{NewtonSettings, Simulation, StepError, StepStop};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Steps taken and steps refused over all cases of the run (the refusal rate is checked
/// at the end of each case against everything seen so far).
static STEPS_TAKEN: AtomicUsize = AtomicUsize::new(0);
static STEPS_REFUSED: AtomicUsize = AtomicUsize::new(0);
/// Accepted steps that ended with a particle within the contact distance of a collider
/// (so the barrier acted): the property is not vacuous only if these are common.
static STEPS_IN_CONTACT: AtomicUsize = AtomicUsize::new(0);
/// Accepted steps during which the barrier stiffness grew.
static STEPS_KAPPA_GREW: AtomicUsize = AtomicUsize::new(0);
/// Accepted steps with a moving collider, whose pieces' paths were checked.
static STEPS_PATHS_CHECKED: AtomicUsize = AtomicUsize::new(0);
/// Drives: colliders given a new motion before a step.
static STEPS_DRIVEN: AtomicUsize = AtomicUsize::new(0);
/// Accepted steps split in pieces (each piece's end state and path checked).
static STEPS_SPLIT: AtomicUsize = AtomicUsize::new(0);
/// Stretches of one function's iterates checked for descent (every minimization of every
/// step, cut where the barrier stiffness changed).
static SLICES_CHECKED: AtomicUsize = AtomicUsize::new(0);
/// Accepted steps by scheme: backward Euler, BDF2.
static STEPS_BY_SCHEME: [AtomicUsize; 2] = [const { AtomicUsize::new(0) }; 2];
/// Samples along each particle's straight path from one accepted state to the next.
const PATH_SAMPLES: usize = 64;

/// The pose of the collider `c` at time `t`, from its fields alone: the reference point
/// (the half-space's point, the sphere's centre, the capsule's midpoint) follows
/// `r(t) = r_0 + v (t - t_0)` and the shape turns by `omega (t - t_0)` about it, `t_0`
/// being the time `c.shape` is the pose at. (The half-space's normal is turned, not
/// renormalised: the distance divides by its length.)
fn independent_pose(c: &Collider, t: f64) -> Shape {
    let elapsed = t - c.pose_time;
    let turn = DQuat::from_axis_angle(
        c.motion
            .angular_velocity
            .try_normalize()
            .unwrap_or(DVec3::Y),
        c.motion.angular_velocity.length() * elapsed,
    );
    let shift = c.motion.linear_velocity * elapsed;
    match c.shape {
        Shape::HalfSpace { point, normal } => Shape::HalfSpace {
            point: point + shift,
            normal: turn * normal,
        },
        Shape::Sphere { center, radius } => Shape::Sphere {
            center: center + shift,
            radius,
        },
        Shape::Capsule { a, b, radius } => {
            let mid = 0.5 * (a + b);
            Shape::Capsule {
                a: mid + shift + turn * (a - mid),
                b: mid + shift + turn * (b - mid),
                radius,
            }
        }
    }
}

/// The distance from `x` to the collider `c` at time `t`, from its fields alone
/// ([`independent_pose`]): the half-space's distance is the height above its plane, the
/// sphere's the distance to the centre minus the radius, the capsule's the distance to
/// the nearest point of its axis segment minus the radius.
fn independent_distance(c: &Collider, t: f64, x: DVec3) -> f64 {
    match independent_pose(c, t) {
        Shape::HalfSpace { point, normal } => (x - point).dot(normal) / normal.length(),
        Shape::Sphere { center, radius } => (x - center).length() - radius,
        Shape::Capsule { a, b, radius } => {
            let ab = b - a;
            let len2 = ab.length_squared();
            let s = if len2 > 0.0 {
                ((x - a).dot(ab) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (x - (a + s * ab)).length() - radius
        }
    }
}

/// The barrier stiffness backward Euler starts with, written out from docs/contact.md:
/// the stiffness whose barrier holds `m (|g| + dhat / h^2)` at half the contact distance.
fn expected_initial_kappa(mass: f64, dhat: f64, h: f64) -> f64 {
    let force = mass * (GRAVITY + dhat / (h * h));
    force / ((2f64.ln() + 0.5) * dhat)
}

proptest! {
    #![proptest_config(config::with_cases(96))]

    /// No particle inside any collider after any accepted step; `g` never increases over
    /// the iterates of a step at fixed `kappa`; everything finite; refusals named and
    /// rare.
    #[test]
    fn no_penetration_and_no_increase_of_g(case in contact_case()) {
        let system = case.build_system();
        let colliders = case.build_colliders();
        let settings = NewtonSettings {
            record_objective: true,
            max_iterations: 100,
            ..NewtonSettings::default()
        };
        let integrator = case.integrator(settings);
        let mut sim = Simulation::new(system, integrator)
            .map_err(|e| TestCaseError::fail(e.to_string()))?;
        let contact = case.settings();
        sim.set_contact(colliders.clone(), contact)
            .map_err(|e| TestCaseError::fail(e.to_string()))?;
        sim.record_piece_ends(true)
            .map_err(|e| TestCaseError::fail(e.to_string()))?;
        let mass = AREAL_DENSITY * case.spacing * case.spacing;
        let mut kappa = expected_initial_kappa(mass, contact.dhat, case.h);
        // The colliders as this test knows them: each drive re-poses one here, from its
        // own fields ([`independent_pose`]), where the library is told to drive it.
        let mut colliders = colliders;
        for n in 0..case.steps {
            for drive in case.drives.iter().filter(|d| d.step == n) {
                let ci = drive.collider % colliders.len();
                let motion = Motion {
                    linear_velocity: drive.linear_velocity,
                    angular_velocity: drive.angular_velocity,
                };
                let t = sim.time();
                colliders[ci] = Collider {
                    shape: independent_pose(&colliders[ci], t),
                    motion,
                    pose_time: t,
                };
                sim.drive_collider(ci, &Drive::Motion(motion))
                    .map_err(|e| TestCaseError::fail(format!("step {n}: drive refused: {e}")))?;
                STEPS_DRIVEN.fetch_add(1, Ordering::Relaxed);
            }
            let before = sim.system().positions().to_vec();
            let result = sim.step(case.h);
            STEPS_TAKEN.fetch_add(1, Ordering::Relaxed);
            let report = match result {
                Ok(report) => report,
                Err(StepError::Contact { particle, collider }) => {
                    // Allowed (two colliders closing in on a particle within a step), but
                    // it must name real items, and the case ends here.
                    prop_assert!(particle < sim.system().len() && collider < colliders.len());
                    STEPS_REFUSED.fetch_add(1, Ordering::Relaxed);
                    break;
                }
                Err(e) => return Err(TestCaseError::fail(format!("step {n} refused: {e}"))),
            };
            STEPS_BY_SCHEME[(case.seed % 2) as usize].fetch_add(1, Ordering::Relaxed);
            prop_assert!(report.stop != StepStop::NonFinite, "step {n}: non-finite");
            prop_assert!(report.residual.is_finite(), "step {n}: residual {}", report.residual);
            prop_assert!(sim.system().positions().iter().all(|x| x.is_finite()), "step {n}: NaN position");
            prop_assert!(sim.system().velocities().iter().all(|v| v.is_finite()), "step {n}: NaN velocity");

            // The guarantee, measured independently at the accepted state's time.
            let t = sim.time();
            let mut closest = f64::INFINITY;
            for (ci, c) in colliders.iter().enumerate() {
                for (i, &x) in sim.system().positions().iter().enumerate() {
                    let d = independent_distance(c, t, x);
                    closest = closest.min(d);
                    prop_assert!(
                        d > 0.0,
                        "step {n}: particle {i} at distance {d:e} from collider {ci} ({:?})", c.shape
                    );
                }
            }

            if closest < contact.dhat {
                STEPS_IN_CONTACT.fetch_add(1, Ordering::Relaxed);
            }

            // No moving collider passed through a particle within the step: the
            // integrator kept no pass (splitting resolved every one), every piece of the
            // step (one for a step taken whole) ends with every particle outside every
            // collider, and every particle's straight path from one piece's end to the
            // next (from the step's start to the first), sampled against the collider
            // posed at the same times, goes no deeper into it than dhat (at most half
            // its radius): the promise is per piece, the path of one solve.
            prop_assert_eq!(report.swept_passes, 0, "step {}: a pass kept", n);
            let record = sim.piece_ends().expect("recording");
            prop_assert_eq!(record.len(), report.pieces, "step {}: pieces recorded", n);
            if colliders.iter().any(Collider::moves_surface) {
                STEPS_PATHS_CHECKED.fetch_add(1, Ordering::Relaxed);
            }
            if report.pieces > 1 {
                STEPS_SPLIT.fetch_add(1, Ordering::Relaxed);
            }
            let (mut t0, mut from) = (t - case.h, before.as_slice());
            for (k, (end, to)) in record.iter().enumerate() {
                prop_assert!(end > t0, "step {n}, piece {k}: ends at {end}, before {t0}");
                for (ci, c) in colliders.iter().enumerate() {
                    for (i, &x) in to.iter().enumerate() {
                        let d = independent_distance(c, end, x);
                        prop_assert!(
                            d > 0.0,
                            "step {n}, piece {k}: particle {i} at distance {d:e} from collider {ci}"
                        );
                    }
                }
                for (ci, c) in colliders.iter().enumerate().filter(|(_, c)| c.moves_surface()) {
                    let allowance = match c.shape {
                        Shape::HalfSpace { .. } => contact.dhat,
                        Shape::Sphere { radius, .. } | Shape::Capsule { radius, .. } => {
                            contact.dhat.min(0.5 * radius)
                        }
                    };
                    for (i, (&p, &q)) in from.iter().zip(to).enumerate() {
                        for j in 1..PATH_SAMPLES {
                            let s = j as f64 / PATH_SAMPLES as f64;
                            let d = independent_distance(c, t0 + s * (end - t0), p.lerp(q, s));
                            prop_assert!(
                                d > -allowance,
                                "step {n}, piece {k}: particle {i}'s path {d:e} deep in collider {ci} at {s} of the piece"
                            );
                        }
                    }
                }
                (t0, from) = (end, to);
            }
            prop_assert!((t0 - t).abs() <= 1e-12 * t.abs().max(1.0), "step {n}: pieces end at {t0}");
            prop_assert!(from == sim.system().positions(), "step {n}: the last piece is not the step's end");

            // g never increases over the iterates of any minimization of the step (a
            // split step's abandoned attempts and its pieces' solves too), each cut by
            // the library where kappa changed its function: kappa only grows (doubling),
            // and a larger kappa is another function.
            let after = sim.contact_kappa().expect("contact is set");
            prop_assert!(after.is_finite() && after > 0.0);
            let be = sim.newton_workspace().expect("an implicit integrator");
            let trace = be.objective_trace();
            prop_assert!(!trace.is_empty() && trace.iter().all(|g| g.is_finite()));
            if (after - kappa).abs() <= 1e-12 * kappa {
                // kappa never moved within the step: the last minimization is one
                // slice, the whole of its trace (a check of the cut itself).
                prop_assert_eq!(be.step_objective_traces().last(), Some(trace), "step {}", n);
            } else {
                STEPS_KAPPA_GREW.fetch_add(1, Ordering::Relaxed);
                prop_assert!(after > kappa, "step {n}: kappa fell from {kappa} to {after}");
            }
            kappa = after;
            for (m, slice) in be.step_objective_traces().enumerate() {
                SLICES_CHECKED.fetch_add(1, Ordering::Relaxed);
                // Each value is a sum over particles, springs and contacts of terms no
                // larger than the largest value's scale; 1e-12 relative covers its
                // rounding with a wide margin on these small sheets.
                let scale = slice.iter().fold(0.0f64, |m, g| m.max(g.abs()));
                let allowance = 1e-12 * scale.max(f64::MIN_POSITIVE);
                for (k, pair) in slice.windows(2).enumerate() {
                    prop_assert!(
                        pair[1] <= pair[0] + allowance,
                        "step {n}, slice {m}, iteration {k}: g rose from {} to {}", pair[0], pair[1]
                    );
                }
            }
        }
        let taken = STEPS_TAKEN.load(Ordering::Relaxed);
        let refused = STEPS_REFUSED.load(Ordering::Relaxed);
        let in_contact = STEPS_IN_CONTACT.load(Ordering::Relaxed);
        if std::env::var_os("SINEW_CONTACT_COUNTS").is_some() {
            eprintln!(
                "steps {taken}, refused {refused}, in contact {in_contact}, kappa grew {}, drives {}, with a moving collider {}, split {}, slices of g checked {}, accepted by backward Euler and BDF2 {:?}",
                STEPS_KAPPA_GREW.load(Ordering::Relaxed),
                STEPS_DRIVEN.load(Ordering::Relaxed),
                STEPS_PATHS_CHECKED.load(Ordering::Relaxed),
                STEPS_SPLIT.load(Ordering::Relaxed),
                SLICES_CHECKED.load(Ordering::Relaxed),
                STEPS_BY_SCHEME.each_ref().map(|c| c.load(Ordering::Relaxed))
            );
        }
        // Not vacuous: at least one accepted step in five ends with the barrier acting.
        prop_assert!(
            taken < 50 || 5 * in_contact >= taken - refused,
            "only {in_contact} of {taken} steps reached the contact distance"
        );
        // The drives are exercised: some by the time 50 steps were seen.
        prop_assert!(
            taken < 50 || STEPS_DRIVEN.load(Ordering::Relaxed) > 0,
            "no collider driven in {taken} steps"
        );
        // Refusals must stay the exception: at most one step in ten, once enough steps
        // were seen for a rate to mean something.
        prop_assert!(
            taken < 50 || 10 * refused <= taken,
            "{refused} of {taken} steps refused"
        );
    }
}
