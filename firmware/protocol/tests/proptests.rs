//! Property tests of the wire protocol: decoding never panics, every packet type survives
//! encode → SLIP → random chunking → decode, and corrupt frames are caught and dropped alone.

use std::collections::HashSet;

use proptest::collection::vec;
use proptest::prelude::*;
use proptest::sample::{select, Index};
use proptest::test_runner::{Config, TestRunner};
use protocol::frame::{byte_sum, checksum_for};
use protocol::packets::*;
use protocol::slip::{self, SlipDecoder, SlipStats, END, ESC, ESC_END, ESC_ESC};
use protocol::state::{ReducedState, RobotState};
use protocol::{decode, AnyPacket, Error, Frame, Layout, PacketType, TypeInfo, MAX_PACKET};

/// Buffer size of the SLIP decoders under test: a little more than the largest frame.
const SLIP_BUF: usize = 300;

// ---------------------------------------------------------------------------------------------
// Generators
// ---------------------------------------------------------------------------------------------

/// Makes every `f32` leaf of `ty` (found through its compile-time layout) finite, so that the
/// derived `PartialEq` of a decoded packet can be compared with `==` (NaN != NaN). Clearing the
/// top exponent bit of an infinity or NaN leaves a finite value.
fn make_floats_finite(ty: &TypeInfo, base: usize, bytes: &mut [u8]) {
    if let Some((elem, n)) = ty.array {
        for i in 0..n {
            make_floats_finite(elem, base + i * elem.size, bytes);
        }
    } else if ty.fields.is_empty() {
        if ty.name == "f32" {
            let raw: [u8; 4] = bytes[base..base + 4].try_into().unwrap();
            let bits = u32::from_le_bytes(raw);
            if !f32::from_bits(bits).is_finite() {
                bytes[base..base + 4].copy_from_slice(&(bits & !(1 << 30)).to_le_bytes());
            }
        }
    } else {
        for f in ty.fields {
            make_floats_finite(f.ty, base + f.offset, bytes);
        }
    }
}

/// A fixed-size packet with every byte random (floats kept finite).
fn pod_packet<P>() -> BoxedStrategy<AnyPacket>
where
    P: Packet + Layout,
    AnyPacket: From<P>,
{
    vec(any::<u8>(), core::mem::size_of::<P>())
        .prop_map(|mut bytes| {
            make_floats_finite(&P::LAYOUT, 0, &mut bytes);
            let p: P = bytemuck::pod_read_unaligned(&bytes);
            AnyPacket::from(p)
        })
        .boxed()
}

/// A random valid packet of type `t`. The match is exhaustive, so a new packet type does not
/// compile until it has a generator here.
fn arb_packet(t: PacketType) -> BoxedStrategy<AnyPacket> {
    use PacketType as T;
    let chunk = || (any::<u16>(), vec(any::<u8>(), 0..=SETTINGS_CHUNK));
    match t {
        T::State => pod_packet::<RobotState>(),
        T::ReducedState => pod_packet::<ReducedState>(),
        T::Hello => pod_packet::<Hello>(),
        T::Pong => pod_packet::<Pong>(),
        T::SettingsData => chunk()
            .prop_map(|(offset, data)| SettingsData::new(offset, &data).unwrap().into())
            .boxed(),
        T::Log => (any::<u8>(), ".{0,10}", "[^\\x00]{0,80}")
            .prop_map(|(level, module, text)| {
                // Text without NUL: a NUL ends the text on the wire, and the bytes after it would
                // come back as zeros. The level is any byte: decoding does not interpret it.
                let mut log = Log::new(LogLevel::Info, &module, &text);
                log.level = level;
                log.into()
            })
            .boxed(),
        T::Nack => pod_packet::<Nack>(),
        T::MoveFinished => pod_packet::<MoveFinished>(),
        T::QueueEmpty => pod_packet::<QueueEmpty>(),
        T::Obstacle => pod_packet::<Obstacle>(),
        T::RobotEncountered => pod_packet::<RobotEncountered>(),
        T::LineEvent => pod_packet::<LineEvent>(),
        T::WatchdogStop => pod_packet::<WatchdogStop>(),
        T::LoopOverrun => pod_packet::<LoopOverrun>(),
        T::SettingsSaved => pod_packet::<SettingsSaved>(),
        T::Bump => pod_packet::<Bump>(),
        T::Reflex => pod_packet::<Reflex>(),
        T::StraightMovement => pod_packet::<StraightMovement>(),
        T::RotationMovement => pod_packet::<RotationMovement>(),
        T::ArcMovement => pod_packet::<ArcMovement>(),
        T::ClearQueue => pod_packet::<ClearQueue>(),
        T::Stop => pod_packet::<Stop>(),
        T::WheelSpeeds => pod_packet::<WheelSpeeds>(),
        T::MotorPower => pod_packet::<MotorPower>(),
        T::LineFollow => pod_packet::<LineFollow>(),
        T::LineCalibration => pod_packet::<LineCalibration>(),
        T::SetLed => pod_packet::<SetLed>(),
        T::IrMessage => pod_packet::<IrMessage>(),
        T::SettingsUpdate => chunk()
            .prop_map(|(offset, data)| SettingsUpdate::new(offset, &data).unwrap().into())
            .boxed(),
        T::SettingsRead => pod_packet::<SettingsRead>(),
        T::SettingsSave => pod_packet::<SettingsSave>(),
        T::SettingsRestoreDefaults => pod_packet::<SettingsRestoreDefaults>(),
        T::ReflectorConfig => pod_packet::<ReflectorConfig>(),
        T::Ping => pod_packet::<Ping>(),
        T::HelloRequest => pod_packet::<HelloRequest>(),
        T::EventReplay => pod_packet::<EventReplay>(),
    }
}

