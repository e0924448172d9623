//! Whole-firmware behaviour on the kinematic mock board: moves, line following, watchdog, link,
//! settings reflection and proximity, each asserted from the board's true motion or the packets a
//! host would receive.

use firmware::hal::{IrFrame, Side};
use firmware::locomotion::tick_m;
use firmware::mock::{MockBoard, MockRobot};
use firmware::protocol::packets::*;
use firmware::protocol::settings::Settings;
use firmware::protocol::{slip, AnyPacket, Frame, SETTINGS_LAYOUT_HASH};
use firmware::{Duration, Instant};

fn robot() -> MockRobot {
    MockRobot::new(MockBoard::default())
}

fn straight(d: f32, v: f32, id: u16) -> StraightMovement {
    StraightMovement {
        distance_m: d,
        speed_mps: v,
        move_id: id,
    }
}

fn rotate(deg: f32, v: f32, id: u16) -> RotationMovement {
    RotationMovement {
        angle_deg: deg,
        speed_mps: v,
        move_id: id,
    }
}

fn finished(p: &AnyPacket, id: u16) -> bool {
    matches!(p, AnyPacket::MoveFinished(m) if { m.move_id } == id)
}

/// The moves the robot reports finished in what it has sent so far, with their outcomes.
fn finished_outcomes(r: &mut MockRobot) -> Vec<(u16, u8)> {
    r.drain()
        .into_iter()
        .filter_map(|p| match p {
            AnyPacket::MoveFinished(m) => Some((m.move_id, m.outcome)),
            _ => None,
        })
        .collect()
}

fn keep_alive(r: &mut MockRobot) {
    r.send(Ping {
        seq: 0,
        host_time_us: 0,
    });
}

/// Runs with a ping every 100 ms so the watchdog stays quiet, until `until` accepts a packet.
fn run_alive(
    r: &mut MockRobot,
    d: Duration,
    mut until: impl FnMut(&AnyPacket) -> bool,
) -> Option<Instant> {
    let end = r.now + d;
    while r.now < end {
        keep_alive(r);
        let slice = Duration::from_millis(100).min(end - r.now);
        if let Some(t) = r.run_until(slice, &mut until) {
            return Some(t);
        }
    }
    None
}

#[test]
fn straight_move_reaches_cruise_and_ends_at_its_distance() {
    let mut r = robot();
    r.send(ReflectorConfig {
        mode: ReflectorMode::Reduced as u8,
        period_ms: 5,
    });
    r.send(straight(0.2, 0.2, 1));
    let mut peak = 0.0f32;
    let mut done_at = None;
    let mut ticks_at_done = 0;
    let end = r.now + Duration::from_millis(3000);
    while r.now < end && done_at.is_none() {
        keep_alive(&mut r);
        r.run(Duration::from_millis(50), |t, p| match p {
            AnyPacket::ReducedState(s) => {
                let v = ({ s.wheels.left_mps } + { s.wheels.right_mps }) * 0.5;
                peak = peak.max(v);
            }
            AnyPacket::MoveFinished(m) if { m.move_id } == 1 => {
                done_at = Some(t);
            }
            _ => {}
        });
        if done_at.is_some() {
            ticks_at_done = r.fw.state().encoders.left_ticks;
        }
    }
    assert!(done_at.is_some(), "move never finished");
    assert!((peak - 0.2).abs() < 0.02, "cruise speed {peak}");
    // Let it coast to a stop, then measure the true travel.
    r.run(Duration::from_millis(200), |_, _| {});
    let x = r.fw.board().pose.x;
    assert!((x - 0.2).abs() < 0.002, "travelled {x} m for 0.2 m");
    // The move ends a little early by design and the wheels coast the rest of the way.
    let tick = tick_m(0.009, 40);
    let ticks = r.fw.state().encoders.left_ticks;
    assert!(
        ticks_at_done as f32 * tick < 0.2,
        "ended late: {ticks_at_done} ticks"
    );
    assert!(
        (ticks as f32 * tick - 0.2).abs() < 2.0 * tick,
        "{ticks} ticks after coasting"
    );
    assert!(r.fw.board().pose.theta.abs() < 2f64.to_radians());
}

