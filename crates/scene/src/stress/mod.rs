//! The numerical stress grid behind `cargo xtask stress` (docs/stress.md says what is
//! checked and why).
//!
//! - [`cloth`]: the lab cloth at 7 stiffness decades x 5 time steps x 3 grid sizes x 5
//!   initial states, stepped by the default backward Euler; divergence, energy, Newton
//!   work, and the invariants (no NaN, no divergence, the energy inequality); steps left
//!   at Newton's cap far from converged are reported. Contact cases: a sheet thrown onto
//!   the ground or a sphere at every stiffness, time step and drop speed; penetrations
//!   (measured independently), NaN, divergence and unconverged steps.
//! - [`ik`]: the degenerate IK set for every solver, with the invariants every solve
//!   must keep (no NaN, bone lengths, a truthful report, the geometric error bound).

pub mod cloth;
pub mod ik;
