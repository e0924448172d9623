//! The embedded control system: owns the modules and the board, and turns the board's interrupts
//! (`tick`, `on_encoder_edge`, `on_ir_frame`, `on_link_bytes`/`on_link_packet`) into motor duties,
//! LED colours, IR frames and outgoing packets.
//!
//! Nothing here blocks or reads a clock: every entry point takes `now`, so the same code runs on a
//! microcontroller timer, in the simulator's physics time, and in host tests.

mod commands;
mod control;
mod drive;
mod link;
mod state;
mod tasks;

use heapless::{Deque, Vec};
use protocol::packets::{self, MoveOutcome};
use protocol::settings::{Settings, SettingsError};
use protocol::slip::SlipDecoder;
use protocol::state::RobotState;
use protocol::MAX_PACKET;

use crate::bump::BumpDetector;
use crate::hal::{Board, EncoderEdge, IrFrame, Side, Wheel};
use crate::line_follow::LineFollower;
use crate::line_sensor::{LineReading, LineSensor};
use crate::locomotion::Locomotion;
use crate::pid::Pid;
use crate::proximity::Proximity;
use crate::reflector::Reflector;
use crate::scheduler::{Channel, Scheduler};
use crate::speed::SpeedMeter;
use crate::time::{Duration, Instant};
use crate::watchdog::Watchdog;
use drive::Drive;

/// Firmware version reported in the hello packet.
pub const FIRMWARE_VERSION: [u8; 3] = [0, 1, 0];
/// Outgoing packets buffered before new ones are dropped and counted.
pub const TX_QUEUE: usize = 24;

/// One encoded outgoing packet.
pub type OutPacket = Vec<u8, MAX_PACKET>;
/// Events kept for the host to ask for again (`EventReplay`): at the busiest (a move finishing
/// every few ms, sightings every 20 ms) more than a Bluetooth link's worst round trip.
pub const EVENT_LOG: usize = 32;
/// Bytes of the longest event frame.
const EVENT_FRAME: usize = 24;

/// The robot's embedded control system running on board `B`.
pub struct Firmware<B: Board> {
    board: B,
    settings: Settings,
    state: RobotState,
    scheduler: Scheduler,
    speed: [SpeedMeter; 2],
    wheel_pid: [Pid; 2],
    locomotion: Locomotion,
    line_sensor: LineSensor,
    line: LineReading,
    follower: LineFollower,
    proximity: Proximity,
    bump: BumpDetector,
    drive: Drive,
    reflector: Reflector,
    watchdog: Watchdog,
    slip: SlipDecoder,
    tx: Deque<OutPacket, TX_QUEUE>,
    /// The last events sent, by number, as they went out.
    events: Deque<(u16, Vec<u8, EVENT_FRAME>), EVENT_LOG>,
    /// The newest move id accepted since the last hello (0: none): older ids are copies.
    last_move_id: u16,
    ir_message: u16,
    last_main: Option<Instant>,
    now: Instant,
    started: bool,
    /// When this boot's first tick ran: the robot's clock (state, events, pongs) counts from it,
    /// as a microcontroller's counter starts again at every reset.
    boot: Instant,
    /// Why the stored settings were refused at boot, reported once the link runs.
    boot_refusal: Option<SettingsError>,
}

impl<B: Board> Firmware<B> {
    /// Boots on `board`: settings come from its storage, or the factory image if none is stored.
    pub fn new(mut board: B) -> Self {
        let mut settings = Settings::default();
        let mut image = [0u8; Settings::SIZE];
        let mut boot_refusal = None;
        if board.load(&mut image).is_ok() {
            let stored: Settings = bytemuck::pod_read_unaligned(&image);
            // A corrupt or out-of-range image would run the loops with nonsense (a zero period
            // floods overruns); the factory image is safe, and the host can write settings again.
            match stored.validate() {
                Ok(()) => settings = stored,
                Err(e) => boot_refusal = Some(e),
            }
        }
        board.set_pwm(0, 0);
        Self {
            board,
            settings,
            state: RobotState::default(),
            scheduler: Scheduler::new(),
            speed: [SpeedMeter::new(); 2],
            wheel_pid: [Pid::new(); 2],
            locomotion: Locomotion::new(),
            line_sensor: LineSensor::new(),
            line: LineReading {
                darkness: [0; 8],
                position_um: 0,
                lost: true,
            },
            follower: LineFollower::new(),
            proximity: Proximity::new(),
            bump: BumpDetector::new(),
            drive: Drive::Idle,
            reflector: Reflector::new(),
            watchdog: Watchdog::new(),
            slip: SlipDecoder::new(),
            tx: Deque::new(),
            events: Deque::new(),
            last_move_id: 0,
            ir_message: 0,
            last_main: None,
            now: Instant::ZERO,
            started: false,
            boot: Instant::ZERO,
            boot_refusal,
        }
    }