/// A random valid packet of a random type.
fn any_packet() -> impl Strategy<Value = AnyPacket> {
    select(PacketType::ALL).prop_flat_map(arb_packet)
}

/// Bytes biased towards the SLIP specials, so that escapes and delimiters are frequent.
fn slip_noise(len: std::ops::Range<usize>) -> impl Strategy<Value = Vec<u8>> {
    vec(
        prop_oneof![
            6 => any::<u8>(),
            1 => Just(END),
            1 => Just(ESC),
            1 => Just(ESC_END),
            1 => Just(ESC_ESC),
        ],
        len,
    )
}

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

fn frame_of(p: &AnyPacket) -> Vec<u8> {
    let mut buf = [0u8; MAX_PACKET];
    let n = p.encode(&mut buf).expect("every packet fits MAX_PACKET");
    buf[..n].to_vec()
}

fn slip_of(frame: &[u8]) -> Vec<u8> {
    slip::encode_iter(frame).collect()
}

/// Frame of type `code` with `payload` and a correct checksum.
fn frame_with_checksum(code: u8, payload: &[u8]) -> Vec<u8> {
    let mut f = vec![0, code, payload.len() as u8];
    f.extend_from_slice(payload);
    f[0] = checksum_for(byte_sum(&f[1..])) as u8;
    f
}

/// Splits `bytes` at the given random boundaries (duplicates and empty chunks allowed).
fn chunks<'a>(bytes: &'a [u8], cuts: &[Index]) -> Vec<&'a [u8]> {
    let mut at: Vec<usize> = cuts.iter().map(|i| i.index(bytes.len() + 1)).collect();
    at.sort_unstable();
    let mut out = Vec::new();
    let mut start = 0;
    for a in at {
        out.push(&bytes[start..a]);
        start = a;
    }
    out.push(&bytes[start..]);
    out
}

/// A SLIP receiver that records everything its decoder delivers or reports.
struct Rx {
    dec: SlipDecoder<SLIP_BUF>,
    frames: Vec<Vec<u8>>,
    errors: Vec<Error>,
}

impl Rx {
    fn new() -> Self {
        Self {
            dec: SlipDecoder::new(),
            frames: Vec::new(),
            errors: Vec::new(),
        }
    }

    fn feed(&mut self, chunk: &[u8]) {
        for &b in chunk {
            match self.dec.push(b) {
                Ok(Some(f)) => {
                    assert!(f.len() <= SLIP_BUF, "delivered {} bytes", f.len());
                    self.frames.push(f.to_vec());
                }
                Ok(None) => {}
                Err(e) => self.errors.push(e),
            }
        }
    }

    /// Feeds `stream` split at `cuts`.
    fn feed_chunked(stream: &[u8], cuts: &[Index]) -> Self {
        let mut rx = Self::new();
        for c in chunks(stream, cuts) {
            rx.feed(c);
        }
        rx
    }

    fn stats(&self) -> SlipStats {
        self.dec.stats()
    }

    /// The delivered frames that decode.
    fn packets(&self) -> Vec<AnyPacket> {
        self.frames.iter().filter_map(|f| decode(f).ok()).collect()
    }
}

