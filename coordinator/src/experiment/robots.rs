//! Finding and connecting the robots: simulated ones started in this process, or robots at
//! addresses; their greeting, settings written before the run, faults and kicks injected.

use super::*;

/// The robots of the plan's transport, their starting poses when the world places them, and the
/// simulation when there is one.
pub(super) async fn find_robots(
    plan: &Plan,
    world: &World,
    hooks: &mut Hooks,
) -> Result<(Vec<Discovered>, Option<Vec<Pose>>, Option<SimHandle>)> {
    Ok(match &plan.transport {
        Transport::Sim => {
            let origins = start_poses(world);
            let (handle, found) = start_simulation(plan, world).await?;
            (found, Some(origins), Some(handle))
        }
        Transport::Addresses(addrs) => {
            let found = StaticList {
                addresses: addrs.clone(),
            }
            .discover()
            .await?;
            (found, None, None)
        }
        Transport::Replay(_) => {
            let (found, simulated) = hooks.replay_connectors()?;
            (found, simulated.then(|| start_poses(world)), None)
        }
        #[cfg(feature = "zenoh")]
        Transport::Zenoh {
            fleet,
            robots,
            options,
        } => {
            use robot_actor::link::zenoh::{open_session, Keys, ZenohDiscoverer};
            let keys = Keys::new(fleet)?;
            let session = open_session(options).await?;
            let found = ZenohDiscoverer::new(session, keys, *robots, HELLO_DEADLINE)
                .discover()
                .await?;
            if found.len() < *robots {
                bail!(
                    "fleet {fleet}: {} of the {robots} robots asked for have a gateway after {} s",
                    found.len(),
                    HELLO_DEADLINE.as_secs()
                );
            }
            (found, None, None)
        }
    })
}

/// Where the world places each robot.
pub(super) fn start_poses(world: &World) -> Vec<Pose> {
    world
        .robots
        .iter()
        .map(|r| Pose {
            x: r.position.x,
            y: r.position.y,
            theta: r.heading_rad,
        })
        .collect()
}

#[cfg(feature = "sim")]
/// Starts the world's simulation with the plan's seed, pace and body faults, and finds its robots.
pub(super) async fn start_simulation(
    plan: &Plan,
    world: &World,
) -> Result<(SimHandle, Vec<Discovered>)> {
    if plan.physics_every >= 4 && !world.obstacles.is_empty() {
        tracing::warn!(
            physics_hz = plan.physics_hz(),
            "physics below 500 Hz: moves, turns and line following keep their accuracy, but \
             contacts are resolved every {} ms, and two robots push the heavy box about a fifth \
             less far in the same time than at 1 kHz (250 Hz: 17 %, 200 Hz: 22 %)",
            plan.physics_every
        );
    }
    let mut sim = Simulation::new(
        world.clone(),
        SimConfig {
            seed: Some(plan.seed),
            physics_every: plan.physics_every,
            ..SimConfig::default()
        },
    );
    for &(id, fault) in &plan.body_faults {
        let i = sim
            .robot_index(id)
            .ok_or_else(|| anyhow!("body fault for robot {id}: no such robot in the world"))?;
        sim.set_body_fault(i, Some(fault));
    }
    let pace = if plan.realtime {
        Pace::WallClock
    } else {
        Pace::TokioClock
    };
    let (handle, ends, _task) = runtime::spawn(sim, pace);
    let found = SimDiscoverer::new(ends).discover().await?;
    Ok((handle, found))
}

/// A coordinator built without the simulator cannot run simulated robots.
#[cfg(not(feature = "sim"))]
pub(super) async fn start_simulation(_: &Plan, _: &World) -> Result<(SimHandle, Vec<Discovered>)> {
    bail!(
        "simulated robots need the coordinator built with its cargo feature `sim` (on by \
         default): give --transport tcp and robot addresses instead"
    )
}

