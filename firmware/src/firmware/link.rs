//! The link: packets from the host in (SLIP bytes or whole datagrams), and the queue of packets
//! out, with the counters, refusals and log messages that go through it.

use protocol::packets::Nack;
use protocol::packets::{Event, LogLevel, NackReason, Packet, PacketType};
use protocol::settings::SettingsError;
use protocol::slip::{self};
use protocol::{Error, Frame, MAX_PACKET};

use heapless::Vec;

use super::{Firmware, OutPacket, EVENT_FRAME};
use crate::hal::Board;
use crate::time::Instant;

impl<B: Board> Firmware<B> {
    /// Link entry point for stream transports: SLIP-framed bytes from the host.
    pub fn on_link_bytes(&mut self, now: Instant, bytes: &[u8]) {
        for &b in bytes {
            match self.slip.push(b) {
                Ok(Some(frame)) => {
                    let mut copy = [0u8; MAX_PACKET];
                    let n = frame.len();
                    copy[..n].copy_from_slice(frame);
                    self.on_link_packet(now, &copy[..n]);
                }
                Ok(None) => {}
                Err(_) => self.rx_error(),
            }
        }
    }

    /// Link entry point for datagram transports (L2CAP): one whole packet from the host.
    pub fn on_link_packet(&mut self, now: Instant, bytes: &[u8]) {
        self.now = now;
        match Frame::parse(bytes) {
            Ok(frame) => {
                self.watchdog.feed(now);
                self.state.link.rx_packets = self.state.link.rx_packets.wrapping_add(1);
                self.handle(frame.packet(), frame.payload().len());
            }
            // The checksum held, so the type code is what the host sent: tell it, then drop.
            Err(Error::DecodeUnknownType(code)) => {
                self.rx_error();
                self.nack_code(code, NackReason::UnknownType, Nack::NO_FIELD);
            }
            Err(Error::DecodeBadPayloadLength(t)) => {
                self.rx_error();
                self.nack(t, NackReason::BadLength);
            }
            // A bad checksum or a short frame says nothing trustworthy about its type.
            Err(e) => {
                self.rx_error();
                crate::fw_log!(self, Debug, "protocol", "dropped frame: {}", e);
            }
        }
    }

    /// The link came up: introduce ourselves.
    pub fn on_link_connected(&mut self, now: Instant) {
        self.now = now;
        self.send_hello();
    }

    /// Takes the oldest outgoing packet, for datagram transports.
    pub fn pop_packet(&mut self) -> Option<OutPacket> {
        self.tx.pop_front()
    }

    /// Takes the oldest outgoing packet SLIP-encoded into `out`, returning the length used.
    pub fn pop_slip(&mut self, out: &mut [u8; slip::max_encoded_len(MAX_PACKET)]) -> Option<usize> {
        let p = self.tx.pop_front()?;
        slip::encode(&p, out).ok()
    }

    /// Whether packets are waiting to be sent.
    pub fn has_outgoing(&self) -> bool {
        !self.tx.is_empty()
    }

    /// Sends a log message if its level passes the configured verbosity (see [`fw_log!`](crate::fw_log)).
    pub fn log(&mut self, level: LogLevel, module: &str, args: core::fmt::Arguments<'_>) {
        if let Some(p) = crate::log::format(level, self.settings.log.level, module, args) {
            self.send(&p);
        }
    }

    fn rx_error(&mut self) {
        self.state.link.rx_errors = self.state.link.rx_errors.wrapping_add(1);
    }

    pub(super) fn send<P: Packet>(&mut self, p: &P) {
        let mut buf = OutPacket::new();
        // A fresh buffer holds MAX_PACKET bytes, more than any packet struct.
        let _ = buf.resize_default(MAX_PACKET);
        match protocol::encode(p, &mut buf) {
            Ok(n) => buf.truncate(n),
            Err(_) => return,
        }
        if self.tx.push_back(buf).is_err() {
            self.state.link.tx_dropped = self.state.link.tx_dropped.wrapping_add(1);
        } else {
            self.state.link.tx_packets = self.state.link.tx_packets.wrapping_add(1);
        }
    }

    /// Sends an event stamped now and numbered.
    pub(super) fn send_event<E: Event>(&mut self, mut e: E) {
        e.stamp(self.clock_ms(self.now), 0);
        self.send_event_at(e);
    }

    /// Sends an event whose time is already set (when it began, not when it is reported),
    /// numbered, and keeps it for a replay.
    pub(super) fn send_event_at<E: Event>(&mut self, mut e: E) {
        let seq = self.state.link.events_sent.wrapping_add(1).max(1);
        e.stamp(e.at_ms(), seq);
        self.state.link.events_sent = seq;
        let mut frame: Vec<u8, EVENT_FRAME> = Vec::new();
        let _ = frame.resize_default(EVENT_FRAME);
        if let Ok(n) = protocol::encode(&e, &mut frame) {
            frame.truncate(n);
            if self.events.is_full() {
                self.events.pop_front();
            }
            let _ = self.events.push_back((seq, frame));
        }
        self.send(&e);
    }

    /// Sends again every kept event numbered `from` or later, oldest first.
    pub(super) fn replay_events(&mut self, from: u16) {
        for i in 0..self.events.len() {
            let Some((seq, frame)) = self.events.iter().nth(i) else {
                break;
            };
            if (seq.wrapping_sub(from) as i16) < 0 {
                continue;
            }
            let mut out = OutPacket::new();
            if out.extend_from_slice(frame).is_err() {
                continue;
            }
            if self.tx.push_back(out).is_err() {
                self.state.link.tx_dropped = self.state.link.tx_dropped.wrapping_add(1);
            } else {
                self.state.link.tx_packets = self.state.link.tx_packets.wrapping_add(1);
            }
        }
    }

    pub(super) fn nack(&mut self, t: PacketType, reason: NackReason) {
        self.nack_code(t as u8, reason, Nack::NO_FIELD);
    }

    fn nack_code(&mut self, code: u8, reason: NackReason, field_offset: u16) {
        self.send(&Nack {
            packet_type: code,
            reason: reason as u8,
            field_offset,
        });
    }

    pub(super) fn settings_nack(&mut self, t: PacketType, e: SettingsError) {
        self.nack_code(t as u8, e.nack_reason(), e.field_offset());
    }
}
