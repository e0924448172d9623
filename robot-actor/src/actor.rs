//! `RobotActor`: one robot on the host (thesis ch. 5 and 9). It owns the robot's link, keeps the
//! reflected state and a mirror of its settings, turns typed commands into packets, resolves move
//! futures from the robot's own events, tracks odometry and link statistics, and reconnects with
//! backoff when the link is lost.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use actix::prelude::*;
use futures::StreamExt;
use protocol::packets::{self, AnyPacket, CalibrationAction, Hello, MoveOutcome, NackReason};
use protocol::{Frame, Layout, Packet, PacketType, ReducedState, RobotState, Settings};
use tokio::sync::{mpsc, oneshot};
use tokio::time::Instant;
use tokio_stream::wrappers::UnboundedReceiverStream;
use tracing::{debug, info, warn};

use crate::link::{Connector, LinkCounters, LinkEvent};
use crate::odometry::{Geometry, Odometry, Pose};
use crate::settings::read_chunks;

/// Why a robot command failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RobotError {
    /// The link is down (and being re-established).
    #[error("robot {robot}: not connected")]
    NotConnected {
        /// Robot id (0 before the hello).
        robot: u16,
    },
    /// The link was lost while the command was pending.
    #[error("robot {robot}: link lost after {after:?}")]
    LinkLost {
        /// Robot id.
        robot: u16,
        /// How long the command had been pending.
        after: Duration,
    },
    /// The robot's hello shows a protocol or a layout other than this host's: the link was closed
    /// and the actor does not reconnect (moves or settings would be misread on either side).
    #[error("robot {robot} refused: {}", list(differences))]
    Incompatible {
        /// Robot id.
        robot: u16,
        /// What differs, in the order version, state layout, settings layout.
        differences: Vec<Incompatibility>,
    },
    /// The robot refused the command.
    #[error("robot {robot}: refused {packet}: {reason:?}")]
    Refused {
        /// Robot id.
        robot: u16,
        /// Which packet.
        packet: &'static str,
        /// Why.
        reason: Option<NackReason>,
    },
    /// The robot refused a settings write; `field` is the offending field's dotted path when the
    /// robot named one.
    #[error("robot {robot}: refused settings write: {reason:?}{}", .field.as_deref().map(|f| format!(" in {f}")).unwrap_or_default())]
    SettingRefused {
        /// Robot id.
        robot: u16,
        /// Dotted path of the offending field (`"geometry.ticks_per_rev"`), if named.
        field: Option<String>,
        /// Why.
        reason: Option<NackReason>,
    },
    /// A settings range is not whole fields inside the structure.
    #[error("bad settings range at {offset} (+{len})")]
    BadSettingsRange {
        /// Offset.
        offset: usize,
        /// Length.
        len: usize,
    },
    /// Read-back after a write returned other bytes.
    #[error("robot {robot}: settings at {offset} read back differently")]
    ReadBackMismatch {
        /// Robot id.
        robot: u16,
        /// Offset.
        offset: usize,
    },
    /// The send queue to the robot is full.
    #[error("robot {robot}: send queue full")]
    Congested {
        /// Robot id.
        robot: u16,
    },
}

/// One way a robot's hello differs from what this host speaks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Incompatibility {
    /// Another [`protocol::PROTOCOL_VERSION`].
    #[error("protocol version {robot}, host speaks {host}")]
    ProtocolVersion {
        /// The robot's.
        robot: u16,
        /// The host's.
        host: u16,
    },
    /// Another [`RobotState`] layout hash: reflected states would be misread.
    #[error("state layout {robot:#018x}, host knows {host:#018x}")]
    StateLayout {
        /// The robot's.
        robot: u64,
        /// The host's.
        host: u64,
    },
    /// Another [`Settings`] layout hash: settings would be written at the wrong offsets.
    #[error("settings layout {robot:#018x}, host knows {host:#018x}")]
    SettingsLayout {
        /// The robot's.
        robot: u64,
        /// The host's.
        host: u64,
    },
}

/// How `hello` differs from this host's protocol version and layouts (empty when it does not).
pub fn incompatibilities(hello: &Hello) -> Vec<Incompatibility> {
    let mut out = Vec::new();
    if hello.protocol_version != protocol::PROTOCOL_VERSION {
        out.push(Incompatibility::ProtocolVersion {
            robot: hello.protocol_version,
            host: protocol::PROTOCOL_VERSION,
        });
    }
    if hello.state_hash != RobotState::LAYOUT.hash {
        out.push(Incompatibility::StateLayout {
            robot: hello.state_hash,
            host: RobotState::LAYOUT.hash,
        });
    }
    if hello.settings_hash != protocol::SETTINGS_LAYOUT_HASH {
        out.push(Incompatibility::SettingsLayout {
            robot: hello.settings_hash,
            host: protocol::SETTINGS_LAYOUT_HASH,
        });
    }
    out
}

fn list(differences: &[Incompatibility]) -> String {
    let parts: Vec<String> = differences.iter().map(ToString::to_string).collect();
    parts.join("; ")
}