#[cfg(feature = "sim")]
/// Schedules the plan's faults and kicks on the simulation's clock; each is recorded (in the
/// report and on the recording's `/events`) as it lands.
pub(super) fn inject_faults(
    h: &SimHandle,
    faults: &[(usize, FaultSpec)],
    kicks: &[(usize, Kick)],
    log: &crate::instruments::EventLog,
) -> Landed {
    let landed: Landed = Arc::default();
    for &(index, fault) in faults {
        let (h, log, landed) = (h.clone(), log.clone(), Arc::clone(&landed));
        tokio::spawn(async move {
            tokio::time::sleep(fault.at).await;
            let at_s = h
                .inspect(move |sim| {
                    match fault.kind {
                        crate::plan::FaultKind::Cut => sim.set_link_up(index, false),
                        crate::plan::FaultKind::Reboot => sim.reboot(index),
                        kind => sim.impair_link(index, kind, fault.lasting),
                    }
                    sim.now().as_secs_f64()
                })
                .await;
            let Some(at_s) = at_s else { return };
            let text = fault.describe();
            tracing::info!(robot = fault.robot, "fault: {text}");
            log.note(fault.robot, "fault", &text);
            lock(&landed).1.push(FaultRecord { spec: fault, at_s });
            if fault.kind == crate::plan::FaultKind::Cut {
                tokio::time::sleep(fault.lasting).await;
                h.set_link_up(index, true);
                log.note(fault.robot, "fault-end", &text);
            }
        });
    }
    for &(index, kick) in kicks {
        let (h, log, landed) = (h.clone(), log.clone(), Arc::clone(&landed));
        tokio::spawn(async move {
            tokio::time::sleep(kick.at).await;
            let record = h.inspect(move |sim| land_kick(sim, index, kick)).await;
            if let Some(record) = record {
                match &record.refused {
                    None => tracing::info!(robot = kick.robot, by = ?record.by, "kicked"),
                    Some(e) => tracing::warn!(robot = kick.robot, "kick not applied: {e}"),
                }
                log.note(kick.robot, "kick", &record.describe());
                lock(&landed).0.push(record);
            }
        });
    }
    landed
}

/// What landed on the simulated robots from outside: kicks and faults, in the order they did.
pub(super) type Landed = Arc<std::sync::Mutex<(Vec<KickRecord>, Vec<FaultRecord>)>>;

#[cfg(feature = "sim")]
fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Gives `kick` to robot `index` now: its displacement drawn here when it is random, turned
/// into the robot's frame when it is sideways.
#[cfg(feature = "sim")]
fn land_kick(sim: &mut Simulation, index: usize, kick: Kick) -> KickRecord {
    let from = sim.robots()[index].pose();
    let heading = from.theta;
    let by = match kick.drawn {
        Some(seed) => sim.draw_kick(
            index,
            seed,
            world::cli::RANDOM_SHIFT_M,
            world::cli::RANDOM_TURN_DEG.to_radians(),
        ),
        None => Some([
            kick.dx_m - kick.sideways_m * heading.sin(),
            kick.dy_m + kick.sideways_m * heading.cos(),
            kick.dtheta_rad,
        ]),
    };
    let mut record = KickRecord {
        robot: kick.robot,
        at_s: sim.now().as_secs_f64(),
        how: kick.how,
        by: by.unwrap_or_default(),
        from: [from.x, from.y, from.theta],
        refused: None,
    };
    record.refused = match by {
        None => Some("no clear shift and turn was found in 200 draws".into()),
        Some(by) => sim.kick(index, by, kick.how).err(),
    };
    record
}

/// Without the simulator there is no simulation to inject faults into.
#[cfg(not(feature = "sim"))]
pub(super) fn inject_faults(
    h: &SimHandle,
    _: &[(usize, FaultSpec)],
    _: &[(usize, Kick)],
    _: &crate::instruments::EventLog,
) -> Landed {
    match *h {}
}

