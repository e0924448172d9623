//! The firmware drives simulated bodies: moves, pushing, IR encounters, watchdog, determinism.

mod common;

use std::time::Duration;

use common::{connected, connected_with, run, send, world};

/// Physics every clock step (1 kHz), every second (500 Hz) and every fifth (200 Hz, the coarsest
/// the CLI offers): moves, turns and pushes must come out the same at all three, since the drive
/// train is integrated on the clock step whatever the physics rate.
const PHYSICS_RATES: [u32; 3] = [1, 2, 5];
use firmware::hal::Side;
use protocol::packets::*;
use protocol::AnyPacket;

const OPEN: &str = r#"
name = "open"
[arena]
width_m = 1.0
height_m = 1.0
[track]
nodes = [{ id = "a", x = 0.1, y = 0.1 }, { id = "b", x = 0.2, y = 0.1 }]
edges = [{ from = "a", to = "b" }]
[[robots]]
id = 1
x = 0.5
y = 0.5
heading_deg = 0
"#;

#[test]
fn square_walk_closes_in_physics() {
    for every in PHYSICS_RATES {
        square_walk(every);
    }
}

fn square_walk(physics_every: u32) {
    let mut sim = connected_with(world(OPEN), 1, physics_every);
    for i in 0..4u16 {
        send(
            &mut sim,
            0,
            StraightMovement {
                distance_m: 0.1,
                speed_mps: 0.2,
                move_id: 2 * i + 1,
            },
        );
        send(
            &mut sim,
            0,
            RotationMovement {
                angle_deg: 90.0,
                speed_mps: 0.2,
                move_id: 2 * i + 2,
            },
        );
    }
    let done = run(&mut sim, Duration::from_secs(15), |_, p| {
        matches!(p, AnyPacket::QueueEmpty(_))
    });
    assert!(done.is_some(), "queue never emptied");
    run(&mut sim, Duration::from_millis(300), |_, _| false);
    let p = sim.robots()[0].pose();
    let err_mm = (p.x - 0.5).hypot(p.y - 0.5) * 1e3;
    let heading = (p.theta.to_degrees() - 360.0).abs();
    eprintln!(
        "physics every {physics_every} ms: square {err_mm:.1} mm, {heading:.1} deg, pose {p:?}, done at {done:?}"
    );
    assert!(err_mm < 10.0, "{err_mm} mm");
    assert!(heading < 5.0, "{heading} deg");
}

fn unwrap_angle(prev: f64, now: f64) -> f64 {
    prev + simulator::world::wrap_angle(now - prev.rem_euclid(std::f64::consts::TAU))
}

#[test]
fn line_following_laps_the_oval_three_times() {
    for every in PHYSICS_RATES {
        lap_the_oval(every);
    }
}

fn lap_the_oval(physics_every: u32) {
    let oval = simulator::world::presets::preset("oval").unwrap();
    let mut sim = connected_with(oval, 3, physics_every);
    for i in 0..2 {
        send(
            &mut sim,
            i,
            LineFollow {
                enable: 1,
                speed_mps: 0.2,
            },
        );
    }
    let centre = (0.5, 0.3);
    let angle = |p: simulator::sim::Pose| (p.y - centre.1).atan2(p.x - centre.0);
    let mut turned = [angle(sim.robots()[0].pose()), angle(sim.robots()[1].pose())];
    let start = turned;
    let mut lost = 0;
    let mut worst_mm: f64 = 0.0;
    let limit = Duration::from_secs(45);
    let end = sim.now() + limit;
    while sim.now() < end {
        run(&mut sim, Duration::from_millis(50), |_, p| {
            if matches!(p, AnyPacket::LineEvent(e) if e.lost == 1) {
                lost += 1;
            }
            false
        });
        for (i, t) in turned.iter_mut().enumerate() {
            let p = sim.robots()[i].pose();
            *t = unwrap_angle(*t, angle(p));
            let ahead = simulator::world::robot::LINE_SENSOR_AHEAD_M;
            let sensor =
                nalgebra::Point2::new(p.x + ahead * p.theta.cos(), p.y + ahead * p.theta.sin());
            let d = sim
                .world()
                .track
                .nearest(sensor)
                .map_or(1.0, |n| n.distance_m);
            worst_mm = worst_mm.max(d * 1e3);
        }
        if turned
            .iter()
            .zip(start)
            .all(|(t, s)| t - s >= 3.0 * std::f64::consts::TAU)
        {
            break;
        }
    }
    let laps: Vec<f64> = turned
        .iter()
        .zip(start)
        .map(|(t, s)| (t - s) / std::f64::consts::TAU)
        .collect();
    eprintln!("physics every {physics_every} ms: laps {laps:?} in {:?}, line lost {lost} times, sensor at most {worst_mm:.1} mm off the tape", sim.now());
    assert!(laps.iter().all(|&l| l >= 3.0), "laps {laps:?} in {limit:?}");
    assert_eq!(lost, 0, "line lost");
    assert!(
        worst_mm < 8.0,
        "sensor {worst_mm:.1} mm off the tape centre"
    );
    assert_eq!(sim.robot_collisions(), 0);
}

