//! SLIP framing (RFC 1055) for byte-stream links: serial ports, TCP, the QEMU UART (thesis 5.2).
//!
//! The decoder takes bytes in any chunking, keeps at most `N` bytes of one frame, and counts what
//! it drops; it never panics. Frames start and end with `END`, so line noise before a frame is
//! flushed as an empty or bad frame.

use crate::Error;

/// Frame delimiter.
pub const END: u8 = 0xC0;
/// Escape byte.
pub const ESC: u8 = 0xDB;
/// Escaped `END`.
pub const ESC_END: u8 = 0xDC;
/// Escaped `ESC`.
pub const ESC_ESC: u8 = 0xDD;

/// Upper bound of the encoded size of a `len`-byte frame.
pub const fn max_encoded_len(len: usize) -> usize {
    2 * len + 2
}

/// Iterator over the SLIP encoding of one frame (leading and trailing `END` included).
#[derive(Clone, Debug)]
pub struct EncodeIter<'a> {
    frame: &'a [u8],
    pos: usize,
    pending: Option<u8>,
    started: bool,
    done: bool,
}

/// Encodes `frame` lazily, one byte at a time; suits a UART transmit interrupt.
pub fn encode_iter(frame: &[u8]) -> EncodeIter<'_> {
    EncodeIter {
        frame,
        pos: 0,
        pending: None,
        started: false,
        done: false,
    }
}

impl Iterator for EncodeIter<'_> {
    type Item = u8;
    fn next(&mut self) -> Option<u8> {
        if !self.started {
            self.started = true;
            return Some(END);
        }
        if let Some(b) = self.pending.take() {
            return Some(b);
        }
        if let Some(&b) = self.frame.get(self.pos) {
            self.pos += 1;
            return Some(match b {
                END => {
                    self.pending = Some(ESC_END);
                    ESC
                }
                ESC => {
                    self.pending = Some(ESC_ESC);
                    ESC
                }
                b => b,
            });
        }
        if !self.done {
            self.done = true;
            return Some(END);
        }
        None
    }
}

/// Encodes `frame` into `out`, returning the encoded length.
pub fn encode(frame: &[u8], out: &mut [u8]) -> Result<usize, Error> {
    let mut n = 0;
    for b in encode_iter(frame) {
        *out.get_mut(n).ok_or(Error::EncodeBufferTooSmall)? = b;
        n += 1;
    }
    Ok(n)
}

/// Counters of what the decoder dropped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SlipStats {
    /// Complete frames delivered.
    pub frames: u32,
    /// Frames dropped for exceeding the buffer.
    pub overflows: u32,
    /// Frames dropped for an invalid escape sequence.
    pub bad_escapes: u32,
}

/// Incremental SLIP decoder holding at most `N` bytes of one frame.
#[derive(Clone, Debug)]
pub struct SlipDecoder<const N: usize = { crate::MAX_PACKET }> {
    buf: [u8; N],
    len: usize,
    escaped: bool,
    /// Set after an error: bytes are skipped until the next `END`.
    discarding: bool,
    stats: SlipStats,
}

impl<const N: usize> Default for SlipDecoder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> SlipDecoder<N> {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            len: 0,
            escaped: false,
            discarding: false,
            stats: SlipStats {
                frames: 0,
                overflows: 0,
                bad_escapes: 0,
            },
        }
    }

    /// What was delivered and dropped so far.
    pub fn stats(&self) -> SlipStats {
        self.stats
    }

    /// Feeds one byte: `Ok(Some(frame))` when a frame ends, `Err` when a frame is dropped.
    pub fn push(&mut self, byte: u8) -> Result<Option<&[u8]>, Error> {
        if byte == END {
            let len = core::mem::replace(&mut self.len, 0);
            let was_discarding = core::mem::replace(&mut self.discarding, false);
            let escaped = core::mem::replace(&mut self.escaped, false);
            if was_discarding || len == 0 {
                return Ok(None);
            }
            if escaped {
                self.stats.bad_escapes += 1;
                return Err(Error::SlipBadEscape);
            }
            self.stats.frames += 1;
            return Ok(Some(&self.buf[..len]));
        }
        if self.discarding {
            return Ok(None);
        }
        let b = if self.escaped {
            self.escaped = false;
            match byte {
                ESC_END => END,
                ESC_ESC => ESC,
                _ => {
                    self.fail();
                    self.stats.bad_escapes += 1;
                    return Err(Error::SlipBadEscape);
                }
            }
        } else if byte == ESC {
            self.escaped = true;
            return Ok(None);
        } else {
            byte
        };
        if self.len == N {
            self.fail();
            self.stats.overflows += 1;
            return Err(Error::SlipOverflow);
        }
        self.buf[self.len] = b;
        self.len += 1;
        Ok(None)
    }

    fn fail(&mut self) {
        self.len = 0;
        self.escaped = false;
        self.discarding = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode_all(bytes: &[u8]) -> (Vec<Vec<u8>>, SlipStats) {
        let mut d = SlipDecoder::<16>::new();
        let mut out = Vec::new();
        for &b in bytes {
            if let Ok(Some(f)) = d.push(b) {
                out.push(f.to_vec());
            }
        }
        (out, d.stats())
    }

    #[test]
    fn escapes_round_trip() {
        let frame = [1, END, 2, ESC, 3, ESC_END, ESC_ESC];
        let mut enc = [0u8; 32];
        let n = encode(&frame, &mut enc).unwrap();
        assert_eq!(
            &enc[..n],
            &[END, 1, ESC, ESC_END, 2, ESC, ESC_ESC, 3, ESC_END, ESC_ESC, END]
        );
        assert_eq!(decode_all(&enc[..n]).0, vec![frame.to_vec()]);
    }

    #[test]
    fn overflow_drops_one_frame_and_recovers() {
        let mut bytes = vec![END];
        bytes.extend([7u8; 20]);
        bytes.push(END);
        bytes.extend([1, 2, END]);
        let (frames, stats) = decode_all(&bytes);
        assert_eq!(frames, vec![vec![1, 2]]);
        assert_eq!(stats.overflows, 1);
        assert_eq!(stats.frames, 1);
    }

    #[test]
    fn bad_escape_drops_one_frame_and_recovers() {
        let (frames, stats) = decode_all(&[END, 1, ESC, 9, 2, END, 3, END, 4, ESC, END]);
        assert_eq!(frames, vec![vec![3]]);
        assert_eq!(stats.bad_escapes, 2);
    }

    #[test]
    fn small_output_buffer_is_an_error() {
        assert_eq!(
            encode(&[1, 2, 3], &mut [0u8; 4]),
            Err(Error::EncodeBufferTooSmall)
        );
    }
}