    /// The robot's clock at `t`, milliseconds since boot (wrapping), as every report gives it.
    pub(crate) fn clock_ms(&self, t: Instant) -> u32 {
        t.since(self.boot).as_millis() as u32
    }

    /// The board, for a simulator or test to inspect.
    pub fn board(&self) -> &B {
        &self.board
    }

    /// The board, for a simulator or test to feed.
    pub fn board_mut(&mut self) -> &mut B {
        &mut self.board
    }

    /// Powers down: hands the board back (for a simulated reboot).
    pub fn into_board(self) -> B {
        self.board
    }

    /// The live settings.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// The latest robot state.
    pub fn state(&self) -> &RobotState {
        &self.state
    }

    /// The robot id from the settings.
    pub fn robot_id(&self) -> u16 {
        self.settings.identity.robot_id
    }

    /// The earliest time `tick` has work to do, for a board that sleeps until then.
    pub fn next_deadline(&self) -> Option<Instant> {
        if !self.started {
            return Some(self.now);
        }
        let wd = self.watchdog_deadline();
        match (self.scheduler.next_due(), wd) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// When the watchdog would stop a moving robot: a board that sleeps until
    /// [`next_deadline`](Self::next_deadline) wakes exactly then, not every millisecond.
    fn watchdog_deadline(&self) -> Option<Instant> {
        if self.drive == Drive::Idle && self.locomotion.is_empty() {
            return None;
        }
        let timeout = Duration::from_millis(u64::from(self.settings.watchdog.timeout_ms));
        self.watchdog.deadline(timeout)
    }

    /// Timer entry point: runs every scheduler channel that is due and checks the watchdog.
    pub fn tick(&mut self, now: Instant) {
        self.now = now;
        if !self.started {
            self.start(now);
        }
        while let Some(edge) = self.board.pop_edge() {
            self.on_encoder_edge(edge.wheel, edge.at);
        }
        while let Some((channel, scheduled)) = self.scheduler.pop_due(now) {
            match channel {
                Channel::MainLoop => self.main_loop(scheduled, now),
                Channel::LineSensor => self.line_task(scheduled, now),
                Channel::IrTransmit => self.ir_transmit_task(scheduled, now),
                Channel::IrReport => self.ir_report_task(scheduled, now),
            }
        }
        let timeout = Duration::from_millis(u64::from(self.settings.watchdog.timeout_ms));
        if let Some(silent) = self.watchdog.check(now, timeout) {
            if self.drive != Drive::Idle || !self.locomotion.is_empty() {
                self.halt(MoveOutcome::Stopped);
                self.send_event(packets::WatchdogStop {
                    at_ms: 0,
                    seq: 0,
                    silent_ms: silent.as_millis().min(u64::from(u32::MAX)) as u32,
                });
                crate::fw_log!(
                    self,
                    Warn,
                    "watchdog",
                    "host silent {} ms",
                    silent.as_millis()
                );
            }
        }
    }

    fn start(&mut self, now: Instant) {
        self.started = true;
        self.boot = now;
        self.scheduler.schedule(Channel::MainLoop, now);
        self.scheduler.schedule(Channel::LineSensor, now);
        self.scheduler.schedule(Channel::IrTransmit, now);
        self.scheduler.schedule(Channel::IrReport, now);
        crate::fw_log!(self, Info, "boot", "robot {} up", self.robot_id());
        if let Some(e) = self.boot_refusal.take() {
            crate::fw_log!(self, Warn, "boot", "stored settings refused: {}", e);
        }
    }

    /// Encoder interrupt entry point: one edge of `wheel` captured at `at`.
    pub fn on_encoder_edge(&mut self, wheel: Wheel, at: Instant) {
        let timeout = Duration::from_micros(u64::from(self.settings.speed_meter.timeout_us));
        self.speed[wheel as usize].on_edge(at, timeout);
    }

    /// IR receiver entry point: `frame` arrived on the `side` receiver at `now`.
    pub fn on_ir_frame(&mut self, now: Instant, side: Side, frame: IrFrame) {
        let id = self.robot_id();
        self.proximity.on_frame(now, side, frame, id);
    }
}

/// Lets a board that queues edges hand them over one by one (used by `tick`).
impl EncoderEdge {
    /// An edge of `wheel` at `at`.
    pub const fn new(wheel: Wheel, at: Instant) -> Self {
        Self { wheel, at }
    }
}