/// The state reflector's mode and period (thesis 9.7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReflectorSetup {
    /// What to reflect.
    pub mode: packets::ReflectorMode,
    /// Period, milliseconds.
    pub period_ms: u16,
}

/// Tunables of a robot actor.
#[derive(Clone, Debug)]
pub struct RobotConfig {
    /// State reflector set on every connect.
    pub reflector: ReflectorSetup,
    /// Ping period; also keeps the robot's link watchdog fed.
    pub ping_period: Duration,
    /// Silence after which the link counts as lost.
    pub link_timeout: Duration,
    /// First reconnect delay; doubles up to `max_backoff`.
    pub min_backoff: Duration,
    /// Longest reconnect delay.
    pub max_backoff: Duration,
    /// Where odometry starts.
    pub origin: Pose,
}

impl Default for RobotConfig {
    fn default() -> Self {
        Self {
            reflector: ReflectorSetup {
                mode: packets::ReflectorMode::Full,
                period_ms: 50,
            },
            ping_period: Duration::from_millis(100),
            link_timeout: Duration::from_millis(1000),
            min_backoff: Duration::from_millis(100),
            max_backoff: Duration::from_secs(2),
            origin: Pose::default(),
        }
    }
}

/// A move for the robot's queue (thesis 6.5).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MoveCommand {
    /// Straight, signed metres at `speed_mps`.
    Straight {
        /// Distance.
        distance_m: f32,
        /// Cruise speed.
        speed_mps: f32,
    },
    /// Turn in place, signed degrees (CCW positive).
    Rotate {
        /// Angle.
        angle_deg: f32,
        /// Wheel speed.
        speed_mps: f32,
    },
    /// Arc of `radius_m` turning `angle_deg`.
    Arc {
        /// Radius of the centre's path.
        radius_m: f32,
        /// Heading change.
        angle_deg: f32,
        /// Outer wheel speed.
        speed_mps: f32,
    },
}

/// Link statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LinkStats {
    /// Packets received and accepted.
    pub packets_in: u64,
    /// Packets sent.
    pub packets_out: u64,
    /// Frames dropped for bad checksum, length or type.
    pub checksum_errors: u64,
    /// Frames dropped by the framing layer.
    pub dropped_frames: u64,
    /// Latest round-trip time.
    pub rtt: Option<Duration>,
    /// Mean round-trip time.
    pub rtt_mean: Option<Duration>,
    /// Time since the last packet from the robot.
    pub silent_for: Option<Duration>,
    /// Links lost so far.
    pub losses: u64,
    /// Successful reconnects.
    pub reconnects: u64,
}

/// Something the robot reported, or the link did.
#[derive(Clone, Debug, PartialEq)]
pub enum RobotEventKind {
    /// The robot introduced itself.
    Connected(Hello),
    /// The link was lost.
    LinkLost,
    /// A move ended.
    MoveFinished {
        /// Move id.
        id: u16,
        /// How.
        outcome: MoveOutcome,
    },
    /// The queue ran empty.
    QueueEmpty,
    /// An obstacle reflection.
    Obstacle(packets::Obstacle),
    /// Another robot identified.
    Encounter(packets::RobotEncountered),
    /// Line lost (`true`) or found.
    Line(bool),
    /// The robot's watchdog stopped it.
    WatchdogStop,
    /// The robot's main loop overran.
    Overrun(u32),
    /// A command was refused.
    Refused(packets::Nack),
}

/// An event from one robot.
#[derive(Clone, Debug, Message)]
#[rtype(result = "()")]
pub struct RobotEvent {
    /// Robot id.
    pub robot_id: u16,
    /// When it arrived.
    pub at: Instant,
    /// What happened.
    pub kind: RobotEventKind,
}

/// A new reflected state (full or reduced) and the odometry pose from it.
#[derive(Clone, Copy, Debug, Message)]
#[rtype(result = "()")]
pub struct StateUpdated {
    /// Robot id.
    pub robot_id: u16,
    /// When it arrived.
    pub at: Instant,
    /// The reflected state (fields a reduced packet does not carry keep their last value).
    pub state: RobotState,
    /// Whether this update came from a reduced packet.
    pub reduced: bool,
    /// Odometry pose.
    pub pose: Pose,
}

/// Everything the actor knows about its robot.
#[derive(Clone, Debug)]
pub struct RobotSnapshot {
    /// Robot id (0 before the first hello).
    pub robot_id: u16,
    /// The link's peer.
    pub peer: String,
    /// Whether a link is up and the hello arrived.
    pub connected: bool,
    /// The hello.
    pub hello: Option<Hello>,
    /// Reflected state.
    pub state: RobotState,
    /// When the last full state arrived.
    pub full_state_at: Option<Instant>,
    /// When the last reduced state arrived.
    pub reduced_state_at: Option<Instant>,
    /// Settings mirror (valid once `settings_known`).
    pub settings: Settings,
    /// Whether every settings chunk was read back since the last connect.
    pub settings_known: bool,
    /// Odometry pose.
    pub pose: Pose,
    /// Encoder totals since the odometry origin.
    pub odometry_totals: (i64, i64),
    /// Link statistics.
    pub link: LinkStats,
    /// Moves waiting for their finish event.
    pub pending_moves: usize,
    /// Why the latest attempt to open a link failed, until one opens.
    pub link_error: Option<String>,
    /// Why the robot was refused after its hello, if it was.
    pub refused: Option<RobotError>,
}

