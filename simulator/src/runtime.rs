//! The simulation as an async service: a task steps the world, paced either by a tokio clock
//! (faster than real time under a paused test clock, or as fast as the machine goes) or by the wall
//! clock, and each robot's link appears as an async packet channel ([`LinkEnd`]).
//!
//! Under tokio's paused clock (`start_paused(true)`) the stepping task sleeps one `dt` per step, so
//! simulated time advances only when every other task is idle: lockstep, deterministic, and as
//! fast as the host side can keep up.
//!
//! Packets a host sends wait in a buffer of [`LINK_BUFFER_BYTES`] until the next step hands them to
//! the link, which holds as much again: a host sending faster than the link carries loses packets
//! (counted in the robot's [`LinkStats`](crate::link::LinkStats) and logged at most once a second),
//! and neither memory nor the delay of later packets grows with the flood.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use tokio::sync::{mpsc, oneshot};

use crate::link::{PacketQueue, LINK_BUFFER_BYTES};
use crate::sim::{Pose, Simulation};

/// How the stepping task keeps time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pace {
    /// One tokio `sleep(dt)` per step: real time on a real clock, instant under a paused clock.
    TokioClock,
    /// Steps as fast as possible, yielding to other tasks between steps.
    Unpaced,
    /// Steps in batches and sleeps until the wall clock catches up.
    WallClock,
    /// As [`Pace::WallClock`], with simulated time running at this fraction of the wall
    /// clock's pace (0.5: one simulated second every two seconds).
    Scaled(f64),
}

enum Command {
    Connect(usize),
    Disconnect(usize, Option<oneshot::Sender<()>>),
    SetLinkUp(usize, bool),
    Truth(oneshot::Sender<Truth>),
    Poses(oneshot::Sender<Poses>),
    Displace(usize, [f64; 3], oneshot::Sender<Result<Pose, String>>),
    DisplaceAt(Duration, usize, [f64; 3]),
    Inspect(Box<dyn FnOnce(&mut Simulation) + Send>),
    Stop,
}

/// Ground truth at one instant, for tests and reports.
#[derive(Clone, Debug, PartialEq)]
pub struct Truth {
    /// Simulated time.
    pub now: Duration,
    /// Robot ids and true poses.
    pub robots: Vec<(u16, Pose)>,
    /// True distance each robot drove, metres.
    pub distances_m: Vec<f64>,
    /// Box poses.
    pub obstacles: Vec<Pose>,
    /// How far each box moved from its start, metres.
    pub obstacle_displacements_m: Vec<f64>,
    /// Robot–robot contacts so far.
    pub robot_collisions: usize,
    /// Each robot–robot contact: when it began (simulated seconds) and the two robot ids.
    pub collision_log: Vec<(f64, u16, u16)>,
    /// Robot–wall contacts so far.
    pub wall_contacts: usize,
    /// Each robot–wall contact: when it began (simulated seconds) and the robot's id.
    pub wall_contact_log: Vec<(f64, u16)>,
    /// Each robot's true wheel rim speeds (left, right), m/s.
    pub wheel_speeds_mps: Vec<[f64; 2]>,
    /// When each robot last heard its host, simulated seconds.
    pub last_host_packet_s: Vec<Option<f64>>,
    /// Each robot's host silences so far.
    pub host_silences: Vec<Vec<crate::sim::HostSilence>>,
    /// Settings update packets each robot received from its host.
    pub settings_updates: Vec<u32>,
    /// Each robot's firmware watchdog timeout now, milliseconds (0: off).
    pub watchdog_ms: Vec<u16>,
}

/// The robots' true poses at one instant: the part of [`Truth`] cheap enough to ask for many times
/// a second.
#[derive(Clone, Debug, PartialEq)]
pub struct Poses {
    /// Simulated time.
    pub now: Duration,
    /// Robot ids and true poses, in world order.
    pub robots: Vec<(u16, Pose)>,
}