#[test]
fn rotation_turns_the_requested_angle_in_place() {
    let mut r = robot();
    r.send(rotate(90.0, 0.1, 1));
    assert!(run_alive(&mut r, Duration::from_millis(3000), |p| finished(p, 1)).is_some());
    r.run(Duration::from_millis(200), |_, _| {});
    let pose = r.fw.board().pose;
    assert!(
        (pose.theta.to_degrees() - 90.0).abs() < 3.0,
        "{}",
        pose.theta.to_degrees()
    );
    assert!(pose.x.hypot(pose.y) < 0.002, "centre drifted {:?}", pose);
}

#[test]
fn square_walk_closes_on_itself() {
    let mut r = robot();
    for i in 0..4u16 {
        r.send(straight(0.1, 0.2, 2 * i + 1));
        r.send(rotate(90.0, 0.2, 2 * i + 2));
    }
    let mut finished_ids = Vec::new();
    let empty = run_alive(&mut r, Duration::from_millis(10_000), |p| {
        if let AnyPacket::MoveFinished(m) = p {
            finished_ids.push(({ m.move_id }, m.outcome));
        }
        matches!(p, AnyPacket::QueueEmpty(_))
    });
    assert!(empty.is_some(), "queue never emptied: {finished_ids:?}");
    let expected: Vec<(u16, u8)> = (1..=8).map(|i| (i, MoveOutcome::Completed as u8)).collect();
    assert_eq!(finished_ids, expected);
    r.run(Duration::from_millis(200), |_, _| {});
    let p = r.fw.board().pose;
    assert!(
        p.x.hypot(p.y) < 0.010,
        "ended {:.1} mm from start",
        p.x.hypot(p.y) * 1e3
    );
    let heading = (p.theta.to_degrees() - 360.0).rem_euclid(360.0);
    let err = heading.min(360.0 - heading);
    assert!(err < 5.0, "heading error {err}°");
}

#[test]
fn watchdog_stops_a_silent_link_at_its_timeout() {
    let mut r = robot();
    r.send(straight(1.0, 0.2, 1));
    let sent = r.now;
    let mut stop_at = None;
    let mut outcome = None;
    r.run(Duration::from_millis(700), |t, p| match p {
        AnyPacket::WatchdogStop(_) if stop_at.is_none() => stop_at = Some(t),
        AnyPacket::MoveFinished(m) => outcome = Some(m.outcome),
        _ => {}
    });
    let at = stop_at.expect("watchdog never fired") - sent;
    let timeout = Duration::from_millis(500);
    assert!(
        at > timeout && at <= timeout + r.dt,
        "fired after {} µs",
        at.as_micros()
    );
    assert_eq!(outcome, Some(MoveOutcome::Stopped as u8));
    assert_eq!(r.fw.board().pwm, (0, 0));
}

#[test]
fn line_following_converges_onto_the_tape() {
    let mut board = MockBoard::default();
    board.pose.y = 0.004; // robot 4 mm left of the tape
    let mut r = MockRobot::new(board);
    r.send(LineFollow {
        enable: 1,
        speed_mps: 0.2,
    });
    let mut lost = false;
    run_alive(&mut r, Duration::from_millis(2000), |p| {
        lost |= matches!(p, AnyPacket::LineEvent(e) if e.lost == 1);
        false
    });
    let p = r.fw.board().pose;
    assert!(!lost, "line lost");
    assert!(p.y.abs() < 0.0005, "still {:.2} mm off the tape", p.y * 1e3);
    assert!(p.x > 0.3, "followed only {:.3} m in 2 s at 0.2 m/s", p.x);
}

