//! sinew-labcheck: property tests of the sinew crates live in `tests/`.
