//! Transport bindings end to end: SLIP over TCP, Unix streams and a tiny pipe, message-per-packet
//! over `SOCK_SEQPACKET` (the L2CAP framing path), and robot address parsing.

use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use protocol::slip::{self, END, ESC};
use protocol::MAX_PACKET;
use robot_actor::discover::{parse_address, StaticList, DEFAULT_BAUD};
use robot_actor::link::seqpacket::{spawn_datagram_link, UnixSeqpacketConnector};
use robot_actor::link::stream::{spawn_stream_link, SerialConnector, TcpConnector, UnixConnector};
use robot_actor::link::{Connector, Discoverer, Link, LinkError, LinkEvent};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, UnixListener};
use tokio_seqpacket::{UnixSeqpacket, UnixSeqpacketListener};

/// Only a safety net: every wait below ends on an event long before this.
const SAFETY: Duration = Duration::from_secs(10);

async fn within<F: std::future::Future>(what: &str, f: F) -> F::Output {
    tokio::time::timeout(SAFETY, f)
        .await
        .unwrap_or_else(|_| panic!("timed out waiting for {what}"))
}

async fn next_event(link: &mut Link) -> LinkEvent {
    within("a link event", link.rx.recv())
        .await
        .expect("the link's task ended without reporting Closed")
}

async fn expect_packet(link: &mut Link, want: &[u8]) {
    match next_event(link).await {
        LinkEvent::Packet(p) => assert_eq!(p, want),
        other => panic!("expected packet {want:?}, got {other:?}"),
    }
}

async fn expect_clean_close(link: &mut Link) {
    match next_event(link).await {
        LinkEvent::Closed(None) => {}
        other => panic!("expected a clean close, got {other:?}"),
    }
    assert!(
        within("the event channel to end", link.rx.recv())
            .await
            .is_none(),
        "Closed must be the last event"
    );
}

fn count(counter: &std::sync::atomic::AtomicU64) -> u64 {
    counter.load(Ordering::Relaxed)
}

fn slip_encoded(packets: &[&[u8]]) -> Vec<u8> {
    packets.iter().flat_map(|p| slip::encode_iter(p)).collect()
}

/// A path in the temp dir no other test (or test run) uses; removed on drop.
struct TempPath(std::path::PathBuf);

impl TempPath {
    fn new(name: &str) -> Self {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let unique = format!(
            "robot-actor-{}-{}-{name}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        );
        let path = std::env::temp_dir().join(unique);
        let _ = std::fs::remove_file(&path);
        Self(path)
    }
}

impl Drop for TempPath {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// Packets with bytes SLIP must escape, so the escaping is exercised too.
const P1: &[u8] = &[1, END, 2, ESC, 3];
const P2: &[u8] = &[ESC, ESC, END];
const P3: &[u8] = &[0x10, 0x20, 0x30, 0x40, 0x50, 0x60, 0x70];

/// Good frames around a frame with an invalid escape (ESC followed by 0x07).
fn stream_with_one_bad_frame() -> Vec<u8> {
    let mut bytes = slip_encoded(&[P1]);
    bytes.extend([END, 0x55, ESC, 0x07, 0x66, END]);
    bytes.extend(slip_encoded(&[P2, P3]));
    bytes
}

#[tokio::test]
async fn tcp_slip_link_reassembles_chunks_skips_a_bad_frame_and_sends_frames() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let connector = TcpConnector {
        addr: listener.local_addr().unwrap().to_string(),
    };
    let (link, accepted) = within("connect and accept", async {
        tokio::join!(connector.connect(), listener.accept())
    })
    .await;
    let mut link = link.unwrap();
    let (mut robot, _) = accepted.unwrap();
    robot.set_nodelay(true).unwrap();
    assert_eq!(link.peer, connector.peer());

    // Chunk sizes cycle through 1, 2, 3, 5, 8 bytes so frames and escapes straddle writes.
    let bytes = stream_with_one_bad_frame();
    let mut rest = &bytes[..];
    for size in [1, 2, 3, 5, 8].into_iter().cycle() {
        if rest.is_empty() {
            break;
        }
        let (chunk, tail) = rest.split_at(size.min(rest.len()));
        robot.write_all(chunk).await.unwrap();
        rest = tail;
    }
    expect_packet(&mut link, P1).await;
    expect_packet(&mut link, P2).await;
    expect_packet(&mut link, P3).await;
    assert_eq!(count(&link.counters.framing_errors), 1);
    assert_eq!(count(&link.counters.packets_in), 3);

    link.tx.send(P1.to_vec()).await.unwrap();
    link.tx.send(P3.to_vec()).await.unwrap();
    let want = slip_encoded(&[P1, P3]);
    let mut got = vec![0u8; want.len()];
    within("the frames at the robot", robot.read_exact(&mut got))
        .await
        .unwrap();
    assert_eq!(got, want);

