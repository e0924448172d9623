//! What a gateway costs, measured in one run on this machine: robots' frames delivered to a
//! host (a) over direct TCP links, the coordinator's own link code, and (b) over the same kind of
//! TCP links bridged by one `Gateway` onto zenoh on loopback, read by a zenoh peer as the
//! coordinator reads them.
//!
//! The robots are stand-ins that speak the protocol: each says hello, then sends `Pong` frames
//! whose `host_time_us` field carries the send instant (nanoseconds since the bench began), so
//! every delivered frame gives its latency. Two loads: 50 robots × 50 Hz (the realistic load,
//! latency compared) and saturation (each robot writes frames as fast as its socket takes them,
//! frames per second compared). Run: `cargo bench -p gateway --bench bridge`.

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use gateway::{Gateway, GatewayConfig};
use protocol::packets::{Hello, Pong};
use protocol::Settings;
use robot_actor::link::zenoh::{on_zenoh, open_session, UpBatch, ZenohOptions};
use robot_actor::link::LinkEvent;
use tokio::io::AsyncWriteExt;
use tokio::sync::mpsc;

const ROBOTS: usize = 50;
const RATE_HZ: u64 = 50;
const PACED_FOR: Duration = Duration::from_secs(6);
/// Frames each robot writes in the saturation runs.
const BURST: u32 = 8_000;

fn epoch() -> Instant {
    static EPOCH: OnceLock<Instant> = OnceLock::new();
    *EPOCH.get_or_init(Instant::now)
}

fn now_ns() -> u64 {
    epoch().elapsed().as_nanos() as u64
}

/// One SLIP-framed protocol packet.
fn slip<P: protocol::Packet>(p: &P) -> Vec<u8> {
    let (frame, n) = protocol::frame::encode_to_array(p);
    protocol::slip::encode_iter(&frame[..n]).collect()
}

#[derive(Clone, Copy)]
enum Load {
    Paced,
    Saturate,
}

/// Stand-in robots on loopback ports: each serves one client, says hello and sends its frames.
async fn robots(load: Load) -> Vec<String> {
    let mut addrs = Vec::new();
    for k in 0..ROBOTS {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .expect("a port");
        addrs.push(format!("tcp://{}", listener.local_addr().expect("bound")));
        tokio::spawn(async move {
            let (mut sock, _) = listener.accept().await.expect("a client");
            sock.set_nodelay(true).expect("nodelay");
            let mut settings = Settings::default();
            settings.identity.robot_id = k as u16 + 1;
            sock.write_all(&slip(&Hello::new(&settings, [0, 1, 0])))
                .await
                .expect("hello");
            let pong = |seq| Pong {
                seq,
                host_time_us: now_ns(),
                robot_time_us: 0,
            };
            match load {
                Load::Paced => {
                    let period = Duration::from_nanos(1_000_000_000 / RATE_HZ);
                    // Robots start spread over one period, as real ones do.
                    let start =
                        tokio::time::Instant::now() + period.mul_f64(k as f64 / ROBOTS as f64);
                    let mut tick = tokio::time::interval_at(start, period);
                    let frames = (PACED_FOR.as_secs_f64() * RATE_HZ as f64) as u32;
                    for seq in 0..frames {
                        tick.tick().await;
                        if sock.write_all(&slip(&pong(seq))).await.is_err() {
                            return;
                        }
                    }
                }
                Load::Saturate => {
                    for seq in 0..BURST {
                        if sock.write_all(&slip(&pong(seq))).await.is_err() {
                            return;
                        }
                    }
                }
            }
            // Keep the link open until the reader is done.
            let mut rest = [0u8; 64];
            let _ = tokio::io::AsyncReadExt::read(&mut sock, &mut rest).await;
        });
    }
    addrs
}

/// Latencies (ns) of the frames delivered and the span from the first to the last delivery.
struct Delivered {
    latencies: Vec<u64>,
    span: Duration,
}