/// What a host's side of one link has dropped for a full buffer, as (packets, bytes) per
/// direction, not yet counted in the simulation.
#[derive(Default)]
struct Dropped {
    to_robot: (u64, u64),
    to_host: (u64, u64),
}

/// Where the stepping task hands a robot's packets when a reader has asked for them directly
/// ([`LinkSender::set_sink`]): `Some(packet)`, or `None` once the simulation has stopped. It returns
/// `false` once its reader is gone.
pub type Sink = Box<dyn FnMut(Option<Vec<u8>>) -> bool + Send>;

/// Host packets on their way into the simulation, shared by a link end and the stepping task.
struct HostBuffer {
    inbox: Mutex<(PacketQueue, Dropped)>,
    stopped: AtomicBool,
    /// A reader's sink with its key, which takes the robot's packets instead of the channel.
    sink: Mutex<Option<(u64, Sink)>>,
    /// Every robot's "something to drain" flag, in one allocation, so the stepping task finds the
    /// few buffers to drain each step without touching every robot's lock.
    waiting: Arc<[AtomicBool]>,
    index: usize,
}

impl HostBuffer {
    fn new(waiting: Arc<[AtomicBool]>, index: usize) -> Self {
        Self {
            inbox: Mutex::new((PacketQueue::new(LINK_BUFFER_BYTES), Dropped::default())),
            stopped: AtomicBool::new(false),
            sink: Mutex::new(None),
            waiting,
            index,
        }
    }

    /// Flags this buffer for the next step's drain; called after the inbox changed.
    fn mark(&self) {
        self.waiting[self.index].store(true, Ordering::Release);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, (PacketQueue, Dropped)> {
        // The guarded data stays consistent whatever panicked while holding it.
        self.inbox.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn sink(&self) -> std::sync::MutexGuard<'_, Option<(u64, Sink)>> {
        self.sink.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn send(&self, packet: &[u8]) -> bool {
        if self.stopped.load(Ordering::Acquire) {
            return false;
        }
        let mut guard = self.lock();
        let (queue, dropped) = &mut *guard;
        if queue.fits(packet.len()) {
            let _ = queue.push(0, packet.to_vec());
        } else {
            dropped.to_robot.0 += 1;
            dropped.to_robot.1 += packet.len() as u64;
        }
        drop(guard);
        self.mark();
        true
    }

    fn dropped_to_host(&self, bytes: usize) {
        let mut guard = self.lock();
        guard.1.to_host.0 += 1;
        guard.1.to_host.1 += bytes as u64;
        drop(guard);
        self.mark();
    }
}

/// Marks the host buffers stopped however the stepping task ends (returned, or dropped with its
/// runtime), so senders learn it.
struct StopOnDrop(Vec<Arc<HostBuffer>>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        for b in &self.0 {
            // Under the sink's lock, so a sink set at the same time hears of the stop either way.
            let mut slot = b.sink();
            b.stopped.store(true, Ordering::Release);
            if let Some((_, mut sink)) = slot.take() {
                sink(None);
            }
        }
    }
}

/// The host end of one robot's link.
pub struct LinkEnd {
    /// Robot id.
    pub robot_id: u16,
    index: usize,
    to_robot: Arc<HostBuffer>,
    from_robot: mpsc::UnboundedReceiver<Vec<u8>>,
    commands: mpsc::UnboundedSender<Command>,
}

impl LinkEnd {
    /// Opens the link: the robot answers with its hello.
    pub fn connect(&self) {
        let _ = self.commands.send(Command::Connect(self.index));
    }

    /// Closes the link; the robot's packets go nowhere until it is opened again.
    pub fn disconnect(&self) {
        let _ = self.commands.send(Command::Disconnect(self.index, None));
    }

    /// Sends one packet's bytes to the robot; `false` once the simulation has stopped. A packet
    /// that finds the host buffer full is dropped and counted, as a serial link would.
    pub fn send(&self, packet: Vec<u8>) -> bool {
        self.to_robot.send(&packet)
    }

