//! `sinew-scene`: sinew's scene files and what they run.
//!
//! [`schema`] reads and checks a RON scene (errors carry the file, line and column),
//! [`spec`] holds the descriptions several task kinds share, and [`tasks`] the task
//! kinds themselves. With the `bench` feature, `bench` holds the time-against-error
//! sweeps and `stress` the numerical stress grid.

#[cfg(feature = "bench")]
pub mod bench;
pub mod schema;
pub mod spec;
#[cfg(feature = "bench")]
pub mod stress;
pub mod tasks;
