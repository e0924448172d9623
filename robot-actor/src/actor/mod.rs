//! `RobotActor`: one robot on the host (thesis ch. 5 and 9). It owns the robot's link, keeps the
//! reflected state and a mirror of its settings, turns typed commands into packets, resolves move
//! futures from the robot's own events, tracks odometry and link statistics, and reconnects with
//! backoff when the link is lost.
//!
//! The actor's state is grouped by concern, each in its own file: the link's liveness (ping,
//! round trips, loss, reconnect: `liveness`), the greeting (`greeting`), the settings mirror
//! (`settings`) and the moves in flight (`moves`); its public types are in `messages` and
//! `error`, re-exported here.

use std::sync::Arc;

use actix::prelude::*;
use protocol::packets::{self, AnyPacket, NackReason};
use protocol::{Frame, Packet, PacketType, ReducedState, RobotState, Settings};
use tokio::sync::{mpsc, oneshot};
use tokio::time::Instant;
use tracing::{debug, info, warn};

use crate::link::{Connector, LinkEvent};
use crate::odometry::{Geometry, Odometry};

mod batch;
mod delivery;
mod error;
mod greeting;
mod liveness;
mod messages;
mod moves;
mod settings;

pub use batch::{StateBatch, SubscribeBatches};
pub use delivery::DeliveryCounts;
pub use error::{incompatibilities, Incompatibility, RobotError};
pub use liveness::LinkStats;
pub use messages::{
    Close, Command, ContinueOdometry, Continued, Enqueue, GetSnapshot, MoveCommand, ReadSettings,
    ReflectorSetup, RestoreDefaults, RobotConfig, RobotEvent, RobotEventKind, RobotSnapshot,
    SaveSettings, SetOdometryOrigin, StateUpdated, Subscribe, SubscribeEvents, WaitConnected,
    WaitIdle, WriteSettings,
};
pub use settings::host_settings_layout;

use delivery::{Delivery, Expect};
use greeting::Greeting;
use liveness::Liveness;
use moves::Moves;
use settings::SettingsMirror;

type Reply<T> = oneshot::Sender<Result<T, RobotError>>;

/// The host-side representation of one robot.
pub struct RobotActor {
    connector: Arc<dyn Connector>,
    config: RobotConfig,
    link: Liveness,
    greeting: Greeting,
    reflected: Reflected,
    mirror: SettingsMirror,
    odometry: Odometry,
    subscribers: Subscribers,
    moves: Moves,
    delivery: Delivery,
    /// A [`ContinueOdometry`] that waits for the link's first state.
    continuing: Option<(ContinueOdometry, oneshot::Sender<Continued>)>,
}

/// The robot's latest reflected state.
#[derive(Default)]
struct Reflected {
    /// Fields a reduced packet does not carry keep their last full value.
    state: RobotState,
    /// When the last full state arrived.
    full_at: Option<Instant>,
    /// When the last reduced state arrived.
    reduced_at: Option<Instant>,
    /// A state showed that the robot restarted since the one before, and the link it came on
    /// has not been restarted for it yet.
    rebooted: bool,
}

/// A robot whose clock since boot goes back by more than this restarted: reordered or delayed
/// states go back by a few packets' worth, never by a second.
const REBOOT_BACK_MS: u32 = 1_000;

impl Reflected {
    /// Whether a state sampled at the robot's `uptime_ms` comes from after a restart: its clock
    /// since boot went back (a wrap after 49 days goes forward).
    fn restarted(&self, uptime_ms: u32) -> bool {
        let back = self.state.uptime_ms.wrapping_sub(uptime_ms);
        (self.full_at.is_some() || self.reduced_at.is_some())
            && back > REBOOT_BACK_MS
            && back < 1 << 31
    }

    fn merge_reduced(&mut self, r: ReducedState) {
        self.state.uptime_ms = r.uptime_ms;
        self.state.encoders = r.encoders;
        self.state.wheels = r.wheels;
        self.state.line.position_um = r.line_position_um;
        self.state.line.flags = r.line_flags;
    }
}