    /// The next packet from the robot; `None` once the simulation has stopped.
    pub async fn recv(&mut self) -> Option<Vec<u8>> {
        self.from_robot.recv().await
    }

    /// A packet from the robot if one is waiting.
    pub fn try_recv(&mut self) -> Option<Vec<u8>> {
        self.from_robot.try_recv().ok()
    }

    /// Splits into a sender half and a receiver half for two tasks.
    pub fn split(self) -> (LinkSender, mpsc::UnboundedReceiver<Vec<u8>>) {
        (
            LinkSender {
                robot_id: self.robot_id,
                index: self.index,
                to_robot: self.to_robot,
                commands: self.commands,
            },
            self.from_robot,
        )
    }
}

/// The sending half of a [`LinkEnd`].
#[derive(Clone)]
pub struct LinkSender {
    /// Robot id.
    pub robot_id: u16,
    index: usize,
    to_robot: Arc<HostBuffer>,
    commands: mpsc::UnboundedSender<Command>,
}

impl LinkSender {
    /// Sends one packet's bytes to the robot; `false` once the simulation has stopped. A packet
    /// that finds the host buffer full is dropped and counted.
    pub fn send(&self, packet: Vec<u8>) -> bool {
        self.to_robot.send(&packet)
    }
    /// As [`send`](Self::send), copying the bytes only if they fit.
    pub fn send_slice(&self, packet: &[u8]) -> bool {
        self.to_robot.send(packet)
    }
    /// Counts a robot packet of `bytes` that the host side dropped because its own client did not
    /// keep up; it shows in the robot's link statistics.
    pub fn count_dropped_to_host(&self, bytes: usize) {
        self.to_robot.dropped_to_host(bytes);
    }
    /// Opens the link.
    pub fn connect(&self) {
        let _ = self.commands.send(Command::Connect(self.index));
    }
    /// From now on the stepping task hands the robot's packets to `sink` as they arrive, instead
    /// of to the receiver half: one task's wake less per packet. Replaces an earlier sink; returns
    /// the key that [`clear_sink`](Self::clear_sink) takes. Once the simulation has stopped, the
    /// sink hears so at once.
    pub fn set_sink(&self, mut sink: Sink) -> u64 {
        static KEYS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
        let key = KEYS.fetch_add(1, Ordering::Relaxed);
        let mut slot = self.to_robot.sink();
        if self.to_robot.stopped.load(Ordering::Acquire) {
            drop(slot);
            sink(None);
        } else {
            *slot = Some((key, sink));
        }
        key
    }
    /// Removes the sink set with `key`, if it is still the one set; the robot's packets go to the
    /// receiver half again.
    pub fn clear_sink(&self, key: u64) {
        let mut slot = self.to_robot.sink();
        if slot.as_ref().is_some_and(|(k, _)| *k == key) {
            *slot = None;
        }
    }
    /// Closes the link.
    pub fn disconnect(&self) {
        let _ = self.commands.send(Command::Disconnect(self.index, None));
    }
    /// Closes the link and waits until the simulation has discarded what was queued either way:
    /// after it, nothing the old host sent reaches the robot and nothing the robot sent the old host
    /// is still to come. Returns at once if the simulation has stopped.
    pub async fn close(&self) {
        let (tx, rx) = oneshot::channel();
        if self
            .commands
            .send(Command::Disconnect(self.index, Some(tx)))
            .is_ok()
        {
            let _ = rx.await;
        }
    }
}

/// Control of a running simulation.
#[derive(Clone)]
pub struct SimHandle {
    commands: mpsc::UnboundedSender<Command>,
}

impl SimHandle {
    /// Cuts (`false`) or restores (`true`) robot `index`'s link.
    pub fn set_link_up(&self, index: usize, up: bool) {
        let _ = self.commands.send(Command::SetLinkUp(index, up));
    }