    drop(robot);
    expect_clean_close(&mut link).await;
    assert_eq!(count(&link.counters.packets_out), 2);
}

#[tokio::test]
async fn slip_link_over_a_one_byte_pipe_delivers_every_frame() {
    // A duplex pipe holding one byte forces every read to return a single byte.
    let (ours, mut robot) = tokio::io::duplex(1);
    let mut link = spawn_stream_link(ours, "pipe".into());
    let writer = tokio::spawn(async move {
        robot.write_all(&stream_with_one_bad_frame()).await.unwrap();
        robot
    });
    expect_packet(&mut link, P1).await;
    expect_packet(&mut link, P2).await;
    expect_packet(&mut link, P3).await;
    assert_eq!(count(&link.counters.framing_errors), 1);
    drop(within("the writer", writer).await.unwrap());
    expect_clean_close(&mut link).await;
}

#[tokio::test]
async fn dropping_tx_closes_a_stream_link_and_the_robot_sees_eof() {
    let (ours, mut robot) = tokio::io::duplex(64);
    let mut link = spawn_stream_link(ours, "pipe".into());
    link.tx.send(P2.to_vec()).await.unwrap();
    // Packets no robot could receive are dropped and counted, not sent.
    link.tx.send(Vec::new()).await.unwrap();
    link.tx.send(vec![7; MAX_PACKET + 1]).await.unwrap();
    drop(link.tx);
    let mut got = Vec::new();
    within("end of file at the robot", robot.read_to_end(&mut got))
        .await
        .unwrap();
    assert_eq!(got, slip_encoded(&[P2]));
    match within("the close", link.rx.recv()).await {
        Some(LinkEvent::Closed(None)) => {}
        other => panic!("expected a clean close, got {other:?}"),
    }
    assert_eq!(count(&link.counters.packets_out), 1);
    assert_eq!(count(&link.counters.framing_errors), 2);
}

#[tokio::test]
async fn unix_stream_connector_carries_slip_both_ways() {
    let path = TempPath::new("stream.sock");
    let listener = UnixListener::bind(&path.0).unwrap();
    let connector = UnixConnector {
        path: path.0.clone(),
    };
    let (link, accepted) = within("connect and accept", async {
        tokio::join!(connector.connect(), listener.accept())
    })
    .await;
    let mut link = link.unwrap();
    let (mut robot, _) = accepted.unwrap();

    robot.write_all(&slip_encoded(&[P3, P1])).await.unwrap();
    expect_packet(&mut link, P3).await;
    expect_packet(&mut link, P1).await;

    link.tx.send(P2.to_vec()).await.unwrap();
    let want = slip_encoded(&[P2]);
    let mut got = vec![0u8; want.len()];
    within("the frame at the robot", robot.read_exact(&mut got))
        .await
        .unwrap();
    assert_eq!(got, want);

    drop(robot);
    expect_clean_close(&mut link).await;
}

#[tokio::test]
async fn seqpacket_link_is_one_message_per_packet_and_drops_oversize_messages() {
    let (ours, robot) = UnixSeqpacket::pair().unwrap();
    let mut link = spawn_datagram_link(ours, "pair".into());

    robot.send(P1).await.unwrap();
    robot.send(P2).await.unwrap();
    expect_packet(&mut link, P1).await;
    expect_packet(&mut link, P2).await;

    robot.send(&[0xAB; MAX_PACKET + 10]).await.unwrap();
    robot.send(P3).await.unwrap();
    expect_packet(&mut link, P3).await;
    assert_eq!(count(&link.counters.framing_errors), 1);
    assert_eq!(count(&link.counters.packets_in), 3);

    // The largest packet fits exactly.
    let largest = vec![0x5A; MAX_PACKET];
    robot.send(&largest).await.unwrap();
    expect_packet(&mut link, &largest).await;

    link.tx.send(P1.to_vec()).await.unwrap();
    link.tx.send(vec![1; MAX_PACKET + 1]).await.unwrap();
    link.tx.send(P3.to_vec()).await.unwrap();
    let mut buf = vec![0u8; 2 * MAX_PACKET];
    for want in [P1, P3] {
        let info = within("a message at the robot", robot.recv(&mut buf))
            .await
            .unwrap();
        assert!(!info.truncated());
        assert_eq!(&buf[..info.bytes_read()], want);
    }
    assert_eq!(count(&link.counters.framing_errors), 2);

    drop(robot);
    expect_clean_close(&mut link).await;
    assert_eq!(count(&link.counters.packets_out), 2);
}

#[tokio::test]
async fn dropping_tx_closes_a_seqpacket_link_and_the_robot_sees_the_close() {
    let (ours, robot) = UnixSeqpacket::pair().unwrap();
    let mut link = spawn_datagram_link(ours, "pair".into());
    drop(link.tx);
    let mut buf = [0u8; 16];
    let info = within("the close at the robot", robot.recv(&mut buf))
        .await
        .unwrap();
    assert_eq!(info.bytes_read(), 0);
    match within("the close", link.rx.recv()).await {
        Some(LinkEvent::Closed(None)) => {}
        other => panic!("expected a clean close, got {other:?}"),
    }
}

#[tokio::test]
async fn seqpacket_connector_reaches_a_listener() {
    let path = TempPath::new("seqpacket.sock");
    let mut listener = UnixSeqpacketListener::bind(&path.0).unwrap();
    let connector = UnixSeqpacketConnector {
        path: path.0.clone(),
    };
    let (link, accepted) = within("connect and accept", async {
        tokio::join!(connector.connect(), listener.accept())
    })
    .await;
    let mut link = link.unwrap();
    let robot = accepted.unwrap();
    assert_eq!(link.peer, format!("seqpacket://{}", path.0.display()));

    robot.send(P2).await.unwrap();
    expect_packet(&mut link, P2).await;
    link.tx.send(P3.to_vec()).await.unwrap();
    let mut buf = [0u8; MAX_PACKET + 1];
    let info = within("a message at the robot", robot.recv(&mut buf))
        .await
        .unwrap();
    assert_eq!(&buf[..info.bytes_read()], P3);

    drop(robot);
    expect_clean_close(&mut link).await;
}

#[tokio::test]
async fn failed_connects_are_connect_errors() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    drop(listener);
    let tcp = TcpConnector { addr }.connect();
    let missing = TempPath::new("missing.sock");
    let unix = UnixConnector {
        path: missing.0.clone(),
    }
    .connect();
    let seqpacket = UnixSeqpacketConnector {
        path: missing.0.clone(),
    }
    .connect();
    let serial = SerialConnector {
        path: missing.0.display().to_string(),
        baud: DEFAULT_BAUD,
    }
    .connect();
    for result in [
        within("tcp", tcp).await,
        within("unix", unix).await,
        within("seqpacket", seqpacket).await,
        within("serial", serial).await,
    ] {
        match result {
            Err(LinkError::Connect { .. }) => {}
            other => panic!("expected a connect error, got {other:?}"),
        }
    }
}

