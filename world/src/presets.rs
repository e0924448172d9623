//! Built-in worlds: the example files in `world/worlds/` compiled in, and a generator of
//! warehouse grids of any size for large-fleet benchmarks.

use nalgebra::Point2;

use super::file::parse;
use super::track::{EdgeSpec, Node, Track};
use super::{Arena, Light, RadioModel, RobotStart, World};

/// Distance between neighbouring grid nodes, in metres.
pub const GRID_SPACING_M: f64 = 0.2;

/// Floor between the outermost grid lines and the walls, in metres.
pub const GRID_MARGIN_M: f64 = 0.2;

/// Most nodes along one side of a generated grid: 400 × 400 nodes already make an 80 m square
/// with 319,200 edges, far beyond any fleet a robot id (u16) can name.
pub const GRID_MAX_SIDE: usize = 400;

const PRESETS: &[(&str, &str)] = &[
    ("oval", include_str!("../worlds/oval.toml")),
    ("push", include_str!("../worlds/push.toml")),
    ("ring", include_str!("../worlds/ring.toml")),
    ("junction", include_str!("../worlds/junction.toml")),
    ("grid", include_str!("../worlds/grid.toml")),
    ("open", include_str!("../worlds/open.toml")),
];

/// Names accepted by [`preset`]: `oval`, `push`, `ring`, `junction`, `grid`, `open`.
pub fn preset_names() -> &'static [&'static str] {
    &["oval", "push", "ring", "junction", "grid", "open"]
}

/// The TOML text of preset `name`, to show or to copy as a starting point.
pub fn preset_text(name: &str) -> Option<&'static str> {
    PRESETS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, text)| *text)
}

/// The built-in world `name`, or `None` for an unknown name.
pub fn preset(name: &str) -> Option<World> {
    let text = preset_text(name)?;
    // The files are checked by this module's tests, so a parse failure cannot reach a user.
    parse(text, &format!("worlds/{name}.toml")).ok()
}

/// Number of edges of a lattice of `cols` × `rows` nodes.
pub fn grid_edge_count(cols: usize, rows: usize) -> usize {
    cols.saturating_sub(1) * rows + cols * rows.saturating_sub(1)
}

/// [`grid`] exactly as asked, for a request from a user: refused instead of clamped or grown.
///
/// # Errors
/// A side outside 2..=[`GRID_MAX_SIDE`], no robots, more than [`crate::MAX_ROBOTS`], or more robots
/// than the lattice has edges (one robot per edge at most), saying which.
pub fn grid_exact(cols: usize, rows: usize, robots: usize) -> Result<World, String> {
    for (side, n) in [("columns", cols), ("rows", rows)] {
        if !(2..=GRID_MAX_SIDE).contains(&n) {
            return Err(format!("{n} {side}: expected 2 to {GRID_MAX_SIDE}"));
        }
    }
    let places = grid_edge_count(cols, rows);
    if robots == 0 {
        return Err("no robots: expected at least 1".into());
    }
    if robots > crate::MAX_ROBOTS {
        return Err(format!(
            "{robots} robots: at most {} are allowed",
            crate::MAX_ROBOTS
        ));
    }
    if robots > places {
        return Err(format!(
            "{robots} robots do not fit on a {cols}x{rows} lattice ({} nodes, room for {places} \
             robots, one per edge)",
            cols * rows
        ));
    }
    Ok(grid(cols, rows, robots))
}