#[test]
fn hello_carries_the_layout_hash_and_settings_round_trip() {
    let mut r = robot();
    r.fw.on_link_connected(r.now);
    let hello = r.drain().into_iter().find_map(|p| match p {
        AnyPacket::Hello(h) => Some(h),
        _ => None,
    });
    let hello = hello.expect("no hello");
    assert_eq!({ hello.settings_hash }, SETTINGS_LAYOUT_HASH);
    assert_eq!(
        { hello.protocol_version },
        firmware::protocol::PROTOCOL_VERSION
    );

    let (off, len) = Settings::field("line_pid.kp").unwrap();
    r.send(SettingsUpdate::new(off as u16, &12.5f32.to_le_bytes()).unwrap());
    r.send(SettingsRead {
        offset: off as u16,
        len: len as u8,
    });
    let back = r.drain().into_iter().find_map(|p| match p {
        AnyPacket::SettingsData(d) => Some(d),
        _ => None,
    });
    let back = back.expect("no read-back");
    assert_eq!(back.bytes(), &12.5f32.to_le_bytes());
    assert_eq!({ r.fw.settings().line_pid.kp }, 12.5);

    // Half a field is refused with a typed answer, and nothing changes.
    let before = *r.fw.settings();
    r.send(SettingsUpdate::new(off as u16 + 1, &[1, 2]).unwrap());
    let nack = r.drain().into_iter().find_map(|p| match p {
        AnyPacket::Nack(n) => Some(n),
        _ => None,
    });
    assert_eq!(
        nack.map(|n| n.reason),
        Some(NackReason::BadSettingsRange as u8)
    );
    assert_eq!(*r.fw.settings(), before);
}

#[test]
fn saved_settings_survive_a_reboot_and_defaults_keep_the_identity() {
    let mut r = robot();
    let (off, _) = Settings::field("identity.robot_id").unwrap();
    r.send(SettingsUpdate::new(off as u16, &42u16.to_le_bytes()).unwrap());
    r.send(SettingsSave {});
    assert!(r
        .drain()
        .iter()
        .any(|p| matches!(p, AnyPacket::SettingsSaved(_))));
    let board = r.fw.board().clone();
    let mut rebooted = MockRobot::new(board);
    assert_eq!(rebooted.fw.robot_id(), 42);
    let (kp_off, _) = Settings::field("wheel_pid.kp").unwrap();
    rebooted.send(SettingsUpdate::new(kp_off as u16, &1.0f32.to_le_bytes()).unwrap());
    rebooted.send(SettingsRestoreDefaults {});
    assert_eq!(rebooted.fw.robot_id(), 42);
    assert_eq!({ rebooted.fw.settings().wheel_pid.kp }, {
        Settings::default().wheel_pid.kp
    });
}

#[test]
fn reflector_sends_reduced_state_at_the_configured_period() {
    let mut r = robot();
    r.send(ReflectorConfig {
        mode: ReflectorMode::Reduced as u8,
        period_ms: 10,
    });
    let mut times = Vec::new();
    let mut full = 0;
    r.run(Duration::from_millis(200), |t, p| match p {
        AnyPacket::ReducedState(_) => times.push(t.as_micros()),
        AnyPacket::State(_) => full += 1,
        _ => {}
    });
    assert_eq!(full, 0);
    assert!(
        (19..=21).contains(&times.len()),
        "{} packets in 200 ms",
        times.len()
    );
    for w in times.windows(2) {
        // Main-loop granularity (5 ms) bounds the jitter around the 10 ms period.
        assert!((w[1] - w[0]).abs_diff(10_000) <= 5_000, "{:?}", w);
    }
}

#[test]
fn a_late_main_loop_is_reported_as_an_overrun() {
    let mut r = robot();
    r.fw.tick(Instant::from_millis(1));
    r.fw.tick(Instant::from_millis(30));
    let overrun = r.drain().into_iter().find_map(|p| match p {
        AnyPacket::LoopOverrun(o) => Some(o.late_us),
        _ => None,
    });
    assert!(overrun.is_some_and(|us| us >= 20_000), "{overrun:?}");
    assert_eq!({ r.fw.state().link.overruns }, 1);
}

