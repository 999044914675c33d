//! SVG line charts of per-frame metrics (error, iterations, energy) with `plotters`.
//!
//! Text in the SVG is laid out by the viewer, so no font is needed when writing. Points
//! with a non-finite coordinate break the line there (a visible gap); on a log-scale y
//! axis, values `<= 0` cannot be placed and are dropped the same way, and the legend
//! entry says how many were dropped. A run of one point between gaps is drawn as a dot.

use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, Ranged, ValueFormatter};
use plotters::prelude::*;
use std::ops::Range;
use std::path::Path;

/// Chart size in pixels (the SVG scales, this sets the proportions and text size).
const SIZE: (u32, u32) = (900, 540);

/// Line colours, in the order series are given; more series reuse them (also the
/// benchmark plots' method colours).
pub const COLOURS: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

/// One named line of a chart.
#[derive(Clone, Copy, Debug)]
pub struct Series<'a> {
    /// Legend entry (empty: no legend entry).
    pub name: &'a str,
    /// The (x, y) points in drawing order.
    pub points: &'a [(f64, f64)],
}

/// A series cut into the runs of points that can be drawn.
struct Prepared {
    label: String,
    colour: RGBColor,
    runs: Vec<Vec<(f64, f64)>>,
}

/// Writes an SVG line chart with `title`, axis labels, one line per series with a legend
/// and, if `log_y`, a logarithmic y axis (values `<= 0` dropped, see the module docs).
/// The legend goes in the corner with the fewest points under it.
///
/// # Errors
/// When no series has a point that can be drawn, or the file cannot be written.
pub fn line_chart_svg(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    log_y: bool,
) -> Result<(), String> {
    let prepared: Vec<Prepared> = series
        .iter()
        .enumerate()
        .map(|(index, s)| prepare(s, COLOURS[index % COLOURS.len()], log_y))
        .collect();
    let mut x_bounds = Bounds::default();
    let mut y_bounds = Bounds::default();
    for &(x, y) in prepared.iter().flat_map(|p| &p.runs).flatten() {
        x_bounds.add(x);
        y_bounds.add(y);
    }
    let (Some(x_range), Some(y_data)) = (x_bounds.range(), y_bounds.range()) else {
        let what = if log_y { "positive finite" } else { "finite" };
        return Err(format!(
            "chart {} ({title}): no {what} points to draw",
            path.display()
        ));
    };
    let x_range = pad_linear(x_range);
    super::create_parent(path)?;
    let root = SVGBackend::new(path, SIZE).into_drawing_area();
    let labels = prepared
        .iter()
        .filter(|p| !p.label.is_empty() && !p.runs.is_empty())
        .count();
    let drawn = if log_y {
        let y_range = pad_log(y_data);
        let (corner, y_range) = place_legend(&prepared, &x_range, y_range, labels, true);
        plot(
            &root,
            title,
            x_label,
            y_label,
            x_range,
            y_range.log_scale(),
            &prepared,
            corner,
        )
    } else {
        let y_range = pad_linear(y_data);
        let (corner, y_range) = place_legend(&prepared, &x_range, y_range, labels, false);
        plot(
            &root, title, x_label, y_label, x_range, y_range, &prepared, corner,
        )
    };
    drawn
        .and_then(|()| root.present().map_err(|e| e.to_string()))
        .map_err(|e| format!("cannot write chart {}: {e}", path.display()))
}

/// Splits a series into drawable runs and builds its legend label.
fn prepare(series: &Series, colour: RGBColor, log_y: bool) -> Prepared {
    let mut runs = Vec::new();
    let mut run = Vec::new();
    let mut dropped = 0;
    for &(x, y) in series.points {
        let drawable = x.is_finite() && y.is_finite() && (!log_y || y > 0.0);
        if drawable {
            run.push((x, y));
        } else {
            if log_y && x.is_finite() && y.is_finite() {
                dropped += 1;
            }
            if !run.is_empty() {
                runs.push(std::mem::take(&mut run));
            }
        }
    }
    if !run.is_empty() {
        runs.push(run);
    }
    let label = match dropped {
        0 => series.name.to_string(),
        1 => format!("{} (1 value <= 0 not shown)", series.name),
        n => format!("{} ({n} values <= 0 not shown)", series.name),
    };
    Prepared {
        label: if series.name.is_empty() {
            String::new()
        } else {
            label
        },
        colour,
        runs,
    }
}

/// Draws the chart on `root` with the given y coordinate (linear or log).
#[allow(clippy::too_many_arguments)]
fn plot<Y>(
    root: &DrawingArea<SVGBackend, Shift>,
    title: &str,
    x_label: &str,
    y_label: &str,
    x_range: Range<f64>,
    y_range: Y,
    prepared: &[Prepared],
    corner: SeriesLabelPosition,
) -> Result<(), String>
where
    Y: AsRangedCoord<Value = f64>,
    Y::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let err = |e: &dyn std::fmt::Display| e.to_string();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 24))
        .margin(18)
        .x_label_area_size(56)
        .y_label_area_size(90)
        .build_cartesian_2d(x_range, y_range)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .axis_desc_style(("sans-serif", 18))
        .label_style(("sans-serif", 14))
        .x_label_formatter(&|v| tick(*v))
        .y_label_formatter(&|v| tick(*v))
        .light_line_style(BLACK.mix(0.04))
        .bold_line_style(BLACK.mix(0.12))
        .draw()
        .map_err(|e| err(&e))?;
    let mut any_label = false;
    for series in prepared {
        let colour = series.colour;
        let mut labelled = series.label.is_empty();
        for run in &series.runs {
            let annotation = if run.len() == 1 {
                chart.draw_series(run.iter().map(|&p| Circle::new(p, 3, colour.filled())))
            } else {
                chart.draw_series(LineSeries::new(run.iter().copied(), colour.stroke_width(2)))
            }
            .map_err(|e| err(&e))?;
            if !labelled {
                annotation
                    .label(series.label.as_str())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 22, y)], colour.stroke_width(3))
                    });
                labelled = true;
                any_label = true;
            }
        }
    }
    if any_label {
        chart
            .configure_series_labels()
            .position(corner)
            .label_font(("sans-serif", 15))
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK.mix(0.4))
            .draw()
            .map_err(|e| err(&e))?;
    }
    Ok(())
}