/// Starts a robot actor per discovered robot and waits for every hello at once, at most
/// `deadline` each. Refused robots, silent ones and two robots claiming one id end the experiment
/// before it starts, with every robot closed; the first such problem in discovery order is the one
/// reported. The observer hears every robot's events, and its states only when `observe_states`.
pub(super) async fn connect_all(
    found: &[Discovered],
    origins: Option<&[Pose]>,
    world: &World,
    (observer, observe_states): (&actix::Addr<Observer>, bool),
    deadline: Duration,
    shards: Option<&Shards>,
) -> Result<Vec<(u16, Robot)>> {
    let mut started: Vec<Robot> = Vec::with_capacity(found.len());
    for (i, d) in found.iter().enumerate() {
        let config = RobotConfig {
            origin: origins.and_then(|o| o.get(i).copied()).unwrap_or_default(),
            ..RobotConfig::default()
        };
        let robot = match shards {
            Some(shards) => shards.start(Arc::clone(&d.connector), config),
            None => Robot::start(Arc::clone(&d.connector), config),
        };
        // Before any packet: replay checks the observer's view after each robot's k-th update.
        if observe_states {
            robot.subscribe(observer.clone().recipient());
        }
        robot.subscribe_events(observer.clone().recipient());
        started.push(robot);
    }
    let hellos = futures::future::join_all(
        started
            .iter()
            .zip(found)
            .map(|(r, d)| greet(r, d, deadline)),
    )
    .await;
    let mut robots: Vec<(u16, Robot, String)> = Vec::with_capacity(found.len());
    let mut failure = None;
    for ((robot, d), greeted) in started.into_iter().zip(found).zip(hellos) {
        let peer = d.connector.peer();
        let greeted = greeted.and_then(|hello| {
            match robots.iter().find(|(id, _, _)| *id == hello.robot_id) {
                Some((id, _, first)) => Err(anyhow!(
                    "robots at {first} and {peer} both say they are robot {id}: every robot \
                     needs its own id"
                )),
                None => Ok(hello),
            }
        });
        let hello = match greeted {
            Ok(hello) if failure.is_none() => hello,
            Ok(_) => {
                robot.close();
                continue;
            }
            Err(e) => {
                robot.close();
                failure.get_or_insert(e);
                continue;
            }
        };
        if origins.is_none() {
            // Robots reached by address start where the world file places their id.
            if let Some(start) = world.robots.iter().find(|r| r.id == hello.robot_id) {
                robot.addr().do_send(SetOdometryOrigin(Pose {
                    x: start.position.x,
                    y: start.position.y,
                    theta: start.heading_rad,
                }));
            }
        }
        tracing::info!(robot = { hello.robot_id }, %peer, "connected");
        robots.push((hello.robot_id, robot, peer));
    }
    if let Some(e) = failure {
        for (_, r, _) in &robots {
            r.close();
        }
        return Err(e);
    }
    Ok(robots.into_iter().map(|(id, r, _)| (id, r)).collect())
}

/// Writes each of `settings` to every robot, confirmed by read-back: a refusal (a value out of
/// the robot's range) ends the experiment before it starts, naming the setting and the robot.
pub(super) async fn write_settings(
    robots: &[(u16, Robot)],
    settings: &[SettingWrite],
) -> Result<()> {
    for (id, robot) in robots {
        for w in settings {
            let msg = robot_actor::WriteSettings {
                offset: w.offset,
                bytes: w.bytes.clone(),
            };
            robot
                .addr()
                .send(msg)
                .await
                .map_err(|e| anyhow!("--setting {}: robot {id}: {e}", w.path))?
                .map_err(|e| anyhow!("--setting {}: robot {id} refused it: {e}", w.path))?;
        }
    }
    Ok(())
}

/// Waits for one robot's hello; a timeout says why the link never came up, if it did not.
pub(super) async fn greet(robot: &Robot, d: &Discovered, deadline: Duration) -> Result<Hello> {
    match tokio::time::timeout(deadline, robot.connected()).await {
        Ok(hello) => hello.with_context(|| d.name.clone()),
        Err(_) => {
            let snapshot = robot.snapshot().await?;
            match snapshot.link_error {
                Some(why) => bail!("{}: {why}; no link within {deadline:?}", d.name),
                None => bail!("{} did not say hello within {deadline:?}", d.name),
            }
        }
    }
}

/// A progress bar over the time limit, on a terminal only; it moves with the experiment's clock.
pub(super) fn progress_bar(
    limit: Duration,
    started: tokio::time::Instant,
) -> Option<(indicatif::ProgressBar, tokio::task::JoinHandle<()>)> {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        return None;
    }
    let bar = indicatif::ProgressBar::new(limit.as_millis() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} ms")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message("experiment time");
    let b = bar.clone();
    let task = tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_millis(100));
        loop {
            tick.tick().await;
            b.set_position((tokio::time::Instant::now() - started).as_millis() as u64);
        }
    });
    Some((bar, task))
}