fn bad_reason(address: &str) -> String {
    match parse_address(address) {
        Err(LinkError::BadAddress { address: a, reason }) => {
            assert_eq!(a, address);
            reason
        }
        Err(other) => panic!("{address:?}: expected BadAddress, got {other}"),
        Ok(c) => panic!("{address:?}: expected BadAddress, got {}", c.peer()),
    }
}

#[test]
fn parse_address_accepts_every_transport() {
    let peer = |a: &str| parse_address(a).unwrap().peer();
    assert_eq!(peer("tcp://127.0.0.1:7000"), "tcp://127.0.0.1:7000");
    assert_eq!(peer("tcp://robot.local:7000"), "tcp://robot.local:7000");
    assert_eq!(peer("tcp://[::1]:7000"), "tcp://[::1]:7000");
    assert_eq!(peer(" unix:///run/bot.sock "), "unix:///run/bot.sock");
    assert_eq!(
        peer("seqpacket:///run/bot.sock"),
        "seqpacket:///run/bot.sock"
    );
    assert_eq!(
        peer("serial:///dev/ttyUSB0"),
        "serial:///dev/ttyUSB0?baud=115200"
    );
    assert_eq!(
        peer("serial:///dev/ttyACM1?baud=9600"),
        "serial:///dev/ttyACM1?baud=9600"
    );
    // Every connector's peer() parses back to the same peer.
    for address in [
        "tcp://10.0.0.2:1",
        "unix:///tmp/x.sock",
        "serial:///dev/ttyS0?baud=57600",
    ] {
        assert_eq!(peer(&peer(address)), peer(address));
    }
}

#[cfg(not(feature = "bluetooth"))]
#[test]
fn bluetooth_addresses_need_the_feature() {
    for address in [
        "bt://AA:BB:CC:DD:EE:FF",
        "bt://aa:bb:cc:dd:ee:ff?psm=0x1003",
    ] {
        match parse_address(address) {
            Err(LinkError::Unavailable("bluetooth", why)) => assert!(why.contains("feature")),
            Err(other) => panic!("{address}: expected Unavailable, got {other}"),
            Ok(c) => panic!("{address}: expected Unavailable, got {}", c.peer()),
        }
    }
}

