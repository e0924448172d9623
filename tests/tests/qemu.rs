//! The firmware on the STM32F405 in QEMU, driven over the emulated USART1: hello, ping, settings,
//! the state reflector's period, a queued move closing on the stand-in wheels, corrupt input, and
//! the link watchdog.
//!
//! Times are the robot's own (state `uptime_ms`, pong `robot_time_us`): QEMU runs with
//! `-icount shift=3,sleep=off`, whose emulated clock is unrelated to the wall clock.

use std::time::{Duration, Instant};

use pocketfleet_tests::{
    build_firmware, image_size, skip_without_qemu, ImageSize, QemuRobot, UartLink,
};
use protocol::packets::{
    self, AnyPacket, MoveOutcome, ReflectorMode, SettingsRead, SettingsUpdate, StraightMovement,
    WheelSpeeds,
};
use protocol::settings::Settings;
use protocol::state::RobotState;
use protocol::{Layout, PROTOCOL_VERSION, SETTINGS_LAYOUT_HASH};

/// Wall-clock limit for one wait; generous for a loaded CI machine.
const WAIT: Duration = Duration::from_secs(30);
const FLASH_LIMIT: u64 = 1024 * 1024;
const RAM_START: u32 = 0x2000_0000;
const RAM_LIMIT: u32 = 128 * 1024;

