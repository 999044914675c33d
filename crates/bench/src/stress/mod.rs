//! The numerical stress grid behind `cargo xtask stress` (docs/stress.md says what is
//! checked and why).
//!
//! - [`cloth`]: the lab cloth at 7 stiffness decades x 5 time steps x 3 grid sizes x 5
//!   initial states, stepped by the default backward Euler; divergence, energy, Newton
//!   work, and the invariants (no NaN, no divergence, the energy inequality); steps left
//!   at Newton's cap far from converged are reported. Contact cases: a sheet thrown onto
//!   the ground or a sphere at every stiffness, time step and drop speed; penetrations
//!   (measured independently), NaN, divergence and unconverged steps.
//! - [`self_contact`]: a free sheet thrown onto a pinned sheet, one mesh with
//!   self-contact, at every stiffness, time step and drop speed; any pair of triangles
//!   passing through each other (by an exact check independent of the solver) fails.
//! - [`ik`]: the degenerate IK set for every solver, with the invariants every solve
//!   must keep (no NaN, bone lengths, a truthful report, the geometric error bound).
//! - [`body`]: the full-body degenerate set for every body solver configuration, with
//!   the invariants every body solve must keep (no NaN, no limit violated, a report equal
//!   to forward kinematics, the cost never above the start).
//! - [`soak`]: W4 with `auto` and W1 tracking for a million steps and frames (no NaN,
//!   no energy gain beyond the scenes' allowance, bone lengths to 1e-12).

pub mod body;
pub mod cloth;
pub mod ik;
pub mod self_contact;
pub mod soak;
