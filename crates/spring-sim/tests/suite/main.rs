//! The crate's integration tests, one module per subject, built as one test binary:
//! each binary links the crate and faer again, and 33 of them cost a build minutes of
//! linking. Run one subject with `cargo test -p sinew-spring-sim --test suite <module>::`.

mod common;

mod assembly;
mod auto_choice;
mod backward_euler;
mod bending;
mod contact_drive;
mod contact_dynamics;
mod contact_kernels;
mod contact_potential;
mod contact_schemes;
mod contact_squeeze;
mod contact_sweep;
mod contact_toi;
mod contact_validation;
mod errors;
mod explicit_bits;
mod factor_reuse;
mod integrators;
mod long_steps;
mod mesh;
mod parallel_assembly;
mod pins;
mod self_contact_broad;
mod self_contact_ccd;
mod self_contact_closed;
mod self_contact_distance;
mod self_contact_dynamics;
mod self_contact_exact;
mod self_contact_friction;
mod self_contact_pattern;
mod self_contact_term;
mod self_contact_threads;
mod sheets;
mod simulation_mesh;
mod splitting;
mod spring_kernels;
mod terms;
mod thread_counts;
mod tolerance;
mod topology;
mod validation;