/// Registers a state subscriber.
#[derive(Message)]
#[rtype(result = "()")]
pub struct Subscribe(pub Recipient<StateUpdated>);

/// Registers an event subscriber.
#[derive(Message)]
#[rtype(result = "()")]
pub struct SubscribeEvents(pub Recipient<RobotEvent>);

/// Asks for a [`RobotSnapshot`].
#[derive(Message)]
#[rtype(result = "RobotSnapshot")]
pub struct GetSnapshot;

/// Waits until the robot has said hello (resolves at once if it has).
#[derive(Message)]
#[rtype(result = "Result<Hello, RobotError>")]
pub struct WaitConnected;

/// Enqueues a move; resolves when the robot reports it finished.
#[derive(Message)]
#[rtype(result = "Result<MoveOutcome, RobotError>")]
pub struct Enqueue(pub MoveCommand);

/// Resolves when the robot has no queued move left.
#[derive(Message)]
#[rtype(result = "Result<(), RobotError>")]
pub struct WaitIdle;

/// A command with no answer beyond being sent.
#[derive(Clone, Copy, Debug, Message)]
#[rtype(result = "Result<(), RobotError>")]
pub enum Command {
    /// Drop every queued move.
    ClearQueue,
    /// Stop everything now.
    Stop,
    /// Hold wheel speeds (m/s).
    WheelSpeeds(f32, f32),
    /// Apply motor duties (permille).
    MotorPower(i16, i16),
    /// Follow the line at a speed (m/s), or stop following (`None`).
    FollowLine(Option<f32>),
    /// A line sensor calibration step.
    CalibrateLine(CalibrationAction),
    /// Set the status LED.
    Led(u8, u8, u8),
    /// Attach a message word to the robot's IR frames.
    IrMessage(u16),
    /// Reconfigure the state reflector.
    Reflector(ReflectorSetup),
}

/// Writes one settings range; resolves when read-back confirms it.
#[derive(Message)]
#[rtype(result = "Result<(), RobotError>")]
pub struct WriteSettings {
    /// Byte offset.
    pub offset: usize,
    /// New bytes.
    pub bytes: Vec<u8>,
}

/// Reads every setting back from the robot.
#[derive(Message)]
#[rtype(result = "Result<Settings, RobotError>")]
pub struct ReadSettings;

/// Stores the robot's settings in its flash.
#[derive(Message)]
#[rtype(result = "Result<(), RobotError>")]
pub struct SaveSettings;

/// Restores the factory settings and reads them back.
#[derive(Message)]
#[rtype(result = "Result<Settings, RobotError>")]
pub struct RestoreDefaults;

/// Moves the odometry origin.
#[derive(Message)]
#[rtype(result = "()")]
pub struct SetOdometryOrigin(pub Pose);

/// Closes the link and stops the actor.
#[derive(Message)]
#[rtype(result = "()")]
pub struct Close;

type Reply<T> = oneshot::Sender<Result<T, RobotError>>;

/// The host-side representation of one robot.
pub struct RobotActor {
    connector: Arc<dyn Connector>,
    config: RobotConfig,
    generation: u64,
    tx: Option<mpsc::Sender<Vec<u8>>>,
    counters: Option<Arc<LinkCounters>>,
    connected_at: Option<Instant>,
    hello: Option<Hello>,
    /// Whether the robot said hello on the current link.
    greeted: bool,
    /// Set when the hello showed an incompatible robot: the actor then stays disconnected.
    refused: Option<RobotError>,
    /// Why the latest connect attempt failed, until a link opens.
    link_error: Option<String>,
    state: RobotState,
    full_state_at: Option<Instant>,
    reduced_state_at: Option<Instant>,
    settings: Settings,
    settings_chunks_missing: usize,
    /// Fields the host wrote, re-applied after a reconnect.
    host_writes: BTreeMap<usize, Vec<u8>>,
    odometry: Odometry,
    subscribers: Vec<Recipient<StateUpdated>>,
    event_subscribers: Vec<Recipient<RobotEvent>>,
    next_move_id: u16,
    moves: HashMap<u16, (Instant, Reply<MoveOutcome>)>,
    idle_waiters: Vec<Reply<()>>,
    hello_waiters: Vec<Reply<Hello>>,
    reads: VecDeque<(usize, usize, Vec<u8>, Reply<()>)>,
    full_reads: Vec<Reply<Settings>>,
    saves: VecDeque<Reply<()>>,
    pings: HashMap<u32, Instant>,
    next_ping: u32,
    last_seen: Option<Instant>,
    stats: LinkStats,
    rtt_sum: Duration,
    rtt_count: u32,
    backoff: Duration,
}