/// A warehouse lattice of `cols` × `rows` nodes [`GRID_SPACING_M`] apart, joined by straight
/// edges along rows and columns, with `robots` robots (ids 1, 2, …) standing at edge middles
/// heading from `from` to `to`, spread evenly over the edges, at most one per edge.
///
/// Node `cCrR` (column C, row R) is at (0.2 + 0.2·C, 0.2 + 0.2·R); edges are listed per node in
/// row-major order, east edge first, then north. Each side is clamped to 2..=[`GRID_MAX_SIDE`]
/// and `robots` to 65,535 (robot ids are u16); when the robots do not fit one per edge the
/// lattice grows, the shorter side first. So `grid(0, 0, 1000)` gives the smallest square-ish
/// lattice for 1000 robots (23 × 23 nodes, 1012 edges).
pub fn grid(cols: usize, rows: usize, robots: usize) -> World {
    let robots = robots.min(usize::from(u16::MAX));
    let mut cols = cols.clamp(2, GRID_MAX_SIDE);
    let mut rows = rows.clamp(2, GRID_MAX_SIDE);
    while grid_edge_count(cols, rows) < robots {
        if cols <= rows {
            cols += 1;
        } else {
            rows += 1;
        }
    }

    let at = |c: usize, r: usize| {
        Point2::new(
            GRID_MARGIN_M + GRID_SPACING_M * c as f64,
            GRID_MARGIN_M + GRID_SPACING_M * r as f64,
        )
    };
    let id = |c: usize, r: usize| format!("c{c}r{r}");
    let mut nodes = Vec::with_capacity(cols * rows);
    let mut ends = Vec::with_capacity(grid_edge_count(cols, rows));
    let mut edges = Vec::with_capacity(grid_edge_count(cols, rows));
    for r in 0..rows {
        for c in 0..cols {
            let p = at(c, r);
            nodes.push(Node::new(id(c, r), p.x, p.y));
            if c + 1 < cols {
                edges.push(EdgeSpec::straight(id(c, r), id(c + 1, r)));
                ends.push((p, at(c + 1, r)));
            }
            if r + 1 < rows {
                edges.push(EdgeSpec::straight(id(c, r), id(c, r + 1)));
                ends.push((p, at(c, r + 1)));
            }
        }
    }
    // Ids are unique and every edge spans 0.2 m, so the track cannot be refused; an empty track
    // (never expected) is safer than a panic in a generator.
    let track = Track::new(nodes, edges).unwrap_or_default();

    let total = ends.len();
    let robots = (0..robots)
        .filter_map(|i| {
            // Distinct for robots ≤ total, since total / robots ≥ 1.
            let (a, b) = ends.get(i * total / robots.max(1))?;
            let along = b - a;
            Some(RobotStart {
                id: u16::try_from(i + 1).ok()?,
                position: nalgebra::center(a, b),
                heading_rad: along.y.atan2(along.x),
            })
        })
        .collect();
    generated(
        "grid",
        format!(
            "Warehouse lattice of {cols} x {rows} nodes {GRID_SPACING_M} m apart, \
             one robot per edge at most."
        ),
        format!("grid({cols}, {rows})"),
        Arena {
            width_m: 2.0 * GRID_MARGIN_M + GRID_SPACING_M * (cols - 1) as f64,
            height_m: 2.0 * GRID_MARGIN_M + GRID_SPACING_M * (rows - 1) as f64,
        },
        track,
        robots,
    )
}

/// A generated world: no boxes, the default radio and light, seed 1.
fn generated(
    name: &str,
    description: String,
    origin: String,
    arena: Arena,
    track: Track,
    robots: Vec<RobotStart>,
) -> World {
    World {
        name: name.to_owned(),
        description,
        origin,
        arena,
        track,
        obstacles: Vec::new(),
        robots,
        link: RadioModel::default(),
        light: Light::default(),
        seed: Some(1),
        faults: Vec::new(),
    }
}

/// Distance between neighbouring lanes of a [`serpentine`], in metres: its U-turns have half
/// this radius, as gentle as the `oval`'s bends.
pub const SERPENTINE_LANE_M: f64 = 0.6;

/// Tape per robot on a [`serpentine`], in metres: room to follow at cruising speed.
pub const SERPENTINE_PER_ROBOT_M: f64 = 0.25;

