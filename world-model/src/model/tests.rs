use super::*;
use world::presets;

/// A snapshot keeps the world as it was taken; the next one shows every robot that changed
/// since, shares the views of those that did not, and takes in robots added and lost.
#[test]
fn snapshots_follow_every_change_and_keep_their_own_time() {
    let world = presets::grid(4, 4, 1);
    let model = WorldModel::new(Arc::new(world.track.clone()));
    for id in [3, 1, 2] {
        model.add(id);
    }
    let update = |id: u16, x: f64| StateUpdated {
        robot_id: id,
        at: tokio::time::Instant::now(),
        state: protocol::RobotState::default(),
        reduced: false,
        pose: Pose {
            x,
            y: 0.0,
            theta: 0.0,
        },
        rtt: None,
    };
    let ids = |v: &[Arc<RobotView>]| v.iter().map(|r| r.id).collect::<Vec<_>>();
    let first = model.shared_views();
    assert_eq!(ids(&first), [1, 2, 3]);
    model.apply(&update(2, 0.5));
    let second = model.shared_views();
    assert!(!first[1].connected, "the earlier snapshot changed");
    assert!(second[1].connected && second[1].odometry.x == 0.5);
    assert!(Arc::ptr_eq(&first[0], &second[0]) && Arc::ptr_eq(&first[2], &second[2]));
    model.lost(2);
    model.add(0);
    let third = model.shared_views();
    assert_eq!(ids(&third), [0, 1, 2, 3]);
    assert!(!third[2].connected && third[2].odometry.x == 0.5);
    // More changes than robots between two snapshots, as the observer's model has.
    for k in 0..20 {
        model.apply(&update(3, f64::from(k) * 0.01));
    }
    let fourth = model.shared_views();
    assert!(
        (fourth[3].odometry.x - 0.19).abs() < 1e-12,
        "{}",
        fourth[3].odometry.x
    );
    for v in fourth.iter() {
        assert!(
            Arc::ptr_eq(v, &model.robots().get(&v.id).unwrap()),
            "robot {}",
            v.id
        );
    }
}

/// A simulated unicycle following the oval's tape (it steers its sensor onto the tape ahead,
/// weaving a little), its odometry drifting in heading by 2° per metre: the model keeps its
/// pose on the truth, the odometry does not.
#[test]
fn line_sightings_pull_a_drifting_odometry_back_onto_the_tape() {
    let world = presets::preset("oval").unwrap();
    let track = Arc::new(world.track.clone());
    let model = WorldModel::new(Arc::clone(&track));
    model.add(1);
    let (v, dt) = (0.15, 0.02);
    let mut truth = Pose {
        x: 0.35,
        y: 0.15,
        theta: 0.0,
    };
    let mut odo = truth;
    let (mut worst_lateral, mut worst_heading) = (0.0f64, 0.0f64);
    for k in 0..4000 {
        let heading = Vector2::new(truth.theta.cos(), truth.theta.sin());
        let sensor = Point2::new(truth.x, truth.y) + heading * LINE_SENSOR_AHEAD_M;
        let near = track.nearest(sensor).unwrap();
        // Pure pursuit of a tape point 20 mm ahead of the sensor, plus a slow weave.
        let target = near.point + near.tangent * 0.02;
        let want = (target.y - truth.y).atan2(target.x - truth.x);
        let omega = 8.0 * wrap_angle(want - truth.theta) + 0.3 * (k as f64 * 0.05).sin();
        let dth = omega * dt;
        let ds = v * dt;
        let mid = truth.theta + dth / 2.0;
        truth = Pose {
            x: truth.x + ds * mid.cos(),
            y: truth.y + ds * mid.sin(),
            theta: truth.theta + dth,
        };
        let dth_odo = dth + ds * 2f64.to_radians();
        let mid = odo.theta + dth_odo / 2.0;
        odo = Pose {
            x: odo.x + ds * mid.cos(),
            y: odo.y + ds * mid.sin(),
            theta: odo.theta + dth_odo,
        };
        let heading = Vector2::new(truth.theta.cos(), truth.theta.sin());
        let right = Vector2::new(heading.y, -heading.x);
        let sensor = Point2::new(truth.x, truth.y) + heading * LINE_SENSOR_AHEAD_M;
        let near = track.nearest(sensor).unwrap();
        let mut state = protocol::RobotState::default();
        state.line.position_um = ((near.point - sensor).dot(&right) * 1e6) as i16;
        state.line.flags = LINE_FOLLOWING;
        model.apply(&StateUpdated {
            robot_id: 1,
            at: tokio::time::Instant::now(),
            state,
            reduced: false,
            pose: odo,
            rtt: None,
        });
        let est = model.views()[0].pose;
        if k > 200 {
            let lateral = right.dot(&Vector2::new(est.x - truth.x, est.y - truth.y));
            worst_lateral = worst_lateral.max(lateral.abs());
            worst_heading = worst_heading.max(wrap_angle(est.theta - truth.theta).abs());
        }
    }
    let v = model.views()[0].clone();
    let odo_err = (v.odometry.x - truth.x).hypot(v.odometry.y - truth.y);
    let est_err = (v.pose.x - truth.x).hypot(v.pose.y - truth.y);
    let laps = 4000.0 * 0.003 / TrackLoopLen::oval();
    assert!(laps > 5.0, "{laps}");
    assert!(odo_err > 0.05, "the drift is real: {odo_err}");
    assert!(worst_lateral < 0.002, "lateral {worst_lateral}");
    assert!(worst_heading < 3f64.to_radians(), "heading {worst_heading}");
    // Along the tape nothing is measured, but the heading held on the tape keeps the error
    // along it to what the odometry's distance alone gets wrong.
    assert!(est_err < 0.005, "estimate {est_err} vs odometry {odo_err}");
}

