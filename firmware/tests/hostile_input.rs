//! Bad input from the host: every settings write is validated whole before it is applied, and a
//! frame of unknown type or wrong length is answered with a Nack, counted and dropped.

use firmware::mock::{MockBoard, MockRobot};
use firmware::protocol::frame::{byte_sum, checksum_for};
use firmware::protocol::packets::*;
use firmware::protocol::settings::Settings;
use firmware::protocol::AnyPacket;
use firmware::Duration;

fn robot() -> MockRobot {
    MockRobot::new(MockBoard::default())
}

/// A frame with a correct checksum around an arbitrary type code and payload.
fn raw_frame(code: u8, payload: &[u8]) -> Vec<u8> {
    let mut f = vec![0u8, code, payload.len() as u8];
    f.extend_from_slice(payload);
    f[0] = checksum_for(byte_sum(&f[1..])) as u8;
    f
}

fn nacks(r: &mut MockRobot) -> Vec<Nack> {
    r.drain()
        .into_iter()
        .filter_map(|p| match p {
            AnyPacket::Nack(n) => Some(n),
            _ => None,
        })
        .collect()
}

fn only_nack(r: &mut MockRobot) -> Nack {
    let all = nacks(r);
    assert_eq!(all.len(), 1, "expected one Nack, got {all:?}");
    all[0]
}

/// Sends `value` to the field at `path` and returns the Nack, asserting nothing changed.
fn refused_write(path: &str, value: &[u8]) -> Nack {
    let mut r = robot();
    let before = *r.fw.settings();
    let (off, _) = Settings::field(path).unwrap_or_else(|| panic!("no field {path}"));
    r.send(SettingsUpdate::new(off as u16, value).unwrap());
    let n = only_nack(&mut r);
    assert_eq!(*r.fw.settings(), before, "{path} changed");
    n
}

fn assert_names_field(n: Nack, path: &str) {
    assert_eq!(n.packet_type, PacketType::SettingsUpdate as u8);
    assert_eq!(n.reason, NackReason::BadSettingValue as u8, "{path}");
    let (off, _) = Settings::field(path).unwrap();
    assert_eq!({ n.field_offset } as usize, off, "{path}");
    assert_eq!(
        Settings::path_of(usize::from(n.field_offset))
            .unwrap()
            .to_string(),
        path
    );
}

#[test]
fn update_whose_len_exceeds_the_carried_bytes_is_refused() {
    let mut r = robot();
    let before = *r.fw.settings();
    let (off, _) = Settings::field("geometry.ticks_per_rev").unwrap();
    // Says 32 bytes, carries 4: decoding zero-fills the rest, which must never be written.
    let mut payload = vec![];
    payload.extend_from_slice(&(off as u16).to_le_bytes());
    payload.push(32);
    payload.extend_from_slice(&[7, 0, 0, 0]);
    r.fw.on_link_packet(r.now, &raw_frame(0x50, &payload));
    let n = only_nack(&mut r);
    assert_eq!(n.packet_type, PacketType::SettingsUpdate as u8);
    assert_eq!(n.reason, NackReason::BadLength as u8);
    assert_eq!({ n.field_offset }, Nack::NO_FIELD);
    assert_eq!(*r.fw.settings(), before);

    // Says 2, carries 4: the extra bytes are as suspect as missing ones.
    payload[2] = 2;
    r.fw.on_link_packet(r.now, &raw_frame(0x50, &payload));
    assert_eq!(only_nack(&mut r).reason, NackReason::BadLength as u8);
    assert_eq!(*r.fw.settings(), before);
}

#[test]
fn zero_main_period_is_refused_and_no_overruns_follow() {
    let n = refused_write("scheduler.main_period_us", &0u32.to_le_bytes());
    assert_names_field(n, "scheduler.main_period_us");

    let mut r = robot();
    let (off, _) = Settings::field("scheduler.main_period_us").unwrap();
    r.send(SettingsUpdate::new(off as u16, &0u32.to_le_bytes()).unwrap());
    let mut overruns = 0;
    r.run(Duration::from_millis(100), |_, p| {
        if matches!(p, AnyPacket::LoopOverrun(_)) {
            overruns += 1;
        }
    });
    assert_eq!(overruns, 0);
    assert_eq!({ r.fw.state().link.overruns }, 0);
}

#[test]
fn zero_ticks_per_rev_is_refused() {
    let n = refused_write("geometry.ticks_per_rev", &0u16.to_le_bytes());
    assert_names_field(n, "geometry.ticks_per_rev");
}

#[test]
fn non_finite_and_non_positive_floats_are_refused() {
    for v in [f32::NAN, f32::INFINITY, -0.009, 0.0] {
        let n = refused_write("geometry.wheel_diameter_m", &v.to_le_bytes());
        assert_names_field(n, "geometry.wheel_diameter_m");
    }
    let n = refused_write("line_pid.kd", &f32::NEG_INFINITY.to_le_bytes());
    assert_names_field(n, "line_pid.kd");
}

