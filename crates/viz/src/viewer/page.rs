//! Writing a page and the scene's index as HTML: the markup, the embedded data object
//! the script reads, and the values derived for it (triangle rest lengths, the default
//! strain scale).

use super::encode::{
    base64_len, f32_base64, group_thousands, html_escape, json_number, json_string,
};
use super::{Budget, Frame, MAX_CHART_POINTS, PageSummary, ViewerPage, pick_even};
use sinew_math::DVec3;
use std::fmt::Write as _;

/// The page's script: camera, drawing, timeline, charts.
const SCRIPT: &str = include_str!("viewer.js");
/// The page's style sheet.
const STYLE: &str = include_str!("viewer.css");

/// The scene's index page as HTML (see [`write_scene_index`](super::write_scene_index)).
#[must_use]
pub fn index_html(scene_name: &str, pages: &[PageSummary]) -> String {
    let name = html_escape(scene_name);
    let mut rows = String::new();
    for p in pages {
        let frames = if p.shown_frames == p.total_frames {
            group_thousands(p.total_frames)
        } else {
            format!(
                "{} of {}",
                group_thousands(p.shown_frames),
                group_thousands(p.total_frames)
            )
        };
        let headline: Vec<String> = p
            .headline
            .iter()
            .map(|(k, v)| format!("{}: {}", html_escape(k), html_escape(v)))
            .collect();
        let _ = writeln!(
            rows,
            "<tr><td><a href=\"{href}\">{title}</a></td><td>{kind}</td><td class=\"num\">{frames}</td><td class=\"num\">{size}</td><td>{headline}</td></tr>",
            href = html_escape(&href_escape(&p.file_name)),
            title = html_escape(&p.title),
            kind = p.kind.label(),
            size = format_bytes(p.bytes),
            headline = headline.join("; "),
        );
    }
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
         <title>{name} · sinew viewer</title>\n<link rel=\"icon\" href=\"data:,\">\n\
         <style>\n{STYLE}</style>\n</head>\n<body class=\"index\">\n\
         <header><h1>Scene {name}</h1><p class=\"sub\">{count} interactive page{plural}; each opens from disk and fetches nothing.</p></header>\n\
         <table id=\"pages\"><thead><tr><th>task</th><th>kind</th><th>frames shown</th><th>size</th><th>headline metrics</th></tr></thead>\n\
         <tbody>\n{rows}</tbody></table>\n</body>\n</html>\n",
        count = pages.len(),
        plural = if pages.len() == 1 { "" } else { "s" },
    )
}

/// The page's HTML showing the frames `indices` of `page`.
pub(super) fn page_html(
    page: &ViewerPage,
    indices: &[usize],
    triangle_rest: &[f64],
    budget: &Budget,
) -> String {
    let title = html_escape(&page.title);
    let total = page.frames.len();
    let note = if indices.len() == total {
        format!("showing all {} frames", group_thousands(total))
    } else {
        format!(
            "showing {} of {} frames (evenly chosen, first and last kept) to stay within {} and {} frames",
            group_thousands(indices.len()),
            group_thousands(total),
            format_bytes(budget.max_bytes),
            group_thousands(budget.max_frames),
        )
    };
    let subtitle = if page.subtitle.is_empty() {
        page.kind.label().to_owned()
    } else {
        format!("{} · {}", page.kind.label(), html_escape(&page.subtitle))
    };
    let mut metrics = String::new();
    for (k, v) in &page.metrics {
        let _ = writeln!(
            metrics,
            "<tr><th>{}</th><td>{}</td></tr>",
            html_escape(k),
            html_escape(v)
        );
    }
    let metrics_table = if metrics.is_empty() {
        String::new()
    } else {
        format!("<h2>Metrics</h2>\n<table id=\"metrics\">\n{metrics}</table>\n")
    };
    let data = page_data(page, indices, triangle_rest);
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
         <title>{title} · sinew viewer</title>\n<link rel=\"icon\" href=\"data:,\">\n\
         <style>\n{STYLE}</style>\n</head>\n<body>\n\
         <header><h1>{title}</h1><p class=\"sub\">{subtitle}</p><p id=\"decimation\">{note}</p></header>\n\
         <main>\n<section id=\"stage\">\n<canvas id=\"view\" width=\"800\" height=\"600\"></canvas>\n\
         <div id=\"caption\"></div>\n<div id=\"legend\"></div>\n\
         <p class=\"hint\">drag: orbit · shift-drag or right-drag: pan · wheel: zoom · double-click: reset view · arrow keys: step · space: play</p>\n\
         <div id=\"controls\"><button id=\"play\" type=\"button\">Play</button>\n\
         <input id=\"timeline\" type=\"range\" min=\"0\" max=\"{last}\" step=\"1\" value=\"0\" aria-label=\"frame\">\n\
         <label>speed <select id=\"speed\"><option value=\"0.25\">0.25x</option><option value=\"0.5\">0.5x</option>\
         <option value=\"1\" selected>1x</option><option value=\"2\">2x</option><option value=\"4\">4x</option></select></label>\n\
         <span id=\"frame-label\"></span></div>\n</section>\n\
         <aside id=\"side\">\n<div id=\"charts\"></div>\n{metrics_table}</aside>\n</main>\n\
         <script type=\"application/json\" id=\"sinew-data\">{data}</script>\n\
         <script>\n{SCRIPT}</script>\n</body>\n</html>\n",
        last = indices.len().saturating_sub(1),
    )
}

