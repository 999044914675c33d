//! The `Curve` task: take points on a curve (uniform parameter steps, or evenly spaced by
//! arc length) and measure how even they are and how long the curve is (the lab's
//! Sub-Task 4.1, done right).

use super::{RunContext, TaskOutput, TaskSpec, median_time_ns, non_negative};
use crate::results::{Csv, CurveMetrics, CurvePictures, Pictures, TaskMetrics};
use crate::spec::build_sampled;
use serde::Deserialize;
use sinew_curves::{Curve, CurveSpec, Sampling};

/// Scene fields of a `Curve` task.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CurveTask {
    /// Unique name in the scene.
    pub name: String,
    /// The curve (see sinew-curves' `CurveSpec`).
    pub curve: CurveSpec,
    /// How to take points on it.
    pub sampling: Sampling,
    /// Fail the task if the arc spacing's largest relative deviation exceeds this.
    #[serde(default)]
    pub expect_spacing_rel_dev_max: Option<f64>,
}

/// Tolerance of the table used only to measure the spacing of uniform samples.
const MEASURE_TOLERANCE: f64 = 1e-12;

impl TaskSpec for CurveTask {
    fn validate(&self) -> Result<(), String> {
        build_sampled(&self.curve, &self.sampling)?;
        non_negative(
            "expect_spacing_rel_dev_max",
            self.expect_spacing_rel_dev_max,
        )?;
        Ok(())
    }

    fn run(&self, ctx: &RunContext) -> Result<TaskOutput, String> {
        let curve = build_sampled(&self.curve, &self.sampling)?;
        let sampling = self.sampling;
        let mut samples = curve
            .sample(&sampling)
            .map_err(|e| format!("sampling: {e}"))?;
        // The time of the whole sampling, table building included.
        let time_ns = median_time_ns(200.0, || {
            std::hint::black_box(curve.sample(&sampling).expect("sampled once already"));
        });
        if samples.arc.is_none() {
            // Uniform sampling reports chord spacing only; measure its arc spacing with
            // an accurate table (not timed: it is the measurement, not the method).
            let table = curve.table(MEASURE_TOLERANCE).map_err(|e| e.to_string())?;
            samples.measure_arc(&table);
        }
        let arc = samples.arc.as_ref().map(|a| a.rel_dev_max);
        // The length each method yields: the arc-length table's for arc-length sampling,
        // the sum of chords for uniform sampling (what the lab measured).
        let length = match sampling {
            Sampling::Uniform { .. } => samples.chord.mean * samples.chord.gaps as f64,
            _ => samples
                .length
                .unwrap_or(samples.chord.mean * samples.chord.gaps as f64),
        };
        let length_error = curve.exact_length().map(|exact| (length - exact).abs());

        let mut csv = String::from("index,t,x,y,z\n");
        for (i, (p, t)) in samples.points.iter().zip(&samples.params).enumerate() {
            csv.push_str(&format!("{i},{t},{},{},{}\n", p.x, p.y, p.z));
        }
        let pictures = if ctx.keep_frames {
            // Beyond about 100 points the dots merge into a line and the bunching no
            // longer shows, so the picture draws at most that many (its caption says how
            // many); the metrics are for all of them.
            Pictures::Curve(comparison(
                &curve,
                samples.points.len().min(MAX_DRAWN_POINTS),
            )?)
        } else {
            Pictures::None
        };

        let mut failures = Vec::new();
        if let (Some(limit), Some(dev)) = (self.expect_spacing_rel_dev_max, arc)
            && dev > limit
        {
            failures.push(format!(
                "arc spacing deviation {dev:.3e} > expected at most {limit:.1e}"
            ));
        }
        let metrics = CurveMetrics {
            sampling: sampling_name(&sampling),
            points: samples.points.len(),
            length,
            length_error,
            spacing_rel_dev_max: arc,
            chord_spacing_rel_dev_max: samples.chord.rel_dev_max,
            time_ns,
        };
        let headline = format!(
            "{} points, spacing deviation {}, length error {}",
            samples.points.len(),
            arc.map_or("n/a".into(), |d| format!("{d:.1e}")),
            length_error.map_or("n/a".into(), |e| format!("{e:.1e}")),
        );
        Ok(TaskOutput {
            metrics: TaskMetrics::Curve(metrics),
            headline,
            failures,
            table: Csv {
                suffix: "points.csv",
                text: csv,
            },
            pictures,
        })
    }
}

fn sampling_name(s: &Sampling) -> &'static str {
    match s {
        Sampling::Uniform { .. } => "uniform",
        Sampling::ArcLength { .. } => "arc_length",
        Sampling::ArcSpacing { .. } => "arc_spacing",
    }
}

/// Pictures show at most this many points (more would be a solid line).
const MAX_DRAWN_POINTS: usize = 100;

/// What the Sub-Task 4.1 picture shows: `n` points at uniform parameter steps next to
/// `n` points evenly spaced by arc length, on the curve's line.
fn comparison(curve: &Curve, n: usize) -> Result<CurvePictures, String> {
    let line = curve
        .sample(&Sampling::ArcLength {
            n: 2_000,
            tolerance: MEASURE_TOLERANCE,
        })
        .map_err(|e| e.to_string())?
        .points;
    let uniform = curve
        .sample(&Sampling::Uniform { n })
        .map_err(|e| e.to_string())?
        .points;
    let even = curve
        .sample(&Sampling::ArcLength {
            n,
            tolerance: MEASURE_TOLERANCE,
        })
        .map_err(|e| e.to_string())?
        .points;
    Ok(CurvePictures {
        line,
        uniform,
        even,
    })
}