/// What the line sensor of a robot at `truth` reports over `track`: eight spots 3 mm apart
/// across the heading, each dark over tape; the tape's offset to the right in µm is the
/// centroid of the dark ones, and the line is lost when none is.
fn sense(track: &Track, truth: Pose) -> protocol::RobotState {
    let heading = Vector2::new(truth.theta.cos(), truth.theta.sin());
    let right = Vector2::new(heading.y, -heading.x);
    let sensor = Point2::new(truth.x, truth.y) + heading * LINE_SENSOR_AHEAD_M;
    let dark: Vec<f64> = (0..8)
        .map(|k| (k as f64 - 3.5) * 0.003)
        .filter(|&off| {
            track
                .nearest(sensor + right * off)
                .is_some_and(|n| n.distance_m < 0.003)
        })
        .collect();
    let mut state = protocol::RobotState::default();
    if dark.is_empty() {
        state.line.flags = LINE_LOST;
    } else {
        let centroid = dark.iter().sum::<f64>() / dark.len() as f64;
        state.line.position_um = (centroid * 1e6) as i16;
    }
    state
}

/// A unicycle step: `ds` along an arc turning `dth`.
fn step(p: Pose, ds: f64, dth: f64) -> Pose {
    let mid = p.theta + dth / 2.0;
    Pose {
        x: p.x + ds * mid.cos(),
        y: p.y + ds * mid.sin(),
        theta: p.theta + dth,
    }
}

struct Drive {
    model: WorldModel,
    track: Arc<Track>,
    truth: Pose,
    odometry: Pose,
    at: tokio::time::Instant,
    /// Each transition and the true pose when it came.
    transitions: Vec<Transition>,
    transition_at: Vec<Pose>,
    /// Whether the firmware follows the tape while its sensor sees one.
    following: bool,
}

impl Drive {
    fn new(track: Track, start: Pose) -> Self {
        let track = Arc::new(track);
        let model = WorldModel::new(Arc::clone(&track));
        model.add(1);
        let mut d = Self {
            model,
            track,
            truth: start,
            odometry: start,
            at: tokio::time::Instant::now(),
            transitions: Vec::new(),
            transition_at: Vec::new(),
            following: false,
        };
        d.report();
        d
    }

    /// Moves the robot by `ds` and `dth`; its odometry reads `ds·(1 + scale)` and turns
    /// `drift` radians per metre more than it did.
    fn go(&mut self, ds: f64, dth: f64, scale: f64, drift: f64) {
        self.truth = step(self.truth, ds, dth);
        self.odometry = step(self.odometry, ds * (1.0 + scale), dth + ds.abs() * drift);
        self.report();
    }