    /// Ground truth now; `None` once the simulation has stopped.
    pub async fn truth(&self) -> Option<Truth> {
        let (tx, rx) = oneshot::channel();
        self.commands.send(Command::Truth(tx)).ok()?;
        rx.await.ok()
    }

    /// The robots' true poses now, without the rest of [`Truth`] (contact logs, obstacles);
    /// `None` once the simulation has stopped.
    pub async fn poses(&self) -> Option<Poses> {
        let (tx, rx) = oneshot::channel();
        self.commands.send(Command::Poses(tx)).ok()?;
        rx.await.ok()
    }

    /// Kicks robot `index` by (`dx`, `dy`) metres and `dtheta` radians between two steps (see
    /// [`Simulation::displace`]) and returns its new true pose.
    ///
    /// # Errors
    /// There is no such robot, the displacement is not finite, or the simulation has stopped.
    pub async fn displace(
        &self,
        index: usize,
        dx: f64,
        dy: f64,
        dtheta: f64,
    ) -> Result<Pose, String> {
        let (tx, rx) = oneshot::channel();
        let stopped = || "cannot displace a robot: the simulation has stopped".to_string();
        self.commands
            .send(Command::Displace(index, [dx, dy, dtheta], tx))
            .map_err(|_| stopped())?;
        rx.await.map_err(|_| stopped())?
    }

    /// Kicks robot `index` as [`displace`](Self::displace) does, at simulated time `at` exactly
    /// however fast the simulation runs (at once if that time has passed). The outcome is logged.
    pub fn displace_at(&self, at: Duration, index: usize, dx: f64, dy: f64, dtheta: f64) {
        let _ = self
            .commands
            .send(Command::DisplaceAt(at, index, [dx, dy, dtheta]));
    }

    /// Runs `f` on the simulation between two steps and returns its result: any ground truth a
    /// test needs, or a fault to inject. `None` once the simulation has stopped.
    pub async fn inspect<T: Send + 'static>(
        &self,
        f: impl FnOnce(&mut Simulation) -> T + Send + 'static,
    ) -> Option<T> {
        let (tx, rx) = oneshot::channel();
        let job = Box::new(move |sim: &mut Simulation| {
            let _ = tx.send(f(sim));
        });
        self.commands.send(Command::Inspect(job)).ok()?;
        rx.await.ok()
    }

    /// Stops the stepping task.
    pub fn stop(&self) {
        let _ = self.commands.send(Command::Stop);
    }
}

/// Ground truth of a simulation.
pub fn truth(sim: &Simulation) -> Truth {
    use crate::sim::ContactKind;
    Truth {
        now: sim.now(),
        robots: sim.robots().iter().map(|r| (r.id(), r.pose())).collect(),
        distances_m: sim.robots().iter().map(|r| r.distance_m()).collect(),
        obstacles: sim.obstacle_poses(),
        obstacle_displacements_m: sim.obstacle_displacements(),
        robot_collisions: sim.robot_collisions(),
        collision_log: sim
            .contacts()
            .iter()
            .filter_map(|c| match c.kind {
                ContactKind::RobotRobot(a, b) => {
                    Some((c.at_s, sim.robots()[a].id(), sim.robots()[b].id()))
                }
                _ => None,
            })
            .collect(),
        wall_contacts: sim
            .contacts()
            .iter()
            .filter(|c| matches!(c.kind, ContactKind::RobotWall(_)))
            .count(),
        wall_contact_log: sim
            .contacts()
            .iter()
            .filter_map(|c| match c.kind {
                ContactKind::RobotWall(a) => Some((c.at_s, sim.robots()[a].id())),
                _ => None,
            })
            .collect(),
        wheel_speeds_mps: sim
            .robots()
            .iter()
            .map(|r| r.wheel_speeds_mps(sim.spec()))
            .collect(),
        last_host_packet_s: sim
            .robots()
            .iter()
            .map(|r| r.last_host_packet_s())
            .collect(),
        host_silences: sim
            .robots()
            .iter()
            .map(|r| r.host_silences().to_vec())
            .collect(),
        settings_updates: sim.robots().iter().map(|r| r.settings_updates()).collect(),
        watchdog_ms: sim
            .robots()
            .iter()
            .map(|r| r.firmware().settings().watchdog.timeout_ms)
            .collect(),
    }
}

