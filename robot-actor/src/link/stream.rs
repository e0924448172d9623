//! SLIP over byte streams (TCP, Unix stream sockets, serial ports): one packet per SLIP frame.
//!
//! A byte stream has no message boundaries, so every packet travels as one SLIP frame (thesis
//! 5.2) and the receiving side re-assembles frames from whatever chunks the stream delivers.

use std::io;
#[cfg(unix)]
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;

use futures::future::BoxFuture;
use futures::FutureExt;
use protocol::slip::{self, SlipDecoder};
use protocol::MAX_PACKET;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::mpsc;

use super::{Connector, Link, LinkCounters, LinkError, LinkEvent, SEND_QUEUE};

/// Bytes asked of the stream per read.
const READ_CHUNK: usize = 4096;

/// Encoded bytes gathered from already-queued packets into one write.
const COALESCE_BYTES: usize = 8 * 1024;

/// Starts the I/O task of a SLIP link over `io` and returns the link.
///
/// The task delivers each received frame as [`LinkEvent::Packet`] (counting dropped frames in
/// [`LinkCounters::framing_errors`]), writes each packet from [`Link::tx`] as one SLIP frame, and
/// ends with exactly one [`LinkEvent::Closed`]: `None` when the peer closes the stream or every
/// sender of `tx` is dropped (the write side is then shut down, so the peer sees end of file),
/// `Some(LinkError::Lost)` on an I/O error. Outgoing packets that are empty or longer than
/// [`MAX_PACKET`] are dropped and counted as framing errors, since no peer can receive them.
///
/// For TCP, set `TCP_NODELAY` on the stream first (as [`TcpConnector`] does): small SLIP frames
/// otherwise wait for the peer's delayed ACK.
///
/// Must be called inside a tokio runtime, which runs the task.
pub fn spawn_stream_link<S>(io: S, peer: String) -> Link
where
    S: AsyncRead + AsyncWrite + Send + Unpin + 'static,
{
    let (tx, packets) = mpsc::channel(SEND_QUEUE);
    let (events, rx) = mpsc::unbounded_channel();
    let counters = Arc::new(LinkCounters::default());
    tokio::spawn(run(io, peer.clone(), packets, events, counters.clone()));
    Link {
        peer,
        tx,
        rx,
        counters,
    }
}

async fn run<S>(
    io: S,
    peer: String,
    packets: mpsc::Receiver<Vec<u8>>,
    events: mpsc::UnboundedSender<LinkEvent>,
    counters: Arc<LinkCounters>,
) where
    S: AsyncRead + AsyncWrite + Send + Unpin + 'static,
{
    let (reader, writer) = tokio::io::split(io);
    // Whichever direction ends first ends the link: a half-open robot link is of no use.
    let end = tokio::select! {
        end = read_frames(reader, &events, &counters) => end,
        end = write_frames(writer, packets, &counters) => end,
    };
    let error = end.err().map(|source| LinkError::Lost { peer, source });
    // The owner may have dropped `rx` already; then nobody is left to tell.
    let _ = events.send(LinkEvent::Closed(error));
}

/// Reads until end of file, delivering frames.
async fn read_frames<R: AsyncRead + Unpin>(
    mut reader: R,
    events: &mpsc::UnboundedSender<LinkEvent>,
    counters: &LinkCounters,
) -> io::Result<()> {
    // Boxed to keep the task's future small; the decoder holds a whole frame.
    let mut decoder = Box::new(SlipDecoder::<MAX_PACKET>::new());
    let mut buf = vec![0u8; READ_CHUNK];
    loop {
        let n = reader.read(&mut buf).await?;
        if n == 0 {
            return Ok(());
        }
        for &byte in &buf[..n] {
            match decoder.push(byte) {
                Ok(Some(frame)) => {
                    LinkCounters::bump(&counters.packets_in);
                    let _ = events.send(LinkEvent::Packet(frame.to_vec()));
                }
                Ok(None) => {}
                Err(_) => LinkCounters::bump(&counters.framing_errors),
            }
        }
    }
}

