//! The interactive HTML viewer: one self-contained page per animated task and an index
//! page per scene.
//!
//! The input is plain data, [`ViewerPage`]: the frames of a run (point positions, goals
//! and colliders per frame), the geometry that joins the points (segments drawn as bones
//! or springs, triangles drawn as a shaded surface), the target path, charts with one
//! value per frame and the task's metrics. [`render_page`] checks it, chooses the frames
//! that fit the [`Budget`] and returns the HTML; [`write_page`] writes it to a file and
//! returns the [`PageSummary`] that [`write_scene_index`] lists.
//!
//! A page fetches nothing: its data, script and style are embedded, so it works when
//! opened from disk. In the page the 3D view can be orbited (drag), panned (shift-drag
//! or right-drag) and zoomed (wheel); a timeline slider, play/pause and a speed choice
//! move through the frames (arrow keys step, space plays); each chart has a cursor at
//! the current frame, and a click on a chart jumps to that frame. What the page draws,
//! and how the browser test in `tests/browser.rs` drives it: docs/viewer.md.
//!
//! Encoding: positions, goals, frame times, rest lengths and chart values are written as
//! little-endian `f32` arrays in base64 (about seven significant digits); other numbers
//! (colliders, strain scale) as the shortest JSON decimal of their `f32` value.
//!
//! World convention: `+y` is up. Strain is `l / L - 1`, current over rest length minus
//! one, computed in the page from the embedded rest lengths.

mod decimate;
mod encode;
mod page;

pub use decimate::pick_even;
pub use page::index_html;

use encode::json_number;
use page::{page_html, triangle_rest_lengths};
use sinew_math::DVec3;
use std::fmt;
use std::path::{Path, PathBuf};

/// The most points a chart keeps; longer series are thinned evenly (first and last
/// value kept), which a chart a few hundred pixels wide cannot show anyway.
pub const MAX_CHART_POINTS: usize = 4000;

/// What kind of task a page shows; it sets the page's wording and how points are drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PageKind {
    /// A chain following a target over frames: segments are bones, points are joints.
    IkTrack,
    /// A full-body clip: a skeleton's joints and bones over frames.
    Clip,
    /// A mass-spring cloth: points are particles, segments springs, triangles the
    /// surface shaded by strain.
    Cloth,
}

impl PageKind {
    /// The kind's name as the page and the index print it.
    #[must_use]
    pub fn label(self) -> &'static str {
        match self {
            PageKind::IkTrack => "IK track",
            PageKind::Clip => "full-body clip",
            PageKind::Cloth => "cloth",
        }
    }

    /// The kind's name in the page's data, read by the script.
    fn code(self) -> &'static str {
        match self {
            PageKind::IkTrack => "ik",
            PageKind::Clip => "clip",
            PageKind::Cloth => "cloth",
        }
    }
}

/// A collider drawn in the view, posed at one frame's time.
///
/// Drawn with an orthographic camera, whose silhouettes of a sphere (a disc) and of a
/// capsule (the projected axis thickened by the radius) are exact.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Collider {
    /// The half-space below the plane through `point` with outward `normal`, drawn as
    /// a square grid on the plane around the scene.
    HalfSpace {
        /// A point of the boundary plane.
        point: DVec3,
        /// The outward normal (any non-zero length; the page normalizes it).
        normal: DVec3,
    },
    /// A solid ball.
    Sphere {
        /// The centre.
        center: DVec3,
        /// The radius, positive.
        radius: f64,
    },
    /// The points within `radius` of the segment from `a` to `b`.
    Capsule {
        /// First end of the axis.
        a: DVec3,
        /// Second end of the axis.
        b: DVec3,
        /// The radius, positive.
        radius: f64,
    },
}

