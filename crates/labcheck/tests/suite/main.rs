//! The property suite, one module per subject, built as one test binary (a binary per
//! file would link proptest, faer and every sinew crate again for each). Run one subject
//! with `cargo test -p sinew-labcheck --test suite <module>::`; each property and its
//! reason are listed in docs/labcheck.md.

mod common;

mod body;
mod contact;
mod curves;
mod ik;
mod math;
mod obstacle;
mod self_contact;
mod springs;
mod tidy;
mod track;