#[test]
fn slip_link_survives_chunking_and_counts_corrupt_frames() {
    let mut r = robot();
    let mut stream = Vec::new();
    let mut frame = [0u8; firmware::protocol::MAX_PACKET];
    let mut enc = [0u8; slip::max_encoded_len(firmware::protocol::MAX_PACKET)];
    for seq in 0..3u32 {
        let n = AnyPacket::from(Ping {
            seq,
            host_time_us: u64::from(seq),
        })
        .encode(&mut frame)
        .unwrap();
        if seq == 1 {
            frame[4] ^= 0x10; // corrupt the middle ping
        }
        let m = slip::encode(&frame[..n], &mut enc).unwrap();
        stream.extend_from_slice(&enc[..m]);
    }
    for chunk in stream.chunks(5) {
        r.fw.on_link_bytes(r.now, chunk);
    }
    let mut seqs = Vec::new();
    while let Some(p) = r.fw.pop_slip(&mut enc) {
        let mut d = slip::SlipDecoder::<300>::new();
        for &b in &enc[..p] {
            if let Ok(Some(f)) = d.push(b) {
                if let AnyPacket::Pong(pong) = Frame::parse(f).unwrap().packet() {
                    seqs.push(pong.seq);
                }
            }
        }
    }
    assert_eq!(seqs, vec![0, 2]);
    assert_eq!({ r.fw.state().link.rx_errors }, 1);
    assert_eq!({ r.fw.state().link.rx_packets }, 2);
}

#[test]
fn another_robots_ir_frame_is_reported_as_an_encounter() {
    let mut r = robot();
    r.run(Duration::from_millis(10), |_, _| {});
    assert!(
        !r.fw.board().ir_sent.is_empty(),
        "robot transmits IR frames"
    );
    let own = r.fw.robot_id();
    assert!(r
        .fw
        .board()
        .ir_sent
        .iter()
        .all(|(_, _, f)| f.robot_id == own));
    let frame = IrFrame {
        robot_id: 9,
        led: 1,
        power: 2,
        message: 0,
    };
    r.fw.on_ir_frame(r.now, Side::Front, frame);
    let mut seen = None;
    r.run(Duration::from_millis(50), |_, p| {
        if let AnyPacket::RobotEncountered(e) = p {
            seen = Some(e);
        }
    });
    let e = seen.expect("no encounter reported");
    assert_eq!({ e.robot_id }, 9);
    assert_eq!(e.side, Side::Front as u8);
    assert_eq!({ e.relative_heading_deg }, 180, "its centre LED faces us");
}

#[test]
fn stop_clears_the_queue_and_halts_the_motors() {
    let mut r = robot();
    r.send(straight(0.5, 0.2, 1));
    r.send(straight(0.5, 0.2, 2));
    r.run(Duration::from_millis(100), |_, _| {});
    assert_ne!(r.fw.board().pwm, (0, 0));
    r.send(Stop { keep_from: 0 });
    let outcomes = finished_outcomes(&mut r);
    let stopped = MoveOutcome::Stopped as u8;
    assert_eq!(outcomes, vec![(1, stopped), (2, stopped)]);
    assert_eq!(r.fw.board().pwm, (0, 0));
}

