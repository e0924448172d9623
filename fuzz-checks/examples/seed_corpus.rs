//! Writes the seed inputs of the fuzz corpora into `fuzz/corpus/<target>/seed-*`: frames of every
//! packet type as the protocol crate encodes them, SLIP streams of them, host command sequences
//! (including the settings writes a hostile host would send), and the shipped world files.
//!
//! Run with `cargo run -p fuzz-checks --example seed_corpus`; recordings are made by the
//! coordinator itself (see `fuzz/README.md`). Re-running overwrites the seeds with the same bytes.

use std::path::{Path, PathBuf};

use protocol::frame::{byte_sum, checksum_for};
use protocol::packets::*;
use protocol::settings::Settings;
use protocol::state::RobotState;
use protocol::{AnyPacket, PacketType, MAX_PACKET};

fn main() -> std::io::Result<()> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus");
    let frames = frames();
    for (name, f) in &frames {
        write(&root, "frame", name, f)?;
        // Check the seed now, so a broken seed never lands in the corpus.
        fuzz_checks::frame::check(f);
    }

    // One stream of every frame, and a few short ones with uneven chunking.
    let all: Vec<u8> = frames.iter().flat_map(|(_, f)| slip(f)).collect();
    write(&root, "slip", "all-frames", &plan(&[5, 63, 0, 17], &all))?;
    for (name, f) in frames.iter().step_by(5) {
        let mut s = slip(f);
        s.extend(slip(f));
        write(&root, "slip", name, &plan(&[0, 3], &s))?;
    }

    for (name, input) in host_sessions() {
        fuzz_checks::firmware_link::check(&input);
        write(&root, "firmware_link", &name, &input)?;
    }

    let worlds = Path::new(env!("CARGO_MANIFEST_DIR")).join("../world/worlds");
    for entry in std::fs::read_dir(worlds)? {
        let path = entry?.path();
        let name = path.file_stem().unwrap_or_default().to_string_lossy();
        write(&root, "world_file", &name, &std::fs::read(&path)?)?;
    }
    Ok(())
}

fn write(root: &Path, target: &str, name: &str, data: &[u8]) -> std::io::Result<()> {
    let dir: PathBuf = root.join(target);
    std::fs::create_dir_all(&dir)?;
    std::fs::write(dir.join(format!("seed-{name}")), data)
}

/// A [`fuzz_checks::Chunked`] input: the plan bytes, then the data.
fn plan(plan: &[u8], data: &[u8]) -> Vec<u8> {
    assert!((1..=8).contains(&plan.len()));
    let mut out = vec![(plan.len() - 1) as u8];
    out.extend_from_slice(plan);
    out.extend_from_slice(data);
    out
}

fn encode(p: impl Into<AnyPacket>) -> Vec<u8> {
    let mut buf = [0u8; MAX_PACKET];
    let n = p.into().encode(&mut buf).expect("every packet fits");
    buf[..n].to_vec()
}

fn slip(frame: &[u8]) -> Vec<u8> {
    protocol::slip::encode_iter(frame).collect()
}

fn settings_write(path: &str, bytes: &[u8]) -> SettingsUpdate {
    let (offset, len) = Settings::field(path).unwrap_or_else(|| panic!("no field {path}"));
    assert_eq!(len, bytes.len(), "{path}");
    SettingsUpdate::new(offset as u16, bytes).expect("a field fits a chunk")
}

/// Every packet type: a realistic value, and one whose payload is a byte pattern.
fn frames() -> Vec<(String, Vec<u8>)> {
    let settings = Settings::default();
    let mut state = RobotState::default();
    state.encoders.left_ticks = -1234;
    state.wheels.left_mps = 0.21;
    state.line.darkness[3] = 900;
    let real: Vec<AnyPacket> = vec![
        state.into(),
        state.reduced().into(),
        Hello::new(&settings, [0, 1, 0]).into(),
        Pong {
            seq: 3,
            host_time_us: 1_000,
            robot_time_us: 2_000,
        }
        .into(),
        SettingsData::new(4, settings.read(4, 12).unwrap_or(&[]))
            .unwrap()
            .into(),
        Log::new(LogLevel::Info, "boot", "robot 1 up").into(),
        Nack {
            packet_type: 0x40,
            reason: NackReason::QueueFull as u8,
            field_offset: Nack::NO_FIELD,
        }
        .into(),
        MoveFinished {
            at_ms: 12_345,
            seq: 3,
            move_id: 7,
            outcome: 0,
        }
        .into(),
        StraightMovement {
            distance_m: 0.2,
            speed_mps: 0.1,
            move_id: 1,
        }
        .into(),
        RotationMovement {
            angle_deg: 90.0,
            speed_mps: 0.1,
            move_id: 2,
        }
        .into(),
        ArcMovement {
            radius_m: 0.1,
            angle_deg: -45.0,
            speed_mps: 0.1,
            move_id: 3,
        }
        .into(),
        settings_write("reflector.period_ms", &20u16.to_le_bytes()).into(),
        Ping {
            seq: 9,
            host_time_us: 123_456,
        }
        .into(),
    ];
    let mut out: Vec<(String, Vec<u8>)> = real
        .into_iter()
        .map(|p| (format!("{:?}", p.packet_type()), encode(p)))
        .collect();
    for &t in PacketType::ALL {
        let (_, max) = t.payload_range();
        let mut f = vec![0u8, t as u8, max as u8];
        f.extend((0..max).map(|i| (i * 37 + 11) as u8));
        f[0] = checksum_for(byte_sum(&f[1..])) as u8;
        let decoded = protocol::decode(&f).expect("a full-size frame of a known type");
        out.push((format!("{t:?}-pattern"), encode(decoded)));
    }
    out
}

