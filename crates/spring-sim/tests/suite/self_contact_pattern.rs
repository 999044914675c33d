//! The Newton matrix's pattern under self-contact: pairs that come within `dhat` get
//! slots (the pattern widens), and once they have left for good their slots go again
//! (the pattern narrows back), so a long run does not factor the zero blocks of every
//! pair that ever touched.

use crate::self_contact_exact::sheets_in_contact;
use sinew_math::DVec3;
use sinew_spring_sim::StepStop;

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
