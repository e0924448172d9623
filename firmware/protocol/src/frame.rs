//! The packet frame: a 3-byte header, the payload, and the checksum (thesis 9.5.1).
//!
//! Decoding does no I/O and never panics: [`Frame::parse`] checks length, checksum, type and the
//! payload length the type allows, and [`Frame::packet`] casts the payload.

use crate::packets::{AnyPacket, Packet, PacketType};
use crate::Error;

/// Header size in bytes.
pub const HEADER_LEN: usize = 3;
/// Largest payload a header can describe.
pub const MAX_PAYLOAD: usize = u8::MAX as usize;
/// Largest frame: header plus the largest payload.
pub const MAX_PACKET: usize = HEADER_LEN + MAX_PAYLOAD;

crate::wire_struct! {
    /// The common header of every packet.
    pub struct Header {
        /// Signed byte that makes the wrapping sum of all frame bytes zero.
        pub checksum: i8,
        /// A [`PacketType`] code.
        pub packet_type: u8,
        /// Number of payload bytes that follow.
        pub payload_len: u8,
    }
}

/// Wrapping sum of bytes, the quantity the checksum cancels.
#[inline]
pub fn byte_sum(bytes: &[u8]) -> u8 {
    // Summing in u32 lanes lets the compiler vectorise; the low byte is the wrapping u8 sum.
    let mut acc = 0u32;
    for &b in bytes {
        acc = acc.wrapping_add(b as u32);
    }
    acc as u8
}

/// The checksum byte for a frame whose other bytes sum to `sum_without_checksum`.
#[inline]
pub fn checksum_for(sum_without_checksum: u8) -> i8 {
    sum_without_checksum.wrapping_neg() as i8
}

/// Encodes a packet into `buf`, returning the frame length.
pub fn encode<P: Packet>(packet: &P, buf: &mut [u8]) -> Result<usize, Error> {
    let len = packet.payload_len();
    let total = HEADER_LEN + len;
    if total > buf.len() {
        return Err(Error::EncodeBufferTooSmall);
    }
    let payload = &bytemuck::bytes_of(packet)[..len];
    buf[1] = P::TYPE as u8;
    buf[2] = len as u8;
    buf[HEADER_LEN..total].copy_from_slice(payload);
    let sum = byte_sum(&buf[1..total]);
    buf[0] = checksum_for(sum) as u8;
    Ok(total)
}

/// Encodes a packet into a fixed buffer, returning it with the used length.
pub fn encode_to_array<P: Packet>(packet: &P) -> ([u8; MAX_PACKET], usize) {
    let mut buf = [0u8; MAX_PACKET];
    // A packet's payload is at most its struct size, which the type table keeps under MAX_PAYLOAD.
    let n = encode(packet, &mut buf).unwrap_or(0);
    (buf, n)
}

/// A checked frame borrowed from a receive buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame<'a> {
    packet_type: PacketType,
    payload: &'a [u8],
}

impl<'a> Frame<'a> {
    /// Checks a whole frame: length, checksum, known type and a payload length the type allows.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, Error> {
        if bytes.len() < HEADER_LEN {
            return Err(Error::DecodeTooShort);
        }
        if bytes.len() > MAX_PACKET {
            return Err(Error::DecodeOversized);
        }
        let declared = bytes[2] as usize;
        if bytes.len() != HEADER_LEN + declared {
            return Err(Error::DecodeLengthMismatch);
        }
        if byte_sum(bytes) != 0 {
            return Err(Error::DecodeBadChecksum);
        }
        let packet_type =
            PacketType::from_code(bytes[1]).ok_or(Error::DecodeUnknownType(bytes[1]))?;
        let (min, max) = packet_type.payload_range();
        if declared < min || declared > max {
            return Err(Error::DecodeBadPayloadLength(packet_type));
        }
        Ok(Self {
            packet_type,
            payload: &bytes[HEADER_LEN..],
        })
    }

    /// The packet type.
    pub fn packet_type(&self) -> PacketType {
        self.packet_type
    }

    /// The payload bytes.
    pub fn payload(&self) -> &'a [u8] {
        self.payload
    }

    /// The payload as `P`, if this frame is of `P`'s type.
    pub fn cast<P: Packet>(&self) -> Option<P> {
        (self.packet_type == P::TYPE).then(|| cast_payload(self.payload))
    }

    /// The payload as whichever packet its type says.
    pub fn packet(&self) -> AnyPacket {
        AnyPacket::from_checked(self.packet_type, self.payload)
    }
}