fn firmware() -> std::path::PathBuf {
    build_firmware().unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn release_image_fits_the_stm32f405() {
    if skip_without_qemu("release_image_fits_the_stm32f405") {
        return;
    }
    let elf = std::fs::read(firmware()).expect("read the firmware ELF");
    let ImageSize { flash, ram } = image_size(&elf, RAM_START, RAM_LIMIT).expect("parse ELF");
    eprintln!(
        "firmware image: flash {flash} B ({:.1} % of 1 MiB), static RAM {ram} B ({:.1} % of 128 KiB)",
        flash as f64 * 100.0 / FLASH_LIMIT as f64,
        ram as f64 * 100.0 / f64::from(RAM_LIMIT),
    );
    assert!(flash <= FLASH_LIMIT, "flash {flash} B exceeds 1 MiB");
    assert!(ram <= u64::from(RAM_LIMIT), "RAM {ram} B exceeds 128 KiB");
}

fn state(p: &AnyPacket) -> Option<RobotState> {
    match p {
        AnyPacket::State(s) => Some(*s),
        _ => None,
    }
}

fn settings_field(path: &str) -> (u16, usize) {
    let (offset, len) = Settings::field(path).unwrap_or_else(|| panic!("no field {path}"));
    (offset as u16, len)
}

/// Writes a settings field and checks the robot's read-back.
fn write_setting(link: &mut UartLink, path: &str, value: &[u8]) {
    let (offset, len) = settings_field(path);
    assert_eq!(len, value.len(), "{path} is {len} bytes");
    link.send(SettingsUpdate::new(offset, value).unwrap())
        .unwrap();
    link.send(SettingsRead {
        offset,
        len: len as u8,
    })
    .unwrap();
    let data = link
        .wait_for(path, WAIT, |_, p| match p {
            AnyPacket::SettingsData(d) if d.offset == offset => Some(d),
            AnyPacket::Nack(n) => panic!("settings refused: {:?}", { n.reason }),
            _ => None,
        })
        .unwrap();
    assert_eq!(data.bytes(), value, "{path} read back");
}

#[test]
fn robot_in_qemu_speaks_the_protocol_moves_and_stops_on_silence() {
    if skip_without_qemu("robot_in_qemu_speaks_the_protocol_moves_and_stops_on_silence") {
        return;
    }
    let elf = firmware();
    let started = Instant::now();
    let mut robot = QemuRobot::start(&elf, WAIT).unwrap_or_else(|e| panic!("{e}"));
    let link = &mut robot.link;

    // Boot: the hello names this protocol and settings layout.
    let hello = link
        .wait_for("hello", WAIT, |_, p| match p {
            AnyPacket::Hello(h) => Some(h),
            _ => None,
        })
        .unwrap();
    assert_eq!({ hello.protocol_version }, PROTOCOL_VERSION);
    assert_eq!({ hello.settings_hash }, SETTINGS_LAYOUT_HASH);
    assert_eq!({ hello.state_hash }, RobotState::LAYOUT.hash);
    assert_eq!(usize::from(hello.settings_size), Settings::SIZE);

    // Ping: the pong echoes the sequence number and host time.
    link.send(packets::Ping {
        seq: 1,
        host_time_us: 4242,
    })
    .unwrap();
    let pong = link
        .wait_for("pong 1", WAIT, |_, p| match p {
            AnyPacket::Pong(p) if p.seq == 1 => Some(p),
            _ => None,
        })
        .unwrap();
    assert_eq!({ pong.host_time_us }, 4242);

    // Settings: write the reflector period, read it back; the reflector then runs at it.
    let period_ms: u16 = 20;
    write_setting(link, "reflector.period_ms", &period_ms.to_le_bytes());
    let (mode_offset, _) = settings_field("reflector.mode");
    link.send(SettingsRead {
        offset: mode_offset,
        len: 1,
    })
    .unwrap();
    let mode = link
        .wait_for("reflector mode", WAIT, |_, p| match p {
            AnyPacket::SettingsData(d) if d.offset == mode_offset => Some(d.bytes()[0]),
            _ => None,
        })
        .unwrap();
    assert_eq!(mode, ReflectorMode::Full as u8);

    // State period, by the robot's clock: 30 intervals, each within ±10 %.
    let mut stamps = Vec::new();
    link.wait_for("30 state intervals", WAIT, |_, p| {
        let s = state(&p)?;
        stamps.push(s.uptime_ms);
        (stamps.len() > 31).then_some(())
    })
    .unwrap();
    // The first packet after the update may come off the old grid.
    let intervals: Vec<u32> = stamps[1..].windows(2).map(|w| w[1] - w[0]).collect();
    let lo = f64::from(period_ms) * 0.9;
    let hi = f64::from(period_ms) * 1.1;
    for &i in &intervals {
        assert!(
            (lo..=hi).contains(&f64::from(i)),
            "state interval {i} ms outside {period_ms} ms ±10 %: {intervals:?}"
        );
    }
    let mean = f64::from(stamps[stamps.len() - 1] - stamps[1]) / intervals.len() as f64;
    eprintln!(
        "state period: configured {period_ms} ms, measured mean {mean:.2} ms, min {} max {} ms (robot clock)",
        intervals.iter().min().unwrap(),
        intervals.iter().max().unwrap()
    );

    // Corrupt input is counted and dropped; the robot keeps answering.
    let before = link
        .wait_for("a state", WAIT, |_, p| state(&p))
        .unwrap()
        .link
        .rx_errors;
    let mut bad_checksum = [0u8; 64];
    let n = AnyPacket::from(packets::Ping {
        seq: 9,
        host_time_us: 0,
    })
    .encode(&mut bad_checksum)
    .unwrap();
    bad_checksum[0] = bad_checksum[0].wrapping_add(1);
    let mut garbage = vec![
        0xC0, 0x01, 0x02, 0xC0, 0xDB, 0x00, 0xC0, 0x00, 0xEE, 0x03, 0xC0,
    ];
    garbage.extend(std::iter::repeat_n(0x55, 600));
    garbage.push(0xC0);
    garbage.extend(protocol::slip::encode_iter(&bad_checksum[..n]));
    link.send_raw(&garbage).unwrap();
    link.send(packets::Ping {
        seq: 2,
        host_time_us: 0,
    })
    .unwrap();
    link.wait_for("pong 2 after corrupt input", WAIT, |_, p| match p {
        AnyPacket::Pong(p) if p.seq == 2 => Some(()),
        _ => None,
    })
    .unwrap();
    let after = link
        .wait_for("a state after corrupt input", WAIT, |_, p| state(&p))
        .unwrap()
        .link
        .rx_errors;
    assert!(
        after >= before + 4,
        "rx_errors went from {before} to {after} after five corrupt frames"
    );

    // The robot feeds its watchdog from answers to its state packets; a host descheduled for long
    // on a loaded machine must not stop the move, so the timeout is long until the watchdog part.
    let watchdog_ms = Settings::default().watchdog.timeout_ms;
    write_setting(link, "watchdog.timeout_ms", &10_000u16.to_le_bytes());

    // A straight move closes on the stand-in wheels and ends with the locomotion's own event.
    let start = link
        .wait_for("a state before the move", WAIT, |_, p| state(&p))
        .unwrap();
    let distance_m = 0.10f32;
    link.send(StraightMovement {
        distance_m,
        speed_mps: 0.2,
        move_id: 1,
    })
    .unwrap();
    let mut seq = 100;
    let mut last_state = start;
    let outcome = link
        .wait_for("move 1 finished", WAIT, |tx, p| {
            match p {
                // Keep the watchdog fed at the robot's pace, whatever the wall clock does.
                AnyPacket::State(s) => {
                    last_state = s;
                    seq += 1;
                    tx.send(packets::Ping {
                        seq,
                        host_time_us: 0,
                    });
                }
                AnyPacket::MoveFinished(m) if m.move_id == 1 => return Some(m.outcome),
                AnyPacket::WatchdogStop(_) => panic!("watchdog stopped a fed robot"),
                AnyPacket::Nack(n) => panic!("move refused: {:?}", { n.reason }),
                _ => {}
            }
            None
        })
        .unwrap();
    assert_eq!(outcome, MoveOutcome::Completed as u8);
    let finished_ms = last_state.uptime_ms;
    // The robot coasts onto its target; measure once both wheels have stopped.
    let rest = link
        .wait_for("wheels at rest after the move", WAIT, |tx, p| {
            let s = state(&p)?;
            seq += 1;
            tx.send(packets::Ping {
                seq,
                host_time_us: 0,
            });
            (s.wheels.left_mps == 0.0 && s.wheels.right_mps == 0.0).then_some(s)
        })
        .unwrap();
    let g = Settings::default().geometry;
    let tick_m = std::f32::consts::PI * g.wheel_diameter_m / f32::from(g.ticks_per_rev);
    let travelled = |a: i32, b: i32| (b - a) as f32 * tick_m;
    let left = travelled(start.encoders.left_ticks, rest.encoders.left_ticks);
    let right = travelled(start.encoders.right_ticks, rest.encoders.right_ticks);
    eprintln!(
        "move: {distance_m} m commanded, wheels travelled {left:.4} m / {right:.4} m, \
         finished after {} ms (robot clock)",
        finished_ms - { start.uptime_ms }
    );
    for (wheel, d) in [("left", left), ("right", right)] {
        assert!(
            (d - distance_m).abs() <= 0.05 * distance_m,
            "{wheel} wheel travelled {d} m for a {distance_m} m move"
        );
    }

    // Watchdog: drive, fall silent, and the robot stops itself after the configured timeout.
    write_setting(link, "watchdog.timeout_ms", &watchdog_ms.to_le_bytes());
    link.send(WheelSpeeds {
        left_mps: 0.1,
        right_mps: 0.1,
    })
    .unwrap();
    link.wait_for("wheels driving", WAIT, |tx, p| {
        let s = state(&p)?;
        seq += 1;
        tx.send(packets::Ping {
            seq,
            host_time_us: 0,
        });
        (s.wheels.left_pwm > 0 && s.wheels.right_pwm > 0 && s.wheels.left_mps > 0.05).then_some(())
    })
    .unwrap();
    let last_seq = seq + 1_000;
    link.send(packets::Ping {
        seq: last_seq,
        host_time_us: 0,
    })
    .unwrap();
    let mut fed_us = None;
    let mut watchdog_silent_ms = None;
    let stopped = link
        .wait_for("motors stopped by the watchdog", WAIT, |_, p| {
            match p {
                AnyPacket::Pong(p) if p.seq == last_seq => fed_us = Some(p.robot_time_us),
                AnyPacket::WatchdogStop(w) => watchdog_silent_ms = Some(w.silent_ms),
                AnyPacket::State(s)
                    if fed_us.is_some() && s.wheels.left_pwm == 0 && s.wheels.right_pwm == 0 =>
                {
                    return Some(s)
                }
                _ => {}
            }
            None
        })
        .unwrap();
    let silent_ms = watchdog_silent_ms.expect("no watchdog-stop event before the motors stopped");
    let fed_ms = fed_us.unwrap() as f64 / 1000.0;
    let stop_ms = f64::from(stopped.uptime_ms) - fed_ms;
    let timeout_ms = f64::from(watchdog_ms);
    eprintln!(
        "watchdog: last host packet at {fed_ms:.1} ms, motors off in the state of {} ms: \
         {stop_ms:.1} ms of silence; the robot's stop event says {silent_ms} ms \
         (timeout {timeout_ms} ms, state period {period_ms} ms)",
        { stopped.uptime_ms }
    );
    assert!(
        stop_ms >= timeout_ms && stop_ms <= timeout_ms + f64::from(period_ms) + 2.0,
        "motors stopped {stop_ms} ms after the last host packet; timeout {timeout_ms} ms"
    );
    let at_rest = link
        .wait_for("wheel speeds zero after the watchdog", WAIT, |_, p| {
            let s = state(&p)?;
            (s.wheels.left_mps == 0.0 && s.wheels.right_mps == 0.0).then_some(s)
        })
        .unwrap();
    assert_eq!({ at_rest.locomotion.mode }, packets::DriveMode::Idle as u8);

    assert_eq!(
        link.bad_frames, 0,
        "the robot sent frames that do not decode"
    );
    assert!(robot.exit_status().is_none(), "QEMU ended during the test");
    eprintln!(
        "QEMU robot test: {:.1} s wall, {:.2} s robot time",
        started.elapsed().as_secs_f64(),
        f64::from(at_rest.uptime_ms) / 1000.0
    );
}
