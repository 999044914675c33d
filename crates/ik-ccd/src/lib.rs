//! sinew-ik-ccd: filled by its own issue; the crate builds empty until then.