/// Who hears from the actor.
#[derive(Default)]
struct Subscribers {
    /// Every reflected state, with its odometry pose.
    states: Vec<Recipient<StateUpdated>>,
    /// The same, in batches.
    batches: Vec<Recipient<StateBatch>>,
    /// Every event.
    events: Vec<Recipient<RobotEvent>>,
}

impl RobotActor {
    /// An actor that will connect through `connector` when started.
    pub fn new(connector: Arc<dyn Connector>, config: RobotConfig) -> Self {
        let settings = Settings::default();
        let odometry = Odometry::new(Geometry::from_settings(&settings), config.origin);
        Self {
            connector,
            link: Liveness::new(config.min_backoff),
            config,
            greeting: Greeting::default(),
            reflected: Reflected::default(),
            mirror: SettingsMirror::new(settings),
            odometry,
            subscribers: Subscribers::default(),
            moves: Moves::new(),
            delivery: Delivery::default(),
            continuing: None,
        }
    }

    fn robot_id(&self) -> u16 {
        self.greeting.hello.map_or(0, |h| h.robot_id)
    }

    fn not_connected(&self) -> RobotError {
        self.greeting
            .refused
            .clone()
            .unwrap_or(RobotError::NotConnected {
                robot: self.robot_id(),
            })
    }

    fn send<P: Packet>(&mut self, p: &P) -> Result<(), RobotError> {
        self.send_frame(p).map(|_| ())
    }

    /// Sends `p` and gives back its frame, for sending again if the robot does not show it.
    fn send_frame<P: Packet>(&mut self, p: &P) -> Result<Vec<u8>, RobotError> {
        let (buf, n) = protocol::frame::encode_to_array(p);
        let frame = buf[..n].to_vec();
        self.send_bytes(frame.clone())?;
        Ok(frame)
    }

