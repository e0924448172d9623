//! A served robot's link is bounded like a serial line: a flood over TCP is read and dropped past
//! the robot's buffer without growing any queue, the robot answers a ping right after it, and a
//! client that leaves takes its queued packets with it so the next one gets the hello at once.

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::time::{Duration, Instant};

use protocol::packets::Ping;
use protocol::slip::{self, SlipDecoder};
use protocol::AnyPacket;
use simulator::link::{LinkStats, LINK_BUFFER_BYTES};
use simulator::runtime::{Pace, SimHandle};
use simulator::serve::serve;
use simulator::world::presets;
use simulator::{SimConfig, Simulation};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// A plain TCP client of one served robot.
struct Client {
    stream: TcpStream,
    decoder: SlipDecoder,
    packets: VecDeque<AnyPacket>,
}

impl Client {
    async fn connect(addr: SocketAddr) -> Self {
        let stream = TcpStream::connect(addr).await.expect("connect");
        stream.set_nodelay(true).unwrap();
        Self {
            stream,
            decoder: SlipDecoder::new(),
            packets: VecDeque::new(),
        }
    }

    /// The next packet from the robot, or `None` if none comes before `deadline`.
    async fn next_before(&mut self, deadline: tokio::time::Instant) -> Option<AnyPacket> {
        let mut buf = vec![0u8; 64 * 1024];
        loop {
            if let Some(p) = self.packets.pop_front() {
                return Some(p);
            }
            let n = tokio::time::timeout_at(deadline, self.stream.read(&mut buf))
                .await
                .ok()?
                .expect("read from the robot");
            assert!(n > 0, "the robot closed the connection");
            for &b in &buf[..n] {
                if let Ok(Some(frame)) = self.decoder.push(b) {
                    if let Ok(p) = protocol::decode(frame) {
                        self.packets.push_back(p);
                    }
                }
            }
        }
    }

    /// Pings every 50 ms until a pong to one of these pings arrives; the wall time it took.
    async fn ping_answered_within(&mut self, limit: Duration) -> Option<Duration> {
        let start = Instant::now();
        let deadline = tokio::time::Instant::now() + limit;
        let mut seq = 1_000_000u32;
        loop {
            seq += 1;
            self.stream.write_all(&ping_frame(seq)).await.unwrap();
            let resend = (tokio::time::Instant::now() + Duration::from_millis(50)).min(deadline);
            while let Some(p) = self.next_before(resend).await {
                if let AnyPacket::Pong(p) = p {
                    if p.seq > 1_000_000 {
                        return Some(start.elapsed());
                    }
                }
            }
            if tokio::time::Instant::now() >= deadline {
                return None;
            }
        }
    }
}

fn ping_frame(seq: u32) -> Vec<u8> {
    let mut packet = [0u8; protocol::MAX_PACKET];
    let n = AnyPacket::from(Ping {
        seq,
        host_time_us: 0,
    })
    .encode(&mut packet)
    .unwrap();
    let mut out = vec![0u8; slip::max_encoded_len(protocol::MAX_PACKET)];
    let m = slip::encode(&packet[..n], &mut out).unwrap();
    out.truncate(m);
    out
}

/// Serves the oval world at wall-clock pace, as `pocketbot-sim` does; the first robot's address.
async fn serve_oval() -> (SocketAddr, SimHandle) {
    let world = presets::preset("oval").expect("oval preset");
    let sim = Simulation::new(
        world,
        SimConfig {
            seed: Some(3),
            ..SimConfig::default()
        },
    );
    let (addrs, handle, _task) = serve(sim, "127.0.0.1", 0, Pace::WallClock)
        .await
        .expect("serve on loopback");
    (addrs[0].1, handle)
}

async fn stats(handle: &SimHandle) -> (LinkStats, (usize, usize)) {
    handle
        .inspect(|sim| {
            let r = &sim.robots()[0];
            (r.link_stats(), r.link_queued_bytes())
        })
        .await
        .expect("simulation running")
}

