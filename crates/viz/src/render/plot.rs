//! SVG plots of run time against error (both logarithmic), one colour per method, with
//! the Pareto front (the configurations no other is both faster and more accurate than)
//! drawn as a black line through its points.

use super::chart::COLOURS;
use plotters::prelude::*;
use std::path::Path;

/// One point: (time in seconds, error).
pub type Point = (f64, f64);

/// Indices of the Pareto-optimal points: sorted by time, each has a smaller error than
/// every faster point. Points with a non-finite or non-positive coordinate are never on
/// the front (a run that diverged is not a trade-off).
pub fn pareto_front(points: &[Point]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..points.len())
        .filter(|&i| {
            let (t, e) = points[i];
            t.is_finite() && t > 0.0 && e.is_finite() && e >= 0.0
        })
        .collect();
    order.sort_by(|&a, &b| {
        points[a]
            .0
            .total_cmp(&points[b].0)
            .then(points[a].1.total_cmp(&points[b].1))
    });
    let mut front = Vec::new();
    let mut best = f64::INFINITY;
    for i in order {
        if points[i].1 < best {
            best = points[i].1;
            front.push(i);
        }
    }
    front
}

/// Writes the plot. `series` are (method, points); errors of 0 are drawn at `floor`
/// (the plot's bottom) and counted in the legend entry, non-finite ones are left out
/// and counted the same way.
pub fn time_error_svg(
    path: &Path,
    title: &str,
    time_label: &str,
    error_label: &str,
    series: &[(String, Vec<Point>)],
) -> Result<(), String> {
    let all: Vec<Point> = series.iter().flat_map(|(_, p)| p.iter().copied()).collect();
    let drawable = |&(t, e): &Point| t.is_finite() && t > 0.0 && e.is_finite() && e >= 0.0;
    let positive_errors: Vec<f64> = all
        .iter()
        .filter(|p| drawable(p) && p.1 > 0.0)
        .map(|p| p.1)
        .collect();
    let times: Vec<f64> = all.iter().filter(|p| drawable(p)).map(|p| p.0).collect();
    if times.is_empty() {
        return Err(format!("plot {}: no point to draw", path.display()));
    }
    let (t_min, t_max) = bounds(&times);
    let (mut e_min, e_max) = if positive_errors.is_empty() {
        (1e-16, 1.0)
    } else {
        bounds(&positive_errors)
    };
    let floor = e_min / 10.0;
    e_min = floor;
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| format!("{}: {e}", parent.display()))?;
    }
    let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
    let draw = || -> Result<(), Box<dyn std::error::Error + '_>> {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d(
                (t_min / 1.5..t_max * 1.5).log_scale(),
                (e_min / 1.5..e_max * 3.0).log_scale(),
            )?;
        chart
            .configure_mesh()
            .x_desc(time_label)
            .y_desc(error_label)
            .x_label_formatter(&|v| format!("{v:.0e}"))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()?;
        for (index, (name, points)) in series.iter().enumerate() {
            let colour = COLOURS[index % COLOURS.len()];
            let shown: Vec<Point> = points
                .iter()
                .filter(|p| drawable(p))
                .map(|&(t, e)| (t, e.max(floor)))
                .collect();
            let hidden = points.len() - shown.len();
            let at_floor = points.iter().filter(|p| drawable(p) && p.1 == 0.0).count();
            let mut label = name.clone();
            if hidden > 0 {
                label.push_str(&format!(" ({hidden} diverged/failed, not drawn)"));
            }
            if at_floor > 0 {
                label.push_str(&format!(" ({at_floor} with error 0, at the bottom)"));
            }
            chart
                .draw_series(
                    shown
                        .iter()
                        .map(move |&p| Circle::new(p, 4, colour.filled())),
                )?
                .label(label)
                .legend(move |(x, y)| Circle::new((x, y), 4, colour.filled()));
        }
        let front_indices = pareto_front(&all);
        let front: Vec<Point> = front_indices
            .iter()
            .map(|&i| (all[i].0, all[i].1.max(floor)))
            .collect();
        chart
            .draw_series(LineSeries::new(front.clone(), BLACK.stroke_width(1)))?
            .label("Pareto front")
            .legend(|(x, y)| PathElement::new(vec![(x - 8, y), (x + 8, y)], BLACK));
        chart.draw_series(
            front
                .iter()
                .map(|&p| Circle::new(p, 7, BLACK.stroke_width(1))),
        )?;
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| format!("cannot write plot {}: {e}", path.display()))
}

fn bounds(v: &[f64]) -> (f64, f64) {
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if hi > lo {
        (lo, hi)
    } else {
        (lo / 2.0, hi * 2.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_front_keeps_exactly_the_undominated_points() {
        let points = [
            (1.0, 1e-3),          // 0: fastest
            (2.0, 1e-2),          // 1: dominated by 0
            (3.0, 1e-6),          // 2: on the front
            (3.0, 1e-5),          // 3: same time, worse error: dominated
            (4.0, f64::INFINITY), // 4: diverged: never on the front
            (5.0, 0.0),           // 5: exact: on the front
            (6.0, 1e-9),          // 6: dominated by 5
            (f64::NAN, 1e-12),    // 7: no time: never on the front
        ];
        assert_eq!(pareto_front(&points), vec![0, 2, 5]);
    }

    #[test]
    fn a_plot_is_written_with_a_diverged_point_left_out() {
        let dir = std::env::temp_dir().join(format!("sinew-plot-{}", std::process::id()));
        let path = dir.join("p.svg");
        let series = vec![
            ("a".to_string(), vec![(1e-6, 1e-3), (2e-6, 1e-9)]),
            ("b".to_string(), vec![(5e-7, f64::INFINITY), (3e-6, 0.0)]),
        ];
        time_error_svg(&path, "t", "time", "error", &series).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        assert!(svg.contains("1 diverged/failed, not drawn"));
        assert!(svg.contains("Pareto front"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
