//! The proptest configuration every property file uses.
//!
//! Case counts: proptest's default is 256 cases per property, overridden by the
//! `PROPTEST_CASES` environment variable. A few properties are expensive per case (a
//! 1 000-joint chain, a 20 x 20 cloth solved by Newton in the dev profile, where the sinew
//! crates are not optimized); they ask for a fraction of the default with [`cases`], and
//! that fraction scales with `PROPTEST_CASES`, so a deep run deepens every property.
//!
//! Regressions: a failing case, once shrunk, is written to
//! `tests/suite/<module>.proptest-regressions` beside the test module and replayed first
//! on every later run (commit those files).
//!
//! Seeds: every run draws the same cases from a fixed seed ([`DEFAULT_SEED`]), so a
//! green CI run is green again on the same code, and a red one is red again. Another seed
//! is one environment variable away: `PROPTEST_RNG_SEED=<u64>` draws a different fixed
//! set, and `PROPTEST_RNG_SEED=random` draws a fresh set on every run (for deep runs,
//! which then explore cases CI never saw; a failure is still written to the regression
//! file, so it is replayed by every later run whatever the seed).

use proptest::test_runner::{Config, FileFailurePersistence, RngSeed};

/// The seed every property uses unless `PROPTEST_RNG_SEED` says otherwise.
pub const DEFAULT_SEED: u64 = 0x5eed_1ab5;

/// The seed from `PROPTEST_RNG_SEED`: a number, `random`, or unset ([`DEFAULT_SEED`]).
/// Any other value is not silently ignored: the seed falls back to the default and the
/// value is reported on standard error once per property.
#[must_use]
pub fn seed() -> RngSeed {
    match std::env::var("PROPTEST_RNG_SEED") {
        Err(_) => RngSeed::Fixed(DEFAULT_SEED),
        Ok(v) if v.trim().eq_ignore_ascii_case("random") => RngSeed::Random,
        Ok(v) => match v.trim().parse::<u64>() {
            Ok(n) => RngSeed::Fixed(n),
            Err(_) => {
                eprintln!(
                    "PROPTEST_RNG_SEED={v:?} is neither a u64 nor `random`; using the default seed {DEFAULT_SEED}"
                );
                RngSeed::Fixed(DEFAULT_SEED)
            }
        },
    }
}

/// proptest's default case count, the reference for [`cases`].
pub const DEFAULT_CASES: u32 = 256;

/// The number of cases for a property that runs `default` cases at the default setting:
/// `default` scaled by `PROPTEST_CASES / 256` when the variable is set (at least 1).
#[must_use]
pub fn cases(default: u32) -> u32 {
    match std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.trim().parse::<u64>().ok())
    {
        Some(total) => {
            let scaled = u64::from(default) * total / u64::from(DEFAULT_CASES);
            u32::try_from(scaled.max(1)).unwrap_or(u32::MAX)
        }
        None => default,
    }
}

/// The configuration of a property running [`cases`]`(default)` cases, with its
/// regression file beside the test file.
#[must_use]
pub fn with_cases(default: u32) -> Config {
    Config {
        cases: cases(default),
        failure_persistence: Some(Box::new(FileFailurePersistence::WithSource(
            "proptest-regressions",
        ))),
        rng_seed: seed(),
        ..Config::default()
    }
}

/// [`with_cases`] for a property that rejects some generated cases (`prop_assume!`)
/// because they fall outside the regime the property is about: it may reject up to
/// `rejects_per_case` times its case count (proptest's fixed default of 1 024 would
/// abort a deep run).
#[must_use]
pub fn with_rejects(default: u32, rejects_per_case: u32) -> Config {
    let config = with_cases(default);
    Config {
        max_global_rejects: config.cases.saturating_mul(rejects_per_case).max(1024),
        ..config
    }
}

/// The configuration of a property at the default case count.
#[must_use]
pub fn standard() -> Config {
    // Properties that reject inputs outside their premise (for example a target already
    // within tolerance) reject a few percent of cases: allow one reject per case, so deep
    // runs of 20 000 cases are not cut short by proptest's fixed 1 024.
    with_rejects(DEFAULT_CASES, 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::strategy::{Strategy, ValueTree};
    use proptest::test_runner::TestRunner;

    fn draw(config: Config) -> Vec<u64> {
        let mut runner = TestRunner::new(config);
        (0..8)
            .map(|_| {
                (0u64..u64::MAX)
                    .new_tree(&mut runner)
                    .expect("a range strategy never rejects")
                    .current()
            })
            .collect()
    }

    #[test]
    fn a_fixed_seed_draws_the_same_cases_every_run() {
        let seed = RngSeed::Fixed(DEFAULT_SEED);
        let a = draw(Config {
            rng_seed: seed,
            ..with_cases(8)
        });
        let b = draw(Config {
            rng_seed: seed,
            ..with_cases(8)
        });
        assert_eq!(a, b);
        let other = draw(Config {
            rng_seed: RngSeed::Fixed(DEFAULT_SEED + 1),
            ..with_cases(8)
        });
        assert_ne!(a, other, "another seed must draw other cases");
    }

    #[test]
    fn the_configuration_uses_the_seed_from_the_environment_or_the_default() {
        // `seed()` reads the environment; whatever it says, the configuration carries it.
        assert_eq!(with_cases(8).rng_seed, seed());
        if std::env::var_os("PROPTEST_RNG_SEED").is_none() {
            assert_eq!(seed(), RngSeed::Fixed(DEFAULT_SEED));
        }
    }
}
