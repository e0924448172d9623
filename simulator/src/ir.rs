//! Infrared light between robots (thesis ch. 7): directed LEDs with ±15° cones and power-dependent
//! reach, wide-angle front and rear receivers, line of sight, and reflections off anything in the
//! cone (walls, boxes, other robots) back to the sender's own receiver.
//!
//! Geometry is analytic (rays against oriented boxes) over a uniform grid of robots, so each
//! transmission looks only at robots within reach.

use firmware::hal::Side;

/// An oriented rectangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Obb {
    /// Centre, metres.
    pub center: [f64; 2],
    /// Half length along the heading and half width, metres.
    pub half: [f64; 2],
    /// Sine and cosine of the heading, computed once (a beam is traced without the angle).
    sin_cos: (f64, f64),
    /// Radius of the circle through the corners, a little widened against rounding.
    reach: f64,
}

impl Obb {
    /// A box centred at `center` with half extents `half`, turned by `angle`.
    pub fn new(center: [f64; 2], half: [f64; 2], angle: f64) -> Self {
        Self {
            center,
            half,
            sin_cos: angle.sin_cos(),
            reach: (half[0] * half[0] + half[1] * half[1]).sqrt() * (1.0 + 1e-9),
        }
    }

    /// Distance along the unit ray `dir` from `origin` to where it enters this box, if it does
    /// within `max`; a ray starting inside reports 0.
    pub fn ray(&self, origin: [f64; 2], dir: [f64; 2], max: f64) -> Option<f64> {
        let rel = [origin[0] - self.center[0], origin[1] - self.center[1]];
        // Most rays pass well clear of a box: rejected against the circle through its corners,
        // without the slab test's divisions. Along the ray the centre lies at `-along`.
        let along = -(rel[0] * dir[0] + rel[1] * dir[1]);
        if along < -self.reach || along > max + self.reach {
            return None;
        }
        let across2 = rel[0] * rel[0] + rel[1] * rel[1] - along * along;
        if across2 > self.reach * self.reach {
            return None;
        }
        let (s, c) = self.sin_cos;
        // Into the box frame.
        let o = [rel[0] * c + rel[1] * s, -rel[0] * s + rel[1] * c];
        let d = [dir[0] * c + dir[1] * s, -dir[0] * s + dir[1] * c];
        let mut t0 = 0.0f64;
        let mut t1 = max;
        for a in 0..2 {
            if d[a].abs() < 1e-12 {
                if o[a].abs() > self.half[a] {
                    return None;
                }
            } else {
                let inv = 1.0 / d[a];
                let (mut near, mut far) =
                    ((-self.half[a] - o[a]) * inv, (self.half[a] - o[a]) * inv);
                if near > far {
                    std::mem::swap(&mut near, &mut far);
                }
                t0 = t0.max(near);
                t1 = t1.min(far);
                if t0 > t1 {
                    return None;
                }
            }
        }
        Some(t0)
    }

    /// A point at `forward` metres along the heading from the centre.
    pub fn ahead(&self, forward: f64) -> [f64; 2] {
        let (s, c) = self.sin_cos;
        [self.center[0] + forward * c, self.center[1] + forward * s]
    }
}

/// Robot indices bucketed by position, rebuilt each step.
#[derive(Clone, Debug, Default)]
pub struct Grid {
    cell: f64,
    cols: usize,
    rows: usize,
    cells: Vec<Vec<u32>>,
}

impl Grid {
    /// Buckets `centers` into cells of `cell` metres covering `[0, w] × [0, h]`.
    pub fn rebuild(&mut self, w: f64, h: f64, cell: f64, centers: impl Iterator<Item = [f64; 2]>) {
        self.cell = cell.max(1e-3);
        self.cols = ((w / self.cell).ceil() as usize).max(1);
        self.rows = ((h / self.cell).ceil() as usize).max(1);
        self.cells.resize_with(self.cols * self.rows, Vec::new);
        for c in &mut self.cells {
            c.clear();
        }
        for (i, p) in centers.enumerate() {
            let k = self.index(p);
            self.cells[k].push(i as u32);
        }
    }