/// A single closed loop of tape for `robots` line followers (ids 1, 2, …): an even number of
/// straight lanes [`SERPENTINE_LANE_M`] apart, joined by U-turns at alternate ends, and a return
/// lane beside them, about square and with at least [`SERPENTINE_PER_ROBOT_M`] of tape per robot.
/// The robots stand on the lanes, evenly spread, heading along the loop. `robots` is clamped to
/// 1..=65,535.
pub fn serpentine(robots: usize) -> World {
    let robots = robots.clamp(1, usize::from(u16::MAX));
    let count = robots;
    let lane_gap = SERPENTINE_LANE_M;
    let turn = lane_gap * 2.0;
    let tape = robots as f64 * SERPENTINE_PER_ROBOT_M;
    // About square: lanes × gap ≈ lane length, and lanes × length ≈ the tape needed.
    // Six lanes at least leave the return lane room for its two quarter turns.
    let mut lanes = ((tape / lane_gap).sqrt().ceil() as usize).max(6);
    lanes += lanes % 2;
    let length = (tape / lanes as f64).max(1.0);
    let margin = 0.3;
    let x0 = margin + turn;
    let x1 = x0 + length;
    let y = |k: usize| margin + lane_gap / 2.0 + lane_gap * k as f64;
    let top = y(lanes - 1);
    let mut nodes = Vec::new();
    let mut edges = Vec::new();
    for k in 0..lanes {
        nodes.push(Node::new(format!("w{k}"), x0, y(k)));
        nodes.push(Node::new(format!("e{k}"), x1, y(k)));
        // Even lanes run east, odd lanes west; each U-turn turns towards the next lane up.
        let (from, to) = if k % 2 == 0 { ("w", "e") } else { ("e", "w") };
        edges.push(EdgeSpec::straight(format!("{from}{k}"), format!("{to}{k}")));
        if k + 1 < lanes {
            let sweep = if k % 2 == 0 { 180.0 } else { -180.0 };
            edges.push(EdgeSpec::arc(
                format!("{to}{k}"),
                format!("{to}{}", k + 1),
                sweep,
            ));
        }
    }
    // The last lane ends west, heading west: turn left twice around the U-turns' outside and
    // come back down to the first lane's start.
    nodes.push(Node::new("rt", x0 - turn, top - turn));
    nodes.push(Node::new("rb", x0 - turn, y(0) + turn));
    edges.push(EdgeSpec::arc(format!("w{}", lanes - 1), "rt", 90.0));
    edges.push(EdgeSpec::straight("rt", "rb"));
    edges.push(EdgeSpec::arc("rb", "w0", 90.0));
    // Every node is placed apart and each arc's chord fits its sweep, so the track cannot be
    // refused; an empty track (never expected) is safer than a panic in a generator.
    let track = Track::new(nodes, edges).unwrap_or_default();

    let per_lane = robots.div_ceil(lanes);
    let robots = (0..robots)
        .filter_map(|i| {
            let (k, slot) = (i / per_lane, i % per_lane);
            let along = length * (slot as f64 + 0.5) / per_lane as f64;
            let (x, heading) = if k % 2 == 0 {
                (x0 + along, 0.0)
            } else {
                (x1 - along, std::f64::consts::PI)
            };
            Some(RobotStart {
                id: u16::try_from(i + 1).ok()?,
                position: Point2::new(x, y(k)),
                heading_rad: heading,
            })
        })
        .collect();
    generated(
        "serpentine",
        format!(
            "One closed loop of {lanes} lanes {length:.2} m long, {lane_gap} m apart, for line \
             following at scale."
        ),
        format!("serpentine({count})"),
        Arena {
            width_m: x1 + turn / 2.0 + margin,
            height_m: top + lane_gap / 2.0 + margin,
        },
        track,
        robots,
    )
}

#[cfg(test)]
mod tests {
    use std::collections::HashSet;
    use std::f64::consts::PI;

    use super::*;
    #[cfg(feature = "graph")]
    use crate::graph::{NodeKind, TrackGraph};
    use crate::track::Surface;
    use crate::{robot, GRAVITY_MPS2};
    use nalgebra::Vector2;

    fn load(name: &str) -> World {
        let text = preset_text(name).expect("known preset");
        parse(text, name).unwrap_or_else(|e| panic!("{e}"))
    }

    /// Every robot stands on a tape centre line (within 1 mm), heading along it, inside the
    /// arena; with `one_per_edge`, no two share an edge.
    fn assert_robots_on_tape(w: &World, one_per_edge: bool) {
        let mut edges = HashSet::new();
        for r in &w.robots {
            let np = w.track.nearest(r.position).expect("track has edges");
            assert!(
                np.distance_m < 1e-3,
                "{}: robot {} is {} m off",
                w.name,
                r.id,
                np.distance_m
            );
            let heading = nalgebra::Vector2::new(r.heading_rad.cos(), r.heading_rad.sin());
            assert!(
                heading.dot(&np.tangent) > 0.999,
                "{}: robot {} not along tape",
                w.name,
                r.id
            );
            assert!(
                w.arena.contains(r.position, robot::RADIUS_M),
                "{}: robot {}",
                w.name,
                r.id
            );
            assert!(w.track.floor_at(r.position).ir_reflectance < 0.5);
            let first_on_edge = edges.insert(np.edge);
            assert!(
                first_on_edge || !one_per_edge,
                "{}: two robots on edge {}",
                w.name,
                np.edge
            );
        }
    }

    #[test]
    fn every_preset_parses_validates_and_has_robots_on_tape() {
        for name in preset_names() {
            let w = load(name);
            assert_eq!(w.name, *name);
            assert!(preset(name).is_some(), "{name}");
            w.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(!w.robots.is_empty(), "{name}");
            // `open` is free floor: its robots stand off the tape on purpose.
            if *name != "open" {
                assert_robots_on_tape(&w, *name != "push");
            }
        }
        assert!(preset("nope").is_none());
        assert_eq!(preset_names().len(), PRESETS.len());
    }