/// Host command sequences for `firmware_link`: raw SLIP streams, and framed-mode inputs whose
/// pieces are `[type, payload...]`.
fn host_sessions() -> Vec<(String, Vec<u8>)> {
    let commands: Vec<(&str, AnyPacket)> = vec![
        ("hello", HelloRequest {}.into()),
        (
            "straight",
            StraightMovement {
                distance_m: 0.05,
                speed_mps: 0.1,
                move_id: 1,
            }
            .into(),
        ),
        (
            "rotate",
            RotationMovement {
                angle_deg: 30.0,
                speed_mps: 0.1,
                move_id: 2,
            }
            .into(),
        ),
        (
            "arc",
            ArcMovement {
                radius_m: 0.05,
                angle_deg: 20.0,
                speed_mps: 0.1,
                move_id: 3,
            }
            .into(),
        ),
        ("clear", ClearQueue { keep_from: 3 }.into()),
        ("stop", Stop { keep_from: 0 }.into()),
        ("replay", EventReplay { from_seq: 1 }.into()),
        (
            "wheels",
            WheelSpeeds {
                left_mps: 0.1,
                right_mps: -0.1,
            }
            .into(),
        ),
        (
            "power",
            MotorPower {
                left_pwm: 400,
                right_pwm: 300,
            }
            .into(),
        ),
        (
            "follow",
            LineFollow {
                enable: 1,
                speed_mps: 0.1,
            }
            .into(),
        ),
        (
            "calibrate",
            LineCalibration {
                action: CalibrationAction::Start as u8,
            }
            .into(),
        ),
        (
            "led",
            SetLed {
                red: 1,
                green: 2,
                blue: 3,
            }
            .into(),
        ),
        ("ir", IrMessage { message: 0x1234 }.into()),
        ("read", SettingsRead { offset: 0, len: 32 }.into()),
        ("save", SettingsSave {}.into()),
        ("restore", SettingsRestoreDefaults {}.into()),
        (
            "reflector",
            ReflectorConfig {
                mode: ReflectorMode::Full as u8,
                period_ms: 1,
            }
            .into(),
        ),
        (
            "log-debug",
            settings_write("log.level", &[LogLevel::Debug as u8]).into(),
        ),
        (
            "period-zero",
            settings_write("scheduler.main_period_us", &0u32.to_le_bytes()).into(),
        ),
        (
            "ticks-zero",
            settings_write("geometry.ticks_per_rev", &0u16.to_le_bytes()).into(),
        ),
        (
            "diameter-nan",
            settings_write("geometry.wheel_diameter_m", &f32::NAN.to_le_bytes()).into(),
        ),
        (
            "ping",
            Ping {
                seq: 1,
                host_time_us: 2,
            }
            .into(),
        ),
    ];
    let mut out = Vec::new();
    for (name, p) in &commands {
        // Raw: the command, ten ticks, the command again split in two.
        let s = slip(&encode(*p));
        let mut stream = s.clone();
        stream.extend_from_slice(&s);
        let first = (s.len() - 1).min(63) as u8 | (2 << 6);
        out.push((format!("raw-{name}"), plan(&[first, 1, 63], &stream)));

        // Framed: [type, payload...] sized by the plan, fifty ticks after.
        let f = encode(*p);
        let mut piece = vec![f[1]];
        piece.extend_from_slice(&f[3..]);
        let size = (piece.len() - 1) as u8 | (3 << 6);
        let mut input = vec![0x80, size];
        input.extend_from_slice(&piece);
        out.push((format!("framed-{name}"), input));
    }
    // The ten-byte update: `len` says 32, the frame carries 4 bytes.
    let mut f = encode(SettingsUpdate::new(0, &[1, 2, 3, 4]).unwrap());
    f[5] = 32;
    f[0] = checksum_for(byte_sum(&f[1..])) as u8;
    let s = slip(&f);
    out.push(("raw-short-update".into(), plan(&[63], &s)));
    // A session: move, stream state, ping, in one framed input.
    let session: Vec<Vec<u8>> = ["straight", "reflector", "ping"]
        .iter()
        .map(|n| {
            let p = commands.iter().find(|(c, _)| c == n).unwrap().1;
            let f = encode(p);
            let mut piece = vec![f[1]];
            piece.extend_from_slice(&f[3..]);
            piece
        })
        .collect();
    let mut input = vec![0x80 | (session.len() as u8 - 1)];
    input.extend(session.iter().map(|p| (p.len() - 1) as u8 | (2 << 6)));
    for p in &session {
        input.extend_from_slice(p);
    }
    out.push(("framed-session".into(), input));
    out
}