impl Collider {
    /// The collider's name in error messages.
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            Collider::HalfSpace { .. } => "half-space",
            Collider::Sphere { .. } => "sphere",
            Collider::Capsule { .. } => "capsule",
        }
    }

    /// Why the collider cannot be drawn, if it cannot.
    fn problem(&self) -> Option<String> {
        let point_problem = |what: &str, p: DVec3| {
            (!representable_point(p)).then(|| format!("{what} {p} is not finite"))
        };
        let radius_problem = |r: f64| {
            (!(representable(r) && r > 0.0)).then(|| format!("radius {r} is not positive"))
        };
        match *self {
            Collider::HalfSpace { point, normal } => point_problem("point", point).or_else(|| {
                if !representable_point(normal) || normal.length() <= 1e-12 {
                    Some(format!("normal {normal} is not a finite non-zero vector"))
                } else {
                    None
                }
            }),
            Collider::Sphere { center, radius } => {
                point_problem("centre", center).or_else(|| radius_problem(radius))
            }
            Collider::Capsule { a, b, radius } => point_problem("end a", a)
                .or_else(|| point_problem("end b", b))
                .or_else(|| radius_problem(radius)),
        }
    }

    /// The collider as a JSON object for the script.
    fn to_json(self) -> String {
        let v = |p: DVec3| {
            format!(
                "[{},{},{}]",
                json_number(p.x),
                json_number(p.y),
                json_number(p.z)
            )
        };
        match self {
            Collider::HalfSpace { point, normal } => {
                format!("{{\"k\":\"plane\",\"p\":{},\"n\":{}}}", v(point), v(normal))
            }
            Collider::Sphere { center, radius } => format!(
                "{{\"k\":\"sphere\",\"c\":{},\"r\":{}}}",
                v(center),
                json_number(radius)
            ),
            Collider::Capsule { a, b, radius } => format!(
                "{{\"k\":\"capsule\",\"a\":{},\"b\":{},\"r\":{}}}",
                v(a),
                v(b),
                json_number(radius)
            ),
        }
    }
}

/// One frame of a run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Frame {
    /// The frame's time in seconds (shown in the caption).
    pub time: f64,
    /// Point positions: joints of a chain or skeleton, particles of a cloth. Every
    /// frame has the same number of points, indexed as in the page's segments,
    /// triangles, fixed points and effectors.
    pub points: Vec<DVec3>,
    /// The goals (targets) of this frame, drawn as rings with a cross; every frame has
    /// the same number of goals.
    pub goals: Vec<DVec3>,
    /// The colliders posed at this frame's time (moving colliders change from frame to
    /// frame; when every shown frame has the same colliders they are written once).
    pub colliders: Vec<Collider>,
}

/// A chart beside the view: one value per frame of the run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Series {
    /// What is plotted, e.g. "effector error" or "total energy".
    pub name: String,
    /// The unit of the values, e.g. "m" or "J" (may be empty).
    pub unit: String,
    /// One finite value per frame of the page (all frames, not only the shown ones).
    pub values: Vec<f64>,
    /// Plot on a logarithmic axis; values that are not positive are drawn at the bottom
    /// of the axis.
    pub log_scale: bool,
}

impl Series {
    /// A series on a linear axis.
    #[must_use]
    pub fn new(name: impl Into<String>, unit: impl Into<String>, values: Vec<f64>) -> Series {
        Series {
            name: name.into(),
            unit: unit.into(),
            values,
            log_scale: false,
        }
    }
}

