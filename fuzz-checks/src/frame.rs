//! `frame`: one frame through `Frame::parse` and `protocol::decode`.
//!
//! Properties: neither panics; they agree; a decoded packet re-encodes to the same bytes. The one
//! exception is a variable-length packet (settings update or read-back, log) whose own length
//! field or text disagrees with the bytes it carries: decode zero-fills the struct's tail, and
//! encode sends what the packet's fields say. For those the re-encoding is exactly the received
//! payload zero-extended and cut to the length the fields give, and it is a fixed point (decoding
//! and encoding it again changes nothing).

use protocol::packets::{AnyPacket, LOG_TEXT, SETTINGS_CHUNK};
use protocol::{Frame, PacketType, HEADER_LEN, MAX_PACKET};

/// Checks one frame; panics when a property fails.
pub fn check(data: &[u8]) {
    let parsed = Frame::parse(data);
    let decoded = protocol::decode(data);
    let (frame, packet) = match (parsed, decoded) {
        (Ok(f), Ok(p)) => (f, p),
        (Err(a), Err(b)) => {
            assert_eq!(a, b, "parse and decode refuse for different reasons");
            assert!(
                !a.to_string().is_empty(),
                "error {a:?} has an empty message"
            );
            return;
        }
        (a, b) => panic!("parse gave {a:?} but decode gave {b:?}"),
    };
    let t = frame.packet_type();
    assert_eq!(packet.packet_type(), t, "decode changed the type");
    assert_eq!(frame.payload(), &data[HEADER_LEN..]);

    let again = encode(&packet);
    if is_canonical(t, frame.payload()) {
        assert_eq!(
            again, data,
            "{t:?} does not re-encode to the bytes it came from"
        );
        return;
    }
    // The fields disagree with the payload length: the re-encoding is what the fields say.
    let mut widened = frame.payload().to_vec();
    widened.resize(t.payload_range().1, 0);
    let n = again.len() - HEADER_LEN;
    assert_eq!(again[1], t as u8);
    assert_eq!(&again[HEADER_LEN..], &widened[..n], "{t:?} re-encoding");
    let back = protocol::decode(&again).expect("a re-encoded packet decodes");
    assert_eq!(
        encode(&back),
        again,
        "{t:?} re-encoding is not a fixed point"
    );
}

/// Whether a payload says exactly as much as it carries, so that it must survive a round trip.
fn is_canonical(t: PacketType, payload: &[u8]) -> bool {
    let (min, max) = t.payload_range();
    if min == max {
        return true;
    }
    match t {
        // offset: u16, len: u8, then `len` bytes.
        PacketType::SettingsUpdate | PacketType::SettingsData => {
            usize::from(payload[2]) == payload.len() - 3 && payload.len() - 3 <= SETTINGS_CHUNK
        }
        // level: u8, module: [u8; 8], then UTF-8 text without NUL.
        PacketType::Log => {
            let text = &payload[9..];
            text.len() <= LOG_TEXT && !text.contains(&0) && std::str::from_utf8(text).is_ok()
        }
        other => panic!("{other:?} has a variable length this check does not know"),
    }
}

fn encode(packet: &AnyPacket) -> Vec<u8> {
    let mut buf = [0u8; MAX_PACKET];
    let n = packet
        .encode(&mut buf)
        .unwrap_or_else(|e| panic!("{packet:?} does not re-encode: {e}"));
    buf[..n].to_vec()
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::packets::{LogLevel, Ping, SettingsUpdate};

    fn frame_of(p: impl Into<AnyPacket>) -> Vec<u8> {
        encode(&p.into())
    }

    #[test]
    fn encoded_packets_pass() {
        check(&frame_of(Ping {
            seq: 7,
            host_time_us: 9,
        }));
        check(&frame_of(SettingsUpdate::new(4, &[1, 2, 3]).unwrap()));
        check(&frame_of(protocol::packets::Log::new(
            LogLevel::Info,
            "m",
            "héllo",
        )));
        check(&[0, 0, 0]);
        check(&[]);
    }

    #[test]
    fn a_length_field_larger_than_the_payload_re_encodes_longer() {
        // Offset 0, len 32, but 4 data bytes: the shape of the 10-byte settings update.
        let mut f = frame_of(SettingsUpdate::new(0, &[1, 2, 3, 4]).unwrap());
        f[5] = 32;
        f[0] = protocol::frame::checksum_for(protocol::frame::byte_sum(&f[1..])) as u8;
        check(&f);
        let again = encode(&protocol::decode(&f).unwrap());
        assert_eq!(again.len(), HEADER_LEN + 3 + 32);
    }
}
