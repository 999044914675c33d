//! `sinew-bench`: the measurements behind `cargo xtask bench` and `cargo xtask stress`.
//!
//! [`sweep`] holds the time-against-error sweeps (every method across its knobs on the
//! reference workloads, docs/bench.md), [`stress`] the numerical stress grid and the
//! degenerate IK and full-body sets (docs/stress.md), and [`seeded`] the seeded parts of
//! the reference workloads. The workloads built from fixed numbers alone are
//! [`sinew_scene::workloads`].
//!
//! The crate is not published: it draws its seeded workloads with the property suite's
//! generator and checks the energy inequality with its reference sums, so it depends on
//! sinew-labcheck, which keeps the published crates (sinew-scene among them) free of it.

pub mod seeded;
pub mod stress;
pub mod sweep;