/// A world with the `push` preset's box and `robots` placed straight behind it, touching.
fn pusher_world(robots: &[(u16, f64)]) -> simulator::World {
    let mut w = simulator::world::presets::preset("push").unwrap();
    let b = &w.obstacles[0];
    let (bx, by) = (b.position.x, b.position.y);
    let back = bx - b.width_m * 0.5 - 0.024 - 0.002;
    w.robots = robots
        .iter()
        .map(|&(id, dy)| simulator::world::RobotStart {
            id,
            position: nalgebra::Point2::new(back, by + dy),
            heading_rad: 0.0,
        })
        .collect();
    w
}

/// Sets every robot's proximity reflex to `power_level` (0 off).
fn reflex(sim: &mut simulator::Simulation, power_level: u8) {
    let (offset, _) = protocol::settings::Settings::field("reflex.power_level").unwrap();
    for i in 0..sim.robots().len() {
        send(
            sim,
            i,
            SettingsUpdate::new(offset as u16, &[power_level]).unwrap(),
        );
    }
}

fn push_for(world: simulator::World, secs: u64, physics_every: u32) -> f64 {
    let mut sim = connected_with(world, 5, physics_every);
    // Pushing is driving into what the front receiver sees: the reflex would stop it.
    reflex(&mut sim, 0);
    for i in 0..sim.robots().len() {
        // Full power straight ahead: the motor-power teleop, no speed loop to back off.
        send(
            &mut sim,
            i,
            MotorPower {
                left_pwm: 1000,
                right_pwm: 1000,
            },
        );
    }
    run(&mut sim, Duration::from_secs(secs), |_, _| false);
    sim.obstacle_displacements()[0]
}

/// A robot sent straight at the box 3 cm ahead stops short of it by its own reflex, the box
/// untouched; with the reflex off, the same move drives into the box.
#[test]
fn the_reflex_stops_a_robot_short_of_a_box_it_was_sent_into() {
    for (power_level, stops) in [(1, true), (0, false)] {
        let mut world = pusher_world(&[(1, 0.0)]);
        world.robots[0].position.x -= 0.03;
        let mut sim = connected_with(world, 5, 1);
        reflex(&mut sim, power_level);
        run(&mut sim, Duration::from_millis(50), |_, _| false);
        let start = sim.robots()[0].pose().x;
        send(
            &mut sim,
            0,
            StraightMovement {
                distance_m: 0.1,
                speed_mps: 0.05,
                move_id: 1,
            },
        );
        let (mut outcome, mut reflexes) = (None, 0);
        run(&mut sim, Duration::from_secs(4), |_, p| {
            match p {
                AnyPacket::MoveFinished(m) => outcome = Some(m.outcome),
                AnyPacket::Reflex(_) => reflexes += 1,
                _ => {}
            }
            false
        });
        let moved = sim.obstacle_displacements()[0];
        let driven = sim.robots()[0].pose().x - start;
        eprintln!(
            "reflex {power_level}: drove {:.1} mm, box moved {:.2} mm, outcome {outcome:?}",
            driven * 1e3,
            moved * 1e3
        );
        if stops {
            assert_eq!(outcome, Some(MoveOutcome::Blocked as u8));
            assert_eq!(reflexes, 1);
            assert!(moved < 1e-4, "the box moved {:.2} mm", moved * 1e3);
            assert!(driven > 0.01 && driven < 0.03, "{:.1} mm", driven * 1e3);
        } else {
            assert_eq!(reflexes, 0);
            assert!(driven > 0.028, "it reaches the box: {:.1} mm", driven * 1e3);
        }
    }
}

