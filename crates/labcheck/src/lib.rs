//! sinew-labcheck: property tests (proptest) of the invariants every sinew release must
//! keep, written so a user can run them in their own CI.
//!
//! The properties live in `tests/` (one file per crate under test); this library holds
//! what they share, reusable by anyone writing more properties:
//!
//! - [`strategies`]: generators of random inputs, documented with the ranges they cover
//!   and how they shrink: [`strategies::chains`] (chains and branching trees with poses),
//!   [`strategies::targets`] (every kind of IK target, degenerate ones included),
//!   [`strategies::curves`] (epicycloids, roses, polylines, placements) and
//!   [`strategies::springs`] (grids and random graphs of springs with their states).
//! - [`mod@reference`]: independent computations the properties compare against (bone-length
//!   errors, an independent rose quadrature, the epicycloid's closed form, the backward
//!   Euler incremental potential), written from the formulas in `docs/labcheck.md`, not
//!   by calling the code under test.
//! - [`bounds`]: the round-off allowances the properties use, each one derived in
//!   `docs/labcheck.md` (no tolerance is chosen by trial).
//! - [`config`]: the proptest configuration (case counts that scale with
//!   `PROPTEST_CASES`, a fixed seed unless `PROPTEST_RNG_SEED` names another or
//!   `random`, regression files beside the test files).
//!
//! Run: `cargo test -p sinew-labcheck` (proptest's default of 256 cases per property,
//! scaled down for the few expensive ones, see [`config::cases`]); deep run:
//! `PROPTEST_CASES=20000 PROPTEST_RNG_SEED=random cargo test -p sinew-labcheck --release`.

pub mod bounds;
pub mod config;
pub mod reference;
pub mod strategies;
