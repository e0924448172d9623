//! `firmware_link`: hostile host bytes into the firmware's `on_link_bytes` on the mock board.
//!
//! The input is a [`Chunked`] plan and stream. Each piece goes to `on_link_bytes` as one receive
//! interrupt; the top two bits of its plan byte say how many board ticks follow it. With bit 7 of
//! the input's first byte set, each piece is instead `[type, payload...]` that the check frames
//! (length, checksum) and SLIP-encodes before feeding, so the fuzzer reaches every command handler
//! with arbitrary payloads without having to solve the checksum.
//!
//! Properties, after the input:
//! - nothing panicked, and every packet the robot sent is a well-formed frame;
//! - with the host reading every tick, the robot drops nothing and sends at most
//!   [`MAX_PACKETS_PER_MS`] packets per millisecond over a quiet stretch: no flood;
//! - the robot answers a ping with its pong at once;
//! - its settings are still valid.

use firmware::firmware::TX_QUEUE;
use firmware::mock::{MockBoard, MockRobot};
use protocol::frame::{byte_sum, checksum_for};
use protocol::packets::Ping;
use protocol::{AnyPacket, Frame, MAX_PACKET};

use crate::Chunked;

/// Board ticks after a piece, by the top two bits of its plan byte.
const TICKS_AFTER: [u32; 4] = [0, 1, 10, 50];
/// Ticks an input may spend in total, so one execution stays around a millisecond.
const TICK_BUDGET: u32 = 2000;
/// Quiet ticks over which the send rate is measured.
const QUIET_TICKS: u32 = 500;
/// The most packets per millisecond a robot may send on its own: the state reflector at its
/// fastest (1 ms) plus its events and logs.
pub const MAX_PACKETS_PER_MS: usize = 4;
/// The sequence number of the final ping.
const PING_SEQ: u32 = 0x5EED_F00D;

/// Checks one input; panics when a property fails.
pub fn check(input: &[u8]) {
    let Some(chunked) = Chunked::new(input) else {
        return;
    };
    let framed = input[0] & 0x80 != 0;
    let mut r = MockRobot::new(MockBoard::default());
    r.step();
    drain(&mut r);

    let mut budget = TICK_BUDGET;
    for (plan, piece) in chunked.pieces(64) {
        if framed {
            let bytes = slip_frame(piece);
            r.fw.on_link_bytes(r.now, &bytes);
        } else {
            r.fw.on_link_bytes(r.now, piece);
        }
        let ticks = TICKS_AFTER[usize::from(plan >> 6)].min(budget);
        budget -= ticks;
        drain(&mut r);
        for _ in 0..ticks {
            r.step();
            drain(&mut r);
        }
    }

    let dropped = r.fw.state().link.tx_dropped;
    let mut sent = 0;
    for _ in 0..QUIET_TICKS {
        r.step();
        sent += drain(&mut r).len();
    }
    assert_eq!(
        { r.fw.state().link.tx_dropped },
        dropped,
        "the robot overflowed its send queue although the host read every tick"
    );
    let ms = (r.dt.as_micros() * u64::from(QUIET_TICKS) / 1000) as usize;
    assert!(
        sent <= MAX_PACKETS_PER_MS * ms,
        "the robot sent {sent} packets in {ms} ms on its own"
    );

    let ping = encode_ping();
    r.fw.on_link_bytes(r.now, &ping);
    let answers = drain(&mut r);
    assert!(
        answers
            .iter()
            .any(|p| matches!(p, AnyPacket::Pong(p) if { p.seq } == PING_SEQ)),
        "no pong to a ping; the robot answered {answers:?}"
    );

    if let Err(e) = r.fw.settings().validate() {
        panic!("the robot's settings are invalid: {e}");
    }
}

/// Takes every waiting packet as a host would, checking each is a well-formed frame.
fn drain(r: &mut MockRobot) -> Vec<AnyPacket> {
    let mut out = Vec::new();
    while let Some(p) = r.fw.pop_packet() {
        let frame = Frame::parse(&p).unwrap_or_else(|e| panic!("the robot sent {p:?}: {e}"));
        out.push(frame.packet());
        assert!(
            out.len() <= TX_QUEUE,
            "more packets queued than the queue holds"
        );
    }
    out
}

/// `[type, payload...]` as a checksummed frame, SLIP-encoded.
fn slip_frame(piece: &[u8]) -> Vec<u8> {
    let (&t, payload) = piece.split_first().expect("pieces are never empty");
    let payload = &payload[..payload.len().min(MAX_PACKET - 3)];
    let mut frame = vec![0, t, payload.len() as u8];
    frame.extend_from_slice(payload);
    frame[0] = checksum_for(byte_sum(&frame[1..])) as u8;
    protocol::slip::encode_iter(&frame).collect()
}

fn encode_ping() -> Vec<u8> {
    let mut buf = [0u8; MAX_PACKET];
    let n = protocol::encode(
        &Ping {
            seq: PING_SEQ,
            host_time_us: 1,
        },
        &mut buf,
    )
    .expect("a ping fits");
    protocol::slip::encode_iter(&buf[..n]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quiet_robot_passes() {
        check(&[0, 0]);
        check(&[0x80, 0xC0, 0x55, 1, 2, 3]);
    }

    #[test]
    fn slip_frames_decode() {
        let bytes = slip_frame(&[0x56]);
        let mut dec = protocol::slip::SlipDecoder::<MAX_PACKET>::new();
        let frame = bytes
            .iter()
            .find_map(|&b| dec.push(b).ok().flatten().map(|f| f.to_vec()))
            .unwrap();
        assert!(matches!(
            protocol::decode(&frame),
            Ok(AnyPacket::HelloRequest(_))
        ));
    }
}