#[test]
fn one_robot_cannot_move_the_heavy_box_and_two_can() {
    for every in PHYSICS_RATES {
        let one = push_for(pusher_world(&[(1, 0.0)]), 10, every);
        let two = push_for(pusher_world(&[(1, -0.0165), (2, 0.0165)]), 10, every);
        eprintln!(
            "physics every {every} ms: box moved {:.1} mm by one robot, {:.1} mm by two",
            one * 1e3,
            two * 1e3
        );
        assert!(one < 0.005, "one robot moved it {:.1} mm", one * 1e3);
        assert!(two > 0.050, "two robots moved it only {:.1} mm", two * 1e3);
    }
}

/// How far two robots push the heavy box in 2 s, before it reaches the arena's wall (in 10 s it
/// does at 1 kHz, which hides the rate's effect): contacts resolved every 5 ms push it about a
/// fifth less far than every millisecond, although the drive train runs on the clock step at
/// every rate. Moving the box's floor friction into the contact solve did not change that share
/// (`docs/measurements.md`, Simulator), so it lies in the contact step itself. The bounds hold
/// the figures measured there (500 Hz 5 %, 200 Hz 22 % short).
#[test]
fn a_coarser_physics_step_pushes_the_box_less_far_by_a_known_share() {
    let two = |every| push_for(pusher_world(&[(1, -0.0165), (2, 0.0165)]), 2, every);
    let reference = two(1);
    assert!(reference > 0.3, "{:.1} mm at 1 kHz", reference * 1e3);
    for (every, least) in [(2, 0.9), (5, 0.7)] {
        let pushed = two(every);
        eprintln!(
            "physics every {every} ms: {:.1} mm in 2 s, {:.0} % of 1 kHz's {:.1} mm",
            pushed * 1e3,
            pushed / reference * 100.0,
            reference * 1e3
        );
        assert!(
            pushed > least * reference && pushed <= reference,
            "physics every {every} ms: {:.1} mm against {:.1} mm at 1 kHz",
            pushed * 1e3,
            reference * 1e3
        );
    }
}

const FACING: &str = r#"
name = "facing"
[arena]
width_m = 0.6
height_m = 0.4
[track]
nodes = [{ id = "a", x = 0.05, y = 0.05 }, { id = "b", x = 0.1, y = 0.05 }]
edges = [{ from = "a", to = "b" }]
[[robots]]
id = 7
x = 0.27
y = 0.2
heading_deg = 0
[[robots]]
id = 9
x = 0.33
y = 0.2
heading_deg = 180
[[robots]]
id = 4
x = 0.555
y = 0.3
heading_deg = 0
"#;

