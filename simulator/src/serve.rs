//! Serving simulated robots over TCP: each robot on its own listener, SLIP-framed packets, one
//! client at a time; what `pocketbot-sim` runs, usable in-process by tests and tools.

use std::net::SocketAddr;

use protocol::slip::{self, SlipDecoder};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpListener;

use crate::runtime::{self, Pace, SimHandle};
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
        let Ok((mut stream, _)) = listener.accept().await else {
            return;
        };
        let _ = stream.set_nodelay(true);
        while from_robot.try_recv().is_ok() {}
        sender.connect();
        let mut decoder = SlipDecoder::<{ protocol::MAX_PACKET }>::new();
        let mut buf = [0u8; 1024];
        let mut out = vec![0u8; slip::max_encoded_len(protocol::MAX_PACKET)];
        loop {
            tokio::select! {
                read = stream.read(&mut buf) => {
                    let n = match read { Ok(0) | Err(_) => break, Ok(n) => n };
                    for &b in &buf[..n] {
                        // Corrupt frames are counted by the decoder and dropped here.
                        if let Ok(Some(frame)) = decoder.push(b) {
                            sender.send(frame.to_vec());
                        }
                    }
                }
                packet = from_robot.recv() => {
                    let Some(p) = packet else { return };
                    let Ok(n) = slip::encode(&p, &mut out) else { continue };
                    if stream.write_all(&out[..n]).await.is_err() {
                        break;
                    }
                }
            }
        }
        sender.disconnect();
    }
}