/// Everything one page shows; the input of [`render_page`] and [`write_page`].
///
/// Build it with [`ViewerPage::new`] and fill the fields that apply. Indices in
/// `segments`, `triangles`, `fixed` and `effectors` refer to [`Frame::points`].
///
/// A cloth of four particles (two triangles) sagging over a sphere, with its energy:
///
/// ```
/// use sinew_math::DVec3;
/// use sinew_viz::viewer::{Budget, Collider, Frame, PageKind, Series, ViewerPage, render_page};
///
/// let mut page = ViewerPage::new("tiny cloth", PageKind::Cloth);
/// page.segments = vec![(0, 1), (1, 3), (3, 2), (2, 0), (0, 3)];
/// page.rest_lengths = vec![1.0, 1.0, 1.0, 1.0, 2f64.sqrt()];
/// page.triangles = vec![[0, 1, 3], [0, 3, 2]];
/// page.fixed = vec![0, 1];
/// let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)];
/// let mut energy = Vec::new();
/// for k in 0..10 {
///     let sag = 0.02 * f64::from(k);
///     let points = corners
///         .iter()
///         .map(|&(x, z)| DVec3::new(x, 1.0 - sag * z, z))
///         .collect();
///     let sphere = Collider::Sphere { center: DVec3::new(0.5, 0.3, 0.5), radius: 0.3 };
///     let time = f64::from(k) / 60.0;
///     page.frames.push(Frame { time, points, goals: vec![], colliders: vec![sphere] });
///     energy.push(1.0 - sag);
/// }
/// page.charts.push(Series::new("energy", "J", energy));
/// page.metrics.push(("steps".into(), "10".into()));
/// let rendered = render_page(&page, &Budget::default())?;
/// assert_eq!(rendered.shown_frames, 10);
///
/// // A segment that names a particle the frames do not have is refused, by name.
/// page.segments.push((3, 4));
/// let err = page.validate().unwrap_err();
/// assert!(err.to_string().contains("segment 5 (3, 4): point 4 out of range"));
/// # Ok::<(), sinew_viz::viewer::ViewerError>(())
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct ViewerPage {
    /// The page's title (the task's name).
    pub title: String,
    /// The kind of task.
    pub kind: PageKind,
    /// One line under the title, e.g. the solver and its settings (may be empty).
    pub subtitle: String,
    /// Every frame of the run, in order; the page shows an even selection of them when
    /// they do not fit the budget.
    pub frames: Vec<Frame>,
    /// Pairs of points joined by a line: bones of a chain or skeleton, springs of a
    /// cloth (drawn only when there are no triangles; with triangles the surface shows
    /// their strain).
    pub segments: Vec<(usize, usize)>,
    /// Empty, or one rest length per segment (positive): then drawn segments are
    /// coloured by strain, and triangle edges take their rest lengths from them.
    pub rest_lengths: Vec<f64>,
    /// Triangles of a surface, shaded by the mean strain of their edges and lit by a
    /// light at the camera. An edge's rest length is that of the segment joining the
    /// same points, or its length in the first frame when no segment does.
    pub triangles: Vec<[usize; 3]>,
    /// Points that do not move (pinned particles, a chain's root), drawn as pins.
    pub fixed: Vec<usize>,
    /// Points that are end effectors, drawn in orange with their recent trail.
    pub effectors: Vec<usize>,
    /// The target path, drawn as a thin polyline (may be empty).
    pub target_path: Vec<DVec3>,
    /// Charts shown beside the view, each with one value per frame.
    pub charts: Vec<Series>,
    /// The task's metrics, shown as a two-column table in this order.
    pub metrics: Vec<(String, String)>,
    /// Strain colours run from blue at `-strain_scale` through grey to red at
    /// `+strain_scale`; `None` uses the largest strain magnitude over the shown frames.
    pub strain_scale: Option<f64>,
}

impl ViewerPage {
    /// An empty page of `kind` titled `title`.
    #[must_use]
    pub fn new(title: impl Into<String>, kind: PageKind) -> ViewerPage {
        ViewerPage {
            title: title.into(),
            kind,
            subtitle: String::new(),
            frames: Vec::new(),
            segments: Vec::new(),
            rest_lengths: Vec::new(),
            triangles: Vec::new(),
            fixed: Vec::new(),
            effectors: Vec::new(),
            target_path: Vec::new(),
            charts: Vec::new(),
            metrics: Vec::new(),
            strain_scale: None,
        }
    }