    fn report(&mut self) {
        self.at += std::time::Duration::from_millis(20);
        let mut state = sense(&self.track, self.truth);
        if self.following && state.line.flags & LINE_LOST == 0 {
            state.line.flags |= LINE_FOLLOWING;
        }
        let u = StateUpdated {
            robot_id: 1,
            at: self.at,
            state,
            reduced: false,
            pose: self.odometry,
            rtt: None,
        };
        if let Some(t) = self.model.apply(&u) {
            self.transitions.push(t);
            self.transition_at.push(self.truth);
        }
    }

    fn view(&self) -> RobotView {
        self.model.views()[0].clone()
    }

    fn error_m(&self) -> f64 {
        let p = self.view().pose;
        (p.x - self.truth.x).hypot(p.y - self.truth.y)
    }

    /// Drives straight to `(x, y)` at 0.1 m/s in 2 mm steps, first turning on the spot
    /// towards it.
    fn drive_to(&mut self, x: f64, y: f64, scale: f64, drift: f64) -> f64 {
        let want = (y - self.truth.y).atan2(x - self.truth.x);
        let turn = wrap_angle(want - self.truth.theta);
        let n = (turn.abs() / 0.05).ceil() as usize;
        for _ in 0..n {
            self.go(0.0, turn / n as f64, scale, drift);
        }
        let d = (x - self.truth.x).hypot(y - self.truth.y);
        let n = (d / 0.002).ceil() as usize;
        let mut worst = 0.0f64;
        for _ in 0..n {
            self.go(d / n as f64, 0.0, scale, drift);
            worst = worst.max(self.error_m());
        }
        worst
    }
}

/// A robot driving moves along a grid's tapes (not following them), its odometry 0.5 % long
/// and drifting 3° per metre: every turn onto a crossing tape takes out what the last one
/// could not see, and the model stays within millimetres while the odometry goes astray.
#[test]
fn a_robot_driving_moves_along_tapes_is_localised_by_them() {
    let world = presets::grid(4, 4, 1);
    let node = |c: usize, r: usize| {
        let id = format!("c{c}r{r}");
        world.track.nodes()[world.track.node_index(&id).unwrap()].position
    };
    let start = node(0, 0);
    let mut d = Drive::new(
        world.track.clone(),
        Pose {
            x: start.x,
            y: start.y,
            theta: 0.0,
        },
    );
    let (scale, drift) = (0.005, 3f64.to_radians());
    let route = [
        (3, 0),
        (3, 3),
        (0, 3),
        (0, 0),
        (2, 0),
        (2, 2),
        (1, 2),
        (1, 0),
    ];
    let mut worst = 0.0f64;
    for lap in 0..3 {
        for &(c, r) in &route {
            let p = node(c, r);
            let w = d.drive_to(p.x, p.y, scale, drift);
            if lap > 0 {
                worst = worst.max(w);
            }
        }
    }
    let v = d.view();
    let odo_err = (v.odometry.x - d.truth.x).hypot(v.odometry.y - d.truth.y);
    assert!(odo_err > 0.05, "the drift is real: {odo_err}");
    assert!(worst < 0.006, "model error {worst}");
    assert!(d.transitions.is_empty(), "{:?}", d.transitions);
    let sigma = v.uncertainty.position_m;
    assert!(sigma > 0.0005 && sigma < 0.01, "uncertainty {sigma}");
    assert_eq!(v.localisation, Localisation::Tracking);
}