impl RobotActor {
    /// An actor that will connect through `connector` when started.
    pub fn new(connector: Arc<dyn Connector>, config: RobotConfig) -> Self {
        let settings = Settings::default();
        let odometry = Odometry::new(Geometry::from_settings(&settings), config.origin);
        let backoff = config.min_backoff;
        Self {
            connector,
            config,
            generation: 0,
            tx: None,
            counters: None,
            connected_at: None,
            hello: None,
            greeted: false,
            refused: None,
            link_error: None,
            state: RobotState::default(),
            full_state_at: None,
            reduced_state_at: None,
            settings,
            settings_chunks_missing: 0,
            host_writes: BTreeMap::new(),
            odometry,
            subscribers: Vec::new(),
            event_subscribers: Vec::new(),
            next_move_id: 1,
            moves: HashMap::new(),
            idle_waiters: Vec::new(),
            hello_waiters: Vec::new(),
            reads: VecDeque::new(),
            full_reads: Vec::new(),
            saves: VecDeque::new(),
            pings: HashMap::new(),
            next_ping: 0,
            last_seen: None,
            stats: LinkStats::default(),
            rtt_sum: Duration::ZERO,
            rtt_count: 0,
            backoff,
        }
    }

    fn robot_id(&self) -> u16 {
        self.hello.map_or(0, |h| h.robot_id)
    }

    fn not_connected(&self) -> RobotError {
        self.refused.clone().unwrap_or(RobotError::NotConnected {
            robot: self.robot_id(),
        })
    }

    fn send<P: Packet>(&mut self, p: &P) -> Result<(), RobotError> {
        let tx = self.tx.as_ref().ok_or_else(|| self.not_connected())?;
        let (buf, n) = protocol::frame::encode_to_array(p);
        match tx.try_send(buf[..n].to_vec()) {
            Ok(()) => {
                self.stats.packets_out += 1;
                Ok(())
            }
            Err(mpsc::error::TrySendError::Full(_)) => Err(RobotError::Congested {
                robot: self.robot_id(),
            }),
            Err(mpsc::error::TrySendError::Closed(_)) => Err(self.not_connected()),
        }
    }

    /// Settings operations need a hello (whose layout was checked on arrival) and no refusal.
    fn layout_ok(&self) -> Result<(), RobotError> {
        match (&self.refused, self.hello) {
            (Some(refusal), _) => Err(refusal.clone()),
            (None, None) => Err(self.not_connected()),
            (None, Some(_)) => Ok(()),
        }
    }

    fn emit(&self, kind: RobotEventKind) {
        let e = RobotEvent {
            robot_id: self.robot_id(),
            at: Instant::now(),
            kind,
        };
        for s in &self.event_subscribers {
            s.do_send(e.clone());
        }
    }

    fn connect(&mut self, ctx: &mut Context<Self>) {
        let fut = self.connector.connect();
        ctx.spawn(fut.into_actor(self).map(|res, act, ctx| match res {
            Ok(link) => {
                act.generation += 1;
                let generation = act.generation;
                info!(peer = %link.peer, "link up");
                act.tx = Some(link.tx);
                act.greeted = false;
                act.counters = Some(link.counters);
                act.connected_at = Some(Instant::now());
                act.last_seen = Some(Instant::now());
                act.backoff = act.config.min_backoff;
                act.link_error = None;
                ctx.add_stream(UnboundedReceiverStream::new(link.rx).map(move |e| (generation, e)));
                let _ = act.send(&packets::HelloRequest {});
            }
            Err(e) => {
                warn!(error = %e, "connect failed");
                act.link_error = Some(describe_connect_error(&e));
                act.schedule_reconnect(ctx);
            }
        }));
    }

    fn schedule_reconnect(&mut self, ctx: &mut Context<Self>) {
        let delay = self.backoff;
        self.backoff = (self.backoff * 2).min(self.config.max_backoff);
        ctx.run_later(delay, |act, ctx| act.connect(ctx));
    }

    fn link_lost(&mut self, ctx: &mut Context<Self>, why: &str) {
        if self.tx.is_none() {
            return;
        }
        warn!(robot = self.robot_id(), why, "link lost");
        self.generation += 1;
        self.tx = None;
        self.greeted = false;
        if let Some(c) = self.counters.take() {
            self.stats.dropped_frames += c.framing_errors.load(Ordering::Relaxed);
        }
        self.stats.losses += 1;
        let robot = self.robot_id();
        let now = Instant::now();
        for (_, (since, reply)) in self.moves.drain() {
            let _ = reply.send(Err(RobotError::LinkLost {
                robot,
                after: now - since,
            }));
        }
        let lost = || RobotError::LinkLost {
            robot,
            after: Duration::ZERO,
        };
        for w in self.idle_waiters.drain(..) {
            let _ = w.send(Err(lost()));
        }
        for (_, _, _, w) in self.reads.drain(..) {
            let _ = w.send(Err(lost()));
        }
        for w in self.full_reads.drain(..) {
            let _ = w.send(Err(lost()));
        }
        for w in self.saves.drain(..) {
            let _ = w.send(Err(lost()));
        }
        self.pings.clear();
        self.emit(RobotEventKind::LinkLost);
        self.schedule_reconnect(ctx);
    }