#[test]
fn moves_sent_again_run_once_in_order_and_a_stop_keeps_what_came_after_it() {
    let mut r = robot();
    let taken = |r: &MockRobot| r.fw.state().locomotion.last_move_id;
    r.send(straight(0.3, 0.2, 1));
    // Move 2 was lost on the way: 3 waits for it, and a copy of 1 is not run twice.
    r.send(straight(0.3, 0.2, 3));
    r.send(straight(0.3, 0.2, 1));
    r.run(Duration::from_millis(20), |_, _| {});
    assert_eq!((taken(&r), r.fw.state().locomotion.queue_len), (1, 1));
    r.send(rotate(90.0, 0.1, 2));
    r.send(straight(0.3, 0.2, 3));
    r.run(Duration::from_millis(20), |_, _| {});
    assert_eq!((taken(&r), r.fw.state().locomotion.queue_len), (3, 3));
    // Moves 4 and 5 never arrived; the stop keeps 6 on, and says 4 and 5 are cleared.
    r.send(Stop { keep_from: 6 });
    r.send(straight(0.1, 0.2, 6));
    r.send(Stop { keep_from: 6 });
    let outcomes = finished_outcomes(&mut r);
    let (stopped, cleared) = (MoveOutcome::Stopped as u8, MoveOutcome::Cleared as u8);
    assert_eq!(
        outcomes,
        [
            (4, cleared),
            (5, cleared),
            (1, stopped),
            (2, stopped),
            (3, stopped)
        ]
    );
    r.run(Duration::from_millis(20), |_, _| {});
    assert_eq!((taken(&r), r.fw.state().locomotion.queue_len), (6, 1));
    let mut done = false;
    run_alive(&mut r, Duration::from_millis(3000), |p| {
        done |= finished(p, 6);
        done
    });
    assert!(done, "the move sent after the stop ran");
}

#[test]
fn events_are_stamped_numbered_and_sent_again_when_asked() {
    let mut r = robot();
    r.run(Duration::from_millis(40), |_, _| {});
    r.send(straight(0.02, 0.1, 1));
    r.send(straight(0.02, 0.1, 2));
    let mut events: Vec<(u16, u32, u16)> = Vec::new();
    run_alive(&mut r, Duration::from_millis(2000), |p| {
        if let AnyPacket::MoveFinished(m) = p {
            events.push((m.seq, m.at_ms, m.move_id));
        }
        events.len() == 2
    });
    assert_eq!(events.len(), 2, "{events:?}");
    let (first, second) = (events[0], events[1]);
    assert!(
        second.0 > first.0 && second.1 > first.1 && first.1 >= 40,
        "{events:?}"
    );
    let newest = r.fw.state().link.events_sent;
    assert!(newest >= second.0, "the state names the newest event");
    r.send(EventReplay { from_seq: first.0 });
    let again: Vec<(u16, u32, u16)> = r
        .drain()
        .into_iter()
        .filter_map(|p| match p {
            AnyPacket::MoveFinished(m) => Some((m.seq, m.at_ms, m.move_id)),
            _ => None,
        })
        .collect();
    assert_eq!(again, events, "the same events, as first sent");
}

#[test]
fn encoder_counts_follow_the_wheels_through_bang_bang_steering() {
    // Line following over a poorly seen mark swings the inner wheel between a slow forward and a
    // small backward set-point every few tens of milliseconds. The single-channel encoders must
    // still count each wheel's true travel: a wrong direction here becomes a phantom heading (it
    // once counted a metre forwards as a metre backwards).
    let tick = f64::from(tick_m(0.009, 40));
    for (fast, on_ms, off_ms) in [
        (0.06, 40, 60),
        (0.03, 40, 60),
        (0.03, 20, 50),
        (0.03, 10, 100),
    ] {
        let mut r = robot();
        for k in 0..60 {
            let (left_mps, ms) = if k % 2 == 0 {
                (fast, on_ms)
            } else {
                (-0.0075, off_ms)
            };
            r.send(WheelSpeeds {
                left_mps,
                right_mps: 0.06,
            });
            run_alive(&mut r, Duration::from_millis(ms), |_| false);
        }
        r.send(Stop { keep_from: 0 });
        run_alive(&mut r, Duration::from_millis(300), |_| false);
        let e = r.fw.state().encoders;
        for (k, counted) in [e.left_ticks, e.right_ticks].into_iter().enumerate() {
            let counted = f64::from(counted) * tick;
            let travel = r.fw.board().wheels[k].travel_m;
            // A wheel creeping slower than the speed meter resolves may lose a pulse at a
            // reversal; over 60 reversals that is a few pulses, not a runaway.
            assert!(
                (counted - travel).abs() < 10.0 * tick,
                "{fast} m/s for {on_ms} ms, -0.0075 m/s for {off_ms} ms: wheel {k} rolled {:.1} mm, \
                 its encoder counted {:.1} mm",
                travel * 1e3,
                counted * 1e3
            );
        }
    }
}