#[test]
fn enum_codes_out_of_range_are_refused() {
    assert_names_field(refused_write("reflector.mode", &[3]), "reflector.mode");
    assert_names_field(refused_write("log.level", &[5]), "log.level");
    assert_names_field(
        refused_write("proximity.led_count", &[7]),
        "proximity.led_count",
    );
}

#[test]
fn cross_field_bounds_and_text_are_checked() {
    assert_names_field(
        refused_write("motor.min_pwm", &1001u16.to_le_bytes()),
        "motor.min_pwm",
    );
    assert_names_field(
        refused_write("motor.max_pwm", &50u16.to_le_bytes()),
        "motor.min_pwm",
    );
    assert_names_field(
        refused_write("line_sensor.black[3]", &3000u16.to_le_bytes()),
        "line_sensor.black[3]",
    );
    let mut name = [0u8; 12];
    name[..3].copy_from_slice(b"a\xffb");
    assert_names_field(refused_write("identity.name", &name), "identity.name[1]");
}

#[test]
fn a_sub_struct_with_one_bad_value_is_refused_whole() {
    let mut r = robot();
    let before = *r.fw.settings();
    let (off, _) = Settings::field("line_pid").unwrap();
    let pid = firmware::protocol::settings::PidSettings {
        kp: 1.0,
        ki: 2.0,
        kd: f32::NAN,
        i_limit: 4.0,
        out_limit: 5.0,
    };
    r.send(SettingsUpdate::new(off as u16, bytemuck::bytes_of(&pid)).unwrap());
    assert_names_field(only_nack(&mut r), "line_pid.kd");
    assert_eq!(*r.fw.settings(), before);
}

#[test]
fn a_valid_write_is_still_applied() {
    let mut r = robot();
    let (off, _) = Settings::field("scheduler.main_period_us").unwrap();
    r.send(SettingsUpdate::new(off as u16, &10_000u32.to_le_bytes()).unwrap());
    assert!(nacks(&mut r).is_empty());
    assert_eq!({ r.fw.settings().scheduler.main_period_us }, 10_000);
}

#[test]
fn unknown_type_is_nacked_counted_and_dropped() {
    let mut r = robot();
    let before = *r.fw.state();
    r.fw.on_link_packet(r.now, &raw_frame(0xEE, &[1, 2, 3]));
    let n = only_nack(&mut r);
    assert_eq!(n.packet_type, 0xEE);
    assert_eq!(n.reason, NackReason::UnknownType as u8);
    assert_eq!({ n.field_offset }, Nack::NO_FIELD);
    assert_eq!(
        { r.fw.state().link.rx_errors },
        { before.link.rx_errors } + 1
    );
    assert_eq!({ r.fw.state().link.rx_packets }, { before.link.rx_packets });
}

#[test]
fn wrong_payload_length_is_nacked_counted_and_dropped() {
    let mut r = robot();
    // A ping is 12 bytes; 5 cannot be one.
    r.fw.on_link_packet(r.now, &raw_frame(0x55, &[0; 5]));
    let n = only_nack(&mut r);
    assert_eq!(n.packet_type, PacketType::Ping as u8);
    assert_eq!(n.reason, NackReason::BadLength as u8);
    assert_eq!({ r.fw.state().link.rx_errors }, 1);
    assert_eq!({ r.fw.state().link.rx_packets }, 0);
}

#[test]
fn untrustworthy_frames_are_counted_but_not_answered() {
    let mut r = robot();
    let mut bad_sum = raw_frame(0x55, &[0; 12]);
    bad_sum[5] ^= 0x10;
    r.fw.on_link_packet(r.now, &bad_sum);
    r.fw.on_link_packet(r.now, &[0x55, 0xAB]);
    assert!(nacks(&mut r).is_empty());
    assert_eq!({ r.fw.state().link.rx_errors }, 2);
}

#[test]
fn an_invalid_stored_image_falls_back_to_defaults() {
    let mut stored = Settings::default();
    stored.identity.robot_id = 9;
    stored.geometry.ticks_per_rev = 0;
    let mut board = MockBoard::default();
    board.storage = Some(bytemuck::cast(stored));
    let mut r = MockRobot::new(board);
    assert_eq!(*r.fw.settings(), Settings::default());
    let mut warned = false;
    r.run(Duration::from_millis(1), |_, p| {
        if let AnyPacket::Log(l) = p {
            warned |= l.text().contains("geometry.ticks_per_rev");
        }
    });
    assert!(warned, "boot did not report the refused image");

    stored.geometry.ticks_per_rev = 40;
    let mut board = MockBoard::default();
    board.storage = Some(bytemuck::cast(stored));
    assert_eq!(MockRobot::new(board).fw.robot_id(), 9);
}
