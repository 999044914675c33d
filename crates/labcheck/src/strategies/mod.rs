//! Generators of random inputs for the sinew crates, one module per domain.
//!
//! Every strategy is built from proptest's own combinators over plain numbers and
//! vectors, so failing cases shrink: lengths and counts towards their lower ends, bone
//! lengths towards 1e-4 (or 0), rotations towards the identity, targets towards the
//! simplest kind. Where a case needs many random numbers (perturbing 400 particles), a
//! seed drives a small deterministic generator ([`SplitMix64`]) and an amplitude that
//! shrinks to zero carries the size of the effect.

pub mod chains;
pub mod contact;
pub mod curves;
pub mod springs;
pub mod targets;

use proptest::prelude::*;
use sinew_math::DVec3;
use std::f64::consts::TAU;

/// A log-uniform number in `[10^lo, 10^hi]`: every decade equally likely.
pub fn log_uniform(lo: f64, hi: f64) -> impl Strategy<Value = f64> + Clone {
    (lo..=hi).prop_map(|e| 10f64.powf(e))
}

/// A unit vector, uniform on the sphere (`z` uniform in `[-1, 1]`, azimuth uniform).
pub fn direction() -> impl Strategy<Value = DVec3> + Clone {
    (-1.0f64..=1.0, 0.0f64..TAU).prop_map(|(z, phi)| {
        let r = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(r * phi.cos(), r * phi.sin(), z)
    })
}

/// A point in the cube `[-extent, extent]^3`.
pub fn point(extent: f64) -> impl Strategy<Value = DVec3> + Clone {
    (-extent..=extent, -extent..=extent, -extent..=extent).prop_map(|(x, y, z)| DVec3::new(x, y, z))
}

/// splitmix64 (Steele, Lea and Flood, 2014): a tiny deterministic generator for the
/// bulk random numbers of one case (its seed is the part proptest chooses).
#[derive(Clone, Debug)]
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

    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in `[-1, 1)`.
    pub fn symmetric(&mut self) -> f64 {
        2.0 * self.unit() - 1.0
    }

    /// A vector with components uniform in `[-1, 1)`.
    pub fn vector(&mut self) -> DVec3 {
        DVec3::new(self.symmetric(), self.symmetric(), self.symmetric())
    }
}
