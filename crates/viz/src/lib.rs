//! `sinew-viz`: pictures of sinew's scene results.
//!
//! [`render::draw_task`] draws a task's pictures from its result
//! ([`sinew_scene::TaskResult::pictures`]): PNG stills and animated GIFs of IK chains
//! and cloth, the curve-sampling comparison and SVG line charts of per-frame metrics;
//! [`render`] also draws the benchmark's time-against-error plots. It only reads the
//! data it is given, so drawing never changes a result.
//!
//! [`viewer`] writes one self-contained interactive HTML page per animated task (an IK
//! chain following its target, a full-body clip, a cloth) and an `index.html` for a
//! scene. A page embeds its data, script and style, fetches nothing and works when
//! opened from disk: orbit, pan and zoom the 3D view, scrub a timeline, play at a chosen
//! speed, read the error or energy chart beside the view and the task's metrics.
//!
//! ```
//! use sinew_math::DVec3;
//! use sinew_viz::viewer::{Budget, Frame, PageKind, ViewerPage, render_page};
//!
//! // A two-joint chain swinging towards a goal, three frames.
//! let mut page = ViewerPage::new("swing", PageKind::IkTrack);
//! page.segments = vec![(0, 1)];
//! for k in 0..3 {
//!     let angle = 0.3 * f64::from(k);
//!     page.frames.push(Frame {
//!         time: f64::from(k) / 30.0,
//!         points: vec![DVec3::ZERO, DVec3::new(angle.cos(), angle.sin(), 0.0)],
//!         goals: vec![DVec3::new(0.0, 1.0, 0.0)],
//!         colliders: Vec::new(),
//!     });
//! }
//! let rendered = render_page(&page, &Budget::default()).unwrap();
//! assert!(rendered.html.starts_with("<!DOCTYPE html>"));
//! assert_eq!(rendered.shown_frames, 3);
//! ```
//!
//! What the page shows, how its data is encoded and how the browser test drives it:
//! docs/viewer.md.
//!
//! Architecture invariant: the viewer uses sinew-math only and reads plain data (the
//! conversion from scene results is [`render::viewer_page`]); nothing here runs a
//! solver, so pictures cannot change a run's numbers.

pub mod render;
pub mod viewer;