#[cfg(feature = "bluetooth")]
#[test]
fn bluetooth_addresses_parse_and_round_trip() {
    let peer = |a: &str| parse_address(a).unwrap().peer();
    assert_eq!(
        peer("bt://aa:bb:cc:dd:ee:ff"),
        "bt://AA:BB:CC:DD:EE:FF?psm=0x1001"
    );
    assert_eq!(
        peer("bt://AA:BB:CC:DD:EE:FF?psm=129&type=le-random"),
        "bt://AA:BB:CC:DD:EE:FF?psm=0x0081&type=le-random"
    );
    let p = peer("bt://AA:BB:CC:DD:EE:FF?psm=0x1003");
    assert_eq!(peer(&p), p);
}

#[test]
fn parse_address_says_what_is_wrong() {
    let cases = [
        ("localhost:7000", "SCHEME://"),
        ("ftp://robot:21", "unknown scheme \"ftp\""),
        ("tcp://localhost", "missing port"),
        ("tcp://localhost:", "missing port"),
        ("tcp://:7000", "missing host"),
        ("tcp://localhost:http", "bad port"),
        ("tcp://localhost:70000", "bad port"),
        ("tcp://::1:7000", "brackets"),
        ("unix://", "missing socket path"),
        ("seqpacket://", "missing socket path"),
        ("serial://", "missing device"),
        ("serial:///dev/ttyUSB0?baud=fast", "bad baud rate"),
        ("serial:///dev/ttyUSB0?baud=0", "bad baud rate"),
        (
            "serial:///dev/ttyUSB0?speed=9600",
            "unknown option \"speed\"",
        ),
        ("serial:///dev/ttyUSB0?baud", "no value"),
        ("bt://AA:BB:CC:DD:EE", "bad MAC"),
        ("bt://AA:BB:CC:DD:EE:FF:00", "bad MAC"),
        ("bt://AA:BB:CC:DD:EE:GG", "bad MAC"),
        ("bt://AABBCCDDEEFF", "bad MAC"),
        ("bt://AA:BB:CC:DD:EE:FF?psm=x", "bad psm"),
        ("bt://AA:BB:CC:DD:EE:FF?psm=0x1002", "bad BR/EDR psm"),
        ("bt://AA:BB:CC:DD:EE:FF?type=le", "needs ?psm"),
        ("bt://AA:BB:CC:DD:EE:FF?type=le&psm=0x1001", "bad LE psm"),
        ("bt://AA:BB:CC:DD:EE:FF?type=radio", "bad address type"),
        ("bt://AA:BB:CC:DD:EE:FF?psm=1&psm=3", "given twice"),
    ];
    for (address, want) in cases {
        let reason = bad_reason(address);
        assert!(
            reason.contains(want),
            "{address:?}: reason {reason:?} does not mention {want:?}"
        );
    }
}

#[tokio::test]
async fn static_list_parses_every_address_and_names_a_bad_one() {
    let list = StaticList {
        addresses: vec![
            "tcp://127.0.0.1:7000".into(),
            "serial:///dev/ttyUSB0".into(),
        ],
    };
    let found = list.discover().await.unwrap();
    let names: Vec<_> = found.iter().map(|d| d.name.as_str()).collect();
    assert_eq!(names, ["tcp://127.0.0.1:7000", "serial:///dev/ttyUSB0"]);
    assert_eq!(
        found[1].connector.peer(),
        "serial:///dev/ttyUSB0?baud=115200"
    );

    let list = StaticList {
        addresses: vec!["tcp://127.0.0.1:7000".into(), "tcp://nowhere".into()],
    };
    match list.discover().await {
        Err(e @ LinkError::BadAddress { .. }) => assert!(e.to_string().contains("tcp://nowhere")),
        other => panic!("expected BadAddress, got {other:?}"),
    }
}

#[cfg(feature = "bluetooth")]
#[tokio::test]
async fn bluetooth_without_a_radio_fails_without_panicking() {
    use robot_actor::discover::{BluezDiscoverer, L2capConnector};
    let connector = L2capConnector::new(bluer::Address::new([0xAA, 0xBB, 0xCC, 0xDD, 0xEE, 0xFF]));
    match within("an L2CAP connect", connector.connect()).await {
        Ok(_) => {}
        Err(LinkError::Unavailable(..) | LinkError::Connect { .. }) => {}
        Err(other) => panic!("unexpected error {other}"),
    }
    let discoverer = BluezDiscoverer {
        scan_for: Duration::from_millis(100),
        ..BluezDiscoverer::default()
    };
    match within("a BlueZ scan", discoverer.discover()).await {
        Ok(_) | Err(LinkError::Unavailable(..)) => {}
        Err(other) => panic!("unexpected error {other}"),
    }
}
