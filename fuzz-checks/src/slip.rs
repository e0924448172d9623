//! `slip`: the SLIP decoder on arbitrary bytes under arbitrary chunking, and encode → decode.
//!
//! The input is a [`Chunked`] plan and stream. Properties:
//! - the decoder never panics and delivers the same frames and errors however the stream is cut,
//!   one decoder kept across the pieces as a link keeps it;
//! - what it delivers is what RFC 1055 framing says, computed independently: the stream split at
//!   `END`, each non-empty piece unescaped, dropped as a bad escape or an overflow of the buffer;
//! - its counters agree with what it delivered;
//! - encoding the pieces as frames and decoding the concatenation gives the pieces back, in order
//!   (an empty piece is no frame; a piece longer than the buffer is one overflow).

use protocol::slip::{self, SlipDecoder, END, ESC, ESC_END, ESC_ESC};
use protocol::Error;

use crate::Chunked;

/// A decoder small enough that the fuzzer reaches its overflow path easily.
const SMALL: usize = 16;

/// What a decoder reported for one frame.
#[derive(Clone, Debug, PartialEq, Eq)]
enum Event {
    Frame(Vec<u8>),
    Dropped(Error),
}

/// Checks one input; panics when a property fails.
pub fn check(input: &[u8]) {
    let Some(chunked) = Chunked::new(input) else {
        return;
    };
    let stream = chunked.data();
    let pieces = chunked.pieces(64);

    let whole = events::<SMALL>(&mut SlipDecoder::new(), stream);
    let mut dec = SlipDecoder::<SMALL>::new();
    let mut cut = Vec::new();
    for (_, piece) in &pieces {
        cut.extend(events(&mut dec, piece));
    }
    assert_eq!(cut, whole, "chunking changed what the decoder delivered");
    assert_eq!(
        whole,
        model(stream, SMALL),
        "decoder disagrees with RFC 1055 framing"
    );
    let stats = dec.stats();
    let count = |f: fn(&Event) -> bool| whole.iter().filter(|e| f(e)).count() as u32;
    assert_eq!(stats.frames, count(|e| matches!(e, Event::Frame(_))));
    assert_eq!(
        stats.overflows,
        count(|e| *e == Event::Dropped(Error::SlipOverflow))
    );
    assert_eq!(
        stats.bad_escapes,
        count(|e| *e == Event::Dropped(Error::SlipBadEscape))
    );

    // The default-size decoder, as links use it, agrees with the model too.
    let full = events::<{ protocol::MAX_PACKET }>(&mut SlipDecoder::new(), stream);
    assert_eq!(full, model(stream, protocol::MAX_PACKET));

    round_trip(&pieces);
}

/// Encodes every piece as a frame into one stream and decodes it.
fn round_trip(pieces: &[(u8, &[u8])]) {
    let mut stream = Vec::new();
    let mut expected = Vec::new();
    for (_, piece) in pieces {
        let mut buf = vec![0u8; slip::max_encoded_len(piece.len())];
        let n = slip::encode(piece, &mut buf).expect("max_encoded_len is enough");
        let lazy: Vec<u8> = slip::encode_iter(piece).collect();
        assert_eq!(&buf[..n], &lazy[..], "encode and encode_iter disagree");
        assert!(!buf[1..n - 1].contains(&END), "END inside an encoded frame");
        stream.extend_from_slice(&buf[..n]);
        if piece.len() > SMALL {
            expected.push(Event::Dropped(Error::SlipOverflow));
        } else if !piece.is_empty() {
            expected.push(Event::Frame(piece.to_vec()));
        }
    }
    let got = events::<SMALL>(&mut SlipDecoder::new(), &stream);
    assert_eq!(got, expected, "encode → decode round trip");
}

fn events<const N: usize>(dec: &mut SlipDecoder<N>, bytes: &[u8]) -> Vec<Event> {
    let mut out = Vec::new();
    for &b in bytes {
        match dec.push(b) {
            Ok(Some(f)) => {
                assert!(!f.is_empty() && f.len() <= N, "delivered {} bytes", f.len());
                out.push(Event::Frame(f.to_vec()));
            }
            Ok(None) => {}
            Err(e) => out.push(Event::Dropped(e)),
        }
    }
    out
}

/// RFC 1055 decoding written from the rules, not from the decoder: each piece between `END`s is
/// unescaped byte by byte; the first bad escape or the first byte beyond `cap` drops the piece,
/// also in the unterminated last piece. A piece that is empty once unescaped (line noise before a
/// frame, a lone `ESC`) is not reported.
fn model(stream: &[u8], cap: usize) -> Vec<Event> {
    let mut out = Vec::new();
    let mut pieces = stream.split(|&b| b == END).peekable();
    while let Some(piece) = pieces.next() {
        // The decoder drops a frame at the bad byte, before its END; it delivers one only at END.
        let terminated = pieces.peek().is_some();
        let mut frame = Vec::new();
        let mut escaped = false;
        let mut dropped = None;
        for &b in piece {
            let byte = if escaped {
                escaped = false;
                match b {
                    ESC_END => END,
                    ESC_ESC => ESC,
                    _ => {
                        dropped = Some(Error::SlipBadEscape);
                        break;
                    }
                }
            } else if b == ESC {
                escaped = true;
                continue;
            } else {
                b
            };
            if frame.len() == cap {
                dropped = Some(Error::SlipOverflow);
                break;
            }
            frame.push(byte);
        }
        match dropped {
            Some(e) => out.push(Event::Dropped(e)),
            None if frame.is_empty() || !terminated => {}
            None if escaped => out.push(Event::Dropped(Error::SlipBadEscape)),
            None => out.push(Event::Frame(frame)),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_model_reads_the_rfc_examples() {
        let stream = [
            END, 1, ESC, ESC_END, 2, END, ESC, 7, END, END, 3, ESC, END, 9,
        ];
        assert_eq!(
            model(&stream, SMALL),
            vec![
                Event::Frame(vec![1, END, 2]),
                Event::Dropped(Error::SlipBadEscape),
                Event::Dropped(Error::SlipBadEscape),
            ]
        );
        assert_eq!(
            model(
                &[5; 20].iter().chain(&[END]).copied().collect::<Vec<_>>(),
                SMALL
            ),
            vec![Event::Dropped(Error::SlipOverflow)]
        );
    }

    #[test]
    fn streams_pass() {
        check(&[0, 3, END, 1, 2, END, ESC, 9, END]);
        check(&[2, 1, 0, 200, END, ESC, ESC_ESC, END, 5, 5, 5, END]);
        check(&[]);
    }
}