    #[test]
    #[cfg(feature = "graph")]
    fn a_serpentine_is_one_closed_loop_with_room_for_its_robots() {
        for n in [1, 10, 500, 1000] {
            let w = serpentine(n);
            assert_eq!(w.robots.len(), n);
            let g = TrackGraph::new(&w.track);
            assert!(g.graph.node_count() > 0, "{n}: the track was refused");
            assert!(
                g.graph.node_weights().all(|n| n.kind == NodeKind::Waypoint),
                "{n}: not a single loop"
            );
            let length: f64 = (0..w.track.edges().len())
                .map(|e| w.track.edge_length(e))
                .sum();
            assert!(
                length >= n as f64 * SERPENTINE_PER_ROBOT_M,
                "{n} robots on {length} m"
            );
            assert_robots_on_tape(&w, false);
            // Neighbours on a lane stand a body length and a stopping gap apart at least.
            for (a, b) in w.robots.iter().zip(w.robots.iter().skip(1)) {
                let d = (a.position - b.position).norm();
                assert!(d > 0.15, "robots {} and {} are {d} m apart", a.id, b.id);
            }
        }
    }

    #[test]
    #[cfg(feature = "graph")]
    fn oval_is_one_closed_loop_of_the_stated_size() {
        let w = load("oval");
        assert_eq!((w.arena.width_m, w.arena.height_m), (1.0, 0.6));
        let g = TrackGraph::new(&w.track);
        assert!(g.graph.node_weights().all(|n| n.kind == NodeKind::Waypoint));
        let length: f64 = (0..w.track.edges().len())
            .map(|e| w.track.edge_length(e))
            .sum();
        // The red arc's end nodes are rounded to a micrometre.
        assert!((length - (1.0 + 2.0 * PI * 0.15)).abs() < 1e-5, "{length}");
        assert_eq!(w.track.floor_at(Point2::new(0.5, 0.15)), Surface::BLUE);
        assert_eq!(w.track.floor_at(Point2::new(0.1, 0.3)), Surface::RED);
        assert_eq!(w.track.floor_at(Point2::new(0.9, 0.3)), Surface::BLACK);
        assert_eq!(w.track.floor_at(Point2::new(0.5, 0.3)), Surface::WHITE);
        assert_eq!(w.robots.len(), 2);
    }

    #[test]
    fn push_box_lies_on_the_tape_ahead_of_both_robots() {
        let w = load("push");
        let [b] = w.obstacles.as_slice() else {
            panic!("one box expected");
        };
        let np = w.track.nearest(b.position).expect("track");
        assert!(np.distance_m < 1e-3);
        assert_eq!(
            (b.width_m, b.height_m, b.mass_kg, b.friction),
            (0.04, 0.04, 0.06, 0.5)
        );
        // Too heavy for one 20 g robot (μ 0.8), light enough for two.
        let one_robot_n = 0.8 * 0.02 * GRAVITY_MPS2;
        assert!(b.floor_friction_n() > one_robot_n && b.floor_friction_n() < 2.0 * one_robot_n);
        let [r1, r2] = w.robots.as_slice() else {
            panic!("two robots expected");
        };
        for r in [r1, r2] {
            assert!((r.position.y - b.position.y).abs() < 1e-9, "same straight");
            assert!(
                r.position.x < b.position.x && r.heading_rad == 0.0,
                "behind, facing it"
            );
        }
        assert!(((r1.position - r2.position).norm() - 0.15).abs() < 1e-9);
    }

