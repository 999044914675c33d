//! Properties of sinew-math's `rotation_between`, on which straightening, CCD and
//! FABRIK's rotation recovery all rest (docs/labcheck.md).

use proptest::prelude::*;
use sinew_labcheck::bounds::EPS;
use sinew_labcheck::config;
use sinew_labcheck::strategies::{direction, log_uniform};
use sinew_math::{DVec3, rotation_between, try_unit};

/// Pairs of vectors: independent directions, or `b` nearly (or exactly) antiparallel or
/// parallel to `a` (perturbed by 0 or 1e-18 to 1e-2), each scaled by 1e-3 to 1e3.
fn pair() -> impl Strategy<Value = (DVec3, DVec3)> {
    let near = (
        direction(),
        direction(),
        prop_oneof![Just(0.0), log_uniform(-18.0, -2.0)],
        prop::bool::ANY,
    )
        .prop_map(|(a, d, tilt, anti)| {
            let b = if anti { -a } else { a } + d * tilt;
            (a, b)
        });
    (
        prop_oneof![(direction(), direction()), near],
        log_uniform(-3.0, 3.0),
        log_uniform(-3.0, 3.0),
    )
        .prop_map(|((a, b), sa, sb)| (a * sa, b * sb))
}

proptest! {
    #![proptest_config(config::standard())]

    /// `rotation_between(a, b)` is a unit quaternion taking the direction of `a` onto
    /// that of `b`, to a few ulps, for every pair of non-zero vectors, including nearly
    /// antiparallel ones (its documentation promises accuracy to rounding there).
    #[test]
    fn rotation_between_maps_a_onto_b((a, b) in pair()) {
        let q = rotation_between(a, b);
        prop_assert!(q.is_finite());
        prop_assert!((q.length() - 1.0).abs() <= 4.0 * EPS);
        let (ua, ub) = (try_unit(a).expect("non-zero"), try_unit(b).expect("non-zero"));
        let off = (q * ua - ub).length();
        prop_assert!(off <= 16.0 * EPS, "|q a - b| = {off:e} for a = {a}, b = {b}, q = {q}");
    }
}