/// Decodes a whole frame into a packet.
pub fn decode(bytes: &[u8]) -> Result<AnyPacket, Error> {
    Frame::parse(bytes).map(|f| f.packet())
}

/// Copies a length-checked payload into `P`, zero-filling a variable tail.
pub(crate) fn cast_payload<P: Packet>(payload: &[u8]) -> P {
    let size = core::mem::size_of::<P>();
    if payload.len() == size {
        bytemuck::pod_read_unaligned(payload)
    } else {
        let mut p = P::zeroed();
        let n = payload.len().min(size);
        bytemuck::bytes_of_mut(&mut p)[..n].copy_from_slice(&payload[..n]);
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::packets::*;
    use crate::state::RobotState;
    use bytemuck::Zeroable;

    fn frame_of<P: Packet>(p: &P) -> Vec<u8> {
        let (buf, n) = encode_to_array(p);
        buf[..n].to_vec()
    }

    #[test]
    fn checksum_zeroes_the_sum() {
        let f = frame_of(&StraightMovement {
            distance_m: 0.1,
            speed_mps: 0.2,
            move_id: 7,
        });
        assert_eq!(f.len(), 3 + 10);
        assert_eq!(f[1], 0x40);
        assert_eq!(f[2], 10);
        assert_eq!(f.iter().fold(0u8, |a, &b| a.wrapping_add(b)), 0);
    }

    #[test]
    fn every_error_is_typed() {
        let good = frame_of(&Ping {
            seq: 1,
            host_time_us: 2,
        });
        assert_eq!(Frame::parse(&good[..2]), Err(Error::DecodeTooShort));
        assert_eq!(
            Frame::parse(&good[..good.len() - 1]),
            Err(Error::DecodeLengthMismatch)
        );
        let mut bad = good.clone();
        bad[4] ^= 1;
        assert_eq!(Frame::parse(&bad), Err(Error::DecodeBadChecksum));
        let mut unknown = good.clone();
        unknown[1] = 0xEE;
        unknown[0] = unknown[0].wrapping_sub(0xEE - 0x55);
        assert_eq!(Frame::parse(&unknown), Err(Error::DecodeUnknownType(0xEE)));
        assert_eq!(
            Frame::parse(&[0u8; MAX_PACKET + 1]),
            Err(Error::DecodeOversized)
        );
        // A ping header declaring a stop's empty payload: known type, wrong size.
        let mut short = vec![0u8, 0x55, 0];
        short[0] = checksum_for(byte_sum(&short[1..])) as u8;
        assert_eq!(
            Frame::parse(&short),
            Err(Error::DecodeBadPayloadLength(PacketType::Ping))
        );
    }

    #[test]
    fn variable_tail_packets_travel_short() {
        let u = SettingsUpdate::new(12, &[1, 2, 3, 4]).unwrap();
        let f = frame_of(&u);
        assert_eq!(f.len(), 3 + 3 + 4);
        match decode(&f).unwrap() {
            AnyPacket::SettingsUpdate(d) => {
                assert_eq!({ d.offset }, 12);
                assert_eq!(d.bytes(), &[1, 2, 3, 4]);
            }
            other => panic!("{other:?}"),
        }
        assert!(SettingsUpdate::new(0, &[0; SETTINGS_CHUNK + 1]).is_none());
    }

    #[test]
    fn state_round_trips() {
        let mut s = RobotState::default();
        s.encoders.left_ticks = -12345;
        s.wheels.left_mps = 0.123;
        s.line.darkness[7] = 999;
        let f = frame_of(&s);
        let back = Frame::parse(&f).unwrap().cast::<RobotState>().unwrap();
        assert_eq!(back, s);
        assert!(Frame::parse(&f).unwrap().cast::<Ping>().is_none());
    }

    #[test]
    fn encode_refuses_a_small_buffer() {
        let mut buf = [0u8; 5];
        assert_eq!(
            encode(&Ping::zeroed(), &mut buf),
            Err(Error::EncodeBufferTooSmall)
        );
    }
}