    /// Checks that the page can be drawn: at least one frame, the same number of points
    /// and goals in every frame, every coordinate, time, radius and chart value finite
    /// (and within `f32` range), every index in range, rest lengths positive and one
    /// per segment, one chart value per frame.
    ///
    /// # Errors
    /// [`ViewerError::InvalidPage`], whose message names the offending frame, point,
    /// goal, collider, segment, triangle or chart.
    pub fn validate(&self) -> Result<(), ViewerError> {
        let fail = |message: String| {
            Err(ViewerError::InvalidPage {
                page: self.title.clone(),
                message,
            })
        };
        let Some(first) = self.frames.first() else {
            return fail("no frames".to_owned());
        };
        let (n_points, n_goals) = (first.points.len(), first.goals.len());
        for (k, frame) in self.frames.iter().enumerate() {
            if !representable(frame.time) {
                return fail(format!("frame {k}: time {} is not finite", frame.time));
            }
            if frame.points.len() != n_points {
                return fail(format!(
                    "frame {k} has {} points, frame 0 has {n_points}",
                    frame.points.len()
                ));
            }
            if frame.goals.len() != n_goals {
                return fail(format!(
                    "frame {k} has {} goals, frame 0 has {n_goals}",
                    frame.goals.len()
                ));
            }
            if let Some(i) = frame.points.iter().position(|&p| !representable_point(p)) {
                return fail(format!(
                    "frame {k}, point {i}: position {} is not finite",
                    frame.points[i]
                ));
            }
            if let Some(i) = frame.goals.iter().position(|&p| !representable_point(p)) {
                return fail(format!(
                    "frame {k}, goal {i}: position {} is not finite",
                    frame.goals[i]
                ));
            }
            for (c, collider) in frame.colliders.iter().enumerate() {
                if let Some(problem) = collider.problem() {
                    return fail(format!(
                        "frame {k}, collider {c} ({}): {problem}",
                        collider.name()
                    ));
                }
            }
        }
        for (s, &(i, j)) in self.segments.iter().enumerate() {
            if let Some(bad) = [i, j].into_iter().find(|&p| p >= n_points) {
                return fail(format!(
                    "segment {s} ({i}, {j}): point {bad} out of range ({n_points} points)"
                ));
            }
        }
        if !self.rest_lengths.is_empty() {
            if self.rest_lengths.len() != self.segments.len() {
                return fail(format!(
                    "{} rest lengths for {} segments",
                    self.rest_lengths.len(),
                    self.segments.len()
                ));
            }
            if let Some(s) = self
                .rest_lengths
                .iter()
                .position(|&l| !(representable(l) && l > 0.0))
            {
                return fail(format!(
                    "segment {s}: rest length {} is not positive",
                    self.rest_lengths[s]
                ));
            }
        }
        for (t, tri) in self.triangles.iter().enumerate() {
            if let Some(bad) = tri.iter().find(|&&p| p >= n_points) {
                return fail(format!(
                    "triangle {t} {tri:?}: point {bad} out of range ({n_points} points)"
                ));
            }
        }
        for (what, list) in [("fixed point", &self.fixed), ("effector", &self.effectors)] {
            if let Some(&bad) = list.iter().find(|&&p| p >= n_points) {
                return fail(format!("{what} {bad} out of range ({n_points} points)"));
            }
        }
        if let Some(i) = self
            .target_path
            .iter()
            .position(|&p| !representable_point(p))
        {
            return fail(format!(
                "target path point {i}: position {} is not finite",
                self.target_path[i]
            ));
        }
        for series in &self.charts {
            if series.values.len() != self.frames.len() {
                return fail(format!(
                    "chart '{}': {} values for {} frames",
                    series.name,
                    series.values.len(),
                    self.frames.len()
                ));
            }
            if let Some(k) = series.values.iter().position(|&v| !representable(v)) {
                return fail(format!(
                    "chart '{}', frame {k}: value {} is not finite",
                    series.name, series.values[k]
                ));
            }
        }
        if let Some(scale) = self.strain_scale
            && !(representable(scale) && scale > 0.0)
        {
            return fail(format!("strain scale {scale} is not positive"));
        }
        Ok(())
    }
}

/// How large a page may grow.
///
/// A run whose frames do not fit is shown with an even selection of its frames (the
/// first and last always kept, see [`pick_even`]), and the page says how many it shows.
///
/// ```
/// use sinew_viz::viewer::Budget;
/// // Pages for a quick look: at most 1 MB and 300 frames each.
/// let small = Budget { max_bytes: 1_000_000, max_frames: 300 };
/// assert_eq!(Budget::default().max_bytes, 5_000_000);
/// # let _ = small;
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Budget {
    /// The most bytes a page may have (the default is 5 000 000, 5 MB).
    pub max_bytes: usize,
    /// The most frames a page shows, however small they are (the default is 1 000),
    /// which keeps scrubbing and playback smooth.
    pub max_frames: usize,
}

