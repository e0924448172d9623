//! The stepping task: commands between steps, host packets into the links, the step, robot
//! packets out to their readers, the pace, and the log of full buffers.

use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::mpsc;

use super::buffer::{HostBuffer, StopOnDrop};
use super::{truth, Command, Pace, Poses};
use crate::link::LINK_BUFFER_BYTES;
use crate::sim::Simulation;

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

/// The stepping task: carries out commands, hands host packets to the links, steps, hands robot
/// packets to their readers, and keeps `pace`; returns the simulation when told to stop.
pub(super) async fn step_loop(
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
    let mut kicks: Vec<Kick> = Vec::new();
    let mut jobs: Vec<Job> = Vec::new();
    loop {
        while let Ok(c) = commands.try_recv() {
            match c {
                Command::At(at, job) => jobs.push((at, job)),
                c => {
                    if obey(&mut sim, c, &to_robot, &mut kicks).is_break() {
                        return sim;
                    }
                }
            }
        }
        start_due_kicks(&mut sim, &mut kicks);
        run_due_jobs(&mut sim, &mut jobs);
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
        deliver_to_host(&mut sim, &from_robot, &to_robot);
        keep_pace(pace, dt, sim.now(), sim_start, wall_start).await;
    }
}

/// A job waiting for its simulated time.
type Job = (Duration, Box<dyn FnOnce(&mut Simulation) + Send>);

/// Runs every job whose time has come, in the order they were given.
fn run_due_jobs(sim: &mut Simulation, jobs: &mut Vec<Job>) {
    if jobs.iter().all(|(at, _)| sim.now() < *at) {
        return;
    }
    let (due, later): (Vec<Job>, Vec<Job>) = std::mem::take(jobs)
        .into_iter()
        .partition(|(at, _)| sim.now() >= *at);
    *jobs = later;
    for (_, job) in due {
        job(sim);
    }
}

/// A kick waiting for its time: when, which robot, by how much and how.
type Kick = (Duration, usize, [f64; 3], world::cli::KickHow);

/// Carries out one command; breaks on [`Command::Stop`].
fn obey(
    sim: &mut Simulation,
    c: Command,
    to_robot: &[Arc<HostBuffer>],
    kicks: &mut Vec<Kick>,
) -> ControlFlow<()> {
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
            let _ = reply.send(truth(sim));
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
        Command::DisplaceAt(at, i, by, how) => kicks.push((at, i, by, how)),
        Command::Inspect(job) => job(sim),
        // Taken by the stepping loop, which keeps the jobs waiting.
        Command::At(_, job) => job(sim),
        Command::Stop => return ControlFlow::Break(()),
    }
    ControlFlow::Continue(())
}

/// Kicks every robot whose kick is due at the simulation's time, and forgets those kicks.
fn start_due_kicks(sim: &mut Simulation, kicks: &mut Vec<Kick>) {
    kicks.retain(|&(at, i, by, how)| {
        if sim.now() < at {
            return true;
        }
        match sim.kick(i, by, how) {
            Ok(()) => {
                let robot = sim.robots()[i].id();
                tracing::info!(robot, ?by, ?how, "kicked");
            }
            Err(e) => tracing::warn!("{e}"),
        }
        false
    });
}

/// Hands every packet due at the host to its robot's reader: the sink when one is set, else the
/// channel.
fn deliver_to_host(
    sim: &mut Simulation,
    from_robot: &[mpsc::UnboundedSender<Vec<u8>>],
    to_robot: &[Arc<HostBuffer>],
) {
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
}

/// Waits as `pace` asks after a step that brought the simulation to `now`.
async fn keep_pace(
    pace: Pace,
    dt: Duration,
    now: Duration,
    sim_start: Duration,
    wall_start: tokio::time::Instant,
) {
    match pace {
        Pace::TokioClock => tokio::time::sleep(dt).await,
        Pace::Unpaced => tokio::task::yield_now().await,
        Pace::WallClock | Pace::Scaled(_) => {
            let rate = match pace {
                Pace::Scaled(r) => r,
                _ => 1.0,
            };
            // Sleep in 10 ms batches: finer sleeps cost more than they buy.
            let ahead = (now - sim_start).div_f64(rate);
            let target = wall_start + ahead;
            if target > tokio::time::Instant::now() + Duration::from_millis(10) {
                tokio::time::sleep_until(target).await;
            } else {
                tokio::task::yield_now().await;
            }
        }
    }
}
