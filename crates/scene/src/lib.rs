//! `sinew-scene`: sinew's scene files and what they run.
//!
//! A scene is a RON file: a description and a list of tasks (forward kinematics, IK
//! tracking, two-bone IK, curve sampling, cloth), each naming what it builds. Reading it
//! checks every value before anything runs; a bad file is an error with the file, line
//! and column and what was expected, a bad value names the task and the item. Running it
//! gives typed results: one metrics struct per task kind, serialized as `metrics.json`.
//!
//! Running a scene from code:
//!
//! ```
//! use sinew_scene::{RunOptions, Scene};
//!
//! // The repository's scenes/fk-tree.ron (a doctest runs in its crate's folder).
//! let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/fk-tree.ron");
//! let scene = Scene::from_file(path)?;
//! let results = scene.run(&RunOptions::default());
//! assert!(results.ok() && results.tasks.len() == scene.tasks.len());
//! println!("{}", serde_json::to_string_pretty(&results)?);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! [`schema`] reads and checks a scene ([`limits`] bounds the work it may ask for), [`spec`] holds the descriptions several task
//! kinds share, [`tasks`] the task kinds, [`results`] their typed results and [`run`]
//! the loop that runs them. [`workloads`] builds the reference workloads that are fixed
//! numbers alone (the chains, the lab flower's targets, the cloths), shared with the
//! benchmark sweeps and the stress grid of the unpublished sinew-bench crate.
//! The self-contact scenes count intersections with sinew-exact's exact check, which
//! shares no code with the solver.

pub mod limits;
pub mod results;
pub mod run;
pub mod schema;
pub mod spec;
pub mod tasks;
pub mod workloads;

pub use results::{SceneResults, TaskMetrics, TaskResult};
pub use run::RunOptions;
pub use schema::{Scene, SceneError};