    fn on_hello(&mut self, hello: Hello) {
        if self.greeted || self.refused.is_some() {
            // The robot greets on connect and on request: one link, one greeting.
            return;
        }
        let reconnect = self.hello.is_some();
        self.hello = Some(hello);
        let differences = incompatibilities(&hello);
        if !differences.is_empty() {
            self.refuse(RobotError::Incompatible {
                robot: hello.robot_id,
                differences,
            });
            return;
        }
        self.greeted = true;
        let r = self.config.reflector;
        let _ = self.send(&packets::ReflectorConfig {
            mode: r.mode as u8,
            period_ms: r.period_ms,
        });
        info!(robot = { hello.robot_id }, "hello");
        if reconnect {
            self.stats.reconnects += 1;
        }
        // Host-made changes survive a robot reboot or a reconnect.
        let writes: Vec<(usize, Vec<u8>)> = self
            .host_writes
            .iter()
            .map(|(o, b)| (*o, b.clone()))
            .collect();
        for (offset, bytes) in writes {
            if let Some(u) = packets::SettingsUpdate::new(offset as u16, &bytes) {
                let _ = self.send(&u);
            }
        }
        self.request_all_settings();
        for w in self.hello_waiters.drain(..) {
            let _ = w.send(Ok(hello));
        }
        self.emit(RobotEventKind::Connected(hello));
    }

    /// Closes the link for good: every waiter and every later command gets `refusal`.
    fn refuse(&mut self, refusal: RobotError) {
        warn!(error = %refusal, "robot refused");
        // Dropping the only sender ends the link's I/O task, which closes the connection; its
        // last events belong to an old generation and are ignored.
        self.generation += 1;
        self.tx = None;
        self.counters = None;
        self.greeted = false;
        for w in self.hello_waiters.drain(..) {
            let _ = w.send(Err(refusal.clone()));
        }
        self.refused = Some(refusal);
    }

    fn request_all_settings(&mut self) {
        let chunks = read_chunks();
        self.settings_chunks_missing = chunks.len();
        for (offset, len) in chunks {
            let _ = self.send(&packets::SettingsRead {
                offset: offset as u16,
                len: len as u8,
            });
        }
    }

    /// A refused write fails its pending `set`. The robot answers in order, so every earlier
    /// write's read-back has already arrived and the oldest pending write is the refused one. It
    /// is not replayed after a reconnect.
    fn on_settings_refused(&mut self, n: packets::Nack, reason: Option<NackReason>) {
        let offset = n.field_offset;
        let field = (offset != packets::Nack::NO_FIELD).then(|| {
            Settings::path_of(usize::from(offset))
                .map_or_else(|| format!("offset {offset}"), |p| p.to_string())
        });
        if let Some((write_offset, _, _, reply)) = self.reads.pop_front() {
            self.host_writes.remove(&write_offset);
            let _ = reply.send(Err(RobotError::SettingRefused {
                robot: self.robot_id(),
                field,
                reason,
            }));
        }
    }

    fn on_settings_data(&mut self, d: packets::SettingsData) {
        let offset = usize::from(d.offset);
        let bytes = d.bytes().to_vec();
        if self.settings.write(offset, &bytes).is_err() {
            return;
        }
        if self.settings_chunks_missing > 0 {
            self.settings_chunks_missing -= 1;
            if self.settings_chunks_missing == 0 {
                if self.odometry.totals() == (0, 0) {
                    // Odometry uses the robot's own wheel geometry once it is known.
                    let pose = self.odometry.pose();
                    self.odometry = Odometry::new(Geometry::from_settings(&self.settings), pose);
                }
                let s = self.settings;
                for w in self.full_reads.drain(..) {
                    let _ = w.send(Ok(s));
                }
            }
        }
        let robot = self.robot_id();
        if let Some(pos) = self
            .reads
            .iter()
            .position(|(o, l, _, _)| *o == offset && *l == bytes.len())
        {
            if let Some((_, _, expected, reply)) = self.reads.remove(pos) {
                let r = if expected == bytes {
                    Ok(())
                } else {
                    Err(RobotError::ReadBackMismatch { robot, offset })
                };
                let _ = reply.send(r);
            }
        }
    }

    fn publish_state(&mut self, reduced: bool) {
        let pose = self.odometry.update(
            self.state.encoders.left_ticks,
            self.state.encoders.right_ticks,
        );
        let u = StateUpdated {
            robot_id: self.robot_id(),
            at: Instant::now(),
            state: self.state,
            reduced,
            pose,
        };
        for s in &self.subscribers {
            s.do_send(u);
        }
    }

