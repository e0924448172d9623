//! Assignment and planning: goal nodes handed out as tasks, the team planned with LaCAM (at a
//! barrier or lifelong from its committed configuration) and the plan run as an action
//! dependency graph.

use super::*;

impl TrafficControl {
    /// A new goal for robot `k`, planned from `here`: a random node that is no other robot's
    /// goal nor `here`.
    pub(super) fn new_task(&mut self, k: usize, here: u32) {
        let n = self.mapf.num_vertices() as u32;
        let used: std::collections::HashSet<u32> = self
            .bots
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != k)
            .map(|(_, b)| b.goal)
            .collect();
        let free: Vec<u32> = (0..n).filter(|v| *v != here && !used.contains(v)).collect();
        let bot = &mut self.bots[k];
        bot.reached = false;
        bot.goal = if free.is_empty() {
            here
        } else {
            free[bot.rng.gen_range(0..free.len())]
        };
    }

    /// Goals for everyone at a goal, then a plan for the whole team from where it stands.
    pub(super) fn replan(&mut self) -> Result<(), String> {
        let starts: Vec<u32> = self.bots.iter().map(|b| b.node).collect();
        let goals = self.assign_goals(&starts);
        let plan = self.solve(&starts, &goals)?;
        self.adg = Some(Adg::new(&plan).map_err(|e| format!("plan not executable: {e}"))?);
        self.replans += 1;
        self.replan_due = false;
        Ok(())
    }

    /// New tasks for the robots standing on their goals, and the goals to plan for: each robot's
    /// own, or the node it is planned from (`starts`) while its goal is another's.
    pub(super) fn assign_goals(&mut self, starts: &[u32]) -> Vec<u32> {
        for (k, &here) in starts.iter().enumerate() {
            let driving = self.bots[k].driving.is_some();
            let b = &mut self.bots[k];
            if b.active && b.goal == here && self.scripted && !driving {
                // A scripted robot that starts on its goal has nothing to do but keep clear.
                b.tasks_done += 1;
                self.tasks += 1;
                b.active = false;
            }
            if !b.active {
                // A robot whose quota is done keeps clear where it is; with lifelong replanning
                // one the plan has sent on from its last goal keeps that goal, so that the last
                // plan, run to its end, brings it back (barrier plans start with it standing on
                // it, as it stops there).
                if !(b.reached && self.replan_mode == Replan::Lifelong) {
                    b.goal = here;
                }
                continue;
            }
            // A robot driving to its goal keeps it: reaching it is counted on arrival.
            if b.reached || b.goal == u32::MAX || (!driving && b.goal == here) {
                self.new_task(k, here);
            }
        }
        // Goals must differ: a robot whose goal another holds waits where it is this round. A
        // standing robot's goal becomes its node (it gets a new task next round, as before); a
        // driving one keeps its goal, so arriving on the node it drives to is not a task done.
        let mut goals: Vec<u32> = self.bots.iter().map(|b| b.goal).collect();
        let mut seen = std::collections::HashSet::with_capacity(goals.len());
        for k in 0..self.bots.len() {
            if seen.contains(&goals[k]) {
                goals[k] = starts[k];
                if self.bots[k].driving.is_none() {
                    self.bots[k].goal = starts[k];
                }
            }
            seen.insert(goals[k]);
        }
        goals
    }

    /// A plan from `starts` to `goals`.
    pub(super) fn solve(&mut self, starts: &[u32], goals: &[u32]) -> Result<Solution, String> {
        let t = Instant::now();
        let plan = lacam::solve(
            &self.mapf,
            starts,
            goals,
            &lacam::Options {
                seed: self.seed.wrapping_add(u64::from(self.replans)),
                time_limit: None,
                max_expansions: Some(MAX_EXPANSIONS),
                // Swap solves narrow-aisle warehouses, but on `junction` its plans (robots backing
                // out to let others pass) kept the 100-task run from finishing in 3,000 s.
                swap: false,
            },
        )
        .map_err(|e| format!("planning failed: {e}"))?;
        self.plan_time_max = self.plan_time_max.max(t.elapsed());
        Ok(plan)
    }

    /// Lifelong replanning: new tasks for the robots on their goals and a plan for the team while
    /// it keeps moving. Each robot is planned from its committed node: the one it stands on, or
    /// the end of the edge it is driving. That drive is kept as the robot's first action of the
    /// new plan (its path gets the edge's start node in front, standing robots' paths a wait),
    /// so the dependency graph makes any robot the plan sends into that start node wait until
    /// the drive is complete, as the old plan did. Committed nodes are distinct (a robot drives
    /// into a node only once its previous occupant has arrived elsewhere) and so are the start
    /// nodes, so the prefixed plan is a valid one.
    ///
    /// Returns false, planning nothing, while some robot drives outside the plan.
    pub(super) fn replan_lifelong(&mut self) -> Result<bool, String> {
        if self
            .bots
            .iter()
            .any(|b| b.driving.is_some_and(|l| l.index.is_none()))
        {
            return Ok(false);
        }
        let committed: Vec<u32> = self
            .bots
            .iter()
            .map(|b| b.driving.map_or(b.node, |l| l.to))
            .collect();
        let goals = self.assign_goals(&committed);
        let mut plan = self.solve(&committed, &goals)?;
        for (b, path) in self.bots.iter().zip(plan.paths.iter_mut()) {
            path.insert(0, b.node);
        }
        self.adg = Some(Adg::new(&plan).map_err(|e| format!("plan not executable: {e}"))?);
        for b in &mut self.bots {
            if let Some(leg) = b.driving.as_mut() {
                leg.index = Some(0);
            }
        }
        self.replans += 1;
        self.replans_live += 1;
        self.replan_due = false;
        Ok(true)
    }

    /// Starts every action the dependency graph allows.
    pub(super) fn dispatch(&mut self, world: &WorldSnapshot, team: &Team) -> Vec<Intent> {
        let mut out = Vec::new();
        if self.phase != Phase::Running {
            return out;
        }
        for k in 0..self.bots.len() {
            let b = &self.bots[k];
            if b.driving.is_some()
                || !team.idle(b.id)
                || b.lost.is_some()
                || b.making_room.is_some()
            {
                continue;
            }
            let Some(action) = self.adg.as_ref().and_then(|a| a.ready(k)) else {
                continue;
            };
            let Some(view) = world.robot(self.bots[k].id) else {
                continue;
            };
            let Some((edge, forward)) = self.edge_between(action.from, action.to) else {
                continue;
            };
            tracing::debug!(
                t = world.time.as_secs_f64(),
                robot = self.bots[k].id,
                from = %self.name(action.from),
                to = %self.name(action.to),
                pose = ?(view.pose.x, view.pose.y, view.pose.theta.to_degrees()),
                "drive"
            );
            self.bots[k].driving = Some(EdgeDrive {
                index: Some(action.index),
                edge,
                forward,
                to: action.to,
                last: false,
                back: false,
            });
            out.extend(self.drive(k, world));
        }
        out
    }
}