    #[test]
    #[cfg(feature = "graph")]
    fn junction_has_fork_merge_siding_and_single_lane_stem() {
        let w = load("junction");
        assert_eq!((w.arena.width_m, w.arena.height_m), (1.6, 1.0));
        assert_eq!(w.robots.len(), 8);
        let g = TrackGraph::new(&w.track);
        let kind = |id| g.node(id).and_then(|n| g.node_weight(n)).map(|n| n.kind);
        for id in ["F", "M", "T", "Y"] {
            assert_eq!(kind(id), Some(NodeKind::Junction), "{id}");
        }
        // The fork point itself is dark, as are points just past it on both branches.
        for p in [(0.45, 0.15), (0.47, 0.15), (0.47, 0.1513)] {
            assert_eq!(
                w.track.floor_at(Point2::new(p.0, p.1)),
                Surface::BLACK,
                "{p:?}"
            );
        }
        // Far corners: the east end of the main line to the top of the upper loop, which is
        // only reachable over the single-lane stem T–Y.
        let route = g.shortest_path("B", "U4").expect("connected");
        let stem = w
            .track
            .edges()
            .iter()
            .position(|e| {
                let ids = [&w.track.nodes()[e.from].id, &w.track.nodes()[e.to].id];
                ids == [&"T".to_owned(), &"Y".to_owned()]
            })
            .expect("stem edge");
        assert!(route.edges.contains(&stem));
        assert!(
            route.length_m > 0.8 && route.length_m < 2.0,
            "{}",
            route.length_m
        );
        // Siding and main line join the same fork and merge.
        let main = g.shortest_path("F", "M").expect("connected");
        assert!(
            (main.length_m - 0.7).abs() < 1e-9,
            "main line is the shorter way"
        );
    }

    #[test]
    fn grid_preset_is_what_the_generator_makes() {
        let file = load("grid");
        let made = grid(10, 6, 12);
        let (a, b) = (&file.track, &made.track);
        assert_eq!(a.nodes().len(), 60);
        assert_eq!(a.nodes().len(), b.nodes().len());
        for (x, y) in a.nodes().iter().zip(b.nodes()) {
            assert_eq!(x.id, y.id);
            assert!((x.position - y.position).norm() < 1e-9);
        }
        assert_eq!(a.edges().len(), b.edges().len());
        for (x, y) in a.edges().iter().zip(b.edges()) {
            assert_eq!((x.from, x.to), (y.from, y.to));
        }
        assert_eq!(file.robots.len(), made.robots.len());
        for (x, y) in file.robots.iter().zip(&made.robots) {
            assert_eq!(x.id, y.id);
            assert!((x.position - y.position).norm() < 1e-9);
            assert!((x.heading_rad - y.heading_rad).abs() < 1e-9);
        }
        assert_eq!((file.arena.width_m, file.arena.height_m), (2.2, 1.4));
        assert!(
            (made.arena.width_m - 2.2).abs() < 1e-9 && (made.arena.height_m - 1.4).abs() < 1e-9
        );
    }

    #[test]
    fn grid_of_1000_robots_puts_each_on_its_own_edge() {
        let w = grid(0, 0, 1000);
        assert_eq!(w.robots.len(), 1000);
        let ids: HashSet<u16> = w.robots.iter().map(|r| r.id).collect();
        assert_eq!(ids.len(), 1000);
        assert!(w.track.edges().len() >= 1000);
        w.validate().unwrap_or_else(|e| panic!("{e}"));
        assert_robots_on_tape(&w, true);
        // Asked for too small a lattice, it grows.
        let w = grid(3, 3, 50);
        assert_eq!(w.robots.len(), 50);
        assert!(w.track.edges().len() >= 50);
    }

    #[test]
    fn a_line_sensors_spots_read_together_see_what_each_alone_sees() {
        // Sensors all over the junction's curves and crossings and a grid's tapes, at every
        // heading, including spots that straddle index cells and leave the arena.
        for w in [preset("junction").unwrap(), grid(0, 0, 10)] {
            let mut differ = 0;
            let mut dark = 0;
            for i in 0..20_000u32 {
                let x = f64::from(i % 173) / 173.0 * w.arena.width_m * 1.1 - 0.02;
                let y = f64::from(i % 211) / 211.0 * w.arena.height_m * 1.1 - 0.02;
                let (s, c) = (f64::from(i) * 0.37).sin_cos();
                let spots: [Point2<f64>; 8] = std::array::from_fn(|k| {
                    let lateral = (k as f64 - 3.5) * 0.003;
                    Point2::new(x + lateral * s, y - lateral * c)
                });
                let together = w.track.floor_at_each(&spots);
                for (p, t) in spots.iter().zip(together) {
                    differ += usize::from(w.track.floor_at(*p) != t);
                    dark += usize::from(t.ir_reflectance < 0.5);
                }
            }
            assert_eq!(differ, 0);
            assert!(
                dark > 1000,
                "the sample must cross tapes: {dark} dark spots"
            );
        }
    }