    fn handle_packet(&mut self, packet: AnyPacket) {
        match packet {
            AnyPacket::State(s) => {
                self.state = s;
                self.full_state_at = Some(Instant::now());
                self.publish_state(false);
            }
            AnyPacket::ReducedState(r) => {
                self.merge_reduced(r);
                self.reduced_state_at = Some(Instant::now());
                self.publish_state(true);
            }
            AnyPacket::Hello(h) => self.on_hello(h),
            AnyPacket::Pong(p) => {
                if let Some(sent) = self.pings.remove(&{ p.seq }) {
                    let rtt = Instant::now() - sent;
                    self.stats.rtt = Some(rtt);
                    self.rtt_sum += rtt;
                    self.rtt_count += 1;
                    self.stats.rtt_mean = Some(self.rtt_sum / self.rtt_count);
                }
            }
            AnyPacket::SettingsData(d) => self.on_settings_data(d),
            AnyPacket::SettingsSaved(_) => {
                if let Some(w) = self.saves.pop_front() {
                    let _ = w.send(Ok(()));
                }
            }
            AnyPacket::Log(l) => {
                info!(
                    robot = self.robot_id(),
                    module = l.module(),
                    level = l.level,
                    "{}",
                    l.text()
                );
            }
            AnyPacket::Nack(n) => {
                let robot = self.robot_id();
                let packet = PacketType::from_code(n.packet_type).map_or("?", |t| t.name());
                let reason = NackReason::try_from(n.reason).ok();
                warn!(robot, packet, ?reason, "command refused");
                let err = RobotError::Refused {
                    robot,
                    packet,
                    reason,
                };
                if n.packet_type == PacketType::SettingsSave as u8 {
                    if let Some(w) = self.saves.pop_front() {
                        let _ = w.send(Err(err.clone()));
                    }
                }
                if n.packet_type == PacketType::SettingsUpdate as u8 {
                    self.on_settings_refused(n, reason);
                }
                self.emit(RobotEventKind::Refused(n));
            }
            AnyPacket::MoveFinished(m) => {
                let outcome = MoveOutcome::try_from(m.outcome).unwrap_or(MoveOutcome::Stopped);
                if let Some((_, reply)) = self.moves.remove(&{ m.move_id }) {
                    let _ = reply.send(Ok(outcome));
                }
                self.emit(RobotEventKind::MoveFinished {
                    id: m.move_id,
                    outcome,
                });
            }
            AnyPacket::QueueEmpty(_) => {
                if self.moves.is_empty() {
                    for w in self.idle_waiters.drain(..) {
                        let _ = w.send(Ok(()));
                    }
                }
                self.emit(RobotEventKind::QueueEmpty);
            }
            AnyPacket::Obstacle(o) => self.emit(RobotEventKind::Obstacle(o)),
            AnyPacket::RobotEncountered(e) => self.emit(RobotEventKind::Encounter(e)),
            AnyPacket::LineEvent(e) => self.emit(RobotEventKind::Line(e.lost != 0)),
            AnyPacket::WatchdogStop(_) => self.emit(RobotEventKind::WatchdogStop),
            AnyPacket::LoopOverrun(o) => self.emit(RobotEventKind::Overrun(o.late_us)),
            other => debug!(
                packet = other.packet_type().name(),
                "ignored host-bound packet"
            ),
        }
    }

    fn merge_reduced(&mut self, r: ReducedState) {
        self.state.uptime_ms = r.uptime_ms;
        self.state.encoders = r.encoders;
        self.state.wheels = r.wheels;
        self.state.line.position_um = r.line_position_um;
        self.state.line.flags = r.line_flags;
    }

    fn ping(&mut self, ctx: &mut Context<Self>) {
        let Some(seen) = self.last_seen else { return };
        if self.tx.is_some() && Instant::now() - seen > self.config.link_timeout {
            self.link_lost(ctx, "silent past the link timeout");
            return;
        }
        if self.tx.is_some() && !self.greeted {
            // The first request may have been lost with a link that came back by itself.
            let _ = self.send(&packets::HelloRequest {});
        }
        self.next_ping = self.next_ping.wrapping_add(1);
        let seq = self.next_ping;
        let now = Instant::now();
        if self
            .send(&packets::Ping {
                seq,
                host_time_us: 0,
            })
            .is_ok()
        {
            self.pings.insert(seq, now);
            // Forget pings whose pong never came, so the table stays small.
            self.pings
                .retain(|_, sent| now - *sent < Duration::from_secs(10));
        }
    }

    fn snapshot(&self) -> RobotSnapshot {
        let mut link = self.stats;
        if let Some(c) = &self.counters {
            link.dropped_frames += c.framing_errors.load(Ordering::Relaxed);
        }
        link.silent_for = self.last_seen.map(|t| Instant::now() - t);
        RobotSnapshot {
            robot_id: self.robot_id(),
            peer: self.connector.peer(),
            connected: self.tx.is_some() && self.greeted,
            hello: self.hello,
            state: self.state,
            full_state_at: self.full_state_at,
            reduced_state_at: self.reduced_state_at,
            settings: self.settings,
            settings_known: self.hello.is_some() && self.settings_chunks_missing == 0,
            pose: self.odometry.pose(),
            odometry_totals: self.odometry.totals(),
            link,
            pending_moves: self.moves.len(),
            link_error: self.link_error.clone(),
            refused: self.refused.clone(),
        }
    }
}

impl Actor for RobotActor {
    type Context = Context<Self>;

    fn started(&mut self, ctx: &mut Self::Context) {
        self.connect(ctx);
        ctx.run_interval(self.config.ping_period, |act, ctx| act.ping(ctx));
    }