impl Default for Budget {
    fn default() -> Budget {
        Budget {
            max_bytes: 5_000_000,
            max_frames: 1000,
        }
    }
}

/// A page as HTML, with which frames it shows.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderedPage {
    /// The complete, self-contained HTML document.
    pub html: String,
    /// The indices (into [`ViewerPage::frames`]) of the frames the page shows, in
    /// increasing order.
    pub frame_indices: Vec<usize>,
    /// How many frames the page shows.
    pub shown_frames: usize,
    /// How many frames the run has.
    pub total_frames: usize,
}

/// What [`write_page`] wrote, as [`write_scene_index`] lists it.
#[derive(Clone, Debug, PartialEq)]
pub struct PageSummary {
    /// The page's file name inside the scene's directory.
    pub file_name: String,
    /// The page's title.
    pub title: String,
    /// The kind of task.
    pub kind: PageKind,
    /// How many frames the page shows.
    pub shown_frames: usize,
    /// How many frames the run has.
    pub total_frames: usize,
    /// The size of the page in bytes.
    pub bytes: usize,
    /// The page's first metrics (at most three), shown in the index.
    pub headline: Vec<(String, String)>,
}

/// Why a page could not be made.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ViewerError {
    /// The page's data is not drawable; the message names the offending item.
    InvalidPage {
        /// The page's title.
        page: String,
        /// What is wrong, naming the frame, point, segment, collider or chart.
        message: String,
    },
    /// Even the first and last frame alone do not fit the budget.
    OverBudget {
        /// The page's title.
        page: String,
        /// The size of the smallest page that could be made.
        bytes: usize,
        /// The budget.
        max_bytes: usize,
    },
    /// A file could not be written.
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's message.
        message: String,
    },
}

impl fmt::Display for ViewerError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ViewerError::InvalidPage { page, message } => {
                write!(f, "viewer page '{page}': {message}")
            }
            ViewerError::OverBudget {
                page,
                bytes,
                max_bytes,
            } => write!(
                f,
                "viewer page '{page}': {bytes} bytes with the fewest frames, over the budget of {max_bytes} bytes"
            ),
            ViewerError::Io { path, message } => {
                write!(f, "viewer: cannot write {}: {message}", path.display())
            }
        }
    }
}

impl std::error::Error for ViewerError {}

/// Checks `page` and renders it as a self-contained HTML document that fits `budget`.
///
/// All frames are shown when they fit both the byte and the frame budget; otherwise the
/// largest even selection that fits (first and last frame kept) is shown, and the page
/// says "showing m of n frames". The result is deterministic: the same page and budget
/// give the same bytes.
///
/// # Errors
/// [`ViewerError::InvalidPage`] when [`ViewerPage::validate`] fails;
/// [`ViewerError::OverBudget`] when even the first and last frame alone exceed
/// `budget.max_bytes`; [`ViewerError::InvalidPage`] naming the budget when
/// `budget.max_frames` is 0.
pub fn render_page(page: &ViewerPage, budget: &Budget) -> Result<RenderedPage, ViewerError> {
    page.validate()?;
    let total = page.frames.len();
    let fewest = total.min(2).min(budget.max_frames);
    let over = |bytes: usize| ViewerError::OverBudget {
        page: page.title.clone(),
        bytes,
        max_bytes: budget.max_bytes,
    };
    if budget.max_frames == 0 {
        return Err(ViewerError::InvalidPage {
            page: page.title.clone(),
            message: "budget: max_frames is 0, and a page shows at least one frame".to_owned(),
        });
    }
    let triangle_rest = triangle_rest_lengths(page);
    let build = |count: usize| {
        let indices = pick_even(total, count);
        let html = page_html(page, &indices, &triangle_rest, budget);
        (indices, html)
    };
    let mut count = total.min(budget.max_frames);
    let (mut indices, mut html) = build(count);
    if html.len() > budget.max_bytes {
        // The size grows linearly with the number of frames shown (give or take a few
        // bytes of number formatting), so two sizes give the cost of a frame; the
        // estimate is then corrected downwards until the page fits.
        let (_, small) = build(fewest);
        if small.len() > budget.max_bytes || count <= fewest {
            return Err(over(small.len()));
        }
        let per_frame = (html.len() - small.len()).div_ceil(count - fewest).max(1);
        count = fewest + (budget.max_bytes - small.len()) / per_frame;
        loop {
            (indices, html) = build(count);
            if html.len() <= budget.max_bytes || count <= fewest {
                break;
            }
            let excess = html.len() - budget.max_bytes;
            count = count.saturating_sub(excess.div_ceil(per_frame)).max(fewest);
        }
        if html.len() > budget.max_bytes {
            return Err(over(html.len()));
        }
    }
    Ok(RenderedPage {
        shown_frames: indices.len(),
        frame_indices: indices,
        total_frames: total,
        html,
    })
}