    fn send_bytes(&mut self, frame: Vec<u8>) -> Result<(), RobotError> {
        let tx = self.link.tx.as_ref().ok_or_else(|| self.not_connected())?;
        match tx.try_send(frame) {
            Ok(()) => {
                self.link.stats.packets_out += 1;
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
        match (&self.greeting.refused, self.greeting.hello) {
            (Some(refusal), _) => Err(refusal.clone()),
            (None, None) => Err(self.not_connected()),
            (None, Some(_)) => Ok(()),
        }
    }

    fn emit(&mut self, kind: RobotEventKind) {
        self.emit_at(kind, None);
    }

    /// Emits what the robot reported as happening at `robot_ms` of its clock.
    fn emit_at(&mut self, kind: RobotEventKind, robot_ms: Option<u32>) {
        // States still waiting in this thread's batches happened before the event.
        batch::flush();
        let at = Instant::now();
        if let Some(ms) = robot_ms {
            self.link.on_event_time(ms, at);
        }
        let e = RobotEvent {
            robot_id: self.robot_id(),
            at,
            robot_ms,
            kind,
        };
        for s in &self.subscribers.events {
            s.do_send(e.clone());
        }
    }

    fn publish_state(&mut self, reduced: bool, at: Instant) {
        if let Some((msg, reply)) = self.continuing.take() {
            let _ = reply.send(self.continue_odometry(&msg));
        }
        let pose = self.odometry.update(
            self.reflected.state.encoders.left_ticks,
            self.reflected.state.encoders.right_ticks,
        );
        let u = StateUpdated {
            robot_id: self.robot_id(),
            at,
            state: self.reflected.state,
            reduced,
            pose,
            rtt: self.delivery.longest_rtt(),
        };
        for s in &self.subscribers.states {
            s.do_send(u);
        }
        for s in &self.subscribers.batches {
            if self.config.batch_states {
                batch::push(s, u);
            } else {
                s.do_send(StateBatch(vec![u]));
            }
        }
    }

    /// A robot that restarted counts its encoders from zero again: the odometry takes the next
    /// totals as its new base, not as a drive back. Its queued moves and unsaved settings are
    /// gone with its RAM, so the link is restarted too (see the stream handler).
    fn restart_if_rebooted(&mut self, uptime_ms: u32) {
        if self.reflected.restarted(uptime_ms) {
            warn!(robot = self.robot_id(), "the robot restarted");
            self.odometry.rebase();
            self.reflected.rebooted = self.greeting.greeted;
        }
    }

    /// `at`: when the packet arrived (one clock read per packet: at thousands of links per core
    /// each read counts).
    fn handle_packet(&mut self, packet: AnyPacket, at: Instant) {
        match packet {
            AnyPacket::State(s) => {
                self.restart_if_rebooted(s.uptime_ms);
                self.reflected.state = s;
                self.reflected.full_at = Some(at);
                self.publish_state(false, at);
                self.redeliver(&s);
            }
            AnyPacket::ReducedState(r) => {
                self.restart_if_rebooted(r.uptime_ms);
                self.reflected.merge_reduced(r);
                self.reflected.reduced_at = Some(at);
                self.publish_state(true, at);
            }
            AnyPacket::Hello(h) => self.on_hello(h),
            AnyPacket::Pong(p) => {
                self.link.on_pong(p.seq, p.robot_time_us);
                if let Some(rtt) = self.link.last_rtt.take() {
                    self.delivery.on_rtt(rtt);
                }
            }
            AnyPacket::SettingsData(d) => self.on_settings_data(d),
            AnyPacket::SettingsSaved(_) => self.mirror.saved(),
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
                    self.mirror.save_refused(err.clone());
                }
                if n.packet_type == PacketType::SettingsUpdate as u8 {
                    self.on_settings_refused(n, reason);
                }
                self.emit(RobotEventKind::Refused(n));
            }
            AnyPacket::MoveFinished(m) if self.news(&m) => self.on_move_finished(m),
            AnyPacket::QueueEmpty(e) if self.news(&e) => self.on_queue_empty(e.at_ms),
            AnyPacket::Obstacle(o) if self.news(&o) => {
                self.emit_at(RobotEventKind::Obstacle(o), Some(o.at_ms))
            }
            AnyPacket::RobotEncountered(e) if self.news(&e) => {
                self.emit_at(RobotEventKind::Encounter(e), Some(e.at_ms))
            }
            AnyPacket::LineEvent(e) if self.news(&e) => {
                self.emit_at(RobotEventKind::Line(e.lost != 0), Some(e.at_ms))
            }
            AnyPacket::WatchdogStop(e) if self.news(&e) => {
                self.delivery.robot_stopped();
                self.emit_at(RobotEventKind::WatchdogStop, Some(e.at_ms))
            }
            AnyPacket::LoopOverrun(o) if self.news(&o) => {
                self.emit_at(RobotEventKind::Overrun(o.late_us), Some(o.at_ms))
            }
            AnyPacket::Bump(b) if self.news(&b) => {
                self.emit_at(RobotEventKind::Bump(b), Some(b.at_ms))
            }
            AnyPacket::Reflex(r) if self.news(&r) => {
                self.delivery.robot_stopped();
                self.emit_at(RobotEventKind::Reflex(r), Some(r.at_ms))
            }
            // A copy of an event already heard (a replay crossing the original).
            AnyPacket::MoveFinished(_)
            | AnyPacket::QueueEmpty(_)
            | AnyPacket::Obstacle(_)
            | AnyPacket::RobotEncountered(_)
            | AnyPacket::LineEvent(_)
            | AnyPacket::WatchdogStop(_)
            | AnyPacket::LoopOverrun(_)
            | AnyPacket::Bump(_)
            | AnyPacket::Reflex(_) => {}
            other => debug!(
                packet = other.packet_type().name(),
                "ignored host-bound packet"
            ),
        }
    }