    fn clamp_cell(&self, p: [f64; 2]) -> (usize, usize) {
        let cx = ((p[0] / self.cell).floor().max(0.0) as usize).min(self.cols - 1);
        let cy = ((p[1] / self.cell).floor().max(0.0) as usize).min(self.rows - 1);
        (cx, cy)
    }

    fn index(&self, p: [f64; 2]) -> usize {
        let (cx, cy) = self.clamp_cell(p);
        cy * self.cols + cx
    }

    /// Calls `f` with every robot bucketed within `radius` of `p` (a superset, in index order).
    pub fn near(&self, p: [f64; 2], radius: f64, mut f: impl FnMut(usize)) {
        if self.cells.is_empty() {
            return;
        }
        let (x0, y0) = self.clamp_cell([p[0] - radius, p[1] - radius]);
        let (x1, y1) = self.clamp_cell([p[0] + radius, p[1] + radius]);
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                for &i in &self.cells[cy * self.cols + cx] {
                    f(i as usize);
                }
            }
        }
    }
}

/// What the world looks like to IR light.
pub struct Scene<'a> {
    /// Every robot's body.
    pub robots: &'a [Obb],
    /// Every box.
    pub obstacles: &'a [Obb],
    /// Arena size; walls stand on its border.
    pub arena: [f64; 2],
    /// Robots bucketed by position.
    pub grid: &'a Grid,
}

/// One transmission: which LED of which robot, and how far its power level reaches.
///
/// Angles are kept as unit vectors `[cos, sin]`: a beam is traced with products and square roots
/// only, since a thousand robots send a quarter of a million beams per simulated second.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Beam {
    /// Transmitting robot.
    pub robot: usize,
    /// LED direction relative to the robot's heading, `[cos, sin]`.
    pub led: [f64; 2],
    /// Reach at this power level, metres.
    pub range: f64,
    /// Half-angle of the LED's cone, `[cos, sin]` (at most a right angle).
    pub cone_half: [f64; 2],
}

impl Beam {
    /// A beam from `robot`'s LED at `led_angle` (radians from its heading) with a cone of
    /// `cone_half` radians each side.
    pub fn new(robot: usize, led_angle: f64, range: f64, cone_half: f64) -> Self {
        let (ls, lc) = led_angle.sin_cos();
        let (cs, cc) = cone_half.sin_cos();
        Self {
            robot,
            led: [lc, ls],
            range,
            cone_half: [cc, cs],
        }
    }
}

/// Where a beam's frame arrives.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Arrivals {
    /// Other robots' receivers that got the frame.
    pub robots: Vec<(usize, Side)>,
    /// The sender's own receiver that got its reflection, if any.
    pub reflection: Option<Side>,
}

/// Cosine of the widest angle off their axis at which receivers accept light (80°: wide-angle
/// remote-control receivers).
const RECEIVER_COS_HALF_ANGLE: f64 = 0.173_648_177_666_930_4;
/// Its square.
const RECEIVER_COS_HALF_ANGLE_2: f64 = RECEIVER_COS_HALF_ANGLE * RECEIVER_COS_HALF_ANGLE;
/// Receiver aperture radius, widening the cone test for near receivers.
const RECEIVER_RADIUS: f64 = 0.003;
/// Its square.
const RECEIVER_RADIUS_2: f64 = RECEIVER_RADIUS * RECEIVER_RADIUS;

/// `a` turned by the angle whose `[cos, sin]` is `by`.
fn turned(a: [f64; 2], by: [f64; 2]) -> [f64; 2] {
    [a[0] * by[0] - a[1] * by[1], a[0] * by[1] + a[1] * by[0]]
}