/// The page's data as one JSON object (see the module documentation for the encoding).
fn page_data(page: &ViewerPage, indices: &[usize], triangle_rest: &[f64]) -> String {
    let shown = || indices.iter().map(|&k| &page.frames[k]);
    let coords = |p: &DVec3| [p.x, p.y, p.z];
    let points = f32_base64(shown().flat_map(|f| f.points.iter().flat_map(coords)));
    let goals = f32_base64(shown().flat_map(|f| f.goals.iter().flat_map(coords)));
    let times = f32_base64(shown().map(|f| f.time));
    let path = f32_base64(page.target_path.iter().flat_map(coords));
    let collider_json = |f: &Frame| {
        let items: Vec<String> = f.colliders.iter().map(|c| c.to_json()).collect();
        format!("[{}]", items.join(","))
    };
    // Colliders that do not move are written once.
    let first_colliders = &page.frames[indices[0]].colliders;
    let colliders = if shown().all(|f| &f.colliders == first_colliders) {
        format!("[{}]", collider_json(&page.frames[indices[0]]))
    } else {
        let all: Vec<String> = shown().map(collider_json).collect();
        format!("[{}]", all.join(","))
    };
    let ints = |values: &mut dyn Iterator<Item = usize>| {
        let list: Vec<String> = values.map(|v| v.to_string()).collect();
        format!("[{}]", list.join(","))
    };
    let total = page.frames.len();
    let chart_frames = pick_even(total, MAX_CHART_POINTS);
    let charts: Vec<String> = page
        .charts
        .iter()
        .map(|s| {
            format!(
                "{{\"name\":{},\"unit\":{},\"log\":{},\"values\":\"{}\"}}",
                json_string(&s.name),
                json_string(&s.unit),
                s.log_scale,
                f32_base64(chart_frames.iter().map(|&k| s.values[k]))
            )
        })
        .collect();
    let strain_scale = page
        .strain_scale
        .or_else(|| largest_strain(page, indices, triangle_rest))
        .map_or("null".to_owned(), json_number);
    let mut out = String::with_capacity(base64_len(points.len()) + 4096);
    let _ = write!(
        out,
        "{{\"kind\":{kind},\"title\":{title},\"totalFrames\":{total},\"frames\":{frames},\
         \"times\":\"{times}\",\"pointCount\":{n_points},\"goalCount\":{n_goals},\
         \"points\":\"{points}\",\"goals\":\"{goals}\",\"segments\":{segments},\
         \"restLengths\":\"{rest}\",\"triangles\":{triangles},\"triangleRest\":\"{tri_rest}\",\
         \"fixed\":{fixed},\"effectors\":{effectors},\"targetPath\":\"{path}\",\
         \"colliders\":{colliders},\"chartFrames\":{chart_frames},\"charts\":[{charts}],\
         \"strainScale\":{strain_scale}}}",
        kind = json_string(page.kind.code()),
        title = json_string(&page.title),
        frames = ints(&mut indices.iter().copied()),
        n_points = page.frames[0].points.len(),
        n_goals = page.frames[0].goals.len(),
        segments = ints(&mut page.segments.iter().flat_map(|&(i, j)| [i, j])),
        rest = f32_base64(page.rest_lengths.iter().copied()),
        triangles = ints(&mut page.triangles.iter().flatten().copied()),
        tri_rest = f32_base64(triangle_rest.iter().copied()),
        fixed = ints(&mut page.fixed.iter().copied()),
        effectors = ints(&mut page.effectors.iter().copied()),
        chart_frames = if chart_frames.len() == total {
            "null".to_owned()
        } else {
            ints(&mut chart_frames.iter().copied())
        },
        charts = charts.join(","),
    );
    out
}

