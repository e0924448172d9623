//! Time per `Track::nearest` query with the spatial index against the scan of every edge, on
//! generated grids of growing size, measured in the same run. Query points are spread over the
//! arena, within a few centimetres of the tape as a localising robot's are.

use std::hint::black_box;
use std::time::Instant;

use nalgebra::Point2;
use world::presets;

fn per_query_ns(queries: &[Point2<f64>], f: impl Fn(Point2<f64>) -> f64) -> f64 {
    let start = Instant::now();
    let mut sum = 0.0;
    for &q in queries {
        sum += f(q);
    }
    black_box(sum);
    start.elapsed().as_nanos() as f64 / queries.len() as f64
}

fn main() {
    // `cargo test --benches` runs this unoptimised: keep that a smoke run.
    let quick = cfg!(debug_assertions);
    println!("grid     edges   indexed ns/query   scan ns/query   indexed / scan");
    for (cols, rows) in [(8usize, 6usize), (24, 16), (64, 32)] {
        let w = presets::grid(cols, rows, 0);
        let n = if quick { 200 } else { 200_000 };
        // A low-discrepancy walk over the arena, then pulled to within 4 cm of the tape.
        let queries: Vec<Point2<f64>> = (0..n)
            .map(|i| {
                let (u, v) = ((i as f64 * 0.618_034) % 1.0, (i as f64 * 0.754_878) % 1.0);
                let q = Point2::new(u * w.arena.width_m, v * w.arena.height_m);
                let t = w.track.nearest_scan(q).expect("grid has edges");
                let pull = (0.04 / t.distance_m.max(1e-9)).min(1.0);
                t.point + (q - t.point) * pull
            })
            .collect();
        let indexed = per_query_ns(&queries, |q| {
            w.track.nearest(q).map_or(0.0, |t| t.distance_m)
        });
        let scan = per_query_ns(&queries, |q| {
            w.track.nearest_scan(q).map_or(0.0, |t| t.distance_m)
        });
        println!(
            "{cols:2}x{rows:<2}  {:7}   {indexed:16.0}   {scan:13.0}   {:14.3}",
            w.track.edges().len(),
            indexed / scan
        );
    }
}