impl Delivered {
    fn pct(&self, p: f64) -> f64 {
        let mut v = self.latencies.clone();
        v.sort_unstable();
        let i = ((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
        v[i] as f64 / 1e3
    }

    fn rate(&self) -> f64 {
        self.latencies.len() as f64 / self.span.as_secs_f64()
    }
}

/// Collects `expected` frames' send instants from `rx`, at most `limit`.
async fn collect(
    mut rx: mpsc::UnboundedReceiver<(u64, u64)>,
    expected: usize,
    limit: Duration,
) -> Delivered {
    let mut latencies = Vec::with_capacity(expected);
    let mut first = None;
    let mut last = Instant::now();
    let deadline = tokio::time::Instant::now() + limit;
    while latencies.len() < expected {
        match tokio::time::timeout_at(deadline, rx.recv()).await {
            Ok(Some((sent, got))) => {
                first.get_or_insert_with(Instant::now);
                last = Instant::now();
                latencies.push(got.saturating_sub(sent));
            }
            _ => break,
        }
    }
    Delivered {
        latencies,
        span: last - first.unwrap_or(last),
    }
}

/// A frame's send instant, if it is a stand-in robot's `Pong`.
fn sent_at(packet: &[u8]) -> Option<u64> {
    match protocol::decode(packet) {
        Ok(protocol::AnyPacket::Pong(p)) => Some(p.host_time_us),
        _ => None,
    }
}

/// (a): the host holds every robot's TCP link itself.
async fn direct(load: Load, expected: usize) -> Delivered {
    let (tx, rx) = mpsc::unbounded_channel();
    for addr in robots(load).await {
        let connector = robot_actor::discover::parse_address(&addr).expect("an address");
        let mut link = connector.connect().await.expect("a link");
        let tx = tx.clone();
        tokio::spawn(async move {
            while let Some(LinkEvent::Packet(p)) = link.rx.recv().await {
                if let Some(sent) = sent_at(&p) {
                    let _ = tx.send((sent, now_ns()));
                }
            }
            drop(link.tx);
        });
    }
    drop(tx);
    collect(rx, expected, Duration::from_secs(120)).await
}

/// (b): one gateway holds the links and bridges them onto zenoh; the host is a zenoh peer.
async fn bridged(load: Load, expected: usize, port: u16) -> Delivered {
    let fleet = format!("bench{port}");
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let (tx, rx) = mpsc::unbounded_channel();
    let host = open_session(&ZenohOptions {
        listen: vec![endpoint.clone()],
        ..Default::default()
    })
    .await
    .expect("the host's session");
    let key = format!("pocketfleet/{fleet}/robot/*/up");
    let session = host.clone();
    let subscriber = on_zenoh(async move {
        session
            .session()
            .declare_subscriber(key)
            .callback(move |sample| {
                let got = now_ns();
                let payload = sample.payload().to_bytes();
                for packet in UpBatch::split(&payload).unwrap_or_default() {
                    if let Some(sent) = sent_at(packet) {
                        let _ = tx.send((sent, got));
                    }
                }
            })
            .await
            .expect("a subscriber")
    })
    .await;
    let gateway = Gateway::start(GatewayConfig {
        fleet,
        name: "bench".into(),
        robots: robots(load).await,
        zenoh: ZenohOptions {
            connect: vec![endpoint],
            ..Default::default()
        },
    })
    .await
    .expect("the gateway");
    let delivered = collect(rx, expected, Duration::from_secs(120)).await;
    drop(gateway);
    drop(subscriber);
    delivered
}

fn free_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").expect("a loopback port");
    l.local_addr().expect("bound").port()
}

fn main() {
    // `cargo test --benches` runs benches with --bench absent: do nothing then.
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    epoch();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("a runtime");
    rt.block_on(async {
        let paced = (PACED_FOR.as_secs_f64() * RATE_HZ as f64) as usize * ROBOTS;
        let a = direct(Load::Paced, paced).await;
        let b = bridged(Load::Paced, paced, free_port()).await;
        let burst = BURST as usize * ROBOTS;
        let sa = direct(Load::Saturate, burst).await;
        let sb = bridged(Load::Saturate, burst, free_port()).await;
        println!("{ROBOTS} robots × {RATE_HZ} Hz for {PACED_FOR:?} ({paced} frames), then {BURST} frames per robot as fast as they go");
        println!();
        println!("| path | delivered | frames/s | p50 (µs) | p99 (µs) |");
        println!("|---|---|---|---|---|");
        for (name, d, n) in [
            ("(a) direct TCP, 50 Hz", &a, paced),
            ("(b) gateway + zenoh, 50 Hz", &b, paced),
            ("(a) direct TCP, saturated", &sa, burst),
            ("(b) gateway + zenoh, saturated", &sb, burst),
        ] {
            println!(
                "| {name} | {}/{n} | {:.0} | {:.0} | {:.0} |",
                d.latencies.len(),
                d.rate(),
                d.pct(0.5),
                d.pct(0.99)
            );
        }
        let added_p50 = b.pct(0.5) - a.pct(0.5);
        let added_p99 = b.pct(0.99) - a.pct(0.99);
        println!();
        println!(
            "added by the gateway at 50 × 50 Hz: p50 {added_p50:.0} µs, p99 {added_p99:.0} µs (goal: p99 < 1000 µs: {})",
            if added_p99 < 1000.0 { "met" } else { "not met" }
        );
        println!(
            "gateway at saturation: {:.0} frames/s, {:.2} of direct TCP's {:.0} (goal: ≥ 200000: {})",
            sb.rate(),
            sb.rate() / sa.rate(),
            sa.rate(),
            if sb.rate() >= 200_000.0 { "met" } else { "not met" }
        );
    });
}
