//! sinew-spring-sim: filled by its own issue; the crate builds empty until then.
