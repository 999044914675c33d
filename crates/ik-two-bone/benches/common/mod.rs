//! The limb and targets the `two_bone` bench and the `two_bone_count` example share, so
//! the timings and the instruction counts measure the same work.

use sinew_ik_two_bone::{Hinge, TwoBoneIk};
use sinew_math::DVec3;
use sinew_skeleton::{GlobalPose, Pose, Skeleton};

/// `n` fixed-seed targets uniform in a ball of radius 0.6 about the shoulder (about a
/// fifth of them beyond the reach of 0.55).
pub fn targets(n: usize) -> Vec<DVec3> {
    let mut state = 0x2b0e_u64;
    let mut next = move || {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let p = DVec3::new(next(), next(), next());
        if p.length() <= 1.0 {
            out.push(p * 0.6);
        }
    }
    out
}

/// Shoulder at the origin, upper arm 0.30 and forearm 0.25 along +x.
pub fn limb() -> Skeleton {
    Skeleton::chain(
        DVec3::ZERO,
        &[DVec3::new(0.30, 0.0, 0.0), DVec3::new(0.25, 0.0, 0.0)],
    )
    .expect("valid limb")
}

/// The limb's rest pose and forward kinematics of it.
pub fn rest(skeleton: &Skeleton) -> (Pose, GlobalPose) {
    let pose = skeleton.rest_pose();
    let mut global = GlobalPose::new();
    skeleton
        .forward_kinematics(&pose, &mut global)
        .expect("valid pose");
    (pose, global)
}

/// The solve: pole (0, -1, -1), elbow hinge 0..150 degrees about z, weight 1, no
/// softening; the target is set before each run.
pub fn job() -> TwoBoneIk {
    let mut job = TwoBoneIk::new(0, 1, 2, DVec3::ZERO, DVec3::new(0.0, -1.0, -1.0));
    job.hinge = Hinge::new(DVec3::Z, 0.0, 150f64.to_radians());
    job
}