/// Off the tape the uncertainty grows with the distance driven; back on a tape it shrinks
/// across the tape.
#[test]
fn uncertainty_grows_off_the_tape_and_shrinks_on_it() {
    let world = presets::grid(4, 4, 1);
    let mut d = Drive::new(
        world.track.clone(),
        Pose {
            x: 0.3,
            y: 0.3,
            theta: 0.0,
        },
    );
    let s0 = d.view().uncertainty.position_m;
    // Round a square inside one cell five times, never over tape.
    for _ in 0..5 {
        for (x, y) in [(0.35, 0.3), (0.35, 0.35), (0.3, 0.35), (0.3, 0.3)] {
            d.drive_to(x, y, 0.0, 0.0);
        }
    }
    let s1 = d.view().uncertainty.position_m;
    let h1 = d.view().uncertainty.heading_rad;
    assert!(s1 > s0 * 2.0, "{s0} -> {s1}");
    assert!(h1 > START_SIGMA_RAD, "{h1}");
    // Then onto the tape at y = 0.4 and along it.
    d.drive_to(0.3, 0.4, 0.0, 0.0);
    d.drive_to(0.39, 0.4, 0.0, 0.0);
    let normal = Vector2::new(0.0, 1.0);
    let est = d.model.estimates.get(&1).unwrap().cov;
    assert!(
        sigma_along(&est, normal) < 0.002,
        "{}",
        sigma_along(&est, normal)
    );
    assert!(d.transitions.is_empty(), "{:?}", d.transitions);
}

/// A robot driving moves along the tape at y = 0.2 of a grid, kicked 30 mm off it at the x it
/// returns, then driven on to (0.35, 0.23).
fn kicked_off_the_tape() -> (Drive, f64) {
    let world = presets::grid(4, 4, 1);
    let mut d = Drive::new(
        world.track.clone(),
        Pose {
            x: 0.2,
            y: 0.2,
            theta: 0.0,
        },
    );
    d.drive_to(0.27, 0.2, 0.0, 0.0);
    d.truth.y += 0.03;
    let kicked_at = d.truth.x;
    d.drive_to(0.35, 0.23, 0.0, 0.0);
    (d, kicked_at)
}

/// Kicked 30 mm sideways off the tape it drives along, a robot no longer sees the tape where
/// the model puts it: it is lost within a few centimetres. Creeping across, its sensor finds
/// the tape, which fixes the position across it; driving along it again, it is tracked.
#[test]
fn a_kicked_robot_is_found_lost_and_relocated_by_the_tape() {
    let (mut d, kicked_at) = kicked_off_the_tape();
    let lost_after = match d.transitions.first() {
        Some(Transition::Lost(why)) => {
            assert!(why.contains("no tape"), "{why}");
            d.transition_at[0].x - kicked_at
        }
        other => panic!("{other:?}"),
    };
    assert!(lost_after < 0.06, "lost only after {lost_after} m");
    assert_eq!(d.view().localisation, Localisation::Lost);
    assert!(d.view().uncertainty.position_m >= LOST_FLOOR_M * 0.99);
    // The search: face across the tape and creep towards it.
    d.drive_to(d.truth.x, 0.15, 0.0, 0.0);
    assert!(
        d.transitions.contains(&Transition::Fixed),
        "{:?}",
        d.transitions
    );
    let across = (d.view().pose.y - d.truth.y).abs();
    assert!(across < 0.003, "across the tape {across}");
    // Onto the tape and along it.
    d.drive_to(d.truth.x, 0.2, 0.0, 0.0);
    d.drive_to(d.truth.x + 0.05, 0.2, 0.0, 0.0);
    assert_eq!(d.transitions.last(), Some(&Transition::Found));
    assert_eq!(d.view().localisation, Localisation::Tracking);
    assert!(d.error_m() < 0.005, "{}", d.error_m());
    let stats = d.model.localisation_stats(d.at);
    assert_eq!(stats[0].1.lost_episodes, 1);
    assert!(stats[0].1.lost_time > std::time::Duration::ZERO);
}

/// A robot driven along the tape at y = 0.2 of a grid from its node at x = 0.2 to `x`,
/// following it or not.
fn on_the_tape_at_x(x: f64, following: bool) -> Drive {
    let world = presets::grid(4, 4, 1);
    let start = Pose {
        x: 0.2,
        y: 0.2,
        theta: 0.0,
    };
    let mut d = Drive::new(world.track.clone(), start);
    d.following = following;
    d.drive_to(x, 0.2, 0.0, 0.0);
    d
}

