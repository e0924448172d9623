//! Serving simulated robots over TCP: each robot on its own listener, SLIP-framed packets, one
//! client at a time; what `pocketbot-sim` runs, usable in-process by tests and tools.
//!
//! A client that leaves takes its queued packets with it: the next one is accepted at once and
//! its first packet from the robot is the hello.

use std::net::SocketAddr;

use protocol::slip::{self, SlipDecoder};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;

use crate::link::LINK_BUFFER_BYTES;
use crate::runtime::{self, LinkSender, Pace, SimHandle};
use crate::Simulation;

/// Starts `sim` with `pace` and serves robot `i` on `bind:port_base + i` (every port free when
/// `port_base` is 0); returns each robot's id and address, the simulation handle and its task.
pub async fn serve(
    sim: Simulation,
    bind: &str,
    port_base: u16,
    pace: Pace,
) -> std::io::Result<(
    Vec<(u16, SocketAddr)>,
    SimHandle,
    tokio::task::JoinHandle<Simulation>,
)> {
    let mut listeners = Vec::new();
    for (i, r) in sim.robots().iter().enumerate() {
        let port = if port_base == 0 {
            0
        } else {
            port_base.saturating_add(i as u16)
        };
        let l = TcpListener::bind((bind, port)).await?;
        listeners.push((r.id(), l));
    }
    let mut addrs = Vec::new();
    for (id, l) in &listeners {
        addrs.push((*id, l.local_addr()?));
    }
    let (handle, ends, task) = runtime::spawn(sim, pace);
    for ((_, listener), end) in listeners.into_iter().zip(ends) {
        tokio::spawn(serve_robot(listener, end));
    }
    Ok((addrs, handle, task))
}

/// Bridges one robot's link to one TCP client at a time.
async fn serve_robot(listener: TcpListener, end: runtime::LinkEnd) {
    let (sender, mut from_robot) = end.split();
    loop {
        let Ok((stream, _)) = listener.accept().await else {
            return;
        };
        let _ = stream.set_nodelay(true);
        // The previous client's `close` guarantees nothing of its session is still to come, so
        // what is in the channel now is all stale and the new client's first packet is the hello.
        while from_robot.try_recv().is_ok() {}
        sender.connect();
        let running = bridge(stream, &sender, &mut from_robot).await;
        sender.close().await;
        if !running {
            return;
        }
    }
}

/// Carries packets between one client and the robot until either ends; `false` once the
/// simulation has stopped.
///
/// The socket is read all the time, whatever the client does with its own side, so a flood never
/// piles up in the kernel: frames beyond the robot's buffer are dropped by the link. Robot packets
/// wait in a buffer of [`LINK_BUFFER_BYTES`] for a client that does not read; beyond, they are
/// dropped and counted in the robot's link statistics.
async fn bridge(
    mut stream: TcpStream,
    sender: &LinkSender,
    from_robot: &mut mpsc::UnboundedReceiver<Vec<u8>>,
) -> bool {
    let (mut rd, mut wr) = stream.split();
    let mut decoder = SlipDecoder::<{ protocol::MAX_PACKET }>::new();
    let mut buf = [0u8; 4096];
    let mut encoded = vec![0u8; slip::max_encoded_len(protocol::MAX_PACKET)];
    // Whole encoded frames, the first possibly partly written.
    let mut pending: Vec<u8> = Vec::with_capacity(LINK_BUFFER_BYTES);
    loop {
        tokio::select! {
            read = rd.read(&mut buf) => {
                let n = match read { Ok(0) | Err(_) => return true, Ok(n) => n };
                for &b in &buf[..n] {
                    // Corrupt frames are counted by the decoder and dropped here.
                    if let Ok(Some(frame)) = decoder.push(b) {
                        if !sender.send_slice(frame) {
                            return false;
                        }
                    }
                }
            }
            packet = from_robot.recv() => {
                let Some(p) = packet else { return false };
                let Ok(n) = slip::encode(&p, &mut encoded) else { continue };
                if pending.len() + n <= LINK_BUFFER_BYTES {
                    pending.extend_from_slice(&encoded[..n]);
                } else {
                    sender.count_dropped_to_host(p.len());
                }
            }
            written = wr.write(&pending), if !pending.is_empty() => {
                match written {
                    Ok(0) | Err(_) => return true,
                    Ok(n) => { pending.drain(..n); }
                }
            }
        }
    }
}