#[test]
fn facing_robots_identify_each_other_and_a_wall_is_an_obstacle() {
    let mut sim = connected(world(FACING), 2);
    let mut seen: Vec<(u16, u16)> = Vec::new();
    let mut obstacles = [0usize; 3];
    let mut encounters_of_wall_robot = 0;
    run(&mut sim, Duration::from_secs(1), |i, p| {
        match p {
            AnyPacket::RobotEncountered(e) => {
                let me = [7u16, 9, 4][i];
                seen.push((me, { e.robot_id }));
                if i == 2 {
                    encounters_of_wall_robot += 1;
                }
            }
            AnyPacket::Obstacle(o) if o.side == Side::Front as u8 => obstacles[i] += 1,
            _ => {}
        }
        false
    });
    eprintln!("encounters {seen:?}, obstacle reports {obstacles:?}");
    assert!(seen.contains(&(7, 9)), "7 did not identify 9 within 1 s");
    assert!(seen.contains(&(9, 7)), "9 did not identify 7 within 1 s");
    assert!(obstacles[2] > 0, "robot facing the wall saw no obstacle");
    assert_eq!(encounters_of_wall_robot, 0, "a wall is not a robot");
}

#[test]
fn a_cut_link_stops_the_robot_within_the_watchdog_timeout() {
    let mut sim = connected(world(OPEN), 1);
    send(
        &mut sim,
        0,
        WheelSpeeds {
            left_mps: 0.1,
            right_mps: 0.1,
        },
    );
    run(&mut sim, Duration::from_millis(500), |_, _| false);
    assert!(
        sim.robots()[0].firmware().board().pwm != (0, 0),
        "not driving"
    );
    let cut_at = sim.now();
    // The last packet the robot got was a ping up to 100 ms before the cut; count from the cut.
    sim.set_link_up(0, false);
    let mut stopped_at = None;
    while sim.now() < cut_at + Duration::from_secs(1) {
        sim.step();
        if sim.robots()[0].firmware().board().pwm == (0, 0) {
            stopped_at = Some(sim.now());
            break;
        }
    }
    let after = stopped_at.expect("never stopped") - cut_at;
    let timeout = Duration::from_millis(u64::from(
        protocol::settings::Settings::default().watchdog.timeout_ms,
    ));
    eprintln!("stopped {after:?} after the cut");
    assert!(
        after <= timeout + sim.dt(),
        "stopped {after:?} after the cut"
    );
}

fn trajectory(seed: u64, physics_every: u32) -> Vec<(f64, f64, f64)> {
    let oval = simulator::world::presets::preset("oval").unwrap();
    let mut sim = connected_with(oval, seed, physics_every);
    for i in 0..2 {
        send(
            &mut sim,
            i,
            LineFollow {
                enable: 1,
                speed_mps: 0.2,
            },
        );
    }
    run(&mut sim, Duration::from_secs(60), |_, _| false);
    sim.robots()
        .iter()
        .map(|r| (r.pose().x, r.pose().y, r.pose().theta))
        .collect()
}

#[test]
fn one_seed_is_bit_identical_and_two_seeds_differ() {
    for every in PHYSICS_RATES {
        let a = trajectory(11, every);
        let b = trajectory(11, every);
        let c = trajectory(12, every);
        assert_eq!(a, b, "same seed, different poses");
        assert_ne!(a, c, "different seeds, same poses");
    }
}

#[test]
fn many_robots_stepped_on_all_cores_are_still_deterministic() {
    let run_once = || {
        let mut sim = connected(simulator::world::presets::grid(0, 0, 300), 4);
        for i in 0..sim.robots().len() {
            send(
                &mut sim,
                i,
                LineFollow {
                    enable: 1,
                    speed_mps: 0.15,
                },
            );
        }
        run(&mut sim, Duration::from_millis(500), |_, _| false);
        sim.robots().iter().map(|r| r.pose()).collect::<Vec<_>>()
    };
    let (a, b) = (run_once(), run_once());
    assert!(
        a.iter().zip(&b).all(|(p, q)| p == q),
        "300-robot runs diverged"
    );
    let moved = a.iter().filter(|p| p.x != 0.0).count();
    assert_eq!(moved, 300);
}

