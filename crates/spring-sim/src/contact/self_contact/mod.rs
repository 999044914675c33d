//! Self-contact of triangle-mesh cloth after IPC (Li et al. 2020) and its codimensional
//! extension C-IPC (Li et al. 2021): every vertex against every triangle it is not part
//! of, and every edge against every edge it shares no vertex with, kept apart by the log
//! barrier on their distance minus the cloth's thickness, with a line search capped by
//! continuous collision detection so no state the minimization visits has two triangles
//! crossing.
//!
//! - [`dual`]: the second-order forward-mode dual number the distances are
//!   differentiated with.
//! - [`distance`]: point-triangle and edge-edge squared distances, their regions, exact
//!   gradients and Hessians, and the mollifier for nearly parallel edges.
//! - [`closed`]: the closed-form gradient and Hessian of the squared distances, and the
//!   projection of the barrier's Hessian in the few dimensions it spans (the hot path).
//! - [`broad`]: the broad phase, a spatial hash over the primitives' (swept) boxes.
//! - [`ccd`]: additive continuous collision detection over a linear step.
//! - [`crossing`]: whether a state has an edge through a triangle (a start that passes
//!   through itself, which the gaps cannot see).
//! - [`friction`]: lagged, smoothed Coulomb friction between the pairs within `dhat`.
//! - [`psd12`]: the positive semidefinite projection of a pair's 12x12 Hessian.
//! - `spread`: the term's per-pair loops on the integrator's thread pool.
//! - [`term`]: [`SelfContactTerm`], the barrier as a term of the implicit minimization
//!   over the end-of-step positions, and [`enable_self_contact`] (which adds it for every
//!   implicit scheme).
//!
//! Derivations: docs/contact.md.

pub mod broad;
pub mod ccd;
pub mod closed;
pub mod crossing;
pub mod distance;
pub mod dual;
pub mod friction;
pub mod psd12;
mod spread;
pub mod term;

pub use broad::{Candidate, CandidateCache, Primitives, candidates};
pub use ccd::additive_ccd;
pub use closed::RegionForm;
pub use distance::{Closest, PairKind, squared_distance, squared_distance_derivatives};
pub use dual::Dual12;
pub use term::{SelfContactSettings, SelfContactStats, SelfContactTerm, enable_self_contact};