/// Renders `page` (see [`render_page`]) and writes it to `dir/file_name`, creating
/// `dir` if needed.
///
/// # Errors
/// As [`render_page`]; [`ViewerError::InvalidPage`] when `file_name` is not a plain file
/// name (empty, `.`, `..`, or holding a path separator); [`ViewerError::Io`] when the
/// directory or file cannot be written.
pub fn write_page(
    dir: &Path,
    file_name: &str,
    page: &ViewerPage,
    budget: &Budget,
) -> Result<PageSummary, ViewerError> {
    // The name becomes a link in the index: a plain file name keeps the page inside the
    // scene's directory and the link valid.
    if file_name.is_empty()
        || file_name == "."
        || file_name == ".."
        || file_name.contains(['/', '\\'])
    {
        return Err(ViewerError::InvalidPage {
            page: page.title.clone(),
            message: format!("file name {file_name:?} is not a plain file name"),
        });
    }
    let rendered = render_page(page, budget)?;
    let path = dir.join(file_name);
    write_file(&path, &rendered.html)?;
    Ok(PageSummary {
        file_name: file_name.to_owned(),
        title: page.title.clone(),
        kind: page.kind,
        shown_frames: rendered.shown_frames,
        total_frames: rendered.total_frames,
        bytes: rendered.html.len(),
        headline: page.metrics.iter().take(3).cloned().collect(),
    })
}

/// Writes `dir/index.html`: the scene's name and a table with a link to each page, its
/// kind, how many frames it shows, its size and its headline metrics. Returns the path
/// written.
///
/// ```no_run
/// use sinew_viz::viewer::{Budget, ViewerPage, write_page, write_scene_index};
/// # fn pages() -> Vec<ViewerPage> { Vec::new() }
/// let dir = std::path::Path::new("target/scenes/lab4");
/// let mut summaries = Vec::new();
/// for (k, page) in pages().iter().enumerate() {
///     summaries.push(write_page(dir, &format!("task-{k}.html"), page, &Budget::default())?);
/// }
/// write_scene_index(dir, "lab4", &summaries)?;
/// # Ok::<(), sinew_viz::viewer::ViewerError>(())
/// ```
///
/// # Errors
/// [`ViewerError::Io`] when the directory or file cannot be written.
pub fn write_scene_index(
    dir: &Path,
    scene_name: &str,
    pages: &[PageSummary],
) -> Result<PathBuf, ViewerError> {
    let path = dir.join("index.html");
    write_file(&path, &index_html(scene_name, pages))?;
    Ok(path)
}

/// Writes `text` to `path`, creating the parent directory.
fn write_file(path: &Path, text: &str) -> Result<(), ViewerError> {
    let io = |e: std::io::Error| ViewerError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(io)?;
    }
    std::fs::write(path, text).map_err(io)
}

/// Whether `v` is finite and within `f32` range, so that it survives the page's
/// encoding.
fn representable(v: f64) -> bool {
    v.is_finite() && v.abs() <= f64::from(f32::MAX)
}

/// Whether every coordinate of `p` is [`representable`].
fn representable_point(p: DVec3) -> bool {
    representable(p.x) && representable(p.y) && representable(p.z)
}

#[cfg(test)]
mod tests;