#[test]
fn a_detour_of_turns_both_ways_ends_where_its_geometry_says() {
    // Around an obstacle on the right: step back, turn right, aside, left, pass, left, back, right.
    // Moves go one at a time, each after the last one finished, as a host sends them.
    let plan: [(bool, f32); 8] = [
        (false, -0.01),
        (true, -90.0),
        (false, 0.05),
        (true, 90.0),
        (false, 0.125),
        (true, 90.0),
        (false, 0.05),
        (true, -90.0),
    ];
    let mut r = robot();
    for (id, (rot, v)) in plan.into_iter().enumerate() {
        let id = id as u16 + 1;
        if rot {
            r.send(rotate(v, 0.08, id));
        } else {
            r.send(straight(v, 0.08, id));
        }
        assert!(
            run_alive(&mut r, Duration::from_millis(5000), |p| finished(p, id)).is_some(),
            "move {id} did not finish"
        );
    }
    r.run(Duration::from_millis(200), |_, _| {});
    let p = r.fw.board().pose;
    let heading = p.theta.to_degrees();
    assert!(heading.abs() < 5.0, "heading {heading:.1}°");
    assert!(
        (p.x - 0.115).hypot(p.y) < 0.01,
        "ended at ({:.1}, {:.1}) mm, not (115, 0)",
        p.x * 1e3,
        p.y * 1e3
    );
}

#[test]
fn a_move_never_drives_a_wheel_backwards_against_its_counted_direction() {
    // A wheel still turning backwards when a forward move starts (the coast of a turn the meter
    // no longer resolves, a push) counts its pulses forwards, so it reads faster than its target.
    // Braking it then drove both wheels backwards while the odometry counted them forwards.
    for backwards_mps in [0.1f32, 0.3, 0.6] {
        let mut r = robot();
        r.fw.board_mut().wheels[1].speed_mps = -backwards_mps;
        r.send(straight(0.08, 0.1, 1));
        assert!(
            run_alive(&mut r, Duration::from_millis(3000), |p| finished(p, 1)).is_some(),
            "the move never finished ({backwards_mps} m/s backwards)"
        );
        r.run(Duration::from_millis(300), |_, _| {});
        let [left, right] = r.fw.board().wheels.map(|w| w.travel_m);
        // The right wheel's unseen backward coast is lost to a single-channel encoder; what
        // matters is that neither wheel is then driven backwards.
        assert!(
            (left - 0.08).abs() < 0.002 && right > 0.0,
            "{backwards_mps} m/s backwards: the wheels rolled {:.1} and {:.1} mm for 80 mm",
            left * 1e3,
            right * 1e3
        );
    }
}

/// Our own light coming back on `side` at power `power`: a surface that close.
fn reflection(r: &mut MockRobot, side: Side, power: u8) {
    let own = r.fw.robot_id();
    let frame = IrFrame {
        robot_id: own,
        led: 0,
        power,
        message: 0,
    };
    r.fw.on_ir_frame(r.now, side, frame);
}