/// Knocked off the tape while it stands, a robot never drives the distance the rule above
/// waits for: its sensor seeing no tape for half a second where the model puts it on one is
/// enough. Standing on the tape, it is not lost however long it waits.
#[test]
fn a_robot_knocked_off_the_tape_at_rest_is_found_lost() {
    let mut d = on_the_tape_at_x(0.27, false);
    for _ in 0..100 {
        d.report();
    }
    assert!(d.transitions.is_empty(), "{:?}", d.transitions);
    d.truth.y += 0.03;
    for _ in 0..20 {
        d.report();
    }
    assert!(
        d.transitions.is_empty(),
        "lost after 0.4 s: {:?}",
        d.transitions
    );
    for _ in 0..10 {
        d.report();
    }
    match d.transitions.first() {
        Some(Transition::Lost(why)) => assert!(why.contains("standing"), "{why}"),
        other => panic!("{other:?}"),
    }
    assert_eq!(d.view().localisation, Localisation::Lost);
}

/// A robot turned where it stands, its sensor still on the tape, is lost: a reading at rest
/// cannot tell a turn from a shift, and a robot that drove off on an unseen turn met a wall.
#[test]
fn a_robot_turned_where_it_stands_is_lost() {
    let mut d = on_the_tape_at_x(0.27, false);
    for _ in 0..50 {
        d.report();
    }
    let calm = d.view().uncertainty.heading_rad;
    assert!(calm < 3f64.to_radians(), "{calm}");
    assert!(d.transitions.is_empty(), "{:?}", d.transitions);
    d.truth.theta -= 12f64.to_radians();
    for _ in 0..10 {
        d.report();
    }
    assert!(
        matches!(d.transitions.first(), Some(Transition::Lost(why)) if why.contains("while it stood")),
        "{:?}",
        d.transitions
    );
    let v = d.view();
    assert!(
        v.uncertainty.heading_rad >= LOST_FLOOR_RAD - 1e-9,
        "heading 1σ {:.1}° after a 12° turn at rest",
        v.uncertainty.heading_rad.to_degrees()
    );
}