/// Follows one beam through the scene.
pub fn propagate(scene: &Scene<'_>, beam: &Beam) -> Arrivals {
    let me = &scene.robots[beam.robot];
    let front = beam.led[0] >= 0.0;
    let origin = me.ahead(if front { me.half[0] } else { -me.half[0] });
    let dir = turned([me.sin_cos.1, me.sin_cos.0], beam.led);
    let [cone_cos, cone_sin] = beam.cone_half;
    let mut out = Arrivals::default();

    // Every robot the beam can reach, block or bounce off has a part of its body within reach of
    // the LED: gathered once, in the grid's order, for every test below. Centres are taken up to
    // 5 cm past the reach, well past a PocketBot2's half-diagonal (2.9 cm).
    let mut near = Vec::with_capacity(16);
    let reach = beam.range + 0.05;
    scene.grid.near(origin, reach, |j| {
        let c = scene.robots[j].center;
        let (dx, dy) = (c[0] - origin[0], c[1] - origin[1]);
        if j != beam.robot && dx * dx + dy * dy <= reach * reach {
            near.push(j as u32);
        }
    });

    for &j in &near {
        let j = j as usize;
        let other = &scene.robots[j];
        for (side, sign) in [(Side::Front, 1.0), (Side::Rear, -1.0)] {
            let rx = other.ahead(sign * other.half[0]);
            let v = [rx[0] - origin[0], rx[1] - origin[1]];
            // Most receivers near the LED are out of reach: reject them before the root.
            let d2 = v[0] * v[0] + v[1] * v[1];
            if d2 > beam.range * beam.range || d2 < 1e-18 {
                continue;
            }
            // Tests without roots or divisions first, as squares of non-negative sides: the
            // receiver must face the LED, and a receiver behind the LED is outside its cone
            // unless the aperture widens the cone past a right angle (within a millimetre).
            let facing = [sign * other.sin_cos.1, sign * other.sin_cos.0];
            let towards = -(facing[0] * v[0] + facing[1] * v[1]);
            if towards < 0.0 || towards * towards < RECEIVER_COS_HALF_ANGLE_2 * d2 {
                continue;
            }
            let ahead = dir[0] * v[0] + dir[1] * v[1];
            if ahead <= 0.0 && cone_cos * cone_cos * d2 > RECEIVER_RADIUS_2 * cone_sin * cone_sin {
                continue;
            }
            let d = d2.sqrt();
            // Inside the cone widened by the aperture's angle atan(r/d): compared as cosines,
            // cos(half + atan x) = (cos half - x sin half) / sqrt(1 + x²), both angles in [0, π].
            let x = RECEIVER_RADIUS / d;
            let widened_cos = (cone_cos - x * cone_sin) / (1.0 + x * x).sqrt();
            if ahead < widened_cos * d {
                continue;
            }
            let unit = [v[0] / d, v[1] / d];
            if blocked(scene, &near, origin, unit, d - 1e-4, j) {
                continue;
            }
            out.robots.push((j, side));
        }
    }

    // Reflection: the nearest surface on the axis or the rays half-way to the cone's edges,
    // there and back. The half angle's cosine and sine follow from the cone's.
    let half = [
        ((1.0 + cone_cos) * 0.5).sqrt(),
        ((1.0 - cone_cos) * 0.5).sqrt(),
    ];
    let mut nearest = f64::INFINITY;
    for d in [dir, turned(dir, [half[0], -half[1]]), turned(dir, half)] {
        if let Some(h) = first_hit(scene, &near, origin, d, beam.range * 0.5) {
            nearest = nearest.min(h);
        }
    }
    if 2.0 * nearest <= beam.range {
        out.reflection = Some(if front { Side::Front } else { Side::Rear });
    }
    out
}

/// Whether a box or a robot of `near` other than the receiver `to` stands on the ray within
/// `dist`.
fn blocked(
    scene: &Scene<'_>,
    near: &[u32],
    origin: [f64; 2],
    dir: [f64; 2],
    dist: f64,
    to: usize,
) -> bool {
    scene
        .obstacles
        .iter()
        .any(|o| o.ray(origin, dir, dist).is_some())
        || near
            .iter()
            .any(|&k| k as usize != to && scene.robots[k as usize].ray(origin, dir, dist).is_some())
}

/// Distance to the first wall, box or robot of `near` along the ray, if within `max`.
fn first_hit(
    scene: &Scene<'_>,
    near: &[u32],
    origin: [f64; 2],
    dir: [f64; 2],
    max: f64,
) -> Option<f64> {
    let mut best = wall_distance(scene.arena, origin, dir).filter(|&d| d <= max);
    let mut take = |h: Option<f64>| {
        if let Some(h) = h {
            if best.is_none_or(|b| h < b) {
                best = Some(h);
            }
        }
    };
    for o in scene.obstacles {
        take(o.ray(origin, dir, max));
    }
    for &k in near {
        take(scene.robots[k as usize].ray(origin, dir, max));
    }
    best
}