/// Starts stepping `sim` on the current tokio runtime; returns its control handle and one link end
/// per robot (not yet connected).
pub fn spawn(
    sim: Simulation,
    pace: Pace,
) -> (SimHandle, Vec<LinkEnd>, tokio::task::JoinHandle<Simulation>) {
    let (cmd_tx, cmd_rx) = mpsc::unbounded_channel();
    let mut ends = Vec::new();
    let mut to_robot_rx = Vec::new();
    let mut from_robot_tx = Vec::new();
    let waiting: Arc<[AtomicBool]> = sim
        .robots()
        .iter()
        .map(|_| AtomicBool::new(false))
        .collect();
    for (i, r) in sim.robots().iter().enumerate() {
        let buffer = Arc::new(HostBuffer::new(Arc::clone(&waiting), i));
        let (from_tx, from_rx) = mpsc::unbounded_channel();
        ends.push(LinkEnd {
            robot_id: r.id(),
            index: i,
            to_robot: Arc::clone(&buffer),
            from_robot: from_rx,
            commands: cmd_tx.clone(),
        });
        to_robot_rx.push(buffer);
        from_robot_tx.push(from_tx);
    }
    let task = tokio::spawn(step_loop(
        sim,
        pace,
        cmd_rx,
        to_robot_rx,
        from_robot_tx,
        waiting,
    ));
    (SimHandle { commands: cmd_tx }, ends, task)
}

/// Logs a robot's buffer overflows at most once a second, with the count since the last line.
struct OverflowLog {
    logged: Vec<u64>,
    last: Vec<Option<std::time::Instant>>,
}

impl OverflowLog {
    const EVERY: Duration = Duration::from_secs(1);
    /// Steps between two checks.
    const STEPS: u128 = 100;

    fn new(robots: usize) -> Self {
        Self {
            logged: vec![0; robots],
            last: vec![None; robots],
        }
    }

    fn check(&mut self, sim: &Simulation) {
        for (i, r) in sim.robots().iter().enumerate() {
            let total = r.link_stats().overflowed();
            if total == self.logged[i] {
                continue;
            }
            let now = std::time::Instant::now();
            if self.last[i].is_some_and(|t| now.duration_since(t) < Self::EVERY) {
                continue;
            }
            let s = r.link_stats();
            tracing::warn!(
                robot = r.id(),
                dropped = total - self.logged[i],
                to_robot_total = s.overflow_to_robot,
                to_host_total = s.overflow_to_host,
                "link buffer full ({LINK_BUFFER_BYTES} bytes): packets dropped"
            );
            self.logged[i] = total;
            self.last[i] = Some(now);
        }
    }
}

/// Hands robot `i`'s waiting host packets to its link and counts what the host side dropped.
fn drain_host_buffer(sim: &mut Simulation, i: usize, buffer: &HostBuffer) {
    let (packets, dropped) = {
        let mut guard = buffer.lock();
        let (queue, dropped) = &mut *guard;
        if queue.is_empty() && dropped.to_robot.0 == 0 && dropped.to_host.0 == 0 {
            return;
        }
        let peak = queue.peak_bytes();
        let packets: Vec<Vec<u8>> = std::iter::from_fn(|| queue.pop().map(|(_, p)| p)).collect();
        (packets, (std::mem::take(dropped), peak))
    };
    let (dropped, peak) = dropped;
    sim.note_host_buffer(i, dropped.to_robot, dropped.to_host, peak);
    for p in packets {
        sim.host_send(i, p);
    }
}