/// Tick label: plain decimals for ordinary magnitudes, scientific otherwise.
#[must_use]
fn tick(v: f64) -> String {
    let a = v.abs();
    if v == 0.0 {
        "0".to_string()
    } else if !(1e-3..1e5).contains(&a) {
        let s = format!("{v:.1e}");
        // "1.0e-4" reads better as "1e-4".
        s.replace(".0e", "e")
    } else {
        let s = format!("{v:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// The smallest and largest of some values.
#[derive(Default)]
struct Bounds(Option<(f64, f64)>);

impl Bounds {
    fn add(&mut self, v: f64) {
        self.0 = Some(self.0.map_or((v, v), |(lo, hi)| (lo.min(v), hi.max(v))));
    }

    fn range(&self) -> Option<Range<f64>> {
        self.0.map(|(lo, hi)| lo..hi)
    }
}

/// A linear axis range with 4% room on each side (a unit or 10% room around a single
/// value).
#[must_use]
fn pad_linear(r: Range<f64>) -> Range<f64> {
    let span = r.end - r.start;
    if span > 0.0 {
        (r.start - 0.04 * span)..(r.end + 0.04 * span)
    } else {
        let half = if r.start == 0.0 {
            1.0
        } else {
            0.1 * r.start.abs()
        };
        (r.start - half)..(r.end + half)
    }
}

/// A log axis range with room on each side (a factor of 2 around a single value).
#[must_use]
fn pad_log(r: Range<f64>) -> Range<f64> {
    if r.end > r.start {
        let factor = (r.end / r.start).powf(0.04);
        (r.start / factor)..(r.end * factor)
    } else {
        (r.start * 0.5)..(r.end * 2.0)
    }
}

/// Where the legend goes: the corner whose quarter of the plot (35% of the width, 30%
/// of the height) holds no point, or else the upper right with the y range raised so
/// that a band above all the data holds the legend's `labels` lines.
#[must_use]
fn place_legend(
    prepared: &[Prepared],
    x_range: &Range<f64>,
    y_range: Range<f64>,
    labels: usize,
    log_y: bool,
) -> (SeriesLabelPosition, Range<f64>) {
    // Positions along the y axis are linear in log10(y) on a log axis.
    let axis = |y: f64| if log_y { y.log10() } else { y };
    let (y0, y1) = (axis(y_range.start), axis(y_range.end));
    let mut counts = [0_usize; 4];
    for &(x, y) in prepared.iter().flat_map(|p| &p.runs).flatten() {
        let u = (x - x_range.start) / (x_range.end - x_range.start);
        let v = (axis(y) - y0) / (y1 - y0);
        let (left, right) = (u < 0.35, u > 0.65);
        let (bottom, top) = (v < 0.3, v > 0.7);
        counts[0] += usize::from(top && right);
        counts[1] += usize::from(top && left);
        counts[2] += usize::from(bottom && right);
        counts[3] += usize::from(bottom && left);
    }
    let corners = [
        SeriesLabelPosition::UpperRight,
        SeriesLabelPosition::UpperLeft,
        SeriesLabelPosition::LowerRight,
        SeriesLabelPosition::LowerLeft,
    ];
    // The first free corner wins, so upper right is used whenever it is free.
    if let Some(free) = (0..4).find(|&k| counts[k] == 0) {
        return (corners[free].clone(), y_range);
    }
    // About 400 pixels of plot height; each legend line takes 22 and the box 24 more.
    let band = ((labels as f64 * 22.0 + 24.0) / 400.0).min(0.6);
    let top = y0 + (y1 - y0) / (1.0 - band);
    let top = if log_y { 10f64.powf(top) } else { top };
    (SeriesLabelPosition::UpperRight, y_range.start..top)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_scale_drops_non_positive_values_and_splits_runs() {
        let points = [
            (0.0, 1.0),
            (1.0, 0.0),
            (2.0, 0.5),
            (3.0, 0.25),
            (4.0, f64::NAN),
        ];
        let p = prepare(
            &Series {
                name: "e",
                points: &points,
            },
            COLOURS[0],
            true,
        );
        assert_eq!(
            p.runs,
            vec![vec![(0.0, 1.0)], vec![(2.0, 0.5), (3.0, 0.25)]]
        );
        assert_eq!(p.label, "e (1 value <= 0 not shown)");
        let linear = prepare(
            &Series {
                name: "e",
                points: &points,
            },
            COLOURS[0],
            false,
        );
        assert_eq!(linear.runs.len(), 1);
        assert_eq!(linear.label, "e");
    }

    #[test]
    fn ticks_are_short() {
        assert_eq!(tick(0.0), "0");
        assert_eq!(tick(0.25), "0.25");
        assert_eq!(tick(12.0), "12");
        assert_eq!(tick(1e-4), "1e-4");
        assert_eq!(tick(2.5e-6), "2.5e-6");
    }
}
