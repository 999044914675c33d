//! The shared workloads of `docs/workloads.md` (W1 flower tracking, W2 random cold solves,
//! W3 unreachable target, and a 10 000-bone chain), generated inline so the benchmark,
//! the time-against-error table and the integration tests use exactly the same data.

#![allow(dead_code)]

use sinew_math::DVec3;
use sinew_skeleton::Skeleton;
use std::f64::consts::TAU;

/// W1: 8 joints, root (0, 0.5, 0), 7 bones of (0.15, 0, 0); reach 1.05.
pub fn w1_skeleton() -> Skeleton {
    Skeleton::chain(DVec3::new(0.0, 0.5, 0.0), &[DVec3::new(0.15, 0.0, 0.0); 7])
        .expect("valid W1 chain")
}

/// A point of the lab flower, `a (6 cos t - cos 6t, 0, 6 sin t - sin 6t)`.
pub fn flower_point(a: f64, t: f64) -> DVec3 {
    DVec3::new(
        a * (6.0 * t.cos() - (6.0 * t).cos()),
        0.0,
        a * (6.0 * t.sin() - (6.0 * t).sin()),
    )
}

/// W1 targets: 500 flower points, `a = 0.1`, `t = 2 pi i / 500`.
pub fn w1_targets() -> Vec<DVec3> {
    (0..500)
        .map(|i| flower_point(0.1, TAU * i as f64 / 500.0))
        .collect()
}

/// W2: root at the origin, 9 bones of (0.1, 0, 0); reach 0.9.
pub fn w2_skeleton() -> Skeleton {
    Skeleton::chain(DVec3::ZERO, &[DVec3::new(0.1, 0.0, 0.0); 9]).expect("valid W2 chain")
}

/// splitmix64: a tiny, well-mixed PRNG, enough for reproducible workloads.
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [-1, 1).
    pub fn next_signed(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// W2 targets: `count` points uniform in the ball of radius 0.95 about the origin
/// (rejection sampling from the cube), fixed seed.
pub fn w2_targets(count: usize) -> Vec<DVec3> {
    let mut rng = SplitMix64(0x5eed_2024);
    let mut out = Vec::with_capacity(count);
    while out.len() < count {
        let p = DVec3::new(rng.next_signed(), rng.next_signed(), rng.next_signed());
        if p.length_squared() <= 1.0 {
            out.push(p * 0.95);
        }
    }
    out
}

/// W3: the W2 chain and the target (3, 1, 0).
pub const W3_TARGET: DVec3 = DVec3::new(3.0, 1.0, 0.0);

/// A chain of `bones` equal bones along x with total reach `reach`, root at (0, 0.5, 0)
/// scaled like W1's.
pub fn long_skeleton(bones: usize, reach: f64) -> Skeleton {
    Skeleton::chain(
        DVec3::new(0.0, 0.5 * reach / 1.05, 0.0),
        &vec![DVec3::new(reach / bones as f64, 0.0, 0.0); bones],
    )
    .expect("valid long chain")
}

/// The W1 flower scaled by `reach / 1.05` (so it sits at the same place relative to the
/// chain's reach), `frames` points.
pub fn scaled_flower(reach: f64, frames: usize) -> Vec<DVec3> {
    (0..frames)
        .map(|i| flower_point(0.1 * reach / 1.05, TAU * i as f64 / frames as f64))
        .collect()
}