/// Rest lengths of each triangle's three edges (edge `k` joins corners `k` and
/// `k + 1`): that of the segment joining the same points, or else the edge's length in
/// the first frame; a zero length there counts as 1 so strain stays finite.
pub(super) fn triangle_rest_lengths(page: &ViewerPage) -> Vec<f64> {
    if page.triangles.is_empty() {
        return Vec::new();
    }
    let mut rest_of = std::collections::HashMap::new();
    for (s, &(i, j)) in page.segments.iter().enumerate() {
        if let Some(&l) = page.rest_lengths.get(s) {
            rest_of.insert((i.min(j), i.max(j)), l);
        }
    }
    let first = &page.frames[0].points;
    let mut out = Vec::with_capacity(3 * page.triangles.len());
    for tri in &page.triangles {
        for k in 0..3 {
            let (i, j) = (tri[k], tri[(k + 1) % 3]);
            let l = rest_of
                .get(&(i.min(j), i.max(j)))
                .copied()
                .unwrap_or_else(|| first[i].distance(first[j]));
            out.push(if l > 0.0 { l } else { 1.0 });
        }
    }
    out
}

/// The largest strain magnitude of any segment or triangle edge with a rest length
/// over the shown frames, or `None` when there is none (or all are zero).
pub(super) fn largest_strain(
    page: &ViewerPage,
    indices: &[usize],
    triangle_rest: &[f64],
) -> Option<f64> {
    let mut largest: f64 = 0.0;
    for &k in indices {
        let p = &page.frames[k].points;
        for (&(i, j), &l) in page.segments.iter().zip(&page.rest_lengths) {
            largest = largest.max((p[i].distance(p[j]) / l - 1.0).abs());
        }
        for (tri, rest) in page.triangles.iter().zip(triangle_rest.chunks(3)) {
            for e in 0..3 {
                let (i, j) = (tri[e], tri[(e + 1) % 3]);
                largest = largest.max((p[i].distance(p[j]) / rest[e] - 1.0).abs());
            }
        }
    }
    (largest > 0.0 && largest.is_finite()).then_some(largest)
}

/// `bytes` as "812 kB" or "4.7 MB" (decimal units, as the budget is stated).
fn format_bytes(bytes: usize) -> String {
    #[allow(clippy::cast_precision_loss)]
    let b = bytes as f64;
    if bytes >= 1_000_000 {
        format!("{:.1} MB", b / 1e6)
    } else if bytes >= 1000 {
        format!("{:.0} kB", b / 1e3)
    } else {
        format!("{bytes} B")
    }
}

/// `name` as a relative URL: bytes other than letters, digits and `-._~` are
/// percent-encoded, so a space, `#` or `?` in a file name cannot break the link.
fn href_escape(name: &str) -> String {
    let mut out = String::with_capacity(name.len());
    for b in name.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
            out.push(char::from(b));
        } else {
            let _ = write!(out, "%{b:02X}");
        }
    }
    out
}
