//! Limits shared by the integration tests and the benchmarks, so both measure the same
//! joints.

use sinew_skeleton::limits::JointLimit;

/// The workload's shoulder (W7, W8): bone along +x, swing 100 degrees about z, 70 about
/// y, twist +-80 degrees.
pub fn shoulder() -> JointLimit {
    JointLimit::swing_twist(
        sinew_math::DVec3::X,
        sinew_math::DVec3::Z,
        100f64.to_radians(),
        70f64.to_radians(),
        -80f64.to_radians(),
        80f64.to_radians(),
    )
    .expect("valid swing-twist")
}
