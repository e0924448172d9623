//! The sweep's plots, as SVG: success rate against each swept coordinate with its Wilson interval,
//! and each metric's distribution over all runs.

use std::path::Path;

use anyhow::{anyhow, Context as _, Result};
use plotters::prelude::*;

use super::store::RunResult;
use super::summary::{coordinate, wilson};
use super::Definition;

/// One point of a success plot: a coordinate value, its runs and successes.
#[derive(Clone, Debug, PartialEq)]
pub struct RatePoint {
    /// The coordinate's value.
    pub label: String,
    /// Runs with that value.
    pub runs: usize,
    /// Their successes.
    pub successes: usize,
}

/// Success rate against the values of one coordinate (runs pooled over the other coordinates).
///
/// # Errors
/// Plotting failed (it does not on well-formed input).
pub fn success_svg(key: &str, points: &[RatePoint]) -> Result<String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (640, 400)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
        let k = points.len().max(1) as f64;
        let labels: Vec<String> = points.iter().map(|p| p.label.clone()).collect();
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("success rate against {key} (Wilson 95 % interval)"),
                ("sans-serif", 18),
            )
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d(-0.5..k - 0.5, 0.0..1.05)
            .map_err(|e| anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc(key)
            .y_desc("success rate")
            .x_labels(points.len().max(1))
            .x_label_formatter(&|x| {
                let i = x.round();
                if (x - i).abs() < 1e-6 && i >= 0.0 {
                    labels.get(i as usize).cloned().unwrap_or_default()
                } else {
                    String::new()
                }
            })
            .draw()
            .map_err(|e| anyhow!("{e}"))?;
        let blue = RGBColor(40, 90, 170);
        for (i, p) in points.iter().enumerate() {
            let x = i as f64;
            let (lo, hi) = wilson(p.successes, p.runs);
            let rate = if p.runs == 0 {
                0.0
            } else {
                p.successes as f64 / p.runs as f64
            };
            let bar = blue.stroke_width(2);
            chart
                .draw_series([
                    PathElement::new(vec![(x, lo), (x, hi)], bar),
                    PathElement::new(vec![(x - 0.08, lo), (x + 0.08, lo)], bar),
                    PathElement::new(vec![(x - 0.08, hi), (x + 0.08, hi)], bar),
                ])
                .map_err(|e| anyhow!("{e}"))?;
            chart
                .draw_series([Circle::new((x, rate), 5, blue.filled())])
                .map_err(|e| anyhow!("{e}"))?;
        }
        root.present().map_err(|e| anyhow!("{e}"))?;
    }
    Ok(svg)
}

/// A histogram of one metric's values.
///
/// # Errors
/// Plotting failed (it does not on well-formed input).
pub fn histogram_svg(metric: &str, values: &[f64]) -> Result<String> {
    const BINS: usize = 20;
    let values: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    let (mut lo, mut hi) = values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    if values.is_empty() {
        (lo, hi) = (0.0, 1.0);
    }
    if hi - lo < 1e-12 {
        (lo, hi) = (lo - 0.5, hi + 0.5);
    }
    let width = (hi - lo) / BINS as f64;
    let mut counts = [0usize; BINS];
    for v in &values {
        counts[(((v - lo) / width) as usize).min(BINS - 1)] += 1;
    }
    let top = counts.iter().copied().max().unwrap_or(0).max(1) as f64;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (640, 400)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("{metric}: {} runs", values.len()),
                ("sans-serif", 18),
            )
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d(lo..hi, 0.0..top * 1.1)
            .map_err(|e| anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc(metric)
            .y_desc("runs")
            .draw()
            .map_err(|e| anyhow!("{e}"))?;
        chart
            .draw_series(
                counts
                    .iter()
                    .enumerate()
                    .filter(|(_, &c)| c > 0)
                    .map(|(i, &c)| {
                        let x0 = lo + i as f64 * width;
                        Rectangle::new(
                            [(x0, 0.0), (x0 + width, c as f64)],
                            RGBColor(40, 90, 170).mix(0.7).filled(),
                        )
                    }),
            )
            .map_err(|e| anyhow!("{e}"))?;
        root.present().map_err(|e| anyhow!("{e}"))?;
    }
    Ok(svg)
}

/// Writes `success_vs_<coordinate>.svg` for each swept coordinate and `metric_<name>.svg` for each
/// metric into `dir`.
///
/// # Errors
/// Plotting or writing failed.
pub fn write_all(dir: &Path, definition: &Definition, results: &[RunResult]) -> Result<()> {
    for (key, values) in definition.swept() {
        let points: Vec<RatePoint> = values
            .iter()
            .map(|v| {
                let rs: Vec<&RunResult> = results
                    .iter()
                    .filter(|r| coordinate(r, &key) == *v)
                    .collect();
                RatePoint {
                    label: v.clone(),
                    runs: rs.len(),
                    successes: rs.iter().filter(|r| r.success()).count(),
                }
            })
            .collect();
        let path = dir.join(format!("success_vs_{}.svg", super::file_stem(&key)));
        std::fs::write(&path, success_svg(&key, &points)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let mut metrics: Vec<&String> = results.iter().flat_map(|r| r.metrics.keys()).collect();
    metrics.sort();
    metrics.dedup();
    for m in metrics {
        let values: Vec<f64> = results
            .iter()
            .filter_map(|r| r.metrics.get(m).copied())
            .collect();
        let path = dir.join(format!("metric_{}.svg", super::file_stem(m)));
        std::fs::write(&path, histogram_svg(m, &values)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plots_draw_a_point_per_value_and_a_bar_per_filled_bin() {
        let points = [
            RatePoint {
                label: "1".into(),
                runs: 10,
                successes: 9,
            },
            RatePoint {
                label: "2".into(),
                runs: 10,
                successes: 4,
            },
        ];
        let svg = success_svg("laps", &points).unwrap();
        assert!(svg.starts_with("<svg"));
        assert_eq!(svg.matches("<circle").count(), 2);
        let svg = histogram_svg("closure_mm", &[1.0, 1.0, 2.0, 3.0]).unwrap();
        assert_eq!(svg.matches("<rect").count() - 1, 3, "{svg}");
        assert!(histogram_svg("x", &[]).is_ok());
        assert!(histogram_svg("x", &[2.0]).is_ok());
    }
}