/// How the middle frame of a good–corrupt–good stream is damaged.
#[derive(Clone, Debug)]
enum Corruption {
    /// One bit of the frame flipped before SLIP encoding: reaches `Frame::parse`, fails there.
    FlipBit(Index),
    /// The frame cut short before SLIP encoding.
    Truncate(Index),
    /// A correctly summed frame with a code outside the table.
    UnknownType(u8, Vec<u8>),
    /// A correctly summed frame of a known type with a payload length the type does not allow.
    BadPayloadLength(PacketType, usize),
    /// An escape byte followed by an invalid byte inserted into the SLIP bytes.
    BadEscape(Index, u8),
    /// An escape byte right before the closing END: the frame ends inside an escape.
    EscapeAtEnd,
    /// More bytes than the decoder holds, without a delimiter.
    Overflow(Vec<u8>),
    /// Random bytes between delimiters (cases that happen to form a valid frame are rejected).
    Garbage(Vec<u8>),
}

fn corruption() -> impl Strategy<Value = Corruption> {
    let unknown = (any::<u8>(), vec(any::<u8>(), 0..40))
        .prop_filter("unknown code", |(c, _)| PacketType::from_code(*c).is_none())
        .prop_map(|(c, p)| Corruption::UnknownType(c, p));
    let bad_len = (select(PacketType::ALL), 0usize..=255)
        .prop_filter("length outside the type's range", |(t, n)| {
            let (min, max) = t.payload_range();
            *n < min || *n > max
        })
        .prop_map(|(t, n)| Corruption::BadPayloadLength(t, n));
    let bad_escape_byte = any::<u8>().prop_filter("not a valid escape", |b| {
        ![END, ESC_END, ESC_ESC].contains(b)
    });
    prop_oneof![
        any::<Index>().prop_map(Corruption::FlipBit),
        any::<Index>().prop_map(Corruption::Truncate),
        unknown,
        bad_len,
        (any::<Index>(), bad_escape_byte).prop_map(|(i, b)| Corruption::BadEscape(i, b)),
        Just(Corruption::EscapeAtEnd),
        vec(
            any::<u8>().prop_filter("no END", |b| *b != END && *b != ESC),
            SLIP_BUF + 1..400
        )
        .prop_map(Corruption::Overflow),
        vec(any::<u8>().prop_filter("no END", |b| *b != END), 0..400).prop_map(Corruption::Garbage),
    ]
}

/// SLIP bytes of `frame` damaged by `c`, or `None` when the damage happens to leave a valid frame.
fn corrupt(frame: &[u8], c: &Corruption) -> Option<Vec<u8>> {
    Some(match c {
        Corruption::FlipBit(i) => {
            let mut f = frame.to_vec();
            let bit = i.index(f.len() * 8);
            f[bit / 8] ^= 1 << (bit % 8);
            slip_of(&f)
        }
        Corruption::Truncate(i) => slip_of(&frame[..i.index(frame.len())]),
        Corruption::UnknownType(code, payload) => slip_of(&frame_with_checksum(*code, payload)),
        Corruption::BadPayloadLength(t, n) => {
            slip_of(&frame_with_checksum(*t as u8, &vec![0x5A; *n]))
        }
        Corruption::BadEscape(i, b) => {
            let mut s = slip_of(frame);
            // Between the opening and closing END.
            let at = 1 + i.index(s.len() - 1);
            s.splice(at..at, [ESC, *b]);
            s
        }
        Corruption::EscapeAtEnd => {
            let mut s = slip_of(frame);
            s.insert(s.len() - 1, ESC);
            s
        }
        Corruption::Overflow(bytes) => [&[END][..], bytes, &[END]].concat(),
        Corruption::Garbage(bytes) => {
            let s = [&[END][..], bytes, &[END]].concat();
            let mut rx = Rx::new();
            rx.feed(&s);
            if !rx.packets().is_empty() {
                return None;
            }
            s
        }
    })
}

