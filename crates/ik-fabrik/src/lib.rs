//! sinew-ik-fabrik: filled by its own issue; the crate builds empty until then.