#[test]
fn jammed_wheels_hold_the_robot_and_dead_encoders_hide_its_motion() {
    let drive = |fault: Option<simulator::BodyFault>| {
        let mut sim = connected(world(OPEN), 1);
        sim.set_body_fault(0, fault);
        send(
            &mut sim,
            0,
            StraightMovement {
                distance_m: 0.1,
                speed_mps: 0.2,
                move_id: 1,
            },
        );
        run(&mut sim, Duration::from_secs(2), |_, _| false);
        let e = sim.robots()[0].firmware().state().encoders;
        let ticks = e.left_ticks.unsigned_abs() + e.right_ticks.unsigned_abs();
        (sim.robots()[0].distance_m(), ticks)
    };
    let (healthy_m, healthy_ticks) = drive(None);
    assert!((healthy_m - 0.1).abs() < 0.01, "{healthy_m} m");
    assert!(healthy_ticks > 100, "{healthy_ticks} pulses");
    let (jammed_m, jammed_ticks) = drive(Some(simulator::BodyFault::JammedWheels));
    assert!(jammed_m < 1e-4, "a jammed robot moved {jammed_m} m");
    assert_eq!(jammed_ticks, 0);
    let (blind_m, blind_ticks) = drive(Some(simulator::BodyFault::DeadEncoders));
    // The firmware never sees the move progress, so it drives on, harder, past its 0.1 m.
    assert!(blind_m > 0.1, "{blind_m} m");
    assert_eq!(blind_ticks, 0);
}

#[test]
fn a_kick_moves_the_body_and_not_the_odometry() {
    let mut sim = connected(world(OPEN), 1);
    run(&mut sim, Duration::from_millis(500), |_, _| false);
    let before = sim.robots()[0].pose();
    let ticks = |sim: &simulator::Simulation| {
        let e = sim.robots()[0].firmware().state().encoders;
        (e.left_ticks, e.right_ticks)
    };
    let ticks_before = ticks(&sim);
    let turn = 30f64.to_radians();
    let kicked = sim.displace(0, 0.05, -0.02, turn).unwrap();
    assert!((kicked.x - before.x - 0.05).abs() < 1e-4, "{kicked:?}");
    assert!((kicked.y - before.y + 0.02).abs() < 1e-4, "{kicked:?}");
    assert!(
        (kicked.theta - before.theta - turn).abs() < 1e-4,
        "{kicked:?}"
    );
    run(&mut sim, Duration::from_millis(500), |_, _| false);
    let after = sim.robots()[0].pose();
    assert!(
        (after.x - kicked.x).hypot(after.y - kicked.y) < 5e-4,
        "a kicked robot at rest stays where it landed: {kicked:?} → {after:?}"
    );
    assert_eq!(ticks(&sim), ticks_before, "the encoders saw the kick");
    assert!(
        sim.robots()[0].distance_m() < 1e-3,
        "a kick is not distance driven"
    );
    // It drives on along its new heading.
    send(
        &mut sim,
        0,
        StraightMovement {
            distance_m: 0.1,
            speed_mps: 0.2,
            move_id: 1,
        },
    );
    run(&mut sim, Duration::from_secs(2), |_, _| false);
    let driven = sim.robots()[0].pose();
    let heading = (driven.y - after.y).atan2(driven.x - after.x);
    assert!(
        (heading - turn).abs() < 3f64.to_radians(),
        "drove at {:.1}°",
        heading.to_degrees()
    );
    assert_ne!(ticks(&sim), ticks_before);
}

#[test]
fn a_kick_of_no_robot_or_by_no_number_is_refused() {
    let mut sim = connected(world(OPEN), 1);
    let e = sim.displace(3, 0.1, 0.0, 0.0).unwrap_err();
    assert!(e.contains("index 3") && e.contains("0 to 0"), "{e}");
    let e = sim.displace(0, f64::NAN, 0.0, 0.0).unwrap_err();
    assert!(e.contains("not finite"), "{e}");
    assert_eq!(sim.robots()[0].pose().x, 0.5);
}