async fn hello_within(client: &mut Client, limit: Duration) -> Option<Duration> {
    let start = Instant::now();
    let p = client
        .next_before(tokio::time::Instant::now() + limit)
        .await?;
    assert!(
        matches!(p, AnyPacket::Hello(_)),
        "the first packet a new client gets is the hello, not {p:?}"
    );
    Some(start.elapsed())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_16_mb_flood_is_dropped_past_the_robots_buffer_and_the_robot_stays_reachable() {
    let (addr, handle) = serve_oval().await;
    let mut client = Client::connect(addr).await;
    hello_within(&mut client, Duration::from_secs(2))
        .await
        .expect("hello before the flood");

    // 16 MB of valid ping frames, written without reading anything back: the server must keep
    // reading its socket for the writes to finish.
    let frame = ping_frame(1);
    let chunk: Vec<u8> = frame.repeat(64 * 1024 / frame.len());
    let mut sent = 0usize;
    let flood = async {
        while sent < 16 << 20 {
            client.stream.write_all(&chunk).await.unwrap();
            sent += chunk.len();
        }
    };
    tokio::time::timeout(Duration::from_secs(120), flood)
        .await
        .expect("the server stopped reading its socket during the flood");
    let frames = (sent / frame.len()) as u64;

    let answered = client
        .ping_answered_within(Duration::from_secs(5))
        .await
        .expect("no pong within 5 s after the flood");
    let (s, queued) = stats(&handle).await;
    eprintln!(
        "flood of {frames} frames: {} dropped ({} bytes), peaks {} B link / {} B host buffer, \
         ping answered {answered:?} after it",
        s.overflow_to_robot,
        s.overflow_to_robot_bytes,
        s.peak_to_robot_bytes,
        s.peak_host_buffer_bytes
    );
    // The link carries ~700 kbit/s: nearly all of the flood is dropped, and counted.
    assert!(
        s.overflow_to_robot > frames / 2,
        "{} of {frames} frames counted as dropped",
        s.overflow_to_robot
    );
    assert!(s.overflow_to_robot_bytes >= s.overflow_to_robot);
    // Nothing held more than the bound, whatever was sent.
    let bound = LINK_BUFFER_BYTES as u64;
    assert!(s.peak_to_robot_bytes <= bound, "{s:?}");
    assert!(s.peak_host_buffer_bytes <= bound, "{s:?}");
    assert!(
        s.peak_to_robot_bytes > 0 && s.peak_host_buffer_bytes > 0,
        "{s:?}"
    );
    assert!(queued.0 <= LINK_BUFFER_BYTES && queued.1 <= LINK_BUFFER_BYTES);
    assert!(
        answered < Duration::from_secs(2),
        "ping answered {answered:?} after the flood"
    );

    // A new client after the flooding one is served at once.
    drop(client);
    let mut next = Client::connect(addr).await;
    let hello = hello_within(&mut next, Duration::from_secs(2))
        .await
        .expect("no hello within 2 s for a new client after a flood");
    let answered = next
        .ping_answered_within(Duration::from_secs(2))
        .await
        .expect("no pong for the new client within 2 s");
    assert!(hello < Duration::from_secs(1), "hello after {hello:?}");
    assert!(answered < Duration::from_secs(1), "pong after {answered:?}");
    handle.stop();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_new_client_gets_the_hello_at_once_after_one_leaves_mid_burst() {
    let (addr, handle) = serve_oval().await;
    let burst = ping_frame(1).repeat(4000);
    for round in 0..3 {
        let mut client = Client::connect(addr).await;
        let took = hello_within(&mut client, Duration::from_secs(2))
            .await
            .unwrap_or_else(|| panic!("round {round}: no hello within 2 s"));
        assert!(
            took < Duration::from_secs(1),
            "round {round}: hello after {took:?}"
        );
        // Leave with the robot's buffer full and pongs on their way, without reading them.
        client.stream.write_all(&burst).await.unwrap();
    }
    let (s, _) = stats(&handle).await;
    assert!(s.discarded_on_close > 0, "{s:?}");
    handle.stop();
}
