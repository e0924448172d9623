//! Setting up: the behaviour's typed parameters and how it is built from them.

use super::*;

params! {
    /// Parameters of `traffic_control`.
    pub struct TrafficControlParams {
        /// Whether an edge's next segment is queued behind the running one, so that the robot does not slow down between them (`false`: each segment is sent once the last has ended).
        flow: bool = true;
        /// Each robot's single task, as comma-separated track node ids, one per robot, for scripted scenarios such as a swap through a single-lane section (default: random goal streams).
        goals: Option<String> = None;
        /// Tasks per robot after which it only keeps out of the way (default: unlimited).
        quota: Option<u32> = None;
        /// How the team is planned again when robots reach their goals: `lifelong` or `barrier`.
        replan: Replan = Replan::Lifelong;
        /// Length of one driven segment, metres.
        segment_m: f64 = LOOKAHEAD, 0.02 => MAX_SEGMENT_M;
        /// Tasks to complete in all (default: 1.5 per robot, rounded up).
        tasks: Option<u32> = None, 1 => 1_000_000;
    }
}

/// The scripted goals' node indices, one per robot, checked against the track.
fn scripted_goals(
    p: &TrafficControlParams,
    graph: &TrackGraph,
    robots: usize,
) -> Result<Option<Vec<u32>>, String> {
    let Some(list) = &p.goals else {
        return Ok(None);
    };
    let goals: Vec<u32> = list
        .split(',')
        .map(|id| {
            graph
                .node(id.trim())
                .map(|n| n.index() as u32)
                .ok_or_else(|| format!("goals: no track node {:?}", id.trim()))
        })
        .collect::<Result<_, _>>()?;
    if goals.len() != robots {
        return Err(format!(
            "goals: {} nodes for {} robots",
            goals.len(),
            robots
        ));
    }
    Ok(Some(goals))
}

impl Register for TrafficControl {
    type Params = TrafficControlParams;

    fn check(p: &TrafficControlParams, cfg: &BehaviourConfig) -> Result<(), String> {
        if cfg.track.edges().is_empty() {
            return Err("traffic control needs a track".into());
        }
        scripted_goals(p, &TrackGraph::new(&cfg.track), cfg.robots.len()).map(drop)
    }

    /// Builds it.
    ///
    /// # Errors
    /// A track without edges, or goal nodes the track does not have.
    fn build(p: TrafficControlParams, cfg: &BehaviourConfig) -> Result<Self, String> {
        if cfg.track.edges().is_empty() {
            return Err("traffic control needs a track".into());
        }
        let graph = TrackGraph::new(&cfg.track);
        let mapf = Graph::from_petgraph(&graph.graph).map_err(|e| e.to_string())?;
        let default_tasks = ((TASKS_PER_ROBOT * cfg.robots.len() as f64).ceil() as u32).max(1);
        let target_tasks = p.tasks.unwrap_or(default_tasks);
        let (quota, replan_mode, segment_m, flow) = (p.quota, p.replan, p.segment_m, p.flow);
        let scripted = scripted_goals(&p, &graph, cfg.robots.len())?;
        let bots = cfg
            .robots
            .iter()
            .enumerate()
            .map(|(k, &id)| Bot {
                id,
                node: 0,
                goal: scripted.as_ref().map_or(u32::MAX, |g| g[k]),
                driving: None,
                at_end: false,
                tasks_done: 0,
                reached: false,
                edges_m: 0.0,
                retry: false,
                held_since: None,
                held_why: String::new(),
                fresh_hold: false,
                lost: None,
                tail: None,
                rng: ChaCha8Rng::seed_from_u64(cfg.seed ^ (u64::from(id) << 32)),
                active: true,
                making_room: None,
            })
            .collect();
        let (target_tasks, quota) = match &scripted {
            Some(g) => (g.len() as u32, Some(1)),
            None => (target_tasks, quota),
        };
        Ok(Self {
            track: Arc::clone(&cfg.track),
            graph,
            mapf,
            bots,
            adg: None,
            phase: Phase::Placing,
            seed: cfg.seed,
            target_tasks,
            quota,
            tasks: 0,
            replans: 0,
            held: 0,
            recoveries: 0,
            recoveries_total: 0,
            scripted: scripted.is_some(),
            replan_mode,
            replan_due: false,
            replans_live: 0,
            segment_m,
            flow,
            plan_time_max: Duration::ZERO,
            last_progress: Duration::ZERO,
            started: Duration::ZERO,
            now: Duration::ZERO,
            odometer: Odometer::new(),
            verdict: None,
        })
    }
}