/// Distance from a point inside the arena to its border along `dir`.
fn wall_distance(arena: [f64; 2], p: [f64; 2], dir: [f64; 2]) -> Option<f64> {
    let mut t = f64::INFINITY;
    for a in 0..2 {
        if dir[a] > 1e-12 {
            t = t.min((arena[a] - p[a]) / dir[a]);
        } else if dir[a] < -1e-12 {
            t = t.min(-p[a] / dir[a]);
        }
    }
    (t.is_finite() && t >= 0.0).then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn robot(x: f64, y: f64, deg: f64) -> Obb {
        Obb::new(
            [x, y],
            [world::robot::LENGTH_M / 2.0, world::robot::WIDTH_M / 2.0],
            deg.to_radians(),
        )
    }

    fn run(robots: &[Obb], obstacles: &[Obb], beam: Beam) -> Arrivals {
        let mut grid = Grid::default();
        grid.rebuild(1.0, 1.0, 0.16, robots.iter().map(|r| r.center));
        let scene = Scene {
            robots,
            obstacles,
            arena: [1.0, 1.0],
            grid: &grid,
        };
        propagate(&scene, &beam)
    }

    fn beam(robot: usize, led_deg: f64, range: f64) -> Beam {
        Beam::new(robot, led_deg.to_radians(), range, 15f64.to_radians())
    }

    #[test]
    fn ray_enters_an_oriented_box() {
        let b = robot(0.5, 0.5, 90.0);
        let h = b.ray([0.5, 0.3], [0.0, 1.0], 1.0).unwrap();
        assert!((h - (0.2 - 0.024)).abs() < 1e-9);
        assert_eq!(b.ray([0.5, 0.3], [1.0, 0.0], 1.0), None);
    }

    #[test]
    fn robots_facing_each_other_hear_each_other_front_to_front() {
        let robots = [robot(0.4, 0.5, 0.0), robot(0.46, 0.5, 180.0)];
        let a = run(&robots, &[], beam(0, 0.0, 0.03));
        assert_eq!(a.robots, vec![(1, Side::Front)]);
        assert_eq!(
            a.reflection,
            Some(Side::Front),
            "the other body reflects too"
        );
        // A side LED at ±30° misses a receiver straight ahead.
        assert!(run(&robots, &[], beam(0, 30.0, 0.03)).robots.is_empty());
    }

    #[test]
    fn range_limits_reception() {
        let robots = [robot(0.3, 0.5, 0.0), robot(0.45, 0.5, 180.0)];
        assert!(run(&robots, &[], beam(0, 0.0, 0.06)).robots.is_empty());
        assert_eq!(
            run(&robots, &[], beam(0, 0.0, 0.15)).robots,
            vec![(1, Side::Front)]
        );
    }

    #[test]
    fn a_box_between_blocks_the_frame_and_reflects_it() {
        let robots = [robot(0.3, 0.5, 0.0), robot(0.42, 0.5, 180.0)];
        let wall = Obb::new([0.36, 0.5], [0.005, 0.05], 0.0);
        let a = run(&robots, &[wall], beam(0, 0.0, 0.1));
        assert!(a.robots.is_empty());
        assert_eq!(a.reflection, Some(Side::Front));
    }

    #[test]
    fn a_wall_reflects_and_no_robot_is_heard() {
        let robots = [robot(0.97, 0.5, 0.0)];
        let a = run(&robots, &[], beam(0, 0.0, 0.03));
        assert!(a.robots.is_empty());
        assert_eq!(a.reflection, Some(Side::Front));
        let a = run(&robots, &[], beam(0, 180.0, 0.03));
        assert_eq!(a.reflection, None, "nothing behind within reach");
    }

    #[test]
    fn rear_receiver_hears_a_follower() {
        let robots = [robot(0.5, 0.5, 0.0), robot(0.44, 0.5, 0.0)];
        let a = run(&robots, &[], beam(1, 0.0, 0.03));
        assert_eq!(a.robots, vec![(0, Side::Rear)]);
    }
}
