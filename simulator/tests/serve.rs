//! `pocketbot-sim` serves each robot on its own TCP port with SLIP framing: a plain TCP client
//! gets a hello and answers to pings from every robot.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use protocol::packets::Ping;
use protocol::slip::{self, SlipDecoder};
use protocol::AnyPacket;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

async fn next_packet(stream: &mut TcpStream, dec: &mut SlipDecoder) -> AnyPacket {
    let mut byte = [0u8; 1];
    loop {
        stream
            .read_exact(&mut byte)
            .await
            .expect("robot closed the connection");
        if let Ok(Some(frame)) = dec.push(byte[0]) {
            if let Ok(p) = protocol::decode(frame) {
                return p;
            }
        }
    }
}

#[tokio::test]
async fn serves_every_robot_of_push_over_tcp() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_pocketbot-sim"))
        .args(["--world", "push", "--port-base", "0", "--duration", "60"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("start pocketbot-sim");
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let mut robots = Vec::new();
    for line in lines.by_ref() {
        let line = line.unwrap();
        if line.starts_with("serving") {
            break;
        }
        let mut parts = line.split_whitespace();
        assert_eq!(parts.next(), Some("robot"), "{line}");
        let id: u16 = parts.next().unwrap().parse().unwrap();
        let addr = parts
            .next()
            .unwrap()
            .trim_start_matches("tcp://")
            .to_string();
        robots.push((id, addr));
    }
    assert_eq!(robots.len(), 2, "the push world has two robots");
    let check = async {
        for (id, addr) in &robots {
            let mut s = TcpStream::connect(addr).await.unwrap();
            s.set_nodelay(true).unwrap();
            let mut dec = SlipDecoder::new();
            let hello = loop {
                if let AnyPacket::Hello(h) = next_packet(&mut s, &mut dec).await {
                    break h;
                }
            };
            assert_eq!({ hello.robot_id }, *id);
            assert_eq!({ hello.settings_hash }, protocol::SETTINGS_LAYOUT_HASH);
            let mut frame = [0u8; protocol::MAX_PACKET];
            let n = AnyPacket::from(Ping {
                seq: 77,
                host_time_us: 5,
            })
            .encode(&mut frame)
            .unwrap();
            let mut out = [0u8; 600];
            let m = slip::encode(&frame[..n], &mut out).unwrap();
            s.write_all(&out[..m]).await.unwrap();
            loop {
                if let AnyPacket::Pong(p) = next_packet(&mut s, &mut dec).await {
                    assert_eq!({ p.seq }, 77);
                    assert_eq!({ p.host_time_us }, 5);
                    break;
                }
            }
        }
    };
    let result = tokio::time::timeout(Duration::from_secs(30), check).await;
    let _ = child.kill();
    let _ = child.wait();
    result.expect("hello + ping exchange timed out");
}