/// A follower knocked off its tape loses it at once: where the model has it squarely on the
/// tape, that alone makes it lost, before it drives or stands for any time.
#[test]
fn a_follower_that_loses_its_tape_where_the_model_has_one_is_lost_at_once() {
    let mut d = on_the_tape_at_x(0.27, true);
    assert!(d.transitions.is_empty(), "{:?}", d.transitions);
    d.truth.y += 0.03;
    d.report();
    match d.transitions.first() {
        Some(Transition::Lost(why)) => assert!(why.contains("follower"), "{why}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_robot_backing_across_a_tape_is_fixed_across_it_when_it_comes_onto_it() {
    let world = presets::grid(4, 4, 1);
    let north = std::f64::consts::FRAC_PI_2;
    let mut d = Drive::new(
        world.track.clone(),
        Pose {
            x: 0.3,
            y: 0.2 - LINE_SENSOR_AHEAD_M,
            theta: north,
        },
    );
    // Pushing: the wheels turn half as far again as the body goes, 60 mm off the tape.
    for _ in 0..30 {
        d.go(0.002, 0.0, 0.5, 0.0);
    }
    let off = d.error_m();
    assert!(off > 0.025, "the odometry is {off} m off");
    // Backing straight down until the sensor is on the tape again.
    let mut steps = 0;
    while d.view().state.line.flags & LINE_LOST != 0 && steps < 100 {
        d.go(-0.002, 0.0, 0.0, 0.0);
        steps += 1;
    }
    assert!(steps < 100, "never came onto the tape");
    let across = (d.view().pose.y - d.truth.y).abs();
    assert!(
        across < 0.004,
        "still {across} m off across the tape (was {off})"
    );
    assert_eq!(
        d.view().localisation,
        Localisation::Tracking,
        "not lost: fixed"
    );
}

struct TrackLoopLen;
impl TrackLoopLen {
    fn oval() -> f64 {
        1.0 + 0.3 * PI
    }
}

/// A robot that reports a bump after its dragged wheels counted 40 mm and 35° of travel that
/// never happened: the model goes back to where it stood before the jolt and halfway along the
/// felt move, widens its pose to cover the push and a turn and loses it, however small the felt
/// move (a hand turns what it shifts); on a floor no tape reaches it is only widened.
#[test]
fn a_bump_takes_the_estimate_back_before_the_jolt_halfway_along_the_felt_move() {
    let world = presets::preset("oval").unwrap();
    let model = WorldModel::new(Arc::new(world.track.clone()));
    model.add(1);
    let update = |uptime_ms: u32, pose: Pose| {
        let mut state = protocol::RobotState {
            uptime_ms,
            ..Default::default()
        };
        // Its line sensor sees no tape: only odometry and the bump move the estimate.
        state.line.flags = LINE_LOST;
        StateUpdated {
            robot_id: 1,
            at: tokio::time::Instant::now(),
            state,
            reduced: false,
            pose,
            rtt: None,
        }
    };
    let felt = |m: f64| Felt {
        moved_m: m,
        along_m: 0.0,
        left_m: m,
        since_ms: 200,
    };
    let start = Pose {
        x: 0.35,
        y: 0.15,
        theta: 0.0,
    };
    for k in 0..10 {
        model.apply(&update(k * 20, start));
    }
    // The jolt from 200 ms on: the odometry runs off.
    let off = Pose {
        x: 0.39,
        y: 0.16,
        theta: 0.6,
    };
    for k in 10..14 {
        model.apply(&update(k * 20, off));
    }
    assert!((model.views()[0].pose.x - 0.39).abs() < 0.01);
    let why = model
        .bumped(1, felt(0.02), tokio::time::Instant::now())
        .expect("lost");
    assert!(why.contains("20 mm"), "{why}");
    let v = &model.views()[0];
    assert_eq!(v.localisation, Localisation::Lost);
    // Felt 20 mm to its left: half of it.
    let mid = Pose {
        y: start.y + 0.01,
        ..start
    };
    assert!(
        (v.pose.x - mid.x).abs() < 1e-9
            && (v.pose.y - mid.y).abs() < 1e-9
            && v.pose.theta.abs() < 1e-9,
        "{:?}",
        v.pose
    );
    // Half the felt move and 5 mm: within 1σ of anywhere between none and all of it.
    assert!(
        v.uncertainty.position_m >= 0.015 - 1e-9,
        "{:?}",
        v.uncertainty
    );
    assert!(v.uncertainty.heading_rad >= 20f64.to_radians() - 1e-9);
    // Further odometry goes on from there.
    model.apply(&update(300, Pose { x: 0.40, ..off }));
    let p = model.views()[0].pose;
    assert!(
        ((p.x - mid.x).hypot(p.y - mid.y) - 0.01).abs() < 1e-6,
        "{p:?}"
    );

    // A small bump: back before the jolt and half the felt move on, widened to the lost floor
    // and a 20° turn, lost.
    let small = WorldModel::new(Arc::new(world.track.clone()));
    small.add(1);
    for k in 0..10 {
        small.apply(&update(k * 20, start));
    }
    small.apply(&update(220, off));
    assert!(small
        .bumped(1, felt(0.008), tokio::time::Instant::now())
        .is_some());
    let v = &small.views()[0];
    assert_eq!(v.localisation, Localisation::Lost);
    assert!((v.pose.x - start.x).abs() < 1e-9, "{:?}", v.pose);
    assert!(v.uncertainty.position_m >= LOST_FLOOR_M - 1e-9);
    assert!(v.uncertainty.heading_rad >= 20f64.to_radians() - 1e-9);

    // Far from every tape nothing could find it again: only widened.
    let far = Pose {
        x: 0.9,
        y: 0.55,
        theta: 0.0,
    };
    let open = WorldModel::new(Arc::new(world.track.clone()));
    open.add(1);
    open.apply(&update(0, far));
    assert!(
        open.track()
            .nearest(Point2::new(far.x, far.y))
            .unwrap()
            .distance_m
            > RELOCATE_M + BUMP_MAX_M
    );
    assert_eq!(
        open.bumped(1, felt(0.012), tokio::time::Instant::now()),
        None
    );
    let v = &open.views()[0];
    assert_eq!(v.localisation, Localisation::Tracking);
    assert!(v.uncertainty.position_m >= 0.018 - 1e-9);
}

/// A robot that reports a bump of 32 m along its heading (a broken accelerometer, or a peer that
/// lies) is lost, its estimate widened no farther than a credible bump and not moved.
#[test]
fn a_bump_of_metres_moves_the_estimate_no_farther_than_a_bump_can() {
    let world = presets::preset("oval").unwrap();
    let model = WorldModel::new(Arc::new(world.track.clone()));
    model.add(1);
    let start = Pose {
        x: 0.35,
        y: 0.15,
        theta: 0.0,
    };
    let mut state = protocol::RobotState::default();
    state.line.flags = LINE_LOST;
    model.apply(&StateUpdated {
        robot_id: 1,
        at: tokio::time::Instant::now(),
        state,
        reduced: false,
        pose: start,
        rtt: None,
    });
    let lie = Felt {
        moved_m: 65.535,
        along_m: 32.767,
        left_m: 0.0,
        since_ms: 0,
    };
    assert!(model.bumped(1, lie, tokio::time::Instant::now()).is_some());
    let v = &model.views()[0];
    assert!(
        (v.pose.x - start.x).hypot(v.pose.y - start.y) < 1e-9,
        "{:?}",
        v.pose
    );
    assert!(
        v.uncertainty.position_m <= BUMP_MAX_M * 1.5,
        "{:?}",
        v.uncertainty
    );
}

/// A follower that drives straight along a straight tape faces along it: the measurement takes
/// out a heading error its odometry carried in (here 12°, which the tape's own gentle gain
/// would take seconds to undo), and leaves the heading as certain as a follower's weave. Near a
/// junction, where tapes cross, it measures nothing.
#[test]
fn a_settled_follower_faces_along_its_tape() {
    let mut d = on_the_tape_at_x(0.3, true);
    d.odometry.theta += 12f64.to_radians();
    d.report();
    let off = d.view().pose.theta.abs();
    assert!(off > 10f64.to_radians(), "{}", off.to_degrees());
    assert!(d.model.faces_along_tape(1));
    let v = d.view();
    assert!(
        v.pose.theta.abs() < 1f64.to_radians(),
        "{}",
        v.pose.theta.to_degrees()
    );
    assert!((v.pose.y - 0.2).abs() < 0.001, "{}", v.pose.y);
    assert!(
        v.uncertainty.heading_rad < 3.5f64.to_radians(),
        "{}",
        v.uncertainty.heading_rad.to_degrees()
    );
    // The next update keeps it: the correction now takes the odometry to the tape's heading.
    d.report();
    assert!(d.view().pose.theta.abs() < 1f64.to_radians());
    let at_node = on_the_tape_at_x(0.21, true);
    assert!(!at_node.model.faces_along_tape(1));
}

/// A search that ended unfound starts afresh: a fix across a tape that the search then gave up
/// on is forgotten, so the next crossing fixes the robot again (before, the next searches'
/// sightings could never fix it, and it ended `lost and not found`).
#[test]
fn a_search_that_ended_unfound_can_fix_the_robot_again() {
    let (mut d, _) = kicked_off_the_tape();
    assert!(matches!(d.transitions.first(), Some(Transition::Lost(_))));
    d.drive_to(d.truth.x, 0.15, 0.0, 0.0);
    let fixes = |d: &Drive| {
        d.transitions
            .iter()
            .filter(|t| **t == Transition::Fixed)
            .count()
    };
    assert_eq!(fixes(&d), 1, "{:?}", d.transitions);
    // Back across the tape: a fixed estimate takes no second fix.
    d.drive_to(d.truth.x, 0.25, 0.0, 0.0);
    assert_eq!(fixes(&d), 1, "{:?}", d.transitions);
    d.model.search_afresh(1, d.at);
    let v = d.view();
    assert_eq!(v.localisation, Localisation::Lost);
    assert!(v.uncertainty.position_m >= LOST_FLOOR_M * 0.99);
    d.drive_to(d.truth.x, 0.15, 0.0, 0.0);
    assert_eq!(fixes(&d), 2, "{:?}", d.transitions);
}