    /// Whether event `e` is news, not a copy of one heard already.
    fn news<E: packets::Event>(&mut self, e: &E) -> bool {
        self.delivery.admit(e.seq())
    }

    /// Asks again for events the robot sent that never came, and sends again what `state`
    /// does not show: moves not taken, a stop or clear not carried out, a drive mode not entered.
    fn redeliver(&mut self, state: &RobotState) {
        let next = self.moves.next_id;
        let again = self.delivery.on_state(state, next);
        if let Some(from_seq) = again.replay_from {
            debug!(
                robot = self.robot_id(),
                from_seq, "asking for lost events again"
            );
            let _ = self.send(&packets::EventReplay { from_seq });
        }
        for frame in again.frames {
            let packet = frame.get(1).and_then(|&c| PacketType::from_code(c));
            debug!(robot = self.robot_id(), ?packet, "sending a command again");
            let _ = self.send_bytes(frame);
        }
        let wait = self.delivery.wait();
        let moves = self.moves.not_taken(state.locomotion.last_move_id, wait);
        if !moves.is_empty() {
            debug!(
                robot = self.robot_id(),
                n = moves.len(),
                "sending moves again"
            );
            self.delivery.counts.commands_resent += moves.len() as u64;
        }
        for frame in moves {
            let _ = self.send_bytes(frame);
        }
    }