/// A kick that would land the robot beyond the walls is refused and the robot stays put: a run
/// once went on, and reported success, with a robot 10 m outside its 1 m arena.
#[test]
fn a_kick_out_of_the_arena_is_refused() {
    let mut sim = connected(world(OPEN), 1);
    for how in [
        world::cli::KickHow::Teleport,
        world::cli::KickHow::Shove(Duration::from_millis(50)),
    ] {
        let e = sim.kick(0, [9.9, 9.9, 0.0], how).unwrap_err();
        assert!(e.contains("outside the 1 × 1 m arena"), "{e}");
        let e = sim.kick(0, [0.0, -0.49, 0.0], how).unwrap_err();
        assert!(e.contains("outside"), "{e}");
        let p = sim.robots()[0].pose();
        assert_eq!((p.x, p.y), (0.5, 0.5));
    }
    assert!(sim
        .kick(0, [0.02, 0.0, 0.0], world::cli::KickHow::Teleport)
        .is_ok());
}

/// The bumps robot 0 reports over `d`.
fn bumps(sim: &mut simulator::Simulation, d: Duration) -> Vec<Bump> {
    let mut seen = Vec::new();
    run(sim, d, |i, p| {
        if let (0, AnyPacket::Bump(b)) = (i, p) {
            seen.push(b);
        }
        false
    });
    seen
}

/// A shove is a hand moving the body: it lands where it was pushed, the accelerometer feels
/// it, and the firmware reports a bump of about its size; driving does not.
#[test]
fn a_shove_moves_the_body_and_the_robot_feels_how_far() {
    let mut sim = connected(world(OPEN), 1);
    send(
        &mut sim,
        0,
        StraightMovement {
            distance_m: 0.1,
            speed_mps: 0.2,
            move_id: 1,
        },
    );
    assert_eq!(
        bumps(&mut sim, Duration::from_secs(2)),
        vec![],
        "its own start and stop are no bump"
    );
    let before = sim.robots()[0].pose();
    // 20 mm to its left (the robot faces +x) and 10° over 50 ms.
    sim.shove(
        0,
        (0.0, 0.02, 10f64.to_radians()),
        Duration::from_millis(50),
    )
    .unwrap();
    let felt = bumps(&mut sim, Duration::from_millis(500));
    let after = sim.robots()[0].pose();
    assert!(
        (after.y - before.y - 0.02).abs() < 1e-3 && (after.x - before.x).abs() < 1e-3,
        "{before:?} → {after:?}"
    );
    assert!((after.theta - before.theta - 10f64.to_radians()).abs() < 0.01);
    let jolt = felt
        .iter()
        .find(|b| b.cause == BumpCause::Jolt as u8)
        .unwrap_or_else(|| panic!("no jolt reported: {felt:?}"));
    assert!(
        (15..=30).contains(&{ jolt.moved_mm }),
        "a 20 mm shove felt as {} mm",
        { jolt.moved_mm }
    );
    assert!({ jolt.peak_mg } > 1000, "{jolt:?}");
    // Teleported, nothing on the robot feels it.
    sim.displace(0, 0.0, -0.02, 0.0).unwrap();
    assert_eq!(bumps(&mut sim, Duration::from_millis(500)), vec![]);
}

/// A turn about its centre moves no accelerometer there, but a robot standing with its motors
/// off feels its wheels dragged round.
#[test]
fn a_standing_robot_turned_by_hand_feels_its_wheels_turn() {
    let mut sim = connected(world(OPEN), 1);
    run(&mut sim, Duration::from_millis(500), |_, _| false);
    sim.shove(0, (0.0, 0.0, 15f64.to_radians()), Duration::from_millis(50))
        .unwrap();
    let felt = bumps(&mut sim, Duration::from_millis(500));
    assert!(
        felt.iter()
            .any(|b| b.cause == BumpCause::WheelsWhileIdle as u8),
        "{felt:?}"
    );
    let e = sim
        .shove(0, (0.0, 0.0, 0.1), Duration::from_millis(5))
        .unwrap_err();
    assert!(e.contains("20 to 100 ms"), "{e}");
}
