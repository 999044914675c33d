//! The Newton matrix's pattern under self-contact: pairs that come within `dhat` get
//! slots (the pattern widens), and once they have left for good their slots go again
//! (the pattern narrows back), so a long run does not factor the zero blocks of every
//! pair that ever touched.

use crate::self_contact_exact::{sheets_in_contact, sheets_in_contact_with};
use sinew_math::DVec3;
use sinew_spring_sim::{LinearSolverChoice, NewtonSettings, StepStop};

const H: f64 = 1.0 / 60.0;

#[test]
fn the_slots_of_pairs_that_left_contact_are_dropped_and_the_pattern_is_the_springs_again() {
    // Without gravity, a free sheet 0.6 mm (within `dhat` of 2 mm, thickness 1 mm) above
    // a held one: the barrier pushes it off, and it drifts away.
    let (mut integrator, stats, mut system) =
        sheets_in_contact(8, (DVec3::X, DVec3::Z), DVec3::ZERO, true);
    let springs_only = integrator.pattern().nnz();
    let (mut added, mut dropped) = (0, 0);
    let mut widest = springs_only;
    let mut apart_since = None;
    for step in 0..80 {
        let report = integrator.step(&mut system, H).unwrap();
        assert_eq!(report.stop, StepStop::Converged, "step {step}: {report:?}");
        added += report.pattern_pairs_added;
        dropped += report.pattern_pairs_dropped;
        widest = widest.max(integrator.pattern().nnz());
        if stats.active_pairs() == 0 {
            apart_since.get_or_insert(step);
        } else {
            assert!(
                apart_since.is_none(),
                "step {step}: the sheets came back into contact"
            );
        }
    }
    let apart_since = apart_since.expect("the sheets never separated: the case tests nothing");
    assert!(apart_since < 40, "apart only from step {apart_since}");
    assert!(
        added >= 64,
        "{added} pairs widened in: too few to be dropped"
    );
    assert!(widest > springs_only, "the pattern never widened");
    // Every pair that was given slots was dropped again, and the pattern is exactly the
    // springs' (and hinges') once more.
    assert_eq!(dropped, added);
    assert_eq!(integrator.pattern().nnz(), springs_only);
}

#[test]
fn the_pattern_narrows_alike_on_one_and_two_threads() {
    // Two 33 x 33 sheets (2 178 particles, so the integrator's pool runs the step) pushed
    // apart as above, on the direct solver, whose set-up for a narrowed pattern runs as a
    // job on the pool: which pairs are dropped, and when, is a function of the Newton
    // matrices' values, so the runs agree to the bit.
    let run = |threads: usize| {
        let newton = NewtonSettings {
            threads,
            linear_solver: LinearSolverChoice::Direct,
            ..NewtonSettings::default()
        };
        let (mut integrator, _, mut system) =
            sheets_in_contact_with(33, (DVec3::X, DVec3::Z), DVec3::ZERO, true, newton);
        assert_eq!(
            integrator.threads(),
            crate::common::expected_threads(threads)
        );
        let mut counts = Vec::new();
        // The pairs leave `dhat` within the first steps; they are dropped at steps 16
        // and 17.
        for step in 0..20 {
            let report = integrator.step(&mut system, H).unwrap();
            assert_eq!(report.stop, StepStop::Converged, "step {step}: {report:?}");
            counts.push((
                report.iterations,
                report.pattern_pairs_added,
                report.pattern_pairs_dropped,
            ));
        }
        (system, counts, integrator.pattern().nnz())
    };
    let (one, one_counts, one_nnz) = run(1);
    let dropped: usize = one_counts.iter().map(|c| c.2).sum();
    assert!(dropped > 0, "no pair was dropped: the case tests nothing");
    let (two, two_counts, two_nnz) = run(2);
    assert_eq!(one_counts, two_counts);
    assert_eq!(one_nnz, two_nnz);
    let same = |a: &[DVec3], b: &[DVec3]| {
        a.iter()
            .zip(b)
            .all(|(p, q)| p.to_array().map(f64::to_bits) == q.to_array().map(f64::to_bits))
    };
    assert!(same(one.positions(), two.positions()), "positions differ");
    assert!(
        same(one.velocities(), two.velocities()),
        "velocities differ"
    );
}
