//! `pocketfleet-gateway`: a host that owns some robots' links and bridges their packets,
//! unchanged, onto zenoh, so the coordinator can run on another machine
//! (`coordinator --transport zenoh`). It coordinates nothing and decodes only what it must: the
//! robot's hello, which names the robot. The key space is documented in
//! [`robot_actor::link::zenoh`].
//!
//! Per robot address the gateway keeps one bridge: it connects (reconnecting with backoff when
//! the link drops), waits for the robot's hello (asking for it when it does not come), then
//! declares the robot's liveliness token and forwards every packet up and down until the link
//! closes, when the token goes and the host sees the link lost.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use protocol::packets::{AnyPacket, HelloRequest, PacketType};
use robot_actor::link::zenoh::{open_session, FleetSession, Keys, UpBatch, ZenohOptions};
use robot_actor::link::{Connector, Link, LinkEvent};
use serde::Serialize;
use tokio::sync::mpsc;
use zenoh::qos::CongestionControl;

/// What a gateway serves.
#[derive(Clone, Debug)]
pub struct GatewayConfig {
    /// The fleet's name: the first chunk of every key.
    pub fleet: String,
    /// This gateway's name, unique in the fleet.
    pub name: String,
    /// The robots' addresses (`tcp://…`, `serial://…`, `bt://…`, `unix://…`).
    pub robots: Vec<String>,
    /// The zenoh endpoints and configuration.
    pub zenoh: ZenohOptions,
}

/// One robot link's figures, as the statistics queryable gives them.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct RobotStats {
    /// The robot's address.
    pub address: String,
    /// Its id, once it said hello.
    pub robot: Option<u16>,
    /// Whether its link is up and bridged now.
    pub connected: bool,
    /// Links opened.
    pub links: u64,
    /// Links lost after they were up.
    pub losses: u64,
    /// Packets from the robot put on zenoh.
    pub packets_up: u64,
    /// Packets from zenoh handed to the robot.
    pub packets_down: u64,
    /// The last connect error, while not connected.
    pub last_error: Option<String>,
    /// Round trip of the last ping the host sent through the gateway and its pong, gateway to
    /// robot and back, milliseconds.
    pub rtt_ms: Option<f64>,
    /// The longest such round trip seen, milliseconds.
    pub rtt_max_ms: Option<f64>,
}

type Stats = Arc<Mutex<Vec<RobotStats>>>;

fn with_stats<R>(stats: &Stats, k: usize, f: impl FnOnce(&mut RobotStats) -> R) -> R {
    let mut all = stats.lock().unwrap_or_else(PoisonError::into_inner);
    f(&mut all[k])
}

/// A running gateway; dropping it leaves the fleet (its tokens go with its session).
pub struct Gateway {
    session: FleetSession,
    stats: Stats,
    tasks: Vec<tokio::task::JoinHandle<()>>,
}

/// The longest wait between reconnect attempts.
const MAX_BACKOFF: Duration = Duration::from_secs(2);
/// How long the robot has to say hello on a new link before it is asked.
const HELLO_WAIT: Duration = Duration::from_millis(500);

impl Gateway {
    /// Joins the fleet, declares the gateway's token and statistics, and bridges every robot.
    ///
    /// # Errors
    /// A bad fleet name or robot address, or a zenoh session that does not open.
    pub async fn start(config: GatewayConfig) -> anyhow::Result<Gateway> {
        // zenoh needs a multi-thread runtime; the bridges run there too.
        robot_actor::link::zenoh::on_zenoh(Self::start_here(config)).await
    }