async fn step_loop(
    mut sim: Simulation,
    pace: Pace,
    mut commands: mpsc::UnboundedReceiver<Command>,
    to_robot: Vec<Arc<HostBuffer>>,
    from_robot: Vec<mpsc::UnboundedSender<Vec<u8>>>,
    waiting: Arc<[AtomicBool]>,
) -> Simulation {
    let _stopped = StopOnDrop(to_robot.clone());
    let mut overflow_log = OverflowLog::new(to_robot.len());
    let dt = sim.dt();
    let wall_start = tokio::time::Instant::now();
    let sim_start = sim.now();
    let mut kicks: Vec<(Duration, usize, [f64; 3])> = Vec::new();
    loop {
        while let Ok(c) = commands.try_recv() {
            match c {
                Command::Connect(i) => sim.connect(i),
                Command::Disconnect(i, done) => {
                    // What the leaving host still had waiting goes with it.
                    let waiting = to_robot[i].lock().0.clear();
                    sim.count_discarded_on_close(i, waiting as u64);
                    sim.disconnect(i);
                    if let Some(done) = done {
                        let _ = done.send(());
                    }
                }
                Command::SetLinkUp(i, up) => sim.set_link_up(i, up),
                Command::Truth(reply) => {
                    let _ = reply.send(truth(&sim));
                }
                Command::Poses(reply) => {
                    let _ = reply.send(Poses {
                        now: sim.now(),
                        robots: sim.robots().iter().map(|r| (r.id(), r.pose())).collect(),
                    });
                }
                Command::Displace(i, [dx, dy, dtheta], reply) => {
                    let _ = reply.send(sim.displace(i, dx, dy, dtheta));
                }
                Command::DisplaceAt(at, i, by) => kicks.push((at, i, by)),
                Command::Inspect(job) => job(&mut sim),
                Command::Stop => return sim,
            }
        }
        kicks.retain(|&(at, i, [dx, dy, dtheta])| {
            if sim.now() < at {
                return true;
            }
            match sim.displace(i, dx, dy, dtheta) {
                Ok(p) => {
                    let robot = sim.robots()[i].id();
                    tracing::info!(robot, x = p.x, y = p.y, theta = p.theta, "kicked");
                }
                Err(e) => tracing::warn!("{e}"),
            }
            false
        });
        for (i, (buffer, flag)) in to_robot.iter().zip(waiting.iter()).enumerate() {
            // Load before swapping: most flags are down, and a load does not take the line.
            if flag.load(Ordering::Acquire) && flag.swap(false, Ordering::AcqRel) {
                drain_host_buffer(&mut sim, i, buffer);
            }
        }
        sim.step();
        // Reading every robot's counters is a cache miss per robot: once per 100 simulated ms is
        // soon enough for a log line limited to one a second.
        if (sim.now().as_nanos() / dt.as_nanos()) % OverflowLog::STEPS == 0 {
            overflow_log.check(&sim);
        }
        for (i, tx) in from_robot.iter().enumerate() {
            let mut sink = None;
            while let Some(p) = sim.host_recv(i) {
                // Locked only for a robot with a packet due, and once per step.
                match sink.get_or_insert_with(|| to_robot[i].sink()).as_mut() {
                    // A sink whose reader has gone drops the packet, as a closed link would.
                    Some((_, sink)) => {
                        sink(Some(p));
                    }
                    None => {
                        let _ = tx.send(p);
                    }
                }
            }
        }
        match pace {
            Pace::TokioClock => tokio::time::sleep(dt).await,
            Pace::Unpaced => tokio::task::yield_now().await,
            Pace::WallClock | Pace::Scaled(_) => {
                let rate = match pace {
                    Pace::Scaled(r) => r,
                    _ => 1.0,
                };
                // Sleep in 10 ms batches: finer sleeps cost more than they buy.
                let ahead = (sim.now() - sim_start).div_f64(rate);
                let target = wall_start + ahead;
                if target > tokio::time::Instant::now() + Duration::from_millis(10) {
                    tokio::time::sleep_until(target).await;
                } else {
                    tokio::task::yield_now().await;
                }
            }
        }
    }
}