/// Writes queued packets until every sender is dropped, then shuts the write side down.
async fn write_frames<W: AsyncWrite + Unpin>(
    mut writer: W,
    mut packets: mpsc::Receiver<Vec<u8>>,
    counters: &LinkCounters,
) -> io::Result<()> {
    let mut buf = Vec::with_capacity(COALESCE_BYTES + slip::max_encoded_len(MAX_PACKET));
    while let Some(first) = packets.recv().await {
        buf.clear();
        let mut count = u64::from(encode_packet(&first, &mut buf, counters));
        // A burst of queued packets goes out in one write (one syscall, often one TCP segment).
        while buf.len() < COALESCE_BYTES {
            match packets.try_recv() {
                Ok(packet) => count += u64::from(encode_packet(&packet, &mut buf, counters)),
                Err(_) => break,
            }
        }
        if buf.is_empty() {
            continue;
        }
        writer.write_all(&buf).await?;
        writer.flush().await?;
        counters.packets_out.fetch_add(count, Ordering::Relaxed);
    }
    // Closing is clean whatever the peer did meanwhile; a failed shutdown only means it left first.
    let _ = writer.shutdown().await;
    Ok(())
}

/// Appends the SLIP frame of `packet` to `buf`; false if the packet was dropped as unsendable.
fn encode_packet(packet: &[u8], buf: &mut Vec<u8>, counters: &LinkCounters) -> bool {
    if packet.is_empty() || packet.len() > MAX_PACKET {
        tracing::warn!(len = packet.len(), "dropping a packet no peer can receive");
        LinkCounters::bump(&counters.framing_errors);
        return false;
    }
    buf.extend(slip::encode_iter(packet));
    true
}

/// Reaches a robot (or a simulator, or the QEMU UART bridge) over TCP.
#[derive(Clone, Debug)]
pub struct TcpConnector {
    /// `HOST:PORT`, as `tokio::net::TcpStream::connect` takes it.
    pub addr: String,
}

impl Connector for TcpConnector {
    fn peer(&self) -> String {
        format!("tcp://{}", self.addr)
    }

    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let addr = self.addr.clone();
        let peer = self.peer();
        async move {
            let connect_error = |source| LinkError::Connect {
                peer: peer.clone(),
                source,
            };
            let stream = tokio::net::TcpStream::connect(&addr)
                .await
                .map_err(connect_error)?;
            stream.set_nodelay(true).map_err(connect_error)?;
            Ok(spawn_stream_link(stream, peer))
        }
        .boxed()
    }
}

/// Reaches a robot through a Unix stream socket (a local bridge or simulator).
#[cfg(unix)]
#[derive(Clone, Debug)]
pub struct UnixConnector {
    /// The socket's path.
    pub path: PathBuf,
}

#[cfg(unix)]
impl Connector for UnixConnector {
    fn peer(&self) -> String {
        format!("unix://{}", self.path.display())
    }

    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let path = self.path.clone();
        let peer = self.peer();
        async move {
            match tokio::net::UnixStream::connect(&path).await {
                Ok(stream) => Ok(spawn_stream_link(stream, peer)),
                Err(source) => Err(LinkError::Connect { peer, source }),
            }
        }
        .boxed()
    }
}

/// Reaches a robot through a serial port (a USB-serial adapter or the robot's own USB CDC port).
#[derive(Clone, Debug)]
pub struct SerialConnector {
    /// The device, e.g. `/dev/ttyUSB0`.
    pub path: String,
    /// Baud rate; 8 data bits, no parity, one stop bit, no flow control.
    pub baud: u32,
}

impl Connector for SerialConnector {
    fn peer(&self) -> String {
        format!("serial://{}?baud={}", self.path, self.baud)
    }

    fn connect(&self) -> BoxFuture<'static, Result<Link, LinkError>> {
        let builder = tokio_serial::new(self.path.clone(), self.baud);
        let peer = self.peer();
        async move {
            match tokio_serial::SerialStream::open(&builder) {
                Ok(port) => Ok(spawn_stream_link(port, peer)),
                Err(e) => Err(LinkError::Connect {
                    peer,
                    source: io::Error::from(e),
                }),
            }
        }
        .boxed()
    }
}
