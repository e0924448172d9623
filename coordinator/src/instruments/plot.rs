//! The trajectory plot of a run: the tape, the boxes' start places, and each robot's path as the
//! world model estimated it (solid) and, when simulated, as it really went (dashed), as SVG.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{anyhow, Context as _, Result};
use plotters::prelude::*;
use world::World;

use crate::instruments::observer::{robot_colour, track_lines};

/// Draws the plot into an SVG string.
///
/// # Errors
/// Plotting failed (it does not on well-formed input).
pub fn trajectories_svg(
    world: &World,
    estimated: &BTreeMap<u16, Vec<[f64; 2]>>,
    truth: &BTreeMap<u16, Vec<[f64; 2]>>,
) -> Result<String> {
    let (w, h) = (world.arena.width_m, world.arena.height_m);
    let px = 800u32;
    let py = ((f64::from(px) * h / w).round() as u32).clamp(200, 1600) + 40;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (px, py)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("{}: world model (solid), ground truth (dashed)", world.name),
                ("sans-serif", 18),
            )
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(40)
            .build_cartesian_2d(0.0..w, 0.0..h)
            .map_err(|e| anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc("x (m)")
            .y_desc("y (m)")
            .light_line_style(WHITE.mix(0.0))
            .draw()
            .map_err(|e| anyhow!("{e}"))?;
        let tape = RGBColor(60, 60, 60).mix(0.35).stroke_width(6);
        for line in track_lines(&world.track) {
            chart
                .draw_series(LineSeries::new(line.iter().map(|p| (p[0], p[1])), tape))
                .map_err(|e| anyhow!("{e}"))?;
        }
        for o in &world.obstacles {
            let (s, c) = o.heading_rad.sin_cos();
            let (hw, hh) = (o.width_m / 2.0, o.height_m / 2.0);
            let corners: Vec<(f64, f64)> = [(-hw, -hh), (hw, -hh), (hw, hh), (-hw, hh), (-hw, -hh)]
                .iter()
                .map(|(x, y)| (o.position.x + c * x - s * y, o.position.y + s * x + c * y))
                .collect();
            chart
                .draw_series(LineSeries::new(
                    corners,
                    RGBColor(200, 130, 40).stroke_width(2),
                ))
                .map_err(|e| anyhow!("{e}"))?;
        }
        for (id, trail) in estimated {
            let (r, g, b) = robot_colour(*id);
            let colour = RGBColor((r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8);
            chart
                .draw_series(LineSeries::new(
                    trail.iter().map(|p| (p[0], p[1])),
                    colour.stroke_width(2),
                ))
                .map_err(|e| anyhow!("{e}"))?
                .label(format!("robot {id} (world model)"))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                });
            if let Some(t) = truth.get(id) {
                chart
                    .draw_series(DashedLineSeries::new(
                        t.iter().map(|p| (p[0], p[1])),
                        4,
                        3,
                        colour.mix(0.6).stroke_width(1),
                    ))
                    .map_err(|e| anyhow!("{e}"))?;
            }
        }
        if !estimated.is_empty() {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(|e| anyhow!("{e}"))?;
        }
        root.present().map_err(|e| anyhow!("{e}"))?;
    }
    Ok(svg)
}

/// Writes the plot to `path`.
///
/// # Errors
/// Plotting or writing failed.
pub fn write_trajectories(
    path: &Path,
    world: &World,
    estimated: &BTreeMap<u16, Vec<[f64; 2]>>,
    truth: &BTreeMap<u16, Vec<[f64; 2]>>,
) -> Result<()> {
    let svg = trajectories_svg(world, estimated, truth)?;
    std::fs::write(path, svg).with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_has_the_tape_and_each_robot() {
        let world = world::presets::preset("oval").unwrap();
        let mut trails = BTreeMap::new();
        trails.insert(1u16, vec![[0.3, 0.15], [0.4, 0.15], [0.5, 0.16]]);
        trails.insert(2u16, vec![[0.3, 0.45], [0.4, 0.45]]);
        let svg = trajectories_svg(&world, &trails, &BTreeMap::new()).unwrap();
        assert!(svg.starts_with("<svg"), "{}", &svg[..40.min(svg.len())]);
        assert!(svg.contains("robot 1 (world model)"));
        assert!(svg.contains("robot 2 (world model)"));
        assert!(svg.matches("<polyline").count() >= world.track.edges().len() + 2);
    }
}