/// Round-trips one packet through encode → SLIP → chunked decoder → `Frame::parse`.
fn round_trip(p: &AnyPacket, cuts: &[Index]) -> Result<(), TestCaseError> {
    let frame = frame_of(p);
    let (min, max) = p.packet_type().payload_range();
    prop_assert!((min..=max).contains(&(frame.len() - 3)));
    let stream = slip_of(&frame);
    let mut buf = [0u8; slip::max_encoded_len(MAX_PACKET)];
    let n = slip::encode(&frame, &mut buf).unwrap();
    prop_assert_eq!(&buf[..n], &stream[..], "slip::encode and encode_iter agree");
    let rx = Rx::feed_chunked(&stream, cuts);
    prop_assert!(rx.errors.is_empty(), "{:?}", rx.errors);
    prop_assert_eq!(&rx.frames, &vec![frame.clone()]);
    let parsed = Frame::parse(&rx.frames[0]).map_err(|e| TestCaseError::fail(format!("{e}")))?;
    prop_assert_eq!(parsed.packet_type(), p.packet_type());
    prop_assert_eq!(parsed.packet(), *p);
    prop_assert_eq!(decode(&frame), Ok(*p));
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Coverage
// ---------------------------------------------------------------------------------------------

/// Every type in `PacketType::ALL` has a generator that makes packets of that type, and 64 random
/// packets of each type round-trip through SLIP with random chunking.
#[test]
fn every_packet_type_is_generated_and_round_trips() {
    let mut seen = HashSet::new();
    for &t in PacketType::ALL {
        let mut runner = TestRunner::new(Config {
            cases: 64,
            failure_persistence: None,
            ..Config::default()
        });
        let strategy = (arb_packet(t), vec(any::<Index>(), 0..8));
        runner
            .run(&strategy, |(p, cuts)| {
                prop_assert_eq!(p.packet_type(), t);
                round_trip(&p, &cuts)
            })
            .unwrap_or_else(|e| panic!("{t:?}: {e}"));
        assert!(seen.insert(t), "{t:?} listed twice");
    }
    assert_eq!(seen.len(), PacketType::ALL.len());
    // ALL lists every code `from_code` knows.
    let known = (0..=u8::MAX)
        .filter(|&c| PacketType::from_code(c).is_some())
        .count();
    assert_eq!(known, PacketType::ALL.len());
}

/// The generators exercise the variable tails at both ends: empty and full.
#[test]
fn variable_tail_extremes_round_trip() {
    let packets: [AnyPacket; 6] = [
        SettingsUpdate::new(0, &[]).unwrap().into(),
        SettingsUpdate::new(u16::MAX, &[0xC0; SETTINGS_CHUNK])
            .unwrap()
            .into(),
        SettingsData::new(7, &[]).unwrap().into(),
        SettingsData::new(7, &[0xDB; SETTINGS_CHUNK])
            .unwrap()
            .into(),
        Log::new(LogLevel::Error, "", "").into(),
        Log::new(LogLevel::Debug, "module12", &"x".repeat(LOG_TEXT + 5)).into(),
    ];
    for p in &packets {
        round_trip(p, &[]).unwrap();
    }
}

// ---------------------------------------------------------------------------------------------
// Properties
// ---------------------------------------------------------------------------------------------

proptest! {
    /// (a) `decode` and `Frame::parse` never panic on arbitrary bytes, and accept only frames whose
    /// length and checksum are right.
    #[test]
    fn decode_never_panics_on_random_bytes(bytes in vec(any::<u8>(), 0..400)) {
        let parsed = Frame::parse(&bytes);
        let decoded = decode(&bytes);
        prop_assert_eq!(parsed.is_ok(), decoded.is_ok());
        if let Ok(f) = parsed {
            prop_assert_eq!(byte_sum(&bytes), 0);
            prop_assert_eq!(bytes.len(), 3 + bytes[2] as usize);
            prop_assert_eq!(f.payload().len(), bytes[2] as usize);
            let _ = f.packet();
        }
    }

    /// (a) Frames with a correct length and checksum but random type and payload reach the type
    /// and payload-length checks; they never panic, are accepted exactly when the length fits the
    /// type, and a fixed-size packet re-encodes to the same bytes.
    #[test]
    fn decode_never_panics_on_summed_frames(
        code in prop_oneof![select(PacketType::ALL).prop_map(|t| t as u8), any::<u8>()],
        payload in vec(any::<u8>(), 0..=255),
    ) {
        let frame = frame_with_checksum(code, &payload);
        match (PacketType::from_code(code), decode(&frame)) {
            (None, r) => prop_assert_eq!(r, Err(Error::DecodeUnknownType(code))),
            (Some(t), r) => {
                let (min, max) = t.payload_range();
                if (min..=max).contains(&payload.len()) {
                    let p = r.map_err(|e| TestCaseError::fail(format!("{e}")))?;
                    prop_assert_eq!(p.packet_type(), t);
                    if min == max {
                        prop_assert_eq!(frame_of(&p), frame);
                    }
                } else {
                    prop_assert_eq!(r, Err(Error::DecodeBadPayloadLength(t)));
                }
            }
        }
    }

    /// (b) A SLIP decoder fed random bytes one at a time never panics, never delivers more than its
    /// buffer or an empty frame, and its counters match what it reported. Half the cases are
    /// dense in SLIP specials (escapes, short frames), half plain bytes, where an END comes only
    /// every 256 bytes on average, so runs past the buffer size (overflows) are common.
    #[test]
    fn slip_decoder_never_panics_on_random_bytes(
        bytes in prop_oneof![slip_noise(0..2000), vec(any::<u8>(), 0..4000)],
    ) {
        let mut rx = Rx::new();
        rx.feed(&bytes);
        let stats = rx.stats();
        prop_assert!(rx.frames.iter().all(|f| !f.is_empty() && f.len() <= SLIP_BUF));
        prop_assert_eq!(stats.frames as usize, rx.frames.len());
        prop_assert_eq!((stats.overflows + stats.bad_escapes) as usize, rx.errors.len());
        for f in &rx.frames {
            let _ = decode(f);
        }
    }

    /// (c) Any packet comes back equal through encode → SLIP → randomly chunked decoder.
    #[test]
    fn packet_round_trips_through_chunked_slip(
        p in any_packet(),
        cuts in vec(any::<Index>(), 0..12),
    ) {
        round_trip(&p, &cuts)?;
    }

    /// (c) Several packets back to back in one randomly chunked stream all come back, in order.
    /// A frame may also share its opening END with the previous frame's closing one.
    #[test]
    fn packet_stream_round_trips_in_order(
        packets in vec((any_packet(), any::<bool>()), 1..10),
        cuts in vec(any::<Index>(), 0..40),
    ) {
        let mut stream = Vec::new();
        let mut frames = Vec::new();
        for (i, (p, share_end)) in packets.iter().enumerate() {
            let frame = frame_of(p);
            let s = slip_of(&frame);
            stream.extend_from_slice(if i > 0 && *share_end { &s[1..] } else { &s[..] });
            frames.push(frame);
        }
        let rx = Rx::feed_chunked(&stream, &cuts);
        prop_assert!(rx.errors.is_empty(), "{:?}", rx.errors);
        prop_assert_eq!(&rx.frames, &frames);
        let expected: Vec<AnyPacket> = packets.iter().map(|(p, _)| *p).collect();
        prop_assert_eq!(rx.packets(), expected);
        prop_assert_eq!(rx.stats().frames as usize, packets.len());
    }

    /// (d) Flipping any single bit of a valid frame makes `Frame::parse` fail: in the length byte
    /// as a length mismatch, anywhere else as a bad checksum (a one-bit flip changes the byte sum
    /// by ±2^k, never by a multiple of 256).
    #[test]
    fn every_single_bit_flip_is_rejected(p in any_packet()) {
        let frame = frame_of(&p);
        for bit in 0..frame.len() * 8 {
            let mut f = frame.clone();
            f[bit / 8] ^= 1 << (bit % 8);
            let expected = if bit / 8 == 2 {
                Error::DecodeLengthMismatch
            } else {
                Error::DecodeBadChecksum
            };
            prop_assert_eq!(Frame::parse(&f), Err(expected), "bit {}", bit);
            prop_assert!(decode(&f).is_err());
        }
    }

    /// (e) A corrupt frame between two good ones in a randomly chunked SLIP stream is dropped, by
    /// the SLIP decoder or by `Frame::parse`, and both good frames survive.
    #[test]
    fn corrupt_frame_between_good_ones_is_dropped(
        first in any_packet(),
        middle in any_packet(),
        last in any_packet(),
        damage in corruption(),
        cuts in vec(any::<Index>(), 0..30),
    ) {
        let bad = corrupt(&frame_of(&middle), &damage);
        prop_assume!(bad.is_some(), "garbage happened to form a valid frame");
        let stream = [slip_of(&frame_of(&first)), bad.unwrap(), slip_of(&frame_of(&last))].concat();
        let rx = Rx::feed_chunked(&stream, &cuts);
        prop_assert_eq!(rx.packets(), vec![first, last]);
        prop_assert_eq!(rx.frames.first(), Some(&frame_of(&first)));
        prop_assert_eq!(rx.frames.last(), Some(&frame_of(&last)));
        let slip_errors = match damage {
            Corruption::BadEscape(..) | Corruption::EscapeAtEnd => vec![Error::SlipBadEscape],
            Corruption::Overflow(_) => vec![Error::SlipOverflow],
            Corruption::Garbage(_) => rx.errors.clone(),
            // Damage inside the frame passes SLIP and is caught by `Frame::parse`.
            _ => vec![],
        };
        prop_assert_eq!(&rx.errors, &slip_errors);
    }
}