    fn stopped(&mut self, _: &mut Self::Context) {
        // Best effort: a robot left alone stops through its watchdog anyway.
        let _ = self.send(&packets::Stop {});
    }
}

impl StreamHandler<(u64, LinkEvent)> for RobotActor {
    fn handle(&mut self, (generation, event): (u64, LinkEvent), ctx: &mut Self::Context) {
        if generation != self.generation {
            return;
        }
        match event {
            LinkEvent::Packet(bytes) => {
                self.last_seen = Some(Instant::now());
                match Frame::parse(&bytes) {
                    Ok(frame) => {
                        self.stats.packets_in += 1;
                        self.handle_packet(frame.packet());
                    }
                    Err(e) => {
                        self.stats.checksum_errors += 1;
                        debug!(error = %e, "dropped frame");
                    }
                }
            }
            LinkEvent::Closed(err) => {
                let why = err.map_or_else(|| "closed by peer".to_string(), |e| e.to_string());
                self.link_lost(ctx, &why);
            }
        }
    }

    fn finished(&mut self, _: &mut Self::Context) {
        // A link's stream ending is handled through `LinkEvent::Closed` or the link timeout; the
        // actor lives on to reconnect.
    }
}

impl Handler<Subscribe> for RobotActor {
    type Result = ();
    fn handle(&mut self, msg: Subscribe, _: &mut Self::Context) {
        self.subscribers.push(msg.0);
    }
}

impl Handler<SubscribeEvents> for RobotActor {
    type Result = ();
    fn handle(&mut self, msg: SubscribeEvents, _: &mut Self::Context) {
        self.event_subscribers.push(msg.0);
    }
}

impl Handler<GetSnapshot> for RobotActor {
    type Result = MessageResult<GetSnapshot>;
    fn handle(&mut self, _: GetSnapshot, _: &mut Self::Context) -> Self::Result {
        MessageResult(self.snapshot())
    }
}

impl Handler<WaitConnected> for RobotActor {
    type Result = ResponseFuture<Result<Hello, RobotError>>;
    fn handle(&mut self, _: WaitConnected, _: &mut Self::Context) -> Self::Result {
        if let (Some(h), true) = (self.hello, self.tx.is_some() && self.greeted) {
            return Box::pin(async move { Ok(h) });
        }
        if let Some(refusal) = self.refused.clone() {
            return Box::pin(async move { Err(refusal) });
        }
        let (tx, rx) = oneshot::channel();
        self.hello_waiters.push(tx);
        let robot = self.robot_id();
        Box::pin(async move { rx.await.unwrap_or(Err(RobotError::NotConnected { robot })) })
    }
}

impl Handler<Enqueue> for RobotActor {
    type Result = ResponseFuture<Result<MoveOutcome, RobotError>>;
    fn handle(&mut self, msg: Enqueue, _: &mut Self::Context) -> Self::Result {
        let id = self.next_move_id;
        self.next_move_id = self.next_move_id.wrapping_add(1).max(1);
        let sent = match msg.0 {
            MoveCommand::Straight {
                distance_m,
                speed_mps,
            } => self.send(&packets::StraightMovement {
                distance_m,
                speed_mps,
                move_id: id,
            }),
            MoveCommand::Rotate {
                angle_deg,
                speed_mps,
            } => self.send(&packets::RotationMovement {
                angle_deg,
                speed_mps,
                move_id: id,
            }),
            MoveCommand::Arc {
                radius_m,
                angle_deg,
                speed_mps,
            } => self.send(&packets::ArcMovement {
                radius_m,
                angle_deg,
                speed_mps,
                move_id: id,
            }),
        };
        if let Err(e) = sent {
            return Box::pin(async move { Err(e) });
        }
        let (tx, rx) = oneshot::channel();
        self.moves.insert(id, (Instant::now(), tx));
        let robot = self.robot_id();
        Box::pin(async move {
            rx.await.unwrap_or(Err(RobotError::LinkLost {
                robot,
                after: Duration::ZERO,
            }))
        })
    }
}

impl Handler<WaitIdle> for RobotActor {
    type Result = ResponseFuture<Result<(), RobotError>>;
    fn handle(&mut self, _: WaitIdle, _: &mut Self::Context) -> Self::Result {
        if self.moves.is_empty() {
            return Box::pin(async { Ok(()) });
        }
        let (tx, rx) = oneshot::channel();
        self.idle_waiters.push(tx);
        let robot = self.robot_id();
        Box::pin(async move { rx.await.unwrap_or(Err(RobotError::NotConnected { robot })) })
    }
}