    fn snapshot(&self) -> RobotSnapshot {
        RobotSnapshot {
            robot_id: self.robot_id(),
            peer: self.connector.peer(),
            connected: self.link.tx.is_some() && self.greeting.greeted,
            hello: self.greeting.hello,
            state: self.reflected.state,
            full_state_at: self.reflected.full_at,
            reduced_state_at: self.reflected.reduced_at,
            settings: self.mirror.settings,
            settings_known: self.greeting.hello.is_some() && self.mirror.chunks_missing == 0,
            pose: self.odometry.pose(),
            odometry_totals: self.odometry.totals(),
            link: LinkStats {
                delivery: self.delivery.counts,
                ..self.link.stats_now()
            },
            pending_moves: self.moves.pending(),
            link_error: self.link.link_error.clone(),
            refused: self.greeting.refused.clone(),
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
        let _ = self.send(&packets::Stop { keep_from: 0 });
    }
}

impl StreamHandler<(u64, LinkEvent)> for RobotActor {
    fn handle(&mut self, (generation, event): (u64, LinkEvent), ctx: &mut Self::Context) {
        if generation != self.link.generation {
            return;
        }
        match event {
            LinkEvent::Packet(bytes) => {
                let now = Instant::now();
                self.link.last_seen = Some(now);
                match Frame::parse(&bytes) {
                    Ok(frame) => {
                        self.link.stats.packets_in += 1;
                        self.handle_packet(frame.packet(), now);
                        if std::mem::take(&mut self.reflected.rebooted) {
                            // Dropped and made again, the link greets afresh: the host's
                            // settings are written again and the supervisor hears of the gap.
                            self.link_lost(ctx, "the robot restarted");
                        }
                    }
                    Err(e) => {
                        self.link.stats.checksum_errors += 1;
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
        self.subscribers.states.push(msg.0);
    }
}

impl Handler<SubscribeBatches> for RobotActor {
    type Result = ();
    fn handle(&mut self, msg: SubscribeBatches, _: &mut Self::Context) {
        self.subscribers.batches.push(msg.0);
    }
}

impl Handler<SubscribeEvents> for RobotActor {
    type Result = ();
    fn handle(&mut self, msg: SubscribeEvents, _: &mut Self::Context) {
        self.subscribers.events.push(msg.0);
    }
}

impl Handler<GetSnapshot> for RobotActor {
    type Result = MessageResult<GetSnapshot>;
    fn handle(&mut self, _: GetSnapshot, _: &mut Self::Context) -> Self::Result {
        MessageResult(self.snapshot())
    }
}

impl Handler<Command> for RobotActor {
    type Result = Result<(), RobotError>;
    fn handle(&mut self, msg: Command, _: &mut Self::Context) -> Self::Result {
        match msg {
            Command::ClearQueue | Command::Stop => {
                let keep_from = self.moves.next_id;
                let stop = matches!(msg, Command::Stop);
                let frame = if stop {
                    self.send_frame(&packets::Stop { keep_from })?
                } else {
                    self.send_frame(&packets::ClearQueue { keep_from })?
                };
                self.delivery.sent_clear(keep_from, stop, frame);
                Ok(())
            }
            Command::WheelSpeeds(left_mps, right_mps) => {
                let p = packets::WheelSpeeds {
                    left_mps,
                    right_mps,
                };
                self.send_drive(&p, Expect::WheelSpeeds)
            }
            Command::MotorPower(left_pwm, right_pwm) => {
                let p = packets::MotorPower {
                    left_pwm,
                    right_pwm,
                };
                self.send_drive(&p, Expect::MotorPower)
            }
            Command::FollowLine(speed) => {
                let p = packets::LineFollow {
                    enable: u8::from(speed.is_some()),
                    speed_mps: speed.unwrap_or(0.0),
                };
                let expect = if speed.is_some() {
                    Expect::Following
                } else {
                    Expect::NotFollowing
                };
                self.send_drive(&p, expect)
            }
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

impl RobotActor {
    /// Sends a drive command, kept until the robot's state shows its drive mode.
    fn send_drive<P: Packet>(&mut self, p: &P, expect: Expect) -> Result<(), RobotError> {
        let frame = self.send_frame(p)?;
        self.delivery.sent_drive(expect, frame, self.moves.next_id);
        Ok(())
    }
}

impl Handler<SetOdometryOrigin> for RobotActor {
    type Result = ();
    fn handle(&mut self, msg: SetOdometryOrigin, _: &mut Self::Context) {
        self.odometry.reset(msg.0);
    }
}

impl Handler<ContinueOdometry> for RobotActor {
    type Result = ResponseFuture<Continued>;
    fn handle(&mut self, msg: ContinueOdometry, _: &mut Self::Context) -> Self::Result {
        let reported = self.reflected.full_at.is_some() || self.reflected.reduced_at.is_some();
        if reported {
            let c = self.continue_odometry(&msg);
            return Box::pin(async move { c });
        }
        // Answered with the first state; a link that closes first answers nothing known.
        let (tx, rx) = oneshot::channel();
        self.continuing = Some((msg, tx));
        Box::pin(async move { rx.await.unwrap_or_default() })
    }
}

impl RobotActor {
    /// Carries the odometry on from `msg`'s record to the latest reflected state.
    fn continue_odometry(&mut self, msg: &ContinueOdometry) -> Continued {
        let elapsed_ms = self.reflected.state.uptime_ms.wrapping_sub(msg.uptime_ms);
        // A clock that went back restarted (one that went forward by half its range did too).
        if elapsed_ms >= 1 << 31 {
            self.odometry.reset(msg.pose);
            return Continued {
                reported: true,
                rebooted: true,
                ..Continued::default()
            };
        }
        self.odometry.continue_from(msg.pose, msg.counters);
        let e = self.reflected.state.encoders;
        let pose = self.odometry.update_across_gap(e.left_ticks, e.right_ticks);
        let (l, r) = self.odometry.totals();
        Continued {
            reported: true,
            rebooted: false,
            driven_m: self.odometry.geometry().tick_m() * (l + r) as f64 * 0.5,
            turned_rad: pose.theta - msg.pose.theta,
            elapsed_ms,
        }
    }
}

impl Handler<Close> for RobotActor {
    type Result = ();
    fn handle(&mut self, _: Close, ctx: &mut Self::Context) {
        ctx.stop();
    }
}