    #[test]
    fn the_floor_is_the_same_everywhere_within_the_radius_a_query_gives() {
        // Points all over curves, crossings, marks and the grid's edges, and off the tape's box;
        // for each, points near the radius's rim in many directions.
        for w in [
            preset("junction").unwrap(),
            preset("oval").unwrap(),
            grid(0, 0, 10),
        ] {
            let (mut checked, mut near_tape, mut reach) = (0usize, 0usize, 0.0);
            for i in 0..20_000u32 {
                let x = f64::from(i % 173) / 173.0 * w.arena.width_m * 1.1 - 0.02;
                let y = f64::from(i % 211) / 211.0 * w.arena.height_m * 1.1 - 0.02;
                let p = Point2::new(x, y);
                let (surface, radius) = w.track.floor_at_within(p);
                assert_eq!(surface, w.track.floor_at(p));
                assert!(radius >= 0.0, "{radius} at {p:?}");
                if let Some(np) = w.track.nearest(p) {
                    if np.distance_m < 0.01 {
                        near_tape += 1;
                        reach += radius;
                    }
                }
                for k in 0..16 {
                    let (s, c) = (f64::from(k) * 0.39 + f64::from(i)).sin_cos();
                    for f in [0.999, 0.5] {
                        let q = p + Vector2::new(c, s) * radius * f;
                        assert_eq!(w.track.floor_at(q), surface, "{q:?}: {p:?} ± {radius}");
                        checked += 1;
                    }
                }
            }
            assert!(checked > 100_000);
            // Within a centimetre of a tape, where a line sensor's spots are, a look still
            // holds for a millimetre on average: several of the spots' 0.3 mm moves between
            // samples at a line follower's speed.
            assert!(
                reach / near_tape as f64 > 0.001,
                "{near_tape} near the tape, mean radius {} m",
                reach / near_tape as f64
            );
        }
    }

    #[test]
    fn grid_floor_queries_look_at_one_cell_and_few_edges() {
        let w = grid(0, 0, 1000);
        let stats = w.track.index_stats();
        assert!(stats.max_edges_per_cell <= 4, "{stats:?}");
        let (mut queries, mut tested, mut worst) = (0usize, 0usize, 0usize);
        let mut x = 0.0;
        while x < w.arena.width_m {
            let mut y = 0.0;
            while y < w.arena.height_m {
                let (_, cost) = w.track.floor_at_counted(Point2::new(x, y));
                assert!(cost.cells_visited <= 1);
                queries += 1;
                tested += cost.edges_tested;
                worst = worst.max(cost.edges_tested);
                y += 0.0037;
            }
            x += 0.0041;
        }
        assert!(worst <= 4, "{worst}");
        // Tapes on multiples of the cell size sit mid-cell, so each 0.2 m line claims one of
        // every four columns (or rows) of 0.05 m cells: about 2 × 1/4 exact tests per query.
        // An index whose tapes straddled cell borders would need about twice that.
        assert!(
            (tested as f64) < 0.6 * queries as f64,
            "{tested} tests in {queries} queries"
        );
    }

    #[test]
    fn grid_exact_refuses_what_grid_would_clamp_or_grow() {
        let w = grid_exact(2, 2, 4).expect("4 robots on 4 edges");
        assert_eq!((w.robots.len(), w.track.edges().len()), (4, 4));
        let e = grid_exact(2, 2, 50).unwrap_err();
        assert!(e.contains("50 robots do not fit on a 2x2 lattice"), "{e}");
        assert!(e.contains("4 nodes, room for 4 robots"), "{e}");
        assert!(grid_exact(2, 2, 0).unwrap_err().contains("no robots"));
        assert!(grid_exact(1, 5, 1).unwrap_err().contains("1 columns"));
        assert!(grid_exact(5, GRID_MAX_SIDE + 1, 1)
            .unwrap_err()
            .contains("rows"));
        let e = grid_exact(GRID_MAX_SIDE, GRID_MAX_SIDE, 70_000).unwrap_err();
        assert!(e.contains("at most 2000"), "{e}");
        let e = grid_exact(GRID_MAX_SIDE, GRID_MAX_SIDE, crate::MAX_ROBOTS + 1).unwrap_err();
        assert!(e.contains("2001 robots: at most 2000"), "{e}");
        assert!(grid_exact(64, 32, 1000).is_ok());
    }

    #[test]
    fn grid_clamps_absurd_requests() {
        let w = grid(usize::MAX, 1, usize::MAX);
        assert_eq!(w.robots.len(), usize::from(u16::MAX));
        assert!(w.track.nodes().len() <= GRID_MAX_SIDE * GRID_MAX_SIDE);
        let w = grid(2, 2, 0);
        assert!(w.robots.is_empty());
        assert_eq!(w.track.edges().len(), 4);
    }
}
