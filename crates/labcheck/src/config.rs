//! The proptest configuration every property file uses.
//!
//! Case counts: proptest's default is 256 cases per property, overridden by the
//! `PROPTEST_CASES` environment variable. A few properties are expensive per case (a
//! 1 000-joint chain, a 20 x 20 cloth solved by Newton in the dev profile, where the sinew
//! crates are not optimized); they ask for a fraction of the default with [`cases`], and
//! that fraction scales with `PROPTEST_CASES`, so a deep run deepens every property.
//!
//! Regressions: a failing case, once shrunk, is written to
//! `tests/<file>.proptest-regressions` beside the test file and replayed first on every
//! later run (commit those files).

use proptest::test_runner::{Config, FileFailurePersistence};

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