impl Handler<Command> for RobotActor {
    type Result = Result<(), RobotError>;
    fn handle(&mut self, msg: Command, _: &mut Self::Context) -> Self::Result {
        match msg {
            Command::ClearQueue => self.send(&packets::ClearQueue {}),
            Command::Stop => self.send(&packets::Stop {}),
            Command::WheelSpeeds(left_mps, right_mps) => self.send(&packets::WheelSpeeds {
                left_mps,
                right_mps,
            }),
            Command::MotorPower(left_pwm, right_pwm) => self.send(&packets::MotorPower {
                left_pwm,
                right_pwm,
            }),
            Command::FollowLine(speed) => self.send(&packets::LineFollow {
                enable: u8::from(speed.is_some()),
                speed_mps: speed.unwrap_or(0.0),
            }),
            Command::CalibrateLine(action) => self.send(&packets::LineCalibration {
                action: action as u8,
            }),
            Command::Led(red, green, blue) => self.send(&packets::SetLed { red, green, blue }),
            Command::IrMessage(message) => self.send(&packets::IrMessage { message }),
            Command::Reflector(r) => {
                self.config.reflector = r;
                self.send(&packets::ReflectorConfig {
                    mode: r.mode as u8,
                    period_ms: r.period_ms,
                })
            }
        }
    }
}

impl Handler<WriteSettings> for RobotActor {
    type Result = ResponseFuture<Result<(), RobotError>>;
    fn handle(&mut self, msg: WriteSettings, _: &mut Self::Context) -> Self::Result {
        let (offset, len) = (msg.offset, msg.bytes.len());
        let prepared = self.layout_ok().and_then(|()| {
            Settings::check_range(offset, len)
                .map_err(|_| RobotError::BadSettingsRange { offset, len })?;
            packets::SettingsUpdate::new(offset as u16, &msg.bytes)
                .ok_or(RobotError::BadSettingsRange { offset, len })
        });
        let update = match prepared {
            Ok(u) => u,
            Err(e) => return Box::pin(async move { Err(e) }),
        };
        if let Err(e) = self.send(&update).and_then(|()| {
            self.send(&packets::SettingsRead {
                offset: offset as u16,
                len: len as u8,
            })
        }) {
            return Box::pin(async move { Err(e) });
        }
        self.host_writes.insert(offset, msg.bytes.clone());
        let (tx, rx) = oneshot::channel();
        self.reads.push_back((offset, len, msg.bytes, tx));
        let robot = self.robot_id();
        Box::pin(async move { rx.await.unwrap_or(Err(RobotError::NotConnected { robot })) })
    }
}

impl Handler<ReadSettings> for RobotActor {
    type Result = ResponseFuture<Result<Settings, RobotError>>;
    fn handle(&mut self, _: ReadSettings, _: &mut Self::Context) -> Self::Result {
        if let Err(e) = self.layout_ok() {
            return Box::pin(async move { Err(e) });
        }
        let (tx, rx) = oneshot::channel();
        self.full_reads.push(tx);
        self.request_all_settings();
        let robot = self.robot_id();
        Box::pin(async move { rx.await.unwrap_or(Err(RobotError::NotConnected { robot })) })
    }
}

impl Handler<SaveSettings> for RobotActor {
    type Result = ResponseFuture<Result<(), RobotError>>;
    fn handle(&mut self, _: SaveSettings, _: &mut Self::Context) -> Self::Result {
        if let Err(e) = self
            .layout_ok()
            .and_then(|()| self.send(&packets::SettingsSave {}))
        {
            return Box::pin(async move { Err(e) });
        }
        let (tx, rx) = oneshot::channel();
        self.saves.push_back(tx);
        let robot = self.robot_id();
        Box::pin(async move { rx.await.unwrap_or(Err(RobotError::NotConnected { robot })) })
    }
}

impl Handler<RestoreDefaults> for RobotActor {
    type Result = ResponseFuture<Result<Settings, RobotError>>;
    fn handle(&mut self, _: RestoreDefaults, _: &mut Self::Context) -> Self::Result {
        if let Err(e) = self
            .layout_ok()
            .and_then(|()| self.send(&packets::SettingsRestoreDefaults {}))
        {
            return Box::pin(async move { Err(e) });
        }
        self.host_writes.clear();
        let (tx, rx) = oneshot::channel();
        self.full_reads.push(tx);
        self.request_all_settings();
        let robot = self.robot_id();
        Box::pin(async move { rx.await.unwrap_or(Err(RobotError::NotConnected { robot })) })
    }
}

impl Handler<SetOdometryOrigin> for RobotActor {
    type Result = ();
    fn handle(&mut self, msg: SetOdometryOrigin, _: &mut Self::Context) {
        self.odometry.reset(msg.0);
    }
}

impl Handler<Close> for RobotActor {
    type Result = ();
    fn handle(&mut self, _: Close, ctx: &mut Self::Context) {
        ctx.stop();
    }
}

/// A failed connect attempt in a few words; a refusal says so plainly, as it is the usual mistake
/// (a wrong port, or a robot server not started yet).
fn describe_connect_error(e: &crate::link::LinkError) -> String {
    match e {
        crate::link::LinkError::Connect { peer, source }
            if source.kind() == std::io::ErrorKind::ConnectionRefused =>
        {
            format!("connection refused by {peer} (nothing listens there)")
        }
        other => other.to_string(),
    }
}

/// Which settings layout hash this host was built with (for reports).
pub fn host_settings_layout() -> u64 {
    Settings::LAYOUT.hash
}