    async fn start_here(config: GatewayConfig) -> anyhow::Result<Gateway> {
        let keys = Keys::new(&config.fleet)?;
        let connectors = config
            .robots
            .iter()
            .map(|a| robot_actor::discover::parse_address(a))
            .collect::<Result<Vec<_>, _>>()?;
        let session = open_session(&config.zenoh).await?;
        let stats: Stats = Arc::new(Mutex::new(
            config
                .robots
                .iter()
                .map(|address| RobotStats {
                    address: address.clone(),
                    ..Default::default()
                })
                .collect(),
        ));
        let token = session
            .session()
            .liveliness()
            .declare_token(keys.gateway_alive(&config.name))
            .await
            .map_err(|e| anyhow::anyhow!("gateway token: {e}"))?;
        let answer = Arc::clone(&stats);
        let stats_key = keys.gateway_stats(&config.name);
        let queryable = session
            .session()
            .declare_queryable(&stats_key)
            .callback(move |query| {
                let all = answer
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .clone();
                let json = serde_json::to_string(&all).unwrap_or_default();
                let key = query.key_expr().clone();
                tokio::spawn(async move {
                    let _ = query.reply(key, json).await;
                });
            })
            .await
            .map_err(|e| anyhow::anyhow!("statistics queryable: {e}"))?;
        let mut tasks = Vec::new();
        // The token and the queryable live as long as the gateway's first task.
        let keep = (token, queryable);
        for (k, connector) in connectors.into_iter().enumerate() {
            let bridge = Bridge {
                session: session.clone(),
                keys: keys.clone(),
                stats: Arc::clone(&stats),
                slot: k,
            };
            tasks.push(tokio::spawn(bridge.run(connector)));
        }
        tasks.push(tokio::spawn(async move {
            let _keep = keep;
            std::future::pending::<()>().await;
        }));
        Ok(Gateway {
            session,
            stats,
            tasks,
        })
    }