#[test]
fn the_reflex_stops_a_drive_into_something_close_and_lets_the_robot_turn_away() {
    let mut r = robot();
    assert_eq!(r.fw.settings().reflex.power_level, 1, "on by default");
    r.send(straight(0.5, 0.1, 1));
    r.send(straight(0.5, 0.1, 2));
    run_alive(&mut r, Duration::from_millis(300), |_| false);
    let before = r.fw.board().pose;
    assert!(before.x > 0.005, "it drives: {before:?}");
    // Something within the weakest power's reach ahead.
    reflection(&mut r, Side::Front, 1);
    let mut blocked = Vec::new();
    let mut reflex = None;
    run_alive(&mut r, Duration::from_millis(200), |p| {
        match p {
            AnyPacket::MoveFinished(m) => blocked.push((m.move_id, m.outcome)),
            AnyPacket::Reflex(x) => reflex = Some(*x),
            _ => {}
        }
        false
    });
    let b = MoveOutcome::Blocked as u8;
    assert_eq!(
        blocked,
        vec![(1, b), (2, b)],
        "both queued moves end blocked"
    );
    let x = reflex.expect("the reflex is reported");
    assert_eq!((x.side, x.power_level), (Side::Front as u8, 1));
    assert_eq!(r.fw.board().pwm, (0, 0));
    let stopped = r.fw.board().pose;
    assert!(
        stopped.x - before.x < 0.01,
        "it stopped within a centimetre: {before:?} -> {stopped:?}"
    );
    // Still close ahead: a turn on the spot and a move backwards go on, a move forwards does not.
    reflection(&mut r, Side::Front, 1);
    r.send(rotate(90.0, 0.05, 3));
    r.send(straight(-0.02, 0.05, 4));
    let mut done = Vec::new();
    run_alive(&mut r, Duration::from_millis(3000), |p| {
        if let AnyPacket::MoveFinished(m) = p {
            done.push((m.move_id, m.outcome));
        }
        done.len() == 2
    });
    let c = MoveOutcome::Completed as u8;
    assert_eq!(done, vec![(3, c), (4, c)]);
    reflection(&mut r, Side::Front, 1);
    r.send(straight(0.1, 0.1, 5));
    let mut fifth = None;
    run_alive(&mut r, Duration::from_millis(300), |p| {
        if let AnyPacket::MoveFinished(m) = p {
            fifth = Some(m.outcome);
        }
        fifth.is_some()
    });
    assert_eq!(fifth, Some(b));
}

#[test]
fn the_reflex_forgets_what_the_robot_has_turned_away_from() {
    // A robot stopped by the box turns away from it and drives on: the reports remember the
    // box for a second, the receivers stop seeing it within a transmit cycle of the turn.
    let mut r = robot();
    reflection(&mut r, Side::Front, 1);
    r.send(rotate(-90.0, 0.08, 1));
    r.send(straight(0.03, 0.08, 2));
    let mut done = Vec::new();
    let mut reflexes = 0;
    run_alive(&mut r, Duration::from_millis(3000), |p| {
        match p {
            AnyPacket::MoveFinished(m) => done.push((m.move_id, m.outcome)),
            AnyPacket::Reflex(_) => reflexes += 1,
            _ => {}
        }
        done.len() == 2
    });
    let c = MoveOutcome::Completed as u8;
    assert_eq!(done, vec![(1, c), (2, c)], "the drive away is not stopped");
    assert_eq!(reflexes, 0);
}

#[test]
fn a_robot_whose_reflex_is_off_closes_in_on_what_it_sees() {
    let mut r = robot();
    let (offset, _) = Settings::field("reflex.power_level").expect("a setting");
    r.send(SettingsUpdate::new(offset as u16, &[0]).expect("fits"));
    run_alive(&mut r, Duration::from_millis(20), |_| false);
    assert_eq!(r.fw.settings().reflex.power_level, 0);
    r.send(straight(0.05, 0.1, 1));
    let mut outcome = None;
    let mut reflexes = 0;
    // A box held against the front the whole way: a push.
    for _ in 0..40 {
        reflection(&mut r, Side::Front, 1);
        keep_alive(&mut r);
        r.run_until(Duration::from_millis(50), |p| {
            match p {
                AnyPacket::MoveFinished(m) => outcome = Some(m.outcome),
                AnyPacket::Reflex(_) => reflexes += 1,
                _ => {}
            }
            false
        });
        if outcome.is_some() {
            break;
        }
    }
    assert_eq!(outcome, Some(MoveOutcome::Completed as u8));
    assert_eq!(reflexes, 0);
}
