//! `sinew-viz`: pictures of sinew's scene results.
//!
//! [`render::draw_task`] draws a task's pictures from its result
//! ([`sinew_scene::TaskResult::pictures`]); below it, [`render`] draws PNG stills and animated GIFs of IK chains and cloth, the
//! curve-sampling comparison, SVG line charts of per-frame metrics and the benchmark's
//! time-against-error plots. It only reads the data it is given, so drawing never
//! changes a result.

pub mod render;
