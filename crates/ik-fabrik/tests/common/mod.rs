//! The reference workloads of `docs/workloads.md` (W1 flower tracking, W2 random cold solves,
//! W3 unreachable), shared by the tests, the benchmarks and the table example, so every
//! number comes from the same chains and targets.

#![allow(dead_code)]

use sinew_math::DVec3;
use sinew_skeleton::Skeleton;
use sinew_skeleton::ik::Chain;
use std::f64::consts::TAU;

/// W1: 8 joints, root offset (0, 0.5, 0), joints 1..7 offset (0.15, 0, 0). Reach 1.05.
pub fn w1_skeleton() -> Skeleton {
    Skeleton::chain(DVec3::new(0.0, 0.5, 0.0), &[DVec3::new(0.15, 0.0, 0.0); 7])
        .expect("W1 chain is valid")
}

/// The lab flower at parameter `t`: `a(6 cos t - cos 6t), 0, a(6 sin t - sin 6t)`.
pub fn flower(t: f64, a: f64) -> DVec3 {
    DVec3::new(
        a * (6.0 * t.cos() - (6.0 * t).cos()),
        0.0,
        a * (6.0 * t.sin() - (6.0 * t).sin()),
    )
}

/// W1 targets: `count` flower points at `t = 2 pi i / count`, a = 0.1.
pub fn flower_targets(count: usize) -> Vec<DVec3> {
    (0..count)
        .map(|i| flower(TAU * i as f64 / count as f64, 0.1))
        .collect()
}

/// W2 (and W3): 10 joints, root at the origin, joints 1..9 offset (0.1, 0, 0). Reach 0.9.
pub fn w2_skeleton() -> Skeleton {
    Skeleton::chain(DVec3::ZERO, &[DVec3::new(0.1, 0.0, 0.0); 9]).expect("W2 chain is valid")
}

/// The whole chain of a serial skeleton.
pub fn whole(skel: &Skeleton) -> Chain {
    Chain::whole(skel).expect("serial chain")
}

/// splitmix64 (Steele, Lea and Flood, 2014): a tiny, well-mixed generator, enough for
/// reproducible workloads.
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [-1, 1).
    pub fn symmetric(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// The fixed seed of the W2 targets.
pub const W2_SEED: u64 = 0x5EED_0000_0000_0002;

/// W2 targets: `count` points uniform in the ball of radius 0.95 about the origin
/// (rejection sampling from the cube), from [`W2_SEED`].
pub fn w2_targets(count: usize) -> Vec<DVec3> {
    let mut rng = SplitMix64(W2_SEED);
    let mut out = Vec::with_capacity(count);
    while out.len() < count {
        let p = DVec3::new(rng.symmetric(), rng.symmetric(), rng.symmetric());
        if p.length_squared() <= 1.0 {
            out.push(p * 0.95);
        }
    }
    out
}

/// The W3 target.
pub const W3_TARGET: DVec3 = DVec3::new(3.0, 1.0, 0.0);

/// A chain of `bones` equal bones with W1's root and reach (1.05), for the flower.
pub fn long_skeleton(bones: usize) -> Skeleton {
    Skeleton::chain(
        DVec3::new(0.0, 0.5, 0.0),
        &vec![DVec3::new(1.05 / bones as f64, 0.0, 0.0); bones],
    )
    .expect("long chain is valid")
}