    /// Every robot link's figures now.
    pub fn stats(&self) -> Vec<RobotStats> {
        self.stats
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    /// The gateway's zenoh session.
    pub fn session(&self) -> &FleetSession {
        &self.session
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}

/// One robot address's bridge.
struct Bridge {
    session: FleetSession,
    keys: Keys,
    stats: Stats,
    slot: usize,
}

impl Bridge {
    async fn run(self, connector: Arc<dyn Connector>) {
        let mut backoff = Duration::from_millis(100);
        loop {
            match connector.connect().await {
                Ok(link) => {
                    backoff = Duration::from_millis(100);
                    with_stats(&self.stats, self.slot, |s| {
                        s.links += 1;
                        s.last_error = None;
                    });
                    let was_up = self.serve(link).await;
                    with_stats(&self.stats, self.slot, |s| {
                        s.connected = false;
                        s.losses += u64::from(was_up);
                    });
                }
                Err(e) => {
                    tracing::debug!(peer = connector.peer(), error = %e, "cannot connect");
                    with_stats(&self.stats, self.slot, |s| {
                        s.last_error = Some(e.to_string())
                    });
                }
            }
            tokio::time::sleep(backoff).await;
            backoff = (backoff * 2).min(MAX_BACKOFF);
        }
    }

    /// Whether a liveliness token for robot `id` is alive on the fleet already.
    async fn taken(&self, id: u16) -> bool {
        robot_actor::link::zenoh::alive_robots(&self.session, &self.keys)
            .await
            .is_ok_and(|ids| ids.contains(&id))
    }

    /// Bridges one open link until it closes; whether it was up (the robot said hello).
    async fn serve(&self, mut link: Link) -> bool {
        let Some((id, hello)) = hello(&mut link).await else {
            return false;
        };
        // A robot id belongs to one gateway at a time: one already alive on the fleet is
        // another gateway's robot, and this one (another simulator's robot 2, say) must never
        // receive that robot's commands. Its link is closed unbridged, and tried again later.
        if self.taken(id).await {
            let why = format!("robot {id} is already bridged by another gateway on this fleet");
            tracing::warn!(robot = id, peer = link.peer, "refused: {why}");
            with_stats(&self.stats, self.slot, |s| s.last_error = Some(why));
            return false;
        }
        let up = match self
            .session
            .session()
            .declare_publisher(self.keys.up(id))
            .congestion_control(CongestionControl::Block)
            .await
        {
            Ok(p) => p,
            Err(e) => {
                tracing::warn!(robot = id, error = %e, "cannot publish");
                return false;
            }
        };
        let (down_tx, mut down) = mpsc::unbounded_channel::<Vec<u8>>();
        let subscriber = self
            .session
            .session()
            .declare_subscriber(self.keys.down(id))
            .callback(move |sample| {
                let _ = down_tx.send(sample.payload().to_bytes().into());
            })
            .await;
        let token = self
            .session
            .session()
            .liveliness()
            .declare_token(self.keys.robot_alive(id))
            .await;
        let (Ok(subscriber), Ok(token)) = (subscriber, token) else {
            tracing::warn!(robot = id, "cannot declare the robot's keys");
            return false;
        };
        tracing::info!(robot = id, peer = link.peer, "robot bridged");
        with_stats(&self.stats, self.slot, |s| {
            s.robot = Some(id);
            s.connected = true;
        });
        let mut batch = UpBatch::default();
        batch.push(&hello);
        if up.put(batch.take()).await.is_ok() {
            with_stats(&self.stats, self.slot, |s| s.packets_up += 1);
        }
        // Pings are timed by their type code alone: the gateway decodes nothing else.
        let mut ping_sent: Option<std::time::Instant> = None;
        loop {
            tokio::select! {
                event = link.rx.recv() => match event {
                    Some(LinkEvent::Packet(p)) => {
                        // Whatever the link has already delivered goes in the same sample.
                        let mut next = Some(p);
                        let mut closed = None;
                        let mut rtt = None;
                        while let Some(p) = next.take() {
                            if packet_type(&p) == Some(PacketType::Pong as u8) {
                                rtt = ping_sent.take().map(|t| t.elapsed()).or(rtt);
                            }
                            batch.push(&p);
                            if batch.is_full() {
                                break;
                            }
                            match link.rx.try_recv() {
                                Ok(LinkEvent::Packet(q)) => next = Some(q),
                                Ok(LinkEvent::Closed(why)) => closed = Some(why),
                                Err(_) => {}
                            }
                        }
                        let packets = batch.packets() as u64;
                        if up.put(batch.take()).await.is_err() {
                            break;
                        }
                        with_stats(&self.stats, self.slot, |s| {
                            s.packets_up += packets;
                            if let Some(rtt) = rtt {
                                let ms = rtt.as_secs_f64() * 1e3;
                                s.rtt_ms = Some(ms);
                                s.rtt_max_ms = Some(s.rtt_max_ms.map_or(ms, |m| m.max(ms)));
                            }
                        });
                        if let Some(why) = closed {
                            tracing::warn!(robot = id, ?why, "robot link closed");
                            break;
                        }
                    }
                    Some(LinkEvent::Closed(why)) => {
                        tracing::warn!(robot = id, ?why, "robot link closed");
                        break;
                    }
                    None => break,
                },
                packet = down.recv() => {
                    let Some(packet) = packet else { break };
                    if packet_type(&packet) == Some(PacketType::Ping as u8) {
                        ping_sent = Some(std::time::Instant::now());
                    }
                    if link.tx.send(packet).await.is_err() {
                        break;
                    }
                    with_stats(&self.stats, self.slot, |s| s.packets_down += 1);
                }
            }
        }
        // The host must see the robot go at once, not when the session times out.
        let _ = token.undeclare().await;
        drop(subscriber);
        true
    }
}

/// A packet's type code: the second byte of its header (after the checksum).
fn packet_type(packet: &[u8]) -> Option<u8> {
    packet.get(1).copied()
}

/// Waits for the robot's hello on a new link, asking for it when it does not come; the robot's
/// id and the hello's bytes, or `None` when the link closed first.
async fn hello(link: &mut Link) -> Option<(u16, Vec<u8>)> {
    loop {
        match tokio::time::timeout(HELLO_WAIT, link.rx.recv()).await {
            Ok(Some(LinkEvent::Packet(p))) => {
                if let Ok(AnyPacket::Hello(h)) = protocol::decode(&p) {
                    return Some((h.robot_id, p));
                }
            }
            Ok(Some(LinkEvent::Closed(_)) | None) => return None,
            Err(_) => {
                let (buf, n) = protocol::frame::encode_to_array(&HelloRequest {});
                if link.tx.send(buf[..n].to_vec()).await.is_err() {
                    return None;
                }
            }
        }
    }
}
