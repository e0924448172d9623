//! Links over datagram transports that keep message boundaries: one message is one packet.
//!
//! L2CAP sequenced packets and `AF_UNIX SOCK_SEQPACKET` sockets deliver each message whole or, when
//! the receive buffer is too small, truncated. No SLIP is needed; the only framing error is an
//! oversize message, detected by reading into a buffer one byte longer than any packet.

use std::future::Future;
use std::io;
#[cfg(unix)]
use std::path::PathBuf;
use std::sync::Arc;

#[cfg(unix)]
use futures::future::BoxFuture;
#[cfg(unix)]
use futures::FutureExt;
use protocol::MAX_PACKET;
use tokio::sync::mpsc;

#[cfg(unix)]
use super::Connector;
use super::{Link, LinkCounters, LinkError, LinkEvent, SEND_QUEUE};

/// A connected socket that sends and receives whole messages.
///
/// Both methods take `&self` because the link's task sends and receives concurrently.
pub trait Datagram: Send + Sync + 'static {
    /// Sends `message` as one message, returning the bytes sent.
    fn send(&self, message: &[u8]) -> impl Future<Output = io::Result<usize>> + Send;

    /// Receives one message into `buf`, returning its length, 0 when the peer has closed.
    ///
    /// A message longer than `buf` may be truncated; the length returned is then at least
    /// `buf.len()`, so the caller can tell.
    fn recv(&self, buf: &mut [u8]) -> impl Future<Output = io::Result<usize>> + Send;
}

/// Starts the I/O task of a message-per-packet link over `sock` and returns the link.
///
/// Each received message is one [`LinkEvent::Packet`]; a message longer than [`MAX_PACKET`] is
/// dropped and counted in [`LinkCounters::framing_errors`]. Each packet from [`Link::tx`] is sent
/// as one message; empty packets (which the peer would take for a close) and ones longer than
/// [`MAX_PACKET`] are dropped and counted as framing errors too. The task ends with exactly one
/// [`LinkEvent::Closed`]: `None` when the peer closes (a zero-length read) or every sender of `tx`
/// is dropped (the socket is then closed), `Some(LinkError::Lost)` on an I/O error.
///
/// Must be called inside a tokio runtime, which runs the task.
pub fn spawn_datagram_link<D: Datagram>(sock: D, peer: String) -> Link {
    let (tx, packets) = mpsc::channel(SEND_QUEUE);
    let (events, rx) = mpsc::unbounded_channel();
    let counters = Arc::new(LinkCounters::default());
    tokio::spawn(run(sock, peer.clone(), packets, events, counters.clone()));
    Link {
        peer,
        tx,
        rx,
        counters,
    }
}

async fn run<D: Datagram>(
    sock: D,
    peer: String,
    packets: mpsc::Receiver<Vec<u8>>,
    events: mpsc::UnboundedSender<LinkEvent>,
    counters: Arc<LinkCounters>,
) {
    let end = tokio::select! {
        end = recv_messages(&sock, &events, &counters) => end,
        end = send_messages(&sock, packets, &counters) => end,
    };
    // Closing the socket before reporting means the peer has seen the close once the owner hears.
    drop(sock);
    let error = end.err().map(|source| LinkError::Lost { peer, source });
    let _ = events.send(LinkEvent::Closed(error));
}

/// Receives until the peer closes, delivering messages.
async fn recv_messages<D: Datagram>(
    sock: &D,
    events: &mpsc::UnboundedSender<LinkEvent>,
    counters: &LinkCounters,
) -> io::Result<()> {
    // One spare byte: a message that fills it is longer than any packet (or was truncated).
    let mut buf = vec![0u8; MAX_PACKET + 1];
    loop {
        let n = sock.recv(&mut buf).await?;
        if n == 0 {
            return Ok(());
        }
        match buf.get(..n) {
            Some(message) if n <= MAX_PACKET => {
                LinkCounters::bump(&counters.packets_in);
                let _ = events.send(LinkEvent::Packet(message.to_vec()));
            }
            _ => LinkCounters::bump(&counters.framing_errors),
        }
    }
}

/// Sends queued packets until every sender is dropped.
async fn send_messages<D: Datagram>(
    sock: &D,
    mut packets: mpsc::Receiver<Vec<u8>>,
    counters: &LinkCounters,
) -> io::Result<()> {
    while let Some(packet) = packets.recv().await {
        if packet.is_empty() || packet.len() > MAX_PACKET {
            tracing::warn!(len = packet.len(), "dropping a packet no peer can receive");
            LinkCounters::bump(&counters.framing_errors);
            continue;
        }
        let sent = sock.send(&packet).await?;
        if sent != packet.len() {
            // Message sockets send all or nothing; anything else means the peer got half a packet.
            return Err(io::Error::new(
                io::ErrorKind::WriteZero,
                format!("sent {sent} of {} bytes of a message", packet.len()),
            ));
        }
        LinkCounters::bump(&counters.packets_out);
    }
    Ok(())
}

#[cfg(unix)]
impl Datagram for tokio_seqpacket::UnixSeqpacket {
    fn send(&self, message: &[u8]) -> impl Future<Output = io::Result<usize>> + Send {
        tokio_seqpacket::UnixSeqpacket::send(self, message)
    }

    fn recv(&self, buf: &mut [u8]) -> impl Future<Output = io::Result<usize>> + Send {
        let len = buf.len();
        tokio_seqpacket::UnixSeqpacket::recv(self, buf).map(move |info| {
            // Linux returns the bytes copied (`len`) for a cut message; `max` keeps the promise to
            // report at least `len` on systems that might report less.
            info.map(|info| match info.truncated() {
                true => info.bytes_read().max(len),
                false => info.bytes_read(),
            })
        })
    }
}

/// Reaches a robot through an `AF_UNIX SOCK_SEQPACKET` socket (a local bridge or simulator).
#[cfg(unix)]
#[derive(Clone, Debug)]
pub struct UnixSeqpacketConnector {
    /// The socket's path.
    pub path: PathBuf,
}

#[cfg(unix)]
impl Connector for UnixSeqpacketConnector {
    fn peer(&self) -> String {
        format!("seqpacket://{}", self.path.display())
    }

    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let path = self.path.clone();
        let peer = self.peer();
        async move {
            match tokio_seqpacket::UnixSeqpacket::connect(&path).await {
                Ok(sock) => Ok(spawn_datagram_link(sock, peer)),
                Err(source) => Err(LinkError::Connect { peer, source }),
            }
        }
        .boxed()
    }
}
